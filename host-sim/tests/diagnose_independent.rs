//! The diagnosis against recordings it was not written against: the independent test rig
//! (`host_sim::diagnose::testrig`: its own plant code, RK4, effect forms unlike the
//! candidates', closed-loop excitation, 1-3 ms sampling, cases with and without force
//! channels, parameter mismatches, pure noise, noise-free nominal data).
//!
//! - The rig's own physics is checked first: on the nominal plant it agrees with the
//!   simulator, and its thermodynamic chamber reproduces
//!   `shared/conformance/pulses_thermal.csv` (an independent implementation of seed 004).
//! - `reduced_matrix` (runs in CI, debug build): a fixed subset of cases on held-out seeds,
//!   asserting the pass count docs/diagnosis.md reports.
//! - `full_matrix` (ignored; the documented command):
//!   `cargo test -p host-sim --test diagnose_independent -- --ignored --nocapture full_matrix`
//!   every kind on the tuning seeds and on the held-out seeds, rates printed separately.
//!
//! A case passes when its verdict is the expected one (`explained` with exactly the expected
//! effect ids and recalibrated keys and every CHECK channel >= 95 % after; `nothing_missing`;
//! or a refusal, exit status 3, for pure noise). Without force channels joint friction and
//! muscle hysteresis count as one answer, and so do the recalibrations of the valve
//! conductance and of the chamber volume (the diagnosis says they cannot be told apart).

use std::path::PathBuf;

use host_sim::diagnose::testrig::{case, Case, Expected, RigPhysics, KINDS};
use host_sim::diagnose::{diagnose, DiagnoseOptions, Diagnosis, Verdict};
use host_sim::fit::fit_percent;
use host_sim::io::recording::Channel;
use host_sim::sim::{simulate, SolverOptions};
use host_sim::{Plant, PlantConfig, Recording};

/// Seeds used while tuning thresholds and the rig.
const TUNING_SEEDS: [u64; 2] = [11, 12];
/// Seeds fixed before the diagnosis code was final and never tuned on.
const HELD_OUT_SEEDS: [u64; 3] = [9101, 9102, 9103];

/// A file of `host-sim/tests/fixtures/` (copies of the shared material, see its README).
fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

fn nominal() -> PlantConfig {
    PlantConfig::load(fixture("reference-1dof.toml")).unwrap()
}

#[test]
fn rig_agrees_with_the_simulator_on_the_nominal_plant() {
    let cfg = nominal();
    let c = case(&cfg, "nominal_noise_free", 5);
    let rig = RigPhysics::from_config(&cfg);
    let ours = rig.replay(&c.train.inputs, c.dt_s);
    let plant = Plant::from_config(&cfg);
    let sim = simulate(&plant, &c.train.inputs, c.dt_s, &SolverOptions::default()).unwrap();
    let theirs = plant.measure_series(&sim.states, c.dt_s);
    for ch in Channel::ALL {
        let a: Vec<f64> = ours.iter().map(|y| y[ch.index()]).collect();
        let b: Vec<f64> = theirs.iter().map(|m| ch.of(m)).collect();
        let f = fit_percent(&a, &b);
        assert!(f > 99.9, "{}: {f:.4} %", ch.name());
    }
}

#[test]
fn rig_thermal_chamber_reproduces_the_conformance_fixture() {
    let rec = Recording::read(fixture("pulses_thermal.csv")).unwrap();
    let mut rig = RigPhysics::from_config(&nominal());
    rig.thermal = Some([2.0, 1.4]);
    let y = rig.replay(&rec.inputs, rec.sample_period_s());
    for ch in Channel::ALL {
        let Some(m) = rec.channel(ch) else { continue };
        let ours: Vec<f64> = y.iter().map(|v| v[ch.index()]).collect();
        let f = fit_percent(m, &ours);
        assert!(f >= 99.5, "{}: {f:.3} %", ch.name());
    }
}

struct Outcome {
    pass: bool,
    line: String,
}

fn ids(d: &Diagnosis, force: bool) -> Vec<String> {
    let mut v: Vec<String> = d
        .effects
        .iter()
        .map(|e| e.id.clone())
        .chain(d.recalibrated.iter().map(|r| r.key.clone()))
        .map(|id| {
            if !force && id == "muscle_hysteresis" {
                "joint_friction".to_string()
            } else if id == "muscle.volume_poly_m3" {
                // The isothermal pressure law sees only conductance / volume: the diagnosis
                // says the two cannot be told apart, and either recalibration is the same model.
                "valve.sonic_conductance_m3_per_s_pa".to_string()
            } else {
                id
            }
        })
        .collect();
    v.sort();
    v
}

