//! The command line of `discover`: its arguments, their checks, and the call of the library's
//! [`host_sim::diagnose::discover::discover`].

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Args;

use host_sim::validate;
use host_sim::Recording;

/// `host-sim discover`: the arguments.
#[derive(Args, Debug)]
#[command(
    after_help = "Example:\n  host-sim discover --plant host-sim/plants/reference-1dof.toml --recording train.csv --check check.csv --json discovery.json --write-plant discovered.toml\n\nSlots: joint, transmission, chamber_p1, chamber_p2, sensor_angle, sensor_p1, sensor_p2 (docs/diagnosis.md \"Discovering a missing term\")."
)]
pub struct DiscoverArgs {
    /// Nominal plant file (TOML) the user believes in (1-DOF).
    #[arg(long, value_name = "P.toml")]
    pub plant: PathBuf,
    /// Training recording (t_s,u_in1,u_ex1,u_in2,u_ex2 and the measured angle_deg,p1_kpa,
    /// p2_kpa; f1_n,f2_n used when present): the terms are fitted on its first 70 % and
    /// scored on the rest.
    #[arg(long, value_name = "R.csv")]
    pub recording: PathBuf,
    /// A recording of the same rig with another excitation: a term is kept only if it also
    /// improves this one.
    #[arg(long, value_name = "C.csv")]
    pub check: Option<PathBuf>,
    /// Write the answer as JSON (key "discovered": the term, or null).
    #[arg(long, value_name = "OUT.json")]
    pub json: Option<PathBuf>,
    /// Write the plant file with the discovered term as its [effects.discovered] table
    /// (only when a term is discovered).
    #[arg(long, value_name = "OUT.toml")]
    pub write_plant: Option<PathBuf>,
    /// Skip the comparison with the catalogue (effects and recalibrations): use when the
    /// diagnosis already answered `unexplained`.
    #[arg(long)]
    pub no_catalogue: bool,
    /// Worker threads.
    #[arg(long, default_value_t = 2, value_parser = host_sim::validate::usize_in(1, 256))]
    pub threads: usize,
}

/// The file outputs of `discover` and `diagnose` (`--json`, `--write-plant`) before the run:
/// no output is an input (named as the input before its content is judged) or another
/// output, and each may be replaced.
pub(super) fn check_outputs(
    inputs: &[(&str, &Path)],
    json: Option<&Path>,
    write_plant: Option<&Path>,
) -> Result<()> {
    let outputs: Vec<(&str, &Path)> = [("--json", json), ("--write-plant", write_plant)]
        .into_iter()
        .filter_map(|(flag, p)| Some((flag, p?)))
        .collect();
    validate::distinct_file_outputs(inputs, &outputs).map_err(anyhow::Error::msg)?;
    if let Some(p) = write_plant {
        validate::replaceable("--write-plant", p, validate::OutputKind::PLANT)
            .map_err(anyhow::Error::msg)?;
    }
    if let Some(j) = json {
        validate::replaceable("--json", j, validate::OutputKind::JSON)
            .map_err(anyhow::Error::msg)?;
    }
    Ok(())
}

/// The text of the plant file `--plant`; when the run is to write a discovered table into it
/// (`--write-plant`), refused if it has one already.
pub(super) fn plant_text_to_write(plant: &Path, write_plant: bool) -> Result<String> {
    let text =
        std::fs::read_to_string(plant).with_context(|| format!("--plant {}", plant.display()))?;
    if write_plant {
        host_sim::diagnose::discover::has_no_discovered_table(&text, plant)
            .map_err(|e| anyhow::anyhow!("--write-plant: {e}"))?;
    }
    Ok(text)
}

/// Runs `discover`: exit status 0 when a term is discovered, 3 when nothing is (the JSON is
/// written), 2 on bad input.
pub fn run(a: &DiscoverArgs) -> Result<ExitCode> {
    use host_sim::diagnose::discover::{discover, DiscoverOptions};
    let mut inputs: Vec<(&str, &Path)> = vec![("--plant", &a.plant), ("--recording", &a.recording)];
    if let Some(c) = &a.check {
        if validate::same_existing_file(c, &a.recording) {
            anyhow::bail!(
                "--check {}: is the same file as --recording {}; give a recording of the same rig \
                 with another excitation",
                c.display(),
                a.recording.display()
            );
        }
        inputs.push(("--check", c));
    }
    check_outputs(&inputs, a.json.as_deref(), a.write_plant.as_deref())?;
    let plant_text = plant_text_to_write(&a.plant, a.write_plant.is_some())?;
    let cfg = host_sim::PlantConfig::from_toml_str(&plant_text, &a.plant)?;
    let train = Recording::read(&a.recording)?;
    let check = a.check.as_ref().map(Recording::read).transpose()?;
    let opts = DiscoverOptions {
        threads: a.threads,
        catalogue_share: if a.no_catalogue {
            None
        } else {
            DiscoverOptions::default().catalogue_share
        },
        ..DiscoverOptions::default()
    };
    let d = discover(&cfg, &train, check.as_ref(), &opts)
        .with_context(|| format!("{}: discovery failed", a.recording.display()))?;
    use std::io::Write as _;
    let mut out = std::io::stdout().lock();
    let _ = write!(out, "{}", d.text());
    if let Some(j) = &a.json {
        let json = serde_json::to_string_pretty(&d.to_json())? + "\n";
        host_sim::identify::write_atomic(j, json.as_bytes())?;
        let _ = writeln!(out, "wrote {}", j.display());
    }
    if let (Some(p), Some(f)) = (&a.write_plant, &d.found) {
        let found_by = format!("`host-sim discover` on {}", a.recording.display());
        let text = host_sim::diagnose::discover::plant_text_with(
            &plant_text,
            &a.plant,
            &found_by,
            &f.table,
        )
        .map_err(|e| anyhow::anyhow!("--write-plant: {e}"))?;
        host_sim::identify::write_atomic(p, text.as_bytes())?;
        let _ = writeln!(out, "wrote {}", p.display());
    } else if let Some(p) = &a.write_plant {
        let _ = writeln!(out, "nothing discovered: {} not written", p.display());
    }
    Ok(if d.found.is_some() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(3)
    })
}
