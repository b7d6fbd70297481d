//! The command line of `identify`: its clap argument types, each converted into the library's
//! plain options.

use std::path::PathBuf;

use clap::{Args, Subcommand};
use host_sim::identify::force;
use host_sim::validate::{self, f64_in, u64_in, usize_in, Range};

/// `host-sim calibrate`.
#[derive(Args, Debug)]
#[command(
    after_help = "Example:\n  host-sim calibrate --recording rec.csv --plant host-sim/plants/reference-1dof.toml --out-dir config/ --tune"
)]
pub struct CalibrateArgs {
    /// Recording of the joint (RECORDING.md: angle_deg, p1_kpa, p2_kpa, optionally f1_n, f2_n):
    /// a motion through a range of angles under varying activation (e.g. `host-sim sweep torque`).
    #[arg(long, value_name = "REC.csv")]
    pub recording: PathBuf,
    /// Plant file (PLANT.md format; e.g. the output of `host-sim identify plant`): geometry,
    /// inertia, supply, valve, and the force model when the recording has no tensions.
    #[arg(long, value_name = "P.toml")]
    pub plant: PathBuf,
    /// Directory of the firmware's constants (config/): torque_model.toml,
    /// joint_geometry.toml, plant_constants.toml (and with --tune control_tuned.toml) are
    /// replaced there.
    #[arg(long, value_name = "DIR")]
    pub out_dir: PathBuf,
    /// Also tune the control gains on the plant file (`host-sim tune`, minutes).
    #[arg(long)]
    pub tune: bool,
    /// Worker threads of the tuner (with --tune; 1..=256, as every command's --threads).
    #[arg(long, default_value_t = 2, value_parser = host_sim::validate::usize_in(1, 256))]
    pub threads: usize,
    /// First identify these plant-file keys (comma separated, `key` or `key=lo:hi`, as
    /// `host-sim identify plant --params`) by replaying a valve-driven recording; the
    /// identified plant file (plant_identified.toml in --out-dir) then feeds every later stage.
    #[arg(long, value_name = "KEYS", value_delimiter = ',')]
    pub identify_plant: Vec<String>,
    /// The valve-driven recording of --identify-plant (columns t_s, u_in1, u_ex1, u_in2,
    /// u_ex2 and the measured channels) [default: --recording].
    #[arg(long, value_name = "R.csv", requires = "identify_plant")]
    pub plant_recording: Option<PathBuf>,
}

/// `host-sim sweep ...`: synthetic identification data from a plant file.
#[derive(Args, Debug)]
#[command(
    after_help = "Examples:\n  host-sim sweep force --plant host-sim/plants/reference-1dof.toml --out force.csv\n  host-sim sweep torque --plant host-sim/plants/reference-1dof.toml --out torque.csv"
)]
pub struct SweepArgs {
    #[command(subcommand)]
    pub what: SweepWhat,
}

#[derive(Subcommand, Debug)]
pub enum SweepWhat {
    /// Isometric force data (writes columns p_kpa, stretch, f_n[, state]) from the plant's
    /// Tondu surface: at each L/L0 the pressure is swept from the maximum to 0 (and back up
    /// with --hysteresis-gap-n), as on the force-law paper's test bench.
    Force(SweepForceArgs),
    /// A measured-style isometric force map (columns p_kpa, stretch, f_n[, state]) from an
    /// independent thick-walled Chou-Hannaford muscle drawn from the seed: 5..9 lengths down to
    /// L/L0 ~ 0.74, 10..15 pressures up to 600..700 kPa, 60..130 points, exactly 0 N where the
    /// muscle is slack, noisy readings; --branches adds the falling branch with braid friction.
    ForceMap(SweepForceMapArgs),
    /// A torque-identification recording (writes RECORDING.md columns t_s, u_in1..u_ex2,
    /// angle_deg, p1_kpa, p2_kpa, f1_n, f2_n) as in the torque-model paper: the joint is driven
    /// quasi-statically and at constant speeds through +-amplitude at each activation dp
    /// (p1 = p0 - dp, p2 = p0 + dp held by regulators); channels from the plant's sensors.
    Torque(SweepTorqueArgs),
}

