//! The control tick (API contract: `docs/tick-contract.md`): sensor validation, the control
//! cascade of [`crate::control`], and the safety state machine of [`crate::safety`], in
//! one pure `step` per tick. Consumed by the QEMU binary, the board binary and host-sim.
//!
//! Order within one tick:
//! 1. `dt` check (watchdog: NaN, <= 0 or longer than `dt_max_s`).
//! 2. Every channel is aged and validated ([`ChannelValidator`]); the velocity estimate is
//!    updated from a new accepted angle sample.
//! 3. Fault conditions (channel faults, over-pressure, invalid set-point, invalid
//!    configuration) latch a [`FaultCode`]; the safe valve state is output in this tick.
//! 4. While a channel has not delivered its first sample (start-up), the valves stay closed
//!    and the tick is not armed (no fault unless the channel goes stale).
//! 5. Otherwise: position PID -> torque loop -> pressure loops -> valve command. A control
//!    law that reports an error latches [`FaultCode::ControllerNumeric`] (ODrive style).

use crate::constants::{FORCE_LAW, TORQUE_MODEL};
use crate::control::{
    torque_estimate_nm, JointState, PidGains, PositionController, PressureController,
    PressureLoopGains, TorqueController, TorqueLoopGains, TorqueMeasurement,
};
use crate::feedforward::{feedforward_torque_nm, FeedforwardGains, SetpointDerivatives};
use crate::force_law::{ForceFlags, ForceLawParams};
use crate::geometry::JointGeometry;
use crate::pid::{DpPid, DpPidGains};
use crate::safety::{clamp_pressure_setpoint_pa, SafeState, SafetyMonitor, TrackingMonitor};
use crate::sensors::{
    ChannelFault, ChannelLimits, ChannelStatus, ChannelValidator, VelocityEstimator,
};
use crate::torque_model::TorqueModelParams;
use crate::P_MUSCLE_MAX_GAUGE_PA;

pub use crate::safety::FaultCode;

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

/// Per-muscle valve command in [-1, 1]: > 0 inflate duty (inflate valve open that fraction
/// of the time), < 0 exhaust duty, 0 both closed. Never inflate and exhaust one muscle at
/// once.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ValveCommand {
    /// Muscle 1 command.
    pub muscle1: f32,
    /// Muscle 2 command.
    pub muscle2: f32,
}

/// Everything one tick produced. All floats are finite.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TickOutput {
    /// What the valve driver applies this tick.
    pub valves: ValveCommand,
    /// Muscle 1 pressure set-point [Pa gauge] (<= 600 kPa). While faulted: the held
    /// (last accepted measured) pressure for [`SafeState::Hold`], 0 for [`SafeState::Vent`].
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
    /// Latched fault (Some => valves are in the safe state).
    pub fault: Option<FaultCode>,
    /// True when the cascade computed this tick's command.
    pub armed: bool,
}

/// Which control law turns the angle set-point into pressure set-points. Both feed the same
/// pressure loops, valve command, pressure-tracking supervision and safety path.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ControlLaw {
    /// The model-based cascade of seed 003 Fig. 5 ([`crate::control`]): position PID ->
    /// torque loop with the force-law feedback and the inverse torque model -> pressures.
    Cascade,
    /// The model-free baseline ([`crate::pid`]): one PD / PID from the angle straight to the
    /// activation `dp`, `p1 = p0 - dp`, `p2 = p0 + dp` (the gains of `position` and `torque`
    /// are not used). `torque_des_nm` is then reported as 0.
    DirectPid(DpPidGains),
}

