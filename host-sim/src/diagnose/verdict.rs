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
//!   [`MIN_HELDOUT_FIT_PCT`], or it makes the CHECK recording's fit worse on a channel (by
//!   more than [`MAX_CHECK_FIT_LOSS_PCT`] points: the correction did not hold there), or
//!   nothing was accepted: no effect is named.
//! - `not_this_plant`: the recording does not look like this plant at all (the nominal model
//!   fits no channel, or a plausibility check on the units and the channel mapping fires):
//!   no effect is named and the likely cause is pointed at.
//!
//! - `partly_explained`: named items each earned their place on held-out data and remove
//!   most of the mismatch, but what remains is above the noise floor: the remaining
//!   mismatch is located (channel, windows, regime), not named.
//!
//! The CLI exits with status 0 on `explained` and `nothing_missing`, 4 on
//! `partly_explained`, 3 on `unexplained` and `not_this_plant` (the JSON is written in every
//! case), 2 on bad input.

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

pub use crate::signal::MAX_RESIDUAL_X_NOISE;

/// A correction that lowers a channel's fit on the CHECK recording by more than this (in
/// percentage points) did not hold there: the verdict is `unexplained`.
pub const MAX_CHECK_FIT_LOSS_PCT: f64 = 2.0;

/// The channels whose CHECK fit the correction lowered by more than
/// [`MAX_CHECK_FIT_LOSS_PCT`] ("p1_kpa 100.0 % -> 82.8 %"), or `None` when it held (a NaN
/// after the correction counts as lost).
pub fn check_not_held(
    before: &std::collections::BTreeMap<&'static str, f64>,
    after: &std::collections::BTreeMap<&'static str, f64>,
) -> Option<String> {
    channels_where(
        before,
        after,
        |b, a| !(a >= b - MAX_CHECK_FIT_LOSS_PCT),
        |k, b, a| format!("{k} {b:.1} % -> {a:.1} %"),
    )
}

/// The channels `k` of `a` (with a finite value in `a` and `b`'s value, NaN where `b` has
/// none) for which `keep(a[k], b[k])` holds, each as `show(k, a[k], b[k])`, joined by
/// commas; `None` when there is none.
fn channels_where(
    a: &std::collections::BTreeMap<&'static str, f64>,
    b: &std::collections::BTreeMap<&'static str, f64>,
    keep: impl Fn(f64, f64) -> bool,
    show: impl Fn(&str, f64, f64) -> String,
) -> Option<String> {
    let listed: Vec<String> = a
        .iter()
        .filter_map(|(k, x)| {
            let y = b.get(k).copied().unwrap_or(f64::NAN);
            (x.is_finite() && keep(*x, y)).then(|| show(k, *x, y))
        })
        .collect();
    (!listed.is_empty()).then(|| listed.join(", "))
}

/// A check recording channel whose nominal fit is this many points below the training
/// recording's, when the nominal model explains the training recording within its noise,
/// departs: the model does not describe the check run, and "nothing is missing" would be
/// said of the training run alone. (A check of other excitation fits a few points lower by
/// its spread and noise alone.)
pub const CHECK_DEPARTS_PCT: f64 = 10.0;

/// The channels of the check recording the nominal model does not describe
/// ([`CHECK_DEPARTS_PCT`] below the training fit), "angle_deg 45.5 % (training 99.9 %)";
/// `None` when every channel holds.
pub fn check_departs(
    train: &std::collections::BTreeMap<&'static str, f64>,
    check: &std::collections::BTreeMap<&'static str, f64>,
) -> Option<String> {
    // A channel whose fit is undefined (NaN: a constant reference) is not judged.
    channels_where(
        check,
        train,
        |c, t| t.is_finite() && c < t - CHECK_DEPARTS_PCT,
        |k, c, t| format!("{k} {c:.1} % (training {t:.1} %)"),
    )
}

/// The kind of answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    Explained,
    /// Named items that each earned their place on held-out data and remove most of the
    /// mismatch, but leave more than the noise: the rest is located, not named.
    PartlyExplained,
    NothingMissing,
    Unexplained,
    NotThisPlant,
}

