//! Closed-loop proof of issue 5: the model-based cascade (seed 003, identified constants)
//! against a tuned model-free PD and PID (seed 004 Table 3: PD 3.61 vs model-based 1.95), on
//! the same set-point suite, the same reference plant and the same firmware tick (the law is
//! selected by [`ControlLaw`] in the tick's configuration; pressure loops, valves and safety
//! path are shared).
//!
//! - The suite: the step, sine and random scenarios of `scenarios/` ([`SUITE`], the same files
//!   `host-sim demo` runs).
//! - The metric: per scenario, the mean squared angle error `(alpha - r)^2` over every tick
//!   of the run (from t = 0, including the transients); the suite MSE is the mean of the three
//!   scenario MSEs. A run that latches any fault scores infinity.
//! - The PD / PID gains: `config/pid_tuned.toml`, written by `examples/tune_pid.rs`
//!   ([`nelder_mead`] on log-gains from the best point of a coarse grid, then a polish,
//!   minimising [`tuning_cost`]: the worse of the suite MSE at the gains and at
//!   [`GAIN_MARGIN`] x the feedback gains, step overshoot <= [`MAX_OVERSHOOT_FRAC`]). The
//!   cascade: [`ControllerConfig::reference`], tuned by the same procedure (`tune_pid
//!   --cascade`; its gains and how they were chosen are documented there).

use std::fmt::Write as _;
use std::path::Path;

use pam_firmware::pid::DpPidGains;
use pam_firmware::tick::{ControlLaw, ControllerConfig, FaultCode};
use serde::{Deserialize, Serialize};

use crate::closed_loop::{run_with, ClosedLoopError, Scenario, SetpointProfile};
use crate::identify::{write_atomic, IdentError};
use crate::plant::Plant;

/// The set-point suite: (file name, text) of the step, sine and random scenarios.
pub const SUITE: [(&str, &str); 3] = crate::demo::SCENARIOS;

/// Where the tuned PD / PID gains live, relative to the repository root.
pub const PID_TUNED_TOML: &str = "config/pid_tuned.toml";

/// The tuned gains file, relative to this crate's source tree (for tests and examples).
pub fn pid_tuned_path() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(PID_TUNED_TOML)
}

/// The reference plant `shared/plant/reference-1dof.toml`: `../shared/...` from the working
/// directory, else next to this crate's repository checkout.
pub fn reference_plant_path() -> Option<std::path::PathBuf> {
    [
        Path::new("../shared/plant/reference-1dof.toml").to_path_buf(),
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/plant/reference-1dof.toml"),
    ]
    .into_iter()
    .find(|p| p.is_file())
}

/// One tuned law as stored in the TOML file (SI units, names with units).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DpPidToml {
    /// [Pa/rad]
    pub kp_pa_per_rad: f64,
    /// [Pa/(rad s)] (0 for PD)
    pub ki_pa_per_rad_s: f64,
    /// [Pa s/rad]
    pub kd_pa_s_per_rad: f64,
    /// 0 = derivative on the measurement, 1 = on the error.
    pub setpoint_rate_weight: f64,
    /// [Hz]
    pub setpoint_rate_cutoff_hz: f64,
    /// [Pa]
    pub i_limit_pa: f64,
    /// [Pa]
    pub dp_max_pa: f64,
    /// [Pa gauge]
    pub p0_gauge_pa: f64,
    /// Suite MSE the tuner measured with these gains [rad^2] (checked by the tests).
    pub suite_mse_rad2: f64,
    /// Suite MSE with kp, ki, kd scaled by [`GAIN_MARGIN`] [rad^2] (checked by the tests).
    pub suite_mse_at_margin_rad2: f64,
}

