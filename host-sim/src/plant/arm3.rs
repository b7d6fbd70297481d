//! The 3-DOF angular (anthropomorphic) arm of seed 001 (Cakurda, Trojanova, Hosovsky,
//! "Complete dynamic model validation of 3-DOF compliant manipulator with fluidic muscles"),
//! each joint driven by an antagonistic pair of muscles through a sprocket.
//!
//! # Model
//! - Arm (seed 001 eqs. 2-6, from Murray, Li, Sastry 1994 ex. 4.3, the "elbow manipulator"):
//!   joint 1 turns about the vertical axis, joints 2 and 3 about horizontal axes; q2 is the
//!   elevation of link 2 above the horizontal, q3 the angle of link 3 relative to link 2.
//!   `M(q) q'' + C(q, q') q' + G(q) + F(q') = tau`. With s2 = sin q2, c23 = cos(q2 + q3) etc.
//!   and A = l2 c2 + lc3 c23 (the horizontal reach of the link-3 centre of mass):
//!   - M11 = Iy2 s2^2 + Iy3 s23^2 + Iz1 + Iz2 c2^2 + Iz3 c23^2 + m2 lc2^2 c2^2 + m3 A^2,
//!     M12 = M13 = 0,
//!   - M22 = Ix2 + Ix3 + m3 l2^2 + m2 lc2^2 + m3 lc3^2 + 2 m3 l2 lc3 c3,
//!   - M23 = Ix3 + m3 lc3^2 + m3 l2 lc3 c3, M33 = Ix3 + m3 lc3^2;
//!   - C from the Christoffel symbols of M: C_ij = sum_k 1/2 (dM_ij/dq_k + dM_ik/dq_j -
//!     dM_jk/dq_i) q'_k, so that M' - 2C is skew-symmetric (the closed forms of eqs. 2-4 are
//!     checked against this in the tests);
//!   - G = dV/dq, V = g [(m2 lc2 + m3 l2) s2 + m3 lc3 s23]: G1 = 0 (seed 001: "in the case of
//!     Joint 1 the effect of gravity is not considered"), G2, G3 as in seed 001 eqs. 21-22
//!     (the static force differences times g / r). Seed 001 eq. 3 prints G2 with a minus sign,
//!     i.e. its q2 grows downwards; we measure q2 upwards so that a positive muscle torque
//!     lifts the arm.
//!   - F (eq. 7) per joint: f_c sgn(w) + f_d w + f_e w^2 sgn(w) + f_g w^3, with sgn(w)
//!     regularised as tanh(w / w_eps) (the right-hand side must stay continuous for the
//!     explicit integrator) and w^2 sgn(w) = w |w| exactly. So there is no true stiction:
//!     a joint loaded below f_c creeps at about w_eps atanh(tau / f_c) instead of sticking.
//! - Muscles, valves and pressures: the 1-DOF code of `shared/plant/PLANT.md` per joint
//!   ([`Muscle`] Tondu force + pressure-proportional damper + volume polynomial,
//!   [`Iso6358Valve`], [`pressure::pressure_rate_pa_s`] Boyle-Mariotte). Muscle 1 of joint i
//!   contracts when q_i grows: chi1 = chi0 + (r / l_n)(q_i - q_i,n), chi2 = chi0 - (r / l_n)
//!   (q_i - q_i,n), q_i,n the joint's neutral angle; tau_i = (F1 - F2) r (seed 001 eq. 20).
//!
//! State (16): q1..q3 [rad], q1'..q3' [rad/s], absolute pressures (p1, p2) of joints 1..3,
//! the LuGre bristle deflections (0 without LuGre) and the supply tank pressure (p_s0 and
//! constant without a tank).
//! Inputs: four valve openings per joint ([`ValveInputs`]), zero-order held over each sample.
//!
//! Effects: each joint has the 1-DOF catalogue in `[jointN.effects]` (in the right-hand side:
//! joint torques, chamber flows, pressure law, muscle friction; outside it, in the joint's
//! signal paths: its valve dead time and its sensors' lag and calibration, see
//! [`Arm3::actuator_paths`] and [`Arm3::sensor_paths`]). The supply is the arm's: one
//! `[effects.supply_drop]` (static line resistance or tank) feeds all twelve valves, so the
//! supply sags with the inlet flow of all six muscles.
//!
//! Integration: [`Arm3Integrator`], `ode_solvers::Dopri5` (adaptive, error controlled, dense
//! output) restarted at every input change, exactly as the 1-DOF [`crate::sim`].

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, SVector, Vector3};

use serde::Deserialize;

use crate::plant::config::{
    parse_plant_text, read_plant_text, ConfigError, EnvironmentConfig, InitialConfig, MuscleConfig,
    ValveConfig, INERTIA_KGM2, INERTIA_UNIT, SONIC_CONDUCTANCE_M3_PER_S_PA, SONIC_CONDUCTANCE_UNIT,
    SPROCKET_RADIUS_M, SPROCKET_UNIT,
};
use crate::plant::effects::{Check, Effect, Effects, EffectsConfig, Supply, SupplyDrop};
use crate::plant::muscle::Muscle;
use crate::plant::pressure;
use crate::plant::valve::Iso6358Valve;
use crate::plant::Measurement;
use crate::plant::ValveInputs;

/// The arm's state vector: angles, velocities, pressures, LuGre bristle deflections and the
/// supply tank pressure.
pub type ArmVector = SVector<f64, 16>;

/// The value of the top-level `kind` key of a 3-DOF arm plant file.
pub const KIND: &str = "arm3";

// ---------------------------------------------------------------------------------------
// Configuration (TOML)
// ---------------------------------------------------------------------------------------

