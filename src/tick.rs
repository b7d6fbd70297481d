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
    torque_from, JointState, PidGains, PositionController, PressureController, PressureLoopGains,
    TorqueController, TorqueLoopGains, TorqueMeasurement,
};
use crate::feedforward::{feedforward_torque_nm, FeedforwardGains, SetpointDerivatives};
use crate::force_law::{ForceFlags, ForceLawParams};
use crate::geometry::JointGeometry;
use crate::pid::{DpPid, DpPidGains};
use crate::residual::{ResidualMonitor, ValveModelParams};
use crate::safety::{
    clamp_pressure_setpoint_pa, FaultSet, SafeState, SafetyMonitor, TrackingMonitor,
};
use crate::sensors::{
    ChannelFault, ChannelLimits, ChannelStatus, ChannelValidator, VelocityEstimator,
};
use crate::torque_model::TorqueModelParams;
use crate::P_MUSCLE_MAX_GAUGE_PA;

pub use crate::safety::FaultCode;
/// The valve command type lives with the valve drivers; re-exported for the tick's users.
pub use crate::valves::ValveCommand;

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
    /// Latched fault: the first cause (Some => valves are in the safe state).
    pub fault: Option<FaultCode>,
    /// Every fault condition that holds in this tick (bit `code - 1`; empty while all is
    /// well). While faulted it keeps being evaluated; [`ControlTick::reset`] is refused
    /// while it is not empty.
    pub active: FaultSet,
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

/// Lowest tick rate the reference gains are stable at [Hz]. Measured with the firmware in
/// the loop on the full plant (host-sim `simulate --scenario` of `scenarios/step.toml` at other
/// `tick_hz`): 50 Hz oscillates +-8.9 deg after settling (the 10-tick valve PWM period is then
/// 200 ms), 100 Hz leaves 0.67 deg, 200 Hz settles to 0.17 deg (0.58 deg on the 11x loaded
/// joint), like 1 kHz. The gains are not scaled with the tick: the allowed range is narrowed.
pub const TICK_HZ_MIN: f32 = 200.0;
/// Highest tick rate accepted [Hz] (the board's timer range).
pub const TICK_HZ_MAX: f32 = 10_000.0;
/// Largest [`ControllerConfig::outer_period_ticks`].
pub const OUTER_PERIOD_TICKS_MAX: u16 = 10;

/// Configuration of the control tick.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ControllerConfig {
    /// Nominal tick rate [Hz], within [`TICK_HZ_MIN`]..=[`TICK_HZ_MAX`] (validated).
    pub tick_hz: f32,
    /// Longest accepted `dt` [s]; longer (a missed deadline) raises [`FaultCode::Watchdog`].
    pub dt_max_s: f32,
    /// Shortest accepted `dt` [s] (> 0, < `dt_max_s`); shorter (a double-triggered tick, a
    /// broken timer) raises [`FaultCode::Watchdog`]: the differentiators and the integrators
    /// assume at least this period.
    pub dt_min_s: f32,
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
    /// Measured pressure above this raises an over-pressure fault, and vents that muscle
    /// while faulted whatever the safe state [Pa gauge]. At most
    /// [`crate::P_MUSCLE_MAX_GAUGE_PA`] (validated); lower for a weaker muscle.
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
    /// The muscle pressure model and thresholds of the valve / supply supervision
    /// ([`crate::residual`]).
    pub valve_model: ValveModelParams,
    /// Bumpless take-over at power-up and after every accepted reset.
    pub start: StartRamp,
    /// The cascade's outer loops (set-point derivatives, position loop, trajectory
    /// feed-forward, force-law torque estimate, torque loop) run on one tick in this many, with
    /// the time since their last run as their `dt`; the pressure loops, their feed-forward,
    /// the validators and the supervision run every tick on the held pressure set-points.
    /// 1 = every loop every tick. In `1..=`[`OUTER_PERIOD_TICKS_MAX`], and the outer loops no
    /// slower than [`TICK_HZ_MIN`] (validated). The model-free law ignores it.
    pub outer_period_ticks: u16,
    /// Inverse thermodynamic feed-forward of the pressure loops ([`crate::pressure_ff`];
    /// cascade only), added to the P loop's valve command when `enabled`. Only with the
    /// `pressure-ff` feature: the default MCU tick carries none of it.
    #[cfg(feature = "pressure-ff")]
    pub pressure_ff: crate::pressure_ff::PressureFfParams,
    /// The hybrid model's learned volume ([`crate::volume_fnn`], seed 004 eq. 8-12) in the
    /// pressure feed-forward instead of the volume polynomial (`None`: the polynomial). Only
    /// with the `volume-fnn` feature; [`ControllerConfig::reference`] selects
    /// [`crate::constants::VOLUME_FNN`] (`config/volume.toml`).
    #[cfg(feature = "volume-fnn")]
    pub volume_fnn: Option<&'static crate::volume_fnn::VolumeFnn>,
}

/// How the tick takes over the joint at power-up and after every accepted
/// [`ControlTick::reset`] (the start phase): the position set-point starts at the measured
/// angle and moves to the requested one at a limited rate, and the muscles are pre-charged
/// at a limited rate to the co-contraction level before the loops get their full pressure
/// range. A joint that is already where it is asked to be, with charged muscles, leaves the
/// start phase in its first tick (the output is then exactly that of the plain cascade).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StartRamp {
    /// Fastest move of the position set-point from the measured angle to the requested one
    /// [rad/s].
    pub setpoint_rate_rad_s: f32,
    /// A joint within this distance of the requested set-point at the first tick is taken
    /// as being there (no ramp) [rad]: the angle sensor's resolution and noise.
    pub catch_rad: f32,
    /// Within `setpoint_rate_rad_s * approach_s` of the requested set-point the ramp slows
    /// down exponentially with this time constant [s] (down to 5 % of the rate limit, at
    /// which it ends on the set-point).
    pub approach_s: f32,
    /// The torque loop's pressure ceiling starts at the higher measured muscle pressure and
    /// rises this fast [Pa/s] to the configured ceiling: vented muscles are pre-charged to
    /// the co-contraction level, and no set-point jumps.
    pub precharge_rate_pa_s: f32,
}

