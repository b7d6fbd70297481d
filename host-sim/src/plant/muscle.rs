//! One McKibben muscle: Tondu-Lopez static force with end-effect factor, pressure
//! proportional damper, cable tension, chamber volume polynomial (PLANT.md "Muscle i").

use crate::plant::tables::MuscleConfig;

/// The Tondu-Lopez static force law with the end-effect factor k (PLANT.md "Muscle i", seed
/// 002 eq. 1): F = pi r0^2 pg (a (1 - k chi)^2 - b), a = 3 / tan^2(alpha0),
/// b = 1 / sin^2(alpha0), chi the contraction. The one implementation: the plant's muscles
/// and the identification's Tondu baseline both evaluate it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TonduLaw {
    /// pi * r0^2.
    pub area_m2: f64,
    /// a = 3 / tan^2(alpha0).
    pub a: f64,
    /// b = 1 / sin^2(alpha0).
    pub b: f64,
    /// k.
    pub end_factor: f64,
}

impl TonduLaw {
    /// The law of a braid of radius `radius_m` (r0) and angle `braid_angle_rad` (alpha0).
    pub fn new(radius_m: f64, braid_angle_rad: f64, end_factor: f64) -> Self {
        let tan = braid_angle_rad.tan();
        let sin = braid_angle_rad.sin();
        Self {
            area_m2: std::f64::consts::PI * radius_m * radius_m,
            a: 3.0 / (tan * tan),
            b: 1.0 / (sin * sin),
            end_factor,
        }
    }

    /// The contraction where the braid gives no force, `(1 - sqrt(b / a)) / k`.
    pub fn max_contraction(&self) -> f64 {
        (1.0 - (self.b / self.a).sqrt()) / self.end_factor
    }

    /// The force before the clamp at 0 (negative where the muscle would have to push).
    #[inline(always)]
    pub fn force_unclamped_n(&self, p_gauge_pa: f64, contraction: f64) -> f64 {
        let e = 1.0 - self.end_factor * contraction;
        self.area_m2 * p_gauge_pa * (self.a * e * e - self.b)
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Muscle {
    /// The static force law.
    pub law: TonduLaw,
    /// gamma [m^2 s].
    pub damping_m2s: f64,
    /// l_n.
    pub rest_length_m: f64,
    /// b0..b3 of V(chi) [m^3].
    pub volume_poly_m3: [f64; 4],
}

impl Muscle {
    pub fn from_config(c: &MuscleConfig) -> Self {
        Self {
            law: TonduLaw::new(c.radius_m, c.braid_angle_deg.to_radians(), c.end_factor),
            damping_m2s: c.damping_m2s,
            rest_length_m: c.rest_length_m,
            volume_poly_m3: c.volume_poly_m3,
        }
    }

    /// Static (spring) force Fs = max(0, pi r0^2 pg (a (1 - k chi)^2 - b)).
    #[inline(always)]
    pub fn static_force_n(&self, p_gauge_pa: f64, contraction: f64) -> f64 {
        self.law.force_unclamped_n(p_gauge_pa, contraction).max(0.0)
    }

    /// Cable tension F = max(0, Fs - gamma pg dchi/dt): the chain cannot push.
    #[inline(always)]
    pub fn tension_n(&self, p_gauge_pa: f64, contraction: f64, contraction_rate_per_s: f64) -> f64 {
        (self.static_force_n(p_gauge_pa, contraction)
            - self.damping_m2s * p_gauge_pa * contraction_rate_per_s)
            .max(0.0)
    }

    /// Cable tension with an extra friction force `friction_n` opposing the contraction
    /// (braid friction, [`crate::plant::effects::MuscleHysteresis`]):
    /// F = max(0, Fs - gamma pg dchi/dt - F_h).
    #[inline(always)]
    pub fn tension_with_friction_n(
        &self,
        p_gauge_pa: f64,
        contraction: f64,
        contraction_rate_per_s: f64,
        friction_n: f64,
    ) -> f64 {
        (self.static_force_n(p_gauge_pa, contraction)
            - self.damping_m2s * p_gauge_pa * contraction_rate_per_s
            - friction_n)
            .max(0.0)
    }

    /// Chamber volume V(chi).
    #[inline(always)]
    pub fn volume_m3(&self, contraction: f64) -> f64 {
        let [b0, b1, b2, b3] = self.volume_poly_m3;
        b0 + contraction * (b1 + contraction * (b2 + contraction * b3))
    }

    /// dV/dt = V'(chi) dchi/dt.
    #[inline(always)]
    pub fn volume_rate_m3_s(&self, contraction: f64, contraction_rate_per_s: f64) -> f64 {
        let [_, b1, b2, b3] = self.volume_poly_m3;
        (b1 + contraction * (2.0 * b2 + 3.0 * b3 * contraction)) * contraction_rate_per_s
    }
}
