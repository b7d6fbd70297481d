//! Firmware in the loop: the firmware's control tick (the same `pam_firmware` code that runs
//! on the MCU) drives the plant through fake valve pins and fake sensors at the tick rate.
//!
//! Per tick `k` (period `dt = 1 / tick_hz`):
//! 1. the plant state at `t_k` is measured ([`Plant::measure`], with its sensor effects), then
//!    passed through the [`SensorModel`] (noise, ADC / encoder quantisation, delay) and the
//!    scenario's injected sensor faults (dropout: no sample; NaN);
//! 2. [`ControlTick::step`] turns the sensor frame and the set-point into a valve command;
//! 3. the firmware's [`OnOffValves`] driver writes the fake pins (tick-level PWM, minimum
//!    on-time); a stuck valve ignores its pin; the effective openings are the plant inputs
//!    held over `[t_k, t_k + dt)`;
//! 4. the plant is integrated over the tick ([`Integrator::advance`]).
//!
//! Scenario events (load inertia change, supply loss) swap in a modified plant at their time,
//! carrying the state over.

use std::cell::Cell;
use std::collections::VecDeque;
use std::path::Path;
use std::rc::Rc;

use pam_firmware::tick::{ControlTick, ControllerConfig, SensorFrame, Setpoint, TickOutput};
use pam_firmware::valves::{OnOffPwmConfig, OnOffValves};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use serde::Deserialize;

use crate::plant::{Plant, PlantState, ValveInputs};
use crate::recording::{Channel, Recording};
use crate::sim::{Integrator, SimError, SimStats, SolverOptions};

// ---------------------------------------------------------------------------------------
// Scenario files.

/// A closed-loop scenario (TOML). Unknown keys are errors.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// `[scenario]`: name, length, tick rate, seed.
    pub scenario: ScenarioHeader,
    /// `[setpoint]`: the angle set-point profile.
    pub setpoint: SetpointProfile,
    /// `[sensors]`: noise, quantisation, delay.
    #[serde(default)]
    pub sensors: SensorModel,
    /// `[[events]]`: injected faults and plant changes.
    #[serde(default)]
    pub events: Vec<Event>,
    /// `[expect]`: bounds a run must meet (checked by [`ClosedLoopRun::check`]).
    #[serde(default)]
    pub expect: Expectations,
}

/// `[scenario]` table.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScenarioHeader {
    /// Name used in reports.
    pub name: String,
    /// Simulated time [s].
    pub duration_s: f64,
    /// Control tick rate [Hz].
    #[serde(default = "default_tick_hz")]
    pub tick_hz: f64,
    /// Seed of the sensor noise and random set-points.
    #[serde(default = "default_seed")]
    pub seed: u64,
}

fn default_tick_hz() -> f64 {
    1000.0
}
fn default_seed() -> u64 {
    1
}

/// Angle set-point profiles.
#[derive(Debug, Clone, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum SetpointProfile {
    /// `initial_rad` until `at_s`, then `final_rad`; with `transition_s > 0` the change is a
    /// minimum-jerk move (quintic `10 u^3 - 15 u^4 + 6 u^5`, zero rate and acceleration at
    /// both ends) over `transition_s` starting at `at_s`.
    Step {
        /// Before the step [rad].
        initial_rad: f64,
        /// After the step [rad].
        final_rad: f64,
        /// Step time [s].
        at_s: f64,
        /// Duration of the minimum-jerk move [s] (0: a jump).
        #[serde(default)]
        transition_s: f64,
    },
    /// Linear from `from_rad` at `start_s` to `to_rad` at `end_s`, constant outside.
    Ramp {
        /// Start value [rad].
        from_rad: f64,
        /// End value [rad].
        to_rad: f64,
        /// Ramp start [s].
        start_s: f64,
        /// Ramp end [s].
        end_s: f64,
    },
    /// `offset + amplitude sin(2 pi f t)`, starting at `start_s` (offset before).
    Sine {
        /// Offset [rad].
        offset_rad: f64,
        /// Amplitude [rad].
        amplitude_rad: f64,
        /// Frequency [Hz].
        freq_hz: f64,
        /// Start [s].
        #[serde(default)]
        start_s: f64,
    },
    /// Piecewise-constant random levels, uniform in `+-amplitude_rad`, each held `hold_s`;
    /// with `transition_s > 0` each change is a minimum-jerk move over the first
    /// `transition_s` of the new level's hold (from 0 rad for the first level).
    Random {
        /// Level bound [rad].
        amplitude_rad: f64,
        /// Hold time of each level [s].
        hold_s: f64,
        /// Duration of the minimum-jerk move into each level [s] (0: jumps), <= `hold_s`.
        #[serde(default)]
        transition_s: f64,
        /// Start [s] (0 rad before).
        #[serde(default)]
        start_s: f64,
    },
}

