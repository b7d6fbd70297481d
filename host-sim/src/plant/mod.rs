//! The reference 1-DOF antagonistic PAM joint of `shared/plant/PLANT.md`.
//!
//! Each physics term lives in its own module: [`valve`] (ISO 6358 flow), [`muscle`] (Tondu
//! force, damper, tension, volume polynomial), [`joint`] (kinematics, J omega' = T),
//! [`pressure`] (Boyle-Mariotte), [`effects`] (optional extensions, one module each, off in the nominal files).

pub mod active_effects;
pub mod arm3;
pub mod channel;
pub mod config;
pub mod effects;
pub mod joint;
pub mod muscle;
pub mod pressure;
pub mod state;
pub mod tables;
pub mod valve;

use std::path::Path;

use crate::plant::config::{ConfigError, PlantConfig};
use effects::Effects;
use joint::Joint;
use muscle::Muscle;
use valve::Iso6358Valve;

pub use crate::plant::state::{
    AuxLayout, AuxState, LoadTorque, Measurement, PlantState, ValveInputs,
};

/// The plant with its derived constants; cheap to copy into the integrator.
#[derive(Debug, Clone, PartialEq)]
pub struct Plant {
    pub p_atm_pa: f64,
    /// p_s, absolute supply pressure.
    pub p_supply_abs_pa: f64,
    /// The `[muscle]` table's muscle (both muscles without per-muscle tables).
    pub muscle: Muscle,
    /// Muscle 1 and muscle 2 as the physics uses them (`[muscle]` with `[muscle.m1]`,
    /// `[muscle.m2]`).
    pub muscles: [Muscle; 2],
    pub joint: Joint,
    /// The `[valve]` table's valve (all four without per-valve tables).
    pub valve: Iso6358Valve,
    /// The four valves as the physics uses them: inlet 1, exhaust 1, inlet 2, exhaust 2
    /// (`[valve]` with `[valve.inlet1]` ...).
    pub valves: [Iso6358Valve; 4],
    pub effects: Effects,
    pub initial: PlantState,
    /// An external torque series an open-loop replay applies ([`LoadTorque`]); `None`: none.
    pub load: Option<LoadTorque>,
}

/// The ISO 6358 valve of a (resolved) `[valve]` table.
pub fn valve_of(v: &crate::plant::config::ValveConfig) -> Iso6358Valve {
    Iso6358Valve::new(
        v.sonic_conductance_m3_per_s_pa,
        v.critical_ratio,
        v.laminar_ratio,
    )
}

impl Plant {
    pub fn from_config(c: &PlantConfig) -> Self {
        let p_atm_pa = c.environment.p_atm_pa;
        let effects = Effects::from_config(&c.effects, &c.valve);
        let mut initial = PlantState {
            angle_rad: c.initial.angle_rad,
            velocity_rad_s: c.initial.velocity_rad_s,
            p1_abs_pa: c.initial.p1_gauge_pa + p_atm_pa,
            p2_abs_pa: c.initial.p2_gauge_pa + p_atm_pa,
        };
        // `[initial]` values that are readings: the state the calibration says was read
        // (in the sensors' units, deg and kPa gauge).
        if let (true, Some(cal)) = (c.initial.as_read, &effects.sensor) {
            let [angle, p1, p2] = [cal.0[0], cal.0[1], cal.0[2]];
            initial.angle_rad = angle
                .read_back(c.initial.angle_rad.to_degrees())
                .to_radians();
            initial.p1_abs_pa = p1.read_back(c.initial.p1_gauge_pa * 1e-3) * 1e3 + p_atm_pa;
            initial.p2_abs_pa = p2.read_back(c.initial.p2_gauge_pa * 1e-3) * 1e3 + p_atm_pa;
        }
        Self {
            p_atm_pa,
            p_supply_abs_pa: c.environment.supply_gauge_pa + p_atm_pa,
            muscle: Muscle::from_config(&c.muscle),
            muscles: [0, 1].map(|i| Muscle::from_config(&c.muscle.of(i))),
            joint: Joint::from_config(&c.joint, c.muscle.rest_length_m).with_muscles(
                [0, 1].map(|i| {
                    c.muscle
                        .initial_contraction_of(i, c.joint.initial_contraction)
                }),
                [0, 1].map(|i| c.muscle.of(i).rest_length_m),
            ),
            valve: valve_of(&c.valve),
            valves: [0, 1, 2, 3].map(|i| valve_of(&c.valve.of(i))),
            effects,
            initial,
            load: c.load.clone(),
        }
    }

