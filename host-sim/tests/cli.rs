//! End-to-end: the built `host-sim` binary simulates a fixture and fits it.

mod common;
use common::*;

#[test]
fn simulate_then_fit_a_fixture() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("sim.csv");
    let plot = dir.path().join("sim.svg");
    let pulses = fixture("pulses_nominal.csv");
    let r = on_plant(
        "simulate",
        &fixture("reference-1dof.toml"),
        &[&"--inputs", &pulses, &"--out", &out, &"--plot", &plot],
    );
    ok(&r);
    let text = std::fs::read_to_string(&out).unwrap();
    let header = text.lines().find(|l| !l.starts_with('#')).unwrap();
    assert_eq!(
        header,
        "t_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg,p1_kpa,p2_kpa,f1_n,f2_n"
    );
    let rows = text.lines().filter(|l| !l.starts_with('#')).count() - 1;
    assert_eq!(rows, 20_000);
    assert!(std::fs::metadata(&plot).unwrap().len() > 1000);

    let stdout = run_ok(&[&"fit", &pulses, &out, &"--min-fit", &"99.5"]);
    println!("{stdout}");
    assert_channel_fits(&stdout, 99.5);
}

/// A segment cut from the middle of a run (as `capture --split` / `import --split` write
/// them: the joint moving, the pressures far from the plant file's [initial]) replays from
/// its own first sample, with a note; `--start file` replays from [initial] and departs.
#[test]
fn a_segment_cut_from_a_run_replays_from_its_first_sample() {
    use host_sim::{Channel, Recording};
    let dir = tempfile::tempdir().unwrap();
    let full = Recording::read(fixture("pulses_nominal.csv")).unwrap();
    let k0 = full.t_s.iter().position(|t| *t >= 7.3).unwrap();
    let mut tail = Recording {
        t_s: full.t_s[k0..].iter().map(|t| t - full.t_s[k0]).collect(),
        inputs: full.inputs[k0..].to_vec(),
        ..Recording::default()
    };
    for c in Channel::ALL {
        if let Some(y) = full.channel(c) {
            tail.set_channel(c, y[k0..].to_vec());
        }
    }
    let seg = dir.path().join("segment.csv");
    tail.write(&seg).unwrap();
    let fit_of = |start: &str| {
        let out = dir.path().join(format!("sim_{start}.csv"));
        let r = on_plant(
            "simulate",
            &fixture("reference-1dof.toml"),
            &[&"--inputs", &seg, &"--out", &out, &"--start", &start],
        );
        let err = String::from_utf8_lossy(&r.stderr).to_string();
        ok(&r);
        let stdout = run_ok(&[&"fit", &seg, &out]);
        (stdout, err)
    };
    let (auto, note) = fit_of("auto");
    assert!(
        note.contains("replayed from its first sample") && note.contains("initial.p1_gauge_pa"),
        "{note}"
    );
    assert_channel_fits(&auto, 99.5);
    let (file, note) = fit_of("file");
    assert!(!note.contains("first sample"), "{note}");
    let angle: f64 = file
        .lines()
        .find(|l| l.starts_with("angle_deg"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse().ok())
        .unwrap();
    assert!(angle < 50.0, "from [initial] the segment departs: {file}");
}

#[test]
fn fit_fails_with_status_1_below_min_fit() {
    let dir = tempfile::tempdir().unwrap();
    let a = dir.path().join("a.csv");
    let b = dir.path().join("b.csv");
    std::fs::write(
        &a,
        "t_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg\n0,0,0,0,0,0\n0.1,0,0,0,0,1\n0.2,0,0,0,0,2\n",
    )
    .unwrap();
    std::fs::write(
        &b,
        "t_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg\n0,0,0,0,0,0\n0.1,0,0,0,0,1\n0.2,0,0,0,0,1\n",
    )
    .unwrap();
    let r = host_sim(&[&"fit", &a, &b, &"--min-fit", &"99"]);
    assert_eq!(r.status.code(), Some(1));
}

#[test]
fn bad_input_is_reported_with_file_line_and_field_and_keeps_old_output() {
    let dir = tempfile::tempdir().unwrap();
    let inputs = dir.path().join("bad.csv");
    let out = previous_output(dir.path(), "out.csv");
    std::fs::write(
        &inputs,
        "t_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg\n0,0,0,0,0,0\n0.001,0,oops,0,0,0\n",
    )
    .unwrap();
    let r = on_plant(
        "simulate",
        &fixture("reference-1dof.toml"),
        &[&"--inputs", &inputs, &"--out", &out],
    );
    let err = exits(2, &r);
    for needle in ["bad.csv:3:", "`u_ex1`"] {
        assert!(err.contains(needle), "`{needle}` not in:\n{err}");
    }
    assert_kept(&out);
}

#[test]
fn scenario_needs_a_plant_and_a_readable_file() {
    let r = host_sim(&[
        &"simulate",
        &"--scenario",
        &"s.toml",
        &"--out",
        &"/tmp/never-written.csv",
    ]);
    assert_eq!(r.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&r.stderr).contains("--plant"));
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.toml");
    let r = on_plant(
        "simulate",
        &fixture("reference-1dof.toml"),
        &[&"--scenario", &missing, &"--out", &dir.path().join("o.csv")],
    );
    assert_eq!(r.status.code(), Some(2));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains(&missing.display().to_string()), "{err}");
    assert!(!dir.path().join("o.csv").exists());
}

