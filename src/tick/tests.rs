//! The control tick's tests.

use super::*;
use crate::safety::SafeState;
use crate::P_MUSCLE_MAX_GAUGE_PA;

const DT: f32 = 1e-3;

fn frame(p1: f32, p2: f32, a: f32) -> SensorFrame {
    SensorFrame {
        p1_gauge_pa: Some(p1),
        p2_gauge_pa: Some(p2),
        angle_rad: Some(a),
    }
}

fn tick() -> ControlTick {
    ControlTick::new(ControllerConfig::reference(1000.0))
}

const SP0: Setpoint = Setpoint { angle_rad: 0.0 };

/// A tick armed by one nominal frame (300 kPa in both muscles, 0 rad).
fn armed() -> ControlTick {
    let mut t = tick();
    t.step(&frame(300e3, 300e3, 0.0), &SP0, DT);
    t
}

/// The reference configuration at 1 kHz with one edit.
fn reference_with(edit: impl FnOnce(&mut ControllerConfig)) -> ControllerConfig {
    let mut cfg = ControllerConfig::reference(1000.0);
    edit(&mut cfg);
    cfg
}

#[test]
fn valve_shortfall_maps_full_valves_to_the_blocked_torque_direction() {
    // Muscle 1 inflating flat out: p1 = p0 - dp cannot rise faster, so dp cannot fall
    // faster: the low side is blocked (with B r > 0 that is the low torque side too).
    assert_eq!(valve_shortfall(1.0, 0.0, 1.0), -1.0);
    assert_eq!(valve_shortfall(1.0, 0.0, -1.0), 1.0);
    // Muscle 2 inflating flat out: dp cannot rise faster.
    assert_eq!(valve_shortfall(0.0, 1.0, 1.0), 1.0);
    assert_eq!(valve_shortfall(-1.0, 1.0, 1.0), 2.0);
    // Anything short of +-1 is not saturated.
    assert_eq!(valve_shortfall(0.999, -0.999, 1.0), 0.0);
    assert_eq!(valve_shortfall(0.0, 0.0, -1.0), 0.0);
}
#[test]
fn reference_config_is_valid() {
    assert!(ControllerConfig::reference(1000.0).is_valid());
    assert!(ControllerConfig::reference(500.0).is_valid());
    assert!(!ControllerConfig::reference(f32::NAN).is_valid());
    assert!(!ControllerConfig::reference(0.0).is_valid());
    assert!(ControllerConfig::reference(TICK_HZ_MIN).is_valid());
    assert!(!ControllerConfig::reference(50.0).is_valid());
    assert!(!ControllerConfig::reference(20_000.0).is_valid());
}

#[test]
fn valid_frame_arms_and_commands_finite_valves() {
    let mut t = tick();
    let o = t.step(&frame(550e3, 550e3, 0.0), &SP0, DT);
    assert!(o.armed);
    assert_eq!(o.fault, None);
    // 550 kPa measured, p0 = 300 kPa wanted: both muscles exhaust.
    assert!(o.valves.muscle1 < 0.0 && o.valves.muscle2 < 0.0);
    assert!(o.p1_set_gauge_pa <= P_MUSCLE_MAX_GAUGE_PA);
}

#[test]
fn startup_waits_closed_without_fault_until_all_channels_arrive() {
    let mut t = tick();
    let f = SensorFrame {
        p1_gauge_pa: Some(300e3),
        p2_gauge_pa: None,
        angle_rad: Some(0.0),
    };
    let o = t.step(&f, &SP0, DT);
    assert!(!o.armed);
    assert_eq!(o.fault, None);
    assert_eq!(o.valves, ValveCommand::default());
}

#[test]
fn nan_pressure_gives_safe_state_in_same_tick() {
    let mut t = tick();
    t.step(&frame(300e3, 300e3, 0.0), &Setpoint { angle_rad: 0.3 }, DT);
    let o = t.step(
        &frame(f32::NAN, 300e3, 0.0),
        &Setpoint { angle_rad: 0.3 },
        DT,
    );
    assert_eq!(o.fault, Some(FaultCode::PressureInvalid1));
    assert_eq!(o.valves, ValveCommand::default());
    assert!(!o.armed);
}

