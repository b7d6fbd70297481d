//! Diagnosis: locate where a recording departs from the nominal model, tell a nominal
//! parameter that is off (recalibration) from physics the model leaves out (a named effect),
//! model it with the plant's own code, and show the fit on the held-out data; or say
//! honestly that nothing is missing, that the catalogue does not explain the recording, or
//! that the recording does not look like this plant.
//!
//! [`diagnose`] is a pipeline of named stages, each a function testable alone:
//! 1. evidence ([`gather_evidence`]): the nominal replay, noise levels, the located error
//!    windows ([`locate`]) and the equation-error evidence ([`screen`]);
//! 2. candidates ([`selection::candidate_pool`]): the effect catalogue ([`candidates`],
//!    with physical bounds) and the recalibration of the plant's own keys
//!    ([`recalibrate`]), each screened for a start;
//! 3. selection ([`selection::select`]): output-error refits ([`fitting`], through the
//!    fitter shared with `identify plant`) on the head of TRAIN, scored on its tail, forward
//!    selection and a swap pass under one acceptance rule ([`selection::Rule`]);
//! 4. recalibration and final refit ([`final_refit`]): the chosen set refitted on all of
//!    TRAIN, with 95 % intervals for recalibrated keys and the parameters at a bound named;
//! 5. verdict and report ([`verdict`], [`answer`], [`report`]): `explained`,
//!    `nothing_missing`, `unexplained` or `not_this_plant`, the JSON and the text.

pub mod answer;
pub mod arm3;
#[cfg(any(test, feature = "test-support"))]
pub mod baseline;
pub mod batch;
pub mod black_box;
pub mod candidates;
pub mod differentiate;
pub mod discover;
pub mod fitting;
pub mod grade;
pub mod key_screen;
pub mod locate;
pub mod recalibrate;
pub mod report;
pub mod screen;
pub mod selection;
pub mod start;
#[cfg(any(test, feature = "test-support"))]
pub mod synth;
pub mod timebase;
pub mod valve_offset;
pub mod verdict;

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};

use crate::fit::fit_percent_of_err2;
use crate::io::recording::{Channel, Recording};
use crate::io::timebase::MeasuredRows;
use crate::plant::config::PlantConfig;
use crate::plant::{Measurement, Plant};
use crate::sim::SolverOptions;

pub use candidates::{catalogue, Candidate, Screening, Setup};
pub use differentiate::{noise_level, Differentiator, SavitzkyGolay};
use fitting::{Part, Problem};
pub use locate::Located;
use screen::{Evidence, Scatter};
pub use verdict::Verdict;

/// Tuning of the diagnosis.
#[derive(Debug, Clone)]
pub struct DiagnoseOptions {
    /// Share of TRAIN (from its start) the candidates are fitted on; the rest scores them.
    pub fit_fraction: f64,
    /// At most this many seconds of TRAIN (its head) are replayed by a fit: a long recording
    /// is fitted on its head and scored on all the rest (held-out fits and the final replay
    /// use the whole recording).
    pub fit_budget_s: f64,
    /// Levenberg-Marquardt iterations per fit (about; the fitter counts replays).
    pub max_iter: usize,
    /// At most this many effects and recalibrations are named.
    pub max_effects: usize,
    /// Worker threads for the candidate refits.
    pub threads: usize,
    /// TRAIN counts as explained within its noise when its cost is below this many times
    /// the cost of the noise alone.
    pub null_ratio: f64,
    /// An effect must remove at least this share of the held-out error beyond noise.
    pub min_explained: f64,
    /// ... and lower the held-out cost by at least this many times the noise's cost (an
    /// improvement clearly beyond noise, also when little error is left).
    pub min_gain_noise: f64,
    /// Held-out fits (%) below this: the answer is `unexplained`.
    pub min_heldout_fit_pct: f64,
    /// An answer that leaves TRAIN's error above this many times the noise on a channel is
    /// `unexplained` ([`verdict::MAX_RESIDUAL_X_NOISE`]).
    pub max_residual_x_noise: f64,
    /// Candidate ids (effects of the catalogue, `recalibrate` keys) left out of the pool:
    /// effects the plant the recording comes from cannot have (the 3-DOF arm has no
    /// thermal chamber). Empty for the 1-DOF plant.
    pub exclude_candidates: Vec<String>,
    /// The nominal model explains TRAIN (and CHECK) within its noise only when it also
    /// leaves no channel's error above this many times that channel's noise
    /// ([`verdict::residual_over_noise`]): one channel that departs is not hidden by the
    /// others in the summed cost.
    pub max_nothing_missing_x_noise: f64,
    /// Plausibility hints found by the caller (the arm's angle-unit check), answered like
    /// the recording's own ([`verdict::plausibility_hints`]): `not_this_plant`, no search.
    pub extra_hints: Vec<String>,
    pub solver: SolverOptions,
}

impl Default for DiagnoseOptions {
    fn default() -> Self {
        Self {
            fit_fraction: 0.7,
            fit_budget_s: 120.0,
            max_iter: 8,
            max_effects: 2,
            threads: 2,
            null_ratio: 1.5,
            min_explained: 0.3,
            min_gain_noise: 0.5,
            min_heldout_fit_pct: verdict::MIN_HELDOUT_FIT_PCT,
            max_residual_x_noise: verdict::MAX_RESIDUAL_X_NOISE,
            exclude_candidates: Vec::new(),
            // Chosen on the tuning seeds of the independent rig: the nominal model leaves
            // 0.8-1.1 times the noise on every channel of its own noisy, jittered and
            // open-loop recordings; an effect outside the model that costs a channel a few
            // points of fit leaves several times more.
            max_nothing_missing_x_noise: 3.0,
            extra_hints: Vec::new(),
            solver: SolverOptions {
                rtol: 1e-5,
                atol: 1e-6,
                // A candidate parameter that makes the plant very stiff fails fast (and
                // scores as a failed simulation) instead of stalling the search.
                max_steps_per_segment: 20_000,
            },
        }
    }
}

/// A named effect.
#[derive(Debug, Clone)]
pub struct NamedEffect {
    pub id: String,
    pub label: String,
    /// Fitted parameters, then fixed ones, (name, value).
    pub params: Vec<(String, f64)>,
    pub evidence: String,
    /// Share (0..1) of the held-out error beyond noise it removes.
    pub score: f64,
    pub description: String,
    /// Parameters that ended at a physical bound (name, bound).
    pub at_bound: Vec<(String, f64)>,
}

/// A recalibrated key of the plant file.
#[derive(Debug, Clone)]
pub struct Recalibrated {
    /// Dotted key (`valve.sonic_conductance_m3_per_s_pa`).
    pub key: String,
    pub label: String,
    pub nominal: f64,
    pub fitted: f64,
    /// 95 % interval (NaN when the recording does not determine it).
    pub ci95: [f64; 2],
    /// Share (0..1) of the held-out error beyond noise it removes.
    pub score: f64,
    /// The bound the fitted value sits on, if any.
    pub at_bound: Option<f64>,
}

/// How one candidate scored.
#[derive(Debug, Clone)]
pub struct CandidateScore {
    pub id: String,
    /// Selection round (1: alone on the nominal model, 2: on top of the first effect;
    /// above `max_effects`: a swap pass, `id` then names the whole trial set `a+b`).
    pub round: usize,
    pub screening: f64,
    pub params: Vec<(String, f64)>,
    /// Held-out cost (sum over channels of mean squared error / spread^2).
    pub heldout_cost: f64,
    /// Share of the held-out excess over noise removed.
    pub explained: f64,
    /// Change of the BIC-like score (negative: better).
    pub bic_delta: f64,
    pub accepted: bool,
    /// Wall time of its refit.
    pub seconds: f64,
}

/// Channels of one recording for the report: every `stride`-th sample (what its plots draw,
/// [`report::MAX_POINTS`] points, so the diagnosis holds no full-length series) and each
/// channel's range over all samples.
#[derive(Debug, Clone)]
pub struct Series {
    /// Samples of the recording.
    pub len: usize,
    /// Kept samples: 0, `stride`, 2 `stride`, ...
    pub stride: usize,
    pub t_s: Vec<f64>,
    /// Time of the recording's last sample.
    pub t_end_s: f64,
    pub measured: [Option<Vec<f64>>; 5],
    pub nominal: Vec<Measurement>,
    pub corrected: Vec<Measurement>,
    /// Per measured channel, the smallest and the largest finite value of the measured,
    /// nominal and corrected series over all samples (`[inf, -inf]` when there is none).
    pub range: [[f64; 2]; 5],
}

/// Widens the range `r` (smallest, largest) to take in `v` if it is finite.
fn widen(r: &mut [f64; 2], v: f64) {
    if v.is_finite() {
        r[0] = r[0].min(v);
        r[1] = r[1].max(v);
    }
}

impl Series {
    /// Every `stride`-th sample of `rec` with its nominal and corrected series, both given
    /// already thinned with their ranges per channel (`nominal` and `corrected`).
    fn thinned(rec: &Recording, stride: usize, nominal: &Replayed, corrected: Replayed) -> Self {
        let n = rec.len();
        let mut range = corrected.range;
        for c in Channel::ALL {
            if let Some(y) = rec.channel(c) {
                let r = &mut range[c.index()];
                y.iter().for_each(|v| widen(r, *v));
                let [lo, hi] = nominal.range[c.index()];
                widen(r, lo);
                widen(r, hi);
            }
        }
        let thin = |v: &[f64]| -> Vec<f64> { v.iter().step_by(stride).copied().collect() };
        Self {
            len: n,
            stride,
            t_s: thin(&rec.t_s),
            t_end_s: rec.t_s[n - 1],
            measured: std::array::from_fn(|i| rec.outputs[i].as_deref().map(thin)),
            nominal: nominal.thinned.clone(),
            corrected: corrected.thinned,
            range,
        }
    }
}

