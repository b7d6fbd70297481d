//! A discovered term set as a diagnosis [`Candidate`]: its coefficients are the parameters the
//! shared output-error fitter ([`crate::diagnose::fitting::Problem::fit_with_ci`], on the
//! `levenberg-marquardt` crate) refines inside the full simulation.

use crate::plant::config::PlantConfig;
use crate::plant::effects::candidate::{Candidate, Evidence, ParamSpec, Screening, Setup};
use crate::plant::effects::discovered::{Discovered, Slot, Term};

/// The terms of one slot; the parameters are their coefficients.
#[derive(Debug, Clone)]
pub struct TermsCandidate {
    pub slot: Slot,
    pub terms: Vec<Term>,
    /// The equation-error coefficients (the start, and the scale of the bounds).
    pub start: Vec<f64>,
}

/// The refit may move a coefficient this many times its equation-error size either way.
const RANGE_X: f64 = 6.0;

impl TermsCandidate {
    /// The `[effects.discovered]` table with coefficients `p`.
    pub fn table(&self, p: &[f64]) -> Discovered {
        Discovered {
            enabled: true,
            slot: self.slot,
            terms: self.terms.clone(),
            coefficients: p.to_vec(),
        }
    }
}

impl Candidate for TermsCandidate {
    fn id(&self) -> &'static str {
        "discovered"
    }
    fn label(&self) -> &'static str {
        "discovered term"
    }
    fn params(&self, _s: &Setup) -> Vec<ParamSpec> {
        self.terms
            .iter()
            .zip(&self.start)
            .map(|(t, c)| {
                let size = c.abs().max(1e-12);
                ParamSpec::new(t.symbol(), c - RANGE_X * size, c + RANGE_X * size, size)
            })
            .collect()
    }
    fn screen(&self, _ev: &Evidence, _s: &Setup) -> Screening {
        Screening {
            score: 0.0,
            initial: self.start.clone(),
            note: String::new(),
            scatter: None,
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], _s: &Setup) {
        cfg.effects.discovered = Some(self.table(p));
    }
    fn changes_dynamics(&self) -> bool {
        !self.slot.is_sensor()
    }
    fn describe(&self, p: &[f64], _s: &Setup) -> String {
        self.table(p).formula()
    }
}
