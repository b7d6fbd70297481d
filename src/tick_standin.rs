//! Stand-in for the control tick of `/tmp/tick_contract.md` (`src/tick.rs`, branch `ctrl`).
//!
//! Same names and signatures as the contract, so the QEMU trace, the board binary and
//! `tests/qemu_trace.rs` switch to the real [`ControlTick`] with one line
//! (`use crate::tick_standin as tick;` -> `use crate::tick;` in `src/trace.rs`). Until then this
//! drives the parts of the firmware that exist: sensor validation and ageing, the torque model
//! inverse (seed 003, eq. 11) for the outer loop, the force law (seed 002, eq. 6) for the torque
//! estimate, and a proportional pressure loop with a dead band to the valves.
//!
//! It is a real, small controller (never panics, every input may be NaN or missing), not the
//! tuned cascade of the `ctrl` branch: its gains are the reference joint's linearisation.

use crate::constants::{FORCE_LAW, TORQUE_MODEL};
use crate::force_law::{ForceFlags, ForceLawParams};
use crate::geometry::JointGeometry;
use crate::torque_model::TorqueModelParams;
use crate::P_MUSCLE_MAX_GAUGE_PA;

/// What the sensors delivered this tick (`None` = no new sample).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct SensorFrame {
    /// Muscle 1 gauge pressure [Pa].
    pub p1_gauge_pa: Option<f32>,
    /// Muscle 2 gauge pressure [Pa].
    pub p2_gauge_pa: Option<f32>,
    /// Joint angle [rad].
    pub angle_rad: Option<f32>,
}

/// Position set-point.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Setpoint {
    /// Desired joint angle [rad].
    pub angle_rad: f32,
}

/// Per-muscle valve command in [-1, 1] (> 0 inflate duty, < 0 exhaust duty, 0 closed).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct ValveCommand {
    /// Muscle 1 command.
    pub muscle1: f32,
    /// Muscle 2 command.
    pub muscle2: f32,
}

/// Latched fault codes (stable numbers).
#[repr(u8)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FaultCode {
    /// Muscle 1 pressure reading NaN or out of range.
    PressureSensorInvalid1 = 1,
    /// Muscle 2 pressure reading NaN or out of range.
    PressureSensorInvalid2 = 2,
    /// Angle reading NaN.
    AngleSensorInvalid = 3,
    /// Muscle 1 pressure missing for longer than the stale limit.
    PressureStale1 = 4,
    /// Muscle 2 pressure missing for longer than the stale limit.
    PressureStale2 = 5,
    /// Angle missing for longer than the stale limit.
    AngleStale = 6,
    /// Angle outside the mechanical range.
    AngleOutOfRange = 7,
    /// A muscle pressure above the limit.
    OverPressure = 8,
    /// The force law could not evaluate (singular / invalid).
    ForceLawInvalid = 9,
}

/// What the tick decided.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TickOutput {
    /// What the valve driver applies this tick.
    pub valves: ValveCommand,
    /// Pressure set-point of muscle 1, gauge [Pa].
    pub p1_set_gauge_pa: f32,
    /// Pressure set-point of muscle 2, gauge [Pa].
    pub p2_set_gauge_pa: f32,
    /// Outer loop output [N m].
    pub torque_des_nm: f32,
    /// (F1 - F2) r from the force law [N m].
    pub torque_est_nm: f32,
    /// Angle estimate [rad].
    pub angle_est_rad: f32,
    /// Velocity estimate [rad/s].
    pub velocity_est_rad_s: f32,
    /// Latched fault (`Some` => valves in the safe state).
    pub fault: Option<FaultCode>,
    /// Controller armed.
    pub armed: bool,
}

/// What the valves do in the safe state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SafeState {
    /// Both muscles' valves closed (command 0).
    Hold,
    /// Both muscles exhausting (command -1).
    Vent,
}