/// Everything the diagnosis found.
#[derive(Debug, Clone)]
pub struct Diagnosis {
    pub verdict: Verdict,
    pub located: Vec<Located>,
    pub effects: Vec<NamedEffect>,
    pub recalibrated: Vec<Recalibrated>,
    pub fit_before: BTreeMap<&'static str, f64>,
    pub fit_after: BTreeMap<&'static str, f64>,
    /// Fits on the held-out tail of TRAIN (error over the whole TRAIN spread) of the
    /// nominal model and of the best answer the selection found.
    pub heldout_before: BTreeMap<&'static str, f64>,
    pub heldout_after: BTreeMap<&'static str, f64>,
    pub check_before: Option<BTreeMap<&'static str, f64>>,
    pub check_after: Option<BTreeMap<&'static str, f64>>,
    /// When the correction made the CHECK recording worse ([`verdict::check_not_held`]): the
    /// channels that lost fit, "p1_kpa 100.0 % -> 82.8 %" (the verdict is then unexplained).
    pub check_not_held: Option<String>,
    /// When the nominal model explains TRAIN within its noise but not CHECK
    /// ([`verdict::check_departs`]): the channels that depart (the verdict is then
    /// unexplained).
    pub check_departs: Option<String>,
    /// When the named items only stood in for a term outside the catalogue
    /// ([`stand_in_check`]): the discovered term and the CHECK fits that showed it (the
    /// verdict is then unexplained).
    pub stood_in: Option<String>,
    /// The discovery on the nominal plant whose term showed the items to be stand-ins (what
    /// the discovery after an `unexplained` answer would compute again).
    pub stand_in_discovery: Option<discover::Discovery>,
    pub candidates: Vec<CandidateScore>,
    /// Every item of the best set graded on held-out data ([`grade`]): its share of the
    /// mismatch removed, kept or dropped and why; and what the kept ones remove together.
    pub grade: grade::Grade,
    /// Where the mismatch that the answer leaves remains (`partly_explained`): channel,
    /// windows, regime, on the corrected model's replay.
    pub remaining: Vec<Located>,
    /// The best set the selection found (ids), also when the verdict names nothing.
    pub best_attempt: Vec<String>,
    /// Parameters of the best set (named or not) that ended at a bound of the range the
    /// diagnosis searches.
    pub best_attempt_at_bound: Vec<BoundHit>,
    /// Look-alike statements.
    pub lookalikes: Vec<String>,
    /// What in the recording itself limits the answer (coarse on/off openings).
    pub data_notes: Vec<String>,
    /// The fitted pressure offset is one atmosphere: the columns were logged absolute, and
    /// the headline says so first.
    pub pressures_absolute: bool,
    /// Why the recording may not be of this plant (units, channel mapping).
    pub hints: Vec<String>,
    /// Failures met on the way (a replay that failed, with its time and state).
    pub failures: Vec<String>,
    /// The recording is explained by the nominal model within its noise.
    pub nothing_missing: bool,
    /// What the best answer (fitted, named or not) leaves of TRAIN's error on its worst
    /// channel, in times that channel's noise, and the channel ([`verdict::residual_over_noise`]).
    pub residual_x_noise: (f64, &'static str),
    /// The most an accepted answer may leave, in times the noise
    /// ([`DiagnoseOptions::max_residual_x_noise`]).
    pub max_residual_x_noise: f64,
    /// TRAIN's fits under the best answer (named or not).
    pub fit_best_attempt: BTreeMap<&'static str, f64>,
    /// Noise level per channel (channel units).
    pub noise: [f64; 5],
    /// Cost of TRAIN under the nominal model and of the noise alone.
    pub nominal_cost: f64,
    pub noise_cost: f64,
    pub corrected: PlantConfig,
    pub train: Series,
    pub check: Option<Series>,
    /// Residual vs regressor of the named effects (id, scatter).
    pub scatters: Vec<(String, Scatter)>,
    /// The unnamed black-box correction (verdict `unexplained` only).
    pub black_box: Option<black_box::BlackBox>,
}

#[derive(Debug, thiserror::Error)]
pub enum DiagnoseError {
    #[error("{0}")]
    Data(String),
    #[error("simulation of the nominal model failed: {0}")]
    Sim(#[from] crate::sim::SimError),
}

/// Fewest samples a recording needs.
pub const MIN_SAMPLES: usize = 200;

/// A pressure or tension channel that holds one value over the whole recording while the
/// valves move: a dead or unplugged sensor, which no physics of the plant explains and no fit
/// can be judged on (its spread is 0). `None` when every such channel moves, or when the
/// valves never change either (nothing was excited). The angle is not judged: a joint at an
/// end stop or clamped, read by a quantising encoder, legitimately holds one value.
fn dead_channel(rec: &Recording) -> Option<String> {
    let excited = rec.inputs.windows(2).any(|w| w[0] != w[1]);
    if !excited {
        return None;
    }
    [Channel::P1Kpa, Channel::P2Kpa, Channel::F1N, Channel::F2N]
        .into_iter()
        .find_map(|c| {
            let y = rec.outputs[c.index()].as_ref()?;
            let first = *y.first()?;
            y.iter().all(|v| *v == first).then(|| {
                format!(
                    "column `{}` is {first} in all {} samples while the valves move: a dead or \
                     unplugged sensor? The diagnosis compares the model with every recorded \
                     channel; fix the sensor, or leave the column out",
                    c.name(),
                    y.len()
                )
            })
        })
}

/// Spreads (max - min) below which a channel holds still: an encoder count or two (0.1 deg),
/// a pressure sensor's noise (1 kPa), a tension sensor's (2 N).
const STILL_DEG: f64 = 0.1;
const STILL_KPA: f64 = 1.0;
const STILL_N: f64 = 2.0;

/// A recording with nothing to judge: valve openings that never change and every recorded
/// channel holding still (a joint resting with its valves shut, e.g. the safe state of a
/// latched fault). Any plant file that rests there fits it, and a fit's percentage over a
/// spread of rounding is meaningless; `None` when something moves.
fn unexcited(rec: &Recording) -> Option<String> {
    if rec.inputs.windows(2).any(|w| w[0] != w[1]) {
        return None;
    }
    let still = |c: Channel, tol: f64| {
        rec.outputs[c.index()].as_ref().is_none_or(|y| {
            let (lo, hi) = y
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                    (lo.min(*v), hi.max(*v))
                });
            hi - lo <= tol
        })
    };
    (still(Channel::AngleDeg, STILL_DEG)
        && still(Channel::P1Kpa, STILL_KPA)
        && still(Channel::P2Kpa, STILL_KPA)
        && still(Channel::F1N, STILL_N)
        && still(Channel::F2N, STILL_N))
    .then(|| {
        format!(
            "nothing to judge: the valve openings never change over its {} samples and every \
             channel holds still (angle within {STILL_DEG} deg, pressures within {STILL_KPA} \
             kPa): a joint at rest with its valves shut (e.g. a latched fault's safe state). \
             Diagnose a recording in which the valves move the joint",
            rec.len()
        )
    })
}

/// A replay of `cfg` over `rec` (`CHECK`) holding no series: its fits, its plot points
/// (every [`plot_stride`]-th sample) and ranges, [`Replayed`]; `f(k, channels)` sees every
/// sample in order.
fn replay_recording(
    cfg: &PlantConfig,
    rec: &Recording,
    opts: &SolverOptions,
    mut f: impl FnMut(usize, &Measurement),
) -> Result<Replayed, crate::sim::SimError> {
    let plant = Plant::from_config(cfg);
    let dt = rec.sample_period_s();
    let mut sums = ReplaySums::new(rec, plot_stride(rec.len()));
    crate::sim::measure_each(&plant, &rec.inputs, dt, opts, |k, _, m| {
        sums.push(rec, k, m);
        f(k, m);
    })?;
    Ok(sums.replayed(rec))
}

/// The fits, plot points and ranges of a replay ([`Replayed`]), summed sample by sample.
struct ReplaySums {
    /// The rows that hold measurements (rows filled in a gap are left out of the fits).
    rows: MeasuredRows,
    err2: [f64; 5],
    range: [[f64; 2]; 5],
    thinned: Vec<Measurement>,
    stride: usize,
}

impl ReplaySums {
    fn new(rec: &Recording, stride: usize) -> Self {
        Self {
            rows: MeasuredRows::of(rec),
            err2: [0.0; 5],
            range: [[f64::INFINITY, f64::NEG_INFINITY]; 5],
            thinned: Vec::with_capacity(rec.len() / stride + 1),
            stride,
        }
    }

    /// Adds sample `k` (in order from 0) with its simulated channels `m`: the sums of
    /// `fit_percent` for every measured channel and its range.
    fn push(&mut self, rec: &Recording, k: usize, m: &Measurement) {
        let measured = self.rows.has(k);
        for c in Channel::ALL {
            if let Some(y) = rec.channel(c) {
                let (a, b) = (y[k], c.of(m));
                if measured {
                    self.err2[c.index()] += (a - b) * (a - b);
                }
                widen(&mut self.range[c.index()], b);
            }
        }
        if k % self.stride == 0 {
            self.thinned.push(*m);
        }
    }

    /// The fit of measured channel `c` (`fit_percent` to the bit).
    fn fit(&self, rec: &Recording, c: Channel) -> Option<f64> {
        let y = rec.channel(c)?;
        let err2 = self.err2[c.index()];
        Some(if self.rows.any_filled() {
            crate::fit::fit_percent_by(|| self.rows.values(y), err2)
        } else {
            fit_percent_of_err2(y, err2)
        })
    }

    fn fits(&self, rec: &Recording) -> BTreeMap<&'static str, f64> {
        Channel::ALL
            .iter()
            .filter_map(|c| Some((c.name(), self.fit(rec, *c)?)))
            .collect()
    }

    fn replayed(self, rec: &Recording) -> Replayed {
        Replayed {
            fits: self.fits(rec),
            thinned: self.thinned,
            range: self.range,
        }
    }
}

/// What the diagnosis keeps of the nominal replay of TRAIN, gathered sample by sample while
/// it runs (no full-length series): the channels of the head the fits and the evidence
/// read, the plot points and ranges, and the sums of the whole-recording fits, the costs
/// over all samples and over the held-out tail, the held-out fits and the plausibility
/// checks (each the held-series code's sum in the same order, so the same values to the
/// bit).
pub struct NominalReplay {
    /// The nominal channels of the first [`Gathered::fit_budget_n`] samples (all of a
    /// recording within the budget).
    pub head: Vec<Measurement>,
    /// Samples of TRAIN.
    pub len: usize,
    /// Samples `head` keeps.
    head_n: usize,
    /// The held-out tail of TRAIN.
    pub held: std::ops::Range<usize>,
    sums: ReplaySums,
    /// Sums of `((nominal - y) / spread)^2` per channel over all samples and over `held`.
    cost_sum: [f64; 5],
    held_cost_sum: [f64; 5],
    /// Sum of `(nominal - y)^2` per channel over `held`.
    held_sq: [f64; 5],
    /// Sum of every nominal channel over all samples.
    pub channel_sum: [f64; 5],
    pub plausibility: verdict::PlausibilitySums,
    /// Measured rows (not filled in a gap) of TRAIN and of `held`: the costs' divisors.
    measured_n: usize,
    measured_held_n: usize,
}

