//! End-to-end: the built `host-sim` binary generates identification data (`sweep`) and
//! identifies the force law, the torque model and plant parameters from it (`identify`).

mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::process::Output;

/// A `key = value` number of a TOML table (top-level scalar keys only).
fn toml_number(path: &Path, table: &str, key: &str) -> f64 {
    let v: toml::Table = std::fs::read_to_string(path).unwrap().parse().unwrap();
    v[table][key].as_float().unwrap()
}

/// "<label> MAE ... N ( x % of range)" -> x.
fn pct_of_range(stdout: &str, label: &str) -> f64 {
    let line = stdout.lines().find(|l| l.starts_with(label)).unwrap();
    let open = line.find('(').unwrap();
    line[open + 1..]
        .split_whitespace()
        .next()
        .unwrap()
        .parse()
        .unwrap()
}

/// `host-sim sweep <kind> --plant <reference plant> --out <out> <extra>`; its stdout (success
/// asserted).
fn sweep(kind: &str, out: &Path, extra: &[&str]) -> String {
    ok(&bin()
        .args(["sweep", kind, "--plant"])
        .arg(plant())
        .arg("--out")
        .arg(out)
        .args(extra)
        .output()
        .unwrap())
}

/// `text` (a CSV) with each line but the `#` comments rewritten by `row(its fields)`.
fn map_rows(text: &str, row: impl Fn(&[&str]) -> String) -> String {
    text.lines()
        .map(|l| {
            if l.starts_with('#') {
                format!("{l}\n")
            } else {
                format!("{}\n", row(&l.split(',').collect::<Vec<_>>()))
            }
        })
        .collect()
}

/// A temporary directory with the data of `host-sim sweep <kind> ... <extra>` in its file
/// `name`: the directory, that file and the sweep's stdout.
fn swept(kind: &str, name: &str, extra: &[&str]) -> (tempfile::TempDir, PathBuf, String) {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join(name);
    let s = sweep(kind, &data, extra);
    (dir, data, s)
}

/// `host-sim identify force --data <data> --out <out>`.
fn identify_force(data: &Path, out: &Path) -> Output {
    host_sim(&[&"identify", &"force", &"--data", &data, &"--out", &out])
}

/// A force map's head (the `#` comments and the column names, each with its newline) and
/// its data rows.
fn force_map_parts(text: &str) -> (String, Vec<&str>) {
    let (head, rows): (Vec<&str>, Vec<&str>) = text
        .lines()
        .partition(|l| l.starts_with('#') || l.starts_with("p_kpa"));
    (head.iter().map(|l| format!("{l}\n")).collect(), rows)
}

/// `identify force` on the map `map`, written as `name` in `dir`: refused with status 2 and
/// nothing written; its stderr.
fn force_map_refused(dir: &Path, name: &str, map: &str) -> String {
    let data = dir.join(name);
    std::fs::write(&data, map).unwrap();
    let out = dir.join("force.toml");
    let r = identify_force(&data, &out);
    assert_eq!(r.status.code(), Some(2), "{}", text(&r.stderr));
    assert!(!out.exists());
    text(&r.stderr)
}

