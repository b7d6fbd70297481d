//! The diagnosis against recordings it was not written against: the independent test rig
//! (`tests/support/testrig.rs`: its own plant code, RK4, effect forms unlike the
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
//! - The evidence base (`testrig::CASES`, the second half of this file): forms unlike the
//!   candidates', mis-set keys, nominal data on jittered and gappy time bases,
//!   out-of-catalogue forms; sensitivity and honesty rates per seed set
//!   (`evidence_reduced_matrix` in CI, `evidence_full_matrix` and `discovery_matrix` ignored).
//!
//! A case passes when its verdict is the expected one (`explained` with exactly the expected
//! effect ids and recalibrated keys and every CHECK channel >= 95 % after; `nothing_missing`;
//! or a refusal, exit status 3, for pure noise). Without force channels joint friction and
//! muscle hysteresis count as one answer, and so do the recalibrations of the valve
//! conductance and of the chamber volume (the diagnosis says they cannot be told apart), and
//! the keys of one group of `recalibrate::GROUPS` (radius or braid angle; end factor,
//! initial contraction or rest length).

#[path = "support/testrig.rs"]
mod testrig;

use std::path::PathBuf;

use host_sim::diagnose::{diagnose, DiagnoseOptions, Diagnosis, Verdict};
use host_sim::fit::fit_percent;
use host_sim::io::recording::Channel;
use host_sim::sim::{simulate, SolverOptions};
use host_sim::{Plant, PlantConfig, Recording};
use testrig::{case, Case, Expected, RigPhysics, KINDS};

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

// ---------------------------------------------------------------------------------------
// The evidence base (`testrig::CASES`): catalogue effects in forms unlike their candidates',
// mis-set keys, nominal data on several time bases, out-of-catalogue forms. Each case names
// its category and expected answer in the table, so the rates below are computed from the
// table alone.
//
// - Sensitivity (catalogue forms): `explained`, the first named item one of the expected
//   ones, and the CHECK fit of the departing channel (the channel the nominal model fits
//   worst on CHECK) lifted by at least half of its gap to 100 %.
// - Honesty: a mis-set key recalibrated (named first, `explained`); nominal data
//   `nothing_missing` (pure noise: nothing named); an out-of-catalogue form `unexplained`
//   with nothing named.
// A refused input (an error from `diagnose`) fails its case; the error is printed.
//
// `evidence_full_matrix` (ignored; every case on the tuning and the held-out seeds):
//   cargo test --release -p host-sim --test diagnose_independent -- --ignored --nocapture evidence_full_matrix
// `EVIDENCE_CASES=name,name` narrows the ignored matrices to those cases, and
// `EVIDENCE_SEEDS=11` runs them on those seeds only (printed as the tuning set).
// `discovery_matrix` (ignored; the out-of-catalogue cases only), `evidence_reduced_matrix`
// (CI: the cases marked `reduced`, one held-out seed). Each case prints a table row and a
// line `EVIDENCE {json}` for scripts.
// ---------------------------------------------------------------------------------------

use host_sim::diagnose::candidates::catalogue;
use host_sim::diagnose::recalibrate;
use testrig::{
    case_spec, evidence_case, CaseSpec, Category, EvidenceCase, Expect, TimeBase, CASES,
    CASE_TABLE_HEADER,
};

/// The result of one evidence case.
struct EvOutcome {
    pass: bool,
    category: Category,
}

/// Named items in the order the selection accepted them (effects and recalibrated keys).
fn named_in_order(d: &Diagnosis) -> Vec<String> {
    let named: Vec<String> = d
        .effects
        .iter()
        .map(|e| e.id.clone())
        .chain(d.recalibrated.iter().map(|r| r.key.clone()))
        .collect();
    let mut accepted: Vec<(usize, String)> = d
        .candidates
        .iter()
        .filter(|s| s.accepted && named.contains(&s.id))
        .map(|s| (s.round, s.id.clone()))
        .collect();
    accepted.sort_by_key(|(r, _)| *r);
    let mut order: Vec<String> = Vec::new();
    for id in accepted.into_iter().map(|(_, id)| id).chain(named) {
        if !order.contains(&id) {
            order.push(id);
        }
    }
    order
}

