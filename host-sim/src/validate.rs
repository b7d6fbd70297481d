//! One validation layer for what a user types: command-line numbers (clap value parsers with
//! their allowed range), values in plant and scenario files (key, file, line and the allowed
//! range), input/output paths (an output may not be one of the inputs) and the size of a run
//! (estimated memory and time against a documented limit, `--allow-large` to go beyond).
//!
//! Ranges are physical or practical bounds, wide enough for any real rig and narrow enough to
//! catch a unit typed wrong (kPa in a Pa key) or a value that would exhaust the machine.

use std::fmt;
use std::path::{Path, PathBuf};

/// A closed or open interval of allowed values.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Range {
    /// Lower bound.
    pub lo: f64,
    /// Lower bound allowed itself.
    pub lo_incl: bool,
    /// Upper bound.
    pub hi: f64,
    /// Upper bound allowed itself.
    pub hi_incl: bool,
}

impl Range {
    /// `[lo, hi]`.
    pub const fn closed(lo: f64, hi: f64) -> Range {
        Range {
            lo,
            lo_incl: true,
            hi,
            hi_incl: true,
        }
    }
    /// `(0, hi]`.
    pub const fn positive(hi: f64) -> Range {
        Range {
            lo: 0.0,
            lo_incl: false,
            hi,
            hi_incl: true,
        }
    }
    /// `[lo, hi)`.
    pub const fn half_open(lo: f64, hi: f64) -> Range {
        Range {
            lo,
            lo_incl: true,
            hi,
            hi_incl: false,
        }
    }
    /// `(lo, hi)`.
    pub const fn open(lo: f64, hi: f64) -> Range {
        Range {
            lo,
            lo_incl: false,
            hi,
            hi_incl: false,
        }
    }

    /// Whether `v` is a finite number inside the range (NaN never is).
    pub fn contains(&self, v: f64) -> bool {
        v.is_finite()
            && (if self.lo_incl {
                v >= self.lo
            } else {
                v > self.lo
            })
            && (if self.hi_incl {
                v <= self.hi
            } else {
                v < self.hi
            })
    }

    /// `Ok(v)` inside the range, else the message "must be within ..., got v".
    pub fn check(&self, v: f64) -> Result<f64, String> {
        if self.contains(v) {
            Ok(v)
        } else {
            Err(format!("must be a number within {self}, got {}", Shown(v)))
        }
    }
}

impl fmt::Display for Range {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}{}, {}{}",
            if self.lo_incl { '[' } else { '(' },
            Shown(self.lo),
            Shown(self.hi),
            if self.hi_incl { ']' } else { ')' }
        )
    }
}

/// The message for a file value `v` of `key` outside `range` ("must be within [lo, hi]
/// UNIT, got v", with a hint when `v` kPa (or bar) typed into a Pa key would have been in range);
/// `None` inside it.
pub fn range_error(key: &str, v: f64, range: Range, unit: &str) -> Option<String> {
    // An initial pressure typed in kPa (a few hundred) reads as a few hundred pascals, inside
    // the range: such a small gauge pressure is atmospheric (0 says that), so it is refused
    // with the hint the other pressure keys give.
    if key.contains("initial.")
        && key.ends_with("_gauge_pa")
        && v != 0.0
        && v.abs() < INITIAL_PRESSURE_MIN_ABS_PA
        && range.contains(v * 1e3)
    {
        return Some(format!(
            "must be 0 or at least {} Pa in magnitude ({range} {unit}), got {} (kPa typed into \
             a Pa key? {} kPa is {} Pa)",
            Shown(INITIAL_PRESSURE_MIN_ABS_PA),
            Shown(v),
            Shown(v),
            Shown(v * 1e3)
        ));
    }
    if range.contains(v) {
        return None;
    }
    let mut msg = format!("must be within {range} {unit}, got {}", Shown(v));
    if key.ends_with("_pa") && v > 0.0 && range.contains(v * 1e3) {
        msg.push_str(&format!(
            " (kPa typed into a Pa key? {} kPa is {} Pa)",
            Shown(v),
            Shown(v * 1e3)
        ));
    } else if key.ends_with("_pa") && v > 0.0 && range.contains(v * 1e5) {
        msg.push_str(&format!(
            " (bar typed into a Pa key? {} bar is {} Pa)",
            Shown(v),
            Shown(v * 1e5)
        ));
    }
    Some(msg)
}

