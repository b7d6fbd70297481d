//! The `host-sim sweep force|torque` and `host-sim identify force|torque|plant` commands: thin
//! wrappers over [`super::force`], [`super::torque`] and [`super::plant`]. Every output file
//! is written atomically; bad input gives an error naming the file, the line and the field.

// `!(a && b)` spelt out as the rule reads; `!(x > 0.0)` also rejects NaN.
#![allow(clippy::nonminimal_bool)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};

use super::force::{self, ForceSweep, Tondu};
use super::force_maps;
use super::plant::{identify_plant_text, PlantFitOptions};
use super::torque::{self, TorqueSource, TorqueSweep};
use super::{write_atomic, MeasurementNoise};
use crate::sim::SolverOptions;
use crate::validate::{self, RunEstimate};
use crate::{Plant, PlantConfig, Recording};

/// `host-sim sweep ...`: synthetic identification data from a plant file.
#[derive(Debug)]
pub struct SweepArgs {
    pub what: SweepWhat,
}

#[derive(Debug)]
pub enum SweepWhat {
    /// Isometric force data (writes columns p_kpa, stretch, f_n[, state]) from the plant's
    /// Tondu surface: at each L/L0 the pressure is swept from the maximum to 0 (and back up
    /// with --hysteresis-gap-n), as on the force-law paper's test bench.
    Force(SweepForceArgs),
    /// A measured-style isometric force map (columns p_kpa, stretch, f_n[, state]) from an
    /// independent thick-walled Chou-Hannaford muscle drawn from the seed: 5..9 lengths down to
    /// L/L0 ~ 0.74, 10..15 pressures up to 600..700 kPa, 60..130 points, exactly 0 N where the
    /// muscle is slack, noisy readings; --branches adds the falling branch with braid friction.
    ForceMap(SweepForceMapArgs),
    /// A torque-identification recording (writes RECORDING.md columns t_s, u_in1..u_ex2,
    /// angle_deg, p1_kpa, p2_kpa, f1_n, f2_n) as in the torque-model paper: the joint is driven
    /// quasi-statically and at constant speeds through +-amplitude at each activation dp
    /// (p1 = p0 - dp, p2 = p0 + dp held by regulators); channels from the plant's sensors.
    Torque(SweepTorqueArgs),
}

#[derive(Debug)]
pub struct SweepForceArgs {
    /// Plant file: the muscle's Tondu parameters (radius_m, braid_angle_deg, end_factor).
    pub plant: PathBuf,
    /// Output CSV.
    pub out: PathBuf,
    /// Number of L/L0 levels.
    pub n_stretch: usize,
    /// Number of pressure levels per sweep.
    pub n_pressure: usize,
    /// Lowest L/L0.
    pub stretch_min: f64,
    /// Highest L/L0.
    pub stretch_max: f64,
    /// Highest gauge pressure [kPa] (20..=2000: `identify force` needs a map reaching 20 kPa;
    /// less is a value in MPa or bar).
    pub p_max_kpa: f64,
    /// Load-cell noise, standard deviation [N].
    pub force_noise_n: f64,
    /// Pressure-sensor noise, standard deviation [kPa].
    pub pressure_noise_kpa: f64,
    /// Gap between the pressurising and depressurising branches at full pressure [N]; > 0
    /// sweeps both branches and writes a `state` column. At most a quarter of the sweep's
    /// largest force (the plant's muscle at --p-max-kpa; the message gives it).
    pub hysteresis_gap_n: f64,
    /// Random seed of the noise (0..=18446744073709551615).
    pub seed: u64,
    /// Run even when the estimated memory or time exceeds the limit (docs/reliability.md).
    pub allow_large: bool,
}

#[derive(Debug)]
pub struct SweepForceMapArgs {
    /// Output CSV.
    pub out: PathBuf,
    /// Seed: the muscle, the grid and the noise (0..=18446744073709551615).
    pub seed: u64,
    /// Sweep every length up and down (rising and falling branches, braid friction).
    pub branches: bool,
}

#[derive(Debug)]
pub struct SweepTorqueArgs {
    /// Plant file.
    pub plant: PathBuf,
    /// Output recording.
    pub out: PathBuf,
    /// Mid pressure p0, gauge [kPa].
    pub p0_kpa: f64,
    /// Activation levels dp [kPa], comma separated.
    pub dp_kpa: Vec<f64>,
    /// Angle amplitude of the motion [rad].
    pub amplitude_rad: f64,
    /// Constant speeds of the passes [rad/s], comma separated (the first quasi-static).
    pub speeds_rad_s: Vec<f64>,
    /// Sample period [s].
    pub dt_s: f64,
    /// Encoder counts per turn: 0 (no angle quantisation) or 360..=1073741824 (a coarser
    /// encoder reads the motion in steps of more than 1 degree).
    pub encoder_counts: u32,
    /// Pressure-sensor noise, standard deviation [kPa].
    pub pressure_noise_kpa: f64,
    /// Force-sensor noise, standard deviation [N].
    pub force_noise_n: f64,
    /// Random seed of the noise (0..=18446744073709551615).
    pub seed: u64,
    /// Run even when the estimated memory or time exceeds the limit (docs/reliability.md).
    pub allow_large: bool,
}

