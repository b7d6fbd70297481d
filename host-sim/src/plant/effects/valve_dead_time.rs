//! `[effects.valve_dead_time]`: every valve applies a command `delay_s` later (valves closed
//! before the first delayed command arrives). The delay must be a whole number of sample
//! periods of the run it is used with.
//!
//! Diagnosis (candidate `valve_delay`): every measured channel lags the nominal simulation
//! by the same shift; fitted on a grid of whole samples. Truth: 8 ms (rounded to samples).

use serde::Deserialize;

use super::{Check, Effect, enabled_default, Hooks, params, Truth};
use crate::diagnose::candidates::{Candidate, ParamSpec, Screening, Setup};
use crate::diagnose::screen::Evidence;
use crate::io::recording::Channel;
use crate::plant::config::{ConfigError, PlantConfig, ValveConfig};
use crate::plant::ValveInputs;

/// The `[effects.valve_dead_time]` table.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ValveDeadTime {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    pub delay_s: f64,
}

/// A delay line of whole samples between valve commands and valve openings.
#[derive(Debug, Clone)]
pub struct DeadTimeLine {
    fifo: std::collections::VecDeque<ValveInputs>,
}

impl DeadTimeLine {
    /// A line for `delay_s` at sample period `dt_s`; `None` when the delay is not a whole
    /// number of samples (within 1e-6 of a sample).
    pub fn new(delay_s: f64, dt_s: f64) -> Option<Self> {
        let samples = delay_s / dt_s;
        let n = samples.round();
        if !(n >= 0.0 && (samples - n).abs() <= 1e-6 && n < 1e9) {
            return None;
        }
        Some(Self {
            fifo: std::iter::repeat_n(ValveInputs::CLOSED, n as usize).collect(),
        })
    }

    /// Delay in samples.
    pub fn samples(&self) -> usize {
        self.fifo.len()
    }

    /// Feeds the command of this sample; returns the opening the valves apply over it.
    pub fn push(&mut self, command: ValveInputs) -> ValveInputs {
        if self.fifo.is_empty() {
            return command;
        }
        self.fifo.push_back(command);
        self.fifo.pop_front().expect("non-empty")
    }
}

impl Hooks for ValveDeadTime {
    fn parameters(&self) -> Option<Vec<(String, String)>> {
        Some(params(&[("delay_s", self.delay_s)]))
    }
    fn valve_dead_time_s(&self) -> Option<f64> {
        Some(self.delay_s)
    }
}

impl Effect for ValveDeadTime {
    table_effect!(ValveDelayCandidate);
    fn validate(&self, c: &Check) -> Result<(), ConfigError> {
        c.non_negative("delay_s", self.delay_s)
    }
    fn truths() -> Vec<Truth> {
        vec![Truth::new("valve_delay", "valve_delay", |dt_s| {
                format!(
                    "[effects.valve_dead_time]\ndelay_s = {}\n",
                    (0.008 / dt_s).round().max(1.0) * dt_s
                )
            })]
    }
}

/// Longest valve dead time tried.
pub const MAX_VALVE_DELAY_S: f64 = 0.05;

/// A dead time of whole samples in front of every valve.
pub struct ValveDelayCandidate;

impl Candidate for ValveDelayCandidate {
    fn id(&self) -> &'static str {
        "valve_delay"
    }
    fn label(&self) -> &'static str {
        "valve delay"
    }
    fn params(&self, s: &Setup) -> Vec<ParamSpec> {
        vec![ParamSpec::new("delay_s", 0.0, MAX_VALVE_DELAY_S, s.dt_s)]
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        // The pressures react to the valves first: their lag is the dead time.
        let ch = [Channel::P1Kpa, Channel::P2Kpa, Channel::AngleDeg]
            .into_iter()
            .find(|c| s.has(*c))
            .unwrap_or(Channel::AngleDeg);
        let lags: Vec<usize> = Channel::ALL
            .iter()
            .filter(|c| s.has(**c))
            .map(|c| ev.lag_samples[c.index()])
            .collect();
        let all_lag = !lags.is_empty() && lags.iter().all(|l| *l > 0);
        let gains: Vec<f64> = Channel::ALL
            .iter()
            .filter(|c| s.has(**c))
            .map(|c| ev.lag_gain[c.index()])
            .collect();
        let score = if all_lag {
            gains.iter().copied().fold(f64::INFINITY, f64::min)
        } else {
            0.0
        };
        Screening {
            score,
            initial: vec![ev.lag_samples[ch.index()] as f64 * s.dt_s],
            note: if all_lag {
                "every measured channel lags the nominal simulation, as when the valves act late"
                    .into()
            } else {
                "not every channel lags: no common dead time in front of the plant".into()
            },
            scatter: ev.lag_scatter(ch),
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], s: &Setup) {
        let n = (p[0] / s.dt_s).round().max(0.0);
        cfg.effects.valve_dead_time = Some(ValveDeadTime {
            enabled: true,
            delay_s: n * s.dt_s,
        });
    }
    fn grid(&self, initial: &[f64], s: &Setup) -> Option<Vec<Vec<f64>>> {
        let max_n = (MAX_VALVE_DELAY_S / s.dt_s).floor() as i64;
        let n0 = (initial[0] / s.dt_s).round() as i64;
        let mut v: Vec<Vec<f64>> = (n0 - 3..=n0 + 3)
            .filter(|n| *n >= 1 && *n <= max_n)
            .map(|n| vec![n as f64 * s.dt_s])
            .collect();
        if v.is_empty() {
            v.push(vec![s.dt_s]);
        }
        Some(v)
    }
    fn describe(&self, p: &[f64], _s: &Setup) -> String {
        format!(
            "a dead time of {:.1} ms between a valve command and the valve opening",
            p[0] * 1e3
        )
    }
}
