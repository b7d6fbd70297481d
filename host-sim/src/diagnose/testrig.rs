//! An independent test rig for the diagnosis: recordings from a plant written again here,
//! NOT through [`crate::plant`], [`crate::sim`] or the candidates' effect code, with effect
//! forms unlike the candidates' (Stribeck friction, a supply reservoir, a choked leak in one
//! muscle, the thermodynamic chamber with wall heat transfer of seed 004, a valve dead time
//! of a fraction of a sample, an offset on one sensor), parameter mismatches of the plant
//! file's own keys, pure noise and noise-free nominal data. Every case draws its sizes from
//! its seed, runs a closed loop (a position controller drives the valves from the measured
//! angle) and samples at 1, 2 or 3 ms; some cases have no force channels.
//!
//! Integration: classical Runge-Kutta 4 at a fixed step of at most 0.1 ms (a plain method on
//! purpose: the simulator's adaptive Dormand-Prince with restarts is the code under test).
//! The physics follows `shared/plant/PLANT.md` (nominal model and the "thermodynamic
//! chamber" section) and is checked against the simulator on the nominal plant and against
//! `shared/conformance/pulses_thermal.csv` for the chamber model (tests/diagnose_independent.rs).

use rand::{rngs::StdRng, Rng, SeedableRng};
use rand_distr::StandardNormal;

use crate::io::recording::{Channel, Recording};
use crate::plant::config::PlantConfig;
use crate::plant::ValveInputs;

/// Gas constant of air, J/(kg K).
const R_AIR: f64 = 287.05;
/// Wall, supply and ambient temperature, K.
const T_WALL_K: f64 = 293.15;

/// The rig's physics, in its own representation (read from a plant file's numbers).
#[derive(Debug, Clone)]
pub struct RigPhysics {
    pub p_atm_pa: f64,
    pub supply_gauge_pa: f64,
    pub rest_length_m: f64,
    pub radius_m: f64,
    pub braid_angle_deg: f64,
    pub end_factor: f64,
    pub damping_m2s: f64,
    pub volume_poly_m3: [f64; 4],
    pub sprocket_radius_m: f64,
    pub inertia_kgm2: f64,
    pub initial_contraction: f64,
    pub conductance_m3_per_s_pa: f64,
    pub critical_ratio: f64,
    pub laminar_ratio: f64,
    pub initial: [f64; 4],
    /// Stribeck friction: (Coulomb N m, static N m, Stribeck velocity rad/s, viscous N m s/rad).
    pub stribeck: Option<[f64; 4]>,
    /// Supply reservoir: (tank volume m^3, feed conductance m^3/(s Pa)).
    pub reservoir: Option<[f64; 2]>,
    /// A choked leak to atmosphere from one muscle: (muscle 0 or 1, conductance m^3/(s Pa)).
    pub leak: Option<(usize, f64)>,
    /// Thermodynamic chamber: (hA W/K per muscle, kappa).
    pub thermal: Option<[f64; 2]>,
    /// Valve dead time (any real number of seconds).
    pub dead_time_s: f64,
    /// Offset added to one measured channel.
    pub offset: Option<(Channel, f64)>,
}

impl RigPhysics {
    /// The nominal physics of a plant file (numbers only; no simulator code).
    pub fn from_config(c: &PlantConfig) -> Self {
        Self {
            p_atm_pa: c.environment.p_atm_pa,
            supply_gauge_pa: c.environment.supply_gauge_pa,
            rest_length_m: c.muscle.rest_length_m,
            radius_m: c.muscle.radius_m,
            braid_angle_deg: c.muscle.braid_angle_deg,
            end_factor: c.muscle.end_factor,
            damping_m2s: c.muscle.damping_m2s,
            volume_poly_m3: c.muscle.volume_poly_m3,
            sprocket_radius_m: c.joint.sprocket_radius_m,
            inertia_kgm2: c.joint.inertia_kgm2,
            initial_contraction: c.joint.initial_contraction,
            conductance_m3_per_s_pa: c.valve.sonic_conductance_m3_per_s_pa,
            critical_ratio: c.valve.critical_ratio,
            laminar_ratio: c.valve.laminar_ratio,
            initial: [
                c.initial.angle_rad,
                c.initial.velocity_rad_s,
                c.initial.p1_gauge_pa + c.environment.p_atm_pa,
                c.initial.p2_gauge_pa + c.environment.p_atm_pa,
            ],
            stribeck: None,
            reservoir: None,
            leak: None,
            thermal: None,
            dead_time_s: 0.0,
            offset: None,
        }
    }

