//! Goodness of fit per channel: NRMSE fit in % (Cakurda et al. eq. 23, PLANT.md "Fit"),
//! MAE (eq. 24) and MSE.

/// fit = 100 (1 - ||y - y_hat|| / ||y - mean(y)||).
///
/// A constant reference has a zero denominator: the fit is then 100 when `y_hat == y`
/// exactly and -infinity otherwise. Panics if the lengths differ.
pub fn fit_percent(y: &[f64], y_hat: &[f64]) -> f64 {
    assert_eq!(y.len(), y_hat.len(), "fit_percent: lengths differ");
    let err2: f64 = y
        .iter()
        .zip(y_hat)
        .map(|(a, b)| (a - b) * (a - b))
        .sum::<f64>();
    fit_percent_of_err2(y, err2)
}

/// [`fit_percent`] of `y` against a prediction that is not held: `err2` is the sum over the
/// samples, in order, of `(y_k - y_hat_k)^2` (then the same value to the bit).
pub fn fit_percent_of_err2(y: &[f64], err2: f64) -> f64 {
    fit_percent_by(|| y.iter().copied(), err2)
}

/// [`fit_percent_of_err2`] of a reference that is not held either: `y()` yields its samples
/// in order (called three times).
pub fn fit_percent_by<I: Iterator<Item = f64>>(y: impl Fn() -> I, err2: f64) -> f64 {
    let n = y().count() as f64;
    let mean = y().sum::<f64>() / n;
    let spread: f64 = y().map(|a| (a - mean) * (a - mean)).sum::<f64>().sqrt();
    fit_from_norms(err2.sqrt(), spread, n, mean)
}

/// 100 (1 - err / spread) from `err = ||y - y_hat||`, `spread = ||y - mean(y)||` and the
/// reference's mean (its scale). A reference whose spread is rounding (1e-12 of its scale:
/// a constant column read from text, whose mean is not exact) is constant: the fit is then 100
/// when the prediction matches it as closely, else undefined (`-inf`).
pub(crate) fn fit_from_norms(err: f64, spread: f64, n: f64, mean: f64) -> f64 {
    let rounding = 1e-12 * n.sqrt() * mean.abs().max(1e-9);
    if spread <= rounding {
        return if err <= rounding {
            100.0
        } else {
            f64::NEG_INFINITY
        };
    }
    100.0 * (1.0 - err / spread)
}

/// Mean absolute error.
pub fn mae(y: &[f64], y_hat: &[f64]) -> f64 {
    assert_eq!(y.len(), y_hat.len(), "mae: lengths differ");
    y.iter().zip(y_hat).map(|(a, b)| (a - b).abs()).sum::<f64>() / y.len() as f64
}

/// Mean squared error.
pub fn mse(y: &[f64], y_hat: &[f64]) -> f64 {
    assert_eq!(y.len(), y_hat.len(), "mse: lengths differ");
    y.iter()
        .zip(y_hat)
        .map(|(a, b)| (a - b) * (a - b))
        .sum::<f64>()
        / y.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn perfect_model_fits_100_percent() {
        let y = [1.0, 2.0, 4.0, 3.0];
        assert_eq!(fit_percent(&y, &y), 100.0);
        assert_eq!(mae(&y, &y), 0.0);
    }

    #[test]
    fn a_constant_reference_is_constant_despite_the_rounding_of_its_mean() {
        // -7.380001 read 800 times: the mean is not exact, the spread is rounding only.
        let y = vec![-7.380001f64; 800];
        let mean = y.iter().sum::<f64>() / 800.0;
        assert!(
            y.iter().any(|v| *v != mean),
            "the case needs an inexact mean"
        );
        assert_eq!(fit_percent(&y, &vec![-7.3; 800]), f64::NEG_INFINITY);
        assert_eq!(fit_percent(&y, &y), 100.0);
        // A small real variation is still a fit.
        let mut z = y.clone();
        z[400] += 1e-6;
        assert!(fit_percent(&z, &y).is_finite());
    }

    #[test]
    fn mean_model_fits_0_percent() {
        let y = [1.0, 3.0];
        assert!((fit_percent(&y, &[2.0, 2.0])).abs() < 1e-12);
    }

    #[test]
    fn known_values() {
        let y = [0.0, 2.0];
        let y_hat = [0.5, 2.0];
        // ||e|| = 0.5, ||y - mean|| = sqrt(2)
        assert!((fit_percent(&y, &y_hat) - 100.0 * (1.0 - 0.5 / 2f64.sqrt())).abs() < 1e-12);
        assert!((mae(&y, &y_hat) - 0.25).abs() < 1e-15);
        assert!((mse(&y, &y_hat) - 0.125).abs() < 1e-15);
    }
}
