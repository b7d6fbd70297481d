//! The fault latch across resets: a small record in storage that survives a reset (the
//! STM32F4 backup SRAM on the board, [`crate::latch_bkpsram`]), and the boot decision.
//!
//! Boot rule: **every reset but a power-on with a clean record boots into the safe state.**
//!
//! | reset cause | stored record | boot |
//! |---|---|---|
//! | power-on | valid, no fault | armed (normal start) |
//! | power-on | valid, with a fault | safe state, the stored fault is the cause |
//! | power-on | missing or corrupt (checksum) | safe state ([`FaultCode::ResetLatched`]) |
//! | watchdog, brown-out, software, pin, lock-up, unknown | any | safe state |
//!
//! A brown-out (valve inrush), a software reset or a watchdog reset in the middle of a fault
//! therefore never re-arms the joint by itself: only the operator's explicit reset, with
//! every cause gone ([`crate::tick::ControlTick::reset`]), writes a clean record again
//! ([`PersistentLatch::cleared`]). A power-on with a missing record (a board without backup
//! battery loses the backup SRAM when unpowered) also starts in the safe state: that is the
//! conservative reading of "clean".
//!
//! Record (four 32-bit words): magic, cause code and vent flags, the set of faults seen,
//! CRC-32 (IEEE 802.3, reflected, the zlib one) of the first three words' little-endian
//! bytes.

use crate::safety::{FaultCode, FaultSet};

/// Where the record lives (backup SRAM, flash, a host buffer in tests).
pub trait LatchStorage {
    /// The stored words (whatever is there: the checksum decides whether it is a record).
    fn read(&self) -> [u32; RECORD_WORDS];
    /// Stores the words.
    fn write(&mut self, words: &[u32; RECORD_WORDS]);
}

/// Number of 32-bit words of a record.
pub const RECORD_WORDS: usize = 4;

/// First word of a record ("PAML" in ASCII, version 1 in the low byte of word 1).
pub const MAGIC: u32 = 0x5041_4D4C;
const VERSION: u32 = 1;

/// Why the MCU (re)started, from the reset-cause flags of the chip.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ResetCause {
    /// Power-on / power-down reset.
    PowerOn,
    /// Brown-out (supply dip, e.g. valve inrush).
    BrownOut,
    /// Independent or window watchdog.
    Watchdog,
    /// Software reset (`SYSRESETREQ`).
    Software,
    /// The reset pin.
    Pin,
    /// Low-power management or lock-up reset.
    LowPower,
    /// No flag set or an unknown combination.
    Unknown,
}

impl ResetCause {
    /// The reset cause from the STM32F4 `RCC_CSR` flags (RM0090 section 7.3.21: bit 31
    /// LPWRRSTF, 30 WWDGRSTF, 29 IWDGRSTF, 28 SFTRSTF, 27 PORRSTF, 26 PINRSTF, 25 BORRSTF).
    ///
    /// A power-on sets POR and BOR (and PIN: every reset pulses the pin), a brown-out sets BOR
    /// and PIN, every other source sets its own flag and PIN: decided in the order power-on,
    /// brown-out, watchdog, software, low-power, pin. No flag (flags cleared and never set
    /// again) is `Unknown`.
    pub fn from_rcc_csr(csr: u32) -> ResetCause {
        let bit = |n: u32| csr >> n & 1 != 0;
        if bit(27) {
            ResetCause::PowerOn
        } else if bit(25) {
            ResetCause::BrownOut
        } else if bit(29) || bit(30) {
            ResetCause::Watchdog
        } else if bit(28) {
            ResetCause::Software
        } else if bit(31) {
            ResetCause::LowPower
        } else if bit(26) {
            ResetCause::Pin
        } else {
            ResetCause::Unknown
        }
    }
}

/// Words of the kept encoder count ([`encoder_words`]).
pub const ENCODER_WORDS: usize = 2;
const ENCODER_KEY: u32 = 0xA5A5_5A5A;

/// The encoder count as two words for retained memory (the count, and its complement xor a
/// key: zeroed or random memory does not pass as a count). Stored every tick, it carries the
/// joint angle across a reset that is not a power-on (the encoder counter restarts at 0).
pub const fn encoder_words(count: i32) -> [u32; ENCODER_WORDS] {
    [count as u32, !(count as u32) ^ ENCODER_KEY]
}

