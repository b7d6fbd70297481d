//! The rotational joint: muscle kinematics over the sprocket and J omega' = T
//! (PLANT.md "Muscle i" contraction and "Joint").

use crate::plant::config::JointConfig;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Joint {
    /// r.
    pub sprocket_radius_m: f64,
    /// J.
    pub inertia_kgm2: f64,
    /// chi0.
    pub initial_contraction: f64,
    /// r / l_n: contraction per radian.
    pub contraction_per_rad: f64,
}

impl Joint {
    pub fn from_config(c: &JointConfig, muscle_rest_length_m: f64) -> Self {
        Self {
            sprocket_radius_m: c.sprocket_radius_m,
            inertia_kgm2: c.inertia_kgm2,
            initial_contraction: c.initial_contraction,
            contraction_per_rad: c.sprocket_radius_m / muscle_rest_length_m,
        }
    }

    /// (chi1, chi2): muscle 1 contracts when the angle grows, muscle 2 when it shrinks.
    #[inline(always)]
    pub fn contractions(&self, angle_rad: f64) -> [f64; 2] {
        let d = self.contraction_per_rad * angle_rad;
        [self.initial_contraction + d, self.initial_contraction - d]
    }

    /// (dchi1/dt, dchi2/dt).
    #[inline(always)]
    pub fn contraction_rates(&self, velocity_rad_s: f64) -> [f64; 2] {
        let d = self.contraction_per_rad * velocity_rad_s;
        [d, -d]
    }

    /// Muscle torque T = (F1 - F2) r.
    #[inline(always)]
    pub fn muscle_torque_nm(&self, tensions_n: [f64; 2]) -> f64 {
        (tensions_n[0] - tensions_n[1]) * self.sprocket_radius_m
    }

    /// domega/dt = T / J.
    #[inline(always)]
    pub fn angular_acceleration_rad_s2(&self, torque_nm: f64) -> f64 {
        torque_nm / self.inertia_kgm2
    }
}
