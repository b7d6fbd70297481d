//! The two signal paths of the plant, shared by every mode (open-loop replay, the closed loop
//! with the firmware, the controller comparison and tuning, identification, the diagnosis
//! candidates): they are the one place where the plant's effects outside the right-hand side
//! act.
//!
//! - [`ActuatorPath`]: valve command -> valve opening. The actuator-side effect is the valve
//!   dead time ([`crate::plant::effects::ValveDeadTime`], whole samples and a fraction of one
//!   through a [`DeadTimeLine`]; a replay at a recording's own stamps shifts the commands
//!   exactly through [`crate::plant::effects::ShiftedCommands`], the same effect's). Open-loop replay feeds it the recorded commands; the closed loop feeds
//!   it the firmware's pin states, tick by tick.
//! - [`SensorPath`]: plant state -> reported channels. The sensor-side effects are the sensor
//!   lag ([`crate::plant::effects::SensorLag`], a sampled first-order low-pass per channel
//!   group, started at the first sample) and then the calibration of each channel
//!   ([`crate::plant::effects::SensorCalibration`]). Open-loop replay writes its output; in
//!   the closed loop the firmware measures it (then the scenario's `[sensors]` noise,
//!   quantisation, injected faults and transport delay act on top).
//!
//! Every other effect (joint friction, gravity, leakage, polytropic process, muscle
//! hysteresis, supply drop) is part of [`Plant::derivatives`], so every integration honours it.
//!
//! A path keeps its memory across a change of plant parameters (the closed loop's load and
//! supply events swap the plant, not the sensors or the valves).

use crate::plant::effects::{ChannelFilter, DeadTimeLine, Effects};
use crate::plant::{Measurement, Plant, PlantState, ValveInputs};
use crate::sim::SimError;

/// Valve command -> valve opening (the valve dead time, if the plant has one).
#[derive(Debug, Clone)]
pub struct ActuatorPath {
    line: Option<DeadTimeLine>,
}

impl ActuatorPath {
    /// The path of `plant` at sample period `dt_s`, for the run mode `mode` (named in the
    /// refusal). Refuses a dead time the line cannot hold (negative, not finite, absurdly long
    /// for the sample period).
    pub fn new(plant: &Plant, dt_s: f64, mode: &'static str) -> Result<Self, SimError> {
        Self::for_effects(&plant.effects, dt_s, mode)
    }

    /// The path of a set of effects (one joint of the arm has its own).
    pub fn for_effects(effects: &Effects, dt_s: f64, mode: &'static str) -> Result<Self, SimError> {
        let line = match effects.valve_dead_time_s() {
            None => None,
            Some(delay_s) => Some(DeadTimeLine::new(delay_s, dt_s).ok_or(SimError::DeadTime {
                delay_s,
                dt_s,
                mode,
            })?),
        };
        Ok(Self { line })
    }

    /// Delay in samples (0 without a dead time).
    pub fn delay_samples(&self) -> usize {
        self.line.as_ref().map_or(0, DeadTimeLine::samples)
    }

    /// Feeds the command of this sample; returns the opening the valves apply over it.
    #[inline]
    pub fn push(&mut self, command: ValveInputs) -> ValveInputs {
        match &mut self.line {
            None => command,
            Some(l) => l.push(command),
        }
    }
}

/// Plant state -> reported channels (sensor dynamics, then calibration, as the plant has them).
pub struct SensorPath {
    filters: Vec<Box<dyn ChannelFilter>>,
}

impl std::fmt::Debug for SensorPath {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SensorPath")
            .field("filters", &self.filters.len())
            .finish()
    }
}

impl SensorPath {
    /// The path of `plant` sampled every `dt_s` (its sensor filters in registry order).
    pub fn new(plant: &Plant, dt_s: f64) -> Self {
        Self::for_effects(&plant.effects, dt_s)
    }

    /// The path of a set of effects (one joint of the arm has its own).
    pub fn for_effects(effects: &Effects, dt_s: f64) -> Self {
        Self {
            filters: effects.sensor_filters(dt_s),
        }
    }

    /// Feeds the state of this sample; returns what the sensors report for it. `plant` gives
    /// the channels and the calibration (it may be a changed copy of the plant the path was
    /// made for: only its sensor effects must be the same).
    pub fn push(&mut self, plant: &Plant, x: &PlantState) -> Measurement {
        self.push_channels(&plant.effects, plant.true_channels(x))
    }

    /// Feeds the true channels `m` of this sample; returns what sensors with `effects`'
    /// lag and calibration report for it.
    pub fn push_channels(&mut self, effects: &Effects, m: Measurement) -> Measurement {
        if self.filters.is_empty() {
            return effects.calibrate(m);
        }
        let mut y = m.to_array();
        for f in self.filters.iter_mut() {
            y = f.push(y);
        }
        effects.calibrate(Measurement {
            angle_deg: y[0],
            p1_kpa: y[1],
            p2_kpa: y[2],
            f1_n: y[3],
            f2_n: y[4],
        })
    }
}

impl Plant {
    /// The recorded channels of a sampled run (`states[k]` at `t_k = k dt`), with the
    /// sensor effects (lag, then calibration) if enabled: the [`SensorPath`] every
    /// mode uses.
    pub fn measure_series(&self, states: &[PlantState], dt_s: f64) -> Vec<Measurement> {
        let mut path = SensorPath::new(self, dt_s);
        states.iter().map(|x| path.push(self, x)).collect()
    }
}
