//! Open-loop integration of the plant with `ode_solvers::Dopri5` (Dormand-Prince 5(4),
//! adaptive, error controlled, 4th-order dense output).
//!
//! Inputs are zero-order held, so the right-hand side jumps at sample boundaries where an
//! input changes. The integrator is therefore restarted at every input change (never
//! stepping across a discontinuity) and runs of identical inputs are integrated as one
//! segment, with the sample states taken from the dense output. The step size is carried
//! from one segment to the next (no fresh step-size guess at each restart).
//!
//! The ODE state is (beta, omega, p1, p2); a plant with a supply reservoir
//! ([`crate::plant::effects::SupplyDrop`], `model = "reservoir"`) adds the tank pressure as a
//! fifth state, carried by the [`Integrator`] ([`Integrator::supply_abs_pa`]). Without it the
//! 4-state path is unchanged.

use nalgebra::SVector;
use ode_solvers::{Dopri5, OutputType, System};

use crate::plant::effects::ShiftedCommands;
use crate::plant::{AuxLayout, AuxState, Plant, PlantState, ValveInputs};

pub mod arm3;
pub(crate) mod replay;
pub mod signal_path;
pub use signal_path::{ActuatorPath, SensorPath};

/// Tolerances of the adaptive integrator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolverOptions {
    /// Relative tolerance (per state component).
    pub rtol: f64,
    /// Absolute tolerance (rad, rad/s, Pa: the pressures are always dominated by `rtol`).
    pub atol: f64,
    /// Upper bound on steps in one constant-input segment (guards against a runaway).
    pub max_steps_per_segment: u32,
}

impl Default for SolverOptions {
    fn default() -> Self {
        Self {
            rtol: 1e-6,
            atol: 1e-6,
            max_steps_per_segment: 1_000_000,
        }
    }
}

/// Counters of one simulation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SimStats {
    pub segments: u64,
    pub rhs_evaluations: u64,
    pub accepted_steps: u64,
    pub rejected_steps: u64,
}

impl std::fmt::Display for SimStats {
    /// `S segments, A steps (R rejected), E rhs evaluations`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} segments, {} steps ({} rejected), {} rhs evaluations",
            self.segments, self.accepted_steps, self.rejected_steps, self.rhs_evaluations
        )
    }
}

impl SimStats {
    /// Adds the counters of `other` (e.g. of an integrator replaced mid-run).
    pub fn add(&mut self, other: &SimStats) {
        self.segments += other.segments;
        self.rhs_evaluations += other.rhs_evaluations;
        self.accepted_steps += other.accepted_steps;
        self.rejected_steps += other.rejected_steps;
    }
}

#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("integration failed at t = {t_s} s: {message}")]
    Integration { t_s: f64, message: String },
    #[error("state became non-finite at t = {t_s} s (state {state:?})")]
    NonFinite { t_s: f64, state: PlantState },
    #[error("invalid sample period {0} s (must be finite and > 0)")]
    SamplePeriod(f64),
    #[error("invalid valve input at sample {index}: {inputs:?} (openings must be in [0, 1])")]
    Input { index: usize, inputs: ValveInputs },
    #[error(
        "effect valve_dead_time (valve dead time): delay_s = {delay_s} s cannot be applied by the {mode} at a \
         sample period of {dt_s} s (allowed: 0 <= delay_s < 1e9 sample periods)"
    )]
    DeadTime {
        delay_s: f64,
        dt_s: f64,
        /// The run mode that refuses (e.g. "open-loop replay", "closed loop").
        mode: &'static str,
    },
    #[error("an auxiliary state (supply reservoir pressure or gas temperature) became non-finite at t = {t_s} s")]
    NonFiniteSupply { t_s: f64 },
}

/// The plant with auxiliary states: (beta, omega, p1, p2) then the [`AuxLayout`]'s
/// components (`N` = 4 + their number).
struct RhsAux<'a, const N: usize> {
    plant: &'a Plant,
    u: ValveInputs,
    layout: AuxLayout,
    /// The values of the components not integrated.
    base: AuxState,
}

