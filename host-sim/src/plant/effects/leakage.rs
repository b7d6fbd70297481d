//! `[effects.leakage]`: a leak from each muscle to atmosphere, modelled as an ISO 6358
//! orifice with the valves' critical and laminar ratios.
//!
//! Diagnosis: the chambers lose pressure at the rate of such an orifice (the pressure-rate
//! residual against the flow of a unit conductance). Truth: C = 4e-10 m^3/(s Pa).

use serde::Deserialize;

use super::{enabled_default, params, Check, Effect, Hooks, Truth};
use crate::diagnose::candidates::{
    clamp_to, pressure_scatter, regress_pressure, Candidate, ParamSpec, Screening, Setup,
};
use crate::diagnose::screen::Evidence;
use crate::plant::config::{ConfigError, PlantConfig, ValveConfig};
use crate::plant::valve::Iso6358Valve;

/// The `[effects.leakage]` table.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Leakage {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    pub sonic_conductance_m3_per_s_pa: f64,
}

/// The leak orifice of one muscle (the run-time form of [`Leakage`]).
#[derive(Debug, Clone, PartialEq)]
pub struct LeakOrifice(pub Iso6358Valve);

impl Hooks for LeakOrifice {
    fn parameters(&self) -> Option<Vec<(String, String)>> {
        Some(params(&[(
            "sonic_conductance_m3_per_s_pa",
            self.0.sonic_conductance_m3_per_s_pa,
        )]))
    }
    #[inline(always)]
    fn chamber_flow_m3_s(&self, p_abs_pa: f64, p_atm_pa: f64) -> f64 {
        -self.0.flow_m3_s(p_abs_pa, p_atm_pa)
    }
}

impl Effect for Leakage {
    type Active = LeakOrifice;
    fn enabled(&self) -> bool {
        self.enabled
    }
    fn validate(&self, c: &Check) -> Result<(), ConfigError> {
        c.non_negative(
            "sonic_conductance_m3_per_s_pa",
            self.sonic_conductance_m3_per_s_pa,
        )
    }
    fn activate(&self, valve: &ValveConfig) -> LeakOrifice {
        LeakOrifice(Iso6358Valve::new(
            self.sonic_conductance_m3_per_s_pa,
            valve.critical_ratio,
            valve.laminar_ratio,
        ))
    }
    fn candidates() -> Vec<Box<dyn Candidate>> {
        vec![Box::new(LeakageCandidate)]
    }
    fn truths() -> Vec<Truth> {
        vec![Truth::new("leakage", "leakage", |_| "[effects.leakage]\nsonic_conductance_m3_per_s_pa = 4.0e-10\n".into())]
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
            let v = plant.muscle.volume_m3(chi[i]);
            leak[i][k] = -p_atm * unit_leak.flow_m3_s(p[i], p_atm) / v;
        }
    }
    leak
}

/// One leak conductance, the same for both muscles.
pub struct LeakageCandidate;

impl Candidate for LeakageCandidate {
    fn id(&self) -> &'static str {
        "leakage"
    }
    fn label(&self) -> &'static str {
        "leakage"
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
        let sig = leak_signature(ev);
        let (c, r2) = regress_pressure(ev, &sig);
        Screening {
            score: r2,
            initial: clamp_to(&self.params(s), vec![c]),
            note: format!(
                "the chambers lose pressure at a rate that follows an orifice to atmosphere (R^2 {r2:.2})"
            ),
            scatter: pressure_scatter(ev, &sig, "leak regressor [Pa/s per m^3/(s Pa)]"),
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], _s: &Setup) {
        cfg.effects.leakage = Some(Leakage {
            enabled: true,
            sonic_conductance_m3_per_s_pa: p[0].max(0.0),
        });
    }
    fn describe(&self, p: &[f64], _s: &Setup) -> String {
        format!(
            "a leak from each muscle to atmosphere (sonic conductance {:.3e} m^3/(s Pa))",
            p[0]
        )
    }
}
