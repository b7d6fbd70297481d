//! `[effects.sensor]`: offset and gain of each measured channel, one optional sub-table per
//! channel, e.g. `[effects.sensor.angle_deg]` `offset = 0.2` `gain = 1.01`:
//! reported = gain * true + offset (channel units). It changes what the sensors report, not
//! the plant.
//!
//! Diagnosis: candidate `sensor_offset`, a constant share of each channel's residual (truth:
//! angle +1.5 deg, p1 +8 kPa, p2 -6 kPa); candidate `sensor_gain`, a share of each channel's
//! residual proportional to the channel itself, one gain per channel (truth: p1 reads 6 %
//! high, the other channels right).

use serde::Deserialize;

use super::{enabled_default, Check, Effect, Hooks, Truth};
use crate::plant::effects::candidate::{EffectCandidates, clamp_to, Candidate, ParamSpec, Screening, Setup};
use crate::plant::effects::candidate::Evidence;
use crate::plant::channel::Channel;
use crate::plant::config::PlantConfig;
use crate::plant::tables::{ConfigError, ValveConfig};
use crate::plant::state::Measurement;

/// Offset and gain of one measured channel: reported = gain * true + offset (channel units).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelCalibration {
    #[serde(default)]
    pub offset: f64,
    #[serde(default = "unit_gain")]
    pub gain: f64,
}

fn unit_gain() -> f64 {
    1.0
}

impl ChannelCalibration {
    pub const IDENTITY: Self = Self {
        offset: 0.0,
        gain: 1.0,
    };
    #[inline]
    pub fn apply(&self, v: f64) -> f64 {
        self.gain * v + self.offset
    }
    /// The true value behind a reading `r` (the inverse of [`Self::apply`]); `r` itself
    /// when the gain is zero or not finite.
    pub fn read_back(&self, r: f64) -> f64 {
        let v = (r - self.offset) / self.gain;
        if v.is_finite() {
            v
        } else {
            r
        }
    }
}

/// The `[effects.sensor]` table.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorCalibration {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    pub angle_deg: Option<ChannelCalibration>,
    pub p1_kpa: Option<ChannelCalibration>,
    pub p2_kpa: Option<ChannelCalibration>,
    pub f1_n: Option<ChannelCalibration>,
    pub f2_n: Option<ChannelCalibration>,
}

/// Calibrations of angle_deg, p1_kpa, p2_kpa, f1_n, f2_n (identity when absent): the
/// run-time form of [`SensorCalibration`].
#[derive(Debug, Clone, PartialEq)]
pub struct Calibrations(pub [ChannelCalibration; 5]);

impl Hooks for Calibrations {
    fn parameters(&self) -> Option<Vec<(String, String)>> {
        // Identity calibrations change nothing and are not listed.
        let names = ["angle_deg", "p1_kpa", "p2_kpa", "f1_n", "f2_n"];
        let mut p = Vec::new();
        for (name, c) in names.iter().zip(&self.0) {
            if c.offset != 0.0 {
                p.push((format!("{name}.offset"), format!("{}", c.offset)));
            }
            if c.gain != 1.0 {
                p.push((format!("{name}.gain"), format!("{}", c.gain)));
            }
        }
        (!p.is_empty()).then_some(p)
    }
    fn calibrate(&self, m: Measurement) -> Measurement {
        let c = &self.0;
        Measurement {
            angle_deg: c[0].apply(m.angle_deg),
            p1_kpa: c[1].apply(m.p1_kpa),
            p2_kpa: c[2].apply(m.p2_kpa),
            f1_n: c[3].apply(m.f1_n),
            f2_n: c[4].apply(m.f2_n),
        }
    }
}