    /// Loads a plant TOML file (see [`PlantConfig::load`]).
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ConfigError> {
        Ok(Self::from_config(&PlantConfig::load(path)?))
    }

    /// The `[initial]` state.
    pub fn initial_state(&self) -> PlantState {
        self.initial
    }

    /// Muscle tensions F1, F2 in newtons for a state (with the braid friction effect if
    /// enabled: these are the measured `f1_n`, `f2_n`).
    #[inline(always)]
    pub fn tensions_n(&self, x: &PlantState) -> [f64; 2] {
        let (chi, dchi, _) = self.kinematics(x.angle_rad, x.velocity_rad_s);
        let pg = [x.p1_abs_pa - self.p_atm_pa, x.p2_abs_pa - self.p_atm_pa];
        self.tensions_and_contractions(pg, chi, dchi).0
    }

    /// Contractions (chi1, chi2), their rates and the lever [m] at a joint angle and speed:
    /// the joint's kinematics, with a discovered transmission map if enabled (the muscles'
    /// travel r (beta + shift(beta)), lever r (1 + shift'(beta))).
    #[inline(always)]
    pub fn kinematics(&self, angle_rad: f64, velocity_rad_s: f64) -> ([f64; 2], [f64; 2], f64) {
        let chi = self.joint.contractions(angle_rad);
        let dchi = self.joint.contraction_rates(velocity_rad_s);
        let r = self.joint.sprocket_radius_m;
        match self.effects.transmission_map(angle_rad, r) {
            None => (chi, dchi, r),
            Some([shift_m, slope_m]) => {
                let l = r / self.joint.contraction_per_rad;
                let g = 1.0 + slope_m / r;
                (
                    [chi[0] + shift_m / l, chi[1] - shift_m / l],
                    [dchi[0] * g, dchi[1] * g],
                    r * g,
                )
            }
        }
    }

    /// The tensions at gauge pressures `pg` and contractions `chi` (rates `dchi`), and the
    /// contractions the muscles take: with a discovered cable compliance (m/N) each muscle
    /// contracts further by its cable's stretch F c (quasi-static, three fixed-point steps).
    #[inline(always)]
    pub fn tensions_and_contractions(
        &self,
        pg: [f64; 2],
        chi: [f64; 2],
        dchi: [f64; 2],
    ) -> ([f64; 2], [f64; 2]) {
        let f = |chi: [f64; 2]| {
            [
                self.tension_n(0, pg[0], chi[0], dchi[0]),
                self.tension_n(1, pg[1], chi[1], dchi[1]),
            ]
        };
        let mut t = f(chi);
        match self.effects.cable_compliance_m_per_n() {
            None => (t, chi),
            Some(c) => {
                let l = [0, 1].map(|i| self.muscles[i].rest_length_m);
                let mut chi_s = chi;
                for _ in 0..3 {
                    chi_s = [chi[0] + c * t[0] / l[0], chi[1] + c * t[1] / l[1]];
                    t = f(chi_s);
                }
                (t, chi_s)
            }
        }
    }

    /// Tension of muscle `i`: the nominal one, minus the braid friction if enabled.
    #[inline(always)]
    fn tension_n(
        &self,
        i: usize,
        p_gauge_pa: f64,
        contraction: f64,
        contraction_rate_per_s: f64,
    ) -> f64 {
        let muscle = &self.muscles[i];
        match self
            .effects
            .muscle_friction_n(p_gauge_pa, contraction_rate_per_s)
        {
            None => muscle.tension_n(p_gauge_pa, contraction, contraction_rate_per_s),
            Some(friction_n) => muscle.tension_with_friction_n(
                p_gauge_pa,
                contraction,
                contraction_rate_per_s,
                friction_n,
            ),
        }
    }

    /// Whether the plant has a state beyond (beta, omega, p1, p2): the supply reservoir's
    /// pressure ([`effects::SupplyDrop`] with `model = "reservoir"`) or the gas temperatures
    /// ([`effects::ThermalChamber`]).
    pub fn has_aux_state(&self) -> bool {
        !self.aux_layout().is_empty()
    }

    /// Whether the plant has a supply reservoir (its pressure is an ODE state).
    pub fn has_supply_state(&self) -> bool {
        self.effects.supply().has_state()
    }

    /// Which auxiliary states the plant integrates.
    pub fn aux_layout(&self) -> AuxLayout {
        match (
            self.has_supply_state(),
            self.effects.thermal_chamber().is_some(),
        ) {
            (false, false) => AuxLayout::None,
            (true, false) => AuxLayout::Supply,
            (false, true) => AuxLayout::Temperatures,
            (true, true) => AuxLayout::SupplyAndTemperatures,
        }
    }

