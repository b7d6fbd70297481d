//! `host-sim tune`: finds, by the same cost and the same kind of search, the model-based
//! cascade's gains and the model-free PD and PID (angle -> activation dp, `pam_firmware::pid`)
//! that minimise the suite MSE on a plant with the firmware in the loop, and writes all three
//! to a gains file (`config/control_tuned.toml`, [`ControlTuning`]).
//!
//! ```sh
//! cargo run --release -p host-sim -- tune --plant ../shared/plant/reference-1dof.toml \
//!     --out config/control_tuned.toml [--threads 2] [--warm-start] [--transition-s T]
//! ```
//!
//! Procedure (deterministic: the scenarios carry their noise seeds). Suite =
//! `control::compare::SUITE` (`--transition-s T` changes the duration of its set-point moves).
//! Suite MSE = the mean over its step, sine and random scenarios of the MSE of the angle over
//! every tick (a latched fault = infinite). Cost ([`tuning_cost`]) = the worse of the suite MSE
//! at the gains and with the feedback gains x [`GAIN_MARGIN`] (2 = 6 dB), infinite if the step
//! overshoots by more than 10 %.
//! 1. Fixed for every law: the set-point differentiators' cut-off (150 Hz); for the PD / PID
//!    the cascade's actuation limits: p0 = 300 kPa, |dp| <= 280 kPa (the torque model's
//!    `dp_max_pa`), PID integrator limit 150 kPa (half the usable dp range).
//! 2. Cascade: from each start (kp, ki, kd, torque-loop ki) = (11, 8, 0.8, 30) (the gains
//!    before the feed-forward existed), the firmware's default gains, (with `--warm-start`)
//!    the gains stored in `--out`, and any `--cascade-start`, each with the feed-forward's
//!    inertia term off and on (J of the plant): Nelder-Mead on log10 of the four gains,
//!    restarted from its result while a restart gains > 1 %, then the polish of step 5. The
//!    firmware's step tests ([`STEP_REQUIREMENTS`]: nominal and 11 x inertia) are hard
//!    constraints of the cascade: a candidate that fails one costs infinity.
//! 3. PD / PID: coarse grid, every point two suite runs:
//!    kp in {3e4, 1e5, 2e5, 5e5, 1e6, 2e6, 5e6} Pa/rad, kd in {1e3, 3e3, 1e4, 3e4, 1e5}
//!    Pa s/rad, for the PID also ki in {3e4, 1e5, 1e6, 3e6, 1e7, 3e7, 1e8} Pa/(rad s), each
//!    with the derivative on the measurement (w = 0) and on the error (w = 1). No PD or PID of
//!    this grid meets the step tests (the PD never settles into +-0.01 rad, the PID does not
//!    survive the 11 x load), so for them the tests are reported, not imposed.
//! 4. PD / PID: Nelder-Mead on (log10 kp, log10 kd[, log10 ki]) from the best grid point (its
//!    w) and (with `--warm-start`) from the stored gains, initial steps 0.2 decades, until the
//!    simplex costs agree within 0.2 % or 120 points; the better result is restarted as in
//!    step 2.
//! 5. Polish: pattern search, each gain x0.7 / x1.4 (PD / PID: and the derivative's set-point
//!    weight flipped), any improvement accepted, until no move improves (the local-optimum
//!    tests of `host-sim/tests/control_compare.rs` check exactly these moves).
//! 6. The results are written (atomically) with their suite MSE and their suite MSE at the
//!    margin (the tests re-measure both) and a provenance header.

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use pam_firmware::pid::DpPidGains;
use pam_firmware::tick::{ControlLaw, ControllerConfig};

use crate::control::closed_loop::Scenario;
use crate::control::compare::{
    config_for, jump_suite_scenarios, meets_step_requirement, suite_scenarios, tuning_cost,
    CascadeToml, ControlTuning, DpPidToml, GAIN_MARGIN, STEP_REQUIREMENTS,
};
use crate::control::robustness::{
    condition_config, stable_with_margin_on, try_condition_plant, CONDITIONS,
    ROBUST_COST_CONDITIONS, ROBUST_STABLE_CONDITIONS,
};
use crate::optimize::{nelder_mead, nelder_mead_restarted, pattern_search};
use crate::Plant;

/// What `--stable-on-jumps` does, for the gains file's header.
const STABLE_ON_JUMPS_NOTE: &str =
    "--stable-on-jumps, every law: infinite cost unless the suite and the jump suite (the\n\
demo's step, sine and random set-points) stay stable on the plant: no fault, |error| < 0.5\n\
rad, and a run that ends in a hold comes to rest (spread of the error over its last 0.5 s\n\
<= 0.01 rad).";

/// What `--pressure-ff` does, for the gains file's header.
const PRESSURE_FF_NOTE: &str =
    "--pressure-ff: the cascade (and the default gains' figure below) runs the pressure loops'\n\
inverse thermodynamic feed-forward (the analytical model, with the options of\n\
config/pressure_ff.toml built into host-sim); the PD / PID do not use it.";

/// What `--robust` does, for the log and the gains file's header.
const ROBUST_NOTE: &str =
    "Robust cost (--robust), every law: the worst of this cost on the plant and on the\n\
plant with an 8 ms valve dead time (valve supervision off: its residual window reads the\n\
delay as a stuck exhaust whatever the law); infinite unless the suite and the jump suite\n\
(the demo's step, sine and random set-points, jumps) stay stable on the plant with 11 x its\n\
inertia: no fault, |error| < 0.5 rad, and a run that ends in a hold comes to rest there\n\
(spread of the error over its last 0.5 s <= 0.01 rad: no limit cycle).";