#[derive(Args, Debug)]
#[command(
    after_help = "Example:\n  host-sim sweep force --plant host-sim/plants/reference-1dof.toml --out force.csv"
)]
pub struct SweepForceArgs {
    /// Plant file: the muscle's Tondu parameters (radius_m, braid_angle_deg, end_factor).
    #[arg(long, value_name = "P.toml")]
    pub plant: PathBuf,
    /// Output CSV.
    #[arg(long, value_name = "F.csv")]
    pub out: PathBuf,
    /// Number of L/L0 levels.
    #[arg(long, default_value_t = 31, value_parser = usize_in(2, 100_000))]
    pub n_stretch: usize,
    /// Number of pressure levels per sweep.
    #[arg(long, default_value_t = 31, value_parser = usize_in(2, 100_000))]
    pub n_pressure: usize,
    /// Lowest L/L0.
    #[arg(long, default_value_t = 0.75, value_parser = f64_in(Range::closed(force::STRETCH_MIN, force::STRETCH_MAX)))]
    pub stretch_min: f64,
    /// Highest L/L0.
    #[arg(long, default_value_t = 1.05, value_parser = f64_in(Range::closed(force::STRETCH_MIN, force::STRETCH_MAX)))]
    pub stretch_max: f64,
    /// Highest gauge pressure [kPa] (20..=2000: `identify force` needs a map reaching 20 kPa;
    /// less is a value in MPa or bar).
    #[arg(long, default_value_t = 600.0, value_parser = f64_in(Range::closed(force::P_KPA_MAX_AT_LEAST, 2000.0)))]
    pub p_max_kpa: f64,
    /// Load-cell noise, standard deviation [N].
    #[arg(long, default_value_t = 3.0, value_parser = f64_in(Range::closed(0.0, 1e4)))]
    pub force_noise_n: f64,
    /// Pressure-sensor noise, standard deviation [kPa].
    #[arg(long, default_value_t = 0.5, value_parser = f64_in(Range::closed(0.0, 100.0)))]
    pub pressure_noise_kpa: f64,
    /// Gap between the pressurising and depressurising branches at full pressure [N]; > 0
    /// sweeps both branches and writes a `state` column. At most a quarter of the sweep's
    /// largest force (the plant's muscle at --p-max-kpa; the message gives it).
    #[arg(long, default_value_t = 0.0, value_parser = f64_in(Range::closed(0.0, 1e4)))]
    pub hysteresis_gap_n: f64,
    /// Random seed of the noise (0..=18446744073709551615).
    #[arg(long, default_value_t = 1, value_parser = u64_in(0, u64::MAX))]
    pub seed: u64,
    /// Run even when the estimated memory or time exceeds the limit (docs/reliability.md).
    #[arg(long)]
    pub allow_large: bool,
}

#[derive(Args, Debug)]
#[command(after_help = "Example:\n  host-sim sweep force-map --seed 3 --branches --out map.csv")]
pub struct SweepForceMapArgs {
    /// Output CSV.
    #[arg(long, value_name = "F.csv")]
    pub out: PathBuf,
    /// Seed: the muscle, the grid and the noise (0..=18446744073709551615).
    #[arg(long, default_value_t = 1, value_parser = u64_in(0, u64::MAX))]
    pub seed: u64,
    /// Sweep every length up and down (rising and falling branches, braid friction).
    #[arg(long)]
    pub branches: bool,
}

