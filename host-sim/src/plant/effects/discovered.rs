//! `[effects.discovered]`: a term found by `host-sim discover` (the discovery stage of the
//! diagnosis, `crate::diagnose::discover`), written back into the plant file so that every
//! mode (replay, closed loop, `identify plant`, `diagnose`) runs it as physics.
//!
//! The table names one **slot** (one equation of the plant) and a short sum of library
//! **terms** with their coefficients:
//!
//! | slot | equation | a term adds |
//! |---|---|---|
//! | `joint` | J omega' = T | a torque [N m] of the angle, the speed or the muscle tensions |
//! | `transmission` | chi = chi0 +- r beta / l, T = r (F1 - F2) | a change of the muscles' travel [m] with the angle (the lever follows as its derivative), or a cable's stretch under the muscle force |
//! | `chamber_p1`, `chamber_p2`, `chambers` (both, one term) | dp/dt = (p_atm Q - p dV) / V | a standard volume flow into that chamber [m^3/s ANR] of its gauge pressure, or of its valves' openings and nominal flows |
//! | `sensor_angle`, `sensor_p1`, `sensor_p2` | reading = x | a reading error [deg or kPa] of the true value or of its rate (a lag) |
//!
//! ```toml
//! [effects.discovered]
//! slot = "joint"
//! terms = ["speed*|speed|"]
//! coefficients = [-0.105]
//! ```
//!
//! Each term is written as its symbol ([`Term::symbol`]); its unit and meaning are in
//! [`Term::unit`] and [`Term::sentence`]. Angles are in rad, speeds in rad/s, tensions in N,
//! pressures in kPa gauge, readings in the channel's unit (deg, kPa).
//!
//! Diagnosis: no candidate (the discovery writes this table; the catalogue never proposes
//! it). Truths: none.

use serde::{Deserialize, Deserializer};

use super::{enabled_default, ChannelFilter, Check, Effect, Hooks, Truth};
use crate::plant::effects::candidate::{Candidate, EffectCandidates};
use crate::plant::state::Measurement;
use crate::plant::tables::{ConfigError, ValveConfig};

/// The equation a discovered term enters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Slot {
    /// The joint's torque balance.
    Joint,
    /// The lever between the muscles and the joint.
    Transmission,
    /// Chamber 1's pressure (mass-flow) equation.
    ChamberP1,
    /// Chamber 2's pressure (mass-flow) equation.
    ChamberP2,
    /// Both chambers' pressure equations, one term for both (a property of all four valves
    /// or of both muscles).
    Chambers,
    /// The angle sensor's map.
    SensorAngle,
    /// The p1 sensor's map.
    SensorP1,
    /// The p2 sensor's map.
    SensorP2,
}

impl Slot {
    pub const ALL: [Slot; 8] = [
        Slot::Joint,
        Slot::Transmission,
        Slot::ChamberP1,
        Slot::ChamberP2,
        Slot::Chambers,
        Slot::SensorAngle,
        Slot::SensorP1,
        Slot::SensorP2,
    ];

    /// Its TOML / JSON name.
    pub fn name(self) -> &'static str {
        match self {
            Slot::Joint => "joint",
            Slot::Transmission => "transmission",
            Slot::ChamberP1 => "chamber_p1",
            Slot::ChamberP2 => "chamber_p2",
            Slot::Chambers => "chambers",
            Slot::SensorAngle => "sensor_angle",
            Slot::SensorP1 => "sensor_p1",
            Slot::SensorP2 => "sensor_p2",
        }
    }

    /// The equation in words.
    pub fn equation(self) -> &'static str {
        match self {
            Slot::Joint => "the joint's torque balance",
            Slot::Transmission => "the transmission between the muscles and the joint",
            Slot::ChamberP1 => "chamber 1's pressure equation",
            Slot::ChamberP2 => "chamber 2's pressure equation",
            Slot::Chambers => "both chambers' pressure equations",
            Slot::SensorAngle => "the angle sensor's map",
            Slot::SensorP1 => "the p1 sensor's map",
            Slot::SensorP2 => "the p2 sensor's map",
        }
    }

    /// What a term adds to (for sentences: "joint torque += ...").
    pub fn lhs(self) -> &'static str {
        match self {
            Slot::Joint => "joint torque",
            Slot::Transmission => "muscle travel",
            Slot::ChamberP1 => "chamber 1 inflow",
            Slot::ChamberP2 => "chamber 2 inflow",
            Slot::Chambers => "each chamber's inflow",
            Slot::SensorAngle => "angle reading",
            Slot::SensorP1 => "p1 reading",
            Slot::SensorP2 => "p2 reading",
        }
    }

    /// The unit of what a term adds.
    pub fn unit(self) -> &'static str {
        match self {
            Slot::Joint => "N m",
            Slot::Transmission => "m",
            Slot::ChamberP1 | Slot::ChamberP2 | Slot::Chambers => "m^3/s (ANR)",
            Slot::SensorAngle => "deg",
            Slot::SensorP1 | Slot::SensorP2 => "kPa",
        }
    }

    /// True when the slot changes only what a sensor reports.
    pub fn is_sensor(self) -> bool {
        matches!(self, Slot::SensorAngle | Slot::SensorP1 | Slot::SensorP2)
    }

    /// The library of terms this slot may use (the parametrised ones at each value the
    /// discovery tries).
    pub fn library(self) -> Vec<Term> {
        use Term::*;
        match self {
            Slot::Joint => {
                let mut v = vec![Speed, SignSpeed];
                v.extend([0.05, 0.2, 1.0].map(TanhSpeed));
                v.extend([SpeedAbsSpeed, Angle, AngleSq, AngleCubed]);
                v.extend([0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4].map(DeadbandAngle));
                v.extend([0.2, 0.35].map(SaturationAngle));
                v.extend([Force1, Force2, ForceDiff]);
                v
            }
            Slot::Transmission => vec![ShiftOneMinusCos, ShiftSin, ShiftAngleSq, ShiftAngleCubed, Stretch],
            Slot::ChamberP1 | Slot::ChamberP2 | Slot::Chambers => {
                let mut v = vec![Pressure, PressureSq, SqrtPressure, InletFlow, ExhaustFlow];
                v.extend([0.1, 0.15, 0.2, 0.25, 0.3].map(InletDeadZone));
                v.extend([0.1, 0.15, 0.2, 0.25, 0.3].map(ExhaustDeadZone));
                v
            }
            Slot::SensorAngle | Slot::SensorP1 | Slot::SensorP2 => {
                vec![Reading, ReadingSq, ReadingCubed, ReadingRate]
            }
        }
    }
}

