//! `[effects.joint_friction]`: Coulomb + viscous + Stribeck friction torque on the joint
//! (Cakurda et al. eq. 7 family), sign function regularized with tanh(omega / omega_eps)
//! so that the right-hand side stays continuous for the explicit integrator.
//!
//! T_f = -[(T_c + (T_s - T_c) exp(-(omega / omega_s)^2)) tanh(omega / omega_eps) + d omega]
//!
//! Diagnosis: the Coulomb + viscous candidate (no Stribeck dip, fixed smoothing) screens the
//! torque-balance residual against -sign(omega) and -omega. Truths: a Coulomb + viscous
//! friction, and a Stribeck one (a form the candidate does not have).

use serde::Deserialize;

use super::{Check, Effect, enabled_default, Hooks, Truth};
use crate::plant::effects::candidate::{clamp_to, Candidate, Screening, Setup};
use crate::plant::effects::candidate::{regress, Evidence, Scatter};
use crate::plant::config::PlantConfig;
use crate::plant::tables::{ConfigError, ValveConfig};

/// The `[effects.joint_friction]` table.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JointFriction {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    /// T_c, Coulomb (sliding) friction torque.
    pub coulomb_nm: f64,
    /// T_s, breakaway (static) friction torque, >= T_c; equal to T_c disables the Stribeck dip.
    pub breakaway_nm: f64,
    /// omega_s, Stribeck velocity.
    pub stribeck_velocity_rad_s: f64,
    /// d, viscous coefficient.
    pub viscous_nm_s_per_rad: f64,
    /// omega_eps, regularization velocity of the sign function (small, > 0).
    pub smoothing_velocity_rad_s: f64,
}

impl JointFriction {
    /// Friction torque acting on the joint (opposes the velocity).
    #[inline]
    pub fn torque_nm(&self, velocity_rad_s: f64) -> f64 {
        let w = velocity_rad_s;
        let r = w / self.stribeck_velocity_rad_s;
        let level = self.coulomb_nm + (self.breakaway_nm - self.coulomb_nm) * (-r * r).exp();
        -(level * (w / self.smoothing_velocity_rad_s).tanh() + self.viscous_nm_s_per_rad * w)
    }
}

impl Hooks for JointFriction {
    parameters!(coulomb_nm, breakaway_nm, stribeck_velocity_rad_s, viscous_nm_s_per_rad, smoothing_velocity_rad_s);
    #[inline(always)]
    fn joint_torque_nm(&self, _angle_rad: f64, velocity_rad_s: f64) -> f64 {
        self.torque_nm(velocity_rad_s)
    }
}

impl Effect for JointFriction {
    const TRUTHS: &'static [Truth] = &[
        Truth::new("joint_friction", "joint_friction", |_| "[effects.joint_friction]\ncoulomb_nm = 0.35\nbreakaway_nm = 0.35\nstribeck_velocity_rad_s = 1.0\nviscous_nm_s_per_rad = 0.08\nsmoothing_velocity_rad_s = 0.01\n".into()),
        Truth::new("joint_friction_stribeck", "joint_friction", |_| "[effects.joint_friction]\ncoulomb_nm = 0.25\nbreakaway_nm = 0.5\nstribeck_velocity_rad_s = 0.3\nviscous_nm_s_per_rad = 0.05\nsmoothing_velocity_rad_s = 0.01\n".into()),
    ];
    table_effect!();
    fn validate(&self, c: &Check) -> Result<(), ConfigError> {
        check_fields!(self, c, positive: stribeck_velocity_rad_s, smoothing_velocity_rad_s);
        use crate::validate::Range;
        // Up to 50 N m: beyond the torque any muscle pair of the plants here can give (N mm
        // typed as N m is 1000 times off).
        let torque = Range::closed(0.0, 50.0);
        let unit = "N m (N mm typed?)";
        c.within("coulomb_nm", self.coulomb_nm, torque, unit)?;
        c.within("breakaway_nm", self.breakaway_nm, torque, unit)?;
        c.within(
            "viscous_nm_s_per_rad",
            self.viscous_nm_s_per_rad,
            torque,
            "N m s/rad",
        )?;
        if self.coulomb_nm < 0.0 || self.breakaway_nm < self.coulomb_nm {
            return Err(c.error(
                "breakaway_nm",
                "need 0 <= coulomb_nm <= breakaway_nm",
            ));
        }
        Ok(())
    }
}

effect_candidates!(JointFriction => JointFrictionCandidate);

/// Regularisation velocity of the friction sign function used by the candidate.
pub const FRICTION_SMOOTHING_RAD_S: f64 = 0.02;

/// Coulomb + viscous friction on the joint (no Stribeck dip).
pub struct JointFrictionCandidate;

impl Candidate for JointFrictionCandidate {
    candidate_spec! {
        id: "joint_friction",
        label: "joint friction",
        params: [("coulomb_nm", 0.0, 20.0, 0.2), ("viscous_nm_s_per_rad", 0.0, 20.0, 0.05)],
        fixed: [("smoothing_velocity_rad_s", FRICTION_SMOOTHING_RAD_S)],
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        let sign: Vec<f64> = ev
            .omega_rad_s
            .iter()
            .map(|w| -(w / FRICTION_SMOOTHING_RAD_S).tanh())
            .collect();
        let visc: Vec<f64> = ev.omega_rad_s.iter().map(|w| -w).collect();
        let (c, r2) = regress(&ev.torque_residual_nm, &[&sign, &visc]);
        Screening {
            score: r2,
            initial: clamp_to(&self.params(s), vec![c[0], c[1]]),
            note: format!(
                "the joint torque balance residual follows -sign(omega) and -omega (R^2 {r2:.2})"
            ),
            scatter: Some(Scatter::new(
                "angular velocity omega [rad/s]",
                "torque balance residual J alpha - T [N m]",
                &ev.omega_rad_s,
                &ev.torque_residual_nm,
            )),
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], _s: &Setup) {
        cfg.effects.joint_friction = Some(JointFriction {
            enabled: true,
            coulomb_nm: p[0],
            breakaway_nm: p[0],
            stribeck_velocity_rad_s: 1.0,
            viscous_nm_s_per_rad: p[1],
            smoothing_velocity_rad_s: FRICTION_SMOOTHING_RAD_S,
        });
    }
    fn describe(&self, p: &[f64], _s: &Setup) -> String {
        format!(
            "a friction torque on the joint, {:.3} N m Coulomb + {:.3} N m s/rad viscous",
            p[0], p[1]
        )
    }
}
