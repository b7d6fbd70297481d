//! Derivative-free optimizers shared by the gain tuner (`host-sim tune`) and the law
//! comparison: Nelder-Mead (with restarts) and a pattern search over discrete moves.
//!
//! Hand-written rather than a crate (argmin would fit, but its solvers own the loop and the
//! cost-function trait, and the tuner needs infinite costs for failed runs, evaluation counts
//! and a pattern search over arbitrary move sets, e.g. a flipped set-point weight): the
//! methods are the textbook ones and are tested on textbook functions (Rosenbrock, Himmelblau,
//! a bowl with a forbidden region).

/// Result of [`nelder_mead`] and [`nelder_mead_restarted`].
#[derive(Debug, Clone, PartialEq)]
pub struct NelderMeadResult {
    /// Best point.
    pub x: Vec<f64>,
    /// Cost at `x`.
    pub cost: f64,
    /// Cost evaluations used.
    pub evaluations: usize,
}

/// Nelder-Mead simplex minimisation (standard coefficients: reflection 1, expansion 2,
/// contraction 1/2, shrink 1/2) from `x0` with initial simplex steps `step`, until the
/// spread of the simplex costs is below `f_tol` or `max_evals` evaluations are used.
/// Infinite (or NaN) costs, e.g. failed runs, are allowed: they are simply never best.
pub fn nelder_mead(
    mut f: impl FnMut(&[f64]) -> f64,
    x0: &[f64],
    step: &[f64],
    f_tol: f64,
    max_evals: usize,
) -> NelderMeadResult {
    let n = x0.len();
    let mut evals = 0;
    let mut eval = |x: &[f64], evals: &mut usize| {
        *evals += 1;
        let c = f(x);
        if c.is_nan() {
            f64::INFINITY
        } else {
            c
        }
    };
    let mut simplex: Vec<(Vec<f64>, f64)> = Vec::with_capacity(n + 1);
    let c0 = eval(x0, &mut evals);
    simplex.push((x0.to_vec(), c0));
    for i in 0..n {
        let mut x = x0.to_vec();
        x[i] += step[i];
        let c = eval(&x, &mut evals);
        simplex.push((x, c));
    }
    let lerp = |a: &[f64], b: &[f64], t: f64| -> Vec<f64> {
        a.iter().zip(b).map(|(a, b)| a + t * (b - a)).collect()
    };
    while evals < max_evals {
        simplex.sort_by(|a, b| a.1.total_cmp(&b.1));
        let (best, worst) = (simplex[0].1, simplex[n].1);
        if worst.is_finite() && (worst - best).abs() <= f_tol {
            break;
        }
        // Centroid of all but the worst.
        let mut centroid = vec![0.0; n];
        for (x, _) in &simplex[..n] {
            for (c, xi) in centroid.iter_mut().zip(x) {
                *c += xi / n as f64;
            }
        }
        let xw = simplex[n].0.clone();
        let xr = lerp(&centroid, &xw, -1.0);
        let cr = eval(&xr, &mut evals);
        if cr < simplex[0].1 {
            let xe = lerp(&centroid, &xw, -2.0);
            let ce = eval(&xe, &mut evals);
            simplex[n] = if ce < cr { (xe, ce) } else { (xr, cr) };
        } else if cr < simplex[n - 1].1 {
            simplex[n] = (xr, cr);
        } else {
            // Contraction: outside if the reflection improved on the worst, else inside.
            let t = if cr < simplex[n].1 { -0.5 } else { 0.5 };
            let xc = lerp(&centroid, &xw, t);
            let cc = eval(&xc, &mut evals);
            if cc < simplex[n].1.min(cr) {
                simplex[n] = (xc, cc);
            } else {
                let x0 = simplex[0].0.clone();
                for v in simplex.iter_mut().skip(1) {
                    let x = lerp(&x0, &v.0, 0.5);
                    let c = eval(&x, &mut evals);
                    *v = (x, c);
                }
            }
        }
    }
    simplex.sort_by(|a, b| a.1.total_cmp(&b.1));
    let (x, cost) = simplex.swap_remove(0);
    NelderMeadResult {
        x,
        cost,
        evaluations: evals,
    }
}

