//! Firmware in the loop on the 3-DOF arm ([`crate::plant::arm3`]): the firmware's
//! [`ArmTick`] (three joint ticks and the rigid-body feed-forward, `pam_firmware::arm`)
//! drives the six muscles of the arm plant, one control period per tick.
//!
//! Per tick `k` (period `dt = 1 / tick_hz`):
//! 1. every joint's angle and pressures at `t_k` pass the joint's sensor path (its
//!    `[jointN.effects]` sensor lag and calibration, [`Arm3::sensor_paths`]), then the
//!    scenario's [`SensorModel`] (the 1-DOF loop's: pressure noise and ADC resolution,
//!    encoder quantisation);
//! 2. [`ArmTick::step`] turns the three frames and set-points into three valve commands;
//! 3. each joint's command goes through the firmware's on/off valve driver
//!    ([`OnOffValves`], tick-level PWM, as the 1-DOF loop) on fake pins; the switched valves
//!    are reported back to the tick ([`ArmTick::valves_switched`]); they reach the plant
//!    through the joint's valve dead time ([`Arm3::actuator_paths`]) and are held over
//!    `[t_k, t_k + dt)`;
//! 4. the arm is integrated over the tick ([`Arm3Integrator`], Dopri5).
//!
//! The run's recording ([`ArmRun::to_recording`]) holds the switched valves (the commands,
//! before any dead time, as a rig logs them) and the sensors' channels, so `host-sim simulate
//! --plant arm3.toml --inputs` on it reproduces it.
//!
//! Scenario files (`scenarios/arm3/*.toml`) reuse the 1-DOF scenario's `[scenario]` and
//! `[sensors]` tables and set-point shapes ([`SetpointProfile`], one per joint, or a
//! `[setpoint] waypoints` sequence of minimum-jerk moves); `[expect]` bounds the per-joint
//! tracking error and the muscle pressure.

use std::path::Path;

use pam_firmware::arm::{ArmConfig, ArmFrame, ArmSetpoint, ArmTick, JOINTS};
use pam_firmware::tick::SensorFrame;
use pam_firmware::valves::{OnOffPwmConfig, OnOffValves, ValveOpenings};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use serde::Deserialize;

use crate::control::closed_loop::{FakePin, TrackingStats};
use crate::io::arm3::Arm3Recording;
use std::f64::consts::PI;

use crate::io::scenario::{
    check_expect, key_error, key_line, read_scenario_text, ClosedLoopError, ScenarioHeader,
    SensorModel, SetpointProfile,
};
use crate::plant::arm3::{Arm3, Arm3Inputs, Arm3State};
use crate::plant::ValveInputs;
use crate::sim::arm3::Arm3Integrator;
use crate::sim::SolverOptions;

/// An arm scenario (TOML). Unknown keys are errors.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArmScenario {
    /// `[scenario]`: name, length, tick rate, seed (as the 1-DOF scenario).
    pub scenario: ScenarioHeader,
    /// `[setpoint]`: per-joint profiles or a waypoint sequence.
    pub setpoint: ArmSetpointSpec,
    /// `[sensors]`: noise and quantisation (as the 1-DOF scenario; no delay, SI only).
    #[serde(default)]
    pub sensors: SensorModel,
    /// `[expect]`: bounds a run must meet.
    #[serde(default)]
    pub expect: ArmExpectations,
}

/// `[setpoint]`: either `joint1`..`joint3` (each a 1-DOF set-point profile, a joint without
/// one holds `hold_rad`), or `waypoints`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArmSetpointSpec {
    /// Angles [rad] of a joint without a profile (and before the first waypoint).
    pub hold_rad: Option<[f64; JOINTS]>,
    /// Joint 1 profile.
    pub joint1: Option<SetpointProfile>,
    /// Joint 2 profile.
    pub joint2: Option<SetpointProfile>,
    /// Joint 3 profile.
    pub joint3: Option<SetpointProfile>,
    /// `[t_s, q1_rad, q2_rad, q3_rad]` rows, times increasing: from each waypoint the joints
    /// move to the next in a minimum-jerk move of `move_s` (starting at the next waypoint's
    /// time minus `move_s`), then hold.
    pub waypoints: Option<Vec<[f64; 4]>>,
    /// Duration of each waypoint move [s].
    pub move_s: Option<f64>,
}

