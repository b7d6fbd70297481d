//! `host-sim demo`: the project's main job in one command.
//!
//! Runs the reference plant (`shared/plant/reference-1dof.toml`) in closed loop with the
//! firmware's control tick on the step, sine and random scenarios of `scenarios/`, writes a
//! recording, a firmware trace and a plot per scenario, replays the conformance fixture
//! `pulses_nominal.csv` open loop and reports its per-channel fit.
//!
//! The three scenario files are compiled in (they are part of this repository); the plant and
//! the fixture are read from `shared/` at run time: `--plant` / `--fixture`, else
//! `../shared/...` relative to the working directory (a repository checkout next to
//! `shared/`), else relative to the source tree this binary was built from.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};

use crate::control::closed_loop::{run, Scenario};
use crate::control::run_files::{
    firmware_trace_path, plot_run, run_recording, write_firmware_trace,
};
use crate::io::compare::{compare, ChannelFit};
use crate::io::plot::plot_comparison;
use crate::io::recording::Recording;
use crate::plant::Plant;
use crate::sim::{simulate, SolverOptions};

pub use crate::io::scenario::SCENARIOS;

/// Inputs and output directory of a demo run.
#[derive(Debug, Clone)]
pub struct DemoOptions {
    /// Where the files go (created if missing).
    pub out_dir: PathBuf,
    /// Plant file; `None`: look for `shared/plant/reference-1dof.toml`.
    pub plant: Option<PathBuf>,
    /// Conformance fixture; `None`: `conformance/pulses_nominal.csv` next to the plant's
    /// directory.
    pub fixture: Option<PathBuf>,
}

/// One closed-loop row of the demo table.
#[derive(Debug, Clone)]
pub struct ScenarioResult {
    pub name: String,
    pub duration_s: f64,
    pub settle_after_s: f64,
    pub rms_error_rad: f64,
    pub max_abs_error_rad: f64,
    pub faults: usize,
    pub expect_fails: Vec<String>,
    /// Simulated seconds per wall second of the closed loop (plant + firmware).
    pub speed_x: f64,
    pub files: Vec<PathBuf>,
}

/// The demo's results.
#[derive(Debug, Clone)]
pub struct DemoReport {
    pub plant: PathBuf,
    /// The plant's active effects ([`Plant::effects_summary`]), honoured by every run.
    pub effects: String,
    pub scenarios: Vec<ScenarioResult>,
    pub replay: FixtureReplay,
}

/// The open-loop replay of the conformance fixture.
#[derive(Debug, Clone)]
pub struct FixtureReplay {
    pub fixture: PathBuf,
    /// Fit of each measured channel of the fixture.
    pub fits: Vec<ChannelFit>,
    /// The replay and its plot.
    pub files: Vec<PathBuf>,
    /// Simulated seconds per wall second.
    pub speed_x: f64,
}

