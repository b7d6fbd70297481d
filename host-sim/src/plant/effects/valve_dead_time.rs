//! `[effects.valve_dead_time]`: every valve applies a command `delay_s` later (valves closed
//! before the first delayed command arrives). A delay of `k + f` samples (`0 <= f < 1`)
//! opens each valve, over a sample period, for the `1 - f` of it that the command of `k`
//! samples ago covers and for the `f` of it that the command before covers: the opening
//! held over the period is their time average (openings count as duty, as for PWM).
//!
//! Diagnosis (candidate `valve_delay`): every measured channel lags the nominal simulation
//! by the same shift; fitted on a grid of whole samples, then refined continuously within a
//! sample of the best. Truth: 8 ms (rounded to samples).

use serde::Deserialize;

use super::{Check, Effect, enabled_default, Hooks, params, Truth};
use crate::plant::effects::candidate::{Candidate, ParamSpec, Screening, Setup};
use crate::plant::effects::candidate::Evidence;
use crate::plant::channel::Channel;
use crate::plant::config::PlantConfig;
use crate::plant::tables::{ConfigError, ValveConfig};
use crate::plant::state::ValveInputs;

/// The `[effects.valve_dead_time]` table.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ValveDeadTime {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    pub delay_s: f64,
}

/// The valve commands of a recording at its own stamps (uniform or jittered) shifted by the
/// dead time `delay_s` exactly: the command logged at `t_s[i]` is in force from
/// `t_s[i] + delay_s` until the next one's; valves closed before the first arrives. This is
/// the dead time itself; [`DeadTimeLine`] is the same shift on a uniform grid, each
/// period's opening the time average of the shifted commands over it (a test checks the
/// two agree).
#[derive(Debug, Clone)]
pub struct ShiftedCommands<'a> {
    t_s: &'a [f64],
    inputs: &'a [ValveInputs],
    delay_s: f64,
    /// Two times closer than this are one (a rounding of the stamps).
    tol_s: f64,
    /// Index of the command in force at the last time asked.
    src: usize,
}

impl<'a> ShiftedCommands<'a> {
    pub fn new(t_s: &'a [f64], inputs: &'a [ValveInputs], delay_s: f64, tol_s: f64) -> Self {
        Self {
            t_s,
            inputs,
            delay_s,
            tol_s,
            src: 0,
        }
    }

    /// The times the openings may change before `t_end`: the stamps and the delayed
    /// stamps, sorted, those within the tolerance of each other merged; then `t_end`.
    pub fn breakpoints(&self, t_end: f64) -> Vec<f64> {
        let mut cuts: Vec<f64> = self.t_s.to_vec();
        if self.delay_s > 0.0 {
            cuts.extend(
                self.t_s
                    .iter()
                    .map(|t| t + self.delay_s)
                    .filter(|t| *t < t_end),
            );
            cuts.sort_by(f64::total_cmp);
            let tol = self.tol_s;
            cuts.dedup_by(|a, b| (*a - *b).abs() <= tol);
        }
        cuts.push(t_end);
        cuts
    }

    /// The opening in force from time `t` on (asked at increasing times).
    pub fn at(&mut self, t: f64) -> ValveInputs {
        let td = t - self.delay_s;
        let n = self.t_s.len();
        while self.src + 1 < n && self.t_s[self.src + 1] <= td + self.tol_s {
            self.src += 1;
        }
        if self.t_s[self.src] <= td + self.tol_s {
            self.inputs[self.src]
        } else {
            ValveInputs::CLOSED
        }
    }
}

/// A delay line between valve commands and valve openings: `whole` samples and a fraction
/// `frac` of one.
#[derive(Debug, Clone)]
pub struct DeadTimeLine {
    /// The last `whole + 1` commands, oldest first.
    fifo: std::collections::VecDeque<ValveInputs>,
    whole: usize,
    frac: f64,
}

impl DeadTimeLine {
    /// A line for `delay_s` at sample period `dt_s`; `None` when the delay is negative, not
    /// finite or absurdly long (1e9 samples). A fraction within 1e-6 of a whole sample is
    /// rounded to it.
    pub fn new(delay_s: f64, dt_s: f64) -> Option<Self> {
        let samples = delay_s / dt_s;
        if !(0.0..1e9).contains(&samples) {
            return None;
        }
        let mut whole = samples.floor();
        let mut frac = samples - whole;
        if frac <= 1e-6 {
            frac = 0.0;
        } else if frac >= 1.0 - 1e-6 {
            whole += 1.0;
            frac = 0.0;
        }
        Some(Self {
            fifo: std::iter::repeat_n(ValveInputs::CLOSED, whole as usize + 1).collect(),
            whole: whole as usize,
            frac,
        })
    }