/// Nelder-Mead restarted from its own best point (a fresh simplex of steps `step`) while a
/// restart lowers the cost by more than `min_gain` (relative), at most `max_restarts` runs of
/// at most `evals_per_run` evaluations. A simplex that has collapsed in one direction stalls;
/// a fresh one does not. `on_run(run, evaluations, cost)` is called after each run.
#[allow(clippy::too_many_arguments)]
pub fn nelder_mead_restarted(
    mut f: impl FnMut(&[f64]) -> f64,
    x0: &[f64],
    step: &[f64],
    f_tol: f64,
    evals_per_run: usize,
    max_restarts: usize,
    min_gain: f64,
    mut on_run: impl FnMut(usize, usize, f64),
) -> NelderMeadResult {
    let mut x = x0.to_vec();
    let mut c = {
        let c = f(&x);
        if c.is_nan() {
            f64::INFINITY
        } else {
            c
        }
    };
    let mut evaluations = 1;
    for run in 1..=max_restarts.max(1) {
        let r = nelder_mead(&mut f, &x, step, f_tol, evals_per_run);
        evaluations += r.evaluations;
        on_run(run, r.evaluations, r.cost);
        let gain = r.cost < c * (1.0 - min_gain) || (!c.is_finite() && r.cost.is_finite());
        if r.cost < c {
            x = r.x;
            c = r.cost;
        }
        if !gain {
            break;
        }
    }
    NelderMeadResult {
        x,
        cost: c,
        evaluations,
    }
}

/// Result of [`pattern_search`].
#[derive(Debug, Clone, PartialEq)]
pub struct PatternSearchResult<T> {
    /// Best point.
    pub point: T,
    /// Its cost.
    pub cost: f64,
    /// Cost evaluations used.
    pub evaluations: usize,
}

/// Pattern search over discrete moves: evaluates every move of the current point (`moves_of`,
/// all at once through `costs`, so they can run in parallel), moves to the best if it lowers
/// the cost, until no move does or `max_evals` evaluations are used. The result is a local
/// optimum with respect to exactly these moves.
pub fn pattern_search<T: Clone>(
    start: T,
    start_cost: f64,
    moves_of: impl Fn(&T) -> Vec<T>,
    mut costs: impl FnMut(&[T]) -> Vec<f64>,
    max_evals: usize,
) -> PatternSearchResult<T> {
    let (mut p, mut c) = (start, start_cost);
    let mut evaluations = 0;
    while evaluations < max_evals {
        let moves = moves_of(&p);
        if moves.is_empty() {
            break;
        }
        let cs = costs(&moves);
        evaluations += moves.len();
        match cs
            .iter()
            .enumerate()
            .filter(|(_, c)| !c.is_nan())
            .min_by(|a, b| a.1.total_cmp(b.1))
        {
            Some((i, &cm)) if cm < c => {
                p = moves[i].clone();
                c = cm;
            }
            _ => break,
        }
    }
    PatternSearchResult {
        point: p,
        cost: c,
        evaluations,
    }
}

