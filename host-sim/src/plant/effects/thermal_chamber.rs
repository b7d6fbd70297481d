//! `[effects.thermal_chamber]`: the gas in each muscle has its own temperature, with heat
//! exchange through the wall (seed 004 eq. 1-2; PLANT.md "Optional: thermodynamic chamber").
//!
//! Each muscle gets a temperature state T_i. With R = 287.05 J/(kg K), the heat capacity
//! ratio kappa, the wall heat-transfer coefficient hA (W/K per muscle), the wall (and supply,
//! and ambient) temperature T_w and the ANR density rho = p_atm / (R 293.15 K), the chamber's
//! flows are split into their signed parts q_k (standard m^3/s, positive into the chamber:
//! the inlet valve, minus the exhaust valve, minus a leak); a part carries T_w when it flows
//! in and T_i when it flows out:
//!
//! - H_i = sum_k rho q_k (T_w if q_k > 0 else T_i);  m_dot_i = rho sum_k q_k
//! - dp_i/dt = (kappa R H_i - kappa p_i dV_i/dt + (kappa - 1) hA (T_w - T_i)) / V_i
//! - dT_i/dt = T_i / (p_i V_i) (dp_i/dt V_i + p_i dV_i/dt - R T_i m_dot_i)
//!
//! The gas heats on filling and cools on exhausting, then relaxes to the wall temperature
//! with the time constant m c_v / hA; hA -> infinity is the nominal isothermal model, hA = 0
//! is adiabatic (kappa is then the polytropic exponent). The temperatures are two more ODE
//! states ([`crate::sim::Integrator`] carries them; they start at `initial_temperature_k`).
//!
//! Diagnosis: the measured pressure rate departs from the isothermal one in proportion to it
//! on fast flows and relaxes afterwards; the candidate fits hA with kappa = 1.4 (air). Truth:
//! hA = 2 W/K per muscle, as the independent conformance fixture `pulses_thermal.csv`.

use serde::Deserialize;

use super::{Check, Effect, enabled_default, Hooks, Truth};
use crate::plant::effects::candidate::{
    clamp_to, pressure_scatter, regress_pressure, Candidate, Screening, Setup,
};
use crate::plant::effects::candidate::Evidence;
use crate::plant::config::PlantConfig;
use crate::plant::tables::{ConfigError, ValveConfig};

/// Specific gas constant of air [J/(kg K)].
pub const GAS_CONSTANT_AIR_J_PER_KG_K: f64 = 287.05;
/// Temperature of the standard (ANR) reference state of the valve flows [K].
pub const ANR_REFERENCE_TEMPERATURE_K: f64 = 293.15;
/// Heat capacity ratio of air (the candidate's fixed kappa).
pub const KAPPA_AIR: f64 = 1.4;

fn reference_temperature_k() -> f64 {
    ANR_REFERENCE_TEMPERATURE_K
}

/// The `[effects.thermal_chamber]` table.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ThermalChamber {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    /// hA, heat transfer through the wall of one muscle [W/K] (>= 0; 0: adiabatic).
    pub heat_transfer_w_per_k: f64,
    /// kappa, heat capacity ratio of the gas (> 1; air 1.4).
    pub kappa: f64,
    /// T_w, wall, supply and ambient temperature [K] (default 293.15).
    #[serde(default = "reference_temperature_k")]
    pub wall_temperature_k: f64,
    /// Gas temperature of both muscles at the start of a run [K] (default 293.15).
    #[serde(default = "reference_temperature_k")]
    pub initial_temperature_k: f64,
}

impl ThermalChamber {
    /// Pressure rate [Pa/s] and temperature rate [K/s] of one chamber at absolute pressure
    /// `p_abs_pa` and gas temperature `t_k`, with volume `volume_m3` changing at
    /// `volume_rate_m3_s`, and the signed standard flows `flows_m3_s` (positive in).
    #[inline(always)]
    pub fn rates(
        &self,
        p_atm_pa: f64,
        p_abs_pa: f64,
        t_k: f64,
        volume_m3: f64,
        volume_rate_m3_s: f64,
        flows_m3_s: [f64; 3],
    ) -> (f64, f64) {
        let r = GAS_CONSTANT_AIR_J_PER_KG_K;
        let rho = p_atm_pa / (r * ANR_REFERENCE_TEMPERATURE_K);
        let t_w = self.wall_temperature_k;
        let mut enthalpy = 0.0;
        let mut mass_rate = 0.0;
        for q in flows_m3_s {
            let m = rho * q;
            enthalpy += m * if q > 0.0 { t_w } else { t_k };
            mass_rate += m;
        }
        let k = self.kappa;
        let dp = (k * r * enthalpy - k * p_abs_pa * volume_rate_m3_s
            + (k - 1.0) * self.heat_transfer_w_per_k * (t_w - t_k))
            / volume_m3;
        let dt = t_k / (p_abs_pa * volume_m3)
            * (dp * volume_m3 + p_abs_pa * volume_rate_m3_s - r * t_k * mass_rate);
        (dp, dt)
    }
}

