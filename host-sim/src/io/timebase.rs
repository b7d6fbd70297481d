//! A recording's time base: jittered stamps and rows the logger dropped, put on one uniform
//! grid.
//!
//! A logger that drops rows leaves steps of a whole number of sample periods (2, 3, ...
//! median steps, each stamp jittered); the plant kept running through them. Such a
//! recording is put on the uniform grid `t_0 + k dt` with the dropped rows filled in (the
//! openings held from the last logged row, which is all the log says of them; the outputs
//! interpolated so that a derivative or a plot sees no jump) and the filled rows listed in
//! the metadata key [`FILLED_ROWS_KEY`]: the diagnosis replays the plant through them (its
//! state carried across the gap) and leaves them out of every cost, fit and noise figure
//! ([`MeasuredRows`]).
//!
//! What is accepted: steps within [[`MIN_STEP_RATIO`], [`MAX_STEP_RATIO`]] median steps
//! (jitter); a longer step within [`GAP_WHOLE_STEP_TOLERANCE`] of a whole number of median
//! steps, at most [`MAX_GAP_STEPS`] of them (a gap); at most [`MAX_FILLED_SHARE`] of the
//! grid's rows filled. Anything else is refused by the recording reader (split the
//! recording).

use std::ops::Range;

use crate::io::recording::{Recording, MAX_STEP_RATIO, MIN_STEP_RATIO};

/// The longest gap filled, in median steps (a step of this many periods: this many minus
/// one rows dropped).
pub const MAX_GAP_STEPS: f64 = 20.0;
/// A gap's step is a whole number of median steps within this many median steps (stamps
/// jittered by up to +-20 % of the period make a gap's step up to 0.4 periods off).
pub const GAP_WHOLE_STEP_TOLERANCE: f64 = 0.45;
/// At most this share of the grid's rows may be filled.
pub const MAX_FILLED_SHARE: f64 = 0.10;
/// The metadata key listing the filled rows of a recording put on its grid: `start+count`
/// pairs separated by spaces (row indices from 0).
pub const FILLED_ROWS_KEY: &str = "filled_rows";

/// The grid index of every time stamp and the grid's period.
#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    /// Grid index of stamp `i` (`index[0] == 0`, increasing).
    pub index: Vec<usize>,
    /// The grid's period: the first-to-last time over the last index (the mean step when no
    /// row is missing).
    pub dt_s: f64,
    /// The median step of the stamps.
    pub median_step_s: f64,
}

impl Grid {
    /// The grid of the increasing stamps `t_s`: a step within [`MAX_STEP_RATIO`] median steps
    /// advances one index, a longer one its whole number of median steps.
    pub fn of(t_s: &[f64]) -> Grid {
        let n = t_s.len();
        if n < 2 {
            return Grid {
                index: (0..n).collect(),
                dt_s: f64::NAN,
                median_step_s: f64::NAN,
            };
        }
        let median = median_step_s(t_s);
        let mut index = Vec::with_capacity(n);
        index.push(0usize);
        let mut k = 0usize;
        for w in t_s.windows(2) {
            k += steps_of(w[1] - w[0], median);
            index.push(k);
        }
        Grid {
            dt_s: (t_s[n - 1] - t_s[0]) / k.max(1) as f64,
            index,
            median_step_s: median,
        }
    }

    /// Rows of the grid.
    pub fn len(&self) -> usize {
        self.index.last().map_or(0, |k| k + 1)
    }

    pub fn is_empty(&self) -> bool {
        self.index.is_empty()
    }

    /// Rows the stamps leave out (the logger dropped), as ranges of grid rows.
    pub fn gaps(&self) -> Vec<Range<usize>> {
        self.index
            .windows(2)
            .filter(|w| w[1] > w[0] + 1)
            .map(|w| w[0] + 1..w[1])
            .collect()
    }

    /// Number of grid rows the stamps leave out.
    pub fn filled(&self) -> usize {
        self.len() - self.index.len()
    }
}

