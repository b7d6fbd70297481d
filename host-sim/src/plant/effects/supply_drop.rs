//! `[effects.supply_drop]`: the supply pressure sags while the inlet valves draw air (seed
//! 000 lists the compressor pressure drop among the causes of its model error). p_s0 is the
//! nominal supply `environment.supply_gauge_pa + p_atm`.
//!
//! - `model = "static"`: p_s = p_s0 - R q_in(p_s), q_in = sum_i u_in_i Q(p_s, p_i) the
//!   standard volume flow through the inlet valves; the implicit equation has one root (its
//!   left side minus right side grows with p_s) and is solved in every right-hand-side call.
//!   Key: `resistance_pa_s_per_m3` (R >= 0).
//! - `model = "reservoir"`: a tank (isothermal) at p_t, fed from p_s0 through an ISO 6358
//!   orifice with the valves' critical and laminar ratios and sonic conductance C_f:
//!   dp_t/dt = p_atm (C_f-flow(p_s0, p_t) - q_in(p_t)) / V_t, p_t(0) = p_s0; the inlet
//!   valves see p_t. At rest the tank refills to p_s0. Keys: `tank_volume_m3` (V_t > 0),
//!   `feed_conductance_m3_per_s_pa` (C_f > 0). The tank pressure is the fifth ODE state
//!   (see [`crate::sim::Integrator`]).
//!
//! Keys of the other form are errors.
//!
//! Diagnosis: two candidates with the same id (the selection keeps whichever form explains
//! the held-out data better, never both): the chambers fill slower than nominal in
//! proportion to the total inlet flow. Truths: a static drop, and a reservoir.

use serde::Deserialize;

use super::{enabled_default, Check, Effect, Hooks, Truth};
use crate::plant::effects::candidate::{EffectCandidates, 
    clamp_to, pressure_scatter, regress_pressure, Candidate, Screening, Setup,
};
use crate::plant::effects::candidate::Evidence;
use crate::plant::config::PlantConfig;
use crate::plant::tables::{ConfigError, ValveConfig};
use crate::plant::valve::Iso6358Valve;

/// Form of [`SupplyDrop`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SupplyDropModel {
    /// p_supply = p_s0 - R q_in: a line resistance, solved with the valve flow it feeds.
    Static,
    /// A tank of volume V_t fed from p_s0 through an ISO 6358 conductance, drained by the
    /// inlet valves; its pressure is an ODE state.
    Reservoir,
}

/// The `[effects.supply_drop]` table.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SupplyDrop {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    pub model: SupplyDropModel,
    /// R (static form).
    pub resistance_pa_s_per_m3: Option<f64>,
    /// V_t (reservoir form).
    pub tank_volume_m3: Option<f64>,
    /// C_f (reservoir form).
    pub feed_conductance_m3_per_s_pa: Option<f64>,
}

/// The supply the inlet valves see, in the form the right-hand side uses.
#[derive(Debug, Clone, PartialEq)]
pub enum Supply {
    /// The constant nominal supply p_s0 (PLANT.md).
    Ideal,
    /// p_s = p_s0 - R q_in(p_s).
    Static { resistance_pa_s_per_m3: f64 },
    /// A tank with its own pressure state.
    Reservoir {
        tank_volume_m3: f64,
        feed: Iso6358Valve,
    },
}

impl Supply {
    /// Whether the supply adds a state (the tank pressure) to the ODE.
    #[inline(always)]
    pub fn has_state(&self) -> bool {
        matches!(self, Supply::Reservoir { .. })
    }

    /// The supply pressure the inlet valves see [Pa abs]: p_s0 (ideal), the static drop's
    /// root for the `N` chambers at `p_chamber_pa` drawing through their inlet valves
    /// `inlets` with openings `u_in`, or the tank pressure `p_tank_abs_pa` (reservoir).
    #[inline(always)]
    pub fn pressure_abs_pa<const N: usize>(
        &self,
        inlets: [&Iso6358Valve; N],
        p_s0_pa: f64,
        p_tank_abs_pa: f64,
        p_chamber_pa: [f64; N],
        u_in: [f64; N],
    ) -> f64 {
        match self {
            Supply::Ideal => p_s0_pa,
            Supply::Static {
                resistance_pa_s_per_m3,
            } => static_supply_pressure_each_pa(
                inlets,
                p_s0_pa,
                *resistance_pa_s_per_m3,
                p_chamber_pa,
                u_in,
            ),
            Supply::Reservoir { .. } => p_tank_abs_pa,
        }
    }

