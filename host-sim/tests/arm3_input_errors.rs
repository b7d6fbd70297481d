//! What a user types into the 3-DOF arm path (arm scenario and plant files, 3-joint
//! recordings) is checked as strictly as the 1-DOF files: a bad value is refused with exit
//! status 2 and a message naming the file, the line and the key, nothing is written and the
//! inputs are left as they were.

mod common;
use common::*;

use std::path::{Path, PathBuf};

/// The shipped arm step scenario with `name` and a 2 s run (short enough for a test).
fn arm_step_named(name: &str) -> String {
    std::fs::read_to_string(root().join("scenarios/arm3/step.toml"))
        .unwrap()
        .replace("name = \"arm_step\"", &format!("name = {name:?}"))
        .replace("duration_s = 9.0", "duration_s = 2.0")
        .replace("at_s = 4.0", "at_s = 1.0")
        .replace("settle_after_s = 6.5", "settle_after_s = 1.5")
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn an_arm_scenario_name_that_is_a_path_is_refused_and_nothing_outside_out_dir_is_touched() {
    let d = tempfile::tempdir().unwrap();
    let victim_dir = d.path().join("victim");
    std::fs::create_dir(&victim_dir).unwrap();
    let victim = previous_output(&victim_dir, "pulses_nominal.csv");
    let out = d.path().join("out/d/e");
    for name in [
        "../../../victim/pulses_nominal",
        "/tmp/abs",
        "a/b",
        ".hidden",
        "a..b",
        "x y",
        "",
    ] {
        let text = arm_step_named(name);
        let s = write(d.path(), "s.toml", &text);
        let r = host_sim(&[
            &"demo",
            &"--plant",
            &arm3_plant(),
            &"--scenario",
            &s,
            &"--out-dir",
            &out,
        ]);
        assert_refused(
            &r,
            &["s.toml", "line 6", "[scenario] name", "A-Za-z0-9_.-"],
            &out,
        );
        assert_kept(&victim);
        assert_eq!(std::fs::read_to_string(&s).unwrap(), text, "input changed");
        assert_eq!(
            std::fs::read_dir(&victim_dir).unwrap().count(),
            1,
            "{name:?}: a file was created next to the victim"
        );
    }
}

#[test]
fn a_one_dof_scenario_name_that_is_a_path_is_refused_at_its_line() {
    let d = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(root().join("scenarios/step.toml"))
        .unwrap()
        .replace("name = \"step\"", "name = \"../escape\"");
    let s = write(d.path(), "step.toml", &text);
    let out = d.path().join("o.csv");
    let r = host_sim(&[
        &"simulate",
        &"--plant",
        &plant(),
        &"--scenario",
        &s,
        &"--out",
        &out,
    ]);
    assert_refused(&r, &["step.toml", "line 3", "[scenario] name"], &out);
    assert!(!out.with_extension("firmware.csv").exists());
}

#[test]
fn two_arm_scenarios_with_one_name_are_refused_before_anything_is_written() {
    let d = tempfile::tempdir().unwrap();
    let a = write(d.path(), "a.toml", &arm_step_named("same"));
    let b = write(d.path(), "b.toml", &arm_step_named("same"));
    let out = d.path().join("out");
    let r = host_sim(&[
        &"demo",
        &"--plant",
        &arm3_plant(),
        &"--scenario",
        &a,
        &"--scenario",
        &b,
        &"--out-dir",
        &out,
    ]);
    assert_refused(&r, &["b.toml", "\"same\"", "a.toml"], &out);
}
