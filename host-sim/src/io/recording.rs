//! Recordings: the CSV format of `shared/plant/RECORDING.md`, read and written with `csv`.
//!
//! - leading comment lines `# key = value` are metadata, kept in order (unknown keys too);
//! - one header line, columns by name in any order;
//! - required: `t_s` (increasing; uniform steps or stamps that jitter by less than half a
//!   median step, see [`Recording::is_uniform`]; a few short gaps of dropped rows are
//!   accepted and filled by [`Recording::to_uniform`], see `io/timebase.rs`; a longer
//!   one is refused), `u_in1`, `u_ex1`,
//!   `u_in2`, `u_ex2` (in [0, 1]) and at least one of `angle_deg`, `p1_kpa`, `p2_kpa`,
//!   `f1_n`, `f2_n`; optional `m_dot_1_kg_s`, `m_dot_2_kg_s` (both or neither: the net mass
//!   flow into each muscle, a flow sensor's reading on a rig, the plant's true flow in
//!   host-sim's recordings); other columns are ignored.
//!
//! Every error names the file, the line and the field. Writing goes to a temporary file in
//! the target directory that is renamed over the target only when complete.

use std::io::{Read as _, Write};
use std::path::{Path, PathBuf};

use crate::io::numfmt;
use crate::plant::ValveInputs;

/// The warning for a recording whose `# plant` metadata names another plant file (by file
/// name) than `plant_path`, the one a command is given; `None` when it names the same one or
/// none.
pub fn other_plant_warning(
    metadata: &[(String, String)],
    plant_path: &Path,
    recording_path: &Path,
    doing: &str,
) -> Option<String> {
    let (_, named) = metadata.iter().find(|(k, _)| k == "plant")?;
    let given = plant_path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned());
    (given.as_deref() != Path::new(named).file_name().and_then(|n| n.to_str())).then(|| {
        format!(
            "warning: {} was recorded on plant `{named}`, {doing} {}",
            recording_path.display(),
            plant_path.display()
        )
    })
}

/// What a recording's metadata says when its valve columns hold no openings: `sweep torque`
/// writes them as 0 (its motion is prescribed, its pressures held by regulators) and says so
/// in its `# source`.
pub const VALVE_COLUMNS_UNUSED: &str = "valve columns unused";

/// The warning for a replay of `recording_path` whose metadata marks its valve columns unused
/// ([`VALVE_COLUMNS_UNUSED`]); `None` when none does. RECORDING.md has the four columns as
/// required openings and no way to leave them out, so they are replayed as recorded: the
/// warning names them, the metadata line (read again from the file's head) and what to replay
/// instead.
pub fn unused_valve_columns_warning(
    metadata: &[(String, String)],
    recording_path: &Path,
) -> Option<String> {
    let i = metadata
        .iter()
        .position(|(_, v)| v.contains(VALVE_COLUMNS_UNUSED))?;
    let line = {
        let mut head = Vec::new();
        std::fs::File::open(recording_path)
            .and_then(|f| f.take(64 * 1024).read_to_end(&mut head))
            .ok()
            .and_then(|_| {
                Preamble::of(&String::from_utf8_lossy(&head))
                    .meta_line_of
                    .get(i)
                    .copied()
            })
    };
    let key = match metadata[i].0.as_str() {
        "" => "#".to_owned(),
        k => format!("# {k}"),
    };
    Some(format!(
        "warning: {}{}: `{key}` marks the valve columns unused: {} are replayed as recorded, \
         so the simulation does not reproduce the recorded motion and pressures (a recording \
         with prescribed motion and regulator-held pressures, as `sweep torque` writes); \
         replay a recording of the valve openings that drove the joint",
        recording_path.display(),
        line.map(|l| format!(":{l}")).unwrap_or_default(),
        INPUT_COLUMNS.join(", ")
    ))
}

pub use crate::plant::channel::{Channel, P_KPA_PLAUSIBLE};

/// The net mass flow a `m_dot_*_kg_s` reading may have [kg/s] (a large valve passes about
/// 0.05 kg/s).
pub const MASS_FLOW_RANGE_KG_S: (f64, f64) = (-10.0, 10.0);

/// Median time step of a recording a PAM joint can be studied from: 100 kHz .. 10 Hz [s].
pub const STEP_RANGE_S: crate::validate::Range = crate::validate::Range::closed(1e-5, 0.1);

pub use crate::io::grid::{MAX_STEP_RATIO, MIN_STEP_RATIO};
/// Steps within this share of the median step (and stamps within it of the uniform grid)
/// count as uniform: such a recording is used as it is.
pub const UNIFORM_TOLERANCE: f64 = 0.01;

/// The optional mass-flow columns (muscle 1, muscle 2) [kg/s].
pub const MASS_FLOW_COLUMNS: [&str; 2] = ["m_dot_1_kg_s", "m_dot_2_kg_s"];

/// The input columns, in the order of [`ValveInputs`].
pub const INPUT_COLUMNS: [&str; 4] = ["u_in1", "u_ex1", "u_in2", "u_ex2"];

/// One recording (one run).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Recording {
    /// `# key = value` lines in file order (a comment without `=` has an empty key).
    pub metadata: Vec<(String, String)>,
    pub t_s: Vec<f64>,
    pub inputs: Vec<ValveInputs>,
    /// Output channels present, indexed by [`Channel::index`].
    pub outputs: [Option<Vec<f64>>; 5],
    /// Net mass flow into muscle 1 and 2 at `t_s` with the openings of the sample [kg/s]
    /// (columns [`MASS_FLOW_COLUMNS`]), when recorded.
    pub mass_flow_kg_s: Option<[Vec<f64>; 2]>,
}

/// A recording that could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}:{line}: field `{field}`: {message}", path.display())]
    Field {
        path: PathBuf,
        line: u64,
        field: String,
        message: String,
    },
    #[error("{}:{line}: {message}", path.display())]
    Line {
        path: PathBuf,
        line: u64,
        message: String,
    },
    #[error("{}: {message}", path.display())]
    Invalid { path: PathBuf, message: String },
}

