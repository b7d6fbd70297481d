//! The arm's diagnosis (`host_sim::diagnose::arm3`, `host-sim diagnose --plant arm3.toml`):
//! recordings of seed 001's arm with the firmware in the loop, made by the arm's own
//! right-hand side (not the 1-DOF plant the diagnosis replays), with encoder quantisation and
//! pressure noise added here; the diagnosis must say which joint departs and name what
//! departs there, and nothing on a nominal arm.

mod common;
use common::*;

use host_sim::control::arm3_loop::{run_arm, ArmScenario};
use host_sim::diagnose::arm3::{diagnose_arm, SupplyForm};
use host_sim::diagnose::DiagnoseOptions;
use host_sim::io::arm3::{Arm3Recording, JOINTS};
use host_sim::io::recording::Channel;
use host_sim::plant::arm3::{Arm3, Arm3Config};
use pam_firmware::arm::ArmConfig;
use rand::{rngs::StdRng, Rng, SeedableRng};
use rand_distr::StandardNormal;

/// The arm's sine scenario, shortened to `duration_s`.
fn scenario(duration_s: f64) -> ArmScenario {
    let text = std::fs::read_to_string(root().join("scenarios/arm3/sine.toml"))
        .unwrap()
        .replace("duration_s = 12.0", &format!("duration_s = {duration_s}"))
        .replace("start_s = 2.0", "start_s = 0.5");
    ArmScenario::from_toml_str(&text, "sine.toml").unwrap()
}

/// The nominal arm file with `extra` appended (concealed effects).
fn truth_config(extra: &str) -> Arm3Config {
    let text = std::fs::read_to_string(arm3_plant()).unwrap() + "\n" + extra;
    Arm3Config::from_toml_str(&text, "truth.toml").unwrap()
}

/// The nominal arm file with the values of `keys` in table `[table]` multiplied by `factor`,
/// and how many lines were changed.
fn scaled_text(table: &str, keys: &[&str], factor: f64) -> (String, usize) {
    let nominal_text = std::fs::read_to_string(arm3_plant()).unwrap();
    let mut text = String::new();
    let mut in_table = false;
    let mut replaced = 0;
    for line in nominal_text.lines() {
        if line.starts_with('[') {
            in_table = line.split('#').next().unwrap().trim() == format!("[{table}]");
        }
        let mut kv = line.splitn(2, '=');
        let k = kv.next().unwrap_or("").trim();
        if in_table && keys.contains(&k) {
            let v: f64 = kv
                .next()
                .unwrap()
                .split('#')
                .next()
                .unwrap()
                .trim()
                .parse()
                .unwrap();
            text.push_str(&format!("{k} = {:e}\n", factor * v));
            replaced += 1;
        } else {
            text.push_str(line);
            text.push('\n');
        }
    }
    (text, replaced)
}

/// The nominal arm file with the value of `key` in table `[table]` multiplied by `factor`
/// (a mis-set key of the plant file).
fn truth_scaled(table: &str, key: &str, factor: f64) -> Arm3Config {
    let (text, replaced) = scaled_text(table, &[key], factor);
    assert_eq!(replaced, 1, "[{table}] {key}");
    Arm3Config::from_toml_str(&text, "truth.toml").unwrap()
}

/// A closed-loop recording of the truth arm: angles quantised like an 8000-count encoder,
/// pressures with 0.5 kPa of white noise, no force channels.
fn recording(truth: &Arm3Config, seed: u64) -> Arm3Recording {
    recording_with(truth, seed, false)
}

