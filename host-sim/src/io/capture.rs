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
//! `p1_kpa` / `p2_kpa` from the firmware's scaled values (what the controller saw). Nothing
//! is interpolated: a gap in the stream (a lost record, a record that does not decode, a
//! tick without a sensor sample, a restart of the firmware) is an error naming it, or with
//! `--split` the end of one segment of the run, each segment its own recording
//! ([`crate::io::segments`], as `import --split`). The 32-bit microsecond time stamp is
//! counted across its wrap (every 71.6 min); a time stamp that does not advance with the
//! sequence is always an error. Ticks with a
//! latched fault are kept (their openings are the safe state's, which the plant saw) and
//! named in the recording's metadata (`faulted`).

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use pam_firmware::safety::FaultCode;
use pam_firmware::stream::{scan_records, DecodeError, TickRecord, RECORD_LEN, RECORD_SYNC};

use crate::io::recording::{Channel, Recording};
use crate::plant::ValveInputs;

/// Arguments of `host-sim capture`.
#[derive(Debug)]
pub struct CaptureArgs {
    /// The firmware image that wrote the log (decodes a raw defmt log through defmt-print).
    pub elf: Option<PathBuf>,
    /// The stream: raw records, `stream [..]` text lines, or (with --elf) a raw defmt log.
    pub log: PathBuf,
    /// Output recording (RECORDING.md); with --split and gaps, one per segment: REC-1.csv,
    /// REC-2.csv, ...
    pub out: PathBuf,
    /// A gap in the stream (lost or corrupted records, a tick without a sensor sample, a
    /// restart of the firmware) ends one segment of the run instead of refusing the log:
    /// each segment of at least 2 ticks is written as its own recording (nothing is
    /// interpolated across a gap), as `import --split` does.
    pub split: bool,
}

/// Records in the raw bytes of a log, with their byte offsets.
pub fn records_of_bytes(bytes: &[u8]) -> (Vec<(usize, TickRecord)>, usize) {
    let mut v = Vec::new();
    let skipped = scan_records(bytes, |at, r| v.push((at, r)));
    (v, skipped)
}

/// The stream records of a text log and what did not decode.
#[derive(Debug, Default)]
pub struct TextRecords {
    /// Records with their line numbers (1-based).
    pub records: Vec<(usize, TickRecord)>,
    /// `stream [..]` lines that are not a record: line number and why.
    pub bad: Vec<(usize, String)>,
    /// The log ends inside its last `stream [` line (a log cut while being written): that
    /// line's number; the line is ignored.
    pub cut_last: Option<usize>,
}

/// Why a record does not decode, in words.
fn decode_error_words(e: DecodeError) -> &'static str {
    match e {
        DecodeError::Short => "fewer bytes than a record",
        DecodeError::Sync => "wrong sync bytes",
        DecodeError::Checksum => "checksum mismatch: a corrupted byte",
    }
}

/// Records in text lines `... stream [b0, b1, ...]`, with their line numbers (1-based).
pub fn records_of_text(text: &str) -> TextRecords {
    let mut out = TextRecords::default();
    let n_lines = text.lines().count();
    for (i, line) in text.lines().enumerate() {
        let Some(p) = line.find("stream [") else {
            continue;
        };
        let rest = &line[p + "stream [".len()..];
        let Some(end) = rest.find(']') else {
            if i + 1 == n_lines && !text.ends_with('\n') {
                out.cut_last = Some(i + 1);
            } else {
                out.bad.push((i + 1, "`stream [` without `]`".into()));
            }
            continue;
        };
        let mut bytes = Vec::with_capacity(RECORD_LEN);
        let mut not_byte = None;
        for tok in rest[..end].split(',') {
            let t = tok.trim();
            match match t.strip_prefix("0x") {
                Some(h) => u8::from_str_radix(h, 16),
                None => t.parse::<u8>(),
            } {
                Ok(b) => bytes.push(b),
                Err(_) => {
                    not_byte = Some(format!("{t:?} is not a byte"));
                    break;
                }
            }
        }
        if let Some(m) = not_byte {
            out.bad.push((i + 1, m));
            continue;
        }
        match TickRecord::decode(&bytes) {
            Ok(r) => out.records.push((i + 1, r)),
            Err(e) => out.bad.push((
                i + 1,
                format!("not a stream record ({})", decode_error_words(e)),
            )),
        }
    }
    out
}

