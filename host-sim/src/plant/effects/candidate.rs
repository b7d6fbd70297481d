//! The contract between an effect and the diagnosis: what a diagnosis candidate is
//! ([`Candidate`]: its parameters, how it screens the equation-error [`Evidence`], how it
//! switches its effect on in a [`PlantConfig`]) and the evidence it screens. Each effect's
//! module implements its candidates against this contract; the diagnosis (`crate::diagnose`)
//! builds the evidence, selects and fits candidates through it. It sits in the plant, below
//! the diagnosis: the plant never imports the diagnosis.

use crate::plant::channel::Channel;
use crate::plant::config::PlantConfig;
use crate::plant::state::{PlantState, ValveInputs};
use crate::plant::Plant;

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

/// Residual against a regressor, subsampled for a plot.
#[derive(Debug, Clone)]
pub struct Scatter {
    pub x_label: String,
    pub y_label: String,
    pub points: Vec<(f64, f64)>,
    /// A model's curve over the same axes, by increasing x (empty: none drawn).
    pub curve: Vec<(f64, f64)>,
}

impl Scatter {
    pub fn new(x_label: &str, y_label: &str, x: &[f64], y: &[f64]) -> Self {
        let n = x.len().min(y.len());
        let stride = (n / 1500).max(1);
        Self {
            x_label: x_label.into(),
            y_label: y_label.into(),
            points: (0..n)
                .step_by(stride)
                .filter(|k| x[*k].is_finite() && y[*k].is_finite())
                .map(|k| (x[k], y[k]))
                .collect(),
            curve: Vec::new(),
        }
    }
}

/// Least squares y ~ sum_j c_j x_j (no intercept: the signatures are physical); returns the
/// coefficients and R^2 = 1 - SS_res / SS_y (uncentred, clipped to [0, 1]).
pub fn regress(y: &[f64], xs: &[&[f64]]) -> (Vec<f64>, f64) {
    let m = xs.len();
    let n = y.len();
    let mut a = nalgebra::DMatrix::<f64>::zeros(m, m);
    let mut b = nalgebra::DVector::<f64>::zeros(m);
    let mut ss = 0.0;
    for k in 0..n {
        if !y[k].is_finite() || xs.iter().any(|x| !x[k].is_finite()) {
            continue;
        }
        ss += y[k] * y[k];
        for i in 0..m {
            b[i] += xs[i][k] * y[k];
            for j in 0..m {
                a[(i, j)] += xs[i][k] * xs[j][k];
            }
        }
    }
    if ss == 0.0 {
        return (vec![0.0; m], 0.0);
    }
    // Scale-invariant ridge on the diagonal against collinear regressors.
    for i in 0..m {
        a[(i, i)] *= 1.0 + 1e-9;
        if a[(i, i)] == 0.0 {
            a[(i, i)] = 1.0;
        }
    }
    let Some(c) = a.clone().cholesky().map(|ch| ch.solve(&b)) else {
        return (vec![0.0; m], 0.0);
    };
    let explained = (c.transpose() * &b)[(0, 0)];
    let r2 = (explained / ss).clamp(0.0, 1.0);
    (c.iter().copied().collect(), r2)
}

/// The evidence the candidates screen.
#[derive(Debug, Clone)]
pub struct Evidence {
    pub dt_s: f64,
    pub angle_rad: Vec<f64>,
    pub omega_rad_s: Vec<f64>,
    pub alpha_rad_s2: Vec<f64>,
    pub dchi1_per_s: Vec<f64>,
    /// Gauge pressures (measured, else simulated).
    pub p_gauge_pa: [Vec<f64>; 2],
    /// J alpha - r (F1 - F2), F measured when both force channels are, else from the
    /// nominal tension law at the measured state.
    pub torque_residual_nm: Vec<f64>,
    /// dp/dt measured - dp/dt nominal at the measured state (where the channel was measured).
    pub pressure_residual_pa_s: [Option<Vec<f64>>; 2],
    /// Nominal dp/dt at the measured state.
    pub nominal_dp: [Vec<f64>; 2],
    /// F measured - F nominal at the measured state (when any force channel was measured).
    pub force_residual_n: Option<[Option<Vec<f64>>; 2]>,
    /// Measured - nominal simulation, per channel present.
    pub residual: [Option<Vec<f64>>; 5],
    /// The nominal simulation of each channel present.
    pub nominal: [Option<Vec<f64>>; 5],
    /// d/dt of the nominal simulation of each measured channel (a lag tau leaves a
    /// residual of about -tau times it).
    pub nominal_rate: [Option<Vec<f64>>; 5],
    /// Standard deviation of each measured channel (1 when absent).
    pub spread: [f64; 5],
    /// Shift (samples) by which the nominal simulation best matches each channel.
    pub lag_samples: [usize; 5],
    /// Share of the residual energy that shift removes.
    pub lag_gain: [f64; 5],
    pub inertia_kgm2: f64,
    pub sprocket_radius_m: f64,
    /// The nominal plant.
    pub plant: Plant,
    /// The measured state at every sample (angle, its smoothed derivative, pressures
    /// measured else simulated), for candidates that build their own regressors.
    pub states: Vec<PlantState>,
    /// The recording's valve inputs.
    pub inputs: Vec<ValveInputs>,
}

