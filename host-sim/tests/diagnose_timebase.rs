//! The diagnosis on every logger's time base, plant in the loop: the simulator's nominal
//! plant replayed at its own stamps (open-loop valve pulses, sensor noise), logged with
//! +-20 % jitter, with dropped rows, or with the valve columns written late.
//!
//! cargo test --release -p host-sim --test diagnose_timebase

use host_sim::diagnose::{diagnose, DiagnoseOptions, Diagnosis, Verdict};
use host_sim::io::recording::Channel;
use host_sim::io::timebase::{shift_valves, MeasuredRows};
use host_sim::plant::ValveInputs;
use host_sim::sim::{simulate_stamped, SolverOptions};
use host_sim::{Plant, PlantConfig, Recording};
use rand::{rngs::StdRng, Rng, SeedableRng};
use rand_distr::StandardNormal;

fn nominal() -> PlantConfig {
    PlantConfig::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/reference-1dof.toml"
    ))
    .unwrap()
}

/// How a run is logged.
struct Log {
    /// Stamps off the grid by up to this share of the period.
    jitter: f64,
    /// Rows dropped: at most this share, in gaps of 1-9 rows.
    dropped: f64,
    /// Valve columns written this late [s] (whole samples).
    valves_late_s: f64,
    /// A real valve dead time of the plant [s].
    dead_time_s: f64,
}

/// 10 s of valve pulses on the nominal plant at 2 ms, simulated at the logged stamps,
/// pressures with 0.5 kPa of noise, the angle quantised to 0.01 deg.
fn run(seed: u64, log: &Log) -> Recording {
    let mut cfg = nominal();
    if log.dead_time_s > 0.0 {
        cfg.effects.valve_dead_time = Some(host_sim::plant::effects::ValveDeadTime {
            enabled: true,
            delay_s: log.dead_time_s,
        });
    }
    let plant = Plant::from_config(&cfg);
    let mut rng = StdRng::seed_from_u64(seed);
    let dt = 2e-3;
    let n = 5000;
    let t_s: Vec<f64> = (0..n)
        .map(|k| {
            k as f64 * dt
                + if k > 0 {
                    rng.random_range(-log.jitter..=log.jitter) * dt
                } else {
                    0.0
                }
        })
        .collect();
    let mut inputs = Vec::with_capacity(n);
    let (mut u, mut until) = (ValveInputs::CLOSED, 0.0);
    for &t in &t_s {
        if t >= until {
            let m: f64 = rng.random_range(-0.6..0.6);
            u = ValveInputs::antagonistic(m);
            until = t + rng.random_range(0.08..0.4);
        }
        inputs.push(u);
    }
    let sim = simulate_stamped(&plant, &t_s, &inputs, &SolverOptions::default(), |_| {}).unwrap();
    let mut out: [Vec<f64>; 3] = Default::default();
    for x in &sim.states {
        let m = plant.measure(x);
        out[0].push((Channel::AngleDeg.of(&m) * 100.0).round() / 100.0);
        out[1].push(Channel::P1Kpa.of(&m) + 0.5 * rng.sample::<f64, _>(StandardNormal));
        out[2].push(Channel::P2Kpa.of(&m) + 0.5 * rng.sample::<f64, _>(StandardNormal));
    }
    let late = (log.valves_late_s / dt).round() as usize;
    let logged: Vec<ValveInputs> = (0..n)
        .map(|k| {
            if k >= late {
                inputs[k - late]
            } else {
                ValveInputs::CLOSED
            }
        })
        .collect();
    let mut keep = vec![true; n];
    let budget = (log.dropped * n as f64) as usize;
    let mut dropped = 0;
    while dropped + 9 <= budget {
        let len = rng.random_range(1..=9);
        let at = rng.random_range(1..n - 11);
        if keep[at - 1..at + len + 1].iter().all(|k| *k) {
            keep[at..at + len].iter_mut().for_each(|k| *k = false);
            dropped += len;
        }
    }
    let pick =
        |v: &[f64]| -> Vec<f64> { v.iter().zip(&keep).filter(|p| *p.1).map(|p| *p.0).collect() };
    let mut rec = Recording {
        metadata: vec![("sample_period_s".into(), format!("{dt}"))],
        t_s: pick(&t_s),
        inputs: logged
            .iter()
            .zip(&keep)
            .filter(|p| *p.1)
            .map(|p| *p.0)
            .collect(),
        outputs: Default::default(),
        mass_flow_kg_s: None,
    };
    rec.set_channel(Channel::AngleDeg, pick(&out[0]));
    rec.set_channel(Channel::P1Kpa, pick(&out[1]));
    rec.set_channel(Channel::P2Kpa, pick(&out[2]));
    rec
}

