//! The `host-sim sweep force|torque` and `host-sim identify force|torque|plant` commands: thin
//! wrappers over [`super::force`], [`super::torque`] and [`super::plant`]. Every output file
//! is written atomically; bad input gives an error naming the file, the line and the field.

// `!(x > 0.0)` is deliberate: it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::nonminimal_bool)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};

use super::force::{self, ForceSweep, Tondu};
use super::plant::{identify_plant_files, PlantFitOptions};
use super::torque::{self, TorqueSource, TorqueSweep};
use super::{write_atomic, MeasurementNoise};
use crate::sim::SolverOptions;
use crate::{Plant, PlantConfig, Recording};

/// `host-sim sweep ...`: synthetic identification data from a plant file.
#[derive(Args, Debug)]
pub struct SweepArgs {
    #[command(subcommand)]
    pub what: SweepWhat,
}

#[derive(Subcommand, Debug)]
pub enum SweepWhat {
    /// Isometric force data (columns p_kpa, stretch, f_n[, state]) from the plant's Tondu
    /// surface: at each L/L0 the pressure is swept from the maximum to 0 (and back up with
    /// --hysteresis-gap-n), as on seed 002's bench.
    Force(SweepForceArgs),
    /// A torque-identification recording (RECORDING.md columns) as in seed 003: the joint is
    /// driven quasi-statically and at constant speeds through +-amplitude at each activation
    /// dp (p1 = p0 - dp, p2 = p0 + dp held by regulators); channels from the plant's sensors.
    Torque(SweepTorqueArgs),
}

#[derive(Args, Debug)]
pub struct SweepForceArgs {
    /// Plant file: the muscle's Tondu parameters (radius_m, braid_angle_deg, end_factor).
    #[arg(long, value_name = "P.toml")]
    pub plant: PathBuf,
    /// Output CSV.
    #[arg(long, value_name = "F.csv")]
    pub out: PathBuf,
    /// Number of L/L0 levels.
    #[arg(long, default_value_t = 31)]
    pub n_stretch: usize,
    /// Number of pressure levels per sweep.
    #[arg(long, default_value_t = 31)]
    pub n_pressure: usize,
    /// Lowest L/L0.
    #[arg(long, default_value_t = 0.75)]
    pub stretch_min: f64,
    /// Highest L/L0.
    #[arg(long, default_value_t = 1.05)]
    pub stretch_max: f64,
    /// Highest gauge pressure [kPa].
    #[arg(long, default_value_t = 600.0)]
    pub p_max_kpa: f64,
    /// Load-cell noise, standard deviation [N].
    #[arg(long, default_value_t = 3.0)]
    pub force_noise_n: f64,
    /// Pressure-sensor noise, standard deviation [kPa].
    #[arg(long, default_value_t = 0.5)]
    pub pressure_noise_kpa: f64,
    /// Gap between the pressurising and depressurising branches at full pressure [N]; > 0
    /// sweeps both branches and writes a `state` column.
    #[arg(long, default_value_t = 0.0)]
    pub hysteresis_gap_n: f64,
    /// Random seed of the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

#[derive(Args, Debug)]
pub struct SweepTorqueArgs {
    /// Plant file.
    #[arg(long, value_name = "P.toml")]
    pub plant: PathBuf,
    /// Output recording.
    #[arg(long, value_name = "R.csv")]
    pub out: PathBuf,
    /// Mid pressure p0, gauge [kPa].
    #[arg(long, default_value_t = 300.0)]
    pub p0_kpa: f64,
    /// Activation levels dp [kPa], comma separated.
    #[arg(
        long,
        value_delimiter = ',',
        allow_hyphen_values = true,
        default_value = "-200,-100,0,100,200"
    )]
    pub dp_kpa: Vec<f64>,
    /// Angle amplitude of the motion [rad].
    #[arg(long, default_value_t = 0.35)]
    pub amplitude_rad: f64,
    /// Constant speeds of the passes [rad/s], comma separated (the first quasi-static).
    #[arg(long, value_delimiter = ',', default_value = "0.1,1,2,4")]
    pub speeds_rad_s: Vec<f64>,
    /// Sample period [s].
    #[arg(long, default_value_t = 0.005)]
    pub dt_s: f64,
    /// Encoder counts per turn (0: no angle quantisation).
    #[arg(long, default_value_t = 8000)]
    pub encoder_counts: u32,
    /// Pressure-sensor noise, standard deviation [kPa].
    #[arg(long, default_value_t = 0.5)]
    pub pressure_noise_kpa: f64,
    /// Force-sensor noise, standard deviation [N].
    #[arg(long, default_value_t = 2.0)]
    pub force_noise_n: f64,
    /// Random seed of the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