    /// d/dt of the tank pressure [Pa/s] (0 without a tank): fed from p_s0 through the feed
    /// conductance, drained by the total standard inlet flow `q_inlet_m3_s` of every
    /// chamber on the supply (isothermal).
    #[inline(always)]
    pub fn tank_rate_pa_s(
        &self,
        p_atm_pa: f64,
        p_s0_pa: f64,
        p_tank_abs_pa: f64,
        q_inlet_m3_s: f64,
    ) -> f64 {
        match self {
            Supply::Reservoir {
                tank_volume_m3,
                feed,
            } => {
                let q_feed = feed.flow_m3_s(p_s0_pa, p_tank_abs_pa);
                p_atm_pa * (q_feed - q_inlet_m3_s) / tank_volume_m3
            }
            _ => 0.0,
        }
    }
}

impl Hooks for Supply {
    fn parameters(&self) -> Option<Vec<(String, String)>> {
        match self {
            Supply::Ideal => None,
            Supply::Static {
                resistance_pa_s_per_m3,
            } => Some(vec![
                ("model".into(), "\"static\"".into()),
                (
                    "resistance_pa_s_per_m3".into(),
                    format!("{resistance_pa_s_per_m3}"),
                ),
            ]),
            Supply::Reservoir {
                tank_volume_m3,
                feed,
            } => Some(vec![
                ("model".into(), "\"reservoir\"".into()),
                ("tank_volume_m3".into(), format!("{tank_volume_m3}")),
                (
                    "feed_conductance_m3_per_s_pa".into(),
                    format!("{}", feed.sonic_conductance_m3_per_s_pa),
                ),
            ]),
        }
    }
    #[inline(always)]
    fn supply(&self) -> Option<&Supply> {
        Some(self)
    }
}

/// Solves p_s = p_s0 - R q(p_s) for the static supply drop, q(p) = sum_i u_i Q(p, p_i) (the
/// inlet flow at supply pressure p). g(p) = p - p_s0 + R q(p) is increasing in p (each Q(p,
/// p_i) is), negative at min(p_s0, p_i) and positive at max(p_s0, p_i), so the root is
/// bracketed; Illinois regula falsi to |g| <= 1e-7 Pa (g' >= 1, so that is the error in p).
///
/// `N` chambers draw from the line: the 1-DOF plant's two muscles, or all six of the arm's
/// (one supply shared by every joint).
pub fn static_supply_pressure_pa<const N: usize>(
    valve: &Iso6358Valve,
    p_s0_pa: f64,
    resistance_pa_s_per_m3: f64,
    p_chamber_pa: [f64; N],
    u_in: [f64; N],
) -> f64 {
    static_supply_pressure_each_pa([valve; N], p_s0_pa, resistance_pa_s_per_m3, p_chamber_pa, u_in)
}

/// [`static_supply_pressure_pa`] with each chamber's own inlet valve (a plant file's
/// per-valve tables).
pub fn static_supply_pressure_each_pa<const N: usize>(
    inlets: [&Iso6358Valve; N],
    p_s0_pa: f64,
    resistance_pa_s_per_m3: f64,
    p_chamber_pa: [f64; N],
    u_in: [f64; N],
) -> f64 {
    if resistance_pa_s_per_m3 == 0.0 || u_in.iter().all(|u| *u == 0.0) {
        return p_s0_pa;
    }
    let g = |p: f64| {
        let mut q = 0.0;
        for i in 0..N {
            if u_in[i] != 0.0 {
                q += u_in[i] * inlets[i].flow_m3_s(p, p_chamber_pa[i]);
            }
        }
        p - p_s0_pa + resistance_pa_s_per_m3 * q
    };
    let (mut lo, mut hi) = (p_s0_pa, p_s0_pa);
    for i in 0..N {
        if u_in[i] != 0.0 {
            lo = lo.min(p_chamber_pa[i]);
            hi = hi.max(p_chamber_pa[i]);
        }
    }
    let (mut g_lo, mut g_hi) = (g(lo), g(hi));
    if g_lo >= 0.0 {
        return lo;
    }
    if g_hi <= 0.0 {
        return hi;
    }
    let mut side = 0i8;
    let mut p = 0.5 * (lo + hi);
    for _ in 0..200 {
        p = (lo * g_hi - hi * g_lo) / (g_hi - g_lo);
        if !(p > lo && p < hi) {
            p = 0.5 * (lo + hi);
        }
        let gp = g(p);
        if gp.abs() <= 1e-7 || hi - lo <= 1e-9 {
            return p;
        }
        if gp < 0.0 {
            lo = p;
            g_lo = gp;
            if side == -1 {
                g_hi *= 0.5;
            }
            side = -1;
        } else {
            hi = p;
            g_hi = gp;
            if side == 1 {
                g_lo *= 0.5;
            }
            side = 1;
        }
    }
    p
}

