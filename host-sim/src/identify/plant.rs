//! Output-error identification of plant parameters from a recording.
//!
//! Chosen numeric keys of a plant TOML file (e.g. `valve.sonic_conductance_m3_per_s_pa`,
//! `muscle.damping_m2s`, `joint.inertia_kgm2`, or any key of an `[effects.*]` table) are fitted
//! by replaying the recording's valve inputs open loop on the plant ([`crate::sim::simulate`])
//! and minimising the difference between the simulated and the recorded channels with the
//! shared output-error fitter [`super::output_error::fit`] (the `levenberg-marquardt` crate).
//!
//! - Bounds by reparameterisation: a parameter with bounds `(lo, hi)` is `lo + (hi - lo)
//!   sigmoid(z)`, with only a lower bound `lo + (x0 - lo) e^z`, with only an upper bound
//!   `hi - (hi - x0) e^z`; every z starts at 0. Default bounds: `(0, inf)` for a positive start
//!   value, `(-inf, 0)` for a negative one, `(0, 1)` for the valve pressure ratios.
//! - Residuals: per recorded channel, `(simulated - measured) / std(measured)`, weighted so
//!   every channel counts equally; the Jacobian by central differences (2 replays per
//!   parameter), with a tight integrator tolerance so the differences are smooth.
//! - Validation: the fit uses the head of the recording; the tail (`holdout_fraction`) is
//!   held out. The whole recording is replayed with the start and the fitted values and the
//!   NRMSE fit of every channel is reported on the held-out tail (and on the training part).
//! - Output: the input plant file with only the fitted values replaced (comments, order and
//!   the other keys kept, `toml_edit`), written atomically.

// `!(a && b)` spelt out as the rule reads; `!(x > 0.0)` also rejects NaN.
#![allow(clippy::nonminimal_bool)]

use std::cell::RefCell;
use std::fmt::Write as _;
use std::path::Path;

use toml_edit::{DocumentMut, Item, Value};

use super::output_error::{self, Differences, OeOptions, OeParam};
use super::IdentError;
use crate::fit::fit_percent;
use crate::io::recording::{Channel, Recording};
use crate::sim::{simulate, SolverOptions};
use crate::{Plant, PlantConfig};

/// One parameter to fit: a dotted key of the plant file and its bounds.
#[derive(Clone, Debug, PartialEq)]
pub struct ParamSpec {
    /// Dotted key, e.g. `muscle.damping_m2s`.
    pub key: String,
    /// Lower bound (may be `-inf`).
    pub lower: f64,
    /// Upper bound (may be `inf`).
    pub upper: f64,
    /// The bounds were given (`key=lo:hi`); else they are the key's physical limits (a
    /// ratio's 0 and 1, the sign of the start value).
    pub user_bounds: bool,
}

/// A fitted value this close to a finite bound (fraction of the range; of the bound's or
/// the start value's magnitude, the larger, for a one-sided range) ended at it. A value the data pushes against a bound
/// ends far closer (the bounded reparameterisation's tail: the inertia of `pulses_loaded`
/// fitted within `0.001:0.1` ends at 0.1 to all printed digits), while a true value near
/// a bound stays clear of it (a laminar ratio of 0.999 in `0..1`).
pub const AT_BOUND_FRACTION: f64 = 1e-5;

/// A fitted value whose 95 % interval is wider than this fraction of its magnitude (of the
/// start value's, when larger) is not determined by the recording.
pub const UNDETERMINED_HALF_WIDTH_FRACTION: f64 = 0.25;

/// Two fitted values whose correlation exceeds this in magnitude are determined only
/// together.
pub const CORRELATED_ABOVE: f64 = 0.99;

/// Options of the plant fit.
#[derive(Clone, Debug)]
pub struct PlantFitOptions {
    /// Fraction of the recording (its tail) held out of the fit for validation.
    pub holdout_fraction: f64,
    /// Integrator tolerances for the replays (tight: the Jacobian is a finite difference).
    pub solver: SolverOptions,
    /// Relative step of the central differences, in the reparameterised coordinates.
    pub fd_step: f64,
    /// Levenberg-Marquardt patience (evaluations = patience * (parameters + 1)).
    pub patience: usize,
}

impl Default for PlantFitOptions {
    fn default() -> Self {
        PlantFitOptions {
            holdout_fraction: 0.25,
            solver: SolverOptions {
                rtol: 1e-9,
                atol: 1e-9,
                ..SolverOptions::default()
            },
            fd_step: 1e-4,
            patience: 40,
        }
    }
}

/// Fit of one channel on one part of the recording.
#[derive(Clone, Debug, PartialEq)]
pub struct ChannelScore {
    /// The channel.
    pub channel: Channel,
    /// NRMSE fit [%] with the start values.
    pub before_pct: f64,
    /// NRMSE fit [%] with the fitted values.
    pub after_pct: f64,
}

/// Result of [`fit_plant`].
#[derive(Clone, Debug)]
pub struct PlantFit {
    /// (key, start value, fitted value), in the order of the specs.
    pub params: Vec<(String, f64, f64)>,
    /// Fitted values that ended at a finite bound of their range (within
    /// [`AT_BOUND_FRACTION`] of the range, or of the value for a one-sided one): the rig's
    /// value may lie beyond it; one warning each.
    pub at_bound: Vec<String>,
    /// 95 % interval of each fitted value (NaN when the recording does not determine it),
    /// in the order of the specs; optimistic (output errors are correlated in time).
    pub ci95: Vec<[f64; 2]>,
    /// Fitted values the recording does not determine (a 95 % interval wider than
    /// [`UNDETERMINED_HALF_WIDTH_FRACTION`] of the value, or none), and pairs determined
    /// only together (correlation beyond [`CORRELATED_ABOVE`]); one warning each.
    pub undetermined: Vec<String>,
    /// Per-channel fit on the training part (head).
    pub train: Vec<ChannelScore>,
    /// Per-channel fit on the held-out tail.
    pub holdout: Vec<ChannelScore>,
    /// Samples used for the fit / held out.
    pub samples: (usize, usize),
    /// Levenberg-Marquardt termination and number of residual evaluations.
    pub termination: String,
    /// Replays of the training part.
    pub evaluations: usize,
    /// Weighted cost 0.5 |r|^2 at the start and at the end.
    pub cost: (f64, f64),
    /// The fitted plant file (the input text with the fitted values replaced).
    pub toml: String,
}

