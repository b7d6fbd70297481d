//! The per-tick stream: one fixed-size binary record per control tick (firmware -> host), and
//! the sensor frame / configuration frames of processor-in-the-loop runs (host -> firmware).
//!
//! Portable (`no_std`, no allocation, no panics on any input): the board, the QEMU images and
//! host-sim encode and decode with the same code.
//!
//! [`TickRecord`] layout, little-endian, [`RECORD_LEN`] = 46 bytes:
//!
//! | bytes | field |
//! |---|---|
//! | 0..2 | sync `A5 5A` |
//! | 2..6 | sequence number (u32, +1 per tick, wraps): a lost record is a jump |
//! | 6..10 | time since start [us] (u32) |
//! | 10..14 | angle set-point [rad] (f32) |
//! | 14..22 | applied openings in1, ex1, in2, ex2 (u16 each, 65535 = fully open) |
//! | 22..26 | raw pressures p1, p2 [ADC counts] (u16 each, 0xFFFF = no sample) |
//! | 26..30 | raw encoder [counts] (i32, `i32::MIN` = no sample) |
//! | 30..42 | scaled p1, p2 [Pa gauge], angle [rad] (f32 each, NaN = no sample) |
//! | 42 | fault code (0 = none, else `FaultCode as u8`) |
//! | 43 | flags (bit 0: armed) |
//! | 44..46 | [`checksum16`] of bytes 2..44 |
//!
//! At 1 kHz that is 46 000 bytes/s of payload.

/// Sync bytes of a [`TickRecord`].
pub const RECORD_SYNC: [u8; 2] = [0xA5, 0x5A];
/// Bytes of one encoded [`TickRecord`].
pub const RECORD_LEN: usize = 46;
/// Sync bytes of a [`SensorInput`] frame.
pub const INPUT_SYNC: [u8; 2] = [0x5A, 0xA5];
/// Bytes of one encoded [`SensorInput`].
pub const INPUT_LEN: usize = 26;
/// Sync bytes of a [`RunConfig`] frame.
pub const CONFIG_SYNC: [u8; 2] = [0x5A, 0xC3];
/// Bytes of one encoded [`RunConfig`].
pub const CONFIG_LEN: usize = 24;
/// Raw pressure value of a missing sample.
pub const MISSING_COUNTS: u16 = 0xFFFF;
/// Raw encoder value of a missing sample.
pub const MISSING_ENCODER: i32 = i32::MIN;

/// One control tick as the firmware applied it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TickRecord {
    /// Sequence number (+1 per tick).
    pub seq: u32,
    /// Time since start [us].
    pub t_us: u32,
    /// Angle set-point [rad].
    pub setpoint_rad: f32,
    /// Applied openings in1, ex1, in2, ex2 in [0, 1] (quantised to 1/65535).
    pub openings: [f32; 4],
    /// Raw pressure ADC counts ([`MISSING_COUNTS`]: no sample).
    pub p_counts: [u16; 2],
    /// Raw encoder counts ([`MISSING_ENCODER`]: no sample).
    pub encoder_counts: i32,
    /// Scaled pressures [Pa gauge] (NaN: no sample).
    pub p_gauge_pa: [f32; 2],
    /// Scaled angle [rad] (NaN: no sample).
    pub angle_rad: f32,
    /// Latched fault code (0: none).
    pub fault: u8,
    /// The cascade computed this tick's command.
    pub armed: bool,
}

/// Fletcher-style checksum with its two sums modulo 256: the low byte (the sum of the bytes)
/// changes with every single-byte change, which the textbook modulo-255 Fletcher-16 misses
/// when a byte turns from 0x00 to 0xFF or back (0 and 255 are equal modulo 255); the high
/// byte (the sum of the running sums) weighs each byte by its position, so swapped bytes
/// are caught too.
pub fn checksum16(data: &[u8]) -> u16 {
    let (mut a, mut b) = (0u8, 0u8);
    for &x in data {
        a = a.wrapping_add(x);
        b = b.wrapping_add(a);
    }
    ((b as u16) << 8) | a as u16
}

