//! End-to-end: `host-sim simulate --plant P --scenario S --out OUT [--plot F]` (closed loop,
//! firmware in the loop) through the built binary.

mod common;
use common::*;
use std::path::Path;
use std::process::Output;

use host_sim::control::run_files::FIRMWARE_COLUMNS;
use host_sim::io::recording::Recording;

fn simulate(scenario: &Path, out: &Path, extra: &[&str]) -> Output {
    bin()
        .arg("simulate")
        .arg("--plant")
        .arg(plant())
        .arg("--scenario")
        .arg(scenario)
        .arg("--out")
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

/// Data rows (after the comment lines and the header) of a CSV file.
fn data_rows(path: &Path) -> (String, Vec<String>) {
    let t = std::fs::read_to_string(path).unwrap();
    let mut lines = t.lines().filter(|l| !l.starts_with('#'));
    let header = lines.next().unwrap().to_owned();
    (header, lines.map(str::to_owned).collect())
}

#[test]
fn step_scenario_writes_recording_trace_plot_and_summary() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("step.csv");
    let plot = dir.path().join("step.png");
    let r = simulate(
        &root().join("scenarios/step.toml"),
        &out,
        &["--plot", plot.to_str().unwrap()],
    );
    let stdout = text(&r.stdout);
    assert!(r.status.success(), "{stdout}\n{}", text(&r.stderr));

    // The recording is RECORDING.md plus the plant's true mass flows (the optional
    // flow-sensor columns) and reads back; one row per 1 ms tick over 4 s.
    let (header, rows) = data_rows(&out);
    assert_eq!(
        header,
        "t_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg,p1_kpa,p2_kpa,f1_n,f2_n,m_dot_1_kg_s,m_dot_2_kg_s"
    );
    assert_eq!(rows.len(), 4000);
    let rec = Recording::read(&out).unwrap();
    assert!((rec.sample_period_s() - 1e-3).abs() < 1e-12);
    assert_eq!(rec.meta("firmware_trace"), Some("step.firmware.csv"));
    // The step to 0.2 rad (11.46 deg) is reached.
    let angle = rec.channel(host_sim::Channel::AngleDeg).unwrap();
    assert!(
        (angle[3999] - 0.2f64.to_degrees()).abs() < 0.5,
        "{}",
        angle[3999]
    );

    // Firmware trace: same ticks, set-point column steps at 1 s, no fault.
    let trace = dir.path().join("step.firmware.csv");
    let (theader, trows) = data_rows(&trace);
    assert_eq!(theader, FIRMWARE_COLUMNS.join(","));
    assert_eq!(trows.len(), rows.len());
    for (k, (a, b)) in rows.iter().zip(&trows).enumerate() {
        assert_eq!(a.split(',').next(), b.split(',').next(), "t_s of row {k}");
        let f: Vec<&str> = b.split(',').collect();
        assert_eq!(f[6], "0", "fault code at row {k}");
        let sp: f64 = f[1].parse().unwrap();
        let want = if k < 1000 { 0.0 } else { 0.2f64.to_degrees() };
        assert!((sp - want).abs() < 1e-4, "set-point at row {k}: {sp}");
    }
    assert!(std::fs::metadata(&plot).unwrap().len() > 10_000);

    // Summary on stdout: whole run and after the settle time, faults, verdict.
    assert!(stdout.contains("scenario step: 4000 ticks"), "{stdout}");
    assert!(stdout.contains("angle error after 2 s: rms"), "{stdout}");
    assert!(stdout.contains("faults: none"), "{stdout}");
    assert!(stdout.contains("expectations: met"), "{stdout}");
}

#[test]
fn injected_nan_reports_the_fault_tick_and_time() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("nan.csv");
    let r = simulate(&root().join("scenarios/sensor_nan.toml"), &out, &[]);
    let stdout = text(&r.stdout);
    assert!(r.status.success(), "{stdout}\n{}", text(&r.stderr));
    // NaN on p2 from 1.5 s: latched in that very tick.
    assert!(
        stdout.contains("fault PressureInvalid2 (code 2) latched at tick 1500 (t = 1.500 s)"),
        "{stdout}"
    );
    let (_, trows) = data_rows(&dir.path().join("nan.firmware.csv"));
    assert!(trows[1499].split(',').nth(6) == Some("0"));
    assert!(trows[1500].split(',').nth(6) == Some("2"));
}

