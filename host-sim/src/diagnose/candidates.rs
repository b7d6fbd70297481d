//! The candidate library: one [`Candidate`] per effect the diagnosis can name. Each one knows
//! its parameters (names, bounds, typical size), how to screen the equation-error evidence
//! for its signature (score and initial guess), and how to switch itself on in a
//! [`PlantConfig`] (the same `[effects]` tables the simulator runs, so the corrected model
//! is the plant code itself).

use crate::io::recording::Channel;
use crate::plant::config::PlantConfig;
use crate::plant::effects::{
    ChannelCalibration, Gravity, JointFriction, Leakage, MuscleHysteresis, Polytropic,
    SensorCalibration, SensorLag, SupplyDrop, SupplyDropModel, ValveDeadTime,
};

use super::screen::{regress, Evidence, Scatter};

/// One parameter of a candidate (SI or the channel's unit, as its name says).
#[derive(Debug, Clone)]
pub struct ParamSpec {
    pub name: String,
    pub lo: f64,
    pub hi: f64,
    /// Typical size: the fit works in units of it.
    pub scale: f64,
}

impl ParamSpec {
    fn new(name: impl Into<String>, lo: f64, hi: f64, scale: f64) -> Self {
        Self {
            name: name.into(),
            lo,
            hi,
            scale,
        }
    }
}

/// What screening found for one candidate.
#[derive(Debug, Clone)]
pub struct Screening {
    /// Share (0..1) of the equation-error (or output) residual the signature explains.
    pub score: f64,
    /// Initial guess of the parameters (same order as [`Candidate::params`]).
    pub initial: Vec<f64>,
    /// One sentence on the signature found.
    pub note: String,
    /// Residual against the regressor that explains it (for the report).
    pub scatter: Option<Scatter>,
}

/// Facts about the recording the candidates need.
#[derive(Debug, Clone)]
pub struct Setup {
    pub dt_s: f64,
    /// Which of `Channel::ALL` were measured.
    pub present: [bool; 5],
}

impl Setup {
    pub fn has(&self, c: Channel) -> bool {
        self.present[c.index()]
    }
    pub fn has_force(&self) -> bool {
        self.has(Channel::F1N) || self.has(Channel::F2N)
    }
    pub fn has_pressure(&self) -> bool {
        self.has(Channel::P1Kpa) || self.has(Channel::P2Kpa)
    }
}

/// One effect the diagnosis can name.
pub trait Candidate: Sync + Send {
    /// Effect id of the JSON contract (`joint_friction`, ...).
    fn id(&self) -> &'static str;
    /// Human name for sentences.
    fn label(&self) -> &'static str;
    /// Its free parameters for this recording.
    fn params(&self, s: &Setup) -> Vec<ParamSpec>;
    /// Parameters that are not fitted but reported (name, value).
    fn fixed(&self) -> Vec<(&'static str, f64)> {
        Vec::new()
    }
    /// Scores the evidence and gives an initial guess.
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening;
    /// Switches the effect on in `cfg` with `params`.
    fn apply(&self, cfg: &mut PlantConfig, params: &[f64], s: &Setup);
    /// False when the effect only changes what the sensors report (the simulated states
    /// can then be reused).
    fn changes_dynamics(&self) -> bool {
        true
    }
    /// For a parameter that only takes discrete values (a dead time in whole samples): the
    /// values to try around `initial`. `None`: continuous, fitted by Levenberg-Marquardt.
    fn grid(&self, _initial: &[f64], _s: &Setup) -> Option<Vec<Vec<f64>>> {
        None
    }
    /// One sentence saying what the fitted effect is.
    fn describe(&self, params: &[f64], s: &Setup) -> String;
}

/// The full catalogue, in a fixed order.
pub fn catalogue() -> Vec<Box<dyn Candidate>> {
    vec![
        Box::new(JointFrictionCandidate),
        Box::new(MuscleHysteresisCandidate),
        Box::new(SensorLagCandidate),
        Box::new(ValveDelayCandidate),
        Box::new(SupplyDropCandidate),
        Box::new(SupplyReservoirCandidate),
        Box::new(PolytropicCandidate),
        Box::new(GravityCandidate),
        Box::new(InertiaCandidate),
        Box::new(LeakageCandidate),
        Box::new(SensorOffsetCandidate),
    ]
}

