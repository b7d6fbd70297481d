//! Discovery: find the missing term in closed form when the catalogue of known effects does
//! not explain a recording (`host-sim discover`; the diagnosis calls [`discover`] after a
//! verdict `unexplained`).
//!
//! Stages, each on the nominal plant's replay of TRAIN:
//! 1. **equation residuals per slot** ([`library::design`]): the joint's torque balance
//!    (J alpha - r (F1 - F2) from the measured angle's Savitzky-Golay derivatives), the
//!    transmission (the same residual against lever terms), each chamber's pressure equation
//!    (measured minus nominal dp/dt at the measured state), each sensor's map (measured minus
//!    the nominal replay);
//! 2. **sparse regression** ([`sparse::stlsq`]): STLSQ on unit-RMS columns of the slot's
//!    library ([`crate::plant::effects::discovered::Slot::library`]) over a grid of
//!    thresholds, at most [`DiscoverOptions::max_terms`] terms;
//! 3. **output error**: every sparse model is replayed in the full simulation (the plant
//!    with `[effects.discovered]`) and scored on the held-out tail of TRAIN; the best
//!    [`DiscoverOptions::refine_top`] are refined by Levenberg-Marquardt on the head of TRAIN
//!    (the diagnosis's output-error fitter, [`crate::diagnose::fitting::Problem`]), with 95 %
//!    intervals;
//! 4. **held-out check**: the best refined term is kept only when it removes at least
//!    [`DiscoverOptions::min_explained`] of TRAIN tail's error beyond noise AND of CHECK's
//!    (and loses no CHECK channel more than [`DiscoverOptions::max_check_loss_pct`] points),
//!    and when no catalogue effect or recalibration does nearly as well
//!    ([`DiscoverOptions::catalogue_share`]: then the answer is the diagnosis's, not a new
//!    term). Otherwise nothing is discovered.

pub mod candidate;
pub mod library;
pub mod sparse;

use std::collections::BTreeMap;

use crate::fit::fit_percent;
use crate::io::recording::{Channel, Recording};
use crate::plant::config::PlantConfig;
use crate::plant::effects::candidate::{Candidate, Evidence, Scatter};
use crate::plant::effects::discovered::{Discovered, Slot};
use crate::plant::Measurement;
use crate::sim::SolverOptions;

use super::differentiate::{noise_level, SavitzkyGolay};
use super::fitting::{par_map, Part, Problem};
use super::DiagnoseError;
use candidate::TermsCandidate;

/// Tuning of the discovery.
#[derive(Debug, Clone)]
pub struct DiscoverOptions {
    /// Share of TRAIN (its head) the terms are fitted on; the rest scores them.
    pub fit_fraction: f64,
    /// Most terms in a discovered sum.
    pub max_terms: usize,
    /// Sparse models per slot replayed in the full simulation (best equation-error R^2).
    pub per_slot: usize,
    /// Models refined by output error (best replayed tail cost).
    pub refine_top: usize,
    /// Levenberg-Marquardt iterations per refinement (about).
    pub max_iter: usize,
    /// A term must remove this share of the held-out error beyond noise, on TRAIN's tail and
    /// on CHECK.
    pub min_explained: f64,
    /// ... and lose no CHECK channel more than this many points of fit.
    pub max_check_loss_pct: f64,
    /// TRAIN counts as explained by the nominal model when its tail cost is below this many
    /// times the noise's (nothing to discover).
    pub null_ratio: f64,
    /// Compare with the catalogue (effects and recalibrations) first: when its best refit
    /// reaches this share of the discovered term's gain on TRAIN's tail, nothing is
    /// discovered (the diagnosis names it). `None`: no comparison (the diagnosis already
    /// found the catalogue wanting).
    pub catalogue_share: Option<f64>,
    /// Catalogue candidates refitted (best screening score).
    pub catalogue_top: usize,
    pub threads: usize,
    pub solver: SolverOptions,
}

impl Default for DiscoverOptions {
    fn default() -> Self {
        Self {
            fit_fraction: 0.7,
            max_terms: 2,
            per_slot: 4,
            refine_top: 4,
            max_iter: 10,
            min_explained: 0.3,
            max_check_loss_pct: 2.0,
            null_ratio: 1.5,
            catalogue_share: Some(0.8),
            catalogue_top: 4,
            threads: 2,
            solver: super::DiagnoseOptions::default().solver,
        }
    }
}