/// A 3-DOF arm plant file, e.g. `host-sim/plants/arm3-seed001.toml`. Every table denies
/// unknown keys; every key without a stated default is required.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Arm3Config {
    /// Must be `"arm3"` (what `host-sim simulate` dispatches on).
    pub kind: String,
    /// Replace the `[jointN.initial]` angles by the static equilibrium under gravity at the
    /// initial pressures (found from those angles by Newton's method). Default false.
    #[serde(default)]
    pub settle_initial_angles: bool,
    pub environment: EnvironmentConfig,
    /// The same ISO 6358 characteristic for all twelve valves.
    pub valve: ValveConfig,
    pub links: LinksConfig,
    pub joint1: ArmJointConfig,
    pub joint2: ArmJointConfig,
    pub joint3: ArmJointConfig,
    /// `[effects]`: what the whole arm shares (the supply).
    #[serde(default)]
    pub effects: ArmEffectsConfig,
}

/// `[effects]` of the whole arm: the effects every muscle shares.
#[derive(Debug, Clone, PartialEq, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArmEffectsConfig {
    /// `[effects.supply_drop]`: the 1-DOF table (static line resistance or tank), here one
    /// supply for all twelve valves: the six inlet flows draw on it together.
    #[serde(default)]
    pub supply_drop: Option<SupplyDrop>,
}

/// `[links]`: the rigid-body parameters of seed 001 tables 3-4 (names of its table 1).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LinksConfig {
    /// I_x2.
    pub inertia_x2_kgm2: f64,
    /// I_x3.
    pub inertia_x3_kgm2: f64,
    /// I_y2.
    pub inertia_y2_kgm2: f64,
    /// I_y3.
    pub inertia_y3_kgm2: f64,
    /// I_z1.
    pub inertia_z1_kgm2: f64,
    /// I_z2.
    pub inertia_z2_kgm2: f64,
    /// I_z3.
    pub inertia_z3_kgm2: f64,
    /// m2.
    pub mass2_kg: f64,
    /// m3.
    pub mass3_kg: f64,
    /// l2, length of link 2 (joint 2 to joint 3).
    pub length2_m: f64,
    /// l_c2, joint 2 to the centre of mass of link 2.
    pub com2_m: f64,
    /// l_c3, joint 3 to the centre of mass of link 3.
    pub com3_m: f64,
    /// g (0 for a gravity-free variant).
    pub gravity_m_s2: f64,
}

/// `[jointN]`: one joint with its muscle pair, friction and initial state.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArmJointConfig {
    /// r = d / 2 of seed 001 eq. 20.
    pub sprocket_radius_m: f64,
    /// chi0, contraction of both muscles at the neutral angle.
    pub initial_contraction: f64,
    /// q_n, the joint angle (in the frame of the M, C, G equations) at which both muscles
    /// have the contraction chi0.
    pub neutral_angle_rad: f64,
    /// Both muscles of the pair (the 1-DOF `[muscle]` table).
    pub muscle: MuscleConfig,
    pub friction: FrictionConfig,
    /// `angle_rad`, `velocity_rad_s`, `p1_gauge_pa`, `p2_gauge_pa` (the 1-DOF `[initial]`).
    pub initial: InitialConfig,
    /// `[jointN.effects.*]`: the 1-DOF effects catalogue on this joint and its two muscles
    /// (the same tables as a 1-DOF plant file's `[effects]`; angles in the joint's own frame,
    /// 0 at `neutral_angle_rad`). On the arm: every effect but the supply (the arm's
    /// `[effects.supply_drop]`, shared by all joints) and the thermal chamber (refused).
    #[serde(default)]
    pub effects: EffectsConfig,
}

/// `[jointN.friction]`: seed 001 eq. 7, f_c sgn(w) + f_d w + f_e w^2 sgn(w) + f_g w^3.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrictionConfig {
    /// f_c.
    pub coulomb_nm: f64,
    /// f_d.
    pub viscous_nm_s_per_rad: f64,
    /// f_e.
    pub quadratic_nm_s2_per_rad2: f64,
    /// f_g.
    pub cubic_nm_s3_per_rad3: f64,
    /// w_eps of sgn(w) ~ tanh(w / w_eps) (not in seed 001; small, > 0).
    pub sign_smoothing_velocity_rad_s: f64,
    /// `[jointN.friction.lugre]`: a true stick-slip model in place of the regularised sign
    /// (not in seed 001; absent: the regularised eq. 7).
    #[serde(default)]
    pub lugre: Option<LuGreConfig>,
}

/// LuGre friction (Canudas de Wit, Olsson, Astrom, Lischinsky 1995): bristle deflection `z`
/// [rad] with `z' = w - sigma0 |w| z / g(w)`, `g(w) = f_c + (f_s - f_c) exp(-(w / w_s)^2)`,
/// friction torque `sigma0 z + sigma1 z'` plus eq. 7's viscous, quadratic and cubic terms.
/// At rest under a torque below `f_s` the bristles deflect by `torque / sigma0` and the
/// joint sticks; above it, it slides (the Coulomb level `f_c` of eq. 7 while sliding).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LuGreConfig {
    /// f_s: breakaway (static) torque [N m], >= f_c.
    pub static_nm: f64,
    /// w_s: Stribeck velocity [rad/s], > 0.
    pub stribeck_velocity_rad_s: f64,
    /// sigma0: bristle stiffness [N m/rad], > 0.
    pub stiffness_nm_per_rad: f64,
    /// sigma1: bristle damping [N m s/rad], >= 0.
    pub damping_nm_s_per_rad: f64,
}