fn evidence_run(c: &EvidenceCase) -> EvOutcome {
    let t0 = std::time::Instant::now();
    let d = diagnose(
        &nominal(),
        &c.train,
        Some(&c.check),
        &DiagnoseOptions::default(),
        &|_, _, _| {},
    );
    let secs = t0.elapsed().as_secs_f64();
    let spec = c.spec;
    let (pass, verdict, named, depart, why) = match &d {
        Err(e) => (
            false,
            "error".to_string(),
            Vec::new(),
            None,
            format!("refused: {e}"),
        ),
        Ok(d) => {
            let named = named_in_order(d);
            // The departing channel: the one the nominal model fits worst on CHECK.
            let depart = d.check_before.as_ref().and_then(|b| {
                b.iter()
                    .min_by(|x, y| x.1.total_cmp(y.1))
                    .map(|(ch, before)| {
                        let after = d
                            .check_after
                            .as_ref()
                            .and_then(|a| a.get(ch).copied())
                            .unwrap_or(f64::NAN);
                        (*ch, *before, after)
                    })
            });
            let lifted = depart.is_some_and(|(_, b, a)| a - b >= 0.5 * (100.0 - b));
            let first_ok = |ids: &[&str]| named.first().is_some_and(|f| ids.contains(&f.as_str()));
            let (pass, why) = match spec.expect {
                Expect::First(ids) | Expect::FirstWith(ids, _) => {
                    let with: &[&str] = match spec.expect {
                        Expect::FirstWith(_, with) => with,
                        _ => &[],
                    };
                    let all_named = with.iter().all(|w| named.iter().any(|n| n == w));
                    // A graded answer: explained, or partly explained with the right items.
                    let explained = d.verdict.names_items();
                    let need_lift = spec.category.is_sensitivity();
                    let pass = explained && first_ok(ids) && all_named && (!need_lift || lifted);
                    let why = if pass {
                        String::new()
                    } else if !explained {
                        "not explained".into()
                    } else if !first_ok(ids) {
                        "wrong item first".into()
                    } else if !all_named {
                        format!("{} not named", with.join(", "))
                    } else {
                        "CHECK lift < half the gap".into()
                    };
                    (pass, why)
                }
                Expect::NothingMissing => (d.verdict == Verdict::NothingMissing, String::new()),
                Expect::NothingNamed => {
                    (named.is_empty() && !d.verdict.names_items(), String::new())
                }
                Expect::Unexplained => (
                    d.verdict == Verdict::Unexplained && named.is_empty(),
                    String::new(),
                ),
                Expect::ValvesLoggedLate => {
                    // The shift the hint names, against the case's (whole samples).
                    let truth_ms = (spec.valves_logged_late_s / c.dt_s).round() * c.dt_s * 1e3;
                    let named_ms = d.hints.iter().find_map(|h| {
                        let at = h.find("--shift-valves-ms ")? + "--shift-valves-ms ".len();
                        let num: String = h[at..]
                            .chars()
                            .take_while(|ch| ch.is_ascii_digit() || *ch == '.' || *ch == '-')
                            .collect();
                        num.parse::<f64>().ok()
                    });
                    let ok_value =
                        named_ms.is_some_and(|v| (v - truth_ms).abs() <= c.dt_s * 1e3 + 0.5);
                    let pass = d.verdict == Verdict::NotThisPlant && named.is_empty() && ok_value;
                    let why = match named_ms {
                        None => "no --shift-valves-ms hint".into(),
                        Some(v) if !ok_value => format!("named {v} ms, logged {truth_ms} ms late"),
                        Some(v) => format!("named {v} ms"),
                    };
                    (pass, if pass { String::new() } else { why })
                }
            };
            (pass, d.verdict.as_str().to_string(), named, depart, why)
        }
    };
    let (dch, db, da) = depart.unwrap_or(("-", f64::NAN, f64::NAN));
    println!(
        "| {} | {} | {} | {:.0} | {} | {} | {} | {verdict} | {} | {dch} {db:.1} -> {da:.1} | {secs:.1} | {}{} |",
        spec.name,
        spec.category.as_str(),
        c.seed,
        c.dt_s * 1e3,
        if c.force_channels { "yes" } else { "no" },
        c.sizes,
        spec.expect.describe(),
        if named.is_empty() { "(none)".into() } else { named.join(" > ") },
        if pass { "pass" } else { "FAIL" },
        if why.is_empty() { String::new() } else { format!(" ({why})") },
    );
    let json = serde_json::json!({
        "case": spec.name,
        "category": spec.category.as_str(),
        "slot": spec.slot,
        "expect": spec.expect.describe(),
        "seed": c.seed,
        "check_seed": c.check_seed,
        "dt_s": c.dt_s,
        "forces": c.force_channels,
        "sizes": c.sizes,
        "verdict": verdict,
        "named": named,
        "departing_channel": dch,
        "check_before": db,
        "check_after": da,
        "removed_check": d.as_ref().ok().and_then(|d| d.grade.removed_check_total),
        "removed_heldout": d.as_ref().ok().map(|d| d.grade.removed_heldout_total),
        "graded": d.as_ref().ok().map(|d| d.grade.items.iter().map(|i| format!("{}:{}:{:.3}", i.id, i.accepted, i.share_check.unwrap_or(i.share_heldout))).collect::<Vec<_>>()),
        "residual_x_noise": d.as_ref().ok().map(|d| d.residual_x_noise.0),
        "round1": d.as_ref().ok().map(|d| { let mut r: Vec<_> = d.candidates.iter().filter(|c| c.round == 1).map(|c| (c.explained, c.id.clone())).collect(); r.sort_by(|a, b| b.0.total_cmp(&a.0)); r.into_iter().take(5).map(|(e, id)| format!("{id}:{e:.3}")).collect::<Vec<_>>() }),
        "pass": pass,
        "why": why,
        "seconds": secs,
    });
    println!("EVIDENCE {json}");
    EvOutcome {
        pass,
        category: spec.category,
    }
}

