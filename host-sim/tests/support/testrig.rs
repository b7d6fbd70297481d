//! An independent test rig for the diagnosis: recordings from a plant written again here,
//! NOT through `host_sim::plant`, `host_sim::sim` or the candidates' effect code, with effect
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
//!
//! The evidence base ([`CASES`], [`evidence_case`]): a machine-readable table of cases, each
//! with its category (a catalogue effect in another functional form, a mis-set plant key,
//! nominal data, an out-of-catalogue form), the catalogue slot it tests and the answer it
//! expects. The forms are written here: LuGre and Dahl friction, Bouc-Wen muscle hysteresis,
//! orifice and laminar leaks, direction-dependent polytropic exponents, flow-dependent wall
//! heat transfer, a quadratic calibration error, second-order sensor lags, a valve dead time
//! with an opening ramp, a gravity load that brings its own inertia, a supply behind a
//! reservoir and a line, large inertia factors; and outside the catalogue velocity-squared
//! damping, a hardening spring, a quadratic transducer, a stretching cable, backlash, end
//! stops, an eccentric sprocket, a valve dead zone, valve columns logged late; mis-set keys
//! of the whole plant, of one valve (one weak valve) or of one muscle (its own geometry). Recordings: closed-loop or open-loop excitation (CHECK always another signal, from
//! its own seed), with or without force channels, uniform, jittered (+-20 % of the period)
//! or gappy (dropped rows) time bases.

use rand::{rngs::StdRng, Rng, SeedableRng};
use rand_distr::StandardNormal;

use host_sim::io::recording::{Channel, Recording};
use host_sim::plant::config::PlantConfig;
use host_sim::plant::ValveInputs;

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
    /// The evidence-base forms below (all off in [`RigPhysics::from_config`]).
    pub forms: Forms,
}

/// Effect forms of the evidence base ([`CASES`]): each unlike the catalogue candidate of its
/// slot, or of no candidate at all. All `None` (or neutral) by default.
#[derive(Debug, Clone)]
pub struct Forms {
    /// LuGre friction with a bristle state: (sigma0 N m/rad, sigma1 N m s/rad, viscous
    /// sigma2 N m s/rad, Coulomb N m, static N m, Stribeck velocity rad/s).
    pub lugre: Option<[f64; 6]>,
    /// Dahl friction (the friction torque is a state): (stiffness N m/rad, Coulomb N m).
    pub dahl: Option<[f64; 2]>,
    /// Bouc-Wen hysteresis inside each muscle (a state per muscle, driven by its contraction
    /// rate): (force amplitude N, yield contraction).
    pub bouc_wen: Option<[f64; 2]>,
    /// Incompressible-orifice leak q = c sqrt(p - p_atm) (standard m^3/s per sqrt(Pa)), from
    /// one muscle (0, 1) or both (`None`).
    pub leak_sqrt: Option<(Option<usize>, f64)>,
    /// Laminar leak q = c (p - p_atm) from one muscle (m^3/(s Pa)).
    pub leak_laminar: Option<(usize, f64)>,
    /// Polytropic exponents that depend on the direction of the process: (filling,
    /// exhausting) instead of one constant exponent.
    pub poly_two: Option<[f64; 2]>,
    /// Forced convection: the wall heat transfer of the thermal chamber grows with the
    /// chamber's mass flow, hA = hA0 + k |m_dot| (k in J/(K kg)).
    pub forced_convection_j_per_k_kg: f64,
    /// A calibration error of one channel: reported = x + o + g x + a x^2 (channel units).
    pub calibration: Option<(Channel, [f64; 3])>,
    /// A second-order sensor lag (natural frequency rad/s, damping ratio) on the angle
    /// (`false`) or both pressures (`true`).
    pub lag2: Option<(bool, [f64; 2])>,
    /// Opening ramp of every valve after its dead time (opening per second; closing is
    /// immediate).
    pub valve_ramp_per_s: Option<f64>,
    /// Commands below this opening do not open a valve (a poppet that needs a minimum duty).
    pub valve_dead_zone: f64,
    /// Conductance factor of each valve (inlet 1, exhaust 1, inlet 2, exhaust 2).
    pub valve_factor: [f64; 4],
    /// Factors on one muscle's own geometry, per muscle: rest length, radius, braid angle,
    /// end factor, initial contraction (indices [`M_REST`] .. [`M_CHI0`]); all 1 by default.
    pub muscle_factor: [[f64; 5]; 2],
    /// A supply line between the reservoir and the valves: (line volume m^3, laminar line
    /// conductance m^3/(s Pa)); needs the reservoir.
    pub supply_line: Option<[f64; 2]>,
    /// A gravity load with its own inertia: (mass kg, lever m, hanging angle rad).
    pub gravity: Option<[f64; 3]>,
    /// Velocity-squared damping of the joint, T = -c omega |omega| (N m s^2/rad^2).
    pub velocity_squared_nms2: f64,
    /// A hardening spring on the joint, T = -k3 beta^3 (N m/rad^3).
    pub cubic_spring_nm_per_rad3: f64,
    /// End stops: (limit rad, stiffness N m/rad, damping N m s/rad in contact).
    pub end_stops: Option<[f64; 3]>,
    /// Backlash between sprocket and joint: (half band rad, chain stiffness N m/rad, chain
    /// damping N m s/rad when engaged, sprocket inertia kg m^2); two more states.
    pub backlash: Option<[f64; 4]>,
    /// A stretching cable between each muscle and the sprocket (Kelvin-Voigt, massless
    /// end): (stiffness N/m, damping N s/m); one more state per muscle.
    pub cable: Option<[f64; 2]>,
    /// An eccentric sprocket: lever r (1 + e sin beta).
    pub eccentric: Option<f64>,
}

impl Default for Forms {
    fn default() -> Self {
        Self {
            lugre: None,
            dahl: None,
            bouc_wen: None,
            leak_sqrt: None,
            leak_laminar: None,
            poly_two: None,
            forced_convection_j_per_k_kg: 0.0,
            calibration: None,
            lag2: None,
            valve_ramp_per_s: None,
            valve_dead_zone: 0.0,
            valve_factor: [1.0; 4],
            muscle_factor: [[1.0; 5]; 2],
            supply_line: None,
            gravity: None,
            velocity_squared_nms2: 0.0,
            cubic_spring_nm_per_rad3: 0.0,
            end_stops: None,
            backlash: None,
            cable: None,
            eccentric: None,
        }
    }
}

/// Indices of [`Forms::muscle_factor`].
pub const M_REST: usize = 0;
pub const M_RADIUS: usize = 1;
pub const M_BRAID: usize = 2;
pub const M_END: usize = 3;
pub const M_CHI0: usize = 4;

