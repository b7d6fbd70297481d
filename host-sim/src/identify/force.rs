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
//! over c7 (with the denominator kept positive over the data) solving a linear least-squares
//! problem (SVD) at each point, then a Levenberg-Marquardt polish of all nine constants
//! (`levenberg-marquardt` crate). This needs no random restarts and is deterministic.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{DMatrix, DVector, Dyn, Owned};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

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
        TonduLaw::new(self.r0_m, self.alpha0_rad, self.k).force_unclamped_n(p_gauge_pa, 1.0 - stretch)
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
// Eq. 6: variable projection over c7, then Levenberg-Marquardt.

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

/// Linear least squares of eq. 6 for a fixed c7: returns (constants, sum of squared residuals).
fn eq6_linear(samples: &[ForceSample], c7: f64) -> Option<(Eq6, f64)> {
    let m = samples.len();
    let mut a = DMatrix::<f64>::zeros(m, 8);
    let mut y = DVector::<f64>::zeros(m);
    // Column scaling keeps the SVD well conditioned (the basis spans many decades).
    for (i, s) in samples.iter().enumerate() {
        let b = eq6_basis(c7, s.p_gauge_pa * 1e-6, s.stretch);
        for (j, v) in b.iter().enumerate() {
            a[(i, j)] = *v;
        }
        y[i] = s.force_n;
    }
    let mut scale = [1.0; 8];
    for (j, sc) in scale.iter_mut().enumerate() {
        let norm = a.column(j).norm();
        if norm > 0.0 {
            *sc = norm;
            a.column_mut(j).scale_mut(1.0 / norm);
        }
    }
    let svd = a.clone().svd(true, true);
    let theta = svd.solve(&y, 1e-12).ok()?;
    let r = &a * &theta - &y;
    let t: Vec<f64> = theta.iter().zip(scale.iter()).map(|(t, s)| t / s).collect();
    let eq = Eq6 {
        c: [t[0], t[1], t[2], t[3], t[4], t[5], c7, 1.0, t[6], t[7]],
    };
    let ssr = r.norm_squared();
    ssr.is_finite().then_some((eq, ssr))
}

/// Lowest c7 for which the denominator `c7 P + e` stays positive over the data (with margin).
fn c7_lower_bound(samples: &[ForceSample]) -> f64 {
    let mut lb = f64::NEG_INFINITY;
    for s in samples {
        let p = s.p_gauge_pa * 1e-6;
        if p > 1e-9 {
            // c7 p + e > 0.05 e  <=>  c7 > -0.95 e / p
            lb = lb.max(-0.95 * s.stretch / p);
        }
    }
    if lb.is_finite() {
        lb
    } else {
        -1.0
    }
}

struct Eq6Problem<'a> {
    samples: &'a [ForceSample],
    /// (c1..c7, c9, c10); c8 = 1.
    x: DVector<f64>,
}

impl Eq6Problem<'_> {
    fn eq6(x: &DVector<f64>) -> Eq6 {
        Eq6 {
            c: [x[0], x[1], x[2], x[3], x[4], x[5], x[6], 1.0, x[7], x[8]],
        }
    }
}

impl LeastSquaresProblem<f64, Dyn, Dyn> for Eq6Problem<'_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, x: &DVector<f64>) {
        self.x.copy_from(x);
    }

    fn params(&self) -> DVector<f64> {
        self.x.clone()
    }

    fn residuals(&self) -> Option<DVector<f64>> {
        let m = Self::eq6(&self.x);
        let r = DVector::from_iterator(
            self.samples.len(),
            self.samples
                .iter()
                .map(|s| m.eval(s.p_gauge_pa, s.stretch) - s.force_n),
        );
        r.iter().all(|v| v.is_finite()).then_some(r)
    }

    fn jacobian(&self) -> Option<DMatrix<f64>> {
        let x = &self.x;
        let mut j = DMatrix::<f64>::zeros(self.samples.len(), 9);
        for (i, s) in self.samples.iter().enumerate() {
            let p = s.p_gauge_pa * 1e-6;
            let e = s.stretch;
            let d = x[6] * p + e;
            let num = x[0] * p * p + x[1] * e * e + x[2] * p + x[3] * e + x[4] * p / e + x[5];
            let basis = [p * p, e * e, p, e, p / e, 1.0];
            for (k, b) in basis.iter().enumerate() {
                j[(i, k)] = b / d;
            }
            j[(i, 6)] = -num * p / (d * d);
            j[(i, 7)] = 1.0;
            j[(i, 8)] = (e - 0.7).exp();
        }
        j.iter().all(|v| v.is_finite()).then_some(j)
    }
}

