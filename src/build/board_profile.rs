//! The `[setpoint]` table of a scenario TOML as the board's compiled-in set-point profile:
//! parsed and validated here, written as a `pam_firmware::profile::SetpointProfile`
//! expression by `build.rs`, checked by `tests/board_profile.rs` (both include this file).

/// The shapes the board plays, in [`Kind`] order: the scenario's `kind`, the
/// `SetpointProfile` variant and its four fields in order (the `[setpoint]` keys have the
/// fields' names).
const KINDS: [(&str, &str, [&str; 4]); 3] = [
    (
        "step",
        "Step",
        ["initial_rad", "final_rad", "at_s", "transition_s"],
    ),
    ("ramp", "Ramp", ["from_rad", "to_rad", "start_s", "end_s"]),
    (
        "sine",
        "Sine",
        ["offset_rad", "amplitude_rad", "freq_hz", "start_s"],
    ),
];

/// Which shape (see [`KINDS`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// `kind = "step"`: initial, final angle, step time, transition time.
    Step,
    /// `kind = "ramp"`: start, end angle, start, end time.
    Ramp,
    /// `kind = "sine"`: offset, amplitude, frequency, start time.
    Sine,
}

/// The profile read from a scenario: its shape and the values of its four fields, in the
/// order of [`KINDS`] (f64 as in the file; the firmware evaluates it in f32).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProfileSpec {
    /// The shape.
    pub kind: Kind,
    /// The field values.
    pub values: [f64; 4],
}

/// The `[setpoint]` of the scenario `text` (read from `path`, named in every error with the
/// key and the reason). Kinds `step`, `ramp`, `sine`; `random` is refused (its levels come
/// from host-sim's random generator); unknown keys, non-numbers, values outside f32 and
/// inconsistent times are errors.
pub fn parse_setpoint(path: &str, text: &str) -> Result<ProfileSpec, String> {
    let doc: toml::Table = text.parse().map_err(|e| format!("{path}: not TOML: {e}"))?;
    let sp = doc
        .get("setpoint")
        .and_then(|v| v.as_table())
        .ok_or_else(|| format!("{path}: no [setpoint] table"))?;
    let num = |key: &str, default: Option<f64>| -> Result<f64, String> {
        match sp.get(key) {
            Some(v) => {
                let x = v
                    .as_float()
                    .or_else(|| v.as_integer().map(|i| i as f64))
                    .ok_or_else(|| format!("{path}: [setpoint] {key}: not a number"))?;
                if !(x as f32).is_finite() {
                    return Err(format!("{path}: [setpoint] {key}: not a finite f32"));
                }
                Ok(x)
            }
            None => default.ok_or_else(|| format!("{path}: [setpoint] {key}: missing")),
        }
    };
    let name = sp
        .get("kind")
        .and_then(|v| v.as_str())
        .ok_or_else(|| format!("{path}: [setpoint] kind: missing or not a string"))?;
    let Some(index) = KINDS.iter().position(|(n, _, _)| *n == name) else {
        return Err(format!(
            "{path}: [setpoint] kind = \"{name}\": the board plays step, ramp or sine"
        ));
    };
    let (kind, keys) = ([Kind::Step, Kind::Ramp, Kind::Sine][index], KINDS[index].2);
    let known: Vec<&str> = core::iter::once("kind").chain(keys).collect();
    for k in sp.keys() {
        if !known.contains(&k.as_str()) {
            return Err(format!(
                "{path}: [setpoint] {k}: unknown key for kind = \"{name}\" (allowed: {known:?})"
            ));
        }
    }
    let mut values = [0.0; 4];
    for (v, key) in values.iter_mut().zip(keys) {
        // A step's transition and a sine's start time are optional.
        let default = match (kind, key) {
            (Kind::Step, "transition_s") | (Kind::Sine, "start_s") => Some(0.0),
            _ => None,
        };
        *v = num(key, default)?;
    }
    let [_, _, c, d] = values;
    let refused = match kind {
        Kind::Step if d < 0.0 => Some("transition_s: must be >= 0"),
        Kind::Ramp if d <= c => Some("end_s: must be > start_s"),
        Kind::Sine if c <= 0.0 => Some("freq_hz: must be > 0"),
        _ => None,
    };
    match refused {
        Some(why) => Err(format!("{path}: [setpoint] {why}")),
        None => Ok(ProfileSpec { kind, values }),
    }
}

impl ProfileSpec {
    /// The f32 values of the profile, in field order.
    #[allow(dead_code)]
    pub fn f32_fields(&self) -> [f32; 4] {
        self.values.map(|x| x as f32)
    }

    /// A `SetpointProfile` constant expression (`SetpointProfile` in scope).
    #[allow(dead_code)]
    pub fn rust_expr(&self) -> String {
        let (_, variant, keys) = KINDS[self.kind as usize];
        let fields: Vec<String> = keys
            .iter()
            .zip(self.f32_fields())
            .map(|(k, x)| format!("{k}: {x:?}"))
            .collect();
        format!("SetpointProfile::{variant} {{ {} }}", fields.join(", "))
    }
}
