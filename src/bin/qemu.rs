//! The firmware under QEMU (`cargo qemu`): `netduinoplus2` (STM32F405, Cortex-M4F).
//!
//! 1. Replays the embedded raw sensor trace (`tests/traces/qemu_sensor_trace.csv`) through sensor
//!    scaling and the control tick, logging every tick's outputs as f32 bit patterns plus a
//!    running FNV-1a hash (`tests/qemu_trace.rs` requires them bit-for-bit equal to a host run).
//! 2. Reports the stack high-water mark (the free RAM is painted at start-up).
//! 3. With the `mcu-bench` feature only (`scripts/bench-mcu.sh`; not in the shipped image):
//!    benchmarks: SysTick counts around the full control tick, the
//!    force law alone and a calibration loop of a known instruction count. Under
//!    `qemu-system-arm -icount shift=0` virtual time advances exactly with the instructions
//!    executed, so counts convert to instructions; without `-icount` they are meaningless.
//!
//! Fault injection (tests/qemu_trace.rs checks the exit status): `cargo qemu -- -append panic`
//! panics, `-append hardfault` reads unmapped memory; both must end with exit status 1.
//!
//! defmt goes out over semihosting (decode with `defmt-print -e <elf>`, which
//! `scripts/qemu-run.sh` does). The exit status reaches QEMU through the semihosting exit call:
//! 0 at the end, 1 on a panic (location logged) or a HardFault (PC logged).
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use defmt_semihosting as _;

use pam_firmware::trace::{TraceRunner, TRACE_TICK_HZ};

#[path = "common/semihost.rs"]
mod semihost;
#[cfg(feature = "mcu-bench")]
#[path = "common/systick.rs"]
mod systick;

/// Pattern of the painted (never used) stack.
const PAINT: u32 = 0xDEAD_C0DE;
/// Words below the current stack pointer left unpainted (the painting function's own frame).
const PAINT_MARGIN_WORDS: usize = 64;

extern "C" {
    static mut _stack_end: u32;
    static mut _stack_start: u32;
}

fn stack_bounds() -> (usize, usize) {
    // Only the addresses of the linker symbols are taken.
    (
        core::ptr::addr_of!(_stack_end) as usize,
        core::ptr::addr_of!(_stack_start) as usize,
    )
}

/// Paints the free stack (from the end of .bss/.uninit up to just below the current frame).
/// Returns the bytes from the top of RAM to the painted region: a measured high-water mark
/// below this figure only says "at most this much".
#[inline(never)]
fn paint_stack() -> u32 {
    let (lo, _) = stack_bounds();
    let sp = cortex_m::register::msp::read() as usize;
    let hi = sp - PAINT_MARGIN_WORDS * 4;
    let mut p = lo;
    while p < hi {
        // SAFETY: [lo, hi) is RAM between the statics and the live stack; nothing uses it yet.
        unsafe { core::ptr::write_volatile(p as *mut u32, PAINT) };
        p += 4;
    }
    let (_, top) = stack_bounds();
    (top - hi) as u32
}

/// Bytes of stack ever used: from the top of RAM down to the lowest overwritten painted word.
fn stack_used_bytes() -> u32 {
    let (lo, top) = stack_bounds();
    let mut p = lo;
    // SAFETY: reads of RAM inside the painted region.
    while p < top && unsafe { core::ptr::read_volatile(p as *const u32) } == PAINT {
        p += 4;
    }
    (top - p) as u32
}

/// The fault requested on the semihosting command line (`-append panic|hardfault`), if any.
#[inline(never)]
fn injected_fault() -> Option<&'static str> {
    let mut buf = [0u8; 256];
    let mut block = [buf.as_mut_ptr() as usize, buf.len()];
    // SAFETY: SYS_GET_CMDLINE writes at most `block[1]` bytes into `buf` and the length back
    // into `block[1]`; both outlive the call.
    let r = unsafe {
        cortex_m_semihosting::syscall1(
            cortex_m_semihosting::nr::GET_CMDLINE,
            block.as_mut_ptr() as usize,
        )
    };
    if r != 0 || block[1] > buf.len() {
        return None;
    }
    let line = &buf[..block[1]];
    ["panic", "hardfault"]
        .into_iter()
        .find(|w| line.ends_with(w.as_bytes()))
}

