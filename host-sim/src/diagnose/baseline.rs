//! Black-box baseline for the diagnosis: an Elman recurrent network trained on the residual
//! (measured - nominal simulation) of each channel, as Hosovsky et al. 2015 (seed 000) do.
//!
//! One network per measured channel (seed 000: one output neuron), all with the same input
//! vector per sample k: the four valve openings and the five nominal (simulated) channels,
//! standardised with the training data's mean and spread:
//!
//! h(k) = tanh(W_in u(k) + W_ctx h(k-1) + b_h),   r(k) = w_out . h(k) + b_out,
//!
//! r the standardised residual of the channel; the corrected channel is nominal + residual.
//! The network runs free over a whole recording from h = 0 (simulation use, as in the seed:
//! it never sees a measured value at prediction time).
//!
//! Training: truncated back-propagation through time over consecutive chunks of the training
//! part (the hidden state is carried from chunk to chunk, gradients are not), Adam updates per
//! chunk with global gradient-norm clipping; after every pass the network is run free over
//! the whole recording and scored on the held-out tail (the last `holdout_fraction` of the
//! samples, never used for updates); the weights with the lowest held-out error are kept and
//! training stops after `patience` passes without improvement (early stopping).
//!
//! Hand-written rather than a deep-learning crate (burn, candle, tch): the network has a few
//! hundred weights, the whole thing is ~400 lines with a gradient check test, it is exactly
//! deterministic for a seed, and it adds no heavy dependency to the workspace build.

use rand::{Rng, SeedableRng};

use crate::io::recording::Channel;
use crate::plant::{Measurement, ValveInputs};

/// Number of network inputs: 4 valve openings + 5 nominal channels.
const N_IN: usize = 9;

/// Training options.
#[derive(Debug, Clone, PartialEq)]
pub struct ElmanOptions {
    /// Hidden (context) neurons per network (seed 000 used 15).
    pub hidden: usize,
    /// Upper bound on passes over the training part.
    pub max_epochs: usize,
    /// Stop after this many passes without a better held-out error.
    pub patience: usize,
    /// Fraction of the samples at the end of the recording held out for early stopping.
    pub holdout_fraction: f64,
    /// Truncated-BPTT chunk length in samples (one Adam update per chunk).
    pub chunk_len: usize,
    /// Adam step size.
    pub learning_rate: f64,
    /// Global gradient norm is clipped to this.
    pub grad_clip: f64,
    /// Seed of the weight initialisation (channel c uses seed + c).
    pub seed: u64,
    /// Train the channels' networks on up to this many threads.
    pub threads: usize,
}