impl Verdict {
    /// The JSON value.
    pub fn as_str(self) -> &'static str {
        match self {
            Verdict::Explained => "explained",
            Verdict::PartlyExplained => "partly_explained",
            Verdict::NothingMissing => "nothing_missing",
            Verdict::Unexplained => "unexplained",
            Verdict::NotThisPlant => "not_this_plant",
        }
    }

    /// Whether the answer is complete: explained, or nothing is missing (the CLI exits 0).
    pub fn is_answer(self) -> bool {
        matches!(self, Verdict::Explained | Verdict::NothingMissing)
    }

    /// Whether the answer names effects or recalibrated keys (explained, partly explained).
    pub fn names_items(self) -> bool {
        matches!(self, Verdict::Explained | Verdict::PartlyExplained)
    }

    /// The command line's exit status: 0 explained or nothing missing, 4 partly explained,
    /// 3 unexplained or not this plant (2 is bad input, before any verdict).
    pub fn exit_status(self) -> u8 {
        match self {
            Verdict::Explained | Verdict::NothingMissing => 0,
            Verdict::PartlyExplained => 4,
            Verdict::Unexplained | Verdict::NotThisPlant => 3,
        }
    }
}

/// The fit (in %) of a channel over `samples` samples from the sum, in sample order, of
/// `(predicted - y)^2` over them, its error normalised by `spread` (the whole recording's
/// standard deviation, so a short tail where a channel barely moves is not judged by its own
/// tiny spread).
pub fn fit_vs_spread_of_sum(sum_sq: f64, samples: usize, spread: f64) -> f64 {
    let mse = sum_sq / samples.max(1) as f64;
    100.0 * (1.0 - mse.sqrt() / spread.max(1e-300))
}

/// How many times its noise the error a model leaves on its worst channel is: per channel
/// `(1 - fit/100)` (the error's rms over the spread) over `noise / spread` (at least
/// [`FIT_FLOOR_REL`]), the largest over the channels of `fits`; with the channel's name.
pub fn residual_over_noise(
    fits: &std::collections::BTreeMap<&'static str, f64>,
    noise: &[f64; 5],
    spread: &[f64; 5],
) -> (f64, &'static str) {
    let mut worst = (0.0, "");
    for c in Channel::ALL {
        let Some(fit) = fits.get(c.name()) else {
            continue;
        };
        let rel_err = 1.0 - fit / 100.0;
        let noise_rel = (noise[c.index()] / spread[c.index()]).max(FIT_FLOOR_REL);
        let x = rel_err / noise_rel;
        // NaN (a failed replay) is the worst.
        if !(x <= worst.0) {
            worst = (x, c.name());
        }
    }
    worst
}

/// What the plausibility checks read of the nominal simulation, summed sample by sample
/// while it runs (so the simulation need not be held): per channel its largest value and,
/// against the measured channels, the error sums of the straight, crossed (`p1` <-> `p2`,
/// `f1` <-> `f2`), sign-flipped and radian readings, each in sample order (the sums of
/// `fit_percent` to the bit).
#[derive(Debug, Clone)]
pub struct PlausibilitySums {
    /// Largest value of every simulated channel (`f64::max` over the samples).
    nominal_max: [f64; 5],
    /// Sum of `(y_c - sim_c)^2` per measured channel `c`.
    straight_err2: [f64; 5],
    /// Sum of `(y_c - sim_pair(c))^2` for the pressure and force pairs.
    crossed_err2: [f64; 5],
    /// The angle against the simulated angle with its sign flipped.
    angle_flipped_err2: f64,
    /// The angle read as radians (converted to degrees) against the simulated angle.
    angle_as_rad_err2: f64,
    /// Per measured channel: `sum y sim`, `sum sim^2` and `sum y^2` (the least-squares scale
    /// of the measured channel on the simulated one, and the error it leaves).
    scale_sums: [[f64; 3]; 5],
}

/// Pressure units a logger may write that a `*_kpa` column reads as kPa: (name, kPa per
/// unit, as written in a message). Logged in `unit`, the column reads `1 / kpa_per_unit`
/// times the pressure in kPa.
pub const PRESSURE_UNITS_READ_AS_KPA: [(&str, f64, &str); 4] = [
    ("Pa", 1e-3, "0.001"),
    ("psi", 6.894_757_293_168, "6.895"),
    ("bar", 100.0, "100"),
    ("MPa", 1000.0, "1000"),
];

