//! Identification of model parameters from data (issue "Identification").
//!
//! - [`force`]: the static force law (seed 002 eq. 6, and the Tondu baseline) from isometric data.
//! - [`torque`]: the simplified torque model (seed 003 eq. 11) from angle, pressures and tensions.

pub mod force;
pub mod torque;

use std::io::Write;
use std::path::Path;

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
    /// A bad value in an input file.
    #[error("{file}:{line}: field `{field}`: {msg}")]
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

/// Writes `bytes` to `path` through a temporary file in the same directory and a rename, so
/// a failed or interrupted write never replaces a good file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), IdentError> {
    let file = path.display().to_string();
    let io = |e: std::io::Error| IdentError::Io {
        file: file.clone(),
        msg: e.to_string(),
    };
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path.file_name().ok_or_else(|| IdentError::Io {
        file: file.clone(),
        msg: "not a file path".into(),
    })?;
    let tmp = dir.join(format!(
        ".{}.tmp{}",
        name.to_string_lossy(),
        std::process::id()
    ));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(io)
}