impl PlantFit {
    /// Mean over channels of the held-out fit before and after.
    pub fn holdout_mean_pct(&self) -> (f64, f64) {
        mean_scores(&self.holdout)
    }

    /// Human-readable report.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "output-error fit: {} training samples, {} held out; {} replays; {}",
            self.samples.0, self.samples.1, self.evaluations, self.termination
        );
        let _ = writeln!(
            s,
            "cost 0.5|r|^2: {:.6e} -> {:.6e}",
            self.cost.0, self.cost.1
        );
        let _ = writeln!(
            s,
            "{:<44} {:>14} {:>14} {:>9}  95 % interval",
            "parameter", "start", "fitted", "change"
        );
        let nan = [f64::NAN; 2];
        for (i, (k, a, b)) in self.params.iter().enumerate() {
            // Relative to the start; from a start of 0 the absolute change.
            let change = if *a != 0.0 {
                format!("{:>8.2}%", 100.0 * (b / a - 1.0))
            } else {
                format!("{:+.3e} (from 0)", b - a)
            };
            let [lo, hi] = self.ci95.get(i).copied().unwrap_or(nan);
            let interval = interval_text(lo, hi, *b);
            let _ = writeln!(s, "{k:<44} {a:>14.6e} {b:>14.6e} {change:>9}  {interval}");
        }
        for (name, scores) in [
            ("training part", &self.train),
            ("held-out tail", &self.holdout),
        ] {
            if scores.is_empty() {
                continue;
            }
            let _ = writeln!(
                s,
                "fit [%] on the {name}: {:<10} {:>9} {:>9}",
                "channel", "before", "after"
            );
            for c in scores.iter() {
                let _ = writeln!(
                    s,
                    "{:>33} {:<10} {:>9.3} {:>9.3}",
                    "",
                    c.channel.name(),
                    c.before_pct,
                    c.after_pct
                );
            }
            let (b, a) = mean_scores(scores);
            let _ = writeln!(s, "{:>33} {:<10} {:>9.3} {:>9.3}", "", "mean", b, a);
        }
        if self.holdout.is_empty() {
            let _ = writeln!(s, "fit [%] on the held-out tail: none held out");
        }
        for w in self.at_bound.iter().chain(&self.undetermined) {
            let _ = writeln!(s, "{w}");
        }
        s
    }
}

pub(crate) fn mean_scores(scores: &[ChannelScore]) -> (f64, f64) {
    let n = scores.len().max(1) as f64;
    (
        scores.iter().map(|c| c.before_pct).sum::<f64>() / n,
        scores.iter().map(|c| c.after_pct).sum::<f64>() / n,
    )
}

/// Parses `--params a,b,c` with optional bounds `key=lo:hi` (either side may be empty).
pub fn parse_param_specs(
    list: &[String],
    doc_text: &str,
    file: &str,
) -> Result<Vec<ParamSpec>, IdentError> {
    parse_param_specs_within(list, doc_text, file, &|_| None)
}

/// [`parse_param_specs`] where `allowed(key)` is the key's range in a plant file (range,
/// unit), when it has one: bounds given beyond it are refused (the fitted file would be),
/// default bounds are clipped to it.
pub fn parse_param_specs_within(
    list: &[String],
    doc_text: &str,
    file: &str,
    allowed: &dyn Fn(&str) -> Option<(crate::validate::Range, &'static str)>,
) -> Result<Vec<ParamSpec>, IdentError> {
    let doc: DocumentMut = doc_text
        .parse()
        .map_err(|e: toml_edit::TomlError| IdentError::Data(format!("{file}: {e}")))?;
    let mut out: Vec<ParamSpec> = Vec::new();
    for raw in list {
        let raw = raw.trim();
        if raw.is_empty() {
            continue;
        }
        let (key, bounds) = match raw.split_once('=') {
            Some((k, b)) => (k.trim(), Some(b.trim())),
            None => (raw, None),
        };
        let x0 = get_number(&doc, key, file)?;
        let (mut lo, mut hi) = default_bounds(key, x0);
        if let Some(b) = bounds {
            let (l, h) = b.split_once(':').ok_or_else(|| {
                IdentError::Data(format!(
                    "--params {raw}: bounds must be `key=lo:hi` (either side may be empty)"
                ))
            })?;
            let num = |s: &str, inf: f64| -> Result<f64, IdentError> {
                if s.trim().is_empty() {
                    Ok(inf)
                } else {
                    s.trim().parse().map_err(|_| {
                        IdentError::Data(format!("--params {raw}: bound {s:?} is not a number"))
                    })
                }
            };
            lo = num(l, f64::NEG_INFINITY)?;
            hi = num(h, f64::INFINITY)?;
            if !(lo < hi) {
                return Err(IdentError::Data(format!(
                    "--params {raw}: the bounds are reversed or empty: the lower {lo} must be \
                     below the upper {hi}"
                )));
            }
            if let Some((r, unit)) = allowed(key) {
                if lo < r.lo || hi > r.hi {
                    return Err(IdentError::Data(format!(
                        "--params {raw}: the bounds ({lo}, {hi}) leave the range of `{key}` in a \
                         plant file, {r} {unit}: a fitted value there would be refused; give \
                         bounds within it"
                    )));
                }
            }
        } else if let Some((r, _)) = allowed(key) {
            lo = lo.max(r.lo);
            hi = hi.min(r.hi);
        }
        if !(lo < hi) || !(x0 > lo && x0 < hi) {
            return Err(IdentError::Data(format!(
                "--params {raw}: the start value {x0} of `{key}` in {file} must lie strictly inside the bounds ({lo}, {hi})"
            )));
        }
        if out.iter().any(|p| p.key == key) {
            return Err(IdentError::Data(format!("--params: `{key}` given twice")));
        }
        out.push(ParamSpec {
            key: key.to_string(),
            lower: lo,
            upper: hi,
            user_bounds: bounds.is_some(),
        });
    }
    if out.is_empty() {
        return Err(IdentError::Data("--params: no parameter given".into()));
    }
    Ok(out)
}

fn default_bounds(key: &str, x0: f64) -> (f64, f64) {
    if key.ends_with("critical_ratio") || key.ends_with("laminar_ratio") {
        (0.0, 1.0)
    } else if x0 > 0.0 {
        (0.0, f64::INFINITY)
    } else if x0 < 0.0 {
        (f64::NEG_INFINITY, 0.0)
    } else {
        (f64::NEG_INFINITY, f64::INFINITY)
    }
}

fn item_at<'a>(doc: &'a DocumentMut, key: &str) -> Option<&'a Item> {
    let mut it: &Item = doc.as_item();
    for part in key.split('.') {
        it = it.get(part)?;
    }
    Some(it)
}

