//! `[effects.gravity]`: a point load on the arm, T_g = -m g l sin(beta - beta_hang).
//!
//! Diagnosis: the torque-balance residual against sin and cos of the angle (only m l
//! counts: the candidate fits the mass at a fixed lever). Truth: 1 kg at 0.1 m.

use std::f64::consts::PI;

use serde::Deserialize;

use super::{Check, Effect, enabled_default, Hooks, Truth};
use crate::plant::effects::candidate::{torque_residual_scatter, clamp_to, Candidate, Screening, Setup};
use crate::plant::effects::candidate::{regress, Evidence};
use crate::plant::config::PlantConfig;
use crate::plant::tables::{ConfigError, ValveConfig};

/// The `[effects.gravity]` table.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Gravity {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    pub mass_kg: f64,
    /// Distance of the centre of mass from the joint axis.
    pub com_distance_m: f64,
    /// Joint angle at which the load hangs straight down (stable equilibrium).
    pub hanging_angle_rad: f64,
    #[serde(default = "standard_gravity")]
    pub g_m_s2: f64,
}

/// Standard gravity (m/s^2).
pub const STANDARD_GRAVITY_M_S2: f64 = 9.806_65;

fn standard_gravity() -> f64 {
    STANDARD_GRAVITY_M_S2
}

impl Gravity {
    #[inline]
    pub fn torque_nm(&self, angle_rad: f64) -> f64 {
        -self.mass_kg
            * self.g_m_s2
            * self.com_distance_m
            * (angle_rad - self.hanging_angle_rad).sin()
    }
}

impl Hooks for Gravity {
    parameters!(mass_kg, com_distance_m, hanging_angle_rad, g_m_s2);
    #[inline(always)]
    fn joint_torque_nm(&self, angle_rad: f64, _velocity_rad_s: f64) -> f64 {
        self.torque_nm(angle_rad)
    }
}

impl Effect for Gravity {
    const TRUTHS: &'static [Truth] = &[Truth::new("gravity", "gravity", |_| "[effects.gravity]\nmass_kg = 1.0\ncom_distance_m = 0.1\nhanging_angle_rad = 0.0\n".into())];
    table_effect!();
    fn validate(&self, c: &Check) -> Result<(), ConfigError> {
        use crate::validate::Range;
        c.within("mass_kg", self.mass_kg, Range::closed(0.0, 100.0), "kg (the load on the joint)")?;
        c.within(
            "com_distance_m",
            self.com_distance_m,
            Range::closed(0.0, 2.0),
            "m (the load's lever from the joint axis; mm typed?)",
        )?;
        c.within(
            "hanging_angle_rad",
            self.hanging_angle_rad,
            Range::closed(-std::f64::consts::PI, std::f64::consts::PI),
            "rad (degrees typed?)",
        )?;
        c.within("g_m_s2", self.g_m_s2, Range::closed(0.0, 30.0), "m/s^2")?;
        Ok(())
    }
}

effect_candidates!(Gravity => GravityCandidate);

/// Lever of the gravity candidate (the fit gives the mass at this distance: only m l counts).
pub const GRAVITY_COM_DISTANCE_M: f64 = 0.1;

/// A point load: mass at [`GRAVITY_COM_DISTANCE_M`] and hanging angle.
pub struct GravityCandidate;

impl Candidate for GravityCandidate {
    candidate_spec! {
        id: "gravity",
        label: "gravity load",
        params: [("mass_kg", 0.0, 20.0, 1.0), ("hanging_angle_rad", -PI, PI, 1.0)],
        fixed: [("com_distance_m", GRAVITY_COM_DISTANCE_M)],
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        let sin: Vec<f64> = ev.angle_rad.iter().map(|b| b.sin()).collect();
        let cos: Vec<f64> = ev.angle_rad.iter().map(|b| b.cos()).collect();
        let (c, r2) = regress(&ev.torque_residual_nm, &[&sin, &cos]);
        // -mgl sin(b - bh) = -mgl cos(bh) sin b + mgl sin(bh) cos b
        let mgl = c[0].hypot(c[1]);
        let bh = c[1].atan2(-c[0]);
        let m = mgl / (STANDARD_GRAVITY_M_S2 * GRAVITY_COM_DISTANCE_M);
        Screening {
            score: r2,
            initial: clamp_to(&self.params(s), vec![m, bh]),
            note: format!(
                "the joint torque balance residual follows the sine of the angle (R^2 {r2:.2})"
            ),
            scatter: torque_residual_scatter(ev, "joint angle [rad]", &ev.angle_rad),
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], _s: &Setup) {
        cfg.effects.gravity = Some(Gravity {
            enabled: true,
            mass_kg: p[0],
            com_distance_m: GRAVITY_COM_DISTANCE_M,
            hanging_angle_rad: p[1],
            g_m_s2: STANDARD_GRAVITY_M_S2,
        });
    }
    fn describe(&self, p: &[f64], _s: &Setup) -> String {
        format!(
            "a gravity load of {:.3} N m peak ({:.3} kg at {GRAVITY_COM_DISTANCE_M} m), hanging at {:.1} deg",
            p[0] * STANDARD_GRAVITY_M_S2 * GRAVITY_COM_DISTANCE_M,
            p[0],
            p[1].to_degrees()
        )
    }
}