/// One model tried.
#[derive(Debug, Clone)]
pub struct Tried {
    pub slot: Slot,
    /// The formula with its coefficients (equation error, then refined when it was).
    pub formula: String,
    /// Equation-error R^2 on the head of TRAIN.
    pub r2: f64,
    /// Tail-of-TRAIN cost (sum over channels of mean squared error / spread^2) with the
    /// equation-error coefficients, and after the output-error refinement.
    pub tail_cost: f64,
    pub refined_tail_cost: Option<f64>,
}

/// A refined model: its index, coefficients, their 95 % intervals and its tail cost.
type Refined = (usize, Vec<f64>, Vec<[f64; 2]>, f64);

/// A discovered term with its statistics.
#[derive(Debug, Clone)]
pub struct Found {
    pub table: Discovered,
    /// 95 % interval of each coefficient (output-error Jacobian at the fit, s^2 (J^T J)^-1:
    /// optimistic, since output errors are correlated in time).
    pub ci95: Vec<[f64; 2]>,
    /// The nominal plant with the term (what `--write-plant` writes).
    pub corrected: PlantConfig,
}

/// What the discovery found.
#[derive(Debug, Clone)]
pub struct Discovery {
    /// The term kept, or `None`: nothing discovered (the honest answer).
    pub found: Option<Found>,
    /// The best term tried (kept or not), with its coefficients and intervals.
    pub best: Option<Found>,
    /// Why the answer is what it is.
    pub reason: String,
    /// Per-channel fits (%) on TRAIN's tail and on CHECK: nominal, and with the best term.
    pub heldout_before: BTreeMap<&'static str, f64>,
    pub heldout_after: BTreeMap<&'static str, f64>,
    pub check_before: Option<BTreeMap<&'static str, f64>>,
    pub check_after: Option<BTreeMap<&'static str, f64>>,
    /// Share of the error beyond noise the best term removes on TRAIN's tail and on CHECK.
    pub heldout_explained: f64,
    pub check_explained: Option<f64>,
    /// The best catalogue refit (id, share of the best term's tail gain it reaches).
    pub catalogue_best: Option<(String, f64)>,
    pub tried: Vec<Tried>,
    /// The best term's slot residual on TRAIN's head against the term's argument, with the
    /// term as its curve (the report's plot).
    pub scatter: Option<Scatter>,
    pub seconds: f64,
}

/// The plant file `plant_text` (read from `plant_path`) with the discovered term appended as
/// its `[effects.discovered]` table, under a comment naming the command and the recording it
/// was found on; checked to read back as a plant file. An error when the file already has
/// such a table (a plant holds one).
pub fn plant_text_with(
    plant_text: &str,
    plant_path: &std::path::Path,
    found_by: &str,
    table: &Discovered,
) -> Result<String, String> {
    has_no_discovered_table(plant_text, plant_path)?;
    let text = format!(
        "{}\n# Found by {found_by}: {}\n{}",
        plant_text.trim_end(),
        table.formula(),
        table.to_toml()
    );
    PlantConfig::from_toml_str(&text, plant_path).map_err(|e| e.to_string())?;
    Ok(text)
}

/// Refuses plant text that already has an `[effects.discovered]` table (a plant holds one):
/// checked before a run that is to write one into it.
pub fn has_no_discovered_table(
    plant_text: &str,
    plant_path: &std::path::Path,
) -> Result<(), String> {
    if plant_text.contains("[effects.discovered]") {
        return Err(format!(
            "{} already has an [effects.discovered] table; remove it (or run against the file \
             without it) so that the written file has one",
            plant_path.display()
        ));
    }
    Ok(())
}

/// The sum of a table's terms as a formula ([`Discovered::formula`]).
pub fn formula(t: &Discovered) -> String {
    t.formula()
}

