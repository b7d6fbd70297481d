//! `host-sim capture`: the firmware's per-tick stream (`pam_firmware::stream::TickRecord`)
//! -> a RECORDING.md recording.
//!
//! The log is either
//! - the raw record bytes (what `host-sim pil --log` writes, what the QEMU image emits), or
//! - text with one record per line as `stream [165, 90, ...]` (decimal or `0x` bytes), which
//!   is what `defmt-print` prints for the board's `defmt::info!("stream {=[u8]}", bytes)`;
//!   with `--elf` a raw defmt log (e.g. saved RTT output) is first decoded by running
//!   `defmt-print -e ELF --log-format {s}` on it.
//!
//! Columns: `t_s` from the record's time stamp, the four applied openings, `angle_deg` and
//! `p1_kpa` / `p2_kpa` from the firmware's scaled values (what the controller saw). A lost
//! record (a jump in the sequence number), a missing sensor sample (NaN) or a time stamp that
//! does not increase is an error naming the record; nothing is interpolated. A record with a
//! latched fault is kept and counted.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use pam_firmware::stream::{scan_records, TickRecord, RECORD_LEN};

use crate::io::recording::{Channel, Recording};
use crate::plant::ValveInputs;

/// Arguments of `host-sim capture`.
#[derive(clap::Args, Debug)]
#[command(
    after_help = "Example (a stream written by `host-sim pil --log`):\n  host-sim capture --log pil.stream --out captured.csv"
)]
pub struct CaptureArgs {
    /// The firmware image that wrote the log (decodes a raw defmt log through defmt-print).
    #[arg(long, value_name = "ELF")]
    pub elf: Option<PathBuf>,
    /// The stream: raw records, `stream [..]` text lines, or (with --elf) a raw defmt log.
    #[arg(long, value_name = "LOG")]
    pub log: PathBuf,
    /// Output recording (RECORDING.md).
    #[arg(long, value_name = "REC.csv")]
    pub out: PathBuf,
}

/// Records in the raw bytes of a log, with their byte offsets.
pub fn records_of_bytes(bytes: &[u8]) -> (Vec<(usize, TickRecord)>, usize) {
    let mut v = Vec::new();
    let skipped = scan_records(bytes, |at, r| v.push((at, r)));
    (v, skipped)
}

/// Records in text lines `... stream [b0, b1, ...]`, with their line numbers (1-based).
pub fn records_of_text(text: &str, file: &Path) -> anyhow::Result<Vec<(usize, TickRecord)>> {
    let mut v = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let Some(p) = line.find("stream [") else {
            continue;
        };
        let rest = &line[p + "stream [".len()..];
        let Some(end) = rest.find(']') else {
            anyhow::bail!("{}:{}: `stream [` without `]`", file.display(), i + 1);
        };
        let mut bytes = Vec::with_capacity(RECORD_LEN);
        for tok in rest[..end].split(',') {
            let t = tok.trim();
            let b = match t.strip_prefix("0x") {
                Some(h) => u8::from_str_radix(h, 16),
                None => t.parse::<u8>(),
            }
            .map_err(|_| anyhow::anyhow!("{}:{}: {t:?} is not a byte", file.display(), i + 1))?;
            bytes.push(b);
        }
        let r = TickRecord::decode(&bytes).map_err(|e| {
            anyhow::anyhow!("{}:{}: not a stream record ({e:?})", file.display(), i + 1)
        })?;
        v.push((i + 1, r));
    }
    Ok(v)
}

/// What [`recording_of`] counted besides the samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CaptureCounts {
    /// Ticks with a latched fault (kept).
    pub faulted: usize,
    /// Records that repeat the one before byte for byte (a logger that read its buffer
    /// twice): dropped, nothing is lost.
    pub repeated: usize,
}

/// The records with byte-for-byte repeats of the one before removed, and how many were.
fn without_repeats(records: &[(usize, TickRecord)]) -> (Vec<(usize, TickRecord)>, usize) {
    let bytes = |r: &TickRecord| {
        let mut b = [0u8; RECORD_LEN];
        r.encode(&mut b);
        b
    };
    let mut kept: Vec<(usize, TickRecord)> = Vec::with_capacity(records.len());
    let mut repeated = 0;
    let mut last = None;
    for (at, r) in records {
        let b = bytes(r);
        if last == Some(b) {
            repeated += 1;
            continue;
        }
        last = Some(b);
        kept.push((*at, *r));
    }
    (kept, repeated)
}