/// `[expect]` of an arm scenario.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArmExpectations {
    /// Where the error bounds start [s].
    #[serde(default)]
    pub settle_after_s: f64,
    /// Largest |angle error| per joint after `settle_after_s` [rad].
    pub max_abs_error_rad: Option<[f64; JOINTS]>,
    /// Root-mean-square angle error per joint after `settle_after_s` [rad].
    pub rms_error_rad: Option<[f64; JOINTS]>,
    /// Highest gauge pressure of any of the six muscles over the whole run [kPa].
    pub max_pressure_kpa: Option<f64>,
    /// No fault may be latched during the run.
    #[serde(default)]
    pub no_fault: bool,
}

impl ArmExpectations {
    /// True when the scenario sets no bound (no `[expect]` table, or only `settle_after_s`).
    pub fn is_empty(&self) -> bool {
        self.max_abs_error_rad.is_none()
            && self.rms_error_rad.is_none()
            && self.max_pressure_kpa.is_none()
            && !self.no_fault
    }
}

impl ArmScenario {
    /// Reads and validates an arm scenario file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ClosedLoopError> {
        let (text, file) = read_scenario_text(path.as_ref())?;
        Self::from_toml_str(&text, &file)
    }

    /// Parses and validates arm scenario text (`file` names it in errors).
    pub fn from_toml_str(text: &str, file: &str) -> Result<Self, ClosedLoopError> {
        let s: ArmScenario = toml::from_str(text).map_err(|e| ClosedLoopError::Scenario {
            file: file.to_string(),
            msg: crate::io::scenario::toml_error_message(&e, text),
        })?;
        let bad = key_error(text, file);
        s.scenario.check(&bad)?;
        if s.sensors.delay_ticks != 0 {
            return Err(bad(
                "sensors",
                "delay_ticks",
                "the arm loop has no transport delay: must be 0".into(),
            ));
        }
        if s.sensors.board_counts {
            return Err(bad(
                "sensors",
                "board_counts",
                "the arm loop feeds SI frames: must be false".into(),
            ));
        }
        // The 1-DOF scenario's checks: sensors, each joint's profile, the [expect] values.
        s.sensors.check(&|key, msg| bad("sensors", key, msg))?;
        let h = &s.scenario;
        let sp = &s.setpoint;
        for (j, p) in [&sp.joint1, &sp.joint2, &sp.joint3].iter().enumerate() {
            if let Some(p) = p {
                let joint = format!("joint{}", j + 1);
                p.check(h, &|key, msg| {
                    // `jointN = { ... }` in [setpoint], or a [setpoint.jointN] table.
                    let line = key_line(text, &format!("setpoint.{joint}"), key)
                        .or_else(|| key_line(text, "setpoint", &joint));
                    ClosedLoopError::Scenario {
                        file: file.to_string(),
                        msg: format!(
                            "{}[setpoint] {joint}.{key}: {msg}",
                            line.map(|l| format!("line {l}: ")).unwrap_or_default()
                        ),
                    }
                })?;
            }
        }
        let e = &s.expect;
        let per_joint = |b: Option<[f64; JOINTS]>, j: usize| b.map(|b| b[j]);
        check_expect(
            h,
            e.settle_after_s,
            e.max_pressure_kpa,
            &[
                ("max_abs_error_rad", per_joint(e.max_abs_error_rad, 0)),
                ("max_abs_error_rad", per_joint(e.max_abs_error_rad, 1)),
                ("max_abs_error_rad", per_joint(e.max_abs_error_rad, 2)),
                ("rms_error_rad", per_joint(e.rms_error_rad, 0)),
                ("rms_error_rad", per_joint(e.rms_error_rad, 1)),
                ("rms_error_rad", per_joint(e.rms_error_rad, 2)),
            ],
            &|key, msg| bad("expect", key, msg),
        )?;
        let profiles = [&sp.joint1, &sp.joint2, &sp.joint3];
        if let Some(w) = &sp.waypoints {
            if profiles.iter().any(|p| p.is_some()) {
                return Err(bad(
                    "setpoint",
                    "waypoints",
                    "either waypoints or per-joint profiles, not both".into(),
                ));
            }
            if w.len() < 2 {
                return Err(bad("setpoint", "waypoints", "needs at least 2 rows".into()));
            }
            if w.iter().flatten().any(|v| !v.is_finite())
                || w.windows(2).any(|p| p[1][0] <= p[0][0])
            {
                return Err(bad(
                    "setpoint",
                    "waypoints",
                    "values must be finite and the times increasing".into(),
                ));
            }
            if let Some(v) = w.iter().flat_map(|r| &r[1..]).find(|v| v.abs() > PI) {
                return Err(bad(
                    "setpoint",
                    "waypoints",
                    format!("{v} rad is more than half a turn (allowed -pi..=pi): degrees typed as radians?"),
                ));
            }
            if let Some(r) = w.iter().find(|r| !(r[0] >= 0.0 && r[0] < h.duration_s)) {
                return Err(bad(
                    "setpoint",
                    "waypoints",
                    format!(
                        "time {} s must be within [0, {}) (before the end of the run, [scenario] \
                         duration_s)",
                        r[0], h.duration_s
                    ),
                ));
            }
            match sp.move_s {
                Some(m) if m > 0.0 && m.is_finite() => {
                    if w.windows(2).any(|p| p[1][0] - p[0][0] < m) {
                        return Err(bad(
                            "setpoint",
                            "move_s",
                            format!("{m} s is longer than the gap between two waypoints"),
                        ));
                    }
                }
                _ => {
                    return Err(bad(
                        "setpoint",
                        "move_s",
                        "required with waypoints, > 0".into(),
                    ))
                }
            }
        } else if profiles.iter().all(|p| p.is_none()) {
            return Err(bad(
                "setpoint",
                "joint1",
                "give joint1..joint3 profiles or waypoints".into(),
            ));
        }
        for (j, p) in profiles.iter().enumerate() {
            if let Some(SetpointProfile::Random { .. }) = p {
                return Err(bad(
                    &format!("setpoint.joint{}", j + 1),
                    "kind",
                    "random set-points are 1-DOF only (step, ramp, sine)".into(),
                ));
            }
        }
        if let Some(hold) = sp.hold_rad {
            if hold.iter().any(|v| !(v.is_finite() && v.abs() <= PI)) {
                return Err(bad(
                    "setpoint",
                    "hold_rad",
                    format!("{hold:?}: every angle must be within -pi..=pi rad"),
                ));
            }
        }
        Ok(s)
    }

    /// The three joint set-points [rad] at `t_s`.
    pub fn setpoint_at(&self, t_s: f64) -> [f64; JOINTS] {
        let sp = &self.setpoint;
        if let (Some(w), Some(move_s)) = (&sp.waypoints, sp.move_s) {
            // Before the first waypoint: its angles. Then from waypoint i to i + 1.
            let i = w.iter().rposition(|p| p[0] <= t_s);
            return match i {
                None => [w[0][1], w[0][2], w[0][3]],
                Some(i) if i + 1 >= w.len() => [w[i][1], w[i][2], w[i][3]],
                Some(i) => {
                    let start = w[i + 1][0] - move_s;
                    std::array::from_fn(|j| {
                        pam_firmware::profile::step_at(
                            t_s,
                            w[i][j + 1],
                            w[i + 1][j + 1],
                            start,
                            move_s,
                        )
                    })
                }
            };
        }
        let hold = sp.hold_rad.unwrap_or([0.0; JOINTS]);
        let profiles = [&sp.joint1, &sp.joint2, &sp.joint3];
        std::array::from_fn(|j| match profiles[j] {
            Some(p) => p.at(t_s, &[]),
            None => hold[j],
        })
    }
}

