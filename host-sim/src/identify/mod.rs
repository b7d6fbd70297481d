//! Identification of model parameters from data (issue "Identification").
//!
//! - [`force`]: the static force law (seed 002 eq. 6, and the Tondu baseline) from isometric data.
//! - [`force_maps`]: measured-style isometric force maps (slack, few points, noise) from an
//!   independent muscle law, to test the force-law fit against.
//! - [`torque`]: the simplified torque model (seed 003 eq. 11) from angle, pressures and tensions.
//! - [`plant`]: output-error fit of plant-file parameters by replaying a recording.
//! - [`volume`]: seed 004's hybrid model, the chamber volume as a network trained on the mass flow.
//! - [`cli`]: the `host-sim sweep` and `host-sim identify` commands.

pub mod cli;
pub mod force;
pub mod force_maps;
pub mod output_error;
pub mod plant;
pub mod torque;
pub mod volume;

use std::path::Path;

// The gates of identified values: below them, nothing reaches the firmware.

/// Lowest torque-model fit [%] (against the force-derived torque) from which constants are
/// written. The reference joint's sweep fits 98.96 %; 90 % leaves room for sensor noise and
/// refuses a recording eq. 11 does not describe.
pub const MIN_TORQUE_FIT_PCT: f64 = 90.0;
/// A joint angle whose standard deviation is below this did not move [deg].
pub const MIN_ANGLE_SD_DEG: f64 = 0.5;
/// A pressure whose standard deviation is below this was not activated [kPa].
pub const MIN_PRESSURE_SD_KPA: f64 = 5.0;
/// Least mean held-out fit of the identified plant (`--identify-plant`) for its values to
/// reach the firmware [%].
pub const MIN_IDENTIFIED_HELDOUT_FIT_PCT: f64 = 50.0;

/// Errors of the identification tools. File errors name the file, the line and the field.
#[derive(Debug, thiserror::Error)]
pub enum IdentError {
    /// A file could not be read or written.
    #[error("{file}: {msg}")]
    Io {
        /// The file.
        file: String,
        /// What went wrong.
        msg: String,
    },
    /// A bad value in an input file (a line of 0 or an empty field: not known, left out).
    #[error("{}", input_text(file, *line, field, msg))]
    Input {
        /// The file.
        file: String,
        /// 1-based line number.
        line: usize,
        /// Column or key.
        field: String,
        /// What is wrong.
        msg: String,
    },
    /// The data cannot support the fit.
    #[error("{0}")]
    Data(String),
}

/// `file:line: field `f`: msg`, without the line when it is 0 and the field when it is empty
/// (a TOML syntax error is at a line but in no field).
fn input_text(file: &str, line: usize, field: &str, msg: &str) -> String {
    let mut s = file.to_string();
    if line > 0 {
        s += &format!(":{line}");
    }
    if !field.is_empty() {
        s += &format!(": field `{field}`");
    }
    format!("{s}: {msg}")
}

impl IdentError {
    pub(crate) fn at(file: &str, line: usize, field: &str, msg: &str) -> Self {
        IdentError::Input {
            file: file.to_string(),
            line,
            field: field.to_string(),
            msg: msg.to_string(),
        }
    }
}

/// Appends the comment header of a firmware TOML written by `host-sim identify <command>`:
/// `lines` (each a whole `#` line), then where its data came from.
pub(crate) fn toml_header(
    s: &mut String,
    lines: &[&str],
    command: &str,
    source: &str,
    n_samples: usize,
) {
    for l in lines {
        s.push_str(l);
        s.push('\n');
    }
    s.push_str(&format!(
        "# Written by `host-sim identify {command}` from {source} ({n_samples} samples).\n"
    ));
}

/// Writes `bytes` to `path` atomically ([`crate::io::atomic`], the one atomic writer): a
/// failed or interrupted write never replaces a good file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), IdentError> {
    crate::io::atomic::write_bytes(path, bytes).map_err(|e| IdentError::Io {
        file: path.display().to_string(),
        msg: e.to_string(),
    })
}

/// Sensor imperfections added to a generated recording (RECORDING.md: an encoder of 8000
/// counts per turn, pressure noise of about 0.5 kPa, force noise of a few N).
#[derive(Clone, Debug, PartialEq)]
pub struct MeasurementNoise {
    /// Encoder counts per turn the angle is quantised to (0: no quantisation).
    pub encoder_counts_per_turn: u32,
    /// Pressure noise, standard deviation [Pa].
    pub pressure_noise_pa: f64,
    /// Force noise, standard deviation [N].
    pub force_noise_n: f64,
    /// Random seed.
    pub seed: u64,
}

impl Default for MeasurementNoise {
    fn default() -> Self {
        MeasurementNoise {
            encoder_counts_per_turn: 8000,
            pressure_noise_pa: 500.0,
            force_noise_n: 2.0,
            seed: 1,
        }
    }
}

impl MeasurementNoise {
    /// No noise at all.
    pub const NONE: MeasurementNoise = MeasurementNoise {
        encoder_counts_per_turn: 0,
        pressure_noise_pa: 0.0,
        force_noise_n: 0.0,
        seed: 0,
    };

    /// Adds the noise to the output channels present in `rec` (deterministic for a seed).
    pub fn apply(&self, rec: &mut crate::Recording) {
        use crate::io::recording::Channel;
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand::rngs::StdRng::seed_from_u64(self.seed);
        let p = Normal::new(0.0, self.pressure_noise_pa.max(0.0) / 1e3).expect("finite sd");
        let f = Normal::new(0.0, self.force_noise_n.max(0.0)).expect("finite sd");
        for c in Channel::ALL {
            let Some(v) = rec.outputs[c.index()].as_mut() else {
                continue;
            };
            match c {
                Channel::AngleDeg => {
                    if self.encoder_counts_per_turn > 0 {
                        let q = 360.0 / self.encoder_counts_per_turn as f64;
                        for x in v.iter_mut() {
                            *x = (*x / q).round() * q;
                        }
                    }
                }
                Channel::P1Kpa | Channel::P2Kpa => {
                    if self.pressure_noise_pa > 0.0 {
                        v.iter_mut().for_each(|x| *x += p.sample(&mut rng));
                    }
                }
                Channel::F1N | Channel::F2N => {
                    if self.force_noise_n > 0.0 {
                        v.iter_mut().for_each(|x| *x += f.sample(&mut rng));
                    }
                }
            }
        }
    }
}
