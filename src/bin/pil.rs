//! Processor in the loop under QEMU (`netduinoplus2`, STM32F405, Cortex-M4F): the board's
//! control path (the board's sensor scaling `pam_firmware::wiring`, sequence gates,
//! `ControlTick`, persistent latch, the on/off valve driver: `pam_firmware::lockstep`)
//! driven by `host-sim pil`, one tick per exchanged frame.
//!
//! Protocol (semihosting console, `pam_firmware::stream`): the host sends one
//! [`RunConfig`] frame, then per tick one [`SensorInput`] (raw ADC and encoder counts, the
//! set-point); the firmware answers each with one [`TickRecord`] (the per-tick stream record
//! the board streams too). A frame with [`FLAG_STOP`] ends the run (exit status 0). The
//! firmware blocks on the semihosting read, so its virtual clock cannot run ahead of the
//! plant: nothing here reads a clock, `dt` is the configured tick period.
//!
//! A separate image rather than a mode of `src/bin/qemu.rs`: that image is at the 32 KiB
//! flash budget and its trace run must stay byte-for-byte as `tests/qemu_trace.rs` checks.
//!
//! defmt output (the library logs latched faults) is discarded here: the semihosting
//! console carries the binary stream. A panic or HardFault writes one text line
//! (`PIL-FAULT ...`) and exits with status 1; `-append hardfault` injects a HardFault at the
//! first tick and `-append hang` makes an image that never answers (tests of the host's
//! error paths).
#![no_std]
#![no_main]

use core::sync::atomic::{AtomicBool, Ordering};

use cortex_m_rt::{entry, exception, ExceptionFrame};
use cortex_m_semihosting::{debug, nr, syscall};

use pam_firmware::lockstep::{FirmwareNode, PinLevel};
use pam_firmware::stream::{
    RunConfig, SensorInput, TickRecord, CONFIG_LEN, FLAG_STOP, INPUT_LEN, RECORD_LEN,
};
use pam_firmware::tick::ControllerConfig;
use pam_firmware::wiring;

/// defmt sink that drops everything (the console carries the binary stream).
#[defmt::global_logger]
struct Discard;

// SAFETY: no state; every method is a no-op.
unsafe impl defmt::Logger for Discard {
    fn acquire() {}
    unsafe fn flush() {}
    unsafe fn release() {}
    unsafe fn write(_bytes: &[u8]) {}
}

/// Semihosting console handles.
fn open_tt(mode: usize) -> usize {
    let name = b":tt\0";
    // SAFETY: SYS_OPEN reads the NUL-terminated name; the buffer outlives the call.
    unsafe { syscall!(OPEN, name.as_ptr(), mode, name.len() - 1) }
}

/// Reads exactly `buf.len()` bytes; false at end of input.
fn read_exact(fd: usize, buf: &mut [u8]) -> bool {
    let mut got = 0;
    while got < buf.len() {
        let want = buf.len() - got;
        // SAFETY: SYS_READ writes at most `want` bytes into the rest of `buf`; returns the
        // number of bytes NOT read.
        let left = unsafe { syscall!(READ, fd, buf[got..].as_mut_ptr(), want) };
        if left >= want {
            return false;
        }
        got += want - left;
    }
    true
}

fn write_all(fd: usize, buf: &[u8]) -> bool {
    // SAFETY: SYS_WRITE reads `buf`; returns the number of bytes NOT written.
    unsafe { syscall!(WRITE, fd, buf.as_ptr(), buf.len()) == 0 }
}

/// Valve pins: the driver's output levels (as GPIO lines on the board).
static PINS: [AtomicBool; 4] = [
    AtomicBool::new(false),
    AtomicBool::new(false),
    AtomicBool::new(false),
    AtomicBool::new(false),
];

#[derive(Clone)]
struct Pin(usize);

impl PinLevel for Pin {
    fn is_high(&self) -> bool {
        PINS[self.0].load(Ordering::Relaxed)
    }
}

impl embedded_hal::digital::ErrorType for Pin {
    type Error = core::convert::Infallible;
}

