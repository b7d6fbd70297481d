//! Optional, switchable model extensions beyond the nominal PLANT.md model.
//!
//! Each effect is its own TOML table under `[effects]`; a table that is absent (as in the
//! nominal reference files) or has `enabled = false` leaves the nominal model untouched.
//! Effects plug into one of three places:
//! - joint torque (right-hand side of J omega' = T + sum of effect torques): [`JointFriction`],
//!   [`Gravity`];
//! - chamber flow (right-hand side of the pressure ODE): [`Leakage`];
//! - the measurement (what a sensor reports for a state): [`SensorCalibration`].
//!
//! Not implemented yet (the table name is rejected as unknown, so a file asking for it fails
//! loudly instead of being silently simulated without it): braid hysteresis, sensor lag,
//! valve dead time, supply pressure drop, polytropic pressure dynamics.

use std::path::Path;

use serde::Deserialize;

use crate::config::ConfigError;
use crate::plant::valve::Iso6358Valve;

fn enabled_default() -> bool {
    true
}

/// The `[effects]` table.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EffectsConfig {
    pub joint_friction: Option<JointFriction>,
    pub gravity: Option<Gravity>,
    pub leakage: Option<Leakage>,
    pub sensor: Option<SensorCalibration>,
}

/// `[effects.joint_friction]`: Coulomb + viscous + Stribeck friction torque on the joint
/// (Cakurda et al. eq. 7 family), sign function regularized with tanh(omega / omega_eps)
/// so that the right-hand side stays continuous for the explicit integrator.
///
/// T_f = -[(T_c + (T_s - T_c) exp(-(omega / omega_s)^2)) tanh(omega / omega_eps) + d omega]
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JointFriction {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    /// T_c, Coulomb (sliding) friction torque.
    pub coulomb_nm: f64,
    /// T_s, breakaway (static) friction torque, >= T_c; equal to T_c disables the Stribeck dip.
    pub breakaway_nm: f64,
    /// omega_s, Stribeck velocity.
    pub stribeck_velocity_rad_s: f64,
    /// d, viscous coefficient.
    pub viscous_nm_s_per_rad: f64,
    /// omega_eps, regularization velocity of the sign function (small, > 0).
    pub smoothing_velocity_rad_s: f64,
}

impl JointFriction {
    /// Friction torque acting on the joint (opposes the velocity).
    #[inline]
    pub fn torque_nm(&self, velocity_rad_s: f64) -> f64 {
        let w = velocity_rad_s;
        let r = w / self.stribeck_velocity_rad_s;
        let level = self.coulomb_nm + (self.breakaway_nm - self.coulomb_nm) * (-r * r).exp();
        -(level * (w / self.smoothing_velocity_rad_s).tanh() + self.viscous_nm_s_per_rad * w)
    }
}

/// `[effects.gravity]`: a point load on the arm, T_g = -m g l sin(beta - beta_hang).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Gravity {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    pub mass_kg: f64,
    /// Distance of the centre of mass from the joint axis.
    pub com_distance_m: f64,
    /// Joint angle at which the load hangs straight down (stable equilibrium).
    pub hanging_angle_rad: f64,
    #[serde(default = "standard_gravity")]
    pub g_m_s2: f64,
}

fn standard_gravity() -> f64 {
    9.806_65
}

impl Gravity {
    #[inline]
    pub fn torque_nm(&self, angle_rad: f64) -> f64 {
        -self.mass_kg
            * self.g_m_s2
            * self.com_distance_m
            * (angle_rad - self.hanging_angle_rad).sin()
    }
}

/// `[effects.leakage]`: a leak from each muscle to atmosphere, modelled as an ISO 6358
/// orifice with the valves' critical and laminar ratios.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Leakage {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    pub sonic_conductance_m3_per_s_pa: f64,
}

/// Offset and gain of one measured channel: reported = gain * true + offset (channel units).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelCalibration {
    #[serde(default)]
    pub offset: f64,
    #[serde(default = "unit_gain")]
    pub gain: f64,
}

fn unit_gain() -> f64 {
    1.0
}

impl ChannelCalibration {
    pub const IDENTITY: Self = Self {
        offset: 0.0,
        gain: 1.0,
    };
    #[inline]
    pub fn apply(&self, v: f64) -> f64 {
        self.gain * v + self.offset
    }
}

/// `[effects.sensor]` with one optional sub-table per channel, e.g.
/// `[effects.sensor.angle_deg]` `offset = 0.2` `gain = 1.01`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorCalibration {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    pub angle_deg: Option<ChannelCalibration>,
    pub p1_kpa: Option<ChannelCalibration>,
    pub p2_kpa: Option<ChannelCalibration>,
    pub f1_n: Option<ChannelCalibration>,
    pub f2_n: Option<ChannelCalibration>,
}

/// The enabled effects, in the form the right-hand side uses.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Effects {
    pub joint_friction: Option<JointFriction>,
    pub gravity: Option<Gravity>,
    pub leak: Option<Iso6358Valve>,
    /// Calibrations of angle_deg, p1_kpa, p2_kpa, f1_n, f2_n (identity when absent).
    pub sensor: Option<[ChannelCalibration; 5]>,
}