/// The median step of increasing stamps (`NaN` for fewer than two).
pub fn median_step_s(t_s: &[f64]) -> f64 {
    if t_s.len() < 2 {
        return f64::NAN;
    }
    let mut steps: Vec<f64> = t_s.windows(2).map(|w| w[1] - w[0]).collect();
    let half = steps.len() / 2;
    *steps.select_nth_unstable_by(half, f64::total_cmp).1
}

/// Grid steps a time step of `step` makes at the median step `median`: one for a step
/// within [`MAX_STEP_RATIO`] median steps, else its whole number of median steps.
fn steps_of(step: f64, median: f64) -> usize {
    let r = step / median;
    if r <= MAX_STEP_RATIO {
        1
    } else {
        (r.round() as usize).max(2)
    }
}

/// Why a step of the stamps is refused, `None` when it is a jittered step or a gap that is
/// filled.
pub fn step_refused(step: f64, median: f64) -> Option<String> {
    let r = step / median;
    if r < MIN_STEP_RATIO {
        return Some(format!(
            "the step is {r:.2} median steps (under {MIN_STEP_RATIO}: a doubled row?)"
        ));
    }
    if r <= MAX_STEP_RATIO {
        return None;
    }
    if r > MAX_GAP_STEPS + GAP_WHOLE_STEP_TOLERANCE {
        return Some(format!(
            "a gap of {r:.1} median steps; gaps of up to {MAX_GAP_STEPS} median steps are \
             filled (the rows left out of every fit), a longer one is not: split the recording"
        ));
    }
    if (r - r.round()).abs() > GAP_WHOLE_STEP_TOLERANCE {
        return Some(format!(
            "a step of {r:.2} median steps: jitter within [{MIN_STEP_RATIO}, \
             {MAX_STEP_RATIO}] median steps is accepted, a gap of dropped rows must be a \
             whole number of median steps (within {GAP_WHOLE_STEP_TOLERANCE})"
        ));
    }
    None
}

/// Why the stamps' gaps, taken together, are refused (more than [`MAX_FILLED_SHARE`] of the
/// grid filled); `None` when they are filled.
pub fn gaps_refused(grid: &Grid) -> Option<String> {
    let share = grid.filled() as f64 / grid.len().max(1) as f64;
    (share > MAX_FILLED_SHARE).then(|| {
        format!(
            "{} of {} rows ({:.1} %) are missing in gaps; up to {:.0} % are filled (left out \
             of every fit), more are not: split the recording",
            grid.filled(),
            grid.len(),
            100.0 * share,
            100.0 * MAX_FILLED_SHARE
        )
    })
}