/// The multiplicative moves of a gain vector: each coordinate times each factor.
pub fn scale_moves(x: &[f64], factors: &[f64]) -> Vec<Vec<f64>> {
    let mut v = Vec::new();
    for &f in factors {
        for i in 0..x.len() {
            let mut m = x.to_vec();
            m[i] *= f;
            v.push(m);
        }
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rosenbrock(x: &[f64]) -> f64 {
        (1.0 - x[0]).powi(2) + 100.0 * (x[1] - x[0] * x[0]).powi(2)
    }

    fn himmelblau(x: &[f64]) -> f64 {
        (x[0] * x[0] + x[1] - 11.0).powi(2) + (x[0] + x[1] * x[1] - 7.0).powi(2)
    }

    #[test]
    fn nelder_mead_finds_the_rosenbrock_minimum() {
        let r = nelder_mead(rosenbrock, &[-1.2, 1.0], &[0.5, 0.5], 1e-14, 2000);
        assert!(
            (r.x[0] - 1.0).abs() < 1e-3 && (r.x[1] - 1.0).abs() < 1e-3,
            "{r:?}"
        );
        assert!(r.evaluations <= 2000);
    }

    #[test]
    fn nelder_mead_finds_a_himmelblau_minimum() {
        // Four minima of value 0; from (0, 0) the simplex goes to (3, 2).
        let r = nelder_mead(himmelblau, &[0.0, 0.0], &[1.0, 1.0], 1e-14, 2000);
        assert!(r.cost < 1e-8, "{r:?}");
        let minima = [
            (3.0, 2.0),
            (-2.805118, 3.131312),
            (-3.779310, -3.283186),
            (3.584428, -1.848126),
        ];
        assert!(
            minima
                .iter()
                .any(|m| (r.x[0] - m.0).abs() < 1e-3 && (r.x[1] - m.1).abs() < 1e-3),
            "{r:?}"
        );
    }

    #[test]
    fn nelder_mead_avoids_infinite_regions() {
        // Quadratic bowl at (2, -1) with a forbidden half-plane x0 < 0 (a failed run).
        let f = |x: &[f64]| {
            if x[0] < 0.0 {
                f64::INFINITY
            } else {
                (x[0] - 2.0).powi(2) + (x[1] + 1.0).powi(2)
            }
        };
        let r = nelder_mead(f, &[0.1, 0.0], &[-1.0, 1.0], 1e-12, 500);
        assert!(
            (r.x[0] - 2.0).abs() < 1e-3 && (r.x[1] + 1.0).abs() < 1e-3,
            "{r:?}"
        );
    }

    #[test]
    fn restarts_beat_a_single_short_run_on_the_4d_rosenbrock() {
        let rosen4 = |x: &[f64]| {
            (0..3)
                .map(|i| (1.0 - x[i]).powi(2) + 100.0 * (x[i + 1] - x[i] * x[i]).powi(2))
                .sum::<f64>()
        };
        let x0 = [-1.2, 1.0, -1.2, 1.0];
        let single = nelder_mead(rosen4, &x0, &[0.5; 4], 1e-16, 300);
        let mut runs = 0;
        let r = nelder_mead_restarted(rosen4, &x0, &[0.5; 4], 1e-16, 300, 30, 1e-6, |_, _, _| {
            runs += 1
        });
        assert!(runs > 1);
        assert!(r.cost < single.cost, "{} vs {}", r.cost, single.cost);
        assert!(r.cost < 1e-6, "{r:?}");
    }

    #[test]
    fn pattern_search_reaches_a_local_optimum_of_its_moves() {
        // Multiplicative moves on a positive bowl at (3, 0.5): the result is within one
        // move factor of the minimum and no move improves on it.
        let f = |x: &[f64]| (x[0].ln() - 3f64.ln()).powi(2) + (x[1].ln() - 0.5f64.ln()).powi(2);
        let factors = [0.9, 1.1];
        let r = pattern_search(
            vec![1.0, 1.0],
            f(&[1.0, 1.0]),
            |x: &Vec<f64>| scale_moves(x, &factors),
            |ms: &[Vec<f64>]| ms.iter().map(|m| f(m)).collect(),
            10_000,
        );
        assert!((r.point[0] / 3.0).ln().abs() < 0.1, "{r:?}");
        assert!((r.point[1] / 0.5).ln().abs() < 0.1, "{r:?}");
        for m in scale_moves(&r.point, &factors) {
            assert!(f(&m) >= r.cost);
        }
        // The evaluation budget is respected.
        let r = pattern_search(
            vec![1.0, 1.0],
            f(&[1.0, 1.0]),
            |x: &Vec<f64>| scale_moves(x, &factors),
            |ms: &[Vec<f64>]| ms.iter().map(|m| f(m)).collect(),
            8,
        );
        assert_eq!(r.evaluations, 8);
    }

    #[test]
    fn pattern_search_on_rosenbrock_descends_into_the_valley_and_stops_at_a_move_optimum() {
        // Axis moves of 0.01 stall in Rosenbrock's curved valley (the textbook weakness of
        // coordinate search, hence Nelder-Mead first and the pattern search only as a polish):
        // the cost falls by more than 5x from the textbook start, and no move improves.
        let start = vec![-1.2, 1.0];
        let moves = |x: &Vec<f64>| {
            let mut v = Vec::new();
            for i in 0..2 {
                for d in [-0.01, 0.01] {
                    let mut m = x.clone();
                    m[i] += d;
                    v.push(m);
                }
            }
            v
        };
        let r = pattern_search(
            start.clone(),
            rosenbrock(&start),
            moves,
            |ms: &[Vec<f64>]| ms.iter().map(|m| rosenbrock(m)).collect(),
            100_000,
        );
        assert!(r.cost < 0.2 * rosenbrock(&start), "{r:?}");
        assert!(r.evaluations < 100_000);
        for m in moves(&r.point) {
            assert!(rosenbrock(&m) >= r.cost);
        }
    }
}
