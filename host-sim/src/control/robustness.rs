//! Robustness of the stored gains (no re-tuning): the three laws of `config/control_tuned.toml`
//! scored on set-point sequences the tuner never saw ([`HELD_OUT_SUITE`]) and on plants with
//! each concealed effect at a realistic size (the sizes of the diagnosis' synthetic truths):
//! joint friction, muscle (braid) hysteresis, an 8 ms valve dead time, a supply that sags with
//! the flow, and the joint carrying 11 x its inertia (seed 000's load).

use pam_firmware::tick::{ControlLaw, ControllerConfig};

use crate::control::closed_loop::{ClosedLoopError, Scenario};
use crate::control::compare::{config_for, score_suite_with, ControlTuning, SuiteScore};
use crate::plant::config::PlantConfig;
use crate::plant::Plant;

/// Set-point sequences for scoring only (other seeds, amplitudes and frequencies than the
/// tuning suite; moves of the same 0.15 s).
pub const HELD_OUT_SUITE: [(&str, &str); 4] = [
    (
        "held-out/random_move_seed11.toml",
        "[scenario]\nname = \"random_move_seed11\"\nduration_s = 8.0\nseed = 11\n\n\
         [setpoint]\nkind = \"random\"\namplitude_rad = 0.3\nhold_s = 0.8\nstart_s = 0.5\ntransition_s = 0.15\n\n\
         [expect]\nsettle_after_s = 0.5\nno_fault = true\n",
    ),
    (
        "held-out/random_move_seed12.toml",
        "[scenario]\nname = \"random_move_seed12\"\nduration_s = 8.0\nseed = 12\n\n\
         [setpoint]\nkind = \"random\"\namplitude_rad = 0.35\nhold_s = 1.2\nstart_s = 0.5\ntransition_s = 0.15\n\n\
         [expect]\nsettle_after_s = 0.5\nno_fault = true\n",
    ),
    (
        "held-out/step_move_down.toml",
        "[scenario]\nname = \"step_move_down\"\nduration_s = 3.0\nseed = 13\n\n\
         [setpoint]\nkind = \"step\"\ninitial_rad = 0.1\nfinal_rad = -0.25\nat_s = 0.5\ntransition_s = 0.15\n\n\
         [expect]\nsettle_after_s = 1.0\nno_fault = true\n",
    ),
    (
        "held-out/sine_0p8hz.toml",
        "[scenario]\nname = \"sine_0p8hz\"\nduration_s = 5.0\nseed = 14\n\n\
         [setpoint]\nkind = \"sine\"\noffset_rad = 0.05\namplitude_rad = 0.2\nfreq_hz = 0.8\nstart_s = 0.5\n\n\
         [expect]\nsettle_after_s = 2.0\nno_fault = true\n",
    ),
];

/// The parsed held-out scenarios.
pub fn held_out_scenarios() -> Result<Vec<Scenario>, ClosedLoopError> {
    HELD_OUT_SUITE
        .iter()
        .map(|(file, text)| Scenario::from_toml_str(text, file))
        .collect()
}

/// A plant condition of the robustness table: name and the `[effects]` TOML appended to the
/// nominal plant file (sizes of `diagnose::synth`'s truths), or an inertia factor.
pub const CONDITIONS: [(&str, &str, f64); 7] = [
    ("nominal", "", 1.0),
    (
        "joint friction 0.35 N m",
        "[effects.joint_friction]\ncoulomb_nm = 0.35\nbreakaway_nm = 0.35\nstribeck_velocity_rad_s = 1.0\nviscous_nm_s_per_rad = 0.08\nsmoothing_velocity_rad_s = 0.01\n",
        1.0,
    ),
    (
        "braid hysteresis 6 N + 20 N/bar",
        "[effects.muscle_hysteresis]\nbase_force_n = 6.0\npressure_gain_n_per_pa = 2.0e-5\nsmoothing_rate_per_s = 0.02\n",
        1.0,
    ),
    (
        "valve dead time 8 ms",
        "[effects.valve_dead_time]\ndelay_s = 0.008\n",
        1.0,
    ),
    (
        "supply drop (line resistance)",
        "[effects.supply_drop]\nmodel = \"static\"\nresistance_pa_s_per_m3 = 2.0e7\n",
        1.0,
    ),
    ("11 x inertia load", "", 11.0),
    (
        SUPERVISION_OFF_DEAD_TIME,
        "[effects.valve_dead_time]\ndelay_s = 0.008\n",
        1.0,
    ),
];

