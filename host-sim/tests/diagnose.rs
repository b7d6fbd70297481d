//! Diagnosis on synthetic rig recordings: the null case says nothing is missing,
//! single concealed effects are named exactly with a check fit >= 95 % on every channel, a
//! Stribeck truth is named by the Coulomb+viscous candidate, a recording without force
//! channels gets the look-alike statement, and bad input gives clear errors.

mod common;
use common::*;
use std::path::Path;

use host_sim::diagnose::synth::{expected_id, generate, plant_with, Excitation, SynthSpec};
use host_sim::diagnose::{diagnose, DiagnoseOptions, Diagnosis, Verdict};
use host_sim::{Channel, PlantConfig, Recording};

fn nominal() -> PlantConfig {
    PlantConfig::load(plant()).unwrap()
}

/// TRAIN (pulses) and CHECK (chirp + steps) recordings of the rig with `truths` concealed.
fn recordings(
    truths: &[&str],
    seed: u64,
    dt_s: f64,
    channels: [bool; 5],
) -> (Recording, Recording) {
    let cfg = plant_with(&nominal_text(), truths, dt_s).unwrap();
    let label = truths.join("+");
    let train = generate(
        &cfg,
        &SynthSpec {
            excitation: Excitation::Pulses,
            duration_s: 8.0,
            dt_s,
            seed,
            noise: true,
            channels,
        },
        &label,
    )
    .unwrap();
    let check = generate(
        &cfg,
        &SynthSpec {
            excitation: Excitation::ChirpSteps,
            duration_s: 6.0,
            dt_s,
            seed: seed + 1000,
            noise: true,
            channels,
        },
        &label,
    )
    .unwrap();
    (train, check)
}

fn run(truths: &[&str], seed: u64, dt_s: f64, channels: [bool; 5]) -> Diagnosis {
    let (train, check) = recordings(truths, seed, dt_s, channels);
    diagnose_checked(&nominal(), &train, &check)
}

/// The diagnosis of `train` against `cfg`, checked on `check`, default options.
fn diagnose_checked(cfg: &PlantConfig, train: &Recording, check: &Recording) -> Diagnosis {
    diagnose(
        cfg,
        train,
        Some(check),
        &DiagnoseOptions::default(),
        &|_, _, _| {},
    )
    .unwrap()
}

/// [`diagnose_checked`] on the nominal plant with a fit budget of `fit_budget_s`.
fn diagnose_on_budget(train: &Recording, check: &Recording, fit_budget_s: f64) -> Diagnosis {
    let opts = DiagnoseOptions {
        fit_budget_s,
        ..DiagnoseOptions::default()
    };
    diagnose(&nominal(), train, Some(check), &opts, &|_, _, _| {}).unwrap()
}

fn named(d: &Diagnosis) -> Vec<String> {
    let mut v: Vec<String> = d.effects.iter().map(|e| e.id.clone()).collect();
    v.sort();
    v
}

fn assert_named_and_fits(truth: &str, seed: u64, dt_s: f64) {
    let d = run(&[truth], seed, dt_s, [true; 5]);
    assert_eq!(
        named(&d),
        vec![expected_id(truth).to_string()],
        "{truth}: {}",
        d.answer()
    );
    let check = d.check_after.as_ref().unwrap();
    for (k, v) in check {
        assert!(
            *v >= 95.0,
            "{truth}: check fit of {k} {v:.2} % < 95 %\n{}",
            d.answer()
        );
    }
    let json = d.to_json();
    assert_eq!(json["effects"][0]["id"], expected_id(truth));
    assert!(json["check"]["after"]["angle_deg"].as_f64().unwrap() >= 95.0);
}

#[test]
fn null_case_says_nothing_is_missing() {
    let d = run(&[], 11, 1e-3, [true; 5]);
    assert!(d.nothing_missing, "{}", d.answer());
    assert!(d.effects.is_empty());
    assert!(
        d.answer().starts_with("Nothing is missing"),
        "{}",
        d.answer()
    );
    let json = d.to_json();
    assert_eq!(json["effects"].as_array().unwrap().len(), 0);
    assert!(json["check"]["before"]["angle_deg"].as_f64().unwrap() > 95.0);
}

/// One test per concealed truth: `name: (truth, seed, sample period [s])`.
macro_rules! named_and_fits {
    ($($test:ident: ($truth:expr, $seed:expr, $dt_s:expr)),* $(,)?) => {
        $(
            #[test]
            fn $test() {
                assert_named_and_fits($truth, $seed, $dt_s);
            }
        )*
    };
}

named_and_fits! {
    joint_friction_is_named: ("joint_friction", 21, 1e-3),
    leakage_is_named_at_2_ms: ("leakage", 22, 2e-3),
    sensor_lag_is_named: ("sensor_lag", 23, 1e-3),
    muscle_hysteresis_is_named: ("muscle_hysteresis", 24, 1e-3),
    stribeck_truth_is_named_joint_friction: ("joint_friction_stribeck", 25, 1e-3),
}

#[test]
fn without_force_channels_the_lookalike_is_stated() {
    let d = run(
        &["joint_friction"],
        26,
        1e-3,
        [true, true, true, false, false],
    );
    let ids = named(&d);
    assert!(
        ids == ["joint_friction"] || ids == ["muscle_hysteresis"],
        "{ids:?}\n{}",
        d.answer()
    );
    assert!(
        d.answer().contains("cannot be told apart"),
        "{}",
        d.answer()
    );
    assert!(d.effects[0].evidence.contains("cannot be told apart"));
}

