//! `host-sim calibrate` on a recording made through the plant (`host-sim sweep torque`) into a
//! temporary config directory: the torque model, joint geometry and plant constants are
//! written with what changed, with exactly the keys the firmware's build.rs reads from the
//! repository's config/; degenerate recordings (a joint that does not move, pressures above the
//! supply, pure noise in the tensions) are refused with exit status 2 and leave the directory
//! untouched.

mod common;
use common::*;

use std::path::Path;
use std::process::Output;

fn calibrate(rec: &Path, dir: &Path) -> Output {
    host_sim(&[
        &"calibrate",
        &"--recording",
        &rec,
        &"--plant",
        &plant(),
        &"--out-dir",
        &dir,
    ])
}

/// Rewrites one column of a recording with `f(row index, old value)`.
fn edit_column(src: &Path, dst: &Path, col: &str, f: impl Fn(usize, f64) -> f64) {
    let text = std::fs::read_to_string(src).unwrap();
    let mut out = String::new();
    let mut idx = None;
    let mut row = 0;
    for line in text.lines() {
        if line.starts_with('#') || line.trim().is_empty() {
            out += line;
        } else if idx.is_none() {
            idx = line.split(',').position(|h| h.trim() == col);
            assert!(idx.is_some(), "no column {col}");
            out += line;
        } else {
            let mut fields: Vec<String> = line.split(',').map(String::from).collect();
            let i = idx.unwrap();
            let v: f64 = fields[i].trim().parse().unwrap();
            fields[i] = format!("{:.6}", f(row, v));
            row += 1;
            out += &fields.join(",");
        }
        out.push('\n');
    }
    std::fs::write(dst, out).unwrap();
}

#[test]
fn calibrate_writes_the_torque_model_and_refuses_degenerate_data() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("rec.csv");
    let cfg = dir.path().join("config");
    std::fs::create_dir(&cfg).unwrap();
    let r = host_sim(&[&"sweep", &"torque", &"--plant", &plant(), &"--out", &rec]);
    assert!(r.status.success(), "{}", text(&r.stderr));

    // Degenerate recordings: nothing is written.
    let bad = dir.path().join("bad.csv");
    for (col, f, want) in [
        (
            "angle_deg",
            Box::new(|_: usize, _: f64| 3.0) as Box<dyn Fn(usize, f64) -> f64>,
            "angle_deg is constant",
        ),
        ("p1_kpa", Box::new(|_, v| v + 700.0), "above the supply"),
        (
            "f1_n",
            Box::new(|i, _| ((i * 7919) % 1000) as f64),
            "torque model fits the data",
        ),
    ] {
        edit_column(&rec, &bad, col, f);
        let r = calibrate(&bad, &cfg);
        assert_eq!(r.status.code(), Some(2), "{col}: {}", text(&r.stdout));
        let err = text(&r.stderr);
        assert!(
            err.contains(want) && err.contains("nothing written"),
            "{col}: {err}"
        );
        assert_eq!(
            std::fs::read_dir(&cfg).unwrap().count(),
            0,
            "{col}: wrote a file"
        );
    }

    // A good recording: the three files are written and reported as new; a second run
    // reports every constant unchanged.
    let r = calibrate(&rec, &cfg);
    let out = text(&r.stdout);
    assert!(r.status.success(), "{out}\n{}", text(&r.stderr));
    assert!(
        out.contains("torque_model.b_m2") && out.contains("(new)"),
        "{out}"
    );
    let written = std::fs::read_to_string(cfg.join("torque_model.toml")).unwrap();
    assert!(written.contains("[torque_model]") && written.contains("# Data ("));
    // The firmware's build reads these files with deny_unknown_fields: the written files must
    // have the same tables and keys as the repository's.
    let repo_config = root().join("config");
    for name in [
        "torque_model.toml",
        "joint_geometry.toml",
        "plant_constants.toml",
    ] {
        let ours = keys(&cfg.join(name));
        let repo = keys(&repo_config.join(name));
        assert_eq!(ours, repo, "{name}: keys differ from config/{name}");
    }
    // The reference plant's geometry and inertia, as the firmware's config has them.
    let geo: toml::Table = std::fs::read_to_string(cfg.join("joint_geometry.toml"))
        .unwrap()
        .parse()
        .unwrap();
    assert_eq!(
        geo["joint_geometry"]["rest_length_m"].as_float(),
        Some(0.25)
    );
    let r = calibrate(&rec, &cfg);
    let out = text(&r.stdout);
    assert!(r.status.success(), "{out}\n{}", text(&r.stderr));
    assert!(
        out.contains("b_m2 = ") && out.contains("(unchanged)"),
        "{out}"
    );
    assert!(!out.contains(" -> ") && !out.contains("(new)"), "{out}");

    // A changed plant: the inertia change is reported old -> new.
    let heavy = dir.path().join("heavy.toml");
    let p = std::fs::read_to_string(plant()).unwrap();
    assert!(p.contains("inertia_kgm2 = 0.014"));
    std::fs::write(
        &heavy,
        p.replace("inertia_kgm2 = 0.014", "inertia_kgm2 = 0.154"),
    )
    .unwrap();
    let r = host_sim(&[
        &"calibrate",
        &"--recording",
        &rec,
        &"--plant",
        &heavy,
        &"--out-dir",
        &cfg,
    ]);
    let out = text(&r.stdout);
    assert!(r.status.success(), "{out}\n{}", text(&r.stderr));
    assert!(
        out.contains("joint.inertia_kgm2: 1.4e-2 -> 1.54e-1"),
        "{out}"
    );
}