/// Configuration of the control tick.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ControllerConfig {
    /// Nominal tick rate [Hz].
    pub tick_hz: f32,
    /// Longest accepted `dt` [s]; longer (a missed deadline) raises [`FaultCode::Watchdog`].
    pub dt_max_s: f32,
    /// Joint geometry (stretches for the force law, sprocket radius).
    pub geometry: JointGeometry,
    /// Identified force law (torque feedback).
    pub force_law: ForceLawParams,
    /// Torque model (inverse = activation).
    pub torque_model: TorqueModelParams,
    /// Position PID.
    pub position: PidGains,
    /// Torque loop.
    pub torque: TorqueLoopGains,
    /// Per-muscle pressure loop (same gains for both).
    pub pressure: PressureLoopGains,
    /// Cutoff of the velocity differentiator [Hz].
    pub velocity_cutoff_hz: f32,
    /// Valve state on a fault.
    pub safe_state: SafeState,
    /// Validation of both pressure channels [Pa gauge, Pa/s].
    pub pressure_limits: ChannelLimits,
    /// Validation of the angle channel [rad, rad/s]; its range is the allowed joint range.
    pub angle_limits: ChannelLimits,
    /// Measured pressure above this raises an over-pressure fault [Pa gauge].
    pub p_over_gauge_pa: f32,
    /// Angle set-points are clamped to `[-angle_setpoint_max_rad, angle_setpoint_max_rad]`.
    pub angle_setpoint_max_rad: f32,
    /// Pressure error [Pa] above which a saturated valve command counts as not tracking
    /// ([`crate::safety::TrackingMonitor`]).
    pub tracking_error_pa: f32,
    /// Consecutive non-tracking ticks that raise `PressureTrackingLost1/2`.
    pub tracking_ticks: u32,
    /// The control law ([`ControlLaw::Cascade`] in [`ControllerConfig::reference`]).
    pub law: ControlLaw,
    /// Trajectory feed-forward of the cascade ([`crate::feedforward`]); unused by
    /// [`ControlLaw::DirectPid`].
    pub feedforward: FeedforwardGains,
}

