//! STM32F4 backend of [`crate::latch`]: the record in the 4 KiB backup SRAM (retained over
//! every reset, and over power-off with a backup battery on VBAT), the reset cause from the
//! RCC flags. Board builds only (feature `board`).
//!
//! What the board calls, first thing in `main` (before the clock tree, so a brown-out in
//! the clock set-up already finds the latch):
//!
//! ```ignore
//! let (storage, reset) = pam_firmware::latch_bkpsram::init();
//! let (mut latch, boot) = pam_firmware::latch::PersistentLatch::boot(storage, reset);
//! let mut tick = ControlTick::new(cfg);
//! if let BootDecision::Safe(record) = boot { tick.restore_latch(&record); }
//! // every tick, after `tick.step(..)`:
//! latch.update(tick.latch_record());
//! // after the operator's `tick.reset()` returned true:
//! latch.cleared();
//! ```

// Register access to PWR/RCC bits the HAL does not wrap (backup domain, reset flags) and the
// backup SRAM itself: raw pointers, documented at each use.
#![allow(unsafe_code)]

use stm32f4xx_hal::pac;

use crate::latch::{LatchStorage, ResetCause, ENCODER_WORDS, RECORD_WORDS};

/// Base address of the backup SRAM (RM0090 section 2.3, memory map: 0x4002_4000, 4 KiB).
const BKPSRAM_BASE: usize = 0x4002_4000;

/// The record at the start of the backup SRAM.
pub struct BackupSram {
    _private: (),
}

/// Enables the backup SRAM (PWR clock, backup-domain write access, backup SRAM clock, the
/// backup regulator so the content survives on VBAT), reads and clears the reset flags.
/// Call once at start-up.
pub fn init() -> (BackupSram, ResetCause) {
    // SAFETY: called once at start-up before the HAL owns RCC/PWR; read-modify-writes of
    // single enable bits (PWREN, BKPSRAMEN, DBP, BRE) and of the reset-flag register, which no
    // other code touches.
    let rcc = unsafe { &*pac::RCC::ptr() };
    let pwr = unsafe { &*pac::PWR::ptr() };
    let reset = ResetCause::from_rcc_csr(rcc.csr().read().bits());
    rcc.csr().modify(|_, w| w.rmvf().set_bit());
    rcc.apb1enr().modify(|_, w| w.pwren().set_bit());
    pwr.cr().modify(|_, w| w.dbp().set_bit());
    rcc.ahb1enr().modify(|_, w| w.bkpsramen().set_bit());
    pwr.csr().modify(|_, w| w.bre().set_bit());
    // The backup regulator is ready within a few microseconds; bounded wait.
    let mut n = 0u32;
    while pwr.csr().read().brr().bit_is_clear() && n < 100_000 {
        n += 1;
    }
    (BackupSram { _private: () }, reset)
}

impl LatchStorage for BackupSram {
    fn read(&self) -> [u32; RECORD_WORDS] {
        let mut w = [0u32; RECORD_WORDS];
        for (i, x) in w.iter_mut().enumerate() {
            // SAFETY: word-aligned addresses inside the enabled 4 KiB backup SRAM.
            *x = unsafe { core::ptr::read_volatile((BKPSRAM_BASE as *const u32).add(i)) };
        }
        w
    }

    fn write(&mut self, words: &[u32; RECORD_WORDS]) {
        for (i, x) in words.iter().enumerate() {
            // SAFETY: as in `read`; backup-domain write access was enabled by `init`.
            unsafe { core::ptr::write_volatile((BKPSRAM_BASE as *mut u32).add(i), *x) };
        }
    }
}

/// The kept encoder count (`latch::encoder_words`), in the backup SRAM words right after the
/// latch record.
pub struct EncoderKeep {
    _private: (),
}

impl BackupSram {
    /// The encoder words' handle (the backup SRAM is enabled: `init` made `self`).
    pub fn encoder_keep(&self) -> EncoderKeep {
        EncoderKeep { _private: () }
    }
}

impl EncoderKeep {
    const BASE: *mut u32 = (BKPSRAM_BASE + 4 * RECORD_WORDS) as *mut u32;

    /// The stored words.
    pub fn read(&self) -> [u32; ENCODER_WORDS] {
        let mut w = [0u32; ENCODER_WORDS];
        for (i, x) in w.iter_mut().enumerate() {
            // SAFETY: word-aligned addresses inside the enabled 4 KiB backup SRAM, after the
            // record's words.
            *x = unsafe { core::ptr::read_volatile(Self::BASE.add(i)) };
        }
        w
    }

    /// Stores the words (two volatile stores: call every tick).
    #[inline]
    pub fn write(&mut self, words: [u32; ENCODER_WORDS]) {
        for (i, x) in words.iter().enumerate() {
            // SAFETY: as in `read`; backup-domain write access was enabled by `init`.
            unsafe { core::ptr::write_volatile(Self::BASE.add(i), *x) };
        }
    }
}