impl Hooks for ThermalChamber {
    parameters!(heat_transfer_w_per_k, kappa, wall_temperature_k, initial_temperature_k);
    #[inline(always)]
    fn thermal_chamber(&self) -> Option<&ThermalChamber> {
        Some(self)
    }
}

impl Effect for ThermalChamber {
    const TRUTHS: &'static [Truth] = &[Truth::new("thermal_chamber", "heat_transfer", |_| {
        "[effects.thermal_chamber]\nheat_transfer_w_per_k = 2.0\nkappa = 1.4\n".into()
    })];
    table_effect!();
    fn validate(&self, c: &Check) -> Result<(), ConfigError> {
        check_fields!(self, c, finite: kappa);
        c.within(
            "heat_transfer_w_per_k",
            self.heat_transfer_w_per_k,
            crate::validate::Range::closed(0.0, 100.0),
            "W/K (a muscle's wall exchanges about 0.1 .. 10; mW/K typed?)",
        )?;
        if !(self.kappa > 1.0 && self.kappa <= 5.0 / 3.0) {
            return Err(c.error(
                "kappa",
                format!(
                    "must be in (1, 5/3] (a heat capacity ratio; air 1.4), got {}",
                    self.kappa
                ),
            ));
        }
        for (key, t) in [
            ("wall_temperature_k", self.wall_temperature_k),
            ("initial_temperature_k", self.initial_temperature_k),
        ] {
            c.finite(key, t)?;
            if !(200.0..=400.0).contains(&t) {
                return Err(c.error(key, format!("must be in [200, 400] K, got {t}")));
            }
        }
        Ok(())
    }
}

effect_candidates!(ThermalChamber => HeatTransferCandidate);

/// Heat exchange of the chamber gas with the wall, kappa of air.
pub struct HeatTransferCandidate;