impl SetpointProfile {
    /// The set-point [rad] at time `t_s`; `levels` are the pre-drawn random levels.
    fn at(&self, t_s: f64, levels: &[f64]) -> f64 {
        match *self {
            SetpointProfile::Step {
                initial_rad,
                final_rad,
                at_s,
                transition_s,
            } => {
                if t_s < at_s {
                    initial_rad
                } else {
                    initial_rad + (final_rad - initial_rad) * min_jerk(t_s - at_s, transition_s)
                }
            }
            SetpointProfile::Ramp {
                from_rad,
                to_rad,
                start_s,
                end_s,
            } => {
                if t_s <= start_s {
                    from_rad
                } else if t_s >= end_s {
                    to_rad
                } else {
                    from_rad + (to_rad - from_rad) * (t_s - start_s) / (end_s - start_s)
                }
            }
            SetpointProfile::Sine {
                offset_rad,
                amplitude_rad,
                freq_hz,
                start_s,
            } => {
                if t_s < start_s {
                    offset_rad
                } else {
                    offset_rad
                        + amplitude_rad
                            * (2.0 * std::f64::consts::PI * freq_hz * (t_s - start_s)).sin()
                }
            }
            SetpointProfile::Random {
                hold_s,
                start_s,
                transition_s,
                ..
            } => {
                if t_s < start_s || levels.is_empty() {
                    0.0
                } else {
                    let i = (((t_s - start_s) / hold_s).floor() as usize).min(levels.len() - 1);
                    let from = if i == 0 { 0.0 } else { levels[i - 1] };
                    let since_s = t_s - start_s - i as f64 * hold_s;
                    from + (levels[i] - from) * min_jerk(since_s, transition_s)
                }
            }
        }
    }
}

/// The minimum-jerk blend `10 u^3 - 15 u^4 + 6 u^5` of `u = t / duration`, clamped to 0..1
/// (a jump, 1 for every `t >= 0`, when `duration_s <= 0`).
fn min_jerk(t_s: f64, duration_s: f64) -> f64 {
    if duration_s <= 0.0 || t_s >= duration_s {
        return 1.0;
    }
    let u = (t_s / duration_s).max(0.0);
    u * u * u * (10.0 + u * (-15.0 + 6.0 * u))
}

/// The fake sensors.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorModel {
    /// Pressure noise, standard deviation [Pa].
    #[serde(default = "default_p_noise")]
    pub pressure_noise_pa: f64,
    /// Pressure ADC resolution [Pa per count] (0: no quantisation).
    #[serde(default = "default_p_lsb")]
    pub pressure_lsb_pa: f64,
    /// Encoder counts per revolution (0: no quantisation).
    #[serde(default = "default_counts")]
    pub angle_counts_per_rev: u32,
    /// Transport delay of all sensors [ticks].
    #[serde(default)]
    pub delay_ticks: usize,
}

fn default_p_noise() -> f64 {
    500.0
}
fn default_p_lsb() -> f64 {
    // 12-bit ADC over 0..1 MPa gauge.
    1.0e6 / 4096.0
}
fn default_counts() -> u32 {
    8000
}

impl Default for SensorModel {
    fn default() -> Self {
        SensorModel {
            pressure_noise_pa: default_p_noise(),
            pressure_lsb_pa: default_p_lsb(),
            angle_counts_per_rev: default_counts(),
            delay_ticks: 0,
        }
    }
}

/// Sensor channels the firmware reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SensorChannel {
    /// Pressure of muscle 1.
    P1,
    /// Pressure of muscle 2.
    P2,
    /// Joint angle.
    Angle,
}

