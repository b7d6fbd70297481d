//! Identification of the static muscle force law from isometric data.
//!
//! Two models are fitted to the same samples:
//! - the trig-free identified law of seed 002, eq. 6 (constants c1..c10), which the firmware
//!   evaluates every tick (`config/force_law.toml`, `src/force_law.rs`);
//! - the Tondu physical model (seed 002 eq. 1 with the end-effect factor k of PLANT.md,
//!   parameters r0, alpha0, k) as the physical baseline.
//!
//! Conventions are those of the firmware: P is gauge pressure in MPa inside eq. 6, the
//! deformation e = L/L0, force in N. The scale of eq. 6's rational part is fixed by c8 = 1.
//!
//! Fitting eq. 6: for a fixed c7 the model is *linear* in the other eight constants
//! (c1..c6, c9, c10), so the fit is a variable-projection problem: a one-dimensional search
//! over c7 (with the denominator kept positive over the data's whole domain box) solving a
//! linear least-squares problem (SVD) at each point, then a Levenberg-Marquardt polish of all
//! nine constants (`levenberg-marquardt` crate). This needs no random restarts and is
//! deterministic.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::ops::RangeInclusive;
use std::path::Path;

use levenberg_marquardt::LevenbergMarquardt;
use nalgebra::{DMatrix, DVector};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

use super::output_error::{LmProblem, LmResiduals};
use super::{write_atomic, IdentError};
use crate::plant::muscle::TonduLaw;

/// Which branch of an isometric pressure sweep a sample was taken on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Branch {
    /// Pressure rising.
    Pressurising,
    /// Pressure falling.
    Depressurising,
}

impl Branch {
    fn label(self) -> &'static str {
        match self {
            Branch::Pressurising => "pressurising",
            Branch::Depressurising => "depressurising",
        }
    }
}

/// One isometric measurement.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ForceSample {
    /// Gauge pressure [Pa].
    pub p_gauge_pa: f64,
    /// Deformation L/L0.
    pub stretch: f64,
    /// Measured tension [N].
    pub force_n: f64,
    /// Branch of the sweep, when the data says.
    pub branch: Option<Branch>,
}

/// A slack threshold within this of one atmosphere, with no pressure below it, reads as
/// pressures logged absolute [Pa].
const ABSOLUTE_THRESHOLD_WITHIN_PA: f64 = 10e3;
/// The standard atmosphere [Pa].
const STANDARD_ATMOSPHERE_PA: f64 = 101_325.0;

/// Eq. 6 of seed 002 with P in MPa gauge and e = L/L0.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Eq6 {
    /// c1..c10.
    pub c: [f64; 10],
}

impl Eq6 {
    /// Force [N] (not clamped) at gauge pressure [Pa] and deformation.
    pub fn eval(&self, p_gauge_pa: f64, stretch: f64) -> f64 {
        let c = &self.c;
        let p = p_gauge_pa * 1e-6;
        let e = stretch;
        (c[0] * p * p + c[1] * e * e + c[2] * p + c[3] * e + c[4] * p / e + c[5])
            / (c[6] * p + c[7] * e)
            + c[8]
            + c[9] * (e - 0.7).exp()
    }

    /// Force [N] clamped at 0, as the firmware evaluates it.
    pub fn force_n(&self, p_gauge_pa: f64, stretch: f64) -> f64 {
        self.eval(p_gauge_pa, stretch).max(0.0)
    }
}

/// The Tondu physical model (PLANT.md form): `F = max(0, pi r0^2 P (a (1 - k chi)^2 - b))`,
/// `a = 3 / tan^2(alpha0)`, `b = 1 / sin^2(alpha0)`, `chi = 1 - L/L0`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tondu {
    /// Braid radius at rest [m].
    pub r0_m: f64,
    /// Initial braid angle [rad].
    pub alpha0_rad: f64,
    /// End-effect factor k.
    pub k: f64,
}

impl Tondu {
    /// Unclamped force [N] ([`TonduLaw`], the plant's law, at contraction 1 - stretch).
    pub fn eval(&self, p_gauge_pa: f64, stretch: f64) -> f64 {
        TonduLaw::new(self.r0_m, self.alpha0_rad, self.k)
            .force_unclamped_n(p_gauge_pa, 1.0 - stretch)
    }

    /// Force [N] clamped at 0 (a muscle cannot push).
    pub fn force_n(&self, p_gauge_pa: f64, stretch: f64) -> f64 {
        self.eval(p_gauge_pa, stretch).max(0.0)
    }
}

/// Error statistics of a model over a data set.
#[derive(Clone, Debug, PartialEq)]
pub struct ErrorStats {
    /// Mean absolute error [N].
    pub mae_n: f64,
    /// Mean absolute error as a percentage of the measured force range.
    pub mae_pct_of_range: f64,
    /// Root-mean-square error [N].
    pub rmse_n: f64,
    /// Largest absolute error [N].
    pub max_abs_n: f64,
    /// Where the largest error is: (gauge pressure [kPa], L/L0).
    pub max_at: (f64, f64),
    /// The pressure/stretch region (thirds of each range) with the largest mean error.
    pub worst_region: String,
    /// Mean absolute error in that region [N].
    pub worst_region_mae_n: f64,
}

/// Computes [`ErrorStats`] of `model` against `samples`.
pub fn error_stats(samples: &[ForceSample], model: impl Fn(f64, f64) -> f64) -> ErrorStats {
    let n = samples.len().max(1) as f64;
    let (mut fmin, mut fmax) = (f64::INFINITY, f64::NEG_INFINITY);
    let (mut pmin, mut pmax) = (f64::INFINITY, f64::NEG_INFINITY);
    let (mut emin, mut emax) = (f64::INFINITY, f64::NEG_INFINITY);
    for s in samples {
        fmin = fmin.min(s.force_n);
        fmax = fmax.max(s.force_n);
        pmin = pmin.min(s.p_gauge_pa);
        pmax = pmax.max(s.p_gauge_pa);
        emin = emin.min(s.stretch);
        emax = emax.max(s.stretch);
    }
    let third = |x: f64, lo: f64, hi: f64| -> usize {
        if hi <= lo {
            0
        } else {
            (((x - lo) / (hi - lo)) * 3.0).floor().clamp(0.0, 2.0) as usize
        }
    };
    let mut sum_abs = 0.0;
    let mut sum_sq = 0.0;
    let mut max_abs = 0.0;
    let mut max_at = (0.0, 0.0);
    let mut regions = [[(0.0f64, 0usize); 3]; 3];
    for s in samples {
        let err = (model(s.p_gauge_pa, s.stretch) - s.force_n).abs();
        sum_abs += err;
        sum_sq += err * err;
        if err > max_abs {
            max_abs = err;
            max_at = (s.p_gauge_pa / 1e3, s.stretch);
        }
        let r = &mut regions[third(s.p_gauge_pa, pmin, pmax)][third(s.stretch, emin, emax)];
        r.0 += err;
        r.1 += 1;
    }
    let p_names = ["low pressure", "mid pressure", "high pressure"];
    let e_names = [
        "short (contracted)",
        "mid stretch",
        "long (near/above rest length)",
    ];
    let mut worst = (0usize, 0usize, -1.0f64);
    for (i, row) in regions.iter().enumerate() {
        for (j, &(sum, count)) in row.iter().enumerate() {
            if count > 0 && sum / count as f64 > worst.2 {
                worst = (i, j, sum / count as f64);
            }
        }
    }
    let range = (fmax - fmin).max(f64::MIN_POSITIVE);
    let p_third = (pmax - pmin) / 3.0;
    let e_third = (emax - emin) / 3.0;
    ErrorStats {
        mae_n: sum_abs / n,
        mae_pct_of_range: 100.0 * sum_abs / n / range,
        rmse_n: (sum_sq / n).sqrt(),
        max_abs_n: max_abs,
        max_at,
        worst_region: format!(
            "{}, {} (P {:.0}..{:.0} kPa, L/L0 {:.3}..{:.3})",
            p_names[worst.0],
            e_names[worst.1],
            (pmin + worst.0 as f64 * p_third) / 1e3,
            (pmin + (worst.0 + 1) as f64 * p_third) / 1e3,
            emin + worst.1 as f64 * e_third,
            emin + (worst.1 + 1) as f64 * e_third,
        ),
        worst_region_mae_n: worst.2.max(0.0),
    }
}

// ---------------------------------------------------------------------------------------
// Eq. 6: the law the firmware evaluates, F = max(eq. 6, 0), fitted by variable projection over
// c7 from many starts, each polished by Levenberg-Marquardt.
//
// Objective: a sample with a positive force counts with (eq. 6 - F)^2 (the firmware's error
// there is never larger); a slack sample (F <= 0: the muscle did not pull) counts only where
// the law would pull, with (max(eq. 6, 0) - F)^2. A law that is negative over the slack
// region is clamped to 0 N by the firmware and so matches it exactly.

/// True for a slack reading (the muscle did not pull).
fn is_slack(s: &ForceSample) -> bool {
    !(s.force_n > 0.0)
}

/// The residual of one sample under the objective above.
fn eq6_residual(f: f64, s: &ForceSample) -> f64 {
    if is_slack(s) {
        f.max(0.0) - s.force_n
    } else {
        f - s.force_n
    }
}

/// Sum of squared residuals of `eq` under the firmware-law objective.
pub fn eq6_cost(eq: &Eq6, samples: &[ForceSample]) -> f64 {
    samples
        .iter()
        .map(|s| eq6_residual(eq.eval(s.p_gauge_pa, s.stretch), s).powi(2))
        .sum()
}

