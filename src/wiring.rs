//! Reference wiring of the board (STM32F407 Discovery, README "Real board"): the sensor
//! scalings from raw counts to SI, shared by the board binary and the QEMU trace (which stores
//! raw counts, so the emulated run exercises the same conversion as the board).
//!
//! The scaling types and conversions are [`crate::sensors`]'; this module only fixes the
//! numbers of the reference electrical chain.

use crate::safety::SafeState;
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

/// GPIOD pins of the four valve drivers, in the order inflate 1, exhaust 1, inflate 2,
/// exhaust 2 (TIM4 CH1..CH4 on PD12..PD15; the driver inputs have pull-downs: a floating pin,
/// i.e. any reset, closes the valve).
pub const VALVE_PINS_GPIOD: [u32; 4] = [12, 13, 14, 15];

/// GPIOD pin of the valve-driver enable line (PD11): high powers the four valve drivers
/// (e.g. the gate of a high-side switch in their supply). The driver board pulls it down: a
/// floating pin (any reset, and the start-up until `init` drives it low) leaves every driver
/// unpowered, which closes normally-closed valves whatever their PWM pins do.
pub const VALVE_ENABLE_PIN_GPIOD: u32 = 11;

/// Level of the valve-enable line: high while armed, and while faulted only when the safe
/// command opens a valve (`Vent`, or a muscle vented by escalation). In `Hold` the drivers
/// are unpowered, so a shorted driver or a pin stuck high cannot open a valve.
#[inline]
pub fn valve_enable(armed: bool, command: &crate::valves::ValveCommand) -> bool {
    armed || command.muscle1 != 0.0 || command.muscle2 != 0.0
}

/// The enable level of a safe state (HardFault and the tick monitor): low unless a valve is
/// to be held open.
pub const fn safe_valve_enable(safe: SafeState) -> bool {
    let l = safe_valve_levels(safe);
    l[0] || l[1] || l[2] || l[3]
}

/// The GPIOD `BSRR` word of a safe state: the four valve pins and the enable line.
pub const fn safe_bsrr(safe: SafeState) -> u32 {
    let en = if safe_valve_enable(safe) {
        1 << VALVE_ENABLE_PIN_GPIOD
    } else {
        1 << (VALVE_ENABLE_PIN_GPIOD + 16)
    };
    valve_bsrr(safe_valve_levels(safe)) | en
}

/// Pin levels (inflate 1, exhaust 1, inflate 2, exhaust 2; high = open) of a safe state:
/// every valve closed (`Hold`) or both exhausts open (`Vent`).
pub const fn safe_valve_levels(safe: SafeState) -> [bool; 4] {
    match safe {
        SafeState::Hold => [false; 4],
        SafeState::Vent => [false, true, false, true],
    }
}

/// The GPIO `BSRR` word that drives the valve pins to `levels` (set bit `n` for a high pin,
/// reset bit `n + 16` for a low one; the other pins are untouched).
pub const fn valve_bsrr(levels: [bool; 4]) -> u32 {
    let mut w = 0u32;
    let mut i = 0;
    while i < 4 {
        let pin = VALVE_PINS_GPIOD[i];
        w |= if levels[i] { 1 << pin } else { 1 << (pin + 16) };
        i += 1;
    }
    w
}

/// `MODER` of the GPIO port with the valve pins as push-pull outputs (`01`): the levels of
/// `ODR` reach the valves whatever the timer does. Other pins unchanged.
pub const fn valve_moder_output(moder: u32) -> u32 {
    valve_moder(moder, 0b01)
}

/// `MODER` with the valve pins back on their alternate function (`10`, the TIM4 PWM).
pub const fn valve_moder_alternate(moder: u32) -> u32 {
    valve_moder(moder, 0b10)
}

const fn valve_moder(moder: u32, mode: u32) -> u32 {
    let mut m = moder;
    let mut i = 0;
    while i < 4 {
        let shift = 2 * VALVE_PINS_GPIOD[i];
        m = (m & !(0b11 << shift)) | (mode << shift);
        i += 1;
    }
    m
}

/// Fill marker of the ADC buffers: 12-bit conversions never produce it, so a buffer entry the
/// DMA did not overwrite since it was handed out still holds it.
pub const ADC_NOT_WRITTEN: u16 = 0xFFFF;