/// One tick of an arm run.
#[derive(Debug, Clone, Copy)]
pub struct ArmTickRow {
    /// Time [s].
    pub t_s: f64,
    /// Set-points [rad].
    pub setpoint_rad: [f64; JOINTS],
    /// True plant state at `t_s`.
    pub state: Arm3State,
    /// Valve openings applied over the tick.
    pub inputs: Arm3Inputs,
    /// Per joint: the tick's desired torque [N m] (feed-forward included).
    pub torque_des_nm: [f64; JOINTS],
    /// Per joint: the rigid-body feed-forward [N m].
    pub feedforward_nm: [f64; JOINTS],
    /// The arm's latched fault code (0 = none) and joint (1-based, 0 = none).
    pub fault: (u8, u8),
}

/// A closed-loop arm run.
#[derive(Debug, Clone)]
pub struct ArmRun {
    /// The scenario's name.
    pub name: String,
    /// Tick period [s].
    pub dt_s: f64,
    /// One row per tick.
    pub rows: Vec<ArmTickRow>,
    /// The scenario's bounds.
    pub expect: ArmExpectations,
    /// Atmospheric pressure of the plant [Pa].
    pub p_atm_pa: f64,
}

/// Runs `scenario` on `arm` with the firmware's arm tick configured by `cfg`.
pub fn run_arm(
    arm: &Arm3,
    scenario: &ArmScenario,
    cfg: ArmConfig,
) -> Result<ArmRun, ClosedLoopError> {
    let h = &scenario.scenario;
    let dt_s = 1.0 / h.tick_hz;
    let n = (h.duration_s / dt_s).round() as usize;
    let mut rng = rand::rngs::StdRng::seed_from_u64(h.seed);
    let p_noise = Normal::new(0.0, scenario.sensors.pressure_noise_pa).map_err(|e| {
        ClosedLoopError::Scenario {
            file: h.name.clone(),
            msg: format!("pressure noise: {e}"),
        }
    })?;
    let sensors = &scenario.sensors;
    let mut tick = ArmTick::new(cfg);
    let mut drivers: [OnOffValves<FakePin, FakePin, FakePin, FakePin>; JOINTS] =
        std::array::from_fn(|_| {
            OnOffValves::new(
                FakePin::default(),
                FakePin::default(),
                FakePin::default(),
                FakePin::default(),
                OnOffPwmConfig::REFERENCE,
            )
        });
    let opts = SolverOptions::default();
    let mut integ = Arm3Integrator::new(arm, arm.initial, opts);
    let mut valves =
        arm.actuator_paths(dt_s, "closed loop")
            .map_err(|e| ClosedLoopError::Firmware {
                tick: 0,
                msg: e.to_string(),
            })?;
    let mut sensor_paths = arm.sensor_paths(dt_s);
    let mut rows = Vec::with_capacity(n);
    for k in 0..n {
        let t_s = k as f64 * dt_s;
        let x = integ.state();
        // What the joints' sensors report (their lag and calibration), then the scenario's
        // noise and quantisation.
        let reported = arm.measure_with(&mut sensor_paths, &x);
        let mut frame = ArmFrame::default();
        for j in 0..JOINTS {
            let mut p = |gauge_kpa: f64| {
                let v = gauge_kpa * 1000.0 + p_noise.sample(&mut rng);
                let lsb = sensors.pressure_lsb_pa;
                (if lsb > 0.0 {
                    (v / lsb).round() * lsb
                } else {
                    v
                }) as f32
            };
            let p1 = p(reported[j].p1_kpa);
            let p2 = p(reported[j].p2_kpa);
            let q = reported[j].angle_deg.to_radians();
            let counts = sensors.angle_counts_per_rev;
            let angle = if counts > 0 {
                let c = (q / std::f64::consts::TAU * counts as f64).floor() as i32;
                pam_firmware::sensors::counts_to_rad(c, counts)
            } else {
                q as f32
            };
            frame.joints[j] = SensorFrame {
                p1_gauge_pa: Some(p1),
                p2_gauge_pa: Some(p2),
                angle_rad: Some(angle),
            };
        }
        let sp = scenario.setpoint_at(t_s);
        let out = tick.step(
            &frame,
            &ArmSetpoint {
                angles_rad: sp.map(|v| v as f32),
            },
            dt_s as f32,
        );
        let inputs: Arm3Inputs = std::array::from_fn(|j| {
            let o = match drivers[j].apply_switched(&out.joints[j].valves) {
                Ok(sw) => {
                    tick.valves_switched(j, sw);
                    sw.openings()
                }
                // Fake pins cannot fail; closed valves if they ever did.
                Err(_) => ValveOpenings::default(),
            };
            ValveInputs {
                u_in1: f64::from(o.u_in1),
                u_ex1: f64::from(o.u_ex1),
                u_in2: f64::from(o.u_in2),
                u_ex2: f64::from(o.u_ex2),
            }
        });
        let applied: Arm3Inputs = std::array::from_fn(|j| valves[j].push(inputs[j]));
        integ
            .advance_samples(applied, dt_s, 1, |_| {})
            .map_err(|e| ClosedLoopError::Firmware {
                tick: k,
                msg: format!("arm plant integration failed: {e}"),
            })?;
        rows.push(ArmTickRow {
            t_s,
            setpoint_rad: sp,
            state: x,
            inputs,
            torque_des_nm: std::array::from_fn(|j| f64::from(out.joints[j].torque_des_nm)),
            feedforward_nm: out.feedforward_nm.map(f64::from),
            fault: out
                .fault
                .map(|f| (f.code.code(), f.joint + 1))
                .unwrap_or((0, 0)),
        });
    }
    Ok(ArmRun {
        name: h.name.clone(),
        dt_s,
        rows,
        expect: scenario.expect.clone(),
        p_atm_pa: arm.p_atm_pa,
    })
}

