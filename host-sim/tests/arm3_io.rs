//! The 3-DOF arm's plant file errors, its 3-joint recording format, and
//! `host-sim simulate` dispatching on an arm plant file.

mod common;
use common::*;

use host_sim::io::arm3::{fits, Arm3Recording, PressureStepScenario};
use host_sim::plant::arm3::{is_arm3_file, Arm3, Arm3Config};
use host_sim::sim::SolverOptions;

fn seed_text() -> String {
    std::fs::read_to_string(arm3_plant()).unwrap()
}

fn load_err(text: &str) -> String {
    parse_error(text, |t| Arm3Config::from_toml_str(t, "bad-arm.toml"))
}

#[test]
fn unknown_key_is_an_error_naming_key_file_and_line() {
    let text = seed_text().replace("f_g2\n", "f_g2\nstiction_nm = 0.3\n");
    assert_ne!(text, seed_text());
    let e = load_err(&text);
    assert!(e.contains("bad-arm.toml"), "{e}");
    assert!(e.contains("stiction_nm"), "{e}");
    assert!(e.contains("line"), "{e}");
}

#[test]
fn missing_key_is_an_error_naming_key_and_file() {
    let text = seed_text().replace("com3_m = 0.1910", "");
    let e = load_err(&text);
    assert!(e.contains("bad-arm.toml") && e.contains("com3_m"), "{e}");
    let text = seed_text().replacen("coulomb_nm = 0.1956", "", 1);
    let e = load_err(&text);
    assert!(
        e.contains("bad-arm.toml") && e.contains("coulomb_nm"),
        "{e}"
    );
}

#[test]
fn invalid_values_name_the_full_key() {
    let e = load_err(&seed_text().replace("coulomb_nm = 0.1956", "coulomb_nm = -0.1956"));
    assert!(e.contains("joint2.friction.coulomb_nm"), "{e}");
    let e = load_err(&seed_text().replace("inertia_x3_kgm2 = 0.0661", "inertia_x3_kgm2 = 0.0"));
    assert!(e.contains("links.inertia_x3_kgm2"), "{e}");
    let e = load_err(&seed_text().replace("kind = \"arm3\"", "kind = \"arm2\""));
    assert!(e.contains("kind"), "{e}");
}

#[test]
fn plant_kind_is_recognised() {
    assert!(is_arm3_file(arm3_plant()).unwrap());
    let one_dof = plant();
    assert!(!is_arm3_file(one_dof).unwrap());
    // A misspelt kind is routed to the arm loader, which names it.
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("arm.toml");
    std::fs::write(
        &bad,
        seed_text().replace("kind = \"arm3\"", "kind = \"arm_3\""),
    )
    .unwrap();
    assert!(is_arm3_file(&bad).unwrap());
    let e = Arm3::load(&bad).unwrap_err().to_string();
    assert!(
        e.contains("arm.toml") && e.contains("kind") && e.contains("arm_3"),
        "{e}"
    );
}

fn short_run() -> (Arm3, Arm3Recording) {
    let arm = Arm3::load(arm3_plant()).unwrap();
    let sc = PressureStepScenario {
        switch_times_s: [0.1, 0.6, 0.7, 1.2],
        duration_s: 1.3,
        ..PressureStepScenario::seed001()
    };
    let (rec, _) = sc.run(&arm, &SolverOptions::default(), |_| {}).unwrap();
    (arm, rec)
}

