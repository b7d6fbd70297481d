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
