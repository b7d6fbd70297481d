//! Open-loop replay speed of the conformance fixtures (speed bar: the 20 s `pulses_nominal`
//! replay, 20,000 samples, in <= 10 ms, i.e. >= 2,000x real time on one core).
//!
//! Timed: integration of all samples plus the measured channels; not timed: file reading.
//! Run: `cargo bench -p host-sim --bench replay`

use std::hint::black_box;
use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion};
use host_sim::sim::{simulate, SolverOptions};
use host_sim::{Plant, Recording};

fn shared() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared")
}

fn replay(c: &mut Criterion) {
    let mut group = c.benchmark_group("replay");
    group.sample_size(50);
    for name in ["pulses_nominal", "pulses_loaded", "pwm_nominal"] {
        let rec = Recording::read(shared().join(format!("conformance/{name}.csv")))
            .unwrap_or_else(|e| panic!("{e}"));
        let plant = Plant::load(shared().join("plant").join(rec.meta("plant").unwrap()))
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

criterion_group!(benches, replay);
criterion_main!(benches);
