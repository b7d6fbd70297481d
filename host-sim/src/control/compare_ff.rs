//! `host-sim compare-control`: the pressure loop with and without the firmware's inverse
//! thermodynamic feed-forward (`pam_firmware::pressure_ff`, seed 004 eq. 7), firmware in the
//! loop, on three sets of set-points: the controller suite ([`super::compare::SUITE`], the
//! set-points the gains were tuned on), held-out moves
//! ([`super::robustness::HELD_OUT_SUITE`]: other seeds, amplitudes and frequencies, never
//! tuned on) and set-point jumps ([`super::compare::JUMP_SUITE`], never tuned on, where the
//! valves saturate); on the given plant and on the same plant with a thermodynamic chamber, a
//! leak, a supply drop and a different volume law.
//!
//! Rows: the tuned cascade (`config/control_tuned.toml`) with the P-only pressure loops, the
//! same cascade + the analytical inverse model (isothermal, k = 1, and polytropic, k = 1.4;
//! k = 1 also with `P'` and `V'` taken the other way: reference trajectory or set-point /
//! measurement, see `rate_from_reference` in `config/pressure_ff.toml`),
//! seed 004's hybrid model (eq. 12: the learned volume of [`pam_firmware::volume_fnn`]
//! in place of the polynomial, k = 1), and the cascade re-tuned with the feed-forward on
//! (`config/control_tuned_ff.toml`, `host-sim tune --pressure-ff`) with the analytical and the
//! hybrid model, plus the P-only loop at those re-tuned gains (diagnostic). The hybrid volume
//! is trained per plant, as the seed trains on its rig: `identify volume`'s trainer
//! ([`crate::identify::volume::train`], seed 1, default options) on a closed-loop run of the
//! P-only cascade on that plant with [`TRAINING_SCENARIO`] (random set-points, none of the
//! compared scenarios). Columns: position MSE [rad^2] (angle error over every tick; infinite
//! when a fault latched), its ratio to the P-only row, and the RMS pressure tracking error
//! [kPa] (set-point minus measured gauge pressure, both muscles, every armed tick). The
//! nominal plant also gets the MSE of every scenario.
//!
//! `--breakdown` adds, on the nominal plant, where each set's position error comes from
//! ([`breakdown`]: moving / at rest, slow pressure error and ripple, lag, deadband,
//! saturation) for P only, two diagnostic variants of its pressure loop and the k = 1 rows.
//!
//! Exit status 1 when, on the given (nominal) plant and the suite, the analytical feed-forward
//! does not improve the position MSE by at least [`REQUIRED_RATIO`] over the P-only cascade,
//! each at its own tuned gains (seed 004 tunes the PD of each design individually: 3.61 ->
//! 1.95 with its hybrid model, 1.85x). The ratio at the same gains is printed beside it.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context;
use pam_firmware::pressure_ff::PressureFfParams;
use pam_firmware::tick::ControllerConfig;

use super::closed_loop::{run_with, Scenario};
use super::compare::{
    at_scenario_rate, default_control_tuning, default_control_tuning_ff, jump_suite_scenarios,
    suite_scenarios, ControlTuning, SHIPPED_CONTROL_TUNED, SHIPPED_CONTROL_TUNED_FF,
};
use super::robustness::held_out_scenarios;
use crate::identify::volume::{
    samples_from_recording, split_samples, train, Thermo, TrainOptions, VolumePoly,
};
use crate::plant::config::PlantConfig;
use crate::plant::Plant;
use pam_firmware::volume_fnn::VolumeFnn;

/// The training run of the hybrid volume (not one of the compared scenarios).
pub const TRAINING_SCENARIO: (&str, &str) = (
    "scenarios/volume_training.toml",
    include_str!("../../../scenarios/volume_training.toml"),
);

/// The hybrid volume of `plant`: trained on the P-only cascade's closed-loop run of
/// [`TRAINING_SCENARIO`] (its true mass flows), seed 1, the firmware's geometry, polynomial
/// and eq. 7 constants. Returns the network (leaked: the tick keeps a `&'static`) and the
/// training recording's mass-flow MSE of the polynomial and of the hybrid [(kg/s)^2].
pub fn train_hybrid(
    plant: &Plant,
    base: ControllerConfig,
) -> anyhow::Result<(&'static VolumeFnn, f64, f64)> {
    let sc = Scenario::from_toml_str(TRAINING_SCENARIO.1, TRAINING_SCENARIO.0)?;
    let off = ControllerConfig {
        pressure_ff: PressureFfParams {
            enabled: false,
            ..base.pressure_ff
        },
        ..base
    };
    let run = run_with(plant, &sc, off, &mut |_| {})?;
    let rec = run.to_recording();
    let hw = ((0.010 / run.dt_s).round() as usize).max(1);
    let per = samples_from_recording(
        &rec,
        &base.geometry,
        pam_firmware::constants::P_ATM_PA as f64,
        hw,
    )
    .map_err(anyhow::Error::msg)?;
    let (samples, _) = split_samples(&per, 0.0, TrainOptions::default().max_evaluations * 2);
    let (poly, thermo) = (VolumePoly::firmware(), Thermo::firmware());
    let t = train(&samples, &poly, &thermo, &TrainOptions::default(), &|_| {})
        .map_err(anyhow::Error::msg)?;
    let mse_poly =
        crate::identify::volume::mse_kg2_s2(&samples, |s| poly.mass_flow_kg_s(s, &thermo));
    let mse_hybrid =
        crate::identify::volume::mse_kg2_s2(&samples, |s| t.net.mass_flow_kg_s(s, &thermo));
    let fw = t.net.to_firmware();
    anyhow::ensure!(
        fw.is_valid(),
        "the trained hybrid volume is not valid in f32"
    );
    Ok((Box::leak(Box::new(fw)), mse_poly, mse_hybrid))
}