/// [`recording`], with the muscle tensions (2 N of white noise) when `forces`.
fn recording_with(truth: &Arm3Config, seed: u64, forces: bool) -> Arm3Recording {
    let arm = Arm3::from_config(truth).unwrap();
    let run = run_arm(&arm, &scenario(8.0), ArmConfig::reference(1000.0)).unwrap();
    let mut rec = run.to_recording(&arm, "truth", "sine");
    let mut rng = StdRng::seed_from_u64(seed);
    let q_deg = 360.0 / 8000.0;
    for j in 0..JOINTS {
        for c in Channel::ALL {
            let Some(v) = rec.outputs[j][c.index()].as_mut() else {
                continue;
            };
            match c {
                Channel::AngleDeg => v.iter_mut().for_each(|x| *x = (*x / q_deg).round() * q_deg),
                Channel::P1Kpa | Channel::P2Kpa => v.iter_mut().for_each(|x| {
                    let g: f64 = rng.sample(StandardNormal);
                    *x += 0.5 * g
                }),
                Channel::F1N | Channel::F2N if forces => v.iter_mut().for_each(|x| {
                    let g: f64 = rng.sample(StandardNormal);
                    *x += 2.0 * g
                }),
                Channel::F1N | Channel::F2N => rec.outputs[j][c.index()] = None,
            }
        }
    }
    rec
}

fn diagnose(truth_extra: &str, seed: u64) -> host_sim::diagnose::arm3::ArmDiagnosis {
    diagnose_truth(&truth_config(truth_extra), seed)
}

fn diagnose_truth(truth: &Arm3Config, seed: u64) -> host_sim::diagnose::arm3::ArmDiagnosis {
    let nominal = Arm3Config::load(arm3_plant()).unwrap();
    let rec = recording(truth, seed);
    let d = diagnose_arm(&nominal, &rec, &DiagnoseOptions::default(), &|_, _, _| {}).unwrap();
    println!("{}", d.answer());
    println!("{}", residual_line(&nominal, &rec, &d, "case"));
    d
}

fn named(d: &host_sim::diagnose::arm3::ArmDiagnosis, joint: usize) -> Vec<String> {
    d.joints[joint - 1]
        .effects
        .iter()
        .map(|e| e.id.clone())
        .chain(
            d.joints[joint - 1]
                .recalibrated
                .iter()
                .map(|r| r.key.clone()),
        )
        .collect()
}

#[test]
fn a_nominal_arm_departs_nowhere() {
    let d = diagnose("", 5);
    assert_eq!(d.departing_joints(), Vec::<usize>::new());
}

/// Two angle columns swapped (joints 2 and 3): no joint is "explained" by invented sensor
/// calibrations; what is answered at all leaves no more than the arm's limit (the swap is
/// named before any search: both joints `not_this_plant`).
#[test]
fn swapped_angle_columns_are_not_explained_by_invented_calibrations() {
    let nominal = truth_config("");
    let mut rec = recording(&nominal, 7);
    let a = Channel::AngleDeg.index();
    let j2 = rec.outputs[1][a].take();
    rec.outputs[1][a] = rec.outputs[2][a].take();
    rec.outputs[2][a] = j2;
    let d = diagnose_arm(&nominal, &rec, &DiagnoseOptions::default(), &|_, _, _| {}).unwrap();
    for (i, j) in d.joints.iter().enumerate() {
        println!(
            "joint {}: {} {:?}",
            i + 1,
            j.verdict.as_str(),
            j.residual_x_noise
        );
        if j.verdict.as_str() == "explained" {
            assert!(
                j.residual_x_noise.0 <= host_sim::diagnose::arm3::MAX_RESIDUAL_X_NOISE,
                "joint {}: {:?}",
                i + 1,
                j.residual_x_noise
            );
        }
    }
    assert!(
        d.joints[1..]
            .iter()
            .any(|j| j.verdict.as_str() != "explained"),
        "{}",
        d.answer()
    );
}

