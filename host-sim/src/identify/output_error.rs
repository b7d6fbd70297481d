//! The one output-error fitter: bounded parameters, a residual function that replays the
//! plant (and may fail), minimised with the `levenberg-marquardt` crate (MINPACK's
//! trust-region Levenberg-Marquardt). `identify plant` and the diagnosis both fit through
//! [`fit`].
//!
//! - Bounds by reparameterisation: bounds `(lo, hi)` give `lo + (hi - lo) sigmoid(z)`, only a
//!   lower bound `lo + (x0 - lo) e^z`, only an upper bound `hi - (hi - x0) e^z`, none
//!   `x0 + z scale`; every z starts at 0 (a start on a bound is moved 0.1 % of the range
//!   inside).
//! - A residual function that fails (`None`: the plant could not be simulated) gives a large
//!   finite residual, so the trust region shrinks instead of the fit ending.
//! - The Jacobian by forward or central differences in z.
//! - The best parameters seen are returned (whatever the termination), with, on request,
//!   95 % confidence intervals from the Jacobian in x at the end: cov = s^2 (J^T J)^-1 with
//!   s^2 = |r|^2 / (m - n). Output errors are correlated in time, so these intervals are
//!   optimistic; they say which digits the recording determines, not a guarantee.

use std::cell::RefCell;

use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{DMatrix, DVector, Dyn, Owned};

/// One parameter: start value, bounds (may be infinite) and typical size.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OeParam {
    pub x0: f64,
    pub lo: f64,
    pub hi: f64,
    /// Typical size (the step of an unbounded parameter per unit of z; the finite-difference
    /// step of the confidence intervals).
    pub scale: f64,
}

impl OeParam {
    /// The start value, moved inside the bounds.
    fn start(&self) -> f64 {
        let (lo, hi) = (self.lo, self.hi);
        let x = self.x0;
        match (lo.is_finite(), hi.is_finite()) {
            (true, true) => {
                let m = 1e-3 * (hi - lo);
                x.clamp(lo + m, hi - m)
            }
            (true, false) => {
                if x > lo {
                    x
                } else {
                    lo + 1e-3 * self.scale.abs().max(1e-300)
                }
            }
            (false, true) => {
                if x < hi {
                    x
                } else {
                    hi - 1e-3 * self.scale.abs().max(1e-300)
                }
            }
            (false, false) => x,
        }
    }

    /// x(z); z = 0 gives the start value.
    pub fn to_x(&self, z: f64) -> f64 {
        let (lo, hi) = (self.lo, self.hi);
        let x0 = self.start();
        match (lo.is_finite(), hi.is_finite()) {
            (true, true) => {
                let s0 = ((x0 - lo) / (hi - lo)).clamp(1e-12, 1.0 - 1e-12);
                let z0 = (s0 / (1.0 - s0)).ln();
                lo + (hi - lo) / (1.0 + (-(z + z0)).exp())
            }
            (true, false) => lo + (x0 - lo) * z.exp(),
            (false, true) => hi - (hi - x0) * z.exp(),
            (false, false) => x0 + z * self.scale.abs().max(x0.abs()).max(1e-300),
        }
    }
}

/// Finite differences of the Jacobian.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Differences {
    /// One replay per parameter.
    Forward,
    /// Two replays per parameter (smoother; for tight integrator tolerances).
    Central,
}

/// Options of [`fit`].
#[derive(Debug, Clone, Copy)]
pub struct OeOptions {
    /// Step in z.
    pub fd_step: f64,
    pub differences: Differences,
    /// The crate's patience: at most `patience * (n + 1)` residual evaluations (Jacobian
    /// replays not counted).
    pub patience: usize,
    /// `ftol` and `xtol` of the crate (relative reduction of the cost and of the step).
    pub tol: f64,
    /// Also compute 95 % confidence intervals (n more replays).
    pub ci95: bool,
}