/// Size of the rig's state: beta, omega, p1, p2, T1, T2, tank pressure, friction state,
/// Bouc-Wen states (2), supply-line pressure, cable stretches (2), sprocket angle and rate.
const NX: usize = 15;

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
            forms: Forms::default(),
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

    /// Tension of muscle `i` (Tondu with the pressure-proportional damper), with its own
    /// geometry factors.
    fn tension(&self, i: usize, p_gauge: f64, chi: f64, dchi: f64) -> f64 {
        let mf = &self.forms.muscle_factor[i];
        let a0 = (self.braid_angle_deg * mf[M_BRAID]).to_radians();
        let radius = self.radius_m * mf[M_RADIUS];
        let area = std::f64::consts::PI * radius * radius;
        let e = 1.0 - self.end_factor * mf[M_END] * chi;
        let f_static =
            (area * p_gauge * (3.0 / a0.tan().powi(2) * e * e - 1.0 / a0.sin().powi(2))).max(0.0);
        (f_static - self.damping_m2s * p_gauge * dchi).max(0.0)
    }

    /// The angle and rate the muscles' sprocket turns with (the joint's, or behind a
    /// backlash the sprocket's own states).
    fn sprocket(&self, x: &[f64; NX]) -> (f64, f64) {
        if self.forms.backlash.is_some() {
            (x[13], x[14])
        } else {
            (x[0], x[1])
        }
    }

    /// Contractions, their rates driven by the sprocket, and the lever of the sprocket.
    fn kinematics(&self, x: &[f64; NX]) -> ([f64; 2], [f64; 2], f64) {
        let (theta, omega) = self.sprocket(x);
        let l = self.rest_length_m;
        let mf = &self.forms.muscle_factor;
        let (mut chi, dchi, lever) = match self.forms.eccentric {
            None => {
                // Each muscle's own rest length and initial contraction.
                let g = [0, 1].map(|i| self.sprocket_radius_m / (l * mf[i][M_REST]));
                let chi0 = [0, 1].map(|i| self.initial_contraction * mf[i][M_CHI0]);
                (
                    [chi0[0] + g[0] * theta, chi0[1] - g[1] * theta],
                    [g[0] * omega, -g[1] * omega],
                    self.sprocket_radius_m,
                )
            }
            Some(e) => {
                let r = self.sprocket_radius_m;
                let d = r * (theta + e * (1.0 - theta.cos()));
                let lever = r * (1.0 + e * theta.sin());
                (
                    [
                        self.initial_contraction + d / l,
                        self.initial_contraction - d / l,
                    ],
                    [lever * omega / l, -lever * omega / l],
                    lever,
                )
            }
        };
        if self.forms.cable.is_some() {
            for (i, c) in chi.iter_mut().enumerate() {
                *c += x[11 + i] / l;
            }
        }
        (chi, dchi, lever)
    }

    /// The tension of each muscle in state `x`.
    fn muscle_forces(&self, x: &[f64; NX], chi: &[f64; 2], dchi: &[f64; 2]) -> [f64; 2] {
        std::array::from_fn(|i| {
            let f = self.tension(i, x[2 + i] - self.p_atm_pa, chi[i], dchi[i]);
            match self.forms.bouc_wen {
                Some([amp, _]) => (f - amp * x[8 + i]).max(0.0),
                None => f,
            }
        })
    }

    /// State: see [`NX`].
    fn rhs(&self, x: &[f64; NX], u: &ValveInputs) -> [f64; NX] {
        let (beta, omega) = (x[0], x[1]);
        let fm = &self.forms;
        let (chi, dchi, lever) = self.kinematics(x);
        let f = self.muscle_forces(x, &chi, &dchi);
        let mut dx = [0.0; NX];
        // Volume rates follow the muscle's own contraction (with a cable: plus its stretch).
        let mut dchi_vol = dchi;
        if let Some([k, c]) = fm.cable {
            for i in 0..2 {
                let ds = (f[i] - k * x[11 + i]) / c;
                dx[11 + i] = ds;
                dchi_vol[i] += ds / self.rest_length_m;
            }
        }
        if let Some([_, yield_chi]) = fm.bouc_wen {
            for i in 0..2 {
                let z = x[8 + i];
                let v = dchi[i];
                let dir = if v * z >= 0.0 { 1.0 } else { 0.0 };
                dx[8 + i] = v / yield_chi * (1.0 - z * z * dir);
            }
        }
        let p_supply = if fm.supply_line.is_some() {
            x[10]
        } else if self.reservoir.is_some() {
            x[6]
        } else {
            self.supply_gauge_pa + self.p_atm_pa
        };
        let u_in = [u.u_in1, u.u_in2];
        let u_ex = [u.u_ex1, u.u_ex2];
        let mut q_supply = 0.0;
        for i in 0..2 {
            let p = x[2 + i];
            let (v, dv_dchi) = self.volume(chi[i]);
            let dv = dv_dchi * dchi_vol[i];
            let c_in = self.conductance_m3_per_s_pa * fm.valve_factor[2 * i];
            let c_ex = self.conductance_m3_per_s_pa * fm.valve_factor[2 * i + 1];
            // Signed flow parts (ANR m^3/s, + into the chamber).
            let q_in = u_in[i] * self.iso_flow(c_in, p_supply, p);
            let q_ex = -u_ex[i] * self.iso_flow(c_ex, p, self.p_atm_pa);
            let mut q_leak = match self.leak {
                Some((m, c)) if m == i && p > self.p_atm_pa => {
                    // Choked orifice form: sonic below the critical ratio, else subsonic.
                    -self.iso_flow(c, p, self.p_atm_pa)
                }
                _ => 0.0,
            };
            if let Some((m, c)) = fm.leak_sqrt {
                if m.is_none() || m == Some(i) {
                    q_leak -= c * (p - self.p_atm_pa).max(0.0).sqrt();
                }
            }
            if let Some((m, c)) = fm.leak_laminar {
                if m == i {
                    q_leak -= c * (p - self.p_atm_pa).max(0.0);
                }
            }
            q_supply += q_in;
            match self.thermal {
                None => {
                    let num = self.p_atm_pa * (q_in + q_ex + q_leak) - p * dv;
                    dx[2 + i] = match fm.poly_two {
                        None => num / v,
                        Some([n_fill, n_exhaust]) => {
                            if num > 0.0 {
                                n_fill * num / v
                            } else {
                                n_exhaust * num / v
                            }
                        }
                    };
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
                    let ha = ha + fm.forced_convection_j_per_k_kg * mdot.abs();
                    let dp = (kappa * R_AIR * h - kappa * p * dv
                        + (kappa - 1.0) * ha * (T_WALL_K - t))
                        / v;
                    dx[2 + i] = dp;
                    dx[4 + i] = t / (p * v) * (dp * v + p * dv - R_AIR * t * mdot);
                }
            }
        }
        let t_muscles = (f[0] - f[1]) * lever;
        let mut torque = match fm.backlash {
            None => t_muscles,
            Some([band, k, c, j_sprocket]) => {
                let (theta, omega_s) = (x[13], x[14]);
                let d = theta - beta;
                let engaged = d.abs() > band;
                let t_chain = if engaged {
                    k * (d - band * d.signum()) + c * (omega_s - omega)
                } else {
                    0.0
                };
                dx[13] = omega_s;
                dx[14] = (t_muscles - t_chain) / j_sprocket;
                t_chain
            }
        };
        if let Some([fc, fs, vs, fv]) = self.stribeck {
            let level = fc + (fs - fc) * (-(omega / vs).powi(2)).exp();
            torque -= level * (omega / 0.01).tanh() + fv * omega;
        }
        if let Some([s0, s1, s2, fc, fs, vs]) = fm.lugre {
            let g = fc + (fs - fc) * (-(omega / vs).powi(2)).exp();
            let z = x[7];
            let dz = omega - s0 * omega.abs() * z / g;
            dx[7] = dz;
            torque -= s0 * z + s1 * dz + s2 * omega;
        }
        if let Some([stiffness, fc]) = fm.dahl {
            let tf = x[7];
            dx[7] = stiffness * omega * (1.0 - tf / fc * omega.signum());
            torque -= tf;
        }
        torque -= fm.velocity_squared_nms2 * omega * omega.abs();
        torque -= fm.cubic_spring_nm_per_rad3 * beta.powi(3);
        if let Some([limit, k, c]) = fm.end_stops {
            if beta.abs() > limit {
                torque -= k * (beta - limit * beta.signum()) + c * omega;
            }
        }
        let mut inertia = self.inertia_kgm2;
        if let Some([m, l, hang]) = fm.gravity {
            torque -= m * 9.80665 * l * (beta - hang).sin();
            inertia += m * l * l;
        }
        dx[0] = omega;
        dx[1] = torque / inertia;
        if let Some([tank, c_feed]) = self.reservoir {
            let q_feed = self.iso_flow(c_feed, self.supply_gauge_pa + self.p_atm_pa, x[6]);
            match fm.supply_line {
                None => dx[6] = self.p_atm_pa * (q_feed - q_supply) / tank,
                Some([v_line, c_line]) => {
                    let q_line = c_line * (x[6] - x[10]);
                    dx[6] = self.p_atm_pa * (q_feed - q_line) / tank;
                    dx[10] = self.p_atm_pa * (q_line - q_supply) / v_line;
                }
            }
        }
        dx
    }

    fn initial_state(&self) -> [f64; NX] {
        let i = self.initial;
        let p_s = self.supply_gauge_pa + self.p_atm_pa;
        let mut x = [0.0; NX];
        x[..7].copy_from_slice(&[i[0], i[1], i[2], i[3], T_WALL_K, T_WALL_K, p_s]);
        x[10] = p_s;
        x[13] = i[0];
        x[14] = i[1];
        if let Some([k, _]) = self.forms.cable {
            // The cable starts stretched by the muscle's force: F(chi(s)) = k s (the force
            // falls as the muscle contracts, so the root is unique); bisection.
            for m in 0..2 {
                let (mut lo, mut hi) = (0.0, 0.05);
                for _ in 0..60 {
                    let s = 0.5 * (lo + hi);
                    x[11 + m] = s;
                    let (chi, dchi, _) = self.kinematics(&x);
                    let f = self.muscle_forces(&x, &chi, &dchi)[m];
                    if f > k * s {
                        lo = s;
                    } else {
                        hi = s;
                    }
                }
                x[11 + m] = 0.5 * (lo + hi);
            }
        }
        x
    }

    /// The true channels of a state (angle deg, gauge kPa, N), with the sensors' offset and
    /// calibration errors (not their lags).
    fn channels(&self, x: &[f64; NX]) -> [f64; 5] {
        let (chi, dchi, _) = self.kinematics(x);
        let f = self.muscle_forces(x, &chi, &dchi);
        let mut y = [
            x[0].to_degrees(),
            (x[2] - self.p_atm_pa) / 1000.0,
            (x[3] - self.p_atm_pa) / 1000.0,
            f[0],
            f[1],
        ];
        if let Some((c, o)) = self.offset {
            y[c.index()] += o;
        }
        if let Some((c, [o, g, a])) = self.forms.calibration {
            let v = y[c.index()];
            y[c.index()] = v + o + g * v + a * v * v;
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
    x: [f64; NX],
    dt_s: f64,
    substeps: usize,
    history: Vec<ValveInputs>,
    /// Start times of the commands of [`Run::advance_by`] (its own time base).
    stamps: Vec<f64>,
    t_s: f64,
    /// The openings the valves hold now (after dead time, dead zone and ramp).
    opening: [f64; 4],
}

impl Run {
    fn new(p: &RigPhysics, dt_s: f64) -> Self {
        Self {
            x: p.initial_state(),
            dt_s,
            substeps: (dt_s / 1e-4).ceil().max(1.0) as usize,
            history: Vec::new(),
            stamps: Vec::new(),
            t_s: 0.0,
            opening: [0.0; 4],
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

    fn rk4(&mut self, p: &RigPhysics, ui: &ValveInputs, h: f64) {
        let f = |x: &[f64; NX]| p.rhs(x, ui);
        let add = |x: &[f64; NX], k: &[f64; NX], c: f64| -> [f64; NX] {
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
            self.rk4(p, &ui, h);
        }
    }

    /// The command in force at time `t` after the dead time, on [`Run::advance_by`]'s own
    /// time base, with the valves' dead zone.
    fn commanded_at(&self, p: &RigPhysics, t: f64) -> [f64; 4] {
        let td = t - p.dead_time_s;
        let k = self.stamps.partition_point(|&s| s <= td);
        if k == 0 {
            return [0.0; 4];
        }
        let u = self.history[k - 1];
        [u.u_in1, u.u_ex1, u.u_in2, u.u_ex2].map(
            |v| {
                if v < p.forms.valve_dead_zone {
                    0.0
                } else {
                    v
                }
            },
        )
    }

    /// Integrates `h_s` seconds with command `u` issued now (any step: jittered time bases).
    fn advance_by(&mut self, p: &RigPhysics, u: ValveInputs, h_s: f64) {
        self.history.push(u);
        self.stamps.push(self.t_s);
        let n = (h_s / 1e-4).ceil().max(1.0) as usize;
        let h = h_s / n as f64;
        for s in 0..n {
            let t = self.t_s + s as f64 * h;
            let target = self.commanded_at(p, t + 0.5 * h);
            for (o, tg) in self.opening.iter_mut().zip(target) {
                *o = match p.forms.valve_ramp_per_s {
                    Some(rate) if tg > *o => (*o + rate * h).min(tg),
                    _ => tg,
                };
            }
            let [u_in1, u_ex1, u_in2, u_ex2] = self.opening;
            let ui = ValveInputs {
                u_in1,
                u_ex1,
                u_in2,
                u_ex2,
            };
            self.rk4(p, &ui, h);
        }
        self.t_s += h_s;
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
        let u = position_command(r, &y, gain_per_deg);
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

/// The rig's position controller: the measured angle error (deg) times the gain opens one
/// muscle's inlet and the other's exhaust (a deadband of 2 % opening), and both inlets top
/// up while the mean pressure is below 250 kPa.
fn position_command(r_deg: f64, y: &[f64; 5], gain_per_deg: f64) -> ValveInputs {
    let e = r_deg - y[0];
    let m = (gain_per_deg * e).clamp(-1.0, 1.0);
    let m = if m.abs() < 0.02 { 0.0 } else { m };
    let mean_kpa = 0.5 * (y[1] + y[2]);
    let top = if mean_kpa < 250.0 { 0.3 } else { 0.0 };
    if m >= 0.0 {
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

// ---------------------------------------------------------------------------------------
// The evidence base: a machine-readable table of cases ([`CASES`]), each a form unlike the
// catalogue candidate of its slot, a mis-set plant key, nominal data on several time bases,
// or a form no candidate has; each with a TRAIN and a CHECK recording of another excitation
// and its own seed ([`evidence_case`]).
// ---------------------------------------------------------------------------------------

/// What a case of the evidence base is evidence of.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Category {
    /// A catalogue effect in a functional form unlike its candidate's (sensitivity).
    CatalogueForm,
    /// A plant-file key set wrong (honesty: the key is recalibrated).
    MisSetKey,
    /// Nominal physics, noise-free, noisy, jittered or gappy, or pure noise (honesty: nothing
    /// is named).
    Nominal,
    /// A form no candidate has, or a logging fault (honesty: `unexplained`, nothing named;
    /// later: discovery of the missing term).
    OutOfCatalogue,
}

impl Category {
    pub fn as_str(self) -> &'static str {
        match self {
            Category::CatalogueForm => "catalogue_form",
            Category::MisSetKey => "mis_set_key",
            Category::Nominal => "nominal",
            Category::OutOfCatalogue => "out_of_catalogue",
        }
    }

    /// Sensitivity cases (the rest are honesty cases).
    pub fn is_sensitivity(self) -> bool {
        self == Category::CatalogueForm
    }
}

/// The answer a case expects.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Expect {
    /// An answer whose first named item is one of these (effect ids or dotted keys; more
    /// than one where the diagnosis documents them as one answer).
    First(&'static [&'static str]),
    /// Verdict `nothing_missing`.
    NothingMissing,
    /// Nothing named, whatever the verdict (pure noise: `nothing_missing` or a refusal).
    NothingNamed,
    /// Verdict `unexplained` with nothing named.
    Unexplained,
    /// A truth of two parts: the first named item one of `.0`, and every item of `.1` named.
    FirstWith(&'static [&'static str], &'static [&'static str]),
    /// A logging fault named, not modelled: verdict `not_this_plant`, nothing named, and a
    /// hint naming the valve columns logged late with the shift that fixes them (within one
    /// sample of the case's).
    ValvesLoggedLate,
}

impl Expect {
    pub fn describe(self) -> String {
        match self {
            Expect::First(ids) => format!("first named: {}", ids.join(" or ")),
            Expect::NothingMissing => "nothing_missing".into(),
            Expect::NothingNamed => "nothing named".into(),
            Expect::Unexplained => "unexplained, nothing named".into(),
            Expect::ValvesLoggedLate => {
                "not_this_plant, the valves' lateness named with --shift-valves-ms".into()
            }
            Expect::FirstWith(first, with) => format!(
                "first named: {}; also named: {}",
                first.join(" or "),
                with.join(" and ")
            ),
        }
    }
}

/// TRAIN's input signal; CHECK gets another one ([`Excitation::check`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Excitation {
    /// Closed loop: a position controller with set-point steps every 0.4-1.2 s.
    ClosedSteps,
    /// Closed loop: sines plus half-size steps.
    ClosedSines,
    /// Open loop: valve-opening pulses of random length, size and direction (the inputs do
    /// not depend on the measurements).
    OpenPulses,
}