/// Position-MSE improvement the analytical feed-forward must reach on the nominal plant.
pub const REQUIRED_RATIO: f64 = 1.85;

/// Arguments of `host-sim compare-control`.
#[derive(Debug)]
pub struct CompareControlArgs {
    /// Plant parameter file (TOML): the nominal plant; the effect variants are added to it.
    pub plant: PathBuf,
    /// Tuned gains of the P-only cascade [default: config/control_tuned.toml under the working
    /// directory if it is there, else the shipped gains built into host-sim]; the report's
    /// first line names the file used. The verdict compares the P-only cascade at these gains
    /// with the feed-forward cascade at --ff-gains (each design tuned for itself, as the
    /// learned-inverse-thermodynamics paper compares them); give both files, tuned on the same plant, or the verdict compares
    /// tunings of different origin. The same-gains ratio is printed beside it.
    pub gains: Option<PathBuf>,
    /// The cascade's gains tuned with the feed-forward on (`host-sim tune --pressure-ff`), for
    /// the rows where each controller runs at its own best gains [default:
    /// config/control_tuned_ff.toml under the working directory if it is there, else the shipped
    /// ones built into host-sim].
    pub ff_gains: Option<PathBuf>,
    pub ff: FfOverrides,
    /// Run the cascade's outer loops (position loop, trajectory feed-forward, torque
    /// estimate, torque loop) on one tick in N, the pressure loops every tick, in every row
    /// (1..=5 at the 1 kHz tick; 1 = every tick) [default: the rate --gains were tuned at
    /// (`host-sim tune --outer-period-ticks`), else config/controller.toml [rates]
    /// outer_period_ticks].
    pub outer_period_ticks: Option<u16>,
    /// Only the nominal plant and the suite's first scenario of each set (the CI run).
    pub quick: bool,
    /// Only the nominal plant, every scenario of both sets.
    pub nominal_only: bool,
    /// Also print, per scenario set on the nominal plant, where the P-only cascade's position
    /// error comes from (moves / rest, pressure lag, ripple, deadband, saturation) and the
    /// same cascade with the pressure loop's deadband removed or its gain x4 (diagnostics
    /// only: those change the cascade).
    pub breakdown: bool,
}

/// The `--ff-*` options of `host-sim compare-control`: values that replace those of
/// config/pressure_ff.toml.
#[derive(Debug)]
pub struct FfOverrides {
    /// Scale of the feed-forward duty (0..=2) [default: config/pressure_ff.toml gain].
    pub gain: Option<f32>,
    /// Cut-off of the set-point rate filter [Hz] (1..=500) [default: config/pressure_ff.toml].
    pub cutoff_hz: Option<f32>,
    /// Where the feed-forward takes its desired pressure rate P' and volume rate V' from:
    /// `reference` (the set-point trajectory through the inverse torque model) or
    /// `set-point` (the torque loop's pressure set-point and the measured velocity)
    /// [default: config/pressure_ff.toml rate_from_reference].
    pub rate_from: Option<String>,
    /// Where the feed-forward takes the volume rate V' from: `reference` (the set-point's
    /// rate) or `measured` (the velocity estimate) [default: config/pressure_ff.toml
    /// volume_rate_from_reference].
    pub volume_rate_from: Option<String>,
    /// Feed-forward duties of a smaller magnitude are dropped (0..=1) [default:
    /// config/pressure_ff.toml min_duty].
    pub min_duty: Option<f32>,
    /// Evaluate the feed-forward once every N ticks and hold it in between (1..=100 at the
    /// 1 kHz tick; 1 = every tick) [default: the period the --ff-gains were tuned at (`host-sim
    /// tune --ff-update-ticks`), else config/pressure_ff.toml update_period_ticks].
    pub update_ticks: Option<u16>,
}

impl FfOverrides {
    /// Replaces the given values in `ff`; a value outside its range is an error naming the
    /// option.
    pub fn apply(&self, ff: &mut PressureFfParams) -> anyhow::Result<()> {
        let checked = |option: &str, v: f32, range: std::ops::RangeInclusive<f32>| {
            anyhow::ensure!(
                range.contains(&v),
                "{option} {v}: outside the allowed range {}..={}",
                range.start(),
                range.end()
            );
            Ok(v)
        };
        if let Some(g) = self.gain {
            ff.gain = checked("--ff-gain", g, 0.0..=2.0)?;
        }
        if let Some(f) = self.cutoff_hz {
            ff.rate_cutoff_hz = checked("--ff-cutoff-hz", f, 1.0..=500.0)?;
        }
        if let Some(d) = self.min_duty {
            ff.min_duty = checked("--ff-min-duty", d, 0.0..=1.0)?;
        }
        // (In range: its parser, `compare::ff_update_ticks_arg`, refuses the rest.)
        if let Some(n) = self.update_ticks {
            ff.update_period_ticks = n;
        }
        if let Some(src) = &self.rate_from {
            ff.rate_from_reference = src == "reference";
        }
        if let Some(src) = &self.volume_rate_from {
            ff.volume_rate_from_reference = src == "reference";
        }
        Ok(())
    }
}

/// The effect variants of the plant: name and the TOML table added to the plant file.
pub const VARIANTS: [(&str, &str); 4] = [
    ("nominal", ""),
    (
        "thermal chamber (hA 2 W/K, kappa 1.4)",
        "[effects.thermal_chamber]\nheat_transfer_w_per_k = 2.0\nkappa = 1.4\n",
    ),
    (
        "leakage (C 4e-10 m^3/(s Pa))",
        "[effects.leakage]\nsonic_conductance_m3_per_s_pa = 4.0e-10\n",
    ),
    (
        "supply drop (static, 2e7 Pa s/m^3)",
        "[effects.supply_drop]\nmodel = \"static\"\nresistance_pa_s_per_m3 = 2.0e7\n",
    ),
];