impl ControllerConfig {
    /// Configuration tuned for the reference joint (`shared/plant/reference-1dof.toml`:
    /// J = 0.014 kg m^2, r = 25 mm, supply 600 kPa gauge, on/off valves C = 8e-9) with the
    /// cascade running at `tick_hz` (tuned at 1 kHz).
    ///
    /// Tuning rationale:
    /// - Plant about p0 = 300 kPa: passive stiffness A r^2 = -14.5 N m/rad and damping
    ///   D = -0.3 N m s/rad are cancelled by the inverse model, so the position loop mostly
    ///   sees the inertia J. Start point: PD for omega_n ~ 25 rad/s (kp = J omega_n^2,
    ///   kd = 2 zeta J omega_n), then a grid search (kp 4..14, kd 0.3..0.9, ki 0..20,
    ///   torque ki 0..60, pressure kp 1/30..1/15 kPa) in an explicit-Euler stand-in of
    ///   the plant (since replaced by the real plant in
    ///   `host-sim/tests/closed_loop_smoke.rs`), also run with the 11x inertia of
    ///   `reference-1dof-loaded.toml` to keep that stable.
    ///   That gave kp = 11 N m/rad, kd = 0.8 N m s/rad, ki = 8 N m/(rad s), +-1.5 N m, with
    ///   the derivative on the measurement only, which lags a moving set-point by
    ///   `kd r' / kp` (0.06 rad on the 0.5 Hz sine).
    /// - Trajectory feed-forward ([`crate::feedforward`], added for the closed-loop
    ///   comparison with PD / PID, `docs/control.md`): derivative on the error (`w = 1`)
    ///   and the inertia torque `J r''` of the desired motion (J = 0.014 kg m^2 of the reference joint), limited to +-2 N m
    ///   (tracking at 2 rad/s needs kd r' = 1.8 N m; a larger limit only adds a kick on
    ///   set-point jumps). The position gains were tuned with it on the full reference plant
    ///   with the firmware in the loop, on the jump suite (step / sine / random set-points
    ///   that jump), minimising the worse of the suite MSE at the gains and at 1.25 x the
    ///   gains, at most 10 % step overshoot: kp = 29.662365 N m/rad, ki = 4.819047
    ///   N m/(rad s), kd = 0.9451818 N m s/rad (Nelder-Mead from (11, 8, 0.8) + polish, on
    ///   2026-11-23, after the identified `config/` constants and the valve driver's
    ///   immediate full-scale opening). Then the inertia term was switched on and the
    ///   set-point differentiators raised from 20 to 150 Hz (the set-point is noise-free, so
    ///   the filter only has to round tick-to-tick jumps). On the comparison suite of 0.15 s
    ///   minimum-jerk moves that tracks 2.6x better (0.0545 -> 0.0206 deg^2). On the jump
    ///   suite it costs 2 % (1.0375 -> 1.0591 deg^2). The step tests (then on the
    ///   Euler stand-in) improved (overshoot 0.0156 -> 0.0110 rad; the 11x load unchanged,
    ///   1.0 s). `host-sim/tests/closed_loop.rs` checks that every scenario,
    ///   the 11x load change included, still meets its bounds, and
    ///   `host-sim/tests/control_compare.rs` that these gains pass both step requirements.
    ///   These are the robust defaults. The gains tuned for the tracking suite of the PD / PID
    ///   comparison (host-sim `control_compare`, 6 dB gain margin) are in
    ///   `config/control_tuned.toml` `[cascade]`: kp 55.7, ki 39.9, kd 0.50, torque ki 2.26,
    ///   inertia term on, 150 Hz. They track 7x better on that suite but fail both step
    ///   requirements (the 0.3 s settling and the 11x load). They are not the default.
    /// - Torque loop: integral only (ki = 30 1/s, +-1.5 N m): trims the force-law /
    ///   linearisation mismatch; proportional torque feedback through the measured
    ///   pressures gave no benefit with on/off valves.
    /// - Pressure loop: P with kp = 1/30 kPa (full valve opening at 30 kPa error; choked
    ///   flow moves a muscle ~4 kPa per ms), deadband 3 kPa.
    /// - On/off PWM ([`crate::valves::OnOffPwmConfig::REFERENCE`]): 10 ticks period, 2 ticks
    ///   minimum on-time.
    pub fn reference(tick_hz: f32) -> Self {
        let ticks = |s: f32| -> u32 {
            // `as` saturates: NaN -> 0, huge -> u32::MAX; at least 1 tick.
            let t = libm::ceilf(s * tick_hz) as u32;
            if t < 1 {
                1
            } else {
                t
            }
        };
        ControllerConfig {
            tick_hz,
            dt_max_s: 5.0 / tick_hz,
            geometry: JointGeometry::REFERENCE,
            force_law: FORCE_LAW,
            torque_model: TORQUE_MODEL,
            position: PidGains {
                kp: 29.662365,
                ki: 4.819047,
                kd: 0.9451818,
                i_limit: 1.5,
                out_limit: 10.0,
            },
            torque: TorqueLoopGains {
                kp: 0.0,
                ki: 30.0,
                corr_limit_nm: 1.5,
                p_set_max_gauge_pa: P_MUSCLE_MAX_GAUGE_PA,
            },
            pressure: PressureLoopGains {
                kp_per_pa: 1.0 / 30_000.0,
                ki_per_pa_s: 0.0,
                deadband_pa: 3_000.0,
                i_limit: 0.0,
            },
            velocity_cutoff_hz: 40.0,
            safe_state: SafeState::Hold,
            pressure_limits: ChannelLimits {
                min: -50_000.0,
                max: 1_000_000.0,
                // Choked inflow into the smallest chamber: ~7 MPa/s; margin x3.
                max_rate_per_s: 20_000_000.0,
                jump_margin: 20_000.0,
                stale_ticks: ticks(0.010),
            },
            angle_limits: ChannelLimits {
                // Force-law stretch domain 0.75..1.05 ends at |angle| = 1.1 rad.
                min: -1.0,
                max: 1.0,
                max_rate_per_s: 50.0,
                jump_margin: 0.02,
                stale_ticks: ticks(0.010),
            },
            p_over_gauge_pa: 630_000.0,
            angle_setpoint_max_rad: 0.8,
            // Filling a muscle across 100 kPa takes ~25 ms with the reference valve; 0.3 s
            // of saturated command without getting there is a valve or supply failure.
            tracking_error_pa: 100_000.0,
            tracking_ticks: ticks(0.3),
            law: ControlLaw::Cascade,
            feedforward: FeedforwardGains {
                rate_weight: 1.0,
                inertia_kgm2: 0.014,
                cutoff_hz: 150.0,
                limit_nm: 2.0,
            },
        }
    }