fn opening_to_u16(u: f32) -> u16 {
    // NaN -> 0 (closed); `as` saturates.
    let v = if u > 0.0 { u } else { 0.0 };
    let v = if v < 1.0 { v } else { 1.0 };
    (v * 65535.0 + 0.5) as u16
}

fn put(buf: &mut [u8], at: usize, bytes: &[u8]) {
    buf[at..at + bytes.len()].copy_from_slice(bytes);
}

fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

/// Completes a frame whose fields are in `buf[2..len - 2]`: the sync bytes at its start,
/// the [`checksum16`] of the fields at its end.
fn seal(buf: &mut [u8], sync: [u8; 2]) {
    let end = buf.len() - 2;
    put(buf, 0, &sync);
    let c = checksum16(&buf[2..end]);
    put(buf, end, &c.to_le_bytes());
}

/// The first `len` bytes of `b` when they are a frame: long enough, `sync` at the start and
/// the checksum of bytes `2..len - 2` in the last two.
fn checked(b: &[u8], len: usize, sync: [u8; 2]) -> Result<&[u8], DecodeError> {
    let Some(b) = b.get(..len) else {
        return Err(DecodeError::Short);
    };
    if b[0..2] != sync {
        return Err(DecodeError::Sync);
    }
    if checksum16(&b[2..len - 2]) != u16_at(b, len - 2) {
        return Err(DecodeError::Checksum);
    }
    Ok(b)
}

/// Why a frame did not decode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DecodeError {
    /// Fewer bytes than a frame.
    Short,
    /// The sync bytes are wrong.
    Sync,
    /// The checksum does not match.
    Checksum,
}

impl TickRecord {
    /// Encodes into `buf`.
    pub fn encode(&self, buf: &mut [u8; RECORD_LEN]) {
        put(buf, 2, &self.seq.to_le_bytes());
        put(buf, 6, &self.t_us.to_le_bytes());
        put(buf, 10, &self.setpoint_rad.to_le_bytes());
        for (i, u) in self.openings.iter().enumerate() {
            put(buf, 14 + 2 * i, &opening_to_u16(*u).to_le_bytes());
        }
        put(buf, 22, &self.p_counts[0].to_le_bytes());
        put(buf, 24, &self.p_counts[1].to_le_bytes());
        put(buf, 26, &self.encoder_counts.to_le_bytes());
        put(buf, 30, &self.p_gauge_pa[0].to_le_bytes());
        put(buf, 34, &self.p_gauge_pa[1].to_le_bytes());
        put(buf, 38, &self.angle_rad.to_le_bytes());
        buf[42] = self.fault;
        buf[43] = self.armed as u8;
        seal(buf, RECORD_SYNC);
    }

    /// Logs the encoded record as the defmt frame `stream {=[u8]}`: the board's per-tick
    /// stream (docs/rig.md), read on the host by `host-sim capture`.
    #[cfg(feature = "defmt")]
    pub fn log(&self) {
        let mut buf = [0u8; RECORD_LEN];
        self.encode(&mut buf);
        defmt::info!("stream {=[u8]}", buf[..]);
    }

    /// Decodes one record from the start of `b`.
    pub fn decode(b: &[u8]) -> Result<Self, DecodeError> {
        let b = checked(b, RECORD_LEN, RECORD_SYNC)?;
        let f = |at| f32::from_bits(u32_at(b, at));
        let mut openings = [0.0f32; 4];
        for (i, o) in openings.iter_mut().enumerate() {
            *o = u16_at(b, 14 + 2 * i) as f32 / 65535.0;
        }
        Ok(TickRecord {
            seq: u32_at(b, 2),
            t_us: u32_at(b, 6),
            setpoint_rad: f(10),
            openings,
            p_counts: [u16_at(b, 22), u16_at(b, 24)],
            encoder_counts: u32_at(b, 26) as i32,
            p_gauge_pa: [f(30), f(34)],
            angle_rad: f(38),
            fault: b[42],
            armed: b[43] & 1 != 0,
        })
    }
}