impl<const N: usize> System<f64, SVector<f64, N>> for RhsAux<'_, N> {
    #[inline(always)]
    fn system(&self, _t: f64, y: &SVector<f64, N>, dy: &mut SVector<f64, N>) {
        let x = PlantState {
            angle_rad: y[0],
            velocity_rad_s: y[1],
            p1_abs_pa: y[2],
            p2_abs_pa: y[3],
        };
        let aux = self.layout.unpack(&self.base, &y.as_slice()[4..]);
        let (d, da) = self.plant.derivatives_aux(&x, &aux, &self.u);
        dy[0] = d.angle_rad;
        dy[1] = d.velocity_rad_s;
        dy[2] = d.p1_abs_pa;
        dy[3] = d.p2_abs_pa;
        let a = self.layout.pack(&da);
        for k in 4..N {
            dy[k] = a[k - 4];
        }
    }
}

/// The solver of one segment ([`dopri_segment`]).
pub(crate) type Dopri5State<const N: usize, F> = Dopri5<f64, SVector<f64, N>, F>;

/// One `Dopri5` run over a segment of zero-order-held inputs, with the settings every
/// integrator here uses (safety 0.9, step-size factors, stiffness test off: the laminar patch
/// keeps |lambda| h small), sparse output for a single sample (the last point is the end of
/// the last accepted step), dense output at the sample times otherwise. Adds the run's
/// counters to `stats`; returns the solver (its `y_out`, read with [`SegmentPlan::points`])
/// and the accepted steps.
pub(crate) fn dopri_segment<const N: usize, F: System<f64, SVector<f64, N>>>(
    f: F,
    y0: SVector<f64, N>,
    plan: &SegmentPlan,
    dt_s: f64,
    opts: &SolverOptions,
    stats: &mut SimStats,
) -> Result<(Dopri5State<N, F>, u32), String> {
    let SegmentPlan {
        single, x_end, h0, ..
    } = *plan;
    let mut solver = Dopri5::from_param(
        f,
        0.0,
        x_end,
        dt_s,
        y0,
        opts.rtol,
        opts.atol,
        0.9,
        0.04,
        0.2,
        10.0,
        x_end,
        h0,
        opts.max_steps_per_segment,
        u32::MAX,
        if single {
            OutputType::Sparse
        } else {
            OutputType::Dense
        },
    );
    let st = solver.integrate().map_err(|e| e.to_string())?;
    stats.segments += 1;
    stats.rhs_evaluations += u64::from(st.num_eval);
    stats.accepted_steps += u64::from(st.accepted_steps);
    stats.rejected_steps += u64::from(st.rejected_steps);
    Ok((solver, st.accepted_steps))
}

/// Where one segment of `n` samples of `dt_s` ends and how it starts (shared by the 1-DOF
/// integrator and the 3-DOF arm's).
#[derive(Clone, Copy)]
pub(crate) struct SegmentPlan {
    /// `n dt_s`.
    pub duration_s: f64,
    /// One sample: sparse output, integrated exactly to its end.
    pub single: bool,
    /// End of the integration.
    pub x_end: f64,
    /// First step (0: let Dopri5 pick it).
    pub h0: f64,
}

impl SegmentPlan {
    /// `h_s`: the step size kept from the previous segment (<= 0: none).
    pub fn new(n: usize, dt_s: f64, h_s: f64) -> Self {
        let duration_s = n as f64 * dt_s;
        // ode_solvers' dense output adds x_end as soon as the next pending output time is
        // within 1e-9 of it, even after a step that has not reached x_end (then it
        // extrapolates). Ending the segment a hair after the last sample time keeps every
        // output an interpolation inside an accepted step.
        // A single sample needs no dense output: integrate exactly to its end (sparse output,
        // the last point is the end of the last accepted step).
        let single = n == 1;
        let x_end = if single {
            duration_s
        } else {
            duration_s + (1e-6 * dt_s).max(4e-9)
        };
        let h0 = if h_s > 0.0 { h_s.min(duration_s) } else { 0.0 };
        SegmentPlan {
            duration_s,
            single,
            x_end,
            h0,
        }
    }

