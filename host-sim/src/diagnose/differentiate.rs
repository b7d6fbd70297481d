//! Differentiation of measured channels (the "differentiation" step of a SINDy-like split):
//! a smoothed derivative that tolerates sensor noise and encoder quantisation.

/// How the diagnosis differentiates a sampled signal.
pub trait Differentiator: Sync {
    /// dy/dt at every sample of `y` (sample period `dt_s`).
    fn derivative(&self, y: &[f64], dt_s: f64) -> Vec<f64>;
}

/// Savitzky-Golay derivative ([`crate::signal::savitzky_golay_derivative`]).
#[derive(Debug, Clone, Copy)]
pub struct SavitzkyGolay {
    pub half_window: usize,
}

impl Default for SavitzkyGolay {
    fn default() -> Self {
        Self { half_window: 7 }
    }
}

impl Differentiator for SavitzkyGolay {
    fn derivative(&self, y: &[f64], dt_s: f64) -> Vec<f64> {
        crate::signal::savitzky_golay_derivative(y, dt_s, self.half_window)
    }
}

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

/// The `k`-th smallest (from 0) of the values `values()` yields, all of them non-negative
/// (a NaN ranks above infinity, as in `f64::total_cmp`), so that their bit patterns sort as
/// the values do: the element a sort of a copy would put at `k`, found 16 bits at a time
/// in four passes over `values()` with 65 536 counters instead of the copy (a channel of a
/// long recording is not duplicated). `k` must be below the number of values.
fn kth_smallest_nonneg<I: Iterator<Item = f64>>(values: impl Fn() -> I, mut k: usize) -> f64 {
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
    fn derivative_of_a_line_is_its_slope() {
        let y: Vec<f64> = (0..50).map(|k| 3.0 * k as f64 * 0.01 + 1.0).collect();
        let d = SavitzkyGolay::default().derivative(&y, 0.01);
        assert!(d.iter().all(|v| (v - 3.0).abs() < 1e-9));
    }

    /// The selection gives the element a sort puts at `k`, also among many equal values
    /// (quantised data), zeros, infinities and NaN.
    #[test]
    fn kth_smallest_matches_a_sorted_copy() {
        use rand::{rngs::StdRng, Rng, SeedableRng};
        let mut rng = StdRng::seed_from_u64(3);
        let mut cases: Vec<Vec<f64>> = vec![
            (0..5000).map(|_| rng.random::<f64>() * 1e3).collect(),
            (0..5000)
                .map(|_| (rng.random_range(0..7) as f64) * 0.25)
                .collect(),
            (0..3000).map(|_| rng.random::<f64>() * 1e-200).collect(),
        ];
        let mut mixed: Vec<f64> = (0..2000).map(|_| rng.random::<f64>()).collect();
        mixed.extend([0.0, f64::INFINITY, f64::NAN, 0.0, 5e-324, f64::MAX]);
        cases.push(mixed);
        cases.push(vec![2.5]);
        for v in cases {
            let mut sorted = v.clone();
            sorted.sort_by(f64::total_cmp);
            for k in [0, v.len() / 20, v.len() / 2, v.len() - 1] {
                let got = kth_smallest_nonneg(|| v.iter().copied(), k);
                assert_eq!(got.to_bits(), sorted[k].to_bits(), "k = {k} of {}", v.len());
            }
        }
    }

    #[test]
    fn noise_level_of_white_noise() {
        use rand::{rngs::StdRng, Rng, SeedableRng};
        let mut rng = StdRng::seed_from_u64(1);
        let y: Vec<f64> = (0..20000)
            .map(|k| {
                (k as f64 * 1e-3).sin() + rng.sample::<f64, _>(rand_distr::StandardNormal) * 0.5
            })
            .collect();
        let s = noise_level(&y);
        assert!((s - 0.5).abs() < 0.05, "{s}");
    }
}