impl Arm3Config {
    /// Reads and validates a 3-DOF arm plant file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ConfigError> {
        let path = path.as_ref();
        Self::from_toml_str(&read_plant_text(path)?, path)
    }

    /// Parses and validates arm TOML text (a validation error names its key's line); `path`
    /// is only used in error messages.
    pub fn from_toml_str(text: &str, path: impl AsRef<Path>) -> Result<Self, ConfigError> {
        parse_plant_text(text, path.as_ref(), Self::validate)
    }

    fn validate(&self, path: &Path) -> Result<(), ConfigError> {
        let bad = |key: &str, message: String| ConfigError::Invalid {
            path: path.to_owned(),
            key: key.to_owned(),
            message,
        };
        if self.kind != KIND {
            return Err(bad(
                "kind",
                format!(
                    "must be \"{KIND}\" in a 3-DOF arm file, got {:?}",
                    self.kind
                ),
            ));
        }
        // Physical or practical ranges, the 1-DOF file's where the key is the same
        // (`PlantConfig::validate`): wide enough for any real rig, narrow enough to catch a
        // unit typed wrong (kPa in a Pa key) or a value the model cannot run in finite time.
        use crate::plant::config::{environment_range_rows, initial_range_rows, muscle_range_rows};
        use crate::validate::{range_rows, Range};
        use std::f64::consts::PI;
        let mut rows = environment_range_rows(&self.environment);
        // M stays positive definite for every q if Iz1, Ix2, Ix3 > 0 and the rest >= 0.
        rows.extend(range_rows![self, "";
            valve.sonic_conductance_m3_per_s_pa: SONIC_CONDUCTANCE_M3_PER_S_PA, SONIC_CONDUCTANCE_UNIT;
            links.inertia_x2_kgm2: INERTIA_KGM2, INERTIA_UNIT;
            links.inertia_x3_kgm2: INERTIA_KGM2, INERTIA_UNIT;
            links.inertia_z1_kgm2: INERTIA_KGM2, INERTIA_UNIT;
            links.inertia_y2_kgm2: Range::closed(0.0, INERTIA_KGM2.hi), INERTIA_UNIT;
            links.inertia_y3_kgm2: Range::closed(0.0, INERTIA_KGM2.hi), INERTIA_UNIT;
            links.inertia_z2_kgm2: Range::closed(0.0, INERTIA_KGM2.hi), INERTIA_UNIT;
            links.inertia_z3_kgm2: Range::closed(0.0, INERTIA_KGM2.hi), INERTIA_UNIT;
            links.mass2_kg: Range::closed(0.0, 1.0e3), "kg";
            links.mass3_kg: Range::closed(0.0, 1.0e3), "kg";
            links.length2_m: Range::closed(0.0, 10.0), "m";
            links.com2_m: Range::closed(-10.0, 10.0), "m";
            links.com3_m: Range::closed(-10.0, 10.0), "m";
            links.gravity_m_s2: Range::closed(0.0, 30.0), "m/s^2";
        ]);
        for (i, j) in self.joints().iter().enumerate() {
            let k = format!("joint{}.", i + 1);
            rows.extend(range_rows![j, &k;
                sprocket_radius_m: SPROCKET_RADIUS_M, SPROCKET_UNIT;
                initial_contraction: Range::half_open(0.0, 1.0), "fraction";
                neutral_angle_rad: Range::closed(-PI, PI), "rad";
            ]);
            rows.extend(muscle_range_rows(&j.muscle, &k));
            rows.extend(range_rows![j.friction, format!("{k}friction.");
                coulomb_nm: Range::closed(0.0, FRICTION_MAX_NM), "N m";
                viscous_nm_s_per_rad: Range::closed(0.0, FRICTION_MAX_NM), "N m s/rad";
                quadratic_nm_s2_per_rad2: Range::closed(0.0, FRICTION_MAX_NM), "N m s^2/rad^2";
                cubic_nm_s3_per_rad3: Range::closed(0.0, FRICTION_MAX_NM), "N m s^3/rad^3";
                sign_smoothing_velocity_rad_s: SIGN_SMOOTHING_RANGE_RAD_S,
                    "rad/s (smaller makes the equations too stiff to integrate in useful time)";
            ]);
            rows.extend(initial_range_rows(&j.initial, &self.environment, &k));
            if let Some(lg) = &j.friction.lugre {
                rows.extend(range_rows![lg, format!("{k}friction.lugre.");
                    static_nm: Range::closed(0.0, FRICTION_MAX_NM), "N m";
                    stribeck_velocity_rad_s: Range::positive(10.0), "rad/s";
                    stiffness_nm_per_rad: LUGRE_STIFFNESS_RANGE_NM_PER_RAD,
                        "N m/rad (stiffer bristles make the equations too stiff to integrate in \
                         useful time)";
                    damping_nm_s_per_rad: LUGRE_DAMPING_RANGE_NM_S_PER_RAD, "N m s/rad";
                ]);
            }
        }
        if let Some((key, msg)) = crate::validate::first_range_error(&rows) {
            return Err(bad(key, msg));
        }
        for (i, j) in self.joints().iter().enumerate() {
            let k = format!("joint{}.", i + 1);
            let m = &j.muscle;
            // The Tondu force vanishes at the maximum contraction: the muscles must start
            // below it (as the 1-DOF file's).
            let chi_max =
                (1.0 - 1.0 / (3f64.sqrt() * m.braid_angle_deg.to_radians().cos())) / m.end_factor;
            if !(j.initial_contraction < chi_max) {
                return Err(bad(
                    &format!("{k}initial_contraction"),
                    format!(
                        "must be within [0, {chi_max:.4}) (below the muscle's maximum contraction \
                         (1 - 1/(sqrt(3) cos braid_angle)) / end_factor), got {}",
                        j.initial_contraction
                    ),
                ));
            }
            // (b0 > 0 is the range row's.)
            if let Some(msg) = crate::plant::config::volume_coefficients_error(&m.volume_poly_m3) {
                return Err(bad(&format!("{k}muscle.volume_poly_m3"), msg));
            }
        }
        for (i, j) in self.joints().iter().enumerate() {
            if let Some(l) = &j.friction.lugre {
                if !(l.static_nm.is_finite() && l.static_nm >= j.friction.coulomb_nm) {
                    return Err(bad(
                        &format!("joint{}.friction.lugre.static_nm", i + 1),
                        format!(
                            "must be a finite number >= coulomb_nm ({}), got {}",
                            j.friction.coulomb_nm, l.static_nm
                        ),
                    ));
                }
            }
        }
        self.validate_joint_effects(path)?;
        if let Some(sd) = &self.effects.supply_drop {
            sd.validate(&Check::new(path, "supply_drop"))?;
        }
        if let Some((key, msg)) = crate::plant::config::valve_ratio_error(&self.valve) {
            return Err(bad(&key, msg));
        }
        if let Some((key, msg)) = crate::plant::config::valve_override_error(&self.valve) {
            return Err(bad(&key, msg));
        }
        for (i, j) in self.joints().iter().enumerate() {
            if j.muscle.has_overrides() {
                let name = if j.muscle.m1.is_some() { "m1" } else { "m2" };
                return Err(bad(
                    &format!("joint{}.muscle.{name}", i + 1),
                    "per-muscle tables are read by the 1-DOF plant only: the arm's joints \
                     have one [jointN.muscle] table for both muscles"
                        .into(),
                ));
            }
        }
        Ok(())
    }

    /// Every joint's `[jointN.effects]`: valid, and none the arm does not model (a supply
    /// drop per joint, a discovered term of the transmission, the tensions, the valves or a
    /// rate, the thermal chamber).
    fn validate_joint_effects(&self, path: &Path) -> Result<(), ConfigError> {
        let bad = |key: &str, message: String| ConfigError::Invalid {
            path: path.to_path_buf(),
            key: key.to_string(),
            message,
        };
        for (i, j) in self.joints().iter().enumerate() {
            let prefix = format!("joint{}.", i + 1);
            j.effects.validate(path).map_err(|e| match e {
                ConfigError::Invalid { path, key, message } => ConfigError::Invalid {
                    path,
                    key: format!("{prefix}{key}"),
                    message,
                },
                other => other,
            })?;
            let active = Effects::from_config(&j.effects, &self.valve);
            if !matches!(active.supply(), Supply::Ideal) {
                return Err(bad(
                    &format!("{prefix}effects.supply_drop"),
                    "the arm's six muscles share one supply: give the supply drop once, as \
                     the arm's [effects.supply_drop]"
                        .into(),
                ));
            }
            if j.effects
                .discovered
                .as_ref()
                .is_some_and(|d| d.arm_refuses())
            {
                return Err(bad(
                    &format!("{prefix}effects.discovered"),
                    "a discovered transmission term, or a term of the muscle tensions, the \
                     valves or a sensor's rate, is not modelled on the 3-DOF arm (terms of the \
                     angle, the speed, the chamber pressures and the sensor maps are)"
                        .into(),
                ));
            }
            if active.thermal_chamber().is_some() {
                return Err(bad(
                    &format!("{prefix}effects.thermal_chamber"),
                    "is not modelled on the 3-DOF arm (every other effect is)".into(),
                ));
            }
        }
        Ok(())
    }

    fn joints(&self) -> [&ArmJointConfig; 3] {
        [&self.joint1, &self.joint2, &self.joint3]
    }
}