/// Passes and totals of the sensitivity and the honesty cases.
#[derive(Default, Debug)]
struct Rates {
    sensitivity: (usize, usize),
    honesty: (usize, usize),
    /// Passes and totals per category.
    by_category: std::collections::BTreeMap<&'static str, (usize, usize)>,
}

impl Rates {
    fn line(&self) -> String {
        let pct = |(p, t): (usize, usize)| 100.0 * p as f64 / (t.max(1)) as f64;
        let cats: Vec<String> = self
            .by_category
            .iter()
            .map(|(c, (p, t))| format!("{c} {p}/{t}"))
            .collect();
        format!(
            "sensitivity {}/{} ({:.0} %), honesty {}/{} ({:.0} %); {}",
            self.sensitivity.0,
            self.sensitivity.1,
            pct(self.sensitivity),
            self.honesty.0,
            self.honesty.1,
            pct(self.honesty),
            cats.join(", ")
        )
    }
}

fn evidence_matrix(cases: &[&'static CaseSpec], seeds: &[u64]) -> Rates {
    let cfg = nominal();
    let mut rates = Rates::default();
    println!("| case | category | seed | dt ms | forces | drawn sizes | expected | verdict | named (order) | departing CHECK channel, fit % before -> after | s | result |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    for &seed in seeds {
        for spec in cases {
            let o = evidence_run(&evidence_case(&cfg, spec, seed));
            let r = if o.category.is_sensitivity() {
                &mut rates.sensitivity
            } else {
                &mut rates.honesty
            };
            r.0 += usize::from(o.pass);
            r.1 += 1;
            let c = rates.by_category.entry(o.category.as_str()).or_default();
            c.0 += usize::from(o.pass);
            c.1 += 1;
        }
    }
    rates
}

/// The cases `keep` selects, narrowed to the names listed in `EVIDENCE_CASES`
/// (comma-separated) when that variable is set: one case re-run while working on it.
fn all_cases(keep: impl Fn(&CaseSpec) -> bool) -> Vec<&'static CaseSpec> {
    let only = std::env::var("EVIDENCE_CASES").ok();
    CASES
        .iter()
        .filter(|c| keep(c))
        .filter(|c| {
            only.as_ref()
                .is_none_or(|o| o.split(',').any(|n| n.trim() == c.name))
        })
        .collect()
}

