//! Every plant effect in every mode: for each effect of `[effects]` at a realistic size,
//! - open-loop replay (`sim::simulate` + `Plant::measure_series`),
//! - the closed loop with the firmware (`control::closed_loop::run_with`),
//! - the controller comparison (`control::compare::score_suite_with`),
//! - the diagnosis (`diagnose::fitting::Problem`: the nominal prediction and every candidate
//!   added on top of the plant file's effects)
//!
//! give a run that differs from the nominal plant's by more than the integration tolerance,
//! and the closed loop with the effect matches an open-loop replay of the valve commands it
//! produced, on the same plant.
//!
//! The integration tolerance is measured, not assumed: for replay it is the difference of the
//! nominal replay at the working tolerances (rtol = atol = 1e-6) from one at 1e-10; for the
//! closed loop it is the difference of the nominal run from the replay of its own commands
//! (the same inputs integrated in other segments, so the whole integration error of both).
//! "Differs" is more than 10 times that on at least one channel.

mod common;
use common::*;

use host_sim::control::closed_loop::{run_with, ClosedLoopRun, Scenario};
use host_sim::control::compare::{control_tuned_path, score_suite_with, ControlTuning};
use host_sim::diagnose::catalogue;
use host_sim::diagnose::fitting::{Part, Problem};
use host_sim::diagnose::synth::{excitation, Excitation};
use host_sim::io::recording::{Channel, Recording};
use host_sim::sim::{simulate, SolverOptions};
use host_sim::{Measurement, Plant, PlantState, ValveInputs};
use pam_firmware::tick::ControllerConfig;

/// Each effect at a realistic size: (name, `[effects]` TOML). Sizes as in the diagnosis's
/// synthetic rig, the dead time and lag of the issue (8 ms, 30 ms), a calibration error on
/// every channel.
const EFFECTS: [(&str, &str); 11] = [
    (
        "joint_friction",
        "[effects.joint_friction]\ncoulomb_nm = 0.25\nbreakaway_nm = 0.5\nstribeck_velocity_rad_s = 0.3\nviscous_nm_s_per_rad = 0.05\nsmoothing_velocity_rad_s = 0.01\n",
    ),
    (
        "gravity",
        "[effects.gravity]\nmass_kg = 1.0\ncom_distance_m = 0.1\nhanging_angle_rad = 0.0\n",
    ),
    (
        "leakage",
        "[effects.leakage]\nsonic_conductance_m3_per_s_pa = 4.0e-10\n",
    ),
    ("polytropic", "[effects.polytropic]\nexponent = 1.3\n"),
    (
        "thermal_chamber",
        "[effects.thermal_chamber]\nheat_transfer_w_per_k = 2.0\nkappa = 1.4\n",
    ),
    ("valve_dead_time", "[effects.valve_dead_time]\ndelay_s = 0.008\n"),
    (
        "sensor",
        "[effects.sensor.angle_deg]\noffset = 0.5\ngain = 1.01\n[effects.sensor.p1_kpa]\noffset = 8.0\n[effects.sensor.p2_kpa]\ngain = 0.98\n[effects.sensor.f1_n]\noffset = 5.0\n[effects.sensor.f2_n]\ngain = 1.03\n",
    ),
    (
        "sensor_lag",
        "[effects.sensor_lag]\nangle_time_constant_s = 0.03\npressure_time_constant_s = 0.03\nforce_time_constant_s = 0.03\n",
    ),
    (
        "muscle_hysteresis",
        "[effects.muscle_hysteresis]\nbase_force_n = 6.0\npressure_gain_n_per_pa = 2.0e-5\nsmoothing_rate_per_s = 0.02\n",
    ),
    (
        "supply_drop_static",
        "[effects.supply_drop]\nmodel = \"static\"\nresistance_pa_s_per_m3 = 2.0e7\n",
    ),
    (
        "supply_drop_reservoir",
        "[effects.supply_drop]\nmodel = \"reservoir\"\ntank_volume_m3 = 5.0e-4\nfeed_conductance_m3_per_s_pa = 6.0e-9\n",
    ),
];

fn step_scenario() -> Scenario {
    Scenario::load(root().join("scenarios/step.toml")).unwrap()
}