/// Largest friction coefficient of a joint (any of eq. 7's and the LuGre static torque):
/// 1000 N m (and per rad/s powers), far above any muscle pair's torque.
pub const FRICTION_MAX_NM: f64 = 1.0e3;

/// Allowed w_eps of the regularised sign [rad/s]: below 1e-4 rad/s the friction torque
/// switches within a velocity the integrator must resolve with ever smaller steps.
pub const SIGN_SMOOTHING_RANGE_RAD_S: crate::validate::Range =
    crate::validate::Range::closed(1.0e-4, 10.0);

/// Allowed LuGre bristle stiffness sigma0 [N m/rad]. LuGre's bristles are stiff springs
/// whose natural frequency sqrt(sigma0 / I) sets the integrator's step: the arm demo's
/// 41 s of scenarios (`host-sim demo --plant` the seed 001 file with a joint-1 LuGre table)
/// take 0.9 s without LuGre, 3.2 s with sigma0 = 1e5, 27 s with 1e6; 1e12 did not end.
pub const LUGRE_STIFFNESS_RANGE_NM_PER_RAD: crate::validate::Range =
    crate::validate::Range::positive(1.0e5);

/// Allowed LuGre bristle damping sigma1 [N m s/rad].
pub const LUGRE_DAMPING_RANGE_NM_S_PER_RAD: crate::validate::Range =
    crate::validate::Range::closed(0.0, 1.0e4);

/// The top-level `kind` of a plant file (`Some("arm3")` for a 3-DOF arm file; the 1-DOF
/// files have none); `None` also when the file cannot be read or is not TOML (the command
/// reading it reports that).
pub fn file_kind(path: impl AsRef<Path>) -> Option<String> {
    let text = std::fs::read_to_string(path).ok()?;
    let v: toml::Table = toml::from_str(&text).ok()?;
    v.get("kind").map(|k| match k.as_str() {
        Some(s) => s.to_owned(),
        None => k.to_string(),
    })
}

/// Whether a plant file is for [`Arm3Config`]: it has a top-level `kind` (the 1-DOF files
/// have none; a `kind` other than `"arm3"` is then reported by [`Arm3Config::load`]). Errors
/// only if the file cannot be read or is not TOML.
pub fn is_arm3_file(path: impl AsRef<Path>) -> Result<bool, ConfigError> {
    let path = path.as_ref();
    let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
        path: path.to_owned(),
        source,
    })?;
    let v: toml::Table = toml::from_str(&text).map_err(|e| ConfigError::Parse {
        path: path.to_owned(),
        message: format!(
            "{}{}",
            e.to_string().trim_end().replace('\n', "\n  "),
            crate::plant::config::not_a_plant_hint(&text)
        ),
    })?;
    Ok(v.contains_key("kind"))
}

// ---------------------------------------------------------------------------------------
// Rigid-body dynamics: M, C, G, friction
// ---------------------------------------------------------------------------------------

/// The link parameters in SI (seed 001 table 1 names).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Links {
    pub ix2: f64,
    pub ix3: f64,
    pub iy2: f64,
    pub iy3: f64,
    pub iz1: f64,
    pub iz2: f64,
    pub iz3: f64,
    pub m2: f64,
    pub m3: f64,
    pub l2: f64,
    pub lc2: f64,
    pub lc3: f64,
    pub g: f64,
}