#[derive(Args, Debug)]
#[command(
    after_help = "Example:\n  host-sim sweep torque --plant host-sim/plants/reference-1dof.toml --out torque.csv --dt-s 0.001"
)]
pub struct SweepTorqueArgs {
    /// Plant file.
    #[arg(long, value_name = "P.toml")]
    pub plant: PathBuf,
    /// Output recording.
    #[arg(long, value_name = "R.csv")]
    pub out: PathBuf,
    /// Mid pressure p0, gauge [kPa].
    #[arg(long, default_value_t = 300.0, value_parser = f64_in(Range::positive(2000.0)))]
    pub p0_kpa: f64,
    /// Activation levels dp [kPa], comma separated.
    #[arg(
        long,
        value_delimiter = ',',
        allow_hyphen_values = true,
        default_value = "-200,-100,0,100,200",
        value_parser = f64_in(Range::closed(-2000.0, 2000.0))
    )]
    pub dp_kpa: Vec<f64>,
    /// Angle amplitude of the motion [rad].
    #[arg(long, default_value_t = 0.35, value_parser = f64_in(Range::positive(std::f64::consts::PI)))]
    pub amplitude_rad: f64,
    /// Constant speeds of the passes [rad/s], comma separated (the first quasi-static).
    #[arg(long, value_delimiter = ',', default_value = "0.1,1,2,4", value_parser = f64_in(Range::positive(1000.0)))]
    pub speeds_rad_s: Vec<f64>,
    /// Sample period [s].
    #[arg(long, default_value_t = 0.005, value_parser = f64_in(Range::closed(1e-6, 1.0)))]
    pub dt_s: f64,
    /// Encoder counts per turn: 0 (no angle quantisation) or 360..=1073741824 (a coarser
    /// encoder reads the motion in steps of more than 1 degree).
    #[arg(long, default_value_t = 8000, value_parser = validate::encoder_counts_per_rev)]
    pub encoder_counts: u32,
    /// Pressure-sensor noise, standard deviation [kPa].
    #[arg(long, default_value_t = 0.5, value_parser = f64_in(Range::closed(0.0, 100.0)))]
    pub pressure_noise_kpa: f64,
    /// Force-sensor noise, standard deviation [N].
    #[arg(long, default_value_t = 2.0, value_parser = f64_in(Range::closed(0.0, 1e4)))]
    pub force_noise_n: f64,
    /// Random seed of the noise (0..=18446744073709551615).
    #[arg(long, default_value_t = 1, value_parser = u64_in(0, u64::MAX))]
    pub seed: u64,
    /// Run even when the estimated memory or time exceeds the limit (docs/reliability.md).
    #[arg(long)]
    pub allow_large: bool,
}

/// `host-sim identify ...`.
#[derive(Args, Debug)]
#[command(
    after_help = "Examples:\n  host-sim identify force --data force.csv --out force_law.toml\n  host-sim identify torque --recording torque.csv --plant host-sim/plants/reference-1dof.toml --out torque_model.toml\n  host-sim identify plant --recording host-sim/tests/fixtures/pulses_loaded.csv --plant host-sim/plants/reference-1dof.toml --params joint.inertia_kgm2 --out fitted.toml"
)]
pub struct IdentifyArgs {
    #[command(subcommand)]
    pub what: IdentifyWhat,
}

#[derive(Subcommand, Debug)]
pub enum IdentifyWhat {
    /// Fit the static force law (the ten-constant polynomial in pressure and L/L0 of the
    /// force-law paper, its eq. 6, constants c1..c10) and the Tondu baseline to isometric data
    /// (CSV columns p_kpa, stretch, f_n[, state|direction]); print both models' errors; write
    /// the firmware's force-law TOML.
    Force(IdentifyForceArgs),
    /// Fit A, B, C, D of the simplified joint torque model (the torque-model paper's eq. 11:
    /// stiffness from the activation, viscous and cubic damping) to a recording (columns t_s,
    /// angle_deg, p1_kpa, p2_kpa and f1_n, f2_n, else tensions from the plant's force model);
    /// write the torque-model TOML.
    Torque(IdentifyTorqueArgs),
    /// Output-error fit of plant-file parameters by replaying the recording's valve inputs
    /// (columns t_s, u_in1, u_ex1, u_in2, u_ex2 and the measured angle_deg, p1_kpa, p2_kpa,
    /// f1_n, f2_n that are present); write the plant file with the fitted values.
    Plant(IdentifyPlantArgs),
    /// Train the hybrid model's chamber volume (eq. 8-12 of the learned-inverse-thermodynamics paper: a network of two hidden
    /// layers V(e, e', P, P'), loss = mass-flow error + weight decay) on a recording with the
    /// mass-flow columns m_dot_1_kg_s, m_dot_2_kg_s; write the firmware's config/volume.toml.
    Volume(IdentifyVolumeArgs),
}

