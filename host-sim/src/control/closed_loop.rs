//! Firmware in the loop: the firmware's control tick (the same `pam_firmware` code that runs
//! on the MCU) drives the plant through fake valve pins and fake sensors at the tick rate.
//!
//! Per tick `k` (period `dt = 1 / tick_hz`):
//! 1. the plant state at `t_k` is measured through the plant's [`SensorPath`] (its sensor
//!    effects: sensor lag, then calibration; the same path open-loop replay writes), then
//!    passed through the scenario's [`SensorModel`] (noise, ADC / encoder quantisation) and
//!    injected sensor faults (dropout: no sample; NaN), then the transport delay;
//! 2. [`ControlTick::step`] turns the sensor frame and the set-point into a valve command;
//! 3. the firmware's [`OnOffValves`] driver writes the fake pins (tick-level PWM, minimum
//!    on-time); a stuck valve ignores its pin; the pin states are the valve commands;
//! 4. the commands pass the plant's [`ActuatorPath`] (its valve dead time; the same path
//!    open-loop replay applies to recorded commands): the effective openings are the plant
//!    inputs held over `[t_k, t_k + dt)`;
//! 5. the plant is integrated over the tick ([`Integrator::advance`]; every other effect is in
//!    the plant's right-hand side).
//!
//! So an open-loop replay ([`crate::sim::simulate`]) of the commands on the same plant gives
//! the same states and the same measured channels, up to the integration tolerance: the
//! run's recording ([`ClosedLoopRun::to_recording`]) holds exactly those (commands and
//! measured channels), and `host-sim simulate --inputs` on it reproduces it.
//!
//! Scenario events (load inertia change, supply loss) swap in a modified plant at their time,
//! carrying the state over.

use std::cell::Cell;
use std::collections::VecDeque;
use std::rc::Rc;

use crate::io::recording::{Channel, Recording};
use crate::io::scenario::event_time;
pub use crate::io::scenario::{
    ClosedLoopError, Event, Expectations, Scenario, ScenarioHeader, SensorChannel, SensorModel,
    SetpointProfile, ValveId,
};
use crate::plant::{AuxState, Measurement, Plant, PlantState, ValveInputs};
use crate::sim::{ActuatorPath, Integrator, SensorPath, SimStats, SolverOptions};
use pam_firmware::latch::ResetCause;
use pam_firmware::lockstep::{FirmwareNode, PinLevel};
use pam_firmware::sensors::{PressureScaling, SequenceGate};
use pam_firmware::stream::SensorInput;
use pam_firmware::tick::{ControllerConfig, SensorFrame, TickOutput};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

// ---------------------------------------------------------------------------------------
// Fake hardware.

/// A fake GPIO pin: the driver writes it, the loop reads it back.
#[derive(Clone, Default)]
pub struct FakePin {
    state: Rc<Cell<bool>>,
}

