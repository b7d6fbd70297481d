//! The 3-DOF arm of seed 001 integrated under zero-order-held valve inputs (adaptive
//! Dormand-Prince, as the 1-DOF joint in [`crate::sim`]), each joint's valve command through
//! its dead time and each sensor through its lag.

use ode_solvers::System;

use crate::plant::arm3::{Arm3, Arm3Inputs, Arm3State, ArmVector, JointMeasurement};
use crate::plant::state::ValveInputs;
use crate::sim::signal_path::{ActuatorPath, SensorPath};
use crate::sim::SolverOptions;

// ---------------------------------------------------------------------------------------
// Integration under zero-order-held inputs
// ---------------------------------------------------------------------------------------

/// A failed arm simulation.
#[derive(Debug, thiserror::Error)]
pub enum Arm3SimError {
    #[error("integration failed at t = {t_s} s: {message}")]
    Integration { t_s: f64, message: String },
    #[error("state became non-finite at t = {t_s} s (state {state:?})")]
    NonFinite { t_s: f64, state: Box<Arm3State> },
    #[error("invalid sample period {0} s (must be finite and > 0)")]
    SamplePeriod(f64),
    #[error("joint {joint}: {message}")]
    Joint { joint: usize, message: String },
    #[error("invalid valve input at sample {index}, joint {joint}: {inputs:?} (openings must be in [0, 1])")]
    Input {
        index: usize,
        joint: usize,
        inputs: ValveInputs,
    },
}

struct Rhs<'a> {
    arm: &'a Arm3,
    u: Arm3Inputs,
}

impl System<f64, ArmVector> for Rhs<'_> {
    fn system(&self, _t: f64, y: &ArmVector, dy: &mut ArmVector) {
        let d = self.arm.derivatives(&Arm3State::from_vector(y), &self.u);
        *dy = d.to_vector();
    }
}

fn check_inputs(index: usize, u: &Arm3Inputs) -> Result<(), Arm3SimError> {
    for (j, v) in u.iter().enumerate() {
        if ![v.u_in1, v.u_ex1, v.u_in2, v.u_ex2]
            .iter()
            .all(|x| (0.0..=1.0).contains(x))
        {
            return Err(Arm3SimError::Input {
                index,
                joint: j + 1,
                inputs: *v,
            });
        }
    }
    Ok(())
}

/// Counters of an arm simulation (the 1-DOF integrator's).
pub type Arm3Stats = crate::sim::SimStats;

/// The arm state advanced piecewise under zero-order-held inputs (one Dopri5 run per run of
/// equal inputs, never stepping across an input change; the step size carried over).
pub struct Arm3Integrator<'a> {
    arm: &'a Arm3,
    state: Arm3State,
    t_s: f64,
    h_s: f64,
    opts: SolverOptions,
    stats: Arm3Stats,
}

impl<'a> Arm3Integrator<'a> {
    pub fn new(arm: &'a Arm3, state: Arm3State, opts: SolverOptions) -> Self {
        Self {
            arm,
            state,
            t_s: 0.0,
            h_s: 0.0,
            opts,
            stats: Arm3Stats::default(),
        }
    }

    pub fn state(&self) -> Arm3State {
        self.state
    }
    pub fn time_s(&self) -> f64 {
        self.t_s
    }
    pub fn stats(&self) -> Arm3Stats {
        self.stats
    }

    /// Holds `inputs` for `n` samples of `dt_s`; calls `on_sample` with the state at the
    /// start of each sample; afterwards [`Self::state`] is the state at the end.
    pub fn advance_samples(
        &mut self,
        inputs: Arm3Inputs,
        dt_s: f64,
        n: usize,
        mut on_sample: impl FnMut(&Arm3State),
    ) -> Result<(), Arm3SimError> {
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return Err(Arm3SimError::SamplePeriod(dt_s));
        }
        check_inputs(0, &inputs)?;
        if n == 0 {
            return Ok(());
        }
        let plan = crate::sim::SegmentPlan::new(n, dt_s, self.h_s);
        let t_s = self.t_s;
        let integration = |message| Arm3SimError::Integration { t_s, message };
        let (solver, accepted) = crate::sim::dopri_segment(
            Rhs {
                arm: self.arm,
                u: inputs,
            },
            self.state.to_vector(),
            &plan,
            dt_s,
            &self.opts,
            &mut self.stats,
        )
        .map_err(integration)?;
        let (starts, last) = plan.points(solver.y_out(), n).map_err(integration)?;
        if plan.single {
            on_sample(&self.state);
        }
        for y in starts {
            on_sample(&Arm3State::from_vector(y));
        }
        let end = Arm3State::from_vector(last);
        let duration_s = plan.duration_s;
        if !end.is_finite() {
            return Err(Arm3SimError::NonFinite {
                t_s: self.t_s + duration_s,
                state: Box::new(end),
            });
        }
        self.state = end;
        self.t_s += duration_s;
        self.h_s = plan.mean_step_s(accepted);
        Ok(())
    }
}

