//! `host-sim import`: a rig logger's CSV file -> a RECORDING.md recording, through a mapping
//! file (TOML) that says which column is which channel, in which unit.
//!
//! The mapping file (every table `deny_unknown_fields`; `docs/rig.md` has a worked example):
//!
//! ```toml
//! [csv]
//! delimiter = ";"        # one character (default ",")
//! decimal = ","          # "." (default) or "," (then the delimiter must not be ",")
//! skip_lines = 2         # lines before the header line (default 0)
//!
//! [time]
//! column = "Zeit"
//! unit = "ms"            # "s" | "ms" | "us"
//!
//! [pressure]
//! p_atm_pa = 101325.0           # atmosphere for absolute pressures (default 101325)
//! regulator_band_pa = 20000.0   # proportional band of the regulator model (default 20 kPa)
//!
//! [[channel]]
//! column = "P1"          # or `constant = 0.0` for a channel the rig does not log
//! channel = "p1"         # p1 p2 angle f1 f2 u_in1 u_ex1 u_in2 u_ex2 valve1 valve2
//!                        # regulator1 regulator2
//! unit = "bar"           # see below
//! reference = "absolute" # pressures: "gauge" (default) or "absolute"
//! scale = 1.0            # value = raw * scale + offset, in `unit`, before the unit conversion
//! offset = 0.0
//! counts_per_rev = 8000  # angle in "counts"
//! threshold = 0.5        # u_* in "onoff": open when the value is >= threshold
//! curve = [[0.0, 0.0], [10.0, 1.0]]  # "V": piecewise-linear (volts, opening) table
//! ```
//!
//! Units: pressures `Pa` `kPa` `bar` `MPa` `psi`; angle `rad` `deg` `counts`; forces `N`
//! `kN`; valve openings (`u_in1` .. `u_ex2`) `fraction` (0..1), `percent`, `onoff` or `V`
//! (through `curve`, clamped to [0, 1]).
//!
//! `valve1` / `valve2`: one signed command per muscle, as a proportional 5/3 valve (e.g. a
//! FESTO MPYE at 0..10 V, 5 V closed) takes: `curve` maps volts (or `fraction` / `percent`
//! values) to a signed opening in [-1, 1]; `s > 0` opens the inflate path (`u_in = s`,
//! `u_ex = 0`), `s < 0` the exhaust path (`u_ex = -s`).
//!
//! `regulator1` / `regulator2`: the set-point of a proportional pressure regulator feeding
//! the muscle (a pressure unit). Model (documented in `docs/rig.md`): a relieving regulator
//! whose main stage is the plant's own ISO 6358 inflate / exhaust valve pair, opened in
//! proportion to the pressure error over the band `b = regulator_band_pa`:
//! `u_in = clamp((p_set - p) / b, 0, 1)`, `u_ex = clamp((p - p_set) / b, 0, 1)`,
//! with `p` the muscle's measured gauge pressure at the same time stamp (so the matching
//! pressure channel must be mapped).
//!
//! Time stamps are written as logged (converted to seconds, shifted to start at 0): jitter
//! is kept (simulate / fit / identify / diagnose accept it, inputs held between stamps). A
//! step longer than [`MAX_STEP_RATIO`] median steps is a gap: gaps are listed and refused, or
//! with `--split` written as separate recordings; never filled. An empty cell is an error.
//! Every error names the file, the line and the column.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::io::recording::{Channel, Recording, MAX_STEP_RATIO, MIN_STEP_RATIO};
use crate::plant::ValveInputs;
use crate::validate::{Range, Shown};

/// The mapping file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Mapping {
    #[serde(default)]
    pub csv: CsvOptions,
    pub time: TimeColumn,
    #[serde(default)]
    pub pressure: PressureOptions,
    pub channel: Vec<ChannelMap>,
    /// The file's text, to name the line of a key in an error.
    #[serde(skip)]
    text: String,
}

/// `[pressure]`: atmosphere and the regulator model.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PressureOptions {
    /// Atmospheric pressure for absolute pressure columns [Pa].
    #[serde(default = "default_p_atm")]
    pub p_atm_pa: f64,
    /// Proportional band of the regulator model [Pa].
    #[serde(default = "default_band")]
    pub regulator_band_pa: f64,
}

impl Default for PressureOptions {
    fn default() -> Self {
        Self {
            p_atm_pa: default_p_atm(),
            regulator_band_pa: default_band(),
        }
    }
}

fn default_p_atm() -> f64 {
    101_325.0
}
fn default_band() -> f64 {
    20_000.0
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CsvOptions {
    #[serde(default = "default_delimiter")]
    pub delimiter: String,
    #[serde(default = "default_decimal")]
    pub decimal: String,
    #[serde(default)]
    pub skip_lines: usize,
}

fn default_delimiter() -> String {
    ",".into()
}
fn default_decimal() -> String {
    ".".into()
}

impl Default for CsvOptions {
    fn default() -> Self {
        Self {
            delimiter: default_delimiter(),
            decimal: default_decimal(),
            skip_lines: 0,
        }
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimeColumn {
    pub column: String,
    pub unit: String,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelMap {
    #[serde(default)]
    pub column: Option<String>,
    #[serde(default)]
    pub constant: Option<f64>,
    pub channel: String,
    #[serde(default)]
    pub unit: Option<String>,
    #[serde(default)]
    pub reference: Option<String>,
    #[serde(default = "one")]
    pub scale: f64,
    #[serde(default)]
    pub offset: f64,
    #[serde(default)]
    /// Read as any number so that a negative, fractional or too large count is refused with
    /// the range ([`COUNTS_PER_REV`]), not as a type error.
    pub counts_per_rev: Option<f64>,
    #[serde(default)]
    pub threshold: Option<f64>,
    #[serde(default)]
    pub curve: Option<Vec<[f64; 2]>>,
}

fn one() -> f64 {
    1.0
}

/// What a mapped column becomes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Target {
    Output(Channel),
    /// Index into [`crate::io::recording::INPUT_COLUMNS`].
    Opening(usize),
    /// Signed proportional valve of muscle 0 / 1.
    Signed(usize),
    /// Regulator set-point of muscle 0 / 1.
    Regulator(usize),
}

impl Target {
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "p1" => Target::Output(Channel::P1Kpa),
            "p2" => Target::Output(Channel::P2Kpa),
            "angle" => Target::Output(Channel::AngleDeg),
            "f1" => Target::Output(Channel::F1N),
            "f2" => Target::Output(Channel::F2N),
            "u_in1" => Target::Opening(0),
            "u_ex1" => Target::Opening(1),
            "u_in2" => Target::Opening(2),
            "u_ex2" => Target::Opening(3),
            "valve1" => Target::Signed(0),
            "valve2" => Target::Signed(1),
            "regulator1" => Target::Regulator(0),
            "regulator2" => Target::Regulator(1),
            _ => return None,
        })
    }
}

/// How one column's values become SI (or the recording's unit).
#[derive(Debug, Clone)]
enum Convert {
    /// Multiply by this factor (after scale / offset); pressures: to Pa, minus `p_atm` if
    /// absolute; angles: to rad; forces: to N; openings: to 0..1.
    Factor {
        factor: f64,
        minus_pa: f64,
    },
    Counts {
        counts_per_rev: u32,
    },
    OnOff {
        threshold: f64,
    },
    Curve(Vec<[f64; 2]>),
}

impl Convert {
    /// Multiply by `factor`, nothing subtracted.
    fn scale(factor: f64) -> Self {
        Convert::Factor {
            factor,
            minus_pa: 0.0,
        }
    }
}

/// An import that failed: the message names file, line and column (or the mapping key).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct ImportError(pub String);

/// The result of an import: one recording per gap-free segment.
#[derive(Debug, Clone)]
pub struct Imported {
    pub segments: Vec<Recording>,
    /// Gaps found: (line of the sample after the gap, time before [s], time after [s]).
    pub gaps: Vec<(u64, f64, f64)>,
    /// Largest |step - median step| / median step.
    pub max_jitter: f64,
    /// Median step [s].
    pub median_step_s: f64,
    /// One line per mapped output channel: its range over the file, in recording units.
    pub ranges: Vec<String>,
    /// Values that are possible but suspect (a unit mistake is the usual cause).
    pub warnings: Vec<String>,
}

impl Mapping {
    pub fn load(path: &Path) -> Result<Self, ImportError> {
        if path.is_dir() {
            return Err(ImportError(format!(
                "--map {}: is a directory; give the mapping file (TOML, docs/rig.md)",
                path.display()
            )));
        }
        let raw =
            std::fs::read(path).map_err(|e| ImportError(format!("{}: {e}", path.display())))?;
        let text = String::from_utf8(raw).map_err(|e| {
            let bytes = e.as_bytes();
            let valid = e.utf8_error().valid_up_to();
            let line = bytes[..valid].iter().filter(|&&b| b == b'\n').count() + 1;
            ImportError(format!(
                "{}:{line}: not UTF-8 (saved by a Windows editor as Latin-1 or Windows-1252?): \
                 save the mapping file as UTF-8",
                path.display()
            ))
        })?;
        let mut m: Mapping =
            toml::from_str(&text).map_err(|e| ImportError(format!("{}: {e}", path.display())))?;
        m.text = text;
        m.check(path)?;
        Ok(m)
    }