impl DpPidToml {
    /// The firmware's gains.
    pub fn gains(&self) -> DpPidGains {
        DpPidGains {
            kp_pa_per_rad: self.kp_pa_per_rad as f32,
            ki_pa_per_rad_s: self.ki_pa_per_rad_s as f32,
            kd_pa_s_per_rad: self.kd_pa_s_per_rad as f32,
            setpoint_rate_weight: self.setpoint_rate_weight as f32,
            setpoint_rate_cutoff_hz: self.setpoint_rate_cutoff_hz as f32,
            i_limit_pa: self.i_limit_pa as f32,
            dp_max_pa: self.dp_max_pa as f32,
            p0_gauge_pa: self.p0_gauge_pa as f32,
        }
    }

    /// From firmware gains and the measured suite MSEs (nominal, at the gain margin).
    pub fn from_gains(g: &DpPidGains, suite_mse_rad2: f64, suite_mse_at_margin_rad2: f64) -> Self {
        DpPidToml {
            kp_pa_per_rad: g.kp_pa_per_rad as f64,
            ki_pa_per_rad_s: g.ki_pa_per_rad_s as f64,
            kd_pa_s_per_rad: g.kd_pa_s_per_rad as f64,
            setpoint_rate_weight: g.setpoint_rate_weight as f64,
            setpoint_rate_cutoff_hz: g.setpoint_rate_cutoff_hz as f64,
            i_limit_pa: g.i_limit_pa as f64,
            dp_max_pa: g.dp_max_pa as f64,
            p0_gauge_pa: g.p0_gauge_pa as f64,
            suite_mse_rad2,
            suite_mse_at_margin_rad2,
        }
    }

    fn validate(&self, table: &str, text: &str, file: &str) -> Result<(), IdentError> {
        let fields = [
            ("kp_pa_per_rad", self.kp_pa_per_rad, f64::INFINITY),
            ("ki_pa_per_rad_s", self.ki_pa_per_rad_s, f64::INFINITY),
            ("kd_pa_s_per_rad", self.kd_pa_s_per_rad, f64::INFINITY),
            ("setpoint_rate_weight", self.setpoint_rate_weight, 1.0),
            ("setpoint_rate_cutoff_hz", self.setpoint_rate_cutoff_hz, 1e4),
            ("i_limit_pa", self.i_limit_pa, 1e6),
            ("dp_max_pa", self.dp_max_pa, 6e5),
            ("p0_gauge_pa", self.p0_gauge_pa, 6e5),
            ("suite_mse_rad2", self.suite_mse_rad2, f64::INFINITY),
            (
                "suite_mse_at_margin_rad2",
                self.suite_mse_at_margin_rad2,
                f64::INFINITY,
            ),
        ];
        for (key, v, max) in fields {
            if !(v.is_finite() && v >= 0.0 && v <= max && (v as f32).is_finite()) {
                let line = key_line(text, table, key).unwrap_or(0);
                return Err(IdentError::at(
                    file,
                    line,
                    &format!("{table}.{key}"),
                    &format!("{v} must be a finite number in 0..={max}"),
                ));
            }
        }
        Ok(())
    }
}

/// `config/pid_tuned.toml`: the tuned PD and PID.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PidTuning {
    /// The tuned PD (`ki = 0`).
    pub pd: DpPidToml,
    /// The tuned PID.
    pub pid: DpPidToml,
}