#[derive(Args, Debug)]
#[command(after_help = "Example:\n  host-sim identify force --data force.csv --out force_law.toml")]
pub struct IdentifyForceArgs {
    /// Isometric data CSV.
    #[arg(long, value_name = "F.csv")]
    pub data: PathBuf,
    /// Output TOML (the format of config/force_law.toml).
    #[arg(long, value_name = "force.toml")]
    pub out: PathBuf,
    /// Upper end of the pressure domain written for the firmware [kPa] (20..=2000: less is a
    /// value in MPa or bar) [default: the largest pressure in the data, which sensor noise
    /// pushes above the sweep's nominal maximum].
    #[arg(long, value_parser = f64_in(Range::closed(force::P_KPA_MAX_AT_LEAST, 2000.0)))]
    pub p_gauge_max_kpa: Option<f64>,
}

#[derive(Args, Debug)]
#[command(
    after_help = "Example:\n  host-sim identify torque --recording torque.csv --plant host-sim/plants/reference-1dof.toml --out torque_model.toml"
)]
pub struct IdentifyTorqueArgs {
    /// Recording (RECORDING.md).
    #[arg(long, value_name = "R.csv")]
    pub recording: PathBuf,
    /// Plant file: the sprocket radius r (and the force model when the recording has no tensions).
    #[arg(long, value_name = "P.toml")]
    pub plant: PathBuf,
    /// Output TOML (the format of config/torque_model.toml).
    #[arg(long, value_name = "torque.toml")]
    pub out: PathBuf,
    /// Half window of the Savitzky-Golay velocity estimate [samples] [default: 25 ms worth].
    #[arg(long, value_parser = usize_in(1, 100_000))]
    pub savgol_half_window: Option<usize>,
    /// Activation limit the controller may command [kPa], at most min(p0, supply - p0)
    /// [default: min(p0, supply - p0) - 20 kPa].
    #[arg(long, value_parser = f64_in(Range::positive(2000.0)))]
    pub dp_max_kpa: Option<f64>,
    /// Fit only the samples of (nearly) constant velocity, as the torque-model paper does: |acceleration|
    /// averaged over the velocity window at most this [rad/s^2] [default: all samples].
    #[arg(long, value_parser = f64_in(Range::positive(1e6)))]
    pub max_accel_rad_s2: Option<f64>,
    /// Write the model even when its fit is below the trustworthy fit that `calibrate`
    /// requires (docs/identification.md).
    #[arg(long)]
    pub allow_poor_fit: bool,
}

#[derive(Args, Debug)]
#[command(
    after_help = "Example:\n  host-sim identify plant --recording host-sim/tests/fixtures/pulses_loaded.csv --plant host-sim/plants/reference-1dof.toml --params joint.inertia_kgm2 --out fitted.toml"
)]
pub struct IdentifyPlantArgs {
    /// Recording whose valve inputs are replayed and whose channels are fitted.
    #[arg(long, value_name = "R.csv")]
    pub recording: PathBuf,
    /// Start plant file.
    #[arg(long, value_name = "P.toml")]
    pub plant: PathBuf,
    /// Dotted keys to fit, comma separated, each optionally with bounds `key=lo:hi`
    /// (e.g. valve.sonic_conductance_m3_per_s_pa,muscle.damping_m2s,joint.inertia_kgm2).
    #[arg(long, value_delimiter = ',', required = true)]
    pub params: Vec<String>,
    /// Output plant file (the input with the fitted values replaced).
    #[arg(long, value_name = "P2.toml")]
    pub out: PathBuf,
    /// Fraction of the recording (its tail) held out for validation.
    #[arg(long, default_value_t = 0.25, value_parser = f64_in(Range::half_open(0.0, 0.9)))]
    pub holdout_fraction: f64,
    /// Relative (and absolute) tolerance of the replays.
    #[arg(long, default_value_t = 1e-9, value_parser = f64_in(Range::closed(1e-14, 0.1)))]
    pub rtol: f64,
    /// Levenberg-Marquardt patience: at most this many model evaluations per fitted
    /// parameter (plus one).
    #[arg(long, default_value_t = 40, value_parser = usize_in(1, 100_000))]
    pub patience: usize,
    /// Write the plant file even when its mean held-out fit is below the one `calibrate`
    /// requires of an identified plant (docs/identification.md).
    #[arg(long)]
    pub allow_poor_fit: bool,
}