/// The shared key a key of one valve or one muscle inherits while its table does not set it
/// (`valve.inlet1.critical_ratio` -> `valve.critical_ratio`, `muscle.m2.initial_contraction`
/// -> `joint.initial_contraction`): fitting it starts from that value and writes the part's
/// own table.
fn inherited_key(key: &str) -> Option<String> {
    use crate::plant::config::{MUSCLE_TABLES, VALVE_TABLES};
    let mut it = key.splitn(3, '.');
    let (table, part, field) = (it.next()?, it.next()?, it.next()?);
    match table {
        "valve" if VALVE_TABLES.contains(&part) => Some(format!("valve.{field}")),
        "muscle" if MUSCLE_TABLES.contains(&part) && field == "initial_contraction" => {
            Some("joint.initial_contraction".into())
        }
        "muscle" if MUSCLE_TABLES.contains(&part) => Some(format!("muscle.{field}")),
        _ => None,
    }
}

fn get_number(doc: &DocumentMut, key: &str, file: &str) -> Result<f64, IdentError> {
    let item = item_at(doc, key)
        .filter(|i| !i.is_none())
        .or_else(|| item_at(doc, &inherited_key(key)?));
    let item = item.ok_or_else(|| {
        IdentError::Data(format!(
            "{file}: key `{key}`: no such key in the plant file"
        ))
    })?;
    match item.as_value() {
        Some(Value::Float(f)) => Ok(*f.value()),
        Some(Value::Integer(i)) => Ok(*i.value() as f64),
        _ => Err(IdentError::Data(format!(
            "{file}: key `{key}`: not a number (only scalar numeric keys can be fitted)"
        ))),
    }
}

/// Sets a numeric key, keeping the comment that follows the value. A missing table on the
/// way (a part's own table, `[valve.inlet1]`, for a key it inherited) is added as a table of
/// its own, not an inline one (a comment after the value would end an inline table's line).
fn set_number(doc: &mut DocumentMut, key: &str, x: f64) {
    let mut it: &mut Item = doc.as_item_mut();
    let parts: Vec<&str> = key.split('.').collect();
    for (n, part) in parts.iter().enumerate() {
        if n + 1 < parts.len() && it.get(part).is_none_or(|i| i.is_none()) {
            it[part] = Item::Table(toml_edit::Table::new());
        }
        it = &mut it[part];
    }
    let decor = it.as_value().map(|v| v.decor().clone());
    // Scientific notation keeps small SI values readable (8e-9, not 0.000000008).
    let mut v: Value = format!("{x:e}").parse().unwrap_or_else(|_| Value::from(x));
    if let Some(d) = decor {
        *v.decor_mut() = d;
    }
    *it = Item::Value(v);
}

/// The channels of a recording used by the fit.
fn channels_of(rec: &Recording) -> Vec<Channel> {
    Channel::ALL
        .into_iter()
        .filter(|c| rec.channel(*c).is_some())
        .collect()
}

struct Model<'a> {
    specs: &'a [ParamSpec],
    doc: RefCell<DocumentMut>,
    file: String,
}

impl Model<'_> {
    /// The plant with the parameters at x; also returns the file text.
    fn plant(&self, xs: &[f64]) -> Result<(Plant, String), IdentError> {
        let mut doc = self.doc.borrow_mut();
        for (s, x) in self.specs.iter().zip(xs) {
            set_number(&mut doc, &s.key, *x);
        }
        let text = doc.to_string();
        let cfg = PlantConfig::from_toml_str(&text, &self.file)
            .map_err(|e| IdentError::Data(e.to_string()))?;
        Ok((Plant::from_config(&cfg), text))
    }
}

/// Replays `rec`'s first `n` inputs on `plant` and returns the recorded channels.
fn replay(plant: &Plant, rec: &Recording, n: usize, opts: &SolverOptions) -> Option<Vec<Vec<f64>>> {
    let dt = rec.sample_period_s();
    let sim = simulate(plant, &rec.inputs[..n], dt, opts).ok()?;
    let meas = plant.measure_series(&sim.states, dt);
    let out: Vec<Vec<f64>> = channels_of(rec)
        .iter()
        .map(|c| meas.iter().map(|m| c.of(m)).collect())
        .collect();
    out.iter()
        .all(|ch| ch.iter().all(|v| v.is_finite()))
        .then_some(out)
}

