//! Closed-loop scenario files (TOML): the set-point profile, the sensor model, injected
//! events (faults, load and supply changes) and the `[expect]` bounds. Errors name the
//! file, line and key.

use std::path::Path;

use pam_firmware::profile;
use serde::Deserialize;

use crate::sim::SimError;

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
    /// Name used in reports and as the stem of `demo`'s output files: letters, digits,
    /// `_`, `.`, `-` only, not starting with `.` (no path).
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

fn larger(a: (&'static str, f64), b: (&'static str, f64)) -> (&'static str, f64) {
    if b.1.abs() > a.1.abs() {
        (b.0, b.1.abs())
    } else {
        (a.0, a.1.abs())
    }
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
    /// The profile's largest |set-point| [rad] and the key that gives it (for a sine the
    /// offset plus the amplitude).
    pub fn extreme_rad(&self) -> (&'static str, f64) {
        match *self {
            SetpointProfile::Step {
                initial_rad,
                final_rad,
                ..
            } => larger(("initial_rad", initial_rad), ("final_rad", final_rad)),
            SetpointProfile::Ramp {
                from_rad, to_rad, ..
            } => larger(("from_rad", from_rad), ("to_rad", to_rad)),
            SetpointProfile::Sine {
                offset_rad,
                amplitude_rad,
                ..
            } => (
                "offset_rad + amplitude_rad",
                offset_rad.abs() + amplitude_rad.abs(),
            ),
            SetpointProfile::Random { amplitude_rad, .. } => ("amplitude_rad", amplitude_rad.abs()),
        }
    }

    /// Refuses a profile that asks for more than the controller's set-point limit
    /// (`ControllerConfig::angle_setpoint_max_rad`): the firmware would clamp it, and the run
    /// would test a smaller move than the file says (and fail its `[expect]` for that reason).
    /// `text` is the scenario file's text (the error names the key's line), `file` its name.
    pub fn check_within(
        &self,
        text: &str,
        file: &str,
        limit_rad: f32,
    ) -> Result<(), ClosedLoopError> {
        let (key, v) = self.extreme_rad();
        if v > f64::from(limit_rad) {
            // A sine's extreme is two keys: the line of the first (`offset_rad`).
            let first_key = key.split(' ').next().unwrap_or(key);
            let at = key_line(text, "setpoint", first_key)
                .map(|l| format!("line {l}: "))
                .unwrap_or_default();
            return Err(ClosedLoopError::Scenario {
                file: file.to_string(),
                msg: format!(
                    "{at}[setpoint] {key}: {} rad is beyond the firmware's set-point limit of \
                     +-{limit_rad} rad (angle_setpoint_max_rad of the controller \
                     configuration): the tick would clamp it, and the run would test a smaller \
                     move than the file asks; give at most {limit_rad} rad",
                    crate::validate::Shown(v),
                ),
            });
        }
        Ok(())
    }

    /// Checks the profile's values against the run `h` (angles within half a turn, times
    /// before the end of the run, a sine below half the tick rate); `bad(key, message)`
    /// makes the error naming the key. The 1-DOF `[setpoint]` and each arm joint's profile.
    pub(crate) fn check(
        &self,
        h: &ScenarioHeader,
        bad: &dyn Fn(&str, String) -> ClosedLoopError,
    ) -> Result<(), ClosedLoopError> {
        let finite = |key: &str, v: f64| -> Result<(), ClosedLoopError> {
            if v.is_finite() {
                Ok(())
            } else {
                Err(bad(key, format!("{v} must be a finite number")))
            }
        };
        // A set-point angle beyond half a turn is a unit mistake (degrees typed into a
        // `_rad` key), and a set-point change at or after the end of the run tests nothing.
        let angle = |key: &str, v: f64| -> Result<(), ClosedLoopError> {
            finite(key, v)?;
            if v.abs() > std::f64::consts::PI {
                return Err(bad(
                    key,
                    format!("{v} rad is more than half a turn (allowed -pi..=pi): degrees typed as radians?"),
                ));
            }
            Ok(())
        };
        let before_end = |key: &str, v: f64| -> Result<(), ClosedLoopError> {
            finite(key, v)?;
            if !(v >= 0.0 && v < h.duration_s) {
                return Err(bad(
                    key,
                    format!(
                        "{v} s must be within [0, {}) (before the end of the run, [scenario] \
                         duration_s): the set-point would never move",
                        h.duration_s
                    ),
                ));
            }
            Ok(())
        };
        // A change from `from_s` that ends at `to_s`, after the end of the run: refused with the
        // share of it the run would cover.
        let ends_within = |key: &str, from_s: f64, to_s: f64| -> Result<(), ClosedLoopError> {
            if to_s > h.duration_s {
                let covered = 100.0 * (h.duration_s - from_s) / (to_s - from_s);
                return Err(bad(
                    key,
                    format!(
                        "the set-point change from {from_s} s ends at {to_s} s, after the end of \
                         the run ([scenario] duration_s = {} s): the run would cover {covered:.1} % \
                         of it and test a smaller move than the file asks (milliseconds typed \
                         as seconds?); end it within the run or lengthen duration_s",
                        h.duration_s
                    ),
                ));
            }
            Ok(())
        };
        // Every profile: its set-point angles, and the time its change starts (before the end).
        let (angles, start): (&[(&str, f64)], (&str, f64)) = match self {
            SetpointProfile::Step {
                initial_rad,
                final_rad,
                at_s,
                ..
            } => (
                &[("initial_rad", *initial_rad), ("final_rad", *final_rad)],
                ("at_s", *at_s),
            ),
            SetpointProfile::Ramp {
                from_rad,
                to_rad,
                start_s,
                ..
            } => (
                &[("from_rad", *from_rad), ("to_rad", *to_rad)],
                ("start_s", *start_s),
            ),
            SetpointProfile::Sine {
                offset_rad,
                amplitude_rad,
                start_s,
                ..
            } => (
                &[
                    ("offset_rad", *offset_rad),
                    ("amplitude_rad", *amplitude_rad),
                ],
                ("start_s", *start_s),
            ),
            SetpointProfile::Random {
                amplitude_rad,
                start_s,
                ..
            } => (&[("amplitude_rad", *amplitude_rad)], ("start_s", *start_s)),
        };
        for (key, v) in angles {
            angle(key, *v)?;
        }
        before_end(start.0, start.1)?;
        // And its own constraints.
        match *self {
            SetpointProfile::Step {
                at_s, transition_s, ..
            } => {
                if !(transition_s >= 0.0 && transition_s.is_finite()) {
                    return Err(bad("transition_s", format!("{transition_s} must be >= 0")));
                }
                // The move must end within the run, or the run tests part of it and its
                // `[expect]` bounds judge a move the file did not ask for.
                ends_within("transition_s", at_s, at_s + transition_s)?;
            }
            SetpointProfile::Ramp { start_s, end_s, .. } => {
                finite("end_s", end_s)?;
                if !(end_s > start_s) {
                    return Err(bad("end_s", format!("{end_s} must be > start_s")));
                }
                ends_within("end_s", start_s, end_s)?;
            }
            SetpointProfile::Sine { freq_hz, .. } => {
                finite("freq_hz", freq_hz)?;
                let nyquist_hz = 0.5 * h.tick_hz;
                if !(freq_hz > 0.0 && freq_hz < nyquist_hz) {
                    return Err(bad(
                        "freq_hz",
                        format!(
                            "{freq_hz} Hz must be within (0, {nyquist_hz}) (below half the tick \
                             rate, [scenario] tick_hz)"
                        ),
                    ));
                }
            }
            SetpointProfile::Random {
                hold_s,
                transition_s,
                ..
            } => {
                if !(hold_s > 0.0 && hold_s.is_finite()) {
                    return Err(bad("hold_s", format!("{hold_s} must be > 0")));
                }
                if !(transition_s >= 0.0 && transition_s <= hold_s) {
                    return Err(bad(
                        "transition_s",
                        format!("{transition_s} must be within 0..hold_s ({hold_s})"),
                    ));
                }
            }
        }
        Ok(())
    }

    /// The set-point [rad] at time `t_s`; `levels` are the pre-drawn random levels.
    pub(crate) fn at(&self, t_s: f64, levels: &[f64]) -> f64 {
        // The shapes are the firmware's (`pam_firmware::profile`), evaluated in f64.
        match *self {
            SetpointProfile::Step {
                initial_rad,
                final_rad,
                at_s,
                transition_s,
            } => profile::step_at(t_s, initial_rad, final_rad, at_s, transition_s),
            SetpointProfile::Ramp {
                from_rad,
                to_rad,
                start_s,
                end_s,
            } => profile::ramp_at(t_s, from_rad, to_rad, start_s, end_s),
            SetpointProfile::Sine {
                offset_rad,
                amplitude_rad,
                freq_hz,
                start_s,
            } => profile::sine_at(t_s, offset_rad, amplitude_rad, freq_hz, start_s),
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
                    profile::step_at(since_s, from, levels[i], 0.0, transition_s)
                }
            }
        }
    }
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
    /// Deliver the sensors in the board's raw units (12-bit ADC counts through the board's
    /// pressure wiring, 8000-count encoder: `pam_firmware::wiring`) and convert them with the
    /// firmware's own scaling and sequence gates, as the board and the processor-in-the-loop
    /// image (`host-sim pil`) do. `pressure_lsb_pa` and `angle_counts_per_rev` are then not
    /// used. Off by default (the stored control scores were measured without it).
    #[serde(default)]
    pub board_counts: bool,
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
            board_counts: false,
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
    /// A sensor freezes for a while: its value and its sequence counter (DMA transfer count)
    /// stop, so the firmware's sequence gate sees no new sample.
    SensorStuck {
        /// Time [s].
        at_s: f64,
        /// Length [s].
        duration_s: f64,
        /// Which sensor.
        channel: SensorChannel,
    },
    /// A sensor's reading jumps by `offset` (Pa for pressures, rad for the angle) and stays
    /// offset.
    SensorStep {
        /// Time [s].
        at_s: f64,
        /// Which sensor.
        channel: SensorChannel,
        /// The offset [Pa or rad].
        offset: f64,
    },
    /// One control tick runs late: the firmware measures a period of `factor` nominal
    /// periods at `at_s`.
    TickOverrun {
        /// Time [s].
        at_s: f64,
        /// Measured period / nominal period (> 0).
        factor: f64,
    },
    /// The MCU resets at `at_s`: the control tick restarts from the persistent latch
    /// (`power_on`: a power-on reset; otherwise a watchdog / brown-out / software reset).
    FirmwareReset {
        /// Time [s].
        at_s: f64,
        /// A power-on reset (true) or any other reset (false).
        #[serde(default)]
        power_on: bool,
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
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Expectations {
    /// Largest |angle error| after `settle_after_s` [rad] (while no fault is latched).
    pub max_abs_error_rad: Option<f64>,
    /// Root-mean-square angle error after `settle_after_s` [rad].
    pub rms_error_rad: Option<f64>,
    /// Where the error bounds start [s].
    #[serde(default)]
    pub settle_after_s: f64,
    /// A fault must be latched, within this many ticks of the injection of the fault that
    /// caused it: the latest injected fault (sensor NaN / dropout, stuck valve, supply loss)
    /// that started at or before the latch. An earlier, harmless injection does not count.
    pub fault_within_ticks: Option<usize>,
    /// Highest gauge pressure of either muscle over the whole run [kPa] (the plant's
    /// pressure, not the set-point).
    pub max_pressure_kpa: Option<f64>,
    /// The joint angle must stay within `+-angle_within_rad` over the whole run [rad].
    pub angle_within_rad: Option<f64>,
    /// No fault may be latched during the run.
    #[serde(default)]
    pub no_fault: bool,
}

impl Expectations {
    /// True when the scenario sets no bound (no `[expect]` table, or an empty one): a run
    /// then has nothing to meet, and says so rather than "met".
    pub fn is_empty(&self) -> bool {
        // Every bound at its default (absent); `settle_after_s` only says where they start.
        Self {
            settle_after_s: 0.0,
            ..self.clone()
        } == Self::default()
    }
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
    /// The plant integration failed at a tick even with the fallback integrator.
    #[error("plant integration failed at t = {t_s:.6} s of the run, state {state:?}: {source}")]
    SimAt {
        /// Run time of the failing tick [s].
        t_s: f64,
        /// Plant state at the start of that tick.
        state: crate::plant::PlantState,
        /// The integrator's error.
        source: SimError,
    },
    /// The firmware side of the loop failed (emulator link, timeout, faulting firmware).
    #[error("tick {tick}: {msg}")]
    Firmware {
        /// Tick at which it failed.
        tick: usize,
        /// What happened.
        msg: String,
    },
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
        let (text, file) = read_scenario_text(path.as_ref())?;
        Self::from_toml_str(&text, &file)
    }

    /// Parses and validates scenario TOML text (`file` names it in errors).
    pub fn from_toml_str(text: &str, file: &str) -> Result<Self, ClosedLoopError> {
        let s: Scenario = toml::from_str(text).map_err(|e| {
            let mut msg = toml_error_message(&e, text);
            // An arm scenario (waypoints of three joints) given where a 1-DOF one belongs.
            let arm = text
                .parse::<toml::Table>()
                .ok()
                .and_then(|d| d.get("setpoint")?.as_table()?.get("waypoints").cloned())
                .is_some();
            if arm {
                msg.push_str(
                    "\n  this is a 3-DOF arm scenario ([setpoint] waypoints, scenarios/arm3/): it \
                     runs on an arm plant file with `host-sim demo --plant \
                     host-sim/plants/arm3-seed001.toml --scenario FILE`",
                );
            }
            ClosedLoopError::Scenario {
                file: file.to_string(),
                msg,
            }
        })?;
        let bad = key_error(text, file);
        s.scenario.check(&bad)?;
        let h = &s.scenario;
        s.setpoint.check(h, &|key, msg| bad("setpoint", key, msg))?;
        s.sensors.check(&|key, msg| bad("sensors", key, msg))?;
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
                Event::SensorDropout { duration_s, .. }
                | Event::SensorNan { duration_s, .. }
                | Event::SensorStuck { duration_s, .. } => {
                    if !(duration_s > 0.0 && duration_s.is_finite()) {
                        ev_bad("duration_s", format!("{duration_s} must be > 0"))?;
                    }
                }
                Event::LoadInertia { inertia_kgm2, .. } => {
                    // The plant file's own range for the joint's inertia.
                    if let Some(msg) = crate::validate::range_error(
                        "inertia_kgm2",
                        inertia_kgm2,
                        crate::plant::config::INERTIA_KGM2,
                        crate::plant::config::INERTIA_UNIT,
                    ) {
                        ev_bad("inertia_kgm2", msg)?;
                    }
                }
                Event::SupplyLoss {
                    supply_gauge_pa, ..
                } => {
                    // 0 (a complete loss) or a supply in the plant file's range; a few Pa is
                    // a value in bar or kPa.
                    let range = crate::plant::config::SUPPLY_GAUGE_PA;
                    if !(supply_gauge_pa == 0.0 || range.contains(supply_gauge_pa)) {
                        let hint = if supply_gauge_pa > 0.0 && supply_gauge_pa < range.lo {
                            format!(
                                " (bar or kPa typed into a Pa key? {} bar is {} Pa, {} kPa is \
                                 {} Pa)",
                                crate::validate::Shown(supply_gauge_pa),
                                crate::validate::Shown(supply_gauge_pa * 1e5),
                                crate::validate::Shown(supply_gauge_pa),
                                crate::validate::Shown(supply_gauge_pa * 1e3)
                            )
                        } else {
                            String::new()
                        };
                        ev_bad(
                            "supply_gauge_pa",
                            format!(
                                "must be 0 (a complete loss) or within {range} Pa gauge, got \
                                 {}{hint}",
                                crate::validate::Shown(supply_gauge_pa)
                            ),
                        )?;
                    }
                }
                Event::SensorStep { offset, .. } => {
                    if !offset.is_finite() {
                        ev_bad("offset", format!("{offset} must be a finite number"))?;
                    }
                }
                Event::TickOverrun { factor, .. } => {
                    if !(factor > 0.0 && factor <= 1000.0) {
                        ev_bad("factor", format!("{factor} must be within (0, 1000]"))?;
                    }
                }
                Event::StuckValve { .. } | Event::FirmwareReset { .. } => {}
            }
            if at_s >= h.duration_s {
                ev_bad(
                    "at_s",
                    format!(
                        "{at_s} is not before the end of the run ([scenario] duration_s = {}): \
                         the event would never happen",
                        h.duration_s
                    ),
                )?;
            }
        }
        let ex = &s.expect;
        check_expect(
            h,
            ex.settle_after_s,
            ex.max_pressure_kpa,
            &[
                ("max_abs_error_rad", ex.max_abs_error_rad),
                ("rms_error_rad", ex.rms_error_rad),
                ("angle_within_rad", ex.angle_within_rad),
            ],
            &|key, msg| bad("expect", key, msg),
        )?;
        Ok(s)
    }
}