impl Excitation {
    pub fn as_str(self) -> &'static str {
        match self {
            Excitation::ClosedSteps => "closed_steps",
            Excitation::ClosedSines => "closed_sines",
            Excitation::OpenPulses => "open_pulses",
        }
    }

    /// The CHECK recording's excitation: another signal than TRAIN's.
    pub fn check(self) -> Excitation {
        match self {
            Excitation::ClosedSteps => Excitation::ClosedSines,
            Excitation::ClosedSines | Excitation::OpenPulses => Excitation::ClosedSteps,
        }
    }
}

/// The recording's time base.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimeBase {
    Uniform,
    /// Samples taken (and stamped) up to +-20 % of the period off the uniform grid.
    Jittered,
    /// Rows dropped from the log: gaps of 1-10 samples, at most 5 % of the rows.
    Gappy,
}

impl TimeBase {
    pub fn as_str(self) -> &'static str {
        match self {
            TimeBase::Uniform => "uniform",
            TimeBase::Jittered => "jittered",
            TimeBase::Gappy => "gappy",
        }
    }
}

/// Whether the recordings have force channels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Forces {
    Yes,
    /// Angle and pressures only.
    No,
    /// Drawn from the seed.
    Seeded,
}

/// One row of the evidence base.
#[derive(Debug, Clone, Copy)]
pub struct CaseSpec {
    pub name: &'static str,
    pub category: Category,
    /// The catalogue slot (effect module or plant key) it tests, or for out-of-catalogue
    /// forms the family of the missing term.
    pub slot: &'static str,
    /// What the form is, and what of the candidate's form it is unlike.
    pub form: &'static str,
    pub expect: Expect,
    pub excitation: Excitation,
    pub time_base: TimeBase,
    pub forces: Forces,
    /// The valve columns are logged this late against the sensor columns (s).
    pub valves_logged_late_s: f64,
    /// Member of the CI-sized subset.
    pub reduced: bool,
}