/// Basis functions of eq. 6 for a fixed c7 (c8 = 1): the model is
/// `sum_j theta_j * phi_j(P, e)` with theta = (c1..c6, c9, c10).
fn eq6_basis(c7: f64, p_mpa: f64, e: f64) -> [f64; 8] {
    let d = c7 * p_mpa + e;
    [
        p_mpa * p_mpa / d,
        e * e / d,
        p_mpa / d,
        e / d,
        p_mpa / e / d,
        1.0 / d,
        1.0,
        (e - 0.7).exp(),
    ]
}

/// Linear least squares of eq. 6 for a fixed c7 over the samples marked active.
fn eq6_solve(samples: &[ForceSample], active: &[bool], c7: f64) -> Option<Eq6> {
    let rows: Vec<&ForceSample> = samples
        .iter()
        .zip(active)
        .filter(|(_, a)| **a)
        .map(|(s, _)| s)
        .collect();
    if rows.len() < 8 {
        return None;
    }
    let m = rows.len();
    let mut a = DMatrix::<f64>::zeros(m, 8);
    let mut y = DVector::<f64>::zeros(m);
    for (i, s) in rows.iter().enumerate() {
        let b = eq6_basis(c7, s.p_gauge_pa * 1e-6, s.stretch);
        for (j, v) in b.iter().enumerate() {
            a[(i, j)] = *v;
        }
        y[i] = s.force_n;
    }
    // Column scaling keeps the SVD well conditioned (the basis spans many decades).
    let mut scale = [1.0; 8];
    for (j, sc) in scale.iter_mut().enumerate() {
        let norm = a.column(j).norm();
        if norm > 0.0 {
            *sc = norm;
            a.column_mut(j).scale_mut(1.0 / norm);
        }
    }
    let svd = a.svd(true, true);
    let theta = svd.solve(&y, 1e-12).ok()?;
    let t: Vec<f64> = theta.iter().zip(scale.iter()).map(|(t, s)| t / s).collect();
    let eq = Eq6 {
        c: [t[0], t[1], t[2], t[3], t[4], t[5], c7, 1.0, t[6], t[7]],
    };
    eq.c.iter().all(|v| v.is_finite()).then_some(eq)
}

/// Variable projection at a fixed c7: the positive samples, plus the slack samples where the
/// law pulls (an active set that grows until no slack sample is violated, or 8 rounds).
/// Returns (constants, firmware-law cost).
fn eq6_linear(samples: &[ForceSample], c7: f64) -> Option<(Eq6, f64)> {
    let mut active: Vec<bool> = samples.iter().map(|s| !is_slack(s)).collect();
    let mut best: Option<(Eq6, f64)> = None;
    for _ in 0..8 {
        let Some(eq) = eq6_solve(samples, &active, c7) else {
            break;
        };
        let cost = eq6_cost(&eq, samples);
        if cost.is_finite() && best.as_ref().is_none_or(|b| cost < b.1) {
            best = Some((eq, cost));
        }
        let mut grew = false;
        for (s, a) in samples.iter().zip(active.iter_mut()) {
            if !*a && eq.eval(s.p_gauge_pa, s.stretch) > 0.0 {
                *a = true;
                grew = true;
            }
        }
        if !grew {
            break;
        }
    }
    best
}

/// Lowest c7 for which the denominator `c7 P + e` stays positive (with margin) over the
/// whole domain the law is written with: every pressure up to the data's highest at every
/// deformation from the data's lowest (the firmware's control tick refuses a law singular
/// anywhere on its domain, `ForceLawParams::is_regular`). `c7 P + e` is linear, so the
/// corner (highest pressure, lowest deformation) decides.
fn c7_lower_bound(samples: &[ForceSample]) -> f64 {
    let p_max = samples
        .iter()
        .map(|s| s.p_gauge_pa * 1e-6)
        .fold(f64::NEG_INFINITY, f64::max);
    let e_min = samples
        .iter()
        .map(|s| s.stretch)
        .fold(f64::INFINITY, f64::min);
    // c7 P + e > 0.05 e  <=>  c7 > -0.95 e / P
    let lb = -0.95 * e_min / p_max;
    if p_max > 1e-9 && lb.is_finite() {
        lb
    } else {
        -1.0
    }
}

/// Levenberg-Marquardt problem of all nine free constants; c7 = lb + exp(u) keeps the
/// denominator positive over the data's domain box ([`c7_lower_bound`]).
/// Its parameters are (c1..c6, u, c9, c10).
struct Eq6Problem<'a> {
    samples: &'a [ForceSample],
    c7_lb: f64,
}

impl Eq6Problem<'_> {
    fn eq6(&self, x: &DVector<f64>) -> Eq6 {
        Eq6 {
            c: [
                x[0],
                x[1],
                x[2],
                x[3],
                x[4],
                x[5],
                self.c7_lb + x[6].exp(),
                1.0,
                x[7],
                x[8],
            ],
        }
    }
}

impl LmResiduals for Eq6Problem<'_> {
    fn residuals_at(&self, x: &DVector<f64>) -> Option<DVector<f64>> {
        let m = self.eq6(x);
        let r = DVector::from_iterator(
            self.samples.len(),
            self.samples
                .iter()
                .map(|s| eq6_residual(m.eval(s.p_gauge_pa, s.stretch), s)),
        );
        r.iter().all(|v| v.is_finite()).then_some(r)
    }

    fn jacobian_at(&self, x: &DVector<f64>, _r: &DVector<f64>) -> Option<DMatrix<f64>> {
        let m = self.eq6(x);
        let c = &m.c;
        let mut j = DMatrix::<f64>::zeros(self.samples.len(), 9);
        for (i, s) in self.samples.iter().enumerate() {
            let p = s.p_gauge_pa * 1e-6;
            let e = s.stretch;
            if is_slack(s) && m.eval(s.p_gauge_pa, e) <= 0.0 {
                continue; // clamped: no gradient
            }
            let d = c[6] * p + e;
            let num = c[0] * p * p + c[1] * e * e + c[2] * p + c[3] * e + c[4] * p / e + c[5];
            let basis = [p * p, e * e, p, e, p / e, 1.0];
            for (k, b) in basis.iter().enumerate() {
                j[(i, k)] = b / d;
            }
            j[(i, 6)] = -num * p / (d * d) * (c[6] - self.c7_lb);
            j[(i, 7)] = 1.0;
            j[(i, 8)] = (e - 0.7).exp();
        }
        j.iter().all(|v| v.is_finite()).then_some(j)
    }
}

/// LM polish of a start; returns the better of the start and the polished law.
fn eq6_polish(samples: &[ForceSample], c7_lb: f64, start: Eq6, cost0: f64) -> (Eq6, f64) {
    let c = start.c;
    let u = (c[6] - c7_lb).max(1e-12).ln();
    let x0 = DVector::from_vec(vec![c[0], c[1], c[2], c[3], c[4], c[5], u, c[8], c[9]]);
    let problem = LmProblem::new(Eq6Problem { samples, c7_lb }, x0);
    let (lm, _report) = LevenbergMarquardt::new()
        .with_patience(100)
        .minimize(problem);
    let polished = lm.problem.eq6(&lm.x);
    let cost1 = eq6_cost(&polished, samples);
    if cost1.is_finite() && cost1 < cost0 && polished.c.iter().all(|v| v.is_finite()) {
        (polished, cost1)
    } else {
        (start, cost0)
    }
}

/// Result of the multi-start fit of eq. 6.
#[derive(Clone, Debug, PartialEq)]
pub struct Eq6Fit {
    /// The best law found.
    pub eq6: Eq6,
    /// Its cost (sum of squared residuals of the firmware law) [N^2].
    pub cost_n2: f64,
    /// Number of starts run.
    pub starts: usize,
    /// Number of starts whose polished cost is within 0.01 % of the best.
    pub starts_at_best: usize,
}

/// Number of c7 starts of a full fit.
pub const EQ6_STARTS: usize = 24;

/// Starting values of c7: log-spaced above the lower bound, plus the hints (when feasible).
fn c7_starts(lb: f64, n: usize, hints: &[f64]) -> Vec<f64> {
    let mut v: Vec<f64> = (0..n)
        .map(|k| {
            let t = if n > 1 {
                k as f64 / (n - 1) as f64
            } else {
                0.5
            };
            lb + 10f64.powf(-3.0 + 5.0 * t)
        })
        .collect();
    v.extend(hints.iter().copied().filter(|&h| h.is_finite() && h > lb));
    v
}

/// Checks that the samples can support eq. 6 at all.
fn eq6_data_check(samples: &[ForceSample]) -> Result<(), IdentError> {
    if samples.len() < 20 {
        return Err(IdentError::Data(format!(
            "eq. 6 has 9 free constants: need at least 20 samples, got {}",
            samples.len()
        )));
    }
    let positive = samples.iter().filter(|s| !is_slack(s)).count();
    if positive < 10 {
        return Err(IdentError::Data(format!(
            "eq. 6 has 9 free constants: need at least 10 samples with a positive force, got {positive}"
        )));
    }
    Ok(())
}

