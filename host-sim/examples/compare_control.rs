//! The closed-loop comparison (seed 004 Table 3): the model-based cascade with the
//! identified constants against the tuned PD and PID of `config/control_tuned.toml`, firmware in
//! the loop on the reference plant, step / sine / random suite (`control::compare::SUITE`:
//! set-point changes as 0.15 s minimum-jerk moves). Prints the MSE table (the one in README),
//! then the same laws on the jump suite (the demo's step / sine / random, changes as jumps) for
//! reference, and exits with status 1 when the cascade's suite MSE is not at least 2x lower
//! than the best tuned PD / PID on the suite.
//!
//! ```sh
//! cargo run --release -p host-sim --example compare_control [-- PLANT.toml [CONTROL_TUNED.toml]]
//! ```

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, Result};
use host_sim::control::compare::{
    compare, compare_on, control_tuned_path, format_table, jump_suite_scenarios,
    reference_plant_path, ControlTuning,
};
use host_sim::Plant;

fn main() -> ExitCode {
    match run() {
        Ok(c) => c,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(2)
        }
    }
}

fn run() -> Result<ExitCode> {
    let mut args = std::env::args().skip(1);
    let plant_path = match args.next() {
        Some(p) => PathBuf::from(p),
        None => reference_plant_path()
            .context("cannot find host-sim/plants/reference-1dof.toml; pass PLANT.toml")?,
    };
    let tuning_path = args
        .next()
        .map(PathBuf::from)
        .unwrap_or_else(control_tuned_path);
    let plant = Plant::load(&plant_path)?;
    let tuning = ControlTuning::load(&tuning_path)?;
    let t0 = Instant::now();
    let rows = compare(&plant, &tuning)?;
    println!(
        "plant {}, gains {}, suite scenarios/suite/step_move.toml, scenarios/sine.toml, scenarios/suite/random_move.toml; MSE of the angle over every tick",
        plant_path.display(),
        tuning_path.display()
    );
    println!("plant effects: {}", plant.effects_summary());
    println!();
    print!("{}", format_table(&rows));
    let cascade = rows[0].score.mse_rad2;
    let best = rows[1..]
        .iter()
        .map(|r| r.score.mse_rad2)
        .fold(f64::INFINITY, f64::min);
    let ratio = best / cascade;
    let jumps = compare_on(&plant, &tuning, &jump_suite_scenarios()?)?;
    println!();
    println!("the same gains on the jump suite (scenarios/step.toml, sine.toml, random.toml):");
    println!();
    print!("{}", format_table(&jumps));
    println!();
    println!(
        "best tuned PD/PID suite MSE / cascade suite MSE = {ratio:.2} (required >= 2); {:.1} s",
        t0.elapsed().as_secs_f64()
    );
    Ok(if ratio >= 2.0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}