impl FakePin {
    /// The level last written (high = open).
    pub fn open(&self) -> bool {
        self.state.get()
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

impl PinLevel for FakePin {
    fn is_high(&self) -> bool {
        self.state.get()
    }
}

// ---------------------------------------------------------------------------------------
// The firmware side.

/// What the firmware gets in one tick.
#[derive(Debug, Clone, Copy)]
pub enum FirmwareInput {
    /// The sensor frame in SI units (the loop did the scaling and gating), the set-point, the
    /// period the firmware measures and an MCU reset before the tick.
    Si {
        /// Sensor frame.
        frame: SensorFrame,
        /// Angle set-point [rad].
        setpoint_rad: f32,
        /// Measured tick period [s].
        dt_s: f32,
        /// Reset before this tick.
        reset: Option<ResetCause>,
    },
    /// The board's raw units (`[sensors] board_counts = true`): the firmware scales and gates.
    Raw(SensorInput),
}

/// What the firmware did in one tick.
#[derive(Debug, Clone, Copy)]
pub struct FirmwareTick {
    /// The control tick's output (from an emulated image: the fields its stream carries).
    pub out: TickOutput,
    /// Pin levels the valve driver wrote (in1, ex1, in2, ex2; high = open).
    pub pins: [bool; 4],
}

/// The firmware side of a closed-loop run: [`FirmwareNode`] in this process, or the
/// processor-in-the-loop image under QEMU ([`crate::control::pil`]).
pub trait Firmware {
    /// Runs tick `k`.
    fn tick(&mut self, k: usize, input: &FirmwareInput) -> Result<FirmwareTick, ClosedLoopError>;
}

impl Firmware for FirmwareNode<FakePin> {
    fn tick(&mut self, _k: usize, input: &FirmwareInput) -> Result<FirmwareTick, ClosedLoopError> {
        let t = match input {
            FirmwareInput::Si {
                frame,
                setpoint_rad,
                dt_s,
                reset,
            } => {
                if let Some(cause) = reset {
                    self.reset(*cause);
                }
                self.step(frame, *setpoint_rad, *dt_s)
            }
            FirmwareInput::Raw(i) => self.step_raw(i),
        };
        Ok(FirmwareTick {
            out: t.out,
            pins: t.pins,
        })
    }
}

/// No sample on any channel (the transport delay's first ticks in board units).
const NO_RAW_SAMPLE: ([u16; 2], i32, u8) = (
    [
        pam_firmware::stream::MISSING_COUNTS,
        pam_firmware::stream::MISSING_COUNTS,
    ],
    pam_firmware::stream::MISSING_ENCODER,
    0,
);

/// The 12-bit ADC count of a gauge pressure through the board's wiring (rounded,
/// saturating at 0 and 4095; a non-finite pressure reads 0).
pub fn pressure_counts(scaling: &PressureScaling, p_gauge_pa: f64) -> u16 {
    let c = ((p_gauge_pa - scaling.offset_pa as f64) / scaling.pa_per_count as f64).round();
    if c >= 4095.0 {
        4095
    } else if c >= 0.0 {
        c as u16
    } else {
        0
    }
}

/// The encoder count of an angle (floor, as a quadrature counter; saturating; a non-finite
/// angle reads 0; never the missing-sample marker).
pub fn encoder_counts(angle_rad: f64) -> i32 {
    let c = (angle_rad / (2.0 * std::f64::consts::PI)
        * pam_firmware::wiring::ENCODER_COUNTS_PER_REV as f64)
        .floor();
    if c.is_nan() {
        0
    } else {
        c.clamp(i32::MIN as f64 + 1.0, i32::MAX as f64) as i32
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
    /// What the plant's sensors report at `t_s` (its sensor effects; before the scenario's
    /// noise, quantisation, faults and transport delay).
    pub measured: Measurement,
    /// The pin levels the firmware's valve driver wrote this tick (in1, ex1, in2, ex2; high =
    /// open), before any stuck valve overrides them.
    pub pins: [bool; 4],
    /// The valve commands of this tick (the pin states, a stuck valve's included): the
    /// inputs an open-loop replay of the run takes.
    pub command: ValveInputs,
    /// Effective valve openings over `[t_s, t_s + dt)` (the commands after the plant's valve
    /// dead time): what the plant is integrated with.
    pub inputs: ValveInputs,
    /// The true net mass flow into muscle 1 and 2 at `t_s` with [`Self::inputs`] [kg/s]
    /// ([`Plant::chamber_mass_flows_kg_s`]).
    pub mass_flow_kg_s: [f64; 2],
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
    /// Tick at which each injected fault started, in time order.
    pub injected_fault_ticks: Vec<usize>,
    /// Ticks at which the MCU was reset (scenario `firmware_reset` events).
    pub reset_ticks: Vec<usize>,
    /// Tick at which the firmware first latched a fault, if any.
    pub first_latched_fault_tick: Option<usize>,
    /// Expectations of the scenario.
    pub expect: Expectations,
    /// Highest gauge pressure seen in either muscle [Pa].
    pub max_p_gauge_pa: f64,
    /// Largest |joint angle| over the run [rad].
    pub max_abs_angle_rad: f64,
    /// Ticks integrated by the fallback (fixed-step) integrator after the adaptive one
    /// failed.
    pub fallback_ticks: usize,
    /// Highest pressure set-point the firmware issued [Pa].
    pub max_p_set_gauge_pa: f64,
    /// Integrator work over the run (steps, right-hand-side evaluations).
    pub sim_stats: SimStats,
    /// The plant's active effects the run honoured ([`Plant::effects_summary`]).
    pub effects: String,
}

/// Wall time of one closed-loop tick (plant integration and firmware), an upper figure of
/// the measurement in docs/reliability.md.
pub const CLOSED_LOOP_S_PER_TICK: f64 = 20e-6;

impl Scenario {
    /// The size of a closed-loop run of this scenario, from its length and tick rate (and
    /// the random set-point levels it draws), for [`crate::validate::RunEstimate::check`].
    pub fn run_estimate(&self) -> crate::validate::RunEstimate {
        let ticks = self.scenario.duration_s * self.scenario.tick_hz;
        let levels = match self.setpoint {
            SetpointProfile::Random { hold_s, .. } => self.scenario.duration_s / hold_s,
            _ => 0.0,
        };
        // Per tick: the run's row, the recording (t_s, 4 inputs, 5 channels) and the
        // formatted CSV lines; measured time per tick in docs/reliability.md.
        let row_bytes = std::mem::size_of::<TickRow>() as f64 + 80.0;
        crate::validate::RunEstimate {
            what: format!("closed-loop run `{}`", self.scenario.name),
            samples: ticks + levels,
            bytes: ticks * row_bytes + levels * 8.0,
            seconds: ticks * CLOSED_LOOP_S_PER_TICK,
        }
    }
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
    let mut node = in_process_firmware(cfg);
    run_with_firmware(plant, scenario, &mut node, progress)
}

/// The firmware in this process, on fake pins, with the board's scaling for raw counts.
pub fn in_process_firmware(cfg: ControllerConfig) -> FirmwareNode<FakePin> {
    FirmwareNode::new(
        cfg,
        Default::default(),
        pam_firmware::wiring::pressure_scaling(),
        pam_firmware::wiring::ENCODER_COUNTS_PER_REV,
    )
}

/// Runs `scenario` with the given firmware side (in process or under an emulator). Per tick:
/// the plant version due, the scenario's events at the tick, the fake sensors' input to the
/// firmware, the firmware's tick, the valve commands (stuck valves override their pins)
/// through the actuator path, the plant integrated over the tick.
pub fn run_with_firmware(
    plant: &Plant,
    scenario: &Scenario,
    firmware: &mut dyn Firmware,
    progress: &mut dyn FnMut(f64),
) -> Result<ClosedLoopRun, ClosedLoopError> {
    let dt_s = 1.0 / scenario.scenario.tick_hz;
    let n_ticks = (scenario.scenario.duration_s / dt_s).round() as usize;
    let mut rng = rand::rngs::StdRng::seed_from_u64(scenario.scenario.seed);
    let levels = random_levels(scenario, &mut rng);
    let plants = plant_versions(plant, scenario, dt_s);
    let mut fake = FakeSensors::new(scenario);
    let mut integration = Integration::new(&plants, plant.initial_state());
    // The plant's effects outside its right-hand side, kept across plant changes.
    let mut actuator = ActuatorPath::new(plant, dt_s, "closed loop")?;
    let mut sensor_path = SensorPath::new(plant, dt_s);
    let mut tally = Tally::new(n_ticks);
    let mut stuck: [Option<bool>; 4] = [None; 4];

    for k in 0..n_ticks {
        let t_s = k as f64 * dt_s;
        integration.switch_to(k);
        let p = integration.plant();
        let x = integration.integ.state();
        let m = sensor_path.push(p, &x);
        tally.max_p = tally
            .max_p
            .max((x.p1_abs_pa - p.p_atm_pa).max(x.p2_abs_pa - p.p_atm_pa));
        tally.max_abs_angle = tally.max_abs_angle.max(x.angle_rad.abs());
        let ev = TickEvents::at(scenario, k, dt_s);
        tally.injected.extend((0..ev.faults_starting).map(|_| k));
        tally.resets.extend((0..ev.resets).map(|_| k));
        let setpoint_rad = scenario.setpoint.at(t_s, &levels);
        let input = fake.input(scenario, k, &m, &ev, setpoint_rad, &mut rng);
        let ft = firmware.tick(k, &input)?;
        let out = ft.out;
        tally.max_p_set = tally
            .max_p_set
            .max(out.p1_set_gauge_pa.max(out.p2_set_gauge_pa) as f64);
        if out.fault.is_some() {
            tally.first_latched.get_or_insert(k);
        }
        update_stuck_valves(scenario, t_s, dt_s, &mut stuck);
        let command = valve_command(&stuck, &ft.pins);
        let inputs = actuator.push(command);
        let mass_flow_kg_s = p.chamber_mass_flows_kg_s(&x, &integration.integ.aux(), &inputs);
        tally.rows.push(TickRow {
            t_s,
            setpoint_rad,
            state: x,
            measured: m,
            pins: ft.pins,
            command,
            inputs,
            mass_flow_kg_s,
            out,
        });
        integration.advance(&x, inputs, dt_s, t_s)?;
        if k % 1000 == 0 {
            progress(k as f64 / n_ticks.max(1) as f64);
        }
    }
    progress(1.0);
    let fallback_ticks = integration.fallback_ticks;
    Ok(ClosedLoopRun {
        name: scenario.scenario.name.clone(),
        dt_s,
        rows: tally.rows,
        injected_fault_ticks: tally.injected,
        reset_ticks: tally.resets,
        first_latched_fault_tick: tally.first_latched,
        expect: scenario.expect.clone(),
        max_p_gauge_pa: tally.max_p,
        max_abs_angle_rad: tally.max_abs_angle,
        fallback_ticks,
        max_p_set_gauge_pa: tally.max_p_set,
        sim_stats: integration.finish(),
        effects: plant.effects_summary(),
    })
}

/// The random set-point profile's levels, drawn once before the run (none for the other
/// profiles).
fn random_levels(scenario: &Scenario, rng: &mut rand::rngs::StdRng) -> Vec<f64> {
    match scenario.setpoint {
        SetpointProfile::Random {
            amplitude_rad,
            hold_s,
            ..
        } => {
            let n = (scenario.scenario.duration_s / hold_s).ceil() as usize + 1;
            let u = rand_distr::Uniform::new_inclusive(-amplitude_rad, amplitude_rad)
                .expect("finite amplitude");
            (0..n).map(|_| u.sample(rng)).collect()
        }
        _ => Vec::new(),
    }
}

/// The plant versions of the run, each from its tick: `plant` from 0, then one per
/// plant-changing event (load inertia, supply loss) in time order, each event applied on
/// top of the ones before.
fn plant_versions(plant: &Plant, scenario: &Scenario, dt_s: f64) -> Vec<(usize, Plant)> {
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
    plants
}

/// What the run records besides the integration: the tick rows and the run's extremes,
/// fault, injection and reset ticks.
struct Tally {
    rows: Vec<TickRow>,
    first_latched: Option<usize>,
    injected: Vec<usize>,
    resets: Vec<usize>,
    max_abs_angle: f64,
    max_p: f64,
    max_p_set: f64,
}

impl Tally {
    fn new(n_ticks: usize) -> Self {
        Tally {
            rows: Vec::with_capacity(n_ticks),
            first_latched: None,
            injected: Vec::new(),
            resets: Vec::new(),
            max_abs_angle: 0.0,
            max_p: f64::NEG_INFINITY,
            max_p_set: f64::NEG_INFINITY,
        }
    }
}

/// The plant's integration over the run: the integrator of the current plant version, its
/// work so far, and the ticks the fallback integrator took.
struct Integration<'a> {
    plants: &'a [(usize, Plant)],
    plant_idx: usize,
    integ: Integrator<'a>,
    opts: SolverOptions,
    stats_done: SimStats,
    fallback_ticks: usize,
}

impl<'a> Integration<'a> {
    fn new(plants: &'a [(usize, Plant)], initial: PlantState) -> Self {
        let opts = SolverOptions {
            rtol: 1e-6,
            atol: 1e-6,
            ..SolverOptions::default()
        };
        Integration {
            plants,
            plant_idx: 0,
            integ: Integrator::new(&plants[0].1, initial, opts),
            opts,
            stats_done: SimStats::default(),
            fallback_ticks: 0,
        }
    }

    /// The plant version in use.
    fn plant(&self) -> &'a Plant {
        &self.plants[self.plant_idx].1
    }

    /// Swaps in the plant versions due by tick `k`, carrying the state over (a supply
    /// reservoir keeps its pressure, the gas its temperature).
    fn switch_to(&mut self, k: usize) {
        let plants = self.plants;
        while self.plant_idx + 1 < plants.len() && plants[self.plant_idx + 1].0 <= k {
            self.plant_idx += 1;
            let x = self.integ.state();
            let aux = self.integ.aux();
            self.stats_done.add(&self.integ.stats());
            self.integ = Integrator::new(&plants[self.plant_idx].1, x, self.opts);
            self.integ.set_aux(aux);
        }
    }

    /// Integrates the tick from `x` with `inputs` held. Fallback: the tick again from its
    /// start state with fixed-step RK4 substeps (a fault combination can make the adaptive
    /// step collapse); a real failure names the run time and the state.
    fn advance(
        &mut self,
        x: &PlantState,
        inputs: ValveInputs,
        dt_s: f64,
        t_s: f64,
    ) -> Result<(), ClosedLoopError> {
        if let Err(e) = self.integ.advance(inputs, dt_s) {
            let p = self.plant();
            let aux = self.integ.aux();
            let end = fallback_tick(p, x, &aux, &inputs, dt_s).ok_or(ClosedLoopError::SimAt {
                t_s,
                state: *x,
                source: e,
            })?;
            self.stats_done.add(&self.integ.stats());
            self.integ = Integrator::new(p, end, self.opts);
            self.integ.set_aux(aux);
            self.fallback_ticks += 1;
        }
        Ok(())
    }

    /// The integrator work over the whole run.
    fn finish(mut self) -> SimStats {
        self.stats_done.add(&self.integ.stats());
        self.stats_done
    }
}

/// The scenario's events in effect at one tick.
#[derive(Default)]
struct TickEvents {
    /// Faults (every event but plant changes) starting at this tick.
    faults_starting: usize,
    /// Persistent sensor offsets (sensor steps) so far, per channel (p1, p2, angle).
    offsets: [f64; 3],
    /// Frozen sensors (repeating their value and sequence number).
    frozen: [bool; 3],
    /// Channels without a sample (dropout).
    dropped: [bool; 3],
    /// Channels reading NaN.
    nan: [bool; 3],
    /// An MCU reset before this tick (the last one of the tick's reset events).
    reset: Option<ResetCause>,
    /// Reset events at this tick.
    resets: usize,
    /// The period the firmware measures (longer on a late tick) [s].
    dt_meas_s: f64,
}

impl TickEvents {
    /// The events of `scenario` at tick `k` of period `dt_s`: an event at `at_s` acts from
    /// the tick nearest to it (within half a tick), for its duration.
    fn at(scenario: &Scenario, k: usize, dt_s: f64) -> Self {
        let t_s = k as f64 * dt_s;
        let mut ev = TickEvents {
            dt_meas_s: dt_s,
            ..Default::default()
        };
        for e in &scenario.events {
            let starts = match *e {
                Event::SupplyLoss { at_s, .. } => (at_s / dt_s).round() as usize == k,
                Event::LoadInertia { .. } => false,
                _ => {
                    let at_s = event_time(e);
                    t_s + 0.5 * dt_s >= at_s && t_s - 0.5 * dt_s < at_s
                }
            };
            if starts {
                ev.faults_starting += 1;
            }
        }
        // Sensor steps (persistent offsets) and frozen sensors: a frozen sensor repeats its
        // value and sequence number; the firmware's sequence gate turns that into "no new
        // sample" as on the board.
        for e in &scenario.events {
            match *e {
                Event::SensorStep {
                    at_s,
                    channel,
                    offset,
                } if t_s + 0.5 * dt_s >= at_s => {
                    ev.offsets[channel as usize] += offset;
                }
                Event::SensorStuck {
                    at_s,
                    duration_s,
                    channel,
                } if t_s + 0.5 * dt_s >= at_s && t_s < at_s + duration_s => {
                    ev.frozen[channel as usize] = true;
                }
                _ => {}
            }
        }
        // Injected sensor faults (dropout: no sample; NaN).
        for e in &scenario.events {
            let (at_s, duration_s, channel, is_nan) = match *e {
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
                let i = match channel {
                    SensorChannel::P1 => 0,
                    SensorChannel::P2 => 1,
                    SensorChannel::Angle => 2,
                };
                // The later event of a channel wins, as when they overwrote the frame.
                ev.nan[i] = is_nan;
                ev.dropped[i] = !is_nan;
            }
        }
        // MCU resets: the firmware restarts; its latch decides the boot.
        for e in &scenario.events {
            if let Event::FirmwareReset { at_s, power_on } = *e {
                if (at_s / dt_s).round() as usize == k {
                    ev.reset = Some(if power_on {
                        ResetCause::PowerOn
                    } else {
                        ResetCause::Watchdog
                    });
                    ev.resets += 1;
                }
            }
        }
        // A late tick: the firmware measures a longer period.
        for e in &scenario.events {
            if let Event::TickOverrun { at_s, factor } = *e {
                if (at_s / dt_s).round() as usize == k {
                    ev.dt_meas_s = dt_s * factor;
                }
            }
        }
        ev
    }
}

/// The fake sensors between the plant's measurement and the firmware: SI values (noise,
/// quantisation, offsets, sequence gates, faults) or the board's raw counts, then the
/// transport delay.
struct FakeSensors {
    board: bool,
    p_noise: Normal<f64>,
    seq: [u32; 3],
    last_values: [f32; 3],
    gates: [SequenceGate; 3],
    delay: VecDeque<SensorFrame>,
    wiring_scaling: PressureScaling,
    /// Board units: the last raw reading per channel (a frozen sensor repeats it).
    raw_last: ([u16; 2], i32),
    raw_delay: VecDeque<([u16; 2], i32, u8)>,
}

impl FakeSensors {
    fn new(scenario: &Scenario) -> Self {
        let wiring_scaling = pam_firmware::wiring::pressure_scaling();
        FakeSensors {
            board: scenario.sensors.board_counts,
            p_noise: Normal::new(0.0, scenario.sensors.pressure_noise_pa.max(0.0))
                .expect("finite noise"),
            seq: [0u32; 3],
            last_values: [0.0f32; 3],
            gates: [SequenceGate::new(); 3],
            delay: VecDeque::new(),
            raw_last: (
                [
                    pressure_counts(&wiring_scaling, 0.0),
                    pressure_counts(&wiring_scaling, 0.0),
                ],
                encoder_counts(0.0),
            ),
            wiring_scaling,
            raw_delay: VecDeque::new(),
        }
    }