    /// True when every parameter is usable (finite, positive where needed, consistent).
    pub fn is_valid(&self) -> bool {
        let pos = |x: f32| x.is_finite() && x > 0.0;
        let nonneg = |x: f32| x.is_finite() && x >= 0.0;
        let lim_ok = |l: &ChannelLimits| {
            l.min.is_finite()
                && l.max.is_finite()
                && l.min < l.max
                && nonneg(l.max_rate_per_s)
                && nonneg(l.jump_margin)
        };
        let g = &self.geometry;
        let p = &self.position;
        let t = &self.torque;
        let pr = &self.pressure;
        pos(self.tick_hz)
            && pos(self.dt_max_s)
            && pos(g.sprocket_radius_m)
            && pos(g.rest_length_m)
            && g.initial_contraction.is_finite()
            && self.force_law.c.iter().all(|c| c.is_finite())
            && self.torque_model.b_m2.is_finite()
            && self.torque_model.b_m2 != 0.0
            && self.torque_model.sprocket_radius_m.is_finite()
            && self.torque_model.sprocket_radius_m != 0.0
            && self.torque_model.a_n_per_m_rad.is_finite()
            && self.torque_model.c_nms3_per_rad3.is_finite()
            && self.torque_model.d_nms_per_rad.is_finite()
            && nonneg(self.torque_model.p0_gauge_pa)
            && self.torque_model.p0_gauge_pa <= P_MUSCLE_MAX_GAUGE_PA
            && nonneg(self.torque_model.dp_max_pa)
            && [p.kp, p.ki, p.kd, p.i_limit, p.out_limit]
                .iter()
                .all(|&x| nonneg(x))
            && [t.kp, t.ki, t.corr_limit_nm, t.p_set_max_gauge_pa]
                .iter()
                .all(|&x| nonneg(x))
            && [pr.kp_per_pa, pr.ki_per_pa_s, pr.deadband_pa, pr.i_limit]
                .iter()
                .all(|&x| nonneg(x))
            && nonneg(self.velocity_cutoff_hz)
            && lim_ok(&self.pressure_limits)
            && lim_ok(&self.angle_limits)
            && pos(self.p_over_gauge_pa)
            && nonneg(self.angle_setpoint_max_rad)
            && pos(self.tracking_error_pa)
            && self.tracking_ticks > 0
            && self.feedforward.is_valid()
            && match self.law {
                ControlLaw::Cascade => true,
                ControlLaw::DirectPid(g) => g.is_valid(),
            }
    }
}

/// The control tick: validation + cascade + safety. No allocation, no panic, no hidden time.
pub struct ControlTick {
    cfg: ControllerConfig,
    config_ok: bool,
    /// The period channels are aged by when `dt` itself is bad: `1 / tick_hz`, or 1 ms for
    /// an unusable `tick_hz` (computed once here instead of every tick).
    dt_fallback_s: f32,
    /// `dt_fallback_s.is_finite() && dt_fallback_s > 0.0`.
    dt_fallback_good: bool,
    /// `dt_max_s`, with +inf replaced by `f32::MAX`: then `dt_ok` is the two comparisons
    /// `0 < dt <= dt_limit_s` (NaN and +inf fail them), the same as the finiteness test too.
    dt_limit_s: f32,
    /// `cfg.torque_model.dp_limit_pa()` (a configuration constant of the torque loop).
    dp_limit_pa: f32,
    /// `clamp_pressure_setpoint_pa(f32::INFINITY, cfg.torque.p_set_max_gauge_pa)`: the
    /// torque loop's upper set-point bound (a configuration constant).
    p_set_hi_pa: f32,
    /// `SetpointDerivatives::tau_s(cfg.feedforward.cutoff_hz)` (a configuration constant).
    ff_tau_s: f32,
    p1: ChannelValidator,
    p2: ChannelValidator,
    angle: ChannelValidator,
    velocity: VelocityEstimator,
    position: PositionController,
    torque: TorqueController,
    /// The model-free law when the configuration selects [`ControlLaw::DirectPid`].
    dp_pid: Option<DpPid>,
    /// Set-point rate and acceleration for the cascade's feed-forward.
    setpoint_derivatives: SetpointDerivatives,
    pressure1: PressureController,
    pressure2: PressureController,
    safety: SafetyMonitor,
    /// The fault condition seen in the last tick (None = all conditions clear).
    condition: Option<FaultCode>,
    last_p1_pa: Option<f32>,
    last_p2_pa: Option<f32>,
    last_angle_rad: Option<f32>,
    tracking1: TrackingMonitor,
    tracking2: TrackingMonitor,
}

fn channel_fault(
    f: ChannelFault,
    invalid: FaultCode,
    range: FaultCode,
    stale: FaultCode,
    jump: FaultCode,
) -> FaultCode {
    match f {
        ChannelFault::NotFinite => invalid,
        ChannelFault::OutOfRange => range,
        ChannelFault::Stale => stale,
        ChannelFault::Implausible => jump,
    }
}

