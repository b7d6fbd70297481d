//! The firmware's arm tick (`pam_firmware::arm::ArmTick`) in the loop on seed 001's arm:
//! `host-sim demo --plant host-sim/plants/arm3-seed001.toml` meets every arm scenario's
//! `[expect]` bounds (exit 0), a missed bound exits 1, a bad scenario exits 2; the recording
//! of a run replays open loop to the same channels; the gravity feed-forward is what holds
//! the arm up.

mod common;
use common::*;

use host_sim::control::arm3_loop::{run_arm, ArmScenario};
use host_sim::io::arm3::Arm3Recording;
use host_sim::plant::arm3::{Arm3, Arm3Config};
use host_sim::sim::arm3::simulate_arm3;
use host_sim::sim::SolverOptions;
use pam_firmware::arm::ArmConfig;

fn scenario(name: &str) -> std::path::PathBuf {
    root().join("scenarios/arm3").join(name)
}

#[test]
fn arm_demo_meets_every_expectation_and_writes_its_files() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("arm");
    let stdout = run_ok(&[&"demo", &"--plant", &arm3_plant(), &"--out-dir", &out]);
    println!("{stdout}");
    for (name, ticks) in [
        ("arm_step", 9000),
        ("arm_sine", 12000),
        ("arm_pick_place", 20000),
    ] {
        let row = stdout
            .lines()
            .find(|l| l.split_whitespace().next() == Some(name))
            .unwrap_or_else(|| panic!("no table row for {name}"));
        assert_eq!(row.split_whitespace().nth(6), Some("met"), "{row}");
        let rec = Arm3Recording::read(out.join(format!("{name}.csv"))).unwrap();
        assert_eq!(rec.len(), ticks, "{name}");
        assert_trace_and_plot(&out, name, ticks);
    }
}

#[test]
fn a_missed_expectation_exits_1_and_a_bad_scenario_exits_2() {
    let dir = tempfile::tempdir().unwrap();
    // The step scenario with a bound its run cannot meet (0.01 deg on joint 2).
    let tight_text = std::fs::read_to_string(scenario("step.toml"))
        .unwrap()
        .replace(
            "max_abs_error_rad = [0.01, 0.015, 0.01]",
            "max_abs_error_rad = [0.01, 0.0002, 0.01]",
        );
    assert!(
        tight_text.contains("0.0002"),
        "the step scenario's bound line changed"
    );
    let tight = dir.path().join("tight.toml");
    std::fs::write(&tight, tight_text).unwrap();
    let out = dir.path().join("out");
    let r = arm_demo(&tight, &out);
    exits(1, &r);
    let stdout = text(&r.stdout);
    assert!(
        stdout.contains("joint 2: max |error|") && stdout.contains("FAILED"),
        "{stdout}"
    );

    // An unknown key: exit 2, naming the file and the key, nothing written.
    let bad = dir.path().join("bad.toml");
    std::fs::write(
        &bad,
        std::fs::read_to_string(scenario("sine.toml"))
            .unwrap()
            .replace("seed = 2", "seed = 2\nspeed = 3"),
    )
    .unwrap();
    let out2 = dir.path().join("out2");
    let r = arm_demo(&bad, &out2);
    assert_refused(&r, &["bad.toml", "speed"], &out2);

    // A bad value names the line and the key.
    let text = std::fs::read_to_string(scenario("pick_place.toml")).unwrap();
    let bad = text.replace("move_s = 2.0", "move_s = 5.0");
    error_naming(
        ArmScenario::from_toml_str(&bad, "pp.toml"),
        &["pp.toml", "line", "move_s"],
    );
}

