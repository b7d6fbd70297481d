//! Firmware in the loop on the full reference plant: every scenario in `scenarios/` is run
//! with the firmware's reference controller and must meet its `[expect]` bounds; pressure
//! set-points never exceed the muscle limit.

mod common;
use common::*;

use host_sim::control::closed_loop::{run, Scenario};
use host_sim::Plant;

fn reference_plant() -> Plant {
    let p = root().join("host-sim/tests/fixtures/reference-1dof.toml");
    Plant::load(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

fn run_scenario(name: &str) -> host_sim::control::closed_loop::ClosedLoopRun {
    let s = Scenario::load(root().join("scenarios").join(format!("{name}.toml"))).unwrap();
    let r = run(&reference_plant(), &s).unwrap();
    let st = r.tracking(s.expect.settle_after_s);
    eprintln!(
        "{name}: rms {:.4} rad, max {:.4} rad after {} s; fault injected {:?}, latched {:?} ({:?}); max p {:.0} kPa, max set {:.0} kPa",
        st.rms_rad,
        st.max_abs_rad,
        s.expect.settle_after_s,
        r.first_injected_fault_tick(),
        r.first_latched_fault_tick,
        r.first_latched_fault_tick.map(|k| r.rows[k].out.fault),
        r.max_p_gauge_pa / 1e3,
        r.max_p_set_gauge_pa / 1e3
    );
    r
}

/// [`run_scenario`], asserting that the run meets the scenario's `[expect]` bounds.
fn assert_expectations(name: &str) -> host_sim::control::closed_loop::ClosedLoopRun {
    let r = run_scenario(name);
    let fails = r.check();
    assert!(fails.is_empty(), "{name}: {fails:?}");
    r
}

#[test]
fn step_settles_within_bound() {
    assert_expectations("step");
}

#[test]
fn ramp_is_tracked() {
    assert_expectations("ramp");
}

#[test]
fn sine_is_tracked() {
    assert_expectations("sine");
}

#[test]
fn random_setpoints_are_tracked() {
    assert_expectations("random");
}

#[test]
fn load_inertia_change_stays_stable() {
    assert_expectations("load_change");
}

#[test]
fn nan_pressure_latches_fault_and_holds_in_the_same_tick() {
    let r = assert_expectations("sensor_nan");
    let k = r.first_latched_fault_tick.unwrap();
    // Safe state (Hold) in that very tick: every valve closed from then on.
    for row in &r.rows[k..] {
        let u = row.inputs;
        assert_eq!(
            [u.u_in1, u.u_ex1, u.u_in2, u.u_ex2],
            [0.0; 4],
            "tick at {} s",
            row.t_s
        );
        assert!(!row.out.armed);
    }
}

#[test]
fn encoder_dropout_is_detected_as_stale() {
    assert_expectations("sensor_dropout");
}

#[test]
fn stuck_inflate_valve_is_seen_by_the_pressure_residual() {
    let r = assert_expectations("stuck_valve");
    // The inflate valve of muscle 1 sticks open at 2.0 s: its pressure climbs with the inlet
    // commanded closed. The pressure residual must latch InletStuckOpen1 within 40 ms of the
    // failure, and not before it.
    let l = r
        .first_latched_fault_tick
        .expect("stuck valve not detected");
    let t_s = r.rows[l].t_s;
    assert_eq!(
        r.rows[l].out.fault,
        Some(pam_firmware::safety::FaultCode::InletStuckOpen1)
    );
    assert!((2.0..=2.04).contains(&t_s), "latched at {t_s} s");
}

/// Every shipped valve / supply fault scenario meets its `[expect]` bounds (detection from the
/// fault's own injection, measured pressure <= 610 kPa, angle in range), and the latched
/// cause is the injected fault.
#[test]
fn valve_and_supply_fault_scenarios_are_detected_and_stay_safe() {
    use pam_firmware::safety::FaultCode::*;
    for (name, causes) in [
        ("stuck_inlet_fast_move", &[InletStuckOpen1][..]),
        ("stuck_inlet_supply_loss", &[InletStuckOpen1][..]),
        ("stuck_exhaust_open", &[ExhaustStuckOpen2][..]),
        ("stuck_inlet_closed", &[InletStuckClosed1][..]),
        ("stuck_exhaust_closed", &[ExhaustStuckClosed2][..]),
        ("supply_loss", &[SupplyLost][..]),
    ] {
        let r = assert_expectations(name);
        let l = r.first_latched_fault_tick.unwrap();
        let cause = r.rows[l].out.fault.unwrap();
        assert!(causes.contains(&cause), "{name}: cause {cause:?}");
        assert_eq!(r.fallback_ticks, 0, "{name}");
    }
}

#[test]
fn supply_loss_never_commands_above_limit() {
    assert_expectations("supply_loss");
}

/// `transition_s` turns a step into a minimum-jerk move: the set-point starts at the old
/// value at `at_s`, is half-way at `at_s + T/2`, arrives at `at_s + T`, and never moves by
/// more than the quintic's peak rate (1.875 x step / T) per tick; the random profile does the
/// same into every level, from the previous one.
#[test]
fn transition_s_makes_set_point_changes_minimum_jerk_moves() {
    let plant = reference_plant();
    let step = Scenario::load(root().join("scenarios/suite/step_move.toml")).unwrap();
    let r = run(&plant, &step).unwrap();
    let at = |t: f64| {
        r.rows
            .iter()
            .find(|row| (row.t_s - t).abs() < 1e-9)
            .unwrap_or_else(|| panic!("no tick at {t} s"))
            .setpoint_rad
    };
    // 0 -> 0.2 rad at 1.0 s over 0.15 s.
    assert_eq!(at(0.999), 0.0);
    assert_eq!(at(1.0), 0.0);
    assert!((at(1.075) - 0.1).abs() < 1e-12, "{}", at(1.075));
    assert!((at(1.15) - 0.2).abs() < 1e-12);
    assert_eq!(at(2.0), 0.2);
    let peak_rate = 1.875 * 0.2 / 0.15;
    let max_step = r
        .rows
        .windows(2)
        .map(|w| (w[1].setpoint_rad - w[0].setpoint_rad).abs())
        .fold(0.0, f64::max);
    assert!(max_step <= peak_rate * r.dt_s * 1.0001 && max_step > 0.9 * peak_rate * r.dt_s);

    // The same levels as the jump scenario, reached by moves.
    let jumps = run(
        &plant,
        &Scenario::load(root().join("scenarios/random.toml")).unwrap(),
    )
    .unwrap();
    let moves = run(
        &plant,
        &Scenario::load(root().join("scenarios/suite/random_move.toml")).unwrap(),
    )
    .unwrap();
    let mut checked = 0;
    for (a, b) in jumps.rows.iter().zip(&moves.rows) {
        let since = (a.t_s - 0.5).rem_euclid(1.0);
        if a.t_s >= 0.5 && since >= 0.15 + 1e-9 {
            assert_eq!(a.setpoint_rad, b.setpoint_rad, "t = {}", a.t_s);
            checked += 1;
        }
    }
    assert!(checked > 6000);
    let max_move = moves
        .rows
        .windows(2)
        .map(|w| (w[1].setpoint_rad - w[0].setpoint_rad).abs())
        .fold(0.0, f64::max);
    // Levels within +-0.3 rad: no change larger than 0.6 rad, so no tick moves more than
    // the quintic's peak rate for 0.6 rad in 0.15 s.
    assert!(
        max_move <= 1.875 * 0.6 / 0.15 * moves.dt_s * 1.0001,
        "{max_move}"
    );
}

#[test]
fn transition_longer_than_the_hold_is_rejected_with_file_line_and_key() {
    // A suite scenario with its transition_s replaced by `to`: (its text, the load error).
    let edited = |file: &str, to: &str| {
        let text = std::fs::read_to_string(root().join("scenarios/suite").join(file))
            .unwrap()
            .replace("transition_s = 0.15", to);
        let e = Scenario::from_toml_str(&text, file)
            .unwrap_err()
            .to_string();
        (text, e)
    };
    let (text, e) = edited("random_move.toml", "transition_s = 1.5");
    let line = text
        .lines()
        .position(|l| l.starts_with("transition_s"))
        .unwrap()
        + 1;
    assert!(e.contains("random_move.toml"), "{e}");
    assert!(e.contains("transition_s"), "{e}");
    assert!(e.contains(&format!("line {line}")), "{e}");
    let (_, e) = edited("step_move.toml", "transition_s = -0.1");
    assert!(e.contains("transition_s") && e.contains(">= 0"), "{e}");
}

#[test]
fn comparison_suite_moves_are_tracked_with_the_default_gains() {
    assert_expectations("suite/step_move");
    assert_expectations("suite/random_move");
}

/// The reference gains over the board's whole allowed tick range (`PAM_TICK_HZ` 200..10000):
/// the step scenario at both ends meets its `[expect]` bounds (settled within 0.01 rad, no
/// fault) and shows no limit cycle: the joint angle's peak-to-peak over the last second stays
/// within the scenario's own error bound (0.01 rad; a 50 Hz tick, outside the range,
/// oscillates by +-7 deg = 0.24 rad peak-to-peak). 1 kHz (the default) is run for comparison.
#[test]
fn step_is_stable_at_both_ends_of_the_allowed_tick_range() {
    for tick_hz in [200.0, 1000.0, 10_000.0] {
        let mut s = Scenario::load(root().join("scenarios/step.toml")).unwrap();
        s.scenario.tick_hz = tick_hz;
        let r = run(&reference_plant(), &s).unwrap();
        let fails = r.check();
        let tail: Vec<f64> = r
            .rows
            .iter()
            .filter(|row| row.t_s >= s.scenario.duration_s - 1.0)
            .map(|row| row.state.angle_rad)
            .collect();
        let hi = tail.iter().cloned().fold(f64::MIN, f64::max);
        let lo = tail.iter().cloned().fold(f64::MAX, f64::min);
        let st = r.tracking(s.expect.settle_after_s);
        eprintln!(
            "step at {tick_hz} Hz: max error {:.5} rad after {} s, last-second peak-to-peak {:.5} rad, fault {:?}",
            st.max_abs_rad, s.expect.settle_after_s, hi - lo, r.first_latched_fault_tick.map(|k| r.rows[k].out.fault)
        );
        assert!(fails.is_empty(), "step at {tick_hz} Hz: {fails:?}");
        assert!(
            !tail.is_empty()
                && hi - lo
                    < s.expect
                        .max_abs_error_rad
                        .expect("step.toml bounds the error"),
            "step at {tick_hz} Hz: limit cycle, peak-to-peak {} rad",
            hi - lo
        );
    }
}