/// Fits eq. 6 (c8 = 1) to the samples. Deterministic.
pub fn fit_eq6(samples: &[ForceSample]) -> Result<Eq6, IdentError> {
    if samples.len() < 20 {
        return Err(IdentError::Data(format!(
            "eq. 6 has 9 free constants: need at least 20 samples, got {}",
            samples.len()
        )));
    }
    let lb = c7_lower_bound(samples);
    // Coarse scan of c7 on a grid that is dense near the bound and spans large values too.
    let mut candidates: Vec<f64> = Vec::new();
    for i in 0..60 {
        let u = i as f64 / 59.0;
        candidates.push(lb + (1e-3 + 50.0 * u * u * u));
    }
    let mut best: Option<(f64, Eq6, f64)> = None;
    for &c7 in &candidates {
        if let Some((eq, ssr)) = eq6_linear(samples, c7) {
            if best.as_ref().is_none_or(|b| ssr < b.2) {
                best = Some((c7, eq, ssr));
            }
        }
    }
    let (mut c7, _, _) = best
        .clone()
        .ok_or_else(|| IdentError::Data("eq. 6: no c7 gave a solvable fit".into()))?;
    // Golden-section refinement around the best grid point.
    let idx = candidates.iter().position(|&c| c == c7).unwrap_or(0);
    let mut lo = candidates[idx.saturating_sub(1)];
    let mut hi = candidates[(idx + 1).min(candidates.len() - 1)];
    let gr = 0.5 * (5f64.sqrt() - 1.0);
    let f = |c: f64| {
        eq6_linear(samples, c)
            .map(|(_, s)| s)
            .unwrap_or(f64::INFINITY)
    };
    for _ in 0..60 {
        let a = hi - gr * (hi - lo);
        let b = lo + gr * (hi - lo);
        if f(a) < f(b) {
            hi = b;
        } else {
            lo = a;
        }
    }
    let mid = 0.5 * (lo + hi);
    if f(mid) < f(c7) {
        c7 = mid;
    }
    let (start, ssr0) = eq6_linear(samples, c7)
        .ok_or_else(|| IdentError::Data("eq. 6: linear solve failed".into()))?;
    // Levenberg-Marquardt polish of all nine constants.
    let c = start.c;
    let x0 = DVector::from_vec(vec![c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[8], c[9]]);
    let problem = Eq6Problem { samples, x: x0 };
    let (problem, _report) = LevenbergMarquardt::new()
        .with_patience(200)
        .minimize(problem);
    let polished = Eq6Problem::eq6(&problem.x);
    let ssr1: f64 = samples
        .iter()
        .map(|s| (polished.eval(s.p_gauge_pa, s.stretch) - s.force_n).powi(2))
        .sum();
    let den_ok = samples
        .iter()
        .all(|s| polished.c[6] * s.p_gauge_pa * 1e-6 + s.stretch > 0.0);
    Ok(if ssr1.is_finite() && ssr1 <= ssr0 && den_ok {
        polished
    } else {
        start
    })
}

// ---------------------------------------------------------------------------------------
// Tondu baseline.

struct TonduProblem<'a> {
    samples: &'a [ForceSample],
    /// (r0 [mm], alpha0 [deg], k): scaled so the parameters are of order 1..30.
    x: DVector<f64>,
}

impl TonduProblem<'_> {
    fn model(x: &DVector<f64>) -> Tondu {
        Tondu {
            r0_m: x[0] * 1e-3,
            alpha0_rad: x[1].to_radians(),
            k: x[2],
        }
    }
}

