//! Streaming open-loop replay of a recording file (`simulate --inputs`): a pipeline of three
//! threads over chunks of rows,
//!
//! reader (file blocks -> rows) -> simulator (integration, sensor path) -> writer (formatting),
//!
//! so reading, simulating and writing overlap, and memory does not grow with the recording
//! beyond its time column (kept for the checks that need every stamp: the median step, the
//! uniform grid). The output is byte-identical to [`Recording::read`](super::recording::Recording::read),
//! then [`simulate_recording`], then [`Recording::write`](super::recording::Recording::write):
//! the same row parser, the same integrator calls (runs of identical inputs are integrated
//! as one segment, also across chunk boundaries), the same sensor path and number formatting.
//!
//! The mean sample period (first to last stamp over the number of rows) is needed before the
//! first integration step. The number of rows follows from the first block and the file's
//! last row when the uniform grid the stream requires leaves one possible count
//! ([`rows_from_ends`]; the 20 s fixture); otherwise the writer thread counts them in a pass
//! over the file while the reader already parses. The passes read the file in blocks of
//! [`REPLAY_BLOCK_BYTES`] into buffers they reuse, and the writer thread formats the
//! simulated rows (the reader and the simulator are the two busy threads).
//!
//! The stream only takes the ordinary case: a plain (quote-free) UTF-8 file whose rows all
//! parse, whose time stamps are uniform and pass the recording checks, and a simulation that
//! succeeds. Anything else — a jittered recording, any error in the file or in the
//! simulation — makes [`replay_file`] answer `None`, and the caller runs the whole-recording
//! path, which reports the error with its file, line and field exactly as before (the
//! caller discards what was written).

use std::io::{Read as _, Seek as _, Write};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;

use crate::io::recording::{self, Channel, RecordingError, RowParser, RowSink, Table};
use crate::plant::{Plant, PlantState, ValveInputs};
use crate::sim::replay::{simulate_chunks, OutChunk, RowChunk, CHUNK_ROWS};
use crate::sim::{
    simulate_stamped, simulate_with_progress, SimError, SimStats, Simulation, SolverOptions,
};

/// Bytes read from the file at a time (whole lines) by [`RowStream`].
const BLOCK_BYTES: usize = 4 << 20;
/// Bytes read at a time by [`replay_file`]'s passes, each into one buffer it reuses: small
/// enough that the buffer's pages are faulted in once (a block of the whole file would take
/// a page fault per 4 KiB of it), large enough that the read calls cost little.
const REPLAY_BLOCK_BYTES: usize = 64 << 10;
/// Chunks in flight between two threads (bounds the memory of the pipeline).
const CHANNEL_CHUNKS: usize = 8;

/// The recording of a replay of `source`: its time stamps and valve inputs, the channels
/// `plant` measures along the simulated `states` (one per sample), and `metadata`.
pub fn replay_recording(
    plant: &Plant,
    source: &crate::io::recording::Recording,
    states: &[PlantState],
    metadata: Vec<(String, String)>,
) -> crate::io::recording::Recording {
    use crate::io::recording::{Channel, Recording};
    let mut out = Recording {
        metadata,
        t_s: source.t_s.clone(),
        inputs: source.inputs.clone(),
        ..Default::default()
    };
    let meas = plant.measure_series(states, source.sample_period_s());
    for c in Channel::ALL {
        out.set_channel(c, meas.iter().map(|m| c.of(m)).collect());
    }
    out
}

/// Replays a recording's valve inputs open loop: [`simulate_with_progress`] on a uniform
/// recording, [`simulate_stamped`] on a jittered one (inputs held between its stamps).
pub fn simulate_recording(
    plant: &Plant,
    rec: &crate::io::recording::Recording,
    opts: &SolverOptions,
    progress: impl FnMut(usize),
) -> Result<Simulation, SimError> {
    if rec.is_uniform() {
        simulate_with_progress(plant, &rec.inputs, rec.sample_period_s(), opts, progress)
    } else {
        simulate_stamped(plant, &rec.t_s, &rec.inputs, opts, progress)
    }
}

/// What a streamed replay did.
#[derive(Debug, Clone)]
pub struct StreamedReplay {
    /// Rows read and written.
    pub samples: usize,
    /// The mean sample period (first to last stamp).
    pub dt_s: f64,
    /// The integrator's counters (the same as the whole-recording path's).
    pub stats: SimStats,
    /// The input recording's metadata.
    pub metadata: Vec<(String, String)>,
}