impl TickRecord {
    /// The record of one tick: the raw readings it got, the frame the tick saw, the tick's
    /// output and the openings the valve driver applied (in1, ex1, in2, ex2; an on/off
    /// driver's pin levels as 0 or 1). This is what the board and the QEMU images call after
    /// `ControlTick::step` and the valve update.
    #[allow(clippy::too_many_arguments)]
    pub fn of_tick(
        seq: u32,
        t_us: u32,
        setpoint_rad: f32,
        p_counts: [u16; 2],
        encoder_counts: i32,
        frame: &crate::tick::io::SensorFrame,
        out: &crate::tick::io::TickOutput,
        openings: [f32; 4],
    ) -> Self {
        let nan_if_none = |v: Option<f32>| v.unwrap_or(f32::NAN);
        TickRecord {
            seq,
            t_us,
            setpoint_rad,
            openings,
            p_counts,
            encoder_counts,
            p_gauge_pa: [
                nan_if_none(frame.p1_gauge_pa),
                nan_if_none(frame.p2_gauge_pa),
            ],
            angle_rad: nan_if_none(frame.angle_rad),
            fault: out.fault.map(|f| f.code()).unwrap_or(0),
            armed: out.armed,
        }
    }
}

/// One tick of sensor data from the host (processor in the loop), in the board's raw units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorInput {
    /// Sequence number (the tick index).
    pub seq: u32,
    /// Angle set-point [rad].
    pub setpoint_rad: f32,
    /// Pressure ADC counts ([`MISSING_COUNTS`]: no sample).
    pub p_counts: [u16; 2],
    /// Encoder counts ([`MISSING_ENCODER`]: no sample).
    pub encoder_counts: i32,
    /// Bit 0/1/2: p1 / p2 / angle read as NaN (a host-side injected sensor fault);
    /// bit 3/4/5: p1 / p2 / angle delivered no new sample (a frozen sensor: the same value
    /// with the same sequence number as before); bit 7: end of run.
    pub flags: u8,
    /// MCU reset before this tick ([`RESET_NONE`], [`RESET_POWER_ON`], [`RESET_WATCHDOG`]).
    pub reset: u8,
    /// Tick period the firmware measured for this tick [s] (longer than the configured
    /// one for a late tick).
    pub dt_s: f32,
}

/// [`SensorInput::flags`]: end of the run.
pub const FLAG_STOP: u8 = 0x80;
/// [`SensorInput::flags`]: bit of channel `i` (0 = p1, 1 = p2, 2 = angle) read as NaN.
pub const FLAG_NAN_SHIFT: u8 = 0;
/// [`SensorInput::flags`]: bit of channel `i` that delivered no new sample.
pub const FLAG_STALE_SHIFT: u8 = 3;
/// [`SensorInput::reset`]: no reset.
pub const RESET_NONE: u8 = 0;
/// [`SensorInput::reset`]: power-on reset before this tick.
pub const RESET_POWER_ON: u8 = 1;
/// [`SensorInput::reset`]: watchdog reset before this tick.
pub const RESET_WATCHDOG: u8 = 2;

impl SensorInput {
    /// Encodes into `buf`.
    pub fn encode(&self, buf: &mut [u8; INPUT_LEN]) {
        put(buf, 2, &self.seq.to_le_bytes());
        put(buf, 6, &self.setpoint_rad.to_le_bytes());
        put(buf, 10, &self.p_counts[0].to_le_bytes());
        put(buf, 12, &self.p_counts[1].to_le_bytes());
        put(buf, 14, &self.encoder_counts.to_le_bytes());
        buf[18] = self.flags;
        buf[19] = self.reset;
        put(buf, 20, &self.dt_s.to_le_bytes());
        seal(buf, INPUT_SYNC);
    }

    /// Decodes one frame from the start of `b`.
    pub fn decode(b: &[u8]) -> Result<Self, DecodeError> {
        let b = checked(b, INPUT_LEN, INPUT_SYNC)?;
        Ok(SensorInput {
            seq: u32_at(b, 2),
            setpoint_rad: f32::from_bits(u32_at(b, 6)),
            p_counts: [u16_at(b, 10), u16_at(b, 12)],
            encoder_counts: u32_at(b, 14) as i32,
            flags: b[18],
            reset: b[19],
            dt_s: f32::from_bits(u32_at(b, 20)),
        })
    }
}