/// An angle column recorded in radians, one with the other sign, two swapped: named on the
/// whole arm before any joint is searched (every joint's load comes from every angle).
#[test]
fn an_angle_in_radians_a_flipped_angle_and_swapped_angles_are_named_before_any_search() {
    let nominal = truth_config("");
    let rec = recording(&nominal, 8);
    let a = Channel::AngleDeg.index();
    let solver = DiagnoseOptions::default().solver;
    let hints =
        |r: &Arm3Recording| host_sim::diagnose::arm3::angle_unit_hints(&nominal, r, &solver);
    assert_eq!(hints(&rec), [None, None, None], "the recording as made");

    let mut rad = rec.clone();
    rad.outputs[1][a]
        .as_mut()
        .unwrap()
        .iter_mut()
        .for_each(|v| *v = v.to_radians());
    let h = hints(&rad);
    println!("{h:?}");
    assert!(h[0].is_none() && h[2].is_none(), "{h:?}");
    assert!(
        h[1].as_deref().unwrap().contains("angle_deg_j2")
            && h[1].as_deref().unwrap().contains("radians"),
        "{h:?}"
    );

    let mut flipped = rec.clone();
    flipped.outputs[0][a]
        .as_mut()
        .unwrap()
        .iter_mut()
        .for_each(|v| *v = -*v);
    let h = hints(&flipped);
    println!("{h:?}");
    assert!(h[0].as_deref().unwrap().contains("sign flipped"), "{h:?}");
    assert!(h[1].is_none() && h[2].is_none(), "{h:?}");

    let mut swapped = rec.clone();
    let j2 = swapped.outputs[1][a].take();
    swapped.outputs[1][a] = swapped.outputs[2][a].take();
    swapped.outputs[2][a] = j2;
    let h = hints(&swapped);
    println!("{h:?}");
    assert!(h[0].is_none(), "{h:?}");
    for j in [1, 2] {
        assert!(h[j].as_deref().unwrap().contains("when swapped"), "{h:?}");
    }

    // The diagnosis answers from the hint alone: every joint `not_this_plant`, the arm's
    // answer says why and names the joint.
    let d = diagnose_arm(&nominal, &rad, &DiagnoseOptions::default(), &|_, _, _| {}).unwrap();
    assert_eq!(d.angle_misrecorded, vec![2]);
    for j in &d.joints {
        assert_eq!(j.verdict.as_str(), "not_this_plant", "{}", d.answer());
    }
    assert!(
        d.answer().contains("no joint was diagnosed"),
        "{}",
        d.answer()
    );
    assert_eq!(d.to_json()["angle_misrecorded_joints"][0], 2);
}

/// No angle hint on a recording whose angles are as RECORDING.md says: the nominal arm (three
/// seeds) and every truth of the arm matrix (36 recordings, seeds the matrix does not use).
#[test]
fn no_angle_hint_on_the_nominal_arm_or_any_truth_of_the_matrix() {
    let nominal = truth_config("");
    let solver = DiagnoseOptions::default().solver;
    let mut truths = vec![("nominal".to_string(), nominal.clone()); 3];
    truths.extend(
        matrix_cases()
            .into_iter()
            .map(|(j, name, _, truth)| (format!("joint {j} {name}"), truth)),
    );
    for (k, (label, truth)) in truths.iter().enumerate() {
        let rec = recording(truth, 900 + k as u64);
        let h = host_sim::diagnose::arm3::angle_unit_hints(&nominal, &rec, &solver);
        assert_eq!(h, [None, None, None], "{label}");
    }
}

#[test]
fn a_leak_in_one_muscle_of_joint_2_is_named_there_and_nowhere_else() {
    let d = diagnose(
        "[joint2.effects.leakage]\nsonic_conductance_m3_per_s_pa = 6.0e-10\nmuscle = 2\n",
        6,
    );
    assert_eq!(d.departing_joints(), vec![2]);
    assert_eq!(named(&d, 2), vec!["leakage_muscle2".to_string()]);
    assert!(d.shared_supply.is_none());
    let j = &d.joints[1];
    for (ch, before) in &j.heldout_before {
        let after = j.heldout_after[ch];
        assert!(
            after >= *before - 0.5,
            "{ch}: held-out fit {before} -> {after}"
        );
    }
}

