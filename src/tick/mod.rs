//! The control tick (API contract: `docs/tick-contract.md`): sensor validation, the control
//! cascade of [`crate::control`], and the safety state machine of [`crate::safety`], in
//! one pure `step` per tick. Consumed by the QEMU binary, the board binary and host-sim.
//!
//! Order within one tick:
//! 1. `dt` check (watchdog: NaN, <= 0 or longer than `dt_max_s`).
//! 2. Every channel is aged and validated
//!    ([`ChannelValidator`](crate::sensors::ChannelValidator)); the velocity estimate is
//!    updated from a new accepted angle sample.
//! 3. Fault conditions (channel faults, over-pressure, invalid set-point, invalid
//!    configuration) latch a [`FaultCode`]; the safe valve state is output in this tick.
//! 4. While a channel has not delivered its first sample (start-up), the valves stay closed
//!    and the tick is not armed (no fault unless the channel goes stale).
//! 5. Otherwise: position PID -> torque loop -> pressure loops -> valve command. A control
//!    law that reports an error latches [`FaultCode::ControllerNumeric`] (ODrive style).
//!
//! The configuration is in [`config`], the tick's inputs and output in [`io`], its state
//! (and how it is built and reset) in `state.rs`, the fault conditions and the safe output in
//! `faults.rs`, the steps of one tick in `steps.rs`; this file is the state machine of one
//! tick.

pub mod config;
mod faults;
pub mod io;
mod state;
#[macro_use]
mod steps;

use crate::control::{torque_from, JointState, TorqueMeasurement};
use crate::feedforward::feedforward_torque_nm;
use crate::force_law::ForceFlags;
use crate::safety::FaultSet;
use crate::sensors::ChannelStatus;
use crate::tick::faults::conditions;
use crate::tick::state::OuterHeld;

/// The fault codes live with the safety state machine; re-exported for the tick's users.
pub use crate::safety::FaultCode;
pub use crate::tick::config::{
    ControlLaw, ControllerConfig, StartRamp, OUTER_PERIOD_TICKS_MAX, TICK_HZ_MAX, TICK_HZ_MIN,
};
pub use crate::tick::io::{SensorFrame, Setpoint, TickOutput};
pub use crate::tick::state::ControlTick;
/// The valve command type lives with the valve drivers; re-exported for the tick's users.
pub use crate::valves::ValveCommand;

impl ControlTick {
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

    /// One tick in named steps (the macros of `steps.rs`, expanded in place: the tick's code
    /// is what it was as one function): sample and validate the inputs, latch this tick's
    /// fault conditions, estimate the torque, then the safe state (faulted), closed valves
    /// (start-up) or the control laws and the tracking supervision (armed).
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
        sample_inputs!(self, frame, dt_s, dt_ok, s1, s2, sa, vel, residual);
        latch_conditions!(self, setpoint, p_over_gauge_pa, dt_ok, s1, s2, sa, residual);
        idle_output!(self, vel, outer, estimate, torque_est, out);
        return_if_faulted!(self, estimate, out);

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
        let result = control_laws!(
            self,
            p1,
            p2,
            angle,
            vel,
            sp,
            outer,
            estimate,
            torque_est,
            torque_ff_nm,
            dt_s
        );
        armed_output!(self, result, p1, p2, sp, angle, out)
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

#[cfg(all(test, feature = "pressure-ff"))]
mod pressure_ff_tests;
#[cfg(test)]
mod tests;