/// Replays the valve inputs of the recording file `input` open loop on `plant` and writes
/// the output recording (metadata `out_metadata(dt_s)`, header, the input's `t_s` and
/// openings, the five simulated channels) to `w`, streaming. `progress(k)`: rows written.
///
/// `Ok(None)`: not done by the stream (see the module documentation); what was written to
/// `w` must be discarded and the whole-recording path run instead. `Err`: writing `w` failed.
pub fn replay_file(
    plant: &Plant,
    input: &Path,
    opts: &SolverOptions,
    out_metadata: impl FnOnce(f64) -> Vec<(String, String)>,
    w: &mut impl Write,
    progress: &(dyn Fn(usize) + Sync),
) -> std::io::Result<Option<StreamedReplay>> {
    let Ok(file) = std::fs::File::open(input) else {
        return Ok(None);
    };
    let mut blocks = Blocks::with_block_bytes(file, REPLAY_BLOCK_BYTES);
    let mut first = Vec::new();
    let Ok(true) = blocks.next_block_into(&mut first) else {
        return Ok(None);
    };
    let Ok(first_text) = std::str::from_utf8(&first) else {
        return Ok(None);
    };
    let Ok(table) = Table::parse(first_text, input) else {
        return Ok(None);
    };
    let Ok(parser) = RowParser::of(&table) else {
        return Ok(None);
    };
    let (data, data_line) = table.data();
    let mut first_count = RowCount::default();
    first_count.add(data);
    let known = rows_from_ends(input, first.len() as u64, &first_count, &table, &parser);

    let abort = AtomicBool::new(false);
    let (valid, sim, written, write_result, n_dt) =
        std::thread::scope(|s| -> std::io::Result<_> {
            let (tx_rows, rx_rows) = mpsc::sync_channel::<RowChunk>(CHANNEL_CHUNKS);
            let (tx_out, rx_out) = mpsc::sync_channel::<OutChunk>(CHANNEL_CHUNKS);
            // The row count and mean step, from the counting pass of this thread.
            let (tx_dt_sim, rx_dt_sim) = mpsc::sync_channel::<f64>(1);
            let (tx_n_dt_reader, rx_n_dt_reader) = mpsc::sync_channel::<(usize, f64)>(1);
            // Simulated rows the writer has formatted go back to the simulator for the next rows
            // (fresh buffers would cost a page fault every 4 KiB).
            let (tx_spent, rx_spent) = mpsc::channel::<OutChunk>();
            // The same for the parsed rows' buffers, from the simulator back to the reader.
            let (tx_spent_rows, rx_spent_rows) = mpsc::channel::<RowChunk>();
            let abort = &abort;
            let table = &table;
            let parser = &parser;
            let first = &first;
            // The reader reads the file itself, block by block into one buffer, while this
            // thread counts its rows.
            let reader = std::thread::Builder::new()
                .name("replay-reader".into())
                .spawn_scoped(s, move || {
                    let source = ReaderSource {
                        input,
                        first_len: first.len() as u64,
                        data,
                        data_line,
                        table,
                        parser,
                    };
                    read_rows(&source, abort, tx_rows, &rx_spent_rows, &rx_n_dt_reader)
                })?;
            let simulator = std::thread::Builder::new()
                .name("replay-simulator".into())
                .spawn_scoped(s, move || {
                    let r = match rx_dt_sim.recv() {
                        Ok(dt_s) => simulate_chunks(
                            plant,
                            dt_s,
                            opts,
                            rx_rows,
                            &tx_out,
                            &tx_spent_rows,
                            &rx_spent,
                            abort,
                        ),
                        Err(_) => Err(()),
                    };
                    if r.is_err() {
                        abort.store(true, Ordering::Relaxed);
                    }
                    r
                })?;
            // The number of rows and the mean sample period (needed before the first
            // integration step): from the file's two ends, or counted here while the reader
            // parses.
            let n_dt = match known {
                Some(n_dt) => Some(n_dt),
                None => count_rows(&mut blocks, first_count, table, parser),
            };
            let mut write_result = Ok(());
            if let Some((n, dt_s)) = n_dt {
                let _ = tx_dt_sim.send(dt_s);
                let _ = tx_n_dt_reader.send((n, dt_s));
                write_result = recording::write_head(&out_metadata(dt_s), &Channel::ALL, &[], w);
            } else {
                abort.store(true, Ordering::Relaxed);
            }
            drop((tx_dt_sim, tx_n_dt_reader));
            // The writer formats the simulated rows (the simulator and the reader keep the two
            // cores busy; this thread would otherwise wait).
            let written = write_rows(
                rx_out,
                w,
                &mut write_result,
                n_dt.is_some(),
                abort,
                progress,
                &tx_spent,
            );
            let valid = reader.join().unwrap_or(false);
            let sim = simulator.join().unwrap_or(Err(()));
            Ok((valid, sim, written, write_result, n_dt))
        })?;
    write_result?;
    match (sim, n_dt) {
        (Ok(stats), Some((n, dt_s))) if valid && written == n => Ok(Some(StreamedReplay {
            samples: n,
            dt_s,
            stats,
            metadata: table.metadata.clone(),
        })),
        _ => Ok(None),
    }
}

