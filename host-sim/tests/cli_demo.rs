//! End-to-end: `host-sim demo --out-dir DIR`, the README's first command, through the built
//! binary (run from the repository root, as `cargo run -p host-sim -- demo` does).

mod common;
use common::*;

use host_sim::io::recording::Recording;

#[test]
fn demo_writes_every_file_and_reports_tracking_and_conformance() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("demo"); // does not exist yet: the demo creates it
    let r = bin()
        .current_dir(root())
        .arg("demo")
        .arg("--out-dir")
        .arg(&out_dir)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&r.stdout);
    println!("{stdout}");
    assert!(
        r.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&r.stderr)
    );

    for (name, ticks) in [("step", 4000), ("sine", 6000), ("random", 8000)] {
        let rec = Recording::read(out_dir.join(format!("{name}.csv"))).unwrap();
        assert_eq!(rec.len(), ticks, "{name}");
        assert_eq!(
            rec.meta("firmware_trace"),
            Some(&*format!("{name}.firmware.csv"))
        );
        assert_trace_and_plot(&out_dir, name, ticks);
        // The table row: name, length, settle time, rms, max, faults, verdict, speed.
        let row = stdout
            .lines()
            .find(|l| l.split_whitespace().next() == Some(name))
            .unwrap_or_else(|| panic!("no table row for {name}"));
        let f: Vec<&str> = row.split_whitespace().collect();
        let rms_deg: f64 = f[3].parse().unwrap();
        let max_deg: f64 = f[4].parse().unwrap();
        assert!(
            rms_deg > 0.0 && rms_deg <= max_deg && max_deg < 20.0,
            "{row}"
        );
        assert_eq!(f[5], "0", "{row}: faults");
        assert_eq!(f[6], "met", "{row}");
    }
    let replay = Recording::read(out_dir.join("pulses_nominal_replay.csv")).unwrap();
    assert_eq!(replay.len(), 20_000);
    assert!(
        std::fs::metadata(out_dir.join("pulses_nominal_replay.png"))
            .unwrap()
            .len()
            > 10_000
    );
    // Conformance fit lines: every channel >= 99.5 %.
    assert_channel_fits(&stdout, 99.5);
}

#[test]
fn demo_with_a_missing_plant_says_where_it_looked() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope.toml");
    let r = host_sim(&[
        &"demo",
        &"--out-dir",
        &dir.path().join("d"),
        &"--plant",
        &missing,
    ]);
    assert_eq!(r.status.code(), Some(2));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains(&missing.display().to_string()), "{err}");
}

#[test]
fn demo_into_a_file_is_refused_before_the_runs_and_the_file_kept() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("afile");
    std::fs::write(&file, "mine\n").unwrap();
    let r = host_sim(&[&"demo", &"--out-dir", &file]);
    assert_eq!(r.status.code(), Some(2));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        err.contains("--out-dir") && err.contains("exists and is not a directory"),
        "{err}"
    );
    // Refused first: nothing of a run on stdout.
    assert!(
        r.stdout.is_empty(),
        "{}",
        String::from_utf8_lossy(&r.stdout)
    );
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "mine\n");
}

#[test]
fn demo_with_a_fixture_it_cannot_fit_is_refused_before_any_run() {
    let dir = tempfile::tempdir().unwrap();
    // The conformance fixture's valve columns without one measured channel.
    let text = std::fs::read_to_string(fixture("pulses_nominal.csv")).unwrap();
    let inputs_only: String = text
        .lines()
        .map(|l| {
            if l.starts_with('#') {
                l.to_string()
            } else {
                l.split(',').take(5).collect::<Vec<_>>().join(",")
            }
        })
        .map(|l| l + "\n")
        .collect();
    let fx = dir.path().join("inputs_only.csv");
    std::fs::write(&fx, inputs_only).unwrap();
    let out_dir = dir.path().join("d");
    let r = host_sim(&[&"demo", &"--out-dir", &out_dir, &"--fixture", &fx]);
    let err = exits(2, &r);
    assert!(
        err.contains("inputs_only.csv") && err.contains("no output column"),
        "{err}"
    );
    assert!(
        !out_dir.exists(),
        "the scenarios ran and wrote into {}",
        out_dir.display()
    );
}
