//! Small f32 kernels shared by the tick's modules.

// The one inline-assembly block of the tick (the FPU's square root, see `sqrtf`).
#![allow(unsafe_code)]

/// Square root, correctly rounded (IEEE 754), as `libm::sqrtf`. On the Cortex-M4F (hard-float
/// ARM targets) the FPU's `VSQRT.F32` (also correctly rounded: the same bits for every input)
/// in place of libm's integer implementation: 7 instructions instead of about 50. Stable Rust
/// has no `f32::sqrt` in `core`, and its `sreg` operands need the `vfp2` feature (double
/// precision, which the M4F lacks), so the value passes through core registers and `s15` is
/// saved and restored around the instruction.
#[inline(always)]
pub fn sqrtf(x: f32) -> f32 {
    #[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
    {
        let r: u32;
        // SAFETY: FPU register moves and one VSQRT; `s15` is restored, no memory is touched
        // and no flags are changed (VSQRT sets only FPSCR's cumulative exception bits, which
        // nothing reads).
        unsafe {
            core::arch::asm!(
                "vmov {t}, s15",
                "vmov s15, {x}",
                "vsqrt.f32 s15, s15",
                "vmov {r}, s15",
                "vmov s15, {t}",
                t = out(reg) _,
                x = in(reg) x.to_bits(),
                r = lateout(reg) r,
                options(pure, nomem, nostack, preserves_flags)
            );
        }
        f32::from_bits(r)
    }
    #[cfg(not(all(target_arch = "arm", target_abi = "eabihf")))]
    {
        libm::sqrtf(x)
    }
}

/// `lo <= x <= hi`: false for NaN (every comparison with NaN is), and for the infinities
/// with finite bounds, so `within(x, 0.0, f32::MAX)` is "finite and not negative". One
/// out-of-line copy for the parameter checks: inlined `is_finite` tests cost flash on the
/// board image.
#[inline(never)]
pub fn within(x: f32, lo: f32, hi: f32) -> bool {
    x >= lo && x <= hi
}

#[cfg(test)]
mod tests {
    /// The host build runs libm; the MCU build's VSQRT is checked against it on target by
    /// the closed-loop digests (scripts/bench-mcu.sh replays the same trace). Here: exact
    /// squares and the correctly rounded result of non-squares (checked in f64).
    #[test]
    fn sqrtf_is_correctly_rounded() {
        for i in 0..10_000u32 {
            let x = i as f32 * 0.37 + 1e-3;
            let r = super::sqrtf(x);
            let exact = (x as f64).sqrt();
            let below = f32::from_bits(r.to_bits() - 1) as f64;
            let above = f32::from_bits(r.to_bits() + 1) as f64;
            let err = (r as f64 - exact).abs();
            assert!(
                err <= (below - exact).abs() && err <= (above - exact).abs(),
                "{x}"
            );
        }
        assert_eq!(super::sqrtf(16.0), 4.0);
    }
}