#[test]
fn cli_end_to_end_writes_json_and_report() {
    let dir = tempfile::tempdir().unwrap();
    let (train, check) = recordings(&["leakage"], 31, 1e-3, [true; 5]);
    let tp = dir.path().join("train.csv");
    let cp = dir.path().join("check.csv");
    train.write(&tp).unwrap();
    check.write(&cp).unwrap();
    let out = dir.path().join("out.json");
    let rep = dir.path().join("report");
    let stdout = ok(&on_plant(
        "diagnose",
        &plant(),
        &[
            &"--recording",
            &tp,
            &"--check",
            &cp,
            &"--json",
            &out,
            &"--report",
            &rep,
        ],
    ));
    assert!(stdout.contains("The model leaves out leakage"), "{stdout}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    for key in ["located", "effects", "fit", "check"] {
        assert!(v.get(key).is_some(), "missing {key}");
    }
    assert_eq!(v["effects"][0]["id"], "leakage");
    assert!(
        v["effects"][0]["params"]["sonic_conductance_m3_per_s_pa"]
            .as_f64()
            .unwrap()
            > 0.0
    );
    assert!(v["located"][0]["windows_s"].as_array().is_some());
    let html = std::fs::read_to_string(rep.join("index.html")).unwrap();
    assert!(html.contains("<svg") && html.contains("Candidate scores"));
    assert!(rep.join("diagnosis.json").exists());
}

#[test]
fn bad_inputs_give_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.json");
    let diagnose_fails = |plant: &Path, recording: &Path| {
        exits(
            2,
            &on_plant(
                "diagnose",
                &plant,
                &[&"--recording", &recording, &"--json", &out],
            ),
        )
    };
    let write = |name: &str, text: &str| {
        let p = dir.path().join(name);
        std::fs::write(&p, text).unwrap();
        p
    };
    // A recording with a non-number on line 4 (2 comment lines, header, then data).
    let bad = write(
        "bad.csv",
        "# sample_period_s = 0.001\n# x = y\nt_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg\n0,0,0,0,0,zero\n0.001,0,0,0,0,0\n",
    );
    // A plant file with a misspelt key.
    let misspelt = write(
        "p.toml",
        &nominal_text().replace("inertia_kgm2", "inertia_kg"),
    );
    // Too short a recording.
    let short = write(
        "short.csv",
        "t_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg\n0,0,0,0,0,0\n0.001,0,0,0,0,0\n0.002,0,0,0,0,0\n",
    );
    for (plant, recording, wants) in [
        (plant(), &bad, ["bad.csv:4", "angle_deg"]),
        (misspelt, &bad, ["p.toml", "inertia_kg"]),
        (plant(), &short, ["short.csv", "at least"]),
    ] {
        let err = diagnose_fails(&plant, recording);
        assert!(wants.iter().all(|w| err.contains(w)), "{err}");
        assert!(!out.exists());
    }
}

/// The diagnosis, against the nominal file, of TRAIN and CHECK of the nominal rig with one
/// plant-file line changed (a key the diagnosis does not refit), at 2 ms.
fn diagnosis_of_edited(from: &str, to: &str, seed: u64, noise: bool) -> Diagnosis {
    let text = nominal_text();
    assert!(text.contains(from), "{from}");
    let cfg = plant_with(&text.replace(from, to), &[], 0.002).unwrap();
    let spec = |excitation, duration_s, seed| SynthSpec {
        excitation,
        duration_s,
        dt_s: 0.002,
        seed,
        noise,
        channels: [true; 5],
    };
    let train = generate(&cfg, &spec(Excitation::Pulses, 8.0, seed), "edited").unwrap();
    let check_spec = spec(Excitation::ChirpSteps, 6.0, seed + 1000);
    let check = generate(&cfg, &check_spec, "edited").unwrap();
    diagnose_checked(&nominal(), &train, &check)
}

/// Asserts that one of the look-alike statements of `d` `says` what is expected.
fn assert_lookalike(d: &Diagnosis, says: impl Fn(&str) -> bool) {
    assert!(d.lookalikes.iter().any(|l| says(l)), "{:?}", d.lookalikes);
}

#[test]
fn a_wrong_initial_contraction_is_recalibrated_and_answered_with_its_group() {
    // The muscles' initial contraction 30 % off (0.14 -> 0.182). Before the diagnosis
    // refitted this key the best it found (sensor gains, a conductance) left 105 times the
    // noise and was rightly unexplained; the key is now refitted, and the answer names the
    // group of keys that move the muscles' operating point alike.
    for noise in [false, true] {
        let d = diagnosis_of_edited(
            "initial_contraction = 0.14 ",
            "initial_contraction = 0.182 ",
            4242,
            noise,
        );
        let answer = d.answer();
        assert_eq!(d.verdict, Verdict::Explained, "noise {noise}: {answer}");
        assert!(d.effects.is_empty(), "{answer}");
        let r = &d.recalibrated[0];
        assert_eq!(r.key, "joint.initial_contraction", "{answer}");
        assert!((r.fitted / 0.182 - 1.0).abs() < 0.01, "{answer}");
        assert_lookalike(&d, |l| {
            l.contains("end factor, initial contraction or rest length")
        });
        println!("noise {noise}: {answer}");
    }
}

