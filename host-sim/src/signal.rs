//! Sampled-signal kernels shared by identification and diagnosis.

/// The half window (samples, at least 1) of a Savitzky-Golay filter spanning about `span_s`
/// on either side at sample period `dt_s`.
pub fn half_window_samples(span_s: f64, dt_s: f64) -> usize {
    ((span_s / dt_s).round() as usize).max(1)
}

/// Longest half window a derivative of a joint's motion may span [s]: a window of 0.2 s
/// already averages the velocity over a fifth of a second; longer ones smear every reversal
/// of a sweep (the default windows are 10 and 25 ms).
pub const HALF_WINDOW_MAX_S: f64 = 0.1;

/// Refuses a Savitzky-Golay half window whose full window (`2 hw + 1` samples) is longer
/// than the recording `file` of `n` samples (every sample would take a shrunk window, and
/// the velocity would be a line through the whole run), or whose half spans more than
/// [`HALF_WINDOW_MAX_S`] at the sample period `dt_s`. `option` names the argument.
pub fn window_fits(option: &str, hw: usize, n: usize, dt_s: f64, file: &str) -> anyhow::Result<()> {
    anyhow::ensure!(
        2 * hw < n,
        "{option} {hw}: its window of {} samples is longer than {file} ({n} samples); give at \
         most {}",
        2 * hw + 1,
        n.saturating_sub(1) / 2
    );
    let max = half_window_samples(HALF_WINDOW_MAX_S, dt_s);
    anyhow::ensure!(
        hw <= max,
        "{option} {hw}: {} s on either side at {file}'s {} s sample period, more than the \
         {HALF_WINDOW_MAX_S} s a velocity of a moving joint may be averaged over (it would \
         smear the motion's reversals into the damping terms); give at most {max}",
        crate::validate::Shown(hw as f64 * dt_s),
        crate::validate::Shown(dt_s)
    );
    Ok(())
}

/// First derivative of a uniformly sampled signal by a Savitzky-Golay filter: the slope of
/// the least-squares line (equivalently quadratic) over `2 half_window + 1` samples centred
/// on each sample, the window shrunk symmetrically near the ends; weights k / sum(k^2).
/// The first and last samples take the one-sided difference; with `half_window = 0` the
/// inside takes the central difference. Returns zeros for fewer than 2 samples or a
/// sample period that is not > 0.
pub fn savitzky_golay_derivative(y: &[f64], dt_s: f64, half_window: usize) -> Vec<f64> {
    let n = y.len();
    let mut out = vec![0.0; n];
    if n < 2 || !(dt_s > 0.0) {
        return out;
    }
    for (i, o) in out.iter_mut().enumerate() {
        let m = half_window.min(i).min(n - 1 - i);
        if m == 0 {
            *o = if i == 0 {
                (y[1] - y[0]) / dt_s
            } else if i == n - 1 {
                (y[n - 1] - y[n - 2]) / dt_s
            } else {
                (y[i + 1] - y[i - 1]) / (2.0 * dt_s)
            };
            continue;
        }
        let mut num = 0.0;
        let mut den = 0.0;
        for k in 1..=m {
            let kf = k as f64;
            num += kf * (y[i + k] - y[i - k]);
            den += 2.0 * kf * kf;
        }
        *o = num / (den * dt_s);
    }
    out
}

/// Pearson correlation of two equally long series (0 when either is constant or they are
/// shorter than 2).
pub fn correlation(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len().min(y.len());
    if n < 2 {
        return 0.0;
    }
    let mx = x[..n].iter().sum::<f64>() / n as f64;
    let my = y[..n].iter().sum::<f64>() / n as f64;
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (a, b) in x[..n].iter().zip(&y[..n]) {
        sxy += (a - mx) * (b - my);
        sxx += (a - mx) * (a - mx);
        syy += (b - my) * (b - my);
    }
    if sxx > 0.0 && syy > 0.0 {
        sxy / (sxx * syy).sqrt()
    } else {
        0.0
    }
}

/// An answer leaves TRAIN's error within this many times each channel's noise (or, on
/// noise-free data, of `crate::diagnose::verdict::FIT_FLOOR_REL`): beyond it, something else is off and the answer
/// is not called an explanation (`unexplained`, its best attempt reported).
pub const MAX_RESIDUAL_X_NOISE: f64 = 5.0;

/// Robust noise level of a sampled channel: the spread of its second differences (MAD,
/// white noise of standard deviation s gives second differences of spread s sqrt(6)),
/// floored by the quantisation step's uniform noise q / sqrt(12) (q: the smallest step the
/// channel takes).
pub fn noise_level(y: &[f64]) -> f64 {
    if y.len() < 4 {
        return 0.0;
    }
    let d2 = || y.windows(3).map(|w| (w[2] - 2.0 * w[1] + w[0]).abs());
    let mad = kth_smallest_nonneg(d2, (y.len() - 2) / 2);
    let sigma_mad = 1.4826 * mad / 6f64.sqrt();
    let steps = || {
        y.windows(2)
            .map(|w| (w[1] - w[0]).abs())
            .filter(|d| *d > 1e-12)
    };
    let n_steps = steps().count();
    let q = if n_steps == 0 {
        0.0
    } else {
        kth_smallest_nonneg(steps, n_steps / 20)
    };
    sigma_mad.max(q / 12f64.sqrt())
}