impl Effect for SensorCalibration {
    type Active = Calibrations;
    const TRUTHS: &'static [Truth] = &[
        Truth::new("sensor_offset", "sensor_offset", |_| {
            "[effects.sensor.angle_deg]\noffset = 1.5\n[effects.sensor.p1_kpa]\noffset = 8.0\n[effects.sensor.p2_kpa]\noffset = -6.0\n".into()
        }),
        Truth::new("sensor_gain_one_channel", "sensor_gain", |_| {
            "[effects.sensor.p1_kpa]\ngain = 1.06\n".into()
        }),
    ];
    fn enabled(&self) -> bool {
        self.enabled
    }
    fn validate(&self, c: &Check) -> Result<(), ConfigError> {
        for (name, cal) in [
            ("angle_deg", self.angle_deg),
            ("p1_kpa", self.p1_kpa),
            ("p2_kpa", self.p2_kpa),
            ("f1_n", self.f1_n),
            ("f2_n", self.f2_n),
        ] {
            if let Some(cal) = cal {
                c.finite(&format!("{name}.offset"), cal.offset)?;
                c.finite(&format!("{name}.gain"), cal.gain)?;
            }
        }
        Ok(())
    }
    fn activate(&self, _valve: &ValveConfig) -> Calibrations {
        let id = ChannelCalibration::IDENTITY;
        Calibrations([
            self.angle_deg.unwrap_or(id),
            self.p1_kpa.unwrap_or(id),
            self.p2_kpa.unwrap_or(id),
            self.f1_n.unwrap_or(id),
            self.f2_n.unwrap_or(id),
        ])
    }
}

impl EffectCandidates for SensorCalibration {
    fn candidates() -> Vec<Box<dyn Candidate>> {
        vec![
            Box::new(SensorOffsetCandidate),
            Box::new(SensorGainCandidate),
        ]
    }
}

/// A constant offset on every measured channel.
pub struct SensorOffsetCandidate;

const OFFSET_NAMES: [&str; 5] = [
    "angle_offset_deg",
    "p1_offset_kpa",
    "p2_offset_kpa",
    "f1_offset_n",
    "f2_offset_n",
];
const OFFSET_SCALES: [f64; 5] = [0.5, 5.0, 5.0, 5.0, 5.0];

impl Candidate for SensorOffsetCandidate {
    candidate_spec! {
        id: "sensor_offset",
        label: "sensor calibration offset",
    }
    fn params(&self, s: &Setup) -> Vec<ParamSpec> {
        per_present_channel(s, |i| {
            let sc = OFFSET_SCALES[i];
            ParamSpec::new(OFFSET_NAMES[i], -1e3 * sc, 1e3 * sc, sc)
        })
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        // Per channel, the residual's mean.
        let share = "a constant share of the residual";
        screen_channels(ev, &self.params(s), share, "a fixed offset", |_, r, w| {
            let n = r.len() as f64;
            let mean = r.iter().sum::<f64>() / n;
            Some((w * mean * mean * n, mean))
        })
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], s: &Setup) {
        // The offsets are fitted; the gains of a calibration the plant file already has stay.
        set_calibration(cfg, p, s, |old, v| ChannelCalibration {
            offset: v,
            gain: old.map_or(1.0, |k| k.gain),
        });
    }
    fn changes_dynamics(&self) -> bool {
        false
    }
    fn describe(&self, p: &[f64], s: &Setup) -> String {
        let parts = channel_values(&self.params(s), p, |_| true, |v| format!("{v:+.3}"));
        format!("constant sensor offsets ({})", parts.join(", "))
    }
}

/// The screening of a per-channel calibration: each measured channel's residual fitted
/// alone, weighted by 1 / spread^2. `fit(channel index, residual, weight)` gives the weighted
/// residual energy the calibration explains and the channel's initial value (`None`: the
/// channel cannot be fitted); the score is the explained share of the weighted residual
/// energy, which the note reports as "`share` (.. % of its energy) is `what`".
fn screen_channels(
    ev: &Evidence,
    params: &[ParamSpec],
    share: &str,
    what: &str,
    fit: impl Fn(usize, &[f64], f64) -> Option<(f64, f64)>,
) -> Screening {
    let mut init = Vec::new();
    let mut explained = 0.0;
    let mut total = 0.0;
    for c in Channel::ALL {
        let Some(r) = &ev.residual[c.index()] else {
            continue;
        };
        let w = 1.0 / ev.spread[c.index()].powi(2);
        if let Some((e, x0)) = fit(c.index(), r, w) {
            let ss: f64 = r.iter().map(|v| v * v).sum();
            explained += e;
            total += w * ss;
            init.push(x0);
        }
    }
    let score = if total > 0.0 { explained / total } else { 0.0 };
    Screening {
        score,
        initial: clamp_to(params, init),
        note: format!(
            "{share} ({:.0} % of its energy) is {what}",
            100.0 * score
        ),
        scatter: None,
    }
}