/// The input file as the reader thread sees it: the first block's data rows (already read)
/// and where the rest of the file starts.
struct ReaderSource<'a, 't> {
    input: &'a Path,
    first_len: u64,
    data: &'a [u8],
    data_line: u64,
    table: &'a Table<'t>,
    parser: &'a RowParser,
}

/// The reader thread: parses the data rows chunk by chunk into `tx_rows` (reusing the
/// buffers that come back on `rx_spent_rows`), then checks the whole time column against the
/// row count and mean step the counting pass sends on `rx_n_dt` (the checks of
/// `Recording::parse` that need the whole column, and the uniform grid the replay assumed).
/// `false`: not a recording the stream can replay.
fn read_rows(
    source: &ReaderSource<'_, '_>,
    abort: &AtomicBool,
    tx_rows: mpsc::SyncSender<RowChunk>,
    rx_spent_rows: &mpsc::Receiver<RowChunk>,
    rx_n_dt: &mpsc::Receiver<(usize, f64)>,
) -> bool {
    let ReaderSource {
        input,
        first_len,
        data,
        data_line,
        table,
        parser,
    } = *source;
    let mut t_all: Vec<f64> = Vec::new();
    let mut line = data_line;
    let mut feed = |bytes: &[u8]| -> bool {
        if memchr::memchr(b'"', bytes).is_some() || std::str::from_utf8(bytes).is_err() {
            return false;
        }
        let mut start = 0;
        while start < bytes.len() {
            if abort.load(Ordering::Relaxed) {
                return false;
            }
            let rest = &bytes[start..];
            let (end, lines) = match memchr::memchr_iter(b'\n', rest).nth(CHUNK_ROWS - 1) {
                Some(i) => (start + i + 1, CHUNK_ROWS as u64),
                None => (bytes.len(), memchr::memchr_iter(b'\n', rest).count() as u64),
            };
            let piece = &bytes[start..end];
            let mut chunk = match rx_spent_rows.try_recv() {
                Ok(mut c) => {
                    c.t_s.clear();
                    c.inputs.clear();
                    c
                }
                Err(_) => RowChunk::default(),
            };
            chunk.reserve(CHUNK_ROWS);
            if !parser.parse_plain_rows(piece, &mut chunk) {
                match table.read_chunk::<_, RowChunk>(piece, line, 0, &|r| parser.parse(r)) {
                    Ok((c, _)) => chunk = c,
                    Err(_) => return false,
                }
            }
            line += lines;
            t_all.extend_from_slice(&chunk.t_s);
            if tx_rows.send(chunk).is_err() {
                return false;
            }
            start = end;
        }
        true
    };
    // The first block is in memory (and UTF-8: it was checked for the table).
    let fed = feed(data) && stream_blocks(input, first_len, &mut feed);
    drop(tx_rows);
    let Ok((n, dt_s)) = rx_n_dt.recv() else {
        return false;
    };
    // The checks of `Recording::parse` that need the whole time column, and the
    // uniform grid the replay assumed.
    fed && t_all.len() == n
        && recording::mean_step_s(&t_all) == dt_s
        && table.check_time(&t_all, |_| 0).is_ok()
        && recording::stamps_uniform(&t_all)
}

/// The writer: formats the simulated rows of `rx_out` to `w` until they end or writing
/// fails (then `write_result` holds the error and the run is aborted); `counted`: the row
/// count is known (else nothing is written). Returns the rows written; `rx_out` is dropped
/// on return, so a simulator still sending stops.
fn write_rows(
    rx_out: mpsc::Receiver<OutChunk>,
    w: &mut impl Write,
    write_result: &mut std::io::Result<()>,
    counted: bool,
    abort: &AtomicBool,
    progress: &(dyn Fn(usize) + Sync),
    tx_spent: &mpsc::Sender<OutChunk>,
) -> usize {
    let mut written = 0usize;
    let mut text = Vec::with_capacity(CHUNK_ROWS * 80);
    let mut row = [0u8; recording::ROW_BYTES];
    for chunk in rx_out {
        if write_result.is_err() || !counted {
            abort.store(true, Ordering::Relaxed);
            break;
        }
        text.clear();
        for (t, u, m) in &chunk.rows {
            recording::push_row_in(&mut row, &mut text, *t, u, m.iter().copied());
        }
        if let Err(e) = w.write_all(&text) {
            abort.store(true, Ordering::Relaxed);
            *write_result = Err(e);
            break;
        }
        written += chunk.rows.len();
        progress(written);
        let _ = tx_spent.send(chunk);
    }
    written
}