/// The 8 ms valve dead time with the firmware's valve / supply supervision off
/// ([`without_valve_supervision`]) for every law: the control alone. The supervision
/// tolerates a dead time up to one residual window, so the row with it on must give the
/// same runs (asserted in the tests).
pub const SUPERVISION_OFF_DEAD_TIME: &str = "valve dead time 8 ms, valve supervision off";

/// `cfg` with the valve / supply residual never judging (thresholds 1e30: the configuration
/// check refuses infinite ones): for measuring
/// a control law on a plant whose valves the supervision's model does not describe.
pub fn without_valve_supervision(mut cfg: ControllerConfig) -> ControllerConfig {
    cfg.valve_model.residual_abs_pa_s = 1e30;
    cfg.valve_model.integral_min_pa = 1e30;
    cfg
}

/// The plant of one condition.
pub fn condition_plant(nominal_toml: &str, effects: &str, inertia_factor: f64) -> Plant {
    try_condition_plant(nominal_toml, effects, inertia_factor, "robustness.toml")
        .expect("the conditions' TOML is valid on a valid nominal plant")
}

/// The plant of one condition, or the plant file's error (e.g. a plant file that already has
/// the effect); `file` names the plant file in the error.
pub fn try_condition_plant(
    nominal_toml: &str,
    effects: &str,
    inertia_factor: f64,
    file: &str,
) -> Result<Plant, crate::plant::config::ConfigError> {
    let text = format!("{nominal_toml}\n{effects}");
    let cfg = PlantConfig::from_toml_str(&text, file)?;
    let mut p = Plant::from_config(&cfg);
    p.joint.inertia_kgm2 *= inertia_factor;
    Ok(p)
}

/// The robust tuner's plants (`host-sim tune --robust`): the cost is the worst over
/// [`ROBUST_COST_CONDITIONS`] (indices into [`CONDITIONS`]: nominal, 8 ms valve dead time
/// with the valve supervision off) and
/// the suite must stay stable ([`Cell`]'s criterion) under [`ROBUST_STABLE_CONDITIONS`]
/// (11 x inertia load).
pub const ROBUST_COST_CONDITIONS: [usize; 2] = [0, 6];
/// See [`ROBUST_COST_CONDITIONS`].
pub const ROBUST_STABLE_CONDITIONS: [usize; 1] = [5];

/// The controller configuration a law runs with under the condition `name` (the valve
/// supervision off for [`SUPERVISION_OFF_DEAD_TIME`], else `cfg`).
pub fn condition_config(name: &str, cfg: ControllerConfig) -> ControllerConfig {
    if name == SUPERVISION_OFF_DEAD_TIME {
        without_valve_supervision(cfg)
    } else {
        cfg
    }
}

/// Largest [`ScenarioScore::final_hold_sd_rad`](crate::control::compare::ScenarioScore) a
/// stable run may end with [rad]: the angle error's spread over the final hold. Past it the
/// joint is still swinging at rest (a limit cycle); the cascade's runs end below 0.01 rad on
/// every plant of the table.
pub const HOLD_SD_MAX_RAD: f64 = 0.02;

/// The tuner's stricter bound on the final hold's spread: half of [`HOLD_SD_MAX_RAD`], a
/// margin like the gain margin of the cost (an optimiser lands on the edge of its
/// constraints, and the held-out moves are larger than the tuning suite's).
pub const TUNING_HOLD_SD_MAX_RAD: f64 = 0.5 * HOLD_SD_MAX_RAD;

/// True when `cfg` runs the suite on `plant` with no fault, every |angle error| below
/// 0.5 rad and no run ending in a limit cycle (the table's "stable").
pub fn stable_on(plant: &Plant, scenarios: &[Scenario], cfg: ControllerConfig) -> bool {
    Cell::of(&score_suite_with(plant, scenarios, cfg)).stable
}

/// [`stable_on`] with the tuner's margin: every final hold's spread at most
/// [`TUNING_HOLD_SD_MAX_RAD`].
pub fn stable_with_margin_on(plant: &Plant, scenarios: &[Scenario], cfg: ControllerConfig) -> bool {
    let c = Cell::of(&score_suite_with(plant, scenarios, cfg));
    c.stable && c.hold_sd_rad <= TUNING_HOLD_SD_MAX_RAD
}

