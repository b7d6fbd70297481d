//! Model-free baseline: a single-loop PD / PID from the joint angle straight to the symmetric
//! pressure activation `dp` (the "simple PD controller" of seed 004 Table 3), for the
//! closed-loop comparison with the model-based cascade of [`crate::control`].
//!
//! ```text
//! e     = r - alpha                                        (set-point r, measured angle)
//! r'    = low-pass((r_k - r_{k-1}) / dt)                   (set-point rate, cutoff fc)
//! u     = kp e + I + kd (w r' - alpha')                    (w = 0: derivative on measurement,
//!                                                           w = 1: on the error, seed 004 eq. 18)
//! I    += ki e dt                                          (conditional integration, |I| <= i_limit)
//! u     = clamp(u, +-dp_max)                               (dp_max also keeps p0 +- u in [0, 600 kPa])
//! dp    = -u;   p1 = p0 - dp = p0 + u;   p2 = p0 + dp = p0 - u
//! ```
//!
//! `u > 0` raises muscle 1 and lowers muscle 2, which drives the angle up (muscle 1 pulls
//! the angle up: `T = (F1 - F2) r`, see the crate README); `dp` keeps the sign convention of
//! the torque model (`p1 = p0 - dp`, `p2 = p0 + dp`), so the two laws feed the same pressure
//! loops, valves and safety path of the control tick ([`crate::tick`]). Nothing here knows the
//! force law or the torque model: no inverse model, no stiffness compensation.
//!
//! Like the laws of [`crate::control`]: every input may be NaN; a non-finite input or result
//! returns [`ControlError`] and resets the internal state; no allocation, no panic, libm only.

use crate::control::{ControlError, JointState};
use crate::math::within;
use crate::safety::clamp_pressure_setpoint_pa;
use crate::P_MUSCLE_MAX_GAUGE_PA;

/// Gains and limits of the angle -> `dp` PID.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DpPidGains {
    /// Proportional gain [Pa/rad].
    pub kp_pa_per_rad: f32,
    /// Integral gain [Pa/(rad s)] (0: PD).
    pub ki_pa_per_rad_s: f32,
    /// Derivative gain [Pa s/rad].
    pub kd_pa_s_per_rad: f32,
    /// Weight `w` of the set-point rate in the derivative term, in [0, 1]: 0 = derivative on
    /// the measurement only (no kick on set-point steps), 1 = derivative on the error.
    pub setpoint_rate_weight: f32,
    /// Cutoff of the set-point rate low-pass [Hz] (0: no set-point rate).
    pub setpoint_rate_cutoff_hz: f32,
    /// |integral term| limit [Pa].
    pub i_limit_pa: f32,
    /// |dp| limit [Pa]; further limited so that both set-points stay in [0, 600 kPa].
    pub dp_max_pa: f32,
    /// Mean pressure p0 of the symmetric activation [Pa gauge].
    pub p0_gauge_pa: f32,
}

impl DpPidGains {
    /// True when every gain and limit is finite and non-negative, `w` is in [0, 1] and p0 is
    /// within [0, 600 kPa].
    pub fn is_valid(&self) -> bool {
        let nonneg = |x: f32| within(x, 0.0, f32::MAX);
        nonneg(self.kp_pa_per_rad)
            && nonneg(self.ki_pa_per_rad_s)
            && nonneg(self.kd_pa_s_per_rad)
            && within(self.setpoint_rate_weight, 0.0, 1.0)
            && nonneg(self.setpoint_rate_cutoff_hz)
            && nonneg(self.i_limit_pa)
            && nonneg(self.dp_max_pa)
            && within(self.p0_gauge_pa, 0.0, P_MUSCLE_MAX_GAUGE_PA)
    }

    /// The usable |dp| [Pa]: `dp_max_pa`, and no more than keeps `p0 +- dp` in [0, 600 kPa].
    pub fn dp_limit_pa(&self) -> f32 {
        let room = libm::fminf(self.p0_gauge_pa, P_MUSCLE_MAX_GAUGE_PA - self.p0_gauge_pa);
        let lim = libm::fminf(libm::fabsf(self.dp_max_pa), room);
        // fminf ignores a NaN operand; a NaN everywhere gives NaN, rejected by `step`.
        if lim > 0.0 {
            lim
        } else {
            0.0
        }
    }
}

