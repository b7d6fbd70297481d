//! The `host-sim` command line (declared from `main.rs` only; the library never imports it):
//! its clap types, each command's argument checks and dispatch. Open-loop replay of recordings on the plant model, closed-loop
//! scenarios with the firmware in the loop (`simulate --scenario`), fit metrics, plots.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use host_sim::io::compare::{compare, format_table};
use host_sim::io::plot::plot_comparison;
use host_sim::io::recording::Channel;
use host_sim::sim::SolverOptions;
use host_sim::validate::{self, f64_in, usize_in, Range};
use host_sim::{Plant, Recording};

mod control;
mod diagnose;
mod discover;
mod identify;
mod io;

#[derive(Parser)]
#[command(
    name = "host-sim",
    version,
    about = "PAM joint plant simulator (shared/plant/PLANT.md)"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Replace existing output files that host-sim did not write, or that are read-only
    /// (without it such a file is refused before any work; docs/reliability.md).
    #[arg(long, global = true)]
    force: bool,
}

#[derive(Subcommand)]
enum Command {
    /// Replay the valve inputs of a recording on the plant (open loop), or run a closed-loop
    /// scenario with the firmware in the loop.
    ///
    /// --inputs needs the columns t_s,u_in1,u_ex1,u_in2,u_ex2 and at least one measured
    /// channel of angle_deg,p1_kpa,p2_kpa,f1_n,f2_n (RECORDING.md); the measured channels
    /// are drawn under the simulated ones.
    Simulate(SimulateArgs),
    /// Per-channel fit (NRMSE %), MAE and MSE of B (model) against A (reference/measured).
    ///
    /// Both recordings need t_s (same length) and share at least one of angle_deg, p1_kpa,
    /// p2_kpa, f1_n, f2_n; the fit is 100 (1 - ||b - a|| / ||a - mean(a)||) % (normalised RMS error), 100 = perfect.
    Fit(FitArgs),
    /// The main job: the reference plant with the firmware in the loop on the step, sine and
    /// random scenarios (CSV + plots), and the conformance fit of an open-loop replay.
    ///
    /// The fixture needs t_s, u_in1, u_ex1, u_in2, u_ex2 and at least one measured channel
    /// (angle_deg, p1_kpa, p2_kpa, f1_n, f2_n; RECORDING.md); each one present is fitted.
    ///
    /// Exit status: 0 when every scenario meets its [expect] and every fixture channel
    /// fits at least 99.5 %; 1 when one does not (the report says which); 2 when an argument
    /// or an input file is refused (nothing is written then).
    Demo(DemoArgs),
    /// Generate identification data from a plant file (force: isometric bench sweep; torque:
    /// constant-speed passes at fixed activations, the torque-model paper's protocol).
    Sweep(identify::SweepArgs),
    /// Identify the force law, the torque model or plant parameters from data.
    Identify(identify::IdentifyArgs),
    /// Tune the cascade, PD and PID gains on the set-point suite (firmware in the loop) and
    /// write the gains file (the format of config/control_tuned.toml).
    Tune(control::TuneArgs),
    /// From a recording to the firmware's constants (config/): refuse degenerate data,
    /// identify the torque model, take the plant-derived constants from the plant file, (with
    /// --tune) tune the gains, and replace the files in --out-dir, printing old -> new per key.
    /// All files or none are written; exit status 2 and nothing written on refused data.
    Calibrate(identify::CalibrateArgs),
    /// Diagnosis: locate where a recording departs from the nominal model, tell a mis-set
    /// parameter (recalibration) from left-out physics (a named effect), model it and report
    /// the fit before/after. Exit status 0: explained or nothing missing; 4: partly explained
    /// (named items hold, but something else is missing too); 3: unexplained or not this
    /// plant (nothing named, the JSON is written); 2: bad input.
    ///
    /// The recording needs t_s,u_in1,u_ex1,u_in2,u_ex2 and the measured angle_deg,p1_kpa,
    /// p2_kpa (f1_n,f2_n used when present), as in RECORDING.md; with an arm plant, the same
    /// columns per joint with a _j1, _j2, _j3 suffix.
    Diagnose(DiagnoseArgs),
    /// Diagnose every recording (*.csv) of a directory against one plant, in parallel: one
    /// JSON per recording and a summary table (summary.csv). Exit status: the worst over the
    /// recordings: 1 if one could not be diagnosed (its error is in the summary), else 3 if one
    /// is unexplained or not this plant (as `diagnose` exits 3), else 4 if one is partly
    /// explained, else 0; 2: bad input.
    ///
    /// Each recording needs t_s,u_in1,u_ex1,u_in2,u_ex2 and the measured angle_deg,p1_kpa,
    /// p2_kpa (f1_n,f2_n used when present), as in RECORDING.md.
    DiagnoseBatch(diagnose::BatchArgs),
    /// Discovery: find the missing term in closed form when the catalogue does not explain a
    /// recording: a sparse regression of each slot's equation residual (joint, transmission,
    /// chambers, sensors) on a library of physical terms, refined by output error, kept only
    /// if it improves the tail of --recording and --check. Exit status 0: a term discovered;
    /// 3: nothing discovered (the JSON is written); 2: bad input.
    Discover(discover::DiscoverArgs),
    /// Import a rig logger's CSV (other column names, units, time base) into a recording,
    /// through a mapping file (docs/rig.md).
    ///
    /// Writes a recording (RECORDING.md) with t_s,u_in1,u_ex1,u_in2,u_ex2 and the mapped
    /// outputs among angle_deg,p1_kpa,p2_kpa,f1_n,f2_n; the report gives each channel's range
    /// and warns of values a unit mistake usually causes.
    Import(io::ImportArgs),
    /// Turn the firmware's per-tick stream (QEMU image or board) into a recording.
    ///
    /// Writes a recording (RECORDING.md) with t_s,u_in1,u_ex1,u_in2,u_ex2 (the valve
    /// openings the firmware commanded) and angle_deg,p1_kpa,p2_kpa (what it measured).
    Capture(io::CaptureArgs),
    /// Processor in the loop: the firmware image under qemu-system-arm closes the loop with the
    /// plant, one exchanged sensor frame (board counts) and valve command per tick; writes the
    /// recording, checks the scenario's [expect] on it and compares it bit for bit with the
    /// in-process loop (exit status 1 on a mismatch, named by its first tick and field, or an
    /// unmet [expect]).
    Pil(control::PilArgs),
    /// The pressure loop with and without the firmware's inverse thermodynamic feed-forward
    /// (the pressure command from the chamber's gas law, eq. 7 of the
    /// learned-inverse-thermodynamics paper), firmware in the loop: position MSE and pressure tracking error on the
    /// controller suite and held-out set-points, on the plant and on it with a thermodynamic
    /// chamber, a leak and a supply drop. Exit status 1 when the feed-forward does not improve
    /// the nominal plant's suite position MSE by >= 1.85x, the P-only cascade at --gains
    /// against the feed-forward cascade at --ff-gains (each tuned for itself).
    CompareControl(control::CompareControlArgs),
}