/// One cell of the table.
#[derive(Debug, Clone)]
pub struct Cell {
    /// Suite MSE [rad^2] (infinite if a run latched a fault).
    pub mse_rad2: f64,
    /// Largest |angle error| over the suite [rad].
    pub max_abs_rad: f64,
    /// Largest spread of the angle error over a run's final hold [rad] (0 when no run ends
    /// in a hold).
    pub hold_sd_rad: f64,
    /// No fault latched, the error stayed bounded (below 0.5 rad) and every run that ends in a
    /// hold comes to rest there (spread at most [`HOLD_SD_MAX_RAD`]).
    pub stable: bool,
}

impl Cell {
    fn of(s: &Result<SuiteScore, ClosedLoopError>) -> Cell {
        match s {
            Ok(s) => {
                let max_abs = s
                    .scenarios
                    .iter()
                    .map(|c| c.max_abs_rad)
                    .fold(0.0, f64::max);
                let hold_sd = s
                    .scenarios
                    .iter()
                    .filter_map(|c| c.final_hold_sd_rad)
                    .fold(0.0, f64::max);
                Cell {
                    mse_rad2: s.mse_rad2,
                    max_abs_rad: max_abs,
                    hold_sd_rad: hold_sd,
                    stable: s.mse_rad2.is_finite()
                        && s.scenarios.iter().all(|c| c.fault.is_none())
                        && max_abs < 0.5
                        && hold_sd <= HOLD_SD_MAX_RAD,
                }
            }
            Err(_) => Cell {
                mse_rad2: f64::INFINITY,
                max_abs_rad: f64::INFINITY,
                hold_sd_rad: f64::INFINITY,
                stable: false,
            },
        }
    }
}

/// A row: one plant condition, the three laws.
#[derive(Debug, Clone)]
pub struct Row {
    /// Condition name.
    pub condition: String,
    /// Cascade, PD, PID.
    pub cells: [Cell; 3],
}

impl Row {
    /// PID suite MSE / cascade suite MSE (the cascade's lead).
    pub fn lead_over_pid(&self) -> f64 {
        self.cells[2].mse_rad2 / self.cells[0].mse_rad2
    }
}

/// Scores the stored gains on `scenarios` under every condition of [`CONDITIONS`] whose
/// index is in `which` (all when empty).
pub fn table(
    nominal_toml: &str,
    tuning: &ControlTuning,
    scenarios: &[Scenario],
    which: &[usize],
) -> Vec<Row> {
    let laws = [
        config_for(ControlLaw::Cascade, 1000.0),
        config_for(ControlLaw::DirectPid(tuning.pd.gains()), 1000.0),
        config_for(ControlLaw::DirectPid(tuning.pid.gains()), 1000.0),
    ];
    let cascade = tuning.cascade.config(1000.0);
    CONDITIONS
        .iter()
        .enumerate()
        .filter(|(i, _)| which.is_empty() || which.contains(i))
        .map(|(_, (name, effects, inertia))| {
            let plant = condition_plant(nominal_toml, effects, *inertia);
            let cfg = |c: ControllerConfig| condition_config(name, c);
            let cells = [
                Cell::of(&score_suite_with(&plant, scenarios, cfg(cascade))),
                Cell::of(&score_suite_with(&plant, scenarios, cfg(laws[1]))),
                Cell::of(&score_suite_with(&plant, scenarios, cfg(laws[2]))),
            ];
            Row {
                condition: name.to_string(),
                cells,
            }
        })
        .collect()
}

/// The table as Markdown.
pub fn format_table(rows: &[Row]) -> String {
    let mut s = String::from(
        "| plant | cascade MSE [rad^2] | PD MSE [rad^2] | PID MSE [rad^2] | PID / cascade | all stable |\n\
         |---|---|---|---|---|---|\n",
    );
    for r in rows {
        s += &format!(
            "| {} | {:.3e} | {:.3e} | {:.3e} | {:.2} | {} |\n",
            r.condition,
            r.cells[0].mse_rad2,
            r.cells[1].mse_rad2,
            r.cells[2].mse_rad2,
            r.lead_over_pid(),
            if r.cells.iter().all(|c| c.stable) {
                "yes".to_string()
            } else {
                let names = ["cascade", "PD", "PID"];
                let bad: Vec<String> = r
                    .cells
                    .iter()
                    .zip(names)
                    .filter(|(c, _)| !c.stable)
                    .map(|(c, n)| {
                        if c.hold_sd_rad > HOLD_SD_MAX_RAD && c.max_abs_rad < 0.5 {
                            format!("{n} (swings at rest, sd {:.3} rad)", c.hold_sd_rad)
                        } else {
                            n.to_string()
                        }
                    })
                    .collect();
                format!("NO: {}", bad.join(", "))
            }
        );
    }
    s
}