impl NominalReplay {
    fn new(rec: &Recording, head: usize, held: std::ops::Range<usize>) -> Self {
        Self {
            head: Vec::with_capacity(head.min(rec.len())),
            len: rec.len(),
            head_n: head.min(rec.len()),
            held,
            sums: ReplaySums::new(rec, plot_stride(rec.len())),
            cost_sum: [0.0; 5],
            held_cost_sum: [0.0; 5],
            held_sq: [0.0; 5],
            channel_sum: [0.0; 5],
            plausibility: verdict::PlausibilitySums::default(),
            measured_n: 0,
            measured_held_n: 0,
        }
    }

    fn push(&mut self, rec: &Recording, spread: &[f64; 5], k: usize, m: &Measurement) {
        if self.head.len() < self.head_n {
            self.head.push(*m);
        }
        self.sums.push(rec, k, m);
        let measured = self.sums.rows.has(k);
        let in_held = self.held.contains(&k);
        self.measured_n += usize::from(measured);
        self.measured_held_n += usize::from(measured && in_held);
        for c in Channel::ALL {
            let i = c.index();
            self.channel_sum[i] += c.of(m);
            if !measured {
                continue;
            }
            if let Some(y) = rec.channel(c) {
                let e = c.of(m) - y[k];
                let q = (e / spread[i]).powi(2);
                self.cost_sum[i] += q;
                if in_held {
                    self.held_cost_sum[i] += q;
                    self.held_sq[i] += e.powi(2);
                }
            }
        }
        self.plausibility.push(rec, k, m);
    }

    /// `fit_percent` of measured channel `c` against the nominal model over all samples.
    pub fn fit(&self, rec: &Recording, c: Channel) -> Option<f64> {
        self.sums.fit(rec, c)
    }

    /// The fits of every measured channel over all samples.
    pub fn fits(&self, rec: &Recording) -> BTreeMap<&'static str, f64> {
        self.sums.fits(rec)
    }

    /// [`Problem::channel_costs`] of the nominal replay over all samples (`held`: over the
    /// held-out tail), summed over the channels.
    pub fn cost(&self, held: bool) -> f64 {
        let (sums, n) = if held {
            (&self.held_cost_sum, self.measured_held_n)
        } else {
            (&self.cost_sum, self.measured_n)
        };
        let n = n.max(1) as f64;
        sums.map(|s| s / n).iter().sum()
    }

    /// Sum of `(nominal - y)^2` per channel over the held-out tail (the nominal model's
    /// residual energy there).
    pub fn held_energy(&self) -> [f64; 5] {
        self.held_sq
    }

    /// [`verdict::fit_vs_spread_of_sum`] of every measured channel over the held-out tail.
    pub fn heldout_fits(&self, rec: &Recording, spread: &[f64; 5]) -> BTreeMap<&'static str, f64> {
        Channel::ALL
            .iter()
            .filter(|c| rec.channel(**c).is_some())
            .map(|c| {
                let i = c.index();
                let fit =
                    verdict::fit_vs_spread_of_sum(self.held_sq[i], self.measured_held_n, spread[i]);
                (c.name(), fit)
            })
            .collect()
    }

    /// The nominal replay as the report keeps it.
    pub fn replayed(&self, rec: &Recording) -> Replayed {
        Replayed {
            fits: self.fits(rec),
            thinned: self.sums.thinned.clone(),
            range: self.sums.range,
        }
    }
}

/// Look-alike pairs (a, b): effects whose signatures resemble each other.
const LOOKALIKES: [(&str, &str); 6] = [
    ("joint_friction", "muscle_hysteresis"),
    // The isothermal pressure law sees only the ratio of the valve conductance to the
    // chamber volume.
    (
        "valve.sonic_conductance_m3_per_s_pa",
        "muscle.volume_poly_m3",
    ),
    ("sensor_lag", "valve_delay"),
    ("joint.inertia_kgm2", "gravity"),
    ("leakage", "supply_drop"),
    // Both make the pressure law non-isothermal; only the relaxation after a flow (the
    // wall heat exchange) tells them apart.
    ("heat_transfer", "polytropic"),
];

/// Output of the evidence stage.
pub struct Gathered<'a> {
    pub problem: Problem<'a>,
    /// The nominal replay of TRAIN: its head's channels and its sums.
    pub nominal: NominalReplay,
    pub present: [bool; 5],
    pub spread: [f64; 5],
    pub noise: [f64; 5],
    pub evidence: Evidence,
    pub located: Vec<Located>,
    /// Samples a fit replays at most ([`DiagnoseOptions::fit_budget_s`]).
    pub fit_budget_n: usize,
    /// Samples of the head of TRAIN the candidates are fitted on (`0..n_fit`); the rest,
    /// `nominal.held`, scores them.
    pub n_fit: usize,
}

/// Stage 1, evidence: replays the nominal plant (the only replay whose failure stops the
/// diagnosis), measures the noise and spread of every channel, builds the equation-error
/// evidence and locates the error windows.
pub fn gather_evidence<'a>(
    nominal: &'a PlantConfig,
    train: &'a Recording,
    opts: &DiagnoseOptions,
) -> Result<Gathered<'a>, DiagnoseError> {
    let n = train.len();
    let present: [bool; 5] = std::array::from_fn(|i| train.outputs[i].is_some());
    let (spread, noise) = timebase::spread_and_noise(train);
    let fit_budget_n = fit_budget_samples(opts, train.sample_period_s());
    let n_fit = ((n as f64 * opts.fit_fraction).round() as usize)
        .min(fit_budget_n)
        .clamp(
            MIN_SAMPLES / 2,
            n.saturating_sub(MIN_SAMPLES / 4).max(MIN_SAMPLES / 2),
        );
    // A recording longer than the budget: fits replay only the head they are scored on
    // (`replay_heads`), so the nominal states and channels are kept for that head alone;
    // the rest of the nominal replay is summed as it runs.
    let mut nom = NominalReplay::new(train, fit_budget_n, n_fit..n);
    let problem =
        Problem::with_nominal_each(nominal, train, spread, opts.solver, fit_budget_n, |k, m| {
            nom.push(train, &spread, k, m)
        })?;
    // The equation-error evidence and the error windows of that head too (a recording
    // within the budget: all of it), so their memory does not grow with the recording.
    let head_rec;
    let ev_rec = if n > fit_budget_n {
        head_rec = train.head(fit_budget_n);
        &head_rec
    } else {
        train
    };
    let ev_nominal = &nom.head[..ev_rec.len()];
    let diff = SavitzkyGolay::default();
    let evidence = Evidence::build(nominal, ev_rec, ev_nominal, &diff);
    let mut located = locate::locate(
        ev_rec,
        ev_nominal,
        &noise,
        &evidence.angle_rad,
        &evidence.omega_rad_s,
        &evidence.p_gauge_pa,
        &diff,
    );
    if ev_rec.len() < n {
        // The fits of the located channels over the whole recording, in locate's order.
        for l in &mut located {
            if let Some(fit) = nom.fit(train, l.channel) {
                l.fit_pct = fit;
            }
        }
        located.sort_by(|a, b| a.fit_pct.total_cmp(&b.fit_pct));
    }
    Ok(Gathered {
        problem,
        nominal: nom,
        present,
        spread,
        noise,
        evidence,
        located,
        fit_budget_n,
        n_fit,
    })
}

/// Cost of the noise alone: per channel (noise / spread)^2, at least
/// [`verdict::FIT_FLOOR_REL`]^2 (noise-free data is fitted to the integrator's accuracy,
/// not to zero).
pub fn noise_cost(present: &[bool; 5], noise: &[f64; 5], spread: &[f64; 5]) -> f64 {
    Channel::ALL
        .iter()
        .filter(|c| present[c.index()])
        .map(|c| {
            (noise[c.index()] / spread[c.index()])
                .max(verdict::FIT_FLOOR_REL)
                .powi(2)
        })
        .sum()
}

/// Output of the recalibration / final-refit stage.
pub struct Final<'c> {
    pub chosen: Vec<Part<'c>>,
    /// 95 % interval of every parameter of every part.
    pub ci95: Vec<Vec<[f64; 2]>>,
    pub corrected: PlantConfig,
    /// The corrected model's replay of TRAIN (the nominal one's if it failed).
    pub replay: Replayed,
    pub failures: Vec<String>,
}

/// What the diagnosis keeps of a replay of TRAIN: the fit of every channel and what the
/// report plots (every `stride`-th sample, each channel's range).
#[derive(Debug, Clone)]
pub struct Replayed {
    pub fits: BTreeMap<&'static str, f64>,
    pub thinned: Vec<Measurement>,
    pub range: [[f64; 2]; 5],
}

impl Replayed {
    /// Of the model `parts` replayed without holding its series (the fits are those of
    /// `fit_percent` on the held series to the bit); `None` if the simulation fails.
    pub fn stream(problem: &Problem, parts: &[Part], stride: usize) -> Option<Self> {
        let rec = problem.recording;
        let mut sums = ReplaySums::new(rec, stride);
        let ok = problem.replay_each(parts, rec.len(), |k, m| sums.push(rec, k, m));
        ok.then(|| sums.replayed(rec))
    }
}

/// The plot stride of a recording of `n` samples (what the report draws).
pub fn plot_stride(n: usize) -> usize {
    (n / report::MAX_POINTS).max(1)
}

