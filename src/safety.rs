//! Safety state machine: latched fault codes, the defined safe valve state, and the
//! pressure set-point limit.
//!
//! ```text
//!            fault (any)                      reset() && condition gone
//!   Armed ----------------> Faulted(code) ---------------------------> Armed
//!     ^                         |  reset() while the condition persists: stays Faulted
//!     +-------------------------+
//! ```
//!
//! - A fault forces the safe valve command ([`SafeState::Hold`]: all valves closed, or
//!   [`SafeState::Vent`]: exhaust valves fully open) in the same tick it is raised.
//! - The first fault is latched as the cause; later faults do not overwrite it (the root
//!   cause stays visible) but are added to the set of faults seen ([`FaultSet`]), so every
//!   condition is reported. Nothing re-arms without an explicit [`SafetyMonitor::reset`].
//! - Escalation while faulted: a muscle whose measured pressure rises above the
//!   over-pressure limit is vented (exhaust open, inlet closed) whatever the configured
//!   safe state, until the next reset ([`SafetyMonitor::escalate_vent`]).
//! - Pressure set-points pass through [`clamp_pressure_setpoint_pa`]: never above
//!   [`crate::P_MUSCLE_MAX_GAUGE_PA`] (600 kPa gauge), never below 0, never NaN.

use crate::valves::ValveCommand;
use crate::P_MUSCLE_MAX_GAUGE_PA;

/// Latched fault codes. The numbers are stable (they appear in logs and recordings).
#[repr(u8)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FaultCode {
    /// Muscle 1 pressure is NaN or infinite.
    PressureInvalid1 = 1,
    /// Muscle 2 pressure is NaN or infinite.
    PressureInvalid2 = 2,
    /// Joint angle is NaN or infinite.
    AngleInvalid = 3,
    /// Muscle 1 pressure outside the sensor range.
    PressureOutOfRange1 = 4,
    /// Muscle 2 pressure outside the sensor range.
    PressureOutOfRange2 = 5,
    /// Joint angle outside the allowed range (joint limits).
    AngleOutOfRange = 6,
    /// No new muscle 1 pressure sample for too long.
    PressureStale1 = 7,
    /// No new muscle 2 pressure sample for too long.
    PressureStale2 = 8,
    /// No new angle sample for too long.
    AngleStale = 9,
    /// Muscle 1 pressure jumped faster than physically possible.
    PressureImplausible1 = 10,
    /// Muscle 2 pressure jumped faster than physically possible.
    PressureImplausible2 = 11,
    /// Joint angle jumped faster than physically possible.
    AngleImplausible = 12,
    /// Muscle 1 measured above the over-pressure limit.
    OverPressure1 = 13,
    /// Muscle 2 measured above the over-pressure limit.
    OverPressure2 = 14,
    /// The angle set-point is NaN or infinite.
    SetpointInvalid = 15,
    /// The tick period `dt` is NaN, shorter than `dt_min_s` (a double-triggered tick or a
    /// broken timer), or longer than `dt_max_s` (a missed deadline / watchdog).
    Watchdog = 16,
    /// A control law produced or received a non-finite value.
    ControllerNumeric = 17,
    /// The configuration failed validation.
    ConfigInvalid = 18,
    /// Muscle 1 pressure stayed far from its set-point with the valve command saturated
    /// towards it for too long (stuck or disconnected valve, lost supply, burst line).
    PressureTrackingLost1 = 19,
    /// As [`FaultCode::PressureTrackingLost1`], muscle 2.
    PressureTrackingLost2 = 20,
    /// Muscle 1 pressure rises faster than the valve model allows with its inlet closed
    /// (inlet valve stuck open or leaking), see [`crate::residual`].
    InletStuckOpen1 = 21,
    /// As [`FaultCode::InletStuckOpen1`], muscle 2.
    InletStuckOpen2 = 22,
    /// Muscle 1 pressure does not rise with its inlet open and the supply present (inlet
    /// valve stuck closed or line blocked).
    InletStuckClosed1 = 23,
    /// As [`FaultCode::InletStuckClosed1`], muscle 2.
    InletStuckClosed2 = 24,
    /// Muscle 1 pressure falls faster than the valve model allows with its exhaust closed
    /// (exhaust valve stuck open, leak, burst line).
    ExhaustStuckOpen1 = 25,
    /// As [`FaultCode::ExhaustStuckOpen1`], muscle 2.
    ExhaustStuckOpen2 = 26,
    /// Muscle 1 pressure does not fall with its exhaust open (exhaust stuck closed).
    ExhaustStuckClosed1 = 27,
    /// As [`FaultCode::ExhaustStuckClosed1`], muscle 2.
    ExhaustStuckClosed2 = 28,
    /// A muscle loses pressure while its inlet is open: the supply is gone.
    SupplyLost = 29,
    /// The MCU restarted by anything but a power-on with a clean latch record (watchdog,
    /// brown-out, software or pin reset, corrupt record): it boots into the safe state
    /// ([`crate::latch`]).
    ResetLatched = 30,
}

