//! Trajectory feed-forward of the cascade: the torque the desired motion needs, added to the
//! position loop's output before the torque loop inverts the torque model (seed 003 eq. 11).
//!
//! ```text
//! r', r''  = low-pass backward differences of the angle set-point r (cutoff fc)
//! T_ff     = kd w r' + J r''
//! T_des    = clamp(T_pid + T_ff, +-out_limit)
//! ```
//!
//! - `kd w r'` turns the position loop's derivative on the measurement (`-kd alpha'`) into a
//!   derivative on the error for `w = 1`: without it, tracking a moving set-point costs a lag
//!   of `kd r' / kp` (0.06 rad on the 0.5 Hz sine with the old gains).
//! - `J r''` is the inertia torque of the desired motion (J of the joint, a model constant).
//!   The passive stiffness and damping of the desired motion need no term here: the torque
//!   loop's inverse model already supplies `A r^2 alpha + D alpha'` for the measured state.
//!
//! The set-point derivatives use only the set-point sequence (the same information the
//! model-free PID of [`crate::pid`] differentiates). Non-finite input or results: error and
//! reset, no allocation, no panic, libm only.

use crate::control::ControlError;

/// Parameters of the trajectory feed-forward.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FeedforwardGains {
    /// Weight `w` of the set-point rate in the position loop's derivative term, in [0, 1]
    /// (multiplies the position loop's `kd`).
    pub rate_weight: f32,
    /// Joint inertia for the acceleration term [kg m^2] (0: no acceleration term).
    pub inertia_kgm2: f32,
    /// Cutoff of the set-point differentiators [Hz] (0: no feed-forward at all).
    pub cutoff_hz: f32,
    /// |T_ff| limit [N m].
    pub limit_nm: f32,
}

impl FeedforwardGains {
    /// No feed-forward (the cascade as before this module).
    pub const OFF: FeedforwardGains = FeedforwardGains {
        rate_weight: 0.0,
        inertia_kgm2: 0.0,
        cutoff_hz: 0.0,
        limit_nm: 0.0,
    };

    /// True when every field is finite and non-negative and `rate_weight <= 1`.
    pub fn is_valid(&self) -> bool {
        let nonneg = |x: f32| x.is_finite() && x >= 0.0;
        nonneg(self.rate_weight)
            && self.rate_weight <= 1.0
            && nonneg(self.inertia_kgm2)
            && nonneg(self.cutoff_hz)
            && nonneg(self.limit_nm)
    }
}

/// Filtered first and second derivative of the set-point.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SetpointDerivatives {
    /// Previous set-point [rad]; NaN before the first sample.
    prev_rad: f32,
    /// Filtered rate [rad/s].
    rate_rad_s: f32,
    /// Filtered rate before the last update [rad/s]; NaN before the first rate.
    prev_rate_rad_s: f32,
    /// Filtered acceleration [rad/s^2].
    accel_rad_s2: f32,
}

impl Default for SetpointDerivatives {
    fn default() -> Self {
        Self::new()
    }
}

impl SetpointDerivatives {
    /// No history: the first updates give zero rate and acceleration.
    pub const fn new() -> Self {
        SetpointDerivatives {
            prev_rad: f32::NAN,
            rate_rad_s: 0.0,
            prev_rate_rad_s: f32::NAN,
            accel_rad_s2: 0.0,
        }
    }

    /// Forgets the history.
    pub fn reset(&mut self) {
        *self = Self::new();
    }

    /// Filtered set-point rate [rad/s].
    pub fn rate_rad_s(&self) -> f32 {
        self.rate_rad_s
    }

    /// Filtered set-point acceleration [rad/s^2].
    pub fn accel_rad_s2(&self) -> f32 {
        self.accel_rad_s2
    }

    /// One sample: updates and returns (rate [rad/s], acceleration [rad/s^2]). `cutoff_hz`
    /// <= 0 gives (0, 0).
    pub fn update(
        &mut self,
        setpoint_rad: f32,
        dt_s: f32,
        cutoff_hz: f32,
    ) -> Result<(f32, f32), ControlError> {
        if !(setpoint_rad.is_finite() && dt_s.is_finite() && dt_s > 0.0 && cutoff_hz.is_finite()) {
            self.reset();
            return Err(ControlError::NonFiniteInput);
        }
        self.update_finite(setpoint_rad, dt_s, cutoff_hz, Self::tau_s(cutoff_hz))
    }

    /// The filter time constant `update` uses for `cutoff_hz` [s].
    #[inline]
    pub(crate) fn tau_s(cutoff_hz: f32) -> f32 {
        1.0 / (2.0 * core::f32::consts::PI * cutoff_hz)
    }

    /// [`Self::update`] for a caller that has checked its inputs (finite set-point and
    /// `dt_s > 0`, finite `cutoff_hz`) and passes `tau_s = Self::tau_s(cutoff_hz)`
    /// (a configuration constant): the same result, bit for bit.
    #[inline(always)]
    pub(crate) fn update_finite(
        &mut self,
        setpoint_rad: f32,
        dt_s: f32,
        cutoff_hz: f32,
        tau_s: f32,
    ) -> Result<(f32, f32), ControlError> {
        if cutoff_hz <= 0.0 {
            self.reset();
            return Ok((0.0, 0.0));
        }
        let a = dt_s / (dt_s + tau_s);
        if self.prev_rad.is_finite() {
            let raw = (setpoint_rad - self.prev_rad) / dt_s;
            self.rate_rad_s += a * (raw - self.rate_rad_s);
            if self.prev_rate_rad_s.is_finite() {
                let raw_acc = (self.rate_rad_s - self.prev_rate_rad_s) / dt_s;
                self.accel_rad_s2 += a * (raw_acc - self.accel_rad_s2);
            }
            self.prev_rate_rad_s = self.rate_rad_s;
        }
        self.prev_rad = setpoint_rad;
        if !crate::control::finite(&[self.rate_rad_s, self.accel_rad_s2]) {
            self.reset();
            return Err(ControlError::NonFiniteOutput);
        }
        Ok((self.rate_rad_s, self.accel_rad_s2))
    }
}