#[derive(Args, Debug)]
#[command(
    after_help = "Example:\n  host-sim simulate --plant host-sim/plants/reference-1dof.toml --scenario scenarios/random.toml --out random.csv\n  host-sim identify volume --recording random.csv --out config/volume.toml"
)]
pub struct IdentifyVolumeArgs {
    /// Recording with angle_deg, p1_kpa, p2_kpa and the mass-flow columns m_dot_1_kg_s,
    /// m_dot_2_kg_s (RECORDING.md; `host-sim simulate --scenario` writes them).
    #[arg(long, value_name = "R.csv")]
    pub recording: std::path::PathBuf,
    /// Output TOML (the format of config/volume.toml).
    #[arg(long, value_name = "volume.toml")]
    pub out: std::path::PathBuf,
    /// Seed of the random start (the same seed and recording give the same file;
    /// 0..=18446744073709551615).
    #[arg(long, default_value_t = 1, value_parser = host_sim::validate::u64_in(0, u64::MAX))]
    pub seed: u64,
    /// Weight decay lambda (the penalty on the network's squared weights in the training
    /// loss, eq. 10 of the learned-inverse-thermodynamics paper).
    #[arg(long, default_value_t = 1e-5, value_parser = host_sim::validate::f64_in(host_sim::validate::Range::closed(0.0, 1.0)))]
    pub weight_decay: f64,
    /// Levenberg-Marquardt budget [loss evaluations].
    #[arg(long, default_value_t = 2000, value_parser = host_sim::validate::usize_in(10, 1_000_000))]
    pub max_evals: usize,
    /// Half window of the Savitzky-Golay derivatives [samples] [default: 10 ms worth].
    #[arg(long, value_parser = host_sim::validate::usize_in(1, 100_000))]
    pub savgol_half_window: Option<usize>,
    /// Fraction of the recording (its tail) held out for the validation figures.
    #[arg(long, default_value_t = 0.25, value_parser = host_sim::validate::f64_in(host_sim::validate::Range::half_open(0.0, 0.9)))]
    pub holdout_fraction: f64,
    /// Also report the mass-flow errors on these recordings (not trained on; comma
    /// separated).
    #[arg(long, value_name = "R2.csv", value_delimiter = ',', value_parser = trimmed_path)]
    pub validate: Vec<std::path::PathBuf>,
    /// At most this many training samples (both muscles; evenly thinned).
    #[arg(long, default_value_t = 4000, value_parser = host_sim::validate::usize_in(100, 1_000_000))]
    pub max_samples: usize,
    /// Write the network even when its mass-flow error on the held-out tail (or on a
    /// --validate recording) is not below the polynomial volume's, or when nothing is held out
    /// to judge it by (docs/identification.md).
    #[arg(long)]
    pub allow_worse: bool,
}

/// A path of a comma-separated list without the blanks around it (`"a.csv, b.csv"`).
fn trimmed_path(s: &str) -> Result<std::path::PathBuf, String> {
    let t = s.trim();
    if t.is_empty() {
        return Err("an empty file name in the list".into());
    }
    Ok(t.into())
}

impl From<CalibrateArgs> for host_sim::control::calibrate::CalibrateArgs {
    fn from(a: CalibrateArgs) -> Self {
        Self {
            recording: a.recording,
            plant: a.plant,
            out_dir: a.out_dir,
            tune: a.tune,
            threads: a.threads,
            identify_plant: a.identify_plant,
            plant_recording: a.plant_recording,
        }
    }
}

impl From<SweepArgs> for host_sim::identify::cli::SweepArgs {
    fn from(a: SweepArgs) -> Self {
        Self {
            what: a.what.into(),
        }
    }
}

impl From<SweepWhat> for host_sim::identify::cli::SweepWhat {
    fn from(a: SweepWhat) -> Self {
        match a {
            SweepWhat::Force(x) => Self::Force(x.into()),
            SweepWhat::ForceMap(x) => Self::ForceMap(x.into()),
            SweepWhat::Torque(x) => Self::Torque(x.into()),
        }
    }
}