impl PidTuning {
    /// Reads and validates the file; errors name the file, the line and the field.
    pub fn load(path: &Path) -> Result<Self, IdentError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| IdentError::Io {
            file: file.clone(),
            msg: e.to_string(),
        })?;
        Self::from_toml_str(&text, &file)
    }

    /// Parses TOML text (`file` names it in errors).
    pub fn from_toml_str(text: &str, file: &str) -> Result<Self, IdentError> {
        let t: PidTuning = toml::from_str(text).map_err(|e| {
            let line = e
                .span()
                .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1)
                .unwrap_or(0);
            let msg = e.message().trim_end().to_string();
            let field = msg
                .split('`')
                .nth(1)
                .filter(|_| msg.contains("field"))
                .unwrap_or("-")
                .to_string();
            IdentError::at(file, line, &field, &msg)
        })?;
        t.pd.validate("pd", text, file)?;
        t.pid.validate("pid", text, file)?;
        if t.pd.ki_pa_per_rad_s != 0.0 {
            let line = key_line(text, "pd", "ki_pa_per_rad_s").unwrap_or(0);
            return Err(IdentError::at(
                file,
                line,
                "pd.ki_pa_per_rad_s",
                "a PD has no integral term: must be 0",
            ));
        }
        Ok(t)
    }

    /// The file text: a provenance header (`header`, each line prefixed with `# `) and both
    /// tables.
    pub fn to_toml_string(&self, header: &str) -> String {
        let mut s = String::new();
        for l in header.lines() {
            let _ = writeln!(s, "# {l}");
        }
        s.push('\n');
        s.push_str(&toml::to_string(self).expect("plain numbers serialise"));
        s
    }

    /// Writes the file atomically.
    pub fn write(&self, path: &Path, header: &str) -> Result<(), IdentError> {
        write_atomic(path, self.to_toml_string(header).as_bytes())
    }
}

/// 1-based line of `key = ...` inside `[table]`.
fn key_line(text: &str, table: &str, key: &str) -> Option<usize> {
    let mut inside = false;
    for (i, line) in text.lines().enumerate() {
        let l = line.trim();
        if l.starts_with('[') {
            inside = l == format!("[{table}]");
            continue;
        }
        if inside
            && l.strip_prefix(key)
                .is_some_and(|r| r.trim_start().starts_with('='))
        {
            return Some(i + 1);
        }
    }
    None
}

/// The tick configuration of `law` at `tick_hz`: the reference configuration (validation,
/// pressure loops, safety) with the law replaced.
pub fn config_for(law: ControlLaw, tick_hz: f32) -> ControllerConfig {
    ControllerConfig {
        law,
        ..ControllerConfig::reference(tick_hz)
    }
}

/// Loop-gain margin every tuning must keep: the tuning cost is the worse of the suite MSE at
/// the gains and at the feedback gains (kp, ki, kd) times this factor. Without it the suite
/// optimum of both the cascade and the PID sits at the edge of a limit cycle (the cascade
/// tuned on the suite MSE alone went from 1.04 to 4.1 deg^2 with kp x1.2).
pub const GAIN_MARGIN: f32 = 1.25;

/// `cfg` with the feedback gains of its law (cascade: the position PID; PD / PID: kp, ki, kd)
/// multiplied by `factor`: the loop as it runs when the actuator's gain is `factor` times
/// the model's.
pub fn scale_feedback(cfg: ControllerConfig, factor: f32) -> ControllerConfig {
    let mut c = cfg;
    match &mut c.law {
        ControlLaw::Cascade => {
            c.position.kp *= factor;
            c.position.ki *= factor;
            c.position.kd *= factor;
        }
        ControlLaw::DirectPid(g) => {
            g.kp_pa_per_rad *= factor;
            g.ki_pa_per_rad_s *= factor;
            g.kd_pa_s_per_rad *= factor;
        }
    }
    c
}

/// Largest step overshoot a tuning may have, as a fraction of the step: the firmware's own
/// step requirement (`tests/closed_loop_smoke.rs`: 0.02 rad on a 0.2 rad step).
pub const MAX_OVERSHOOT_FRAC: f64 = 0.10;

/// The tuning cost [rad^2]: the worse of the suite MSE of `cfg` and of
/// `scale_feedback(cfg, GAIN_MARGIN)`; infinite when a run fails or the step overshoots by
/// more than [`MAX_OVERSHOOT_FRAC`] at the nominal gains. Returns (cost, nominal suite MSE,
/// suite MSE at the margin).
pub fn tuning_cost(
    plant: &Plant,
    scenarios: &[Scenario],
    cfg: ControllerConfig,
) -> (f64, f64, f64) {
    let nominal = score_suite_with(plant, scenarios, cfg);
    let margin = score_suite_with(plant, scenarios, scale_feedback(cfg, GAIN_MARGIN))
        .map(|s| s.mse_rad2)
        .unwrap_or(f64::INFINITY);
    let (mse, overshoot) = match nominal {
        Ok(s) => (
            s.mse_rad2,
            s.scenarios
                .iter()
                .map(|c| c.overshoot_frac)
                .fold(0.0, f64::max),
        ),
        Err(_) => (f64::INFINITY, 0.0),
    };
    let cost = if overshoot > MAX_OVERSHOOT_FRAC {
        f64::INFINITY
    } else {
        mse.max(margin)
    };
    (cost, mse, margin)
}

