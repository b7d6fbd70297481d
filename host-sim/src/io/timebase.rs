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

pub use crate::io::grid::{
    gaps_refused, median_step_s, step_refused, Grid, FILLED_ROWS_KEY, GAP_WHOLE_STEP_TOLERANCE,
    MAX_FILLED_SHARE, MAX_GAP_STEPS,
};
use crate::io::recording::Recording;

impl Recording {
    /// The recording on the uniform grid `t_0 + k dt` ([`on_grid`]):
    /// each grid cell's valve opening is the time average of the openings held between the
    /// original stamps over that cell (the opening-time a valve delivers is kept; an on/off
    /// edge between grid points becomes one fractional opening), and each output channel is
    /// linearly interpolated between the two stamps around the grid point. Rows the logger
    /// dropped (a step of a whole number of periods) are filled (the last logged opening
    /// held) and listed under [`FILLED_ROWS_KEY`]: the diagnosis leaves
    /// them out of its fits. Without gaps `dt` is the mean step and the number of samples
    /// is kept. A uniform recording is returned unchanged.
    pub fn to_uniform(&self) -> Recording {
        if self.is_uniform() {
            return self.clone();
        }
        on_grid(self)
    }
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
