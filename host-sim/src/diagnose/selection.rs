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

/// Forward selection and the swap pass.
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
    let setup = &problem.setup;
    let mut scores: Vec<CandidateScore> = Vec::new();
    let mut round1_explained: BTreeMap<&'static str, f64> = BTreeMap::new();
    let mut chosen_explained: Vec<f64> = Vec::new();
    let mut current: Vec<Part<'c>> = Vec::new();
    let mut j_cur = j0_h;
    let trial = |parts: &[Part<'c>]| -> (Vec<Part<'c>>, f64, f64) {
        let t0 = std::time::Instant::now();
        let (fitted, _) = problem.fit(parts, fit_range.clone(), opts.max_iter);
        // Scored on the held-out tail by a replay that is not held.
        let jh = match problem.replay_costs(&fitted, held.clone()) {
            Some(c) => c.iter().sum(),
            None => f64::INFINITY,
        };
        (fitted, jh, t0.elapsed().as_secs_f64())
    };
    for round in 1..=opts.max_effects {
        if j_cur <= opts.null_ratio * rule.noise_cost {
            break;
        }
        let todo: Vec<usize> = (0..cands.len())
            .filter(|i| !current.iter().any(|p| p.candidate.id() == cands[*i].id()))
            .collect();
        let results = par_map(&todo, opts.threads, |&i| {
            let mut parts = current.clone();
            parts.push(Part {
                candidate: cands[i].as_ref(),
                params: screenings[i].initial.clone(),
            });
            let r = trial(&parts);
            step(&format!("round {round}: {}", cands[i].id()));
            (i, r)
        });
        let k_cur = n_params(&current);
        let mut accepted: Vec<(Vec<Part<'c>>, f64)> = Vec::new();
        for (i, (fitted, jh, seconds)) in results {
            let j = rule.judge(j_cur, k_cur, jh, n_params(&fitted));
            if round == 1 {
                round1_explained.insert(cands[i].id(), j.explained);
            }
            let last = fitted.last().expect("one part added");
            scores.push(CandidateScore {
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
        let explained = rule.judge(j_cur, k_cur, jh, n_params(&fitted)).explained;
        if let Some(s) = scores.iter_mut().find(|s| s.round == round && s.id == id) {
            s.accepted = true;
        }
        current = fitted;
        j_cur = jh;
        chosen_explained.push(explained);
    }
    // Swap pass (stepwise selection): forward selection is greedy, and a first pick that
    // stands in for two effects at once (supply drop for friction + leakage without force
    // channels) blocks the right pair. While the held-out error is still clearly above
    // noise, try the sets the greedy path skipped: each chosen part replaced by one of the
    // SWAP_TOP best round-1 candidates, and (below max_effects) every pair of those that
    // leaves the chosen ones out. Judged by the same rule; repeated while it helps.
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
    let mut tried: Vec<Vec<&str>> = Vec::new();
    for pass in 1..=3 {
        if current.is_empty() || j_cur <= opts.null_ratio * rule.noise_cost {
            break;
        }
        let in_current = |i: usize| current.iter().any(|p| p.candidate.id() == cands[i].id());
        let part = |i: usize| Part {
            candidate: cands[i].as_ref(),
            params: screenings[i].initial.clone(),
        };
        let mut trials: Vec<Vec<Part<'c>>> = Vec::new();
        for j in 0..current.len() {
            for &(i, _) in &top {
                if !in_current(i) {
                    let mut t = current.clone();
                    t[j] = part(i);
                    trials.push(t);
                }
            }
        }
        if current.len() < opts.max_effects {
            for (a, &(i, _)) in top.iter().enumerate() {
                for &(k, _) in &top[a + 1..] {
                    // Pairs that keep a chosen part were the forward step's.
                    if !in_current(i) && !in_current(k) {
                        trials.push(vec![part(i), part(k)]);
                    }
                }
            }
        }
        trials.retain(|t| {
            let mut ids: Vec<&str> = t.iter().map(|p| p.candidate.id()).collect();
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
        let results = par_map(&trials, opts.threads, |parts| trial(parts));
        let k_cur = n_params(&current);
        let round = opts.max_effects + pass;
        let mut accepted: Vec<(Vec<Part<'c>>, f64)> = Vec::new();
        for (fitted, jh, seconds) in results {
            let j = rule.judge(j_cur, k_cur, jh, n_params(&fitted));
            scores.push(set_score(&fitted, round, jh, Some(j), seconds));
            if j.accepted {
                accepted.push((fitted, jh));
            }
        }
        let Some((fitted, jh)) = pick(rule, accepted) else {
            break;
        };
        mark_accepted(&mut scores, round, &set_id(&fitted));
        chosen_explained = round1_shares(&fitted, &round1_explained);
        current = fitted;
        j_cur = jh;
    }
    // Backward pass: a part the others do without is dropped. Each part is left out in turn
    // and the rest refitted from their current values; when the current set does not beat
    // such a reduced set under the same rule (e.g. the reduced set already explains the
    // data within its noise), the best reduced set replaces it: the simpler explanation.
    let round = opts.max_effects + 4;
    while current.len() > 1 {
        let trials: Vec<Vec<Part<'c>>> = (0..current.len())
            .map(|j| {
                let mut t = current.clone();
                t.remove(j);
                t
            })
            .collect();
        let results = par_map(&trials, opts.threads, |parts| trial(parts));
        let k_cur = n_params(&current);
        let mut best: Option<(Vec<Part<'c>>, f64)> = None;
        for (fitted, jh, seconds) in results {
            let kept = rule.judge(jh, n_params(&fitted), j_cur, k_cur).accepted;
            scores.push(set_score(&fitted, round, jh, None, seconds));
            if !kept && jh.is_finite() && best.as_ref().is_none_or(|b| jh < b.1) {
                best = Some((fitted, jh));
            }
        }
        let Some((fitted, jh)) = best else {
            break;
        };
        mark_accepted(&mut scores, round, &set_id(&fitted));
        chosen_explained = round1_shares(&fitted, &round1_explained);
        current = fitted;
        j_cur = jh;
    }
    // A part that leaves the plant file as it is (a recalibration by a hair) is no answer:
    // dropped, the rest refitted without it.
    while let Some(j) = current
        .iter()
        .position(|p| p.candidate.changes_nothing(&p.params))
    {
        let mut t = current.clone();
        t.remove(j);
        if t.is_empty() {
            current = t;
            j_cur = j0_h;
            chosen_explained.clear();
            break;
        }
        let (fitted, jh, seconds) = trial(&t);
        scores.push(set_score(&fitted, round + 1, jh, None, seconds));
        mark_accepted(&mut scores, round + 1, &set_id(&fitted));
        chosen_explained = round1_shares(&fitted, &round1_explained);
        current = fitted;
        j_cur = jh;
    }
    Selected {
        chosen: current,
        heldout_cost: j_cur,
        explained: chosen_explained,
        round1_explained,
        scores,
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
        let nominal = PlantConfig::from_toml_str(
            &std::fs::read_to_string(
                std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                    .join("tests/fixtures/reference-1dof.toml"),
            )
            .unwrap(),
            "p.toml",
        )
        .unwrap();
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