/// The first fault condition of a tick, in the documented order (configuration, `dt`,
/// pressure 1, pressure 2, angle, over-pressure 1, 2, set-point). Off the hot path.
#[cold]
#[inline(never)]
#[allow(clippy::too_many_arguments)]
fn first_condition(
    config_ok: bool,
    dt_ok: bool,
    s1: ChannelStatus,
    s2: ChannelStatus,
    sa: ChannelStatus,
    over1: bool,
    over2: bool,
    sp_ok: bool,
) -> Option<FaultCode> {
    use FaultCode::*;
    if !config_ok {
        return Some(ConfigInvalid);
    }
    if !dt_ok {
        return Some(Watchdog);
    }
    if let ChannelStatus::Fault(f) = s1 {
        return Some(channel_fault(
            f,
            PressureInvalid1,
            PressureOutOfRange1,
            PressureStale1,
            PressureImplausible1,
        ));
    }
    if let ChannelStatus::Fault(f) = s2 {
        return Some(channel_fault(
            f,
            PressureInvalid2,
            PressureOutOfRange2,
            PressureStale2,
            PressureImplausible2,
        ));
    }
    if let ChannelStatus::Fault(f) = sa {
        return Some(channel_fault(
            f,
            AngleInvalid,
            AngleOutOfRange,
            AngleStale,
            AngleImplausible,
        ));
    }
    if over1 {
        return Some(OverPressure1);
    }
    if over2 {
        return Some(OverPressure2);
    }
    if !sp_ok {
        return Some(SetpointInvalid);
    }
    None
}

impl ControlTick {
    /// A tick in the armed state (control starts once every channel delivered a valid
    /// sample). An invalid configuration latches [`FaultCode::ConfigInvalid`] for good.
    pub fn new(cfg: ControllerConfig) -> Self {
        let config_ok = cfg.is_valid();
        let mut safety = SafetyMonitor::new(cfg.safe_state);
        if !config_ok {
            safety.raise(FaultCode::ConfigInvalid);
        }
        let dt_fallback_s = if cfg.tick_hz.is_finite() && cfg.tick_hz > 0.0 {
            1.0 / cfg.tick_hz
        } else {
            1.0e-3
        };
        let dt_limit_s = if cfg.dt_max_s == f32::INFINITY {
            f32::MAX
        } else {
            cfg.dt_max_s
        };
        ControlTick {
            cfg,
            config_ok,
            dt_fallback_s,
            dt_fallback_good: dt_fallback_s.is_finite() && dt_fallback_s > 0.0,
            dt_limit_s,
            dp_limit_pa: cfg.torque_model.dp_limit_pa(),
            p_set_hi_pa: clamp_pressure_setpoint_pa(f32::INFINITY, cfg.torque.p_set_max_gauge_pa),
            ff_tau_s: SetpointDerivatives::tau_s(cfg.feedforward.cutoff_hz),
            p1: ChannelValidator::new(cfg.pressure_limits),
            p2: ChannelValidator::new(cfg.pressure_limits),
            angle: ChannelValidator::new(cfg.angle_limits),
            velocity: VelocityEstimator::new(cfg.velocity_cutoff_hz),
            position: PositionController::new(cfg.position),
            torque: TorqueController::new(
                cfg.torque,
                cfg.force_law,
                cfg.geometry,
                cfg.torque_model,
            ),
            dp_pid: match cfg.law {
                ControlLaw::Cascade => None,
                ControlLaw::DirectPid(g) => Some(DpPid::new(g)),
            },
            setpoint_derivatives: SetpointDerivatives::new(),
            pressure1: PressureController::new(cfg.pressure),
            pressure2: PressureController::new(cfg.pressure),
            safety,
            condition: if config_ok {
                None
            } else {
                Some(FaultCode::ConfigInvalid)
            },
            last_p1_pa: None,
            last_p2_pa: None,
            last_angle_rad: None,
            tracking1: TrackingMonitor::default(),
            tracking2: TrackingMonitor::default(),
        }
    }

    /// The configuration.
    pub fn config(&self) -> &ControllerConfig {
        &self.cfg
    }

    /// The latched fault.
    pub fn fault(&self) -> Option<FaultCode> {
        self.safety.fault()
    }

    fn reset_laws(&mut self) {
        self.tracking1.reset();
        self.tracking2.reset();
        self.position.reset();
        self.torque.reset();
        if let Some(pid) = self.dp_pid.as_mut() {
            pid.reset();
        }
        self.setpoint_derivatives.reset();
        self.pressure1.reset();
        self.pressure2.reset();
    }

