//! The rule of every output (`output`): host-sim replaces only files it wrote (its mark,
//! or a report folder's manifest) unless `--force`; read-only files and folders that cannot
//! be written are refused before the work; an interrupted run leaves no temporary file and a
//! killed run's are removed by the next run; without the repository's files in the working
//! directory the built-in reference plant is used and the paths tried are named.

mod common;
use common::*;

use std::path::{Path, PathBuf};

/// The temporary files of the atomic writer in `dir`.
fn temps_in(dir: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| host_sim::output::is_temp_name(&p.file_name().unwrap().to_string_lossy()))
        .collect()
}

fn simulate(out: &Path, extra: &[&str]) -> std::process::Output {
    let mut c = bin();
    c.arg("simulate")
        .arg("--plant")
        .arg(plant())
        .arg("--inputs")
        .arg(fixture("pulses_nominal.csv"))
        .arg("--out")
        .arg(out);
    c.args(extra);
    c.output().unwrap()
}

#[test]
fn a_users_file_is_not_replaced_without_force_and_host_sims_own_output_is() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("mine.csv");
    let mine = "t_s,angle_deg\n0,1\n0.01,2\n";
    std::fs::write(&out, mine).unwrap();
    let e = exits(2, &simulate(&out, &[]));
    assert!(
        e.contains("mine.csv") && e.contains("not written by host-sim") && e.contains("--force"),
        "{e}"
    );
    assert_eq!(std::fs::read_to_string(&out).unwrap(), mine);
    // --force replaces it; the output carries the mark, so the next run replaces it freely.
    ok(&simulate(&out, &["--force"]));
    let first = std::fs::read_to_string(&out).unwrap();
    assert!(
        first.starts_with("# generator = host-sim"),
        "{}",
        &first[..80]
    );
    assert!(host_sim::output::written_by_host_sim(&out));
    ok(&simulate(&out, &[]));
    assert!(temps_in(dir.path()).is_empty());
}

#[test]
fn a_users_plot_and_json_are_refused_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("fit.png");
    std::fs::write(&png, b"\x89PNG\r\n\x1a\nnot host-sim's").unwrap();
    let r = bin()
        .args(["fit"])
        .arg(fixture("pulses_nominal.csv"))
        .arg(fixture("pulses_nominal.csv"))
        .arg("--plot")
        .arg(&png)
        .output()
        .unwrap();
    let e = exits(2, &r);
    assert!(e.contains("--plot") && e.contains("fit.png"), "{e}");
    assert_eq!(
        std::fs::read(&png).unwrap(),
        b"\x89PNG\r\n\x1a\nnot host-sim's"
    );
    // A JSON file of the user's (settings.json) given as --json.
    let json = dir.path().join("settings.json");
    std::fs::write(&json, "{\"theme\": \"dark\"}\n").unwrap();
    let t0 = std::time::Instant::now();
    let r = bin()
        .args(["diagnose", "--plant"])
        .arg(plant())
        .arg("--recording")
        .arg(fixture("pulses_loaded.csv"))
        .arg("--json")
        .arg(&json)
        .output()
        .unwrap();
    let e = exits(2, &r);
    assert!(e.contains("--json") && e.contains("settings.json"), "{e}");
    assert!(
        t0.elapsed().as_secs_f64() < 10.0,
        "refused only after the work"
    );
    assert_eq!(
        std::fs::read_to_string(&json).unwrap(),
        "{\"theme\": \"dark\"}\n"
    );
}

#[test]
fn host_sims_plot_carries_its_mark_and_is_replaced() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["fit.png", "fit.svg"] {
        let p = dir.path().join(name);
        for _ in 0..2 {
            ok(&bin()
                .args(["fit"])
                .arg(fixture("pulses_nominal.csv"))
                .arg(fixture("pulses_nominal.csv"))
                .arg("--plot")
                .arg(&p)
                .output()
                .unwrap());
            assert!(host_sim::output::written_by_host_sim(&p), "{name}");
        }
    }
}