    /// The output points of a [`dopri_segment`] over this plan's `n` samples (`ys`: the
    /// solver's output): the states at the starts of the samples (none for a single sample,
    /// whose start is the caller's state) and the state at the end.
    pub fn points<'y, V>(&self, ys: &'y [V], n: usize) -> Result<(&'y [V], &'y V), String> {
        if self.single {
            return Ok((&[], ys.last().expect("sparse output holds the start point")));
        }
        if ys.len() < n + 1 {
            return Err(format!(
                "dense output gave {} points for {} samples",
                ys.len(),
                n + 1
            ));
        }
        Ok((&ys[..n], &ys[n]))
    }

    /// The mean accepted step of the segment, as the first step of the next one.
    pub fn mean_step_s(&self, accepted: u32) -> f64 {
        self.duration_s / f64::from(accepted.max(1))
    }
}

fn valid_inputs(u: &ValveInputs) -> bool {
    [u.u_in1, u.u_ex1, u.u_in2, u.u_ex2]
        .iter()
        .all(|v| (0.0..=1.0).contains(v))
}

/// A plant state advanced piecewise under zero-order-held inputs. Keeps the step size
/// between calls, so it also serves closed-loop use (one call per control tick). A clone
/// continues from the same point (to try several inputs from one state).
#[derive(Clone)]
pub struct Integrator<'a> {
    plant: &'a Plant,
    state: PlantState,
    t_s: f64,
    h_s: f64,
    opts: SolverOptions,
    stats: SimStats,
    /// The auxiliary states (reservoir pressure, gas temperatures); constant where the
    /// plant does not integrate them.
    aux: AuxState,
    /// f(state, inputs) of the last single-sample step (first-same-as-last), with the
    /// inputs it was evaluated under.
    fsal: Option<(ValveInputs, [f64; 4])>,
    /// Whether single samples may take [`Self::single_step`] (default true).
    single_step_path: bool,
}

impl<'a> Integrator<'a> {
    pub fn new(plant: &'a Plant, state: PlantState, opts: SolverOptions) -> Self {
        Self {
            plant,
            state,
            t_s: 0.0,
            h_s: 0.0,
            opts,
            stats: SimStats::default(),
            aux: plant.initial_aux(),
            fsal: None,
            single_step_path: true,
        }
    }

    /// Integrates every sample with `Dopri5` itself, never with the allocation-free single
    /// step (which gives the same accepted steps; this is how tests check that).
    pub fn without_single_step_path(mut self) -> Self {
        self.single_step_path = false;
        self
    }

    /// Sets the supply reservoir pressure (absolute), e.g. to carry it over to an integrator
    /// of another plant. No effect on a plant without a reservoir.
    pub fn set_supply_abs_pa(&mut self, p_abs_pa: f64) {
        self.aux.supply_abs_pa = p_abs_pa;
    }

    /// Sets the external torque on the joint held from now on [N m] (see
    /// [`crate::plant::LoadTorque`]).
    pub fn set_load_torque_nm(&mut self, torque_nm: f64) {
        if torque_nm != self.aux.load_torque_nm {
            self.aux.load_torque_nm = torque_nm;
            // The stored f(state, inputs) was evaluated under the old torque.
            self.fsal = None;
        }
    }

    /// The supply reservoir pressure now (absolute); p_s0 for a plant without a reservoir.
    pub fn supply_abs_pa(&self) -> f64 {
        self.aux.supply_abs_pa
    }

    /// The auxiliary states now (reservoir pressure, gas temperatures).
    pub fn aux(&self) -> AuxState {
        self.aux
    }