    /// Whole samples of the delay (its fraction not counted).
    pub fn samples(&self) -> usize {
        self.whole
    }

    /// Feeds the command of this sample; returns the opening the valves apply over it.
    pub fn push(&mut self, command: ValveInputs) -> ValveInputs {
        self.fifo.push_back(command);
        // `whole + 2` entries now: the command of `whole + 1` samples ago, then that of `whole`.
        let older = self.fifo.pop_front().unwrap_or(ValveInputs::CLOSED);
        let newer = *self.fifo.front().unwrap_or(&command);
        if self.frac == 0.0 {
            return newer;
        }
        let (a, b) = (1.0 - self.frac, self.frac);
        ValveInputs {
            u_in1: a * newer.u_in1 + b * older.u_in1,
            u_ex1: a * newer.u_ex1 + b * older.u_ex1,
            u_in2: a * newer.u_in2 + b * older.u_in2,
            u_ex2: a * newer.u_ex2 + b * older.u_ex2,
        }
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
    const TRUTHS: &'static [Truth] = &[Truth::new("valve_delay", "valve_delay", |dt_s| {
        format!(
            "[effects.valve_dead_time]\ndelay_s = {}\n",
            (0.008 / dt_s).round().max(1.0) * dt_s
        )
    })];
    table_effect!();
    fn validate(&self, c: &Check) -> Result<(), ConfigError> {
        check_fields!(self, c, non_negative: delay_s);
        if self.delay_s > MAX_PLAUSIBLE_DELAY_S {
            return Err(c.error(
                "delay_s",
                format!(
                    "{} s is more than {MAX_PLAUSIBLE_DELAY_S} s (allowed 0..={MAX_PLAUSIBLE_DELAY_S}): \
                     milliseconds typed as seconds?",
                    self.delay_s
                ),
            ));
        }
        Ok(())
    }
}

effect_candidates!(ValveDeadTime => ValveDelayCandidate);

/// Longest valve dead time a plant file may state [s]: a pneumatic valve answers within tens
/// of milliseconds; more is a unit mistake.
pub const MAX_PLAUSIBLE_DELAY_S: f64 = 1.0;

/// Longest valve dead time tried: the longest a plant file may state, so that every dead
/// time the plant can have can be found.
pub const MAX_VALVE_DELAY_S: f64 = MAX_PLAUSIBLE_DELAY_S;

/// The shift (samples, `1..=max`) by which the nominal channel `c` best matches the
/// measured one (least squares over the samples after the longest shift), and the share of
/// the residual energy it removes: the evidence's own search
/// ([`crate::plant::effects::candidate::MAX_LAG_S`]) carried on to `max` samples when it
/// ended at its bound.
fn longer_lag(ev: &Evidence, c: Channel, max: usize) -> Option<(usize, f64)> {
    let yn = ev.nominal[c.index()].as_ref()?;
    let r = ev.residual[c.index()].as_ref()?;
    let n = yn.len();
    let max = max.min(n / 4);
    if max == 0 {
        return None;
    }
    let y: Vec<f64> = r.iter().zip(yn).map(|(a, b)| a + b).collect();
    let cost = |s: usize| (max..n).map(|k| (y[k] - yn[k - s]).powi(2)).sum::<f64>();
    let c0 = cost(0);
    let (mut best, mut best_cost) = (0, c0);
    for s in 1..=max {
        let cs = cost(s);
        if cs < best_cost {
            best = s;
            best_cost = cs;
        }
    }
    Some((best, if c0 > 0.0 { 1.0 - best_cost / c0 } else { 0.0 }))
}

/// A dead time in front of every valve.
pub struct ValveDelayCandidate;

