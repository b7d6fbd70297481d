//! Plant parameter files (TOML), e.g. `shared/plant/reference-1dof.toml`.
//!
//! Every table is `deny_unknown_fields`: a misspelt or unknown key is an error, and so is a
//! missing one. Errors name the file and the key (the `toml` crate reports line, column and
//! the key; we prefix the file path).

use std::path::Path;

use serde::Deserialize;

use crate::plant::effects::EffectsConfig;
pub use crate::plant::tables::{
    ConfigError, EnvironmentConfig, InitialConfig, JointConfig, MuscleConfig, MuscleOverride,
    ValveConfig, ValveOverride, MUSCLE_TABLES, VALVE_TABLES,
};
use crate::validate::{range_rows, Range, RangeRow};

/// The whole plant file.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlantConfig {
    pub environment: EnvironmentConfig,
    pub muscle: MuscleConfig,
    pub joint: JointConfig,
    pub valve: ValveConfig,
    pub initial: InitialConfig,
    /// Optional, switchable model extensions; absent in the nominal reference files.
    #[serde(default)]
    pub effects: EffectsConfig,
    /// An external torque series for open-loop replays (not in a plant file: set in code,
    /// e.g. by the arm's diagnosis for one joint).
    #[serde(skip)]
    pub load: Option<crate::plant::state::LoadTorque>,
}

/// Reads a plant file's text (an I/O error names the file).
pub fn read_plant_text(path: &Path) -> Result<String, ConfigError> {
    std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
        path: path.to_owned(),
        source,
    })
}

/// What a file given as a plant file is instead, when it is another of this product's
/// files or a recording (a line to append to the parse error); empty otherwise.
pub(crate) fn not_a_plant_hint(text: &str) -> String {
    other_product_file(text)
        .map(|kind| {
            format!(
                "\n  this is {kind}, not a plant file (PLANT.md: [environment], [muscle], \
                 [joint], [valve], [initial])"
            )
        })
        .or_else(|| {
            looks_like_recording(text).then(|| {
                "\n  this is a recording (CSV), not a plant file (TOML): are the plant file and \
                 the recording given the other way round?"
                    .to_string()
            })
        })
        .unwrap_or_default()
}

/// Whether `text` is a recording (RECORDING.md): its first line that is not a `#` comment
/// is a comma-separated header starting with `t_s`.
fn looks_like_recording(text: &str) -> bool {
    text.lines()
        .map(str::trim)
        .find(|l| !l.is_empty() && !l.starts_with('#'))
        .is_some_and(|l| l.trim_start_matches('\u{feff}').starts_with("t_s,"))
}

/// What another of this product's TOML files is, told by its tables, when `text` is one
/// (given where a plant file belongs): `None` for anything else.
fn other_product_file(text: &str) -> Option<&'static str> {
    let doc: toml::Table = text.parse().ok()?;
    let has = |t: &str| doc.contains_key(t);
    if has("links") && has("joint1") && !has("kind") {
        return Some(
            "the firmware's arm constants (config/arm3.toml; the 3-DOF arm plant file is \
             host-sim/plants/arm3-seed001.toml, kind = \"arm3\")",
        );
    }
    if has("muscle") || has("joint") || has("joint1") {
        return None;
    }
    [
        (
            "cascade",
            "a control gains file (host-sim tune, config/control_tuned.toml)",
        ),
        (
            "torque_model",
            "a torque model file (host-sim identify torque)",
        ),
        ("force_law", "a force law file (host-sim identify force)"),
        ("joint_geometry", "a firmware joint geometry file (config/)"),
        (
            "pressure_ff",
            "a firmware feed-forward file (config/pressure_ff.toml)",
        ),
        (
            "volume_fnn",
            "a learned volume file (host-sim identify volume)",
        ),
        ("scenario", "a scenario file (scenarios/)"),
        ("setpoint", "a scenario file (scenarios/)"),
        ("channel", "an import mapping file (host-sim import)"),
        (
            "position",
            "a firmware controller file (config/controller.toml)",
        ),
    ]
    .into_iter()
    .find(|(t, _)| has(t))
    .map(|(_, kind)| kind)
}