    /// ISO 6358 standard volume flow from `up` to `down` (signed).
    fn iso_flow(&self, c: f64, up: f64, down: f64) -> f64 {
        if up < down {
            return -self.iso_flow(c, down, up);
        }
        if up <= 0.0 {
            return 0.0;
        }
        let (b, l) = (self.critical_ratio, self.laminar_ratio);
        let sub = |s: f64| (1.0 - ((s - b) / (1.0 - b)).powi(2)).max(0.0).sqrt();
        let s = down / up;
        let phi = if s <= b {
            1.0
        } else if s < l {
            sub(s)
        } else {
            sub(l) * (1.0 - s) / (1.0 - l)
        };
        c * up * phi
    }

    fn volume(&self, chi: f64) -> (f64, f64) {
        let [b0, b1, b2, b3] = self.volume_poly_m3;
        (
            b0 + b1 * chi + b2 * chi * chi + b3 * chi * chi * chi,
            b1 + 2.0 * b2 * chi + 3.0 * b3 * chi * chi,
        )
    }

    /// Tension of one muscle (Tondu with the pressure-proportional damper).
    fn tension(&self, p_gauge: f64, chi: f64, dchi: f64) -> f64 {
        let a0 = self.braid_angle_deg.to_radians();
        let area = std::f64::consts::PI * self.radius_m * self.radius_m;
        let e = 1.0 - self.end_factor * chi;
        let f_static =
            (area * p_gauge * (3.0 / a0.tan().powi(2) * e * e - 1.0 / a0.sin().powi(2))).max(0.0);
        (f_static - self.damping_m2s * p_gauge * dchi).max(0.0)
    }

