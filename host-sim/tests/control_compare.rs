//! Issue 5 proof, closed loop: on the reference plant with the firmware in the loop, the
//! model-based cascade (identified constants, trajectory feed-forward,
//! `ControllerConfig::reference`) against the tuned PD and PID of `config/pid_tuned.toml` on
//! the step / sine / random suite (seed 004 Table 3: PD 3.61 vs model-based 1.95, 1.85x).
//!
//! What holds and is asserted here (measured figures in README, "Closed loop: cascade vs
//! tuned PD / PID"):
//! - the cascade's suite MSE is at least 2x lower than the tuned PD's (measured 5.4x);
//! - it is lower than the tuned PID's (measured 1.27x): the 2x against the best tuned
//!   PD / PID is NOT reached on the suite MSE. The step and random scenarios are dominated by
//!   the first ~100 ms after each set-point jump, where both laws open the valves fully and
//!   the rise is bounded by the valve flow (cascade and PID within 1 % of each other there,
//!   the PID marginally ahead);
//! - on the tracking part of the suite (the sine) the cascade is at least 2x better than both
//!   (measured 59x against the PID);
//! - the stored gains of all three laws are local optima of the tuning cost (the worse of the
//!   suite MSE at the gains and at 1.25 x the feedback gains, step overshoot <= 10 %).
//!
//! `cargo test -p host-sim --test control_compare -- --nocapture` prints the table
//! (`cargo run --release -p host-sim --example compare_control` prints the same).

use std::path::PathBuf;

use host_sim::control_compare::{
    compare, config_for, format_table, pid_tuned_path, scale_feedback, suite_scenarios,
    tuning_cost, PidTuning, GAIN_MARGIN,
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
    let sc = suite_scenarios().unwrap();
    for (row, stored) in [(&rows[1], &t.pd), (&rows[2], &t.pid)] {
        let (_, nominal, margin) = tuning_cost(
            &plant,
            &sc,
            config_for(ControlLaw::DirectPid(stored.gains()), 1000.0),
        );
        assert_eq!(nominal, row.score.mse_rad2);
        for (what, measured, recorded) in [
            ("suite", nominal, stored.suite_mse_rad2),
            (
                "at the gain margin",
                margin,
                stored.suite_mse_at_margin_rad2,
            ),
        ] {
            let rel = (measured - recorded).abs() / recorded;
            assert!(
                rel < 1e-6,
                "{} {what}: measured {measured:.6e} rad^2, stored {recorded:.6e} rad^2",
                row.controller
            );
        }
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
/// or kd by 0.7 or 1.4 does not lower the tuning cost by more than 2 %; the loop keeps its
/// gain margin; switching the feed-forward off makes the suite MSE worse.
#[test]
fn reference_cascade_gains_are_a_local_optimum_of_the_tuning_cost() {
    let plant = reference_plant();
    let sc = suite_scenarios().unwrap();
    let base = config_for(ControlLaw::Cascade, 1000.0);
    let (c0, nominal, margin) = tuning_cost(&plant, &sc, base);
    assert!(margin <= 1.1 * nominal, "{margin:.4e} vs {nominal:.4e}");
    for f in [0.7f32, 1.4] {
        for (what, k) in [("kp", 0), ("ki", 1), ("kd", 2)] {
            let mut cfg = base;
            match k {
                0 => cfg.position.kp *= f,
                1 => cfg.position.ki *= f,
                _ => cfg.position.kd *= f,
            }
            let (c, ..) = tuning_cost(&plant, &sc, cfg);
            eprintln!("cascade {what} x{f}: cost {c:.4e} rad^2 (reference {c0:.4e})");
            assert!(
                c >= 0.98 * c0,
                "cascade with {what} x{f} costs {c:.4e} rad^2 < reference {c0:.4e} rad^2"
            );
        }
    }
    let mut off = base;
    off.feedforward = pam_firmware::feedforward::FeedforwardGains::OFF;
    let (_, n_off, _) = tuning_cost(&plant, &sc, off);
    eprintln!("cascade without feed-forward: suite MSE {n_off:.4e} rad^2 (with {nominal:.4e})");
    assert!(n_off > nominal);
    // The gain margin is real: 1.25 x the loop gains still tracks (scale_feedback is what
    // the cost used).
    let (_, n_margin, _) = tuning_cost(&plant, &sc, scale_feedback(base, GAIN_MARGIN));
    assert!(n_margin.is_finite());
}

/// The stored PD / PID are tuned: scaling any one gain by 0.7 or 1.4 (or flipping the
/// derivative's set-point weight) does not lower the tuning cost by more than 2 %.
#[test]
fn stored_pd_and_pid_gains_are_a_local_optimum_of_the_tuning_cost() {
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
        let c0 = stored.suite_mse_rad2.max(stored.suite_mse_at_margin_rad2);
        for (what, v) in variants {
            let (c, ..) = tuning_cost(&plant, &sc, config_for(ControlLaw::DirectPid(v), 1000.0));
            eprintln!("{name} {what}: cost {c:.4e} rad^2 (stored {c0:.4e})");
            assert!(
                c >= 0.98 * c0,
                "{name} with {what} costs {c:.4e} rad^2 < stored {c0:.4e} rad^2: not tuned"
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

/// Robustness, not part of the criterion: the same gains on the loaded joint
/// (`reference-1dof-loaded.toml`, 11x the inertia, no retuning). The cascade stays stable and
/// best; the PID tuned on the nominal joint limit-cycles there (measured 128x the cascade's
/// suite MSE, README).
#[test]
fn on_the_loaded_joint_the_cascade_stays_stable_and_best() {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/plant/reference-1dof-loaded.toml");
    let plant = Plant::load(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    let rows = compare(&plant, &tuning()).unwrap();
    eprintln!("{}", format_table(&rows));
    let cascade = &rows[0].score;
    assert!(cascade.scenarios.iter().all(|s| s.fault.is_none()));
    assert!(cascade.mse_rad2.is_finite());
    for r in &rows[1..] {
        assert!(
            r.score.mse_rad2 > cascade.mse_rad2,
            "{}: {:.4e} rad^2 vs cascade {:.4e} rad^2",
            r.controller,
            r.score.mse_rad2,
            cascade.mse_rad2
        );
    }
}
