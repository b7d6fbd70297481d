//! The grading stage: every item of the best answer (a named effect or a recalibrated key)
//! earns its place on held-out data, or is dropped; what the accepted items remove of the
//! mismatch is measured per channel, and what remains is located.
//!
//! An item is judged by leaving it out of the answer (the others at their fitted values)
//! and replaying the held-out tail of TRAIN and the CHECK recording:
//! - **gain on held-out data**: leaving it out must raise the mismatch of CHECK (and must
//!   not lower the tail's) by at least [`MIN_ITEM_SHARE`] of the nominal model's mismatch
//!   (relative residual energy, summed over the channels, each over its spread);
//! - **an interval that excludes the null value**: the 95 % interval of a parameter whose
//!   null value is in range (a recalibrated key's file value, an effect's zero) must not
//!   hold it (an interval the recording does not determine is not held against it);
//! - a value inside the candidate's physical bounds (the search cannot leave them). A
//!   recalibrated key at the end of the range the diagnosis searches is kept only in a
//!   complete answer: the file's value is off by more than the
//!   range, and the bound note says so.
//!
//! Never on a multiple of the noise alone: the noise only grades the accepted answer into
//! `explained` (what remains is at the noise floor) or `partly_explained`.

use std::collections::BTreeMap;

use super::candidates::{Candidate, Setup};
use super::fitting::Part;
use crate::fit::fit_percent_of_err2;
use crate::io::recording::{Channel, Recording};
use crate::plant::config::PlantConfig;
use crate::plant::{Measurement, Plant};
use crate::sim::SolverOptions;

/// An item must remove at least this share of the nominal model's mismatch on CHECK (and
/// not add to the held-out tail's) to be kept: chosen on the tuning seeds of the
/// independent rig (`host-sim/tests/diagnose_independent.rs`).
pub const MIN_ITEM_SHARE: f64 = 0.01;

/// A `partly_explained` answer removes at least this share of the nominal model's mismatch
/// on the held-out tail and on CHECK (relative residual energy summed over the channels:
/// 75 % halves the rms mismatch). Chosen on the tuning seeds of the independent rig
/// (EVIDENCE lines of `evidence_full_matrix`, seeds 11 and 12): catalogue effects in other
/// functional forms that lift CHECK's departing channel by half its gap remove 77-100 %;
/// catalogue items standing in for physics outside the catalogue remove 63-99.4 %, and those
/// above this bar are answered by the stand-in check (`diagnose`'s stage 5b), which the
/// discovered term wins on those seeds.
pub const MIN_PARTLY_SHARE: f64 = 0.75;

/// Residual energy per channel (sums of squared errors) of one replay; `None`: it failed.
pub type Energy = Option<[f64; 5]>;

/// A replay of some of the answer's parts, as its residual energy.
pub type EnergyOf<'a> = &'a dyn Fn(&[Part]) -> Energy;

/// How one item of the answer did on held-out data.
#[derive(Debug, Clone)]
pub struct ItemGrade {
    /// Candidate id (an effect, or a plant-file key).
    pub id: String,
    /// Per channel: the share of the nominal model's mismatch (residual energy) this item
    /// removes, the others kept: on CHECK when there is one, else on the held-out tail.
    pub share: BTreeMap<&'static str, f64>,
    /// The same summed over the channels (each over its spread), on the held-out tail and
    /// on CHECK.
    pub share_heldout: f64,
    pub share_check: Option<f64>,
    /// Fit points of the departing channel lost when the item is left out (CHECK, else the
    /// held-out tail).
    pub gain_pts: f64,
    /// Whether a parameter's 95 % interval excludes its null value (`None`: no parameter
    /// has a null value in range, or the recording does not determine the interval).
    pub ci_excludes_null: Option<bool>,
    pub accepted: bool,
    /// Why it was dropped.
    pub why_not: Option<String>,
}

