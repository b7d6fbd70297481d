//! The trust gates of `host-sim identify torque|force|plant`: a model below the fit
//! `calibrate` requires, or data in the wrong unit, is refused with status 2, the values
//! named and nothing written (an earlier output kept); the override writes it. The data comes
//! from the plant's own generators (`sweep torque`, `sweep force`), not from the fitters.

mod common;

use common::*;
use std::path::{Path, PathBuf};

/// `sweep <what> --plant <reference> --out <out>` followed by `extra`.
fn sweep_to(what: &str, out: &Path, extra: &[&str]) -> std::process::Output {
    let mut c = bin();
    c.args(["sweep", what, "--plant"])
        .arg(plant())
        .arg("--out")
        .arg(out);
    c.args(extra).output().unwrap()
}

/// `sweep <what> --plant <reference> --out dir/name`, which must succeed; its output.
fn sweep(what: &str, dir: &Path, name: &str) -> PathBuf {
    let out = dir.join(name);
    ok(&sweep_to(what, &out, &[]));
    out
}

/// A `sweep <what>` in `dir` with its `col` column mapped by `f`, written to `dir/name`: its
/// path and the 1-based line of its first data row (after the comments and the header).
fn mapped_sweep(
    what: &str,
    dir: &Path,
    name: &str,
    col: &str,
    f: impl Fn(f64) -> f64,
) -> (PathBuf, usize) {
    let good = sweep(what, dir, &format!("good-{name}"));
    let text = map_column(&good, col, f);
    let path = dir.join(name);
    std::fs::write(&path, &text).unwrap();
    (
        path,
        text.lines().position(|l| !l.starts_with('#')).unwrap() + 2,
    )
}

/// The data lines of a CSV with the `col` column mapped by `f` (comments and header kept).
fn map_column(path: &Path, col: &str, f: impl Fn(f64) -> f64) -> String {
    let text = std::fs::read_to_string(path).unwrap();
    let header = text
        .lines()
        .find(|l| !l.starts_with('#'))
        .unwrap()
        .to_string();
    let i = header.split(',').position(|c| c == col).unwrap();
    text.lines()
        .map(|l| {
            if l.starts_with('#') || l == header {
                return format!("{l}\n");
            }
            let mut v: Vec<String> = l.split(',').map(str::to_string).collect();
            v[i] = format!("{}", f(v[i].parse::<f64>().unwrap()));
            format!("{}\n", v.join(","))
        })
        .collect()
}

fn identify_torque(rec: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    let p = plant();
    let mut args: Vec<&dyn AsRef<std::ffi::OsStr>> = vec![
        &"identify",
        &"torque",
        &"--recording",
        &rec,
        &"--plant",
        &p,
        &"--out",
        &out,
    ];
    for e in extra {
        args.push(e);
    }
    host_sim(&args)
}

#[test]
fn identify_torque_refuses_a_fit_below_the_calibrate_gate_and_keeps_the_old_file() {
    let dir = tempfile::tempdir().unwrap();
    // A load cell with 200 N of noise (sd) on each tension: eq. 11 explains a third of it.
    let short = dir.path().join("noisy.csv");
    ok(&sweep_to("torque", &short, &["--force-noise-n", "200"]));
    let out = previous_output(dir.path(), "torque.toml");
    let e = exits(2, &identify_torque(&short, &out, &[]));
    assert_kept(&out);
    // The override writes the same model; the refusal named its fit.
    let forced = dir.path().join("forced.toml");
    let report = ok(&identify_torque(&short, &forced, &["--allow-poor-fit"]));
    let fit_line = report
        .lines()
        .find(|l| l.starts_with("fit against"))
        .unwrap();
    let fit: f64 = fit_line.split_whitespace().nth(5).unwrap().parse().unwrap();
    let gate = host_sim::control::calibrate::MIN_TORQUE_FIT_PCT;
    assert!(
        fit < gate,
        "{fit_line}: not a poor fit, the test data changed"
    );
    for n in [
        "noisy.csv".to_string(),
        format!("{fit:.2} %"),
        format!("{gate} %"),
        "--allow-poor-fit".into(),
        "nothing written".into(),
    ] {
        assert!(e.contains(&n), "`{n}` not in:\n{e}");
    }
    assert!(forced.exists());
    // The sweep with the default noise passes the gate.
    let full = sweep("torque", dir.path(), "sweep.csv");
    let good = dir.path().join("good.toml");
    ok(&identify_torque(&full, &good, &[]));
}

