//! The rotational joint: muscle kinematics over the sprocket and J omega' = T
//! (PLANT.md "Muscle i" contraction and "Joint"), plus mechanical end stops.
//!
//! End stops (not in PLANT.md; they only act beyond the joint's range): a one-sided
//! spring-damper at each limit,
//!
//! ```text
//! T_stop = -k (beta - beta_max) - c omega    for beta > beta_max (never pulling: <= 0)
//! T_stop = -k (beta - beta_min) - c omega    for beta < beta_min (never pulling: >= 0)
//! ```
//!
//! The limits come from the plant file (`[joint] angle_min_rad`, `angle_max_rad`). Without
//! them they sit at +-2.6 rad: beyond every angle PLANT.md's independent conformance
//! recordings reach (2.42 rad, the loaded joint), so the reference model is untouched there,
//! and before the muscle law leaves its domain (a fault run that drains both muscles swings
//! the loaded joint past 3.1 rad, where the integration fails). A real joint usually stops
//! where the stretched muscle is back at its rest length (`chi = 0`, `|beta| = chi0 l_n / r`,
//! 1.4 rad on the reference joint): set the keys to that for a rig with hard stops. `k` defaults to 2000 N m/rad (a 40 N m muscle
//! torque, more than the reference pair gives at 6 bar, pushes 0.02 rad into the stop), `c`
//! to a damping ratio of 0.7 with the joint inertia (`2 0.7 sqrt(k J)`).

use crate::plant::tables::JointConfig;

/// Default end-stop angle [rad] (module documentation).
pub const DEFAULT_END_STOP_RAD: f64 = 2.6;
/// Default end-stop stiffness [N m/rad].
pub const END_STOP_STIFFNESS_NM_PER_RAD: f64 = 2000.0;
/// Default end-stop damping ratio.
pub const END_STOP_DAMPING_RATIO: f64 = 0.7;

/// The joint's mechanical end stops (module documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EndStops {
    /// Lower limit [rad].
    pub angle_min_rad: f64,
    /// Upper limit [rad].
    pub angle_max_rad: f64,
    /// k [N m/rad].
    pub stiffness_nm_per_rad: f64,
    /// c [N m s/rad].
    pub damping_nms_per_rad: f64,
}

impl EndStops {
    /// The stops of a plant file's `[joint]` table (defaults in the module documentation).
    pub fn from_config(c: &JointConfig, muscle_rest_length_m: f64) -> Self {
        let _ = muscle_rest_length_m;
        let k = c
            .end_stop_stiffness_nm_per_rad
            .unwrap_or(END_STOP_STIFFNESS_NM_PER_RAD);
        let damping = c
            .end_stop_damping_nms_per_rad
            .unwrap_or_else(|| 2.0 * END_STOP_DAMPING_RATIO * (k * c.inertia_kgm2.max(0.0)).sqrt());
        Self {
            angle_min_rad: c.angle_min_rad.unwrap_or(-DEFAULT_END_STOP_RAD),
            angle_max_rad: c.angle_max_rad.unwrap_or(DEFAULT_END_STOP_RAD),
            stiffness_nm_per_rad: k,
            damping_nms_per_rad: damping,
        }
    }

    /// The stop torque [N m] at `angle_rad`, `velocity_rad_s` (0 inside the range).
    #[inline(always)]
    pub fn torque_nm(&self, angle_rad: f64, velocity_rad_s: f64) -> f64 {
        if angle_rad > self.angle_max_rad {
            (-self.stiffness_nm_per_rad * (angle_rad - self.angle_max_rad)
                - self.damping_nms_per_rad * velocity_rad_s)
                .min(0.0)
        } else if angle_rad < self.angle_min_rad {
            (-self.stiffness_nm_per_rad * (angle_rad - self.angle_min_rad)
                - self.damping_nms_per_rad * velocity_rad_s)
                .max(0.0)
        } else {
            0.0
        }
    }
}

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
    /// chi0 of each muscle (both [`Self::initial_contraction`] unless a per-muscle table
    /// sets one: [`Self::with_muscles`]).
    pub initial_contraction_each: [f64; 2],
    /// r / l_n of each muscle (both [`Self::contraction_per_rad`] unless a per-muscle table
    /// sets a rest length).
    pub contraction_per_rad_each: [f64; 2],
    /// Mechanical end stops.
    pub stops: EndStops,
}