/// Output of one [`DpPid::step`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DpCommand {
    /// Activation dp [Pa] (`p1 = p0 - dp`, `p2 = p0 + dp`).
    pub dp_pa: f32,
    /// Muscle 1 set-point [Pa gauge], in [0, 600 kPa].
    pub p1_gauge_pa: f32,
    /// Muscle 2 set-point [Pa gauge], in [0, 600 kPa].
    pub p2_gauge_pa: f32,
    /// True when |dp| hit its limit.
    pub saturated: bool,
}

/// Angle -> `dp` PID with set-point-rate weighting and anti-windup (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DpPid {
    /// Gains.
    pub gains: DpPidGains,
    integral_pa: f32,
    /// Previous set-point [rad]; NaN before the first step (no rate yet).
    setpoint_prev_rad: f32,
    setpoint_rate_rad_s: f32,
}

impl DpPid {
    /// A PID with zero state.
    pub const fn new(gains: DpPidGains) -> Self {
        DpPid {
            gains,
            integral_pa: 0.0,
            setpoint_prev_rad: f32::NAN,
            setpoint_rate_rad_s: 0.0,
        }
    }

    /// Integrator state [Pa].
    pub fn integral_pa(&self) -> f32 {
        self.integral_pa
    }

    /// Filtered set-point rate [rad/s].
    pub fn setpoint_rate_rad_s(&self) -> f32 {
        self.setpoint_rate_rad_s
    }

    /// Clears the integrator and the set-point rate.
    pub fn reset(&mut self) {
        self.integral_pa = 0.0;
        self.setpoint_prev_rad = f32::NAN;
        self.setpoint_rate_rad_s = 0.0;
    }