/// Regularisation velocity of the friction sign function used by the candidate.
pub const FRICTION_SMOOTHING_RAD_S: f64 = 0.02;
/// Contraction-rate scale of the braid-friction candidate.
pub const HYSTERESIS_SMOOTHING_PER_S: f64 = 0.01;
/// Lever of the gravity candidate (the fit gives the mass at this distance: only m l counts).
pub const GRAVITY_COM_DISTANCE_M: f64 = 0.1;

fn clamp_to(p: &[ParamSpec], v: Vec<f64>) -> Vec<f64> {
    v.iter()
        .zip(p)
        .map(|(x, s)| {
            if x.is_finite() {
                x.clamp(s.lo, s.hi)
            } else {
                s.scale.clamp(s.lo, s.hi)
            }
        })
        .collect()
}

pub struct JointFrictionCandidate;

impl Candidate for JointFrictionCandidate {
    fn id(&self) -> &'static str {
        "joint_friction"
    }
    fn label(&self) -> &'static str {
        "joint friction"
    }
    fn params(&self, _s: &Setup) -> Vec<ParamSpec> {
        vec![
            ParamSpec::new("coulomb_nm", 0.0, 20.0, 0.2),
            ParamSpec::new("viscous_nm_s_per_rad", 0.0, 20.0, 0.05),
        ]
    }
    fn fixed(&self) -> Vec<(&'static str, f64)> {
        vec![("smoothing_velocity_rad_s", FRICTION_SMOOTHING_RAD_S)]
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        let sign: Vec<f64> = ev
            .omega_rad_s
            .iter()
            .map(|w| -(w / FRICTION_SMOOTHING_RAD_S).tanh())
            .collect();
        let visc: Vec<f64> = ev.omega_rad_s.iter().map(|w| -w).collect();
        let (c, r2) = regress(&ev.torque_residual_nm, &[&sign, &visc]);
        Screening {
            score: r2,
            initial: clamp_to(&self.params(s), vec![c[0], c[1]]),
            note: format!(
                "the joint torque balance residual follows -sign(omega) and -omega (R^2 {r2:.2})"
            ),
            scatter: Some(Scatter::new(
                "angular velocity omega [rad/s]",
                "torque balance residual J alpha - T [N m]",
                &ev.omega_rad_s,
                &ev.torque_residual_nm,
            )),
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], _s: &Setup) {
        cfg.effects.joint_friction = Some(JointFriction {
            enabled: true,
            coulomb_nm: p[0],
            breakaway_nm: p[0],
            stribeck_velocity_rad_s: 1.0,
            viscous_nm_s_per_rad: p[1],
            smoothing_velocity_rad_s: FRICTION_SMOOTHING_RAD_S,
        });
    }
    fn describe(&self, p: &[f64], _s: &Setup) -> String {
        format!(
            "a friction torque on the joint, {:.3} N m Coulomb + {:.3} N m s/rad viscous",
            p[0], p[1]
        )
    }
}

pub struct MuscleHysteresisCandidate;

