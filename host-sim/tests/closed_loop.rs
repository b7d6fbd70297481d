//! Firmware in the loop on the full reference plant: every scenario in `scenarios/` is run
//! with the firmware's reference controller and must meet its `[expect]` bounds; pressure
//! set-points never exceed the muscle limit.

use std::path::PathBuf;

use host_sim::closed_loop::{run, Scenario};
use host_sim::Plant;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn reference_plant() -> Plant {
    let p = root().join("../shared/plant/reference-1dof.toml");
    Plant::load(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

fn run_scenario(name: &str) -> host_sim::closed_loop::ClosedLoopRun {
    let s = Scenario::load(root().join("scenarios").join(format!("{name}.toml"))).unwrap();
    let r = run(&reference_plant(), &s).unwrap();
    let st = r.tracking(s.expect.settle_after_s);
    eprintln!(
        "{name}: rms {:.4} rad, max {:.4} rad after {} s; fault injected {:?}, latched {:?} ({:?}); max p {:.0} kPa, max set {:.0} kPa",
        st.rms_rad,
        st.max_abs_rad,
        s.expect.settle_after_s,
        r.first_injected_fault_tick,
        r.first_latched_fault_tick,
        r.first_latched_fault_tick.map(|k| r.rows[k].out.fault),
        r.max_p_gauge_pa / 1e3,
        r.max_p_set_gauge_pa / 1e3
    );
    r
}

fn assert_expectations(name: &str) {
    let r = run_scenario(name);
    let fails = r.check();
    assert!(fails.is_empty(), "{name}: {fails:?}");
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
    let r = run_scenario("sensor_nan");
    assert!(r.check().is_empty(), "{:?}", r.check());
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
    let r = run_scenario("sensor_dropout");
    assert!(r.check().is_empty(), "{:?}", r.check());
}

#[test]
fn stuck_inflate_valve_latches_pressure_tracking_lost() {
    let r = run_scenario("stuck_valve");
    assert!(r.check().is_empty(), "{:?}", r.check());
    // The inflate valve of muscle 1 sticks open at 2.0 s: its pressure climbs towards supply
    // while the pressure loop exhausts at full command. The firmware must latch
    // PressureTrackingLost1 (0.3 s of saturated command against a > 100 kPa gap) within
    // 0.5 s of the failure, and not before it.
    let l = r
        .first_latched_fault_tick
        .expect("stuck valve not detected");
    let t_s = r.rows[l].t_s;
    assert_eq!(
        r.rows[l].out.fault,
        Some(pam_firmware::safety::FaultCode::PressureTrackingLost1)
    );
    assert!((2.0..=2.5).contains(&t_s), "latched at {t_s} s");
}

#[test]
fn supply_loss_never_commands_above_limit() {
    let r = run_scenario("supply_loss");
    assert!(r.check().is_empty(), "{:?}", r.check());
}