/// The answer graded on held-out data.
#[derive(Debug, Clone, Default)]
pub struct Grade {
    pub items: Vec<ItemGrade>,
    /// Share of the nominal mismatch the accepted items remove together, per channel, on
    /// the held-out tail and on CHECK.
    pub removed_heldout: BTreeMap<&'static str, f64>,
    pub removed_check: Option<BTreeMap<&'static str, f64>>,
    /// The same summed over the channels (each over its spread).
    pub removed_heldout_total: f64,
    pub removed_check_total: Option<f64>,
}

impl Grade {
    /// Ids of the accepted items.
    pub fn accepted(&self) -> Vec<&str> {
        self.items
            .iter()
            .filter(|i| i.accepted)
            .map(|i| i.id.as_str())
            .collect()
    }

    /// The accepted items remove at least [`MIN_PARTLY_SHARE`] of the mismatch on the
    /// held-out tail and on CHECK.
    pub fn removes_most(&self) -> bool {
        self.removed_heldout_total >= MIN_PARTLY_SHARE
            && self
                .removed_check_total
                .is_none_or(|s| s >= MIN_PARTLY_SHARE)
    }
}

/// What the grading replays: the held-out tail of TRAIN and CHECK, each under a model made
/// of some of the answer's parts.
pub struct Replays<'a> {
    /// Residual energy on TRAIN's held-out tail of the model `parts` (`None`: it failed).
    pub heldout: EnergyOf<'a>,
    /// The same on CHECK (absent without a CHECK recording).
    pub check: Option<EnergyOf<'a>>,
    /// Spread of every channel (the costs' normalisation) and which channels are measured.
    pub spread: [f64; 5],
    pub present: [bool; 5],
    /// TRAIN's held-out tail and CHECK (for the fits in points).
    pub heldout_y: Vec<(Channel, Vec<f64>)>,
    pub check_rec: Option<&'a Recording>,
}

impl Replays<'_> {
    fn total(&self, e: &[f64; 5]) -> f64 {
        Channel::ALL
            .iter()
            .filter(|c| self.present[c.index()])
            .map(|c| e[c.index()] / self.spread[c.index()].powi(2))
            .sum()
    }

    /// Per measured channel `1 - e / e0`.
    fn shares(&self, e0: &[f64; 5], e: &[f64; 5]) -> BTreeMap<&'static str, f64> {
        Channel::ALL
            .iter()
            .filter(|c| self.present[c.index()])
            .map(|c| {
                let i = c.index();
                (c.name(), 1.0 - e[i] / e0[i].max(1e-300))
            })
            .collect()
    }
}

/// The null value of parameter `i` of `c` when it is in range: a recalibrated key's file
/// value (its typical size), an effect's zero.
fn null_value(c: &dyn Candidate, setup: &Setup, i: usize) -> Option<f64> {
    let spec = c.params(setup).into_iter().nth(i)?;
    if super::recalibrate::is_recal_id(c.id()) {
        Some(spec.scale)
    } else {
        (spec.lo <= 0.0 && 0.0 <= spec.hi).then_some(0.0)
    }
}

/// Whether `part` is a recalibrated key whose value ended at a bound of its search range.
pub fn recal_at_bound(part: &Part, setup: &Setup) -> bool {
    super::recalibrate::is_recal_id(part.candidate.id())
        && !super::recalibrate::at_bounds(part.candidate, &part.params, setup).is_empty()
}

/// Whether a parameter of `part` has a 95 % interval `ci` that excludes its null value;
/// `None` when no parameter can be judged.
fn ci_excludes_null(part: &Part, ci: &[[f64; 2]], setup: &Setup) -> Option<bool> {
    let mut judged = None;
    for (i, iv) in ci.iter().enumerate() {
        let Some(null) = null_value(part.candidate, setup, i) else {
            continue;
        };
        if !(iv[0].is_finite() && iv[1].is_finite()) {
            continue;
        }
        let excludes = null < iv[0] || null > iv[1];
        judged = Some(judged.unwrap_or(false) || excludes);
    }
    judged
}