/// The plant file at `path` with the effect of [`VARIANTS`] whose name starts with `variant`
/// added (e.g. `"thermal chamber"`).
pub fn variant_plant(path: &std::path::Path, variant: &str) -> anyhow::Result<Plant> {
    let (_, table) = VARIANTS
        .iter()
        .find(|(n, _)| n.starts_with(variant))
        .ok_or_else(|| anyhow::anyhow!("no plant variant {variant}"))?;
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("{}: cannot read", path.display()))?;
    let cfg = PlantConfig::from_toml_str(&format!("{text}\n{table}"), path)?;
    Ok(Plant::from_config(&cfg))
}

/// The variant whose chamber volume law differs from the firmware's polynomial (the
/// hybrid model's case): `b0` x 1.3 (dead volume of a longer tube to the valve), `b1..b3` x 0.7
/// (a flatter volume-contraction curve). On the reference plant: V +3 % at the working
/// contraction 0.14, dV/de -30 %.
pub const VOLUME_VARIANT: &str = "volume law differs (b0 x 1.3, b1..b3 x 0.7)";

/// The plant file `text` with its `[muscle] volume_poly_m3` changed as [`VOLUME_VARIANT`]
/// says (the other keys and comments kept).
pub fn with_volume_mismatch(text: &str) -> anyhow::Result<String> {
    let mut doc: toml_edit::DocumentMut = text.parse()?;
    let arr = doc["muscle"]["volume_poly_m3"]
        .as_array_mut()
        .ok_or_else(|| anyhow::anyhow!("[muscle] volume_poly_m3: not an array"))?;
    let b: Vec<f64> = arr
        .iter()
        .map(|v| v.as_float().or_else(|| v.as_integer().map(|i| i as f64)))
        .collect::<Option<_>>()
        .ok_or_else(|| anyhow::anyhow!("[muscle] volume_poly_m3: not numbers"))?;
    arr.clear();
    for (i, c) in b.iter().enumerate() {
        arr.push(c * if i == 0 { 1.3 } else { 0.7 });
    }
    Ok(doc.to_string())
}

/// One controller's figures on one scenario set.
#[derive(Debug, Clone, PartialEq)]
pub struct FfScore {
    /// Mean over the scenarios of the position MSE [rad^2] (infinite when a fault latched).
    pub position_mse_rad2: f64,
    /// RMS pressure tracking error over both muscles and all armed ticks [Pa].
    pub pressure_rms_pa: f64,
    /// The first latched fault of each scenario that latched one (scenario name, fault).
    pub faults: Vec<(String, String)>,
}

/// Runs `cfg` on `scenarios` and scores position and pressure tracking.
pub fn score(
    plant: &Plant,
    scenarios: &[Scenario],
    cfg: ControllerConfig,
) -> anyhow::Result<FfScore> {
    let mut mse_sum = 0.0;
    let (mut p_sq, mut p_n) = (0.0f64, 0usize);
    let mut faults = Vec::new();
    for s in scenarios {
        let run = run_with(plant, s, at_scenario_rate(cfg, s), &mut |_| {})?;
        let st = run.tracking(0.0);
        if let Some(f) = run
            .first_latched_fault_tick
            .and_then(|k| run.rows[k].out.fault)
        {
            faults.push((run.name.clone(), format!("{f:?}")));
        }
        mse_sum += if run.first_latched_fault_tick.is_some() || st.n == 0 {
            f64::INFINITY
        } else {
            st.mse_rad2
        };
        for r in run.rows.iter().filter(|r| r.out.armed) {
            let e1 = r.out.p1_set_gauge_pa as f64 - r.measured.p1_kpa * 1e3;
            let e2 = r.out.p2_set_gauge_pa as f64 - r.measured.p2_kpa * 1e3;
            p_sq += e1 * e1 + e2 * e2;
            p_n += 2;
        }
    }
    Ok(FfScore {
        position_mse_rad2: mse_sum / scenarios.len().max(1) as f64,
        pressure_rms_pa: if p_n == 0 {
            f64::INFINITY
        } else {
            (p_sq / p_n as f64).sqrt()
        },
        faults,
    })
}

/// The controllers compared: P-only, + analytical isothermal, + analytical polytropic, and
/// with `hybrid`, + the hybrid model (its learned volume, isothermal).
pub fn controllers(
    base: ControllerConfig,
    hybrid: Option<&'static VolumeFnn>,
    retuned: Option<ControllerConfig>,
) -> Vec<(&'static str, ControllerConfig)> {
    let with_rate = |k: f32, from_reference: bool| ControllerConfig {
        pressure_ff: PressureFfParams {
            enabled: true,
            polytropic_index: k,
            rate_from_reference: from_reference,
            volume_rate_from_reference: from_reference,
            ..base.pressure_ff
        },
        volume_fnn: None,
        ..base
    };
    let from_ref = base.pressure_ff.rate_from_reference;
    let with = |k: f32| ControllerConfig {
        pressure_ff: PressureFfParams {
            polytropic_index: k,
            enabled: true,
            ..base.pressure_ff
        },
        volume_fnn: None,
        ..base
    };
    let off = ControllerConfig {
        pressure_ff: PressureFfParams {
            enabled: false,
            ..base.pressure_ff
        },
        ..base
    };
    let mut v = vec![
        ("P only", off),
        ("+ analytical inverse model, k = 1 (isothermal)", with(1.0)),
        (
            "+ analytical inverse model, k = 1.4 (polytropic)",
            with(1.4),
        ),
        (
            if from_ref {
                "+ analytical, k = 1, P' and V' of the set-point / measurement"
            } else {
                "+ analytical, k = 1, P' and V' of the reference"
            },
            with_rate(1.0, !from_ref),
        ),
    ];
    if let Some(n) = hybrid {
        v.push((
            "+ hybrid model (learned volume), k = 1",
            ControllerConfig {
                volume_fnn: Some(n),
                ..with(1.0)
            },
        ));
    }
    if let Some(r) = retuned {
        let on = ControllerConfig {
            pressure_ff: PressureFfParams {
                enabled: true,
                polytropic_index: 1.0,
                ..base.pressure_ff
            },
            volume_fnn: None,
            ..r
        };
        v.push((RETUNED_ROW, on));
        if let Some(n) = hybrid {
            v.push((
                "+ hybrid model, k = 1, cascade re-tuned with it on",
                ControllerConfig {
                    volume_fnn: Some(n),
                    ..on
                },
            ));
        }
        v.push((
            "P only at the gains re-tuned with the feed-forward (diagnostic)",
            ControllerConfig {
                pressure_ff: PressureFfParams {
                    enabled: false,
                    ..on.pressure_ff
                },
                ..on
            },
        ));
    }
    v
}

