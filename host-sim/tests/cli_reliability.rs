//! Nothing a user types crashes, hangs, exhausts memory or loses data: every bad argument or
//! file value below exits with status 2 and a message naming the argument (or file, line and
//! key) and its allowed range, and leaves the user's files exactly as they were (an existing
//! output keeps its content, no new file or directory appears).

mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::process::Output;

/// Status 2, every `needles` in stderr, and no panic.
fn refused(r: &Output, needles: &[&str]) -> String {
    let err = text(&r.stderr);
    assert_eq!(
        r.status.code(),
        Some(2),
        "stdout:\n{}\nstderr:\n{err}",
        text(&r.stdout)
    );
    assert!(!err.contains("panicked"), "{err}");
    for n in needles {
        assert!(err.contains(n), "`{n}` not in:\n{err}");
    }
    err
}

/// The files of `dir` with their contents.
fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut v: Vec<_> = walk(dir)
        .into_iter()
        .map(|p| {
            let c = if p.is_file() {
                std::fs::read(&p).unwrap()
            } else {
                Vec::new()
            };
            (p, c)
        })
        .collect();
    v.sort();
    v
}

fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walk(&p));
        }
        out.push(p);
    }
    out
}

/// A temporary directory with a precious existing output `out.*` in it.
struct Workspace {
    dir: tempfile::TempDir,
}

impl Workspace {
    fn new() -> Workspace {
        let dir = tempfile::tempdir().unwrap();
        // Each of the kind a command writes there and with host-sim's mark, as an earlier
        // run left it (commands refuse to replace a file of another kind, or one host-sim
        // did not write, before any work; these tests are about the refusals after that).
        for (name, text) in [
            (
                "out.csv",
                "# generator = host-sim (an earlier run)\n# precious out.csv\nt_s,u_in1,u_ex1,u_in2,u_ex2\n0,0,0,0,0\n",
            ),
            (
                "out.toml",
                "# generator = host-sim (an earlier run)\n# precious out.toml\n[force_law]\n[torque_model]\n[volume_fnn]\n[cascade]\n[muscle]\n",
            ),
            (
                "out.json",
                "{\"generator\": \"host-sim (an earlier run)\", \"precious\": \"out.json\"}\n",
            ),
            ("out.png", "precious out.png (tEXt generator\0host-sim)\n"),
        ] {
            std::fs::write(dir.path().join(name), text).unwrap();
        }
        Workspace { dir }
    }
    fn p(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }
    fn write(&self, name: &str, content: &str) -> PathBuf {
        let p = self.p(name);
        std::fs::write(&p, content).unwrap();
        p
    }
    fn snapshot(&self) -> Vec<(PathBuf, Vec<u8>)> {
        snapshot(self.dir.path())
    }
    /// Runs `host-sim` with `command_line` (split at spaces; then `{plant}`, `{fixture}`,
    /// `{w}` (this directory) and each `{name}` of `paths` replaced in every argument),
    /// requires the refusal of [`refused`] with `needles` and this directory unchanged.
    fn refuses_with(
        &self,
        command_line: &str,
        paths: &[(&str, &Path)],
        needles: &[&str],
    ) -> String {
        let before = self.snapshot();
        let args: Vec<String> = command_line
            .split(' ')
            .map(|a| {
                let mut a = a
                    .replace("{plant}", &plant().to_string_lossy())
                    .replace(
                        "{fixture}",
                        &fixture("pulses_nominal.csv").to_string_lossy(),
                    )
                    .replace("{w}", &self.dir.path().to_string_lossy());
                for (name, p) in paths {
                    a = a.replace(&format!("{{{name}}}"), &p.to_string_lossy());
                }
                a
            })
            .collect();
        let r = bin().args(&args).output().unwrap();
        let err = refused(&r, needles);
        assert_eq!(
            self.snapshot(),
            before,
            "{command_line}: the directory changed"
        );
        err
    }
    fn refuses(&self, command_line: &str, needles: &[&str]) -> String {
        self.refuses_with(command_line, &[], needles)
    }
}

#[test]
fn identify_plant_with_zero_patience_is_refused() {
    let w = Workspace::new();
    w.refuses(
        "identify plant --recording {fixture} --plant {plant} --params joint.inertia_kgm2 --out {w}/out.toml --patience 0",
        &["--patience", "1..=100000"],
    );
}

#[test]
fn identify_plant_bounds_reversed_or_beyond_the_keys_range_are_refused() {
    let w = Workspace::new();
    w.refuses(
        "identify plant --recording {fixture} --plant {plant} --params joint.inertia_kgm2=1:0.001 --out {w}/out.toml",
        &["--params joint.inertia_kgm2=1:0.001", "reversed", "lower 1 must be below the upper 0.001"],
    );
    w.refuses(
        "identify plant --recording {fixture} --plant {plant} --params joint.inertia_kgm2=0.001:1000 --out {w}/out.toml",
        &["joint.inertia_kgm2", "[0.0001, 10]", "bounds within it"],
    );
}

#[test]
fn sweep_torque_sizes_that_would_exhaust_memory_are_refused_with_the_estimate() {
    let w = Workspace::new();
    w.refuses(
        "sweep torque --plant {plant} --out {w}/out.csv --dt-s 1e-7",
        &["--dt-s", "[0.000001, 1]"],
    );
    w.refuses(
        "sweep torque --plant {plant} --out {w}/out.csv --speeds-rad-s 1e-6",
        &["sweep torque", "of memory", "--allow-large"],
    );
    w.refuses(
        "sweep force --plant {plant} --out {w}/force.csv --n-stretch 100000 --n-pressure 100000",
        &["sweep force", "1.000e10 samples", "--allow-large"],
    );
}

