//! Batch diagnosis: every recording (`*.csv`) of a directory against one nominal plant, in
//! parallel (rayon; one recording per worker, each diagnosis single-threaded), one JSON per
//! recording and a summary table. A recording that cannot be diagnosed is listed in the
//! summary with its error; the others are still written.

use std::io::Read as _;
use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::{diagnose, DiagnoseOptions};
use crate::{PlantConfig, Recording};

/// The outcome for one recording.
#[derive(Debug, Clone)]
pub struct BatchRow {
    /// The recording.
    pub recording: PathBuf,
    /// Samples in it (0 if it could not be read).
    pub samples: usize,
    /// The diagnosis JSON, or the error.
    pub result: Result<BatchDiagnosis, String>,
}

/// What the summary shows of one diagnosis.
#[derive(Debug, Clone)]
pub struct BatchDiagnosis {
    /// Pretty JSON (as `diagnose --json` writes it).
    pub json: String,
    /// The verdict (`explained`, `partly_explained`, `nothing_missing`, `unexplained`,
    /// `not_this_plant`).
    pub verdict: &'static str,
    /// Labels of the named effects, then `recalibrate KEY` for each recalibrated key.
    pub effects: Vec<String>,
    /// Lowest channel fit before / after the named effects [%].
    pub worst_fit_before_pct: f64,
    /// After.
    pub worst_fit_after_pct: f64,
    /// Wall time [s].
    pub wall_s: f64,
}

/// The `*.csv` entries of `dir`, sorted by name: every one, also a symbolic link that leads
/// nowhere or a directory named `*.csv`, so that each is a row of the summary (one that
/// cannot be read fails there with its cause) instead of being skipped unsaid.
pub fn recordings_in(dir: &Path) -> std::io::Result<Vec<PathBuf>> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("csv")))
        .filter(|p| {
            !p.file_name()
                .is_some_and(|n| crate::output::is_temp_name(&n.to_string_lossy()))
        })
        .collect();
    v.sort();
    Ok(v)
}

/// The JSON file of `recording` in `out_dir`: `out_dir/<stem>.json`.
pub fn json_path(out_dir: &Path, recording: &Path) -> PathBuf {
    let stem = crate::io::file_stem_or(recording, "recording");
    out_dir.join(format!("{stem}.json"))
}

/// Diagnoses every recording on `jobs` worker threads; rows in the order of `recordings`.
/// `done` is called (from the workers) after each recording.
pub fn diagnose_all(
    nominal: &PlantConfig,
    recordings: &[PathBuf],
    opts: &DiagnoseOptions,
    jobs: usize,
    done: &(dyn Fn(&Path) + Sync),
) -> Result<Vec<BatchRow>, String> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(jobs.max(1))
        .build()
        .map_err(|e| format!("cannot start {jobs} worker threads: {e}"))?;
    let one = DiagnoseOptions {
        threads: 1,
        ..opts.clone()
    };
    Ok(pool.install(|| {
        recordings
            .par_iter()
            .map(|path| {
                let row = diagnose_one(nominal, path, &one);
                done(path);
                row
            })
            .collect()
    }))
}

fn diagnose_one(nominal: &PlantConfig, path: &Path, opts: &DiagnoseOptions) -> BatchRow {
    let t0 = std::time::Instant::now();
    let rec = match Recording::read(path) {
        Ok(r) => r,
        Err(e) => {
            return BatchRow {
                recording: path.to_owned(),
                samples: 0,
                result: Err(e.to_string()),
            }
        }
    };
    let samples = rec.len();
    let result = diagnose(nominal, &rec, None, opts, &|_, _, _| {})
        .map_err(|e| format!("{}: diagnosis failed: {e}", path.display()))
        .and_then(|d| {
            let json = serde_json::to_string_pretty(&d.to_json())
                .map_err(|e| format!("{}: {e}", path.display()))?
                + "\n";
            let worst = |m: &std::collections::BTreeMap<&'static str, f64>| {
                m.values().copied().fold(f64::INFINITY, f64::min)
            };
            Ok(BatchDiagnosis {
                json,
                verdict: d.verdict.as_str(),
                effects: d
                    .effects
                    .iter()
                    .map(|e| e.label.clone())
                    .chain(
                        d.recalibrated
                            .iter()
                            .map(|r| format!("recalibrate {}", r.key)),
                    )
                    .collect(),
                worst_fit_before_pct: worst(&d.fit_before),
                worst_fit_after_pct: worst(&d.fit_after),
                wall_s: t0.elapsed().as_secs_f64(),
            })
        });
    BatchRow {
        recording: path.to_owned(),
        samples,
        result,
    }
}

