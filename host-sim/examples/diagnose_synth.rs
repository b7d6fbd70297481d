//! Writes synthetic TRAIN/CHECK recordings of the reference rig with concealed effects, for
//! trying `host-sim diagnose` by hand and for the speed benchmark:
//!
//! `cargo run --release -p host-sim --example diagnose_synth -- OUT_DIR [EFFECT[,EFFECT]] [--seconds S] [--dt S] [--seed N] [--no-force]`
//!
//! EFFECT is one of `host_sim::diagnose::synth::truth_names()` (none: the nominal rig). Writes
//! OUT_DIR/train.csv (valve pulses) and OUT_DIR/check.csv (chirp + steps).

use std::path::PathBuf;

use host_sim::diagnose::synth::{generate, plant_with, truth_names, Excitation, SynthSpec};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = format!(
        "usage: diagnose_synth OUT_DIR [EFFECT[,EFFECT]] [--seconds S] [--dt S] [--seed N] [--no-force]\n  effects: {}",
        truth_names().join(", ")
    );
    let mut positional = Vec::new();
    let (mut seconds, mut dt, mut seed, mut force) = (10.0, 1e-3, 1u64, true);
    let mut i = 0;
    while i < args.len() {
        let val = |i: usize| args.get(i + 1).ok_or_else(|| usage.clone());
        match args[i].as_str() {
            "--seconds" => {
                seconds = val(i)?.parse()?;
                i += 1
            }
            "--dt" => {
                dt = val(i)?.parse()?;
                i += 1
            }
            "--seed" => {
                seed = val(i)?.parse()?;
                i += 1
            }
            "--no-force" => force = false,
            a => positional.push(a.to_string()),
        }
        i += 1;
    }
    let out = PathBuf::from(positional.first().ok_or(usage.clone())?);
    let truths: Vec<&str> = positional
        .get(1)
        .map(|s| s.split(',').filter(|t| !t.is_empty()).collect())
        .unwrap_or_default();
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("plants/reference-1dof.toml");
    let cfg = plant_with(&std::fs::read_to_string(&root)?, &truths, dt)?;
    std::fs::create_dir_all(&out)?;
    let channels = [true, true, true, force, force];
    let label = if truths.is_empty() {
        "none".to_string()
    } else {
        truths.join("+")
    };
    for (name, excitation, s) in [
        ("train.csv", Excitation::Pulses, seed),
        ("check.csv", Excitation::ChirpSteps, seed + 1000),
    ] {
        let spec = SynthSpec {
            excitation,
            duration_s: seconds,
            dt_s: dt,
            seed: s,
            noise: true,
            channels,
        };
        let rec = generate(&cfg, &spec, &label)?;
        rec.write(out.join(name))?;
        println!(
            "wrote {} ({} samples, truth {label})",
            out.join(name).display(),
            rec.len()
        );
    }
    Ok(())
}
