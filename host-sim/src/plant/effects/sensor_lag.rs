//! `[effects.sensor_lag]`: first-order sensor dynamics per channel group, as the sensor's
//! own sampled low-pass: y_k = y_{k-1} + a (x_k - y_{k-1}), a = 1 - exp(-dt / tau), started
//! at the first sample. An absent time constant means no lag on that group. It changes what
//! the sensors report, not the plant.
//!
//! `p1_time_constant_s` / `p2_time_constant_s` give one pressure sensor its own lag (they
//! override `pressure_time_constant_s` for that channel).
//!
//! Diagnosis: the shift that best aligns each measured channel with the nominal simulation
//! (cross-correlation of the residuals). Candidates `sensor_lag` (one time constant per
//! channel group) and `sensor_lag_p1` / `sensor_lag_p2` (one pressure sensor alone). Truths:
//! angle 15 ms, pressures 8 ms; the p2 sensor alone 20 ms.

use serde::Deserialize;

use super::{ChannelFilter, Check, Effect, enabled_default, Hooks, Truth};
use crate::plant::effects::candidate::{clamp_to, Candidate, ParamSpec, Screening, Setup};
use crate::plant::effects::candidate::Evidence;
use crate::plant::channel::Channel;
use crate::plant::config::PlantConfig;
use crate::plant::tables::{ConfigError, ValveConfig};

/// The `[effects.sensor_lag]` table.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorLag {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    /// angle_deg.
    pub angle_time_constant_s: Option<f64>,
    /// p1_kpa, p2_kpa.
    pub pressure_time_constant_s: Option<f64>,
    /// p1_kpa alone (overrides `pressure_time_constant_s` for it).
    #[serde(default)]
    pub p1_time_constant_s: Option<f64>,
    /// p2_kpa alone (overrides `pressure_time_constant_s` for it).
    #[serde(default)]
    pub p2_time_constant_s: Option<f64>,
    /// f1_n, f2_n.
    pub force_time_constant_s: Option<f64>,
}

/// The running state of [`SensorLag`] for one sample period.
#[derive(Debug, Clone)]
pub struct SensorLagFilter {
    /// Filter gains of angle, p1, p2, f1, f2 (1 = no lag).
    gain: [f64; 5],
    y: Option<[f64; 5]>,
}

impl SensorLagFilter {
    pub fn new(lag: &SensorLag, dt_s: f64) -> Self {
        let a = |tau: Option<f64>| match tau {
            Some(t) if t > 0.0 => 1.0 - (-dt_s / t).exp(),
            _ => 1.0,
        };
        let (ang, p1, p2, f) = (
            a(lag.angle_time_constant_s),
            a(lag.p1_time_constant_s.or(lag.pressure_time_constant_s)),
            a(lag.p2_time_constant_s.or(lag.pressure_time_constant_s)),
            a(lag.force_time_constant_s),
        );
        Self {
            gain: [ang, p1, p2, f, f],
            y: None,
        }
    }
}

impl ChannelFilter for SensorLagFilter {
    /// Feeds the undelayed channels of one sample (angle, p1, p2, f1, f2); returns the lagged ones.
    fn push(&mut self, x: [f64; 5]) -> [f64; 5] {
        let y = match self.y {
            None => x,
            Some(mut y) => {
                for i in 0..5 {
                    y[i] += self.gain[i] * (x[i] - y[i]);
                }
                y
            }
        };
        self.y = Some(y);
        y
    }
}

impl Hooks for SensorLag {
    fn parameters(&self) -> Option<Vec<(String, String)>> {
        Some(
            [
                ("angle_time_constant_s", self.angle_time_constant_s),
                ("pressure_time_constant_s", self.pressure_time_constant_s),
                ("p1_time_constant_s", self.p1_time_constant_s),
                ("p2_time_constant_s", self.p2_time_constant_s),
                ("force_time_constant_s", self.force_time_constant_s),
            ]
            .into_iter()
            .filter_map(|(k, v)| v.map(|v| (k.to_string(), format!("{v}"))))
            .collect(),
        )
    }
    fn sensor_filter(&self, dt_s: f64) -> Option<Box<dyn ChannelFilter>> {
        Some(Box::new(SensorLagFilter::new(self, dt_s)))
    }
}