/// The row of the analytical feed-forward with the cascade's gains tuned with it on: the
/// verdict's row (each controller at its own best gains, as the learned-inverse-thermodynamics paper compares them).
pub const RETUNED_ROW: &str = "+ analytical, k = 1, cascade re-tuned with it on";

/// Where the position error of one controller comes from on one scenario set (sums over the
/// scenarios' armed, unfaulted ticks).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Breakdown {
    /// Position MSE over all ticks [rad^2] and the share of its squared error on ticks whose
    /// set-point moved within the last [`MOVE_WINDOW_TICKS`] ticks.
    pub position_mse_rad2: f64,
    pub moving_share: f64,
    /// The pressure error while moving (index 0) and at rest (1), from the first set-point
    /// change on (as every pressure figure below).
    pub pressure: [PressureErrorRms; 2],
    /// Least-squares lag `tau` of the slow pressure error against the set-point's rate.
    pub lag: PressureLag,
    /// Shares of the muscle-ticks inside the deadband and with the valve saturated (|u| = 1).
    pub valves: ValveShares,
}

/// RMS of the pressure error (set-point minus measured) of one regime of [`Breakdown`].
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PressureErrorRms {
    /// Averaged over one PWM period (the part that moves the joint) [Pa].
    pub slow_pa: f64,
    /// The rest (the ripple) [Pa].
    pub ripple_pa: f64,
    /// The slow activation error `((e2 - e1) / 2)` as a joint torque through the torque
    /// model's gain `B r` [N m].
    pub torque_nm: f64,
}

/// `e ~ tau P'` fitted to the slow pressure error `e` and the set-point's rate `P'`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PressureLag {
    /// `tau` [s].
    pub tau_s: f64,
    /// Share of the slow error's energy it explains.
    pub explained: f64,
}

/// Shares of the muscle-ticks in each valve state.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ValveShares {
    pub deadband: f64,
    pub saturated: f64,
}

/// Ticks after a set-point change counted as "moving" in [`Breakdown`].
pub const MOVE_WINDOW_TICKS: usize = 20;

/// Runs `cfg` on `scenarios` and splits its errors ([`Breakdown`]).
pub fn breakdown(
    plant: &Plant,
    scenarios: &[Scenario],
    cfg: ControllerConfig,
) -> anyhow::Result<Breakdown> {
    let pwm = pam_firmware::valves::OnOffPwmConfig::REFERENCE.period_ticks as usize;
    let half = pwm / 2;
    let gain_nm_per_pa =
        (cfg.torque_model.b_m2 as f64 * cfg.torque_model.sprocket_radius_m as f64).abs();
    let (mut sq, mut sq_moving, mut n) = (0.0, 0.0, 0usize);
    let (mut slow, mut ripple, mut torque, mut cnt) =
        ([0.0f64; 2], [0.0f64; 2], [0.0f64; 2], [0usize; 2]);
    let (mut ep, mut pp, mut ee) = (0.0f64, 0.0f64, 0.0f64);
    let (mut dead, mut sat, mut m) = (0usize, 0usize, 0usize);
    let db = cfg.pressure.deadband_pa as f64;
    for s in scenarios {
        let run = run_with(plant, s, at_scenario_rate(cfg, s), &mut |_| {})?;
        let rows: Vec<_> = run
            .rows
            .iter()
            .take_while(|r| r.out.fault.is_none())
            .collect();
        let err = |r: &super::closed_loop::TickRow| {
            [
                r.out.p1_set_gauge_pa as f64 - r.measured.p1_kpa * 1e3,
                r.out.p2_set_gauge_pa as f64 - r.measured.p2_kpa * 1e3,
            ]
        };
        let mut last_change = None::<usize>;
        for k in 0..rows.len() {
            let r = rows[k];
            if k > 0 && r.setpoint_rad != rows[k - 1].setpoint_rad {
                last_change = Some(k);
            }
            let moving = matches!(last_change, Some(c) if k - c < MOVE_WINDOW_TICKS);
            let e = r.state.angle_rad - r.setpoint_rad;
            sq += e * e;
            n += 1;
            if moving {
                sq_moving += e * e;
            }
            // Pressure figures from the first set-point change on (before it the muscles
            // leave their initial pressures).
            if last_change.is_none() || !r.out.armed || k < half + 1 || k + half + 1 >= rows.len() {
                continue;
            }
            let win = &rows[k - half..k - half + pwm];
            if !win.iter().all(|w| w.out.armed) {
                continue;
            }
            let j = usize::from(!moving);
            let e_now = err(r);
            let mut e_slow = [0.0; 2];
            for w in win {
                let x = err(w);
                e_slow[0] += x[0] / pwm as f64;
                e_slow[1] += x[1] / pwm as f64;
            }
            // Set-point rate over the PWM period (the slow part of P').
            let (a, b) = (win[0], win[pwm - 1]);
            let dt = (b.t_s - a.t_s).max(1e-9);
            let rate = [
                (b.out.p1_set_gauge_pa - a.out.p1_set_gauge_pa) as f64 / dt,
                (b.out.p2_set_gauge_pa - a.out.p2_set_gauge_pa) as f64 / dt,
            ];
            let t_err = gain_nm_per_pa * 0.5 * (e_slow[1] - e_slow[0]);
            torque[j] += t_err * t_err;
            for i in 0..2 {
                slow[j] += e_slow[i] * e_slow[i];
                ripple[j] += (e_now[i] - e_slow[i]).powi(2);
                cnt[j] += 1;
                ep += e_slow[i] * rate[i];
                pp += rate[i] * rate[i];
                ee += e_slow[i] * e_slow[i];
                dead += usize::from(e_now[i].abs() <= db);
                m += 1;
            }
            sat += usize::from(r.out.valves.muscle1.abs() >= 1.0)
                + usize::from(r.out.valves.muscle2.abs() >= 1.0);
        }
    }
    let rms = |x: f64, c: usize| {
        if c == 0 {
            f64::NAN
        } else {
            (x / c as f64).sqrt()
        }
    };
    let tau_s = if pp > 0.0 { ep / pp } else { f64::NAN };
    Ok(Breakdown {
        position_mse_rad2: sq / n.max(1) as f64,
        moving_share: sq_moving / sq.max(f64::MIN_POSITIVE),
        pressure: std::array::from_fn(|j| PressureErrorRms {
            slow_pa: rms(slow[j], cnt[j]),
            ripple_pa: rms(ripple[j], cnt[j]),
            torque_nm: rms(2.0 * torque[j], cnt[j]),
        }),
        lag: PressureLag {
            tau_s,
            explained: if ee > 0.0 { tau_s * ep / ee } else { f64::NAN },
        },
        valves: ValveShares {
            deadband: dead as f64 / m.max(1) as f64,
            saturated: sat as f64 / m.max(1) as f64,
        },
    })
}