/// The benchmarks (`scripts/bench-mcu.sh`): built only with the `mcu-bench` feature, so the
/// shipped image carries the trace replay and the stack report only.
#[cfg(feature = "mcu-bench")]
#[cfg_attr(feature = "mcu-bench-arm", allow(dead_code, unused_imports))]
mod bench {
    use core::hint::black_box;
    use core::sync::atomic::{AtomicU32, Ordering};

    use cortex_m::peripheral::SYST;

    use crate::systick::{measure, start_and_calibrate, Tally};

    use pam_firmware::constants::{FIXED_FORCE_LAW, FORCE_LAW};
    use pam_firmware::tick::{ControllerConfig, StartRamp};
    use pam_firmware::trace::{force_law_inputs, ControlTick, SENSOR_TRACE, TRACE_TICK_HZ};
    use pam_firmware::valves::{OnOffPwmConfig, OnOffValves};
    use pam_firmware::wiring;

    /// SysTick counts elapsed while `f` runs, for an `f` that ends in volatile stores (its
    /// work cannot be moved past them, nor they past the second read).
    #[inline(always)]
    fn measure_effectful<R>(f: impl FnOnce() -> R) -> (u32, R) {
        let a = SYST::get_current();
        let r = f();
        let b = SYST::get_current();
        (a.wrapping_sub(b) & 0x00FF_FFFF, r)
    }

    pub fn bench(syst: &mut SYST) {
        start_and_calibrate(syst);

        #[cfg(feature = "mcu-bench-arm")]
        {
            bench_arm_ticks();
            return;
        }
        #[cfg(not(feature = "mcu-bench-arm"))]
        bench_one_dof();
    }

    /// The 1-DOF rows: the f32 tick with and without the start phase, the force laws.
    #[cfg(not(feature = "mcu-bench-arm"))]
    fn bench_one_dof() {
        bench_ticks("tick", pam_firmware::trace::trace_config());
        // The same trace with the reference start phase: its first ~300 armed ticks ramp the
        // pressure ceiling from the trace's pressures to 600 kPa.
        bench_ticks(
            "start tick",
            ControllerConfig {
                start: StartRamp::REFERENCE,
                ..pam_firmware::trace::trace_config()
            },
        );
        bench_force_law();
        bench_force_law_fixed();
        // With the hybrid volume compiled in (`volume-fnn`, its own image): the tick with the
        // pressure feed-forward on, analytical (polynomial volume) and hybrid (learned
        // volume), and the network's inference alone.
        #[cfg(feature = "volume-fnn")]
        {
            let ff_on = |fnn| {
                let mut c = pam_firmware::trace::trace_config();
                c.pressure_ff.enabled = true;
                c.volume_fnn = fnn;
                c
            };
            bench_ticks("ff tick", ff_on(None));
            // The same with the outer loops at half the tick rate and the feed-forward
            // evaluated on every second tick (config/controller.toml [rates],
            // config/pressure_ff.toml update_period_ticks).
            bench_ticks("ff split tick", {
                let mut c = ff_on(None);
                c.outer_period_ticks = 2;
                c.pressure_ff.update_period_ticks = 2;
                c
            });
            bench_ticks("split tick", {
                let mut c = pam_firmware::trace::trace_config();
                c.outer_period_ticks = 2;
                c
            });
            bench_ticks(
                "hybrid tick",
                ff_on(Some(&pam_firmware::constants::VOLUME_FNN)),
            );
            bench_volume_fnn();
        }
    }

    /// The hybrid volume network alone (one muscle: value and eq. 9 rate), at the trace's
    /// contractions and pressures, rates from the trace's differences.
    #[cfg(feature = "volume-fnn")]
    #[inline(never)]
    fn bench_volume_fnn() {
        let p = wiring::pressure_scaling();
        let g = pam_firmware::geometry::JointGeometry::REFERENCE;
        let net = &pam_firmware::constants::VOLUME_FNN;
        let mut t = Tally::default();
        let (mut e_prev, mut p_prev) = (g.initial_contraction, 0.0f32);
        for row in SENSOR_TRACE.iter() {
            let f = row.frame(&p);
            let (Some(p1), Some(a)) = (f.p1_gauge_pa, f.angle_rad) else {
                continue;
            };
            let (e1, _) = g.contractions(a);
            let p_abs = p1 + pam_firmware::constants::P_ATM_PA;
            let e_rate = (e1 - e_prev) * TRACE_TICK_HZ;
            let p_rate = (p_abs - p_prev) * TRACE_TICK_HZ;
            (e_prev, p_prev) = (e1, p_abs);
            let x = black_box((e1, e_rate, p_abs, p_rate));
            let (c, r) = measure(|| net.volume_and_rate(x.0, x.1, x.2, x.3));
            black_box(r);
            t.add(c);
        }
        t.log("volume_fnn");
    }