    /// "file:line: `table.key`: message" (the line when it is found).
    fn key_error(
        &self,
        path: &Path,
        table: &str,
        index: usize,
        key: &str,
        msg: &str,
    ) -> ImportError {
        let dotted = if table.is_empty() {
            key.to_string()
        } else {
            format!("{table}.{key}")
        };
        ImportError(
            match crate::validate::toml_key_line(&self.text, table, index, key) {
                Some(line) => format!("{}:{line}: `{dotted}`: {msg}", path.display()),
                None => format!("{}: `{dotted}`: {msg}", path.display()),
            },
        )
    }

    fn check(&self, path: &Path) -> Result<(), ImportError> {
        let bad = |dotted: &str, msg: String| {
            let (table, key) = dotted.rsplit_once('.').unwrap_or(("", dotted));
            self.key_error(path, table, 0, key, &msg)
        };
        if self.csv.delimiter.chars().count() != 1 || !self.csv.delimiter.is_ascii() {
            return Err(bad("csv.delimiter", "must be one ASCII character".into()));
        }
        if !matches!(self.csv.decimal.as_str(), "." | ",") {
            return Err(bad("csv.decimal", "must be \".\" or \",\"".into()));
        }
        if self.csv.decimal == "," && self.csv.delimiter == "," {
            return Err(bad(
                "csv.decimal",
                "a decimal comma needs another delimiter (e.g. \";\")".into(),
            ));
        }
        time_factor(&self.time.unit).ok_or_else(|| {
            bad(
                "time.unit",
                format!("{:?}: use \"s\", \"ms\" or \"us\"", self.time.unit),
            )
        })?;
        let p = &self.pressure;
        for (key, v, range) in [
            ("pressure.p_atm_pa", p.p_atm_pa, P_ATM_RANGE_PA),
            (
                "pressure.regulator_band_pa",
                p.regulator_band_pa,
                REGULATOR_BAND_RANGE_PA,
            ),
        ] {
            if let Err(msg) = range.check(v) {
                let mut msg = format!("{msg} Pa");
                for (unit, factor) in [("kPa", 1e3), ("bar", 1e5)] {
                    if v > 0.0 && range.contains(v * factor) {
                        msg.push_str(&format!(
                            " ({unit} typed into a Pa key? {} {unit} is {} Pa)",
                            Shown(v),
                            Shown(v * factor)
                        ));
                    }
                }
                return Err(bad(key, msg));
            }
        }
        Ok(())
    }
}

/// Atmospheric pressure a rig can see: from about 5 500 m of altitude to a deep mine [Pa].
pub const P_ATM_RANGE_PA: Range = Range::closed(50_000.0, 110_000.0);
/// Proportional band of a pressure regulator [Pa].
pub const REGULATOR_BAND_RANGE_PA: Range = Range::closed(100.0, 1e6);
pub use crate::validate::COUNTS_PER_REV;

pub use crate::io::recording::STEP_RANGE_S;
/// A recording shorter than this [s] is too short to identify or diagnose a joint from (a
/// few valve pulses): with a time column that, read in the next larger unit, has a plausible
/// step, the import takes it for a unit off by 1000 (ms read as us, s read as ms).
pub const SPAN_MIN_S: f64 = 0.5;
/// A median step below this [s] (above 20 kHz) that reads as a plausible step in the next
/// larger time unit is taken for a unit off by 1000.
pub const FAST_STEP_S: f64 = 5e-5;
/// Highest gauge pressure a mapped column may reach [Pa] (pneumatics runs below 1.6 MPa):
/// the recording's own limit, so that the import names the raw line and the mapping.
pub const P_GAUGE_MAX_PA: f64 = crate::io::recording::P_KPA_PLAUSIBLE.1 * 1e3;
/// Largest |angle| a joint may report [rad]: half a turn.
pub const ANGLE_MAX_RAD: f64 = std::f64::consts::PI;
/// Largest |force| a muscle may report [N] (the largest fluidic muscles give about 6 kN).
pub const FORCE_MAX_N: f64 = 1e5;
/// A pressure channel whose |gauge| never reaches this is suspect (a unit too large read
/// as a smaller one: bar or MPa mapped as kPa) [Pa].
pub const P_SUSPECT_BELOW_PA: f64 = 10e3;
/// A muscle exhausts to the atmosphere, and one whose valves are closed while the joint
/// stretches it falls below it only as far as its volume grows (isothermal `p V` constant: a
/// volume 1.5 times larger takes 0 kPa gauge to about -34 kPa; the reference plant's loaded
/// conformance run reaches -39 kPa): a gauge pressure below this fraction of the atmosphere
/// below 0 (a volume doubled) is suspect (a gauge sensor mapped as absolute, an absolute one
/// with a wrong offset, or a unit too large read as a smaller one).
pub const P_SUSPECT_GAUGE_BELOW_ATM_FRACTION: f64 = 0.5;
/// A gauge pressure column whose minimum lies within this of the atmosphere (and so never
/// vents to 0 kPa gauge) looks like an absolute sensor read as gauge [Pa].
pub const P_ABSOLUTE_SUSPECT_WITHIN_PA: f64 = 15e3;
/// What to do about pressures that look absolute (the import's warning and the diagnosis'
/// note say the same).
pub const ABSOLUTE_PRESSURE_HINT: &str = "the pressure columns look absolute, not gauge; \
     RECORDING.md's columns are gauge: subtract p_atm or import with reference = \"absolute\"";

/// Time stamps whose resolution (the decimals they are written with) reaches this fraction of
/// the median step are warned about.
pub const COARSE_STAMP_FRACTION: f64 = 0.1;

/// An angle channel that never moves more than this is suspect (radians mapped as degrees)
/// [rad].
pub const ANGLE_SPAN_SUSPECT_BELOW_RAD: f64 = 1.0 * std::f64::consts::PI / 180.0;

fn time_factor(unit: &str) -> Option<f64> {
    match unit {
        "s" => Some(1.0),
        "ms" => Some(1e-3),
        "us" => Some(1e-6),
        _ => None,
    }
}

fn pressure_factor(unit: &str) -> Option<f64> {
    match unit {
        "Pa" => Some(1.0),
        "kPa" => Some(1e3),
        "bar" => Some(1e5),
        "MPa" => Some(1e6),
        "psi" => Some(6_894.757_293_168),
        _ => None,
    }
}

/// Where one channel entry of the mapping file is, for its messages.
struct EntryAt<'a> {
    m: &'a Mapping,
    i: usize,
    c: &'a ChannelMap,
    path: &'a Path,
}

impl EntryAt<'_> {
    /// "file:line: channel[i] (`name`): `k`", the line of key `k` (or of the entry's
    /// `channel` key) when it is found.
    fn key(&self, k: &str) -> String {
        let (m, i, c, path) = (self.m, self.i, self.c, self.path);
        let at = match crate::validate::toml_key_line(&m.text, "channel", i, k)
            .or_else(|| crate::validate::toml_key_line(&m.text, "channel", i, "channel"))
        {
            Some(line) => format!("{}:{line}", path.display()),
            None => path.display().to_string(),
        };
        format!("{at}: channel[{i}] (`{}`): `{k}`", c.channel)
    }

    /// The error for a unit this channel does not take.
    fn unit_error(&self, unit: &str, allowed: &str) -> ImportError {
        ImportError(format!(
            "{}: {unit:?} is not a unit of this channel (use {allowed})",
            self.key("unit")
        ))
    }
}

/// Checks one channel entry and gives its target and conversion.
fn plan(
    m: &Mapping,
    i: usize,
    c: &ChannelMap,
    path: &Path,
) -> Result<(Target, Convert), ImportError> {
    let at = EntryAt { m, i, c, path };
    let target = Target::parse(&c.channel).ok_or_else(|| {
        ImportError(format!(
            "{}: {:?} is not a channel (p1 p2 angle f1 f2 u_in1 u_ex1 u_in2 u_ex2 valve1 valve2 \
             regulator1 regulator2)",
            at.key("channel"),
            c.channel
        ))
    })?;
    check_entry_numbers(&at)?;
    let unit = c.unit.as_deref().unwrap_or(match target {
        Target::Opening(_) | Target::Signed(_) => "fraction",
        _ => "",
    });
    let reference = c.reference.as_deref().unwrap_or("gauge");
    if !matches!(reference, "gauge" | "absolute") {
        return Err(ImportError(format!(
            "{}: {reference:?}: use \"gauge\" or \"absolute\"",
            at.key("reference")
        )));
    }
    let conv = conversion(&at, target, unit, reference)?;
    refuse_stray_keys(&at, target, &conv, unit)?;
    Ok((target, conv))
}

