//! A rig logger's file (40 Hz with +-15 % time stamp jitter, time in ms, pressures in bar
//! absolute, a FESTO MPYE-style proportional valve per muscle commanded in volts, the angle
//! in encoder counts, `;` separated with decimal commas) goes through `host-sim import` and
//! then `simulate` and `diagnose`.
//!
//! The rig data come from the nominal plant through another path than the tools use: a
//! uniform 0.25 ms open-loop replay (`host_sim::simulate`) with the valve openings held
//! between the jittered stamps (which lie on that fine grid), sampled at the stamps, then
//! noise, encoder quantisation and the unit conversions written out here.

mod common;
use common::*;
use std::path::{Path, PathBuf};

use host_sim::io::compare::compare;
use host_sim::{simulate, Plant, Recording, SolverOptions, ValveInputs};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};

const FINE_DT_S: f64 = 0.000_25;
const NOMINAL_STEP_S: f64 = 0.025; // 40 Hz
const P_ATM_PA: f64 = 101_325.0;

fn tmp() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

/// The rig's valve amplifier: signed opening -> volts (5 V closed, +-0.2 V dead band).
fn volts_of(s: f64) -> f64 {
    if s > 0.0 {
        5.2 + 4.8 * s
    } else if s < 0.0 {
        4.8 + 4.8 * s
    } else {
        5.0
    }
}

const MAP: &str = r#"
# A FESTO joint logged by a PC at about 40 Hz: German CSV, two lines of logger header.
[csv]
delimiter = ";"
decimal = ","
skip_lines = 2

[time]
column = "Zeit [ms]"
unit = "ms"

[pressure]
p_atm_pa = 101325.0

[[channel]]
column = "P1 [bar abs]"
channel = "p1"
unit = "bar"
reference = "absolute"

[[channel]]
column = "P2 [bar abs]"
channel = "p2"
unit = "bar"
reference = "absolute"

[[channel]]
column = "Encoder"
channel = "angle"
unit = "counts"
counts_per_rev = 8000

[[channel]]
column = "MPYE1 [V]"
channel = "valve1"
unit = "V"
curve = [[0.0, -1.0], [4.8, 0.0], [5.2, 0.0], [10.0, 1.0]]

[[channel]]
column = "MPYE2 [V]"
channel = "valve2"
unit = "V"
curve = [[0.0, -1.0], [4.8, 0.0], [5.2, 0.0], [10.0, 1.0]]
"#;

/// Writes the rig file; returns its path and the true gauge pressures at the stamps [Pa].
fn rig_file(dir: &Path, duration_s: f64, seed: u64, drop_rows: &[usize]) -> (PathBuf, Vec<f64>) {
    let plant = Plant::load(plant()).unwrap();
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    // Jittered stamps on the fine grid: k * 25 ms +- 15 % (3.75 ms).
    let n = (duration_s / NOMINAL_STEP_S) as usize;
    let jitter_ticks = (0.15 * NOMINAL_STEP_S / FINE_DT_S).round() as i64; // 15
    let nominal_ticks = (NOMINAL_STEP_S / FINE_DT_S).round() as i64; // 100
    let stamps: Vec<i64> = (0..n as i64)
        .map(|k| {
            if k == 0 {
                0
            } else {
                k * nominal_ticks + rng.random_range(-jitter_ticks..=jitter_ticks)
            }
        })
        .collect();
    // Signed openings per stamp: held levels of 2..8 samples.
    let levels = [-1.0, -0.6, -0.3, 0.0, 0.25, 0.5, 1.0];
    let mut s = vec![[0.0f64; 2]; n];
    let mut k = 0;
    while k < n {
        let hold = rng.random_range(2..=8);
        let v = [
            levels[rng.random_range(0..levels.len())],
            levels[rng.random_range(0..levels.len())],
        ];
        for row in s.iter_mut().skip(k).take(hold) {
            *row = v;
        }
        k += hold;
    }
    // The fine replay: openings held from each stamp to the next.
    let fine_n = (stamps[n - 1] + nominal_ticks) as usize;
    let mut fine = Vec::with_capacity(fine_n);
    let mut j = 0;
    for i in 0..fine_n as i64 {
        while j + 1 < n && stamps[j + 1] <= i {
            j += 1;
        }
        let [a, b] = s[j];
        fine.push(ValveInputs {
            u_in1: a.max(0.0),
            u_ex1: (-a).max(0.0),
            u_in2: b.max(0.0),
            u_ex2: (-b).max(0.0),
        });
    }
    let sim = simulate(&plant, &fine, FINE_DT_S, &SolverOptions::default()).unwrap();
    let noise = Normal::new(0.0, 500.0).unwrap();
    let mut text = String::from(
        "Prüfstand Muskelgelenk, Messung 7\nexportiert am 23.11.2026\n\
         Zeit [ms];P1 [bar abs];P2 [bar abs];Encoder;MPYE1 [V];MPYE2 [V];Temp [C]\n",
    );
    let mut p_true = Vec::new();
    for k in 0..n {
        if drop_rows.contains(&k) {
            continue;
        }
        let x = sim.states[stamps[k] as usize];
        let p1 = x.p1_abs_pa + noise.sample(&mut rng);
        let p2 = x.p2_abs_pa + noise.sample(&mut rng);
        p_true.push(x.p1_abs_pa - P_ATM_PA);
        let counts = (x.angle_rad / (2.0 * std::f64::consts::PI) * 8000.0).floor() as i64;
        let row = format!(
            "{:.2};{:.5};{:.5};{};{:.4};{:.4};21,5\n",
            stamps[k] as f64 * FINE_DT_S * 1e3,
            p1 / 1e5,
            p2 / 1e5,
            counts,
            volts_of(s[k][0]),
            volts_of(s[k][1]),
        );
        // Decimal commas, as the lab's locale writes them.
        text.push_str(&row.replace('.', ","));
    }
    let path = dir.join("rig.csv");
    std::fs::write(&path, text).unwrap();
    (path, p_true)
}