impl Default for ElmanOptions {
    fn default() -> Self {
        Self {
            hidden: 15,
            max_epochs: 150,
            patience: 15,
            holdout_fraction: 0.2,
            chunk_len: 200,
            learning_rate: 3e-3,
            grad_clip: 1.0,
            seed: 1,
            threads: 2,
        }
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum BaselineError {
    #[error("{what} has {got} samples, the inputs have {expected}")]
    Length {
        what: String,
        got: usize,
        expected: usize,
    },
    #[error("{what}: non-finite value at sample {index}")]
    NonFinite { what: String, index: usize },
    #[error("need at least {min} samples to train (with a held-out part), got {got}")]
    TooShort { min: usize, got: usize },
    #[error("no measured channel to train on")]
    NoChannel,
    #[error("invalid option {name}: {message}")]
    Option { name: &'static str, message: String },
}

/// What training did for one channel.
#[derive(Debug, Clone, PartialEq)]
pub struct TrainReport {
    pub channel: Channel,
    /// Passes run (early stopping may end before `max_epochs`).
    pub epochs: usize,
    /// Pass whose weights were kept (1-based; 0 = the initial weights).
    pub best_epoch: usize,
    /// Mean squared residual error (channel units^2) of the kept network on the training part
    /// and on the held-out part, and the same for "no correction" (the nominal model).
    pub train_mse: f64,
    pub holdout_mse: f64,
    pub train_mse_nominal: f64,
    pub holdout_mse_nominal: f64,
}

/// One trained Elman network (standardised input and output).
#[derive(Debug, Clone, PartialEq)]
pub struct ElmanNet {
    hidden: usize,
    /// Flat parameters, see [`Layout`].
    params: Vec<f64>,
}

/// Index layout of the flat parameter vector.
#[derive(Debug, Clone, Copy)]
struct Layout {
    h: usize,
}

impl Layout {
    fn w_in(&self, j: usize, i: usize) -> usize {
        j * N_IN + i
    }
    fn w_ctx(&self, j: usize, l: usize) -> usize {
        self.h * N_IN + j * self.h + l
    }
    fn b_h(&self, j: usize) -> usize {
        self.h * N_IN + self.h * self.h + j
    }
    fn w_out(&self, j: usize) -> usize {
        self.h * N_IN + self.h * self.h + self.h + j
    }
    fn b_out(&self) -> usize {
        self.h * N_IN + self.h * self.h + 2 * self.h
    }
    fn len(&self) -> usize {
        self.b_out() + 1
    }
}

impl ElmanNet {
    fn new(hidden: usize, seed: u64) -> Self {
        let l = Layout { h: hidden };
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let mut params = vec![0.0; l.len()];
        // Xavier-uniform input and output weights; a small context matrix (spectral radius
        // well below 1: the free-running network starts stable).
        let a_in = (6.0 / (N_IN + hidden) as f64).sqrt();
        let a_ctx = 0.5 / (hidden as f64).sqrt();
        let a_out = (6.0 / (hidden + 1) as f64).sqrt() * 0.1;
        for j in 0..hidden {
            for i in 0..N_IN {
                params[l.w_in(j, i)] = rng.random_range(-a_in..a_in);
            }
            for k in 0..hidden {
                params[l.w_ctx(j, k)] = rng.random_range(-a_ctx..a_ctx);
            }
            params[l.w_out(j)] = rng.random_range(-a_out..a_out);
        }
        Self { hidden, params }
    }

    fn layout(&self) -> Layout {
        Layout { h: self.hidden }
    }

    /// One step: h <- tanh(W_in u + W_ctx h + b), returns the output.
    #[inline]
    fn step(&self, u: &[f64; N_IN], h_prev: &[f64], h: &mut [f64]) -> f64 {
        let l = self.layout();
        let p = &self.params;
        let mut y = p[l.b_out()];
        for j in 0..self.hidden {
            let mut a = p[l.b_h(j)];
            for (i, ui) in u.iter().enumerate() {
                a += p[l.w_in(j, i)] * ui;
            }
            let row = l.w_ctx(j, 0);
            for (k, hk) in h_prev.iter().enumerate() {
                a += p[row + k] * hk;
            }
            h[j] = a.tanh();
            y += p[l.w_out(j)] * h[j];
        }
        y
    }

    /// Free run over a whole sequence from h = 0.
    fn run(&self, u: &[[f64; N_IN]]) -> Vec<f64> {
        let mut h = vec![0.0; self.hidden];
        let mut h_next = vec![0.0; self.hidden];
        u.iter()
            .map(|uk| {
                let y = self.step(uk, &h, &mut h_next);
                std::mem::swap(&mut h, &mut h_next);
                y
            })
            .collect()
    }

    /// Mean squared error over `u[range]` of a chunk started from `h0`, its gradient
    /// (added to `grad`, which is zeroed first) and the hidden state at the chunk's end.
    fn chunk_loss_grad(
        &self,
        u: &[[f64; N_IN]],
        target: &[f64],
        h0: &[f64],
        grad: &mut [f64],
    ) -> (f64, Vec<f64>) {
        let l = self.layout();
        let p = &self.params;
        let n = u.len();
        let hd = self.hidden;
        grad.iter_mut().for_each(|g| *g = 0.0);
        // Forward, keeping every hidden state (hs[0] = h0).
        let mut hs = vec![0.0; (n + 1) * hd];
        hs[..hd].copy_from_slice(h0);
        let mut dy = vec![0.0; n];
        let mut loss = 0.0;
        for k in 0..n {
            let (prev, next) = hs.split_at_mut((k + 1) * hd);
            let y = self.step(&u[k], &prev[k * hd..], &mut next[..hd]);
            let e = y - target[k];
            loss += e * e;
            dy[k] = 2.0 * e / n as f64;
        }
        loss /= n as f64;
        // Backward through time.
        let mut dh_next = vec![0.0; hd];
        let mut da = vec![0.0; hd];
        for k in (0..n).rev() {
            let h = &hs[(k + 1) * hd..(k + 2) * hd];
            let h_prev = &hs[k * hd..(k + 1) * hd];
            grad[l.b_out()] += dy[k];
            for j in 0..hd {
                grad[l.w_out(j)] += dy[k] * h[j];
                let dh = p[l.w_out(j)] * dy[k] + dh_next[j];
                da[j] = dh * (1.0 - h[j] * h[j]);
            }
            dh_next.iter_mut().for_each(|v| *v = 0.0);
            for j in 0..hd {
                let d = da[j];
                if d == 0.0 {
                    continue;
                }
                grad[l.b_h(j)] += d;
                for (i, ui) in u[k].iter().enumerate() {
                    grad[l.w_in(j, i)] += d * ui;
                }
                let row = l.w_ctx(j, 0);
                for m in 0..hd {
                    grad[row + m] += d * h_prev[m];
                    dh_next[m] += p[row + m] * d;
                }
            }
        }
        let h_end = hs[n * hd..].to_vec();
        (loss, h_end)
    }
}

/// Standardisation of the network inputs (per input) and of one channel's residual.
#[derive(Debug, Clone, PartialEq)]
struct Scaling {
    in_mean: [f64; N_IN],
    in_scale: [f64; N_IN],
}

fn mean_std(x: impl Iterator<Item = f64> + Clone) -> (f64, f64) {
    let n = x.clone().count().max(1) as f64;
    let m = x.clone().sum::<f64>() / n;
    let v = x.map(|v| (v - m) * (v - m)).sum::<f64>() / n;
    (m, v.sqrt())
}

fn raw_inputs(inputs: &[ValveInputs], nominal: &[Measurement]) -> Vec<[f64; N_IN]> {
    inputs
        .iter()
        .zip(nominal)
        .map(|(u, m)| {
            let y = m.to_array();
            [
                u.u_in1, u.u_ex1, u.u_in2, u.u_ex2, y[0], y[1], y[2], y[3], y[4],
            ]
        })
        .collect()
}

impl Scaling {
    fn fit(raw: &[[f64; N_IN]]) -> Self {
        let mut s = Self {
            in_mean: [0.0; N_IN],
            in_scale: [1.0; N_IN],
        };
        for i in 0..N_IN {
            let (m, sd) = mean_std(raw.iter().map(|r| r[i]));
            s.in_mean[i] = m;
            // A constant input (e.g. a valve never used) stays 0 after centring.
            s.in_scale[i] = if sd > 1e-12 { 1.0 / sd } else { 0.0 };
        }
        s
    }

    fn apply(&self, raw: &[[f64; N_IN]]) -> Vec<[f64; N_IN]> {
        raw.iter()
            .map(|r| std::array::from_fn(|i| (r[i] - self.in_mean[i]) * self.in_scale[i]))
            .collect()
    }
}

/// One channel's trained network and residual scaling.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelModel {
    pub channel: Channel,
    net: ElmanNet,
    /// Residual = mean + scale * network output.
    res_mean: f64,
    res_scale: f64,
    pub report: TrainReport,
}

/// The trained baseline: one network per channel that was measured in training.
#[derive(Debug, Clone, PartialEq)]
pub struct ElmanBaseline {
    scaling: Scaling,
    pub channels: Vec<ChannelModel>,
}

fn check_len(what: &str, got: usize, expected: usize) -> Result<(), BaselineError> {
    if got != expected {
        return Err(BaselineError::Length {
            what: what.into(),
            got,
            expected,
        });
    }
    Ok(())
}

fn check_finite(what: &str, v: impl Iterator<Item = f64>) -> Result<(), BaselineError> {
    for (index, x) in v.enumerate() {
        if !x.is_finite() {
            return Err(BaselineError::NonFinite {
                what: what.into(),
                index,
            });
        }
    }
    Ok(())
}

fn check_series(inputs: &[ValveInputs], nominal: &[Measurement]) -> Result<(), BaselineError> {
    check_len("nominal", nominal.len(), inputs.len())?;
    check_finite(
        "inputs",
        inputs
            .iter()
            .flat_map(|u| [u.u_in1, u.u_ex1, u.u_in2, u.u_ex2]),
    )?;
    check_finite("nominal", nominal.iter().flat_map(|m| m.to_array()))
}

/// Trains the baseline on one recording: `inputs[k]` the valve openings, `nominal[k]` the
/// nominal model's simulated channels, `measured[c]` the measured channel `Channel::ALL[c]`
/// (`None` when the recording lacks it: that channel gets no network).
pub fn train(
    inputs: &[ValveInputs],
    nominal: &[Measurement],
    measured: &[Option<Vec<f64>>; 5],
    opts: &ElmanOptions,
) -> Result<ElmanBaseline, BaselineError> {
    let n = inputs.len();
    check_series(inputs, nominal)?;
    if opts.hidden == 0 || opts.chunk_len == 0 || opts.max_epochs == 0 || opts.threads == 0 {
        return Err(BaselineError::Option {
            name: "hidden/chunk_len/max_epochs/threads",
            message: "must be > 0".into(),
        });
    }
    if !(opts.holdout_fraction > 0.0 && opts.holdout_fraction < 1.0) {
        return Err(BaselineError::Option {
            name: "holdout_fraction",
            message: format!("must be in (0, 1), got {}", opts.holdout_fraction),
        });
    }
    if !(opts.learning_rate > 0.0 && opts.grad_clip > 0.0) {
        return Err(BaselineError::Option {
            name: "learning_rate/grad_clip",
            message: "must be > 0".into(),
        });
    }
    let n_hold = ((n as f64) * opts.holdout_fraction).round() as usize;
    let n_train = n.saturating_sub(n_hold);
    const MIN: usize = 20;
    if n_train < MIN || n_hold < MIN / 2 {
        return Err(BaselineError::TooShort {
            min: 2 * MIN,
            got: n,
        });
    }
    let mut jobs = Vec::new();
    for c in Channel::ALL {
        if let Some(y) = &measured[c.index()] {
            check_len(c.name(), y.len(), n)?;
            check_finite(c.name(), y.iter().copied())?;
            let res: Vec<f64> = y.iter().zip(nominal).map(|(m, s)| m - c.of(s)).collect();
            jobs.push((c, res));
        }
    }
    if jobs.is_empty() {
        return Err(BaselineError::NoChannel);
    }
    let raw = raw_inputs(inputs, nominal);
    let scaling = Scaling::fit(&raw[..n_train]);
    let u = scaling.apply(&raw);

    // Train the channels' networks on up to `threads` threads (each independent and seeded:
    // the result does not depend on the thread count).
    let mut results: Vec<Option<ChannelModel>> = vec![None; jobs.len()];
    let threads = opts.threads.min(jobs.len());
    std::thread::scope(|s| {
        let chunks: Vec<_> = results.chunks_mut(jobs.len().div_ceil(threads)).collect();
        let mut start = 0;
        for out in chunks {
            let my_jobs = &jobs[start..start + out.len()];
            start += out.len();
            let u = &u;
            s.spawn(move || {
                for ((c, res), slot) in my_jobs.iter().zip(out.iter_mut()) {
                    *slot = Some(train_channel(*c, u, res, n_train, opts));
                }
            });
        }
    });
    Ok(ElmanBaseline {
        scaling,
        channels: results.into_iter().map(|r| r.expect("trained")).collect(),
    })
}

fn mse(a: impl Iterator<Item = f64>) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for v in a {
        s += v * v;
        n += 1;
    }
    s / n.max(1) as f64
}

fn train_channel(
    channel: Channel,
    u: &[[f64; N_IN]],
    residual: &[f64],
    n_train: usize,
    opts: &ElmanOptions,
) -> ChannelModel {
    let (res_mean, sd) = mean_std(residual[..n_train].iter().copied());
    let res_scale = if sd > 1e-12 { sd } else { 1.0 };
    let target: Vec<f64> = residual
        .iter()
        .map(|r| (r - res_mean) / res_scale)
        .collect();
    let mut net = ElmanNet::new(opts.hidden, opts.seed.wrapping_add(channel.index() as u64));
    let np = net.params.len();
    let holdout_mse = |net: &ElmanNet| {
        let y = net.run(u);
        mse((n_train..u.len()).map(|k| (y[k] - target[k]) * res_scale))
    };
    let mut best = (holdout_mse(&net), net.params.clone(), 0usize);
    let (mut m1, mut m2) = (vec![0.0; np], vec![0.0; np]);
    let mut grad = vec![0.0; np];
    let (b1, b2, eps) = (0.9f64, 0.999f64, 1e-8);
    let mut t = 0i32;
    let mut epochs = 0;
    for epoch in 1..=opts.max_epochs {
        epochs = epoch;
        let mut h = vec![0.0; opts.hidden];
        let mut start = 0;
        while start < n_train {
            let end = (start + opts.chunk_len).min(n_train);
            let (_, h_end) =
                net.chunk_loss_grad(&u[start..end], &target[start..end], &h, &mut grad);
            h = h_end;
            let norm = grad.iter().map(|g| g * g).sum::<f64>().sqrt();
            let clip = if norm > opts.grad_clip {
                opts.grad_clip / norm
            } else {
                1.0
            };
            t += 1;
            let (c1, c2) = (1.0 - b1.powi(t), 1.0 - b2.powi(t));
            for i in 0..np {
                let g = grad[i] * clip;
                m1[i] = b1 * m1[i] + (1.0 - b1) * g;
                m2[i] = b2 * m2[i] + (1.0 - b2) * g * g;
                net.params[i] -= opts.learning_rate * (m1[i] / c1) / ((m2[i] / c2).sqrt() + eps);
            }
            start = end;
        }
        let e = holdout_mse(&net);
        if e < best.0 {
            best = (e, net.params.clone(), epoch);
        } else if epoch - best.2 >= opts.patience {
            break;
        }
    }
    net.params = best.1;
    let y = net.run(u);
    let err = |k: usize| (y[k] - target[k]) * res_scale;
    let report = TrainReport {
        channel,
        epochs,
        best_epoch: best.2,
        train_mse: mse((0..n_train).map(err)),
        holdout_mse: mse((n_train..u.len()).map(err)),
        train_mse_nominal: mse(residual[..n_train].iter().copied()),
        holdout_mse_nominal: mse(residual[n_train..].iter().copied()),
    };
    ChannelModel {
        channel,
        net,
        res_mean,
        res_scale,
        report,
    }
}

impl ElmanBaseline {
    /// The corrected channels (nominal + predicted residual) for another run of the same rig:
    /// `corrected[c]` for every channel trained, `None` for the others.
    pub fn predict(
        &self,
        inputs: &[ValveInputs],
        nominal: &[Measurement],
    ) -> Result<[Option<Vec<f64>>; 5], BaselineError> {
        check_series(inputs, nominal)?;
        let u = self.scaling.apply(&raw_inputs(inputs, nominal));
        let mut out: [Option<Vec<f64>>; 5] = Default::default();
        for cm in &self.channels {
            let y = cm.net.run(&u);
            out[cm.channel.index()] = Some(
                y.iter()
                    .zip(nominal)
                    .map(|(r, m)| cm.channel.of(m) + cm.res_mean + cm.res_scale * r)
                    .collect(),
            );
        }
        Ok(out)
    }