#[test]
fn a_key_off_beyond_its_search_range_is_named_at_its_bound() {
    // The muscle radius 40 % large, beyond the 0.7x..1.3x the diagnosis searches, with its
    // look-alikes (the braid angle and the end factor, which together make up for it) left
    // out of the pool: the best attempt puts the radius at the end of its range and still
    // leaves many times the noise. The answer is unexplained, and it says the radius ended
    // at its bound.
    let text = nominal_text().replace("radius_m = 0.01 ", "radius_m = 0.014 ");
    let cfg = plant_with(&text, &[], 0.002).unwrap();
    let spec = |excitation, duration_s, seed| SynthSpec {
        excitation,
        duration_s,
        dt_s: 0.002,
        seed,
        noise: false,
        channels: [true; 5],
    };
    let train = generate(&cfg, &spec(Excitation::Pulses, 8.0, 4244), "edited").unwrap();
    let check = generate(&cfg, &spec(Excitation::ChirpSteps, 6.0, 5244), "edited").unwrap();
    let opts = DiagnoseOptions {
        exclude_candidates: [
            "muscle.braid_angle_deg",
            "muscle.end_factor",
            "joint.initial_contraction",
            "muscle.rest_length_m",
        ]
        .map(String::from)
        .to_vec(),
        ..DiagnoseOptions::default()
    };
    let d = diagnose(&nominal(), &train, Some(&check), &opts, &|_, _, _| {}).unwrap();
    let answer = d.answer();
    assert_eq!(d.verdict, Verdict::Unexplained, "{answer}");
    let hit = d
        .best_attempt_at_bound
        .iter()
        .find(|h| h.part == "muscle.radius_m")
        .unwrap_or_else(|| panic!("{:?}\n{answer}", d.best_attempt_at_bound));
    assert_eq!(hit.nominal, Some(0.01));
    assert!((hit.bound - 0.013).abs() < 1e-12, "{hit:?}");
    assert!(answer.contains("muscle.radius_m ended at"), "{answer}");
    assert!(answer.contains("--params muscle.radius_m"), "{answer}");
}

#[test]
fn a_radius_off_beyond_its_search_range_is_answered_by_its_group() {
    // The same radius 40 % large with the whole pool: the braid angle (with the end factor)
    // makes up for it, and the answer says the radius and the braid angle are one group.
    let d = diagnosis_of_edited("radius_m = 0.01 ", "radius_m = 0.014 ", 4244, false);
    let answer = d.answer();
    assert_eq!(d.verdict, Verdict::Explained, "{answer}");
    assert!(
        d.recalibrated
            .iter()
            .any(|r| r.key == "muscle.radius_m" || r.key == "muscle.braid_angle_deg"),
        "{answer}"
    );
    assert_lookalike(&d, |l| l.contains("muscle radius or braid angle"));
}

#[test]
fn a_wrong_sprocket_radius_is_recalibrated_and_its_bound_said() {
    // A sprocket radius 30 % large, beyond the 0.8x..1.25x the diagnosis searches: the key
    // is refitted to its bound (the rest length makes up the rest of the gearing r / l_n),
    // and the answer says the true value may lie beyond the bound. (Before the key was
    // refitted this was answered by its exact look-alike, an angle gain.)
    let d = diagnosis_of_edited(
        "sprocket_radius_m = 0.025 ",
        "sprocket_radius_m = 0.0325 ",
        4243,
        true,
    );
    let answer = d.answer();
    assert_eq!(d.verdict, Verdict::Explained, "{answer}");
    let r = d
        .recalibrated
        .iter()
        .find(|r| r.key == "joint.sprocket_radius_m")
        .unwrap_or_else(|| panic!("{answer}"));
    assert_eq!(r.at_bound, Some(0.025 * 1.25), "{answer}");
    assert!(
        answer.contains("at its bound 3.1250e-2: the true value may lie beyond"),
        "{answer}"
    );
    assert!(
        d.residual_x_noise.0 <= host_sim::diagnose::verdict::MAX_RESIDUAL_X_NOISE,
        "{:?}",
        d.residual_x_noise
    );
}

fn diagnose_default(rec: &Recording) -> Diagnosis {
    diagnose(
        &nominal(),
        rec,
        None,
        &DiagnoseOptions::default(),
        &|_, _, _| {},
    )
    .unwrap()
}

#[test]
fn independent_loaded_fixture_is_an_inertia_recalibration() {
    // shared/conformance/pulses_loaded.csv comes from an independent implementation of the
    // plant with the 3.34 kg load (J = 0.155 kg m^2); diagnosed against the unloaded
    // nominal file, the answer must be the plant file's inertia, recalibrated to the loaded
    // value (a wrong parameter, not missing physics).
    let rec = Recording::read(fixture("pulses_loaded.csv")).unwrap();
    let d = diagnose_default(&rec);
    assert_eq!(d.verdict, Verdict::Explained, "{}", d.answer());
    assert!(d.effects.is_empty(), "{}", d.answer());
    assert_eq!(d.recalibrated.len(), 1, "{}", d.answer());
    let r = &d.recalibrated[0];
    assert_eq!(r.key, "joint.inertia_kgm2");
    assert_eq!(r.nominal, 0.014);
    assert!((r.fitted - 0.155).abs() < 0.155 * 0.02, "J = {}", r.fitted);
    assert!(
        r.ci95[0] <= r.fitted && r.fitted <= r.ci95[1],
        "{:?}",
        r.ci95
    );
    assert!(d.fit_after.values().all(|f| *f > 99.0), "{:?}", d.fit_after);
    let json = d.to_json();
    assert!(json.get("check").is_none());
    assert_eq!(json["verdict"], "explained");
    assert_eq!(json["recalibrated"][0]["key"], "joint.inertia_kgm2");
    assert!(json["recalibrated"][0]["ci95"][1].as_f64().unwrap() > 0.15);
}