    /// The supply pressure (absolute) the inlet valves see at the start of a run: p_s0, also
    /// the initial reservoir pressure.
    pub fn initial_supply_abs_pa(&self) -> f64 {
        self.p_supply_abs_pa
    }

    /// The auxiliary states at the start of a run: the reservoir at p_s0, the gas at the
    /// thermal chamber's initial temperature (the ANR reference 293.15 K without one).
    pub fn initial_aux(&self) -> AuxState {
        let t = self
            .effects
            .thermal_chamber()
            .map_or(effects::thermal_chamber::ANR_REFERENCE_TEMPERATURE_K, |c| {
                c.initial_temperature_k
            });
        AuxState {
            supply_abs_pa: self.p_supply_abs_pa,
            gas_temperature_k: [t, t],
            load_torque_nm: self.load.as_ref().map_or(0.0, |l| l.at(0)),
        }
    }

    /// Right-hand side: d/dt of (beta, omega, p1, p2) for inputs `u`, with the auxiliary
    /// states at their initial values (see [`Self::derivatives_aux`]).
    #[inline(always)]
    pub fn derivatives(&self, x: &PlantState, u: &ValveInputs) -> PlantState {
        self.derivatives_aux(x, &self.initial_aux(), u).0
    }

    /// Right-hand side with the supply reservoir pressure `reservoir_abs_pa`: returns d/dt of
    /// (beta, omega, p1, p2) and of the reservoir pressure (0 without a reservoir).
    #[inline(always)]
    pub fn derivatives_with_supply(
        &self,
        x: &PlantState,
        reservoir_abs_pa: f64,
        u: &ValveInputs,
    ) -> (PlantState, f64) {
        let aux = AuxState {
            supply_abs_pa: reservoir_abs_pa,
            ..self.initial_aux()
        };
        let (d, da) = self.derivatives_aux(x, &aux, u);
        (d, da.supply_abs_pa)
    }

    /// The supply pressure the inlet valves see [Pa abs] (ideal, static drop or reservoir).
    #[inline(always)]
    fn supply_abs_pa(&self, p_abs_pa: [f64; 2], aux: &AuxState, u: &ValveInputs) -> f64 {
        self.effects.supply().pressure_abs_pa(
            [&self.valves[0], &self.valves[2]],
            self.p_supply_abs_pa,
            aux.supply_abs_pa,
            p_abs_pa,
            [u.u_in1, u.u_in2],
        )
    }

    /// The signed standard (ANR) volume flows into chamber `i` [m^3/s]: leak, inlet valve
    /// (from `p_supply_abs_pa`), exhaust valve (to the atmosphere). A closed valve
    /// contributes nothing (the flow function is skipped).
    #[inline(always)]
    fn chamber_flows_m3_s(
        &self,
        i: usize,
        p_abs_pa: f64,
        p_supply_abs_pa: f64,
        u: &ValveInputs,
    ) -> [f64; 3] {
        let (u_in, u_ex) = if i == 0 {
            (u.u_in1, u.u_ex1)
        } else {
            (u.u_in2, u.u_ex2)
        };
        let q_leak = self.effects.chamber_flow_m3_s(i, p_abs_pa, self.p_atm_pa);
        let mut q_in = 0.0;
        let mut q_out = 0.0;
        if u_in != 0.0 {
            q_in = u_in * self.valves[2 * i].flow_m3_s(p_supply_abs_pa, p_abs_pa);
        }
        if u_ex != 0.0 {
            q_out = -u_ex * self.valves[2 * i + 1].flow_m3_s(p_abs_pa, self.p_atm_pa);
        }
        if u_in != 0.0 || u_ex != 0.0 {
            q_in += self.effects.chamber_valve_flow_m3_s(
                i,
                p_abs_pa,
                self.p_atm_pa,
                [u_in, u_ex],
                [q_in, q_out],
            );
        }
        [q_leak, q_in, q_out]
    }

