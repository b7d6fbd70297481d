//! Optional, switchable model extensions beyond the nominal PLANT.md model: one module per
//! physical effect, all registered in the one list at the bottom of this file ([`registry!`]).
//!
//! Each effect is its own TOML table under `[effects]`; a table that is absent (as in the
//! nominal reference files) or has `enabled = false` leaves the nominal model untouched.
//! An effect module holds everything about its effect:
//! - its TOML table (a `Deserialize` struct) and the checks of its values ([`Effect`]);
//! - its physics, as the hooks of [`Hooks`] it overrides in its run-time form
//!   ([`Effect::Active`]): joint torque, chamber flow, pressure-rate factor, muscle friction,
//!   supply model, valve dead time, sensor dynamics, sensor calibration;
//! - the diagnosis candidate(s) that can name it in a recording ([`candidate::EffectCandidates`]:
//!   parameters, bounds, screening signature, how to switch it on in a `PlantConfig`);
//! - the synthetic truths the diagnosis tests conceal in generated recordings, at a
//!   realistic size ([`Effect::truths`]).
//!
//! The registry generates [`EffectsConfig`] (the `[effects]` table), [`Effects`] (the enabled
//! effects the right-hand side iterates), the diagnosis catalogue ([`catalogue::candidates`]) and the
//! synthetic truths ([`truths`]), always in registry order. Adding an effect is one new file
//! and one line in the registry (see `docs/adding-an-effect.md`).
//!
//! The effects: [`JointFriction`], [`Gravity`] (joint torque); [`Leakage`], [`Polytropic`]
//! (chamber flow and pressure law); [`SensorCalibration`], [`SensorLag`] (the measurement);
//! [`ValveDeadTime`] (the valve command path); [`MuscleHysteresis`] (the muscle tension);
//! [`ThermalChamber`] (gas temperatures with wall heat transfer, two more ODE states);
//! [`SupplyDrop`] (the supply pressure, either a static flow-dependent drop or a reservoir
//! with its own pressure state, the fifth ODE state, see [`crate::sim::Integrator`]);
//! [`InertiaMismatch`] (not a table: the diagnosis candidate for a wrong `joint.inertia_kgm2`);
//! [`Discovered`] (a term `host-sim discover` found, in one slot of the equations).

use std::fmt::Debug;
use std::path::Path;

use serde::de::DeserializeOwned;
use serde::Deserialize;

use crate::plant::state::Measurement;
use crate::plant::tables::{ConfigError, ValveConfig};

pub use sensor::ChannelCalibration;
pub use sensor_lag::SensorLagFilter;
pub use supply_drop::{static_supply_pressure_pa, Supply, SupplyDropModel};
pub use valve_dead_time::{DeadTimeLine, ShiftedCommands, MAX_PLAUSIBLE_DELAY_S};

/// One effect: its `[effects.<name>]` table. Implemented by the table's struct.
pub trait Effect: Debug + Clone + PartialEq + DeserializeOwned {
    /// What the right-hand side uses (often the table itself).
    type Active: Hooks;
    /// The table's `enabled` key (default true).
    fn enabled(&self) -> bool;
    /// Checks the values; `check` builds errors naming `effects.<name>.<key>` and the file.
    fn validate(&self, check: &Check) -> Result<(), ConfigError>;
    /// The run-time form (`valve`: the plant's valves, for orifice-like effects).
    fn activate(&self, valve: &ValveConfig) -> Self::Active;
    /// The synthetic truths that conceal this effect in generated recordings.
    const TRUTHS: &'static [Truth];
}

/// The [`Effect`] items of an effect whose run-time form is its own table (`Active = Self`,
/// activated by a copy), switched by its `enabled` key: write `table_effect!();` inside
/// `impl Effect for TheTable`, after `TRUTHS`, then `validate`. Its diagnosis candidates
/// follow the impl: `effect_candidates!(TheTable => TheCandidate);`.
macro_rules! table_effect {
    () => {
        type Active = Self;
        fn enabled(&self) -> bool {
            self.enabled
        }
        fn activate(&self, _valve: &ValveConfig) -> Self {
            self.clone()
        }
    };
}