#[test]
fn vent_safe_state_opens_exhausts() {
    let mut t = ControlTick::new(reference_with(|c| c.safe_state = SafeState::Vent));
    let o = t.step(&frame(300e3, 300e3, f32::INFINITY), &SP0, DT);
    assert_eq!(o.fault, Some(FaultCode::AngleInvalid));
    assert_eq!(
        o.valves,
        ValveCommand {
            muscle1: -1.0,
            muscle2: -1.0
        }
    );
}

#[test]
fn fault_is_latched_until_explicit_reset() {
    let mut t = armed();
    t.step(&frame(300e3, 300e3, 2.0), &SP0, DT);
    assert_eq!(t.fault(), Some(FaultCode::AngleOutOfRange));
    // Good data again: still latched.
    for _ in 0..10 {
        let o = t.step(&frame(300e3, 300e3, 0.0), &SP0, DT);
        assert_eq!(o.fault, Some(FaultCode::AngleOutOfRange));
        assert!(!o.armed);
    }
    assert!(t.reset());
    let o = t.step(&frame(300e3, 300e3, 0.0), &SP0, DT);
    assert!(o.armed);
    assert_eq!(o.fault, None);
}

#[test]
fn reset_refused_while_condition_persists() {
    let mut t = tick();
    t.step(&frame(700e3, 300e3, 0.0), &SP0, DT);
    assert_eq!(t.fault(), Some(FaultCode::OverPressure1));
    t.step(&frame(700e3, 300e3, 0.0), &SP0, DT);
    assert!(!t.reset());
    assert_eq!(t.fault(), Some(FaultCode::OverPressure1));
}

#[test]
fn over_pressure_in_hold_vents_that_muscle_and_reports_all_conditions() {
    let mut t = armed();
    // A first fault (angle out of range) puts the joint in Hold.
    let o = t.step(&frame(300e3, 300e3, 1.5), &SP0, DT);
    assert_eq!(o.fault, Some(FaultCode::AngleOutOfRange));
    assert_eq!(o.valves, ValveCommand::default());
    // Muscle 2 is compressed in Hold (10 kPa per tick): up to 598 kPa it is held...
    let mut p2: f32 = 300e3;
    while p2 < 598e3 {
        p2 = (p2 + 10e3).min(598e3);
        let o = t.step(&frame(300e3, p2, 1.5), &SP0, DT);
        assert_eq!(o.valves, ValveCommand::default(), "{p2}");
    }
    // ... 602 kPa (above the 600 kPa limit) vents muscle 2 only, and the cause stays.
    let o = t.step(&frame(300e3, 602e3, 1.5), &SP0, DT);
    assert_eq!(o.fault, Some(FaultCode::AngleOutOfRange));
    assert_eq!(o.valves.muscle1, 0.0);
    assert_eq!(o.valves.muscle2, -1.0);
    assert_eq!(o.p2_set_gauge_pa, 0.0);
    assert!(o.active.contains(FaultCode::AngleOutOfRange));
    assert!(o.active.contains(FaultCode::OverPressure2));
    assert!(t.faults_seen().contains(FaultCode::OverPressure2));
    // The vent stays after the pressure fell; reset refused while the angle is out.
    let o = t.step(&frame(300e3, 590e3, 1.5), &SP0, DT);
    assert_eq!(o.valves.muscle2, -1.0);
    assert!(!t.reset());
    t.step(&frame(300e3, 590e3, 0.2), &SP0, DT);
    assert!(t.reset());
    let o = t.step(&frame(300e3, 590e3, 0.2), &SP0, DT);
    assert!(o.armed && o.active.is_empty());
}

#[test]
fn over_pressure_vents_with_vent_or_hold_and_limit_is_validated() {
    let mut t = ControlTick::new(reference_with(|c| c.p_over_gauge_pa = 500e3));
    let o = t.step(&frame(520e3, 300e3, 0.0), &SP0, DT);
    assert_eq!(o.fault, Some(FaultCode::OverPressure1));
    assert_eq!(o.valves.muscle1, -1.0);
    assert_eq!(o.valves.muscle2, 0.0);
    assert!(!reference_with(|c| c.p_over_gauge_pa = 630e3).is_valid());
}

#[test]
fn short_dt_raises_watchdog() {
    let mut t = armed();
    let o = t.step(&frame(300e3, 300e3, 0.0), &SP0, 1e-5);
    assert_eq!(o.fault, Some(FaultCode::Watchdog));
    assert!(!reference_with(|c| c.dt_min_s = 0.0).is_valid());
}