impl StartRamp {
    /// 1 rad/s, slowing down over the last 0.2 rad (a 0.6 rad error is taken up in ~1 s),
    /// no ramp within 0.01 rad; 1 MPa/s (a vented muscle reaches the 294 kPa co-contraction
    /// level in 0.3 s, the 600 kPa ceiling in 0.6 s; the pressure loop lags the ramp by
    /// ~8 kPa, a quarter of its full-opening error).
    pub const REFERENCE: StartRamp = StartRamp {
        setpoint_rate_rad_s: 1.0,
        catch_rad: 0.01,
        approach_s: 0.2,
        precharge_rate_pa_s: 1.0e6,
    };

    /// No ramp: the start phase ends in the first armed tick whatever the joint's state
    /// (the plain cascade from the first tick: replays of recorded traces, tests that look
    /// at one tick).
    pub const INSTANT: StartRamp = StartRamp {
        setpoint_rate_rad_s: f32::MAX,
        catch_rad: f32::MAX,
        approach_s: 0.0,
        precharge_rate_pa_s: f32::MAX,
    };

    /// True when every parameter is usable.
    pub fn is_valid(&self) -> bool {
        let pos = |x: f32| x.is_finite() && x > 0.0;
        pos(self.setpoint_rate_rad_s)
            && self.approach_s.is_finite()
            && self.approach_s >= 0.0
            && self.catch_rad.is_finite()
            && self.catch_rad >= 0.0
            && pos(self.precharge_rate_pa_s)
    }
}

