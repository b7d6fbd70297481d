//! Tuning procedure of the closed-loop comparison (cascade vs PD / PID): finds, by the same cost
//! and the same kind of search, the model-based cascade's gains and the model-free PD and PID
//! (angle -> activation dp, `pam_firmware::pid`) that minimise the suite MSE on the reference
//! plant with the firmware in the loop, and writes all three to `config/control_tuned.toml`.
//!
//! ```sh
//! cargo run --release -p host-sim --example tune_pid [-- --plant P.toml --out config/control_tuned.toml
//!     --threads 2 --setpoint-cutoff-hz 150 --transition-s T --cascade-start KP,KI,KD[,TORQUE_KI]]
//! ```
//!
//! Procedure (deterministic: the scenarios carry their noise seeds; ~35 s on 2 cores). Suite =
//! `control::compare::SUITE` (`--transition-s T` changes the duration of its set-point moves,
//! for `scripts/suite-transition-sweep.sh`). Suite MSE = the mean over its step, sine and
//! random scenarios of the MSE of the angle over every tick (a latched fault = infinite).
//! Cost ([`tuning_cost`]) = the worse of the suite MSE at the gains and with the feedback gains
//! x [`GAIN_MARGIN`] (2 = 6 dB), infinite if the step overshoots by more than 10 %.
//! 1. Fixed for every law: the set-point differentiators' cut-off (150 Hz); for the PD / PID
//!    the cascade's actuation limits: p0 = 300 kPa, |dp| <= 280 kPa (the torque model's
//!    `dp_max_pa`), PID integrator limit 150 kPa (half the usable dp range).
//! 2. Cascade: from each start (kp, ki, kd, torque-loop ki) = (11, 8, 0.8, 30) (the gains
//!    before the feed-forward existed), the firmware's default gains, the stored [cascade]
//!    gains and any `--cascade-start`, each with the feed-forward's inertia term off and on
//!    (J of the plant): Nelder-Mead on log10 of the four gains, restarted from its result
//!    while a restart gains > 1 %, then the polish of step 5. The best result is stored.
//! 3. PD / PID: coarse grid, every point two suite runs:
//!    kp in {3e4, 1e5, 2e5, 5e5, 1e6, 2e6, 5e6} Pa/rad, kd in {1e3, 3e3, 1e4, 3e4, 1e5}
//!    Pa s/rad, for the PID also ki in {3e4, 1e5, 1e6, 3e6, 1e7, 3e7, 1e8} Pa/(rad s), each
//!    with the derivative on the measurement (w = 0) and on the error (w = 1).
//! 4. PD / PID: Nelder-Mead ([`nelder_mead`]) on (log10 kp, log10 kd[, log10 ki]) from the
//!    best grid point (its w) and from the gains stored in the output file (their w), initial
//!    steps 0.2 decades, until the simplex costs agree within 0.2 % or 120 points; the better
//!    result is restarted as in step 2.
//! 5. Polish: pattern search, each gain x0.7 / x1.4 (PD / PID: and the derivative's set-point
//!    weight flipped), any improvement accepted, until no move improves (the local-optimum
//!    tests of `host-sim/tests/control_compare.rs` check exactly these moves).
//! 6. The results are written with their suite MSE and their suite MSE at the margin (the
//!    tests re-measure both) and a provenance header.

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use host_sim::control::closed_loop::Scenario;
use host_sim::control::compare::{
    config_for, control_tuned_path, nelder_mead, reference_plant_path, suite_scenarios,
    tuning_cost, CascadeToml, ControlTuning, DpPidToml, GAIN_MARGIN,
};
use host_sim::Plant;
use pam_firmware::pid::DpPidGains;
use pam_firmware::tick::{ControlLaw, ControllerConfig};

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
}

impl Ctx {
    /// The tuning cost of `law` (worse of nominal and gain-margin suite MSE).
    fn cost(&self, law: ControlLaw) -> f64 {
        self.cost_cfg(config_for(law, 1000.0)).0
    }

