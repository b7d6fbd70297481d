//! Closed-loop smoke test of `ControlTick` + `OnOffValves` (the firmware's own code) on the
//! reference plant (`host_sim::Plant`, `tests/fixtures/reference-1dof.toml`, integrated by
//! `host_sim::sim::Integrator` over each 1 ms tick with the valve openings held). Fake
//! sensors quantise like the board's ADC and encoder. The step requirement asserted here
//! is the firmware's own (0 -> 0.2 rad: settled within +-0.01 rad in 0.3 s, overshoot below
//! 0.02 rad; 11x inertia: stable, settled in 2 s).
//!
//! Run with `cargo test -p host-sim --test closed_loop_smoke -- --nocapture` to see the
//! measured step-response figures.

mod common;
use common::{tight_integrator, unwired_valves};

use core::f64::consts::PI;

use host_sim::{Plant, PlantConfig, ValveInputs};
use pam_firmware::log::{TickLog, TickRecord};
use pam_firmware::safety::SafeState;
use pam_firmware::sensors::{counts_to_rad, PressureScaling};
use pam_firmware::tick::{
    ControlTick, ControllerConfig, FaultCode, SensorFrame, Setpoint, TickOutput, ValveCommand,
};
use pam_firmware::valves::{OnOffPwmConfig, ValveOpenings};

/// The reference plant with joint inertia `inertia_kgm2`.
fn plant(inertia_kgm2: f64) -> Plant {
    let path = common::plant();
    let mut cfg = PlantConfig::load(path).unwrap();
    cfg.joint.inertia_kgm2 = inertia_kgm2;
    Plant::from_config(&cfg)
}

/// J_n of reference-1dof.toml; reference-1dof-loaded.toml has 11 x J_n.
const J_NOMINAL: f64 = 0.014;

const TICK_HZ: f32 = 1000.0;
const DT: f64 = 1.0 / TICK_HZ as f64;
const ENCODER_CPR: u32 = 8000;

/// 12-bit ADC over 0..1 MPa gauge (the sensor's counts, as the board would read them).
fn adc_scaling() -> PressureScaling {
    PressureScaling::from_two_points(0, 4095, 1_000_000.0)
}

fn measure(plant: &Plant, x: &host_sim::PlantState) -> SensorFrame {
    let s = adc_scaling();
    let p_atm = plant.p_atm_pa;
    let counts = |p_abs: f64| (((p_abs - p_atm) / s.pa_per_count as f64).round().max(0.0)) as u32;
    let enc = (x.angle_rad / (2.0 * PI) * ENCODER_CPR as f64).round() as i32;
    SensorFrame {
        p1_gauge_pa: Some(s.to_gauge_pa(counts(x.p1_abs_pa))),
        p2_gauge_pa: Some(s.to_gauge_pa(counts(x.p2_abs_pa))),
        angle_rad: Some(counts_to_rad(enc, ENCODER_CPR)),
    }
}

fn inputs(u: &ValveOpenings) -> ValveInputs {
    ValveInputs {
        u_in1: u.u_in1 as f64,
        u_ex1: u.u_ex1 as f64,
        u_in2: u.u_in2 as f64,
        u_ex2: u.u_ex2 as f64,
    }
}

struct Run {
    t: Vec<f64>,
    beta: Vec<f64>,
    out: Vec<TickOutput>,
    openings: Vec<ValveOpenings>,
    p_max_gauge: f64,
    /// The firmware's ring log of the last 256 ticks.
    log: TickLog<256>,
}

/// Runs the loop for `seconds`; the set-point is 0 until `t_step`, then `target`.
/// `inject(k, frame)` may corrupt the frame of tick k.
fn simulate(
    inertia_kgm2: f64,
    cfg: ControllerConfig,
    seconds: f64,
    t_step: f64,
    target: f32,
    mut inject: impl FnMut(usize, &mut SensorFrame),
) -> Run {
    let plant = plant(inertia_kgm2);
    let mut integ = tight_integrator(&plant);
    let mut tick = ControlTick::new(cfg);
    let mut valves = unwired_valves();
    let n = (seconds / DT).round() as usize;
    let mut run = Run {
        t: Vec::with_capacity(n),
        beta: Vec::with_capacity(n),
        out: Vec::with_capacity(n),
        openings: Vec::with_capacity(n),
        p_max_gauge: 0.0,
        log: TickLog::new(),
    };
    for k in 0..n {
        let t = k as f64 * DT;
        let sp = Setpoint {
            angle_rad: if t >= t_step { target } else { 0.0 },
        };
        let x = integ.state();
        let mut frame = measure(&plant, &x);
        inject(k, &mut frame);
        let out = tick.step(&frame, &sp, DT as f32);
        let u = valves.apply(&out.valves).unwrap();
        tick.valves_applied(&u);
        run.log.push(TickRecord::new(k as u32, &frame, &sp, &out));
        run.t.push(t);
        run.beta.push(x.angle_rad);
        run.out.push(out);
        run.openings.push(u);
        let x = integ.advance(inputs(&u), DT).unwrap();
        run.p_max_gauge = run
            .p_max_gauge
            .max(x.p1_abs_pa - plant.p_atm_pa)
            .max(x.p2_abs_pa - plant.p_atm_pa);
        assert!(x.angle_rad.is_finite() && x.p1_abs_pa.is_finite() && x.p2_abs_pa.is_finite());
    }
    run
}

