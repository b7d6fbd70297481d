//! The steps of one control tick ([`crate::tick::ControlTick::step`]), as macros expanded in
//! place in its body: split into functions (even `#[inline(always)]`), LLVM simplifies each
//! step on its own before inlining it, and the tick's machine code changes (measured: every
//! step moved instructions in the Cortex-M4 image). Expanded in place, the tick compiles to
//! the same instructions as one function. Each macro names the variables it declares or reads
//! (`$t` is the `ControlTick`).

/// Step 1 of a tick: the `dt` check, every channel aged and validated, the velocity
/// estimate updated from a new accepted angle sample, the valve / supply supervision on this
/// tick's fresh samples. Declares `dt_ok`, the channels' status `s1`, `s2`, `sa`, the velocity
/// `vel` and the residual's faults `residual`.
macro_rules! sample_inputs {
    ($t:ident, $frame:ident, $dt_s:ident, $dt_ok:ident, $s1:ident, $s2:ident, $sa:ident, $vel:ident, $residual:ident) => {
        // `dt_s.is_finite() && dt_s >= dt_min_s && dt_s <= dt_max_s` (see `dt_limit_s`).
        let $dt_ok = $dt_s >= $t.dt_floor_s && $dt_s <= $t.dt_limit_s;
        // Channels are aged by the nominal period when dt itself is bad.
        let dt_age = if $dt_ok { $dt_s } else { $t.dt_fallback_s };

        // `dt_age.is_finite() && dt_age > 0.0`, decided once (`dt_ok` implies it).
        let dt_age_good = $dt_ok || $t.dt_fallback_good;
        let $s1 = $t.p1.update_with($frame.p1_gauge_pa, dt_age, dt_age_good);
        let $s2 = $t.p2.update_with($frame.p2_gauge_pa, dt_age, dt_age_good);
        let $sa = $t.angle.update_with($frame.angle_rad, dt_age, dt_age_good);
        let new_angle = match $sa {
            ChannelStatus::Valid {
                value,
                age_ticks: 0,
            } => Some(value),
            _ => None,
        };
        let $vel = $t.velocity.update_with(new_angle, dt_age, dt_age_good);
        // Valve / supply supervision on this tick's fresh samples.
        let $residual = match ($s1, $s2, new_angle) {
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
            ) if $dt_ok => $t.residual.observe(true, p1, p2, a, $dt_s),
            _ => $t.residual.observe(false, 0.0, 0.0, 0.0, $dt_s),
        };
    };
}

/// Step 2: this tick's fault conditions become the active set; each one is raised (the first
/// one found is the reported cause) and an over-pressured muscle is vented.
macro_rules! latch_conditions {
    ($t:ident, $setpoint:ident, $p_over_gauge_pa:ident, $dt_ok:ident, $s1:ident, $s2:ident, $sa:ident, $residual:ident) => {
        // Fault conditions of this tick (the first one found is reported). Fast path: one
        // branch-free test of all of them; the ordered search runs only when one holds.
        let over1 = matches!($s1.value(), Some(p) if p > $p_over_gauge_pa);
        let over2 = matches!($s2.value(), Some(p) if p > $p_over_gauge_pa);
        let sp_ok = $setpoint.angle_rad.is_finite();
        let any = !$t.config_ok
            | !$dt_ok
            | matches!($s1, ChannelStatus::Fault(_))
            | matches!($s2, ChannelStatus::Fault(_))
            | matches!($sa, ChannelStatus::Fault(_))
            | over1
            | over2
            | !sp_ok;
        $t.active = $residual;
        if !$residual.is_empty() {
            $t.residual_fault($residual);
        }
        if any {
            let (set, first) = conditions($t.config_ok, $dt_ok, $s1, $s2, $sa, over1, over2, sp_ok);
            $t.active = set.union($residual);
            if let Some(c) = first {
                $t.safety.raise(c);
            }
            $t.safety.raise_all(set);
            // Escalation: a muscle above the over-pressure limit is vented (this tick: the
            // over-pressure fault itself puts the valves in the safe state).
            if over1 {
                $t.safety.escalate_vent(0);
            }
            if over2 {
                $t.safety.escalate_vent(1);
            }
        }
    };
}

