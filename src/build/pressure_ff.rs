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
    rate_from_reference: bool,
    volume_rate_from_reference: bool,
    gain: f64,
    min_duty: f64,
    update_period_ticks: u16,
}

/// The Rust source of `PRESSURE_FF`.
pub fn constants() -> String {
    let f = super::read::<FfFile>(FILE).pressure_ff;
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
        (
            "min_duty",
            f.min_duty,
            (0.0..=1.0).contains(&f.min_duty),
            "in [0, 1]",
        ),
    ];
    assert!(
        (1..=100).contains(&f.update_period_ticks),
        "{FILE}: [pressure_ff] update_period_ticks = {} must be in [1, 100]",
        f.update_period_ticks
    );
    for (name, v, ok, must) in checks {
        assert!(
            ok && v.is_finite(),
            "{FILE}: [pressure_ff] {name} = {v} must be {must}"
        );
    }
    let fields = [
        vec![("enabled", f.enabled.to_string())],
        super::lits(
            keyed!(f; polytropic_index, gas_constant_j_per_kg_k, temperature_k,
            rate_cutoff_hz),
        ),
        vec![
            ("rate_from_reference", f.rate_from_reference.to_string()),
            (
                "volume_rate_from_reference",
                f.volume_rate_from_reference.to_string(),
            ),
        ],
        super::lits(keyed!(f; gain, min_duty)),
        vec![("update_period_ticks", f.update_period_ticks.to_string())],
    ]
    .concat();
    format!(
        "/// Inverse thermodynamic feed-forward of the pressure loop (config/pressure_ff.toml).\n{}",
        super::const_struct("PRESSURE_FF", "crate::pressure_ff::PressureFfParams", &fields)
    )
}