#[test]
fn sweep_torque_names_a_mid_pressure_in_the_wrong_unit_not_the_levels() {
    let w = Workspace::new();
    w.refuses(
        "sweep torque --plant {plant} --out {w}/out.csv --p0-kpa 0.3",
        &[
            "--p0-kpa 0.3",
            "bar or MPa",
            "0.3 MPa = 300 kPa",
            "0.3 bar = 30 kPa",
        ],
    );
    w.refuses(
        "sweep torque --plant {plant} --out {w}/out.csv --p0-kpa 300 --dp-kpa 400",
        &["--dp-kpa 400 with --p0-kpa 300", "the supply"],
    );
    // The reference joint reaches +-1.099 rad (muscle 1 at its maximum contraction 0.2499).
    w.refuses(
        "sweep torque --plant {plant} --out {w}/out.csv --amplitude-rad 2.0",
        &["--amplitude-rad 2", "reach", "+-1.099 rad", "0.2499"],
    );
}

const STEP: &str = "[scenario]\nname = \"long\"\nduration_s = 1e9\ntick_hz = 1000.0\n\n\
[setpoint]\nkind = \"step\"\ninitial_rad = 0.0\nfinal_rad = 0.2\nat_s = 1.0\n";

#[test]
fn a_scenario_too_long_for_memory_is_refused_with_the_estimate() {
    let w = Workspace::new();
    w.write("long.toml", STEP);
    w.refuses(
        "simulate --plant {plant} --scenario {w}/long.toml --out {w}/out.csv",
        &[
            "long.toml",
            "1.000e12 samples",
            "TB of memory",
            "--allow-large",
        ],
    );
}

#[test]
fn a_set_point_beyond_the_firmware_limit_is_refused_not_silently_clamped() {
    let w = Workspace::new();
    w.write(
        "far.toml",
        &STEP
            .replace("1e9", "4.0")
            .replace("final_rad = 0.2", "final_rad = 1.2"),
    );
    w.refuses(
        "simulate --plant {plant} --scenario {w}/far.toml --out {w}/out.csv",
        &["far.toml", "final_rad: 1.2 rad", "+-0.8 rad", "clamp"],
    );
    let sine = "[scenario]\nname = \"wide\"\nduration_s = 4.0\n\n[setpoint]\nkind = \"sine\"\n\
offset_rad = 0.3\namplitude_rad = 0.6\nfreq_hz = 0.5\n";
    w.write("wide.toml", sine);
    w.refuses(
        "simulate --plant {plant} --scenario {w}/wide.toml --out {w}/out.csv",
        &["wide.toml", "offset_rad + amplitude_rad: 0.9 rad"],
    );
}

#[test]
fn event_values_in_the_wrong_unit_are_refused_with_the_plant_files_ranges() {
    let w = Workspace::new();
    let short = STEP.replace("1e9", "4.0");
    for (event, needles) in [
        (
            "kind = \"supply_loss\"\nat_s = 1.0\nsupply_gauge_pa = 5.5\n",
            &[
                "supply_gauge_pa",
                "bar or kPa typed",
                "5.5 bar is 550000 Pa",
            ][..],
        ),
        (
            "kind = \"load_inertia\"\nat_s = 1.0\ninertia_kgm2 = 1550.0\n",
            &["inertia_kgm2", "[0.0001, 10]"][..],
        ),
    ] {
        w.write("ev.toml", &format!("{short}\n[[events]]\n{event}"));
        let mut n = vec!["ev.toml", "[[events]] #1"];
        n.extend_from_slice(needles);
        w.refuses(
            "simulate --plant {plant} --scenario {w}/ev.toml --out {w}/out.csv",
            &n,
        );
    }
}

#[test]
fn a_scenario_settling_after_its_end_is_refused_at_its_line() {
    let w = Workspace::new();
    w.write(
        "late.toml",
        &format!(
            "{}\n[expect]\nsettle_after_s = 10.0\nmax_abs_error_rad = 0.01\n",
            STEP.replace("1e9", "4.0")
        ),
    );
    w.refuses(
        "simulate --plant {plant} --scenario {w}/late.toml --out {w}/out.csv",
        &["late.toml", "line 13", "settle_after_s", "[0, 4)"],
    );
}

/// Unit mistakes and set-points that test nothing are refused at their line: degrees typed into
/// a `_rad` key, a step after the end of the run, a sine above half the tick rate (it would
/// alias to a constant and "meet" its expectations), Pa typed into a kPa bound.
#[test]
fn scenario_unit_mistakes_are_refused_at_their_line() {
    let w = Workspace::new();
    let short = STEP.replace("1e9", "4.0");
    let sine = "[scenario]\nname = \"fast\"\nduration_s = 4.0\ntick_hz = 1000.0\n\n\
[setpoint]\nkind = \"sine\"\noffset_rad = 0.0\namplitude_rad = 0.2\nfreq_hz = 1e6\nstart_s = 0.5\n";
    for (name, text, needles) in [
        (
            "deg.toml",
            short.replace("final_rad = 0.2", "final_rad = 20.0"),
            &[
                "deg.toml",
                "line 9",
                "final_rad",
                "degrees typed as radians",
            ][..],
        ),
        (
            "late_step.toml",
            short.replace("at_s = 1.0", "at_s = 10.0"),
            &["late_step.toml", "line 10", "at_s", "never move"][..],
        ),
        (
            "fast.toml",
            sine.to_string(),
            &["fast.toml", "freq_hz", "half the tick rate"][..],
        ),
        (
            "pa.toml",
            format!("{short}\n[expect]\nmax_pressure_kpa = 610000.0\n"),
            &["pa.toml", "max_pressure_kpa", "Pa typed"][..],
        ),
    ] {
        let path = w.write(name, &text);
        w.refuses_with(
            "simulate --plant {plant} --scenario {s} --out {w}/out.csv",
            &[("s", &path)],
            needles,
        );
    }
}