/// The four valves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ValveId {
    /// Inflate valve of muscle 1.
    In1,
    /// Exhaust valve of muscle 1.
    Ex1,
    /// Inflate valve of muscle 2.
    In2,
    /// Exhaust valve of muscle 2.
    Ex2,
}

/// Injected faults and plant changes.
#[derive(Debug, Clone, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Event {
    /// The joint inertia changes (a load is attached or removed).
    LoadInertia {
        /// Time [s].
        at_s: f64,
        /// New inertia [kg m^2].
        inertia_kgm2: f64,
    },
    /// The supply pressure changes (compressor loss: 0).
    SupplyLoss {
        /// Time [s].
        at_s: f64,
        /// New supply pressure, gauge [Pa].
        supply_gauge_pa: f64,
    },
    /// A sensor delivers no samples for a while.
    SensorDropout {
        /// Time [s].
        at_s: f64,
        /// Length [s].
        duration_s: f64,
        /// Which sensor.
        channel: SensorChannel,
    },
    /// A sensor delivers NaN for a while.
    SensorNan {
        /// Time [s].
        at_s: f64,
        /// Length [s].
        duration_s: f64,
        /// Which sensor.
        channel: SensorChannel,
    },
    /// A valve sticks open or closed from `at_s` on.
    StuckValve {
        /// Time [s].
        at_s: f64,
        /// Which valve.
        valve: ValveId,
        /// Stuck open (true) or closed (false).
        open: bool,
    },
}

/// What a run must achieve (all optional).
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Expectations {
    /// Largest |angle error| after `settle_after_s` [rad] (while no fault is latched).
    pub max_abs_error_rad: Option<f64>,
    /// Root-mean-square angle error after `settle_after_s` [rad].
    pub rms_error_rad: Option<f64>,
    /// Where the error bounds start [s].
    #[serde(default)]
    pub settle_after_s: f64,
    /// A fault must be latched within this many ticks of the first injected sensor fault.
    pub fault_within_ticks: Option<usize>,
    /// No fault may be latched during the run.
    #[serde(default)]
    pub no_fault: bool,
}

/// Errors of closed-loop runs.
#[derive(Debug, thiserror::Error)]
pub enum ClosedLoopError {
    /// The scenario file could not be read or parsed.
    #[error("{file}: {msg}")]
    Scenario {
        /// The file.
        file: String,
        /// What is wrong (the TOML parser's message names line and key).
        msg: String,
    },
    /// The plant integration failed.
    #[error(transparent)]
    Sim(#[from] SimError),
}

impl Scenario {
    /// Sets the minimum-jerk move duration of a `step` or `random` set-point (other
    /// profiles have none and are left alone).
    pub fn set_transition_s(&mut self, t_s: f64) {
        match &mut self.setpoint {
            SetpointProfile::Step { transition_s, .. }
            | SetpointProfile::Random { transition_s, .. } => *transition_s = t_s,
            _ => {}
        }
    }