impl Recording {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t_s.len()
    }

    pub fn is_empty(&self) -> bool {
        self.t_s.is_empty()
    }

    /// Uniform sample period, from the first and last time stamps.
    pub fn sample_period_s(&self) -> f64 {
        mean_step_s(&self.t_s)
    }

    /// Whether the time stamps are uniform (each step within [`UNIFORM_TOLERANCE`] of the
    /// median step, each stamp within it of the uniform grid from the first to the last).
    /// A jittered recording is not: [`crate::io::replay_stream::simulate_recording`] integrates it between
    /// its own stamps, and the tools that need a uniform grid take [`Self::to_uniform`].
    pub fn is_uniform(&self) -> bool {
        stamps_uniform(&self.t_s)
    }

    pub fn channel(&self, c: Channel) -> Option<&[f64]> {
        self.outputs[c.index()].as_deref()
    }

    pub fn set_channel(&mut self, c: Channel, values: Vec<f64>) {
        self.outputs[c.index()] = Some(values);
    }

    /// A copy of the first `n` samples (all of them if there are fewer).
    pub fn head(&self, n: usize) -> Recording {
        let n = n.min(self.len());
        Recording {
            metadata: self.metadata.clone(),
            t_s: self.t_s[..n].to_vec(),
            inputs: self.inputs[..n].to_vec(),
            outputs: std::array::from_fn(|i| self.outputs[i].as_ref().map(|y| y[..n].to_vec())),
            mass_flow_kg_s: self
                .mass_flow_kg_s
                .as_ref()
                .map(|m| [m[0][..n].to_vec(), m[1][..n].to_vec()]),
        }
    }

    /// The value of a metadata key, if present.
    pub fn meta(&self, key: &str) -> Option<&str> {
        self.metadata
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }

    /// Parses recording text; `path` is used in error messages.
    pub fn parse(text: &str, path: impl AsRef<Path>) -> Result<Self, RecordingError> {
        let path = path.as_ref();
        let table = Table::parse(text, path)?;
        let parser = RowParser::of(&table)?;
        let flow_cols = [
            table.find(MASS_FLOW_COLUMNS[0])?,
            table.find(MASS_FLOW_COLUMNS[1])?,
        ];
        let flow_cols = match flow_cols {
            [Some(a), Some(b)] => Some([a, b]),
            [None, None] => None,
            [a, _] => {
                let (has, lacks) = if a.is_some() { (0, 1) } else { (1, 0) };
                return Err(table.field_err(
                    table.header_line,
                    MASS_FLOW_COLUMNS[lacks],
                    format!(
                        "missing: the mass-flow columns come in pairs ({} is present)",
                        MASS_FLOW_COLUMNS[has]
                    ),
                ));
            }
        };
        let (cols, lines): (RecordingColumns, _) = table.rows(|row| {
            let (t_s, u, y) = parser.parse(row)?;
            let mut m = [0.0; 2];
            if let Some(cols) = flow_cols {
                for i in 0..2 {
                    m[i] = row.num(cols[i], MASS_FLOW_COLUMNS[i])?;
                    let (lo, hi) = MASS_FLOW_RANGE_KG_S;
                    if !(lo..=hi).contains(&m[i]) {
                        return Err(row.field_err(
                            MASS_FLOW_COLUMNS[i],
                            format!(
                                "{} is outside the plausible range [{lo}, {hi}] kg/s",
                                crate::validate::Shown(m[i])
                            ),
                        ));
                    }
                }
            }
            Ok((t_s, u, y, m))
        })?;
        let out_cols = parser.out_cols;
        let mut rec = Recording {
            metadata: table.metadata.clone(),
            t_s: cols.t_s,
            inputs: cols.inputs,
            mass_flow_kg_s: flow_cols.map(|_| cols.mass_flows),
            ..Default::default()
        };
        for (c, y) in Channel::ALL.into_iter().zip(cols.outputs) {
            if out_cols[c.index()].is_some() {
                rec.outputs[c.index()] = Some(y);
            }
        }

        table.check_time(&rec.t_s, |k| lines[k])?;
        Ok(rec)
    }

    /// Writes the recording; the target is replaced only once the new file is complete.
    pub fn write(&self, path: impl AsRef<Path>) -> Result<(), RecordingError> {
        let path = path.as_ref();
        let io = |source: std::io::Error| RecordingError::Io {
            path: path.to_owned(),
            source,
        };
        let n = self.t_s.len();
        if self.inputs.len() != n
            || self.outputs.iter().flatten().any(|c| c.len() != n)
            || self.mass_flow_kg_s.iter().flatten().any(|c| c.len() != n)
        {
            return Err(RecordingError::Invalid {
                path: path.to_owned(),
                message: "columns of unequal length".into(),
            });
        }
        write_atomically(path, |w| self.write_to(w)).map_err(io)
    }

    /// The CSV text of the recording (metadata, header, rows) into `w`.
    pub fn write_to(&self, w: &mut impl Write) -> std::io::Result<()> {
        let n = self.t_s.len();
        let present: Vec<Channel> = Channel::ALL
            .into_iter()
            .filter(|c| self.outputs[c.index()].is_some())
            .collect();
        let flow_names: &[&str] = if self.mass_flow_kg_s.is_some() {
            &MASS_FLOW_COLUMNS
        } else {
            &[]
        };
        write_head(&self.metadata, &present, flow_names, w)?;
        // The rows: numbers only (nothing to quote), formatted by `numfmt` ([`push_row`]) in
        // blocks, each block's two halves on two threads, so memory stays one block whatever
        // the length.
        let outputs: Vec<&[f64]> = present
            .iter()
            .map(|c| self.outputs[c.index()].as_deref().unwrap_or(&[]))
            .collect();
        let rows = |range: std::ops::Range<usize>| -> Vec<u8> {
            let mut buf = Vec::with_capacity(range.len() * (16 + 8 * outputs.len()));
            for k in range {
                push_row(
                    &mut buf,
                    self.t_s[k],
                    &self.inputs[k],
                    outputs.iter().map(|col| col[k]),
                );
                if let Some(flows) = &self.mass_flow_kg_s {
                    // The mass flows after the channels, before the row's end.
                    buf.pop();
                    for col in flows {
                        buf.push(b',');
                        numfmt::push_shortest(&mut buf, col[k]);
                    }
                    buf.push(b'\n');
                }
            }
            buf
        };
        write_rows_in_blocks(n, rows, w)
    }
}

/// The metadata lines and the CSV header (`t_s`, the valve openings, the `present` channels,
/// then `extra` columns).
pub(crate) fn write_head(
    metadata: &[(String, String)],
    present: &[Channel],
    extra: &[&str],
    w: &mut impl Write,
) -> std::io::Result<()> {
    for (k, v) in metadata {
        if k.is_empty() {
            writeln!(w, "# {v}")?;
        } else {
            writeln!(w, "# {k} = {v}")?;
        }
    }
    let mut cw = csv::WriterBuilder::new().from_writer(&mut *w);
    let mut header: Vec<&str> = vec!["t_s"];
    header.extend(INPUT_COLUMNS);
    header.extend(present.iter().map(|c| c.name()));
    header.extend(extra);
    cw.write_record(&header)?;
    cw.flush()?;
    Ok(())
}

/// Bytes a row of [`push_row_in`] may take before it is appended.
pub(crate) const ROW_BYTES: usize = 10 * (numfmt::NUMBER_BYTES + 1);

/// One data row: numbers only (nothing to quote), formatted by `numfmt` (byte-identical to
/// `{}` for the time rounded to the nanosecond ([`numfmt::time_to_ns`]) and the openings,
/// `{:.6}` for the readings), at most 5 readings. The row is
/// built on the stack and appended at once; a number the integer path cannot prove (a
/// rounding tie, a huge value) sends the row through the standard formatter.
#[inline]
pub(crate) fn push_row(
    buf: &mut Vec<u8>,
    t_s: f64,
    u: &ValveInputs,
    outputs: impl Iterator<Item = f64> + Clone,
) {
    push_row_in(&mut [0u8; ROW_BYTES], buf, t_s, u, outputs);
}

