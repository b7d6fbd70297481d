//! Recordings of the 3-DOF arm ([`crate::plant::arm3`]), a pressure-regulated step scenario
//! (seed 001 section 4) and a plot of the three joints.
//!
//! # 3-joint recording format
//! The RECORDING.md format with every joint's columns suffixed `_j1`, `_j2`, `_j3`:
//! - optional leading `# key = value` metadata lines, then a header, then one row per sample;
//! - required: `t_s` (increasing; jitter within [0.5, 1.5] median steps is accepted and put
//!   on the uniform grid, a gap is refused, as in a 1-DOF recording) and the twelve valve openings `u_in1_jN`, `u_ex1_jN`,
//!   `u_in2_jN`, `u_ex2_jN` (N = 1..3, in [0, 1], held over [t_k, t_k+1));
//! - outputs, optional, at least one: `angle_deg_jN`, `p1_kpa_jN`, `p2_kpa_jN` (gauge),
//!   `f1_n_jN`, `f2_n_jN`; other columns are ignored; columns in any order.
//!
//! Muscle 1 of joint N contracts when the joint angle grows. Every error names the file, the
//! line and the field; outputs are written atomically.

use std::path::Path;

use crate::fit::fit_percent;
use crate::io::numfmt;
use crate::io::recording::{
    read_text, write_atomically, Channel, Recording, RecordingError, Table, INPUT_COLUMNS,
};
use crate::plant::arm3::{Arm3, Arm3Inputs, Arm3State};
use crate::plant::ValveInputs;
use crate::sim::arm3::{Arm3Integrator, Arm3SimError};
use crate::sim::SolverOptions;

/// Number of joints.
pub const JOINTS: usize = 3;

/// Column name of a 1-DOF column `base` for joint `joint` (0-based): `base_j{joint+1}`.
pub fn column(base: &str, joint: usize) -> String {
    format!("{base}_j{}", joint + 1)
}

/// Whether the file at `path` is a 3-joint recording: its header (the first line that is
/// not `#` metadata, within the first 64 KiB) names `u_in1_j1`. False when it cannot be read.
pub fn is_arm3_recording(path: impl AsRef<Path>) -> bool {
    use std::io::Read;
    let mut head = Vec::new();
    let Ok(f) = std::fs::File::open(path) else {
        return false;
    };
    if f.take(64 * 1024).read_to_end(&mut head).is_err() {
        return false;
    }
    let text = String::from_utf8_lossy(&head);
    let header = text
        .lines()
        .map(str::trim)
        .find(|l| !l.is_empty() && !l.starts_with('#'));
    header.is_some_and(|h| {
        h.split(',')
            .any(|c| c.trim().trim_matches('"') == column(INPUT_COLUMNS[0], 0))
    })
}

/// One run of the arm.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Arm3Recording {
    pub metadata: Vec<(String, String)>,
    pub t_s: Vec<f64>,
    pub inputs: Vec<Arm3Inputs>,
    /// `outputs[joint][channel.index()]`.
    pub outputs: [[Option<Vec<f64>>; 5]; JOINTS],
}

impl Arm3Recording {
    pub fn len(&self) -> usize {
        self.t_s.len()
    }

    pub fn is_empty(&self) -> bool {
        self.t_s.is_empty()
    }

    /// Uniform sample period from the first and last time stamps.
    pub fn sample_period_s(&self) -> f64 {
        crate::io::recording::mean_step_s(&self.t_s)
    }

    pub fn channel(&self, joint: usize, c: Channel) -> Option<&[f64]> {
        self.outputs[joint][c.index()].as_deref()
    }

    /// Joint `joint` (0-based) as a 1-DOF [`Recording`] (columns without the suffix), for
    /// [`crate::io::compare::compare`] and [`crate::io::plot::plot_comparison`].
    pub fn joint_recording(&self, joint: usize) -> Recording {
        Recording {
            metadata: self.metadata.clone(),
            t_s: self.t_s.clone(),
            inputs: self.inputs.iter().map(|u| u[joint]).collect(),
            outputs: self.outputs[joint].clone(),
            mass_flow_kg_s: None,
        }
    }