/// Largest `[sensors] pressure_noise_pa` and `pressure_lsb_pa` [Pa]: 100 kPa, a tenth of
/// the pressure sensors' range; above it the firmware sees only noise (its pressure checks
/// latch a fault at the first tick).
pub const SENSOR_PA_MAX: f64 = 1.0e5;

impl SensorModel {
    /// The `[sensors]` ranges (1-DOF and arm scenarios); `bad(key, message)` makes the
    /// error naming the key.
    pub(crate) fn check(
        &self,
        bad: &dyn Fn(&str, String) -> ClosedLoopError,
    ) -> Result<(), ClosedLoopError> {
        let range = crate::validate::Range::closed(0.0, SENSOR_PA_MAX);
        for (key, v, what) in [
            (
                "pressure_noise_pa",
                self.pressure_noise_pa,
                "Pa (a standard deviation)",
            ),
            ("pressure_lsb_pa", self.pressure_lsb_pa, "Pa per count"),
        ] {
            if let Some(msg) = crate::validate::range_error(key, v, range, what) {
                return Err(bad(key, msg));
            }
        }
        let counts = self.angle_counts_per_rev;
        if counts != 0 && counts < crate::validate::MIN_ENCODER_COUNTS_PER_REV {
            return Err(bad(
                "angle_counts_per_rev",
                format!(
                    "{counts} counts per revolution is coarser than one a degree (allowed: 0 \
                     for no quantisation, or >= {})",
                    crate::validate::MIN_ENCODER_COUNTS_PER_REV
                ),
            ));
        }
        if self.delay_ticks > 10_000 {
            return Err(bad(
                "delay_ticks",
                format!("{} is more than 10000 ticks", self.delay_ticks),
            ));
        }
        Ok(())
    }
}