impl Links {
    pub fn from_config(c: &LinksConfig) -> Self {
        Self {
            ix2: c.inertia_x2_kgm2,
            ix3: c.inertia_x3_kgm2,
            iy2: c.inertia_y2_kgm2,
            iy3: c.inertia_y3_kgm2,
            iz1: c.inertia_z1_kgm2,
            iz2: c.inertia_z2_kgm2,
            iz3: c.inertia_z3_kgm2,
            m2: c.mass2_kg,
            m3: c.mass3_kg,
            l2: c.length2_m,
            lc2: c.com2_m,
            lc3: c.com3_m,
            g: c.gravity_m_s2,
        }
    }

    /// Mass (inertia) matrix M(q).
    pub fn mass_matrix(&self, q: &[f64; 3]) -> Matrix3<f64> {
        let (s2, c2) = q[1].sin_cos();
        let (s23, c23) = (q[1] + q[2]).sin_cos();
        let c3 = q[2].cos();
        let a = self.l2 * c2 + self.lc3 * c23;
        let m11 = self.iy2 * s2 * s2
            + self.iy3 * s23 * s23
            + self.iz1
            + self.iz2 * c2 * c2
            + self.iz3 * c23 * c23
            + self.m2 * self.lc2 * self.lc2 * c2 * c2
            + self.m3 * a * a;
        let m33 = self.ix3 + self.m3 * self.lc3 * self.lc3;
        let m23 = m33 + self.m3 * self.l2 * self.lc3 * c3;
        let m22 = self.ix2
            + self.ix3
            + self.m3 * self.l2 * self.l2
            + self.m2 * self.lc2 * self.lc2
            + self.m3 * self.lc3 * self.lc3
            + 2.0 * self.m3 * self.l2 * self.lc3 * c3;
        Matrix3::new(m11, 0.0, 0.0, 0.0, m22, m23, 0.0, m23, m33)
    }

    /// The partial derivatives dM/dq_k, k = 1..3 (M does not depend on q1).
    pub fn mass_matrix_partials(&self, q: &[f64; 3]) -> [Matrix3<f64>; 3] {
        let (s2, c2) = q[1].sin_cos();
        let (s23, c23) = (q[1] + q[2]).sin_cos();
        let s3 = q[2].sin();
        let a = self.l2 * c2 + self.lc3 * c23;
        let b = self.l2 * s2 + self.lc3 * s23;
        // Seed 001 eq. 2: the coefficients of q1' q2' and q1' q3' are these halves.
        let h12 = (self.iy2 - self.iz2 - self.m2 * self.lc2 * self.lc2) * c2 * s2
            + (self.iy3 - self.iz3) * c23 * s23
            - self.m3 * a * b;
        let h13 = (self.iy3 - self.iz3) * c23 * s23 - self.m3 * self.lc3 * s23 * a;
        let e = self.m3 * self.l2 * self.lc3 * s3;
        let d2 = Matrix3::new(2.0 * h12, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        let d3 = Matrix3::new(2.0 * h13, 0.0, 0.0, 0.0, -2.0 * e, -e, 0.0, -e, 0.0);
        [Matrix3::zeros(), d2, d3]
    }

    /// Coriolis and centrifugal matrix C(q, q') from the Christoffel symbols of M.
    pub fn coriolis_matrix(&self, q: &[f64; 3], qd: &[f64; 3]) -> Matrix3<f64> {
        let dm = self.mass_matrix_partials(q);
        let mut c = Matrix3::zeros();
        for i in 0..3 {
            for j in 0..3 {
                let mut s = 0.0;
                for k in 0..3 {
                    s += 0.5 * (dm[k][(i, j)] + dm[j][(i, k)] - dm[i][(j, k)]) * qd[k];
                }
                c[(i, j)] = s;
            }
        }
        c
    }

    /// Potential energy V(q) (zero with both links horizontal at the joint-2 height).
    pub fn potential_energy_j(&self, q: &[f64; 3]) -> f64 {
        self.g
            * ((self.m2 * self.lc2 + self.m3 * self.l2) * q[1].sin()
                + self.m3 * self.lc3 * (q[1] + q[2]).sin())
    }

    /// Gravity torques G(q) = dV/dq.
    pub fn gravity_torques_nm(&self, q: &[f64; 3]) -> Vector3<f64> {
        let c2 = q[1].cos();
        let c23 = (q[1] + q[2]).cos();
        let g3 = self.g * self.m3 * self.lc3 * c23;
        let g2 = self.g * (self.m2 * self.lc2 + self.m3 * self.l2) * c2 + g3;
        Vector3::new(0.0, g2, g3)
    }

    /// Kinetic energy 1/2 q'^T M q'.
    pub fn kinetic_energy_j(&self, q: &[f64; 3], qd: &[f64; 3]) -> f64 {
        let v = Vector3::from(*qd);
        0.5 * v.dot(&(self.mass_matrix(q) * v))
    }

    /// q'' = M^-1 (tau - C q' - G - F) for joint torques `tau` (muscles) and friction torques
    /// `friction` (the F of eq. 6, i.e. opposing the motion when positive along q').
    pub fn acceleration(
        &self,
        q: &[f64; 3],
        qd: &[f64; 3],
        tau: &[f64; 3],
        friction: &[f64; 3],
    ) -> [f64; 3] {
        let m = self.mass_matrix(q);
        let v = Vector3::from(*qd);
        let rhs = Vector3::from(*tau)
            - self.coriolis_matrix(q, qd) * v
            - self.gravity_torques_nm(q)
            - Vector3::from(*friction);
        // M is symmetric positive definite (validated parameters): Cholesky.
        let x = match m.cholesky() {
            Some(ch) => ch.solve(&rhs),
            None => Vector3::repeat(f64::NAN),
        };
        [x[0], x[1], x[2]]
    }
}

/// Seed 001 eq. 7 for one joint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Eq7Friction {
    pub f_c: f64,
    pub f_d: f64,
    pub f_e: f64,
    pub f_g: f64,
    pub w_eps: f64,
    /// The stick-slip model in place of `f_c tanh(w / w_eps)`.
    pub lugre: Option<LuGreConfig>,
}

impl Eq7Friction {
    pub fn from_config(c: &FrictionConfig) -> Self {
        Self {
            f_c: c.coulomb_nm,
            f_d: c.viscous_nm_s_per_rad,
            f_e: c.quadratic_nm_s2_per_rad2,
            f_g: c.cubic_nm_s3_per_rad3,
            w_eps: c.sign_smoothing_velocity_rad_s,
            lugre: c.lugre,
        }
    }