/// `host-sim tune`.
#[derive(Debug)]
pub struct TuneArgs {
    /// Plant file the gains are tuned on.
    pub plant: PathBuf,
    /// Output gains file (the format of config/control_tuned.toml), written atomically.
    pub out: PathBuf,
    /// Threads for the PD / PID grids and polish (1..=256, as every command's --threads).
    pub threads: usize,
    /// Also start every search from the gains stored in --out (when it loads); without it the
    /// search is reproducible from scratch.
    pub warm_start: bool,
    /// Cut-off of every law's set-point differentiators [Hz] (1..=500).
    pub setpoint_cutoff_hz: f32,
    /// Duration of the suite's set-point moves [s] (0..=2, 0 = jumps) [default: the suite's 0.15 s].
    pub transition_s: Option<f64>,
    /// One more cascade start KP,KI,KD[,TORQUE_KI] (repeatable), each > 0 and at most what a
    /// gains file loads (kp 1e4 N m/rad, ki 1e6 N m/(rad s), kd 1e3 N m s/rad, torque ki 1e5 1/s).
    pub cascade_start: Vec<String>,
    /// Do not impose the firmware's step tests on the cascade (report them only).
    pub no_step_constraints: bool,
    /// Robustness term in every law's cost: the worse of the cost on the plant and on the
    /// plant with an 8 ms valve dead time (valve supervision off), and infinite unless the suite and the jump
    /// suite (the demo's set-points) stay stable on the plant with 11 x its inertia (no fault, |error| <
    /// 0.5 rad, no limit cycle at rest).
    pub robust: bool,
    /// Tune the cascade with the pressure loops' inverse thermodynamic feed-forward on
    /// (config/pressure_ff.toml's options; the gains file records it), so that it can be
    /// compared at its own best gains (`compare-control --ff-gains`). The PD / PID do not use it.
    pub pressure_ff: bool,
    /// Infinite cost unless the suite and the jump suite (the demo's step, sine and random
    /// set-points) stay stable on the plant itself: no fault, |error| < 0.5 rad, and a run that
    /// ends in a hold comes to rest (spread of the error over its last 0.5 s <= 0.01 rad).
    /// Keeps gains tuned on the smooth suite from limit-cycling after a set-point jump.
    pub stable_on_jumps: bool,
    /// Tune the cascade with its outer loops (position loop, trajectory feed-forward, torque
    /// estimate, torque loop) on one tick in N (1..=5 at the 1 kHz tick); the gains file
    /// records it, and compare-control runs those gains at that rate [default:
    /// config/controller.toml [rates] outer_period_ticks]. The PD / PID do not use it.
    pub outer_period_ticks: Option<u16>,
    /// With --pressure-ff: evaluate the feed-forward once every N ticks and hold it in between
    /// (1..=100 at the 1 kHz tick; 1 = every tick); the gains file records it, and
    /// compare-control runs those gains at that period [default: config/pressure_ff.toml
    /// update_period_ticks, 1 as shipped].
    pub ff_update_ticks: Option<u16>,
}

const KP_GRID: [f64; 7] = [3e4, 1e5, 2e5, 5e5, 1e6, 2e6, 5e6];
const KD_GRID: [f64; 5] = [1e3, 3e3, 1e4, 3e4, 1e5];
const KI_GRID: [f64; 7] = [3e4, 1e5, 1e6, 3e6, 1e7, 3e7, 1e8];

/// The fixed part of every PD / PID tried; `cutoff_hz`: the set-point differentiators.
fn base(ki_on: bool, cutoff_hz: f32) -> DpPidGains {
    DpPidGains {
        kp_pa_per_rad: 0.0,
        ki_pa_per_rad_s: 0.0,
        kd_pa_s_per_rad: 0.0,
        setpoint_rate_weight: 0.0,
        setpoint_rate_cutoff_hz: cutoff_hz,
        i_limit_pa: if ki_on { 150_000.0 } else { 0.0 },
        dp_max_pa: 280_000.0,
        p0_gauge_pa: 300_000.0,
    }
}

fn gains(ki_on: bool, cutoff_hz: f32, w: f32, kp: f64, kd: f64, ki: f64) -> DpPidGains {
    DpPidGains {
        kp_pa_per_rad: kp as f32,
        kd_pa_s_per_rad: kd as f32,
        ki_pa_per_rad_s: if ki_on { ki as f32 } else { 0.0 },
        setpoint_rate_weight: w,
        ..base(ki_on, cutoff_hz)
    }
}