/// The `[expect]` values both the 1-DOF and the arm scenarios have: `settle_after_s` before
/// the end of the run `h`, a gauge pressure bound in kPa, angle bounds (`(key, bound)`,
/// one per joint for the arm) within (0, pi]; `bad(key, message)` makes the error.
pub(crate) fn check_expect(
    h: &ScenarioHeader,
    settle_after_s: f64,
    max_pressure_kpa: Option<f64>,
    error_bounds_rad: &[(&str, Option<f64>)],
    bad: &dyn Fn(&str, String) -> ClosedLoopError,
) -> Result<(), ClosedLoopError> {
    if let Some(v) = max_pressure_kpa {
        if !(v > 0.0 && v <= 2000.0) {
            return Err(bad(
                "max_pressure_kpa",
                format!(
                    "{} kPa must be within (0, 2000] (gauge, in kPa: Pa typed?)",
                    crate::validate::Shown(v)
                ),
            ));
        }
    }
    if !(settle_after_s >= 0.0 && settle_after_s < h.duration_s) {
        return Err(bad(
            "settle_after_s",
            format!(
                "{} must be within [0, {}) (before the end of the run, [scenario] duration_s): \
                 after the end there is nothing to check",
                crate::validate::Shown(settle_after_s),
                crate::validate::Shown(h.duration_s)
            ),
        ));
    }
    // Angle bounds: above half a turn they are degrees typed into a `_rad` key, as for the
    // set-point angles.
    for (key, v) in error_bounds_rad {
        if let Some(v) = v {
            if !(*v > 0.0 && *v <= std::f64::consts::PI) {
                return Err(bad(
                    key,
                    format!(
                        "{} rad must be within (0, pi] (half a turn): degrees typed as radians?",
                        crate::validate::Shown(*v)
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// The text of a scenario file and the name its errors give it.
pub(crate) fn read_scenario_text(path: &Path) -> Result<(String, String), ClosedLoopError> {
    let file = path.display().to_string();
    match std::fs::read_to_string(path) {
        Ok(text) => Ok((text, file)),
        Err(e) => Err(ClosedLoopError::Scenario {
            file,
            msg: e.to_string(),
        }),
    }
}

/// The error of a scenario value: it names the file and the line of the offending key (the
/// first line that sets it inside its table) as the TOML parser's own errors do.
pub(crate) fn key_error<'a>(
    text: &'a str,
    file: &'a str,
) -> impl Fn(&str, &str, String) -> ClosedLoopError + 'a {
    move |table: &str, key: &str, msg: String| {
        let at = key_line(text, table, key)
            .map(|l| format!("line {l}: "))
            .unwrap_or_default();
        ClosedLoopError::Scenario {
            file: file.to_string(),
            msg: format!("{at}[{table}] {key}: {msg}"),
        }
    }
}

impl ScenarioHeader {
    /// The `[scenario]` table's ranges: a name usable as a file name (the outputs of `demo`
    /// are named after it), a positive finite length, a tick rate within the firmware's
    /// stable range (`pam_firmware::tick::TICK_HZ_MIN` / `TICK_HZ_MAX`).
    pub(crate) fn check(
        &self,
        bad: &impl Fn(&str, &str, String) -> ClosedLoopError,
    ) -> Result<(), ClosedLoopError> {
        if let Err(msg) = crate::validate::file_name_part(&self.name) {
            return Err(bad("scenario", "name", msg));
        }
        if !(self.duration_s > 0.0 && self.duration_s.is_finite()) {
            return Err(bad(
                "scenario",
                "duration_s",
                format!("{} must be > 0", crate::validate::Shown(self.duration_s)),
            ));
        }
        let (lo, hi) = (
            pam_firmware::tick::TICK_HZ_MIN as f64,
            pam_firmware::tick::TICK_HZ_MAX as f64,
        );
        if !(self.tick_hz >= lo && self.tick_hz <= hi) {
            return Err(bad(
                "scenario",
                "tick_hz",
                format!(
                    "{} must be within {lo}..{hi} (the firmware's gains are stable from {lo} Hz)",
                    crate::validate::Shown(self.tick_hz)
                ),
            ));
        }
        Ok(())
    }
}

/// 1-based line of `key = ...` inside `[table]` of TOML `text`, if it is there.
pub(crate) fn key_line(text: &str, table: &str, key: &str) -> Option<usize> {
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

/// When an event happens [s].
pub(crate) fn event_time(e: &Event) -> f64 {
    match *e {
        Event::LoadInertia { at_s, .. }
        | Event::SupplyLoss { at_s, .. }
        | Event::SensorDropout { at_s, .. }
        | Event::SensorNan { at_s, .. }
        | Event::SensorStuck { at_s, .. }
        | Event::SensorStep { at_s, .. }
        | Event::TickOverrun { at_s, .. }
        | Event::FirmwareReset { at_s, .. }
        | Event::StuckValve { at_s, .. } => at_s,
    }
}

/// The message of a scenario file's TOML error `e` (1-DOF or arm): tagged tables
/// (`[setpoint]`, `[[events]]`) are reported at their header line, so an unknown key, a
/// misspelt choice and a number in quotes are named at their own line instead.
pub(crate) fn toml_error_message(e: &toml::de::Error, text: &str) -> String {
    let mut msg = e.to_string().trim_end().to_string();
    // The parser's last line is its message, without the header's line and snippet.
    let reason = e.message().trim_end().to_string();
    if let Some(name) = reason
        .split("unknown field `")
        .nth(1)
        .and_then(|r| r.split('`').next())
    {
        if let Some((i, _)) = text
            .lines()
            .enumerate()
            .find(|(_, l)| sets_key(l.trim(), name))
        {
            msg = format!("line {}: key `{name}`: {reason}", i + 1);
        }
    } else if let Some(value) = reason
        .strip_prefix("unknown variant `")
        .and_then(|r| r.split('`').next())
    {
        // A misspelt choice inside a tagged table (`channel = "p9"` in [[events]]):
        // the line that sets it.
        if let Some((i, key)) = text.lines().enumerate().find_map(|(i, l)| {
            let (k, v) = l.split_once('=')?;
            let v = v.split('#').next()?.trim();
            (v.trim_matches('"') == value && v.starts_with('"')).then(|| (i, k.trim()))
        }) {
            msg = format!("line {}: key `{key}`: {reason}", i + 1);
        }
    } else if reason.starts_with("invalid type: string") && reason.contains("expected f64") {
        // A number typed in quotes: the first quoted value of a key that takes a
        // number (every such key carries its unit or is a count).
        if let Some((i, key)) = text.lines().enumerate().find_map(|(i, l)| {
            let (k, v) = l.split_once('=')?;
            let k = k.trim();
            let quoted = v.trim().starts_with('"');
            let numeric = !matches!(k, "kind" | "name" | "channel" | "valve" | "state");
            (quoted && numeric).then_some((i, k))
        }) {
            msg = format!(
                "line {}: key `{key}`: a number is expected, got a string (remove the \
                 quotes)",
                i + 1
            );
        }
    }
    msg
}

/// The bundled scenarios (the demo's, and the comparison's jump suite): (file name in `scenarios/`, its text).
pub const SCENARIOS: [(&str, &str); 3] = [
    (
        "scenarios/step.toml",
        include_str!("../../../scenarios/step.toml"),
    ),
    (
        "scenarios/sine.toml",
        include_str!("../../../scenarios/sine.toml"),
    ),
    (
        "scenarios/random.toml",
        include_str!("../../../scenarios/random.toml"),
    ),
];