/// Per-channel fit (%) of `pred` against the recording over `range`.
fn fits(
    rec: &Recording,
    pred: &[Measurement],
    range: std::ops::Range<usize>,
) -> BTreeMap<&'static str, f64> {
    let mut out = BTreeMap::new();
    for c in Channel::ALL {
        if let Some(y) = rec.channel(c) {
            let yh: Vec<f64> = range.clone().map(|k| c.of(&pred[k])).collect();
            out.insert(c.name(), fit_percent(&y[range.clone()], &yh));
        }
    }
    out
}

/// Standard deviation of `y`.
fn spread_of(y: &[f64]) -> f64 {
    let n = y.len().max(1) as f64;
    let mean = y.iter().sum::<f64>() / n;
    (y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt()
}

/// Per-channel spread and noise cost of a recording.
fn scales(rec: &Recording) -> ([f64; 5], f64) {
    let n = rec.len();
    let mut spread = [1.0; 5];
    let mut noise_cost = 0.0;
    for c in Channel::ALL {
        if let Some(y) = rec.channel(c) {
            let mean = y.iter().sum::<f64>() / n as f64;
            let sd = (y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n as f64).sqrt();
            let sd = if sd > 0.0 { sd } else { 1.0 };
            spread[c.index()] = sd;
            // Noise-free data: 0.2 % of the spread (the diagnosis's floor).
            let noise = noise_level(y).max(2e-3 * sd);
            noise_cost += (noise / sd).powi(2);
        }
    }
    (spread, noise_cost)
}

/// Runs the discovery on `train` (and `check`, a recording of the same rig with another
/// excitation) against the `nominal` plant. Errors: the recording is too short, or the
/// nominal plant cannot replay it.
pub fn discover(
    nominal: &PlantConfig,
    train: &Recording,
    check: Option<&Recording>,
    opts: &DiscoverOptions,
) -> Result<Discovery, DiagnoseError> {
    let t0 = std::time::Instant::now();
    let uniform =
        |r: &Recording| -> Option<Recording> { (!r.is_uniform()).then(|| r.to_uniform()) };
    let (train_u, check_u) = (uniform(train), check.and_then(uniform));
    let train = train_u.as_ref().unwrap_or(train);
    let check = check_u.as_ref().or(check);
    let n = train.len();
    if n < super::MIN_SAMPLES {
        return Err(DiagnoseError::Data(format!(
            "the recording has {n} samples; discovery needs at least {}",
            super::MIN_SAMPLES
        )));
    }
    let n_fit = ((n as f64 * opts.fit_fraction).round() as usize).clamp(n / 4, n - n / 10);
    let tail = n_fit..n;
    let (spread, noise_cost) = scales(train);
    let problem = Problem::new(nominal, train, spread, opts.solver)?;
    let nominal_pred = problem
        .predict(&[])
        .ok_or_else(|| DiagnoseError::Data("the nominal replay failed".into()))?;
    let nom_tail: f64 = problem
        .channel_costs(&nominal_pred, tail.clone())
        .iter()
        .sum();
    let heldout_before = fits(train, &nominal_pred, tail.clone());
    // CHECK: its own problem (its spread, its noise).
    let check_problem = check_problem_of(nominal, check, opts)?;
    let check_before = check_problem
        .as_ref()
        .map(|(p, pred, _)| fits(p.recording, pred, 0..p.recording.len()));
    let mut d = Discovery::before(heldout_before, check_before);
    let check_departs = check_problem.as_ref().is_some_and(|(p, pred, nc)| {
        let c: f64 = p.channel_costs(pred, 0..p.recording.len()).iter().sum();
        c > opts.null_ratio * nc
    });
    if nom_tail <= opts.null_ratio * noise_cost && !check_departs {
        d.reason = format!(
            "nothing to discover: the nominal model fits TRAIN's tail within its noise (cost \
             {nom_tail:.3e}, noise {noise_cost:.3e})"
        );
        d.seconds = t0.elapsed().as_secs_f64();
        return Ok(d);
    }
    // Channels that are noise (the noise level of each at half its spread or more: pure
    // noise, a dead rig) carry no equation to complete: a term fitted to them would only
    // flatten the replay.
    let noisy = noisy_channels(train, tail.clone());
    if noisy.len() == problem.setup.present.iter().filter(|p| **p).count() {
        d.reason = format!(
            "nothing discovered: every channel is noise ({}); the recording does not look like \
             this plant (run `host-sim diagnose` for the likely cause)",
            noisy.join(", ")
        );
        d.seconds = t0.elapsed().as_secs_f64();
        return Ok(d);
    }
    // 1-2. Equation residuals and sparse models per slot.
    let ev = Evidence::build(nominal, train, &nominal_pred, &SavitzkyGolay::default());
    let mut models = Vec::new();
    for slot in Slot::ALL {
        models.extend(
            library::slot_models(&ev, slot, 0..n_fit, opts.max_terms)
                .into_iter()
                .filter(|m| m.r2 >= 0.01)
                .take(opts.per_slot),
        );
    }
    let cands: Vec<TermsCandidate> = models
        .iter()
        .map(|m| TermsCandidate {
            slot: m.slot,
            terms: m.terms.clone(),
            start: m.coefficients.clone(),
        })
        .collect();
    // 3. Output error: replay each, then refine the best.
    let tail_costs: Vec<f64> = par_map(&cands, opts.threads, |c| {
        let parts = [Part {
            candidate: c as &dyn Candidate,
            params: c.start.clone(),
        }];
        problem.cost(&parts, tail.clone())
    });
    d.tried = tried_rows(&models, &cands, &tail_costs);
    let refined = refine_best(&problem, &cands, &tail_costs, n_fit, tail.clone(), opts);
    for (i, p, _, cost) in &refined {
        d.tried[*i].refined_tail_cost = Some(*cost);
        d.tried[*i].formula = formula(&cands[*i].table(p));
    }
    let Some((bi, bp, bci, best_tail)) = refined.iter().min_by(|a, b| a.3.total_cmp(&b.3)).cloned()
    else {
        d.reason =
            "nothing discovered: no library term explains any slot's equation residual".into();
        d.seconds = t0.elapsed().as_secs_f64();
        return Ok(d);
    };
    let best_cand = &cands[bi];
    let table = best_cand.table(&bp);
    let mut corrected = nominal.clone();
    corrected.effects.discovered = Some(table.clone());
    d.scatter = library::residual_scatter(&ev, &table, 0..n_fit);
    let best = Found {
        table,
        ci95: bci,
        corrected: corrected.clone(),
    };
    let parts = [Part {
        candidate: best_cand as &dyn Candidate,
        params: bp.clone(),
    }];
    if let Some(pred) = problem.predict(&parts) {
        d.heldout_after = fits(train, &pred, tail.clone());
    }
    d.heldout_explained = share_beyond_noise(nom_tail, best_tail, noise_cost);
    // 4. The held-out check (a tail within its noise already: the term must still lower it).
    let mut why_not: Vec<String> = Vec::new();
    let explains_enough = d.heldout_explained.is_nan() || d.heldout_explained >= opts.min_explained;
    if !(explains_enough && best_tail < 0.98 * nom_tail) {
        why_not.push(format!(
            "{} of TRAIN tail's error beyond noise (needs {:.0} %)",
            removes_text(d.heldout_explained),
            100.0 * opts.min_explained
        ));
    }
    if let Some(cp) = &check_problem {
        check_holds(cp, &parts, &mut d, opts, &mut why_not);
    }
    // The catalogue first: a known effect or a recalibration that does nearly as well is
    // the diagnosis's answer, not a new term.
    if why_not.is_empty() {
        let costs = (nom_tail, best_tail, noise_cost);
        why_not.extend(catalogue_objection(
            nominal, &problem, &ev, n_fit, costs, &mut d, opts,
        ));
    }
    conclude(&mut d, &best, &why_not);
    d.best = Some(best);
    d.seconds = t0.elapsed().as_secs_f64();
    Ok(d)
}

/// CHECK's own problem (its spread), its nominal replay and its noise cost.
#[allow(clippy::type_complexity)]
fn check_problem_of<'a>(
    nominal: &'a PlantConfig,
    check: Option<&'a Recording>,
    opts: &DiscoverOptions,
) -> Result<Option<(Problem<'a>, Vec<Measurement>, f64)>, DiagnoseError> {
    Ok(match check {
        Some(c) => {
            let (sc, nc) = scales(c);
            let p = Problem::new(nominal, c, sc, opts.solver)?;
            let pred = p
                .predict(&[])
                .ok_or_else(|| DiagnoseError::Data("the nominal replay of CHECK failed".into()))?;
            Some((p, pred, nc))
        }
        None => None,
    })
}