/// [`push_row`] built in `row`, a scratch buffer the caller keeps from row to row (what it
/// holds is overwritten; a fresh one would be zeroed for every row).
#[inline]
pub(crate) fn push_row_in(
    row: &mut [u8; ROW_BYTES],
    buf: &mut Vec<u8>,
    t_s: f64,
    u: &ValveInputs,
    outputs: impl Iterator<Item = f64> + Clone,
) {
    let t_s = numfmt::time_to_ns(t_s);
    let openings = [u.u_in1, u.u_ex1, u.u_in2, u.u_ex2];
    let fast = (|| {
        let mut k = numfmt::shortest_into(&mut row[..], t_s)?;
        for v in openings {
            row[k] = b',';
            // The usual openings, +0 and 1, in place (-0 is written `-0` by the standard
            // formatter, through `shortest_into`).
            if v.to_bits() == 0 || v == 1.0 {
                row[k + 1] = if v == 1.0 { b'1' } else { b'0' };
                k += 2;
            } else {
                k += 1 + numfmt::shortest_into(&mut row[k + 1..], v)?;
            }
        }
        for (i, y) in outputs.clone().enumerate() {
            if i >= 5 {
                return None;
            }
            row[k] = b',';
            k += 1 + numfmt::fixed_into_const::<6>(&mut row[k + 1..], y)?;
        }
        row[k] = b'\n';
        Some(k + 1)
    })();
    if let Some(k) = fast {
        buf.extend_from_slice(&row[..k]);
        return;
    }
    numfmt::push_shortest(buf, t_s);
    for v in openings {
        buf.push(b',');
        numfmt::push_shortest(buf, v);
    }
    for y in outputs {
        buf.push(b',');
        numfmt::push_fixed(buf, y, 6);
    }
    buf.push(b'\n');
}

/// Formats rows `0..n` with `rows` block by block (each block's halves on two threads when
/// it is large enough to pay for the thread) and writes them to `w` in order.
pub(crate) fn write_rows_in_blocks(
    n: usize,
    rows: impl Fn(std::ops::Range<usize>) -> Vec<u8> + Sync,
    w: &mut impl Write,
) -> std::io::Result<()> {
    const BLOCK_ROWS: usize = 16_384;
    const PARALLEL_MIN_ROWS: usize = 4_096;
    let mut start = 0;
    while start < n {
        let end = (start + BLOCK_ROWS).min(n);
        if end - start >= PARALLEL_MIN_ROWS {
            let mid = start + (end - start) / 2;
            let (a, b) = std::thread::scope(|s| {
                let second = s.spawn(|| rows(mid..end));
                (rows(start..mid), second.join())
            });
            let b = b.map_err(|_| std::io::Error::other("a formatting thread failed"))?;
            w.write_all(&a)?;
            w.write_all(&b)?;
        } else {
            w.write_all(&rows(start..end))?;
        }
        start = end;
    }
    Ok(())
}

/// [`Recording::is_uniform`] of the time stamps `t_s`.
pub(crate) fn stamps_uniform(t_s: &[f64]) -> bool {
    let n = t_s.len();
    if n < 2 {
        return true;
    }
    let dt = mean_step_s(t_s);
    let mut steps: Vec<f64> = t_s.windows(2).map(|w| w[1] - w[0]).collect();
    // The middle element of the sorted steps, selected without sorting them all.
    let half = steps.len() / 2;
    let median = *steps.select_nth_unstable_by(half, f64::total_cmp).1;
    steps
        .iter()
        .all(|s| (s - median).abs() <= UNIFORM_TOLERANCE * median.abs())
        && (0..n).all(|k| (t_s[k] - (t_s[0] + k as f64 * dt)).abs() <= UNIFORM_TOLERANCE * dt)
}

/// Linear interpolation of `(t, y)` (increasing `t`) at `at` (clamped to the end values).
pub fn interpolate(t: &[f64], y: &[f64], at: &[f64]) -> Vec<f64> {
    let n = t.len();
    let mut j = 0usize;
    at.iter()
        .map(|&x| {
            if x <= t[0] {
                return y[0];
            }
            if x >= t[n - 1] {
                return y[n - 1];
            }
            while j + 1 < n && t[j + 1] < x {
                j += 1;
            }
            let (t0, t1) = (t[j], t[j + 1]);
            let w = (x - t0) / (t1 - t0);
            y[j] + w * (y[j + 1] - y[j])
        })
        .collect()
}

