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

use crate::fit::fit_percent_of_err2;
use crate::io::recording::{Channel, Recording};
use crate::plant::{Measurement, ValveInputs};

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

/// Streams the nominal simulation's channels of every sample of a run to `f(k, channels)`,
/// in order from 0; `false` if the simulation fails (a replay, or a held series).
pub type NominalStream<'a> = &'a dyn Fn(&mut dyn FnMut(usize, &Measurement)) -> bool;

/// The nominal simulation of TRAIN as the fallback reads it: the channels of its first
/// samples (at least those it is fitted on), their sums over the whole run (the basis's
/// means) and a stream of every sample (the scales and the scores), so a long run is never
/// held.
pub struct NominalRun<'a> {
    pub head: &'a [Measurement],
    /// Sum of every channel over the run, in sample order.
    pub channel_sum: [f64; 5],
    pub stream: NominalStream<'a>,
}

/// The regressor matrix of a run: nominal channels and valve inputs, raw and low-passed,
/// scaled to unit spread (the scales come from TRAIN so every run uses the same ones).
struct Basis {
    /// (channel or input index, signal scale).
    signals: Vec<(usize, f64)>,
    dt_s: f64,
}

/// Valve input `which - 5` of a sample.
fn input_of(u: &ValveInputs, which: usize) -> f64 {
    match which - 5 {
        0 => u.u_in1,
        1 => u.u_ex1,
        2 => u.u_in2,
        _ => u.u_ex2,
    }
}

impl Basis {
    /// Signal `which` of samples `0..end`.
    fn signal(rec: &Recording, nominal: &[Measurement], which: usize, end: usize) -> Vec<f64> {
        if which < 5 {
            nominal[..end].iter().map(|m| m.to_array()[which]).collect()
        } else {
            rec.inputs[..end]
                .iter()
                .map(|u| input_of(u, which))
                .collect()
        }
    }

    /// The scales of every signal, the valve inputs' and the nominal channels', over all of
    /// TRAIN (`None`: constant or not finite): the mean from the run's sums, the spread
    /// from a second pass over the stream (the sums of a held series, in order).
    fn scales(rec: &Recording, nominal: &NominalRun) -> Option<[Option<f64>; 9]> {
        let n = rec.len().max(1) as f64;
        let mut mean = [0.0; 9];
        for (which, m) in mean.iter_mut().enumerate() {
            *m = if which < 5 {
                nominal.channel_sum[which] / n
            } else {
                rec.inputs.iter().map(|u| input_of(u, which)).sum::<f64>() / n
            };
        }
        let mut sq = [0.0f64; 9];
        for (which, s) in sq.iter_mut().enumerate().skip(5) {
            *s = rec
                .inputs
                .iter()
                .map(|u| (input_of(u, which) - mean[which]).powi(2))
                .sum::<f64>();
        }
        let ok = (nominal.stream)(&mut |_, m| {
            let a = m.to_array();
            for which in 0..5 {
                sq[which] += (a[which] - mean[which]).powi(2);
            }
        });
        ok.then(|| {
            std::array::from_fn(|which| {
                let sd = (sq[which] / n).sqrt();
                (sd > 0.0 && sd.is_finite()).then_some(sd)
            })
        })
    }

