//! Property tests of the model-free baseline law (`pam_firmware::pid`) and of the control
//! tick running it (`ControlLaw::DirectPid`): over the whole f32 input space (NaN, +-inf,
//! huge values, mixed with realistic ones) the law never panics, never emits a non-finite
//! value, keeps both set-points in [0, 600 kPa] and symmetric about p0, and refuses bad
//! input with an error; the tick with it faults on bad input and never outputs NaN. Also the
//! cascade's trajectory feed-forward (`pam_firmware::feedforward`) in the tick.

use pam_firmware::control::{ControlError, JointState};
use pam_firmware::pid::{DpPid, DpPidGains};
use pam_firmware::tick::{
    ControlLaw, ControlTick, ControllerConfig, SensorFrame, Setpoint, StartRamp,
};
use pam_firmware::P_MUSCLE_MAX_GAUGE_PA;
use proptest::prelude::*;

mod common;
use common::{dt, f32_any_or, frame};

/// Both muscles at 300 kPa gauge, the joint at `angle_rad`.
fn frame_at(angle_rad: f32) -> SensorFrame {
    SensorFrame {
        p1_gauge_pa: Some(300e3),
        p2_gauge_pa: Some(300e3),
        angle_rad: Some(angle_rad),
    }
}

/// `cfg` is refused (`is_valid`), and the tick built from it latches a fault at its first
/// step on good sensor data instead of arming; the tick is returned.
fn assert_config_fault(cfg: ControllerConfig, setpoint_rad: f32) -> ControlTick {
    assert!(!cfg.is_valid());
    let mut t = ControlTick::new(cfg);
    let o = t.step(
        &frame_at(0.0),
        &Setpoint {
            angle_rad: setpoint_rad,
        },
        1e-3,
    );
    assert!(o.fault.is_some() && !o.armed, "{o:?}");
    t
}

fn realistic_gains() -> impl Strategy<Value = DpPidGains> {
    (
        0.0f32..1e7,
        0.0f32..1e7,
        0.0f32..1e5,
        0.0f32..=1.0,
        0.0f32..200.0,
        0.0f32..3e5,
        0.0f32..6e5,
        0.0f32..=6e5,
    )
        .prop_map(gains)
}

/// The gains of a drawn tuple (kp, ki, kd, w, fc, i_limit, dp_max, p0).
fn gains((kp, ki, kd, w, fc, il, dpm, p0): (f32, f32, f32, f32, f32, f32, f32, f32)) -> DpPidGains {
    DpPidGains {
        kp_pa_per_rad: kp,
        ki_pa_per_rad_s: ki,
        kd_pa_s_per_rad: kd,
        setpoint_rate_weight: w,
        setpoint_rate_cutoff_hz: fc,
        i_limit_pa: il,
        dp_max_pa: dpm,
        p0_gauge_pa: p0,
    }
}

fn any_gains() -> impl Strategy<Value = DpPidGains> {
    prop_oneof![
        4 => realistic_gains(),
        1 => (
            f32_any_or(0.0, 1e7),
            f32_any_or(0.0, 1e7),
            f32_any_or(0.0, 1e5),
            f32_any_or(0.0, 1.0),
            f32_any_or(0.0, 200.0),
            f32_any_or(0.0, 3e5),
            f32_any_or(0.0, 6e5),
            f32_any_or(0.0, 6e5),
        )
            .prop_map(gains),
    ]
}

fn tuned_like() -> DpPidGains {
    DpPidGains {
        kp_pa_per_rad: 1e6,
        ki_pa_per_rad_s: 3e5,
        kd_pa_s_per_rad: 1e4,
        setpoint_rate_weight: 1.0,
        setpoint_rate_cutoff_hz: 20.0,
        i_limit_pa: 150_000.0,
        dp_max_pa: 280_000.0,
        p0_gauge_pa: 300_000.0,
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(1000))]

    #[test]
    fn law_never_nan_bounded_symmetric_and_errors_on_bad_input(
        g in any_gains(),
        steps in prop::collection::vec(
            (f32_any_or(-1.5, 1.5), f32_any_or(-20.0, 20.0), f32_any_or(-1.0, 1.0), dt()),
            1..60),
    ) {
        let mut c = DpPid::new(g);
        for (a, v, sp, dt) in steps {
            let r = c.step(JointState { angle_rad: a, velocity_rad_s: v }, sp, dt);
            let bad_input = !(a.is_finite() && v.is_finite() && sp.is_finite() && dt.is_finite())
                || dt <= 0.0;
            if bad_input {
                prop_assert_eq!(r, Err(ControlError::NonFiniteInput));
            }
            if !g.is_valid() {
                prop_assert!(r.is_err());
            }
            match r {
                Ok(o) => {
                    prop_assert!(o.dp_pa.is_finite());
                    prop_assert!((0.0..=P_MUSCLE_MAX_GAUGE_PA).contains(&o.p1_gauge_pa));
                    prop_assert!((0.0..=P_MUSCLE_MAX_GAUGE_PA).contains(&o.p2_gauge_pa));
                    prop_assert!(o.dp_pa.abs() <= g.dp_limit_pa());
                    // p1 = p0 - dp, p2 = p0 + dp (|dp| is limited so neither is clamped).
                    let tol = 1e-6 * g.p0_gauge_pa.max(1.0) + 0.1;
                    prop_assert!((o.p1_gauge_pa - (g.p0_gauge_pa - o.dp_pa)).abs() <= tol);
                    prop_assert!((o.p2_gauge_pa - (g.p0_gauge_pa + o.dp_pa)).abs() <= tol);
                    prop_assert!(c.integral_pa().abs() <= g.i_limit_pa);
                }
                Err(_) => {
                    // An error always leaves a clean state.
                    prop_assert_eq!(c.integral_pa(), 0.0);
                    prop_assert_eq!(c.setpoint_rate_rad_s(), 0.0);
                }
            }
        }
    }

    #[test]
    fn tick_with_pid_never_nan_faults_on_bad_input(
        steps in prop::collection::vec((frame(), f32_any_or(-1.5, 1.5), dt()), 1..80),
        vent in any::<bool>(),
    ) {
        let mut cfg = ControllerConfig::reference(1000.0);
        cfg.law = ControlLaw::DirectPid(tuned_like());
        // The PID drives dp directly: no joint torque is ever asked for.
        common::run_checked(cfg, vent, steps, |o| {
            prop_assert_eq!(o.torque_des_nm, 0.0);
            Ok(())
        })?;
    }

    #[test]
    fn tick_with_invalid_pid_gains_latches_config_fault(
        kp in prop_oneof![Just(f32::NAN), Just(-1.0f32), Just(f32::INFINITY)],
    ) {
        let mut cfg = ControllerConfig::reference(1000.0);
        cfg.law = ControlLaw::DirectPid(DpPidGains { kp_pa_per_rad: kp, ..tuned_like() });
        let mut t = assert_config_fault(cfg, 0.1);
        prop_assert!(!t.reset());
    }
}

