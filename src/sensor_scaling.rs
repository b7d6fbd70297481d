//! Raw sensor counts -> SI, the one place where the board's electrical scaling lives.
//!
//! Shared by the board binary (ADC and quadrature-encoder timer) and the QEMU trace (which
//! stores raw counts, so the emulated run exercises the same conversion). A reading outside
//! the sensor's electrical window (broken wire, short) becomes NaN, which the control tick
//! rejects as invalid; a missing sample stays `None`.

use core::f32::consts::PI;

/// Ratiometric pressure transducer on a 12-bit ADC.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PressureScaling {
    /// Gauge pressure per ADC count [Pa/count].
    pub pa_per_count: f32,
    /// ADC count at 0 Pa gauge.
    pub zero_counts: u16,
    /// Lowest count of a working sensor (below: broken wire).
    pub min_valid_counts: u16,
    /// Highest count of a working sensor (above: short to supply).
    pub max_valid_counts: u16,
}

impl PressureScaling {
    /// 0..1 MPa gauge transducer with a 0.5..4.5 V output, divided by 2/3 (10k/20k) into a
    /// 12-bit ADC at VREF = 3.0 V (STM32F407 Discovery): 0.333 V = 455 counts at 0 Pa,
    /// 3.0 V = 4095 counts at 1 MPa -> 1e6 / (4095 - 455) Pa/count. A working sensor never
    /// reads below 0.4 V out (0.267 V, 364 counts) nor saturates the ADC.
    pub const REFERENCE: PressureScaling = PressureScaling {
        pa_per_count: 1.0e6 / 3640.0,
        zero_counts: 455,
        min_valid_counts: 364,
        max_valid_counts: 4094,
    };

    /// Gauge pressure [Pa] of an ADC sample; NaN outside the electrical window.
    #[inline]
    pub fn gauge_pa(&self, counts: u16) -> f32 {
        if counts < self.min_valid_counts || counts > self.max_valid_counts {
            return f32::NAN;
        }
        (counts as i32 - self.zero_counts as i32) as f32 * self.pa_per_count
    }
}

/// Quadrature encoder on a timer in encoder mode (x4 counting).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EncoderScaling {
    /// Counts per joint revolution (x4 quadrature).
    pub counts_per_rev: u32,
    /// Count at joint angle 0 (set at homing).
    pub zero_count: i32,
}

impl EncoderScaling {
    /// 2000-line encoder, x4 = 8000 counts per turn (RECORDING.md), zero at count 0.
    pub const REFERENCE: EncoderScaling = EncoderScaling {
        counts_per_rev: 8000,
        zero_count: 0,
    };

    /// Joint angle [rad] of a (wrapping) 16- or 32-bit timer count, sign-extended by the caller.
    #[inline]
    pub fn angle_rad(&self, count: i32) -> f32 {
        let d = count.wrapping_sub(self.zero_count);
        d as f32 * (2.0 * PI / self.counts_per_rev as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pressure_zero_and_full_scale() {
        let s = PressureScaling::REFERENCE;
        assert_eq!(s.gauge_pa(455), 0.0);
        assert!((s.gauge_pa(4094) - (1.0e6 - 1.0e6 / 3640.0)).abs() < 1.0);
        assert!((s.gauge_pa(455 + 1092) - 300_000.0).abs() < 1.0);
    }

    #[test]
    fn pressure_outside_electrical_window_is_nan() {
        let s = PressureScaling::REFERENCE;
        assert!(s.gauge_pa(0).is_nan());
        assert!(s.gauge_pa(363).is_nan());
        assert!(s.gauge_pa(4095).is_nan());
        assert!(!s.gauge_pa(364).is_nan());
    }

    #[test]
    fn encoder_quarter_turn_is_half_pi() {
        let e = EncoderScaling::REFERENCE;
        assert!((e.angle_rad(2000) - PI / 2.0).abs() < 1e-6);
        assert!((e.angle_rad(-2000) + PI / 2.0).abs() < 1e-6);
        let z = EncoderScaling {
            zero_count: 100,
            ..e
        };
        assert_eq!(z.angle_rad(100), 0.0);
    }
}