/// `host-sim identify <kind> --recording <recording> --plant <reference plant> --out <out>
/// <extra>`.
fn identify(kind: &str, recording: &Path, out: &Path, extra: &[&str]) -> Output {
    bin()
        .args(["identify", kind, "--recording"])
        .arg(recording)
        .arg("--plant")
        .arg(plant())
        .arg("--out")
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn sweep_force_then_identify_force_reports_both_models_and_writes_the_firmware_toml() {
    let (dir, data, s) = swept("force", "F.csv", &[]);
    let out = dir.path().join("force.toml");
    assert!(s.contains("961 samples"), "{s}");
    let s = ok(&identify_force(&data, &out));
    println!("{s}");
    // Both models, with MAE, % of range, max error and where; no branch column.
    for want in [
        "eq. 6",
        "Tondu",
        "% of range",
        "max",
        "largest mean error",
        "not assessed",
    ] {
        assert!(s.contains(want), "missing {want:?} in\n{s}");
    }
    let eq6 = pct_of_range(&s, "eq. 6");
    assert!(eq6 < 0.77, "eq. 6 MAE {eq6} % of range");
    // The file has the layout build.rs reads, and the statistics as comments.
    let toml_text = std::fs::read_to_string(&out).unwrap();
    let t: toml::Table = toml_text.parse().unwrap();
    let c = t["force_law"]["c"].as_array().unwrap();
    assert_eq!(c.len(), 10);
    assert_eq!(c[7].as_float(), Some(1.0));
    assert_eq!(toml_number(&out, "force_law", "stretch_min"), 0.75);
    assert!(toml_text.contains("# eq. 6    MAE") && toml_text.contains("# Tondu    MAE"));
    assert!(toml_text.contains("# global search:") && toml_text.contains("# held out, one length"));
    assert!(!s.contains("look absolute"), "{s}");

    // The same bench logged with absolute pressures: the slack threshold lands on one
    // atmosphere, said so (the law would be written shifted by it).
    let abs = dir.path().join("F_abs.csv");
    let text = std::fs::read_to_string(&data).unwrap();
    let shifted = map_rows(&text, |f| {
        if f[0] == "p_kpa" {
            return f.join(",");
        }
        let p: f64 = f[0].parse().unwrap();
        format!("{:.4},{},{}", p + 101.325, f[1], f[2])
    });
    std::fs::write(&abs, shifted).unwrap();
    let s = ok(&identify_force(&abs, &dir.path().join("abs.toml")));
    assert!(
        s.contains("warning: the muscle goes taut at p_th = 101") && s.contains("look absolute"),
        "{s}"
    );
}

#[test]
fn identify_force_reports_the_hysteresis_gap_of_two_branches() {
    let (dir, data, _) = swept("force", "F.csv", &["--hysteresis-gap-n", "40"]);
    let out = dir.path().join("force.toml");
    let header = std::fs::read_to_string(&data)
        .unwrap()
        .lines()
        .find(|l| !l.starts_with('#'))
        .unwrap()
        .to_string();
    assert_eq!(header, "p_kpa,stretch,f_n,state");
    let s = ok(&identify_force(&data, &out));
    let line = s.lines().find(|l| l.starts_with("hysteresis:")).unwrap();
    // gap 40 N * P / Pmax, averaged over the (P, e) points with force: between 10 and 30 N.
    let mean: f64 = line
        .split("mean ")
        .nth(1)
        .unwrap()
        .split_whitespace()
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!((10.0..30.0).contains(&mean), "{line}");
}

#[test]
fn bad_force_data_names_file_line_and_field_and_keeps_the_old_output() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("bad.csv");
    let out = previous_output(dir.path(), "force.toml");
    let cases = [
        (
            "# meta\np_kpa,stretch,f_n\n100,0.9,50\n200,0.9,x\n",
            "bad.csv:4:",
            "`f_n`",
        ),
        ("p_kpa,stretch\n100,0.9\n", "bad.csv:1:", "`f_n`"),
        (
            "p_kpa,stretch,f_n\n100,-0.9,50\n",
            "bad.csv:2:",
            "`stretch`",
        ),
        (
            "p_kpa,stretch,f_n,state\n100,0.9,50,sideways\n",
            "bad.csv:2:",
            "`state`",
        ),
    ];
    for (body, at, field) in cases {
        std::fs::write(&data, body).unwrap();
        let r = identify_force(&data, &out);
        assert_eq!(r.status.code(), Some(2));
        let err = text(&r.stderr);
        assert!(err.contains(at) && err.contains(field), "{body:?}: {err}");
        assert_kept(&out);
    }
    // Too few samples for eq. 6: an error, and still no output.
    std::fs::write(&data, "p_kpa,stretch,f_n\n100,0.9,50\n200,0.9,90\n").unwrap();
    let r = identify_force(&data, &out);
    assert_eq!(r.status.code(), Some(2));
    assert!(text(&r.stderr).contains("at least 20 samples"));
    assert_kept(&out);
    // An output in a missing directory fails without leaving a temporary file behind.
    let good = dir.path().join("F.csv");
    sweep("force", &good, &[]);
    let r = identify_force(&good, &dir.path().join("no/such/dir/force.toml"));
    assert_eq!(r.status.code(), Some(2));
    assert!(text(&r.stderr).contains("no/such/dir/force.toml"));
}