/// One parameter per channel the recording has (`spec` of the channel index), in channel
/// order.
fn per_present_channel(s: &Setup, spec: impl Fn(usize) -> ParamSpec) -> Vec<ParamSpec> {
    Channel::ALL
        .iter()
        .filter(|c| s.has(**c))
        .map(|c| spec(c.index()))
        .collect()
}

/// "channel value" of each fitted value `keep` accepts (`value` formats it), for `describe`.
fn channel_values(
    params: &[ParamSpec],
    p: &[f64],
    keep: impl Fn(f64) -> bool,
    value: impl Fn(f64) -> String,
) -> Vec<String> {
    params
        .iter()
        .zip(p)
        .filter(|(_, v)| keep(**v))
        .map(|(n, v)| format!("{} {}", n.name, value(*v)))
        .collect()
}

/// Writes one fitted value per present channel (`p`, in channel order) into the plant's
/// sensor calibration through `set(old calibration, value)`.
fn set_calibration(
    cfg: &mut PlantConfig,
    p: &[f64],
    s: &Setup,
    set: impl Fn(Option<ChannelCalibration>, f64) -> ChannelCalibration,
) {
    let mut cal = cfg
        .effects
        .sensor
        .clone()
        .filter(|c| c.enabled)
        .unwrap_or(SensorCalibration {
            enabled: true,
            angle_deg: None,
            p1_kpa: None,
            p2_kpa: None,
            f1_n: None,
            f2_n: None,
        });
    let mut it = p.iter();
    for c in Channel::ALL {
        if !s.has(c) {
            continue;
        }
        let slot = match c {
            Channel::AngleDeg => &mut cal.angle_deg,
            Channel::P1Kpa => &mut cal.p1_kpa,
            Channel::P2Kpa => &mut cal.p2_kpa,
            Channel::F1N => &mut cal.f1_n,
            Channel::F2N => &mut cal.f2_n,
        };
        *slot = Some(set(*slot, *it.next().unwrap_or(&0.0)));
    }
    cfg.effects.sensor = Some(cal);
}

/// A gain on each measured channel: reported = gain * true (a transducer that reads a fixed
/// share high or low). One gain per channel, so one wrong sensor is fitted alone.
pub struct SensorGainCandidate;

const GAIN_NAMES: [&str; 5] = ["angle_gain", "p1_gain", "p2_gain", "f1_gain", "f2_gain"];

impl Candidate for SensorGainCandidate {
    candidate_spec! {
        id: "sensor_gain",
        label: "sensor calibration gain",
    }
    fn params(&self, s: &Setup) -> Vec<ParamSpec> {
        per_present_channel(s, |i| ParamSpec::new(GAIN_NAMES[i], 0.5, 2.0, 0.05))
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        // Per channel, the residual's projection on the nominal channel: r = (g - 1) y.
        let share = "a share of the residual proportional to the channel itself";
        screen_channels(ev, &self.params(s), share, "a gain", |i, r, w| {
            let y = ev.nominal[i].as_ref()?;
            let yy: f64 = y.iter().map(|v| v * v).sum();
            let ry: f64 = r.iter().zip(y).map(|(a, b)| a * b).sum();
            let k = if yy > 0.0 { ry / yy } else { 0.0 };
            Some((w * k * ry, 1.0 + k))
        })
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], s: &Setup) {
        // The gains are fitted; the offsets of a calibration the plant file already has stay.
        set_calibration(cfg, p, s, |old, v| ChannelCalibration {
            offset: old.map_or(0.0, |k| k.offset),
            gain: v,
        });
    }
    fn changes_dynamics(&self) -> bool {
        false
    }
    fn describe(&self, p: &[f64], s: &Setup) -> String {
        let off_1 = |v: f64| (v - 1.0).abs() >= 0.005;
        let parts = channel_values(&self.params(s), p, off_1, |v| format!("{v:.3}"));
        format!(
            "sensor gains off 1 ({})",
            if parts.is_empty() {
                "none above 0.5 %".to_string()
            } else {
                parts.join(", ")
            }
        )
    }
}
