//! `host-sim diagnose-batch`: every recording of a directory diagnosed in parallel, one JSON
//! each (the same as `diagnose --json` writes) and a summary; a bad recording is listed with
//! its error (status 1) without stopping the others; an unexplained one gives status 3 as
//! `diagnose` does; the output directory may be the recordings' own.

mod common;
use common::*;

/// The summary's rows, read back as CSV (quoted fields unquoted); every row has the header's
/// seven fields.
fn rows(summary: &str) -> Vec<Vec<String>> {
    let mut r = csv::ReaderBuilder::new()
        .has_headers(false)
        .from_reader(summary.as_bytes());
    let rows: Vec<Vec<String>> = r
        .records()
        .map(|rec| rec.unwrap().iter().map(String::from).collect())
        .collect();
    for row in &rows {
        assert_eq!(row.len(), 7, "{row:?} in:\n{summary}");
    }
    rows
}

#[test]
fn a_directory_is_diagnosed_in_parallel_with_one_json_each_and_a_summary() {
    let dir = tempfile::tempdir().unwrap();
    let recs = dir.path().join("recs");
    std::fs::create_dir(&recs).unwrap();
    std::fs::copy(fixture("pulses_nominal.csv"), recs.join("nominal.csv")).unwrap();
    std::fs::write(recs.join("broken.csv"), "t_s,u_in1\n0,0\n").unwrap();
    let out = dir.path().join("out");
    let plant = fixture("reference-1dof.toml");
    let r = batch(&plant, &recs, &out, &[&"--jobs", &"2"]);
    let stdout = String::from_utf8_lossy(&r.stdout);
    assert_eq!(
        r.status.code(),
        Some(1),
        "{stdout}\n{}",
        String::from_utf8_lossy(&r.stderr)
    );
    let summary = std::fs::read_to_string(out.join("summary.csv")).unwrap();
    let lines = rows(&summary);
    assert_eq!(lines.len(), 3, "{summary}");
    assert!(
        lines[1][..2] == ["broken.csv", "0"]
            && lines[1][2].starts_with("error:")
            && lines[1][2].contains("u_ex1"),
        "{summary}"
    );
    assert_eq!(lines[2][..3], ["nominal.csv", "20000", "nothing_missing"]);
    assert_eq!(lines[0][2..4], ["verdict", "effects"]);
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
    // The nominal recording replaced by a broken one: its earlier answer is removed, not left
    // next to a summary that says "error"; a JSON that is not a diagnosis is left alone.
    std::fs::write(recs.join("nominal.csv"), "t_s,u_in1\n0,0\n").unwrap();
    std::fs::write(out.join("broken.json"), "my notes\n").unwrap();
    let r = batch(&plant, &recs, &out, &[&"--jobs", &"2"]);
    let stdout = String::from_utf8_lossy(&r.stdout);
    assert_eq!(r.status.code(), Some(1), "{stdout}");
    assert!(!out.join("nominal.json").exists(), "{stdout}");
    assert!(
        stdout.contains("nominal.json: an earlier run's answer"),
        "{stdout}"
    );
    assert_eq!(
        std::fs::read_to_string(out.join("broken.json")).unwrap(),
        "my notes\n"
    );
    // A `*.csv` that is a link to nowhere or a directory is a row with its cause, not skipped.
    #[cfg(unix)]
    {
        let odd = dir.path().join("odd");
        std::fs::create_dir(&odd).unwrap();
        std::os::unix::fs::symlink(dir.path().join("gone.csv"), odd.join("gone.csv")).unwrap();
        std::fs::create_dir(odd.join("sub.csv")).unwrap();
        let o = dir.path().join("odd-out");
        let r = batch(&plant, &odd, &o, &[]);
        let stdout = String::from_utf8_lossy(&r.stdout);
        assert_eq!(r.status.code(), Some(1), "{stdout}");
        let summary = std::fs::read_to_string(o.join("summary.csv")).unwrap();
        let lines = rows(&summary);
        for name in ["gone.csv", "sub.csv"] {
            assert!(
                lines
                    .iter()
                    .any(|l| l[0] == name && l[1] == "0" && l[2].starts_with("error:")),
                "{summary}"
            );
        }
        // Names with a comma or a quote (a lab's "run 1, left arm.csv"): quoted, seven fields
        // each, the names read back as they are.
        let named = dir.path().join("named");
        std::fs::create_dir(&named).unwrap();
        std::fs::copy(
            fixture("pulses_nominal.csv"),
            named.join("run 1, left arm.csv"),
        )
        .unwrap();
        std::fs::write(named.join("bad \"q\".csv"), "t_s,u_in1\n0,0\n").unwrap();
        let o = dir.path().join("named-out");
        batch(&plant, &named, &o, &[]);
        let summary = std::fs::read_to_string(o.join("summary.csv")).unwrap();
        let lines = rows(&summary);
        assert!(
            lines
                .iter()
                .any(|l| l[0] == "run 1, left arm.csv" && l[2] == "nothing_missing"),
            "{summary}"
        );
        assert!(
            lines
                .iter()
                .any(|l| l[0] == "bad \"q\".csv" && l[2].contains("bad \"q\".csv")),
            "{summary}"
        );
    }
    // Two recordings whose names differ only in their extension's case share a JSON: both
    // named, nothing run.
    std::fs::copy(fixture("pulses_nominal.csv"), recs.join("nominal.CSV")).unwrap();
    let r = batch(&plant, &recs, &out, &[]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert!(
        err.contains("the JSON of") && err.contains("nominal.CSV") && err.contains("nominal.csv"),
        "{err}"
    );
}

/// `diagnose-batch` of `recs` against `plant` into `out`, with `extra` arguments.
fn batch(
    plant: &std::path::Path,
    recs: &std::path::Path,
    out: &std::path::Path,
    extra: &[&dyn AsRef<std::ffi::OsStr>],
) -> std::process::Output {
    let mut rest: Vec<&dyn AsRef<std::ffi::OsStr>> =
        vec![&"--recordings", &recs, &"--out-dir", &out];
    rest.extend_from_slice(extra);
    on_plant("diagnose-batch", &plant, &rest)
}

#[test]
fn the_exit_status_follows_the_worst_verdict_and_the_out_dir_may_be_the_recordings() {
    let dir = tempfile::tempdir().unwrap();
    let recs = dir.path().join("recs");
    std::fs::create_dir(&recs).unwrap();
    let plant = fixture("reference-1dof.toml");
    std::fs::copy(fixture("pulses_nominal.csv"), recs.join("nominal.csv")).unwrap();
    // All explained or nothing missing: 0, with the outputs next to the recordings.
    ok(&batch(&plant, &recs, &recs, &[]));
    assert!(recs.join("summary.csv").exists() && recs.join("nominal.json").exists());
    // Again into the same directory: its own summary.csv is not read as a recording.
    let stdout = ok(&batch(&plant, &recs, &recs, &[]));
    assert!(!stdout.contains("summary.csv  "), "{stdout}");
    let summary = std::fs::read_to_string(recs.join("summary.csv")).unwrap();
    assert_eq!(summary.lines().count(), 2, "{summary}");
    // Into another directory: the summary left in the recordings' is skipped, with a note;
    // so is the firmware trace `simulate --scenario` writes beside its recording.
    std::fs::write(
        recs.join("step.firmware.csv"),
        format!(
            "# source = host-sim closed loop\n{}\n0.000,0,0,300,300,0,0,1\n",
            host_sim::control::run_files::FIRMWARE_COLUMNS.join(",")
        ),
    )
    .unwrap();
    let r = batch(&plant, &recs, &dir.path().join("elsewhere"), &[]);
    let stdout = ok(&r);
    assert!(!stdout.contains("summary.csv  "), "{stdout}");
    assert!(!stdout.contains("step.firmware"), "{stdout}");
    let err = text(&r.stderr);
    assert!(
        err.contains("the summary of an earlier diagnose-batch, not a recording")
            && err.contains("step.firmware.csv: the firmware trace of a host-sim simulate run"),
        "{err}"
    );
    // A recording of another rig (muscles mounted at another initial contraction, a key the
    // diagnosis does not refit; simulated through the CLI): not explained -> 3.
    let other = dir.path().join("other.toml");
    std::fs::write(
        &other,
        nominal_text().replace("initial_contraction = 0.14", "initial_contraction = 0.05"),
    )
    .unwrap();
    ok(&host_sim(&[
        &"simulate",
        &"--plant",
        &other,
        &"--inputs",
        &fixture("pulses_nominal.csv"),
        &"--out",
        &recs.join("other.csv"),
    ]));
    let r = batch(&plant, &recs, &recs, &[]);
    let summary = std::fs::read_to_string(recs.join("summary.csv")).unwrap();
    let lines = rows(&summary);
    let other_row = lines.iter().find(|l| l[0] == "other.csv").unwrap();
    assert!(
        other_row[2] == "unexplained" || other_row[2] == "not_this_plant",
        "{summary}"
    );
    assert_eq!(r.status.code(), Some(3), "{}", text(&r.stderr));
    // The other rig's recording moved away: its earlier answer is named, not taken for this
    // batch's (the summary does not list it).
    std::fs::rename(recs.join("other.csv"), dir.path().join("other.csv")).unwrap();
    let stdout = ok(&batch(&plant, &recs, &recs, &[]));
    assert!(
        stdout
            .contains("other.json is an earlier batch's answer for a recording not in this batch")
            && !stdout.contains("nominal.json is an earlier"),
        "{stdout}"
    );
    // A user's recording that happens to be named summary.csv is not skipped: refused as an
    // input the batch would overwrite.
    std::fs::copy(fixture("pulses_nominal.csv"), recs.join("summary.csv")).unwrap();
    let e = exits(2, &batch(&plant, &recs, &recs, &[]));
    assert!(e.contains("summary.csv") && e.contains("input"), "{e}");
}
