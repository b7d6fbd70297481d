//! Output-error fitting: the plant with a set of candidate effects switched on is simulated
//! with the recording's valve inputs, and the effects' parameters are fitted by
//! Levenberg-Marquardt on the simulated-minus-measured channels (each channel divided by its
//! spread, so the cost is the sum over channels of (1 - fit/100)^2).
//!
//! The parameters are fitted by the shared output-error fitter of `identify plant`
//! ([`crate::identify::output_error`]); failed simulations count as large residuals.

use crate::io::recording::{Channel, Recording};
use crate::io::timebase::MeasuredRows;
use crate::plant::config::PlantConfig;
use crate::plant::{Measurement, Plant, PlantState, ValveInputs};
use crate::sim::{simulate_each, SensorPath, SolverOptions};

use super::candidates::{Candidate, Setup};
use crate::identify::output_error::{self, Differences, OeOptions, OeParam};

/// One effect of a model with its parameter values.
#[derive(Clone)]
pub struct Part<'c> {
    pub candidate: &'c dyn Candidate,
    pub params: Vec<f64>,
}

/// The output-error problem on one recording.
pub struct Problem<'a> {
    pub nominal: &'a PlantConfig,
    /// The recording fitted.
    pub recording: &'a Recording,
    pub setup: Setup,
    pub inputs: &'a [ValveInputs],
    /// The recording's output channels (borrowed: no copy of a long recording).
    pub measured: [Option<&'a [f64]>; 5],
    /// Per-channel normalisation (the measured channel's standard deviation).
    pub scale: [f64; 5],
    /// States of the nominal simulation (reused when only sensor effects change): of every
    /// sample, or of the head a fit replays ([`Self::replay_heads`], built by
    /// [`Self::with_nominal_each`]); longer replays of sensor effects replay the nominal plant.
    pub base_states: Vec<PlantState>,
    pub opts: SolverOptions,
    /// Fits over a head of the recording replay only that head (set for recordings longer
    /// than the fit budget; a replay of a head can differ from the same samples of a full
    /// replay within the solver tolerance, so short recordings keep full replays).
    pub replay_heads: bool,
    /// The rows that hold measurements: rows filled in a gap of the log are replayed (the
    /// plant ran through them) but left out of every cost.
    pub rows: MeasuredRows,
}

impl<'a> Problem<'a> {
    /// The problem over `rec` (its present channels fitted, each divided by `scale`), with
    /// the nominal replay's states of every sample.
    pub fn new(
        nominal: &'a PlantConfig,
        rec: &'a Recording,
        scale: [f64; 5],
        opts: SolverOptions,
    ) -> Result<Self, crate::sim::SimError> {
        Self::with_nominal_each(nominal, rec, scale, opts, usize::MAX, |_, _| {})
    }

