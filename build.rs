//! Build script of the firmware crate.
//!
//! 1. Generates `constants.rs` (in OUT_DIR) from `config/force_law.toml`,
//!    `config/torque_model.toml`, `config/joint_geometry.toml`, `config/plant_constants.toml`
//!    and `config/controller.toml`, so identified constants flow from the identification
//!    tools (`host-sim calibrate`) into the firmware without being copied by hand.
//! 2. For bare-metal targets only (`target_os = "none"`), passes the linker scripts to
//!    the binaries.

use std::{env, fs, path::PathBuf};

/// `[("prefix.field", s.field), ...]`: fields of `s` with their TOML keys (the prefix is
/// optional), for the checks and the generated constants.
macro_rules! keyed {
    ($prefix:literal, $s:expr; $($field:ident),+ $(,)?) => {
        [$((concat!($prefix, stringify!($field)), $s.$field)),+]
    };
    ($s:expr; $($field:ident),+ $(,)?) => {
        [$((stringify!($field), $s.$field)),+]
    };
}

// Shared with the library (`crate::fixed_point::prescale`): the same f64 pre-scaling runs here
// for the compile-time constants and in `FixedForceLaw::from_params` at run time.
#[allow(dead_code)]
#[path = "src/fixed_point/prescale.rs"]
mod prescale;

// The board's set-point scenario: parsing shared with tests/board_profile.rs.
#[path = "src/build/board_profile.rs"]
mod board_profile_spec;

// The 3-DOF arm's per-joint constants (config/arm3.toml).
#[path = "src/build/arm3.rs"]
mod arm3;

// The pressure loop's inverse thermodynamic feed-forward (config/pressure_ff.toml).
#[path = "src/build/pressure_ff.rs"]
mod pressure_ff;

