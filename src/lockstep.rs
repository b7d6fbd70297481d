//! The firmware side of a closed loop driven one tick at a time: sensor data in, valve pin
//! levels out. host-sim's in-process closed loop and the processor-in-the-loop image
//! (`src/bin/pil.rs` under QEMU) both run this, so the two differ only in the machine that
//! executes it.
//!
//! Per tick ([`FirmwareNode::step`]): an MCU reset if one is asked for (the persistent latch
//! decides the boot, the control tick and the valve driver restart), the sensor frame,
//! [`ControlTick::step`], the latch update, the on/off valve driver writing the pins, and the
//! driver's openings reported back to the tick (valve / supply supervision).
//!
//! In board units ([`FirmwareNode::step_raw`]) the frame comes from raw ADC and encoder
//! counts through the board's scaling ([`crate::wiring`] on the board and in the image) and a
//! sequence gate per channel, as the board's sensor reads deliver it: a frozen sensor (same
//! sequence number) gives no sample.

use core::convert::Infallible;

use embedded_hal::digital::OutputPin;

use crate::latch::{BootDecision, LatchRecord, PersistentLatch, RamStorage, ResetCause};
use crate::sensors::{counts_to_rad, PressureScaling, SequenceGate};
use crate::stream::{
    SensorInput, FLAG_NAN_SHIFT, FLAG_STALE_SHIFT, MISSING_COUNTS, MISSING_ENCODER, RESET_POWER_ON,
    RESET_WATCHDOG,
};
use crate::tick::config::ControllerConfig;
use crate::tick::io::{SensorFrame, Setpoint, TickOutput};
use crate::tick::ControlTick;
use crate::valves::{OnOffPwmConfig, OnOffValves};

/// Raw counts to the tick's sensor frame, with a sequence gate per channel (p1, p2, angle).
#[derive(Clone, Copy, Debug, Default)]
pub struct RawSensors {
    seq: [u32; 3],
    gates: [SequenceGate; 3],
}

impl RawSensors {
    /// Sensors that delivered nothing yet.
    pub const fn new() -> Self {
        RawSensors {
            seq: [0; 3],
            gates: [SequenceGate::new(); 3],
        }
    }

    /// The frame for `input`: a missing marker gives no sample (the gate is not consulted),
    /// a stale flag repeats the channel's sequence number (the gate gives no sample), a NaN
    /// flag reads NaN.
    pub fn frame(
        &mut self,
        input: &SensorInput,
        scaling: &PressureScaling,
        counts_per_rev: u32,
    ) -> SensorFrame {
        let value = |i: usize| -> Option<f32> {
            match i {
                0 | 1 if input.p_counts[i] != MISSING_COUNTS => {
                    Some(scaling.to_gauge_pa(input.p_counts[i] as u32))
                }
                2 if input.encoder_counts != MISSING_ENCODER => {
                    Some(counts_to_rad(input.encoder_counts, counts_per_rev))
                }
                _ => None,
            }
        };
        let mut out = [None; 3];
        for (i, o) in out.iter_mut().enumerate() {
            if let Some(v) = value(i) {
                if input.flags & (1 << (FLAG_STALE_SHIFT + i as u8)) == 0 {
                    self.seq[i] = self.seq[i].wrapping_add(1);
                }
                *o = self.gates[i].gate(self.seq[i], v);
            }
            if input.flags & (1 << (FLAG_NAN_SHIFT + i as u8)) != 0 {
                *o = Some(f32::NAN);
            }
        }
        SensorFrame {
            p1_gauge_pa: out[0],
            p2_gauge_pa: out[1],
            angle_rad: out[2],
        }
    }
}

/// What one tick did.
#[derive(Clone, Copy, Debug)]
pub struct NodeTick {
    /// The frame the control tick saw.
    pub frame: SensorFrame,
    /// The control tick's output.
    pub out: TickOutput,
    /// Pin levels the valve driver wrote (in1, ex1, in2, ex2; high = open).
    pub pins: [bool; 4],
}