/// Controller parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControllerConfig {
    /// Tick rate [Hz].
    pub tick_hz: f32,
    /// Joint geometry.
    pub geometry: JointGeometry,
    /// Force law constants.
    pub force_law: ForceLawParams,
    /// Torque model constants.
    pub torque_model: TorqueModelParams,
    /// Outer loop proportional gain [N m / rad].
    pub kp_nm_per_rad: f32,
    /// Outer loop damping gain [N m s / rad].
    pub kd_nms_per_rad: f32,
    /// Velocity low-pass time constant [s].
    pub velocity_tau_s: f32,
    /// Pressure loop gain [1 / Pa] (command per pressure error).
    pub valve_gain_per_pa: f32,
    /// Pressure error below which the valves stay closed [Pa].
    pub valve_deadband_pa: f32,
    /// Ticks a reading may be missing before it is a fault.
    pub stale_limit_ticks: u16,
    /// Valid angle range [rad].
    pub angle_range_rad: (f32, f32),
    /// Highest plausible gauge pressure reading [Pa].
    pub p_max_gauge_pa: f32,
    /// Lowest plausible gauge pressure reading [Pa] (sensor offset tolerance).
    pub p_min_gauge_pa: f32,
    /// Safe valve state.
    pub safe_state: SafeState,
}

impl ControllerConfig {
    /// Parameters for the reference joint at the given tick rate.
    pub fn reference(tick_hz: f32) -> Self {
        ControllerConfig {
            tick_hz,
            geometry: JointGeometry::REFERENCE,
            force_law: FORCE_LAW,
            torque_model: TORQUE_MODEL,
            kp_nm_per_rad: 40.0,
            kd_nms_per_rad: 1.5,
            velocity_tau_s: 0.01,
            valve_gain_per_pa: 1.0 / 50_000.0,
            valve_deadband_pa: 2_000.0,
            stale_limit_ticks: 5,
            angle_range_rad: (-1.2, 1.2),
            p_max_gauge_pa: P_MUSCLE_MAX_GAUGE_PA + 50_000.0,
            p_min_gauge_pa: -20_000.0,
            safe_state: SafeState::Hold,
        }
    }
}

#[derive(Clone, Copy, Debug)]
struct Channel {
    value: f32,
    age_ticks: u16,
    seen: bool,
}

impl Channel {
    const EMPTY: Channel = Channel {
        value: 0.0,
        age_ticks: 0,
        seen: false,
    };
}

/// The control tick (stand-in, see the module docs).
pub struct ControlTick {
    cfg: ControllerConfig,
    p1: Channel,
    p2: Channel,
    angle: Channel,
    prev_angle_rad: f32,
    velocity_rad_s: f32,
    fault: Option<FaultCode>,
    armed: bool,
}

fn clamp(x: f32, lo: f32, hi: f32) -> f32 {
    if x < lo {
        lo
    } else if x > hi {
        hi
    } else {
        x
    }
}

impl ControlTick {
    /// A controller that arms on the first complete valid frame.
    pub fn new(cfg: ControllerConfig) -> Self {
        ControlTick {
            cfg,
            p1: Channel::EMPTY,
            p2: Channel::EMPTY,
            angle: Channel::EMPTY,
            prev_angle_rad: 0.0,
            velocity_rad_s: 0.0,
            fault: None,
            armed: false,
        }
    }

    /// Takes one reading: `Err(fault)` for an invalid value or a stale channel.
    fn take(
        ch: &mut Channel,
        reading: Option<f32>,
        lo: f32,
        hi: f32,
        invalid: FaultCode,
        stale: FaultCode,
        limit: u16,
    ) -> Result<(), FaultCode> {
        match reading {
            Some(v) if v.is_finite() && v >= lo && v <= hi => {
                ch.value = v;
                ch.age_ticks = 0;
                ch.seen = true;
                Ok(())
            }
            Some(_) => Err(invalid),
            None => {
                ch.age_ticks = ch.age_ticks.saturating_add(1);
                if ch.seen && ch.age_ticks > limit {
                    Err(stale)
                } else {
                    Ok(())
                }
            }
        }
    }

    fn safe_output(&self) -> TickOutput {
        let u = match self.cfg.safe_state {
            SafeState::Hold => 0.0,
            SafeState::Vent => -1.0,
        };
        TickOutput {
            valves: ValveCommand {
                muscle1: u,
                muscle2: u,
            },
            p1_set_gauge_pa: 0.0,
            p2_set_gauge_pa: 0.0,
            torque_des_nm: 0.0,
            torque_est_nm: 0.0,
            angle_est_rad: self.angle.value,
            velocity_est_rad_s: self.velocity_rad_s,
            fault: self.fault,
            armed: false,
        }
    }