impl ArmRun {
    /// Per-joint tracking statistics from `after_s` on, over the ticks without a latched
    /// fault.
    pub fn tracking(&self, after_s: f64) -> [TrackingStats; JOINTS] {
        std::array::from_fn(|j| {
            TrackingStats::of_errors(
                self.rows
                    .iter()
                    .filter(|r| r.t_s >= after_s && r.fault.0 == 0)
                    .map(|r| r.state.angles_rad[j] - r.setpoint_rad[j]),
            )
        })
    }

    /// Highest gauge pressure of any muscle over the run [kPa].
    pub fn max_pressure_kpa(&self) -> f64 {
        self.rows
            .iter()
            .flat_map(|r| r.state.p_abs_pa.iter().flatten())
            .fold(f64::NEG_INFINITY, |m, p| m.max((p - self.p_atm_pa) / 1e3))
    }

    /// The first latched fault: (time [s], code, joint 1-based).
    pub fn first_fault(&self) -> Option<(f64, u8, u8)> {
        self.rows
            .iter()
            .find(|r| r.fault.0 != 0)
            .map(|r| (r.t_s, r.fault.0, r.fault.1))
    }

    /// Checks the scenario's expectations; the failures as sentences.
    pub fn check(&self) -> Vec<String> {
        let e = &self.expect;
        let mut fails = Vec::new();
        let st = self.tracking(e.settle_after_s);
        for j in 0..JOINTS {
            if (e.max_abs_error_rad.is_some() || e.rms_error_rad.is_some()) && st[j].n == 0 {
                fails.push(format!(
                    "joint {}: no tick without a latched fault after {} s to bound the error",
                    j + 1,
                    e.settle_after_s
                ));
                continue;
            }
            for (what, bound, value) in [
                ("max |error|", e.max_abs_error_rad, st[j].max_abs_rad),
                ("rms error", e.rms_error_rad, st[j].rms_rad),
            ] {
                if let Some(b) = bound {
                    if !(value <= b[j]) {
                        fails.push(format!(
                            "joint {}: {what} {value:.4} rad after {} s exceeds {} rad",
                            j + 1,
                            e.settle_after_s,
                            b[j]
                        ));
                    }
                }
            }
        }
        if let Some(b) = e.max_pressure_kpa {
            let p = self.max_pressure_kpa();
            if !(p <= b) {
                fails.push(format!("max muscle pressure {p:.1} kPa exceeds {b} kPa"));
            }
        }
        if e.no_fault {
            if let Some((t, code, joint)) = self.first_fault() {
                fails.push(format!(
                    "fault code {code} latched by joint {joint} at t = {t:.3} s (no_fault)"
                ));
            }
        }
        fails
    }