/// Settling time after `t_step`: the first time after which |beta - target| stays <= band.
fn settling_time(run: &Run, t_step: f64, target: f64, band: f64) -> Option<f64> {
    let mut last_outside = None;
    for (i, (&t, &b)) in run.t.iter().zip(&run.beta).enumerate() {
        if t >= t_step && (b - target).abs() > band {
            last_outside = Some(i);
        }
    }
    match last_outside {
        None => Some(0.0),
        Some(i) if i + 1 < run.t.len() => Some(run.t[i + 1] - t_step),
        Some(_) => None,
    }
}

const T_STEP: f64 = 0.5;
const TARGET: f64 = 0.2;
/// Stated requirement of this smoke test: after the 0 -> 0.2 rad step the angle enters
/// and stays within +-0.01 rad (5 % of the step) within 0.3 s, overshoot below 0.02 rad
/// (measured on the real plant with the reference tuning: 0.093 s, 0.0115 rad).
const BAND_RAD: f64 = 0.01;
const SETTLE_MAX_S: f64 = 0.3;
const OVERSHOOT_MAX_RAD: f64 = 0.02;

#[test]
fn step_0_to_0p2_rad_settles_within_bound() {
    let run = simulate(
        J_NOMINAL,
        ControllerConfig::reference(TICK_HZ),
        3.0,
        T_STEP,
        TARGET as f32,
        |_, _| {},
    );
    assert!(
        run.out.iter().all(|o| o.fault.is_none()),
        "unexpected fault"
    );
    assert!(run.out.iter().skip(1).all(|o| o.armed));
    let ts = settling_time(&run, T_STEP, TARGET, BAND_RAD);
    let after: Vec<f64> = run
        .t
        .iter()
        .zip(&run.beta)
        .filter(|(&t, _)| t >= T_STEP)
        .map(|(_, &b)| b)
        .collect();
    let peak = after.iter().cloned().fold(f64::MIN, f64::max);
    let overshoot = (peak - TARGET).max(0.0);
    let tail: Vec<f64> = run
        .t
        .iter()
        .zip(&run.beta)
        .filter(|(&t, _)| t >= 2.0)
        .map(|(_, &b)| b - TARGET)
        .collect();
    let tail_max = tail.iter().map(|e| e.abs()).fold(0.0, f64::max);
    let tail_rms = (tail.iter().map(|e| e * e).sum::<f64>() / tail.len() as f64).sqrt();
    // Before the step: the joint stays near 0 while both muscles vent from 550 kPa to p0.
    let pre_max = run
        .t
        .iter()
        .zip(&run.beta)
        .filter(|(&t, _)| t < T_STEP)
        .map(|(_, &b)| b.abs())
        .fold(0.0, f64::max);
    let t_rise = run
        .t
        .iter()
        .zip(&run.beta)
        .find(|(&t, &b)| t >= T_STEP && b >= 0.9 * TARGET)
        .map(|(&t, _)| t - T_STEP);
    let switches: usize = run
        .openings
        .windows(2)
        .map(|w| {
            (w[0].u_in1 != w[1].u_in1) as usize
                + (w[0].u_ex1 != w[1].u_ex1) as usize
                + (w[0].u_in2 != w[1].u_in2) as usize
                + (w[0].u_ex2 != w[1].u_ex2) as usize
        })
        .sum();
    let last = run.out.last().unwrap();
    println!(
        "step 0 -> {TARGET} rad at t = {T_STEP} s (1 kHz, on/off valves, PWM {} ticks, min on {} ticks):\n  \
         |beta| before step max {pre_max:.4} rad\n  rise to 90 %: {:?} s\n  settling (+-{BAND_RAD} rad): {:?} s\n  \
         overshoot {overshoot:.4} rad\n  error t >= 2 s: max {tail_max:.4} rad, rms {tail_rms:.5} rad\n  \
         final p_set = ({:.0}, {:.0}) Pa, torque_des {:.3} N m, torque_est {:.3} N m\n  \
         max muscle pressure {:.0} Pa gauge, valve switchings {switches} in 3 s",
        OnOffPwmConfig::REFERENCE.period_ticks,
        OnOffPwmConfig::REFERENCE.min_on_ticks,
        t_rise,
        ts,
        last.p1_set_gauge_pa,
        last.p2_set_gauge_pa,
        last.torque_des_nm,
        last.torque_est_nm,
        run.p_max_gauge,
    );
    assert!(pre_max < 0.02, "moved {pre_max} rad before the step");
    let ts = ts.expect("never settled");
    assert!(ts <= SETTLE_MAX_S, "settling {ts} s");
    assert!(overshoot <= OVERSHOOT_MAX_RAD, "overshoot {overshoot} rad");
    assert!(tail_max <= BAND_RAD);
    assert!(run.p_max_gauge <= 600_000.0 + 1.0);
    for o in &run.out {
        assert!(o.p1_set_gauge_pa <= 600_000.0 && o.p2_set_gauge_pa <= 600_000.0);
    }
}

