//! `host-sim demo --plant <arm file>`: the firmware's arm tick (`pam_firmware::arm::ArmTick`,
//! `config/arm3.toml`) in the loop on the 3-DOF arm of seed 001, on the arm scenarios of
//! `scenarios/arm3/` (compiled in): a recording, a firmware trace and a plot per scenario,
//! and a table of the per-joint tracking against each scenario's `[expect]` bounds.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};

use crate::control::arm3_loop::{run_arm, ArmScenario};
use crate::demo::{expect_column, out_file, write_expect_fails};
use crate::io::arm3::plot_arm3;
use crate::plant::arm3::Arm3;
use pam_firmware::arm::{ArmConfig, JOINTS};

/// The arm demo's scenarios: (file name, text).
pub const ARM_SCENARIOS: [(&str, &str); 3] = [
    (
        "scenarios/arm3/step.toml",
        include_str!("../../scenarios/arm3/step.toml"),
    ),
    (
        "scenarios/arm3/sine.toml",
        include_str!("../../scenarios/arm3/sine.toml"),
    ),
    (
        "scenarios/arm3/pick_place.toml",
        include_str!("../../scenarios/arm3/pick_place.toml"),
    ),
];

/// One scenario's result.
#[derive(Debug, Clone)]
pub struct ArmScenarioResult {
    pub name: String,
    pub duration_s: f64,
    pub settle_after_s: f64,
    /// Per joint [rad].
    pub rms_error_rad: [f64; JOINTS],
    /// Per joint [rad].
    pub max_abs_error_rad: [f64; JOINTS],
    /// Highest muscle pressure [kPa].
    pub max_pressure_kpa: f64,
    pub expect_fails: Vec<String>,
    /// The scenario sets no `[expect]` bound (nothing to meet).
    pub no_expectations: bool,
    /// The first latched fault: (time [s], code, joint 1-based).
    pub first_fault: Option<(f64, u8, u8)>,
    /// Simulated seconds per wall second.
    pub speed_x: f64,
    pub files: Vec<PathBuf>,
}

/// The arm demo's results.
#[derive(Debug, Clone)]
pub struct ArmDemoReport {
    pub plant: PathBuf,
    pub scenarios: Vec<ArmScenarioResult>,
}

impl ArmDemoReport {
    /// True when every scenario met its expectations.
    pub fn ok(&self) -> bool {
        self.scenarios.iter().all(|c| c.expect_fails.is_empty())
    }
}