/// Runs the demo, writing into `opts.out_dir`.
pub fn run_demo(opts: &DemoOptions) -> Result<DemoReport> {
    // Before the runs: an --out-dir that is a file is refused by name (not "File exists"
    // from the directory creation after them).
    crate::validate::output_dir("--out-dir", &opts.out_dir).map_err(anyhow::Error::msg)?;
    // Without --plant / --fixture: the repository's copies from the working directory, else
    // the ones built into host-sim (`defaults`); the fixture is first looked for beside a
    // --plant's folder (`shared/plant/X.toml` -> `shared/conformance/pulses_nominal.csv`).
    use crate::defaults::{Found, PULSES_NOMINAL, REFERENCE_PLANT};
    let given = |p: &PathBuf| Found {
        path: p.clone(),
        builtin: None,
        tried: Vec::new(),
    };
    let plant_file = opts
        .plant
        .as_ref()
        .map_or_else(|| REFERENCE_PLANT.find(), given);
    let fixture_file = opts.fixture.as_ref().map_or_else(
        || {
            let mut c = Vec::new();
            if let Some(dir) = opts.plant.as_ref().and_then(|p| p.parent()?.parent()) {
                c.push(dir.join("conformance/pulses_nominal.csv"));
            }
            c.extend(PULSES_NOMINAL.candidates());
            PULSES_NOMINAL.find_among(c)
        },
        given,
    );
    for (f, what) in [
        (&plant_file, "default plant"),
        (&fixture_file, "default fixture"),
    ] {
        if let Some(n) = f.note(what) {
            eprintln!("{n}");
        }
    }
    let (plant_path, fixture_path) = (plant_file.path.clone(), fixture_file.path.clone());
    let plant = match plant_file.builtin {
        Some(text) => Plant::from_config(&crate::PlantConfig::from_toml_str(text, &plant_path)?),
        None => Plant::load(&plant_path)?,
    };
    let parsed = SCENARIOS
        .iter()
        .map(|(file, text)| Ok((*file, Scenario::from_toml_str(text, file)?)))
        .collect::<Result<Vec<_>>>()?;
    // Every output named before any run: none may be an input (a `--plant` or `--fixture`
    // inside the output directory under an output's name would be replaced).
    let stem = crate::io::file_stem_or(&fixture_path, "fixture");
    let replay_csv = out_file(&opts.out_dir, &stem, "_replay.csv")?;
    let replay_png = out_file(&opts.out_dir, &stem, "_replay.png")?;
    // Per scenario: its firmware trace, plot and recording.
    let files = parsed
        .iter()
        .map(|(_, s)| {
            let csv = out_file(&opts.out_dir, &s.scenario.name, ".csv")?;
            let png = out_file(&opts.out_dir, &s.scenario.name, ".png")?;
            Ok([firmware_trace_path(&csv), png, csv])
        })
        .collect::<Result<Vec<_>>>()?;
    let flagged: Vec<(&str, &Path)> = files
        .iter()
        .flatten()
        .chain([&replay_csv, &replay_png])
        .map(|p| ("--out-dir", p.as_path()))
        .collect();
    crate::validate::distinct_outputs(
        &[("--plant", &plant_path), ("--fixture", &fixture_path)],
        &flagged,
    )
    .map_err(anyhow::Error::msg)?;
    let all: Vec<PathBuf> = flagged.iter().map(|(_, p)| p.to_path_buf()).collect();
    crate::output::check_dir("--out-dir", &opts.out_dir, &all).map_err(anyhow::Error::msg)?;
    crate::io::atomic::create_dir_all(&opts.out_dir)
        .with_context(|| format!("{}: cannot create the directory", opts.out_dir.display()))?;
    crate::io::atomic::write_manifest(&opts.out_dir, &all)?;

    let mut scenarios = Vec::new();
    for ((file, s), [trace, png, csv]) in parsed.iter().zip(files) {
        let t0 = Instant::now();
        let r = run(&plant, s).with_context(|| format!("{file}: closed-loop run failed"))?;
        let wall = t0.elapsed().as_secs_f64();
        let name = &s.scenario.name;
        write_firmware_trace(&r, &trace)?;
        run_recording(&r, &plant_path.display().to_string(), file, Some(&trace)).write(&csv)?;
        plot_run(&png, &r, &plant)?;
        let st = r.tracking(s.expect.settle_after_s);
        scenarios.push(ScenarioResult {
            name: name.clone(),
            duration_s: s.scenario.duration_s,
            settle_after_s: s.expect.settle_after_s,
            rms_error_rad: st.rms_rad,
            max_abs_error_rad: st.max_abs_rad,
            faults: crate::control::run_files::fault_changes(&r)
                .iter()
                .filter(|c| c.fault.is_some())
                .count(),
            expect_fails: r.check(),
            speed_x: s.scenario.duration_s / wall.max(1e-9),
            files: vec![csv, trace, png],
        });
    }

    // Open-loop replay of the conformance fixture and its fit.
    let fixture = match fixture_file.builtin {
        Some(text) => Recording::parse(text, &fixture_path)?,
        None => Recording::read(&fixture_path)?,
    };
    let dt = fixture.sample_period_s();
    let t0 = Instant::now();
    let sim = simulate(&plant, &fixture.inputs, dt, &SolverOptions::default())
        .with_context(|| format!("{}: replay failed", fixture_path.display()))?;
    let replay_wall = t0.elapsed().as_secs_f64();
    let metadata = vec![
        ("plant".into(), plant_path.display().to_string()),
        ("inputs".into(), fixture_path.display().to_string()),
        ("sample_period_s".into(), format!("{dt}")),
        (
            "source".into(),
            "host-sim demo: open-loop replay, ode_solvers Dopri5".into(),
        ),
        ("effects".into(), plant.effects_summary()),
    ];
    let out = crate::io::replay_stream::replay_recording(&plant, &fixture, &sim.states, metadata);
    out.write(&replay_csv)?;
    let fits = compare(&fixture, &out)
        .with_context(|| format!("cannot compare {} with the replay", fixture_path.display()))?;
    plot_comparison(&replay_png, Some(&fixture), &out)?;
    let duration_s = dt * fixture.len() as f64;
    Ok(DemoReport {
        effects: plant.effects_summary(),
        plant: plant_path,
        scenarios,
        replay: FixtureReplay {
            fixture: fixture_path,
            fits,
            files: vec![replay_csv, replay_png],
            speed_x: duration_s / replay_wall.max(1e-9),
        },
    })
}

