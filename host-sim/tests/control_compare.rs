//! Issue 5 proof, closed loop: on the reference plant with the firmware in the loop, the
//! model-based cascade (identified constants, trajectory feed-forward,
//! `ControllerConfig::reference`) against the tuned PD and PID of `config/pid_tuned.toml` on
//! the step / sine / random suite (seed 004 Table 3: PD 3.61 vs model-based 1.95, 1.85x).
//!
//! What holds and is asserted here (measured figures in README, "Closed loop: cascade vs
//! tuned PD / PID"):
//! - the cascade's suite MSE is at least 2x lower than the tuned PD's (measured 4.8x);
//! - it is lower than the tuned PID's (measured 1.11x): the 2x against the best tuned
//!   PD / PID is NOT reached on the suite MSE. The step and random scenarios are dominated by
//!   the first ~100 ms after each set-point jump, where both laws open the valves fully and
//!   the rise is bounded by the valve flow (both within 4 % of each other there);
//! - on the tracking part of the suite (the sine) the cascade is at least 2x better than both
//!   (measured 19x against the PID);
//! - the stored gains of all three laws are local optima of the suite MSE.
//!
//! `cargo test -p host-sim --test control_compare -- --nocapture` prints the table
//! (`cargo run --release -p host-sim --example compare_control` prints the same).

use std::path::PathBuf;

use host_sim::control_compare::{
    compare, config_for, format_table, pid_tuned_path, score_suite, score_suite_with,
    suite_scenarios, PidTuning,
};
use host_sim::Plant;
use pam_firmware::pid::DpPidGains;
use pam_firmware::tick::ControlLaw;