const fn spec(
    name: &'static str,
    category: Category,
    slot: &'static str,
    form: &'static str,
    expect: Expect,
) -> CaseSpec {
    CaseSpec {
        name,
        category,
        slot,
        form,
        expect,
        excitation: Excitation::ClosedSteps,
        time_base: TimeBase::Uniform,
        forces: Forces::Seeded,
        valves_logged_late_s: 0.0,
        reduced: false,
    }
}

impl CaseSpec {
    const fn excite(mut self, e: Excitation) -> Self {
        self.excitation = e;
        self
    }
    const fn time(mut self, t: TimeBase) -> Self {
        self.time_base = t;
        self
    }
    const fn forces(mut self, f: Forces) -> Self {
        self.forces = f;
        self
    }
    const fn late(mut self, s: f64) -> Self {
        self.valves_logged_late_s = s;
        self
    }
    const fn reduced(mut self) -> Self {
        self.reduced = true;
        self
    }

    /// One tab-separated line of the case table (see [`CASE_TABLE_HEADER`]).
    pub fn tsv(&self) -> String {
        format!(
            "{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}",
            self.name,
            self.category.as_str(),
            self.slot,
            self.expect.describe(),
            self.excitation.as_str(),
            self.time_base.as_str(),
            match self.forces {
                Forces::Yes => "yes",
                Forces::No => "no",
                Forces::Seeded => "seeded",
            },
            self.valves_logged_late_s,
            self.reduced,
            self.form
        )
    }
}

/// Columns of [`CaseSpec::tsv`].
pub const CASE_TABLE_HEADER: &str =
    "name\tcategory\tslot\texpect\texcitation\ttime_base\tforces\tvalves_logged_late_s\treduced\tform";

use Category::{CatalogueForm, MisSetKey, Nominal, OutOfCatalogue};

const FRICTION: &[&str] = &["joint_friction"];
/// Without force channels the diagnosis documents joint friction and muscle hysteresis as
/// one answer.
const FRICTION_NO_FORCES: &[&str] = &["joint_friction", "muscle_hysteresis"];
const CONDUCTANCE: &[&str] = &[
    "valve.sonic_conductance_m3_per_s_pa",
    "muscle.volume_poly_m3",
];
const INERTIA: &[&str] = &["joint.inertia_kgm2", "inertia"];
/// Keys the diagnosis documents as one group (`recalibrate::GROUPS`): the muscles'
/// operating contraction, and per muscle its force keys and its contraction keys.
const CONTRACTION: &[&str] = &[
    "muscle.end_factor",
    "joint.initial_contraction",
    "muscle.rest_length_m",
];
const M1_FORCE: &[&str] = &["muscle.m1.radius_m", "muscle.m1.braid_angle_deg"];
const M2_FORCE: &[&str] = &["muscle.m2.radius_m", "muscle.m2.braid_angle_deg"];
const M1_CONTRACTION: &[&str] = &[
    "muscle.m1.end_factor",
    "muscle.m1.initial_contraction",
    "muscle.m1.rest_length_m",
];
const M2_CONTRACTION: &[&str] = &[
    "muscle.m2.end_factor",
    "muscle.m2.initial_contraction",
    "muscle.m2.rest_length_m",
];
const CHAMBER_HEAT: &[&str] = &["polytropic", "heat_transfer"];

