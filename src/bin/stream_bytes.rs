//! Measures what one stream record costs on the defmt wire (`scripts/stream-bytes.sh`; feature `stream-bytes`):
//! replays the embedded sensor trace through the control tick under QEMU netduinoplus2,
//! logging exactly the board's per-tick record (`TickRecord::of_tick` and `TickRecord::log`,
//! as `src/bin/board.rs` does) and nothing else, then exits.
//! defmt-semihosting and defmt-rtt carry the same encoded frames (defmt's rzCOBS encoder
//! runs before the transport), so the bytes on semihosting stdout per record are the bytes
//! per tick the RTT up channel must carry.
#![no_std]
#![no_main]

use cortex_m_rt::{entry, exception, ExceptionFrame};
use cortex_m_semihosting::debug;
use defmt_semihosting as _;

use pam_firmware::stream::{TickRecord, MISSING_COUNTS, MISSING_ENCODER};
use pam_firmware::tick::{ControlTick, ControllerConfig};
use pam_firmware::trace::{MISSING_ADC, SENSOR_TRACE, TRACE_TICK_HZ};
use pam_firmware::valves::ValveOpenings;
use pam_firmware::wiring;

#[entry]
fn main() -> ! {
    let mut tick = ControlTick::new(ControllerConfig::reference(TRACE_TICK_HZ));
    let scaling = wiring::pressure_scaling();
    let us_per_tick = (1.0e6 / TRACE_TICK_HZ) as u32;
    for (i, row) in SENSOR_TRACE.iter().enumerate() {
        let frame = row.frame(&scaling);
        let sp = row.setpoint();
        let out = tick.step(&frame, &sp, 1.0 / TRACE_TICK_HZ);
        let o = ValveOpenings::from_command(&out.valves);
        tick.valves_applied(&o);
        let counts = |adc: u16| {
            if adc == MISSING_ADC {
                MISSING_COUNTS
            } else {
                adc
            }
        };
        let encoder_counts = if row.encoder == pam_firmware::trace::MISSING_ENCODER {
            MISSING_ENCODER
        } else {
            row.encoder as i32
        };
        let rec = TickRecord::of_tick(
            i as u32,
            (i as u32).wrapping_mul(us_per_tick),
            sp.angle_rad,
            [counts(row.p1_adc), counts(row.p2_adc)],
            encoder_counts,
            &frame,
            &out,
            [o.u_in1, o.u_ex1, o.u_in2, o.u_ex2],
        );
        rec.log();
    }
    debug::exit(debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::nop();
    }
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::nop();
    }
}

#[exception]
unsafe fn HardFault(_ef: &ExceptionFrame) -> ! {
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::nop();
    }
}