/// Smallest non-zero magnitude of an `[initial]` gauge pressure [Pa]: below it, a value is
/// a pressure in kPa typed into the Pa key.
pub const INITIAL_PRESSURE_MIN_ABS_PA: f64 = 1000.0;

/// One range check of a file value: its key, the value, the allowed range and the unit the
/// message names.
pub type RangeRow = (String, f64, Range, &'static str);

/// The rows of a range table: `range_rows![base, prefix; field.path: range, "unit"; ...]`
/// checks `base.field.path` under the key `prefix` + `field.path`, so that a key cannot
/// drift from the field it checks. Rows keep their order (the first error is reported).
macro_rules! range_rows {
    ($base:expr, $prefix:expr; $($first:ident $(. $rest:ident)* : $range:expr, $unit:expr;)+) => {
        vec![$((
            format!(concat!("{}", stringify!($first) $(, ".", stringify!($rest))*), $prefix),
            $base.$first $(.$rest)*,
            $range,
            $unit,
        )),+]
    };
}
pub(crate) use range_rows;

/// The first row outside its range: its key and [`range_error`]'s message.
pub fn first_range_error(rows: &[RangeRow]) -> Option<(&str, String)> {
    rows.iter()
        .find_map(|(key, v, range, unit)| Some((key.as_str(), range_error(key, *v, *range, unit)?)))
}

/// A number as an error message shows it: plain when it reads well, in exponent form when
/// it is very large or very small (a typed `1e300` is not echoed with 300 digits), and
/// without the last bits of a rounding error.
#[derive(Clone, Copy, Debug)]
pub struct Shown(pub f64);

impl fmt::Display for Shown {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let a = self.0.abs();
        if !self.0.is_finite() || a == 0.0 {
            return write!(f, "{}", self.0);
        }
        // At most 12 significant digits: 104.60800000000002 reads 104.608.
        let rounded: f64 = format!("{:.11e}", self.0).parse().unwrap_or(self.0);
        if (1e-6..1e9).contains(&a) {
            write!(f, "{rounded}")
        } else {
            write!(f, "{rounded:e}")
        }
    }
}

/// A clap value parser for an `f64` within `range` (NaN and infinities refused).
pub fn f64_in(
    range: Range,
) -> impl Fn(&str) -> Result<f64, String> + Clone + Send + Sync + 'static {
    move |s: &str| range.check(parse_trimmed(s, "a number", range)?)
}

/// A clap value parser for an `f64` within `range` of `unit` (a physical quantity): both
/// messages name the unit, so that `150ms` typed for seconds says what to give instead.
pub fn f64_in_unit(
    range: Range,
    unit: &'static str,
) -> impl Fn(&str) -> Result<f64, String> + Clone + Send + Sync + 'static {
    move |s: &str| {
        let v: f64 = s.trim().parse().map_err(|_| {
            format!("`{s}` is not a number: give {unit} within {range} as a plain number")
        })?;
        if range.contains(v) {
            Ok(v)
        } else {
            Err(format!(
                "must be a number of {unit} within {range}, got {}",
                Shown(v)
            ))
        }
    }
}

/// A clap value parser for a whole number within `lo..=hi`.
pub fn usize_in(
    lo: usize,
    hi: usize,
) -> impl Fn(&str) -> Result<usize, String> + Clone + Send + Sync + 'static {
    move |s: &str| whole_in(s, lo, hi)
}

/// A clap value parser for a whole number within `lo..=hi` (a seed: `0..=u64::MAX`).
pub fn u64_in(
    lo: u64,
    hi: u64,
) -> impl Fn(&str) -> Result<u64, String> + Clone + Send + Sync + 'static {
    move |s: &str| whole_in(s, lo, hi)
}

/// `s` as a whole number within `lo..=hi`; a negative or too large whole number is one, just
/// out of range (the message gives the range either way).
fn whole_in<T>(s: &str, lo: T, hi: T) -> Result<T, String>
where
    T: std::str::FromStr + PartialOrd + fmt::Display + Copy + TryInto<i128>,
{
    let wide = |x: T| x.try_into().unwrap_or(i128::MAX);
    if let Ok(v) = s.trim().parse::<i128>() {
        if v < wide(lo) || v > wide(hi) {
            return Err(format!("must be within {lo}..={hi}, got {v}"));
        }
    }
    let v: T = parse_trimmed(s, "a whole number", format!("{lo}..={hi}"))?;
    if lo <= v && v <= hi {
        Ok(v)
    } else {
        Err(format!("must be within {lo}..={hi}, got {v}"))
    }
}