    /// Friction torque [N m] and bristle deflection rate `z'` [rad/s] at velocity `w` and
    /// deflection `z` (without the LuGre model: eq. 7 regularised, `z' = 0`).
    #[inline(always)]
    pub fn torque_and_rate(&self, w: f64, z: f64) -> (f64, f64) {
        let rest = self.f_d * w + self.f_e * w * w.abs() + self.f_g * w * w * w;
        match &self.lugre {
            None => (self.f_c * (w / self.w_eps).tanh() + rest, 0.0),
            Some(l) => {
                let r = w / l.stribeck_velocity_rad_s;
                let g = self.f_c + (l.static_nm - self.f_c) * (-r * r).exp();
                let dz = w - l.stiffness_nm_per_rad * w.abs() * z / g;
                (
                    l.stiffness_nm_per_rad * z + l.damping_nm_s_per_rad * dz + rest,
                    dz,
                )
            }
        }
    }

    /// F(w) = f_c sgn(w) + f_d w + f_e w |w| + f_g w^3 (the torque the joint loses; it
    /// opposes the motion: w F(w) >= 0).
    #[inline(always)]
    pub fn torque_nm(&self, w: f64) -> f64 {
        self.f_c * (w / self.w_eps).tanh()
            + self.f_d * w
            + self.f_e * w * w.abs()
            + self.f_g * w * w * w
    }
}

// ---------------------------------------------------------------------------------------
// The arm with its muscles
// ---------------------------------------------------------------------------------------

/// One joint's antagonistic muscle pair over its sprocket.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MusclePair {
    pub muscle: Muscle,
    /// r.
    pub sprocket_radius_m: f64,
    /// chi0.
    pub initial_contraction: f64,
    /// q_n.
    pub neutral_angle_rad: f64,
    /// r / l_n.
    pub contraction_per_rad: f64,
}

impl MusclePair {
    /// (chi1, chi2) at joint angle `q`.
    #[inline(always)]
    pub fn contractions(&self, q_rad: f64) -> [f64; 2] {
        let d = self.contraction_per_rad * (q_rad - self.neutral_angle_rad);
        [self.initial_contraction + d, self.initial_contraction - d]
    }

    /// (dchi1/dt, dchi2/dt).
    #[inline(always)]
    pub fn contraction_rates(&self, qd_rad_s: f64) -> [f64; 2] {
        let d = self.contraction_per_rad * qd_rad_s;
        [d, -d]
    }
}

/// Arm state (SI, absolute pressures).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Arm3State {
    pub angles_rad: [f64; 3],
    pub velocities_rad_s: [f64; 3],
    /// (p1, p2) of joints 1..3, absolute.
    pub p_abs_pa: [[f64; 2]; 3],
    /// LuGre bristle deflection of joints 1..3 [rad] (0 without the LuGre model).
    pub friction_z_rad: [f64; 3],
    /// Supply tank pressure [Pa abs] (with a `model = "reservoir"` supply drop; otherwise
    /// unused and constant).
    pub supply_abs_pa: f64,
}

impl Arm3State {
    pub fn to_vector(&self) -> ArmVector {
        let mut y = ArmVector::zeros();
        for i in 0..3 {
            y[i] = self.angles_rad[i];
            y[3 + i] = self.velocities_rad_s[i];
            y[6 + 2 * i] = self.p_abs_pa[i][0];
            y[7 + 2 * i] = self.p_abs_pa[i][1];
            y[12 + i] = self.friction_z_rad[i];
        }
        y[15] = self.supply_abs_pa;
        y
    }

    pub fn from_vector(y: &ArmVector) -> Self {
        let mut s = Self::default();
        for i in 0..3 {
            s.angles_rad[i] = y[i];
            s.velocities_rad_s[i] = y[3 + i];
            s.p_abs_pa[i] = [y[6 + 2 * i], y[7 + 2 * i]];
            s.friction_z_rad[i] = y[12 + i];
        }
        s.supply_abs_pa = y[15];
        s
    }

    pub(crate) fn is_finite(&self) -> bool {
        self.to_vector().iter().all(|v| v.is_finite())
    }
}

/// Valve openings of the three joints, held over one sample.
pub type Arm3Inputs = [ValveInputs; 3];

/// The recorded channels of one joint (same names and units as the 1-DOF recording, with a
/// `_jN` suffix in a 3-joint recording).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct JointMeasurement {
    pub angle_deg: f64,
    /// Gauge.
    pub p1_kpa: f64,
    /// Gauge.
    pub p2_kpa: f64,
    pub f1_n: f64,
    pub f2_n: f64,
}

impl JointMeasurement {
    /// The channel `c` (RECORDING.md's order: angle, p1, p2, f1, f2).
    pub fn channel(&self, c: crate::plant::channel::Channel) -> f64 {
        [
            self.angle_deg,
            self.p1_kpa,
            self.p2_kpa,
            self.f1_n,
            self.f2_n,
        ][c.index()]
    }
}

impl From<Measurement> for JointMeasurement {
    fn from(m: Measurement) -> Self {
        Self {
            angle_deg: m.angle_deg,
            p1_kpa: m.p1_kpa,
            p2_kpa: m.p2_kpa,
            f1_n: m.f1_n,
            f2_n: m.f2_n,
        }
    }
}

/// The 3-DOF arm plant with its derived constants.
#[derive(Debug, Clone, PartialEq)]
pub struct Arm3 {
    pub p_atm_pa: f64,
    pub p_supply_abs_pa: f64,
    pub valve: Iso6358Valve,
    /// The valves of every joint's muscle 1 and 2: inlet 1, exhaust 1, inlet 2, exhaust 2
    /// (`[valve]` with its per-valve tables, the same on each joint).
    pub valves: [Iso6358Valve; 4],
    pub links: Links,
    pub pairs: [MusclePair; 3],
    pub friction: [Eq7Friction; 3],
    /// The enabled `[jointN.effects]` of each joint.
    pub effects: [Effects; 3],
    /// The supply of all twelve valves (the arm's `[effects.supply_drop]`).
    pub supply: Supply,
    pub initial: Arm3State,
}