/// Smoothing speed of `sign(speed)` (rad/s): the right-hand side stays continuous for the
/// integrator.
pub const SIGN_SMOOTHING_RAD_S: f64 = 0.01;

/// One library term. Its value is computed from [`TermInput`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Term {
    /// omega [rad/s].
    Speed,
    /// sign(omega), smoothed as tanh(omega / [`SIGN_SMOOTHING_RAD_S`]) [1].
    SignSpeed,
    /// tanh(omega / v0) [1], v0 in rad/s.
    TanhSpeed(f64),
    /// omega |omega| [rad^2/s^2].
    SpeedAbsSpeed,
    /// beta [rad].
    Angle,
    /// beta^2 [rad^2].
    AngleSq,
    /// beta^3 [rad^3].
    AngleCubed,
    /// max(|beta| - delta, 0) sign(beta) [rad], delta in rad: zero inside a band.
    DeadbandAngle(f64),
    /// clamp(beta, -delta, delta) [rad].
    SaturationAngle(f64),
    /// F1 [N].
    Force1,
    /// F2 [N].
    Force2,
    /// F1 - F2 [N].
    ForceDiff,
    /// Transmission: the muscles' travel gains r (1 - cos beta) [m] (an eccentric sprocket:
    /// its lever r (1 + c sin beta)).
    ShiftOneMinusCos,
    /// Transmission: the travel gains r sin(beta) [m] (lever r (1 + c cos beta)).
    ShiftSin,
    /// Transmission: the travel gains r beta^2 [m] (lever r (1 + 2 c beta)).
    ShiftAngleSq,
    /// Transmission: the travel gains r beta^3 [m] (lever r (1 + 3 c beta^2)).
    ShiftAngleCubed,
    /// Transmission: each cable stretches by its muscle's tension F [N] times the coefficient
    /// (a compliance, m/N; the muscle contracts further by the stretch; quasi-static).
    Stretch,
    /// p (gauge) [kPa].
    Pressure,
    /// p^2 [kPa^2].
    PressureSq,
    /// sqrt(max(p, 0)) [kPa^0.5].
    SqrtPressure,
    /// The inlet valve's nominal flow u_in Q(p_s, p) [m^3/s ANR] (a coefficient of -0.2: the
    /// valve passes 20 % less).
    InletFlow,
    /// The exhaust valve's nominal flow -u_ex Q(p, p_atm) [m^3/s ANR] (negative: out).
    ExhaustFlow,
    /// The inlet flow while the opening is below z (a coefficient of -1: the valve stays shut
    /// below z).
    InletDeadZone(f64),
    /// The exhaust flow while its opening is below z.
    ExhaustDeadZone(f64),
    /// x, the true value of the sensor's channel [deg or kPa].
    Reading,
    /// x^2.
    ReadingSq,
    /// x^3.
    ReadingCubed,
    /// dx/dt, the rate of the sensor's channel (a coefficient of -tau: a first-order lag of
    /// tau seconds, for tau small against the signal's time scale).
    ReadingRate,
}

