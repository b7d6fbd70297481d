//! The hybrid model's learned chamber volume (seed 004, eq. 8-9): a feed-forward network of
//! two hidden layers of [`HIDDEN`] units estimating the muscle's volume
//! `V(e, e', P, P')` from its contraction `e`, contraction rate `e'`, absolute pressure `P`
//! and pressure rate `P'`, and the volume's rate along the motion (eq. 9)
//!
//! ```text
//! V' = dV/de e' + dV/dP P'
//! ```
//!
//! by forward-mode differentiation (one tangent pass next to the value pass). The pressure
//! feed-forward ([`crate::pressure_ff`]) uses them in eq. 7 in place of the volume polynomial
//! when the crate feature `volume-fnn` is on, which makes it seed 004's eq. 12.
//!
//! Network: inputs normalised `x_n = (x - mean) / std`, then
//! `a1 = s(W1 x_n + b1)`, `a2 = s(W2 a1 + b2)`, `y = w3 . a2 + b3`,
//! `V = volume_offset + volume_scale y`, floored at `volume_floor`; `s(z) = z / (1 + |z|)`
//! (softsign: smooth like the seed's SoftPlus, but one division instead of an exponential and
//! a logarithm per unit on the MCU). Trained by `host-sim identify volume` (seed 004 eq. 10:
//! mass-flow error + weight decay); the weights come from `config/volume.toml` through
//! `build.rs` ([`crate::constants::VOLUME_FNN`]).
//!
//! Cost per call (two muscles per tick): `4 H + H H` multiply-adds for the value, `2 H + H H`
//! for the tangent (only `e` and `P` move along eq. 9), `2 H` divisions. f32, no allocation,
//! never NaN out for finite weights (non-finite inputs give the floor and a zero rate).

/// Units per hidden layer (both layers).
pub const HIDDEN: usize = 8;
/// Network inputs: contraction [-], contraction rate [1/s], absolute pressure [Pa], pressure
/// rate [Pa/s].
pub const INPUTS: usize = 4;
/// Number of weights and biases: `4 H + H + H H + H + H + 1`.
pub const PARAMETERS: usize = INPUTS * HIDDEN + HIDDEN + HIDDEN * HIDDEN + HIDDEN + HIDDEN + 1;

/// The trained network (`config/volume.toml`).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct VolumeFnn {
    /// Mean of each input over the training data (e, e' [1/s], P [Pa abs], P' [Pa/s]).
    pub input_mean: [f32; INPUTS],
    /// 1 / standard deviation of each input over the training data.
    pub input_inv_std: [f32; INPUTS],
    /// First layer: `w1[j][i]` from input `i` to unit `j`.
    pub w1: [[f32; INPUTS]; HIDDEN],
    /// First-layer biases.
    pub b1: [f32; HIDDEN],
    /// Second layer: `w2[j][i]` from first-layer unit `i` to unit `j`.
    pub w2: [[f32; HIDDEN]; HIDDEN],
    /// Second-layer biases.
    pub b2: [f32; HIDDEN],
    /// Output layer.
    pub w3: [f32; HIDDEN],
    /// Output bias.
    pub b3: f32,
    /// `V = volume_offset_m3 + volume_scale_m3 y` [m^3].
    pub volume_offset_m3: f32,
    /// Scale of the output [m^3] (> 0).
    pub volume_scale_m3: f32,
    /// Smallest volume returned [m^3] (> 0).
    pub volume_floor_m3: f32,
}

/// `s(z) = z / (1 + |z|)` and `s'(z) = 1 / (1 + |z|)^2`.
#[inline(always)]
fn softsign(z: f32) -> (f32, f32) {
    let d = 1.0 / (1.0 + libm::fabsf(z));
    (z * d, d * d)
}

impl VolumeFnn {
    /// Every weight finite, the scales > 0, the floor > 0.
    pub fn is_valid(&self) -> bool {
        let fin = |x: &f32| x.is_finite();
        self.input_mean.iter().all(fin)
            && self.input_inv_std.iter().all(|x| x.is_finite() && *x > 0.0)
            && self.w1.iter().flatten().all(fin)
            && self.b1.iter().all(fin)
            && self.w2.iter().flatten().all(fin)
            && self.b2.iter().all(fin)
            && self.w3.iter().all(fin)
            && self.b3.is_finite()
            && self.volume_offset_m3.is_finite()
            && self.volume_scale_m3.is_finite()
            && self.volume_scale_m3 > 0.0
            && self.volume_floor_m3.is_finite()
            && self.volume_floor_m3 > 0.0
    }

