//! Output-error fitting: the plant with a set of candidate effects switched on is simulated
//! with the recording's valve inputs, and the effects' parameters are fitted by
//! Levenberg-Marquardt on the simulated-minus-measured channels (each channel divided by its
//! spread, so the cost is the sum over channels of (1 - fit/100)^2).
//!
//! The small Levenberg-Marquardt loop is written out here rather than driven through the
//! `levenberg-marquardt` crate: every residual evaluation is a whole simulation, and the loop
//! needs to count, bound and share them (forward-difference Jacobian, at most a few
//! iterations, failed simulations as rejected steps), which the crate's trait interface
//! would hide behind separate `residuals`/`jacobian` calls.

use crate::plant::config::PlantConfig;
use crate::plant::{Measurement, Plant, PlantState, ValveInputs};
use crate::io::recording::{Channel, Recording};
use crate::sim::{simulate, SolverOptions};

use super::candidates::{Candidate, Setup};

/// One effect of a model with its parameter values.
#[derive(Clone)]
pub struct Part<'c> {
    pub candidate: &'c dyn Candidate,
    pub params: Vec<f64>,
}

/// The output-error problem on one recording.
pub struct Problem<'a> {
    pub nominal: &'a PlantConfig,
    pub setup: Setup,
    pub inputs: &'a [ValveInputs],
    pub measured: [Option<Vec<f64>>; 5],
    /// Per-channel normalisation (the measured channel's standard deviation).
    pub scale: [f64; 5],
    /// States of the nominal simulation (reused when only sensor effects change).
    pub base_states: Vec<PlantState>,
    pub opts: SolverOptions,
}

impl<'a> Problem<'a> {
    pub fn new(
        nominal: &'a PlantConfig,
        rec: &'a Recording,
        present: [bool; 5],
        scale: [f64; 5],
        opts: SolverOptions,
    ) -> Result<Self, crate::sim::SimError> {
        let dt = rec.sample_period_s();
        let plant = Plant::from_config(nominal);
        let base = simulate(&plant, &rec.inputs, dt, &opts)?;
        Ok(Self {
            nominal,
            setup: Setup { dt_s: dt, present },
            inputs: &rec.inputs,
            measured: rec.outputs.clone(),
            scale,
            base_states: base.states,
            opts,
        })
    }

    /// The plant configuration with `parts` switched on.
    pub fn config(&self, parts: &[Part]) -> PlantConfig {
        let mut cfg = self.nominal.clone();
        for p in parts {
            p.candidate.apply(&mut cfg, &p.params, &self.setup);
        }
        cfg
    }

    /// The simulated channels of the model `parts`; `None` if the simulation fails.
    pub fn predict(&self, parts: &[Part]) -> Option<Vec<Measurement>> {
        let cfg = self.config(parts);
        let plant = Plant::from_config(&cfg);
        let dt = self.setup.dt_s;
        if parts.iter().all(|p| !p.candidate.changes_dynamics()) {
            return Some(plant.measure_series(&self.base_states, dt));
        }
        let sim = simulate(&plant, self.inputs, dt, &self.opts).ok()?;
        Some(plant.measure_series(&sim.states, dt))
    }

    /// Per-channel mean squared normalised error over `range` (0 for absent channels).
    pub fn channel_costs(&self, pred: &[Measurement], range: std::ops::Range<usize>) -> [f64; 5] {
        let mut out = [0.0; 5];
        let n = range.len().max(1) as f64;
        for c in Channel::ALL {
            if let Some(y) = &self.measured[c.index()] {
                let s = self.scale[c.index()];
                out[c.index()] = range
                    .clone()
                    .map(|k| ((c.of(&pred[k]) - y[k]) / s).powi(2))
                    .sum::<f64>()
                    / n;
            }
        }
        out
    }

    /// Total cost over `range` (sum of [`Self::channel_costs`]); infinite if the simulation fails.
    pub fn cost(&self, parts: &[Part], range: std::ops::Range<usize>) -> f64 {
        match self.predict(parts) {
            Some(p) => self.channel_costs(&p, range).iter().sum(),
            None => f64::INFINITY,
        }
    }

    /// Residual vector for LM: normalised errors of every channel on every `stride`-th
    /// sample of `range`, scaled so that its squared norm is the cost.
    fn residuals(
        &self,
        parts: &[Part],
        range: &std::ops::Range<usize>,
        stride: usize,
    ) -> Option<Vec<f64>> {
        let pred = self.predict(parts)?;
        let idx: Vec<usize> = range.clone().step_by(stride).collect();
        let w = 1.0 / (idx.len() as f64).sqrt();
        let mut r = Vec::with_capacity(idx.len() * 5);
        for c in Channel::ALL {
            if let Some(y) = &self.measured[c.index()] {
                let s = self.scale[c.index()];
                for &k in &idx {
                    let e = w * (c.of(&pred[k]) - y[k]) / s;
                    if !e.is_finite() {
                        return None;
                    }
                    r.push(e);
                }
            }
        }
        Some(r)
    }