/// The channels of `train` whose noise level over `tail` is half their spread or more
/// ("p1_kpa noise 0.512 of spread 0.9").
fn noisy_channels(train: &Recording, tail: std::ops::Range<usize>) -> Vec<String> {
    Channel::ALL
        .iter()
        .filter_map(|c| {
            let y = &train.channel(*c)?[tail.clone()];
            let sd = spread_of(y);
            Some((c.name(), noise_level(y), sd))
        })
        .filter(|(_, nl, sd)| *nl >= 0.5 * sd)
        .map(|(k, nl, sd)| format!("{k} noise {nl:.3} of spread {sd:.3}"))
        .collect()
}

/// The held-out check on CHECK: the term `parts` must remove
/// [`DiscoverOptions::min_explained`] of CHECK's error beyond noise and cost no channel more
/// than [`DiscoverOptions::max_check_loss_pct`]; `d` gets CHECK's fits, `why_not` the reasons.
fn check_holds(
    cp: &(Problem, Vec<Measurement>, f64),
    parts: &[Part],
    d: &mut Discovery,
    opts: &DiscoverOptions,
    why_not: &mut Vec<String>,
) {
    let (p, pred0, nc) = (&cp.0, &cp.1, &cp.2);
    let m = p.recording.len();
    let c0: f64 = p.channel_costs(pred0, 0..m).iter().sum();
    match p.predict(parts) {
        Some(pred) => {
            let c1: f64 = p.channel_costs(&pred, 0..m).iter().sum();
            let ex = share_beyond_noise(c0, c1, *nc);
            d.check_explained = Some(ex);
            let after = fits(p.recording, &pred, 0..m);
            let before = d.check_before.clone().unwrap_or_default();
            let lost: Vec<String> = before
                .iter()
                .filter(|(k, b)| {
                    after
                        .get(*k)
                        .is_some_and(|a| *a < **b - opts.max_check_loss_pct)
                })
                .map(|(k, b)| format!("{k} {b:.1} % -> {:.1} %", after[k]))
                .collect();
            d.check_after = Some(after);
            if !((ex.is_nan() || ex >= opts.min_explained) && c1 < 0.98 * c0) {
                why_not.push(format!(
                    "on CHECK {} of the error beyond noise (needs {:.0} %)",
                    removes_text(ex),
                    100.0 * opts.min_explained
                ));
            }
            if !lost.is_empty() {
                why_not.push(format!("it makes CHECK worse: {}", lost.join(", ")));
            }
        }
        None => why_not.push("the plant with the term cannot replay CHECK".into()),
    }
}