// The hybrid model's learned volume (config/volume.toml).
#[path = "src/build/volume_fnn.rs"]
mod volume_fnn;

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct ForceFile {
    force_law: ForceLaw,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct ForceLaw {
    c: [f64; 10],
    p_gauge_max_pa: f64,
    stretch_min: f64,
    stretch_max: f64,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct TorqueFile {
    torque_model: TorqueModel,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct TorqueModel {
    a_n_per_m_rad: f64,
    b_m2: f64,
    c_nms3_per_rad3: f64,
    d_nms_per_rad: f64,
    sprocket_radius_m: f64,
    p0_gauge_pa: f64,
    dp_max_pa: f64,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct GeometryFile {
    joint_geometry: Geometry,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Geometry {
    sprocket_radius_m: f64,
    rest_length_m: f64,
    initial_contraction: f64,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct PlantFile {
    joint: PlantJoint,
    muscle: PlantMuscle,
    environment: PlantEnvironment,
    valve: PlantValve,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct PlantJoint {
    inertia_kgm2: f64,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct PlantMuscle {
    p_max_gauge_pa: f64,
    volume_poly_m3: [f64; 4],
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct PlantEnvironment {
    p_atm_pa: f64,
    supply_gauge_pa: f64,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct PlantValve {
    sonic_conductance_m3_per_s_pa: f64,
    critical_ratio: f64,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct ControllerFile {
    position: PositionGains,
    torque: TorqueGains,
    pressure: PressureGains,
    feedforward: FeedforwardGains,
    rates: LoopRates,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct LoopRates {
    outer_period_ticks: u16,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct PositionGains {
    kp_nm_per_rad: f64,
    ki_nm_per_rad_s: f64,
    kd_nm_s_per_rad: f64,
    i_limit_nm: f64,
    out_limit_nm: f64,
    velocity_cutoff_hz: f64,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct TorqueGains {
    kp: f64,
    ki_per_s: f64,
    corr_limit_nm: f64,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct PressureGains {
    full_opening_error_pa: f64,
    ki_per_pa_s: f64,
    deadband_pa: f64,
    i_limit: f64,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct FeedforwardGains {
    rate_weight: f64,
    cutoff_hz: f64,
    limit_nm: f64,
}

/// Panics with `file: field = value must be ...` unless `ok`.
fn check(ok: bool, file: &str, field: &str, value: f64, must: &str) {
    assert!(ok, "{file}: {field} = {value} must be {must}");
}

/// Every value must be finite and >= 0.
fn check_non_negative(file: &str, fields: &[(&str, f64)]) {
    for &(field, v) in fields {
        check(v.is_finite() && v >= 0.0, file, field, v, "finite and >= 0");
    }
}

/// The ISO 6358 valve constants of a `[valve]` table.
fn check_valve(file: &str, sonic_conductance_m3_per_s_pa: f64, critical_ratio: f64) {
    let c = sonic_conductance_m3_per_s_pa;
    check(
        c > 0.0,
        file,
        "valve.sonic_conductance_m3_per_s_pa",
        c,
        "> 0",
    );
    let b = critical_ratio;
    check(
        (0.0..1.0).contains(&b),
        file,
        "valve.critical_ratio",
        b,
        "in 0..1",
    );
}

/// The text of a config file (the build re-runs when it changes).
fn read_text(path: &str) -> String {
    println!("cargo:rerun-if-changed={path}");
    fs::read_to_string(path).unwrap_or_else(|e| panic!("{path}: cannot read: {e}"))
}

/// A config file, parsed.
fn read<T: serde::de::DeserializeOwned>(path: &str) -> T {
    parse(path, &read_text(path))
}

/// The TOML `text` of the config file `path`, parsed.
fn parse<T: serde::de::DeserializeOwned>(path: &str, text: &str) -> T {
    toml::from_str(text).unwrap_or_else(|e| panic!("{path}: {e}"))
}

/// The f32 constant the firmware uses, widened back to f64 (the fixed-point model is pre-scaled
/// from exactly the values of the f32 model).
fn f32w(x: f64) -> f64 {
    x as f32 as f64
}

/// Formats an f64 as an f32 literal that round-trips.
fn lit(x: f64) -> String {
    assert!(x.is_finite(), "non-finite constant {x}");
    format!("{:?}_f32", x as f32)
}

/// [`lit`] of each value.
fn lits<const N: usize>(fields: [(&'static str, f64); N]) -> Vec<(&'static str, String)> {
    fields.into_iter().map(|(k, x)| (k, lit(x))).collect()
}

/// The Rust source of `pub const NAME: Type = Type { field: value, ... };`, one field a line.
fn const_struct(name: &str, ty: &str, fields: &[(&str, String)]) -> String {
    format!(
        "pub const {name}: {ty} = {};\n",
        struct_literal(ty, fields, "")
    )
}

/// `Type { field: value, ... }`, one field a line, the lines after the first indented by
/// `indent`.
fn struct_literal(ty: &str, fields: &[(&str, String)], indent: &str) -> String {
    let mut s = format!("{ty} {{\n");
    for (field, value) in fields {
        s += &format!("{indent}    {field}: {value},\n");
    }
    s + indent + "}"
}

/// `Type { field: value, ... }` on one line.
fn inline_struct(ty: &str, fields: &[(&str, String)]) -> String {
    format!("{ty} {{ {} }}", inline_fields(fields))
}

/// `field: value, ...`
fn inline_fields(fields: &[(&str, String)]) -> String {
    let fields: Vec<String> = fields.iter().map(|(f, v)| format!("{f}: {v}")).collect();
    fields.join(", ")
}

fn main() {
    println!("cargo:rerun-if-changed=src/fixed_point/prescale.rs");
    println!("cargo:rerun-if-changed=src/build/pressure_ff.rs");
    println!("cargo:rerun-if-changed=src/build/volume_fnn.rs");
    let force: ForceFile = read("config/force_law.toml");
    let torque: TorqueFile = read("config/torque_model.toml");
    let geometry: GeometryFile = read("config/joint_geometry.toml");
    let f = force.force_law;
    let t = torque.torque_model;
    let g = geometry.joint_geometry;
    check_model(&f, &t, &g);
    let plant: PlantFile = read("config/plant_constants.toml");
    let ctl: ControllerFile = read("config/controller.toml");
    check_plant_and_controller(&plant, &ctl);
    let src = model_constants(&f, &t, &g)
        + &plant_and_loop_constants(&plant, &ctl)
        + &fixed_point_constants(&f, &t, &ctl)
        + &pressure_ff::constants()
        + &volume_fnn::constants();
    let out = PathBuf::from(env::var("OUT_DIR").unwrap()).join("constants.rs");
    fs::write(&out, src).expect("write constants.rs");
    let arm = arm3::constants(&arm3::Reference {
        c: f.c,
        abcd: [t.a_n_per_m_rad, t.b_m2, t.c_nms3_per_rad3, t.d_nms_per_rad],
        r_m: g.sprocket_radius_m,
        l_m: g.rest_length_m,
    });
    let out = PathBuf::from(env::var("OUT_DIR").unwrap()).join("arm3_constants.rs");
    fs::write(&out, arm).expect("write arm3_constants.rs");

    sensor_trace(
        "tests/traces/qemu_sensor_trace.csv",
        1,
        "SENSOR_TRACE",
        "sensor_trace.rs",
    );
    sensor_trace(
        "tests/traces/arm3_sensor_trace.csv",
        3,
        "ARM3_SENSOR_TRACE",
        "arm3_sensor_trace.rs",
    );
    board_profile();
    link_args();
}

/// Stops the build when the force law, the torque model or the joint geometry is unusable
/// (the file and the field in the message).
fn check_model(f: &ForceLaw, t: &TorqueModel, g: &Geometry) {
    assert!(
        g.sprocket_radius_m > 0.0 && g.rest_length_m > 0.0,
        "config/joint_geometry.toml: sprocket_radius_m and rest_length_m must be > 0"
    );
    assert!(
        (0.0..0.5).contains(&g.initial_contraction),
        "config/joint_geometry.toml: initial_contraction must be in 0..0.5"
    );
    assert!(
        (g.sprocket_radius_m - t.sprocket_radius_m).abs() <= 1e-9 * g.sprocket_radius_m,
        "config/joint_geometry.toml: sprocket_radius_m = {} but config/torque_model.toml says {}",
        g.sprocket_radius_m,
        t.sprocket_radius_m
    );
    assert!(
        f.stretch_min < f.stretch_max,
        "config/force_law.toml: stretch_min >= stretch_max"
    );
    assert!(
        f.p_gauge_max_pa > 0.0,
        "config/force_law.toml: p_gauge_max_pa must be > 0"
    );
    assert!(
        t.sprocket_radius_m > 0.0,
        "config/torque_model.toml: sprocket_radius_m must be > 0"
    );
    assert!(
        t.dp_max_pa > 0.0,
        "config/torque_model.toml: dp_max_pa must be > 0"
    );
    assert!(
        t.b_m2 != 0.0,
        "config/torque_model.toml: b_m2 must not be 0 (the model could not be inverted)"
    );
}

/// Stops the build when a plant constant or a controller gain is out of its range (the
/// file, the field and the value in the message).
fn check_plant_and_controller(plant: &PlantFile, ctl: &ControllerFile) {
    const P: &str = "config/plant_constants.toml";
    let (j, m, e, v) = (
        &plant.joint,
        &plant.muscle,
        &plant.environment,
        &plant.valve,
    );
    for (field, x) in [
        ("joint.inertia_kgm2", j.inertia_kgm2),
        ("muscle.p_max_gauge_pa", m.p_max_gauge_pa),
        ("muscle.volume_poly_m3[0]", m.volume_poly_m3[0]),
        ("environment.p_atm_pa", e.p_atm_pa),
    ] {
        check(x > 0.0, P, field, x, "> 0");
    }
    let supply = e.supply_gauge_pa;
    check(
        supply >= 0.0,
        P,
        "environment.supply_gauge_pa",
        supply,
        ">= 0",
    );
    check_valve(P, v.sonic_conductance_m3_per_s_pa, v.critical_ratio);
    const C: &str = "config/controller.toml";
    check_non_negative(
        C,
        &keyed!("position.", ctl.position;
        kp_nm_per_rad, ki_nm_per_rad_s, kd_nm_s_per_rad, i_limit_nm, out_limit_nm,
        velocity_cutoff_hz),
    );
    check_non_negative(
        C,
        &keyed!("torque.", ctl.torque; kp, ki_per_s, corr_limit_nm),
    );
    check_non_negative(
        C,
        &keyed!("pressure.", ctl.pressure; ki_per_pa_s, deadband_pa, i_limit),
    );
    check_non_negative(
        C,
        &keyed!("feedforward.", ctl.feedforward; rate_weight, cutoff_hz, limit_nm),
    );
    assert!(
        (1..=10).contains(&ctl.rates.outer_period_ticks),
        "{C}: [rates] outer_period_ticks = {} must be in [1, 10]",
        ctl.rates.outer_period_ticks
    );
    check(
        ctl.pressure.full_opening_error_pa > 0.0,
        C,
        "pressure.full_opening_error_pa",
        ctl.pressure.full_opening_error_pa,
        "> 0",
    );
}

/// The generated joint geometry, force law and torque model (`constants.rs`, first part).
fn model_constants(f: &ForceLaw, t: &TorqueModel, g: &Geometry) -> String {
    let c: Vec<String> = f.c.iter().map(|&x| lit(x)).collect();
    let force_law = [
        vec![("c", format!("[{}]", c.join(", ")))],
        lits(keyed!(f; p_gauge_max_pa, stretch_min, stretch_max)),
    ]
    .concat();
    format!(
        "// @generated by build.rs from config/force_law.toml, config/torque_model.toml,\n\
         // config/joint_geometry.toml, config/plant_constants.toml and config/controller.toml.\n\
         // Do not edit: change the config file (each states where its numbers come from).\n\
         /// Joint geometry (config/joint_geometry.toml).\n\
         {}\
         /// Identified force-law constants (config/force_law.toml).\n\
         {}\
         /// Torque-model constants (config/torque_model.toml).\n\
         {}",
        const_struct(
            "JOINT_GEOMETRY",
            "crate::geometry::JointGeometry",
            &lits(keyed!(g; sprocket_radius_m, rest_length_m, initial_contraction)),
        ),
        const_struct("FORCE_LAW", "crate::force_law::ForceLawParams", &force_law),
        const_struct(
            "TORQUE_MODEL",
            "crate::torque_model::TorqueModelParams",
            &lits(
                keyed!(t; a_n_per_m_rad, b_m2, c_nms3_per_rad3, d_nms_per_rad,
                sprocket_radius_m, p0_gauge_pa, dp_max_pa)
            ),
        ),
    )
}

/// The generated plant constants and the default gains of the cascade's loops.
fn plant_and_loop_constants(plant: &PlantFile, ctl: &ControllerFile) -> String {
    let (pm, env_, val, pos, tq, pr, ff) = (
        &plant.muscle,
        &plant.environment,
        &plant.valve,
        &ctl.position,
        &ctl.torque,
        &ctl.pressure,
        &ctl.feedforward,
    );
    let vp: Vec<String> = pm.volume_poly_m3.iter().map(|&x| lit(x)).collect();
    let torque_loop = [
        lits(keyed!(tq; kp, ki_per_s, corr_limit_nm)),
        vec![("p_set_max_gauge_pa", "P_MUSCLE_MAX_GAUGE_PA".into())],
    ]
    .concat();
    let pressure_loop = [
        vec![(
            "kp_per_pa",
            format!("1.0 / {}", lit(pr.full_opening_error_pa)),
        )],
        lits(keyed!(pr; ki_per_pa_s, deadband_pa, i_limit)),
    ]
    .concat();
    let feedforward = [
        ("rate_weight", lit(ff.rate_weight)),
        ("inertia_kgm2", "JOINT_INERTIA_KGM2".into()),
        ("cutoff_hz", lit(ff.cutoff_hz)),
        ("limit_nm", lit(ff.limit_nm)),
    ];
    format!(
        "\
         // From config/plant_constants.toml.\n\
         /// Joint inertia [kg m^2] (config/plant_constants.toml [joint]).\n\
         pub const JOINT_INERTIA_KGM2: f32 = {};\n\
         /// Upper limit of every muscle pressure set-point, gauge [Pa] (config/plant_constants.toml [muscle]).\n\
         pub const P_MUSCLE_MAX_GAUGE_PA: f32 = {};\n\
         /// Atmospheric pressure [Pa] (config/plant_constants.toml [environment]).\n\
         pub const P_ATM_PA: f32 = {};\n\
         /// Supply pressure, gauge [Pa] (config/plant_constants.toml [environment]).\n\
         pub const SUPPLY_GAUGE_PA: f32 = {};\n\
         /// ISO 6358 sonic conductance [m^3/(s Pa)] (config/plant_constants.toml [valve]).\n\
         pub const VALVE_CONDUCTANCE_M3_PER_S_PA: f32 = {};\n\
         /// ISO 6358 critical pressure ratio (config/plant_constants.toml [valve]).\n\
         pub const VALVE_CRITICAL_RATIO: f32 = {};\n\
         /// Muscle chamber volume polynomial in the contraction [m^3] (config/plant_constants.toml [muscle]).\n\
         pub const MUSCLE_VOLUME_POLY_M3: [f32; 4] = [{}];\n\
         // From config/controller.toml.\n\
         /// Default position-loop gains of the cascade (config/controller.toml [position]).\n\
         {}\
         /// Velocity filter cut-off of the position loop [Hz] (config/controller.toml [position]).\n\
         pub const VELOCITY_CUTOFF_HZ: f32 = {};\n\
         /// Default torque-loop gains (config/controller.toml [torque]); the set-point ceiling is\n\
         /// [`P_MUSCLE_MAX_GAUGE_PA`].\n\
         {}\
         /// Default pressure-loop gains (config/controller.toml [pressure]).\n\
         {}\
         /// Default trajectory feed-forward (config/controller.toml [feedforward]; the inertia is\n\
         /// [`JOINT_INERTIA_KGM2`]).\n\
         {}",
        lit(plant.joint.inertia_kgm2),
        lit(pm.p_max_gauge_pa),
        lit(env_.p_atm_pa),
        lit(env_.supply_gauge_pa),
        lit(val.sonic_conductance_m3_per_s_pa),
        lit(val.critical_ratio),
        vp.join(", "),
        const_struct(
            "POSITION_GAINS",
            "crate::control::PidGains",
            &lits(keyed!(pos; kp_nm_per_rad, ki_nm_per_rad_s, kd_nm_s_per_rad, i_limit_nm,
                out_limit_nm)),
        ),
        lit(pos.velocity_cutoff_hz),
        const_struct("TORQUE_LOOP", "crate::control::TorqueLoopGains", &torque_loop),
        const_struct("PRESSURE_LOOP", "crate::control::PressureLoopGains", &pressure_loop),
        const_struct("FEEDFORWARD", "crate::feedforward::FeedforwardGains", &feedforward),
    )
}

/// The fixed-point force law and torque model pre-scaled from the f32 constants, and the
/// outer loops' period.
fn fixed_point_constants(f: &ForceLaw, t: &TorqueModel, ctl: &ControllerFile) -> String {
    let fb = prescale::force_law_bits(
        f.c.map(f32w),
        f32w(f.p_gauge_max_pa),
        f32w(f.stretch_min),
        f32w(f.stretch_max),
        f64::exp,
    );
    let tb = prescale::torque_model_bits(
        f32w(t.a_n_per_m_rad),
        f32w(t.b_m2),
        f32w(t.c_nms3_per_rad3),
        f32w(t.d_nms_per_rad),
        f32w(t.sprocket_radius_m),
        f32w(t.p0_gauge_pa),
        f32w(t.dp_max_pa),
    );
    let fixed = format!(
        "\
         /// Fixed-point force law pre-scaled (in f64, by `src/fixed_point/prescale.rs`) from the\n\
         /// f32 constants of [`FORCE_LAW`].\n\
         pub const FIXED_FORCE_LAW: crate::fixed_point::FixedForceLaw = crate::fixed_point::FixedForceLaw::from_bits(\n\
         \x20   crate::fixed_point::prescale::{fb:?});\n\
         /// Fixed-point torque model pre-scaled (in f64, by `src/fixed_point/prescale.rs`) from the\n\
         /// f32 constants of [`TORQUE_MODEL`].\n\
         pub const FIXED_TORQUE_MODEL: crate::fixed_point::FixedTorqueModel = crate::fixed_point::FixedTorqueModel::from_bits(\n\
         \x20   crate::fixed_point::prescale::{tb:?});\n"
    );
    let rates = format!(
        "\
         /// The cascade's outer loops run on one tick in this many (config/controller.toml [rates]).\n\
         pub const OUTER_PERIOD_TICKS: u16 = {};\n",
        ctl.rates.outer_period_ticks
    );
    fixed + &rates
}

/// Bare-metal firmware binaries only (the `firmware` feature gates them): linker scripts
/// (cortex-m-rt's link.x, defmt's defmt.x) and the memory map's search path.
fn link_args() {
    if env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none")
        && env::var("CARGO_FEATURE_FIRMWARE").is_ok()
    {
        let dir = PathBuf::from(env::var("CARGO_MANIFEST_DIR").unwrap());
        // memory.x: the top-level one (STM32F405/F407: QEMU netduinoplus2 and the board) is
        // the default; the linker finds it in its working directory (the workspace root) and
        // through this search path. Cortex-M0 builds (thumbv6m, the FPU-less benchmark image
        // under QEMU `microbit`) use scripts/nrf51/memory.x: their linker
        // (scripts/ld-nrf51.sh, .cargo/config.toml) runs in that directory, because an
        // INCLUDEd file in the working directory would shadow any search path.
        let mem = if env::var("TARGET")
            .unwrap_or_default()
            .starts_with("thumbv6m")
        {
            dir.join("scripts/nrf51")
        } else {
            dir.clone()
        };
        println!("cargo:rustc-link-search={}", mem.display());
        println!("cargo:rerun-if-changed={}", mem.join("memory.x").display());
        // Binaries, and the on-target tests (tests/on_target.rs) when they are built.
        let mut kinds = vec!["bins"];
        if env::var("CARGO_FEATURE_ON_TARGET_TESTS").is_ok() {
            kinds.push("tests");
        }
        for kind in kinds {
            println!("cargo:rustc-link-arg-{kind}=--nmagic");
            println!("cargo:rustc-link-arg-{kind}=-Tlink.x");
            if env::var("CARGO_FEATURE_DEFMT").is_ok() {
                println!("cargo:rustc-link-arg-{kind}=-Tdefmt.x");
            }
        }
    }
}

/// Generates `sensor_trace.rs` (OUT_DIR) from the raw sensor trace CSV that the QEMU firmware
/// and `tests/qemu_trace.rs` replay (see `scripts/gen-qemu-trace.py` for the columns). Errors
/// name the file, line and field.
fn sensor_trace(path: &str, joints: usize, name: &str, out_file: &str) {
    let text = read_text(path);
    const GROUP: [&str; 4] = [
        "angle_set_mrad",
        "p1_adc_counts",
        "p2_adc_counts",
        "encoder_counts",
    ];
    // One joint: `tick` and the four columns; several: each group with a `_jN` suffix.
    let mut cols = vec!["tick".to_string()];
    for j in 1..=joints {
        for c in GROUP {
            cols.push(if joints == 1 {
                c.to_string()
            } else {
                format!("{c}_j{j}")
            });
        }
    }
    let mut header_seen = false;
    let mut rows = String::new();
    let mut n = 0usize;
    for (i, line) in text.lines().enumerate() {
        let line_no = i + 1;
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if !header_seen {
            assert!(
                fields == cols,
                "{path}:{line_no}: header must be `{}`, found `{line}`",
                cols.join(",")
            );
            header_seen = true;
            continue;
        }
        assert!(
            fields.len() == cols.len(),
            "{path}:{line_no}: expected {} fields, found {}",
            cols.len(),
            fields.len()
        );
        let int = |j: usize, lo: i64, hi: i64, optional: bool| -> Option<i64> {
            let f = fields[j];
            if f.is_empty() {
                assert!(
                    optional,
                    "{path}:{line_no}: field `{}` is required",
                    cols[j]
                );
                return None;
            }
            let v: i64 = f.parse().unwrap_or_else(|e| {
                panic!(
                    "{path}:{line_no}: field `{}`: `{f}` is not an integer: {e}",
                    cols[j]
                )
            });
            assert!(
                (lo..=hi).contains(&v),
                "{path}:{line_no}: field `{}` = {v} outside {lo}..={hi}",
                cols[j]
            );
            Some(v)
        };
        let tick = int(0, 0, u32::MAX as i64, false).unwrap();
        assert!(
            tick == n as i64,
            "{path}:{line_no}: field `tick` = {tick}, expected {n} (one row per tick, in order)"
        );
        let mut group_rows = Vec::new();
        for j in 0..joints {
            let b = 1 + 4 * j;
            let sp = int(b, i16::MIN as i64, i16::MAX as i64, false).unwrap();
            let p1 = int(b + 1, 0, 4095, true).unwrap_or(0xFFFF);
            let p2 = int(b + 2, 0, 4095, true).unwrap_or(0xFFFF);
            let enc =
                int(b + 3, i16::MIN as i64 + 1, i16::MAX as i64, true).unwrap_or(i16::MIN as i64);
            group_rows.push(format!(
                "TraceRow {{ angle_set_mrad: {sp}, p1_adc: {p1}, p2_adc: {p2}, encoder: {enc} }}"
            ));
        }
        if joints == 1 {
            rows.push_str(&format!("    {},\n", group_rows[0]));
        } else {
            rows.push_str(&format!("    [{}],\n", group_rows.join(", ")));
        }
        n += 1;
    }
    assert!(header_seen && n > 0, "{path}: no header or no rows");
    let ty = if joints == 1 {
        format!("[TraceRow; {n}]")
    } else {
        format!("[[TraceRow; {joints}]; {n}]")
    };
    let src = format!(
        "// @generated by build.rs from {path}. Do not edit.\n\
         /// The raw sensor trace ({path}), one row per control tick.\n\
         pub static {name}: {ty} = [\n{rows}];\n"
    );
    let out = PathBuf::from(env::var("OUT_DIR").unwrap()).join(out_file);
    fs::write(&out, src).unwrap_or_else(|e| panic!("write {out_file}: {e}"));
}

/// The board's compiled-in set-point (`OUT_DIR/board_profile.rs`, included by
/// `src/bin/board.rs`): the `[setpoint]` of the scenario TOML named by `PAM_BOARD_SCENARIO`
/// (a path relative to the crate root), else a hold at 0 rad. Parsing and validation:
/// `src/build/board_profile.rs` (shared with `tests/board_profile.rs`). A bad file stops the
/// build with the file, the key and the reason.
fn board_profile() {
    println!("cargo:rerun-if-env-changed=PAM_BOARD_SCENARIO");
    println!("cargo:rerun-if-changed=src/build/board_profile.rs");
    let (name, expr) = match env::var("PAM_BOARD_SCENARIO") {
        Err(_) => (
            "none (hold 0 rad)".to_string(),
            "SetpointProfile::Hold { angle_rad: 0.0 }".to_string(),
        ),
        Ok(path) => {
            println!("cargo:rerun-if-changed={path}");
            let text = fs::read_to_string(&path)
                .unwrap_or_else(|e| panic!("PAM_BOARD_SCENARIO={path}: cannot read: {e}"));
            let spec =
                board_profile_spec::parse_setpoint(&path, &text).unwrap_or_else(|e| panic!("{e}"));
            (path, spec.rust_expr())
        }
    };
    let src = format!(
        "// @generated by build.rs from PAM_BOARD_SCENARIO. Do not edit.\n\
         /// The scenario file the set-point comes from.\n\
         pub const BOARD_SCENARIO: &str = {name:?};\n\
         /// The compiled-in angle set-point profile.\n\
         pub const BOARD_PROFILE: pam_firmware::profile::SetpointProfile = {{\n\
         \x20   use pam_firmware::profile::SetpointProfile;\n\
         \x20   {expr}\n\
         }};\n"
    );
    let out = PathBuf::from(env::var("OUT_DIR").unwrap()).join("board_profile.rs");
    fs::write(&out, src).expect("write board_profile.rs");
}
