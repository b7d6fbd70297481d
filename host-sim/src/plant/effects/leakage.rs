//! `[effects.leakage]`: a leak to atmosphere from each muscle, or with `muscle = 1` or `2`
//! from that muscle only (a split tube, a worn fitting), modelled as an ISO 6358 orifice with
//! the valves' critical and laminar ratios.
//!
//! Diagnosis: the chambers lose pressure at the rate of such an orifice (the pressure-rate
//! residual against the flow of a unit conductance): `leakage` for both muscles,
//! `leakage_muscle1` / `leakage_muscle2` for one (the residual of that chamber only; the
//! held-out criterion picks the form). Truths: C = 4e-10 m^3/(s Pa) in both, and in muscle 2.

use serde::Deserialize;

use super::{enabled_default, params, Check, Effect, Hooks, Truth};
use crate::plant::effects::candidate::{EffectCandidates, 
    clamp_to, pressure_scatter, regress_pressure, Candidate, ParamSpec, Screening, Setup,
};
use crate::plant::effects::candidate::Evidence;
use crate::plant::config::PlantConfig;
use crate::plant::tables::{ConfigError, ValveConfig};
use crate::plant::valve::Iso6358Valve;

/// The `[effects.leakage]` table.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Leakage {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    pub sonic_conductance_m3_per_s_pa: f64,
    /// The leaking muscle (1 or 2); absent: both, each with this conductance.
    #[serde(default)]
    pub muscle: Option<u8>,
}

/// The leak orifice (the run-time form of [`Leakage`]): in every muscle, or in muscle
/// `only` (0-based).
#[derive(Debug, Clone, PartialEq)]
pub struct LeakOrifice {
    pub orifice: Iso6358Valve,
    pub only: Option<usize>,
}

impl Hooks for LeakOrifice {
    fn parameters(&self) -> Option<Vec<(String, String)>> {
        let mut p = params(&[(
            "sonic_conductance_m3_per_s_pa",
            self.orifice.sonic_conductance_m3_per_s_pa,
        )]);
        if let Some(m) = self.only {
            p.push(("muscle".into(), (m + 1).to_string()));
        }
        Some(p)
    }
    #[inline(always)]
    fn chamber_flow_m3_s(&self, muscle: usize, p_abs_pa: f64, p_atm_pa: f64) -> f64 {
        match self.only {
            Some(m) if m != muscle => 0.0,
            _ => -self.orifice.flow_m3_s(p_abs_pa, p_atm_pa),
        }
    }
}

impl Effect for Leakage {
    type Active = LeakOrifice;
    const TRUTHS: &'static [Truth] = &[
        Truth::new("leakage", "leakage", |_| "[effects.leakage]\nsonic_conductance_m3_per_s_pa = 4.0e-10\n".into()),
        Truth::new("leakage_one_muscle", "leakage_muscle2", |_| {
            "[effects.leakage]\nsonic_conductance_m3_per_s_pa = 6.0e-10\nmuscle = 2\n".into()
        }),
    ];
    fn enabled(&self) -> bool {
        self.enabled
    }
    fn validate(&self, c: &Check) -> Result<(), ConfigError> {
        if let Some(m) = self.muscle {
            if m != 1 && m != 2 {
                return Err(c.error("muscle", format!("{m}: the leaking muscle is 1 or 2")));
            }
        }
        c.within(
            "sonic_conductance_m3_per_s_pa",
            self.sonic_conductance_m3_per_s_pa,
            crate::validate::Range::closed(0.0, crate::plant::config::SONIC_CONDUCTANCE_M3_PER_S_PA.hi),
            crate::plant::config::SONIC_CONDUCTANCE_UNIT,
        )?;
        Ok(())
    }
    fn activate(&self, valve: &ValveConfig) -> LeakOrifice {
        LeakOrifice {
            orifice: Iso6358Valve::new(
                self.sonic_conductance_m3_per_s_pa,
                valve.critical_ratio,
                valve.laminar_ratio,
            ),
            only: self.muscle.map(|m| m as usize - 1),
        }
    }
}

impl EffectCandidates for Leakage {
    fn candidates() -> Vec<Box<dyn Candidate>> {
        vec![
            Box::new(LeakageCandidate { only: None }),
            Box::new(LeakageCandidate { only: Some(0) }),
            Box::new(LeakageCandidate { only: Some(1) }),
        ]
    }
}

/// Regressor of a unit leak conductance in each chamber's pressure rate (Pa/s per
/// m^3/(s Pa)), at the measured states.
pub fn leak_signature(ev: &Evidence) -> [Vec<f64>; 2] {
    let plant = &ev.plant;
    let n = ev.states.len();
    let p_atm = plant.p_atm_pa;
    let unit_leak = Iso6358Valve::new(1.0, plant.valve.critical_ratio, plant.valve.laminar_ratio);
    let mut leak = [vec![0.0; n], vec![0.0; n]];
    for (k, x) in ev.states.iter().enumerate() {
        let chi = plant.joint.contractions(x.angle_rad);
        let p = [x.p1_abs_pa, x.p2_abs_pa];
        for i in 0..2 {
            let v = plant.muscles[i].volume_m3(chi[i]);
            leak[i][k] = -p_atm * unit_leak.flow_m3_s(p[i], p_atm) / v;
        }
    }
    leak
}

/// A leak conductance: the same in both muscles (`only: None`), or in one muscle only.
pub struct LeakageCandidate {
    pub only: Option<usize>,
}

impl Candidate for LeakageCandidate {
    fn id(&self) -> &'static str {
        match self.only {
            None => "leakage",
            Some(0) => "leakage_muscle1",
            Some(_) => "leakage_muscle2",
        }
    }
    fn label(&self) -> &'static str {
        match self.only {
            None => "leakage",
            Some(0) => "leak in muscle 1",
            Some(_) => "leak in muscle 2",
        }
    }
    fn params(&self, _s: &Setup) -> Vec<ParamSpec> {
        vec![ParamSpec::new(
            "sonic_conductance_m3_per_s_pa",
            0.0,
            5e-8,
            2e-10,
        )]
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        let mut sig = leak_signature(ev);
        if let Some(m) = self.only {
            // The other chamber has no leak: its regressor is zero.
            sig[1 - m].iter_mut().for_each(|x| *x = 0.0);
        }
        let (c, r2) = regress_pressure(ev, &sig);
        let which = match self.only {
            None => "the chambers lose".to_string(),
            Some(m) => format!("chamber {} loses", m + 1),
        };
        Screening {
            score: r2,
            initial: clamp_to(&self.params(s), vec![c]),
            note: format!(
                "{which} pressure at a rate that follows an orifice to atmosphere (R^2 {r2:.2})"
            ),
            scatter: pressure_scatter(ev, &sig, "leak regressor [Pa/s per m^3/(s Pa)]"),
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], _s: &Setup) {
        cfg.effects.leakage = Some(Leakage {
            enabled: true,
            sonic_conductance_m3_per_s_pa: p[0].max(0.0),
            muscle: self.only.map(|m| m as u8 + 1),
        });
    }
    fn describe(&self, p: &[f64], _s: &Setup) -> String {
        match self.only {
            None => format!(
                "a leak from each muscle to atmosphere (sonic conductance {:.3e} m^3/(s Pa))",
                p[0]
            ),
            Some(m) => format!(
                "a leak from muscle {} to atmosphere, the other muscle tight (sonic conductance {:.3e} m^3/(s Pa))",
                m + 1,
                p[0]
            ),
        }
    }
}
