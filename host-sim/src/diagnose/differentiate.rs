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
    let mut d2: Vec<f64> = y
        .windows(3)
        .map(|w| (w[2] - 2.0 * w[1] + w[0]).abs())
        .collect();
    d2.sort_by(f64::total_cmp);
    let mad = d2[d2.len() / 2];
    drop(d2);
    let sigma_mad = 1.4826 * mad / 6f64.sqrt();
    let mut steps: Vec<f64> = y
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .filter(|d| *d > 1e-12)
        .collect();
    let q = if steps.is_empty() {
        0.0
    } else {
        steps.sort_by(f64::total_cmp);
        steps[steps.len() / 20]
    };
    sigma_mad.max(q / 12f64.sqrt())
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