/// The evidence base. Every catalogue effect has at least one form unlike its candidate's;
/// every recalibrated key a mis-set case; at least eight forms are outside the catalogue.
pub const CASES: &[CaseSpec] = &[
    // --- catalogue effects, other functional forms --------------------------------------
    spec("friction_lugre", CatalogueForm, "joint_friction",
        "LuGre friction (bristle state, Stribeck level, pre-sliding stiffness); the candidate is memoryless Coulomb + viscous",
        Expect::First(FRICTION)).forces(Forces::Yes).reduced(),
    spec("friction_lugre_jittered", CatalogueForm, "joint_friction",
        "LuGre friction on a jittered time base (+-20 % of the period)",
        Expect::First(FRICTION)).forces(Forces::Yes).time(TimeBase::Jittered),
    spec("friction_dahl_open_loop", CatalogueForm, "joint_friction",
        "Dahl friction (the friction torque is a state that follows the angle); angle and pressures only, open loop",
        Expect::First(FRICTION_NO_FORCES)).forces(Forces::No).excite(Excitation::OpenPulses),
    spec("hysteresis_bouc_wen", CatalogueForm, "muscle_hysteresis",
        "Bouc-Wen hysteresis in each muscle (a state per muscle, constant amplitude); the candidate is a memoryless tanh of the contraction rate, pressure-proportional",
        Expect::First(&["muscle_hysteresis"])).forces(Forces::Yes),
    spec("hysteresis_bouc_wen_open_loop", CatalogueForm, "muscle_hysteresis",
        "Bouc-Wen muscle hysteresis under open-loop excitation",
        Expect::First(&["muscle_hysteresis"])).forces(Forces::Yes).excite(Excitation::OpenPulses),
    spec("leak_orifice_sqrt", CatalogueForm, "leakage",
        "incompressible-orifice leak q ~ sqrt(p - p_atm) from both muscles; the candidate is an ISO 6358 (choked, ~p) orifice",
        Expect::First(&["leakage"])).reduced(),
    spec("leak_laminar_muscle2", CatalogueForm, "leakage",
        "laminar leak q ~ (p - p_atm) from muscle 2 only, angle and pressures only, open loop",
        Expect::First(&["leakage_muscle2"])).forces(Forces::No).excite(Excitation::OpenPulses),
    spec("polytropic_two_exponents", CatalogueForm, "polytropic",
        "polytropic exponent that depends on the process direction (filling 1.3-1.4, exhausting 1.05-1.15); the candidate has one constant exponent",
        Expect::First(CHAMBER_HEAT)),
    spec("heat_forced_convection", CatalogueForm, "thermal_chamber",
        "thermal chamber whose wall heat transfer grows with the mass flow (hA0 + k |m_dot|); the candidate's hA is constant",
        Expect::First(CHAMBER_HEAT)).excite(Excitation::OpenPulses),
    spec("sensor_quadratic_calibration", CatalogueForm, "sensor",
        "p2 transducer with offset, gain and a quadratic term; the candidates are offset or gain alone",
        Expect::First(&["sensor_gain", "sensor_offset"])),
    spec("sensor_second_order_angle", CatalogueForm, "sensor_lag",
        "second-order (underdamped) lag on the angle sensor; the candidate is a first-order sampled low-pass",
        Expect::First(&["sensor_lag"])).reduced(),
    spec("sensor_second_order_pressures", CatalogueForm, "sensor_lag",
        "second-order lag on both pressure sensors, jittered time base",
        Expect::First(&["sensor_lag", "sensor_lag_p1", "sensor_lag_p2"])).time(TimeBase::Jittered),
    spec("valve_dead_time_ramp", CatalogueForm, "valve_dead_time",
        "valve dead time plus an opening ramp (slew-limited opening, immediate closing); the candidate is a pure delay",
        Expect::First(&["valve_delay"])).reduced(),
    spec("valve_dead_time_80ms", CatalogueForm, "valve_dead_time",
        "a valve dead time of 75-85 ms, longer than the 50 ms the lag search once stopped at",
        Expect::First(&["valve_delay"])),
    spec("valve_dead_time_ramp_open_loop", CatalogueForm, "valve_dead_time",
        "valve dead time plus opening ramp, angle and pressures only, open loop",
        Expect::First(&["valve_delay"])).forces(Forces::No).excite(Excitation::OpenPulses),
    spec("gravity_offset_load", CatalogueForm, "gravity",
        "gravity load hanging 20-40 deg off, whose mass also adds its inertia m l^2 (the candidate's point load adds none)",
        Expect::FirstWith(&["gravity", "joint.inertia_kgm2", "inertia"], &["gravity"])),
    spec("supply_reservoir_line", CatalogueForm, "supply_drop",
        "supply behind a reservoir AND a line (a laminar resistance into a line volume: a lag); the candidates are a static drop or a reservoir alone",
        Expect::First(&["supply_drop"])),
    spec("inertia_x4", CatalogueForm, "inertia",
        "inertia 4x the file's",
        Expect::First(INERTIA)),
    spec("inertia_x11_open_loop", CatalogueForm, "inertia",
        "inertia 11x the file's, open loop",
        Expect::First(INERTIA)).excite(Excitation::OpenPulses),
    spec("inertia_x4_gappy", CatalogueForm, "inertia",
        "inertia 4x the file's on a gappy time base (dropped rows)",
        Expect::First(INERTIA)).time(TimeBase::Gappy),
    // --- mis-set plant keys -------------------------------------------------------------
    spec("key_conductance", MisSetKey, "valve.sonic_conductance_m3_per_s_pa",
        "valve conductance 65-80 % of the file's", Expect::First(CONDUCTANCE)).reduced(),
    spec("key_radius", MisSetKey, "muscle.radius_m",
        "muscle radius 4-8 % above the file's", Expect::First(&["muscle.radius_m"])),
    spec("key_braid_angle", MisSetKey, "muscle.braid_angle_deg",
        "braid angle 2-4 % above the file's", Expect::First(&["muscle.braid_angle_deg"])),
    spec("key_volume", MisSetKey, "muscle.volume_poly_m3",
        "chamber volume 125-150 % of the file's", Expect::First(CONDUCTANCE)),
    spec("key_damping", MisSetKey, "muscle.damping_m2s",
        "muscle damping 4-8x the file's", Expect::First(&["muscle.damping_m2s"])),
    spec("key_inertia", MisSetKey, "joint.inertia_kgm2",
        "inertia 1.8-2.5x the file's", Expect::First(INERTIA)).reduced(),
    spec("key_supply", MisSetKey, "environment.supply_gauge_pa",
        "supply pressure 75-85 % of the file's, open loop",
        Expect::First(&["environment.supply_gauge_pa"])).excite(Excitation::OpenPulses),
    spec("key_rest_length", MisSetKey, "muscle.rest_length_m",
        "both muscles' rest length 6-10 % above the file's", Expect::First(CONTRACTION)),
    spec("key_initial_contraction", MisSetKey, "joint.initial_contraction",
        "both muscles' initial contraction 15-25 % below the file's", Expect::First(CONTRACTION)),
    spec("key_end_factor", MisSetKey, "muscle.end_factor",
        "both muscles' end factor 6-10 % above the file's", Expect::First(CONTRACTION)),
    spec("key_sprocket_radius", MisSetKey, "joint.sprocket_radius_m",
        "sprocket radius 6-10 % above the file's", Expect::First(&["joint.sprocket_radius_m"])),
    spec("key_critical_ratio", MisSetKey, "valve.critical_ratio",
        "all four valves' critical ratio 60-70 % of the file's, open loop",
        Expect::First(&["valve.critical_ratio"])).excite(Excitation::OpenPulses),
    spec("key_exhaust1", MisSetKey, "valve.exhaust1.sonic_conductance_m3_per_s_pa",
        "the exhaust valve of muscle 1 at 55-70 % of the file's conductance, the other three as the file's, open loop",
        Expect::First(&["valve.exhaust1.sonic_conductance_m3_per_s_pa"])).excite(Excitation::OpenPulses),
    spec("key_inlet2", MisSetKey, "valve.inlet2.sonic_conductance_m3_per_s_pa",
        "the inlet valve of muscle 2 at 55-70 % of the file's conductance, open loop",
        Expect::First(&["valve.inlet2.sonic_conductance_m3_per_s_pa"])).excite(Excitation::OpenPulses),
    spec("key_exhaust2", MisSetKey, "valve.exhaust2.sonic_conductance_m3_per_s_pa",
        "the exhaust valve of muscle 2 at 55-70 % of the file's conductance, open loop",
        Expect::First(&["valve.exhaust2.sonic_conductance_m3_per_s_pa"])).excite(Excitation::OpenPulses),
    spec("key_m1_radius", MisSetKey, "muscle.m1.radius_m",
        "muscle 1's radius 6-10 % above the file's (muscle 2 as the file's)", Expect::First(M1_FORCE)),
    spec("key_m2_radius", MisSetKey, "muscle.m2.radius_m",
        "muscle 2's radius 6-10 % above the file's", Expect::First(M2_FORCE)),
    spec("key_m1_braid_angle", MisSetKey, "muscle.m1.braid_angle_deg",
        "muscle 1's braid angle 3-5 % above the file's", Expect::First(M1_FORCE)),
    spec("key_m2_braid_angle", MisSetKey, "muscle.m2.braid_angle_deg",
        "muscle 2's braid angle 3-5 % above the file's", Expect::First(M2_FORCE)),
    spec("key_m1_end_factor", MisSetKey, "muscle.m1.end_factor",
        "muscle 1's end factor 6-10 % above the file's", Expect::First(M1_CONTRACTION)),
    spec("key_m2_end_factor", MisSetKey, "muscle.m2.end_factor",
        "muscle 2's end factor 6-10 % above the file's", Expect::First(M2_CONTRACTION)),
    spec("key_m1_rest_length", MisSetKey, "muscle.m1.rest_length_m",
        "muscle 1's rest length 8-12 % above the file's", Expect::First(M1_CONTRACTION)),
    spec("key_m2_rest_length", MisSetKey, "muscle.m2.rest_length_m",
        "muscle 2's rest length 8-12 % above the file's", Expect::First(M2_CONTRACTION)),
    spec("key_m1_initial_contraction", MisSetKey, "muscle.m1.initial_contraction",
        "muscle 1's initial contraction 15-25 % below the file's", Expect::First(M1_CONTRACTION)),
    spec("key_m2_initial_contraction", MisSetKey, "muscle.m2.initial_contraction",
        "muscle 2's initial contraction 15-25 % below the file's", Expect::First(M2_CONTRACTION)),
    // Out of the catalogue while the plant file had one [valve] table for all four valves;
    // a mis-set key of the inlet valve's own table since per-valve tables exist.
    spec("ooc_one_valve_weak", MisSetKey, "valve.inlet1.sonic_conductance_m3_per_s_pa",
        "the inlet valve of muscle 1 is 25 % weaker than the other three (the shared conductance key scales all four)",
        Expect::First(&["valve.inlet1.sonic_conductance_m3_per_s_pa"])),
    // --- nominal physics ----------------------------------------------------------------
    spec("nominal_noise_free", Nominal, "none", "nominal physics, no noise",
        Expect::NothingMissing).reduced(),
    spec("nominal", Nominal, "none", "nominal physics with sensor noise", Expect::NothingMissing),
    spec("nominal_jittered", Nominal, "none", "nominal physics, jittered time base",
        Expect::NothingMissing).time(TimeBase::Jittered).reduced(),
    spec("nominal_gappy", Nominal, "none", "nominal physics, gappy time base",
        Expect::NothingMissing).time(TimeBase::Gappy).reduced(),
    spec("nominal_open_loop", Nominal, "none", "nominal physics, open loop, angle and pressures only",
        Expect::NothingMissing).excite(Excitation::OpenPulses).forces(Forces::No),
    spec("pure_noise", Nominal, "none",
        "every channel replaced by noise of its own spread (nothing this plant does)",
        Expect::NothingNamed).reduced(),
    // --- out of the catalogue -----------------------------------------------------------
    spec("ooc_velocity_squared_damping", OutOfCatalogue, "joint_damping",
        "velocity-squared (aerodynamic) damping of the joint, -c omega |omega|",
        Expect::Unexplained).reduced(),
    spec("ooc_cubic_spring", OutOfCatalogue, "joint_spring",
        "a position-dependent (hardening) spring on the joint, -k3 beta^3",
        Expect::Unexplained),
    spec("ooc_quadratic_transducer", OutOfCatalogue, "pressure_sensor",
        "p1 transducer reading a (x^2 - x x_ref) off: right at 0 and at x_ref, curved between",
        Expect::Unexplained),
    spec("ooc_cable_compliance", OutOfCatalogue, "transmission",
        "a cable between each muscle and the sprocket that stretches under the muscle force (Kelvin-Voigt, an extra state per muscle)",
        Expect::Unexplained).forces(Forces::Yes).reduced(),
    spec("ooc_backlash", OutOfCatalogue, "transmission",
        "a dead band in the joint: backlash of 0.5-1 deg between sprocket and joint (sprocket angle and rate as extra states)",
        Expect::Unexplained),
    spec("ooc_end_stops", OutOfCatalogue, "joint_limit",
        "a saturation: stiff end stops at +-15-20 deg",
        Expect::Unexplained),
    spec("ooc_eccentric_sprocket", OutOfCatalogue, "transmission",
        "an eccentric sprocket: lever r (1 + e sin beta)",
        Expect::Unexplained),
    spec("ooc_valve_dead_zone", OutOfCatalogue, "valve",
        "valve commands below 15-25 % opening do not open the valve",
        Expect::Unexplained),
    spec("valves_logged_late", Nominal, "logging",
        "nominal plant, valve columns logged 50 ms late against the sensor columns (a negative valve delay)",
        Expect::ValvesLoggedLate).late(0.05),
];

