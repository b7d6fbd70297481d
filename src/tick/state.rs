//! The control tick's state ([`ControlTick`]): its configuration and the constants derived
//! from it, the sensor validators, the control laws, the outer-loop schedule, the start phase
//! and the supervision; how it is built, inspected, reset and told what the valves did.

use crate::control::{PositionController, PressureController, TorqueController};
use crate::feedforward::SetpointDerivatives;
use crate::pid::DpPid;
use crate::residual::ResidualMonitor;
use crate::safety::{
    clamp_pressure_setpoint_pa, FaultCode, FaultSet, SafetyMonitor, TrackingMonitor,
};
use crate::sensors::{ChannelValidator, VelocityEstimator};
use crate::tick::config::{ControlLaw, ControllerConfig};
use crate::valves::ValveCommand;

/// The control tick: validation + cascade + safety. No allocation, no panic, no hidden time.
pub struct ControlTick {
    pub(super) cfg: ControllerConfig,
    pub(super) config_ok: bool,
    /// The period channels are aged by when `dt` itself is bad: `1 / tick_hz`, or 1 ms for
    /// an unusable `tick_hz` (computed once here instead of every tick).
    pub(super) dt_fallback_s: f32,
    /// `dt_fallback_s.is_finite() && dt_fallback_s > 0.0`.
    pub(super) dt_fallback_good: bool,
    /// `dt_max_s`, with +inf replaced by `f32::MAX`: then `dt_ok` is the two comparisons
    /// `dt_floor_s <= dt <= dt_limit_s` (NaN and +inf fail them), the same as the finiteness
    /// test too.
    pub(super) dt_limit_s: f32,
    /// `dt_min_s`, or the smallest positive float when that is not positive (then the
    /// configuration is invalid and faulted anyway): `dt >= dt_floor_s` implies `dt > 0`.
    pub(super) dt_floor_s: f32,
    /// `cfg.torque_model.dp_limit_pa()` (a configuration constant of the torque loop).
    pub(super) dp_limit_pa: f32,
    /// `clamp_pressure_setpoint_pa(f32::INFINITY, cfg.torque.p_set_max_gauge_pa)`: the
    /// torque loop's upper set-point bound (a configuration constant).
    pub(super) p_set_hi_pa: f32,
    /// The configured value of `p_set_hi_pa` (which the start phase lowers while it
    /// pre-charges the muscles).
    pub(super) p_set_hi_cfg_pa: f32,
    /// `cfg.angle_setpoint_max_rad` when the start phase is over, -1 while it runs: the
    /// set-point's one in-range comparison then fails and the start phase runs on the cold
    /// path, at no cost to the armed tick.
    pub(super) sp_fast_max_rad: f32,
    /// Start phase: the ramped set-point [rad] and pressure ceiling [Pa]; `start_init` once
    /// they hold the values of the first armed tick.
    pub(super) start_sp_rad: f32,
    /// The requested set-point of the last start-phase tick [rad].
    pub(super) start_sp_prev_rad: f32,
    pub(super) start_p_hi_pa: f32,
    pub(super) start_init: bool,
    /// `SetpointDerivatives::tau_s(cfg.feedforward.cutoff_hz)` (a configuration constant).
    pub(super) ff_tau_s: f32,
    pub(super) p1: ChannelValidator,
    pub(super) p2: ChannelValidator,
    pub(super) angle: ChannelValidator,
    pub(super) velocity: VelocityEstimator,
    pub(super) position: PositionController,
    pub(super) torque: TorqueController,
    /// The model-free law when the configuration selects [`ControlLaw::DirectPid`].
    pub(super) dp_pid: Option<DpPid>,
    /// Set-point rate and acceleration for the cascade's feed-forward.
    pub(super) setpoint_derivatives: SetpointDerivatives,
    pub(super) pressure1: PressureController,
    pub(super) pressure2: PressureController,
    /// `cfg.pressure_ff.enabled` and the feed-forward's state.
    #[cfg(feature = "pressure-ff")]
    pub(super) pressure_ff_on: bool,
    #[cfg(feature = "pressure-ff")]
    pub(super) pressure_ff: crate::pressure_ff::PressureFeedforward,
    /// `cfg.outer_period_ticks` (at least 1), the ticks until the outer loops run next (0:
    /// this tick), the time since their last run [s] and what they held for the ticks in
    /// between.
    pub(super) outer_period_ticks: u16,
    /// `1 / outer_period_ticks`: a set-point's change over a period, per tick.
    pub(super) outer_per_tick: f32,
    pub(super) outer_countdown: u16,
    pub(super) outer_dt_s: f32,
    pub(super) outer_held: OuterHeld,
    /// Anti-windup state: which way the valves were fully open last tick, as a joint-torque
    /// [`crate::control::Shortfall`] (see [`valve_shortfall`](super::valve_shortfall)).
    pub(super) valve_shortfall: f32,
    /// Sign of `B r` of the configured torque model (+-1: maps dp to torque direction).
    pub(super) torque_sign: f32,
    pub(super) safety: SafetyMonitor,
    /// The fault conditions that held in the last tick (empty = all clear).
    pub(super) active: FaultSet,

    pub(super) tracking1: TrackingMonitor,
    pub(super) tracking2: TrackingMonitor,
    pub(super) residual: ResidualMonitor,
    /// The last command, and whether its openings still have to be given to the residual.
    pub(super) last_command: ValveCommand,
    pub(super) pending_command: bool,
}

/// What the cascade's outer loops computed on their last tick, held for the ticks in between
/// ([`ControllerConfig::outer_period_ticks`]).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct OuterHeld {
    /// Desired joint torque [N m].
    pub(super) torque_des_nm: f32,
    /// The torque loop's pressure set-points [Pa gauge] of the last outer run, and their
    /// change per tick since the run before [Pa]: the ticks in between extrapolate them, so
    /// the pressure loops follow a set-point that moves every tick (held, they would see it
    /// jump once per period and answer with one-tick valve pulses).
    pub(super) p1_set_gauge_pa: f32,
    pub(super) p2_set_gauge_pa: f32,
    pub(super) p1_step_pa: f32,
    pub(super) p2_step_pa: f32,
    /// Whether the set-points above are of an outer run since the last reset (else the
    /// next run's steps are 0).
    pub(super) primed: bool,
    /// The force-law torque of the last outer run [N m].
    pub(super) torque_est_nm: f32,
    /// The set-point's filtered rate [rad/s] and acceleration [rad/s^2].
    pub(super) sp_rate_rad_s: f32,
    pub(super) sp_accel_rad_s2: f32,
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
    /// Back to the state of a tick that has not armed yet: every control law, the
    /// supervision of the pressure tracking, the outer-loop schedule and the start phase.
    pub(super) fn reset_laws(&mut self) {
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

    /// Explicit re-arm after a fault. Returns false (and stays faulted) when any fault
    /// condition was still present in the last tick or the configuration is invalid.
    pub fn reset(&mut self) -> bool {
        if !self.config_ok || !self.active.is_empty() {
            return false;
        }
        self.reset_laws();
        self.safety.reset(true)
    }

    /// When the caller did not report the driver's openings of the last command, the
    /// command stands in for them in the valve / supply residual.
    #[inline(always)]
    pub(super) fn command_stands_in(&mut self) {
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
}