impl Effects {
    pub fn from_config(
        c: &EffectsConfig,
        valve_critical_ratio: f64,
        valve_laminar_ratio: f64,
    ) -> Self {
        let id = ChannelCalibration::IDENTITY;
        Self {
            joint_friction: c.joint_friction.clone().filter(|f| f.enabled),
            gravity: c.gravity.clone().filter(|g| g.enabled),
            leak: c.leakage.as_ref().filter(|l| l.enabled).map(|l| {
                Iso6358Valve::new(
                    l.sonic_conductance_m3_per_s_pa,
                    valve_critical_ratio,
                    valve_laminar_ratio,
                )
            }),
            sensor: c.sensor.as_ref().filter(|s| s.enabled).map(|s| {
                [
                    s.angle_deg.unwrap_or(id),
                    s.p1_kpa.unwrap_or(id),
                    s.p2_kpa.unwrap_or(id),
                    s.f1_n.unwrap_or(id),
                    s.f2_n.unwrap_or(id),
                ]
            }),
        }
    }

    /// Sum of the effect torques on the joint.
    #[inline(always)]
    pub fn joint_torque_nm(&self, angle_rad: f64, velocity_rad_s: f64) -> f64 {
        let mut t = 0.0;
        if let Some(f) = &self.joint_friction {
            t += f.torque_nm(velocity_rad_s);
        }
        if let Some(g) = &self.gravity {
            t += g.torque_nm(angle_rad);
        }
        t
    }

    /// Extra standard volume flow into a chamber (negative: out).
    #[inline(always)]
    pub fn chamber_flow_m3_s(&self, p_abs_pa: f64, p_atm_pa: f64) -> f64 {
        match &self.leak {
            Some(l) => -l.flow_m3_s(p_abs_pa, p_atm_pa),
            None => 0.0,
        }
    }
}

impl EffectsConfig {
    pub(crate) fn validate(&self, path: &Path) -> Result<(), ConfigError> {
        let bad = |key: &str, message: String| ConfigError::Invalid {
            path: path.to_owned(),
            key: key.to_owned(),
            message,
        };
        let check = |key: &str, v: f64, min_exclusive: Option<f64>| -> Result<(), ConfigError> {
            if !v.is_finite() {
                return Err(bad(key, format!("must be finite, got {v}")));
            }
            if let Some(m) = min_exclusive {
                if v <= m {
                    return Err(bad(key, format!("must be > {m}, got {v}")));
                }
            }
            Ok(())
        };
        if let Some(f) = &self.joint_friction {
            let k = "effects.joint_friction.";
            check(&format!("{k}coulomb_nm"), f.coulomb_nm, None)?;
            check(&format!("{k}breakaway_nm"), f.breakaway_nm, None)?;
            check(
                &format!("{k}viscous_nm_s_per_rad"),
                f.viscous_nm_s_per_rad,
                None,
            )?;
            check(
                &format!("{k}stribeck_velocity_rad_s"),
                f.stribeck_velocity_rad_s,
                Some(0.0),
            )?;
            check(
                &format!("{k}smoothing_velocity_rad_s"),
                f.smoothing_velocity_rad_s,
                Some(0.0),
            )?;
            if f.coulomb_nm < 0.0 || f.breakaway_nm < f.coulomb_nm {
                return Err(bad(
                    &format!("{k}breakaway_nm"),
                    "need 0 <= coulomb_nm <= breakaway_nm".into(),
                ));
            }
        }
        if let Some(g) = &self.gravity {
            let k = "effects.gravity.";
            check(&format!("{k}mass_kg"), g.mass_kg, None)?;
            check(&format!("{k}com_distance_m"), g.com_distance_m, None)?;
            check(&format!("{k}hanging_angle_rad"), g.hanging_angle_rad, None)?;
            check(&format!("{k}g_m_s2"), g.g_m_s2, None)?;
        }
        if let Some(l) = &self.leakage {
            check(
                "effects.leakage.sonic_conductance_m3_per_s_pa",
                l.sonic_conductance_m3_per_s_pa,
                None,
            )?;
            if l.sonic_conductance_m3_per_s_pa < 0.0 {
                return Err(bad(
                    "effects.leakage.sonic_conductance_m3_per_s_pa",
                    "must be >= 0".into(),
                ));
            }
        }
        if let Some(s) = &self.sensor {
            for (name, c) in [
                ("angle_deg", s.angle_deg),
                ("p1_kpa", s.p1_kpa),
                ("p2_kpa", s.p2_kpa),
                ("f1_n", s.f1_n),
                ("f2_n", s.f2_n),
            ] {
                if let Some(c) = c {
                    check(&format!("effects.sensor.{name}.offset"), c.offset, None)?;
                    check(&format!("effects.sensor.{name}.gain"), c.gain, None)?;
                }
            }
        }
        Ok(())
    }
}