/// The case of the evidence base named `name`.
pub fn case_spec(name: &str) -> Option<&'static CaseSpec> {
    CASES.iter().find(|c| c.name == name)
}

/// One generated case of the evidence base.
pub struct EvidenceCase {
    pub spec: &'static CaseSpec,
    pub seed: u64,
    /// The seed of the CHECK recording (its controller draws and noise).
    pub check_seed: u64,
    pub dt_s: f64,
    pub force_channels: bool,
    /// The drawn sizes, for the report.
    pub sizes: String,
    pub train: Recording,
    pub check: Recording,
}

/// FNV-1a of a case name: each case draws from its own stream.
fn name_hash(name: &str) -> u64 {
    name.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    })
}

fn sign(rng: &mut StdRng) -> f64 {
    if rng.random_bool(0.5) {
        1.0
    } else {
        -1.0
    }
}

/// Puts the form of case `name` into `p`; returns the drawn sizes.
fn apply_form(name: &str, p: &mut RigPhysics, rng: &mut StdRng) -> String {
    let f = &mut p.forms;
    match name {
        "friction_lugre" | "friction_lugre_jittered" => {
            let fc = rng.random_range(0.2..0.4);
            let fs = fc * rng.random_range(1.4..2.0);
            let vs = rng.random_range(0.05..0.3);
            let s0 = rng.random_range(300.0..800.0);
            let s1 = (s0 * p.inertia_kgm2).sqrt();
            let s2 = rng.random_range(0.02..0.06);
            f.lugre = Some([s0, s1, s2, fc, fs, vs]);
            format!("sigma0 {s0:.0} N m/rad, Coulomb {fc:.3} N m, static {fs:.3} N m, vs {vs:.2} rad/s, viscous {s2:.3}")
        }
        "friction_dahl_open_loop" => {
            let fc = rng.random_range(0.25..0.45);
            let k = rng.random_range(30.0..120.0);
            f.dahl = Some([k, fc]);
            format!("stiffness {k:.0} N m/rad, Coulomb {fc:.3} N m")
        }
        "hysteresis_bouc_wen" | "hysteresis_bouc_wen_open_loop" => {
            let amp = rng.random_range(6.0..12.0);
            let y = rng.random_range(0.002..0.005);
            f.bouc_wen = Some([amp, y]);
            format!("amplitude {amp:.1} N, yield contraction {y:.4}")
        }
        "leak_orifice_sqrt" => {
            let c = rng.random_range(2.5e-7..5e-7);
            f.leak_sqrt = Some((None, c));
            format!("both muscles, c {c:.2e} m^3/(s sqrt(Pa))")
        }
        "leak_laminar_muscle2" => {
            let c = rng.random_range(3e-10..6e-10);
            f.leak_laminar = Some((1, c));
            format!("muscle 2, c {c:.2e} m^3/(s Pa)")
        }
        "polytropic_two_exponents" => {
            let nf = rng.random_range(1.3..1.4);
            let ne = rng.random_range(1.05..1.15);
            f.poly_two = Some([nf, ne]);
            format!("filling n {nf:.3}, exhausting n {ne:.3}")
        }
        "heat_forced_convection" => {
            let ha0 = rng.random_range(0.3..1.0);
            let k = rng.random_range(300.0..1000.0);
            p.thermal = Some([ha0, 1.4]);
            p.forms.forced_convection_j_per_k_kg = k;
            format!("hA0 {ha0:.2} W/K + {k:.0} J/(K kg) |m_dot|")
        }
        "sensor_quadratic_calibration" => {
            let o = rng.random_range(4.0..8.0) * sign(rng);
            let g = rng.random_range(0.03..0.06) * sign(rng);
            let a = rng.random_range(2e-5..5e-5) * sign(rng);
            f.calibration = Some((Channel::P2Kpa, [o, g, a]));
            format!("p2: {o:+.2} kPa {g:+.3} x {a:+.2e} x^2")
        }
        "sensor_second_order_angle" | "sensor_second_order_pressures" => {
            let fn_hz = rng.random_range(6.0..12.0);
            let zeta = rng.random_range(0.4..0.7);
            let pressures = name.ends_with("pressures");
            f.lag2 = Some((pressures, [2.0 * std::f64::consts::PI * fn_hz, zeta]));
            format!(
                "{}: {fn_hz:.1} Hz, damping ratio {zeta:.2}",
                if pressures { "pressures" } else { "angle" }
            )
        }
        "valve_dead_time_ramp" | "valve_dead_time_ramp_open_loop" => {
            let d = rng.random_range(4e-3..10e-3);
            let ramp_s = rng.random_range(4e-3..10e-3);
            p.dead_time_s = d;
            p.forms.valve_ramp_per_s = Some(1.0 / ramp_s);
            format!(
                "dead time {:.2} ms, opening ramp {:.2} ms",
                d * 1e3,
                ramp_s * 1e3
            )
        }
        "valve_dead_time_80ms" => {
            let d = rng.random_range(75e-3..85e-3);
            p.dead_time_s = d;
            format!("dead time {:.2} ms", d * 1e3)
        }
        "gravity_offset_load" => {
            let m = rng.random_range(0.3..0.6);
            let l = rng.random_range(0.1..0.15);
            let hang = rng.random_range(20f64..40.0).to_radians() * sign(rng);
            f.gravity = Some([m, l, hang]);
            format!(
                "{m:.2} kg at {l:.3} m hanging at {:+.1} deg (adds {:.4} kg m^2)",
                hang.to_degrees(),
                m * l * l
            )
        }
        "supply_reservoir_line" => {
            let tank = rng.random_range(3e-4..8e-4);
            let feed = rng.random_range(4e-9..8e-9);
            let v_line = rng.random_range(6e-5..1.5e-4);
            let c_line = rng.random_range(5e-8..9e-8);
            p.reservoir = Some([tank, feed]);
            p.forms.supply_line = Some([v_line, c_line]);
            format!(
                "tank {:.2} l, feed {feed:.2e}; line {:.0} ml, {c_line:.1e} m^3/(s Pa) (lag {:.1} ms)",
                tank * 1e3,
                v_line * 1e6,
                1e3 * v_line / (p.p_atm_pa * c_line)
            )
        }
        "inertia_x4" | "inertia_x4_gappy" => {
            p.inertia_kgm2 *= 4.0;
            "x4".into()
        }
        "inertia_x11_open_loop" => {
            p.inertia_kgm2 *= 11.0;
            "x11".into()
        }
        "key_conductance" => {
            let k = rng.random_range(0.65..0.8);
            p.conductance_m3_per_s_pa *= k;
            format!("x{k:.3}")
        }
        "key_radius" => {
            let k = rng.random_range(1.04..1.08);
            p.radius_m *= k;
            format!("x{k:.3}")
        }
        "key_braid_angle" => {
            let k = rng.random_range(1.02..1.04);
            p.braid_angle_deg *= k;
            format!("x{k:.3}")
        }
        "key_volume" => {
            let k = rng.random_range(1.25..1.5);
            for b in &mut p.volume_poly_m3 {
                *b *= k;
            }
            format!("x{k:.3}")
        }
        "key_damping" => {
            let k = rng.random_range(4.0..8.0);
            p.damping_m2s *= k;
            format!("x{k:.2}")
        }
        "key_inertia" => {
            let k = rng.random_range(1.8..2.5);
            p.inertia_kgm2 *= k;
            format!("x{k:.2}")
        }
        "key_supply" => {
            let k = rng.random_range(0.75..0.85);
            p.supply_gauge_pa *= k;
            format!("x{k:.3}")
        }
        "key_rest_length" => {
            let k = rng.random_range(1.06..1.10);
            p.rest_length_m *= k;
            format!("x{k:.3}")
        }
        "key_initial_contraction" => {
            let k = rng.random_range(0.75..0.85);
            p.initial_contraction *= k;
            format!("x{k:.3}")
        }
        "key_end_factor" => {
            let k = rng.random_range(1.06..1.10);
            p.end_factor *= k;
            format!("x{k:.3}")
        }
        "key_sprocket_radius" => {
            let k = rng.random_range(1.06..1.10);
            p.sprocket_radius_m *= k;
            format!("x{k:.3}")
        }
        "key_critical_ratio" => {
            let k = rng.random_range(0.6..0.7);
            p.critical_ratio *= k;
            format!("x{k:.3}")
        }
        "key_exhaust1" | "key_inlet2" | "key_exhaust2" => {
            let v = match name {
                "key_exhaust1" => 1,
                "key_inlet2" => 2,
                _ => 3,
            };
            let k = rng.random_range(0.55..0.7);
            f.valve_factor[v] = k;
            format!("valve {v} x{k:.3}")
        }
        "key_m1_radius"
        | "key_m2_radius"
        | "key_m1_braid_angle"
        | "key_m2_braid_angle"
        | "key_m1_end_factor"
        | "key_m2_end_factor"
        | "key_m1_rest_length"
        | "key_m2_rest_length"
        | "key_m1_initial_contraction"
        | "key_m2_initial_contraction" => {
            let m = usize::from(name.starts_with("key_m2"));
            let (field, k) = if name.ends_with("radius") {
                (M_RADIUS, rng.random_range(1.06..1.10))
            } else if name.ends_with("braid_angle") {
                (M_BRAID, rng.random_range(1.03..1.05))
            } else if name.ends_with("end_factor") {
                (M_END, rng.random_range(1.06..1.10))
            } else if name.ends_with("rest_length") {
                (M_REST, rng.random_range(1.08..1.12))
            } else {
                (M_CHI0, rng.random_range(0.75..0.85))
            };
            f.muscle_factor[m][field] = k;
            format!("muscle {} x{k:.3}", m + 1)
        }
        "nominal_noise_free" | "nominal" | "nominal_jittered" | "nominal_gappy"
        | "nominal_open_loop" | "pure_noise" | "valves_logged_late" => String::new(),
        "ooc_velocity_squared_damping" => {
            let c = rng.random_range(0.05..0.15);
            f.velocity_squared_nms2 = c;
            format!("c {c:.3} N m s^2/rad^2")
        }
        "ooc_cubic_spring" => {
            let k3 = rng.random_range(15.0..40.0);
            f.cubic_spring_nm_per_rad3 = k3;
            format!(
                "k3 {k3:.1} N m/rad^3 ({:.2} N m at 25 deg)",
                k3 * 25f64.to_radians().powi(3)
            )
        }
        "ooc_quadratic_transducer" => {
            let x_ref = rng.random_range(300.0..400.0);
            let dev_kpa = rng.random_range(6.0..12.0);
            let a = 4.0 * dev_kpa / (x_ref * x_ref) * sign(rng);
            f.calibration = Some((Channel::P1Kpa, [0.0, -a * x_ref, a]));
            format!(
                "p1: a {a:+.2e}/kPa, right at 0 and {x_ref:.0} kPa, {dev_kpa:.1} kPa off between"
            )
        }
        "ooc_cable_compliance" => {
            let k = rng.random_range(3e4..8e4);
            let tau = rng.random_range(2e-3..5e-3);
            f.cable = Some([k, k * tau]);
            format!("{:.0} N/mm, time constant {:.1} ms", k * 1e-3, tau * 1e3)
        }
        "ooc_backlash" => {
            let band = rng.random_range(0.25f64..0.5).to_radians();
            let k = rng.random_range(100.0..300.0);
            let j_s = 0.1 * p.inertia_kgm2;
            let c = 0.4 * (k * j_s).sqrt();
            f.backlash = Some([band, k, c, j_s]);
            format!("+-{:.2} deg, chain {k:.0} N m/rad", band.to_degrees())
        }
        "ooc_end_stops" => {
            let lim = rng.random_range(15f64..20.0).to_radians();
            let k = rng.random_range(20.0..40.0);
            f.end_stops = Some([lim, k, 0.3]);
            format!("+-{:.1} deg, {k:.0} N m/rad", lim.to_degrees())
        }
        "ooc_eccentric_sprocket" => {
            let e = rng.random_range(0.1..0.2) * sign(rng);
            f.eccentric = Some(e);
            format!("e {e:+.3}")
        }
        "ooc_valve_dead_zone" => {
            let z = rng.random_range(0.15..0.25);
            f.valve_dead_zone = z;
            format!("openings below {z:.2} stay shut")
        }
        "ooc_one_valve_weak" => {
            f.valve_factor[0] = 0.75;
            "inlet 1 at 0.75".into()
        }
        other => panic!("no form for case {other}"),
    }
}