impl Candidate for MuscleHysteresisCandidate {
    fn id(&self) -> &'static str {
        "muscle_hysteresis"
    }
    fn label(&self) -> &'static str {
        "muscle (braid) hysteresis"
    }
    fn params(&self, _s: &Setup) -> Vec<ParamSpec> {
        vec![
            ParamSpec::new("base_force_n", 0.0, 500.0, 5.0),
            ParamSpec::new("pressure_gain_n_per_pa", 0.0, 1e-3, 1e-5),
        ]
    }
    fn fixed(&self) -> Vec<(&'static str, f64)> {
        vec![("smoothing_rate_per_s", HYSTERESIS_SMOOTHING_PER_S)]
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        let th: Vec<f64> = ev
            .dchi1_per_s
            .iter()
            .map(|d| (d / HYSTERESIS_SMOOTHING_PER_S).tanh())
            .collect();
        let (c, r2, scatter) = if let Some(fr) = &ev.force_residual_n {
            // F_i,meas - F_i,nominal = -(f0 + k pg_i) tanh(dchi_i / v), dchi_2 = -dchi_1.
            let mut y = Vec::new();
            let mut x0 = Vec::new();
            let mut x1 = Vec::new();
            for (i, sgn) in [(0usize, 1.0), (1, -1.0)] {
                if let Some(r) = &fr[i] {
                    for k in 0..th.len() {
                        y.push(r[k]);
                        x0.push(-sgn * th[k]);
                        x1.push(-sgn * th[k] * ev.p_gauge_pa[i][k].max(0.0));
                    }
                }
            }
            let (c, r2) = regress(&y, &[&x0, &x1]);
            let sc = fr[0].as_ref().map(|r| {
                Scatter::new(
                    "muscle 1 contraction rate dchi1/dt [1/s]",
                    "f1 residual F1 measured - F1 nominal [N]",
                    &ev.dchi1_per_s,
                    r,
                )
            });
            (c, r2, sc)
        } else {
            // Without force sensors it shows only in the torque balance:
            // dT = -r tanh(dchi1/v) (2 f0 + k (pg1 + pg2)).
            let r = ev.sprocket_radius_m;
            let x0: Vec<f64> = th.iter().map(|t| -2.0 * r * t).collect();
            let x1: Vec<f64> = th
                .iter()
                .enumerate()
                .map(|(k, t)| {
                    -r * t * (ev.p_gauge_pa[0][k].max(0.0) + ev.p_gauge_pa[1][k].max(0.0))
                })
                .collect();
            let (c, r2) = regress(&ev.torque_residual_nm, &[&x0, &x1]);
            let sc = Scatter::new(
                "muscle 1 contraction rate dchi1/dt [1/s]",
                "torque balance residual [N m]",
                &ev.dchi1_per_s,
                &ev.torque_residual_nm,
            );
            (c, r2, Some(sc))
        };
        Screening {
            score: r2,
            initial: clamp_to(&self.params(s), vec![c[0], c[1]]),
            note: if ev.force_residual_n.is_some() {
                format!("the measured tensions fall short of the nominal ones by a force that follows the contraction direction (R^2 {r2:.2})")
            } else {
                format!("the torque balance residual follows -sign(contraction rate) (R^2 {r2:.2}); no force channel to confirm it is in the muscles")
            },
            scatter,
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], _s: &Setup) {
        cfg.effects.muscle_hysteresis = Some(MuscleHysteresis {
            enabled: true,
            base_force_n: p[0],
            pressure_gain_n_per_pa: p[1],
            smoothing_rate_per_s: HYSTERESIS_SMOOTHING_PER_S,
        });
    }
    fn describe(&self, p: &[f64], _s: &Setup) -> String {
        format!(
            "braid friction inside the muscles, {:.2} N + {:.2} N per 100 kPa gauge, opposing the contraction",
            p[0],
            p[1] * 1e5
        )
    }
}

pub struct SensorLagCandidate;

impl SensorLagCandidate {
    fn groups(s: &Setup) -> Vec<(&'static str, Channel)> {
        let mut g = Vec::new();
        if s.has(Channel::AngleDeg) {
            g.push(("angle_time_constant_s", Channel::AngleDeg));
        }
        if s.has_pressure() {
            g.push((
                "pressure_time_constant_s",
                if s.has(Channel::P1Kpa) {
                    Channel::P1Kpa
                } else {
                    Channel::P2Kpa
                },
            ));
        }
        if s.has_force() {
            g.push((
                "force_time_constant_s",
                if s.has(Channel::F1N) {
                    Channel::F1N
                } else {
                    Channel::F2N
                },
            ));
        }
        g
    }
}