impl Default for OeOptions {
    fn default() -> Self {
        Self {
            fd_step: 1e-4,
            differences: Differences::Central,
            patience: 40,
            tol: 30.0 * f64::EPSILON,
            ci95: false,
        }
    }
}

/// Result of [`fit`].
#[derive(Debug, Clone)]
pub struct OeResult {
    /// Best parameters seen.
    pub x: Vec<f64>,
    /// 0.5 |r|^2 at the start and at `x` (infinite if the start could not be evaluated).
    pub cost: (f64, f64),
    /// Residual evaluations (Jacobian replays included).
    pub evaluations: usize,
    pub termination: String,
    /// 95 % confidence interval of each parameter (if asked for and the Jacobian is of full
    /// rank; else NaN).
    pub ci95: Vec<[f64; 2]>,
}

/// A residual function of the parameters (in x); `None` when the model fails there.
pub type Residuals<'a> = dyn Fn(&[f64]) -> Option<Vec<f64>> + 'a;

struct Problem<'a, 'f> {
    params: &'a [OeParam],
    f: &'a Residuals<'f>,
    opts: OeOptions,
    m: usize,
    evaluations: RefCell<usize>,
    best: RefCell<(f64, DVector<f64>)>,
}

impl Problem<'_, '_> {
    fn x(&self, z: &DVector<f64>) -> Vec<f64> {
        self.params
            .iter()
            .zip(z.iter())
            .map(|(p, z)| p.to_x(*z))
            .collect()
    }

    fn eval(&self, z: &DVector<f64>) -> DVector<f64> {
        *self.evaluations.borrow_mut() += 1;
        let r = match (self.f)(&self.x(z)) {
            Some(r) if r.len() == self.m && r.iter().all(|v| v.is_finite()) => DVector::from_vec(r),
            _ => DVector::from_element(self.m, 10.0),
        };
        let cost = 0.5 * r.norm_squared();
        let mut best = self.best.borrow_mut();
        if cost < best.0 {
            *best = (cost, z.clone());
        }
        r
    }
}

impl LmResiduals for Problem<'_, '_> {
    fn residuals_at(&self, z: &DVector<f64>) -> Option<DVector<f64>> {
        Some(self.eval(z))
    }

    fn jacobian_at(&self, z: &DVector<f64>, r0: &DVector<f64>) -> Option<DMatrix<f64>> {
        let n = z.len();
        let mut j = DMatrix::zeros(self.m, n);
        let h = self.opts.fd_step;
        for k in 0..n {
            let mut zp = z.clone();
            zp[k] += h;
            let rp = self.eval(&zp);
            match self.opts.differences {
                Differences::Forward => j.set_column(k, &((rp - r0) / h)),
                Differences::Central => {
                    let mut zm = z.clone();
                    zm[k] -= h;
                    let rm = self.eval(&zm);
                    j.set_column(k, &((rp - rm) / (2.0 * h)));
                }
            }
        }
        Some(j)
    }
}

/// A least-squares problem for the `levenberg_marquardt` solver, driven through
/// [`LmProblem`]: the residuals at a parameter vector and the Jacobian there.
pub(crate) trait LmResiduals {
    /// The residuals at `x`; `None` where they are not defined (the solver rejects the step).
    fn residuals_at(&self, x: &DVector<f64>) -> Option<DVector<f64>>;
    /// The Jacobian at `x`, whose residuals are `r`.
    fn jacobian_at(&self, x: &DVector<f64>, r: &DVector<f64>) -> Option<DMatrix<f64>>;
}

/// `problem` at the parameters `x` the solver set last, with their residuals (evaluated once
/// per point set): the solver's `LeastSquaresProblem`.
pub(crate) struct LmProblem<P> {
    pub problem: P,
    pub x: DVector<f64>,
    r: Option<DVector<f64>>,
}

impl<P: LmResiduals> LmProblem<P> {
    /// `problem` at `x0`.
    pub fn new(problem: P, x0: DVector<f64>) -> Self {
        let r = problem.residuals_at(&x0);
        Self { problem, x: x0, r }
    }
}