#[test]
fn an_error_bound_with_every_tick_faulted_is_not_met() {
    // NaN on p1 before the settle time, no `no_fault`: the fault stays latched, so no tick
    // is left to bound the error; that must not read as "met".
    let dir = tempfile::tempdir().unwrap();
    let s = dir.path().join("faulted.toml");
    std::fs::write(
        &s,
        "[scenario]\nname = \"faulted\"\nduration_s = 2.0\n\n[setpoint]\nkind = \"step\"\n\
initial_rad = 0.0\nfinal_rad = 0.2\nat_s = 0.5\n\n[[events]]\nkind = \"sensor_nan\"\nat_s = 0.1\n\
duration_s = 0.01\nchannel = \"p1\"\n\n[expect]\nsettle_after_s = 1.0\nmax_abs_error_rad = 0.01\n",
    )
    .unwrap();
    let r = simulate(&s, &dir.path().join("f.csv"), &[]);
    let stdout = text(&r.stdout);
    assert_eq!(r.status.code(), Some(1), "{stdout}\n{}", text(&r.stderr));
    assert!(
        stdout.contains("no tick without a latched fault after 1 s to bound the angle error")
            && stdout.contains("(fault PressureInvalid1, code 1, latched at tick 100)")
            && !stdout.contains("Some("),
        "{stdout}"
    );
    assert!(!stdout.contains("expectations: met"), "{stdout}");
}

#[test]
fn a_late_fault_is_said_in_ticks_not_in_debug_notation() {
    let dir = tempfile::tempdir().unwrap();
    let s = dir.path().join("late.toml");
    let dropout = std::fs::read_to_string(root().join("scenarios/sensor_dropout.toml")).unwrap();
    assert!(dropout.contains("fault_within_ticks = 11"));
    std::fs::write(
        &s,
        dropout.replace("fault_within_ticks = 11", "fault_within_ticks = 0"),
    )
    .unwrap();
    let r = simulate(&s, &dir.path().join("o.csv"), &[]);
    let stdout = text(&r.stdout);
    assert_eq!(r.status.code(), Some(1), "{stdout}\n{}", text(&r.stderr));
    assert!(
        stdout.contains("fault latched at tick 1210, 10 ticks after the injection of its cause (injected at tick 1200): not within 0 ticks")
            && !stdout.contains("Some("),
        "{stdout}"
    );
}

#[test]
fn unmet_expectation_exits_with_status_1_and_says_why() {
    let dir = tempfile::tempdir().unwrap();
    let s = dir.path().join("tight.toml");
    let step = std::fs::read_to_string(root().join("scenarios/step.toml")).unwrap();
    std::fs::write(
        &s,
        step.replace("max_abs_error_rad = 0.01", "max_abs_error_rad = 0.00001"),
    )
    .unwrap();
    let r = simulate(&s, &dir.path().join("o.csv"), &[]);
    assert_eq!(r.status.code(), Some(1), "{}", text(&r.stderr));
    assert!(
        text(&r.stdout).contains("expectation not met: max |angle error|"),
        "{}",
        text(&r.stdout)
    );
    assert!(dir.path().join("o.csv").exists());
}