    /// The valve inputs, and with `channels` also the nominal simulation's channels.
    fn new(rec: &Recording, scales: &[Option<f64>; 9], channels: bool) -> Self {
        let mut signals = Vec::new();
        for (which, sd) in scales.iter().enumerate() {
            if which < 5 && (!channels || rec.channel(Channel::ALL[which]).is_none()) {
                continue;
            }
            if let Some(sd) = sd {
                signals.push((which, *sd));
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

    /// Rows `range` of the regressor matrix (the filters run from the start of the run;
    /// `nominal` holds at least `range.end` samples).
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
            let s = Self::signal(rec, nominal, which, range.end);
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

/// The regressor rows of a run one sample at a time (the rows of [`Basis::matrix`] to the
/// bit, without the matrix).
struct Rows<'b> {
    basis: &'b Basis,
    /// Per signal: the low-pass states (`None` before the first sample).
    state: Vec<Option<[f64; TIME_CONSTANTS_S.len()]>>,
    coef: [f64; TIME_CONSTANTS_S.len()],
    row: Vec<f64>,
}

impl<'b> Rows<'b> {
    fn new(basis: &'b Basis) -> Self {
        Self {
            basis,
            state: vec![None; basis.signals.len()],
            coef: TIME_CONSTANTS_S.map(|tau| (-basis.dt_s / tau).exp()),
            row: vec![0.0; basis.width()],
        }
    }

    /// Makes `row` the row of the next sample (`u` its valve inputs, `m` its nominal
    /// channels).
    fn next(&mut self, u: &ValveInputs, m: &Measurement) {
        let per = 1 + TIME_CONSTANTS_S.len();
        let a = m.to_array();
        for (j, &(which, sd)) in self.basis.signals.iter().enumerate() {
            let v = if which < 5 {
                a[which]
            } else {
                input_of(u, which)
            };
            let ys = self.state[j].get_or_insert([v; TIME_CONSTANTS_S.len()]);
            self.row[j * per] = v / sd;
            for (t, y) in ys.iter_mut().enumerate() {
                let c = self.coef[t];
                *y = c * *y + (1.0 - c) * v;
                self.row[j * per + 1 + t] = *y / sd;
            }
        }
        let w = self.row.len();
        self.row[w - 1] = 1.0;
    }
}

/// `x . beta` summed in column order (the value of nalgebra's matrix-vector product to the
/// bit).
fn dot(x: &[f64], beta: &DVector<f64>) -> f64 {
    let mut acc = x[0] * beta[0];
    for (xj, bj) in x.iter().zip(beta.iter()).skip(1) {
        acc += xj * bj;
    }
    acc
}

/// Fits the fallback on `train[fit]`, scores it on `train[held]` and on `check`, from held
/// nominal series (every sample of each run).
/// `None` when there is nothing to fit (no channel, too few samples).
pub fn fit(
    train: &Recording,
    train_nominal: &[Measurement],
    fit: Range<usize>,
    held: Range<usize>,
    check: Option<(&Recording, &[Measurement])>,
) -> Option<BlackBox> {
    fn stream_of(s: &[Measurement], f: &mut dyn FnMut(usize, &Measurement)) -> bool {
        s.iter().enumerate().for_each(|(k, m)| f(k, m));
        true
    }
    let mut channel_sum = [0.0; 5];
    for m in train_nominal {
        let a = m.to_array();
        (0..5).for_each(|i| channel_sum[i] += a[i]);
    }
    let train_stream = |f: &mut dyn FnMut(usize, &Measurement)| stream_of(train_nominal, f);
    let check_nominal = check.map(|c| c.1).unwrap_or_default();
    let check_stream = |f: &mut dyn FnMut(usize, &Measurement)| stream_of(check_nominal, f);
    fit_streamed(
        train,
        &NominalRun {
            head: train_nominal,
            channel_sum,
            stream: &train_stream,
        },
        fit,
        held,
        check.map(|(r, _)| (r, &check_stream as NominalStream)),
    )
}

/// [`fit`] from nominal runs that are streamed (TRAIN's head is held for the fit): the
/// regressor matrices of the fit range only, the held-out tail and CHECK (its nominal
/// stream) scored row by row. `None` also when a stream's simulation fails. Steps: the
/// bases with their ridge factors, every channel's candidate coefficients, their held-out
/// scores, the choice per channel, CHECK scored.
pub fn fit_streamed(
    train: &Recording,
    train_nominal: &NominalRun,
    fit: Range<usize>,
    held: Range<usize>,
    check: Option<(&Recording, NominalStream)>,
) -> Option<BlackBox> {
    if held.is_empty() || train_nominal.head.len() < fit.end {
        return None;
    }
    let scales = Basis::scales(train, train_nominal)?;
    let variants = fit_variants(train, train_nominal, &scales, &fit);
    if variants.is_empty() {
        return None;
    }
    let trials = candidate_coefficients(train, train_nominal, &fit, &variants);
    // The fit matrices are no longer needed.
    let bases: Vec<Basis> = variants.into_iter().map(|v| v.basis).collect();
    // The held-out scores of every trial, summed row by row over the tail of TRAIN:
    // `fit_percent` of the nominal and of the corrected channel (their error sums).
    let scored = score(train, train_nominal.stream, held.clone(), &bases, &trials)?;
    let mut b = BlackBox {
        heldout: BTreeMap::new(),
        check: None,
        corrected: Vec::new(),
        regressors: BTreeMap::new(),
        ridge: BTreeMap::new(),
    };
    let mut chosen: Vec<(Channel, usize, usize)> = Vec::new();
    for c in Channel::ALL {
        let Some(y) = train.channel(c) else {
            continue;
        };
        let ys = &y[held.clone()];
        let fits = |t: usize| {
            let (nom, after) = scored[t];
            (fit_percent_of_err2(ys, nom), fit_percent_of_err2(ys, after))
        };
        // Per basis the trial with the best held-out fit.
        let per_basis: Vec<Option<(usize, (f64, f64))>> = (0..bases.len())
            .map(|vi| {
                let mut own: Option<(usize, (f64, f64))> = None;
                for (t, _) in trials
                    .iter()
                    .enumerate()
                    .filter(|(_, tr)| tr.0 == c && tr.1 == vi)
                {
                    let h = fits(t);
                    if own.as_ref().is_none_or(|b| h.1 > b.1 .1) {
                        own = Some((t, h));
                    }
                }
                own
            })
            .collect();
        let Some((t, h)) = pick_basis(&per_basis) else {
            continue;
        };
        let (_, vi, rel, _) = &trials[t];
        b.regressors.insert(c.name(), bases[*vi].width());
        b.heldout.insert(c.name(), h);
        b.ridge.insert(c.name(), *rel);
        chosen.push((c, *vi, t));
        if h.1 > h.0 {
            b.corrected.push(c.name());
        }
    }
    b.check = match check {
        Some((rec, stream)) => Some(check_fits(rec, stream, &bases, &trials, &chosen)?),
        None => None,
    };
    Some(b)
}

/// One basis with its fit matrix and the Cholesky factors of its ridge-regularised normal
/// matrices (one per [`RIDGE_REL`] that factors).
struct Variant {
    basis: Basis,
    x_fit: DMatrix<f64>,
    chols: Vec<(f64, nalgebra::Cholesky<f64, nalgebra::Dyn>)>,
}

/// Candidate coefficients of one channel: (channel, variant, ridge, beta).
type Trial = (Channel, usize, f64, DVector<f64>);

/// Two bases: the valve inputs alone, and with the nominal channels; each kept when the fit
/// range has at least 4 rows per regressor and a ridge weight factors.
fn fit_variants(
    train: &Recording,
    train_nominal: &NominalRun,
    scales: &[Option<f64>; 9],
    fit: &Range<usize>,
) -> Vec<Variant> {
    let mut variants = Vec::new();
    for channels in [false, true] {
        let basis = Basis::new(train, scales, channels);
        let w = basis.width();
        if fit.len() < 4 * w {
            continue;
        }
        let x_fit = basis.matrix(train, train_nominal.head, fit.clone());
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
                chols,
            });
        }
    }
    variants
}

