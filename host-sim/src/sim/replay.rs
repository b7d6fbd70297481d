//! The simulator stage of the streaming open-loop replay (`io::replay_stream`, what
//! `simulate --inputs` runs): the integration of chunks of rows as they come, then the sensor
//! path, in the pipeline's own thread. The reading and writing of the files are `io`'s.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;

use crate::plant::{Plant, ValveInputs};
use crate::sim::{ActuatorPath, Integrator, SensorPath, SimStats, SolverOptions};

/// Rows per chunk passed between the threads (small chunks: the buffers in flight are
/// reused instead of faulted in fresh, and the pipeline fills and drains sooner).
pub(crate) const CHUNK_ROWS: usize = 256;

/// Rows as the reader passes them on: time stamps and valve openings.
#[derive(Default)]
pub(crate) struct RowChunk {
    pub(crate) t_s: Vec<f64>,
    pub(crate) inputs: Vec<ValveInputs>,
}

/// Simulated rows, for the writer to format: the input's time and openings with the
/// simulated channels (by `Channel::index`).
pub(crate) struct OutChunk {
    pub(crate) rows: Vec<(f64, ValveInputs, [f64; 5])>,
}

impl OutChunk {
    pub(crate) fn with_capacity(rows: usize) -> Self {
        Self {
            rows: Vec::with_capacity(rows),
        }
    }
}

/// The simulator stage: [`crate::sim::simulate_with_progress`] over the rows as they come,
/// then the sensor path, sending the simulated rows on (`spent_rows`: parsed rows back to
/// the reader; `spent_out`: output chunks back from the writer).
#[allow(clippy::too_many_arguments)]
pub(crate) fn simulate_chunks(
    plant: &Plant,
    dt_s: f64,
    opts: &SolverOptions,
    rx: mpsc::Receiver<RowChunk>,
    tx: &mpsc::SyncSender<OutChunk>,
    spent_rows: &mpsc::Sender<RowChunk>,
    spent_out: &mpsc::Receiver<OutChunk>,
    abort: &AtomicBool,
) -> Result<SimStats, ()> {
    let mut actuator = ActuatorPath::new(plant, dt_s, "open-loop replay").map_err(|_| ())?;
    let delayed = actuator.delay_samples() != 0;
    let mut integ = Integrator::new(plant, plant.initial_state(), *opts);
    let mut sensor = SensorPath::new(plant, dt_s);
    // Rows read but not yet simulated (the current run of identical inputs).
    let mut pending: VecDeque<(f64, ValveInputs)> = VecDeque::new();
    let mut run: Option<(ValveInputs, usize)> = None;
    let mut out = OutChunk::with_capacity(CHUNK_ROWS);
    let mut advance = |u: ValveInputs,
                       len: usize,
                       pending: &mut VecDeque<(f64, ValveInputs)>,
                       out: &mut OutChunk|
     -> Result<(), ()> {
        integ
            .advance_samples(u, dt_s, len, |x| {
                let (t, u) = pending.pop_front().unwrap_or_default();
                let m = sensor.push(plant, x);
                out.rows.push((t, u, m.to_array()));
            })
            .map_err(|_| ())
    };
    for chunk in rx {
        if abort.load(Ordering::Relaxed) {
            return Err(());
        }
        for (&t, &u) in chunk.t_s.iter().zip(&chunk.inputs) {
            pending.push_back((t, u));
            let d = if delayed { actuator.push(u) } else { u };
            match &mut run {
                Some((ru, len)) if *ru == d => *len += 1,
                _ => {
                    if let Some((ru, len)) = run.take() {
                        advance(ru, len, &mut pending, &mut out)?;
                    }
                    run = Some((d, 1));
                }
            }
        }
        let _ = spent_rows.send(chunk);
        if out.rows.len() >= CHUNK_ROWS {
            let next = match spent_out.try_recv() {
                Ok(mut c) => {
                    c.rows.clear();
                    c
                }
                Err(_) => OutChunk::with_capacity(CHUNK_ROWS),
            };
            let full = std::mem::replace(&mut out, next);
            tx.send(full).map_err(|_| ())?;
        }
    }
    if let Some((ru, len)) = run.take() {
        advance(ru, len, &mut pending, &mut out)?;
    }
    if !pending.is_empty() {
        return Err(());
    }
    if !out.rows.is_empty() {
        tx.send(out).map_err(|_| ())?;
    }
    Ok(integ.stats())
}
