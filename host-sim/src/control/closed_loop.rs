//! Firmware in the loop: the firmware's control tick (the same `pam_firmware` code that runs
//! on the MCU) drives the plant through fake valve pins and fake sensors at the tick rate.
//!
//! Per tick `k` (period `dt = 1 / tick_hz`):
//! 1. the plant state at `t_k` is measured ([`Plant::measure`], with its sensor effects), then
//!    passed through the [`SensorModel`] (noise, ADC / encoder quantisation to raw counts,
//!    delay) and the scenario's injected sensor faults (dropout: no sample; NaN);
//! 2. the firmware ([`FirmwareLoop`]: [`InProcess`] here, or the QEMU image of
//!    `control::pil`) scales the raw counts with its own code (`PressureScaling`,
//!    `counts_to_rad`) and [`ControlTick::step`] turns the sensor frame and the set-point
//!    into a valve command;
//! 3. the firmware's [`OnOffValves`] driver writes the fake pins (tick-level PWM, minimum
//!    on-time); a stuck valve ignores its pin; the effective openings are the plant inputs
//!    held over `[t_k, t_k + dt)`;
//! 4. the plant is integrated over the tick ([`Integrator::advance`]).
//!
//! Scenario events (load inertia change, supply loss) swap in a modified plant at their time,
//! carrying the state over.

use std::cell::Cell;
use std::collections::VecDeque;
use std::rc::Rc;

use pam_firmware::sensors::PressureScaling;
use pam_firmware::tick::{ControlTick, ControllerConfig, SensorFrame, Setpoint, TickOutput};
use pam_firmware::valves::{OnOffPwmConfig, OnOffValves};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use crate::io::recording::{Channel, Recording};
pub use crate::io::scenario::{
    ClosedLoopError, Event, Expectations, Scenario, ScenarioHeader, SensorChannel, SensorModel,
    SetpointProfile, ValveId,
};
use crate::io::scenario::event_time;
use crate::plant::{Plant, PlantState, ValveInputs};
use crate::sim::{Integrator, SimStats, SolverOptions};

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
    let mut fw = InProcess::new(cfg, &scenario.sensors);
    run_with_firmware(plant, scenario, &mut fw, progress)
}

/// Fake pressure ADC: zero gauge pressure reads this many counts (the reference wiring's
/// 0.5 V offset), so noise around atmosphere stays a valid reading.
pub const ADC_ZERO_COUNTS: u16 = pam_firmware::wiring::PRESSURE_COUNTS_AT_ZERO as u16;
/// Highest count of the fake ADC's transport (`0xFFFF` marks a missing sample).
pub const ADC_MAX_COUNTS: u16 = 0xFFFE;

/// The pressure scaling of the fake ADC of a scenario: `pressure_lsb_pa` per count, zero at
/// [`ADC_ZERO_COUNTS`]; `None` without quantisation (`pressure_lsb_pa = 0`).
pub fn fake_adc_scaling(sensors: &SensorModel) -> Option<PressureScaling> {
    (sensors.pressure_lsb_pa > 0.0).then(|| {
        let lsb = sensors.pressure_lsb_pa as f32;
        PressureScaling {
            pa_per_count: lsb,
            offset_pa: -lsb * ADC_ZERO_COUNTS as f32,
        }
    })
}

/// One pressure reading as the sensor delivers it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PressureReading {
    /// ADC counts (through [`fake_adc_scaling`]).
    Counts(u16),
    /// Unquantised gauge pressure [Pa] (`pressure_lsb_pa = 0`).
    Pa(f32),
}

/// One angle reading as the sensor delivers it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AngleReading {
    /// Encoder counts (`angle_counts_per_rev` per turn).
    Counts(i32),
    /// Unquantised angle [rad] (`angle_counts_per_rev = 0`).
    Rad(f32),
}

/// One tick of raw sensor data (before the firmware's scaling), after the scenario's
/// injected faults: `None` = no sample (dropout), `nan[i]` = the channel reads NaN (p1, p2,
/// angle).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RawFrame {
    pub p: [Option<PressureReading>; 2],
    pub angle: Option<AngleReading>,
    pub nan: [bool; 3],
}

impl RawFrame {
    /// The frame the control tick sees: the firmware's own conversions
    /// (`PressureScaling::to_gauge_pa`, `sensors::counts_to_rad`).
    pub fn frame(&self, scaling: Option<&PressureScaling>, counts_per_rev: u32) -> SensorFrame {
        let p = |i: usize| -> Option<f32> {
            if self.nan[i] {
                return Some(f32::NAN);
            }
            match self.p[i]? {
                PressureReading::Counts(c) => Some(match scaling {
                    Some(s) => s.to_gauge_pa(c as u32),
                    None => f32::NAN,
                }),
                PressureReading::Pa(v) => Some(v),
            }
        };
        let angle = if self.nan[2] {
            Some(f32::NAN)
        } else {
            self.angle.map(|a| match a {
                AngleReading::Counts(c) => pam_firmware::sensors::counts_to_rad(c, counts_per_rev),
                AngleReading::Rad(v) => v,
            })
        };
        SensorFrame {
            p1_gauge_pa: p(0),
            p2_gauge_pa: p(1),
            angle_rad: angle,
        }
    }
}