/// The closed loop's solver tolerances (`closed_loop::run_with`).
const OPTS: SolverOptions = SolverOptions {
    rtol: 1e-6,
    atol: 1e-6,
    max_steps_per_segment: 1_000_000,
};

/// Largest |a - b| per channel (angle deg, p1 kPa, p2 kPa, f1 N, f2 N).
fn max_diff(a: &[Measurement], b: &[Measurement]) -> [f64; 5] {
    assert_eq!(a.len(), b.len());
    let mut d = [0.0f64; 5];
    for (x, y) in a.iter().zip(b) {
        for (i, (u, v)) in x.to_array().iter().zip(y.to_array()).enumerate() {
            d[i] = d[i].max((u - v).abs());
        }
    }
    d
}

/// The channels of the true plant state (no sensor effects).
fn true_channels(plant: &Plant, run: &ClosedLoopRun) -> Vec<Measurement> {
    run.rows
        .iter()
        .map(|r| plant.true_channels(&r.state))
        .collect()
}

/// Five channel values in short exponent form.
fn e5(v: &[f64; 5]) -> String {
    let s: Vec<String> = v.iter().map(|x| format!("{x:.2e}")).collect();
    format!("[{}]", s.join(", "))
}

/// Whether `d` exceeds `factor` x the tolerance `tol` on some channel; the report line.
fn exceeds(d: &[f64; 5], tol: &[f64; 5], factor: f64) -> (bool, String) {
    let ratio: Vec<f64> = d.iter().zip(tol).map(|(d, t)| d / t.max(1e-12)).collect();
    let best = ratio.iter().copied().fold(0.0, f64::max);
    (
        best > factor,
        format!(
            "max diff {} / tolerance {}: best ratio {best:.3e}",
            e5(d),
            e5(tol)
        ),
    )
}

/// Replays `run`'s valve commands open loop on `plant`: (true channels, measured channels).
fn replay(plant: &Plant, run: &ClosedLoopRun) -> (Vec<Measurement>, Vec<Measurement>) {
    let commands: Vec<_> = run.rows.iter().map(|r| r.command).collect();
    let sim = simulate(plant, &commands, run.dt_s, &OPTS).unwrap();
    (
        sim.states.iter().map(|x| plant.true_channels(x)).collect(),
        plant.measure_series(&sim.states, run.dt_s),
    )
}

fn closed_loop(plant: &Plant, s: &Scenario) -> ClosedLoopRun {
    let cfg = ControllerConfig::reference(s.scenario.tick_hz as f32);
    run_with(plant, s, cfg, &mut |_| {}).unwrap()
}

/// The step scenario on the nominal plant and its closed-loop run.
fn nominal_step() -> (Scenario, Plant, ClosedLoopRun) {
    let s = step_scenario();
    let nominal = plant_with("");
    let run = closed_loop(&nominal, &s);
    (s, nominal, run)
}

/// How far a closed-loop run may depart from the replay of its own commands, per channel:
/// 10 x the larger of the nominal run's own departure (the integration error of the two
/// integrations, measured) and the solver's relative tolerance (1e-6) times the channel's
/// largest magnitude in the nominal run (what the error control allows per step).
fn replay_bound(nominal_departure: &[f64; 5], nominal: &[Measurement]) -> [f64; 5] {
    let mut b = [0.0; 5];
    for (i, bi) in b.iter_mut().enumerate() {
        let size = nominal
            .iter()
            .map(|m| m.to_array()[i].abs())
            .fold(0.0, f64::max);
        *bi = 10.0 * nominal_departure[i].max(OPTS.rtol * size);
    }
    b
}