/// The encoder count to restore at boot: the kept count after any reset but a power-on (the
/// joint may have been moved while unpowered: the pose at power-on is the zero), None when
/// the words are not a kept count.
pub fn encoder_at_boot(words: [u32; ENCODER_WORDS], reset: ResetCause) -> Option<i32> {
    if reset == ResetCause::PowerOn || words[1] != !words[0] ^ ENCODER_KEY {
        return None;
    }
    Some(words[0] as i32)
}

/// The operator's reset request from a push button sampled once per tick: a request is made
/// once, when the button has been held for `hold_ticks` consecutive ticks (a bounce or a
/// brush does not re-arm the joint), and not again until it was released.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ResetButton {
    hold_ticks: u32,
    held: u32,
}

impl ResetButton {
    /// A button that must be held `hold_ticks` ticks (at least 1).
    pub const fn new(hold_ticks: u32) -> Self {
        ResetButton {
            hold_ticks: if hold_ticks == 0 { 1 } else { hold_ticks },
            held: 0,
        }
    }

    /// One tick's button level; true in the tick the request is made.
    pub fn update(&mut self, pressed: bool) -> bool {
        if !pressed {
            self.held = 0;
            return false;
        }
        if self.held <= self.hold_ticks {
            self.held += 1;
        }
        self.held == self.hold_ticks
    }
}

/// The latch content.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LatchRecord {
    /// The latched cause (None = armed, a clean record).
    pub cause: Option<FaultCode>,
    /// Every fault seen since the last reset.
    pub seen: FaultSet,
    /// Muscles vented by the over-pressure escalation.
    pub vented: [bool; 2],
}

impl LatchRecord {
    /// A clean record (no fault).
    pub const CLEAN: LatchRecord = LatchRecord {
        cause: None,
        seen: FaultSet::EMPTY,
        vented: [false; 2],
    };

    /// The storage words of the record.
    pub fn encode(&self) -> [u32; RECORD_WORDS] {
        let code = self.cause.map_or(0, |c| c.code() as u32);
        let w1 =
            VERSION | code << 8 | (self.vented[0] as u32) << 16 | (self.vented[1] as u32) << 17;
        let w = [MAGIC, w1, self.seen.bits()];
        [w[0], w[1], w[2], crc32_words(&w)]
    }

    /// The record stored in `words`, or None when it is not a valid record (wrong magic,
    /// version or checksum, unknown fault code).
    pub fn decode(words: &[u32; RECORD_WORDS]) -> Option<LatchRecord> {
        if words[0] != MAGIC || crc32_words(&[words[0], words[1], words[2]]) != words[3] {
            return None;
        }
        if words[1] & 0xff != VERSION || words[1] >> 18 != 0 {
            return None;
        }
        let code = ((words[1] >> 8) & 0xff) as u8;
        let cause = match code {
            0 => None,
            c => Some(FaultCode::from_code(c)?),
        };
        if words[2] != FaultSet::from_bits(words[2]).bits() {
            return None;
        }
        Some(LatchRecord {
            cause,
            seen: FaultSet::from_bits(words[2]),
            vented: [words[1] >> 16 & 1 != 0, words[1] >> 17 & 1 != 0],
        })
    }
}

/// What the firmware does at boot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BootDecision {
    /// Start normally (armed once every channel delivered).
    Arm,
    /// Start in the safe state with this cause latched (and these faults seen, these
    /// muscles vented); the operator's reset re-arms.
    Safe(LatchRecord),
}

/// The boot rule of the [module documentation](self).
pub fn boot_decision(reset: ResetCause, stored: Option<LatchRecord>) -> BootDecision {
    match (reset, stored) {
        (ResetCause::PowerOn, Some(r)) if r.cause.is_none() => BootDecision::Arm,
        (_, Some(r)) if r.cause.is_some() => BootDecision::Safe(r),
        (_, Some(r)) => BootDecision::Safe(LatchRecord {
            cause: Some(FaultCode::ResetLatched),
            seen: r.seen.union(FaultSet::of(FaultCode::ResetLatched)),
            vented: r.vented,
        }),
        (_, None) => BootDecision::Safe(LatchRecord {
            cause: Some(FaultCode::ResetLatched),
            seen: FaultSet::of(FaultCode::ResetLatched),
            vented: [false; 2],
        }),
    }
}