#[test]
fn stale_angle_raises_fault_after_limit() {
    let mut t = armed();
    let f = SensorFrame {
        p1_gauge_pa: Some(300e3),
        p2_gauge_pa: Some(300e3),
        angle_rad: None,
    };
    for _ in 0..10 {
        assert!(t.step(&f, &SP0, DT).armed);
    }
    let o = t.step(&f, &SP0, DT);
    assert_eq!(o.fault, Some(FaultCode::AngleStale));
}

#[test]
fn implausible_pressure_jump_raises_fault() {
    let mut t = armed();
    let o = t.step(&frame(300e3, 500e3, 0.0), &SP0, DT);
    assert_eq!(o.fault, Some(FaultCode::PressureImplausible2));
}

#[test]
fn bad_dt_raises_watchdog() {
    for dt in [f32::NAN, 0.0, -1e-3, 1.0, f32::INFINITY] {
        let mut t = tick();
        let o = t.step(&frame(300e3, 300e3, 0.0), &SP0, dt);
        assert_eq!(o.fault, Some(FaultCode::Watchdog), "dt {dt}");
    }
}

#[test]
fn nan_setpoint_raises_fault_and_large_setpoint_is_clamped() {
    let mut t = tick();
    let o = t.step(
        &frame(300e3, 300e3, 0.0),
        &Setpoint {
            angle_rad: f32::NAN,
        },
        DT,
    );
    assert_eq!(o.fault, Some(FaultCode::SetpointInvalid));
    let mut a = tick();
    let mut b = tick();
    let oa = a.step(&frame(300e3, 300e3, 0.0), &Setpoint { angle_rad: 1e30 }, DT);
    let ob = b.step(&frame(300e3, 300e3, 0.0), &Setpoint { angle_rad: 0.8 }, DT);
    assert_eq!(oa, ob);
}

#[test]
fn invalid_config_latches_config_fault_forever() {
    let mut t = ControlTick::new(reference_with(|c| c.position.kp_nm_per_rad = f32::NAN));
    let o = t.step(&frame(300e3, 300e3, 0.0), &SP0, DT);
    assert_eq!(o.fault, Some(FaultCode::ConfigInvalid));
    assert!(!t.reset());
}

#[test]
fn a_force_law_singular_on_its_domain_or_an_overflowing_geometry_is_a_config_fault() {
    // c7 P + c8 e crosses 0 inside the domain (P up to 0.6 MPa, e down to 0.75).
    let singular = reference_with(|c| c.force_law.c[6] = -2.0);
    let overflow = reference_with(|c| c.geometry.rest_length_m = 1e-44);
    for cfg in [singular, overflow] {
        assert!(!cfg.is_valid());
        let o = ControlTick::new(cfg).step(&frame(300e3, 300e3, 0.0), &SP0, DT);
        assert_eq!(o.fault, Some(FaultCode::ConfigInvalid));
        assert!(!o.armed && o.torque_est_nm.is_finite());
    }
}

#[test]
fn positive_step_inflates_muscle_one_and_deflates_muscle_two() {
    let mut t = tick();
    // The joint is where it is asked to be; the start phase ends once the pressure
    // ceiling has risen from 300 to 600 kPa (0.3 s).
    for _ in 0..301 {
        t.step(&frame(300e3, 300e3, 0.0), &SP0, DT);
    }
    let o = t.step(&frame(300e3, 300e3, 0.0), &Setpoint { angle_rad: 0.2 }, DT);
    assert!(o.torque_des_nm > 0.0);
    assert!(o.p1_set_gauge_pa > 300e3 && o.p2_set_gauge_pa < 300e3);
    assert!(o.valves.muscle1 > 0.0 && o.valves.muscle2 < 0.0);
}

/// The reference tick with the valve / supply residual off: the start-phase tests feed
/// frames whose pressures do not follow the valves.
fn cfg_no_residual() -> ControllerConfig {
    let mut c = ControllerConfig::reference(1000.0);
    c.valve_model.residual_abs_pa_s = 1e30;
    c.valve_model.integral_min_pa = 1e30;
    c
}

fn tick_no_residual() -> ControlTick {
    ControlTick::new(cfg_no_residual())
}

/// An instant start: rates so high that the start phase ends in its first tick.
fn instant_start() -> ControllerConfig {
    ControllerConfig {
        start: StartRamp::INSTANT,
        ..cfg_no_residual()
    }
}