    /// Reads and validates a scenario TOML file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ClosedLoopError> {
        let path = path.as_ref();
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| ClosedLoopError::Scenario {
            file: file.clone(),
            msg: e.to_string(),
        })?;
        Self::from_toml_str(&text, &file)
    }

    /// Parses and validates scenario TOML text (`file` names it in errors).
    pub fn from_toml_str(text: &str, file: &str) -> Result<Self, ClosedLoopError> {
        let s: Scenario = toml::from_str(text).map_err(|e| {
            let mut msg = e.to_string().trim_end().to_string();
            // Tagged tables (`[setpoint]`, `[[events]]`) are reported at their header line;
            // point at the offending key's own line too.
            if let Some(name) = msg
                .split("unknown field `")
                .nth(1)
                .and_then(|r| r.split('`').next())
            {
                if let Some((i, _)) = text
                    .lines()
                    .enumerate()
                    .find(|(_, l)| sets_key(l.trim(), name))
                {
                    msg = format!("line {}: key `{name}`: {msg}", i + 1);
                }
            }
            ClosedLoopError::Scenario {
                file: file.to_string(),
                msg,
            }
        })?;
        // Validation errors name the line of the offending key (the first line that sets
        // it inside its table) as the TOML parser's own errors do.
        let bad = |table: &str, key: &str, msg: String| {
            let at = key_line(text, table, key)
                .map(|l| format!("line {l}: "))
                .unwrap_or_default();
            ClosedLoopError::Scenario {
                file: file.to_string(),
                msg: format!("{at}[{table}] {key}: {msg}"),
            }
        };
        let h = &s.scenario;
        if !(h.duration_s > 0.0 && h.duration_s.is_finite()) {
            return Err(bad(
                "scenario",
                "duration_s",
                format!("{} must be > 0", h.duration_s),
            ));
        }
        if !(h.tick_hz >= 10.0 && h.tick_hz <= 100_000.0) {
            return Err(bad(
                "scenario",
                "tick_hz",
                format!("{} must be within 10..100000", h.tick_hz),
            ));
        }
        let finite = |key: &str, v: f64| -> Result<(), ClosedLoopError> {
            if v.is_finite() {
                Ok(())
            } else {
                Err(bad("setpoint", key, format!("{v} must be a finite number")))
            }
        };
        match s.setpoint {
            SetpointProfile::Step {
                initial_rad,
                final_rad,
                at_s,
                transition_s,
            } => {
                finite("initial_rad", initial_rad)?;
                finite("final_rad", final_rad)?;
                finite("at_s", at_s)?;
                if !(transition_s >= 0.0 && transition_s.is_finite()) {
                    return Err(bad(
                        "setpoint",
                        "transition_s",
                        format!("{transition_s} must be >= 0"),
                    ));
                }
            }
            SetpointProfile::Ramp {
                from_rad,
                to_rad,
                start_s,
                end_s,
            } => {
                finite("from_rad", from_rad)?;
                finite("to_rad", to_rad)?;
                finite("start_s", start_s)?;
                finite("end_s", end_s)?;
                if !(end_s > start_s) {
                    return Err(bad(
                        "setpoint",
                        "end_s",
                        format!("{end_s} must be > start_s"),
                    ));
                }
            }
            SetpointProfile::Sine {
                offset_rad,
                amplitude_rad,
                freq_hz,
                start_s,
            } => {
                finite("offset_rad", offset_rad)?;
                finite("amplitude_rad", amplitude_rad)?;
                finite("freq_hz", freq_hz)?;
                finite("start_s", start_s)?;
            }
            SetpointProfile::Random {
                amplitude_rad,
                hold_s,
                start_s,
                transition_s,
            } => {
                finite("amplitude_rad", amplitude_rad)?;
                finite("start_s", start_s)?;
                if !(hold_s > 0.0 && hold_s.is_finite()) {
                    return Err(bad("setpoint", "hold_s", format!("{hold_s} must be > 0")));
                }
                if !(transition_s >= 0.0 && transition_s <= hold_s) {
                    return Err(bad(
                        "setpoint",
                        "transition_s",
                        format!("{transition_s} must be within 0..hold_s ({hold_s})"),
                    ));
                }
            }
        }
        let se = &s.sensors;
        if !(se.pressure_noise_pa >= 0.0 && se.pressure_noise_pa.is_finite()) {
            return Err(bad(
                "sensors",
                "pressure_noise_pa",
                format!("{} must be >= 0", se.pressure_noise_pa),
            ));
        }
        if !(se.pressure_lsb_pa >= 0.0 && se.pressure_lsb_pa.is_finite()) {
            return Err(bad(
                "sensors",
                "pressure_lsb_pa",
                format!("{} must be >= 0", se.pressure_lsb_pa),
            ));
        }
        if se.delay_ticks > 10_000 {
            return Err(bad(
                "sensors",
                "delay_ticks",
                format!("{} is more than 10000 ticks", se.delay_ticks),
            ));
        }
        for (i, e) in s.events.iter().enumerate() {
            let ev_bad = |key: &str, msg: String| -> Result<(), ClosedLoopError> {
                let at = event_key_line(text, i, key)
                    .map(|l| format!("line {l}: "))
                    .unwrap_or_default();
                Err(ClosedLoopError::Scenario {
                    file: file.to_string(),
                    msg: format!("{at}[[events]] #{} {key}: {msg}", i + 1),
                })
            };
            let at_s = event_time(e);
            if !(at_s >= 0.0 && at_s.is_finite()) {
                ev_bad("at_s", format!("{at_s} must be a finite time >= 0"))?;
            }
            match *e {
                Event::SensorDropout { duration_s, .. } | Event::SensorNan { duration_s, .. } => {
                    if !(duration_s > 0.0 && duration_s.is_finite()) {
                        ev_bad("duration_s", format!("{duration_s} must be > 0"))?;
                    }
                }
                Event::LoadInertia { inertia_kgm2, .. } => {
                    if !(inertia_kgm2 > 0.0 && inertia_kgm2.is_finite()) {
                        ev_bad("inertia_kgm2", format!("{inertia_kgm2} must be > 0"))?;
                    }
                }
                Event::SupplyLoss {
                    supply_gauge_pa, ..
                } => {
                    if !(supply_gauge_pa >= 0.0 && supply_gauge_pa.is_finite()) {
                        ev_bad("supply_gauge_pa", format!("{supply_gauge_pa} must be >= 0"))?;
                    }
                }
                Event::StuckValve { .. } => {}
            }
        }
        Ok(s)
    }
}