/// Fits F = max(eq. 6, 0) (c8 = 1) from `n_starts` log-spaced c7 starts plus `c7_hints`.
/// Deterministic.
pub fn fit_eq6_multistart(
    samples: &[ForceSample],
    n_starts: usize,
    c7_hints: &[f64],
) -> Result<Eq6Fit, IdentError> {
    eq6_data_check(samples)?;
    let lb = c7_lower_bound(samples);
    let mut results: Vec<(Eq6, f64)> = Vec::new();
    for c7 in c7_starts(lb, n_starts, c7_hints) {
        if let Some((start, cost0)) = eq6_linear(samples, c7) {
            results.push(eq6_polish(samples, lb, start, cost0));
        }
    }
    let best = results
        .iter()
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .cloned()
        .ok_or_else(|| IdentError::Data("eq. 6: no start gave a solvable fit".into()))?;
    let tol = best.1 * 1e-4 + 1e-9;
    Ok(Eq6Fit {
        eq6: best.0,
        cost_n2: best.1,
        starts: results.len(),
        starts_at_best: results.iter().filter(|r| r.1 <= best.1 + tol).count(),
    })
}

/// Fits F = max(eq. 6, 0) (c8 = 1) to the samples ([`EQ6_STARTS`] starts). Deterministic.
pub fn fit_eq6(samples: &[ForceSample]) -> Result<Eq6, IdentError> {
    fit_eq6_multistart(samples, EQ6_STARTS, &[]).map(|f| f.eq6)
}

// ---------------------------------------------------------------------------------------
// Held-out error: leave-one-length-out and leave-one-pressure-out.

/// Error of eq. 6 on data it was not fitted to.
#[derive(Clone, Debug, PartialEq)]
pub struct HeldOut {
    /// What was held out ("length", "pressure level").
    pub what: &'static str,
    /// Distinct groups (lengths or pressure levels) in the data.
    pub groups: usize,
    /// Folds (groups are assigned to folds in turn when there are more than 10).
    pub folds: usize,
    /// Mean absolute error of the held-out predictions (firmware law) [N].
    pub mae_n: f64,
    /// The same as a percentage of the data's force range.
    pub mae_pct_of_range: f64,
}

/// Group index of each sample by length: cells of [`POINT_CELL_STRETCH`] in L/L0, the
/// resolution operating points are told apart on (a length sensor's jitter about one
/// length of a sweep keeps it one length).
pub fn length_groups(samples: &[ForceSample]) -> (Vec<usize>, usize) {
    let mut keys: Vec<i64> = samples.iter().map(|s| length_cell(s.stretch)).collect();
    let mut uniq = keys.clone();
    uniq.sort_unstable();
    uniq.dedup();
    for k in keys.iter_mut() {
        *k = uniq.binary_search(k).unwrap() as i64;
    }
    (keys.into_iter().map(|k| k as usize).collect(), uniq.len())
}

/// The largest mean error of eq. 6 on its own map [% of the force range] from which a law
/// is written: a map it fits worse is not a muscle's (shuffled forces fit at 17.7 %).
pub const MAX_EQ6_MAE_PCT_OF_RANGE: f64 = 10.0;

/// Group index of each sample by pressure level: sorted pressures split where the gap
/// exceeds 30 % of the largest gap (sensor noise spreads each nominal level).
pub fn pressure_groups(samples: &[ForceSample]) -> (Vec<usize>, usize) {
    let mut idx: Vec<usize> = (0..samples.len()).collect();
    idx.sort_by(|&a, &b| samples[a].p_gauge_pa.total_cmp(&samples[b].p_gauge_pa));
    let gaps: Vec<f64> = idx
        .windows(2)
        .map(|w| samples[w[1]].p_gauge_pa - samples[w[0]].p_gauge_pa)
        .collect();
    let max_gap = gaps.iter().cloned().fold(0.0, f64::max);
    let mut out = vec![0usize; samples.len()];
    let mut g = 0;
    for (k, &i) in idx.iter().enumerate() {
        if k > 0 && gaps[k - 1] > 0.3 * max_gap && max_gap > 0.0 {
            g += 1;
        }
        out[i] = g;
    }
    (out, g + 1)
}

/// Fits eq. 6 with each fold of groups left out and scores it on the left-out samples.
/// None when there are fewer than 3 groups.
pub fn held_out_error(
    samples: &[ForceSample],
    what: &'static str,
    (groups, n_groups): (Vec<usize>, usize),
    c7_hint: f64,
) -> Option<HeldOut> {
    if n_groups < 3 {
        return None;
    }
    let folds = n_groups.min(10);
    let (fmin, fmax) = samples
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), s| {
            (a.min(s.force_n), b.max(s.force_n))
        });
    let range = (fmax - fmin).max(f64::MIN_POSITIVE);
    let mut sum = 0.0;
    let mut n = 0usize;
    for fold in 0..folds {
        let train: Vec<ForceSample> = samples
            .iter()
            .zip(&groups)
            .filter(|(_, g)| **g % folds != fold)
            .map(|(s, _)| *s)
            .collect();
        let Ok(fit) = fit_eq6_multistart(&train, 6, &[c7_hint]) else {
            continue;
        };
        for (s, g) in samples.iter().zip(&groups) {
            if *g % folds == fold {
                sum += (fit.eq6.force_n(s.p_gauge_pa, s.stretch) - s.force_n).abs();
                n += 1;
            }
        }
    }
    (n > 0).then(|| HeldOut {
        what,
        groups: n_groups,
        folds,
        mae_n: sum / n as f64,
        mae_pct_of_range: 100.0 * sum / n as f64 / range,
    })
}

// ---------------------------------------------------------------------------------------
// Physical baselines, fitted with bounds.

/// Chou-Hannaford-type law with Tondu's end effect and a slack threshold pressure:
/// `F = max(0, pi r0^2 (P - p_th) (a (1 - k chi)^2 - b))`, a, b, chi as in [`Tondu`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChouHannaford {
    /// Braid radius at rest [m].
    pub r0_m: f64,
    /// Initial braid angle [rad].
    pub alpha0_rad: f64,
    /// End-effect factor k.
    pub k: f64,
    /// Gauge pressure below which the muscle is slack [Pa].
    pub p_threshold_pa: f64,
}

impl ChouHannaford {
    /// Force [N] clamped at 0.
    pub fn force_n(&self, p_gauge_pa: f64, stretch: f64) -> f64 {
        if p_gauge_pa <= self.p_threshold_pa {
            return 0.0;
        }
        Tondu {
            r0_m: self.r0_m,
            alpha0_rad: self.alpha0_rad,
            k: self.k,
        }
        .force_n(p_gauge_pa - self.p_threshold_pa, stretch)
    }
}

/// Least squares of a clamped physical model in bounded parameters: x = lo + (hi - lo) (1 +
/// tanh z) / 2, Levenberg-Marquardt on z with a central-difference Jacobian.
struct BoundedProblem<'a> {
    samples: &'a [ForceSample],
    lo: &'a [f64],
    hi: &'a [f64],
    model: &'a dyn Fn(&[f64], f64, f64) -> f64,
}

impl BoundedProblem<'_> {
    fn x_of(&self, z: &DVector<f64>) -> Vec<f64> {
        z.iter()
            .enumerate()
            .map(|(i, z)| self.lo[i] + (self.hi[i] - self.lo[i]) * 0.5 * (1.0 + z.tanh()))
            .collect()
    }
    fn z_of(lo: &[f64], hi: &[f64], x: &[f64]) -> DVector<f64> {
        DVector::from_iterator(
            x.len(),
            x.iter().enumerate().map(|(i, x)| {
                let t = (2.0 * (x - lo[i]) / (hi[i] - lo[i]) - 1.0).clamp(-0.999, 0.999);
                t.atanh()
            }),
        )
    }
    fn residuals_of(&self, z: &DVector<f64>) -> DVector<f64> {
        let x = self.x_of(z);
        DVector::from_iterator(
            self.samples.len(),
            self.samples
                .iter()
                .map(|s| (self.model)(&x, s.p_gauge_pa, s.stretch).max(0.0) - s.force_n),
        )
    }
}

impl LmResiduals for BoundedProblem<'_> {
    fn residuals_at(&self, z: &DVector<f64>) -> Option<DVector<f64>> {
        let r = self.residuals_of(z);
        r.iter().all(|v| v.is_finite()).then_some(r)
    }

    fn jacobian_at(&self, z: &DVector<f64>, _r: &DVector<f64>) -> Option<DMatrix<f64>> {
        let n = self.samples.len();
        let mut j = DMatrix::<f64>::zeros(n, z.len());
        for k in 0..z.len() {
            let h = 1e-6;
            let mut zp = z.clone();
            let mut zm = z.clone();
            zp[k] += h;
            zm[k] -= h;
            let d = (self.residuals_of(&zp) - self.residuals_of(&zm)) / (2.0 * h);
            j.set_column(k, &d);
        }
        j.iter().all(|v| v.is_finite()).then_some(j)
    }
}

/// Fits the baseline `name` (at least `min_samples` samples), the model `of_x(x)` whose force
/// is `force_n(model, p, L/L0)` clamped at 0, within `bounds` from every start; returns the
/// best.
fn fit_bounded<M, const N: usize>(
    name: &str,
    min_samples: usize,
    samples: &[ForceSample],
    bounds: &([f64; N], [f64; N]),
    starts: &[Vec<f64>],
    of_x: fn(&[f64]) -> M,
    force_n: fn(&M, f64, f64) -> f64,
) -> Result<M, IdentError> {
    if samples.len() < min_samples {
        return Err(IdentError::Data(format!(
            "{name}: need at least {min_samples} samples"
        )));
    }
    let (lo, hi) = (&bounds.0[..], &bounds.1[..]);
    let model = |x: &[f64], p: f64, e: f64| force_n(&of_x(x), p, e);
    let model: &dyn Fn(&[f64], f64, f64) -> f64 = &model;
    let mut best: Option<(Vec<f64>, f64)> = None;
    for x0 in starts {
        let problem = BoundedProblem {
            samples,
            lo,
            hi,
            model,
        };
        let z0 = BoundedProblem::z_of(lo, hi, x0);
        let (lm, _) = LevenbergMarquardt::new()
            .with_patience(100)
            .minimize(LmProblem::new(problem, z0));
        let cost = lm.problem.residuals_of(&lm.x).norm_squared();
        if cost.is_finite() && best.as_ref().is_none_or(|b| cost < b.1) {
            best = Some((lm.problem.x_of(&lm.x), cost));
        }
    }
    best.map(|(x, _)| of_x(&x))
        .ok_or_else(|| IdentError::Data(format!("{name}: no start converged")))
}