/// Score of one scenario.
#[derive(Debug, Clone, PartialEq)]
pub struct ScenarioScore {
    /// Scenario name.
    pub name: String,
    /// Mean squared angle error over the run [rad^2] (infinite if a fault latched).
    pub mse_rad2: f64,
    /// Largest |angle error| [rad].
    pub max_abs_rad: f64,
    /// Mean squared angle error after the scenario's `settle_after_s` [rad^2] (infinite if a
    /// fault latched): the tracking phase without the first transient.
    pub mse_settled_rad2: f64,
    /// Step scenarios: overshoot past the final set-point as a fraction of the step (0 for
    /// other set-point profiles).
    pub overshoot_frac: f64,
    /// The first latched fault, if any.
    pub fault: Option<FaultCode>,
}

/// Score of the suite.
#[derive(Debug, Clone, PartialEq)]
pub struct SuiteScore {
    /// Per scenario, in [`SUITE`] order.
    pub scenarios: Vec<ScenarioScore>,
    /// Mean of the scenario MSEs [rad^2] (infinite if any run latched a fault).
    pub mse_rad2: f64,
    /// Mean of the scenario MSEs after their settle times [rad^2].
    pub mse_settled_rad2: f64,
}

/// The parsed suite scenarios.
pub fn suite_scenarios() -> Result<Vec<Scenario>, ClosedLoopError> {
    SUITE
        .iter()
        .map(|(file, text)| Scenario::from_toml_str(text, file))
        .collect()
}

/// Runs `scenarios` with `law` on `plant` (firmware in the loop) and scores them.
pub fn score_suite(
    plant: &Plant,
    scenarios: &[Scenario],
    law: ControlLaw,
) -> Result<SuiteScore, ClosedLoopError> {
    score_suite_with(plant, scenarios, config_for(law, 1000.0))
}

/// [`score_suite`] with a whole tick configuration (`tick_hz` and `dt_max_s` are set per
/// scenario).
pub fn score_suite_with(
    plant: &Plant,
    scenarios: &[Scenario],
    cfg: ControllerConfig,
) -> Result<SuiteScore, ClosedLoopError> {
    let mut out = Vec::with_capacity(scenarios.len());
    for s in scenarios {
        let tick_hz = s.scenario.tick_hz as f32;
        let reference = ControllerConfig::reference(tick_hz);
        let cfg = ControllerConfig {
            tick_hz,
            dt_max_s: reference.dt_max_s,
            pressure_limits: reference.pressure_limits,
            angle_limits: reference.angle_limits,
            tracking_ticks: reference.tracking_ticks,
            ..cfg
        };
        let run = run_with(plant, s, cfg, &mut |_| {})?;
        let fault = run
            .first_latched_fault_tick
            .and_then(|k| run.rows[k].out.fault);
        let st = run.tracking(0.0);
        let settled = run.tracking(s.expect.settle_after_s);
        let overshoot_frac = match s.setpoint {
            SetpointProfile::Step {
                initial_rad,
                final_rad,
                at_s,
            } if final_rad != initial_rad => {
                let dir = (final_rad - initial_rad).signum();
                let past = run
                    .rows
                    .iter()
                    .filter(|r| r.t_s >= at_s)
                    .map(|r| (r.state.angle_rad - final_rad) * dir)
                    .fold(0.0f64, f64::max);
                past / (final_rad - initial_rad).abs()
            }
            _ => 0.0,
        };
        out.push(ScenarioScore {
            name: run.name.clone(),
            mse_rad2: if fault.is_some() || st.n == 0 {
                f64::INFINITY
            } else {
                st.mse_rad2
            },
            max_abs_rad: st.max_abs_rad,
            mse_settled_rad2: if fault.is_some() || settled.n == 0 {
                f64::INFINITY
            } else {
                settled.mse_rad2
            },
            overshoot_frac,
            fault,
        });
    }
    let mean = |f: fn(&ScenarioScore) -> f64| {
        let m = out.iter().map(f).sum::<f64>() / out.len().max(1) as f64;
        if m.is_nan() {
            f64::INFINITY
        } else {
            m
        }
    };
    let mse_rad2 = mean(|s| s.mse_rad2);
    let mse_settled_rad2 = mean(|s| s.mse_settled_rad2);
    Ok(SuiteScore {
        scenarios: out,
        mse_rad2,
        mse_settled_rad2,
    })
}

