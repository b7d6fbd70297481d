//! One McKibben muscle: Tondu-Lopez static force with end-effect factor, pressure
//! proportional damper, cable tension, chamber volume polynomial (PLANT.md "Muscle i").

use crate::plant::config::MuscleConfig;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Muscle {
    /// pi * r0^2.
    pub area_m2: f64,
    /// a = 3 / tan^2(alpha0).
    pub tondu_a: f64,
    /// b = 1 / sin^2(alpha0).
    pub tondu_b: f64,
    /// k.
    pub end_factor: f64,
    /// gamma [m^2 s].
    pub damping_m2s: f64,
    /// l_n.
    pub rest_length_m: f64,
    /// b0..b3 of V(chi) [m^3].
    pub volume_poly_m3: [f64; 4],
}

impl Muscle {
    pub fn from_config(c: &MuscleConfig) -> Self {
        let alpha0 = c.braid_angle_deg.to_radians();
        let tan = alpha0.tan();
        let sin = alpha0.sin();
        Self {
            area_m2: std::f64::consts::PI * c.radius_m * c.radius_m,
            tondu_a: 3.0 / (tan * tan),
            tondu_b: 1.0 / (sin * sin),
            end_factor: c.end_factor,
            damping_m2s: c.damping_m2s,
            rest_length_m: c.rest_length_m,
            volume_poly_m3: c.volume_poly_m3,
        }
    }

    /// Static (spring) force Fs = max(0, pi r0^2 pg (a (1 - k chi)^2 - b)).
    #[inline(always)]
    pub fn static_force_n(&self, p_gauge_pa: f64, contraction: f64) -> f64 {
        let e = 1.0 - self.end_factor * contraction;
        (self.area_m2 * p_gauge_pa * (self.tondu_a * e * e - self.tondu_b)).max(0.0)
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