/// Parses plant TOML text of any plant kind and validates it with `validate`; a validation
/// error names the line of its key where the text has one. `path` is only used in messages.
pub fn parse_plant_text<T: serde::de::DeserializeOwned>(
    text: &str,
    path: &Path,
    validate: impl FnOnce(&T, &Path) -> Result<(), ConfigError>,
) -> Result<T, ConfigError> {
    let cfg: T = toml::from_str(text).map_err(|e| ConfigError::Parse {
        path: path.to_owned(),
        // toml's message already names the key (`unknown field `x``, `missing field `y``)
        // and the line; keep it on one line after the file name.
        message: format!(
            "{}{}",
            e.to_string().trim_end().replace('\n', "\n  "),
            not_a_plant_hint(text)
        ),
    })?;
    validate(&cfg, path).map_err(|e| match e {
        ConfigError::Invalid { path, key, message } => {
            let (table, k) = key.rsplit_once('.').unwrap_or(("", key.as_str()));
            match crate::validate::toml_key_line(text, table, 0, k) {
                Some(line) => ConfigError::InvalidAt {
                    path,
                    line,
                    key,
                    message,
                },
                None => ConfigError::Invalid { path, key, message },
            }
        }
        e => e,
    })?;
    Ok(cfg)
}

// Range rows the 1-DOF and the arm plant files share (same keys under the arm's `jointN.`
// prefix, same physical or practical ranges): wide enough for any real rig, narrow enough to
// catch a unit typed wrong (kPa in a Pa key) or a value the model cannot run.
//
// The bounds are those of this product's plants (rehabilitation joints and soft manipulators
// driven by pneumatic muscles), not of the number type: a value far outside them (an inertia
// of 1e-30 kg m^2) would only fail later inside the integrator. docs/reliability.md lists them.

/// Joint (and link) inertia about the joint axis: a small soft-manipulator finger to a
/// loaded leg or arm of a rehabilitation device [kg m^2].
pub(crate) const INERTIA_KGM2: Range = Range::closed(1.0e-4, 10.0);
/// The unit and context [`INERTIA_KGM2`]'s message names.
pub(crate) const INERTIA_UNIT: &str = "kg m^2 (a rehab joint or soft manipulator)";
/// Sprocket (pulley) radius: 5 mm .. 20 cm [m].
pub(crate) const SPROCKET_RADIUS_M: Range = Range::closed(0.005, 0.2);
/// The unit and context [`SPROCKET_RADIUS_M`]'s message names.
pub(crate) const SPROCKET_UNIT: &str = "m (5 mm .. 20 cm)";
/// ISO 6358 sonic conductance of a valve: 0.001 .. 100 dm^3/(s bar) [m^3/(s Pa)].
pub(crate) const SONIC_CONDUCTANCE_M3_PER_S_PA: Range = Range::closed(1.0e-11, 1.0e-6);
/// The unit and context [`SONIC_CONDUCTANCE_M3_PER_S_PA`]'s message names.
pub(crate) const SONIC_CONDUCTANCE_UNIT: &str = "m^3/(s Pa) (0.001 .. 100 dm^3/(s bar))";

/// Supply gauge pressure a plant (or a supply-loss event) may have [Pa].
pub(crate) const SUPPLY_GAUGE_PA: Range = Range::closed(1.0e4, 2.0e6);

/// `[environment]`: atmospheric and supply pressure.
pub(crate) fn environment_range_rows(env: &EnvironmentConfig) -> Vec<RangeRow> {
    range_rows![env, "environment.";
        p_atm_pa: Range::closed(5.0e4, 1.2e5), "Pa absolute";
        supply_gauge_pa: SUPPLY_GAUGE_PA, "Pa gauge";
    ]
}