/// One row of the comparison table.
#[derive(Debug, Clone)]
pub struct Row {
    /// Controller name.
    pub controller: String,
    /// Its score.
    pub score: SuiteScore,
}

/// The comparison of the cascade with the tuned PD and PID on the suite.
pub fn compare(plant: &Plant, tuning: &PidTuning) -> Result<Vec<Row>, ClosedLoopError> {
    let sc = suite_scenarios()?;
    let laws = [
        ("cascade (model-based)", ControlLaw::Cascade),
        ("PD (tuned)", ControlLaw::DirectPid(tuning.pd.gains())),
        ("PID (tuned)", ControlLaw::DirectPid(tuning.pid.gains())),
    ];
    laws.into_iter()
        .map(|(name, law)| {
            Ok(Row {
                controller: name.to_string(),
                score: score_suite(plant, &sc, law)?,
            })
        })
        .collect()
}

/// The comparison as a Markdown table: MSE per scenario and for the suite in rad^2 and deg^2,
/// each controller's suite MSE relative to the cascade's, and the same after each scenario's
/// `settle_after_s` (step 2 s, sine 2 s, random 0.5 s).
pub fn format_table(rows: &[Row]) -> String {
    let mut s = String::new();
    let names: Vec<&str> = rows
        .first()
        .map(|r| r.score.scenarios.iter().map(|c| c.name.as_str()).collect())
        .unwrap_or_default();
    let _ = write!(s, "| controller |");
    for n in &names {
        let _ = write!(s, " {n} MSE [deg^2] |");
    }
    let _ = writeln!(
        s,
        " suite MSE [deg^2] | suite MSE [rad^2] | / cascade | suite MSE after settle [deg^2] | / cascade |"
    );
    let _ = write!(s, "|---|");
    for _ in &names {
        let _ = write!(s, "---:|");
    }
    let _ = writeln!(s, "---:|---:|---:|---:|---:|");
    let base = rows.first().map(|r| r.score.mse_rad2).unwrap_or(f64::NAN);
    let base_settled = rows
        .first()
        .map(|r| r.score.mse_settled_rad2)
        .unwrap_or(f64::NAN);
    let deg2 = (180.0 / std::f64::consts::PI).powi(2);
    for r in rows {
        let _ = write!(s, "| {} |", r.controller);
        for c in &r.score.scenarios {
            match c.fault {
                Some(f) => {
                    let _ = write!(s, " fault {f:?} |");
                }
                None => {
                    let _ = write!(s, " {:.4} |", c.mse_rad2 * deg2);
                }
            }
        }
        let _ = writeln!(
            s,
            " {:.4} | {:.3e} | {:.2} | {:.4} | {:.2} |",
            r.score.mse_rad2 * deg2,
            r.score.mse_rad2,
            r.score.mse_rad2 / base,
            r.score.mse_settled_rad2 * deg2,
            r.score.mse_settled_rad2 / base_settled
        );
    }
    s
}

