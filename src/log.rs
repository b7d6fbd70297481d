//! Per-tick log: a fixed-size ring buffer (heapless 0.8 `HistoryBuffer`, no allocation)
//! of [`TickRecord`]s with set-points, measurements, commands and faults. The newest
//! `N` ticks are kept; older ones are overwritten. Under the `defmt` feature every record
//! is `defmt::Format`, so a board can dump the buffer after a fault.
//!
//! heapless is used because it is the standard no_std fixed-capacity container crate
//! (already a dependency); its `HistoryBuffer` is exactly "keep the last N".

use heapless::HistoryBuffer;

use crate::tick::io::{SensorFrame, Setpoint, TickOutput};
use crate::valves::ValveCommand;

/// One control tick as logged. Missing samples are stored as NaN (so a log dump shows
/// them); every other field is copied from the tick's output.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TickRecord {
    /// Tick index (caller's counter).
    pub tick: u32,
    /// Angle set-point [rad].
    pub angle_set_rad: f32,
    /// Measured muscle 1 gauge pressure [Pa] (NaN = no sample this tick).
    pub p1_meas_gauge_pa: f32,
    /// Measured muscle 2 gauge pressure [Pa] (NaN = no sample this tick).
    pub p2_meas_gauge_pa: f32,
    /// Measured angle [rad] (NaN = no sample this tick).
    pub angle_meas_rad: f32,
    /// Pressure set-point muscle 1 [Pa gauge].
    pub p1_set_gauge_pa: f32,
    /// Pressure set-point muscle 2 [Pa gauge].
    pub p2_set_gauge_pa: f32,
    /// Desired torque [N m].
    pub torque_des_nm: f32,
    /// Estimated torque [N m].
    pub torque_est_nm: f32,
    /// Velocity estimate [rad/s].
    pub velocity_est_rad_s: f32,
    /// Valve command applied.
    pub valves: ValveCommand,
    /// Latched fault code (0 = none; see [`crate::safety::FaultCode`]).
    pub fault_code: u8,
    /// Fault conditions active this tick (bit `code - 1`, see [`crate::safety::FaultSet`]).
    pub active_faults: u32,
    /// Armed this tick.
    pub armed: bool,
}

impl TickRecord {
    /// Builds the record of one tick from its inputs and output.
    pub fn new(tick: u32, frame: &SensorFrame, setpoint: &Setpoint, out: &TickOutput) -> Self {
        TickRecord {
            tick,
            angle_set_rad: setpoint.angle_rad,
            p1_meas_gauge_pa: frame.p1_gauge_pa.unwrap_or(f32::NAN),
            p2_meas_gauge_pa: frame.p2_gauge_pa.unwrap_or(f32::NAN),
            angle_meas_rad: frame.angle_rad.unwrap_or(f32::NAN),
            p1_set_gauge_pa: out.p1_set_gauge_pa,
            p2_set_gauge_pa: out.p2_set_gauge_pa,
            torque_des_nm: out.torque_des_nm,
            torque_est_nm: out.torque_est_nm,
            velocity_est_rad_s: out.velocity_est_rad_s,
            valves: out.valves,
            fault_code: out.fault.map_or(0, |f| f.code()),
            active_faults: out.active.bits(),
            armed: out.armed,
        }
    }
}

/// Ring buffer of the last `N` tick records.
pub struct TickLog<const N: usize> {
    buf: HistoryBuffer<TickRecord, N>,
}

impl<const N: usize> Default for TickLog<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> TickLog<N> {
    /// An empty log (const: can live in a `static`).
    pub const fn new() -> Self {
        TickLog {
            buf: HistoryBuffer::new(),
        }
    }

    /// Appends a record, overwriting the oldest when full.
    pub fn push(&mut self, rec: TickRecord) {
        self.buf.write(rec);
    }

    /// Number of records held (<= N).
    pub fn len(&self) -> usize {
        self.buf.len()
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.buf.is_empty()
    }

    /// Capacity N.
    pub fn capacity(&self) -> usize {
        self.buf.capacity()
    }

    /// The newest record.
    pub fn latest(&self) -> Option<&TickRecord> {
        self.buf.recent()
    }

    /// Records oldest first.
    pub fn iter(&self) -> impl Iterator<Item = &TickRecord> {
        self.buf.oldest_ordered()
    }

    /// Removes everything.
    pub fn clear(&mut self) {
        self.buf.clear();
    }

    /// Emits every record (oldest first) at info level through defmt (no-op without the
    /// `defmt` feature).
    pub fn dump(&self) {
        for r in self.iter() {
            info!("{}", r);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::safety::FaultCode;

    fn out(fault: Option<FaultCode>) -> TickOutput {
        TickOutput {
            valves: ValveCommand {
                muscle1: 0.5,
                muscle2: -0.5,
            },
            p1_set_gauge_pa: 1.0,
            p2_set_gauge_pa: 2.0,
            torque_des_nm: 3.0,
            torque_est_nm: 4.0,
            angle_est_rad: 5.0,
            velocity_est_rad_s: 6.0,
            fault,
            active: crate::safety::FaultSet::EMPTY,
            armed: fault.is_none(),
        }
    }

    #[test]
    fn record_copies_tick_and_marks_missing_samples_nan() {
        let f = SensorFrame {
            p1_gauge_pa: Some(1e5),
            p2_gauge_pa: None,
            angle_rad: Some(0.1),
        };
        let r = TickRecord::new(
            7,
            &f,
            &Setpoint { angle_rad: 0.2 },
            &out(Some(FaultCode::AngleStale)),
        );
        assert_eq!(r.tick, 7);
        assert_eq!(r.p1_meas_gauge_pa, 1e5);
        assert!(r.p2_meas_gauge_pa.is_nan());
        assert_eq!(r.fault_code, FaultCode::AngleStale as u8);
        assert!(!r.armed);
        assert_eq!(r.valves.muscle2, -0.5);
    }

    #[test]
    fn ring_keeps_newest_n_in_order() {
        let mut log: TickLog<4> = TickLog::new();
        assert!(log.is_empty());
        for k in 0..10u32 {
            log.push(TickRecord::new(
                k,
                &SensorFrame::default(),
                &Setpoint::default(),
                &out(None),
            ));
        }
        assert_eq!(log.len(), 4);
        assert_eq!(log.capacity(), 4);
        let ticks: heapless::Vec<u32, 4> = log.iter().map(|r| r.tick).collect();
        assert_eq!(&ticks[..], &[6, 7, 8, 9]);
        assert_eq!(log.latest().unwrap().tick, 9);
        log.dump();
        log.clear();
        assert!(log.is_empty());
    }
}