    /// One step: pressure set-points for the angle set-point `setpoint_rad`.
    pub fn step(
        &mut self,
        meas: JointState,
        setpoint_rad: f32,
        dt_s: f32,
    ) -> Result<DpCommand, ControlError> {
        let g = self.gains;
        let ins = [meas.angle_rad, meas.velocity_rad_s, setpoint_rad, dt_s];
        if ins.iter().any(|x| !x.is_finite()) || dt_s <= 0.0 {
            self.reset();
            return Err(ControlError::NonFiniteInput);
        }
        if !g.is_valid() {
            self.reset();
            return Err(ControlError::NonFiniteOutput);
        }
        // Set-point rate: first-order low-pass of the backward difference.
        let fc = g.setpoint_rate_cutoff_hz;
        if fc > 0.0 && self.setpoint_prev_rad.is_finite() {
            let raw = (setpoint_rad - self.setpoint_prev_rad) / dt_s;
            let tau_s = 1.0 / (2.0 * core::f32::consts::PI * fc);
            let a = dt_s / (dt_s + tau_s);
            self.setpoint_rate_rad_s += a * (raw - self.setpoint_rate_rad_s);
        } else {
            self.setpoint_rate_rad_s = 0.0;
        }
        self.setpoint_prev_rad = setpoint_rad;

        let e = setpoint_rad - meas.angle_rad;
        let rate_err = g.setpoint_rate_weight * self.setpoint_rate_rad_s - meas.velocity_rad_s;
        let pd = g.kp_pa_per_rad * e + g.kd_pa_s_per_rad * rate_err;
        let lim = g.dp_limit_pa();
        let unsat = pd + self.integral_pa;
        let di = g.ki_pa_per_rad_s * e * dt_s;
        // Conditional integration: do not integrate further into saturation.
        if !((unsat > lim && di > 0.0) || (unsat < -lim && di < 0.0)) {
            let i = self.integral_pa + di;
            let il = libm::fabsf(g.i_limit_pa);
            self.integral_pa = if i > il {
                il
            } else if i < -il {
                -il
            } else {
                i
            };
        }
        let u = pd + self.integral_pa;
        let saturated = !(u <= lim && u >= -lim);
        let u = if u > lim {
            lim
        } else if u < -lim {
            -lim
        } else {
            u
        };
        let dp_pa = -u;
        let p1 = clamp_pressure_setpoint_pa(g.p0_gauge_pa - dp_pa, P_MUSCLE_MAX_GAUGE_PA);
        let p2 = clamp_pressure_setpoint_pa(g.p0_gauge_pa + dp_pa, P_MUSCLE_MAX_GAUGE_PA);
        let outs = [dp_pa, p1, p2, self.integral_pa, self.setpoint_rate_rad_s];
        if outs.iter().any(|x| !x.is_finite()) {
            self.reset();
            return Err(ControlError::NonFiniteOutput);
        }
        Ok(DpCommand {
            dp_pa,
            p1_gauge_pa: p1,
            p2_gauge_pa: p2,
            saturated,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gains() -> DpPidGains {
        DpPidGains {
            kp_pa_per_rad: 500_000.0,
            ki_pa_per_rad_s: 100_000.0,
            kd_pa_s_per_rad: 10_000.0,
            setpoint_rate_weight: 1.0,
            setpoint_rate_cutoff_hz: 20.0,
            i_limit_pa: 50_000.0,
            dp_max_pa: 280_000.0,
            p0_gauge_pa: 300_000.0,
        }
    }

    const AT_REST: JointState = JointState {
        angle_rad: 0.0,
        velocity_rad_s: 0.0,
    };

    fn pd() -> DpPid {
        DpPid::new(DpPidGains {
            ki_pa_per_rad_s: 0.0,
            ..gains()
        })
    }

    #[test]
    fn zero_error_gives_p0_in_both_muscles() {
        let mut c = DpPid::new(gains());
        let o = c.step(AT_REST, 0.0, 1e-3).unwrap();
        assert_eq!(o.dp_pa, 0.0);
        assert_eq!(o.p1_gauge_pa, 300_000.0);
        assert_eq!(o.p2_gauge_pa, 300_000.0);
        assert!(!o.saturated);
    }

    #[test]
    fn positive_error_inflates_muscle_one_symmetrically() {
        let mut c = pd();
        // First step: no set-point rate yet, so u = kp e exactly.
        let o = c.step(AT_REST, 0.1, 1e-3).unwrap();
        assert!((o.dp_pa + 50_000.0).abs() < 1e-2, "{}", o.dp_pa);
        assert!((o.p1_gauge_pa - 350_000.0).abs() < 1e-2);
        assert!((o.p2_gauge_pa - 250_000.0).abs() < 1e-2);
        let mut c = pd();
        let o = c.step(AT_REST, -0.1, 1e-3).unwrap();
        assert!(o.p1_gauge_pa < 300_000.0 && o.p2_gauge_pa > 300_000.0);
    }

    #[test]
    fn derivative_brakes_motion_and_follows_setpoint_rate() {
        let mut c = pd();
        let moving_up = JointState {
            angle_rad: 0.0,
            velocity_rad_s: 2.0,
        };
        let o = c.step(moving_up, 0.0, 1e-3).unwrap();
        // u = -kd * 2 = -20 kPa: muscle 1 down.
        assert!((o.dp_pa - 20_000.0).abs() < 1e-2, "{}", o.dp_pa);
        // A ramp set-point at 1 rad/s tracked exactly (angle on it, velocity 1 rad/s): the
        // filtered set-point rate converges to 1 rad/s and cancels the velocity term.
        let mut c = pd();
        let mut last = None;
        for k in 0..2000 {
            let t = k as f32 * 1e-3;
            let m = JointState {
                angle_rad: t,
                velocity_rad_s: 1.0,
            };
            last = Some(c.step(m, t, 1e-3).unwrap());
        }
        assert!((c.setpoint_rate_rad_s() - 1.0).abs() < 1e-3);
        assert!(last.unwrap().dp_pa.abs() < 20.0);
        // With w = 0 the same ramp leaves the full braking term.
        let mut c = DpPid::new(DpPidGains {
            setpoint_rate_weight: 0.0,
            ..gains()
        });
        let o = c
            .step(
                JointState {
                    angle_rad: 0.0,
                    velocity_rad_s: 1.0,
                },
                0.0,
                1e-3,
            )
            .unwrap();
        assert!((o.dp_pa - 10_000.0).abs() < 1.0);
    }

    #[test]
    fn integrator_removes_steady_error_and_is_bounded() {
        let mut c = DpPid::new(gains());
        let first = c.step(AT_REST, 0.01, 1e-3).unwrap();
        let mut last = first;
        for _ in 0..100_000 {
            last = c.step(AT_REST, 0.01, 1e-3).unwrap();
        }
        assert!(last.dp_pa < first.dp_pa - 40_000.0);
        assert!((c.integral_pa() - 50_000.0).abs() < 1e-2);
    }

    #[test]
    fn no_windup_while_saturated() {
        let mut c = DpPid::new(gains());
        for _ in 0..100_000 {
            let o = c.step(AT_REST, 10.0, 1e-3).unwrap();
            assert!(o.saturated);
            assert!(o.p1_gauge_pa <= 580_000.0 + 1e-3 && o.p2_gauge_pa >= 20_000.0 - 1e-3);
        }
        assert_eq!(c.integral_pa(), 0.0);
    }

    #[test]
    fn setpoints_stay_within_0_and_600_kpa_for_any_p0() {
        for p0 in [0.0f32, 50_000.0, 300_000.0, 590_000.0, 600_000.0] {
            let mut c = DpPid::new(DpPidGains {
                p0_gauge_pa: p0,
                dp_max_pa: 1e9,
                ..gains()
            });
            for sp in [-100.0f32, -0.3, 0.0, 0.3, 100.0] {
                let o = c.step(AT_REST, sp, 1e-3).unwrap();
                for p in [o.p1_gauge_pa, o.p2_gauge_pa] {
                    assert!(
                        (0.0..=P_MUSCLE_MAX_GAUGE_PA).contains(&p),
                        "p0 {p0} sp {sp}: {p}"
                    );
                }
                assert!((o.p1_gauge_pa + o.p2_gauge_pa - 2.0 * p0).abs() < 1.0);
            }
        }
    }

    #[test]
    fn bad_inputs_are_errors_and_reset_state() {
        crate::control::assert_refuses_bad_inputs_and_resets(
            &mut DpPid::new(gains()),
            DpPid::step,
            DpPid::integral_pa,
            0.05,
            100,
        );
    }

    #[test]
    fn invalid_gains_are_refused() {
        for g in [
            DpPidGains {
                kp_pa_per_rad: f32::NAN,
                ..gains()
            },
            DpPidGains {
                kd_pa_s_per_rad: -1.0,
                ..gains()
            },
            DpPidGains {
                setpoint_rate_weight: 1.5,
                ..gains()
            },
            DpPidGains {
                p0_gauge_pa: 700_000.0,
                ..gains()
            },
        ] {
            assert!(!g.is_valid());
            let mut c = DpPid::new(g);
            assert_eq!(
                c.step(AT_REST, 0.1, 1e-3),
                Err(ControlError::NonFiniteOutput)
            );
        }
        assert!(gains().is_valid());
    }

    #[test]
    fn huge_finite_gains_overflowing_to_infinity_fault_instead_of_emitting_nan() {
        let mut c = DpPid::new(DpPidGains {
            kp_pa_per_rad: f32::MAX,
            kd_pa_s_per_rad: f32::MAX,
            ..gains()
        });
        // kp e = +inf and kd (w r' - alpha') = -inf: u is NaN, which must be an error.
        let m = JointState {
            angle_rad: -1.0,
            velocity_rad_s: 2.0,
        };
        assert_eq!(c.step(m, 1.0, 1e-3), Err(ControlError::NonFiniteOutput));
        assert_eq!(c.integral_pa(), 0.0);
        // Same gains, only one term infinite: saturates to the finite limit.
        let m = JointState {
            angle_rad: -1.0,
            velocity_rad_s: 0.0,
        };
        let o = c.step(m, 1.0, 1e-3).unwrap();
        assert!(o.saturated && o.dp_pa == -280_000.0);
    }
}
