//! The control tick of the 3-DOF arm of seed 001 (docs/arm3.md): three joint
//! [`ControlTick`]s, one per joint with its own force law, torque model, geometry, valve model
//! and gains (`config/arm3.toml`, generated into [`constants`] by build.rs), run in one control
//! period, plus the arm's rigid-body feed-forward evaluated here on the MCU:
//!
//! ```text
//! tau_ff = M(q) r'' + G(q)      (each joint clamped to +-feedforward_limit_nm)
//! ```
//!
//! - `G(q)` is the gravity torque of seed 001's model (joint 1 vertical: none; joints 2 and 3:
//!   `g (m2 lc2 + m3 l2) cos q2 + g m3 lc3 cos(q2 + q3)` and `g m3 lc3 cos(q2 + q3)`), at the
//!   measured angles (the last accepted sample of each joint: a smooth function of the pose,
//!   so the measured pose is the one that has to be held).
//! - `M(q) r''` is the inertia torque of the desired motion with the full mass matrix (the
//!   coupling `M23` between joints 2 and 3 and the pose-dependent `M11` of joint 1 included);
//!   `r''` is the filtered second difference of each joint's set-point (the same
//!   [`SetpointDerivatives`] as the 1-DOF feed-forward), so the joint ticks run with their own
//!   inertia term off. The Coriolis / centrifugal term `C(q, q') q'` is left out: at the
//!   arm's speeds (< 1 rad/s) it is below the friction (docs/arm3.md).
//!
//! The feed-forward enters each joint tick after its position loop
//! ([`ControlTick::step_with_torque`]), so the torque loop inverts the joint's torque model
//! for `T_pid + T_ff(trajectory) + tau_ff`.
//!
//! Faults: a fault latched by any joint puts all six muscles in the safe state: the other
//! joints' outputs are replaced by their configured safe command (their pressure set-points
//! held at the last accepted measurement, or 0 when venting) until [`ArmTick::reset`], which
//! re-arms every joint only when every one accepts its reset. The healthy joints keep running
//! their validation meanwhile (their channels do not go stale).
//!
//! `no_std`, f32, libm, no allocation; no panic on any sensor value or set-point.

use crate::control::PidGains;
use crate::feedforward::SetpointDerivatives;
use crate::force_law::ForceLawParams;
use crate::geometry::JointGeometry;
use crate::safety::{clamp_pressure_setpoint_pa, FaultCode, SafeState};
use crate::tick::config::ControllerConfig;
use crate::tick::io::{SensorFrame, Setpoint, TickOutput};
use crate::tick::ControlTick;
use crate::torque_model::TorqueModelParams;
use crate::valves::{ValveCommand, ValveOpenings};
use crate::P_MUSCLE_MAX_GAUGE_PA;

/// Constants generated from `config/arm3.toml` by build.rs.
pub mod constants {
    include!(concat!(env!("OUT_DIR"), "/arm3_constants.rs"));
}

/// Number of joints.
pub const JOINTS: usize = 3;

/// Rigid-body constants of the arm (seed 001 tables 3-4; `config/arm3.toml` [links]).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ArmLinks {
    /// I_x2 [kg m^2].
    pub ix2_kgm2: f32,
    /// I_x3 [kg m^2].
    pub ix3_kgm2: f32,
    /// I_y2 [kg m^2].
    pub iy2_kgm2: f32,
    /// I_y3 [kg m^2].
    pub iy3_kgm2: f32,
    /// I_z1 [kg m^2].
    pub iz1_kgm2: f32,
    /// I_z2 [kg m^2].
    pub iz2_kgm2: f32,
    /// I_z3 [kg m^2].
    pub iz3_kgm2: f32,
    /// Mass of link 2 [kg].
    pub m2_kg: f32,
    /// Mass of link 3 [kg].
    pub m3_kg: f32,
    /// Length of link 2 [m].
    pub l2_m: f32,
    /// Centre of mass of link 2 from joint 2 [m].
    pub lc2_m: f32,
    /// Centre of mass of link 3 from joint 3 [m].
    pub lc3_m: f32,
    /// Gravity [m/s^2].
    pub g_m_s2: f32,
}

