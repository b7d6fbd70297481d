//! The tables of a plant file below `[effects]` (`[environment]`, `[muscle]`, `[joint]`,
//! `[valve]`, `[initial]`) and the error of a plant file that cannot be read or is invalid.
//! A leaf: the effects and the physics read these; [`crate::plant::config`] assembles the file.

use std::path::PathBuf;

use serde::Deserialize;

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EnvironmentConfig {
    /// Atmospheric pressure, absolute.
    pub p_atm_pa: f64,
    /// Supply pressure above atmosphere.
    pub supply_gauge_pa: f64,
}

/// Both muscles, unless a per-muscle table (`[muscle.m1]`, `[muscle.m2]`) overrides some of
/// the keys for one of them ([`MuscleConfig::of`]).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MuscleConfig {
    /// l_n, length at zero contraction.
    pub rest_length_m: f64,
    /// r0, braid radius at rest (Tondu model).
    pub radius_m: f64,
    /// alpha0, initial braid angle.
    pub braid_angle_deg: f64,
    /// k, end-effect factor.
    pub end_factor: f64,
    /// gamma in F_d = gamma * p_gauge * dchi/dt.
    pub damping_m2s: f64,
    /// V(chi) = b0 + b1 chi + b2 chi^2 + b3 chi^3 in m^3.
    pub volume_poly_m3: [f64; 4],
    /// `[muscle.m1]`: keys of muscle 1 that differ from the table's (optional).
    #[serde(default)]
    pub m1: Option<MuscleOverride>,
    /// `[muscle.m2]`: keys of muscle 2 that differ from the table's (optional).
    #[serde(default)]
    pub m2: Option<MuscleOverride>,
}

/// The keys one muscle has of its own (`[muscle.m1]`, `[muscle.m2]`): each missing key is the
/// `[muscle]` table's (`initial_contraction`: `[joint]`'s).
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MuscleOverride {
    pub rest_length_m: Option<f64>,
    pub radius_m: Option<f64>,
    pub braid_angle_deg: Option<f64>,
    pub end_factor: Option<f64>,
    pub damping_m2s: Option<f64>,
    pub volume_poly_m3: Option<[f64; 4]>,
    /// chi0 of this muscle at angle 0 (the `[joint]` key of both otherwise).
    pub initial_contraction: Option<f64>,
}

/// The per-muscle table names, muscle 1 then muscle 2.
pub const MUSCLE_TABLES: [&str; 2] = ["m1", "m2"];

impl MuscleConfig {
    /// The override table of muscle `i` (0: `m1`, 1: `m2`), if the file has one.
    pub fn override_of(&self, i: usize) -> Option<&MuscleOverride> {
        [&self.m1, &self.m2][i].as_ref()
    }

    /// The override table of muscle `i`, created empty when missing (for code that sets a
    /// key of one muscle).
    pub fn override_mut(&mut self, i: usize) -> &mut MuscleOverride {
        let slot = if i == 0 { &mut self.m1 } else { &mut self.m2 };
        slot.get_or_insert_with(MuscleOverride::default)
    }

    /// Whether a per-muscle table exists.
    pub fn has_overrides(&self) -> bool {
        self.m1.is_some() || self.m2.is_some()
    }

    /// Muscle `i` (0 or 1) as the physics sees it: the table's keys with that muscle's
    /// overrides (the result has no override tables).
    pub fn of(&self, i: usize) -> MuscleConfig {
        let o = self.override_of(i).cloned().unwrap_or_default();
        MuscleConfig {
            rest_length_m: o.rest_length_m.unwrap_or(self.rest_length_m),
            radius_m: o.radius_m.unwrap_or(self.radius_m),
            braid_angle_deg: o.braid_angle_deg.unwrap_or(self.braid_angle_deg),
            end_factor: o.end_factor.unwrap_or(self.end_factor),
            damping_m2s: o.damping_m2s.unwrap_or(self.damping_m2s),
            volume_poly_m3: o.volume_poly_m3.unwrap_or(self.volume_poly_m3),
            m1: None,
            m2: None,
        }
    }

