//! Valve columns logged late (or early) against the sensor columns: a logging
//! misalignment, told apart from a valve dead time by its sign.
//!
//! A valve dead time makes the sensors answer a command later than the nominal model
//! does (a positive delay, the `valve_delay` candidate). Valve columns written late by the
//! logger make the sensors answer BEFORE the logged command: the measured channels lead the
//! nominal replay, a negative dead time, which no valve has. When the nominal model
//! replayed with the valve columns moved earlier by one common shift fits the recording far
//! better, the shift is named, with the fix (`--shift-valves-ms` of `import` and
//! `diagnose`), as a plausibility hint: the answer is `not_this_plant` (the recording as
//! logged is not this plant's response), nothing is named.

use crate::io::recording::{Channel, Recording};
use crate::io::timebase::{shift_valves, MeasuredRows};
use crate::plant::config::PlantConfig;
use crate::plant::{Measurement, Plant};
use crate::sim::SolverOptions;

/// Longest lead searched [s] (the longest valve dead time a plant file may state).
pub const MAX_LEAD_S: f64 = crate::plant::effects::MAX_PLAUSIBLE_DELAY_S;
/// Samples of the recording's head the lead is searched on.
const SEARCH_SAMPLES: usize = 20_000;
/// The replay with the valve columns moved earlier must leave at most this share of the
/// nominal replay's cost (over the same rows) to name the shift.
pub const MAX_COST_SHARE: f64 = 0.25;

/// A valve-column offset found in a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct ValveOffset {
    /// How much earlier the valve columns fit (the valves were logged this late) [s].
    pub late_s: f64,
    /// Cost of the nominal replay as logged and with the columns moved (same rows).
    pub cost_as_logged: f64,
    pub cost_shifted: f64,
}

impl ValveOffset {
    /// The hint: the offset, why it is no dead time, the fix.
    pub fn hint(&self) -> String {
        let ms = self.late_s * 1e3;
        format!(
            "the valve columns look logged {ms:.0} ms late against the sensor columns: the \
             sensors answer {ms:.0} ms before the logged valve command (a negative dead time, \
             which no valve has; a real valve dead time makes them answer later). The nominal \
             model replayed with the valve columns moved {ms:.0} ms earlier leaves {:.1} % of \
             the error of the recording as logged. Fix the logger, or import or diagnose with \
             `--shift-valves-ms {ms:.0}`",
            100.0 * self.cost_shifted / self.cost_as_logged.max(1e-300)
        )
    }
}

/// Normalised cost of `yn` against the recording's measured channels over `rows` (measured
/// rows only).
fn cost(
    rec: &Recording,
    yn: &[Measurement],
    rows: std::ops::Range<usize>,
    spread: &[f64; 5],
) -> f64 {
    let m = MeasuredRows::of(rec);
    let mut sum = 0.0;
    let mut n = 0usize;
    for k in rows.filter(|&k| m.has(k) && k < yn.len()) {
        n += 1;
        for c in Channel::ALL {
            if let Some(y) = rec.channel(c) {
                sum += ((c.of(&yn[k]) - y[k]) / spread[c.index()]).powi(2);
            }
        }
    }
    sum / n.max(1) as f64
}

/// The valve columns' offset of the uniform recording `rec` against `nominal`, if the
/// measured channels lead the nominal replay and the replay with the valve columns moved
/// earlier by that lead fits far better ([`MAX_COST_SHARE`]); `None` otherwise.
pub fn find(nominal: &PlantConfig, rec: &Recording, opts: &SolverOptions) -> Option<ValveOffset> {
    let n = rec.len().min(SEARCH_SAMPLES);
    let dt = rec.sample_period_s();
    let max_lead = ((MAX_LEAD_S / dt).round() as usize).min(n / 4);
    if max_lead == 0 {
        return None;
    }
    let head = rec.head(n);
    let plant = Plant::from_config(nominal);
    let replay = |r: &Recording| -> Option<Vec<Measurement>> {
        let mut out = Vec::with_capacity(r.len());
        crate::sim::measure_each(&plant, &r.inputs, dt, opts, |_, _, m| out.push(*m)).ok()?;
        Some(out)
    };
    let yn = replay(&head)?;
    let (spread, _) = super::timebase::spread_and_noise(&head);
    let rows = MeasuredRows::of(&head);
    // Every channel together, y[k] against yn[k + s]: s > 0 a lead (the sensors answer
    // before the logged command), s < 0 a lag (a valve dead time), over the same samples.
    let shift_cost = |s: isize| -> f64 {
        let mut sum = 0.0;
        for c in Channel::ALL {
            if let Some(y) = head.channel(c) {
                let w = spread[c.index()].powi(-2);
                sum += (max_lead..n - max_lead)
                    .filter(|&k| rows.has(k))
                    .map(|k| (y[k] - c.of(&yn[(k as isize + s) as usize])).powi(2))
                    .sum::<f64>()
                    * w;
            }
        }
        sum
    };
    let m = max_lead as isize;
    let (mut best, mut best_cost) = (0isize, shift_cost(0));
    for s in (-m..=m).filter(|s| *s != 0) {
        let c = shift_cost(s);
        if c < best_cost {
            best = s;
            best_cost = c;
        }
    }
    // Only a lead that beats every lag is a logging offset: a lag is what a dead time does.
    if best <= 0 {
        return None;
    }
    let best = best as usize;
    // Verified by a replay with the valve columns moved earlier.
    let late_s = best as f64 * dt;
    let shifted = shift_valves(&head, late_s).ok()?;
    let ys = replay(&shifted)?;
    let m = shifted.len();
    let as_logged = cost(&head, &yn, 0..m, &spread);
    let moved = cost(&shifted, &ys, 0..m, &spread);
    (moved <= MAX_COST_SHARE * as_logged).then_some(ValveOffset {
        late_s,
        cost_as_logged: as_logged,
        cost_shifted: moved,
    })
}

/// [`find`] on the head of a recording as read (jittered or gappy: put on its grid).
pub fn find_in(
    nominal: &PlantConfig,
    rec: &Recording,
    opts: &SolverOptions,
) -> Option<ValveOffset> {
    let head = rec.head(SEARCH_SAMPLES + SEARCH_SAMPLES / 10).to_uniform();
    find(nominal, &head, opts)
}