/// 1-based line of `key = ...` inside `[table]` of TOML `text`, if it is there.
fn key_line(text: &str, table: &str, key: &str) -> Option<usize> {
    let mut in_table = false;
    for (i, line) in text.lines().enumerate() {
        let l = line.trim();
        if l.starts_with('[') {
            in_table = l.trim_start_matches('[').trim_end_matches(']').trim() == table;
            continue;
        }
        if in_table && sets_key(l, key) {
            return Some(i + 1);
        }
    }
    None
}

/// 1-based line of `key = ...` inside the `index`-th `[[events]]` table.
fn event_key_line(text: &str, index: usize, key: &str) -> Option<usize> {
    let mut n: Option<usize> = None;
    let mut in_table = false;
    for (i, line) in text.lines().enumerate() {
        let l = line.trim();
        if l.starts_with('[') {
            in_table = l == "[[events]]" && {
                n = Some(n.map_or(0, |n| n + 1));
                n == Some(index)
            };
            continue;
        }
        if in_table && sets_key(l, key) {
            return Some(i + 1);
        }
    }
    None
}

fn sets_key(line: &str, key: &str) -> bool {
    line.strip_prefix(key)
        .is_some_and(|rest| rest.trim_start().starts_with('='))
}

// ---------------------------------------------------------------------------------------
// Fake hardware.

/// A fake GPIO pin: the driver writes it, a stuck valve overrides it.
#[derive(Clone, Default)]
pub struct FakePin {
    state: Rc<Cell<bool>>,
    stuck: Rc<Cell<Option<bool>>>,
}

impl FakePin {
    /// What the valve actually does.
    pub fn open(&self) -> bool {
        self.stuck.get().unwrap_or(self.state.get())
    }
}

impl embedded_hal::digital::ErrorType for FakePin {
    type Error = core::convert::Infallible;
}