impl LeastSquaresProblem<f64, Dyn, Dyn> for TonduProblem<'_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, x: &DVector<f64>) {
        self.x.copy_from(x);
    }

    fn params(&self) -> DVector<f64> {
        self.x.clone()
    }

    fn residuals(&self) -> Option<DVector<f64>> {
        let m = Self::model(&self.x);
        let r = DVector::from_iterator(
            self.samples.len(),
            self.samples
                .iter()
                .map(|s| m.force_n(s.p_gauge_pa, s.stretch) - s.force_n),
        );
        r.iter().all(|v| v.is_finite()).then_some(r)
    }

    fn jacobian(&self) -> Option<DMatrix<f64>> {
        // Central differences: three parameters, the clamp makes analytic forms piecewise anyway.
        let n = self.samples.len();
        let mut j = DMatrix::<f64>::zeros(n, 3);
        for k in 0..3 {
            let h = 1e-6 * self.x[k].abs().max(1e-3);
            let mut xp = self.x.clone();
            let mut xm = self.x.clone();
            xp[k] += h;
            xm[k] -= h;
            let mp = Self::model(&xp);
            let mm = Self::model(&xm);
            for (i, s) in self.samples.iter().enumerate() {
                j[(i, k)] = (mp.force_n(s.p_gauge_pa, s.stretch)
                    - mm.force_n(s.p_gauge_pa, s.stretch))
                    / (2.0 * h);
            }
        }
        j.iter().all(|v| v.is_finite()).then_some(j)
    }
}

/// Fits the Tondu model (r0, alpha0, k) by Levenberg-Marquardt from a few starting points.
pub fn fit_tondu(samples: &[ForceSample]) -> Result<Tondu, IdentError> {
    if samples.len() < 3 {
        return Err(IdentError::Data(
            "Tondu model: need at least 3 samples".into(),
        ));
    }
    let mut best: Option<(Tondu, f64)> = None;
    for &(r0, a0, k) in &[
        (10.0, 25.0, 1.3),
        (8.0, 20.0, 1.0),
        (12.0, 30.0, 1.6),
        (10.0, 22.0, 1.8),
    ] {
        let problem = TonduProblem {
            samples,
            x: DVector::from_vec(vec![r0, a0, k]),
        };
        let (problem, _) = LevenbergMarquardt::new()
            .with_patience(200)
            .minimize(problem);
        let m = TonduProblem::model(&problem.x);
        let ssr: f64 = samples
            .iter()
            .map(|s| (m.force_n(s.p_gauge_pa, s.stretch) - s.force_n).powi(2))
            .sum();
        if ssr.is_finite() && best.as_ref().is_none_or(|b| ssr < b.1) {
            best = Some((m, ssr));
        }
    }
    best.map(|b| b.0)
        .ok_or_else(|| IdentError::Data("Tondu model: no start converged".into()))
}

// ---------------------------------------------------------------------------------------
// Whole identification run.

/// Hysteresis between the two branches of the sweeps.
#[derive(Clone, Debug, PartialEq)]
pub struct Hysteresis {
    /// Mean |F_pressurising - F_depressurising| over the data's (P, e) points [N], from an
    /// eq. 6 model fitted to each branch.
    pub gap_mean_n: f64,
    /// Largest gap [N].
    pub gap_max_n: f64,
    /// Samples on each branch.
    pub samples: (usize, usize),
}

/// Everything `identify force` produces.
#[derive(Clone, Debug)]
pub struct ForceIdentification {
    /// Eq. 6 fitted to all samples (the mid-curve when both branches are present).
    pub eq6: Eq6,
    /// Its errors on the data.
    pub eq6_stats: ErrorStats,
    /// Tondu baseline.
    pub tondu: Tondu,
    /// Its errors on the data.
    pub tondu_stats: ErrorStats,
    /// Branch gap, when the data has a branch column with both branches.
    pub hysteresis: Option<Hysteresis>,
    /// Domain of the data: (max gauge pressure [Pa], min stretch, max stretch).
    pub domain: (f64, f64, f64),
    /// Number of samples.
    pub n_samples: usize,
}

/// Fits eq. 6 and the Tondu baseline to the samples.
pub fn identify(samples: &[ForceSample]) -> Result<ForceIdentification, IdentError> {
    let eq6 = fit_eq6(samples)?;
    let tondu = fit_tondu(samples)?;
    let eq6_stats = error_stats(samples, |p, e| eq6.force_n(p, e));
    let tondu_stats = error_stats(samples, |p, e| tondu.force_n(p, e));
    let up: Vec<ForceSample> = samples
        .iter()
        .copied()
        .filter(|s| s.branch == Some(Branch::Pressurising))
        .collect();
    let down: Vec<ForceSample> = samples
        .iter()
        .copied()
        .filter(|s| s.branch == Some(Branch::Depressurising))
        .collect();
    let hysteresis = if up.len() >= 20 && down.len() >= 20 {
        let mu = fit_eq6(&up)?;
        let md = fit_eq6(&down)?;
        let gaps: Vec<f64> = samples
            .iter()
            .map(|s| {
                (mu.force_n(s.p_gauge_pa, s.stretch) - md.force_n(s.p_gauge_pa, s.stretch)).abs()
            })
            .collect();
        Some(Hysteresis {
            gap_mean_n: gaps.iter().sum::<f64>() / gaps.len() as f64,
            gap_max_n: gaps.iter().cloned().fold(0.0, f64::max),
            samples: (up.len(), down.len()),
        })
    } else {
        None
    };
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
        eq6_stats,
        tondu,
        tondu_stats,
        hysteresis,
        domain: (pmax, emin, emax),
        n_samples: samples.len(),
    })
}