/// `seeds`, or when `EVIDENCE_SEEDS` (comma-separated) is set: those seeds for the tuning
/// set (`first`) and none for the held-out one.
fn seeds_or_env(seeds: &[u64], first: bool) -> Vec<u64> {
    match std::env::var("EVIDENCE_SEEDS") {
        Ok(s) if first => s.split(',').filter_map(|v| v.trim().parse().ok()).collect(),
        Ok(_) => Vec::new(),
        Err(_) => seeds.to_vec(),
    }
}

#[test]
fn evidence_table_covers_every_catalogue_effect_and_key() {
    println!("{CASE_TABLE_HEADER}");
    for c in CASES {
        println!("{}", c.tsv());
    }
    let expected_ids: Vec<&str> = CASES
        .iter()
        .filter(|c| c.category == Category::CatalogueForm)
        .flat_map(|c| match c.expect {
            Expect::First(ids) => ids.to_vec(),
            Expect::FirstWith(_, with) => with.to_vec(),
            _ => Vec::new(),
        })
        .collect();
    // Every effect family of the catalogue is the expected answer of some form.
    let family = |id: &str| -> String {
        match id {
            "leakage_muscle1" | "leakage_muscle2" => "leakage".into(),
            "sensor_lag_p1" | "sensor_lag_p2" => "sensor_lag".into(),
            "sensor_gain" => "sensor_offset".into(),
            "heat_transfer" => "polytropic".into(),
            other => other.into(),
        }
    };
    let covered: Vec<String> = expected_ids.iter().map(|id| family(id)).collect();
    for cand in catalogue() {
        let f = family(cand.id());
        assert!(
            covered.contains(&f),
            "catalogue effect {} has no form in the evidence base",
            cand.id()
        );
    }
    for slot in ["polytropic", "thermal_chamber", "sensor", "sensor_lag"] {
        assert!(
            CASES
                .iter()
                .any(|c| c.slot == slot && c.category == Category::CatalogueForm),
            "slot {slot} has no form"
        );
    }
    for k in recalibrate::keys() {
        assert!(
            CASES
                .iter()
                .any(|c| c.category == Category::MisSetKey && c.slot == k.key),
            "key {} has no mis-set case",
            k.key
        );
    }
    let ooc = CASES
        .iter()
        .filter(|c| c.category == Category::OutOfCatalogue)
        .count();
    assert!(ooc >= 8, "{ooc} out-of-catalogue forms");
    for tb in [TimeBase::Jittered, TimeBase::Gappy] {
        assert!(CASES
            .iter()
            .any(|c| c.category == Category::Nominal && c.time_base == tb));
    }
    let mut names: Vec<&str> = CASES.iter().map(|c| c.name).collect();
    names.sort();
    names.dedup();
    assert_eq!(names.len(), CASES.len(), "case names are unique");
}