    /// Sets the auxiliary states, e.g. to carry them over to an integrator of another plant
    /// (the closed loop's load and supply events): a reservoir keeps its pressure, the gas
    /// its temperature.
    pub fn set_aux(&mut self, aux: AuxState) {
        self.aux = aux;
    }

    pub fn state(&self) -> PlantState {
        self.state
    }
    pub fn time_s(&self) -> f64 {
        self.t_s
    }
    pub fn stats(&self) -> SimStats {
        self.stats
    }

    /// Holds `inputs` for `n` samples of `dt_s`; calls `on_sample` with the state at the
    /// start of each of the `n` samples; afterwards [`Self::state`] is the state at the end.
    pub fn advance_samples(
        &mut self,
        inputs: ValveInputs,
        dt_s: f64,
        n: usize,
        mut on_sample: impl FnMut(&PlantState),
    ) -> Result<(), SimError> {
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return Err(SimError::SamplePeriod(dt_s));
        }
        if !valid_inputs(&inputs) {
            return Err(SimError::Input { index: 0, inputs });
        }
        if n == 0 {
            return Ok(());
        }
        let plan = SegmentPlan::new(n, dt_s, self.h_s);
        let duration_s = plan.duration_s;
        if plan.single
            && self.single_step_path
            && !self.plant.has_aux_state()
            && self.h_s >= 0.5 * duration_s
        {
            if let Some(end) = self.single_step(inputs, duration_s) {
                on_sample(&self.state);
                self.state = end;
                self.t_s += duration_s;
                return Ok(());
            }
        }
        self.fsal = None;
        match self.plant.aux_layout() {
            AuxLayout::None => self.advance_samples_n::<4>(inputs, dt_s, n, &plan, on_sample),
            AuxLayout::Supply => self.advance_samples_n::<5>(inputs, dt_s, n, &plan, on_sample),
            AuxLayout::Temperatures => {
                self.advance_samples_n::<6>(inputs, dt_s, n, &plan, on_sample)
            }
            AuxLayout::SupplyAndTemperatures => {
                self.advance_samples_n::<7>(inputs, dt_s, n, &plan, on_sample)
            }
        }
    }

    /// One Dormand-Prince 5(4) step over the whole sample, the step `Dopri5` takes first when
    /// the previous sample needed a single step (same tableau, same error norm, same
    /// acceptance rule err <= 1, so an accepted step gives the state `Dopri5` would), without
    /// its per-call allocations, and reusing the last stage of the previous sample
    /// (first-same-as-last) while the inputs stay the same. This is the closed-loop pattern:
    /// one restart per control tick; tried when the previous sample needed at most two steps.
    /// `None` when the step is rejected or not finite; the
    /// caller then integrates the sample adaptively.
    fn single_step(&mut self, inputs: ValveInputs, h: f64) -> Option<PlantState> {
        let aux = self.aux;
        let f = |y: &[f64; 4]| {
            // The plant has no auxiliary states on this path: the stored ones are constants.
            self.plant
                .derivatives_aux(&PlantState::from_array(*y), &aux, &inputs)
                .0
                .to_array()
        };
        let y0 = self.state.to_array();
        let (k1, fresh) = match self.fsal {
            Some((u, k)) if u == inputs => (k, 0),
            _ => (f(&y0), 1),
        };
        let stage = |coef: &[(f64, &[f64; 4])]| -> [f64; 4] {
            let mut y = y0;
            for (a, k) in coef {
                for i in 0..4 {
                    y[i] += h * a * k[i];
                }
            }
            y
        };
        let k2 = f(&stage(&[(1.0 / 5.0, &k1)]));
        let k3 = f(&stage(&[(3.0 / 40.0, &k1), (9.0 / 40.0, &k2)]));
        let k4 = f(&stage(&[
            (44.0 / 45.0, &k1),
            (-56.0 / 15.0, &k2),
            (32.0 / 9.0, &k3),
        ]));
        let k5 = f(&stage(&[
            (19372.0 / 6561.0, &k1),
            (-25360.0 / 2187.0, &k2),
            (64448.0 / 6561.0, &k3),
            (-212.0 / 729.0, &k4),
        ]));
        let k6 = f(&stage(&[
            (9017.0 / 3168.0, &k1),
            (-355.0 / 33.0, &k2),
            (46732.0 / 5247.0, &k3),
            (49.0 / 176.0, &k4),
            (-5103.0 / 18656.0, &k5),
        ]));
        let y1 = stage(&[
            (35.0 / 384.0, &k1),
            (500.0 / 1113.0, &k3),
            (125.0 / 192.0, &k4),
            (-2187.0 / 6784.0, &k5),
            (11.0 / 84.0, &k6),
        ]);
        let k7 = f(&y1);
        self.stats.rhs_evaluations += 6 + fresh;
        let mut err2 = 0.0;
        for i in 0..4 {
            let e = h
                * (71.0 / 57600.0 * k1[i] - 71.0 / 16695.0 * k3[i] + 71.0 / 1920.0 * k4[i]
                    - 17253.0 / 339200.0 * k5[i]
                    + 22.0 / 525.0 * k6[i]
                    - 1.0 / 40.0 * k7[i]);
            let sc = self.opts.atol + y0[i].abs().max(y1[i].abs()) * self.opts.rtol;
            err2 += (e / sc) * (e / sc);
        }
        let err = (err2 / 4.0).sqrt();
        if !(err <= 1.0 && y1.iter().all(|v| v.is_finite())) {
            self.stats.rejected_steps += 1;
            // The adaptive integration starts from the step Dopri5's controller would retry.
            self.h_s = if err.is_finite() {
                h * (0.9 * err.powf(-0.2)).clamp(0.2, 1.0)
            } else {
                0.2 * h
            };
            return None;
        }
        self.stats.segments += 1;
        self.stats.accepted_steps += 1;
        self.fsal = Some((inputs, k7));
        Some(PlantState::from_array(y1))
    }

    /// [`Self::advance_samples`] with `Dopri5` over (beta, omega, p1, p2) and the plant's
    /// auxiliary states (`N` = 4 + their number).
    fn advance_samples_n<const N: usize>(
        &mut self,
        inputs: ValveInputs,
        dt_s: f64,
        n: usize,
        plan: &SegmentPlan,
        mut on_sample: impl FnMut(&PlantState),
    ) -> Result<(), SimError> {
        let duration_s = plan.duration_s;
        let t_s = self.t_s;
        let integration = |message| SimError::Integration { t_s, message };
        let a = self.state.to_array();
        let layout = self.plant.aux_layout();
        let packed = layout.pack(&self.aux);
        let mut y0 = SVector::<f64, N>::zeros();
        for k in 0..N {
            y0[k] = if k < 4 { a[k] } else { packed[k - 4] };
        }
        let (solver, accepted) = dopri_segment(
            RhsAux::<N> {
                plant: self.plant,
                u: inputs,
                layout,
                base: self.aux,
            },
            y0,
            plan,
            dt_s,
            &self.opts,
            &mut self.stats,
        )
        .map_err(integration)?;
        let (starts, last) = plan.points(solver.y_out(), n).map_err(integration)?;
        let end = PlantState::from_array([last[0], last[1], last[2], last[3]]);
        if !end.to_array().iter().all(|v| v.is_finite()) {
            return Err(SimError::NonFinite {
                t_s: self.t_s + duration_s,
                state: end,
            });
        }
        if !last.as_slice()[4..].iter().all(|v| v.is_finite()) {
            return Err(SimError::NonFiniteSupply {
                t_s: self.t_s + duration_s,
            });
        }
        if plan.single {
            on_sample(&self.state);
        }
        for y in starts {
            on_sample(&PlantState::from_array([y[0], y[1], y[2], y[3]]));
        }
        self.state = end;
        self.aux = layout.unpack(&self.aux, &last.as_slice()[4..]);
        self.t_s += duration_s;
        self.h_s = plan.mean_step_s(accepted);
        Ok(())
    }

    /// Holds `inputs` for `duration_s` (one control tick) and returns the state at its end.
    pub fn advance(
        &mut self,
        inputs: ValveInputs,
        duration_s: f64,
    ) -> Result<PlantState, SimError> {
        self.advance_samples(inputs, duration_s, 1, |_| {})?;
        Ok(self.state)
    }
}