/// `host-sim identify ...`.
#[derive(Args, Debug)]
pub struct IdentifyArgs {
    #[command(subcommand)]
    pub what: IdentifyWhat,
}

#[derive(Subcommand, Debug)]
pub enum IdentifyWhat {
    /// Fit eq. 6 (seed 002, c1..c10) and the Tondu baseline to isometric data (p_kpa, stretch,
    /// f_n[, state|direction]); print both models' errors; write the firmware's force-law TOML.
    Force(IdentifyForceArgs),
    /// Fit A, B, C, D of eq. 11 (seed 003) to a recording (angle_deg, p1_kpa, p2_kpa and
    /// f1_n, f2_n, else tensions from the plant's force model); write the torque-model TOML.
    Torque(IdentifyTorqueArgs),
    /// Output-error fit of plant-file parameters by replaying the recording's valve inputs;
    /// write the plant file with the fitted values.
    Plant(IdentifyPlantArgs),
}

#[derive(Args, Debug)]
pub struct IdentifyForceArgs {
    /// Isometric data CSV.
    #[arg(long, value_name = "F.csv")]
    pub data: PathBuf,
    /// Output TOML (the format of config/force_law.toml).
    #[arg(long, value_name = "force.toml")]
    pub out: PathBuf,
    /// Upper end of the pressure domain written for the firmware [kPa] [default: the largest
    /// pressure in the data, which sensor noise pushes above the sweep's nominal maximum].
    #[arg(long)]
    pub p_gauge_max_kpa: Option<f64>,
}

#[derive(Args, Debug)]
pub struct IdentifyTorqueArgs {
    /// Recording (RECORDING.md).
    #[arg(long, value_name = "R.csv")]
    pub recording: PathBuf,
    /// Plant file: the sprocket radius r (and the force model when the recording has no tensions).
    #[arg(long, value_name = "P.toml")]
    pub plant: PathBuf,
    /// Output TOML (the format of config/torque_model.toml).
    #[arg(long, value_name = "torque.toml")]
    pub out: PathBuf,
    /// Half window of the Savitzky-Golay velocity estimate [samples] [default: 25 ms worth].
    #[arg(long)]
    pub savgol_half_window: Option<usize>,
    /// Activation limit the controller may command [kPa] [default: min(p0, supply - p0) - 20 kPa].
    #[arg(long)]
    pub dp_max_kpa: Option<f64>,
    /// Fit only the samples of (nearly) constant velocity, as seed 003 does: |acceleration|
    /// averaged over the velocity window at most this [rad/s^2] [default: all samples].
    #[arg(long)]
    pub max_accel_rad_s2: Option<f64>,
}

#[derive(Args, Debug)]
pub struct IdentifyPlantArgs {
    /// Recording whose valve inputs are replayed and whose channels are fitted.
    #[arg(long, value_name = "R.csv")]
    pub recording: PathBuf,
    /// Start plant file.
    #[arg(long, value_name = "P.toml")]
    pub plant: PathBuf,
    /// Dotted keys to fit, comma separated, each optionally with bounds `key=lo:hi`
    /// (e.g. valve.sonic_conductance_m3_per_s_pa,muscle.damping_m2s,joint.inertia_kgm2).
    #[arg(long, value_delimiter = ',', required = true)]
    pub params: Vec<String>,
    /// Output plant file (the input with the fitted values replaced).
    #[arg(long, value_name = "P2.toml")]
    pub out: PathBuf,
    /// Fraction of the recording (its tail) held out for validation.
    #[arg(long, default_value_t = 0.25)]
    pub holdout_fraction: f64,
    /// Relative (and absolute) tolerance of the replays.
    #[arg(long, default_value_t = 1e-9)]
    pub rtol: f64,
    /// Levenberg-Marquardt patience.
    #[arg(long, default_value_t = 40)]
    pub patience: usize,
}