/// Bounds of the Tondu baseline: r0 [mm], alpha0 [deg], k.
pub const TONDU_BOUNDS: ([f64; 3], [f64; 3]) = ([1.0, 10.0, 0.5], [40.0, 50.0, 3.0]);
/// Bounds of the Chou-Hannaford baseline: r0 [mm], alpha0 [deg], k, p_th [kPa].
pub const CHOU_HANNAFORD_BOUNDS: ([f64; 4], [f64; 4]) =
    ([1.0, 10.0, 0.5, 0.0], [40.0, 50.0, 3.0, 300.0]);

fn tondu_of_x(x: &[f64]) -> Tondu {
    Tondu {
        r0_m: x[0] * 1e-3,
        alpha0_rad: x[1].to_radians(),
        k: x[2],
    }
}

fn ch_of_x(x: &[f64]) -> ChouHannaford {
    ChouHannaford {
        r0_m: x[0] * 1e-3,
        alpha0_rad: x[1].to_radians(),
        k: x[2],
        p_threshold_pa: x[3] * 1e3,
    }
}

fn physical_starts(with_threshold: bool) -> Vec<Vec<f64>> {
    let mut v = Vec::new();
    for r0 in [5.0, 10.0, 18.0] {
        for a0 in [20.0, 28.0] {
            for k in [1.1, 1.5] {
                if with_threshold {
                    for p in [10.0, 60.0] {
                        v.push(vec![r0, a0, k, p]);
                    }
                } else {
                    v.push(vec![r0, a0, k]);
                }
            }
        }
    }
    v
}

/// Fits the Tondu model (r0, alpha0, k) within [`TONDU_BOUNDS`] from 12 starts.
pub fn fit_tondu(samples: &[ForceSample]) -> Result<Tondu, IdentError> {
    let starts = physical_starts(false);
    fit_bounded(
        "Tondu model",
        3,
        samples,
        &TONDU_BOUNDS,
        &starts,
        tondu_of_x,
        Tondu::eval,
    )
}

/// Fits the Chou-Hannaford-type baseline within [`CHOU_HANNAFORD_BOUNDS`] from 24 starts.
pub fn fit_chou_hannaford(samples: &[ForceSample]) -> Result<ChouHannaford, IdentError> {
    let starts = physical_starts(true);
    let bounds = &CHOU_HANNAFORD_BOUNDS;
    let force_n = ChouHannaford::force_n;
    fit_bounded(
        "Chou-Hannaford model",
        4,
        samples,
        bounds,
        &starts,
        ch_of_x,
        force_n,
    )
}

/// True when a fitted parameter sits on a bound (within 0.1 % of the range).
fn at_bound(x: f64, lo: f64, hi: f64) -> bool {
    let tol = 1e-3 * (hi - lo);
    x <= lo + tol || x >= hi - tol
}

// ---------------------------------------------------------------------------------------
// Whole identification run.

/// Hysteresis between the two branches of the sweeps.
#[derive(Clone, Debug, PartialEq)]
pub struct Hysteresis {
    /// Mean |F_pressurising - F_depressurising| over the data's (P, e) points where either
    /// branch pulls [N], from an eq. 6 law fitted to each branch.
    pub gap_mean_n: f64,
    /// Largest gap [N].
    pub gap_max_n: f64,
    /// Samples on each branch.
    pub samples: (usize, usize),
    /// The law fitted to the pressurising branch, with its error on that branch.
    pub rising: (Eq6Fit, ErrorStats),
    /// The law fitted to the depressurising branch, with its error on that branch.
    pub falling: (Eq6Fit, ErrorStats),
}

/// Everything `identify force` produces.
#[derive(Clone, Debug)]
pub struct ForceIdentification {
    /// Eq. 6 fitted to all samples (the mid-curve when both branches are present).
    pub eq6: Eq6,
    /// The global search behind it.
    pub eq6_fit: Eq6Fit,
    /// Its errors on the data.
    pub eq6_stats: ErrorStats,
    /// Its error on lengths left out of the fit.
    pub leave_length_out: Option<HeldOut>,
    /// Its error on pressure levels left out of the fit.
    pub leave_pressure_out: Option<HeldOut>,
    /// Tondu baseline.
    pub tondu: Tondu,
    /// Its errors on the data.
    pub tondu_stats: ErrorStats,
    /// Chou-Hannaford-type baseline (end effect and slack threshold).
    pub chou_hannaford: ChouHannaford,
    /// Its errors on the data.
    pub chou_hannaford_stats: ErrorStats,
    /// Branch gap, when the data has a branch column with both branches.
    pub hysteresis: Option<Hysteresis>,
    /// Domain of the data: (max gauge pressure [Pa], min stretch, max stretch).
    pub domain: (f64, f64, f64),
    /// Number of samples.
    pub n_samples: usize,
    /// Number of slack samples (F <= 0).
    pub n_slack: usize,
    /// Warnings (over-fitting, baselines on their bounds).
    pub warnings: Vec<String>,
}

/// Refuses data eq. 6 cannot be identified from: too few samples, no positive force, a
/// single length.
fn check_map(samples: &[ForceSample]) -> Result<(), IdentError> {
    if samples.len() < 20 {
        return eq6_data_check(samples);
    }
    if !samples.iter().any(|s| s.force_n > 0.0) {
        return Err(IdentError::Data(format!(
            "no sample has a positive force (all {} readings <= 0 N): the muscle never pulled, \
             nothing to identify",
            samples.len()
        )));
    }
    let (groups, n_lengths) = length_groups(samples);
    if n_lengths < 3 {
        // Each length once, in the groups' (ascending) order.
        let listed: Vec<String> = (0..n_lengths)
            .filter_map(|g| groups.iter().position(|&k| k == g))
            .map(|i| format!("{:.4}", samples[i].stretch))
            .collect();
        let (at, these) = if n_lengths == 1 {
            (
                format!("all samples are at one length (L/L0 = {})", listed[0]),
                "one length",
            )
        } else {
            (
                format!(
                    "the samples are at 2 lengths only (L/L0 = {})",
                    listed.join(", ")
                ),
                "2 lengths",
            )
        };
        return Err(IdentError::Data(format!(
            "{at}: eq. 6 depends on the length through five terms (e^2, e, P/e, the \
             denominator's e, the exponential), which {these} cannot tell apart (a law fitted \
             on 2 lengths fits them and misses between them); sweep at least 3 lengths (more \
             for the leave-one-length-out check)"
        )));
    }
    let (_, n_levels) = pressure_groups(samples);
    if n_levels < 2 {
        return Err(IdentError::Data(
            "all samples are at one pressure: eq. 6 needs at least 2 pressure levels".into(),
        ));
    }
    // Repeats of one operating point average its noise but add no equation: points are
    // told apart on cells of the length and pressure resolution a sweep steps by (a length
    // sensor's jitter or a pressure's noise does not make a repeat a new point).
    let mut points: Vec<(i64, i64)> = samples
        .iter()
        .map(|s| {
            (
                length_cell(s.stretch),
                (s.p_gauge_pa / POINT_CELL_PA).round() as i64,
            )
        })
        .collect();
    points.sort_unstable();
    points.dedup();
    if points.len() < MIN_FORCE_MAP_POINTS {
        let mut rows: Vec<[u64; 3]> = samples
            .iter()
            .map(|s| [s.p_gauge_pa, s.stretch, s.force_n].map(f64::to_bits))
            .collect();
        rows.sort_unstable();
        rows.dedup();
        let copies = samples.len() - rows.len();
        let copies = if copies > 0 {
            format!(
                ", {copies} of them exact copies of another row (a logger writing a sample twice?)"
            )
        } else {
            String::new()
        };
        return Err(IdentError::Data(format!(
            "the {} samples hold {} distinct operating points (0.005 L/L0 x 5 kPa cells){copies}: \
             eq. 6 has 9 free constants and needs at least {MIN_FORCE_MAP_POINTS} distinct \
             points; repeats of a point average its noise but add no equation. Sweep more \
             pressure levels or lengths",
            samples.len(),
            points.len()
        )));
    }
    eq6_data_check(samples)
}

/// Distinct operating points (length x pressure cells of [`POINT_CELL_STRETCH`] and
/// [`POINT_CELL_PA`]) a force map needs for eq. 6's 9 free constants: as many as samples
/// ([`eq6_data_check`]), repeats not counted.
pub const MIN_FORCE_MAP_POINTS: usize = 20;

/// The length cell [L/L0] two samples of one operating point share: 0.5 % of the rest
/// length, well above a length sensor's jitter and below the steps of a length sweep.
pub const POINT_CELL_STRETCH: f64 = 0.005;

/// The length cell of a stretch L/L0 ([`POINT_CELL_STRETCH`] wide).
fn length_cell(stretch: f64) -> i64 {
    (stretch / POINT_CELL_STRETCH).round() as i64
}