/// A valve output wired to nothing: writes are dropped. For runs that need only the openings
/// the valve driver computes (host tests, benchmarks of the control law), never for a board.
#[derive(Clone, Copy, Debug, Default)]
pub struct UnwiredPin;

impl embedded_hal::digital::ErrorType for UnwiredPin {
    type Error = Infallible;
}

impl OutputPin for UnwiredPin {
    fn set_low(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
    fn set_high(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}

/// Reads a pin level back (the fake pins of the host, the image's pin latches).
pub trait PinLevel {
    /// The level last written.
    fn is_high(&self) -> bool;
}

/// The firmware: control tick, persistent latch (in RAM, kept over simulated resets), valve
/// driver on four pins, raw sensor front end.
pub struct FirmwareNode<P: OutputPin<Error = Infallible> + PinLevel + Clone> {
    cfg: ControllerConfig,
    tick: ControlTick,
    latch: PersistentLatch<RamStorage>,
    pins: [P; 4],
    valves: OnOffValves<P, P, P, P>,
    sensors: RawSensors,
    scaling: PressureScaling,
    counts_per_rev: u32,
}

impl<P: OutputPin<Error = Infallible> + PinLevel + Clone> FirmwareNode<P> {
    /// Powered on with a clean latch record; `scaling` and `counts_per_rev` convert raw
    /// counts ([`Self::step_raw`]).
    pub fn new(
        cfg: ControllerConfig,
        pins: [P; 4],
        scaling: PressureScaling,
        counts_per_rev: u32,
    ) -> Self {
        let (latch, _) =
            PersistentLatch::boot(RamStorage(LatchRecord::CLEAN.encode()), ResetCause::PowerOn);
        let valves = Self::driver(&pins);
        FirmwareNode {
            cfg,
            tick: ControlTick::new(cfg),
            latch,
            pins,
            valves,
            sensors: RawSensors::new(),
            scaling,
            counts_per_rev,
        }
    }

    fn driver(pins: &[P; 4]) -> OnOffValves<P, P, P, P> {
        OnOffValves::new(
            pins[0].clone(),
            pins[1].clone(),
            pins[2].clone(),
            pins[3].clone(),
            OnOffPwmConfig::REFERENCE,
        )
    }

    /// An MCU reset: the latch decides the boot; the control tick, the valve driver and the
    /// sensor front end restart.
    pub fn reset(&mut self, cause: ResetCause) {
        // Take the latch out (a throw-away latch on blank storage stands in meanwhile).
        let blank = PersistentLatch::boot(RamStorage::default(), ResetCause::PowerOn).0;
        let storage = core::mem::replace(&mut self.latch, blank).release();
        let (latch, boot) = PersistentLatch::boot(storage, cause);
        self.latch = latch;
        self.tick = ControlTick::new(self.cfg);
        if let BootDecision::Safe(rec) = boot {
            self.tick.restore_latch(&rec);
        }
        self.valves = Self::driver(&self.pins);
        self.sensors = RawSensors::new();
    }

    /// One tick on an SI sensor frame.
    pub fn step(&mut self, frame: &SensorFrame, setpoint_rad: f32, dt_s: f32) -> NodeTick {
        let out = self.tick.step(
            frame,
            &Setpoint {
                angle_rad: setpoint_rad,
            },
            dt_s,
        );
        self.latch.update(self.tick.latch_record());
        let Ok(o) = self.valves.apply_switched(&out.valves);
        self.tick.valves_switched(o);
        NodeTick {
            frame: *frame,
            out,
            pins: core::array::from_fn(|i| self.pins[i].is_high()),
        }
    }

    /// One tick on a raw frame (its reset, counts, flags, set-point and measured period).
    pub fn step_raw(&mut self, input: &SensorInput) -> NodeTick {
        match input.reset {
            RESET_POWER_ON => self.reset(ResetCause::PowerOn),
            RESET_WATCHDOG => self.reset(ResetCause::Watchdog),
            _ => {}
        }
        let frame = self
            .sensors
            .frame(input, &self.scaling, self.counts_per_rev);
        self.step(&frame, input.setpoint_rad, input.dt_s)
    }
}