/// `s` without surrounding blanks as a `T`; the error says it is not `what` and what is
/// `allowed`.
fn parse_trimmed<T: std::str::FromStr>(
    s: &str,
    what: &str,
    allowed: impl std::fmt::Display,
) -> Result<T, String> {
    s.trim()
        .parse()
        .map_err(|_| format!("`{s}` is not {what} (allowed: {allowed})"))
}

/// A clap value parser for a plot file: `.png` or `.svg` (checked before any work).
pub fn plot_path(s: &str) -> Result<PathBuf, String> {
    let p = PathBuf::from(s);
    let ext = p
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    if ext == "png" || ext == "svg" {
        Ok(p)
    } else {
        Err(format!(
            "{s}: unsupported plot format (use a .png or .svg file name)"
        ))
    }
}

/// Outputs named by labels of their own (`labels[i]` names `paths[i]`), as
/// [`distinct_file_outputs`] takes them.
pub fn labelled<'a>(labels: &'a [String], paths: &'a [PathBuf]) -> Vec<(&'a str, &'a Path)> {
    labels
        .iter()
        .zip(paths)
        .map(|(l, p)| (l.as_str(), p.as_path()))
        .collect()
}

/// What a command writes to a path: an existing file there that is of this kind is an
/// earlier output (replaced); anything else is a file the user would lose (refused before the
/// run, [`replaceable`]).
#[derive(Clone, Copy, Debug)]
pub enum OutputKind {
    /// A TOML file with one of these tables; `what` names the kind in the message.
    Toml {
        tables: &'static [&'static str],
        what: &'static str,
    },
    /// A CSV file whose header line (the first line that is not a `#` comment) starts with
    /// the column `first_column`.
    Csv {
        first_column: &'static str,
        what: &'static str,
    },
    /// A JSON object.
    Json { what: &'static str },
}

impl OutputKind {
    pub const RECORDING: OutputKind = OutputKind::Csv {
        first_column: "t_s",
        what: "a recording",
    };
    pub const PLANT: OutputKind = OutputKind::Toml {
        tables: &["muscle", "joint", "valve", "links"],
        what: "a plant file",
    };
    pub const FORCE_SWEEP: OutputKind = OutputKind::Csv {
        first_column: "p_kpa",
        what: "a force sweep (p_kpa, stretch, f_n)",
    };
    pub const FORCE_LAW: OutputKind = OutputKind::Toml {
        tables: &["force_law"],
        what: "a force-law file ([force_law])",
    };
    pub const TORQUE_MODEL: OutputKind = OutputKind::Toml {
        tables: &["torque_model"],
        what: "a torque-model file ([torque_model])",
    };
    pub const VOLUME_FNN: OutputKind = OutputKind::Toml {
        tables: &["volume_fnn"],
        what: "a learned-volume file ([volume_fnn])",
    };
    pub const GAINS: OutputKind = OutputKind::Toml {
        tables: &["cascade", "pd", "pid"],
        what: "a gains file (no [cascade], [pd] or [pid] table)",
    };
    pub const JSON: OutputKind = OutputKind::Json {
        what: "a JSON file",
    };
}

/// Largest existing file [`replaceable`] reads whole to recognise a TOML output; a larger
/// one is not such an output. (A CSV or JSON output is recognised by its head.)
const REPLACEABLE_READ_MAX_BYTES: u64 = 4 << 20;

/// `Err` naming `flag` and `path` when `path` exists and is not an output of `kind` (a
/// recording about to be replaced by a force law, a plant file by a recording): the command
/// would replace it, and the user would lose it. An absent or empty file is replaceable.
/// `--force` lets any file be replaced ([`crate::output`]).
pub fn replaceable(flag: &str, path: &Path, kind: OutputKind) -> Result<(), String> {
    use std::io::Read as _;
    let Ok(meta) = std::fs::metadata(path) else {
        return Ok(());
    };
    if crate::output::forced() {
        return Ok(());
    }
    if !meta.is_file() || meta.len() == 0 {
        return Ok(());
    }
    let mut head = Vec::new();
    let read_max = match kind {
        OutputKind::Toml { .. } => REPLACEABLE_READ_MAX_BYTES,
        OutputKind::Csv { .. } | OutputKind::Json { .. } => 64 << 10,
    };
    if std::fs::File::open(path)
        .and_then(|f| f.take(read_max).read_to_end(&mut head))
        .is_err()
    {
        return Ok(()); // unreadable: the write itself says why
    }
    let text = String::from_utf8_lossy(&head);
    let (ok, what) = match kind {
        OutputKind::Toml { tables, what } => (
            meta.len() <= REPLACEABLE_READ_MAX_BYTES
                && text
                    .parse::<toml::Table>()
                    .is_ok_and(|t| tables.iter().any(|k| t.contains_key(*k))),
            what,
        ),
        OutputKind::Csv { first_column, what } => (
            text.lines()
                .map(|l| l.trim_start_matches('\u{feff}'))
                .find(|l| !l.starts_with('#') && !l.trim().is_empty())
                .is_some_and(|l| l.split(',').next().map(str::trim) == Some(first_column)),
            what,
        ),
        OutputKind::Json { what } => (text.trim_start().starts_with('{'), what),
    };
    if ok {
        return Ok(());
    }
    Err(format!(
        "{flag} {}: exists and is not {what}; this command replaces {flag}: give another file, \
         or move this one away first",
        path.display()
    ))
}