/// The pressure cell [Pa] of one operating point: 5 kPa, above a pressure sensor's noise and
/// below the steps of a pressure sweep.
pub const POINT_CELL_PA: f64 = 5e3;

/// Fits eq. 6 (multi-start, firmware law), its held-out errors, the two physical baselines and
/// (when the data has both branches) one law per branch. Steps: eq. 6 fitted and checked to
/// describe the map, its held-out errors, the baselines, the warnings, the branches.
pub fn identify(samples: &[ForceSample]) -> Result<ForceIdentification, IdentError> {
    check_map(samples)?;
    let eq6_fit = fit_eq6_multistart(samples, EQ6_STARTS, &[])?;
    let eq6 = eq6_fit.eq6;
    let eq6_stats = error_stats(samples, |p, e| eq6.force_n(p, e));
    check_eq6_describes(&eq6_stats)?;
    let leave_length_out = held_out_error(samples, "length", length_groups(samples), eq6.c[6]);
    let leave_pressure_out = held_out_error(
        samples,
        "pressure level",
        pressure_groups(samples),
        eq6.c[6],
    );
    let tondu = fit_tondu(samples)?;
    let tondu_stats = error_stats(samples, |p, e| tondu.force_n(p, e));
    let chou_hannaford = fit_chou_hannaford(samples)?;
    let chou_hannaford_stats = error_stats(samples, |p, e| chou_hannaford.force_n(p, e));
    let mut warnings = overfit_warnings(&[&leave_length_out, &leave_pressure_out], &eq6_stats);
    warnings.extend(baseline_bound_warnings(&tondu, &chou_hannaford));
    warnings.extend(absolute_pressure_warning(samples, &chou_hannaford));
    let hysteresis = fit_hysteresis(samples, eq6.c[6])?;
    let pmax = samples
        .iter()
        .map(|s| s.p_gauge_pa)
        .fold(f64::NEG_INFINITY, f64::max);
    let emin = samples
        .iter()
        .map(|s| s.stretch)
        .fold(f64::INFINITY, f64::min);
    let emax = samples
        .iter()
        .map(|s| s.stretch)
        .fold(f64::NEG_INFINITY, f64::max);
    Ok(ForceIdentification {
        eq6,
        eq6_fit,
        eq6_stats,
        leave_length_out,
        leave_pressure_out,
        tondu,
        tondu_stats,
        chou_hannaford,
        chou_hannaford_stats,
        hysteresis,
        domain: (pmax, emin, emax),
        n_samples: samples.len(),
        n_slack: samples.iter().filter(|s| is_slack(s)).count(),
        warnings,
    })
}

/// A map eq. 6 does not describe (a column of another quantity, rows mixed up) is refused:
/// the law would be written and clamp the firmware's torque estimate to nonsense.
fn check_eq6_describes(eq6_stats: &ErrorStats) -> Result<(), IdentError> {
    if !(eq6_stats.mae_pct_of_range <= MAX_EQ6_MAE_PCT_OF_RANGE) {
        return Err(IdentError::Data(format!(
            "eq. 6 does not describe this map: its best fit errs by {:.1} % of the force range \
             on average (MAE {:.1} N; a bench map fits within a few %, the reference sweep \
             0.7 %; {MAX_EQ6_MAE_PCT_OF_RANGE} % is the limit): a column mapped to the wrong \
             quantity, rows mixed up, or forces of another muscle; nothing written",
            eq6_stats.mae_pct_of_range, eq6_stats.mae_n
        )));
    }
    Ok(())
}

/// A warning per held-out error more than twice the fitted data's: eq. 6 likely over-fitted.
fn overfit_warnings(held: &[&Option<HeldOut>], eq6_stats: &ErrorStats) -> Vec<String> {
    let mut warnings = Vec::new();
    for h in held.iter().copied().flatten() {
        if h.mae_n > 2.0 * eq6_stats.mae_n {
            warnings.push(format!(
                "eq. 6 errs {:.2}x more on held-out {}s ({:.3} % of range) than on the fitted \
                 data ({:.3} %): likely over-fitted, use it only inside the measured grid",
                h.mae_n / eq6_stats.mae_n.max(f64::MIN_POSITIVE),
                h.what,
                h.mae_pct_of_range,
                eq6_stats.mae_pct_of_range
            ));
        }
    }
    warnings
}

/// A warning per baseline parameter on its bound (the Chou-Hannaford threshold left out);
/// the Tondu radius pinned at an end names the force unit it suggests.
fn baseline_bound_warnings(tondu: &Tondu, chou_hannaford: &ChouHannaford) -> Vec<String> {
    let mut warnings = Vec::new();
    let tx = [tondu.r0_m * 1e3, tondu.alpha0_rad.to_degrees(), tondu.k];
    let cx = [
        chou_hannaford.r0_m * 1e3,
        chou_hannaford.alpha0_rad.to_degrees(),
        chou_hannaford.k,
        chou_hannaford.p_threshold_pa / 1e3,
    ];
    let names = ["r0 [mm]", "alpha0 [deg]", "k", "p_th [kPa]"];
    for (i, x) in tx.iter().enumerate() {
        if at_bound(*x, TONDU_BOUNDS.0[i], TONDU_BOUNDS.1[i]) {
            // The radius scales the force: pinned at an end, the forces are likely off by a
            // unit.
            let unit_hint = match i {
                0 if *x <= TONDU_BOUNDS.0[0] * 1.001 => {
                    " (forces this small for their pressures: f_n in kN instead of N?)"
                }
                0 => " (forces this large for their pressures: f_n in mN instead of N?)",
                _ => "",
            };
            warnings.push(format!(
                "Tondu baseline: {} = {x:.6} is on its bound {}..{}{unit_hint}",
                names[i], TONDU_BOUNDS.0[i], TONDU_BOUNDS.1[i]
            ));
        }
    }
    for (i, x) in cx.iter().enumerate() {
        if at_bound(*x, CHOU_HANNAFORD_BOUNDS.0[i], CHOU_HANNAFORD_BOUNDS.1[i]) && i != 3 {
            warnings.push(format!(
                "Chou-Hannaford baseline: {} = {x:.6} is on its bound {}..{}",
                names[i], CHOU_HANNAFORD_BOUNDS.0[i], CHOU_HANNAFORD_BOUNDS.1[i]
            ));
        }
    }
    warnings
}

/// Pressures logged absolute: no sample below one atmosphere, and the slack threshold the
/// Chou-Hannaford baseline finds is the atmosphere itself (a gauge-logged muscle goes taut
/// within some ten kPa). Eq. 6 would be written shifted by one atmosphere. The data carries
/// no atmosphere of its own: the standard one.
fn absolute_pressure_warning(
    samples: &[ForceSample],
    chou_hannaford: &ChouHannaford,
) -> Option<String> {
    let p_atm_pa = STANDARD_ATMOSPHERE_PA;
    let p_min_pa = samples
        .iter()
        .map(|s| s.p_gauge_pa)
        .fold(f64::INFINITY, f64::min);
    ((chou_hannaford.p_threshold_pa - p_atm_pa).abs() <= ABSOLUTE_THRESHOLD_WITHIN_PA
        && p_min_pa >= p_atm_pa - crate::io::import::P_ABSOLUTE_SUSPECT_WITHIN_PA)
        .then(|| {
            format!(
                "the muscle goes taut at p_th = {:.1} kPa, one atmosphere, and no pressure is \
                 below {:.1} kPa: {}",
                chou_hannaford.p_threshold_pa * 1e-3,
                p_min_pa * 1e-3,
                crate::io::import::ABSOLUTE_PRESSURE_HINT
            )
        })
}

/// With at least 20 samples on each branch: one eq. 6 law per branch (the exponent `c6`
/// of the whole map kept) and the gap between them over the taut samples.
fn fit_hysteresis(samples: &[ForceSample], c6: f64) -> Result<Option<Hysteresis>, IdentError> {
    let branch = |b: Branch| -> Vec<ForceSample> {
        samples
            .iter()
            .copied()
            .filter(|s| s.branch == Some(b))
            .collect()
    };
    let (up, down) = (branch(Branch::Pressurising), branch(Branch::Depressurising));
    if !(up.len() >= 20 && down.len() >= 20) {
        return Ok(None);
    }
    let mu = fit_eq6_multistart(&up, EQ6_STARTS, &[c6])?;
    let md = fit_eq6_multistart(&down, EQ6_STARTS, &[c6])?;
    let su = error_stats(&up, |p, e| mu.eq6.force_n(p, e));
    let sd = error_stats(&down, |p, e| md.eq6.force_n(p, e));
    let gaps: Vec<f64> = samples
        .iter()
        .filter_map(|s| {
            let (fu, fd) = (
                mu.eq6.force_n(s.p_gauge_pa, s.stretch),
                md.eq6.force_n(s.p_gauge_pa, s.stretch),
            );
            (fu > 0.0 || fd > 0.0).then_some((fu - fd).abs())
        })
        .collect();
    let n = gaps.len().max(1) as f64;
    Ok(Some(Hysteresis {
        gap_mean_n: gaps.iter().sum::<f64>() / n,
        gap_max_n: gaps.iter().cloned().fold(0.0, f64::max),
        samples: (up.len(), down.len()),
        rising: (mu, su),
        falling: (md, sd),
    }))
}

