//! The cascade tuned with the pressure loops' inverse thermodynamic feed-forward on
//! (`config/control_tuned_ff.toml`, written by `host-sim tune --pressure-ff`): the file is the
//! tuner's result, its gains are a local optimum of the same tuning cost as the P-only
//! cascade's, and they need the feed-forward (the same gains without it cost more: the
//! feed-forward is what makes the higher position gains usable). `compare-control`'s verdict
//! compares this cascade against `config/control_tuned.toml`'s, each at its own gains.

mod common;

use std::path::PathBuf;

use common::assert_cascade_local_optimum;
use host_sim::control::compare::{
    suite_scenarios, tuning_cost, ControlTuning, CONTROL_TUNED_FF_TOML, CONTROL_TUNED_TOML,
};
use host_sim::Plant;

fn reference_plant() -> Plant {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/reference-1dof.toml");
    Plant::load(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

fn load(rel: &str) -> ControlTuning {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(rel);
    ControlTuning::load(&p).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn the_feed_forward_cascade_re_measures_its_stored_cost_and_runs_with_the_feed_forward_on() {
    let t = load(CONTROL_TUNED_FF_TOML);
    assert!(t.cascade.pressure_feedforward);
    let cfg = t.cascade.config(1000.0);
    assert!(cfg.pressure_ff.enabled);
    let (_, nominal, margin) = tuning_cost(&reference_plant(), &suite_scenarios().unwrap(), cfg);
    for (what, measured, stored) in [
        ("suite", nominal, t.cascade.suite_mse_rad2),
        (
            "at the gain margin",
            margin,
            t.cascade.suite_mse_at_margin_rad2,
        ),
    ] {
        assert!(
            ((measured - stored) / stored).abs() < 1e-6,
            "{what}: measured {measured:e} rad^2, stored {stored:e} rad^2"
        );
    }
    // The P-only file's cascade does not run the feed-forward.
    let p_only = load(CONTROL_TUNED_TOML);
    assert!(!p_only.cascade.pressure_feedforward);
    assert!(!p_only.cascade.config(1000.0).pressure_ff.enabled);
}

#[test]
fn the_feed_forward_cascade_is_a_local_optimum_and_needs_the_feed_forward() {
    let plant = reference_plant();
    let sc = suite_scenarios().unwrap();
    let t = load(CONTROL_TUNED_FF_TOML);
    let base = assert_cascade_local_optimum(&plant, &sc, &t.cascade);
    let c0 = t
        .cascade
        .suite_mse_rad2
        .max(t.cascade.suite_mse_at_margin_rad2);
    // Without the feed-forward, the same gains cost more than the P-only cascade's own tuning:
    // the P-only loop cannot use them.
    let mut off = base;
    off.pressure_ff.enabled = false;
    let (c_off, ..) = tuning_cost(&plant, &sc, off);
    let p_only = load(CONTROL_TUNED_TOML).cascade;
    let c_p_only = p_only.suite_mse_rad2.max(p_only.suite_mse_at_margin_rad2);
    eprintln!(
        "feed-forward cascade {c0:.4e} rad^2; same gains without it {c_off:.4e}; P-only cascade at its own gains {c_p_only:.4e}"
    );
    assert!(c_off > c_p_only && c_p_only > c0, "{c_off} {c_p_only} {c0}");
}

/// The file was tuned with `--stable-on-jumps`: the suite and the jump suite stay stable on the
/// plant and come to rest (the tuner's constraint holds for the stored gains); the same gains
/// without the feed-forward do not.
#[test]
fn the_feed_forward_cascade_comes_to_rest_after_jumps() {
    use host_sim::control::compare::jump_suite_scenarios;
    use host_sim::control::robustness::stable_with_margin_on;
    let plant = reference_plant();
    let mut sc = suite_scenarios().unwrap();
    sc.extend(jump_suite_scenarios().unwrap());
    let t = load(CONTROL_TUNED_FF_TOML);
    let cfg = t.cascade.config(1000.0);
    assert!(stable_with_margin_on(&plant, &sc, cfg));
    let mut off = cfg;
    off.pressure_ff.enabled = false;
    assert!(!stable_with_margin_on(&plant, &sc, off));
}