impl Candidate for SensorLagCandidate {
    fn id(&self) -> &'static str {
        "sensor_lag"
    }
    fn label(&self) -> &'static str {
        "sensor lag"
    }
    fn params(&self, s: &Setup) -> Vec<ParamSpec> {
        Self::groups(s)
            .into_iter()
            .map(|(n, _)| ParamSpec::new(n, 0.0, 0.5, 0.005))
            .collect()
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        let groups = Self::groups(s);
        let initial: Vec<f64> = groups
            .iter()
            .map(|(_, c)| ev.lag_samples[c.index()] as f64 * s.dt_s)
            .collect();
        let score = groups
            .iter()
            .map(|(_, c)| ev.lag_gain[c.index()])
            .fold(0.0, f64::max);
        let lagging: Vec<&str> = groups
            .iter()
            .filter(|(_, c)| ev.lag_samples[c.index()] > 0)
            .map(|(_, c)| c.name())
            .collect();
        let most = groups
            .iter()
            .max_by(|a, b| ev.lag_gain[a.1.index()].total_cmp(&ev.lag_gain[b.1.index()]))
            .map(|g| g.1);
        Screening {
            score,
            initial: clamp_to(&self.params(s), initial),
            note: if lagging.is_empty() {
                "no measured channel lags the nominal simulation".into()
            } else {
                format!(
                    "{} lag(s) the nominal simulation (cross-correlation of the residuals)",
                    lagging.join(", ")
                )
            },
            scatter: most.and_then(|c| ev.lag_scatter(c)),
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], s: &Setup) {
        let mut lag = SensorLag {
            enabled: true,
            angle_time_constant_s: None,
            pressure_time_constant_s: None,
            force_time_constant_s: None,
        };
        for ((name, _), v) in Self::groups(s).iter().zip(p) {
            let v = Some(v.max(0.0));
            match *name {
                "angle_time_constant_s" => lag.angle_time_constant_s = v,
                "pressure_time_constant_s" => lag.pressure_time_constant_s = v,
                _ => lag.force_time_constant_s = v,
            }
        }
        cfg.effects.sensor_lag = Some(lag);
    }
    fn changes_dynamics(&self) -> bool {
        false
    }
    fn describe(&self, p: &[f64], s: &Setup) -> String {
        let parts: Vec<String> = Self::groups(s)
            .iter()
            .zip(p)
            .map(|((n, _), v)| {
                format!(
                    "{} {:.1} ms",
                    n.trim_end_matches("_time_constant_s"),
                    v * 1e3
                )
            })
            .collect();
        format!(
            "first-order lag of the sensors ({}), the plant itself on time",
            parts.join(", ")
        )
    }
}

pub struct ValveDelayCandidate;

/// Longest valve dead time tried.
pub const MAX_VALVE_DELAY_S: f64 = 0.05;

impl Candidate for ValveDelayCandidate {
    fn id(&self) -> &'static str {
        "valve_delay"
    }
    fn label(&self) -> &'static str {
        "valve delay"
    }
    fn params(&self, s: &Setup) -> Vec<ParamSpec> {
        vec![ParamSpec::new("delay_s", 0.0, MAX_VALVE_DELAY_S, s.dt_s)]
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        // The pressures react to the valves first: their lag is the dead time.
        let ch = [Channel::P1Kpa, Channel::P2Kpa, Channel::AngleDeg]
            .into_iter()
            .find(|c| s.has(*c))
            .unwrap_or(Channel::AngleDeg);
        let lags: Vec<usize> = Channel::ALL
            .iter()
            .filter(|c| s.has(**c))
            .map(|c| ev.lag_samples[c.index()])
            .collect();
        let all_lag = !lags.is_empty() && lags.iter().all(|l| *l > 0);
        let gains: Vec<f64> = Channel::ALL
            .iter()
            .filter(|c| s.has(**c))
            .map(|c| ev.lag_gain[c.index()])
            .collect();
        let score = if all_lag {
            gains.iter().copied().fold(f64::INFINITY, f64::min)
        } else {
            0.0
        };
        Screening {
            score,
            initial: vec![ev.lag_samples[ch.index()] as f64 * s.dt_s],
            note: if all_lag {
                "every measured channel lags the nominal simulation, as when the valves act late"
                    .into()
            } else {
                "not every channel lags: no common dead time in front of the plant".into()
            },
            scatter: ev.lag_scatter(ch),
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], s: &Setup) {
        let n = (p[0] / s.dt_s).round().max(0.0);
        cfg.effects.valve_dead_time = Some(ValveDeadTime {
            enabled: true,
            delay_s: n * s.dt_s,
        });
    }
    fn grid(&self, initial: &[f64], s: &Setup) -> Option<Vec<Vec<f64>>> {
        let max_n = (MAX_VALVE_DELAY_S / s.dt_s).floor() as i64;
        let n0 = (initial[0] / s.dt_s).round() as i64;
        let mut v: Vec<Vec<f64>> = (n0 - 3..=n0 + 3)
            .filter(|n| *n >= 1 && *n <= max_n)
            .map(|n| vec![n as f64 * s.dt_s])
            .collect();
        if v.is_empty() {
            v.push(vec![s.dt_s]);
        }
        Some(v)
    }
    fn describe(&self, p: &[f64], _s: &Setup) -> String {
        format!(
            "a dead time of {:.1} ms between a valve command and the valve opening",
            p[0] * 1e3
        )
    }
}