/// What a term is computed from.
#[derive(Debug, Clone, Copy, Default)]
pub struct TermInput {
    pub angle_rad: f64,
    pub speed_rad_s: f64,
    pub tensions_n: [f64; 2],
    pub sprocket_radius_m: f64,
    pub p_gauge_kpa: f64,
    /// The sensor's channel (deg, kPa).
    pub reading: f64,
    /// Its rate (deg/s, kPa/s).
    pub reading_rate: f64,
    /// The chamber's valve openings (inlet, exhaust) and their nominal signed flows [m^3/s
    /// ANR] (inlet >= 0, exhaust <= 0).
    pub openings: [f64; 2],
    pub valve_flows_m3_s: [f64; 2],
}

impl Term {
    /// Its symbol (also its TOML form).
    pub fn symbol(&self) -> String {
        use Term::*;
        match *self {
            Speed => "speed".into(),
            SignSpeed => "sign(speed)".into(),
            TanhSpeed(v0) => format!("tanh(speed/{})", fmt_param(v0)),
            SpeedAbsSpeed => "speed*|speed|".into(),
            Angle => "angle".into(),
            AngleSq => "angle^2".into(),
            AngleCubed => "angle^3".into(),
            DeadbandAngle(d) => format!("deadband(angle,{})", fmt_param(d)),
            SaturationAngle(d) => format!("saturation(angle,{})", fmt_param(d)),
            Force1 => "f1".into(),
            Force2 => "f2".into(),
            ForceDiff => "f1-f2".into(),
            ShiftOneMinusCos => "travel(r*(1-cos(angle)))".into(),
            ShiftSin => "travel(r*sin(angle))".into(),
            ShiftAngleSq => "travel(r*angle^2)".into(),
            ShiftAngleCubed => "travel(r*angle^3)".into(),
            Stretch => "stretch(f)".into(),
            Pressure => "p".into(),
            PressureSq => "p^2".into(),
            SqrtPressure => "sqrt(p)".into(),
            InletFlow => "q_in".into(),
            ExhaustFlow => "q_ex".into(),
            InletDeadZone(z) => format!("deadzone(u_in,{})*q_in", fmt_param(z)),
            ExhaustDeadZone(z) => format!("deadzone(u_ex,{})*q_ex", fmt_param(z)),
            Reading => "x".into(),
            ReadingSq => "x^2".into(),
            ReadingCubed => "x^3".into(),
            ReadingRate => "dx/dt".into(),
        }
    }

    /// Parses a symbol ([`Self::symbol`]).
    pub fn parse(s: &str) -> Option<Term> {
        use Term::*;
        let s: String = s.chars().filter(|c| !c.is_whitespace()).collect();
        let param = |prefix: &str, suffix: &str| -> Option<f64> {
            let v: f64 = s.strip_prefix(prefix)?.strip_suffix(suffix)?.parse().ok()?;
            (v.is_finite() && v > 0.0).then_some(v)
        };
        Some(match s.as_str() {
            "speed" => Speed,
            "sign(speed)" => SignSpeed,
            "speed*|speed|" => SpeedAbsSpeed,
            "angle" => Angle,
            "angle^2" => AngleSq,
            "angle^3" => AngleCubed,
            "f1" => Force1,
            "f2" => Force2,
            "f1-f2" => ForceDiff,
            "travel(r*(1-cos(angle)))" => ShiftOneMinusCos,
            "travel(r*sin(angle))" => ShiftSin,
            "travel(r*angle^2)" => ShiftAngleSq,
            "travel(r*angle^3)" => ShiftAngleCubed,
            "stretch(f)" => Stretch,
            "p" => Pressure,
            "p^2" => PressureSq,
            "sqrt(p)" => SqrtPressure,
            "q_in" => InletFlow,
            "q_ex" => ExhaustFlow,
            "x" => Reading,
            "x^2" => ReadingSq,
            "x^3" => ReadingCubed,
            "dx/dt" => ReadingRate,
            _ => {
                if let Some(v) = param("tanh(speed/", ")") {
                    TanhSpeed(v)
                } else if let Some(d) = param("deadband(angle,", ")") {
                    DeadbandAngle(d)
                } else if let Some(d) = param("saturation(angle,", ")") {
                    SaturationAngle(d)
                } else if let Some(z) = param("deadzone(u_in,", ")*q_in") {
                    InletDeadZone(z)
                } else if let Some(z) = param("deadzone(u_ex,", ")*q_ex") {
                    ExhaustDeadZone(z)
                } else {
                    return None;
                }
            }
        })
    }