/// `rec` on its uniform grid ([`Grid::of`]): each grid cell's valve opening is the time
/// average of the openings held between the stamps over that cell (a dropped row's cell
/// holds the last logged opening), each output channel (and the mass flows) linearly
/// interpolated between the stamps around the grid point; filled rows listed under
/// [`FILLED_ROWS_KEY`].
pub fn on_grid(rec: &Recording) -> Recording {
    use crate::io::recording::{interpolate, Channel};
    use crate::plant::ValveInputs;
    let n = rec.t_s.len();
    let g = Grid::of(&rec.t_s);
    let t0 = rec.t_s[0];
    let dt = g.dt_s;
    let rows = g.len();
    let grid: Vec<f64> = (0..rows).map(|k| t0 + k as f64 * dt).collect();
    // Input i is held over [t_i, t_{i+1}); the last one over [t_{n-1}, end of the grid).
    let t_end = (t0 + rows as f64 * dt).max(rec.t_s[n - 1]);
    let hold_end = |i: usize| if i + 1 < n { rec.t_s[i + 1] } else { t_end };
    let mut inputs = Vec::with_capacity(rows);
    let mut j = 0usize;
    for &a in &grid {
        let b = a + dt;
        while j + 1 < n && rec.t_s[j + 1] <= a {
            j += 1;
        }
        let mut acc = [0.0f64; 4];
        let mut i = j;
        loop {
            let lo = rec.t_s[i].max(a);
            let hi = hold_end(i).min(b);
            if hi > lo {
                let u = rec.inputs[i];
                for (s, v) in acc.iter_mut().zip([u.u_in1, u.u_ex1, u.u_in2, u.u_ex2]) {
                    *s += v * (hi - lo);
                }
            }
            if i + 1 >= n || rec.t_s[i + 1] >= b {
                break;
            }
            i += 1;
        }
        let f = |s: f64| (s / dt).clamp(0.0, 1.0);
        inputs.push(ValveInputs {
            u_in1: f(acc[0]),
            u_ex1: f(acc[1]),
            u_in2: f(acc[2]),
            u_ex2: f(acc[3]),
        });
    }
    let gaps = g.gaps();
    let mut out = Recording {
        metadata: rec.metadata.clone(),
        t_s: grid.clone(),
        inputs,
        outputs: Default::default(),
        mass_flow_kg_s: rec.mass_flow_kg_s.as_ref().map(|[a, b]| {
            [
                interpolate(&rec.t_s, a, &grid),
                interpolate(&rec.t_s, b, &grid),
            ]
        }),
    };
    out.metadata
        .retain(|(k, _)| k != "sample_period_s" && k != FILLED_ROWS_KEY);
    out.metadata
        .push(("sample_period_s".into(), format!("{dt}")));
    let what = if gaps.is_empty() {
        "jittered time stamps put on the uniform grid (openings time-averaged, outputs \
         linearly interpolated)"
            .to_string()
    } else {
        format!(
            "time stamps put on the uniform grid (openings time-averaged, outputs linearly \
             interpolated); {} rows the logger dropped in {} gaps filled (openings held from \
             the last logged row, outputs interpolated) and left out of every fit ({})",
            g.filled(),
            gaps.len(),
            FILLED_ROWS_KEY
        )
    };
    out.metadata.push(("resampled".into(), what));
    if !gaps.is_empty() {
        let list: Vec<String> = gaps
            .iter()
            .map(|r| format!("{}+{}", r.start, r.len()))
            .collect();
        out.metadata.push((FILLED_ROWS_KEY.into(), list.join(" ")));
    }
    for c in Channel::ALL {
        if let Some(y) = rec.channel(c) {
            out.set_channel(c, interpolate(&rec.t_s, y, &grid));
        }
    }
    out
}

/// The rows of a recording that hold measurements (not rows filled in a gap,
/// [`FILLED_ROWS_KEY`]): every row of a recording without gaps.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MeasuredRows {
    /// `filled[k]`: row `k` was filled in; `None`: no row was.
    filled: Option<Vec<bool>>,
}

impl MeasuredRows {
    /// The measured rows of `rec` (its [`FILLED_ROWS_KEY`] read; a malformed or
    /// out-of-range entry is ignored).
    pub fn of(rec: &Recording) -> MeasuredRows {
        let n = rec.len();
        let Some(list) = rec.meta(FILLED_ROWS_KEY) else {
            return MeasuredRows::default();
        };
        let mut filled = vec![false; n];
        let mut any = false;
        for item in list.split_whitespace() {
            let Some((a, b)) = item.split_once('+') else {
                continue;
            };
            let (Ok(a), Ok(b)) = (a.parse::<usize>(), b.parse::<usize>()) else {
                continue;
            };
            for f in filled.iter_mut().skip(a).take(b) {
                *f = true;
                any = true;
            }
        }
        MeasuredRows {
            filled: any.then_some(filled),
        }
    }

    /// Every row measured.
    pub fn all() -> MeasuredRows {
        MeasuredRows::default()
    }

    /// Whether row `k` holds a measurement.
    #[inline]
    pub fn has(&self, k: usize) -> bool {
        self.filled
            .as_ref()
            .is_none_or(|f| !f.get(k).copied().unwrap_or(false))
    }

    /// Whether some row was filled.
    pub fn any_filled(&self) -> bool {
        self.filled.is_some()
    }

    /// Measured rows in `range`.
    pub fn count(&self, range: Range<usize>) -> usize {
        match &self.filled {
            None => range.len(),
            Some(f) => range
                .filter(|&k| !f.get(k).copied().unwrap_or(false))
                .count(),
        }
    }

    /// The measured values of `y` (rows in order).
    pub fn values<'y>(&'y self, y: &'y [f64]) -> impl Iterator<Item = f64> + 'y {
        y.iter()
            .enumerate()
            .filter(move |(k, _)| self.has(*k))
            .map(|(_, v)| *v)
    }