#[test]
fn independent_thermal_fixture_is_the_chamber_thermodynamics() {
    // pulses_thermal.csv comes from an independent implementation of the plant with the
    // thermodynamic chamber of PLANT.md (its header states hA and kappa). Diagnosed against
    // the isothermal nominal file, the answer must be that chamber, with the header's hA,
    // and nothing else (the data is noise-free: no parameter is off).
    let rec = Recording::read(fixture("pulses_thermal.csv")).unwrap();
    let header = rec.meta("thermal").expect("# thermal = ... header");
    let h_at = header.find("hA_w_per_k = ").unwrap() + "hA_w_per_k = ".len();
    let h_true: f64 = header[h_at..]
        .split_whitespace()
        .next()
        .unwrap()
        .parse()
        .unwrap();
    let d = diagnose_default(&rec);
    assert_eq!(d.verdict, Verdict::Explained, "{}", d.answer());
    assert!(d.recalibrated.is_empty(), "{}", d.answer());
    assert_eq!(d.effects.len(), 1, "{}", d.answer());
    assert_eq!(d.effects[0].id, "heat_transfer", "{}", d.answer());
    let h = d.effects[0].params[0].1;
    assert!(
        (h - h_true).abs() < 0.05 * h_true,
        "hA = {h} W/K, header {h_true}"
    );
    assert!(d.fit_after.values().all(|f| *f > 99.5), "{:?}", d.fit_after);
    assert!(
        d.fit_before.values().all(|f| *f < 95.0),
        "{:?}",
        d.fit_before
    );
    // The look-alike (a constant polytropic exponent) is named, with what each removes.
    assert_lookalike(&d, |l| {
        l.starts_with("Chamber thermodynamics vs a constant polytropic exponent")
    });
}

#[test]
fn noise_free_nominal_data_says_nothing_is_missing() {
    let cfg = nominal();
    let mk = |excitation, seed| {
        generate(
            &cfg,
            &SynthSpec {
                excitation,
                duration_s: 6.0,
                dt_s: 1e-3,
                seed,
                noise: false,
                channels: [true; 5],
            },
            "none",
        )
        .unwrap()
    };
    let train = mk(Excitation::Pulses, 41);
    let check = mk(Excitation::ChirpSteps, 42);
    let d = diagnose_checked(&cfg, &train, &check);
    assert_eq!(d.verdict, Verdict::NothingMissing, "{}", d.answer());
    assert!(
        d.answer().starts_with("Nothing is missing"),
        "{}",
        d.answer()
    );
    assert!(!d.answer().contains("misses something"));
}

#[test]
fn pure_noise_names_nothing_and_exits_3_with_the_json_written() {
    let dir = tempfile::tempdir().unwrap();
    let (mut train, _) = recordings(&[], 51, 2e-3, [true, true, true, false, false]);
    // Replace every channel by noise around its mean: nothing this plant does.
    let mut state = 12345u64;
    let mut next = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((state >> 11) as f64 / (1u64 << 53) as f64) - 0.5
    };
    for y in train.outputs.iter_mut().flatten() {
        for v in y.iter_mut() {
            *v = 300.0 * next();
        }
    }
    let tp = dir.path().join("noise.csv");
    train.write(&tp).unwrap();
    let out = dir.path().join("out.json");
    let o = on_plant(
        "diagnose",
        &plant(),
        &[&"--recording", &tp, &"--json", &out],
    );
    exits(3, &o);
    let stdout = text(&o.stdout);
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let verdict = v["verdict"].as_str().unwrap();
    assert!(
        verdict == "not_this_plant" || verdict == "unexplained",
        "{verdict}"
    );
    assert_eq!(v["effects"].as_array().unwrap().len(), 0);
    assert_eq!(v["recalibrated"].as_array().unwrap().len(), 0);
    assert!(
        stdout.contains("no effect is named") && stdout.contains("Likely causes"),
        "{stdout}"
    );
}

#[test]
fn valve_delay_is_told_from_sensor_lag() {
    assert_named_and_fits("valve_delay", 27, 3e-3);
    let d = run(&["valve_delay"], 27, 3e-3, [true; 5]);
    let a = d.answer();
    assert!(a.contains("Sensor lag vs valve delay"), "{a}");
    // 8 ms rounded to whole 3 ms samples (the truth's generator): 9 ms, found within 0.1 %
    // by the continuous refinement.
    let delay = d.effects[0].params[0].1;
    assert!((delay - 9e-3).abs() < 1e-5, "delay {delay}");
}

#[test]
fn a_recording_longer_than_the_fit_budget_is_fitted_on_its_head_with_the_same_answer() {
    // 8 s of TRAIN against a 2 s budget: the fits replay only the head, the held-out scoring
    // and the final replay all of it. The answer and the parameter stay those of the full
    // fits (within the solver tolerance's effect on a refit).
    let (train, check) = recordings(&["leakage"], 77, 1e-3, [true; 5]);
    let full = diagnose_checked(&nominal(), &train, &check);
    let head = diagnose_on_budget(&train, &check, 2.0);
    assert_eq!(
        named(&full),
        vec!["leakage".to_string()],
        "{}",
        full.answer()
    );
    assert_eq!(named(&head), named(&full), "{}", head.answer());
    let c = |d: &Diagnosis| d.effects[0].params[0].1;
    assert!(
        (c(&head) / c(&full) - 1.0).abs() < 0.05,
        "{} vs {}",
        c(&head),
        c(&full)
    );
}