/// The [`DiscoverOptions::refine_top`] candidates best on TRAIN's tail (`tail_costs`)
/// refined by output error on `0..n_fit`: (index, coefficients, 95 % intervals, tail cost);
/// a refinement that does not help the tail keeps the equation-error coefficients.
fn refine_best(
    problem: &Problem,
    cands: &[TermsCandidate],
    tail_costs: &[f64],
    n_fit: usize,
    tail: std::ops::Range<usize>,
    opts: &DiscoverOptions,
) -> Vec<Refined> {
    let mut order: Vec<usize> = (0..cands.len())
        .filter(|&i| tail_costs[i].is_finite())
        .collect();
    order.sort_by(|&a, &b| tail_costs[a].total_cmp(&tail_costs[b]));
    order.truncate(opts.refine_top);
    par_map(&order, opts.threads, |&i| {
        let c = &cands[i];
        let parts = [Part {
            candidate: c as &dyn Candidate,
            params: c.start.clone(),
        }];
        let (fitted, _, ci) = problem.fit_with_ci(&parts, 0..n_fit, opts.max_iter, true);
        let cost = problem.cost(&fitted, tail.clone());
        // Keep the equation-error coefficients when the refinement did not help the tail.
        if cost <= tail_costs[i] {
            (i, fitted[0].params.clone(), ci[0].clone(), cost)
        } else {
            (
                i,
                c.start.clone(),
                vec![[f64::NAN; 2]; c.start.len()],
                tail_costs[i],
            )
        }
    })
}