/// The breakdown report of the nominal plant: P-only, the diagnostic variants of its pressure
/// loop, and the feed-forward designs, on each set.
fn breakdown_report(
    out: &mut String,
    plant: &Plant,
    sets: &[(&str, &Vec<Scenario>)],
    base: ControllerConfig,
    retuned: ControllerConfig,
) -> anyhow::Result<()> {
    let ctl = controllers(base, None, Some(retuned));
    let off = ctl[0].1;
    let mut rows: Vec<(String, ControllerConfig)> = vec![(ctl[0].0.to_string(), off)];
    let mut no_db = off;
    no_db.pressure.deadband_pa = 0.0;
    rows.push(("P only, deadband 0 (diagnostic)".into(), no_db));
    let mut fast = off;
    fast.pressure.kp_per_pa *= 4.0;
    rows.push(("P only, pressure kp x4 (diagnostic)".into(), fast));
    for (n, c) in ctl.iter().skip(1) {
        if c.pressure_ff.polytropic_index == 1.0 {
            rows.push((n.to_string(), *c));
        }
    }
    writeln!(
        out,
        "\n### Where the position error comes from (nominal plant)\n\n\
         moving = set-point changed within {MOVE_WINDOW_TICKS} ticks; pressure figures from the \
         first set-point change on; slow = pressure error averaged over one PWM period; \
         torque = slow activation error x B r; lag = least-squares tau in e_slow ~ tau P'_set \
         (share of the slow error it explains)\n"
    )?;
    writeln!(
        out,
        "| controller | set | position MSE [rad^2] | share moving | slow pressure RMS moving / rest [kPa] | ripple RMS moving / rest [kPa] | torque RMS moving / rest [N m] | lag [ms] (explained) | in deadband | saturated |"
    )?;
    writeln!(out, "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")?;
    for (set_name, sc) in sets {
        for (name, c) in &rows {
            let b = breakdown(plant, sc, *c)?;
            writeln!(
                out,
                "| {name} | {set_name} | {:.3e} | {:.0} % | {:.1} / {:.1} | {:.1} / {:.1} | {:.3} / {:.3} | {:.1} ({:.0} %) | {:.0} % | {:.1} % |",
                b.position_mse_rad2,
                100.0 * b.moving_share,
                b.pressure[0].slow_pa / 1e3,
                b.pressure[1].slow_pa / 1e3,
                b.pressure[0].ripple_pa / 1e3,
                b.pressure[1].ripple_pa / 1e3,
                b.pressure[0].torque_nm,
                b.pressure[1].torque_nm,
                b.lag.tau_s * 1e3,
                100.0 * b.lag.explained,
                100.0 * b.valves.deadband,
                100.0 * b.valves.saturated,
            )?;
        }
    }
    Ok(())
}

