//! The robustness table of the stored gains (no re-tuning): `config/control_tuned.toml`'s
//! cascade, PD and PID on the held-out set-point suite and on the tuning suite, each under the
//! nominal plant and every concealed effect of `control::robustness::CONDITIONS`.
//!
//! ```sh
//! cargo run --release -p host-sim --example robustness [-- PLANT.toml]
//! ```

use anyhow::{Context, Result};
use host_sim::control::compare::{
    control_tuned_path, reference_plant_path, suite_scenarios, ControlTuning,
};
use host_sim::control::robustness::{format_table, held_out_scenarios, table};

fn main() -> Result<()> {
    let plant = match std::env::args().nth(1) {
        Some(p) => p.into(),
        None => reference_plant_path().context("pass the plant file")?,
    };
    let text = std::fs::read_to_string(&plant).with_context(|| plant.display().to_string())?;
    let tuning = ControlTuning::load(&control_tuned_path())?;
    for (title, scenarios) in [
        ("Held-out set-point suite", held_out_scenarios()?),
        ("Tuning suite", suite_scenarios()?),
    ] {
        let t0 = std::time::Instant::now();
        let rows = table(&text, &tuning, &scenarios, &[]);
        println!(
            "{title} ({} scenarios, {:.0} s)\n\n{}",
            scenarios.len(),
            t0.elapsed().as_secs_f64(),
            format_table(&rows)
        );
    }
    Ok(())
}