#[test]
fn sweep_torque_then_identify_torque_recovers_the_plant_torque_model() {
    let (dir, rec, s) = swept("torque", "R.csv", &[]);
    let out = dir.path().join("torque.toml");
    println!("{s}");
    let s = ok(&identify(
        "torque",
        &rec,
        &out,
        &["--max-accel-rad-s2", "2"],
    ));
    println!("{s}");
    assert!(s.contains("the recorded tensions"), "{s}");
    let a = toml_number(&out, "torque_model", "a_n_per_m_rad");
    let b = toml_number(&out, "torque_model", "b_m2");
    let d = toml_number(&out, "torque_model", "d_nms_per_rad");
    let p0 = toml_number(&out, "torque_model", "p0_gauge_pa");
    let dp_max = toml_number(&out, "torque_model", "dp_max_pa");
    // The plant linearised about angle 0, p0 = 300 kPa: A = -23204 N/(m rad),
    // B = -1.926e-3 m^2, and exactly D = -2 gamma r^2 p0 / l = -0.30 N m s/rad, C = 0 (its
    // damper is linear). The least-squares line over +-0.35 rad differs from the tangent by < 2 %.
    assert!((a / -23204.0 - 1.0).abs() < 0.02, "A = {a}");
    assert!((b / -1.926e-3 - 1.0).abs() < 0.02, "B = {b}");
    assert!((d / -0.30 - 1.0).abs() < 0.01, "D = {d}");
    let c = toml_number(&out, "torque_model", "c_nms3_per_rad3");
    assert!(
        c.abs() * 64.0 < 0.01 * 0.3 * 4.0,
        "C = {c}: C w^3 at 4 rad/s above 1 % of D w"
    );
    assert!((p0 - 300e3).abs() < 100.0, "p0 = {p0}");
    // min(p0, supply - p0) - 20 kPa, to whole kPa.
    assert_eq!(dp_max, 280e3);
    let fit_line = s.lines().find(|l| l.starts_with("fit against")).unwrap();
    let fit: f64 = fit_line.split_whitespace().nth(5).unwrap().parse().unwrap();
    assert!(fit > 95.0, "{fit_line}");
}

#[test]
fn identify_torque_without_tensions_uses_the_plant_force_model_and_needs_pressures() {
    let (dir, full, _) = swept("torque", "R.csv", &["--speeds-rad-s", "0.5,2"]);
    // Drop the tension columns (the last two).
    let body = map_rows(&std::fs::read_to_string(&full).unwrap(), |f| {
        f[..f.len() - 2].join(",")
    });
    let no_f = dir.path().join("no_f.csv");
    std::fs::write(&no_f, &body).unwrap();
    let out = dir.path().join("torque.toml");
    let s = ok(&identify("torque", &no_f, &out, &[]));
    assert!(s.contains("the plant's force model"), "{s}");
    assert!((toml_number(&out, "torque_model", "a_n_per_m_rad") / -23204.0 - 1.0).abs() < 0.03);

    // Without p1_kpa: an error naming the file, the header line and the field.
    let lines: Vec<&str> = body.lines().collect();
    let header_at = lines.iter().position(|l| !l.starts_with('#')).unwrap();
    // t_s, 4 valves, angle_deg, p1_kpa, p2_kpa: drop p1_kpa.
    let no_p = map_rows(&body, |f| format!("{},{}", f[..6].join(","), f[7]));
    let bad = dir.path().join("no_p.csv");
    std::fs::write(&bad, no_p).unwrap();
    std::fs::write(&out, previous_output_text("torque.toml")).unwrap();
    let r = identify("torque", &bad, &out, &[]);
    assert_eq!(r.status.code(), Some(2));
    let err = text(&r.stderr);
    assert!(
        err.contains(&format!("no_p.csv:{}:", header_at + 1)) && err.contains("`p1_kpa`"),
        "{err}"
    );
    assert_kept(&out);
}

