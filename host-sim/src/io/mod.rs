//! Files in and out: recordings (RECORDING.md CSV), closed-loop scenarios (TOML), the files
//! a closed-loop run writes, plots, and the 3-joint arm's recordings.

pub mod arm3;
pub mod atomic;
pub mod capture;
pub mod compare;
pub mod grid;
pub mod import;
pub mod numfmt;
pub mod plot;
pub mod recording;
pub mod replay_stream;
pub mod scenario;
pub mod segments;
pub mod timebase;

use std::path::Path;

/// The file name of `path` without its extension (`dir/name.csv` -> `name`), or `fallback`
/// when it has none: the base of the names of the files written next to or for it.
pub fn file_stem_or(path: &Path, fallback: &str) -> String {
    path.file_stem()
        .map_or_else(|| fallback.to_owned(), |s| s.to_string_lossy().into_owned())
}