/// What [`segments_of`] counted besides the samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CaptureCounts {
    /// Ticks with a latched fault (kept).
    pub faulted: usize,
    /// Records that repeat the one before byte for byte (a logger that read its buffer
    /// twice): dropped, nothing is lost.
    pub repeated: usize,
    /// Ticks without a sensor sample (split mode: dropped, each ends a segment).
    pub missing: usize,
    /// Ticks in segments too short to be a recording (split mode: fewer than 2 ticks).
    pub too_short: usize,
}

/// One segment of a captured run: its recording and how it ended.
#[derive(Debug)]
pub struct Segment {
    pub recording: Recording,
    /// First and last sequence number.
    pub seq: (u32, u32),
    /// The gap after it (`None`: the log's end).
    pub ended_by: Option<String>,
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

/// Where the records were found: raw bytes (positions are byte offsets) or text lines
/// (line numbers, with the lines that did not decode).
pub enum Positions<'a> {
    Bytes,
    Lines(&'a [(usize, String)]),
}

impl Positions<'_> {
    fn what(&self) -> &'static str {
        match self {
            Positions::Bytes => "byte",
            Positions::Lines(_) => "line",
        }
    }

    /// What lies between two consecutive records at `prev_at` and `at` that did not decode.
    fn between(&self, prev_at: usize, at: usize) -> Option<String> {
        match self {
            Positions::Bytes => {
                let n = at.saturating_sub(prev_at + RECORD_LEN);
                (n > 0).then(|| {
                    format!(
                        "{n} byte(s) between them do not decode: a corrupted record, not a \
                         lost one"
                    )
                })
            }
            Positions::Lines(bad) => {
                let inside: Vec<&(usize, String)> = bad
                    .iter()
                    .filter(|(l, _)| *l > prev_at && *l < at)
                    .collect();
                inside.first().map(|(l, why)| {
                    format!(
                        "line {l} between them is {why}{}",
                        if inside.len() > 1 {
                            format!(" (and {} more lines)", inside.len() - 1)
                        } else {
                            String::new()
                        }
                    )
                })
            }
        }
    }
}

/// The segments of a record sequence. Without `split` a gap is an error (one segment, the
/// whole run); with it each gap ends a segment, a restart of the firmware (its sequence
/// number going back) starts a new one, and segments shorter than 2 ticks are dropped
/// (counted). The firmware's 32-bit microsecond time stamp wraps every 71.6 min: time is
/// counted across the wrap. A time stamp that does not advance while the sequence does is
/// an error either way. Per record: its place after the one before ([`Segmenter::follow`]),
/// then its samples ([`Segmenter::take`]).
pub fn segments_of(
    records: &[(usize, TickRecord)],
    file: &Path,
    pos: &Positions<'_>,
    split: bool,
) -> anyhow::Result<(Vec<Segment>, CaptureCounts)> {
    let (records, repeated) = without_repeats(records);
    if let (false, Positions::Lines(bad)) = (split, pos) {
        if let Some((l, why)) = bad.first() {
            anyhow::bail!("{}:{l}: {why}; {SPLIT_HINT}", file.display());
        }
    }
    let mut s = Segmenter {
        file,
        pos,
        split,
        period_us: tick_period_us(&records),
        segments: Vec::new(),
        cur: Vec::new(),
        counts: CaptureCounts {
            repeated,
            ..CaptureCounts::default()
        },
    };
    let mut prev: Option<(usize, TickRecord, u64)> = None;
    for &(at, r) in &records {
        let t_us = match prev {
            Some(p) => s.follow(p, at, r)?,
            None => r.t_us as u64,
        };
        prev = Some((at, r, t_us));
        s.take(at, r, t_us)?;
    }
    s.close(None);
    if s.segments.is_empty() {
        anyhow::bail!(
            "{}: {} stream record(s){}; a recording needs at least 2 consecutive ticks with \
             every sensor sample",
            file.display(),
            records.len(),
            if s.counts.missing > 0 {
                format!(", {} without a sensor sample", s.counts.missing)
            } else {
                String::new()
            }
        );
    }
    Ok((s.segments, s.counts))
}