#[test]
fn a_report_folder_with_the_users_files_is_refused_and_other_files_are_not_touched() {
    let dir = tempfile::tempdir().unwrap();
    let report = dir.path().join("report");
    std::fs::create_dir(&report).unwrap();
    std::fs::write(report.join("index.html"), "<html>my page</html>").unwrap();
    std::fs::write(report.join("notes.txt"), "mine").unwrap();
    let json = dir.path().join("d.json");
    let r = bin()
        .args(["diagnose", "--plant"])
        .arg(plant())
        .arg("--recording")
        .arg(fixture("pulses_loaded.csv"))
        .arg("--json")
        .arg(&json)
        .arg("--report")
        .arg(&report)
        .output()
        .unwrap();
    let e = assert_refused(&r, &["--report", "index.html"], &json);
    assert!(e.contains("not written by host-sim"), "{e}");
    assert_eq!(
        std::fs::read_to_string(report.join("index.html")).unwrap(),
        "<html>my page</html>"
    );
    assert_eq!(
        std::fs::read_to_string(report.join("notes.txt")).unwrap(),
        "mine"
    );
}

#[test]
fn demo_and_batch_folders_refuse_the_users_files_and_the_built_in_plant_is_named() {
    // From a folder without the repository's files: the built-in plant, the paths tried.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    std::fs::create_dir(&out).unwrap();
    std::fs::write(out.join("step.csv"), "t_s,angle_deg\n0,0\n").unwrap();
    let r = bin()
        .current_dir(dir.path())
        .args(["demo", "--out-dir", "demo"])
        .output()
        .unwrap();
    let e = exits(2, &r);
    assert!(e.contains("step.csv") && e.contains("--out-dir"), "{e}");
    assert!(
        e.contains("host-sim/plants/reference-1dof.toml")
            && e.contains("plants/reference-1dof.toml")
            && e.contains("built into host-sim"),
        "{e}"
    );
    assert_eq!(
        std::fs::read_to_string(out.join("step.csv")).unwrap(),
        "t_s,angle_deg\n0,0\n"
    );
    // diagnose-batch over a summary.csv of the user's.
    let recs = dir.path().join("recs");
    std::fs::create_dir(&recs).unwrap();
    std::fs::copy(fixture("pulses_nominal.csv"), recs.join("nominal.csv")).unwrap();
    let bout = dir.path().join("bout");
    std::fs::create_dir(&bout).unwrap();
    std::fs::write(bout.join("summary.csv"), "my,own\n").unwrap();
    let r = bin()
        .args(["diagnose-batch", "--plant"])
        .arg(plant())
        .arg("--recordings")
        .arg(&recs)
        .arg("--out-dir")
        .arg(&bout)
        .output()
        .unwrap();
    let e = exits(2, &r);
    assert!(e.contains("summary.csv"), "{e}");
    assert_eq!(
        std::fs::read_to_string(bout.join("summary.csv")).unwrap(),
        "my,own\n"
    );
}

#[cfg(unix)]
#[test]
fn a_read_only_output_is_refused_unless_forced() {
    use std::os::unix::fs::PermissionsExt as _;
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("ro.csv");
    ok(&simulate(&out, &[]));
    std::fs::set_permissions(&out, std::fs::Permissions::from_mode(0o444)).unwrap();
    let before = std::fs::read(&out).unwrap();
    let e = exits(2, &simulate(&out, &[]));
    assert!(
        e.contains("ro.csv") && e.contains("read-only (mode 0444)"),
        "{e}"
    );
    assert_eq!(std::fs::read(&out).unwrap(), before);
    ok(&simulate(&out, &["--force"]));
}

#[test]
fn an_output_folder_that_cannot_be_written_is_refused_before_the_work() {
    // /proc/1 cannot take a new file, even for root.
    let r = bin()
        .args(["diagnose", "--plant"])
        .arg(plant())
        .arg("--recording")
        .arg(fixture("pulses_loaded.csv"))
        .args(["--json", "/proc/1/d.json"])
        .output()
        .unwrap();
    let e = exits(2, &r);
    assert!(e.contains("cannot write in the folder /proc/1"), "{e}");
}