    /// (tuning cost, nominal suite MSE, suite MSE at the gain margin) of `cfg`.
    fn cost_cfg(&self, cfg: ControllerConfig) -> (f64, f64, f64) {
        self.runs.fetch_add(2, Ordering::Relaxed);
        tuning_cost(&self.plant, &self.scenarios, cfg)
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

/// Nelder-Mead (steps 0.2 in the coordinates of `to_x`) restarted from its own best point
/// while a restart lowers the cost by more than 1 %, at most 8 restarts; returns the best
/// point and cost and adds the evaluations to `evaluations`.
#[allow(clippy::too_many_arguments)]
fn restarted_nm<T: Copy>(
    to_x: impl Fn(&T) -> Vec<f64>,
    from_x: impl Fn(&[f64]) -> T,
    cost: impl Fn(&T) -> f64,
    mut p: T,
    mut c: f64,
    evaluations: &mut usize,
    name: &str,
) -> (T, f64) {
    for restart in 1..=8 {
        let x0 = to_x(&p);
        let r = nelder_mead(
            |x| cost(&from_x(x)) / c,
            &x0,
            &vec![0.2; x0.len()],
            2e-3,
            160,
        );
        *evaluations += r.evaluations;
        let c_new = r.cost * c;
        eprintln!(
            "{name}: restart {restart} ({} points): cost {:.4e} -> {:.4e} rad^2",
            r.evaluations, c, c_new
        );
        let gain = c_new < c * 0.99;
        if c_new < c {
            p = from_x(&r.x);
            c = c_new;
        }
        if !gain {
            break;
        }
    }
    (p, c)
}

/// Pattern search: evaluates `moves_of(p)` (with `costs`), moves to the best if it lowers the
/// cost, until no move does. Returns the point, its cost and the number of evaluations.
fn polish<T: Copy>(
    mut p: T,
    mut c: f64,
    moves_of: impl Fn(&T) -> Vec<T>,
    costs: impl Fn(&[T]) -> Vec<f64>,
) -> (T, f64, usize) {
    let mut evaluations = 0;
    loop {
        let moves = moves_of(&p);
        let cs = costs(&moves);
        evaluations += moves.len();
        match cs.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1)) {
            Some((i, &cm)) if cm < c => {
                p = moves[i];
                c = cm;
            }
            _ => return (p, c, evaluations),
        }
    }
}