impl SensorLag {
    /// Switched on, every time constant absent (no channel lags yet).
    fn switched_on() -> Self {
        SensorLag {
            enabled: true,
            angle_time_constant_s: None,
            pressure_time_constant_s: None,
            p1_time_constant_s: None,
            p2_time_constant_s: None,
            force_time_constant_s: None,
        }
    }
}

impl Effect for SensorLag {
    const TRUTHS: &'static [Truth] = &[
        Truth::new("sensor_lag", "sensor_lag", |_| "[effects.sensor_lag]\nangle_time_constant_s = 0.015\npressure_time_constant_s = 0.008\n".into()),
        Truth::new("sensor_lag_one_pressure", "sensor_lag_p2", |_| {
            "[effects.sensor_lag]\np2_time_constant_s = 0.02\n".into()
        }),
    ];
    table_effect!();
    fn validate(&self, c: &Check) -> Result<(), ConfigError> {
        for (key, tau) in [
            ("angle_time_constant_s", self.angle_time_constant_s),
            ("pressure_time_constant_s", self.pressure_time_constant_s),
            ("p1_time_constant_s", self.p1_time_constant_s),
            ("p2_time_constant_s", self.p2_time_constant_s),
            ("force_time_constant_s", self.force_time_constant_s),
        ] {
            if let Some(t) = tau {
                c.non_negative(key, t)?;
            }
        }
        Ok(())
    }
}

effect_candidates!(SensorLag => SensorLagCandidate, PressureSensorLagCandidate { channel: Channel::P1Kpa }, PressureSensorLagCandidate { channel: Channel::P2Kpa });

/// One time constant per measured channel group.
pub struct SensorLagCandidate;

impl SensorLagCandidate {
    fn groups(s: &Setup) -> Vec<(&'static str, Channel)> {
        // A group is fitted on its first measured channel.
        let first = |a: Channel, b: Channel| if s.has(a) { a } else { b };
        let mut g = Vec::new();
        if s.has(Channel::AngleDeg) {
            g.push(("angle_time_constant_s", Channel::AngleDeg));
        }
        if s.has_pressure() {
            let c = first(Channel::P1Kpa, Channel::P2Kpa);
            g.push(("pressure_time_constant_s", c));
        }
        if s.has_force() {
            g.push(("force_time_constant_s", first(Channel::F1N, Channel::F2N)));
        }
        g
    }
}