/// `[muscle]` (`prefix` `""`, or the arm's `jointN.`).
pub(crate) fn muscle_range_rows(m: &MuscleConfig, prefix: &str) -> Vec<RangeRow> {
    let mut rows = range_rows![m, format!("{prefix}muscle.");
        rest_length_m: Range::closed(0.02, 2.0), "m (a muscle 2 cm .. 2 m long)";
        radius_m: Range::closed(0.001, 0.1), "m (a muscle 2 mm .. 20 cm across)";
        braid_angle_deg: Range::open(5.0, 54.7),
            "degrees (between 5 and the neutral braid angle 54.7; radians typed?)";
        end_factor: Range::closed(0.5, 5.0), "(Tondu's k, about 1 .. 1.6 on real muscles)";
        damping_m2s: Range::closed(0.0, 0.01), "m^2 s";
    ];
    // The chamber at zero contraction against the muscle's own cylinder: a volume in cm^3 or
    // litres typed into the m^3 key is 1e6 or 1e3 times off (the reference: 1.01). Checked
    // on b0 as typed, within the ratios' bounds in m^3 (to 3 significant digits, outward).
    rows.push((
        format!("{prefix}muscle.volume_poly_m3"),
        m.volume_poly_m3[0],
        b0_range_m3(m),
        "m^3 (b0, the first coefficient: the chamber at zero contraction, 0.2 .. 5 x the \
         muscle's cylinder pi radius_m^2 rest_length_m; cm^3 or litres typed as m^3?)",
    ));
    rows
}

/// The allowed `volume_poly_m3` b0 of muscle `m` [m^3]: [`VOLUME_OVER_CYLINDER`] times its
/// cylinder, the bounds rounded outward to 3 significant digits (as an error message shows
/// them).
fn b0_range_m3(m: &MuscleConfig) -> Range {
    let cylinder_m3 = std::f64::consts::PI * m.radius_m * m.radius_m * m.rest_length_m;
    let round = |v: f64, f: fn(f64) -> f64| -> f64 {
        if !(v.is_finite() && v > 0.0) {
            return v;
        }
        let scale = 10f64.powi(2 - v.log10().floor() as i32);
        f(v * scale) / scale
    };
    Range::closed(
        round(VOLUME_OVER_CYLINDER.0 * cylinder_m3, f64::floor),
        round(VOLUME_OVER_CYLINDER.1 * cylinder_m3, f64::ceil),
    )
}

/// `volume_poly_m3` as typed, for a message: `[7.9e-5, 4.8e-4, -1.8e-5, -1.1e-3]`.
pub(crate) fn shown_coefficients(v: &[f64; 4]) -> String {
    use crate::validate::Shown;
    format!(
        "[{}, {}, {}, {}]",
        Shown(v[0]),
        Shown(v[1]),
        Shown(v[2]),
        Shown(v[3])
    )
}

/// The message for `volume_poly_m3` coefficients that are not all finite (quoting them).
pub(crate) fn volume_coefficients_error(v: &[f64; 4]) -> Option<String> {
    (!v.iter().all(|c| c.is_finite())).then(|| {
        format!(
            "the coefficients must be finite numbers [b0, b1, b2, b3] in m^3, got {}",
            shown_coefficients(v)
        )
    })
}

/// The first `[valve]` pressure ratio outside its range: its key and the message quoting the
/// typed value and the allowed range (1-DOF and arm files).
pub(crate) fn valve_ratio_error(v: &ValveConfig) -> Option<(String, String)> {
    valve_ratio_error_in(v, "valve")
}

