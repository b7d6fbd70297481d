//! Property tests over the whole f32 input space (NaN, +-inf, subnormals, huge values,
//! mixed with realistic values so the control paths run too): sensor validation, control
//! laws, valve drivers and the control tick never panic, never emit NaN in a command,
//! raise a fault for bad inputs, and never ask for more than 600 kPa.

use pam_firmware::constants::{FORCE_LAW, TORQUE_MODEL};
use pam_firmware::control::{
    JointState, PidGains, PositionController, PressureController, PressureLoopGains,
    TorqueController, TorqueLoopGains, TorqueMeasurement,
};
use pam_firmware::geometry::JointGeometry;
use pam_firmware::sensors::{
    counts_to_rad, ChannelFault, ChannelLimits, ChannelStatus, ChannelValidator, PressureScaling,
    VelocityEstimator,
};
use pam_firmware::tick::{ControlTick, ControllerConfig, SensorFrame, Setpoint, ValveCommand};
use pam_firmware::valves::{OnOffPwmConfig, OnOffValves, ValveOpenings};
use pam_firmware::P_MUSCLE_MAX_GAUGE_PA;
use proptest::prelude::*;

mod common;
use common::{angle, dt, f32_any_or, frame, opt, outputs_finite, pressure};
use pam_firmware::lockstep::UnwiredPin;