/// `table.key` names of a TOML file (arrays as one key).
fn keys(path: &Path) -> Vec<String> {
    let t: toml::Table = std::fs::read_to_string(path).unwrap().parse().unwrap();
    let mut k: Vec<String> = t
        .iter()
        .flat_map(|(name, v)| {
            v.as_table()
                .unwrap()
                .keys()
                .map(move |k| format!("{name}.{k}"))
        })
        .collect();
    k.sort();
    k
}

/// `--identify-plant`: the joint was built with two keys other than the plant file says
/// (muscle damping 3.0e-4 instead of 2.0e-4, valve conductance 6.5e-9 instead of 8.0e-9). The
/// recordings (a valve-driven one for the plant keys, a torque sweep for the torque model) come
/// from that plant; calibrate starts from the reference plant file, identifies the two keys,
/// writes plant_identified.toml beside the constants, prints old -> new, and the constants
/// (plant_constants.toml's conductance) come from the identified plant.
#[test]
fn calibrate_identifies_the_plant_first_when_asked() {
    let dir = tempfile::tempdir().unwrap();
    let mut text = std::fs::read_to_string(plant()).unwrap();
    for (from, to) in [
        ("damping_m2s = 2.0e-4", "damping_m2s = 3.0e-4"),
        (
            "sonic_conductance_m3_per_s_pa = 8.0e-9",
            "sonic_conductance_m3_per_s_pa = 6.5e-9",
        ),
    ] {
        assert!(text.contains(from), "{from}");
        text = text.replacen(from, to, 1);
    }
    let truth = dir.path().join("truth.toml");
    std::fs::write(&truth, text).unwrap();
    let valves = dir.path().join("valves.csv");
    ok(&host_sim(&[
        &"simulate",
        &"--plant",
        &truth,
        &"--inputs",
        &fixture("pulses_nominal.csv"),
        &"--out",
        &valves,
    ]));
    let rec = dir.path().join("rec.csv");
    ok(&host_sim(&[&"sweep", &"torque", &"--plant", &truth, &"--out", &rec]));
    let cfg = dir.path().join("config");
    std::fs::create_dir(&cfg).unwrap();
    let s = ok(&host_sim(&[
        &"calibrate",
        &"--recording",
        &rec,
        &"--plant",
        &plant(),
        &"--out-dir",
        &cfg,
        &"--identify-plant",
        &"muscle.damping_m2s,valve.sonic_conductance_m3_per_s_pa",
        &"--valve-recording",
        &valves,
    ]));
    println!("{s}");
    assert!(s.contains("muscle.damping_m2s: 2e-4 -> "), "{s}");
    assert!(
        s.contains("valve.sonic_conductance_m3_per_s_pa: 8e-9 -> "),
        "{s}"
    );
    let fitted = host_sim::PlantConfig::load(cfg.join("plant_identified.toml")).unwrap();
    assert!((fitted.muscle.damping_m2s / 3.0e-4 - 1.0).abs() < 0.01, "{fitted:?}");
    let c = fitted.valve.sonic_conductance_m3_per_s_pa;
    assert!((c / 6.5e-9 - 1.0).abs() < 0.01, "{c}");
    // The firmware's valve constant is the identified one, and the headers name the file.
    let constants = std::fs::read_to_string(cfg.join("plant_constants.toml")).unwrap();
    let line = constants
        .lines()
        .find(|l| l.starts_with("sonic_conductance_m3_per_s_pa"))
        .expect("conductance key");
    let written: f64 = line.split('=').nth(1).unwrap().trim().parse().unwrap();
    assert!((written / 6.5e-9 - 1.0).abs() < 0.01, "{line}");
    assert!(constants.contains("plant_identified.toml"), "{constants}");
    // An unknown key: exit 2, nothing written.
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    let e = run_exits(
        2,
        &[
            &"calibrate",
            &"--recording",
            &rec,
            &"--plant",
            &plant(),
            &"--out-dir",
            &empty,
            &"--identify-plant",
            &"muscle.no_such_key",
            &"--valve-recording",
            &valves,
        ],
    );
    assert!(e.contains("muscle.no_such_key"), "{e}");
    assert_eq!(std::fs::read_dir(&empty).unwrap().count(), 0);
}
