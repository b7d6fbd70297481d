//! The command line of `control`: its clap argument types, each converted into the library's
//! plain options.

use std::path::PathBuf;

use clap::Args;

/// Arguments of `host-sim compare-control`.
#[derive(Args, Debug)]
#[command(
    after_help = "Example:\n  host-sim compare-control --plant host-sim/plants/reference-1dof.toml"
)]
pub struct CompareControlArgs {
    /// Plant parameter file (TOML): the nominal plant; the effect variants are added to it.
    #[arg(long, value_name = "P.toml")]
    pub plant: PathBuf,
    /// Tuned gains of the P-only cascade [default: config/control_tuned.toml under the working
    /// directory if it is there, else the shipped gains built into host-sim]; the report's
    /// first line names the file used. The verdict compares the P-only cascade at these gains
    /// with the feed-forward cascade at --ff-gains (each design tuned for itself, as the
    /// learned-inverse-thermodynamics paper compares them); give both files, tuned on the same plant, or the verdict compares
    /// tunings of different origin. The same-gains ratio is printed beside it.
    #[arg(long, value_name = "CONTROL_TUNED.toml")]
    pub gains: Option<PathBuf>,
    /// The cascade's gains tuned with the feed-forward on (`host-sim tune --pressure-ff`), for
    /// the rows where each controller runs at its own best gains [default:
    /// config/control_tuned_ff.toml under the working directory if it is there, else the shipped
    /// ones built into host-sim].
    #[arg(long, value_name = "CONTROL_TUNED_FF.toml")]
    pub ff_gains: Option<PathBuf>,
    #[command(flatten)]
    pub ff: FfOverrides,
    /// Run the cascade's outer loops (position loop, trajectory feed-forward, torque
    /// estimate, torque loop) on one tick in N, the pressure loops every tick, in every row
    /// (1..=5 at the 1 kHz tick; 1 = every tick) [default: the rate --gains were tuned at
    /// (`host-sim tune --outer-period-ticks`), else config/controller.toml [rates]
    /// outer_period_ticks].
    #[arg(long, value_name = "N", value_parser = host_sim::control::compare::outer_period_arg)]
    pub outer_period_ticks: Option<u16>,
    /// Only the nominal plant and the suite's first scenario of each set (the CI run).
    #[arg(long)]
    pub quick: bool,
    /// Only the nominal plant, every scenario of both sets.
    #[arg(long, conflicts_with = "quick")]
    pub nominal_only: bool,
    /// Also print, per scenario set on the nominal plant, where the P-only cascade's position
    /// error comes from (moves / rest, pressure lag, ripple, deadband, saturation) and the
    /// same cascade with the pressure loop's deadband removed or its gain x4 (diagnostics
    /// only: those change the cascade).
    #[arg(long)]
    pub breakdown: bool,
}

/// The `--ff-*` options of `host-sim compare-control`: values that replace those of
/// config/pressure_ff.toml.
#[derive(Args, Debug)]
pub struct FfOverrides {
    /// Scale of the feed-forward duty (0..=2) [default: config/pressure_ff.toml gain].
    #[arg(long = "ff-gain", value_name = "G")]
    pub gain: Option<f32>,
    /// Cut-off of the set-point rate filter [Hz] (1..=500) [default: config/pressure_ff.toml].
    #[arg(long = "ff-cutoff-hz", value_name = "HZ")]
    pub cutoff_hz: Option<f32>,
    /// Where the feed-forward takes its desired pressure rate P' and volume rate V' from:
    /// `reference` (the set-point trajectory through the inverse torque model) or
    /// `set-point` (the torque loop's pressure set-point and the measured velocity)
    /// [default: config/pressure_ff.toml rate_from_reference].
    #[arg(long = "ff-rate-from", value_name = "SOURCE", value_parser = ["reference", "set-point"])]
    pub rate_from: Option<String>,
    /// Where the feed-forward takes the volume rate V' from: `reference` (the set-point's
    /// rate) or `measured` (the velocity estimate) [default: config/pressure_ff.toml
    /// volume_rate_from_reference].
    #[arg(long = "ff-volume-rate-from", value_name = "SOURCE", value_parser = ["reference", "measured"])]
    pub volume_rate_from: Option<String>,
    /// Feed-forward duties of a smaller magnitude are dropped (0..=1) [default:
    /// config/pressure_ff.toml min_duty].
    #[arg(long = "ff-min-duty", value_name = "D")]
    pub min_duty: Option<f32>,
    /// Evaluate the feed-forward once every N ticks and hold it in between (1..=100 at the
    /// 1 kHz tick; 1 = every tick) [default: the period the --ff-gains were tuned at (`host-sim
    /// tune --ff-update-ticks`), else config/pressure_ff.toml update_period_ticks].
    #[arg(
        long = "ff-update-ticks",
        value_name = "N",
        value_parser = host_sim::control::compare::ff_update_ticks_arg
    )]
    pub update_ticks: Option<u16>,
}

