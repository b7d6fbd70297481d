//! How well one recording reproduces another, channel by channel (the `fit` command, the
//! conformance checks): the fit of every channel both recordings carry, in memory or streamed
//! from their files, and its table.

use std::path::Path;

use crate::fit::{fit_from_norms, fit_percent, mae, mse};
use crate::io::recording::{Channel, Recording};

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

/// [`compare`] of two recording files without holding them: two passes over both files,
/// row by row (the first for the time columns and the means, the second for the errors),
/// with the same sums in the same order, so the figures are [`compare`]'s to the bit.
/// Memory: the two time columns (8 bytes a row each, for the checks of
/// [`Recording::read`](crate::io::recording::Recording::read) and the time comparison).
///
/// `None` when the stream does not decide: an error in a file (or a row it does not take,
/// e.g. quoted fields), recordings of different lengths or times, no common channel. Then
/// read both files and call [`compare`], which reports the error.
pub fn compare_files(reference: &Path, model: &Path) -> Option<Vec<ChannelFit>> {
    use crate::io::replay_stream::RowStream;
    let (mut a, mut b) = (RowStream::open(reference)?, RowStream::open(model)?);
    let common: Vec<Channel> = Channel::ALL
        .into_iter()
        .filter(|c| a.channels()[c.index()] && b.channels()[c.index()])
        .collect();
    if common.is_empty() {
        return None;
    }
    let (mut ta, mut tb) = (Vec::new(), Vec::new());
    let mut sum_y = [0.0f64; 5];
    loop {
        match (a.next_row().ok()?, b.next_row().ok()?) {
            (Some(ra), Some(rb)) => {
                ta.push(ra.0);
                tb.push(rb.0);
                for c in &common {
                    sum_y[c.index()] += ra.2[c.index()];
                }
            }
            (None, None) => break,
            _ => return None,
        }
    }
    if !(a.check_time(&ta) && b.check_time(&tb)) {
        return None;
    }
    let n = ta.len();
    let tol = 0.01 * crate::io::recording::mean_step_s(&ta).abs();
    if ta.iter().zip(&tb).any(|(x, y)| {
        let d = (x - y).abs();
        d.is_nan() || d > tol
    }) {
        return None;
    }
    drop((ta, tb));
    let mean = sum_y.map(|s| s / n as f64);
    let (mut a, mut b) = (RowStream::open(reference)?, RowStream::open(model)?);
    let (mut err2, mut spread2, mut abs_err) = ([0.0f64; 5], [0.0f64; 5], [0.0f64; 5]);
    loop {
        match (a.next_row().ok()?, b.next_row().ok()?) {
            (Some(ra), Some(rb)) => {
                for c in &common {
                    let i = c.index();
                    let (y, y_hat) = (ra.2[i], rb.2[i]);
                    err2[i] += (y - y_hat) * (y - y_hat);
                    spread2[i] += (y - mean[i]) * (y - mean[i]);
                    abs_err[i] += (y - y_hat).abs();
                }
            }
            (None, None) => break,
            _ => return None,
        }
    }
    Some(
        common
            .into_iter()
            .map(|c| {
                let i = c.index();
                ChannelFit {
                    channel: c,
                    fit_percent: fit_from_norms(
                        err2[i].sqrt(),
                        spread2[i].sqrt(),
                        n as f64,
                        mean[i],
                    ),
                    mae: abs_err[i] / n as f64,
                    mse: err2[i] / n as f64,
                    samples: n,
                }
            })
            .collect(),
    )
}

/// A plain-text table of fits.
pub fn format_table(fits: &[ChannelFit]) -> String {
    let mut s = format!(
        "{:<10} {:>10} {:>14} {:>14} {:>8}\n",
        "channel", "fit_%", "MAE", "MSE", "samples"
    );
    for f in fits {
        // A constant reference has no spread to normalise by: its fit is undefined (the note
        // under the table says so), not -inf.
        let fit = if f.fit_percent.is_finite() {
            format!("{:.4}", f.fit_percent)
        } else {
            "undefined".to_string()
        };
        s += &format!(
            "{:<10} {:>10} {:>14.6e} {:>14.6e} {:>8}\n",
            f.channel.name(),
            fit,
            f.mae,
            f.mse,
            f.samples
        );
    }
    s
}