    /// State: beta, omega, p1, p2, T1, T2, tank pressure.
    fn rhs(&self, x: &[f64; 7], u: &ValveInputs) -> [f64; 7] {
        let (beta, omega) = (x[0], x[1]);
        let g = self.sprocket_radius_m / self.rest_length_m;
        let chi = [
            self.initial_contraction + g * beta,
            self.initial_contraction - g * beta,
        ];
        let dchi = [g * omega, -g * omega];
        let p_supply = if self.reservoir.is_some() {
            x[6]
        } else {
            self.supply_gauge_pa + self.p_atm_pa
        };
        let u_in = [u.u_in1, u.u_in2];
        let u_ex = [u.u_ex1, u.u_ex2];
        let mut dx = [0.0; 7];
        let mut q_supply = 0.0;
        let mut f = [0.0; 2];
        for i in 0..2 {
            let p = x[2 + i];
            let (v, dv_dchi) = self.volume(chi[i]);
            let dv = dv_dchi * dchi[i];
            f[i] = self.tension(p - self.p_atm_pa, chi[i], dchi[i]);
            // Signed flow parts (ANR m^3/s, + into the chamber).
            let q_in = u_in[i] * self.iso_flow(self.conductance_m3_per_s_pa, p_supply, p);
            let q_ex = -u_ex[i] * self.iso_flow(self.conductance_m3_per_s_pa, p, self.p_atm_pa);
            let q_leak = match self.leak {
                Some((m, c)) if m == i && p > self.p_atm_pa => {
                    // Choked orifice form: sonic below the critical ratio, else subsonic.
                    -self.iso_flow(c, p, self.p_atm_pa)
                }
                _ => 0.0,
            };
            q_supply += q_in;
            match self.thermal {
                None => {
                    dx[2 + i] = (self.p_atm_pa * (q_in + q_ex + q_leak) - p * dv) / v;
                }
                Some([ha, kappa]) => {
                    let t = x[4 + i];
                    let rho = self.p_atm_pa / (R_AIR * T_WALL_K);
                    let mut h = 0.0;
                    let mut mdot = 0.0;
                    for q in [q_in, q_ex, q_leak] {
                        h += rho * q * if q > 0.0 { T_WALL_K } else { t };
                        mdot += rho * q;
                    }
                    let dp = (kappa * R_AIR * h - kappa * p * dv
                        + (kappa - 1.0) * ha * (T_WALL_K - t))
                        / v;
                    dx[2 + i] = dp;
                    dx[4 + i] = t / (p * v) * (dp * v + p * dv - R_AIR * t * mdot);
                }
            }
        }
        let mut torque = (f[0] - f[1]) * self.sprocket_radius_m;
        if let Some([fc, fs, vs, fv]) = self.stribeck {
            let level = fc + (fs - fc) * (-(omega / vs).powi(2)).exp();
            torque -= level * (omega / 0.01).tanh() + fv * omega;
        }
        dx[0] = omega;
        dx[1] = torque / self.inertia_kgm2;
        if let Some([tank, c_feed]) = self.reservoir {
            let q_feed = self.iso_flow(c_feed, self.supply_gauge_pa + self.p_atm_pa, x[6]);
            dx[6] = self.p_atm_pa * (q_feed - q_supply) / tank;
        }
        dx
    }

    fn initial_state(&self) -> [f64; 7] {
        let i = self.initial;
        [
            i[0],
            i[1],
            i[2],
            i[3],
            T_WALL_K,
            T_WALL_K,
            self.supply_gauge_pa + self.p_atm_pa,
        ]
    }

    /// The true channels of a state (angle deg, gauge kPa, N).
    fn channels(&self, x: &[f64; 7]) -> [f64; 5] {
        let g = self.sprocket_radius_m / self.rest_length_m;
        let chi = [
            self.initial_contraction + g * x[0],
            self.initial_contraction - g * x[0],
        ];
        let dchi = [g * x[1], -g * x[1]];
        let mut y = [
            x[0].to_degrees(),
            (x[2] - self.p_atm_pa) / 1000.0,
            (x[3] - self.p_atm_pa) / 1000.0,
            self.tension(x[2] - self.p_atm_pa, chi[0], dchi[0]),
            self.tension(x[3] - self.p_atm_pa, chi[1], dchi[1]),
        ];
        if let Some((c, o)) = self.offset {
            y[c.index()] += o;
        }
        y
    }

    /// Replays the valve openings `inputs` (held over each sample period `dt_s`, delayed by
    /// the dead time) and returns the true channels at every sample.
    pub fn replay(&self, inputs: &[ValveInputs], dt_s: f64) -> Vec<[f64; 5]> {
        let mut run = Run::new(self, dt_s);
        inputs
            .iter()
            .map(|u| {
                let y = self.channels(&run.x);
                run.advance(self, *u);
                y
            })
            .collect()
    }
}

/// A running integration: the state, the sample period and the commanded history (for the
/// dead time).
struct Run {
    x: [f64; 7],
    dt_s: f64,
    substeps: usize,
    history: Vec<ValveInputs>,
}

impl Run {
    fn new(p: &RigPhysics, dt_s: f64) -> Self {
        Self {
            x: p.initial_state(),
            dt_s,
            substeps: (dt_s / 1e-4).ceil().max(1.0) as usize,
            history: Vec::new(),
        }
    }