/// Writes a file atomically through [`crate::io::atomic::write_with`] (the one atomic
/// writer): a failure never leaves a half-written target.
pub fn write_atomically(
    path: &Path,
    fill: impl FnOnce(&mut crate::io::atomic::Output<'_>) -> std::io::Result<()>,
) -> std::io::Result<()> {
    crate::io::atomic::write_with(path, fill)
}

/// The columns of a 1-DOF recording's table and the reading of one row: time, the four
/// valve openings, the output channels present (absent ones 0). Shared by
/// [`Recording::parse`] and the streaming replay (`io::replay_stream`).
pub(crate) struct RowParser {
    t_col: usize,
    u_cols: [usize; 4],
    /// Column of each output channel, by [`Channel::index`].
    pub out_cols: [Option<usize>; 5],
    /// What each column of the header is, for [`Self::parse_plain_rows`].
    roles: Vec<Role>,
}

/// What a column holds for [`RowParser`].
#[derive(Debug, Clone, Copy, PartialEq)]
enum Role {
    Ignored,
    Time,
    Opening(usize),
    Output(usize),
}

impl RowParser {
    /// The columns of `table`; a missing required column or no output column is an error.
    pub(crate) fn of(table: &Table) -> Result<Self, RecordingError> {
        let t_col = table.required("t_s", "")?;
        let mut u_cols = [0usize; 4];
        for (i, name) in INPUT_COLUMNS.iter().enumerate() {
            u_cols[i] = table.required(name, "")?;
        }
        let mut out_cols: [Option<usize>; 5] = [None; 5];
        for c in Channel::ALL {
            out_cols[c.index()] = table.find(c.name())?;
        }
        // A channel present under another unit or spelling (`angle_rad`, `p1_kPa`) would be
        // ignored, and the file judged without it.
        for c in Channel::ALL {
            if out_cols[c.index()].is_none() {
                if let Some(h) = table.near_miss(c.name()) {
                    return Err(table.field_err(
                        table.header_line,
                        h,
                        format!("not a RECORDING.md column: {}", rename_advice(c.name())),
                    ));
                }
            }
        }
        if out_cols.iter().all(|c| c.is_none()) {
            return Err(table.field_err(
                table.header_line,
                "angle_deg",
                "no output column (need at least one of angle_deg, p1_kpa, p2_kpa, f1_n, f2_n)",
            ));
        }
        let mut roles = vec![Role::Ignored; table.headers.len()];
        roles[t_col] = Role::Time;
        for (i, &c) in u_cols.iter().enumerate() {
            roles[c] = Role::Opening(i);
        }
        for (i, c) in out_cols.iter().enumerate() {
            if let Some(c) = *c {
                roles[c] = Role::Output(i);
            }
        }
        Ok(Self {
            t_col,
            u_cols,
            out_cols,
            roles,
        })
    }

    /// The rows of `bytes` (whole lines) into `sink`, if every row is plain: the header's
    /// number of fields, each number a plain decimal ([`numfmt::parse_plain_decimal`]),
    /// openings in [0, 1], lines ending in `\n` or `\r\n` (empty lines skipped), none longer than
    /// [`MAX_DATA_LINE_BYTES`]. Then the
    /// values are those of [`Table::read_chunk`] with [`Self::parse`]; `false` as soon as a row
    /// is not plain (what was pushed must be discarded: the general reader reads the bytes
    /// and words any error).
    pub(crate) fn parse_plain_rows<S: RowSink<(f64, [f64; 4], [f64; 5])>>(
        &self,
        bytes: &[u8],
        sink: &mut S,
    ) -> bool {
        let len = bytes.len();
        let n_fields = self.roles.len();
        let mut i = 0;
        while i < len {
            match bytes[i] {
                b'\n' => {
                    i += 1;
                    continue;
                }
                b'\r' if bytes.get(i + 1) == Some(&b'\n') => {
                    i += 2;
                    continue;
                }
                _ => {}
            }
            let row_start = i;
            let (mut t_s, mut u, mut y) = (0.0, [0.0; 4], [0.0; 5]);
            for (f, role) in self.roles.iter().enumerate() {
                match *role {
                    Role::Ignored => {
                        while i < len && !matches!(bytes[i], b',' | b'\n' | b'\r') {
                            i += 1;
                        }
                    }
                    // The usual openings, `0` and `1` alone in their field: their value
                    // without the scanner.
                    Role::Opening(k)
                        if matches!(bytes.get(i), Some(b'0' | b'1'))
                            && matches!(bytes.get(i + 1), Some(b',' | b'\n' | b'\r')) =>
                    {
                        u[k] = f64::from(bytes[i] - b'0');
                        i += 1;
                    }
                    // A reading the sink does not keep: checked as the scanner checks it,
                    // without its value.
                    Role::Output(_) if !S::WANTS_OUTPUTS => {
                        let (plain, end) = numfmt::scan_plain_decimal_syntax(bytes, i);
                        i = end;
                        if !plain {
                            return false;
                        }
                    }
                    _ => {
                        // The field read as `parse_plain_decimal` reads it, in the same pass
                        // that finds its end.
                        let (value, end) = numfmt::scan_plain_decimal(bytes, i);
                        i = end;
                        let Some(v) = value else {
                            return false;
                        };
                        match *role {
                            Role::Time => t_s = v,
                            Role::Opening(k) if (0.0..=1.0).contains(&v) => u[k] = v,
                            Role::Output(k) if Channel::ALL[k].is_plausible(v) => y[k] = v,
                            _ => return false,
                        }
                    }
                }
                if f + 1 < n_fields {
                    if bytes.get(i) != Some(&b',') {
                        return false;
                    }
                    i += 1;
                } else {
                    match bytes.get(i) {
                        None => {}
                        Some(b'\n') => i += 1,
                        Some(b'\r') if bytes.get(i + 1) == Some(&b'\n') => i += 2,
                        _ => return false,
                    }
                }
            }
            // A row longer than a recording may have: the general reader refuses it.
            if i - row_start > MAX_DATA_LINE_BYTES {
                return false;
            }
            sink.push((t_s, u, y));
        }
        true
    }

    /// One row: (t_s, openings, outputs).
    #[inline]
    pub(crate) fn parse(&self, row: &Row) -> Result<(f64, [f64; 4], [f64; 5]), RecordingError> {
        let t_s = row.num(self.t_col, "t_s")?;
        let mut u = [0.0; 4];
        for i in 0..4 {
            u[i] = row.opening(self.u_cols[i], INPUT_COLUMNS[i])?;
        }
        let mut y = [0.0; 5];
        for c in Channel::ALL {
            if let Some(col) = self.out_cols[c.index()] {
                let v = row.num(col, c.name())?;
                if !c.is_plausible(v) {
                    return Err(row.field_err(c.name(), c.implausible(v)));
                }
                y[c.index()] = v;
            }
        }
        Ok((t_s, u, y))
    }
}

/// The columns of a recording as [`Recording::parse`] reads them (absent outputs stay empty).
#[derive(Default)]
struct RecordingColumns {
    t_s: Vec<f64>,
    inputs: Vec<ValveInputs>,
    outputs: [Vec<f64>; 5],
    mass_flows: [Vec<f64>; 2],
}

impl RowSink<(f64, [f64; 4], [f64; 5], [f64; 2])> for RecordingColumns {
    fn reserve(&mut self, n: usize) {
        self.t_s.reserve(n);
        self.inputs.reserve(n);
        for y in self.outputs.iter_mut().chain(self.mass_flows.iter_mut()) {
            y.reserve(n);
        }
    }
    fn push(&mut self, (t_s, u, y, m): (f64, [f64; 4], [f64; 5], [f64; 2])) {
        self.t_s.push(t_s);
        self.inputs.push(ValveInputs::from_openings(u));
        for (col, v) in self.outputs.iter_mut().zip(y) {
            col.push(v);
        }
        for (col, v) in self.mass_flows.iter_mut().zip(m) {
            col.push(v);
        }
    }
    fn append(&mut self, mut other: Self) {
        self.t_s.append(&mut other.t_s);
        self.inputs.append(&mut other.inputs);
        for (a, b) in self
            .outputs
            .iter_mut()
            .zip(other.outputs.iter_mut())
            .chain(self.mass_flows.iter_mut().zip(other.mass_flows.iter_mut()))
        {
            a.append(b);
        }
    }
}

/// The leading `# key = value` metadata and blank lines of a recording (RECORDING.md).
pub(crate) struct Preamble {
    /// (key, value); a comment without `=` has an empty key.
    pub metadata: Vec<(String, String)>,
    /// 1-based line of each metadata entry.
    pub meta_line_of: Vec<u64>,
    /// Lines before the CSV header.
    pub lines: u64,
    /// Byte offset of the CSV header.
    pub offset: usize,
}

impl Preamble {
    pub(crate) fn of(text: &str) -> Self {
        let mut p = Preamble {
            metadata: Vec::new(),
            meta_line_of: Vec::new(),
            lines: 0,
            offset: 0,
        };
        for raw in text.split_inclusive('\n') {
            let trimmed = raw.trim();
            if let Some(c) = trimmed.strip_prefix('#') {
                let c = c.trim();
                match c.split_once('=') {
                    // host-sim's mark says who wrote the file, not what it holds: not kept
                    // (a recording written from it gets its own).
                    Some((k, _)) if k.trim() == crate::output::MARK_KEY => {}
                    Some((k, v)) => {
                        p.metadata.push((k.trim().to_owned(), v.trim().to_owned()));
                        p.meta_line_of.push(p.lines + 1);
                    }
                    None => {
                        p.metadata.push((String::new(), c.to_owned()));
                        p.meta_line_of.push(p.lines + 1);
                    }
                }
            } else if !trimmed.is_empty() {
                break;
            }
            p.lines += 1;
            p.offset += raw.len();
        }
        p
    }
}

/// A recording file being read: its metadata and the CSV rows after it, with the errors
/// naming the file, line and field. Shared by the 1-DOF and the 3-joint readers.
pub(crate) struct Table<'t> {
    path: &'t Path,
    pub metadata: Vec<(String, String)>,
    /// 1-based line of each metadata entry.
    pub meta_line_of: Vec<u64>,
    /// 1-based line of the CSV header.
    pub header_line: u64,
    headers: csv::StringRecord,
    /// The bytes after the header line: the data rows.
    data: &'t [u8],
    /// 1-based line of the first byte of `data`.
    data_line: u64,
}