/// The conversions of a buffer the DMA handed back, each `None` when the DMA did not write
/// it (a stale or frozen buffer reaches the tick as a missing sample, which ages into a
/// `...Stale` fault), and the buffer marked again before it goes back to the DMA.
pub fn take_fresh_counts(buf: &mut [u16; 2]) -> [Option<u16>; 2] {
    let mut out = [None; 2];
    for (o, v) in out.iter_mut().zip(buf.iter_mut()) {
        if *v != ADC_NOT_WRITTEN && *v <= 4095 {
            *o = Some(*v);
        }
        *v = ADC_NOT_WRITTEN;
    }
    out
}

/// Largest accepted distance of a calibrated zero from [`PRESSURE_COUNTS_AT_ZERO`] [counts]:
/// 10 % of the span, about 100 kPa (the transducer's offset tolerance is a few %; more is
/// a muscle not vented, a broken wire or a wrong sensor).
pub const PRESSURE_ZERO_TOLERANCE_COUNTS: u32 =
    (PRESSURE_COUNTS_AT_FULL - PRESSURE_COUNTS_AT_ZERO) / 10;

/// Why a start-up pressure calibration was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CalibrationError {
    /// No sample arrived during the calibration time.
    NoSamples,
    /// The mean reading at atmospheric pressure [counts] is outside
    /// `PRESSURE_COUNTS_AT_ZERO +- PRESSURE_ZERO_TOLERANCE_COUNTS`.
    ZeroOutOfRange {
        /// The mean [counts].
        mean_counts: u32,
    },
}

