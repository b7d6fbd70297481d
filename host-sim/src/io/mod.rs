//! Files in and out: recordings (RECORDING.md CSV), closed-loop scenarios (TOML), the files
//! a closed-loop run writes, plots, and the 3-joint arm's recordings.

pub mod arm3;
pub mod atomic;
pub mod capture;
pub mod import;
pub mod numfmt;
pub mod plot;
pub mod recording;
pub mod replay_stream;
pub mod run_files;
pub mod scenario;
