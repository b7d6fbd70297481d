//! FPU-less benchmark image (`thumbv6m-none-eabi`, QEMU `microbit` = nRF51822, Cortex-M0):
//! the cost of the fixed-point force law, torque model and whole fixed-point tick
//! (src/fixed_point.rs, src/fixed_point/tick.rs) where they are meant to run, next to the f32
//! law and tick in soft-float. Same method as src/bin/qemu.rs (SysTick around each call under
//! `-icount`, calibrated on a loop of known instruction count); `scripts/bench-mcu.sh` runs it.
//!
//! `cargo run -p pam-firmware --bin qemu_m0 --features pam-firmware/firmware --release
//! --target thumbv6m-none-eabi` (runner: scripts/qemu-run.sh, which picks `microbit`).
#![no_std]
#![no_main]

use core::hint::black_box;

use cortex_m::peripheral::{syst::SystClkSource, SYST};
use cortex_m_rt::{entry, exception, ExceptionFrame};
use cortex_m_semihosting::debug;
use defmt_semihosting as _;

use pam_firmware::constants::{FIXED_FORCE_LAW, FIXED_TORQUE_MODEL, FORCE_LAW};
use pam_firmware::fixed_point::tick::{mrad_to_q16, reference_from_params, FixedTick};
use pam_firmware::fixed_point::{
    pressure_pa_from_f32, q16_from_f32, AngleRad, PressurePa, VelocityRadS,
};
use pam_firmware::geometry::JointGeometry;
use pam_firmware::trace::{ControlTick, SENSOR_TRACE, TRACE_TICK_HZ};
use pam_firmware::wiring;

#[inline(always)]
fn measure<R>(f: impl FnOnce() -> R) -> (u32, R) {
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

#[entry]
fn main() -> ! {
    let mut cp = cortex_m::Peripherals::take().unwrap();
    let syst = &mut cp.SYST;
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

    let p = wiring::pressure_scaling();
    let g = JointGeometry::REFERENCE;
    // black_box: the constants are not folded into the measured code (the tick reads them
    // from its configuration too).
    let law = black_box(FIXED_FORCE_LAW);
    let (mut fx_sum, mut fx_max, mut fl_sum, mut fl_max, mut n) = (0u32, 0u32, 0u32, 0u32, 0u32);
    for row in SENSOR_TRACE.iter() {
        let f = row.frame(&p);
        let (Some(p1), Some(a)) = (f.p1_gauge_pa, f.angle_rad) else {
            continue;
        };
        let (e1, _) = g.stretches(a);
        let (Some(pq), Some(eq)) = (pressure_pa_from_f32(p1), q16_from_f32(e1)) else {
            continue;
        };
        let (pq, eq) = (black_box(pq), black_box(eq));
        let (c, r) = measure(|| law.force(black_box(pq), black_box(eq)));
        black_box(r);
        fx_sum += c;
        fx_max = fx_max.max(c);
        let (p1, e1) = (black_box(p1), black_box(e1));
        let (c, r) = measure(|| FORCE_LAW.force(black_box(p1), black_box(e1)));
        black_box(r);
        fl_sum += c;
        fl_max = fl_max.max(c);
        n += 1;
    }
    defmt::info!(
        "bench m0 force_law_fixed n={=u32} sum_counts={=u32} max_counts={=u32}",
        n,
        fx_sum,
        fx_max
    );
    defmt::info!(
        "bench m0 force_law_f32_soft n={=u32} sum_counts={=u32} max_counts={=u32}",
        n,
        fl_sum,
        fl_max
    );
    // The whole control tick (f32, in soft-float: the cascade has no fixed-point build) on
    // the M0, per armed tick of the trace: what a 1 kHz tick costs on an FPU-less core.
    let dt = 1.0 / TRACE_TICK_HZ;
    let mut tick = ControlTick::new(pam_firmware::trace::trace_config());
    let (mut t_sum, mut t_max, mut t_n) = (0u32, 0u32, 0u32);
    for row in SENSOR_TRACE.iter() {
        let frame = black_box(row.frame(&p));
        let sp = black_box(row.setpoint());
        let (c, out) = measure(|| tick.step(&frame, &sp, black_box(dt)));
        if out.armed {
            t_sum += c;
            t_n += 1;
        }
        t_max = t_max.max(c);
    }
    defmt::info!(
        "bench m0 tick_f32_soft n={=u32} sum_counts={=u32} max_counts={=u32}",
        t_n,
        t_sum,
        t_max
    );
    // The fixed-point torque model (forward and inverse) and the whole fixed-point tick
    // (src/fixed_point/tick.rs: raw counts -> valve commands), per armed tick of the trace.
    // The tick's configuration is pre-scaled once here (f64 soft-float, start-up only).
    let mut ftick = FixedTick::new(reference_from_params(TRACE_TICK_HZ));
    let model = black_box(FIXED_TORQUE_MODEL);
    let (mut ft_sum, mut ft_max, mut ft_n) = (0u32, 0u32, 0u32);
    let (mut tf_sum, mut tf_max, mut ti_sum, mut ti_max) = (0u32, 0u32, 0u32, 0u32);
    for row in SENSOR_TRACE.iter() {
        let frame = black_box(row.fixed_frame());
        let sp = black_box(mrad_to_q16(row.angle_set_mrad as i32));
        let (c, out) = measure(|| ftick.step(&frame, sp));
        if !out.armed {
            continue;
        }
        ft_sum += c;
        ft_max = ft_max.max(c);
        ft_n += 1;
        let a = black_box(AngleRad::from_bits(out.angle_q16));
        let v = black_box(VelocityRadS::from_bits(out.velocity_q16));
        let dp = black_box(PressurePa::from_bits(
            (out.p_set_pa[1] - out.p_set_pa[0]) / 2,
        ));
        let (c, t) = measure(|| model.torque_nm(black_box(a), black_box(v), black_box(dp)));
        tf_sum += c;
        tf_max = tf_max.max(c);
        let t = black_box(t);
        let (c, r) = measure(|| model.activation(black_box(t), black_box(a), black_box(v)));
        black_box(r);
        ti_sum += c;
        ti_max = ti_max.max(c);
    }
    defmt::info!(
        "bench m0 tick_fixed n={=u32} sum_counts={=u32} max_counts={=u32}",
        ft_n,
        ft_sum,
        ft_max
    );
    defmt::info!(
        "bench m0 torque_fixed_forward n={=u32} sum_counts={=u32} max_counts={=u32}",
        ft_n,
        tf_sum,
        tf_max
    );
    defmt::info!(
        "bench m0 torque_fixed_inverse n={=u32} sum_counts={=u32} max_counts={=u32}",
        ft_n,
        ti_sum,
        ti_max
    );
    // The fixed-point path over the whole trace, hashed: tests/qemu_trace.rs compares it with
    // the host run of the same function bit for bit.
    let (rows, hash) = pam_firmware::trace::fixed_path_digest();
    defmt::info!("fixed path rows={=u32} digest={=u32:08x}", rows, hash);
    debug::exit(debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::bkpt();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    match info.location() {
        Some(l) => defmt::error!("panicked at {=str}:{=u32}", l.file(), l.line()),
        None => defmt::error!("panicked"),
    }
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::bkpt();
    }
}

#[exception]
unsafe fn HardFault(ef: &ExceptionFrame) -> ! {
    defmt::error!("HardFault at pc={=u32:x}", ef.pc());
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::bkpt();
    }
}