/// The result of an open-loop replay: `states[k]` is the state at `t_k = k dt`.
#[derive(Debug, Clone)]
pub struct Simulation {
    pub states: Vec<PlantState>,
    pub final_state: PlantState,
    pub stats: SimStats,
}

/// Open-loop replay from the plant's `[initial]` state: `inputs[k]` is held over
/// `[t_k, t_k + dt)`; returns one state per input sample (the state at `t_k`).
pub fn simulate(
    plant: &Plant,
    inputs: &[ValveInputs],
    dt_s: f64,
    opts: &SolverOptions,
) -> Result<Simulation, SimError> {
    simulate_with_progress(plant, inputs, dt_s, opts, |_| {})
}

/// [`simulate`] with a progress callback (number of samples done so far).
pub fn simulate_with_progress(
    plant: &Plant,
    inputs: &[ValveInputs],
    dt_s: f64,
    opts: &SolverOptions,
    progress: impl FnMut(usize),
) -> Result<Simulation, SimError> {
    let mut states = Vec::with_capacity(inputs.len());
    let (final_state, stats) =
        simulate_each(plant, inputs, dt_s, opts, progress, |x| states.push(*x))?;
    Ok(Simulation {
        states,
        final_state,
        stats,
    })
}

/// [`simulate_each`] followed by the plant's sensor path ([`SensorPath`], as
/// `Plant::measure_series`): `f(k, state, channels)` for every sample `k` in order, holding no
/// series (the same values to the bit as simulating, then measuring the series).
pub fn measure_each(
    plant: &Plant,
    inputs: &[ValveInputs],
    dt_s: f64,
    opts: &SolverOptions,
    mut f: impl FnMut(usize, &PlantState, &crate::plant::Measurement),
) -> Result<(PlantState, SimStats), SimError> {
    let mut sensor = SensorPath::new(plant, dt_s);
    let mut k = 0;
    simulate_each(
        plant,
        inputs,
        dt_s,
        opts,
        |_| {},
        |x| {
            f(k, x, &sensor.push(plant, x));
            k += 1;
        },
    )
}

