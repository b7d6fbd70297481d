//! The time stamps of a recording: its median step, which steps are jitter and which are
//! gaps of dropped rows, and the uniform grid they are put on (`io/timebase.rs` fills the
//! gaps; `io/recording.rs` refuses what cannot be filled). Pure arithmetic on the stamps.

use std::ops::Range;

/// Largest accepted step between two time stamps, in median steps: a longer step is a gap.
pub const MAX_STEP_RATIO: f64 = 1.5;
/// Smallest accepted step between two time stamps, in median steps.
pub const MIN_STEP_RATIO: f64 = 0.5;

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