/// Step 3: whether the outer loops run this tick (`outer`), the force-law torque estimate
/// (`estimate`, `torque_est`: on those ticks and on faulted ones) and the output of a tick that
/// does not arm (`out`).
macro_rules! idle_output {
    ($t:ident, $vel:ident, $outer:ident, $estimate:ident, $torque_est:ident, $out:ident) => {
        let angle_est = $t.angle.last().unwrap_or(0.0);
        // The force-law torque estimate, computed once per tick on the ticks the outer loops
        // run (every tick that does not arm is one: `reset_laws`): it is both the logged
        // `torque_est_nm` and, when all channels are fresh this tick (then `last_*` are this
        // tick's values), the torque loop's feedback. In between, the last one is held.
        // A faulted tick computes it too (its output and the numeric fault's persistence).
        let $outer = $t.outer_countdown == 0;
        let fresh = $outer || $t.safety.fault().is_some();
        let $estimate = if fresh { $t.estimate() } else { None };
        let $torque_est = if fresh {
            usable_torque($estimate).unwrap_or(0.0)
        } else {
            $t.outer_held.torque_est_nm
        };
        // `vel` is finite: the estimator stores only finite velocities (starts at 0).

        // The output of a tick that does not arm; the armed path builds its own (no field
        // written twice on the hot path).
        let $out = TickOutput {
            valves: ValveCommand::default(),
            p1_set_gauge_pa: 0.0,
            p2_set_gauge_pa: 0.0,
            torque_des_nm: 0.0,
            torque_est_nm: $torque_est,
            angle_est_rad: angle_est,
            velocity_est_rad_s: $vel,
            fault: None,
            active: FaultSet::EMPTY,
            armed: false,
        };
    };
}

/// Step 4: with a latched fault, returns the safe state; a numeric fault persists while the
/// force-law estimate of the current measurements is unusable.
macro_rules! return_if_faulted {
    ($t:ident, $estimate:ident, $out:ident) => {
        if $t.safety.fault().is_some() {
            // A numeric fault persists while the force-law estimate of the current
            // measurements is unusable.
            if $t.safety.seen().contains(FaultCode::ControllerNumeric)
                && usable_torque($estimate).is_none()
            {
                $t.active.insert(FaultCode::ControllerNumeric);
            }
            return $t.safe_output($out);
        }
    };
}

