//! The unnamed fallback: when no catalogue effect and no recalibration explains the residual
//! (verdict `unexplained`), a small black-box model of the residual still gives the user a
//! better simulation, labelled as naming no physics.
//!
//! Model: for each measured channel, the residual `measured - nominal simulation` is a linear
//! function of the four valve inputs (and, only where that gains held-out fit, of the nominal
//! simulation's channels too), each taken as it is and through first-order low-pass filters of [`TIME_CONSTANTS_S`] (a basis of fading
//! memories: a linear finite-memory model, like an orthonormal-basis-function model), plus a
//! constant. It is fitted by ridge-regularised least squares on the head of TRAIN (the part
//! the selection fits on), the ridge weight chosen per channel by the held-out tail of TRAIN,
//! and scored on that tail and on CHECK. It has no
//! feedback of its own output, so the corrected simulation cannot go unstable. A channel whose
//! held-out fit the correction does not improve keeps the nominal simulation.

use std::collections::BTreeMap;
use std::ops::Range;

use nalgebra::{DMatrix, DVector};

use crate::fit::fit_percent;
use crate::io::recording::{Channel, Recording};
use crate::plant::Measurement;

/// Time constants of the low-pass copies of every regressor signal [s].
pub const TIME_CONSTANTS_S: [f64; 4] = [0.01, 0.03, 0.1, 0.3];
/// Ridge weights tried, relative to the mean diagonal of the normal matrix; the one with the
/// best held-out fit (tail of TRAIN) is kept, per channel.
pub const RIDGE_REL: [f64; 4] = [1e-6, 1e-4, 1e-2, 1.0];
/// The basis with the nominal channels is used for a channel only when its held-out fit beats
/// the valve inputs' alone by more than this [percentage points] (the simpler model wins ties).
pub const LARGER_BASIS_GAIN_PCT: f64 = 2.0;

/// The fitted fallback.
#[derive(Debug, Clone)]
pub struct BlackBox {
    /// Per channel: (name, held-out fit before, after) on the tail of TRAIN.
    pub heldout: BTreeMap<&'static str, (f64, f64)>,
    /// Per channel: (name, fit before, after) on CHECK, when one was given.
    pub check: Option<BTreeMap<&'static str, (f64, f64)>>,
    /// Channels whose correction is used (it improved the held-out fit).
    pub corrected: Vec<&'static str>,
    /// Per channel: the number of regressors of the basis chosen.
    pub regressors: BTreeMap<&'static str, usize>,
    /// Per channel: the ridge weight chosen (relative to the mean diagonal).
    pub ridge: BTreeMap<&'static str, f64>,
}

/// The regressor matrix of a run: nominal channels and valve inputs, raw and low-passed,
/// scaled to unit spread (the scales come from TRAIN so every run uses the same ones).
struct Basis {
    /// (channel or input index, signal scale).
    signals: Vec<(usize, f64)>,
    dt_s: f64,
}

impl Basis {
    fn signal(rec: &Recording, nominal: &[Measurement], which: usize) -> Vec<f64> {
        if which < 5 {
            nominal.iter().map(|m| m.to_array()[which]).collect()
        } else {
            rec.inputs
                .iter()
                .map(|u| match which - 5 {
                    0 => u.u_in1,
                    1 => u.u_ex1,
                    2 => u.u_in2,
                    _ => u.u_ex2,
                })
                .collect()
        }
    }

    /// The valve inputs, and with `channels` also the nominal simulation's channels.
    fn new(rec: &Recording, nominal: &[Measurement], channels: bool) -> Self {
        let mut signals = Vec::new();
        for which in 0..9 {
            if which < 5 && (!channels || rec.channel(Channel::ALL[which]).is_none()) {
                continue;
            }
            let s = Self::signal(rec, nominal, which);
            let mean = s.iter().sum::<f64>() / s.len().max(1) as f64;
            let sd =
                (s.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / s.len().max(1) as f64).sqrt();
            if sd > 0.0 && sd.is_finite() {
                signals.push((which, sd));
            }
        }
        Self {
            signals,
            dt_s: rec.sample_period_s(),
        }
    }

    fn width(&self) -> usize {
        self.signals.len() * (1 + TIME_CONSTANTS_S.len()) + 1
    }

    /// Rows `range` of the regressor matrix (the filters run from the start of the run).
    fn matrix(
        &self,
        rec: &Recording,
        nominal: &[Measurement],
        range: Range<usize>,
    ) -> DMatrix<f64> {
        let n = range.len();
        let w = self.width();
        let mut x = DMatrix::<f64>::zeros(n, w);
        let mut col = 0;
        for &(which, sd) in &self.signals {
            let s = Self::signal(rec, nominal, which);
            for (i, k) in range.clone().enumerate() {
                x[(i, col)] = s[k] / sd;
            }
            col += 1;
            for tau in TIME_CONSTANTS_S {
                let a = (-self.dt_s / tau).exp();
                let mut y = s.first().copied().unwrap_or(0.0);
                for (k, v) in s.iter().enumerate().take(range.end) {
                    y = a * y + (1.0 - a) * v;
                    if k >= range.start {
                        x[(k - range.start, col)] = y / sd;
                    }
                }
                col += 1;
            }
        }
        for i in 0..n {
            x[(i, col)] = 1.0;
        }
        x
    }
}

