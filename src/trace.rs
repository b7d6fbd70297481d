//! Replays the embedded raw sensor trace (`tests/traces/qemu_sensor_trace.csv`, compiled in by
//! `build.rs`) through sensor scaling and the control tick, one row per tick.
//!
//! The QEMU firmware (`src/bin/qemu.rs`) and the host test (`tests/qemu_trace.rs`) both run
//! [`TraceRunner`], so the per-tick outputs (compared as f32 bit patterns, see
//! [`TickRecord::words`]) must be bit-for-bit identical between the Cortex-M4F build and the
//! host build.

// The control tick driven by the trace: the real one of `docs/tick-contract.md` (src/tick/).
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

// `ARM3_SENSOR_TRACE`: the 3-DOF arm's raw sensor trace (tests/traces/arm3_sensor_trace.csv, made
// by host-sim/examples/gen_arm3_trace.rs), one row of three joints per tick, for the arm
// tick's MCU benchmark. A `const`: it takes flash only in an image that uses it.
include!(concat!(env!("OUT_DIR"), "/arm3_sensor_trace.rs"));

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

    /// The raw samples of this row for the fixed-point tick (`fixed_point::tick`).
    #[inline]
    pub fn fixed_frame(&self) -> crate::fixed_point::tick::FixedFrame {
        crate::fixed_point::tick::FixedFrame {
            p1_adc: (self.p1_adc != MISSING_ADC).then_some(self.p1_adc),
            p2_adc: (self.p2_adc != MISSING_ADC).then_some(self.p2_adc),
            encoder: (self.encoder != MISSING_ENCODER).then_some(self.encoder as i32),
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

/// The configuration the trace runs with: the reference one at [`TRACE_TICK_HZ`], with the
/// valve / supply residual ([`crate::residual`]) unable to trip. The trace is a recorded
/// replay: its pressures do not answer this run's valve commands, so any model-based
/// residual would (rightly) call them faulty. The supervision still runs every tick, so its
/// cost is in the MCU figures.
pub fn trace_config() -> ControllerConfig {
    let mut cfg = ControllerConfig::reference(TRACE_TICK_HZ);
    open_loop_replay(&mut cfg);
    cfg
}

/// The 3-DOF arm's reference configuration with every joint set up as [`trace_config`] is
/// for an open-loop replay of [`ARM3_SENSOR_TRACE`].
pub fn arm3_trace_config() -> crate::arm::ArmConfig {
    let mut cfg = crate::arm::ArmConfig::reference(TRACE_TICK_HZ);
    for j in cfg.joints.iter_mut() {
        open_loop_replay(j);
    }
    cfg
}

/// A configuration for replaying a recorded trace open loop.
fn open_loop_replay(cfg: &mut ControllerConfig) {
    cfg.valve_model.residual_abs_pa_s = f32::MAX;
    // The trace's pressures do not follow the commands (open loop): the integrated valve
    // check would see every opening as a stuck-closed valve. It still runs (its cost is
    // measured) but never judges.
    cfg.valve_model.integral_min_pa = f32::MAX;
    // Nor does its angle follow a ramped set-point: the start phase (a transient of at most
    // ~1 s after arming, measured on its own by `bench-mcu.sh`) is skipped.
    cfg.start = crate::tick::config::StartRamp::INSTANT;
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
            tick: ControlTick::new(trace_config()),
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

/// Muscle 1's force-law inputs over the trace, for every row with a pressure and an angle:
/// gauge pressure [Pa] and stretch (f32), and both quantised for the fixed-point law (`None`
/// where either does not fit). The benchmark images and the on-target tests evaluate the
/// force laws at these.
pub fn force_law_inputs() -> impl Iterator<
    Item = (
        f32,
        f32,
        Option<(crate::fixed_point::PressurePa, crate::fixed_point::Stretch)>,
    ),
> {
    use crate::fixed_point::{pressure_pa_from_f32, q16_from_f32};
    let p = wiring::pressure_scaling();
    let g = crate::geometry::JointGeometry::REFERENCE;
    SENSOR_TRACE.iter().filter_map(move |row| {
        let f = row.frame(&p);
        let (e1, _) = g.stretches(f.angle_rad?);
        let p1 = f.p1_gauge_pa?;
        let fixed = pressure_pa_from_f32(p1).zip(q16_from_f32(e1));
        Some((p1, e1, fixed))
    })
}

/// The fixed-point path (src/fixed_point.rs) over the trace, as the FPU-less image runs it:
/// for every row with both pressures and the angle, the fixed force law on both muscles
/// (force bits and flags) and the fixed torque model (forward at half the pressure
/// difference, then inverted), then the whole fixed-point tick (`fixed_point::tick`, all
/// output words of every row), FNV-1a hashed. Returns (rows evaluated, hash). The Cortex-M0
/// image (`src/bin/qemu_m0.rs`) prints it; `tests/qemu_trace.rs` compares it with this host
/// run bit for bit.
pub fn fixed_path_digest() -> (u32, u32) {
    use crate::constants::{FIXED_FORCE_LAW, FIXED_TORQUE_MODEL};
    use crate::fixed_point::{pressure_pa_from_f32, q16_from_f32, PressurePa, VelocityRadS};
    let p = wiring::pressure_scaling();
    let g = crate::geometry::JointGeometry::REFERENCE;
    let (mut n, mut h) = (0u32, FNV_OFFSET);
    for row in SENSOR_TRACE.iter() {
        let f = row.frame(&p);
        let (Some(p1), Some(p2), Some(a)) = (f.p1_gauge_pa, f.p2_gauge_pa, f.angle_rad) else {
            continue;
        };
        let (e1, e2) = g.stretches(a);
        let (Some(p1), Some(p2), Some(e1), Some(e2), Some(aq)) = (
            pressure_pa_from_f32(p1),
            pressure_pa_from_f32(p2),
            q16_from_f32(e1),
            q16_from_f32(e2),
            q16_from_f32(a),
        ) else {
            continue;
        };
        for (pp, e) in [(p1, e1), (p2, e2)] {
            let r = FIXED_FORCE_LAW.force(pp, e);
            h = fnv1a(h, r.force_n.to_bits() as u32);
            h = fnv1a(h, r.flags.0 as u32);
        }
        let dp = PressurePa::from_bits((p2.to_bits() - p1.to_bits()) / 2);
        let t = FIXED_TORQUE_MODEL.torque_nm(aq, VelocityRadS::ZERO, dp);
        let act = FIXED_TORQUE_MODEL.activation(t, aq, VelocityRadS::ZERO);
        h = fnv1a(h, t.to_bits() as u32);
        h = fnv1a(
            h,
            act.dp_pa.to_bits() as u32 ^ ((act.saturated as u32) << 31),
        );
        n += 1;
    }
    let mut tick = crate::fixed_point::tick::FixedTick::new(
        crate::fixed_point::tick::reference_from_params(TRACE_TICK_HZ),
    );
    for row in SENSOR_TRACE.iter() {
        let sp = crate::fixed_point::tick::mrad_to_q16(row.angle_set_mrad as i32);
        for w in tick.step(&row.fixed_frame(), sp).words() {
            h = fnv1a(h, w);
        }
    }
    (n, h)
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