impl embedded_hal::digital::OutputPin for FakePin {
    fn set_low(&mut self) -> Result<(), Self::Error> {
        self.state.set(false);
        Ok(())
    }
    fn set_high(&mut self) -> Result<(), Self::Error> {
        self.state.set(true);
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------
// The run.

/// One tick of a closed-loop run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TickRow {
    /// Time [s].
    pub t_s: f64,
    /// Set-point [rad].
    pub setpoint_rad: f64,
    /// True plant state at `t_s`.
    pub state: PlantState,
    /// Effective valve openings over `[t_s, t_s + dt)`.
    pub inputs: ValveInputs,
    /// The firmware's output.
    pub out: TickOutput,
}

/// A finished closed-loop run.
#[derive(Debug, Clone)]
pub struct ClosedLoopRun {
    /// Scenario name.
    pub name: String,
    /// Tick period [s].
    pub dt_s: f64,
    /// One row per tick.
    pub rows: Vec<TickRow>,
    /// Tick of the first injected sensor fault, if any.
    pub first_injected_fault_tick: Option<usize>,
    /// Tick at which the firmware first latched a fault, if any.
    pub first_latched_fault_tick: Option<usize>,
    /// Expectations of the scenario.
    pub expect: Expectations,
    /// Highest gauge pressure seen in either muscle [Pa].
    pub max_p_gauge_pa: f64,
    /// Highest pressure set-point the firmware issued [Pa].
    pub max_p_set_gauge_pa: f64,
    /// Integrator work over the run (steps, right-hand-side evaluations).
    pub sim_stats: SimStats,
}

/// Runs `scenario` with the firmware's reference controller on `plant`.
pub fn run(plant: &Plant, scenario: &Scenario) -> Result<ClosedLoopRun, ClosedLoopError> {
    let cfg = ControllerConfig::reference(scenario.scenario.tick_hz as f32);
    run_with(plant, scenario, cfg, &mut |_| {})
}

/// Runs `scenario` with a given controller configuration; `progress` gets the fraction done.
pub fn run_with(
    plant: &Plant,
    scenario: &Scenario,
    cfg: ControllerConfig,
    progress: &mut dyn FnMut(f64),
) -> Result<ClosedLoopRun, ClosedLoopError> {
    let dt_s = 1.0 / scenario.scenario.tick_hz;
    let n_ticks = (scenario.scenario.duration_s / dt_s).round() as usize;
    let mut rng = rand::rngs::StdRng::seed_from_u64(scenario.scenario.seed);

    // Random set-point levels, drawn once.
    let levels: Vec<f64> = match scenario.setpoint {
        SetpointProfile::Random {
            amplitude_rad,
            hold_s,
            ..
        } => {
            let n = (scenario.scenario.duration_s / hold_s).ceil() as usize + 1;
            let u = rand_distr::Uniform::new_inclusive(-amplitude_rad, amplitude_rad)
                .expect("finite amplitude");
            (0..n).map(|_| u.sample(&mut rng)).collect()
        }
        _ => Vec::new(),
    };

    // Plant versions: one per plant-changing event, in time order.
    let mut changes: Vec<(usize, Plant)> = Vec::new();
    let mut current = plant.clone();
    let mut plant_events: Vec<&Event> = scenario
        .events
        .iter()
        .filter(|e| matches!(e, Event::LoadInertia { .. } | Event::SupplyLoss { .. }))
        .collect();
    plant_events.sort_by(|a, b| event_time(a).total_cmp(&event_time(b)));
    for e in plant_events {
        match *e {
            Event::LoadInertia { at_s, inertia_kgm2 } => {
                current.joint.inertia_kgm2 = inertia_kgm2;
                changes.push(((at_s / dt_s).round() as usize, current.clone()));
            }
            Event::SupplyLoss {
                at_s,
                supply_gauge_pa,
            } => {
                current.p_supply_abs_pa = supply_gauge_pa + current.p_atm_pa;
                changes.push(((at_s / dt_s).round() as usize, current.clone()));
            }
            _ => {}
        }
    }
    let mut plants: Vec<(usize, Plant)> = vec![(0, plant.clone())];
    plants.extend(changes);

    let pins: [FakePin; 4] = Default::default();
    let mut valves = OnOffValves::new(
        pins[0].clone(),
        pins[1].clone(),
        pins[2].clone(),
        pins[3].clone(),
        OnOffPwmConfig::REFERENCE,
    );
    let mut tick = ControlTick::new(cfg);
    let opts = SolverOptions {
        rtol: 1e-6,
        atol: 1e-6,
        ..SolverOptions::default()
    };
    let mut plant_idx = 0;
    let mut stats_done = SimStats::default();
    let mut integ = Integrator::new(&plants[0].1, plant.initial_state(), opts);
    let p_noise =
        Normal::new(0.0, scenario.sensors.pressure_noise_pa.max(0.0)).expect("finite noise");
    let mut delay: VecDeque<SensorFrame> = VecDeque::new();
    let mut rows = Vec::with_capacity(n_ticks);
    let mut first_injected = None;
    let mut first_latched = None;
    let mut max_p = f64::NEG_INFINITY;
    let mut max_p_set = f64::NEG_INFINITY;

    for k in 0..n_ticks {
        let t_s = k as f64 * dt_s;
        while plant_idx + 1 < plants.len() && plants[plant_idx + 1].0 <= k {
            plant_idx += 1;
            let x = integ.state();
            let p_tank = integ.supply_abs_pa();
            stats_done.add(&integ.stats());
            integ = Integrator::new(&plants[plant_idx].1, x, opts);
            integ.set_supply_abs_pa(p_tank); // a supply reservoir keeps its pressure
        }
        let p = &plants[plant_idx].1;
        let x = integ.state();
        let m = p.measure(&x);
        max_p = max_p.max((x.p1_abs_pa - p.p_atm_pa).max(x.p2_abs_pa - p.p_atm_pa));

        // Fake sensors: noise, quantisation.
        let quant_p = |pa: f64, rng: &mut rand::rngs::StdRng| {
            let v = pa + p_noise.sample(rng);
            let lsb = scenario.sensors.pressure_lsb_pa;
            (if lsb > 0.0 {
                (v / lsb).round() * lsb
            } else {
                v
            }) as f32
        };
        let p1 = quant_p(m.p1_kpa * 1e3, &mut rng);
        let p2 = quant_p(m.p2_kpa * 1e3, &mut rng);
        let angle_rad = m.angle_deg.to_radians();
        let counts = scenario.sensors.angle_counts_per_rev;
        let angle = if counts > 0 {
            let c = (angle_rad / (2.0 * std::f64::consts::PI) * counts as f64).floor() as i32;
            pam_firmware::sensors::counts_to_rad(c, counts)
        } else {
            angle_rad as f32
        };
        let mut frame = SensorFrame {
            p1_gauge_pa: Some(p1),
            p2_gauge_pa: Some(p2),
            angle_rad: Some(angle),
        };
        // Injected sensor faults.
        for e in &scenario.events {
            let (at_s, duration_s, channel, nan) = match *e {
                Event::SensorDropout {
                    at_s,
                    duration_s,
                    channel,
                } => (at_s, duration_s, channel, false),
                Event::SensorNan {
                    at_s,
                    duration_s,
                    channel,
                } => (at_s, duration_s, channel, true),
                _ => continue,
            };
            if t_s + 0.5 * dt_s >= at_s && t_s < at_s + duration_s {
                let slot = match channel {
                    SensorChannel::P1 => &mut frame.p1_gauge_pa,
                    SensorChannel::P2 => &mut frame.p2_gauge_pa,
                    SensorChannel::Angle => &mut frame.angle_rad,
                };
                *slot = if nan { Some(f32::NAN) } else { None };
                first_injected.get_or_insert(k);
            }
        }
        // Transport delay.
        delay.push_back(frame);
        let frame = if delay.len() > scenario.sensors.delay_ticks {
            delay.pop_front().unwrap_or_default()
        } else {
            SensorFrame::default()
        };

        let setpoint_rad = scenario.setpoint.at(t_s, &levels);
        let out = tick.step(
            &frame,
            &Setpoint {
                angle_rad: setpoint_rad as f32,
            },
            dt_s as f32,
        );
        max_p_set = max_p_set.max(out.p1_set_gauge_pa.max(out.p2_set_gauge_pa) as f64);
        if out.fault.is_some() {
            first_latched.get_or_insert(k);
        }
        // Stuck valves from their time on.
        for e in &scenario.events {
            if let Event::StuckValve { at_s, valve, open } = *e {
                if t_s + 0.5 * dt_s >= at_s {
                    let i = match valve {
                        ValveId::In1 => 0,
                        ValveId::Ex1 => 1,
                        ValveId::In2 => 2,
                        ValveId::Ex2 => 3,
                    };
                    pins[i].stuck.set(Some(open));
                }
            }
        }
        // Infallible pins: the driver cannot fail here.
        let _ = valves.apply(&out.valves);
        let b = |pin: &FakePin| if pin.open() { 1.0 } else { 0.0 };
        let inputs = ValveInputs {
            u_in1: b(&pins[0]),
            u_ex1: b(&pins[1]),
            u_in2: b(&pins[2]),
            u_ex2: b(&pins[3]),
        };
        rows.push(TickRow {
            t_s,
            setpoint_rad,
            state: x,
            inputs,
            out,
        });
        integ.advance(inputs, dt_s)?;
        if k % 1000 == 0 {
            progress(k as f64 / n_ticks.max(1) as f64);
        }
    }
    progress(1.0);
    stats_done.add(&integ.stats());
    Ok(ClosedLoopRun {
        name: scenario.scenario.name.clone(),
        dt_s,
        rows,
        first_injected_fault_tick: first_injected,
        first_latched_fault_tick: first_latched,
        expect: scenario.expect.clone(),
        max_p_gauge_pa: max_p,
        max_p_set_gauge_pa: max_p_set,
        sim_stats: stats_done,
    })
}

fn event_time(e: &Event) -> f64 {
    match *e {
        Event::LoadInertia { at_s, .. }
        | Event::SupplyLoss { at_s, .. }
        | Event::SensorDropout { at_s, .. }
        | Event::SensorNan { at_s, .. }
        | Event::StuckValve { at_s, .. } => at_s,
    }
}

/// Tracking statistics of a run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackingStats {
    /// Mean squared angle error [rad^2] after the settle time.
    pub mse_rad2: f64,
    /// Root-mean-square angle error [rad].
    pub rms_rad: f64,
    /// Largest |angle error| [rad].
    pub max_abs_rad: f64,
    /// Samples counted.
    pub n: usize,
}