#[derive(Args)]
#[command(
    after_help = "Examples:\n  host-sim diagnose --plant host-sim/plants/reference-1dof.toml --recording host-sim/tests/fixtures/pulses_thermal.csv --json diagnosis.json --report report/\n  host-sim diagnose --plant host-sim/plants/arm3-seed001.toml --recording target/demo/arm_sine.csv --json arm.json"
)]
struct DiagnoseArgs {
    /// Nominal plant file (TOML) the user believes in. A 3-DOF arm file (`kind = "arm3"`)
    /// diagnoses each joint of a 3-joint recording (`_j1`.. `_j3` columns, every angle
    /// recorded): which joint departs and what.
    #[arg(long, value_name = "P.toml")]
    plant: PathBuf,
    /// Training recording of the real rig (RECORDING.md).
    #[arg(long, value_name = "TRAIN.csv")]
    recording: PathBuf,
    /// Optional check recording (other excitation, not --recording itself), used only to
    /// validate: an answer that makes its fit worse on a channel (by more than 2 points) is
    /// not named (unexplained, exit status 3).
    #[arg(long, value_name = "CHECK.csv")]
    check: Option<PathBuf>,
    /// Output JSON (written atomically).
    #[arg(long, value_name = "OUT.json")]
    json: PathBuf,
    /// Also write an HTML report with plots (DIR/index.html, DIR/diagnosis.json).
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
    /// Worker threads for the candidate refits.
    #[arg(long, default_value_t = 2, value_parser = usize_in(1, 256))]
    threads: usize,
    /// Run even when the estimated memory or time exceeds the limit (docs/reliability.md);
    /// the estimate is printed on stderr when the run is long.
    #[arg(long)]
    allow_large: bool,
    /// The valve columns were logged this late against the sensor columns [ms]: move them
    /// earlier by it (-1000..=1000; negative: logged early) in --recording and --check
    /// before diagnosing. The diagnosis names such an offset when it finds one.
    #[arg(long, value_name = "MS", allow_negative_numbers = true)]
    shift_valves_ms: Option<f64>,
    /// Write the plant file with the discovered term as its [effects.discovered] table, when
    /// the answer is unexplained and the discovery finds a term (1-DOF plants): the next
    /// diagnosis of the rig starts from it.
    #[arg(long, value_name = "OUT.toml")]
    write_plant: Option<PathBuf>,
}

#[derive(Args)]
#[command(after_help = "Example:\n  host-sim demo --out-dir target/demo")]
struct DemoArgs {
    /// Output directory (created if missing).
    #[arg(long, value_name = "DIR", default_value = "target/demo")]
    out_dir: PathBuf,
    /// Plant file [default: host-sim/plants/reference-1dof.toml or plants/reference-1dof.toml
    /// from the working directory, else the copy built into host-sim]; a 3-DOF arm file
    /// (`kind = "arm3"`) runs the arm tick on the arm scenarios (scenarios/arm3/).
    #[arg(long, value_name = "P.toml")]
    plant: Option<PathBuf>,
    /// Conformance fixture replayed open loop [default: conformance/pulses_nominal.csv beside
    /// the --plant file's folder, else host-sim/tests/fixtures/pulses_nominal.csv (or
    /// tests/fixtures/...) from the working directory, else the copy built into host-sim].
    #[arg(long, value_name = "REC.csv")]
    fixture: Option<PathBuf>,
    /// Arm plants only: run these arm scenario files (scenarios/arm3/ format) instead of the
    /// built-in ones (repeatable).
    #[arg(long, value_name = "S.toml")]
    scenario: Vec<PathBuf>,
}

#[derive(Args)]
#[command(
    after_help = "Examples:\n  host-sim simulate --plant host-sim/plants/reference-1dof.toml --inputs host-sim/tests/fixtures/pulses_nominal.csv --out sim.csv --plot sim.png\n  host-sim simulate --plant host-sim/plants/reference-1dof.toml --scenario scenarios/step.toml --out step.csv"
)]
// Exactly one of --inputs (open loop) and --scenario (closed loop): a missing one names both.
#[command(group(clap::ArgGroup::new("run").required(true).args(["inputs", "scenario"])))]
struct SimulateArgs {
    /// Plant parameter file (TOML, e.g. host-sim/plants/reference-1dof.toml).
    #[arg(long, value_name = "P.toml")]
    plant: PathBuf,
    /// Recording whose t_s and valve columns are replayed (RECORDING.md).
    #[arg(long, value_name = "REC.csv")]
    inputs: Option<PathBuf>,
    /// Closed-loop scenario (firmware in the loop): OUT.csv is a RECORDING.md recording, the
    /// firmware's set-point, torque estimate and fault code go to OUT.firmware.csv; the
    /// tracking summary goes to stdout; exit status 1 if the scenario's [expect] is not met.
    #[arg(long, value_name = "S.toml")]
    scenario: Option<PathBuf>,
    /// Output recording: the input t_s and valve columns plus the simulated channels.
    #[arg(long, value_name = "OUT.csv")]
    out: PathBuf,
    /// Also draw the simulated channels (over the measured ones of --inputs) to .png or .svg.
    #[arg(long, value_name = "out.png|svg", value_parser = validate::plot_path)]
    plot: Option<PathBuf>,
    /// Relative tolerance of the integrator of an --inputs replay (a closed-loop --scenario
    /// integrates each tick's step with its own fixed tolerances).
    #[arg(long, default_value_t = SolverOptions::default().rtol, value_parser = f64_in(Range::closed(1e-14, 0.1)), conflicts_with = "scenario")]
    rtol: f64,
    /// Absolute tolerance of the integrator of an --inputs replay.
    #[arg(long, default_value_t = SolverOptions::default().atol, value_parser = f64_in(Range::closed(1e-14, 1e3)), conflicts_with = "scenario")]
    atol: f64,
    /// Run even when the estimated memory or time of a closed-loop scenario exceeds the limit
    /// (docs/reliability.md).
    #[arg(long)]
    allow_large: bool,
    /// Where an --inputs replay starts: `auto` = from the recording's first sample when it
    /// sits away from the plant file's [initial] (20 kPa or 3 deg; a segment cut from a run,
    /// a rig that rests elsewhere), else from [initial]; `recording` = always from the first
    /// sample (angle, pressures as the sensors read them, velocity from the angle's first
    /// 20 ms); `file` = always from [initial].
    #[arg(long, value_enum, default_value_t = StartFrom::Auto, requires = "inputs", conflicts_with = "scenario")]
    start: StartFrom,
}