/// [`valve_ratio_error`] of the valve table `table` (`valve`, `valve.inlet1`, ...).
fn valve_ratio_error_in(v: &ValveConfig, table: &str) -> Option<(String, String)> {
    use crate::validate::range_error;
    let b = v.critical_ratio;
    let critical = format!("{table}.critical_ratio");
    let laminar = format!("{table}.laminar_ratio");
    range_error(
        &critical,
        b,
        Range::half_open(0.0, 1.0),
        "(ISO 6358 b: the downstream over upstream absolute pressure at which the flow \
         chokes, about 0.2 .. 0.5 on real valves; the reference plant has 0.433)",
    )
    .map(|msg| (critical.clone(), msg))
    .or_else(|| {
        range_error(
            &laminar,
            v.laminar_ratio,
            Range::open(b, 1.0),
            "(above valve.critical_ratio and below 1: from it the flow falls linearly to 0 at \
             ratio 1; the reference plant has 0.999)",
        )
        .map(|msg| (laminar.clone(), msg))
    })
}

/// The first invalid key of the per-valve tables (`[valve.inlet1]` ...): its dotted key and
/// the message. A table's missing keys are the `[valve]` table's, checked there.
pub(crate) fn valve_override_error(v: &ValveConfig) -> Option<(String, String)> {
    (0..4).find_map(|i| {
        v.override_of(i)?;
        let table = format!("valve.{}", VALVE_TABLES[i]);
        let one = v.of(i);
        let rows: Vec<RangeRow> = vec![(
            format!("{table}.sonic_conductance_m3_per_s_pa"),
            one.sonic_conductance_m3_per_s_pa,
            SONIC_CONDUCTANCE_M3_PER_S_PA,
            SONIC_CONDUCTANCE_UNIT,
        )];
        crate::validate::first_range_error(&rows)
            .map(|(k, m)| (k.to_string(), m))
            .or_else(|| valve_ratio_error_in(&one, &table))
    })
}

/// The range rows of the per-muscle tables (`[muscle.m1]`, `[muscle.m2]`, `prefix` `""` or
/// the arm's `jointN.`): each present table's muscle as the physics sees it, under the
/// table's keys.
pub(crate) fn muscle_override_rows(m: &MuscleConfig, prefix: &str) -> Vec<RangeRow> {
    let mut rows = Vec::new();
    for (i, name) in MUSCLE_TABLES.iter().enumerate() {
        if m.override_of(i).is_none() {
            continue;
        }
        for (key, v, r, unit) in muscle_range_rows(&m.of(i), prefix) {
            let key = key.replacen(
                &format!("{prefix}muscle."),
                &format!("{prefix}muscle.{name}."),
                1,
            );
            rows.push((key, v, r, unit));
        }
    }
    rows
}

/// The message for a volume polynomial `v` that is not > 0 somewhere in `0..=chi_max`.
fn volume_positive_error(v: &[f64; 4], chi_max: f64) -> Option<String> {
    (0..=64).find_map(|k| {
        let chi = chi_max * k as f64 / 64.0;
        let vol = v[0] + chi * (v[1] + chi * (v[2] + chi * v[3]));
        (!(vol > 0.0)).then(|| {
            format!(
                "{}: the volume V(chi) = {vol:.3e} m^3 at contraction {chi:.3} is not > 0 \
                 (it must stay > 0 up to the maximum contraction {chi_max:.3}: check the \
                 signs and the unit, m^3, of b1 .. b3)",
                shown_coefficients(v)
            )
        })
    })
}

/// Allowed ratio of a muscle's chamber volume at zero contraction (`volume_poly_m3` b0) to the
/// cylinder of its radius and rest length: a McKibben chamber is about that cylinder.
pub const VOLUME_OVER_CYLINDER: (f64, f64) = (0.2, 5.0);

/// `[initial]`: angle, velocity, and the two pressures between vacuum and the supply.
pub(crate) fn initial_range_rows(
    n: &InitialConfig,
    env: &EnvironmentConfig,
    prefix: &str,
) -> Vec<RangeRow> {
    let p_range = Range::closed(-env.p_atm_pa, env.supply_gauge_pa);
    let p_unit = "Pa gauge (vacuum .. environment.supply_gauge_pa)";
    range_rows![n, format!("{prefix}initial.");
        angle_rad: Range::closed(-std::f64::consts::PI, std::f64::consts::PI), "rad";
        velocity_rad_s: Range::closed(-100.0, 100.0), "rad/s";
        p1_gauge_pa: p_range, p_unit;
        p2_gauge_pa: p_range, p_unit;
    ]
}

