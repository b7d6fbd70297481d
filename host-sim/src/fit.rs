//! Goodness of fit per channel: NRMSE fit in % (Cakurda et al. eq. 23, PLANT.md "Fit"),
//! MAE (eq. 24) and MSE.

use crate::io::recording::{Channel, Recording};

/// fit = 100 (1 - ||y - y_hat|| / ||y - mean(y)||).
///
/// A constant reference has a zero denominator: the fit is then 100 when `y_hat == y`
/// exactly and -infinity otherwise. Panics if the lengths differ.
pub fn fit_percent(y: &[f64], y_hat: &[f64]) -> f64 {
    assert_eq!(y.len(), y_hat.len(), "fit_percent: lengths differ");
    let n = y.len() as f64;
    let mean = y.iter().sum::<f64>() / n;
    let err: f64 = y
        .iter()
        .zip(y_hat)
        .map(|(a, b)| (a - b) * (a - b))
        .sum::<f64>()
        .sqrt();
    let spread: f64 = y
        .iter()
        .map(|a| (a - mean) * (a - mean))
        .sum::<f64>()
        .sqrt();
    if spread == 0.0 {
        return if err == 0.0 { 100.0 } else { f64::NEG_INFINITY };
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

/// The fit of one channel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChannelFit {
    pub channel: Channel,
    pub fit_percent: f64,
    pub mae: f64,
    pub mse: f64,
    pub samples: usize,
}

#[derive(Debug, thiserror::Error)]
pub enum FitError {
    #[error("the recordings have different lengths ({0} and {1} samples)")]
    Length(usize, usize),
    #[error("the recordings differ in time at sample {index}: t_s = {a} and {b}")]
    Time { index: usize, a: f64, b: f64 },
    #[error("the recordings have no output channel in common")]
    NoCommonChannel,
}

/// Fits of every channel present in both recordings (`reference` is y, `model` is y_hat).
pub fn compare(reference: &Recording, model: &Recording) -> Result<Vec<ChannelFit>, FitError> {
    if reference.len() != model.len() {
        return Err(FitError::Length(reference.len(), model.len()));
    }
    let tol = 0.01 * reference.sample_period_s().abs();
    for (index, (a, b)) in reference.t_s.iter().zip(&model.t_s).enumerate() {
        let d = (a - b).abs();
        if d.is_nan() || d > tol {
            return Err(FitError::Time {
                index,
                a: *a,
                b: *b,
            });
        }
    }
    let fits: Vec<ChannelFit> = Channel::ALL
        .into_iter()
        .filter_map(|c| {
            let y = reference.channel(c)?;
            let y_hat = model.channel(c)?;
            Some(ChannelFit {
                channel: c,
                fit_percent: fit_percent(y, y_hat),
                mae: mae(y, y_hat),
                mse: mse(y, y_hat),
                samples: y.len(),
            })
        })
        .collect();
    if fits.is_empty() {
        return Err(FitError::NoCommonChannel);
    }
    Ok(fits)
}

/// A plain-text table of fits.
pub fn format_table(fits: &[ChannelFit]) -> String {
    let mut s = format!(
        "{:<10} {:>10} {:>14} {:>14} {:>8}\n",
        "channel", "fit_%", "MAE", "MSE", "samples"
    );
    for f in fits {
        s += &format!(
            "{:<10} {:>10.4} {:>14.6e} {:>14.6e} {:>8}\n",
            f.channel.name(),
            f.fit_percent,
            f.mae,
            f.mse,
            f.samples
        );
    }
    s
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
