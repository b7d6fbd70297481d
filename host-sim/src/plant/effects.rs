//! Optional, switchable model extensions beyond the nominal PLANT.md model.
//!
//! Each effect is its own TOML table under `[effects]`; a table that is absent (as in the
//! nominal reference files) or has `enabled = false` leaves the nominal model untouched.
//! Effects plug into one of four places:
//! - joint torque (right-hand side of J omega' = T + sum of effect torques): [`JointFriction`],
//!   [`Gravity`];
//! - chamber flow and pressure law (right-hand side of the pressure ODE): [`Leakage`],
//!   [`Polytropic`];
//! - the measurement (what a sensor reports for a state): [`SensorCalibration`], and over a
//!   sampled sequence [`SensorLag`] (applied by [`SensorLagFilter`] once per sample);
//! - the valve command path (what the valves see of a command): [`ValveDeadTime`], applied by
//!   [`DeadTimeLine`] once per sample;
//! - the muscle tension (what the cable transmits and the force sensors measure):
//!   [`MuscleHysteresis`] (braid friction);
//! - the supply pressure the inlet valves see: [`SupplyDrop`], either a static flow-dependent
//!   drop or a reservoir with its own pressure state (the fifth ODE state, see
//!   [`crate::sim::Integrator`]).

use std::path::Path;

use serde::Deserialize;

use crate::plant::config::ConfigError;
use crate::plant::valve::Iso6358Valve;
use crate::plant::ValveInputs;

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
    pub polytropic: Option<Polytropic>,
    pub valve_dead_time: Option<ValveDeadTime>,
    pub sensor: Option<SensorCalibration>,
    pub sensor_lag: Option<SensorLag>,
    pub muscle_hysteresis: Option<MuscleHysteresis>,
    pub supply_drop: Option<SupplyDrop>,
}

/// `[effects.muscle_hysteresis]`: friction in the braid (thread on thread, thread on bladder;
/// seed 003 names both, and finds the torque hysteresis to be a velocity-dependent offset on
/// the static characteristic that widens with speed), as a force in each muscle opposing its
/// contraction rate, with a magnitude proportional to the gauge pressure (the normal force
/// between the braid threads grows with it):
///
/// F_h,i = (f0 + k_p max(pg_i, 0)) tanh(dchi_i/dt / v_s),
/// F_i = max(0, Fs_i - gamma pg_i dchi_i/dt - F_h,i).
///
/// It acts inside the muscle, so it shows in the measured tensions `f1_n`, `f2_n` (a
/// contracting muscle pulls less, a stretched one more); joint friction does not. It is
/// memoryless (no extra ODE state): seed 003 measured an offset that is a function of the
/// velocity, not a history-dependent loop, and a tanh-regularized Coulomb term keeps the
/// right-hand side smooth for the explicit integrator. It always dissipates: the change of
/// joint torque it causes has the sign of -omega.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MuscleHysteresis {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    /// f0, friction force at zero gauge pressure (>= 0).
    pub base_force_n: f64,
    /// k_p, friction force per pascal of gauge pressure (>= 0).
    pub pressure_gain_n_per_pa: f64,
    /// v_s, contraction rate (1/s, dchi/dt) at which the friction reaches tanh(1) = 76 % of
    /// its level (> 0; small: Coulomb-like, large: viscous-like).
    pub smoothing_rate_per_s: f64,
}

impl MuscleHysteresis {
    /// Friction force F_h opposing a contraction rate `contraction_rate_per_s` (positive while
    /// contracting), at gauge pressure `p_gauge_pa`.
    #[inline(always)]
    pub fn force_n(&self, p_gauge_pa: f64, contraction_rate_per_s: f64) -> f64 {
        (self.base_force_n + self.pressure_gain_n_per_pa * p_gauge_pa.max(0.0))
            * (contraction_rate_per_s / self.smoothing_rate_per_s).tanh()
    }
}

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