    /// Explicit re-arm after a fault. Returns false (and stays faulted) when the fault
    /// condition was still present in the last tick or the configuration is invalid.
    pub fn reset(&mut self) -> bool {
        if !self.config_ok || self.condition.is_some() {
            return false;
        }
        self.reset_laws();
        self.safety.reset(true)
    }

    /// One control tick. Pure: no hidden time, no I/O. Never panics; every float of the
    /// output is finite.
    pub fn step(&mut self, frame: &SensorFrame, setpoint: &Setpoint, dt_s: f32) -> TickOutput {
        // Scalars read once; the configuration (with its force-law and torque-model tables) is
        // not copied: a whole-struct copy cost ~190 instructions per tick on the Cortex-M4.
        let p_over_gauge_pa = self.cfg.p_over_gauge_pa;
        let sp_max = self.cfg.angle_setpoint_max_rad;
        // `dt_s.is_finite() && dt_s > 0.0 && dt_s <= dt_max_s` (see `dt_limit_s`).
        let dt_ok = dt_s > 0.0 && dt_s <= self.dt_limit_s;
        // Channels are aged by the nominal period when dt itself is bad.
        let dt_age = if dt_ok { dt_s } else { self.dt_fallback_s };

        // `dt_age.is_finite() && dt_age > 0.0`, decided once (`dt_ok` implies it).
        let dt_age_good = dt_ok || self.dt_fallback_good;
        let s1 = self.p1.update_with(frame.p1_gauge_pa, dt_age, dt_age_good);
        let s2 = self.p2.update_with(frame.p2_gauge_pa, dt_age, dt_age_good);
        let sa = self.angle.update_with(frame.angle_rad, dt_age, dt_age_good);
        if let Some(v) = s1.value() {
            self.last_p1_pa = Some(v);
        }
        if let Some(v) = s2.value() {
            self.last_p2_pa = Some(v);
        }
        if let Some(v) = sa.value() {
            self.last_angle_rad = Some(v);
        }
        let new_angle = match sa {
            ChannelStatus::Valid {
                value,
                age_ticks: 0,
            } => Some(value),
            _ => None,
        };
        let vel = self.velocity.update_with(new_angle, dt_age, dt_age_good);

        // Fault conditions of this tick (the first one found is reported). Fast path: one
        // branch-free test of all of them; the ordered search runs only when one holds.
        let over1 = matches!(s1.value(), Some(p) if p > p_over_gauge_pa);
        let over2 = matches!(s2.value(), Some(p) if p > p_over_gauge_pa);
        let sp_ok = setpoint.angle_rad.is_finite();
        let any = !self.config_ok
            | !dt_ok
            | matches!(s1, ChannelStatus::Fault(_))
            | matches!(s2, ChannelStatus::Fault(_))
            | matches!(sa, ChannelStatus::Fault(_))
            | over1
            | over2
            | !sp_ok;
        let cond = if any {
            first_condition(self.config_ok, dt_ok, s1, s2, sa, over1, over2, sp_ok)
        } else {
            None
        };
        self.condition = cond;
        if let Some(c) = cond {
            self.safety.raise(c);
        }

        let angle_est = self.last_angle_rad.unwrap_or(0.0);
        // The force-law torque estimate, computed once per tick: it is both the logged
        // `torque_est_nm` and, when all channels are fresh this tick (then `last_*` are this
        // tick's values), the torque loop's feedback.
        let estimate = match (self.last_p1_pa, self.last_p2_pa, self.last_angle_rad) {
            (Some(p1), Some(p2), Some(a)) => Some(torque_estimate_nm(
                &self.cfg.force_law,
                &self.cfg.geometry,
                p1,
                p2,
                a,
            )),
            _ => None,
        };
        let torque_est = match estimate {
            Some((t, flags)) if !flags.contains_any(ForceFlags::FATAL) && t.is_finite() => t,
            _ => 0.0,
        };
        // `vel` is finite: the estimator stores only finite velocities (starts at 0).

        let mut out = TickOutput {
            valves: ValveCommand::default(),
            p1_set_gauge_pa: 0.0,
            p2_set_gauge_pa: 0.0,
            torque_des_nm: 0.0,
            torque_est_nm: torque_est,
            angle_est_rad: angle_est,
            velocity_est_rad_s: vel,
            fault: None,
            armed: false,
        };

        if self.safety.fault().is_some() {
            return self.safe_output(out);
        }

        let (Some(p1), Some(p2), Some(angle)) = (s1.value(), s2.value(), sa.value()) else {
            // Start-up: some channel has not delivered yet. Valves closed, not armed.
            self.reset_laws();
            return out;
        };

        // Same result as `f32::clamp`, but without its (unreachable: the configuration is
        // validated) panic, whose message would link core::fmt's float formatting (~20 KiB of
        // MCU flash).
        let sp = if libm::fabsf(setpoint.angle_rad) <= sp_max {
            // In range: one comparison (NaN fails it; a NaN set-point has faulted anyway).
            setpoint.angle_rad
        } else if setpoint.angle_rad > sp_max {
            sp_max
        } else if setpoint.angle_rad < -sp_max {
            -sp_max
        } else {
            setpoint.angle_rad
        };
        // Every input of the control laws below is finite and `dt_s > 0` here (validated
        // channels, sanitised velocity, finite set-point, `dt_ok`; `t_des` is the clamped sum
        // of two finite torques), so the laws run without their own input checks
        // (`step_finite`: bit-identical to `step` for such inputs).
        let result = (|| {
            if let Some(pid) = self.dp_pid.as_mut() {
                // Model-free baseline: angle -> dp -> pressure set-points, no torque level.
                let c = pid.step(
                    JointState {
                        angle_rad: angle,
                        velocity_rad_s: vel,
                    },
                    sp,
                    dt_s,
                )?;
                let u1 = self.pressure1.step(p1, c.p1_gauge_pa, dt_s)?;
                let u2 = self.pressure2.step(p2, c.p2_gauge_pa, dt_s)?;
                return Ok::<_, crate::control::ControlError>((
                    0.0,
                    c.p1_gauge_pa,
                    c.p2_gauge_pa,
                    torque_est,
                    u1,
                    u2,
                ));
            }
            let ff = &self.cfg.feedforward;
            // Valid configuration here: `ff.cutoff_hz` is finite (>= 0).
            let (rate, accel) =
                self.setpoint_derivatives
                    .update_finite(sp, dt_s, ff.cutoff_hz, self.ff_tau_s)?;
            let t_pid = self.position.step_finite(
                JointState {
                    angle_rad: angle,
                    velocity_rad_s: vel,
                },
                sp,
                dt_s,
            )?;
            // Trajectory feed-forward (derivative on the error, inertia of the desired
            // motion), within the position loop's output limit.
            let t_ff = feedforward_torque_nm(ff, self.cfg.position.kd, rate, accel);
            let t_lim = libm::fabsf(self.cfg.position.out_limit);
            let t_sum = t_pid + t_ff;
            // In range (the usual case, one comparison; NaN fails it) or the full clamp.
            let t_des = if libm::fabsf(t_sum) <= t_lim {
                t_sum
            } else if t_sum > t_lim {
                t_lim
            } else if t_sum < -t_lim {
                -t_lim
            } else {
                t_sum
            };
            let meas = TorqueMeasurement {
                p1_gauge_pa: p1,
                p2_gauge_pa: p2,
                angle_rad: angle,
                velocity_rad_s: vel,
            };
            let ps = match estimate {
                // Armed implies all three channels valid this tick, so `estimate` was
                // computed from exactly `meas`; the torque loop reuses it (the loop's own force
                // law is the configuration's, see `ControlTick::new`).
                Some(est) => self.torque.step_finite(
                    meas,
                    est,
                    t_des,
                    dt_s,
                    self.dp_limit_pa,
                    self.p_set_hi_pa,
                )?,
                None => self.torque.step(meas, t_des, dt_s)?,
            };
            let u1 = self.pressure1.step_finite(p1, ps.p1_gauge_pa, dt_s)?;
            let u2 = self.pressure2.step_finite(p2, ps.p2_gauge_pa, dt_s)?;
            Ok((
                t_des,
                ps.p1_gauge_pa,
                ps.p2_gauge_pa,
                ps.torque_est_nm,
                u1,
                u2,
            ))
        })();
        match result {
            Ok((t_des, p1_set, p2_set, t_est, u1, u2)) => {
                let (e_pa, n) = (self.cfg.tracking_error_pa, self.cfg.tracking_ticks);
                let lost1 = self.tracking1.update(p1_set, p1, u1, e_pa, n);
                let lost2 = self.tracking2.update(p2_set, p2, u2, e_pa, n);
                if lost1 || lost2 {
                    let f = if lost1 {
                        FaultCode::PressureTrackingLost1
                    } else {
                        FaultCode::PressureTrackingLost2
                    };
                    warn!("pressure tracking lost: {}", f);
                    self.safety.raise(f);
                    out.torque_des_nm = t_des;
                    return self.safe_output(out);
                }
                // What `self.safety.gate(cmd)` and `clamp_pressure_setpoint_pa(p, P_MAX)` return
                // here, without recomputing it: no fault is latched (checked above, tracking
                // returned early), u1/u2 are finite and in [-1, 1] (pressure loop output),
                // and both laws' set-points are already in [0, P_MUSCLE_MAX] (the torque loop's
                // clamp, `DpPid::step`'s `clamp_pressure_setpoint_pa`).
                out.valves = ValveCommand {
                    muscle1: u1,
                    muscle2: u2,
                };
                out.p1_set_gauge_pa = p1_set;
                out.p2_set_gauge_pa = p2_set;
                out.torque_des_nm = t_des;
                out.torque_est_nm = t_est;
                out.armed = true;
                trace!(
                    "tick sp={} a={} T*={} p*=({}, {}) u=({}, {})",
                    sp,
                    angle,
                    t_des,
                    p1_set,
                    p2_set,
                    u1,
                    u2
                );
                out
            }
            Err(e) => {
                warn!("control law error: {}", e);
                self.condition = Some(FaultCode::ControllerNumeric);
                self.safety.raise(FaultCode::ControllerNumeric);
                self.safe_output(out)
            }
        }
    }