/// Where an open-loop replay starts (`simulate --start`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum StartFrom {
    Auto,
    Recording,
    File,
}

#[derive(Args)]
#[command(
    after_help = "Example:\n  host-sim fit host-sim/tests/fixtures/pulses_nominal.csv sim.csv --min-fit 99.5 --plot fit.png"
)]
struct FitArgs {
    /// Reference (measured) recording.
    a: PathBuf,
    /// Model (simulated) recording.
    b: PathBuf,
    /// Draw B over A for every channel to .png or .svg.
    #[arg(long, value_name = "out.png|svg", value_parser = validate::plot_path)]
    plot: Option<PathBuf>,
    /// Exit with status 1 if any channel fits below this many percent (at most 100; 0 < x <= 1
    /// is refused: a fraction typed for a percentage).
    #[arg(long, value_name = "PERCENT", value_parser = min_fit_percent)]
    min_fit: Option<f64>,
}

/// `cmd` and its subcommands with negative numbers taken as values (`--offset -5`): a value
/// out of range is then refused by the argument's range check, which names the range.
fn with_negative_numbers(cmd: clap::Command) -> clap::Command {
    cmd.allow_negative_numbers(true)
        .mut_subcommands(with_negative_numbers)
}

/// `fit --min-fit`: a percentage up to 100; a value in (0, 1] is a fraction typed for one
/// (0.995 for 99.5 %), refused with the percentage it likely meant.
fn min_fit_percent(s: &str) -> Result<f64, String> {
    let v = f64_in(Range::closed(-1e6, 100.0))(s)?;
    if v > 0.0 && v <= 1.0 {
        return Err(format!(
            "{v} looks like a fraction; the threshold is in percent (give {} for {} %)",
            v * 100.0,
            v * 100.0
        ));
    }
    Ok(v)
}

/// `--opt -1e-6`, `--opt -.5` and `--opts -1,1` passed as `--opt=-1e-6`, `--opt=-.5`,
/// `--opts=-1,1`: clap takes `-1` and `-0.5` after an option as values, but not a negative
/// number with an exponent or without a leading digit, nor a comma-separated list that starts
/// with a negative number (they would be read as short flags). The option's range check then
/// refuses a negative value where none is allowed.
fn join_negative_values(args: impl Iterator<Item = std::ffi::OsString>) -> Vec<std::ffi::OsString> {
    let mut out: Vec<std::ffi::OsString> = Vec::new();
    for a in args {
        let joined = match (out.last().and_then(|o| o.to_str()), a.to_str()) {
            (Some(opt), Some(v))
                if opt.starts_with("--")
                    && opt.len() > 2
                    && !opt.contains('=')
                    && v.starts_with('-')
                    && v.split(',').all(|x| x.trim().parse::<f64>().is_ok()) =>
            {
                Some(format!("{opt}={v}"))
            }
            _ => None,
        };
        match joined {
            Some(j) => *out.last_mut().unwrap() = j.into(),
            None => out.push(a),
        }
    }
    out
}

pub fn main() -> ExitCode {
    let cli = {
        use clap::{CommandFactory as _, FromArgMatches as _};
        let matches = with_negative_numbers(Cli::command())
            .get_matches_from(join_negative_values(std::env::args_os()));
        Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit())
    };
    host_sim::output::set_force(cli.force);
    host_sim::io::atomic::install_interrupt_cleanup();
    if let Err(e) = refuse_arm_files(&cli.command) {
        eprintln!("error: {e}");
        return ExitCode::from(2);
    }
    // Every output of the command is staged and renamed into place only if it succeeds: a
    // failed run leaves the user's files as they were and nothing behind.
    let outputs = host_sim::io::atomic::Transaction::begin();
    let result = match cli.command {
        Command::Simulate(a) => run_simulate(&a),
        Command::Fit(a) => run_fit(&a),
        Command::Demo(a) => run_demo(&a),
        Command::Diagnose(a) => run_diagnose(&a),
        Command::Discover(a) => discover::run(&a),
        Command::DiagnoseBatch(a) => {
            host_sim::diagnose::batch::run_batch(&a.into()).map(|(report, code)| {
                print!("{report}");
                ExitCode::from(code)
            })
        }
        Command::Sweep(a) => run_report(host_sim::identify::cli::run_sweep(&a.into())),
        Command::Identify(a) => run_report(host_sim::identify::cli::run_identify(&a.into())),
        Command::Tune(a) => run_report(host_sim::control::tune::run_tune(&a.into())),
        Command::Import(a) => run_report(host_sim::io::import::run_import(&a.into())),
        Command::Capture(a) => run_report(host_sim::io::capture::run_capture(&a.into())),
        Command::Calibrate(a) => run_report(host_sim::control::calibrate::run_calibrate(&a.into())),
        Command::CompareControl(a) => run_verdict(
            host_sim::control::compare_ff::run_compare_control(&a.into()),
        ),
        Command::Pil(a) => run_verdict(host_sim::control::pil::run_pil(&a.into())),
    };
    match result.and_then(|code| {
        outputs.commit().context("cannot write the outputs")?;
        Ok(code)
    }) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {}", error_text(&e));
            ExitCode::from(2)
        }
    }
}

