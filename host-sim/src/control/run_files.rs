//! Files and reports of closed-loop runs (`host-sim simulate --scenario`, `host-sim demo`).
//!
//! A run is written as two CSV files:
//! - `OUT.csv`, a recording strictly in the `shared/plant/RECORDING.md` format (`t_s`, the
//!   four valve commands, and the channels `angle_deg`, `p1_kpa`, `p2_kpa`, `f1_n`, `f2_n`
//!   as the plant's sensors report them: the true state when the plant has no sensor
//!   effects), with the plant's active effects in its metadata (`# effects = ...`); an
//!   open-loop replay of it on the same plant reproduces it. RECORDING.md lists the columns of a recording and says
//!   nothing about others, so no extra column goes into it: every tool that reads
//!   recordings can read it (`host-sim fit`, identification, diagnosis).
//! - `OUT.firmware.csv`, the firmware side of the same ticks (same `t_s`): the angle
//!   set-point, the firmware's torque estimate and demand, its pressure set-points, the
//!   latched fault code (0 = none, else [`FaultCode::code`]) and whether it was armed. The
//!   recording names it in its metadata (`# firmware_trace = ...`).
//!
//! Both are written through a temporary file renamed over the target when complete.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

use pam_firmware::safety::FaultCode;
use plotters::prelude::*;

use crate::control::closed_loop::{ClosedLoopRun, Scenario, TrackingStats};
use crate::io::plot::PlotError;
use crate::io::recording::{write_atomically, Recording, RecordingError};
use crate::plant::Plant;

/// Header of the firmware trace (the sidecar of a closed-loop recording).
pub const FIRMWARE_COLUMNS: [&str; 8] = [
    "t_s",
    "setpoint_angle_deg",
    "torque_est_nm",
    "torque_des_nm",
    "p1_set_kpa",
    "p2_set_kpa",
    "fault_code",
    "armed",
];

/// `dir/name.csv` -> `dir/name.firmware.csv` (the firmware trace next to a recording).
pub fn firmware_trace_path(recording: &Path) -> PathBuf {
    let stem = crate::io::file_stem_or(recording, "out");
    recording.with_file_name(format!("{stem}.firmware.csv"))
}

/// The recording of a run with metadata naming the plant, the scenario and the trace file.
pub fn run_recording(
    run: &ClosedLoopRun,
    plant_name: &str,
    scenario_name: &str,
    trace: Option<&Path>,
) -> Recording {
    let mut rec = run.to_recording();
    rec.metadata.insert(0, ("plant".into(), plant_name.into()));
    rec.metadata
        .insert(1, ("scenario".into(), scenario_name.into()));
    if let Some(t) = trace {
        let name = t
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        rec.metadata.push(("firmware_trace".into(), name));
    }
    rec.metadata.push((
        "notes".into(),
        "channels are what the plant's sensors report at t_s (its sensor effects, no scenario noise or quantisation); inputs are the valve commands over [t_s, t_s + dt), before the plant's valve dead time: `host-sim simulate --inputs` on this file with the same plant replays the run"
            .into(),
    ));
    rec
}

/// Writes the firmware trace of `run` (columns [`FIRMWARE_COLUMNS`]) atomically.
pub fn write_firmware_trace(run: &ClosedLoopRun, path: &Path) -> Result<(), RecordingError> {
    write_atomically(path, |w| {
        writeln!(
            w,
            "# source = host-sim closed loop, scenario {}, firmware pam_firmware::tick::ControlTick",
            run.name
        )?;
        writeln!(w, "# sample_period_s = {}", run.dt_s)?;
        writeln!(w, "# effects = {}", run.effects)?;
        writeln!(
            w,
            "# fault_code: 0 = none, else pam_firmware::safety::FaultCode numbers"
        )?;
        writeln!(w, "{}", FIRMWARE_COLUMNS.join(","))?;
        for r in &run.rows {
            writeln!(
                w,
                "{},{:.6},{:.6},{:.6},{:.3},{:.3},{},{}",
                crate::io::numfmt::time_to_ns(r.t_s),
                r.setpoint_rad.to_degrees(),
                r.out.torque_est_nm,
                r.out.torque_des_nm,
                r.out.p1_set_gauge_pa / 1e3,
                r.out.p2_set_gauge_pa / 1e3,
                r.out.fault.map_or(0, FaultCode::code),
                u8::from(r.out.armed)
            )?;
        }
        Ok(())
    })
    .map_err(|source| RecordingError::Io {
        path: path.to_owned(),
        source,
    })
}