    /// The training reports, one per trained channel.
    pub fn reports(&self) -> Vec<&TrainReport> {
        self.channels.iter().map(|c| &c.report).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bptt_gradient_matches_finite_differences() {
        let net = ElmanNet::new(4, 7);
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let u: Vec<[f64; N_IN]> = (0..30)
            .map(|_| std::array::from_fn(|_| rng.random_range(-1.0..1.0)))
            .collect();
        let target: Vec<f64> = (0..30).map(|k| (k as f64 * 0.3).sin()).collect();
        let h0: Vec<f64> = (0..4).map(|j| 0.1 * j as f64 - 0.15).collect();
        let mut grad = vec![0.0; net.params.len()];
        let (loss, _) = net.chunk_loss_grad(&u, &target, &h0, &mut grad);
        assert!(loss > 0.0);
        let mut scratch = vec![0.0; net.params.len()];
        for (i, g) in grad.iter().enumerate() {
            let e = 1e-6;
            let mut a = net.clone();
            a.params[i] += e;
            let mut b = net.clone();
            b.params[i] -= e;
            let (la, _) = a.chunk_loss_grad(&u, &target, &h0, &mut scratch);
            let (lb, _) = b.chunk_loss_grad(&u, &target, &h0, &mut scratch);
            let fd = (la - lb) / (2.0 * e);
            assert!(
                (fd - g).abs() <= 1e-6 * (1.0 + fd.abs()),
                "param {i}: analytic {g} vs numeric {fd}"
            );
        }
    }

    /// A residual that an Elman network of the same size can represent exactly (made by a
    /// random "teacher" network from the same inputs) is learnt on the training part and
    /// predicted on the held-out part.
    #[test]
    fn learns_a_residual_it_can_represent() {
        let n = 3000;
        let mut rng = rand::rngs::StdRng::seed_from_u64(5);
        let mut inputs = Vec::with_capacity(n);
        let mut cur = ValveInputs::CLOSED;
        for _ in 0..n {
            if rng.random_bool(0.02) {
                let b = |r: &mut rand::rngs::StdRng| if r.random_bool(0.5) { 1.0 } else { 0.0 };
                cur = ValveInputs {
                    u_in1: b(&mut rng),
                    u_ex1: b(&mut rng),
                    u_in2: b(&mut rng),
                    u_ex2: b(&mut rng),
                };
            }
            inputs.push(cur);
        }
        let nominal: Vec<Measurement> = (0..n)
            .map(|k| {
                let t = k as f64 * 1e-3;
                Measurement {
                    angle_deg: 10.0 * (1.3 * t).sin(),
                    p1_kpa: 300.0 + 100.0 * (0.7 * t).cos(),
                    p2_kpa: 300.0 - 100.0 * (0.7 * t).cos(),
                    f1_n: 400.0 + 50.0 * (2.1 * t).sin(),
                    f2_n: 400.0 - 50.0 * (1.9 * t).sin(),
                }
            })
            .collect();
        let raw = raw_inputs(&inputs, &nominal);
        let u = Scaling::fit(&raw).apply(&raw);
        let mut teacher = ElmanNet::new(6, 99);
        // A teacher with a slow, clearly recurrent response.
        let l = teacher.layout();
        for j in 0..6 {
            teacher.params[l.w_ctx(j, j)] += 0.8;
        }
        let r = teacher.run(&u);
        let measured_p1: Vec<f64> = nominal
            .iter()
            .zip(&r)
            .map(|(m, r)| m.p1_kpa + 20.0 * r)
            .collect();
        let mut measured: [Option<Vec<f64>>; 5] = Default::default();
        measured[1] = Some(measured_p1.clone());
        let opts = ElmanOptions {
            hidden: 8,
            max_epochs: 300,
            patience: 30,
            ..Default::default()
        };
        let model = train(&inputs, &nominal, &measured, &opts).unwrap();
        let rep = &model.channels[0].report;
        assert_eq!(rep.channel, Channel::P1Kpa);
        assert!(
            rep.train_mse < 0.05 * rep.train_mse_nominal,
            "train {} vs nominal {}",
            rep.train_mse,
            rep.train_mse_nominal
        );
        assert!(
            rep.holdout_mse < 0.1 * rep.holdout_mse_nominal,
            "holdout {} vs nominal {}",
            rep.holdout_mse,
            rep.holdout_mse_nominal
        );
        let corrected = model.predict(&inputs, &nominal).unwrap();
        assert!(corrected[0].is_none() && corrected[2].is_none());
        let c = corrected[1].as_ref().unwrap();
        let fit_before = crate::fit::fit_percent(
            &measured_p1,
            &nominal.iter().map(|m| m.p1_kpa).collect::<Vec<_>>(),
        );
        let fit_after = crate::fit::fit_percent(&measured_p1, c);
        assert!(fit_after > fit_before + 5.0, "{fit_before} -> {fit_after}");
    }

    #[test]
    fn free_run_matches_chunked_forward() {
        let net = ElmanNet::new(5, 11);
        let u: Vec<[f64; N_IN]> = (0..50)
            .map(|k| std::array::from_fn(|i| ((k * (i + 1)) as f64 * 0.1).sin()))
            .collect();
        let y = net.run(&u);
        let mut grad = vec![0.0; net.params.len()];
        let target = y.clone();
        let (loss, _) = net.chunk_loss_grad(&u, &target, &[0.0; 5], &mut grad);
        assert!(loss < 1e-24, "{loss}");
        assert!(grad.iter().all(|g| g.abs() < 1e-12));
    }
}