/// The entry's source (exactly one of `column` and `constant`) and its numbers (`scale`,
/// `offset`, `constant`) are usable.
fn check_entry_numbers(at: &EntryAt) -> Result<(), ImportError> {
    let c = at.c;
    match (&c.column, c.constant) {
        (Some(_), None) | (None, Some(_)) => {}
        _ => {
            return Err(ImportError(format!(
                "{}: give exactly one of `column` and `constant`",
                at.key("column")
            )))
        }
    }
    if !(c.scale.is_finite() && c.scale != 0.0) {
        return Err(ImportError(format!(
            "{}: must be a finite number other than 0 (value = raw * scale + offset), got {}",
            at.key("scale"),
            Shown(c.scale)
        )));
    }
    if !c.offset.is_finite() {
        return Err(ImportError(format!(
            "{}: must be a finite number, got {}",
            at.key("offset"),
            c.offset
        )));
    }
    if let Some(v) = c.constant.filter(|v| !v.is_finite()) {
        return Err(ImportError(format!(
            "{}: must be a finite number (the channel's raw value on every row), got {}",
            at.key("constant"),
            Shown(v)
        )));
    }
    Ok(())
}

/// How the entry's values become SI, from its target, `unit` and pressure `reference`.
fn conversion(
    at: &EntryAt,
    target: Target,
    unit: &str,
    reference: &str,
) -> Result<Convert, ImportError> {
    Ok(match target {
        Target::Output(Channel::P1Kpa | Channel::P2Kpa) | Target::Regulator(_) => {
            let f = pressure_factor(unit)
                .ok_or_else(|| at.unit_error(unit, "Pa, kPa, bar, MPa, psi"))?;
            Convert::Factor {
                factor: f,
                minus_pa: if reference == "absolute" {
                    at.m.pressure.p_atm_pa
                } else {
                    0.0
                },
            }
        }
        Target::Output(Channel::AngleDeg) => match unit {
            "rad" => Convert::scale(1.0),
            "deg" => Convert::scale(std::f64::consts::PI / 180.0),
            "counts" => counts_conversion(at)?,
            _ => return Err(at.unit_error(unit, "rad, deg, counts")),
        },
        Target::Output(_) => match unit {
            "N" => Convert::scale(1.0),
            "kN" => Convert::scale(1e3),
            _ => return Err(at.unit_error(unit, "N, kN")),
        },
        Target::Opening(_) | Target::Signed(_) => {
            opening_conversion(at, matches!(target, Target::Signed(_)), unit)?
        }
    })
}

/// An angle in encoder counts: `counts_per_rev` a whole number in [`COUNTS_PER_REV`].
fn counts_conversion(at: &EntryAt) -> Result<Convert, ImportError> {
    let c = at.c;
    let cpr = c
        .counts_per_rev
        .filter(|n| {
            n.fract() == 0.0
                && (f64::from(*COUNTS_PER_REV.start())..=f64::from(*COUNTS_PER_REV.end()))
                    .contains(n)
        })
        .map(|n| n as u32)
        .ok_or_else(|| {
            ImportError(format!(
                "{}: angle in counts needs counts_per_rev, an integer in [{}, {}] \
                 (encoder counts per turn){}",
                at.key("counts_per_rev"),
                COUNTS_PER_REV.start(),
                COUNTS_PER_REV.end(),
                c.counts_per_rev
                    .map(|n| format!(", got {}", Shown(n)))
                    .unwrap_or_else(|| ", not given".into())
            ))
        })?;
    Ok(Convert::Counts {
        counts_per_rev: cpr,
    })
}

/// A valve opening (`signed`: a 5/3 valve's signed command): fraction, percent, on/off
/// (not signed) or volts through a `curve` of >= 2 points, volts increasing, openings in
/// [0, 1] ([-1, 1] signed).
fn opening_conversion(at: &EntryAt, signed: bool, unit: &str) -> Result<Convert, ImportError> {
    let c = at.c;
    Ok(match unit {
        "fraction" => Convert::scale(1.0),
        "percent" => Convert::scale(0.01),
        "onoff" if !signed => Convert::OnOff {
            threshold: c.threshold.unwrap_or(0.5),
        },
        "V" => {
            let curve = c.curve.clone().ok_or_else(|| {
                ImportError(format!(
                    "{}: a valve command in volts needs `curve = [[volts, opening], ...]`",
                    at.key("curve")
                ))
            })?;
            let lo = if signed { -1.0 } else { 0.0 };
            if curve.len() < 2
                || curve.windows(2).any(|w| !(w[1][0] > w[0][0]))
                || curve
                    .iter()
                    .any(|p| !(p[1] >= lo && p[1] <= 1.0 && p[0].is_finite()))
            {
                return Err(ImportError(format!(
                    "{}: needs >= 2 points with increasing volts and openings in [{lo}, 1]",
                    at.key("curve")
                )));
            }
            Convert::Curve(curve)
        }
        _ => {
            return Err(at.unit_error(
                unit,
                if signed {
                    "fraction, percent, V"
                } else {
                    "fraction, percent, onoff, V"
                },
            ))
        }
    })
}

/// A key that does nothing for this channel and unit is a mistake somewhere (the unit it was
/// meant for, or the channel): refused rather than ignored.
fn refuse_stray_keys(
    at: &EntryAt,
    target: Target,
    conv: &Convert,
    unit: &str,
) -> Result<(), ImportError> {
    let c = at.c;
    let is_pressure = matches!(
        target,
        Target::Output(Channel::P1Kpa | Channel::P2Kpa) | Target::Regulator(_)
    );
    for (k, given, applies, what) in [
        (
            "counts_per_rev",
            c.counts_per_rev.is_some(),
            matches!(conv, Convert::Counts { .. }),
            "an angle with `unit = \"counts\"`",
        ),
        (
            "threshold",
            c.threshold.is_some(),
            matches!(conv, Convert::OnOff { .. }),
            "a valve with `unit = \"onoff\"`",
        ),
        (
            "curve",
            c.curve.is_some(),
            matches!(conv, Convert::Curve(_)),
            "a valve with `unit = \"V\"`",
        ),
        (
            "reference",
            c.reference.is_some(),
            is_pressure,
            "a pressure (p1, p2, regulator1, regulator2)",
        ),
    ] {
        if given && !applies {
            return Err(ImportError(format!(
                "{}: applies to {what} only, not to this channel with `unit = {unit:?}`: is the \
                 unit or the channel wrong? (remove the key otherwise)",
                at.key(k)
            )));
        }
    }
    Ok(())
}

fn convert(conv: &Convert, v: f64) -> f64 {
    match conv {
        Convert::Factor { factor, minus_pa } => v * factor - minus_pa,
        Convert::Counts { counts_per_rev } => {
            v / *counts_per_rev as f64 * 2.0 * std::f64::consts::PI
        }
        Convert::OnOff { threshold } => {
            if v >= *threshold {
                1.0
            } else {
                0.0
            }
        }
        Convert::Curve(pts) => {
            let n = pts.len();
            if v <= pts[0][0] {
                return pts[0][1];
            }
            if v >= pts[n - 1][0] {
                return pts[n - 1][1];
            }
            let j = pts.windows(2).position(|w| v <= w[1][0]).unwrap_or(n - 2);
            let (a, b) = (pts[j], pts[j + 1]);
            a[1] + (v - a[0]) / (b[0] - a[0]) * (b[1] - a[1])
        }
    }
}

/// How far beyond its `curve`'s voltage table a valve command may read before it is refused
/// rather than clamped to the table's end (a fraction of the table's span).
pub const CURVE_MARGIN_OF_SPAN: f64 = 0.1;

/// What a cell that does not parse as a number probably is, as the tail of the message: a
/// decimal comma read with `decimal = "."`, or a thousands separator (both separators in the
/// cell); empty when neither.
fn number_hint(cell: &str, comma: bool) -> &'static str {
    let digits_around = |sep: char| {
        cell.split(sep).count() >= 2
            && cell.split(sep).all(|p| {
                !p.is_empty()
                    && p.trim_start_matches(['-', '+'])
                        .chars()
                        .all(|c| c.is_ascii_digit())
            })
    };
    let (has_dot, has_comma) = (cell.contains('.'), cell.contains(','));
    if has_dot && has_comma {
        " (a thousands separator? export the numbers without one)"
    } else if !comma && has_comma && digits_around(',') {
        " (a decimal comma? set `decimal = \",\"` under [csv] in the mapping file)"
    } else if comma && has_dot && digits_around('.') {
        " (a decimal point? this mapping says `decimal = \",\"`; a thousands separator?)"
    } else {
        ""
    }
}

