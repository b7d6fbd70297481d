//! A run cut at its gaps into segments, each its own recording (`import --split`, `capture
//! --split`): their file names, the checks before writing, and the removal of an earlier
//! run's segments that this one no longer has.

use std::path::{Path, PathBuf};

use crate::io::recording::Recording;

/// Output path of segment `i` of `n`: `OUT` itself for one segment, else `OUT-1.csv`, ...
pub fn segment_path(out: &Path, i: usize, n: usize) -> PathBuf {
    if n == 1 {
        return out.to_owned();
    }
    let stem = super::file_stem_or(out, "");
    let ext = out
        .extension()
        .map(|s| format!(".{}", s.to_string_lossy()))
        .unwrap_or_default();
    out.with_file_name(format!("{stem}-{}{ext}", i + 1))
}

/// True when `path` is a recording `host-sim <command>` wrote (a leading comment line is the
/// `# source = host-sim <version> <command> of ...` metadata).
pub fn is_output_of(path: &Path, command: &str) -> bool {
    use std::io::{BufRead as _, Read as _};
    let Ok(f) = std::fs::File::open(path) else {
        return false;
    };
    // Among the leading comment lines (host-sim's mark comes first, `output`).
    std::io::BufReader::new(f.take(4096))
        .lines()
        .map_while(Result::ok)
        .take_while(|l| l.starts_with('#'))
        .any(|l| l.starts_with("# source = host-sim ") && l.contains(&format!(" {command} of ")))
}

/// Writes `segments` to their paths ([`segment_path`] of `out`), after checking that none is
/// one of `inputs` and that each reads back as a recording (nothing is written when one does
/// not). Returns one line per file (`describe(index, path, recording)`), then the report of the
/// stale segments: `OUT-k.csv` beyond this run's that an earlier `host-sim <command>` into the
/// same `OUT` wrote are removed (they would pass for part of this run); any other file of
/// such a name is named and left as it was.
pub fn write_segments(
    out: &Path,
    inputs: &[(&str, &Path)],
    segments: &[Recording],
    command: &str,
    describe: impl Fn(usize, &Path, &Recording) -> String,
) -> anyhow::Result<(String, String)> {
    use anyhow::Context as _;
    let n = segments.len();
    let paths: Vec<PathBuf> = (0..n).map(|i| segment_path(out, i, n)).collect();
    // Named as what they are: the user typed OUT, not OUT-2.csv.
    let labels: Vec<String> = (0..n)
        .map(|i| {
            if n == 1 {
                "--out".to_string()
            } else {
                format!("segment {} of --out {}:", i + 1, out.display())
            }
        })
        .collect();
    let outputs = crate::validate::labelled(&labels, &paths);
    crate::validate::distinct_file_outputs(inputs, &outputs).map_err(anyhow::Error::msg)?;
    if n == 1 {
        crate::validate::replaceable("--out", out, crate::validate::OutputKind::RECORDING)
            .map_err(anyhow::Error::msg)?;
    } else {
        // The user named OUT, not OUT-2.csv: a file of a segment's name that an earlier
        // `host-sim <command>` did not write is the user's, never replaced.
        for (i, p) in paths.iter().enumerate() {
            if p.exists() && !is_output_of(p, command) {
                anyhow::bail!(
                    "segment {} of --out {}: {} exists and was not written by host-sim \
                     {command}: refusing to replace it (this {command} has {n} segments, \
                     written as {} .. {}); move that file or give another --out",
                    i + 1,
                    out.display(),
                    p.display(),
                    segment_path(out, 0, n).display(),
                    segment_path(out, n - 1, n).display()
                );
            }
        }
    }
    for (rec, p) in segments.iter().zip(&paths) {
        let mut text = Vec::new();
        rec.write_to(&mut text)
            .with_context(|| p.display().to_string())?;
        Recording::parse(&String::from_utf8_lossy(&text), p)?;
    }
    let mut written = String::new();
    for (i, (rec, p)) in segments.iter().zip(&paths).enumerate() {
        rec.write(p)?;
        written += &describe(i, p, rec);
        written.push('\n');
    }
    let mut stale = String::new();
    // OUT itself, from an earlier run of one segment, when this one has several.
    if n > 1 && out.exists() {
        if is_output_of(out, command) {
            std::fs::remove_file(out)
                .with_context(|| format!("{}: cannot remove", out.display()))?;
            stale += &format!(
                "removed {}: an earlier {command} into it (this {command} has {n} segments, \
                 written as {} .. {})\n",
                out.display(),
                segment_path(out, 0, n).display(),
                segment_path(out, n - 1, n).display()
            );
        } else {
            stale += &format!(
                "note: {} is not part of this {command} ({n} segments) and not written by \
                 host-sim {command}: left as it was\n",
                out.display()
            );
        }
    }
    let first_stale = if n == 1 { 0 } else { n };
    let plural = if n == 1 { "" } else { "s" };
    for k in first_stale..first_stale + 1000 {
        let p = segment_path(out, k, n.max(2));
        if !p.exists() {
            break;
        }
        if is_output_of(&p, command) {
            std::fs::remove_file(&p).with_context(|| format!("{}: cannot remove", p.display()))?;
            stale += &format!(
                "removed {}: a segment of an earlier {command} into {} (this {command} has {n} \
                 segment{plural})\n",
                p.display(),
                out.display()
            );
        } else {
            stale += &format!(
                "note: {} is not part of this {command} ({n} segment{plural}) and not written \
                 by host-sim {command}: left as it was\n",
                p.display()
            );
        }
    }
    Ok((written, stale))
}