/// Generates case `spec` from `seed` on the nominal plant `nominal`.
pub fn evidence_case(nominal: &PlantConfig, spec: &'static CaseSpec, seed: u64) -> EvidenceCase {
    let h = name_hash(spec.name);
    let mut rng = StdRng::seed_from_u64(seed ^ h);
    let check_seed = seed.wrapping_mul(0x2545_f491_4f6c_dd1d) ^ h.rotate_left(17) ^ 0xc4ec;
    let dt_s = [1e-3, 2e-3, 3e-3][rng.random_range(0..3)];
    let force_channels = match spec.forces {
        Forces::Yes => true,
        Forces::No => false,
        Forces::Seeded => rng.random_bool(0.5),
    };
    let mut p = RigPhysics::from_config(nominal);
    let sizes = apply_form(spec.name, &mut p, &mut rng);
    let noise = spec.name != "nominal_noise_free";
    let plan = |excitation, duration_s| Plan {
        excitation,
        duration_s,
        time_base: spec.time_base,
        noise,
        force_channels,
        valves_logged_late_s: spec.valves_logged_late_s,
    };
    let train = record(&p, dt_s, &plan(spec.excitation, 10.0), &mut rng);
    let mut check_rng = StdRng::seed_from_u64(check_seed);
    let check = record(
        &p,
        dt_s,
        &plan(spec.excitation.check(), 8.0),
        &mut check_rng,
    );
    let (train, check) = if spec.name == "pure_noise" {
        (
            noise_only(&train, &mut rng),
            noise_only(&check, &mut check_rng),
        )
    } else {
        (train, check)
    };
    EvidenceCase {
        spec,
        seed,
        check_seed,
        dt_s,
        force_channels,
        sizes,
        train,
        check,
    }
}