/// Stage 4: refits the chosen set on all of TRAIN (with confidence intervals) and replays
/// the corrected model.
pub fn final_refit<'c>(
    g: &Gathered,
    chosen: Vec<Part<'c>>,
    n: usize,
    opts: &DiagnoseOptions,
) -> Final<'c> {
    let mut failures = Vec::new();
    let (chosen, ci95) = if chosen.is_empty() {
        (chosen, Vec::new())
    } else {
        let (fitted, _, ci) =
            g.problem
                .fit_with_ci(&chosen, 0..n.min(g.fit_budget_n), opts.max_iter, true);
        (fitted, ci)
    };
    let corrected = g.problem.config(&chosen);
    let rec = g.problem.recording;
    let stride = plot_stride(rec.len());
    let nominal_replay = || g.nominal.replayed(rec);
    // No part: the corrected model is the nominal one, whose replay is held.
    let replayed = if chosen.is_empty() {
        Some(nominal_replay())
    } else {
        Replayed::stream(&g.problem, &chosen, stride)
    };
    let replay = match replayed {
        Some(r) => r,
        None => {
            let plant = Plant::from_config(&corrected);
            let why = crate::sim::simulate_each(
                &plant,
                &rec.inputs,
                rec.sample_period_s(),
                &opts.solver,
                |_| {},
                |_| {},
            )
            .err()
            .map(|e| e.to_string())
            .unwrap_or_else(|| "non-finite channels".into());
            failures.push(format!("the corrected model could not replay TRAIN: {why}"));
            nominal_replay()
        }
    };
    Final {
        chosen,
        ci95,
        corrected,
        replay,
        failures,
    }
}

/// Samples a fit replays at most ([`DiagnoseOptions::fit_budget_s`] at the sample period
/// `dt_s`; unbounded without a budget).
fn fit_budget_samples(opts: &DiagnoseOptions, dt_s: f64) -> usize {
    if opts.fit_budget_s.is_finite() && opts.fit_budget_s > 0.0 {
        ((opts.fit_budget_s / dt_s).round() as usize).max(MIN_SAMPLES)
    } else {
        usize::MAX
    }
}

/// Run time per sample a fit replays [s] (one laptop core; measured: 120 s at 10 kHz took
/// 161 s, the fits of 1 h at 1 kHz about 16 s of its 18-25 s).
const SECONDS_PER_FIT_SAMPLE: f64 = 1.3e-4;
/// Run time per sample of the whole-recording replays (nominal, answer, check) [s].
const SECONDS_PER_REPLAY_SAMPLE: f64 = 1.5e-6;
/// Memory per recorded row (time, four openings, five channels as f64) [bytes].
const BYTES_PER_ROW: f64 = 80.0;
/// Memory per sample a fit replays (states and channels of the head kept) [bytes]
/// (measured: 650 MB at 1.2e6 fit samples, 367 MB for 1 h at 1 kHz).
const BYTES_PER_FIT_SAMPLE: f64 = 460.0;

/// The estimated time and memory of [`diagnose`] on these recordings, before any work:
/// within a factor of two on this project's machines (`docs/performance.md`).
pub fn run_estimate(
    train: &Recording,
    check: Option<&Recording>,
    opts: &DiagnoseOptions,
) -> crate::validate::RunEstimate {
    estimate_for(
        train.len(),
        train.sample_period_s(),
        check.map_or(0, |c| c.len()),
        opts,
    )
}

/// [`run_estimate`] from the rows of TRAIN, its sample period and the rows of CHECK.
pub fn estimate_for(
    rows: usize,
    dt_s: f64,
    check_rows: usize,
    opts: &DiagnoseOptions,
) -> crate::validate::RunEstimate {
    let (n, n_check) = (rows as f64, check_rows as f64);
    let fit_n = (fit_budget_samples(opts, dt_s) as f64).min(n);
    crate::validate::RunEstimate {
        what: format!(
            "diagnose: the fits replay {fit_n:.3e} samples (the first {:.0} s at {:.0} Hz)",
            fit_n * dt_s,
            1.0 / dt_s
        ),
        samples: n + n_check,
        bytes: BYTES_PER_ROW * (n + n_check) + BYTES_PER_FIT_SAMPLE * fit_n,
        seconds: SECONDS_PER_FIT_SAMPLE * fit_n
            + SECONDS_PER_REPLAY_SAMPLE * (2.0 * n + 2.0 * n_check),
    }
}

#[cfg(test)]
mod estimate_tests {
    use super::*;

    #[test]
    fn the_estimate_is_within_twice_the_measured_runs_and_refuses_beyond_the_limit() {
        let o = DiagnoseOptions::default();
        // (rows, dt, measured seconds, measured bytes): 120 s at 10 kHz, 1 h at 1 kHz.
        for (rows, dt_s, s, b) in [
            (1_200_000, 1e-4, 161.0, 650e6),
            (3_600_000, 1e-3, 22.0, 367e6),
        ] {
            let e = estimate_for(rows, dt_s, 0, &o);
            assert!(e.seconds > s / 2.0 && e.seconds < 2.0 * s, "{e:?}");
            assert!(e.bytes > b / 2.0 && e.bytes < 2.0 * b, "{e:?}");
            assert!(e.check(false).is_ok());
        }
        // 1 kHz for 30 s: a few seconds, no message needed.
        assert!(estimate_for(30_000, 1e-3, 0, &o).seconds < 30.0);
        // 20 M rows at 1 MHz: the fits replay all of it; refused unless allowed.
        let e = estimate_for(20_000_000, 1e-6, 0, &o);
        let msg = e.check(false).unwrap_err();
        assert!(
            msg.contains("--allow-large") && msg.contains("at 1000000 Hz"),
            "{msg}"
        );
        assert!(e.check(true).is_ok());
    }
}

/// A fitted parameter that ended at a bound of its search range.
#[derive(Clone, Debug, PartialEq)]
pub struct BoundHit {
    /// The candidate's id (an effect, or a plant-file key such as `muscle.radius_m`).
    pub part: String,
    /// The parameter's name.
    pub param: String,
    pub value: f64,
    pub bound: f64,
    /// The plant file's value, for a recalibrated key.
    pub nominal: Option<f64>,
}

/// Runs the diagnosis. `progress(done, total, stage)` is called as it goes. The stages of
/// the module doc, in order: the data checked ([`check_data`]), 1. [`gather_evidence`],
/// 2. [`screen_candidates`], 3. [`select_stage`] (and [`heldout_fits_after`]),
/// 4. [`final_refit`] (and [`bound_hits`], then CHECK: [`replay_check`]), 5. [`judge`] and
/// the answer ([`answer_of`], [`black_box_fallback`], [`lookalike_notes`], [`named_effects`]).
pub fn diagnose(
    nominal: &PlantConfig,
    train: &Recording,
    check: Option<&Recording>,
    opts: &DiagnoseOptions,
    progress: &(dyn Fn(u64, u64, &str) + Sync),
) -> Result<Diagnosis, DiagnoseError> {
    // Valve columns logged late against the sensors: named with the fix, as a unit slip is
    // (a plausibility hint: not this plant as logged, no search).
    let with_hint;
    let opts = match valve_offset::find_in(nominal, train, &opts.solver) {
        Some(off) => {
            with_hint = DiagnoseOptions {
                extra_hints: [opts.extra_hints.clone(), vec![off.hint()]].concat(),
                ..opts.clone()
            };
            &with_hint
        }
        None => opts,
    };
    timebase::diagnose_through_gaps(nominal, train, check, opts, progress, diagnose_pass)
}

/// One pass of [`diagnose`]: the openings over the gaps of a log that dropped rows are
/// estimated on `gap_model` (the nominal model when `None`). Returns the diagnosis and the
/// model of its best attempt (what the selection chose, whatever the verdict).
pub(crate) fn diagnose_pass(
    nominal: &PlantConfig,
    train: &Recording,
    check: Option<&Recording>,
    opts: &DiagnoseOptions,
    progress: &(dyn Fn(u64, u64, &str) + Sync),
    gap_model: Option<&PlantConfig>,
) -> Result<(Diagnosis, PlantConfig), DiagnoseError> {
    // Derivatives, lags and refits work on a uniform grid: jittered recordings are put on it
    // (openings time-averaged per cell, outputs interpolated; `Recording::to_uniform`).
    // A recording already on its grid is used as it is (no copy of a long recording).
    let uniform =
        |r: &Recording| -> Option<Recording> { (!r.is_uniform()).then(|| r.to_uniform()) };
    let (train_u, check_u) = (uniform(train), check.and_then(uniform));
    let train = train_u.as_ref().unwrap_or(train);
    let check = check.map(|c| check_u.as_ref().unwrap_or(c));
    let n = train.len();
    check_data(train, check)?;
    // A recording that starts away from the file's `[initial]` is replayed from its first
    // sample when that replays it better (`start`): the departure of the first seconds is
    // then not answered as the model's.
    let recorded_start = start::for_diagnosis(nominal, train, opts);
    let file_nominal = nominal;
    let nominal = recorded_start.as_ref().unwrap_or(nominal);
    // Rows the logger dropped: the openings over each gap estimated from the pressures
    // after it (`timebase::openings_over_gaps`); the rows stay out of every cost and fit.
    let gap_model = gap_model.unwrap_or(nominal);
    let (train_g, check_g) = (
        timebase::openings_over_gaps(gap_model, train, &opts.solver),
        check.and_then(|c| timebase::openings_over_gaps(gap_model, c, &opts.solver)),
    );
    let train = train_g.as_ref().unwrap_or(train);
    let check = check.map(|c| check_g.as_ref().unwrap_or(c));
    // Stage 2's pool is known before stage 1 runs (for the progress total).
    let cands = candidates_of(nominal, opts);
    let total = 4 + 2 * cands.len() as u64;
    let done = AtomicU64::new(0);
    let step = |msg: &str| {
        let d = done.fetch_add(1, Ordering::Relaxed) + 1;
        progress(d.min(total), total, msg);
    };
    progress(0, total, "nominal simulation");

    // 1. Evidence.
    let g = gather_evidence(nominal, train, opts)?;
    // Keys of one valve or one muscle only where the evidence points at that part.
    let cands = key_screen::retain_indicated(cands, nominal, &g.evidence);
    step("screening");
    // 2. Candidates, screened.
    let mut s = screen_candidates(&g, &cands, nominal, train, opts);
    step("screening done");
    // 3. Selection.
    let sel = select_stage(&g, &cands, &s, opts, &step);
    let heldout_before = g.nominal.heldout_fits(train, &g.spread);
    let heldout_after = heldout_fits_after(&g, &sel.chosen, train, &heldout_before);
    let best_attempt: Vec<String> = sel.chosen.iter().map(|p| p.candidate.id().into()).collect();
    // 4. Recalibration and final refit, then CHECK.
    let mut fin = final_refit(&g, sel.chosen, n, opts);
    step("final refit");
    let best_attempt_at_bound = bound_hits(&fin.chosen, &g.problem.setup);
    let mut failures = std::mem::take(&mut fin.failures);
    let from = CheckStart {
        file_nominal,
        nominal,
        train_own_start: recorded_start.is_some(),
    };
    let mut chk = replay_check(&from, check, &fin.chosen, g.present, opts);
    // 5. Grading: every item earns its place on held-out data, or is dropped.
    let (graded, not_held_before_grading) =
        grade_stage(&g, &from, check, &mut fin, &mut chk, opts, train);
    s.hints.append(&mut chk.hints);
    failures.append(&mut chk.failures);
    step("check");
    // 6. Verdict and answer.
    let j = judge(&s, &heldout_after, &chk, &fin, &g, &failures, &graded, opts);
    let j = stand_in_check(j, nominal, train, check, &chk, opts);
    let check_not_held = j.check_not_held.clone().or(not_held_before_grading);
    let v = j.verdict;
    let fit_best_attempt = fin.replay.fits.clone();
    let attempt_model = fin.corrected.clone();
    let (chosen, ci95, corrected, corrected_replay) = answer_of(v, fin, nominal, &g, train);
    let remaining = remaining_mismatch(v, &g, &chosen, train);
    if !v.names_items() {
        chk.show_nominal(check);
    }
    // The unnamed fallback when nothing explains the residual.
    let bb_check = check.filter(|_| chk.series.is_some());
    let black_box = black_box_fallback(v, &g, train, bb_check, nominal, opts);
    let named: Vec<&str> = chosen.iter().map(|p| p.candidate.id()).collect();
    let lookalikes = lookalike_notes(&named, &cands, &sel.round1_explained, &g, v);
    let named_out = named_effects(&chosen, &cands, &sel.explained, &ci95, &g, &s, &lookalikes);
    progress(total, total, "done");
    let absolute_note = verdict::absolute_pressure_note(nominal, &named_out.effects);
    let d = Diagnosis {
        pressures_absolute: absolute_note.is_some(),
        verdict: v,
        located: g.located,
        effects: named_out.effects,
        recalibrated: named_out.recalibrated,
        fit_before: s.fit_before,
        fit_after: corrected_replay.fits.clone(),
        heldout_before,
        heldout_after,
        check_before: chk.before,
        check_after: chk.after,
        check_not_held: check_not_held.filter(|_| v == Verdict::Unexplained),
        check_departs: j.check_departs,
        stood_in: j.stood_in,
        stand_in_discovery: j.stand_in_discovery,
        candidates: sel.scores,
        grade: graded,
        remaining,
        best_attempt,
        best_attempt_at_bound,
        lookalikes,
        data_notes: [
            verdict::coarse_onoff_note(train),
            verdict::unrecorded_note(train),
            verdict::start_note(file_nominal, train, recorded_start.is_some()),
            chk.start_note,
            absolute_note,
        ]
        .into_iter()
        .flatten()
        .collect(),
        hints: s.hints,
        failures,
        nothing_missing: v == Verdict::NothingMissing,
        residual_x_noise: j.residual_x_noise,
        max_residual_x_noise: opts.max_residual_x_noise,
        fit_best_attempt,
        black_box,
        noise: g.noise,
        nominal_cost: s.nominal_cost,
        noise_cost: s.noise_cost,
        corrected,
        train: Series::thinned(
            train,
            plot_stride(n),
            &g.nominal.replayed(train),
            corrected_replay,
        ),
        check: chk.series,
        scatters: named_out.scatters,
    };
    Ok((d, attempt_model))
}