/// What a refusal for a gap suggests.
const SPLIT_HINT: &str = "capture with --split to write the segments between gaps as recordings";

/// The tick period [us]: the median time step between records of consecutive sequence
/// (steps of 0 or beyond half the stamp's range left out); `None` without any.
fn tick_period_us(records: &[(usize, TickRecord)]) -> Option<u32> {
    let mut steps: Vec<u32> = records
        .windows(2)
        .filter(|w| w[1].1.seq.wrapping_sub(w[0].1.seq) == 1)
        .map(|w| w[1].1.t_us.wrapping_sub(w[0].1.t_us))
        .filter(|d| *d > 0 && *d <= u32::MAX / 2)
        .collect();
    steps.sort_unstable();
    steps.get(steps.len() / 2).copied()
}

/// Cuts a record sequence into segments.
struct Segmenter<'a> {
    file: &'a Path,
    pos: &'a Positions<'a>,
    split: bool,
    period_us: Option<u32>,
    segments: Vec<Segment>,
    /// The segment being built: (position, record, time since the log's first record of this
    /// run [us], counted across the wrap of the 32-bit stamp).
    cur: Vec<(usize, TickRecord, u64)>,
    counts: CaptureCounts,
}

impl Segmenter<'_> {
    /// Ends the current segment (`ended_by` the gap after it): kept with at least 2 ticks,
    /// counted as too short otherwise.
    fn close(&mut self, ended_by: Option<String>) {
        if self.cur.len() >= 2 {
            self.segments
                .push(segment_of(&self.cur, self.file, ended_by));
        } else {
            self.counts.too_short += self.cur.len();
        }
        self.cur.clear();
    }

    /// Record `r` at `at` after `prev`: its time counted on from `prev`'s [us]. A repeated
    /// sequence with other content, or one going back without `split`, is refused; a restart
    /// (the sequence going back) ends the segment; a time stamp that does not advance is
    /// refused; a gap ([`gap_after`]) is refused without `split` and ends the segment with it.
    fn follow(
        &mut self,
        (prev_at, p, prev_t_us): (usize, TickRecord, u64),
        at: usize,
        r: TickRecord,
    ) -> anyhow::Result<u64> {
        let (file, what) = (self.file, self.pos.what());
        let ahead = r.seq.wrapping_sub(p.seq);
        let restarted = ahead > u32::MAX / 2;
        if ahead == 0 || (restarted && !self.split) {
            anyhow::bail!(
                "{}: {what} {at}: sequence {} after {}: a record {} (not a byte-for-byte \
                 repeat); the log is not one run in order{}",
                file.display(),
                r.seq,
                p.seq,
                if ahead == 0 {
                    "repeated with other content"
                } else {
                    "out of order"
                },
                if restarted {
                    " (a firmware that restarted: --split writes each run on its own)"
                } else {
                    ""
                }
            );
        }
        if restarted {
            self.close(Some(format!(
                "sequence {} after {}: the firmware restarted (a new run)",
                r.seq, p.seq
            )));
            return Ok(r.t_us as u64);
        }
        let dt_us = r.t_us.wrapping_sub(p.t_us);
        if dt_us == 0 || dt_us > u32::MAX / 2 {
            anyhow::bail!(
                "{}: {what} {at}: sequence {} after {} but time {} us after {} us: the \
                 time stamp does not advance with the sequence",
                file.display(),
                r.seq,
                p.seq,
                r.t_us,
                p.t_us
            );
        }
        let pos = self.pos;
        if let Some((g, ended_by)) = gap_after(&p, &r, self.period_us, || pos.between(prev_at, at))
        {
            if !self.split {
                anyhow::bail!(
                    "{}: {what} {at}: sequence {} after {}: {g}; nothing is \
                     interpolated: {SPLIT_HINT}",
                    file.display(),
                    r.seq,
                    p.seq
                );
            }
            self.close(Some(ended_by));
        }
        Ok(prev_t_us + dt_us as u64)
    }

    /// Adds record `r` to the current segment; a record without a sensor sample (dropout or
    /// NaN) is refused without `split`, and with it ends the segment (counted, left out).
    fn take(&mut self, at: usize, r: TickRecord, t_us: u64) -> anyhow::Result<()> {
        let missing = [
            ("angle", r.angle_rad),
            ("p1", r.p_gauge_pa[0]),
            ("p2", r.p_gauge_pa[1]),
        ]
        .into_iter()
        .find(|(_, v)| !v.is_finite());
        if let Some((name, _)) = missing {
            if !self.split {
                anyhow::bail!(
                    "{}: {} {at} (sequence {}): no {name} sample (dropout or NaN); a \
                     missing sample is not filled: {SPLIT_HINT}",
                    self.file.display(),
                    self.pos.what(),
                    r.seq
                );
            }
            self.counts.missing += 1;
            if !self.cur.is_empty() {
                self.close(Some(format!("sequence {}: no {name} sample", r.seq)));
            }
            return Ok(());
        }
        if r.fault != 0 {
            self.counts.faulted += 1;
        }
        self.cur.push((at, r, t_us));
        Ok(())
    }
}

