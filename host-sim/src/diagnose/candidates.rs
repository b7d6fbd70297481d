//! The candidate interface: one [`Candidate`] per effect the diagnosis can name. Each one knows
//! its parameters (names, bounds, typical size), how to screen the equation-error evidence
//! for its signature (score and initial guess), and how to switch itself on in a
//! [`PlantConfig`] (the same `[effects]` tables the simulator runs, so the corrected model
//! is the plant code itself).
//!
//! The candidates themselves live with their effects, one module each under
//! [`crate::plant::effects`]; [`catalogue`] collects them from the effect registry.

use crate::io::recording::Channel;
use crate::plant::config::PlantConfig;

use super::screen::{regress, Evidence, Scatter};

/// One parameter of a candidate (SI or the channel's unit, as its name says).
#[derive(Debug, Clone)]
pub struct ParamSpec {
    pub name: String,
    pub lo: f64,
    pub hi: f64,
    /// Typical size: the fit works in units of it.
    pub scale: f64,
}

impl ParamSpec {
    pub fn new(name: impl Into<String>, lo: f64, hi: f64, scale: f64) -> Self {
        Self {
            name: name.into(),
            lo,
            hi,
            scale,
        }
    }
}

/// What screening found for one candidate.
#[derive(Debug, Clone)]
pub struct Screening {
    /// Share (0..1) of the equation-error (or output) residual the signature explains.
    pub score: f64,
    /// Initial guess of the parameters (same order as [`Candidate::params`]).
    pub initial: Vec<f64>,
    /// One sentence on the signature found.
    pub note: String,
    /// Residual against the regressor that explains it (for the report).
    pub scatter: Option<Scatter>,
}

/// Facts about the recording the candidates need.
#[derive(Debug, Clone)]
pub struct Setup {
    pub dt_s: f64,
    /// Which of `Channel::ALL` were measured.
    pub present: [bool; 5],
}

impl Setup {
    pub fn has(&self, c: Channel) -> bool {
        self.present[c.index()]
    }
    pub fn has_force(&self) -> bool {
        self.has(Channel::F1N) || self.has(Channel::F2N)
    }
    pub fn has_pressure(&self) -> bool {
        self.has(Channel::P1Kpa) || self.has(Channel::P2Kpa)
    }
}

/// One effect the diagnosis can name.
pub trait Candidate: Sync + Send {
    /// Effect id of the JSON contract (`joint_friction`, ...).
    fn id(&self) -> &'static str;
    /// Human name for sentences.
    fn label(&self) -> &'static str;
    /// Its free parameters for this recording.
    fn params(&self, s: &Setup) -> Vec<ParamSpec>;
    /// Parameters that are not fitted but reported (name, value).
    fn fixed(&self) -> Vec<(&'static str, f64)> {
        Vec::new()
    }
    /// Scores the evidence and gives an initial guess.
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening;
    /// Switches the effect on in `cfg` with `params`.
    fn apply(&self, cfg: &mut PlantConfig, params: &[f64], s: &Setup);
    /// False when the effect only changes what the sensors report (the simulated states
    /// can then be reused).
    fn changes_dynamics(&self) -> bool {
        true
    }
    /// For a parameter that only takes discrete values (a dead time in whole samples): the
    /// values to try around `initial`. `None`: continuous, fitted by Levenberg-Marquardt.
    fn grid(&self, _initial: &[f64], _s: &Setup) -> Option<Vec<Vec<f64>>> {
        None
    }
    /// For a gridded parameter that is continuous in truth (a dead time that need not be a
    /// whole number of samples): after the grid, refine it continuously within one grid
    /// step (its `ParamSpec::scale`) of the best grid value.
    fn refine_after_grid(&self) -> bool {
        false
    }
    /// One sentence saying what the fitted effect is.
    fn describe(&self, params: &[f64], s: &Setup) -> String;
    /// True when the fitted parameters leave the model as the plant file has it (a
    /// recalibration within [`crate::diagnose::recalibrate::RECAL_NEGLIGIBLE`] of the file's
    /// value): such a part is not an answer, whatever residue it fits.
    fn changes_nothing(&self, _params: &[f64]) -> bool {
        false
    }
}

/// The full catalogue, in the fixed order of the effect registry
/// ([`crate::plant::effects`]).
pub fn catalogue() -> Vec<Box<dyn Candidate>> {
    crate::plant::effects::candidates()
}

/// `v` clamped to the bounds of `p` (a non-finite value becomes the typical size).
pub fn clamp_to(p: &[ParamSpec], v: Vec<f64>) -> Vec<f64> {
    v.iter()
        .zip(p)
        .map(|(x, s)| {
            if x.is_finite() {
                x.clamp(s.lo, s.hi)
            } else {
                s.scale.clamp(s.lo, s.hi)
            }
        })
        .collect()
}

/// Regression of both chambers' pressure-rate residual on one regressor per chamber;
/// returns (coefficient, R^2).
#[allow(clippy::needless_range_loop)]
pub fn regress_pressure(ev: &Evidence, reg: &[Vec<f64>; 2]) -> (f64, f64) {
    let mut y = Vec::new();
    let mut x = Vec::new();
    for i in 0..2 {
        if let Some(r) = &ev.pressure_residual_pa_s[i] {
            y.extend_from_slice(r);
            x.extend_from_slice(&reg[i]);
        }
    }
    if y.is_empty() {
        return (0.0, 0.0);
    }
    let (c, r2) = regress(&y, &[&x]);
    (c[0], r2)
}

/// The pressure-rate residual of the first measured chamber against its regressor.
pub fn pressure_scatter(ev: &Evidence, reg: &[Vec<f64>; 2], xlabel: &str) -> Option<Scatter> {
    let (i, r) = ev
        .pressure_residual_pa_s
        .iter()
        .enumerate()
        .find_map(|(i, r)| r.as_ref().map(|r| (i, r)))?;
    Some(Scatter::new(
        xlabel,
        &format!("p{} rate residual [Pa/s]", i + 1),
        &reg[i],
        r,
    ))
}
