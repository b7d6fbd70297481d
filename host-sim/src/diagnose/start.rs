//! Where the diagnosis' replays start.
//!
//! A replay starts from the plant file's `[initial]`; a rig log rarely starts there (the rig
//! sits wherever the last run left it), and the first seconds of a replay from the file's
//! state then depart by the start alone. When the recording's first sample is clearly away
//! from the file's state on two channels or more (20 kPa or 3 deg each) and the nominal
//! model replays the recording better from that sample, the replays start from it, as the
//! sensors read it (a sensor calibration the diagnosis fits moves the start with it:
//! `InitialConfig::as_read`). A 3-DOF arm's joints make the same choice against the arm's
//! settled state.
//!
//! Also here: where a fit of a wide-ranging key starts ([`log_grid`]): a key far off the
//! file's value (a joint with 11 times the inertia) is found from a coarse logarithmic grid
//! over its search range, ranked on a short head of the recording, before the local search.

use crate::diagnose::DiagnoseOptions;
use crate::io::recording::{Channel, Recording};
use crate::plant::config::{InitialConfig, PlantConfig};

/// `initial` set to a recording's first sample (`first(channel)`, `None` where the channel is
/// not recorded): the angle, at rest, and the two pressures; the others stay.
pub fn at_first_sample(initial: &mut InitialConfig, first: impl Fn(Channel) -> Option<f64>) {
    if let Some(a) = first(Channel::AngleDeg) {
        initial.angle_rad = a.to_radians();
        initial.velocity_rad_s = 0.0;
    }
    if let Some(p) = first(Channel::P1Kpa) {
        initial.p1_gauge_pa = p * 1e3;
    }
    if let Some(p) = first(Channel::P2Kpa) {
        initial.p2_gauge_pa = p * 1e3;
    }
}

/// `plant` starting from the first sample of `rec` (a 1-DOF recording), as the sensors
/// read it, moving at the angle's initial slope.
pub fn as_recorded(plant: &PlantConfig, rec: &Recording) -> PlantConfig {
    let mut c = plant.clone();
    c.initial.as_read = true;
    at_first_sample(&mut c.initial, |ch| rec.channel(ch).map(|y| y[0]));
    // A recording cut from a moving run starts in motion: the angle's least-squares slope
    // over its first 20 ms (0 for a joint at rest, up to the encoder's quantisation).
    if let Some(a) = rec.channel(Channel::AngleDeg) {
        c.initial.velocity_rad_s = initial_slope(a, rec.sample_period_s()).to_radians();
    }
    c
}

/// Least-squares slope [unit/s] of `y` over its first 20 ms (at least 3 samples; 0 for
/// fewer or a bad sample period).
fn initial_slope(y: &[f64], dt_s: f64) -> f64 {
    let m = ((0.02 / dt_s).round() as usize).max(3).min(y.len());
    if m < 3 || !(dt_s > 0.0) {
        return 0.0;
    }
    let t_mean = (m - 1) as f64 / 2.0;
    let y_mean = y[..m].iter().sum::<f64>() / m as f64;
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for (k, v) in y[..m].iter().enumerate() {
        let dk = k as f64 - t_mean;
        sxy += dk * (v - y_mean);
        sxx += dk * dk;
    }
    sxy / sxx / dt_s
}

/// Cost of `plant`'s replay of `rec`: per recorded channel the mean squared error over the
/// channel's variance, summed (infinite when the replay fails).
pub fn replay_cost(plant: &PlantConfig, rec: &Recording, opts: &DiagnoseOptions) -> f64 {
    let n = rec.len();
    let mut variance = [1.0f64; 5];
    for c in Channel::ALL {
        if let Some(y) = rec.channel(c) {
            let mean = y.iter().sum::<f64>() / n as f64;
            let var = y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n as f64;
            variance[c.index()] = if var > 0.0 { var } else { 1.0 };
        }
    }
    let mut cost = 0.0;
    let ok = crate::sim::measure_each(
        &crate::plant::Plant::from_config(plant),
        &rec.inputs,
        rec.sample_period_s(),
        &opts.solver,
        |k, _, m| {
            for c in Channel::ALL {
                if let Some(y) = rec.channel(c) {
                    cost += (c.of(m) - y[k]).powi(2) / variance[c.index()];
                }
            }
        },
    )
    .is_ok();
    if ok && cost.is_finite() {
        cost / n.max(1) as f64
    } else {
        f64::INFINITY
    }
}

/// `plant` started from `rec`'s first sample ([`as_recorded`]) when the nominal model replays
/// `rec` better from there than from `plant`'s own start; `None` otherwise.
pub fn better_from_recording(
    plant: &PlantConfig,
    rec: &Recording,
    opts: &DiagnoseOptions,
) -> Option<PlantConfig> {
    if rec.is_empty() {
        return None;
    }
    let recorded = as_recorded(plant, rec);
    (replay_cost(&recorded, rec, opts) < replay_cost(plant, rec, opts)).then_some(recorded)
}