/// A change of the firmware's latched fault.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaultChange {
    /// Tick index.
    pub tick: usize,
    /// Time [s].
    pub t_s: f64,
    /// The fault from this tick on (`None`: cleared).
    pub fault: Option<FaultCode>,
}

/// Every tick at which the latched fault changed (first latch, change of code, clearing).
pub fn fault_changes(run: &ClosedLoopRun) -> Vec<FaultChange> {
    let mut prev = None;
    let mut out = Vec::new();
    for (k, r) in run.rows.iter().enumerate() {
        if r.out.fault != prev {
            out.push(FaultChange {
                tick: k,
                t_s: r.t_s,
                fault: r.out.fault,
            });
            prev = r.out.fault;
        }
    }
    out
}

fn tracking_line(label: &str, st: &TrackingStats) -> String {
    if st.n == 0 {
        format!("{label}: no tick without a latched fault\n")
    } else {
        format!(
            "{label}: rms {:.5} rad ({:.3} deg), max {:.5} rad ({:.3} deg) over {} ticks\n",
            st.rms_rad,
            st.rms_rad.to_degrees(),
            st.max_abs_rad,
            st.max_abs_rad.to_degrees(),
            st.n
        )
    }
}

/// The summary's highest pressure set-point: in kPa, or said unknown (NaN: a processor-in-
/// the-loop run whose stream does not carry the set-points, not confirmed by the in-process
/// run).
fn max_set_point_text(p_set_gauge_pa: f64) -> String {
    if p_set_gauge_pa.is_finite() {
        format!("{:.1} kPa", p_set_gauge_pa / 1e3)
    } else {
        "unknown (not in the firmware's stream)".to_string()
    }
}

/// The tracking summary of a run: error over the whole run and after the scenario's settle
/// time, fault changes with tick and time, and the `[expect]` verdict (`fails` from
/// [`ClosedLoopRun::check`]).
pub fn summary(run: &ClosedLoopRun, scenario: &Scenario, fails: &[String]) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "scenario {}: {} ticks at {} Hz ({} s)",
        run.name,
        run.rows.len(),
        scenario.scenario.tick_hz,
        scenario.scenario.duration_s
    );
    let _ = writeln!(s, "plant effects: {}", run.effects);
    s += &tracking_line("angle error, whole run", &run.tracking(0.0));
    let settle = scenario.expect.settle_after_s;
    if settle > 0.0 {
        s += &tracking_line(
            &format!("angle error after {settle} s"),
            &run.tracking(settle),
        );
    }
    if let Some(k) = run.first_injected_fault_tick() {
        let _ = writeln!(
            s,
            "injected sensor fault from tick {k} (t = {:.3} s)",
            run.rows[k].t_s
        );
    }
    let changes = fault_changes(run);
    if changes.is_empty() {
        s += "faults: none\n";
    }
    for c in changes {
        match c.fault {
            Some(f) => {
                let _ = writeln!(
                    s,
                    "fault {f:?} (code {}) latched at tick {} (t = {:.3} s)",
                    f.code(),
                    c.tick,
                    c.t_s
                );
            }
            None => {
                let _ = writeln!(s, "fault cleared at tick {} (t = {:.3} s)", c.tick, c.t_s);
            }
        }
    }
    let _ = writeln!(
        s,
        "max muscle pressure {:.1} kPa, max pressure set-point {}",
        run.max_p_gauge_pa / 1e3,
        max_set_point_text(run.max_p_set_gauge_pa)
    );
    if scenario.expect.is_empty() {
        s += "expectations: none given (no [expect] bounds in the scenario)\n";
    } else if fails.is_empty() {
        s += "expectations: met\n";
    } else {
        for f in fails {
            let _ = writeln!(s, "expectation not met: {f}");
        }
    }
    s
}

