//! Synthetic rig recordings for testing the diagnosis: the plant with a chosen effect switched
//! on at a realistic size, driven by one of two unlike excitations, with sensor noise and
//! encoder quantisation as RECORDING.md describes real data.

use rand::{rngs::StdRng, Rng, SeedableRng};
use rand_distr::StandardNormal;

use crate::io::recording::{Channel, Recording};
use crate::plant::config::{ConfigError, PlantConfig};
use crate::plant::effects::{truths, Truth};
use crate::plant::{Plant, ValveInputs};
use crate::sim::{simulate, SimError, SolverOptions};

/// Valve excitation of a synthetic run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Excitation {
    /// PRBS-like antagonistic valve pulses of random length and opening (training style).
    Pulses,
    /// A chirp of PWM-like duties (0.2 to 3 Hz) with superposed steps (check style).
    ChirpSteps,
}

/// Encoder resolution (counts per turn) of the synthetic angle channel.
pub const ENCODER_COUNTS: f64 = 8000.0;
/// Pressure noise (kPa, 1 sigma).
pub const PRESSURE_NOISE_KPA: f64 = 0.5;
/// Force noise (N, 1 sigma).
pub const FORCE_NOISE_N: f64 = 2.0;

/// Every effect the synthetic rig can conceal, from the effect registry
/// ([`crate::plant::effects::truths`]): the catalogue's ids plus forms that differ from the
/// candidate's (`joint_friction_stribeck`, `supply_drop_reservoir`).
pub fn truth_names() -> Vec<&'static str> {
    truths().iter().map(|t| t.name).collect()
}

fn truth(name: &str) -> Option<Truth> {
    truths().into_iter().find(|t| t.name == name)
}

/// The catalogue id a truth should be named as (the name itself when it is not a truth).
pub fn expected_id(truth_name: &str) -> &str {
    match truth(truth_name) {
        Some(t) => t.expected_id,
        None => truth_name,
    }
}

/// TOML of a concealed effect at a realistic size (`inertia` becomes a `[joint]` override,
/// see [`plant_with`]). `None` for an unknown name.
pub fn effect_toml(truth_name: &str, dt_s: f64) -> Option<String> {
    truth(truth_name).map(|t| (t.toml)(dt_s))
}

/// The nominal plant text with concealed effects (by truth name) added.
pub fn plant_with(nominal_toml: &str, truths: &[&str], dt_s: f64) -> Result<PlantConfig, String> {
    let mut text = nominal_toml.to_string();
    let mut effects = String::new();
    for name in truths {
        let t = truth(name).ok_or_else(|| format!("unknown effect `{name}`"))?;
        let e = (t.toml)(dt_s);
        if let Some(key) = t.replaces_key {
            // Override the key's line in place.
            let mut out = String::new();
            for line in text.lines() {
                if line.trim_start().starts_with(key) {
                    out += &e;
                } else {
                    out += line;
                    out.push('\n');
                }
            }
            text = out;
        } else {
            // Two sensor tables would collide only for sensor_offset twice; truths are distinct.
            effects += &e;
        }
    }
    text.push('\n');
    text += &effects;
    PlantConfig::from_toml_str(&text, "synthetic.toml").map_err(|e: ConfigError| e.to_string())
}

