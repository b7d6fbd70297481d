//! The control tick's configuration: which control law, the gains and limits of every loop,
//! the sensor validation, the safe state, the start phase and the loop rates
//! ([`ControllerConfig`], [`ControllerConfig::reference`], [`ControllerConfig::is_valid`]).

use crate::constants::{FORCE_LAW, TORQUE_MODEL};
use crate::control::{PidGains, PressureLoopGains, TorqueLoopGains};
use crate::feedforward::FeedforwardGains;
use crate::force_law::ForceLawParams;
use crate::geometry::JointGeometry;
use crate::pid::DpPidGains;
use crate::residual::ValveModelParams;
use crate::safety::SafeState;
use crate::sensors::ChannelLimits;
use crate::torque_model::TorqueModelParams;
use crate::P_MUSCLE_MAX_GAUGE_PA;

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
    /// Longest accepted `dt` [s]; longer (a missed deadline) raises [`FaultCode::Watchdog`](crate::safety::FaultCode::Watchdog).
    pub dt_max_s: f32,
    /// Shortest accepted `dt` [s] (> 0, < `dt_max_s`); shorter (a double-triggered tick, a
    /// broken timer) raises [`FaultCode::Watchdog`](crate::safety::FaultCode::Watchdog): the differentiators and the integrators
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
/// [`ControlTick::reset`](crate::tick::ControlTick::reset) (the start phase): the position set-point starts at the measured
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