fn nan_injection(safe: SafeState) {
    let k_nan = 1500; // 1.5 s: after the step has settled, in closed loop
    let mut cfg = ControllerConfig::reference(TICK_HZ);
    cfg.safe_state = safe;
    let run = simulate(J_NOMINAL, cfg, 1.7, T_STEP, TARGET as f32, |k, f| {
        if k == k_nan {
            f.p2_gauge_pa = Some(f32::NAN);
        }
    });
    // Until the injection: armed, no fault, and valves were actually working.
    assert!(run.out[..k_nan].iter().all(|o| o.fault.is_none()));
    assert!(run.out[k_nan - 1].armed);
    // The very tick with the NaN: fault latched and the safe state applied.
    let o = &run.out[k_nan];
    assert_eq!(o.fault, Some(FaultCode::PressureInvalid2));
    assert!(!o.armed);
    let want = match safe {
        SafeState::Hold => ValveCommand::default(),
        SafeState::Vent => ValveCommand {
            muscle1: -1.0,
            muscle2: -1.0,
        },
    };
    assert_eq!(o.valves, want);
    let want_open = match safe {
        SafeState::Hold => ValveOpenings::default(),
        SafeState::Vent => ValveOpenings {
            u_in1: 0.0,
            u_ex1: 1.0,
            u_in2: 0.0,
            u_ex2: 1.0,
        },
    };
    // Valve openings (what the plant gets) in the same tick and every tick after, although
    // the sensor data is good again from the next tick: the fault is latched.
    for k in k_nan..run.out.len() {
        assert_eq!(run.openings[k], want_open, "tick {k}");
        assert_eq!(run.out[k].fault, Some(FaultCode::PressureInvalid2));
    }
    // The tick log holds the NaN tick with its fault code, and the ticks before it armed.
    let recs: Vec<&TickRecord> = run.log.iter().collect();
    let at = recs.iter().position(|r| r.tick as usize == k_nan).unwrap();
    assert!(recs[at].p2_meas_gauge_pa.is_nan());
    assert_eq!(recs[at].fault_code, FaultCode::PressureInvalid2 as u8);
    assert!(recs[at - 1].armed && recs[at - 1].fault_code == 0);
    // Hold keeps the joint near where it was (the muscles keep their air).
    if safe == SafeState::Hold {
        let drift = (run.beta.last().unwrap() - run.beta[k_nan]).abs();
        println!("Hold after NaN: angle drift over 0.2 s = {drift:.4} rad");
        assert!(drift < 0.05);
    }
}

#[test]
fn nan_sensor_mid_run_gives_hold_state_in_same_tick_and_fault_code() {
    nan_injection(SafeState::Hold);
}

#[test]
fn nan_sensor_mid_run_gives_vent_state_in_same_tick_and_fault_code() {
    nan_injection(SafeState::Vent);
}

/// Robustness: the same gains on the loaded joint (11 x J, reference-1dof-loaded.toml)
/// must stay stable and settle, more slowly (measured on the real plant: 1.0 s, overshoot 0.107 rad).
#[test]
fn loaded_joint_11x_inertia_step_is_stable_and_settles() {
    let run = simulate(
        11.0 * J_NOMINAL,
        ControllerConfig::reference(TICK_HZ),
        4.0,
        T_STEP,
        TARGET as f32,
        |_, _| {},
    );
    assert!(run.out.iter().all(|o| o.fault.is_none()));
    let ts = settling_time(&run, T_STEP, TARGET, BAND_RAD).expect("never settled");
    let peak = run.beta.iter().cloned().fold(f64::MIN, f64::max);
    println!(
        "loaded joint (J = {:.3} kg m^2): settling (+-{BAND_RAD} rad) {ts:.3} s, overshoot {:.4} rad",
        11.0 * J_NOMINAL,
        peak - TARGET
    );
    assert!(ts <= 2.0, "settling {ts} s");
    assert!(peak - TARGET <= 0.12);
}