#[test]
fn every_evidence_case_is_generated_with_its_recording_features() {
    let cfg = nominal();
    for spec in CASES {
        let c = evidence_case(&cfg, spec, HELD_OUT_SEEDS[0]);
        for r in [&c.train, &c.check] {
            assert!(r.t_s.windows(2).all(|w| w[1] > w[0]), "{}", spec.name);
            for ch in Channel::ALL {
                if let Some(y) = r.channel(ch) {
                    assert!(
                        y.iter().all(|v| v.is_finite()),
                        "{} {}",
                        spec.name,
                        ch.name()
                    );
                }
            }
            assert_eq!(r.channel(Channel::F1N).is_some(), c.force_channels);
            let steps: Vec<f64> = r.t_s.windows(2).map(|w| w[1] - w[0]).collect();
            let max_ratio = steps.iter().fold(0.0f64, |m, s| m.max(s / c.dt_s));
            match spec.time_base {
                TimeBase::Uniform => assert!(r.is_uniform(), "{}", spec.name),
                TimeBase::Jittered => {
                    assert!(!r.is_uniform() && max_ratio < 1.41, "{}", spec.name)
                }
                TimeBase::Gappy => {
                    assert!(max_ratio > 1.9 && max_ratio < 11.1, "{}", spec.name);
                    let expected_rows =
                        (if std::ptr::eq(r, &c.train) { 10.0 } else { 8.0 } / c.dt_s).round();
                    assert!(r.t_s.len() as f64 >= 0.95 * expected_rows, "{}", spec.name);
                }
            }
        }
        assert_ne!(c.seed, c.check_seed);
    }
}

#[test]
fn every_evidence_form_departs_from_the_nominal_rig() {
    // The TRAIN recording of each uniform case against the nominal rig's replay of its own
    // valve columns: a form that changes nothing would be no evidence.
    let cfg = nominal();
    let rig = RigPhysics::from_config(&cfg);
    let nominal_fit = |c: &EvidenceCase| -> f64 {
        let y = rig.replay(&c.train.inputs, c.dt_s);
        Channel::ALL
            .iter()
            .filter_map(|&ch| {
                let m = c.train.channel(ch)?;
                let ours: Vec<f64> = y.iter().map(|v| v[ch.index()]).collect();
                Some(fit_percent(m, &ours))
            })
            .fold(f64::INFINITY, f64::min)
    };
    let floor = nominal_fit(&evidence_case(&cfg, case_spec("nominal").unwrap(), 11));
    for spec in CASES {
        if spec.category == Category::Nominal || spec.time_base != TimeBase::Uniform {
            continue;
        }
        let f = nominal_fit(&evidence_case(&cfg, spec, 11));
        println!(
            "{}: worst channel fit {f:.2} % (nominal data {floor:.2} %)",
            spec.name
        );
        assert!(
            f < floor - 0.5,
            "{}: {f:.2} % vs nominal {floor:.2} %",
            spec.name
        );
    }
}

/// Passes of the reduced evidence matrix on the diagnosis as it was when the evidence base
/// was written (cases marked `reduced`, held-out seed 9101: sensitivity 2 of 4 - the
/// second-order angle lag and the dead time with an opening ramp are unexplained -, honesty
/// 7 of 8 - the gappy nominal recording is unexplained). These are floors: later work on
/// the diagnosis raises them as it passes more cases, and never lowers them.
const EVIDENCE_REDUCED_SENSITIVITY_FLOOR: usize = 2;
const EVIDENCE_REDUCED_HONESTY_FLOOR: usize = 7;

#[test]
fn evidence_reduced_matrix() {
    let rates = evidence_matrix(&all_cases(|c| c.reduced), &HELD_OUT_SEEDS[..1]);
    println!("evidence reduced matrix: {}", rates.line());
    assert!(
        rates.sensitivity.0 >= EVIDENCE_REDUCED_SENSITIVITY_FLOOR,
        "{}",
        rates.line()
    );
    assert!(
        rates.honesty.0 >= EVIDENCE_REDUCED_HONESTY_FLOOR,
        "{}",
        rates.line()
    );
}

