//! Every fixture in `shared/conformance/` reproduced with fit >= 99.5 % on every channel.
//!
//! A fixture whose metadata declares the thermodynamic chamber of PLANT.md (`# thermal =
//! ... hA_w_per_k = H ..., kappa = K, ...`) is replayed with `[effects.thermal_chamber]` at the
//! values its header states (read from the header, not written here);
//! `thermal_fixture_needs_the_chamber` checks that the isothermal plant does NOT reproduce
//! it, so the chamber is what makes it pass.
//!
//! The fixtures are those of `../shared/conformance/` when the shared specification sits next
//! to the repository, else their in-repo copies (`tests/fixtures/`, a note says so); the
//! other tests read the copies, and `fixture_copies_equal_the_shared_originals` checks they
//! equal the shared originals (skipped, with a note, without `../shared`).

mod common;
use common::*;

use std::path::PathBuf;

use host_sim::io::compare::{compare, format_table};
use host_sim::io::recording::Channel;
use host_sim::plant::config::PlantConfig;
use host_sim::sim::{simulate, SolverOptions};
use host_sim::{Plant, Recording};

/// Whether the shared specification sits next to the repository (else a note is printed).
fn shared_present() -> bool {
    let here = shared().join("conformance").is_dir();
    if !here {
        println!(
            "note: {} not found: the in-repo copies (tests/fixtures/) are used and not compared \
             with the shared originals",
            shared().display()
        );
    }
    here
}

/// The folder of the conformance recordings and that of the plant files they name.
fn conformance_dirs() -> (PathBuf, PathBuf) {
    if shared_present() {
        (shared().join("conformance"), shared().join("plant"))
    } else {
        (fixture(""), fixture(""))
    }
}

fn conformance_files() -> Vec<PathBuf> {
    let (dir, _) = conformance_dirs();
    let entries = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("conformance fixtures not found at {} ({e})", dir.display()));
    let mut files: Vec<PathBuf> = entries
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "csv"))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "no .csv fixture in {}", dir.display());
    files
}