impl ControllerConfig {
    /// The feed-forward's constants are valid (always without the `pressure-ff` feature).
    fn pressure_ff_valid(&self) -> bool {
        #[cfg(feature = "volume-fnn")]
        if self.volume_fnn.is_some_and(|n| !n.is_valid()) {
            return false;
        }
        #[cfg(feature = "pressure-ff")]
        return self.pressure_ff.is_valid();
        #[cfg(not(feature = "pressure-ff"))]
        return true;
    }

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
    /// - Trajectory feed-forward ([`crate::feedforward`], added for the closed-loop comparison
    ///   of the control laws): derivative on the error (`w = 1`) and the inertia torque `J r''` of the
    ///   desired motion (J = 0.014 kg m^2 of the reference joint), limited to +-2 N m
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
    ///
    /// The numbers live in `config/controller.toml` (gains) and `config/plant_constants.toml`
    /// (inertia, pressure ceiling, valve and supply), turned into `crate::constants` by build.rs.
    pub fn reference(tick_hz: f32) -> Self {
        let ticks_ceil = |x: f32| -> u32 {
            // `as` saturates: NaN -> 0, huge -> u32::MAX; at least 1 tick.
            let t = libm::ceilf(x) as u32;
            if t < 1 {
                1
            } else {
                t
            }
        };
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
            dt_min_s: 0.25 / tick_hz,
            geometry: JointGeometry::REFERENCE,
            force_law: FORCE_LAW,
            torque_model: TORQUE_MODEL,
            position: crate::constants::POSITION_GAINS,
            torque: crate::constants::TORQUE_LOOP,
            pressure: crate::constants::PRESSURE_LOOP,
            velocity_cutoff_hz: crate::constants::VELOCITY_CUTOFF_HZ,
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
            p_over_gauge_pa: P_MUSCLE_MAX_GAUGE_PA,
            angle_setpoint_max_rad: 0.8,
            // Filling a muscle across 100 kPa takes ~25 ms with the reference valve; 0.3 s
            // of saturated command without getting there is a valve or supply failure.
            tracking_error_pa: 100_000.0,
            tracking_ticks: ticks(0.3),
            law: ControlLaw::Cascade,
            feedforward: crate::constants::FEEDFORWARD,
            #[cfg(feature = "pressure-ff")]
            pressure_ff: crate::constants::PRESSURE_FF,
            #[cfg(feature = "volume-fnn")]
            volume_fnn: Some(&crate::constants::VOLUME_FNN),
            // The residual window is 10 ms whatever the tick (10 ticks at 1 kHz): a shorter
            // window at a fast tick would turn the sensor noise into false valve faults.
            valve_model: ValveModelParams {
                window_ticks: ticks_ceil(tick_hz / 100.0),
                ..ValveModelParams::REFERENCE
            },
            start: StartRamp::REFERENCE,
            outer_period_ticks: crate::constants::OUTER_PERIOD_TICKS,
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
            && self.tick_hz >= TICK_HZ_MIN
            && self.tick_hz <= TICK_HZ_MAX
            && pos(self.dt_max_s)
            && pos(self.dt_min_s)
            && self.dt_min_s < self.dt_max_s
            && pos(g.sprocket_radius_m)
            && pos(g.rest_length_m)
            && g.initial_contraction.is_finite()
            // The tick's torque estimate relies on both (`torque_from` with `force_regular`).
            && self.force_law.is_regular()
            && g.stretches_finite_over(self.angle_limits.min, self.angle_limits.max)
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
            && [
                p.kp_nm_per_rad,
                p.ki_nm_per_rad_s,
                p.kd_nm_s_per_rad,
                p.i_limit_nm,
                p.out_limit_nm,
            ]
            .iter()
            .all(|&x| nonneg(x))
            && [t.kp, t.ki_per_s, t.corr_limit_nm, t.p_set_max_gauge_pa]
                .iter()
                .all(|&x| nonneg(x))
            && [pr.kp_per_pa, pr.ki_per_pa_s, pr.deadband_pa, pr.i_limit]
                .iter()
                .all(|&x| nonneg(x))
            && nonneg(self.velocity_cutoff_hz)
            && lim_ok(&self.pressure_limits)
            && lim_ok(&self.angle_limits)
            && pos(self.p_over_gauge_pa)
            && self.pressure_ff_valid()
            && self.p_over_gauge_pa <= P_MUSCLE_MAX_GAUGE_PA
            && nonneg(self.angle_setpoint_max_rad)
            && pos(self.tracking_error_pa)
            && self.tracking_ticks > 0
            && self.feedforward.is_valid()
            && self.valve_model.is_valid()
            && self.start.is_valid()
            && (1..=OUTER_PERIOD_TICKS_MAX).contains(&self.outer_period_ticks)
            && self.tick_hz / self.outer_period_ticks as f32 >= TICK_HZ_MIN
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
    /// `dt_floor_s <= dt <= dt_limit_s` (NaN and +inf fail them), the same as the finiteness
    /// test too.
    dt_limit_s: f32,
    /// `dt_min_s`, or the smallest positive float when that is not positive (then the
    /// configuration is invalid and faulted anyway): `dt >= dt_floor_s` implies `dt > 0`.
    dt_floor_s: f32,
    /// `cfg.torque_model.dp_limit_pa()` (a configuration constant of the torque loop).
    dp_limit_pa: f32,
    /// `clamp_pressure_setpoint_pa(f32::INFINITY, cfg.torque.p_set_max_gauge_pa)`: the
    /// torque loop's upper set-point bound (a configuration constant).
    p_set_hi_pa: f32,
    /// The configured value of `p_set_hi_pa` (which the start phase lowers while it
    /// pre-charges the muscles).
    p_set_hi_cfg_pa: f32,
    /// `cfg.angle_setpoint_max_rad` when the start phase is over, -1 while it runs: the
    /// set-point's one in-range comparison then fails and the start phase runs on the cold
    /// path, at no cost to the armed tick.
    sp_fast_max_rad: f32,
    /// Start phase: the ramped set-point [rad] and pressure ceiling [Pa]; `start_init` once
    /// they hold the values of the first armed tick.
    start_sp_rad: f32,
    /// The requested set-point of the last start-phase tick [rad].
    start_sp_prev_rad: f32,
    start_p_hi_pa: f32,
    start_init: bool,
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
    /// `cfg.pressure_ff.enabled` and the feed-forward's state.
    #[cfg(feature = "pressure-ff")]
    pressure_ff_on: bool,
    #[cfg(feature = "pressure-ff")]
    pressure_ff: crate::pressure_ff::PressureFeedforward,
    /// `cfg.outer_period_ticks` (at least 1), the ticks until the outer loops run next (0:
    /// this tick), the time since their last run [s] and what they held for the ticks in
    /// between.
    outer_period_ticks: u16,
    /// `1 / outer_period_ticks`: a set-point's change over a period, per tick.
    outer_per_tick: f32,
    outer_countdown: u16,
    outer_dt_s: f32,
    outer_held: OuterHeld,
    /// Anti-windup state: which way the valves were fully open last tick, as a joint-torque
    /// [`crate::control::Shortfall`] (see [`valve_shortfall`]).
    valve_shortfall: f32,
    /// Sign of `B r` of the configured torque model (+-1: maps dp to torque direction).
    torque_sign: f32,
    safety: SafetyMonitor,
    /// The fault conditions that held in the last tick (empty = all clear).
    active: FaultSet,

    tracking1: TrackingMonitor,
    tracking2: TrackingMonitor,
    residual: ResidualMonitor,
    /// The last command, and whether its openings still have to be given to the residual.
    last_command: ValveCommand,
    pending_command: bool,
}

/// What the cascade's outer loops computed on their last tick, held for the ticks in between
/// ([`ControllerConfig::outer_period_ticks`]).
#[derive(Clone, Copy, Debug, Default)]
struct OuterHeld {
    /// Desired joint torque [N m].
    torque_des_nm: f32,
    /// The torque loop's pressure set-points [Pa gauge] of the last outer run, and their
    /// change per tick since the run before [Pa]: the ticks in between extrapolate them, so
    /// the pressure loops follow a set-point that moves every tick (held, they would see it
    /// jump once per period and answer with one-tick valve pulses).
    p1_set_gauge_pa: f32,
    p2_set_gauge_pa: f32,
    p1_step_pa: f32,
    p2_step_pa: f32,
    /// Whether the set-points above are of an outer run since the last reset (else the
    /// next run's steps are 0).
    primed: bool,
    /// The force-law torque of the last outer run [N m].
    torque_est_nm: f32,
    /// The set-point's filtered rate [rad/s] and acceleration [rad/s^2].
    sp_rate_rad_s: f32,
    sp_accel_rad_s2: f32,
}

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
fn conditions(
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
        let dt_floor_s = if cfg.dt_min_s > 0.0 {
            cfg.dt_min_s
        } else {
            f32::MIN_POSITIVE
        };
        ControlTick {
            cfg,
            config_ok,
            dt_fallback_s,
            dt_fallback_good: dt_fallback_s.is_finite() && dt_fallback_s > 0.0,
            dt_limit_s,
            dt_floor_s,
            dp_limit_pa: cfg.torque_model.dp_limit_pa(),
            p_set_hi_pa: clamp_pressure_setpoint_pa(f32::INFINITY, cfg.torque.p_set_max_gauge_pa),
            p_set_hi_cfg_pa: clamp_pressure_setpoint_pa(
                f32::INFINITY,
                cfg.torque.p_set_max_gauge_pa,
            ),
            sp_fast_max_rad: -1.0,
            start_sp_rad: 0.0,
            start_sp_prev_rad: 0.0,
            start_p_hi_pa: 0.0,
            start_init: false,
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
            #[cfg(feature = "pressure-ff")]
            pressure_ff_on: cfg.pressure_ff.enabled,
            #[cfg(feature = "pressure-ff")]
            pressure_ff: {
                let ff = crate::pressure_ff::PressureFeedforward::new(
                    &cfg.pressure_ff,
                    &cfg.valve_model,
                    &cfg.geometry,
                    clamp_pressure_setpoint_pa(f32::INFINITY, cfg.torque.p_set_max_gauge_pa),
                    cfg.tick_hz,
                );
                #[cfg(feature = "volume-fnn")]
                let ff = ff.with_volume_fnn(cfg.volume_fnn);
                ff
            },
            outer_period_ticks: cfg.outer_period_ticks.max(1),
            outer_per_tick: 1.0 / cfg.outer_period_ticks.max(1) as f32,
            outer_countdown: 0,
            outer_dt_s: 0.0,
            outer_held: OuterHeld::default(),
            valve_shortfall: 0.0,
            torque_sign: if cfg.torque_model.b_m2 * cfg.torque_model.sprocket_radius_m < 0.0 {
                -1.0
            } else {
                1.0
            },
            safety,
            active: if config_ok {
                FaultSet::EMPTY
            } else {
                FaultSet::of(FaultCode::ConfigInvalid)
            },
            tracking1: TrackingMonitor::default(),
            tracking2: TrackingMonitor::default(),
            residual: ResidualMonitor::new(cfg.valve_model, &cfg.geometry),
            last_command: ValveCommand {
                muscle1: 0.0,
                muscle2: 0.0,
            },
            pending_command: false,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &ControllerConfig {
        &self.cfg
    }

    /// The latched fault (the first cause).
    pub fn fault(&self) -> Option<FaultCode> {
        self.safety.fault()
    }

    /// Every fault raised since the last reset.
    pub fn faults_seen(&self) -> FaultSet {
        self.safety.seen()
    }

    /// The fault conditions that held in the last tick.
    pub fn active_conditions(&self) -> FaultSet {
        self.active
    }

    /// The latched state as a persistent-latch record ([`crate::latch`]): store it after
    /// every tick ([`crate::latch::PersistentLatch::update`] writes only on a change).
    pub fn latch_record(&self) -> crate::latch::LatchRecord {
        crate::latch::LatchRecord {
            cause: self.safety.fault(),
            seen: self.safety.seen(),
            vented: self.safety.vented(),
        }
    }

    /// Starts in the latched state of a stored record (the boot decision was
    /// [`crate::latch::BootDecision::Safe`]): the safe state from the first tick, until an
    /// explicit [`ControlTick::reset`].
    pub fn restore_latch(&mut self, record: &crate::latch::LatchRecord) {
        self.safety
            .restore(record.cause, record.seen, record.vented);
    }

    /// The P loops' commands plus the inverse thermodynamic feed-forward, each clamped to
    /// [-1, 1] (both terms are finite and in [-1, 1]): the held duties between the
    /// feed-forward's evaluations, else [`Self::evaluate_pressure_ff`].
    #[cfg(feature = "pressure-ff")]
    #[inline(always)]
    fn add_pressure_ff(
        &mut self,
        (u1, u2): (f32, f32),
        set_pa: [f32; 2],
        meas: &TorqueMeasurement,
        reference: JointState,
        sp_accel_rad_s2: f32,
    ) -> (f32, f32) {
        let [f1, f2] = match self.pressure_ff.held([meas.p1_gauge_pa, meas.p2_gauge_pa]) {
            Some(f) => f,
            None => self.evaluate_pressure_ff(set_pa, meas, reference, sp_accel_rad_s2),
        };
        // In range (the usual case: one test) or the clamp; NaN passes unchanged. (Not
        // `f32::clamp`: its unreachable panic message would link core::fmt's float formatting.)
        #[allow(clippy::manual_clamp)]
        let c = |u: f32| {
            if libm::fabsf(u) <= 1.0 {
                u
            } else if u > 1.0 {
                1.0
            } else if u < -1.0 {
                -1.0
            } else {
                u
            }
        };
        (c(u1 + f1), c(u2 + f2))
    }

    /// The feed-forward's evaluating tick: with `rate_from_reference` the desired pressures
    /// are those of the reference trajectory: the torque loop's inverse model at the
    /// `reference` (set-point and its rate) for the inertia torque `J r''` of the trajectory
    /// feed-forward (within its limit), `p0 -+ dp`, otherwise the set-points themselves;
    /// `V'` from the set-point rate with `volume_rate_from_reference`, otherwise from the
    /// measured velocity of `meas` (this tick's measurements).
    #[cfg(feature = "pressure-ff")]
    #[inline(always)]
    fn evaluate_pressure_ff(
        &mut self,
        set_pa: [f32; 2],
        meas: &TorqueMeasurement,
        reference: JointState,
        sp_accel_rad_s2: f32,
    ) -> [f32; 2] {
        let pf = &self.cfg.pressure_ff;
        let (sp_rad, sp_rate_rad_s) = (reference.angle_rad, reference.velocity_rad_s);
        let v_rad_s = if pf.volume_rate_from_reference {
            sp_rate_rad_s
        } else {
            meas.velocity_rad_s
        };
        let desired_pa = if pf.rate_from_reference {
            // The trajectory feed-forward's inertia term alone (no derivative gain), within
            // its limit.
            let t =
                feedforward_torque_nm(&self.cfg.feedforward, 0.0, sp_rate_rad_s, sp_accel_rad_s2);
            let m = &self.cfg.torque_model;
            // Finite inputs (validated set-point and its derivatives): dp finite and clamped.
            let dp = m
                .inverse_at_finite(sp_rad, sp_rate_rad_s, self.dp_limit_pa)
                .activation(t)
                .dp_pa;
            [m.p0_gauge_pa - dp, m.p0_gauge_pa + dp]
        } else {
            set_pa
        };
        // Finite inputs (see `step_inner`): no finiteness test of its own.
        self.pressure_ff
            .evaluate_finite(&crate::pressure_ff::FfInputs {
                set_pa,
                desired_pa,
                meas_pa: [meas.p1_gauge_pa, meas.p2_gauge_pa],
                angle_rad: meas.angle_rad,
                velocity_rad_s: v_rad_s,
            })
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
        #[cfg(feature = "pressure-ff")]
        self.pressure_ff.reset();
        self.valve_shortfall = 0.0;
        // The next armed tick runs the outer loops, with no set-point history.
        self.outer_countdown = 0;
        self.outer_dt_s = 0.0;
        self.outer_held.primed = false;
        // The next armed tick starts a new start phase.
        self.sp_fast_max_rad = -1.0;
        self.start_init = false;
        self.p_set_hi_pa = self.p_set_hi_cfg_pa;
    }

    /// The set-point of an armed tick when the fast in-range test failed: the clamp to
    /// `+-sp_max`, and the start phase (see [`StartRamp`]) while it runs. Inputs are finite
    /// (validated channels, a finite set-point, `dt_ok`).
    #[cold]
    #[inline(never)]
    fn setpoint_slow(
        &mut self,
        requested_rad: f32,
        angle_rad: f32,
        p1_gauge_pa: f32,
        p2_gauge_pa: f32,
        dt_s: f32,
    ) -> f32 {
        let sp_max = self.cfg.angle_setpoint_max_rad;
        let sp = if requested_rad > sp_max {
            sp_max
        } else if requested_rad < -sp_max {
            -sp_max
        } else {
            requested_rad
        };
        if self.sp_fast_max_rad >= 0.0 {
            return sp;
        }
        let r = self.cfg.start;
        let hi = self.p_set_hi_cfg_pa;
        if !self.start_init {
            self.start_init = true;
            // Within `catch_rad` (the angle sensor's resolution and noise) the joint is where
            // it is asked to be: no ramp.
            self.start_sp_rad = if libm::fabsf(sp - angle_rad) <= r.catch_rad {
                sp
            } else {
                angle_rad
            };
            self.start_p_hi_pa =
                libm::fminf(libm::fmaxf(libm::fmaxf(p1_gauge_pa, p2_gauge_pa), 0.0), hi);
            self.start_sp_prev_rad = sp;
        }
        let d = sp - self.start_sp_rad;
        // The set-point's own motion this tick: the ramp chases a moving set-point at its
        // speed plus the approach term, so the distance decays whatever the set-point does
        // (unless it moves faster than the rate limit).
        let sp_move_rad = libm::fabsf(sp - self.start_sp_prev_rad);
        self.start_sp_prev_rad = sp;
        // The rate limit, and near the end an exponential approach (rate |d| / approach_s)
        // that keeps 5 % of the rate limit so that it ends.
        let full_rad = r.setpoint_rate_rad_s * dt_s;
        let step_rad = libm::fminf(
            full_rad,
            libm::fmaxf(
                libm::fabsf(d) * dt_s / libm::fmaxf(r.approach_s, dt_s) + sp_move_rad,
                0.05 * full_rad,
            ),
        );
        // Caught once the rest is within one tick at the full rate: the set-point then
        // moves by at most that much, and a moving set-point is followed from there.
        let caught = libm::fabsf(d) <= full_rad;
        self.start_sp_rad = if caught {
            sp
        } else if d > 0.0 {
            self.start_sp_rad + step_rad
        } else {
            self.start_sp_rad - step_rad
        };
        let charged = self.start_p_hi_pa >= hi;
        if caught && charged {
            // The start phase is over: from here on the plain cascade.
            self.sp_fast_max_rad = sp_max;
            self.p_set_hi_pa = hi;
            return sp;
        }
        let p = libm::fminf(self.start_p_hi_pa + r.precharge_rate_pa_s * dt_s, hi);
        self.start_p_hi_pa = p;
        self.p_set_hi_pa = p;
        self.start_sp_rad
    }

    /// Explicit re-arm after a fault. Returns false (and stays faulted) when any fault
    /// condition was still present in the last tick or the configuration is invalid.
    pub fn reset(&mut self) -> bool {
        if !self.config_ok || !self.active.is_empty() {
            return false;
        }
        self.reset_laws();
        self.safety.reset(true)
    }

    /// One control tick. Pure: no hidden time, no I/O. Never panics; every float of the
    /// output is finite.
    #[inline]
    pub fn step(&mut self, frame: &SensorFrame, setpoint: &Setpoint, dt_s: f32) -> TickOutput {
        self.command_stands_in();
        // Without the external torque (`None`, a constant once `step_inner` is inlined: the
        // 1-DOF tick's code is what it was before the torque input existed).
        let out = self.step_inner(frame, setpoint, None, dt_s);
        self.last_command = out.valves;
        self.pending_command = true;
        out
    }

    /// [`Self::step`] with an extra joint torque `torque_ff_nm` [N m] added to the position
    /// loop's (clamped) output before the torque loop inverts the torque model: a
    /// feed-forward computed outside this joint (the arm's gravity and coupling torques,
    /// [`crate::arm`]). A non-finite value counts as 0.
    #[inline(never)]
    pub fn step_with_torque(
        &mut self,
        frame: &SensorFrame,
        setpoint: &Setpoint,
        torque_ff_nm: f32,
        dt_s: f32,
    ) -> TickOutput {
        let t = if torque_ff_nm.is_finite() {
            torque_ff_nm
        } else {
            0.0
        };
        self.command_stands_in();
        let out = self.step_inner(frame, setpoint, Some(t), dt_s);
        self.last_command = out.valves;
        self.pending_command = true;
        out
    }

    /// When the caller did not report the driver's openings of the last command, the
    /// command stands in for them in the valve / supply residual.
    #[inline(always)]
    fn command_stands_in(&mut self) {
        if self.pending_command {
            let c = crate::valves::ValveOpenings::from_command(&self.last_command);
            self.residual.openings(c.u_in1, c.u_ex1, c.u_in2, c.u_ex2);
        }
    }

    /// Reports what the valve driver switched for this tick's command (the return of
    /// [`crate::valves::OnOffValves::apply`]), for the valve / supply supervision
    /// ([`crate::residual`]). Call after every `step`; without it the command stands in.
    #[inline]
    pub fn valves_applied(&mut self, o: &crate::valves::ValveOpenings) {
        self.residual.openings(o.u_in1, o.u_ex1, o.u_in2, o.u_ex2);
        self.pending_command = false;
    }

    /// [`Self::valves_applied`] for on/off valves: what
    /// [`crate::valves::OnOffValves::apply_switched`] returns.
    #[inline]
    pub fn valves_switched(&mut self, s: crate::valves::SwitchedValves) {
        self.residual.switched(s.lanes());
        self.pending_command = false;
    }

    /// A residual (valve / supply) fault: raised, and a tracking-lost cause of the same
    /// muscle stays active while it persists.
    #[cold]
    #[inline(never)]
    fn residual_fault(&mut self, set: FaultSet) {
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

    #[inline(always)]
    fn step_inner(
        &mut self,
        frame: &SensorFrame,
        setpoint: &Setpoint,
        torque_ff_nm: Option<f32>,
        dt_s: f32,
    ) -> TickOutput {
        // Scalars read once; the configuration (with its force-law and torque-model tables) is
        // not copied: a whole-struct copy cost ~190 instructions per tick on the Cortex-M4.
        let p_over_gauge_pa = self.cfg.p_over_gauge_pa;
        // `dt_s.is_finite() && dt_s >= dt_min_s && dt_s <= dt_max_s` (see `dt_limit_s`).
        let dt_ok = dt_s >= self.dt_floor_s && dt_s <= self.dt_limit_s;
        // Channels are aged by the nominal period when dt itself is bad.
        let dt_age = if dt_ok { dt_s } else { self.dt_fallback_s };

        // `dt_age.is_finite() && dt_age > 0.0`, decided once (`dt_ok` implies it).
        let dt_age_good = dt_ok || self.dt_fallback_good;
        let s1 = self.p1.update_with(frame.p1_gauge_pa, dt_age, dt_age_good);
        let s2 = self.p2.update_with(frame.p2_gauge_pa, dt_age, dt_age_good);
        let sa = self.angle.update_with(frame.angle_rad, dt_age, dt_age_good);
        let new_angle = match sa {
            ChannelStatus::Valid {
                value,
                age_ticks: 0,
            } => Some(value),
            _ => None,
        };
        let vel = self.velocity.update_with(new_angle, dt_age, dt_age_good);
        // Valve / supply supervision on this tick's fresh samples.
        let residual = match (s1, s2, new_angle) {
            (
                ChannelStatus::Valid {
                    value: p1,
                    age_ticks: 0,
                },
                ChannelStatus::Valid {
                    value: p2,
                    age_ticks: 0,
                },
                Some(a),
            ) if dt_ok => self.residual.observe(true, p1, p2, a, dt_s),
            _ => self.residual.observe(false, 0.0, 0.0, 0.0, dt_s),
        };

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
        self.active = residual;
        if !residual.is_empty() {
            self.residual_fault(residual);
        }
        if any {
            let (set, first) = conditions(self.config_ok, dt_ok, s1, s2, sa, over1, over2, sp_ok);
            self.active = set.union(residual);
            if let Some(c) = first {
                self.safety.raise(c);
            }
            self.safety.raise_all(set);
            // Escalation: a muscle above the over-pressure limit is vented (this tick: the
            // over-pressure fault itself puts the valves in the safe state).
            if over1 {
                self.safety.escalate_vent(0);
            }
            if over2 {
                self.safety.escalate_vent(1);
            }
        }

        let angle_est = self.angle.last().unwrap_or(0.0);
        // The force-law torque estimate, computed once per tick on the ticks the outer loops
        // run (every tick that does not arm is one: `reset_laws`): it is both the logged
        // `torque_est_nm` and, when all channels are fresh this tick (then `last_*` are this
        // tick's values), the torque loop's feedback. In between, the last one is held.
        // A faulted tick computes it too (its output and the numeric fault's persistence).
        let outer = self.outer_countdown == 0;
        let fresh = outer || self.safety.fault().is_some();
        let estimate = if fresh { self.estimate() } else { None };
        let torque_est = if fresh {
            usable_torque(estimate).unwrap_or(0.0)
        } else {
            self.outer_held.torque_est_nm
        };
        // `vel` is finite: the estimator stores only finite velocities (starts at 0).

        // The output of a tick that does not arm; the armed path builds its own (no field
        // written twice on the hot path).
        let out = TickOutput {
            valves: ValveCommand::default(),
            p1_set_gauge_pa: 0.0,
            p2_set_gauge_pa: 0.0,
            torque_des_nm: 0.0,
            torque_est_nm: torque_est,
            angle_est_rad: angle_est,
            velocity_est_rad_s: vel,
            fault: None,
            active: FaultSet::EMPTY,
            armed: false,
        };

        if self.safety.fault().is_some() {
            // A numeric fault persists while the force-law estimate of the current
            // measurements is unusable.
            if self.safety.seen().contains(FaultCode::ControllerNumeric)
                && usable_torque(estimate).is_none()
            {
                self.active.insert(FaultCode::ControllerNumeric);
            }
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
        // One comparison in the usual case (NaN fails it; a NaN set-point has faulted
        // anyway). Out of range, and during the start phase (`sp_fast_max_rad` < 0), the cold
        // path clamps or ramps. (`f32::clamp` is avoided: its unreachable panic message would
        // link core::fmt's float formatting, ~20 KiB of MCU flash.)
        let sp = if libm::fabsf(setpoint.angle_rad) <= self.sp_fast_max_rad {
            setpoint.angle_rad
        } else {
            self.setpoint_slow(setpoint.angle_rad, angle, p1, p2, dt_s)
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
            let meas = TorqueMeasurement {
                p1_gauge_pa: p1,
                p2_gauge_pa: p2,
                angle_rad: angle,
                velocity_rad_s: vel,
            };
            // The outer loops on one tick in `outer_period_ticks` (`outer`: the estimate was
            // computed), with the time since their last run; in between, their held output.
            let (t_des, ps, rate, accel) = if outer {
                self.outer_countdown = self.outer_period_ticks - 1;
                // `0.0 + dt_s` is `dt_s` (dt_s > 0): every tick's bits when the period is 1.
                let dt_outer_s = self.outer_dt_s + dt_s;
                self.outer_dt_s = 0.0;
                let (t_des, ps, rate, accel) =
                    self.outer_loops(&meas, sp, torque_ff_nm, estimate, dt_outer_s)?;
                if self.outer_period_ticks > 1 {
                    let h = &self.outer_held;
                    let (s1, s2) = if h.primed {
                        let per_tick = self.outer_per_tick;
                        (
                            (ps.p1_gauge_pa - h.p1_set_gauge_pa) * per_tick,
                            (ps.p2_gauge_pa - h.p2_set_gauge_pa) * per_tick,
                        )
                    } else {
                        (0.0, 0.0)
                    };
                    self.outer_held = OuterHeld {
                        torque_des_nm: t_des,
                        p1_set_gauge_pa: ps.p1_gauge_pa,
                        p2_set_gauge_pa: ps.p2_gauge_pa,
                        p1_step_pa: s1,
                        p2_step_pa: s2,
                        primed: true,
                        torque_est_nm: ps.torque_est_nm,
                        sp_rate_rad_s: rate,
                        sp_accel_rad_s2: accel,
                    };
                }
                (
                    t_des,
                    [ps.p1_gauge_pa, ps.p2_gauge_pa, ps.torque_est_nm],
                    rate,
                    accel,
                )
            } else {
                self.between_outer_runs(dt_s)
            };
            let [p1_set, p2_set, t_est] = ps;
            let u1 = self.pressure1.step_finite(p1, p1_set, dt_s)?;
            let u2 = self.pressure2.step_finite(p2, p2_set, dt_s)?;
            // Compiled in with the `pressure-ff` feature only (the default MCU tick has none of
            // it), and run when the configuration enables it.
            #[cfg(feature = "pressure-ff")]
            let (u1, u2) = if self.pressure_ff_on {
                self.add_pressure_ff(
                    (u1, u2),
                    [p1_set, p2_set],
                    &meas,
                    JointState {
                        angle_rad: sp,
                        velocity_rad_s: rate,
                    },
                    accel,
                )
            } else {
                (u1, u2)
            };
            #[cfg(not(feature = "pressure-ff"))]
            let _ = (rate, accel);
            self.valve_shortfall = valve_shortfall(u1, u2, self.torque_sign);
            Ok((t_des, p1_set, p2_set, t_est, u1, u2))
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
                    if lost1 {
                        self.active.insert(FaultCode::PressureTrackingLost1);
                    }
                    if lost2 {
                        self.active.insert(FaultCode::PressureTrackingLost2);
                        self.safety.raise(FaultCode::PressureTrackingLost2);
                    }
                    return self.safe_output(out);
                }
                // What `self.safety.gate(cmd)` and `clamp_pressure_setpoint_pa(p, P_MAX)` return
                // here, without recomputing it: no fault is latched (checked above, tracking
                // returned early), u1/u2 are finite and in [-1, 1] (pressure loop output),
                // and both laws' set-points are already in [0, P_MUSCLE_MAX] (the torque loop's
                // clamp, `DpPid::step`'s `clamp_pressure_setpoint_pa`).
                let armed = TickOutput {
                    valves: ValveCommand {
                        muscle1: u1,
                        muscle2: u2,
                    },
                    p1_set_gauge_pa: p1_set,
                    p2_set_gauge_pa: p2_set,
                    torque_des_nm: t_des,
                    torque_est_nm: t_est,
                    armed: true,
                    ..out
                };
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
                armed
            }
            Err(e) => {
                warn!("control law error: {}", e);
                self.active.insert(FaultCode::ControllerNumeric);
                self.safety.raise(FaultCode::ControllerNumeric);
                self.safe_output(out)
            }
        }
    }

    /// A tick between two runs of the outer loops: their held torques and set-point
    /// derivatives, and the pressure set-points extrapolated by their change over the last
    /// period, within the torque loop's bounds (its ceiling, 0). Not inlined: inlined, the
    /// compiler copies the rest of the tick into both branches (+760 B of board flash).
    #[inline(never)]
    fn between_outer_runs(&mut self, dt_s: f32) -> (f32, [f32; 3], f32, f32) {
        self.outer_countdown -= 1;
        self.outer_dt_s += dt_s;
        let h = self.outer_held;
        // Ticks since the outer run (1 on the first tick after it).
        let k = (self.outer_period_ticks - self.outer_countdown - 1) as f32;
        let hi = self.p_set_hi_pa;
        (
            h.torque_des_nm,
            [
                crate::safety::clamp_setpoint_to(h.p1_set_gauge_pa + k * h.p1_step_pa, hi),
                crate::safety::clamp_setpoint_to(h.p2_set_gauge_pa + k * h.p2_step_pa, hi),
                h.torque_est_nm,
            ],
            h.sp_rate_rad_s,
            h.sp_accel_rad_s2,
        )
    }

    /// The force-law torque estimate of the last samples (`None` until all three channels
    /// delivered) and its flags.
    #[inline(always)]
    fn estimate(&self) -> Option<(f32, ForceFlags)> {
        match (self.p1.last(), self.p2.last(), self.angle.last()) {
            (Some(p1), Some(p2), Some(a)) => Some(torque_from(
                |p, e| self.cfg.force_law.force_regular(p, e),
                &self.cfg.geometry,
                p1,
                p2,
                a,
            )),
            _ => None,
        }
    }

    /// The cascade's outer loops of an armed tick (inputs finite, `dt_s` the time since their
    /// last run): the set-point's rate and acceleration, the position loop with the trajectory
    /// feed-forward (and the external one of `step_with_torque`) within its limit, and the
    /// torque loop on the force-law `estimate` of this tick's measurements `meas`. Returns the
    /// desired torque, the pressure set-points, the set-point's rate and acceleration.
    #[inline(always)]
    fn outer_loops(
        &mut self,
        meas: &TorqueMeasurement,
        sp: f32,
        torque_ff_nm: Option<f32>,
        estimate: Option<(f32, ForceFlags)>,
        dt_s: f32,
    ) -> Result<(f32, crate::control::PressureSetpoints, f32, f32), crate::control::ControlError>
    {
        let ff = &self.cfg.feedforward;
        // Valid configuration here: `ff.cutoff_hz` is finite (>= 0).
        let (rate, accel) =
            self.setpoint_derivatives
                .update_finite(sp, dt_s, ff.cutoff_hz, self.ff_tau_s)?;
        // Anti-windup from downstream: the torque loop's and the valves' saturation of
        // the last tick, in joint-torque direction.
        let t_pid = self.position.step_finite(
            JointState {
                angle_rad: meas.angle_rad,
                velocity_rad_s: meas.velocity_rad_s,
            },
            sp,
            dt_s,
            self.torque.shortfall_nm() + self.valve_shortfall,
        )?;
        // Trajectory feed-forward (derivative on the error, inertia of the desired
        // motion), within the position loop's output limit.
        let t_ff = feedforward_torque_nm(ff, self.cfg.position.kd_nm_s_per_rad, rate, accel);
        let t_lim = libm::fabsf(self.cfg.position.out_limit_nm);
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
        // The external feed-forward (finite), only in `step_with_torque`.
        let t_des = match torque_ff_nm {
            Some(t) => t_des + t,
            None => t_des,
        };
        let ps = match estimate {
            // Armed implies all three channels valid this tick, so `estimate` was
            // computed from exactly `meas`; the torque loop reuses it (the loop's own force
            // law is the configuration's, see `ControlTick::new`).
            Some(est) => self.torque.step_finite(
                *meas,
                est,
                t_des,
                dt_s,
                self.dp_limit_pa,
                self.p_set_hi_pa,
                self.valve_shortfall,
            )?,
            None => self.torque.step(*meas, t_des, dt_s)?,
        };
        Ok((t_des, ps, rate, accel))
    }

    fn safe_output(&mut self, mut out: TickOutput) -> TickOutput {
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

/// The torque of a force-law estimate, `None` when there is none or it is unusable.
#[inline(always)]
fn usable_torque(estimate: Option<(f32, ForceFlags)>) -> Option<f32> {
    match estimate {
        Some((t, flags)) if !flags.contains_any(ForceFlags::FATAL) && t.is_finite() => Some(t),
        _ => None,
    }
}

/// The valves' saturation as a joint-torque [`crate::control::Shortfall`]: a muscle whose
/// valve command is at +-1 cannot change its pressure faster that way. Muscle 1 follows
/// `p1 = p0 - dp`, muscle 2 `p2 = p0 + dp`; `torque_sign` (sign of B r) maps dp to torque.
/// The commands are in [-1, 1], so their truncation is +-1 exactly at saturation, else 0:
/// `trunc(u2) - trunc(u1)` is the blocked dp direction (two conversions, no branch).
#[inline(always)]
fn valve_shortfall(u1: f32, u2: f32, torque_sign: f32) -> f32 {
    ((u2 as i32) - (u1 as i32)) as f32 * torque_sign
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
}
