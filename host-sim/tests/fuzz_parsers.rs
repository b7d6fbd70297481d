//! Fuzzing of the file parsers a user reaches from the command line: recording CSV
//! (RECORDING.md), plant TOML (1-DOF with effects, and the 3-DOF arm), scenario TOML. No
//! input may panic: each parser must return a value or an error.
//!
//! Inputs are valid seed files mutated by a proptest strategy (structure-aware: numbers,
//! keys, table headers and CSV fields replaced by hostile tokens such as `NaN`, `1e309`, an
//! empty field, a quote, a NUL; lines duplicated, swapped, cut; bytes flipped), so most inputs
//! get past the syntax into the validation code, where the panics would be. Stable toolchain,
//! nothing to install in CI (docs/reliability.md says why not cargo-fuzz).
//!
//! Short run (CI, `cargo test`): 2000 inputs per parser. Full run (>= 1e6 per parser):
//!
//! ```text
//! FUZZ_CASES=1000000 cargo test --release -p host-sim --test fuzz_parsers -- --nocapture --test-threads 2
//! ```
//!
//! Each test prints how many inputs it ran and how many the parser accepted / rejected.

mod common;
use common::*;

use std::cell::Cell;
use std::path::PathBuf;

use host_sim::io::scenario::Scenario;
use host_sim::plant::arm3::Arm3Config;
use host_sim::{Plant, PlantConfig, Recording};
use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};

fn cases() -> u32 {
    std::env::var("FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(2000)
}

/// Hostile tokens spliced into the seeds.
const TOKENS: &[&str] = &[
    "NaN",
    "nan",
    "inf",
    "-inf",
    "1e309",
    "-1e309",
    "1e-320",
    "-0",
    "0",
    "-1",
    "1e9",
    "1e18",
    "18446744073709551616",
    "9999999999999999999999",
    ".",
    "",
    "\"",
    "'",
    "[",
    "]",
    "[[",
    "]]",
    "=",
    ",",
    ",,",
    "\n",
    "\r\n",
    "#",
    "\u{0}",
    "\u{feff}",
    "é",
    "true",
    "{",
    "}",
    "[[events]]",
    "[expect]",
    "[setpoint]",
    "[effects.gravity]",
    "kind = \"random\"",
    "kind = \"sine\"",
    "duration_s = 1e-9",
    "hold_s = 1e-12",
    "0.000001",
    "1e300",
    "t_s",
    "angle_deg",
    "u_in1",
    "p1_kpa",
    "# sample_period_s = 0",
];

#[derive(Clone, Debug)]
enum Mutation {
    /// Replace the `n`-th number of the text with a token.
    Number(u32, u8),
    /// Insert a token at a byte position.
    Insert(u32, u8),
    /// Delete a byte range.
    Delete(u32, u8),
    /// Duplicate a line.
    DupLine(u32),
    /// Swap two lines.
    SwapLines(u32, u32),
    /// Cut the text at a position.
    Truncate(u32),
    /// Flip a byte (kept UTF-8 by a lossy conversion).
    Flip(u32, u8),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        4 => (any::<u32>(), any::<u8>()).prop_map(|(a, b)| Mutation::Number(a, b)),
        2 => (any::<u32>(), any::<u8>()).prop_map(|(a, b)| Mutation::Insert(a, b)),
        1 => (any::<u32>(), any::<u8>()).prop_map(|(a, b)| Mutation::Delete(a, b)),
        1 => any::<u32>().prop_map(Mutation::DupLine),
        1 => (any::<u32>(), any::<u32>()).prop_map(|(a, b)| Mutation::SwapLines(a, b)),
        1 => any::<u32>().prop_map(Mutation::Truncate),
        1 => (any::<u32>(), any::<u8>()).prop_map(|(a, b)| Mutation::Flip(a, b)),
    ]
}

fn floor_char(s: &str, i: usize) -> usize {
    let mut i = i.min(s.len());
    while !s.is_char_boundary(i) {
        i -= 1;
    }
    i
}

/// Byte ranges of the numbers in `s`.
fn numbers(s: &str) -> Vec<(usize, usize)> {
    let b = s.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        if b[i].is_ascii_digit() {
            let start = if i > 0 && (b[i - 1] == b'-' || b[i - 1] == b'.') {
                i - 1
            } else {
                i
            };
            while i < b.len()
                && (b[i].is_ascii_alphanumeric() || matches!(b[i], b'.' | b'-' | b'+'))
            {
                i += 1;
            }
            out.push((start, i));
        } else {
            i += 1;
        }
    }
    out
}

fn apply(seed: &str, muts: &[Mutation]) -> String {
    let mut s = seed.to_string();
    for m in muts {
        let len = s.len().max(1);
        let tok = |t: u8| TOKENS[t as usize % TOKENS.len()];
        match *m {
            Mutation::Number(n, t) => {
                let nums = numbers(&s);
                if !nums.is_empty() {
                    let (a, b) = nums[n as usize % nums.len()];
                    s.replace_range(a..b, tok(t));
                }
            }
            Mutation::Insert(p, t) => {
                let p = floor_char(&s, p as usize % len);
                s.insert_str(p, tok(t));
            }
            Mutation::Delete(p, n) => {
                let a = floor_char(&s, p as usize % len);
                let b = floor_char(&s, a + n as usize % 64);
                s.replace_range(a..b, "");
            }
            Mutation::DupLine(l) => {
                let mut lines: Vec<&str> = s.lines().collect();
                if !lines.is_empty() {
                    let i = l as usize % lines.len();
                    lines.insert(i, lines[i]);
                }
                s = lines.join("\n");
            }
            Mutation::SwapLines(a, b) => {
                let mut lines: Vec<&str> = s.lines().collect();
                if !lines.is_empty() {
                    let n = lines.len();
                    lines.swap(a as usize % n, b as usize % n);
                }
                s = lines.join("\n");
            }
            Mutation::Truncate(p) => {
                let p = floor_char(&s, p as usize % len);
                s.truncate(p);
            }
            Mutation::Flip(p, x) => {
                let mut bytes = s.into_bytes();
                if !bytes.is_empty() {
                    let i = p as usize % bytes.len();
                    bytes[i] ^= x | 1;
                }
                s = String::from_utf8_lossy(&bytes).into_owned();
            }
        }
    }
    s
}