/// A static equilibrium that could not be found.
#[derive(Debug, thiserror::Error)]
#[error("no static equilibrium found from {start_rad:?} rad: {message}")]
pub struct EquilibriumError {
    pub start_rad: [f64; 3],
    pub message: String,
}

impl Arm3 {
    /// The arm of a validated configuration; with `settle_initial_angles` the initial angles
    /// are the static equilibrium at the initial pressures (velocities then must be zero).
    pub fn from_config(c: &Arm3Config) -> Result<Self, EquilibriumError> {
        let p_atm_pa = c.environment.p_atm_pa;
        let joints = c.joints();
        let pair = |j: &ArmJointConfig| MusclePair {
            muscle: Muscle::from_config(&j.muscle),
            sprocket_radius_m: j.sprocket_radius_m,
            initial_contraction: j.initial_contraction,
            neutral_angle_rad: j.neutral_angle_rad,
            contraction_per_rad: j.sprocket_radius_m / j.muscle.rest_length_m,
        };
        let mut initial = Arm3State {
            supply_abs_pa: c.environment.supply_gauge_pa + p_atm_pa,
            ..Default::default()
        };
        for (i, j) in joints.iter().enumerate() {
            initial.angles_rad[i] = j.initial.angle_rad;
            initial.velocities_rad_s[i] = j.initial.velocity_rad_s;
            initial.p_abs_pa[i] = [
                j.initial.p1_gauge_pa + p_atm_pa,
                j.initial.p2_gauge_pa + p_atm_pa,
            ];
        }
        let mut arm = Self {
            p_atm_pa,
            p_supply_abs_pa: c.environment.supply_gauge_pa + p_atm_pa,
            valve: crate::plant::valve_of(&c.valve),
            valves: [0, 1, 2, 3].map(|v| crate::plant::valve_of(&c.valve.of(v))),
            links: Links::from_config(&c.links),
            pairs: joints.map(pair),
            friction: joints.map(|j| Eq7Friction::from_config(&j.friction)),
            effects: joints.map(|j| Effects::from_config(&j.effects, &c.valve)),
            supply: match &c.effects.supply_drop {
                Some(sd) if sd.enabled() => sd.activate(&c.valve),
                _ => Supply::Ideal,
            },
            initial,
        };
        if c.settle_initial_angles {
            arm.initial.angles_rad =
                arm.static_equilibrium(&initial.p_abs_pa, initial.angles_rad)?;
        }
        Ok(arm)
    }

    /// Loads a plant file; the errors name the file (and the key where there is one).
    pub fn load(path: impl AsRef<Path>) -> Result<Self, Arm3LoadError> {
        let path = path.as_ref();
        let cfg = Arm3Config::load(path)?;
        Self::from_config(&cfg).map_err(|e| Arm3LoadError::Equilibrium {
            path: path.to_owned(),
            source: e,
        })
    }

    /// Muscle torques tau_i = (F1 - F2) r_i (seed 001 eq. 20).
    pub fn muscle_torques_nm(&self, x: &Arm3State) -> [f64; 3] {
        let mut tau = [0.0; 3];
        for (i, pair) in self.pairs.iter().enumerate() {
            let f = self.tensions_n(i, x);
            tau[i] = (f[0] - f[1]) * pair.sprocket_radius_m;
        }
        tau
    }

    /// Tension of muscle `m` of joint `i`: the pair's, with that joint's muscle-friction
    /// effect if enabled (as the 1-DOF plant's).
    #[inline(always)]
    fn tension_n(&self, i: usize, p_gauge_pa: f64, chi: f64, dchi: f64) -> f64 {
        let muscle = &self.pairs[i].muscle;
        match self.effects[i].muscle_friction_n(p_gauge_pa, dchi) {
            None => muscle.tension_n(p_gauge_pa, chi, dchi),
            Some(friction_n) => muscle.tension_with_friction_n(p_gauge_pa, chi, dchi, friction_n),
        }
    }

    /// (F1, F2) of joint `i` in state `x`.
    pub fn tensions_n(&self, i: usize, x: &Arm3State) -> [f64; 2] {
        let pair = &self.pairs[i];
        let chi = pair.contractions(x.angles_rad[i]);
        let dchi = pair.contraction_rates(x.velocities_rad_s[i]);
        let p = x.p_abs_pa[i];
        [
            self.tension_n(i, p[0] - self.p_atm_pa, chi[0], dchi[0]),
            self.tension_n(i, p[1] - self.p_atm_pa, chi[1], dchi[1]),
        ]
    }

    /// Friction torques F(q') of eq. 7 (regularised sign; the LuGre model needs the state:
    /// [`Eq7Friction::torque_and_rate`]).
    pub fn friction_torques_nm(&self, qd: &[f64; 3]) -> [f64; 3] {
        [
            self.friction[0].torque_nm(qd[0]),
            self.friction[1].torque_nm(qd[1]),
            self.friction[2].torque_nm(qd[2]),
        ]
    }