/// The run's recording, its open-loop replay, and the largest angle difference between the
/// replay and the run: equal up to the integration tolerance (the replay integrates runs of
/// equal openings in one segment, the loop tick by tick).
fn replay(
    arm: &Arm3,
    run: &host_sim::control::arm3_loop::ArmRun,
) -> (Arm3Recording, host_sim::sim::arm3::Arm3Simulation, f64) {
    let rec = run.to_recording(arm, "arm", "sine");
    let sim = simulate_arm3(
        arm,
        &rec.inputs,
        run.dt_s,
        &SolverOptions::default(),
        |_| {},
    )
    .unwrap();
    let worst = sim
        .states
        .iter()
        .zip(&run.rows)
        .flat_map(|(x, r)| (0..3).map(move |j| (x.angles_rad[j] - r.state.angles_rad[j]).abs()))
        .fold(0.0, f64::max);
    (rec, sim, worst)
}

#[test]
fn the_run_recording_replays_open_loop_to_the_same_channels() {
    let arm = Arm3::load(arm3_plant()).unwrap();
    let s = ArmScenario::load(scenario("sine.toml")).unwrap();
    let mut short = s.clone();
    short.scenario.duration_s = 3.0;
    let run = run_arm(&arm, &short, ArmConfig::reference(1000.0)).unwrap();
    let (_, _, worst) = replay(&arm, &run);
    println!("largest angle difference {worst:.3e} rad");
    assert!(worst < 1e-5, "{worst}");
}

/// The seed 001 arm with an 8 ms valve dead time on joint 2, a lagging angle sensor
/// (15 ms) and pressure sensors (8 ms) on joint 3, and a supply line resistance shared by
/// all six muscles (3e6 Pa s/m^3: the supply sags by 127 kPa, a fifth, when all six inlets
/// are fully open).
fn arm_with_signal_effects() -> Arm3 {
    let text = std::fs::read_to_string(arm3_plant()).unwrap();
    let text = format!(
        "{text}\n[joint2.effects.valve_dead_time]\ndelay_s = 0.008\n\
         [joint3.effects.sensor_lag]\nangle_time_constant_s = 0.015\npressure_time_constant_s = 0.008\n\
         [effects.supply_drop]\nmodel = \"static\"\nresistance_pa_s_per_m3 = 3.0e6\n"
    );
    Arm3::from_config(&Arm3Config::from_toml_str(&text, "arm-effects.toml").unwrap()).unwrap()
}

#[test]
fn with_dead_time_sensor_lag_and_a_shared_supply_drop_the_loop_tracks_and_replays() {
    let arm = arm_with_signal_effects();
    let nominal = Arm3::load(arm3_plant()).unwrap();
    let s = ArmScenario::load(scenario("sine.toml")).unwrap();
    let mut short = s.clone();
    short.scenario.duration_s = 4.0;
    let run = run_arm(&arm, &short, ArmConfig::reference(1000.0)).unwrap();
    let base = run_arm(&nominal, &short, ArmConfig::reference(1000.0)).unwrap();
    assert_eq!(run.first_fault(), None, "no fault with the effects");
    let (st, sb) = (run.tracking(1.0), base.tracking(1.0));
    for j in 0..3 {
        println!(
            "joint {}: RMS error {:.4} rad with the effects, {:.4} rad without",
            j + 1,
            st[j].rms_rad,
            sb[j].rms_rad
        );
        assert!(st[j].rms_rad < 0.05, "joint {}: {}", j + 1, st[j].rms_rad);
    }
    // The effects act: the run differs from the nominal arm's.
    let moved = run
        .rows
        .iter()
        .zip(&base.rows)
        .map(|(a, b)| (a.state.p_abs_pa[1][0] - b.state.p_abs_pa[1][0]).abs())
        .fold(0.0, f64::max);
    assert!(moved > 1e3, "joint 2 pressure differs by {moved} Pa only");
    // The recording holds the commands and the lagged channels; the open-loop replay applies
    // the same dead time and the same sensor path.
    let (rec, sim, worst) = replay(&arm, &run);
    let replayed = arm.measure_run(&sim.states, run.dt_s);
    let lagged = rec
        .channel(2, host_sim::io::recording::Channel::AngleDeg)
        .unwrap();
    let worst_reported = replayed
        .iter()
        .zip(lagged)
        .map(|(m, a)| (m[2].angle_deg - a).abs())
        .fold(0.0, f64::max);
    println!("replay: largest angle difference {worst:.3e} rad, joint 3 reported {worst_reported:.3e} deg");
    assert!(worst < 1e-5, "{worst}");
    assert!(worst_reported < 1e-3, "{worst_reported}");
    // Joint 3's recorded angle lags its true angle.
    let true_deg: Vec<f64> = run
        .rows
        .iter()
        .map(|r| r.state.angles_rad[2].to_degrees())
        .collect();
    let lag_err = true_deg
        .iter()
        .zip(lagged)
        .map(|(t, a)| (t - a).abs())
        .fold(0.0, f64::max);
    assert!(lag_err > 1e-3, "{lag_err}");
}