/// Why a term is not kept when the catalogue's best refit does nearly as well on TRAIN's
/// tail (`costs`: the nominal model's, the term's and the noise's tail cost); `d` gets the
/// catalogue's best. `None` when the term beats it or the comparison is off.
fn catalogue_objection(
    nominal: &PlantConfig,
    problem: &Problem,
    ev: &Evidence,
    n_fit: usize,
    costs: (f64, f64, f64),
    d: &mut Discovery,
    opts: &DiscoverOptions,
) -> Option<String> {
    let (nom_tail, best_tail, noise_cost) = costs;
    let share = opts.catalogue_share?;
    if let Some((id, reach)) =
        catalogue_reach(nominal, problem, ev, n_fit, nom_tail, best_tail, opts)
    {
        d.catalogue_best = Some((id.clone(), reach));
        // The term must remove a share of what the catalogue's best leaves beyond noise,
        // as a catalogue effect must of the nominal model's.
        let cat_tail = nom_tail - reach * (nom_tail - best_tail);
        let beats = ((cat_tail - best_tail) / (cat_tail - noise_cost).max(1e-300)).clamp(-1.0, 1.0);
        if reach >= share && beats < opts.min_explained {
            return Some(format!(
                "the catalogue's `{id}` does {:.0} % as well on TRAIN's tail (the term removes \
                 only {:.0} % of what it leaves): run `host-sim diagnose`, which names it",
                100.0 * reach,
                100.0 * beats
            ));
        }
    }
    None
}

/// The share of the error beyond noise that a cost `after` removes from `before` (noise
/// cost `noise`); NaN when `before` is within the noise already (no share to take).
fn share_beyond_noise(before: f64, after: f64, noise: f64) -> f64 {
    let excess = before - noise;
    if excess > 1e-9 * before.abs() {
        (before - after) / excess
    } else {
        f64::NAN
    }
}

/// "it removes 42 %" of a share of [`share_beyond_noise`], or what a NaN share means.
fn removes_text(share: f64) -> String {
    if share.is_nan() {
        "it leaves no error beyond noise to remove (within its noise already)".into()
    } else {
        format!("it removes {:.0} %", 100.0 * share)
    }
}

/// The discovery's reason, and its term when `why_not` is empty.
fn conclude(d: &mut Discovery, best: &Found, why_not: &[String]) {
    let f = formula(&best.table);
    if why_not.is_empty() {
        d.reason = format!(
            "discovered in {}: {f}; {} of TRAIN tail's error beyond noise{}",
            best.table.slot.equation(),
            removes_text(d.heldout_explained),
            d.check_explained
                .map(|e| format!("; on CHECK {}", removes_text(e)))
                .unwrap_or_default()
        );
        d.found = Some(best.clone());
    } else {
        d.reason = format!(
            "nothing discovered: the best term tried ({f}) was not kept: {}",
            why_not.join("; ")
        );
    }
}

/// A row per tried candidate: its slot, formula, equation-error R² and tail cost.
fn tried_rows(
    models: &[library::SlotModel],
    cands: &[TermsCandidate],
    tail_costs: &[f64],
) -> Vec<Tried> {
    models
        .iter()
        .zip(cands)
        .zip(tail_costs)
        .map(|((m, c), tc)| Tried {
            slot: m.slot,
            formula: formula(&c.table(&c.start)),
            r2: m.r2,
            tail_cost: *tc,
            refined_tail_cost: None,
        })
        .collect()
}

impl Discovery {
    /// Nothing found yet: the fits before (and after) are the nominal model's.
    fn before(
        heldout_before: BTreeMap<&'static str, f64>,
        check_before: Option<BTreeMap<&'static str, f64>>,
    ) -> Self {
        Discovery {
            found: None,
            best: None,
            reason: String::new(),
            heldout_before: heldout_before.clone(),
            heldout_after: heldout_before,
            check_before: check_before.clone(),
            check_after: check_before,
            heldout_explained: 0.0,
            check_explained: None,
            catalogue_best: None,
            tried: Vec::new(),
            scatter: None,
            seconds: 0.0,
        }
    }
}