/// The time stamp of the data row `line` (the general row reader's), `None` if it does not
/// parse.
fn time_of(table: &Table<'_>, parser: &RowParser, line: &[u8]) -> Option<f64> {
    let (v, _): (Vec<_>, _) = table.read_chunk(line, 1, 0, &|r| parser.parse(r)).ok()?;
    (v.len() == 1).then(|| v[0].0)
}

/// The number of rows and the mean step of [`replay_file`] (`recording::mean_step_s` of the
/// whole column: first to last stamp over the rows) from the two ends of the file alone,
/// without a pass over it: `first` counts the rows of the first block (the file's bytes up
/// to `data_end`), the last row is read from the file's last [`REPLAY_BLOCK_BYTES`].
///
/// Between the two ends the count follows from the sample period: a recording the stream
/// takes has every stamp within `UNIFORM_TOLERANCE` of a step of the uniform grid of the
/// mean step (`recording::stamps_uniform`, checked at the end), so the first block's mean
/// step over `k` steps is within `UNIFORM_TOLERANCE / k` of the whole file's, and the span
/// over it gives the number of steps up to that share. `None` when that range holds more
/// than one whole number (a long file, a short first block) or an end is not a plain row:
/// the caller counts the rows. A count that is still wrong (a file that is not uniform,
/// or changed under us) is caught by the reader's checks of the whole column, and the
/// stream is left to the whole-recording path.
fn rows_from_ends(
    input: &Path,
    data_end: u64,
    first: &RowCount,
    table: &Table<'_>,
    parser: &RowParser,
) -> Option<(usize, f64)> {
    let mut file = std::fs::File::open(input).ok()?;
    let size = file.metadata().ok()?.len();
    if size <= data_end {
        return None;
    }
    let tail_start = size.saturating_sub(REPLAY_BLOCK_BYTES as u64).max(data_end);
    file.seek(std::io::SeekFrom::Start(tail_start)).ok()?;
    let mut tail = Vec::new();
    file.take(size - tail_start).read_to_end(&mut tail).ok()?;
    let whole_rest = tail_start == data_end;
    let lines = if whole_rest {
        &tail[..]
    } else {
        // From the first line end on (the tail starts inside a line).
        &tail[memchr::memchr(b'\n', &tail)? + 1..]
    };
    let mut end = RowCount::default();
    end.add(lines);
    let t_first = time_of(table, parser, first.first.as_deref()?)?;
    let t_last = time_of(table, parser, end.last.as_deref()?)?;
    let n = if whole_rest {
        first.rows + end.rows
    } else {
        let k = first.rows.checked_sub(1).filter(|&k| k >= 1)?;
        let step_s = (time_of(table, parser, first.last.as_deref()?)? - t_first) / k as f64;
        let steps = (t_last - t_first) / step_s;
        // The share above, with a margin for the rounding of the stamps and of these
        // divisions.
        let share = 1.5 * recording::UNIFORM_TOLERANCE / k as f64 + 1e-9;
        let (lo, hi) = (steps * (1.0 - share), steps * (1.0 + share));
        if !(lo > 0.0 && hi < 1e15 && hi.floor() == lo.ceil()) {
            return None;
        }
        let n = hi.floor() as usize + 1;
        if n < first.rows + end.rows {
            return None;
        }
        n
    };
    if n < 2 {
        return None;
    }
    let dt_s = (t_last - t_first) / (n - 1) as f64;
    (dt_s > 0.0).then_some((n, dt_s))
}