#[test]
fn simulate_refuses_to_write_over_its_input_recording() {
    let w = Workspace::new();
    w.write(
        "rec.csv",
        &std::fs::read_to_string(fixture("pulses_nominal.csv")).unwrap(),
    );
    // The same file under another spelling of its path.
    w.refuses(
        "simulate --plant {plant} --inputs {w}/rec.csv --out {w}/./rec.csv",
        &["--out", "is the input --inputs"],
    );
}

/// Every command that writes refuses an output that is one of its inputs, before any work,
/// and leaves the input as it was (the plant file as tune's gains file replaced a plant file
/// before this check).
#[test]
fn no_command_writes_over_one_of_its_inputs() {
    let w = Workspace::new();
    let rec = w.write(
        "rec.csv",
        &std::fs::read_to_string(fixture("pulses_nominal.csv")).unwrap(),
    );
    let p = w.write("plant.toml", &std::fs::read_to_string(plant()).unwrap());
    std::fs::create_dir(w.dir.path().join("cfg")).unwrap();
    let pc = w.write(
        "cfg/plant_constants.toml",
        &std::fs::read_to_string(plant()).unwrap(),
    );
    let scenario = w.write("step.toml", &STEP.replace("1e9", "2.0"));
    let paths = [
        ("rec", rec.as_path()),
        ("p", &p),
        ("pc", &pc),
        ("s", &scenario),
    ];
    for (line, needle) in [
        ("tune --plant {p} --out {p}", "--out"),
        ("sweep force --plant {p} --out {p}", "--out"),
        (
            "identify torque --recording {rec} --plant {p} --out {rec}",
            "--out",
        ),
        ("import --map {p} --input {rec} --out {rec}", "--out"),
        ("capture --log {rec} --out {w}/./rec.csv", "--out"),
        ("pil --plant {p} --scenario {s} --out {s}", "--out"),
        (
            "calibrate --recording {rec} --plant {pc} --out-dir {w}/cfg",
            "--out-dir",
        ),
    ] {
        w.refuses_with(line, &paths, &[needle, "refusing to overwrite an input"]);
    }
}

/// An output path that is a directory (or a missing directory's file, for a run that takes
/// minutes) is refused before the run: the other outputs stay as they were.
#[test]
fn an_output_that_cannot_be_written_is_refused_before_the_run() {
    let w = Workspace::new();
    w.write(
        "out.csv",
        "# generator = host-sim (an earlier run)\nprevious\n",
    );
    w.write(
        "old.json",
        "{\"generator\": \"host-sim (an earlier run)\"}\n",
    );
    std::fs::create_dir_all(w.dir.path().join("d.png")).unwrap();
    std::fs::create_dir_all(w.dir.path().join("rd/index.html")).unwrap();
    for (line, needles) in [
        (
            "simulate --plant {plant} --inputs {fixture} --out {w}/out.csv --plot {w}/d.png",
            &["--plot", "not a regular file (a directory)"][..],
        ),
        (
            "diagnose --plant {plant} --recording {fixture} --json {w}/old.json --report {w}/rd",
            &["index.html", "not a regular file"][..],
        ),
        (
            "diagnose --plant {plant} --recording {fixture} --json {w}/rd",
            &["--json", "not a regular file"][..],
        ),
        (
            "tune --plant {plant} --out {w}/missing/gains.toml",
            &["--out", "does not exist"][..],
        ),
        (
            "simulate --plant {plant} --inputs {fixture} --out {w}/missing/o.csv",
            &["--out", "missing", "does not exist"][..],
        ),
        (
            "sweep force --plant {plant} --out {w}/missing/f.csv",
            &["--out", "missing", "does not exist"][..],
        ),
        (
            "fit {fixture} {fixture} --plot {w}/missing/x.png",
            &["--plot", "missing", "does not exist"][..],
        ),
    ] {
        w.refuses(line, needles);
    }
}

#[test]
fn a_negative_number_with_an_exponent_or_no_leading_digit_is_read_as_the_value() {
    // Not as short flags: the option's own range message.
    let w = Workspace::new();
    for v in ["-1e-6", "-.5"] {
        w.refuses(
            &format!(
                "simulate --plant {{plant}} --inputs {{fixture}} --out {{w}}/o.csv --rtol {v}"
            ),
            &["--rtol", "must be a number within"],
        );
    }
}

#[test]
fn a_list_that_starts_with_a_negative_number_is_read_as_the_value() {
    // `--speeds-rad-s -1,1` was read as the short flag `-1`: now the option's own range
    // message, as `--speeds-rad-s=-1,1` gives.
    let w = Workspace::new();
    for v in ["-1,1", "-1e-3,2", "-.5"] {
        let err = w.refuses(
            &format!("sweep torque --plant {{plant}} --out {{w}}/t.csv --speeds-rad-s {v}"),
            &["--speeds-rad-s", "must be a number within (0, 1000], got -"],
        );
        assert!(!err.contains("unexpected argument"), "{err}");
    }
    // Where a negative is allowed it is taken (activation levels below p0).
    let out = w.p("t.csv");
    ok(&bin()
        .args(["sweep", "torque", "--plant"])
        .arg(plant())
        .arg("--out")
        .arg(&out)
        .args(["--dp-kpa", "-100,100", "--speeds-rad-s", "4"])
        .output()
        .unwrap());
    assert!(out.exists());
}