/// `key = number` in a metadata value (`... hA_w_per_k = 2.0 per muscle, kappa = 1.4, ...`).
fn meta_number(value: &str, key: &str) -> f64 {
    let at = value
        .find(key)
        .unwrap_or_else(|| panic!("`{key}` not in `{value}`"));
    let rest = value[at + key.len()..].trim_start();
    let rest = rest
        .strip_prefix('=')
        .unwrap_or_else(|| panic!("`{key} =` expected in `{value}`"))
        .trim_start();
    let end = rest
        .find(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-' || c == 'e'))
        .unwrap_or(rest.len());
    rest[..end]
        .parse()
        .unwrap_or_else(|e| panic!("`{key}` in `{value}`: {e}"))
}

/// The `[effects.thermal_chamber]` table a `# thermal = ...` header describes.
fn thermal_table(meta: &str) -> String {
    let h = meta_number(meta, "hA_w_per_k");
    let kappa = meta_number(meta, "kappa");
    assert!(
        meta.contains("293.15 K"),
        "wall temperature not the documented 293.15 K: `{meta}`"
    );
    format!("\n[effects.thermal_chamber]\nheat_transfer_w_per_k = {h:?}\nkappa = {kappa:?}\n")
}

/// Replays the fixture's inputs on the plant its metadata names (with the model options
/// it declares when `with_options`) and compares.
fn check(file: &PathBuf, opts: &SolverOptions, with_options: bool) -> Vec<(Channel, f64)> {
    let reference = Recording::read(file).unwrap_or_else(|e| panic!("{e}"));
    let plant_name = reference
        .meta("plant")
        .unwrap_or_else(|| panic!("{}: no `# plant = ...` metadata", file.display()));
    let plant_path = conformance_dirs().1.join(plant_name);
    let plant = match reference.meta("thermal") {
        Some(t) if with_options => {
            let mut text = std::fs::read_to_string(&plant_path).unwrap();
            text.push_str(&thermal_table(t));
            let cfg =
                PlantConfig::from_toml_str(&text, &plant_path).unwrap_or_else(|e| panic!("{e}"));
            Plant::from_config(&cfg)
        }
        _ => Plant::load(&plant_path).unwrap_or_else(|e| panic!("{e}")),
    };
    let sim = simulate(&plant, &reference.inputs, reference.sample_period_s(), opts)
        .unwrap_or_else(|e| panic!("{}: {e}", file.display()));
    let model =
        host_sim::io::replay_stream::replay_recording(&plant, &reference, &sim.states, Vec::new());
    let fits = compare(&reference, &model).unwrap();
    println!(
        "{} (plant {plant_name}, {} samples, {:?}):\n{}",
        file.file_name().unwrap().to_string_lossy(),
        reference.len(),
        sim.stats,
        format_table(&fits)
    );
    let present = Channel::ALL
        .into_iter()
        .filter(|c| reference.channel(*c).is_some())
        .count();
    assert_eq!(
        fits.len(),
        present,
        "every channel of the fixture is compared"
    );
    fits.iter().map(|f| (f.channel, f.fit_percent)).collect()
}

#[test]
fn every_fixture_is_reproduced_with_fit_at_least_99_5_percent() {
    let opts = SolverOptions::default();
    let mut failures = Vec::new();
    for file in conformance_files() {
        for (c, fit) in check(&file, &opts, true) {
            if fit.is_nan() || fit < 99.5 {
                failures.push(format!("{} {}: {fit:.4} %", file.display(), c.name()));
            }
        }
    }
    assert!(failures.is_empty(), "fit below 99.5 %: {failures:#?}");
}

#[test]
fn thermal_fixture_needs_the_chamber() {
    let opts = SolverOptions::default();
    let thermal: Vec<PathBuf> = conformance_files()
        .into_iter()
        .filter(|f| {
            Recording::read(f)
                .unwrap_or_else(|e| panic!("{e}"))
                .meta("thermal")
                .is_some()
        })
        .collect();
    assert!(!thermal.is_empty(), "no fixture declares `# thermal`");
    for file in &thermal {
        let fits = check(file, &opts, false);
        let worst = fits.iter().map(|(_, f)| *f).fold(f64::INFINITY, f64::min);
        println!(
            "{}: worst channel fit {worst:.2} % on the isothermal plant",
            file.display()
        );
        assert!(
            worst < 99.5,
            "{} is reproduced without the chamber (worst fit {worst:.3} %): it tests nothing",
            file.display()
        );
    }
}

/// The copies the other tests read (`tests/fixtures/README.md` lists where each came from)
/// are byte for byte the shared originals.
#[test]
fn fixture_copies_equal_the_shared_originals() {
    if !shared_present() {
        return;
    }
    let fixtures = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures");
    let copies = [
        (
            "../../plants/reference-1dof.toml",
            "plant/reference-1dof.toml",
        ),
        ("pwm_nominal.csv", "conformance/pwm_nominal.csv"),
        ("reference-1dof.toml", "plant/reference-1dof.toml"),
        (
            "reference-1dof-loaded.toml",
            "plant/reference-1dof-loaded.toml",
        ),
        ("pulses_nominal.csv", "conformance/pulses_nominal.csv"),
        ("pulses_loaded.csv", "conformance/pulses_loaded.csv"),
        ("pulses_thermal.csv", "conformance/pulses_thermal.csv"),
    ];
    let readme = std::fs::read_to_string(fixtures.join("README.md")).unwrap();
    for (copy, original) in copies {
        let a = std::fs::read(fixtures.join(copy)).unwrap_or_else(|e| panic!("{copy}: {e}"));
        let b = std::fs::read(shared().join(original))
            .unwrap_or_else(|e| panic!("../shared/{original}: {e}"));
        assert!(
            a == b,
            "tests/fixtures/{copy} differs from ../shared/{original}"
        );
        assert!(
            readme.contains(copy) && readme.contains(original),
            "README.md: {copy}"
        );
    }
}