impl PlantConfig {
    /// Reads and validates a plant file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ConfigError> {
        let path = path.as_ref();
        Self::from_toml_str(&read_plant_text(path)?, path)
    }

    /// The reference plant of the shared specification (`host-sim/plants/reference-1dof.toml`,
    /// built into the binary; `tests/conformance.rs` checks it against the specification).
    pub fn reference() -> Self {
        let builtin = crate::defaults::REFERENCE_PLANT;
        Self::from_toml_str(builtin.text, builtin.rel)
            .expect("the built-in reference plant is a valid plant file")
    }

    /// Parses and validates plant TOML text; `path` is only used in error messages.
    pub fn from_toml_str(text: &str, path: impl AsRef<Path>) -> Result<Self, ConfigError> {
        parse_plant_text(text, path.as_ref(), Self::validate)
    }

    /// The range checks of the file's scalar keys: key, value, allowed range, unit (the
    /// `muscle.volume_poly_m3` row checks its first coefficient b0, within a range set by the
    /// muscle's cylinder).
    pub(crate) fn range_rows(&self) -> Vec<RangeRow> {
        let mut rows = environment_range_rows(&self.environment);
        rows.extend(muscle_range_rows(&self.muscle, ""));
        rows.extend(range_rows![self, "";
            joint.sprocket_radius_m: SPROCKET_RADIUS_M, SPROCKET_UNIT;
            joint.inertia_kgm2: INERTIA_KGM2, INERTIA_UNIT;
            joint.initial_contraction: Range::half_open(0.0, 1.0), "fraction";
            valve.sonic_conductance_m3_per_s_pa: SONIC_CONDUCTANCE_M3_PER_S_PA, SONIC_CONDUCTANCE_UNIT;
        ]);
        rows.extend(muscle_override_rows(&self.muscle, ""));
        for (i, name) in MUSCLE_TABLES.iter().enumerate() {
            if let Some(chi0) = self
                .muscle
                .override_of(i)
                .and_then(|o| o.initial_contraction)
            {
                rows.push((
                    format!("muscle.{name}.initial_contraction"),
                    chi0,
                    Range::half_open(0.0, 1.0),
                    "fraction",
                ));
            }
        }
        rows.extend(initial_range_rows(&self.initial, &self.environment, ""));
        rows
    }

    fn validate(&self, path: &Path) -> Result<(), ConfigError> {
        let bad = |key: &str, message: &str| ConfigError::Invalid {
            path: path.to_owned(),
            key: key.to_owned(),
            message: message.to_owned(),
        };
        // Physical or practical ranges: wide enough for any real rig, narrow enough to catch
        // a unit typed wrong (kPa in a Pa key) or a value the model cannot run.
        use crate::validate::Shown;
        let rows = self.range_rows();
        if let Some((key, msg)) = crate::validate::first_range_error(&rows) {
            return Err(bad(key, &msg));
        }
        // The Tondu force vanishes at the maximum contraction
        // (1 - 1 / (sqrt(3) cos alpha0)) / k: the muscles must start below it.
        let chi_max_of = |m: &MuscleConfig| {
            (1.0 - 1.0 / (3f64.sqrt() * m.braid_angle_deg.to_radians().cos())) / m.end_factor
        };
        let chi_max = chi_max_of(&self.muscle);
        if !(self.joint.initial_contraction < chi_max) {
            return Err(bad(
                "joint.initial_contraction",
                &format!(
                    "must be within [0, {chi_max:.4}) (below the muscle's maximum contraction \
                     (1 - 1/(sqrt(3) cos braid_angle)) / end_factor), got {}",
                    self.joint.initial_contraction
                ),
            ));
        }
        for (i, name) in MUSCLE_TABLES.iter().enumerate() {
            let Some(o) = self.muscle.override_of(i) else {
                continue;
            };
            let m = self.muscle.of(i);
            let chi0 = self
                .muscle
                .initial_contraction_of(i, self.joint.initial_contraction);
            let chi_max = chi_max_of(&m);
            if !(chi0 < chi_max) {
                let key = if o.initial_contraction.is_some() {
                    format!("muscle.{name}.initial_contraction")
                } else {
                    "joint.initial_contraction".to_string()
                };
                return Err(bad(
                    &key,
                    &format!(
                        "must be within [0, {chi_max:.4}) (below muscle {}'s maximum contraction \
                         (1 - 1/(sqrt(3) cos braid_angle)) / end_factor of [muscle.{name}]), got {chi0}",
                        i + 1
                    ),
                ));
            }
            if let Some(msg) = volume_coefficients_error(&m.volume_poly_m3) {
                return Err(bad(&format!("muscle.{name}.volume_poly_m3"), &msg));
            }
            if let Some(msg) = volume_positive_error(&m.volume_poly_m3, chi_max) {
                return Err(bad(&format!("muscle.{name}.volume_poly_m3"), &msg));
            }
        }
        if let Some(msg) = volume_coefficients_error(&self.muscle.volume_poly_m3) {
            return Err(bad("muscle.volume_poly_m3", &msg));
        }
        if let Some((key, msg)) = valve_ratio_error(&self.valve) {
            return Err(bad(&key, &msg));
        }
        if let Some((key, msg)) = valve_override_error(&self.valve) {
            return Err(bad(&key, &msg));
        }
        for (key, v) in [
            ("joint.angle_min_rad", self.joint.angle_min_rad),
            ("joint.angle_max_rad", self.joint.angle_max_rad),
        ] {
            if let Some(v) = v {
                if !v.is_finite() {
                    return Err(bad(key, &format!("must be a finite number, got {v}")));
                }
            }
        }
        for (key, v) in [
            (
                "joint.end_stop_stiffness_nm_per_rad",
                self.joint.end_stop_stiffness_nm_per_rad,
            ),
            (
                "joint.end_stop_damping_nms_per_rad",
                self.joint.end_stop_damping_nms_per_rad,
            ),
        ] {
            if let Some(v) = v {
                if !(v.is_finite() && v >= 0.0) {
                    return Err(bad(
                        key,
                        &format!("must be a finite number >= 0, got {}", Shown(v)),
                    ));
                }
            }
        }
        let stops =
            crate::plant::joint::EndStops::from_config(&self.joint, self.muscle.rest_length_m);
        if !(stops.angle_min_rad < stops.angle_max_rad) {
            return Err(bad(
                "joint.angle_max_rad",
                &format!(
                    "the end stops must satisfy angle_min_rad < angle_max_rad, got {} and {}",
                    stops.angle_min_rad, stops.angle_max_rad
                ),
            ));
        }
        // The chamber volume must stay positive over the contractions the muscles reach (b0
        // > 0 is the range row's).
        if let Some(msg) = volume_positive_error(&self.muscle.volume_poly_m3, chi_max) {
            return Err(bad("muscle.volume_poly_m3", &msg));
        }
        self.effects.validate(path)?;
        let on = |e: Option<bool>| e.unwrap_or(false);
        if on(self.effects.thermal_chamber.as_ref().map(|t| t.enabled))
            && on(self
                .effects
                .polytropic
                .as_ref()
                .map(|p| p.enabled && p.exponent != 1.0))
        {
            return Err(bad(
                "effects.polytropic",
                "a polytropic exponent and the thermal chamber both set the pressure law: \
                 keep one (the thermal chamber models the non-isothermal process itself)",
            ));
        }
        Ok(())
    }
}