#[test]
fn simulate_without_a_run_names_both_inputs_and_scenario() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.csv");
    let r = on_plant(
        "simulate",
        &fixture("reference-1dof.toml"),
        &[&"--out", &out],
    );
    let err = exits(2, &r);
    for needle in ["--inputs <REC.csv>", "--scenario <S.toml>"] {
        assert!(err.contains(needle), "`{needle}` not in:\n{err}");
    }
    // And one of them only.
    let r = on_plant(
        "simulate",
        &fixture("reference-1dof.toml"),
        &[
            &"--inputs",
            &fixture("pulses_nominal.csv"),
            &"--scenario",
            &root().join("scenarios/step.toml"),
            &"--out",
            &out,
        ],
    );
    let err = exits(2, &r);
    assert!(
        err.contains("--inputs")
            && err.contains("cannot be used with")
            && err.contains("--scenario"),
        "{err}"
    );
    assert!(!out.exists());
}

/// A `sweep torque` recording (prescribed motion, regulator-held pressures) says in its
/// `# source` that its valve columns are unused: a replay warns, naming the columns and the
/// line; a recording of valve openings replays without the warning.
#[test]
fn replaying_a_recording_whose_valve_columns_are_unused_warns() {
    let dir = tempfile::tempdir().unwrap();
    let swept = dir.path().join("torque.csv");
    ok(&bin()
        .args(["sweep", "torque", "--plant"])
        .arg(fixture("reference-1dof.toml"))
        .arg("--out")
        .arg(&swept)
        .args(["--dp-kpa", "0", "--speeds-rad-s", "4"])
        .output()
        .unwrap());
    let out = dir.path().join("sim.csv");
    let r = on_plant(
        "simulate",
        &fixture("reference-1dof.toml"),
        &[&"--inputs", &swept, &"--out", &out],
    );
    ok(&r);
    let err = text(&r.stderr);
    // The line of the `# source` comment (after host-sim's mark).
    let source_line = 1 + std::fs::read_to_string(&swept)
        .unwrap()
        .lines()
        .position(|l| l.starts_with("# source"))
        .unwrap();
    for needle in [
        format!("warning: {}:{source_line}:", swept.display()),
        "`# source` marks the valve columns unused".into(),
        "u_in1, u_ex1, u_in2, u_ex2 are replayed as recorded".into(),
    ] {
        assert!(err.contains(&needle), "`{needle}` not in:\n{err}");
    }
    let r = on_plant(
        "simulate",
        &fixture("reference-1dof.toml"),
        &[&"--inputs", &fixture("pulses_nominal.csv"), &"--out", &out],
    );
    ok(&r);
    assert!(!text(&r.stderr).contains("unused"), "{}", text(&r.stderr));
}

/// Every subcommand's help (found by walking `host-sim --help`, so a new one is covered) has
/// a usage example that starts with `host-sim <subcommand>`, and names the paper jargon only
/// with a plain-words gloss.
#[test]
fn every_subcommand_help_has_an_example_and_no_bare_jargon() {
    let top = run_ok(&[&"--help"]);
    let mut commands: Vec<Vec<String>> = Vec::new();
    let list = |help: &str| -> Vec<String> {
        help.split("Commands:")
            .nth(1)
            .map(|t| {
                t.lines()
                    .skip(1)
                    .take_while(|l| !l.trim().is_empty())
                    .filter_map(|l| l.split_whitespace().next())
                    .filter(|c| *c != "help")
                    .map(str::to_string)
                    .collect()
            })
            .unwrap_or_default()
    };
    for c in list(&top) {
        let help = run_ok(&[&c, &"--help"]);
        let subs = list(&help);
        if subs.is_empty() {
            commands.push(vec![c]);
        } else {
            // A command with subcommands: its own help or each subcommand's has the example.
            for s in subs {
                commands.push(vec![c.clone(), s]);
            }
        }
    }
    assert!(commands.len() >= 14, "{commands:?}");
    for cmd in &commands {
        let mut args: Vec<&dyn AsRef<std::ffi::OsStr>> = cmd.iter().map(|s| s as _).collect();
        args.push(&"--help");
        let help = run_ok(&args);
        let parent_help = run_ok(&[&cmd[0], &"--help"]);
        let example = format!("host-sim {}", cmd.join(" "));
        assert!(
            (help.contains("Example") && help.contains(&example))
                || (parent_help.contains("Example") && parent_help.contains(&example)),
            "`{example} --help` has no example:\n{help}"
        );
        // Paper references say which paper in plain words (the seeds' file numbers are no
        // gloss): an equation number comes with "paper" on its line or the line before.
        let lines: Vec<&str> = help.lines().collect();
        for (k, line) in lines.iter().enumerate() {
            assert!(
                !line.contains("seed 00"),
                "`{example} --help`: a seed number instead of the paper's name: {line}"
            );
            if line.contains("eq. ") {
                let before = if k > 0 { lines[k - 1] } else { "" };
                assert!(
                    line.contains("paper") || before.contains("paper"),
                    "`{example} --help`: an equation without its paper: {line}"
                );
            }
        }
    }
}
