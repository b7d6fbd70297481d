//! Fit metrics (PLANT.md / Cakurda et al. eqs. 23-24) and recording comparison.

use host_sim::fit::{fit_percent, mae, mse};
use host_sim::io::compare::{compare, FitError};
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

/// Rows of a recording file written with `format!` (not the crate's writer).
fn write_file(path: &std::path::Path, header: &str, rows: impl Iterator<Item = String>) {
    let mut s = format!("# source = fit_metrics test\n{header}\n");
    for r in rows {
        s += &r;
        s += "\n";
    }
    std::fs::write(path, s).unwrap();
}

#[test]
fn streamed_file_comparison_equals_compare_to_the_bit() {
    use host_sim::io::compare::compare_files;
    let dir = tempfile::tempdir().unwrap();
    let (a, b, c) = (
        dir.path().join("a.csv"),
        dir.path().join("b.csv"),
        dir.path().join("c.csv"),
    );
    let n = 9_000;
    let wave = |k: usize, f: f64| (k as f64 * f).sin() * 40.0 + (k % 7) as f64 * 0.37;
    write_file(
        &a,
        "t_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg,p1_kpa,f2_n",
        (0..n).map(|k| {
            format!(
                "{:.3},0,1,0,0.5,{:.6},{:.4},{:.2}",
                k as f64 * 1e-3,
                wave(k, 0.01),
                wave(k, 0.003) + 300.0,
                wave(k, 0.02)
            )
        }),
    );
    // Other column order, p1 missing, p2 extra, the time within the tolerance.
    write_file(
        &b,
        "p2_kpa,angle_deg,t_s,u_in1,u_ex1,u_in2,u_ex2,f2_n",
        (0..n).map(|k| {
            format!(
                "1,{:.6},{:.6},0,0,0,0,{:.3}",
                wave(k, 0.0101),
                k as f64 * 1e-3 + 2e-6,
                wave(k, 0.019) * 1.01
            )
        }),
    );
    let streamed = compare_files(&a, &b).expect("streamed");
    let whole = compare(&Recording::read(&a).unwrap(), &Recording::read(&b).unwrap()).unwrap();
    assert_eq!(streamed.len(), 2);
    for (s, w) in streamed.iter().zip(&whole) {
        assert_eq!(s.channel, w.channel);
        assert_eq!(s.samples, w.samples);
        for (x, y) in [
            (s.fit_percent, w.fit_percent),
            (s.mae, w.mae),
            (s.mse, w.mse),
        ] {
            assert_eq!(x.to_bits(), y.to_bits(), "{:?}", s.channel);
        }
    }
    assert_eq!(streamed.len(), whole.len());

    // Different lengths, then different times: left to `compare`, which reports them.
    write_file(
        &c,
        "t_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg",
        (0..n - 1).map(|k| format!("{:.3},0,0,0,0,1", k as f64 * 1e-3)),
    );
    assert!(compare_files(&a, &c).is_none());
    write_file(
        &c,
        "t_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg",
        (0..n).map(|k| format!("{:.3},0,0,0,0,1", 0.5 + k as f64 * 1e-3)),
    );
    assert!(compare_files(&a, &c).is_none());
    assert!(matches!(
        compare(&Recording::read(&a).unwrap(), &Recording::read(&c).unwrap()),
        Err(FitError::Time { .. })
    ));
    // An error in a file: left to `Recording::read`.
    write_file(
        &c,
        "t_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg",
        (0..n).map(|k| {
            format!(
                "{:.3},0,0,0,0,{}",
                k as f64 * 1e-3,
                if k == 8000 { "x" } else { "1" }
            )
        }),
    );
    assert!(compare_files(&a, &c).is_none());
    assert!(Recording::read(&c).is_err());
}
