//! The valve supervision on a muscle whose gas heats and cools (the plant's thermal chamber,
//! hA 2 W/K, kappa 1.4): the runs of the feed-forward comparison in which its isothermal
//! model used to read the gas cooling after a fill, or a vent of hot gas, as a stuck valve.
//! These are the cases the supervision's heat allowances were designed on (regressions); the
//! independent checks are the unit test with its own chamber energy balance
//! (`residual::tests`) and the loaded plant of `docs/control.md`.

use host_sim::control::closed_loop::Scenario;
use host_sim::control::compare::{
    default_control_tuning, default_control_tuning_ff, jump_suite_scenarios,
};
use host_sim::control::compare_ff::{controllers, score, variant_plant};
use host_sim::control::robustness::held_out_scenarios;
use host_sim::Plant;
use pam_firmware::tick::ControllerConfig;

fn thermal_plant() -> Plant {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/reference-1dof.toml");
    variant_plant(&path, "thermal chamber").unwrap()
}

fn row(name: &str) -> ControllerConfig {
    let (tuning, _) = default_control_tuning().unwrap();
    let (tuning_ff, _) = default_control_tuning_ff().unwrap();
    let base = tuning.cascade.config(1000.0);
    let retuned = ControllerConfig {
        pressure_ff: base.pressure_ff,
        outer_period_ticks: base.outer_period_ticks,
        ..tuning_ff.cascade.config(1000.0)
    };
    controllers(base, None, Some(retuned))
        .into_iter()
        .find(|(n, _)| n.starts_with(name))
        .unwrap_or_else(|| panic!("no row {name}"))
        .1
}

fn pick(set: Vec<Scenario>, name: &str) -> Scenario {
    set.into_iter()
        .find(|s| s.scenario.name == name)
        .unwrap_or_else(|| panic!("no scenario {name}"))
}

#[test]
fn fills_and_vents_on_a_chamber_exchanging_heat_latch_no_valve_fault() {
    let plant = thermal_plant();
    let jumps = || jump_suite_scenarios().unwrap();
    let moves = || held_out_scenarios().unwrap();
    let diagnostic = "P only at the gains re-tuned";
    let cases = [
        // A long fill, then an inlet pulse beside a vent: read as a stuck-closed inlet.
        (diagnostic, pick(jumps(), "step")),
        (diagnostic, pick(jumps(), "random")),
        (diagnostic, pick(moves(), "random_move_seed12")),
        // The same on muscle 2, read as a stuck-open exhaust.
        (
            "+ analytical inverse model, k = 1.4",
            pick(moves(), "random_move_seed12"),
        ),
        ("+ analytical, k = 1, P' and V'", pick(jumps(), "step")),
    ];
    for (r, s) in cases {
        let f = score(&plant, std::slice::from_ref(&s), row(r)).unwrap();
        assert!(
            f.faults.is_empty(),
            "{r} / {}: {:?}",
            s.scenario.name,
            f.faults
        );
    }
}
