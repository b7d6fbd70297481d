//! The end of a QEMU image (src/bin/qemu.rs, qemu_m0.rs, on_target.rs): success, or the
//! location of a panic / the PC of a HardFault logged over defmt and exit status 1, through the
//! semihosting exit call. [`handlers!`] defines an image's panic and HardFault handlers.

use cortex_m_rt::ExceptionFrame;
use cortex_m_semihosting::debug;

/// Exits QEMU with status 0 (1 for `failure`).
#[inline(always)]
pub fn exit(failure: bool) -> ! {
    debug::exit(if failure {
        debug::EXIT_FAILURE
    } else {
        debug::EXIT_SUCCESS
    });
    loop {
        cortex_m::asm::bkpt();
    }
}

/// Panic: log the location (not the message: see Cargo.toml) and exit with status 1.
#[inline(always)]
pub fn panicked(info: &core::panic::PanicInfo) -> ! {
    match info.location() {
        Some(l) => defmt::error!("panicked at {=str}:{=u32}", l.file(), l.line()),
        None => defmt::error!("panicked"),
    }
    exit(true)
}

/// HardFault: log the faulting PC and exit with status 1.
#[inline(always)]
#[allow(dead_code)]
pub fn hard_fault(ef: &ExceptionFrame) -> ! {
    defmt::error!("HardFault at pc={=u32:x}", ef.pc());
    exit(true)
}

/// The panic handler ([`panicked`]) and the HardFault handler ([`hard_fault`]) of an image.
#[allow(unused_macros)]
macro_rules! handlers {
    () => {
        #[panic_handler]
        fn panic(info: &core::panic::PanicInfo) -> ! {
            semihost::panicked(info)
        }

        #[cortex_m_rt::exception]
        unsafe fn HardFault(ef: &cortex_m_rt::ExceptionFrame) -> ! {
            semihost::hard_fault(ef)
        }
    };
}
#[allow(unused_imports)]
pub(crate) use handlers;