/// The latch over a storage: boot decision at start-up, a write whenever the latched state
/// changes (one comparison per tick otherwise).
pub struct PersistentLatch<S: LatchStorage> {
    storage: S,
    last: LatchRecord,
}

impl<S: LatchStorage> PersistentLatch<S> {
    /// Reads the stored record and decides how to boot. The storage then holds the boot
    /// state (a safe boot is stored at once, so a second reset before the first tick is
    /// still safe).
    pub fn boot(mut storage: S, reset: ResetCause) -> (Self, BootDecision) {
        let stored = LatchRecord::decode(&storage.read());
        let decision = boot_decision(reset, stored);
        let last = match decision {
            BootDecision::Arm => LatchRecord::CLEAN,
            BootDecision::Safe(r) => r,
        };
        storage.write(&last.encode());
        (PersistentLatch { storage, last }, decision)
    }

    /// Stores `now` when it differs from the stored record (call once per tick with the
    /// tick's latched state, e.g. [`crate::tick::ControlTick::latch_record`]).
    #[inline]
    pub fn update(&mut self, now: LatchRecord) {
        if now != self.last {
            self.storage.write(&now.encode());
            self.last = now;
        }
    }

    /// Stores a clean record (after the operator's successful reset).
    pub fn cleared(&mut self) {
        self.update(LatchRecord::CLEAN);
    }

    /// The record last stored.
    pub fn stored(&self) -> LatchRecord {
        self.last
    }

    /// The storage back.
    pub fn release(self) -> S {
        self.storage
    }
}

/// CRC-32 (IEEE, reflected, init and final xor 0xFFFFFFFF) of the words' little-endian
/// bytes. Bitwise: a few hundred instructions, run only when the record changes.
pub fn crc32_words(words: &[u32]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for w in words {
        for b in w.to_le_bytes() {
            crc ^= b as u32;
            for _ in 0..8 {
                let mask = (crc & 1).wrapping_neg();
                crc = (crc >> 1) ^ (0xEDB8_8320 & mask);
            }
        }
    }
    !crc
}

/// A storage in RAM (host tests, and boards without a retained memory: then every boot is
/// a power-on with a missing record, i.e. safe).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RamStorage(pub [u32; RECORD_WORDS]);

