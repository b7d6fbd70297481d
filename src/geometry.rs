//! Joint geometry: from the joint angle to each muscle's contraction and deformation.
//!
//! PLANT.md convention: muscle 1 contracts when the angle grows,
//! `chi1 = chi0 + (r / l_n) beta`, `chi2 = chi0 - (r / l_n) beta`, and the deformation used
//! by the force law is `L / L0 = 1 - chi` (L0 = rest length `l_n`).

/// Geometry of an antagonistic joint with a chain over a sprocket.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct JointGeometry {
    /// Sprocket (chain wheel) radius r [m].
    pub sprocket_radius_m: f32,
    /// Muscle rest length l_n (zero contraction) [m].
    pub rest_length_m: f32,
    /// Contraction of both muscles at angle 0 (chi0, a fraction).
    pub initial_contraction: f32,
}

impl JointGeometry {
    /// The reference joint of `shared/plant/reference-1dof.toml`.
    pub const REFERENCE: JointGeometry = JointGeometry {
        sprocket_radius_m: 0.025,
        rest_length_m: 0.25,
        initial_contraction: 0.14,
    };

    /// Contractions (chi1, chi2) at the joint angle [rad].
    #[inline]
    pub fn contractions(&self, angle_rad: f32) -> (f32, f32) {
        let d = self.sprocket_radius_m / self.rest_length_m * angle_rad;
        (self.initial_contraction + d, self.initial_contraction - d)
    }

    /// Deformations L/L0 = 1 - chi of (muscle 1, muscle 2) at the joint angle [rad].
    #[inline]
    pub fn stretches(&self, angle_rad: f32) -> (f32, f32) {
        let (c1, c2) = self.contractions(angle_rad);
        (1.0 - c1, 1.0 - c2)
    }
}