/// Refuses a 3-DOF arm plant file or arm recording given to a 1-DOF-only command, naming
/// the file, what it is and the commands that take it (the 1-DOF parsers would report an
/// unknown key or a missing column instead).
fn refuse_arm_files(c: &Command) -> Result<(), String> {
    use identify::{IdentifyWhat, SweepWhat};
    let (name, plants, recordings): (&str, Vec<&Path>, Vec<&Path>) = match c {
        Command::Tune(a) => ("tune", vec![&a.plant], vec![]),
        Command::Pil(a) => ("pil", vec![&a.plant], vec![]),
        Command::DiagnoseBatch(a) => ("diagnose-batch", vec![&a.plant], vec![]),
        Command::Discover(a) => ("discover", vec![&a.plant], vec![&a.recording]),
        Command::CompareControl(a) => ("compare-control", vec![&a.plant], vec![]),
        Command::Fit(a) => ("fit", vec![], vec![&a.a, &a.b]),
        Command::Calibrate(a) => {
            let mut r = vec![a.recording.as_path()];
            r.extend(a.plant_recording.as_deref());
            ("calibrate", vec![&a.plant], r)
        }
        Command::Sweep(a) => match &a.what {
            SweepWhat::Force(w) => ("sweep force", vec![&w.plant], vec![]),
            SweepWhat::Torque(w) => ("sweep torque", vec![&w.plant], vec![]),
            SweepWhat::ForceMap(_) => return Ok(()),
        },
        Command::Identify(a) => match &a.what {
            IdentifyWhat::Plant(w) => ("identify plant", vec![&w.plant], vec![&w.recording]),
            IdentifyWhat::Torque(w) => ("identify torque", vec![&w.plant], vec![&w.recording]),
            IdentifyWhat::Volume(w) => ("identify volume", vec![], vec![&w.recording]),
            IdentifyWhat::Force(_) => return Ok(()),
        },
        _ => return Ok(()),
    };
    let arm_use = "for the arm use demo / simulate / diagnose";
    for p in plants {
        if let Some(kind) = host_sim::plant::arm3::file_kind(p) {
            return Err(format!(
                "{} is a 3-DOF arm plant file (kind = {kind:?}); {name} is 1-DOF only: {arm_use}",
                p.display()
            ));
        }
    }
    for r in recordings {
        if host_sim::io::arm3::is_arm3_recording(r) {
            return Err(format!(
                "{} is a 3-DOF arm recording (columns with a _j1.._j3 suffix); {name} is 1-DOF \
                 only: {arm_use}",
                r.display()
            ));
        }
    }
    Ok(())
}

/// An error with its causes, `: `-separated, each cause left out when the text before it
/// already says it (file errors quote their I/O cause in their own message).
fn error_text(e: &anyhow::Error) -> String {
    let mut text = e.to_string();
    for cause in e.chain().skip(1) {
        let c = cause.to_string();
        if !text.contains(&c) {
            text.push_str(": ");
            text.push_str(&c);
        }
    }
    text
}

/// Prints the report of a sweep / identify command.
fn run_report(report: Result<String>) -> Result<ExitCode> {
    print!("{}", report?);
    Ok(ExitCode::SUCCESS)
}