fn tune(
    ctx: &Ctx,
    ki_on: bool,
    threads: usize,
    stored: Option<DpPidGains>,
) -> (DpPidGains, (f64, f64), String) {
    let name = if ki_on { "PID" } else { "PD" };
    let mut grid = Vec::new();
    for w in [0.0f32, 1.0] {
        for kp in KP_GRID {
            for kd in KD_GRID {
                if ki_on {
                    for ki in KI_GRID {
                        grid.push(gains(true, ctx.cutoff_hz, w, kp, kd, ki));
                    }
                } else {
                    grid.push(gains(false, ctx.cutoff_hz, w, kp, kd, 0.0));
                }
            }
        }
    }
    let t0 = Instant::now();
    let costs = ctx.costs(&grid, threads);
    let (ibest, &cbest) = costs
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))
        .expect("non-empty grid");
    let g0 = grid[ibest];
    eprintln!(
        "{name}: grid of {} points in {:.0} s, best cost {:.3e} rad^2 at kp {:.3e} kd {:.3e} ki {:.3e} w {}",
        grid.len(),
        t0.elapsed().as_secs_f64(),
        cbest,
        g0.kp_pa_per_rad,
        g0.kd_pa_s_per_rad,
        g0.ki_pa_per_rad_s,
        g0.setpoint_rate_weight
    );
    // Nelder-Mead from the best grid point and, when there is one, from the stored gains (the
    // previous tuning: a search from the grid alone once found a PID 1.8x worse than them).
    let mut starts = vec![("grid", g0, cbest)];
    if let Some(gs) = stored {
        let cs = ctx.cost(ControlLaw::DirectPid(gs));
        eprintln!(
            "{name}: stored gains kp {:.3e} kd {:.3e} ki {:.3e} w {}: cost {:.3e} rad^2",
            gs.kp_pa_per_rad, gs.kd_pa_s_per_rad, gs.ki_pa_per_rad_s, gs.setpoint_rate_weight, cs
        );
        if cs.is_finite() {
            starts.push(("stored gains", gs, cs));
        }
    }
    let t1 = Instant::now();
    let mut best: Option<(DpPidGains, f64)> = None;
    let mut nm_points = 0;
    let mut from = Vec::new();
    for (label, gs, cs) in starts {
        let w = gs.setpoint_rate_weight;
        let to_gains = |x: &[f64]| DpPidGains {
            kp_pa_per_rad: 10f64.powf(x[0]) as f32,
            kd_pa_s_per_rad: 10f64.powf(x[1]) as f32,
            ki_pa_per_rad_s: if ki_on { 10f64.powf(x[2]) as f32 } else { 0.0 },
            setpoint_rate_weight: w,
            ..gs
        };
        let mut x0 = vec![
            (gs.kp_pa_per_rad as f64).log10(),
            (gs.kd_pa_s_per_rad as f64).log10(),
        ];
        if ki_on {
            x0.push((gs.ki_pa_per_rad_s as f64).log10());
        }
        let step = vec![0.2; x0.len()];
        let r = nelder_mead(
            |x| ctx.cost(ControlLaw::DirectPid(to_gains(x))) / cs,
            &x0,
            &step,
            2e-3,
            120,
        );
        nm_points += r.evaluations;
        let (g, c) = if r.cost < 1.0 {
            (to_gains(&r.x), r.cost * cs)
        } else {
            (gs, cs)
        };
        eprintln!(
            "{name}: Nelder-Mead from the {label} ({} points): cost {:.4e} rad^2",
            r.evaluations, c
        );
        from.push(format!("{label} {c:.4e}"));
        if best.is_none_or(|(_, cb)| c < cb) {
            best = Some((g, c));
        }
    }
    let (g, c) = best.expect("at least the grid start");
    // Nelder-Mead restarted from its own result until a restart gains less than 1 % (a
    // simplex that has collapsed in one direction stalls; a fresh one does not).
    let w = g.setpoint_rate_weight;
    let (g, c) = restarted_nm(
        |g: &DpPidGains| {
            let mut x = vec![
                (g.kp_pa_per_rad as f64).log10(),
                (g.kd_pa_s_per_rad as f64).log10(),
            ];
            if ki_on {
                x.push((g.ki_pa_per_rad_s as f64).log10());
            }
            x
        },
        |x: &[f64]| DpPidGains {
            kp_pa_per_rad: 10f64.powf(x[0]) as f32,
            kd_pa_s_per_rad: 10f64.powf(x[1]) as f32,
            ki_pa_per_rad_s: if ki_on { 10f64.powf(x[2]) as f32 } else { 0.0 },
            setpoint_rate_weight: w,
            ..g
        },
        |g: &DpPidGains| ctx.cost(ControlLaw::DirectPid(*g)),
        g,
        c,
        &mut nm_points,
        name,
    );
    // Polish: pattern search with the moves the local-optimum test checks (each gain x0.7 /
    // x1.4, the derivative's set-point weight flipped), accepting any improvement, until no
    // move improves.
    let (g, c, polish_runs) = polish(
        g,
        c,
        |g: &DpPidGains| {
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
        },
        |moves: &[DpPidGains]| ctx.costs(moves, threads),
    );
    // Re-measure the stored point (f32 rounding of the gains).
    let (c_check, c_nominal, c_margin) = ctx.cost_cfg(config_for(ControlLaw::DirectPid(g), 1000.0));
    eprintln!(
        "{name}: Nelder-Mead {} points in {:.0} s + polish: cost {:.3e} rad^2 (re-measured {:.3e}) at kp {:.4e} kd {:.4e} ki {:.4e} w {}",
        nm_points,
        t1.elapsed().as_secs_f64(),
        c,
        c_check,
        g.kp_pa_per_rad,
        g.kd_pa_s_per_rad,
        g.ki_pa_per_rad_s,
        g.setpoint_rate_weight
    );
    let note = format!(
        "{name}: grid {} points (best cost {:.4e} rad^2), Nelder-Mead {} points from the best grid\n\
         \x20 point and the stored gains (costs after it: {}),\n\
         \x20 polish {} points -> cost {:.4e} rad^2 (suite MSE {:.4e} rad^2, at the gain margin {:.4e} rad^2, w = {})",
        grid.len(),
        cbest,
        nm_points,
        from.join(", "),
        polish_runs,
        c_check,
        c_nominal,
        c_margin,
        g.setpoint_rate_weight
    );
    (g, (c_nominal, c_margin), note)
}