struct Ctx {
    plant: Plant,
    scenarios: Vec<Scenario>,
    runs: AtomicUsize,
    /// Cut-off of the set-point differentiators of every law tuned [Hz].
    cutoff_hz: f32,
    /// Progress (a bar over the searches on a terminal, hidden otherwise) and the log lines.
    progress: ProgressBar,
    /// The log of the search (printed above the bar, returned in the report).
    log: Mutex<Vec<String>>,
    /// The cascade must meet the firmware's step tests ([`STEP_REQUIREMENTS`]).
    cascade_step_constraints: bool,
    /// `--robust`: plants (and their condition names) whose tuning cost is also taken (the
    /// cost is the worst).
    robust_cost: Vec<(Plant, &'static str)>,
    /// `--robust`: plants on which the suite must stay stable (else the cost is infinite).
    robust_stable: Vec<(Plant, &'static str)>,
    /// `--robust`: the set-points that must stay stable on `robust_stable`: the suite and the
    /// jump suite (larger and faster moves than the suite's, so a law that only just holds the
    /// suite on a heavy load is refused).
    stability_scenarios: Vec<Scenario>,
}

impl Ctx {
    /// The tuning cost of `law` (worse of nominal and gain-margin suite MSE).
    fn cost(&self, law: ControlLaw) -> f64 {
        self.cost_cfg(config_for(law, 1000.0)).0
    }

    /// (tuning cost, nominal suite MSE, suite MSE at the gain margin) of `cfg`; with
    /// `--robust` the cost is the worst over the robust plants too, and infinite when the suite
    /// is not stable on one of the stability plants (the MSEs are the plant's own).
    fn cost_cfg(&self, cfg: ControllerConfig) -> (f64, f64, f64) {
        let n = self.runs.fetch_add(2, Ordering::Relaxed) + 2;
        self.progress.set_prefix(format!("{n} runs"));
        let (mut cost, mse, margin) = tuning_cost(&self.plant, &self.scenarios, cfg);
        for p in &self.robust_cost {
            if !cost.is_finite() {
                break;
            }
            self.runs.fetch_add(2, Ordering::Relaxed);
            cost = cost.max(tuning_cost(&p.0, &self.scenarios, condition_config(p.1, cfg)).0);
        }
        for p in &self.robust_stable {
            if !cost.is_finite() {
                break;
            }
            self.runs.fetch_add(1, Ordering::Relaxed);
            if !stable_with_margin_on(&p.0, &self.stability_scenarios, condition_config(p.1, cfg)) {
                cost = f64::INFINITY;
            }
        }
        (cost, mse, margin)
    }

    /// The cascade's cost: [`Ctx::cost_cfg`], infinite when a finite-cost candidate fails one
    /// of the firmware's step tests (hard constraints).
    fn cascade_cost(&self, cfg: ControllerConfig) -> (f64, f64, f64) {
        let c = self.cost_cfg(cfg);
        if !self.cascade_step_constraints || !c.0.is_finite() {
            return c;
        }
        for req in &STEP_REQUIREMENTS {
            self.runs.fetch_add(1, Ordering::Relaxed);
            if !meets_step_requirement(&self.plant, cfg, req).unwrap_or(false) {
                return (f64::INFINITY, c.1, c.2);
            }
        }
        c
    }

    /// Logs a line above the progress bar.
    fn say(&self, line: String) {
        self.progress.set_message(line.clone());
        if self.progress.is_hidden() {
            eprintln!("{line}");
        } else {
            self.progress.println(&line);
        }
        self.log.lock().expect("log lock").push(line);
    }

    /// Costs of `points`, evaluated on `threads` threads.
    fn costs(&self, points: &[DpPidGains], threads: usize) -> Vec<f64> {
        let mut out = vec![f64::INFINITY; points.len()];
        let chunk = points.len().div_ceil(threads.max(1)).max(1);
        std::thread::scope(|s| {
            for (ps, os) in points.chunks(chunk).zip(out.chunks_mut(chunk)) {
                s.spawn(move || {
                    for (p, o) in ps.iter().zip(os.iter_mut()) {
                        *o = self.cost(ControlLaw::DirectPid(*p));
                    }
                });
            }
        });
        out
    }
}

/// Nelder-Mead (steps 0.2 in the coordinates of `to_x`, costs relative to the start's)
/// restarted from its own best point while a restart lowers the cost by more than 1 %, at most
/// 8 runs of 160 points; returns the best point and cost and adds the evaluations to
/// `evaluations`.
#[allow(clippy::too_many_arguments)]
fn restarted_nm<T: Copy>(
    ctx: &Ctx,
    to_x: impl Fn(&T) -> Vec<f64>,
    from_x: impl Fn(&[f64]) -> T,
    cost: impl Fn(&T) -> f64,
    p: T,
    c: f64,
    evaluations: &mut usize,
    name: &str,
) -> (T, f64) {
    let x0 = to_x(&p);
    let r = nelder_mead_restarted(
        |x| cost(&from_x(x)) / c,
        &x0,
        &vec![0.2; x0.len()],
        2e-3,
        160,
        8,
        0.01,
        |run, n, rc| {
            ctx.say(format!(
                "{name}: restart {run} ({n} points): cost {:.4e} rad^2",
                rc * c
            ))
        },
    );
    *evaluations += r.evaluations;
    if r.cost < 1.0 {
        (from_x(&r.x), r.cost * c)
    } else {
        (p, c)
    }
}

/// Pattern search ([`pattern_search`]): evaluates `moves_of(p)` (with `costs`), moves to the
/// best if it lowers the cost, until no move does. Returns the point, its cost and the number
/// of evaluations.
fn polish<T: Copy>(
    p: T,
    c: f64,
    moves_of: impl Fn(&T) -> Vec<T>,
    costs: impl FnMut(&[T]) -> Vec<f64>,
) -> (T, f64, usize) {
    let r = pattern_search(p, c, moves_of, costs, 10_000);
    (r.point, r.cost, r.evaluations)
}

/// Tunes the PD (`ki_on` false) or the PID: the best point of a coarse grid, Nelder-Mead on
/// log10 gains from it and from the `stored` gains, restarted, then the x0.7 / x1.4 polish;
/// the result re-measured. Returns the gains, their (suite MSE, MSE at the gain margin) and
/// the note for the gains file.
fn tune(
    ctx: &Ctx,
    ki_on: bool,
    threads: usize,
    stored: Option<DpPidGains>,
) -> (DpPidGains, (f64, f64), String) {
    let name = if ki_on { "PID" } else { "PD" };
    let grid = pid_grid(ki_on, ctx.cutoff_hz);
    let (g0, cbest) = best_of_grid(ctx, name, &grid, threads);
    let starts = pid_starts(ctx, name, (g0, cbest), stored);
    let from_stored = starts.len() > 1;
    let t1 = Instant::now();
    let mut nm = nm_from_starts(ctx, name, ki_on, starts);
    let (g, c) = nm.best;
    // Nelder-Mead restarted from its own result until a restart gains less than 1 % (a
    // simplex that has collapsed in one direction stalls; a fresh one does not).
    let (g, c) = restarted_nm(
        ctx,
        |g: &DpPidGains| pid_log10_gains(g, ki_on),
        |x: &[f64]| pid_from_log10(x, ki_on, &g),
        |g: &DpPidGains| ctx.cost(ControlLaw::DirectPid(*g)),
        g,
        c,
        &mut nm.points,
        name,
    );
    // Polish: pattern search with the moves the local-optimum test checks, accepting any
    // improvement, until no move improves.
    let (g, c, polish_runs) = polish(
        g,
        c,
        |g: &DpPidGains| pid_polish_moves(g, ki_on),
        |moves: &[DpPidGains]| ctx.costs(moves, threads),
    );
    // Re-measure the stored point (f32 rounding of the gains).
    let (c_check, c_nominal, c_margin) = ctx.cost_cfg(config_for(ControlLaw::DirectPid(g), 1000.0));
    ctx.say(format!(
        "{name}: Nelder-Mead {} points in {:.0} s + polish: cost {:.3e} rad^2 (re-measured {:.3e}) at kp {:.4e} kd {:.4e} ki {:.4e} w {}",
        nm.points,
        t1.elapsed().as_secs_f64(),
        c,
        c_check,
        g.kp_pa_per_rad,
        g.kd_pa_s_per_rad,
        g.ki_pa_per_rad_s,
        g.setpoint_rate_weight
    ));
    let note = format!(
        "{name}: grid {} points (best cost {:.4e} rad^2), Nelder-Mead {} points from the best grid\n\
         \x20 point{} (costs after it: {}),\n\
         \x20 polish {} points -> cost {:.4e} rad^2 (suite MSE {:.4e} rad^2, at the gain margin {:.4e} rad^2, w = {})",
        grid.len(),
        cbest,
        nm.points,
        if from_stored {
            " and the stored gains"
        } else {
            ""
        },
        nm.from.join(", "),
        polish_runs,
        c_check,
        c_nominal,
        c_margin,
        g.setpoint_rate_weight
    );
    (g, (c_nominal, c_margin), note)
}

/// The coarse grid of the PD / PID search: each set-point rate weight (0, 1) by
/// [`KP_GRID`] by [`KD_GRID`] (by [`KI_GRID`] with `ki_on`, else ki 0).
fn pid_grid(ki_on: bool, cutoff_hz: f32) -> Vec<DpPidGains> {
    let mut grid = Vec::new();
    for w in [0.0f32, 1.0] {
        for kp in KP_GRID {
            for kd in KD_GRID {
                if ki_on {
                    for ki in KI_GRID {
                        grid.push(gains(true, cutoff_hz, w, kp, kd, ki));
                    }
                } else {
                    grid.push(gains(false, cutoff_hz, w, kp, kd, 0.0));
                }
            }
        }
    }
    grid
}

/// The grid's lowest-cost point and its cost (said in the log).
fn best_of_grid(ctx: &Ctx, name: &str, grid: &[DpPidGains], threads: usize) -> (DpPidGains, f64) {
    let t0 = Instant::now();
    let costs = ctx.costs(grid, threads);
    let (ibest, &cbest) = costs
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))
        .expect("non-empty grid");
    let g0 = grid[ibest];
    ctx.say(format!(
        "{name}: grid of {} points in {:.0} s, best cost {:.3e} rad^2 at kp {:.3e} kd {:.3e} ki {:.3e} w {}",
        grid.len(),
        t0.elapsed().as_secs_f64(),
        cbest,
        g0.kp_pa_per_rad,
        g0.kd_pa_s_per_rad,
        g0.ki_pa_per_rad_s,
        g0.setpoint_rate_weight
    ));
    (g0, cbest)
}