impl ArmLinks {
    /// True when every constant is finite and non-negative.
    pub fn is_valid(&self) -> bool {
        [
            self.ix2_kgm2,
            self.ix3_kgm2,
            self.iy2_kgm2,
            self.iy3_kgm2,
            self.iz1_kgm2,
            self.iz2_kgm2,
            self.iz3_kgm2,
            self.m2_kg,
            self.m3_kg,
            self.l2_m,
            self.lc2_m,
            self.lc3_m,
            self.g_m_s2,
        ]
        .iter()
        .all(|x| x.is_finite() && *x >= 0.0)
    }

    /// Gravity torques `G(q) = dV/dq` [N m] (q2 = elevation of link 2, q3 relative to it).
    pub fn gravity_torques_nm(&self, q_rad: &[f32; JOINTS]) -> [f32; JOINTS] {
        let c2 = libm::cosf(q_rad[1]);
        let c23 = libm::cosf(q_rad[1] + q_rad[2]);
        let g3 = self.g_m_s2 * self.m3_kg * self.lc3_m * c23;
        let g2 = self.g_m_s2 * (self.m2_kg * self.lc2_m + self.m3_kg * self.l2_m) * c2 + g3;
        [0.0, g2, g3]
    }

    /// `M(q) a` and `G(q)` in one pass (the sines and cosines shared) [N m].
    pub fn inertia_and_gravity_nm(
        &self,
        q_rad: &[f32; JOINTS],
        accel_rad_s2: &[f32; JOINTS],
    ) -> ([f32; JOINTS], [f32; JOINTS]) {
        let (s2, c2) = (libm::sinf(q_rad[1]), libm::cosf(q_rad[1]));
        let q23 = q_rad[1] + q_rad[2];
        let (s23, c23) = (libm::sinf(q23), libm::cosf(q23));
        let c3 = libm::cosf(q_rad[2]);
        let a = self.l2_m * c2 + self.lc3_m * c23;
        let lc2_sq = self.lc2_m * self.lc2_m;
        let lc3_sq = self.lc3_m * self.lc3_m;
        let m11 = self.iy2_kgm2 * s2 * s2
            + self.iy3_kgm2 * s23 * s23
            + self.iz1_kgm2
            + self.iz2_kgm2 * c2 * c2
            + self.iz3_kgm2 * c23 * c23
            + self.m2_kg * lc2_sq * c2 * c2
            + self.m3_kg * a * a;
        let m33 = self.ix3_kgm2 + self.m3_kg * lc3_sq;
        let m23 = m33 + self.m3_kg * self.l2_m * self.lc3_m * c3;
        let m22 = self.ix2_kgm2
            + self.ix3_kgm2
            + self.m3_kg * self.l2_m * self.l2_m
            + self.m2_kg * lc2_sq
            + self.m3_kg * lc3_sq
            + 2.0 * self.m3_kg * self.l2_m * self.lc3_m * c3;
        let inertia = [
            m11 * accel_rad_s2[0],
            m22 * accel_rad_s2[1] + m23 * accel_rad_s2[2],
            m23 * accel_rad_s2[1] + m33 * accel_rad_s2[2],
        ];
        let g3 = self.g_m_s2 * self.m3_kg * self.lc3_m * c23;
        let g2 = self.g_m_s2 * (self.m2_kg * self.lc2_m + self.m3_kg * self.l2_m) * c2 + g3;
        (inertia, [0.0, g2, g3])
    }
}

/// One joint's constants (`config/arm3.toml` [jointN], scaled from the reference muscle by
/// build.rs).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ArmJointConstants {
    /// Sprocket radius, rest length, initial contraction.
    pub geometry: JointGeometry,
    /// The reference force law scaled to this joint's muscle.
    pub force_law: ForceLawParams,
    /// The reference torque model mapped to this joint.
    pub torque_model: TorqueModelParams,
    /// Chamber volume polynomial of this joint's muscles (valve supervision) [m^3].
    pub volume_poly_m3: [f32; 4],
    /// ISO 6358 sonic conductance of the arm's valves [m^3/(s Pa)].
    pub valve_conductance_m3_per_s_pa: f32,
    /// ISO 6358 critical pressure ratio of the arm's valves.
    pub valve_critical_ratio: f32,
    /// Expected change at which the valve supervision's integrated check judges [Pa].
    pub valve_integral_min_pa: f32,
    /// Position-loop gains.
    pub position: PidGains,
    /// Torque-loop integral gain [1/s].
    pub torque_ki_per_s: f32,
    /// Torque-loop correction limit [N m].
    pub torque_corr_limit_nm: f32,
    /// |tau_ff| limit of this joint [N m].
    pub feedforward_limit_nm: f32,
    /// Saturated valve command without reaching the pressure set-point for this long [s]
    /// raises `PressureTrackingLost1/2` (the 1-DOF tick's 0.3 s scaled with the chamber
    /// volume and the arm's pressure swings).
    pub tracking_time_s: f32,
}

