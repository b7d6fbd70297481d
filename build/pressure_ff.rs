//! `PRESSURE_FF` (in `constants.rs`) from `config/pressure_ff.toml`: the constants of the
//! inverse thermodynamic feed-forward of the pressure loop (`src/pressure_ff.rs`).

use serde::Deserialize;

const FILE: &str = "config/pressure_ff.toml";

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FfFile {
    pressure_ff: Ff,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Ff {
    enabled: bool,
    polytropic_index: f64,
    gas_constant_j_per_kg_k: f64,
    temperature_k: f64,
    rate_cutoff_hz: f64,
    gain: f64,
}

/// The Rust source of `PRESSURE_FF`.
pub fn constants() -> String {
    println!("cargo:rerun-if-changed={FILE}");
    let text = std::fs::read_to_string(FILE).unwrap_or_else(|e| panic!("{FILE}: cannot read: {e}"));
    let f: FfFile = toml::from_str(&text).unwrap_or_else(|e| panic!("{FILE}: {e}"));
    let f = f.pressure_ff;
    let checks = [
        (
            "polytropic_index",
            f.polytropic_index,
            (1.0..=1.67).contains(&f.polytropic_index),
            "in [1.0, 1.67]",
        ),
        (
            "gas_constant_j_per_kg_k",
            f.gas_constant_j_per_kg_k,
            f.gas_constant_j_per_kg_k > 0.0,
            "> 0",
        ),
        (
            "temperature_k",
            f.temperature_k,
            f.temperature_k > 0.0,
            "> 0",
        ),
        (
            "rate_cutoff_hz",
            f.rate_cutoff_hz,
            f.rate_cutoff_hz > 0.0,
            "> 0",
        ),
        ("gain", f.gain, (0.0..=2.0).contains(&f.gain), "in [0, 2]"),
    ];
    for (name, v, ok, must) in checks {
        assert!(
            ok && v.is_finite(),
            "{FILE}: [pressure_ff] {name} = {v} must be {must}"
        );
    }
    let lit = |x: f64| format!("{:?}_f32", x as f32);
    format!(
        "/// Inverse thermodynamic feed-forward of the pressure loop (config/pressure_ff.toml).\n\
         pub const PRESSURE_FF: crate::pressure_ff::PressureFfParams = crate::pressure_ff::PressureFfParams {{\n\
         \x20   enabled: {},\n\
         \x20   polytropic_index: {},\n\
         \x20   gas_constant_j_per_kg_k: {},\n\
         \x20   temperature_k: {},\n\
         \x20   rate_cutoff_hz: {},\n\
         \x20   gain: {},\n\
         }};\n",
        f.enabled,
        lit(f.polytropic_index),
        lit(f.gas_constant_j_per_kg_k),
        lit(f.temperature_k),
        lit(f.rate_cutoff_hz),
        lit(f.gain),
    )
}
