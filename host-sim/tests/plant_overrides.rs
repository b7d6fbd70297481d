//! Per-valve and per-muscle tables of the plant file (`[valve.inlet1]` .. `[valve.exhaust2]`,
//! `[muscle.m1]`, `[muscle.m2]`) in the plant's loop: an override that repeats the shared
//! table's value changes nothing (to the bit, open loop and closed loop), one that differs
//! changes exactly the valve or muscle it names, as the equations say; invalid values are
//! errors naming the table and the key.

mod common;
use common::*;

use host_sim::control::closed_loop::{run_with, Scenario};
use host_sim::sim::{simulate, SolverOptions};
use host_sim::{Plant, PlantState, ValveInputs};
use pam_firmware::tick::ControllerConfig;

const OPTS: SolverOptions = SolverOptions {
    rtol: 1e-6,
    atol: 1e-6,
    max_steps_per_segment: 1_000_000,
};

/// Every per-valve and per-muscle table, each repeating the shared table's values.
const IDENTICAL: &str = "\
[valve.inlet1]\nsonic_conductance_m3_per_s_pa = 8.0e-9\ncritical_ratio = 0.433\n\
[valve.exhaust1]\nlaminar_ratio = 0.999\n\
[valve.inlet2]\nsonic_conductance_m3_per_s_pa = 8.0e-9\n\
[valve.exhaust2]\n\
[muscle.m1]\nradius_m = 0.01\nbraid_angle_deg = 25.3\nrest_length_m = 0.25\n\
[muscle.m2]\nend_factor = 1.446\ninitial_contraction = 0.14\n";

fn states(plant: &Plant, inputs: &[ValveInputs]) -> Vec<PlantState> {
    simulate(plant, inputs, 1e-3, &OPTS).unwrap().states
}

#[test]
fn an_override_that_repeats_the_shared_value_changes_nothing() {
    let nominal = plant_with("");
    let same = plant_with(IDENTICAL);
    let inputs = pulse_inputs(3000, 150);
    assert_eq!(states(&nominal, &inputs), states(&same, &inputs));
    let s = Scenario::load(root().join("scenarios/step.toml")).unwrap();
    let cfg = ControllerConfig::reference(s.scenario.tick_hz as f32);
    let a = run_with(&nominal, &s, cfg, &mut |_| {}).unwrap();
    let b = run_with(&same, &s, cfg, &mut |_| {}).unwrap();
    assert_eq!(a.rows.len(), b.rows.len());
    for (x, y) in a.rows.iter().zip(&b.rows) {
        assert_eq!(x.state, y.state);
        assert_eq!(x.command, y.command);
    }
}

#[test]
fn a_weaker_inlet_valve_slows_only_the_filling_of_its_muscle() {
    let nominal = plant_with("");
    let weak = plant_with("[valve.inlet1]\nsonic_conductance_m3_per_s_pa = 4.0e-9\n");
    let x = nominal.initial_state();
    let only = |u_in1, u_ex1, u_in2, u_ex2| ValveInputs {
        u_in1,
        u_ex1,
        u_in2,
        u_ex2,
    };
    // At rest (no volume change) dp/dt is proportional to the flow: inlet 1 at half its
    // conductance fills muscle 1 at half the rate; the other valves are as they were.
    let fill1 = only(1.0, 0.0, 0.0, 0.0);
    let (a, b) = (
        nominal.derivatives(&x, &fill1),
        weak.derivatives(&x, &fill1),
    );
    assert!(
        (b.p1_abs_pa / a.p1_abs_pa - 0.5).abs() < 1e-12,
        "{a:?} {b:?}"
    );
    for u in [
        only(0.0, 1.0, 0.0, 0.0),
        only(0.0, 0.0, 1.0, 0.0),
        only(0.0, 0.0, 0.0, 1.0),
    ] {
        assert_eq!(nominal.derivatives(&x, &u), weak.derivatives(&x, &u));
    }
    // Open loop: muscle 1 ends its first fill lower, and the joint turns less.
    let inputs = pulse_inputs(600, 150);
    let (sn, sw) = (states(&nominal, &inputs), states(&weak, &inputs));
    let k = 149;
    assert!(
        sw[k].p1_abs_pa < sn[k].p1_abs_pa - 5e3,
        "{:?} {:?}",
        sn[k],
        sw[k]
    );
    assert!(sw[k].angle_rad < sn[k].angle_rad);
    // The same through the shared key scales every valve: not the same run.
    let all = plant_with("")
        .valves
        .map(|v| v.sonic_conductance_m3_per_s_pa);
    assert_eq!(all, [8.0e-9; 4]);
    assert_eq!(
        weak.valves.map(|v| v.sonic_conductance_m3_per_s_pa),
        [4.0e-9, 8.0e-9, 8.0e-9, 8.0e-9]
    );
}