#[test]
fn start_phase_ramps_the_setpoint_from_the_measured_angle() {
    let mut t = tick_no_residual();
    let far = Setpoint { angle_rad: 0.6 };
    for k in 0..100 {
        let o = t.step(&frame(300e3, 300e3, 0.0), &far, DT);
        assert!(o.armed && o.fault.is_none());
        if k == 0 {
            // 1 mrad of ramp: a small torque, not the saturated 0.6 rad step.
            assert!(
                o.torque_des_nm > 0.0 && o.torque_des_nm < 1.0,
                "{}",
                o.torque_des_nm
            );
        }
        // 1 mrad per tick: after 0.1 s a 0.1 rad error, far from saturating.
        assert!(o.torque_des_nm.abs() < 5.0, "tick {k}: {}", o.torque_des_nm);
    }
    assert!(t.sp_fast_max_rad < 0.0, "still ramping after 0.1 s");
    // The same request without the start phase saturates the position loop at once.
    let mut instant = ControlTick::new(instant_start());
    let o = instant.step(&frame(300e3, 300e3, 0.0), &far, DT);
    assert!(o.torque_des_nm > 5.0, "{}", o.torque_des_nm);
}

#[test]
fn start_phase_ends_when_the_ramp_has_caught_up() {
    // 0.05 rad away: inside the 0.2 rad approach zone, the distance decays with 0.2 s
    // down to 0.01 rad (0.2 s ln(5) = 0.32 s), then 0.05 rad/s to the last 1 mrad (0.18 s).
    let mut t = tick_no_residual();
    let near = Setpoint { angle_rad: 0.05 };
    for _ in 0..470 {
        t.step(&frame(300e3, 300e3, 0.0), &near, DT);
    }
    assert!(t.sp_fast_max_rad < 0.0);
    for _ in 0..60 {
        t.step(&frame(300e3, 300e3, 0.0), &near, DT);
    }
    assert!(t.sp_fast_max_rad > 0.0);
}

#[test]
fn start_phase_catches_a_moving_setpoint() {
    // Armed 0.3 rad away from a set-point moving at 0.5 rad/s: the ramp closes the gap
    // and the start phase ends (the distance decays with 0.2 s, whatever the motion).
    let mut t = tick_no_residual();
    let mut over_at = None;
    for k in 0..2000 {
        let sp = Setpoint {
            angle_rad: -0.3 + 0.5 * DT * k as f32,
        };
        if sp.angle_rad > 0.7 {
            break;
        }
        t.step(&frame(300e3, 300e3, 0.0), &sp, DT);
        if t.sp_fast_max_rad > 0.0 {
            over_at = Some(k);
            break;
        }
    }
    let k = over_at.expect("the start phase never ended");
    assert!(k < 1500, "{k}");
}

#[test]
fn start_phase_precharges_vented_muscles_at_the_limited_rate() {
    let mut t = tick_no_residual();
    for k in 1..=700u32 {
        let o = t.step(&frame(0.0, 0.0, 0.0), &SP0, DT);
        let ceiling = 1.0e6 * DT * k as f32 + 1.0;
        assert!(
            o.p1_set_gauge_pa <= ceiling && o.p2_set_gauge_pa <= ceiling,
            "tick {k}: {} / {} > {ceiling}",
            o.p1_set_gauge_pa,
            o.p2_set_gauge_pa
        );
    }
}

#[test]
fn a_joint_in_place_with_charged_muscles_starts_exactly_like_an_instant_start() {
    let mut t = tick_no_residual();
    let mut instant = ControlTick::new(instant_start());
    for k in 0..300 {
        let a = 0.001 * k as f32;
        let f = frame(550e3, 540e3, a);
        let sp = Setpoint {
            angle_rad: 0.3 * libm::sinf(a),
        };
        let (o, oi) = (t.step(&f, &sp, DT), instant.step(&f, &sp, DT));
        assert_eq!(o.valves, oi.valves, "tick {k}: {:?} {:?}", o, oi);
        assert_eq!(o.p1_set_gauge_pa.to_bits(), oi.p1_set_gauge_pa.to_bits());
        assert_eq!(o.torque_des_nm.to_bits(), oi.torque_des_nm.to_bits());
    }
}