impl From<SweepForceArgs> for host_sim::identify::cli::SweepForceArgs {
    fn from(a: SweepForceArgs) -> Self {
        Self {
            plant: a.plant,
            out: a.out,
            n_stretch: a.n_stretch,
            n_pressure: a.n_pressure,
            stretch_min: a.stretch_min,
            stretch_max: a.stretch_max,
            p_max_kpa: a.p_max_kpa,
            force_noise_n: a.force_noise_n,
            pressure_noise_kpa: a.pressure_noise_kpa,
            hysteresis_gap_n: a.hysteresis_gap_n,
            seed: a.seed,
            allow_large: a.allow_large,
        }
    }
}

impl From<SweepForceMapArgs> for host_sim::identify::cli::SweepForceMapArgs {
    fn from(a: SweepForceMapArgs) -> Self {
        Self {
            out: a.out,
            seed: a.seed,
            branches: a.branches,
        }
    }
}

impl From<SweepTorqueArgs> for host_sim::identify::cli::SweepTorqueArgs {
    fn from(a: SweepTorqueArgs) -> Self {
        Self {
            plant: a.plant,
            out: a.out,
            p0_kpa: a.p0_kpa,
            dp_kpa: a.dp_kpa,
            amplitude_rad: a.amplitude_rad,
            speeds_rad_s: a.speeds_rad_s,
            dt_s: a.dt_s,
            encoder_counts: a.encoder_counts,
            pressure_noise_kpa: a.pressure_noise_kpa,
            force_noise_n: a.force_noise_n,
            seed: a.seed,
            allow_large: a.allow_large,
        }
    }
}

impl From<IdentifyArgs> for host_sim::identify::cli::IdentifyArgs {
    fn from(a: IdentifyArgs) -> Self {
        Self {
            what: a.what.into(),
        }
    }
}

impl From<IdentifyWhat> for host_sim::identify::cli::IdentifyWhat {
    fn from(a: IdentifyWhat) -> Self {
        match a {
            IdentifyWhat::Force(x) => Self::Force(x.into()),
            IdentifyWhat::Torque(x) => Self::Torque(x.into()),
            IdentifyWhat::Plant(x) => Self::Plant(x.into()),
            IdentifyWhat::Volume(x) => Self::Volume(x.into()),
        }
    }
}

impl From<IdentifyForceArgs> for host_sim::identify::cli::IdentifyForceArgs {
    fn from(a: IdentifyForceArgs) -> Self {
        Self {
            data: a.data,
            out: a.out,
            p_gauge_max_kpa: a.p_gauge_max_kpa,
        }
    }
}

impl From<IdentifyTorqueArgs> for host_sim::identify::cli::IdentifyTorqueArgs {
    fn from(a: IdentifyTorqueArgs) -> Self {
        Self {
            recording: a.recording,
            plant: a.plant,
            out: a.out,
            savgol_half_window: a.savgol_half_window,
            dp_max_kpa: a.dp_max_kpa,
            max_accel_rad_s2: a.max_accel_rad_s2,
            allow_poor_fit: a.allow_poor_fit,
        }
    }
}

impl From<IdentifyPlantArgs> for host_sim::identify::cli::IdentifyPlantArgs {
    fn from(a: IdentifyPlantArgs) -> Self {
        Self {
            recording: a.recording,
            plant: a.plant,
            params: a.params,
            out: a.out,
            holdout_fraction: a.holdout_fraction,
            rtol: a.rtol,
            patience: a.patience,
            allow_poor_fit: a.allow_poor_fit,
        }
    }
}

impl From<IdentifyVolumeArgs> for host_sim::identify::volume::IdentifyVolumeArgs {
    fn from(a: IdentifyVolumeArgs) -> Self {
        Self {
            recording: a.recording,
            out: a.out,
            seed: a.seed,
            weight_decay: a.weight_decay,
            max_evals: a.max_evals,
            savgol_half_window: a.savgol_half_window,
            holdout_fraction: a.holdout_fraction,
            validate: a.validate,
            max_samples: a.max_samples,
            allow_worse: a.allow_worse,
        }
    }
}