/// [`simulate_with_progress`] without the state series: `on_state` is called with the state
/// of every sample in order (the same integrator calls, so the same states to the bit), and
/// the final state and the counters are returned. Memory does not grow with the inputs (the
/// valve dead time, if any, is applied sample by sample while the runs of identical
/// openings are collected).
pub fn simulate_each(
    plant: &Plant,
    inputs: &[ValveInputs],
    dt_s: f64,
    opts: &SolverOptions,
    mut progress: impl FnMut(usize),
    mut on_state: impl FnMut(&PlantState),
) -> Result<(PlantState, SimStats), SimError> {
    if let Some((index, u)) = inputs.iter().enumerate().find(|(_, u)| !valid_inputs(u)) {
        return Err(SimError::Input { index, inputs: *u });
    }
    let mut actuator = ActuatorPath::new(plant, dt_s, "open-loop replay")?;
    // A dead time shorter than a sample leaves the openings as they are.
    let delayed = actuator.delay_samples() != 0;
    let mut integ = Integrator::new(plant, plant.initial_state(), *opts);
    // The current run of identical (delayed) openings: (openings, samples).
    let mut run: Option<(ValveInputs, usize)> = None;
    for (k, u) in inputs.iter().enumerate() {
        let u = if delayed { actuator.push(*u) } else { *u };
        // An external torque series changes every sample: one segment per sample.
        if let Some(load) = &plant.load {
            integ.set_load_torque_nm(load.at(k));
            integ.advance_samples(u, dt_s, 1, &mut on_state)?;
            progress(k + 1);
            continue;
        }
        match &mut run {
            Some((ru, len)) if *ru == u => *len += 1,
            _ => {
                if let Some((ru, len)) = run.take() {
                    integ.advance_samples(ru, dt_s, len, &mut on_state)?;
                    progress(k);
                }
                run = Some((u, 1));
            }
        }
    }
    if let Some((ru, len)) = run {
        integ.advance_samples(ru, dt_s, len, &mut on_state)?;
        progress(inputs.len());
    }
    Ok((integ.state(), integ.stats()))
}