/// Adds what no catalogue effect has to the angle channel: electrical cross-talk of the valve
/// drivers onto the angle sensor (a slow response to the inlet of muscle 1 minus that of
/// muscle 2, time constant 80 ms), as large as the angle's own spread. A code path of its
/// own (not the candidates'): the recordings come from the nominal plant, the cross-talk is
/// added here.
fn with_crosstalk(mut rec: Recording) -> Recording {
    let dt = rec.sample_period_s();
    let a = (-dt / 0.08f64).exp();
    let angle = rec
        .channel(host_sim::io::recording::Channel::AngleDeg)
        .unwrap()
        .to_vec();
    let (lo, hi) = angle
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
            (l.min(*v), h.max(*v))
        });
    let mut slow = 0.0;
    let out: Vec<f64> = angle
        .iter()
        .zip(&rec.inputs)
        .map(|(y, u)| {
            slow = a * slow + (1.0 - a) * (u.u_in1 - u.u_in2);
            y + (hi - lo) * slow
        })
        .collect();
    rec.set_channel(host_sim::io::recording::Channel::AngleDeg, out);
    rec
}

#[test]
fn an_effect_outside_the_catalogue_gets_an_unnamed_black_box_correction() {
    let (train, check) = recordings(&[], 41, 1e-3, [true; 5]);
    let (train, check) = (with_crosstalk(train), with_crosstalk(check));
    let d = diagnose_checked(&nominal(), &train, &check);
    assert_eq!(d.verdict, Verdict::Unexplained, "{}", d.answer());
    assert!(d.effects.is_empty() && d.recalibrated.is_empty());
    let b = d.black_box.as_ref().expect("a black-box fallback");
    let (before, after) = b.heldout["angle_deg"];
    let (cb, ca) = b.check.as_ref().expect("check fits")["angle_deg"];
    eprintln!(
        "{}\nheld-out angle {before:.1} -> {after:.1} %, check {cb:.1} -> {ca:.1} %",
        d.answer()
    );
    assert!(after > before + 20.0, "held-out {before} -> {after}");
    assert!(ca > cb + 20.0, "check {cb} -> {ca}");
    let a = d.answer();
    assert!(a.contains("Unnamed black-box correction"), "{a}");
    let j = d.to_json();
    assert_eq!(j["black_box"]["named"], serde_json::json!(false));
    assert!(j["effects"].as_array().unwrap().is_empty());
}

/// The replays the diagnosis scores without holding them (`Problem::replay_costs`, on a
/// problem that keeps the nominal states of a head only) give the costs of the held replays
/// of `Problem::new` + `predict` + `channel_costs` to the bit: a dynamic effect, a sensor
/// effect (replayed on the nominal plant past the kept head) and the two together.
#[test]
fn streamed_replay_costs_match_held_replays() {
    use host_sim::diagnose::fitting::{Part, Problem};
    use host_sim::diagnose::selection::candidate_pool;
    let nominal = nominal();
    let (train, _) = recordings(&["leakage"], 11, 1e-3, [true, true, true, true, true]);
    let n = train.len();
    let scale = [2.0, 50.0, 60.0, 40.0, 45.0];
    let opts = DiagnoseOptions::default().solver;
    let held = Problem::new(&nominal, &train, scale, opts).unwrap();
    let mut nominal_meas = Vec::new();
    let streamed = Problem::with_nominal_each(&nominal, &train, scale, opts, n / 4, |_, m| {
        nominal_meas.push(*m)
    })
    .unwrap();
    assert!(streamed.replay_heads && streamed.base_states.len() == n / 4);
    assert_eq!(nominal_meas, held.predict(&[]).unwrap());
    let pool = candidate_pool(&nominal);
    let part = |id: &str| -> Part {
        let c = pool.iter().find(|c| c.id() == id).expect(id).as_ref();
        let params = c.params(&held.setup).iter().map(|s| s.scale).collect();
        Part {
            candidate: c,
            params,
        }
    };
    for parts in [
        vec![part("leakage")],
        vec![part("sensor_lag")],
        vec![part("sensor_lag"), part("leakage")],
    ] {
        let range = n / 2..n;
        let want = held.channel_costs(&held.predict(&parts).unwrap(), range.clone());
        let got = streamed.replay_costs(&parts, range).unwrap();
        assert_eq!(got.map(f64::to_bits), want.map(f64::to_bits));
        assert!(got.iter().sum::<f64>() > 0.0);
    }
}

/// A recording read from its file block by block is the one parsed from the whole text,
/// also when its time stamps have more digits than the fast row reader takes.
#[test]
fn streamed_read_matches_whole_text() {
    let (train, _) = recordings(&["leakage"], 12, 1e-3, [true, true, true, false, false]);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("train.csv");
    train.write(&path).unwrap();
    // The writer writes stamps to the nanosecond: put back `{}` of the float k * dt, as
    // another tool writes them (0.009000000000000001).
    let written = std::fs::read_to_string(&path).unwrap();
    let mut rows = train.t_s.iter();
    let text: String = written
        .lines()
        .map(|l| match l.split_once(',') {
            Some((t, rest)) if !l.starts_with('#') && t != "t_s" => {
                format!("{},{rest}\n", rows.next().unwrap())
            }
            _ => format!("{l}\n"),
        })
        .collect();
    std::fs::write(&path, &text).unwrap();
    assert!(text.contains("0.009000000000000001,"), "a long stamp");
    let whole = Recording::parse(&text, &path).unwrap();
    let read = Recording::read(&path).unwrap();
    assert_eq!(read, whole);
    assert!(read
        .channel(host_sim::io::recording::Channel::F1N)
        .is_none());
}

