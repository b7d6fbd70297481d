//! Cycle counting on the QEMU benchmark images (src/bin/qemu.rs with `mcu-bench`,
//! src/bin/qemu_m0.rs): SysTick (core clock) read around each call under `-icount`, calibrated
//! on a loop of known instruction count.

use core::hint::black_box;

use cortex_m::peripheral::{syst::SystClkSource, SYST};

/// SysTick counts elapsed while `f` runs (24-bit down counter, wraps once at most).
#[inline(always)]
pub fn measure<R>(f: impl FnOnce() -> R) -> (u32, R) {
    let a = SYST::get_current();
    // black_box: the result must exist before the second read (a pure computation could
    // otherwise be scheduled after it and not be measured).
    let r = black_box(f());
    let b = SYST::get_current();
    (a.wrapping_sub(b) & 0x00FF_FFFF, r)
}

/// Calibration: exactly 2 instructions per iteration (`subs`, `bne`).
#[inline(never)]
fn spin(iterations: u32) {
    // SAFETY: a register-only loop.
    unsafe {
        core::arch::asm!(
            "1:",
            "subs {0}, {0}, #1",
            "bne 1b",
            inout(reg) iterations => _,
            options(nomem, nostack),
        );
    }
}

/// Starts SysTick on the core clock (full 24-bit reload) and logs the calibration line
/// (`bench calib`: instructions, counts of the spin loop, counts of an empty call).
pub fn start_and_calibrate(syst: &mut SYST) {
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(0x00FF_FFFF);
    syst.clear_current();
    syst.enable_counter();

    const CAL_ITER: u32 = 100_000;
    let (cal, _) = measure(|| spin(black_box(CAL_ITER)));
    let (empty, _) = measure(|| black_box(0u32));
    defmt::info!(
        "bench calib insns={=u32} counts={=u32} empty_counts={=u32}",
        2 * CAL_ITER,
        cal,
        empty
    );
}

/// How many measurements, their sum and the largest, in SysTick counts.
#[derive(Default)]
pub struct Tally {
    pub n: u32,
    pub sum: u32,
    pub max: u32,
}

impl Tally {
    pub fn add(&mut self, counts: u32) {
        self.add_counted(counts, true);
    }

    /// A control tick: it counts in `n` and `sum` (the mean over the armed ticks) only when
    /// `counted`, in `max` always (the worst tick of the trace, armed or not).
    pub fn add_counted(&mut self, counts: u32, counted: bool) {
        if counted {
            self.n += 1;
            self.sum += counts;
        }
        self.max = self.max.max(counts);
    }

    /// Logs `bench <label> n=.. sum_counts=.. max_counts=..` (read by scripts/bench-mcu.sh).
    pub fn log(&self, label: &str) {
        defmt::info!(
            "bench {=str} n={=u32} sum_counts={=u32} max_counts={=u32}",
            label,
            self.n,
            self.sum,
            self.max
        );
    }
}