/// The starts of Nelder-Mead: the best grid point and, when there is one with a finite cost,
/// the stored gains (the previous tuning: a search from the grid alone once found a PID 1.8x
/// worse than them).
fn pid_starts(
    ctx: &Ctx,
    name: &str,
    grid_best: (DpPidGains, f64),
    stored: Option<DpPidGains>,
) -> Vec<(&'static str, DpPidGains, f64)> {
    let mut starts = vec![("grid", grid_best.0, grid_best.1)];
    if let Some(gs) = stored {
        let cs = ctx.cost(ControlLaw::DirectPid(gs));
        ctx.say(format!(
            "{name}: stored gains kp {:.3e} kd {:.3e} ki {:.3e} w {}: cost {:.3e} rad^2",
            gs.kp_pa_per_rad, gs.kd_pa_s_per_rad, gs.ki_pa_per_rad_s, gs.setpoint_rate_weight, cs
        ));
        if cs.is_finite() {
            starts.push(("stored gains", gs, cs));
        }
    }
    starts
}

/// The Nelder-Mead searches from each start: the best result, the points evaluated, and
/// each start's cost after its search ("label cost").
struct NmFromStarts {
    best: (DpPidGains, f64),
    points: usize,
    from: Vec<String>,
}

/// Nelder-Mead on log10 gains from each start (costs relative to the start's); a search
/// that does not improve on its start keeps the start.
fn nm_from_starts(
    ctx: &Ctx,
    name: &str,
    ki_on: bool,
    starts: Vec<(&'static str, DpPidGains, f64)>,
) -> NmFromStarts {
    let mut best: Option<(DpPidGains, f64)> = None;
    let mut points = 0;
    let mut from = Vec::new();
    for (label, gs, cs) in starts {
        let x0 = pid_log10_gains(&gs, ki_on);
        let step = vec![0.2; x0.len()];
        let r = nelder_mead(
            |x| ctx.cost(ControlLaw::DirectPid(pid_from_log10(x, ki_on, &gs))) / cs,
            &x0,
            &step,
            2e-3,
            120,
        );
        points += r.evaluations;
        let (g, c) = if r.cost < 1.0 {
            (pid_from_log10(&r.x, ki_on, &gs), r.cost * cs)
        } else {
            (gs, cs)
        };
        ctx.say(format!(
            "{name}: Nelder-Mead from the {label} ({} points): cost {:.4e} rad^2",
            r.evaluations, c
        ));
        from.push(format!("{label} {c:.4e}"));
        if best.is_none_or(|(_, cb)| c < cb) {
            best = Some((g, c));
        }
    }
    NmFromStarts {
        best: best.expect("at least the grid start"),
        points,
        from,
    }
}

/// The search coordinates of PD / PID gains: log10 of kp, kd (and ki with `ki_on`).
fn pid_log10_gains(g: &DpPidGains, ki_on: bool) -> Vec<f64> {
    let mut x = vec![
        (g.kp_pa_per_rad as f64).log10(),
        (g.kd_pa_s_per_rad as f64).log10(),
    ];
    if ki_on {
        x.push((g.ki_pa_per_rad_s as f64).log10());
    }
    x
}

/// The gains at search coordinates `x` ([`pid_log10_gains`]), the rest (set-point weight,
/// cut-off, ...) from `base`; ki 0 without `ki_on`.
fn pid_from_log10(x: &[f64], ki_on: bool, base: &DpPidGains) -> DpPidGains {
    DpPidGains {
        kp_pa_per_rad: 10f64.powf(x[0]) as f32,
        kd_pa_s_per_rad: 10f64.powf(x[1]) as f32,
        ki_pa_per_rad_s: if ki_on { 10f64.powf(x[2]) as f32 } else { 0.0 },
        setpoint_rate_weight: base.setpoint_rate_weight,
        ..*base
    }
}

/// The PD / PID polish moves (the local-optimum test's): each gain x0.7, then each x1.4
/// (kp, kd, and ki with `ki_on`), then the derivative's set-point weight flipped.
fn pid_polish_moves(g: &DpPidGains, ki_on: bool) -> Vec<DpPidGains> {
    let mut moves = Vec::new();
    for f in [0.7f32, 1.4] {
        moves.push(DpPidGains {
            kp_pa_per_rad: g.kp_pa_per_rad * f,
            ..*g
        });
        moves.push(DpPidGains {
            kd_pa_s_per_rad: g.kd_pa_s_per_rad * f,
            ..*g
        });
        if ki_on {
            moves.push(DpPidGains {
                ki_pa_per_rad_s: g.ki_pa_per_rad_s * f,
                ..*g
            });
        }
    }
    moves.push(DpPidGains {
        setpoint_rate_weight: 1.0 - g.setpoint_rate_weight,
        ..*g
    });
    moves
}

/// The cascade's position-loop gains and torque-loop integral gain, with the feed-forward of
/// `start` (`w = 1`, its cut-off and inertia): Nelder-Mead on (log10 kp, ki, kd, torque ki)
/// from `start`, restarted, then the x0.7 / x1.4 polish. Prints the result; returns (config,
/// tuning cost).
fn tune_cascade(ctx: &Ctx, start: ControllerConfig) -> (ControllerConfig, f64) {
    let cost_cfg = |cfg: ControllerConfig| ctx.cascade_cost(cfg).0;
    let c_start = cost_cfg(start);
    ctx.say(format!(
        "cascade: start kp {} ki {} kd {} torque ki {} feed-forward (rate weight {}, J {} kg m^2, \
         cutoff {} Hz, limit {} N m): cost {:.4e} rad^2",
        start.position.kp_nm_per_rad,
        start.position.ki_nm_per_rad_s,
        start.position.kd_nm_s_per_rad,
        start.torque.ki_per_s,
        start.feedforward.rate_weight,
        start.feedforward.inertia_kgm2,
        start.feedforward.cutoff_hz,
        start.feedforward.limit_nm,
        c_start
    ));
    let with = |x: &[f64]| {
        let mut cfg = start;
        cfg.position.kp_nm_per_rad = 10f64.powf(x[0]) as f32;
        cfg.position.ki_nm_per_rad_s = 10f64.powf(x[1]) as f32;
        cfg.position.kd_nm_s_per_rad = 10f64.powf(x[2]) as f32;
        cfg.torque.ki_per_s = 10f64.powf(x[3]) as f32;
        cfg
    };
    let x0 = [
        (start.position.kp_nm_per_rad as f64).log10(),
        (start.position.ki_nm_per_rad_s as f64).log10(),
        (start.position.kd_nm_s_per_rad as f64).log10(),
        (start.torque.ki_per_s as f64).log10(),
    ];
    // Costs relative to the start's (absolute when the start fails or overshoots).
    let scale = if c_start.is_finite() { c_start } else { 1.0 };
    let r = nelder_mead(|x| cost_cfg(with(x)) / scale, &x0, &[0.2; 4], 2e-3, 160);
    let (cfg, c) = if r.cost * scale < c_start {
        (with(&r.x), r.cost * scale)
    } else {
        (start, c_start)
    };
    let mut evaluations = r.evaluations;
    let (cfg, c) = if c.is_finite() {
        restarted_nm(
            ctx,
            |cfg: &ControllerConfig| {
                vec![
                    (cfg.position.kp_nm_per_rad as f64).log10(),
                    (cfg.position.ki_nm_per_rad_s as f64).log10(),
                    (cfg.position.kd_nm_s_per_rad as f64).log10(),
                    (cfg.torque.ki_per_s as f64).log10(),
                ]
            },
            |x: &[f64]| with(x),
            |cfg: &ControllerConfig| cost_cfg(*cfg),
            cfg,
            c,
            &mut evaluations,
            "cascade",
        )
    } else {
        (cfg, c)
    };
    let (cfg, c, _) = polish(
        cfg,
        c,
        |cfg: &ControllerConfig| {
            cascade_polish_moves(cfg)
                .into_iter()
                .map(|(_, _, m)| m)
                .collect()
        },
        |moves: &[ControllerConfig]| moves.iter().map(|m| cost_cfg(*m)).collect(),
    );
    let (_, nominal, margin) = ctx.cascade_cost(cfg);
    ctx.say(format!(
        "cascade: Nelder-Mead {} points + polish: cost {:.4e} rad^2 ({:.3} x start; suite MSE {:.4e}, at the margin {:.4e}) at kp {} ki {} kd {} torque ki {} (J {}, cutoff {} Hz)",
        evaluations, c, c / c_start, nominal, margin, cfg.position.kp_nm_per_rad, cfg.position.ki_nm_per_rad_s, cfg.position.kd_nm_s_per_rad,
        cfg.torque.ki_per_s, cfg.feedforward.inertia_kgm2, cfg.feedforward.cutoff_hz
    ));
    (cfg, c)
}

/// The cascade's polish moves (and the local-optimum tests' perturbations): each gain x 0.7,
/// then each x 1.4 (kp, ki, kd, torque ki), with the gain's name and the factor.
pub fn cascade_polish_moves(cfg: &ControllerConfig) -> Vec<(&'static str, f32, ControllerConfig)> {
    type Gain = fn(&mut ControllerConfig) -> &mut f32;
    let gains: [(&str, Gain); 4] = [
        ("kp", |c| &mut c.position.kp_nm_per_rad),
        ("ki", |c| &mut c.position.ki_nm_per_rad_s),
        ("kd", |c| &mut c.position.kd_nm_s_per_rad),
        ("torque ki", |c| &mut c.torque.ki_per_s),
    ];
    let mut moves = Vec::new();
    for f in [0.7f32, 1.4] {
        for (name, g) in gains {
            let mut m = *cfg;
            *g(&mut m) *= f;
            moves.push((name, f, m));
        }
    }
    moves
}

/// Runs `host-sim tune`; returns the report for stdout.
pub fn run_tune(a: &TuneArgs) -> Result<String> {
    run_tune_text(a).map(|(report, _)| report)
}

/// [`run_tune`], also returning the text of the gains file it wrote. Steps: the arguments
/// checked, the tuning context (plant, suites, robust plants), the stored gains, the
/// cascade from each start, the PD and the PID, the firmware's step tests, the gains file
/// with its header.
pub fn run_tune_text(a: &TuneArgs) -> Result<(String, String)> {
    let cascade_starts = check_tune_args(a)?;
    let ctx = tuning_context(a)?;
    // --out is replaced at the end: an existing file there must be a gains file (a plant
    // file or another config picked by a completion slip would be lost after the run).
    crate::validate::replaceable("--out", &a.out, crate::validate::OutputKind::GAINS)
        .map_err(anyhow::Error::msg)?;
    // With --warm-start, the gains stored in the output file are one more start of every search.
    let stored = if a.warm_start {
        match ControlTuning::load(&a.out) {
            Ok(t) => Some(t),
            Err(e) => {
                ctx.say(format!("no stored gains to start from ({e})"));
                None
            }
        }
    } else {
        None
    };
    let t0 = Instant::now();
    let reference = reference_config(a, &ctx);
    let starts = cascade_start_points(&reference, stored.as_ref(), cascade_starts);
    ctx.progress.set_length(2 * starts.len() as u64 + 2);
    let (cascade, c_best, cascade_from) = best_cascade(&ctx, &reference, starts);
    if !c_best.is_finite() {
        ctx.progress.finish_and_clear();
        bail!(
            "{}: no cascade gains found that meet the firmware's step tests and keep the suite \
             stable; nothing written",
            a.plant.display()
        );
    }
    let (_, c_cascade, c_cascade_margin) = ctx.cost_cfg(cascade);
    let cutoff_hz = a.setpoint_cutoff_hz;
    let with_cutoff = |g: DpPidGains| DpPidGains {
        setpoint_rate_cutoff_hz: cutoff_hz,
        ..g
    };
    let threads = a.threads;
    // The PD (no integral) then the PID, each from the stored law of its kind with --warm-start.
    let [(pd, c_pd, note_pd), (pid, c_pid, note_pid)] = [false, true].map(|ki_on| {
        let start = stored
            .as_ref()
            .map(|t| with_cutoff(if ki_on { t.pid.gains() } else { t.pd.gains() }));
        let tuned = tune(&ctx, ki_on, threads, start);
        ctx.progress.inc(1);
        tuned
    });
    let (_, c_default, c_default_margin) = ctx.cost_cfg(reference);
    let step_tests = step_test_lines(
        &ctx,
        [
            ("cascade", cascade),
            ("PD", config_for(ControlLaw::DirectPid(pd), 1000.0)),
            ("PID", config_for(ControlLaw::DirectPid(pid), 1000.0)),
        ],
    );
    let tuning = ControlTuning {
        cascade: CascadeToml::from_config(&cascade, c_cascade, c_cascade_margin),
        pd: DpPidToml::from_gains(&pd, c_pd.0, c_pd.1),
        pid: DpPidToml::from_gains(&pid, c_pid.0, c_pid.1),
    };
    let header = gains_header(
        a,
        &HeaderNotes {
            step_constraints: ctx.cascade_step_constraints,
            cascade_from,
            from_stored: stored.is_some(),
            note_pd,
            note_pid,
            step_tests: step_tests.clone(),
            c_default,
            c_default_margin,
        },
    );
    ctx.progress.finish_and_clear();
    tuning.write(&a.out, &header)?;
    let text = tuning.to_toml_string(&header);
    let log = ctx.log.lock().expect("log lock").join("\n");
    let report = format!(
        "{log}\n{}\nwrote {} ({} suite runs, {:.0} s)\n",
        step_tests.join("\n"),
        a.out.display(),
        ctx.runs.load(Ordering::Relaxed),
        t0.elapsed().as_secs_f64()
    );
    Ok((report, text))
}

/// A cascade start point: kp, ki, kd and, when given, the torque loop's ki.
type CascadeStart = (f32, f32, f32, Option<f32>);

/// Checks the ranges of `--threads`, `--setpoint-cutoff-hz` and `--transition-s` and that
/// `--out` is not `--plant`; returns the `--cascade-start` points.
fn check_tune_args(a: &TuneArgs) -> Result<Vec<CascadeStart>> {
    if !(1..=256).contains(&a.threads) {
        bail!("--threads {}: allowed 1..=256", a.threads);
    }
    if !(a.setpoint_cutoff_hz >= 1.0 && a.setpoint_cutoff_hz <= 500.0) {
        bail!(
            "--setpoint-cutoff-hz {}: allowed 1..=500 Hz",
            a.setpoint_cutoff_hz
        );
    }
    if let Some(t) = a.transition_s {
        if !(0.0..=2.0).contains(&t) {
            bail!("--transition-s {t}: allowed 0..=2 s");
        }
    }
    crate::validate::distinct_file_outputs(&[("--plant", &a.plant)], &[("--out", &a.out)])
        .map_err(anyhow::Error::msg)?;
    a.cascade_start
        .iter()
        .map(|s| parse_cascade_start(s))
        .collect()
}

/// One `--cascade-start KP,KI,KD[,TORQUE_KI]`: 3 or 4 finite numbers, each > 0 and at most
/// what a gains file loads ([`CascadeToml::GAIN_MAX`]).
fn parse_cascade_start(s: &str) -> Result<CascadeStart> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("--cascade-start {s}: KP,KI,KD[,TORQUE_KI], numbers"))?;
    if !(3..=4).contains(&v.len()) || v.iter().any(|x| !(*x > 0.0 && x.is_finite())) {
        bail!("--cascade-start {s}: KP,KI,KD[,TORQUE_KI], each > 0");
    }
    for (x, (key, max)) in v.iter().zip(CascadeToml::GAIN_MAX) {
        if f64::from(*x) > max {
            bail!(
                "--cascade-start {s}: {key} {x} is above {max:e}, the largest a gains file \
                 loads"
            );
        }
    }
    Ok((v[0], v[1], v[2], v.get(3).copied()))
}