    /// The recording on the uniform grid `t_0 + k dt` (`dt` the mean step): each joint's
    /// columns through [`Recording::to_uniform`] (openings time-averaged over each grid
    /// cell, outputs linearly interpolated). A uniform recording is returned unchanged.
    pub fn to_uniform(self) -> Arm3Recording {
        if crate::io::recording::stamps_uniform(&self.t_s) {
            return self;
        }
        let joints: [Recording; JOINTS] =
            std::array::from_fn(|j| self.joint_recording(j).to_uniform());
        Arm3Recording {
            metadata: joints[0].metadata.clone(),
            t_s: joints[0].t_s.clone(),
            inputs: (0..self.t_s.len())
                .map(|k| std::array::from_fn(|j| joints[j].inputs[k]))
                .collect(),
            outputs: std::array::from_fn(|j| joints[j].outputs.clone()),
        }
    }

    /// The recorded channels of simulated states sampled every `dt_s` (all five channels of
    /// every joint, through each joint's sensor lag and calibration).
    pub fn set_outputs_from_states(&mut self, arm: &Arm3, states: &[Arm3State], dt_s: f64) {
        let meas = arm.measure_run(states, dt_s);
        for j in 0..JOINTS {
            let col = |f: fn(&crate::plant::arm3::JointMeasurement) -> f64| {
                Some(meas.iter().map(|m| f(&m[j])).collect())
            };
            self.outputs[j] = [
                col(|m| m.angle_deg),
                col(|m| m.p1_kpa),
                col(|m| m.p2_kpa),
                col(|m| m.f1_n),
                col(|m| m.f2_n),
            ];
        }
    }

    /// Reads and validates a 3-joint recording.
    pub fn read(path: impl AsRef<Path>) -> Result<Self, RecordingError> {
        let path = path.as_ref();
        Self::parse(&read_text(path)?, path)
    }

    /// Parses 3-joint recording text; `path` is used in error messages.
    pub fn parse(text: &str, path: impl AsRef<Path>) -> Result<Self, RecordingError> {
        let path = path.as_ref();
        let table = Table::parse(text, path)?;
        let t_col = table.required("t_s", "")?;
        let mut u_cols: [[(usize, String); 4]; JOINTS] = Default::default();
        for (j, cols) in u_cols.iter_mut().enumerate() {
            for (i, base) in INPUT_COLUMNS.iter().enumerate() {
                let name = column(base, j);
                let c = table.required(
                    &name,
                    " (a 3-joint recording names every valve column with a _j1.._j3 suffix)",
                )?;
                cols[i] = (c, name);
            }
        }
        let mut out_cols: Vec<(usize, usize, usize, String)> = Vec::new(); // joint, channel, col, name
        for j in 0..JOINTS {
            for c in Channel::ALL {
                let name = column(c.name(), j);
                if let Some(col) = table.find(&name)? {
                    out_cols.push((j, c.index(), col, name));
                }
            }
        }
        if out_cols.is_empty() {
            return Err(table.field_err(
                table.header_line,
                "angle_deg_j1",
                "no output column (need at least one of angle_deg_jN, p1_kpa_jN, p2_kpa_jN, \
                 f1_n_jN, f2_n_jN)",
            ));
        }
        let (rows, lines): (Vec<_>, _) = table.rows(|row| {
            let t_s = row.num(t_col, "t_s")?;
            let mut u = [ValveInputs::CLOSED; JOINTS];
            for (j, cols) in u_cols.iter().enumerate() {
                let mut v = [0.0; 4];
                for (i, (col, name)) in cols.iter().enumerate() {
                    v[i] = row.opening(*col, name)?;
                }
                u[j] = ValveInputs {
                    u_in1: v[0],
                    u_ex1: v[1],
                    u_in2: v[2],
                    u_ex2: v[3],
                };
            }
            let y = out_cols
                .iter()
                .map(|(_, _, col, name)| row.num(*col, name))
                .collect::<Result<Vec<f64>, _>>()?;
            Ok((t_s, u, y))
        })?;
        let mut rec = Arm3Recording {
            metadata: table.metadata.clone(),
            t_s: rows.iter().map(|r| r.0).collect(),
            inputs: rows.iter().map(|r| r.1).collect(),
            ..Default::default()
        };
        for (i, (j, c, _, _)) in out_cols.iter().enumerate() {
            rec.outputs[*j][*c] = Some(rows.iter().map(|r| r.2[i]).collect());
        }
        drop(rows);
        // The 1-DOF reader's time check: increasing, jitter within [0.5, 1.5] median steps
        // accepted, a gap refused at its own line, a declared sample period that agrees.
        table.check_time(&rec.t_s, |k| lines[k])?;
        // The arm integrates and is diagnosed on a uniform grid: jittered stamps are put on
        // it as the 1-DOF tools do ([`Recording::to_uniform`], joint by joint).
        Ok(rec.to_uniform())
    }

