//! Shared by the property tests (`tests/proptest_control.rs`, `tests/proptest_pid.rs`): input
//! strategies over the whole f32 space and the invariants every control tick output keeps.

#![allow(dead_code)] // each test crate uses its own subset

use pam_firmware::safety::{FaultCode, SafeState};
use pam_firmware::tick::{
    ControlTick, ControllerConfig, SensorFrame, Setpoint, TickOutput, ValveCommand,
};
use pam_firmware::P_MUSCLE_MAX_GAUGE_PA;
use proptest::prelude::*;
use proptest::test_runner::TestCaseError;

/// Mostly `lo..hi`, often any f32, sometimes one of the special values.
pub fn f32_any_or(lo: f32, hi: f32) -> impl Strategy<Value = f32> {
    prop_oneof![
        3 => proptest::num::f32::ANY,
        5 => lo..hi,
        1 => prop::sample::select(vec![
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            0.0,
            -0.0,
            f32::MAX,
            f32::MIN,
            f32::MIN_POSITIVE,
            f32::EPSILON,
        ]),
    ]
}

/// A missing reading now and then.
pub fn opt(s: impl Strategy<Value = f32>) -> impl Strategy<Value = Option<f32>> {
    prop_oneof![1 => Just(None), 6 => s.prop_map(Some)]
}

/// Gauge pressure around the valid range [Pa].
pub fn pressure() -> impl Strategy<Value = f32> {
    f32_any_or(-100_000.0, 800_000.0)
}

/// Joint angle around the valid range [rad].
pub fn angle() -> impl Strategy<Value = f32> {
    f32_any_or(-1.5, 1.5)
}

/// Mostly the nominal 1 ms tick.
pub fn dt() -> impl Strategy<Value = f32> {
    prop_oneof![8 => Just(1e-3f32), 2 => f32_any_or(0.0, 0.01)]
}

/// One tick's sensor readings.
pub fn frame() -> impl Strategy<Value = SensorFrame> {
    (opt(pressure()), opt(pressure()), opt(angle())).prop_map(|(p1, p2, a)| SensorFrame {
        p1_gauge_pa: p1,
        p2_gauge_pa: p2,
        angle_rad: a,
    })
}

/// Every float of a tick output is finite.
pub fn outputs_finite(o: &TickOutput) -> bool {
    [
        o.valves.muscle1,
        o.valves.muscle2,
        o.p1_set_gauge_pa,
        o.p2_set_gauge_pa,
        o.torque_des_nm,
        o.torque_est_nm,
        o.angle_est_rad,
        o.velocity_est_rad_s,
    ]
    .iter()
    .all(|x| x.is_finite())
}

/// The invariants of one tick's output `o` for the input (`f`, `setpoint_rad`, `dt_s`):
/// finite, valve commands in [-1, 1], pressure set-points in [0, 600 kPa]; a non-finite or
/// invalid input raises a fault in the same tick; a fault, once latched (`latched`), stays
/// the same; while faulted the valves are in `safe_cmd` and the law is disarmed.
pub fn check_tick_output(
    o: &TickOutput,
    f: &SensorFrame,
    setpoint_rad: f32,
    dt_s: f32,
    latched: &mut Option<FaultCode>,
    safe_cmd: ValveCommand,
) -> Result<(), TestCaseError> {
    prop_assert!(outputs_finite(o));
    prop_assert!((-1.0..=1.0).contains(&o.valves.muscle1));
    prop_assert!((-1.0..=1.0).contains(&o.valves.muscle2));
    prop_assert!((0.0..=P_MUSCLE_MAX_GAUGE_PA).contains(&o.p1_set_gauge_pa));
    prop_assert!((0.0..=P_MUSCLE_MAX_GAUGE_PA).contains(&o.p2_set_gauge_pa));
    let bad = [f.p1_gauge_pa, f.p2_gauge_pa, f.angle_rad]
        .iter()
        .any(|x| matches!(x, Some(v) if !v.is_finite()))
        || !setpoint_rad.is_finite()
        || !dt_s.is_finite()
        || dt_s <= 0.0;
    if bad {
        prop_assert!(o.fault.is_some());
    }
    if let Some(l) = *latched {
        prop_assert_eq!(o.fault, Some(l));
    }
    if o.fault.is_some() {
        *latched = o.fault;
        // The configured safe state, or a muscle vented by the over-pressure escalation.
        prop_assert!(
            o.valves.muscle1 == safe_cmd.muscle1 || o.valves.muscle1 == -1.0,
            "{:?}",
            o.valves
        );
        prop_assert!(
            o.valves.muscle2 == safe_cmd.muscle2 || o.valves.muscle2 == -1.0,
            "{:?}",
            o.valves
        );
        prop_assert!(!o.armed);
    }
    Ok(())
}

/// Runs `steps` (frame, angle set-point, dt) through a control tick configured by `cfg` with
/// the safe state `Vent` (`vent`) or `Hold`, checks every output with [`check_tick_output`] and
/// hands the armed ones to `armed`.
pub fn run_checked(
    mut cfg: ControllerConfig,
    vent: bool,
    steps: Vec<(SensorFrame, f32, f32)>,
    mut armed: impl FnMut(&TickOutput) -> Result<(), TestCaseError>,
) -> Result<(), TestCaseError> {
    cfg.safe_state = if vent {
        SafeState::Vent
    } else {
        SafeState::Hold
    };
    let safe_cmd = cfg.safe_state.command();
    let mut t = ControlTick::new(cfg);
    let mut latched = None;
    for (f, sp, dt) in steps {
        let o = t.step(&f, &Setpoint { angle_rad: sp }, dt);
        // Finite, bounded, a fault in the tick of a bad input, latched, safe valves.
        check_tick_output(&o, &f, sp, dt, &mut latched, safe_cmd)?;
        if o.armed {
            armed(&o)?;
        }
    }
    Ok(())
}