/// The tuning's context: the plant, the suite (with `--transition-s`), the progress bar, the
/// `--robust` condition plants and the stability suite; the log opened with what the run
/// tunes on.
fn tuning_context(a: &TuneArgs) -> Result<Ctx> {
    let plant = Plant::load(&a.plant)?;
    let mut scenarios = suite_scenarios()?;
    if let Some(t) = a.transition_s {
        for s in &mut scenarios {
            s.set_transition_s(t);
        }
    }
    // A bar over the searches (each cascade start twice, the PD, the PID), the closed-loop
    // runs so far beside it; the total is set once the cascade's starts are known.
    let progress = ProgressBar::new(0);
    progress.set_style(
        ProgressStyle::with_template(
            "{spinner} tune [{bar:30}] {pos}/{len} searches, {prefix} {elapsed}  {wide_msg}",
        )
        .expect("static template")
        .progress_chars("=> "),
    );
    progress.enable_steady_tick(std::time::Duration::from_millis(200));
    let (robust_cost, mut robust_stable) = robust_plants(a)?;
    if a.stable_on_jumps {
        robust_stable.push((Plant::load(&a.plant)?, "nominal"));
    }
    let stability_scenarios = if a.robust || a.stable_on_jumps {
        let mut all = scenarios.clone();
        all.extend(jump_suite_scenarios()?);
        all
    } else {
        Vec::new()
    };
    let ctx = Ctx {
        plant,
        scenarios,
        stability_scenarios,
        runs: AtomicUsize::new(0),
        cutoff_hz: a.setpoint_cutoff_hz,
        progress,
        log: Mutex::new(Vec::new()),
        cascade_step_constraints: !a.no_step_constraints,
        robust_cost,
        robust_stable,
    };
    ctx.say(format!(
        "tuning on {} (plant effects: {})",
        a.plant.display(),
        ctx.plant.effects_summary()
    ));
    if let Some(t) = a.transition_s {
        ctx.say(format!("suite with every set-point move lasting {t} s"));
    }
    if a.robust {
        ctx.say(ROBUST_NOTE.replace('\n', " "));
    }
    if a.stable_on_jumps {
        ctx.say(
            "--stable-on-jumps: infinite cost unless the suite and the jump suite stay stable \
             on the plant (no fault, |error| < 0.5 rad, at rest within 0.01 rad)"
                .into(),
        );
    }
    Ok(ctx)
}