/// TRAIN longer than the fit budget (3 s of 8 s): the nominal states are kept for the head
/// only, the evidence and the error location are built on it, the candidates are scored on
/// the rest by replays that are not held (a sensor effect past the head on the nominal
/// plant replayed again). A dynamic and a sensor truth are still named, with check fits of
/// at least 95 %, and the report series is thinned to the plot.
#[test]
fn fit_budget_shorter_than_train_names_the_truth() {
    for (truth, seed) in [("leakage", 3), ("sensor_lag", 5)] {
        let (train, check) = recordings(&[truth], seed, 1e-3, [true; 5]);
        let d = diagnose_on_budget(&train, &check, 3.0);
        assert_eq!(
            named(&d),
            vec![expected_id(truth).to_string()],
            "{truth}: {}",
            d.answer()
        );
        for (k, v) in d.check_after.as_ref().unwrap() {
            assert!(*v >= 95.0, "{truth}: check fit of {k} {v:.2} %");
        }
        assert_eq!(d.train.len, train.len());
        assert_eq!(d.train.stride, train.len() / 2500);
        assert_eq!(d.train.t_s.len(), train.len().div_ceil(d.train.stride));
        assert_eq!(d.train.corrected.len(), d.train.t_s.len());
    }
}

/// A rig log rarely starts at the plant file's `[initial]`: the conformance fixture
/// (an independent implementation of the plant, started at 550 kPa) against a plant file that
/// says 450 kPa. The replays start from the recording's first sample, and the answer says so;
/// before, the first seconds' departure was answered `unexplained`.
#[test]
fn a_recording_that_starts_away_from_the_files_initial_state_is_replayed_from_its_first_sample() {
    let text = nominal_text()
        .replace("p1_gauge_pa = 550000.0", "p1_gauge_pa = 450000.0")
        .replace("p2_gauge_pa = 550000.0", "p2_gauge_pa = 450000.0");
    assert_ne!(text, nominal_text());
    let cfg = PlantConfig::from_toml_str(&text, "mis_initial.toml").unwrap();
    let train = Recording::read(fixture("pulses_nominal.csv")).unwrap();
    let d = diagnose(
        &cfg,
        &train,
        None,
        &DiagnoseOptions::default(),
        &|_, _, _| {},
    )
    .unwrap();
    println!("{}\n{:?}", d.answer(), d.data_notes);
    assert_eq!(d.verdict, Verdict::NothingMissing, "{}", d.answer());
    assert!(
        d.data_notes
            .iter()
            .any(|n| n.contains("p1_kpa 550") && n.contains("starts there")),
        "{:?}",
        d.data_notes
    );
    assert!(
        d.answer().contains("Note: the recording does not start"),
        "{}",
        d.answer()
    );
}

/// `diagnose` of the nominal rig's recording with `check` as the check recording.
fn nominal_with_check(check: &std::path::Path, json: &std::path::Path) -> std::process::Output {
    on_plant(
        "diagnose",
        &plant(),
        &[
            &"--recording",
            &fixture("pulses_nominal.csv"),
            &"--check",
            &check,
            &"--json",
            &json,
        ],
    )
}

/// `text` (a recording) with every cell of `columns` multiplied by `factor`.
fn scaled_columns(text: &str, columns: &[&str], factor: f64) -> String {
    mapped_columns(text, columns, |v| v * factor)
}

/// `text` (a recording) with `add` added to every cell of `columns`.
fn shifted_columns(text: &str, columns: &[&str], add: f64) -> String {
    mapped_columns(text, columns, |v| v + add)
}

/// `text` (a recording) with `f` applied to every cell of `columns`.
fn mapped_columns(text: &str, columns: &[&str], f: impl Fn(f64) -> f64) -> String {
    let mut header: Option<Vec<&str>> = None;
    let mut out = String::new();
    for l in text.lines() {
        if l.starts_with('#') {
            out += l;
        } else if let Some(h) = &header {
            let f: Vec<String> = l
                .split(',')
                .zip(h)
                .map(|(v, name)| {
                    if columns.contains(name) {
                        format!("{:.6}", f(v.parse::<f64>().unwrap()))
                    } else {
                        v.to_string()
                    }
                })
                .collect();
            out += &f.join(",");
        } else {
            header = Some(l.split(',').collect());
            out += l;
        }
        out.push('\n');
    }
    out
}

#[test]
fn a_unit_slip_in_the_check_recording_is_named_as_such_not_as_a_departure() {
    // TRAIN is the nominal rig's recording; CHECK the same run with its angle logged in
    // radians: the answer names CHECK's unit, not a rig that "went elsewhere".
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(fixture("pulses_nominal.csv")).unwrap();
    let check = dir.path().join("check_rad.csv");
    std::fs::write(
        &check,
        scaled_columns(&text, &["angle_deg"], 1f64.to_radians()),
    )
    .unwrap();
    let json = dir.path().join("d.json");
    let out = text_of_any_status(&nominal_with_check(&check, &json));
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["verdict"], "not_this_plant", "{out}");
    assert!(
        out.contains("in the check recording (--check): angle_deg fits the model")
            && out.contains("read as radians"),
        "{out}"
    );
}