/// A set of fault codes, one bit per code (bit `code - 1`); `bits()` is the value logged.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FaultSet(u32);

impl FaultSet {
    /// No fault.
    pub const EMPTY: FaultSet = FaultSet(0);

    /// The set with exactly `code`.
    #[inline]
    pub const fn of(code: FaultCode) -> Self {
        FaultSet(1u32 << (code as u8 - 1))
    }

    /// The set of these bits (unknown bits are dropped).
    #[inline]
    pub const fn from_bits(bits: u32) -> Self {
        FaultSet(bits & ((1u32 << FaultCode::COUNT) - 1))
    }

    /// The bits (bit `code - 1` set when `code` is in the set).
    #[inline]
    pub const fn bits(self) -> u32 {
        self.0
    }

    /// True when the set is empty.
    #[inline]
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// True when `code` is in the set.
    #[inline]
    pub const fn contains(self, code: FaultCode) -> bool {
        self.0 & Self::of(code).0 != 0
    }

    /// Adds `code`.
    #[inline]
    pub fn insert(&mut self, code: FaultCode) {
        self.0 |= Self::of(code).0;
    }

    /// Both sets.
    #[inline]
    pub const fn union(self, other: FaultSet) -> FaultSet {
        FaultSet(self.0 | other.0)
    }

    /// The codes in the set, lowest code first.
    pub fn iter(self) -> impl Iterator<Item = FaultCode> {
        (1..=FaultCode::COUNT as u8)
            .filter(move |c| self.0 & (1u32 << (c - 1)) != 0)
            .filter_map(FaultCode::from_code)
    }
}

impl FaultCode {
    /// Number of fault codes (codes are `1..=COUNT`).
    pub const COUNT: u32 = 30;

    /// The stable numeric code.
    #[inline]
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// The fault with this code, if any.
    pub const fn from_code(code: u8) -> Option<FaultCode> {
        use FaultCode::*;
        Some(match code {
            1 => PressureInvalid1,
            2 => PressureInvalid2,
            3 => AngleInvalid,
            4 => PressureOutOfRange1,
            5 => PressureOutOfRange2,
            6 => AngleOutOfRange,
            7 => PressureStale1,
            8 => PressureStale2,
            9 => AngleStale,
            10 => PressureImplausible1,
            11 => PressureImplausible2,
            12 => AngleImplausible,
            13 => OverPressure1,
            14 => OverPressure2,
            15 => SetpointInvalid,
            16 => Watchdog,
            17 => ControllerNumeric,
            18 => ConfigInvalid,
            19 => PressureTrackingLost1,
            20 => PressureTrackingLost2,
            21 => InletStuckOpen1,
            22 => InletStuckOpen2,
            23 => InletStuckClosed1,
            24 => InletStuckClosed2,
            25 => ExhaustStuckOpen1,
            26 => ExhaustStuckOpen2,
            27 => ExhaustStuckClosed1,
            28 => ExhaustStuckClosed2,
            29 => SupplyLost,
            30 => ResetLatched,
            _ => return None,
        })
    }
}

/// Pressure-tracking supervision of one muscle: a fault when the pressure error stays above
/// `error_pa` while the valve command is saturated *towards* the set-point (the valve is
/// doing all it can and the pressure does not follow) for more than `ticks` consecutive
/// ticks. A healthy on/off valve closes a 100 kPa gap in a few tens of ms; a stuck-open
/// valve, a lost supply or a burst line keeps the gap. Any tick that breaks the condition
/// (error small, command not saturated, or saturated away from the error) restarts the count.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TrackingMonitor {
    count: u32,
}

impl TrackingMonitor {
    /// Command magnitude counted as saturated.
    pub const SATURATED: f32 = 0.999;