fn dead_channel_recording(w: &Workspace, column: &str) -> PathBuf {
    let text = std::fs::read_to_string(fixture("pulses_nominal.csv")).unwrap();
    let mut col = usize::MAX;
    let dead: String = text
        .lines()
        .map(|l| {
            if l.starts_with("t_s") {
                col = l.split(',').position(|c| c == column).unwrap();
            } else if !l.starts_with('#') && col != usize::MAX {
                let mut v: Vec<&str> = l.split(',').collect();
                v[col] = "0";
                return v.join(",") + "\n";
            }
            format!("{l}\n")
        })
        .collect();
    w.write("dead.csv", &dead);
    w.p("dead.csv")
}

#[test]
fn fit_against_a_constant_reference_channel_says_so_instead_of_a_bare_minus_infinity() {
    let w = Workspace::new();
    let dead = dead_channel_recording(&w, "angle_deg");
    let r = bin()
        .args(["fit", &dead.to_string_lossy()])
        .arg(fixture("pulses_nominal.csv"))
        .args(["--min-fit", "99"])
        .output()
        .unwrap();
    assert_eq!(r.status.code(), Some(1));
    let (out, err) = (
        String::from_utf8_lossy(&r.stdout),
        String::from_utf8_lossy(&r.stderr),
    );
    assert!(
        out.contains("angle_deg: constant in the reference") && out.contains("dead.csv"),
        "{out}"
    );
    // The table's fit column says it too (it printed -inf).
    let row = out.lines().find(|l| l.starts_with("angle_deg ")).unwrap();
    assert!(row.contains("undefined") && !row.contains("inf "), "{row}");
    assert!(
        err.contains("angle_deg: fit undefined (the reference is constant)"),
        "{err}"
    );
    assert!(!err.contains("p1_kpa"), "{err}");
}

#[test]
fn diagnose_refuses_a_dead_pressure_sensor_instead_of_naming_physics_for_it() {
    let w = Workspace::new();
    let dead = dead_channel_recording(&w, "p2_kpa");
    w.refuses_with(
        "diagnose --plant {plant} --recording {dead} --json {w}/out.json",
        &[("dead", &dead)],
        &["dead.csv", "p2_kpa", "dead or unplugged sensor"],
    );
}

#[test]
fn an_unsupported_plot_format_is_refused_before_the_recording_is_replaced() {
    let w = Workspace::new();
    w.refuses(
        "simulate --plant {plant} --inputs {fixture} --out {w}/out.csv --plot {w}/x.jpg",
        &["x.jpg", ".png or .svg"],
    );
}

#[test]
fn diagnose_with_a_report_path_that_is_a_file_keeps_the_json() {
    let w = Workspace::new();
    w.refuses(
        "diagnose --plant {plant} --recording {fixture} --json {w}/out.json --report {w}/out.png",
        &["--report", "not a directory"],
    );
}

#[test]
fn demo_with_a_bad_fixture_leaves_nothing_behind() {
    let w = Workspace::new();
    let mut bad = std::fs::read_to_string(fixture("pulses_nominal.csv")).unwrap();
    bad.push_str("20.000000,0,0,0,0,abc,550,550,529,529\n");
    w.write("bad.csv", &bad);
    // The demo directory must not appear.
    w.refuses(
        "demo --out-dir {w}/demo --plant {plant} --fixture {w}/bad.csv",
        &["bad.csv", "angle_deg"],
    );
}

#[test]
fn demo_refuses_an_input_that_sits_where_it_writes() {
    // The fixture under the name of a scenario's recording, the plant under the name of a
    // firmware trace: both would be replaced; nothing is written, both stay as they were.
    let w = Workspace::new();
    std::fs::create_dir(w.p("out")).unwrap();
    std::fs::copy(fixture("pulses_nominal.csv"), w.p("out/step.csv")).unwrap();
    w.refuses(
        "demo --out-dir {w}/out --plant {plant} --fixture {w}/out/step.csv",
        &["--out-dir", "step.csv", "is the input --fixture"],
    );
    std::fs::remove_file(w.p("out/step.csv")).unwrap();
    std::fs::copy(plant(), w.p("out/sine.firmware.csv")).unwrap();
    w.refuses(
        "demo --out-dir {w}/out --plant {w}/out/sine.firmware.csv --fixture {fixture}",
        &["--out-dir", "sine.firmware.csv", "is the input --plant"],
    );
}

#[test]
fn identify_force_on_a_constant_map_is_refused() {
    let w = Workspace::new();
    // Fifty readings of one point: one length, one pressure.
    w.write(
        "const.csv",
        &("p_kpa,stretch,f_n\n".to_owned() + &"300,0.9,400\n".repeat(50)),
    );
    w.refuses(
        "identify force --data {w}/const.csv --out {w}/out.toml",
        &["const.csv", "one length"],
    );
}