/// Fits the fallback on `train[fit]`, scores it on `train[held]` and on `check`.
/// `None` when there is nothing to fit (no channel, too few samples).
pub fn fit(
    train: &Recording,
    train_nominal: &[Measurement],
    fit: Range<usize>,
    held: Range<usize>,
    check: Option<(&Recording, &[Measurement])>,
) -> Option<BlackBox> {
    // Two bases: the valve inputs alone, and with the nominal channels. Each with its
    // matrices and the Cholesky factors of its ridge-regularised normal matrices.
    struct Variant {
        basis: Basis,
        x_fit: DMatrix<f64>,
        x_held: DMatrix<f64>,
        x_check: Option<DMatrix<f64>>,
        chols: Vec<(f64, nalgebra::Cholesky<f64, nalgebra::Dyn>)>,
    }
    let mut variants = Vec::new();
    for channels in [false, true] {
        let basis = Basis::new(train, train_nominal, channels);
        let w = basis.width();
        if fit.len() < 4 * w || held.is_empty() {
            continue;
        }
        let x_fit = basis.matrix(train, train_nominal, fit.clone());
        let x_held = basis.matrix(train, train_nominal, held.clone());
        let x_check = check.map(|(r, nom)| basis.matrix(r, nom, 0..r.len()));
        let xtx = x_fit.tr_mul(&x_fit);
        let mean_diag = (0..w).map(|i| xtx[(i, i)]).sum::<f64>() / w as f64;
        let chols: Vec<_> = RIDGE_REL
            .iter()
            .filter_map(|&rel| {
                let a = &xtx + DMatrix::<f64>::identity(w, w) * (rel * mean_diag);
                a.cholesky().map(|c| (rel, c))
            })
            .collect();
        if !chols.is_empty() {
            variants.push(Variant {
                basis,
                x_fit,
                x_held,
                x_check,
                chols,
            });
        }
    }
    if variants.is_empty() {
        return None;
    }
    let mut heldout = BTreeMap::new();
    let mut check_fits = check.map(|_| BTreeMap::new());
    let mut corrected = Vec::new();
    let mut ridge = BTreeMap::new();
    let mut regressors = BTreeMap::new();
    for c in Channel::ALL {
        let Some(y) = train.channel(c) else {
            continue;
        };
        let r: DVector<f64> = DVector::from_iterator(
            fit.len(),
            fit.clone().map(|k| y[k] - c.of(&train_nominal[k])),
        );
        let score = |beta: &DVector<f64>,
                     x: &DMatrix<f64>,
                     y: &[f64],
                     nominal: &[Measurement],
                     range: Range<usize>| {
            let nom: Vec<f64> = range.clone().map(|k| c.of(&nominal[k])).collect();
            let corr = x * beta;
            let after: Vec<f64> = nom.iter().zip(corr.iter()).map(|(a, b)| a + b).collect();
            let ys = &y[range];
            (fit_percent(ys, &nom), fit_percent(ys, &after))
        };
        // Per basis the ridge weight with the best held-out fit; the larger basis only when it
        // gains more than `LARGER_BASIS_GAIN_PCT` of held-out fit over the inputs alone.
        let mut best: Option<(usize, f64, DVector<f64>, (f64, f64))> = None;
        for (vi, v) in variants.iter().enumerate() {
            let xtr = v.x_fit.tr_mul(&r);
            let mut own: Option<(usize, f64, DVector<f64>, (f64, f64))> = None;
            for (rel, chol) in &v.chols {
                let beta = chol.solve(&xtr);
                if beta.iter().any(|b| !b.is_finite()) {
                    continue;
                }
                let h = score(&beta, &v.x_held, y, train_nominal, held.clone());
                if own.as_ref().is_none_or(|b| h.1 > b.3 .1) {
                    own = Some((vi, *rel, beta, h));
                }
            }
            if let Some(o) = own {
                let gain = if best.is_some() {
                    LARGER_BASIS_GAIN_PCT
                } else {
                    0.0
                };
                if best.as_ref().is_none_or(|b| o.3 .1 > b.3 .1 + gain) {
                    best = Some(o);
                }
            }
        }
        let Some((vi, rel, beta, h)) = best else {
            continue;
        };
        let v = &variants[vi];
        regressors.insert(c.name(), v.basis.width());
        heldout.insert(c.name(), h);
        ridge.insert(c.name(), rel);
        if let (Some(m), Some((rec, nom)), Some(xc)) = (&mut check_fits, check, &v.x_check) {
            if let Some(yc) = rec.channel(c) {
                m.insert(c.name(), score(&beta, xc, yc, nom, 0..rec.len()));
            }
        }
        if h.1 > h.0 {
            corrected.push(c.name());
        }
    }
    Some(BlackBox {
        heldout,
        check: check_fits,
        corrected,
        regressors,
        ridge,
    })
}

