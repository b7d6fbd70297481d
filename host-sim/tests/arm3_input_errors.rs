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
        let r = arm_demo(&s, &out);
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
    simulate_step_refused(
        ("name = \"step\"", "name = \"../escape\""),
        &["step.toml", "line 3", "[scenario] name"],
    );
}

/// `simulate` of the shipped step scenario with `edit` (from, to) applied must be refused
/// naming every needle and the line of the edit, writing nothing (no firmware trace either).
fn simulate_step_refused(edit: (&str, &str), needles: &[&str]) {
    let d = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(root().join("scenarios/step.toml"))
        .unwrap()
        .replace(edit.0, edit.1);
    let s = write(d.path(), "step.toml", &text);
    let out = d.path().join("o.csv");
    let r = on_plant("simulate", &plant(), &[&"--scenario", &s, &"--out", &out]);
    let at = format!("line {}", line_of(&text, edit.1));
    let mut needles = needles.to_vec();
    needles.push(&at);
    assert_refused(&r, &needles, &out);
    assert!(!out.with_extension("firmware.csv").exists());
}

#[test]
fn two_arm_scenarios_with_one_name_are_refused_before_anything_is_written() {
    let d = tempfile::tempdir().unwrap();
    let a = write(d.path(), "a.toml", &arm_step_named("same"));
    let b = write(d.path(), "b.toml", &arm_step_named("same"));
    let out = d.path().join("out");
    let r = on_plant(
        "demo",
        &arm3_plant(),
        &[&"--scenario", &a, &"--scenario", &b, &"--out-dir", &out],
    );
    assert_refused(&r, &["b.toml", "\"same\"", "a.toml"], &out);
}

// ---------------------------------------------------------------------------------------
// Arm plant files: physical ranges.

/// The seed 001 arm plant file with `from` replaced by `to` (the first occurrence only).
fn arm_plant_with(from: &str, to: &str) -> String {
    let t = std::fs::read_to_string(arm3_plant()).unwrap();
    assert!(t.contains(from), "{from} not in the arm plant file");
    t.replacen(from, to, 1)
}

/// 1-based line of the first line of `text` containing `needle`.
fn line_of(text: &str, needle: &str) -> usize {
    text.lines().position(|l| l.contains(needle)).unwrap() + 1
}

/// `demo --plant <text>` on a 2 s arm step must be refused naming `key` at the line that
/// contains `needle`, writing nothing and leaving the plant file as it was.
fn assert_arm_plant_refused(text: &str, key: &str, needle: &str, more: &[&str]) -> String {
    let d = tempfile::tempdir().unwrap();
    let p = write(d.path(), "arm.toml", text);
    let s = write(d.path(), "s.toml", &arm_step_named("arm_step"));
    let out = d.path().join("out");
    let t0 = std::time::Instant::now();
    let r = on_plant("demo", &p, &[&"--scenario", &s, &"--out-dir", &out]);
    let at = format!("arm.toml:{}", line_of(text, needle));
    let mut needles = vec![at.as_str(), key];
    needles.extend(more);
    let e = assert_refused(&r, &needles, &out);
    assert_eq!(std::fs::read_to_string(&p).unwrap(), text);
    // Refused while reading the file, not after a long run.
    assert!(t0.elapsed().as_secs_f64() < 30.0);
    e
}

#[test]
fn arm_lugre_bristles_too_stiff_to_integrate_are_refused_at_their_line() {
    let lugre = "\n[joint1.friction.lugre]\nstatic_nm = 0.3\nstribeck_velocity_rad_s = 0.01\n\
                 stiffness_nm_per_rad = 1e12\ndamping_nm_s_per_rad = 60.0\n";
    let text = std::fs::read_to_string(arm3_plant()).unwrap() + lugre;
    assert_arm_plant_refused(
        &text,
        "joint1.friction.lugre.stiffness_nm_per_rad",
        "stiffness_nm_per_rad = 1e12",
        &["(0, 100000]"],
    );
    // A sign smoothing velocity that makes the equations as stiff.
    let text = arm_plant_with(
        "sign_smoothing_velocity_rad_s = 0.01",
        "sign_smoothing_velocity_rad_s = 1e-12",
    );
    assert_arm_plant_refused(
        &text,
        "joint1.friction.sign_smoothing_velocity_rad_s",
        "sign_smoothing_velocity_rad_s = 1e-12",
        &[],
    );
}