/// The reference plant file with `key = old` replaced by `key = new` (first match).
fn perturbed_plant(dir: &Path, edits: &[(&str, &str)]) -> PathBuf {
    let mut text = std::fs::read_to_string(plant()).unwrap();
    for (from, to) in edits {
        assert!(text.contains(from), "{from}");
        text = text.replacen(from, to, 1);
    }
    let p = dir.join("perturbed.toml");
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn identify_plant_recovers_perturbed_parameters_from_a_simulated_recording() {
    let dir = tempfile::tempdir().unwrap();
    let truth = perturbed_plant(
        dir.path(),
        &[
            ("damping_m2s = 2.0e-4", "damping_m2s = 3.0e-4"),
            (
                "sonic_conductance_m3_per_s_pa = 8.0e-9",
                "sonic_conductance_m3_per_s_pa = 6.5e-9",
            ),
        ],
    );
    let rec = dir.path().join("rec.csv");
    ok(&on_plant(
        "simulate",
        &truth,
        &[&"--inputs", &fixture("pulses_nominal.csv"), &"--out", &rec],
    ));
    let out = dir.path().join("P2.toml");
    let s = ok(&identify(
        "plant",
        &rec,
        &out,
        &[
            "--params",
            "muscle.damping_m2s,valve.sonic_conductance_m3_per_s_pa",
        ],
    ));
    println!("{s}");
    assert!(s.contains("held-out tail"), "{s}");
    // A complete plant file: loads, keeps the other values and the comments.
    let cfg = host_sim::PlantConfig::load(&out).unwrap();
    let reference = host_sim::PlantConfig::load(plant()).unwrap();
    assert_rel(cfg.muscle.damping_m2s, 3.0e-4, 0.01, &cfg);
    assert_rel(cfg.valve.sonic_conductance_m3_per_s_pa, 6.5e-9, 0.01, &cfg);
    assert_eq!(cfg.joint, reference.joint);
    assert_eq!(cfg.environment, reference.environment);
    // The comments of the keys not fitted are kept; a fitted value's says it was fitted
    // (the start file's described the start value).
    let out_text = std::fs::read_to_string(&out).unwrap();
    assert!(
        out_text.contains("# supply pressure (6 bar gauge)"),
        "{out_text}"
    );
    assert!(!out_text.contains("# gamma in F_d = gamma * p_gauge * dchi/dt"));
    let damping = out_text
        .lines()
        .find(|l| l.starts_with("damping_m2s"))
        .unwrap();
    assert!(
        damping.contains("# fitted by host-sim identify plant to"),
        "{damping}"
    );
}

#[test]
fn identify_plant_rejects_unknown_keys_and_bad_bounds_without_writing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("P2.toml");
    let pulses = fixture("pulses_nominal.csv");
    for (params, want) in [
        ("muscle.no_such_key", "`muscle.no_such_key`"),
        (
            "muscle.damping_m2s=1:2",
            "leave the range of `muscle.damping_m2s`",
        ),
        ("muscle.damping_m2s=0.001:0.002", "inside the bounds"),
        ("joint", "not a number"),
    ] {
        let r = identify("plant", &pulses, &out, &["--params", params]);
        assert_eq!(r.status.code(), Some(2));
        let err = text(&r.stderr);
        assert!(err.contains(want), "{params}: {err}");
        assert!(!out.exists());
    }
}