/// The other way to read a rig's file, for hints.
const IMPORT_ADVICE: &str = "or read the file with `host-sim import` and a mapping (docs/rig.md)";

/// What to do about a column that names RECORDING.md's `name` another way.
fn rename_advice(name: &str) -> String {
    format!(
        "RECORDING.md's is `{name}`, {}; convert and rename it, {IMPORT_ADVICE}",
        column_meaning(name)
    )
}

/// What a RECORDING.md column holds, for hints.
fn column_meaning(name: &str) -> &'static str {
    match name {
        "t_s" => "the time in seconds",
        "angle_deg" => "the joint angle in degrees",
        "p1_kpa" | "p2_kpa" => "the muscle's gauge pressure in kPa",
        "f1_n" | "f2_n" => "the muscle's tension in N",
        _ => "a valve opening in [0, 1]",
    }
}

/// The quantity a column name stands for: lower case, without a unit suffix (`angle_rad`,
/// `Angle_deg` and `angle` are `angle`; `P1_kPa` is `p1`; `time_ms` is `t`).
fn column_stem(name: &str) -> String {
    const UNITS: [&str; 16] = [
        "s", "ms", "us", "deg", "rad", "kpa", "pa", "mpa", "bar", "psi", "n", "kn", "mn", "lbf",
        "pct", "percent",
    ];
    let lower = name.trim().to_ascii_lowercase();
    let stem = match lower.rsplit_once(['_', ' ', '[']) {
        Some((head, unit)) if UNITS.contains(&unit.trim_end_matches(']')) => head.trim(),
        _ => lower.as_str(),
    };
    match stem {
        "time" => "t".into(),
        s => s.into(),
    }
}

/// One data row of a [`Table`]: its fields, read with errors naming file, line and field.
pub(crate) struct Row<'r> {
    /// The row's bytes and the byte range of each field in them.
    data: &'r [u8],
    fields: &'r [std::ops::Range<usize>],
    path: &'r Path,
    /// 1-based line of the row in the file.
    pub line: u64,
}

impl Row<'_> {
    /// An error about `field` of this row.
    pub(crate) fn field_err(&self, field: &str, message: impl Into<String>) -> RecordingError {
        RecordingError::Field {
            path: self.path.to_owned(),
            line: self.line,
            field: field.to_owned(),
            message: message.into(),
        }
    }

    /// The finite number in column `col` (named `name`).
    pub(crate) fn num(&self, col: usize, name: &str) -> Result<f64, RecordingError> {
        let raw = self
            .fields
            .get(col)
            .and_then(|r| self.data.get(r.clone()))
            .unwrap_or(b"");
        if let Some(v) = numfmt::parse_plain_decimal(raw) {
            return Ok(v);
        }
        let bytes = raw.trim_ascii();
        let s = std::str::from_utf8(bytes).unwrap_or("");
        let v: f64 = s.parse().map_err(|_| {
            self.field_err(
                name,
                format!("not a number: {:?}", String::from_utf8_lossy(bytes)),
            )
        })?;
        if !v.is_finite() {
            return Err(self.field_err(name, format!("not a finite number: {s:?}")));
        }
        Ok(v)
    }

    /// The valve opening in [0, 1] in column `col` (named `name`).
    pub(crate) fn opening(&self, col: usize, name: &str) -> Result<f64, RecordingError> {
        let v = self.num(col, name)?;
        if !(0.0..=1.0).contains(&v) {
            return Err(self.field_err(name, format!("valve opening {v} outside [0, 1]")));
        }
        Ok(v)
    }
}

/// Where [`Table::rows`] collects the values `f` makes of the rows: a `Vec` of them, or a
/// column store that splits each value into its columns as it comes.
pub(crate) trait RowSink<T>: Default + Send {
    /// Whether the sink keeps the output channels' values; when it does not,
    /// [`RowParser::parse_plain_rows`] only checks that those fields are plain decimals.
    const WANTS_OUTPUTS: bool = true;
    /// Room for `n` more rows.
    fn reserve(&mut self, n: usize);
    /// One row's value.
    fn push(&mut self, value: T);
    /// The rows of `other` after these.
    fn append(&mut self, other: Self);
}

impl<T: Send> RowSink<T> for Vec<T> {
    fn reserve(&mut self, n: usize) {
        Vec::reserve(self, n);
    }
    fn push(&mut self, value: T) {
        Vec::push(self, value);
    }
    fn append(&mut self, mut other: Self) {
        Vec::append(self, &mut other);
    }
}

/// Data of at least this many bytes is read in two chunks on two threads.
const PARALLEL_READ_MIN_BYTES: usize = 256 * 1024;

/// The mean step of time stamps `t_s` (first to last); NaN with fewer than two.
pub(crate) fn mean_step_s(t_s: &[f64]) -> f64 {
    let n = t_s.len();
    if n < 2 {
        return f64::NAN;
    }
    (t_s[n - 1] - t_s[0]) / (n - 1) as f64
}

/// The longest metadata or CSV header line a recording may have, in bytes before its line
/// end. A longer line is refused, naming its file and line, as soon as the reader has seen
/// this many bytes of it (the rest of the file is not read).
pub const MAX_HEAD_LINE_BYTES: usize = 64 * 1024;

/// The longest data row a recording may have, in bytes before its line end (a row of the
/// columns RECORDING.md defines takes under 200).
pub const MAX_DATA_LINE_BYTES: usize = 16 * 1024;

/// The error for line `line` of `path`, longer than `limit` bytes.
fn line_too_long(path: &Path, line: u64, limit: usize) -> RecordingError {
    let what = if limit == MAX_HEAD_LINE_BYTES {
        "a metadata or header line"
    } else {
        "a data row"
    };
    RecordingError::Line {
        path: path.to_owned(),
        line,
        message: format!(
            "line longer than {limit} bytes, the longest {what} may be (not read further)"
        ),
    }
}