/// `out_dir/<name><suffix>`, refused unless it is a plain file inside `out_dir` (a name from
/// a scenario file never writes elsewhere; the scenario parser refuses such names first).
pub(crate) fn out_file(out_dir: &Path, name: &str, suffix: &str) -> Result<PathBuf> {
    crate::validate::inside_dir(out_dir, &format!("{name}{suffix}")).map_err(anyhow::Error::msg)
}

/// The tables' `expect` column: whether a scenario met its `[expect]` bounds.
pub(crate) fn expect_column(expect_fails: &[String]) -> &'static str {
    if expect_fails.is_empty() {
        "met"
    } else {
        "FAILED"
    }
}

/// One line per failed expectation of scenario `name`, under its row of the table.
pub(crate) fn write_expect_fails(s: &mut String, name: &str, expect_fails: &[String]) {
    for f in expect_fails {
        let _ = writeln!(s, "  {name}: {f}");
    }
}

/// The demo's text report.
pub fn format_report(r: &DemoReport, out_dir: &Path) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "plant {}: firmware (pam_firmware::tick::ControlTick, reference gains) in the loop",
        r.plant.display()
    );
    let _ = writeln!(s, "plant effects: {}", r.effects);
    let _ = writeln!(
        s,
        "\n{:<8} {:>6} {:>8} {:>10} {:>10} {:>7} {:>7} {:>10}",
        "scenario", "len_s", "after_s", "rms_deg", "max_deg", "faults", "expect", "x_realtime"
    );
    for c in &r.scenarios {
        let _ = writeln!(
            s,
            "{:<8} {:>6.1} {:>8.1} {:>10.3} {:>10.3} {:>7} {:>7} {:>10.0}",
            c.name,
            c.duration_s,
            c.settle_after_s,
            c.rms_error_rad.to_degrees(),
            c.max_abs_error_rad.to_degrees(),
            c.faults,
            expect_column(&c.expect_fails),
            c.speed_x
        );
        write_expect_fails(&mut s, &c.name, &c.expect_fails);
    }
    let _ = writeln!(
        s,
        "\nconformance: open-loop replay of {} ({:.0} x real time), fit per channel (>= 99.5 % required):",
        r.replay.fixture.display(),
        r.replay.speed_x
    );
    for f in &r.replay.fits {
        let _ = writeln!(
            s,
            "  {:<10} {:>8.4} %{}",
            f.channel.name(),
            f.fit_percent,
            if f.fit_percent >= 99.5 {
                ""
            } else {
                "  BELOW 99.5 %"
            }
        );
    }
    let _ = writeln!(
        s,
        "\nfiles in {}: <scenario>.csv (RECORDING.md), <scenario>.firmware.csv (set-point, torque estimate, fault code), <scenario>.png, {}",
        out_dir.display(),
        r.replay
            .files
            .iter()
            .filter_map(|p| p.file_name())
            .map(|n| n.to_string_lossy().into_owned())
            .collect::<Vec<_>>()
            .join(", ")
    );
    s
}

impl DemoReport {
    /// True when every scenario met its expectations and every fixture channel fits >= 99.5 %.
    pub fn ok(&self) -> bool {
        self.scenarios.iter().all(|c| c.expect_fails.is_empty())
            && self.replay.fits.iter().all(|f| f.fit_percent >= 99.5)
    }
}