/// Why a converted value cannot be what the channel says (gauge Pa, rad, N), with the unit
/// mistake that usually causes it; `None` when it can be.
fn implausible(target: Target, v: f64, p_atm_pa: f64, unit: &str) -> Option<String> {
    match target {
        Target::Output(Channel::P1Kpa | Channel::P2Kpa) | Target::Regulator(_) => {
            if v < -p_atm_pa {
                Some(format!(
                    "{} kPa gauge is below vacuum ({} kPa): a gauge sensor mapped with \
                     `reference = \"absolute\"` (the atmosphere subtracted from a gauge \
                     value), a wrong `pressure.p_atm_pa` or `offset`, or the wrong `unit`?",
                    Shown(v * 1e-3),
                    Shown(-p_atm_pa * 1e-3)
                ))
            } else if v > P_GAUGE_MAX_PA {
                Some(format!(
                    "{} kPa gauge is above {} kPa: the wrong `unit` (bar mapped as MPa, Pa as kPa?) \
                     or `scale`?",
                    Shown(v * 1e-3),
                    Shown(P_GAUGE_MAX_PA * 1e-3)
                ))
            } else {
                None
            }
        }
        Target::Output(Channel::AngleDeg) if v.abs() > ANGLE_MAX_RAD => Some(format!(
            "{} rad ({} deg) is beyond half a turn: {}",
            Shown(v),
            Shown(v.to_degrees()),
            match unit {
                "rad" => "degrees mapped with `unit = \"rad\"`, or the wrong `scale`?",
                "deg" => {
                    "encoder counts mapped with `unit = \"deg\"` (use `unit = \"counts\"` with \
                     `counts_per_rev`), or the wrong `scale`?"
                }
                _ => "the wrong `counts_per_rev` or `scale`?",
            }
        )),
        Target::Output(Channel::F1N | Channel::F2N) if v.abs() > FORCE_MAX_N => Some(format!(
            "{} N is beyond {} N: kN mapped as N, or the wrong `scale`?",
            Shown(v),
            Shown(FORCE_MAX_N)
        )),
        _ => None,
    }
}

/// Reads `input` through `mapping`; `split`: gaps cut the run into segments instead of
/// failing. Steps: the mapping's channels planned, the file read as text, its rows converted,
/// its time column checked, then one recording per gap-free segment.
pub fn import(
    mapping: &Mapping,
    map_path: &Path,
    input: &Path,
    split: bool,
) -> Result<Imported, ImportError> {
    let files = Files {
        mapping,
        map_path,
        input,
    };
    let plans = plan_channels(mapping, map_path)?;
    let (text, encoding_note) = read_text(input)?;
    let table = read_table(&files, &plans, &text)?;
    let timing = check_time(&files, &table)?;
    if !timing.gaps.is_empty() && !split {
        return Err(gaps_error(&files, &timing));
    }
    let (ranges, mut warnings) = channel_ranges(mapping, &plans, &table.values);
    warnings.extend(encoding_note);
    warnings.extend(timing.coarse_note.clone());
    warnings.extend(stuck_onoff_valves(mapping, map_path, &plans, &table.values));
    let segments = assemble_segments(&files, &plans, &table, &timing, &mut warnings)?;
    Ok(Imported {
        segments,
        gaps: timing.gaps,
        max_jitter: timing.max_jitter,
        median_step_s: timing.median_s,
        ranges,
        warnings,
    })
}

/// The files of one import: the mapping (and its path) and the rig's CSV file.
struct Files<'a> {
    mapping: &'a Mapping,
    map_path: &'a Path,
    input: &'a Path,
}

impl Files<'_> {
    /// "input:line: column `col`: msg".
    fn at(&self, line: u64, col: &str, msg: String) -> ImportError {
        ImportError(format!(
            "{}:{line}: column `{col}`: {msg}",
            self.input.display()
        ))
    }
}

/// The CSV file's rows, converted: line numbers, times [s] and each channel's values (SI).
struct Table {
    lines: Vec<u64>,
    t_s: Vec<f64>,
    /// The most decimals a time stamp is written with; `None` when one has an exponent.
    t_decimals: Option<usize>,
    /// Time stamps per second (1, 1000, 1e6).
    t_per_s: f64,
    /// One column per mapping channel.
    values: Vec<Vec<f64>>,
}

/// The time column's verdict: its median step, its gaps and the cuts they make.
struct Timing {
    median_s: f64,
    gaps: Vec<(u64, f64, f64)>,
    /// Row indices where segments start, and the row count last.
    cuts: Vec<usize>,
    max_jitter: f64,
    coarse_note: Option<String>,
}

/// The gaps of the time column (see [`find_gaps`]).
struct Gaps {
    gaps: Vec<(u64, f64, f64)>,
    cuts: Vec<usize>,
    max_jitter: f64,
}

/// Each mapping channel's target and conversion, checked as a set: each target once, one
/// channel per column and not the time column, each valve input given once, a regulator's
/// pressure mapped, and at least one output.
fn plan_channels(
    mapping: &Mapping,
    map_path: &Path,
) -> Result<Vec<(Target, Convert)>, ImportError> {
    let plans: Vec<(Target, Convert)> = mapping
        .channel
        .iter()
        .enumerate()
        .map(|(i, c)| plan(mapping, i, c, map_path))
        .collect::<Result<_, _>>()?;
    let seen = targets_once(mapping, map_path, &plans)?;
    columns_once(mapping, map_path)?;
    valve_inputs_once(map_path, &seen)?;
    for m in 0..2 {
        let p = if m == 0 {
            Channel::P1Kpa
        } else {
            Channel::P2Kpa
        };
        if seen.contains_key(&Target::Regulator(m)) && !seen.contains_key(&Target::Output(p)) {
            return Err(ImportError(format!(
                "{}: regulator{} needs the measured pressure `p{}` mapped (the regulator model \
                 opens in proportion to set-point minus pressure)",
                map_path.display(),
                m + 1,
                m + 1
            )));
        }
    }
    if !plans.iter().any(|(t, _)| matches!(t, Target::Output(_))) {
        return Err(ImportError(format!(
            "{}: no output channel mapped (need at least one of angle, p1, p2, f1, f2)",
            map_path.display()
        )));
    }
    Ok(plans)
}

/// Each target mapped once: the channel index of each.
fn targets_once(
    mapping: &Mapping,
    map_path: &Path,
    plans: &[(Target, Convert)],
) -> Result<BTreeMap<Target, usize>, ImportError> {
    let mut seen: BTreeMap<Target, usize> = BTreeMap::new();
    for (i, (t, _)) in plans.iter().enumerate() {
        if let Some(j) = seen.insert(*t, i) {
            let line = |k: usize| {
                crate::validate::toml_key_line(&mapping.text, "channel", k, "channel")
                    .map_or_else(String::new, |l| format!(" (line {l})"))
            };
            return Err(ImportError(format!(
                "{}: channel[{i}]{} and channel[{j}]{} both map `{}`",
                map_path.display(),
                line(i),
                line(j),
                mapping.channel[i].channel
            )));
        }
    }
    Ok(seen)
}

/// One source column, one meaning: the time column is not a channel, and no column is read
/// as two channels.
fn columns_once(mapping: &Mapping, map_path: &Path) -> Result<(), ImportError> {
    let column_at =
        |i: usize| match crate::validate::toml_key_line(&mapping.text, "channel", i, "column") {
            Some(line) => format!("{}:{line}", map_path.display()),
            None => map_path.display().to_string(),
        };
    for (i, c) in mapping.channel.iter().enumerate() {
        let Some(col) = c.column.as_deref() else {
            continue;
        };
        if col == mapping.time.column {
            return Err(ImportError(format!(
                "{}: channel[{i}] (`{}`): `column`: {col:?} is the time column ([time] column); \
                 a column is read as one thing: map the channel's own column",
                column_at(i),
                c.channel
            )));
        }
        if let Some(j) = mapping.channel[..i]
            .iter()
            .position(|d| d.column.as_deref() == Some(col))
        {
            return Err(ImportError(format!(
                "{}: channel[{i}] (`{}`): `column`: {col:?} is already mapped by channel[{j}] \
                 (`{}`); a column is read as one channel: map each channel's own column",
                column_at(i),
                c.channel,
                mapping.channel[j].channel
            )));
        }
    }
    Ok(())
}