impl ClosedLoopRun {
    /// Tracking error statistics from `after_s` on, over the ticks without a latched fault.
    pub fn tracking(&self, after_s: f64) -> TrackingStats {
        let mut sum = 0.0;
        let mut max: f64 = 0.0;
        let mut n = 0;
        for r in &self.rows {
            if r.t_s < after_s || r.out.fault.is_some() {
                continue;
            }
            let e = r.state.angle_rad - r.setpoint_rad;
            sum += e * e;
            max = max.max(e.abs());
            n += 1;
        }
        let mse = if n > 0 { sum / n as f64 } else { f64::NAN };
        TrackingStats {
            mse_rad2: mse,
            rms_rad: mse.sqrt(),
            max_abs_rad: max,
            n,
        }
    }

    /// Checks the scenario's expectations; returns the failures as sentences.
    pub fn check(&self) -> Vec<String> {
        let mut fails = Vec::new();
        let e = &self.expect;
        let st = self.tracking(e.settle_after_s);
        if let Some(b) = e.max_abs_error_rad {
            if !(st.max_abs_rad <= b) {
                fails.push(format!(
                    "max |angle error| {:.4} rad > {b} rad after {} s",
                    st.max_abs_rad, e.settle_after_s
                ));
            }
        }
        if let Some(b) = e.rms_error_rad {
            if !(st.rms_rad <= b) {
                fails.push(format!(
                    "rms angle error {:.4} rad > {b} rad after {} s",
                    st.rms_rad, e.settle_after_s
                ));
            }
        }
        if let Some(b) = e.fault_within_ticks {
            match (
                self.first_injected_fault_tick,
                self.first_latched_fault_tick,
            ) {
                (Some(i), Some(l)) if l >= i && l - i <= b => {}
                (i, l) => fails.push(format!(
                    "fault latched at tick {l:?}, injected at {i:?}: not within {b} ticks"
                )),
            }
        }
        if e.no_fault {
            if let Some(l) = self.first_latched_fault_tick {
                fails.push(format!(
                    "a fault ({:?}) was latched at tick {l}",
                    self.rows[l].out.fault
                ));
            }
        }
        if self.max_p_set_gauge_pa > pam_firmware::P_MUSCLE_MAX_GAUGE_PA as f64 {
            fails.push(format!(
                "pressure set-point {:.0} Pa above the muscle limit",
                self.max_p_set_gauge_pa
            ));
        }
        fails
    }

    /// The run as a recording (RECORDING.md channels from the true plant state) for
    /// `host-sim fit` / `--plot`.
    pub fn to_recording(&self, plant: &Plant) -> Recording {
        let mut rec = Recording::default();
        rec.metadata.push((
            "source".into(),
            format!("host-sim closed loop, scenario {}", self.name),
        ));
        rec.metadata
            .push(("sample_period_s".into(), format!("{}", self.dt_s)));
        let mut ch: [Vec<f64>; 5] = Default::default();
        for r in &self.rows {
            rec.t_s.push(r.t_s);
            rec.inputs.push(r.inputs);
            let m = plant.measure(&r.state).to_array();
            for (c, v) in ch.iter_mut().zip(m) {
                c.push(v);
            }
        }
        for (c, v) in [
            Channel::AngleDeg,
            Channel::P1Kpa,
            Channel::P2Kpa,
            Channel::F1N,
            Channel::F2N,
        ]
        .into_iter()
        .zip(ch)
        {
            rec.set_channel(c, v);
        }
        rec
    }
}