/// The two report lines of one model's errors.
fn stats_lines(name: &str, st: &ErrorStats) -> [String; 2] {
    [
        format!(
            "{name:<8} MAE {:8.3} N ({:6.3} % of range)  RMSE {:8.3} N  max {:8.3} N at {:.0} kPa, L/L0 {:.3}",
            st.mae_n, st.mae_pct_of_range, st.rmse_n, st.max_abs_n, st.max_at.0, st.max_at.1
        ),
        format!(
            "         largest mean error: {} ({:.3} N)",
            st.worst_region, st.worst_region_mae_n
        ),
    ]
}

impl ForceIdentification {
    /// The report lines shared by the summary and the TOML header (without a comment prefix).
    fn report_lines(&self) -> Vec<String> {
        let mut v = Vec::new();
        v.push(format!(
            "{} samples ({} slack, F <= 0), P up to {:.1} kPa, L/L0 {:.4}..{:.4}",
            self.n_samples,
            self.n_slack,
            self.domain.0 / 1e3,
            self.domain.1,
            self.domain.2
        ));
        v.extend(stats_lines("eq. 6", &self.eq6_stats));
        v.push(format!(
            "global search: {} of {} c7 starts reached the best cost {:.6e} N^2 (firmware law max(eq. 6, 0))",
            self.eq6_fit.starts_at_best, self.eq6_fit.starts, self.eq6_fit.cost_n2
        ));
        for h in [&self.leave_length_out, &self.leave_pressure_out]
            .into_iter()
            .flatten()
        {
            v.push(format!(
                "held out, one {} at a time ({} {}s, {} folds): MAE {:.3} N ({:.3} % of range) vs {:.3} N fitted ({:.2}x)",
                h.what,
                h.groups,
                h.what,
                h.folds,
                h.mae_n,
                h.mae_pct_of_range,
                self.eq6_stats.mae_n,
                h.mae_n / self.eq6_stats.mae_n.max(f64::MIN_POSITIVE)
            ));
        }
        if self.leave_length_out.is_none() {
            v.push("held out, one length at a time: fewer than 3 lengths, not assessed".into());
        }
        let c = &self.eq6.c;
        v.push(format!(
            "constants: c1 = {:.9e}, c2 = {:.9e}, c3 = {:.9e}, c4 = {:.9e}, c5 = {:.9e},",
            c[0], c[1], c[2], c[3], c[4]
        ));
        v.push(format!(
            "           c6 = {:.9e}, c7 = {:.9e}, c8 = {:.9e}, c9 = {:.9e}, c10 = {:.9e}",
            c[5], c[6], c[7], c[8], c[9]
        ));
        v.extend(stats_lines("Tondu", &self.tondu_stats));
        v.push(format!(
            "Tondu fit: r0 = {:.5} mm, alpha0 = {:.4} deg, k = {:.5} (bounds r0 {}..{} mm, alpha0 {}..{} deg, k {}..{})",
            self.tondu.r0_m * 1e3,
            self.tondu.alpha0_rad.to_degrees(),
            self.tondu.k,
            TONDU_BOUNDS.0[0],
            TONDU_BOUNDS.1[0],
            TONDU_BOUNDS.0[1],
            TONDU_BOUNDS.1[1],
            TONDU_BOUNDS.0[2],
            TONDU_BOUNDS.1[2]
        ));
        v.extend(stats_lines("Chou-H.", &self.chou_hannaford_stats));
        let ch = &self.chou_hannaford;
        v.push(format!(
            "Chou-Hannaford fit (end effect, slack threshold): r0 = {:.5} mm, alpha0 = {:.4} deg, k = {:.5}, p_th = {:.3} kPa",
            ch.r0_m * 1e3,
            ch.alpha0_rad.to_degrees(),
            ch.k,
            ch.p_threshold_pa / 1e3
        ));
        match &self.hysteresis {
            Some(h) => {
                v.push(format!(
                    "hysteresis: branch gap mean {:.3} N, max {:.3} N ({} pressurising / {} depressurising samples)",
                    h.gap_mean_n, h.gap_max_n, h.samples.0, h.samples.1
                ));
                for (name, (fit, st)) in [("rising", &h.rising), ("falling", &h.falling)] {
                    v.push(format!(
                        "  {name} branch alone: MAE {:.3} N ({:.3} % of range), {} of {} starts at the best cost",
                        st.mae_n, st.mae_pct_of_range, fit.starts_at_best, fit.starts
                    ));
                }
            }
            None => v.push("hysteresis: no branch column with both branches; not assessed".into()),
        }
        for w in &self.warnings {
            v.push(format!("warning: {w}"));
        }
        v
    }

    /// Human-readable summary.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        for l in self.report_lines() {
            let _ = writeln!(s, "{l}");
        }
        s
    }

    /// The `config/force_law.toml` text (the firmware's build reads it).
    /// The firmware's law as written by [`Self::to_toml`] (f32 constants, the domain).
    pub fn firmware_law(&self) -> pam_firmware::force_law::ForceLawParams {
        pam_firmware::force_law::ForceLawParams {
            c: self.eq6.c.map(|c| c as f32),
            p_gauge_max_pa: self.domain.0.max(1.0) as f32,
            stretch_min: self.domain.1 as f32,
            stretch_max: self.domain.2 as f32,
        }
    }

    /// Refuses a law the firmware's control tick would refuse: eq. 6 singular or unbounded
    /// somewhere on the written domain (`ForceLawParams::is_regular`). The fit keeps the
    /// denominator positive on the data's own domain; a wider pressure range given by hand
    /// can take it through 0.
    pub fn check_regular(&self) -> Result<(), IdentError> {
        if self.firmware_law().is_regular() {
            return Ok(());
        }
        let c7 = self.eq6.c[6];
        let hint = if c7 < 0.0 {
            format!(
                "its denominator c7 P + e (c7 = {c7:.4}) reaches 0 at {:.0} kPa for the lowest \
                 deformation {:.3}: keep the pressure range below {:.0} kPa",
                -self.domain.1 / c7 * 1e3,
                self.domain.1,
                -0.95 * self.domain.1 / c7 * 1e3
            )
        } else {
            "a constant is not finite or the force exceeds 1e30 N on the domain".into()
        };
        Err(IdentError::Data(format!(
            "the fitted law is not usable up to {:.0} kPa, deformation {:.3} .. {:.3} (the \
             firmware refuses a law singular on its domain): {hint}",
            self.domain.0 / 1e3,
            self.domain.1,
            self.domain.2
        )))
    }

    pub fn to_toml(&self, source: &str) -> String {
        let mut s = String::new();
        let _ = writeln!(s, "# Identified force law of the muscle (seed 002, eq. 6):");
        let _ = writeln!(s, "#");
        let _ = writeln!(s, "#   F = (c1 P^2 + c2 e^2 + c3 P + c4 e + c5 P/e + c6) / (c7 P + c8 e) + c9 + c10 exp(e - 0.7)");
        let _ = writeln!(s, "#");
        super::toml_header(
            &mut s,
            &[
                "# Conventions (fixed by the firmware, see src/force_law.rs):",
                "#   P  = gauge pressure in MPa (the unit of the paper's Fig. 4)",
                "#   e  = deformation L / L0 (the paper's Fig. 4 axis), L0 = rest length",
                "#   F  = muscle tension in N (clamped at 0: the muscle cannot push)",
                "# The scale of the rational part is fixed by c8 = 1. p_gauge_max_pa, stretch_min and",
                "# stretch_max are the domain of the data; outside it the firmware's law returns a",
                "# flagged, clamped result. Fitted as the firmware evaluates it, F = max(eq. 6, 0):",
                "# slack readings (F <= 0) constrain the law only where it would pull.",
                "#",
            ],
            "force",
            source,
            self.n_samples,
        );
        for l in self.report_lines() {
            let _ = writeln!(s, "# {l}");
        }
        let _ = writeln!(s, "\n[force_law]\nc = [");
        for c in self.eq6.c {
            let _ = writeln!(s, "    {c:.12e},");
        }
        let _ = writeln!(s, "]");
        let _ = writeln!(s, "p_gauge_max_pa = {:.1}", self.domain.0.max(1.0));
        let _ = writeln!(s, "stretch_min = {:.6}", self.domain.1);
        let _ = writeln!(s, "stretch_max = {:.6}", self.domain.2);
        s
    }
}

// ---------------------------------------------------------------------------------------
// Data files.

/// Lowest gauge pressure a force map may hold [kPa] (sensor noise around 0 gauge).
pub const P_KPA_MIN: f64 = -20.0;
/// Physical range of L/L0 in force data and sweeps: a braided muscle contracts by at most
/// about 40 % (L/L0 0.6; 0.5 leaves room) and is not stretched by half its length.
pub const STRETCH_MIN: f64 = 0.5;
/// Upper end of [`STRETCH_MIN`]'s range.
pub const STRETCH_MAX: f64 = 1.5;
/// Highest gauge pressure a force map may hold [kPa] (no braided muscle runs above 1.5 MPa).
pub const P_KPA_MAX: f64 = 1500.0;
/// A force map's largest pressure must reach this [kPa]; below, the column is not in kPa.
pub const P_KPA_MAX_AT_LEAST: f64 = 20.0;
/// Plausible tension of one sample [N]: a little negative (load-cell offset) up to well above
/// the largest fluidic muscles (~6 kN); beyond it the column is in mN.
pub const F_N_MIN: f64 = -500.0;
/// See [`F_N_MIN`].
pub const F_N_MAX: f64 = 20_000.0;
/// A map that reaches [`F_N_KPA_FOR_AT_LEAST`] kPa pulls at least this much [N] somewhere
/// (a 5 mm muscle pulls a few N at 200 kPa); less is a column in kN.
pub const F_N_MAX_AT_LEAST: f64 = 1.0;
/// See [`F_N_MAX_AT_LEAST`] [kPa].
pub const F_N_KPA_FOR_AT_LEAST: f64 = 200.0;