    /// Fits the parameters of `parts` on `range` starting from their current values: first
    /// every discrete parameter over its grid (the others held), then Levenberg-Marquardt on
    /// the continuous ones. Returns the fitted parts and the cost on `range`.
    pub fn fit<'c>(
        &self,
        parts: &[Part<'c>],
        range: std::ops::Range<usize>,
        max_iter: usize,
    ) -> (Vec<Part<'c>>, f64) {
        let mut parts: Vec<Part<'c>> = parts.to_vec();
        for i in 0..parts.len() {
            if let Some(grid) = parts[i].candidate.grid(&parts[i].params, &self.setup) {
                let mut best = (f64::INFINITY, parts[i].params.clone());
                for g in grid {
                    let mut trial = parts.clone();
                    trial[i].params = g.clone();
                    let c = self.cost(&trial, range.clone());
                    if c < best.0 {
                        best = (c, g);
                    }
                }
                parts[i].params = best.1;
            }
        }
        // Continuous parameters, in units of their typical size.
        let mut slots: Vec<(usize, usize, f64, f64, f64)> = Vec::new(); // part, index, scale, lo, hi
        for (i, p) in parts.iter().enumerate() {
            if p.candidate.grid(&p.params, &self.setup).is_some() {
                continue;
            }
            for (j, spec) in p.candidate.params(&self.setup).iter().enumerate() {
                slots.push((i, j, spec.scale, spec.lo, spec.hi));
            }
        }
        let stride = (range.len() / 3000).max(1);
        let set = |parts: &mut Vec<Part<'c>>, theta: &[f64]| {
            for (s, t) in slots.iter().zip(theta) {
                parts[s.0].params[s.1] = (t * s.2).clamp(s.3, s.4);
            }
        };
        let mut theta: Vec<f64> = slots.iter().map(|s| parts[s.0].params[s.1] / s.2).collect();
        let m = theta.len();
        let eval = |theta: &[f64]| -> Option<Vec<f64>> {
            let mut trial = parts.clone();
            set(&mut trial, theta);
            self.residuals(&trial, &range, stride)
        };
        if m > 0 {
            if let Some(mut r) = eval(&theta) {
                let mut cost: f64 = r.iter().map(|v| v * v).sum();
                let mut lambda = 1e-3;
                for _ in 0..max_iter {
                    // Forward-difference Jacobian.
                    let mut jac = nalgebra::DMatrix::<f64>::zeros(r.len(), m);
                    let mut ok = true;
                    for j in 0..m {
                        let h = 1e-3 * theta[j].abs().max(0.05);
                        let mut t2 = theta.clone();
                        t2[j] += h;
                        match eval(&t2) {
                            Some(r2) => {
                                for k in 0..r.len() {
                                    jac[(k, j)] = (r2[k] - r[k]) / h;
                                }
                            }
                            None => ok = false,
                        }
                    }
                    if !ok {
                        break;
                    }
                    let rv = nalgebra::DVector::from_column_slice(&r);
                    let a = jac.transpose() * &jac;
                    let g = jac.transpose() * rv;
                    let mut improved = false;
                    for _ in 0..6 {
                        let mut al = a.clone();
                        for d in 0..m {
                            al[(d, d)] += lambda * (a[(d, d)] + 1e-12);
                        }
                        let Some(step) = al.lu().solve(&(-&g)) else {
                            lambda *= 10.0;
                            continue;
                        };
                        let t_new: Vec<f64> = theta
                            .iter()
                            .zip(step.iter())
                            .zip(&slots)
                            .map(|((t, s), sl)| (t + s).clamp(sl.3 / sl.2, sl.4 / sl.2))
                            .collect();
                        if let Some(r_new) = eval(&t_new) {
                            let c_new: f64 = r_new.iter().map(|v| v * v).sum();
                            if c_new < cost {
                                let rel = (cost - c_new) / cost.max(1e-300);
                                theta = t_new;
                                r = r_new;
                                cost = c_new;
                                lambda = (lambda / 5.0).max(1e-7);
                                improved = rel > 1e-4;
                                break;
                            }
                        }
                        lambda *= 8.0;
                    }
                    if !improved {
                        break;
                    }
                }
                set(&mut parts, &theta);
            }
        }
        let c = self.cost(&parts, range);
        (parts, c)
    }
}

/// Maps `f` over `items` on up to `threads` scoped threads, keeping the order.
pub fn par_map<T: Sync, R: Send>(
    items: &[T],
    threads: usize,
    f: impl Fn(&T) -> R + Sync,
) -> Vec<R> {
    let threads = threads.max(1).min(items.len().max(1));
    if threads == 1 {
        return items.iter().map(&f).collect();
    }
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results: std::sync::Mutex<Vec<Option<R>>> =
        std::sync::Mutex::new((0..items.len()).map(|_| None).collect());
    std::thread::scope(|s| {
        for _ in 0..threads {
            s.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                if i >= items.len() {
                    break;
                }
                let r = f(&items[i]);
                results.lock().expect("no panic while holding the lock")[i] = Some(r);
            });
        }
    });
    results
        .into_inner()
        .expect("threads joined")
        .into_iter()
        .map(|r| r.expect("every item mapped"))
        .collect()
}