pub struct SupplyDropCandidate;

impl Candidate for SupplyDropCandidate {
    fn id(&self) -> &'static str {
        "supply_drop"
    }
    fn label(&self) -> &'static str {
        "supply pressure drop"
    }
    fn params(&self, _s: &Setup) -> Vec<ParamSpec> {
        vec![ParamSpec::new("resistance_pa_s_per_m3", 0.0, 1e9, 1e7)]
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        let (c, r2) = regress_pressure(ev, &ev.supply_signature);
        Screening {
            score: r2,
            initial: clamp_to(&self.params(s), vec![c]),
            note: format!(
                "the chambers fill slower than nominal in proportion to the total inlet flow (R^2 {r2:.2})"
            ),
            scatter: pressure_scatter(ev, &ev.supply_signature, "supply-drop regressor [Pa/s per Pa s/m^3]"),
        }
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
    fn id(&self) -> &'static str {
        "supply_drop"
    }
    fn label(&self) -> &'static str {
        "supply pressure drop"
    }
    fn params(&self, _s: &Setup) -> Vec<ParamSpec> {
        vec![
            ParamSpec::new("tank_volume_m3", 1e-6, 0.1, 1e-3),
            ParamSpec::new("feed_conductance_m3_per_s_pa", 1e-11, 1e-6, 1e-8),
        ]
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        let (_, r2) = regress_pressure(ev, &ev.supply_signature);
        Screening {
            score: r2,
            initial: self.params(s).iter().map(|p| p.scale).collect(),
            note: format!(
                "the chambers fill slower than nominal while the inlet valves draw air, as from a supply tank that drains and refills (R^2 {r2:.2})"
            ),
            scatter: pressure_scatter(ev, &ev.supply_signature, "supply-drop regressor [Pa/s per Pa s/m^3]"),
        }
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

pub struct PolytropicCandidate;

impl Candidate for PolytropicCandidate {
    fn id(&self) -> &'static str {
        "polytropic"
    }
    fn label(&self) -> &'static str {
        "polytropic (non-isothermal) chamber process"
    }
    fn params(&self, _s: &Setup) -> Vec<ParamSpec> {
        vec![ParamSpec::new("exponent", 0.5, 2.0, 1.0)]
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        let (c, r2) = regress_pressure(ev, &ev.nominal_dp);
        Screening {
            score: r2,
            initial: clamp_to(&self.params(s), vec![1.0 + c]),
            note: format!(
                "the measured pressure rate is the nominal (isothermal) rate scaled by a constant (R^2 {r2:.2})"
            ),
            scatter: pressure_scatter(ev, &ev.nominal_dp, "nominal pressure rate dp/dt [Pa/s]"),
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], _s: &Setup) {
        cfg.effects.polytropic = Some(Polytropic {
            enabled: true,
            exponent: p[0],
        });
    }
    fn describe(&self, p: &[f64], _s: &Setup) -> String {
        format!(
            "a polytropic chamber process with exponent {:.3} instead of isothermal (1)",
            p[0]
        )
    }
}

pub struct GravityCandidate;