#[test]
fn without_the_gravity_feed_forward_the_arm_sags_out_of_range_and_all_joints_go_safe() {
    let arm = Arm3::load(arm3_plant()).unwrap();
    let mut s = ArmScenario::load(scenario("step.toml")).unwrap();
    s.scenario.duration_s = 2.0;
    let mut cfg = ArmConfig::reference(1000.0);
    cfg.gravity = false;
    let run = run_arm(&arm, &s, cfg).unwrap();
    let (t, code, joint) = run.first_fault().expect("the unsupported joint 2 faults");
    assert_eq!(joint, 2, "joint 2 carries the arm");
    assert_eq!(
        code,
        pam_firmware::safety::FaultCode::AngleOutOfRange.code(),
        "at {t} s"
    );
    // From the fault on, every joint's valves are closed (the Hold safe state).
    for r in run.rows.iter().filter(|r| r.t_s > t + 0.002) {
        for u in r.inputs {
            assert_eq!(
                [u.u_in1, u.u_ex1, u.u_in2, u.u_ex2],
                [0.0; 4],
                "t = {}",
                r.t_s
            );
        }
    }
    // With it, the same run holds every joint within 1 deg after 1.5 s.
    let ok = run_arm(&arm, &s, ArmConfig::reference(1000.0)).unwrap();
    assert!(ok.first_fault().is_none());
    for st in ok.tracking(1.5) {
        assert!(st.max_abs_rad < 1f64.to_radians(), "{st:?}");
    }
}

#[test]
fn the_mcu_rigid_body_model_matches_the_plant_over_the_workspace() {
    // The firmware's f32 feed-forward (config/arm3.toml through build.rs) against the
    // plant's own f64 mass matrix and gravity (host-sim/plants/arm3-seed001.toml).
    use rand::{Rng, SeedableRng};
    let arm = Arm3::load(arm3_plant()).unwrap();
    let links = pam_firmware::arm::constants::ARM3_LINKS;
    let mut rng = rand::rngs::StdRng::seed_from_u64(11);
    let mut worst = 0.0f64;
    for _ in 0..2000 {
        let q: [f64; 3] = std::array::from_fn(|_| rng.random_range(-1.2..1.2));
        let a: [f64; 3] = std::array::from_fn(|_| rng.random_range(-5.0..5.0));
        let m = arm.links.mass_matrix(&q);
        let g = arm.links.gravity_torques_nm(&q);
        let (inertia, grav) =
            links.inertia_and_gravity_nm(&q.map(|x| x as f32), &a.map(|x| x as f32));
        for i in 0..3 {
            let want = (0..3).map(|j| m[(i, j)] * a[j]).sum::<f64>() + g[i];
            let got = (inertia[i] + grav[i]) as f64;
            let scale = 1.0 + want.abs();
            worst = worst.max((got - want).abs() / scale);
        }
    }
    println!("largest relative difference {worst:.2e}");
    assert!(worst < 1e-4, "{worst}");
}