#[test]
fn identify_torque_warns_when_the_activation_is_not_symmetric() {
    // The pulses fixture drives the muscles independently: (p1 + p2) / 2 is far from constant,
    // which eq. 11 assumes: the fit is poor (2.41 %), refused with the cause; with
    // --allow-poor-fit it is written and the report says so.
    let dir = tempfile::tempdir().unwrap();
    let out = previous_output(dir.path(), "torque.toml");
    let r = identify("torque", &fixture("pulses_nominal.csv"), &out, &[]);
    let e = exits(2, &r);
    for n in [
        "pulses_nominal.csv",
        "2.41 %",
        "90 %",
        "(p1 + p2) / 2 spreads",
        "--allow-poor-fit",
    ] {
        assert!(e.contains(n), "`{n}` not in:\n{e}");
    }
    assert_kept(&out);
    let s = ok(&identify(
        "torque",
        &fixture("pulses_nominal.csv"),
        &out,
        &["--allow-poor-fit"],
    ));
    assert!(s.contains("warning: (p1 + p2) / 2 spreads"), "{s}");
    assert!(std::fs::read_to_string(&out)
        .unwrap()
        .contains("[torque_model]"));
}

#[test]
fn identify_plant_finds_the_load_inertia_in_the_independent_loaded_fixture() {
    // pulses_loaded.csv was computed by an independent implementation from
    // reference-1dof-loaded.toml (J = 0.155 kg m^2, 11 x the nominal 0.014). Starting from the
    // nominal plant, the fit must find the load and leave damping and conductance alone.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("P2.toml");
    let s = ok(&identify(
        "plant",
        &fixture("pulses_loaded.csv"),
        &out,
        &[
            "--params",
            "joint.inertia_kgm2,muscle.damping_m2s,valve.sonic_conductance_m3_per_s_pa",
        ],
    ));
    println!("{s}");
    let cfg = host_sim::PlantConfig::load(&out).unwrap();
    assert_rel(cfg.joint.inertia_kgm2, 0.155, 0.005, &cfg);
    assert_rel(cfg.muscle.damping_m2s, 2.0e-4, 0.005, &cfg);
    assert_rel(cfg.valve.sonic_conductance_m3_per_s_pa, 8.0e-9, 0.005, &cfg);
    // Held-out tail: the mean fit goes from about 51 % to the conformance level.
    let tail = s
        .split("held-out tail")
        .nth(1)
        .unwrap()
        .lines()
        .find(|l| l.trim_start().starts_with("mean"))
        .unwrap()
        .to_string();
    let v: Vec<f64> = tail
        .split_whitespace()
        .skip(1)
        .map(|x| x.parse().unwrap())
        .collect();
    assert!(v[0] < 80.0 && v[1] > 99.5, "{tail}");
    assert!(!s.contains("ended at its"), "{s}");
    // Each value gets its interval: values of very different sizes (8e-9 next to 0.155) are
    // each stepped by their own size (a step of 1e-4 for the conductance called all three
    // "not determined").
    assert!(!s.contains("not determined"), "{s}");
    for key in [
        "joint.inertia_kgm2",
        "muscle.damping_m2s",
        "valve.sonic_conductance_m3_per_s_pa",
    ] {
        // The fixture is noise-free: an interval of (almost) zero width is said not
        // estimable, never "+-0.00 %".
        let row = s.lines().find(|l| l.starts_with(key)).unwrap();
        assert!(
            (row.trim_end().ends_with('%') && row.contains("+-")) || row.contains("not estimable"),
            "{row}"
        );
        assert!(!row.contains("+-0.00 %"), "{row}");
    }
    // Bounds that leave the rig's inertia outside: the fit ends at the upper one and says so.
    let r = identify(
        "plant",
        &fixture("pulses_loaded.csv"),
        &out,
        &[
            "--params",
            "joint.inertia_kgm2=0.001:0.1",
            "--allow-poor-fit",
        ],
    );
    let s = text(&r.stdout);
    assert!(
        s.contains("warning: joint.inertia_kgm2 ended at its upper bound 1.000000e-1"),
        "{s}\n{}",
        text(&r.stderr)
    );
}