    /// The runs of consecutive measured rows of a recording of `n` rows.
    pub fn runs(&self, n: usize) -> Vec<Range<usize>> {
        let mut out = Vec::new();
        let mut start = None;
        for k in 0..n {
            match (self.has(k), start) {
                (true, None) => start = Some(k),
                (false, Some(s)) => {
                    out.push(s..k);
                    start = None;
                }
                _ => {}
            }
        }
        if let Some(s) = start {
            out.push(s..n);
        }
        out
    }
}

/// The range of a valve-column shift ([`shift_valves`]) [ms]: the longest valve dead time
/// a plant file may state, either way.
pub const SHIFT_VALVES_MS: crate::validate::Range = crate::validate::Range::closed(-1000.0, 1000.0);

/// `rec` with its valve columns moved `shift_s` earlier against the sensor columns (valves
/// logged `shift_s` late; a negative shift: logged early): the row stamped `t` gets the
/// openings logged at `t + shift_s` (the last row at or before it). Rows that have no
/// opening left (the last `shift_s` of the run; the first `-shift_s` for a negative shift)
/// are dropped. Refused outside [`SHIFT_VALVES_MS`] or when fewer than two rows are left.
pub fn shift_valves(rec: &Recording, shift_s: f64) -> Result<Recording, String> {
    let ms = shift_s * 1e3;
    if !SHIFT_VALVES_MS.contains(ms) {
        return Err(format!(
            "--shift-valves-ms {ms}: outside {SHIFT_VALVES_MS} ms (the longest valve dead \
             time a plant file may state, either way)"
        ));
    }
    let n = rec.len();
    let (t_first, t_last) = (rec.t_s[0], rec.t_s[n - 1]);
    let keep: Vec<usize> = (0..n)
        .filter(|&k| {
            let t = rec.t_s[k] + shift_s;
            t >= t_first - 1e-9 * shift_s.abs() && t <= t_last + 1e-9 * shift_s.abs()
        })
        .collect();
    if keep.len() < 2 {
        return Err(format!(
            "--shift-valves-ms {ms}: leaves {} rows of {n} (the shift is longer than the \
             recording)",
            keep.len()
        ));
    }
    let mut j = 0usize;
    let inputs = keep
        .iter()
        .map(|&k| {
            let t = rec.t_s[k] + shift_s + 1e-9 * (t_last - t_first) / n as f64;
            while j + 1 < n && rec.t_s[j + 1] <= t {
                j += 1;
            }
            rec.inputs[j]
        })
        .collect();
    let pick = |v: &[f64]| keep.iter().map(|&k| v[k]).collect::<Vec<f64>>();
    let mut out = Recording {
        metadata: rec.metadata.clone(),
        t_s: pick(&rec.t_s),
        inputs,
        outputs: std::array::from_fn(|i| rec.outputs[i].as_deref().map(pick)),
        mass_flow_kg_s: rec.mass_flow_kg_s.as_ref().map(|[a, b]| [pick(a), pick(b)]),
    };
    out.metadata.retain(|(k, _)| k != FILLED_ROWS_KEY);
    out.metadata.push((
        "valves_shifted_ms".into(),
        format!("{ms} (valve columns moved {ms} ms earlier against the sensor columns)"),
    ));
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::recording::Channel;
    use crate::plant::ValveInputs;

    fn rec(t_s: Vec<f64>) -> Recording {
        let n = t_s.len();
        let mut r = Recording {
            metadata: Vec::new(),
            inputs: (0..n)
                .map(|k| ValveInputs {
                    u_in1: ((k + 1) % 2) as f64,
                    ..ValveInputs::CLOSED
                })
                .collect(),
            t_s,
            outputs: Default::default(),
            mass_flow_kg_s: None,
        };
        let y: Vec<f64> = r.t_s.iter().map(|t| 3.0 * t + 1.0).collect();
        r.set_channel(Channel::AngleDeg, y);
        r
    }

    /// Rows dropped from a jittered log: the grid has the logged rows' period, the dropped
    /// rows are listed as filled, the openings over a gap are the last logged one and a
    /// line is interpolated exactly.
    #[test]
    fn dropped_rows_are_filled_on_the_grid_and_listed() {
        let dt = 0.002;
        let jitter = [
            0.0, 0.15, -0.2, 0.1, -0.05, 0.2, 0.0, -0.18, 0.12, 0.0, 0.0, 0.05,
        ];
        let keep = |k: usize| !(3..5).contains(&k) && k != 8;
        let t: Vec<f64> = (0..12)
            .filter(|&k| keep(k))
            .map(|k| (k as f64 + if k == 11 { 0.0 } else { jitter[k] }) * dt)
            .collect();
        let g = Grid::of(&t);
        assert_eq!(g.index, vec![0, 1, 2, 5, 6, 7, 9, 10, 11]);
        assert_eq!(g.gaps(), vec![3..5, 8..9]);
        assert!((g.dt_s - dt).abs() < 1e-15);
        let r = rec(t);
        let u = on_grid(&r);
        assert_eq!(u.len(), 12);
        assert_eq!(u.meta(FILLED_ROWS_KEY), Some("3+2 8+1"));
        let m = MeasuredRows::of(&u);
        assert_eq!(m.count(0..12), 9);
        assert!(!m.has(3) && !m.has(4) && !m.has(8) && m.has(5));
        assert_eq!(m.runs(12), vec![0..3, 5..8, 9..12]);
        for (k, y) in u.channel(Channel::AngleDeg).unwrap().iter().enumerate() {
            assert!((y - (3.0 * k as f64 * dt + 1.0)).abs() < 1e-12, "{k}: {y}");
        }
        // Logged row 2 (at 1.8 periods, opening 1; rows 1 and 3 have 0) holds over the gap
        // until the next logged row at 5.2 periods.
        assert_eq!(u.inputs[3].u_in1, 1.0);
        assert_eq!(u.inputs[4].u_in1, 1.0);
        assert!((u.inputs[5].u_in1 - 0.2).abs() < 1e-9, "{:?}", u.inputs[5]);
    }

    /// Valves logged two samples late are moved back: the row at t gets the openings
    /// logged at t + 2 dt, the last two rows (no opening left) are dropped; a shift outside
    /// the range is refused with the range named.
    #[test]
    fn valve_columns_shift_earlier_by_whole_rows() {
        let r = rec((0..10).map(|k| k as f64 * 0.01).collect());
        let s = shift_valves(&r, 0.02).unwrap();
        assert_eq!(s.len(), 8);
        for k in 0..8 {
            assert_eq!(s.inputs[k], r.inputs[k + 2], "{k}");
            assert_eq!(s.t_s[k], r.t_s[k]);
        }
        let back = shift_valves(&r, -0.02).unwrap();
        assert_eq!(back.t_s[0], r.t_s[2]);
        assert_eq!(back.inputs[0], r.inputs[0]);
        let e = shift_valves(&r, 1.5).unwrap_err();
        assert!(e.contains("-1000") && e.contains("1000"), "{e}");
        assert!(shift_valves(&r, 0.095).is_err());
    }

    /// Steps that are neither jitter nor a gap of whole samples, gaps too long and too many
    /// rows missing are refused with the limits named.
    #[test]
    fn steps_and_gaps_beyond_the_limits_are_refused() {
        assert!(step_refused(1.4, 1.0).is_none());
        assert!(step_refused(2.3, 1.0).is_none());
        assert!(step_refused(10.0, 1.0).is_none());
        assert!(step_refused(2.5, 1.0).unwrap().contains("whole number"));
        assert!(step_refused(30.0, 1.0)
            .unwrap()
            .contains("split the recording"));
        assert!(step_refused(0.3, 1.0).is_some());
        let t: Vec<f64> = (0..100)
            .filter(|k| !(10..25).contains(k))
            .map(f64::from)
            .collect();
        let msg = gaps_refused(&Grid::of(&t)).unwrap();
        assert!(
            msg.contains("15 of 100 rows") && msg.contains("10 %"),
            "{msg}"
        );
    }
}