/// The 1-DOF diagnosis' start: `nominal` from `train`'s first sample when that sample is
/// away from the file's `[initial]` on two channels or more
/// ([`super::verdict::channels_away_from_initial`]) and the nominal model replays TRAIN
/// better from it; `None`: the file's start. One channel alone away is what a sensor reading
/// off looks like (a gain of 1.06 on p1 reads 583 kPa for 550), which the diagnosis names as
/// a calibration: starting from that reading cost the generated matrix three one-channel
/// gains; a rig that sits elsewhere shows on both pressures, or on the angle with them.
pub fn for_diagnosis(
    nominal: &PlantConfig,
    train: &Recording,
    opts: &DiagnoseOptions,
) -> Option<PlantConfig> {
    if super::verdict::channels_away_from_initial(nominal, train).len() < 2 {
        return None;
    }
    better_from_recording(nominal, train, opts)
}

/// A recalibrated key's search range spanning at least this ratio (hi / lo) is gridded
/// before the local search ([`log_grid`]): the inertia (1/30 .. 30x), the conductances
/// (0.2 .. 5x) and the damping (0 .. 20x); the narrow geometry keys are not.
pub const GRID_MIN_SPAN: f64 = 10.0;
/// A range starting at 0 is gridded from this share of its upper bound.
pub const GRID_ZERO_FLOOR: f64 = 1.0 / 400.0;
/// The best grid point replaces the start when its cost on the head is below this share of
/// the start's (the start stays unless the grid is clearly better: a start near the optimum
/// is the common case, and its fit stays as it was).
pub const GRID_SWITCH: f64 = 0.8;
/// The head the grid is ranked on: this share of the fitted range ...
pub const GRID_HEAD_SHARE: f64 = 1.0 / 3.0;
/// ... but at least this many seconds (or the whole range).
pub const GRID_HEAD_MIN_S: f64 = 1.5;

/// The grid of a one-parameter recalibration whose range spans [`GRID_MIN_SPAN`] or more:
/// about one point per factor 2, log-spaced in the middle of equal cells (never on a bound);
/// `None` for any other candidate.
pub fn log_grid(
    c: &dyn crate::diagnose::candidates::Candidate,
    s: &crate::diagnose::candidates::Setup,
) -> Option<Vec<f64>> {
    if !crate::diagnose::recalibrate::is_recal_id(c.id()) || c.grid(&[], s).is_some() {
        return None;
    }
    let specs = c.params(s);
    let [p] = specs.as_slice() else {
        return None;
    };
    if !(p.hi.is_finite() && p.hi > 0.0 && p.lo >= 0.0) {
        return None;
    }
    let lo = if p.lo > 0.0 {
        p.lo
    } else {
        p.hi * GRID_ZERO_FLOOR
    };
    let span = p.hi / lo;
    if !(span >= GRID_MIN_SPAN) {
        return None;
    }
    let n = (span.log2().ceil() as usize).clamp(4, 12);
    Some(
        (0..n)
            .map(|j| lo * span.powf((j as f64 + 0.5) / n as f64))
            .collect(),
    )
}

/// The head of `range` a grid is ranked on ([`GRID_HEAD_SHARE`], [`GRID_HEAD_MIN_S`]).
pub fn grid_head(range: &std::ops::Range<usize>, dt_s: f64) -> std::ops::Range<usize> {
    let min = (GRID_HEAD_MIN_S / dt_s.max(1e-9)).round() as usize;
    let len = ((range.len() as f64 * GRID_HEAD_SHARE) as usize)
        .max(min)
        .min(range.len());
    range.start..range.start + len
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::candidates::Setup;

    #[test]
    fn wide_keys_get_a_log_grid_inside_their_range_and_narrow_ones_none() {
        let nominal = PlantConfig::reference();
        let s = Setup {
            dt_s: 1e-3,
            present: [true; 5],
        };
        let pool = crate::diagnose::recalibrate::candidates(&nominal);
        let grid = |id: &str| log_grid(pool.iter().find(|c| c.id() == id).unwrap().as_ref(), &s);
        let g = grid("joint.inertia_kgm2").unwrap();
        let (lo, hi) = (0.014 / 30.0, 0.014 * 30.0);
        assert!(
            g.len() >= 8 && g.iter().all(|v| *v > lo && *v < hi),
            "{g:?}"
        );
        // 11 times the file's inertia lies within a factor 1.5 of a grid point.
        assert!(g
            .iter()
            .any(|v| (v / (11.0 * 0.014)).ln().abs() < 1.5f64.ln()));
        assert!(grid("muscle.damping_m2s").is_some());
        assert!(grid("valve.sonic_conductance_m3_per_s_pa").is_some());
        assert!(grid("muscle.radius_m").is_none());
        assert!(grid("environment.supply_gauge_pa").is_none());
        assert_eq!(grid_head(&(0..9000), 1e-3), 0..3000);
        assert_eq!(grid_head(&(100..1100), 1e-3), 100..1100);
    }
}