fn reference_plant() -> Plant {
    let p =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/plant/reference-1dof.toml");
    Plant::load(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

fn tuning() -> PidTuning {
    let p = pid_tuned_path();
    PidTuning::load(&p).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn cascade_beats_tuned_pd_by_2x_and_tuned_pid_on_the_suite_and_both_by_2x_on_the_sine() {
    let plant = reference_plant();
    let t = tuning();
    let rows = compare(&plant, &t).unwrap();
    eprintln!("{}", format_table(&rows));
    for r in &rows {
        for s in &r.score.scenarios {
            assert!(
                s.fault.is_none(),
                "{}: {}: fault {:?}",
                r.controller,
                s.name,
                s.fault
            );
            assert!(s.mse_rad2.is_finite() && s.mse_rad2 > 0.0);
        }
    }
    // The stored gains score what the tuner measured (the file is the tuner's result and the
    // runs are deterministic).
    for (row, stored) in [(&rows[1], &t.pd), (&rows[2], &t.pid)] {
        let rel = (row.score.mse_rad2 - stored.suite_mse_rad2).abs() / stored.suite_mse_rad2;
        assert!(
            rel < 1e-6,
            "{}: measured {:.6e} rad^2, stored {:.6e} rad^2",
            row.controller,
            row.score.mse_rad2,
            stored.suite_mse_rad2
        );
    }
    let (cascade, pd, pid) = (&rows[0].score, &rows[1].score, &rows[2].score);
    assert!(
        pd.mse_rad2 >= 2.0 * cascade.mse_rad2,
        "suite: cascade {:.4e} rad^2 vs tuned PD {:.4e} rad^2: only {:.2}x",
        cascade.mse_rad2,
        pd.mse_rad2,
        pd.mse_rad2 / cascade.mse_rad2
    );
    assert!(
        pid.mse_rad2 > cascade.mse_rad2,
        "suite: cascade {:.4e} rad^2 not below tuned PID {:.4e} rad^2",
        cascade.mse_rad2,
        pid.mse_rad2
    );
    let sine = |s: &host_sim::control_compare::SuiteScore| {
        s.scenarios
            .iter()
            .find(|c| c.name == "sine")
            .expect("sine in the suite")
            .mse_rad2
    };
    for (name, other) in [("PD", pd), ("PID", pid)] {
        assert!(
            sine(other) >= 2.0 * sine(cascade),
            "sine: cascade {:.4e} rad^2 vs tuned {name} {:.4e} rad^2",
            sine(cascade),
            sine(other)
        );
    }
}

/// The cascade's reference position gains are tuned with its feed-forward on: scaling kp, ki
/// or kd by 0.7 or 1.4 does not lower the suite MSE by more than 2 %; switching the
/// feed-forward off makes it worse.
#[test]
fn reference_cascade_gains_are_a_local_optimum_of_the_suite_mse() {
    let plant = reference_plant();
    let sc = suite_scenarios().unwrap();
    let base = config_for(ControlLaw::Cascade, 1000.0);
    let c0 = score_suite_with(&plant, &sc, base).unwrap().mse_rad2;
    for f in [0.7f32, 1.4] {
        for (what, k) in [("kp", 0), ("ki", 1), ("kd", 2)] {
            let mut cfg = base;
            match k {
                0 => cfg.position.kp *= f,
                1 => cfg.position.ki *= f,
                _ => cfg.position.kd *= f,
            }
            let c = score_suite_with(&plant, &sc, cfg).unwrap().mse_rad2;
            eprintln!("cascade {what} x{f}: suite MSE {c:.4e} rad^2 (reference {c0:.4e})");
            assert!(
                c >= 0.98 * c0,
                "cascade with {what} x{f} scores {c:.4e} rad^2 < reference {c0:.4e} rad^2"
            );
        }
    }
    let mut off = base;
    off.feedforward = pam_firmware::feedforward::FeedforwardGains::OFF;
    let c_off = score_suite_with(&plant, &sc, off).unwrap().mse_rad2;
    eprintln!("cascade without feed-forward: suite MSE {c_off:.4e} rad^2 (with {c0:.4e})");
    assert!(c_off > c0);
}

/// The stored PD / PID are tuned: scaling any one gain by 0.7 or 1.4 (or flipping the
/// derivative's set-point weight) does not lower the suite MSE by more than 2 %.
#[test]
fn stored_pd_and_pid_gains_are_a_local_optimum_of_the_suite_mse() {
    let plant = reference_plant();
    let sc = suite_scenarios().unwrap();
    let t = tuning();
    for (name, stored) in [("PD", &t.pd), ("PID", &t.pid)] {
        let g = stored.gains();
        let mut variants: Vec<(String, DpPidGains)> = Vec::new();
        for f in [0.7f32, 1.4] {
            variants.push((
                format!("kp x{f}"),
                DpPidGains {
                    kp_pa_per_rad: g.kp_pa_per_rad * f,
                    ..g
                },
            ));
            variants.push((
                format!("kd x{f}"),
                DpPidGains {
                    kd_pa_s_per_rad: g.kd_pa_s_per_rad * f,
                    ..g
                },
            ));
            if g.ki_pa_per_rad_s > 0.0 {
                variants.push((
                    format!("ki x{f}"),
                    DpPidGains {
                        ki_pa_per_rad_s: g.ki_pa_per_rad_s * f,
                        ..g
                    },
                ));
            }
        }
        variants.push((
            "w flipped".into(),
            DpPidGains {
                setpoint_rate_weight: 1.0 - g.setpoint_rate_weight,
                ..g
            },
        ));
        for (what, v) in variants {
            let s = score_suite(&plant, &sc, ControlLaw::DirectPid(v)).unwrap();
            eprintln!(
                "{name} {what}: suite MSE {:.4e} rad^2 (stored {:.4e})",
                s.mse_rad2, stored.suite_mse_rad2
            );
            assert!(
                s.mse_rad2 >= 0.98 * stored.suite_mse_rad2,
                "{name} with {what} scores {:.4e} rad^2 < stored {:.4e} rad^2: not tuned",
                s.mse_rad2,
                stored.suite_mse_rad2
            );
        }
    }
}

#[test]
fn the_checked_in_tuning_file_parses_and_names_both_laws() {
    let text = std::fs::read_to_string(pid_tuned_path()).unwrap();
    let t = PidTuning::from_toml_str(&text, "config/pid_tuned.toml").unwrap();
    assert_eq!(t.pd.ki_pa_per_rad_s, 0.0);
    assert!(t.pid.ki_pa_per_rad_s > 0.0);
    assert!(text.contains("tune_pid"), "provenance header missing");
}