/// Each valve input (`u_in1` .. `u_ex2`) given by exactly one of its own channel, its
/// muscle's signed valve and its muscle's regulator.
fn valve_inputs_once(map_path: &Path, seen: &BTreeMap<Target, usize>) -> Result<(), ImportError> {
    let names = ["u_in1", "u_ex1", "u_in2", "u_ex2"];
    for (k, name) in names.iter().enumerate() {
        let m = k / 2;
        let by = [
            seen.contains_key(&Target::Opening(k)),
            seen.contains_key(&Target::Signed(m)),
            seen.contains_key(&Target::Regulator(m)),
        ];
        let count = by.iter().filter(|b| **b).count();
        if count == 0 {
            return Err(ImportError(format!(
                "{}: no channel gives `{name}` (map it, or valve{}, or regulator{}; a valve the \
                 rig does not log: `constant = 0.0`)",
                map_path.display(),
                m + 1,
                m + 1
            )));
        }
        if count > 1 {
            return Err(ImportError(format!(
                "{}: `{name}` is given twice (u_*, valve{} and regulator{} exclude each other)",
                map_path.display(),
                m + 1,
                m + 1
            )));
        }
    }
    Ok(())
}

/// The rig's file as text, without a byte-order mark, and a note when it was not UTF-8: a
/// Windows export (`Winkel [°]` in Windows-1252 / Latin-1) is read byte for byte as Latin-1,
/// so that its column names match the mapping's. A directory, a binary file (a NUL byte: a
/// binary log or a UTF-16 export) and an empty file are refused.
fn read_text(input: &Path) -> Result<(String, Option<String>), ImportError> {
    if input.is_dir() {
        return Err(ImportError(format!(
            "--input {}: is a directory; give the rig logger's CSV file",
            input.display()
        )));
    }
    let raw = std::fs::read(input).map_err(|e| ImportError(format!("{}: {e}", input.display())))?;
    if let Some(at) = raw.iter().position(|&b| b == 0) {
        return Err(ImportError(format!(
            "{}: not a text file (a NUL byte at byte {at}): a binary log or a UTF-16 export? \
             export the log as CSV text (UTF-8 or Latin-1)",
            input.display()
        )));
    }
    let (mut text, encoding_note) = match String::from_utf8(raw) {
        Ok(t) => (t, None),
        Err(e) => {
            let raw = e.as_bytes();
            let line = raw[..e.utf8_error().valid_up_to()]
                .iter()
                .filter(|&&b| b == b'\n')
                .count()
                + 1;
            (
                raw.iter().map(|&b| b as char).collect::<String>(),
                Some(format!(
                    "{}:{line}: not UTF-8 (a Windows or Latin-1 export): read as Latin-1",
                    input.display()
                )),
            )
        }
    };
    if text.starts_with('\u{feff}') {
        text.drain(..'\u{feff}'.len_utf8());
    }
    if text.trim().is_empty() {
        return Err(ImportError(format!(
            "{}: the file is empty",
            input.display()
        )));
    }
    Ok((text, encoding_note))
}

/// The byte offset of the header line: after the mapping's `csv.skip_lines`, which must leave
/// one.
fn header_offset(files: &Files, text: &str) -> Result<usize, ImportError> {
    let mapping = files.mapping;
    let mut offset = 0usize;
    for _ in 0..mapping.csv.skip_lines {
        match text[offset..].find('\n') {
            Some(i) => offset += i + 1,
            None => offset = text.len(),
        }
    }
    if text[offset..].trim().is_empty() {
        return Err(ImportError(format!(
            "{}: `csv.skip_lines = {}` of {} skips the whole file ({} line(s)): no header line \
             is left",
            files.input.display(),
            mapping.csv.skip_lines,
            files.map_path.display(),
            text.lines().count()
        )));
    }
    Ok(offset)
}

/// The index of column `name` in the header, which must hold it once.
fn column_index(
    files: &Files,
    headers: &csv::StringRecord,
    header_line: u64,
    name: &str,
) -> Result<usize, ImportError> {
    let mut it = headers.iter().enumerate().filter(|(_, h)| *h == name);
    let first = it.next().map(|(i, _)| i);
    if it.next().is_some() {
        return Err(files.at(
            header_line,
            name,
            "column appears twice in the header".into(),
        ));
    }
    first.ok_or_else(|| {
        files.at(
            header_line,
            name,
            format!(
                "not in the header (columns: {})",
                headers.iter().collect::<Vec<_>>().join(", ")
            ),
        )
    })
}

/// Reads the rows of `text`: each time stamp in seconds and each channel's value converted
/// and checked (see [`channel_value`]).
fn read_table(
    files: &Files,
    plans: &[(Target, Convert)],
    text: &str,
) -> Result<Table, ImportError> {
    let (mapping, input) = (files.mapping, files.input);
    let offset = header_offset(files, text)?;
    let skipped = mapping.csv.skip_lines as u64;
    let mut rdr = csv::ReaderBuilder::new()
        .delimiter(mapping.csv.delimiter.as_bytes()[0])
        .trim(csv::Trim::All)
        .flexible(false)
        .from_reader(&text.as_bytes()[offset..]);
    let headers = rdr
        .headers()
        .map_err(|e| ImportError(format!("{}:{}: {e}", input.display(), skipped + 1)))?
        .clone();
    let header_line = skipped + 1;
    let t_col = column_index(files, &headers, header_line, &mapping.time.column)?;
    // Stamps per second (1, 1000, 1e6), divided by: 14998 ms is 14.998 s, not the
    // 14.998000000000001 of a multiplication by 1e-3.
    let t_per_s = (1.0 / time_factor(&mapping.time.unit).expect("checked")).round();
    let cols: Vec<Option<usize>> = mapping
        .channel
        .iter()
        .map(|c| {
            c.column
                .as_deref()
                .map(|name| column_index(files, &headers, header_line, name))
                .transpose()
        })
        .collect::<Result<_, _>>()?;
    let comma = mapping.csv.decimal == ",";

    let mut table = Table {
        lines: Vec::new(),
        t_s: Vec::new(),
        t_decimals: Some(0),
        t_per_s,
        values: vec![Vec::new(); plans.len()],
    };
    let mut record = csv::StringRecord::new();
    loop {
        match rdr.read_record(&mut record) {
            Ok(false) => break,
            Ok(true) => {}
            Err(e) => return Err(record_error(input, &e, skipped, header_line)),
        }
        let row = Row {
            files,
            headers: &headers,
            record: &record,
            line: record.position().map(|p| p.line()).unwrap_or(0) + skipped,
            comma,
        };
        table.t_s.push(row.number(t_col)? / t_per_s);
        let cell = record.get(t_col).unwrap_or("").trim();
        table.t_decimals = match (table.t_decimals, stamp_decimals(cell, comma)) {
            (Some(d), Some(e)) => Some(d.max(e)),
            _ => None,
        };
        for (i, (c, col)) in mapping.channel.iter().zip(&cols).enumerate() {
            let raw = match (col, c.constant) {
                (Some(col), _) => row.number(*col)?,
                (None, Some(k)) => k,
                _ => unreachable!("checked: column or constant"),
            };
            let v = channel_value(&row, c, &plans[i], raw)?;
            table.values[i].push(v);
        }
        table.lines.push(row.line);
    }
    Ok(table)
}

/// The message of a row the CSV reader refuses, at its line.
fn record_error(input: &Path, e: &csv::Error, skipped: u64, header_line: u64) -> ImportError {
    let line = e
        .position()
        .map(|p| p.line() + skipped)
        .unwrap_or(header_line);
    let message = match e.kind() {
        csv::ErrorKind::UnequalLengths {
            expected_len, len, ..
        } => {
            format!("{len} fields, the header has {expected_len}")
        }
        _ => e.to_string(),
    };
    ImportError(format!("{}:{line}: {message}", input.display()))
}

/// The decimals a time stamp is written with (its resolution); `None` for one with an
/// exponent, whose resolution is unknown.
fn stamp_decimals(cell: &str, comma: bool) -> Option<usize> {
    if cell.contains(['e', 'E']) {
        return None;
    }
    let sep = if comma { ',' } else { '.' };
    Some(cell.find(sep).map_or(0, |i| cell.len() - i - 1))
}

/// One data row of the CSV file, at its line.
struct Row<'a> {
    files: &'a Files<'a>,
    headers: &'a csv::StringRecord,
    record: &'a csv::StringRecord,
    line: u64,
    /// The mapping's decimal separator is a comma.
    comma: bool,
}

impl Row<'_> {
    /// The number in column `col`: not empty (gaps are not filled), a finite number.
    fn number(&self, col: usize) -> Result<f64, ImportError> {
        let (line, comma) = (self.line, self.comma);
        let name = &self.headers[col];
        let s = self.record.get(col).unwrap_or("");
        if s.is_empty() {
            return Err(self.files.at(
                line,
                name,
                "empty cell (a gap in this channel; import does not fill gaps)".into(),
            ));
        }
        let cell = s;
        let owned;
        let s = if comma {
            owned = s.replace(',', ".");
            owned.as_str()
        } else {
            s
        };
        let v: f64 = s.parse().map_err(|_| {
            self.files.at(
                line,
                name,
                format!("not a number: {cell:?}{}", number_hint(cell, comma)),
            )
        })?;
        if !v.is_finite() {
            return Err(self
                .files
                .at(line, name, format!("not a finite number: {cell:?}")));
        }
        Ok(v)
    }
}