/// Draws a closed-loop run (`.png` or `.svg`): angle and set-point, muscle pressures and the
/// firmware's pressure set-points, the firmware's torque estimate and demand; ticks with a
/// latched fault are shaded. Written through a temporary file renamed over `path`.
pub fn plot_run(path: &Path, run: &ClosedLoopRun, plant: &Plant) -> Result<(), PlotError> {
    if run.rows.is_empty() {
        return Err(PlotError::Empty(path.to_owned()));
    }
    struct Run<'a> {
        run: &'a ClosedLoopRun,
        plant: &'a Plant,
    }
    impl crate::io::plot::Figure for Run<'_> {
        fn draw<DB: DrawingBackend>(
            &self,
            root: &DrawingArea<DB, plotters::coord::Shift>,
        ) -> Result<(), String> {
            draw_run(root, self.run, self.plant)
        }
    }
    crate::io::plot::write_plot(path, (1200u32, 780u32), &Run { run, plant })
}

type Series<'a> = (&'a str, RGBColor, Vec<f64>);

fn draw_run<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    run: &ClosedLoopRun,
    plant: &Plant,
) -> Result<(), String> {
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let t: Vec<f64> = run.rows.iter().map(|r| r.t_s).collect();
    let col = |f: &dyn Fn(&crate::control::closed_loop::TickRow) -> f64| -> Vec<f64> {
        run.rows.iter().map(f).collect()
    };
    let orange = RGBColor(230, 130, 0);
    let green = RGBColor(0, 140, 60);
    let gauge_kpa = |p_abs_pa: f64| (p_abs_pa - plant.p_atm_pa) / 1e3;
    let kpa = |p_gauge_pa: f32| p_gauge_pa as f64 / 1e3;
    let panels: [(&str, Vec<Series>); 3] = [
        (
            "angle_deg",
            vec![
                ("set-point", BLUE, col(&|r| r.setpoint_rad.to_degrees())),
                ("simulated", RED, col(&|r| r.state.angle_rad.to_degrees())),
            ],
        ),
        (
            "pressure_kpa (gauge)",
            vec![
                ("p1", RED, col(&|r| gauge_kpa(r.state.p1_abs_pa))),
                ("p1 set", orange, col(&|r| kpa(r.out.p1_set_gauge_pa))),
                ("p2", BLUE, col(&|r| gauge_kpa(r.state.p2_abs_pa))),
                ("p2 set", green, col(&|r| kpa(r.out.p2_set_gauge_pa))),
            ],
        ),
        (
            "torque_nm (firmware)",
            vec![
                ("estimate", RED, col(&|r| r.out.torque_est_nm as f64)),
                ("demand", BLUE, col(&|r| r.out.torque_des_nm as f64)),
            ],
        ),
    ];
    let faulted: Vec<bool> = run.rows.iter().map(|r| r.out.fault.is_some()).collect();
    let t0 = t[0];
    let t1 = t[t.len() - 1].max(t0 + 1e-9);
    for (area, (name, series)) in root.split_evenly((3, 1)).iter().zip(panels) {
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        for v in series.iter().flat_map(|s| s.2.iter()) {
            if v.is_finite() {
                lo = lo.min(*v);
                hi = hi.max(*v);
            }
        }
        if !(lo.is_finite() && hi.is_finite()) {
            lo = -1.0;
            hi = 1.0;
        }
        let pad = ((hi - lo) * 0.05).max(1e-6);
        let (lo, hi) = (lo - pad, hi + pad);
        let mut chart = crate::io::plot::time_panel(
            area,
            &format!("{} / {name}", run.name),
            Some(name),
            (t0, t1),
            (lo, hi),
        )?;
        // Shade the ticks with a latched fault.
        let mut k = 0;
        while k < faulted.len() {
            if !faulted[k] {
                k += 1;
                continue;
            }
            let start = k;
            while k < faulted.len() && faulted[k] {
                k += 1;
            }
            let end_t = if k < t.len() { t[k] } else { t1 };
            chart
                .draw_series(std::iter::once(Rectangle::new(
                    [(t[start], lo), (end_t, hi)],
                    RGBColor(255, 200, 200).mix(0.5).filled(),
                )))
                .map_err(|e| e.to_string())?;
        }
        for (label, color, v) in series {
            crate::io::plot::labelled_line(
                &mut chart,
                t.iter().copied().zip(v.iter().copied()),
                color.stroke_width(1),
                color,
                label,
            )?;
        }
        crate::io::plot::draw_legend(&mut chart)?;
    }
    Ok(())
}