/// A measured pressure whose least-squares scale on the nominal one lies within this
/// relative distance of a unit's (and whose scaled fit is good) is named as that unit.
pub const PRESSURE_UNIT_SCALE_TOLERANCE: f64 = 0.2;

/// The other muscle's channel of a pressure or force channel (`None` for the angle).
fn pair_of(c: Channel) -> Option<Channel> {
    match c {
        Channel::P1Kpa => Some(Channel::P2Kpa),
        Channel::P2Kpa => Some(Channel::P1Kpa),
        Channel::F1N => Some(Channel::F2N),
        Channel::F2N => Some(Channel::F1N),
        Channel::AngleDeg => None,
    }
}

impl Default for PlausibilitySums {
    fn default() -> Self {
        Self {
            nominal_max: [f64::NEG_INFINITY; 5],
            straight_err2: [0.0; 5],
            crossed_err2: [0.0; 5],
            angle_flipped_err2: 0.0,
            angle_as_rad_err2: 0.0,
            scale_sums: [[0.0; 3]; 5],
        }
    }
}

impl PlausibilitySums {
    /// Adds sample `k` of `rec` with its simulated channels `m` (samples in order from 0).
    pub fn push(&mut self, rec: &Recording, k: usize, m: &Measurement) {
        let sq = |a: f64, b: f64| (a - b) * (a - b);
        for c in Channel::ALL {
            let i = c.index();
            self.nominal_max[i] = self.nominal_max[i].max(c.of(m));
            let Some(y) = rec.channel(c) else { continue };
            let a = y[k];
            self.straight_err2[i] += sq(a, c.of(m));
            self.scale_sums[i][0] += a * c.of(m);
            self.scale_sums[i][1] += c.of(m) * c.of(m);
            self.scale_sums[i][2] += a * a;
            if let Some(p) = pair_of(c) {
                self.crossed_err2[i] += sq(a, p.of(m));
            } else {
                self.angle_flipped_err2 += sq(a, -c.of(m));
                self.angle_as_rad_err2 += sq(a.to_degrees(), c.of(m));
            }
        }
    }

    /// The sums of a simulation that is held.
    pub fn of(rec: &Recording, sim: &[Measurement]) -> Self {
        let mut s = Self::default();
        sim.iter().enumerate().for_each(|(k, m)| s.push(rec, k, m));
        s
    }
}

/// Plausibility checks of a recording against the nominal simulation of the same inputs
/// (its sums, [`PlausibilitySums`]): each message names a likely cause (units, channel
/// mapping, plant file).
pub fn plausibility_hints(
    nominal: &PlantConfig,
    rec: &Recording,
    sums: &PlausibilitySums,
) -> Vec<String> {
    let mut hints = Vec::new();
    let supply_kpa = nominal.environment.supply_gauge_pa / 1000.0;
    let p_atm_kpa = nominal.environment.p_atm_pa / 1000.0;
    let fit_of = |y: &[f64], err2: f64| fit_percent_by(|| y.iter().copied(), err2);
    let straight_of = |y: &[f64], c: Channel| fit_of(y, sums.straight_err2[c.index()]);
    let crossed_of = |y: &[f64], c: Channel| fit_of(y, sums.crossed_err2[c.index()]);
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
        if let Some(h) = pressure_unit_hint(c, y, sums) {
            hints.push(h);
            continue;
        }
        let nom_hi = sums.nominal_max[c.index()];
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
        let straight = straight_of(ya, a).min(straight_of(yb, b));
        let crossed = crossed_of(ya, a).min(crossed_of(yb, b));
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
        let straight = straight_of(y, Channel::AngleDeg);
        let flipped = fit_of(y, sums.angle_flipped_err2);
        if flipped > straight + 30.0 && flipped > 30.0 {
            hints.push(format!(
                "angle_deg fits the model {flipped:.0} % with its sign flipped and {straight:.0} % as recorded: check the angle sign convention (muscle 1 contracts when the angle grows)"
            ));
        }
        let as_rad = fit_percent_by(|| y.iter().map(|v| v.to_degrees()), sums.angle_as_rad_err2);
        if as_rad > straight + 30.0 && as_rad > 30.0 {
            hints.push(format!(
                "angle_deg fits the model {as_rad:.0} % read as radians and {straight:.0} % as degrees: check the angle unit"
            ));
        }
    }
    hints
}