#[test]
fn tick_with_pid_drives_a_positive_step_like_the_cascade() {
    // Same sign convention as the cascade: a positive angle error raises muscle 1 and lowers
    // muscle 2, through the same pressure loops.
    // An instant start (no start-phase ramp): the step acts in the first tick.
    let instant = StartRamp::INSTANT;
    let mut cfg = ControllerConfig::reference(1000.0);
    cfg.law = ControlLaw::DirectPid(tuned_like());
    cfg.start = instant;
    let mut pid = ControlTick::new(cfg);
    let mut cascade = ControlTick::new(ControllerConfig {
        start: instant,
        ..ControllerConfig::reference(1000.0)
    });
    let f = frame_at(0.0);
    let sp = Setpoint { angle_rad: 0.2 };
    let a = pid.step(&f, &sp, 1e-3);
    let b = cascade.step(&f, &sp, 1e-3);
    for o in [a, b] {
        assert!(o.armed && o.fault.is_none());
        assert!(
            o.p1_set_gauge_pa > 300e3 && o.p2_set_gauge_pa < 300e3,
            "{o:?}"
        );
        assert!(o.valves.muscle1 > 0.0 && o.valves.muscle2 < 0.0);
    }
    // kp e = 1e6 * 0.2 = 200 kPa (no rate on the first tick, integrator 1 ms old).
    assert!((a.p1_set_gauge_pa - 500e3).abs() < 100.0, "{a:?}");
    assert!((a.p2_set_gauge_pa - 100e3).abs() < 100.0, "{a:?}");
}

#[test]
fn invalid_feedforward_latches_config_fault() {
    use pam_firmware::feedforward::FeedforwardGains;
    for ff in [
        FeedforwardGains {
            rate_weight: f32::NAN,
            ..ControllerConfig::reference(1000.0).feedforward
        },
        FeedforwardGains {
            rate_weight: 1.5,
            ..ControllerConfig::reference(1000.0).feedforward
        },
        FeedforwardGains {
            inertia_kgm2: -0.1,
            ..ControllerConfig::reference(1000.0).feedforward
        },
    ] {
        let mut cfg = ControllerConfig::reference(1000.0);
        cfg.feedforward = ff;
        assert_config_fault(cfg, 0.0);
    }
}

#[test]
fn cascade_feedforward_adds_kd_times_setpoint_rate_on_a_ramp() {
    // The angle sits exactly on a 0.5 rad/s ramp and moves with it (velocity estimate from
    // the angle samples): with w = 1 the derivative acts on the error, so the desired torque
    // no longer brakes the motion; without the feed-forward it brakes by ~kd * 0.5 N m.
    use pam_firmware::feedforward::FeedforwardGains;
    let run = |ff: FeedforwardGains| {
        let mut cfg = ControllerConfig::reference(1000.0);
        cfg.feedforward = FeedforwardGains {
            inertia_kgm2: 0.0,
            ..ff
        };
        // Constant pressures while the angle moves do not answer the valve commands: the
        // valve / supply residual may not trip on this synthetic input.
        cfg.valve_model.residual_abs_pa_s = f32::MAX;
        cfg.valve_model.integral_min_pa = f32::MAX;
        let kd = cfg.position.kd_nm_s_per_rad;
        let mut t = ControlTick::new(cfg);
        let mut last = None;
        for k in 0..400 {
            let a = 0.5 * k as f32 * 1e-3;
            last = Some(t.step(&frame_at(a), &Setpoint { angle_rad: a }, 1e-3));
        }
        (last.unwrap(), kd)
    };
    let (with, kd) = run(ControllerConfig::reference(1000.0).feedforward);
    let (without, _) = run(FeedforwardGains::OFF);
    assert!(with.armed && without.armed);
    let diff = with.torque_des_nm - without.torque_des_nm;
    assert!(
        (diff - kd * 0.5).abs() < 0.05 * kd,
        "{diff} vs {}",
        kd * 0.5
    );
}