/// The cascade's position-loop gains and torque-loop integral gain, with the feed-forward of
/// `start` (`w = 1`, its cut-off and inertia): Nelder-Mead on (log10 kp, ki, kd, torque ki)
/// from `start`, restarted, then the x0.7 / x1.4 polish. Prints the result; returns (config,
/// tuning cost).
fn tune_cascade(ctx: &Ctx, start: ControllerConfig) -> (ControllerConfig, f64) {
    let cost_cfg = |cfg: ControllerConfig| ctx.cost_cfg(cfg).0;
    let c_start = cost_cfg(start);
    eprintln!(
        "cascade: start kp {} ki {} kd {} torque ki {} feed-forward {:?}: cost {:.4e} rad^2",
        start.position.kp,
        start.position.ki,
        start.position.kd,
        start.torque.ki,
        start.feedforward,
        c_start
    );
    let with = |x: &[f64]| {
        let mut cfg = start;
        cfg.position.kp = 10f64.powf(x[0]) as f32;
        cfg.position.ki = 10f64.powf(x[1]) as f32;
        cfg.position.kd = 10f64.powf(x[2]) as f32;
        cfg.torque.ki = 10f64.powf(x[3]) as f32;
        cfg
    };
    let x0 = [
        (start.position.kp as f64).log10(),
        (start.position.ki as f64).log10(),
        (start.position.kd as f64).log10(),
        (start.torque.ki as f64).log10(),
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
            |cfg: &ControllerConfig| {
                vec![
                    (cfg.position.kp as f64).log10(),
                    (cfg.position.ki as f64).log10(),
                    (cfg.position.kd as f64).log10(),
                    (cfg.torque.ki as f64).log10(),
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
            let mut moves = Vec::new();
            for f in [0.7f32, 1.4] {
                let mut m = *cfg;
                m.position.kp *= f;
                moves.push(m);
                let mut m = *cfg;
                m.position.ki *= f;
                moves.push(m);
                let mut m = *cfg;
                m.position.kd *= f;
                moves.push(m);
                let mut m = *cfg;
                m.torque.ki *= f;
                moves.push(m);
            }
            moves
        },
        |moves: &[ControllerConfig]| moves.iter().map(|m| cost_cfg(*m)).collect(),
    );
    let (_, nominal, margin) = ctx.cost_cfg(cfg);
    eprintln!(
        "cascade: Nelder-Mead {} points + polish: cost {:.4e} rad^2 ({:.3} x start; suite MSE {:.4e}, at the margin {:.4e}) at kp {} ki {} kd {} torque ki {} (J {}, cutoff {} Hz)",
        evaluations, c, c / c_start, nominal, margin, cfg.position.kp, cfg.position.ki, cfg.position.kd,
        cfg.torque.ki, cfg.feedforward.inertia_kgm2, cfg.feedforward.cutoff_hz
    );
    (cfg, c)
}

fn main() -> Result<()> {
    let mut plant_path = None;
    let mut out = control_tuned_path();
    let mut threads = 2usize;
    let mut cascade_starts: Vec<(f32, f32, f32, Option<f32>)> = Vec::new();
    let mut transition_s: Option<f64> = None;
    // Cut-off of the set-point differentiators of every law tuned [Hz].
    let mut cutoff_hz = 150.0f32;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--plant" => plant_path = Some(PathBuf::from(args.next().context("--plant PATH")?)),
            "--out" => out = PathBuf::from(args.next().context("--out PATH")?),
            "--threads" => {
                threads = args
                    .next()
                    .context("--threads N")?
                    .parse()
                    .context("--threads N")?
            }
            "--setpoint-cutoff-hz" => {
                cutoff_hz = args
                    .next()
                    .context("--setpoint-cutoff-hz HZ")?
                    .parse()
                    .context("--setpoint-cutoff-hz HZ")?
            }
            "--transition-s" => {
                transition_s = Some(
                    args.next()
                        .context("--transition-s T")?
                        .parse::<f64>()
                        .context("--transition-s T (seconds)")?,
                )
            }
            "--cascade-start" => {
                let v: Vec<f32> = args
                    .next()
                    .context("--cascade-start KP,KI,KD[,TORQUE_KI]")?
                    .split(',')
                    .map(|x| x.trim().parse::<f32>())
                    .collect::<Result<_, _>>()
                    .context("--cascade-start KP,KI,KD[,TORQUE_KI]")?;
                if !(3..=4).contains(&v.len()) {
                    bail!("--cascade-start takes KP,KI,KD[,TORQUE_KI]");
                }
                cascade_starts.push((v[0], v[1], v[2], v.get(3).copied()));
            }
            other => bail!("unknown argument {other}"),
        }
    }
    let plant_path = match plant_path {
        Some(p) => p,
        None => reference_plant_path()
            .context("cannot find ../shared/plant/reference-1dof.toml; pass --plant")?,
    };
    let mut scenarios = suite_scenarios()?;
    if let Some(t) = transition_s {
        // A sweep over the suite's move duration (scripts/suite-transition-sweep.sh).
        for s in &mut scenarios {
            s.set_transition_s(t);
        }
        eprintln!("suite with every set-point move lasting {t} s");
    }
    let ctx = Ctx {
        plant: Plant::load(&plant_path)?,
        scenarios,
        runs: AtomicUsize::new(0),
        cutoff_hz,
    };
    // The gains stored in the output file (if it exists and loads) are one more start point
    // of every search.
    let stored = match ControlTuning::load(&out) {
        Ok(t) => Some(t),
        Err(e) => {
            eprintln!("no stored gains to start from ({e})");
            None
        }
    };
    let t0 = Instant::now();

    // The cascade: start points (kp, ki, kd[, torque ki]) = the gains tuned before the
    // feed-forward existed, the firmware's default gains, the stored tuning, any given with
    // --cascade-start; each with the inertia feed-forward off and on (J of the plant).
    let reference = ControllerConfig::reference(1000.0);
    let mut starts = vec![
        (11.0, 8.0, 0.8, None),
        (
            reference.position.kp,
            reference.position.ki,
            reference.position.kd,
            Some(reference.torque.ki),
        ),
    ];
    if let Some(t) = &stored {
        let c = t.cascade.config(1000.0);
        starts.push((
            c.position.kp,
            c.position.ki,
            c.position.kd,
            Some(c.torque.ki),
        ));
    }
    starts.extend(cascade_starts);
    let j_plant = ctx.plant.joint.inertia_kgm2 as f32;
    let mut best_cascade: Option<(ControllerConfig, f64)> = None;
    let mut cascade_from = Vec::new();
    for (kp, ki, kd, torque_ki) in starts {
        for j_kgm2 in [0.0f32, j_plant] {
            let mut start = reference;
            start.position.kp = kp;
            start.position.ki = ki;
            start.position.kd = kd;
            start.torque.ki = torque_ki.unwrap_or(reference.torque.ki);
            start.feedforward.inertia_kgm2 = j_kgm2;
            start.feedforward.cutoff_hz = cutoff_hz;
            let (cfg, c) = tune_cascade(&ctx, start);
            cascade_from.push(format!(
                "({kp:.4}, {ki:.4}, {kd:.4}, {:.4}, J {j_kgm2}) -> {c:.4e}",
                start.torque.ki
            ));
            if best_cascade.is_none_or(|(_, cb)| c < cb) {
                best_cascade = Some((cfg, c));
            }
        }
    }
    let (cascade, _) = best_cascade.expect("at least one start");
    let (_, c_cascade, c_cascade_margin) = ctx.cost_cfg(cascade);

    let with_cutoff = |g: DpPidGains| DpPidGains {
        setpoint_rate_cutoff_hz: cutoff_hz,
        ..g
    };
    let (pd, c_pd, note_pd) = tune(
        &ctx,
        false,
        threads,
        stored.as_ref().map(|t| with_cutoff(t.pd.gains())),
    );
    let (pid, c_pid, note_pid) = tune(
        &ctx,
        true,
        threads,
        stored.as_ref().map(|t| with_cutoff(t.pid.gains())),
    );
    let (_, c_default, c_default_margin) = ctx.cost_cfg(reference);
    let tuning = ControlTuning {
        cascade: CascadeToml::from_config(&cascade, c_cascade, c_cascade_margin),
        pd: DpPidToml::from_gains(&pd, c_pd.0, c_pd.1),
        pid: DpPidToml::from_gains(&pid, c_pid.0, c_pid.1),
    };
    let header = format!(
        "The three laws of the closed-loop comparison (cascade vs PD / PID), each tuned on the suite\n\
         (host-sim control::compare::SUITE) by the same procedure and cost. Written by\n\
         \x20 cargo run --release -p host-sim --example tune_pid\n\
         on {} with the firmware in the loop. Suite MSE = mean over the step_move, sine and\n\
         random_move scenarios of the MSE of the angle over every tick (a latched fault = infinite);\n\
         cost = the worse of the suite MSE at the gains and with the feedback gains x {}\n\
         (gain margin, 6 dB), infinite if the step overshoots by more than 10 %.\n\
         Set-point differentiators of every law: {cutoff_hz} Hz.\n\
         [cascade]: the model-based cascade (ControllerConfig::reference with these gains);\n\
         \x20 Nelder-Mead (restarted) on log10 (kp, ki, kd, torque ki) + x0.7 / x1.4 polish from\n\
         \x20 each start (kp, ki, kd, torque ki, feed-forward J) -> cost [rad^2]:\n\
         \x20 {}\n\
         [pd] / [pid]: the model-free baselines (pam_firmware::pid::DpPid: angle -> dp,\n\
         \x20 p1 = p0 - dp, p2 = p0 + dp); coarse grid, Nelder-Mead on log10 gains from the best grid\n\
         \x20 point and from the stored gains, restarted, x0.7 / x1.4 polish.\n\
         {note_pd}\n\
         {note_pid}\n\
         For comparison, the cascade with the firmware's default gains (ControllerConfig::reference,\n\
         tuned for the jump suite and the firmware's step tests) scored {:.4e} rad^2\n\
         ({:.4e} rad^2 at the gain margin).\n\
         Units: SI (Pa, N m, rad, s); suite_mse_rad2 and suite_mse_at_margin_rad2 are what the\n\
         tuner measured (host-sim/tests/control_compare.rs re-measures them).",
        plant_path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default(),
        GAIN_MARGIN,
        cascade_from.join("\n  "),
        c_default,
        c_default_margin
    );
    tuning.write(&out, &header)?;
    eprintln!(
        "wrote {} ({} suite runs, {:.0} s)",
        out.display(),
        ctx.runs.load(Ordering::Relaxed),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}