    /// The unit of the term's value (its coefficient's unit is the slot's over it).
    pub fn unit(&self, slot: Slot) -> &'static str {
        use Term::*;
        match self {
            Speed => "rad/s",
            SignSpeed | TanhSpeed(_) => "1",
            SpeedAbsSpeed => "rad^2/s^2",
            Angle | DeadbandAngle(_) | SaturationAngle(_) => "rad",
            AngleSq => "rad^2",
            AngleCubed => "rad^3",
            Force1 | Force2 | ForceDiff => "N",
            ShiftOneMinusCos | ShiftSin | ShiftAngleSq | ShiftAngleCubed => "m",
            Stretch => "N",
            Pressure => "kPa",
            PressureSq => "kPa^2",
            SqrtPressure => "kPa^0.5",
            InletFlow | ExhaustFlow | InletDeadZone(_) | ExhaustDeadZone(_) => "m^3/s (ANR)",
            Reading => match slot {
                Slot::SensorAngle => "deg",
                _ => "kPa",
            },
            ReadingSq => match slot {
                Slot::SensorAngle => "deg^2",
                _ => "kPa^2",
            },
            ReadingCubed => match slot {
                Slot::SensorAngle => "deg^3",
                _ => "kPa^3",
            },
            ReadingRate => match slot {
                Slot::SensorAngle => "deg/s",
                _ => "kPa/s",
            },
        }
    }

    /// One sentence on what the term means physically.
    pub fn sentence(&self) -> String {
        use Term::*;
        match *self {
            Speed => "viscous damping: a torque proportional to the speed".into(),
            SignSpeed => "dry (Coulomb) friction: a constant torque against the motion".into(),
            TanhSpeed(v0) => format!(
                "friction that saturates with the speed: linear below {} rad/s, constant above",
                fmt_param(v0)
            ),
            SpeedAbsSpeed => {
                "quadratic (aerodynamic or turbulent) damping: a torque growing with the speed squared".into()
            }
            Angle => "a linear spring on the joint".into(),
            AngleSq => "an asymmetric spring (stiffer on one side)".into(),
            AngleCubed => "a hardening spring (stiffens with the angle)".into(),
            DeadbandAngle(d) => format!(
                "a spring that acts only beyond +-{:.1} deg: end stops or a dead band",
                d.to_degrees()
            ),
            SaturationAngle(d) => format!(
                "a spring torque that saturates beyond +-{:.1} deg",
                d.to_degrees()
            ),
            Force1 => "a torque proportional to muscle 1's tension".into(),
            Force2 => "a torque proportional to muscle 2's tension".into(),
            ForceDiff => "a torque proportional to the tension difference (a lever that is off)".into(),
            ShiftOneMinusCos => {
                "an eccentric sprocket: the muscles travel r (angle + e (1 - cos angle)), the lever is r (1 + e sin angle)".into()
            }
            ShiftSin => "a sprocket whose lever changes with cos(angle): travel r (angle + c sin angle)".into(),
            ShiftAngleSq => "a lever growing linearly with the angle: travel r (angle + c angle^2)".into(),
            ShiftAngleCubed => "a lever growing with the angle squared: travel r (angle + c angle^3)".into(),
            Stretch => {
                "a compliant cable: each muscle contracts further by its cable's stretch, F / k (the coefficient is 1/k)".into()
            }
            Pressure => "a flow proportional to the gauge pressure (a laminar leak or supply)".into(),
            PressureSq => "a flow growing with the pressure squared".into(),
            SqrtPressure => "an orifice flow, proportional to sqrt(pressure)".into(),
            InletFlow => "the inlet valve passes a different share of its nominal flow".into(),
            ExhaustFlow => "the exhaust valve passes a different share of its nominal flow".into(),
            InletDeadZone(z) => format!(
                "a dead zone of the inlet valve: openings below {} pass a different flow \
                 (coefficient -1: none)",
                fmt_param(z)
            ),
            ExhaustDeadZone(z) => format!(
                "a dead zone of the exhaust valve: openings below {} pass a different flow \
                 (coefficient -1: none)",
                fmt_param(z)
            ),
            Reading => "a gain error of the sensor".into(),
            ReadingSq => "a quadratic (curved) transducer characteristic".into(),
            ReadingCubed => "a cubic transducer characteristic".into(),
            ReadingRate => {
                "a lag of the sensor: the reading trails the value by -coefficient seconds".into()
            }
        }
    }

    /// True when the term needs the valve openings and flows.
    pub fn needs_valves(&self) -> bool {
        use Term::*;
        matches!(
            self,
            InletFlow | ExhaustFlow | InletDeadZone(_) | ExhaustDeadZone(_)
        )
    }

    /// True when the term needs the muscle tensions.
    pub fn needs_tensions(&self) -> bool {
        use Term::*;
        matches!(self, Force1 | Force2 | ForceDiff)
    }

    /// The term's value.
    #[inline]
    pub fn eval(&self, x: &TermInput) -> f64 {
        use Term::*;
        let b = x.angle_rad;
        let w = x.speed_rad_s;
        let p = x.p_gauge_kpa;
        let y = x.reading;
        match *self {
            Speed => w,
            SignSpeed => (w / SIGN_SMOOTHING_RAD_S).tanh(),
            TanhSpeed(v0) => (w / v0).tanh(),
            SpeedAbsSpeed => w * w.abs(),
            Angle => b,
            AngleSq => b * b,
            AngleCubed => b * b * b,
            DeadbandAngle(d) => (b.abs() - d).max(0.0) * b.signum(),
            SaturationAngle(d) => b.clamp(-d, d),
            Force1 => x.tensions_n[0],
            Force2 => x.tensions_n[1],
            ForceDiff => x.tensions_n[0] - x.tensions_n[1],
            ShiftOneMinusCos => x.sprocket_radius_m * (1.0 - b.cos()),
            ShiftSin => x.sprocket_radius_m * b.sin(),
            ShiftAngleSq => x.sprocket_radius_m * b * b,
            ShiftAngleCubed => x.sprocket_radius_m * b * b * b,
            Stretch => x.tensions_n[0],
            Pressure => p,
            PressureSq => p * p,
            SqrtPressure => p.max(0.0).sqrt(),
            InletFlow => x.valve_flows_m3_s[0],
            ExhaustFlow => x.valve_flows_m3_s[1],
            InletDeadZone(z) => {
                if x.openings[0] < z {
                    x.valve_flows_m3_s[0]
                } else {
                    0.0
                }
            }
            ExhaustDeadZone(z) => {
                if x.openings[1] < z {
                    x.valve_flows_m3_s[1]
                } else {
                    0.0
                }
            }
            Reading => y,
            ReadingSq => y * y,
            ReadingCubed => y * y * y,
            ReadingRate => x.reading_rate,
        }
    }

    /// The variable the term is a function of, with its label and unit (the x axis of the
    /// report's plot of the residual against the term): speed, angle, a tension, the gauge
    /// pressure, the valve opening, the sensor's reading or its rate.
    pub fn argument(&self) -> (&'static str, fn(&TermInput) -> f64) {
        use Term::*;
        match *self {
            Speed | SignSpeed | TanhSpeed(_) | SpeedAbsSpeed => {
                ("speed [rad/s]", |x| x.speed_rad_s)
            }
            Angle | AngleSq | AngleCubed | DeadbandAngle(_) | SaturationAngle(_)
            | ShiftOneMinusCos | ShiftSin | ShiftAngleSq | ShiftAngleCubed => {
                ("angle [rad]", |x| x.angle_rad)
            }
            Force1 | Stretch => ("muscle 1 tension [N]", |x| x.tensions_n[0]),
            Force2 => ("muscle 2 tension [N]", |x| x.tensions_n[1]),
            ForceDiff => ("F1 - F2 [N]", |x| x.tensions_n[0] - x.tensions_n[1]),
            Pressure | PressureSq | SqrtPressure => ("gauge pressure [kPa]", |x| x.p_gauge_kpa),
            InletFlow | InletDeadZone(_) => ("inlet opening [1]", |x| x.openings[0]),
            ExhaustFlow | ExhaustDeadZone(_) => ("exhaust opening [1]", |x| x.openings[1]),
            Reading | ReadingSq | ReadingCubed => ("reading [deg or kPa]", |x| x.reading),
            ReadingRate => ("reading rate [deg/s or kPa/s]", |x| x.reading_rate),
        }
    }

    /// d/dbeta of a transmission term's travel [m/rad] (0 for other terms).
    pub fn travel_slope(&self, angle_rad: f64, sprocket_radius_m: f64) -> f64 {
        use Term::*;
        let b = angle_rad;
        sprocket_radius_m
            * match self {
                ShiftOneMinusCos => b.sin(),
                ShiftSin => b.cos(),
                ShiftAngleSq => 2.0 * b,
                ShiftAngleCubed => 3.0 * b * b,
                _ => 0.0,
            }
    }

    /// True when the term may enter `slot`.
    pub fn fits(&self, slot: Slot) -> bool {
        use Term::*;
        match slot {
            Slot::Joint => matches!(
                self,
                Speed
                    | SignSpeed
                    | TanhSpeed(_)
                    | SpeedAbsSpeed
                    | Angle
                    | AngleSq
                    | AngleCubed
                    | DeadbandAngle(_)
                    | SaturationAngle(_)
                    | Force1
                    | Force2
                    | ForceDiff
            ),
            Slot::Transmission => matches!(
                self,
                ShiftOneMinusCos | ShiftSin | ShiftAngleSq | ShiftAngleCubed | Stretch
            ),
            Slot::ChamberP1 | Slot::ChamberP2 | Slot::Chambers => matches!(
                self,
                Pressure
                    | PressureSq
                    | SqrtPressure
                    | InletFlow
                    | ExhaustFlow
                    | InletDeadZone(_)
                    | ExhaustDeadZone(_)
            ),
            _ => matches!(self, Reading | ReadingSq | ReadingCubed | ReadingRate),
        }
    }
}