    /// chi0 of muscle `i`: its override, else the joint's `initial_contraction`.
    pub fn initial_contraction_of(&self, i: usize, joint_initial_contraction: f64) -> f64 {
        self.override_of(i)
            .and_then(|o| o.initial_contraction)
            .unwrap_or(joint_initial_contraction)
    }
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JointConfig {
    /// r.
    pub sprocket_radius_m: f64,
    /// J.
    pub inertia_kgm2: f64,
    /// chi0, contraction of both muscles at angle 0.
    pub initial_contraction: f64,
    /// Mechanical end stops (optional; see [`crate::plant::joint::EndStops`]). Lower stop
    /// [rad]; default: the angle at which muscle 1 is stretched back to its rest length
    /// (`chi1 = 0`, `-chi0 l_n / r`).
    #[serde(default)]
    pub angle_min_rad: Option<f64>,
    /// Upper stop [rad]; default: muscle 2 at its rest length (`chi2 = 0`, `chi0 l_n / r`).
    #[serde(default)]
    pub angle_max_rad: Option<f64>,
    /// Stiffness of the stops [N m/rad] (default 2000).
    #[serde(default)]
    pub end_stop_stiffness_nm_per_rad: Option<f64>,
    /// Damping of the stops [N m s/rad] (default: damping ratio 0.7 with the joint inertia).
    #[serde(default)]
    pub end_stop_damping_nms_per_rad: Option<f64>,
}

/// The four valves' ISO 6358 characteristic: one for all, unless a per-valve table
/// (`[valve.inlet1]`, `[valve.exhaust1]`, `[valve.inlet2]`, `[valve.exhaust2]`) overrides
/// some of the keys for one valve ([`ValveConfig::of`]).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ValveConfig {
    /// C, ISO 6358 sonic conductance.
    pub sonic_conductance_m3_per_s_pa: f64,
    /// b, critical pressure ratio.
    pub critical_ratio: f64,
    /// l, laminar ratio (flow falls linearly to zero above it).
    pub laminar_ratio: f64,
    /// `[valve.inlet1]`: the inlet valve of muscle 1 (optional).
    #[serde(default)]
    pub inlet1: Option<ValveOverride>,
    /// `[valve.exhaust1]`: the exhaust valve of muscle 1 (optional).
    #[serde(default)]
    pub exhaust1: Option<ValveOverride>,
    /// `[valve.inlet2]`: the inlet valve of muscle 2 (optional).
    #[serde(default)]
    pub inlet2: Option<ValveOverride>,
    /// `[valve.exhaust2]`: the exhaust valve of muscle 2 (optional).
    #[serde(default)]
    pub exhaust2: Option<ValveOverride>,
}

/// The keys one valve has of its own: each missing key is the `[valve]` table's.
#[derive(Debug, Clone, Copy, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ValveOverride {
    pub sonic_conductance_m3_per_s_pa: Option<f64>,
    pub critical_ratio: Option<f64>,
    pub laminar_ratio: Option<f64>,
}

/// The per-valve table names in the order of [`ValveConfig::of`]'s index (and of the
/// recording's valve columns u_in1, u_ex1, u_in2, u_ex2).
pub const VALVE_TABLES: [&str; 4] = ["inlet1", "exhaust1", "inlet2", "exhaust2"];

impl ValveConfig {
    /// The override table of valve `i` ([`VALVE_TABLES`] order), if the file has one.
    pub fn override_of(&self, i: usize) -> Option<&ValveOverride> {
        [&self.inlet1, &self.exhaust1, &self.inlet2, &self.exhaust2][i].as_ref()
    }

    /// The override table of valve `i`, created empty when missing.
    pub fn override_mut(&mut self, i: usize) -> &mut ValveOverride {
        let slot = match i {
            0 => &mut self.inlet1,
            1 => &mut self.exhaust1,
            2 => &mut self.inlet2,
            _ => &mut self.exhaust2,
        };
        slot.get_or_insert_with(ValveOverride::default)
    }

    /// Whether a per-valve table exists.
    pub fn has_overrides(&self) -> bool {
        (0..4).any(|i| self.override_of(i).is_some())
    }

    /// Valve `i` ([`VALVE_TABLES`] order) as the physics sees it: the table's keys with that
    /// valve's overrides (the result has no override tables).
    pub fn of(&self, i: usize) -> ValveConfig {
        let o = self.override_of(i).copied().unwrap_or_default();
        ValveConfig {
            sonic_conductance_m3_per_s_pa: o
                .sonic_conductance_m3_per_s_pa
                .unwrap_or(self.sonic_conductance_m3_per_s_pa),
            critical_ratio: o.critical_ratio.unwrap_or(self.critical_ratio),
            laminar_ratio: o.laminar_ratio.unwrap_or(self.laminar_ratio),
            inlet1: None,
            exhaust1: None,
            inlet2: None,
            exhaust2: None,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InitialConfig {
    pub angle_rad: f64,
    pub velocity_rad_s: f64,
    pub p1_gauge_pa: f64,
    pub p2_gauge_pa: f64,
    /// The angle and the two pressures are what the sensors read (a recording's first
    /// sample), not the plant's state: the plant starts from the values the
    /// `[effects.sensor]` calibration says were read, so a calibration fitted by the
    /// diagnosis moves the start with it. Not a plant-file key.
    #[serde(skip)]
    pub as_read: bool,
}

/// A plant file that could not be read or is invalid.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("{path}: cannot read plant file: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("{path}: key `{key}`: {message}")]
    Invalid {
        path: PathBuf,
        key: String,
        message: String,
    },
    /// An invalid value whose line was found in the file.
    #[error("{path}:{line}: key `{key}`: {message}")]
    InvalidAt {
        path: PathBuf,
        line: usize,
        key: String,
        message: String,
    },
}