/// Reads isometric force data: columns `p_kpa` (gauge), `stretch` (L/L0), `f_n`, and
/// optionally `state` (`pressurising|up|inflate` / `depressurising|down|deflate`) or
/// `direction` (+1 / -1). Comment lines start with `#`. Steps: the columns, each row read and
/// range-checked ([`force_row`]), then the map's scale ([`check_force_map_scale`]).
pub fn read_force_csv(path: &Path) -> Result<Vec<ForceSample>, IdentError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| IdentError::Io {
        file: file.clone(),
        msg: e.to_string(),
    })?;
    let mut rdr = csv::ReaderBuilder::new()
        .comment(Some(b'#'))
        .trim(csv::Trim::All)
        .from_reader(text.as_bytes());
    let headers = rdr
        .headers()
        .map_err(|e| IdentError::at(&file, 1, "header", &e.to_string()))?
        .clone();
    let col = |name: &str| headers.iter().position(|h| h == name);
    let need = |name: &str| {
        col(name).ok_or_else(|| {
            IdentError::at(&file, header_line(&text), name, "missing required column")
        })
    };
    let cols = ForceColumns {
        p: need("p_kpa")?,
        stretch: need("stretch")?,
        f: need("f_n")?,
        state: col("state"),
        direction: col("direction"),
    };
    let mut out = Vec::new();
    // Largest pressure and force with their lines: a map whose largest pressure is a few
    // units is in MPa or bar, not kPa.
    let mut max_p = (f64::NEG_INFINITY, 0usize);
    let mut max_f = (f64::NEG_INFINITY, 0usize);
    for rec in rdr.records() {
        let rec = rec.map_err(|e| {
            let line = e.position().map(|p| p.line() as usize).unwrap_or(0);
            IdentError::at(&file, line, "row", &e.to_string())
        })?;
        let line = rec.position().map(|p| p.line() as usize).unwrap_or(0);
        let (p_kpa, s) = force_row(&rec, &cols, &file, line)?;
        if p_kpa > max_p.0 {
            max_p = (p_kpa, line);
        }
        if s.force_n > max_f.0 {
            max_f = (s.force_n, line);
        }
        out.push(s);
    }
    if out.is_empty() {
        return Err(IdentError::at(
            &file,
            header_line(&text) + 1,
            "row",
            "no data rows",
        ));
    }
    check_force_map_scale(&file, max_p, max_f)?;
    Ok(out)
}

/// The columns of a force map.
struct ForceColumns {
    p: usize,
    stretch: usize,
    f: usize,
    state: Option<usize>,
    direction: Option<usize>,
}

/// One row of a force map at `line` (with its pressure as written [kPa]): finite numbers,
/// each within its physical range (the message names the unit mistake a value outside
/// suggests), and its branch.
fn force_row(
    rec: &csv::StringRecord,
    cols: &ForceColumns,
    file: &str,
    line: usize,
) -> Result<(f64, ForceSample), IdentError> {
    let num = |i: usize, name: &str| -> Result<f64, IdentError> {
        let raw = rec.get(i).unwrap_or("");
        let v: f64 = raw
            .parse()
            .map_err(|_| IdentError::at(file, line, name, &format!("not a number: {raw:?}")))?;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(IdentError::at(
                file,
                line,
                name,
                &format!("not finite: {raw:?}"),
            ))
        }
    };
    let p_kpa = num(cols.p, "p_kpa")?;
    let stretch = num(cols.stretch, "stretch")?;
    let f_n = num(cols.f, "f_n")?;
    // `hint` follows the range in the message: the unit mistake such a value suggests.
    let in_range = |name: &str, v: f64, range: RangeInclusive<f64>, hint: &str| {
        if range.contains(&v) {
            return Ok(());
        }
        let (lo, hi) = range.into_inner();
        let msg = format!("{v} is outside {lo}..{hi}{hint}");
        Err(IdentError::at(file, line, name, &msg))
    };
    // Below the range and under 0.5: a contraction 1 - L/L0; above it: a percentage.
    let stretch_hint = if (0.0..STRETCH_MIN).contains(&stretch) {
        format!(
            ": the column is L/L0, the deformation; a contraction 1 - L/L0 instead? \
             contraction {stretch} is L/L0 = {}",
            crate::validate::Shown(1.0 - stretch)
        )
    } else {
        ": the column is L/L0, a ratio (contraction 0..0.5); a percentage? 75 % is 0.75".to_string()
    };
    in_range("stretch", stretch, STRETCH_MIN..=STRETCH_MAX, &stretch_hint)?;
    in_range(
        "p_kpa",
        p_kpa,
        P_KPA_MIN..=P_KPA_MAX,
        " kPa gauge (a value in Pa? the column is in kPa)",
    )?;
    in_range(
        "f_n",
        f_n,
        F_N_MIN..=F_N_MAX,
        " N (the column is the tension in N, positive; the largest fluidic muscles pull \
         ~6 kN: a value in mN, or a load cell logging tension negative?)",
    )?;
    let branch = if let Some(i) = cols.state {
        branch_of_state(rec.get(i).unwrap_or(""))
            .map_err(|msg| IdentError::at(file, line, "state", &msg))?
    } else if let Some(i) = cols.direction {
        let d = num(i, "direction")?;
        if d > 0.0 {
            Some(Branch::Pressurising)
        } else if d < 0.0 {
            Some(Branch::Depressurising)
        } else {
            None
        }
    } else {
        None
    };
    Ok((
        p_kpa,
        ForceSample {
            p_gauge_pa: p_kpa * 1e3,
            stretch,
            force_n: f_n,
            branch,
        },
    ))
}

/// The branch a `state` cell names (any case; empty: none), or why it names none.
fn branch_of_state(cell: &str) -> Result<Option<Branch>, String> {
    match cell.to_ascii_lowercase().as_str() {
        "pressurising" | "pressurizing" | "up" | "inflate" | "rising" => {
            Ok(Some(Branch::Pressurising))
        }
        "depressurising" | "depressurizing" | "down" | "deflate" | "falling" => {
            Ok(Some(Branch::Depressurising))
        }
        "" => Ok(None),
        other => Err(format!(
            "unknown branch {other:?} (pressurising, up, inflate or rising; \
             depressurising, down, deflate or falling; empty for none)"
        )),
    }
}

/// The map's largest pressure (and force) with its line: a map that never reaches
/// [`P_KPA_MAX_AT_LEAST`] is in MPa or bar; one that reaches [`F_N_KPA_FOR_AT_LEAST`] but
/// pulls less than [`F_N_MAX_AT_LEAST`] is in kN (no positive force at all has its own
/// message, after the read).
fn check_force_map_scale(
    file: &str,
    max_p: (f64, usize),
    max_f: (f64, usize),
) -> Result<(), IdentError> {
    if max_p.0 < P_KPA_MAX_AT_LEAST {
        return Err(IdentError::at(
            file,
            max_p.1,
            "p_kpa",
            &format!(
                "the largest pressure is {} kPa: the column is in kPa gauge and a force map reaches \
                 at least {P_KPA_MAX_AT_LEAST} kPa (values this small look like MPa or bar)",
                max_p.0
            ),
        ));
    }
    if max_f.0 > 0.0 && max_f.0 < F_N_MAX_AT_LEAST && max_p.0 >= F_N_KPA_FOR_AT_LEAST {
        return Err(IdentError::at(
            file,
            max_f.1,
            "f_n",
            &format!(
                "the largest force is {} N with pressures up to {} kPa: the column is in N and a \
                 muscle at {F_N_KPA_FOR_AT_LEAST} kPa pulls at least {F_N_MAX_AT_LEAST} N \
                 (values this small look like kN)",
                max_f.0, max_p.0
            ),
        ));
    }
    Ok(())
}

fn header_line(text: &str) -> usize {
    text.lines()
        .position(|l| !l.trim_start().starts_with('#') && !l.trim().is_empty())
        .map(|i| i + 1)
        .unwrap_or(1)
}

/// Options of the synthetic isometric sweep (`host-sim sweep force`).
#[derive(Clone, Debug)]
pub struct ForceSweep {
    /// Number of deformation levels between `stretch_min` and `stretch_max`.
    pub n_stretch: usize,
    /// Number of pressure levels from 0 to `p_max_pa`.
    pub n_pressure: usize,
    /// Lowest L/L0.
    pub stretch_min: f64,
    /// Highest L/L0.
    pub stretch_max: f64,
    /// Highest gauge pressure [Pa].
    pub p_max_pa: f64,
    /// Force sensor noise, standard deviation [N].
    pub force_noise_n: f64,
    /// Pressure sensor noise, standard deviation [Pa].
    pub pressure_noise_pa: f64,
    /// Branch gap [N] at full pressure: when > 0 each stretch level is swept up and down and
    /// the branches differ by `gap * P / p_max` (braid friction grows with pressure).
    pub hysteresis_gap_n: f64,
    /// Random seed.
    pub seed: u64,
}

impl Default for ForceSweep {
    fn default() -> Self {
        ForceSweep {
            n_stretch: 31,
            n_pressure: 31,
            stretch_min: 0.75,
            stretch_max: 1.05,
            p_max_pa: 600_000.0,
            force_noise_n: 3.0,
            pressure_noise_pa: 500.0,
            hysteresis_gap_n: 0.0,
            seed: 1,
        }
    }
}

