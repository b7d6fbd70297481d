//! Helpers shared by the command-line tests (`mod common;` in a test file). Not every test
//! binary uses every helper.
#![allow(dead_code)]

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use pam_firmware::lockstep::UnwiredPin;

/// The workspace root.
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// A file of `host-sim/tests/fixtures/` (copies of the shared material, see its README).
pub fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

/// The reference plant file (fixture copy).
pub fn plant() -> PathBuf {
    fixture("reference-1dof.toml")
}

/// The shared, read-only material next to the repository.
pub fn shared() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared")
}

/// Runs the `host-sim` binary with `args`.
pub fn host_sim(args: &[&dyn AsRef<OsStr>]) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_host-sim"));
    for a in args {
        c.arg(a);
    }
    c.output().unwrap()
}

/// A command for the `host-sim` binary.
pub fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_host-sim"))
}

/// Process output as text.
pub fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// Asserts that the run succeeded (status, stdout and stderr shown otherwise); its stdout.
pub fn ok(r: &Output) -> String {
    assert!(
        r.status.success(),
        "status {:?}\nstdout:\n{}\nstderr:\n{}",
        r.status,
        text(&r.stdout),
        text(&r.stderr)
    );
    text(&r.stdout)
}

/// Asserts that the run exited with status `code` (stdout and stderr shown otherwise); its
/// stderr.
pub fn exits(code: i32, r: &Output) -> String {
    assert_eq!(
        r.status.code(),
        Some(code),
        "stdout:\n{}\nstderr:\n{}",
        text(&r.stdout),
        text(&r.stderr)
    );
    text(&r.stderr)
}

/// Asserts that the run was refused with status 2, a message naming every one of `needles`
/// and nothing written at `out`; its stderr.
pub fn assert_refused(r: &Output, needles: &[&str], out: &Path) -> String {
    let e = exits(2, r);
    for n in needles {
        assert!(e.contains(n), "`{n}` not in the message:\n{e}");
    }
    assert!(!out.exists(), "{} was written", out.display());
    e
}

/// The message of `r`, which must be an error naming every one of `needles`.
pub fn error_naming<T, E: std::fmt::Display>(r: Result<T, E>, needles: &[&str]) -> String {
    let Err(e) = r.map_err(|e| e.to_string()) else {
        panic!("accepted; expected an error naming {needles:?}");
    };
    for n in needles {
        assert!(e.contains(n), "`{n}` not in the error:\n{e}");
    }
    e
}

/// The error message of `parse(text)`, which must fail (the text is shown otherwise).
pub fn parse_error<T, E: std::fmt::Display>(
    text: &str,
    parse: impl FnOnce(&str) -> Result<T, E>,
) -> String {
    match parse(text) {
        Ok(_) => panic!("accepted:\n{text}"),
        Err(e) => e.to_string(),
    }
}

/// The firmware trace (`<name>.firmware.csv`: a header and one row per tick; `#` lines are
/// metadata) and the plot (`<name>.png`) a demo run wrote into `dir`.
pub fn assert_trace_and_plot(dir: &Path, name: &str, ticks: usize) {
    let trace = std::fs::read_to_string(dir.join(format!("{name}.firmware.csv"))).unwrap();
    assert_eq!(
        trace.lines().filter(|l| !l.starts_with('#')).count(),
        ticks + 1,
        "{name}: header + one row per tick"
    );
    let png = std::fs::read(dir.join(format!("{name}.png"))).unwrap();
    assert!(
        png.starts_with(b"\x89PNG") && png.len() > 10_000,
        "{name}.png"
    );
}

/// What a refused run must leave in an output file an earlier good run wrote.
/// What an earlier good run left in an output file named `name`: a file of the kind the
/// command writes there (commands refuse to replace a file of another kind), recognisable.
pub fn previous_output_text(name: &str) -> &'static str {
    match name {
        n if n.ends_with(".csv") => {
            "# generator = host-sim (an earlier run)\n# previous good output\nt_s,u_in1,u_ex1,u_in2,u_ex2\n0,0,0,0,0\n"
        }
        "force.toml" => "# generator = host-sim (an earlier run)\n# previous good output\n[force_law]\n",
        "torque.toml" => "# generator = host-sim (an earlier run)\n# previous good output\n[torque_model]\n",
        "volume.toml" => "# generator = host-sim (an earlier run)\n# previous good output\n[volume_fnn]\n",
        "fitted.toml" => "# generator = host-sim (an earlier run)\n# previous good output\n[muscle]\n",
        _ => "# generator = host-sim (an earlier run)\n# previous good output\n",
    }
}

/// `dir/name` holding [`previous_output_text`] (an output file of an earlier good run).
pub fn previous_output(dir: &Path, name: &str) -> PathBuf {
    let out = dir.join(name);
    std::fs::write(&out, previous_output_text(name)).unwrap();
    out
}

/// Asserts that `out` still holds [`previous_output_text`].
pub fn assert_kept(out: &Path) {
    let name = out.file_name().unwrap().to_string_lossy();
    assert_eq!(
        std::fs::read_to_string(out).unwrap(),
        previous_output_text(&name)
    );
}

/// Runs `host-sim` with `args` and asserts success; its stdout.
pub fn run_ok(args: &[&dyn AsRef<OsStr>]) -> String {
    ok(&host_sim(args))
}