/// What [`simulate_scenario`] produced.
#[derive(Debug)]
pub struct ScenarioOutcome {
    /// The run.
    pub run: ClosedLoopRun,
    /// The `[expect]` failures (empty: met).
    pub fails: Vec<String>,
    /// The printed summary.
    pub summary: String,
    /// The firmware trace written next to the recording.
    pub trace_path: PathBuf,
    /// Wall time of the closed loop alone (plant + firmware), seconds.
    pub wall_s: f64,
}

/// `host-sim simulate --plant P --scenario S --out OUT [--plot F]`: runs the scenario with
/// the firmware's reference controller, writes `OUT` (RECORDING.md) and its firmware trace
/// ([`firmware_trace_path`]), optionally the plot.
pub fn simulate_scenario(
    plant_path: &Path,
    scenario_path: &Path,
    out: &Path,
    plot: Option<&Path>,
    progress: &mut dyn FnMut(f64),
) -> anyhow::Result<ScenarioOutcome> {
    use anyhow::Context;
    let plant = Plant::load(plant_path)?;
    let (text, file) = crate::io::scenario::read_scenario_text(scenario_path)?;
    let scenario = Scenario::from_toml_str(&text, &file)?;
    let cfg = pam_firmware::tick::ControllerConfig::reference(scenario.scenario.tick_hz as f32);
    scenario
        .setpoint
        .check_within(&text, &file, cfg.angle_setpoint_max_rad)?;
    let t0 = std::time::Instant::now();
    let run = crate::control::closed_loop::run_with(&plant, &scenario, cfg, progress)
        .with_context(|| format!("{}: closed-loop run failed", scenario_path.display()))?;
    let wall_s = t0.elapsed().as_secs_f64();
    let fails = run.check();
    let trace_path = firmware_trace_path(out);
    let rec = run_recording(
        &run,
        &plant_path.display().to_string(),
        &scenario_path.display().to_string(),
        Some(&trace_path),
    );
    // The trace first: the recording that names it appears only once both are complete.
    write_firmware_trace(&run, &trace_path)?;
    rec.write(out)?;
    if let Some(p) = plot {
        plot_run(p, &run, &plant)?;
    }
    let summary = summary(&run, &scenario, &fails);
    Ok(ScenarioOutcome {
        run,
        fails,
        summary,
        trace_path,
        wall_s,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_unknown_pressure_set_point_is_said_unknown_not_zero() {
        assert_eq!(max_set_point_text(470_000.0), "470.0 kPa");
        let t = max_set_point_text(f64::NAN);
        assert!(t.contains("unknown") && !t.contains("0.0"), "{t}");
    }
}