/// The departing channel of `rec`: the one `e0` (the nominal model) fits worst.
fn departing(present: &[bool; 5], ys: &[(Channel, &[f64])], e0: &[f64; 5]) -> Option<Channel> {
    ys.iter()
        .filter(|(c, _)| present[c.index()])
        .map(|(c, y)| (*c, fit_percent_of_err2(y, e0[c.index()])))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(c, _)| c)
}

/// Grades the answer `chosen` (95 % intervals `ci95`, one row per part): each part left
/// out in turn, the held-out tail and CHECK replayed; parts that do not earn their place
/// are dropped and the rest graded again (their fitted values kept) until all stand.
/// `e0_heldout` and `e0_check` are the nominal model's residual energies.
pub fn grade(
    chosen: &[Part],
    ci95: &[Vec<[f64; 2]>],
    setup: &Setup,
    r: &Replays,
    e0_heldout: &[f64; 5],
    e0_check: Option<&[f64; 5]>,
) -> Grade {
    let mut keep: Vec<usize> = (0..chosen.len()).collect();
    let mut dropped: Vec<ItemGrade> = Vec::new();
    loop {
        let parts: Vec<Part> = keep.iter().map(|&i| chosen[i].clone()).collect();
        let (all_h, all_c) = ((r.heldout)(&parts), r.check.map(|f| f(&parts)));
        let (Some(all_h), Some(all_c)) = (all_h, all_c.map_or(Some(None), |e| e.map(Some))) else {
            // The answer itself does not replay: nothing stands.
            dropped.extend(
                keep.iter()
                    .map(|&i| failed_item(&chosen[i], "the answer's replay failed")),
            );
            return finish(Vec::new(), dropped, r, e0_heldout, e0_check, None);
        };
        let items: Vec<ItemGrade> = keep
            .iter()
            .enumerate()
            .map(|(j, &i)| {
                let mut without = parts.clone();
                without.remove(j);
                item_grade(
                    &chosen[i],
                    ci95.get(i).map(|v| v.as_slice()).unwrap_or(&[]),
                    setup,
                    r,
                    (&all_h, all_c.as_ref()),
                    ((r.heldout)(&without), r.check.map(|f| f(&without))),
                    (e0_heldout, e0_check),
                )
            })
            .collect();
        if items.iter().all(|i| i.accepted) {
            return finish(
                items,
                dropped,
                r,
                e0_heldout,
                e0_check,
                Some((all_h, all_c)),
            );
        }
        // Drop the weakest failing item and grade the rest again.
        let worst = items
            .iter()
            .enumerate()
            .filter(|(_, g)| !g.accepted)
            .min_by(|a, b| {
                a.1.share_check
                    .unwrap_or(a.1.share_heldout)
                    .total_cmp(&b.1.share_check.unwrap_or(b.1.share_heldout))
            })
            .map(|(j, _)| j)
            .expect("a failing item");
        dropped.push(items[worst].clone());
        keep.remove(worst);
        if keep.is_empty() {
            return finish(Vec::new(), dropped, r, e0_heldout, e0_check, None);
        }
    }
}

fn failed_item(p: &Part, why: &str) -> ItemGrade {
    ItemGrade {
        id: p.candidate.id().to_string(),
        share: BTreeMap::new(),
        share_heldout: f64::NAN,
        share_check: None,
        gain_pts: f64::NAN,
        ci_excludes_null: None,
        accepted: false,
        why_not: Some(why.to_string()),
    }
}

