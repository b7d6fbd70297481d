//! The candidates and selection stages.
//!
//! Candidates: the effect catalogue (with the parameter bounds narrowed to physics,
//! [`super::recalibrate::Bounded`]; the catalogue's inertia candidate is replaced by the
//! recalibration of `joint.inertia_kgm2`) and the recalibration of the plant file's own keys.
//!
//! Selection: every candidate is refitted by output error on the head of TRAIN and scored on
//! its held-out tail; forward selection adds the best accepted candidate while it helps, then
//! a swap pass tries the sets the greedy path skipped. Every step (forward and swap) is
//! judged by ONE rule, [`Rule::judge`]: a trial set is accepted over the current one when it
//! removes at least `min_explained` of the held-out error beyond noise, lowers the held-out
//! cost by 2 % and by `min_gain_noise` times the noise's cost, and improves the BIC-like
//! score (held-out log cost plus ln N per parameter); nothing is added to a set that
//! already explains the data within its noise, and a last backward pass drops any part the
//! rest does without (the same rule, the other way round). Among accepted trials the lowest
//! held-out cost wins, unless a simpler one (fewer named effects: a recalibration counts as
//! none) is not beaten by it under the same rule.

use std::collections::BTreeMap;

use super::candidates::{catalogue, Candidate, Screening};
use super::fitting::{par_map, Part, Problem};
use super::recalibrate::{self, is_recal_id, Bounded};
use super::{CandidateScore, DiagnoseOptions};
use crate::plant::config::PlantConfig;

/// The candidate pool: bounded catalogue effects, then recalibrations.
pub fn candidate_pool(nominal: &PlantConfig) -> Vec<Box<dyn Candidate>> {
    let mut v: Vec<Box<dyn Candidate>> = catalogue()
        .into_iter()
        .filter(|c| c.id() != "inertia")
        .map(|c| Box::new(Bounded(c)) as Box<dyn Candidate>)
        .collect();
    v.extend(recalibrate::candidates(nominal));
    v
}

/// The one acceptance rule.
#[derive(Debug, Clone, Copy)]
pub struct Rule {
    pub min_explained: f64,
    pub min_gain_noise: f64,
    /// Cost of the noise alone (with the floor of the verdict stage).
    pub noise_cost: f64,
    /// Held-out samples.
    pub n_heldout: f64,
    /// A set whose held-out cost is at or below this explains the data within its noise:
    /// nothing is added to it (`null_ratio` times the noise cost, the verdict's own bar).
    pub explained_cost: f64,
}

/// How a trial set compares with the current one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Judgement {
    /// Share of the current held-out excess over noise removed (clamped to [-1, 1]).
    pub explained: f64,
    pub bic_delta: f64,
    pub accepted: bool,
}

impl Rule {
    pub fn bic(&self, j: f64, k: usize) -> f64 {
        self.n_heldout * (j / self.noise_cost.max(1e-300)).ln() + k as f64 * self.n_heldout.ln()
    }

    /// Judges a trial of held-out cost `jh` with `k_new` parameters against the current set
    /// (held-out cost `j_cur`, `k_cur` parameters).
    pub fn judge(&self, j_cur: f64, k_cur: usize, jh: f64, k_new: usize) -> Judgement {
        let excess = (j_cur - self.noise_cost).max(1e-12);
        let explained = ((j_cur - jh) / excess).clamp(-1.0, 1.0);
        let bic_delta = self.bic(jh, k_new) - self.bic(j_cur, k_cur);
        let accepted = jh.is_finite()
            && j_cur > self.explained_cost
            && explained >= self.min_explained
            && jh < j_cur * 0.98
            && j_cur - jh >= self.min_gain_noise * self.noise_cost
            && bic_delta < 0.0;
        Judgement {
            explained,
            bic_delta,
            accepted,
        }
    }
}

/// Named effects in a set (recalibrations are the user's own model: they count as none).
pub fn complexity(parts: &[Part]) -> usize {
    parts
        .iter()
        .filter(|p| !is_recal_id(p.candidate.id()))
        .count()
}

fn n_params(parts: &[Part]) -> usize {
    parts.iter().map(|p| p.params.len()).sum()
}