#[test]
fn an_accepted_reset_starts_a_new_start_phase() {
    let mut t = tick_no_residual();
    for _ in 0..301 {
        t.step(&frame(300e3, 300e3, 0.0), &SP0, DT);
    }
    assert!(t.sp_fast_max_rad > 0.0);
    let o = t.step(&frame(f32::NAN, 300e3, 0.0), &SP0, DT);
    assert!(o.fault.is_some());
    // While faulted the joint is moved 0.4 rad by hand, then held still.
    for k in 1..=500 {
        let a = 0.001 * (k.min(400)) as f32;
        t.step(&frame(300e3, 300e3, a), &SP0, DT);
    }
    assert!(t.reset(), "{:?}", t.active);
    // Re-armed 0.4 rad away from the set-point: the ramp starts at the measured angle.
    let o = t.step(&frame(300e3, 300e3, 0.4), &SP0, DT);
    assert!(o.armed);
    assert!(o.torque_des_nm.abs() < 1.0, "{}", o.torque_des_nm);
    assert!(t.sp_fast_max_rad < 0.0);
}

#[test]
fn start_ramp_rates_must_be_positive() {
    for bad in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        let mut c = ControllerConfig::reference(1000.0);
        c.start.setpoint_rate_rad_s = bad;
        assert!(!c.is_valid());
        let mut c = ControllerConfig::reference(1000.0);
        c.start.precharge_rate_pa_s = bad;
        assert!(!c.is_valid());
    }
}

/// A split cascade (`outer_period_ticks = 2`) and an unsplit one, instant start.
fn split_and_whole() -> (ControlTick, ControlTick) {
    let cfg = |n: u16| {
        reference_with(|c| {
            c.start = StartRamp::INSTANT;
            c.outer_period_ticks = n;
            // Open loop: the pressures do not follow the valves; the valve supervision
            // runs but never judges.
            c.valve_model.residual_abs_pa_s = f32::MAX;
            c.valve_model.integral_min_pa = f32::MAX;
        })
    };
    (ControlTick::new(cfg(2)), ControlTick::new(cfg(1)))
}

#[test]
fn outer_loops_run_on_one_tick_in_n_with_the_time_since_their_last_run() {
    // The split tick at 1 ms against the whole cascade stepped only on the split one's
    // outer ticks, at 2 ms: the same set-points, desired torques and estimates, bit for
    // bit (the joint at rest, so the velocity estimate is 0 in both). In between, the
    // split tick holds the torques and extrapolates the pressure set-points by their last
    // change, while its pressure loops follow the measured pressures every tick.
    let (mut split, mut whole) = split_and_whole();
    assert_eq!(split.outer_period_ticks, 2);
    let mut n_outer = 0;
    let mut prev: Option<TickOutput> = None;
    // The last two outer runs' set-points.
    let mut outer_sets: [Option<(f32, f32)>; 2] = [None; 2];
    for k in 0..400 {
        let sp = Setpoint {
            angle_rad: 0.02 * libm::sinf(k as f32 * 0.01),
        };
        // The pressures alternate by 8 kPa from tick to tick (the valves never saturate
        // here, so the anti-windup sees the same in both).
        // The muscles follow the last set-points (a stand-in for the pressure dynamics).
        let wobble = if k % 2 == 0 { 0.0 } else { 8e3 };
        let (p1, p2) = prev.map_or((300e3, 300e3), |h| (h.p1_set_gauge_pa, h.p2_set_gauge_pa));
        let f = frame(p1 + wobble, p2 - wobble, 0.0);
        let o = split.step(&f, &sp, DT);
        assert!(o.armed, "tick {k}");
        assert!(o.valves.muscle1.abs() < 1.0 && o.valves.muscle2.abs() < 1.0);
        if k % 2 == 0 {
            // The first outer run has only its own tick behind it.
            let w = whole.step(&f, &sp, if k == 0 { DT } else { 2.0 * DT });
            assert!(w.armed);
            assert_eq!(
                (
                    o.p1_set_gauge_pa,
                    o.p2_set_gauge_pa,
                    o.torque_des_nm,
                    o.torque_est_nm
                ),
                (
                    w.p1_set_gauge_pa,
                    w.p2_set_gauge_pa,
                    w.torque_des_nm,
                    w.torque_est_nm
                ),
                "outer tick {k}"
            );
            n_outer += 1;
            outer_sets = [outer_sets[1], Some((o.p1_set_gauge_pa, o.p2_set_gauge_pa))];
        } else {
            let h = prev.unwrap();
            assert_eq!(
                (o.torque_des_nm, o.torque_est_nm),
                (h.torque_des_nm, h.torque_est_nm),
                "held on tick {k}"
            );
            let (c1, c2) = outer_sets[1].unwrap();
            let (b1, b2) = outer_sets[0].unwrap_or((c1, c2));
            assert_eq!(
                (o.p1_set_gauge_pa, o.p2_set_gauge_pa),
                (c1 + (c1 - b1) * 0.5, c2 + (c2 - b2) * 0.5),
                "extrapolated on tick {k}"
            );
            // The pressure loops ran on this tick's pressures: the commands moved.
            assert_ne!(o.valves, h.valves, "tick {k}");
        }
        prev = Some(o);
    }
    assert_eq!(n_outer, 200);
    // The set-point moved: the held values were not all the same.
    assert!(prev.unwrap().torque_des_nm != 0.0);
}