/// The counting pass of [`replay_file`]: the number of data rows of the file (`first`
/// counted the rows of its first block; the blocks of `blocks` are read into one buffer)
/// and the mean sample period from the first and last stamp, `recording::mean_step_s` of
/// the whole column; `None` if the file cannot be replayed by the stream.
fn count_rows(
    blocks: &mut Blocks,
    mut count: RowCount,
    table: &Table<'_>,
    parser: &RowParser,
) -> Option<(usize, f64)> {
    let mut block = Vec::new();
    loop {
        match blocks.next_block_into(&mut block) {
            Ok(true) => count.add(&block),
            Ok(false) => break,
            Err(_) => return None,
        }
    }
    let n = count.rows;
    let t_first = time_of(table, parser, count.first.as_deref()?)?;
    let t_last = time_of(table, parser, count.last.as_deref()?)?;
    if n < 2 {
        return None;
    }
    let dt_s = (t_last - t_first) / (n - 1) as f64;
    (dt_s > 0.0).then_some((n, dt_s))
}

/// The rows of a recording file one at a time, read block by block (memory: one block and
/// one chunk of parsed rows), for the streaming commands that need every column (`fit`).
/// Rows are parsed by the fast path ([`RowParser::parse_plain_rows`]), a chunk it does not
/// take by the general row reader; quoted fields or any error is `Err(())`, and the caller
/// leaves the file to [`Recording::parse`](super::recording::Recording::parse), which words
/// the error.
pub(crate) struct RowStream {
    path: std::path::PathBuf,
    /// The metadata and header lines (for [`Self::check_time`]).
    head: String,
    parser: RowParser,
    blocks: Blocks,
    /// The unparsed rest of the current block.
    block: Vec<u8>,
    block_pos: usize,
    rows: Vec<(f64, [f64; 4], [f64; 5])>,
    row_pos: usize,
}

/// A parsed row: time, openings, output channels by [`Channel::index`] (absent ones 0).
pub(crate) type ParsedRow = (f64, [f64; 4], [f64; 5]);

impl RowStream {
    /// Opens `path` and reads its metadata and header; `None` if the stream cannot take it.
    pub(crate) fn open(path: &Path) -> Option<Self> {
        let mut blocks = Blocks::new(std::fs::File::open(path).ok()?);
        let first = blocks.next_block().ok()??;
        let text = std::str::from_utf8(&first).ok()?;
        let table = Table::parse(text, path).ok()?;
        let parser = RowParser::of(&table).ok()?;
        let (data, _) = table.data();
        let data_offset = data.as_ptr() as usize - first.as_ptr() as usize;
        let head = text[..data_offset].to_owned();
        drop(table);
        Some(Self {
            path: path.to_owned(),
            head,
            parser,
            blocks,
            block: first,
            block_pos: data_offset,
            rows: Vec::new(),
            row_pos: 0,
        })
    }

    /// The output channels the file has, by [`Channel::index`].
    pub(crate) fn channels(&self) -> [bool; 5] {
        self.parser.out_cols.map(|c| c.is_some())
    }

    /// The next row; `Ok(None)` at the end of the file, `Err(())` if a row is not plain.
    pub(crate) fn next_row(&mut self) -> Result<Option<ParsedRow>, ()> {
        while self.row_pos == self.rows.len() {
            self.rows.clear();
            self.row_pos = 0;
            if self.block_pos == self.block.len() {
                match self.blocks.next_block() {
                    Ok(Some(b)) => {
                        if std::str::from_utf8(&b).is_err() {
                            return Err(());
                        }
                        self.block = b;
                        self.block_pos = 0;
                    }
                    Ok(None) => return Ok(None),
                    Err(_) => return Err(()),
                }
            }
            let rest = &self.block[self.block_pos..];
            let end = memchr::memchr_iter(b'\n', rest)
                .nth(CHUNK_ROWS - 1)
                .map_or(rest.len(), |i| i + 1);
            if memchr::memchr(b'"', &rest[..end]).is_some() {
                return Err(());
            }
            if !self.parser.parse_plain_rows(&rest[..end], &mut self.rows) {
                // Rows the fast path does not take (e.g. a time stamp with more digits than
                // it reads): the general row reader, as `Recording::read` has it.
                let table = Table::parse(&self.head, &self.path).map_err(|_| ())?;
                let (rows, _) = table
                    .read_chunk::<_, Vec<ParsedRow>>(&rest[..end], 1, 0, &|r| self.parser.parse(r))
                    .map_err(|_| ())?;
                self.rows = rows;
            }
            self.block_pos += end;
        }
        self.row_pos += 1;
        Ok(Some(self.rows[self.row_pos - 1]))
    }

    /// Whether the whole time column `t_s` passes the checks of
    /// [`Recording::read`](super::recording::Recording::read) (at least two rows, increasing,
    /// no gap, the declared sample period).
    pub(crate) fn check_time(&self, t_s: &[f64]) -> bool {
        Table::parse(&self.head, &self.path).is_ok_and(|t| t.check_time(t_s, |_| 0).is_ok())
    }
}