/// Any f32 (all classes), or a value in a realistic range, or a special value.
fn limits() -> ChannelLimits {
    ChannelLimits {
        min: -50_000.0,
        max: 1_000_000.0,
        max_rate_per_s: 2e7,
        jump_margin: 2e4,
        stale_ticks: 10,
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(1000))]

    #[test]
    fn validator_never_panics_and_valid_means_finite_in_range(
        samples in prop::collection::vec((opt(pressure()), dt()), 1..60)
    ) {
        let mut v = ChannelValidator::new(limits());
        for (s, dt) in samples {
            let st = v.update(s, dt);
            if let ChannelStatus::Valid { value, .. } = st {
                prop_assert!(value.is_finite());
                prop_assert!((-50_000.0..=1_000_000.0).contains(&value));
            }
            if let Some(x) = s {
                if !x.is_finite() {
                    prop_assert_eq!(st, ChannelStatus::Fault(ChannelFault::NotFinite));
                } else if !(-50_000.0..=1_000_000.0).contains(&x) {
                    prop_assert_eq!(st, ChannelStatus::Fault(ChannelFault::OutOfRange));
                }
            }
            prop_assert!(v.age_ticks() <= 60);
        }
    }

    #[test]
    fn velocity_estimate_is_always_finite(
        cutoff in f32_any_or(0.1, 500.0),
        samples in prop::collection::vec((opt(angle()), dt()), 1..60)
    ) {
        let mut ve = VelocityEstimator::new(cutoff);
        for (a, dt) in samples {
            prop_assert!(ve.update(a, dt).is_finite());
        }
    }

    #[test]
    fn unit_conversions_never_panic(
        counts in any::<i32>(), cpr in any::<u32>(), adc in any::<u32>(),
        a in any::<u32>(), b in any::<u32>(), fs in proptest::num::f32::ANY
    ) {
        let r = counts_to_rad(counts, cpr);
        prop_assert!(cpr == 0 || r.is_finite());
        let s = PressureScaling::from_two_points(a, b, fs);
        let _ = s.to_gauge_pa(adc);
    }

    #[test]
    fn position_loop_output_is_finite_bounded_or_error(
        a in angle(), v in f32_any_or(-20.0, 20.0), sp in angle(), dt in dt(), n in 1usize..20
    ) {
        let mut c = PositionController::new(PidGains { kp_nm_per_rad: 11.0, ki_nm_per_rad_s: 8.0, kd_nm_s_per_rad: 0.8, i_limit_nm: 1.5, out_limit_nm: 10.0 });
        let inputs_ok = [a, v, sp, dt].iter().all(|x| x.is_finite()) && dt > 0.0;
        for _ in 0..n {
            let r = c.step(JointState { angle_rad: a, velocity_rad_s: v }, sp, dt);
            if !inputs_ok {
                prop_assert!(r.is_err());
            }
            if let Ok(t) = r {
                prop_assert!(t.is_finite() && t.abs() <= 10.0);
            } else if inputs_ok {
                // Finite inputs fail only through overflow (e.g. kp * 3e38).
                prop_assert!(!(11.0 * (sp - a) - 0.8 * v).is_finite() || !(8.0 * (sp - a) * dt).is_finite());
            }
        }
    }

    #[test]
    fn torque_loop_setpoints_within_0_and_600_kpa_or_error(
        p1 in pressure(), p2 in pressure(), a in angle(), v in f32_any_or(-20.0, 20.0),
        t in f32_any_or(-50.0, 50.0), dt in dt(), n in 1usize..20
    ) {
        let mut c = TorqueController::new(
            TorqueLoopGains { kp: 0.2, ki_per_s: 30.0, corr_limit_nm: 1.5, p_set_max_gauge_pa: 600_000.0 },
            FORCE_LAW, JointGeometry::REFERENCE, TORQUE_MODEL);
        let all_finite = [p1, p2, a, v, t, dt].iter().all(|x| x.is_finite()) && dt > 0.0;
        let m = TorqueMeasurement { p1_gauge_pa: p1, p2_gauge_pa: p2, angle_rad: a, velocity_rad_s: v };
        for _ in 0..n {
            let r = c.step(m, t, dt);
            if !all_finite {
                prop_assert!(r.is_err());
            }
            if let Ok(s) = r {
                for p in [s.p1_gauge_pa, s.p2_gauge_pa] {
                    prop_assert!(p.is_finite() && (0.0..=P_MUSCLE_MAX_GAUGE_PA).contains(&p));
                }
                prop_assert!(s.dp_pa.is_finite() && s.torque_est_nm.is_finite());
            }
        }
    }

    #[test]
    fn pressure_loop_command_in_unit_range_or_error(
        p in pressure(), sp in pressure(), dt in dt(), n in 1usize..20,
        kp in f32_any_or(0.0, 1e-3), ki in f32_any_or(0.0, 1e-2)
    ) {
        let mut c = PressureController::new(PressureLoopGains { kp_per_pa: kp, ki_per_pa_s: ki, deadband_pa: 3000.0, i_limit: 0.3 });
        let inputs_ok = p.is_finite() && sp.is_finite() && dt.is_finite() && dt > 0.0;
        for _ in 0..n {
            let r = c.step(p, sp, dt);
            if !inputs_ok {
                prop_assert!(r.is_err());
            }
            if let Ok(u) = r {
                prop_assert!(u.is_finite() && (-1.0..=1.0).contains(&u));
            }
        }
        if !inputs_ok {
            prop_assert!(c.step(p, sp, dt).is_err());
        }
    }

    #[test]
    fn on_off_valves_never_open_both_and_report_binary_openings(
        cmds in prop::collection::vec((f32_any_or(-1.5, 1.5), f32_any_or(-1.5, 1.5)), 1..100),
        period in 0u16..20, min_on in 0u16..20
    ) {
        let mut v = OnOffValves::new(UnwiredPin, UnwiredPin, UnwiredPin, UnwiredPin,
            OnOffPwmConfig { period_ticks: period, min_on_ticks: min_on });
        for (m1, m2) in cmds {
            let o = v.apply(&ValveCommand { muscle1: m1, muscle2: m2 }).unwrap();
            prop_assert!(!(o.u_in1 > 0.0 && o.u_ex1 > 0.0));
            prop_assert!(!(o.u_in2 > 0.0 && o.u_ex2 > 0.0));
            for u in [o.u_in1, o.u_ex1, o.u_in2, o.u_ex2] {
                prop_assert!(u == 0.0 || u == 1.0);
            }
            if !m1.is_finite() || m1 == 0.0 {
                prop_assert!(o.u_in1 == 0.0 && o.u_ex1 == 0.0);
            }
        }
    }

    #[test]
    fn ideal_openings_never_both_and_within_unit_range(m1 in f32_any_or(-2.0, 2.0), m2 in f32_any_or(-2.0, 2.0)) {
        let o = ValveOpenings::from_command(&ValveCommand { muscle1: m1, muscle2: m2 });
        prop_assert!(o.u_in1 == 0.0 || o.u_ex1 == 0.0);
        prop_assert!(o.u_in2 == 0.0 || o.u_ex2 == 0.0);
        for u in [o.u_in1, o.u_ex1, o.u_in2, o.u_ex2] {
            prop_assert!((0.0..=1.0).contains(&u));
        }
    }

    #[test]
    fn control_tick_never_panics_never_nan_never_above_600_kpa(
        steps in prop::collection::vec((frame(), angle(), dt()), 1..80),
        vent in any::<bool>(),
    ) {
        common::run_checked(ControllerConfig::reference(1000.0), vent, steps, |_| Ok(()))?;
    }

    #[test]
    fn control_tick_reset_only_rearms_on_clean_data(
        bad in prop_oneof![Just(f32::NAN), Just(f32::INFINITY), Just(2e6f32), Just(-1e6f32)],
        which in 0usize..3,
        good_ticks in 1usize..5,
    ) {
        let mut t = ControlTick::new(ControllerConfig::reference(1000.0));
        let good = SensorFrame { p1_gauge_pa: Some(3e5), p2_gauge_pa: Some(3e5), angle_rad: Some(0.0) };
        let sp = Setpoint { angle_rad: 0.1 };
        prop_assert!(t.step(&good, &sp, 1e-3).armed);
        let mut f = good;
        match which {
            0 => f.p1_gauge_pa = Some(bad),
            1 => f.p2_gauge_pa = Some(bad),
            _ => f.angle_rad = Some(bad),
        }
        let o = t.step(&f, &sp, 1e-3);
        prop_assert!(o.fault.is_some());
        prop_assert_eq!(o.valves, ValveCommand::default());
        prop_assert!(!t.reset());
        for _ in 0..good_ticks {
            prop_assert!(t.step(&good, &sp, 1e-3).fault.is_some());
        }
        prop_assert!(t.reset());
        prop_assert!(t.step(&good, &sp, 1e-3).armed);
    }

    #[test]
    fn control_tick_on_plausible_random_walk_stays_armed_finite_and_bounded(
        steps in prop::collection::vec(
            (-5_000.0f32..5_000.0, -5_000.0f32..5_000.0, -0.005f32..0.005, f32_any_or(-2.0, 2.0)),
            1..200),
    ) {
        // A random walk of the pressures does not answer the valve commands: the valve /
        // supply residual would rightly call it faulty, so it may not trip here (it still runs).
        let mut cfg = ControllerConfig::reference(1000.0);
        cfg.valve_model.residual_abs_pa_s = f32::MAX;
        cfg.valve_model.integral_min_pa = f32::MAX;
        let mut t = ControlTick::new(cfg);
        let (mut p1, mut p2, mut a) = (300_000.0f32, 300_000.0f32, 0.0f32);
        for (d1, d2, da, sp) in steps {
            p1 = (p1 + d1).clamp(0.0, 600_000.0);
            p2 = (p2 + d2).clamp(0.0, 600_000.0);
            a = (a + da).clamp(-0.9, 0.9);
            let f = SensorFrame { p1_gauge_pa: Some(p1), p2_gauge_pa: Some(p2), angle_rad: Some(a) };
            let o = t.step(&f, &Setpoint { angle_rad: sp }, 1e-3);
            if sp.is_finite() {
                prop_assert!(o.armed && o.fault.is_none(), "{:?}", o);
            } else {
                prop_assert!(o.fault.is_some());
                break;
            }
            prop_assert!(outputs_finite(&o));
            prop_assert!((-1.0..=1.0).contains(&o.valves.muscle1));
            prop_assert!((-1.0..=1.0).contains(&o.valves.muscle2));
            prop_assert!((0.0..=P_MUSCLE_MAX_GAUGE_PA).contains(&o.p1_set_gauge_pa));
            prop_assert!((0.0..=P_MUSCLE_MAX_GAUGE_PA).contains(&o.p2_set_gauge_pa));
            prop_assert!(o.torque_des_nm.abs() <= 10.0);
        }
    }
}
