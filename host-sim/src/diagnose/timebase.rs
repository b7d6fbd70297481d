//! What the diagnosis does with a recording's time base: rows filled in a gap of the log
//! ([`crate::io::timebase`]) are replayed (the plant ran through them) but left out of the
//! spread and noise of every channel, as they are left out of every cost and fit.

use crate::io::recording::{Channel, Recording};
use crate::io::timebase::MeasuredRows;
use crate::signal::{noise_level, noise_level_where};

/// The spread (standard deviation, 1 for a constant channel) and the noise level
/// ([`noise_level`]) of every channel of `rec` over its measured rows (absent channels:
/// spread 1, noise 0).
pub fn spread_and_noise(rec: &Recording) -> ([f64; 5], [f64; 5]) {
    let rows = MeasuredRows::of(rec);
    let n = rows.count(0..rec.len());
    let mut spread = [1.0; 5];
    let mut noise = [0.0; 5];
    for c in Channel::ALL {
        if let Some(y) = rec.channel(c) {
            let mean = rows.values(y).sum::<f64>() / n as f64;
            let sd = (rows.values(y).map(|v| (v - mean).powi(2)).sum::<f64>() / n as f64).sqrt();
            spread[c.index()] = if sd > 0.0 { sd } else { 1.0 };
            noise[c.index()] = if rows.any_filled() {
                noise_level_where(y, |k| rows.has(k))
            } else {
                noise_level(y)
            };
        }
    }
    (spread, noise)
}

/// Measured rows after a gap (fewer when the next gap comes first) whose mean pressure the
/// gap's openings are fitted to: on the tuning seeds of the independent rig's gappy nominal
/// recordings, 5, 20 and 40 rows left 2.07, 1.99 and 1.67 times the noise on the angle.
pub const GAP_MATCH_ROWS: usize = 40;