/// The gap between consecutive records `p` and `r` (the sequence advanced, the time too):
/// (what it is, what ended the segment before it), `None` when there is none. Consecutive
/// ticks whose stamps are not within 0.5..1.5 tick periods apart: the clock jumped (or ticks
/// ran late), and a recording's time is uniform. A sequence that skips: records lost, or
/// (`between`: what lies between them) corrupted.
fn gap_after(
    p: &TickRecord,
    r: &TickRecord,
    period_us: Option<u32>,
    between: impl FnOnce() -> Option<String>,
) -> Option<(String, String)> {
    let ahead = r.seq.wrapping_sub(p.seq);
    let dt_us = r.t_us.wrapping_sub(p.t_us);
    let jumped = period_us.filter(|&per| {
        ahead == 1 && (dt_us as f64 > 1.5 * per as f64 || (dt_us as f64) < 0.5 * per as f64)
    });
    if let Some(per) = jumped {
        let g = format!(
            "the time stamp moves {dt_us} us between consecutive ticks (the tick \
             period is {per} us): the firmware's clock jumped or the tick ran late"
        );
        Some((
            g.clone(),
            format!("sequence {} after {}: {g}", r.seq, p.seq),
        ))
    } else if ahead != 1 {
        let n = ahead - 1;
        let g = match between() {
            Some(c) => format!("{n} record(s) missing; {c}"),
            None => format!(
                "{n} record(s) lost (capture again with a larger RTT buffer or a \
                 lower rate)"
            ),
        };
        let ended_by = format!(
            "sequence {}..={}: {g}",
            p.seq.wrapping_add(1),
            r.seq.wrapping_sub(1)
        );
        Some((g, ended_by))
    } else {
        None
    }
}

