//! Plant TOML: the nominal files load unchanged; unknown or missing keys are errors naming
//! the key and the file; effects tables switch on model extensions.

mod common;
use common::*;

use host_sim::plant::PlantState;
use host_sim::{Plant, PlantConfig, ValveInputs};

/// The reference plant file's text with `extra` (TOML) appended.
fn with_nominal(extra: &str) -> String {
    format!("{}\n{extra}", nominal_text())
}

fn load_err(text: &str) -> String {
    parse_error(text, |t| PlantConfig::from_toml_str(t, "custom-plant.toml"))
}

#[test]
fn both_reference_files_load_unchanged_without_effects() {
    for f in ["reference-1dof.toml", "reference-1dof-loaded.toml"] {
        let cfg = PlantConfig::load(fixture(f)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(cfg.effects, Default::default(), "{f}");
    }
    let n = PlantConfig::load(fixture("reference-1dof.toml")).unwrap();
    let l = PlantConfig::load(fixture("reference-1dof-loaded.toml")).unwrap();
    assert!(l.joint.inertia_kgm2 > 10.0 * n.joint.inertia_kgm2);
}

#[test]
fn unknown_key_names_key_and_file() {
    let text = nominal_text().replace("end_factor = 1.446", "end_factor = 1.446\nend_fctor = 2.0");
    let e = load_err(&text);
    assert!(e.contains("end_fctor"), "{e}");
    assert!(e.contains("custom-plant.toml"), "{e}");
}

#[test]
fn unknown_table_names_key_and_file() {
    let text = with_nominal("[effects.braid_hysteresis]\nwidth_n = 5.0\n");
    let e = load_err(&text);
    assert!(e.contains("braid_hysteresis"), "{e}");
    assert!(e.contains("custom-plant.toml"), "{e}");
}

#[test]
fn missing_key_names_key_and_file() {
    let text: String = nominal_text()
        .lines()
        .filter(|l| !l.starts_with("inertia_kgm2"))
        .map(|l| format!("{l}\n"))
        .collect();
    let e = load_err(&text);
    assert!(e.contains("inertia_kgm2"), "{e}");
    assert!(e.contains("custom-plant.toml"), "{e}");
}

#[test]
fn missing_file_names_file() {
    let e = PlantConfig::load("/nonexistent/dir/plant-xyz.toml")
        .unwrap_err()
        .to_string();
    assert!(e.contains("plant-xyz.toml"), "{e}");
}

#[test]
fn invalid_value_names_key() {
    let text = nominal_text().replace("laminar_ratio = 0.999", "laminar_ratio = 1.5");
    let e = load_err(&text);
    assert!(e.contains("valve.laminar_ratio"), "{e}");
}

#[test]
fn initial_state_is_an_equilibrium_with_the_fixture_tension() {
    let plant = Plant::load(fixture("reference-1dof.toml")).unwrap();
    let x = plant.initial_state();
    let d = plant.derivatives(&x, &ValveInputs::CLOSED);
    assert_eq!(d, PlantState::default());
    let m = plant.measure(&x);
    assert!((m.p1_kpa - 550.0).abs() < 1e-9 && (m.p2_kpa - 550.0).abs() < 1e-9);
    // Row 0 of the conformance fixtures: f1_n = f2_n = 529.601003.
    assert!((m.f1_n - 529.601003).abs() < 1e-5, "{}", m.f1_n);
    assert_eq!(m.f1_n, m.f2_n);
}

#[test]
fn effects_tables_switch_on_friction_and_sensor_calibration() {
    let text = format!(
        "{}\n[effects.joint_friction]\ncoulomb_nm = 0.2\nbreakaway_nm = 0.3\n\
         stribeck_velocity_rad_s = 0.1\nviscous_nm_s_per_rad = 0.05\nsmoothing_velocity_rad_s = 0.01\n\
         [effects.sensor.angle_deg]\noffset = 1.5\ngain = 2.0\n",
        nominal_text()
    );
    let cfg =
        PlantConfig::from_toml_str(&text, "with-effects.toml").unwrap_or_else(|e| panic!("{e}"));
    let plant = Plant::from_config(&cfg);
    let nominal = plant_with("");

    // Friction decelerates a joint moving at equal pressures.
    let mut x = plant.initial_state();
    x.velocity_rad_s = 1.0;
    let with = plant.derivatives(&x, &ValveInputs::CLOSED).velocity_rad_s;
    let without = nominal.derivatives(&x, &ValveInputs::CLOSED).velocity_rad_s;
    let j = cfg.joint.inertia_kgm2;
    let expected_torque = -(0.2 + 0.1 * (-100.0f64).exp()) * (100.0f64).tanh() - 0.05;
    assert!(((with - without) * j - expected_torque).abs() < 1e-9);

    // Sensor calibration only changes the measurement.
    let x0 = plant.initial_state();
    assert_eq!(plant.measure(&x0).angle_deg, 1.5);
    let mut x1 = x0;
    x1.angle_rad = 1f64.to_radians();
    assert!((plant.measure(&x1).angle_deg - 3.5).abs() < 1e-12);
    assert_eq!(plant.measure(&x1).p1_kpa, nominal.measure(&x1).p1_kpa);

    // enabled = false switches an effect off without deleting its table.
    let off = text.replace("coulomb_nm = 0.2", "enabled = false\ncoulomb_nm = 0.2");
    let p_off = Plant::from_config(&PlantConfig::from_toml_str(&off, "off.toml").unwrap());
    assert_eq!(
        p_off.derivatives(&x, &ValveInputs::CLOSED).velocity_rad_s,
        without
    );
}

#[test]
fn leakage_and_gravity_act_on_the_right_hand_side() {
    let text = format!(
        "{}\n[effects.leakage]\nsonic_conductance_m3_per_s_pa = 1.0e-11\n\
         [effects.gravity]\nmass_kg = 1.0\ncom_distance_m = 0.1\nhanging_angle_rad = 0.0\n",
        nominal_text()
    );
    let plant = Plant::from_config(&PlantConfig::from_toml_str(&text, "e.toml").unwrap());
    let mut x = plant.initial_state();
    let d = plant.derivatives(&x, &ValveInputs::CLOSED);
    assert!(
        d.p1_abs_pa < 0.0 && d.p2_abs_pa < 0.0,
        "leak lowers the pressures: {d:?}"
    );
    x.angle_rad = 0.5;
    x.p1_abs_pa = x.p2_abs_pa; // same pressures; remove the spring torque difference
    let nominal = plant_with("");
    let dg = plant.derivatives(&x, &ValveInputs::CLOSED).velocity_rad_s
        - nominal.derivatives(&x, &ValveInputs::CLOSED).velocity_rad_s;
    let expected = -9.80665 * 0.1 * 0.5f64.sin() / 0.014;
    assert!((dg - expected).abs() < 1e-9, "{dg} vs {expected}");
}

#[test]
fn polytropic_exponent_scales_the_pressure_rate() {
    let text = with_nominal("[effects.polytropic]\nexponent = 1.4\n");
    let plant = Plant::from_config(&PlantConfig::from_toml_str(&text, "p.toml").unwrap());
    let nominal = plant_with("");
    let u = ValveInputs {
        u_in1: 1.0,
        u_ex2: 0.5,
        ..ValveInputs::CLOSED
    };
    let mut x = plant.initial_state();
    x.velocity_rad_s = 0.3;
    let a = plant.derivatives(&x, &u);
    let b = nominal.derivatives(&x, &u);
    assert!((a.p1_abs_pa - 1.4 * b.p1_abs_pa).abs() < 1e-9 * b.p1_abs_pa.abs());
    assert!((a.p2_abs_pa - 1.4 * b.p2_abs_pa).abs() < 1e-9 * b.p2_abs_pa.abs());
    assert_eq!(a.velocity_rad_s, b.velocity_rad_s);
    let bad = text.replace("exponent = 1.4", "exponent = 0.0");
    let e = PlantConfig::from_toml_str(&bad, "p.toml")
        .unwrap_err()
        .to_string();
    assert!(e.contains("effects.polytropic.exponent"), "{e}");
}

#[test]
fn valve_dead_time_delays_the_inputs_by_whole_and_fractional_samples() {
    use host_sim::sim::{simulate, SolverOptions};
    let text = with_nominal("[effects.valve_dead_time]\ndelay_s = 0.003\n");
    let delayed = Plant::from_config(&PlantConfig::from_toml_str(&text, "d.toml").unwrap());
    let nominal = plant_with("");
    let dt = 0.001;
    let mut u = vec![ValveInputs::CLOSED; 40];
    for v in &mut u[5..25] {
        v.u_in1 = 1.0;
        v.u_ex2 = 1.0;
    }
    let opts = SolverOptions::default();
    let a = simulate(&delayed, &u, dt, &opts).unwrap().states;
    let b = simulate(&nominal, &u, dt, &opts).unwrap().states;
    // The delayed run is the nominal run shifted by 3 samples (valves closed at rest = equilibrium).
    for (k, x) in a.iter().enumerate().take(8) {
        assert_eq!(*x, delayed.initial_state(), "sample {k}");
    }
    assert!(b[7].p1_abs_pa > b[5].p1_abs_pa);
    for k in 3..40 {
        let d = (a[k].p1_abs_pa - b[k - 3].p1_abs_pa).abs();
        assert!(d < 1.0, "sample {k}: {d} Pa");
    }
    // 2.5 samples: each opening is split over two periods, so the run lies between the runs
    // shifted by 2 and by 3 samples.
    let half = Plant::from_config(
        &PlantConfig::from_toml_str(&text.replace("0.003", "0.0025"), "d.toml").unwrap(),
    );
    let h = simulate(&half, &u, dt, &opts).unwrap().states;
    for k in 3..30 {
        let (x, y) = (b[k - 2].p1_abs_pa, b[k - 3].p1_abs_pa);
        let p = h[k].p1_abs_pa;
        assert!(
            p >= x.min(y) - 1.0 && p <= x.max(y) + 1.0,
            "sample {k}: {p} not within [{x}, {y}]"
        );
    }
}

#[test]
fn sensor_lag_filters_the_sampled_channels() {
    use host_sim::plant::PlantState;
    let text = with_nominal("[effects.sensor_lag]\nangle_time_constant_s = 0.01\n");
    let plant = Plant::from_config(&PlantConfig::from_toml_str(&text, "l.toml").unwrap());
    let x0 = plant.initial_state();
    let mut x1 = x0;
    x1.angle_rad = 1f64.to_radians();
    let states: Vec<PlantState> = std::iter::once(x0)
        .chain(std::iter::repeat_n(x1, 3))
        .collect();
    let m = plant.measure_series(&states, 0.001);
    let a = 1.0 - (-0.1f64).exp();
    assert_eq!(m[0].angle_deg, 0.0);
    assert!((m[1].angle_deg - a).abs() < 1e-12);
    assert!((m[2].angle_deg - (a + a * (1.0 - a))).abs() < 1e-12);
    // Pressures and forces have no lag configured.
    assert_eq!(m[1].f1_n, plant.measure(&x1).f1_n);
    let bad = text.replace(
        "angle_time_constant_s = 0.01",
        "angle_time_constant_s = -1.0",
    );
    error_naming(
        PlantConfig::from_toml_str(&bad, "l.toml"),
        &["effects.sensor_lag.angle_time_constant_s"],
    );
}

/// Values in the wrong unit are refused with the key, the range and the likely unit: the
/// chamber volume in cm^3, the effect tables' physical ranges.
#[test]
fn unit_slips_in_the_volume_and_the_effect_tables_are_refused() {
    let text = nominal_text().replace(
        "volume_poly_m3 = [79.0e-6, 48.0e-5, -18.0e-6, -11.0e-4]",
        "volume_poly_m3 = [79.0, 480.0, -18.0, -1100.0]",
    );
    assert!(text.contains("[79.0, 480.0"));
    let e = load_err(&text);
    for n in ["muscle.volume_poly_m3", "cylinder", "cm^3"] {
        assert!(e.contains(n), "`{n}` not in {e}");
    }
    for (table, key, needle) in [
        (
            "[effects.gravity]\nmass_kg = 1.0\ncom_distance_m = 200.0\nhanging_angle_rad = 0.0\n",
            "effects.gravity.com_distance_m",
            "mm typed?",
        ),
        (
            "[effects.gravity]\nmass_kg = 1.0\ncom_distance_m = 0.1\nhanging_angle_rad = 90.0\n",
            "effects.gravity.hanging_angle_rad",
            "degrees typed?",
        ),
        (
            "[effects.joint_friction]\ncoulomb_nm = 350.0\nbreakaway_nm = 400.0\n\
             stribeck_velocity_rad_s = 0.1\nviscous_nm_s_per_rad = 0.05\n\
             smoothing_velocity_rad_s = 0.01\n",
            "effects.joint_friction.coulomb_nm",
            "N mm typed?",
        ),
    ] {
        let e = load_err(&with_nominal(table));
        assert!(e.contains(key) && e.contains(needle), "{e}");
    }
}