/// The candidate pool ([`selection::candidate_pool`]) without
/// [`DiagnoseOptions::exclude_candidates`].
fn candidates_of(nominal: &PlantConfig, opts: &DiagnoseOptions) -> Vec<Box<dyn Candidate>> {
    selection::candidate_pool(nominal)
        .into_iter()
        .filter(|c| !opts.exclude_candidates.iter().any(|x| x == c.id()))
        .collect()
}

/// The recordings are long enough and every channel of them alive and excited.
fn check_data(train: &Recording, check: Option<&Recording>) -> Result<(), DiagnoseError> {
    let n = train.len();
    if n < MIN_SAMPLES {
        return Err(DiagnoseError::Data(format!(
            "{n} samples; the diagnosis needs at least {MIN_SAMPLES}"
        )));
    }
    if let Some(c) = check {
        if c.len() < 2 {
            return Err(DiagnoseError::Data(
                "check recording has fewer than 2 samples".into(),
            ));
        }
    }
    for (what, r) in [("recording", Some(train)), ("check recording", check)] {
        if let Some(msg) = r.and_then(dead_channel).or_else(|| r.and_then(unexcited)) {
            return Err(DiagnoseError::Data(format!("{what}: {msg}")));
        }
    }
    Ok(())
}

/// Output of stage 2: the candidates screened, and the nominal model against the noise.
pub struct Screened {
    pub screenings: Vec<Screening>,
    /// TRAIN's fits under the nominal model.
    pub fit_before: BTreeMap<&'static str, f64>,
    pub noise_cost: f64,
    pub nominal_cost: f64,
    /// Held-out cost of the nominal model.
    pub j0_h: f64,
    /// The nominal model explains TRAIN within its noise.
    pub nothing_missing: bool,
    /// Unit and wiring mistakes seen on the nominal replay (and the caller's extra hints).
    pub hints: Vec<String>,
}

/// Stage 2: screens every candidate on the evidence; judges the nominal model against the
/// noise (nothing missing: its cost within [`DiagnoseOptions::null_ratio`] times the
/// noise's and no channel's residual over [`DiagnoseOptions::max_nothing_missing_x_noise`]
/// times its noise) and looks for unit and wiring mistakes (a pressure in Pa, an angle in
/// radians, swapped channels), which are seen on the nominal replay alone.
pub fn screen_candidates(
    g: &Gathered,
    cands: &[Box<dyn Candidate>],
    nominal: &PlantConfig,
    train: &Recording,
    opts: &DiagnoseOptions,
) -> Screened {
    let fit_before = g.nominal.fits(train);
    let screenings: Vec<Screening> = cands
        .iter()
        .map(|c| c.screen(&g.evidence, &g.problem.setup))
        .collect();
    let noise_cost = noise_cost(&g.present, &g.noise, &g.spread);
    let nominal_cost = g.nominal.cost(false);
    let j0_h = g.nominal.cost(true);
    let nothing_missing = nominal_cost <= opts.null_ratio * noise_cost
        && !(verdict::residual_over_noise(&fit_before, &g.noise, &g.spread).0
            > opts.max_nothing_missing_x_noise);
    let mut hints = verdict::plausibility_hints(nominal, train, &g.nominal.plausibility);
    hints.extend(opts.extra_hints.iter().cloned());
    Screened {
        screenings,
        fit_before,
        noise_cost,
        nominal_cost,
        j0_h,
        nothing_missing,
        hints,
    }
}

/// Stage 3: the selection ([`selection::select`]) under the acceptance rule; skipped (an
/// empty set at the nominal held-out cost) when nothing is missing or a unit or wiring
/// mistake makes the answer `not_this_plant` whatever it finds (seconds instead of minutes).
pub fn select_stage<'c>(
    g: &Gathered,
    cands: &'c [Box<dyn Candidate>],
    s: &Screened,
    opts: &DiagnoseOptions,
    step: &(dyn Fn(&str) + Sync),
) -> selection::Selected<'c> {
    let held = g.nominal.held.clone();
    let rule = selection::Rule {
        min_explained: opts.min_explained,
        min_gain_noise: opts.min_gain_noise,
        noise_cost: s.noise_cost,
        n_heldout: g.problem.rows.count(held.clone()) as f64,
        explained_cost: opts.null_ratio * s.noise_cost,
    };
    if s.nothing_missing || !s.hints.is_empty() {
        selection::Selected {
            chosen: Vec::new(),
            heldout_cost: s.j0_h,
            explained: Vec::new(),
            round1_explained: BTreeMap::new(),
            scores: Vec::new(),
        }
    } else {
        selection::select(
            &g.problem,
            cands,
            &s.screenings,
            0..g.n_fit,
            held,
            s.j0_h,
            &rule,
            opts,
            step,
        )
    }
}

/// The held-out fits of the selection's best set (fitted on the head only): the same sums
/// as `heldout_before` (the nominal replay's, also when no part is chosen or the replay
/// fails), from a replay that is not held.
fn heldout_fits_after(
    g: &Gathered,
    chosen: &[Part],
    train: &Recording,
    heldout_before: &BTreeMap<&'static str, f64>,
) -> BTreeMap<&'static str, f64> {
    if chosen.is_empty() {
        return heldout_before.clone();
    }
    let held = &g.nominal.held;
    let rows = &g.problem.rows;
    let mut sum_sq = [0.0f64; 5];
    let ok = g.problem.replay_each(chosen, train.len(), |k, m| {
        if held.contains(&k) && rows.has(k) {
            for c in Channel::ALL {
                if let Some(y) = train.channel(c) {
                    sum_sq[c.index()] += (c.of(m) - y[k]).powi(2);
                }
            }
        }
    });
    if ok {
        Channel::ALL
            .iter()
            .filter(|c| train.channel(**c).is_some())
            .map(|c| {
                let fit = verdict::fit_vs_spread_of_sum(
                    sum_sq[c.index()],
                    rows.count(held.clone()),
                    g.spread[c.index()],
                );
                (c.name(), fit)
            })
            .collect()
    } else {
        heldout_before.clone()
    }
}

/// The parameters of the best set that ended at a bound of their search range.
fn bound_hits(chosen: &[Part], setup: &Setup) -> Vec<BoundHit> {
    chosen
        .iter()
        .flat_map(|p| {
            let c = p.candidate;
            let specs = c.params(setup);
            recalibrate::at_bounds(c, &p.params, setup)
                .into_iter()
                .map(move |(param, bound)| {
                    let i = specs.iter().position(|s| s.name == param).unwrap_or(0);
                    BoundHit {
                        part: c.id().to_string(),
                        value: p.params.get(i).copied().unwrap_or(f64::NAN),
                        nominal: recalibrate::is_recal_id(c.id()).then(|| specs[i].scale),
                        param,
                        bound,
                    }
                })
        })
        .collect()
}

/// Where the models replaying CHECK come from.
struct CheckStart<'a> {
    /// The plant file's model.
    file_nominal: &'a PlantConfig,
    /// The model TRAIN was replayed with (from its own first sample or the file's).
    nominal: &'a PlantConfig,
    /// TRAIN was replayed from its own first sample.
    train_own_start: bool,
}