impl<P: LmResiduals> LeastSquaresProblem<f64, Dyn, Dyn> for LmProblem<P> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, x: &DVector<f64>) {
        self.x.copy_from(x);
        self.r = self.problem.residuals_at(x);
    }

    fn params(&self) -> DVector<f64> {
        self.x.clone()
    }

    fn residuals(&self) -> Option<DVector<f64>> {
        self.r.clone()
    }

    fn jacobian(&self) -> Option<DMatrix<f64>> {
        self.problem.jacobian_at(&self.x, self.r.as_ref()?)
    }
}

/// Fits `params` by minimising |f(x)|^2.
pub fn fit(f: &Residuals<'_>, params: &[OeParam], opts: &OeOptions) -> OeResult {
    let n = params.len();
    let x_start: Vec<f64> = params.iter().map(|p| p.to_x(0.0)).collect();
    let Some(r0) = f(&x_start).filter(|r| !r.is_empty() && r.iter().all(|v| v.is_finite())) else {
        return OeResult {
            x: x_start,
            cost: (f64::INFINITY, f64::INFINITY),
            evaluations: 1,
            termination: "the start could not be evaluated".into(),
            ci95: vec![[f64::NAN; 2]; n],
        };
    };
    let cost0 = 0.5 * r0.iter().map(|v| v * v).sum::<f64>();
    if n == 0 {
        return OeResult {
            x: x_start,
            cost: (cost0, cost0),
            evaluations: 1,
            termination: "no parameter".into(),
            ci95: Vec::new(),
        };
    }
    let z0 = DVector::zeros(n);
    let problem = Problem {
        params,
        f,
        opts: *opts,
        m: r0.len(),
        evaluations: RefCell::new(1),
        best: RefCell::new((cost0, z0.clone())),
    };
    let (LmProblem { problem, .. }, report) = LevenbergMarquardt::new()
        .with_stepbound(1.0)
        .with_patience(opts.patience.max(1))
        .with_ftol(opts.tol)
        .with_xtol(opts.tol)
        .minimize(LmProblem::new(problem, z0));
    let (cost1, z_best) = problem.best.borrow().clone();
    let x = problem.x(&z_best);
    let mut evaluations = *problem.evaluations.borrow();
    let ci95 = if opts.ci95 {
        let (u, used) = uncertainty(f, params, &x);
        evaluations += used;
        u.ci95(&x)
    } else {
        vec![[f64::NAN; 2]; n]
    };
    OeResult {
        x,
        cost: (cost0, cost1),
        evaluations,
        termination: format!(
            "{:?} after {} evaluations",
            report.termination, report.number_of_evaluations
        ),
        ci95,
    }
}

/// How well the residuals determine each parameter at `x` (see [`uncertainty`]).
#[derive(Debug, Clone)]
pub struct Uncertainty {
    /// Standard deviation of each parameter (NaN when the Jacobian is rank deficient there:
    /// the residuals do not move with some combination of the parameters).
    pub sd: Vec<f64>,
    /// Correlation of each pair (NaN as `sd`).
    pub correlation: DMatrix<f64>,
}

impl Uncertainty {
    /// The 95 % interval of each parameter about `x` (`x -+ 1.96 sd`).
    pub fn ci95(&self, x: &[f64]) -> Vec<[f64; 2]> {
        x.iter()
            .zip(&self.sd)
            .map(|(x, sd)| [x - 1.96 * sd, x + 1.96 * sd])
            .collect()
    }
}