/// The hook for the diagnosis: after `diagnosis` answered TRAIN (and CHECK), run the
/// discovery when the catalogue did not explain the recording: verdict `unexplained` (on the
/// nominal plant) or `partly_explained` (on the plant its named items corrected, for what
/// they leave), with no second comparison with the catalogue (the diagnosis made it). `None`
/// for the other verdicts: nothing is missing, the answer is complete, or the recording is
/// not of this plant.
pub fn after_diagnosis(
    nominal: &PlantConfig,
    train: &Recording,
    check: Option<&Recording>,
    diagnosis: &super::Diagnosis,
    opts: &DiscoverOptions,
) -> Option<Result<Discovery, DiagnoseError>> {
    let opts = DiscoverOptions {
        catalogue_share: None,
        ..opts.clone()
    };
    match diagnosis.verdict {
        // After the stand-in check, its discovery on the nominal plant is the answer.
        super::Verdict::Unexplained => Some(match &diagnosis.stand_in_discovery {
            Some(x) => Ok(x.clone()),
            None => discover(nominal, train, check, &opts),
        }),
        // What the named items leave: discovered on the plant they corrected.
        super::Verdict::PartlyExplained => {
            Some(discover(&diagnosis.corrected, train, check, &opts))
        }
        _ => None,
    }
}

/// The best catalogue refit (effects and recalibrations, the diagnosis's candidate pool, top
/// [`DiscoverOptions::catalogue_top`] by screening score, fitted alone on the head): its id
/// and the share of the discovered term's tail gain it reaches.
fn catalogue_reach(
    nominal: &PlantConfig,
    problem: &Problem,
    ev: &Evidence,
    n_fit: usize,
    nom_tail: f64,
    best_tail: f64,
    opts: &DiscoverOptions,
) -> Option<(String, f64)> {
    let pool = super::selection::candidate_pool(nominal);
    let mut screened: Vec<(usize, f64, Vec<f64>)> = pool
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let s = c.screen(ev, &problem.setup);
            (i, s.score, s.initial)
        })
        .filter(|(_, s, _)| s.is_finite())
        .collect();
    screened.sort_by(|a, b| b.1.total_cmp(&a.1));
    screened.truncate(opts.catalogue_top);
    let n = problem.inputs.len();
    let costs: Vec<(usize, f64)> = par_map(&screened, opts.threads, |(i, _, init)| {
        let parts = [Part {
            candidate: pool[*i].as_ref(),
            params: init.clone(),
        }];
        let (fitted, _) = problem.fit(&parts, 0..n_fit, opts.max_iter);
        (*i, problem.cost(&fitted, n_fit..n))
    });
    let (i, c) = costs.into_iter().min_by(|a, b| a.1.total_cmp(&b.1))?;
    let gain = (nom_tail - best_tail).max(1e-300);
    Some((pool[i].id().to_string(), (nom_tail - c) / gain))
}

fn ci95_json(ci: &[f64; 2]) -> serde_json::Value {
    let v = |x: f64| {
        if x.is_finite() {
            serde_json::json!(x)
        } else {
            serde_json::Value::Null
        }
    };
    serde_json::json!([v(ci[0]), v(ci[1])])
}

fn fits_json(m: &BTreeMap<&'static str, f64>) -> serde_json::Value {
    serde_json::Value::Object(
        m.iter()
            .map(|(k, v)| {
                (
                    k.to_string(),
                    serde_json::json!((v * 100.0).round() / 100.0),
                )
            })
            .collect(),
    )
}

/// The departing channel: the one the nominal model fits worst on CHECK (else on TRAIN's
/// tail), with its fit before and after.
pub fn departing(
    before: &BTreeMap<&'static str, f64>,
    after: &BTreeMap<&'static str, f64>,
) -> Option<(&'static str, f64, f64)> {
    before
        .iter()
        .min_by(|a, b| a.1.total_cmp(b.1))
        .map(|(k, b)| (*k, *b, after.get(k).copied().unwrap_or(*b)))
}

impl Discovery {
    /// The channel the nominal model fits worst on CHECK (else on TRAIN's tail), its fit
    /// before and with the best term.
    pub fn departing(&self) -> Option<(&'static str, f64, f64)> {
        match (&self.check_before, &self.check_after) {
            (Some(b), Some(a)) => departing(b, a),
            _ => departing(&self.heldout_before, &self.heldout_after),
        }
    }

