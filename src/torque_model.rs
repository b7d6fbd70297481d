//! Simplified torque model of an antagonistic muscle joint (seed 003, eq. 11) and its inverse:
//!
//! ```text
//! T = A r^2 alpha + B r dp + C alpha'^3 + D alpha'
//! ```
//!
//! with the paper's symmetric activation `p1 = p0 - dp`, `p2 = p0 + dp` (gauge). All
//! quantities are SI here: `alpha` [rad], `alpha'` [rad/s], `dp` [Pa], `T` [N m],
//! `A` [N/(m rad)], `B` [m^2], `C` [N m s^3/rad^3], `D` [N m s/rad]. The paper's constants
//! are in pi-rad and kg/cm^2 units; [`TorqueModelParams::from_paper_units`] is the one place
//! that converts them.
//!
//! Torque sign: positive torque drives the joint angle up (PLANT.md, `T = (F1 - F2) r`).

use crate::P_MUSCLE_MAX_GAUGE_PA;

/// 1 kg/cm^2 (kilogram-force per square centimetre) in Pa.
pub const PA_PER_KGF_CM2: f32 = 98_066.5;

/// Constants of eq. 11 plus the activation scheme, in SI units.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TorqueModelParams {
    /// A [N/(m rad)]: angle stiffness per r^2.
    pub a_n_per_m_rad: f32,
    /// B [m^2]: torque per unit activation per unit radius.
    pub b_m2: f32,
    /// C [N m s^3/rad^3]: cubic velocity term.
    pub c_nms3_per_rad3: f32,
    /// D [N m s/rad]: linear velocity term.
    pub d_nms_per_rad: f32,
    /// Sprocket radius r [m].
    pub sprocket_radius_m: f32,
    /// Mid pressure p0 of the symmetric activation, gauge [Pa].
    pub p0_gauge_pa: f32,
    /// Largest |dp| [Pa] the activation may use.
    pub dp_max_pa: f32,
}

/// Result of inverting the torque model.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Activation {
    /// Activation dp [Pa], finite and within the valid range.
    pub dp_pa: f32,
    /// True when the desired torque needed more than the valid range (dp was clamped), or
    /// an input was not finite (dp = 0).
    pub saturated: bool,
}

impl TorqueModelParams {
    /// Converts the paper's units (seed 003 section 4): A in N/(m pi-rad), B in
    /// N cm^2/kg (torque per radius per kg/cm^2), C in N m (s/pi)^3, D in N m s/pi.
    pub fn from_paper_units(
        a_n_per_m_pi: f32,
        b_n_cm2_per_kg: f32,
        c_nm_s3_per_pi3: f32,
        d_nm_s_per_pi: f32,
        sprocket_radius_m: f32,
        p0_kgf_cm2: f32,
        dp_max_kgf_cm2: f32,
    ) -> Self {
        let pi = core::f32::consts::PI;
        TorqueModelParams {
            // alpha[pi] = alpha[rad] / pi
            a_n_per_m_rad: a_n_per_m_pi / pi,
            // dp[kg/cm^2] = dp[Pa] / 98066.5
            b_m2: b_n_cm2_per_kg / PA_PER_KGF_CM2,
            // alpha'[pi/s]^3 = alpha'[rad/s]^3 / pi^3
            c_nms3_per_rad3: c_nm_s3_per_pi3 / (pi * pi * pi),
            d_nms_per_rad: d_nm_s_per_pi / pi,
            sprocket_radius_m,
            p0_gauge_pa: p0_kgf_cm2 * PA_PER_KGF_CM2,
            dp_max_pa: dp_max_kgf_cm2 * PA_PER_KGF_CM2,
        }
    }

    /// The paper's identified joint (Shadow muscles, r = 0.019 m / 2 chain wheel diameter
    /// quoted as r, p0 = 3 kg/cm^2, dp within +-2 kg/cm^2).
    pub fn paper_si() -> Self {
        Self::from_paper_units(-73_670.0, 174.2, 0.07, 0.45, 0.019, 3.0, 2.0)
    }

    /// The part of the torque that does not depend on the activation [N m].
    #[inline]
    fn passive_nm(&self, angle_rad: f32, velocity_rad_s: f32) -> f32 {
        let r = self.sprocket_radius_m;
        let v = velocity_rad_s;
        self.a_n_per_m_rad * r * r * angle_rad
            + self.c_nms3_per_rad3 * v * v * v
            + self.d_nms_per_rad * v
    }