impl Candidate for SensorLagCandidate {
    candidate_spec! {
        id: "sensor_lag",
        label: "sensor lag",
    }
    fn params(&self, s: &Setup) -> Vec<ParamSpec> {
        Self::groups(s)
            .into_iter()
            .map(|(n, _)| ParamSpec::new(n, 0.0, 0.5, 0.005))
            .collect()
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        let groups = Self::groups(s);
        let initial: Vec<f64> = groups
            .iter()
            .map(|(_, c)| ev.lag_samples[c.index()] as f64 * s.dt_s)
            .collect();
        let score = groups
            .iter()
            .map(|(_, c)| ev.lag_gain[c.index()])
            .fold(0.0, f64::max);
        let lagging: Vec<&str> = groups
            .iter()
            .filter(|(_, c)| ev.lag_samples[c.index()] > 0)
            .map(|(_, c)| c.name())
            .collect();
        let most = groups
            .iter()
            .max_by(|a, b| ev.lag_gain[a.1.index()].total_cmp(&ev.lag_gain[b.1.index()]))
            .map(|g| g.1);
        Screening {
            score,
            initial: clamp_to(&self.params(s), initial),
            note: if lagging.is_empty() {
                "no measured channel lags the nominal simulation".into()
            } else {
                format!(
                    "{} lag(s) the nominal simulation (cross-correlation of the residuals)",
                    lagging.join(", ")
                )
            },
            scatter: most.and_then(|c| ev.lag_scatter(c)),
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], s: &Setup) {
        let mut lag = SensorLag::switched_on();
        for ((name, _), v) in Self::groups(s).iter().zip(p) {
            let v = Some(v.max(0.0));
            match *name {
                "angle_time_constant_s" => lag.angle_time_constant_s = v,
                "pressure_time_constant_s" => lag.pressure_time_constant_s = v,
                _ => lag.force_time_constant_s = v,
            }
        }
        cfg.effects.sensor_lag = Some(lag);
    }
    fn changes_dynamics(&self) -> bool {
        false
    }
    fn describe(&self, p: &[f64], s: &Setup) -> String {
        let parts: Vec<String> = Self::groups(s)
            .iter()
            .zip(p)
            .map(|((n, _), v)| {
                format!(
                    "{} {:.1} ms",
                    n.trim_end_matches("_time_constant_s"),
                    v * 1e3
                )
            })
            .collect();
        format!(
            "first-order lag of the sensors ({}), the plant itself on time",
            parts.join(", ")
        )
    }
}

/// The lag of one pressure sensor alone (the other channels on time).
pub struct PressureSensorLagCandidate {
    pub channel: Channel,
}

impl PressureSensorLagCandidate {
    fn key(&self) -> &'static str {
        if self.channel == Channel::P1Kpa {
            "p1_time_constant_s"
        } else {
            "p2_time_constant_s"
        }
    }
}

impl Candidate for PressureSensorLagCandidate {
    fn id(&self) -> &'static str {
        if self.channel == Channel::P1Kpa {
            "sensor_lag_p1"
        } else {
            "sensor_lag_p2"
        }
    }
    fn label(&self) -> &'static str {
        if self.channel == Channel::P1Kpa {
            "lag of the p1 sensor"
        } else {
            "lag of the p2 sensor"
        }
    }
    fn params(&self, s: &Setup) -> Vec<ParamSpec> {
        if s.has(self.channel) {
            vec![ParamSpec::new(self.key(), 0.0, 0.5, 0.005)]
        } else {
            Vec::new()
        }
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        let i = self.channel.index();
        let lags = ev.lag_samples[i] > 0;
        // The channel lags and the others do not.
        let others_lag = Channel::ALL
            .iter()
            .filter(|c| **c != self.channel && s.has(**c))
            .any(|c| ev.lag_samples[c.index()] > 0);
        Screening {
            score: if s.has(self.channel) && !others_lag {
                ev.lag_gain[i]
            } else {
                0.0
            },
            initial: clamp_to(&self.params(s), vec![ev.lag_samples[i] as f64 * s.dt_s]),
            note: if lags && !others_lag {
                format!("{} alone lags the nominal simulation", self.channel.name())
            } else {
                format!("{} does not lag alone", self.channel.name())
            },
            scatter: ev.lag_scatter(self.channel),
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], _s: &Setup) {
        let tau = p.first().map(|v| v.max(0.0));
        let mut lag = SensorLag::switched_on();
        if self.channel == Channel::P1Kpa {
            lag.p1_time_constant_s = tau;
        } else {
            lag.p2_time_constant_s = tau;
        }
        cfg.effects.sensor_lag = Some(lag);
    }
    fn changes_dynamics(&self) -> bool {
        false
    }
    fn describe(&self, p: &[f64], _s: &Setup) -> String {
        format!(
            "first-order lag of the {} sensor alone ({:.1} ms), the plant and the other sensors on time",
            self.channel.name(),
            p.first().copied().unwrap_or(0.0) * 1e3
        )
    }
}