    /// The true net mass flow into each muscle [kg/s] at state `x` with the valve openings
    /// `u`: `rho_ANR (Q_leak + Q_in + Q_out)` with `rho_ANR = p_atm / (R 293.15 K)` (the
    /// standard flows of PLANT.md are at the ANR density). What a mass-flow sensor in the
    /// muscle's port would read (the recording columns `m_dot_1_kg_s`, `m_dot_2_kg_s`).
    pub fn chamber_mass_flows_kg_s(
        &self,
        x: &PlantState,
        aux: &AuxState,
        u: &ValveInputs,
    ) -> [f64; 2] {
        let p = [x.p1_abs_pa, x.p2_abs_pa];
        let p_supply = self.supply_abs_pa(p, aux, u);
        let rho_anr = self.p_atm_pa
            / (effects::thermal_chamber::GAS_CONSTANT_AIR_J_PER_KG_K
                * effects::thermal_chamber::ANR_REFERENCE_TEMPERATURE_K);
        let mut out = [0.0; 2];
        for (i, o) in out.iter_mut().enumerate() {
            let q = self.chamber_flows_m3_s(i, p[i], p_supply, u);
            *o = rho_anr * (q[0] + q[1] + q[2]);
        }
        out
    }

    /// Right-hand side with the auxiliary states `aux`: returns d/dt of (beta, omega, p1, p2)
    /// and of the auxiliary states (0 for those the plant does not integrate).
    #[inline(always)]
    pub fn derivatives_aux(
        &self,
        x: &PlantState,
        aux: &AuxState,
        u: &ValveInputs,
    ) -> (PlantState, AuxState) {
        let (chi, dchi, lever) = self.kinematics(x.angle_rad, x.velocity_rad_s);
        let p = [x.p1_abs_pa, x.p2_abs_pa];
        let (tension, chi) =
            self.tensions_and_contractions([p[0] - self.p_atm_pa, p[1] - self.p_atm_pa], chi, dchi);
        let supply = self.effects.supply();
        let reservoir_abs_pa = aux.supply_abs_pa;
        let p_supply = self.supply_abs_pa(p, aux, u);
        let pressure_factor = self.effects.pressure_rate_factor();
        let thermal = self.effects.thermal_chamber();
        let mut q_supply = 0.0;
        let mut dp = [0.0; 2];
        let mut dt = [0.0; 2];
        for i in 0..2 {
            // The signed standard flows into the chamber: leak, inlet, exhaust. A closed
            // valve contributes nothing (skip the flow function).
            let [q_leak, q_in, q_out] = self.chamber_flows_m3_s(i, p[i], p_supply, u);
            q_supply += q_in;
            let volume = self.muscles[i].volume_m3(chi[i]);
            let volume_rate = self.muscles[i].volume_rate_m3_s(chi[i], dchi[i]);
            match thermal {
                None => {
                    dp[i] = pressure_factor
                        * pressure::pressure_rate_pa_s(
                            self.p_atm_pa,
                            p[i],
                            q_leak + q_in + q_out,
                            volume,
                            volume_rate,
                        );
                }
                Some(c) => {
                    (dp[i], dt[i]) = c.rates(
                        self.p_atm_pa,
                        p[i],
                        aux.gas_temperature_k[i],
                        volume,
                        volume_rate,
                        [q_leak, q_in, q_out],
                    );
                }
            }
        }
        let torque = (tension[0] - tension[1]) * lever
            + self.effects.joint_torque_nm(x.angle_rad, x.velocity_rad_s)
            + self.effects.joint_torque_tensions_nm(
                x.angle_rad,
                x.velocity_rad_s,
                tension,
                self.joint.sprocket_radius_m,
            )
            + self.joint.end_stop_torque_nm(x.angle_rad, x.velocity_rad_s)
            + aux.load_torque_nm;
        let d_reservoir = supply.tank_rate_pa_s(
            self.p_atm_pa,
            self.p_supply_abs_pa,
            reservoir_abs_pa,
            q_supply,
        );
        (
            PlantState {
                angle_rad: x.velocity_rad_s,
                velocity_rad_s: self.joint.angular_acceleration_rad_s2(torque),
                p1_abs_pa: dp[0],
                p2_abs_pa: dp[1],
            },
            AuxState {
                supply_abs_pa: d_reservoir,
                gas_temperature_k: dt,
                load_torque_nm: 0.0,
            },
        )
    }

    /// The recorded channels for a state, with the sensor calibration effect if enabled
    /// (sensor lag needs the history: see `measure_series` in [`crate::sim`]).
    pub fn measure(&self, x: &PlantState) -> Measurement {
        self.effects.calibrate(self.true_channels(x))
    }

    /// The physical values of the recorded channels (PLANT.md "Measured channels").
    pub fn true_channels(&self, x: &PlantState) -> Measurement {
        let f = self.tensions_n(x);
        Measurement {
            angle_deg: x.angle_rad.to_degrees(),
            p1_kpa: (x.p1_abs_pa - self.p_atm_pa) / 1000.0,
            p2_kpa: (x.p2_abs_pa - self.p_atm_pa) / 1000.0,
            f1_n: f[0],
            f2_n: f[1],
        }
    }
}