    /// The JSON: `{"discovered": {...} | null, "best_attempt": {...}, "reason", fits, ...}`.
    pub fn to_json(&self) -> serde_json::Value {
        let term_json = |f: &Found| {
            let t = &f.table;
            serde_json::json!({
                "slot": t.slot.name(),
                "equation": t.slot.equation(),
                "formula": formula(t),
                "terms": t.terms.iter().zip(&t.coefficients).zip(&f.ci95).map(|((term, c), ci)| {
                    serde_json::json!({
                        "symbol": term.symbol(),
                        "meaning": term.sentence(),
                        "term_unit": term.unit(t.slot),
                        "coefficient": c,
                        "coefficient_unit": format!("{}/({})", t.slot.unit(), term.unit(t.slot)),
                        "ci95": ci95_json(ci),
                    })
                }).collect::<Vec<_>>(),
                "toml": t.to_toml(),
            })
        };
        let dep = self.departing();
        serde_json::json!({
            "discovered": self.found.as_ref().map(term_json),
            "best_attempt": self.best.as_ref().map(term_json),
            "reason": self.reason,
            "heldout_fit": {"before": fits_json(&self.heldout_before), "after": fits_json(&self.heldout_after)},
            "check_fit": self.check_before.as_ref().map(|b| serde_json::json!({
                "before": fits_json(b),
                "after": fits_json(self.check_after.as_ref().unwrap_or(b)),
            })),
            "heldout_explained": self.heldout_explained,
            "check_explained": self.check_explained,
            "departing_channel": dep.map(|(c, b, a)| serde_json::json!({"channel": c, "before": b, "after": a})),
            "catalogue_best": self.catalogue_best.as_ref().map(|(id, r)| serde_json::json!({"id": id, "share_of_gain": r})),
            "tried": self.tried.iter().map(|t| serde_json::json!({
                "slot": t.slot.name(),
                "formula": t.formula,
                "equation_r2": t.r2,
                "tail_cost": t.tail_cost,
                "refined_tail_cost": t.refined_tail_cost,
            })).collect::<Vec<_>>(),
            "seconds": self.seconds,
        })
    }

    /// The answer in words.
    pub fn text(&self) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        let _ = writeln!(s, "{}", capitalise(&self.reason));
        if let Some(f) = self.found.as_ref().or(self.best.as_ref()) {
            let t = &f.table;
            let head = if self.found.is_some() {
                "Term"
            } else {
                "Best attempt (not kept)"
            };
            let _ = writeln!(
                s,
                "{head}, slot `{}` ({}):",
                t.slot.name(),
                t.slot.equation()
            );
            for ((term, c), ci) in t.terms.iter().zip(&t.coefficients).zip(&f.ci95) {
                let interval = if ci.iter().all(|v| v.is_finite()) {
                    format!("95 % [{:.4e}, {:.4e}]", ci[0], ci[1])
                } else {
                    "95 % interval undetermined by the recording".into()
                };
                let _ = writeln!(
                    s,
                    "  {} += {c:+.4e} {}/({}) * {}   {interval}: {}",
                    t.slot.lhs(),
                    t.slot.unit(),
                    term.unit(t.slot),
                    term.symbol(),
                    term.sentence()
                );
            }
        }
        let row = |name: &str, b: &BTreeMap<&'static str, f64>, a: &BTreeMap<&'static str, f64>| {
            let cells: Vec<String> = b
                .iter()
                .map(|(k, v)| format!("{k} {v:.1} % -> {:.1} %", a.get(k).copied().unwrap_or(*v)))
                .collect();
            format!("  {name}: {}\n", cells.join(", "))
        };
        s.push_str("Fit before -> after:\n");
        s.push_str(&row(
            "TRAIN tail",
            &self.heldout_before,
            &self.heldout_after,
        ));
        if let (Some(b), Some(a)) = (&self.check_before, &self.check_after) {
            s.push_str(&row("CHECK", b, a));
        }
        s
    }
}

fn capitalise(s: &str) -> String {
    let mut c = s.chars();
    match c.next() {
        Some(f) => f.to_uppercase().collect::<String>() + c.as_str(),
        None => String::new(),
    }
}