/// Every recorded channel's candidate coefficients: the ridge solution of its nominal
/// residual over the fit range in each variant at each ridge weight (non-finite ones left
/// out).
fn candidate_coefficients(
    train: &Recording,
    train_nominal: &NominalRun,
    fit: &Range<usize>,
    variants: &[Variant],
) -> Vec<Trial> {
    let mut trials: Vec<Trial> = Vec::new();
    for c in Channel::ALL {
        let Some(y) = train.channel(c) else {
            continue;
        };
        let r: DVector<f64> = DVector::from_iterator(
            fit.len(),
            fit.clone().map(|k| y[k] - c.of(&train_nominal.head[k])),
        );
        for (vi, v) in variants.iter().enumerate() {
            let xtr = v.x_fit.tr_mul(&r);
            for (rel, chol) in &v.chols {
                let beta = chol.solve(&xtr);
                if beta.iter().any(|b| !b.is_finite()) {
                    continue;
                }
                trials.push((c, vi, *rel, beta));
            }
        }
    }
    trials
}

/// The chosen trial of a channel from each basis's best (trial, (nominal, corrected)
/// held-out fit), in basis order: a larger basis only when it gains more than
/// [`LARGER_BASIS_GAIN_PCT`] of held-out fit over the one before.
fn pick_basis(per_basis: &[Option<(usize, (f64, f64))>]) -> Option<(usize, (f64, f64))> {
    let mut best: Option<(usize, (f64, f64))> = None;
    for o in per_basis.iter().flatten() {
        let gain = if best.is_some() {
            LARGER_BASIS_GAIN_PCT
        } else {
            0.0
        };
        if best.as_ref().is_none_or(|b| o.1 .1 > b.1 .1 + gain) {
            best = Some(*o);
        }
    }
    best
}