#[test]
fn identify_force_refuses_forces_a_thousand_times_off() {
    // A plausible map of a 300 N muscle (tension falling with contraction, rising with
    // pressure), then the same in mN and in kN.
    let w = Workspace::new();
    let map = |scale: f64| {
        let mut s = "p_kpa,stretch,f_n\n".to_owned();
        for p in [0, 100, 200, 300, 400, 500, 600] {
            for e in [0.8, 0.85, 0.9, 0.95, 1.0] {
                let f = (p as f64 * 0.5 * (e - 0.7) / 0.3).max(0.0);
                s += &format!("{p},{e},{}\n", f * scale);
            }
        }
        s
    };
    w.write("mn.csv", &map(1e3));
    w.refuses(
        "identify force --data {w}/mn.csv --out {w}/out.toml",
        &["mn.csv:", "field `f_n`", "mN"],
    );
    w.write("kn.csv", &map(1e-3));
    w.refuses(
        "identify force --data {w}/kn.csv --out {w}/out.toml",
        &["kn.csv:", "field `f_n`", "kN"],
    );
    // The domain's upper pressure in MPa, and one far below the data's 600 kPa: the firmware
    // would clamp every pressure to it.
    w.write("n.csv", &map(1.0));
    w.refuses(
        "identify force --data {w}/n.csv --out {w}/out.toml --p-gauge-max-kpa 0.6",
        &["--p-gauge-max-kpa", "[20, 2000]"],
    );
    w.refuses(
        "identify force --data {w}/n.csv --out {w}/out.toml --p-gauge-max-kpa 60",
        &["--p-gauge-max-kpa 60", "600 kPa", "clamps"],
    );
}

#[test]
fn identify_torque_refuses_an_activation_limit_in_mpa_and_a_window_longer_than_the_recording() {
    let w = Workspace::new();
    w.refuses(
        "identify torque --recording {fixture} --plant {plant} --out {w}/t.toml --dp-max-kpa 0.2",
        &["--dp-max-kpa 0.2", "MPa", "200 kPa"],
    );
    w.refuses(
        "identify torque --recording {fixture} --plant {plant} --out {w}/t.toml \
         --savgol-half-window 99999",
        &[
            "--savgol-half-window 99999",
            "longer than",
            "pulses_nominal.csv",
        ],
    );
    // Shorter than the recording but 8 s on either side: the velocity a line through whole
    // sweeps, its damping terms fitted to the smear.
    w.refuses(
        "identify torque --recording {fixture} --plant {plant} --out {w}/t.toml \
         --savgol-half-window 8000",
        &[
            "--savgol-half-window 8000",
            "8 s on either side",
            "give at most 100",
        ],
    );
}

#[test]
fn identify_torque_on_a_constant_recording_is_refused() {
    let w = Workspace::new();
    // 2 s at 200 Hz of a joint at rest under constant pressures and tensions.
    let rows = (0..400).map(|k| format!("{:.3},0,0,0,0,0,300,300,400,400\n", k as f64 * 0.005));
    let header = "t_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg,p1_kpa,p2_kpa,f1_n,f2_n\n";
    w.write(
        "const.csv",
        &(header.to_owned() + &rows.collect::<String>()),
    );
    w.refuses(
        "identify torque --recording {w}/const.csv --plant {plant} --out {w}/out.toml",
        &["const.csv", "angle_deg", "does not move"],
    );
}

#[test]
fn identify_torque_refuses_an_activation_limit_above_the_supply() {
    let w = Workspace::new();
    let rec = w.p("sweep.csv");
    let r = host_sim(&[&"sweep", &"torque", &"--plant", &plant(), &"--out", &rec]);
    assert!(r.status.success(), "{}", text(&r.stderr));
    w.refuses_with(
        "identify torque --recording {rec} --plant {plant} --out {w}/out.toml --dp-max-kpa 900",
        &[("rec", &rec)],
        &["--dp-max-kpa 900", "(0, 300.0]", "supply"],
    );
}

fn edited_plant(w: &Workspace, key: &str, value: &str) -> PathBuf {
    let text = std::fs::read_to_string(plant()).unwrap();
    let mut found = false;
    let edited: Vec<String> = text
        .lines()
        .map(|l| {
            if l.starts_with(&format!("{key} =")) {
                found = true;
                format!("{key} = {value}")
            } else {
                l.to_string()
            }
        })
        .collect();
    assert!(found, "{key}");
    w.write("plant.toml", &(edited.join("\n") + "\n"))
}

#[test]
fn plant_values_out_of_their_physical_range_are_refused_at_their_line() {
    let w = Workspace::new();
    for (key, value, needles) in [
        (
            "initial_contraction",
            "1.0",
            vec!["plant.toml:23:", "joint.initial_contraction", "[0, 1)"],
        ),
        (
            "initial_contraction",
            "0.3",
            vec![
                "plant.toml:23:",
                "joint.initial_contraction",
                "[0, 0.2499)",
                "maximum contraction",
            ],
        ),
        (
            "supply_gauge_pa",
            "600.0",
            vec![
                "plant.toml:9:",
                "environment.supply_gauge_pa",
                "[10000, 2000000]",
                "kPa typed into a Pa key",
            ],
        ),
        (
            "p1_gauge_pa",
            "-200000.0",
            vec!["plant.toml:33:", "initial.p1_gauge_pa", "vacuum"],
        ),
        // Finite and positive but absurd for this product: refused before any work with the
        // plausible range, not inside the integrator.
        (
            "inertia_kgm2",
            "1e-30",
            vec![
                "plant.toml:22:",
                "joint.inertia_kgm2",
                "[0.0001, 10] kg m^2",
                "rehab joint or soft manipulator",
                "got 1e-30",
            ],
        ),
        (
            "inertia_kgm2",
            "500.0",
            vec!["plant.toml:22:", "joint.inertia_kgm2", "[0.0001, 10]"],
        ),
        (
            "sprocket_radius_m",
            "0.9",
            vec![
                "plant.toml:21:",
                "joint.sprocket_radius_m",
                "[0.005, 0.2] m",
            ],
        ),
        (
            "radius_m",
            "1e-9",
            vec!["plant.toml:13:", "muscle.radius_m", "[0.001, 0.1] m"],
        ),
        (
            "sonic_conductance_m3_per_s_pa",
            "1e-20",
            vec![
                "plant.toml:26:",
                "valve.sonic_conductance_m3_per_s_pa",
                "[1e-11, 0.000001] m^3/(s Pa)",
            ],
        ),
        // The valve ratios and the volume quote the value as typed (b0 of the volume, not
        // its ratio to the muscle's cylinder).
        (
            "critical_ratio",
            "1.433",
            vec![
                "plant.toml:27:",
                "valve.critical_ratio",
                "[0, 1)",
                "got 1.433",
            ],
        ),
        (
            "laminar_ratio",
            "0.3",
            vec![
                "plant.toml:28:",
                "valve.laminar_ratio",
                "(0.433, 1)",
                "above valve.critical_ratio",
                "got 0.3",
            ],
        ),
        (
            "volume_poly_m3",
            "[-79.0e-6, 48.0e-5, -18.0e-6, -11.0e-4]",
            vec![
                "plant.toml:18:",
                "muscle.volume_poly_m3",
                "[0.0000157, 0.000393] m^3",
                "got -0.000079",
            ],
        ),
        (
            "volume_poly_m3",
            "[79.0e-6, 48.0e-5, -18.0e-6, -11.0e-1]",
            vec![
                "plant.toml:18:",
                "muscle.volume_poly_m3",
                "[0.000079, 0.00048, -0.000018, -1.1]",
                "is not > 0",
            ],
        ),
    ] {
        let p = edited_plant(&w, key, value);
        w.refuses_with(
            "simulate --plant {p} --inputs {fixture} --out {w}/out.csv",
            &[("p", &p)],
            &needles,
        );
    }
}

