//! The command line of `diagnose`: its clap argument types, each converted into the library's
//! plain options.

use std::path::PathBuf;

use clap::Args;

/// `host-sim diagnose-batch`: the arguments.
#[derive(Args, Debug)]
#[command(
    after_help = "Example:\n  host-sim diagnose-batch --plant host-sim/plants/reference-1dof.toml --recordings host-sim/tests/fixtures --out-dir diagnoses/"
)]
pub struct BatchArgs {
    /// Nominal plant file (TOML) the user believes in.
    #[arg(long, value_name = "P.toml")]
    pub plant: PathBuf,
    /// Directory of recordings (every `*.csv` in it, RECORDING.md columns t_s, u_in1, u_ex1,
    /// u_in2, u_ex2, angle_deg, p1_kpa, p2_kpa[, f1_n, f2_n]).
    #[arg(long, value_name = "DIR")]
    pub recordings: PathBuf,
    /// Output directory (created if missing): one `<recording>.json` each and `summary.csv`;
    /// it may be --recordings itself (an earlier run's summary.csv there is not read as a
    /// recording).
    #[arg(long, value_name = "OUT_DIR")]
    pub out_dir: PathBuf,
    /// Recordings diagnosed at once (worker threads).
    #[arg(long, default_value_t = 2, value_parser = host_sim::validate::usize_in(1, 256))]
    pub jobs: usize,
}

impl From<BatchArgs> for host_sim::diagnose::batch::BatchArgs {
    fn from(a: BatchArgs) -> Self {
        Self {
            plant: a.plant,
            recordings: a.recordings,
            out_dir: a.out_dir,
            jobs: a.jobs,
        }
    }
}