#[test]
fn pressures_logged_in_psi_or_bar_and_read_as_kpa_are_named_as_such() {
    // The nominal rig's recording (the independent reference implementation) with both
    // pressure columns written in psi, then in bar, but read as kPa: the answer names the
    // unit, not a plant-file key.
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(fixture("pulses_nominal.csv")).unwrap();
    for (unit, kpa_per_unit) in [("psi", 6.894_757_293_168), ("bar", 100.0)] {
        let train = dir.path().join(format!("train_{unit}.csv"));
        std::fs::write(
            &train,
            scaled_columns(&text, &["p1_kpa", "p2_kpa"], 1.0 / kpa_per_unit),
        )
        .unwrap();
        let json = dir.path().join(format!("d_{unit}.json"));
        let out = text_of_any_status(&on_plant(
            "diagnose",
            &plant(),
            &[&"--recording", &train, &"--json", &json],
        ));
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        assert_eq!(v["verdict"], "not_this_plant", "{unit}: {out}");
        assert!(
            out.contains(&format!("pressures logged in {unit} and read as kPa")),
            "{unit}: {out}"
        );
    }
}

#[test]
fn a_correction_that_makes_the_check_recording_worse_is_not_named() {
    // TRAIN from a rig with twice the inertia (the simulator, through the CLI); CHECK is the
    // nominal rig's recording (the independent reference implementation): the inertia the
    // diagnosis refits on TRAIN makes CHECK worse, so it did not hold there.
    let dir = tempfile::tempdir().unwrap();
    let heavy = dir.path().join("heavy.toml");
    std::fs::write(
        &heavy,
        nominal_text().replace("inertia_kgm2 = 0.014", "inertia_kgm2 = 0.028"),
    )
    .unwrap();
    let train = dir.path().join("train.csv");
    ok(&host_sim(&[
        &"simulate",
        &"--plant",
        &heavy,
        &"--inputs",
        &fixture("pulses_nominal.csv"),
        &"--out",
        &train,
    ]));
    let json = dir.path().join("d.json");
    let r = on_plant(
        "diagnose",
        &plant(),
        &[
            &"--recording",
            &train,
            &"--check",
            &fixture("pulses_nominal.csv"),
            &"--json",
            &json,
        ],
    );
    exits(3, &r);
    let out = text(&r.stdout);
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["verdict"], "unexplained", "{out}");
    assert!(v["recalibrated"].as_array().unwrap().is_empty(), "{v}");
    let not_held = v["check"]["not_held"].as_str().unwrap();
    assert!(not_held.contains("angle_deg 100.0 % -> "), "{not_held}");
    assert!(
        out.contains("did not hold on the check recording") && out.contains("joint.inertia_kgm2"),
        "{out}"
    );
    // Without the check recording the same training data is explained (the inertia).
    let stdout = ok(&on_plant(
        "diagnose",
        &plant(),
        &[&"--recording", &train, &"--json", &json],
    ));
    assert!(stdout.contains("joint.inertia_kgm2"), "{stdout}");
}

#[test]
fn pressures_logged_absolute_get_the_gauge_hint() {
    // The nominal rig's recording with p_atm added to both pressure columns (an absolute
    // sensor logged as gauge): the fitted offset is the atmosphere, and the answer says so.
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(fixture("pulses_nominal.csv")).unwrap();
    let abs = dir.path().join("abs.csv");
    std::fs::write(&abs, shifted_columns(&text, &["p1_kpa", "p2_kpa"], 101.325)).unwrap();
    let json = dir.path().join("d.json");
    let stdout = text_of_any_status(&on_plant(
        "diagnose",
        &plant(),
        &[&"--recording", &abs, &"--json", &json],
    ));
    for n in [
        "the pressure columns look absolute, not gauge",
        "RECORDING.md's columns are gauge: subtract p_atm or import with reference = \"absolute\"",
    ] {
        assert!(stdout.contains(n), "`{n}` not in:\n{stdout}");
    }
    // The answer's first words name the absolute logging, before any effect.
    assert!(
        stdout.lines().any(|l| l.starts_with(
            "The pressure columns were logged absolute, not gauge (the fitted offset is one \
             atmosphere): subtract p_atm or import with reference = \"absolute\". The model \
             leaves out"
        )),
        "{stdout}"
    );
    // Without the force columns: the offset alone, every channel at 100 %, nothing
    // recalibrated. (The calibrated sensors move the replay's start, which is the recording's
    // first sample as read: the muscles start an atmosphere lower than the columns say. A
    // shortcut that reused the nominal replay's states missed that, and a braid angle moved
    // by 0.0 % "explained" the rest.)
    let no_forces: String = shifted_columns(&text, &["p1_kpa", "p2_kpa"], 101.325)
        .lines()
        .map(|l| {
            if l.starts_with('#') {
                format!("{l}\n")
            } else {
                format!("{}\n", l.split(',').take(8).collect::<Vec<_>>().join(","))
            }
        })
        .collect();
    std::fs::write(&abs, no_forces).unwrap();
    let stdout = ok(&on_plant(
        "diagnose",
        &plant(),
        &[&"--recording", &abs, &"--json", &json],
    ));
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert!(v["recalibrated"].as_array().unwrap().is_empty(), "{stdout}");
    assert!(
        stdout.contains("angle_deg 96.4 % -> 100.0 %")
            && stdout.contains("p1_kpa 58.3 % -> 100.0 %")
            && stdout.contains("look absolute"),
        "{stdout}"
    );
    // A real sensor offset (20 kPa) gets no such hint.
    std::fs::write(&abs, shifted_columns(&text, &["p1_kpa", "p2_kpa"], 20.0)).unwrap();
    let stdout = text_of_any_status(&on_plant(
        "diagnose",
        &plant(),
        &[&"--recording", &abs, &"--json", &json],
    ));
    assert!(stdout.contains("p1_offset_kpa +20.0"), "{stdout}");
    assert!(!stdout.contains("look absolute"), "{stdout}");
    assert!(!stdout.contains("logged absolute"), "{stdout}");
}