/// `[effects.supply_drop]`: the supply pressure sags while the inlet valves draw air (seed
/// 000 lists the compressor pressure drop among the causes of its model error). p_s0 is the
/// nominal supply `environment.supply_gauge_pa + p_atm`.
///
/// - `model = "static"`: p_s = p_s0 - R q_in(p_s), q_in = sum_i u_in_i Q(p_s, p_i) the
///   standard volume flow through the inlet valves; the implicit equation has one root (its
///   left side minus right side grows with p_s) and is solved in every right-hand-side call.
///   Key: `resistance_pa_s_per_m3` (R >= 0).
/// - `model = "reservoir"`: a tank (isothermal) at p_t, fed from p_s0 through an ISO 6358
///   orifice with the valves' critical and laminar ratios and sonic conductance C_f:
///   dp_t/dt = p_atm (C_f-flow(p_s0, p_t) - q_in(p_t)) / V_t, p_t(0) = p_s0; the inlet
///   valves see p_t. At rest the tank refills to p_s0. Keys: `tank_volume_m3` (V_t > 0),
///   `feed_conductance_m3_per_s_pa` (C_f > 0).
///
/// Keys of the other form are errors.
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
}

/// Solves p_s = p_s0 - R q(p_s) for the static supply drop, q(p) = sum_i u_i Q(p, p_i) (the
/// inlet flow at supply pressure p). g(p) = p - p_s0 + R q(p) is increasing in p (each Q(p,
/// p_i) is), negative at min(p_s0, p_i) and positive at max(p_s0, p_i), so the root is
/// bracketed; Illinois regula falsi to |g| <= 1e-7 Pa (g' >= 1, so that is the error in p).
pub fn static_supply_pressure_pa(
    valve: &Iso6358Valve,
    p_s0_pa: f64,
    resistance_pa_s_per_m3: f64,
    p_chamber_pa: [f64; 2],
    u_in: [f64; 2],
) -> f64 {
    if resistance_pa_s_per_m3 == 0.0 || (u_in[0] == 0.0 && u_in[1] == 0.0) {
        return p_s0_pa;
    }
    let g = |p: f64| {
        let mut q = 0.0;
        for i in 0..2 {
            if u_in[i] != 0.0 {
                q += u_in[i] * valve.flow_m3_s(p, p_chamber_pa[i]);
            }
        }
        p - p_s0_pa + resistance_pa_s_per_m3 * q
    };
    let (mut lo, mut hi) = (p_s0_pa, p_s0_pa);
    for i in 0..2 {
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

/// `[effects.sensor_lag]`: first-order sensor dynamics per channel group, as the sensor's
/// own sampled low-pass: y_k = y_{k-1} + a (x_k - y_{k-1}), a = 1 - exp(-dt / tau), started
/// at the first sample. An absent time constant means no lag on that group.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorLag {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    /// angle_deg.
    pub angle_time_constant_s: Option<f64>,
    /// p1_kpa, p2_kpa.
    pub pressure_time_constant_s: Option<f64>,
    /// f1_n, f2_n.
    pub force_time_constant_s: Option<f64>,
}

/// The running state of [`SensorLag`] for one sample period.
#[derive(Debug, Clone)]
pub struct SensorLagFilter {
    /// Filter gains of angle, p1, p2, f1, f2 (1 = no lag).
    gain: [f64; 5],
    y: Option<[f64; 5]>,
}

impl SensorLagFilter {
    pub fn new(lag: &SensorLag, dt_s: f64) -> Self {
        let a = |tau: Option<f64>| match tau {
            Some(t) if t > 0.0 => 1.0 - (-dt_s / t).exp(),
            _ => 1.0,
        };
        let (ang, p, f) = (
            a(lag.angle_time_constant_s),
            a(lag.pressure_time_constant_s),
            a(lag.force_time_constant_s),
        );
        Self {
            gain: [ang, p, p, f, f],
            y: None,
        }
    }

    /// Feeds the undelayed channels of one sample (angle, p1, p2, f1, f2); returns the lagged ones.
    pub fn push(&mut self, x: [f64; 5]) -> [f64; 5] {
        let y = match self.y {
            None => x,
            Some(mut y) => {
                for i in 0..5 {
                    y[i] += self.gain[i] * (x[i] - y[i]);
                }
                y
            }
        };
        self.y = Some(y);
        y
    }
}

/// `[effects.valve_dead_time]`: every valve applies a command `delay_s` later (valves closed
/// before the first delayed command arrives). The delay must be a whole number of sample
/// periods of the run it is used with.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ValveDeadTime {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    pub delay_s: f64,
}