/// Result of [`nelder_mead`].
#[derive(Debug, Clone, PartialEq)]
pub struct NelderMeadResult {
    /// Best point.
    pub x: Vec<f64>,
    /// Cost at `x`.
    pub cost: f64,
    /// Cost evaluations used.
    pub evaluations: usize,
}

/// Nelder-Mead simplex minimisation (standard coefficients: reflection 1, expansion 2,
/// contraction 1/2, shrink 1/2) from `x0` with initial simplex steps `step`, until the
/// spread of the simplex costs is below `f_tol` or `max_evals` evaluations are used.
/// Infinite costs (failed runs) are allowed: they are simply never best.
///
/// A hand-written 60-line routine rather than a crate: the tuner needs nothing beyond the
/// textbook method, and it is tested on the Rosenbrock function.
pub fn nelder_mead(
    mut f: impl FnMut(&[f64]) -> f64,
    x0: &[f64],
    step: &[f64],
    f_tol: f64,
    max_evals: usize,
) -> NelderMeadResult {
    let n = x0.len();
    let mut evals = 0;
    let mut eval = |x: &[f64], evals: &mut usize| {
        *evals += 1;
        let c = f(x);
        if c.is_nan() {
            f64::INFINITY
        } else {
            c
        }
    };
    let mut simplex: Vec<(Vec<f64>, f64)> = Vec::with_capacity(n + 1);
    let c0 = eval(x0, &mut evals);
    simplex.push((x0.to_vec(), c0));
    for i in 0..n {
        let mut x = x0.to_vec();
        x[i] += step[i];
        let c = eval(&x, &mut evals);
        simplex.push((x, c));
    }
    let lerp = |a: &[f64], b: &[f64], t: f64| -> Vec<f64> {
        a.iter().zip(b).map(|(a, b)| a + t * (b - a)).collect()
    };
    while evals < max_evals {
        simplex.sort_by(|a, b| a.1.total_cmp(&b.1));
        let (best, worst) = (simplex[0].1, simplex[n].1);
        if worst.is_finite() && (worst - best).abs() <= f_tol {
            break;
        }
        // Centroid of all but the worst.
        let mut centroid = vec![0.0; n];
        for (x, _) in &simplex[..n] {
            for (c, xi) in centroid.iter_mut().zip(x) {
                *c += xi / n as f64;
            }
        }
        let xw = simplex[n].0.clone();
        let xr = lerp(&centroid, &xw, -1.0);
        let cr = eval(&xr, &mut evals);
        if cr < simplex[0].1 {
            let xe = lerp(&centroid, &xw, -2.0);
            let ce = eval(&xe, &mut evals);
            simplex[n] = if ce < cr { (xe, ce) } else { (xr, cr) };
        } else if cr < simplex[n - 1].1 {
            simplex[n] = (xr, cr);
        } else {
            // Contraction: outside if the reflection improved on the worst, else inside.
            let (xc, cc) = if cr < simplex[n].1 {
                let xc = lerp(&centroid, &xw, -0.5);
                let cc = eval(&xc, &mut evals);
                (xc, cc)
            } else {
                let xc = lerp(&centroid, &xw, 0.5);
                let cc = eval(&xc, &mut evals);
                (xc, cc)
            };
            if cc < simplex[n].1.min(cr) {
                simplex[n] = (xc, cc);
            } else {
                let x0 = simplex[0].0.clone();
                for v in simplex.iter_mut().skip(1) {
                    let x = lerp(&x0, &v.0, 0.5);
                    let c = eval(&x, &mut evals);
                    *v = (x, c);
                }
            }
        }
    }
    simplex.sort_by(|a, b| a.1.total_cmp(&b.1));
    let (x, cost) = simplex.swap_remove(0);
    NelderMeadResult {
        x,
        cost,
        evaluations: evals,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nelder_mead_finds_the_rosenbrock_minimum() {
        let rosen = |x: &[f64]| (1.0 - x[0]).powi(2) + 100.0 * (x[1] - x[0] * x[0]).powi(2);
        let r = nelder_mead(rosen, &[-1.2, 1.0], &[0.5, 0.5], 1e-14, 2000);
        assert!(
            (r.x[0] - 1.0).abs() < 1e-3 && (r.x[1] - 1.0).abs() < 1e-3,
            "{r:?}"
        );
        assert!(r.evaluations <= 2000);
    }

    #[test]
    fn nelder_mead_avoids_infinite_regions() {
        // Quadratic bowl at (2, -1) with a forbidden half-plane x0 < 0 (a failed run).
        let f = |x: &[f64]| {
            if x[0] < 0.0 {
                f64::INFINITY
            } else {
                (x[0] - 2.0).powi(2) + (x[1] + 1.0).powi(2)
            }
        };
        let r = nelder_mead(f, &[0.1, 0.0], &[-1.0, 1.0], 1e-12, 500);
        assert!(
            (r.x[0] - 2.0).abs() < 1e-3 && (r.x[1] + 1.0).abs() < 1e-3,
            "{r:?}"
        );
    }

    const GOOD: &str = "[pd]
kp_pa_per_rad = 500000.0
ki_pa_per_rad_s = 0.0
kd_pa_s_per_rad = 10000.0
setpoint_rate_weight = 1.0
setpoint_rate_cutoff_hz = 20.0
i_limit_pa = 0.0
dp_max_pa = 280000.0
p0_gauge_pa = 300000.0
suite_mse_rad2 = 0.001
suite_mse_at_margin_rad2 = 0.002

[pid]
kp_pa_per_rad = 500000.0
ki_pa_per_rad_s = 100000.0
kd_pa_s_per_rad = 10000.0
setpoint_rate_weight = 1.0
setpoint_rate_cutoff_hz = 20.0
i_limit_pa = 150000.0
dp_max_pa = 280000.0
p0_gauge_pa = 300000.0
suite_mse_rad2 = 0.001
suite_mse_at_margin_rad2 = 0.002
";

    #[test]
    fn tuning_file_round_trips() {
        let t = PidTuning::from_toml_str(GOOD, "t.toml").unwrap();
        assert_eq!(t.pid.gains().ki_pa_per_rad_s, 100_000.0);
        let text = t.to_toml_string("provenance\nline two");
        assert!(text.starts_with("# provenance\n# line two\n"));
        assert_eq!(PidTuning::from_toml_str(&text, "t.toml").unwrap(), t);
    }

    #[test]
    fn tuning_file_errors_name_file_line_and_field() {
        let bad = GOOD.replace("kd_pa_s_per_rad = 10000.0\nsetpoint_rate_weight = 1.0\nsetpoint_rate_cutoff_hz = 20.0\ni_limit_pa = 150000.0",
            "kd_pa_s_per_rad = -5.0\nsetpoint_rate_weight = 1.0\nsetpoint_rate_cutoff_hz = 20.0\ni_limit_pa = 150000.0");
        let e = PidTuning::from_toml_str(&bad, "t.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("t.toml:16: field `pid.kd_pa_s_per_rad`"),
            "{e}"
        );
        let bad = GOOD.replace("ki_pa_per_rad_s = 0.0", "ki_pa_per_rad_s = 3.0");
        let e = PidTuning::from_toml_str(&bad, "t.toml")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("t.toml:3: field `pd.ki_pa_per_rad_s`"), "{e}");
        let bad = GOOD.replace("i_limit_pa = 0.0", "i_limit_pa = 0.0\nkq = 1.0");
        let e = PidTuning::from_toml_str(&bad, "t.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("t.toml:8:") && e.contains("kq"), "{e}");
        let bad = GOOD.replace("setpoint_rate_weight = 1.0\n", "");
        let e = PidTuning::from_toml_str(&bad, "t.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("setpoint_rate_weight"), "{e}");
    }
}