impl ArmJointConstants {
    /// The joint tick's configuration: [`ControllerConfig::reference`] (validation, pressure
    /// loop, safety, start ramp) with this joint's force law, torque model, geometry, valve
    /// model and gains; the tick's own inertia feed-forward off (the arm supplies `M(q) r''`).
    pub fn controller_config(&self, tick_hz: f32) -> ControllerConfig {
        let mut c = ControllerConfig::reference(tick_hz);
        c.geometry = self.geometry;
        c.force_law = self.force_law;
        c.torque_model = self.torque_model;
        c.position = self.position;
        c.torque.ki_per_s = self.torque_ki_per_s;
        c.torque.corr_limit_nm = self.torque_corr_limit_nm;
        c.feedforward.inertia_kgm2 = 0.0;
        // The rate term `kd r'` of the arm's heavier joints needs more than the 1-DOF joint's
        // 2 N m: the position loop's own output limit.
        c.feedforward.limit_nm = self.position.out_limit_nm;
        // `as` saturates (NaN -> 0); at least one tick.
        let ticks = libm::ceilf(self.tracking_time_s * tick_hz) as u32;
        c.tracking_ticks = if ticks < 1 { 1 } else { ticks };
        c.valve_model.volume_poly_m3 = self.volume_poly_m3;
        c.valve_model.conductance_m3_per_s_pa = self.valve_conductance_m3_per_s_pa;
        c.valve_model.critical_ratio = self.valve_critical_ratio;
        c.valve_model.integral_min_pa = self.valve_integral_min_pa;
        c
    }
}

/// Configuration of the arm tick.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ArmConfig {
    /// The three joint ticks.
    pub joints: [ControllerConfig; JOINTS],
    /// The rigid-body model of the feed-forward.
    pub links: ArmLinks,
    /// |tau_ff| limit per joint [N m].
    pub feedforward_limit_nm: [f32; JOINTS],
    /// Cutoff of the set-point differentiators of `M(q) r''` [Hz] (0: no inertia term).
    pub accel_cutoff_hz: f32,
    /// Gravity term on (false: the joints see no `G(q)`; for comparisons).
    pub gravity: bool,
}

impl ArmConfig {
    /// The generated constants ([`constants`]) at `tick_hz`; the set-point differentiators
    /// at the 1-DOF feed-forward's cutoff.
    pub fn reference(tick_hz: f32) -> Self {
        let j = &constants::ARM3_JOINTS;
        let joints = [
            j[0].controller_config(tick_hz),
            j[1].controller_config(tick_hz),
            j[2].controller_config(tick_hz),
        ];
        ArmConfig {
            accel_cutoff_hz: joints[0].feedforward.cutoff_hz,
            joints,
            links: constants::ARM3_LINKS,
            feedforward_limit_nm: [
                j[0].feedforward_limit_nm,
                j[1].feedforward_limit_nm,
                j[2].feedforward_limit_nm,
            ],
            gravity: true,
        }
    }
}

/// What the sensors of the three joints delivered this tick.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct ArmFrame {
    /// Joint 1..3.
    pub joints: [SensorFrame; JOINTS],
}

/// The joint-angle set-points [rad].
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct ArmSetpoint {
    /// Joint 1..3 [rad].
    pub angles_rad: [f32; JOINTS],
}

/// The fault that put the arm in its safe state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ArmFault {
    /// The first joint (0-based) that latched a fault in the first faulted tick.
    pub joint: u8,
    /// That joint's fault cause.
    pub code: FaultCode,
}

/// Everything one arm tick produced.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ArmTickOutput {
    /// Per joint. While the arm is faulted, a joint that did not fault itself reports the
    /// arm's cause in `fault`, `armed = false`, and its safe command.
    pub joints: [TickOutput; JOINTS],
    /// The rigid-body feed-forward given to each joint this tick [N m] (finite).
    pub feedforward_nm: [f32; JOINTS],
    /// The latched arm fault (Some => all six muscles are in the safe state).
    pub fault: Option<ArmFault>,
}