#[test]
fn arm_plant_values_outside_their_physical_range_are_refused_like_the_one_dof_ones() {
    // kPa typed into a Pa key.
    let text = arm_plant_with("supply_gauge_pa = 600000.0", "supply_gauge_pa = 600.0");
    assert_arm_plant_refused(
        &text,
        "environment.supply_gauge_pa",
        "supply_gauge_pa = 600.0",
        &["kPa typed into a Pa key?"],
    );
    // Initial pressures above the supply (550 kPa on a 420 kPa supply).
    let text = arm_plant_with("supply_gauge_pa = 600000.0", "supply_gauge_pa = 420000.0");
    assert_arm_plant_refused(
        &text,
        "joint1.initial.p1_gauge_pa",
        "p1_gauge_pa = 550000.0",
        &["supply_gauge_pa"],
    );
    // An initial angle of 100 rad (the run then failed, blaming the scenario).
    let text = arm_plant_with(
        "[joint2.initial]\nangle_rad = 0.0",
        "[joint2.initial]\nangle_rad = 100.0",
    );
    assert_arm_plant_refused(
        &text,
        "joint2.initial.angle_rad",
        "angle_rad = 100.0",
        &["rad"],
    );
    // A mass in grams.
    let text = arm_plant_with("mass2_kg = 11.7805", "mass2_kg = 11780.5");
    assert_arm_plant_refused(&text, "links.mass2_kg", "mass2_kg = 11780.5", &[]);
}

// ---------------------------------------------------------------------------------------
// Arm scenario files: the 1-DOF scenario's checks.

fn assert_arm_scenario_refused(text: &str, needle: &str, more: &[&str]) -> String {
    let d = tempfile::tempdir().unwrap();
    let s = write(d.path(), "s.toml", text);
    let out = d.path().join("out");
    let r = arm_demo(&s, &out);
    let at = format!("line {}", line_of(text, needle));
    let mut needles = vec!["s.toml", at.as_str()];
    needles.extend(more);
    let e = assert_refused(&r, &needles, &out);
    assert_eq!(std::fs::read_to_string(&s).unwrap(), text);
    e
}

#[test]
fn arm_scenario_values_are_checked_as_the_one_dof_scenario_values() {
    let base = arm_step_named("arm_step");
    // A set-point of 25 rad (degrees typed as radians).
    let text = base.replace("final_rad = 0.3", "final_rad = 25.0");
    assert_arm_scenario_refused(
        &text,
        "final_rad = 25.0",
        &["[setpoint] joint1.final_rad", "half a turn"],
    );
    // A sine amplitude of 25 rad, in a [setpoint.joint2] table of its own.
    let text = base.replace(
        "joint2 = { kind = \"step\", initial_rad = -0.55, final_rad = -0.40, at_s = 1.0 }\n",
        "",
    ) + "\n[setpoint.joint2]\nkind = \"sine\"\noffset_rad = -0.5\namplitude_rad = 25.0\nfreq_hz = 0.2\n";
    assert_arm_scenario_refused(
        &text,
        "amplitude_rad = 25.0",
        &["[setpoint] joint2.amplitude_rad"],
    );
    // A step after the end of the run.
    let text = base.replace("final_rad = 0.3, at_s = 1.0", "final_rad = 0.3, at_s = 5.0");
    assert_arm_scenario_refused(&text, "at_s = 5.0", &["joint1.at_s", "[0, 2)"]);
    // Settling after the end of the run.
    let text = base.replace("settle_after_s = 1.5", "settle_after_s = 4.0");
    assert_arm_scenario_refused(&text, "settle_after_s = 4.0", &["[expect] settle_after_s"]);
    // A pressure noise of 1 GPa.
    let text = base.replace("pressure_noise_pa = 500.0", "pressure_noise_pa = 1e9");
    assert_arm_scenario_refused(
        &text,
        "pressure_noise_pa = 1e9",
        &["[sensors] pressure_noise_pa", "[0, 100000]"],
    );
}