/// Relative RMS error of the fit (over the channels, each by its spread) above which
/// [`fit_plant`] tries more starts.
pub const RESTART_ABOVE_REL_RMS: f64 = 0.1;

/// Fits `specs` of the plant file `plant_text` (named `plant_file` in messages) to `rec`.
/// Steps: the training / hold-out split, the start plant (it must replay the recording),
/// the excitation, the channel weights, the output-error fit (restarted when it stays
/// far off), the whole recording replayed before and after, the warnings.
pub fn fit_plant(
    rec: &Recording,
    plant_text: &str,
    plant_file: &str,
    specs: &[ParamSpec],
    opts: &PlantFitOptions,
) -> Result<PlantFit, IdentError> {
    let n = rec.len();
    let n_train = training_samples(n, specs.len(), opts.holdout_fraction)?;
    let chans = channels_of(rec);
    let doc: DocumentMut = plant_text
        .parse()
        .map_err(|e: toml_edit::TomlError| IdentError::Data(format!("{plant_file}: {e}")))?;
    let x0: Vec<f64> = specs
        .iter()
        .map(|s| get_number(&doc, &s.key, plant_file))
        .collect::<Result<_, _>>()?;
    let model = Model {
        specs,
        doc: RefCell::new(doc),
        file: plant_file.to_string(),
    };
    // Check the start plant before fitting.
    let (plant0, _) = model.plant(&x0)?;
    if replay(&plant0, rec, n_train, &opts.solver).is_none() {
        return Err(IdentError::Data(format!(
            "{plant_file}: the start plant cannot replay the recording"
        )));
    }
    check_excitation(rec, &chans, n_train)?;
    let weights = channel_weights(rec, &chans, n_train);
    let residuals = |xs: &[f64]| -> Option<Vec<f64>> {
        let (plant, _) = model.plant(xs).ok()?;
        let sim = replay(&plant, rec, n_train, &opts.solver)?;
        let mut r = Vec::with_capacity(n_train * chans.len());
        for (ci, c) in chans.iter().enumerate() {
            let y = &rec.channel(*c).expect("present")[..n_train];
            r.extend((0..n_train).map(|k| (sim[ci][k] - y[k]) * weights[ci]));
        }
        Some(r)
    };
    let params: Vec<OeParam> = specs
        .iter()
        .zip(&x0)
        .map(|(s, x)| OeParam {
            x0: *x,
            lo: s.lower,
            hi: s.upper,
            scale: param_scale(*x, s.lower, s.upper),
        })
        .collect();
    let oe = OeOptions {
        fd_step: opts.fd_step,
        differences: Differences::Central,
        patience: opts.patience,
        ..OeOptions::default()
    };
    let fit = fit_with_restarts(&residuals, &params, &oe);
    let (result, mut evaluations) = (fit.result, fit.evaluations);
    let cost1 = result.cost.1;
    let x1 = result.x.clone();
    let (plant1, toml) = model.plant(&x1)?;

    // Validation: whole recording, before and after.
    let full0 = replay(&plant0, rec, n, &opts.solver)
        .ok_or_else(|| IdentError::Data("the start plant cannot replay the recording".into()))?;
    let full1 = replay(&plant1, rec, n, &opts.solver)
        .ok_or_else(|| IdentError::Data("the fitted plant cannot replay the recording".into()))?;
    let score = |range: std::ops::Range<usize>| -> Vec<ChannelScore> {
        chans
            .iter()
            .enumerate()
            .map(|(ci, c)| {
                let y = &rec.channel(*c).expect("present")[range.clone()];
                ChannelScore {
                    channel: *c,
                    before_pct: fit_percent(y, &full0[ci][range.clone()]),
                    after_pct: fit_percent(y, &full1[ci][range.clone()]),
                }
            })
            .collect()
    };
    let held = held_warnings(specs, &params, &x1, &model);
    let (u, used) = output_error::uncertainty(&residuals, &params, &x1);
    evaluations += used;
    let mut undetermined = undetermined_warnings(specs, &x0, &x1, &u, &held);
    undetermined.extend(held.iter().flatten().cloned());
    // A value the recording does not pin down is not news at a bound.
    let at_bound = at_bound_warnings(specs, &x0, &x1)
        .into_iter()
        .enumerate()
        .filter(|&(i, _)| held[i].is_none() && determined(&x0, &x1, &u, i))
        .filter_map(|(_, w)| w)
        .collect();
    let (x_noise, worst) = residual_over_noise(rec, &chans, &full1, n_train);
    if !(x_noise <= crate::signal::MAX_RESIDUAL_X_NOISE) {
        undetermined.push(format!(
            "warning: the fitted plant still leaves {x_noise:.0} times the noise on {worst} (one \
             that describes the recording leaves at most {:.0}): the plant file with these keys \
             does not describe it, and the intervals (which assume it does) mean little. Widen \
             the bounds, fit other keys, or run `host-sim diagnose`",
            crate::signal::MAX_RESIDUAL_X_NOISE
        ));
    }
    Ok(PlantFit {
        params: specs
            .iter()
            .zip(x0.iter().zip(&x1))
            .map(|(s, (a, b))| (s.key.clone(), *a, *b))
            .collect(),
        at_bound,
        ci95: u.ci95(&x1),
        undetermined,
        train: score(0..n_train),
        holdout: if n_train < n {
            score(n_train..n)
        } else {
            Vec::new()
        },
        samples: (n_train, n - n_train),
        termination: format!("{}{}", result.termination, fit.starts_note),
        evaluations,
        cost: (fit.cost0, cost1),
        toml,
    })
}