    fn safe_output(&mut self, mut out: TickOutput) -> TickOutput {
        self.reset_laws();
        out.valves = self.safety.safe_state().command();
        let (h1, h2) = match self.safety.safe_state() {
            SafeState::Hold => (
                clamp_pressure_setpoint_pa(self.last_p1_pa.unwrap_or(0.0), P_MUSCLE_MAX_GAUGE_PA),
                clamp_pressure_setpoint_pa(self.last_p2_pa.unwrap_or(0.0), P_MUSCLE_MAX_GAUGE_PA),
            ),
            SafeState::Vent => (0.0, 0.0),
        };
        out.p1_set_gauge_pa = h1;
        out.p2_set_gauge_pa = h2;
        out.torque_des_nm = 0.0;
        out.fault = self.safety.fault();
        out.armed = false;
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn reference_config_is_valid() {
        assert!(ControllerConfig::reference(1000.0).is_valid());
        assert!(ControllerConfig::reference(500.0).is_valid());
        assert!(!ControllerConfig::reference(f32::NAN).is_valid());
        assert!(!ControllerConfig::reference(0.0).is_valid());
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
        let mut cfg = ControllerConfig::reference(1000.0);
        cfg.safe_state = SafeState::Vent;
        let mut t = ControlTick::new(cfg);
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
        let mut t = tick();
        t.step(&frame(300e3, 300e3, 0.0), &SP0, DT);
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
    fn stale_angle_raises_fault_after_limit() {
        let mut t = tick();
        t.step(&frame(300e3, 300e3, 0.0), &SP0, DT);
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
        let mut t = tick();
        t.step(&frame(300e3, 300e3, 0.0), &SP0, DT);
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
        let mut cfg = ControllerConfig::reference(1000.0);
        cfg.position.kp = f32::NAN;
        let mut t = ControlTick::new(cfg);
        let o = t.step(&frame(300e3, 300e3, 0.0), &SP0, DT);
        assert_eq!(o.fault, Some(FaultCode::ConfigInvalid));
        assert!(!t.reset());
    }

    #[test]
    fn positive_step_inflates_muscle_one_and_deflates_muscle_two() {
        let mut t = tick();
        let o = t.step(&frame(300e3, 300e3, 0.0), &Setpoint { angle_rad: 0.2 }, DT);
        assert!(o.torque_des_nm > 0.0);
        assert!(o.p1_set_gauge_pa > 300e3 && o.p2_set_gauge_pa < 300e3);
        assert!(o.valves.muscle1 > 0.0 && o.valves.muscle2 < 0.0);
    }
}