/// `host-sim identify ...`.
#[derive(Debug)]
pub struct IdentifyArgs {
    pub what: IdentifyWhat,
}

#[derive(Debug)]
pub enum IdentifyWhat {
    /// Fit the static force law (the ten-constant polynomial in pressure and L/L0 of the
    /// force-law paper, its eq. 6, constants c1..c10) and the Tondu baseline to isometric data
    /// (CSV columns p_kpa, stretch, f_n[, state|direction]); print both models' errors; write
    /// the firmware's force-law TOML.
    Force(IdentifyForceArgs),
    /// Fit A, B, C, D of the simplified joint torque model (the torque-model paper's eq. 11:
    /// stiffness from the activation, viscous and cubic damping) to a recording (columns t_s,
    /// angle_deg, p1_kpa, p2_kpa and f1_n, f2_n, else tensions from the plant's force model);
    /// write the torque-model TOML.
    Torque(IdentifyTorqueArgs),
    /// Output-error fit of plant-file parameters by replaying the recording's valve inputs
    /// (columns t_s, u_in1, u_ex1, u_in2, u_ex2 and the measured angle_deg, p1_kpa, p2_kpa,
    /// f1_n, f2_n that are present); write the plant file with the fitted values.
    Plant(IdentifyPlantArgs),
    /// Train the hybrid model's chamber volume (eq. 8-12 of the learned-inverse-thermodynamics paper: a network of two hidden
    /// layers V(e, e', P, P'), loss = mass-flow error + weight decay) on a recording with the
    /// mass-flow columns m_dot_1_kg_s, m_dot_2_kg_s; write the firmware's config/volume.toml.
    Volume(super::volume::IdentifyVolumeArgs),
}

#[derive(Debug)]
pub struct IdentifyForceArgs {
    /// Isometric data CSV.
    pub data: PathBuf,
    /// Output TOML (the format of config/force_law.toml).
    pub out: PathBuf,
    /// Upper end of the pressure domain written for the firmware [kPa] (20..=2000: less is a
    /// value in MPa or bar) [default: the largest pressure in the data, which sensor noise
    /// pushes above the sweep's nominal maximum].
    pub p_gauge_max_kpa: Option<f64>,
}

#[derive(Debug)]
pub struct IdentifyTorqueArgs {
    /// Recording (RECORDING.md).
    pub recording: PathBuf,
    /// Plant file: the sprocket radius r (and the force model when the recording has no tensions).
    pub plant: PathBuf,
    /// Output TOML (the format of config/torque_model.toml).
    pub out: PathBuf,
    /// Half window of the Savitzky-Golay velocity estimate [samples] [default: 25 ms worth].
    pub savgol_half_window: Option<usize>,
    /// Activation limit the controller may command [kPa], at most min(p0, supply - p0)
    /// [default: min(p0, supply - p0) - 20 kPa].
    pub dp_max_kpa: Option<f64>,
    /// Fit only the samples of (nearly) constant velocity, as the torque-model paper does: |acceleration|
    /// averaged over the velocity window at most this [rad/s^2] [default: all samples].
    pub max_accel_rad_s2: Option<f64>,
    /// Write the model even when its fit is below the trustworthy fit that `calibrate`
    /// requires (docs/identification.md).
    pub allow_poor_fit: bool,
}

#[derive(Debug)]
pub struct IdentifyPlantArgs {
    /// Recording whose valve inputs are replayed and whose channels are fitted.
    pub recording: PathBuf,
    /// Start plant file.
    pub plant: PathBuf,
    /// Dotted keys to fit, comma separated, each optionally with bounds `key=lo:hi`
    /// (e.g. valve.sonic_conductance_m3_per_s_pa,muscle.damping_m2s,joint.inertia_kgm2).
    pub params: Vec<String>,
    /// Output plant file (the input with the fitted values replaced).
    pub out: PathBuf,
    /// Fraction of the recording (its tail) held out for validation.
    pub holdout_fraction: f64,
    /// Relative (and absolute) tolerance of the replays.
    pub rtol: f64,
    /// Levenberg-Marquardt patience: at most this many model evaluations per fitted
    /// parameter (plus one).
    pub patience: usize,
    /// Write the plant file even when its mean held-out fit is below the one `calibrate`
    /// requires of an identified plant (docs/identification.md).
    pub allow_poor_fit: bool,
}

/// Runs `host-sim sweep ...`; returns the report for stdout.
pub fn run_sweep(a: &SweepArgs) -> Result<String> {
    match &a.what {
        SweepWhat::Force(a) => sweep_force(a),
        SweepWhat::ForceMap(a) => sweep_force_map(a),
        SweepWhat::Torque(a) => sweep_torque(a),
    }
}