/// Asserts `value` within the relative tolerance `rel` of `want` (`context` shown otherwise).
fn assert_rel(value: f64, want: f64, rel: f64, context: &dyn std::fmt::Debug) {
    assert!(
        (value / want - 1.0).abs() < rel,
        "{value} is not within {rel} (relative) of {want}: {context:?}"
    );
}

/// Data that fits eq. 11 at 97-99 % but cannot determine it: a sweep at one activation
/// (dp = 0: B is noise), the angle logged in radians (A 57 times too large), pressures in
/// bar. Refused by `identify torque` itself, as `calibrate` refuses them; an earlier output
/// stays; a recording given as --out of another kind is never replaced.
#[test]
fn identify_torque_refuses_data_that_cannot_determine_the_model() {
    let (dir, one_level, _) = swept("torque", "R.csv", &["--dp-kpa", "0"]);
    let out = dir.path().join("torque.toml");
    let e = text(&identify("torque", &one_level, &out, &[]).stderr);
    assert!(
        e.contains("does not vary") && e.contains("several activations") && !out.exists(),
        "{e}"
    );
    let full = dir.path().join("full.csv");
    sweep("torque", &full, &[]);
    let text_of = std::fs::read_to_string(&full).unwrap();
    let names: Vec<String> = text_of
        .lines()
        .find(|l| !l.starts_with('#'))
        .unwrap()
        .split(',')
        .map(String::from)
        .collect();
    let rewrite = |f: &dyn Fn(&str, &str) -> String| {
        map_rows(&text_of, |fields| {
            if fields[0] == "t_s" {
                return fields.join(",");
            }
            fields
                .iter()
                .zip(&names)
                .map(|(v, n)| f(n, v))
                .collect::<Vec<_>>()
                .join(",")
        })
    };
    let radians = dir.path().join("rad.csv");
    std::fs::write(
        &radians,
        rewrite(&|n, v| {
            if n == "angle_deg" {
                format!("{:.6}", v.parse::<f64>().unwrap().to_radians())
            } else {
                v.to_string()
            }
        }),
    )
    .unwrap();
    let e = text(&identify("torque", &radians, &out, &[]).stderr);
    assert!(e.contains("an angle logged in radians"), "{e}");
    let bar = dir.path().join("bar.csv");
    std::fs::write(
        &bar,
        rewrite(&|n, v| {
            if n == "p1_kpa" || n == "p2_kpa" {
                format!("{:.6}", v.parse::<f64>().unwrap() / 100.0)
            } else {
                v.to_string()
            }
        }),
    )
    .unwrap();
    let e = text(&identify("torque", &bar, &out, &[]).stderr);
    assert!(e.contains("logged in bar or MPa"), "{e}");
    assert!(!out.exists());
    // --out naming a recording: refused before the fit, the recording kept.
    let before = std::fs::read(&radians).unwrap();
    let e = text(&identify("torque", &full, &radians, &[]).stderr);
    assert!(e.contains("exists and is not a torque-model file"), "{e}");
    assert_eq!(std::fs::read(&radians).unwrap(), before);
}