impl Joint {
    pub fn from_config(c: &JointConfig, muscle_rest_length_m: f64) -> Self {
        Self {
            sprocket_radius_m: c.sprocket_radius_m,
            inertia_kgm2: c.inertia_kgm2,
            initial_contraction: c.initial_contraction,
            contraction_per_rad: c.sprocket_radius_m / muscle_rest_length_m,
            initial_contraction_each: [c.initial_contraction; 2],
            contraction_per_rad_each: [c.sprocket_radius_m / muscle_rest_length_m; 2],
            stops: EndStops::from_config(c, muscle_rest_length_m),
        }
    }

    /// The joint with each muscle's own chi0 and rest length (a plant file's per-muscle
    /// tables); the same values as the shared ones leave it as it was.
    pub fn with_muscles(mut self, initial_contraction: [f64; 2], rest_length_m: [f64; 2]) -> Self {
        self.initial_contraction_each = initial_contraction;
        self.contraction_per_rad_each = rest_length_m.map(|l| self.sprocket_radius_m / l);
        self
    }

    /// (chi1, chi2): muscle 1 contracts when the angle grows, muscle 2 when it shrinks.
    #[inline(always)]
    pub fn contractions(&self, angle_rad: f64) -> [f64; 2] {
        let [g1, g2] = self.contraction_per_rad_each;
        let [c1, c2] = self.initial_contraction_each;
        [c1 + g1 * angle_rad, c2 - g2 * angle_rad]
    }

    /// (dchi1/dt, dchi2/dt).
    #[inline(always)]
    pub fn contraction_rates(&self, velocity_rad_s: f64) -> [f64; 2] {
        let [g1, g2] = self.contraction_per_rad_each;
        [g1 * velocity_rad_s, -(g2 * velocity_rad_s)]
    }

    /// Muscle torque T = (F1 - F2) r.
    #[inline(always)]
    pub fn muscle_torque_nm(&self, tensions_n: [f64; 2]) -> f64 {
        (tensions_n[0] - tensions_n[1]) * self.sprocket_radius_m
    }

    /// Torque of the end stops [N m] (0 inside the range).
    #[inline(always)]
    pub fn end_stop_torque_nm(&self, angle_rad: f64, velocity_rad_s: f64) -> f64 {
        self.stops.torque_nm(angle_rad, velocity_rad_s)
    }

    /// domega/dt = T / J.
    #[inline(always)]
    pub fn angular_acceleration_rad_s2(&self, torque_nm: f64) -> f64 {
        torque_nm / self.inertia_kgm2
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> JointConfig {
        JointConfig {
            sprocket_radius_m: 0.025,
            inertia_kgm2: 0.014,
            initial_contraction: 0.14,
            angle_min_rad: None,
            angle_max_rad: None,
            end_stop_stiffness_nm_per_rad: None,
            end_stop_damping_nms_per_rad: None,
        }
    }

    #[test]
    fn default_stops_lie_beyond_the_reference_range_and_configured_ones_act() {
        let none = EndStops::from_config(&cfg(), 0.25);
        assert_eq!(none.torque_nm(2.55, 5.0), 0.0);
        assert_eq!(none.torque_nm(-2.55, -5.0), 0.0);
        assert!(none.torque_nm(2.7, 0.0) < 0.0);
        let mut c = cfg();
        c.angle_min_rad = Some(-1.4);
        c.angle_max_rad = Some(1.4);
        let s = EndStops::from_config(&c, 0.25);
        assert!((s.angle_max_rad - 1.4).abs() < 1e-12);
        assert!((s.angle_min_rad + 1.4).abs() < 1e-12);
        assert_eq!(s.torque_nm(1.39, 5.0), 0.0);
        // 0.01 rad into the upper stop, at rest: -k * 0.01.
        assert!((s.torque_nm(1.41, 0.0) + 20.0).abs() < 1e-9);
        // Leaving the stop fast: the damper never pulls the joint into the stop.
        assert_eq!(s.torque_nm(1.41, -100.0), 0.0);
        assert!(s.torque_nm(-1.45, -1.0) > 0.0);
        let mut c = cfg();
        c.angle_max_rad = Some(0.5);
        c.end_stop_damping_nms_per_rad = Some(0.0);
        c.end_stop_stiffness_nm_per_rad = Some(100.0);
        let s = EndStops::from_config(&c, 0.25);
        assert!((s.torque_nm(0.6, 3.0) + 10.0).abs() < 1e-9);
    }
}
