//! Diagnosis: locate where a recording departs from the nominal model, name the
//! physics the model leaves out, model it with the plant's own effect code, and show the fit
//! improve on the training and on a check recording.
//!
//! Split like PySINDy, each step behind a small trait with a default:
//! - [`differentiate`]: smoothed derivatives of the measured channels ([`Differentiator`],
//!   default Savitzky-Golay) and their noise level;
//! - [`candidates`]: the effect library ([`Candidate`]: parameters, screening signature,
//!   how to switch it on in a [`PlantConfig`]);
//! - [`screen`]: equation-error evidence (torque balance, pressure law, tension law) from
//!   the measured states, plus output-side lags and offsets;
//! - [`fitting`]: output-error Levenberg-Marquardt refits of candidate parameters;
//! - selection ([`diagnose`]): forward selection scored on the held-out tail of TRAIN.
//!
//! Pipeline: (1) simulate the nominal plant with the recording's valve inputs, locate the
//! error per channel ([`locate`]); (2) screen every candidate; (3) refit every candidate by
//! output error on the first [`DiagnoseOptions::fit_fraction`] of TRAIN and score it on the
//! rest: an effect is accepted only if it removes a clear share of the held-out error
//! beyond the noise level and its BIC-like score (held-out log cost plus ln N per
//! parameter) improves; the best is taken and a second one tried on top (forward
//! selection); (4) if the nominal model already explains TRAIN within its noise, nothing is
//! named; (5) the chosen set is refitted on all of TRAIN and fits are reported on TRAIN and
//! CHECK.

pub mod baseline;
pub mod candidates;
pub mod differentiate;
pub mod fitting;
pub mod locate;
pub mod report;
pub mod screen;
pub mod synth;

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};

use crate::plant::config::PlantConfig;
use crate::fit::fit_percent;
use crate::plant::{Measurement, Plant};
use crate::io::recording::{Channel, Recording};
use crate::sim::{simulate, SolverOptions};

pub use candidates::{catalogue, Candidate, Screening, Setup};
pub use differentiate::{noise_level, Differentiator, SavitzkyGolay};
use fitting::{par_map, Part, Problem};
pub use locate::Located;
use screen::{Evidence, Scatter};

/// Tuning of the diagnosis.
#[derive(Debug, Clone)]
pub struct DiagnoseOptions {
    /// Share of TRAIN (from its start) the candidates are fitted on; the rest scores them.
    pub fit_fraction: f64,
    /// Levenberg-Marquardt iterations per fit.
    pub max_iter: usize,
    /// At most this many effects are named.
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
    pub solver: SolverOptions,
}