/// Channel `c`'s value on `row` from its `raw` reading, through its `plan`: a volts command
/// within its curve's table (plus [`CURVE_MARGIN_OF_SPAN`]), a plausible value (see
/// [`implausible`]), an opening within [0, 1] (signed: [-1, 1]).
fn channel_value(
    row: &Row,
    c: &ChannelMap,
    plan: &(Target, Convert),
    raw: f64,
) -> Result<f64, ImportError> {
    let (files, line) = (row.files, row.line);
    let name = c.column.as_deref().unwrap_or("constant");
    let x = raw * c.scale + c.offset;
    // A command far outside its curve's table (millivolts logged for volts) would be clamped
    // to the table's end on every row: refused. Slightly beyond (a 10.05 V reading of a
    // 0..10 V command) is clamped.
    if let Convert::Curve(pts) = &plan.1 {
        let (lo, hi) = (pts[0][0], pts[pts.len() - 1][0]);
        let margin = CURVE_MARGIN_OF_SPAN * (hi - lo);
        if !(x >= lo - margin && x <= hi + margin) {
            return Err(files.at(
                line,
                name,
                format!(
                    "channel `{}`: {} V is outside its curve's {}..{} V (by more than {:.0} % of \
                     the span): a value in mV? (check the column's unit and `scale`)",
                    c.channel,
                    Shown(x),
                    Shown(lo),
                    Shown(hi),
                    100.0 * CURVE_MARGIN_OF_SPAN
                ),
            ));
        }
    }
    let v = convert(&plan.1, x);
    if let Some(msg) = implausible(
        plan.0,
        v,
        files.mapping.pressure.p_atm_pa,
        c.unit.as_deref().unwrap_or(""),
    ) {
        return Err(files.at(line, name, format!("channel `{}`: {msg}", c.channel)));
    }
    // Openings must end up in range: say where they do not.
    if let Target::Opening(_) = plan.0 {
        if !(0.0..=1.0).contains(&v) {
            return Err(files.at(
                line,
                name,
                format!("opening {} outside [0, 1] after the mapping", Shown(v)),
            ));
        }
    }
    if let Target::Signed(_) = plan.0 {
        if !(-1.0..=1.0).contains(&v) {
            return Err(files.at(
                line,
                name,
                format!(
                    "signed opening {} outside [-1, 1] after the mapping",
                    Shown(v)
                ),
            ));
        }
    }
    Ok(v)
}

/// Checks the time column: at least 2 rows, increasing, a median step of a PAM rig in the
/// declared unit, no step far under the median; finds the gaps.
fn check_time(files: &Files, table: &Table) -> Result<Timing, ImportError> {
    let n = table.t_s.len();
    if n < 2 {
        return Err(ImportError(format!(
            "{}: {n} data rows; a recording needs at least 2",
            files.input.display()
        )));
    }
    check_increasing(files, table)?;
    let mut steps: Vec<f64> = table.t_s.windows(2).map(|w| w[1] - w[0]).collect();
    steps.sort_by(f64::total_cmp);
    let median_s = steps[steps.len() / 2];
    check_time_unit(files, table, median_s)?;
    let coarse_note = coarse_stamps_note(files, table, median_s);
    let Gaps {
        gaps,
        cuts,
        max_jitter,
    } = find_gaps(files, table, median_s)?;
    Ok(Timing {
        median_s,
        gaps,
        cuts,
        max_jitter,
        coarse_note,
    })
}

/// Time increases row by row. One repeated stamp is a duplicated row; many are stamps
/// coarser than the sampling.
fn check_increasing(files: &Files, table: &Table) -> Result<(), ImportError> {
    let (t_s, n) = (&table.t_s, table.t_s.len());
    let time_name = files.mapping.time.column.as_str();
    let repeats = t_s.windows(2).filter(|w| w[1] == w[0]).count();
    for k in 1..n {
        if !(t_s[k] > t_s[k - 1]) {
            return Err(files.at(
                table.lines[k],
                time_name,
                if t_s[k] == t_s[k - 1] && repeats > 1 {
                    format!(
                        "time does not increase: time stamp {} s repeated, and {repeats} of the \
                         {n} rows repeat the stamp before them: the time stamps are coarser than \
                         the sampling (a logger writing whole milliseconds at more than 1 kHz?); \
                         log finer time stamps (or in another `time.unit`)",
                        Shown(t_s[k])
                    )
                } else if t_s[k] == t_s[k - 1] {
                    format!(
                        "time does not increase: time stamp {} s repeated (a duplicated row?)",
                        Shown(t_s[k])
                    )
                } else {
                    format!(
                        "time does not increase: {} s after {} s (rows out of order? the rows \
                         must be sorted by time)",
                        Shown(t_s[k]),
                        Shown(t_s[k - 1])
                    )
                },
            ));
        }
    }
    Ok(())
}

/// The declared time unit fits the median step: within [`STEP_RANGE_S`]; a step faster than
/// [`FAST_STEP_S`], or a span under [`SPAN_MIN_S`], that reads as a plausible step in the
/// next larger unit is a unit off by 1000 (ms read as us, s read as ms). A short file whose
/// unit gives no such reading is left alone.
fn check_time_unit(files: &Files, table: &Table, median: f64) -> Result<(), ImportError> {
    let (mapping, map_path) = (files.mapping, files.map_path);
    let (t_s, lines, n) = (&table.t_s, &table.lines, table.t_s.len());
    let time_name = mapping.time.column.as_str();
    if !STEP_RANGE_S.contains(median) {
        return Err(files.at(
            lines[1],
            time_name,
            format!(
                "the median time step is {} s (with `time.unit = {:?}` in {}), outside {} s \
                 (100 kHz .. 10 Hz): is the time column in another unit ({})?",
                Shown(median),
                mapping.time.unit,
                map_path.display(),
                STEP_RANGE_S,
                if median < STEP_RANGE_S.lo {
                    "a larger one, e.g. ms declared us or s declared ms"
                } else {
                    "a smaller one, e.g. ms declared s"
                }
            ),
        ));
    }
    let span_s = t_s[n - 1] - t_s[0];
    let larger = match mapping.time.unit.as_str() {
        "us" => Some("ms"),
        "ms" => Some("s"),
        _ => None,
    };
    // Likewise a step faster than any PAM rig logs (above 20 kHz: valves switch at a few
    // hundred Hz, pressure sensors settle in a millisecond) that reads as a plausible rate in
    // the next larger unit: 40 Hz logged in ms and declared us reads as 40 kHz.
    if let Some(u) = larger.filter(|_| median < FAST_STEP_S && STEP_RANGE_S.contains(median * 1e3))
    {
        return Err(files.at(
            lines[1],
            time_name,
            format!(
                "the median time step is {} s ({} kHz, `time.unit = {:?}` in {}), faster than \
                 a PAM rig is logged (up to {} kHz): is the time column in {u}? With \
                 `time.unit = \"{u}\"` it spans {} s at {} Hz. (A logger truly this fast: \
                 decimate its file first.)",
                Shown(median),
                Shown(1e-3 / median),
                mapping.time.unit,
                map_path.display(),
                Shown(1e-3 / FAST_STEP_S),
                Shown(span_s * 1e3),
                Shown(1.0 / (median * 1e3))
            ),
        ));
    }
    if let Some(u) = larger.filter(|_| span_s < SPAN_MIN_S && STEP_RANGE_S.contains(median * 1e3)) {
        return Err(files.at(
            lines[n - 1],
            time_name,
            format!(
                "the recording spans {} s (median step {} s, `time.unit = {:?}` in {}), under \
                 the {SPAN_MIN_S} s a joint can be identified or diagnosed from: is the time \
                 column in {u}? With `time.unit = \"{u}\"` it spans {} s at {} Hz",
                Shown(span_s),
                Shown(median),
                mapping.time.unit,
                map_path.display(),
                Shown(span_s * 1e3),
                Shown(1.0 / (median * 1e3))
            ),
        ));
    }
    Ok(())
}

/// A note when the stamps are written with too few decimals (a spreadsheet's two): each
/// sample sits up to half the resolution off its time, which jitters every step.
fn coarse_stamps_note(files: &Files, table: &Table, median: f64) -> Option<String> {
    let mapping = files.mapping;
    let time_name = mapping.time.column.as_str();
    table.t_decimals.and_then(|d| {
        let resolution_s = 10f64.powi(-(d as i32)) / table.t_per_s;
        (resolution_s >= COARSE_STAMP_FRACTION * median).then(|| {
            format!(
                "{}: column `{time_name}`: time stamps written to {} s ({d} decimals in {}), {:.0} \
                 % of the median step {} s: each sample sits up to half of that off its time; \
                 log (or export) the time with more decimals",
                files.input.display(),
                Shown(resolution_s),
                mapping.time.unit,
                100.0 * resolution_s / median,
                Shown(median)
            )
        })
    })
}

