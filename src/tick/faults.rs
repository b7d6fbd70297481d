//! The control tick's faults: every fault condition of a tick in the documented order, a
//! valve / supply fault of the residual, and the output of a faulted tick (the safe state).

use crate::safety::{clamp_pressure_setpoint_pa, FaultCode, FaultSet, SafeState};
use crate::sensors::{ChannelFault, ChannelStatus};
use crate::tick::io::TickOutput;
use crate::tick::state::ControlTick;
use crate::P_MUSCLE_MAX_GAUGE_PA;

/// The fault codes of the channels pressure 1, pressure 2 and angle, each in
/// [`ChannelFault`] order (not finite, out of range, stale, implausible).
const CHANNEL_CODES: [[FaultCode; 4]; 3] = {
    use FaultCode::*;
    [
        [
            PressureInvalid1,
            PressureOutOfRange1,
            PressureStale1,
            PressureImplausible1,
        ],
        [
            PressureInvalid2,
            PressureOutOfRange2,
            PressureStale2,
            PressureImplausible2,
        ],
        [AngleInvalid, AngleOutOfRange, AngleStale, AngleImplausible],
    ]
};

/// The fault code of a channel's status (`None` unless it is a fault).
fn channel_fault(s: ChannelStatus, codes: &[FaultCode; 4]) -> Option<FaultCode> {
    match s {
        ChannelStatus::Fault(ChannelFault::NotFinite) => Some(codes[0]),
        ChannelStatus::Fault(ChannelFault::OutOfRange) => Some(codes[1]),
        ChannelStatus::Fault(ChannelFault::Stale) => Some(codes[2]),
        ChannelStatus::Fault(ChannelFault::Implausible) => Some(codes[3]),
        _ => None,
    }
}

/// Every fault condition of a tick, and the first one in the documented order
/// (configuration, `dt`, pressure 1, pressure 2, angle, over-pressure 1, 2, set-point).
/// Off the hot path.
#[cold]
#[inline(never)]
#[allow(clippy::too_many_arguments)]
pub(super) fn conditions(
    config_ok: bool,
    dt_ok: bool,
    s1: ChannelStatus,
    s2: ChannelStatus,
    sa: ChannelStatus,
    over1: bool,
    over2: bool,
    sp_ok: bool,
) -> (FaultSet, Option<FaultCode>) {
    use FaultCode::*;
    // Each condition, in the documented order.
    let ordered = [
        (!config_ok).then_some(ConfigInvalid),
        (!dt_ok).then_some(Watchdog),
        channel_fault(s1, &CHANNEL_CODES[0]),
        channel_fault(s2, &CHANNEL_CODES[1]),
        channel_fault(sa, &CHANNEL_CODES[2]),
        over1.then_some(OverPressure1),
        over2.then_some(OverPressure2),
        (!sp_ok).then_some(SetpointInvalid),
    ];
    let mut set = FaultSet::EMPTY;
    for c in ordered.into_iter().flatten() {
        set.insert(c);
    }
    (set, ordered.into_iter().flatten().next())
}

impl ControlTick {
    /// A residual (valve / supply) fault: raised, and a tracking-lost cause of the same
    /// muscle stays active while it persists.
    #[cold]
    #[inline(never)]
    pub(super) fn residual_fault(&mut self, set: FaultSet) {
        use FaultCode::*;
        let m1 = [
            InletStuckOpen1,
            InletStuckClosed1,
            ExhaustStuckOpen1,
            ExhaustStuckClosed1,
            SupplyLost,
        ];
        let m2 = [
            InletStuckOpen2,
            InletStuckClosed2,
            ExhaustStuckOpen2,
            ExhaustStuckClosed2,
            SupplyLost,
        ];
        let seen = self.safety.seen();
        if m1.iter().any(|&c| set.contains(c)) && seen.contains(PressureTrackingLost1) {
            self.active.insert(PressureTrackingLost1);
        }
        if m2.iter().any(|&c| set.contains(c)) && seen.contains(PressureTrackingLost2) {
            self.active.insert(PressureTrackingLost2);
        }
        self.safety.raise_all(set);
    }

    /// The output of a faulted tick: the safe valve state, the held (or vented) pressure
    /// set-points, the latched fault and the active conditions; the control laws restart.
    pub(super) fn safe_output(&mut self, mut out: TickOutput) -> TickOutput {
        self.reset_laws();
        out.valves = self.safety.safe_command();
        let (h1, h2) = match self.safety.safe_state() {
            SafeState::Hold => (
                clamp_pressure_setpoint_pa(self.p1.last().unwrap_or(0.0), P_MUSCLE_MAX_GAUGE_PA),
                clamp_pressure_setpoint_pa(self.p2.last().unwrap_or(0.0), P_MUSCLE_MAX_GAUGE_PA),
            ),
            SafeState::Vent => (0.0, 0.0),
        };
        let vented = self.safety.vented();
        out.p1_set_gauge_pa = if vented[0] { 0.0 } else { h1 };
        out.p2_set_gauge_pa = if vented[1] { 0.0 } else { h2 };
        out.torque_des_nm = 0.0;
        out.fault = self.safety.fault();
        out.active = self.active;
        out.armed = false;
        out
    }
}