/// Start of a processor-in-the-loop run: the tick rate and the sensor scaling (on the board,
/// the start-up calibration's result).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RunConfig {
    /// Control tick rate [Hz].
    pub tick_hz: f32,
    /// Tick period passed to the control tick [s].
    pub dt_s: f32,
    /// Pressure scaling: Pa per ADC count.
    pub pa_per_count: f32,
    /// Pressure scaling: gauge pressure at 0 counts [Pa].
    pub offset_pa: f32,
    /// Encoder counts per joint revolution.
    pub counts_per_rev: u32,
}

impl RunConfig {
    /// Encodes into `buf`.
    pub fn encode(&self, buf: &mut [u8; CONFIG_LEN]) {
        put(buf, 2, &self.tick_hz.to_le_bytes());
        put(buf, 6, &self.dt_s.to_le_bytes());
        put(buf, 10, &self.pa_per_count.to_le_bytes());
        put(buf, 14, &self.offset_pa.to_le_bytes());
        put(buf, 18, &self.counts_per_rev.to_le_bytes());
        seal(buf, CONFIG_SYNC);
    }

    /// Decodes one frame from the start of `b`.
    pub fn decode(b: &[u8]) -> Result<Self, DecodeError> {
        let b = checked(b, CONFIG_LEN, CONFIG_SYNC)?;
        let f = |at| f32::from_bits(u32_at(b, at));
        Ok(RunConfig {
            tick_hz: f(2),
            dt_s: f(6),
            pa_per_count: f(10),
            offset_pa: f(14),
            counts_per_rev: u32_at(b, 18),
        })
    }
}

/// The sensor frame the control tick sees for a raw input: the same conversions as the board
/// ([`crate::sensors::PressureScaling::to_gauge_pa`], [`crate::sensors::counts_to_rad`]).
pub fn frame_of(
    input: &SensorInput,
    scaling: &crate::sensors::PressureScaling,
    counts_per_rev: u32,
) -> crate::tick::io::SensorFrame {
    let p = |i: usize| {
        if input.flags & (1 << i) != 0 {
            Some(f32::NAN)
        } else if input.p_counts[i] == MISSING_COUNTS {
            None
        } else {
            Some(scaling.to_gauge_pa(input.p_counts[i] as u32))
        }
    };
    let angle = if input.flags & 4 != 0 {
        Some(f32::NAN)
    } else if input.encoder_counts == MISSING_ENCODER {
        None
    } else {
        Some(crate::sensors::counts_to_rad(
            input.encoder_counts,
            counts_per_rev,
        ))
    };
    crate::tick::io::SensorFrame {
        p1_gauge_pa: p(0),
        p2_gauge_pa: p(1),
        angle_rad: angle,
    }
}