impl BatchRow {
    /// The recording's file name.
    fn name(&self) -> String {
        self.recording
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    }
}

/// The summary as CSV (`recording,samples,verdict,effects,worst_fit_before_pct,
/// worst_fit_after_pct,wall_s`; `effects` joins the named effects and `recalibrate KEY` with
/// `+`). Written by the `csv` crate: a field with a comma, a quote or a line break (a
/// recording named `run 1, left.csv`, an error message) is quoted as RFC 4180 says, so every
/// row has the header's seven fields; an error is kept on one line.
pub fn summary_csv(rows: &[BatchRow]) -> String {
    let mut w = csv::WriterBuilder::new()
        .terminator(csv::Terminator::Any(b'\n'))
        .from_writer(Vec::new());
    let mut row = |fields: &[&str]| {
        w.write_record(fields)
            .expect("writing CSV into memory cannot fail")
    };
    row(&SUMMARY_HEADER.split(',').collect::<Vec<_>>());
    for r in rows {
        let (name, samples) = (r.name(), r.samples.to_string());
        match &r.result {
            Ok(d) => row(&[
                &name,
                &samples,
                d.verdict,
                &d.effects.join("+"),
                &format!("{:.2}", d.worst_fit_before_pct),
                &format!("{:.2}", d.worst_fit_after_pct),
                &format!("{:.2}", d.wall_s),
            ]),
            Err(e) => row(&[
                &name,
                &samples,
                &format!("error: {}", e.replace('\n', " ")),
                "",
                "",
                "",
                "",
            ]),
        }
    }
    String::from_utf8(w.into_inner().expect("an in-memory writer flushes"))
        .expect("the fields are UTF-8")
}

/// The summary as an aligned table for the terminal.
pub fn summary_table(rows: &[BatchRow]) -> String {
    let w = rows
        .iter()
        .map(|r| r.recording.file_name().map_or(0, |n| n.len()))
        .max()
        .unwrap_or(9)
        .max(9);
    let head = format!(
        "{:<w$}  {:>8}  {:<14}  {:>12}  {:>11}  effects\n",
        "recording", "samples", "verdict", "worst fit %", "after %"
    );
    let lines: String = rows
        .iter()
        .map(|r| {
            let (name, samples) = (r.name(), r.samples);
            match &r.result {
                Ok(d) => {
                    let effects = if d.effects.is_empty() {
                        "-".to_string()
                    } else {
                        d.effects.join(", ")
                    };
                    format!(
                        "{name:<w$}  {samples:>8}  {:<14}  {:>12.2}  {:>11.2}  {effects}\n",
                        d.verdict, d.worst_fit_before_pct, d.worst_fit_after_pct
                    )
                }
                Err(e) => format!("{name:<w$}  {samples:>8}  error           {e}\n"),
            }
        })
        .collect();
    head + &lines
}

/// `host-sim diagnose-batch`: the arguments.
#[derive(Debug)]
pub struct BatchArgs {
    /// Nominal plant file (TOML) the user believes in.
    pub plant: PathBuf,
    /// Directory of recordings (every `*.csv` in it, RECORDING.md columns t_s, u_in1, u_ex1,
    /// u_in2, u_ex2, angle_deg, p1_kpa, p2_kpa[, f1_n, f2_n]).
    pub recordings: PathBuf,
    /// Output directory (created if missing): one `<recording>.json` each and `summary.csv`;
    /// it may be --recordings itself (an earlier run's summary.csv there is not read as a
    /// recording).
    pub out_dir: PathBuf,
    /// Recordings diagnosed at once (worker threads).
    pub jobs: usize,
}