/// The checks of [`Effect::validate`] for keys named as their fields, run in the order
/// written and stopping at the first error: `check_fields!(self, c, finite: mass_kg,
/// com_distance_m; positive: smoothing_rate_per_s);` inside `validate` (`c` the [`Check`];
/// each kind is one of its methods).
macro_rules! check_fields {
    ($table:expr, $check:expr, $($kind:ident: $($field:ident),+);+ $(;)?) => {
        $($($check.$kind(stringify!($field), $table.$field)?;)+)+
    };
}

/// [`Hooks::parameters`] of an effect that changes the plant whenever it is enabled: the
/// named fields, each reported under its own name as TOML key. Write
/// `parameters!(mass_kg, com_distance_m);` inside `impl Hooks for TheTable`.
macro_rules! parameters {
    ($($field:ident),+ $(,)?) => {
        fn parameters(&self) -> Option<Vec<(String, String)>> {
            Some($crate::plant::effects::params(&[$((stringify!($field), self.$field)),+]))
        }
    };
}

/// How an enabled effect acts on the plant. Every hook defaults to "no change"; an effect
/// overrides the ones it acts through.
pub trait Hooks: Debug + Clone + PartialEq {
    /// The parameters a run reports for this effect (TOML key, value as TOML writes it), in
    /// the `# effects = ...` metadata and the `plant effects: ...` line; `None`: the effect
    /// as configured changes nothing (e.g. a polytropic exponent of 1) and is not listed.
    fn parameters(&self) -> Option<Vec<(String, String)>>;
    /// Torque on the joint (N m), added to the muscles' torque.
    #[inline(always)]
    fn joint_torque_nm(&self, _angle_rad: f64, _velocity_rad_s: f64) -> f64 {
        0.0
    }
    /// Torque on the joint (N m) that also depends on the muscle tensions `tensions_n` and the
    /// sprocket radius (a discovered transmission term); added to the muscles' torque. The
    /// 3-DOF arm does not run this hook (`Arm3Config::validate` refuses such a table).
    #[inline(always)]
    fn joint_torque_tensions_nm(
        &self,
        _angle_rad: f64,
        _velocity_rad_s: f64,
        _tensions_n: [f64; 2],
        _sprocket_radius_m: f64,
    ) -> f64 {
        0.0
    }
    /// Extra standard volume flow into the chamber of `muscle` (0 or 1) at absolute pressure
    /// `p_abs_pa` (m^3/s, negative: out of it).
    #[inline(always)]
    fn chamber_flow_m3_s(&self, _muscle: usize, _p_abs_pa: f64, _p_atm_pa: f64) -> f64 {
        0.0
    }
    /// Extra standard volume flow into the chamber of `muscle` that depends on its valves:
    /// their `openings` (inlet, exhaust) and nominal signed flows `valve_flows_m3_s` (the
    /// inlet's into the chamber, the exhaust's out of it, negative; a discovered valve term).
    /// Added to the inlet's flow. The 3-DOF arm does not run this hook
    /// (`Arm3Config::validate` refuses such a table).
    #[inline(always)]
    fn chamber_valve_flow_m3_s(
        &self,
        _muscle: usize,
        _p_abs_pa: f64,
        _p_atm_pa: f64,
        _openings: [f64; 2],
        _valve_flows_m3_s: [f64; 2],
    ) -> f64 {
        0.0
    }
    /// A change of the transmission at joint angle `angle_rad`: the muscles' extra travel
    /// [m] and its derivative by the angle [m/rad] (muscle 1 contracts by it, muscle 2
    /// extends; the lever grows by the derivative). `None`: the sprocket's r beta. The 3-DOF
    /// arm does not run this hook.
    #[inline(always)]
    fn transmission_map(&self, _angle_rad: f64, _sprocket_radius_m: f64) -> Option<[f64; 2]> {
        None
    }
    /// A compliance of the cables between the muscles and the sprocket [m/N] (each muscle
    /// contracts further by F times it). The 3-DOF arm does not run this hook.
    #[inline(always)]
    fn cable_compliance_m_per_n(&self) -> Option<f64> {
        None
    }
    /// Factor on the isothermal pressure rate (the polytropic exponent).
    #[inline(always)]
    fn pressure_rate_factor(&self) -> f64 {
        1.0
    }
    /// A force inside each muscle opposing its contraction rate (N), at gauge pressure
    /// `p_gauge_pa`; `None`: no such force.
    #[inline(always)]
    fn muscle_friction_n(&self, _p_gauge_pa: f64, _contraction_rate_per_s: f64) -> Option<f64> {
        None
    }
    /// The supply the inlet valves see, if this effect models it.
    #[inline(always)]
    fn supply(&self) -> Option<&Supply> {
        None
    }
    /// The chamber thermodynamics (gas temperatures as states), if this effect models them.
    #[inline(always)]
    fn thermal_chamber(&self) -> Option<&ThermalChamber> {
        None
    }
    /// Delay (s) between a valve command and the valve opening.
    fn valve_dead_time_s(&self) -> Option<f64> {
        None
    }
    /// Sampled sensor dynamics at sample period `dt_s`: a filter over the channels
    /// (angle, p1, p2, f1, f2), fed once per sample.
    fn sensor_filter(&self, _dt_s: f64) -> Option<Box<dyn ChannelFilter>> {
        None
    }
    /// What the sensors report for channel values `m` (after the sensor dynamics).
    fn calibrate(&self, m: Measurement) -> Measurement {
        m
    }
}