/// The training samples of a recording of `n` (the head; the rest is held out): the
/// hold-out fraction in [0, 1), at least 20 training samples and 10 per parameter, and a
/// held-out tail of none or at least 20 samples (a tail of a few has no spread to judge a
/// fit by: its fit came out -inf %).
fn training_samples(n: usize, n_params: usize, holdout_fraction: f64) -> Result<usize, IdentError> {
    if !(0.0..1.0).contains(&holdout_fraction) {
        return Err(IdentError::Data(
            "hold-out fraction must be in [0, 1)".into(),
        ));
    }
    let n_train = ((1.0 - holdout_fraction) * n as f64).round() as usize;
    let n_train_min = (10 * n_params).max(20);
    if n_train < n_train_min {
        return Err(IdentError::Data(format!(
            "recording too short: {n_train} training samples for {n_params} parameters (at least \
             {n_train_min}: 20, and 10 a parameter); record a longer run"
        )));
    }
    let n_held = n - n_train;
    if n_held > 0 && n_held < 20 {
        return Err(IdentError::Data(format!(
            "recording too short: {n} samples leave {n_held} held out ({:.0} %), too few to \
             judge the fit by (at least 20); record a longer run",
            100.0 * holdout_fraction
        )));
    }
    Ok(n_train)
}

/// A recording in which nothing moves has nothing to identify (and no spread to judge a fit
/// by): refused when every channel is constant over the training part.
fn check_excitation(rec: &Recording, chans: &[Channel], n_train: usize) -> Result<(), IdentError> {
    let flat = |c: &Channel| {
        let y = &rec.channel(*c).expect("present")[..n_train];
        y.iter().all(|v| *v == y[0])
    };
    if chans.iter().all(flat) {
        return Err(IdentError::Data(format!(
            "no excitation: every channel ({}) is constant over the {n_train} training \
             samples, so no parameter shows in them; record a run in which the valves move \
             the joint",
            chans
                .iter()
                .map(|c| c.name())
                .collect::<Vec<_>>()
                .join(", ")
        )));
    }
    Ok(())
}

/// The residual weight of each channel: 1 / (its spread (sd) over the training part, a flat
/// channel's taken as 1) / sqrt(training samples x channels), so every channel counts alike
/// whatever its unit.
fn channel_weights(rec: &Recording, chans: &[Channel], n_train: usize) -> Vec<f64> {
    chans
        .iter()
        .map(|c| {
            let y = &rec.channel(*c).expect("present")[..n_train];
            let mean = y.iter().sum::<f64>() / y.len() as f64;
            let var = y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / y.len() as f64;
            // A flat channel is weighted by a unit spread.
            let sd = if var > 0.0 { var.sqrt() } else { 1.0 };
            1.0 / (sd * ((n_train * chans.len()) as f64).sqrt())
        })
        .collect()
}

/// The output-error fit and how it was reached.
struct RestartedFit {
    result: output_error::OeResult,
    /// The cost at the plant file's values.
    cost0: f64,
    evaluations: usize,
    /// What the restarts did ("; N starts (...)"), empty without them.
    starts_note: String,
}

/// The output-error fit from the plant file's values. A local search from them can stop in
/// a local minimum when a value is far off (an inertia 11 x the file's stops at 1.6 x): when
/// the fit leaves more than [`RESTART_ABOVE_REL_RMS`] relative RMS error, it starts again with
/// each value x 10 and / 10 (inside its bounds) and keeps the lowest cost.
fn fit_with_restarts(
    residuals: &output_error::Residuals<'_>,
    params: &[OeParam],
    oe: &OeOptions,
) -> RestartedFit {
    let mut result = output_error::fit(residuals, params, oe);
    let cost0 = result.cost.0;
    let mut evaluations = result.evaluations;
    let rel_rms = |cost: f64| (2.0 * cost).sqrt();
    let mut starts_note = String::new();
    let first_rel_rms = rel_rms(result.cost.1);
    if !(first_rel_rms <= RESTART_ABOVE_REL_RMS) {
        let mut tried = 1;
        for i in 0..params.len() {
            for f in [10.0, 0.1] {
                let mut p = params.to_vec();
                p[i].x0 *= f;
                let r = output_error::fit(residuals, &p, oe);
                evaluations += r.evaluations;
                tried += 1;
                if r.cost.1 < result.cost.1 {
                    result = r;
                }
            }
        }
        starts_note = format!(
            "; {tried} starts (the first left {:.1} % relative RMS error, the best {:.1} %)",
            100.0 * first_rel_rms,
            100.0 * rel_rms(result.cost.1)
        );
    }
    RestartedFit {
        result,
        cost0,
        evaluations,
        starts_note,
    }
}

/// Per key, a warning when the plant file's rules hold it where the fit ended (one key
/// bounded by another: coulomb friction at most the breakaway): a step of 1e-6 of its size
/// up or down, inside its bounds, makes the plant file refuse it. Such a key is named with
/// the rule, not as one the recording does not excite.
fn held_warnings(
    specs: &[ParamSpec],
    params: &[OeParam],
    x1: &[f64],
    model: &Model,
) -> Vec<Option<String>> {
    (0..specs.len())
        .map(|i| {
            let step = 1e-6 * x1[i].abs().max(params[i].scale.abs());
            [("up", step), ("down", -step)]
                .iter()
                .find_map(|&(way, h)| {
                    let mut x = x1.to_vec();
                    x[i] += h;
                    let inside = x[i] > specs[i].lower && x[i] < specs[i].upper;
                    let refused = inside.then(|| model.plant(&x).err()).flatten()?;
                    Some(format!(
                        "warning: {} is held at {:.6e}: the plant file refuses it a step {way} \
                     ({refused}); fit the key it is tied to as well, or give that key room in \
                     the start file",
                        specs[i].key, x1[i]
                    ))
                })
        })
        .collect()
}