    /// Right-hand side d/dt of the state for inputs `u`.
    pub fn derivatives(&self, x: &Arm3State, u: &Arm3Inputs) -> Arm3State {
        let mut d = Arm3State {
            angles_rad: x.velocities_rad_s,
            ..Default::default()
        };
        let mut tau = [0.0; 3];
        let (inlet1, inlet2) = (&self.valves[0], &self.valves[2]);
        let p_supply = self.supply.pressure_abs_pa(
            [inlet1, inlet2, inlet1, inlet2, inlet1, inlet2],
            self.p_supply_abs_pa,
            x.supply_abs_pa,
            [
                x.p_abs_pa[0][0],
                x.p_abs_pa[0][1],
                x.p_abs_pa[1][0],
                x.p_abs_pa[1][1],
                x.p_abs_pa[2][0],
                x.p_abs_pa[2][1],
            ],
            [
                u[0].u_in1, u[0].u_in2, u[1].u_in1, u[1].u_in2, u[2].u_in1, u[2].u_in2,
            ],
        );
        let mut q_inlet = 0.0;
        for (i, pair) in self.pairs.iter().enumerate() {
            let chi = pair.contractions(x.angles_rad[i]);
            let dchi = pair.contraction_rates(x.velocities_rad_s[i]);
            let u_in = [u[i].u_in1, u[i].u_in2];
            let u_ex = [u[i].u_ex1, u[i].u_ex2];
            let effects = &self.effects[i];
            let pressure_factor = effects.pressure_rate_factor();
            let mut f = [0.0; 2];
            for m in 0..2 {
                let p = x.p_abs_pa[i][m];
                f[m] = self.tension_n(i, p - self.p_atm_pa, chi[m], dchi[m]);
                let mut q = effects.chamber_flow_m3_s(m, p, self.p_atm_pa);
                if u_in[m] != 0.0 {
                    let q_in = u_in[m] * self.valves[2 * m].flow_m3_s(p_supply, p);
                    q += q_in;
                    q_inlet += q_in;
                }
                if u_ex[m] != 0.0 {
                    q -= u_ex[m] * self.valves[2 * m + 1].flow_m3_s(p, self.p_atm_pa);
                }
                d.p_abs_pa[i][m] = pressure_factor
                    * pressure::pressure_rate_pa_s(
                        self.p_atm_pa,
                        p,
                        q,
                        pair.muscle.volume_m3(chi[m]),
                        pair.muscle.volume_rate_m3_s(chi[m], dchi[m]),
                    );
            }
            tau[i] = (f[0] - f[1]) * pair.sprocket_radius_m
                + effects.joint_torque_nm(
                    x.angles_rad[i] - pair.neutral_angle_rad,
                    x.velocities_rad_s[i],
                );
        }
        let mut fr = [0.0; 3];
        for i in 0..3 {
            let (f, dz) =
                self.friction[i].torque_and_rate(x.velocities_rad_s[i], x.friction_z_rad[i]);
            fr[i] = f;
            d.friction_z_rad[i] = dz;
        }
        d.velocities_rad_s = self
            .links
            .acceleration(&x.angles_rad, &x.velocities_rad_s, &tau, &fr);
        d.supply_abs_pa = self.supply.tank_rate_pa_s(
            self.p_atm_pa,
            self.p_supply_abs_pa,
            x.supply_abs_pa,
            q_inlet,
        );
        d
    }

    /// The true channels of joint `i` (what ideal sensors would report).
    pub fn true_channels(&self, i: usize, x: &Arm3State) -> Measurement {
        let f = self.tensions_n(i, x);
        Measurement {
            angle_deg: x.angles_rad[i].to_degrees(),
            p1_kpa: (x.p_abs_pa[i][0] - self.p_atm_pa) / 1000.0,
            p2_kpa: (x.p_abs_pa[i][1] - self.p_atm_pa) / 1000.0,
            f1_n: f[0],
            f2_n: f[1],
        }
    }

    /// The recorded channels of each joint in state `x` with the joints' sensor calibration
    /// (no sensor lag: a lag needs the run, see `sensor_paths` in [`crate::sim::arm3`]).
    pub fn measure(&self, x: &Arm3State) -> [JointMeasurement; 3] {
        std::array::from_fn(|i| self.effects[i].calibrate(self.true_channels(i, x)).into())
    }

    /// Static torque balance at rest: tau_muscle(q, p) - G(q) (friction is zero at rest).
    pub fn static_residual_nm(&self, p_abs_pa: &[[f64; 2]; 3], q: &[f64; 3]) -> Vector3<f64> {
        let x = Arm3State {
            angles_rad: *q,
            velocities_rad_s: [0.0; 3],
            p_abs_pa: *p_abs_pa,
            friction_z_rad: [0.0; 3],
            supply_abs_pa: self.p_supply_abs_pa,
        };
        Vector3::from(self.muscle_torques_nm(&x)) - self.links.gravity_torques_nm(q)
    }

    /// The angles at which the arm rests under gravity with the muscle pressures `p_abs_pa`
    /// (Newton's method from `start_rad` with a central-difference Jacobian and step
    /// halving). Converged when every torque residual is below 1e-9 N m.
    pub fn static_equilibrium(
        &self,
        p_abs_pa: &[[f64; 2]; 3],
        start_rad: [f64; 3],
    ) -> Result<[f64; 3], EquilibriumError> {
        let fail = |message: String| EquilibriumError { start_rad, message };
        let mut q = start_rad;
        let mut r = self.static_residual_nm(p_abs_pa, &q);
        for _ in 0..100 {
            if r.amax() < 1e-9 {
                return Ok(q);
            }
            let h = 1e-7;
            let mut jac = Matrix3::zeros();
            for k in 0..3 {
                let mut qp = q;
                let mut qm = q;
                qp[k] += h;
                qm[k] -= h;
                let col = (self.static_residual_nm(p_abs_pa, &qp)
                    - self.static_residual_nm(p_abs_pa, &qm))
                    / (2.0 * h);
                jac.set_column(k, &col);
            }
            let step = jac
                .lu()
                .solve(&(-r))
                .ok_or_else(|| fail(format!("singular stiffness at {q:?} rad")))?;
            let mut lambda = 1.0;
            loop {
                let qn = [
                    q[0] + lambda * step[0],
                    q[1] + lambda * step[1],
                    q[2] + lambda * step[2],
                ];
                let rn = self.static_residual_nm(p_abs_pa, &qn);
                if rn.norm() < r.norm() || lambda < 1e-6 {
                    q = qn;
                    r = rn;
                    break;
                }
                lambda *= 0.5;
            }
        }
        Err(fail(format!(
            "no convergence in 100 Newton steps (residual {:?} N m at {q:?} rad)",
            r.as_slice()
        )))
    }
}

/// An arm plant file that could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum Arm3LoadError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error("{}: settle_initial_angles: {source}", path.display())]
    Equilibrium {
        path: PathBuf,
        #[source]
        source: EquilibriumError,
    },
}