/// A TOML key (within its table) and its value, if given.
type KeyValue<'a> = (&'a str, Option<f64>);

impl Effect for SupplyDrop {
    type Active = Supply;
    const TRUTHS: &'static [Truth] = &[
        Truth::new("supply_drop", "supply_drop", |_| "[effects.supply_drop]\nmodel = \"static\"\nresistance_pa_s_per_m3 = 2.0e7\n".into()),
        Truth::new("supply_drop_reservoir", "supply_drop", |_| "[effects.supply_drop]\nmodel = \"reservoir\"\ntank_volume_m3 = 5.0e-4\nfeed_conductance_m3_per_s_pa = 6.0e-9\n".into()),
    ];
    fn enabled(&self) -> bool {
        self.enabled
    }
    fn validate(&self, c: &Check) -> Result<(), ConfigError> {
        let (needed, foreign): (&[KeyValue], &[KeyValue]) = match self.model {
            SupplyDropModel::Static => (
                &[("resistance_pa_s_per_m3", self.resistance_pa_s_per_m3)],
                &[
                    ("tank_volume_m3", self.tank_volume_m3),
                    (
                        "feed_conductance_m3_per_s_pa",
                        self.feed_conductance_m3_per_s_pa,
                    ),
                ],
            ),
            SupplyDropModel::Reservoir => (
                &[
                    ("tank_volume_m3", self.tank_volume_m3),
                    (
                        "feed_conductance_m3_per_s_pa",
                        self.feed_conductance_m3_per_s_pa,
                    ),
                ],
                &[("resistance_pa_s_per_m3", self.resistance_pa_s_per_m3)],
            ),
        };
        let model = match self.model {
            SupplyDropModel::Static => "static",
            SupplyDropModel::Reservoir => "reservoir",
        };
        for (key, v) in foreign {
            if v.is_some() {
                return Err(c.error(key, format!("does not belong to model = \"{model}\"")));
            }
        }
        for (key, v) in needed {
            let Some(v) = v else {
                return Err(c.error(key, format!("missing (required by model = \"{model}\")")));
            };
            if *key == "resistance_pa_s_per_m3" {
                c.non_negative(key, *v)?;
            } else {
                c.positive(key, *v)?;
            }
        }
        Ok(())
    }
    fn activate(&self, valve: &ValveConfig) -> Supply {
        match self.model {
            // validate() guarantees the keys of the chosen form are present.
            SupplyDropModel::Static => Supply::Static {
                resistance_pa_s_per_m3: self.resistance_pa_s_per_m3.unwrap_or(0.0),
            },
            SupplyDropModel::Reservoir => Supply::Reservoir {
                tank_volume_m3: self.tank_volume_m3.unwrap_or(f64::INFINITY),
                feed: Iso6358Valve::new(
                    self.feed_conductance_m3_per_s_pa.unwrap_or(0.0),
                    valve.critical_ratio,
                    valve.laminar_ratio,
                ),
            },
        }
    }
}

impl EffectCandidates for SupplyDrop {
    fn candidates() -> Vec<Box<dyn Candidate>> {
        vec![Box::new(SupplyDropCandidate), Box::new(SupplyReservoirCandidate)]
    }
}