    /// Writes the recording (header `t_s`, the twelve valve columns, then the present
    /// outputs joint by joint); the target is replaced only once the new file is complete.
    pub fn write(&self, path: impl AsRef<Path>) -> Result<(), RecordingError> {
        use std::io::Write;
        let path = path.as_ref();
        let n = self.t_s.len();
        if self.inputs.len() != n
            || self
                .outputs
                .iter()
                .flatten()
                .flatten()
                .any(|c| c.len() != n)
        {
            return Err(RecordingError::Invalid {
                path: path.to_owned(),
                message: "columns of unequal length".into(),
            });
        }
        let present: Vec<(usize, Channel)> = (0..JOINTS)
            .flat_map(|j| Channel::ALL.into_iter().map(move |c| (j, c)))
            .filter(|(j, c)| self.outputs[*j][c.index()].is_some())
            .collect();
        write_atomically(path, |w| {
            for (k, v) in &self.metadata {
                if k.is_empty() {
                    writeln!(w, "# {v}")?;
                } else {
                    writeln!(w, "# {k} = {v}")?;
                }
            }
            let mut cw = csv::WriterBuilder::new().from_writer(&mut *w);
            let mut header = vec!["t_s".to_owned()];
            for j in 0..JOINTS {
                header.extend(INPUT_COLUMNS.iter().map(|b| column(b, j)));
            }
            header.extend(present.iter().map(|(j, c)| column(c.name(), *j)));
            cw.write_record(&header)?;
            let mut row: Vec<String> = Vec::with_capacity(header.len());
            for k in 0..n {
                row.clear();
                row.push(format!("{}", numfmt::time_to_ns(self.t_s[k])));
                for u in &self.inputs[k] {
                    for v in [u.u_in1, u.u_ex1, u.u_in2, u.u_ex2] {
                        row.push(format!("{v}"));
                    }
                }
                for (j, c) in &present {
                    row.push(format!(
                        "{:.6}",
                        self.outputs[*j][c.index()].as_ref().unwrap()[k]
                    ));
                }
                cw.write_record(&row)?;
            }
            cw.flush()?;
            Ok(())
        })
        .map_err(|source| RecordingError::Io {
            path: path.to_owned(),
            source,
        })
    }
}

/// Per joint and channel present in both: the fit (NRMSE %) of `model` against `reference`.
pub fn fits(reference: &Arm3Recording, model: &Arm3Recording) -> Vec<(String, f64)> {
    let mut out = Vec::new();
    for j in 0..JOINTS {
        for c in Channel::ALL {
            if let (Some(a), Some(b)) = (reference.channel(j, c), model.channel(j, c)) {
                if a.len() == b.len() {
                    out.push((column(c.name(), j), fit_percent(a, b)));
                }
            }
        }
    }
    out
}

// ---------------------------------------------------------------------------------------
// Pressure-regulated step scenario (seed 001 section 4)
// ---------------------------------------------------------------------------------------