impl recording::Recording {
    /// Reads and validates a recording file.
    ///
    /// Memory: the columns the file has; a plain file is parsed block by block without its
    /// text (`replay_stream::read_recording`), anything else is read whole.
    pub fn read(path: impl AsRef<Path>) -> Result<Self, RecordingError> {
        let path = path.as_ref();
        if let Some(rec) = read_recording(path) {
            return Ok(rec);
        }
        Self::parse(&recording::read_text(path)?, path)
    }
}

/// [`Recording::read`](super::recording::Recording::read) of a file without holding its
/// text: the rows are parsed block by block ([`RowStream`]) into the columns the file has
/// (time, openings and the output channels present: 8 + 32 + 8 per channel bytes a row).
/// The same row parser and the same time checks, so the recording is `read`'s to the bit.
/// `None` when the stream does not take the file (quoted fields, mass-flow columns, a time
/// column the checks refuse, any error): the caller reads it whole, which words the error.
pub(crate) fn read_recording(path: &Path) -> Option<recording::Recording> {
    let mut rows = RowStream::open(path)?;
    let table = Table::parse(&rows.head, path).ok()?;
    for name in recording::MASS_FLOW_COLUMNS {
        if table.find(name).ok()?.is_some() {
            return None;
        }
    }
    let metadata = table.metadata.clone();
    drop(table);
    let present = rows.channels();
    let mut t_s = Vec::new();
    let mut inputs = Vec::new();
    let mut outputs: [Vec<f64>; 5] = Default::default();
    while let Some((t, u, y)) = rows.next_row().ok()? {
        t_s.push(t);
        inputs.push(ValveInputs::from_openings(u));
        for (i, col) in outputs.iter_mut().enumerate() {
            if present[i] {
                col.push(y[i]);
            }
        }
    }
    if !rows.check_time(&t_s) {
        return None;
    }
    // The columns grew by doubling: give back what they did not use.
    t_s.shrink_to_fit();
    inputs.shrink_to_fit();
    outputs.iter_mut().for_each(Vec::shrink_to_fit);
    let mut rec = recording::Recording {
        metadata,
        t_s,
        inputs,
        ..Default::default()
    };
    for (i, col) in outputs.into_iter().enumerate() {
        if present[i] {
            rec.outputs[i] = Some(col);
        }
    }
    Some(rec)
}

impl RowSink<(f64, [f64; 4], [f64; 5])> for RowChunk {
    // The replay reads the readings only to refuse a file `Recording::read` would refuse.
    const WANTS_OUTPUTS: bool = false;
    fn reserve(&mut self, n: usize) {
        self.t_s.reserve(n);
        self.inputs.reserve(n);
    }
    fn push(&mut self, (t_s, u, _): (f64, [f64; 4], [f64; 5])) {
        self.t_s.push(t_s);
        self.inputs.push(ValveInputs::from_openings(u));
    }
    fn append(&mut self, mut other: Self) {
        self.t_s.append(&mut other.t_s);
        self.inputs.append(&mut other.inputs);
    }
}

/// The rows of the data part as `Table::read_chunk` sees them (lines that are not empty once
/// a trailing `\r` is removed), with the first and the last one.
#[derive(Default)]
struct RowCount {
    rows: usize,
    first: Option<Vec<u8>>,
    last: Option<Vec<u8>>,
}

impl RowCount {
    /// Counts the lines of `bytes` (whole lines, or the file's tail).
    fn add(&mut self, bytes: &[u8]) {
        if self.add_without_empty_lines(bytes) {
            return;
        }
        self.add_line_by_line(bytes);
    }

    /// [`Self::add_line_by_line`] when `bytes` has no empty line (nor a lone `\r`, which
    /// counts as one): the rows are then the line ends, counted by one vectorised pass, plus
    /// an unfinished tail. `false` (nothing counted) when an empty line may be present.
    fn add_without_empty_lines(&mut self, bytes: &[u8]) -> bool {
        let (Some(&head), Some(&tail)) = (bytes.first(), bytes.last()) else {
            return true;
        };
        if head == b'\n'
            || head == b'\r'
            || memchr::memmem::find(bytes, b"\n\n").is_some()
            || memchr::memmem::find(bytes, b"\n\r").is_some()
        {
            return false;
        }
        let ends = memchr::memchr_iter(b'\n', bytes).count();
        self.rows += ends + usize::from(tail != b'\n');
        if self.first.is_none() {
            let raw = &bytes[..memchr::memchr(b'\n', bytes).unwrap_or(bytes.len())];
            self.first = Some(raw.strip_suffix(b"\r").unwrap_or(raw).to_vec());
        }
        // The last row: the last line, without its line end and `\r`.
        let body = bytes.strip_suffix(b"\n").unwrap_or(bytes);
        let start = memchr::memrchr(b'\n', body).map_or(0, |i| i + 1);
        let raw = &body[start..];
        self.last = Some(raw.strip_suffix(b"\r").unwrap_or(raw).to_vec());
        true
    }