/// A delay line of whole samples between valve commands and valve openings.
#[derive(Debug, Clone)]
pub struct DeadTimeLine {
    fifo: std::collections::VecDeque<ValveInputs>,
}

impl DeadTimeLine {
    /// A line for `delay_s` at sample period `dt_s`; `None` when the delay is not a whole
    /// number of samples (within 1e-6 of a sample).
    pub fn new(delay_s: f64, dt_s: f64) -> Option<Self> {
        let samples = delay_s / dt_s;
        let n = samples.round();
        if !(n >= 0.0 && (samples - n).abs() <= 1e-6 && n < 1e9) {
            return None;
        }
        Some(Self {
            fifo: std::iter::repeat_n(ValveInputs::CLOSED, n as usize).collect(),
        })
    }

    /// Delay in samples.
    pub fn samples(&self) -> usize {
        self.fifo.len()
    }

    /// Feeds the command of this sample; returns the opening the valves apply over it.
    pub fn push(&mut self, command: ValveInputs) -> ValveInputs {
        if self.fifo.is_empty() {
            return command;
        }
        self.fifo.push_back(command);
        self.fifo.pop_front().expect("non-empty")
    }
}

/// `[effects.polytropic]`: polytropic instead of isothermal chamber process (seed 004 eq. 3
/// with the standard flow at the reference temperature): dp/dt = n (p_atm Q - p dV/dt) / V.
/// `exponent = 1` is the nominal isothermal (Boyle-Mariotte) model, 1.4 adiabatic air.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Polytropic {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    pub exponent: f64,
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
#[derive(Debug, Clone, PartialEq)]
pub struct Effects {
    pub joint_friction: Option<JointFriction>,
    pub gravity: Option<Gravity>,
    pub leak: Option<Iso6358Valve>,
    /// Valve dead time in seconds, if enabled.
    pub valve_dead_time_s: Option<f64>,
    /// Polytropic exponent n of the pressure law (1 when the effect is off).
    pub pressure_exponent: f64,
    /// Sensor lag, if enabled.
    pub sensor_lag: Option<SensorLag>,
    /// Calibrations of angle_deg, p1_kpa, p2_kpa, f1_n, f2_n (identity when absent).
    pub sensor: Option<[ChannelCalibration; 5]>,
    /// Braid friction in the muscle tension, if enabled.
    pub muscle_hysteresis: Option<MuscleHysteresis>,
    /// The supply the inlet valves see ([`Supply::Ideal`] when the drop is off).
    pub supply: Supply,
}