    /// One tick; true when tracking is lost. NaN inputs never count (other checks catch them).
    #[inline]
    pub fn update(
        &mut self,
        p_set_gauge_pa: f32,
        p_meas_gauge_pa: f32,
        command: f32,
        error_pa: f32,
        ticks: u32,
    ) -> bool {
        // Almost always the command is not saturated: one test of |command| decides then
        // (a NaN command fails it as it fails both comparisons of the full test).
        let pushing = libm::fabsf(command) >= Self::SATURATED && {
            let e = p_set_gauge_pa - p_meas_gauge_pa;
            (e > error_pa && command >= Self::SATURATED)
                || (e < -error_pa && command <= -Self::SATURATED)
        };
        self.count = if pushing {
            self.count.saturating_add(1)
        } else {
            0
        };
        self.count > ticks
    }

    /// Restarts the count.
    #[inline]
    pub fn reset(&mut self) {
        self.count = 0;
    }
}

/// The valve state applied on a fault.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SafeState {
    /// All valves closed: the muscles keep their air and the joint stays stiff near where
    /// it is (default: no sudden motion on the reference joint).
    #[default]
    Hold,
    /// Exhaust valves fully open, inflate valves closed: both muscles vent to atmosphere.
    Vent,
}

impl SafeState {
    /// The valve command of this safe state.
    #[inline]
    pub const fn command(self) -> ValveCommand {
        match self {
            SafeState::Hold => ValveCommand {
                muscle1: 0.0,
                muscle2: 0.0,
            },
            SafeState::Vent => ValveCommand {
                muscle1: -1.0,
                muscle2: -1.0,
            },
        }
    }
}

/// Clamps a pressure set-point [Pa gauge] to `[0, min(limit_pa, P_MUSCLE_MAX_GAUGE_PA)]`.
/// NaN gives 0 (the caller raises a fault for non-finite set-points before this).
#[inline]
pub fn clamp_pressure_setpoint_pa(p_gauge_pa: f32, limit_pa: f32) -> f32 {
    // A NaN or negative limit allows nothing but 0 (conservative).
    let hi = if !(limit_pa >= 0.0) {
        0.0
    } else if limit_pa < P_MUSCLE_MAX_GAUGE_PA {
        limit_pa
    } else {
        P_MUSCLE_MAX_GAUGE_PA
    };
    clamp_setpoint_to(p_gauge_pa, hi)
}

/// Clamps a pressure set-point [Pa gauge] to `[0, hi]` (`hi` already checked: non-negative,
/// at most [`P_MUSCLE_MAX_GAUGE_PA`]); NaN and p <= 0 give +0.
#[inline(always)]
pub(crate) fn clamp_setpoint_to(p_gauge_pa: f32, hi: f32) -> f32 {
    if !(p_gauge_pa > 0.0) {
        0.0
    } else if p_gauge_pa > hi {
        hi
    } else {
        p_gauge_pa
    }
}

/// The safety state machine: latches the first fault until an explicit reset.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SafetyMonitor {
    safe_state: SafeState,
    fault: Option<FaultCode>,
    seen: FaultSet,
    vent: [bool; 2],
}

impl SafetyMonitor {
    /// An armed monitor with the given safe state.
    pub const fn new(safe_state: SafeState) -> Self {
        SafetyMonitor {
            safe_state,
            fault: None,
            seen: FaultSet::EMPTY,
            vent: [false; 2],
        }
    }

    /// Every fault raised since the last reset (the cause included).
    pub fn seen(&self) -> FaultSet {
        self.seen
    }

    /// Which muscles the escalation vents (`[muscle 1, muscle 2]`).
    pub fn vented(&self) -> [bool; 2] {
        self.vent
    }

    /// Escalation: vents `muscle` (0 = muscle 1, 1 = muscle 2; others ignored) in the safe
    /// state until the next reset, whatever the configured safe state. Called when a
    /// muscle's measured pressure exceeds the over-pressure limit.
    pub fn escalate_vent(&mut self, muscle: usize) {
        if let Some(v) = self.vent.get_mut(muscle) {
            if !*v {
                error!("over-pressure: venting muscle {}", muscle + 1);
            }
            *v = true;
        }
    }

    /// The safe valve command: the configured safe state, with every escalated muscle
    /// vented.
    #[inline]
    pub fn safe_command(&self) -> ValveCommand {
        let mut c = self.safe_state.command();
        if self.vent[0] {
            c.muscle1 = -1.0;
        }
        if self.vent[1] {
            c.muscle2 = -1.0;
        }
        c
    }

    /// The configured safe state.
    pub fn safe_state(&self) -> SafeState {
        self.safe_state
    }

    /// The latched fault.
    pub fn fault(&self) -> Option<FaultCode> {
        self.fault
    }