    /// Counts the lines of `bytes` one by one, skipping empty ones.
    fn add_line_by_line(&mut self, bytes: &[u8]) {
        let mut last: Option<&[u8]> = None;
        let ends = memchr::memchr_iter(b'\n', bytes).chain(std::iter::once(bytes.len()));
        let mut start = 0;
        for end in ends {
            if start > bytes.len() {
                break;
            }
            let raw = &bytes[start..end];
            start = end + 1;
            let row = raw.strip_suffix(b"\r").unwrap_or(raw);
            if !row.is_empty() {
                self.rows += 1;
                if self.first.is_none() {
                    self.first = Some(row.to_vec());
                }
                last = Some(row);
            }
        }
        if let Some(l) = last {
            self.last = Some(l.to_vec());
        }
    }
}

/// A file read in blocks of whole lines.
struct Blocks {
    file: std::fs::File,
    /// Bytes read at a time.
    block_bytes: usize,
    /// The bytes after the last line end of the previous read.
    carry: Vec<u8>,
    eof: bool,
    /// Bytes left in the file by its size (a hint: the file may change).
    left_hint: u64,
}

impl Blocks {
    /// The blocks of `file` from its current position, [`BLOCK_BYTES`] at a time.
    fn new(file: std::fs::File) -> Self {
        Self::with_block_bytes(file, BLOCK_BYTES)
    }

    /// The blocks of `file` from its current position, `block_bytes` at a time.
    fn with_block_bytes(mut file: std::fs::File, block_bytes: usize) -> Self {
        let size = file.metadata().map_or(0, |m| m.len());
        let pos = file.stream_position().unwrap_or(0);
        Self {
            file,
            block_bytes,
            carry: Vec::new(),
            eof: false,
            left_hint: size.saturating_sub(pos),
        }
    }

    /// The next block: whole lines (ending with `\n`), or the rest of the file at its end;
    /// `None` after the end.
    fn next_block(&mut self) -> std::io::Result<Option<Vec<u8>>> {
        let mut buf = Vec::new();
        Ok(self.next_block_into(&mut buf)?.then_some(buf))
    }

    /// [`Self::next_block`] into `buf` (its old content dropped, its memory reused); `false`
    /// after the end.
    fn next_block_into(&mut self, buf: &mut Vec<u8>) -> std::io::Result<bool> {
        buf.clear();
        buf.extend_from_slice(&self.carry);
        self.carry.clear();
        loop {
            if self.eof {
                return Ok(!buf.is_empty());
            }
            // One read call for a block (asking one byte more than a file of at most one
            // block holds finds its end in the same call), into the buffer's spare capacity
            // (not zeroed first).
            let before = buf.len();
            let left = usize::try_from(self.left_hint).unwrap_or(usize::MAX);
            let want = self.block_bytes.min(left.saturating_add(1)).max(1);
            buf.reserve(want);
            let got = (&mut self.file).take(want as u64).read_to_end(buf)?;
            self.eof = got < want;
            self.left_hint = self.left_hint.saturating_sub(got as u64);
            if self.eof {
                continue;
            }
            if let Some(i) = memchr::memrchr(b'\n', &buf[before..]) {
                self.carry.extend_from_slice(&buf[before + i + 1..]);
                buf.truncate(before + i + 1);
                return Ok(true);
            }
            // No line end yet: a line this long is refused (`recording::read_text` words
            // the error), so it is not read any further.
            if buf.len() > recording::MAX_HEAD_LINE_BYTES {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::InvalidData,
                    "a line longer than a recording accepts",
                ));
            }
        }
    }
}