#[test]
fn fit_refuses_a_nan_gate() {
    let w = Workspace::new();
    // A negative number is taken as the value and refused by the range check.
    for gate in ["NaN", "150", "-2e6"] {
        w.refuses(
            &format!("fit {{fixture}} {{fixture}} --min-fit {gate}"),
            &["--min-fit", "100"],
        );
    }
    // A fraction typed for a percentage.
    w.refuses(
        "fit {fixture} {fixture} --min-fit 0.995",
        &["--min-fit", "looks like a fraction", "give 99.5"],
    );
}

#[test]
fn capture_refuses_an_elf_that_is_not_a_firmware_image_before_decoding() {
    let w = Workspace::new();
    w.write("raw.log", "\u{1}\u{2}not records\n");
    w.write("notes.txt", "not an image\n");
    w.refuses(
        "capture --log {w}/raw.log --elf {w}/notes.txt --out {w}/rec.csv",
        &[
            "--elf",
            "notes.txt",
            "ELF magic",
            "the board's or the QEMU image's ELF",
        ],
    );
}

#[test]
fn sweep_force_refuses_a_top_pressure_in_mpa() {
    let w = Workspace::new();
    w.refuses(
        "sweep force --plant {plant} --out {w}/f.csv --p-max-kpa 0.6",
        &["--p-max-kpa", "[20, 2000]", "0.6"],
    );
}

#[test]
fn plant_values_at_the_ends_of_their_plausible_ranges_run() {
    // The bounds the plant file accepts are ones the simulator can run.
    let w = Workspace::new();
    for (key, value) in [
        ("inertia_kgm2", "1e-4"),
        ("inertia_kgm2", "10.0"),
        ("sprocket_radius_m", "0.005"),
        ("sonic_conductance_m3_per_s_pa", "1e-6"),
        ("radius_m", "0.001"),
    ] {
        let mut p = edited_plant(&w, key, value);
        if key == "radius_m" {
            // A muscle 2 mm across has a chamber to match (the volume must lie near its
            // cylinder): the reference polynomial scaled by (1 mm / 10 mm)^2.
            let text = std::fs::read_to_string(&p).unwrap().replace(
                "volume_poly_m3 = [79.0e-6, 48.0e-5, -18.0e-6, -11.0e-4]",
                "volume_poly_m3 = [79.0e-8, 48.0e-7, -18.0e-8, -11.0e-6]",
            );
            assert!(text.contains("79.0e-8"));
            p = w.write("plant.toml", &text);
        }
        let out = w.p("end.csv");
        ok(&bin()
            .args(["simulate", "--plant"])
            .arg(&p)
            .arg("--inputs")
            .arg(fixture("pulses_nominal.csv"))
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap());
        // and what it wrote reads back.
        host_sim::Recording::read(&out).unwrap();
    }
}

/// The nominal fixture with the cell of `column` on data row `row` (0-based) replaced by
/// `value`; its 1-based line in the file.
fn fixture_with_cell(
    w: &Workspace,
    name: &str,
    column: &str,
    row: usize,
    value: &str,
) -> (PathBuf, usize) {
    let text = std::fs::read_to_string(fixture("pulses_nominal.csv")).unwrap();
    let mut out = Vec::new();
    let (mut header, mut data, mut line_no) = (None::<Vec<String>>, 0usize, 0usize);
    for (i, l) in text.lines().enumerate() {
        if l.starts_with('#') {
            out.push(l.to_string());
            continue;
        }
        let Some(h) = &header else {
            header = Some(l.split(',').map(String::from).collect());
            out.push(l.to_string());
            continue;
        };
        let mut f: Vec<String> = l.split(',').map(String::from).collect();
        if data == row {
            let c = h.iter().position(|x| x == column).unwrap();
            f[c] = value.to_string();
            line_no = i + 1;
        }
        data += 1;
        out.push(f.join(","));
    }
    assert!(line_no > 0);
    (w.write(name, &(out.join("\n") + "\n")), line_no)
}