/// The arm tick. No allocation, no panic, no hidden time.
pub struct ArmTick {
    joints: [ControlTick; JOINTS],
    links: ArmLinks,
    links_ok: bool,
    ff_limit_nm: [f32; JOINTS],
    accel_cutoff_hz: f32,
    gravity: bool,
    derivatives: [SetpointDerivatives; JOINTS],
    /// Angles of the rigid-body model: the last accepted sample of each joint [rad].
    q_rad: [f32; JOINTS],
    /// Last finite pressure samples (the held set-points of the safe state) [Pa gauge].
    p_last_pa: [[f32; 2]; JOINTS],
    fault: Option<ArmFault>,
}

impl ArmTick {
    /// A tick in the armed state. An invalid joint configuration latches that joint's
    /// `ConfigInvalid` (and so the arm's fault); invalid links switch the feed-forward off.
    pub fn new(cfg: ArmConfig) -> Self {
        let links_ok = cfg.links.is_valid();
        ArmTick {
            joints: [
                ControlTick::new(cfg.joints[0]),
                ControlTick::new(cfg.joints[1]),
                ControlTick::new(cfg.joints[2]),
            ],
            links: cfg.links,
            links_ok,
            ff_limit_nm: cfg.feedforward_limit_nm.map(|x| {
                if x.is_finite() {
                    libm::fabsf(x)
                } else {
                    0.0
                }
            }),
            accel_cutoff_hz: cfg.accel_cutoff_hz,
            gravity: cfg.gravity,
            derivatives: [SetpointDerivatives::new(); JOINTS],
            q_rad: [0.0; JOINTS],
            p_last_pa: [[0.0; 2]; JOINTS],
            fault: None,
        }
    }

    /// Joint `i`'s tick.
    pub fn joint(&self, i: usize) -> Option<&ControlTick> {
        self.joints.get(i)
    }

    /// The latched arm fault.
    pub fn fault(&self) -> Option<ArmFault> {
        self.fault
    }

    /// Re-arms all joints after a fault: true when every joint accepted its reset (no fault
    /// condition held in the last tick); otherwise the arm stays faulted.
    pub fn reset(&mut self) -> bool {
        let mut ok = true;
        for j in self.joints.iter_mut() {
            ok &= j.reset();
        }
        if ok {
            self.fault = None;
            for d in self.derivatives.iter_mut() {
                d.reset();
            }
        }
        ok
    }

    /// Reports what joint `i`'s valve driver applied (see [`ControlTick::valves_applied`]).
    pub fn valves_applied(&mut self, i: usize, o: &ValveOpenings) {
        if let Some(j) = self.joints.get_mut(i) {
            j.valves_applied(o);
        }
    }

    /// Reports which on/off valves joint `i`'s driver switched open (see
    /// [`ControlTick::valves_switched`]).
    pub fn valves_switched(&mut self, i: usize, s: crate::valves::SwitchedValves) {
        if let Some(j) = self.joints.get_mut(i) {
            j.valves_switched(s);
        }
    }

    /// The rigid-body feed-forward for this tick's set-points [N m] (finite, clamped).
    fn feedforward(&mut self, frame: &ArmFrame, sp: &ArmSetpoint, dt_s: f32) -> [f32; JOINTS] {
        for i in 0..JOINTS {
            let lim = &self.joints[i].config().angle_limits;
            if let Some(a) = frame.joints[i].angle_rad {
                // NaN fails both comparisons.
                if a >= lim.min && a <= lim.max {
                    self.q_rad[i] = a;
                }
            }
            for (m, p) in [frame.joints[i].p1_gauge_pa, frame.joints[i].p2_gauge_pa]
                .into_iter()
                .enumerate()
            {
                if let Some(p) = p {
                    if p.is_finite() {
                        self.p_last_pa[i][m] = p;
                    }
                }
            }
        }
        if !self.links_ok {
            return [0.0; JOINTS];
        }
        let mut accel = [0.0f32; JOINTS];
        if self.accel_cutoff_hz > 0.0 {
            for (i, a) in accel.iter_mut().enumerate() {
                // Non-finite input: an error, the differentiator resets, no inertia term.
                *a = match self.derivatives[i].update(sp.angles_rad[i], dt_s, self.accel_cutoff_hz)
                {
                    Ok((_, acc)) => acc,
                    Err(_) => 0.0,
                };
            }
        }
        let (inertia, g) = self.links.inertia_and_gravity_nm(&self.q_rad, &accel);
        let mut ff = [0.0f32; JOINTS];
        for i in 0..JOINTS {
            let t = inertia[i] + if self.gravity { g[i] } else { 0.0 };
            let lim = self.ff_limit_nm[i];
            ff[i] = if !t.is_finite() {
                0.0
            } else if t > lim {
                lim
            } else if t < -lim {
                -lim
            } else {
                t
            };
        }
        ff
    }