/// Regressor of a unit supply-line resistance in each chamber's pressure rate (Pa/s per
/// Pa s/m^3), at the measured states: the change of the inlet flow when the supply drops by
/// 1e4 Pa s/m^3 times the total inlet flow, scaled back to a resistance of 1.
pub fn supply_signature(ev: &Evidence) -> [Vec<f64>; 2] {
    let plant = &ev.plant;
    let n = ev.states.len();
    let p_atm = plant.p_atm_pa;
    let p_s0 = plant.p_supply_abs_pa;
    let mut supply = [vec![0.0; n], vec![0.0; n]];
    for (k, (x, u)) in ev.states.iter().zip(&ev.inputs).enumerate() {
        let chi = plant.joint.contractions(x.angle_rad);
        let p = [x.p1_abs_pa, x.p2_abs_pa];
        let u_in = [u.u_in1, u.u_in2];
        let q_tot: f64 = (0..2)
            .map(|j| u_in[j] * plant.valve.flow_m3_s(p_s0, p[j]))
            .sum();
        let delta = 1.0; // Pa s/m^3 of line resistance
        for i in 0..2 {
            let v = plant.muscles[i].volume_m3(chi[i]);
            if u_in[i] != 0.0 && q_tot > 0.0 {
                let dq = plant.valve.flow_m3_s(p_s0 - delta * 1e4 * q_tot, p[i])
                    - plant.valve.flow_m3_s(p_s0, p[i]);
                supply[i][k] = p_atm * u_in[i] * dq / (1e4 * v);
            }
        }
    }
    supply
}

/// The screening of both forms: the chambers' pressure-rate residual regressed on
/// [`supply_signature`]; `initial(coefficient)` gives the initial parameters, `note` says
/// what a good score means.
fn screen_supply(ev: &Evidence, note: &str, initial: impl FnOnce(f64) -> Vec<f64>) -> Screening {
    let sig = supply_signature(ev);
    let (c, r2) = regress_pressure(ev, &sig);
    Screening {
        score: r2,
        initial: initial(c),
        note: format!("{note} (R^2 {r2:.2})"),
        scatter: pressure_scatter(ev, &sig, "supply-drop regressor [Pa/s per Pa s/m^3]"),
    }
}

/// The static form: a line resistance.
pub struct SupplyDropCandidate;

impl Candidate for SupplyDropCandidate {
    candidate_spec! {
        id: "supply_drop",
        label: "supply pressure drop",
        params: [("resistance_pa_s_per_m3", 0.0, 1e9, 1e7)],
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        let note = "the chambers fill slower than nominal in proportion to the total inlet flow";
        screen_supply(ev, note, |c| clamp_to(&self.params(s), vec![c]))
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], _s: &Setup) {
        cfg.effects.supply_drop = Some(SupplyDrop {
            enabled: true,
            model: SupplyDropModel::Static,
            resistance_pa_s_per_m3: Some(p[0].max(0.0)),
            tank_volume_m3: None,
            feed_conductance_m3_per_s_pa: None,
        });
    }
    fn describe(&self, p: &[f64], _s: &Setup) -> String {
        format!(
            "the supply pressure sags while the inlet valves draw air (line resistance {:.3e} Pa s/m^3)",
            p[0]
        )
    }
}

/// The supply drop in its reservoir form (same effect id as [`SupplyDropCandidate`]: the
/// selection keeps whichever form explains the held-out data better, never both).
pub struct SupplyReservoirCandidate;

impl Candidate for SupplyReservoirCandidate {
    candidate_spec! {
        id: "supply_drop",
        label: "supply pressure drop",
        params: [
            ("tank_volume_m3", 1e-6, 0.1, 1e-3),
            ("feed_conductance_m3_per_s_pa", 1e-11, 1e-6, 1e-8),
        ],
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        let note = "the chambers fill slower than nominal while the inlet valves draw air, as from a supply tank that drains and refills";
        // No closed form for the tank: the typical sizes.
        screen_supply(ev, note, |_| self.params(s).iter().map(|p| p.scale).collect())
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], _s: &Setup) {
        cfg.effects.supply_drop = Some(SupplyDrop {
            enabled: true,
            model: SupplyDropModel::Reservoir,
            resistance_pa_s_per_m3: None,
            tank_volume_m3: Some(p[0].max(1e-9)),
            feed_conductance_m3_per_s_pa: Some(p[1].max(1e-14)),
        });
    }
    fn describe(&self, p: &[f64], _s: &Setup) -> String {
        format!(
            "the supply sags while the inlet valves draw air, as from a {:.2} L tank fed through a conductance of {:.3e} m^3/(s Pa)",
            p[0] * 1e3,
            p[1]
        )
    }
}