/// Valve inputs of `n` samples of `dt_s`.
pub fn excitation(kind: Excitation, n: usize, dt_s: f64, seed: u64) -> Vec<ValveInputs> {
    let mut rng = StdRng::seed_from_u64(seed);
    let mut u = Vec::with_capacity(n);
    match kind {
        Excitation::Pulses => {
            while u.len() < n {
                let len_s: f64 = rng.random_range(0.03..0.3);
                let len = ((len_s / dt_s).round() as usize).max(1);
                let a: f64 = if rng.random_bool(0.6) {
                    1.0
                } else {
                    rng.random_range(0.3..1.0)
                };
                let mode = rng.random_range(0..6);
                let v = match mode {
                    0 | 1 => ValveInputs {
                        u_in1: a,
                        u_ex1: 0.0,
                        u_in2: 0.0,
                        u_ex2: a,
                    },
                    2 | 3 => ValveInputs {
                        u_in1: 0.0,
                        u_ex1: a,
                        u_in2: a,
                        u_ex2: 0.0,
                    },
                    4 => ValveInputs::CLOSED,
                    _ => ValveInputs {
                        u_in1: a,
                        u_ex1: 0.0,
                        u_in2: a,
                        u_ex2: 0.0,
                    },
                };
                u.extend(std::iter::repeat_n(v, len));
            }
        }
        Excitation::ChirpSteps => {
            // Duties held for 10 ms (a PWM period) and quantised to 5 %.
            let hold = ((0.01 / dt_s).round() as usize).max(1);
            let duration = n as f64 * dt_s;
            let step_every = 1.5;
            let mut level = 0.0;
            let mut next_step = step_every;
            let mut k = 0;
            while k < n {
                let t = k as f64 * dt_s;
                if t >= next_step {
                    level = rng.random_range(-0.4..0.4);
                    next_step += step_every;
                }
                let f0: f64 = 0.2;
                let f1: f64 = 3.0;
                let phase =
                    2.0 * std::f64::consts::PI * (f0 * t + (f1 - f0) * t * t / (2.0 * duration));
                let s: f64 = (0.6 * phase.sin() + level).clamp(-1.0, 1.0);
                let d = (s.abs() * 20.0).round() / 20.0;
                let v = if s >= 0.0 {
                    ValveInputs {
                        u_in1: d,
                        u_ex1: 0.0,
                        u_in2: 0.0,
                        u_ex2: d,
                    }
                } else {
                    ValveInputs {
                        u_in1: 0.0,
                        u_ex1: d,
                        u_in2: d,
                        u_ex2: 0.0,
                    }
                };
                u.extend(std::iter::repeat_n(v, hold));
                k += hold;
            }
        }
    }
    u.truncate(n);
    u
}

/// What to generate.
#[derive(Debug, Clone)]
pub struct SynthSpec {
    pub excitation: Excitation,
    pub duration_s: f64,
    pub dt_s: f64,
    pub seed: u64,
    /// Add sensor noise and quantisation.
    pub noise: bool,
    /// Which channels the recording has.
    pub channels: [bool; 5],
}

impl Default for SynthSpec {
    fn default() -> Self {
        Self {
            excitation: Excitation::Pulses,
            duration_s: 10.0,
            dt_s: 1e-3,
            seed: 1,
            noise: true,
            channels: [true; 5],
        }
    }
}

/// A recording of the plant `cfg` under `spec`.
pub fn generate(cfg: &PlantConfig, spec: &SynthSpec, label: &str) -> Result<Recording, SimError> {
    let n = (spec.duration_s / spec.dt_s).round() as usize;
    let inputs = excitation(spec.excitation, n, spec.dt_s, spec.seed);
    let plant = Plant::from_config(cfg);
    let sim = simulate(&plant, &inputs, spec.dt_s, &SolverOptions::default())?;
    let meas = plant.measure_series(&sim.states, spec.dt_s);
    let mut rng = StdRng::seed_from_u64(spec.seed ^ 0x05ee_d0f0_015e);
    let mut rec = Recording {
        metadata: vec![
            ("sample_period_s".into(), format!("{}", spec.dt_s)),
            (
                "source".into(),
                format!(
                    "host-sim diagnose::synth truth={label} excitation={:?} seed={} noise={}",
                    spec.excitation, spec.seed, spec.noise
                ),
            ),
        ],
        t_s: (0..n).map(|k| k as f64 * spec.dt_s).collect(),
        inputs,
        ..Default::default()
    };
    let q = 360.0 / ENCODER_COUNTS;
    for c in Channel::ALL {
        if !spec.channels[c.index()] {
            continue;
        }
        let v: Vec<f64> = meas
            .iter()
            .map(|m| {
                let x = c.of(m);
                if !spec.noise {
                    return x;
                }
                let g: f64 = rng.sample(StandardNormal);
                match c {
                    Channel::AngleDeg => (x / q).round() * q,
                    Channel::P1Kpa | Channel::P2Kpa => x + PRESSURE_NOISE_KPA * g,
                    Channel::F1N | Channel::F2N => x + FORCE_NOISE_N * g,
                }
            })
            .collect();
        rec.set_channel(c, v);
    }
    Ok(rec)
}