/// An open-loop arm run: `states[k]` is the state at `t_k = k dt`.
#[derive(Debug, Clone)]
pub struct Arm3Simulation {
    pub states: Vec<Arm3State>,
    pub final_state: Arm3State,
    pub stats: Arm3Stats,
}

/// Open-loop replay from the arm's initial state: the valve commands `inputs[k]` of
/// `[t_k, t_k + dt)` through each joint's valve dead time; `progress` gets the number of
/// samples done.
pub fn simulate_arm3(
    arm: &Arm3,
    inputs: &[Arm3Inputs],
    dt_s: f64,
    opts: &SolverOptions,
    mut progress: impl FnMut(usize),
) -> Result<Arm3Simulation, Arm3SimError> {
    for (k, u) in inputs.iter().enumerate() {
        check_inputs(k, u)?;
    }
    let applied = arm.applied_inputs(inputs, dt_s)?;
    let inputs = &applied[..];
    let mut integ = Arm3Integrator::new(arm, arm.initial, *opts);
    let mut states = Vec::with_capacity(inputs.len());
    let mut k = 0;
    while k < inputs.len() {
        let u = inputs[k];
        let run = inputs[k..].iter().take_while(|v| **v == u).count();
        integ.advance_samples(u, dt_s, run, |x| states.push(*x))?;
        k += run;
        progress(k);
    }
    Ok(Arm3Simulation {
        states,
        final_state: integ.state(),
        stats: integ.stats(),
    })
}

/// The arm's sampled signal paths: each joint's valve dead time and sensor lag.
impl Arm3 {
    /// Valve command -> valve opening of each joint (its `[jointN.effects.valve_dead_time]`)
    /// at sample period `dt_s`; `mode` names the run in a refusal.
    pub fn actuator_paths(
        &self,
        dt_s: f64,
        mode: &'static str,
    ) -> Result<[ActuatorPath; 3], Arm3SimError> {
        let mut paths = Vec::with_capacity(3);
        for (j, e) in self.effects.iter().enumerate() {
            paths.push(ActuatorPath::for_effects(e, dt_s, mode).map_err(|e| {
                Arm3SimError::Joint {
                    joint: j + 1,
                    message: e.to_string(),
                }
            })?);
        }
        Ok(paths.try_into().expect("three joints"))
    }

    /// Plant state -> reported channels of each joint (its sensor lag and calibration),
    /// sampled every `dt_s`.
    pub fn sensor_paths(&self, dt_s: f64) -> [SensorPath; 3] {
        std::array::from_fn(|i| SensorPath::for_effects(&self.effects[i], dt_s))
    }

    /// The channels the sensors of every joint report over a sampled run (`states[k]` at
    /// `t_k = k dt_s`): lag, then calibration.
    pub fn measure_run(&self, states: &[Arm3State], dt_s: f64) -> Vec<[JointMeasurement; 3]> {
        let mut paths = self.sensor_paths(dt_s);
        states
            .iter()
            .map(|x| self.measure_with(&mut paths, x))
            .collect()
    }

    /// What the sensors of `paths` report for the next sample `x`.
    pub fn measure_with(
        &self,
        paths: &mut [SensorPath; 3],
        x: &Arm3State,
    ) -> [JointMeasurement; 3] {
        std::array::from_fn(|i| {
            paths[i]
                .push_channels(&self.effects[i], self.true_channels(i, x))
                .into()
        })
    }

    /// The valve openings applied over each sample for the commands `commands` (each joint's
    /// valve dead time).
    pub fn applied_inputs(
        &self,
        commands: &[Arm3Inputs],
        dt_s: f64,
    ) -> Result<Vec<Arm3Inputs>, Arm3SimError> {
        let mut paths = self.actuator_paths(dt_s, "open-loop replay")?;
        Ok(commands
            .iter()
            .map(|u| std::array::from_fn(|j| paths[j].push(u[j])))
            .collect())
    }
}
