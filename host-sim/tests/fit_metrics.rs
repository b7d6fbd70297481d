//! Fit metrics (PLANT.md / Cakurda et al. eqs. 23-24) and recording comparison.

use host_sim::fit::{compare, fit_percent, mae, mse, FitError};
use host_sim::io::recording::Channel;
use host_sim::{Recording, ValveInputs};

fn rec(t: &[f64], angle: &[f64], p1: Option<&[f64]>) -> Recording {
    let mut r = Recording {
        t_s: t.to_vec(),
        inputs: vec![ValveInputs::CLOSED; t.len()],
        ..Default::default()
    };
    r.set_channel(Channel::AngleDeg, angle.to_vec());
    if let Some(p) = p1 {
        r.set_channel(Channel::P1Kpa, p.to_vec());
    }
    r
}

#[test]
fn nrmse_fit_matches_hand_computation() {
    let y = [1.0, 2.0, 3.0, 4.0];
    let y_hat = [1.1, 1.9, 3.2, 3.8];
    // ||e|| = sqrt(0.01+0.01+0.04+0.04) = sqrt(0.1); ||y - 2.5|| = sqrt(5)
    let expected = 100.0 * (1.0 - (0.1f64).sqrt() / 5f64.sqrt());
    assert!((fit_percent(&y, &y_hat) - expected).abs() < 1e-12);
    assert!((mae(&y, &y_hat) - 0.15).abs() < 1e-12);
    assert!((mse(&y, &y_hat) - 0.025).abs() < 1e-12);
}

#[test]
fn fit_is_100_for_identical_and_0_for_the_mean() {
    let y = [3.0, -1.0, 2.0];
    assert_eq!(fit_percent(&y, &y), 100.0);
    let m = [4.0 / 3.0; 3];
    assert!(fit_percent(&y, &m).abs() < 1e-12);
    assert!(fit_percent(&y, &[-3.0, 1.0, -2.0]) < 0.0);
}

#[test]
fn compare_uses_channels_present_in_both() {
    let t = [0.0, 0.1, 0.2];
    let a = rec(&t, &[0.0, 1.0, 2.0], Some(&[5.0, 6.0, 7.0]));
    let b = rec(&t, &[0.0, 1.0, 2.5], None);
    let fits = compare(&a, &b).unwrap();
    assert_eq!(fits.len(), 1);
    assert_eq!(fits[0].channel, Channel::AngleDeg);
    assert!((fits[0].mae - 0.5 / 3.0).abs() < 1e-12);
}

#[test]
fn compare_rejects_different_lengths_and_times() {
    let a = rec(&[0.0, 0.1, 0.2], &[0.0, 1.0, 2.0], None);
    let b = rec(&[0.0, 0.1], &[0.0, 1.0], None);
    assert!(matches!(compare(&a, &b), Err(FitError::Length(3, 2))));
    let c = rec(&[1.0, 1.1, 1.2], &[0.0, 1.0, 2.0], None);
    assert!(matches!(
        compare(&a, &c),
        Err(FitError::Time { index: 0, .. })
    ));
}
