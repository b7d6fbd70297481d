//! Closed-loop speed: the firmware's control tick (the MCU code, natively) in the loop with
//! the reference plant on the step, sine and random scenarios of `scenarios/`.
//!
//! Timed: the whole run (fake sensors with noise and quantisation, the firmware tick, the
//! valve driver, the plant integration over each 1 ms tick). Not timed: file reading.
//! Simulated seconds per wall second = scenario duration / time per iteration.
//! Run: `cargo bench -p host-sim --bench closed_loop`

use std::hint::black_box;
use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion};
use host_sim::control::closed_loop::{run, Scenario};
use host_sim::Plant;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn closed_loop(c: &mut Criterion) {
    let mut group = c.benchmark_group("closed_loop");
    group.sample_size(20);
    let plant = Plant::load(root().join("host-sim/plants/reference-1dof.toml"))
        .unwrap_or_else(|e| panic!("{e}"));
    for name in ["step", "sine", "random"] {
        let scenario = Scenario::load(root().join(format!("scenarios/{name}.toml")))
            .unwrap_or_else(|e| panic!("{e}"));
        let r = run(&plant, &scenario).unwrap_or_else(|e| panic!("{e}"));
        let st = r.sim_stats;
        eprintln!(
            "{name}: {:.1} s simulated, {} ticks, {:.2} accepted steps / tick, {:.2} rhs evaluations / tick, {} rejected",
            scenario.scenario.duration_s,
            r.rows.len(),
            st.accepted_steps as f64 / r.rows.len() as f64,
            st.rhs_evaluations as f64 / r.rows.len() as f64,
            st.rejected_steps
        );
        group.bench_function(format!("{name}/{}s", scenario.scenario.duration_s), |b| {
            b.iter(|| black_box(run(&plant, black_box(&scenario)).unwrap().rows.len()))
        });
    }
    group.finish();
}

criterion_group!(benches, closed_loop);
criterion_main!(benches);