/// `T_ff = kd w r' + J r''`, clamped to `+-limit_nm` [N m]; `kd` is the position loop's
/// derivative gain [N m s/rad].
pub fn feedforward_torque_nm(g: &FeedforwardGains, kd: f32, rate_rad_s: f32, accel: f32) -> f32 {
    let t = kd * g.rate_weight * rate_rad_s + g.inertia_kgm2 * accel;
    let lim = libm::fabsf(g.limit_nm);
    // In range (the usual case): one comparison; NaN fails it and takes the chain below.
    if libm::fabsf(t) <= lim {
        t
    } else if t > lim {
        lim
    } else if t < -lim {
        -lim
    } else if !t.is_nan() {
        t
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ramp_gives_its_rate_and_zero_acceleration() {
        let mut d = SetpointDerivatives::new();
        let mut last = (0.0, 0.0);
        for k in 0..3000 {
            last = d.update(0.5 * k as f32 * 1e-3, 1e-3, 20.0).unwrap();
        }
        assert!((last.0 - 0.5).abs() < 1e-3, "{last:?}");
        assert!(last.1.abs() < 1e-2, "{last:?}");
    }

    #[test]
    fn sine_derivatives_match_analytic_with_small_lag() {
        // r = 0.25 sin(pi t): r' = 0.25 pi cos, r'' = -0.25 pi^2 sin; 20 Hz filters lag by
        // ~8 ms each at 0.5 Hz (a phase of ~1.4 degrees per filter): the rate within 4 %, the acceleration (two
        // filters) within 8 % of its amplitude.
        let mut d = SetpointDerivatives::new();
        let w = core::f32::consts::PI;
        let mut worst_rate: f32 = 0.0;
        let mut worst_acc: f32 = 0.0;
        for k in 0..4000 {
            let t = k as f32 * 1e-3;
            let (r1, r2) = d.update(0.25 * libm::sinf(w * t), 1e-3, 20.0).unwrap();
            if t > 1.0 {
                worst_rate = worst_rate.max((r1 - 0.25 * w * libm::cosf(w * t)).abs());
                worst_acc = worst_acc.max((r2 + 0.25 * w * w * libm::sinf(w * t)).abs());
            }
        }
        assert!(worst_rate < 0.03, "{worst_rate}");
        assert!(worst_acc < 0.2, "{worst_acc}");
    }

    #[test]
    fn zero_cutoff_or_first_sample_gives_nothing() {
        let mut d = SetpointDerivatives::new();
        assert_eq!(d.update(0.3, 1e-3, 20.0), Ok((0.0, 0.0)));
        assert_eq!(d.update(0.5, 1e-3, 0.0), Ok((0.0, 0.0)));
    }

    #[test]
    fn bad_input_errors_and_resets() {
        let mut d = SetpointDerivatives::new();
        for k in 0..100 {
            d.update(k as f32 * 1e-3, 1e-3, 20.0).unwrap();
        }
        assert!(d.rate_rad_s() > 0.0);
        assert!(d.update(f32::NAN, 1e-3, 20.0).is_err());
        assert_eq!(d.rate_rad_s(), 0.0);
        assert!(d.update(0.0, 0.0, 20.0).is_err());
        assert!(d.update(0.0, f32::INFINITY, 20.0).is_err());
        assert!(d.update(0.0, 1e-3, f32::NAN).is_err());
        // Huge but finite jumps overflow to infinity: error, never a NaN output.
        let mut d = SetpointDerivatives::new();
        d.update(-3e38, 1e-30, 20.0).unwrap();
        assert!(d.update(3e38, 1e-30, 20.0).is_err());
        assert_eq!(d.accel_rad_s2(), 0.0);
    }

    #[test]
    fn torque_is_rate_and_inertia_terms_clamped() {
        let g = FeedforwardGains {
            rate_weight: 1.0,
            inertia_kgm2: 0.014,
            cutoff_hz: 20.0,
            limit_nm: 3.0,
        };
        assert!((feedforward_torque_nm(&g, 0.8, 1.0, 10.0) - (0.8 + 0.14)).abs() < 1e-6);
        assert_eq!(feedforward_torque_nm(&g, 0.8, 100.0, 0.0), 3.0);
        assert_eq!(feedforward_torque_nm(&g, 0.8, -100.0, 0.0), -3.0);
        assert_eq!(feedforward_torque_nm(&g, 0.8, f32::NAN, 0.0), 0.0);
        assert_eq!(
            feedforward_torque_nm(&FeedforwardGains::OFF, 0.8, 1.0, 1.0),
            0.0
        );
        assert!(g.is_valid() && FeedforwardGains::OFF.is_valid());
        assert!(!FeedforwardGains {
            rate_weight: 2.0,
            ..g
        }
        .is_valid());
    }
}
