//! Angle set-point profiles the firmware plays by itself (the board's compiled-in scenario):
//! the same shapes as host-sim's scenario `[setpoint]` table (`step` with an optional
//! minimum-jerk transition, `ramp`, `sine`) plus a constant `hold`, evaluated in f32.
//!
//! `build.rs` turns the `[setpoint]` of the scenario named by the build-time variable
//! `PAM_BOARD_SCENARIO` into a [`SetpointProfile`] constant for the board binary; without it
//! the board holds 0 rad. Time is f32 seconds since the control start: its resolution is
//! 1 ms at 4.6 hours, which bounds how long a sine is played accurately.

/// An angle set-point as a function of time.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SetpointProfile {
    /// A constant angle [rad].
    Hold {
        /// The angle [rad].
        angle_rad: f32,
    },
    /// `initial_rad` until `at_s`, then `final_rad`; with `transition_s > 0` a minimum-jerk
    /// move (`10 u^3 - 15 u^4 + 6 u^5`) over `transition_s` from `at_s`.
    Step {
        /// Before the step [rad].
        initial_rad: f32,
        /// After the step [rad].
        final_rad: f32,
        /// Step time [s].
        at_s: f32,
        /// Duration of the move [s] (0: a jump).
        transition_s: f32,
    },
    /// Linear from `from_rad` at `start_s` to `to_rad` at `end_s`, constant outside.
    Ramp {
        /// Start value [rad].
        from_rad: f32,
        /// End value [rad].
        to_rad: f32,
        /// Ramp start [s].
        start_s: f32,
        /// Ramp end [s].
        end_s: f32,
    },
    /// `offset + amplitude sin(2 pi f (t - start))` from `start_s`, `offset` before.
    Sine {
        /// Offset [rad].
        offset_rad: f32,
        /// Amplitude [rad].
        amplitude_rad: f32,
        /// Frequency [Hz].
        freq_hz: f32,
        /// Start [s].
        start_s: f32,
    },
}

impl SetpointProfile {
    /// The set-point [rad] at `t_s` seconds since the control start. A NaN `t_s` gives a
    /// NaN set-point, which the control tick refuses (`SetpointInvalid`): no panic.
    pub fn at(&self, t_s: f32) -> f32 {
        match *self {
            SetpointProfile::Hold { angle_rad } => angle_rad,
            SetpointProfile::Step {
                initial_rad,
                final_rad,
                at_s,
                transition_s,
            } => step_at(t_s, initial_rad, final_rad, at_s, transition_s),
            SetpointProfile::Ramp {
                from_rad,
                to_rad,
                start_s,
                end_s,
            } => ramp_at(t_s, from_rad, to_rad, start_s, end_s),
            SetpointProfile::Sine {
                offset_rad,
                amplitude_rad,
                freq_hz,
                start_s,
            } => sine_at(t_s, offset_rad, amplitude_rad, freq_hz, start_s),
        }
    }
}

/// The float types the shapes are evaluated in: f32 on the MCU, f64 in host-sim (its
/// scenarios use the same shapes, so a simulated run and a board playing the profile agree).
pub trait ProfileFloat:
    Copy
    + PartialOrd
    + core::ops::Add<Output = Self>
    + core::ops::Sub<Output = Self>
    + core::ops::Mul<Output = Self>
    + core::ops::Div<Output = Self>
{
    /// 0.
    const ZERO: Self;
    /// 1.
    const ONE: Self;
    /// 2 pi.
    const TWO_PI: Self;
    /// The minimum-jerk coefficients 10, -15, 6.
    const MIN_JERK: [Self; 3];
    /// Largest integer not above `self` (libm).
    fn floor(self) -> Self;
    /// Sine (libm).
    fn sin(self) -> Self;
    /// Not a number.
    fn is_nan(self) -> bool;
}

/// The impl for one float type: its libm floor and sine, its pi.
macro_rules! profile_float {
    ($t:ident, $floor:path, $sin:path, $pi:expr) => {
        impl ProfileFloat for $t {
            const ZERO: Self = 0.0;
            const ONE: Self = 1.0;
            const TWO_PI: Self = 2.0 * $pi;
            const MIN_JERK: [Self; 3] = [10.0, -15.0, 6.0];
            fn floor(self) -> Self {
                $floor(self)
            }
            fn sin(self) -> Self {
                $sin(self)
            }
            fn is_nan(self) -> bool {
                $t::is_nan(self)
            }
        }
    };
}

profile_float!(f32, libm::floorf, libm::sinf, core::f32::consts::PI);
profile_float!(f64, libm::floor, libm::sin, core::f64::consts::PI);

/// `initial` until `at_s`, then `final`; with `transition_s > 0` a minimum-jerk move over
/// `transition_s` from `at_s`.
pub fn step_at<T: ProfileFloat>(t_s: T, initial: T, final_: T, at_s: T, transition_s: T) -> T {
    if t_s < at_s {
        initial
    } else {
        initial + (final_ - initial) * min_jerk(t_s - at_s, transition_s)
    }
}