    /// Eq. 8 and 9: the volume [m^3] and its rate [m^3/s] at contraction `e`, contraction
    /// rate `e_rate_per_s`, absolute pressure `p_abs_pa` and pressure rate `p_rate_pa_s`.
    /// On the floor the rate is 0. Non-finite inputs give the floor and 0.
    #[inline(never)]
    pub fn volume_and_rate(
        &self,
        e: f32,
        e_rate_per_s: f32,
        p_abs_pa: f32,
        p_rate_pa_s: f32,
    ) -> (f32, f32) {
        let m = &self.input_mean;
        let s = &self.input_inv_std;
        let x = [
            (e - m[0]) * s[0],
            (e_rate_per_s - m[1]) * s[1],
            (p_abs_pa - m[2]) * s[2],
            (p_rate_pa_s - m[3]) * s[3],
        ];
        // The direction of eq. 9 in normalised inputs: e and P move, e' and P' do not.
        let de = e_rate_per_s * s[0];
        let dp = p_rate_pa_s * s[2];
        let mut a1 = [0.0f32; HIDDEN];
        let mut t1 = [0.0f32; HIDDEN];
        for j in 0..HIDDEN {
            let w = &self.w1[j];
            let z = self.b1[j] + w[0] * x[0] + w[1] * x[1] + w[2] * x[2] + w[3] * x[3];
            let (a, da) = softsign(z);
            a1[j] = a;
            t1[j] = da * (w[0] * de + w[2] * dp);
        }
        let mut y = self.b3;
        let mut ty = 0.0f32;
        for j in 0..HIDDEN {
            let w = &self.w2[j];
            let mut z = self.b2[j];
            let mut tz = 0.0f32;
            for i in 0..HIDDEN {
                z += w[i] * a1[i];
                tz += w[i] * t1[i];
            }
            let (a, da) = softsign(z);
            y += self.w3[j] * a;
            ty += self.w3[j] * da * tz;
        }
        let v = self.volume_offset_m3 + self.volume_scale_m3 * y;
        let v_rate = self.volume_scale_m3 * ty;
        // NaN fails both comparisons: the floor and no rate.
        if v > self.volume_floor_m3 && v_rate.is_finite() {
            (v, v_rate)
        } else {
            (self.volume_floor_m3, 0.0)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A network whose volume is exactly linear in e and P: one active unit per layer in its
    /// linear range is not exact, so test the tangent against a central difference instead.
    fn net() -> VolumeFnn {
        let mut n = crate::constants::VOLUME_FNN;
        // Deterministic, non-trivial weights independent of the trained file.
        for j in 0..HIDDEN {
            for i in 0..INPUTS {
                n.w1[j][i] = libm::sinf((j * INPUTS + i) as f32 * 0.7 + 0.3) * 0.8;
            }
            n.b1[j] = libm::cosf(j as f32 * 1.3) * 0.2;
            for i in 0..HIDDEN {
                n.w2[j][i] = libm::sinf((j * HIDDEN + i) as f32 * 0.37 + 1.1) * 0.6;
            }
            n.b2[j] = libm::sinf(j as f32 * 2.1) * 0.1;
            n.w3[j] = libm::cosf(j as f32 * 0.9) * 0.5;
        }
        n.b3 = 0.05;
        n.input_mean = [0.14, 0.0, 4.0e5, 0.0];
        n.input_inv_std = [1.0 / 0.05, 1.0 / 0.5, 1.0 / 1.5e5, 1.0 / 1.0e6];
        n.volume_offset_m3 = 1.0e-4;
        n.volume_scale_m3 = 2.0e-5;
        n.volume_floor_m3 = 1.0e-6;
        n
    }

    #[test]
    fn the_rate_is_the_directional_derivative_of_eq_9() {
        let n = net();
        for &(e, er, p, pr) in &[
            (0.12f32, 0.4f32, 3.0e5f32, 2.0e5f32),
            (0.18, -0.7, 5.0e5, -6.0e5),
            (0.10, 0.0, 2.0e5, 1.0e6),
        ] {
            let (_, rate) = n.volume_and_rate(e, er, p, pr);
            // Central difference along (e', P') over +-h seconds (e' and P' held; f32
            // rounding of V limits it to ~0.5 %).
            let h = 1e-3f32;
            let (vp, _) = n.volume_and_rate(e + er * h, er, p + pr * h, pr);
            let (vm, _) = n.volume_and_rate(e - er * h, er, p - pr * h, pr);
            let fd = (vp - vm) / (2.0 * h);
            assert!(
                (rate - fd).abs() <= 1e-2 * fd.abs().max(1e-9),
                "{e} {er} {p} {pr}: {rate} vs {fd}"
            );
        }
    }

    #[test]
    fn never_nan_and_floored() {
        let n = net();
        for a in crate::HOSTILE_F32 {
            for b in crate::HOSTILE_F32 {
                let (v, r) = n.volume_and_rate(a, b, 3e5, b);
                assert!(
                    v.is_finite() && v >= n.volume_floor_m3 && r.is_finite(),
                    "{a} {b}"
                );
            }
        }
        let mut low = n;
        low.volume_offset_m3 = -1.0;
        assert_eq!(
            low.volume_and_rate(0.1, 1.0, 3e5, 1e5),
            (n.volume_floor_m3, 0.0)
        );
    }

    #[test]
    fn generated_weights_are_valid() {
        assert!(crate::constants::VOLUME_FNN.is_valid());
        let mut bad = crate::constants::VOLUME_FNN;
        bad.w2[3][5] = f32::NAN;
        assert!(!bad.is_valid());
        let mut bad = crate::constants::VOLUME_FNN;
        bad.volume_floor_m3 = 0.0;
        assert!(!bad.is_valid());
    }
}