/// Open-loop replay at a recording's own time stamps (uniform or jittered): `inputs[k]` is
/// held over `[t_s[k], t_s[k + 1])`; returns the state at every stamp (`states[k]` at
/// `t_s[k]`, the first one the plant's `[initial]` state). The last input is held for the
/// mean step to give `final_state`. A valve dead time delays every input edge by exactly
/// `delay_s` (the edges then fall between the stamps).
pub fn simulate_stamped(
    plant: &Plant,
    t_s: &[f64],
    inputs: &[ValveInputs],
    opts: &SolverOptions,
    mut progress: impl FnMut(usize),
) -> Result<Simulation, SimError> {
    let n = inputs.len();
    if let Some((index, u)) = inputs.iter().enumerate().find(|(_, u)| !valid_inputs(u)) {
        return Err(SimError::Input { index, inputs: *u });
    }
    if plant.load.is_some() {
        return Err(SimError::Integration {
            t_s: 0.0,
            message: "an external torque series is replayed at uniform samples only".into(),
        });
    }
    if t_s.len() != n || n == 0 {
        return Err(SimError::Integration {
            t_s: 0.0,
            message: format!("{} time stamps for {n} input samples", t_s.len()),
        });
    }
    let mean_step = if n > 1 {
        (t_s[n - 1] - t_s[0]) / (n - 1) as f64
    } else {
        1.0
    };
    let t_end = t_s[n - 1] + mean_step;
    for k in 1..n {
        let step = t_s[k] - t_s[k - 1];
        if !(step.is_finite() && step > 0.0) {
            return Err(SimError::SamplePeriod(step));
        }
    }
    let delay_s = plant.effects.valve_dead_time_s().unwrap_or(0.0);
    // The dead time is its effect's (`ShiftedCommands`): the input in force at time t is
    // the sample of the last stamp <= t - delay (all valves closed before the first delayed
    // edge, as the dead-time line starts). Breakpoints: the stamps, the delayed stamps, the
    // end.
    let mut shifted = ShiftedCommands::new(t_s, inputs, delay_s, 1e-12 * mean_step);
    let cuts = shifted.breakpoints(t_end);
    let mut integ = Integrator::new(plant, plant.initial_state(), *opts);
    let mut states = Vec::with_capacity(n);
    let mut next_stamp = 0usize;
    for w in cuts.windows(2) {
        let (a, b) = (w[0], w[1]);
        if next_stamp < n && (t_s[next_stamp] - a).abs() <= 1e-12 * mean_step {
            states.push(integ.state());
            next_stamp += 1;
            if next_stamp % 1000 == 0 {
                progress(next_stamp);
            }
        }
        let u = if delay_s > 0.0 {
            shifted.at(a)
        } else {
            inputs[next_stamp.saturating_sub(1)]
        };
        let h = b - a;
        if h > 0.0 {
            integ.advance(u, h)?;
        }
    }
    progress(n);
    Ok(Simulation {
        states,
        final_state: integ.state(),
        stats: integ.stats(),
    })
}