/// The parameters' covariance at `x` from a forward-difference Jacobian in x: `s^2 (J^T
/// J)^-1` with `s^2 = |r|^2 / (m - n)`, as standard deviations and correlations; also the
/// replays used. Output errors are correlated in time, so the spreads are optimistic: a
/// parameter they call loosely determined is, one they call tight may still not be.
pub fn uncertainty(f: &Residuals<'_>, params: &[OeParam], x: &[f64]) -> (Uncertainty, usize) {
    let n = x.len();
    let undetermined = |used| {
        (
            Uncertainty {
                sd: vec![f64::NAN; n],
                correlation: DMatrix::from_element(n, n, f64::NAN),
            },
            used,
        )
    };
    let Some(r) = f(x) else {
        return undetermined(1);
    };
    let m = r.len();
    if m <= n {
        return undetermined(1);
    }
    let mut jac = DMatrix::<f64>::zeros(m, n);
    for k in 0..n {
        let h = 1e-4 * params[k].scale.abs().max(x[k].abs()).max(1e-300);
        // Forward, or backward where the model refuses the step (a value at a limit the
        // model enforces, e.g. one key bounded by another).
        let step = |h: f64| {
            let mut xp = x.to_vec();
            xp[k] += h;
            f(&xp).map(|rp| (rp, h))
        };
        let Some((rp, h)) = step(h).or_else(|| step(-h)) else {
            return undetermined(1 + 2 * (k + 1));
        };
        for i in 0..m {
            jac[(i, k)] = (rp[i] - r[i]) / h;
        }
    }
    let s2 = r.iter().map(|v| v * v).sum::<f64>() / (m - n) as f64;
    // A parameter the residuals do not move with (its column, scaled by the parameter's
    // size, vanishes next to the others') is undetermined on its own; the covariance of the
    // others is taken without it.
    let size = |k: usize| params[k].scale.abs().max(x[k].abs()).max(1e-300);
    let norms: Vec<f64> = (0..n).map(|k| jac.column(k).norm() * size(k)).collect();
    let top = norms.iter().cloned().fold(0.0, f64::max);
    let kept: Vec<usize> = (0..n).filter(|&k| norms[k] > 1e-9 * top).collect();
    let j = jac.select_columns(&kept);
    let Some(inv) = (j.transpose() * &j).try_inverse() else {
        return undetermined(1 + n);
    };
    let mut sd = vec![f64::NAN; n];
    let mut correlation = DMatrix::from_element(n, n, f64::NAN);
    for (a, &i) in kept.iter().enumerate() {
        sd[i] = (s2 * inv[(a, a)]).max(0.0).sqrt();
        for (b, &k) in kept.iter().enumerate() {
            correlation[(i, k)] = inv[(a, b)] / (inv[(a, a)] * inv[(b, b)]).max(0.0).sqrt();
        }
    }
    (Uncertainty { sd, correlation }, 1 + 2 * n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reparameterisation_starts_at_x0_and_respects_bounds() {
        let both = OeParam {
            x0: 0.433,
            lo: 0.0,
            hi: 1.0,
            scale: 0.4,
        };
        assert!((both.to_x(0.0) - 0.433).abs() < 1e-12);
        for z in [-50.0, -3.0, 3.0, 50.0] {
            assert!((0.0..=1.0).contains(&both.to_x(z)));
        }
        let lower = OeParam {
            x0: 0.014,
            lo: 0.0,
            hi: f64::INFINITY,
            scale: 0.01,
        };
        assert!((lower.to_x(0.0) - 0.014).abs() < 1e-15);
        assert!(lower.to_x(-40.0) > 0.0);
        let upper = OeParam {
            x0: -2.0,
            lo: f64::NEG_INFINITY,
            hi: 0.0,
            scale: 1.0,
        };
        assert!((upper.to_x(0.0) + 2.0).abs() < 1e-15);
        assert!(upper.to_x(5.0) < 0.0);
        // A start on a bound is moved inside, so the fit can leave it.
        let at = OeParam {
            x0: 1.0,
            lo: 1.0,
            hi: 1.4,
            scale: 1.0,
        };
        assert!(at.to_x(0.0) > 1.0 && at.to_x(0.0) < 1.001);
    }

    #[test]
    fn fits_an_exponential_with_intervals_covering_the_truth() {
        // y = a exp(-b t) + noise, a textbook output-error problem.
        let t: Vec<f64> = (0..200).map(|k| k as f64 * 0.02).collect();
        let noise: Vec<f64> = (0..200)
            .map(|k| 0.01 * ((k * 7919 % 200) as f64 / 100.0 - 1.0))
            .collect();
        let y: Vec<f64> = t
            .iter()
            .zip(&noise)
            .map(|(t, e)| 2.0 * (-1.3 * t).exp() + e)
            .collect();
        let f = |x: &[f64]| -> Option<Vec<f64>> {
            Some(
                t.iter()
                    .zip(&y)
                    .map(|(t, y)| x[0] * (-x[1] * t).exp() - y)
                    .collect(),
            )
        };
        let params = [
            OeParam {
                x0: 1.0,
                lo: 0.0,
                hi: 10.0,
                scale: 1.0,
            },
            OeParam {
                x0: 0.5,
                lo: 0.0,
                hi: f64::INFINITY,
                scale: 1.0,
            },
        ];
        let r = fit(
            &f,
            &params,
            &OeOptions {
                ci95: true,
                ..OeOptions::default()
            },
        );
        assert!((r.x[0] - 2.0).abs() < 0.02, "{:?}", r.x);
        assert!((r.x[1] - 1.3).abs() < 0.02, "{:?}", r.x);
        for (k, truth) in [2.0, 1.3].iter().enumerate() {
            let [lo, hi] = r.ci95[k];
            assert!(lo < *truth && *truth < hi, "{k}: [{lo}, {hi}]");
            assert!(hi - lo < 0.05, "{k}: [{lo}, {hi}]");
        }
        assert!(r.cost.1 < r.cost.0);
    }

    #[test]
    fn intervals_of_parameters_of_very_different_sizes_are_determined() {
        // A sonic conductance (1e-8 m^3/(s Pa)) fitted with an inertia (1e-2 kg m^2): the
        // same exponential with a = 2e-8 * 1e8 and b = 0.013 * 100, with a little noise.
        let t: Vec<f64> = (0..400).map(|k| k as f64 * 0.01).collect();
        let y: Vec<f64> = t
            .iter()
            .enumerate()
            .map(|(k, t)| 2.0 * (-1.3 * t).exp() + 1e-4 * ((k * 7919 % 400) as f64 / 200.0 - 1.0))
            .collect();
        let f = |x: &[f64]| -> Option<Vec<f64>> {
            Some(
                t.iter()
                    .zip(&y)
                    .map(|(t, y)| 1e8 * x[0] * (-100.0 * x[1] * t).exp() - y)
                    .collect(),
            )
        };
        let x = [2e-8, 0.013];
        let params = [
            OeParam {
                x0: x[0],
                lo: 0.0,
                hi: f64::INFINITY,
                scale: 1e-8,
            },
            OeParam {
                x0: x[1],
                lo: 0.0,
                hi: f64::INFINITY,
                scale: 1e-2,
            },
        ];
        let (u, _) = uncertainty(&f, &params, &x);
        for (k, v) in x.iter().enumerate() {
            let rel = u.sd[k] / v;
            assert!(
                rel.is_finite() && rel > 0.0 && rel < 1e-3,
                "{k}: sd {} ({rel})",
                u.sd[k]
            );
        }
        assert!(u.correlation[(0, 1)].abs() < 1.0, "{}", u.correlation);
    }

    #[test]
    fn a_failing_model_region_is_avoided() {
        // The model fails for x > 3; the optimum is at 2.
        let f = |x: &[f64]| -> Option<Vec<f64>> {
            (x[0] <= 3.0).then(|| vec![x[0] - 2.0, 0.5 * (x[0] - 2.0)])
        };
        let r = fit(
            &f,
            &[OeParam {
                x0: 0.0,
                lo: f64::NEG_INFINITY,
                hi: f64::INFINITY,
                scale: 1.0,
            }],
            &OeOptions::default(),
        );
        assert!((r.x[0] - 2.0).abs() < 1e-6, "{:?}", r);
    }
}