/// A parameter in a symbol: the shortest text that reads back as the same number (the
/// plant file written replays exactly what the discovery scored).
fn fmt_param(v: f64) -> String {
    format!("{v}")
}

impl<'de> Deserialize<'de> for Term {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        Term::parse(&s).ok_or_else(|| {
            serde::de::Error::custom(format!(
                "unknown term `{s}` (e.g. `speed`, `sign(speed)`, `tanh(speed/0.05)`, \
                 `speed*|speed|`, `angle^3`, `deadband(angle,0.3)`, `f1-f2`, \
                 `r*(f1-f2)*sin(angle)`, `p`, `p^2`, `x`, `x^2`)"
            ))
        })
    }
}

/// The `[effects.discovered]` table.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Discovered {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    /// The equation the terms enter.
    pub slot: Slot,
    /// The terms, as symbols.
    pub terms: Vec<Term>,
    /// One coefficient per term, in the slot's unit over the term's.
    pub coefficients: Vec<f64>,
}

/// Most terms a table may hold.
pub const MAX_TERMS: usize = 6;

impl Discovered {
    /// The sum of the terms at `x`.
    #[inline]
    pub fn value(&self, x: &TermInput) -> f64 {
        self.terms
            .iter()
            .zip(&self.coefficients)
            .map(|(t, c)| c * t.eval(x))
            .sum()
    }