/// The excitation of seed 001 section 4, time-compressed: every muscle held at `base_kpa`;
/// in `[t1, t2)` muscle 1 of joint N deflated by `deflation_kpa[N]`, in `[t3, t4)` muscle 2;
/// back to `base_kpa` in between and after. Seed 001 deflates by 350, 250 and 450 kPa (joints
/// 1, 2, 3) from 550 kPa. The pressure regulators (MATRIX ERP50 in seed 001) are modelled by
/// a proportional law on each muscle's valves: u_in = clamp((p_ref - p) / band), u_ex =
/// clamp((p - p_ref) / band), sampled every `dt_s` and held (zero order).
#[derive(Debug, Clone, PartialEq)]
pub struct PressureStepScenario {
    pub base_kpa: f64,
    pub deflation_kpa: [f64; JOINTS],
    /// t1, t2, t3, t4 in seconds.
    pub switch_times_s: [f64; 4],
    pub duration_s: f64,
    pub dt_s: f64,
    /// Pressure error (kPa) at which a valve is fully open.
    pub regulator_band_kpa: f64,
}

impl PressureStepScenario {
    /// Seed 001's deflations (350, 250, 450 kPa from 550 kPa) on all joints at once (its
    /// "complete model validation"), over its 120 s measurement time: deflations in
    /// [5, 35) s and [60, 90) s, 1 ms samples.
    pub fn seed001() -> Self {
        Self {
            base_kpa: 550.0,
            deflation_kpa: [350.0, 250.0, 450.0],
            switch_times_s: [5.0, 35.0, 60.0, 90.0],
            duration_s: 120.0,
            dt_s: 1e-3,
            regulator_band_kpa: 20.0,
        }
    }

    /// Pressure references (gauge, kPa) of (muscle 1, muscle 2) of every joint at time `t_s`.
    pub fn references_kpa(&self, t_s: f64) -> [[f64; 2]; JOINTS] {
        let [t1, t2, t3, t4] = self.switch_times_s;
        std::array::from_fn(|j| {
            let d = self.deflation_kpa[j];
            let mut r = [self.base_kpa; 2];
            if (t1..t2).contains(&t_s) {
                r[0] -= d;
            } else if (t3..t4).contains(&t_s) {
                r[1] -= d;
            }
            r
        })
    }

    /// Runs the scenario on `arm` from its initial state: a recording with the applied
    /// valve openings and all simulated channels, plus the true states.
    pub fn run(
        &self,
        arm: &Arm3,
        opts: &SolverOptions,
        mut progress: impl FnMut(f64),
    ) -> Result<(Arm3Recording, Vec<Arm3State>), Arm3SimError> {
        let n = (self.duration_s / self.dt_s).round() as usize;
        let mut integ = Arm3Integrator::new(arm, arm.initial, *opts);
        let mut valves = arm.actuator_paths(self.dt_s, "pressure-step scenario")?;
        let mut rec = Arm3Recording {
            metadata: vec![
                (
                    "source".into(),
                    "host-sim arm3 pressure-step scenario (seed 001 sec. 4)".into(),
                ),
                ("sample_period_s".into(), format!("{}", self.dt_s)),
            ],
            ..Default::default()
        };
        let mut states = Vec::with_capacity(n);
        let band_pa = self.regulator_band_kpa * 1000.0;
        let mut k = 0;
        while k < n {
            let t = k as f64 * self.dt_s;
            let x = integ.state();
            let r = self.references_kpa(t);
            let u: Arm3Inputs = std::array::from_fn(|j| {
                let e = |m: usize| (r[j][m] * 1000.0 + arm.p_atm_pa - x.p_abs_pa[j][m]) / band_pa;
                // Openings quantised to 1/1000 (a PWM duty resolution): equal openings over
                // consecutive samples make one integration segment.
                let open = |v: f64| (v.clamp(0.0, 1.0) * 1000.0).round() / 1000.0;
                ValveInputs {
                    u_in1: open(e(0)),
                    u_ex1: open(-e(0)),
                    u_in2: open(e(1)),
                    u_ex2: open(-e(1)),
                }
            });
            let applied: Arm3Inputs = std::array::from_fn(|j| valves[j].push(u[j]));
            integ.advance_samples(applied, self.dt_s, 1, |s| states.push(*s))?;
            rec.t_s.push(t);
            rec.inputs.push(u);
            k += 1;
            if k % 256 == 0 {
                progress(k as f64 / n as f64);
            }
        }
        rec.set_outputs_from_states(arm, &states, self.dt_s);
        Ok((rec, states))
    }
}