/// Runs `parse` (true: accepted) on `cases()` mutated seeds; fails on the first panic.
fn fuzz(name: &str, seeds: Vec<String>, parse: impl Fn(&str) -> bool) {
    assert!(!seeds.is_empty());
    for s in &seeds {
        assert!(parse(s), "{name}: an unmutated seed must parse:\n{s}");
    }
    let n = cases();
    let mut runner = TestRunner::new(Config {
        cases: n,
        failure_persistence: None,
        ..Config::default()
    });
    let (ok, bad) = (Cell::new(0u64), Cell::new(0u64));
    let strategy = (0..seeds.len(), prop::collection::vec(mutation(), 1..6));
    let result = runner.run(&strategy, |(i, muts)| {
        let input = apply(&seeds[i], &muts);
        if parse(&input) {
            ok.set(ok.get() + 1);
        } else {
            bad.set(bad.get() + 1);
        }
        Ok(())
    });
    println!(
        "fuzz {name}: {} inputs, {} accepted, {} rejected with an error, 0 panics",
        ok.get() + bad.get(),
        ok.get(),
        bad.get()
    );
    if let Err(e) = result {
        panic!("fuzz {name}: {e}");
    }
}

fn read(p: PathBuf) -> String {
    std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

#[test]
fn fuzz_recording_csv() {
    // The head of each conformance fixture (the parser's work is per line; 40 rows keep a
    // million inputs fast) and a recording with only some channels.
    let mut seeds: Vec<String> = ["pulses_nominal", "pwm_nominal", "pulses_loaded"]
        .iter()
        .map(|f| {
            read(fixture(&format!("{f}.csv")))
                .lines()
                .take(45)
                .collect::<Vec<_>>()
                .join("\n")
                + "\n"
        })
        .collect();
    seeds.push("# sample_period_s = 0.01\nt_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg\n0,0,0,0,0,0\n0.01,1,0,0,1,0.5\n0.02,1,0,0,1,1.5\n".into());
    fuzz("recording CSV", seeds, |text| {
        match Recording::parse(text, "fuzz.csv") {
            Ok(r) => {
                // What every command does next with a recording.
                let _ = r.sample_period_s();
                let _ = r.len();
                true
            }
            Err(e) => {
                let _ = e.to_string();
                false
            }
        }
    });
}

fn plant_seeds() -> Vec<String> {
    let nominal = read(fixture("reference-1dof.toml"));
    vec![
        nominal.clone(),
        read(fixture("reference-1dof-loaded.toml")),
        format!(
            "{nominal}\n[effects.joint_friction]\ncoulomb_nm = 0.2\nbreakaway_nm = 0.3\n\
             stribeck_velocity_rad_s = 0.1\nviscous_nm_s_per_rad = 0.05\nsmoothing_velocity_rad_s = 0.01\n\
             [effects.sensor.angle_deg]\noffset = 1.5\ngain = 2.0\n[effects.polytropic]\nexponent = 1.4\n\
             [effects.leakage]\nsonic_conductance_m3_per_s_pa = 1.0e-11\n\
             [effects.gravity]\nmass_kg = 1.0\ncom_distance_m = 0.1\nhanging_angle_rad = 0.0\n"
        ),
    ]
}

#[test]
fn fuzz_plant_toml() {
    fuzz("plant TOML", plant_seeds(), |text| {
        match PlantConfig::from_toml_str(text, "fuzz.toml") {
            Ok(cfg) => {
                // A valid file must give a plant whose initial state can be evaluated.
                let plant = Plant::from_config(&cfg);
                let x = plant.initial_state();
                let _ = plant.measure(&x);
                let _ = plant.derivatives(&x, &host_sim::ValveInputs::CLOSED);
                true
            }
            Err(e) => {
                let _ = e.to_string();
                false
            }
        }
    });
}

#[test]
fn fuzz_arm3_plant_toml() {
    let seeds = vec![read(root().join("host-sim/plants/arm3-seed001.toml"))];
    fuzz(
        "arm3 plant TOML",
        seeds,
        |text| match Arm3Config::from_toml_str(text, "fuzz.toml") {
            Ok(cfg) => {
                let _ = host_sim::plant::arm3::Arm3::from_config(&cfg);
                true
            }
            Err(e) => {
                let _ = e.to_string();
                false
            }
        },
    );
}

#[test]
fn fuzz_scenario_toml() {
    let mut seeds = Vec::new();
    for dir in [root().join("scenarios"), root().join("scenarios/suite")] {
        let mut files: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == "toml"))
            .collect();
        files.sort();
        seeds.extend(files.into_iter().map(read));
    }
    fuzz("scenario TOML", seeds, |text| {
        match Scenario::from_toml_str(text, "fuzz.toml") {
            Ok(s) => {
                // The size check every run does before it allocates.
                let _ = s.run_estimate().check(false);
                true
            }
            Err(e) => {
                let _ = e.to_string();
                false
            }
        }
    });
}