    /// True when a term needs the muscle tensions.
    pub fn needs_tensions(&self) -> bool {
        self.terms.iter().any(Term::needs_tensions)
    }

    /// True when a term needs the valve openings and flows.
    pub fn needs_valves(&self) -> bool {
        self.terms.iter().any(Term::needs_valves)
    }

    /// True when the 3-DOF arm cannot run the table (terms of the tensions or the valves:
    /// the arm runs the angle, speed, pressure and sensor hooks only).
    pub fn arm_refuses(&self) -> bool {
        self.needs_tensions()
            || self.needs_valves()
            || self.slot == Slot::Transmission
            || self.terms.contains(&Term::ReadingRate)
    }

    /// The channel index (angle, p1, p2) of a sensor slot.
    fn sensor_channel(&self) -> Option<usize> {
        match self.slot {
            Slot::SensorAngle => Some(0),
            Slot::SensorP1 => Some(1),
            Slot::SensorP2 => Some(2),
            _ => None,
        }
    }

    /// The chamber index (0, 1) the slot acts on.
    fn acts_on_chamber(&self, muscle: usize) -> bool {
        match self.slot {
            Slot::ChamberP1 => muscle == 0,
            Slot::ChamberP2 => muscle == 1,
            Slot::Chambers => true,
            _ => false,
        }
    }

    /// The sum of the terms as a formula: "joint torque += -2.100e-1 N m/(1) * tanh(speed/0.05)".
    pub fn formula(&self) -> String {
        let parts: Vec<String> = self
            .terms
            .iter()
            .zip(&self.coefficients)
            .map(|(term, c)| {
                format!(
                    "{c:+.3e} {}/({}) * {}",
                    self.slot.unit(),
                    term.unit(self.slot),
                    term.symbol()
                )
            })
            .collect();
        format!("{} += {}", self.slot.lhs(), parts.join(" "))
    }

    /// The table as TOML (`[effects.discovered]` and its keys).
    pub fn to_toml(&self) -> String {
        let terms: Vec<String> = self.terms.iter().map(|t| format!("\"{}\"", t.symbol())).collect();
        let coefs: Vec<String> = self.coefficients.iter().map(|c| format!("{c:e}")).collect();
        format!(
            "[effects.discovered]\nslot = \"{}\"\nterms = [{}]\ncoefficients = [{}]\n",
            self.slot.name(),
            terms.join(", "),
            coefs.join(", ")
        )
    }
}

impl Hooks for Discovered {
    fn parameters(&self) -> Option<Vec<(String, String)>> {
        let terms: Vec<String> = self.terms.iter().map(Term::symbol).collect();
        let coefs: Vec<String> = self.coefficients.iter().map(|c| format!("{c:e}")).collect();
        Some(vec![
            ("slot".into(), self.slot.name().into()),
            ("terms".into(), terms.join(" ")),
            ("coefficients".into(), coefs.join(" ")),
        ])
    }

    #[inline]
    fn joint_torque_nm(&self, angle_rad: f64, velocity_rad_s: f64) -> f64 {
        if self.slot != Slot::Joint || self.needs_tensions() {
            return 0.0;
        }
        self.value(&TermInput {
            angle_rad,
            speed_rad_s: velocity_rad_s,
            ..TermInput::default()
        })
    }

    #[inline]
    fn joint_torque_tensions_nm(
        &self,
        angle_rad: f64,
        velocity_rad_s: f64,
        tensions_n: [f64; 2],
        sprocket_radius_m: f64,
    ) -> f64 {
        if self.slot != Slot::Joint || !self.needs_tensions() {
            return 0.0;
        }
        self.value(&TermInput {
            angle_rad,
            speed_rad_s: velocity_rad_s,
            tensions_n,
            sprocket_radius_m,
            ..TermInput::default()
        })
    }

    #[inline]
    fn chamber_flow_m3_s(&self, muscle: usize, p_abs_pa: f64, p_atm_pa: f64) -> f64 {
        if !self.acts_on_chamber(muscle) || self.needs_valves() {
            return 0.0;
        }
        self.value(&TermInput {
            p_gauge_kpa: (p_abs_pa - p_atm_pa) * 1e-3,
            ..TermInput::default()
        })
    }