    /// The run as a 3-joint recording: the switched valves and the sensors' channels.
    pub fn to_recording(&self, arm: &Arm3, plant: &str, scenario: &str) -> Arm3Recording {
        let mut rec = Arm3Recording {
            metadata: vec![
                ("plant".into(), plant.into()),
                ("scenario".into(), scenario.into()),
                ("sample_period_s".into(), format!("{}", self.dt_s)),
                (
                    "source".into(),
                    "host-sim arm closed loop (pam_firmware::arm::ArmTick in the loop)".into(),
                ),
            ],
            t_s: self.rows.iter().map(|r| r.t_s).collect(),
            inputs: self.rows.iter().map(|r| r.inputs).collect(),
            ..Default::default()
        };
        let states: Vec<Arm3State> = self.rows.iter().map(|r| r.state).collect();
        rec.set_outputs_from_states(arm, &states, self.dt_s);
        rec
    }

    /// The set-points as a recording (angle channels only), to plot under the run.
    pub fn setpoint_recording(&self) -> Arm3Recording {
        let mut rec = Arm3Recording {
            t_s: self.rows.iter().map(|r| r.t_s).collect(),
            inputs: self.rows.iter().map(|r| r.inputs).collect(),
            ..Default::default()
        };
        for j in 0..JOINTS {
            rec.outputs[j][crate::io::recording::Channel::AngleDeg.index()] = Some(
                self.rows
                    .iter()
                    .map(|r| r.setpoint_rad[j].to_degrees())
                    .collect(),
            );
        }
        rec
    }

    /// The firmware side as CSV text: set-points, desired torques, feed-forward, fault.
    pub fn firmware_trace_csv(&self) -> String {
        let mut s = String::from("t_s");
        for j in 1..=JOINTS {
            s += &format!(",setpoint_deg_j{j},torque_des_nm_j{j},feedforward_nm_j{j}");
        }
        s += ",fault_code,fault_joint\n";
        for r in &self.rows {
            s += &format!("{:.6}", r.t_s);
            for j in 0..JOINTS {
                s += &format!(
                    ",{:.6},{:.6},{:.6}",
                    r.setpoint_rad[j].to_degrees(),
                    r.torque_des_nm[j],
                    r.feedforward_nm[j]
                );
            }
            s += &format!(",{},{}\n", r.fault.0, r.fault.1);
        }
        s
    }
}