    /// One control tick. Pure: no hidden time, no I/O. Never panics.
    pub fn step(&mut self, frame: &SensorFrame, setpoint: &Setpoint, dt_s: f32) -> TickOutput {
        let c = self.cfg;
        let lim = c.stale_limit_ticks;
        let (plo, phi) = (c.p_min_gauge_pa, c.p_max_gauge_pa);
        let r = Self::take(
            &mut self.p1,
            frame.p1_gauge_pa,
            plo,
            phi,
            FaultCode::PressureSensorInvalid1,
            FaultCode::PressureStale1,
            lim,
        )
        .and(Self::take(
            &mut self.p2,
            frame.p2_gauge_pa,
            plo,
            phi,
            FaultCode::PressureSensorInvalid2,
            FaultCode::PressureStale2,
            lim,
        ))
        .and(Self::take(
            &mut self.angle,
            frame.angle_rad,
            f32::NEG_INFINITY,
            f32::INFINITY,
            FaultCode::AngleSensorInvalid,
            FaultCode::AngleStale,
            lim,
        ));
        if let Err(f) = r {
            self.latch(f);
        }
        if self.fault.is_none() && self.angle.seen {
            let a = self.angle.value;
            if a < c.angle_range_rad.0 || a > c.angle_range_rad.1 {
                self.latch(FaultCode::AngleOutOfRange);
            } else if self.p1.value > P_MUSCLE_MAX_GAUGE_PA || self.p2.value > P_MUSCLE_MAX_GAUGE_PA
            {
                self.latch(FaultCode::OverPressure);
            }
        }
        if self.fault.is_some() {
            return self.safe_output();
        }
        if !(self.p1.seen && self.p2.seen && self.angle.seen) {
            // Not armed yet: wait for a complete frame, valves closed.
            return TickOutput {
                fault: None,
                ..self.safe_output()
            };
        }
        let dt = if dt_s.is_finite() && dt_s > 0.0 {
            dt_s
        } else {
            1.0 / c.tick_hz
        };
        let angle = self.angle.value;
        if self.armed {
            let raw_v = (angle - self.prev_angle_rad) / dt;
            let a = dt / (c.velocity_tau_s + dt);
            self.velocity_rad_s += a * (raw_v - self.velocity_rad_s);
        } else {
            self.velocity_rad_s = 0.0;
            self.armed = true;
            info!("control tick armed");
        }
        self.prev_angle_rad = angle;
        let v = self.velocity_rad_s;

        // Outer loop: angle -> desired torque; torque model inverse -> activation.
        let sp = if setpoint.angle_rad.is_finite() {
            clamp(setpoint.angle_rad, c.angle_range_rad.0, c.angle_range_rad.1)
        } else {
            angle
        };
        let torque_des = c.kp_nm_per_rad * (sp - angle) - c.kd_nms_per_rad * v;
        let act = c.torque_model.activation(torque_des, angle, v);
        let (p1_set, p2_set) = c.torque_model.pressures_gauge_pa(act.dp_pa);

        // Torque estimate from the force law at the measured pressures.
        let (e1, e2) = c.geometry.stretches(angle);
        let f1 = c.force_law.force(self.p1.value, e1);
        let f2 = c.force_law.force(self.p2.value, e2);
        if f1.flags.union(f2.flags).contains_any(ForceFlags::FATAL) {
            self.latch(FaultCode::ForceLawInvalid);
            return self.safe_output();
        }
        let torque_est = (f1.force_n - f2.force_n) * c.geometry.sprocket_radius_m;

        // Inner loop: pressure error -> valve duty.
        let valve = |p_set: f32, p: f32| {
            let e = p_set - p;
            if libm::fabsf(e) < c.valve_deadband_pa {
                0.0
            } else {
                clamp(e * c.valve_gain_per_pa, -1.0, 1.0)
            }
        };
        TickOutput {
            valves: ValveCommand {
                muscle1: valve(p1_set, self.p1.value),
                muscle2: valve(p2_set, self.p2.value),
            },
            p1_set_gauge_pa: p1_set,
            p2_set_gauge_pa: p2_set,
            torque_des_nm: torque_des,
            torque_est_nm: torque_est,
            angle_est_rad: angle,
            velocity_est_rad_s: v,
            fault: None,
            armed: true,
        }
    }

    fn latch(&mut self, f: FaultCode) {
        if self.fault.is_none() {
            warn!("fault latched: {}", f as u8);
            self.fault = Some(f);
            self.armed = false;
        }
    }

    /// Explicit re-arm after a fault (always succeeds here: the next tick re-checks).
    pub fn reset(&mut self) -> bool {
        self.fault = None;
        self.p1 = Channel::EMPTY;
        self.p2 = Channel::EMPTY;
        self.angle = Channel::EMPTY;
        true
    }
}