/// Reads `path` from byte `offset` in blocks of whole lines ([`REPLAY_BLOCK_BYTES`], into
/// one buffer) through `feed` until it answers false or the file ends; whether every block
/// was fed.
fn stream_blocks(path: &Path, offset: u64, feed: &mut impl FnMut(&[u8]) -> bool) -> bool {
    let Ok(mut file) = std::fs::File::open(path) else {
        return false;
    };
    if file.seek(std::io::SeekFrom::Start(offset)).is_err() {
        return false;
    }
    let mut blocks = Blocks::with_block_bytes(file, REPLAY_BLOCK_BYTES);
    let mut block = Vec::new();
    loop {
        match blocks.next_block_into(&mut block) {
            Ok(true) => {
                if !feed(&block) {
                    return false;
                }
            }
            Ok(false) => return true,
            Err(_) => return false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use rand::{Rng as _, SeedableRng as _};

    /// A row count and mean step.
    type Counted = Option<(usize, f64)>;

    /// The count and mean step [`rows_from_ends`] gives for the recording `text` (written to
    /// `path`), and the counting pass's.
    fn from_ends_and_counted(path: &Path, text: &str) -> (Counted, Counted) {
        std::fs::write(path, text).unwrap();
        let mut blocks =
            Blocks::with_block_bytes(std::fs::File::open(path).unwrap(), REPLAY_BLOCK_BYTES);
        let mut first = Vec::new();
        assert!(blocks.next_block_into(&mut first).unwrap());
        let table = Table::parse(std::str::from_utf8(&first).unwrap(), path).unwrap();
        let parser = RowParser::of(&table).unwrap();
        let mut count = RowCount::default();
        count.add(table.data().0);
        let ends = rows_from_ends(path, first.len() as u64, &count, &table, &parser);
        (ends, count_rows(&mut blocks, count, &table, &parser))
    }

    /// The count from the file's ends is the counting pass's (or left to it) for every
    /// recording the stream takes (uniform stamps), with stamps on the grid and jittered up
    /// to the tolerance, sample periods that are not a whole number of microseconds, short
    /// and long files, blank lines at the end; the 20 s recording at 1 kHz is counted from
    /// its ends.
    #[test]
    fn row_counts_from_the_ends_are_the_counting_passes() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("rec.csv");
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let mut from_ends = 0;
        for (rows, dt_s, jitter, tail) in [
            (20_001, 0.001, 0.0, ""),
            (20_001, 0.001, 0.0, "\n\n"),
            (900, 0.001, 0.0, ""),
            (1_500, 1.0 / 3.0, 0.0, ""),
            (4_000, 1.0 / 3.0, 0.0, ""),
            (60_000, 1.0 / 3.0, 0.0, ""),
            (200_000, 0.001, 0.0, ""),
            (20_001, 0.001, 0.004, ""),
            (200_000, 1.0 / 7.0, 0.004, "\r\n"),
            (20_001, 0.002, 0.2, ""),
        ] {
            let mut text =
                String::from("# sample_period_s = 0.001\nt_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg\n");
            let mut t_s = Vec::with_capacity(rows);
            for k in 0..rows {
                let j = if k == 0 {
                    0.0
                } else {
                    jitter * rng.random_range(-1.0..1.0)
                };
                let t = format!("{:.6}", (k as f64 + j) * dt_s);
                t_s.push(t.parse::<f64>().unwrap());
                text += &format!("{t},0,1,0.25,0,1.5\n");
            }
            text += tail;
            let (ends, counted) = from_ends_and_counted(&path, &text);
            assert_eq!(counted.map(|c| c.0), Some(rows));
            if let Some(e) = ends {
                if recording::stamps_uniform(&t_s) {
                    assert_eq!(Some(e), counted, "{rows} rows, dt {dt_s}, jitter {jitter}");
                }
                from_ends += 1;
            } else {
                // A file of one block is counted in it; a long or jittered one is counted.
                assert!(
                    text.len() <= REPLAY_BLOCK_BYTES || rows > 20_001 || jitter > 0.01,
                    "{rows} rows, dt {dt_s} not from the ends"
                );
            }
        }
        assert!(from_ends >= 4, "{from_ends}");
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(5_000))]
        /// The counting pass with its fast path for blocks without empty lines gives the
        /// line-by-line count, first and last row, over blocks of lines of `a`, `\r`, `\n`.
        #[test]
        fn row_counts_match_the_line_by_line_count(
            blocks in proptest::collection::vec(
                proptest::collection::vec(prop_oneof![
                    4 => Just(b'a'), 1 => Just(b'\r'), 2 => Just(b'\n'), 1 => Just(b','),
                ], 0..40),
                1..4,
            ),
        ) {
            let (mut fast, mut slow) = (RowCount::default(), RowCount::default());
            for b in &blocks {
                fast.add(b);
                slow.add_line_by_line(b);
            }
            prop_assert_eq!(fast.rows, slow.rows);
            prop_assert_eq!(fast.first, slow.first);
            prop_assert_eq!(fast.last, slow.last);
        }
    }
}
