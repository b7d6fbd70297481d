//! Reference wiring of the board (STM32F407 Discovery, README "Real board"): the sensor
//! scalings from raw counts to SI, shared by the board binary and the QEMU trace (which stores
//! raw counts, so the emulated run exercises the same conversion as the board).
//!
//! The scaling types and conversions are [`crate::sensors`]'; this module only fixes the
//! numbers of the reference electrical chain.

use crate::sensors::{counts_to_rad, PressureScaling};

/// ADC count at 0 Pa gauge: 0..1 MPa transducer with 0.5..4.5 V output, divided by 2/3
/// (10 kOhm / 20 kOhm) into the 12-bit ADC at VREF = 3.0 V: 0.333 V = 455 counts.
pub const PRESSURE_COUNTS_AT_ZERO: u32 = 455;
/// ADC count at full scale (1 MPa gauge): 4.5 V * 2/3 = 3.0 V = 4095 counts.
pub const PRESSURE_COUNTS_AT_FULL: u32 = 4095;
/// Full-scale gauge pressure of the transducer [Pa].
pub const PRESSURE_FULL_SCALE_PA: f32 = 1.0e6;
/// Encoder counts per joint revolution: 2000 lines, x4 quadrature decoding (RECORDING.md).
pub const ENCODER_COUNTS_PER_REV: u32 = 8000;

/// The scaling of both pressure channels (about 274.7 Pa per count).
pub fn pressure_scaling() -> PressureScaling {
    PressureScaling::from_two_points(
        PRESSURE_COUNTS_AT_ZERO,
        PRESSURE_COUNTS_AT_FULL,
        PRESSURE_FULL_SCALE_PA,
    )
}

/// Joint angle [rad] of a signed encoder count.
#[inline]
pub fn angle_rad(counts: i32) -> f32 {
    counts_to_rad(counts, ENCODER_COUNTS_PER_REV)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pressure_zero_and_full_scale_counts() {
        let s = pressure_scaling();
        assert!(s.to_gauge_pa(PRESSURE_COUNTS_AT_ZERO).abs() < 1.0);
        assert!((s.to_gauge_pa(PRESSURE_COUNTS_AT_FULL) - 1.0e6).abs() < 1.0);
        assert!((s.to_gauge_pa(455 + 1092) - 300_000.0).abs() < 1.0);
        // A broken wire (0 counts) reads far below the validated range.
        assert!(s.to_gauge_pa(0) < -100_000.0);
    }

    #[test]
    fn quarter_turn_of_the_encoder_is_half_pi() {
        assert!((angle_rad(2000) - core::f32::consts::FRAC_PI_2).abs() < 1e-6);
        assert!((angle_rad(-2000) + core::f32::consts::FRAC_PI_2).abs() < 1e-6);
    }
}