/// A causal filter over the sampled channels (angle, p1, p2, f1, f2).
pub trait ChannelFilter {
    /// Feeds one sample; returns the filtered one.
    fn push(&mut self, x: [f64; 5]) -> [f64; 5];
}

/// A synthetic truth: an effect at a realistic size, concealed in a generated recording.
#[derive(Debug, Clone, Copy)]
pub struct Truth {
    /// Name in the diagnosis tests and examples (`joint_friction_stribeck`).
    pub name: &'static str,
    /// The catalogue id the diagnosis should name it as.
    pub expected_id: &'static str,
    /// The plant TOML that conceals it at sample period `dt_s`: `[effects.*]` tables added
    /// to the plant file, or (with [`Self::replaces_key`]) the line that replaces a key.
    pub toml: fn(dt_s: f64) -> String,
    /// A key (`inertia_kgm2`) whose line in the plant file [`Self::toml`] replaces.
    pub replaces_key: Option<&'static str>,
}

impl Truth {
    /// A truth whose TOML is `[effects.*]` tables added to the plant file.
    pub const fn new(
        name: &'static str,
        expected_id: &'static str,
        toml: fn(dt_s: f64) -> String,
    ) -> Self {
        Self {
            name,
            expected_id,
            toml,
            replaces_key: None,
        }
    }
}

/// Builds the validation errors of one `[effects.<name>]` table.
pub struct Check<'a> {
    path: &'a Path,
    table: &'static str,
}

impl<'a> Check<'a> {
    pub fn new(path: &'a Path, table: &'static str) -> Self {
        Self { path, table }
    }

    /// An error about `key` of the table.
    pub fn error(&self, key: &str, message: impl Into<String>) -> ConfigError {
        ConfigError::Invalid {
            path: self.path.to_owned(),
            key: format!("effects.{}.{key}", self.table),
            message: message.into(),
        }
    }

    /// `v` must be finite.
    pub fn finite(&self, key: &str, v: f64) -> Result<(), ConfigError> {
        if v.is_finite() {
            Ok(())
        } else {
            Err(self.error(key, format!("must be finite, got {v}")))
        }
    }

    /// `v` must be finite and > 0.
    pub fn positive(&self, key: &str, v: f64) -> Result<(), ConfigError> {
        self.finite(key, v)?;
        if v > 0.0 {
            Ok(())
        } else {
            Err(self.error(key, format!("must be > 0, got {v}")))
        }
    }

    /// `v` must lie in `range` (a physical range: wide enough for any real rig, narrow enough
    /// to catch a unit typed wrong); `unit` is named in the message.
    pub fn within(
        &self,
        key: &str,
        v: f64,
        range: crate::validate::Range,
        unit: &str,
    ) -> Result<(), ConfigError> {
        match crate::validate::range_error(key, v, range, unit) {
            Some(msg) => Err(self.error(key, msg)),
            None => Ok(()),
        }
    }