    /// True when no fault is latched.
    pub fn is_armed(&self) -> bool {
        self.fault.is_none()
    }

    /// Raises a fault. The first one is latched as the cause; every one is added to
    /// [`SafetyMonitor::seen`].
    pub fn raise(&mut self, code: FaultCode) {
        if !self.seen.contains(code) {
            self.seen.insert(code);
            if self.fault.is_none() {
                error!("fault latched: {}", code);
                self.fault = Some(code);
            } else {
                warn!("further fault: {}", code);
            }
        }
    }

    /// Raises every fault of `set`, lowest code first (the caller raises its preferred
    /// cause first).
    pub fn raise_all(&mut self, set: FaultSet) {
        for c in set.iter() {
            self.raise(c);
        }
    }

    /// The command the valves get this tick: `requested` while armed, the safe state
    /// otherwise. A non-finite requested command is itself answered with the safe state.
    pub fn gate(&self, requested: ValveCommand) -> ValveCommand {
        if self.fault.is_some() {
            self.safe_command()
        } else if !requested.muscle1.is_finite() || !requested.muscle2.is_finite() {
            self.safe_state.command()
        } else {
            ValveCommand {
                muscle1: requested.muscle1.clamp(-1.0, 1.0),
                muscle2: requested.muscle2.clamp(-1.0, 1.0),
            }
        }
    }

    /// Restores a latched state (cause, faults seen, vented muscles), e.g. from the
    /// persistent latch at boot. An empty cause changes nothing.
    pub fn restore(&mut self, cause: Option<FaultCode>, seen: FaultSet, vented: [bool; 2]) {
        if let Some(c) = cause {
            self.raise(c);
            self.raise_all(seen);
            self.vent[0] |= vented[0];
            self.vent[1] |= vented[1];
        }
    }

    /// Explicit re-arm. `condition_cleared` says whether every cause is gone (judged by the
    /// caller on the latest measurements). Returns true when armed afterwards; then the set
    /// of faults seen and the escalation are cleared too.
    pub fn reset(&mut self, condition_cleared: bool) -> bool {
        if self.fault.is_some() && condition_cleared {
            info!("fault reset");
            self.fault = None;
            self.seen = FaultSet::EMPTY;
            self.vent = [false; 2];
        }
        self.fault.is_none()
    }
}

#[cfg(test)]
mod tests {

    #[test]
    fn tracking_monitor_trips_only_after_persistent_saturated_gap() {
        let mut m = TrackingMonitor::default();
        // Gap of 150 kPa, command saturated towards it: trips on tick 11 with ticks = 10.
        for k in 1..=10 {
            assert!(!m.update(400e3, 250e3, 1.0, 100e3, 10), "tick {k}");
        }
        assert!(m.update(400e3, 250e3, 1.0, 100e3, 10));
        // One tick with the gap closed restarts the count.
        m.update(400e3, 350e3, 1.0, 100e3, 10);
        for _ in 0..10 {
            assert!(!m.update(400e3, 250e3, 1.0, 100e3, 10));
        }
        // Saturated away from the error (or not saturated) never counts.
        let mut m = TrackingMonitor::default();
        for _ in 0..100 {
            assert!(!m.update(400e3, 250e3, -1.0, 100e3, 10));
            assert!(!m.update(400e3, 250e3, 0.9, 100e3, 10));
            assert!(!m.update(f32::NAN, 250e3, 1.0, 100e3, 10));
        }
        // Exhausting against a pressure stuck high counts as well.
        let mut m = TrackingMonitor::default();
        for _ in 0..=10 {
            m.update(100e3, 500e3, -1.0, 100e3, 10);
        }
        assert!(m.update(100e3, 500e3, -1.0, 100e3, 10));
    }

    use super::*;

    #[test]
    fn fault_codes_round_trip_and_are_stable() {
        for c in 1..=FaultCode::COUNT as u8 {
            assert_eq!(FaultCode::from_code(c).unwrap().code(), c);
        }
        assert_eq!(FaultCode::from_code(0), None);
        assert_eq!(FaultCode::from_code(FaultCode::COUNT as u8 + 1), None);
        assert_eq!(FaultCode::SupplyLost as u8, 29);
        assert_eq!(FaultCode::OverPressure1 as u8, 13);
        assert_eq!(FaultCode::PressureTrackingLost2 as u8, 20);
    }