#[test]
fn a_recording_value_absurd_for_its_channel_is_refused_at_its_line() {
    let w = Workspace::new();
    for (column, value, needles) in [
        // Not a plain decimal: the general reader.
        (
            "p1_kpa",
            "1e300",
            vec!["`p1_kpa`", "1e300", "[-200, 2500] kPa gauge"],
        ),
        // A plain decimal (a pressure in Pa): the fast reader hands the row to the general one.
        (
            "p2_kpa",
            "550000.0",
            vec!["`p2_kpa`", "550000", "a value in Pa?"],
        ),
        (
            "angle_deg",
            "-1e9",
            vec!["`angle_deg`", "[-3600, 3600] degrees"],
        ),
        ("f1_n", "3e12", vec!["`f1_n`", "[-1000000, 1000000] N"]),
    ] {
        let (rec, line) = fixture_with_cell(&w, "absurd.csv", column, 7000, value);
        let line = format!("absurd.csv:{line}:");
        let mut all = vec![line.as_str()];
        all.extend(needles.iter());
        for cmd in [
            "diagnose --plant {plant} --recording {rec} --json {w}/out.json",
            "fit {rec} {fixture}",
        ] {
            w.refuses_with(cmd, &[("rec", &rec)], &all);
        }
    }
    // Legitimate extremes of the channels read: vacuum, a full supply, a large angle.
    for (column, value) in [
        ("p1_kpa", "-101.3"),
        ("p2_kpa", "1999.5"),
        ("angle_deg", "-720.0"),
    ] {
        let (rec, _) = fixture_with_cell(&w, "extreme.csv", column, 7000, value);
        host_sim::Recording::read(&rec).unwrap();
    }
}

#[test]
fn diagnose_refuses_a_check_recording_that_is_the_training_recording() {
    let w = Workspace::new();
    let rec = w.p("train.csv");
    std::fs::copy(fixture("pulses_nominal.csv"), &rec).unwrap();
    let hard = w.p("hard.csv");
    std::fs::hard_link(&rec, &hard).unwrap();
    #[cfg(unix)]
    std::os::unix::fs::symlink(&rec, w.p("link.csv")).unwrap();
    let dotted = w.dir.path().join(".").join("train.csv");
    let mut checks = vec![rec.clone(), hard.clone(), dotted];
    #[cfg(unix)]
    checks.push(w.p("link.csv"));
    for check in &checks {
        w.refuses_with(
            "diagnose --plant {plant} --recording {rec} --check {check} --json {w}/out.json",
            &[("rec", &rec), ("check", check)],
            &["--check", "is the same file as --recording"],
        );
    }
    // A check recording with nothing to judge is named as --check, not as the training file.
    let text = std::fs::read_to_string(fixture("pulses_nominal.csv")).unwrap();
    let still = w.write(
        "still.csv",
        &(text.lines().take(30).collect::<Vec<_>>().join("\n") + "\n"),
    );
    w.refuses_with(
        "diagnose --plant {plant} --recording {rec} --check {check} --json {w}/out.json",
        &[("rec", &rec), ("check", &still)],
        &[
            "--check",
            "still.csv: diagnosis failed: check recording: nothing to judge",
        ],
    );
}

/// The fixture's text with its header edited by `header` and each line's fields filtered by
/// `keep` (the field's index).
fn fixture_edited(header: impl Fn(&str) -> String, keep: impl Fn(usize) -> bool) -> String {
    let text = std::fs::read_to_string(fixture("pulses_nominal.csv")).unwrap();
    let mut out = String::new();
    let mut seen_header = false;
    for line in text.lines() {
        if line.starts_with('#') {
            out += line;
        } else {
            let l = if seen_header {
                line.to_owned()
            } else {
                seen_header = true;
                header(line)
            };
            let fields: Vec<&str> = l
                .split(',')
                .enumerate()
                .filter(|(i, _)| keep(*i))
                .map(|(_, f)| f)
                .collect();
            out += &fields.join(",");
        }
        out.push('\n');
    }
    out
}

/// A channel under another unit or spelling is not silently dropped (the file judged without
/// it), and a semicolon file is named as such.
#[test]
fn a_channel_in_another_unit_or_separator_is_named_not_ignored() {
    let w = Workspace::new();
    w.write(
        "rad.csv",
        &fixture_edited(|h| h.replace("angle_deg", "angle_rad"), |_| true),
    );
    w.refuses(
        "fit {fixture} {w}/rad.csv",
        &[
            "rad.csv",
            "angle_rad",
            "RECORDING.md's is `angle_deg`",
            "degrees",
        ],
    );
    w.write(
        "case.csv",
        &fixture_edited(|h| h.replace("p1_kpa", "P1_kPa"), |_| true),
    );
    w.refuses(
        "diagnose --plant {plant} --recording {w}/case.csv --json {w}/d.json",
        &["case.csv", "P1_kPa", "`p1_kpa`"],
    );
    w.write(
        "semi.csv",
        &fixture_edited(|h| h.replace(',', ";"), |_| true),
    );
    w.refuses(
        "fit {fixture} {w}/semi.csv",
        &["semi.csv", "t_s", "comma-separated", "host-sim import"],
    );
}

/// A model that lacks a channel of the reference does not pass `--min-fit` on the others.
#[test]
fn fit_fails_min_fit_when_the_model_lacks_a_reference_channel() {
    let w = Workspace::new();
    // The fixture without its angle column (the sixth).
    let b = w.write("noangle.csv", &fixture_edited(|h| h.to_owned(), |i| i != 5));
    let r = bin()
        .args(["fit"])
        .arg(fixture("pulses_nominal.csv"))
        .arg(&b)
        .args(["--min-fit", "99.5"])
        .output()
        .unwrap();
    let (out, err) = (text(&r.stdout), text(&r.stderr));
    assert_eq!(r.status.code(), Some(1), "{out}\n{err}");
    assert!(
        out.contains("angle_deg: in the reference, not in the model"),
        "{out}"
    );
    assert!(err.contains("angle_deg: missing in the model"), "{err}");
    // Without --min-fit it still says so, and exits 0.
    let r = bin()
        .args(["fit"])
        .arg(fixture("pulses_nominal.csv"))
        .arg(&b)
        .output()
        .unwrap();
    assert_eq!(r.status.code(), Some(0));
    assert!(text(&r.stdout).contains("not compared"));
}

