//! Sequentially thresholded least squares (STLSQ, the sparse regression of SINDy): least
//! squares on columns normalised to unit RMS, coefficients below a threshold set to zero,
//! the rest refitted, until the support stops changing.
//!
//! The least squares are nalgebra's Cholesky on the normal equations (a few columns over
//! thousands of samples), with a scale-invariant ridge of 1e-9 of each diagonal against
//! collinear columns, as [`crate::plant::effects::candidate::regress`] does.

/// The columns and the response of one slot's regression (samples in rows).
#[derive(Debug, Clone)]
pub struct Design {
    pub y: Vec<f64>,
    pub columns: Vec<Vec<f64>>,
}

/// A sparse fit: the chosen columns, their coefficients (in the columns' own units) and the
/// share of the response's energy they explain (uncentred R^2).
#[derive(Debug, Clone, PartialEq)]
pub struct SparseFit {
    pub support: Vec<usize>,
    pub coefficients: Vec<f64>,
    pub r2: f64,
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

/// Least squares of `y` on the columns `cols` (each scaled by `norm`); `None` if singular.
fn lstsq(y: &[f64], cols: &[&[f64]], norm: &[f64]) -> Option<(Vec<f64>, f64)> {
    let m = cols.len();
    let mut a = nalgebra::DMatrix::<f64>::zeros(m, m);
    let mut b = nalgebra::DVector::<f64>::zeros(m);
    let mut ss = 0.0;
    for k in 0..y.len() {
        ss += y[k] * y[k];
        for i in 0..m {
            let xi = cols[i][k] / norm[i];
            b[i] += xi * y[k];
            for j in i..m {
                a[(i, j)] += xi * cols[j][k] / norm[j];
            }
        }
    }
    for i in 0..m {
        for j in 0..i {
            a[(i, j)] = a[(j, i)];
        }
        a[(i, i)] *= 1.0 + 1e-9;
        if a[(i, i)] == 0.0 {
            return None;
        }
    }
    let c = a.cholesky()?.solve(&b);
    let explained = (c.transpose() * &b)[(0, 0)];
    let r2 = if ss > 0.0 {
        (explained / ss).clamp(0.0, 1.0)
    } else {
        0.0
    };
    Some((c.iter().copied().collect(), r2))
}

/// STLSQ of `d` at threshold `lambda` (on the coefficients of unit-RMS columns and a
/// unit-RMS response). `None` when nothing survives or the fit is singular.
pub fn stlsq(d: &Design, lambda: f64) -> Option<SparseFit> {
    let y_rms = rms(&d.y);
    if y_rms == 0.0 || d.columns.is_empty() {
        return None;
    }
    let y: Vec<f64> = d.y.iter().map(|v| v / y_rms).collect();
    let norms: Vec<f64> = d.columns.iter().map(|c| rms(c)).collect();
    let mut active: Vec<usize> = (0..d.columns.len()).filter(|&i| norms[i] > 0.0).collect();
    for _ in 0..20 {
        if active.is_empty() {
            return None;
        }
        let cols: Vec<&[f64]> = active.iter().map(|&i| d.columns[i].as_slice()).collect();
        let norm: Vec<f64> = active.iter().map(|&i| norms[i]).collect();
        let (c, r2) = lstsq(&y, &cols, &norm)?;
        let keep: Vec<usize> = active
            .iter()
            .zip(&c)
            .filter(|(_, v)| v.abs() >= lambda)
            .map(|(i, _)| *i)
            .collect();
        if keep.len() == active.len() {
            return Some(SparseFit {
                coefficients: active
                    .iter()
                    .zip(&c)
                    .map(|(i, v)| v * y_rms / norms[*i])
                    .collect(),
                support: active,
                r2,
            });
        }
        active = keep;
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stlsq_finds_the_two_true_columns_among_five() {
        use rand::{rngs::StdRng, Rng, SeedableRng};
        let mut rng = StdRng::seed_from_u64(4);
        let n = 4000;
        let cols: Vec<Vec<f64>> = (0..5)
            .map(|_| (0..n).map(|_| rng.random_range(-1.0..1.0)).collect())
            .collect();
        let y: Vec<f64> = (0..n)
            .map(|k| 3.0 * cols[1][k] - 0.5 * cols[3][k] + 0.05 * rng.random_range(-1.0..1.0))
            .collect();
        let f = stlsq(&Design { y, columns: cols }, 0.1).unwrap();
        assert_eq!(f.support, vec![1, 3]);
        assert!((f.coefficients[0] - 3.0).abs() < 0.01);
        assert!((f.coefficients[1] + 0.5).abs() < 0.01);
        assert!(f.r2 > 0.99);
    }
}