/// Picks the winner among trials `(set, held-out cost)` accepted against the current set:
/// the lowest cost, unless a simpler accepted trial is not beaten by it under `rule`.
pub fn pick<'c>(rule: &Rule, accepted: Vec<(Vec<Part<'c>>, f64)>) -> Option<(Vec<Part<'c>>, f64)> {
    let best_i = (0..accepted.len()).min_by(|a, b| accepted[*a].1.total_cmp(&accepted[*b].1))?;
    let (best, jb) = (&accepted[best_i].0, accepted[best_i].1);
    let simpler = (0..accepted.len())
        .filter(|i| complexity(&accepted[*i].0) < complexity(best))
        .filter(|i| {
            let (t, jt) = (&accepted[*i].0, accepted[*i].1);
            !rule.judge(jt, n_params(t), jb, n_params(best)).accepted
        })
        .min_by(|a, b| accepted[*a].1.total_cmp(&accepted[*b].1));
    let i = simpler.unwrap_or(best_i);
    accepted.into_iter().nth(i)
}

/// Result of the selection stage.
pub struct Selected<'c> {
    pub chosen: Vec<Part<'c>>,
    /// Held-out cost of the chosen set.
    pub heldout_cost: f64,
    /// Share of the held-out excess each chosen part removed alone in round 1 (or when added).
    pub explained: Vec<f64>,
    /// Round-1 share per candidate id.
    pub round1_explained: BTreeMap<&'static str, f64>,
    pub scores: Vec<CandidateScore>,
}

/// Round-1 candidates (best held-out cost first) the swap pass draws from.
const SWAP_TOP: usize = 5;

/// Forward selection, the swap pass, the backward pass, then the parts that change nothing
/// dropped.
#[allow(clippy::too_many_arguments)]
pub fn select<'c>(
    problem: &Problem,
    cands: &'c [Box<dyn Candidate>],
    screenings: &[Screening],
    fit_range: std::ops::Range<usize>,
    held: std::ops::Range<usize>,
    j0_h: f64,
    rule: &Rule,
    opts: &DiagnoseOptions,
    step: &(dyn Fn(&str) + Sync),
) -> Selected<'c> {
    let t = Trials {
        problem,
        cands,
        screenings,
        fit_range,
        held,
        rule,
        opts,
    };
    let mut s = Search {
        scores: Vec::new(),
        round1_explained: BTreeMap::new(),
        chosen_explained: Vec::new(),
        current: Vec::new(),
        j_cur: j0_h,
    };
    forward_selection(&t, &mut s, step);
    swap_pass(&t, &mut s);
    backward_pass(&t, &mut s);
    drop_parts_that_change_nothing(&t, &mut s, j0_h);
    Selected {
        chosen: s.current,
        heldout_cost: s.j_cur,
        explained: s.chosen_explained,
        round1_explained: s.round1_explained,
        scores: s.scores,
    }
}

/// What every trial of the selection shares: the problem, the pool, the ranges it is fitted
/// on and scored on, the acceptance rule.
struct Trials<'a, 'c> {
    problem: &'a Problem<'a>,
    cands: &'c [Box<dyn Candidate>],
    screenings: &'a [Screening],
    fit_range: std::ops::Range<usize>,
    held: std::ops::Range<usize>,
    rule: &'a Rule,
    opts: &'a DiagnoseOptions,
}

impl<'c> Trials<'_, 'c> {
    /// Fits `parts` on the fit range and scores them on the held-out tail by a replay that
    /// is not held: (fitted parts, held-out cost (infinite when the replay fails), seconds).
    fn trial(&self, parts: &[Part<'c>]) -> (Vec<Part<'c>>, f64, f64) {
        let t0 = std::time::Instant::now();
        let (fitted, _) = self
            .problem
            .fit(parts, self.fit_range.clone(), self.opts.max_iter);
        let jh = match self.problem.replay_costs(&fitted, self.held.clone()) {
            Some(c) => c.iter().sum(),
            None => f64::INFINITY,
        };
        (fitted, jh, t0.elapsed().as_secs_f64())
    }

    /// Candidate `i` at its screening's start values.
    fn part(&self, i: usize) -> Part<'c> {
        Part {
            candidate: self.cands[i].as_ref(),
            params: self.screenings[i].initial.clone(),
        }
    }

    /// The held-out cost counts as explained within the noise.
    fn explained(&self, j: f64) -> bool {
        j <= self.opts.null_ratio * self.rule.noise_cost
    }
}