    #[cfg(feature = "mcu-bench-arm")]
    /// The 3-DOF arm's tick (three joint ticks, the rigid-body feed-forward and three on/off
    /// valve drivers) on the arm's sensor trace, each tick measured alone.
    #[inline(never)]
    fn bench_arm_ticks() {
        use pam_firmware::arm::{ArmFrame, ArmSetpoint, ArmTick};
        use pam_firmware::trace::ARM3_SENSOR_TRACE;
        let p = wiring::pressure_scaling();
        let dt = 1.0 / TRACE_TICK_HZ;
        let mut arm = ArmTick::new(pam_firmware::trace::arm3_trace_config());
        let pwm = OnOffPwmConfig::REFERENCE;
        let mut v1 = OnOffValves::new(
            BenchPin::<0>,
            BenchPin::<1>,
            BenchPin::<2>,
            BenchPin::<3>,
            pwm,
        );
        let mut v2 = OnOffValves::new(
            BenchPin::<4>,
            BenchPin::<5>,
            BenchPin::<6>,
            BenchPin::<7>,
            pwm,
        );
        let mut v3 = OnOffValves::new(
            BenchPin::<8>,
            BenchPin::<9>,
            BenchPin::<10>,
            BenchPin::<11>,
            pwm,
        );
        let mut t = Tally::default();
        for row in ARM3_SENSOR_TRACE.iter() {
            let frame = black_box(ArmFrame {
                joints: [row[0].frame(&p), row[1].frame(&p), row[2].frame(&p)],
            });
            let sp = black_box(ArmSetpoint {
                angles_rad: [0, 1, 2].map(|j| row[j].setpoint().angle_rad),
            });
            let (c, out) = measure_effectful(|| {
                let out = arm.step(&frame, &sp, black_box(dt));
                let Ok(o) = v1.apply_switched(&out.joints[0].valves);
                arm.valves_switched(0, o);
                let Ok(o) = v2.apply_switched(&out.joints[1].valves);
                arm.valves_switched(1, o);
                let Ok(o) = v3.apply_switched(&out.joints[2].valves);
                arm.valves_switched(2, o);
                out
            });
            let out = black_box(out);
            t.add_counted(c, out.fault.is_none() && out.joints.iter().all(|j| j.armed));
        }
        defmt::info!(
            "bench arm tick n={=u32} sum_counts={=u32} max_counts={=u32} ticks={=u32}",
            t.n,
            t.sum,
            t.max,
            ARM3_SENSOR_TRACE.len() as u32
        );
    }

    /// Full control tick, each tick measured alone (frame built before the measurement).
    /// Not inlined: `scripts/bench-mcu.sh --breakdown` attributes the instructions executed
    /// between this function's entry and `bench_force_law`'s to symbols.
    #[inline(never)]
    fn bench_ticks(label: &str, cfg: ControllerConfig) {
        let p = wiring::pressure_scaling();
        let dt = 1.0 / TRACE_TICK_HZ;
        let mut tick = ControlTick::new(cfg);
        // The valve update is part of the measured tick: the reference on/off driver (tick-level
        // PWM, minimum on-time) writing four pins, each a volatile store like a GPIO BSRR write.
        let mut valves = OnOffValves::new(
            BenchPin::<0>,
            BenchPin::<1>,
            BenchPin::<2>,
            BenchPin::<3>,
            OnOffPwmConfig::REFERENCE,
        );
        let mut t = Tally::default();
        for row in SENSOR_TRACE.iter() {
            let frame = black_box(row.frame(&p));
            let sp = black_box(row.setpoint());
            // No black_box around the result here: the valve writes are volatile stores, which
            // keep the whole tick before the second SysTick read.
            let (c, out) = measure_effectful(|| {
                let out = tick.step(&frame, &sp, black_box(dt));
                // The bench pins cannot fail (`Infallible`).
                let Ok(o) = valves.apply_switched(&out.valves);
                tick.valves_switched(o);
                out
            });
            let out = black_box(out);
            t.add_counted(c, out.armed);
        }
        t.log(label);
    }