fn run(c: &Case) -> Outcome {
    let t0 = std::time::Instant::now();
    let d = diagnose(
        &nominal(),
        &c.train,
        Some(&c.check),
        &DiagnoseOptions::default(),
        &|_, _, _| {},
    );
    let secs = t0.elapsed().as_secs_f64();
    let (pass, got, verdict, min_check) = match &d {
        Err(e) => (false, format!("error: {e}"), "error", f64::NAN),
        Ok(d) => {
            let got = ids(d, c.force_channels);
            let min_check = d
                .check_after
                .as_ref()
                .map(|m| m.values().copied().fold(f64::INFINITY, f64::min))
                .unwrap_or(f64::NAN);
            let pass = match &c.expected {
                Expected::Named(want) => {
                    d.verdict == Verdict::Explained && &got == want && min_check >= 95.0
                }
                Expected::Nothing => d.verdict == Verdict::NothingMissing,
                Expected::Refuse => !d.verdict.is_answer(),
            };
            (
                pass,
                if got.is_empty() {
                    "(none)".into()
                } else {
                    got.join("+")
                },
                d.verdict.as_str(),
                min_check,
            )
        }
    };
    if std::env::var("DIAG_DEBUG").is_ok_and(|v| v == format!("{}:{}", c.kind, c.seed)) {
        if let Ok(d) = &d {
            eprintln!("{}", d.answer());
            for s in &d.candidates {
                eprintln!(
                    "  round {} {:<44} held-out {:.4e} explained {:>6.1} % bic {:>9.1} {}",
                    s.round,
                    s.id,
                    s.heldout_cost,
                    100.0 * s.explained,
                    s.bic_delta,
                    if s.accepted { "ACCEPTED" } else { "" }
                );
            }
        }
    }
    Outcome {
        pass,
        line: format!(
            "| {} | {} | {:.0} | {} | {} | {:?} | {verdict} | {got} | {min_check:.1} | {secs:.1} | {} |",
            c.kind,
            c.seed,
            c.dt_s * 1e3,
            if c.force_channels { "yes" } else { "no" },
            c.sizes,
            c.expected,
            if pass { "pass" } else { "FAIL" }
        ),
    }
}

fn matrix(kinds: &[&'static str], seeds: &[u64]) -> (usize, usize) {
    let cfg = nominal();
    let mut passed = 0;
    let mut total = 0;
    println!("| case | seed | dt ms | forces | drawn sizes | expected | verdict | named | min CHECK fit % | s | result |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for &seed in seeds {
        for &k in kinds {
            let o = run(&case(&cfg, k, seed));
            println!("{}", o.line);
            total += 1;
            passed += usize::from(o.pass);
        }
    }
    (passed, total)
}

/// The CI subset: kinds that cover each answer type (nothing, refusal, recalibration,
/// effects with other functional forms), one held-out seed.
const REDUCED: [&str; 6] = [
    "nominal_noise_free",
    "pure_noise",
    "conductance_low",
    "inertia_load",
    "stribeck",
    "dead_time_fractional",
];

/// Passes of [`REDUCED`] on `HELD_OUT_SEEDS[0]` (docs/diagnosis.md).
const REDUCED_PASSES: usize = 6;

#[test]
fn reduced_matrix() {
    let (passed, total) = matrix(&REDUCED, &HELD_OUT_SEEDS[..1]);
    println!("reduced matrix: {passed}/{total}");
    assert!(
        passed >= REDUCED_PASSES,
        "{passed}/{total} < {REDUCED_PASSES}"
    );
}

#[test]
#[ignore = "about 10 minutes: the documented full matrix (docs/diagnosis.md)"]
fn full_matrix() {
    let (tp, tt) = matrix(&KINDS, &TUNING_SEEDS);
    let (hp, ht) = matrix(&KINDS, &HELD_OUT_SEEDS);
    println!(
        "tuning seeds {TUNING_SEEDS:?}: {tp}/{tt} ({:.0} %); held-out seeds {HELD_OUT_SEEDS:?}: {hp}/{ht} ({:.0} %)",
        100.0 * tp as f64 / tt as f64,
        100.0 * hp as f64 / ht as f64
    );
}