/// [`distinct_outputs`] for outputs that are files in directories the command does not
/// create: also each output's directory exists and can be written, and an existing file
/// there is one host-sim wrote ([`crate::output::check_file`]), checked before the run
/// (not found by the rename after it).
pub fn distinct_file_outputs(
    inputs: &[(&str, &Path)],
    outputs: &[(&str, &Path)],
) -> Result<(), String> {
    distinct_outputs(inputs, outputs)?;
    for (flag, p) in outputs {
        output_parent_exists(flag, p)?;
        crate::output::check_file(flag, p)?;
    }
    Ok(())
}

/// A file output whose directory must already exist (the command does not create it):
/// refused before the run, not after it (a tuning run takes minutes).
pub fn output_parent_exists(flag: &str, path: &Path) -> Result<(), String> {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() && !d.is_dir() => Err(format!(
            "{flag} {}: the directory {} does not exist",
            path.display(),
            d.display()
        )),
        _ => Ok(()),
    }
}

/// A directory output (`--report DIR`, `--out-dir DIR`): absent (created) or a directory.
pub fn output_dir(flag: &str, dir: &Path) -> Result<(), String> {
    if dir.exists() && !dir.is_dir() {
        return Err(format!(
            "{flag} {}: exists and is not a directory; give a directory (created if missing)",
            dir.display()
        ));
    }
    Ok(())
}

/// Longest name [`file_name_part`] accepts [characters].
pub const MAX_NAME_CHARS: usize = 100;

/// Encoder counts per turn an angle in `counts` may give (1 to 2^30: a 30-bit encoder).
pub const COUNTS_PER_REV: std::ops::RangeInclusive<u32> = 1..=1 << 30;

/// Fewest counts per revolution of a joint's angle encoder (0 aside, "not quantised"): one
/// count a degree. Coarser, the firmware sees a joint that jumps by whole degrees (at 3
/// counts, 120 deg) and the run or the recording tells nothing about the controller.
pub const MIN_ENCODER_COUNTS_PER_REV: u32 = 360;

/// The value parser of an encoder's counts per revolution (`sweep torque --encoder-counts`):
/// 0 (no quantisation) or [`MIN_ENCODER_COUNTS_PER_REV`] up to the largest encoder `import`
/// reads.
pub fn encoder_counts_per_rev(s: &str) -> Result<u32, String> {
    let hi = *COUNTS_PER_REV.end();
    let allowed =
        format!("0 (no angle quantisation) or {MIN_ENCODER_COUNTS_PER_REV}..={hi} counts per turn");
    let v: i128 = s
        .trim()
        .parse()
        .map_err(|_| format!("`{s}` is not a whole number (allowed: {allowed})"))?;
    if v == 0 || (i128::from(MIN_ENCODER_COUNTS_PER_REV)..=i128::from(hi)).contains(&v) {
        Ok(v as u32)
    } else {
        Err(format!(
            "must be {allowed}, got {v} (fewer than {MIN_ENCODER_COUNTS_PER_REV} counts per turn \
             read the motion in steps of more than 1 degree)"
        ))
    }
}