/// Line lengths checked over a file's bytes as they are read: metadata, blank lines and the
/// CSV header (the first other line) against [`MAX_HEAD_LINE_BYTES`], the rows after it
/// against [`MAX_DATA_LINE_BYTES`].
struct LineLimits {
    /// 1-based line of the line being read.
    line: u64,
    /// Offset of its first byte.
    start: usize,
    /// Whether it is a metadata, blank or header line.
    head: bool,
}

impl LineLimits {
    fn new() -> Self {
        Self {
            line: 1,
            start: 0,
            head: true,
        }
    }

    fn limit(&self) -> usize {
        if self.head {
            MAX_HEAD_LINE_BYTES
        } else {
            MAX_DATA_LINE_BYTES
        }
    }

    /// Checks the lines of `text` that end at or after `from` (the bytes before `from` were
    /// checked by the previous calls); `Err((line, limit))` for the first one too long,
    /// including the unfinished last line.
    fn check(&mut self, text: &[u8], from: usize) -> Result<(), (u64, usize)> {
        for i in memchr::memchr_iter(b'\n', &text[from..]) {
            let end = from + i;
            if end - self.start > self.limit() {
                return Err((self.line, self.limit()));
            }
            if self.head {
                // As `Preamble::of` tells the metadata from the header.
                let mut raw = &text[self.start..end];
                if self.line == 1 {
                    raw = raw.strip_prefix("\u{feff}".as_bytes()).unwrap_or(raw);
                }
                let meta = std::str::from_utf8(raw)
                    .map(str::trim)
                    .is_ok_and(|t| t.is_empty() || t.starts_with('#'));
                self.head = meta;
            }
            self.line += 1;
            self.start = end + 1;
        }
        if text.len() - self.start > self.limit() {
            return Err((self.line, self.limit()));
        }
        Ok(())
    }
}

/// The text of a recording file. A line longer than [`MAX_HEAD_LINE_BYTES`] (metadata,
/// header) or [`MAX_DATA_LINE_BYTES`] (rows) is refused, naming the file and the line, once
/// that many bytes of it are read: memory stays bounded by the limit, whatever the line.
pub(crate) fn read_text(path: &Path) -> Result<String, RecordingError> {
    /// Bytes read between two checks.
    const PIECE_BYTES: u64 = 1 << 20;
    let io = |source: std::io::Error| RecordingError::Io {
        path: path.to_owned(),
        source,
    };
    let mut file = std::fs::File::open(path).map_err(io)?;
    let size = file.metadata().map_or(0, |m| m.len());
    let mut text = Vec::new();
    // The whole file in one allocation when it is read to its end (pages are only touched
    // as they are read).
    text.reserve_exact(usize::try_from(size).unwrap_or(0).saturating_add(1));
    let mut limits = LineLimits::new();
    loop {
        let before = text.len();
        let got = (&mut file)
            .take(PIECE_BYTES)
            .read_to_end(&mut text)
            .map_err(io)?;
        limits
            .check(&text, before)
            .map_err(|(line, limit)| line_too_long(path, line, limit))?;
        if got == 0 {
            break;
        }
    }
    String::from_utf8(text).or_else(|e| decode_non_utf8(path, e.into_bytes()))
}

/// A recording that is not UTF-8: accepted when every line that is not UTF-8 is a `#`
/// comment (a note typed in a Latin-1 editor; those lines are read as Latin-1, as `import`
/// reads a whole file), else refused at the first such line with the byte and the remedy.
fn decode_non_utf8(path: &Path, bytes: Vec<u8>) -> Result<String, RecordingError> {
    let mut out = String::with_capacity(bytes.len() + 64);
    for (i, line) in bytes.split_inclusive(|&b| b == b'\n').enumerate() {
        match std::str::from_utf8(line) {
            Ok(l) => out.push_str(l),
            Err(e) if line.trim_ascii_start().starts_with(b"#") => {
                let _ = e;
                out.extend(line.iter().map(|&b| char::from(b)));
            }
            Err(e) => {
                let at = e.valid_up_to();
                return Err(RecordingError::Line {
                    path: path.to_owned(),
                    line: i as u64 + 1,
                    message: format!(
                        "not UTF-8 (byte 0x{:02X} at column {}; saved as Latin-1 or \
                         Windows-1252?): save the recording as UTF-8, or convert it with \
                         `host-sim import` (which reads Latin-1)",
                        line[at],
                        String::from_utf8_lossy(&line[..at]).chars().count() + 1
                    ),
                });
            }
        }
    }
    Ok(out)
}

impl<'t> Table<'t> {
    /// The metadata and the CSV header of `text` (a leading byte-order mark is skipped).
    pub(crate) fn parse(text: &'t str, path: &'t Path) -> Result<Self, RecordingError> {
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let Preamble {
            metadata,
            meta_line_of,
            lines: meta_lines,
            offset,
        } = Preamble::of(text);
        // The line limits of `read_text`, for text that did not come through it.
        let mut limits = LineLimits::new();
        let head_end = memchr::memchr(b'\n', &text.as_bytes()[offset..])
            .map_or(text.len(), |i| offset + i + 1);
        limits
            .check(&text.as_bytes()[..head_end], 0)
            .map_err(|(line, limit)| line_too_long(path, line, limit))?;
        let after_meta = &text.as_bytes()[offset..];
        let mut rdr = csv::ReaderBuilder::new()
            .has_headers(true)
            .from_reader(after_meta);
        let header_line = meta_lines + 1;
        let headers = rdr
            .headers()
            .map_err(|e| RecordingError::Line {
                path: path.to_owned(),
                line: header_line,
                message: format!("cannot read the header: {e}"),
            })?
            .iter()
            .map(str::trim)
            .collect::<csv::StringRecord>();
        if headers.is_empty() || (headers.len() == 1 && headers[0].is_empty()) {
            return Err(RecordingError::Line {
                path: path.to_owned(),
                line: header_line,
                message: "no header line (expected t_s,u_in1,u_ex1,u_in2,u_ex2,...)".into(),
            });
        }
        let pos = rdr.position();
        let data_start = (pos.byte() as usize).min(after_meta.len());
        Ok(Self {
            path,
            metadata,
            meta_line_of,
            header_line,
            headers,
            data: &after_meta[data_start..],
            data_line: pos.line() + meta_lines,
        })
    }

    /// The bytes after the header line (the data rows) and the 1-based line of their first
    /// byte.
    pub(crate) fn data(&self) -> (&'t [u8], u64) {
        (self.data, self.data_line)
    }