/// How one recording is made.
struct Plan {
    excitation: Excitation,
    duration_s: f64,
    time_base: TimeBase,
    noise: bool,
    force_channels: bool,
    valves_logged_late_s: f64,
}

/// A second-order sensor: y'' = wn^2 (x - y) - 2 zeta wn y', x linear between samples.
#[derive(Clone, Copy)]
struct Lag2 {
    y: f64,
    dy: f64,
    x: f64,
}

impl Lag2 {
    fn step(&mut self, x_new: f64, h: f64, wn: f64, zeta: f64) -> f64 {
        let n = ((h * wn / 0.05).ceil() as usize).max(4);
        let hh = h / n as f64;
        for s in 0..n {
            let x = self.x + (x_new - self.x) * (s as f64 + 0.5) / n as f64;
            // Semi-implicit Euler (stable for hh wn << 1).
            self.dy += hh * (wn * wn * (x - self.y) - 2.0 * zeta * wn * self.dy);
            self.y += hh * self.dy;
        }
        self.x = x_new;
        self.y
    }
}

/// Records one run of the rig: samples at the plan's time base, the controller (or the
/// open-loop signal) sets the valves from the measured channels, noise and quantisation as
/// in [`closed_loop`]; then the logging faults (valve columns late, dropped rows).
fn record(p: &RigPhysics, dt_s: f64, plan: &Plan, rng: &mut StdRng) -> Recording {
    let n = (plan.duration_s / dt_s).round() as usize;
    let stamps: Vec<f64> = (0..n)
        .map(|k| {
            let t = k as f64 * dt_s;
            if plan.time_base == TimeBase::Jittered && k > 0 {
                t + rng.random_range(-0.2..0.2) * dt_s
            } else {
                t
            }
        })
        .collect();
    let mut run = Run::new(p, dt_s);
    let mut lags: Option<(Vec<usize>, [f64; 2], Vec<Lag2>)> = p.forms.lag2.map(|(pr, wz)| {
        let chans = if pr { vec![1, 2] } else { vec![0] };
        let y0 = p.channels(&run.x);
        let st = chans
            .iter()
            .map(|&c| Lag2 {
                y: y0[c],
                dy: 0.0,
                x: y0[c],
            })
            .collect();
        (chans, wz, st)
    });
    let mut setpoint_deg = 0.0;
    let mut next_step_s = 0.0;
    let gain_per_deg = rng.random_range(0.08..0.2);
    let (w1, w2) = (rng.random_range(1.5..3.0), rng.random_range(4.0..7.0));
    let mut open = (ValveInputs::CLOSED, 0.0);
    let mut inputs = Vec::with_capacity(n);
    let mut out: [Vec<f64>; 5] = std::array::from_fn(|_| Vec::with_capacity(n));
    for k in 0..n {
        let t = stamps[k];
        let h = if k + 1 < n { stamps[k + 1] - t } else { dt_s };
        let mut y = p.channels(&run.x);
        if let Some((chans, [wn, zeta], st)) = lags.as_mut() {
            for (c, s) in chans.iter().zip(st.iter_mut()) {
                y[*c] = if k == 0 {
                    s.y
                } else {
                    s.step(y[*c], h, *wn, *zeta)
                };
            }
        }
        if plan.noise {
            let counts = ENCODER_COUNTS / 360.0;
            y[0] = (y[0] * counts).round() / counts;
            for v in &mut y[1..3] {
                *v += PRESSURE_NOISE_KPA * rng.sample::<f64, _>(StandardNormal);
            }
            for v in &mut y[3..5] {
                *v += FORCE_NOISE_N * rng.sample::<f64, _>(StandardNormal);
            }
        }
        let u = match plan.excitation {
            Excitation::OpenPulses => {
                if t >= open.1 {
                    let m: f64 = rng.random_range(-0.7..0.7);
                    let u = if rng.random_bool(0.2) {
                        // Both muscles together: fill or vent.
                        let a = rng.random_range(0.2..0.6);
                        if rng.random_bool(0.5) {
                            ValveInputs::from_openings([a, 0.0, a, 0.0])
                        } else {
                            ValveInputs::from_openings([0.0, a, 0.0, a])
                        }
                    } else {
                        ValveInputs::antagonistic(m)
                    };
                    open = (u, t + rng.random_range(0.08..0.4));
                }
                open.0
            }
            Excitation::ClosedSteps | Excitation::ClosedSines => {
                if t >= next_step_s {
                    setpoint_deg = rng.random_range(-25.0..25.0);
                    next_step_s = t + rng.random_range(0.4..1.2);
                }
                let r = if plan.excitation == Excitation::ClosedSines {
                    0.5 * setpoint_deg + 12.0 * (w1 * t).sin() + 5.0 * (w2 * t).sin()
                } else {
                    setpoint_deg
                };
                position_command(r, &y, gain_per_deg)
            }
        };
        inputs.push(u);
        for c in 0..5 {
            out[c].push(y[c]);
        }
        run.advance_by(p, u, h);
    }
    // Valve columns logged late: the row stamped t holds the command issued at t - late.
    let late = (plan.valves_logged_late_s / dt_s).round() as usize;
    if late > 0 {
        let issued = inputs.clone();
        for (k, u) in inputs.iter_mut().enumerate() {
            *u = if k >= late {
                issued[k - late]
            } else {
                ValveInputs::CLOSED
            };
        }
    }
    let mut keep = vec![true; n];
    if plan.time_base == TimeBase::Gappy {
        // Gaps of 1-10 rows, at most 5 % of the rows, none at the ends.
        let budget = n / 20;
        let mut dropped = 0;
        while dropped + 10 <= budget {
            let len = rng.random_range(1..=10);
            let at = rng.random_range(1..n - 11);
            if keep[at - 1..at + len + 1].iter().all(|&k| k) {
                keep[at..at + len].iter_mut().for_each(|k| *k = false);
                dropped += len;
            }
        }
    }
    let pick = |v: &[f64]| -> Vec<f64> {
        v.iter()
            .zip(&keep)
            .filter(|(_, &k)| k)
            .map(|(x, _)| *x)
            .collect()
    };
    let mut outputs: [Option<Vec<f64>>; 5] = std::array::from_fn(|c| Some(pick(&out[c])));
    if !plan.force_channels {
        outputs[3] = None;
        outputs[4] = None;
    }
    Recording {
        metadata: vec![
            ("sample_period_s".into(), format!("{dt_s}")),
            (
                "source".into(),
                format!(
                    "independent test rig (diagnose::testrig), {}, {} time base",
                    plan.excitation.as_str(),
                    plan.time_base.as_str()
                ),
            ),
        ],
        t_s: pick(&stamps),
        inputs: inputs
            .iter()
            .zip(&keep)
            .filter(|(_, &k)| k)
            .map(|(u, _)| *u)
            .collect(),
        outputs,
        mass_flow_kg_s: None,
    }
}