impl Default for DiagnoseOptions {
    fn default() -> Self {
        Self {
            fit_fraction: 0.7,
            max_iter: 8,
            max_effects: 2,
            threads: 2,
            null_ratio: 1.5,
            min_explained: 0.3,
            min_gain_noise: 0.5,
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

/// Channels of one recording for the report.
#[derive(Debug, Clone)]
pub struct Series {
    pub t_s: Vec<f64>,
    pub measured: [Option<Vec<f64>>; 5],
    pub nominal: Vec<Measurement>,
    pub corrected: Vec<Measurement>,
}

/// Everything the diagnosis found.
#[derive(Debug, Clone)]
pub struct Diagnosis {
    pub located: Vec<Located>,
    pub effects: Vec<NamedEffect>,
    pub fit_before: BTreeMap<&'static str, f64>,
    pub fit_after: BTreeMap<&'static str, f64>,
    pub check_before: Option<BTreeMap<&'static str, f64>>,
    pub check_after: Option<BTreeMap<&'static str, f64>>,
    pub candidates: Vec<CandidateScore>,
    /// Look-alike statements.
    pub lookalikes: Vec<String>,
    /// The recording is explained by the nominal model within its noise.
    pub nothing_missing: bool,
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

/// Round-1 candidates (best held-out cost first) the swap pass of [`diagnose`] draws from.
const SWAP_TOP: usize = 5;

fn fits_of(rec: &Recording, pred: &[Measurement]) -> BTreeMap<&'static str, f64> {
    let mut m = BTreeMap::new();
    for c in Channel::ALL {
        if let Some(y) = rec.channel(c) {
            let yh: Vec<f64> = pred.iter().map(|p| c.of(p)).collect();
            m.insert(c.name(), fit_percent(y, &yh));
        }
    }
    m
}

fn simulate_measure(
    cfg: &PlantConfig,
    rec: &Recording,
    opts: &SolverOptions,
) -> Result<Vec<Measurement>, crate::sim::SimError> {
    let plant = Plant::from_config(cfg);
    let dt = rec.sample_period_s();
    let sim = simulate(&plant, &rec.inputs, dt, opts)?;
    Ok(plant.measure_series(&sim.states, dt))
}

/// Look-alike pairs (a, b): effects whose signatures resemble each other.
const LOOKALIKES: [(&str, &str); 4] = [
    ("joint_friction", "muscle_hysteresis"),
    ("sensor_lag", "valve_delay"),
    ("inertia", "gravity"),
    ("leakage", "supply_drop"),
];

/// Runs the diagnosis. `progress(done, total, stage)` is called as it goes.
pub fn diagnose(
    nominal: &PlantConfig,
    train: &Recording,
    check: Option<&Recording>,
    opts: &DiagnoseOptions,
    progress: &(dyn Fn(u64, u64, &str) + Sync),
) -> Result<Diagnosis, DiagnoseError> {
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
    let cands = catalogue();
    let total = 4 + 2 * cands.len() as u64;
    let done = AtomicU64::new(0);
    let step = |msg: &str| {
        let d = done.fetch_add(1, Ordering::Relaxed) + 1;
        progress(d.min(total), total, msg);
    };
    progress(0, total, "nominal simulation");

    let present: [bool; 5] = std::array::from_fn(|i| train.outputs[i].is_some());
    let mut spread = [1.0; 5];
    let mut noise = [0.0; 5];
    for c in Channel::ALL {
        if let Some(y) = train.channel(c) {
            let mean = y.iter().sum::<f64>() / n as f64;
            let sd = (y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n as f64).sqrt();
            spread[c.index()] = if sd > 0.0 { sd } else { 1.0 };
            noise[c.index()] = noise_level(y);
        }
    }
    let problem = Problem::new(nominal, train, present, spread, opts.solver)?;
    let setup = problem.setup.clone();
    let nominal_plant = Plant::from_config(nominal);
    let nominal_meas = nominal_plant.measure_series(&problem.base_states, setup.dt_s);
    let fit_before = fits_of(train, &nominal_meas);
    step("screening");

    let diff = SavitzkyGolay::default();
    let ev = Evidence::build(nominal, train, &nominal_meas, &diff);
    let located = locate::locate(
        train,
        &nominal_meas,
        &noise,
        &ev.angle_rad,
        &ev.omega_rad_s,
        &ev.p_gauge_pa,
        &diff,
    );
    let screenings: Vec<Screening> = cands.iter().map(|c| c.screen(&ev, &setup)).collect();

    let n_fit = ((n as f64 * opts.fit_fraction).round() as usize)
        .clamp(MIN_SAMPLES / 2, n - MIN_SAMPLES / 4);
    let fit_range = 0..n_fit;
    let held = n_fit..n;
    let n_h = held.len() as f64;
    let noise_cost: f64 = Channel::ALL
        .iter()
        .filter(|c| present[c.index()])
        .map(|c| (noise[c.index()] / spread[c.index()]).powi(2))
        .sum();
    let nominal_cost: f64 = problem.channel_costs(&nominal_meas, 0..n).iter().sum();
    let j0_h: f64 = problem
        .channel_costs(&nominal_meas, held.clone())
        .iter()
        .sum();
    let nothing_missing = nominal_cost <= opts.null_ratio * noise_cost;
    step("screening done");

    let mut scores: Vec<CandidateScore> = Vec::new();
    let mut chosen: Vec<Part> = Vec::new();
    let mut chosen_explained: Vec<f64> = Vec::new();
    let mut round1_explained: BTreeMap<&str, f64> = BTreeMap::new();
    let bic = |j: f64, k: usize| n_h * (j / noise_cost.max(1e-300)).ln() + k as f64 * n_h.ln();
    if !nothing_missing {
        let mut current: Vec<Part> = Vec::new();
        let mut j_cur = j0_h;
        for round in 1..=opts.max_effects {
            if j_cur <= opts.null_ratio * noise_cost {
                break;
            }
            let todo: Vec<usize> = (0..cands.len())
                .filter(|i| !current.iter().any(|p| p.candidate.id() == cands[*i].id()))
                .collect();
            let results = par_map(&todo, opts.threads, |&i| {
                let t0 = std::time::Instant::now();
                let mut parts = current.clone();
                parts.push(Part {
                    candidate: cands[i].as_ref(),
                    params: screenings[i].initial.clone(),
                });
                let (fitted, _) = problem.fit(&parts, fit_range.clone(), opts.max_iter);
                let jh = match problem.predict(&fitted) {
                    Some(p) => problem.channel_costs(&p, held.clone()).iter().sum(),
                    None => f64::INFINITY,
                };
                step(&format!("round {round}: {}", cands[i].id()));
                (i, fitted, jh, t0.elapsed().as_secs_f64())
            });
            let excess = (j_cur - noise_cost).max(1e-12);
            let k_cur: usize = current.iter().map(|p| p.params.len()).sum();
            let mut best: Option<(usize, Vec<Part>, f64, f64)> = None;
            for (i, fitted, jh, seconds) in results {
                let explained = ((j_cur - jh) / excess).clamp(-1.0, 1.0);
                let k_new = fitted.iter().map(|p| p.params.len()).sum::<usize>();
                let bic_delta = bic(jh, k_new) - bic(j_cur, k_cur);
                let ok = jh.is_finite()
                    && explained >= opts.min_explained
                    && jh < j_cur * 0.98
                    && j_cur - jh >= opts.min_gain_noise * noise_cost
                    && bic_delta < 0.0;
                if round == 1 {
                    round1_explained.insert(cands[i].id(), explained);
                }
                let last = fitted.last().expect("one part added");
                let specs = cands[i].params(&setup);
                scores.push(CandidateScore {
                    id: cands[i].id().into(),
                    round,
                    screening: screenings[i].score,
                    params: specs
                        .iter()
                        .zip(&last.params)
                        .map(|(s, v)| (s.name.clone(), *v))
                        .collect(),
                    heldout_cost: jh,
                    explained,
                    bic_delta,
                    accepted: false,
                    seconds,
                });
                if ok && best.as_ref().is_none_or(|b| jh < b.2) {
                    best = Some((i, fitted, jh, explained));
                }
            }
            let Some((i, fitted, jh, explained)) = best else {
                break;
            };
            if let Some(s) = scores
                .iter_mut()
                .find(|s| s.round == round && s.id == cands[i].id())
            {
                s.accepted = true;
            }
            current = fitted;
            j_cur = jh;
            chosen_explained.push(explained);
        }
        // Swap pass (stepwise selection): forward selection is greedy, and a first pick
        // that stands in for two effects at once (supply drop for friction + leakage
        // without force channels) blocks the right pair. While the held-out error is still
        // clearly above noise, try the sets the greedy path skipped: each chosen effect
        // replaced by one of the SWAP_TOP best round-1 candidates, and (below max_effects)
        // every pair of those that leaves the chosen effects out. The best set is taken if it beats the current one by the
        // same rules as a forward step; repeated while it helps.
        let mut top: Vec<(usize, f64)> = scores
            .iter()
            .filter(|s| s.round == 1 && s.heldout_cost.is_finite())
            .filter_map(|s| {
                cands
                    .iter()
                    .position(|c| c.id() == s.id)
                    .map(|i| (i, s.heldout_cost))
            })
            .collect();
        top.sort_by(|a, b| a.1.total_cmp(&b.1));
        // One entry per effect id (supply drop has two forms).
        let mut seen: Vec<&str> = Vec::new();
        top.retain(|(i, _)| {
            let id = cands[*i].id();
            let new = !seen.contains(&id);
            seen.push(id);
            new
        });
        top.truncate(SWAP_TOP);
        let part = |i: usize| Part {
            candidate: cands[i].as_ref(),
            params: screenings[i].initial.clone(),
        };
        for pass in 1..=2 {
            if current.is_empty() || j_cur <= opts.null_ratio * noise_cost {
                break;
            }
            let in_current = |i: usize| current.iter().any(|p| p.candidate.id() == cands[i].id());
            let mut trials: Vec<Vec<Part>> = Vec::new();
            for j in 0..current.len() {
                for &(i, _) in top.iter().filter(|(i, _)| !in_current(*i)) {
                    let mut t = current.clone();
                    t[j] = part(i);
                    trials.push(t);
                }
            }
            if current.len() < opts.max_effects {
                for (a, &(i, _)) in top.iter().enumerate() {
                    for &(k, _) in &top[a + 1..] {
                        // Pairs that keep a chosen effect were the forward step's.
                        if !in_current(i) && !in_current(k) {
                            trials.push(vec![part(i), part(k)]);
                        }
                    }
                }
            }
            let results = par_map(&trials, opts.threads, |parts| {
                let t0 = std::time::Instant::now();
                let (fitted, _) = problem.fit(parts, fit_range.clone(), opts.max_iter);
                let jh = match problem.predict(&fitted) {
                    Some(p) => problem.channel_costs(&p, held.clone()).iter().sum(),
                    None => f64::INFINITY,
                };
                (fitted, jh, t0.elapsed().as_secs_f64())
            });
            let k_cur: usize = current.iter().map(|p| p.params.len()).sum();
            let excess = (j_cur - noise_cost).max(1e-12);
            let mut best: Option<(Vec<Part>, f64)> = None;
            let round = opts.max_effects + pass;
            for (fitted, jh, seconds) in results {
                let k_new = fitted.iter().map(|p| p.params.len()).sum::<usize>();
                let bic_delta = bic(jh, k_new) - bic(j_cur, k_cur);
                let ok = jh.is_finite()
                    && jh < j_cur * 0.98
                    && j_cur - jh >= opts.min_gain_noise * noise_cost
                    && bic_delta < 0.0;
                scores.push(CandidateScore {
                    id: fitted
                        .iter()
                        .map(|p| p.candidate.id())
                        .collect::<Vec<_>>()
                        .join("+"),
                    round,
                    screening: f64::NAN,
                    params: Vec::new(),
                    heldout_cost: jh,
                    explained: ((j_cur - jh) / excess).clamp(-1.0, 1.0),
                    bic_delta,
                    accepted: false,
                    seconds,
                });
                if ok && best.as_ref().is_none_or(|b| jh < b.1) {
                    best = Some((fitted, jh));
                }
            }
            let Some((fitted, jh)) = best else {
                break;
            };
            let id = fitted
                .iter()
                .map(|p| p.candidate.id())
                .collect::<Vec<_>>()
                .join("+");
            if let Some(s) = scores.iter_mut().find(|s| s.round == round && s.id == id) {
                s.accepted = true;
            }
            // Each effect's share: what it removed alone in round 1.
            chosen_explained = fitted
                .iter()
                .map(|p| {
                    round1_explained
                        .get(p.candidate.id())
                        .copied()
                        .unwrap_or(0.0)
                })
                .collect();
            current = fitted;
            j_cur = jh;
        }
        chosen = current;
    }
    // Final refit of the chosen set on all of TRAIN.
    if !chosen.is_empty() {
        let (fitted, _) = problem.fit(&chosen, 0..n, opts.max_iter);
        chosen = fitted;
    }
    step("final refit");
    let corrected = problem.config(&chosen);
    let corrected_meas = problem
        .predict(&chosen)
        .unwrap_or_else(|| nominal_meas.clone());
    let fit_after = fits_of(train, &corrected_meas);

    // Check recording: same rig, its own sample period.
    let mut check_series = None;
    let (mut check_before, mut check_after) = (None, None);
    if let Some(rec) = check {
        let csetup = Setup {
            dt_s: rec.sample_period_s(),
            present,
        };
        let mut ccfg = nominal.clone();
        for p in &chosen {
            p.candidate.apply(&mut ccfg, &p.params, &csetup);
        }
        let before = simulate_measure(nominal, rec, &opts.solver)?;
        let after = simulate_measure(&ccfg, rec, &opts.solver)?;
        check_before = Some(fits_of(rec, &before));
        check_after = Some(fits_of(rec, &after));
        check_series = Some(Series {
            t_s: rec.t_s.clone(),
            measured: rec.outputs.clone(),
            nominal: before,
            corrected: after,
        });
    }
    step("check");

    // Look-alikes.
    let has_force = setup.has_force();
    let mut lookalikes = Vec::new();
    let pct = |id: &str| {
        round1_explained
            .get(id)
            .map(|v| 100.0 * v.max(0.0))
            .unwrap_or(0.0)
    };
    let named: Vec<&str> = chosen.iter().map(|p| p.candidate.id()).collect();
    let label_of = |id: &str| {
        cands
            .iter()
            .find(|c| c.id() == id)
            .map(|c| c.label())
            .unwrap_or("?")
    };
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
            ("sensor_lag", _) => {
                let lags: Vec<String> = Channel::ALL
                    .iter()
                    .filter(|c| present[c.index()])
                    .map(|c| format!("{} {:.0} ms", c.name(), ev.lag_samples[c.index()] as f64 * setup.dt_s * 1e3))
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
    if !has_force {
        let s = "No force channel was measured: joint friction and muscle hysteresis cannot be told apart.".to_string();
        if !lookalikes.iter().any(|l| l.starts_with("Without force")) {
            lookalikes.push(s);
        }
    }
    if !setup.has_pressure() {
        lookalikes.push("No pressure channel was measured: leakage, supply drop and polytropic behaviour are judged from the angle alone and may not be told apart.".into());
    }

    let mut effects = Vec::new();
    let mut scatters = Vec::new();
    for (k, p) in chosen.iter().enumerate() {
        let c = p.candidate;
        let i = cands
            .iter()
            .position(|x| x.id() == c.id())
            .expect("from catalogue");
        let mut params: Vec<(String, f64)> = c
            .params(&setup)
            .iter()
            .zip(&p.params)
            .map(|(s, v)| (s.name.clone(), *v))
            .collect();
        for (name, v) in c.fixed() {
            params.push((name.into(), v));
        }
        let score = chosen_explained
            .get(k)
            .copied()
            .unwrap_or(0.0)
            .clamp(0.0, 1.0);
        let description = c.describe(&p.params, &setup);
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
                lookalikes.iter().find(|s| s.contains(label_of(other)))
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
        });
    }
    progress(total, total, "done");
    Ok(Diagnosis {
        located,
        effects,
        fit_before,
        fit_after,
        check_before,
        check_after,
        candidates: scores,
        lookalikes,
        nothing_missing,
        noise,
        nominal_cost,
        noise_cost,
        corrected,
        train: Series {
            t_s: train.t_s.clone(),
            measured: train.outputs.clone(),
            nominal: nominal_meas,
            corrected: corrected_meas,
        },
        check: check_series,
        scatters,
    })
}

fn json_num(v: f64, decimals: i32) -> serde_json::Value {
    if !v.is_finite() {
        return serde_json::Value::Null;
    }
    let f = 10f64.powi(decimals);
    serde_json::json!((v * f).round() / f)
}

fn json_fits(m: &BTreeMap<&'static str, f64>) -> serde_json::Value {
    serde_json::Value::Object(
        m.iter()
            .map(|(k, v)| (k.to_string(), json_num(*v, 2)))
            .collect(),
    )
}

impl Diagnosis {
    /// The JSON of the contract.
    pub fn to_json(&self) -> serde_json::Value {
        let located: Vec<serde_json::Value> = self
            .located
            .iter()
            .map(|l| {
                serde_json::json!({
                    "channel": l.channel.name(),
                    "fit_pct": json_num(l.fit_pct, 2),
                    "windows_s": l.windows_s.iter().map(|w| [json_num(w[0], 4), json_num(w[1], 4)]).collect::<Vec<_>>(),
                    "regime": l.regime,
                })
            })
            .collect();
        let effects: Vec<serde_json::Value> = self
            .effects
            .iter()
            .map(|e| {
                let params: serde_json::Map<String, serde_json::Value> = e
                    .params
                    .iter()
                    .map(|(k, v)| {
                        (
                            k.clone(),
                            if v.is_finite() {
                                serde_json::json!(v)
                            } else {
                                serde_json::Value::Null
                            },
                        )
                    })
                    .collect();
                serde_json::json!({
                    "id": e.id,
                    "params": params,
                    "evidence": e.evidence,
                    "score": json_num(e.score, 3),
                })
            })
            .collect();
        let mut out = serde_json::json!({
            "located": located,
            "effects": effects,
            "fit": {"before": json_fits(&self.fit_before), "after": json_fits(&self.fit_after)},
        });
        if let (Some(b), Some(a)) = (&self.check_before, &self.check_after) {
            out["check"] = serde_json::json!({"before": json_fits(b), "after": json_fits(a)});
        }
        out
    }

    /// The short human answer for stdout.
    pub fn answer(&self) -> String {
        let mut s = String::new();
        let fits = |m: &BTreeMap<&'static str, f64>| -> String {
            m.iter()
                .map(|(k, v)| format!("{k} {v:.1} %"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let change = |b: &BTreeMap<&'static str, f64>, a: &BTreeMap<&'static str, f64>| -> String {
            b.iter()
                .map(|(k, v)| {
                    format!(
                        "{k} {v:.1} % -> {:.1} %",
                        a.get(k).copied().unwrap_or(f64::NAN)
                    )
                })
                .collect::<Vec<_>>()
                .join(", ")
        };
        if self.nothing_missing {
            s += &format!(
                "Nothing is missing: the nominal model explains the recording within its noise (fits {}).\n",
                fits(&self.fit_before)
            );
            if let Some(b) = &self.check_before {
                s += &format!("Check recording: {}.\n", fits(b));
            }
            return s;
        }
        if self.effects.is_empty() {
            s += &format!(
                "The nominal model misses something (fits {}), but no effect in the catalogue explains it on the held-out part of the recording.\n",
                fits(&self.fit_before)
            );
        } else {
            let names: Vec<&str> = self.effects.iter().map(|e| e.label.as_str()).collect();
            s += &format!("The model leaves out {}:\n", names.join(" and "));
            for e in &self.effects {
                s += &format!("  - {} ({}): {}\n", e.label, e.id, e.description);
            }
            s += &format!(
                "Fit on the training recording: {}.\n",
                change(&self.fit_before, &self.fit_after)
            );
            if let (Some(b), Some(a)) = (&self.check_before, &self.check_after) {
                s += &format!("Fit on the check recording: {}.\n", change(b, a));
            }
        }
        for l in &self.located {
            let first = l
                .first_departure_s
                .map(|t| format!(", first departs at {t:.3} s"))
                .unwrap_or_default();
            s += &format!(
                "Located: {} (fit {:.1} %) in {} window(s), mostly during {}{}.\n",
                l.channel.name(),
                l.fit_pct,
                l.windows_s.len(),
                l.regime,
                first
            );
        }
        if let Some(first) = self
            .located
            .iter()
            .filter_map(|l| l.first_departure_s.map(|t| (t, l.channel)))
            .min_by(|a, b| a.0.total_cmp(&b.0))
        {
            s += &format!(
                "The first channel to depart is {} (at {:.3} s).\n",
                first.1.name(),
                first.0
            );
        }
        for l in &self.lookalikes {
            s += l;
            s.push('\n');
        }
        s
    }
}