/// Runs the batch: writes the JSON files and the summary (atomically, through the run's
/// transaction); returns the summary table and the exit status ([`exit_status`]).
pub fn run_batch(a: &BatchArgs) -> anyhow::Result<(String, u8)> {
    use anyhow::Context as _;
    crate::validate::output_dir("--out-dir", &a.out_dir).map_err(anyhow::Error::msg)?;
    let cfg = PlantConfig::load(&a.plant)?;
    let mut recs = recordings_in(&a.recordings)
        .with_context(|| format!("--recordings {}", a.recordings.display()))?;
    // With --out-dir equal to --recordings, an earlier run's summary.csv is listed too: it
    // is this command's output (its header says so), not a recording. A user's recording
    // named summary.csv is kept (and refused below as an output that is an input).
    // A summary an earlier run left in --recordings with another --out-dir is no recording
    // either: skipped, and said so on stderr.
    let own_summary = a.out_dir.join(SUMMARY_FILE);
    recs.retain(|r| {
        if is_firmware_trace(r) {
            eprintln!(
                "note: {}: the firmware trace of a host-sim simulate run (its set-point, torque \
                 estimate and fault code per tick), not a recording: skipped",
                r.display()
            );
            return false;
        }
        if !is_batch_summary(r) {
            return true;
        }
        if !crate::validate::same_existing_file(r, &own_summary) {
            eprintln!(
                "note: {}: the summary of an earlier diagnose-batch, not a recording: skipped",
                r.display()
            );
        }
        false
    });
    if recs.is_empty() {
        anyhow::bail!(
            "--recordings {}: no *.csv file in it",
            a.recordings.display()
        );
    }
    // Two recordings with the same stem would write the same JSON.
    let mut jsons: Vec<PathBuf> = recs.iter().map(|r| json_path(&a.out_dir, r)).collect();
    jsons.push(own_summary.clone());
    // Each output named by what it is for (two recordings whose names differ only in case
    // or extension share a JSON: the message names both).
    let labels: Vec<String> = recs
        .iter()
        .map(|r| format!("the JSON of {}", r.display()))
        .chain(std::iter::once("the summary".to_string()))
        .collect();
    let outs = crate::validate::labelled(&labels, &jsons);
    let ins: Vec<(&str, &Path)> = std::iter::once(("--plant", a.plant.as_path()))
        .chain(recs.iter().map(|p| ("--recordings", p.as_path())))
        .collect();
    crate::validate::distinct_outputs(&ins, &outs).map_err(anyhow::Error::msg)?;
    crate::output::check_dir("--out-dir", &a.out_dir, &jsons).map_err(anyhow::Error::msg)?;
    let n = recs.len();
    let count = std::sync::atomic::AtomicUsize::new(0);
    let rows = diagnose_all(&cfg, &recs, &DiagnoseOptions::default(), a.jobs, &|p| {
        let k = count.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
        eprintln!("[{k}/{n}] {}", p.display());
    })
    .map_err(anyhow::Error::msg)?;
    crate::io::atomic::create_dir_all(&a.out_dir)
        .with_context(|| format!("{}: cannot create the directory", a.out_dir.display()))?;
    crate::io::atomic::write_manifest(&a.out_dir, &jsons)?;
    let mut removed = String::new();
    for r in &rows {
        let p = json_path(&a.out_dir, &r.recording);
        match &r.result {
            Ok(d) => crate::io::atomic::write_bytes(&p, d.json.as_bytes())
                .with_context(|| format!("{}", p.display()))?,
            // An earlier run's answer for a recording that now fails would read as this
            // run's: removed (only a diagnosis JSON, this command's own output).
            Err(_) => {
                if is_diagnosis_json(&p) && crate::output::is_own(&p) {
                    std::fs::remove_file(&p).with_context(|| format!("{}", p.display()))?;
                    removed += &format!(
                        "removed {}: an earlier run's answer for a recording that now fails\n",
                        p.display()
                    );
                }
            }
        }
    }
    // Answers of an earlier batch for recordings no longer in --recordings would read as
    // this batch's: named (left in place; the summary does not list them).
    let ours: Vec<PathBuf> = rows
        .iter()
        .map(|r| json_path(&a.out_dir, &r.recording))
        .collect();
    let mut earlier: Vec<PathBuf> = std::fs::read_dir(&a.out_dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "json") && !ours.contains(p))
        // The run's own temporary files (`.NAME.json.PID.XXXXXX.tmp.json`) are no answers.
        .filter(|p| {
            !p.file_name()
                .is_some_and(|n| crate::output::is_temp_name(&n.to_string_lossy()))
        })
        .filter(|p| is_diagnosis_json(p))
        .collect();
    earlier.sort();
    for p in &earlier {
        removed += &format!(
            "note: {} is an earlier batch's answer for a recording not in this batch (not in \
             the summary; left as it is)\n",
            p.display()
        );
    }
    let summary = own_summary;
    // Unmarked (a table for spreadsheets): the folder's manifest lists it.
    crate::io::atomic::write_bytes_unmarked(&summary, summary_csv(&rows).as_bytes())
        .with_context(|| format!("{}", summary.display()))?;
    Ok((
        format!(
            "{}{removed}wrote {} JSON files and {}\n",
            summary_table(&rows),
            rows.iter().filter(|r| r.result.is_ok()).count(),
            summary.display()
        ),
        exit_status(&rows),
    ))
}