/// Runs `scenarios` (file name, text) on the arm plant `plant_path`, writing into `out_dir`.
pub fn run_arm_demo_with(
    plant_path: &Path,
    out_dir: &Path,
    scenarios: &[(&str, &str)],
) -> Result<ArmDemoReport> {
    let arm = Arm3::load(plant_path)?;
    // Every scenario parses (its name is a plain file name) before anything runs, and two
    // scenarios may not write the same files.
    let parsed = scenarios
        .iter()
        .map(|(file, text)| ArmScenario::from_toml_str(text, file).map(|s| (*file, s)))
        .collect::<Result<Vec<_>, _>>()?;
    for (k, (file, s)) in parsed.iter().enumerate() {
        if let Some((other, _)) = parsed[..k]
            .iter()
            .find(|(_, o)| o.scenario.name == s.scenario.name)
        {
            bail!(
                "{file}: [scenario] name {:?} is also the name of {other}: each scenario's \
                 files are named after it, give the two scenarios different names",
                s.scenario.name
            );
        }
    }
    // No output may be the plant file (under an output's name in the output directory).
    // Per scenario: its recording, firmware trace and plot.
    let files = parsed
        .iter()
        .map(|(_, s)| {
            let f = |suffix| out_file(out_dir, &s.scenario.name, suffix);
            Ok([f(".csv")?, f(".firmware.csv")?, f(".png")?])
        })
        .collect::<Result<Vec<_>>>()?;
    let flagged: Vec<(&str, &Path)> = files
        .iter()
        .flatten()
        .map(|p| ("--out-dir", p.as_path()))
        .collect();
    crate::validate::distinct_outputs(&[("--plant", plant_path)], &flagged)
        .map_err(anyhow::Error::msg)?;
    let all: Vec<PathBuf> = flagged.iter().map(|(_, p)| p.to_path_buf()).collect();
    crate::output::check_dir("--out-dir", out_dir, &all).map_err(anyhow::Error::msg)?;
    crate::io::atomic::create_dir_all(out_dir)
        .with_context(|| format!("{}: cannot create the directory", out_dir.display()))?;
    crate::io::atomic::write_manifest(out_dir, &all)?;
    let mut results = Vec::new();
    for ((file, s), [csv, trace, png]) in parsed.iter().zip(files) {
        let file = *file;
        let cfg = ArmConfig::reference(s.scenario.tick_hz as f32);
        let t0 = Instant::now();
        let r = run_arm(&arm, s, cfg).with_context(|| format!("{file}: closed-loop run failed"))?;
        let wall = t0.elapsed().as_secs_f64();
        let name = &s.scenario.name;
        let rec = r.to_recording(&arm, &plant_path.display().to_string(), file);
        rec.write(&csv)?;
        crate::io::atomic::write_bytes(&trace, r.firmware_trace_csv().as_bytes())
            .with_context(|| format!("{}: cannot write", trace.display()))?;
        plot_arm3(&png, Some(&r.setpoint_recording()), &rec)?;
        let st = r.tracking(s.expect.settle_after_s);
        results.push(ArmScenarioResult {
            name: name.clone(),
            duration_s: s.scenario.duration_s,
            settle_after_s: s.expect.settle_after_s,
            rms_error_rad: st.map(|t| t.rms_rad),
            max_abs_error_rad: st.map(|t| t.max_abs_rad),
            max_pressure_kpa: r.max_pressure_kpa(),
            expect_fails: r.check(),
            no_expectations: s.expect.is_empty(),
            first_fault: r.first_fault(),
            speed_x: s.scenario.duration_s / wall.max(1e-9),
            files: vec![csv, trace, png],
        });
    }
    Ok(ArmDemoReport {
        plant: plant_path.to_path_buf(),
        scenarios: results,
    })
}

/// Runs the arm demo's scenarios.
pub fn run_arm_demo(plant_path: &Path, out_dir: &Path) -> Result<ArmDemoReport> {
    run_arm_demo_with(plant_path, out_dir, &ARM_SCENARIOS)
}

/// The arm demo's text report.
pub fn format_arm_report(r: &ArmDemoReport, out_dir: &Path) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "plant {}: firmware (pam_firmware::arm::ArmTick: three joint ticks, config/arm3.toml, \
         gravity and inertia feed-forward) in the loop",
        r.plant.display()
    );
    let _ = writeln!(
        s,
        "\n{:<15} {:>5} {:>7} {:>23} {:>23} {:>7} {:>7} {:>6}",
        "scenario",
        "len_s",
        "after_s",
        "rms_deg j1/j2/j3",
        "max_deg j1/j2/j3",
        "p_kpa",
        "expect",
        "x_rt"
    );
    for c in &r.scenarios {
        let tri = |v: [f64; JOINTS]| {
            format!(
                "{:.3}/{:.3}/{:.3}",
                v[0].to_degrees(),
                v[1].to_degrees(),
                v[2].to_degrees()
            )
        };
        let _ = writeln!(
            s,
            "{:<15} {:>5.1} {:>7.1} {:>23} {:>23} {:>7.1} {:>7} {:>6.1}",
            c.name,
            c.duration_s,
            c.settle_after_s,
            tri(c.rms_error_rad),
            tri(c.max_abs_error_rad),
            c.max_pressure_kpa,
            if c.no_expectations {
                "none"
            } else {
                expect_column(&c.expect_fails)
            },
            c.speed_x
        );
        write_expect_fails(&mut s, &c.name, &c.expect_fails);
        if c.no_expectations {
            let _ = writeln!(
                s,
                "  {}: no expectations given (no [expect] bounds)",
                c.name
            );
        }
        if let Some((t, code, joint)) = c.first_fault {
            if c.expect_fails.is_empty() {
                let _ = writeln!(
                    s,
                    "  {}: fault code {code} latched by joint {joint} at t = {t:.3} s",
                    c.name
                );
            }
        }
    }
    let _ = writeln!(
        s,
        "\nfiles in {}: <scenario>.csv (3-joint recording, docs/arm3.md), \
         <scenario>.firmware.csv (set-points, desired torque, feed-forward, fault), <scenario>.png",
        out_dir.display()
    );
    s
}