#[derive(Args, Debug)]
#[command(
    after_help = "Example (build the image first):\n  cargo build -p pam-firmware --bin pil --features pam-firmware/firmware --release --target thumbv7em-none-eabihf\n  host-sim pil --plant host-sim/plants/reference-1dof.toml --scenario scenarios/step.toml --out pil.csv --log pil.stream"
)]
pub struct PilArgs {
    /// Plant parameter file (TOML).
    #[arg(long, value_name = "P.toml")]
    pub plant: PathBuf,
    /// Closed-loop scenario (TOML). The firmware gets raw board counts: the scenario's
    /// [sensors] run with `board_counts = true` (turned on, and said, when the file leaves it
    /// off). Its [expect] bounds are checked on the firmware's run (exit status 1 if not met).
    #[arg(long, value_name = "S.toml")]
    pub scenario: PathBuf,
    /// Output recording (RECORDING.md), as `simulate --scenario` writes it.
    #[arg(long, value_name = "REC.csv")]
    pub out: PathBuf,
    /// Firmware image [default: target/thumbv7em-none-eabihf/release/pil under the working
    /// directory].
    #[arg(long, value_name = "ELF")]
    pub elf: Option<PathBuf>,
    /// Also write the firmware's per-tick stream (binary records) here, for `host-sim capture`.
    #[arg(long, value_name = "LOG")]
    pub log: Option<PathBuf>,
    /// Longest wait for one tick's answer from QEMU [s] (1..=600).
    #[arg(long, value_name = "S", default_value_t = 20.0)]
    pub tick_timeout_s: f64,
}