/// The batch's exit status, the worst over its recordings: 1 if one could not be diagnosed
/// (its error is in the summary), else 3 if one is `unexplained` or `not_this_plant` (as
/// `diagnose` exits 3 on them), else 4 if one is `partly_explained`, else 0.
pub fn exit_status(rows: &[BatchRow]) -> u8 {
    if rows.iter().any(|r| r.result.is_err()) {
        1
    } else if rows.iter().any(|r| {
        matches!(
            &r.result,
            Ok(d) if !matches!(d.verdict, "explained" | "nothing_missing" | "partly_explained")
        )
    }) {
        3
    } else if rows
        .iter()
        .any(|r| matches!(&r.result, Ok(d) if d.verdict == "partly_explained"))
    {
        4
    } else {
        0
    }
}

/// The name of the batch's summary in `--out-dir`.
pub const SUMMARY_FILE: &str = "summary.csv";

/// The first line of [`summary_csv`].
const SUMMARY_HEADER: &str =
    "recording,samples,verdict,effects,worst_fit_before_pct,worst_fit_after_pct,wall_s";

/// Whether `path` holds a diagnosis JSON (this command's own output, as `diagnose --json`
/// writes it): the only kind of file the batch removes or names as an earlier answer.
fn is_diagnosis_json(path: &Path) -> bool {
    std::fs::read_to_string(path)
        .is_ok_and(|t| t.trim_start().starts_with('{') && t.contains("\"verdict\""))
}

/// Whether `path` is a summary this command wrote (its first line is the summary's header).
fn is_batch_summary(path: &Path) -> bool {
    header_line(path).is_some_and(|h| h == SUMMARY_HEADER)
}

/// True when `path` is the firmware trace `simulate --scenario` writes beside its recording
/// (`OUT.firmware.csv`: set-point, torque estimate, fault code per tick), by its header.
fn is_firmware_trace(path: &Path) -> bool {
    header_line(path).is_some_and(|h| h == crate::control::run_files::FIRMWARE_COLUMNS.join(","))
}

/// The first line of `path` that is not a `#` comment (within its first 64 KiB), without its
/// line end; `None` when it cannot be read.
fn header_line(path: &Path) -> Option<String> {
    use std::io::BufRead as _;
    let f = std::fs::File::open(path).ok()?;
    std::io::BufReader::new(f)
        .take(64 * 1024)
        .lines()
        .map_while(Result::ok)
        .find(|l| !l.starts_with('#'))
        .map(|l| l.trim_end().to_string())
}