fn diag(train: &Recording, check: &Recording) -> Diagnosis {
    diagnose(
        &nominal(),
        train,
        Some(check),
        &DiagnoseOptions::default(),
        &|_, _, _| {},
    )
    .unwrap()
}

/// The verdict is `nothing_missing`; else the fits, the residual per noise and the hints.
fn assert_nothing_missing(d: &Diagnosis) {
    assert_eq!(
        d.verdict,
        Verdict::NothingMissing,
        "{:?} {:?} {:?}",
        d.fit_before,
        d.residual_x_noise,
        d.hints
    );
}

const PLAIN: Log = Log {
    jitter: 0.0,
    dropped: 0.0,
    valves_late_s: 0.0,
    dead_time_s: 0.0,
};

/// Stamps jittered by up to +-20 % of the period: nothing is missing.
#[test]
fn nominal_data_jittered_by_20_percent_misses_nothing() {
    let log = Log {
        jitter: 0.2,
        ..PLAIN
    };
    let (train, check) = (run(1, &log), run(2, &log));
    assert!(!train.is_uniform());
    let d = diag(&train, &check);
    assert_nothing_missing(&d);
}

/// 5 % of the rows dropped in gaps of 1-9 rows (and +-20 % jitter): the gaps are filled on
/// the grid and left out of the fits; nothing is missing.
#[test]
fn nominal_data_with_dropped_rows_misses_nothing() {
    let log = Log {
        jitter: 0.2,
        dropped: 0.05,
        ..PLAIN
    };
    let (train, check) = (run(3, &log), run(4, &log));
    let u = train.to_uniform();
    assert!(u.len() > train.len() && MeasuredRows::of(&u).count(0..u.len()) == train.len());
    let d = diag(&train, &check);
    assert_nothing_missing(&d);
}

/// Valve columns logged 50 ms late: named as a logging misalignment with its value and the
/// option that fixes it (not a dead time, nothing named); with that option applied the same
/// recording misses nothing.
#[test]
fn valves_logged_late_are_named_with_the_shift_that_fixes_them() {
    let log = Log {
        valves_late_s: 0.05,
        ..PLAIN
    };
    let (train, check) = (run(5, &log), run(6, &log));
    let d = diag(&train, &check);
    assert_eq!(d.verdict, Verdict::NotThisPlant);
    assert!(d.effects.is_empty() && d.recalibrated.is_empty());
    let hint = d
        .hints
        .iter()
        .find(|h| h.contains("--shift-valves-ms"))
        .expect("a shift hint");
    assert!(
        hint.contains("--shift-valves-ms 50") && hint.contains("negative dead time"),
        "{hint}"
    );
    let fixed = |r: &Recording| shift_valves(r, 0.05).unwrap();
    let d = diag(&fixed(&train), &fixed(&check));
    assert_nothing_missing(&d);
}

/// A real valve dead time of 80 ms (the sensors answer late) is no logging offset: the
/// search for valve columns logged late finds nothing, and the diagnosis names the dead
/// time, found beyond the 50 ms its search once stopped at.
#[test]
fn a_real_80_ms_dead_time_is_found_and_not_taken_for_a_logging_offset() {
    let log = Log {
        dead_time_s: 0.08,
        ..PLAIN
    };
    let (train, check) = (run(7, &log), run(8, &log));
    let found =
        host_sim::diagnose::valve_offset::find_in(&nominal(), &train, &SolverOptions::default());
    assert!(found.is_none(), "{found:?}");
    let d = diag(&train, &check);
    assert_eq!(d.verdict, Verdict::Explained, "{:?}", d.hints);
    let e = d
        .effects
        .iter()
        .find(|e| e.id == "valve_delay")
        .expect("valve_delay named");
    let delay = e.params.iter().find(|p| p.0 == "delay_s").unwrap().1;
    assert!((delay - 0.08).abs() < 0.004, "{delay}");
}

/// `diagnose --shift-valves-ms`: out of range refused (exit status 2, the range named);
/// the reference fixture with its valve columns moved 20 ms late by the option is named as
/// logged 20 ms late, with the fix (exit status 3).
#[test]
fn the_cli_option_is_validated_and_the_offset_it_makes_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("out.json");
    let run = |ms: &str| {
        std::process::Command::new(env!("CARGO_BIN_EXE_host-sim"))
            .args(["diagnose", "--plant"])
            .arg(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/tests/fixtures/reference-1dof.toml"
            ))
            .arg("--recording")
            .arg(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/tests/fixtures/pulses_nominal.csv"
            ))
            .arg("--json")
            .arg(&json)
            .args(["--shift-valves-ms", ms])
            .output()
            .unwrap()
    };
    let out = run("5000");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("[-1000, 1000] ms"), "{err}");
    let out = run("-20");
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(3), "{text}");
    assert!(
        text.contains("logged 20 ms late") && text.contains("--shift-valves-ms 20"),
        "{text}"
    );
}