#[test]
fn bad_scenario_names_file_line_and_key_and_keeps_the_old_output() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.csv");
    std::fs::write(
        &out,
        "# generator = host-sim (an earlier run)\n# good old file\nt_s,u_in1\n0,0\n",
    )
    .unwrap();
    let step = std::fs::read_to_string(root().join("scenarios/step.toml")).unwrap();
    let cases = [
        // (replace, with, expected fragments)
        (
            "duration_s = 4.0",
            "duration_s = -4.0",
            vec!["line 4", "[scenario] duration_s", "must be > 0"],
        ),
        (
            "at_s = 1.0",
            "at_s = 1.0\nat_z = 2.0",
            vec!["line 13: key `at_z`", "unknown field", "at_z"],
        ),
        (
            "at_s = 1.0",
            "at_s = \"1.0\"",
            vec![
                "line 12: key `at_s`",
                "a number is expected",
                "remove the quotes",
            ],
        ),
        (
            "pressure_noise_pa = 500.0",
            "pressure_noise_pa = -1.0",
            vec!["line 15", "[sensors] pressure_noise_pa"],
        ),
        (
            "kind = \"step\"",
            "kind = \"stepp\"",
            vec!["line 9", "unknown variant", "stepp"],
        ),
        // Beyond the firmware's set-point limit (within half a turn): its line too, and the
        // limit to give.
        (
            "final_rad = 0.2",
            "final_rad = 2.0",
            vec![
                "line 11: [setpoint] final_rad",
                "2 rad is beyond the firmware's set-point limit of +-0.8 rad",
                "give at most 0.8 rad",
            ],
        ),
        // A move that ends after the run (milliseconds typed into a seconds key): the run
        // would cover a sliver of it and still meet its bounds.
        (
            "at_s = 1.0",
            "at_s = 1.0\ntransition_s = 150",
            vec![
                "line 13: [setpoint] transition_s",
                "ends at 151 s, after the end of the run",
                "cover 2.0 % of it",
            ],
        ),
        // Degrees typed into an angle bound, and an encoder coarser than a count a degree.
        (
            "max_abs_error_rad = 0.01",
            "max_abs_error_rad = 57.0",
            vec!["line 20: [expect] max_abs_error_rad", "within (0, pi]"],
        ),
        (
            "max_abs_error_rad = 0.01",
            "angle_within_rad = 57.0",
            vec![
                "line 20: [expect] angle_within_rad",
                "degrees typed as radians?",
            ],
        ),
        (
            "angle_counts_per_rev = 8000",
            "angle_counts_per_rev = 3",
            vec!["line 16: [sensors] angle_counts_per_rev", ">= 360"],
        ),
    ];
    for (from, to, want) in cases {
        let s = dir.path().join("bad.toml");
        assert!(step.contains(from));
        std::fs::write(&s, step.replace(from, to)).unwrap();
        let r = simulate(&s, &out, &[]);
        let err = text(&r.stderr);
        assert_eq!(r.status.code(), Some(2), "{to}: {err}");
        assert!(err.contains(&s.display().to_string()), "{err}");
        for w in want {
            assert!(err.contains(w), "{to}: expected {w:?} in {err}");
        }
        assert_eq!(
            std::fs::read_to_string(&out).unwrap(),
            "# generator = host-sim (an earlier run)\n# good old file\nt_s,u_in1\n0,0\n"
        );
    }
    // A bad event names its [[events]] entry and line.
    let s = dir.path().join("ev.toml");
    std::fs::write(
        &s,
        format!("{step}\n[[events]]\nkind = \"sensor_nan\"\nat_s = 1.0\nduration_s = 0.0\nchannel = \"p1\"\n"),
    )
    .unwrap();
    let r = simulate(&s, &out, &[]);
    let err = text(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert!(err.contains("[[events]] #1 duration_s"), "{err}");
    let line = step.lines().count() + 5;
    assert!(err.contains(&format!("line {line}:")), "{err}");
    // A ramp that ends after the run.
    let ramp = std::fs::read_to_string(root().join("scenarios/ramp.toml")).unwrap();
    let s = dir.path().join("ramp.toml");
    std::fs::write(&s, ramp.replace("end_s = 4.0", "end_s = 40.0")).unwrap();
    let r = simulate(&s, &out, &[]);
    let err = text(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert!(
        err.contains("[setpoint] end_s") && err.contains("ends at 40 s, after the end of the run"),
        "{err}"
    );
}

#[test]
fn replay_only_options_are_refused_with_a_scenario() {
    // The integrator tolerances and the replay's start belong to an --inputs replay: with a
    // closed-loop scenario they would be ignored without a word.
    let dir = tempfile::tempdir().unwrap();
    let step = root().join("scenarios/step.toml");
    for extra in [
        ["--rtol", "0.1"],
        ["--atol", "1e-3"],
        ["--start", "recording"],
    ] {
        let r = simulate(&step, &dir.path().join("o.csv"), &extra);
        let err = text(&r.stderr);
        assert_eq!(r.status.code(), Some(2), "{extra:?}: {err}");
        assert!(
            err.contains("cannot be used with") && err.contains(extra[0]),
            "{extra:?}: {err}"
        );
        assert!(!dir.path().join("o.csv").exists());
    }
}

#[test]
fn a_misspelt_choice_in_an_event_or_the_setpoint_names_its_own_line() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.csv");
    let dropout = std::fs::read_to_string(root().join("scenarios/sensor_dropout.toml")).unwrap();
    let step = std::fs::read_to_string(root().join("scenarios/step.toml")).unwrap();
    for (name, text, typo, key) in [
        (
            "channel.toml",
            dropout.replace("channel = \"angle\"", "channel = \"p9\""),
            "p9",
            "channel",
        ),
        (
            "event_kind.toml",
            dropout.replace("kind = \"sensor_dropout\"", "kind = \"dropout\""),
            "dropout",
            "kind",
        ),
        (
            "step_kind.toml",
            step.replace("kind = \"step\"", "kind = \"stp\""),
            "stp",
            "kind",
        ),
    ] {
        let line = 1 + text
            .lines()
            .position(|l| l.contains(&format!("\"{typo}\"")))
            .unwrap();
        let s = dir.path().join(name);
        std::fs::write(&s, &text).unwrap();
        let r = simulate(&s, &out, &[]);
        assert_refused(
            &r,
            &[
                name,
                &format!("line {line}: key `{key}`: unknown variant `{typo}`"),
            ],
            &out,
        );
    }
}
