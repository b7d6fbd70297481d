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

pub use crate::signal::noise_level;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::signal::kth_smallest_nonneg;

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