/// Runs `host-sim sweep ...`; returns the report for stdout.
pub fn run_sweep(a: &SweepArgs) -> Result<String> {
    match &a.what {
        SweepWhat::Force(a) => sweep_force(a),
        SweepWhat::Torque(a) => sweep_torque(a),
    }
}

/// Runs `host-sim identify ...`; returns the report for stdout.
pub fn run_identify(a: &IdentifyArgs) -> Result<String> {
    match &a.what {
        IdentifyWhat::Force(a) => identify_force(a),
        IdentifyWhat::Torque(a) => identify_torque(a),
        IdentifyWhat::Plant(a) => identify_plant(a),
    }
}

/// The Tondu surface of a plant file's muscle.
pub fn tondu_of(cfg: &PlantConfig) -> Tondu {
    Tondu {
        r0_m: cfg.muscle.radius_m,
        alpha0_rad: cfg.muscle.braid_angle_deg.to_radians(),
        k: cfg.muscle.end_factor,
    }
}

fn sweep_force(a: &SweepForceArgs) -> Result<String> {
    let cfg = PlantConfig::load(&a.plant)?;
    if !(a.stretch_min > 0.0 && a.stretch_min < a.stretch_max) {
        bail!("--stretch-min must be > 0 and below --stretch-max");
    }
    if !(a.p_max_kpa > 0.0) || a.n_stretch < 2 || a.n_pressure < 2 {
        bail!("--p-max-kpa must be > 0; --n-stretch and --n-pressure at least 2");
    }
    if !(a.force_noise_n >= 0.0 && a.pressure_noise_kpa >= 0.0 && a.hysteresis_gap_n >= 0.0) {
        bail!("noise levels and the hysteresis gap must be >= 0");
    }
    let opt = ForceSweep {
        n_stretch: a.n_stretch,
        n_pressure: a.n_pressure,
        stretch_min: a.stretch_min,
        stretch_max: a.stretch_max,
        p_max_pa: a.p_max_kpa * 1e3,
        force_noise_n: a.force_noise_n,
        pressure_noise_pa: a.pressure_noise_kpa * 1e3,
        hysteresis_gap_n: a.hysteresis_gap_n,
        seed: a.seed,
    };
    let data = force::sweep(&tondu_of(&cfg), &opt);
    let mut meta = BTreeMap::new();
    meta.insert("plant".to_string(), a.plant.display().to_string());
    meta.insert(
        "source".to_string(),
        format!(
            "host-sim {} sweep force (Tondu surface of the plant's muscle)",
            env!("CARGO_PKG_VERSION")
        ),
    );
    meta.insert(
        "noise".to_string(),
        format!(
            "force sd {} N, pressure sd {} kPa, seed {}",
            a.force_noise_n, a.pressure_noise_kpa, a.seed
        ),
    );
    force::write_force_csv(&a.out, &data, &meta)?;
    Ok(format!(
        "{}: {} samples ({} L/L0 levels {}..{}, {} pressure levels 0..{} kPa{})\n",
        a.out.display(),
        data.len(),
        a.n_stretch,
        a.stretch_min,
        a.stretch_max,
        a.n_pressure,
        a.p_max_kpa,
        if a.hysteresis_gap_n > 0.0 {
            ", both branches"
        } else {
            ""
        }
    ))
}