impl Candidate for GravityCandidate {
    fn id(&self) -> &'static str {
        "gravity"
    }
    fn label(&self) -> &'static str {
        "gravity load"
    }
    fn params(&self, _s: &Setup) -> Vec<ParamSpec> {
        vec![
            ParamSpec::new("mass_kg", 0.0, 20.0, 1.0),
            ParamSpec::new(
                "hanging_angle_rad",
                -std::f64::consts::PI,
                std::f64::consts::PI,
                1.0,
            ),
        ]
    }
    fn fixed(&self) -> Vec<(&'static str, f64)> {
        vec![("com_distance_m", GRAVITY_COM_DISTANCE_M)]
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        let sin: Vec<f64> = ev.angle_rad.iter().map(|b| b.sin()).collect();
        let cos: Vec<f64> = ev.angle_rad.iter().map(|b| b.cos()).collect();
        let (c, r2) = regress(&ev.torque_residual_nm, &[&sin, &cos]);
        // -mgl sin(b - bh) = -mgl cos(bh) sin b + mgl sin(bh) cos b
        let mgl = c[0].hypot(c[1]);
        let bh = c[1].atan2(-c[0]);
        let m = mgl / (9.806_65 * GRAVITY_COM_DISTANCE_M);
        Screening {
            score: r2,
            initial: clamp_to(&self.params(s), vec![m, bh]),
            note: format!(
                "the joint torque balance residual follows the sine of the angle (R^2 {r2:.2})"
            ),
            scatter: Some(Scatter::new(
                "joint angle [rad]",
                "torque balance residual [N m]",
                &ev.angle_rad,
                &ev.torque_residual_nm,
            )),
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], _s: &Setup) {
        cfg.effects.gravity = Some(Gravity {
            enabled: true,
            mass_kg: p[0],
            com_distance_m: GRAVITY_COM_DISTANCE_M,
            hanging_angle_rad: p[1],
            g_m_s2: 9.806_65,
        });
    }
    fn describe(&self, p: &[f64], _s: &Setup) -> String {
        format!(
            "a gravity load of {:.3} N m peak ({:.3} kg at {GRAVITY_COM_DISTANCE_M} m), hanging at {:.1} deg",
            p[0] * 9.806_65 * GRAVITY_COM_DISTANCE_M,
            p[0],
            p[1].to_degrees()
        )
    }
}

pub struct InertiaCandidate;

