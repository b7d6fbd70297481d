//! What goes into one control tick (the sensor frame, the set-point) and what comes out
//! ([`TickOutput`]).

use crate::safety::{FaultCode, FaultSet};
use crate::valves::ValveCommand;

/// What the sensors delivered this tick. `None` = no new sample this tick (not ready /
/// missing). Values may be NaN or out of range: the tick validates them.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SensorFrame {
    /// Muscle 1 gauge pressure [Pa].
    pub p1_gauge_pa: Option<f32>,
    /// Muscle 2 gauge pressure [Pa].
    pub p2_gauge_pa: Option<f32>,
    /// Joint angle [rad].
    pub angle_rad: Option<f32>,
}

/// The joint angle set-point.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Setpoint {
    /// Desired joint angle [rad].
    pub angle_rad: f32,
}

/// Everything one tick produced. All floats are finite.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TickOutput {
    /// What the valve driver applies this tick.
    pub valves: ValveCommand,
    /// Muscle 1 pressure set-point [Pa gauge] (<= 600 kPa). While faulted: the held
    /// (last accepted measured) pressure for [`SafeState::Hold`](crate::safety::SafeState::Hold), 0 for [`SafeState::Vent`](crate::safety::SafeState::Vent).
    pub p1_set_gauge_pa: f32,
    /// Muscle 2 pressure set-point [Pa gauge] (<= 600 kPa).
    pub p2_set_gauge_pa: f32,
    /// Outer loop output [N m] (0 when not controlling).
    pub torque_des_nm: f32,
    /// `(F1 - F2) r` from the force law, measured p and angle [N m] (0 when unknown).
    pub torque_est_nm: f32,
    /// Last accepted angle [rad] (0 before the first sample).
    pub angle_est_rad: f32,
    /// Velocity estimate [rad/s].
    pub velocity_est_rad_s: f32,
    /// Latched fault: the first cause (Some => valves are in the safe state).
    pub fault: Option<FaultCode>,
    /// Every fault condition that holds in this tick (bit `code - 1`; empty while all is
    /// well). While faulted it keeps being evaluated; [`ControlTick::reset`](crate::tick::ControlTick::reset) is refused
    /// while it is not empty.
    pub active: FaultSet,
    /// True when the cascade computed this tick's command.
    pub armed: bool,
}