/// A force map at two lengths fits them well and says nothing between them: refused, naming
/// the lengths.
#[test]
fn identify_force_refuses_a_map_of_two_lengths() {
    let (dir, data, _) = swept("force", "force.csv", &[]);
    let text_of = std::fs::read_to_string(&data).unwrap();
    let mut lengths: Vec<String> = Vec::new();
    let kept: String = text_of
        .lines()
        .filter(|l| {
            let f: Vec<&str> = l.split(',').collect();
            if l.starts_with('#') || f[0] == "p_kpa" {
                return true;
            }
            if !lengths.iter().any(|e| e == f[1]) && lengths.len() < 2 {
                lengths.push(f[1].to_string());
            }
            lengths.iter().any(|e| e == f[1])
        })
        .map(|l| format!("{l}\n"))
        .collect();
    let e = force_map_refused(dir.path(), "two.csv", &kept);
    assert!(
        e.contains("2 lengths only") && e.contains("sweep at least 3 lengths"),
        "{e}"
    );
    // The same two lengths read through a length sensor's jitter (+-0.0004 L/L0, each row
    // a different reading): still 2 lengths, not one per reading.
    let k = std::cell::Cell::new(0usize);
    let jittered = map_rows(&kept, |f| {
        if f[0] == "p_kpa" {
            return f.join(",");
        }
        k.set(k.get() + 1);
        let e = f[1].parse::<f64>().unwrap() + 0.0004 * ((k.get() % 3) as f64 - 1.0);
        format!("{},{e:.6},{}", f[0], f[2..].join(","))
    });
    let e = force_map_refused(dir.path(), "two.csv", &jittered);
    assert!(e.contains("2 lengths only"), "{e}");
}

/// Twelve operating points logged three times each pass the sample count (36 >= 20) but
/// give eq. 6's 9 constants only 12 equations: refused, naming the distinct points and the
/// copied rows.
#[test]
fn identify_force_refuses_repeated_rows_of_too_few_points() {
    let (dir, data, _) = swept("force", "force.csv", &[]);
    let text_of = std::fs::read_to_string(&data).unwrap();
    let (head, rows) = force_map_parts(&text_of);
    let mut picked: Vec<&str> = Vec::new();
    let mut per_length: Vec<(String, usize)> = Vec::new();
    for l in rows {
        let f: Vec<&str> = l.split(',').collect();
        // Four points (different pressures) at each of the first three lengths.
        let known = per_length.len();
        match per_length.iter_mut().find(|(e, _)| e == f[1]) {
            Some((_, n)) if *n < 4 => {
                *n += 1;
                picked.push(l);
            }
            None if known < 3 => {
                per_length.push((f[1].to_string(), 1));
                picked.push(l);
            }
            _ => {}
        }
    }
    assert_eq!(picked.len(), 12);
    let rows: String = (0..3)
        .flat_map(|_| picked.iter())
        .map(|l| format!("{l}\n"))
        .collect();
    let e = force_map_refused(dir.path(), "thrice.csv", &format!("{head}{rows}"));
    assert!(
        e.contains("36 samples hold 12 distinct operating points")
            && e.contains("24 of them exact copies"),
        "{e}"
    );
    // The same repeats with a length sensor's jitter (+-0.0004 L/L0) and pressure noise
    // (+-0.8 kPa): still 12 points, none an exact copy.
    let jittered: String = (0..3)
        .flat_map(|r| picked.iter().map(move |l| (r, l)))
        .map(|(r, l)| {
            let f: Vec<&str> = l.split(',').collect();
            let d = r as f64 - 1.0;
            let p = f[0].parse::<f64>().unwrap() + 0.8 * d;
            let e = f[1].parse::<f64>().unwrap() + 0.0004 * d;
            format!("{p:.3},{e:.6},{}\n", f[2..].join(","))
        })
        .collect();
    let e = force_map_refused(dir.path(), "thrice.csv", &format!("{head}{jittered}"));
    assert!(
        e.contains("36 samples hold 12 distinct operating points") && !e.contains("copies"),
        "{e}"
    );
}