#[test]
fn a_one_dof_scenario_with_a_huge_pressure_noise_is_refused_too() {
    simulate_step_refused(
        ("pressure_noise_pa = 500.0", "pressure_noise_pa = 1e9"),
        &["step.toml", "[sensors] pressure_noise_pa"],
    );
}

#[test]
fn a_run_without_expectations_says_so_and_reports_its_faults() {
    let d = tempfile::tempdir().unwrap();
    // Arm: no [expect] table.
    let text = arm_step_named("arm_free");
    let text = &text[..text.find("[expect]").unwrap()];
    let s = write(d.path(), "s.toml", text);
    let out = d.path().join("out");
    let stdout = ok(&arm_demo(&s, &out));
    assert!(
        stdout.contains("arm_free: no expectations given"),
        "{stdout}"
    );
    assert!(!stdout.contains(" met "), "{stdout}");
    // 1-DOF: a NaN pressure sensor latches a fault; no [expect] table.
    let text = std::fs::read_to_string(root().join("scenarios/step.toml")).unwrap();
    let text = text[..text.find("[expect]").unwrap_or(text.len())].to_string()
        + "\n[[events]]\nkind = \"sensor_nan\"\nat_s = 0.5\nduration_s = 0.5\nchannel = \"p1\"\n";
    let s = write(d.path(), "step.toml", &text);
    let o = d.path().join("o.csv");
    let stdout = ok(&on_plant(
        "simulate",
        &plant(),
        &[&"--scenario", &s, &"--out", &o],
    ));
    assert!(stdout.contains("expectations: none given"), "{stdout}");
    assert!(!stdout.contains("expectations: met"), "{stdout}");
    assert!(stdout.contains("latched at tick"), "{stdout}");
}

// ---------------------------------------------------------------------------------------
// 3-joint recordings: the 1-DOF reader's time check.

/// A 3-joint recording written by a closed-loop arm run (`demo`, 2 s at 1 kHz): its lines.
fn arm_recording_lines(dir: &Path) -> Vec<String> {
    let text = arm_step_named("rec");
    // No [expect] bounds: the run is data, not a test of the controller.
    let s = write(dir, "rec.toml", &text[..text.find("[expect]").unwrap()]);
    let out = dir.join("rec_out");
    ok(&arm_demo(&s, &out));
    std::fs::read_to_string(out.join("rec.csv"))
        .unwrap()
        .lines()
        .map(str::to_owned)
        .collect()
}

/// Index of the header in `lines` (the first line that is not `#` metadata).
fn header_index(lines: &[String]) -> usize {
    lines.iter().position(|l| !l.starts_with('#')).unwrap()
}

fn replay(dir: &Path, name: &str, lines: &[String]) -> (PathBuf, std::process::Output) {
    let rec = write(dir, name, &(lines.join("\n") + "\n"));
    let out = dir.join(format!("{name}.sim.csv"));
    let r = on_plant(
        "simulate",
        &arm3_plant(),
        &[&"--inputs", &rec, &"--out", &out],
    );
    (out, r)
}