#[test]
fn a_killed_runs_temporary_files_are_removed_by_the_next_run() {
    let dir = tempfile::tempdir().unwrap();
    // Process ids above the kernel's limit (4194304) never run.
    let stale = dir.path().join(".fit.png.9999999.aB3dE6.tmp.png");
    std::fs::write(&stale, vec![0u8; 1000]).unwrap();
    let user = dir.path().join(".fit.png.tmp.png");
    std::fs::write(&user, "not of the pattern").unwrap();
    let r = bin()
        .args(["fit"])
        .arg(fixture("pulses_nominal.csv"))
        .arg(fixture("pulses_nominal.csv"))
        .arg("--plot")
        .arg(dir.path().join("fit.png"))
        .output()
        .unwrap();
    ok(&r);
    assert!(!stale.exists());
    assert!(user.exists());
    assert!(text(&r.stderr).contains("temporary file of an interrupted host-sim run"));
}

/// A recording of `copies` times the conformance fixture, end to end (a run of some seconds).
fn long_recording(path: &Path, copies: usize) {
    let text = std::fs::read_to_string(fixture("pulses_nominal.csv")).unwrap();
    #[allow(clippy::type_complexity)]
    let (head, rows): (Vec<&str>, Vec<&str>) = {
        let mut lines = text.lines();
        let mut head = Vec::new();
        for l in lines.by_ref() {
            head.push(l);
            if !l.starts_with('#') {
                break;
            }
        }
        (head, lines.filter(|l| !l.trim().is_empty()).collect())
    };
    let dt = 0.001;
    let mut out = head.join("\n") + "\n";
    let mut k = 0usize;
    for _ in 0..copies {
        for r in &rows {
            let (_, rest) = r.split_once(',').unwrap();
            out += &format!("{:.6},{rest}\n", k as f64 * dt);
            k += 1;
        }
    }
    std::fs::write(path, out).unwrap();
}

#[cfg(unix)]
#[test]
fn an_interrupt_removes_the_runs_temporary_files_and_keeps_the_old_output() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("long.csv");
    let out_dir = dir.path().join("out");
    std::fs::create_dir(&out_dir).unwrap();
    let out = out_dir.join("sim.csv");
    std::fs::write(&out, "# generator = host-sim 0.1.0\nt_s,angle_deg\n0,0\n").unwrap();
    let old = std::fs::read(&out).unwrap();
    let mut interrupted = Vec::new();
    // A longer recording when the run ended before the signal (a fast machine).
    'sizes: for copies in [40, 160] {
        long_recording(&input, copies);
        for sig in ["INT", "TERM"] {
            let child = bin()
                .arg("simulate")
                .arg("--plant")
                .arg(plant())
                .arg("--inputs")
                .arg(&input)
                .arg("--out")
                .arg(&out)
                .stdout(std::process::Stdio::null())
                .stderr(std::process::Stdio::piped())
                .spawn()
                .unwrap();
            // The temporary output appears as the run starts writing: interrupt then.
            let t0 = std::time::Instant::now();
            while temps_in(&out_dir).is_empty() && t0.elapsed().as_secs() < 60 {
                std::thread::sleep(std::time::Duration::from_millis(1));
            }
            let _ = std::process::Command::new("kill")
                .arg(format!("-{sig}"))
                .arg(child.id().to_string())
                .status();
            let r = child.wait_with_output().unwrap();
            if r.status.code() == Some(0) {
                std::fs::write(&out, &old).unwrap();
                continue 'sizes; // finished before the signal
            }
            let code = if sig == "INT" { 130 } else { 143 };
            assert_eq!(r.status.code(), Some(code), "{}", text(&r.stderr));
            assert!(temps_in(&out_dir).is_empty(), "{:?}", temps_in(&out_dir));
            assert_eq!(
                std::fs::read(&out).unwrap(),
                old,
                "the old output was replaced"
            );
            interrupted.push(sig);
        }
        break;
    }
    assert_eq!(interrupted, ["INT", "TERM"], "no run was interrupted");
}
