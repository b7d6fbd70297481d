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

/// Both muscles are identical.
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

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ValveConfig {
    /// C, ISO 6358 sonic conductance.
    pub sonic_conductance_m3_per_s_pa: f64,
    /// b, critical pressure ratio.
    pub critical_ratio: f64,
    /// l, laminar ratio (flow falls linearly to zero above it).
    pub laminar_ratio: f64,
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