/// `host-sim tune`.
#[derive(Args, Debug)]
#[command(
    after_help = "Example:\n  host-sim tune --plant host-sim/plants/reference-1dof.toml --out control_tuned.toml"
)]
pub struct TuneArgs {
    /// Plant file the gains are tuned on.
    #[arg(long, value_name = "P.toml")]
    pub plant: PathBuf,
    /// Output gains file (the format of config/control_tuned.toml), written atomically.
    #[arg(long, value_name = "control.toml")]
    pub out: PathBuf,
    /// Threads for the PD / PID grids and polish (1..=256, as every command's --threads).
    #[arg(long, default_value_t = 2, value_parser = host_sim::validate::usize_in(1, 256))]
    pub threads: usize,
    /// Also start every search from the gains stored in --out (when it loads); without it the
    /// search is reproducible from scratch.
    #[arg(long)]
    pub warm_start: bool,
    /// Cut-off of every law's set-point differentiators [Hz] (1..=500).
    #[arg(long, default_value_t = 150.0)]
    pub setpoint_cutoff_hz: f32,
    /// Duration of the suite's set-point moves [s] (0..=2, 0 = jumps) [default: the suite's 0.15 s].
    #[arg(long, value_parser = host_sim::validate::f64_in_unit(host_sim::validate::Range::closed(0.0, 2.0), "seconds"))]
    pub transition_s: Option<f64>,
    /// One more cascade start KP,KI,KD[,TORQUE_KI] (repeatable), each > 0 and at most what a
    /// gains file loads (kp 1e4 N m/rad, ki 1e6 N m/(rad s), kd 1e3 N m s/rad, torque ki 1e5 1/s).
    #[arg(long, value_name = "KP,KI,KD[,TORQUE_KI]")]
    pub cascade_start: Vec<String>,
    /// Do not impose the firmware's step tests on the cascade (report them only).
    #[arg(long)]
    pub no_step_constraints: bool,
    /// Robustness term in every law's cost: the worse of the cost on the plant and on the
    /// plant with an 8 ms valve dead time (valve supervision off), and infinite unless the suite and the jump
    /// suite (the demo's set-points) stay stable on the plant with 11 x its inertia (no fault, |error| <
    /// 0.5 rad, no limit cycle at rest).
    #[arg(long)]
    pub robust: bool,
    /// Tune the cascade with the pressure loops' inverse thermodynamic feed-forward on
    /// (config/pressure_ff.toml's options; the gains file records it), so that it can be
    /// compared at its own best gains (`compare-control --ff-gains`). The PD / PID do not use it.
    #[arg(long)]
    pub pressure_ff: bool,
    /// Infinite cost unless the suite and the jump suite (the demo's step, sine and random
    /// set-points) stay stable on the plant itself: no fault, |error| < 0.5 rad, and a run that
    /// ends in a hold comes to rest (spread of the error over its last 0.5 s <= 0.01 rad).
    /// Keeps gains tuned on the smooth suite from limit-cycling after a set-point jump.
    #[arg(long)]
    pub stable_on_jumps: bool,
    /// Tune the cascade with its outer loops (position loop, trajectory feed-forward, torque
    /// estimate, torque loop) on one tick in N (1..=5 at the 1 kHz tick); the gains file
    /// records it, and compare-control runs those gains at that rate [default:
    /// config/controller.toml [rates] outer_period_ticks]. The PD / PID do not use it.
    #[arg(long, value_name = "N", value_parser = host_sim::control::compare::outer_period_arg)]
    pub outer_period_ticks: Option<u16>,
    /// With --pressure-ff: evaluate the feed-forward once every N ticks and hold it in between
    /// (1..=100 at the 1 kHz tick; 1 = every tick); the gains file records it, and
    /// compare-control runs those gains at that period [default: config/pressure_ff.toml
    /// update_period_ticks, 1 as shipped].
    #[arg(
        long = "ff-update-ticks",
        value_name = "N",
        requires = "pressure_ff",
        value_parser = host_sim::control::compare::ff_update_ticks_arg
    )]
    pub ff_update_ticks: Option<u16>,
}

impl From<CompareControlArgs> for host_sim::control::compare_ff::CompareControlArgs {
    fn from(a: CompareControlArgs) -> Self {
        Self {
            plant: a.plant,
            gains: a.gains,
            ff_gains: a.ff_gains,
            ff: a.ff.into(),
            outer_period_ticks: a.outer_period_ticks,
            quick: a.quick,
            nominal_only: a.nominal_only,
            breakdown: a.breakdown,
        }
    }
}

impl From<FfOverrides> for host_sim::control::compare_ff::FfOverrides {
    fn from(a: FfOverrides) -> Self {
        Self {
            gain: a.gain,
            cutoff_hz: a.cutoff_hz,
            rate_from: a.rate_from,
            volume_rate_from: a.volume_rate_from,
            min_duty: a.min_duty,
            update_ticks: a.update_ticks,
        }
    }
}

impl From<PilArgs> for host_sim::control::pil::PilArgs {
    fn from(a: PilArgs) -> Self {
        Self {
            plant: a.plant,
            scenario: a.scenario,
            out: a.out,
            elf: a.elf,
            log: a.log,
            tick_timeout_s: a.tick_timeout_s,
        }
    }
}

impl From<TuneArgs> for host_sim::control::tune::TuneArgs {
    fn from(a: TuneArgs) -> Self {
        Self {
            plant: a.plant,
            out: a.out,
            threads: a.threads,
            warm_start: a.warm_start,
            setpoint_cutoff_hz: a.setpoint_cutoff_hz,
            transition_s: a.transition_s,
            cascade_start: a.cascade_start,
            no_step_constraints: a.no_step_constraints,
            robust: a.robust,
            pressure_ff: a.pressure_ff,
            stable_on_jumps: a.stable_on_jumps,
            outer_period_ticks: a.outer_period_ticks,
            ff_update_ticks: a.ff_update_ticks,
        }
    }
}
