//! Replays the embedded raw sensor trace (`traces/qemu_sensor_trace.csv`, compiled in by
//! `build.rs`) through sensor scaling and the control tick, one row per tick.
//!
//! The QEMU firmware (`src/bin/qemu.rs`) and the host test (`tests/qemu_trace.rs`) both run
//! [`TraceRunner`], so the per-tick outputs (compared as f32 bit patterns, see
//! [`TickRecord::words`]) must be bit-for-bit identical between the Cortex-M4F build and the
//! host build.

// The control tick driven by the trace: the real one of `docs/tick-contract.md` (src/tick.rs).
use crate::tick;

pub use tick::{ControlTick, ControllerConfig, SensorFrame, Setpoint, TickOutput};

use crate::sensors::PressureScaling;
use crate::wiring;

/// One tick of raw sensor data.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TraceRow {
    /// Position set-point [mrad].
    pub angle_set_mrad: i16,
    /// Muscle 1 pressure ADC counts, [`MISSING_ADC`] = no sample.
    pub p1_adc: u16,
    /// Muscle 2 pressure ADC counts, [`MISSING_ADC`] = no sample.
    pub p2_adc: u16,
    /// Encoder count (x4), [`MISSING_ENCODER`] = no sample.
    pub encoder: i16,
}

/// Marks a missing ADC sample in [`TraceRow`].
pub const MISSING_ADC: u16 = 0xFFFF;
/// Marks a missing encoder sample in [`TraceRow`].
pub const MISSING_ENCODER: i16 = i16::MIN;

include!(concat!(env!("OUT_DIR"), "/sensor_trace.rs"));

/// Tick rate of the trace [Hz].
pub const TRACE_TICK_HZ: f32 = 1000.0;

/// Number of 32-bit words in a [`TickRecord`].
pub const WORDS: usize = 9;

/// The outputs of one tick as exact bit patterns.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TickRecord {
    /// Tick index (row of the trace).
    pub tick: u32,
    /// valves.muscle1, valves.muscle2, p1_set, p2_set, torque_des, torque_est, angle_est,
    /// velocity_est as `f32::to_bits`, then `fault code | armed << 8`.
    pub words: [u32; WORDS],
    /// FNV-1a hash of all words up to and including this tick.
    pub hash: u32,
}

impl TraceRow {
    /// The sensor frame this row delivers through the reference wiring's scaling.
    #[inline]
    pub fn frame(&self, p: &PressureScaling) -> SensorFrame {
        SensorFrame {
            p1_gauge_pa: (self.p1_adc != MISSING_ADC).then(|| p.to_gauge_pa(self.p1_adc as u32)),
            p2_gauge_pa: (self.p2_adc != MISSING_ADC).then(|| p.to_gauge_pa(self.p2_adc as u32)),
            angle_rad: (self.encoder != MISSING_ENCODER)
                .then(|| wiring::angle_rad(self.encoder as i32)),
        }
    }

    /// The set-point of this row.
    #[inline]
    pub fn setpoint(&self) -> Setpoint {
        Setpoint {
            angle_rad: self.angle_set_mrad as f32 * 1.0e-3,
        }
    }
}

/// FNV-1a offset basis.
pub const FNV_OFFSET: u32 = 0x811c_9dc5;

/// Folds one word into an FNV-1a hash (byte-wise, little-endian).
#[inline]
pub fn fnv1a(mut h: u32, w: u32) -> u32 {
    for b in w.to_le_bytes() {
        h ^= b as u32;
        h = h.wrapping_mul(0x0100_0193);
    }
    h
}

/// The words of a tick output (see [`TickRecord::words`]).
#[inline]
pub fn output_words(o: &TickOutput) -> [u32; WORDS] {
    let fault = match o.fault {
        Some(f) => f as u8 as u32,
        None => 0,
    };
    [
        o.valves.muscle1.to_bits(),
        o.valves.muscle2.to_bits(),
        o.p1_set_gauge_pa.to_bits(),
        o.p2_set_gauge_pa.to_bits(),
        o.torque_des_nm.to_bits(),
        o.torque_est_nm.to_bits(),
        o.angle_est_rad.to_bits(),
        o.velocity_est_rad_s.to_bits(),
        fault | (o.armed as u32) << 8,
    ]
}

/// Steps a control tick through [`SENSOR_TRACE`].
pub struct TraceRunner {
    tick: ControlTick,
    pressure: PressureScaling,
    next: usize,
    hash: u32,
    dt_s: f32,
}

impl Default for TraceRunner {
    fn default() -> Self {
        Self::new()
    }
}

impl TraceRunner {
    /// A fresh controller (reference configuration at [`TRACE_TICK_HZ`]) at the trace start.
    pub fn new() -> Self {
        TraceRunner {
            tick: ControlTick::new(ControllerConfig::reference(TRACE_TICK_HZ)),
            pressure: wiring::pressure_scaling(),
            next: 0,
            hash: FNV_OFFSET,
            dt_s: 1.0 / TRACE_TICK_HZ,
        }
    }

    /// Number of ticks in the trace.
    pub const fn len() -> usize {
        SENSOR_TRACE.len()
    }

    /// Runs the next tick; `None` at the end of the trace.
    #[inline]
    pub fn step(&mut self) -> Option<TickRecord> {
        let row = SENSOR_TRACE.get(self.next)?;
        let frame = row.frame(&self.pressure);
        let out = self.tick.step(&frame, &row.setpoint(), self.dt_s);
        let words = output_words(&out);
        for w in words {
            self.hash = fnv1a(self.hash, w);
        }
        let rec = TickRecord {
            tick: self.next as u32,
            words,
            hash: self.hash,
        };
        self.next += 1;
        Some(rec)
    }

    /// Hash of all ticks run so far.
    pub fn hash(&self) -> u32 {
        self.hash
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trace_has_one_row_per_tick_with_missing_samples() {
        assert_eq!(SENSOR_TRACE.len(), 500);
        assert_eq!(SENSOR_TRACE[0].p1_adc, MISSING_ADC);
        assert_eq!(SENSOR_TRACE[0].encoder, MISSING_ENCODER);
        assert_eq!(SENSOR_TRACE[150].p1_adc, MISSING_ADC);
        assert_eq!(SENSOR_TRACE[460].p2_adc, 4095);
    }

    #[test]
    fn replay_arms_controls_and_faults_on_the_shorted_sensor() {
        let mut r = TraceRunner::new();
        let recs: heapless::Vec<TickRecord, 500> =
            core::iter::from_fn(|| r.step()).take(500).collect();
        assert_eq!(recs.len(), 500);
        let armed = |t: &TickRecord| t.words[8] >> 8 == 1;
        assert!(!armed(&recs[0]), "no sensors yet: disarmed");
        assert!(armed(&recs[10]));
        // After the set-point step the outer loop asks for torque and the valves move.
        assert!(recs[60..200]
            .iter()
            .any(|t| f32::from_bits(t.words[0]) != 0.0));
        // Missing samples below the stale limit do not fault.
        assert!(armed(&recs[152]) && armed(&recs[202]));
        // The shorted transducer at tick 460 latches a fault: valves closed from then on.
        for t in &recs[460..] {
            assert_ne!(t.words[8] & 0xFF, 0, "a fault is latched");
            assert!(!armed(t));
            assert_eq!(f32::from_bits(t.words[0]), 0.0);
            assert_eq!(f32::from_bits(t.words[1]), 0.0);
        }
        assert_eq!(recs[499].hash, r.hash());
    }
}