/// Checks a name typed into a file that becomes part of an output file name (a scenario's
/// `name`): 1 to [`MAX_NAME_CHARS`] characters of `A-Za-z0-9_.-`, not starting with `.`
/// and without `..`, so that it can never name a path outside the output directory.
pub fn file_name_part(name: &str) -> Result<(), String> {
    let allowed = |c: char| c.is_ascii_alphanumeric() || matches!(c, '_' | '.' | '-');
    let why = if name.is_empty() {
        "is empty"
    } else if name.chars().count() > MAX_NAME_CHARS {
        "is too long"
    } else if name.contains('/') || name.contains('\\') {
        "contains a path separator"
    } else if name.starts_with('.') {
        "starts with '.'"
    } else if name.contains("..") {
        "contains '..'"
    } else if !name.chars().all(allowed) {
        "contains a character outside A-Za-z0-9_.-"
    } else {
        return Ok(());
    };
    Err(format!(
        "{name:?} {why}: the name becomes a file name, so it must be 1 to {MAX_NAME_CHARS} \
         characters of A-Za-z0-9_.- , not start with '.' and not contain '..'"
    ))
}

/// `dir/file_name`, refused unless `file_name` is one plain component (no separator, no
/// `..`, not absolute): every output of a run named after user text stays inside `dir`.
pub fn inside_dir(dir: &Path, file_name: &str) -> Result<PathBuf, String> {
    let mut parts = Path::new(file_name).components();
    match (parts.next(), parts.next()) {
        (Some(std::path::Component::Normal(n)), None) if n == std::ffi::OsStr::new(file_name) => {
            Ok(dir.join(file_name))
        }
        _ => Err(format!(
            "output file name {file_name:?} is not a plain file name inside {}",
            dir.display()
        )),
    }
}

/// 1-based line of `key = ...` inside `[table]` (or `[[table]]`, the `index`-th one) of TOML
/// `text`; `table = ""` is the top level.
pub fn toml_key_line(text: &str, table: &str, index: usize, key: &str) -> Option<usize> {
    let mut in_table = table.is_empty();
    let mut seen = 0usize;
    for (i, line) in text.lines().enumerate() {
        let l = line.split('#').next().unwrap_or("").trim();
        if l.starts_with('[') {
            let name = l.trim_start_matches('[').trim_end_matches(']').trim();
            in_table = false;
            if name == table {
                in_table = seen == index;
                seen += 1;
            }
            continue;
        }
        if in_table
            && l.strip_prefix(key)
                .is_some_and(|rest| rest.trim_start().starts_with('='))
        {
            return Some(i + 1);
        }
    }
    None
}

/// The dotted key (`table.key`, or `key` at the top level) of the `key = value` line of TOML
/// `text` that holds byte `offset` (a parser's error span), if that line is one.
pub fn toml_key_at(text: &str, offset: usize) -> Option<String> {
    let offset = offset.min(text.len());
    let start = text[..offset].rfind('\n').map_or(0, |i| i + 1);
    let line = text[start..].lines().next().unwrap_or("");
    let (key, _) = line.split('#').next()?.split_once('=')?;
    let key = key.trim();
    if key.is_empty() || key.starts_with('[') {
        return None;
    }
    let table = text[..start]
        .lines()
        .map(|l| l.split('#').next().unwrap_or("").trim())
        .rfind(|l| l.starts_with('['))
        .map(|l| l.trim_start_matches('[').trim_end_matches(']').trim());
    Some(match table {
        Some(t) if !t.is_empty() => format!("{t}.{key}"),
        _ => key.to_string(),
    })
}

/// "file:line: key `table.key` = v: message" (the line when it is found in `text`).
pub fn file_value_error(file: &Path, text: &str, dotted: &str, message: &str) -> String {
    let (table, key) = dotted.rsplit_once('.').unwrap_or(("", dotted));
    match toml_key_line(text, table, 0, key) {
        Some(line) => format!("{}:{line}: key `{dotted}`: {message}", file.display()),
        None => format!("{}: key `{dotted}`: {message}", file.display()),
    }
}

/// Whether two existing paths name the same file: the same canonical path (a symbolic link,
/// `./` or `..`), or on Unix the same device and inode (a hard link).
pub fn same_existing_file(a: &Path, b: &Path) -> bool {
    if let (Ok(x), Ok(y)) = (a.canonicalize(), b.canonicalize()) {
        if x == y {
            return true;
        }
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt as _;
        if let (Ok(x), Ok(y)) = (std::fs::metadata(a), std::fs::metadata(b)) {
            return x.dev() == y.dev() && x.ino() == y.ino();
        }
    }
    false
}

fn same_target(input: &Path, output: &Path) -> bool {
    let Ok(i) = input.canonicalize() else {
        return false;
    };
    if output.exists() {
        // A symbolic link, `..`, or a hard link: another name of the input.
        return same_existing_file(input, output);
    }
    // A new output: compare its directory and name.
    let dir = match output.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_owned(),
        _ => PathBuf::from("."),
    };
    match (dir.canonicalize(), output.file_name()) {
        (Ok(d), Some(n)) => d.join(n) == i,
        _ => false,
    }
}