impl ForceIdentification {
    /// Human-readable summary.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        let line = |s: &mut String, name: &str, st: &ErrorStats| {
            let _ = writeln!(
                s,
                "{name:<8} MAE {:8.2} N ({:5.2} % of range)  RMSE {:8.2} N  max {:8.2} N at {:.0} kPa, L/L0 {:.3}\n         largest mean error: {} ({:.2} N)",
                st.mae_n, st.mae_pct_of_range, st.rmse_n, st.max_abs_n, st.max_at.0, st.max_at.1, st.worst_region, st.worst_region_mae_n
            );
        };
        let _ = writeln!(
            s,
            "{} samples, P up to {:.0} kPa, L/L0 {:.3}..{:.3}",
            self.n_samples,
            self.domain.0 / 1e3,
            self.domain.1,
            self.domain.2
        );
        line(&mut s, "eq. 6", &self.eq6_stats);
        line(&mut s, "Tondu", &self.tondu_stats);
        let _ = writeln!(
            s,
            "Tondu fit: r0 = {:.3} mm, alpha0 = {:.2} deg, k = {:.4}",
            self.tondu.r0_m * 1e3,
            self.tondu.alpha0_rad.to_degrees(),
            self.tondu.k
        );
        match &self.hysteresis {
            Some(h) => {
                let _ = writeln!(
                    s,
                    "hysteresis: branch gap mean {:.2} N, max {:.2} N ({} pressurising / {} depressurising samples)",
                    h.gap_mean_n, h.gap_max_n, h.samples.0, h.samples.1
                );
            }
            None => {
                let _ = writeln!(
                    s,
                    "hysteresis: no branch column with both branches; not assessed"
                );
            }
        }
        s
    }

    /// The `config/force_law.toml` text (the firmware's build reads it).
    pub fn to_toml(&self, source: &str) -> String {
        let mut s = String::new();
        let _ = writeln!(s, "# Identified force law of the muscle (seed 002, eq. 6):");
        let _ = writeln!(s, "#");
        let _ = writeln!(s, "#   F = (c1 P^2 + c2 e^2 + c3 P + c4 e + c5 P/e + c6) / (c7 P + c8 e) + c9 + c10 exp(e - 0.7)");
        let _ = writeln!(s, "#");
        for l in [
            "# Conventions (fixed by the firmware, see src/force_law.rs):",
            "#   P  = gauge pressure in MPa (the unit of the paper's Fig. 4)",
            "#   e  = deformation L / L0 (the paper's Fig. 4 axis), L0 = rest length",
            "#   F  = muscle tension in N (clamped at 0: the muscle cannot push)",
            "# The scale of the rational part is fixed by c8 = 1. p_gauge_max_pa, stretch_min and",
            "# stretch_max are the domain of the data; outside it the firmware's law returns a",
            "# flagged, clamped result.",
            "#",
        ] {
            let _ = writeln!(s, "{l}");
        }
        let _ = writeln!(
            s,
            "# Written by `host-sim identify force` from {source} ({} samples).",
            self.n_samples
        );
        for (name, st) in [("eq. 6: ", &self.eq6_stats), ("Tondu: ", &self.tondu_stats)] {
            let _ = writeln!(
                s,
                "# {name} MAE {:.3} N = {:.3} % of the force range, RMSE {:.3} N, max {:.3} N at {:.0} kPa, L/L0 {:.3}",
                st.mae_n, st.mae_pct_of_range, st.rmse_n, st.max_abs_n, st.max_at.0, st.max_at.1
            );
            let _ = writeln!(
                s,
                "#          largest mean error: {} ({:.3} N)",
                st.worst_region, st.worst_region_mae_n
            );
        }
        let _ = writeln!(
            s,
            "# Tondu fit: r0 = {:.4} mm, alpha0 = {:.3} deg, k = {:.4}",
            self.tondu.r0_m * 1e3,
            self.tondu.alpha0_rad.to_degrees(),
            self.tondu.k
        );
        if let Some(h) = &self.hysteresis {
            let _ = writeln!(
                s,
                "# hysteresis: branch gap mean {:.3} N, max {:.3} N",
                h.gap_mean_n, h.gap_max_n
            );
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

/// Reads isometric force data: columns `p_kpa` (gauge), `stretch` (L/L0), `f_n`, and
/// optionally `state` (`pressurising|up|inflate` / `depressurising|down|deflate`) or
/// `direction` (+1 / -1). Comment lines start with `#`.
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
    let (ip, ie, iff) = (need("p_kpa")?, need("stretch")?, need("f_n")?);
    let istate = col("state");
    let idir = col("direction");
    let mut out = Vec::new();
    for rec in rdr.records() {
        let rec = rec.map_err(|e| {
            let line = e.position().map(|p| p.line() as usize).unwrap_or(0);
            IdentError::at(&file, line, "row", &e.to_string())
        })?;
        let line = rec.position().map(|p| p.line() as usize).unwrap_or(0);
        let num = |i: usize, name: &str| -> Result<f64, IdentError> {
            let raw = rec.get(i).unwrap_or("");
            let v: f64 = raw.parse().map_err(|_| {
                IdentError::at(&file, line, name, &format!("not a number: {raw:?}"))
            })?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(IdentError::at(
                    &file,
                    line,
                    name,
                    &format!("not finite: {raw:?}"),
                ))
            }
        };
        let p_kpa = num(ip, "p_kpa")?;
        let stretch = num(ie, "stretch")?;
        let f_n = num(iff, "f_n")?;
        if stretch <= 0.0 {
            return Err(IdentError::at(&file, line, "stretch", "L/L0 must be > 0"));
        }
        let branch = if let Some(i) = istate {
            let v = rec.get(i).unwrap_or("").to_ascii_lowercase();
            match v.as_str() {
                "pressurising" | "pressurizing" | "up" | "inflate" | "rising" => {
                    Some(Branch::Pressurising)
                }
                "depressurising" | "depressurizing" | "down" | "deflate" | "falling" => {
                    Some(Branch::Depressurising)
                }
                "" => None,
                other => {
                    return Err(IdentError::at(
                        &file,
                        line,
                        "state",
                        &format!("unknown branch {other:?}"),
                    ))
                }
            }
        } else if let Some(i) = idir {
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
        out.push(ForceSample {
            p_gauge_pa: p_kpa * 1e3,
            stretch,
            force_n: f_n,
            branch,
        });
    }
    if out.is_empty() {
        return Err(IdentError::at(
            &file,
            header_line(&text) + 1,
            "row",
            "no data rows",
        ));
    }
    Ok(out)
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
        let e = opt.stretch_min + (opt.stretch_max - opt.stretch_min) * i as f64 / (ns - 1) as f64;
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

    #[test]
    fn tondu_matches_plant_equilibrium_force() {
        // PLANT.md / fixtures: 529.601003 N at 550 kPa, chi = 0.14.
        let f = reference().force_n(550_000.0, 0.86);
        assert!((f - 529.601003).abs() < 1e-3, "{f}");
    }

    #[test]
    fn eq6_fit_on_noisy_tondu_data_beats_the_paper_error_against_the_truth() {
        let truth = reference();
        let data = sweep(
            &truth,
            &ForceSweep {
                n_stretch: 31,
                n_pressure: 31,
                ..ForceSweep::default()
            },
        );
        let id = identify(&data).unwrap();
        // Error against the noise-free surface on a dense grid over the whole domain.
        let grid = sweep(
            &truth,
            &ForceSweep {
                n_stretch: 61,
                n_pressure: 61,
                force_noise_n: 0.0,
                pressure_noise_pa: 0.0,
                ..ForceSweep::default()
            },
        );
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
        let data = sweep(
            &reference(),
            &ForceSweep {
                n_stretch: 2,
                n_pressure: 3,
                ..ForceSweep::default()
            },
        );
        assert!(matches!(fit_eq6(&data), Err(IdentError::Data(_))));
    }
}