    /// Forward model: joint torque [N m] at the angle, velocity and activation.
    #[inline]
    pub fn torque_nm(&self, angle_rad: f32, velocity_rad_s: f32, dp_pa: f32) -> f32 {
        self.passive_nm(angle_rad, velocity_rad_s) + self.b_m2 * self.sprocket_radius_m * dp_pa
    }

    /// Inverse model: the activation dp [Pa] that yields `torque_nm` at the angle and
    /// velocity, clamped to `+-dp_max_pa` and to the pressures staying within
    /// `[0, P_MUSCLE_MAX_GAUGE_PA]`. Non-finite inputs give dp = 0, saturated.
    pub fn activation(&self, torque_nm: f32, angle_rad: f32, velocity_rad_s: f32) -> Activation {
        self.inverse_at(angle_rad, velocity_rad_s)
            .activation(torque_nm)
    }

    /// The inverse model at one joint state, for several torques: the passive torque, the
    /// gain `B r` and the limit are computed once (the torque loop inverts twice per tick).
    /// `inverse_at(a, v).activation(t)` is exactly `activation(t, a, v)`.
    #[inline]
    pub fn inverse_at(&self, angle_rad: f32, velocity_rad_s: f32) -> InverseAt {
        let dp_limit_pa = self.dp_limit_pa();
        if angle_rad.is_finite() && velocity_rad_s.is_finite() {
            self.inverse_at_finite(angle_rad, velocity_rad_s, dp_limit_pa)
        } else {
            InverseAt {
                passive_nm: 0.0,
                gain_m3: self.b_m2 * self.sprocket_radius_m,
                dp_limit_pa,
                valid: false,
            }
        }
    }

    /// [`Self::inverse_at`] for a finite angle and velocity, with `dp_limit_pa` =
    /// [`Self::dp_limit_pa`] precomputed by the caller: the same result, bit for bit.
    #[inline(always)]
    pub(crate) fn inverse_at_finite(
        &self,
        angle_rad: f32,
        velocity_rad_s: f32,
        dp_limit_pa: f32,
    ) -> InverseAt {
        let gain = self.b_m2 * self.sprocket_radius_m;
        let valid = gain != 0.0;
        InverseAt {
            passive_nm: if valid {
                self.passive_nm(angle_rad, velocity_rad_s)
            } else {
                0.0
            },
            gain_m3: gain,
            dp_limit_pa,
            valid,
        }
    }

    /// The usable |dp| [Pa]: `dp_max_pa`, reduced so that both `p0 -+ dp` stay within
    /// `[0, P_MUSCLE_MAX_GAUGE_PA]`.
    #[inline]
    pub fn dp_limit_pa(&self) -> f32 {
        let p0 = self.p0_gauge_pa;
        let room = if p0 < P_MUSCLE_MAX_GAUGE_PA - p0 {
            p0
        } else {
            P_MUSCLE_MAX_GAUGE_PA - p0
        };
        let room = if room > 0.0 { room } else { 0.0 };
        if self.dp_max_pa < room {
            self.dp_max_pa
        } else {
            room
        }
    }

    /// Pressure set-points (p1, p2) gauge [Pa] of the symmetric activation
    /// `p1 = p0 - dp`, `p2 = p0 + dp`, each clamped to `[0, P_MUSCLE_MAX_GAUGE_PA]`.
    #[inline]
    pub fn pressures_gauge_pa(&self, dp_pa: f32) -> (f32, f32) {
        let clamp = |p: f32| {
            if !(p >= 0.0) {
                0.0
            } else if p > P_MUSCLE_MAX_GAUGE_PA {
                P_MUSCLE_MAX_GAUGE_PA
            } else {
                p
            }
        };
        (
            clamp(self.p0_gauge_pa - dp_pa),
            clamp(self.p0_gauge_pa + dp_pa),
        )
    }
}

/// [`TorqueModelParams::inverse_at`]: the inverse torque model at one angle and velocity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InverseAt {
    passive_nm: f32,
    gain_m3: f32,
    dp_limit_pa: f32,
    valid: bool,
}