    /// Every data row through `f`, in file order, with the row's 1-based line. The first
    /// error in file order is returned. Large files (without quoted fields) are read in two
    /// chunks, split at a line end, on two threads.
    pub(crate) fn rows<T, S: RowSink<T>>(
        &self,
        f: impl Fn(&Row) -> Result<T, RecordingError> + Sync,
    ) -> Result<(S, Vec<u64>), RecordingError> {
        let data = self.data;
        let split = if data.len() >= PARALLEL_READ_MIN_BYTES && memchr::memchr(b'"', data).is_none()
        {
            memchr::memchr(b'\n', &data[data.len() / 2..]).map(|i| data.len() / 2 + i + 1)
        } else {
            None
        };
        let Some(mid) = split else {
            return self.read_chunk(data, self.data_line, 0, &f);
        };
        let second_line = self.data_line + memchr::memchr_iter(b'\n', &data[..mid]).count() as u64;
        let rows_after_mid = memchr::memchr_iter(b'\n', &data[mid..]).count() + 1;
        let (first, second) = std::thread::scope(|s| {
            let second = s.spawn(|| self.read_chunk(&data[mid..], second_line, 0, &f));
            (
                // Room for the second chunk's rows too: appending them copies nothing.
                self.read_chunk(&data[..mid], self.data_line, rows_after_mid, &f),
                second.join(),
            )
        });
        let (mut values, mut lines): (S, _) = first?;
        let (v2, l2) = second.map_err(|_| RecordingError::Invalid {
            path: self.path.to_owned(),
            message: "a reading thread failed".into(),
        })??;
        values.append(v2);
        lines.extend(l2);
        Ok((values, lines))
    }

    /// The rows of `bytes` (whose first byte is on line `first_line`) through `f`.
    /// `extra_rows`: room reserved for rows appended later.
    pub(crate) fn read_chunk<T, S: RowSink<T>>(
        &self,
        bytes: &[u8],
        first_line: u64,
        extra_rows: usize,
        f: &impl Fn(&Row) -> Result<T, RecordingError>,
    ) -> Result<(S, Vec<u64>), RecordingError> {
        let rows_guess = memchr::memchr_iter(b'\n', bytes).count() + 1 + extra_rows;
        let mut values = S::default();
        values.reserve(rows_guess);
        let mut lines = Vec::with_capacity(rows_guess);
        // Plain rows (no quotes, `\n` or `\r\n` line ends, the header's field count) are
        // split at the commas directly: what the CSV reader does for them, at a fraction of
        // its cost. Anything else, errors included, goes through the CSV reader.
        if memchr::memchr(b'"', bytes).is_none()
            && self.split_plain(bytes, first_line, f, &mut values, &mut lines)?
        {
            return Ok((values, lines));
        }
        values = S::default();
        lines.clear();
        // Fields are trimmed where they are read (`Row::num`), not by the reader: its
        // trimming builds a new record per row.
        let mut rdr = csv::ReaderBuilder::new()
            .has_headers(false)
            .flexible(true)
            .from_reader(bytes);
        let mut record = csv::ByteRecord::new();
        let mut fields = Vec::with_capacity(self.headers.len());
        loop {
            match rdr.read_byte_record(&mut record) {
                Ok(false) => return Ok((values, lines)),
                Ok(true) => {
                    let line = record.position().map(|p| p.line()).unwrap_or(1) - 1 + first_line;
                    if record.len() != self.headers.len() {
                        return Err(RecordingError::Line {
                            path: self.path.to_owned(),
                            line,
                            message: format!(
                                "{} fields, the header has {}",
                                record.len(),
                                self.headers.len()
                            ),
                        });
                    }
                    fields.clear();
                    fields.extend((0..record.len()).filter_map(|i| record.range(i)));
                    let row = Row {
                        data: record.as_slice(),
                        fields: &fields,
                        path: self.path,
                        line,
                    };
                    values.push(f(&row)?);
                    lines.push(line);
                }
                Err(e) => {
                    let line = e
                        .position()
                        .map(|p| p.line() - 1 + first_line)
                        .unwrap_or(first_line);
                    return Err(RecordingError::Line {
                        path: self.path.to_owned(),
                        line,
                        message: e.to_string(),
                    });
                }
            }
        }
    }

    /// The fast path of [`Self::read_chunk`] for quote-free `bytes`: `Ok(false)` (nothing
    /// reported) as soon as a row is not plain (a lone `\r`, another field count), so the
    /// CSV reader reads the chunk and words any error; `f`'s own errors are returned.
    fn split_plain<T, S: RowSink<T>>(
        &self,
        bytes: &[u8],
        first_line: u64,
        f: &impl Fn(&Row) -> Result<T, RecordingError>,
        values: &mut S,
        lines: &mut Vec<u64>,
    ) -> Result<bool, RecordingError> {
        let n_fields = self.headers.len();
        let mut fields: Vec<std::ops::Range<usize>> = Vec::with_capacity(n_fields);
        let mut line = first_line;
        let mut line_start = 0;
        while line_start <= bytes.len() {
            let line_end =
                memchr::memchr(b'\n', &bytes[line_start..]).map_or(bytes.len(), |i| line_start + i);
            let raw = &bytes[line_start..line_end];
            line_start = line_end + 1;
            if raw.len() > MAX_DATA_LINE_BYTES {
                return Err(line_too_long(self.path, line, MAX_DATA_LINE_BYTES));
            }
            let row = raw.strip_suffix(b"\r").unwrap_or(raw);
            if !row.is_empty() {
                fields.clear();
                let mut start = 0;
                for i in memchr::memchr2_iter(b',', b'\r', row) {
                    if row[i] == b'\r' {
                        return Ok(false);
                    }
                    fields.push(start..i);
                    start = i + 1;
                }
                fields.push(start..row.len());
                if fields.len() != n_fields {
                    return Ok(false);
                }
                let r = Row {
                    data: row,
                    fields: &fields,
                    path: self.path,
                    line,
                };
                values.push(f(&r)?);
                lines.push(line);
            }
            line += 1;
        }
        Ok(true)
    }

    /// An error about `field` at `line`.
    pub(crate) fn field_err(
        &self,
        line: u64,
        field: &str,
        message: impl Into<String>,
    ) -> RecordingError {
        RecordingError::Field {
            path: self.path.to_owned(),
            line,
            field: field.to_owned(),
            message: message.into(),
        }
    }

    /// The column named `name`, if present (twice is an error).
    pub(crate) fn find(&self, name: &str) -> Result<Option<usize>, RecordingError> {
        let mut it = self.headers.iter().enumerate().filter(|(_, h)| *h == name);
        let first = it.next().map(|(i, _)| i);
        if it.next().is_some() {
            return Err(self.field_err(self.header_line, name, "column appears twice"));
        }
        Ok(first)
    }

    /// The column named `name`; missing is an error saying `why` (may be empty), with a hint
    /// when the header looks like another separator or has a near miss of the name.
    pub(crate) fn required(&self, name: &str, why: &str) -> Result<usize, RecordingError> {
        self.find(name)?.ok_or_else(|| {
            self.field_err(
                self.header_line,
                name,
                format!("required column is missing{why}{}", self.missing_hint(name)),
            )
        })
    }

