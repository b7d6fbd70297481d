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

use cortex_m_rt::entry;
use defmt_semihosting as _;

use pam_firmware::constants::{FIXED_FORCE_LAW, FIXED_TORQUE_MODEL, FORCE_LAW};
use pam_firmware::fixed_point::tick::{mrad_to_q16, reference_from_params, FixedTick};
use pam_firmware::fixed_point::{AngleRad, PressurePa, VelocityRadS};
use pam_firmware::trace::{force_law_inputs, ControlTick, SENSOR_TRACE, TRACE_TICK_HZ};
use pam_firmware::wiring;

#[path = "common/semihost.rs"]
mod semihost;
#[path = "common/systick.rs"]
mod systick;
use systick::{measure, Tally};

#[entry]
fn main() -> ! {
    let mut cp = cortex_m::Peripherals::take().unwrap();
    systick::start_and_calibrate(&mut cp.SYST);

    let p = wiring::pressure_scaling();
    // black_box: the constants are not folded into the measured code (the tick reads them
    // from its configuration too).
    let law = black_box(FIXED_FORCE_LAW);
    let (mut fx, mut fl) = (Tally::default(), Tally::default());
    for (p1, e1, fixed) in force_law_inputs() {
        let Some((pq, eq)) = fixed else {
            continue;
        };
        let (pq, eq) = (black_box(pq), black_box(eq));
        let (c, r) = measure(|| law.force(black_box(pq), black_box(eq)));
        black_box(r);
        fx.add(c);
        let (p1, e1) = (black_box(p1), black_box(e1));
        let (c, r) = measure(|| FORCE_LAW.force(black_box(p1), black_box(e1)));
        black_box(r);
        fl.add(c);
    }
    fx.log("m0 force_law_fixed");
    fl.log("m0 force_law_f32_soft");
    // The whole control tick (f32, in soft-float: the cascade has no fixed-point build) on
    // the M0, per armed tick of the trace: what a 1 kHz tick costs on an FPU-less core.
    let dt = 1.0 / TRACE_TICK_HZ;
    let mut tick = ControlTick::new(pam_firmware::trace::trace_config());
    let mut tf32 = Tally::default();
    for row in SENSOR_TRACE.iter() {
        let frame = black_box(row.frame(&p));
        let sp = black_box(row.setpoint());
        let (c, out) = measure(|| tick.step(&frame, &sp, black_box(dt)));
        tf32.add_counted(c, out.armed);
    }
    tf32.log("m0 tick_f32_soft");
    // The fixed-point torque model (forward and inverse) and the whole fixed-point tick
    // (src/fixed_point/tick.rs: raw counts -> valve commands), per armed tick of the trace.
    // The tick's configuration is pre-scaled once here (f64 soft-float, start-up only).
    let mut ftick = FixedTick::new(reference_from_params(TRACE_TICK_HZ));
    let model = black_box(FIXED_TORQUE_MODEL);
    let (mut ft, mut tf, mut ti) = (Tally::default(), Tally::default(), Tally::default());
    for row in SENSOR_TRACE.iter() {
        let frame = black_box(row.fixed_frame());
        let sp = black_box(mrad_to_q16(row.angle_set_mrad as i32));
        let (c, out) = measure(|| ftick.step(&frame, sp));
        if !out.armed {
            continue;
        }
        ft.add(c);
        let a = black_box(AngleRad::from_bits(out.angle_q16));
        let v = black_box(VelocityRadS::from_bits(out.velocity_q16));
        let dp = black_box(PressurePa::from_bits(
            (out.p_set_pa[1] - out.p_set_pa[0]) / 2,
        ));
        let (c, t) = measure(|| model.torque_nm(black_box(a), black_box(v), black_box(dp)));
        tf.add(c);
        let t = black_box(t);
        let (c, r) = measure(|| model.activation(black_box(t), black_box(a), black_box(v)));
        black_box(r);
        ti.add(c);
    }
    ft.log("m0 tick_fixed");
    tf.log("m0 torque_fixed_forward");
    ti.log("m0 torque_fixed_inverse");
    // The fixed-point path over the whole trace, hashed: tests/qemu_trace.rs compares it with
    // the host run of the same function bit for bit.
    let (rows, hash) = pam_firmware::trace::fixed_path_digest();
    defmt::info!("fixed path rows={=u32} digest={=u32:08x}", rows, hash);
    semihost::exit(false)
}

semihost::handlers!();