/// The recording of a record sequence; `what` names a record's position for errors
/// (`byte 92`, `line 7`).
pub fn recording_of(
    records: &[(usize, TickRecord)],
    file: &Path,
    what: &str,
) -> anyhow::Result<(Recording, CaptureCounts)> {
    let (records, repeated) = without_repeats(records);
    let records = records.as_slice();
    if records.len() < 2 {
        anyhow::bail!(
            "{}: {} stream record(s); a recording needs at least 2",
            file.display(),
            records.len()
        );
    }
    let mut rec = Recording::default();
    let mut ch: [Vec<f64>; 3] = Default::default();
    let mut faulted = 0;
    for (i, (at, r)) in records.iter().enumerate() {
        if i > 0 {
            let prev = &records[i - 1].1;
            let ahead = r.seq.wrapping_sub(prev.seq);
            if ahead == 0 || ahead > u32::MAX / 2 {
                anyhow::bail!(
                    "{}: {what} {at}: sequence {} after {}: a record {} (not a byte-for-byte \
                     repeat); the log is not one run in order",
                    file.display(),
                    r.seq,
                    prev.seq,
                    if ahead == 0 {
                        "repeated with other content"
                    } else {
                        "out of order"
                    }
                );
            }
            if r.seq != prev.seq.wrapping_add(1) {
                anyhow::bail!(
                    "{}: {what} {at}: sequence {} after {}: {} record(s) lost (not \
                     interpolated; capture again with a larger RTT buffer or a lower rate)",
                    file.display(),
                    r.seq,
                    prev.seq,
                    r.seq.wrapping_sub(prev.seq).wrapping_sub(1)
                );
            }
            if r.t_us <= prev.t_us {
                anyhow::bail!(
                    "{}: {what} {at}: time {} us after {} us",
                    file.display(),
                    r.t_us,
                    prev.t_us
                );
            }
        }
        let vals = [
            ("angle", (r.angle_rad as f64).to_degrees()),
            ("p1", r.p_gauge_pa[0] as f64 * 1e-3),
            ("p2", r.p_gauge_pa[1] as f64 * 1e-3),
        ];
        for (c, (name, v)) in ch.iter_mut().zip(vals) {
            if !v.is_finite() {
                anyhow::bail!(
                    "{}: {what} {at} (sequence {}): no {name} sample (dropout or NaN); a \
                     missing sample is not filled",
                    file.display(),
                    r.seq
                );
            }
            c.push(v);
        }
        if r.fault != 0 {
            faulted += 1;
        }
        rec.t_s.push((r.t_us - records[0].1.t_us) as f64 * 1e-6);
        let u = |x: f32| x as f64;
        rec.inputs.push(ValveInputs {
            u_in1: u(r.openings[0]),
            u_ex1: u(r.openings[1]),
            u_in2: u(r.openings[2]),
            u_ex2: u(r.openings[3]),
        });
    }
    let [a, p1, p2] = ch;
    rec.set_channel(Channel::AngleDeg, a);
    rec.set_channel(Channel::P1Kpa, p1);
    rec.set_channel(Channel::P2Kpa, p2);
    rec.metadata = vec![
        (
            "source".into(),
            format!(
                "host-sim {} capture of {} (firmware per-tick stream, sequence {}..={})",
                env!("CARGO_PKG_VERSION"),
                file.display(),
                records[0].1.seq,
                records[records.len() - 1].1.seq
            ),
        ),
        (
            "sample_period_s".into(),
            format!("{}", rec.sample_period_s()),
        ),
        (
            "channels".into(),
            "angle_deg, p1_kpa, p2_kpa as the firmware scaled them".into(),
        ),
    ];
    Ok((rec, CaptureCounts { faulted, repeated }))
}

/// `host-sim capture`: returns the report printed on stdout.
pub fn run_capture(a: &CaptureArgs) -> anyhow::Result<String> {
    let mut inputs = vec![("--log", a.log.as_path())];
    if let Some(elf) = &a.elf {
        inputs.push(("--elf", elf.as_path()));
    }
    crate::validate::distinct_file_outputs(&inputs, &[("--out", &a.out)])
        .map_err(anyhow::Error::msg)?;
    if let Some(elf) = &a.elf {
        crate::control::pil::check_elf_for(
            elf,
            "give the firmware image that wrote the log: the board's or the QEMU image's ELF",
        )
        .map_err(|e| anyhow::anyhow!("--elf {}: {e}", elf.display()))?;
    }
    let bytes = std::fs::read(&a.log).map_err(|e| anyhow::anyhow!("{}: {e}", a.log.display()))?;
    let (raw, skipped) = records_of_bytes(&bytes);
    let (records, what, how) = if !raw.is_empty() {
        (
            raw,
            "byte",
            format!("raw records ({skipped} other bytes skipped)"),
        )
    } else {
        let text = match (&a.elf, std::str::from_utf8(&bytes)) {
            (_, Ok(t)) if t.contains("stream [") => t.to_string(),
            (Some(elf), _) => decode_defmt(elf, &a.log)?,
            (None, _) => anyhow::bail!(
                "{}: no stream records (neither raw records nor `stream [..]` lines); a raw \
                 defmt log needs --elf",
                a.log.display()
            ),
        };
        (
            records_of_text(&text, &a.log)?,
            "line",
            "text lines".to_string(),
        )
    };
    let (rec, counts) = recording_of(&records, &a.log, what)?;
    rec.write(&a.out)?;
    Ok(format!(
        "wrote {}: {} ticks from {how}, {} bytes per record, {:.0} bytes/s at the logged rate; \
         {} tick(s) with a latched fault; {} repeated record(s) dropped\n",
        a.out.display(),
        rec.len(),
        RECORD_LEN,
        RECORD_LEN as f64 / rec.sample_period_s(),
        counts.faulted,
        counts.repeated
    ))
}

/// Runs `defmt-print -e ELF --log-format {s}` on a raw defmt log.
fn decode_defmt(elf: &Path, log: &Path) -> anyhow::Result<String> {
    let input = std::fs::File::open(log).map_err(|e| anyhow::anyhow!("{}: {e}", log.display()))?;
    let out = Command::new("defmt-print")
        .arg("-e")
        .arg(elf)
        .args(["--log-format", "{s}"])
        .stdin(Stdio::from(input))
        .output()
        .map_err(|e| {
            anyhow::anyhow!("cannot run defmt-print: {e} (scripts/setup.sh installs it)")
        })?;
    if !out.status.success() {
        anyhow::bail!(
            "defmt-print -e {} failed on {}: {}",
            elf.display(),
            log.display(),
            // Its first lines: the cause, not a backtrace.
            String::from_utf8_lossy(&out.stderr)
                .lines()
                .take(3)
                .collect::<Vec<_>>()
                .join(" / ")
        );
    }
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}