/// A pressure channel `y` that is the nominal simulation's times the factor of another unit
/// read as kPa ([`PRESSURE_UNITS_READ_AS_KPA`]: psi, bar, MPa, Pa), within
/// [`PRESSURE_UNIT_SCALE_TOLERANCE`], and fits the model far better so scaled than as
/// recorded: the hint naming the unit and the fix.
fn pressure_unit_hint(c: Channel, y: &[f64], sums: &PlausibilitySums) -> Option<String> {
    let [ys, ss, yy] = sums.scale_sums[c.index()];
    if !(ss > 0.0) {
        return None;
    }
    let scale = ys / ss;
    let straight = fit_percent_by(|| y.iter().copied(), sums.straight_err2[c.index()]);
    let scaled_err2 = (yy - 2.0 * scale * ys + scale * scale * ss).max(0.0);
    let scaled = fit_percent_by(|| y.iter().copied(), scaled_err2);
    if !(scaled > 50.0 && scaled > straight + 30.0) {
        return None;
    }
    let (unit, _, kpa_per_unit) = PRESSURE_UNITS_READ_AS_KPA
        .into_iter()
        .find(|(_, k, _)| (scale * k - 1.0).abs() <= PRESSURE_UNIT_SCALE_TOLERANCE)?;
    Some(format!(
        "{} reads {scale:.4} times the nominal model's pressure (it fits the model {scaled:.0} % so \
         scaled and {straight:.0} % as recorded): pressures logged in {unit} and read as kPa? \
         (1 {unit} = {kpa_per_unit} kPa): map the column with `unit = \"{unit}\"` in `host-sim \
         import`, or convert it to kPa gauge",
        c.name()
    ))
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
    fn the_residual_is_counted_in_noise_levels_on_the_worst_channel() {
        let mut fits = std::collections::BTreeMap::new();
        fits.insert("angle_deg", 78.9);
        fits.insert("p1_kpa", 99.0);
        let spread = [1.0; 5];
        // Noise-free angle: the floor (0.2 % of the spread) is its noise: 0.211 / 0.002.
        let mut noise = [0.0; 5];
        noise[Channel::P1Kpa.index()] = 0.01;
        let (x, c) = residual_over_noise(&fits, &noise, &spread);
        assert_eq!(c, "angle_deg");
        assert!((x - 105.5).abs() < 1e-9, "{x}");
        // A noisy angle at its noise level is within the limit.
        noise[Channel::AngleDeg.index()] = 0.2;
        let (x, _) = residual_over_noise(&fits, &noise, &spread);
        assert!(x <= MAX_RESIDUAL_X_NOISE, "{x}");
        // A failed replay (NaN fit) is the worst.
        fits.insert("p2_kpa", f64::NAN);
        assert_eq!(residual_over_noise(&fits, &noise, &spread).1, "p2_kpa");
    }

    #[test]
    fn verdict_strings_and_exit_kind() {
        assert_eq!(Verdict::NotThisPlant.as_str(), "not_this_plant");
        assert!(Verdict::NothingMissing.is_answer());
        assert!(!Verdict::Unexplained.is_answer());
    }

    /// The streamed sums give the fits of `fit_percent` on copied (crossed, flipped,
    /// converted) series to the bit.
    #[test]
    fn plausibility_sums_are_those_of_fit_percent() {
        use crate::fit::fit_percent;
        let n = 500;
        let sim: Vec<Measurement> = (0..n)
            .map(|k| {
                let t = k as f64 * 1e-2;
                Measurement {
                    angle_deg: 10.0 * t.sin(),
                    p1_kpa: 200.0 + 50.0 * (1.3 * t).cos(),
                    p2_kpa: 180.0 - 40.0 * (0.7 * t).sin(),
                    f1_n: 90.0 * (0.3 * t).cos(),
                    f2_n: 70.0 + t,
                }
            })
            .collect();
        let mut rec = Recording {
            metadata: Vec::new(),
            t_s: (0..n).map(|k| k as f64 * 1e-2).collect(),
            inputs: vec![crate::plant::ValveInputs::CLOSED; n],
            outputs: Default::default(),
            mass_flow_kg_s: None,
        };
        for c in Channel::ALL {
            let y: Vec<f64> = sim
                .iter()
                .enumerate()
                .map(|(k, m)| 1.1 * c.of(m) + ((k * 7919) % 13) as f64 * 0.01)
                .collect();
            rec.set_channel(c, y);
        }
        let s = PlausibilitySums::of(&rec, &sim);
        let col = |c: Channel, f: &dyn Fn(f64) -> f64| -> Vec<f64> {
            sim.iter().map(|m| f(c.of(m))).collect()
        };
        let fit = |err2: f64, y: &[f64]| crate::fit::fit_percent_of_err2(y, err2).to_bits();
        for c in Channel::ALL {
            let y = rec.channel(c).unwrap();
            let own = fit_percent(y, &col(c, &|v| v));
            assert_eq!(fit(s.straight_err2[c.index()], y), own.to_bits());
            if let Some(p) = pair_of(c) {
                let crossed = fit_percent(y, &col(p, &|v| v));
                assert_eq!(fit(s.crossed_err2[c.index()], y), crossed.to_bits());
            }
            let hi = col(c, &|v| v).into_iter().fold(f64::NEG_INFINITY, f64::max);
            assert_eq!(s.nominal_max[c.index()], hi);
        }
        let y = rec.channel(Channel::AngleDeg).unwrap();
        let flipped = fit_percent(y, &col(Channel::AngleDeg, &|v| -v));
        assert_eq!(fit(s.angle_flipped_err2, y), flipped.to_bits());
        let y_deg: Vec<f64> = y.iter().map(|v| v.to_degrees()).collect();
        let as_rad = fit_percent(&y_deg, &col(Channel::AngleDeg, &|v| v));
        assert_eq!(fit(s.angle_as_rad_err2, &y_deg), as_rad.to_bits());
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

/// Sample periods from which on/off valve openings are too coarse to describe a valve that
/// switches faster (a PWM at the firmware's rate) [s].
pub const COARSE_ONOFF_DT_S: f64 = 0.005;

/// A note when the valve openings are on/off values sampled every [`COARSE_ONOFF_DT_S`] or
/// more: a valve that switches between two samples (PWM) is then not described by them,
/// and no plant model can replay it (the nominal one included).
pub fn coarse_onoff_note(rec: &Recording) -> Option<String> {
    let dt_s = rec.sample_period_s();
    let on_off = |u: f64| u == 0.0 || u == 1.0;
    let all_on_off = rec
        .inputs
        .iter()
        .all(|u| on_off(u.u_in1) && on_off(u.u_ex1) && on_off(u.u_in2) && on_off(u.u_ex2));
    (dt_s >= COARSE_ONOFF_DT_S && all_on_off).then(|| {
        format!(
            "the valve openings are on/off values sampled every {} ms: a valve that switches \
             between two samples (PWM) is not described by them; record the openings at the \
             valves' switching rate, or time-averaged over each sample",
            crate::validate::Shown(1e3 * dt_s)
        )
    })
}

/// A note when one of the channels every rig has (angle, p1, p2) was not recorded: the
/// answer says nothing about it.
pub fn unrecorded_note(rec: &Recording) -> Option<String> {
    let missing: Vec<&str> = [Channel::AngleDeg, Channel::P1Kpa, Channel::P2Kpa]
        .into_iter()
        .filter(|c| rec.channel(*c).is_none())
        .map(|c| c.name())
        .collect();
    (!missing.is_empty()).then(|| {
        format!(
            "{} not recorded: the answer says nothing about {}",
            missing.join(", "),
            if missing.len() == 1 { "it" } else { "them" }
        )
    })
}

/// A fitted pressure offset within this of the atmosphere (either sign) is the atmosphere:
/// pressures logged absolute (or the offset of a gauge column subtracted twice) [kPa].
pub const ABSOLUTE_OFFSET_WITHIN_KPA: f64 = 5.0;

/// A note when a named sensor offset on a pressure channel is the atmosphere
/// (+-`environment.p_atm_pa`, within [`ABSOLUTE_OFFSET_WITHIN_KPA`]): the columns were
/// logged absolute, not gauge, and the "offset" is a unit of reference, not a sensor fault.
pub fn absolute_pressure_note(
    plant: &PlantConfig,
    effects: &[crate::diagnose::NamedEffect],
) -> Option<String> {
    let p_atm_kpa = plant.environment.p_atm_pa * 1e-3;
    let hits: Vec<String> = effects
        .iter()
        .filter(|e| e.id == "sensor_offset")
        .flat_map(|e| e.params.iter())
        .filter(|(name, v)| {
            matches!(name.as_str(), "p1_offset_kpa" | "p2_offset_kpa")
                && (v.abs() - p_atm_kpa).abs() <= ABSOLUTE_OFFSET_WITHIN_KPA
        })
        .map(|(name, v)| format!("{name} {v:+.1} kPa"))
        .collect();
    (!hits.is_empty()).then(|| {
        format!(
            "the fitted pressure offset ({}) is the atmosphere ({p_atm_kpa:.3} kPa): {}",
            hits.join(", "),
            crate::io::import::ABSOLUTE_PRESSURE_HINT
        )
    })
}

/// How far a recording's first sample may sit from the plant file's `[initial]` before the
/// answer notes it: pressures (kPa) and angle (deg), well above a sensor's noise and the
/// offsets the diagnosis names as calibrations.
const START_NOTE_KPA: f64 = 20.0;
const START_NOTE_DEG: f64 = 3.0;

/// The recorded channels whose first sample sits away from the plant file's `[initial]`
/// (more than 20 kPa or 3 deg), each as "channel value (`initial.key`: value)"; empty for a
/// start given as readings (`as_read`) or an empty recording.
pub fn channels_away_from_initial(
    plant: &crate::plant::config::PlantConfig,
    rec: &Recording,
) -> Vec<String> {
    if plant.initial.as_read || rec.is_empty() {
        return Vec::new();
    }
    let i = &plant.initial;
    let mut off = Vec::new();
    let mut check = |c: Channel, key: &str, file: f64, tol: f64, unit: &str| {
        if let Some(y) = rec.channel(c) {
            if (y[0] - file).abs() > tol {
                off.push(format!(
                    "{} {} {unit} (`initial.{key}`: {} {unit})",
                    c.name(),
                    crate::validate::Shown(y[0]),
                    crate::validate::Shown(file)
                ));
            }
        }
    };
    check(
        Channel::AngleDeg,
        "angle_rad",
        i.angle_rad.to_degrees(),
        START_NOTE_DEG,
        "deg",
    );
    check(
        Channel::P1Kpa,
        "p1_gauge_pa",
        i.p1_gauge_pa * 1e-3,
        START_NOTE_KPA,
        "kPa",
    );
    check(
        Channel::P2Kpa,
        "p2_gauge_pa",
        i.p2_gauge_pa * 1e-3,
        START_NOTE_KPA,
        "kPa",
    );
    off
}

/// A note when the recording does not start where the plant file's `[initial]` says: a rig
/// log rarely starts at the file's state, and the departure of the first seconds is then the
/// start's, not the model's. `started_from_recording`: the replays started from the
/// recording's first sample ([`super::start`]); otherwise from the file's values.
pub fn start_note(
    plant: &crate::plant::config::PlantConfig,
    rec: &Recording,
    started_from_recording: bool,
) -> Option<String> {
    channels_away_from_initial_joined(plant, rec).map(|off| {
        if started_from_recording {
            format!(
                "the recording does not start where the plant file's [initial] says: {off}; \
                 the nominal model replays it better from its first sample, so every replay \
                 (and a check recording's, from its own first sample) starts there, as the \
                 sensors read it"
            )
        } else {
            format!(
                "the recording does not start where the plant file's [initial] says: {off}; \
                 the replays start from the file's values, so the first seconds depart by the \
                 start alone: set [initial] to the rig's first sample (angle in rad, pressures \
                 in Pa gauge)"
            )
        }
    })
}

/// A note when the check recording starts away from the plant file's `[initial]`: from
/// where it was replayed, and that a check cut from a moving run replays only as well as its
/// start is known.
pub fn check_start_note(
    plant: &crate::plant::config::PlantConfig,
    check: &Recording,
    started_from_recording: bool,
) -> Option<String> {
    let from = if started_from_recording {
        "its own first sample (the velocity from the angle over its first 20 ms)"
    } else {
        "the file's values"
    };
    channels_away_from_initial_joined(plant, check).map(|off| {
        format!(
            "the check recording does not start where the plant file's [initial] says: {off}; \
             it was replayed from {from}. A check cut from the middle of a run replays only as \
             well as that start is known (the chambers' temperature and the valves' history \
             are not recorded): cut it where the joint rests, or record it from its own start"
        )
    })
}

/// [`channels_away_from_initial`] joined for a sentence, `None` when none is away.
fn channels_away_from_initial_joined(
    plant: &crate::plant::config::PlantConfig,
    rec: &Recording,
) -> Option<String> {
    let off = channels_away_from_initial(plant, rec);
    (!off.is_empty()).then(|| off.join(", "))
}

#[cfg(test)]
mod coarse_tests {
    use super::*;

    fn rec(dt_s: f64, opening: f64) -> Recording {
        let mut t = String::from("t_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg\n");
        for k in 0..10 {
            let u = if k % 2 == 0 { opening } else { 0.0 };
            t += &format!("{},{u},0,0,{u},0\n", k as f64 * dt_s);
        }
        Recording::parse(&t, "r.csv").unwrap()
    }

    #[test]
    fn channels_a_rig_always_has_are_noted_when_not_recorded() {
        // Only the angle was recorded.
        let note = unrecorded_note(&rec(0.001, 0.4)).expect("p1, p2 missing");
        assert_eq!(
            note,
            "p1_kpa, p2_kpa not recorded: the answer says nothing about them"
        );
        let full = Recording::parse(
            "t_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg,p1_kpa,p2_kpa\n0,0,0,0,0,0,1,1\n0.001,0,0,0,0,0,1,1\n",
            "r.csv",
        )
        .unwrap();
        assert!(unrecorded_note(&full).is_none());
    }

    #[test]
    fn coarse_on_off_openings_are_noted_and_fine_or_averaged_ones_are_not() {
        let note = coarse_onoff_note(&rec(0.01, 1.0)).expect("10 ms on/off");
        assert!(note.contains("every 10 ms"), "{note}");
        assert!(coarse_onoff_note(&rec(0.001, 1.0)).is_none());
        assert!(coarse_onoff_note(&rec(0.01, 0.4)).is_none());
    }

    #[test]
    fn a_recording_that_starts_away_from_the_files_initial_state_is_noted() {
        let text = include_str!("../../tests/fixtures/reference-1dof.toml");
        let plant = crate::plant::config::PlantConfig::from_toml_str(text, "p.toml").unwrap();
        let i = &plant.initial;
        let rec = |dp_kpa: f64| {
            let row = |t: f64| {
                format!(
                    "{t},0,0,0,0,{},{},{}\n",
                    i.angle_rad.to_degrees(),
                    i.p1_gauge_pa * 1e-3 + dp_kpa,
                    i.p2_gauge_pa * 1e-3
                )
            };
            let t = String::from("t_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg,p1_kpa,p2_kpa\n");
            Recording::parse(&(t + &row(0.0) + &row(0.001)), "r.csv").unwrap()
        };
        assert!(start_note(&plant, &rec(0.0), false).is_none());
        assert!(
            start_note(&plant, &rec(8.0), false).is_none(),
            "a sensor offset's size"
        );
        let note = start_note(&plant, &rec(-100.0), false).expect("100 kPa below the file's start");
        assert!(
            note.contains("p1_kpa") && note.contains("initial.p1_gauge_pa"),
            "{note}"
        );
        assert!(!note.contains("p2_kpa"), "{note}");
        // The check recording's own note says from where it was replayed.
        assert!(check_start_note(&plant, &rec(0.0), true).is_none());
        let note = check_start_note(&plant, &rec(-100.0), true).expect("away");
        assert!(
            note.contains("check recording") && note.contains("its own first sample"),
            "{note}"
        );
        let note = check_start_note(&plant, &rec(-100.0), false).expect("away");
        assert!(note.contains("the file's values"), "{note}");
    }
}