/// One item judged from the replays with it (`all`) and without it (`without`).
#[allow(clippy::type_complexity)]
fn item_grade(
    part: &Part,
    ci: &[[f64; 2]],
    setup: &Setup,
    r: &Replays,
    all: (&[f64; 5], Option<&[f64; 5]>),
    without: (Energy, Option<Energy>),
    e0: (&[f64; 5], Option<&[f64; 5]>),
) -> ItemGrade {
    let id = part.candidate.id().to_string();
    let (Some(wo_h), wo_c) = (without.0, without.1) else {
        // Without it the model does not even replay: it is needed.
        return ItemGrade {
            id,
            share: BTreeMap::new(),
            share_heldout: 1.0,
            share_check: all.1.map(|_| 1.0),
            gain_pts: f64::INFINITY,
            ci_excludes_null: ci_excludes_null(part, ci, setup),
            accepted: true,
            why_not: None,
        };
    };
    let share_of = |e0: &[f64; 5], wo: &[f64; 5], a: &[f64; 5]| {
        (r.total(wo) - r.total(a)) / r.total(e0).max(1e-300)
    };
    let share_heldout = share_of(e0.0, &wo_h, all.0);
    let (share_check, per_channel, gain_pts) = match (all.1, wo_c, e0.1, r.check_rec) {
        (Some(a), Some(Some(wo)), Some(e0c), Some(rec)) => {
            let ys: Vec<(Channel, &[f64])> = Channel::ALL
                .iter()
                .filter_map(|c| Some((*c, rec.channel(*c)?)))
                .collect();
            let per: BTreeMap<&'static str, f64> = ys
                .iter()
                .filter(|(c, _)| r.present[c.index()])
                .map(|(c, _)| {
                    let i = c.index();
                    (c.name(), (wo[i] - a[i]) / e0c[i].max(1e-300))
                })
                .collect();
            let gain = departing(&r.present, &ys, e0c)
                .and_then(|c| {
                    let y = rec.channel(c)?;
                    Some(
                        fit_percent_of_err2(y, a[c.index()])
                            - fit_percent_of_err2(y, wo[c.index()]),
                    )
                })
                .unwrap_or(f64::NAN);
            (Some(share_of(e0c, &wo, a)), per, gain)
        }
        (Some(_), Some(None), _, _) => (Some(1.0), BTreeMap::new(), f64::INFINITY),
        _ => {
            let ys: Vec<(Channel, &[f64])> = r
                .heldout_y
                .iter()
                .map(|(c, y)| (*c, y.as_slice()))
                .collect();
            let per = ys
                .iter()
                .map(|(c, _)| {
                    let i = c.index();
                    (c.name(), (wo_h[i] - all.0[i]) / e0.0[i].max(1e-300))
                })
                .collect();
            let gain = departing(&r.present, &ys, e0.0)
                .and_then(|c| {
                    let y = ys.iter().find(|(d, _)| *d == c)?.1;
                    Some(
                        fit_percent_of_err2(y, all.0[c.index()])
                            - fit_percent_of_err2(y, wo_h[c.index()]),
                    )
                })
                .unwrap_or(f64::NAN);
            (None, per, gain)
        }
    };
    let ci_ok = ci_excludes_null(part, ci, setup);
    let why_not = if share_check.is_some_and(|s| !(s >= MIN_ITEM_SHARE)) {
        Some(format!(
            "left out, the check recording's mismatch changes by {:.1} % of the nominal model's (an item must remove at least {:.0} %)",
            100.0 * share_check.unwrap_or(f64::NAN),
            100.0 * MIN_ITEM_SHARE
        ))
    } else if share_check.is_none() && !(share_heldout >= MIN_ITEM_SHARE) {
        Some(format!(
            "left out, the held-out tail's mismatch changes by {:.1} % of the nominal model's (an item must remove at least {:.0} %)",
            100.0 * share_heldout,
            100.0 * MIN_ITEM_SHARE
        ))
    } else if !(share_heldout >= 0.0) {
        Some(format!(
            "it helps the check recording but worsens the held-out tail of the training recording ({:.1} % of the nominal mismatch)",
            100.0 * share_heldout
        ))
    } else if ci_ok == Some(false) {
        Some("its 95 % interval holds the value that changes nothing".to_string())
    } else {
        None
    };
    ItemGrade {
        id,
        share: per_channel,
        share_heldout,
        share_check,
        gain_pts,
        ci_excludes_null: ci_ok,
        accepted: why_not.is_none(),
        why_not,
    }
}