/// CHECK's replays by the nominal and the corrected model.
#[derive(Default)]
struct CheckReplay {
    series: Option<Series>,
    /// The nominal model's replay.
    nominal: Option<Replayed>,
    start_note: Option<String>,
    before: Option<BTreeMap<&'static str, f64>>,
    after: Option<BTreeMap<&'static str, f64>>,
    /// Unit and wiring mistakes seen on CHECK.
    hints: Vec<String>,
    /// What the nominal model leaves of CHECK's error on its worst channel, in times that
    /// channel's noise (measured on CHECK), and the channel.
    nominal_x_noise: Option<(f64, &'static str)>,
    /// Replays that failed.
    failures: Vec<String>,
}

impl CheckReplay {
    /// Shows CHECK under the nominal model as the corrected one too (the answer names
    /// nothing).
    fn show_nominal(&mut self, check: Option<&Recording>) {
        if let (Some(b), Some(cs), Some(rec)) = (&self.before, &mut self.series, check) {
            self.after = Some(b.clone());
            let nom = self.nominal.as_ref().expect("replayed with the series");
            *cs = Series::thinned(rec, cs.stride, nom, nom.clone());
        }
    }
}

/// The answer's parts from the final refit: its set, intervals, corrected model and replay
/// when the verdict is `explained`; otherwise nothing named and the nominal model (whose
/// replay is held).
#[allow(clippy::type_complexity)]
fn answer_of<'c>(
    v: Verdict,
    fin: Final<'c>,
    nominal: &PlantConfig,
    g: &Gathered,
    train: &Recording,
) -> (Vec<Part<'c>>, Vec<Vec<[f64; 2]>>, PlantConfig, Replayed) {
    if v.names_items() {
        (fin.chosen, fin.ci95, fin.corrected, fin.replay)
    } else {
        (
            Vec::new(),
            Vec::new(),
            nominal.clone(),
            g.nominal.replayed(train),
        )
    }
}

/// Replays the check recording `rec` (none: nothing) (same rig, its own sample period) with the nominal
/// model and the one corrected by `chosen`. Both replays are summed as they run (plot
/// points, ranges, fits): no CHECK series is held. CHECK starts from its own first sample
/// when TRAIN did from its own, or when CHECK itself starts away from the file's
/// `[initial]` (a check cut from later in a run) and replays better from there: decided on
/// CHECK as on TRAIN. The unit and wiring checks run on CHECK too: a slip there is no
/// departure of the rig.
fn replay_check(
    from: &CheckStart,
    rec: Option<&Recording>,
    chosen: &[Part],
    present: [bool; 5],
    opts: &DiagnoseOptions,
) -> CheckReplay {
    let mut out = CheckReplay::default();
    let Some(rec) = rec else {
        return out;
    };
    let own_start = check_own_start(from, rec, opts);
    out.start_note = verdict::check_start_note(from.file_nominal, rec, own_start);
    let ccfg = check_config(from, rec, chosen, present, own_start);
    let mut check_plausibility = verdict::PlausibilitySums::default();
    let check_start = check_config(from, rec, &[], present, own_start);
    match (
        replay_recording(&check_start, rec, &opts.solver, |k, m| {
            check_plausibility.push(rec, k, m)
        }),
        replay_recording(&ccfg, rec, &opts.solver, |_, _| {}),
    ) {
        (Ok(before), Ok(after)) => {
            out.hints.extend(
                verdict::plausibility_hints(&check_start, rec, &check_plausibility)
                    .into_iter()
                    .map(|h| format!("in the check recording (--check): {h}")),
            );
            out.nominal_x_noise = Some(noise_multiple(rec, &before.fits));
            out.before = Some(before.fits.clone());
            out.after = Some(after.fits.clone());
            out.series = Some(Series::thinned(rec, plot_stride(rec.len()), &before, after));
            out.nominal = Some(before);
        }
        (b, a) => {
            for (which, r) in [("nominal", b.err()), ("corrected", a.err())] {
                if let Some(e) = r {
                    out.failures
                        .push(format!("the {which} model could not replay CHECK: {e}"));
                }
            }
        }
    }
    out
}