/// Per scenario on `plant`: `rows` = the P-only cascade, the same gains + the analytical
/// feed-forward (k = 1) and the cascade re-tuned with it on. The sets' figures are means of these
/// MSEs, so one scenario the valves cannot follow can hide what the others say.
fn per_scenario_report(
    out: &mut String,
    plant: &Plant,
    sets: &[(&str, &Vec<Scenario>)],
    rows: [ControllerConfig; 3],
) -> anyhow::Result<()> {
    writeln!(
        out,
        "\nper scenario (position MSE [rad^2]; ratio = P only / the row):\n\n\
         | set | scenario | P only | + analytical, same gains | vs P only | + analytical, re-tuned | vs P only |\n\
         |---|---|---:|---:|---:|---:|---:|"
    )?;
    for (set_name, sc) in sets {
        for s in sc.iter() {
            let one = std::slice::from_ref(s);
            let m = rows
                .iter()
                .map(|c| score(plant, one, *c).map(|x| x.position_mse_rad2))
                .collect::<anyhow::Result<Vec<f64>>>()?;
            writeln!(
                out,
                "| {set_name} | {} | {:.3e} | {:.3e} | {} | {:.3e} | {} |",
                s.scenario.name,
                m[0],
                m[1],
                ratio_text(m[0] / m[1]),
                m[2],
                ratio_text(m[0] / m[2])
            )?;
        }
    }
    Ok(())
}

/// A ratio of two MSEs as the tables print it: two decimals ("2.55x"), two significant
/// digits below 0.1 ("0.0011x", not "0.00x").
fn ratio_text(r: f64) -> String {
    if r.is_finite() && r.abs() < 0.1 && r != 0.0 {
        let decimals = (1.0 - r.abs().log10().floor()).clamp(2.0, 12.0) as usize;
        format!("{r:.decimals$}x")
    } else {
        format!("{r:.2}x")
    }
}

/// `host-sim compare-control`: the report and whether the nominal-plant requirement holds.
/// Steps: the plant and both gains files checked, the run's configurations, the scenario
/// sets and plant variants, the report's header, one table per variant, the verdict.
pub fn run_compare_control(a: &CompareControlArgs) -> anyhow::Result<(String, bool)> {
    // Arguments first: a bad one touches nothing and costs no run.
    let t = load_tunings(a)?;
    let cfg = run_configs(a, &t)?;
    let sets = ScenarioSets::new(a, &t.text)?;
    let mut out = String::new();
    write_header(&mut out, a, &t, &cfg, &sets)?;
    let mut ratios = SuiteRatios {
        nominal: f64::NAN,
        same_gains: f64::NAN,
    };
    for (vname, plant_text) in &sets.variants {
        variant_report(&mut out, a, (vname, plant_text), &sets, &cfg, &mut ratios)?;
    }
    let ok = ratios.nominal >= REQUIRED_RATIO;
    let which = if a.quick {
        format!(" (--quick: {} only)", scenario_names(&sets.suite))
    } else {
        String::new()
    };
    writeln!(
        out,
        "\nfor comparison, same gains, nominal plant, suite{which}: P-only position MSE / with the analytical feed-forward (k = 1) = {} (the feed-forward added to the cascade tuned without it)",
        ratio_text(ratios.same_gains)
    )?;
    writeln!(
        out,
        "verdict (exit status), nominal plant, suite{which}: P-only position MSE / with the analytical feed-forward (k = 1), each cascade at its gains (the files named at the top) = {} (required >= {REQUIRED_RATIO}x): {}",
        ratio_text(ratios.nominal),
        if ok { "met" } else { "NOT met" }
    )?;
    let shipped = |tuning: &ControlTuning, text: &str| {
        ControlTuning::from_toml_str(text, "shipped").is_ok_and(|s| s == *tuning)
    };
    if let Some(note) = one_sided_gains_note(
        (&t.gains, shipped(&t.tuning, SHIPPED_CONTROL_TUNED)),
        (&t.gains_ff, shipped(&t.tuning_ff, SHIPPED_CONTROL_TUNED_FF)),
    ) {
        writeln!(out, "{note}")?;
    }
    Ok((out, ok))
}

/// The plant file's text and the two tunings of the comparison, each with its label.
struct Tunings {
    text: String,
    /// The P-only cascade's gains (`--gains` or the shipped ones).
    tuning: ControlTuning,
    gains: String,
    /// The cascade re-tuned with the feed-forward on (`--ff-gains` or the shipped ones).
    tuning_ff: ControlTuning,
    gains_ff: String,
}

/// Reads the plant file (valid itself before its variants are made from it: an error then
/// names its own key, not one of a variant's edits) and the two gains files, each of which
/// must hold the cascade its rows say (a mix-up would print a verdict on the wrong
/// comparison).
fn load_tunings(a: &CompareControlArgs) -> anyhow::Result<Tunings> {
    let text = std::fs::read_to_string(&a.plant)
        .with_context(|| format!("--plant {}: cannot read", a.plant.display()))?;
    PlantConfig::from_toml_str(&text, &a.plant).context("--plant")?;
    let (tuning, gains) = match &a.gains {
        Some(p) => (
            ControlTuning::load(p).context("--gains")?,
            format!("{} (--gains)", p.display()),
        ),
        None => default_control_tuning()?,
    };
    let (tuning_ff, gains_ff) = match &a.ff_gains {
        Some(p) => (
            ControlTuning::load(p).context("--ff-gains")?,
            format!("{} (--ff-gains)", p.display()),
        ),
        None => default_control_tuning_ff()?,
    };
    anyhow::ensure!(
        !tuning.cascade.pressure_feedforward,
        "gains {gains}: its cascade was tuned with the pressure feed-forward on \
         (pressure_feedforward = true); the P-only rows need gains tuned without it \
         (host-sim tune without --pressure-ff); give this file to --ff-gains"
    );
    anyhow::ensure!(
        tuning_ff.cascade.pressure_feedforward,
        "re-tuned gains {gains_ff}: its cascade was tuned without the pressure feed-forward \
         (no pressure_feedforward = true); --ff-gains needs the output of host-sim tune \
         --pressure-ff"
    );
    Ok(Tunings {
        text,
        tuning,
        gains,
        tuning_ff,
        gains_ff,
    })
}