/// The pressure scaling of one channel after the start-up zero calibration: `sum_counts` of
/// `n` samples taken with the muscle vented to atmosphere (both exhausts open) is 0 Pa gauge;
/// the slope stays the nominal one (the transducer's span). 32-bit: 12-bit samples sum
/// without overflow for a million samples (the board averages at most 5000); a saturated sum
/// reads as out of range, never as a valid zero.
pub fn calibrated_pressure_scaling(
    sum_counts: u32,
    n: u32,
) -> Result<PressureScaling, CalibrationError> {
    if n == 0 {
        return Err(CalibrationError::NoSamples);
    }
    let mean_counts = sum_counts / n + u32::from(sum_counts % n >= n - n / 2);
    if mean_counts.abs_diff(PRESSURE_COUNTS_AT_ZERO) > PRESSURE_ZERO_TOLERANCE_COUNTS {
        return Err(CalibrationError::ZeroOutOfRange { mean_counts });
    }
    let nominal = pressure_scaling();
    // Sub-count resolution: the offset uses the exact mean, not the rounded one.
    let mean_exact = sum_counts as f32 / n as f32;
    Ok(PressureScaling {
        pa_per_count: nominal.pa_per_count,
        offset_pa: -nominal.pa_per_count * mean_exact,
    })
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

    #[test]
    fn safe_levels_and_register_words() {
        assert_eq!(safe_valve_levels(SafeState::Hold), [false; 4]);
        assert_eq!(
            safe_valve_levels(SafeState::Vent),
            [false, true, false, true]
        );
        // Hold: reset PD12..PD15.
        assert_eq!(valve_bsrr([false; 4]), 0xF000 << 16);
        // Vent: PD13 and PD15 set, PD12 and PD14 reset.
        assert_eq!(
            valve_bsrr(safe_valve_levels(SafeState::Vent)),
            (1 << 13 | 1 << 15) | (1 << 12 | 1 << 14) << 16
        );
        // MODER: pins 12..15 are bits 24..31; the other pins keep their mode.
        let other = 0x00AB_CDEF;
        assert_eq!(valve_moder_output(other | 0xFF00_0000), other | 0x5500_0000);
        assert_eq!(valve_moder_alternate(other), other | 0xAA00_0000);
        assert_eq!(
            valve_moder_alternate(valve_moder_output(other)),
            other | 0xAA00_0000
        );
    }

    #[test]
    fn a_buffer_the_dma_did_not_rewrite_is_a_missing_sample() {
        let mut buf = [ADC_NOT_WRITTEN; 2];
        assert_eq!(take_fresh_counts(&mut buf), [None, None]);
        buf = [1000, ADC_NOT_WRITTEN];
        assert_eq!(take_fresh_counts(&mut buf), [Some(1000), None]);
        // Marked again: handed back unchanged (frozen DMA), it reads as missing.
        assert_eq!(buf, [ADC_NOT_WRITTEN; 2]);
        assert_eq!(take_fresh_counts(&mut buf), [None, None]);
        buf = [0, 4095];
        assert_eq!(take_fresh_counts(&mut buf), [Some(0), Some(4095)]);
        // Not a 12-bit value: not a conversion.
        buf = [4096, 17];
        assert_eq!(take_fresh_counts(&mut buf), [None, Some(17)]);
    }

    #[test]
    fn pressure_zero_calibration() {
        // 2000 samples averaging 470.5 counts: that reading is 0 Pa, the slope is nominal.
        let s = calibrated_pressure_scaling(2000 * 4705 / 10, 2000).unwrap();
        let nominal = pressure_scaling();
        assert_eq!(s.pa_per_count, nominal.pa_per_count);
        assert!((s.offset_pa + 470.5 * nominal.pa_per_count).abs() < 1e-2);
        assert!(s.to_gauge_pa(470).abs() < nominal.pa_per_count);
        assert!((s.to_gauge_pa(4095) - (4095.0 - 470.5) * nominal.pa_per_count).abs() < 1.0);
        assert_eq!(
            calibrated_pressure_scaling(0, 0),
            Err(CalibrationError::NoSamples)
        );
        // A muscle not vented (200 kPa = +728 counts) or a broken wire (0 counts) is refused.
        assert_eq!(
            calibrated_pressure_scaling(10 * (455 + 728), 10),
            Err(CalibrationError::ZeroOutOfRange { mean_counts: 1183 })
        );
        assert_eq!(
            calibrated_pressure_scaling(0, 10),
            Err(CalibrationError::ZeroOutOfRange { mean_counts: 0 })
        );
        // The tolerance edges.
        let t = PRESSURE_ZERO_TOLERANCE_COUNTS;
        assert!(calibrated_pressure_scaling(455 + t, 1).is_ok());
        assert!(calibrated_pressure_scaling(455 - t, 1).is_ok());
        assert!(calibrated_pressure_scaling(455 + t + 1, 1).is_err());
        assert!(calibrated_pressure_scaling(455 - t - 1, 1).is_err());
        // No overflow for any sum; rounding to the nearest count (half up).
        assert!(calibrated_pressure_scaling(u32::MAX, 1).is_err());
        assert!(calibrated_pressure_scaling(u32::MAX, u32::MAX).is_err());
        assert_eq!(
            calibrated_pressure_scaling(4 * 455 + 1, 4).map(|s| s.to_gauge_pa(455).abs() < 100.0),
            Ok(true)
        );
        // 818.5 rounds to 819 = 455 + 364 (the edge, accepted), 819.5 to 820 (refused),
        // 819.33 to 819.
        assert_eq!(PRESSURE_ZERO_TOLERANCE_COUNTS, 364);
        assert!(calibrated_pressure_scaling(2 * 818 + 1, 2).is_ok());
        assert_eq!(
            calibrated_pressure_scaling(2 * 819 + 1, 2),
            Err(CalibrationError::ZeroOutOfRange { mean_counts: 820 })
        );
        assert!(calibrated_pressure_scaling(3 * 819 + 1, 3).is_ok());
    }

    #[test]
    fn the_valve_enable_line_is_low_in_hold_and_high_when_a_valve_must_open() {
        use crate::valves::ValveCommand;
        let closed = ValveCommand::default();
        assert!(!valve_enable(false, &closed));
        assert!(valve_enable(true, &closed));
        let vent1 = ValveCommand {
            muscle1: -1.0,
            muscle2: 0.0,
        };
        assert!(valve_enable(false, &vent1));
        assert!(!safe_valve_enable(SafeState::Hold));
        assert!(safe_valve_enable(SafeState::Vent));
        // Hold: the four valve pins and the enable line reset (BSRR bits 16+).
        assert_eq!(
            safe_bsrr(SafeState::Hold),
            (1 << (12 + 16))
                | (1 << (13 + 16))
                | (1 << (14 + 16))
                | (1 << (15 + 16))
                | (1 << (11 + 16))
        );
        // Vent: exhausts and the enable line set.
        assert_eq!(
            safe_bsrr(SafeState::Vent) & 0xffff,
            (1 << 13) | (1 << 15) | (1 << 11)
        );
    }
}