impl BlackBox {
    /// The JSON object (`"black_box"`).
    pub fn to_json(&self) -> serde_json::Value {
        let fits = |m: &BTreeMap<&'static str, (f64, f64)>| -> serde_json::Value {
            serde_json::Value::Object(
                m.iter()
                    .map(|(k, (b, a))| {
                        (
                            k.to_string(),
                            serde_json::json!({"before": round2(*b), "after": round2(*a)}),
                        )
                    })
                    .collect(),
            )
        };
        serde_json::json!({
            "named": false,
            "model": "linear residual model on the valve inputs, and where it gains held-out fit the nominal simulation's channels (raw and low-passed, time constants 10, 30, 100, 300 ms), ridge least squares on the head of TRAIN",
            "regressors": self.regressors,
            "ridge_relative": self.ridge,
            "corrected_channels": self.corrected,
            "heldout_fit": fits(&self.heldout),
            "check_fit": self.check.as_ref().map(fits),
        })
    }

    /// The report lines.
    pub fn describe(&self) -> String {
        let line = |m: &BTreeMap<&'static str, (f64, f64)>| -> String {
            m.iter()
                .map(|(k, (b, a))| format!("{k} {b:.1} % -> {a:.1} %"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let mut s = format!(
            "Unnamed black-box correction (names no physics: a linear model of the residual on the valve inputs, and where it helps the nominal simulation, fitted on the head of TRAIN): held-out fit {}",
            line(&self.heldout)
        );
        if let Some(c) = &self.check {
            s += &format!("; check recording {}", line(c));
        }
        s += ". Use it to simulate this rig, not to explain it.";
        s
    }
}

fn round2(v: f64) -> serde_json::Value {
    if v.is_finite() {
        serde_json::json!((v * 100.0).round() / 100.0)
    } else {
        serde_json::Value::Null
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plant::ValveInputs;

    /// A recording whose angle carries a slow response to the inlet of muscle 1 that the
    /// "nominal" simulation (a copy without it) lacks.
    fn case() -> (Recording, Vec<Measurement>) {
        let n = 6000;
        let dt = 1e-3;
        let mut rec = Recording {
            metadata: Vec::new(),
            t_s: (0..n).map(|k| k as f64 * dt).collect(),
            inputs: vec![ValveInputs::CLOSED; n],
            outputs: Default::default(),
            mass_flow_kg_s: None,
        };
        let mut nominal = Vec::with_capacity(n);
        let mut slow = 0.0;
        let a = (-dt / 0.08f64).exp();
        let mut angle = Vec::with_capacity(n);
        for k in 0..n {
            let on = ((k / 250) % 3 == 0) as u8 as f64;
            rec.inputs[k] = ValveInputs {
                u_in1: on,
                ..ValveInputs::CLOSED
            };
            let base = (k as f64 * dt * 2.0).sin();
            slow = a * slow + (1.0 - a) * on;
            nominal.push(Measurement {
                angle_deg: base,
                ..Default::default()
            });
            angle.push(base + 0.8 * slow);
        }
        rec.set_channel(Channel::AngleDeg, angle);
        (rec, nominal)
    }

    #[test]
    fn the_fallback_recovers_an_input_driven_residual_on_held_out_data() {
        let (rec, nominal) = case();
        let b = fit(&rec, &nominal, 0..4000, 4000..6000, None).expect("fitted");
        let (before, after) = b.heldout["angle_deg"];
        assert!(before < 80.0 && after > 95.0, "{before} -> {after}");
        assert_eq!(b.corrected, vec!["angle_deg"]);
    }

    #[test]
    fn nothing_to_gain_keeps_the_nominal_channel() {
        let (mut rec, nominal) = case();
        // The measured angle is the nominal one plus white noise: nothing to correct.
        let noise: Vec<f64> = (0..rec.len())
            .map(|k| nominal[k].angle_deg + 0.01 * (((k * 7919) % 1000) as f64 / 500.0 - 1.0))
            .collect();
        rec.set_channel(Channel::AngleDeg, noise);
        let b = fit(&rec, &nominal, 0..4000, 4000..6000, None).expect("fitted");
        let (before, after) = b.heldout["angle_deg"];
        assert!((after - before).abs() < 1.0, "{before} -> {after}");
    }
}