    /// Why a RECORDING.md column `name` may be missing: a header that is one field holding
    /// `;` or tabs (another separator), or a column that names the same quantity in another
    /// unit or spelling (`angle_rad`, `P1_kPa`, `p1`). Empty when neither.
    pub(crate) fn missing_hint(&self, name: &str) -> String {
        if let [only] = self.headers.iter().collect::<Vec<_>>()[..] {
            if only.contains(';') || only.contains('\t') {
                return format!(
                    " (the header is one field, `{only}`: RECORDING.md is comma-separated; \
                     convert the file, {IMPORT_ADVICE})"
                );
            }
        }
        match self.near_miss(name) {
            Some(h) => format!(" (column `{h}` is there: {})", rename_advice(name)),
            // Not one of RECORDING.md's columns: a rig logger's own file (its banner line or
            // its own column names).
            // A TOML file (a plant or configuration file) where the recording belongs.
            None if self
                .headers
                .get(0)
                .is_some_and(|h| h.trim_start().starts_with('[') || h.contains('=')) =>
            {
                " (this is a TOML file, a plant or configuration file, not a recording: are \
                 the plant file and the recording given the other way round?)"
                    .to_string()
            }
            None if !self.headers.iter().any(|h| h == "t_s") => {
                " (the header has no `t_s` either: not a recording of RECORDING.md; a rig \
                 logger's file? read it with `host-sim import` and a mapping, docs/rig.md)"
                    .to_string()
            }
            None => String::new(),
        }
    }

    /// A header other than `name` naming the same quantity: equal ignoring case, or the same
    /// stem with another (or no) unit suffix.
    fn near_miss(&self, name: &str) -> Option<&str> {
        let want = column_stem(name);
        self.headers
            .iter()
            .find(|h| *h != name && (h.eq_ignore_ascii_case(name) || column_stem(h) == want))
    }

    /// At least two rows (`t_s`, their `lines`) and increasing time: the mean sample period.
    pub(crate) fn sample_period_s(
        &self,
        t_s: &[f64],
        lines: &[u64],
    ) -> Result<f64, RecordingError> {
        let n = t_s.len();
        if n < 2 {
            return Err(RecordingError::Invalid {
                path: self.path.to_owned(),
                message: format!("{n} data rows; a recording needs at least 2"),
            });
        }
        let dt = mean_step_s(t_s);
        if dt.is_nan() || dt <= 0.0 {
            return Err(self.field_err(
                *lines.last().unwrap_or(&self.header_line),
                "t_s",
                "time does not increase (last time <= first time)",
            ));
        }
        Ok(dt)
    }

    /// The time column `t_s` of a 1-DOF recording (`line_of(k)`: the file line of row `k`):
    /// at least two rows, increasing, each step within [[`MIN_STEP_RATIO`],
    /// [`MAX_STEP_RATIO`]] median steps (jitter is accepted), or a gap of a whole number of
    /// median steps within the limits of `io/timebase.rs` (filled by
    /// [`Recording::to_uniform`], left out of the diagnosis's fits; a longer one is refused),
    /// and a declared `sample_period_s` that agrees with the mean step.
    pub(crate) fn check_time(
        &self,
        t_s: &[f64],
        line_of: impl Fn(usize) -> u64,
    ) -> Result<(), RecordingError> {
        let n = t_s.len();
        let last_line = if n == 0 {
            self.header_line
        } else {
            line_of(n - 1)
        };
        let dt = self.sample_period_s(t_s, &[last_line])?;
        let mut steps: Vec<f64> = t_s.windows(2).map(|w| w[1] - w[0]).collect();
        let half = steps.len() / 2;
        let median_step = *steps.select_nth_unstable_by(half, f64::total_cmp).1;
        drop(steps);
        // Rows out of order or repeated, named at the row where time stops increasing.
        let order_err = |k: usize| {
            let what = if t_s[k] == t_s[k - 1] {
                format!(
                    "time does not increase: time stamp {} repeated (a duplicated row?)",
                    t_s[k]
                )
            } else {
                format!(
                    "time does not increase: {} after {} (rows out of order? the rows must be \
                     sorted by t_s)",
                    t_s[k],
                    t_s[k - 1]
                )
            };
            self.field_err(line_of(k), "t_s", what)
        };
        for k in 1..n {
            let step = t_s[k] - t_s[k - 1];
            if !(step > 0.0) {
                return Err(order_err(k));
            }
            if let Some(why) = crate::io::grid::step_refused(step, median_step) {
                // Two swapped rows first show as a double step: name the swap, not a gap.
                if k + 1 < n && !(t_s[k + 1] > t_s[k]) {
                    return Err(order_err(k + 1));
                }
                return Err(self.field_err(
                    line_of(k),
                    "t_s",
                    format!(
                        "non-uniform time: {} after {} (step {} s, median step {} s): {why}",
                        t_s[k],
                        t_s[k - 1],
                        crate::validate::Shown(step),
                        crate::validate::Shown(median_step)
                    ),
                ));
            }
        }
        // Gaps (rows the logger dropped) are filled when they are few; the declared period is
        // then the grid's, not the mean step.
        let grid = crate::io::grid::Grid::of(t_s);
        let dt = if grid.filled() > 0 {
            if let Some(why) = crate::io::grid::gaps_refused(&grid) {
                let first = grid
                    .index
                    .windows(2)
                    .position(|w| w[1] > w[0] + 1)
                    .unwrap_or(0);
                return Err(self.field_err(
                    line_of(first + 1),
                    "t_s",
                    format!("non-uniform time: {why}"),
                ));
            }
            grid.dt_s
        } else {
            dt
        };
        let tol = 0.01 * dt;
        // A time column in another unit (ms written under `t_s`): the step range of a rig's
        // import, 100 kHz .. 10 Hz.
        let range = STEP_RANGE_S;
        if n >= 2 && !range.contains(median_step) {
            return Err(self.field_err(
                line_of(1),
                "t_s",
                format!(
                    "the median time step is {} s, outside {range} s (100 kHz .. 10 Hz): is \
                     the time column in another unit ({})?",
                    crate::validate::Shown(median_step),
                    if median_step > range.hi {
                        "ms written as s"
                    } else {
                        "us written as s"
                    }
                ),
            ));
        }
        self.check_declared_period(dt, tol)
    }

    /// A `# sample_period_s = ...` metadata entry must agree with the time column's `dt_s`
    /// within `tol_s`.
    pub(crate) fn check_declared_period(
        &self,
        dt_s: f64,
        tol_s: f64,
    ) -> Result<(), RecordingError> {
        for (i, (k, v)) in self.metadata.iter().enumerate() {
            if k == "sample_period_s" {
                let line = self.meta_line_of[i];
                let declared: f64 = v.parse().map_err(|_| {
                    self.field_err(line, "sample_period_s", format!("not a number: {v:?}"))
                })?;
                let d = (declared - dt_s).abs();
                if d.is_nan() || d > tol_s {
                    return Err(self.field_err(
                        line,
                        "sample_period_s",
                        format!("declares {declared} s but the time column steps by {dt_s} s"),
                    ));
                }
            }
        }
        Ok(())
    }
}