    /// One arm tick: the feed-forward, then the three joint ticks with their own frames and
    /// set-points; a fault in any joint puts all six muscles in the safe state.
    pub fn step(&mut self, frame: &ArmFrame, sp: &ArmSetpoint, dt_s: f32) -> ArmTickOutput {
        let ff = self.feedforward(frame, sp, dt_s);
        let mut out = [TickOutput {
            valves: ValveCommand::default(),
            p1_set_gauge_pa: 0.0,
            p2_set_gauge_pa: 0.0,
            torque_des_nm: 0.0,
            torque_est_nm: 0.0,
            angle_est_rad: 0.0,
            velocity_est_rad_s: 0.0,
            fault: None,
            active: crate::safety::FaultSet::EMPTY,
            armed: false,
        }; JOINTS];
        for i in 0..JOINTS {
            let s = Setpoint {
                angle_rad: sp.angles_rad[i],
            };
            out[i] = self.joints[i].step_with_torque(&frame.joints[i], &s, ff[i], dt_s);
        }
        if self.fault.is_none() {
            for (i, o) in out.iter().enumerate() {
                if let Some(code) = o.fault {
                    self.fault = Some(ArmFault {
                        joint: i as u8,
                        code,
                    });
                    break;
                }
            }
        }
        if let Some(f) = self.fault {
            for (i, o) in out.iter_mut().enumerate() {
                if o.fault.is_some() {
                    continue;
                }
                let safe = self.joints[i].config().safe_state;
                o.valves = safe.command();
                let (h1, h2) = match safe {
                    SafeState::Hold => (
                        clamp_pressure_setpoint_pa(self.p_last_pa[i][0], P_MUSCLE_MAX_GAUGE_PA),
                        clamp_pressure_setpoint_pa(self.p_last_pa[i][1], P_MUSCLE_MAX_GAUGE_PA),
                    ),
                    SafeState::Vent => (0.0, 0.0),
                };
                o.p1_set_gauge_pa = h1;
                o.p2_set_gauge_pa = h2;
                o.torque_des_nm = 0.0;
                o.armed = false;
                o.fault = Some(f.code);
            }
        }
        ArmTickOutput {
            joints: out,
            feedforward_nm: ff,
            fault: self.fault,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trace::ARM3_SENSOR_TRACE;
    use crate::valves::{OnOffPwmConfig, OnOffValves};
    use crate::wiring;

    /// A valve pin for the host: infallible, records nothing.
    struct Pin;
    impl embedded_hal::digital::ErrorType for Pin {
        type Error = core::convert::Infallible;
    }
    impl embedded_hal::digital::OutputPin for Pin {
        fn set_low(&mut self) -> Result<(), Self::Error> {
            Ok(())
        }
        fn set_high(&mut self) -> Result<(), Self::Error> {
            Ok(())
        }
    }

    fn frames(row: &[crate::trace::TraceRow; JOINTS]) -> (ArmFrame, ArmSetpoint) {
        let p = wiring::pressure_scaling();
        (
            ArmFrame {
                joints: [row[0].frame(&p), row[1].frame(&p), row[2].frame(&p)],
            },
            ArmSetpoint {
                angles_rad: [0, 1, 2].map(|j| row[j].setpoint().angle_rad),
            },
        )
    }

    /// Replays the arm trace through the arm tick and three on/off drivers, with `edit`
    /// changing each tick's frame: (ticks with every joint armed, the first fault).
    fn replay(edit: impl Fn(usize, &mut ArmFrame)) -> (usize, Option<(usize, ArmFault)>) {
        let mut arm = ArmTick::new(crate::trace::arm3_trace_config());
        let mut drivers =
            [0; JOINTS].map(|_| OnOffValves::new(Pin, Pin, Pin, Pin, OnOffPwmConfig::REFERENCE));
        let (mut armed, mut first) = (0, None);
        for (k, row) in ARM3_SENSOR_TRACE.iter().enumerate() {
            let (mut frame, sp) = frames(row);
            edit(k, &mut frame);
            let out = arm.step(&frame, &sp, 1e-3);
            for (j, d) in drivers.iter_mut().enumerate() {
                let Ok(s) = d.apply_switched(&out.joints[j].valves);
                arm.valves_switched(j, s);
            }
            if out.fault.is_none() && out.joints.iter().all(|o| o.armed) {
                armed += 1;
            }
            if first.is_none() {
                first = out.fault.map(|f| (k, f));
            }
        }
        (armed, first)
    }

    #[test]
    fn the_arm_trace_replays_armed_without_a_fault() {
        let (armed, first) = replay(|_, _| {});
        assert_eq!(first, None);
        assert!(
            armed > 1400,
            "{armed} of {} ticks armed",
            ARM3_SENSOR_TRACE.len()
        );
    }

    #[test]
    fn a_nan_angle_on_one_joint_puts_all_six_muscles_in_the_safe_state_until_reset() {
        use crate::safety::FaultCode;
        let mut arm = ArmTick::new(crate::trace::arm3_trace_config());
        let mut last = None;
        for (k, row) in ARM3_SENSOR_TRACE.iter().take(400).enumerate() {
            let (mut frame, sp) = frames(row);
            if (300..310).contains(&k) {
                frame.joints[2].angle_rad = Some(f32::NAN);
            }
            let out = arm.step(&frame, &sp, 1e-3);
            if k < 300 {
                assert!(out.fault.is_none(), "tick {k}");
            } else {
                assert_eq!(
                    out.fault,
                    Some(ArmFault {
                        joint: 2,
                        code: FaultCode::AngleInvalid
                    }),
                    "tick {k}"
                );
                for (j, o) in out.joints.iter().enumerate() {
                    let safe = arm.joint(j).unwrap().config().safe_state.command();
                    assert_eq!(o.valves, safe, "tick {k}, joint {j}");
                    assert!(!o.armed && o.fault.is_some(), "tick {k}, joint {j}");
                    assert!(o.p1_set_gauge_pa.is_finite() && o.p2_set_gauge_pa.is_finite());
                }
                assert!(out.feedforward_nm.iter().all(|t| t.is_finite()));
            }
            if k == 305 {
                assert!(!arm.reset(), "reset refused while the NaN persists");
            }
            last = Some(out);
        }
        // The readings are valid again: a reset re-arms every joint.
        assert!(last.unwrap().fault.is_some(), "no re-arm without a reset");
        assert!(arm.reset());
        let (frame, sp) = frames(&ARM3_SENSOR_TRACE[400]);
        let out = arm.step(&frame, &sp, 1e-3);
        assert!(out.fault.is_none() && out.joints.iter().all(|o| o.armed));
    }

    #[test]
    fn non_finite_inputs_never_reach_the_valves_as_nan() {
        let mut arm = ArmTick::new(crate::trace::arm3_trace_config());
        let bad = [f32::NAN, f32::INFINITY, -f32::INFINITY, 1e30, -1e30];
        for k in 0..200 {
            let (mut frame, mut sp) = frames(&ARM3_SENSOR_TRACE[k]);
            let v = bad[k % bad.len()];
            match k % 4 {
                0 => sp.angles_rad[k % 3] = v,
                1 => frame.joints[k % 3].p1_gauge_pa = Some(v),
                2 => frame.joints[k % 3].p2_gauge_pa = None,
                _ => frame.joints[k % 3].angle_rad = Some(v),
            }
            let out = arm.step(&frame, &sp, if k % 7 == 0 { f32::NAN } else { 1e-3 });
            assert!(out.feedforward_nm.iter().all(|t| t.is_finite()));
            for o in &out.joints {
                assert!(o.p1_set_gauge_pa.is_finite() && o.p2_set_gauge_pa.is_finite());
                assert!(o.p1_set_gauge_pa <= crate::P_MUSCLE_MAX_GAUGE_PA);
                assert!(o.p2_set_gauge_pa <= crate::P_MUSCLE_MAX_GAUGE_PA);
            }
            arm.reset();
        }
    }
}