/// Finds records in a byte stream (resynchronising on the sync bytes, skipping anything
/// else, e.g. interleaved log text); calls `f` with each valid record and its byte offset.
/// Returns the number of bytes skipped between records (0 for a clean stream).
pub fn scan_records(b: &[u8], mut f: impl FnMut(usize, TickRecord)) -> usize {
    let mut i = 0;
    let mut skipped = 0;
    while i + RECORD_LEN <= b.len() {
        match TickRecord::decode(&b[i..]) {
            Ok(r) => {
                f(i, r);
                i += RECORD_LEN;
            }
            Err(_) => {
                i += 1;
                skipped += 1;
            }
        }
    }
    skipped + (b.len() - i)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> TickRecord {
        TickRecord {
            seq: 7,
            t_us: 7000,
            setpoint_rad: 0.25,
            openings: [1.0, 0.0, 0.0, 1.0],
            p_counts: [1547, MISSING_COUNTS],
            encoder_counts: -123,
            p_gauge_pa: [300_000.0, f32::NAN],
            angle_rad: -0.0966,
            fault: 0,
            armed: true,
        }
    }

    #[test]
    fn record_round_trips_and_on_off_openings_are_exact() {
        let r = sample();
        let mut b = [0u8; RECORD_LEN];
        r.encode(&mut b);
        let d = TickRecord::decode(&b).unwrap();
        assert_eq!(d.seq, 7);
        assert_eq!(d.openings, [1.0, 0.0, 0.0, 1.0]);
        assert_eq!(d.p_counts, r.p_counts);
        assert_eq!(d.encoder_counts, -123);
        assert_eq!(d.p_gauge_pa[0].to_bits(), r.p_gauge_pa[0].to_bits());
        assert!(d.p_gauge_pa[1].is_nan());
        assert_eq!(d.angle_rad.to_bits(), r.angle_rad.to_bits());
        assert!(d.armed);
    }

    #[test]
    fn every_single_byte_change_and_swap_fails_the_checksum() {
        let mut b = [0u8; RECORD_LEN];
        sample().encode(&mut b);
        for at in 2..RECORD_LEN {
            for v in 0..=255u8 {
                if v == b[at] {
                    continue;
                }
                let mut bad = b;
                bad[at] = v;
                assert_eq!(
                    TickRecord::decode(&bad),
                    Err(DecodeError::Checksum),
                    "byte {at} set to {v:#04x}"
                );
            }
        }
        for at in 2..43 {
            if b[at] != b[at + 1] {
                let mut bad = b;
                bad.swap(at, at + 1);
                assert_eq!(
                    TickRecord::decode(&bad),
                    Err(DecodeError::Checksum),
                    "swap {at}"
                );
            }
        }
        // The textbook modulo-255 Fletcher-16 misses a zero byte read as 0xFF.
        let fletcher255 = |d: &[u8]| {
            let (mut a, mut b) = (0u16, 0u16);
            for &x in d {
                a = (a + x as u16) % 255;
                b = (b + a) % 255;
            }
            (b << 8) | a
        };
        let zero = b[2..44].iter().position(|x| *x == 0).expect("a zero byte") + 2;
        let mut bad = b;
        bad[zero] = 0xFF;
        assert_eq!(fletcher255(&b[2..44]), fletcher255(&bad[2..44]));
        assert_ne!(checksum16(&b[2..44]), checksum16(&bad[2..44]));
    }

    #[test]
    fn a_flipped_bit_fails_the_checksum_and_the_scan_skips_it() {
        let mut b = [0u8; RECORD_LEN];
        sample().encode(&mut b);
        let mut bad = b;
        bad[12] ^= 0x10;
        assert_eq!(TickRecord::decode(&bad), Err(DecodeError::Checksum));
        let mut stream = [0u8; 3 * RECORD_LEN + 5];
        stream[..RECORD_LEN].copy_from_slice(&b);
        stream[RECORD_LEN..RECORD_LEN + 5].copy_from_slice(b"junk\n");
        stream[RECORD_LEN + 5..2 * RECORD_LEN + 5].copy_from_slice(&bad);
        stream[2 * RECORD_LEN + 5..].copy_from_slice(&b);
        let mut n = 0;
        scan_records(&stream, |_, r| {
            assert_eq!(r.seq, 7);
            n += 1;
        });
        assert_eq!(n, 2);
    }

    #[test]
    fn input_and_config_round_trip() {
        let i = SensorInput {
            seq: 3,
            setpoint_rad: 0.5,
            p_counts: [455, 4095],
            encoder_counts: MISSING_ENCODER,
            flags: 2,
            reset: RESET_WATCHDOG,
            dt_s: 0.0015,
        };
        let mut b = [0u8; INPUT_LEN];
        i.encode(&mut b);
        assert_eq!(SensorInput::decode(&b), Ok(i));
        let c = RunConfig {
            tick_hz: 1000.0,
            dt_s: 0.001,
            pa_per_count: 244.14062,
            offset_pa: -111_084.0,
            counts_per_rev: 8000,
        };
        let mut b = [0u8; CONFIG_LEN];
        c.encode(&mut b);
        assert_eq!(RunConfig::decode(&b), Ok(c));
        let s = crate::sensors::PressureScaling {
            pa_per_count: c.pa_per_count,
            offset_pa: c.offset_pa,
        };
        let f = frame_of(&i, &s, 8000);
        assert_eq!(f.p1_gauge_pa, Some(s.to_gauge_pa(455)));
        assert!(f.p2_gauge_pa.unwrap().is_nan());
        assert_eq!(f.angle_rad, None);
    }
}
