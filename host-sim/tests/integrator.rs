//! The integration strategy: spanning runs of identical inputs with dense output agrees with
//! restarting at every sample (the closed-loop pattern), and tolerances converge.

mod common;
use common::*;

use host_sim::sim::{simulate, Integrator, SolverOptions};
use host_sim::{Plant, Recording};

fn loaded() -> (Plant, Recording) {
    let rec = Recording::read(fixture("pulses_loaded.csv")).unwrap();
    let plant = Plant::load(fixture("reference-1dof-loaded.toml")).unwrap();
    (plant, rec)
}

fn max_rel_diff(a: &[[f64; 4]], b: &[[f64; 4]]) -> [f64; 4] {
    let mut scale = [0f64; 4];
    for x in a {
        for i in 0..4 {
            scale[i] = scale[i].max(x[i].abs());
        }
    }
    let mut d = [0f64; 4];
    for (x, y) in a.iter().zip(b) {
        for i in 0..4 {
            d[i] = d[i].max((x[i] - y[i]).abs() / scale[i]);
        }
    }
    d
}

#[test]
fn segment_spanning_matches_per_sample_restarts() {
    let (plant, rec) = loaded();
    let dt = rec.sample_period_s();
    let opts = SolverOptions::default();
    let spanned: Vec<[f64; 4]> = simulate(&plant, &rec.inputs, dt, &opts)
        .unwrap()
        .states
        .iter()
        .map(|x| x.to_array())
        .collect();
    let mut integ = Integrator::new(&plant, plant.initial_state(), opts);
    let mut stepped = Vec::with_capacity(rec.len());
    for u in &rec.inputs {
        stepped.push(integ.state().to_array());
        integ.advance(*u, dt).unwrap();
    }
    let d = max_rel_diff(&spanned, &stepped);
    println!("max relative difference (angle, velocity, p1, p2): {d:?}");
    assert!(d.iter().all(|v| *v < 1e-3), "{d:?}");
}

#[test]
fn tightening_the_tolerance_changes_the_result_by_little() {
    let (plant, rec) = loaded();
    let dt = rec.sample_period_s();
    let run = |rtol: f64| -> Vec<[f64; 4]> {
        let opts = SolverOptions {
            rtol,
            atol: rtol,
            ..SolverOptions::default()
        };
        simulate(&plant, &rec.inputs, dt, &opts)
            .unwrap()
            .states
            .iter()
            .map(|x| x.to_array())
            .collect()
    };
    let default = run(SolverOptions::default().rtol);
    let tight = run(1e-10);
    let d = max_rel_diff(&tight, &default);
    println!("default vs rtol 1e-10, max relative difference: {d:?}");
    assert!(d.iter().all(|v| *v < 1e-3), "{d:?}");
}

/// The allocation-free single step per sample (closed-loop pattern) takes the step Dopri5
/// takes: per-sample restarts with and without it agree to rounding, on a recording whose
/// inputs switch often (first-same-as-last reuse and its invalidation on an input change are
/// both exercised), and it does the same work or less.
#[test]
fn single_step_path_matches_dopri5_per_sample() {
    // The valve commands the firmware issued on the random set-point scenario.
    let plant = Plant::load(fixture("reference-1dof.toml")).unwrap();
    let scenario =
        host_sim::control::closed_loop::Scenario::load(root().join("scenarios/random.toml"))
            .unwrap();
    let run = host_sim::control::closed_loop::run(&plant, &scenario).unwrap();
    let inputs: Vec<_> = run.rows.iter().map(|r| r.inputs).collect();
    let dt = run.dt_s;
    // The closed loop's tolerances (closed_loop::run_with).
    let opts = SolverOptions {
        rtol: 1e-6,
        atol: 1e-6,
        ..SolverOptions::default()
    };
    let mut fast = Integrator::new(&plant, plant.initial_state(), opts);
    let mut slow = Integrator::new(&plant, plant.initial_state(), opts).without_single_step_path();
    let mut a = Vec::new();
    let mut b = Vec::new();
    let mut switches = 0;
    for (k, u) in inputs.iter().enumerate() {
        if k > 0 && *u != inputs[k - 1] {
            switches += 1;
        }
        fast.advance(*u, dt).unwrap();
        slow.advance(*u, dt).unwrap();
        a.push(fast.state().to_array());
        b.push(slow.state().to_array());
    }
    assert!(
        switches > 50,
        "fixture switches its inputs {switches} times"
    );
    let d = max_rel_diff(&a, &b);
    assert!(d.iter().all(|v| *v < 1e-9), "max relative difference {d:?}");
    let (sf, ss) = (fast.stats(), slow.stats());
    assert_eq!(
        sf.accepted_steps, ss.accepted_steps,
        "fast {sf:?} vs Dopri5 {ss:?}"
    );
    assert!(
        sf.rhs_evaluations < ss.rhs_evaluations,
        "fast {sf:?} vs Dopri5 {ss:?}"
    );
}