/// The selection's state: the chosen set, its held-out cost, each chosen part's share, and
/// the score rows so far.
struct Search<'c> {
    scores: Vec<CandidateScore>,
    round1_explained: BTreeMap<&'static str, f64>,
    chosen_explained: Vec<f64>,
    current: Vec<Part<'c>>,
    j_cur: f64,
}

impl<'c> Search<'c> {
    /// Takes `fitted` (held-out cost `jh`) as the chosen set, its row of `round` marked
    /// accepted and the shares re-read from round 1.
    fn replace(&mut self, round: usize, fitted: Vec<Part<'c>>, jh: f64) {
        mark_accepted(&mut self.scores, round, &set_id(&fitted));
        self.chosen_explained = round1_shares(&fitted, &self.round1_explained);
        self.current = fitted;
        self.j_cur = jh;
    }
}

/// Forward selection: each round adds to the chosen set the candidate the rule accepts
/// ([`pick`] among the accepted), until none is accepted, [`DiagnoseOptions::max_effects`]
/// are chosen or the held-out cost is within the noise. Round 1's shares are kept per
/// candidate.
fn forward_selection<'c>(t: &Trials<'_, 'c>, s: &mut Search<'c>, step: &(dyn Fn(&str) + Sync)) {
    let (cands, screenings, rule, opts) = (t.cands, t.screenings, t.rule, t.opts);
    let setup = &t.problem.setup;
    for round in 1..=opts.max_effects {
        if t.explained(s.j_cur) {
            break;
        }
        let todo: Vec<usize> = (0..cands.len())
            .filter(|i| !s.current.iter().any(|p| p.candidate.id() == cands[*i].id()))
            .collect();
        let current = &s.current;
        let results = par_map(&todo, opts.threads, |&i| {
            let mut parts = current.clone();
            parts.push(t.part(i));
            let r = t.trial(&parts);
            step(&format!("round {round}: {}", cands[i].id()));
            (i, r)
        });
        let k_cur = n_params(&s.current);
        let mut accepted: Vec<(Vec<Part<'c>>, f64)> = Vec::new();
        for (i, (fitted, jh, seconds)) in results {
            let j = rule.judge(s.j_cur, k_cur, jh, n_params(&fitted));
            if round == 1 {
                s.round1_explained.insert(cands[i].id(), j.explained);
            }
            let last = fitted.last().expect("one part added");
            s.scores.push(CandidateScore {
                id: cands[i].id().into(),
                round,
                screening: screenings[i].score,
                params: cands[i]
                    .params(setup)
                    .iter()
                    .zip(&last.params)
                    .map(|(s, v)| (s.name.clone(), *v))
                    .collect(),
                heldout_cost: jh,
                explained: j.explained,
                bic_delta: j.bic_delta,
                accepted: false,
                seconds,
            });
            if j.accepted {
                accepted.push((fitted, jh));
            }
        }
        let Some((fitted, jh)) = pick(rule, accepted) else {
            break;
        };
        let id = fitted.last().expect("one part added").candidate.id();
        let explained = rule.judge(s.j_cur, k_cur, jh, n_params(&fitted)).explained;
        if let Some(row) = s.scores.iter_mut().find(|r| r.round == round && r.id == id) {
            row.accepted = true;
        }
        s.current = fitted;
        s.j_cur = jh;
        s.chosen_explained.push(explained);
    }
}

/// The [`SWAP_TOP`] best round-1 candidates (pool indices with their held-out cost, best
/// first, each once).
fn swap_top(scores: &[CandidateScore], cands: &[Box<dyn Candidate>]) -> Vec<(usize, f64)> {
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
    let mut seen: Vec<&str> = Vec::new();
    top.retain(|(i, _)| {
        let id = cands[*i].id();
        let new = !seen.contains(&id);
        seen.push(id);
        new
    });
    top.truncate(SWAP_TOP);
    top
}

/// Swap pass (stepwise selection): forward selection is greedy, and a first pick that
/// stands in for two effects at once (supply drop for friction + leakage without force
/// channels) blocks the right pair. While the held-out error is still clearly above noise,
/// try the sets the greedy path skipped: each chosen part replaced by one of the
/// [`SWAP_TOP`] best round-1 candidates, and (below max_effects) every pair of those that
/// leaves the chosen ones out. Judged by the same rule; repeated while it helps (3 passes
/// at most, no set tried twice).
fn swap_pass<'c>(t: &Trials<'_, 'c>, s: &mut Search<'c>) {
    let (cands, rule, opts) = (t.cands, t.rule, t.opts);
    let top = swap_top(&s.scores, cands);
    let mut tried: Vec<Vec<&str>> = Vec::new();
    for pass in 1..=3 {
        if s.current.is_empty() || t.explained(s.j_cur) {
            break;
        }
        let current = &s.current;
        let in_current = |i: usize| current.iter().any(|p| p.candidate.id() == cands[i].id());
        let mut trials: Vec<Vec<Part<'c>>> = Vec::new();
        for j in 0..current.len() {
            for &(i, _) in &top {
                if !in_current(i) {
                    let mut tr = current.clone();
                    tr[j] = t.part(i);
                    trials.push(tr);
                }
            }
        }
        if current.len() < opts.max_effects {
            for (a, &(i, _)) in top.iter().enumerate() {
                for &(k, _) in &top[a + 1..] {
                    // Pairs that keep a chosen part were the forward step's.
                    if !in_current(i) && !in_current(k) {
                        trials.push(vec![t.part(i), t.part(k)]);
                    }
                }
            }
        }
        trials.retain(|tr| {
            let mut ids: Vec<&str> = tr.iter().map(|p| p.candidate.id()).collect();
            ids.sort();
            let new = !tried.contains(&ids);
            if new {
                tried.push(ids);
            }
            new
        });
        if trials.is_empty() {
            break;
        }
        let results = par_map(&trials, opts.threads, |parts| t.trial(parts));
        let k_cur = n_params(&s.current);
        let round = opts.max_effects + pass;
        let mut accepted: Vec<(Vec<Part<'c>>, f64)> = Vec::new();
        for (fitted, jh, seconds) in results {
            let j = rule.judge(s.j_cur, k_cur, jh, n_params(&fitted));
            s.scores
                .push(set_score(&fitted, round, jh, Some(j), seconds));
            if j.accepted {
                accepted.push((fitted, jh));
            }
        }
        let Some((fitted, jh)) = pick(rule, accepted) else {
            break;
        };
        s.replace(round, fitted, jh);
    }
}

/// Backward pass: a part the others do without is dropped. Each part is left out in turn
/// and the rest refitted from their current values; when the current set does not beat
/// such a reduced set under the same rule (e.g. the reduced set already explains the data
/// within its noise), the best reduced set replaces it: the simpler explanation.
fn backward_pass<'c>(t: &Trials<'_, 'c>, s: &mut Search<'c>) {
    let (rule, opts) = (t.rule, t.opts);
    let round = opts.max_effects + 4;
    while s.current.len() > 1 {
        let trials: Vec<Vec<Part<'c>>> = (0..s.current.len())
            .map(|j| {
                let mut tr = s.current.clone();
                tr.remove(j);
                tr
            })
            .collect();
        let results = par_map(&trials, opts.threads, |parts| t.trial(parts));
        let k_cur = n_params(&s.current);
        let mut best: Option<(Vec<Part<'c>>, f64)> = None;
        for (fitted, jh, seconds) in results {
            let kept = rule.judge(jh, n_params(&fitted), s.j_cur, k_cur).accepted;
            s.scores.push(set_score(&fitted, round, jh, None, seconds));
            if !kept && jh.is_finite() && best.as_ref().is_none_or(|b| jh < b.1) {
                best = Some((fitted, jh));
            }
        }
        let Some((fitted, jh)) = best else {
            break;
        };
        s.replace(round, fitted, jh);
    }
}

/// A part that leaves the plant file as it is (a recalibration by a hair) is no answer:
/// dropped, the rest refitted without it (nothing left: the nominal held-out cost `j0_h`).
fn drop_parts_that_change_nothing<'c>(t: &Trials<'_, 'c>, s: &mut Search<'c>, j0_h: f64) {
    let round = t.opts.max_effects + 4;
    while let Some(j) = s
        .current
        .iter()
        .position(|p| p.candidate.changes_nothing(&p.params))
    {
        let mut tr = s.current.clone();
        tr.remove(j);
        if tr.is_empty() {
            s.current = tr;
            s.j_cur = j0_h;
            s.chosen_explained.clear();
            break;
        }
        let (fitted, jh, seconds) = t.trial(&tr);
        s.scores
            .push(set_score(&fitted, round + 1, jh, None, seconds));
        s.replace(round + 1, fitted, jh);
    }
}

