//! `host-sim calibrate` on a recording made through the plant (`host-sim sweep torque`) into a
//! temporary config directory: the torque model, joint geometry and plant constants are
//! written with what changed, with exactly the keys the firmware's build.rs reads from the
//! repository's config/; degenerate recordings (a joint that does not move, pressures above the
//! supply, pure noise in the tensions) are refused with exit status 2 and leave the directory
//! untouched.

mod common;
use common::*;

use std::ffi::OsStr;
use std::path::Path;
use std::process::Output;

/// `host-sim calibrate --recording <rec> --plant <plant> --out-dir <dir> <extra>`.
fn calibrate_with(rec: &Path, plant: &Path, dir: &Path, extra: &[&dyn AsRef<OsStr>]) -> Output {
    let mut c = bin();
    c.arg("calibrate").arg("--recording").arg(rec);
    c.arg("--plant").arg(plant).arg("--out-dir").arg(dir);
    c.args(extra).output().unwrap()
}

/// [`calibrate_with`] on the reference plant, nothing more.
fn calibrate(rec: &Path, dir: &Path) -> Output {
    calibrate_with(rec, &plant(), dir, &[])
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
        // The sweep's +-20 degrees logged in radians: said as a likely unit slip.
        (
            "angle_deg",
            Box::new(|_: usize, v: f64| v.to_radians()),
            "or it is logged in radians",
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

    // Data that fits eq. 11 as well as the good recording but would make the firmware push
    // the joint away, or run it an atmosphere too high: the angle logged the other way round,
    // and both pressures logged absolute (the tensions are the gauge pressures' ones).
    edit_column(&rec, &bad, "angle_deg", |_, v| -v);
    let flipped = bad.clone();
    let absolute = dir.path().join("absolute.csv");
    edit_column(&rec, &absolute, "p1_kpa", |_, v| v + 101.325);
    edit_column(&absolute, &absolute, "p2_kpa", |_, v| v + 101.325);
    for (rec, want) in [
        (&flipped, "the encoder's direction"),
        (&absolute, "the pressures look absolute"),
    ] {
        let r = calibrate(rec, &cfg);
        let err = text(&r.stderr);
        assert_eq!(r.status.code(), Some(2), "{want}: {err}");
        assert!(
            err.contains(want) && err.contains("nothing written"),
            "{err}"
        );
        assert_eq!(std::fs::read_dir(&cfg).unwrap().count(), 0, "{want}");
    }

    // A good recording: the three files are written and reported as new; a second run
    // reports every constant unchanged.
    let r = calibrate(&rec, &cfg);
    assert!(
        !text(&r.stderr).contains("recorded on plant"),
        "{}",
        text(&r.stderr)
    );
    let out = ok(&r);
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
    let out = ok(&calibrate(&rec, &cfg));
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
    let r = calibrate_with(&rec, &heavy, &cfg, &[]);
    // The recording names the plant it was made on: another file given is said first.
    let err = text(&r.stderr);
    assert!(
        err.contains("rec.csv was recorded on plant `")
            && err.contains(
                "reference-1dof.toml`, calibrating with the geometry, supply and valve of"
            )
            && err.contains("heavy.toml"),
        "{err}"
    );
    let out = ok(&r);
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

#[test]
fn calibrate_identifies_two_mis_set_plant_keys_before_the_firmware_constants() {
    // The truth: the reference plant. The user's plant file: inertia 1.5x, valve conductance
    // 0.7x. A valve-driven recording of the true plant (the firmware in the loop on random
    // set-points) identifies both; the torque sweep gives the torque model as before.
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("config");
    std::fs::create_dir(&cfg).unwrap();
    let sweep = dir.path().join("sweep.csv");
    let valves = dir.path().join("valves.csv");
    let r = host_sim(&[&"sweep", &"torque", &"--plant", &plant(), &"--out", &sweep]);
    assert!(r.status.success(), "{}", text(&r.stderr));
    let scenario = root().join("scenarios/random.toml");
    let r = on_plant(
        "simulate",
        &plant(),
        &[&"--scenario", &scenario, &"--out", &valves],
    );
    assert!(r.status.success(), "{}", text(&r.stderr));
    let truth = std::fs::read_to_string(plant()).unwrap();
    let mis = truth
        .replace("inertia_kgm2 = 0.014 ", "inertia_kgm2 = 0.021 ")
        .replace(
            "sonic_conductance_m3_per_s_pa = 8.0e-9 ",
            "sonic_conductance_m3_per_s_pa = 5.6e-9 ",
        );
    assert_ne!(mis, truth, "the reference plant file's key lines changed");
    let mis_path = dir.path().join("mis.toml");
    std::fs::write(&mis_path, &mis).unwrap();
    // Calibrate on the torque sweep with the mis-set plant, identifying `keys` of it on the
    // valve recording.
    let calibrate_identifying = |keys: &str, out_dir: &Path| {
        let extra: [&dyn AsRef<OsStr>; 4] =
            [&"--identify-plant", &keys, &"--plant-recording", &valves];
        calibrate_with(&sweep, &mis_path, out_dir, &extra)
    };
    let out = ok(&calibrate_identifying(
        "joint.inertia_kgm2,valve.sonic_conductance_m3_per_s_pa",
        &cfg,
    ));
    println!("{out}");
    assert!(
        out.contains("joint.inertia_kgm2: 2.1e-2 -> 1.3999"),
        "{out}"
    );
    assert!(
        out.contains("valve.sonic_conductance_m3_per_s_pa: 5.6e-9 -> 8.0000"),
        "{out}"
    );
    // The identified plant file is written beside the config and feeds the constants.
    let identified: toml::Table = std::fs::read_to_string(cfg.join("plant_identified.toml"))
        .unwrap()
        .parse()
        .unwrap();
    let inertia = identified["joint"]["inertia_kgm2"].as_float().unwrap();
    assert!((inertia / 0.014 - 1.0).abs() < 1e-3, "{inertia}");
    let constants: toml::Table = std::fs::read_to_string(cfg.join("plant_constants.toml"))
        .unwrap()
        .parse()
        .unwrap();
    let c = constants["valve"]["sonic_conductance_m3_per_s_pa"]
        .as_float()
        .unwrap();
    assert!((c / 8.0e-9 - 1.0).abs() < 1e-3, "{c}");
    // No temporary plant file is left behind.
    let names: Vec<String> = std::fs::read_dir(&cfg)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(names.iter().all(|n| !n.starts_with('.')), "{names:?}");

    // A key the plant file does not have: refused, nothing written.
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    let r = calibrate_identifying("joint.no_such_key", &empty);
    assert_eq!(r.status.code(), Some(2), "{}", text(&r.stderr));
    assert!(
        text(&r.stderr).contains("joint.no_such_key"),
        "{}",
        text(&r.stderr)
    );
    assert_eq!(std::fs::read_dir(&empty).unwrap().count(), 0);
}