/// stdout of a run that exited 0 or 3 (an answer either way), without a panic.
fn text_of_any_status(r: &std::process::Output) -> String {
    assert!(
        matches!(r.status.code(), Some(0 | 3)),
        "{:?}\n{}\n{}",
        r.status,
        text(&r.stdout),
        text(&r.stderr)
    );
    text(&r.stdout)
}

/// A noise-free recording (the independent conformance run) whose angle alone is offset by
/// 0.5 deg after 1 s: only the angle is located; the other channels, which still fit the
/// model to rounding (100.0 %), are not listed as departures.
#[test]
fn only_channels_that_depart_are_located_on_noise_free_data() {
    let dir = tempfile::tempdir().unwrap();
    let mut rec = Recording::read(fixture("pulses_nominal.csv")).unwrap();
    let t = rec.t_s.clone();
    let mut angle = rec.channel(Channel::AngleDeg).unwrap().to_vec();
    for (a, t) in angle.iter_mut().zip(&t) {
        if *t > 1.0 {
            *a += 0.5;
        }
    }
    rec.set_channel(Channel::AngleDeg, angle);
    let p = dir.path().join("bumped.csv");
    rec.write(&p).unwrap();
    let out = dir.path().join("out.json");
    let r = on_plant("diagnose", &plant(), &[&"--recording", &p, &"--json", &out]);
    let stdout = String::from_utf8_lossy(&r.stdout).to_string();
    let located: Vec<&str> = stdout
        .lines()
        .filter(|l| l.starts_with("Located:"))
        .collect();
    assert_eq!(located.len(), 1, "{stdout}");
    assert!(located[0].starts_with("Located: angle_deg"), "{stdout}");
    assert!(!stdout.contains("(fit 100.0 %)"), "{stdout}");
}

/// A joint resting with its valves shut (a latched fault's safe state, captured): nothing
/// to judge, said so, exit 2, instead of a verdict on a fit over rounding.
#[test]
fn a_recording_in_which_nothing_moves_is_refused_as_nothing_to_judge() {
    let dir = tempfile::tempdir().unwrap();
    let n = 800;
    let mut rec = Recording {
        t_s: (0..n).map(|k| k as f64 * 1e-3).collect(),
        inputs: vec![host_sim::ValveInputs::default(); n],
        ..Recording::default()
    };
    rec.set_channel(Channel::AngleDeg, vec![-7.380001; n]);
    rec.set_channel(
        Channel::P1Kpa,
        (0..n).map(|k| 312.4 + 0.1 * (k % 3) as f64).collect(),
    );
    rec.set_channel(Channel::P2Kpa, vec![288.1; n]);
    let p = dir.path().join("rest.csv");
    rec.write(&p).unwrap();
    let out = dir.path().join("out.json");
    let r = on_plant("diagnose", &plant(), &[&"--recording", &p, &"--json", &out]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert!(
        err.contains("nothing to judge") && err.contains("never change"),
        "{err}"
    );
    assert!(!out.exists());
}

/// The training run fits the nominal model within its noise, but the check run was made with
/// a load on the joint: "nothing is missing" would be said of the training run alone. The
/// answer names the check's departing channels and exits 3.
#[test]
fn a_check_recording_the_nominal_model_does_not_describe_is_not_nothing_missing() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("d.json");
    let with_check = |check: &std::path::Path| nominal_with_check(check, &json);
    let r = with_check(&fixture("pulses_loaded.csv"));
    let out = text(&r.stdout);
    exits(3, &r);
    assert!(
        out.contains("explains the training recording within its noise")
            && out.contains("but not the check recording (angle_deg"),
        "{out}"
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["verdict"], "unexplained");
    assert!(
        v["check"]["departs"]
            .as_str()
            .unwrap()
            .contains("angle_deg"),
        "{v}"
    );
    // The same training run checked on another run of the same joint: nothing is missing.
    let out = ok(&with_check(&fixture("pwm_nominal.csv")));
    assert!(out.contains("Nothing is missing"), "{out}");
}

#[test]
fn far_off_keys_are_found_from_the_grid_before_the_local_search() {
    // A plant file whose valve conductance is 4.4 times the rig's, or whose muscle damping is
    // 1/15 of it, against the independent nominal recording: the local search from the
    // file's value alone stopped far off (unexplained); the log grid over the key's range
    // starts it near the truth (8e-9, 2e-4).
    let train = Recording::read(fixture("pulses_nominal.csv")).unwrap();
    for (from, to, key, truth, tol) in [
        (
            "sonic_conductance_m3_per_s_pa = 8.0e-9",
            "sonic_conductance_m3_per_s_pa = 3.5e-8",
            "valve.sonic_conductance_m3_per_s_pa",
            8.0e-9,
            0.01,
        ),
        (
            "damping_m2s = 2.0e-4",
            "damping_m2s = 1.33e-5",
            "muscle.damping_m2s",
            2.0e-4,
            0.1,
        ),
    ] {
        let text = nominal_text();
        assert!(text.contains(from), "{from}");
        let cfg = PlantConfig::from_toml_str(&text.replace(from, to), "far.toml").unwrap();
        let d = diagnose(
            &cfg,
            &train,
            None,
            &DiagnoseOptions::default(),
            &|_, _, _| {},
        )
        .unwrap();
        let answer = d.answer();
        assert_eq!(d.verdict, Verdict::Explained, "{answer}");
        let r = &d.recalibrated[0];
        assert_eq!(r.key, key, "{answer}");
        assert!((r.fitted / truth - 1.0).abs() < tol, "{answer}");
        assert!(r.at_bound.is_none(), "{answer}");
    }
}