/// The worst channel's error on the training part (the first `n_train` samples of the
/// replay `sim`) in times its own noise (the diagnosis' measure,
/// [`crate::signal::noise_level`], at least 1e-3 of the channel's spread):
/// a plant that describes the recording leaves a few times the noise at most.
fn residual_over_noise(
    rec: &Recording,
    chans: &[Channel],
    sim: &[Vec<f64>],
    n_train: usize,
) -> (f64, &'static str) {
    chans
        .iter()
        .zip(sim)
        .map(|(c, s)| {
            let y = &rec.channel(*c).expect("present")[..n_train];
            let n = n_train as f64;
            let mse = y.iter().zip(s).map(|(a, b)| (a - b).powi(2)).sum::<f64>() / n;
            let mean = y.iter().sum::<f64>() / n;
            let sd = (y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
            // A flat, noise-free channel matched exactly leaves 0 (not 0 / 0).
            let noise = crate::signal::noise_level(y)
                .max(1e-3 * sd)
                .max(f64::MIN_POSITIVE);
            (mse.sqrt() / noise, c.name())
        })
        .fold((0.0, ""), |w, x| if !(x.0 <= w.0) { x } else { w })
}

/// One warning per fitted value that ended at a bound it moved to (a value the plant file
/// already had there is no news): beyond a bound the user gave, the rig's value may lie; a
/// physical limit (a ratio's 0 or 1, zero for a signed key) means the recording asks for
/// more than the key can give.
fn at_bound_warnings(specs: &[ParamSpec], x0: &[f64], x1: &[f64]) -> Vec<Option<String>> {
    specs
        .iter()
        .zip(x0.iter().zip(x1))
        .map(|(s, (&start, &v))| {
            let span = if s.lower.is_finite() && s.upper.is_finite() {
                s.upper - s.lower
            } else {
                f64::NAN
            };
            // Of the range, else of the bound or the start value (a bound of 0).
            let near = |x: f64, b: f64| {
                let size = if span.is_finite() {
                    span
                } else {
                    b.abs().max(start.abs())
                };
                let tol = size * AT_BOUND_FRACTION;
                b.is_finite() && (x - b).abs() <= tol
            };
            let which = [("lower", s.lower), ("upper", s.upper)]
                .into_iter()
                .find(|&(_, b)| near(v, b) && !near(start, b) && !near(v, start))?;
            let (w, b) = which;
            Some(if s.user_bounds {
                format!(
                    "warning: {} ended at its {w} bound {b:.6e}: the rig's value may lie beyond \
                     it; give a wider range (--params {}=lo:hi) or check the plant file's other \
                     keys",
                    s.key, s.key
                )
            } else {
                format!(
                    "warning: {} was pushed to its physical limit {b:.6e}: the recording asks \
                     for more than this key can give; another key or an effect the plant file \
                     leaves out is likely off (host-sim diagnose names it)",
                    s.key
                )
            })
        })
        .collect()
}

/// The typical size of a fitted value starting at `x0` within `lower..upper`: its own
/// magnitude (a sonic conductance of 8e-9 m^3/(s Pa) next to an inertia of 1e-2 kg m^2; a
/// floor of 1 made the interval's difference step 1e-4, twelve thousand times the
/// conductance, and every value "not determined"), else the finite range's, else 1.
fn param_scale(x0: f64, lower: f64, upper: f64) -> f64 {
    if x0 != 0.0 && x0.is_finite() {
        x0.abs()
    } else if (upper - lower).is_finite() && upper > lower {
        (upper - lower).min(lower.abs().max(upper.abs()))
    } else {
        1.0
    }
}

/// The `i`-th value's 95 % interval is within [`UNDETERMINED_HALF_WIDTH_FRACTION`] of its
/// magnitude (of the start value's, when larger).
fn determined(x0: &[f64], x1: &[f64], u: &output_error::Uncertainty, i: usize) -> bool {
    let half = 1.96 * u.sd[i];
    half.is_finite() && half <= UNDETERMINED_HALF_WIDTH_FRACTION * x1[i].abs().max(x0[i].abs())
}

/// One warning per fitted value the recording does not determine (its 95 % interval wider
/// than [`UNDETERMINED_HALF_WIDTH_FRACTION`] of the value, or none) and per pair determined
/// only together (correlation beyond [`CORRELATED_ABOVE`]).
fn undetermined_warnings(
    specs: &[ParamSpec],
    x0: &[f64],
    x1: &[f64],
    u: &output_error::Uncertainty,
    held: &[Option<String>],
) -> Vec<String> {
    let mut out = Vec::new();
    for (i, s) in specs.iter().enumerate() {
        if held[i].is_some() || determined(x0, x1, u, i) {
            continue;
        }
        let half = 1.96 * u.sd[i];
        let size = x1[i].abs().max(x0[i].abs());
        let how = if half.is_finite() {
            let holds = if (x0[i] - x1[i]).abs() <= half {
                ", and it holds the plant file's value"
            } else {
                ""
            };
            format!(
                "its 95 % interval is +-{:.0} % of the value{holds}",
                100.0 * half / size.max(f64::MIN_POSITIVE)
            )
        } else {
            "the fit does not move with it".to_string()
        };
        out.push(format!(
            "warning: {} is not determined by this recording ({how}): the run does not excite \
             what it describes, and the written value is where the fit stopped. Fit it on a run \
             that excites it, or leave it out of --params to keep the plant file's value",
            s.key
        ));
    }
    for i in 0..specs.len() {
        for k in i + 1..specs.len() {
            let r = u.correlation[(i, k)];
            if r.abs() > CORRELATED_ABOVE {
                out.push(format!(
                    "warning: {} and {} are determined only together (correlation {r:+.3}): \
                     their fitted values can trade off against each other; fit one and keep the \
                     other at the plant file's value",
                    specs[i].key, specs[k].key
                ));
            }
        }
    }
    out
}

/// Reads the recording and the plant file and fits: the fit and the fitted plant file's text
/// (the input with the fitted values replaced, under a header saying what changed).
pub fn identify_plant_text(
    recording: &Path,
    plant: &Path,
    params: &[String],
    opts: &PlantFitOptions,
) -> Result<(PlantFit, String), IdentError> {
    // Jittered time stamps go on the uniform grid the fit simulates on.
    let rec = Recording::read(recording)
        .map_err(|e| IdentError::Data(e.to_string()))?
        .to_uniform();
    let file = plant.display().to_string();
    let text = std::fs::read_to_string(plant).map_err(|e| IdentError::Io {
        file: file.clone(),
        msg: e.to_string(),
    })?;
    // Validate the plant file as a whole first (errors name the key).
    let cfg =
        PlantConfig::from_toml_str(&text, plant).map_err(|e| IdentError::Data(e.to_string()))?;
    let rows = cfg.range_rows();
    let allowed = |key: &str| {
        rows.iter()
            .find(|(k, ..)| k == key && key != "muscle.volume_poly_m3")
            .map(|(_, _, r, unit)| (*r, *unit))
    };
    let specs = parse_param_specs_within(params, &text, &file, &allowed)?;
    let fit = fit_plant(&rec, &text, &file, &specs, opts).map_err(|e| match e {
        // Name the recording that is too short (`calibrate` passes its --plant-recording).
        IdentError::Data(m) if m.starts_with("recording too short") => {
            IdentError::Data(format!("{}: {m}", recording.display()))
        }
        e => e,
    })?;
    let mut body = String::new();
    let _ = writeln!(
        body,
        "# Fitted by `host-sim identify plant` from {} (start: {file}):",
        recording.display()
    );
    for (k, a, b) in &fit.params {
        let _ = writeln!(body, "#   {k}: {a:e} -> {b:e}");
    }
    if fit.holdout.is_empty() {
        let (tb, ta) = mean_scores(&fit.train);
        let _ = writeln!(
            body,
            "#   nothing held out; training part ({} samples): mean fit {tb:.3} % -> {ta:.3} %",
            fit.samples.0
        );
    } else {
        let (hb, ha) = fit.holdout_mean_pct();
        let _ = writeln!(
            body,
            "#   held-out tail ({} samples): mean fit {hb:.3} % -> {ha:.3} %",
            fit.samples.1
        );
    }
    body.push_str(&fitted_comments(
        &fit.toml,
        &fit.params,
        &recording.display().to_string(),
    ));
    Ok((fit, body))
}

/// The summary's 95 % interval of a fitted value `b`: `+-x %`, in the key's unit about a
/// value of (almost) 0, `none` when not determined, and said not estimable when it rounds to
/// zero width (a noise-free recording: the residual left is the integrator's error, not
/// noise, and an interval from it is no uncertainty of the value).
fn interval_text(lo: f64, hi: f64, b: f64) -> String {
    let half = 0.5 * (hi - lo);
    if !(lo.is_finite() && hi.is_finite()) {
        "none (not determined)".to_string()
    } else if half < 5e-5 * b.abs() || half == 0.0 {
        "not estimable (noise-free recording: no measurement noise in the residual)".to_string()
    } else if half <= 10.0 * b.abs() {
        format!("+-{:.2} %", 100.0 * half / b.abs())
    } else {
        // About a value of (almost) 0: in the key's unit.
        format!("+-{half:.3e}")
    }
}

/// `toml` with the comment after each fitted value replaced by where it came from: the start
/// file's comment described the start value (`# J_n (no load weight)` next to a fitted load
/// inertia misled).
fn fitted_comments(toml: &str, params: &[(String, f64, f64)], recording: &str) -> String {
    let Ok(mut doc) = toml.parse::<DocumentMut>() else {
        return toml.to_string();
    };
    for (key, start, _) in params {
        let mut it: &mut Item = doc.as_item_mut();
        for part in key.split('.') {
            it = &mut it[part];
        }
        if let Some(v) = it.as_value_mut() {
            v.decor_mut().set_suffix(format!(
                "   # fitted by host-sim identify plant to {recording} (start {start:e})"
            ));
        }
    }
    doc.to_string()
}

#[cfg(test)]
mod tests {

    #[test]
    fn a_parameters_scale_is_its_own_size_not_a_floor_of_one() {
        assert_eq!(param_scale(8e-9, 1e-12, 1e-6), 8e-9);
        assert_eq!(param_scale(-2.5, f64::NEG_INFINITY, 0.0), 2.5);
        // From 0: the range's size, else 1.
        assert_eq!(param_scale(0.0, 0.0, 1e-6), 1e-6);
        assert_eq!(param_scale(0.0, 0.0, f64::INFINITY), 1.0);
    }

    use super::*;

    #[test]
    fn a_zero_width_interval_is_called_not_estimable_not_plus_minus_zero() {
        assert!(interval_text(0.155, 0.155, 0.155).contains("not estimable"));
        assert!(interval_text(0.155 - 1e-9, 0.155 + 1e-9, 0.155).contains("not estimable"));
        assert_eq!(interval_text(0.15, 0.16, 0.155), "+-3.23 %");
        assert_eq!(
            interval_text(f64::NAN, f64::NAN, 0.155),
            "none (not determined)"
        );
    }

    #[test]
    fn a_fitted_value_loses_the_start_files_comment() {
        let toml =
            "[joint]\ninertia_kgm2 = 1.55e-1         # J_n (no load weight)\nr = 1.0 # kept\n";
        let out = fitted_comments(
            toml,
            &[("joint.inertia_kgm2".into(), 0.014, 0.155)],
            "rec.csv",
        );
        assert!(!out.contains("no load weight"), "{out}");
        assert!(
            out.contains("fitted by host-sim identify plant to rec.csv (start 1.4e-2)"),
            "{out}"
        );
        assert!(out.contains("r = 1.0 # kept"), "{out}");
        assert_eq!(
            out.parse::<toml::Table>().unwrap()["joint"]["inertia_kgm2"].as_float(),
            Some(0.155)
        );
    }

    #[test]
    fn the_summary_reports_a_start_of_zero_and_nothing_held_out_in_words() {
        let score = |c| ChannelScore {
            channel: c,
            before_pct: 90.0,
            after_pct: 99.0,
        };
        let fit = PlantFit {
            params: vec![
                ("joint.inertia_kgm2".into(), 0.014, 0.0154),
                ("initial.angle_rad".into(), 0.0, 0.002),
            ],
            at_bound: Vec::new(),
            ci95: Vec::new(),
            undetermined: Vec::new(),
            train: vec![score(Channel::AngleDeg)],
            holdout: Vec::new(),
            samples: (100, 0),
            termination: "converged".into(),
            evaluations: 3,
            cost: (1.0, 0.1),
            toml: String::new(),
        };
        let s = fit.summary();
        assert!(s.contains("10.00%"), "{s}");
        assert!(s.contains("+2.000e-3 (from 0)"), "{s}");
        assert!(!s.contains("NaN") && !s.contains("-0.000"), "{s}");
        assert!(s.contains("held-out tail: none held out"), "{s}");
    }

    #[test]
    fn only_a_value_the_fit_moved_onto_a_bound_is_warned_and_physical_limits_say_so() {
        let spec = |key: &str, lower, upper, user_bounds| ParamSpec {
            key: key.into(),
            lower,
            upper,
            user_bounds,
        };
        let specs = [
            spec("joint.inertia_kgm2", 0.001, 0.1, true),
            spec("valve.laminar_ratio", 0.0, 1.0, false),
            spec("valve.critical_ratio", 0.0, 1.0, false),
            spec("muscle.damping_m2s", 0.0, f64::INFINITY, false),
        ];
        // inertia pushed onto its given bound; the laminar ratio's true 0.999 is clear of 1;
        // the critical ratio already sat at the limit in the file; damping pushed to 0.
        let w: Vec<String> =
            at_bound_warnings(&specs, &[0.014, 0.99, 1.0, 2e-4], &[0.1, 0.999, 1.0, 1e-12])
                .into_iter()
                .flatten()
                .collect();
        assert_eq!(w.len(), 2, "{w:?}");
        assert!(
            w[0].contains("joint.inertia_kgm2 ended at its upper bound"),
            "{}",
            w[0]
        );
        assert!(
            w[1].contains("muscle.damping_m2s was pushed to its physical limit"),
            "{}",
            w[1]
        );
    }

    #[test]
    fn param_specs_parse_bounds_and_reject_bad_keys() {
        let text = "[a]\nx = 2.0 # c\ny = -1\nz = \"s\"\n";
        let s = parse_param_specs(&["a.x".into(), "a.y=-5:".into()], text, "p.toml").unwrap();
        assert_eq!(s[0].lower, 0.0);
        assert_eq!(s[0].upper, f64::INFINITY);
        assert_eq!(s[1].lower, -5.0);
        assert_eq!(s[1].upper, f64::INFINITY);
        let e = parse_param_specs(&["a.q".into()], text, "p.toml").unwrap_err();
        assert!(
            e.to_string().contains("p.toml") && e.to_string().contains("a.q"),
            "{e}"
        );
        let e = parse_param_specs(&["a.z".into()], text, "p.toml").unwrap_err();
        assert!(e.to_string().contains("not a number"), "{e}");
        let e = parse_param_specs(&["a.x=3:4".into()], text, "p.toml").unwrap_err();
        assert!(e.to_string().contains("inside the bounds"), "{e}");
    }

    #[test]
    fn set_number_keeps_the_comment() {
        let mut doc: DocumentMut = "[a]\nx = 2.0   # the x\n".parse().unwrap();
        set_number(&mut doc, "a.x", 3.5);
        let s = doc.to_string();
        assert!(s.contains("x = 3.5e0   # the x"), "{s}");
        set_number(&mut doc, "a.x", 6.5e-9);
        assert!(doc.to_string().contains("x = 6.5e-9   # the x"));
        assert_eq!(get_number(&doc, "a.x", "p.toml").unwrap(), 6.5e-9);
    }
}

#[cfg(test)]
mod split_tests {
    use super::*;

    #[test]
    fn the_training_head_needs_20_samples_and_10_a_parameter_and_a_judgeable_tail() {
        assert_eq!(training_samples(1000, 3, 0.25).unwrap(), 750);
        assert_eq!(training_samples(100, 2, 0.0).unwrap(), 100);
        // 3 parameters need 30 training samples.
        assert!(training_samples(35, 3, 0.2).is_err());
        // A tail of 10 samples is too few to judge a fit by.
        let err = training_samples(100, 1, 0.1).unwrap_err();
        assert!(err.to_string().contains("10 held out"), "{err}");
        assert!(training_samples(1000, 1, 1.0).is_err());
        assert!(training_samples(1000, 1, f64::NAN).is_err());
    }
}