/// Prints the report of a command that passes or fails a check (the batch's runs, the
/// feed-forward's gain, PIL's bit-for-bit match): exit status 0 if it passed, 1 if not.
fn run_verdict(result: Result<(String, bool)>) -> Result<ExitCode> {
    let (report, passed) = result?;
    print!("{report}");
    Ok(if passed {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}

fn run_simulate(a: &SimulateArgs) -> Result<ExitCode> {
    let plant_path = &a.plant;
    let mut inputs: Vec<(&str, &Path)> = vec![("--plant", plant_path.as_path())];
    if let Some(i) = &a.inputs {
        inputs.push(("--inputs", i));
    }
    if let Some(s) = &a.scenario {
        inputs.push(("--scenario", s));
    }
    let mut outputs: Vec<(&str, &Path)> = vec![("--out", a.out.as_path())];
    let trace = host_sim::control::run_files::firmware_trace_path(&a.out);
    if a.scenario.is_some() {
        outputs.push(("the firmware trace", &trace));
    }
    if let Some(p) = &a.plot {
        outputs.push(("--plot", p));
    }
    validate::distinct_file_outputs(&inputs, &outputs).map_err(anyhow::Error::msg)?;
    validate::replaceable("--out", &a.out, validate::OutputKind::RECORDING)
        .map_err(anyhow::Error::msg)?;
    if let Some(s) = &a.scenario {
        let sc = host_sim::io::scenario::Scenario::load(s)?;
        sc.run_estimate()
            .check(a.allow_large)
            .map_err(|e| anyhow::anyhow!("{}: {e}", s.display()))?;
    }
    if let Some(s) = &a.scenario {
        if host_sim::plant::arm3::is_arm3_file(plant_path)? {
            bail!(
                "{}: a 3-DOF arm plant (kind = \"arm3\"); --scenario runs the 1-DOF plant with \
                 the firmware, use --inputs with a 3-joint recording",
                plant_path.display()
            );
        }
        return run_closed_loop(a, s);
    }
    let inputs_path = a.inputs.as_ref().expect("clap: --inputs required");
    if host_sim::plant::arm3::is_arm3_file(plant_path)? {
        return run_simulate_arm3(a, inputs_path);
    }
    let plant = replay_start(a, plant_path, inputs_path)?;
    let opts = a.solver_options()?;
    if a.plot.is_none() {
        if let Some(done) = simulate_streaming(a, &plant, inputs_path, &opts)? {
            warn_other_plant(&done.metadata, plant_path, inputs_path);
            warn_unused_valve_columns(&done.metadata, inputs_path);
            println!("plant effects: {}", plant.effects_summary());
            eprint_written(&a.out, done.samples, &done.stats);
            return Ok(ExitCode::SUCCESS);
        }
    }
    let rec = Recording::read(inputs_path)?;
    warn_other_plant(&rec.metadata, plant_path, inputs_path);
    warn_unused_valve_columns(&rec.metadata, inputs_path);
    let dt = rec.sample_period_s();
    let bar = stderr_bar(
        Some(rec.len()),
        "{spinner} simulate [{bar:40}] {pos}/{len} samples {elapsed}",
    );
    let sim = host_sim::io::replay_stream::simulate_recording(&plant, &rec, &opts, |k| {
        bar.set_position(k as u64)
    })
    .with_context(|| format!("{}: simulation failed", inputs_path.display()))?;
    bar.finish_and_clear();

    let mut metadata = simulate_metadata(plant_path, inputs_path, dt, &opts, "simulate");
    metadata.push(("effects".into(), plant.effects_summary()));
    let out = host_sim::io::replay_stream::replay_recording(&plant, &rec, &sim.states, metadata);
    out.write(&a.out)?;
    println!("plant effects: {}", plant.effects_summary());
    eprint_written(&a.out, out.len(), &sim.stats);
    if let Some(p) = &a.plot {
        plot_comparison(p, Some(&rec), &out)?;
    }
    Ok(ExitCode::SUCCESS)
}

/// `simulate --inputs` through the streaming pipeline (`io::replay_stream`): read,
/// simulate and write overlap, memory stays bounded. `None` when the stream leaves the run to
/// the whole-recording path (a jittered recording, or any error, which that path reports).
fn simulate_streaming(
    a: &SimulateArgs,
    plant: &Plant,
    inputs_path: &Path,
    opts: &SolverOptions,
) -> Result<Option<host_sim::io::replay_stream::StreamedReplay>> {
    let bar = stderr_bar(None, "{spinner} simulate {pos} samples {elapsed}");
    let mut done = None;
    let written = host_sim::io::atomic::write_with(&a.out, |w| {
        let metadata = |dt_s: f64| {
            let mut m = simulate_metadata(&a.plant, inputs_path, dt_s, opts, "simulate");
            m.push(("effects".into(), plant.effects_summary()));
            m
        };
        done = host_sim::io::replay_stream::replay_file(
            plant,
            inputs_path,
            opts,
            metadata,
            w,
            &|k| bar.set_position(k as u64),
        )?;
        match done {
            Some(_) => Ok(()),
            None => Err(std::io::Error::other("left to the whole-recording path")),
        }
    });
    bar.finish_and_clear();
    match (written, done) {
        (Ok(()), done) => Ok(done),
        (Err(_), None) => Ok(None),
        (Err(e), Some(_)) => Err(anyhow::anyhow!("{}: {e}", a.out.display())),
    }
}

/// The plant of an `--inputs` replay, started as `--start` says (a note on stderr when it
/// starts from the recording). The recording's start is read from its head (the first 64
/// KiB), so that a long recording still streams; a head that does not parse leaves the
/// file's start (the full read then names the error).
fn replay_start(a: &SimulateArgs, plant_path: &Path, inputs_path: &Path) -> Result<Plant> {
    let cfg = host_sim::PlantConfig::load(plant_path)?;
    if a.start == StartFrom::File {
        return Ok(Plant::from_config(&cfg));
    }
    let head = {
        use std::io::Read as _;
        let mut buf = Vec::new();
        std::fs::File::open(inputs_path)
            .and_then(|f| f.take(64 * 1024).read_to_end(&mut buf))
            .with_context(|| inputs_path.display().to_string())?;
        let text = String::from_utf8_lossy(&buf);
        // Whole lines only (the head may end inside one).
        let end = if buf.len() < 64 * 1024 {
            text.len()
        } else {
            text.rfind('\n').map_or(0, |i| i + 1)
        };
        Recording::parse(&text[..end], inputs_path).ok()
    };
    let Some(head) = head.filter(|h| h.len() >= 2) else {
        return Ok(Plant::from_config(&cfg));
    };
    let away = host_sim::diagnose::verdict::channels_away_from_initial(&cfg, &head);
    if a.start == StartFrom::Auto && away.is_empty() {
        return Ok(Plant::from_config(&cfg));
    }
    let started = host_sim::diagnose::start::as_recorded(&cfg, &head);
    eprintln!(
        "note: {} replayed from its first sample (angle {:.3} deg, p1 {}, p2 {}, velocity \
         {:.4} rad/s from its first 20 ms){}; --start file replays from [initial]",
        inputs_path.display(),
        started.initial.angle_rad.to_degrees(),
        fmt_kpa(head.channel(host_sim::Channel::P1Kpa)),
        fmt_kpa(head.channel(host_sim::Channel::P2Kpa)),
        started.initial.velocity_rad_s,
        if away.is_empty() {
            String::new()
        } else {
            format!(
                ": it does not start at the plant file's [initial] ({})",
                away.join(", ")
            )
        }
    );
    Ok(Plant::from_config(&started))
}

/// A recording's first pressure sample as text (`not recorded: [initial]'s` when absent).
fn fmt_kpa(ch: Option<&[f64]>) -> String {
    ch.map_or_else(
        || "not recorded ([initial]'s)".to_string(),
        |y| format!("{:.1} kPa", y[0]),
    )
}

/// A progress bar on stderr of `len` steps (`None`: unknown) drawn by `template`.
fn stderr_bar(len: Option<usize>, template: &str) -> ProgressBar {
    let bar = ProgressBar::with_draw_target(len.map(|n| n as u64), ProgressDrawTarget::stderr());
    bar.set_style(
        ProgressStyle::with_template(template)
            .expect("static template")
            .progress_chars("=> "),
    );
    bar
}

/// The line `simulate` prints on stderr for the recording it wrote to `out`.
fn eprint_written(out: &Path, samples: usize, stats: &impl std::fmt::Display) {
    eprintln!("{}: {samples} samples, {stats}", out.display());
}

/// Warns when the recording's `plant` metadata names another plant file than `plant_path`.
fn warn_other_plant(metadata: &[(String, String)], plant_path: &Path, inputs_path: &Path) {
    if let Some(w) = host_sim::io::recording::other_plant_warning(
        metadata,
        plant_path,
        inputs_path,
        "simulating",
    ) {
        eprintln!("{w}");
    }
}

/// Warns when the recording's metadata marks its valve columns unused (they are replayed).
fn warn_unused_valve_columns(metadata: &[(String, String)], inputs_path: &Path) {
    if let Some(w) = host_sim::io::recording::unused_valve_columns_warning(metadata, inputs_path) {
        eprintln!("{w}");
    }
}

impl SimulateArgs {
    /// The solver tolerances of `--rtol` / `--atol`, both > 0.
    fn solver_options(&self) -> Result<SolverOptions> {
        let opts = SolverOptions {
            rtol: self.rtol,
            atol: self.atol,
            ..SolverOptions::default()
        };
        if !(opts.rtol > 0.0 && opts.atol > 0.0) {
            bail!("--rtol and --atol must be > 0");
        }
        Ok(opts)
    }
}

/// Metadata of a recording written by `simulate`: plant, inputs, sample period and source.
fn simulate_metadata(
    plant: &Path,
    inputs: &Path,
    dt_s: f64,
    opts: &SolverOptions,
    what: &str,
) -> Vec<(String, String)> {
    vec![
        ("plant".into(), plant.display().to_string()),
        ("inputs".into(), inputs.display().to_string()),
        ("sample_period_s".into(), format!("{dt_s}")),
        (
            "source".into(),
            format!(
                "host-sim {} {what}, ode_solvers Dopri5 rtol={} atol={}",
                env!("CARGO_PKG_VERSION"),
                opts.rtol,
                opts.atol
            ),
        ),
    ]
}

/// `simulate` on a 3-DOF arm plant file (`kind = "arm3"`): replays a 3-joint recording
/// (columns with `_j1`..`_j3` suffixes, `host_sim::io::arm3`).
fn run_simulate_arm3(a: &SimulateArgs, inputs_path: &Path) -> Result<ExitCode> {
    use host_sim::io::arm3::{fits, plot_arm3, Arm3Recording};
    use host_sim::plant::arm3::Arm3;
    use host_sim::sim::arm3::simulate_arm3;
    let arm = Arm3::load(&a.plant)?;
    let rec = Arm3Recording::read(inputs_path)?;
    let opts = a.solver_options()?;
    let dt = rec.sample_period_s();
    let bar = stderr_bar(
        Some(rec.len()),
        "{spinner} simulate arm3 [{bar:40}] {pos}/{len} samples {elapsed}",
    );
    let sim = simulate_arm3(&arm, &rec.inputs, dt, &opts, |k| bar.set_position(k as u64))
        .with_context(|| format!("{}: simulation failed", inputs_path.display()))?;
    bar.finish_and_clear();
    let mut out = Arm3Recording {
        metadata: simulate_metadata(&a.plant, inputs_path, dt, &opts, "simulate (arm3)"),
        t_s: rec.t_s.clone(),
        inputs: rec.inputs.clone(),
        ..Default::default()
    };
    out.set_outputs_from_states(&arm, &sim.states, dt);
    out.write(&a.out)?;
    eprint_written(&a.out, out.len(), &sim.stats);
    for (name, fit) in fits(&rec, &out) {
        println!("{name:<14} fit {fit:9.4} %");
    }
    if let Some(p) = &a.plot {
        plot_arm3(p, Some(&rec), &out)?;
    }
    Ok(ExitCode::SUCCESS)
}

/// `simulate --scenario`: the closed loop with the firmware on the 1-DOF plant.
fn run_closed_loop(a: &SimulateArgs, scenario: &Path) -> Result<ExitCode> {
    let bar = ProgressBar::with_draw_target(Some(1000), ProgressDrawTarget::stderr());
    let plot = a.plot.as_deref();
    let r = host_sim::control::run_files::simulate_scenario(
        &a.plant,
        scenario,
        &a.out,
        plot,
        &mut |f| bar.set_position((f * 1000.0) as u64),
    )?;
    bar.finish_and_clear();
    print!("{}", r.summary);
    println!("wrote {} and {}", a.out.display(), r.trace_path.display());
    Ok(if r.fails.is_empty() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}

fn run_demo(a: &DemoArgs) -> Result<ExitCode> {
    let t0 = std::time::Instant::now();
    // A 3-DOF arm plant file: the arm tick on the arm scenarios (no 1-DOF fixture replay).
    let arm_plant = match &a.plant {
        Some(p) => host_sim::plant::arm3::is_arm3_file(p)?,
        None => false,
    };
    if !arm_plant && !a.scenario.is_empty() {
        eprintln!("error: --scenario: arm plants only (a plant file with kind = \"arm3\")");
        return Ok(ExitCode::from(2));
    }
    if let Some(p) = &a.plant {
        if host_sim::plant::arm3::is_arm3_file(p)? {
            if a.fixture.is_some() {
                eprintln!(
                    "error: --fixture: the conformance fixture is a 1-DOF recording; an arm \
                     plant ({}) runs the arm scenarios only",
                    p.display()
                );
                return Ok(ExitCode::from(2));
            }
            let texts = a
                .scenario
                .iter()
                .map(|f| {
                    std::fs::read_to_string(f)
                        .map(|t| (f.display().to_string(), t))
                        .map_err(|e| (f.clone(), e))
                })
                .collect::<Result<Vec<_>, _>>();
            let texts = match texts {
                Ok(t) => t,
                Err((f, e)) => {
                    eprintln!("error: --scenario {}: cannot read: {e}", f.display());
                    return Ok(ExitCode::from(2));
                }
            };
            // Every file parses before anything runs or is written.
            for (f, t) in &texts {
                if let Err(e) = host_sim::control::arm3_loop::ArmScenario::from_toml_str(t, f) {
                    eprintln!("error: {e}");
                    return Ok(ExitCode::from(2));
                }
            }
            let r = if texts.is_empty() {
                host_sim::demo_arm3::run_arm_demo(p, &a.out_dir)?
            } else {
                let refs: Vec<(&str, &str)> = texts
                    .iter()
                    .map(|(f, t)| (f.as_str(), t.as_str()))
                    .collect();
                host_sim::demo_arm3::run_arm_demo_with(p, &a.out_dir, &refs)?
            };
            print!("{}", host_sim::demo_arm3::format_arm_report(&r, &a.out_dir));
            println!("done in {:.2} s", t0.elapsed().as_secs_f64());
            return Ok(if r.ok() {
                ExitCode::SUCCESS
            } else {
                ExitCode::from(1)
            });
        }
    }
    let opts = host_sim::demo::DemoOptions {
        out_dir: a.out_dir.clone(),
        plant: a.plant.clone(),
        fixture: a.fixture.clone(),
    };
    let r = host_sim::demo::run_demo(&opts)?;
    print!("{}", host_sim::demo::format_report(&r, &a.out_dir));
    println!("done in {:.2} s", t0.elapsed().as_secs_f64());
    Ok(if r.ok() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}

/// The output channels a recording's header names (its `#` metadata lines skipped; the
/// file has been read or streamed successfully before).
fn header_channels(path: &Path) -> Result<Vec<Channel>> {
    use std::io::BufRead as _;
    let f = std::fs::File::open(path).with_context(|| format!("{}", path.display()))?;
    for line in std::io::BufReader::new(f).lines() {
        let line = line.with_context(|| format!("{}", path.display()))?;
        let line = line.trim_start_matches('\u{feff}');
        if line.starts_with('#') || line.trim().is_empty() {
            continue;
        }
        let names: Vec<&str> = line.split(',').map(str::trim).collect();
        return Ok(Channel::ALL
            .into_iter()
            .filter(|c| names.contains(&c.name()))
            .collect());
    }
    Ok(Vec::new())
}

fn run_fit(a: &FitArgs) -> Result<ExitCode> {
    if let Some(p) = &a.plot {
        validate::distinct_file_outputs(&[("A", &a.a), ("B", &a.b)], &[("--plot", p)])
            .map_err(anyhow::Error::msg)?;
    }
    // Without a plot the files are compared streaming (memory: their time columns); the
    // whole recordings are read for a plot, or to report an error.
    let streamed = match a.plot {
        None => host_sim::io::compare::compare_files(&a.a, &a.b),
        Some(_) => None,
    };
    let fits = match streamed {
        Some(fits) => fits,
        None => {
            let ra = Recording::read(&a.a)?;
            let rb = Recording::read(&a.b)?;
            let fits = compare(&ra, &rb).with_context(|| {
                format!("cannot compare {} with {}", a.a.display(), a.b.display())
            })?;
            if let Some(p) = &a.plot {
                plot_comparison(p, Some(&ra), &only_common(&rb, &ra))?;
            }
            fits
        }
    };
    println!("reference: {}\nmodel:     {}", a.a.display(), a.b.display());
    print!("{}", format_table(&fits));
    // A reference channel the model lacks is not compared: say so, and fail --min-fit on it
    // (a model that drops a channel must not pass on the others alone).
    let unmatched: Vec<Channel> = header_channels(&a.a)?
        .into_iter()
        .filter(|c| !fits.iter().any(|f| f.channel == *c))
        .collect();
    for c in &unmatched {
        println!(
            "{}: in the reference, not in the model {}: not compared",
            c.name(),
            a.b.display()
        );
    }
    // -inf only comes from a reference channel that never changes (no spread to normalise
    // by) while the model differs from it: say so instead of a bare -inf.
    let constant = |f: &host_sim::io::compare::ChannelFit| f.fit_percent == f64::NEG_INFINITY;
    for f in fits.iter().filter(|f| constant(f)) {
        println!(
            "{}: constant in the reference {} (a dead or unplugged sensor?): its fit is undefined; \
             MAE and MSE still compare",
            f.channel.name(),
            a.a.display()
        );
    }
    if let Some(min) = a.min_fit {
        let bad: Vec<_> = fits
            .iter()
            .filter(|f| f.fit_percent.is_nan() || f.fit_percent < min)
            .collect();
        for c in &unmatched {
            eprintln!("{}: missing in the model, no fit < {min} %", c.name());
        }
        if !bad.is_empty() || !unmatched.is_empty() {
            for f in bad {
                if constant(f) {
                    eprintln!(
                        "{}: fit undefined (the reference is constant) < {min} %",
                        f.channel.name()
                    );
                } else {
                    eprintln!("{}: fit {:.4} % < {min} %", f.channel.name(), f.fit_percent);
                }
            }
            return Ok(ExitCode::from(1));
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// `model` restricted to the channels `reference` has too.
fn only_common(model: &Recording, reference: &Recording) -> Recording {
    let mut r = model.clone();
    for c in Channel::ALL {
        if reference.channel(c).is_none() {
            r.outputs[c.index()] = None;
        }
    }
    r
}

/// `diagnose --write-plant`: the plant file with the discovered term, when the answer is
/// unexplained and the discovery (on the nominal plant) found one; else why nothing is
/// written. Returns the line to print.
fn write_discovered_plant(
    a: &DiagnoseArgs,
    out: &Path,
    plant_text: &str,
    d: &host_sim::diagnose::Diagnosis,
    discovered: Option<&host_sim::diagnose::discover::Discovery>,
) -> Result<String> {
    use host_sim::diagnose::Verdict;
    let found = discovered.and_then(|x| x.found.as_ref());
    let Some(f) = found.filter(|_| d.verdict == Verdict::Unexplained) else {
        let why = match (d.verdict, found) {
            (Verdict::PartlyExplained, Some(_)) => {
                "the term completes the named items (write their values from the JSON into \
                 the plant file, then diagnose again)"
            }
            _ => "nothing discovered",
        };
        return Ok(format!("{why}: {} not written", out.display()));
    };
    let found_by = format!("`host-sim diagnose` on {}", a.recording.display());
    let text =
        host_sim::diagnose::discover::plant_text_with(plant_text, &a.plant, &found_by, &f.table)
            .map_err(|e| anyhow::anyhow!("--write-plant: {e}"))?;
    host_sim::identify::write_atomic(out, text.as_bytes())?;
    Ok(format!("wrote {}", out.display()))
}

/// `diagnose` with a 3-DOF arm plant file: every joint through the 1-DOF pipeline
/// (`host_sim::diagnose::arm3`); one JSON for the arm, a report per joint (DIR/jointN/).
fn run_diagnose_arm(
    a: &DiagnoseArgs,
    opts: &host_sim::diagnose::DiagnoseOptions,
    bar: &ProgressBar,
) -> Result<ExitCode> {
    use host_sim::diagnose::arm3::diagnose_arm;
    use host_sim::diagnose::report::write_report;
    use host_sim::io::arm3::Arm3Recording;
    if a.check.is_some() {
        anyhow::bail!(
            "--check: not supported with an arm plant (the held-out part is the tail of --recording)"
        );
    }
    let cfg = host_sim::plant::arm3::Arm3Config::load(&a.plant)?;
    let rec = Arm3Recording::read(&a.recording)?;
    let result = diagnose_arm(&cfg, &rec, opts, &|done, total, msg| {
        bar.set_length(total);
        bar.set_position(done);
        bar.set_message(msg.to_string());
    });
    bar.finish_and_clear();
    let d = result.with_context(|| format!("{}: diagnosis failed", a.recording.display()))?;
    let json = serde_json::to_string_pretty(&d.to_json())? + "\n";
    if let Some(dir) = &a.report {
        for (i, j) in d.joints.iter().enumerate() {
            let sub = dir.join(format!("joint{}", i + 1));
            let joint_json = serde_json::to_string_pretty(&j.to_json())? + "\n";
            write_report(
                &sub,
                j,
                None,
                &joint_json,
                &format!("{} (joint {})", a.recording.display(), i + 1),
                None,
            )
            .map_err(|e| anyhow::anyhow!("report {}: {e}", sub.display()))?;
        }
    }
    host_sim::identify::write_atomic(&a.json, json.as_bytes())?;
    use std::io::Write as _;
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{}wrote {}", d.answer(), a.json.display());
    // The joints' worst status: 3 before 4 before 0.
    let status = d
        .joints
        .iter()
        .map(|j| j.verdict.exit_status())
        .max_by_key(|s| match s {
            3 => 2,
            4 => 1,
            _ => 0,
        })
        .unwrap_or(0);
    Ok(ExitCode::from(status))
}

/// `diagnose`'s files before anything runs: --check is not --recording, no output is an
/// input or another output, every output may be replaced, the report folder can be written.
fn check_diagnose_files(a: &DiagnoseArgs) -> Result<()> {
    let mut inputs: Vec<(&str, &Path)> = vec![("--plant", &a.plant), ("--recording", &a.recording)];
    if let Some(c) = &a.check {
        // The check recording validates the answer on data it was not fitted to.
        if validate::same_existing_file(c, &a.recording) {
            anyhow::bail!(
                "--check {}: is the same file as --recording {}; give a recording of the same rig \
                 with another excitation (or leave out --check: the held-out tail of --recording \
                 is always checked)",
                c.display(),
                a.recording.display()
            );
        }
        inputs.push(("--check", c));
    }
    discover::check_outputs(&inputs, Some(&a.json), a.write_plant.as_deref())?;
    let mut outputs: Vec<(&str, &Path)> = vec![("--json", &a.json)];
    if let Some(p) = &a.write_plant {
        outputs.push(("--write-plant", p));
    }
    if let Some(dir) = &a.report {
        validate::output_dir("--report", dir).map_err(anyhow::Error::msg)?;
        let report_json = dir.join("diagnosis.json");
        let index = dir.join("index.html");
        validate::distinct_outputs(&inputs, &[("--report", &report_json), ("--report", &index)])
            .map_err(anyhow::Error::msg)?;
        // --json and --write-plant are neither the report folder nor one of its files.
        for (flag, file) in &outputs {
            if validate::same_path(file, dir) {
                anyhow::bail!(
                    "{flag} {} is the --report folder: give a file outside it",
                    file.display()
                );
            }
            for own in [&report_json, &index] {
                if validate::same_path(file, own) {
                    anyhow::bail!(
                        "{flag} {} is the report's own {}: give a file outside --report {}",
                        file.display(),
                        own.file_name().unwrap_or_default().to_string_lossy(),
                        dir.display()
                    );
                }
            }
        }
        // The report's own files (arm plants: one folder per joint).
        let files: Vec<PathBuf> = [
            PathBuf::new(),
            "joint1".into(),
            "joint2".into(),
            "joint3".into(),
        ]
        .iter()
        .flat_map(|sub| {
            [
                dir.join(sub).join("diagnosis.json"),
                dir.join(sub).join("index.html"),
            ]
        })
        .collect();
        host_sim::output::check_dir("--report", dir, &files).map_err(anyhow::Error::msg)?;
    }
    Ok(())
}

fn run_diagnose(a: &DiagnoseArgs) -> Result<ExitCode> {
    use host_sim::diagnose::{
        answer::failure_json, diagnose, report::write_report, DiagnoseError, DiagnoseOptions,
    };
    check_diagnose_files(a)?;
    let bar = stderr_bar(
        Some(100),
        "{spinner} diagnose [{bar:40}] {pos}/{len} {msg} {elapsed}",
    );
    let opts = DiagnoseOptions {
        threads: a.threads,
        ..DiagnoseOptions::default()
    };
    if host_sim::plant::arm3::is_arm3_file(&a.plant)? {
        if a.write_plant.is_some() {
            anyhow::bail!("--write-plant: not supported with an arm plant (1-DOF plants only)");
        }
        return run_diagnose_arm(a, &opts, &bar);
    }
    let cfg = host_sim::PlantConfig::load(&a.plant)?;
    let plant_text = discover::plant_text_to_write(&a.plant, a.write_plant.is_some())?;
    let mut train = Recording::read(&a.recording)?;
    let mut check = a.check.as_ref().map(Recording::read).transpose()?;
    if let Some(ms) = a.shift_valves_ms {
        let shift = |r: &Recording| {
            host_sim::io::timebase::shift_valves(r, ms * 1e-3).map_err(anyhow::Error::msg)
        };
        train = shift(&train)?;
        check = check.as_ref().map(shift).transpose()?;
    }
    let estimate = host_sim::diagnose::run_estimate(&train, check.as_ref(), &opts);
    estimate.check(a.allow_large).map_err(anyhow::Error::msg)?;
    if estimate.seconds > 30.0 {
        bar.suspend(|| eprintln!("{}", estimate.summary()));
    }
    let result = diagnose(&cfg, &train, check.as_ref(), &opts, &|done, total, msg| {
        bar.set_length(total);
        bar.set_position(done);
        bar.set_message(msg.to_string());
    });
    bar.finish_and_clear();
    use std::io::Write as _;
    let d = match result {
        Ok(d) => d,
        // The nominal replay failed: still an answer (unexplained, with the time and state
        // of the failure), the JSON is written and the exit status is 3.
        Err(DiagnoseError::Sim(e)) => {
            let msg = e.to_string();
            let json = serde_json::to_string_pretty(&failure_json(&msg))? + "\n";
            host_sim::identify::write_atomic(&a.json, json.as_bytes())?;
            let mut out = std::io::stdout().lock();
            let _ = write!(
                out,
                "Unexplained: the nominal model cannot replay {}: {msg}\nwrote {}\n",
                a.recording.display(),
                a.json.display()
            );
            return Ok(ExitCode::from(3));
        }
        Err(e) => {
            // An error of the check recording names that file (`--check`), not the training one.
            let file = match &a.check {
                Some(c) if e.to_string().starts_with("check recording") => {
                    format!("--check {}", c.display())
                }
                _ => a.recording.display().to_string(),
            };
            return Err(anyhow::Error::new(e)).with_context(|| format!("{file}: diagnosis failed"));
        }
    };
    // What the catalogue left: the missing term in closed form, held-out checked.
    let discovered = host_sim::diagnose::discover::after_diagnosis(
        &cfg,
        &train,
        check.as_ref(),
        &d,
        &host_sim::diagnose::discover::DiscoverOptions {
            threads: a.threads,
            ..Default::default()
        },
    )
    .and_then(|r| r.ok());
    let mut json_value = d.to_json();
    // The option that moved the valve columns, so that the answer can be traced to it.
    json_value["shift_valves_ms"] = a.shift_valves_ms.into();
    json_value["discovered"] = discovered
        .as_ref()
        .map(|x| x.to_json())
        .unwrap_or(serde_json::Value::Null);
    let json = serde_json::to_string_pretty(&json_value)? + "\n";
    host_sim::identify::write_atomic(&a.json, json.as_bytes())?;
    if let Some(dir) = &a.report {
        write_report(
            dir,
            &d,
            discovered.as_ref(),
            &json,
            &a.recording.display().to_string(),
            a.check.as_ref().map(|c| c.display().to_string()).as_deref(),
        )
        .map_err(|e| anyhow::anyhow!("report {}: {e}", dir.display()))?;
    }
    // A closed stdout (`| head`) is not an error of the diagnosis: the JSON is written.
    let mut out = std::io::stdout().lock();
    let _ = writeln!(
        out,
        "nominal plant effects: {}",
        Plant::from_config(&cfg).effects_summary()
    );
    let _ = write!(out, "{}", d.answer());
    if let Some(x) = &discovered {
        let _ = write!(out, "Discovery (what the catalogue leaves):\n{}", x.text());
    }
    let _ = writeln!(out, "wrote {}", a.json.display());
    if let Some(dir) = &a.report {
        let _ = writeln!(out, "wrote {}", dir.join("index.html").display());
    }
    if let Some(p) = &a.write_plant {
        let line = write_discovered_plant(a, p, &plant_text, &d, discovered.as_ref())?;
        let _ = writeln!(out, "{line}");
    }
    // Exit status 4: partly explained; 3: the diagnosis names nothing because the recording
    // is unexplained or not of this plant (the JSON says which).
    Ok(ExitCode::from(d.verdict.exit_status()))
}