#[test]
#[ignore = "every evidence case on every seed: minutes in release"]
fn evidence_full_matrix() {
    let cases = all_cases(|_| true);
    let t = evidence_matrix(&cases, &seeds_or_env(&TUNING_SEEDS, true));
    let h = evidence_matrix(&cases, &seeds_or_env(&HELD_OUT_SEEDS, false));
    println!("evidence, tuning seeds {TUNING_SEEDS:?}: {}", t.line());
    println!("evidence, held-out seeds {HELD_OUT_SEEDS:?}: {}", h.line());
    // The rows scripts/bench-evidence.sh writes to docs/figures/evidence.tsv.
    for row in figure_rows(&t, &h) {
        println!("FIGURE\t{row}");
    }
}

/// The rates as figure rows (`key<TAB>figure<TAB>measured<TAB>target<TAB>check`): tuning
/// and held-out apart, the held-out ones against the targets.
fn figure_rows(t: &Rates, h: &Rates) -> Vec<String> {
    let rate =
        |(p, n): (usize, usize)| format!("{p}/{n} ({:.0} %)", 100.0 * p as f64 / n.max(1) as f64);
    let check = |(p, n): (usize, usize), min: f64| {
        if n > 0 && p as f64 >= min * n as f64 {
            "met"
        } else {
            "missed"
        }
    };
    let mut rows = vec![
        format!(
            "sensitivity_tuning\tsensitivity, tuning seeds {TUNING_SEEDS:?}: forms unlike the candidates, right item first (explained or partly explained), CHECK's departing channel lifted by half its gap\t{}\t\t",
            rate(t.sensitivity)
        ),
        format!(
            "sensitivity_heldout\tsensitivity, held-out seeds {HELD_OUT_SEEDS:?}\t{}\t>= 90 %\t{}",
            rate(h.sensitivity),
            check(h.sensitivity, 0.9)
        ),
        format!(
            "honesty_tuning\thonesty, tuning seeds: mis-set keys recalibrated, nominal data nothing missing, pure noise and out-of-catalogue forms nothing named\t{}\t\t",
            rate(t.honesty)
        ),
        format!(
            "honesty_heldout\thonesty, held-out seeds\t{}\t>= 95 %\t{}",
            rate(h.honesty),
            check(h.honesty, 0.95)
        ),
    ];
    for (cat, pn) in &h.by_category {
        rows.push(format!(
            "heldout_{cat}\theld-out seeds, {}\t{}\t\t",
            cat.replace('_', " "),
            rate(*pn)
        ));
    }
    rows
}

/// The data the stand-in rule (`diagnose`'s stage 5b) was checked against: for every
/// catalogue-form and out-of-catalogue case on the seeds of `EVIDENCE_SEEDS` (default: the
/// tuning seeds), the diagnosis's CHECK fit of the departing channel against the fit of the
/// term the discovery keeps on the nominal plant, and each model's CHECK cost (sum over
/// channels of (1 - fit)^2). Run before the rule, it shows what the rule would do; after, the
/// stood-in answers are `unexplained`.
/// `cargo test --release -p host-sim --features test-support --test diagnose_independent -- --ignored --nocapture stand_in_vs_discovery`
#[test]
#[ignore = "prints the CHECK fits of the diagnosis and of the discovered term per case"]
fn stand_in_vs_discovery() {
    use host_sim::diagnose::discover::{discover, DiscoverOptions};
    type Fits = std::collections::BTreeMap<&'static str, f64>;
    let cfg = nominal();
    let cost = |m: Option<&Fits>| -> f64 {
        m.map_or(f64::NAN, |m| {
            m.values().map(|f| (1.0 - f / 100.0).powi(2)).sum()
        })
    };
    println!("STAND-IN\tcase\tcategory\tseed\tverdict\tnamed\tchannel\tnominal %\tdiagnosis %\tterm kept\tterm %\tdiagnosis cost\tterm cost\tterm");
    let cases = all_cases(|c| {
        matches!(
            c.category,
            Category::CatalogueForm | Category::OutOfCatalogue
        )
    });
    for seed in seeds_or_env(&TUNING_SEEDS, true) {
        for spec in &cases {
            let c = evidence_case(&cfg, spec, seed);
            let Ok(d) = diagnose(
                &cfg,
                &c.train,
                Some(&c.check),
                &DiagnoseOptions::default(),
                &|_, _, _| {},
            ) else {
                continue;
            };
            let opts = DiscoverOptions {
                catalogue_share: None,
                ..DiscoverOptions::default()
            };
            let Ok(x) = discover(&cfg, &c.train, Some(&c.check), &opts) else {
                continue;
            };
            let Some((ch, before)) = d
                .check_before
                .as_ref()
                .and_then(|b| b.iter().min_by(|x, y| x.1.total_cmp(y.1)))
                .map(|(c, v)| (*c, *v))
            else {
                continue;
            };
            let at = |m: Option<&Fits>| m.and_then(|m| m.get(ch).copied()).unwrap_or(f64::NAN);
            let term = x.found.as_ref().or(x.best.as_ref());
            println!(
                "STAND-IN\t{}\t{}\t{seed}\t{}\t{}\t{ch}\t{before:.1}\t{:.1}\t{}\t{:.1}\t{:.3e}\t{:.3e}\t{}",
                spec.name,
                spec.category.as_str(),
                d.verdict.as_str(),
                named_in_order(&d).join("+"),
                at(d.check_after.as_ref()),
                x.found.is_some(),
                at(x.check_after.as_ref()),
                cost(d.check_after.as_ref()),
                cost(x.check_after.as_ref()),
                term.map(|f| f.table.formula()).unwrap_or_default()
            );
        }
    }
}