#[test]
fn identify_torque_refuses_pressures_in_pa() {
    let dir = tempfile::tempdir().unwrap();
    let (pa, line) = mapped_sweep("torque", dir.path(), "pa.csv", "p1_kpa", |p| p * 1e3);
    let out = previous_output(dir.path(), "torque.toml");
    let e = exits(2, &identify_torque(&pa, &out, &[]));
    for n in [
        format!("pa.csv:{line}:"),
        "`p1_kpa`".into(),
        // Refused when the recording is read: the plausible range of a gauge pressure.
        "[-200, 2500] kPa gauge".into(),
        "a value in Pa?".into(),
    ] {
        assert!(e.contains(n.as_str()), "`{n}` not in:\n{e}");
    }
    assert_kept(&out);
}

#[test]
fn identify_force_refuses_a_stretch_in_percent_naming_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let (pct, first_data) =
        mapped_sweep("force", dir.path(), "percent.csv", "stretch", |e| e * 100.0);
    let out = previous_output(dir.path(), "force.toml");
    let r = host_sim(&[&"identify", &"force", &"--data", &pct, &"--out", &out]);
    let e = exits(2, &r);
    for n in [
        format!("percent.csv:{first_data}"),
        "`stretch`".into(),
        "75".into(),
        "0.5..1.5".into(),
        "a percentage? 75 % is 0.75".into(),
    ] {
        assert!(e.contains(&n), "`{n}` not in:\n{e}");
    }
    assert_kept(&out);
    // A contraction (1 - L/L0) in the column is named as such.
    let (chi, first_data) = mapped_sweep("force", dir.path(), "contraction.csv", "stretch", |e| {
        1.0 - e
    });
    let r = host_sim(&[&"identify", &"force", &"--data", &chi, &"--out", &out]);
    let e = exits(2, &r);
    for n in [
        format!("contraction.csv:{first_data}"),
        "a contraction 1 - L/L0 instead?".into(),
    ] {
        assert!(e.contains(&n), "`{n}` not in:\n{e}");
    }
    assert_kept(&out);
    // The same bounds on the sweep's arguments.
    let e = exits(
        2,
        &sweep_to("force", &dir.path().join("s.csv"), &["--stretch-min", "75"]),
    );
    assert!(e.contains("--stretch-min") && e.contains("75"), "{e}");
}

#[test]
fn identify_plant_refuses_a_fit_below_the_calibrate_gate() {
    // The torque sweep holds every valve closed and moves the joint by hand: replaying its
    // valve inputs reproduces none of its channels, whatever the inertia.
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("sweep.csv");
    ok(&sweep_to(
        "torque",
        &rec,
        &["--speeds-rad-s", "2", "--dp-kpa", "0, 100"],
    ));
    let out = previous_output(dir.path(), "fitted.toml");
    let args = |out: &Path, extra: &'static str| {
        let mut c = bin();
        c.args(["identify", "plant", "--recording"])
            .arg(&rec)
            .arg("--plant")
            .arg(plant());
        c.args(["--params", "joint.inertia_kgm2", "--patience", "3", "--out"])
            .arg(out);
        if !extra.is_empty() {
            c.arg(extra);
        }
        c.output().unwrap()
    };
    let e = exits(2, &args(&out, ""));
    let gate = host_sim::control::calibrate::MIN_IDENTIFIED_HELDOUT_FIT_PCT;
    for n in [
        "sweep.csv",
        "held-out",
        &format!("{gate} %"),
        "--allow-poor-fit",
        "nothing written",
    ] {
        assert!(e.contains(n), "`{n}` not in:\n{e}");
    }
    assert_kept(&out);
    let forced = dir.path().join("forced.toml");
    let report = ok(&args(&forced, "--allow-poor-fit"));
    assert!(forced.exists(), "{report}");
}