    #[test]
    fn first_fault_is_latched() {
        let mut s = SafetyMonitor::new(SafeState::Hold);
        assert!(s.is_armed());
        s.raise(FaultCode::AngleStale);
        s.raise(FaultCode::OverPressure2);
        assert_eq!(s.fault(), Some(FaultCode::AngleStale));
        assert!(!s.is_armed());
        // Every fault is reported in the set.
        let seen: std::vec::Vec<_> = s.seen().iter().collect();
        assert_eq!(seen, [FaultCode::AngleStale, FaultCode::OverPressure2]);
        assert_eq!(
            s.seen().bits(),
            (1 << (FaultCode::AngleStale as u32 - 1))
                | (1 << (FaultCode::OverPressure2 as u32 - 1))
        );
        assert!(s.reset(true));
        assert!(s.seen().is_empty());
    }

    #[test]
    fn escalation_vents_a_muscle_whatever_the_safe_state() {
        let mut s = SafetyMonitor::new(SafeState::Hold);
        s.raise(FaultCode::PressureTrackingLost1);
        s.escalate_vent(1);
        s.escalate_vent(7); // ignored
        let c = s.gate(ValveCommand {
            muscle1: 1.0,
            muscle2: 1.0,
        });
        assert_eq!((c.muscle1, c.muscle2), (0.0, -1.0));
        assert_eq!(s.vented(), [false, true]);
        assert!(s.reset(true));
        assert_eq!(s.vented(), [false, false]);
    }

    #[test]
    fn fault_set_bits_round_trip() {
        let mut f = FaultSet::EMPTY;
        f.insert(FaultCode::SupplyLost);
        f.insert(FaultCode::PressureInvalid1);
        assert_eq!(f.bits(), 1 | (1 << 28));
        assert_eq!(
            FaultSet::from_bits(u32::MAX).iter().count(),
            FaultCode::COUNT as usize
        );
        assert!(f.contains(FaultCode::SupplyLost) && !f.contains(FaultCode::Watchdog));
    }

    #[test]
    fn fault_forces_hold_state_in_same_call() {
        let mut s = SafetyMonitor::new(SafeState::Hold);
        let req = ValveCommand {
            muscle1: 0.7,
            muscle2: -0.3,
        };
        assert_eq!(s.gate(req), req);
        s.raise(FaultCode::PressureInvalid1);
        assert_eq!(s.gate(req), ValveCommand::default());
    }

    #[test]
    fn fault_forces_vent_state_when_configured() {
        let mut s = SafetyMonitor::new(SafeState::Vent);
        s.raise(FaultCode::Watchdog);
        let c = s.gate(ValveCommand {
            muscle1: 1.0,
            muscle2: 1.0,
        });
        assert_eq!(c.muscle1, -1.0);
        assert_eq!(c.muscle2, -1.0);
    }

    #[test]
    fn non_finite_request_gets_safe_state_and_finite_is_clamped() {
        let s = SafetyMonitor::new(SafeState::Hold);
        let c = s.gate(ValveCommand {
            muscle1: f32::NAN,
            muscle2: 0.5,
        });
        assert_eq!(c, ValveCommand::default());
        let c = s.gate(ValveCommand {
            muscle1: 3.0,
            muscle2: -7.0,
        });
        assert_eq!((c.muscle1, c.muscle2), (1.0, -1.0));
    }

    #[test]
    fn no_rearm_without_reset_and_not_while_condition_persists() {
        let mut s = SafetyMonitor::new(SafeState::Hold);
        s.raise(FaultCode::AngleOutOfRange);
        assert!(!s.reset(false));
        assert_eq!(s.fault(), Some(FaultCode::AngleOutOfRange));
        assert!(s.reset(true));
        assert!(s.is_armed());
    }

    #[test]
    fn pressure_setpoint_never_exceeds_600_kpa() {
        assert_eq!(clamp_pressure_setpoint_pa(700_000.0, 1e9), 600_000.0);
        assert_eq!(clamp_pressure_setpoint_pa(700_000.0, 550_000.0), 550_000.0);
        assert_eq!(clamp_pressure_setpoint_pa(f32::NAN, 550_000.0), 0.0);
        assert_eq!(clamp_pressure_setpoint_pa(f32::INFINITY, f32::NAN), 0.0);
        assert_eq!(
            clamp_pressure_setpoint_pa(f32::INFINITY, f32::INFINITY),
            600_000.0
        );
        assert_eq!(clamp_pressure_setpoint_pa(-5.0, 550_000.0), 0.0);
        assert_eq!(clamp_pressure_setpoint_pa(300_000.0, 550_000.0), 300_000.0);
    }
}