/// The configurations every row runs.
struct RunConfigs {
    /// The P-only cascade with the run's feed-forward options and rates.
    base: ControllerConfig,
    /// The re-tuned cascade with the same options and rates.
    retuned: ControllerConfig,
    /// The feed-forward period the re-tuned gains were tuned at [ticks].
    ff_tuned_every: u16,
    /// The rates each gains file was tuned at, when they are not the rate of this run.
    rate_notes: Vec<String>,
}

/// The run's configurations: the feed-forward evaluated at the period its gains were tuned
/// at (a re-tuned file records it when it is not config/pressure_ff.toml's) unless
/// `--ff-update-ticks` says, the `--ff-*` options, `--outer-period-ticks`; and a note per
/// gains file tuned at other rates.
fn run_configs(a: &CompareControlArgs, t: &Tunings) -> anyhow::Result<RunConfigs> {
    let mut base = t.tuning.cascade.config(1000.0);
    let ff_tuned_every = t
        .tuning_ff
        .cascade
        .config(1000.0)
        .pressure_ff
        .update_period_ticks;
    base.pressure_ff.update_period_ticks = ff_tuned_every;
    a.ff.apply(&mut base.pressure_ff)?;
    // (In range: its parser, `compare::outer_period_arg`, refuses the rest.)
    if let Some(n) = a.outer_period_ticks {
        base.outer_period_ticks = n;
    }
    let tuned_at = |t: &ControlTuning| t.cascade.config(1000.0).outer_period_ticks;
    let rate_notes: Vec<String> = [
        (&t.gains, tuned_at(&t.tuning)),
        (&t.gains_ff, tuned_at(&t.tuning_ff)),
    ]
    .into_iter()
    .filter(|(_, n)| *n != base.outer_period_ticks)
    .map(|(g, n)| format!("gains {g} were tuned with the outer loops every {n} tick(s)"))
    .chain(
        (ff_tuned_every != base.pressure_ff.update_period_ticks).then(|| {
            format!(
                "gains {} were tuned with the feed-forward evaluated every \
                 {ff_tuned_every} tick(s)",
                t.gains_ff
            )
        }),
    )
    .collect();
    let retuned = ControllerConfig {
        pressure_ff: base.pressure_ff,
        outer_period_ticks: base.outer_period_ticks,
        ..t.tuning_ff.cascade.config(1000.0)
    };
    Ok(RunConfigs {
        base,
        retuned,
        ff_tuned_every,
        rate_notes,
    })
}

/// The comparison's scenario sets and plant variants.
struct ScenarioSets {
    suite: Vec<Scenario>,
    moves: Vec<Scenario>,
    jumps: Vec<Scenario>,
    /// (name, plant file text) of each plant variant, the nominal plant first.
    variants: Vec<(&'static str, String)>,
}

impl ScenarioSets {
    /// The suite (tuned on), the held-out moves and the jumps; the plant variants made from
    /// the plant file's `text` (with `--quick` one scenario of each set, and with it or
    /// `--nominal-only` the nominal plant alone).
    fn new(a: &CompareControlArgs, text: &str) -> anyhow::Result<Self> {
        let mut suite = suite_scenarios()?;
        let mut moves = held_out_scenarios()?;
        let mut jumps = jump_suite_scenarios()?;
        let mut variants: Vec<(&str, String)> = VARIANTS
            .iter()
            .map(|(n, t)| (*n, format!("{text}\n{t}")))
            .collect();
        variants.push((
            VOLUME_VARIANT,
            with_volume_mismatch(text).with_context(|| a.plant.display().to_string())?,
        ));
        if a.quick {
            suite.truncate(1);
            moves.truncate(1);
            jumps.truncate(1);
        }
        if a.quick || a.nominal_only {
            variants.truncate(1);
        }
        Ok(ScenarioSets {
            suite,
            moves,
            jumps,
            variants,
        })
    }