impl Default for Effects {
    fn default() -> Self {
        Self {
            joint_friction: None,
            gravity: None,
            leak: None,
            valve_dead_time_s: None,
            pressure_exponent: 1.0,
            sensor_lag: None,
            sensor: None,
            muscle_hysteresis: None,
            supply: Supply::Ideal,
        }
    }
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
            sensor_lag: c.sensor_lag.clone().filter(|l| l.enabled),
            valve_dead_time_s: c
                .valve_dead_time
                .as_ref()
                .filter(|d| d.enabled)
                .map(|d| d.delay_s),
            pressure_exponent: c
                .polytropic
                .as_ref()
                .filter(|p| p.enabled)
                .map_or(1.0, |p| p.exponent),
            sensor: c.sensor.as_ref().filter(|s| s.enabled).map(|s| {
                [
                    s.angle_deg.unwrap_or(id),
                    s.p1_kpa.unwrap_or(id),
                    s.p2_kpa.unwrap_or(id),
                    s.f1_n.unwrap_or(id),
                    s.f2_n.unwrap_or(id),
                ]
            }),
            muscle_hysteresis: c.muscle_hysteresis.clone().filter(|h| h.enabled),
            supply: match c.supply_drop.as_ref().filter(|d| d.enabled) {
                None => Supply::Ideal,
                Some(d) => match d.model {
                    // validate() guarantees the keys of the chosen form are present.
                    SupplyDropModel::Static => Supply::Static {
                        resistance_pa_s_per_m3: d.resistance_pa_s_per_m3.unwrap_or(0.0),
                    },
                    SupplyDropModel::Reservoir => Supply::Reservoir {
                        tank_volume_m3: d.tank_volume_m3.unwrap_or(f64::INFINITY),
                        feed: Iso6358Valve::new(
                            d.feed_conductance_m3_per_s_pa.unwrap_or(0.0),
                            valve_critical_ratio,
                            valve_laminar_ratio,
                        ),
                    },
                },
            },
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

/// A TOML key (within its table) and its value, if given.
type KeyValue<'a> = (&'a str, Option<f64>);

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
        if let Some(d) = &self.valve_dead_time {
            check("effects.valve_dead_time.delay_s", d.delay_s, None)?;
            if d.delay_s < 0.0 {
                return Err(bad(
                    "effects.valve_dead_time.delay_s",
                    format!("must be >= 0, got {}", d.delay_s),
                ));
            }
        }
        if let Some(l) = &self.sensor_lag {
            for (key, tau) in [
                ("angle_time_constant_s", l.angle_time_constant_s),
                ("pressure_time_constant_s", l.pressure_time_constant_s),
                ("force_time_constant_s", l.force_time_constant_s),
            ] {
                if let Some(t) = tau {
                    check(&format!("effects.sensor_lag.{key}"), t, None)?;
                    if t < 0.0 {
                        return Err(bad(
                            &format!("effects.sensor_lag.{key}"),
                            format!("must be >= 0, got {t}"),
                        ));
                    }
                }
            }
        }
        if let Some(p) = &self.polytropic {
            check("effects.polytropic.exponent", p.exponent, Some(0.0))?;
        }
        if let Some(h) = &self.muscle_hysteresis {
            let k = "effects.muscle_hysteresis.";
            for (key, v) in [
                ("base_force_n", h.base_force_n),
                ("pressure_gain_n_per_pa", h.pressure_gain_n_per_pa),
            ] {
                check(&format!("{k}{key}"), v, None)?;
                if v < 0.0 {
                    return Err(bad(&format!("{k}{key}"), format!("must be >= 0, got {v}")));
                }
            }
            check(
                &format!("{k}smoothing_rate_per_s"),
                h.smoothing_rate_per_s,
                Some(0.0),
            )?;
        }
        if let Some(d) = &self.supply_drop {
            let k = "effects.supply_drop.";
            let (needed, foreign): (&[KeyValue], &[KeyValue]) = match d.model {
                SupplyDropModel::Static => (
                    &[("resistance_pa_s_per_m3", d.resistance_pa_s_per_m3)],
                    &[
                        ("tank_volume_m3", d.tank_volume_m3),
                        (
                            "feed_conductance_m3_per_s_pa",
                            d.feed_conductance_m3_per_s_pa,
                        ),
                    ],
                ),
                SupplyDropModel::Reservoir => (
                    &[
                        ("tank_volume_m3", d.tank_volume_m3),
                        (
                            "feed_conductance_m3_per_s_pa",
                            d.feed_conductance_m3_per_s_pa,
                        ),
                    ],
                    &[("resistance_pa_s_per_m3", d.resistance_pa_s_per_m3)],
                ),
            };
            let model = match d.model {
                SupplyDropModel::Static => "static",
                SupplyDropModel::Reservoir => "reservoir",
            };
            for (key, v) in foreign {
                if v.is_some() {
                    return Err(bad(
                        &format!("{k}{key}"),
                        format!("does not belong to model = \"{model}\""),
                    ));
                }
            }
            for (key, v) in needed {
                let Some(v) = v else {
                    return Err(bad(
                        &format!("{k}{key}"),
                        format!("missing (required by model = \"{model}\")"),
                    ));
                };
                check(&format!("{k}{key}"), *v, None)?;
                let positive = *key != "resistance_pa_s_per_m3";
                if (positive && *v <= 0.0) || *v < 0.0 {
                    let bound = if positive { "> 0" } else { ">= 0" };
                    return Err(bad(
                        &format!("{k}{key}"),
                        format!("must be {bound}, got {v}"),
                    ));
                }
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