/// The recording of consecutive, complete records (with their times counted across the
/// stamp's wrap).
fn segment_of(
    records: &[(usize, TickRecord, u64)],
    file: &Path,
    ended_by: Option<String>,
) -> Segment {
    let mut rec = Recording::default();
    let mut ch: [Vec<f64>; 3] = Default::default();
    let t0_us = records[0].2;
    let mut first_fault: Option<(f64, u32, u8)> = None;
    let mut faulted = 0usize;
    let mut armed = 0usize;
    // Microseconds to seconds by a division: correctly rounded (0.798, not 0.7979999...).
    let s_of_us = |us: u64| us as f64 / 1e6;
    for (_, r, t_us) in records {
        let t_s = s_of_us(t_us - t0_us);
        ch[0].push((r.angle_rad as f64).to_degrees());
        ch[1].push(r.p_gauge_pa[0] as f64 * 1e-3);
        ch[2].push(r.p_gauge_pa[1] as f64 * 1e-3);
        if r.fault != 0 {
            faulted += 1;
            first_fault.get_or_insert((t_s, r.seq, r.fault));
        }
        armed += r.armed as usize;
        rec.t_s.push(t_s);
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
    let last = records.len() - 1;
    let seq = (records[0].1.seq, records[last].1.seq);
    // The period to the microsecond the firmware stamps (no float noise of the mean).
    let period_us = ((records[last].2 - t0_us) as f64 / last as f64).round() as u64;
    rec.metadata = vec![
        (
            "source".into(),
            format!(
                "host-sim {} capture of {} (firmware per-tick stream, sequence {}..={}, \
                 firmware time {} s at t_s = 0)",
                env!("CARGO_PKG_VERSION"),
                file.display(),
                seq.0,
                seq.1,
                s_of_us(records[0].1.t_us as u64)
            ),
        ),
        ("sample_period_s".into(), format!("{}", s_of_us(period_us))),
        (
            "channels".into(),
            "angle_deg, p1_kpa, p2_kpa as the firmware scaled them".into(),
        ),
        (
            "armed_ticks".into(),
            format!("{armed} of {}", records.len()),
        ),
    ];
    if let Some((t_s, s, code)) = first_fault {
        let name = FaultCode::from_code(code)
            .map(|c| format!("{c:?}"))
            .unwrap_or_else(|| format!("unknown code {code}"));
        rec.metadata.push((
            "faulted".into(),
            format!(
                "{faulted} tick(s) with a latched fault, the first at t_s = {t_s} (sequence \
                 {s}, {name}); their openings are the safe state's"
            ),
        ));
    }
    Segment {
        recording: rec,
        seq,
        ended_by,
    }
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
        check_elf_for(
            elf,
            "give the firmware image that wrote the log: the board's or the QEMU image's ELF",
        )
        .map_err(|e| anyhow::anyhow!("--elf {}: {e}", elf.display()))?;
    }
    let bytes = std::fs::read(&a.log).map_err(|e| anyhow::anyhow!("{}: {e}", a.log.display()))?;
    let (raw, skipped) = records_of_bytes(&bytes);
    let mut notes = Vec::new();
    let (segments, counts, how) = if !raw.is_empty() {
        // Bytes before the first record or after the last that do not decode: other output,
        // or a corrupted first / last record (its tick is then not in the recording).
        let lead = raw[0].0;
        let trail = bytes.len() - (raw[raw.len() - 1].0 + RECORD_LEN);
        for (n, where_, part) in [
            (lead, "before the first record", &bytes[..lead]),
            (
                trail,
                "after the last record",
                &bytes[bytes.len() - trail..],
            ),
        ] {
            if part.windows(2).any(|w| w == RECORD_SYNC) {
                notes.push(format!(
                    "{n} byte(s) {where_} do not decode but hold a record's sync bytes: a \
                     corrupted or cut record, its tick is not in the recording"
                ));
            }
        }
        let (s, c) = segments_of(&raw, &a.log, &Positions::Bytes, a.split)?;
        (s, c, format!("raw records ({skipped} other bytes skipped)"))
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
        let t = records_of_text(&text);
        if let Some(l) = t.cut_last {
            notes.push(format!(
                "line {l}, the log's last, is cut inside its record (a log cut while being \
                 written): ignored"
            ));
        }
        if let Some((l, why)) = t.bad.first() {
            if a.split {
                notes.push(format!(
                    "{} `stream [` line(s) do not decode (the first: line {l}, {why}); a gap \
                     where they stood between records",
                    t.bad.len()
                ));
            }
        }
        let (s, c) = segments_of(&t.records, &a.log, &Positions::Lines(&t.bad), a.split)?;
        (s, c, "text lines".to_string())
    };
    // A reading the recording format refuses is the log's (a record scaled by a wrong
    // board configuration, a corrupted field): named by its sequence number in the log, before
    // anything is written.
    for s in &segments {
        for c in crate::Channel::ALL {
            let Some(y) = s.recording.channel(c) else {
                continue;
            };
            if let Some((k, v)) = y.iter().enumerate().find(|(_, v)| !c.is_plausible(**v)) {
                anyhow::bail!(
                    "{}: record of sequence {}: {}: {} (the firmware's scaled reading; nothing \
                     written)",
                    a.log.display(),
                    s.seq.0.wrapping_add(k as u32),
                    c.name(),
                    c.implausible(*v)
                );
            }
        }
    }
    let recordings: Vec<Recording> = segments.iter().map(|s| s.recording.clone()).collect();
    let (written, stale) = crate::io::segments::write_segments(
        &a.out,
        &inputs,
        &recordings,
        "capture",
        |i, p, rec| {
            let s = &segments[i];
            format!(
                "wrote {}: {} ticks (sequence {}..={}), {} s{}",
                p.display(),
                rec.len(),
                s.seq.0,
                s.seq.1,
                rec.t_s.last().copied().unwrap_or(0.0),
                match &s.ended_by {
                    Some(g) => format!("; then a gap: {g}"),
                    None => String::new(),
                }
            )
        },
    )?;
    let mut report = written;
    let period_s = segments[0].recording.sample_period_s();
    report += &format!(
        "{} segment(s) from {how}, {} bytes per record, {:.0} bytes/s at the logged rate; {} \
         tick(s) with a latched fault (kept, named in each recording's `faulted` line); {} \
         repeated record(s) dropped",
        segments.len(),
        RECORD_LEN,
        RECORD_LEN as f64 / period_s,
        counts.faulted,
        counts.repeated
    );
    if a.split {
        report += &format!(
            "; {} tick(s) without a sensor sample dropped; {} tick(s) in segments shorter \
             than 2 ticks dropped",
            counts.missing, counts.too_short
        );
    }
    report.push('\n');
    report += &stale;
    for n in notes {
        report += &format!("note: {n}\n");
    }
    Ok(report)
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

/// [`check_elf`](crate::control::pil::check_elf) with `hint` (what the image should be) in place of the PIL image's build
/// command.
pub fn check_elf_for(elf: &std::path::Path, hint: &str) -> Result<(), String> {
    use std::io::Read;
    #[allow(non_snake_case)]
    let BUILD = hint;
    let meta = std::fs::metadata(elf).map_err(|e| format!("cannot read it: {e} ({BUILD})"))?;
    if !meta.is_file() {
        return Err("is not a regular file: give the firmware image (an ELF file)".into());
    }
    if meta.len() == 0 {
        return Err(format!("is empty, not a firmware image ({BUILD})"));
    }
    let mut head = Vec::with_capacity(20);
    std::fs::File::open(elf)
        .and_then(|f| f.take(20).read_to_end(&mut head))
        .map_err(|e| format!("cannot read it: {e}"))?;
    if !head.starts_with(b"\x7fELF") {
        return Err(format!(
            "is not an ELF file (it does not start with the ELF magic bytes) ({BUILD})"
        ));
    }
    // e_ident[EI_CLASS] = 1 (32-bit), e_ident[EI_DATA] = 1 (little endian), e_machine = 40
    // (EM_ARM) at byte 18.
    const EM_ARM: u16 = 40;
    let machine = (head.len() >= 20).then(|| u16::from_le_bytes([head[18], head[19]]));
    if head.get(4) != Some(&1) || head.get(5) != Some(&1) || machine != Some(EM_ARM) {
        let class = match head.get(4) {
            Some(1) => "32-bit",
            Some(2) => "64-bit",
            _ => "unknown class",
        };
        let data = match head.get(5) {
            Some(1) => "little-endian",
            Some(2) => "big-endian",
            _ => "unknown byte order",
        };
        let arch = match machine {
            Some(3) => "x86".to_string(),
            Some(40) => "ARM".to_string(),
            Some(62) => "x86-64".to_string(),
            Some(183) => "AArch64".to_string(),
            Some(243) => "RISC-V".to_string(),
            Some(m) => format!("machine {m}"),
            None => "no machine field".to_string(),
        };
        return Err(format!(
            "is a {class} {data} {arch} ELF file, not a 32-bit little-endian ARM (Cortex-M) \
             firmware image ({BUILD})"
        ));
    }
    elf32_layout_within(elf, meta.len())
        .map_err(|why| format!("is a truncated or damaged ELF file: {why} ({BUILD})"))
}

/// Checks that the program and section header tables of the 32-bit little-endian ELF file
/// `elf` (`len` bytes), and every loadable segment's bytes, lie within the file: a copy cut
/// short passes the header check and makes QEMU abort with a register dump.
fn elf32_layout_within(elf: &std::path::Path, len: u64) -> Result<(), String> {
    use std::io::{Read, Seek, SeekFrom};
    let mut f = std::fs::File::open(elf).map_err(|e| format!("cannot read it: {e}"))?;
    let mut read_at = |at: u64, n: usize| -> Result<Vec<u8>, String> {
        let mut b = vec![0u8; n];
        f.seek(SeekFrom::Start(at))
            .and_then(|_| f.read_exact(&mut b))
            .map_err(|_| format!("{n} bytes at offset {at} lie beyond its {len} bytes"))?;
        Ok(b)
    };
    let h = read_at(0, 52).map_err(|_| format!("its {len} bytes hold no complete ELF header"))?;
    let u16_at = |b: &[u8], i: usize| u64::from(u16::from_le_bytes([b[i], b[i + 1]]));
    let u32_at =
        |b: &[u8], i: usize| u64::from(u32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]));
    let (phoff, shoff) = (u32_at(&h, 28), u32_at(&h, 32));
    let (phentsize, phnum) = (u16_at(&h, 42), u16_at(&h, 44));
    let (shentsize, shnum) = (u16_at(&h, 46), u16_at(&h, 48));
    if phnum == 0 {
        return Err("it has no program headers (nothing to load)".into());
    }
    for (what, off, size, n) in [
        ("program header table", phoff, phentsize, phnum),
        ("section header table", shoff, shentsize, shnum),
    ] {
        if off + size * n > len {
            return Err(format!(
                "its {what} ends at byte {} of a {len}-byte file",
                off + size * n
            ));
        }
    }
    const PT_LOAD: u64 = 1;
    for i in 0..phnum {
        let ph = read_at(phoff + i * phentsize, 32)?;
        let (offset, filesz) = (u32_at(&ph, 4), u32_at(&ph, 16));
        if u32_at(&ph, 0) == PT_LOAD && offset + filesz > len {
            return Err(format!(
                "loadable segment {i} ends at byte {} of a {len}-byte file",
                offset + filesz
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(seq: u32, t_us: u32) -> TickRecord {
        TickRecord {
            seq,
            t_us,
            setpoint_rad: 0.0,
            openings: [0.0; 4],
            p_counts: [0; 2],
            encoder_counts: 0,
            p_gauge_pa: [0.0; 2],
            angle_rad: 0.0,
            fault: 0,
            armed: true,
        }
    }

    #[test]
    fn the_tick_period_is_the_median_step_of_consecutive_sequence_numbers() {
        let records: Vec<(usize, TickRecord)> =
            [(1, 0), (2, 1000), (3, 2000), (7, 9000), (8, 10_100)]
                .iter()
                .enumerate()
                .map(|(k, &(seq, t))| (k, record(seq, t)))
                .collect();
        // Steps of consecutive records: 1000, 1000, 1100 (the skip 3 -> 7 left out).
        assert_eq!(tick_period_us(&records), Some(1000));
        assert_eq!(tick_period_us(&records[..1]), None);
    }

    #[test]
    fn a_gap_is_a_skipped_sequence_or_a_step_outside_half_to_one_and_a_half_periods() {
        let p = record(10, 50_000);
        let none = || None;
        assert!(gap_after(&p, &record(11, 51_000), Some(1000), none).is_none());
        assert!(gap_after(&p, &record(11, 51_400), Some(1000), none).is_none());
        let (late, ended_by) = gap_after(&p, &record(11, 51_600), Some(1000), none).unwrap();
        assert!(late.contains("1600 us"), "{late}");
        assert!(ended_by.starts_with("sequence 11 after 10"), "{ended_by}");
        let (lost, ended_by) = gap_after(&p, &record(13, 53_000), Some(1000), none).unwrap();
        assert!(lost.starts_with("2 record(s) lost"), "{lost}");
        assert!(ended_by.starts_with("sequence 11..=12"), "{ended_by}");
        let (bad, _) = gap_after(&p, &record(12, 52_000), Some(1000), || {
            Some("corrupt".into())
        })
        .unwrap();
        assert_eq!(bad, "1 record(s) missing; corrupt");
    }
}
