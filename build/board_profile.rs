//! The `[setpoint]` table of a scenario TOML as the board's compiled-in set-point profile:
//! parsed and validated here, written as a `pam_firmware::profile::SetpointProfile`
//! expression by `build.rs`, checked by `tests/board_profile.rs` (both include this file).

/// The profile read from a scenario (f64 as in the file; the firmware evaluates it in f32).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ProfileSpec {
    /// `kind = "step"`.
    Step {
        initial_rad: f64,
        final_rad: f64,
        at_s: f64,
        transition_s: f64,
    },
    /// `kind = "ramp"`.
    Ramp {
        from_rad: f64,
        to_rad: f64,
        start_s: f64,
        end_s: f64,
    },
    /// `kind = "sine"`.
    Sine {
        offset_rad: f64,
        amplitude_rad: f64,
        freq_hz: f64,
        start_s: f64,
    },
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
    let kind = sp
        .get("kind")
        .and_then(|v| v.as_str())
        .ok_or_else(|| format!("{path}: [setpoint] kind: missing or not a string"))?;
    let known: &[&str] = match kind {
        "step" => &["kind", "initial_rad", "final_rad", "at_s", "transition_s"],
        "ramp" => &["kind", "from_rad", "to_rad", "start_s", "end_s"],
        "sine" => &["kind", "offset_rad", "amplitude_rad", "freq_hz", "start_s"],
        other => {
            return Err(format!(
                "{path}: [setpoint] kind = \"{other}\": the board plays step, ramp or sine"
            ))
        }
    };
    for k in sp.keys() {
        if !known.contains(&k.as_str()) {
            return Err(format!(
                "{path}: [setpoint] {k}: unknown key for kind = \"{kind}\" (allowed: {known:?})"
            ));
        }
    }
    Ok(match kind {
        "step" => {
            let transition_s = num("transition_s", Some(0.0))?;
            if transition_s < 0.0 {
                return Err(format!("{path}: [setpoint] transition_s: must be >= 0"));
            }
            ProfileSpec::Step {
                initial_rad: num("initial_rad", None)?,
                final_rad: num("final_rad", None)?,
                at_s: num("at_s", None)?,
                transition_s,
            }
        }
        "ramp" => {
            let (start_s, end_s) = (num("start_s", None)?, num("end_s", None)?);
            if end_s <= start_s {
                return Err(format!("{path}: [setpoint] end_s: must be > start_s"));
            }
            ProfileSpec::Ramp {
                from_rad: num("from_rad", None)?,
                to_rad: num("to_rad", None)?,
                start_s,
                end_s,
            }
        }
        _ => {
            let freq_hz = num("freq_hz", None)?;
            if freq_hz <= 0.0 {
                return Err(format!("{path}: [setpoint] freq_hz: must be > 0"));
            }
            ProfileSpec::Sine {
                offset_rad: num("offset_rad", None)?,
                amplitude_rad: num("amplitude_rad", None)?,
                freq_hz,
                start_s: num("start_s", Some(0.0))?,
            }
        }
    })
}

impl ProfileSpec {
    /// The f32 values of the profile, in field order.
    #[allow(dead_code)]
    pub fn f32_fields(&self) -> [f32; 4] {
        let v = match *self {
            ProfileSpec::Step {
                initial_rad,
                final_rad,
                at_s,
                transition_s,
            } => [initial_rad, final_rad, at_s, transition_s],
            ProfileSpec::Ramp {
                from_rad,
                to_rad,
                start_s,
                end_s,
            } => [from_rad, to_rad, start_s, end_s],
            ProfileSpec::Sine {
                offset_rad,
                amplitude_rad,
                freq_hz,
                start_s,
            } => [offset_rad, amplitude_rad, freq_hz, start_s],
        };
        v.map(|x| x as f32)
    }

    /// A `SetpointProfile` constant expression (`SetpointProfile` in scope).
    #[allow(dead_code)]
    pub fn rust_expr(&self) -> String {
        let [a, b, c, d] = self.f32_fields();
        match self {
            ProfileSpec::Step { .. } => format!(
                "SetpointProfile::Step {{ initial_rad: {a:?}, final_rad: {b:?}, at_s: {c:?}, transition_s: {d:?} }}"
            ),
            ProfileSpec::Ramp { .. } => format!(
                "SetpointProfile::Ramp {{ from_rad: {a:?}, to_rad: {b:?}, start_s: {c:?}, end_s: {d:?} }}"
            ),
            ProfileSpec::Sine { .. } => format!(
                "SetpointProfile::Sine {{ offset_rad: {a:?}, amplitude_rad: {b:?}, freq_hz: {c:?}, start_s: {d:?} }}"
            ),
        }
    }
}