#[test]
fn recording_round_trips_and_bad_files_name_file_line_field() {
    let (_, rec) = short_run();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.csv");
    rec.write(&path).unwrap();
    let back = Arm3Recording::read(&path).unwrap();
    assert_eq!(back.len(), rec.len());
    assert_eq!(back.inputs, rec.inputs);
    for (name, fit) in fits(&rec, &back) {
        assert!(fit > 99.999, "{name}: {fit}");
    }
    let text = std::fs::read_to_string(&path).unwrap();
    let header = text.lines().find(|l| !l.starts_with('#')).unwrap();
    assert!(header.starts_with(
        "t_s,u_in1_j1,u_ex1_j1,u_in2_j1,u_ex2_j1,u_in1_j2,u_ex1_j2,u_in2_j2,u_ex2_j2,u_in1_j3"
    ));
    assert!(header.ends_with("angle_deg_j3,p1_kpa_j3,p2_kpa_j3,f1_n_j3,f2_n_j3"));

    // A missing valve column.
    let bad = text.replacen("u_ex2_j3", "u_ex2_x3", 1);
    let e = Arm3Recording::parse(&bad, "bad.csv")
        .unwrap_err()
        .to_string();
    assert!(e.contains("bad.csv") && e.contains("u_ex2_j3"), "{e}");
    // A non-number on a known line.
    let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
    let header_idx = lines.iter().position(|l| !l.starts_with('#')).unwrap();
    let mut fields: Vec<String> = lines[header_idx + 3]
        .split(',')
        .map(str::to_owned)
        .collect();
    fields[5] = "open".into(); // u_in1_j2
    lines[header_idx + 3] = fields.join(",");
    let e = Arm3Recording::parse(&lines.join("\n"), "bad.csv")
        .unwrap_err()
        .to_string();
    assert!(e.contains(&format!("bad.csv:{}", header_idx + 4)), "{e}");
    assert!(e.contains("u_in1_j2"), "{e}");
    // A declared sample period that the time column contradicts.
    let e = Arm3Recording::parse(
        &text.replacen("sample_period_s = 0.001", "sample_period_s = 0.002", 1),
        "bad.csv",
    )
    .unwrap_err()
    .to_string();
    let period_line = 1 + text
        .lines()
        .position(|l| l.contains("sample_period_s = 0.001"))
        .unwrap();
    assert!(
        e.contains(&format!("bad.csv:{period_line}")) && e.contains("sample_period_s"),
        "{e}"
    );
    // A valve opening out of range.
    fields[5] = "1.5".into();
    lines[header_idx + 3] = fields.join(",");
    let e = Arm3Recording::parse(&lines.join("\n"), "bad.csv")
        .unwrap_err()
        .to_string();
    assert!(e.contains("u_in1_j2") && e.contains("outside"), "{e}");
}

#[test]
fn cli_simulate_dispatches_on_an_arm_plant_and_reproduces_the_scenario() {
    let (_, rec) = short_run();
    let dir = tempfile::tempdir().unwrap();
    let inputs = dir.path().join("steps.csv");
    let out = dir.path().join("sim.csv");
    let plot = dir.path().join("sim.svg");
    rec.write(&inputs).unwrap();
    let r = on_plant(
        "simulate",
        &arm3_plant(),
        &[&"--inputs", &inputs, &"--out", &out, &"--plot", &plot],
    );
    let stdout = ok(&r);
    println!("{stdout}");
    let sim = Arm3Recording::read(&out).unwrap();
    // The stamps of the file it was given (written to the nanosecond: `rec`'s k * dt without
    // its float noise).
    let given = Arm3Recording::read(&inputs).unwrap();
    assert_eq!(sim.t_s, given.t_s);
    for (a, b) in given.t_s.iter().zip(&rec.t_s) {
        assert!((a - b).abs() <= 0.5e-9, "{a} vs {b}");
    }
    assert_eq!(sim.inputs, rec.inputs);
    let f = fits(&rec, &sim);
    assert_eq!(f.len(), 15);
    for (name, fit) in f {
        // The replay integrates runs of equal inputs as one segment, the scenario sample by
        // sample: equal to the integrator's tolerance.
        assert!(fit > 99.9, "{name}: {fit}");
    }
    assert!(std::fs::metadata(&plot).unwrap().len() > 1000);

    // A 1-DOF recording on the arm plant: the missing suffixed column is named.
    let one = dir.path().join("one.csv");
    std::fs::write(
        &one,
        "t_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg\n0,0,0,0,0,0\n0.1,0,0,0,0,1\n",
    )
    .unwrap();
    let x = dir.path().join("x.csv");
    let r = on_plant(
        "simulate",
        &arm3_plant(),
        &[&"--inputs", &one, &"--out", &x],
    );
    assert_refused(&r, &["one.csv:1", "u_in1_j1"], &x);
}