#[test]
#[ignore = "the out-of-catalogue cases on every seed"]
fn discovery_matrix() {
    let cases = all_cases(|c| c.category == Category::OutOfCatalogue);
    let t = evidence_matrix(&cases, &seeds_or_env(&TUNING_SEEDS, true));
    let h = evidence_matrix(&cases, &seeds_or_env(&HELD_OUT_SEEDS, false));
    println!("discovery, tuning seeds {TUNING_SEEDS:?}: {}", t.line());
    println!("discovery, held-out seeds {HELD_OUT_SEEDS:?}: {}", h.line());
}

/// The sensitivity regressions the pool's per-valve and per-muscle keys are screened by
/// (`diagnose::key_screen`), per case and seed: the numbers its thresholds were chosen on
/// (tuning seeds only: `EVIDENCE_SEEDS=11,12`).
#[test]
#[ignore = "prints the key screening's R^2 of the cases selected by EVIDENCE_CASES"]
fn key_screen_values() {
    use host_sim::diagnose::key_screen::{key_evidence, retain_indicated};
    use host_sim::diagnose::{gather_evidence, selection::candidate_pool};
    let cfg = nominal();
    let keys = recalibrate::keys();
    for seed in seeds_or_env(&TUNING_SEEDS, true) {
        for spec in all_cases(|c| c.category == Category::MisSetKey) {
            let c = evidence_case(&cfg, spec, seed);
            let train = if c.train.is_uniform() {
                c.train.clone()
            } else {
                c.train.to_uniform()
            };
            let opts = DiagnoseOptions::default();
            let Ok(g) = gather_evidence(&cfg, &train, &opts) else {
                continue;
            };
            let r2 = |k: &str| {
                keys.iter()
                    .find(|x| x.key == k)
                    .and_then(|x| key_evidence(&cfg, &g.evidence, x))
                    .map_or(f64::NAN, |e| e.r2)
            };
            let row: Vec<String> = keys
                .iter()
                .map(|k| format!("{} {:.3}", k.key, r2(k.key)))
                .collect();
            let kept: Vec<String> = retain_indicated(candidate_pool(&cfg), &cfg, &g.evidence)
                .iter()
                .map(|c| c.id().to_string())
                .filter(|id| recalibrate::is_part_key(id))
                .collect();
            println!(
                "KEYSCREEN {} seed {seed} ({}): kept {:?}\n  {}",
                spec.name,
                c.sizes,
                kept,
                row.join(", ")
            );
        }
    }
}