/// The gaps (steps over [`MAX_STEP_RATIO`] median steps), the cuts they make (starting with
/// row 0, ending with the row count) and the largest jitter of the other steps; a step under
/// [`MIN_STEP_RATIO`] median steps is refused.
fn find_gaps(files: &Files, table: &Table, median: f64) -> Result<Gaps, ImportError> {
    let (t_s, lines, n) = (&table.t_s, &table.lines, table.t_s.len());
    let mut gaps = Vec::new();
    let mut cuts = vec![0usize];
    let mut max_jitter: f64 = 0.0;
    for k in 1..n {
        let step = t_s[k] - t_s[k - 1];
        if step > MAX_STEP_RATIO * median {
            gaps.push((lines[k], t_s[k - 1] - t_s[0], t_s[k] - t_s[0]));
            cuts.push(k);
        } else if step < MIN_STEP_RATIO * median {
            return Err(files.at(
                lines[k],
                files.mapping.time.column.as_str(),
                format!(
                    "step {} s is less than {MIN_STEP_RATIO} median steps ({} s): a doubled or \
                     misordered time stamp",
                    Shown(step),
                    Shown(median)
                ),
            ));
        } else {
            max_jitter = max_jitter.max((step - median).abs() / median);
        }
    }
    cuts.push(n);
    Ok(Gaps {
        gaps,
        cuts,
        max_jitter,
    })
}

/// The refusal of a file with gaps (without `--split`), listing them.
fn gaps_error(files: &Files, timing: &Timing) -> ImportError {
    let median = timing.median_s;
    let list: Vec<String> = timing
        .gaps
        .iter()
        .map(|(l, a, b)| {
            format!(
                "  line {l}: {a:.6} s -> {b:.6} s ({:.6} s missing)",
                b - a - median
            )
        })
        .collect();
    ImportError(format!(
        "{}: {} gap(s) in column `{}` (steps over {MAX_STEP_RATIO} median steps of {} s); gaps \
         are not filled: cut the file, or pass --split to write one recording per gap-free \
         segment\n{}",
        files.input.display(),
        timing.gaps.len(),
        files.mapping.time.column,
        Shown(median),
        list.join("\n")
    ))
}

/// One recording per gap-free segment of at least 2 samples (a single sample between two
/// gaps is left out with a warning); none is an error.
fn assemble_segments(
    files: &Files,
    plans: &[(Target, Convert)],
    table: &Table,
    timing: &Timing,
    warnings: &mut Vec<String>,
) -> Result<Vec<Recording>, ImportError> {
    let mut segments = Vec::new();
    for w in timing.cuts.windows(2) {
        let (a, b) = (w[0], w[1]);
        if b - a < 2 {
            if b > a {
                warnings.push(format!(
                    "{}:{}: a single sample between two gaps (t = {} s) is not a recording: \
                     left out",
                    files.input.display(),
                    table.lines[a],
                    Shown(table.t_s[a])
                ));
            }
            continue;
        }
        segments.push(segment(files, plans, table, timing, a..b));
    }
    if segments.is_empty() {
        return Err(ImportError(format!(
            "{}: no gap-free segment of at least 2 samples",
            files.input.display()
        )));
    }
    Ok(segments)
}

/// The recording of rows `rows`: time from 0, the output channels in recording units, the
/// valve inputs and the metadata saying where it came from.
fn segment(
    files: &Files,
    plans: &[(Target, Convert)],
    table: &Table,
    timing: &Timing,
    rows: std::ops::Range<usize>,
) -> Recording {
    let (a, b) = (rows.start, rows.end);
    let (t_s, values, lines) = (&table.t_s, &table.values, &table.lines);
    let find = |t: Target| plans.iter().position(|(p, _)| *p == t);
    let mut rec = Recording::default();
    let t0 = t_s[a];
    rec.t_s = t_s[a..b].iter().map(|t| t - t0).collect();
    for c in Channel::ALL {
        if let Some(i) = find(Target::Output(c)) {
            let scale = match c {
                Channel::AngleDeg => 180.0 / std::f64::consts::PI,
                Channel::P1Kpa | Channel::P2Kpa => 1e-3,
                _ => 1.0,
            };
            rec.set_channel(c, values[i][a..b].iter().map(|v| v * scale).collect());
        }
    }
    for k in a..b {
        let u = valve_openings(plans, values, k, files.mapping.pressure.regulator_band_pa);
        rec.inputs.push(ValveInputs::from_openings(u));
    }
    rec.metadata = vec![
        (
            "source".into(),
            format!(
                "host-sim {} import of {} (lines {}..={}) with {}",
                env!("CARGO_PKG_VERSION"),
                files.input.display(),
                lines[a],
                lines[b - 1],
                files.map_path.display()
            ),
        ),
        (
            "sample_period_s".into(),
            format!("{}", rec.sample_period_s()),
        ),
        (
            "time_stamps".into(),
            format!(
                "as logged, max |step - median| = {:.1} % of the median step {} s",
                100.0 * timing.max_jitter,
                Shown(timing.median_s)
            ),
        ),
    ];
    rec
}

/// The four valve openings (`u_in1`, `u_ex1`, `u_in2`, `u_ex2`) of row `k`: each from its
/// own channel, its muscle's signed valve (`s > 0` inflates, `s < 0` exhausts) or its
/// muscle's regulator (the pressure error over `band_pa`, clamped to [0, 1]).
fn valve_openings(
    plans: &[(Target, Convert)],
    values: &[Vec<f64>],
    k: usize,
    band_pa: f64,
) -> [f64; 4] {
    let find = |t: Target| plans.iter().position(|(p, _)| *p == t);
    let mut u = [0.0f64; 4];
    for (j, uj) in u.iter_mut().enumerate() {
        let m = j / 2;
        let inflate = j % 2 == 0;
        *uj = if let Some(i) = find(Target::Opening(j)) {
            values[i][k]
        } else if let Some(i) = find(Target::Signed(m)) {
            let s = values[i][k];
            if inflate {
                s.max(0.0)
            } else {
                (-s).max(0.0)
            }
        } else {
            let i = find(Target::Regulator(m)).expect("checked: one source per input");
            let p = if m == 0 {
                Channel::P1Kpa
            } else {
                Channel::P2Kpa
            };
            let ip = find(Target::Output(p)).expect("checked: regulator needs its pressure");
            let err = values[i][k] - values[ip][k];
            let e = if inflate { err } else { -err };
            (e / band_pa).clamp(0.0, 1.0)
        };
    }
    u
}

/// A warning for each on/off valve column whose `threshold` leaves it closed (or open) over
/// the whole file (the threshold is probably on the wrong side of the logged levels), and for
/// each percent valve column that never passes 1 % (fractions read as percent).
fn stuck_onoff_valves(
    mapping: &Mapping,
    map_path: &Path,
    plans: &[(Target, Convert)],
    values: &[Vec<f64>],
) -> Vec<String> {
    let mut warnings = Vec::new();
    for (i, ((target, conv), (c, v))) in plans
        .iter()
        .zip(mapping.channel.iter().zip(values))
        .enumerate()
    {
        // A percent column that never passes 1 %: fractions (0..1) read as percent.
        if let (Convert::Factor { factor, .. }, Some(col), Target::Opening(_) | Target::Signed(_)) =
            (conv, c.column.as_deref(), target)
        {
            let hi = v.iter().fold(0.0f64, |m, u| m.max(u.abs()));
            // Within 1 %: fractions; within 10 %: a valve's 0..10 V command.
            let slip = if hi <= 0.01 {
                "values in 0..1 (`unit = \"fraction\"`) read as percent?"
            } else {
                "valve volts (0..10 V) read as percent? (`unit = \"V\"` with a `curve`)"
            };
            if *factor == 0.01 && hi > 0.0 && hi <= 0.1 * (1.0 + 1e-9) {
                let at = crate::validate::toml_key_line(&mapping.text, "channel", i, "unit")
                    .map(|line| format!("{}:{line}", map_path.display()))
                    .unwrap_or_else(|| map_path.display().to_string());
                warnings.push(format!(
                    "{at}: channel[{i}] (`{}`): column `{col}` with `unit = \"percent\"` never \
                     opens beyond {} % over the whole file: {slip}",
                    c.channel,
                    Shown(hi * 100.0)
                ));
            }
        }
        let (Convert::OnOff { threshold }, Some(col)) = (conv, c.column.as_deref()) else {
            continue;
        };
        let state = if v.iter().all(|u| *u == 0.0) {
            "closed"
        } else if v.iter().all(|u| *u == 1.0) {
            "open"
        } else {
            continue;
        };
        let at = crate::validate::toml_key_line(&mapping.text, "channel", i, "threshold")
            .or_else(|| crate::validate::toml_key_line(&mapping.text, "channel", i, "unit"))
            .map(|line| format!("{}:{line}", map_path.display()))
            .unwrap_or_else(|| map_path.display().to_string());
        warnings.push(format!(
            "{at}: channel[{i}] (`{}`): `threshold` {} leaves column `{col}` {state} over the \
             whole file (open when the value is >= threshold): is the threshold between the \
             column's closed and open levels?",
            c.channel,
            Shown(*threshold)
        ));
    }
    warnings
}

