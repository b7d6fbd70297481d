//! `host-sim diagnose-batch`: every recording of a directory diagnosed in parallel, one JSON
//! each (the same as `diagnose --json` writes) and a summary; a bad recording is listed with
//! its error (status 1) without stopping the others.

mod common;
use common::*;

#[test]
fn a_directory_is_diagnosed_in_parallel_with_one_json_each_and_a_summary() {
    let dir = tempfile::tempdir().unwrap();
    let recs = dir.path().join("recs");
    std::fs::create_dir(&recs).unwrap();
    std::fs::copy(
        shared().join("conformance/pulses_nominal.csv"),
        recs.join("nominal.csv"),
    )
    .unwrap();
    std::fs::write(recs.join("broken.csv"), "t_s,u_in1\n0,0\n").unwrap();
    let out = dir.path().join("out");
    let plant = shared().join("plant/reference-1dof.toml");
    let r = host_sim(&[
        &"diagnose-batch",
        &"--jobs",
        &"2",
        &"--plant",
        &plant,
        &"--recordings",
        &recs,
        &"--out-dir",
        &out,
    ]);
    let stdout = String::from_utf8_lossy(&r.stdout);
    assert_eq!(
        r.status.code(),
        Some(1),
        "{stdout}\n{}",
        String::from_utf8_lossy(&r.stderr)
    );
    let summary = std::fs::read_to_string(out.join("summary.csv")).unwrap();
    let lines: Vec<&str> = summary.lines().collect();
    assert_eq!(lines.len(), 3, "{summary}");
    assert!(
        lines[1].starts_with("broken.csv,0,\"error:") && lines[1].contains("u_ex1"),
        "{summary}"
    );
    assert!(
        lines[2].starts_with("nominal.csv,20000,nothing_missing,"),
        "{summary}"
    );
    assert!(lines[0].contains(",verdict,effects,"), "{summary}");
    assert!(
        stdout.contains("nominal.csv") && stdout.contains("broken.csv"),
        "{stdout}"
    );
    assert!(!out.join("broken.json").exists());

    // The batch JSON is what the single-recording command writes.
    let single = dir.path().join("single.json");
    let r = on_plant(
        "diagnose",
        &plant,
        &[
            &"--recording",
            &recs.join("nominal.csv"),
            &"--json",
            &single,
        ],
    );
    ok(&r);
    assert_eq!(
        std::fs::read_to_string(out.join("nominal.json")).unwrap(),
        std::fs::read_to_string(&single).unwrap()
    );
}