#[test]
fn arm_recording_time_errors_name_their_own_line_and_jitter_is_accepted() {
    let d = tempfile::tempdir().unwrap();
    let lines = arm_recording_lines(d.path());
    let h = header_index(&lines);
    assert!(lines.len() - h - 1 == 2000, "2 s at 1 kHz");
    // Without the samples of t in [1.0, 1.5) s: a 0.5 s gap before the row of t = 1.5 s.
    let mut gap = lines.clone();
    gap.drain(h + 1 + 1000..h + 1 + 1500);
    let gap_line = h + 1 + 1000 + 1; // 1-based line of the row after the gap
    assert!(
        gap[gap_line - 1].starts_with("1.5"),
        "{}",
        gap[gap_line - 1]
    );
    let (out, r) = replay(d.path(), "gap.csv", &gap);
    assert_refused(
        &r,
        &[&format!("gap.csv:{gap_line}"), "t_s", "non-uniform time"],
        &out,
    );
    // A duplicated row at sample 1200.
    let mut dup = lines.clone();
    dup.insert(h + 1 + 1200, lines[h + 1 + 1200].clone());
    let dup_line = h + 1 + 1200 + 2;
    let (out, r) = replay(d.path(), "dup.csv", &dup);
    assert_refused(
        &r,
        &[&format!("dup.csv:{dup_line}"), "time does not increase"],
        &out,
    );
    // +-0.1 ms of jitter at 1 kHz: accepted, replayed on the uniform grid.
    let mut jit = lines.clone();
    for (k, l) in jit[h + 1..].iter_mut().enumerate() {
        let (t, rest) = l.split_once(',').unwrap();
        let t: f64 = t.parse().unwrap();
        let j = [0.0, 1e-4, -1e-4, 0.5e-4][k % 4] * if k == 0 { 0.0 } else { 1.0 };
        *l = format!("{},{rest}", t + j);
    }
    jit.retain(|l| !l.starts_with("# sample_period_s"));
    let (out, r) = replay(d.path(), "jitter.csv", &jit);
    ok(&r);
    let sim = std::fs::read_to_string(&out).unwrap();
    assert_eq!(
        sim.lines().filter(|l| !l.starts_with('#')).count(),
        2001,
        "header + one row per sample"
    );
}

// ---------------------------------------------------------------------------------------
// Arm files in 1-DOF-only commands.

#[test]
fn one_dof_commands_name_an_arm_plant_file_or_recording_as_such() {
    let d = tempfile::tempdir().unwrap();
    let arm = arm3_plant();
    let out = d.path().join("out.x");
    let s = root().join("scenarios/step.toml");
    let recs = d.path().join("recs");
    std::fs::create_dir(&recs).unwrap();
    let plant_cases: Vec<(&str, Vec<&dyn AsRef<std::ffi::OsStr>>)> = vec![
        ("tune", vec![&"tune", &"--plant", &arm, &"--out", &out]),
        (
            "sweep torque",
            vec![&"sweep", &"torque", &"--plant", &arm, &"--out", &out],
        ),
        (
            "pil",
            vec![&"pil", &"--plant", &arm, &"--scenario", &s, &"--out", &out],
        ),
        (
            "diagnose-batch",
            vec![
                &"diagnose-batch",
                &"--plant",
                &arm,
                &"--recordings",
                &recs,
                &"--out-dir",
                &out,
            ],
        ),
        (
            "compare-control",
            vec![&"compare-control", &"--plant", &arm],
        ),
    ];
    let what = format!(
        "{} is a 3-DOF arm plant file (kind = \"arm3\")",
        arm.display()
    );
    for (cmd, args) in plant_cases {
        let r = host_sim(&args);
        assert_refused(
            &r,
            &[
                &what,
                &format!("{cmd} is 1-DOF only"),
                "demo / simulate / diagnose",
            ],
            &out,
        );
    }
    // An arm recording in fit and identify plant.
    let lines = arm_recording_lines(d.path());
    let rec = write(d.path(), "arm.csv", &(lines.join("\n") + "\n"));
    let what = format!("{} is a 3-DOF arm recording", rec.display());
    let r = host_sim(&[&"fit", &rec, &rec]);
    assert_refused(&r, &[&what, "fit is 1-DOF only"], &out);
    let r = host_sim(&[
        &"identify",
        &"plant",
        &"--recording",
        &rec,
        &"--plant",
        &plant(),
        &"--params",
        &"joint.inertia_kgm2",
        &"--out",
        &out,
    ]);
    assert_refused(&r, &[&what, "identify plant is 1-DOF only"], &out);
}

// ---------------------------------------------------------------------------------------
// pil: the firmware image is checked first and named.