impl Candidate for ValveDelayCandidate {
    candidate_spec! {
        id: "valve_delay",
        label: "valve delay",
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
        // The evidence searches lags up to its own bound; a channel whose lag ended there is
        // searched on to the longest dead time a plant file may state.
        let at_cap = ((crate::plant::effects::candidate::MAX_LAG_S / s.dt_s).round() as usize)
            .min(ev.nominal[ch.index()].as_ref().map_or(0, |v| v.len() / 4));
        let max_n = (MAX_VALVE_DELAY_S / s.dt_s).floor() as usize;
        let lag_of = |c: Channel| -> (usize, f64) {
            let (l, g) = (ev.lag_samples[c.index()], ev.lag_gain[c.index()]);
            if l > 0 && l >= at_cap {
                longer_lag(ev, c, max_n).unwrap_or((l, g))
            } else {
                (l, g)
            }
        };
        let found: Vec<(Channel, usize, f64)> = Channel::ALL
            .iter()
            .filter(|c| s.has(**c))
            .map(|c| {
                let (l, g) = lag_of(*c);
                (*c, l, g)
            })
            .collect();
        let lags: Vec<usize> = found.iter().map(|f| f.1).collect();
        let all_lag = !lags.is_empty() && lags.iter().all(|l| *l > 0);
        let gains: Vec<f64> = found.iter().map(|f| f.2).collect();
        let ch_lag = found.iter().find(|f| f.0 == ch).map_or(0, |f| f.1);
        let len = ev.nominal[ch.index()].as_ref().map_or(0, Vec::len);
        let searched_to_bound = ch_lag > 0 && ch_lag >= max_n.min(len / 4);
        let score = if all_lag {
            gains.iter().copied().fold(f64::INFINITY, f64::min)
        } else {
            0.0
        };
        Screening {
            score,
            initial: vec![ch_lag as f64 * s.dt_s],
            note: if all_lag && searched_to_bound {
                format!(
                    "every measured channel lags the nominal simulation, {} ms on {}: the \
                     search ended at its bound ({} ms, the longest valve dead time a plant \
                     file may state); the true delay may be longer",
                    ch_lag as f64 * s.dt_s * 1e3,
                    ch.name(),
                    MAX_VALVE_DELAY_S * 1e3
                )
            } else if all_lag {
                "every measured channel lags the nominal simulation, as when the valves act late"
                    .into()
            } else {
                "not every channel lags: no common dead time in front of the plant".into()
            },
            scatter: ev.lag_scatter(ch),
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], _s: &Setup) {
        cfg.effects.valve_dead_time = Some(ValveDeadTime {
            enabled: true,
            delay_s: p[0].max(0.0),
        });
    }
    fn refine_after_grid(&self) -> bool {
        true
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
            "a dead time of {:.2} ms between a valve command and the valve opening",
            p[0] * 1e3
        )
    }
}

#[cfg(test)]
mod line_tests {
    use super::*;

    fn pulse(k: usize) -> ValveInputs {
        ValveInputs {
            u_in1: if k == 3 { 1.0 } else { 0.0 },
            ..ValveInputs::CLOSED
        }
    }

    /// The line's opening over each period is the time average of the exactly shifted
    /// commands over it: one dead time, two views.
    #[test]
    fn the_line_is_the_shift_averaged_over_each_period() {
        let dt = 0.001;
        let cmds: Vec<ValveInputs> = (0..12).map(pulse).collect();
        let t: Vec<f64> = (0..12).map(|k| k as f64 * dt).collect();
        for delay in [0.0, 0.002, 0.00225, 0.0037] {
            let mut line = DeadTimeLine::new(delay, dt).expect("line");
            let mut shift = ShiftedCommands::new(&t, &cmds, delay, 1e-12 * dt);
            for (k, c) in cmds.iter().enumerate() {
                let got = line.push(*c).u_in1;
                // Average of the shifted command over [k dt, (k+1) dt), at the midpoints of
                // 20 sub-intervals (exact for delays of whole twentieths of a sample).
                let m = 20;
                let avg = (0..m)
                    .map(|j| shift.at((k as f64 + (j as f64 + 0.5) / m as f64) * dt).u_in1)
                    .sum::<f64>()
                    / m as f64;
                assert!((got - avg).abs() < 1e-9, "delay {delay}, k {k}: {got} vs {avg}");
            }
        }
    }

    #[test]
    fn a_whole_sample_delay_shifts_the_commands() {
        let mut l = DeadTimeLine::new(0.002, 0.001).expect("line");
        let out: Vec<f64> = (0..8).map(|k| l.push(pulse(k)).u_in1).collect();
        assert_eq!(out, vec![0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0]);
        let mut l = DeadTimeLine::new(0.0, 0.001).expect("line");
        assert_eq!(l.push(pulse(3)).u_in1, 1.0);
    }

    #[test]
    fn a_fractional_delay_splits_each_opening_over_two_periods() {
        // 2.25 samples: the pulse of sample 3 covers 0.75 of period 5 and 0.25 of period 6.
        let mut l = DeadTimeLine::new(0.00225, 0.001).expect("line");
        let out: Vec<f64> = (0..8).map(|k| l.push(pulse(k)).u_in1).collect();
        let want = [0.0, 0.0, 0.0, 0.0, 0.0, 0.75, 0.25, 0.0];
        for (o, w) in out.iter().zip(want) {
            assert!((o - w).abs() < 1e-12, "{out:?}");
        }
        assert!(DeadTimeLine::new(-0.001, 0.001).is_none());
        assert!(DeadTimeLine::new(f64::NAN, 0.001).is_none());
    }
}