impl ForceSweep {
    /// The noise-free surface on an `n` x `n` grid over the default domain (to measure a fitted
    /// law's error against the truth).
    pub fn noise_free_grid(n: usize) -> Self {
        ForceSweep {
            n_stretch: n,
            n_pressure: n,
            force_noise_n: 0.0,
            pressure_noise_pa: 0.0,
            ..ForceSweep::default()
        }
    }
}

/// Largest branch gap of a sweep as a share of its largest force ([`largest_force`]):
/// braid friction of a braided muscle is a fraction of its force, so a larger gap gives
/// forces the muscle cannot produce.
pub const HYSTERESIS_GAP_MAX_SHARE: f64 = 0.25;
/// [`HYSTERESIS_GAP_MAX_SHARE`] as the messages say it.
pub const HYSTERESIS_GAP_MAX_SHARE_TEXT: &str = "a quarter";

/// L/L0 of the sweep's stretch level `i` (of `opt.n_stretch`, at least 2).
fn stretch_level(opt: &ForceSweep, i: usize) -> f64 {
    let ns = opt.n_stretch.max(2);
    opt.stretch_min + (opt.stretch_max - opt.stretch_min) * i as f64 / (ns - 1) as f64
}

/// The largest noise-free force of the sweep without a branch gap [N] and the L/L0 where it
/// is: at `opt.p_max_pa` (the Tondu force grows in proportion to the pressure), over the
/// sweep's stretch levels.
pub fn largest_force(truth: &Tondu, opt: &ForceSweep) -> (f64, f64) {
    (0..opt.n_stretch.max(2))
        .map(|i| {
            let e = stretch_level(opt, i);
            (truth.force_n(opt.p_max_pa, e), e)
        })
        .fold(
            (0.0, opt.stretch_min),
            |best, x| if x.0 > best.0 { x } else { best },
        )
}

/// Generates isometric data from a Tondu surface, as seed 002's bench does (fixed length,
/// pressure swept from maximum to zero, and back up when a hysteresis gap is set).
pub fn sweep(truth: &Tondu, opt: &ForceSweep) -> Vec<ForceSample> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(opt.seed);
    let fnoise = Normal::new(0.0, opt.force_noise_n.max(0.0)).expect("finite sd");
    let pnoise = Normal::new(0.0, opt.pressure_noise_pa.max(0.0)).expect("finite sd");
    let mut out = Vec::new();
    let ns = opt.n_stretch.max(2);
    let np = opt.n_pressure.max(2);
    for i in 0..ns {
        let e = stretch_level(opt, i);
        let mut branches = vec![Branch::Depressurising];
        if opt.hysteresis_gap_n > 0.0 {
            branches.push(Branch::Pressurising);
        }
        for &b in &branches {
            for j in 0..np {
                let frac = match b {
                    Branch::Depressurising => 1.0 - j as f64 / (np - 1) as f64,
                    Branch::Pressurising => j as f64 / (np - 1) as f64,
                };
                let p = opt.p_max_pa * frac;
                let half_gap = 0.5 * opt.hysteresis_gap_n * frac;
                // Pressurising: friction opposes the growing tension (lower); depressurising: higher.
                let offset = match b {
                    Branch::Pressurising => -half_gap,
                    Branch::Depressurising => half_gap,
                };
                let f_true = (truth.force_n(p, e)
                    + if truth.force_n(p, e) > 0.0 {
                        offset
                    } else {
                        0.0
                    })
                .max(0.0);
                let p_meas = (p + pnoise.sample(&mut rng)).max(0.0);
                let f_meas = f_true + fnoise.sample(&mut rng);
                out.push(ForceSample {
                    p_gauge_pa: p_meas,
                    stretch: e,
                    force_n: f_meas,
                    branch: (opt.hysteresis_gap_n > 0.0).then_some(b),
                });
            }
        }
    }
    out
}

/// Writes force data as CSV (`p_kpa,stretch,f_n[,state]`) atomically.
pub fn write_force_csv(
    path: &Path,
    samples: &[ForceSample],
    meta: &BTreeMap<String, String>,
) -> Result<(), IdentError> {
    let with_state = samples.iter().any(|s| s.branch.is_some());
    let mut s = String::new();
    for (k, v) in meta {
        let _ = writeln!(s, "# {k} = {v}");
    }
    let _ = writeln!(
        s,
        "p_kpa,stretch,f_n{}",
        if with_state { ",state" } else { "" }
    );
    for x in samples {
        let _ = write!(
            s,
            "{:.4},{:.6},{:.4}",
            x.p_gauge_pa / 1e3,
            x.stretch,
            x.force_n
        );
        if with_state {
            let _ = write!(s, ",{}", x.branch.map(Branch::label).unwrap_or(""));
        }
        s.push('\n');
    }
    write_atomic(path, s.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reference() -> Tondu {
        Tondu {
            r0_m: 0.01,
            alpha0_rad: 25.3f64.to_radians(),
            k: 1.446,
        }
    }

    /// The default sweep on an `n_stretch` x `n_pressure` grid.
    fn grid_sweep(n_stretch: usize, n_pressure: usize) -> ForceSweep {
        ForceSweep {
            n_stretch,
            n_pressure,
            ..ForceSweep::default()
        }
    }

    #[test]
    fn tondu_matches_plant_equilibrium_force() {
        // PLANT.md / fixtures: 529.601003 N at 550 kPa, chi = 0.14.
        let f = reference().force_n(550_000.0, 0.86);
        assert!((f - 529.601003).abs() < 1e-3, "{f}");
    }

    #[test]
    fn eq6_fit_on_noisy_tondu_data_beats_the_paper_error_against_the_truth() {
        let truth = reference();
        let data = sweep(&truth, &grid_sweep(31, 31));
        let id = identify(&data).unwrap();
        // Error against the noise-free surface on a dense grid over the whole domain.
        let grid = sweep(&truth, &ForceSweep::noise_free_grid(61));
        let st = error_stats(&grid, |p, e| id.eq6.force_n(p, e));
        eprintln!("{}\nagainst the noise-free surface: {st:?}", id.summary());
        assert!(
            st.mae_pct_of_range <= 0.77,
            "eq. 6 MAE {:.3} % of range",
            st.mae_pct_of_range
        );
        // The Tondu baseline recovers the true parameters from the same data.
        assert!((id.tondu.k - 1.446).abs() < 0.01, "{:?}", id.tondu);
        assert!(
            (id.tondu.alpha0_rad.to_degrees() - 25.3).abs() < 0.3,
            "{:?}",
            id.tondu
        );
    }

    #[test]
    fn a_law_singular_on_its_written_domain_is_refused_with_the_pressure_to_keep_below() {
        let mut id = identify(&sweep(&reference(), &grid_sweep(11, 11))).unwrap();
        id.check_regular().unwrap();
        assert!(id.firmware_law().is_regular());
        // A negative c7: the denominator c7 P + e is 0 at P = e / |c7| = 750 kPa for e = 0.75.
        id.eq6.c[6] = -1.0;
        id.domain = (600e3, 0.75, 1.05);
        id.check_regular().unwrap();
        id.domain.0 = 800e3;
        let e = id.check_regular().unwrap_err().to_string();
        assert!(
            e.contains("reaches 0 at 750 kPa") && e.contains("below 712 kPa"),
            "{e}"
        );
    }

    #[test]
    fn hysteresis_gap_is_measured_from_branches() {
        let data = sweep(
            &reference(),
            &ForceSweep {
                hysteresis_gap_n: 40.0,
                force_noise_n: 1.0,
                ..ForceSweep::default()
            },
        );
        let id = identify(&data).unwrap();
        let h = id.hysteresis.expect("both branches present");
        // gap * P/pmax averaged over a uniform pressure grid is ~ gap/2 where the force is > 0.
        assert!(h.gap_mean_n > 10.0 && h.gap_mean_n < 30.0, "{h:?}");
    }

    #[test]
    fn too_few_samples_is_an_error() {
        let data = sweep(&reference(), &grid_sweep(2, 3));
        assert!(matches!(fit_eq6(&data), Err(IdentError::Data(_))));
    }
}

#[cfg(test)]
mod read_tests {
    use super::*;

    #[test]
    fn a_state_cell_names_its_branch_in_any_case_and_an_unknown_one_is_refused() {
        assert_eq!(branch_of_state("UP"), Ok(Some(Branch::Pressurising)));
        assert_eq!(branch_of_state("Deflate"), Ok(Some(Branch::Depressurising)));
        assert_eq!(branch_of_state(""), Ok(None));
        let err = branch_of_state("sideways").unwrap_err();
        assert!(err.starts_with("unknown branch \"sideways\""), "{err}");
    }

    #[test]
    fn a_force_map_in_mpa_or_in_kn_is_refused_at_the_line_of_its_largest_value() {
        assert!(check_force_map_scale("m.csv", (600.0, 9), (900.0, 9)).is_ok());
        let mpa = check_force_map_scale("m.csv", (0.6, 7), (900.0, 9)).unwrap_err();
        assert!(mpa.to_string().contains(":7"), "{mpa}");
        let kn = check_force_map_scale("m.csv", (600.0, 7), (0.9, 4)).unwrap_err();
        assert!(kn.to_string().contains(":4"), "{kn}");
        // Under the pressure at which a muscle must pull a newton, a small force is allowed.
        assert!(check_force_map_scale("m.csv", (100.0, 7), (0.9, 4)).is_ok());
    }
}