    /// `v` must be finite and >= 0.
    pub fn non_negative(&self, key: &str, v: f64) -> Result<(), ConfigError> {
        self.finite(key, v)?;
        if v >= 0.0 {
            Ok(())
        } else {
            Err(self.error(key, format!("must be >= 0, got {v}")))
        }
    }
}

/// `(key, value)` pairs of [`Hooks::parameters`] from numbers.
pub(crate) fn params(p: &[(&str, f64)]) -> Vec<(String, String)> {
    p.iter()
        .map(|(k, v)| (k.to_string(), format!("{v}")))
        .collect()
}

pub(crate) fn enabled_default() -> bool {
    true
}

/// Visits each enabled effect's run-time form (static dispatch: the right-hand side stays
/// as fast as hand-written code).
pub trait Visit<'e> {
    fn visit<A: Hooks>(&mut self, active: &'e A);
}

/// Generates, from the one list of effect modules, the `[effects]` table, the run-time
/// [`Effects`], validation and the truths (all in list order); [`catalogue`] the diagnosis
/// catalogue from the same list.
/// An entry is `module::TableStruct`; attributes (e.g. `#[cfg(test)]`) apply to all of it.
macro_rules! registry {
    ($( $(#[$attr:meta])* $module:ident :: $ty:ident ),* $(,)?) => {
        $( $(#[$attr])* pub mod $module; )*
        $( $(#[$attr])* pub use $module::$ty; )*

        /// The `[effects]` table: one optional sub-table per registered effect.
        #[derive(Debug, Clone, Default, PartialEq, Deserialize)]
        #[serde(deny_unknown_fields)]
        pub struct EffectsConfig {
            $( $(#[$attr])* pub $module: Option<$ty>, )*
        }

        /// The enabled effects, in the form the right-hand side uses.
        #[derive(Debug, Clone, Default, PartialEq)]
        pub struct Effects {
            $( $(#[$attr])* pub $module: Option<<$ty as Effect>::Active>, )*
        }

        impl EffectsConfig {
            pub(crate) fn validate(&self, path: &Path) -> Result<(), ConfigError> {
                $( $(#[$attr])* if let Some(e) = &self.$module {
                    e.validate(&Check::new(path, stringify!($module)))?;
                } )*
                Ok(())
            }
        }

        impl Effects {
            /// The enabled effects of `c`; `valve` is the plant's `[valve]` table.
            pub fn from_config(c: &EffectsConfig, valve: &ValveConfig) -> Self {
                Self {
                    $( $(#[$attr])* $module: c
                        .$module
                        .as_ref()
                        .filter(|e| e.enabled())
                        .map(|e| e.activate(valve)), )*
                }
            }

            /// Every enabled effect that changes the model: its table name and
            /// [`Hooks::parameters`], in registry order.
            pub fn active(&self) -> Vec<(&'static str, Vec<(String, String)>)> {
                let mut v = Vec::new();
                $( $(#[$attr])* if let Some(p) = self.$module.as_ref().and_then(|a| a.parameters()) {
                    v.push((stringify!($module), p));
                } )*
                v
            }

            /// Calls `v` with every enabled effect, in registry order.
            #[inline(always)]
            pub fn visit<'e>(&'e self, v: &mut impl Visit<'e>) {
                $( $(#[$attr])* if let Some(a) = &self.$module {
                    v.visit(a);
                } )*
            }
        }

        /// Every synthetic truth of every registered effect, in registry order.
        pub fn truths() -> Vec<Truth> {
            let mut v = Vec::new();
            $( $(#[$attr])* v.extend_from_slice(<$ty as Effect>::TRUTHS); )*
            v
        }
    };
}

// The registry: one line per effect. The order is the order of the diagnosis catalogue (its
// tie-breaks and report) and of the sums in the right-hand side. `effect_list!(m)` hands the
// list to the macro `m`: `registry` here, the catalogue in [`catalogue`].
macro_rules! effect_list {
    ($then:ident) => {
        $then! {
            joint_friction::JointFriction,
            muscle_hysteresis::MuscleHysteresis,
            sensor_lag::SensorLag,
            valve_dead_time::ValveDeadTime,
            supply_drop::SupplyDrop,
            polytropic::Polytropic,
            gravity::Gravity,
            inertia::InertiaMismatch,
            leakage::Leakage,
            sensor::SensorCalibration,
            thermal_chamber::ThermalChamber,
            discovered::Discovered,
            #[cfg(test)]
            toy_spring::ToySpring,
        }
    };
}

#[macro_use]
pub mod candidate;

effect_list!(registry);

pub mod catalogue;

/// The first enabled effect's `Some` answer, in registry order, to `hook`, a [`Hooks`] method
/// returning `Option<&T>`: `first_answer!(effects, supply -> Supply)`.
macro_rules! first_answer {
    ($effects:expr, $hook:ident -> $t:ty) => {{
        struct First<'e>(Option<&'e $t>);
        impl<'e> Visit<'e> for First<'e> {
            #[inline(always)]
            fn visit<A: Hooks>(&mut self, a: &'e A) {
                if self.0.is_none() {
                    self.0 = a.$hook();
                }
            }
        }
        let mut f = First(None);
        $effects.visit(&mut f);
        f.0
    }};
}

impl Effects {
    /// Sum of the effect torques on the joint.
    #[inline(always)]
    pub fn joint_torque_nm(&self, angle_rad: f64, velocity_rad_s: f64) -> f64 {
        struct Sum(f64, f64, f64);
        impl Visit<'_> for Sum {
            #[inline(always)]
            fn visit<A: Hooks>(&mut self, a: &A) {
                self.0 += a.joint_torque_nm(self.1, self.2);
            }
        }
        let mut s = Sum(0.0, angle_rad, velocity_rad_s);
        self.visit(&mut s);
        s.0
    }

    /// Sum of the effect torques on the joint that depend on the muscle tensions.
    #[inline(always)]
    pub fn joint_torque_tensions_nm(
        &self,
        angle_rad: f64,
        velocity_rad_s: f64,
        tensions_n: [f64; 2],
        sprocket_radius_m: f64,
    ) -> f64 {
        struct Sum(f64, f64, f64, [f64; 2], f64);
        impl Visit<'_> for Sum {
            #[inline(always)]
            fn visit<A: Hooks>(&mut self, a: &A) {
                self.0 += a.joint_torque_tensions_nm(self.1, self.2, self.3, self.4);
            }
        }
        let mut s = Sum(
            0.0,
            angle_rad,
            velocity_rad_s,
            tensions_n,
            sprocket_radius_m,
        );
        self.visit(&mut s);
        s.0
    }

    /// Extra standard volume flow into the chamber of `muscle` (0 or 1; negative: out).
    #[inline(always)]
    pub fn chamber_flow_m3_s(&self, muscle: usize, p_abs_pa: f64, p_atm_pa: f64) -> f64 {
        struct Sum(f64, usize, f64, f64);
        impl Visit<'_> for Sum {
            #[inline(always)]
            fn visit<A: Hooks>(&mut self, a: &A) {
                self.0 += a.chamber_flow_m3_s(self.1, self.2, self.3);
            }
        }
        let mut s = Sum(0.0, muscle, p_abs_pa, p_atm_pa);
        self.visit(&mut s);
        s.0
    }

    /// Extra standard volume flow into the chamber of `muscle` from its valves' openings and
    /// nominal flows ([`Hooks::chamber_valve_flow_m3_s`]).
    #[inline(always)]
    pub fn chamber_valve_flow_m3_s(
        &self,
        muscle: usize,
        p_abs_pa: f64,
        p_atm_pa: f64,
        openings: [f64; 2],
        valve_flows_m3_s: [f64; 2],
    ) -> f64 {
        struct Sum(f64, usize, f64, f64, [f64; 2], [f64; 2]);
        impl Visit<'_> for Sum {
            #[inline(always)]
            fn visit<A: Hooks>(&mut self, a: &A) {
                self.0 += a.chamber_valve_flow_m3_s(self.1, self.2, self.3, self.4, self.5);
            }
        }
        let mut s = Sum(0.0, muscle, p_abs_pa, p_atm_pa, openings, valve_flows_m3_s);
        self.visit(&mut s);
        s.0
    }

    /// The transmission's extra travel and its slope ([`Hooks::transmission_map`], summed);
    /// `None` when no effect changes it.
    #[inline(always)]
    pub fn transmission_map(&self, angle_rad: f64, sprocket_radius_m: f64) -> Option<[f64; 2]> {
        struct Sum(Option<[f64; 2]>, f64, f64);
        impl Visit<'_> for Sum {
            #[inline(always)]
            fn visit<A: Hooks>(&mut self, a: &A) {
                if let Some([d, s]) = a.transmission_map(self.1, self.2) {
                    let o = self.0.get_or_insert([0.0; 2]);
                    o[0] += d;
                    o[1] += s;
                }
            }
        }
        let mut s = Sum(None, angle_rad, sprocket_radius_m);
        self.visit(&mut s);
        s.0
    }

    /// The cables' compliance [m/N], if an effect models it.
    #[inline(always)]
    pub fn cable_compliance_m_per_n(&self) -> Option<f64> {
        struct First(Option<f64>);
        impl Visit<'_> for First {
            #[inline(always)]
            fn visit<A: Hooks>(&mut self, a: &A) {
                if self.0.is_none() {
                    self.0 = a.cable_compliance_m_per_n();
                }
            }
        }
        let mut f = First(None);
        self.visit(&mut f);
        f.0
    }

    /// Factor on the isothermal pressure rate (1 without a polytropic effect).
    #[inline(always)]
    pub fn pressure_rate_factor(&self) -> f64 {
        struct Product(f64);
        impl Visit<'_> for Product {
            #[inline(always)]
            fn visit<A: Hooks>(&mut self, a: &A) {
                self.0 *= a.pressure_rate_factor();
            }
        }
        let mut p = Product(1.0);
        self.visit(&mut p);
        p.0
    }

    /// Total friction force inside a muscle opposing its contraction; `None` when no effect
    /// adds one.
    #[inline(always)]
    pub fn muscle_friction_n(&self, p_gauge_pa: f64, contraction_rate_per_s: f64) -> Option<f64> {
        struct Sum(Option<f64>, f64, f64);
        impl Visit<'_> for Sum {
            #[inline(always)]
            fn visit<A: Hooks>(&mut self, a: &A) {
                if let Some(f) = a.muscle_friction_n(self.1, self.2) {
                    self.0 = Some(self.0.map_or(f, |g| g + f));
                }
            }
        }
        let mut s = Sum(None, p_gauge_pa, contraction_rate_per_s);
        self.visit(&mut s);
        s.0
    }

    /// The supply the inlet valves see ([`Supply::Ideal`] unless an effect models it).
    #[inline(always)]
    pub fn supply(&self) -> &Supply {
        first_answer!(self, supply -> Supply).unwrap_or(&Supply::Ideal)
    }

    /// The chamber thermodynamics, if enabled (then the gas temperatures are ODE states).
    #[inline(always)]
    pub fn thermal_chamber(&self) -> Option<&ThermalChamber> {
        first_answer!(self, thermal_chamber -> ThermalChamber)
    }

    /// Total delay between a valve command and the valve opening; `None`: no delay effect.
    pub fn valve_dead_time_s(&self) -> Option<f64> {
        struct Sum(Option<f64>);
        impl Visit<'_> for Sum {
            fn visit<A: Hooks>(&mut self, a: &A) {
                if let Some(d) = a.valve_dead_time_s() {
                    self.0 = Some(self.0.map_or(d, |e| e + d));
                }
            }
        }
        let mut s = Sum(None);
        self.visit(&mut s);
        s.0
    }

    /// The sensor dynamics at sample period `dt_s`, in registry order.
    pub fn sensor_filters(&self, dt_s: f64) -> Vec<Box<dyn ChannelFilter>> {
        struct Collect(Vec<Box<dyn ChannelFilter>>, f64);
        impl Visit<'_> for Collect {
            fn visit<A: Hooks>(&mut self, a: &A) {
                self.0.extend(a.sensor_filter(self.1));
            }
        }
        let mut c = Collect(Vec::new(), dt_s);
        self.visit(&mut c);
        c.0
    }

    /// What the sensors report for channel values `m`.
    pub fn calibrate(&self, m: Measurement) -> Measurement {
        struct Chain(Measurement);
        impl Visit<'_> for Chain {
            fn visit<A: Hooks>(&mut self, a: &A) {
                self.0 = a.calibrate(self.0);
            }
        }
        let mut c = Chain(m);
        self.visit(&mut c);
        c.0
    }
}