// ---------------------------------------------------------------------------------------
// Plot
// ---------------------------------------------------------------------------------------

/// Draws the angle and the two pressures of every joint (simulated; `reference` under it
/// where present) to a PNG or SVG file, written atomically.
pub fn plot_arm3(
    path: &Path,
    reference: Option<&Arm3Recording>,
    model: &Arm3Recording,
) -> Result<(), crate::io::plot::PlotError> {
    struct Arm<'a> {
        reference: Option<&'a Arm3Recording>,
        model: &'a Arm3Recording,
    }
    impl crate::io::plot::Figure for Arm<'_> {
        fn draw<DB: plotters::prelude::DrawingBackend>(
            &self,
            root: &plotters::prelude::DrawingArea<DB, plotters::coord::Shift>,
        ) -> Result<(), String> {
            draw_arm3(root, self.reference, self.model)
        }
    }
    crate::io::plot::write_plot(path, (1400u32, 900u32), &Arm { reference, model })
}

/// A channel, its colour, its simulated values and the reference values if any.
type Series<'a> = (
    Channel,
    plotters::style::RGBColor,
    &'a [f64],
    Option<&'a [f64]>,
);

fn draw_arm3<DB: plotters::prelude::DrawingBackend>(
    root: &plotters::prelude::DrawingArea<DB, plotters::coord::Shift>,
    reference: Option<&Arm3Recording>,
    model: &Arm3Recording,
) -> Result<(), String> {
    use plotters::prelude::*;
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let panels = root.split_evenly((JOINTS, 2));
    let t0 = model.t_s.first().copied().unwrap_or(0.0);
    let t1 = model.t_s.last().copied().unwrap_or(1.0).max(t0 + 1e-9);
    for j in 0..JOINTS {
        for (col, chans) in [
            vec![(Channel::AngleDeg, RED)],
            vec![(Channel::P1Kpa, RED), (Channel::P2Kpa, BLUE)],
        ]
        .into_iter()
        .enumerate()
        {
            let panel = &panels[2 * j + col];
            let series: Vec<Series> = chans
                .iter()
                .filter_map(|(c, color)| {
                    model
                        .channel(j, *c)
                        .map(|s| (*c, *color, s, reference.and_then(|r| r.channel(j, *c))))
                })
                .collect();
            if series.is_empty() {
                continue;
            }
            let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
            for (_, _, s, r) in &series {
                for v in s.iter().chain(r.iter().flat_map(|r| r.iter())) {
                    lo = lo.min(*v);
                    hi = hi.max(*v);
                }
            }
            let pad = ((hi - lo) * 0.05).max(1e-6);
            let caption = series
                .iter()
                .map(|(c, _, _, _)| column(c.name(), j))
                .collect::<Vec<_>>()
                .join(", ");
            let mut chart =
                crate::io::plot::time_panel(panel, &caption, None, (t0, t1), (lo - pad, hi + pad))?;
            for (c, color, s, r) in &series {
                let color = *color;
                if let (Some(r), Some(rr)) = (r, reference) {
                    chart
                        .draw_series(LineSeries::new(
                            rr.t_s.iter().copied().zip(r.iter().copied()),
                            color.mix(0.35).stroke_width(3),
                        ))
                        .map_err(|e| e.to_string())?;
                }
                crate::io::plot::labelled_line(
                    &mut chart,
                    model.t_s.iter().copied().zip(s.iter().copied()),
                    color.stroke_width(1),
                    color,
                    column(c.name(), j),
                )?;
            }
            crate::io::plot::draw_legend(&mut chart)?;
        }
    }
    Ok(())
}
