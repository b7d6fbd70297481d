//! The Elman residual baseline on simulated rig data: deterministic for a seed (and for any
//! thread count), reduces the residual of a concealed effect on the data it was trained on,
//! rejects bad input.

mod common;
use common::*;

use host_sim::diagnose::baseline::{train, BaselineError, ElmanOptions};
use host_sim::sim::{simulate, SolverOptions};
use host_sim::{Measurement, Plant, ValveInputs};

fn channels(m: &[Measurement]) -> [Option<Vec<f64>>; 5] {
    std::array::from_fn(|c| Some(m.iter().map(|x| x.to_array()[c]).collect()))
}

fn run(p: &Plant, u: &[ValveInputs]) -> Vec<Measurement> {
    let s = simulate(p, u, 1e-3, &SolverOptions::default()).unwrap();
    p.measure_series(&s.states, 1e-3)
}

fn quick() -> ElmanOptions {
    ElmanOptions {
        hidden: 8,
        max_epochs: 40,
        patience: 10,
        ..Default::default()
    }
}

#[test]
fn training_is_deterministic_for_a_seed_and_thread_count_independent() {
    let u = pulse_inputs(3000, 300);
    let nominal = run(&plant_with(""), &u);
    let real = run(&plant_with("[effects.polytropic]\nexponent = 1.3\n"), &u);
    let measured = channels(&real);
    let a = train(&u, &nominal, &measured, &quick()).unwrap();
    let b = train(&u, &nominal, &measured, &quick()).unwrap();
    assert_eq!(a, b);
    let one_thread = train(
        &u,
        &nominal,
        &measured,
        &ElmanOptions {
            threads: 1,
            ..quick()
        },
    )
    .unwrap();
    assert_eq!(a, one_thread);
    assert_eq!(
        a.predict(&u, &nominal).unwrap(),
        b.predict(&u, &nominal).unwrap()
    );
    let other = train(
        &u,
        &nominal,
        &measured,
        &ElmanOptions { seed: 2, ..quick() },
    )
    .unwrap();
    assert_ne!(a, other);
}

#[test]
fn learns_the_residual_of_a_concealed_supply_drop_on_its_training_data() {
    let u = pulse_inputs(6000, 250);
    let nominal = run(&plant_with(""), &u);
    let real = run(
        &plant_with("[effects.supply_drop]\nmodel = \"static\"\nresistance_pa_s_per_m3 = 1.5e7\n"),
        &u,
    );
    let mut measured = channels(&real);
    measured[3] = None; // no force sensors on this rig
    measured[4] = None;
    let model = train(
        &u,
        &nominal,
        &measured,
        &ElmanOptions {
            max_epochs: 80,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(model.channels.len(), 3);
    let corrected = model.predict(&u, &nominal).unwrap();
    assert!(corrected[3].is_none() && corrected[4].is_none());
    for rep in model.reports() {
        // Early stopping keeps a network at least as good as the start on the held-out part.
        assert!(rep.best_epoch >= 1, "{rep:?}");
        assert!(
            rep.train_mse < 0.5 * rep.train_mse_nominal,
            "{:?}: {} vs nominal {}",
            rep.channel,
            rep.train_mse,
            rep.train_mse_nominal
        );
    }
}

#[test]
fn bad_input_is_an_error() {
    let u = pulse_inputs(500, 50);
    let nominal = run(&plant_with(""), &u);
    let mut measured = channels(&nominal);
    assert!(matches!(
        train(&u[..400], &nominal, &measured, &quick()),
        Err(BaselineError::Length { .. })
    ));
    measured[1].as_mut().unwrap()[17] = f64::NAN;
    assert_eq!(
        train(&u, &nominal, &measured, &quick()).unwrap_err(),
        BaselineError::NonFinite {
            what: "p1_kpa".into(),
            index: 17
        }
    );
    let none: [Option<Vec<f64>>; 5] = Default::default();
    assert_eq!(
        train(&u, &nominal, &none, &quick()).unwrap_err(),
        BaselineError::NoChannel
    );
    assert!(matches!(
        train(
            &u[..10],
            &nominal[..10],
            &channels(&nominal[..10]),
            &quick()
        ),
        Err(BaselineError::TooShort { .. })
    ));
    let model = train(&u, &nominal, &channels(&nominal), &quick()).unwrap();
    assert!(matches!(
        model.predict(&u, &nominal[..3]),
        Err(BaselineError::Length { .. })
    ));
}