impl Candidate for InertiaCandidate {
    fn id(&self) -> &'static str {
        "inertia"
    }
    fn label(&self) -> &'static str {
        "inertia (load) mismatch"
    }
    fn params(&self, _s: &Setup) -> Vec<ParamSpec> {
        vec![ParamSpec::new("inertia_kgm2", 1e-3, 10.0, 0.01)]
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        let (c, r2) = regress(&ev.torque_residual_nm, &[&ev.alpha_rad_s2]);
        Screening {
            score: r2,
            initial: clamp_to(&self.params(s), vec![ev.inertia_kgm2 - c[0]]),
            note: format!(
                "the joint torque balance residual is proportional to the angular acceleration (R^2 {r2:.2})"
            ),
            scatter: Some(Scatter::new(
                "angular acceleration [rad/s^2]",
                "torque balance residual [N m]",
                &ev.alpha_rad_s2,
                &ev.torque_residual_nm,
            )),
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], _s: &Setup) {
        cfg.joint.inertia_kgm2 = p[0];
    }
    fn describe(&self, p: &[f64], _s: &Setup) -> String {
        format!("a joint inertia of {:.4} kg m^2", p[0])
    }
}

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
        let (c, r2) = regress_pressure(ev, &ev.leak_signature);
        Screening {
            score: r2,
            initial: clamp_to(&self.params(s), vec![c]),
            note: format!(
                "the chambers lose pressure at a rate that follows an orifice to atmosphere (R^2 {r2:.2})"
            ),
            scatter: pressure_scatter(ev, &ev.leak_signature, "leak regressor [Pa/s per m^3/(s Pa)]"),
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

pub struct SensorOffsetCandidate;

const OFFSET_NAMES: [&str; 5] = [
    "angle_offset_deg",
    "p1_offset_kpa",
    "p2_offset_kpa",
    "f1_offset_n",
    "f2_offset_n",
];
const OFFSET_SCALES: [f64; 5] = [0.5, 5.0, 5.0, 5.0, 5.0];

impl Candidate for SensorOffsetCandidate {
    fn id(&self) -> &'static str {
        "sensor_offset"
    }
    fn label(&self) -> &'static str {
        "sensor calibration offset"
    }
    fn params(&self, s: &Setup) -> Vec<ParamSpec> {
        Channel::ALL
            .iter()
            .filter(|c| s.has(**c))
            .map(|c| {
                let sc = OFFSET_SCALES[c.index()];
                ParamSpec::new(OFFSET_NAMES[c.index()], -1e3 * sc, 1e3 * sc, sc)
            })
            .collect()
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        let mut init = Vec::new();
        let mut explained = 0.0;
        let mut total = 0.0;
        for c in Channel::ALL {
            if let Some(r) = &ev.residual[c.index()] {
                let n = r.len() as f64;
                let mean = r.iter().sum::<f64>() / n;
                let ss: f64 = r.iter().map(|v| v * v).sum();
                let w = 1.0 / ev.spread[c.index()].powi(2);
                explained += w * mean * mean * n;
                total += w * ss;
                init.push(mean);
            }
        }
        let score = if total > 0.0 { explained / total } else { 0.0 };
        Screening {
            score,
            initial: clamp_to(&self.params(s), init),
            note: format!(
                "a constant share of the residual ({:.0} % of its energy) is a fixed offset",
                100.0 * score
            ),
            scatter: None,
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], s: &Setup) {
        // The offsets are fitted; the gains of a calibration the plant file already has stay.
        let mut cal =
            cfg.effects
                .sensor
                .clone()
                .filter(|c| c.enabled)
                .unwrap_or(SensorCalibration {
                    enabled: true,
                    angle_deg: None,
                    p1_kpa: None,
                    p2_kpa: None,
                    f1_n: None,
                    f2_n: None,
                });
        let mut it = p.iter();
        for c in Channel::ALL {
            if !s.has(c) {
                continue;
            }
            let slot = match c {
                Channel::AngleDeg => &mut cal.angle_deg,
                Channel::P1Kpa => &mut cal.p1_kpa,
                Channel::P2Kpa => &mut cal.p2_kpa,
                Channel::F1N => &mut cal.f1_n,
                Channel::F2N => &mut cal.f2_n,
            };
            *slot = Some(ChannelCalibration {
                offset: *it.next().unwrap_or(&0.0),
                gain: slot.map_or(1.0, |k| k.gain),
            });
        }
        cfg.effects.sensor = Some(cal);
    }
    fn changes_dynamics(&self) -> bool {
        false
    }
    fn describe(&self, p: &[f64], s: &Setup) -> String {
        let parts: Vec<String> = self
            .params(s)
            .iter()
            .zip(p)
            .map(|(n, v)| format!("{} {:+.3}", n.name, v))
            .collect();
        format!("constant sensor offsets ({})", parts.join(", "))
    }
}

/// Regression of both chambers' pressure-rate residual on one regressor per chamber;
/// returns (coefficient, R^2).
#[allow(clippy::needless_range_loop)]
fn regress_pressure(ev: &Evidence, reg: &[Vec<f64>; 2]) -> (f64, f64) {
    let mut y = Vec::new();
    let mut x = Vec::new();
    for i in 0..2 {
        if let Some(r) = &ev.pressure_residual_pa_s[i] {
            y.extend_from_slice(r);
            x.extend_from_slice(&reg[i]);
        }
    }
    if y.is_empty() {
        return (0.0, 0.0);
    }
    let (c, r2) = regress(&y, &[&x]);
    (c[0], r2)
}

fn pressure_scatter(ev: &Evidence, reg: &[Vec<f64>; 2], xlabel: &str) -> Option<Scatter> {
    let (i, r) = ev
        .pressure_residual_pa_s
        .iter()
        .enumerate()
        .find_map(|(i, r)| r.as_ref().map(|r| (i, r)))?;
    Some(Scatter::new(
        xlabel,
        &format!("p{} rate residual [Pa/s]", i + 1),
        &reg[i],
        r,
    ))
}