/// The chosen trial of every channel CHECK records, scored over all of it: (nominal,
/// corrected) fit per channel; `None` when CHECK's nominal stream fails.
fn check_fits(
    rec: &Recording,
    stream: NominalStream,
    bases: &[Basis],
    trials: &[Trial],
    chosen: &[(Channel, usize, usize)],
) -> Option<BTreeMap<&'static str, (f64, f64)>> {
    let picked: Vec<Trial> = chosen
        .iter()
        .filter(|(c, _, _)| rec.channel(*c).is_some())
        .map(|(_, _, t)| trials[*t].clone())
        .collect();
    let sums = score(rec, stream, 0..rec.len(), bases, &picked)?;
    let mut m = BTreeMap::new();
    for ((c, ..), (nom, after)) in picked.iter().zip(sums) {
        let yc = rec.channel(*c).expect("picked: recorded");
        m.insert(
            c.name(),
            (fit_percent_of_err2(yc, nom), fit_percent_of_err2(yc, after)),
        );
    }
    Some(m)
}

/// Per trial (channel, variant, ridge, coefficients): the error sums over `range` of `rec`,
/// in sample order, of the nominal channel and of the nominal channel plus the correction
/// `x . beta` (the sums of `fit_percent` on the held series to the bit). `None` if the
/// nominal stream fails.
fn score(
    rec: &Recording,
    stream: NominalStream,
    range: Range<usize>,
    bases: &[Basis],
    trials: &[(Channel, usize, f64, DVector<f64>)],
) -> Option<Vec<(f64, f64)>> {
    let mut rows: Vec<Rows> = bases.iter().map(Rows::new).collect();
    let mut sums = vec![(0.0f64, 0.0f64); trials.len()];
    let ok = stream(&mut |k, m| {
        if k >= range.end {
            return;
        }
        let u = &rec.inputs[k];
        rows.iter_mut().for_each(|r| r.next(u, m));
        if k < range.start {
            return;
        }
        for ((c, vi, _, beta), s) in trials.iter().zip(sums.iter_mut()) {
            let y = rec.channel(*c).expect("a trial's channel is recorded")[k];
            let nom = c.of(m);
            let after = nom + dot(&rows[*vi].row, beta);
            s.0 += (y - nom) * (y - nom);
            s.1 += (y - after) * (y - after);
        }
    });
    ok.then_some(sums)
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

    /// The rows streamed for the scores are those of the regressor matrix, and the
    /// column-order dot product is nalgebra's matrix-vector product, to the bit.
    #[test]
    fn streamed_rows_and_products_match_the_matrix() {
        let (rec, nominal) = case();
        let mut sum = [0.0; 5];
        nominal
            .iter()
            .for_each(|m| (0..5).for_each(|i| sum[i] += m.to_array()[i]));
        let stream = |f: &mut dyn FnMut(usize, &Measurement)| {
            nominal.iter().enumerate().for_each(|(k, m)| f(k, m));
            true
        };
        let run = NominalRun {
            head: &nominal,
            channel_sum: sum,
            stream: &stream,
        };
        let scales = Basis::scales(&rec, &run).expect("scales");
        let basis = Basis::new(&rec, &scales, true);
        assert!(basis.signals.len() >= 2, "{:?}", basis.signals);
        let x = basis.matrix(&rec, &nominal, 1000..3000);
        let beta = DVector::from_iterator(
            basis.width(),
            (0..basis.width()).map(|j| ((j * 37 % 11) as f64 - 5.0) * 0.173),
        );
        let product = &x * &beta;
        let mut rows = Rows::new(&basis);
        for k in 0..3000 {
            rows.next(&rec.inputs[k], &nominal[k]);
            if k >= 1000 {
                let i = k - 1000;
                for (j, v) in rows.row.iter().enumerate() {
                    assert_eq!(v.to_bits(), x[(i, j)].to_bits(), "row {k} column {j}");
                }
                assert_eq!(dot(&rows.row, &beta).to_bits(), product[i].to_bits());
            }
        }
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

#[cfg(test)]
mod pick_tests {
    use super::*;

    #[test]
    fn the_larger_basis_is_chosen_only_when_it_gains_more_than_its_margin() {
        let inputs = Some((0, (10.0, 60.0)));
        let small_gain = Some((1, (10.0, 60.0 + 0.5 * LARGER_BASIS_GAIN_PCT)));
        let large_gain = Some((1, (10.0, 60.0 + 2.0 * LARGER_BASIS_GAIN_PCT)));
        assert_eq!(pick_basis(&[inputs, small_gain]), inputs);
        assert_eq!(pick_basis(&[inputs, large_gain]), large_gain);
        // Without the inputs' basis the larger one needs no margin.
        assert_eq!(pick_basis(&[None, small_gain]), small_gain);
        assert_eq!(pick_basis(&[None, None]), None);
    }
}