/// The grade from the accepted `items` (replays `all`: their residual energies on the
/// held-out tail and on CHECK) and the `dropped` ones.
fn finish(
    items: Vec<ItemGrade>,
    dropped: Vec<ItemGrade>,
    r: &Replays,
    e0_heldout: &[f64; 5],
    e0_check: Option<&[f64; 5]>,
    all: Option<([f64; 5], Option<[f64; 5]>)>,
) -> Grade {
    let (removed_heldout, removed_heldout_total, removed_check, removed_check_total) = match &all {
        Some((h, c)) => {
            let tot = |e0: &[f64; 5], e: &[f64; 5]| 1.0 - r.total(e) / r.total(e0).max(1e-300);
            let (rc, rct) = match (c, e0_check) {
                (Some(c), Some(e0c)) => (Some(r.shares(e0c, c)), Some(tot(e0c, c))),
                _ => (None, None),
            };
            (r.shares(e0_heldout, h), tot(e0_heldout, h), rc, rct)
        }
        None => (
            BTreeMap::new(),
            0.0,
            e0_check.map(|_| BTreeMap::new()),
            e0_check.map(|_| 0.0),
        ),
    };
    let mut all_items = items;
    all_items.extend(dropped);
    Grade {
        items: all_items,
        removed_heldout,
        removed_check,
        removed_heldout_total,
        removed_check_total,
    }
}

/// Residual energy per channel of the model `cfg` replaying `rec` (sums of squared errors
/// of the measured channels); `None` if the replay fails.
pub fn energy_of_replay(cfg: &PlantConfig, rec: &Recording, opts: &SolverOptions) -> Energy {
    let plant = Plant::from_config(cfg);
    let mut e = [0.0f64; 5];
    let ys: Vec<(Channel, &[f64])> = Channel::ALL
        .iter()
        .filter_map(|c| Some((*c, rec.channel(*c)?)))
        .collect();
    crate::sim::measure_each(
        &plant,
        &rec.inputs,
        rec.sample_period_s(),
        opts,
        |k, _, m: &Measurement| {
            for (c, y) in &ys {
                e[c.index()] += (c.of(m) - y[k]).powi(2);
            }
        },
    )
    .ok()?;
    e.iter().all(|v| v.is_finite()).then_some(e)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_interval_that_holds_zero_does_not_exclude_the_null_value() {
        use crate::plant::effects::joint_friction::JointFrictionCandidate;
        let c = JointFrictionCandidate;
        let setup = Setup {
            dt_s: 1e-3,
            present: [true; 5],
        };
        let part = Part {
            candidate: &c,
            params: vec![0.1, 0.1],
        };
        let specs = c.params(&setup);
        // Only parameters whose range holds zero are judged.
        let judged: Vec<bool> = (0..specs.len())
            .map(|i| null_value(&c, &setup, i).is_some())
            .collect();
        if judged.iter().any(|j| *j) {
            let wide: Vec<[f64; 2]> = specs.iter().map(|_| [-1.0, 1.0]).collect();
            assert_eq!(ci_excludes_null(&part, &wide, &setup), Some(false));
            let off: Vec<[f64; 2]> = specs.iter().map(|_| [0.05, 0.2]).collect();
            assert_eq!(ci_excludes_null(&part, &off, &setup), Some(true));
        }
        // An undetermined interval is not held against the item.
        let nan: Vec<[f64; 2]> = specs.iter().map(|_| [f64::NAN, f64::NAN]).collect();
        assert_eq!(ci_excludes_null(&part, &nan, &setup), None);
    }
}