/// The force column shuffled against the pressures and lengths (rows mixed up by a
/// spreadsheet sort of one column): eq. 6 cannot describe it; refused, nothing written.
#[test]
fn identify_force_refuses_a_map_eq6_does_not_describe() {
    let (dir, data, _) = swept("force", "force.csv", &[]);
    let text_of = std::fs::read_to_string(&data).unwrap();
    let (_, rows) = force_map_parts(&text_of);
    let n = rows.len();
    let forces: Vec<&str> = rows.iter().map(|r| r.rsplit(',').next().unwrap()).collect();
    let k = std::cell::Cell::new(0usize);
    let shuffled = map_rows(&text_of, |f| {
        if f[0] == "p_kpa" {
            return f.join(",");
        }
        let j = (k.get() * 7919 + 13) % n;
        k.set(k.get() + 1);
        format!("{},{},{}", f[0], f[1], forces[j])
    });
    let e = force_map_refused(dir.path(), "shuffled.csv", &shuffled);
    assert!(e.contains("eq. 6 does not describe this map"), "{e}");
}

#[test]
fn sweep_torque_writes_its_time_stamps_as_decimals_of_its_grid() {
    // The stamps were summed steps: 0.030000000000000002 for the 7th at 5 ms.
    let (_dir, rec, _) = swept(
        "torque",
        "R.csv",
        &["--dp-kpa", "0", "--speeds-rad-s", "1,4", "--dt-s", "0.005"],
    );
    let text = std::fs::read_to_string(&rec).unwrap();
    let stamps: Vec<&str> = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .skip(1)
        .map(|l| l.split(',').next().unwrap())
        .collect();
    assert!(stamps.len() > 100, "{}", stamps.len());
    for (k, t) in stamps.iter().enumerate() {
        let want = format!("{}", (k as f64 * 5e6).round() / 1e9);
        assert_eq!(*t, want, "row {k}");
    }
}

#[test]
fn sweep_arguments_out_of_their_physical_range_are_refused_with_the_range() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("sweep.csv");
    for (kind, args, want) in [
        // An encoder of 3 counts a turn reads the sweep's +-20 degrees as 0 throughout.
        (
            "torque",
            vec!["--encoder-counts", "3"],
            "0 (no angle quantisation) or 360..=1073741824 counts per turn, got 3",
        ),
        // A branch gap of 10 kN on a muscle of about 1.9 kN: the bound is said in newtons.
        (
            "force",
            vec!["--hysteresis-gap-n", "10000"],
            "a quarter of the sweep's largest force",
        ),
        (
            "force",
            vec!["--seed", "-1"],
            "must be within 0..=18446744073709551615, got -1",
        ),
        (
            "force",
            vec!["--stretch-min", "1.2", "--stretch-max", "1.0"],
            "--stretch-min 1.2 must be > 0 and below --stretch-max 1",
        ),
    ] {
        let r = bin()
            .args(["sweep", kind, "--plant"])
            .arg(plant())
            .arg("--out")
            .arg(&out)
            .args(&args)
            .output()
            .unwrap();
        assert_refused(&r, &[want], &out);
    }
    // A gap within the bound still sweeps both branches.
    let text = sweep("force", &out, &["--hysteresis-gap-n", "20"]);
    assert!(text.contains("both branches"), "{text}");
    // The force map into a directory that does not exist names the directory, not a
    // temporary file.
    let r = bin()
        .args(["sweep", "force-map", "--out"])
        .arg(dir.path().join("no_dir/map.csv"))
        .output()
        .unwrap();
    assert_eq!(r.status.code(), Some(2));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        err.contains("no_dir") && err.contains("does not exist") && !err.contains(".map.csv."),
        "{err}"
    );
}

#[test]
fn a_recording_too_short_for_identify_plant_is_named_with_the_minimum() {
    let dir = tempfile::tempdir().unwrap();
    // The first 15 samples of the conformance recording (its 3 comment lines and header).
    let text = std::fs::read_to_string(fixture("pulses_nominal.csv")).unwrap();
    let short = dir.path().join("short.csv");
    std::fs::write(
        &short,
        text.lines().take(19).collect::<Vec<_>>().join("\n") + "\n",
    )
    .unwrap();
    let out = dir.path().join("P.toml");
    let r = identify("plant", &short, &out, &["--params", "joint.inertia_kgm2"]);
    assert_refused(&r, &["short.csv: recording too short", "at least 20"], &out);
}