/// [`noise_level`] of a channel some of whose rows are not measurements (`measured(k)`
/// false: a row filled in a gap of the log): only second differences of three measured rows
/// in a row and steps between two measured rows count, so a gap's jump (or its filling) is
/// not taken for noise.
pub fn noise_level_where(y: &[f64], measured: impl Fn(usize) -> bool) -> f64 {
    let ok3: Vec<usize> = (2..y.len())
        .filter(|&k| measured(k) && measured(k - 1) && measured(k - 2))
        .collect();
    if ok3.len() < 2 {
        return 0.0;
    }
    let d2 = || {
        ok3.iter()
            .map(|&k| (y[k] - 2.0 * y[k - 1] + y[k - 2]).abs())
    };
    let mad = kth_smallest_nonneg(d2, ok3.len() / 2);
    let sigma_mad = 1.4826 * mad / 6f64.sqrt();
    let steps = || {
        (1..y.len())
            .filter(|&k| measured(k) && measured(k - 1))
            .map(|k| (y[k] - y[k - 1]).abs())
            .filter(|d| *d > 1e-12)
    };
    let n_steps = steps().count();
    let q = if n_steps == 0 {
        0.0
    } else {
        kth_smallest_nonneg(steps, n_steps / 20)
    };
    sigma_mad.max(q / 12f64.sqrt())
}

/// The `k`-th smallest (from 0) of the values `values()` yields, all of them non-negative
/// (a NaN ranks above infinity, as in `f64::total_cmp`), so that their bit patterns sort as
/// the values do: the element a sort of a copy would put at `k`, found 16 bits at a time
/// in four passes over `values()` with 65 536 counters instead of the copy (a channel of a
/// long recording is not duplicated). `k` must be below the number of values.
pub(crate) fn kth_smallest_nonneg<I: Iterator<Item = f64>>(
    values: impl Fn() -> I,
    mut k: usize,
) -> f64 {
    const DIGIT_BITS: u32 = 16;
    let mut counts = vec![0usize; 1 << DIGIT_BITS];
    // The bits fixed so far (the high ones) and their mask.
    let (mut prefix, mut mask) = (0u64, 0u64);
    for pass in 1..=64 / DIGIT_BITS {
        let shift = 64 - pass * DIGIT_BITS;
        counts.fill(0);
        for v in values() {
            let b = v.to_bits();
            if b & mask == prefix {
                counts[((b >> shift) & 0xFFFF) as usize] += 1;
            }
        }
        let mut below = 0;
        for (digit, &c) in counts.iter().enumerate() {
            if k < below + c {
                prefix |= (digit as u64) << shift;
                k -= below;
                break;
            }
            below += c;
        }
        mask |= 0xFFFF << shift;
    }
    f64::from_bits(prefix)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn derivative_of_a_ramp_is_its_slope() {
        let a: Vec<f64> = (0..100).map(|k| 0.5 * k as f64 * 0.001).collect();
        for hw in [0, 1, 5, 7] {
            for v in savitzky_golay_derivative(&a, 0.001, hw) {
                assert!((v - 0.5).abs() < 1e-9, "half window {hw}: {v}");
            }
        }
    }

    #[test]
    fn derivative_of_a_parabola_is_exact_inside() {
        let dt = 0.01;
        let a: Vec<f64> = (0..50).map(|k| (k as f64 * dt).powi(2)).collect();
        let v = savitzky_golay_derivative(&a, dt, 3);
        for (k, vk) in v.iter().enumerate().take(46).skip(4) {
            assert!((vk - 2.0 * k as f64 * dt).abs() < 1e-9);
        }
    }

    /// A jump over rows that are not measured is not noise: the level of a smooth ramp
    /// with jumps at unmeasured rows is that of the ramp alone, the same as where every row
    /// is measured and there is no jump.
    #[test]
    fn a_gaps_jump_is_not_noise() {
        let mut y: Vec<f64> = (0..400).map(|k| (k as f64 * 0.01).sin()).collect();
        let clean = noise_level(&y);
        let holes = |k: usize| k % 50 == 25;
        for k in (0..400).filter(|&k| holes(k)) {
            y[k] += 5.0;
        }
        assert!(noise_level_where(&y, |k| !holes(k)) <= clean * 1.01 + 1e-12);
        assert!(noise_level_where(&y, |_| true) >= noise_level(&y) * 0.99);
    }

    #[test]
    fn degenerate_input_gives_zeros() {
        assert_eq!(savitzky_golay_derivative(&[1.0], 0.1, 3), vec![0.0]);
        assert_eq!(
            savitzky_golay_derivative(&[1.0, 2.0], 0.0, 3),
            vec![0.0, 0.0]
        );
    }
}
