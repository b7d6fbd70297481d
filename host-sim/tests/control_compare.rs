//! The closed-loop comparison: on the reference plant with the firmware in the loop, the
//! model-based cascade (identified constants, trajectory feed-forward, torque loop) against the
//! tuned PD and PID, all three tuned on the suite by the same procedure and cost and stored in
//! `config/control_tuned.toml` (seed 004 Table 3: PD 3.61 vs model-based 1.95, 1.85x).
//! The suite: `control::compare::SUITE` (step and random levels reached by 0.15 s minimum-jerk
//! moves, 0.5 Hz sine).
//!
//! What holds and is asserted here (measured figures in README, "Closed loop: cascade vs
//! tuned PD / PID"):
//! - the tuned cascade's suite MSE is at least 2x lower than the tuned PD's and the tuned
//!   PID's (measured 815x and 2.84x), and the stored MSEs re-measure exactly;
//! - the stored gains of all three laws are local optima of the tuning cost (the worse of the
//!   suite MSE at the gains and at 2 x the feedback gains, step overshoot <= 10 %);
//! - the firmware's default cascade gains (`ControllerConfig::reference`) meet the firmware's
//!   step requirements on the nominal and the 11 x loaded joint, the suite-tuned cascade does
//!   not; on the loaded joint the default gains beat every suite-tuned law.
//!
//! `cargo test -p host-sim --test control_compare -- --nocapture` prints the table
//! (`cargo run --release -p host-sim --example compare_control` prints the same).

mod common;

use std::path::PathBuf;

use common::assert_cascade_local_optimum;
use host_sim::control::compare::{
    compare, config_for, control_tuned_path, format_table, meets_step_requirement, scale_feedback,
    suite_scenarios, tuning_cost, ControlTuning, GAIN_MARGIN, STEP_REQUIREMENTS,
};
use host_sim::Plant;
use pam_firmware::pid::DpPidGains;
use pam_firmware::tick::ControlLaw;