/// How `plans` converts output channel `ch`.
fn plan_conv(plans: &[(Target, Convert)], ch: Channel) -> Option<&Convert> {
    plans
        .iter()
        .find(|(t, _)| *t == Target::Output(ch))
        .map(|(_, c)| c)
}

/// The range of each mapped output channel, and a warning for a pressure that never leaves
/// the first few kPa or an angle that never moves a degree (a unit too large read as a
/// smaller one: bar as kPa, radians as degrees).
fn channel_ranges(
    mapping: &Mapping,
    plans: &[(Target, Convert)],
    values: &[Vec<f64>],
) -> (Vec<String>, Vec<String>) {
    let mut ranges = Vec::new();
    let mut warnings = Vec::new();
    for ((target, _), (c, v)) in plans.iter().zip(mapping.channel.iter().zip(values)) {
        let Target::Output(ch) = *target else {
            continue;
        };
        let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let source = match &c.column {
            Some(col) => format!("column `{col}`"),
            None => "constant".into(),
        };
        let (scale, unit) = match ch {
            Channel::P1Kpa | Channel::P2Kpa => (1e-3, "kPa gauge"),
            Channel::AngleDeg => (180.0 / std::f64::consts::PI, "deg"),
            _ => (1.0, "N"),
        };
        ranges.push(format!(
            "{} ({source}): {:.4} .. {:.4} {unit}",
            c.channel,
            lo * scale,
            hi * scale
        ));
        if c.column.is_none() {
            continue;
        }
        let read_as_gauge = matches!(plan_conv(plans, ch), Some(Convert::Factor { minus_pa, .. }) if *minus_pa == 0.0);
        match ch {
            Channel::P1Kpa | Channel::P2Kpa
                if read_as_gauge
                    && (lo - mapping.pressure.p_atm_pa).abs() <= P_ABSOLUTE_SUSPECT_WITHIN_PA =>
            {
                warnings.push(format!(
                    "{} never goes below {} kPa gauge over the file (a muscle that vents \
                     reaches 0 kPa gauge, and the atmosphere is {} kPa): {ABSOLUTE_PRESSURE_HINT}",
                    c.channel,
                    Shown(lo * 1e-3),
                    Shown(mapping.pressure.p_atm_pa * 1e-3)
                ))
            }
            Channel::P1Kpa | Channel::P2Kpa if lo.abs().max(hi.abs()) < P_SUSPECT_BELOW_PA => {
                warnings.push(format!(
                    "{} never exceeds {} kPa gauge over the file: a muscle that moves sees \
                     hundreds of kPa; is `unit` right (bar or MPa read as kPa?)",
                    c.channel,
                    P_SUSPECT_BELOW_PA * 1e-3
                ))
            }
            Channel::P1Kpa | Channel::P2Kpa
                if lo < -P_SUSPECT_GAUGE_BELOW_ATM_FRACTION * mapping.pressure.p_atm_pa =>
            {
                warnings.push(format!(
                    "{} goes down to {:.1} kPa gauge: a muscle exhausts to the atmosphere (0 \
                     kPa gauge), and closed valves on a stretched muscle take it a few tens of \
                     kPa below, not this far; is `reference` right (absolute read as gauge, \
                     gauge mapped as absolute?), or `unit` (bar read as kPa?)",
                    c.channel,
                    lo * 1e-3
                ))
            }
            Channel::AngleDeg if hi - lo < ANGLE_SPAN_SUSPECT_BELOW_RAD => warnings.push(format!(
                "angle moves {:.4} deg over the whole file: is `unit` right (radians read as \
                 degrees?)",
                (hi - lo).to_degrees()
            )),
            // Read as degrees, it never leaves +-pi "degrees": the range of an angle logged
            // in radians.
            Channel::AngleDeg
                if matches!(plan_conv(plans, ch), Some(Convert::Factor { factor, .. })
                    if *factor == std::f64::consts::PI / 180.0)
                    && lo.abs().max(hi.abs()) <= std::f64::consts::PI.to_radians() =>
            {
                warnings.push(format!(
                    "angle stays within {:.4} .. {:.4} deg over the whole file, inside +-3.1416: \
                     the range of an angle logged in radians. Is `unit = \"deg\"` right \
                     (radians read as degrees?); if the joint moved this little, ignore this",
                    lo.to_degrees(),
                    hi.to_degrees()
                ))
            }
            _ => {}
        }
    }
    (ranges, warnings)
}

/// Arguments of `host-sim import`.
#[derive(Debug)]
pub struct ImportArgs {
    /// Mapping file (TOML): rig columns -> recording channels and units (docs/rig.md).
    pub map: PathBuf,
    /// The rig logger's CSV file.
    pub input: PathBuf,
    /// Output recording (RECORDING.md).
    pub out: PathBuf,
    /// Write one recording per gap-free segment (REC-1.csv, REC-2.csv, ...) instead of
    /// refusing a file with gaps.
    pub split: bool,
    /// Valve columns logged this late against the sensor columns [ms]: moved earlier by it
    /// ([`crate::io::timebase::shift_valves`]).
    pub shift_valves_ms: Option<f64>,
}

/// `host-sim import`: returns the report printed on stdout.
pub fn run_import(a: &ImportArgs) -> anyhow::Result<String> {
    let inputs = [("--map", a.map.as_path()), ("--input", a.input.as_path())];
    crate::validate::distinct_file_outputs(&inputs, &[("--out", &a.out)])
        .map_err(anyhow::Error::msg)?;
    let mapping = Mapping::load(&a.map)?;
    let mut imp = import(&mapping, &a.map, &a.input, a.split)?;
    if let Some(ms) = a.shift_valves_ms {
        for seg in &mut imp.segments {
            *seg = crate::io::timebase::shift_valves(seg, ms * 1e-3).map_err(anyhow::Error::msg)?;
        }
    }
    let (written, stale) = crate::io::segments::write_segments(
        &a.out,
        &inputs,
        &imp.segments,
        "import",
        |_, p, rec| {
            format!(
                "wrote {}: {} samples, {:.3} s, median step {} s",
                p.display(),
                rec.len(),
                rec.t_s[rec.len() - 1],
                Shown(imp.median_step_s)
            )
        },
    )?;
    let mut report = written;
    use std::fmt::Write as _;
    let _ = writeln!(
        report,
        "time stamps: max jitter {:.1} % of the median step; {} gap(s){}",
        100.0 * imp.max_jitter,
        imp.gaps.len(),
        if imp.gaps.is_empty() {
            ""
        } else {
            " (split, not filled):"
        }
    );
    for (l, t0, t1) in &imp.gaps {
        let _ = writeln!(report, "  gap before line {l}: {t0:.6} s -> {t1:.6} s");
    }
    for r in &imp.ranges {
        let _ = writeln!(report, "  {r}");
    }
    // Warnings go to stderr (the report on stdout stays the record of what was written).
    for w in &imp.warnings {
        eprintln!("warning: {w}");
    }
    report += &stale;
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stamp_decimals_counts_the_digits_after_the_mappings_separator() {
        assert_eq!(stamp_decimals("12.345", false), Some(3));
        assert_eq!(stamp_decimals("12,5", true), Some(1));
        assert_eq!(stamp_decimals("12", false), Some(0));
        // A comma is no separator in a point mapping.
        assert_eq!(stamp_decimals("12,5", false), Some(0));
        assert_eq!(stamp_decimals("1.5e-3", false), None);
    }

    #[test]
    fn valve_openings_split_a_signed_valve_and_model_a_regulator() {
        let plans = vec![
            (Target::Signed(0), Convert::scale(1.0)),
            (Target::Regulator(1), Convert::scale(1.0)),
            (Target::Output(Channel::P2Kpa), Convert::scale(1.0)),
        ];
        let band_pa = 20e3;
        // Row 0: valve1 exhausts at 0.4; regulator2 10 kPa above p2 (half the band).
        // Row 1: valve1 inflates at 0.7; regulator2 50 kPa under p2 (beyond the band).
        let values = vec![vec![-0.4, 0.7], vec![310e3, 250e3], vec![300e3, 300e3]];
        let u0 = valve_openings(&plans, &values, 0, band_pa);
        assert_eq!(u0, [0.0, 0.4, 0.5, 0.0]);
        let u1 = valve_openings(&plans, &values, 1, band_pa);
        assert_eq!(u1, [0.7, 0.0, 0.0, 1.0]);
    }
}