/// The score row of a trial set (swap and backward passes), not yet accepted.
fn set_score(
    parts: &[Part],
    round: usize,
    jh: f64,
    j: Option<Judgement>,
    seconds: f64,
) -> CandidateScore {
    CandidateScore {
        id: set_id(parts),
        round,
        screening: f64::NAN,
        params: Vec::new(),
        heldout_cost: jh,
        explained: j.map_or(f64::NAN, |j| j.explained),
        bic_delta: j.map_or(f64::NAN, |j| j.bic_delta),
        accepted: false,
        seconds,
    }
}

/// Marks the row of `id` in `round` accepted.
fn mark_accepted(scores: &mut [CandidateScore], round: usize, id: &str) {
    if let Some(s) = scores.iter_mut().find(|s| s.round == round && s.id == id) {
        s.accepted = true;
    }
}

/// Each part's share of a chosen set: what it removed alone in round 1.
fn round1_shares(parts: &[Part], round1_explained: &BTreeMap<&'static str, f64>) -> Vec<f64> {
    parts
        .iter()
        .map(|p| {
            round1_explained
                .get(p.candidate.id())
                .copied()
                .unwrap_or(0.0)
        })
        .collect()
}

/// `a+b` for a trial set.
pub fn set_id(parts: &[Part]) -> String {
    parts
        .iter()
        .map(|p| p.candidate.id())
        .collect::<Vec<_>>()
        .join("+")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plant::effects::joint_friction::JointFrictionCandidate;

    fn rule() -> Rule {
        Rule {
            min_explained: 0.3,
            min_gain_noise: 0.5,
            noise_cost: 0.01,
            n_heldout: 1000.0,
            explained_cost: 0.02,
        }
    }

    #[test]
    fn the_rule_needs_a_clear_gain_beyond_noise() {
        let r = rule();
        // Removes most of the excess: accepted.
        assert!(r.judge(1.0, 0, 0.05, 2).accepted);
        // Removes 10 % of the excess: not enough.
        assert!(!r.judge(1.0, 0, 0.9, 1).accepted);
        // Removes all of a tiny excess, but less than half the noise cost: not accepted.
        assert!(!r.judge(0.012, 0, 0.0105, 1).accepted);
        // The current set already explains the data within its noise: nothing is added,
        // however large the relative gain (noise-free data, numerical residue).
        assert!(!r.judge(0.019, 0, 0.0001, 1).accepted);
        // A failed simulation is never accepted.
        assert!(!r.judge(1.0, 0, f64::INFINITY, 1).accepted);
    }

    #[test]
    fn a_recalibration_wins_unless_an_effect_beats_it_clearly() {
        let nominal = PlantConfig::reference();
        let recal: Vec<Box<dyn Candidate>> = recalibrate::candidates(&nominal);
        let friction: Box<dyn Candidate> = Box::new(JointFrictionCandidate);
        let rc: &dyn Candidate = recal[0].as_ref();
        assert!(rc.id().contains('.'));
        let r_part = || {
            vec![Part {
                candidate: rc,
                params: vec![1.0],
            }]
        };
        let e_part = || {
            vec![Part {
                candidate: friction.as_ref(),
                params: vec![0.1, 0.1],
            }]
        };
        // The effect is a hair better: the recalibration is kept.
        let w = pick(&rule(), vec![(e_part(), 0.0100), (r_part(), 0.0102)]).unwrap();
        assert!(is_recal_id(w.0[0].candidate.id()));
        // The effect is clearly better: it wins.
        let w = pick(&rule(), vec![(e_part(), 0.011), (r_part(), 0.5)]).unwrap();
        assert_eq!(w.0[0].candidate.id(), "joint_friction");
        assert!(pick(&rule(), Vec::new()).is_none());
    }
}