    /// The firmware's input at tick `k` from the measurement `m` and the tick's events.
    fn input(
        &mut self,
        scenario: &Scenario,
        k: usize,
        m: &Measurement,
        ev: &TickEvents,
        setpoint_rad: f64,
        rng: &mut rand::rngs::StdRng,
    ) -> FirmwareInput {
        if !self.board {
            FirmwareInput::Si {
                frame: self.si_frame(scenario, k, m, ev, rng),
                setpoint_rad: setpoint_rad as f32,
                dt_s: ev.dt_meas_s as f32,
                reset: ev.reset,
            }
        } else {
            FirmwareInput::Raw(self.raw_input(scenario, k, m, ev, setpoint_rad, rng))
        }
    }

    /// Fake sensors in SI: noise, quantisation, offsets, sequence gates, faults, delay.
    fn si_frame(
        &mut self,
        scenario: &Scenario,
        k: usize,
        m: &Measurement,
        ev: &TickEvents,
        rng: &mut rand::rngs::StdRng,
    ) -> SensorFrame {
        let dt_s = 1.0 / scenario.scenario.tick_hz;
        let t_s = k as f64 * dt_s;
        let p_noise = &self.p_noise;
        let quant_p = |pa: f64, rng: &mut rand::rngs::StdRng| {
            let v = pa + p_noise.sample(rng);
            let lsb = scenario.sensors.pressure_lsb_pa;
            (if lsb > 0.0 {
                (v / lsb).round() * lsb
            } else {
                v
            }) as f32
        };
        let p1 = quant_p(m.p1_kpa * 1e3, rng);
        let p2 = quant_p(m.p2_kpa * 1e3, rng);
        let angle_rad = m.angle_deg.to_radians();
        let counts = scenario.sensors.angle_counts_per_rev;
        let angle = if counts > 0 {
            let c = (angle_rad / (2.0 * std::f64::consts::PI) * counts as f64).floor() as i32;
            pam_firmware::sensors::counts_to_rad(c, counts)
        } else {
            angle_rad as f32
        };
        let mut values = [p1, p2, angle];
        for e in &scenario.events {
            if let Event::SensorStep {
                at_s,
                channel,
                offset,
            } = *e
            {
                if t_s + 0.5 * dt_s >= at_s {
                    values[channel as usize] += offset as f32;
                }
            }
        }
        let mut gated = [None; 3];
        for i in 0..3 {
            if !ev.frozen[i] {
                self.seq[i] = self.seq[i].wrapping_add(1);
                self.last_values[i] = values[i];
            }
            gated[i] = self.gates[i].gate(self.seq[i], self.last_values[i]);
            if ev.nan[i] {
                gated[i] = Some(f32::NAN);
            } else if ev.dropped[i] {
                gated[i] = None;
            }
        }
        let frame = SensorFrame {
            p1_gauge_pa: gated[0],
            p2_gauge_pa: gated[1],
            angle_rad: gated[2],
        };
        // Transport delay.
        self.delay.push_back(frame);
        if self.delay.len() > scenario.sensors.delay_ticks {
            self.delay.pop_front().unwrap_or_default()
        } else {
            SensorFrame::default()
        }
    }