fn sweep_torque(a: &SweepTorqueArgs) -> Result<String> {
    let plant = Plant::load(&a.plant)?;
    if !(a.dt_s > 0.0 && a.amplitude_rad > 0.0) {
        bail!("--dt-s and --amplitude-rad must be > 0");
    }
    if a.dp_kpa.is_empty()
        || a.speeds_rad_s.is_empty()
        || a.speeds_rad_s.iter().any(|w| !(*w > 0.0))
    {
        bail!("--dp-kpa needs at least one level; --speeds-rad-s at least one speed, all > 0");
    }
    let supply_kpa = (plant.p_supply_abs_pa - plant.p_atm_pa) / 1e3;
    for dp in &a.dp_kpa {
        let (p1, p2) = (a.p0_kpa - dp, a.p0_kpa + dp);
        if p1 < 0.0 || p2 < 0.0 || p1 > supply_kpa || p2 > supply_kpa {
            bail!(
                "--dp-kpa {dp}: p0 -+ dp = {p1}, {p2} kPa leave 0..{supply_kpa} kPa (the supply)"
            );
        }
    }
    let opt = TorqueSweep {
        p0_gauge_pa: a.p0_kpa * 1e3,
        dp_levels_pa: a.dp_kpa.iter().map(|d| d * 1e3).collect(),
        amplitude_rad: a.amplitude_rad,
        speeds_rad_s: a.speeds_rad_s.clone(),
        dt_s: a.dt_s,
    };
    let mut rec = torque::sweep_recording(&plant, &opt);
    let noise = MeasurementNoise {
        encoder_counts_per_turn: a.encoder_counts,
        pressure_noise_pa: a.pressure_noise_kpa * 1e3,
        force_noise_n: a.force_noise_n,
        seed: a.seed,
    };
    noise.apply(&mut rec);
    rec.metadata
        .insert(0, ("plant".into(), a.plant.display().to_string()));
    rec.metadata.push((
        "noise".into(),
        format!(
            "encoder {} counts/turn, pressure sd {} kPa, force sd {} N, seed {}",
            a.encoder_counts, a.pressure_noise_kpa, a.force_noise_n, a.seed
        ),
    ));
    rec.write(&a.out)?;
    Ok(format!(
        "{}: {} samples ({:.1} s), {} activation levels x {} speeds\n",
        a.out.display(),
        rec.len(),
        rec.len() as f64 * a.dt_s,
        a.dp_kpa.len(),
        a.speeds_rad_s.len()
    ))
}

fn identify_force(a: &IdentifyForceArgs) -> Result<String> {
    let data = force::read_force_csv(&a.data)?;
    let mut id = force::identify(&data)?;
    if let Some(p) = a.p_gauge_max_kpa {
        if !(p > 0.0 && p.is_finite()) {
            bail!("--p-gauge-max-kpa must be > 0");
        }
        id.domain.0 = p * 1e3;
    }
    let toml = with_provenance(
        &id.to_toml(&a.data.display().to_string()),
        &a.data,
        "\n[force_law]",
    );
    write_atomic(&a.out, toml.as_bytes())?;
    Ok(format!("{}wrote {}\n", id.summary(), a.out.display()))
}

/// Copies the leading `# key = value` lines of the data file (its provenance: plant, generator,
/// noise) into the header of the identified TOML, before `table`.
fn with_provenance(toml: &str, data: &Path, table: &str) -> String {
    let meta: Vec<String> = std::fs::read_to_string(data)
        .unwrap_or_default()
        .lines()
        .take_while(|l| l.trim_start().starts_with('#'))
        .map(|l| format!("#   {}", l.trim_start().trim_start_matches('#').trim()))
        .collect();
    match toml.find(table) {
        Some(i) if !meta.is_empty() => format!(
            "{}# Data ({}):\n{}\n{}",
            &toml[..i],
            data.display(),
            meta.join("\n"),
            &toml[i..]
        ),
        _ => toml.to_string(),
    }
}

/// 1-based line of the header of a CSV with leading `#` comments.
fn header_line_of(path: &Path) -> usize {
    std::fs::read_to_string(path)
        .ok()
        .and_then(|t| {
            t.lines()
                .position(|l| !l.trim_start().starts_with('#') && !l.trim().is_empty())
        })
        .map(|i| i + 1)
        .unwrap_or(1)
}