/// Runs `host-sim` with `args` and asserts the exit status `code`; its stderr.
pub fn run_exits(code: i32, args: &[&dyn AsRef<OsStr>]) -> String {
    exits(code, &host_sim(args))
}

/// Seed 001's three-joint arm (the plant file shipped with host-sim).
pub fn arm3_plant() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("plants/arm3-seed001.toml")
}

/// Asserts that every channel's fit line of `stdout` ("<channel> <fit %> ...", as `fit` and
/// `demo` print them) reads at least `min_percent`.
pub fn assert_channel_fits(stdout: &str, min_percent: f64) {
    for c in ["angle_deg", "p1_kpa", "p2_kpa", "f1_n", "f2_n"] {
        let line = stdout
            .lines()
            .find(|l| l.trim_start().starts_with(c))
            .unwrap_or_else(|| panic!("no fit line for {c}:\n{stdout}"));
        let fit: f64 = line.split_whitespace().nth(1).unwrap().parse().unwrap();
        assert!(fit >= min_percent, "{line}");
    }
}

/// The text of the reference plant file (fixture copy).
pub fn nominal_text() -> String {
    std::fs::read_to_string(plant()).expect("tests/fixtures/reference-1dof.toml")
}

/// The reference plant file with the TOML `extra` (e.g. an `[effects.*]` table) appended.
pub fn config_with(extra: &str) -> host_sim::PlantConfig {
    let text = format!("{}\n{extra}\n", nominal_text());
    host_sim::PlantConfig::from_toml_str(&text, "test-plant.toml").unwrap_or_else(|e| panic!("{e}"))
}

/// [`config_with`] as a plant.
pub fn plant_with(extra: &str) -> host_sim::Plant {
    host_sim::Plant::from_config(&config_with(extra))
}

/// `n` samples of on/off valve pulses that swing the joint both ways: fill muscle 1 and vent
/// muscle 2, hold, vent 1 and fill 2, hold; each phase `period` samples long.
pub fn pulse_inputs(n: usize, period: usize) -> Vec<host_sim::ValveInputs> {
    (0..n)
        .map(|k| {
            let phase = (k / period) % 4;
            let on = |b: bool| if b { 1.0 } else { 0.0 };
            host_sim::ValveInputs {
                u_in1: on(phase == 0),
                u_ex2: on(phase == 0),
                u_ex1: on(phase == 2),
                u_in2: on(phase == 2),
            }
        })
        .collect()
}

/// Runs `host-sim <command> --plant <plant>` followed by `rest`.
pub fn on_plant(command: &str, plant: &dyn AsRef<OsStr>, rest: &[&dyn AsRef<OsStr>]) -> Output {
    let mut c = bin();
    c.arg(command).arg("--plant").arg(plant);
    for a in rest {
        c.arg(a);
    }
    c.output().unwrap()
}

/// `host-sim demo` of the seed 001 arm ([`arm3_plant`]) on the scenario file `scenario`,
/// writing into `out_dir`.
pub fn arm_demo(scenario: &Path, out_dir: &Path) -> Output {
    on_plant(
        "demo",
        &arm3_plant(),
        &[&"--scenario", &scenario, &"--out-dir", &out_dir],
    )
}

/// The reference on/off valve driver on pins wired to nothing (the openings it computes are
/// what a plant-in-the-loop test applies).
pub fn unwired_valves(
) -> pam_firmware::valves::OnOffValves<UnwiredPin, UnwiredPin, UnwiredPin, UnwiredPin> {
    pam_firmware::valves::OnOffValves::new(
        UnwiredPin,
        UnwiredPin,
        UnwiredPin,
        UnwiredPin,
        pam_firmware::valves::OnOffPwmConfig::REFERENCE,
    )
}

/// An integrator of `plant` from its initial state at tight tolerances (1e-6 relative and
/// absolute), for closed-loop step tests.
pub fn tight_integrator(plant: &host_sim::Plant) -> host_sim::sim::Integrator<'_> {
    let opts = host_sim::sim::SolverOptions {
        rtol: 1e-6,
        atol: 1e-6,
        ..Default::default()
    };
    host_sim::sim::Integrator::new(plant, plant.initial_state(), opts)
}

/// Asserts that no polish move of the tuner (each cascade gain x 0.7 / x 1.4) lowers the
/// tuning cost below 98 % of the stored cascade's (the worse of its two stored suite MSEs):
/// the stored gains are a local optimum. Returns the stored cascade's configuration.
pub fn assert_cascade_local_optimum(
    plant: &host_sim::Plant,
    scenarios: &[host_sim::control::closed_loop::Scenario],
    stored: &host_sim::control::compare::CascadeToml,
) -> pam_firmware::tick::ControllerConfig {
    let cfg = stored.config(1000.0);
    let stored_cost = stored.suite_mse_rad2.max(stored.suite_mse_at_margin_rad2);
    for (what, f, moved) in host_sim::control::tune::cascade_polish_moves(&cfg) {
        let (c, ..) = host_sim::control::compare::tuning_cost(plant, scenarios, moved);
        eprintln!("cascade {what} x{f}: cost {c:.4e} rad^2 (stored {stored_cost:.4e})");
        assert!(
            c >= 0.98 * stored_cost,
            "cascade with {what} x{f} costs {c:.4e} rad^2 < stored {stored_cost:.4e} rad^2"
        );
    }
    cfg
}