    /// [`Self::new`] for a recording whose fits replay only its first `head` samples
    /// ([`Self::replay_heads`] set when `head` is shorter than it): the nominal replay keeps
    /// the states of the head alone and hands the nominal channels of every sample to
    /// `f(k, channels)` in order as it runs (the same integrator calls and sensor path as
    /// `Plant::measure_series` on the full replay, so the same values to the bit).
    pub fn with_nominal_each(
        nominal: &'a PlantConfig,
        rec: &'a Recording,
        scale: [f64; 5],
        opts: SolverOptions,
        head: usize,
        mut f: impl FnMut(usize, &Measurement),
    ) -> Result<Self, crate::sim::SimError> {
        let dt_s = rec.sample_period_s();
        let plant = Plant::from_config(nominal);
        let n = rec.inputs.len();
        let keep = head.min(n);
        let mut base_states = Vec::with_capacity(keep);
        crate::sim::measure_each(&plant, &rec.inputs, dt_s, &opts, |k, x, m| {
            if base_states.len() < keep {
                base_states.push(*x);
            }
            f(k, m);
        })?;
        Ok(Self {
            nominal,
            recording: rec,
            setup: Setup {
                dt_s,
                present: std::array::from_fn(|i| rec.outputs[i].is_some()),
            },
            inputs: &rec.inputs,
            measured: std::array::from_fn(|i| rec.outputs[i].as_deref()),
            scale,
            base_states,
            opts,
            replay_heads: keep < n,
            rows: MeasuredRows::of(rec),
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

    /// True when the model `parts` moves the plant exactly as the nominal one (its parts
    /// change only what the sensors make of the states): the nominal states can be reused.
    /// Not when the replay starts from the recording's first sample as the sensors read it
    /// (`initial.as_read`): a sensor calibration then moves the start, and with it every
    /// state after (a pressure column logged absolute, read back to gauge, starts the muscle
    /// an atmosphere lower).
    fn sensors_only(&self, parts: &[Part]) -> bool {
        parts.iter().all(|p| !p.candidate.changes_dynamics()) && !self.nominal.initial.as_read
    }

    /// The simulated channels of the model `parts`; `None` if the simulation fails.
    pub fn predict(&self, parts: &[Part]) -> Option<Vec<Measurement>> {
        self.predict_until(parts, self.inputs.len())
    }

    /// [`Self::predict`] for the samples `0..end` a cost over a range ending at `end`
    /// reads: with [`Self::replay_heads`] only those are replayed, else all.
    fn predict_until(&self, parts: &[Part], end: usize) -> Option<Vec<Measurement>> {
        let end = if self.replay_heads {
            end.clamp(1, self.inputs.len())
        } else {
            self.inputs.len()
        };
        let cfg = self.config(parts);
        let plant = Plant::from_config(&cfg);
        let dt = self.setup.dt_s;
        if self.sensors_only(parts) && end <= self.base_states.len() {
            return Some(plant.measure_series(&self.base_states[..end], dt));
        }
        let mut out = Vec::with_capacity(end);
        self.replay_each(parts, end, |_, m| out.push(*m))
            .then_some(out)
    }

    /// Replays the model `parts` over samples `0..end` and hands the simulated channels of
    /// every sample to `f(k, channels)` in order, holding no series: the values of
    /// [`Self::predict`] to the bit when `end` is the recording's length. `false` if the
    /// simulation fails (`f` may then have seen a part of the samples).
    pub fn replay_each(
        &self,
        parts: &[Part],
        end: usize,
        mut f: impl FnMut(usize, &Measurement),
    ) -> bool {
        let cfg = self.config(parts);
        let plant = Plant::from_config(&cfg);
        let dt = self.setup.dt_s;
        let mut sensor = SensorPath::new(&plant, dt);
        let mut k = 0;
        let visit = |x: &PlantState| {
            let m = sensor.push(&plant, x);
            f(k, &m);
            k += 1;
        };
        let end = end.min(self.inputs.len());
        if self.sensors_only(parts) {
            // Sensor effects alone: the nominal states, measured by this model's sensors.
            if end <= self.base_states.len() {
                self.base_states[..end].iter().for_each(visit);
                return true;
            }
            let nominal = Plant::from_config(self.nominal);
            return simulate_each(&nominal, &self.inputs[..end], dt, &self.opts, |_| {}, visit)
                .is_ok();
        }
        simulate_each(&plant, &self.inputs[..end], dt, &self.opts, |_| {}, visit).is_ok()
    }

    /// Per-channel costs ([`Self::channel_costs`]) of the model `parts` over `range`, from a
    /// replay of the whole recording that holds no series (the same sums in the same order,
    /// so the same values to the bit as [`Self::predict`] + [`Self::channel_costs`]); `None`
    /// if the simulation fails.
    pub fn replay_costs(&self, parts: &[Part], range: std::ops::Range<usize>) -> Option<[f64; 5]> {
        let mut sums = [0.0f64; 5];
        let ok = self.replay_each(parts, self.inputs.len(), |k, m| {
            if range.contains(&k) && self.rows.has(k) {
                for c in Channel::ALL {
                    if let Some(y) = self.measured[c.index()] {
                        sums[c.index()] += ((c.of(m) - y[k]) / self.scale[c.index()]).powi(2);
                    }
                }
            }
        });
        let n = self.rows.count(range).max(1) as f64;
        ok.then(|| sums.map(|s| s / n))
    }

    /// Per-channel mean squared normalised error over `range` (0 for absent channels).
    pub fn channel_costs(&self, pred: &[Measurement], range: std::ops::Range<usize>) -> [f64; 5] {
        let mut out = [0.0; 5];
        let n = self.rows.count(range.clone()).max(1) as f64;
        for c in Channel::ALL {
            if let Some(y) = self.measured[c.index()] {
                let s = self.scale[c.index()];
                out[c.index()] = range
                    .clone()
                    .filter(|&k| self.rows.has(k))
                    .map(|k| ((c.of(&pred[k]) - y[k]) / s).powi(2))
                    .sum::<f64>()
                    / n;
            }
        }
        out
    }

    /// Total cost over `range` (sum of [`Self::channel_costs`]); infinite if the simulation fails.
    pub fn cost(&self, parts: &[Part], range: std::ops::Range<usize>) -> f64 {
        match self.predict_until(parts, range.end) {
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
        let pred = self.predict_until(parts, range.end)?;
        let idx: Vec<usize> = range
            .clone()
            .step_by(stride)
            .filter(|&k| self.rows.has(k))
            .collect();
        let w = 1.0 / (idx.len() as f64).sqrt();
        let mut r = Vec::with_capacity(idx.len() * 5);
        for c in Channel::ALL {
            if let Some(y) = self.measured[c.index()] {
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

    /// Cost of the model `parts` over `head` from a replay of `0..head.end` only (the
    /// ranking of a start grid: cheap, not the cost a fit reports); infinite when the replay
    /// fails.
    pub fn head_cost(&self, parts: &[Part], head: std::ops::Range<usize>) -> f64 {
        let mut sums = [0.0f64; 5];
        let ok = self.replay_each(parts, head.end, |k, m| {
            if head.contains(&k) {
                for c in Channel::ALL {
                    if let Some(y) = self.measured[c.index()] {
                        sums[c.index()] += ((c.of(m) - y[k]) / self.scale[c.index()]).powi(2);
                    }
                }
            }
        });
        let total: f64 = sums.iter().sum::<f64>() / head.len().max(1) as f64;
        if ok && total.is_finite() {
            total
        } else {
            f64::INFINITY
        }
    }

    /// Far-off values: each recalibrated key with a wide search range
    /// ([`super::start::log_grid`]) starts from the best point of its grid, ranked on a short
    /// head of `range` with the other parts held, when that point's cost is below
    /// [`super::start::GRID_SWITCH`] times the current start's.
    fn start_far_off(&self, parts: &mut [Part], range: &std::ops::Range<usize>) {
        let head = super::start::grid_head(range, self.setup.dt_s);
        if head.is_empty() {
            return;
        }
        for i in 0..parts.len() {
            let Some(grid) = super::start::log_grid(parts[i].candidate, &self.setup) else {
                continue;
            };
            let mut trial = parts.to_vec();
            let mut cost_at = |v: f64| {
                trial[i].params[0] = v;
                self.head_cost(&trial, head.clone())
            };
            let c0 = cost_at(parts[i].params[0]);
            let best = grid
                .into_iter()
                .map(|v| (cost_at(v), v))
                .min_by(|a, b| a.0.total_cmp(&b.0));
            if let Some((cb, v)) = best {
                if cb < super::start::GRID_SWITCH * c0 {
                    parts[i].params[0] = v;
                }
            }
        }
    }

    /// Fits the parameters of `parts` on `range` starting from their current values: first
    /// every discrete parameter over its grid (the others held), then the continuous ones
    /// with the shared output-error fitter ([`crate::identify::output_error::fit`]). Returns
    /// the fitted parts and the cost on `range`.
    pub fn fit<'c>(
        &self,
        parts: &[Part<'c>],
        range: std::ops::Range<usize>,
        max_iter: usize,
    ) -> (Vec<Part<'c>>, f64) {
        let (parts, cost, _) = self.fit_with_ci(parts, range, max_iter, false);
        (parts, cost)
    }

    /// [`Self::fit`], also returning (when `ci95`) the 95 % interval of every parameter of
    /// every part (NaN for grid parameters that are not refined).
    pub fn fit_with_ci<'c>(
        &self,
        parts: &[Part<'c>],
        range: std::ops::Range<usize>,
        max_iter: usize,
        ci95: bool,
    ) -> (Vec<Part<'c>>, f64, Vec<Vec<[f64; 2]>>) {
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
        self.start_far_off(&mut parts, &range);
        // Continuous parameters: (part, index) and their bounds.
        let mut slots: Vec<(usize, usize)> = Vec::new();
        let mut oe: Vec<OeParam> = Vec::new();
        for (i, p) in parts.iter().enumerate() {
            let gridded = p.candidate.grid(&p.params, &self.setup).is_some();
            if gridded && !p.candidate.refine_after_grid() {
                continue;
            }
            for (j, spec) in p.candidate.params(&self.setup).iter().enumerate() {
                // A refined grid parameter stays within one grid step of its grid value.
                let (lo, hi) = if gridded {
                    (
                        (p.params[j] - spec.scale).max(spec.lo),
                        (p.params[j] + spec.scale).min(spec.hi),
                    )
                } else {
                    (spec.lo, spec.hi)
                };
                slots.push((i, j));
                oe.push(OeParam {
                    x0: p.params[j].clamp(lo, hi),
                    lo,
                    hi,
                    scale: spec.scale,
                });
            }
        }
        let stride = (range.len() / 3000).max(1);
        let with = |xs: &[f64]| -> Vec<Part<'c>> {
            let mut trial = parts.clone();
            for (s, x) in slots.iter().zip(xs) {
                trial[s.0].params[s.1] = *x;
            }
            trial
        };
        let mut ci: Vec<Vec<[f64; 2]>> = parts
            .iter()
            .map(|p| vec![[f64::NAN; 2]; p.params.len()])
            .collect();
        if !oe.is_empty() {
            let residuals = |xs: &[f64]| self.residuals(&with(xs), &range, stride);
            let n = oe.len();
            let r = output_error::fit(
                &residuals,
                &oe,
                &OeOptions {
                    fd_step: 1e-3,
                    differences: Differences::Forward,
                    // About `max_iter` accepted steps: the crate counts residual evaluations.
                    patience: (2 * max_iter).div_ceil(n + 1).max(1),
                    tol: 1e-4,
                    ci95,
                },
            );
            if r.cost.1.is_finite() {
                parts = with(&r.x);
                for (s, c) in slots.iter().zip(&r.ci95) {
                    ci[s.0][s.1] = *c;
                }
            }
        }
        let c = self.cost(&parts, range);
        (parts, c, ci)
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