/// [`verdict::residual_over_noise`] of the fits `fits` of `rec`, against its own noise and
/// spread per channel.
fn noise_multiple(rec: &Recording, fits: &BTreeMap<&'static str, f64>) -> (f64, &'static str) {
    let mut noise = [0.0; 5];
    let mut spread = [1.0; 5];
    for c in Channel::ALL {
        if let Some(y) = rec.channel(c) {
            let n = y.len().max(1) as f64;
            let mean = y.iter().sum::<f64>() / n;
            let sd = (y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
            spread[c.index()] = if sd > 0.0 { sd } else { 1.0 };
            noise[c.index()] = noise_level(y);
        }
    }
    verdict::residual_over_noise(fits, &noise, &spread)
}

/// CHECK starts from its own first sample when TRAIN did from its own, or when CHECK itself
/// starts away from the file's `[initial]` and replays better from there.
fn check_own_start(from: &CheckStart, rec: &Recording, opts: &DiagnoseOptions) -> bool {
    from.train_own_start || start::for_diagnosis(from.file_nominal, rec, opts).is_some()
}

/// The model replaying CHECK: the nominal one with `parts` applied at CHECK's sample
/// period, from CHECK's own first sample when `own_start`.
fn check_config(
    from: &CheckStart,
    rec: &Recording,
    parts: &[Part],
    present: [bool; 5],
    own_start: bool,
) -> PlantConfig {
    let csetup = Setup {
        dt_s: rec.sample_period_s(),
        present,
    };
    let mut cfg = from.nominal.clone();
    for p in parts {
        p.candidate.apply(&mut cfg, &p.params, &csetup);
    }
    if own_start {
        start::as_recorded(&cfg, rec)
    } else {
        cfg
    }
}

/// Stage 5: grades every item of the final set on the held-out tail of TRAIN and on CHECK
/// ([`grade::grade`]); items that do not earn their place are dropped, and the corrected
/// model and CHECK's replays are then those of the rest. Also returns the CHECK channels the
/// selection's set made worse ([`verdict::check_not_held`]), said even when it is dropped.
fn grade_stage(
    g: &Gathered,
    from: &CheckStart,
    check: Option<&Recording>,
    fin: &mut Final,
    chk: &mut CheckReplay,
    opts: &DiagnoseOptions,
    train: &Recording,
) -> (grade::Grade, Option<String>) {
    // The selection's set made CHECK worse (said even when the grading then drops it).
    let not_held = match (&chk.before, &chk.after) {
        (Some(b), Some(a)) if !fin.chosen.is_empty() => verdict::check_not_held(b, a),
        _ => None,
    };
    if fin.chosen.is_empty() {
        return (grade::Grade::default(), not_held);
    }
    let held = g.nominal.held.clone();
    let n_held = held.len() as f64;
    let spread = g.spread;
    let heldout = |parts: &[Part]| -> grade::Energy {
        g.problem
            .replay_costs(parts, held.clone())
            .map(|c| std::array::from_fn(|i| c[i] * n_held * spread[i].powi(2)))
    };
    let check_rec = check.filter(|_| chk.before.is_some());
    let own_start = check_rec.is_some_and(|rec| check_own_start(from, rec, opts));
    let check_energy = |parts: &[Part]| -> grade::Energy {
        let rec = check_rec?;
        let cfg = check_config(from, rec, parts, g.present, own_start);
        grade::energy_of_replay(&cfg, rec, &opts.solver)
    };
    let e0_check = check_energy(&[]);
    let heldout_y = Channel::ALL
        .iter()
        .filter_map(|c| Some((*c, train.channel(*c)?[held.clone()].to_vec())))
        .collect();
    let replays = grade::Replays {
        heldout: &heldout,
        check: e0_check
            .is_some()
            .then_some(&check_energy as &dyn Fn(&[Part]) -> grade::Energy),
        spread,
        present: g.present,
        heldout_y,
        check_rec: check_rec.filter(|_| e0_check.is_some()),
    };
    let graded = grade::grade(
        &fin.chosen,
        &fin.ci95,
        &g.problem.setup,
        &replays,
        &g.nominal.held_energy(),
        e0_check.as_ref(),
    );
    let kept = graded.accepted();
    if kept.len() < fin.chosen.len() {
        let keep: Vec<bool> = fin
            .chosen
            .iter()
            .map(|p| kept.contains(&p.candidate.id()))
            .collect();
        let mut k = keep.iter();
        fin.chosen.retain(|_| *k.next().expect("one flag per part"));
        let mut k = keep.iter();
        fin.ci95.retain(|_| *k.next().unwrap_or(&false));
        fin.corrected = g.problem.config(&fin.chosen);
        let stride = plot_stride(train.len());
        fin.replay = if fin.chosen.is_empty() {
            g.nominal.replayed(train)
        } else {
            Replayed::stream(&g.problem, &fin.chosen, stride)
                .unwrap_or_else(|| g.nominal.replayed(train))
        };
        *chk = replay_check(from, check, &fin.chosen, g.present, opts);
    }
    (graded, not_held)
}

/// Where the mismatch a `partly_explained` answer `chosen` leaves remains
/// ([`locate::locate`] on the corrected model's replay of the head of TRAIN the evidence
/// was built on); nothing for another verdict.
fn remaining_mismatch(
    v: Verdict,
    g: &Gathered,
    chosen: &[Part],
    train: &Recording,
) -> Vec<Located> {
    if v != Verdict::PartlyExplained {
        return Vec::new();
    }
    let n = train.len().min(g.fit_budget_n);
    let head_rec;
    let rec = if n < train.len() {
        head_rec = train.head(n);
        &head_rec
    } else {
        train
    };
    let mut corrected = Vec::with_capacity(n);
    if !g.problem.replay_each(chosen, n, |_, m| corrected.push(*m)) || corrected.len() < n {
        return Vec::new();
    }
    locate::locate(
        rec,
        &corrected,
        &g.noise,
        &g.evidence.angle_rad,
        &g.evidence.omega_rad_s,
        &g.evidence.p_gauge_pa,
        &SavitzkyGolay::default(),
    )
}

/// Stage 6's verdict and what it rests on.
struct Judged {
    verdict: Verdict,
    residual_x_noise: (f64, &'static str),
    check_not_held: Option<String>,
    check_departs: Option<String>,
    stood_in: Option<String>,
    stand_in_discovery: Option<discover::Discovery>,
}

/// Stage 5b: an answer (`explained` or `partly_explained`) whose items only stand in for a
/// term outside the catalogue. The discovery runs on the nominal plant (a slot's term in closed form, kept
/// only when it holds on TRAIN's tail and on CHECK); when the term it keeps has physics the
/// catalogue lacks ([`discover::library::catalogue_counterpart`]) and fits CHECK's
/// departing channel (the nominal model's worst there) better than the named items by more
/// than [`verdict::MAX_CHECK_FIT_LOSS_PCT`], the margin within which two CHECK fits count as
/// equal, the items are not named: the verdict is `unexplained`, and `stood_in` says which
/// term held better.
fn stand_in_check(
    mut j: Judged,
    nominal: &PlantConfig,
    train: &Recording,
    check: Option<&Recording>,
    chk: &CheckReplay,
    opts: &DiagnoseOptions,
) -> Judged {
    if !j.verdict.names_items() {
        return j;
    }
    let (Some(check), Some(before), Some(after)) = (check, &chk.before, &chk.after) else {
        return j;
    };
    let Some(ch) = before
        .iter()
        .min_by(|a, b| a.1.total_cmp(b.1))
        .map(|(c, _)| *c)
    else {
        return j;
    };
    let dopts = discover::DiscoverOptions {
        catalogue_share: None,
        threads: opts.threads,
        solver: opts.solver,
        ..discover::DiscoverOptions::default()
    };
    let Ok(x) = discover::discover(nominal, train, Some(check), &dopts) else {
        return j;
    };
    let (Some(found), Some(fits)) = (&x.found, &x.check_after) else {
        return j;
    };
    // A term made only of the catalogue's own physics in other forms refines the answer.
    let new_physics = found
        .table
        .terms
        .iter()
        .any(|t| discover::library::catalogue_counterpart(t).is_none());
    if !new_physics {
        return j;
    }
    let (named, term) = (after.get(ch).copied(), fits.get(ch).copied());
    if let (Some(named), Some(term)) = (named, term) {
        if term - named > verdict::MAX_CHECK_FIT_LOSS_PCT {
            j.verdict = Verdict::Unexplained;
            j.stood_in = Some(format!(
                "{} (in {}): {ch} {term:.1} % on the check recording, against {named:.1} %",
                found.table.formula(),
                found.table.slot.equation()
            ));
            j.stand_in_discovery = Some(x);
        }
    }
    j
}

/// Stage 5: the verdict ([`verdict_of`]) from the fits the answer reaches on the held-out
/// tail and CHECK, what it leaves of TRAIN's error, and whether CHECK holds or departs.
#[allow(clippy::too_many_arguments)]
fn judge(
    s: &Screened,
    heldout_after: &BTreeMap<&'static str, f64>,
    chk: &CheckReplay,
    fin: &Final,
    g: &Gathered,
    failures: &[String],
    graded: &grade::Grade,
    opts: &DiagnoseOptions,
) -> Judged {
    let (nothing_missing, hints) = (s.nothing_missing, &s.hints);
    let min_heldout = lowest_fit(
        heldout_after
            .values()
            .chain(chk.after.iter().flat_map(|m| m.values()))
            .copied(),
    );
    // What the answer leaves of TRAIN's error, against the noise.
    let residual_x_noise = verdict::residual_over_noise(&fin.replay.fits, &g.noise, &g.spread);
    // A correction that makes the check recording worse did not hold there.
    let check_not_held = match (&chk.before, &chk.after) {
        (Some(b), Some(a)) if !fin.chosen.is_empty() => verdict::check_not_held(b, a),
        _ => None,
    };
    // Nothing missing on TRAIN, but CHECK departs from the same model: not an answer.
    let check_departs = match &chk.before {
        Some(c) if nothing_missing && hints.is_empty() => verdict::check_departs(&s.fit_before, c)
            .or_else(|| {
                chk.nominal_x_noise
                    .filter(|(x, _)| !(*x <= opts.max_nothing_missing_x_noise))
                    .map(|(x, ch)| {
                        format!(
                            "{ch} {:.1} % leaves {x:.1} times its noise (at most {:.0})",
                            c.get(ch).copied().unwrap_or(f64::NAN),
                            opts.max_nothing_missing_x_noise
                        )
                    })
            }),
        _ => None,
    };
    let facts = VerdictFacts {
        nothing_missing,
        hints: !hints.is_empty(),
        check_departs: check_departs.is_some(),
        unlike_plant: verdict::unlike_plant(&s.fit_before),
        min_heldout_fit_pct: min_heldout,
        chosen: !fin.chosen.is_empty(),
        residual_x_noise: residual_x_noise.0,
        failures: !failures.is_empty(),
        check_not_held: check_not_held.is_some(),
        removes_most: graded.removes_most(),
        key_at_bound: fin
            .chosen
            .iter()
            .any(|p| grade::recal_at_bound(p, &g.problem.setup)),
    };
    Judged {
        verdict: verdict_of(&facts, opts),
        residual_x_noise,
        check_not_held,
        check_departs,
        stood_in: None,
        stand_in_discovery: None,
    }
}

/// The lowest of `fits` [%]; a NaN fit (a channel that could not be scored) is the lowest
/// of all; `+inf` without any.
fn lowest_fit(fits: impl Iterator<Item = f64>) -> f64 {
    fits.fold(f64::INFINITY, |a, b| {
        if b.is_nan() {
            f64::NEG_INFINITY
        } else {
            a.min(b)
        }
    })
}

/// What the verdict is decided from.
struct VerdictFacts {
    /// The nominal model explains TRAIN within its noise.
    nothing_missing: bool,
    /// A unit or wiring hint was found.
    hints: bool,
    /// CHECK departs from the nominal model that explains TRAIN.
    check_departs: bool,
    /// TRAIN's nominal fits are unlike this plant's.
    unlike_plant: bool,
    /// The lowest held-out (and CHECK) fit of the answer [%].
    min_heldout_fit_pct: f64,
    /// The selection chose a set.
    chosen: bool,
    /// What the answer leaves of TRAIN's error on its worst channel, in times its noise.
    residual_x_noise: f64,
    /// A replay failed.
    failures: bool,
    /// The correction made CHECK worse.
    check_not_held: bool,
    /// The accepted items remove most of the mismatch on the held-out tail and on CHECK
    /// ([`grade::Grade::removes_most`]).
    removes_most: bool,
    /// A recalibrated key of the answer ended at the end of its search range: the file's
    /// value is off by more than the range; only a complete answer may rest on it.
    key_at_bound: bool,
}

/// The verdict: `nothing_missing` when the nominal model explains TRAIN within its noise,
/// no hint objects and CHECK does not depart; `unexplained` when CHECK departs;
/// `not_this_plant` on a unit or wiring hint, or when the recording is unlike the plant and
/// the held-out fits stay under [`DiagnoseOptions::min_heldout_fit_pct`]. Otherwise a set
/// whose items earned their place on held-out data ([`grade`]), whose fits reach that
/// minimum, that nothing failed and that CHECK holds is `explained` when what it leaves is at
/// the noise floor (within [`DiagnoseOptions::max_residual_x_noise`] times the noise) and
/// `partly_explained` when it removes most of the mismatch on the held-out data
/// ([`grade::MIN_PARTLY_SHARE`]); everything else is `unexplained`.
fn verdict_of(f: &VerdictFacts, opts: &DiagnoseOptions) -> Verdict {
    if f.nothing_missing && !f.hints && !f.check_departs {
        Verdict::NothingMissing
    } else if f.check_departs {
        Verdict::Unexplained
    } else if f.hints || (f.unlike_plant && !(f.min_heldout_fit_pct >= opts.min_heldout_fit_pct)) {
        Verdict::NotThisPlant
    } else if !f.chosen
        || !(f.min_heldout_fit_pct >= opts.min_heldout_fit_pct)
        || f.failures
        || f.check_not_held
    {
        Verdict::Unexplained
    } else if f.residual_x_noise <= opts.max_residual_x_noise {
        Verdict::Explained
    } else if f.removes_most && !f.key_at_bound {
        Verdict::PartlyExplained
    } else {
        Verdict::Unexplained
    }
}

/// The unnamed black-box correction ([`black_box::fit_streamed`]) on TRAIN's nominal replay
/// (its head held, the rest replayed) and CHECK's (`check`: when it was replayed).
fn black_box_fallback(
    v: Verdict,
    g: &Gathered,
    train: &Recording,
    check: Option<&Recording>,
    nominal: &PlantConfig,
    opts: &DiagnoseOptions,
) -> Option<black_box::BlackBox> {
    if v != Verdict::Unexplained {
        return None;
    }
    let (n, n_fit) = (train.len(), g.n_fit);
    let train_stream =
        |f: &mut dyn FnMut(usize, &Measurement)| g.problem.replay_each(&[], n, |k, m| f(k, m));
    let check_stream = |f: &mut dyn FnMut(usize, &Measurement)| match check {
        Some(rec) => replay_recording(nominal, rec, &opts.solver, |k, m| f(k, m)).is_ok(),
        None => false,
    };
    black_box::fit_streamed(
        train,
        &black_box::NominalRun {
            head: &g.nominal.head,
            channel_sum: g.nominal.channel_sum,
            stream: &train_stream,
        },
        0..n_fit,
        n_fit..n,
        check.map(|r| (r, &check_stream as black_box::NominalStream)),
    )
}

/// The label of candidate `id` ("?" when it is not in the pool).
fn label_of<'a>(cands: &'a [Box<dyn Candidate>], id: &str) -> &'a str {
    cands
        .iter()
        .find(|c| c.id() == id)
        .map(|c| c.label())
        .unwrap_or("?")
}