/// Linear from `from` at `start_s` to `to` at `end_s`, constant outside.
pub fn ramp_at<T: ProfileFloat>(t_s: T, from: T, to: T, start_s: T, end_s: T) -> T {
    if t_s <= start_s {
        from
    } else if t_s >= end_s {
        to
    } else {
        from + (to - from) * (t_s - start_s) / (end_s - start_s)
    }
}

/// `offset + amplitude sin(2 pi f (t - start))` from `start_s`, `offset` before. The phase in
/// turns is wrapped to [0, 1) before the sine (keeps the argument small for libm).
pub fn sine_at<T: ProfileFloat>(t_s: T, offset: T, amplitude: T, freq_hz: T, start_s: T) -> T {
    if t_s < start_s {
        offset
    } else {
        let turns = freq_hz * (t_s - start_s);
        let frac = turns - turns.floor();
        offset + amplitude * (T::TWO_PI * frac).sin()
    }
}

/// The minimum-jerk blend `10 u^3 - 15 u^4 + 6 u^5` of `u = t / duration` clamped to 0..1
/// (1, a jump, for a zero, negative or NaN duration).
pub fn min_jerk<T: ProfileFloat>(t_s: T, duration_s: T) -> T {
    if duration_s.is_nan() || duration_s <= T::ZERO || t_s >= duration_s {
        return T::ONE;
    }
    let u = if t_s > T::ZERO {
        t_s / duration_s
    } else {
        T::ZERO
    };
    let [c3, c4, c5] = T::MIN_JERK;
    u * u * u * (c3 + u * (c4 + c5 * u))
}

#[cfg(test)]
mod tests {
    use super::*;

    // References in f64 with std's sin and the closed forms (a separate code path).
    fn close(a: f32, b: f64, tol: f64) -> bool {
        (a as f64 - b).abs() <= tol
    }

    /// The values `p` must hit to the bit: `(t_s, angle_rad)` pairs.
    fn assert_exact(p: &SetpointProfile, cases: &[(f32, f32)]) {
        for &(t_s, want) in cases {
            assert_eq!(p.at(t_s), want, "{p:?} at {t_s} s");
        }
    }

    #[test]
    fn step_with_and_without_transition() {
        let jump = SetpointProfile::Step {
            initial_rad: 0.0,
            final_rad: 0.2,
            at_s: 1.0,
            transition_s: 0.0,
        };
        assert_exact(&jump, &[(0.0, 0.0), (0.999, 0.0), (1.0, 0.2), (100.0, 0.2)]);
        let smooth = SetpointProfile::Step {
            initial_rad: -0.1,
            final_rad: 0.3,
            at_s: 1.0,
            transition_s: 0.5,
        };
        assert_exact(&smooth, &[(1.0, -0.1), (1.5, 0.3)]);
        assert!(close(smooth.at(1.25), 0.1, 1e-6)); // symmetric: half-way at mid-time
        for k in 0..=50 {
            let t = 1.0 + 0.01 * k as f64;
            let u = (t - 1.0) / 0.5;
            let want = -0.1 + 0.4 * (10.0 * u.powi(3) - 15.0 * u.powi(4) + 6.0 * u.powi(5));
            assert!(close(smooth.at(t as f32), want, 1e-5), "t={t}");
        }
    }

    #[test]
    fn ramp_and_hold() {
        let r = SetpointProfile::Ramp {
            from_rad: 0.0,
            to_rad: 0.5,
            start_s: 1.0,
            end_s: 3.0,
        };
        assert_exact(&r, &[(0.5, 0.0), (3.5, 0.5)]);
        assert!(close(r.at(2.0), 0.25, 1e-6));
        let h = SetpointProfile::Hold { angle_rad: 0.1 };
        assert_exact(&h, &[(0.0, 0.1), (1e6, 0.1)]);
    }

    #[test]
    fn sine_matches_f64_over_a_long_run() {
        let (off, amp, f, t0) = (0.05f64, 0.25f64, 0.5f64, 0.5f64);
        let s = SetpointProfile::Sine {
            offset_rad: off as f32,
            amplitude_rad: amp as f32,
            freq_hz: f as f32,
            start_s: t0 as f32,
        };
        assert_eq!(s.at(0.2), 0.05);
        // 1 kHz ticks up to one hour: within 1e-4 rad of the f64 reference at the f32 time.
        let mut worst = 0.0f64;
        for k in (0..3_600_000u32).step_by(997) {
            let t32 = k as f32 / 1000.0;
            let t = t32 as f64;
            let want = if t < t0 {
                off
            } else {
                off + amp * (2.0 * std::f64::consts::PI * f * (t - t0)).sin()
            };
            worst = worst.max((s.at(t32) as f64 - want).abs());
        }
        assert!(worst < 1e-4, "worst {worst}");
    }

    #[test]
    fn nan_time_gives_a_nan_setpoint_not_a_panic() {
        let s = SetpointProfile::Sine {
            offset_rad: 0.0,
            amplitude_rad: 0.1,
            freq_hz: 1.0,
            start_s: 0.0,
        };
        assert!(s.at(f32::NAN).is_nan());
        let st = SetpointProfile::Step {
            initial_rad: 0.0,
            final_rad: 1.0,
            at_s: 0.0,
            transition_s: 1.0,
        };
        let _ = st.at(f32::NAN);
    }
}