/// What the firmware did in one tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FirmwareTick {
    /// Valve pin levels in1, ex1, in2, ex2 the driver wrote.
    pub pins: [bool; 4],
    /// The control tick's output (a remote firmware reports the fields its stream carries;
    /// the others are 0).
    pub out: TickOutput,
}

/// The firmware side of the loop: the control tick and the valve driver, in this process
/// ([`InProcess`]) or on an emulated MCU (`control::pil`).
pub trait FirmwareLoop {
    /// One control tick on raw sensor data; `k` is the tick index.
    fn tick(
        &mut self,
        k: usize,
        raw: &RawFrame,
        setpoint_rad: f32,
        dt_s: f32,
    ) -> Result<FirmwareTick, ClosedLoopError>;
}

/// The firmware library in this process: sensor scaling, [`ControlTick`], [`OnOffValves`]
/// on fake pins.
pub struct InProcess {
    tick: ControlTick,
    pins: [FakePin; 4],
    valves: OnOffValves<FakePin, FakePin, FakePin, FakePin>,
    scaling: Option<PressureScaling>,
    counts_per_rev: u32,
}

impl InProcess {
    pub fn new(cfg: ControllerConfig, sensors: &SensorModel) -> Self {
        let pins: [FakePin; 4] = Default::default();
        let valves = OnOffValves::new(
            pins[0].clone(),
            pins[1].clone(),
            pins[2].clone(),
            pins[3].clone(),
            OnOffPwmConfig::REFERENCE,
        );
        Self {
            tick: ControlTick::new(cfg),
            pins,
            valves,
            scaling: fake_adc_scaling(sensors),
            counts_per_rev: sensors.angle_counts_per_rev,
        }
    }
}

impl FirmwareLoop for InProcess {
    fn tick(
        &mut self,
        _k: usize,
        raw: &RawFrame,
        setpoint_rad: f32,
        dt_s: f32,
    ) -> Result<FirmwareTick, ClosedLoopError> {
        let frame = raw.frame(self.scaling.as_ref(), self.counts_per_rev);
        let out = self.tick.step(
            &frame,
            &Setpoint {
                angle_rad: setpoint_rad,
            },
            dt_s,
        );
        // Infallible pins: the driver cannot fail here.
        let _ = self.valves.apply(&out.valves);
        Ok(FirmwareTick {
            pins: std::array::from_fn(|i| self.pins[i].state.get()),
            out,
        })
    }
}

/// Runs `scenario` with `fw` as the firmware: the plant, the fake sensors (noise, ADC and
/// encoder quantisation, delay, injected faults) and stuck valves are on this side.
pub fn run_with_firmware(
    plant: &Plant,
    scenario: &Scenario,
    fw: &mut dyn FirmwareLoop,
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

    let mut stuck: [Option<bool>; 4] = [None; 4];
    let adc = fake_adc_scaling(&scenario.sensors);
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
    let mut delay: VecDeque<RawFrame> = VecDeque::new();
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

        // Fake sensors: noise, ADC / encoder quantisation (raw counts; the firmware scales).
        let quant_p = |pa: f64, rng: &mut rand::rngs::StdRng| {
            let v = pa + p_noise.sample(rng);
            let lsb = scenario.sensors.pressure_lsb_pa;
            if adc.is_some() {
                let c = (v / lsb).round() + f64::from(ADC_ZERO_COUNTS);
                PressureReading::Counts(c.clamp(0.0, f64::from(ADC_MAX_COUNTS)) as u16)
            } else {
                PressureReading::Pa(v as f32)
            }
        };
        let p1 = quant_p(m.p1_kpa * 1e3, &mut rng);
        let p2 = quant_p(m.p2_kpa * 1e3, &mut rng);
        let angle_rad = m.angle_deg.to_radians();
        let counts = scenario.sensors.angle_counts_per_rev;
        let angle = if counts > 0 {
            let c = (angle_rad / (2.0 * std::f64::consts::PI) * counts as f64).floor() as i32;
            AngleReading::Counts(c)
        } else {
            AngleReading::Rad(angle_rad as f32)
        };
        let mut frame = RawFrame {
            p: [Some(p1), Some(p2)],
            angle: Some(angle),
            nan: [false; 3],
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
                let i = match channel {
                    SensorChannel::P1 => 0,
                    SensorChannel::P2 => 1,
                    SensorChannel::Angle => 2,
                };
                if nan {
                    frame.nan[i] = true;
                } else {
                    match i {
                        0 | 1 => frame.p[i] = None,
                        _ => frame.angle = None,
                    }
                    frame.nan[i] = false;
                }
                first_injected.get_or_insert(k);
            }
        }
        // Transport delay.
        delay.push_back(frame);
        let frame = if delay.len() > scenario.sensors.delay_ticks {
            delay.pop_front().unwrap_or_default()
        } else {
            RawFrame::default()
        };

        let setpoint_rad = scenario.setpoint.at(t_s, &levels);
        let FirmwareTick { pins, out } = fw.tick(k, &frame, setpoint_rad as f32, dt_s as f32)?;
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
                    stuck[i] = Some(open);
                }
            }
        }
        // What each valve does: a stuck valve ignores its pin.
        let b = |i: usize| {
            if stuck[i].unwrap_or(pins[i]) {
                1.0
            } else {
                0.0
            }
        };
        let inputs = ValveInputs {
            u_in1: b(0),
            u_ex1: b(1),
            u_in2: b(2),
            u_ex2: b(3),
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
