//! How the closed-loop comparison (cascade vs PD / PID) depends on how fast the set-point moves: the
//! step and random scenarios of the jump suite (`scenarios/step.toml`, `random.toml`) with
//! each set-point change made a minimum-jerk move of duration T (`transition_s`), T = 0 the
//! jumps themselves; the sine is unchanged. The cascade with the firmware's default gains
//! (`ControllerConfig::reference`) and the cascade, PD and PID of `config/control_tuned.toml`
//! (or the file given; tuned for T = 0.15 s), firmware in the loop on the reference plant. The
//! gains are NOT retuned per T. The last column is how the comparison suite's T was chosen:
//! the share of ticks in which the default cascade drives a valve at full scale.
//!
//! ```sh
//! cargo run --release -p host-sim --example suite_transition [-- CONTROL_TUNED.toml [T_s ...]]
//! ```

use std::path::PathBuf;

use anyhow::{Context, Result};
use host_sim::control::closed_loop::{run, Scenario, SetpointProfile};
use host_sim::control::compare::{
    control_tuned_path, jump_suite_scenarios, reference_plant_path, score_suite, score_suite_with,
    ControlTuning,
};
use host_sim::Plant;
use pam_firmware::tick::ControlLaw;

fn with_transition(scenarios: &[Scenario], t_s: f64) -> Vec<Scenario> {
    scenarios
        .iter()
        .cloned()
        .map(|mut s| {
            s.set_transition_s(t_s);
            s
        })
        .collect()
}

/// Percentage of the ticks of the step and random runs, from the first set-point move on, in
/// which the cascade commands a valve at full scale (|command| >= 0.999): the set-point moves
/// faster than the valves follow. (Before the first move both muscles fill from 0 to p0 with
/// the valves fully open; those ticks are not counted.)
fn cascade_saturated_pct(plant: &Plant, scenarios: &[Scenario]) -> Result<f64> {
    let (mut sat, mut n) = (0usize, 0usize);
    for s in scenarios {
        let first_move_s = match s.setpoint {
            SetpointProfile::Step { at_s, .. } => at_s,
            SetpointProfile::Random { start_s, .. } => start_s,
            _ => continue,
        };
        let r = run(plant, s)?;
        for row in r.rows.iter().filter(|row| row.t_s >= first_move_s) {
            n += 1;
            let v = row.out.valves;
            if v.muscle1.abs() >= 0.999 || v.muscle2.abs() >= 0.999 {
                sat += 1;
            }
        }
    }
    Ok(100.0 * sat as f64 / n.max(1) as f64)
}

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let tuning_path = args
        .next()
        .map(PathBuf::from)
        .unwrap_or_else(control_tuned_path);
    let mut ts: Vec<f64> = args
        .map(|a| a.parse::<f64>().with_context(|| format!("bad T {a:?}")))
        .collect::<Result<_>>()?;
    if ts.is_empty() {
        ts = vec![0.0, 0.05, 0.1, 0.2, 0.3, 0.5];
    }
    let plant_path = reference_plant_path().context("cannot find reference-1dof.toml")?;
    let plant = Plant::load(&plant_path)?;
    let tuning = ControlTuning::load(&tuning_path)?;
    let base = jump_suite_scenarios()?;
    let deg2 = (180.0 / std::f64::consts::PI).powi(2);
    println!("gains {}", tuning_path.display());
    println!("| T [s] | cascade, default gains [deg^2] | cascade, tuned [deg^2] | PD [deg^2] | PID [deg^2] | PID / tuned cascade | default cascade: valve at full scale [% of step + random ticks after the first move] |");
    println!("|---:|---:|---:|---:|---:|---:|---:|");
    for t in ts {
        let sc = with_transition(&base, t);
        let c = score_suite(&plant, &sc, ControlLaw::Cascade)?.mse_rad2;
        let ct = score_suite_with(&plant, &sc, tuning.cascade.config(1000.0))?.mse_rad2;
        let pd = score_suite(&plant, &sc, ControlLaw::DirectPid(tuning.pd.gains()))?.mse_rad2;
        let pid = score_suite(&plant, &sc, ControlLaw::DirectPid(tuning.pid.gains()))?.mse_rad2;
        let sat = cascade_saturated_pct(&plant, &sc)?;
        println!(
            "| {t:.2} | {:.4} | {:.4} | {:.4} | {:.4} | {:.2} | {sat:.2} |",
            c * deg2,
            ct * deg2,
            pd * deg2,
            pid * deg2,
            pid / ct
        );
    }
    Ok(())
}