impl LatchStorage for RamStorage {
    fn read(&self) -> [u32; RECORD_WORDS] {
        self.0
    }
    fn write(&mut self, words: &[u32; RECORD_WORDS]) {
        self.0 = *words;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every reset cause but a power-on.
    const NOT_POWER_ON: [ResetCause; 6] = [
        ResetCause::BrownOut,
        ResetCause::Watchdog,
        ResetCause::Software,
        ResetCause::Pin,
        ResetCause::LowPower,
        ResetCause::Unknown,
    ];

    /// The record of a latched `cause` (the only fault seen), with the vent state `vented`.
    fn faulted(cause: FaultCode, vented: [bool; 2]) -> LatchRecord {
        LatchRecord {
            cause: Some(cause),
            seen: FaultSet::of(cause),
            vented,
        }
    }

    #[test]
    fn crc_matches_the_standard_check_value() {
        // The bitwise reference (CRC-32/ISO-HDLC, byte at a time), apart from the word version.
        let crc32_bytes = |bytes: &[u8]| {
            let mut crc = 0xFFFF_FFFFu32;
            for &b in bytes {
                crc ^= b as u32;
                for _ in 0..8 {
                    let mask = (crc & 1).wrapping_neg();
                    crc = (crc >> 1) ^ (0xEDB8_8320 & mask);
                }
            }
            !crc
        };
        // The check value of "123456789" (9 bytes: not word aligned).
        assert_eq!(crc32_bytes(b"123456789"), 0xCBF4_3926);
        // The word version on "1234" equals the byte loop on the same bytes.
        let w = u32::from_le_bytes(*b"1234");
        assert_eq!(crc32_words(&[w]), crc32_bytes(b"1234"));
        // zlib's crc32(b"1234") = 0x9BE3E0A3.
        assert_eq!(crc32_words(&[w]), 0x9BE3_E0A3);
    }

    #[test]
    fn records_round_trip_and_corruption_is_detected() {
        let mut seen = FaultSet::EMPTY;
        seen.insert(FaultCode::InletStuckOpen1);
        seen.insert(FaultCode::OverPressure2);
        let r = LatchRecord {
            cause: Some(FaultCode::InletStuckOpen1),
            seen,
            vented: [false, true],
        };
        let w = r.encode();
        assert_eq!(LatchRecord::decode(&w), Some(r));
        assert_eq!(
            LatchRecord::decode(&LatchRecord::CLEAN.encode()),
            Some(LatchRecord::CLEAN)
        );
        // Every single-bit flip is caught.
        for i in 0..RECORD_WORDS {
            for bit in 0..32 {
                let mut c = w;
                c[i] ^= 1 << bit;
                assert_eq!(LatchRecord::decode(&c), None, "word {i} bit {bit}");
            }
        }
        assert_eq!(LatchRecord::decode(&[0; 4]), None);
        assert_eq!(LatchRecord::decode(&[u32::MAX; 4]), None);
    }

    #[test]
    fn only_a_power_on_with_a_clean_record_arms() {
        let clean = Some(LatchRecord::CLEAN);
        let record = faulted(FaultCode::SupplyLost, [false; 2]);
        let faulted = Some(record);
        assert_eq!(boot_decision(ResetCause::PowerOn, clean), BootDecision::Arm);
        for cause in NOT_POWER_ON {
            match boot_decision(cause, clean) {
                BootDecision::Safe(r) => assert_eq!(r.cause, Some(FaultCode::ResetLatched)),
                d => panic!("{cause:?}: {d:?}"),
            }
            assert_eq!(boot_decision(cause, faulted), BootDecision::Safe(record));
        }
        assert_eq!(
            boot_decision(ResetCause::PowerOn, faulted),
            BootDecision::Safe(record)
        );
        match boot_decision(ResetCause::PowerOn, None) {
            BootDecision::Safe(r) => assert_eq!(r.cause, Some(FaultCode::ResetLatched)),
            d => panic!("{d:?}"),
        }
    }

    #[test]
    fn latch_survives_a_brown_out_and_clears_only_on_reset() {
        // Power-on with a clean record: armed; a fault is stored when it happens.
        let (mut latch, d) =
            PersistentLatch::boot(RamStorage(LatchRecord::CLEAN.encode()), ResetCause::PowerOn);
        assert_eq!(d, BootDecision::Arm);
        let fault = faulted(FaultCode::InletStuckOpen2, [false; 2]);
        latch.update(fault);
        // Brown-out: the storage survives; the board boots into the safe state.
        let (latch2, d) = PersistentLatch::boot(latch.release(), ResetCause::BrownOut);
        assert_eq!(d, BootDecision::Safe(fault));
        // Even a power-on afterwards stays safe (the record holds the fault)...
        let (mut latch3, d) = PersistentLatch::boot(latch2.release(), ResetCause::PowerOn);
        assert_eq!(d, BootDecision::Safe(fault));
        // ... until the operator's reset writes a clean record.
        latch3.cleared();
        let (_, d) = PersistentLatch::boot(latch3.release(), ResetCause::PowerOn);
        assert_eq!(d, BootDecision::Arm);
        // A software reset right after a clean record is still safe.
        let (_, d) = PersistentLatch::boot(
            RamStorage(LatchRecord::CLEAN.encode()),
            ResetCause::Software,
        );
        assert!(matches!(d, BootDecision::Safe(_)));
    }

    #[test]
    fn reset_cause_from_the_rcc_flags() {
        const POR: u32 = 1 << 27;
        const BOR: u32 = 1 << 25;
        const PIN: u32 = 1 << 26;
        // What the chip sets for each source (every reset pulses the pin); RMVF (bit 24) and
        // the reserved bits do not count.
        for (csr, cause) in [
            (POR | BOR | PIN, ResetCause::PowerOn),
            (BOR | PIN, ResetCause::BrownOut),
            (1 << 29 | PIN, ResetCause::Watchdog),
            (1 << 30 | PIN, ResetCause::Watchdog),
            (1 << 28 | PIN, ResetCause::Software),
            (1 << 31 | PIN, ResetCause::LowPower),
            (PIN, ResetCause::Pin),
            (0, ResetCause::Unknown),
            (1 << 24 | 0xff, ResetCause::Unknown),
        ] {
            assert_eq!(ResetCause::from_rcc_csr(csr), cause, "{csr:#x}");
        }
    }

    #[test]
    fn reset_button_requests_once_per_press_after_the_hold_time() {
        let mut b = ResetButton::new(3);
        // Bounces shorter than the hold time never request.
        for level in [true, true, false, true, false, true, true, false] {
            assert!(!b.update(level));
        }
        // Held: the third tick requests, then nothing until released.
        assert!(!b.update(true));
        assert!(!b.update(true));
        assert!(b.update(true));
        for _ in 0..10 {
            assert!(!b.update(true));
        }
        assert!(!b.update(false));
        assert!(!b.update(true));
        assert!(!b.update(true));
        assert!(b.update(true));
        // A zero hold time is one tick.
        let mut b = ResetButton::new(0);
        assert!(b.update(true));
        assert!(!b.update(true));
    }

    /// The boot table of the module documentation, every row, through the storage (the
    /// path the board takes): encode, decode, decide.
    #[test]
    fn boot_table_through_the_storage() {
        let faulted = faulted(FaultCode::InletStuckOpen1, [true, false]);
        let stores: [(&str, [u32; RECORD_WORDS]); 4] = [
            ("clean", LatchRecord::CLEAN.encode()),
            ("fault", faulted.encode()),
            ("missing", [0; RECORD_WORDS]),
            ("corrupt", {
                let mut w = LatchRecord::CLEAN.encode();
                w[2] ^= 1;
                w
            }),
        ];
        for cause in core::iter::once(ResetCause::PowerOn).chain(NOT_POWER_ON) {
            for (name, words) in stores {
                let (latch, d) = PersistentLatch::boot(RamStorage(words), cause);
                let armed = d == BootDecision::Arm;
                assert_eq!(
                    armed,
                    cause == ResetCause::PowerOn && name == "clean",
                    "{cause:?} with a {name} record"
                );
                match d {
                    BootDecision::Arm => assert_eq!(latch.stored(), LatchRecord::CLEAN),
                    BootDecision::Safe(r) => {
                        // The stored fault stays the cause; otherwise ResetLatched.
                        let want = if name == "fault" {
                            FaultCode::InletStuckOpen1
                        } else {
                            FaultCode::ResetLatched
                        };
                        assert_eq!(r.cause, Some(want), "{cause:?} with a {name} record");
                        if name == "fault" {
                            assert_eq!(r.vented, [true, false]);
                        }
                        // The safe boot is stored at once.
                        assert_eq!(LatchRecord::decode(&latch.release().0), Some(r));
                    }
                }
            }
        }
    }

    #[test]
    fn the_encoder_count_survives_every_reset_but_power_on() {
        for count in [0, 1, -1, 8000, -123_456, i32::MAX, i32::MIN] {
            let w = encoder_words(count);
            assert_eq!(encoder_at_boot(w, ResetCause::PowerOn), None);
            for cause in NOT_POWER_ON {
                assert_eq!(encoder_at_boot(w, cause), Some(count));
            }
            // Any single-bit flip is refused.
            for i in 0..ENCODER_WORDS {
                for bit in 0..32 {
                    let mut c = w;
                    c[i] ^= 1 << bit;
                    assert_eq!(encoder_at_boot(c, ResetCause::Watchdog), None);
                }
            }
        }
        // Zeroed or erased memory is not a count.
        assert_eq!(encoder_at_boot([0, 0], ResetCause::Watchdog), None);
        assert_eq!(encoder_at_boot([u32::MAX; 2], ResetCause::Watchdog), None);
    }
}