    /// The sets with their names, in the report's order.
    fn named(&self) -> [(&'static str, &Vec<Scenario>); 3] {
        [
            ("suite", &self.suite),
            ("held-out moves", &self.moves),
            ("jumps", &self.jumps),
        ]
    }
}

/// The scenarios' names, comma-separated.
fn scenario_names(v: &[Scenario]) -> String {
    v.iter()
        .map(|s| s.scenario.name.as_str())
        .collect::<Vec<_>>()
        .join(", ")
}

/// The report's first lines: the plant, the gains files and the sets; whether `--ff-*`
/// options move the re-tuned rows off their tuned optimum; the feed-forward and loop rates;
/// the rate notes; the hybrid model's training run.
fn write_header(
    out: &mut String,
    a: &CompareControlArgs,
    t: &Tunings,
    cfg: &RunConfigs,
    sets: &ScenarioSets,
) -> anyhow::Result<()> {
    let (gains, gains_ff, base) = (&t.gains, &t.gains_ff, &cfg.base);
    writeln!(
        out,
        "plant {}, gains {gains} (tuned cascade), suite (tuned on): {}; held-out moves (never \
         tuned on): {}; jumps (held out, valve-limited): {}",
        a.plant.display(),
        scenario_names(&sets.suite),
        scenario_names(&sets.moves),
        scenario_names(&sets.jumps),
    )?;
    let overridden = a.ff.gain.is_some()
        || a.ff.cutoff_hz.is_some()
        || a.ff.rate_from.is_some()
        || a.ff.volume_rate_from.is_some()
        || a.ff.min_duty.is_some()
        || a.ff.update_ticks.is_some_and(|n| n != cfg.ff_tuned_every);
    writeln!(
        out,
        "re-tuned rows: gains {gains_ff} (the cascade tuned with the pressure feed-forward on, \
         with the options of config/pressure_ff.toml built into host-sim{})",
        if overridden {
            "; the --ff-* options given here change them: those rows are no longer at their \
             tuned optimum"
        } else {
            ""
        }
    )?;
    let f = &base.pressure_ff;
    writeln!(
        out,
        "feed-forward: P' of the {}, V' of the {}, rate cut-off {} Hz, gain {}, minimum duty {}, \
         evaluated every {} tick(s); outer loops (position, torque) every {} tick(s)",
        if f.rate_from_reference {
            "reference trajectory"
        } else {
            "pressure set-point"
        },
        if f.volume_rate_from_reference {
            "set-point rate"
        } else {
            "measured velocity"
        },
        f.rate_cutoff_hz,
        f.gain,
        f.min_duty,
        f.update_period_ticks,
        base.outer_period_ticks
    )?;
    for n in &cfg.rate_notes {
        writeln!(
            out,
            "note: {n}; every row here runs them at the rates above"
        )?;
    }
    writeln!(
        out,
        "hybrid model: volume network trained per plant on the P-only cascade's run of {} (seed 1)",
        TRAINING_SCENARIO.0
    )?;
    Ok(())
}

/// The P-only / feed-forward MSE ratios of the nominal plant's suite the verdict reads.
struct SuiteRatios {
    /// With the re-tuned cascade.
    nominal: f64,
    /// With the P-only cascade's gains.
    same_gains: f64,
}

/// One plant variant's section: the breakdown (`--breakdown`, nominal plant), the hybrid
/// volume trained on it, the table of every controller on every set, and for the nominal
/// plant the per-scenario table; the nominal suite's ratios kept in `ratios`.
fn variant_report(
    out: &mut String,
    a: &CompareControlArgs,
    (vname, plant_text): (&str, &str),
    sets: &ScenarioSets,
    cfg: &RunConfigs,
    ratios: &mut SuiteRatios,
) -> anyhow::Result<()> {
    let (base, retuned) = (cfg.base, cfg.retuned);
    let sets = sets.named();
    let config = PlantConfig::from_toml_str(plant_text, &a.plant)
        .with_context(|| format!("--plant {} with the {vname} variant", a.plant.display()))?;
    let plant = Plant::from_config(&config);
    if a.breakdown && vname == "nominal" {
        breakdown_report(out, &plant, &sets, base, retuned)?;
    }
    writeln!(out, "\n### {vname}\n")?;
    let (hybrid, mse_poly, mse_hybrid) = train_hybrid(&plant, base)
        .with_context(|| format!("training the hybrid volume on the {vname} plant"))?;
    writeln!(
        out,
        "hybrid volume training run: mass-flow MSE polynomial volume {mse_poly:.3e}, hybrid {mse_hybrid:.3e} (kg/s)^2\n"
    )?;
    writeln!(
        out,
        "vs P only = the P-only row's MSE / this row's (above 1: better than P only); pressure RMS error over every armed tick, the start's fill included (its share of the slow error while moving is in --breakdown)\n\n\
         | controller | set | position MSE [rad^2] | vs P only | pressure RMS error [kPa] | latched faults |"
    )?;
    writeln!(out, "|---|---|---:|---:|---:|---|")?;
    for (set_name, sc) in &sets {
        let mut p_only = f64::NAN;
        for (i, (cname, c)) in controllers(base, Some(hybrid), Some(retuned))
            .into_iter()
            .enumerate()
        {
            let s = score(&plant, sc, c)?;
            if i == 0 {
                p_only = s.position_mse_rad2;
            }
            let ratio = p_only / s.position_mse_rad2;
            if vname == "nominal" && *set_name == "suite" {
                if i == 1 {
                    ratios.same_gains = ratio;
                }
                if cname == RETUNED_ROW {
                    ratios.nominal = ratio;
                }
            }
            writeln!(
                out,
                "| {cname} | {set_name} | {:.3e} | {} | {:.1} | {} |",
                s.position_mse_rad2,
                if ratio.is_finite() && ratio > 0.0 {
                    ratio_text(ratio)
                } else {
                    "-".to_string()
                },
                s.pressure_rms_pa / 1e3,
                if s.faults.is_empty() {
                    "none".to_string()
                } else {
                    s.faults
                        .iter()
                        .map(|(n, f)| format!("{n}: {f}"))
                        .collect::<Vec<_>>()
                        .join(", ")
                }
            )?;
        }
    }
    if vname == "nominal" {
        let ctl = controllers(base, None, Some(retuned));
        let pick = |name: &str| {
            ctl.iter()
                .find(|(n, _)| *n == name)
                .map(|(_, c)| *c)
                .expect("controllers() has this row")
        };
        let rows = [
            pick("P only"),
            pick("+ analytical inverse model, k = 1 (isothermal)"),
            pick(RETUNED_ROW),
        ];
        per_scenario_report(out, &plant, &sets, rows)?;
    }
    Ok(())
}

/// The warning when one of the two tunings is the user's and the other the shipped one:
/// the verdict then sets the user's tuning against the other design's shipped one, tuned on
/// the reference plant, and says little about either (a weak P-only tuning inflates it, a
/// strong one deflates it). Each argument: the label the report's first lines print, and
/// whether the tuning is the shipped one.
fn one_sided_gains_note(
    (gains, gains_shipped): (&str, bool),
    (gains_ff, ff_shipped): (&str, bool),
) -> Option<String> {
    let (given, missing, how) = match (gains_shipped, ff_shipped) {
        (false, true) => (gains, "--ff-gains", "host-sim tune --pressure-ff"),
        (true, false) => (gains_ff, "--gains", "host-sim tune"),
        _ => return None,
    };
    Some(format!(
        "warning: the verdict compares the gains {given} with the shipped {missing} (tuned on \
         the reference plant, not with yours): tune that design too ({how} --plant P.toml) and \
         give both files; the same-gains ratio above needs no second file"
    ))
}