/// A plant of the tuning with the name of its condition.
type ConditionPlant = (Plant, &'static str);

/// With `--robust`: the plants of [`ROBUST_COST_CONDITIONS`] and of
/// [`ROBUST_STABLE_CONDITIONS`] (the nominal one left out), from the plant file.
fn robust_plants(a: &TuneArgs) -> Result<(Vec<ConditionPlant>, Vec<ConditionPlant>)> {
    let (mut robust_cost, mut robust_stable) = (Vec::new(), Vec::new());
    if a.robust {
        let text = std::fs::read_to_string(&a.plant)
            .with_context(|| format!("reading {}", a.plant.display()))?;
        let file = a.plant.display().to_string();
        for (which, out) in [
            (&ROBUST_COST_CONDITIONS[..], &mut robust_cost),
            (&ROBUST_STABLE_CONDITIONS[..], &mut robust_stable),
        ] {
            for &i in which.iter().filter(|&&i| i != 0) {
                let (name, effects, inertia) = CONDITIONS[i];
                out.push((
                    try_condition_plant(&text, effects, inertia, &file)
                        .with_context(|| format!("--robust: {file} with {name}"))?,
                    name,
                ));
            }
        }
    }
    Ok((robust_cost, robust_stable))
}

/// The cascade's reference configuration: the firmware's, with `--outer-period-ticks`, and
/// with `--pressure-ff` the pressure feed-forward on (evaluated every `--ff-update-ticks`).
fn reference_config(a: &TuneArgs, ctx: &Ctx) -> ControllerConfig {
    let mut reference = ControllerConfig::reference(1000.0);
    if let Some(n) = a.outer_period_ticks {
        reference.outer_period_ticks = n;
        ctx.say(format!(
            "cascade tuned with its outer loops every {n} tick(s)"
        ));
    }
    if a.pressure_ff {
        reference.pressure_ff.enabled = true;
        reference.volume_fnn = None;
        ctx.say("cascade tuned with the pressure feed-forward on (config/pressure_ff.toml)".into());
        if let Some(n) = a.ff_update_ticks {
            reference.pressure_ff.update_period_ticks = n;
            ctx.say(format!("feed-forward evaluated every {n} tick(s)"));
        }
    }
    reference
}

/// The cascade's start points (kp, ki, kd[, torque ki]): the gains tuned before the
/// feed-forward existed, the firmware's default gains, the stored tuning, then any given
/// with --cascade-start.
fn cascade_start_points(
    reference: &ControllerConfig,
    stored: Option<&ControlTuning>,
    given: Vec<CascadeStart>,
) -> Vec<CascadeStart> {
    let mut starts = vec![
        (11.0, 8.0, 0.8, None),
        (
            reference.position.kp_nm_per_rad,
            reference.position.ki_nm_per_rad_s,
            reference.position.kd_nm_s_per_rad,
            Some(reference.torque.ki_per_s),
        ),
    ];
    if let Some(t) = stored {
        let c = t.cascade.config(1000.0);
        starts.push((
            c.position.kp_nm_per_rad,
            c.position.ki_nm_per_rad_s,
            c.position.kd_nm_s_per_rad,
            Some(c.torque.ki_per_s),
        ));
    }
    starts.extend(given);
    starts
}

/// The cascade tuned ([`tune_cascade`]) from each start with the inertia feed-forward off
/// and on (J of the plant): the best configuration, its cost and one line per start.
fn best_cascade(
    ctx: &Ctx,
    reference: &ControllerConfig,
    starts: Vec<CascadeStart>,
) -> (ControllerConfig, f64, Vec<String>) {
    let j_plant = ctx.plant.joint.inertia_kgm2 as f32;
    let mut best_cascade: Option<(ControllerConfig, f64)> = None;
    let mut cascade_from = Vec::new();
    for (kp, ki, kd, torque_ki) in starts {
        for j_kgm2 in [0.0f32, j_plant] {
            let mut start = *reference;
            start.position.kp_nm_per_rad = kp;
            start.position.ki_nm_per_rad_s = ki;
            start.position.kd_nm_s_per_rad = kd;
            start.torque.ki_per_s = torque_ki.unwrap_or(reference.torque.ki_per_s);
            start.feedforward.inertia_kgm2 = j_kgm2;
            start.feedforward.cutoff_hz = ctx.cutoff_hz;
            let (cfg, c) = tune_cascade(ctx, start);
            ctx.progress.inc(1);
            cascade_from.push(format!(
                "({kp:.4}, {ki:.4}, {kd:.4}, {:.4}, J {j_kgm2}) -> {c:.4e}",
                start.torque.ki_per_s
            ));
            if best_cascade.is_none_or(|(_, cb)| c < cb) {
                best_cascade = Some((cfg, c));
            }
        }
    }
    let (cascade, c_best) = best_cascade.expect("at least one start");
    (cascade, c_best, cascade_from)
}

/// One line per law: the firmware's step tests ([`STEP_REQUIREMENTS`]) passed or failed.
fn step_test_lines(ctx: &Ctx, laws: [(&str, ControllerConfig); 3]) -> Vec<String> {
    let mut step_tests = Vec::new();
    for (name, cfg) in laws {
        let passed: Vec<String> = STEP_REQUIREMENTS
            .iter()
            .map(|r| {
                let ok = meets_step_requirement(&ctx.plant, cfg, r).unwrap_or(false);
                format!(
                    "{} x inertia {}",
                    r.inertia_factor,
                    if ok { "pass" } else { "FAIL" }
                )
            })
            .collect();
        step_tests.push(format!("{name}: {}", passed.join(", ")));
    }
    step_tests
}

/// What the gains file's header reports of the run besides its arguments.
struct HeaderNotes {
    /// The cascade had to meet the firmware's step tests.
    step_constraints: bool,
    /// One line per cascade start.
    cascade_from: Vec<String>,
    /// The searches also started from the stored gains.
    from_stored: bool,
    note_pd: String,
    note_pid: String,
    step_tests: Vec<String>,
    /// The cascade's cost with the firmware's default gains, and at the gain margin.
    c_default: f64,
    c_default_margin: f64,
}

/// The gains file's header: what each law is, how it was tuned, the command that wrote the
/// file (every option that changes the result), the step tests and the default gains' cost.
fn gains_header(a: &TuneArgs, notes: &HeaderNotes) -> String {
    let cutoff_hz = a.setpoint_cutoff_hz;
    let (note_pd, note_pid) = (&notes.note_pd, &notes.note_pid);
    format!(
        "The three laws of the closed-loop comparison, each tuned on the suite\n\
         (host-sim control::compare::SUITE) by the same procedure and cost. Written by\n\
         \x20 host-sim tune --plant {} --out {}{}{}{}{}{}{}{}{}\n\
         with the firmware in the loop. Suite MSE = mean over the step_move, sine and\n\
         random_move scenarios of the MSE of the angle over every tick (a latched fault = infinite);\n\
         cost = the worse of the suite MSE at the gains and with the feedback gains x {}\n\
         (gain margin, 6 dB), infinite if the step overshoots by more than 10 %.{}\n\
         Set-point differentiators of every law: {cutoff_hz} Hz.\n\
         [cascade]: the model-based cascade (ControllerConfig::reference with these gains);\n\
         \x20 Nelder-Mead (restarted) on log10 (kp, ki, kd, torque ki) + x0.7 / x1.4 polish from\n\
         \x20 each start (kp, ki, kd, torque ki, feed-forward J) -> cost [rad^2]{}:\n\
         \x20 {}\n\
         [pd] / [pid]: the model-free baselines (pam_firmware::pid::DpPid: angle -> dp,\n\
         \x20 p1 = p0 - dp, p2 = p0 + dp); coarse grid, Nelder-Mead on log10 gains from the best grid\n\
         \x20 point{}, restarted, x0.7 / x1.4 polish.\n\
         {note_pd}\n\
         {note_pid}\n\
         Firmware step tests (settle and overshoot, nominal and 11 x inertia){}:\n\
         \x20 {}\n\
         For comparison, the cascade with the firmware's default gains (ControllerConfig::reference,\n\
         tuned for the jump suite and the firmware's step tests) scored {:.4e} rad^2\n\
         ({:.4e} rad^2 at the gain margin).\n\
         Units: SI (Pa, N m, rad, s); suite_mse_rad2 and suite_mse_at_margin_rad2 are what the\n\
         tuner measured (host-sim/tests/control_compare.rs re-measures them).",
        a.plant.display(),
        a.out.display(),
        if a.warm_start { " --warm-start" } else { "" },
        if a.robust { " --robust" } else { "" },
        if a.no_step_constraints { " --no-step-constraints" } else { "" },
        if a.pressure_ff { " --pressure-ff" } else { "" },
        a.outer_period_ticks
            .map(|n| format!(" --outer-period-ticks {n}"))
            .unwrap_or_default(),
        a.ff_update_ticks
            .map(|n| format!(" --ff-update-ticks {n}"))
            .unwrap_or_default(),
        if a.stable_on_jumps {
            " --stable-on-jumps"
        } else {
            ""
        },
        a.cascade_start
            .iter()
            .map(|s| format!(" --cascade-start {s}"))
            .collect::<String>(),
        GAIN_MARGIN,
        [
            (a.robust, ROBUST_NOTE),
            (a.stable_on_jumps, STABLE_ON_JUMPS_NOTE),
            (a.pressure_ff, PRESSURE_FF_NOTE),
        ]
        .iter()
        .filter(|(on, _)| *on)
        .map(|(_, note)| format!("\n{note}"))
        .collect::<String>(),
        if notes.step_constraints {
            ", the firmware's step tests imposed"
        } else {
            ""
        },
        notes.cascade_from.join("\n  "),
        if notes.from_stored {
            " and from the stored gains"
        } else {
            ""
        },
        if notes.step_constraints {
            ""
        } else {
            ", reported, not imposed (--no-step-constraints)"
        },
        notes.step_tests.join("\n  "),
        notes.c_default,
        notes.c_default_margin
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cascade_start_takes_three_or_four_positive_gains_within_a_gains_files_range() {
        assert_eq!(
            parse_cascade_start("11, 8,0.8").unwrap(),
            (11.0, 8.0, 0.8, None)
        );
        assert_eq!(
            parse_cascade_start("11,8,0.8,40").unwrap(),
            (11.0, 8.0, 0.8, Some(40.0))
        );
        for bad in [
            "11,8",
            "11,8,0.8,40,1",
            "11,-8,0.8",
            "11,eight,0.8",
            "11,8,inf",
        ] {
            assert!(parse_cascade_start(bad).is_err(), "{bad}");
        }
        let (key, max) = CascadeToml::GAIN_MAX[0];
        let err = parse_cascade_start(&format!("{},1,1", 2.0 * max)).unwrap_err();
        assert!(err.to_string().contains(key), "{err}");
    }

    #[test]
    fn the_pid_polish_moves_each_gain_both_ways_and_flips_the_rate_weight() {
        let g = gains(true, 20.0, 0.0, 1e5, 1e3, 1e4);
        let moves = pid_polish_moves(&g, true);
        assert_eq!(moves.len(), 7);
        assert_eq!(moves[0].kp_pa_per_rad, g.kp_pa_per_rad * 0.7);
        assert_eq!(moves[5].ki_pa_per_rad_s, g.ki_pa_per_rad_s * 1.4);
        assert_eq!(moves[6].setpoint_rate_weight, 1.0);
        // Without an integral the ki moves are left out.
        assert_eq!(pid_polish_moves(&g, false).len(), 5);
    }

    #[test]
    fn pid_search_coordinates_are_log10_gains_and_ki_is_zero_without_an_integral() {
        let g = gains(true, 20.0, 1.0, 1e5, 1e3, 1e4);
        let x = pid_log10_gains(&g, true);
        assert_eq!(x.len(), 3);
        assert!((x[0] - 5.0).abs() < 1e-6 && (x[2] - 4.0).abs() < 1e-6);
        let back = pid_from_log10(&x, true, &g);
        assert!((back.kd_pa_s_per_rad / g.kd_pa_s_per_rad - 1.0).abs() < 1e-6);
        assert_eq!(back.setpoint_rate_weight, 1.0);
        assert_eq!(pid_from_log10(&x[..2], false, &g).ki_pa_per_rad_s, 0.0);
    }
}