impl Candidate for HeatTransferCandidate {
    candidate_spec! {
        id: "heat_transfer",
        label: "chamber thermodynamics (gas temperature with wall heat transfer)",
        params: [("heat_transfer_w_per_k", 0.0, 50.0, 1.0)],
        fixed: [("kappa", KAPPA_AIR)],
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        // On fast flows the gas has no time to exchange heat: the pressure rate is the
        // isothermal one times an apparent exponent between 1 and kappa.
        let (c, r2) = regress_pressure(ev, &ev.nominal_dp);
        let apparent = (1.0 + c).clamp(1.0, KAPPA_AIR);
        // A rough inverse of the apparent exponent: hA large -> 1, hA small -> kappa.
        let frac = (apparent - 1.0) / (KAPPA_AIR - 1.0);
        let h = 10.0 * (1.0 - frac).max(0.02) / frac.max(0.02);
        Screening {
            score: r2,
            initial: clamp_to(&self.params(s), vec![h]),
            note: format!(
                "the measured pressure rate is the isothermal one scaled by an apparent exponent {apparent:.2} (R^2 {r2:.2})"
            ),
            scatter: pressure_scatter(ev, &ev.nominal_dp, "nominal pressure rate dp/dt [Pa/s]"),
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], _s: &Setup) {
        // The chamber model replaces the file's pressure law (a polytropic exponent).
        cfg.effects.polytropic = None;
        cfg.effects.thermal_chamber = Some(ThermalChamber {
            enabled: true,
            heat_transfer_w_per_k: p[0],
            kappa: KAPPA_AIR,
            wall_temperature_k: ANR_REFERENCE_TEMPERATURE_K,
            initial_temperature_k: ANR_REFERENCE_TEMPERATURE_K,
        });
    }
    fn describe(&self, p: &[f64], _s: &Setup) -> String {
        format!(
            "the chamber gas heats on filling and cools on exhausting, exchanging {:.3} W/K with the wall (kappa {KAPPA_AIR})",
            p[0]
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plant::{Plant, ValveInputs};
    use crate::sim::{Integrator, SolverOptions};

    const P_ATM_PA: f64 = 101_325.0;

    fn chamber(h: f64) -> ThermalChamber {
        ThermalChamber {
            enabled: true,
            heat_transfer_w_per_k: h,
            kappa: 1.4,
            wall_temperature_k: 293.15,
            initial_temperature_k: 293.15,
        }
    }

    #[test]
    fn a_closed_adiabatic_chamber_follows_the_adiabat() {
        // p V^kappa and T V^(kappa - 1) are constant: dp/p = -kappa dV/V, dT/T = -(kappa-1) dV/V.
        let (p, t, v, dv) = (400e3, 310.0, 2e-5, -3e-5);
        let (dp, dt) = chamber(0.0).rates(P_ATM_PA, p, t, v, dv, [0.0; 3]);
        assert!((dp / p + 1.4 * dv / v).abs() < 1e-12, "{dp}");
        assert!((dt / t + 0.4 * dv / v).abs() < 1e-12, "{dt}");
    }

    #[test]
    fn the_gas_mass_changes_by_the_flows_alone() {
        // m = p V / (R T): dm/dt from (dp, dT, dV) must equal rho * sum(q), in and out.
        let c = chamber(3.0);
        let rho = P_ATM_PA / (GAS_CONSTANT_AIR_J_PER_KG_K * ANR_REFERENCE_TEMPERATURE_K);
        for flows in [[1e-4, 0.0, 0.0], [0.0, -2e-4, -1e-6], [3e-4, -1e-4, 0.0]] {
            let (p, t, v, dv) = (350e3, 280.0, 2.5e-5, 1e-5);
            let (dp, dt) = c.rates(P_ATM_PA, p, t, v, dv, flows);
            let r = GAS_CONSTANT_AIR_J_PER_KG_K;
            let dm = (dp * v + p * dv) / (r * t) - p * v / (r * t * t) * dt;
            let want = rho * flows.iter().sum::<f64>();
            assert!((dm - want).abs() < 1e-9 * want.abs().max(1e-9), "{dm} vs {want}");
        }
    }

    #[test]
    fn at_rest_the_wall_heat_moves_the_pressure_at_constant_volume() {
        // dU = m c_v dT = V dp / (kappa - 1) = hA (T_w - T) dt.
        let c = chamber(2.0);
        let (p, t, v) = (300e3, 330.0, 2e-5);
        let (dp, _) = c.rates(P_ATM_PA, p, t, v, 0.0, [0.0; 3]);
        let want = 0.4 * 2.0 * (293.15 - t) / v;
        assert!((dp - want).abs() < 1e-9 * want.abs());
    }

    fn plant(thermal: &str) -> Plant {
        let text = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tests/fixtures/reference-1dof.toml"
        ))
        .unwrap();
        Plant::from_config(&PlantConfig::from_toml_str(&format!("{text}\n{thermal}"), "t.toml").unwrap())
    }

    #[test]
    fn filling_heats_the_gas_exhausting_cools_it_and_both_relax_to_the_wall() {
        let hot = plant("[effects.thermal_chamber]\nheat_transfer_w_per_k = 2.0\nkappa = 1.4\n");
        let mut integ = Integrator::new(&hot, hot.initial_state(), SolverOptions::default());
        let dt = 1e-3;
        let temps = |i: &Integrator| i.aux().gas_temperature_k;
        assert_eq!(temps(&integ), [293.15, 293.15]);
        // Exhaust muscle 2 and fill muscle 1 for 50 ms.
        let u = ValveInputs {
            u_in1: 1.0,
            u_ex2: 1.0,
            ..ValveInputs::CLOSED
        };
        integ.advance_samples(u, dt, 50, |_| {}).unwrap();
        let [t1, t2] = temps(&integ);
        assert!(t1 > 293.15 + 2.0, "filled gas {t1} K");
        assert!(t2 < 293.15 - 2.0, "exhausted gas {t2} K");
        // Hold 2 s (the time constant m c_v / hA is about 0.1 s): back at the wall.
        integ
            .advance_samples(ValveInputs::CLOSED, dt, 2000, |_| {})
            .unwrap();
        for t in temps(&integ) {
            assert!((t - 293.15).abs() < 0.25, "{t} K after 2 s");
        }
    }

    #[test]
    fn bad_values_name_the_key_and_a_second_pressure_law_is_refused() {
        let text = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tests/fixtures/reference-1dof.toml"
        ))
        .unwrap();
        let e = PlantConfig::from_toml_str(
            &format!("{text}\n[effects.thermal_chamber]\nheat_transfer_w_per_k = 2.0\nkappa = 0.9\n"),
            "k.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("effects.thermal_chamber.kappa") && e.contains("k.toml"), "{e}");
        let e = PlantConfig::from_toml_str(
            &format!(
                "{text}\n[effects.thermal_chamber]\nheat_transfer_w_per_k = 2.0\nkappa = 1.4\n[effects.polytropic]\nexponent = 1.2\n"
            ),
            "both.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("effects.polytropic") && e.contains("thermal chamber"), "{e}");
    }
}