#[test]
fn every_effect_changes_the_closed_loop_and_matches_its_own_replay() {
    let (s, nominal, run0) = nominal_step();
    let (rep_true0, rep_meas0) = replay(&nominal, &run0);
    let true0 = true_channels(&nominal, &run0);
    let meas0: Vec<Measurement> = run0.rows.iter().map(|r| r.measured).collect();
    // Integration tolerance of the closed loop: the nominal run against its own replay.
    let tol = max_diff(&true0, &rep_true0);
    let tol_meas = max_diff(&meas0, &rep_meas0);
    eprintln!(
        "closed-loop integration tolerance (true) {}, (measured) {}",
        e5(&tol),
        e5(&tol_meas)
    );
    let bound = replay_bound(&tol, &true0);
    eprintln!("replay bound {}", e5(&bound));
    let st0 = run0.tracking(0.0);
    eprintln!(
        "nominal: rms {:.5} rad, max {:.5} rad",
        st0.rms_rad, st0.max_abs_rad
    );
    let mut failures = Vec::new();
    for (name, toml) in EFFECTS {
        let plant = plant_with(toml);
        let run = closed_loop(&plant, &s);
        let st = run.tracking(0.0);
        let truth = true_channels(&plant, &run);
        let meas: Vec<Measurement> = run.rows.iter().map(|r| r.measured).collect();
        // Differs from the nominal run: the true trajectory or what the sensors report.
        let (d_true, l_true) = exceeds(&max_diff(&truth, &true0), &tol, 10.0);
        let (d_meas, l_meas) = exceeds(&max_diff(&meas, &meas0), &tol_meas, 10.0);
        // Matches its own replay (same plant, the commands it produced).
        let (rep_true, rep_meas) = replay(&plant, &run);
        let dt_rep = max_diff(&truth, &rep_true);
        let dm_rep = max_diff(&meas, &rep_meas);
        let matches = dt_rep.iter().zip(&bound).all(|(d, b)| d <= b)
            && dm_rep.iter().zip(&bound).all(|(d, b)| d <= b);
        eprintln!(
            "{name}: rms {:.5} rad, max {:.5} rad, fault {:?}; vs nominal (true) {l_true}; (measured) {l_meas}; vs own replay (true) {} (measured) {}",
            st.rms_rad,
            st.max_abs_rad,
            run.first_latched_fault_tick,
            e5(&dt_rep),
            e5(&dm_rep)
        );
        if !(d_true || d_meas) {
            failures.push(format!("{name}: closed loop does not differ from nominal"));
        }
        if !matches {
            failures.push(format!(
                "{name}: closed loop departs from its replay: true {}, measured {}, bound {}",
                e5(&dt_rep),
                e5(&dm_rep),
                e5(&bound)
            ));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

#[test]
fn every_effect_changes_the_open_loop_replay() {
    let dt = 1e-3;
    let inputs = excitation(Excitation::Pulses, 3000, dt, 7);
    let nominal = plant_with("");
    let fine = SolverOptions {
        rtol: 1e-10,
        atol: 1e-10,
        ..OPTS
    };
    let base = |p: &Plant, o: &SolverOptions| {
        let sim = simulate(p, &inputs, dt, o).unwrap();
        p.measure_series(&sim.states, dt)
    };
    let m0 = base(&nominal, &OPTS);
    let tol = max_diff(&m0, &base(&nominal, &fine));
    eprintln!("replay integration tolerance {}", e5(&tol));
    let mut failures = Vec::new();
    for (name, toml) in EFFECTS {
        let plant = plant_with(toml);
        let (ok, line) = exceeds(&max_diff(&base(&plant, &OPTS), &m0), &tol, 10.0);
        eprintln!("{name}: {line}");
        if !ok {
            failures.push(name);
        }
    }
    assert!(failures.is_empty(), "no change in replay: {failures:?}");
}

#[test]
fn every_effect_changes_the_controller_comparison() {
    let tuning = ControlTuning::load(&control_tuned_path()).unwrap();
    let s = Scenario::load(root().join("scenarios/suite/step_move.toml")).unwrap();
    let cfg = tuning.cascade.config(1000.0);
    let nominal = plant_with("");
    let score0 = score_suite_with(&nominal, std::slice::from_ref(&s), cfg).unwrap();
    // Integration tolerance of the angle in this scenario's closed loop (nominal run against
    // the replay of its commands), and what it allows of the MSE:
    // |mse(x + e) - mse(x)| <= 2 rms e + e^2.
    let run0 = run_with(
        &nominal,
        &s,
        ControllerConfig {
            tick_hz: 1000.0,
            ..cfg
        },
        &mut |_| {},
    )
    .unwrap();
    let (rep0, _) = replay(&nominal, &run0);
    let e_rad = max_diff(&true_channels(&nominal, &run0), &rep0)[0].to_radians();
    let mse0 = score0.mse_rad2;
    let tol_mse = 2.0 * mse0.sqrt() * e_rad + e_rad * e_rad;
    eprintln!("comparison: nominal suite MSE {mse0:.4e} rad^2, tolerance {tol_mse:.3e}");
    let mut failures = Vec::new();
    for (name, toml) in EFFECTS {
        let plant = plant_with(toml);
        let score = score_suite_with(&plant, std::slice::from_ref(&s), cfg).unwrap();
        let d = (score.mse_rad2 - mse0).abs();
        eprintln!(
            "{name}: suite MSE {:.4e} rad^2 (fault {:?}), |change| {d:.3e} = {:.1} x tolerance",
            score.mse_rad2,
            score.scenarios[0].fault,
            d / tol_mse.max(1e-300)
        );
        if !(d > 10.0 * tol_mse) {
            failures.push(name);
        }
    }
    assert!(
        failures.is_empty(),
        "no change in the comparison: {failures:?}"
    );
}

/// The diagnosis simulates the plant file's effects: its nominal prediction and every
/// candidate it tries on top of them differ from the same without the effect.
#[test]
fn every_effect_is_kept_by_the_diagnosis_and_its_candidates() {
    let dt = 1e-3;
    let inputs = excitation(Excitation::ChirpSteps, 2000, dt, 3);
    let nominal_cfg = config_with("");
    // Any recording: the predictions do not depend on its channels.
    let nominal = Plant::from_config(&nominal_cfg);
    let sim = simulate(&nominal, &inputs, dt, &OPTS).unwrap();
    let meas = nominal.measure_series(&sim.states, dt);
    let mut rec = Recording {
        t_s: (0..inputs.len()).map(|k| k as f64 * dt).collect(),
        inputs: inputs.clone(),
        ..Default::default()
    };
    for c in Channel::ALL {
        rec.set_channel(c, meas.iter().map(|m| c.of(m)).collect());
    }
    let problem0 = Problem::new(&nominal_cfg, &rec, [1.0; 5], OPTS).unwrap();
    let cands = catalogue();
    let parts = |p: &Problem| -> Vec<Vec<Measurement>> {
        let mut out = vec![p.predict(&[]).unwrap()];
        for c in &cands {
            let params: Vec<f64> = c
                .params(&p.setup)
                .iter()
                .map(|s| s.scale.clamp(s.lo, s.hi))
                .collect();
            out.push(
                p.predict(&[Part {
                    candidate: c.as_ref(),
                    params,
                }])
                .unwrap(),
            );
        }
        out
    };
    let base = parts(&problem0);
    // The replay tolerance as in `every_effect_changes_the_open_loop_replay`.
    let fine = SolverOptions {
        rtol: 1e-10,
        atol: 1e-10,
        ..OPTS
    };
    let sim_fine = simulate(&nominal, &inputs, dt, &fine).unwrap();
    let tol = max_diff(&meas, &nominal.measure_series(&sim_fine.states, dt));
    let mut failures = Vec::new();
    for (name, toml) in EFFECTS {
        let cfg = config_with(toml);
        let problem = Problem::new(&cfg, &rec, [1.0; 5], OPTS).unwrap();
        let with = parts(&problem);
        for (i, (a, b)) in with.iter().zip(&base).enumerate() {
            let what = if i == 0 {
                "nominal prediction".to_string()
            } else {
                format!("candidate {}", cands[i - 1].id())
            };
            let (ok, line) = exceeds(&max_diff(a, b), &tol, 10.0);
            // A candidate for the same effect replaces the file's (a refit of it): exempt.
            let same = i > 0 && same_effect(name, cands[i - 1].id());
            if !ok && !same {
                failures.push(format!("{name}, {what}: {line}"));
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// Whether the diagnosis candidate `id` models the test effect `name` (it then replaces the
/// plant file's table of that effect).
fn same_effect(name: &str, id: &str) -> bool {
    matches!(
        (name, id),
        ("joint_friction", "joint_friction")
            | ("gravity", "gravity")
            | ("leakage", "leakage")
            | ("leakage", "leakage_muscle1")
            | ("leakage", "leakage_muscle2")
            | ("polytropic", "polytropic")
            // Both set the chamber's pressure law: either candidate replaces the other.
            | ("polytropic", "heat_transfer")
            | ("thermal_chamber", "heat_transfer")
            | ("thermal_chamber", "polytropic")
            | ("valve_dead_time", "valve_delay")
            | ("sensor_lag", "sensor_lag")
            | ("sensor_lag", "sensor_lag_p1")
            | ("sensor_lag", "sensor_lag_p2")
            | ("muscle_hysteresis", "muscle_hysteresis")
            | ("supply_drop_static", "supply_drop")
            | ("supply_drop_static", "supply_reservoir")
            | ("supply_drop_reservoir", "supply_drop")
            | ("supply_drop_reservoir", "supply_reservoir")
    )
}

/// The acceptance case: the step scenario with an 8 ms valve dead time, or with a
/// 30 ms lag on the angle and pressure sensors, is not the nominal run (it was, to the last
/// digit: rms 0.01898 rad, max 0.19891 rad), and matches the open-loop replay of its own
/// valve commands.
#[test]
fn step_with_dead_time_or_sensor_lag_differs_and_matches_its_replay() {
    let (s, nominal, run0) = nominal_step();
    let (rep0, _) = replay(&nominal, &run0);
    let tol = max_diff(&true_channels(&nominal, &run0), &rep0);
    let st0 = run0.tracking(0.0);
    for toml in [
        "[effects.valve_dead_time]\ndelay_s = 0.008\n",
        "[effects.sensor_lag]\nangle_time_constant_s = 0.03\npressure_time_constant_s = 0.03\n",
    ] {
        let plant = plant_with(toml);
        let run = closed_loop(&plant, &s);
        let st = run.tracking(0.0);
        eprintln!(
            "{}: rms {:.5} rad, max {:.5} rad (nominal {:.5}, {:.5})",
            plant.effects_summary(),
            st.rms_rad,
            st.max_abs_rad,
            st0.rms_rad,
            st0.max_abs_rad
        );
        assert!(
            (st.rms_rad - st0.rms_rad).abs() > 1e-5,
            "{toml}: rms {} vs nominal {}",
            st.rms_rad,
            st0.rms_rad
        );
        let d = max_diff(
            &true_channels(&plant, &run),
            &true_channels(&nominal, &run0),
        );
        assert!(
            d[0] > 100.0 * tol[0].max(1e-9),
            "{toml}: angle differs by {} deg",
            d[0]
        );
        let (rep, rep_meas) = replay(&plant, &run);
        let dr = max_diff(&true_channels(&plant, &run), &rep);
        let meas: Vec<Measurement> = run.rows.iter().map(|r| r.measured).collect();
        let dm = max_diff(&meas, &rep_meas);
        let bound = replay_bound(&tol, &true_channels(&nominal, &run0));
        assert!(
            dr.iter().zip(&bound).all(|(d, b)| d <= b)
                && dm.iter().zip(&bound).all(|(d, b)| d <= b),
            "{toml}: replay departs by {} (true), {} (measured); bound {}",
            e5(&dr),
            e5(&dm),
            e5(&bound)
        );
        // The recording of the run holds the commands and the measured channels, and says
        // which effects were on.
        let rec = run.to_recording();
        assert_eq!(rec.meta("effects"), Some(plant.effects_summary().as_str()));
        assert_eq!(rec.inputs[1500], run.rows[1500].command);
    }
}

#[test]
fn a_fractional_dead_time_runs_in_every_mode_between_its_whole_neighbours() {
    // Open loop: the pressure response to valve pulses with an 8.5 ms dead time lies between
    // those with 8 and 9 ms (half way: each opening is split over two periods).
    let inputs = pulse_inputs(600, 50);
    let p1 = |delay_s: f64| -> Vec<f64> {
        let plant = plant_with(&format!("[effects.valve_dead_time]\ndelay_s = {delay_s}\n"));
        simulate(&plant, &inputs, 1e-3, &OPTS)
            .unwrap_or_else(|e| panic!("{e}"))
            .states
            .iter()
            .map(|x| x.p1_abs_pa)
            .collect()
    };
    let (a, m, b) = (p1(0.008), p1(0.0085), p1(0.009));
    let dist = |x: &[f64], y: &[f64]| -> f64 {
        x.iter()
            .zip(y)
            .map(|(u, v)| (u - v).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    let ab = dist(&a, &b);
    assert!(ab > 0.0);
    for (name, d) in [("8 ms", dist(&m, &a)), ("9 ms", dist(&m, &b))] {
        assert!(
            d > 0.2 * ab && d < 0.8 * ab,
            "8.5 ms vs {name}: {d} of {ab}"
        );
    }
    // Closed loop: the same dead time runs to the end.
    let plant = plant_with("[effects.valve_dead_time]\ndelay_s = 0.0085\n");
    let run = run_with(
        &plant,
        &step_scenario(),
        ControllerConfig::reference(1000.0),
        &mut |_| {},
    )
    .unwrap_or_else(|e| panic!("{e}"));
    assert!(run.rows.len() > 1000);
}

#[test]
fn active_effects_are_listed_with_their_parameters() {
    assert_eq!(plant_with("").effects_summary(), "none (nominal model)");
    assert!(plant_with("").active_effects().is_empty());
    let all: String = EFFECTS
        .iter()
        // The reservoir replaces the static supply drop; the chamber refuses a polytropic
        // exponent beside it (both set the pressure law).
        .filter(|(n, _)| *n != "supply_drop_reservoir" && *n != "thermal_chamber")
        .map(|(_, t)| *t)
        .collect();
    let p = plant_with(&all);
    let names: Vec<&str> = p.active_effects().iter().map(|e| e.name).collect();
    // Registry order (plant/effects/mod.rs), the order of the right-hand side's sums.
    assert_eq!(
        names,
        [
            "joint_friction",
            "muscle_hysteresis",
            "sensor_lag",
            "valve_dead_time",
            "supply_drop",
            "polytropic",
            "gravity",
            "leakage",
            "sensor",
        ]
    );
    let s = p.effects_summary();
    for part in [
        "valve_dead_time(delay_s = 0.008)",
        "sensor_lag(angle_time_constant_s = 0.03, pressure_time_constant_s = 0.03, force_time_constant_s = 0.03)",
        "sensor(angle_deg.offset = 0.5, angle_deg.gain = 1.01, p1_kpa.offset = 8, p2_kpa.gain = 0.98",
        "polytropic(exponent = 1.3)",
        "supply_drop(model = \"static\", resistance_pa_s_per_m3 = 20000000)",
    ] {
        assert!(s.contains(part), "{part} not in {s}");
    }
    assert_eq!(
        plant_with(EFFECTS.iter().find(|(n, _)| *n == "thermal_chamber").unwrap().1)
            .effects_summary(),
        "thermal_chamber(heat_transfer_w_per_k = 2, kappa = 1.4, wall_temperature_k = 293.15, initial_temperature_k = 293.15)"
    );
    // A disabled table is not active.
    let off = plant_with("[effects.valve_dead_time]\nenabled = false\ndelay_s = 0.008\n");
    assert!(off.active_effects().is_empty());
}

/// End to end through the binary: `simulate --scenario` on a plant with a dead time prints
/// and records the effect, and `simulate --inputs` of its recording on the same plant
/// reproduces the recorded channels.
#[test]
fn cli_closed_loop_recording_replays_open_loop_on_the_same_plant() {
    let dir = tempfile::tempdir().unwrap();
    let plant = root().join("host-sim/plants/reference-1dof-dead-time-8ms.toml");
    let closed = dir.path().join("closed.csv");
    // Exit status 1 is a run whose `[expect]` is not met: the step scenario's bounds are for
    // the nominal plant, and its reference gains do not settle with an 8 ms dead time.
    let run = |args: &[&std::ffi::OsStr], codes: &[i32]| {
        let o = bin().args(args).output().unwrap();
        let out = String::from_utf8_lossy(&o.stdout).into_owned();
        assert!(
            o.status.code().is_some_and(|c| codes.contains(&c)),
            "{:?}: {out}{}",
            o.status,
            String::from_utf8_lossy(&o.stderr)
        );
        out
    };
    let scenario = root().join("scenarios/step.toml");
    let out = run(
        &[
            "simulate".as_ref(),
            "--plant".as_ref(),
            plant.as_os_str(),
            "--scenario".as_ref(),
            scenario.as_os_str(),
            "--out".as_ref(),
            closed.as_os_str(),
        ],
        &[0, 1],
    );
    assert!(
        out.contains("plant effects: valve_dead_time(delay_s = 0.008)"),
        "{out}"
    );
    let replayed = dir.path().join("replayed.csv");
    let out = run(
        &[
            "simulate".as_ref(),
            "--plant".as_ref(),
            plant.as_os_str(),
            "--inputs".as_ref(),
            closed.as_os_str(),
            "--out".as_ref(),
            replayed.as_os_str(),
        ],
        &[0],
    );
    assert!(
        out.contains("plant effects: valve_dead_time(delay_s = 0.008)"),
        "{out}"
    );
    let a = Recording::read(&closed).unwrap();
    let b = Recording::read(&replayed).unwrap();
    for r in [&a, &b] {
        assert_eq!(r.meta("effects"), Some("valve_dead_time(delay_s = 0.008)"));
    }
    // Channels are written with 6 decimals: the replay may differ by the rounding of both
    // files (1e-6) plus the integration error (measured above as < 1e-5 deg, kPa, N).
    for c in Channel::ALL {
        let (x, y) = (a.channel(c).unwrap(), b.channel(c).unwrap());
        let d = x
            .iter()
            .zip(y)
            .map(|(u, v)| (u - v).abs())
            .fold(0.0, f64::max);
        assert!(d < 1e-4, "{}: replay departs by {d}", c.name());
    }
}

#[test]
fn a_leak_in_one_muscle_drains_that_chamber_only() {
    let leak = |muscle: &str| {
        plant_with(&format!(
            "[effects.leakage]\nsonic_conductance_m3_per_s_pa = 6.0e-10\n{muscle}"
        ))
    };
    let nominal = plant_with("");
    let x = PlantState {
        p1_abs_pa: 400e3,
        p2_abs_pa: 450e3,
        ..nominal.initial_state()
    };
    let u = ValveInputs::CLOSED;
    let d0 = nominal.derivatives(&x, &u);
    let both = leak("").derivatives(&x, &u);
    let only2 = leak("muscle = 2\n").derivatives(&x, &u);
    assert!(both.p1_abs_pa < d0.p1_abs_pa && both.p2_abs_pa < d0.p2_abs_pa);
    assert_eq!(only2.p1_abs_pa, d0.p1_abs_pa);
    assert_eq!(only2.p2_abs_pa, both.p2_abs_pa);
    // The muscle is 1 or 2, named in the error with the file and key.
    let text = format!(
        "{}\n[effects.leakage]\nsonic_conductance_m3_per_s_pa = 6.0e-10\nmuscle = 3\n",
        nominal_text()
    );
    let e = host_sim::PlantConfig::from_toml_str(&text, "leaky.toml")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("leaky.toml") && e.contains("effects.leakage.muscle"),
        "{e}"
    );
}

/// A start given as sensor readings (a recording's first sample) is read back through the
/// plant's sensor calibration: the calibrated measurement of the starting state gives the
/// readings again, so a calibration fitted by the diagnosis moves the start with it.
#[test]
fn a_start_given_as_readings_starts_where_the_calibration_says() {
    let mut c = config_with(
        "[effects.sensor.angle_deg]\noffset = 2.0\ngain = 1.1\n[effects.sensor.p1_kpa]\ngain = 1.06\n[effects.sensor.p2_kpa]\noffset = -7.0\n",
    );
    c.initial.angle_rad = 0.3;
    c.initial.p1_gauge_pa = 250e3;
    c.initial.p2_gauge_pa = 180e3;
    let as_state = Plant::from_config(&c).initial_state();
    assert_eq!(as_state.angle_rad, 0.3);
    assert_eq!(as_state.p1_abs_pa, 250e3 + c.environment.p_atm_pa);
    c.initial.as_read = true;
    let plant = Plant::from_config(&c);
    let x = plant.initial_state();
    assert!((x.angle_rad.to_degrees() - (0.3f64.to_degrees() - 2.0) / 1.1).abs() < 1e-9);
    let m = plant.measure(&x);
    for (got, want) in [
        (m.angle_deg, 0.3f64.to_degrees()),
        (m.p1_kpa, 250.0),
        (m.p2_kpa, 180.0),
    ] {
        assert!((got - want).abs() < 1e-9, "read {got}, first sample {want}");
    }
    // Without a calibration the readings are the state.
    let mut plain = c.clone();
    plain.effects.sensor = None;
    assert_eq!(
        Plant::from_config(&plain).initial_state().p2_abs_pa,
        180e3 + c.environment.p_atm_pa
    );
}
