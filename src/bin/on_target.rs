//! On-target tests (defmt-test) for the Cortex-M4F build, run under QEMU's netduinoplus2
//! (STM32F405) through the cargo runner: `cargo on-target` (alias for `cargo run -p
//! pam-firmware --bin on_target --features pam-firmware/on-target-tests --release --target
//! thumbv7em-none-eabihf`). Exit status 0 when all passed, 1 at the first failure.
//! `tests/qemu_trace.rs` runs it in CI. A binary, not a `[[test]]` target in `tests/`: a test
//! target would build the std-only dev-dependencies for the bare-metal target.
//!
//! They check on the target, with its FPU and its code generation, what the host tests check
//! on the host: the FPU square root against libm's, the fixed-point force law against the f32 law, the anti-windup of a saturated
//! step, the valve commands of the control tick over the embedded sensor trace, and the
//! fixed-point tick over the trace (its digest is compared with the host's by
//! `tests/qemu_trace.rs`).
#![no_std]
#![no_main]

// The runtime (vector table, reset handler, default handlers): defmt-test's entry does not
// name the crate, so it is linked in here.
use cortex_m_rt as _;
use defmt_semihosting as _;

#[path = "common/semihost.rs"]
mod semihost;

/// A failed assertion panics: log the location and exit with status 1 (semihosting).
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    semihost::panicked(info)
}

#[defmt_test::tests]
mod tests {
    use pam_firmware::constants::{FIXED_FORCE_LAW, FORCE_LAW};
    use pam_firmware::control::saturated_step;
    use pam_firmware::trace::{force_law_inputs, TraceRunner, SENSOR_TRACE};

    /// The tick's square root (`math::sqrtf`: the FPU's VSQRT here) has the bits of
    /// `libm::sqrtf` (the host's and the Cortex-M0's) for every 4099th non-negative f32 bit
    /// pattern from zero (subnormals, normals), for infinity, and for every
    /// argument `1 - x^2` of the valve flow functions at 2^-16 steps of `x` in [0, 1].
    #[test]
    fn fpu_sqrt_has_the_bits_of_libm() {
        let mut bits = 0u32;
        while bits <= 0x7f80_0000 {
            let x = f32::from_bits(bits);
            let (a, b) = (pam_firmware::math::sqrtf(x), libm::sqrtf(x));
            defmt::assert_eq!(a.to_bits(), b.to_bits(), "sqrt of bits {=u32:08x}", bits);
            bits += 4099;
        }
        let inf = f32::INFINITY;
        defmt::assert_eq!(
            pam_firmware::math::sqrtf(inf).to_bits(),
            libm::sqrtf(inf).to_bits()
        );
        for k in 0..=65_536u32 {
            let x = k as f32 / 65_536.0;
            let y = 1.0 - x * x;
            let (a, b) = (pam_firmware::math::sqrtf(y), libm::sqrtf(y));
            defmt::assert_eq!(a.to_bits(), b.to_bits(), "sqrt(1 - x^2) at x = {=f32}", x);
        }
    }

    /// Over the trace: the fixed-point force law within 0.1 N of the f32 law (the FPU's) at
    /// the same inputs, for every row with a pressure and an angle.
    #[test]
    fn fixed_force_law_tracks_the_f32_law_over_the_trace() {
        let mut n = 0u32;
        for (_, _, fixed) in force_law_inputs() {
            let Some((pq, eq)) = fixed else {
                continue;
            };
            let fx = FIXED_FORCE_LAW.force(pq, eq);
            let fl = FORCE_LAW.force(pq.to_num::<f32>(), eq.to_num::<f32>());
            let d = fx.force_n.to_num::<f32>() - fl.force_n;
            defmt::assert!(
                d.abs() < 0.1,
                "{=f32} N off at {=i32} Pa",
                d,
                pq.to_num::<i32>()
            );
            n += 1;
        }
        defmt::assert!(n > 100);
    }

    /// The saturated step of the host test (`control::saturated_step`), on the target: 0.8 N m
    /// available, step 0 -> 1 rad; with anti-windup the overshoot is less than half.
    #[test]
    fn anti_windup_cuts_the_overshoot_of_a_saturated_step() {
        let (with, _, _) = saturated_step(true);
        let (without, _, _) = saturated_step(false);
        defmt::info!(
            "overshoot with {=f32} rad, without {=f32} rad",
            with,
            without
        );
        defmt::assert!(with < 0.5 * without);
    }

    /// The control tick over the whole trace: every valve command finite and within [-1, 1].
    #[test]
    fn tick_valve_commands_stay_in_range_over_the_trace() {
        let mut r = TraceRunner::new();
        let mut n = 0u32;
        while let Some(rec) = r.step() {
            for w in [rec.words[0], rec.words[1]] {
                let u = f32::from_bits(w);
                defmt::assert!(u.is_finite() && (-1.0..=1.0).contains(&u));
            }
            n += 1;
        }
        defmt::assert_eq!(n as usize, TraceRunner::len());
    }

    /// The fixed-point tick over the trace: armed after start-up, valves within [-1, 1], the
    /// shorted transducer latched at tick 460; the whole fixed path's digest is logged for
    /// the host comparison.
    #[test]
    fn fixed_tick_over_the_trace() {
        use pam_firmware::fixed_point::tick::{
            fault, mrad_to_q16, reference_from_params, FixedTick,
        };
        let mut t = FixedTick::new(reference_from_params(pam_firmware::trace::TRACE_TICK_HZ));
        for (i, row) in SENSOR_TRACE.iter().enumerate() {
            let o = t.step(&row.fixed_frame(), mrad_to_q16(row.angle_set_mrad as i32));
            for u in o.valves_q16 {
                defmt::assert!((-65_536..=65_536).contains(&u));
            }
            if (10..460).contains(&i) {
                defmt::assert!(o.armed, "tick {=usize} not armed", i);
            }
            if i >= 460 {
                defmt::assert_eq!(o.fault, fault::PRESSURE2_IMPLAUSIBLE);
            }
        }
        let (rows, digest) = pam_firmware::trace::fixed_path_digest();
        defmt::info!(
            "on-target fixed path rows={=u32} digest={=u32:08x}",
            rows,
            digest
        );
    }
}