    /// Board units: ADC and encoder counts (the firmware scales and gates them), stale and
    /// NaN flags, missing-sample markers, delay.
    fn raw_input(
        &mut self,
        scenario: &Scenario,
        k: usize,
        m: &Measurement,
        ev: &TickEvents,
        setpoint_rad: f64,
        rng: &mut rand::rngs::StdRng,
    ) -> SensorInput {
        let (offsets, frozen) = (ev.offsets, ev.frozen);
        let p1 = m.p1_kpa * 1e3 + self.p_noise.sample(rng) + offsets[0];
        let p2 = m.p2_kpa * 1e3 + self.p_noise.sample(rng) + offsets[1];
        let angle_rad = m.angle_deg.to_radians() + offsets[2];
        let mut flags = 0u8;
        for (i, f) in frozen.iter().enumerate() {
            if *f {
                flags |= 1 << (pam_firmware::stream::FLAG_STALE_SHIFT + i as u8);
            }
        }
        if !frozen[0] {
            self.raw_last.0[0] = pressure_counts(&self.wiring_scaling, p1);
        }
        if !frozen[1] {
            self.raw_last.0[1] = pressure_counts(&self.wiring_scaling, p2);
        }
        if !frozen[2] {
            self.raw_last.1 = encoder_counts(angle_rad);
        }
        let (mut pc, mut ec) = self.raw_last;
        for i in 0..3 {
            if ev.nan[i] {
                flags |= 1 << (pam_firmware::stream::FLAG_NAN_SHIFT + i as u8);
            } else if ev.dropped[i] {
                match i {
                    0 | 1 => pc[i] = pam_firmware::stream::MISSING_COUNTS,
                    _ => ec = pam_firmware::stream::MISSING_ENCODER,
                }
            }
        }
        // Transport delay (of the sensor data only; set-point, period and reset are the
        // tick's own).
        self.raw_delay.push_back((pc, ec, flags));
        let (pc, ec, flags) = if self.raw_delay.len() > scenario.sensors.delay_ticks {
            self.raw_delay.pop_front().unwrap_or(NO_RAW_SAMPLE)
        } else {
            NO_RAW_SAMPLE
        };
        SensorInput {
            seq: k as u32,
            setpoint_rad: setpoint_rad as f32,
            p_counts: pc,
            encoder_counts: ec,
            flags,
            reset: match ev.reset {
                None => pam_firmware::stream::RESET_NONE,
                Some(ResetCause::PowerOn) => pam_firmware::stream::RESET_POWER_ON,
                Some(_) => pam_firmware::stream::RESET_WATCHDOG,
            },
            dt_s: ev.dt_meas_s as f32,
        }
    }
}

/// Stuck valves from their time on: the valve ignores its pin (`stuck[i]`: the valve's fixed
/// state, in the order in1, ex1, in2, ex2).
fn update_stuck_valves(scenario: &Scenario, t_s: f64, dt_s: f64, stuck: &mut [Option<bool>; 4]) {
    for e in &scenario.events {
        if let Event::StuckValve { at_s, valve, open } = *e {
            if t_s + 0.5 * dt_s >= at_s {
                let i = match valve {
                    ValveId::In1 => 0,
                    ValveId::Ex1 => 1,
                    ValveId::In2 => 2,
                    ValveId::Ex2 => 3,
                };
                stuck[i] = Some(open);
            }
        }
    }
}

/// The valve commands: each pin's state, unless its valve is stuck.
fn valve_command(stuck: &[Option<bool>; 4], pins: &[bool; 4]) -> ValveInputs {
    let b = |i: usize| {
        if stuck[i].unwrap_or(pins[i]) {
            1.0
        } else {
            0.0
        }
    };
    ValveInputs {
        u_in1: b(0),
        u_ex1: b(1),
        u_in2: b(2),
        u_ex2: b(3),
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

impl TrackingStats {
    /// The statistics of the angle errors `errors_rad` (NaN mean square when empty).
    pub fn of_errors(errors_rad: impl Iterator<Item = f64>) -> Self {
        let (mut sum, mut max, mut n) = (0.0, 0.0f64, 0usize);
        for e in errors_rad {
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
}

/// One tick of the plant with fixed-step classic RK4 (256 substeps), for when the adaptive
/// integrator fails: `None` if the state becomes non-finite. The auxiliary states (a supply
/// reservoir's pressure, the gas temperatures) are held over the tick.
fn fallback_tick(
    plant: &Plant,
    x: &PlantState,
    aux: &AuxState,
    u: &ValveInputs,
    dt_s: f64,
) -> Option<PlantState> {
    const N: usize = 256;
    let h = dt_s / N as f64;
    let f = |y: [f64; 4]| {
        plant
            .derivatives_aux(&PlantState::from_array(y), aux, u)
            .0
            .to_array()
    };
    let mut y = x.to_array();
    let add = |y: [f64; 4], k: [f64; 4], a: f64| -> [f64; 4] {
        let mut r = y;
        for i in 0..4 {
            r[i] += a * k[i];
        }
        r
    };
    for _ in 0..N {
        let k1 = f(y);
        let k2 = f(add(y, k1, 0.5 * h));
        let k3 = f(add(y, k2, 0.5 * h));
        let k4 = f(add(y, k3, h));
        for i in 0..4 {
            y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        }
        if !y.iter().all(|v| v.is_finite()) {
            return None;
        }
    }
    Some(PlantState::from_array(y))
}

impl ClosedLoopRun {
    /// Tick of the first injected fault (sensor, valve or supply), if any.
    pub fn first_injected_fault_tick(&self) -> Option<usize> {
        self.injected_fault_ticks.first().copied()
    }

    /// Ticks from the injection of the latched fault's cause to the latch: from the latest
    /// injection at or before the first latched tick. `None` without a latch or when the
    /// latch came before any injection.
    pub fn fault_latency_ticks(&self) -> Option<usize> {
        let l = self.first_latched_fault_tick?;
        let i = self.injected_fault_ticks.iter().rev().find(|&&i| i <= l)?;
        Some(l - i)
    }

    /// Tracking error statistics from `after_s` on, over the ticks without a latched fault.
    pub fn tracking(&self, after_s: f64) -> TrackingStats {
        TrackingStats::of_errors(
            self.rows
                .iter()
                .filter(|r| r.t_s >= after_s && r.out.fault.is_none())
                .map(|r| r.state.angle_rad - r.setpoint_rad),
        )
    }

    /// Checks the scenario's expectations; returns the failures as sentences.
    pub fn check(&self) -> Vec<String> {
        let mut fails = Vec::new();
        let e = &self.expect;
        let st = self.tracking(e.settle_after_s);
        // An error bound with no tick to judge (a fault latched before `settle_after_s` and
        // stayed) is not met: the run shows nothing about the tracking it asks for.
        if (e.max_abs_error_rad.is_some() || e.rms_error_rad.is_some()) && st.n == 0 {
            let latched = match self.first_latched_fault_tick {
                Some(l) => match self.rows[l].out.fault {
                    Some(f) => format!(" (fault {f:?}, code {}, latched at tick {l})", f.code()),
                    None => format!(" (a fault latched at tick {l})"),
                },
                None => String::new(),
            };
            fails.push(format!(
                "no tick without a latched fault after {} s to bound the angle error{latched}",
                e.settle_after_s,
            ));
        } else if let Some(b) = e.max_abs_error_rad {
            if !(st.max_abs_rad <= b) {
                fails.push(format!(
                    "max |angle error| {:.4} rad > {b} rad after {} s",
                    st.max_abs_rad, e.settle_after_s
                ));
            }
        }
        if let (Some(b), true) = (e.rms_error_rad, st.n > 0) {
            if !(st.rms_rad <= b) {
                fails.push(format!(
                    "rms angle error {:.4} rad > {b} rad after {} s",
                    st.rms_rad, e.settle_after_s
                ));
            }
        }
        if let Some(b) = e.fault_within_ticks {
            let injected = match self.injected_fault_ticks.as_slice() {
                [] => "nothing injected".to_string(),
                ticks => format!(
                    "injected at tick {}",
                    ticks
                        .iter()
                        .map(|k| k.to_string())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            };
            match (self.first_latched_fault_tick, self.fault_latency_ticks()) {
                (Some(_), Some(d)) if d <= b => {}
                (Some(l), Some(d)) => fails.push(format!(
                    "fault latched at tick {l}, {d} ticks after the injection of its cause \
                     ({injected}): not within {b} ticks"
                )),
                (Some(l), None) => fails.push(format!(
                    "fault latched at tick {l}, with no injected cause before it ({injected}): not \
                     within {b} ticks of an injection"
                )),
                (None, _) => fails.push(format!(
                    "no fault latched ({injected}): expected within {b} ticks"
                )),
            }
        }
        if let Some(b) = e.max_pressure_kpa {
            if !(self.max_p_gauge_pa <= b * 1e3) {
                fails.push(format!(
                    "muscle pressure reached {:.1} kPa > {b} kPa",
                    self.max_p_gauge_pa / 1e3
                ));
            }
        }
        if let Some(b) = e.angle_within_rad {
            if !(self.max_abs_angle_rad <= b) {
                fails.push(format!(
                    "|joint angle| reached {:.4} rad > {b} rad",
                    self.max_abs_angle_rad
                ));
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

    /// The run as a recording for `host-sim fit` / `--plot` / `simulate --inputs`: the valve
    /// commands ([`TickRow::command`]) and the channels the plant's sensors report
    /// ([`TickRow::measured`]: the true state through the plant's sensor effects, without the
    /// scenario's noise and quantisation), so that an open-loop replay on `plant` reproduces
    /// it. The metadata lists the plant's active effects (`# effects = ...`).
    pub fn to_recording(&self) -> Recording {
        let mut rec = Recording::default();
        rec.metadata.push((
            "source".into(),
            format!("host-sim closed loop, scenario {}", self.name),
        ));
        rec.metadata
            .push(("sample_period_s".into(), format!("{}", self.dt_s)));
        rec.metadata.push(("effects".into(), self.effects.clone()));
        let mut ch: [Vec<f64>; 5] = Default::default();
        let mut flows: [Vec<f64>; 2] = Default::default();
        for r in &self.rows {
            rec.t_s.push(r.t_s);
            rec.inputs.push(r.command);
            for (f, v) in flows.iter_mut().zip(r.mass_flow_kg_s) {
                f.push(v);
            }
            let m = r.measured.to_array();
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
        rec.mass_flow_kg_s = Some(flows);
        rec
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scenario(events: &str) -> Scenario {
        let text = format!(
            "[scenario]\nname = \"t\"\nduration_s = 1.0\nseed = 1\n\n[setpoint]\nkind = \"step\"\n\
             initial_rad = 0.0\nfinal_rad = 0.1\nat_s = 0.5\n{events}"
        );
        Scenario::from_toml_str(&text, "t.toml").expect("a valid scenario")
    }

    #[test]
    fn a_stuck_valve_overrides_its_pin_and_the_others_follow_theirs() {
        let command = valve_command(
            &[None, Some(true), Some(false), None],
            &[true, false, true, false],
        );
        assert_eq!(
            [command.u_in1, command.u_ex1, command.u_in2, command.u_ex2],
            [1.0, 1.0, 0.0, 0.0]
        );
    }

    #[test]
    fn the_later_sensor_fault_of_a_channel_wins_and_acts_for_its_duration() {
        let s = scenario(
            "[[events]]\nkind = \"sensor_dropout\"\nat_s = 0.1\nduration_s = 0.5\nchannel = \"p2\"\n\
             [[events]]\nkind = \"sensor_nan\"\nat_s = 0.2\nduration_s = 0.1\nchannel = \"p2\"\n",
        );
        let dt_s = 1.0 / s.scenario.tick_hz;
        let tick = |t_s: f64| (t_s / dt_s).round() as usize;
        let both = TickEvents::at(&s, tick(0.25), dt_s);
        assert!(both.nan[1] && !both.dropped[1]);
        let dropout_only = TickEvents::at(&s, tick(0.4), dt_s);
        assert!(!dropout_only.nan[1] && dropout_only.dropped[1]);
        let after = TickEvents::at(&s, tick(0.7), dt_s);
        assert!(!after.nan[1] && !after.dropped[1]);
        assert_eq!(TickEvents::at(&s, tick(0.1), dt_s).faults_starting, 1);
        assert_eq!(TickEvents::at(&s, tick(0.1) + 1, dt_s).faults_starting, 0);
    }
}