/// The look-alike statements of the answer: for each named member of a [`LOOKALIKES`] pair,
/// how much each of the pair removed in round 1 (and what tells them apart), then what the
/// recording's channels leave undecided (no force, no pressure).
fn lookalike_notes(
    named: &[&str],
    cands: &[Box<dyn Candidate>],
    round1_explained: &BTreeMap<&'static str, f64>,
    g: &Gathered,
    v: Verdict,
) -> Vec<String> {
    let setup = &g.problem.setup;
    let has_force = setup.has_force();
    let mut lookalikes = Vec::new();
    let pct = |id: &str| {
        round1_explained
            .get(id)
            .map(|v| 100.0 * v.max(0.0))
            .unwrap_or(0.0)
    };
    let label_of = |id: &str| label_of(cands, id);
    for (a, b) in LOOKALIKES {
        let (e, other) = if named.contains(&a) {
            (a, b)
        } else if named.contains(&b) {
            (b, a)
        } else {
            continue;
        };
        let s = match (a, has_force) {
            ("joint_friction", false) => format!(
                "Without force channels joint friction and muscle hysteresis cannot be told apart (both act as a torque opposing the motion): {} removes {:.0} % of the held-out error beyond noise, {} {:.0} %.",
                label_of(e), pct(e), label_of(other), pct(other)
            ),
            ("joint_friction", true) => format!(
                "The force channels tell joint friction from muscle hysteresis (braid friction changes the measured tensions, joint friction does not): {} removes {:.0} % of the held-out error beyond noise, {} {:.0} %.",
                label_of(e), pct(e), label_of(other), pct(other)
            ),
            ("valve.sonic_conductance_m3_per_s_pa", _) => format!(
                "The valve conductance and the chamber volume cannot be told apart by this recording (the isothermal pressure law sees only their ratio): recalibrating {} removes {:.0} % of the held-out error beyond noise, {} {:.0} %; measure one of them to fix the other.",
                label_of(e), pct(e), label_of(other), pct(other)
            ),
            ("heat_transfer", _) => format!(
                "Chamber thermodynamics vs a constant polytropic exponent, told apart by the pressure relaxing after each flow (the wall heat exchange): {} removes {:.0} % of the held-out error beyond noise, {} {:.0} %{}.",
                label_of(e), pct(e), label_of(other), pct(other),
                if (pct(e) - pct(other)).abs() < 5.0 {
                    "; this recording cannot tell them apart (hold the valves closed for a few tenths of a second after a fill to show the relaxation)"
                } else {
                    ""
                }
            ),
            ("sensor_lag", _) => {
                let lags: Vec<String> = Channel::ALL
                    .iter()
                    .filter(|c| g.present[c.index()])
                    .map(|c| format!("{} {:.0} ms", c.name(), g.evidence.lag_samples[c.index()] as f64 * setup.dt_s * 1e3))
                    .collect();
                format!(
                    "Sensor lag vs valve delay, told apart by which channels lag (best shifts: {}): {} removes {:.0} % of the held-out error beyond noise, {} {:.0} %.",
                    lags.join(", "), label_of(e), pct(e), label_of(other), pct(other)
                )
            }
            _ => format!(
                "Look-alike check: {} removes {:.0} % of the held-out error beyond noise, {} {:.0} %.",
                label_of(e), pct(e), label_of(other), pct(other)
            ),
        };
        lookalikes.push(s);
    }
    lookalikes.extend(recalibrate::group_notes(named, |k| {
        round1_explained.get(k).copied()
    }));
    if named.contains(&"sensor_gain") {
        lookalikes.push("A sensor gain on the angle, with or without a changed inertia, is also what a wrong sprocket radius or muscle rest length does to the model (the angle scales with the muscle travel over the radius): check `joint.sprocket_radius_m` and `muscle.rest_length_m` before trusting the gain (`host-sim identify plant --params KEY` fits one key).".into());
    }
    if (v.names_items() || v == Verdict::NothingMissing) && !has_force {
        let s = "No force channel was measured: joint friction and muscle hysteresis cannot be told apart.".to_string();
        if !lookalikes.iter().any(|l| l.starts_with("Without force")) {
            lookalikes.push(s);
        }
    }
    if (v.names_items() || v == Verdict::NothingMissing) && !setup.has_pressure() {
        lookalikes.push("No pressure channel was measured: leakage, supply drop and polytropic behaviour are judged from the angle alone and may not be told apart.".into());
    }
    lookalikes
}

/// The named parts of the answer, as the report shows them.
struct NamedParts {
    effects: Vec<NamedEffect>,
    recalibrated: Vec<Recalibrated>,
    /// Residual vs regressor of the named effects (id, scatter).
    scatters: Vec<(String, Scatter)>,
}

/// The answer's parts: a recalibrated key with its fitted value and 95 % interval, or a
/// named effect with its parameters, its description (a parameter at its physical bound
/// said), its evidence (its screening, its share of the held-out error, its look-alike
/// statement) and its scatter.
fn named_effects(
    chosen: &[Part],
    cands: &[Box<dyn Candidate>],
    explained: &[f64],
    ci95: &[Vec<[f64; 2]>],
    g: &Gathered,
    s: &Screened,
    lookalikes: &[String],
) -> NamedParts {
    let setup = &g.problem.setup;
    let screenings = &s.screenings;
    let mut effects = Vec::new();
    let mut recalibrated = Vec::new();
    let mut scatters = Vec::new();
    for (k, p) in chosen.iter().enumerate() {
        let c = p.candidate;
        let i = cands
            .iter()
            .position(|x| x.id() == c.id())
            .expect("from the pool");
        let score = explained.get(k).copied().unwrap_or(0.0).clamp(0.0, 1.0);
        let at_bound = recalibrate::at_bounds(c, &p.params, setup);
        if recalibrate::is_recal_id(c.id()) {
            let spec = &c.params(setup)[0];
            recalibrated.push(Recalibrated {
                key: c.id().to_string(),
                label: c.label().to_string(),
                nominal: spec.scale,
                fitted: p.params[0],
                ci95: ci95
                    .get(k)
                    .and_then(|v| v.first())
                    .copied()
                    .unwrap_or([f64::NAN; 2]),
                score,
                at_bound: at_bound.first().map(|b| b.1),
            });
            continue;
        }
        let mut params: Vec<(String, f64)> = c
            .params(setup)
            .iter()
            .zip(&p.params)
            .map(|(s, v)| (s.name.clone(), *v))
            .collect();
        for (name, v) in c.fixed() {
            params.push((name.into(), v));
        }
        let mut description = c.describe(&p.params, setup);
        for (name, b) in &at_bound {
            description += &format!(" ({name} at its physical bound {b})");
        }
        let mut evidence = format!(
            "{}: {}; refitted by output error it removes {:.0} % of the held-out error beyond noise.",
            description,
            screenings[i].note,
            100.0 * score
        );
        if let Some(l) = LOOKALIKES
            .iter()
            .find(|(a, b)| *a == c.id() || *b == c.id())
            .and_then(|(a, b)| {
                let other = if *a == c.id() { b } else { a };
                lookalikes
                    .iter()
                    .find(|s| s.contains(label_of(cands, other)))
            })
        {
            evidence.push(' ');
            evidence.push_str(l);
        }
        if let Some(sc) = &screenings[i].scatter {
            scatters.push((c.id().to_string(), sc.clone()));
        }
        effects.push(NamedEffect {
            id: c.id().into(),
            label: c.label().into(),
            params,
            evidence,
            score,
            description,
            at_bound,
        });
    }
    NamedParts {
        effects,
        recalibrated,
        scatters,
    }
}

#[cfg(test)]
mod verdict_rule_tests {
    use super::*;

    /// A set that explains: chosen, fits and residual within the options, nothing failed.
    fn explaining() -> VerdictFacts {
        let o = DiagnoseOptions::default();
        VerdictFacts {
            nothing_missing: false,
            hints: false,
            check_departs: false,
            unlike_plant: false,
            min_heldout_fit_pct: o.min_heldout_fit_pct + 1.0,
            chosen: true,
            residual_x_noise: 0.5 * o.max_residual_x_noise,
            failures: false,
            check_not_held: false,
            removes_most: true,
            key_at_bound: false,
        }
    }

    #[test]
    fn a_chosen_set_within_every_limit_explains_and_any_one_lapse_leaves_it_unexplained() {
        let o = DiagnoseOptions::default();
        assert_eq!(verdict_of(&explaining(), &o), Verdict::Explained);
        let lapses: [fn(&mut VerdictFacts); 4] = [
            |f| f.chosen = false,
            |f| f.min_heldout_fit_pct = f64::NAN,
            |f| f.failures = true,
            |f| f.check_not_held = true,
        ];
        for lapse in lapses {
            let mut f = explaining();
            lapse(&mut f);
            assert_eq!(verdict_of(&f, &o), Verdict::Unexplained);
        }
    }

    #[test]
    fn a_held_answer_above_the_noise_floor_is_partly_explained_when_it_removes_most_of_the_mismatch(
    ) {
        let o = DiagnoseOptions::default();
        let mut f = explaining();
        f.residual_x_noise = 2.0 * o.max_residual_x_noise;
        assert_eq!(verdict_of(&f, &o), Verdict::PartlyExplained);
        // A remainder of any size: the items held, so they are named.
        f.residual_x_noise = f64::INFINITY;
        assert_eq!(verdict_of(&f, &o), Verdict::PartlyExplained);
        // A key at the end of its search range does not carry a partial answer.
        f.key_at_bound = true;
        assert_eq!(verdict_of(&f, &o), Verdict::Unexplained);
        f.key_at_bound = false;
        // Removing a little of the mismatch is no answer.
        f.removes_most = false;
        assert_eq!(verdict_of(&f, &o), Verdict::Unexplained);
        // At the noise floor the share is not asked: explained.
        f.residual_x_noise = 0.5 * o.max_residual_x_noise;
        assert_eq!(verdict_of(&f, &o), Verdict::Explained);
    }

    #[test]
    fn a_hint_is_not_this_plant_unless_check_departs_and_nothing_missing_needs_neither() {
        let o = DiagnoseOptions::default();
        let mut f = explaining();
        f.nothing_missing = true;
        assert_eq!(verdict_of(&f, &o), Verdict::NothingMissing);
        f.hints = true;
        assert_eq!(verdict_of(&f, &o), Verdict::NotThisPlant);
        f.hints = false;
        f.check_departs = true;
        assert_eq!(verdict_of(&f, &o), Verdict::Unexplained);
        let mut unlike = explaining();
        unlike.unlike_plant = true;
        assert_eq!(verdict_of(&unlike, &o), Verdict::Explained);
        unlike.min_heldout_fit_pct = o.min_heldout_fit_pct - 1.0;
        assert_eq!(verdict_of(&unlike, &o), Verdict::NotThisPlant);
    }

    #[test]
    fn lowest_fit_takes_a_nan_for_the_lowest_of_all() {
        assert_eq!(lowest_fit([90.0, 40.0, 70.0].into_iter()), 40.0);
        assert_eq!(
            lowest_fit([90.0, f64::NAN, 40.0].into_iter()),
            f64::NEG_INFINITY
        );
        assert_eq!(lowest_fit(std::iter::empty()), f64::INFINITY);
    }
}
