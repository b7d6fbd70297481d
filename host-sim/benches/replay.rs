//! Open-loop replay speed of the conformance fixtures (speed bar: the 20 s `pulses_nominal`
//! replay, 20,000 samples, in <= 10 ms, i.e. >= 2,000x real time on one core).
//!
//! Timed: integration of all samples plus the measured channels; not timed: file reading.
//! Run: `cargo bench -p host-sim --bench replay`

use std::hint::black_box;
use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion};
use host_sim::sim::{simulate, Integrator, SolverOptions};
use host_sim::{Plant, Recording};

/// The in-repo copies of the shared fixtures and plants (`tests/fixtures/README.md`).
fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures")
}

fn replay(c: &mut Criterion) {
    let mut group = c.benchmark_group("replay");
    group.sample_size(50);
    for name in ["pulses_nominal", "pulses_loaded", "pwm_nominal"] {
        let rec = Recording::read(fixtures().join(format!("{name}.csv")))
            .unwrap_or_else(|e| panic!("{e}"));
        let plant = Plant::load(fixtures().join(rec.meta("plant").unwrap()))
            .unwrap_or_else(|e| panic!("{e}"));
        let dt = rec.sample_period_s();
        for (label, rtol) in [("rtol1e-6", 1e-6), ("rtol1e-8", 1e-8)] {
            let opts = SolverOptions {
                rtol,
                atol: rtol,
                ..SolverOptions::default()
            };
            group.bench_function(format!("{name}/{label}"), |b| {
                b.iter(|| {
                    let sim = simulate(&plant, black_box(&rec.inputs), dt, &opts).unwrap();
                    let mut acc = 0.0;
                    for x in &sim.states {
                        acc += plant.measure(x).angle_deg;
                    }
                    black_box(acc)
                })
            });
        }
    }
    group.finish();
}

/// Closed-loop pattern: one integrator restart per 1 ms tick (no segment spanning).
fn per_tick(c: &mut Criterion) {
    let mut group = c.benchmark_group("per_tick");
    group.sample_size(20);
    let rec = Recording::read(fixtures().join("pulses_nominal.csv")).unwrap();
    let plant = Plant::load(fixtures().join("reference-1dof.toml")).unwrap();
    let dt = rec.sample_period_s();
    group.bench_function("pulses_nominal/rtol1e-6", |b| {
        b.iter(|| {
            let mut integ =
                Integrator::new(&plant, plant.initial_state(), SolverOptions::default());
            for u in &rec.inputs {
                integ.advance(*u, dt).unwrap();
            }
            black_box(integ.state())
        })
    });
    group.finish();
}

criterion_group!(benches, replay, per_tick);
criterion_main!(benches);
