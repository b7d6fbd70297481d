//! The list of a plant's active effects with their parameters, as every run prints it and
//! writes it into its recording's metadata (`# effects = ...`).

use std::fmt;

use crate::plant::effects::Supply;
use crate::plant::Plant;

/// One active effect: its `[effects.NAME]` table name and its parameters (TOML key, value in
/// the key's unit, as TOML would write it).
#[derive(Debug, Clone, PartialEq)]
pub struct ActiveEffect {
    pub name: &'static str,
    pub parameters: Vec<(String, String)>,
}

fn effect(name: &'static str, p: &[(&str, f64)]) -> ActiveEffect {
    ActiveEffect {
        name,
        parameters: p
            .iter()
            .map(|(k, v)| (k.to_string(), format!("{v}")))
            .collect(),
    }
}

impl fmt::Display for ActiveEffect {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}(", self.name)?;
        for (i, (k, v)) in self.parameters.iter().enumerate() {
            if i > 0 {
                write!(f, ", ")?;
            }
            write!(f, "{k} = {v}")?;
        }
        write!(f, ")")
    }
}

impl Plant {
    /// The effects this plant runs with, in the order of the `[effects]` tables; empty for the
    /// nominal PLANT.md model. A polytropic exponent of 1 (the nominal isothermal law) and
    /// identity sensor calibrations are not listed: they change nothing.
    pub fn active_effects(&self) -> Vec<ActiveEffect> {
        let e = &self.effects;
        let mut out = Vec::new();
        let mut add = |name: &'static str, p: &[(&str, f64)]| out.push(effect(name, p));
        if let Some(f) = &e.joint_friction {
            add(
                "joint_friction",
                &[
                    ("coulomb_nm", f.coulomb_nm),
                    ("breakaway_nm", f.breakaway_nm),
                    ("stribeck_velocity_rad_s", f.stribeck_velocity_rad_s),
                    ("viscous_nm_s_per_rad", f.viscous_nm_s_per_rad),
                    ("smoothing_velocity_rad_s", f.smoothing_velocity_rad_s),
                ],
            );
        }
        if let Some(g) = &e.gravity {
            add(
                "gravity",
                &[
                    ("mass_kg", g.mass_kg),
                    ("com_distance_m", g.com_distance_m),
                    ("hanging_angle_rad", g.hanging_angle_rad),
                    ("g_m_s2", g.g_m_s2),
                ],
            );
        }
        if let Some(l) = &e.leak {
            add(
                "leakage",
                &[(
                    "sonic_conductance_m3_per_s_pa",
                    l.sonic_conductance_m3_per_s_pa,
                )],
            );
        }
        if e.pressure_exponent != 1.0 {
            add("polytropic", &[("exponent", e.pressure_exponent)]);
        }
        if let Some(d) = e.valve_dead_time_s {
            add("valve_dead_time", &[("delay_s", d)]);
        }
        if let Some(c) = &e.sensor {
            let names = ["angle_deg", "p1_kpa", "p2_kpa", "f1_n", "f2_n"];
            let mut p = Vec::new();
            for (name, c) in names.iter().zip(c) {
                if c.offset != 0.0 {
                    p.push((format!("{name}.offset"), format!("{}", c.offset)));
                }
                if c.gain != 1.0 {
                    p.push((format!("{name}.gain"), format!("{}", c.gain)));
                }
            }
            if !p.is_empty() {
                out.push(ActiveEffect {
                    name: "sensor",
                    parameters: p,
                });
            }
        }
        if let Some(l) = &e.sensor_lag {
            let mut p = Vec::new();
            for (k, v) in [
                ("angle_time_constant_s", l.angle_time_constant_s),
                ("pressure_time_constant_s", l.pressure_time_constant_s),
                ("force_time_constant_s", l.force_time_constant_s),
            ] {
                if let Some(v) = v {
                    p.push((k.to_string(), format!("{v}")));
                }
            }
            out.push(ActiveEffect {
                name: "sensor_lag",
                parameters: p,
            });
        }
        if let Some(h) = &e.muscle_hysteresis {
            out.push(effect(
                "muscle_hysteresis",
                &[
                    ("base_force_n", h.base_force_n),
                    ("pressure_gain_n_per_pa", h.pressure_gain_n_per_pa),
                    ("smoothing_rate_per_s", h.smoothing_rate_per_s),
                ],
            ));
        }
        match &e.supply {
            Supply::Ideal => {}
            Supply::Static {
                resistance_pa_s_per_m3,
            } => out.push(ActiveEffect {
                name: "supply_drop",
                parameters: vec![
                    ("model".into(), "\"static\"".into()),
                    (
                        "resistance_pa_s_per_m3".into(),
                        format!("{resistance_pa_s_per_m3}"),
                    ),
                ],
            }),
            Supply::Reservoir {
                tank_volume_m3,
                feed,
            } => out.push(ActiveEffect {
                name: "supply_drop",
                parameters: vec![
                    ("model".into(), "\"reservoir\"".into()),
                    ("tank_volume_m3".into(), format!("{tank_volume_m3}")),
                    (
                        "feed_conductance_m3_per_s_pa".into(),
                        format!("{}", feed.sonic_conductance_m3_per_s_pa),
                    ),
                ],
            }),
        }
        out
    }

    /// [`Self::active_effects`] on one line: `none (nominal model)` or the effects separated
    /// by `; `, e.g. `valve_dead_time(delay_s = 0.008); sensor_lag(angle_time_constant_s = 0.03)`.
    pub fn effects_summary(&self) -> String {
        let a = self.active_effects();
        if a.is_empty() {
            return "none (nominal model)".into();
        }
        a.iter()
            .map(ToString::to_string)
            .collect::<Vec<_>>()
            .join("; ")
    }
}