impl embedded_hal::digital::OutputPin for Pin {
    fn set_low(&mut self) -> Result<(), Self::Error> {
        PINS[self.0].store(false, Ordering::Relaxed);
        Ok(())
    }
    fn set_high(&mut self) -> Result<(), Self::Error> {
        PINS[self.0].store(true, Ordering::Relaxed);
        Ok(())
    }
}

/// Whether the QEMU command line (`-append WORD`) ends with `word`: `hardfault` injects a
/// HardFault at the first tick, `hang` never answers (tests of the host's bounded waits).
fn cmdline_ends_with(word: &[u8]) -> bool {
    let mut buf = [0u8; 128];
    let mut block = [buf.as_mut_ptr() as usize, buf.len()];
    // SAFETY: SYS_GET_CMDLINE writes at most `block[1]` bytes into `buf` and the length back.
    let r = unsafe { cortex_m_semihosting::syscall1(nr::GET_CMDLINE, block.as_mut_ptr() as usize) };
    r == 0 && block[1] <= buf.len() && buf[..block[1]].ends_with(word)
}

fn fail(msg: &[u8]) -> ! {
    let out = open_tt(nr::open::W_APPEND);
    let _ = write_all(out, msg);
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::bkpt();
    }
}

#[entry]
fn main() -> ! {
    let inp = open_tt(nr::open::R);
    let out = open_tt(nr::open::W_TRUNC);
    let fault_at_first_tick = cmdline_ends_with(b"hardfault");
    if cmdline_ends_with(b"hang") {
        loop {
            cortex_m::asm::nop();
        }
    }

    let mut cbuf = [0u8; CONFIG_LEN];
    if !read_exact(inp, &mut cbuf) {
        fail(b"PIL-FAULT no configuration frame\n");
    }
    let Ok(cfg) = RunConfig::decode(&cbuf) else {
        fail(b"PIL-FAULT bad configuration frame\n");
    };
    let scaling = wiring::pressure_scaling();
    // The host must quantise with the board's wiring: the image converts with it.
    if cfg.pa_per_count.to_bits() != scaling.pa_per_count.to_bits()
        || cfg.offset_pa.to_bits() != scaling.offset_pa.to_bits()
        || cfg.counts_per_rev != wiring::ENCODER_COUNTS_PER_REV
    {
        fail(b"PIL-FAULT configuration frame does not match the board wiring\n");
    }
    let mut node = FirmwareNode::new(
        ControllerConfig::reference(cfg.tick_hz),
        [Pin(0), Pin(1), Pin(2), Pin(3)],
        scaling,
        wiring::ENCODER_COUNTS_PER_REV,
    );
    let mut ibuf = [0u8; INPUT_LEN];
    let mut rbuf = [0u8; RECORD_LEN];
    let mut seq: u32 = 0;
    // `as` saturates: a NaN or huge period gives 0 or u32::MAX, never a panic.
    let dt_us = (cfg.dt_s * 1.0e6 + 0.5) as u32;
    loop {
        if !read_exact(inp, &mut ibuf) {
            fail(b"PIL-FAULT input ended without a stop frame\n");
        }
        let Ok(input) = SensorInput::decode(&ibuf) else {
            fail(b"PIL-FAULT bad sensor frame (sync or checksum)\n");
        };
        if input.flags & FLAG_STOP != 0 {
            break;
        }
        if fault_at_first_tick {
            // SAFETY: deliberately faulting read (0xF000_0000 is unmapped on the STM32F405).
            let v = unsafe { core::ptr::read_volatile(0xF000_0000 as *const u32) };
            core::hint::black_box(v);
        }
        let t = node.step_raw(&input);
        let rec = TickRecord::of_tick(
            seq,
            seq.wrapping_mul(dt_us),
            input.setpoint_rad,
            input.p_counts,
            input.encoder_counts,
            &t.frame,
            &t.out,
            t.pins.map(|high| if high { 1.0 } else { 0.0 }),
        );
        rec.encode(&mut rbuf);
        if !write_all(out, &rbuf) {
            fail(b"PIL-FAULT write failed\n");
        }
        seq = seq.wrapping_add(1);
    }
    debug::exit(debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::bkpt();
    }
}

#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    fail(b"PIL-FAULT panic\n")
}

#[exception]
unsafe fn HardFault(_ef: &ExceptionFrame) -> ! {
    fail(b"PIL-FAULT HardFault\n")
}