/// Runs `host-sim identify ...`; returns the report for stdout.
pub fn run_identify(a: &IdentifyArgs) -> Result<String> {
    match &a.what {
        IdentifyWhat::Force(a) => identify_force(a),
        IdentifyWhat::Torque(a) => identify_torque(a),
        IdentifyWhat::Plant(a) => identify_plant(a),
        IdentifyWhat::Volume(a) => super::volume::run_identify_volume(a),
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
    validate::distinct_file_outputs(&[("--plant", &a.plant)], &[("--out", &a.out)])
        .map_err(anyhow::Error::msg)?;
    validate::replaceable("--out", &a.out, validate::OutputKind::FORCE_SWEEP)
        .map_err(anyhow::Error::msg)?;
    let points =
        a.n_stretch as f64 * a.n_pressure as f64 * if a.hysteresis_gap_n > 0.0 { 2.0 } else { 1.0 };
    RunEstimate {
        what: "sweep force".into(),
        samples: points,
        // The samples (32 B) and their CSV line (~40 B) at once.
        bytes: points * 80.0,
        seconds: points * 1e-6,
    }
    .check(a.allow_large)
    .map_err(anyhow::Error::msg)?;
    let cfg = PlantConfig::load(&a.plant)?;
    if !(a.stretch_min > 0.0 && a.stretch_min < a.stretch_max) {
        bail!(
            "--stretch-min {} must be > 0 and below --stretch-max {} (L/L0 from --stretch-min \
             up to --stretch-max)",
            validate::Shown(a.stretch_min),
            validate::Shown(a.stretch_max)
        );
    }
    if !(a.p_max_kpa > 0.0) || a.n_stretch < 2 || a.n_pressure < 2 {
        bail!("--p-max-kpa must be > 0; --n-stretch and --n-pressure at least 2");
    }
    if !(a.force_noise_n >= 0.0 && a.pressure_noise_kpa >= 0.0 && a.hysteresis_gap_n >= 0.0) {
        bail!("noise levels and the hysteresis gap must be >= 0");
    }
    let truth = tondu_of(&cfg);
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
    // Braid friction is a share of the force: a gap beyond it makes forces the muscle
    // cannot give (10 kN on a 2 kN muscle).
    let (f_max_n, at_stretch) = force::largest_force(&truth, &opt);
    let gap_max_n = force::HYSTERESIS_GAP_MAX_SHARE * f_max_n;
    if a.hysteresis_gap_n > gap_max_n {
        bail!(
            "--hysteresis-gap-n {} N: must be within 0..={:.1} N here, {} of the sweep's largest \
             force ({:.1} N, at {} kPa and L/L0 {:.4}; {})",
            validate::Shown(a.hysteresis_gap_n),
            gap_max_n,
            force::HYSTERESIS_GAP_MAX_SHARE_TEXT,
            f_max_n,
            validate::Shown(a.p_max_kpa),
            at_stretch,
            a.plant.display()
        );
    }
    let data = force::sweep(&truth, &opt);
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

fn sweep_force_map(a: &SweepForceMapArgs) -> Result<String> {
    validate::distinct_file_outputs(&[], &[("--out", &a.out)]).map_err(anyhow::Error::msg)?;
    validate::replaceable("--out", &a.out, validate::OutputKind::FORCE_SWEEP)
        .map_err(anyhow::Error::msg)?;
    let map = force_maps::force_map(&force_maps::MapOptions {
        seed: a.seed,
        branches: a.branches,
    });
    let m = &map.muscle;
    let mut meta = BTreeMap::new();
    meta.insert(
        "source".to_string(),
        format!(
            "host-sim {} sweep force-map --seed {}{} (thick-walled Chou-Hannaford muscle, slack threshold)",
            env!("CARGO_PKG_VERSION"),
            a.seed,
            if a.branches { " --branches" } else { "" }
        ),
    );
    meta.insert(
        "truth".to_string(),
        format!(
            "r0 {:.4} mm, alpha0 {:.3} deg, k {:.4}, wall {:.4} mm, p_th {:.1} kPa + {:.1} kPa (1 - L/L0)^2, swell {:.3e} /Pa, friction {:.4}",
            m.r0_m * 1e3,
            m.alpha0_rad.to_degrees(),
            m.end_factor,
            m.wall_m * 1e3,
            m.p_threshold_rest_pa / 1e3,
            m.p_threshold_growth_pa / 1e3,
            m.swell_per_pa,
            m.friction
        ),
    );
    meta.insert(
        "noise".to_string(),
        format!(
            "force sd {:.3} N (0.5 N steps), pressure sd {:.3} kPa",
            map.force_noise_n,
            map.pressure_noise_pa / 1e3
        ),
    );
    force::write_force_csv(&a.out, &map.samples, &meta)?;
    let slack = map.samples.iter().filter(|s| s.force_n == 0.0).count();
    Ok(format!(
        "{}: {} samples ({} lengths L/L0 {:.3}..{:.3} x {} pressures 0..{:.0} kPa{}), {} slack (0 N)\n",
        a.out.display(),
        map.samples.len(),
        map.stretches.len(),
        map.stretches[0],
        map.stretches[map.stretches.len() - 1],
        map.pressures_pa.len(),
        map.pressures_pa[map.pressures_pa.len() - 1] / 1e3,
        if a.branches { ", both branches" } else { "" },
        slack
    ))
}

/// Lowest mid pressure of a torque sweep [kPa gauge]: below it both muscles are near slack
/// (and a value typed in MPa or bar lands here).
const P0_MIN_KPA: f64 = 20.0;

fn sweep_torque(a: &SweepTorqueArgs) -> Result<String> {
    validate::distinct_file_outputs(&[("--plant", &a.plant)], &[("--out", &a.out)])
        .map_err(anyhow::Error::msg)?;
    validate::replaceable("--out", &a.out, validate::OutputKind::RECORDING)
        .map_err(anyhow::Error::msg)?;
    // Each pass -a -> +a -> -a at speed w lasts 4 a / w.
    let samples = a.dp_kpa.len() as f64
        * a.speeds_rad_s
            .iter()
            .map(|w| (4.0 * a.amplitude_rad / w / a.dt_s).max(2.0))
            .sum::<f64>();
    RunEstimate {
        what: "sweep torque".into(),
        samples,
        // Kinematics (40 B), recording (80 B), measurements (40 B), CSV text (~100 B).
        bytes: samples * 260.0,
        seconds: samples * 2e-6,
    }
    .check(a.allow_large)
    .map_err(anyhow::Error::msg)?;
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
    // The passes sweep +-amplitude: both muscles must stay between their rest length and
    // the contraction where the braid gives no force.
    let joint = &plant.joint;
    let chi_max = plant.muscle.law.max_contraction();
    let chi0 = joint.initial_contraction;
    let reach_rad = (chi_max - chi0).min(chi0) / joint.contraction_per_rad;
    if !(a.amplitude_rad < reach_rad) {
        bail!(
            "--amplitude-rad {}: beyond the joint's reach on {} (+-{:.3} rad: from contraction \
             {chi0} at 0 rad, {} rad per rad, a muscle reaches its maximum contraction {chi_max:.4} \
             (no force left) or its rest length there)",
            a.amplitude_rad,
            a.plant.display(),
            reach_rad,
            joint.contraction_per_rad
        );
    }
    let supply_kpa = (plant.p_supply_abs_pa - plant.p_atm_pa) / 1e3;
    // The mid pressure first: a slip of its unit would otherwise be blamed on every level.
    if a.p0_kpa < P0_MIN_KPA {
        bail!(
            "--p0-kpa {}: below {P0_MIN_KPA} kPa the muscles are slack around the mid pressure \
             (a value in bar or MPa? {} bar = {} kPa, {} MPa = {} kPa)",
            a.p0_kpa,
            a.p0_kpa,
            a.p0_kpa * 1e2,
            a.p0_kpa,
            a.p0_kpa * 1e3
        );
    }
    if a.p0_kpa >= supply_kpa {
        bail!(
            "--p0-kpa {}: at or above the plant's supply ({supply_kpa} kPa gauge, {})",
            a.p0_kpa,
            a.plant.display()
        );
    }
    for dp in &a.dp_kpa {
        let (p1, p2) = (a.p0_kpa - dp, a.p0_kpa + dp);
        if p1 < 0.0 || p2 < 0.0 || p1 > supply_kpa || p2 > supply_kpa {
            bail!(
                "--dp-kpa {dp} with --p0-kpa {}: p0 -+ dp = {p1}, {p2} kPa leave 0..{supply_kpa} kPa \
                 (the supply)",
                a.p0_kpa
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
    validate::distinct_file_outputs(&[("--data", &a.data)], &[("--out", &a.out)])
        .map_err(anyhow::Error::msg)?;
    validate::replaceable("--out", &a.out, validate::OutputKind::FORCE_LAW)
        .map_err(anyhow::Error::msg)?;
    let data = force::read_force_csv(&a.data)?;
    // The fit refuses maps it cannot determine (too few samples, no positive force, one
    // length, one pressure level, a pressure unit off): the error names the file.
    let mut id = force::identify(&data)
        .with_context(|| format!("{}: cannot fit the force law", a.data.display()))?;
    if let Some(p) = a.p_gauge_max_kpa {
        if !(p > 0.0 && p.is_finite()) {
            bail!("--p-gauge-max-kpa must be > 0");
        }
        // The firmware clamps the pressure to the domain: a domain far below the data's
        // pressures flattens every force above it.
        let data_kpa = id.domain.0 / 1e3;
        if p < 0.5 * data_kpa {
            bail!(
                "--p-gauge-max-kpa {p}: below half the data's highest pressure ({data_kpa:.0} kPa \
                 in {}); the firmware clamps pressures to it, so every force above {p} kPa would \
                 be the force at {p} kPa (a value in MPa or bar? leave the option out to use the \
                 data's range)",
                a.data.display()
            );
        }
        id.domain.0 = p * 1e3;
    }
    id.check_regular().with_context(|| {
        format!(
            "{}: the force law fitted to it cannot be written{}",
            a.data.display(),
            if a.p_gauge_max_kpa.is_some() {
                " with this --p-gauge-max-kpa"
            } else {
                ""
            }
        )
    })?;
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
    use super::MIN_TORQUE_FIT_PCT;
    let t = torque_model_file(a)?;
    if !a.allow_poor_fit && !(t.fit_pct >= MIN_TORQUE_FIT_PCT) {
        bail!(
            "{}: the torque model fits the force-derived torque {:.2} %, below the {MIN_TORQUE_FIT_PCT} % \
             `calibrate` requires; nothing written. {}Likely causes: an activation that is not \
             symmetric (p1 + p2 != 2 p0), pressures in another unit than kPa, tensions that do not \
             belong to this plant's sprocket, too little motion or too much sensor noise. Record a \
             `sweep torque`-like run (the joint driven through its range at a few activations); \
             --allow-poor-fit writes the model anyway",
            a.recording.display(),
            t.fit_pct,
            t.warnings.replace("warning: ", "")
        );
    }
    write_atomic(&a.out, t.toml.as_bytes())?;
    Ok(t.report)
}

/// The torque model identified from a recording, not yet written.
pub struct TorqueModelFile {
    /// Content of the constants file (provenance header + `[torque_model]`).
    pub toml: String,
    /// The report `host-sim identify torque` prints.
    pub report: String,
    /// Fit against the force-derived torque [%].
    pub fit_pct: f64,
    /// Warnings about the data (empty or lines ending in a newline), also in the report.
    pub warnings: String,
}

/// `host-sim identify torque` without the write: the file content, the report, the fit.
/// Steps: the files and pressure columns checked, the samples (velocity filtered), their
/// excitation checked, the fit, its signs checked against the plant's muscles, the
/// activation limit, the file and the report.
pub fn torque_model_file(a: &IdentifyTorqueArgs) -> Result<TorqueModelFile> {
    validate::distinct_file_outputs(
        &[("--recording", &a.recording), ("--plant", &a.plant)],
        &[("--out", &a.out)],
    )
    .map_err(anyhow::Error::msg)?;
    validate::replaceable("--out", &a.out, validate::OutputKind::TORQUE_MODEL)
        .map_err(anyhow::Error::msg)?;
    let plant = Plant::load(&a.plant)?;
    let raw = Recording::read(&a.recording)?;
    let file = a.recording.display().to_string();
    check_pressure_range(&raw, &a.recording)?;
    // Jittered time stamps go on the uniform grid the velocity filter needs.
    let rec = raw.to_uniform();
    let dt = rec.sample_period_s();
    let hw = a
        .savgol_half_window
        .unwrap_or_else(|| crate::signal::half_window_samples(0.025, dt));
    if a.savgol_half_window.is_some() {
        crate::signal::window_fits("--savgol-half-window", hw, rec.len(), dt, &file)?;
    }
    let (mut samples, source) =
        torque::samples_from_recording(&rec, &plant, hw, &file, header_line_of(&a.recording))?;
    let n_all = samples.len();
    check_torque_excitation(&samples, &file)?;
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
    check_torque_signs(&model, &plant, source, &file, &a.plant)?;
    let symmetric_note = symmetric_activation_note(&samples, &model);
    let supply_gauge_pa = plant.p_supply_abs_pa - plant.p_atm_pa;
    let dp_max_pa = dp_max_pa(a.dp_max_kpa, model.p0_gauge_pa, supply_gauge_pa)?;
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
    let report = format!(
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
    );
    Ok(TorqueModelFile {
        toml,
        report,
        fit_pct: q.fit_pct,
        warnings: symmetric_note,
    })
}

/// A pressure beyond what a muscle bears is a unit mistake (Pa or MPa written for kPa):
/// refused at its line.
fn check_pressure_range(raw: &Recording, path: &Path) -> Result<()> {
    let file = path.display().to_string();
    for (c, name) in [
        (crate::io::recording::Channel::P1Kpa, "p1_kpa"),
        (crate::io::recording::Channel::P2Kpa, "p2_kpa"),
    ] {
        let Some(p) = raw.channel(c) else { continue };
        if let Some(k) = p
            .iter()
            .position(|v| !(force::P_KPA_MIN..=force::P_KPA_MAX).contains(v))
        {
            bail!(
                "{file}:{}: column `{name}`: {} is outside {}..{} kPa gauge (a value in Pa? the \
                 column is in kPa); nothing written",
                header_line_of(path) + 1 + k,
                p[k],
                force::P_KPA_MIN,
                force::P_KPA_MAX
            );
        }
    }
    Ok(())
}

/// A recording without motion or without activation cannot determine the model (the fit
/// would write zeros and call them a perfect fit). The same floors as `calibrate`'s (the
/// firmware's constants come from either): a joint that moved less than half a degree (sd),
/// or an activation dp = (p2 - p1) / 2 that did not vary, cannot determine A, or B: the
/// least-squares fit would write what the noise gives (a sweep at dp = 0 fitted B 640 times
/// too small at 97 %). The torque must vary too.
fn check_torque_excitation(samples: &[torque::TorqueSample], file: &str) -> Result<()> {
    let spread = |f: &dyn Fn(&torque::TorqueSample) -> f64| {
        let lo = samples.iter().map(f).fold(f64::INFINITY, f64::min);
        let hi = samples.iter().map(f).fold(f64::NEG_INFINITY, f64::max);
        hi - lo
    };
    if !(spread(&|s| s.angle_rad) > 1e-3) {
        bail!(
            "{file}: column `angle_deg`: the joint does not move (angle range below 0.06 degrees); \
             the torque model needs a recording through a range of angles"
        );
    }
    let sd_of = |f: &dyn Fn(&torque::TorqueSample) -> f64| {
        let n = samples.len() as f64;
        let m = samples.iter().map(f).sum::<f64>() / n;
        (samples.iter().map(|s| (f(s) - m).powi(2)).sum::<f64>() / n).sqrt()
    };
    let angle_sd_deg = sd_of(&|s| s.angle_rad).to_degrees();
    if !(angle_sd_deg >= super::MIN_ANGLE_SD_DEG) {
        bail!(
            "{file}: column `angle_deg`: the joint hardly moves (sd {angle_sd_deg:.3} deg < {} deg; \
             an angle logged in radians? the column is in degrees); the torque model needs a \
             recording through a range of angles; nothing written",
            super::MIN_ANGLE_SD_DEG
        );
    }
    let dp_sd_kpa = sd_of(&|s| 0.5 * (s.p2_gauge_pa - s.p1_gauge_pa)) / 1e3;
    if !(dp_sd_kpa >= super::MIN_PRESSURE_SD_KPA) {
        let p_max_kpa = samples
            .iter()
            .map(|s| s.p1_gauge_pa.abs().max(s.p2_gauge_pa.abs()))
            .fold(0.0, f64::max)
            / 1e3;
        let unit = if p_max_kpa < 10.0 {
            format!(" (pressures up to {p_max_kpa:.3} kPa: logged in bar or MPa? the columns are in kPa)")
        } else {
            String::new()
        };
        bail!(
            "{file}: the activation dp = (p2_kpa - p1_kpa) / 2 does not vary (sd {dp_sd_kpa:.3} kPa \
             < {} kPa){unit}: B of eq. 11 needs a recording at several activations (`host-sim \
             sweep torque --dp-kpa` takes several levels); nothing written",
            super::MIN_PRESSURE_SD_KPA
        );
    }
    if !(spread(&|s| s.torque_nm) > 1e-6) {
        bail!(
            "{file}: the torque (f1_n - f2_n) r is constant; the torque model needs a recording \
             with varying torque"
        );
    }
    Ok(())
}

/// dT/dalpha of the plant's pair at equal gauge pressures `p_gauge_pa` [N m/rad] (negative:
/// a contracting muscle loses tension).
fn plant_stiffness_nm_per_rad(plant: &Plant, p_gauge_pa: f64) -> f64 {
    let delta_rad = 0.05;
    let t = |angle_rad: f64| {
        let [c1, c2] = plant.joint.contractions(angle_rad);
        plant.joint.sprocket_radius_m
            * (plant.muscle.static_force_n(p_gauge_pa, c1)
                - plant.muscle.static_force_n(p_gauge_pa, c2))
    };
    (t(delta_rad) - t(-delta_rad)) / (2.0 * delta_rad)
}

/// The fitted model's signs are physics, not data: refused when B r or A r^2 has the sign
/// opposite to the plant's muscles', or when measured tensions give the stiffness of the
/// plant's muscles an atmosphere below the data's p0 (pressures logged absolute).
fn check_torque_signs(
    model: &torque::TorqueModelFit,
    plant: &Plant,
    source: TorqueSource,
    file: &str,
    plant_path: &Path,
) -> Result<()> {
    // The sign of B r: dp raises p2 and lowers p1, so the plant's own muscles at angle 0 say
    // which way the torque goes. The opposite sign fits as well on data whose p1 and p2 (or
    // valves, or tension columns) are the other muscle's, and would make the firmware drive
    // the joint the wrong way.
    let chi0 = plant.joint.initial_contraction;
    let delta_pa = 10e3;
    let f = |p: f64| plant.muscle.static_force_n(p, chi0);
    let plant_gain = plant.joint.sprocket_radius_m
        * (f(model.p0_gauge_pa - delta_pa) - f(model.p0_gauge_pa + delta_pa))
        / (2.0 * delta_pa);
    let fitted_gain = model.b_m2 * model.sprocket_radius_m;
    if fitted_gain * plant_gain < 0.0 {
        bail!(
            "{file}: the fitted B r = {fitted_gain:.4e} m^3 has the opposite sign of the plant's \
             muscles ({plant_gain:.4e} m^3 at angle 0 and p0 = {:.1} kPa of {}): the recording's \
             muscle 1 and 2 are swapped (p1_kpa / p2_kpa, the valve columns, or f1_n / f2_n); \
             nothing written",
            model.p0_gauge_pa / 1e3,
            plant_path.display()
        );
    }
    // The sign of A: at equal pressures a muscle that contracts loses tension, so the pair
    // pulls the joint back (dT/dalpha < 0 for the plant's muscles). The opposite sign fits as
    // well on data whose angle is logged the other way round (the encoder's direction) or
    // whose muscles are swapped in every column (pressures, tensions and valves together: B
    // keeps its sign then); the firmware's inverse model would push the joint away from
    // where it is.
    let plant_stiffness = plant_stiffness_nm_per_rad(plant, model.p0_gauge_pa);
    let r = model.sprocket_radius_m;
    let fitted_stiffness = model.a_n_per_m_rad * r * r;
    if fitted_stiffness * plant_stiffness < 0.0 {
        bail!(
            "{file}: the fitted stiffness A r^2 = {fitted_stiffness:.4e} N m/rad has the opposite \
             sign of the plant's muscles ({plant_stiffness:.4e} N m/rad at p0 = {:.1} kPa of {}: \
             a contracting muscle loses tension, so the pair pulls the joint back): the angle \
             is logged the other way round (the encoder's direction: negate angle_deg), or \
             muscle 1 and 2 are swapped in every column (p1_kpa with p2_kpa, f1_n with f2_n, \
             and the valves); the firmware would push the joint away; nothing written",
            model.p0_gauge_pa / 1e3,
            plant_path.display()
        );
    }
    // Pressures logged absolute, with the tensions measured: the tensions are those of the
    // true gauge pressures, so the fitted stiffness is the plant's muscles' one an atmosphere
    // below the data's p0, not at it.
    if source == TorqueSource::MeasuredTensions {
        let at_p0 = fitted_stiffness / plant_stiffness;
        let below = fitted_stiffness
            / plant_stiffness_nm_per_rad(plant, model.p0_gauge_pa - plant.p_atm_pa);
        if (below - 1.0).abs() < 0.05 && (at_p0 - 1.0).abs() > 0.15 {
            bail!(
                "{file}: the pressures look absolute, not gauge: the tensions f1_n, f2_n give the \
                 stiffness A r^2 = {fitted_stiffness:.4e} N m/rad, {:.0} % of the plant's muscles \
                 at the data's p0 = {:.1} kPa but {:.0} % at {:.1} kPa, one atmosphere ({:.3} \
                 kPa) lower; RECORDING.md's columns are gauge: subtract the atmosphere from \
                 p1_kpa and p2_kpa (or import with reference = \"absolute\"); nothing written",
                100.0 * at_p0,
                model.p0_gauge_pa / 1e3,
                100.0 * below,
                (model.p0_gauge_pa - plant.p_atm_pa) / 1e3,
                plant.p_atm_pa / 1e3
            );
        }
    }
    Ok(())
}

/// Eq. 11 assumes the symmetric activation p1 + p2 = 2 p0: a warning (ending in a newline)
/// when (p1 + p2) / 2 spreads by more than 5 % of p0 (at least 50 Pa) around it; empty
/// otherwise.
fn symmetric_activation_note(
    samples: &[torque::TorqueSample],
    model: &torque::TorqueModelFit,
) -> String {
    let p0_sd_pa = (samples
        .iter()
        .map(|s| (0.5 * (s.p1_gauge_pa + s.p2_gauge_pa) - model.p0_gauge_pa).powi(2))
        .sum::<f64>()
        / samples.len() as f64)
        .sqrt();
    if p0_sd_pa > 0.05 * model.p0_gauge_pa.abs().max(1e3) {
        format!(
            "warning: (p1 + p2) / 2 spreads by {:.1} kPa (sd) around p0 = {:.1} kPa; eq. 11 assumes the \
             symmetric activation p1 = p0 - dp, p2 = p0 + dp (seed 003), so its fit is poor on such data\n",
            p0_sd_pa / 1e3,
            model.p0_gauge_pa / 1e3
        )
    } else {
        String::new()
    }
}

/// The activation limit written with the model [Pa]: `--dp-max-kpa` (`given_kpa`), within
/// (0, limit] where p1 = p0 - dp and p2 = p0 + dp stay between atmosphere and the supply (and
/// not under [`DP_MAX_KPA_MIN`] when the limit allows it: a value in MPa or bar); by default
/// 20 kPa of headroom to atmosphere and to the supply, to whole kPa.
fn dp_max_pa(given_kpa: Option<f64>, p0_gauge_pa: f64, supply_gauge_pa: f64) -> Result<f64> {
    Ok(match given_kpa {
        Some(v) => {
            let limit_kpa = p0_gauge_pa.min(supply_gauge_pa - p0_gauge_pa) / 1e3;
            if v < DP_MAX_KPA_MIN && v <= limit_kpa {
                bail!(
                    "--dp-max-kpa {v}: below {DP_MAX_KPA_MIN} kPa the controller can hardly \
                     activate the joint (within (0, {limit_kpa:.1}] kPa here): a value in MPa or \
                     bar? 0.2 MPa = 2 bar = 200 kPa"
                );
            }
            if !(v > 0.0 && v <= limit_kpa) {
                bail!(
                    "--dp-max-kpa {v}: must be within (0, {limit_kpa:.1}] kPa: p0 -+ dp must stay \
                     between atmosphere and the supply ({:.1} kPa gauge, p0 = {:.1} kPa)",
                    supply_gauge_pa / 1e3,
                    p0_gauge_pa / 1e3
                );
            }
            v * 1e3
        }
        None => {
            let v = ((p0_gauge_pa.min(supply_gauge_pa - p0_gauge_pa) - 20e3) / 1e3).round() * 1e3;
            if !(v > 0.0) {
                bail!(
                    "p0 = {:.1} kPa of the data leaves no activation range below the supply; give --dp-max-kpa",
                    p0_gauge_pa / 1e3
                );
            }
            v
        }
    })
}

/// Smallest activation limit `identify torque --dp-max-kpa` takes [kPa].
const DP_MAX_KPA_MIN: f64 = 5.0;

fn identify_plant(a: &IdentifyPlantArgs) -> Result<String> {
    validate::distinct_file_outputs(
        &[("--recording", &a.recording), ("--plant", &a.plant)],
        &[("--out", &a.out)],
    )
    .map_err(anyhow::Error::msg)?;
    validate::replaceable("--out", &a.out, validate::OutputKind::PLANT)
        .map_err(anyhow::Error::msg)?;
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
    let (fit, body) = identify_plant_text(&a.recording, &a.plant, &a.params, &opts)?;
    // The gate `calibrate --identify-plant` applies, on the held-out tail (on the training
    // part when nothing is held out).
    let (set, (before, after)) = if fit.holdout.is_empty() {
        ("training", super::plant::mean_scores(&fit.train))
    } else {
        ("held-out", fit.holdout_mean_pct())
    };
    let min = super::MIN_IDENTIFIED_HELDOUT_FIT_PCT;
    if !a.allow_poor_fit && !(after >= min) && after < before {
        // Worse than where it started: the search left the start's basin, the recording is
        // not to blame.
        bail!(
            "{}: the fit ended below its start ({before:.1} % -> {after:.1} % on the {set} part, \
             mean over channels; {min} % needed); nothing written. The search left the start \
             values' basin: give tighter bounds (--params key=lo:hi) around a start value \
             closer to the rig's; --allow-poor-fit writes the plant file anyway",
            a.recording.display()
        );
    }
    if !a.allow_poor_fit && !(after >= min) {
        bail!(
            "{}: the identified plant fits the recording's channels {after:.1} % on the {set} \
             part (mean over channels; {before:.1} % with the start values), below the {min} % \
             `calibrate` requires; nothing written. The recording does not excite these keys, it \
             is not driven by the valve inputs it records, or another part of the plant file is \
             wrong; --allow-poor-fit writes the plant file anyway",
            a.recording.display()
        );
    }
    write_atomic(&a.out, body.as_bytes())?;
    Ok(format!(
        "{}wrote {} ({:.2} s)\n",
        fit.summary(),
        a.out.display(),
        t0.elapsed().as_secs_f64()
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_activation_limit_leaves_20_kpa_to_atmosphere_and_supply() {
        // p0 300 kPa, supply 500 kPa gauge: 200 kPa to the supply, 180 kPa with headroom.
        assert_eq!(dp_max_pa(None, 300e3, 500e3).unwrap(), 180e3);
        // Rounded to whole kPa.
        assert_eq!(dp_max_pa(None, 100.4e3, 500e3).unwrap(), 80e3);
        assert!(dp_max_pa(None, 15e3, 500e3).is_err());
    }

    #[test]
    fn a_given_activation_limit_is_refused_beyond_the_range_or_when_it_looks_like_mpa() {
        assert_eq!(dp_max_pa(Some(150.0), 300e3, 500e3).unwrap(), 150e3);
        let too_far = dp_max_pa(Some(250.0), 300e3, 500e3).unwrap_err();
        assert!(too_far.to_string().contains("(0, 200.0]"), "{too_far}");
        let mpa = dp_max_pa(Some(0.2), 300e3, 500e3).unwrap_err();
        assert!(mpa.to_string().contains("MPa"), "{mpa}");
    }
}