#[test]
fn extrapolated_pressure_set_points_stay_within_the_ceiling_and_above_zero() {
    // Set-points driven hard both ways: the pressures rise and fall by the most the torque
    // loop allows per outer run, so the extrapolation would overshoot the bounds unclamped.
    let (mut t, _) = split_and_whole();
    let (mut p1, mut p2) = (300e3f32, 300e3f32);
    let (mut hit_hi, mut hit_lo) = (false, false);
    for k in 0..3000 {
        let sp = Setpoint {
            angle_rad: if (k / 500) % 2 == 0 { 0.8 } else { -0.8 },
        };
        let o = t.step(&frame(p1, p2, 0.0), &sp, DT);
        assert!(o.armed, "tick {k}");
        for p in [o.p1_set_gauge_pa, o.p2_set_gauge_pa] {
            assert!((0.0..=P_MUSCLE_MAX_GAUGE_PA).contains(&p), "tick {k}: {p}");
            hit_hi |= p == P_MUSCLE_MAX_GAUGE_PA;
            hit_lo |= p == 0.0;
        }
        // The muscles follow their set-points within 20 kPa a tick.
        p1 += (o.p1_set_gauge_pa - p1).clamp(-20e3, 20e3);
        p2 += (o.p2_set_gauge_pa - p2).clamp(-20e3, 20e3);
    }
    assert!(hit_hi && hit_lo, "the bounds were not reached");
}

#[test]
fn a_fault_between_outer_runs_gives_the_safe_state_in_the_same_tick_and_restarts_them() {
    let (mut t, _) = split_and_whole();
    let f = frame(300e3, 300e3, 0.0);
    assert!(t.step(&f, &SP0, DT).armed); // outer
    assert!(t.step(&f, &SP0, DT).armed); // held
    assert!(t.step(&f, &SP0, DT).armed); // outer
    let o = t.step(&frame(f32::NAN, 300e3, 0.1), &SP0, DT); // would be held
    assert!(!o.armed);
    assert_eq!(o.fault, Some(FaultCode::PressureInvalid1));
    assert_eq!(o.valves, t.safety.safe_command());
    // The estimate of the last valid samples (300 kPa, 0 rad), not the held one.
    let (e, _) = t.estimate().unwrap();
    assert_eq!(o.torque_est_nm, e);
    // After the reset the first armed tick runs the outer loops again.
    for _ in 0..3 {
        t.step(&f, &SP0, DT);
    }
    assert!(t.reset());
    let a = t.step(&f, &Setpoint { angle_rad: 0.2 }, DT);
    assert!(a.armed && a.torque_des_nm > 0.0, "{a:?}");
}

#[test]
fn the_outer_period_is_bounded_and_keeps_the_outer_loops_at_200_hz_or_faster() {
    for (hz, n, ok) in [
        (1000.0, 1, true),
        (1000.0, 2, true),
        (1000.0, 5, true),
        (1000.0, 0, false),
        (1000.0, 6, false),
        (2000.0, 10, true),
        (2000.0, 11, false),
        (500.0, 2, true),
        (500.0, 3, false),
    ] {
        let mut c = ControllerConfig::reference(hz);
        c.outer_period_ticks = n;
        assert_eq!(c.is_valid(), ok, "{hz} Hz, {n} ticks");
    }
}