fn write_map(dir: &Path, text: &str) -> PathBuf {
    let p = dir.join("map.toml");
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn jittered_40hz_bar_and_volts_rig_file_imports_simulates_and_diagnoses() {
    let dir = tmp();
    let (raw, p_true) = rig_file(dir.path(), 20.0, 11, &[]);
    let map = write_map(dir.path(), MAP);
    let rec_path = dir.path().join("rec.csv");
    let out = host_sim(&[
        &"import", &"--map", &map, &"--input", &raw, &"--out", &rec_path,
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}{}",
        stdout,
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("0 gap(s)"), "{stdout}");

    // The recording: jittered, kPa gauge, openings from the volts.
    let rec = Recording::read(&rec_path).unwrap();
    assert_eq!(rec.len(), 800);
    assert!(!rec.is_uniform(), "the stamps jitter by up to 15 %");
    let p1 = rec.channel(host_sim::Channel::P1Kpa).unwrap();
    for (k, (m, t)) in p1.iter().zip(&p_true).enumerate() {
        assert!(
            (m * 1e3 - t).abs() < 3_000.0,
            "sample {k}: {m} kPa vs {t} Pa"
        );
    }
    assert!(rec.inputs.iter().any(|u| u.u_in1 == 1.0) && rec.inputs.iter().any(|u| u.u_ex2 == 1.0));
    assert!(rec.inputs.iter().any(|u| u.u_in1 > 0.2 && u.u_in1 < 0.3));

    // simulate replays it between its own stamps and fits the rig data closely.
    let sim_path = dir.path().join("sim.csv");
    let out = on_plant(
        "simulate",
        &plant(),
        &[&"--inputs", &rec_path, &"--out", &sim_path],
    );
    ok(&out);
    let sim = Recording::read(&sim_path).unwrap();
    assert_eq!(sim.t_s, rec.t_s);
    let fits = compare(&rec, &sim).unwrap();
    for f in &fits {
        eprintln!(
            "simulate vs rig: {:?} fit {:.2} %",
            f.channel, f.fit_percent
        );
        assert!(f.fit_percent > 90.0, "{:?}: {}", f.channel, f.fit_percent);
    }

    // diagnose takes the jittered recording and finds nothing missing in a nominal rig.
    let json = dir.path().join("d.json");
    let out = on_plant(
        "diagnose",
        &plant(),
        &[&"--recording", &rec_path, &"--json", &json],
    );
    let stdout = ok(&out);
    let d: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    eprintln!("diagnose: {stdout}");
    assert_eq!(d["effects"].as_array().unwrap().len(), 0, "{stdout}\n{d:#}");
    // docs/rig.md's answer for this example.
    assert_eq!(d["verdict"], "nothing_missing", "{stdout}");
    assert!(stdout.contains("Nothing is missing"), "{stdout}");
}

#[test]
fn stamped_replay_beats_treating_jittered_stamps_as_uniform() {
    // The same jittered rig data replayed as if the stamps were uniform fits worse: the
    // jitter handling matters (a test that fails if `simulate` ignored the stamps).
    let dir = tmp();
    let (raw, _) = rig_file(dir.path(), 10.0, 5, &[]);
    let map = write_map(dir.path(), MAP);
    let mapping = host_sim::io::import::Mapping::load(&map).unwrap();
    let imp = host_sim::io::import::import(&mapping, &map, &raw, false).unwrap();
    let rec = &imp.segments[0];
    assert!(
        imp.max_jitter > 0.2 && imp.max_jitter <= 0.31,
        "{}",
        imp.max_jitter
    );
    let plant = Plant::load(plant()).unwrap();
    let opts = SolverOptions::default();
    let fit_of = |states: &[host_sim::PlantState]| {
        let mut m = rec.clone();
        let meas = plant.measure_series(states, rec.sample_period_s());
        for c in host_sim::Channel::ALL {
            if rec.channel(c).is_some() {
                m.set_channel(c, meas.iter().map(|x| c.of(x)).collect());
            }
        }
        compare(rec, &m).unwrap()
    };
    let stamped =
        host_sim::io::replay_stream::simulate_recording(&plant, rec, &opts, |_| {}).unwrap();
    let uniform = simulate(&plant, &rec.inputs, rec.sample_period_s(), &opts).unwrap();
    let (a, b) = (fit_of(&stamped.states), fit_of(&uniform.states));
    let p1 = |f: &Vec<host_sim::io::compare::ChannelFit>| {
        f.iter()
            .find(|c| c.channel == host_sim::Channel::P1Kpa)
            .unwrap()
            .fit_percent
    };
    eprintln!(
        "p1 fit: stamped {:.2} %, stamps taken as uniform {:.2} %",
        p1(&a),
        p1(&b)
    );
    assert!(
        p1(&a) > p1(&b) + 2.0,
        "stamped {} vs uniform {}",
        p1(&a),
        p1(&b)
    );
}

#[test]
fn gaps_are_listed_and_refused_or_split_never_filled() {
    let dir = tmp();
    let (raw, _) = rig_file(dir.path(), 6.0, 3, &[100, 101, 102]);
    let map = write_map(dir.path(), MAP);
    let out_path = dir.path().join("rec.csv");
    let out = host_sim(&[
        &"import", &"--map", &map, &"--input", &raw, &"--out", &out_path,
    ]);
    let e = exits(2, &out);
    // Row 100 of the data is line 104 (2 skipped, header, 1-based); the first kept row after
    // the gap is data row 103 -> line 104.
    assert!(
        e.contains("rig.csv") && e.contains("1 gap(s)") && e.contains("line 104"),
        "{e}"
    );
    assert!(!out_path.exists());
    // A third segment left by an earlier import of another file is named, not taken over.
    std::fs::write(dir.path().join("rec-3.csv"), "earlier").unwrap();
    let out = host_sim(&[
        &"import", &"--split", &"--map", &map, &"--input", &raw, &"--out", &out_path,
    ]);
    ok(&out);
    let report = String::from_utf8_lossy(&out.stdout);
    assert!(
        report.contains("rec-3.csv is not part of this import (2 segments)"),
        "{report}"
    );
    assert_eq!(
        std::fs::read_to_string(dir.path().join("rec-3.csv")).unwrap(),
        "earlier"
    );
    let a = Recording::read(dir.path().join("rec-1.csv")).unwrap();
    let b = Recording::read(dir.path().join("rec-2.csv")).unwrap();
    assert_eq!(a.len(), 100);
    assert_eq!(a.len() + b.len(), 240 - 3);
    // Data row 103 alone between two gaps (line 104 of the file without the dropped rows):
    // left out, and said so.
    let (raw, _) = rig_file(dir.path(), 6.0, 3, &[100, 101, 102, 104, 105, 106]);
    let out = host_sim(&[
        &"import",
        &"--split",
        &"--map",
        &map,
        &"--input",
        &raw,
        &"--out",
        &dir.path().join("alone.csv"),
    ]);
    ok(&out);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(
        e.contains("rig.csv:104: a single sample between two gaps") && e.contains("left out"),
        "{e}"
    );
}

#[test]
fn unit_mistakes_in_a_mapping_are_refused_at_their_line_or_flagged() {
    let dir = tmp();
    let (raw, _) = rig_file(dir.path(), 2.0, 5, &[]);
    let out_path = dir.path().join("rec.csv");
    let run = |map_text: &str| {
        let map = write_map(dir.path(), map_text);
        host_sim(&[
            &"import", &"--map", &map, &"--input", &raw, &"--out", &out_path,
        ])
    };
    let refused = |map_text: &str, needles: &[&str]| {
        let out = run(map_text);
        let e = exits(2, &out);
        for n in needles {
            assert!(e.contains(n), "`{n}` not in: {e}");
        }
        assert!(!out_path.exists(), "{e}");
    };
    // The atmosphere typed in kPa into its Pa key (line 13 of the mapping).
    refused(
        &MAP.replace("p_atm_pa = 101325.0", "p_atm_pa = 101.325"),
        &[
            "map.toml:13",
            "pressure.p_atm_pa",
            "kPa typed into a Pa key",
        ],
    );
    // A time column in ms declared as seconds: a 25 s median step.
    refused(
        &MAP.replace("unit = \"ms\"", "unit = \"s\""),
        &[
            "rig.csv:5",
            "Zeit [ms]",
            "median time step is 25 s",
            "a smaller one, e.g. ms declared s",
        ],
    );
    // The same column declared as microseconds: a 40 kHz step, faster than a PAM rig is
    // logged, and 40 Hz in ms (whatever the file's length: a long log is no excuse).
    refused(
        &MAP.replace("unit = \"ms\"", "unit = \"us\""),
        &[
            "rig.csv:",
            "Zeit [ms]",
            "faster than a PAM rig is logged",
            "is the time column in ms?",
            "at 40",
        ],
    );
    // Absolute pressures below vacuum: the atmosphere given as 2 bar.
    refused(
        &MAP.replace(
            "p_atm_pa = 101325.0",
            "p_atm_pa = 101325.0\nregulator_band_pa = 2e4",
        )
        .replace(
            "[[channel]]\ncolumn = \"P1 [bar abs]\"",
            "[[channel]]\ncolumn = \"P1 [bar abs]\"\noffset = -3.0",
        ),
        &[
            "rig.csv:",
            "P1 [bar abs]",
            "-104.608 kPa gauge is below vacuum (-101.325 kPa)",
        ],
    );
    // Bar mapped as MPa: ten times too high, refused at the raw file's line and column
    // (not at the output's, as the recording's own range check would).
    refused(
        &MAP.replacen(
            "channel = \"p1\"\nunit = \"bar\"",
            "channel = \"p1\"\nunit = \"MPa\"",
            1,
        ),
        &[
            "rig.csv:",
            "P1 [bar abs]",
            "kPa gauge is above 2500 kPa",
            "bar mapped as MPa",
        ],
    );
    // Millivolts mapped as volts (scale 1000 stands for the logger's mV): every command far
    // beyond the 0..10 V curve, which would clamp all of them to full opening.
    refused(
        &MAP.replacen(
            "column = \"MPYE1 [V]\"\nchannel = \"valve1\"\nunit = \"V\"",
            "column = \"MPYE1 [V]\"\nchannel = \"valve1\"\nunit = \"V\"\nscale = 1000.0",
            1,
        ),
        &[
            "rig.csv:",
            "MPYE1 [V]",
            "outside its curve's 0..10 V",
            "a value in mV?",
        ],
    );
    // Two entries for one channel: both named with their lines.
    let dup = MAP.replacen("channel = \"p2\"", "channel = \"p1\"", 1);
    refused(
        &dup,
        &[&format!(
            "channel[1] (line {}) and channel[0] (line {}) both map `p1`",
            line_of(&dup, "channel = \"p1\"", 1),
            line_of(&dup, "channel = \"p1\"", 0)
        )],
    );
    // Encoder counts mapped as degrees: the hint names the unit the mapping gave.
    refused(
        &MAP.replace("unit = \"counts\"\ncounts_per_rev = 8000", "unit = \"deg\""),
        &[
            "rig.csv:",
            "Encoder",
            "encoder counts mapped with `unit = \"deg\"`",
        ],
    );
    // A scale of zero would flatten the channel.
    refused(
        &MAP.replacen(
            "channel = \"p1\"\nunit = \"bar\"",
            "channel = \"p1\"\nscale = 0.0\nunit = \"bar\"",
            1,
        ),
        &["map.toml:", "channel[0]", "`scale`", "other than 0"],
    );
    // Gauge bar read as kPa, and absolute bar read as kPa, are possible but suspect:
    // imported, with a warning naming the channel, and each channel's range.
    let warned = |map_text: &str, needles: &[&str]| {
        let out = run(map_text);
        ok(&out);
        // The ranges on stdout, the warnings on stderr.
        let report = String::from_utf8_lossy(&out.stdout).into_owned()
            + &String::from_utf8_lossy(&out.stderr);
        for n in needles {
            assert!(report.contains(n), "`{n}` not in: {report}");
        }
        assert!(!report.contains("warning: p2"), "{report}");
        assert!(
            !String::from_utf8_lossy(&out.stdout).contains("warning:"),
            "warnings belong on stderr"
        );
    };
    warned(
        &MAP.replacen(
            "unit = \"bar\"\nreference = \"absolute\"",
            "unit = \"kPa\"\noffset = -1.01325",
            1,
        ),
        &[
            "warning: p1 never exceeds 10 kPa gauge",
            "bar or MPa read as kPa",
            "p2 (column `P2 [bar abs]`):",
        ],
    );
    warned(
        &MAP.replacen("unit = \"bar\"", "unit = \"kPa\"", 1),
        &["warning: p1 goes down to -100.", "absolute read as gauge"],
    );
}

#[test]
fn bad_mapping_and_bad_cells_name_file_line_and_column() {
    let dir = tmp();
    let (raw, _) = rig_file(dir.path(), 2.0, 1, &[]);
    let run = |map_text: &str, raw: &Path| {
        let map = write_map(dir.path(), map_text);
        let out_path = dir.path().join("never.csv");
        let out = host_sim(&[
            &"import", &"--map", &map, &"--input", &raw, &"--out", &out_path,
        ]);
        assert_eq!(out.status.code(), Some(2));
        assert!(!out_path.exists());
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let e = run(&MAP.replace("unit = \"bar\"", "unit = \"atm\""), &raw);
    assert!(
        e.contains("map.toml") && e.contains("`unit`") && e.contains("atm"),
        "{e}"
    );
    let e = run(&MAP.replace("\"Encoder\"", "\"Enc\""), &raw);
    assert!(e.contains("rig.csv:3") && e.contains("`Enc`"), "{e}");
    let e = run(
        &MAP.replace("channel = \"valve2\"", "channel = \"valve9\""),
        &raw,
    );
    assert!(e.contains("valve9"), "{e}");
    let text = std::fs::read_to_string(&raw).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    lines[9] = lines[9].replacen(';', ";x", 1);
    let bad = dir.path().join("bad.csv");
    std::fs::write(&bad, lines.join("\n")).unwrap();
    let e = run(MAP, &bad);
    assert!(
        e.contains("bad.csv:10") && e.contains("`P1 [bar abs]`"),
        "{e}"
    );
    // The cell is quoted as the file has it, with what it probably is: a thousands
    // separator, or decimal commas read with the default `decimal = "."`.
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let cells: Vec<&str> = lines[9].split(';').collect();
    let t_ms = cells[0].to_string();
    lines[9] = lines[9].replacen(&t_ms, "1.234,5", 1);
    std::fs::write(&bad, lines.join("\n")).unwrap();
    let e = run(MAP, &bad);
    assert!(
        e.contains("bad.csv:10") && e.contains("\"1.234,5\"") && e.contains("thousands separator"),
        "{e}"
    );
    let e = run(&MAP.replace("decimal = \",\"\n", ""), &raw);
    assert!(
        e.contains("decimal comma") && e.contains("decimal = \",\""),
        "{e}"
    );
    // A binary file: said so in a line, not its bytes on the terminal.
    let binary = dir.path().join("log.bin");
    let mut bytes = b"\x04\x00\x00\x12".repeat(300);
    bytes.extend_from_slice(text.as_bytes());
    std::fs::write(&binary, bytes).unwrap();
    let e = run(MAP, &binary);
    assert!(
        e.contains("log.bin: not a text file (a NUL byte at byte 1)") && e.lines().count() == 1,
        "{e}"
    );
}

#[test]
fn regulator_set_points_become_proportional_openings() {
    // A rig with a pressure regulator per muscle: the openings follow the documented
    // proportional-band model from the set-point and the measured pressure.
    let dir = tmp();
    let raw = dir.path().join("reg.csv");
    std::fs::write(
        &raw,
        "t,p1,p2,pset1,pset2,angle\n0,3.0,3.0,3.1,2.0,0\n0.01,3.05,2.5,3.1,2.0,0.01\n0.02,3.1,2.1,3.1,2.0,0.02\n",
    )
    .unwrap();
    let map = write_map(
        dir.path(),
        r#"
[time]
column = "t"
unit = "s"
[pressure]
regulator_band_pa = 20000.0
[[channel]]
column = "p1"
channel = "p1"
unit = "bar"
[[channel]]
column = "p2"
channel = "p2"
unit = "bar"
[[channel]]
column = "pset1"
channel = "regulator1"
unit = "bar"
[[channel]]
column = "pset2"
channel = "regulator2"
unit = "bar"
[[channel]]
column = "angle"
channel = "angle"
unit = "rad"
"#,
    );
    let mapping = host_sim::io::import::Mapping::load(&map).unwrap();
    let imp = host_sim::io::import::import(&mapping, &map, &raw, false).unwrap();
    let u = &imp.segments[0].inputs;
    // 0.1 bar below the set-point: 10 kPa / 20 kPa band = half open inflate.
    assert!(
        (u[0].u_in1 - 0.5).abs() < 1e-9 && u[0].u_ex1 == 0.0,
        "{:?}",
        u[0]
    );
    // 1 bar above: exhaust fully open.
    assert!(u[0].u_ex2 == 1.0 && u[0].u_in2 == 0.0);
    assert!(u[2].u_in1 == 0.0 && u[2].u_ex1 == 0.0);
    assert!((u[2].u_ex2 - 0.5).abs() < 1e-9);
}

/// `import` of `raw` through `map_text` into `out`.
fn import_with(
    dir: &Path,
    map_text: &str,
    raw: &Path,
    out: &Path,
    split: bool,
) -> std::process::Output {
    let map = write_map(dir, map_text);
    let mut args: Vec<&dyn AsRef<std::ffi::OsStr>> =
        vec![&"import", &"--map", &map, &"--input", &raw, &"--out", &out];
    if split {
        args.push(&"--split");
    }
    host_sim(&args)
}

/// The 1-based line of the `n`-th (0-based) line of `text` equal to `line`.
fn line_of(text: &str, line: &str, n: usize) -> usize {
    text.lines()
        .enumerate()
        .filter(|(_, l)| l.trim() == line)
        .nth(n)
        .unwrap()
        .0
        + 1
}

#[test]
fn a_key_that_does_nothing_for_its_channel_is_refused_at_its_line() {
    let dir = tmp();
    let (raw, _) = rig_file(dir.path(), 2.0, 1, &[]);
    let out = dir.path().join("rec.csv");
    let p1 = "[[channel]]\ncolumn = \"P1 [bar abs]\"\nchannel = \"p1\"\nunit = \"bar\"\nreference = \"absolute\"\n";
    assert!(MAP.contains(p1));
    for (extra, key) in [
        (
            "threshold = 0.5\n",
            "`threshold`: applies to a valve with `unit = \"onoff\"` only",
        ),
        (
            "counts_per_rev = 8000\n",
            "`counts_per_rev`: applies to an angle",
        ),
    ] {
        let text = MAP.replace(p1, &format!("{p1}{extra}"));
        let r = import_with(dir.path(), &text, &raw, &out, false);
        let e = exits(2, &r);
        let line = line_of(&text, extra.trim_end(), 0);
        assert!(
            e.contains(&format!("map.toml:{line}: channel[0] (`p1`): {key}")),
            "{e}"
        );
        assert!(!out.exists());
    }
}

#[test]
fn a_constant_that_is_not_a_number_is_refused_at_its_line() {
    let dir = tmp();
    let (raw, _) = rig_file(dir.path(), 2.0, 1, &[]);
    let out = dir.path().join("never.csv");
    for value in ["nan", "inf", "-inf"] {
        let text =
            format!("{MAP}\n[[channel]]\nchannel = \"f1\"\nconstant = {value}\nunit = \"N\"\n");
        let r = import_with(dir.path(), &text, &raw, &out, false);
        let e = exits(2, &r);
        let line = line_of(&text, &format!("constant = {value}"), 0);
        assert!(
            e.contains(&format!(
                "map.toml:{line}: channel[5] (`f1`): `constant`: must be a finite number"
            )),
            "{e}"
        );
        assert!(!out.exists());
    }
}

#[test]
fn a_column_mapped_twice_is_refused_at_its_line() {
    let dir = tmp();
    let (raw, _) = rig_file(dir.path(), 2.0, 1, &[]);
    let out = dir.path().join("never.csv");
    for (extra, needles) in [
        (
            "\n[[channel]]\ncolumn = \"Zeit [ms]\"\nchannel = \"f1\"\nunit = \"N\"\n",
            vec![
                "channel[5] (`f1`): `column`",
                "\"Zeit [ms]\" is the time column",
            ],
        ),
        (
            "\n[[channel]]\ncolumn = \"MPYE1 [V]\"\nchannel = \"f2\"\nunit = \"N\"\n",
            vec![
                "channel[5] (`f2`): `column`",
                "\"MPYE1 [V]\" is already mapped by channel[3] (`valve1`)",
            ],
        ),
    ] {
        let text = format!("{MAP}{extra}");
        let e = exits(2, &import_with(dir.path(), &text, &raw, &out, false));
        let col = extra.lines().nth(2).unwrap();
        // The column's second mention (the first is its [time] or its valve1 entry).
        let at = format!("map.toml:{}:", line_of(&text, col, 1));
        assert!(e.contains(&at), "`{at}` not in: {e}");
        for n in needles {
            assert!(e.contains(n), "`{n}` not in: {e}");
        }
        assert!(!out.exists());
    }
}

#[test]
fn an_onoff_threshold_that_leaves_a_valve_closed_or_open_is_warned_at_its_line() {
    let dir = tmp();
    let (raw, _) = rig_file(dir.path(), 2.0, 1, &[]);
    let out = dir.path().join("rec.csv");
    let valve1 = "[[channel]]\ncolumn = \"MPYE1 [V]\"\nchannel = \"valve1\"\nunit = \"V\"\ncurve = [[0.0, -1.0], [4.8, 0.0], [5.2, 0.0], [10.0, 1.0]]\n";
    assert!(MAP.contains(valve1));
    // The valve voltage (0..10 V) against 50: never open. The lab temperature (21.5) against
    // 5: always open.
    let onoff = "[[channel]]\ncolumn = \"MPYE1 [V]\"\nchannel = \"u_in1\"\nunit = \"onoff\"\nthreshold = 50.0\n\n\
                 [[channel]]\ncolumn = \"Temp [C]\"\nchannel = \"u_ex1\"\nunit = \"onoff\"\nthreshold = 5.0\n";
    let text = MAP.replace(valve1, onoff);
    let r = import_with(dir.path(), &text, &raw, &out, false);
    ok(&r);
    let e = text_of(&r.stderr);
    for (n, state, value) in [(0, "closed", "50"), (1, "open", "5")] {
        let line = line_of(&text, &format!("threshold = {value}.0"), 0);
        let want = format!("map.toml:{line}: channel[{}]", 3 + n);
        assert!(e.contains(&want), "`{want}` not in: {e}");
        let want = format!("`threshold` {value} leaves column");
        assert!(e.contains(&want), "`{want}` not in: {e}");
        assert!(e.contains(&format!("{state} over the whole file")), "{e}");
    }
    // A valve logged as a fraction (0..1, here the volts scaled by 0.1) mapped as percent:
    // it never opens beyond 1 %.
    let percent = "[[channel]]\ncolumn = \"MPYE1 [V]\"\nchannel = \"u_in1\"\nunit = \"percent\"\nscale = 0.1\n\n\
                   [[channel]]\ncolumn = \"Temp [C]\"\nchannel = \"u_ex1\"\nunit = \"percent\"\n";
    let text = MAP.replace(valve1, percent);
    let r = import_with(dir.path(), &text, &raw, &out, false);
    ok(&r);
    let e = text_of(&r.stderr);
    assert!(
        e.contains(
            "channel[3] (`u_in1`): column `MPYE1 [V]` with `unit = \"percent\"` never opens beyond"
        ),
        "{e}"
    );
    assert!(
        e.contains("read as percent?") && !e.contains("channel[4]"),
        "{e}"
    );
    // The valve's 0..10 V command mapped as percent: never beyond 10 %.
    let volts = "[[channel]]\ncolumn = \"MPYE1 [V]\"\nchannel = \"u_in1\"\nunit = \"percent\"\n\n\
                 [[channel]]\nchannel = \"u_ex1\"\nconstant = 0.0\n";
    let r = import_with(dir.path(), &MAP.replace(valve1, volts), &raw, &out, false);
    ok(&r);
    let e = text_of(&r.stderr);
    assert!(
        e.contains("column `MPYE1 [V]` with `unit = \"percent\"` never opens beyond 10 %")
            && e.contains("valve volts (0..10 V) read as percent?"),
        "{e}"
    );
    // The encoder's counts scaled to radians and mapped as degrees. The rig's joint spans
    // 0.8 rad, which the 1-degree span check already catches; x3 (a joint swinging 2.4 rad)
    // spans more than a degree read as degrees, yet stays inside +-pi.
    let encoder =
        "column = \"Encoder\"\nchannel = \"angle\"\nunit = \"counts\"\ncounts_per_rev = 8000\n";
    assert!(MAP.contains(encoder));
    let radians = format!(
        "column = \"Encoder\"\nchannel = \"angle\"\nunit = \"deg\"\nscale = {}\n",
        3.0 * std::f64::consts::TAU / 8000.0
    );
    let r = import_with(
        dir.path(),
        &MAP.replace(encoder, &radians),
        &raw,
        &out,
        false,
    );
    ok(&r);
    let e = text_of(&r.stderr);
    assert!(e.contains("the range of an angle logged in radians"), "{e}");
    // The rig's own mapping warns of nothing.
    let r = import_with(dir.path(), MAP, &raw, &out, false);
    ok(&r);
    assert!(
        !text_of(&r.stderr).contains("read as percent")
            && !text_of(&r.stderr).contains("threshold")
            && !text_of(&r.stderr).contains("radians"),
        "{}",
        text_of(&r.stderr)
    );
}

fn text_of(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

#[test]
fn split_removes_its_own_stale_segments_and_a_missing_directory_names_the_users_path() {
    let dir = tmp();
    let map = MAP;
    let out = dir.path().join("rec.csv");
    // Three segments, then two: rec-3.csv of the first import would pass for part of the
    // second; it is removed and the report says so.
    let (raw3, _) = rig_file(dir.path(), 6.0, 3, &[60, 61, 62, 150, 151, 152]);
    ok(&import_with(dir.path(), map, &raw3, &out, true));
    assert!(dir.path().join("rec-3.csv").exists());
    let (raw2, _) = rig_file(dir.path(), 6.0, 3, &[100, 101, 102]);
    let report = ok(&import_with(dir.path(), map, &raw2, &out, true));
    assert!(!dir.path().join("rec-3.csv").exists(), "{report}");
    assert!(
        report.contains("removed") && report.contains("rec-3.csv") && report.contains("2 segments"),
        "{report}"
    );
    Recording::read(dir.path().join("rec-2.csv")).unwrap();
    // One segment: OUT itself, and the earlier run's rec-1.csv, rec-2.csv go.
    let (raw1, _) = rig_file(dir.path(), 6.0, 3, &[]);
    ok(&import_with(dir.path(), map, &raw1, &out, true));
    assert!(out.exists());
    assert!(!dir.path().join("rec-1.csv").exists() && !dir.path().join("rec-2.csv").exists());
    // Two segments again: OUT of that one-segment import goes (it would pass for this run).
    let (raw2, _) = rig_file(dir.path(), 6.0, 3, &[100, 101, 102]);
    let report = ok(&import_with(dir.path(), map, &raw2, &out, true));
    assert!(!out.exists() && report.contains("removed"), "{report}");

    // A file of a segment's name that no import wrote is the user's: refused, untouched.
    let mine = dir.path().join("rec-2.csv");
    std::fs::write(&mine, "my notes\n").unwrap();
    let e = exits(2, &import_with(dir.path(), map, &raw2, &out, true));
    assert!(
        e.contains("segment 2 of --out")
            && e.contains("rec-2.csv: exists and was not written by host-sim"),
        "{e}"
    );
    assert_eq!(std::fs::read_to_string(&mine).unwrap(), "my notes\n");

    // A missing output directory: the user's path, not a temporary file's.
    let missing = dir.path().join("no_such_dir").join("rec.csv");
    let e = exits(2, &import_with(dir.path(), map, &raw1, &missing, false));
    assert!(
        e.contains(&format!("--out {}", missing.display())) && e.contains("does not exist"),
        "{e}"
    );
    assert!(!e.contains("no_such_dir/."), "{e}");
}

#[test]
fn a_negative_or_fractional_counts_per_rev_is_refused_with_its_range() {
    let dir = tmp();
    let (raw, _) = rig_file(dir.path(), 2.0, 1, &[]);
    let out = dir.path().join("never.csv");
    for (value, got) in [
        ("-8000", "got -8000"),
        ("1e300", "got 1e300"),
        ("8000.5", "got 8000.5"),
    ] {
        let text = MAP.replace(
            "counts_per_rev = 8000",
            &format!("counts_per_rev = {value}"),
        );
        let e = exits(2, &import_with(dir.path(), &text, &raw, &out, false));
        let line = line_of(&text, &format!("counts_per_rev = {value}"), 0);
        for n in [
            format!("map.toml:{line}:"),
            "`counts_per_rev`".to_string(),
            "[1, 1073741824]".to_string(),
            got.to_string(),
        ] {
            assert!(e.contains(&n), "`{n}` not in: {e}");
        }
        assert!(!e.contains("expected"), "{e}");
        assert!(!out.exists());
    }
}

#[test]
fn absolute_pressures_mapped_as_gauge_get_the_hint_on_stderr() {
    let dir = tmp();
    // A logger file whose muscles vent from 6.5 bar absolute down to the atmosphere (written
    // here, 200 rows at 25 ms, in the rig's layout).
    let mut t = String::from(
        "Prüfstand\nexportiert\nZeit [ms];P1 [bar abs];P2 [bar abs];Encoder;MPYE1 [V];MPYE2 [V];Temp [C]\n",
    );
    for k in 0..200 {
        let p_bar = 1.01325 + 5.5 * (-(k as f64) / 20.0).exp();
        let row = format!(
            "{:.1};{p_bar:.5};{p_bar:.5};{};2.0;2.0;21.5\n",
            25.0 * k as f64,
            k % 7
        );
        t.push_str(&row.replace('.', ","));
    }
    let raw = dir.path().join("vent.csv");
    std::fs::write(&raw, t).unwrap();
    let out = dir.path().join("rec.csv");
    // bar absolute read as bar gauge: the minimum is about 1 bar.
    let text = MAP.replace("reference = \"absolute\"", "reference = \"gauge\"");
    let r = import_with(dir.path(), &text, &raw, &out, false);
    let e = text_of(&r.stderr) + &text_of(&r.stdout);
    ok(&r);
    for n in [
        "warning: p1 never goes below",
        "the pressure columns look absolute, not gauge; RECORDING.md's columns are gauge: subtract p_atm or import with reference = \"absolute\"",
    ] {
        assert!(e.contains(n), "`{n}` not in: {e}");
    }
    let r = import_with(dir.path(), MAP, &raw, &out, false);
    assert!(!text_of(&r.stderr).contains("look absolute"));
}

/// The independent reference implementation's loaded run: its muscles, stretched with closed
/// valves, fall to -39 kPa gauge. That is physics, not a unit mistake: imported without a
/// pressure warning.
#[test]
fn a_muscle_stretched_below_the_atmosphere_is_not_a_unit_warning() {
    let dir = tmp();
    let map = dir.path().join("recording.toml");
    let mut text = String::from(
        "[csv]\ndelimiter = \",\"\nskip_lines = 3\n[time]\ncolumn = \"t_s\"\nunit = \"s\"\n[pressure]\np_atm_pa = 101325.0\n",
    );
    for (col, ch, unit) in [
        ("p1_kpa", "p1", "kPa"),
        ("p2_kpa", "p2", "kPa"),
        ("angle_deg", "angle", "deg"),
        ("u_in1", "u_in1", "onoff"),
        ("u_ex1", "u_ex1", "onoff"),
        ("u_in2", "u_in2", "onoff"),
        ("u_ex2", "u_ex2", "onoff"),
    ] {
        text +=
            &format!("[[channel]]\ncolumn = \"{col}\"\nchannel = \"{ch}\"\nunit = \"{unit}\"\n");
        if unit == "kPa" {
            text += "reference = \"gauge\"\n";
        }
    }
    std::fs::write(&map, text).unwrap();
    let out_path = dir.path().join("loaded.csv");
    let input = fixture("pulses_loaded.csv");
    let out = host_sim(&[
        &"import", &"--map", &map, &"--input", &input, &"--out", &out_path,
    ]);
    ok(&out);
    let stderr = String::from_utf8_lossy(&out.stderr);
    let stdout = String::from_utf8_lossy(&out.stdout);
    // The range is reported, and it does go below the atmosphere.
    assert!(stdout.contains("p1 (column `p1_kpa`): -38.7"), "{stdout}");
    assert!(!stderr.contains("warning: p"), "{stderr}");
    // A gauge sensor mapped as absolute (the atmosphere subtracted from a gauge value: a
    // vented muscle reads -101.3 kPa) is warned about.
    let input = fixture("pwm_nominal.csv");
    let twice = std::fs::read_to_string(&map)
        .unwrap()
        .replace("reference = \"gauge\"", "reference = \"absolute\"");
    std::fs::write(&map, twice).unwrap();
    let out = host_sim(&[
        &"import", &"--map", &map, &"--input", &input, &"--out", &out_path,
    ]);
    let report = String::from_utf8_lossy(&out.stderr);
    assert!(
        report.contains("warning: p1 goes down to") && report.contains("gauge mapped as absolute"),
        "{report}"
    );
}

/// What a logger or an editor on a lab PC produces: a Windows (Latin-1) export whose column
/// names carry a degree sign, an empty file, a `skip_lines` past the end, a directory given
/// as the file, a mapping saved as Latin-1.
#[test]
fn windows_exports_empty_files_and_directories_are_named_for_what_they_are() {
    let dir = tmp();
    let map = write_map(
        dir.path(),
        "[time]\ncolumn = \"t [s]\"\nunit = \"s\"\n[[channel]]\ncolumn = \"Winkel [\u{b0}]\"\nchannel = \"angle\"\nunit = \"deg\"\n[[channel]]\ncolumn = \"V1\"\nchannel = \"valve1\"\nunit = \"fraction\"\n[[channel]]\ncolumn = \"V2\"\nchannel = \"valve2\"\nunit = \"fraction\"\n",
    );
    let raw = dir.path().join("win.csv");
    // Latin-1: the degree sign is the one byte 0xB0.
    let mut bytes = b"t [s],Winkel [".to_vec();
    bytes.push(0xB0);
    bytes.extend_from_slice(b"],V1,V2\n");
    for k in 0..100 {
        bytes.extend_from_slice(
            format!("{:.3},{:.2},0.5,0\n", k as f64 * 0.01, k as f64 * 0.1).as_bytes(),
        );
    }
    std::fs::write(&raw, &bytes).unwrap();
    let out = dir.path().join("win.rec.csv");
    let run = |input: &Path| {
        host_sim(&[
            &"import", &"--map", &map, &"--input", &input, &"--out", &out,
        ])
    };
    let r = run(&raw);
    ok(&r);
    let e = text_of(&r.stderr);
    assert!(
        e.contains("win.csv:1: not UTF-8") && e.contains("read as Latin-1"),
        "{e}"
    );
    assert_eq!(Recording::read(&out).unwrap().len(), 100);
    // An empty file, a directory.
    let empty = dir.path().join("empty.csv");
    std::fs::write(&empty, "").unwrap();
    assert!(exits(2, &run(&empty)).contains("empty.csv: the file is empty"));
    assert!(exits(2, &run(dir.path())).contains("is a directory; give the rig logger's CSV file"));
    // skip_lines past the end.
    let text = std::fs::read_to_string(&map).unwrap();
    std::fs::write(&map, format!("[csv]\nskip_lines = 100000\n{text}")).unwrap();
    let e = exits(2, &run(&raw));
    assert!(
        e.contains("skip_lines = 100000") && e.contains("skips the whole file (101 line(s))"),
        "{e}"
    );
    // A mapping saved as Latin-1: its line named.
    let mut latin = text.replace('\u{b0}', "").into_bytes();
    let at = latin.windows(7).position(|w| w == b"Winkel ").unwrap() + 7;
    latin.insert(at, 0xB0);
    std::fs::write(&map, &latin).unwrap();
    let e = exits(2, &run(&raw));
    assert!(
        e.contains("map.toml:5: not UTF-8") && e.contains("save the mapping file as UTF-8"),
        "{e}"
    );
}

/// Stamps coarser than the sampling (the 40 Hz rig's ms stamps cut to tenths of a second)
/// repeat on many rows: named as coarse stamps, not as one duplicated row; a single copied
/// row still is.
#[test]
fn coarse_time_stamps_are_told_from_a_duplicated_row() {
    let dir = tmp();
    let (raw, _) = rig_file(dir.path(), 2.0, 3, &[]);
    let text = std::fs::read_to_string(&raw).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let coarse = retimed(&lines, |ms| format!("{}", (ms / 100.0).floor() * 100.0));
    let out = dir.path().join("rec.csv");
    let coarse_path = dir.path().join("coarse.csv");
    std::fs::write(&coarse_path, coarse).unwrap();
    let e = exits(2, &import_with(dir.path(), MAP, &coarse_path, &out, false));
    assert!(
        e.contains("the time stamps are coarser than the sampling") && !e.contains("duplicated"),
        "{e}"
    );
    // One row copied: a duplicated row.
    let copy = lines[10].clone();
    lines.insert(11, copy);
    let once = dir.path().join("once.csv");
    std::fs::write(&once, lines.join("\n") + "\n").unwrap();
    let e = exits(2, &import_with(dir.path(), MAP, &once, &out, false));
    assert!(
        e.contains("(a duplicated row?)") && !e.contains("coarser"),
        "{e}"
    );
    assert!(!out.exists());
    // The stamps in seconds with two decimals (a spreadsheet's export): none repeats, but
    // their 10 ms resolution is a third of the step (25 ms, 30 ms once rounded). Imported,
    // with a warning; the rig's own 0.01 ms stamps get none.
    lines.remove(11);
    let seconds = retimed(&lines, |ms| format!("{:.2}", ms / 1e3).replace('.', ","));
    let in_s = dir.path().join("seconds.csv");
    std::fs::write(&in_s, seconds).unwrap();
    let map_s = MAP.replace("unit = \"ms\"", "unit = \"s\"");
    assert_ne!(map_s, MAP);
    let r = import_with(dir.path(), &map_s, &in_s, &out, false);
    ok(&r);
    let e = text_of(&r.stderr);
    assert!(
        e.contains(
            "time stamps written to 0.01 s (2 decimals in s), 33 % of the median step 0.03 s"
        ),
        "{e}"
    );
    let r = import_with(dir.path(), MAP, &raw, &out, false);
    ok(&r);
    assert!(
        !text_of(&r.stderr).contains("time stamps written"),
        "{}",
        text_of(&r.stderr)
    );
}

/// The rig file's `lines` (three of head, then data) with each time stamp (ms, decimal
/// comma) written as `stamp(its ms)`.
fn retimed(lines: &[String], stamp: impl Fn(f64) -> String) -> String {
    lines
        .iter()
        .enumerate()
        .map(|(i, l)| {
            if i < 3 {
                return format!("{l}\n");
            }
            let (t, rest) = l.split_once(';').unwrap();
            format!("{};{rest}\n", stamp(t.replace(',', ".").parse().unwrap()))
        })
        .collect()
}
