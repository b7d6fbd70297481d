//! The verdict stage: what kind of answer the diagnosis gives, and when it refuses to name
//! anything.
//!
//! - `nothing_missing`: the nominal model already fits TRAIN at the noise level (or, on
//!   noise-free data, at the integrator's accuracy: every channel within
//!   [`FIT_FLOOR_REL`] of its spread).
//! - `explained`: effects and/or recalibrated keys were accepted and the held-out fits
//!   (the held-out tail of TRAIN and the CHECK recording) are all at least
//!   [`MIN_HELDOUT_FIT_PCT`].
//! - `unexplained`: the best answer still leaves a held-out fit below
//!   [`MIN_HELDOUT_FIT_PCT`] (or nothing was accepted): no effect is named.
//! - `not_this_plant`: the recording does not look like this plant at all (the nominal model
//!   fits no channel, or a plausibility check on the units and the channel mapping fires):
//!   no effect is named and the likely cause is pointed at.
//!
//! The CLI exits with status 3 on `unexplained` and `not_this_plant` (the JSON is written).

use crate::fit::fit_percent_by;
use crate::io::recording::{Channel, Recording};
use crate::plant::config::PlantConfig;
use crate::plant::Measurement;

/// Held-out fits below this (in %) mean the answer does not explain the recording.
pub const MIN_HELDOUT_FIT_PCT: f64 = 50.0;

/// Relative error (of a channel's spread) below which a channel counts as fitted even when
/// the recording has no noise (integrator tolerance and CSV rounding): 0.2 %, a fit of
/// 99.8 %.
pub const FIT_FLOOR_REL: f64 = 2e-3;

/// The kind of answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    Explained,
    NothingMissing,
    Unexplained,
    NotThisPlant,
}

impl Verdict {
    /// The JSON value.
    pub fn as_str(self) -> &'static str {
        match self {
            Verdict::Explained => "explained",
            Verdict::NothingMissing => "nothing_missing",
            Verdict::Unexplained => "unexplained",
            Verdict::NotThisPlant => "not_this_plant",
        }
    }

    /// Whether the answer names effects / recalibrations (the CLI exits 0) or refuses (3).
    pub fn is_answer(self) -> bool {
        matches!(self, Verdict::Explained | Verdict::NothingMissing)
    }
}

/// The fit (in %) of channel `c` over `range`, its error normalised by `spread` (the whole
/// recording's standard deviation, so a short tail where a channel barely moves is not
/// judged by its own tiny spread).
pub fn fit_vs_spread(
    y: &[f64],
    pred: &[Measurement],
    c: Channel,
    range: std::ops::Range<usize>,
    spread: f64,
) -> f64 {
    let sum_sq = range
        .clone()
        .map(|k| (c.of(&pred[k]) - y[k]).powi(2))
        .sum::<f64>();
    fit_vs_spread_of_sum(sum_sq, range.len(), spread)
}

/// [`fit_vs_spread`] from the sum, in sample order, of `(predicted - y)^2` over `samples`
/// samples (for a prediction that is not held; the same value to the bit).
pub fn fit_vs_spread_of_sum(sum_sq: f64, samples: usize, spread: f64) -> f64 {
    let mse = sum_sq / samples.max(1) as f64;
    100.0 * (1.0 - mse.sqrt() / spread.max(1e-300))
}

/// `fit_percent(y, sign * channel c of sim)` with neither series copied (the same sums).
fn fit_to_sim<I: Iterator<Item = f64>>(
    y: impl Fn() -> I,
    sim: &[Measurement],
    c: Channel,
    sign: f64,
) -> f64 {
    let err2 = y()
        .zip(sim)
        .map(|(a, m)| {
            let b = sign * c.of(m);
            (a - b) * (a - b)
        })
        .sum::<f64>();
    fit_percent_by(y, err2)
}