/// Longest lag searched by cross-correlation.
pub const MAX_LAG_S: f64 = 0.05;

impl Evidence {
    /// Residual of channel `c` against its nominal rate (the lag signature).
    pub fn lag_scatter(&self, c: Channel) -> Option<Scatter> {
        Some(Scatter::new(
            &format!("nominal d({})/dt [{} per s]", c.name(), c.name()),
            &format!("{} residual, measured - nominal", c.name()),
            self.nominal_rate[c.index()].as_ref()?,
            self.residual[c.index()].as_ref()?,
        ))
    }
}
/// The joint torque balance residual drawn against the regressor `x` (`x_label`): the scatter
/// of the joint-torque candidates' screening.
pub fn torque_residual_scatter(ev: &Evidence, x_label: &str, x: &[f64]) -> Option<Scatter> {
    Some(Scatter::new(
        x_label,
        "torque balance residual [N m]",
        x,
        &ev.torque_residual_nm,
    ))
}

/// The diagnosis candidates of one effect (usually one), in catalogue order. Implemented by
/// each effect's table with [`effect_candidates!`].
pub trait EffectCandidates {
    fn candidates() -> Vec<Box<dyn Candidate>>;
}

/// `effect_candidates!(TheTable => TheCandidate, ...)`: the [`EffectCandidates`] of an effect
/// whose candidates are unit values or expressions.
macro_rules! effect_candidates {
    ($ty:ty => $($candidate:expr),+ $(,)?) => {
        impl $crate::plant::effects::candidate::EffectCandidates for $ty {
            fn candidates() -> Vec<Box<dyn $crate::plant::effects::candidate::Candidate>> {
                vec![$(Box::new($candidate)),+]
            }
        }
    };
}

/// The fixed part of a diagnosis candidate, written inside `impl Candidate for TheCandidate`:
/// [`Candidate::id`] (the effect id of the diagnosis JSON), [`Candidate::label`] (its name in
/// sentences) and, when they do not depend on the recording, [`Candidate::params`] (name,
/// bounds and typical size, as `ParamSpec::new` takes them) and [`Candidate::fixed`]:
///
/// ```text
/// candidate_spec! {
///     id: "gravity",
///     label: "gravity load",
///     params: [("mass_kg", 0.0, 20.0, 1.0)],
///     fixed: [("com_distance_m", GRAVITY_COM_DISTANCE_M)],
/// }
/// ```
///
/// A candidate whose id depends on its fields (`leakage.rs`) writes the methods by hand.
macro_rules! candidate_spec {
    (
        id: $id:literal,
        label: $label:literal
        $(, params: [$(($name:literal, $lo:expr, $hi:expr, $scale:expr)),+ $(,)?])?
        $(, fixed: [$(($key:literal, $value:expr)),+ $(,)?])?
        $(,)?
    ) => {
        fn id(&self) -> &'static str {
            $id
        }
        fn label(&self) -> &'static str {
            $label
        }
        $(
            fn params(
                &self,
                _s: &$crate::plant::effects::candidate::Setup,
            ) -> Vec<$crate::plant::effects::candidate::ParamSpec> {
                vec![$($crate::plant::effects::candidate::ParamSpec::new($name, $lo, $hi, $scale)),+]
            }
        )?
        $(
            fn fixed(&self) -> Vec<(&'static str, f64)> {
                vec![$(($key, $value)),+]
            }
        )?
    };
}