/// A time column in ms under `t_s` is named as such (it used to run as a 1000 times slower
/// recording).
#[test]
fn a_recording_time_column_in_ms_is_refused() {
    let w = Workspace::new();
    let text = std::fs::read_to_string(fixture("pulses_nominal.csv")).unwrap();
    let ms: String = text
        .lines()
        .map(|l| match l.split_once(',') {
            Some((t, rest)) if t.parse::<f64>().is_ok() => {
                format!("{},{rest}\n", t.parse::<f64>().unwrap() * 1e3)
            }
            _ => format!("{l}\n"),
        })
        .collect();
    w.write("ms.csv", &ms);
    w.refuses(
        "fit {fixture} {w}/ms.csv",
        &[
            "ms.csv:6",
            "t_s",
            "median time step is 1 s",
            "ms written as s",
        ],
    );
}

/// Muscle 1 and 2 swapped in a torque recording (p1/p2 wired the other way) flips the sign of
/// B, which fits as well: refused by `identify torque` and so by `calibrate`, instead of a
/// torque model that drives the joint the wrong way.
#[test]
fn a_torque_recording_with_the_muscles_swapped_is_refused() {
    let w = Workspace::new();
    let rec = w.p("rec.csv");
    ok(&bin()
        .args(["sweep", "torque", "--plant"])
        .arg(plant())
        .arg("--out")
        .arg(&rec)
        .output()
        .unwrap());
    let text = std::fs::read_to_string(&rec).unwrap();
    let mut header_done = false;
    let swapped: String = text
        .lines()
        .map(|l| {
            if !header_done && !l.starts_with('#') {
                header_done = true;
                format!(
                    "{}\n",
                    l.replace("p1_kpa", "P_TMP")
                        .replace("p2_kpa", "p1_kpa")
                        .replace("P_TMP", "p2_kpa")
                )
            } else {
                format!("{l}\n")
            }
        })
        .collect();
    w.write("swap.csv", &swapped);
    w.refuses(
        "identify torque --recording {w}/swap.csv --plant {plant} --out {w}/out.toml",
        &[
            "swap.csv",
            "opposite sign of the plant's muscles",
            "swapped",
        ],
    );
}

/// A config file calibrate replaces that does not parse is named, nothing written: it keeps
/// the muscle's pressure rating from plant_constants.toml, which a typo elsewhere in the file
/// used to reset to 600 kPa silently.
#[test]
fn calibrate_refuses_a_config_file_it_replaces_that_does_not_parse() {
    let w = Workspace::new();
    std::fs::create_dir(w.p("cfg")).unwrap();
    w.write(
        "cfg/plant_constants.toml",
        "[muscle]\np_max_gauge_pa = 400000.0   # our muscles: 4 bar\ninertia_kgm2 = 0.014 kg m^2\n",
    );
    w.refuses(
        "calibrate --recording {fixture} --plant {plant} --out-dir {w}/cfg",
        &[
            "plant_constants.toml:3",
            "does not parse",
            "p_max_gauge_pa",
            "nothing written",
        ],
    );
}

/// `tune` replaces --out at the end of a long run: an existing file there that is not a gains
/// file (a plant file picked by a completion slip) is refused before any work.
#[test]
fn tune_refuses_an_out_that_is_not_a_gains_file() {
    let w = Workspace::new();
    // A plant file host-sim wrote (`identify plant --out`): its, but of another kind.
    let text = std::fs::read_to_string(plant()).unwrap();
    w.write(
        "plant-copy.toml",
        &format!("# generator = host-sim (an earlier run)\n{text}"),
    );
    w.refuses(
        "tune --plant {plant} --out {w}/plant-copy.toml --warm-start",
        &["--out", "plant-copy.toml", "not a gains file"],
    );
}

/// One tension column without the other is named, not silently replaced by the force model.
#[test]
fn identify_torque_refuses_one_tension_column_without_the_other() {
    let w = Workspace::new();
    // The fixture without f2_n (its tenth column).
    w.write("onef.csv", &fixture_edited(|h| h.to_owned(), |i| i != 9));
    w.refuses(
        "identify torque --recording {w}/onef.csv --plant {plant} --out {w}/out.toml",
        &[
            "onef.csv",
            "f2_n",
            "while `f1_n` is there",
            "needs both tensions",
        ],
    );
}

#[test]
fn a_plant_file_and_a_recording_given_the_other_way_round_are_named_as_such() {
    let w = Workspace::new();
    let swapped = "are the plant file and the recording given the other way round?";
    for line in [
        "diagnose --plant {fixture} --recording {plant} --json {w}/out.json",
        "identify plant --plant {fixture} --recording {plant} --params joint.inertia_kgm2 --out {w}/P.toml",
        "simulate --plant {fixture} --inputs {plant} --out {w}/out.csv",
    ] {
        // Whichever file the command reads first is named with the hint.
        w.refuses(line, &[swapped]);
    }
    // The recording side given the plant file: named as a TOML file.
    w.refuses(
        "identify plant --plant {plant} --recording {plant} --params joint.inertia_kgm2 --out {w}/P.toml",
        &["reference-1dof.toml", "this is a TOML file", swapped],
    );
}