fn reference_plant() -> Plant {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/reference-1dof.toml");
    Plant::load(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

fn tuning() -> ControlTuning {
    let p = control_tuned_path();
    ControlTuning::load(&p).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn tuned_cascade_beats_tuned_pd_and_pid_by_2x_on_the_suite() {
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
    let stored = [
        (
            &rows[0],
            t.cascade.config(1000.0),
            t.cascade.suite_mse_rad2,
            t.cascade.suite_mse_at_margin_rad2,
        ),
        (
            &rows[1],
            config_for(ControlLaw::DirectPid(t.pd.gains()), 1000.0),
            t.pd.suite_mse_rad2,
            t.pd.suite_mse_at_margin_rad2,
        ),
        (
            &rows[2],
            config_for(ControlLaw::DirectPid(t.pid.gains()), 1000.0),
            t.pid.suite_mse_rad2,
            t.pid.suite_mse_at_margin_rad2,
        ),
    ];
    let mut mismatches = Vec::new();
    for (row, cfg, mse, mse_margin) in stored {
        let (_, nominal, margin) = tuning_cost(&plant, &sc, cfg);
        assert_eq!(nominal, row.score.mse_rad2);
        for (what, measured, recorded) in [
            ("suite", nominal, mse),
            ("at the gain margin", margin, mse_margin),
        ] {
            let rel = (measured - recorded).abs() / recorded;
            if rel >= 1e-6 {
                mismatches.push(format!(
                    "{} {what}: measured {measured:?} rad^2, stored {recorded:?} rad^2",
                    row.controller
                ));
            }
        }
    }
    assert!(mismatches.is_empty(), "{}", mismatches.join("\n"));
    let cascade = &rows[0].score;
    for other in &rows[1..3] {
        assert!(
            other.score.mse_rad2 >= 2.0 * cascade.mse_rad2,
            "suite: cascade {:.4e} rad^2 vs {} {:.4e} rad^2: only {:.2}x",
            cascade.mse_rad2,
            other.controller,
            other.score.mse_rad2,
            other.score.mse_rad2 / cascade.mse_rad2
        );
    }
}

/// The stored cascade gains are tuned: scaling the position kp, ki, kd or the torque loop's
/// ki by 0.7 or 1.4 does not lower the tuning cost by more than 2 %; switching the
/// feed-forward off, or only its inertia term, makes the suite MSE worse.
#[test]
fn stored_cascade_gains_are_a_local_optimum_of_the_tuning_cost() {
    let plant = reference_plant();
    let sc = suite_scenarios().unwrap();
    let t = tuning();
    let base = assert_cascade_local_optimum(&plant, &sc, &t.cascade);
    let (_, nominal, _) = tuning_cost(&plant, &sc, base);
    let mut off = base;
    off.feedforward = pam_firmware::feedforward::FeedforwardGains::OFF;
    let (_, n_off, _) = tuning_cost(&plant, &sc, off);
    let mut no_inertia = base;
    no_inertia.feedforward.inertia_kgm2 = 0.0;
    let (_, n_no_inertia, _) = tuning_cost(&plant, &sc, no_inertia);
    eprintln!(
        "cascade: suite MSE {nominal:.4e} rad^2; without feed-forward {n_off:.4e}, without its inertia term {n_no_inertia:.4e}"
    );
    assert!(n_off > nominal && n_no_inertia > nominal);
    // The gain margin is real: 2 x the position gains still tracks without a fault.
    let (_, n_margin, _) = tuning_cost(&plant, &sc, scale_feedback(base, GAIN_MARGIN));
    assert!(n_margin.is_finite());
}

/// The firmware ships robust gains, not the suite-tuned ones: `ControllerConfig::reference`
/// meets both step requirements (nominal and 11 x loaded joint); the suite-tuned cascade
/// meets neither (it trades the load margin for tracking).
#[test]
fn firmware_default_gains_meet_the_step_requirements_the_suite_tuned_cascade_does_not() {
    let plant = reference_plant();
    let t = tuning();
    for req in &STEP_REQUIREMENTS {
        assert!(
            meets_step_requirement(&plant, config_for(ControlLaw::Cascade, 1000.0), req).unwrap(),
            "firmware default gains fail {req:?}"
        );
        assert!(
            !meets_step_requirement(&plant, t.cascade.config(1000.0), req).unwrap(),
            "suite-tuned cascade meets {req:?}: README says it does not"
        );
    }
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
fn the_checked_in_tuning_file_parses_and_names_all_three_laws() {
    let text = std::fs::read_to_string(control_tuned_path()).unwrap();
    let t = ControlTuning::from_toml_str(&text, "config/control_tuned.toml").unwrap();
    assert!(t.cascade.position_kp_nm_per_rad > 0.0);
    assert_eq!(t.pd.ki_pa_per_rad_s, 0.0);
    assert!(t.pid.ki_pa_per_rad_s > 0.0);
    assert!(text.contains("host-sim tune"), "provenance header missing");
}

/// Robustness, not part of the criterion: the same gains on the loaded joint
/// (`reference-1dof-loaded.toml`, 11x the inertia, no retuning). The cascade with the
/// firmware's default gains stays stable and beats every suite-tuned law; the PID tuned on the
/// nominal joint limit-cycles there (measured 26x the default cascade's suite MSE, README).
#[test]
fn on_the_loaded_joint_the_firmware_default_cascade_stays_stable_and_best() {
    let p =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/reference-1dof-loaded.toml");
    let plant = Plant::load(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    let rows = compare(&plant, &tuning()).unwrap();
    eprintln!("{}", format_table(&rows));
    assert_eq!(rows[3].controller, "cascade, firmware default gains");
    let cascade = &rows[3].score;
    assert!(cascade.scenarios.iter().all(|s| s.fault.is_none()));
    assert!(cascade.mse_rad2.is_finite());
    for r in &rows[..3] {
        assert!(
            r.score.mse_rad2 > cascade.mse_rad2,
            "{}: {:.4e} rad^2 vs cascade {:.4e} rad^2",
            r.controller,
            r.score.mse_rad2,
            cascade.mse_rad2
        );
    }
}