/// Plausibility checks of a recording against the nominal simulation of the same inputs:
/// each message names a likely cause (units, channel mapping, plant file).
pub fn plausibility_hints(
    nominal: &PlantConfig,
    rec: &Recording,
    sim: &[Measurement],
) -> Vec<String> {
    let mut hints = Vec::new();
    let supply_kpa = nominal.environment.supply_gauge_pa / 1000.0;
    let p_atm_kpa = nominal.environment.p_atm_pa / 1000.0;
    let fit_of = |y: &[f64], c: Channel, sign: f64| fit_to_sim(|| y.iter().copied(), sim, c, sign);
    for c in [Channel::P1Kpa, Channel::P2Kpa] {
        let Some(y) = rec.channel(c) else { continue };
        let hi = y.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let lo = y.iter().copied().fold(f64::INFINITY, f64::min);
        if hi > 1.5 * supply_kpa + 50.0 {
            hints.push(format!(
                "{} reaches {hi:.0} kPa, above the plant file's supply ({supply_kpa:.0} kPa gauge): check the units (RECORDING.md: kPa gauge, not Pa or absolute) or the supply in the plant file",
                c.name()
            ));
        } else if lo < -1.2 * p_atm_kpa {
            hints.push(format!(
                "{} goes down to {lo:.0} kPa, below vacuum: check the units and the sign (kPa gauge)",
                c.name()
            ));
        }
        let nom_hi = sim
            .iter()
            .map(|m| c.of(m))
            .fold(f64::NEG_INFINITY, f64::max);
        if nom_hi > 50.0 && hi.abs() < nom_hi / 50.0 && hi - lo < nom_hi / 50.0 {
            hints.push(format!(
                "{} stays below {hi:.3} kPa where the nominal model reaches {nom_hi:.0} kPa: bar or MPa instead of kPa, or the valve columns are not mapped to the right valves",
                c.name()
            ));
        }
    }
    // Swapped pairs: measured channel a fits the simulated b clearly better than its own.
    for (a, b) in [
        (Channel::P1Kpa, Channel::P2Kpa),
        (Channel::F1N, Channel::F2N),
    ] {
        let (Some(ya), Some(yb)) = (rec.channel(a), rec.channel(b)) else {
            continue;
        };
        let straight = fit_of(ya, a, 1.0).min(fit_of(yb, b, 1.0));
        let crossed = fit_of(ya, b, 1.0).min(fit_of(yb, a, 1.0));
        if crossed > straight + 30.0 && crossed > 30.0 {
            hints.push(format!(
                "{} and {} fit the model {:.0} % when swapped and {:.0} % as labelled: check the channel mapping (muscle 1 contracts when the angle grows) or the valve columns",
                a.name(),
                b.name(),
                crossed,
                straight
            ));
        }
    }
    if let Some(y) = rec.channel(Channel::AngleDeg) {
        let straight = fit_of(y, Channel::AngleDeg, 1.0);
        let flipped = fit_of(y, Channel::AngleDeg, -1.0);
        if flipped > straight + 30.0 && flipped > 30.0 {
            hints.push(format!(
                "angle_deg fits the model {flipped:.0} % with its sign flipped and {straight:.0} % as recorded: check the angle sign convention (muscle 1 contracts when the angle grows)"
            ));
        }
        let radians = || y.iter().map(|v| v.to_degrees());
        let as_rad = fit_to_sim(radians, sim, Channel::AngleDeg, 1.0);
        if as_rad > straight + 30.0 && as_rad > 30.0 {
            hints.push(format!(
                "angle_deg fits the model {as_rad:.0} % read as radians and {straight:.0} % as degrees: check the angle unit"
            ));
        }
    }
    hints
}

/// Whether the nominal fits say the recording is nothing like the plant: every recorded
/// channel fits below 0 %.
pub fn unlike_plant(fit_before: &std::collections::BTreeMap<&'static str, f64>) -> bool {
    !fit_before.is_empty() && fit_before.values().all(|f| !(*f >= 0.0))
}

/// The generic pointer at likely causes, for `unexplained` and `not_this_plant`.
pub const LIKELY_CAUSES: &str = "Likely causes: a plant file that does not describe this rig (another muscle, load or valve), units other than RECORDING.md's (angle in degrees, pressures in kPa gauge, forces in N), or a channel or valve column mapped to the wrong muscle.";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn verdict_strings_and_exit_kind() {
        assert_eq!(Verdict::NotThisPlant.as_str(), "not_this_plant");
        assert!(Verdict::NothingMissing.is_answer());
        assert!(!Verdict::Unexplained.is_answer());
    }

    #[test]
    fn unlike_plant_needs_every_channel_below_zero() {
        let mut m = std::collections::BTreeMap::new();
        m.insert("angle_deg", -40.0);
        m.insert("p1_kpa", -3.0);
        assert!(unlike_plant(&m));
        m.insert("p2_kpa", 10.0);
        assert!(!unlike_plant(&m));
        m.insert("p2_kpa", f64::NEG_INFINITY);
        assert!(unlike_plant(&m));
    }
}