/// The valve openings over the rows filled in a gap of `rec`'s log, estimated from the
/// pressures after the gap: the logger lost the commands, the plant kept running, and with
/// the valves shut between commands (a controller's deadband) the air that went in or out
/// during the gap stays. Muscle by muscle, one signed opening (inlet above 0, exhaust below)
/// held over the gap is found by bisection on the model `cfg` replayed from its state before
/// the gap, such that the mean pressure over the next [`GAP_MATCH_ROWS`] measured rows is
/// the measured one (averaged, so the noise of one row does not set it). Recordings without
/// both pressure channels, or without gaps, are returned as they are (the last logged
/// opening held). `None` when the replay fails.
pub fn openings_over_gaps(
    cfg: &crate::plant::config::PlantConfig,
    rec: &Recording,
    opts: &crate::sim::SolverOptions,
) -> Option<Recording> {
    use crate::plant::{Plant, ValveInputs};
    use crate::sim::Integrator;
    let rows = MeasuredRows::of(rec);
    let (Some(p1), Some(p2)) = (rec.channel(Channel::P1Kpa), rec.channel(Channel::P2Kpa)) else {
        return None;
    };
    if !rows.any_filled() {
        return None;
    }
    let n = rec.len();
    let dt = rec.sample_period_s();
    let plant = Plant::from_config(cfg);
    let measured = [p1, p2];
    let mut inputs = rec.inputs.clone();
    let mut integ = Integrator::new(&plant, plant.initial_state(), *opts);
    let runs = rows.runs(n);
    // Replays rows `from..to` with `inputs` from `integ`; the mean simulated pressure
    // (kPa) of each muscle over the measured rows in `window`.
    let mean_p = |integ: &Integrator,
                  inputs: &[ValveInputs],
                  from: usize,
                  window: &std::ops::Range<usize>| {
        let mut it = integ.clone();
        let mut sum = [0.0f64; 2];
        for (k, u) in inputs.iter().enumerate().take(window.end).skip(from) {
            if window.contains(&k) {
                let m = plant.measure(&it.state());
                sum[0] += Channel::P1Kpa.of(&m);
                sum[1] += Channel::P2Kpa.of(&m);
            }
            it.advance_samples(*u, dt, 1, |_| {}).ok()?;
        }
        Some(sum.map(|s| s / window.len().max(1) as f64))
    };
    let mut k = 0usize;
    for (r, run) in runs.iter().enumerate() {
        // Replay up to the end of this run of measured rows.
        while k < run.end {
            integ.advance_samples(inputs[k], dt, 1, |_| {}).ok()?;
            k += 1;
        }
        let Some(next) = runs.get(r + 1) else { break };
        // The gap run.end..next.start; matched over the first rows of the next run.
        let gap = run.end..next.start;
        let window = next.start..(next.start + GAP_MATCH_ROWS).min(next.end);
        let target = [0, 1]
            .map(|i| measured[i][window.clone()].iter().sum::<f64>() / window.len().max(1) as f64);
        let mut signed = [0.0f64; 2];
        let set = |inputs: &mut Vec<ValveInputs>, s: [f64; 2]| {
            for u in &mut inputs[gap.clone()] {
                *u = ValveInputs {
                    u_in1: s[0].max(0.0),
                    u_ex1: (-s[0]).max(0.0),
                    u_in2: s[1].max(0.0),
                    u_ex2: (-s[1]).max(0.0),
                };
            }
        };
        for _pass in 0..2 {
            for i in 0..2 {
                let (mut lo, mut hi) = (-1.0f64, 1.0f64);
                for _ in 0..14 {
                    let mid = 0.5 * (lo + hi);
                    signed[i] = mid;
                    set(&mut inputs, signed);
                    let p = mean_p(&integ, &inputs, gap.start, &window)?;
                    if p[i] < target[i] {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                signed[i] = 0.5 * (lo + hi);
            }
        }
        set(&mut inputs, signed);
    }
    let mut out = rec.clone();
    out.inputs = inputs;
    Some(out)
}

/// One pass of the diagnosis ([`super::diagnose_pass`]): the openings over the gaps
/// estimated on the model given (the nominal one when `None`).
pub(crate) type Pass =
    fn(
        &crate::plant::config::PlantConfig,
        &Recording,
        Option<&Recording>,
        &super::DiagnoseOptions,
        &(dyn Fn(u64, u64, &str) + Sync),
        Option<&crate::plant::config::PlantConfig>,
    ) -> Result<(super::Diagnosis, crate::plant::config::PlantConfig), super::DiagnoseError>;

/// Passes at most of [`diagnose_through_gaps`].
pub const GAP_PASSES: usize = 3;

/// The diagnosis of a recording whose log dropped rows: the openings over its gaps are
/// estimated on a model ([`openings_over_gaps`]), first the nominal one; when a pass's best
/// attempt is another model (a key off, an effect), the openings are estimated again on
/// that model and the diagnosis run again, until the best attempt stays the same (at most
/// [`GAP_PASSES`] passes). A nominal model far off (a load 4 times the file's inertia)
/// estimates the air that went in during a gap wrongly, and the model that fits is then
/// judged on openings that were never there. A recording without gaps takes one pass.
pub fn diagnose_through_gaps(
    nominal: &crate::plant::config::PlantConfig,
    train: &Recording,
    check: Option<&Recording>,
    opts: &super::DiagnoseOptions,
    progress: &(dyn Fn(u64, u64, &str) + Sync),
    pass: Pass,
) -> Result<super::Diagnosis, super::DiagnoseError> {
    let gappy =
        |r: &Recording| !r.is_uniform() && crate::io::timebase::Grid::of(&r.t_s).filled() > 0;
    let (mut d, mut model) = pass(nominal, train, check, opts, progress, None)?;
    if !(gappy(train) || check.is_some_and(gappy)) {
        return Ok(d);
    }
    for _ in 1..GAP_PASSES {
        if d.best_attempt.is_empty() {
            break;
        }
        let (d2, model2) = pass(nominal, train, check, opts, progress, Some(&model))?;
        let same = d2.best_attempt == d.best_attempt;
        (d, model) = (d2, model2);
        if same {
            break;
        }
    }
    Ok(d)
}
