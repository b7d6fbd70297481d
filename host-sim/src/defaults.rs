//! The reference files host-sim runs on when none is given (`demo` without `--plant` or
//! `--fixture`): the copies in this repository (`host-sim/plants/`, `host-sim/tests/fixtures/`,
//! checked byte for byte against the shared specification by `tests/conformance.rs`), looked
//! up from the working directory, else the same files built into the binary, so that an
//! installed binary (`cargo install --path host-sim`) works in any folder.

use std::path::{Path, PathBuf};

/// The reference plant, `host-sim/plants/reference-1dof.toml`.
pub const REFERENCE_PLANT: Builtin = Builtin {
    rel: "plants/reference-1dof.toml",
    text: include_str!("../plants/reference-1dof.toml"),
};

/// The conformance fixture the demo replays, `host-sim/tests/fixtures/pulses_nominal.csv`.
pub const PULSES_NOMINAL: Builtin = Builtin {
    rel: "tests/fixtures/pulses_nominal.csv",
    text: include_str!("../tests/fixtures/pulses_nominal.csv"),
};

/// A file of the host-sim crate built into the binary.
#[derive(Clone, Copy, Debug)]
pub struct Builtin {
    /// Its path inside the crate (`host-sim/<rel>` in the repository).
    pub rel: &'static str,
    /// Its content.
    pub text: &'static str,
}

/// Where a default file was found.
#[derive(Clone, Debug)]
pub struct Found {
    /// The file read (a label `host-sim's built-in <rel>` for the built-in copy).
    pub path: PathBuf,
    /// The built-in content when no file was found.
    pub builtin: Option<&'static str>,
    /// The paths tried, in order (relative to the working directory).
    pub tried: Vec<PathBuf>,
}

impl Builtin {
    /// The paths tried from the working directory: the repository root, then the crate's
    /// folder.
    pub fn candidates(&self) -> Vec<PathBuf> {
        vec![
            Path::new("host-sim").join(self.rel),
            PathBuf::from(self.rel),
        ]
    }

    /// The first of [`candidates`](Self::candidates) that exists, else the built-in copy.
    pub fn find(&self) -> Found {
        self.find_among(self.candidates())
    }

    /// The first of `tried` that is a file, else the built-in copy.
    pub fn find_among(&self, tried: Vec<PathBuf>) -> Found {
        match tried.iter().find(|p| p.is_file()) {
            Some(p) => Found {
                path: p.clone(),
                builtin: None,
                tried,
            },
            None => Found {
                path: PathBuf::from(format!("host-sim's built-in {}", self.rel)),
                builtin: Some(self.text),
                tried,
            },
        }
    }
}

impl Found {
    /// A note for stderr when the built-in copy is used: the paths tried (from which
    /// folder); `None` when a file was found.
    pub fn note(&self, what: &str) -> Option<String> {
        self.builtin?;
        let cwd = std::env::current_dir()
            .map(|d| d.display().to_string())
            .unwrap_or_else(|_| ".".into());
        let tried: Vec<String> = self.tried.iter().map(|p| p.display().to_string()).collect();
        Some(format!(
            "note: {what}: not found at {} (from {cwd}); using the copy built into host-sim",
            tried.join(", ")
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_built_in_files_are_the_repository_copies() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR"));
        for b in [REFERENCE_PLANT, PULSES_NOMINAL] {
            assert_eq!(
                std::fs::read_to_string(dir.join(b.rel)).unwrap(),
                b.text,
                "{}",
                b.rel
            );
        }
    }

    #[test]
    fn without_a_file_the_built_in_copy_is_used_and_the_paths_tried_are_named() {
        let tmp = tempfile::tempdir().unwrap();
        let missing = vec![tmp.path().join("a.toml"), tmp.path().join("b.toml")];
        let f = REFERENCE_PLANT.find_among(missing.clone());
        assert_eq!(f.builtin, Some(REFERENCE_PLANT.text));
        let note = f.note("default plant").unwrap();
        for m in &missing {
            assert!(note.contains(&m.display().to_string()), "{note}");
        }
        std::fs::write(&missing[1], "x").unwrap();
        let f = REFERENCE_PLANT.find_among(missing.clone());
        assert_eq!(f.path, missing[1]);
        assert!(f.note("default plant").is_none());
    }
}
