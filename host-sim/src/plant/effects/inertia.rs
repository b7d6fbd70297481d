//! Inertia mismatch: not an `[effects]` table (the inertia is `joint.inertia_kgm2`), but an
//! effect the diagnosis can name: a load that makes the joint heavier or lighter than the
//! nominal file says.
//!
//! Diagnosis: the torque-balance residual proportional to the angular acceleration.
//! Truth: J = 0.03 kg m^2 (replaces the `[joint]` line).

use serde::{Deserialize, Deserializer};

use super::{Check, Effect, Hooks, Truth};
use crate::plant::effects::candidate::{EffectCandidates, torque_residual_scatter, clamp_to, Candidate, Screening, Setup};
use crate::plant::effects::candidate::{regress, Evidence};
use crate::plant::config::PlantConfig;
use crate::plant::tables::{ConfigError, ValveConfig};

/// Registry entry of the inertia mismatch. There is no `[effects.inertia]` table: giving
/// one is an error that points at `joint.inertia_kgm2`.
#[derive(Debug, Clone, PartialEq)]
pub struct InertiaMismatch;

impl<'de> Deserialize<'de> for InertiaMismatch {
    fn deserialize<D: Deserializer<'de>>(_d: D) -> Result<Self, D::Error> {
        Err(serde::de::Error::custom(
            "there is no [effects.inertia] table: the inertia is `joint.inertia_kgm2`",
        ))
    }
}

impl Hooks for InertiaMismatch {
    fn parameters(&self) -> Option<Vec<(String, String)>> {
        None
    }}

impl Effect for InertiaMismatch {
    type Active = Self;
    const TRUTHS: &'static [Truth] = &[Truth {
        name: "inertia",
        expected_id: "inertia",
        toml: |_| "inertia_kgm2 = 0.03\n".into(),
        replaces_key: Some("inertia_kgm2"),
    }];
    fn enabled(&self) -> bool {
        false
    }
    fn validate(&self, _c: &Check) -> Result<(), ConfigError> {
        Ok(())
    }
    fn activate(&self, _valve: &ValveConfig) -> Self {
        Self
    }
}

impl EffectCandidates for InertiaMismatch {
    fn candidates() -> Vec<Box<dyn Candidate>> {
        vec![Box::new(InertiaCandidate)]
    }
}

/// The joint inertia, refitted.
pub struct InertiaCandidate;

impl Candidate for InertiaCandidate {
    candidate_spec! {
        id: "inertia",
        label: "inertia (load) mismatch",
        params: [("inertia_kgm2", 1e-3, 10.0, 0.01)],
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        let (c, r2) = regress(&ev.torque_residual_nm, &[&ev.alpha_rad_s2]);
        Screening {
            score: r2,
            initial: clamp_to(&self.params(s), vec![ev.inertia_kgm2 - c[0]]),
            note: format!(
                "the joint torque balance residual is proportional to the angular acceleration (R^2 {r2:.2})"
            ),
            scatter: torque_residual_scatter(ev, "angular acceleration [rad/s^2]", &ev.alpha_rad_s2),
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], _s: &Setup) {
        cfg.joint.inertia_kgm2 = p[0];
    }
    fn describe(&self, p: &[f64], _s: &Setup) -> String {
        format!("a joint inertia of {:.4} kg m^2", p[0])
    }
}