    /// The valve openings applied at time `t` (commands delayed by the dead time).
    fn applied(&self, p: &RigPhysics, t: f64) -> ValveInputs {
        let td = t - p.dead_time_s;
        if td < 0.0 {
            return ValveInputs::CLOSED;
        }
        let k = ((td / self.dt_s) + 1e-9).floor() as usize;
        self.history
            .get(k.min(self.history.len().saturating_sub(1)))
            .copied()
            .unwrap_or(ValveInputs::CLOSED)
    }

    /// Integrates one sample period with command `u` issued at its start.
    fn advance(&mut self, p: &RigPhysics, u: ValveInputs) {
        let k0 = self.history.len();
        self.history.push(u);
        let h = self.dt_s / self.substeps as f64;
        for s in 0..self.substeps {
            let t = k0 as f64 * self.dt_s + s as f64 * h;
            // The input over the substep: at its midpoint (a dead time of a fraction of a
            // sample switches inside the sample period).
            let ui = self.applied(p, t + 0.5 * h);
            let f = |x: &[f64; 7]| p.rhs(x, &ui);
            let add = |x: &[f64; 7], k: &[f64; 7], c: f64| -> [f64; 7] {
                std::array::from_fn(|i| x[i] + c * k[i])
            };
            let k1 = f(&self.x);
            let k2 = f(&add(&self.x, &k1, 0.5 * h));
            let k3 = f(&add(&self.x, &k2, 0.5 * h));
            let k4 = f(&add(&self.x, &k3, h));
            self.x = std::array::from_fn(|i| {
                self.x[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
            });
        }
    }
}

/// What a case should be diagnosed as.
#[derive(Debug, Clone, PartialEq)]
pub enum Expected {
    /// These effect ids and recalibrated keys, exactly (sorted).
    Named(Vec<String>),
    /// Verdict `nothing_missing`.
    Nothing,
    /// Verdict `unexplained` or `not_this_plant` (exit status 3).
    Refuse,
}

/// The kinds of case of the matrix.
pub const KINDS: [&str; 13] = [
    "nominal_noise_free",
    "nominal",
    "pure_noise",
    "stribeck",
    "reservoir",
    "leak_one_muscle",
    "heat_transfer",
    "dead_time_fractional",
    "offset_one_sensor",
    "conductance_low",
    "radius_large",
    "inertia_load",
    "supply_low",
];

/// One generated case.
pub struct Case {
    pub kind: &'static str,
    pub seed: u64,
    pub dt_s: f64,
    pub force_channels: bool,
    /// The drawn sizes, for the report.
    pub sizes: String,
    pub expected: Expected,
    pub train: Recording,
    pub check: Recording,
}

/// Sensor noise of the rig (angle: encoder counts per turn; kPa; N).
pub const ENCODER_COUNTS: f64 = 4096.0;
pub const PRESSURE_NOISE_KPA: f64 = 0.6;
pub const FORCE_NOISE_N: f64 = 1.0;

/// Runs the rig in closed loop: a proportional position controller with a deadband turns
/// the measured angle error into valve openings (inflate one muscle, exhaust the other)
/// and keeps the mean pressure up; the set point steps every 0.4-1.2 s (TRAIN) or follows
/// a sum of sines with steps (CHECK).
fn closed_loop(
    p: &RigPhysics,
    dt_s: f64,
    duration_s: f64,
    rng: &mut StdRng,
    check_style: bool,
    noise: bool,
    force_channels: bool,
) -> Recording {
    let n = (duration_s / dt_s).round() as usize;
    let mut run = Run::new(p, dt_s);
    let mut setpoint_deg = 0.0;
    let mut next_step_s = 0.0;
    let gain_per_deg = rng.random_range(0.08..0.2);
    let (w1, w2) = (rng.random_range(1.5..3.0), rng.random_range(4.0..7.0));
    let mut t_s = Vec::with_capacity(n);
    let mut inputs = Vec::with_capacity(n);
    let mut out: [Vec<f64>; 5] = std::array::from_fn(|_| Vec::with_capacity(n));
    for k in 0..n {
        let t = k as f64 * dt_s;
        let mut y = p.channels(&run.x);
        if noise {
            let counts = ENCODER_COUNTS / 360.0;
            y[0] = (y[0] * counts).round() / counts;
            for c in 1..3 {
                y[c] += PRESSURE_NOISE_KPA * rng.sample::<f64, _>(StandardNormal);
            }
            for c in 3..5 {
                y[c] += FORCE_NOISE_N * rng.sample::<f64, _>(StandardNormal);
            }
        }
        if t >= next_step_s {
            setpoint_deg = rng.random_range(-25.0..25.0);
            next_step_s = t + rng.random_range(0.4..1.2);
        }
        let r = if check_style {
            0.5 * setpoint_deg + 12.0 * (w1 * t).sin() + 5.0 * (w2 * t).sin()
        } else {
            setpoint_deg
        };
        let e = r - y[0];
        let m = (gain_per_deg * e).clamp(-1.0, 1.0);
        let m = if m.abs() < 0.02 { 0.0 } else { m };
        let mean_kpa = 0.5 * (y[1] + y[2]);
        let top = if mean_kpa < 250.0 { 0.3 } else { 0.0 };
        let u = if m >= 0.0 {
            ValveInputs {
                u_in1: (m + top).min(1.0),
                u_ex1: 0.0,
                u_in2: top,
                u_ex2: m,
            }
        } else {
            ValveInputs {
                u_in1: top,
                u_ex1: -m,
                u_in2: (-m + top).min(1.0),
                u_ex2: 0.0,
            }
        };
        t_s.push(t);
        inputs.push(u);
        for c in 0..5 {
            out[c].push(y[c]);
        }
        run.advance(p, u);
    }
    let mut outputs: [Option<Vec<f64>>; 5] = out.map(Some);
    if !force_channels {
        outputs[3] = None;
        outputs[4] = None;
    }
    Recording {
        metadata: vec![
            ("sample_period_s".into(), format!("{dt_s}")),
            (
                "source".into(),
                "independent test rig (diagnose::testrig), closed loop".into(),
            ),
        ],
        t_s,
        inputs,
        outputs,
        mass_flow_kg_s: None,
    }
}

fn named(ids: &[&str]) -> Expected {
    let mut v: Vec<String> = ids.iter().map(|s| s.to_string()).collect();
    v.sort();
    Expected::Named(v)
}

/// Generates one case of `kind` from `seed` on the nominal plant `nominal` (sizes, sample
/// period and force channels drawn from the seed).
pub fn case(nominal: &PlantConfig, kind: &'static str, seed: u64) -> Case {
    let mut rng = StdRng::seed_from_u64(seed ^ 0x9e37_79b9_7f4a_7c15);
    let dt_s = [1e-3, 2e-3, 3e-3][rng.random_range(0..3)];
    let force_channels = rng.random_bool(0.5);
    let mut p = RigPhysics::from_config(nominal);
    let mut noise = true;
    let (sizes, expected) = match kind {
        "nominal_noise_free" => {
            noise = false;
            (String::new(), Expected::Nothing)
        }
        "nominal" => (String::new(), Expected::Nothing),
        "pure_noise" => (String::new(), Expected::Refuse),
        "stribeck" => {
            let fc = rng.random_range(0.2..0.4);
            let fs = fc * rng.random_range(1.5..2.5);
            let vs = rng.random_range(0.1..0.5);
            let fv = rng.random_range(0.02..0.08);
            p.stribeck = Some([fc, fs, vs, fv]);
            (
                format!("Coulomb {fc:.3} N m, static {fs:.3} N m, Stribeck {vs:.2} rad/s, viscous {fv:.3} N m s/rad"),
                named(&["joint_friction"]),
            )
        }
        "reservoir" => {
            let tank = rng.random_range(3e-4..8e-4);
            let feed = rng.random_range(4e-9..8e-9);
            p.reservoir = Some([tank, feed]);
            (
                format!("tank {:.2} l, feed conductance {feed:.2e}", tank * 1e3),
                named(&["supply_drop"]),
            )
        }
        "leak_one_muscle" => {
            let m = rng.random_range(0..2);
            let c = rng.random_range(4e-10..9e-10);
            p.leak = Some((m, c));
            (
                format!("muscle {}, conductance {c:.2e}", m + 1),
                // The one-muscle form names the leaking muscle (the form that leaks both
                // muscles was the expected answer while the catalogue had no other).
                named(&[["leakage_muscle1", "leakage_muscle2"][m]]),
            )
        }
        "heat_transfer" => {
            let ha = rng.random_range(0.5..3.0);
            p.thermal = Some([ha, 1.4]);
            // The catalogue's physical form of it (the polytropic exponent is its look-alike,
            // the accepted answer only while the catalogue had no heat-transfer candidate).
            (
                format!("hA {ha:.2} W/K, kappa 1.4"),
                named(&["heat_transfer"]),
            )
        }
        "dead_time_fractional" => {
            let d = rng.random_range(5e-3..12e-3);
            p.dead_time_s = d;
            (
                format!("{:.2} ms ({:.2} samples)", d * 1e3, d / dt_s),
                named(&["valve_delay"]),
            )
        }
        "offset_one_sensor" => {
            let (c, o) = if rng.random_bool(0.5) {
                (
                    Channel::P1Kpa,
                    rng.random_range(6.0..12.0) * if rng.random_bool(0.5) { 1.0 } else { -1.0 },
                )
            } else {
                (
                    Channel::AngleDeg,
                    rng.random_range(1.0..2.5) * if rng.random_bool(0.5) { 1.0 } else { -1.0 },
                )
            };
            p.offset = Some((c, o));
            (format!("{} {o:+.2}", c.name()), named(&["sensor_offset"]))
        }
        "conductance_low" => {
            let f = rng.random_range(0.6..0.8);
            p.conductance_m3_per_s_pa *= f;
            (
                format!("x{f:.3}"),
                named(&["valve.sonic_conductance_m3_per_s_pa"]),
            )
        }
        "radius_large" => {
            let f = rng.random_range(1.03..1.08);
            p.radius_m *= f;
            (format!("x{f:.3}"), named(&["muscle.radius_m"]))
        }
        "inertia_load" => {
            let f = rng.random_range(2.0..6.0);
            p.inertia_kgm2 *= f;
            (format!("x{f:.2}"), named(&["joint.inertia_kgm2"]))
        }
        "supply_low" => {
            let f = rng.random_range(0.7..0.85);
            p.supply_gauge_pa *= f;
            (format!("x{f:.3}"), named(&["environment.supply_gauge_pa"]))
        }
        other => panic!("unknown case kind {other}"),
    };
    let train = closed_loop(&p, dt_s, 10.0, &mut rng, false, noise, force_channels);
    let check = closed_loop(&p, dt_s, 8.0, &mut rng, true, noise, force_channels);
    let (train, check) = if kind == "pure_noise" {
        (noise_only(&train, &mut rng), noise_only(&check, &mut rng))
    } else {
        (train, check)
    };
    Case {
        kind,
        seed,
        dt_s,
        force_channels,
        sizes,
        expected,
        train,
        check,
    }
}

/// The same inputs with every channel replaced by noise of the channel's own spread (a
/// recording of nothing this plant does).
fn noise_only(rec: &Recording, rng: &mut StdRng) -> Recording {
    let mut r = rec.clone();
    for c in Channel::ALL {
        if let Some(y) = r.outputs[c.index()].as_mut() {
            let n = y.len() as f64;
            let mean = y.iter().sum::<f64>() / n;
            let sd = (y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n)
                .sqrt()
                .max(1.0);
            for v in y.iter_mut() {
                *v = mean + sd * rng.sample::<f64, _>(StandardNormal);
            }
        }
    }
    r
}