    /// A valve output for the tick benchmark: set/reset are single volatile stores of a
    /// constant mask, as a GPIO BSRR write through the HAL's typed pins (one type per pin, the
    /// mask known at compile time).
    struct BenchPin<const K: u32>;

    static BENCH_GPIO: AtomicU32 = AtomicU32::new(0);

    impl<const K: u32> embedded_hal::digital::ErrorType for BenchPin<K> {
        type Error = core::convert::Infallible;
    }

    impl<const K: u32> embedded_hal::digital::OutputPin for BenchPin<K> {
        fn set_low(&mut self) -> Result<(), Self::Error> {
            BENCH_GPIO.store(1 << (K + 16), Ordering::Relaxed);
            Ok(())
        }
        fn set_high(&mut self) -> Result<(), Self::Error> {
            BENCH_GPIO.store(1 << K, Ordering::Relaxed);
            Ok(())
        }
    }

    /// Force law alone (f32), at the trace's pressures and the stretches of its angles.
    #[inline(never)]
    fn bench_force_law() {
        let mut t = Tally::default();
        for (p1, e1, _) in force_law_inputs() {
            let (p1, e1) = (black_box(p1), black_box(e1));
            let (c, r) = measure(|| FORCE_LAW.force(p1, e1));
            black_box(r);
            t.add(c);
        }
        t.log("force_law_f32");
    }

    /// Fixed-point force law (src/fixed_point.rs, `constants::FIXED_FORCE_LAW`) at the same
    /// inputs as [`bench_force_law`], quantised before the measurement (the FPU-less build gets
    /// integer readings).
    #[inline(never)]
    fn bench_force_law_fixed() {
        let law = FIXED_FORCE_LAW;
        let (mut t, mut off) = (Tally::default(), 0u32);
        for (p1, e1, fixed) in force_law_inputs() {
            let Some((pq, eq)) = fixed else {
                continue;
            };
            let (pq, eq) = (black_box(pq), black_box(eq));
            let (c, r) = measure(|| law.force(pq, eq));
            let r = black_box(r);
            // Sanity: a real evaluation, within 0.1 N of the f32 law (fixed_point.rs's bound).
            let f32_law = FORCE_LAW.force(p1, e1);
            if r.flags != f32_law.flags
                || libm::fabsf(r.force_n.to_num::<f32>() - f32_law.force_n) > 0.1
            {
                off += 1;
            }
            t.add(c);
        }
        defmt::info!(
            "bench force_law_fixed n={=u32} sum_counts={=u32} max_counts={=u32} off_by_more_than_0.1N={=u32}",
            t.n,
            t.sum,
            t.max,
            off
        );
    }
}

#[entry]
fn main() -> ! {
    let unpainted = paint_stack();
    match injected_fault() {
        Some("panic") => panic!("injected panic"),
        Some(_) => {
            defmt::warn!("injecting a HardFault (read of unmapped memory)");
            // SAFETY: deliberately faulting read (0xF000_0000 is unmapped on the STM32F405).
            let v = unsafe { core::ptr::read_volatile(0xF000_0000 as *const u32) };
            defmt::error!("unmapped read returned {=u32:x}", v);
        }
        None => {}
    }

    defmt::info!(
        "pam-firmware qemu: replaying {=usize} ticks at {=f32} Hz",
        TraceRunner::len(),
        TRACE_TICK_HZ
    );
    let mut runner = TraceRunner::new();
    let mut ticks = 0u32;
    while let Some(r) = runner.step() {
        let w = r.words;
        defmt::info!(
            "tick={=u32} out={=u32:x},{=u32:x},{=u32:x},{=u32:x},{=u32:x},{=u32:x},{=u32:x},{=u32:x},{=u32:x} hash={=u32:x}",
            r.tick, w[0], w[1], w[2], w[3], w[4], w[5], w[6], w[7], w[8], r.hash
        );
        ticks += 1;
    }
    defmt::info!(
        "trace done ticks={=u32} digest={=u32:x}",
        ticks,
        runner.hash()
    );

    #[cfg(feature = "mcu-bench")]
    bench::bench(&mut cortex_m::Peripherals::take().unwrap().SYST);

    // After everything ran: the deepest the stack ever got (main, the tick, defmt, bench).
    defmt::info!(
        "stack_used_bytes={=u32} unpainted_top_bytes={=u32}",
        stack_used_bytes(),
        unpainted
    );
    semihost::exit(false)
}

semihost::handlers!();