impl InverseAt {
    /// The forward model at this joint state: the torque [N m] that the activation `dp_pa`
    /// gives (0 for an invalid inverse).
    #[inline(always)]
    pub fn torque_nm(&self, dp_pa: f32) -> f32 {
        self.passive_nm + self.gain_m3 * dp_pa
    }

    /// The activation dp [Pa] that yields `torque_nm`, clamped to the usable range;
    /// non-finite inputs give dp = 0, saturated.
    #[inline]
    pub fn activation(&self, torque_nm: f32) -> Activation {
        if !self.valid {
            return Activation {
                dp_pa: 0.0,
                saturated: true,
            };
        }
        let dp = (torque_nm - self.passive_nm) / self.gain_m3;
        // A non-finite torque always gives a non-finite dp (inf - finite, NaN, and a
        // non-finite numerator over any divisor), so this one test also rejects it.
        if !dp.is_finite() {
            return Activation {
                dp_pa: 0.0,
                saturated: true,
            };
        }
        let lim = self.dp_limit_pa;
        if dp > lim {
            Activation {
                dp_pa: lim,
                saturated: true,
            }
        } else if dp < -lim {
            Activation {
                dp_pa: -lim,
                saturated: true,
            }
        } else {
            Activation {
                dp_pa: dp,
                saturated: false,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::constants::TORQUE_MODEL;

    #[test]
    fn non_finite_torque_gives_zero_saturated_activation() {
        // `InverseAt::activation` tests only dp for finiteness; a non-finite torque must
        // still give the safe answer, at finite and at extreme passive torques.
        let m = TORQUE_MODEL;
        for (angle, v) in [(0.0f32, 0.0f32), (0.5, -2.0), (1e30, 1e30), (-1e30, 3e12)] {
            let inv = m.inverse_at(angle, v);
            for t in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -f32::NAN] {
                let a = inv.activation(t);
                assert_eq!(
                    a.dp_pa.to_bits(),
                    0.0f32.to_bits(),
                    "angle {angle} v {v} t {t}"
                );
                assert!(a.saturated);
            }
        }
    }

    #[test]
    fn inverse_at_equals_activation_bit_for_bit() {
        let m = TORQUE_MODEL;
        let vals = [
            0.0f32,
            -0.0,
            1e-3,
            -2.5,
            7.0,
            40.0,
            -1e6,
            f32::NAN,
            f32::INFINITY,
            1e-30,
        ];
        for &t in &vals {
            for &a in &vals {
                for &v in &vals {
                    let x = m.activation(t, a, v);
                    let y = m.inverse_at(a, v).activation(t);
                    assert_eq!(x.dp_pa.to_bits(), y.dp_pa.to_bits(), "t={t} a={a} v={v}");
                    assert_eq!(x.saturated, y.saturated);
                }
            }
        }
    }

    #[test]
    fn paper_constants_convert_to_si() {
        let m = TorqueModelParams::paper_si();
        let pi = core::f32::consts::PI;
        assert!((m.a_n_per_m_rad - (-73_670.0 / pi)).abs() < 0.01);
        assert!((m.b_m2 - 174.2 / 98_066.5).abs() < 1e-9);
        assert!((m.c_nms3_per_rad3 - 0.07 / (pi * pi * pi)).abs() < 1e-9);
        assert!((m.d_nms_per_rad - 0.45 / pi).abs() < 1e-7);
        assert!((m.p0_gauge_pa - 294_199.5).abs() < 0.5);
    }

    #[test]
    fn forward_model_matches_hand_computed_value() {
        // A r^2 alpha + B r dp + C a'^3 + D a' with the config constants (identified by
        // `host-sim identify torque`, README "Identification"):
        // -23351.22 * 0.025^2 * 0.2 + (-1.932721e-3) * 0.025 * 1e5 + (-6.947928e-5) * 1.5^3
        //   + (-0.2993833) * 1.5 = -2.918903 - 4.831803 - 0.000234 - 0.449075 = -8.200015
        let t = TORQUE_MODEL.torque_nm(0.2, 1.5, 100_000.0);
        assert!((t - (-8.200015)).abs() < 1e-3, "{t}");
    }

    #[test]
    fn inverse_round_trips_forward_model_inside_range() {
        for &(a, v, dp) in &[
            (0.0, 0.0, 0.0),
            (0.3, -1.0, 150_000.0),
            (-0.4, 2.0, -250_000.0),
        ] {
            let t = TORQUE_MODEL.torque_nm(a, v, dp);
            let act = TORQUE_MODEL.activation(t, a, v);
            assert!(!act.saturated);
            assert!((act.dp_pa - dp).abs() < 1.0, "{} vs {}", act.dp_pa, dp);
        }
    }

    #[test]
    fn inverse_saturates_and_pressures_respect_limits() {
        let act = TORQUE_MODEL.activation(1.0e6, 0.0, 0.0);
        assert!(act.saturated);
        assert_eq!(act.dp_pa.abs(), TORQUE_MODEL.dp_limit_pa());
        let (p1, p2) = TORQUE_MODEL.pressures_gauge_pa(act.dp_pa);
        assert!((0.0..=P_MUSCLE_MAX_GAUGE_PA).contains(&p1));
        assert!((0.0..=P_MUSCLE_MAX_GAUGE_PA).contains(&p2));
        let act = TORQUE_MODEL.activation(f32::NAN, 0.0, 0.0);
        assert_eq!(
            act,
            Activation {
                dp_pa: 0.0,
                saturated: true
            }
        );
    }

    #[test]
    fn symmetric_activation_is_p0_minus_plus_dp() {
        let (p1, p2) = TORQUE_MODEL.pressures_gauge_pa(50_000.0);
        assert_eq!(p1, TORQUE_MODEL.p0_gauge_pa - 50_000.0);
        assert_eq!(p2, TORQUE_MODEL.p0_gauge_pa + 50_000.0);
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(4096))]

        /// Any f32 bit patterns: the activation is finite and within +-dp_limit, and the
        /// pressures it leads to are within [0, 600 kPa]; non-finite inputs give dp = 0.
        #[test]
        fn activation_of_any_f32_is_finite_and_bounded([t, a, v] in crate::any_f32s()) {
            let m = &TORQUE_MODEL;
            let act = m.activation(t, a, v);
            proptest::prop_assert!(act.dp_pa.is_finite());
            proptest::prop_assert!(act.dp_pa.abs() <= m.dp_limit_pa(), "{:?}", act);
            if !t.is_finite() || !a.is_finite() || !v.is_finite() {
                proptest::prop_assert_eq!(act, Activation { dp_pa: 0.0, saturated: true });
            }
            let (p1, p2) = m.pressures_gauge_pa(act.dp_pa);
            for p in [p1, p2] {
                proptest::prop_assert!((0.0..=P_MUSCLE_MAX_GAUGE_PA).contains(&p));
            }
        }

        /// Pressures stay within [0, 600 kPa] for any dp bit pattern (NaN included).
        #[test]
        fn pressures_of_any_dp_are_in_range(dp in proptest::num::f32::ANY) {
            let (p1, p2) = TORQUE_MODEL.pressures_gauge_pa(dp);
            for p in [p1, p2] {
                proptest::prop_assert!((0.0..=P_MUSCLE_MAX_GAUGE_PA).contains(&p), "{dp} -> {p}");
            }
        }

        /// The forward model never panics on any bit pattern and is finite for finite,
        /// physically meaningful inputs.
        #[test]
        fn forward_never_panics([a, v, dp] in crate::any_f32s()) {
            let t = TORQUE_MODEL.torque_nm(a, v, dp);
            if a.abs() <= 1e3 && v.abs() <= 1e3 && dp.abs() <= 1e7 {
                proptest::prop_assert!(t.is_finite(), "{a} {v} {dp} -> {t}");
            }
        }

        /// Inside the range the inverse undoes the forward model (to well below 1 Pa).
        #[test]
        fn inverse_round_trips_forward_inside_range(
            a in -1.5f32..1.5,
            v in -10.0f32..10.0,
            frac in -0.999f32..0.999,
        ) {
            let m = &TORQUE_MODEL;
            let dp = frac * m.dp_limit_pa();
            let act = m.activation(m.torque_nm(a, v, dp), a, v);
            proptest::prop_assert!(!act.saturated);
            proptest::prop_assert!((act.dp_pa - dp).abs() < 1.0, "{} vs {}", act.dp_pa, dp);
        }
    }
}
