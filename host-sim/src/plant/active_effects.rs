//! The list of a plant's active effects with their parameters, as every run prints it and
//! writes it into its recording's metadata (`# effects = ...`).

use std::fmt;

use crate::plant::Plant;

/// One active effect: its `[effects.NAME]` table name and its parameters (TOML key, value in
/// the key's unit, as TOML would write it).
#[derive(Debug, Clone, PartialEq)]
pub struct ActiveEffect {
    pub name: &'static str,
    pub parameters: Vec<(String, String)>,
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
    /// The effects this plant runs with, in the order of the effect registry; empty for the
    /// nominal PLANT.md model. A polytropic exponent of 1 (the nominal isothermal law) and
    /// identity sensor calibrations are not listed: they change nothing.
    pub fn active_effects(&self) -> Vec<ActiveEffect> {
        self.effects
            .active()
            .into_iter()
            .map(|(name, parameters)| ActiveEffect { name, parameters })
            .collect()
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