#[test]
fn an_exhaust_override_changes_the_venting_and_a_critical_ratio_override_the_flow_function() {
    let nominal = plant_with("");
    let p = plant_with("[valve.exhaust2]\nsonic_conductance_m3_per_s_pa = 1.6e-8\n[valve.inlet2]\ncritical_ratio = 0.3\n");
    let x = nominal.initial_state();
    let vent2 = ValveInputs {
        u_in1: 0.0,
        u_ex1: 0.0,
        u_in2: 0.0,
        u_ex2: 1.0,
    };
    let (a, b) = (nominal.derivatives(&x, &vent2), p.derivatives(&x, &vent2));
    assert!((b.p2_abs_pa / a.p2_abs_pa - 2.0).abs() < 1e-12);
    assert_eq!(a.p1_abs_pa, b.p1_abs_pa);
    assert_eq!(p.valves[2].critical_ratio, 0.3);
    assert_eq!(p.valves[2].sonic_conductance_m3_per_s_pa, 8.0e-9);
    assert_eq!(p.valves[0], nominal.valves[0]);
}

#[test]
fn a_muscle_override_changes_that_muscle_only() {
    let nominal = plant_with("");
    let p = plant_with("[muscle.m1]\nradius_m = 0.011\n");
    let x = nominal.initial_state();
    let (fa, fb) = (nominal.tensions_n(&x), p.tensions_n(&x));
    // Tondu: the force scales with the radius squared.
    assert!((fb[0] / fa[0] - 1.21).abs() < 1e-9, "{fa:?} {fb:?}");
    assert_eq!(fa[1], fb[1]);
    // A muscle 2 that starts less contracted pulls harder at angle 0: the joint turns.
    let q = plant_with("[muscle.m2]\ninitial_contraction = 0.12\n");
    let chi = q.joint.contractions(0.0);
    assert_eq!(chi, [0.14, 0.12]);
    let inputs = vec![ValveInputs::CLOSED; 200];
    let s = states(&q, &inputs);
    assert!(s[199].angle_rad < -1e-3, "{:?}", s[199]);
    // A longer muscle 1 contracts less per radian.
    let r = plant_with("[muscle.m1]\nrest_length_m = 0.3\n");
    let g = r.joint.contraction_rates(1.0);
    assert!((g[0] - 0.025 / 0.3).abs() < 1e-15 && (g[1] + 0.025 / 0.25).abs() < 1e-15);
}

#[test]
fn invalid_overrides_name_their_table_and_key() {
    let err = |extra: &str| {
        let text = format!("{}\n{extra}\n", nominal_text());
        host_sim::PlantConfig::from_toml_str(&text, "p.toml")
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default()
    };
    let e = err("[valve.inlet1]\ncritical_ratio = 1.5\n");
    assert!(e.contains("valve.inlet1.critical_ratio"), "{e}");
    assert!(e.contains("p.toml:"), "the line is named: {e}");
    let e = err("[valve.exhaust2]\nsonic_conductance_m3_per_s_pa = 8.0\n");
    assert!(
        e.contains("valve.exhaust2.sonic_conductance_m3_per_s_pa"),
        "{e}"
    );
    let e = err("[valve.exhaust2]\nconductance = 8.0e-9\n");
    assert!(e.contains("conductance"), "{e}");
    let e = err("[valve.inlet3]\nsonic_conductance_m3_per_s_pa = 8.0e-9\n");
    assert!(e.contains("inlet3"), "{e}");
    let e = err("[muscle.m2]\nradius_m = 5.0\n");
    assert!(e.contains("muscle.m2.radius_m"), "{e}");
    let e = err("[muscle.m1]\ninitial_contraction = 0.3\n");
    assert!(e.contains("muscle.m1.initial_contraction"), "{e}");
    let e = err("[muscle.m1]\nbraid_angle_deg = 0.44\n");
    assert!(e.contains("muscle.m1.braid_angle_deg"), "{e}");
}

#[test]
fn identify_fits_a_key_of_one_valve_into_its_own_table() {
    // The reference file has no [valve.inlet1]: the key starts from the [valve] value it
    // inherits, and the fitted file gets the table (a valid plant file, the fit in it).
    let dir = std::env::temp_dir().join(format!("plant_overrides_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("fitted.toml");
    let _ = std::fs::remove_file(&out);
    run_ok(&[
        &"identify",
        &"plant",
        &"--plant",
        &plant(),
        &"--recording",
        &fixture("pulses_nominal.csv"),
        &"--params",
        &"valve.inlet1.sonic_conductance_m3_per_s_pa,muscle.m2.radius_m",
        &"--out",
        &out,
    ]);
    let cfg = host_sim::PlantConfig::load(&out).unwrap_or_else(|e| panic!("{e}"));
    let c = cfg.valve.of(0).sonic_conductance_m3_per_s_pa;
    assert!((c / 8.0e-9 - 1.0).abs() < 1e-3, "{c}");
    assert!(cfg.valve.inlet1.is_some() && cfg.valve.exhaust1.is_none());
    let r = cfg.muscle.of(1).radius_m;
    assert!((r / 0.01 - 1.0).abs() < 1e-3, "{r}");
    assert!(cfg.muscle.m2.is_some() && cfg.muscle.m1.is_none());
}