    #[inline]
    fn chamber_valve_flow_m3_s(
        &self,
        muscle: usize,
        p_abs_pa: f64,
        p_atm_pa: f64,
        openings: [f64; 2],
        valve_flows_m3_s: [f64; 2],
    ) -> f64 {
        if !self.acts_on_chamber(muscle) || !self.needs_valves() {
            return 0.0;
        }
        self.value(&TermInput {
            p_gauge_kpa: (p_abs_pa - p_atm_pa) * 1e-3,
            openings,
            valve_flows_m3_s,
            ..TermInput::default()
        })
    }

    fn transmission_map(&self, angle_rad: f64, sprocket_radius_m: f64) -> Option<[f64; 2]> {
        if self.slot != Slot::Transmission {
            return None;
        }
        let x = TermInput {
            angle_rad,
            sprocket_radius_m,
            ..TermInput::default()
        };
        let mut out = [0.0; 2];
        let mut any = false;
        for (t, c) in self.terms.iter().zip(&self.coefficients) {
            if *t != Term::Stretch {
                out[0] += c * t.eval(&x);
                out[1] += c * t.travel_slope(angle_rad, sprocket_radius_m);
                any = true;
            }
        }
        any.then_some(out)
    }

    fn cable_compliance_m_per_n(&self) -> Option<f64> {
        if self.slot != Slot::Transmission {
            return None;
        }
        self.terms
            .iter()
            .zip(&self.coefficients)
            .find(|(t, _)| **t == Term::Stretch)
            .map(|(_, c)| *c)
    }

    fn sensor_filter(&self, dt_s: f64) -> Option<Box<dyn ChannelFilter>> {
        let channel = self.sensor_channel()?;
        let c = self
            .terms
            .iter()
            .zip(&self.coefficients)
            .find(|(t, _)| **t == Term::ReadingRate)
            .map(|(_, c)| *c)?;
        Some(Box::new(RateFilter {
            channel,
            c,
            dt_s,
            prev: None,
        }))
    }

    fn calibrate(&self, mut m: Measurement) -> Measurement {
        let field = match self.slot {
            Slot::SensorAngle => &mut m.angle_deg,
            Slot::SensorP1 => &mut m.p1_kpa,
            Slot::SensorP2 => &mut m.p2_kpa,
            _ => return m,
        };
        let reading = *field;
        *field += self.value(&TermInput {
            reading,
            ..TermInput::default()
        });
        m
    }
}

/// The rate term of a sensor slot: reading = x + c dx/dt, dx/dt by the backward difference
/// of the samples (0 at the first).
struct RateFilter {
    channel: usize,
    c: f64,
    dt_s: f64,
    prev: Option<f64>,
}

impl ChannelFilter for RateFilter {
    fn push(&mut self, mut x: [f64; 5]) -> [f64; 5] {
        let v = x[self.channel];
        let rate = self.prev.map_or(0.0, |p| (v - p) / self.dt_s);
        self.prev = Some(v);
        x[self.channel] = v + self.c * rate;
        x
    }
}

impl Effect for Discovered {
    type Active = Self;
    const TRUTHS: &'static [Truth] = &[];
    fn enabled(&self) -> bool {
        self.enabled
    }
    fn activate(&self, _valve: &ValveConfig) -> Self {
        self.clone()
    }
    fn validate(&self, c: &Check) -> Result<(), ConfigError> {
        if self.terms.is_empty() || self.terms.len() > MAX_TERMS {
            return Err(c.error(
                "terms",
                format!("needs 1 to {MAX_TERMS} terms, got {}", self.terms.len()),
            ));
        }
        if self.coefficients.len() != self.terms.len() {
            return Err(c.error(
                "coefficients",
                format!(
                    "needs one coefficient per term: {} terms, {} coefficients",
                    self.terms.len(),
                    self.coefficients.len()
                ),
            ));
        }
        if let Some(t) = self.terms.iter().find(|t| !t.fits(self.slot)) {
            let allowed: Vec<String> = self.slot.library().iter().map(Term::symbol).collect();
            return Err(c.error(
                "terms",
                format!(
                    "`{}` does not enter the slot `{}` (its terms: {})",
                    t.symbol(),
                    self.slot.name(),
                    allowed.join(", ")
                ),
            ));
        }
        if let Some(v) = self.coefficients.iter().find(|v| !v.is_finite()) {
            return Err(c.error("coefficients", format!("must be finite, got {v}")));
        }
        if let Some((_, v)) = self
            .terms
            .iter()
            .zip(&self.coefficients)
            .find(|(t, v)| **t == Term::Stretch && !(0.0..1e-3).contains(*v))
        {
            return Err(c.error(
                "coefficients",
                format!("the cable compliance of `stretch(f)` must be in 0 .. 1e-3 m/N, got {v}"),
            ));
        }
        Ok(())
    }
}