/// Whether `a` and `b` name the same path: the same file or folder where both exist, else
/// the same absolute path (`./d/x.json` and `d/x.json`).
pub fn same_path(a: &Path, b: &Path) -> bool {
    a == b
        || (a.exists() && same_target(a, b))
        || (b.exists() && same_target(b, a))
        || matches!(
            (std::path::absolute(a), std::path::absolute(b)),
            (Ok(x), Ok(y)) if x == y
        )
}

/// Refuses an output that is one of the inputs (the run would replace the user's data), two
/// outputs that are the same file, or an output that exists and is not a regular file (a
/// directory, a device such as /dev/null, a pipe: the rename of the finished file would
/// replace it, or fail only after the run). Each path comes with the flag that named it.
pub fn distinct_outputs(inputs: &[(&str, &Path)], outputs: &[(&str, &Path)]) -> Result<(), String> {
    for (oflag, o) in outputs {
        if let Ok(m) = std::fs::metadata(o) {
            if !m.is_file() {
                return Err(format!(
                    "{oflag} {}: exists and is not a regular file ({}); give a file path",
                    o.display(),
                    if m.is_dir() {
                        "a directory"
                    } else {
                        "a device, pipe or socket"
                    }
                ));
            }
        }
    }
    for (oflag, o) in outputs {
        for (iflag, i) in inputs {
            if same_target(i, o) {
                return Err(format!(
                    "{oflag} {} is the input {iflag}: refusing to overwrite an input; write to another file",
                    o.display()
                ));
            }
        }
    }
    for (k, (aflag, a)) in outputs.iter().enumerate() {
        for (bflag, b) in &outputs[k + 1..] {
            if same_path(a, b) {
                return Err(format!(
                    "{aflag} and {bflag} are the same file {}: give two different files",
                    a.display()
                ));
            }
        }
    }
    Ok(())
}

/// Largest estimated memory of one run without `--allow-large` [bytes] (docs/reliability.md).
pub const MAX_RUN_BYTES: f64 = 2.0e9;
/// Largest estimated run time without `--allow-large` [s] (docs/reliability.md).
pub const MAX_RUN_S: f64 = 1800.0;

/// The estimated size of a run, from its arguments, before any work.
#[derive(Clone, Debug, PartialEq)]
pub struct RunEstimate {
    /// What is estimated ("sweep torque").
    pub what: String,
    /// Samples (or ticks, or table points) the run makes.
    pub samples: f64,
    /// Memory the run needs [bytes].
    pub bytes: f64,
    /// Run time on one core of a laptop [s].
    pub seconds: f64,
}

fn human_bytes(b: f64) -> String {
    if b >= 1e12 {
        format!("{:.1} TB", b / 1e12)
    } else if b >= 1e9 {
        format!("{:.1} GB", b / 1e9)
    } else {
        format!("{:.0} MB", b / 1e6)
    }
}

fn human_s(s: f64) -> String {
    if s >= 86400.0 {
        format!("{:.1} days", s / 86400.0)
    } else if s >= 3600.0 {
        format!("{:.1} h", s / 3600.0)
    } else if s >= 60.0 {
        format!("{:.0} min", s / 60.0)
    } else {
        format!("{s:.1} s")
    }
}

impl RunEstimate {
    /// One line: what, and the estimated memory and time.
    pub fn summary(&self) -> String {
        format!(
            "{}: estimated {} of memory and {} of run time",
            self.what,
            human_bytes(self.bytes),
            human_s(self.seconds)
        )
    }

