//! `[effects.polytropic]`: polytropic instead of isothermal chamber process (seed 004 eq. 3
//! with the standard flow at the reference temperature): dp/dt = n (p_atm Q - p dV/dt) / V.
//! `exponent = 1` is the nominal isothermal (Boyle-Mariotte) model, 1.4 adiabatic air.
//!
//! Diagnosis: the measured pressure rate is the nominal one scaled by a constant. Truth:
//! n = 1.3.

use serde::Deserialize;

use super::{Check, Effect, enabled_default, Hooks, params, Truth};
use crate::plant::effects::candidate::{
    clamp_to, pressure_scatter, regress_pressure, Candidate, Screening, Setup,
};
use crate::plant::effects::candidate::Evidence;
use crate::plant::config::PlantConfig;
use crate::plant::tables::{ConfigError, ValveConfig};

/// The `[effects.polytropic]` table.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Polytropic {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    pub exponent: f64,
}

impl Hooks for Polytropic {
    fn parameters(&self) -> Option<Vec<(String, String)>> {
        // An exponent of 1 is the nominal isothermal law: nothing changes.
        (self.exponent != 1.0).then(|| params(&[("exponent", self.exponent)]))
    }
    #[inline(always)]
    fn pressure_rate_factor(&self) -> f64 {
        self.exponent
    }
}

impl Effect for Polytropic {
    const TRUTHS: &'static [Truth] = &[Truth::new("polytropic", "polytropic", |_| "[effects.polytropic]\nexponent = 1.3\n".into())];
    table_effect!();
    fn validate(&self, c: &Check) -> Result<(), ConfigError> {
        check_fields!(self, c, positive: exponent);
        Ok(())
    }
}

effect_candidates!(Polytropic => PolytropicCandidate);

/// A constant polytropic exponent.
pub struct PolytropicCandidate;

impl Candidate for PolytropicCandidate {
    candidate_spec! {
        id: "polytropic",
        label: "polytropic (non-isothermal) chamber process",
        params: [("exponent", 0.5, 2.0, 1.0)],
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        let (c, r2) = regress_pressure(ev, &ev.nominal_dp);
        Screening {
            score: r2,
            initial: clamp_to(&self.params(s), vec![1.0 + c]),
            note: format!(
                "the measured pressure rate is the nominal (isothermal) rate scaled by a constant (R^2 {r2:.2})"
            ),
            scatter: pressure_scatter(ev, &ev.nominal_dp, "nominal pressure rate dp/dt [Pa/s]"),
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], _s: &Setup) {
        // The exponent replaces the file's pressure law (a thermal chamber).
        cfg.effects.thermal_chamber = None;
        cfg.effects.polytropic = Some(Polytropic {
            enabled: true,
            exponent: p[0],
        });
    }
    fn describe(&self, p: &[f64], _s: &Setup) -> String {
        format!(
            "a polytropic chamber process with exponent {:.3} instead of isothermal (1)",
            p[0]
        )
    }
}
