//! The robustness table of the stored gains (no re-tuning): `config/control_tuned.toml`'s
//! cascade, PD and PID on the held-out set-point suite and on the tuning suite, each under the
//! nominal plant and every concealed effect of `control::robustness::CONDITIONS`.
//!
//! ```sh
//! cargo run --release -p host-sim --example robustness [-- PLANT.toml [GAINS.toml]]
//! ```
//!
//! Tables for the held-out sequences, the tuning suite and the jump suite (the demo's
//! set-points). After them: the MSE of every held-out scenario for each law on the nominal
//! plant, with the valve dead time and on the 11 x load (where the cascade's lead comes from,
//! or goes).

use anyhow::{Context, Result};
use host_sim::control::compare::{
    config_for, control_tuned_path, jump_suite_scenarios, reference_plant_path, score_suite_with,
    suite_scenarios, ControlTuning,
};
use host_sim::control::robustness::{
    condition_config, condition_plant, format_table, held_out_scenarios, table, CONDITIONS,
};
use pam_firmware::tick::ControlLaw;

fn main() -> Result<()> {
    let plant = match std::env::args().nth(1) {
        Some(p) => p.into(),
        None => reference_plant_path().context("pass the plant file")?,
    };
    let text = std::fs::read_to_string(&plant).with_context(|| plant.display().to_string())?;
    // The gains file scored: config/control_tuned.toml unless given (e.g.
    // config/control_robust.toml, the gains of `host-sim tune --robust`).
    let gains = match std::env::args().nth(2) {
        Some(g) => g.into(),
        None => control_tuned_path(),
    };
    let tuning = ControlTuning::load(&gains)?;
    println!("gains: {}\n", gains.display());
    for (title, scenarios) in [
        ("Held-out set-point suite", held_out_scenarios()?),
        ("Tuning suite", suite_scenarios()?),
        ("Jump suite", jump_suite_scenarios()?),
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
    // Per scenario: cascade, PD, PID MSE [rad^2] and max |error| [rad].
    let laws = [
        ("cascade", tuning.cascade.config(1000.0)),
        (
            "PD",
            config_for(ControlLaw::DirectPid(tuning.pd.gains()), 1000.0),
        ),
        (
            "PID",
            config_for(ControlLaw::DirectPid(tuning.pid.gains()), 1000.0),
        ),
    ];
    let held_out = held_out_scenarios()?;
    for (name, effects, inertia) in CONDITIONS
        .iter()
        .filter(|c| c.0 == "nominal" || c.0.starts_with("valve dead time") || c.2 != 1.0)
    {
        let plant = condition_plant(&text, effects, *inertia);
        println!("Held-out scenarios, {name}: MSE [rad^2] (max |error| [rad])\n");
        println!("| scenario | cascade | PD | PID | PID / cascade |\n|---|---|---|---|---|");
        let scores: Vec<_> = laws
            .iter()
            .map(|(_, c)| score_suite_with(&plant, &held_out, condition_config(name, *c)))
            .collect();
        for (i, sc) in held_out.iter().enumerate() {
            let cell = |k: usize| match &scores[k] {
                Ok(s) => {
                    if let Some(f) = &s.scenarios[i].fault {
                        println!(
                            "({name}, {}: {} latched {f:?})",
                            sc.scenario.name, laws[k].0
                        );
                    }
                    (s.scenarios[i].mse_rad2, s.scenarios[i].max_abs_rad)
                }
                Err(_) => (f64::INFINITY, f64::INFINITY),
            };
            let (c, p, d) = (cell(0), cell(1), cell(2));
            println!(
                "| {} | {:.3e} ({:.3}) | {:.3e} ({:.3}) | {:.3e} ({:.3}) | {:.2} |",
                sc.scenario.name,
                c.0,
                c.1,
                p.0,
                p.1,
                d.0,
                d.1,
                d.0 / c.0
            );
        }
        println!();
    }
    Ok(())
}