#[test]
fn pil_checks_the_firmware_image_before_the_run_and_names_it() {
    let d = tempfile::tempdir().unwrap();
    let s = root().join("scenarios/step.toml");
    let out = d.path().join("pil.csv");
    let empty = write(d.path(), "empty.elf", "");
    let text = write(d.path(), "text.elf", "not an image\n");
    // The host-sim binary: an ELF, but not for the board.
    let host_elf = PathBuf::from(env!("CARGO_BIN_EXE_host-sim"));
    for (elf, why) in [
        (d.path().join("missing.elf"), "cannot read it"),
        (d.path().to_path_buf(), "not a regular file"),
        (empty, "is empty"),
        (text, "not an ELF file"),
        (
            host_elf,
            "64-bit little-endian x86-64 ELF file, not a 32-bit little-endian ARM",
        ),
    ] {
        let r = on_plant(
            "pil",
            &plant(),
            &[&"--scenario", &s, &"--out", &out, &"--elf", &elf],
        );
        let e = assert_refused(&r, &[&format!("--elf {}", elf.display()), why], &out);
        assert!(!e.contains("step.toml"), "blames the scenario:\n{e}");
        assert_eq!(e.lines().count(), 1, "one line:\n{e}");
    }
}

#[test]
fn a_crashing_image_gives_qemus_first_line_and_a_few_lines_of_details() {
    if std::process::Command::new("qemu-system-arm")
        .arg("--version")
        .output()
        .is_err()
    {
        eprintln!("SKIPPED: qemu-system-arm not installed (scripts/setup.sh)");
        return;
    }
    // A well-formed 32-bit ARM ELF whose one segment is a vector table of zeros (stack
    // pointer 0, reset vector 0): QEMU loads it and the core locks up.
    let mut h = b"\x7fELF\x01\x01\x01\x00".to_vec();
    h.extend([0u8; 8]);
    for (v, bytes) in [
        // ELF header: type, machine, version, entry, phoff, shoff, flags, ehsize,
        // phentsize, phnum, shentsize, shnum, shstrndx.
        (2u32, 2),
        (40, 2),
        (1, 4),
        (0x0800_0000, 4),
        (52, 4),
        (0, 4),
        (0, 4),
        (52, 2),
        (32, 2),
        (1, 2),
        (40, 2),
        (0, 2),
        (0, 2),
        // PT_LOAD: offset 84, vaddr, paddr, filesz 8, memsz 8, flags r-x, align 4.
        (1, 4),
        (84, 4),
        (0x0800_0000, 4),
        (0x0800_0000, 4),
        (8, 4),
        (8, 4),
        (5, 4),
        (4, 4),
    ] {
        h.extend(&v.to_le_bytes()[..bytes]);
    }
    h.extend([0u8; 8]);
    let d = tempfile::tempdir().unwrap();
    let elf = d.path().join("hdr.elf");
    std::fs::write(&elf, &h).unwrap();
    let out = d.path().join("pil.csv");
    let r = on_plant(
        "pil",
        &plant(),
        &[
            &"--scenario",
            &root().join("scenarios/step.toml"),
            &"--out",
            &out,
            &"--elf",
            &elf,
            &"--tick-timeout-s",
            &"5",
        ],
    );
    let e = assert_refused(&r, &["hdr.elf", "QEMU"], &out);
    assert!(e.lines().count() <= 8, "at most a few lines:\n{e}");
    if e.lines().count() > 1 {
        assert!(e.contains("\n  details:"), "{e}");
    }
}

#[test]
fn an_arm_scenario_or_the_firmwares_arm_constants_given_to_the_one_dof_loop_are_named() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("out.csv");
    let arm_scenario = root().join("scenarios/arm3/pick_place.toml");
    // An arm scenario on the 1-DOF plant (or the arm plant: the scenario is read first).
    for p in [plant(), arm3_plant()] {
        let r = on_plant(
            "simulate",
            &p,
            &[&"--scenario", &arm_scenario, &"--out", &out],
        );
        assert_refused(
            &r,
            &[
                "pick_place.toml",
                "a 3-DOF arm scenario",
                "host-sim demo --plant host-sim/plants/arm3-seed001.toml",
            ],
            &out,
        );
    }
    // The firmware's arm constants given as a plant.
    let r = on_plant(
        "simulate",
        &root().join("config/arm3.toml"),
        &[
            &"--scenario",
            &root().join("scenarios/step.toml"),
            &"--out",
            &out,
        ],
    );
    assert_refused(
        &r,
        &[
            "config/arm3.toml",
            "the firmware's arm constants",
            "arm3-seed001.toml",
        ],
        &out,
    );
}
