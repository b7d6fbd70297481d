//! Bumpless take-over: the firmware arms on a vented joint 0.6 rad away from its set-point
//! (after a vent, a power-up with empty muscles, a reset after moving the joint by hand).
//! With the start phase (`pam_firmware::tick::StartRamp`) the set-point is ramped from the
//! measured angle and the muscles are pre-charged at a limited rate; without it (an instant
//! start) the position loop saturates at once and drives the valves flat out.

mod common;

use common::config_with;
use host_sim::control::closed_loop::{run_with, ClosedLoopRun, Scenario};
use host_sim::Plant;
use pam_firmware::tick::{ControllerConfig, StartRamp};

const TARGET_RAD: f64 = 0.6;

fn vented_joint() -> Plant {
    let mut c = config_with("");
    c.initial.p1_gauge_pa = 0.0;
    c.initial.p2_gauge_pa = 0.0;
    Plant::from_config(&c)
}

fn hold_at_target() -> Scenario {
    let text = format!(
        "[scenario]\nname = \"take-over\"\nduration_s = 3.0\nseed = 5\n\n[setpoint]\nkind = \"step\"\ninitial_rad = {TARGET_RAD}\nfinal_rad = {TARGET_RAD}\nat_s = 0.0\n"
    );
    Scenario::from_toml_str(&text, "take-over").unwrap_or_else(|e| panic!("{e}"))
}

struct TakeOver {
    /// Ticks in which both muscles' valves were commanded fully open (inflate or exhaust).
    both_full_ticks: usize,
    /// Ticks in which either muscle's valve was commanded fully open.
    any_full_ticks: usize,
    /// Largest angle beyond the target, in the direction of the move [rad].
    overshoot_rad: f64,
    /// |angle error| at the end [rad].
    final_error_rad: f64,
    faulted: bool,
}

fn take_over(cfg: ControllerConfig) -> TakeOver {
    let r: ClosedLoopRun = run_with(&vented_joint(), &hold_at_target(), cfg, &mut |_| {})
        .unwrap_or_else(|e| panic!("{e}"));
    let full = |u: f32| u.abs() >= 1.0;
    let last = r.rows.last().expect("rows");
    TakeOver {
        both_full_ticks: r
            .rows
            .iter()
            .filter(|w| full(w.out.valves.muscle1) && full(w.out.valves.muscle2))
            .count(),
        any_full_ticks: r
            .rows
            .iter()
            .filter(|w| full(w.out.valves.muscle1) || full(w.out.valves.muscle2))
            .count(),
        overshoot_rad: r
            .rows
            .iter()
            .map(|w| w.state.angle_rad - TARGET_RAD)
            .fold(0.0, f64::max),
        final_error_rad: (last.state.angle_rad - TARGET_RAD).abs(),
        faulted: r.first_latched_fault_tick.is_some(),
    }
}

fn report(name: &str, t: &TakeOver) {
    eprintln!(
        "{name}: both valves full {} ticks, any valve full {} ticks, overshoot {:.4} rad, final error {:.4} rad, fault {}",
        t.both_full_ticks, t.any_full_ticks, t.overshoot_rad, t.final_error_rad, t.faulted
    );
}

#[test]
fn a_vented_joint_far_from_its_setpoint_is_taken_over_without_a_bump() {
    let ramped = take_over(ControllerConfig::reference(1000.0));
    let instant = take_over(ControllerConfig {
        start: StartRamp::INSTANT,
        ..ControllerConfig::reference(1000.0)
    });
    report("start phase", &ramped);
    report("instant start", &instant);
    assert!(!ramped.faulted && !instant.faulted);
    // Measured: the start phase 1 tick with both valves flat out (the last correction near
    // the target at 1.18 s), no overshoot; the instant start 43 ticks (both muscles filled
    // flat out from empty), 149 ticks with a valve flat out, 0.016 rad overshoot.
    assert!(ramped.both_full_ticks <= 3, "{}", ramped.both_full_ticks);
    assert!(ramped.any_full_ticks <= 10, "{}", ramped.any_full_ticks);
    assert!(ramped.overshoot_rad <= 0.005, "{}", ramped.overshoot_rad);
    assert!(
        ramped.final_error_rad < 0.015,
        "not settled: {}",
        ramped.final_error_rad
    );
    // The same take-over without the start phase is what the start phase prevents.
    assert!(instant.both_full_ticks >= 20, "{}", instant.both_full_ticks);
    assert!(instant.overshoot_rad > ramped.overshoot_rad);
}