impl EffectCandidates for Discovered {
    /// None: the discovery writes this table, the catalogue never proposes it.
    fn candidates() -> Vec<Box<dyn Candidate>> {
        Vec::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plant::config::PlantConfig;
    use crate::plant::{Plant, PlantState, ValveInputs};

    fn plant_with(table: &str) -> Result<PlantConfig, ConfigError> {
        let base = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/plants/reference-1dof.toml"
        ))
        .unwrap();
        PlantConfig::from_toml_str(&format!("{base}\n{table}"), "p.toml")
    }

    #[test]
    fn every_library_term_reads_back_from_its_symbol() {
        for slot in Slot::ALL {
            for t in slot.library() {
                assert_eq!(Term::parse(&t.symbol()), Some(t), "{}", t.symbol());
                assert!(t.fits(slot));
            }
        }
    }

    #[test]
    fn a_joint_term_reaches_the_right_hand_side() {
        let table = "[effects.discovered]\nslot = \"joint\"\nterms = [\"speed*|speed|\"]\ncoefficients = [-0.1]\n";
        let cfg = plant_with(table).unwrap();
        let nominal = plant_with("").unwrap();
        let x = PlantState {
            angle_rad: 0.1,
            velocity_rad_s: 2.0,
            p1_abs_pa: 3e5,
            p2_abs_pa: 3e5,
        };
        let u = ValveInputs::CLOSED;
        let a = Plant::from_config(&cfg).derivatives(&x, &u).velocity_rad_s;
        let b = Plant::from_config(&nominal).derivatives(&x, &u).velocity_rad_s;
        let j = cfg.joint.inertia_kgm2;
        assert!(((a - b) * j + 0.4).abs() < 1e-9, "{} N m", (a - b) * j);
        let ecc = "[effects.discovered]\nslot = \"transmission\"\nterms = [\"travel(r*(1-cos(angle)))\"]\ncoefficients = [0.2]\n";
        let p = Plant::from_config(&plant_with(ecc).unwrap());
        let (chi, _, lever) = p.kinematics(0.1, 0.0);
        let r = p.joint.sprocket_radius_m;
        assert!((lever - r * (1.0 + 0.2 * 0.1f64.sin())).abs() < 1e-12);
        let chi0 = p.joint.contractions(0.1);
        let l = r / p.joint.contraction_per_rad;
        assert!((chi[0] - chi0[0] - 0.2 * r * (1.0 - 0.1f64.cos()) / l).abs() < 1e-12);
    }

    #[test]
    fn a_sensor_term_changes_the_reading() {
        let table = "[effects.discovered]\nslot = \"sensor_p1\"\nterms = [\"x^2\"]\ncoefficients = [1e-4]\n";
        let p = Plant::from_config(&plant_with(table).unwrap());
        let x = PlantState {
            angle_rad: 0.0,
            velocity_rad_s: 0.0,
            p1_abs_pa: p.p_atm_pa + 200e3,
            p2_abs_pa: p.p_atm_pa + 100e3,
        };
        let m = p.measure(&x);
        assert!((m.p1_kpa - 204.0).abs() < 1e-9, "{}", m.p1_kpa);
        assert!((m.p2_kpa - 100.0).abs() < 1e-9);
    }

    #[test]
    fn a_rate_term_lags_the_reading() {
        let table = "[effects.discovered]\nslot = \"sensor_p1\"\nterms = [\"dx/dt\"]\ncoefficients = [-0.01]\n";
        let p = Plant::from_config(&plant_with(table).unwrap());
        // p1 rising at 100 kPa/s: read 1 kPa low (10 ms of lag) after the first sample.
        let states: Vec<PlantState> = (0..5)
            .map(|k| PlantState {
                angle_rad: 0.0,
                velocity_rad_s: 0.0,
                p1_abs_pa: p.p_atm_pa + 100e3 + 100e3 * k as f64 * 1e-3,
                p2_abs_pa: p.p_atm_pa + 100e3,
            })
            .collect();
        let m = p.measure_series(&states, 1e-3);
        assert!((m[0].p1_kpa - 100.0).abs() < 1e-9);
        assert!((m[3].p1_kpa - (100.3 - 1.0)).abs() < 1e-6, "{}", m[3].p1_kpa);
    }

    #[test]
    fn bad_tables_name_their_key() {
        let e = plant_with("[effects.discovered]\nslot = \"joint\"\nterms = [\"p\"]\ncoefficients = [1.0]\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("effects.discovered.terms"), "{e}");
        let e = plant_with("[effects.discovered]\nslot = \"joint\"\nterms = [\"speed\"]\ncoefficients = []\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("effects.discovered.coefficients"), "{e}");
        let e = plant_with("[effects.discovered]\nslot = \"joint\"\nterms = [\"speed^7\"]\ncoefficients = [1.0]\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("unknown term"), "{e}");
    }

    #[test]
    fn the_table_written_reads_back() {
        let d = Discovered {
            enabled: true,
            slot: Slot::Joint,
            terms: vec![Term::TanhSpeed(0.05), Term::DeadbandAngle(0.2618)],
            coefficients: vec![-0.21, -30.0],
        };
        let cfg = plant_with(&d.to_toml()).unwrap();
        assert_eq!(cfg.effects.discovered, Some(d));
    }
}