#[test]
fn the_cli_diagnoses_an_arm_recording_and_refuses_a_check_recording() {
    let dir = tempfile::tempdir().unwrap();
    let rec_path = dir.path().join("arm.csv");
    let truth = truth_config(
        "[joint3.effects.joint_friction]\ncoulomb_nm = 0.35\nbreakaway_nm = 0.35\n\
         stribeck_velocity_rad_s = 1.0\nviscous_nm_s_per_rad = 0.08\nsmoothing_velocity_rad_s = 0.01\n",
    );
    recording(&truth, 7).write(&rec_path).unwrap();
    let json = dir.path().join("arm.json");
    let diagnose = |rest: &[&dyn AsRef<std::ffi::OsStr>]| {
        let recording: [&dyn AsRef<std::ffi::OsStr>; 2] = [&"--recording", &rec_path];
        on_plant("diagnose", &arm3_plant(), &[&recording[..], rest].concat())
    };
    let stdout = ok(&diagnose(&[&"--json", &json]));
    println!("{stdout}");
    assert!(stdout.contains("Arm: joint 3 departs"), "{stdout}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["departing_joints"], serde_json::json!([3]));
    assert_eq!(v["joints"][2]["joint"], serde_json::json!(3));
    // A check recording is not supported with an arm plant: exit 2, no JSON written.
    let json2 = dir.path().join("arm2.json");
    assert_refused(
        &diagnose(&[&"--check", &rec_path, &"--json", &json2]),
        &["--check"],
        &json2,
    );
}

/// The concealed truths of the effect registry that act on one arm joint (all but the
/// supply, which is the arm's, the thermal chamber, refused on the arm, and the 1-DOF
/// joint's own gravity, inertia and end-stop truths), each on each joint, plus eq. 7's own friction terms three times larger than the file says (a
/// mis-set value of another functional form than the candidate's Coulomb + viscous).
/// Prints the table and the rates (`cargo test --release -p host-sim --test arm3_diagnose
/// -- --ignored --nocapture`, about 8 minutes each).
#[test]
#[ignore]
fn every_arm_truth_on_every_joint_from_angles_and_pressures() {
    let (effects, n) = matrix(false);
    assert!(effects * 10 >= n * 6, "{effects}/{n}");
}

/// [`every_arm_truth_on_every_joint_from_angles_and_pressures`] with force sensors on every
/// muscle.
#[test]
#[ignore]
fn every_arm_truth_on_every_joint_with_force_sensors() {
    let (effects, n) = matrix(true);
    // Measured 28/36: with force channels a lagging sensor on joints 2 and 3 is left
    // unexplained in three of six cases (docs/arm3.md).
    assert!(effects * 4 >= n * 3, "{effects}/{n}");
}

/// Per joint: the verdict, the nominal model's TRAIN residual on its worst channel in times
/// that channel's noise, the best answer's, and the nominal cost over the noise's (the
/// figures the verdict reads).
fn residual_line(
    nominal: &Arm3Config,
    rec: &Arm3Recording,
    d: &host_sim::diagnose::arm3::ArmDiagnosis,
    label: &str,
) -> String {
    let mut s = format!("residuals {label}:");
    for (i, j) in d.joints.iter().enumerate() {
        let r = host_sim::diagnose::arm3::joint_recording(nominal, rec, i);
        let spread: [f64; 5] = std::array::from_fn(|c| {
            r.outputs[c].as_ref().map_or(1.0, |y| {
                let m = y.iter().sum::<f64>() / y.len() as f64;
                (y.iter().map(|v| (v - m).powi(2)).sum::<f64>() / y.len() as f64).sqrt()
            })
        });
        let nom =
            host_sim::diagnose::verdict::residual_over_noise(&j.fit_before, &j.noise, &spread);
        s.push_str(&format!(
            " j{} {} nominal {:.1}x ({}) best {:.1}x ({}) cost/noise {:.2};",
            i + 1,
            j.verdict.as_str(),
            nom.0,
            nom.1,
            j.residual_x_noise.0,
            j.residual_x_noise.1,
            j.nominal_cost / j.noise_cost,
        ));
    }
    s
}

/// Runs the matrix and checks that at least 9 cases of 10 name the right joint (with or without
/// force channels); returns (cases with the right effect, cases).
/// The arm matrix's truths: per joint (1-based) every effect of the registry concealed on that
/// joint, and eq. 7's friction x3 there: (joint, case name, expected answer, truth).
fn matrix_cases() -> Vec<(usize, String, String, Arm3Config)> {
    let registry = [
        "valve_delay",
        "sensor_lag",
        "sensor_lag_one_pressure",
        "joint_friction",
        "joint_friction_stribeck",
        "leakage",
        "leakage_one_muscle",
        "muscle_hysteresis",
        "polytropic",
        "sensor_offset",
        "sensor_gain_one_channel",
    ];
    let mut all = Vec::new();
    for joint in 1..=JOINTS {
        for name in registry {
            let toml = host_sim::diagnose::synth::effect_toml(name, 1e-3)
                .unwrap()
                .replace("[effects.", &format!("[joint{joint}.effects."));
            all.push((
                joint,
                name.to_string(),
                host_sim::diagnose::synth::expected_id(name).to_string(),
                truth_config(&toml),
            ));
        }
        // eq. 7 x3 on this joint: scale f_c and f_d in its [jointN.friction] table.
        let (text, replaced) = scaled_text(
            &format!("joint{joint}.friction"),
            &["coulomb_nm", "viscous_nm_s_per_rad"],
            3.0,
        );
        assert_eq!(replaced, 2, "joint{joint}.friction");
        all.push((
            joint,
            "eq7_friction_x3".into(),
            "joint_friction".into(),
            Arm3Config::from_toml_str(&text, "truth.toml").unwrap(),
        ));
    }
    all
}

fn matrix(forces: bool) -> (usize, usize) {
    let nominal_text = std::fs::read_to_string(arm3_plant()).unwrap();
    let nominal = Arm3Config::from_toml_str(&nominal_text, "arm3-seed001.toml").unwrap();
    let mut rows = Vec::new();
    // ARM_MATRIX_SEED_BASE: other noise seeds than the ones the limits were read off (100).
    let mut seed: u64 = std::env::var("ARM_MATRIX_SEED_BASE")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(100);
    let all = matrix_cases();
    for joint in 1..=JOINTS {
        let cases = all
            .iter()
            .filter(|c| c.0 == joint)
            .map(|c| (c.1.clone(), c.2.clone(), c.3.clone()));
        for (name, expected, truth) in cases {
            seed += 1;
            let rec = recording_with(&truth, seed, forces);
            let d =
                diagnose_arm(&nominal, &rec, &DiagnoseOptions::default(), &|_, _, _| {}).unwrap();
            let departing = d.departing_joints();
            let got = named(&d, joint);
            println!(
                "{}",
                residual_line(&nominal, &rec, &d, &format!("joint {joint} {name}"))
            );
            let joint_ok = departing == vec![joint];
            let effect_ok = joint_ok && got.first().map(String::as_str) == Some(expected.as_str());
            rows.push((joint, name, expected, departing, got, joint_ok, effect_ok));
        }
    }
    println!(
        "| joint | truth | expected | departing joints | named on the joint | joint | effect |"
    );
    println!("|---|---|---|---|---|---|---|");
    for (j, name, exp, dep, got, jo, eo) in &rows {
        println!(
            "| {j} | {name} | {exp} | {dep:?} | {} | {} | {} |",
            got.join(", "),
            if *jo { "right" } else { "WRONG" },
            if *eo { "right" } else { "WRONG" }
        );
    }
    let n = rows.len();
    let joints_right = rows.iter().filter(|r| r.5).count();
    let effects_right = rows.iter().filter(|r| r.6).count();
    println!(
        "force channels: {forces}; joint right {joints_right}/{n}, effect right {effects_right}/{n}"
    );
    assert!(joints_right * 10 >= n * 9, "joint right {joints_right}/{n}");
    (effects_right, n)
}

/// The shared supply: a static line resistance (or a tank) on the arm's `[effects.supply_drop]`.
/// Every joint that inflates sees it; the arm-level stage names one supply for all six muscles.
fn shared_supply_case(truth: &str, seed: u64) -> host_sim::diagnose::arm3::SharedSupply {
    shared_supply_of(&truth_config(truth), seed)
}

fn shared_supply_of(truth: &Arm3Config, seed: u64) -> host_sim::diagnose::arm3::SharedSupply {
    let d = diagnose_truth(truth, seed);
    assert!(
        d.answer().contains("The shared supply departs"),
        "{}",
        d.answer()
    );
    let sup = d.shared_supply.expect("the shared supply is named");
    assert!(sup.named_by.len() >= 2, "{sup:?}");
    for (ch, before, after) in &sup.heldout_fits {
        assert!(after >= &(before - 0.5), "{ch}: {before} -> {after}");
        // Never an answer that does not reproduce the held-out data.
        assert!(*after >= 50.0, "{ch}: {before} -> {after}");
    }
    sup
}

#[test]
fn a_sagging_supply_shared_by_the_six_muscles_is_named_as_the_arm_supply() {
    let sup = shared_supply_case(
        "[effects.supply_drop]\nmodel = \"static\"\nresistance_pa_s_per_m3 = 3.0e6\n",
        204,
    );
    let r = sup
        .form
        .supply_drop()
        .and_then(|t| t.resistance_pa_s_per_m3)
        .expect("the static form");
    println!("fitted line resistance {r:.4e} Pa s/m^3 (truth 3e6)");
    assert!((r / 3.0e6 - 1.0).abs() < 0.05, "{r}");
}

/// The tank form (not the form the matrix' CI case uses): named as the arm's supply, in
/// whichever form fits better (`cargo test --release -p host-sim --test arm3_diagnose --
/// --ignored tank --nocapture`).
#[test]
#[ignore]
fn a_supply_tank_shared_by_the_six_muscles_is_named_as_the_arm_supply() {
    let sup = shared_supply_case(
        "[effects.supply_drop]\nmodel = \"reservoir\"\ntank_volume_m3 = 2.0e-3\n\
         feed_conductance_m3_per_s_pa = 4.0e-8\n",
        205,
    );
    println!("{:?}", sup.form);
}

/// A supply that holds another pressure than the plant file says (750 kPa, not 600; a lower
/// one would be below the file's initial pressures of 550 kPa): every joint that inflates
/// names another supply pressure; the arm level names the one supply pressure, with the
/// whole-arm replay's held-out fits before and after.
#[test]
fn a_supply_at_another_pressure_is_named_once_for_the_arm_with_its_value() {
    let sup = shared_supply_of(&truth_scaled("environment", "supply_gauge_pa", 1.25), 206);
    match sup.form {
        SupplyForm::Pressure {
            nominal_gauge_pa,
            fitted_gauge_pa,
        } => {
            println!("supply {nominal_gauge_pa:.4e} -> {fitted_gauge_pa:.4e} Pa (truth 7.5e5)");
            assert!(
                (fitted_gauge_pa / 7.5e5 - 1.0).abs() < 0.01,
                "{fitted_gauge_pa}"
            );
        }
        f => panic!("named {f:?}, not the supply pressure"),
    }
}

/// The arm has no thermal chamber (its plant refuses one on a joint), so no joint's pool
/// offers it; every other candidate of the 1-DOF pool stays (the supply drop included: the
/// joint's view of the arm's supply).
/// A rig whose supply is 30 % below the file's and whose muscles start 170 kPa lower than the
/// file's initial pressures (a user who edits both keys): the recording starts away from the
/// file's start, and the arm is still answered with one supply pressure.
#[test]
fn a_lower_supply_with_other_initial_pressures_is_named_once_for_the_arm() {
    let (text, replaced) = scaled_text("environment", &["supply_gauge_pa"], 0.7);
    assert_eq!(replaced, 1);
    let start = "_gauge_pa = 550000.0";
    assert_eq!(text.matches(start).count(), 6, "the six initial pressures");
    let text = text.replace(start, "_gauge_pa = 380000.0");
    let truth = Arm3Config::from_toml_str(&text, "truth.toml").unwrap();
    match shared_supply_of(&truth, 207).form {
        SupplyForm::Pressure {
            fitted_gauge_pa, ..
        } => assert!(
            (fitted_gauge_pa / 4.2e5 - 1.0).abs() < 0.01,
            "{fitted_gauge_pa}"
        ),
        f => panic!("named {f:?}, not the supply pressure"),
    }
}

#[test]
fn the_arm_candidate_pool_leaves_out_only_what_the_arm_cannot_simulate() {
    let cfg = Arm3Config::load(arm3_plant()).unwrap();
    let arm = Arm3::from_config(&cfg).unwrap();
    for j in 0..JOINTS {
        let plant = host_sim::diagnose::arm3::joint_plant_config(&cfg, &arm.initial, j, 1.0);
        let out = host_sim::diagnose::arm3::candidates_the_arm_cannot_simulate(&plant);
        // The thermal chamber, and the keys of one valve or one muscle (the arm file has one
        // muscle table per joint and one valve table for all).
        let parts: Vec<String> = host_sim::diagnose::recalibrate::keys()
            .iter()
            .map(|k| k.key.to_string())
            .filter(|k| host_sim::diagnose::recalibrate::is_part_key(k))
            .collect();
        let (heat, rest): (Vec<String>, Vec<String>) =
            out.into_iter().partition(|id| id == "heat_transfer");
        assert_eq!(heat, vec!["heat_transfer".to_string()], "joint {}", j + 1);
        assert_eq!(rest, parts, "joint {}", j + 1);
        // And the arm plant indeed refuses a thermal chamber on that joint.
        let text = std::fs::read_to_string(arm3_plant()).unwrap()
            + &format!(
                "\n[joint{}.effects.thermal_chamber]\nheat_transfer_w_per_k = 1.0\n",
                j + 1
            );
        let err = Arm3Config::from_toml_str(&text, "arm.toml").unwrap_err();
        assert!(err.to_string().contains("thermal_chamber"), "{err}");
    }
}

/// Joint 2's muscle radius 30 % larger than the file says: a key the arm can have, answered
/// by that key on joint 2, never by an effect the arm cannot simulate.
#[test]
fn a_wrong_muscle_radius_on_joint_2_is_not_answered_with_a_thermal_chamber() {
    let d = diagnose_truth(&truth_scaled("joint2.muscle", "radius_m", 1.3), 207);
    for j in 1..=JOINTS {
        assert!(
            !named(&d, j).iter().any(|id| id == "heat_transfer"),
            "joint {j}: {:?}",
            named(&d, j)
        );
    }
    // Joint 3 is as the file says: it starts elsewhere (joint 2 settles at another angle)
    // but is not called departing for that.
    assert_eq!(d.departing_joints(), vec![2]);
    assert_eq!(
        named(&d, 2).first().map(String::as_str),
        Some("muscle.radius_m"),
        "{:?}",
        named(&d, 2)
    );
}

/// Joint 3's muscle damping twice what the file says: a 2.6 % angle error on noise-free
/// data, hidden in the summed cost by the pressures' noise. The joint departs (each channel
/// is judged against its own noise) and nothing else does.
#[test]
fn twice_the_muscle_damping_on_joint_3_is_noticed_there() {
    let d = diagnose_truth(&truth_scaled("joint3.muscle", "damping_m2s", 2.0), 208);
    assert_eq!(d.departing_joints(), vec![3]);
}