/// Step 5, armed: the configured control law from the set-point `sp` and this tick's
/// measurements to the pressure set-points and valve commands (an expression: the laws'
/// `Result`). The outer loops of the cascade run on one tick in `outer_period_ticks`.
macro_rules! control_laws {
    ($t:ident, $p1:ident, $p2:ident, $angle:ident, $vel:ident, $sp:ident, $outer:ident, $estimate:ident, $torque_est:ident, $torque_ff_nm:ident, $dt_s:ident) => {
        (|| {
            if let Some(pid) = $t.dp_pid.as_mut() {
                // Model-free baseline: angle -> dp -> pressure set-points, no torque level.
                let c = pid.step(
                    JointState {
                        angle_rad: $angle,
                        velocity_rad_s: $vel,
                    },
                    $sp,
                    $dt_s,
                )?;
                let u1 = $t.pressure1.step($p1, c.p1_gauge_pa, $dt_s)?;
                let u2 = $t.pressure2.step($p2, c.p2_gauge_pa, $dt_s)?;
                return Ok::<_, crate::control::ControlError>((
                    0.0,
                    c.p1_gauge_pa,
                    c.p2_gauge_pa,
                    $torque_est,
                    u1,
                    u2,
                ));
            }
            let meas = TorqueMeasurement {
                p1_gauge_pa: $p1,
                p2_gauge_pa: $p2,
                angle_rad: $angle,
                velocity_rad_s: $vel,
            };
            // The outer loops on one tick in `outer_period_ticks` (`outer`: the estimate was
            // computed), with the time since their last run; in between, their held output.
            let (t_des, ps, rate, accel) = if $outer {
                $t.outer_countdown = $t.outer_period_ticks - 1;
                // `0.0 + dt_s` is `dt_s` (dt_s > 0): every tick's bits when the period is 1.
                let dt_outer_s = $t.outer_dt_s + $dt_s;
                $t.outer_dt_s = 0.0;
                let (t_des, ps, rate, accel) =
                    $t.outer_loops(&meas, $sp, $torque_ff_nm, $estimate, dt_outer_s)?;
                if $t.outer_period_ticks > 1 {
                    let h = &$t.outer_held;
                    let (s1, s2) = if h.primed {
                        let per_tick = $t.outer_per_tick;
                        (
                            (ps.p1_gauge_pa - h.p1_set_gauge_pa) * per_tick,
                            (ps.p2_gauge_pa - h.p2_set_gauge_pa) * per_tick,
                        )
                    } else {
                        (0.0, 0.0)
                    };
                    $t.outer_held = OuterHeld {
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
                $t.between_outer_runs($dt_s)
            };
            let [p1_set, p2_set, t_est] = ps;
            let u1 = $t.pressure1.step_finite($p1, p1_set, $dt_s)?;
            let u2 = $t.pressure2.step_finite($p2, p2_set, $dt_s)?;
            // Compiled in with the `pressure-ff` feature only (the default MCU tick has none of
            // it), and run when the configuration enables it.
            #[cfg(feature = "pressure-ff")]
            let (u1, u2) = if $t.pressure_ff_on {
                $t.add_pressure_ff(
                    (u1, u2),
                    [p1_set, p2_set],
                    &meas,
                    JointState {
                        angle_rad: $sp,
                        velocity_rad_s: rate,
                    },
                    accel,
                )
            } else {
                (u1, u2)
            };
            #[cfg(not(feature = "pressure-ff"))]
            let _ = (rate, accel);
            $t.valve_shortfall = valve_shortfall(u1, u2, $t.torque_sign);
            Ok((t_des, p1_set, p2_set, t_est, u1, u2))
        })()
    };
}

/// Step 6, armed: the pressure-tracking supervision, then the armed output (an expression);
/// a control law error or lost tracking latches its fault and gives the safe state.
macro_rules! armed_output {
    ($t:ident, $result:ident, $p1:ident, $p2:ident, $sp:ident, $angle:ident, $out:ident) => {
        match $result {
            Ok((t_des, p1_set, p2_set, t_est, u1, u2)) => {
                let (e_pa, n) = ($t.cfg.tracking_error_pa, $t.cfg.tracking_ticks);
                let lost1 = $t.tracking1.update(p1_set, $p1, u1, e_pa, n);
                let lost2 = $t.tracking2.update(p2_set, $p2, u2, e_pa, n);
                if lost1 || lost2 {
                    let f = if lost1 {
                        FaultCode::PressureTrackingLost1
                    } else {
                        FaultCode::PressureTrackingLost2
                    };
                    warn!("pressure tracking lost: {}", f);
                    $t.safety.raise(f);
                    if lost1 {
                        $t.active.insert(FaultCode::PressureTrackingLost1);
                    }
                    if lost2 {
                        $t.active.insert(FaultCode::PressureTrackingLost2);
                        $t.safety.raise(FaultCode::PressureTrackingLost2);
                    }
                    return $t.safe_output($out);
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
                    ..$out
                };
                trace!(
                    "tick sp={} a={} T*={} p*=({}, {}) u=({}, {})",
                    $sp,
                    $angle,
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
                $t.active.insert(FaultCode::ControllerNumeric);
                $t.safety.raise(FaultCode::ControllerNumeric);
                $t.safe_output($out)
            }
        }
    };
}