fn identify_torque(a: &IdentifyTorqueArgs) -> Result<String> {
    let plant = Plant::load(&a.plant)?;
    // Jittered time stamps go on the uniform grid the velocity filter needs.
    let rec = Recording::read(&a.recording)?.to_uniform();
    let file = a.recording.display().to_string();
    let dt = rec.sample_period_s();
    let hw = a
        .savgol_half_window
        .unwrap_or_else(|| ((0.025 / dt).round() as usize).max(1));
    let (mut samples, source) =
        torque::samples_from_recording(&rec, &plant, hw, &file, header_line_of(&a.recording))?;
    let n_all = samples.len();
    if let Some(max) = a.max_accel_rad_s2 {
        if !(max > 0.0) {
            bail!("--max-accel-rad-s2 must be > 0");
        }
        samples = torque::constant_velocity_samples(&samples, dt, hw, max);
    }
    let (mut model, q) = torque::fit(&samples, plant.joint.sprocket_radius_m)
        .with_context(|| format!("{file}: torque model fit"))?;
    // p0 is the controller's mid pressure: the data mean to 0.1 kPa (the mean of noisy
    // readings is not meaningful below that).
    model.p0_gauge_pa = (model.p0_gauge_pa / 100.0).round() * 100.0;
    // Eq. 11 assumes the symmetric activation p1 + p2 = 2 p0: report how far the data is from it.
    let p0_sd_pa = (samples
        .iter()
        .map(|s| (0.5 * (s.p1_gauge_pa + s.p2_gauge_pa) - model.p0_gauge_pa).powi(2))
        .sum::<f64>()
        / samples.len() as f64)
        .sqrt();
    let symmetric_note = if p0_sd_pa > 0.05 * model.p0_gauge_pa.abs().max(1e3) {
        format!(
            "warning: (p1 + p2) / 2 spreads by {:.1} kPa (sd) around p0 = {:.1} kPa; eq. 11 assumes the \
             symmetric activation p1 = p0 - dp, p2 = p0 + dp (seed 003), so its fit is poor on such data\n",
            p0_sd_pa / 1e3,
            model.p0_gauge_pa / 1e3
        )
    } else {
        String::new()
    };
    let supply_gauge_pa = plant.p_supply_abs_pa - plant.p_atm_pa;
    let dp_max_pa = match a.dp_max_kpa {
        Some(v) => {
            if !(v > 0.0) {
                bail!("--dp-max-kpa must be > 0");
            }
            v * 1e3
        }
        None => {
            // 20 kPa of headroom to atmosphere and to the supply, to whole kPa.
            let v = ((model.p0_gauge_pa.min(supply_gauge_pa - model.p0_gauge_pa) - 20e3) / 1e3)
                .round()
                * 1e3;
            if !(v > 0.0) {
                bail!(
                    "p0 = {:.1} kPa of the data leaves no activation range below the supply; give --dp-max-kpa",
                    model.p0_gauge_pa / 1e3
                );
            }
            v
        }
    };
    let src = match source {
        TorqueSource::MeasuredTensions => format!("{file} (torque from f1_n, f2_n)"),
        TorqueSource::PlantForceModel => format!(
            "{file} (no tension columns: torque from the force model of {})",
            a.plant.display()
        ),
    };
    let toml = with_provenance(
        &model.to_toml(&q, &src, dp_max_pa),
        &a.recording,
        "\n[torque_model]",
    );
    write_atomic(&a.out, toml.as_bytes())?;
    Ok(format!(
        "{} of {n_all} samples fitted, velocity by Savitzky-Golay over {} samples; torque from {}\n\
         A = {:.6e} N/(m rad), B = {:.6e} m^2, C = {:.6e} N m s^3/rad^3, D = {:.6e} N m s/rad \
         (r = {} m, p0 = {:.1} kPa)\n\
         fit against the force-derived torque: {:.3} % (static part A, B only: {:.3} %), \
         MAE {:.4} N m, RMSE {:.4} N m, max {:.4} N m\n{symmetric_note}wrote {}\n",
        q.n,
        2 * hw + 1,
        match source {
            TorqueSource::MeasuredTensions => "the recorded tensions",
            TorqueSource::PlantForceModel => "the plant's force model",
        },
        model.a_n_per_m_rad,
        model.b_m2,
        model.c_nms3_per_rad3,
        model.d_nms_per_rad,
        model.sprocket_radius_m,
        model.p0_gauge_pa / 1e3,
        q.fit_pct,
        q.static_fit_pct,
        q.mae_nm,
        q.rmse_nm,
        q.max_abs_nm,
        a.out.display()
    ))
}

fn identify_plant(a: &IdentifyPlantArgs) -> Result<String> {
    if !(a.rtol > 0.0) {
        bail!("--rtol must be > 0");
    }
    let opts = PlantFitOptions {
        holdout_fraction: a.holdout_fraction,
        solver: SolverOptions {
            rtol: a.rtol,
            atol: a.rtol,
            ..SolverOptions::default()
        },
        patience: a.patience,
        ..PlantFitOptions::default()
    };
    let t0 = std::time::Instant::now();
    let fit = identify_plant_files(&a.recording, &a.plant, &a.params, &a.out, &opts)?;
    Ok(format!(
        "{}wrote {} ({:.2} s)\n",
        fit.summary(),
        a.out.display(),
        t0.elapsed().as_secs_f64()
    ))
}
