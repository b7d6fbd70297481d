//! The command line of `io`: its clap argument types, each converted into the library's
//! plain options.

use std::path::PathBuf;

use clap::Args;

/// Arguments of `host-sim capture`.
#[derive(Args, Debug)]
#[command(
    after_help = "Examples:\n  host-sim capture --log pil.stream --out captured.csv\n  host-sim capture --log rtt.log --out run.csv --split   # run-1.csv, run-2.csv, ... at the gaps"
)]
pub struct CaptureArgs {
    /// The firmware image that wrote the log (decodes a raw defmt log through defmt-print).
    #[arg(long, value_name = "ELF")]
    pub elf: Option<PathBuf>,
    /// The stream: raw records, `stream [..]` text lines, or (with --elf) a raw defmt log.
    #[arg(long, value_name = "LOG")]
    pub log: PathBuf,
    /// Output recording (RECORDING.md); with --split and gaps, one per segment: REC-1.csv,
    /// REC-2.csv, ...
    #[arg(long, value_name = "REC.csv")]
    pub out: PathBuf,
    /// A gap in the stream (lost or corrupted records, a tick without a sensor sample, a
    /// restart of the firmware) ends one segment of the run instead of refusing the log:
    /// each segment of at least 2 ticks is written as its own recording (nothing is
    /// interpolated across a gap), as `import --split` does.
    #[arg(long)]
    pub split: bool,
}

/// Arguments of `host-sim import`.
#[derive(Args, Debug)]
#[command(
    after_help = "Example (docs/rig.md has the mapping file):\n  host-sim import --map festo-joint.toml --input messung7.csv --out messung7.rec.csv"
)]
pub struct ImportArgs {
    /// Mapping file (TOML): rig columns -> recording channels and units (docs/rig.md).
    #[arg(long, value_name = "MAP.toml")]
    pub map: PathBuf,
    /// The rig logger's CSV file.
    #[arg(long, value_name = "RAW.csv")]
    pub input: PathBuf,
    /// Output recording (RECORDING.md).
    #[arg(long, value_name = "REC.csv")]
    pub out: PathBuf,
    /// Write one recording per gap-free segment (REC-1.csv, REC-2.csv, ...) instead of
    /// refusing a file with gaps.
    #[arg(long)]
    pub split: bool,
    /// The valve columns were logged this late against the sensor columns [ms]: write them
    /// moved earlier by it (-1000..=1000; negative: logged early; the rows left without a
    /// valve opening at the end are dropped).
    #[arg(long, value_name = "MS", allow_negative_numbers = true)]
    pub shift_valves_ms: Option<f64>,
}

impl From<CaptureArgs> for host_sim::io::capture::CaptureArgs {
    fn from(a: CaptureArgs) -> Self {
        Self {
            elf: a.elf,
            log: a.log,
            out: a.out,
            split: a.split,
        }
    }
}

impl From<ImportArgs> for host_sim::io::import::ImportArgs {
    fn from(a: ImportArgs) -> Self {
        Self {
            map: a.map,
            input: a.input,
            out: a.out,
            split: a.split,
            shift_valves_ms: a.shift_valves_ms,
        }
    }
}