    /// Refuses (naming the estimate and the limit) a run above [`MAX_RUN_BYTES`] or
    /// [`MAX_RUN_S`] unless `allow_large`.
    pub fn check(&self, allow_large: bool) -> Result<(), String> {
        let too_big = !(self.bytes <= MAX_RUN_BYTES && self.seconds <= MAX_RUN_S);
        if too_big && !allow_large {
            return Err(format!(
                "{}: {:.3e} samples, estimated {} of memory and {} of run time; the limit is {} \
                 and {} (--allow-large runs it anyway)",
                self.what,
                self.samples,
                human_bytes(self.bytes),
                human_s(self.seconds),
                human_bytes(MAX_RUN_BYTES),
                human_s(MAX_RUN_S)
            ));
        }
        if !(self.samples < 1e15) {
            // Not even --allow-large: the count does not fit an index.
            return Err(format!(
                "{}: {:.3e} samples cannot be indexed; reduce the run",
                self.what, self.samples
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_initial_pressure_typed_in_kpa_is_refused_with_the_kpa_hint() {
        let text = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/plants/reference-1dof.toml"
        ))
        .unwrap()
        .replace("p1_gauge_pa = 550000.0", "p1_gauge_pa = 550");
        let e = crate::PlantConfig::from_toml_str(&text, "kpa.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("kpa.toml:33") && e.contains("initial.p1_gauge_pa"),
            "{e}"
        );
        assert!(
            e.contains("kPa typed into a Pa key? 550 kPa is 550000 Pa"),
            "{e}"
        );
        // 0 (atmospheric) and a real pressure in Pa are accepted.
        for ok in ["p1_gauge_pa = 0.0", "p1_gauge_pa = 1500.0"] {
            let t = text.replace("p1_gauge_pa = 550", ok);
            assert!(
                crate::PlantConfig::from_toml_str(&t, "ok.toml").is_ok(),
                "{ok}"
            );
        }
    }

    #[test]
    fn the_key_of_an_error_span_is_its_lines_dotted_key() {
        let text = "a = 1 # top\n\n[cascade] # gains\nkp = \"x\"\n[[rows]]\n";
        let at = |needle: &str| toml_key_at(text, text.find(needle).unwrap());
        assert_eq!(at("1 #").as_deref(), Some("a"));
        assert_eq!(at("\"x\"").as_deref(), Some("cascade.kp"));
        assert_eq!(at("[cascade]"), None);
        assert_eq!(at("[[rows]]"), None);
        assert_eq!(toml_key_at(text, 10_000), None);
    }

    #[test]
    fn an_output_replaces_only_an_earlier_output_of_its_kind() {
        let dir = tempfile::tempdir().unwrap();
        let file = |name: &str, text: &str| {
            let p = dir.path().join(name);
            std::fs::write(&p, text).unwrap();
            p
        };
        let rec = file("rec.csv", "# plant = p.toml\nt_s,u_in1\n0,0\n");
        let law = file("law.toml", "# identified\n[force_law]\nc = [1.0]\n");
        let notes = file("notes.txt", "my notes\n");
        let empty = file("empty.csv", "");
        let json = file("d.json", "  {\"verdict\": \"explained\"}");
        let force_law = OutputKind::FORCE_LAW;
        // Its own kind, an empty file, a missing file: replaced.
        assert!(replaceable("--out", &rec, OutputKind::RECORDING).is_ok());
        assert!(replaceable("--out", &law, force_law).is_ok());
        assert!(replaceable("--out", &empty, force_law).is_ok());
        assert!(replaceable("--out", &dir.path().join("new.toml"), force_law).is_ok());
        assert!(replaceable("--json", &json, OutputKind::JSON).is_ok());
        // Another kind: refused, naming the flag, the path and what was expected.
        let e = replaceable("--out", &rec, force_law).unwrap_err();
        assert!(
            e.contains("--out") && e.contains("rec.csv") && e.contains("not a force-law file"),
            "{e}"
        );
        assert!(replaceable("--out", &law, OutputKind::RECORDING).is_err());
        assert!(replaceable("--out", &notes, OutputKind::PLANT).is_err());
        assert!(replaceable("--json", &rec, OutputKind::JSON).is_err());
    }

    #[test]
    fn an_output_that_is_another_name_of_an_input_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("plant.toml");
        std::fs::write(&input, "x = 1\n").unwrap();
        let hard = dir.path().join("hard.toml");
        std::fs::hard_link(&input, &hard).unwrap();
        let dotted = dir.path().join(".").join("plant.toml");
        let mut names = vec![input.clone(), hard, dotted];
        #[cfg(unix)]
        {
            let link = dir.path().join("link.toml");
            std::os::unix::fs::symlink(&input, &link).unwrap();
            names.push(link);
        }
        for out in &names {
            let e = distinct_outputs(&[("--plant", &input)], &[("--out", out)]).unwrap_err();
            assert!(e.contains("is the input --plant"), "{}: {e}", out.display());
        }
        // A new file next to it, and an existing other file, are fine.
        let other = dir.path().join("other.toml");
        assert!(distinct_outputs(&[("--plant", &input)], &[("--out", &other)]).is_ok());
        std::fs::write(&other, "y = 2\n").unwrap();
        assert!(distinct_outputs(&[("--plant", &input)], &[("--out", &other)]).is_ok());
    }

    #[test]
    fn a_pressure_in_kpa_or_bar_gets_its_unit_hint() {
        let supply = Range::closed(1.0e4, 2.0e6);
        let e = range_error("supply_gauge_pa", 600.0, supply, "Pa").unwrap();
        assert!(e.contains("600 kPa is 600000 Pa"), "{e}");
        let e = range_error("supply_gauge_pa", 6.0, supply, "Pa").unwrap();
        assert!(
            e.contains("bar typed into a Pa key? 6 bar is 600000 Pa"),
            "{e}"
        );
        // Not a pressure key, or no unit that fits: no hint.
        assert!(!range_error("mass_kg", 6.0, supply, "kg")
            .unwrap()
            .contains("typed"));
        assert!(!range_error("supply_gauge_pa", 0.01, supply, "Pa")
            .unwrap()
            .contains("typed"));
    }

    #[test]
    fn ranges_refuse_nan_and_the_bounds_they_exclude() {
        let p = f64_in(Range::positive(10.0));
        assert!(p("NaN").is_err());
        assert!(p("inf").is_err());
        assert!(p("0").is_err());
        assert_eq!(p("10").unwrap(), 10.0);
        assert!(p("10.5").unwrap_err().contains("(0, 10]"));
        assert!(usize_in(1, 5)("0").is_err());
        assert_eq!(usize_in(1, 5)("5").unwrap(), 5);
        assert_eq!(
            usize_in(1, 5)("-1").unwrap_err(),
            "must be within 1..=5, got -1"
        );
        assert!(usize_in(1, 5)("1.5")
            .unwrap_err()
            .contains("not a whole number"));
    }

    #[test]
    fn numbers_in_messages_are_short_but_keep_what_was_typed() {
        let shown = |v: f64| Shown(v).to_string();
        assert_eq!(shown(1e300), "1e300");
        assert_eq!(shown(-2.5e-9), "-2.5e-9");
        assert_eq!(shown(-104.60800000000002), "-104.608");
        assert_eq!(shown(10.0000000001), "10.0000000001");
        assert_eq!(shown(600000.0), "600000");
        assert_eq!(shown(f64::NAN), "NaN");
        let e = f64_in(Range::closed(1e-14, 0.1))("1e300").unwrap_err();
        assert!(e.contains("[1e-14, 0.1], got 1e300"), "{e}");
    }

    #[test]
    fn key_lines_are_found_in_their_table() {
        let t = "[a]\nx = 1\n[b]\ny = 2 # c\nx = 3\n[[e]]\nz=1\n[[e]]\nz = 2\n";
        assert_eq!(toml_key_line(t, "a", 0, "x"), Some(2));
        assert_eq!(toml_key_line(t, "b", 0, "x"), Some(5));
        assert_eq!(toml_key_line(t, "e", 1, "z"), Some(9));
        assert_eq!(toml_key_line(t, "b", 0, "z"), None);
    }

    #[test]
    fn names_that_would_leave_the_output_directory_are_refused() {
        for bad in [
            "",
            "../x",
            "a/b",
            "a\\b",
            ".hidden",
            "a..b",
            "..",
            "x y",
            "caf\u{e9}",
            "/abs",
        ] {
            assert!(file_name_part(bad).is_err(), "{bad:?} accepted");
        }
        for good in ["step", "arm_pick-place.v2", "A1"] {
            file_name_part(good).unwrap();
        }
        let d = Path::new("out");
        assert_eq!(inside_dir(d, "a.csv").unwrap(), d.join("a.csv"));
        for bad in ["../a.csv", "/a.csv", "x/a.csv", "..", "."] {
            assert!(inside_dir(d, bad).is_err(), "{bad:?} accepted");
        }
    }

    #[test]
    fn an_output_equal_to_an_input_is_refused() {
        let d = tempfile::tempdir().unwrap();
        let a = d.path().join("a.csv");
        std::fs::write(&a, "x").unwrap();
        let alias = d.path().join(".").join("a.csv");
        assert!(distinct_outputs(&[("--inputs", &a)], &[("--out", &alias)]).is_err());
        let b = d.path().join("b.csv");
        assert!(distinct_outputs(&[("--inputs", &a)], &[("--out", &b)]).is_ok());
        assert!(distinct_outputs(&[], &[("--out", &b), ("--plot", &b)]).is_err());
    }
}
