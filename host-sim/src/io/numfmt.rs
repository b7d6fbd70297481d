//! Fast number formatting and parsing for the CSV files, identical to the standard library:
//! byte-identical to `{}` (shortest round-trip) and `{:.N}` (fixed decimals), and the same
//! `f64` as `str::parse` for every plain decimal.
//!
//! Formatting with `core::fmt` costs about 60 ns per number, most of it in the general
//! exact algorithms; a recording of 20 000 rows has 200 000 numbers. Recordings hold
//! values of a few digits (time stamps, valve openings, readings to a micro-unit), for which
//! an integer path is exact: the value scaled by a power of ten is rounded to an integer and
//! printed digit by digit. Whenever that path cannot prove its result equal to the standard
//! library's (a rounding tie within one unit in the last place, more than 15 significant
//! digits, NaN, infinities, negative zero), the standard formatter is used instead, so the
//! output never changes. The property tests compare both on random and edge values.

use std::io::Write as _;

/// Powers of ten exactly representable in `f64` and `u64`, up to 10^9.
const POW10: [u64; 10] = [
    1,
    10,
    100,
    1_000,
    10_000,
    100_000,
    1_000_000,
    10_000_000,
    100_000_000,
    1_000_000_000,
];

/// Largest scaled value taken by the integer path: 10^15, so that the printed decimal has
/// at most 15 significant digits (below f64's 15.95 digits of precision).
const MAX_SCALED: f64 = 1e15;

/// 2^52: from it up to 2^53 the doubles are the integers.
const TWO_POW_52: f64 = 4_503_599_627_370_496.0;

/// `x` (`0 <= x < 2^52`) rounded to the nearest integer, ties to even, as a double and as an
/// integer, without a conversion instruction (the baseline x86-64 target has no rounding
/// instruction, and Rust's saturating `as` conversions cost a few compares each): `x + 2^52`
/// lies where the doubles are the integers, so the addition rounds `x` to one, and that
/// double's mantissa bits are the integer. Callers refuse values within an ulp of a tie, so
/// ties-to-even and `f64::round`'s half-away-from-zero never differ on what they print.
#[inline(always)]
fn round_even(x: f64) -> (f64, u64) {
    debug_assert!((0.0..TWO_POW_52).contains(&x));
    let y = x + TWO_POW_52;
    (y - TWO_POW_52, y.to_bits() - TWO_POW_52.to_bits())
}

/// Room [`fixed_into`] and [`shortest_into`] need: a sign, 15 digits, a point, 9 decimals.
pub const NUMBER_BYTES: usize = 32;

/// Appends `v` as `format!("{v:.decimals$}")` would (`decimals` <= 9).
pub fn push_fixed(buf: &mut Vec<u8>, v: f64, decimals: usize) {
    let mut tmp = [0u8; NUMBER_BYTES];
    match fixed_into(&mut tmp, v, decimals) {
        Some(k) => buf.extend_from_slice(&tmp[..k]),
        // The standard library's exact algorithm (ties, huge values, non-finite).
        None => {
            let _ = write!(buf, "{v:.decimals$}");
        }
    }
}

/// Writes `v` as `format!("{v:.decimals$}")` would (`decimals` <= 9) at the start of `out`
/// (at least [`NUMBER_BYTES`] long) and returns the number of bytes, when the integer path
/// can prove its result; `None` otherwise (then [`push_fixed`] takes the exact algorithm).
#[inline]
pub fn fixed_into(out: &mut [u8], v: f64, decimals: usize) -> Option<usize> {
    // One instance per number of decimals: the divisions by 10^decimals are by constants.
    match decimals {
        0 => fixed_into_const::<0>(out, v),
        1 => fixed_into_const::<1>(out, v),
        2 => fixed_into_const::<2>(out, v),
        3 => fixed_into_const::<3>(out, v),
        4 => fixed_into_const::<4>(out, v),
        5 => fixed_into_const::<5>(out, v),
        6 => fixed_into_const::<6>(out, v),
        7 => fixed_into_const::<7>(out, v),
        8 => fixed_into_const::<8>(out, v),
        9 => fixed_into_const::<9>(out, v),
        _ => None,
    }
}

/// [`fixed_into`] with `D` decimals (for a caller whose number of decimals is a constant).
#[inline(always)]
pub fn fixed_into_const<const D: usize>(out: &mut [u8], v: f64) -> Option<usize> {
    let scale = POW10[D];
    let x = v.abs() * scale as f64;
    // Also refuses NaN and the infinities.
    if !(x < MAX_SCALED) {
        return None;
    }
    let (r, n) = round_even(x);
    // `x` carries at most half an ulp of error from the multiplication; away from a tie by
    // more than that, rounding `x` and rounding the exact product agree. `x - r` is exact,
    // and `0.5 - |x - r|` is the distance of `x` from the nearest tie.
    let ulp = f64::from_bits(x.to_bits() + 1) - x;
    if !(0.5 - (x - r).abs() > ulp) {
        return None;
    }
    let mut k = 0;
    if v.is_sign_negative() {
        out[0] = b'-';
        k = 1;
    }
    let int = n / scale;
    k += put_u64(&mut out[k..], int);
    if D > 0 {
        out[k] = b'.';
        put_padded(&mut out[k + 1..k + 1 + D], n - int * scale);
        k += 1 + D;
    }
    Some(k)
}

/// Largest |time stamp| [s] [`time_to_ns`] rounds: its nanoseconds stay below 2^53, where
/// every integer is a double (9e6 s, 104 days).
const MAX_ROUNDED_TIME_S: f64 = 9.0e6;

/// A time stamp [s] as the files write it: rounded to the nanosecond, so that the float noise
/// of `k * dt` or of summed steps (`6.0 * 0.005` is 0.030000000000000002) does not reach the
/// file (nor the slow path of the formatter). The sample periods of this product are at least
/// a microsecond (the firmware ticks at most at 10 kHz, `sweep torque --dt-s` from 1e-6 s),
/// so a stamp moves by at most 0.05 % of a step. Beyond [`MAX_ROUNDED_TIME_S`], and NaN or
/// infinities: `t_s` unchanged.
#[inline]
pub fn time_to_ns(t_s: f64) -> f64 {
    let ns = t_s * 1e9;
    if ns.abs() < MAX_ROUNDED_TIME_S * 1e9 {
        ns.round() / 1e9
    } else {
        t_s
    }
}

/// Appends `v` as `format!("{v}")` would (the shortest decimal that reads back as `v`).
pub fn push_shortest(buf: &mut Vec<u8>, v: f64) {
    let mut tmp = [0u8; NUMBER_BYTES];
    match shortest_into(&mut tmp, v) {
        Some(k) => buf.extend_from_slice(&tmp[..k]),
        None => {
            let _ = write!(buf, "{v}");
        }
    }
}

/// Writes `v` as `format!("{v}")` would at the start of `out` (at least [`NUMBER_BYTES`]
/// long) and returns the number of bytes, when `v` is a decimal of at most 9 fractional
/// digits and 15 significant ones; `None` otherwise (then [`push_shortest`] takes the
/// standard formatter).
#[inline]
pub fn shortest_into(out: &mut [u8], v: f64) -> Option<usize> {
    // A decimal with at most 9 fractional digits and 15 significant digits that reads back
    // as `v` is the shortest one: two different decimals of at most 15 significant digits
    // never read back as the same f64, so the standard library's shortest output has the
    // same value, and `{}` prints it without exponent and without trailing zeros.
    if !v.is_finite() || (v == 0.0 && v.is_sign_negative()) {
        return None;
    }
    // The usual valve openings.
    if v == 0.0 || v == 1.0 {
        out[0] = if v == 0.0 { b'0' } else { b'1' };
        return Some(1);
    }
    let a = v.abs();
    // Below 10^12 the three-decimal step writes an integer as the integer step would (its
    // fraction is then 0), so the integer step is only needed above.
    if a >= 1e12 {
        let r = shortest_with::<0>(out, v, a)?;
        if r.is_some() {
            return r;
        }
    }
    let r = shortest_with::<3>(out, v, a)?;
    if r.is_some() {
        return r;
    }
    let r = shortest_with::<6>(out, v, a)?;
    if r.is_some() {
        return r;
    }
    shortest_with::<9>(out, v, a)?
}

/// One step of [`shortest_into`]: `|v| = a` as a decimal of `D` fractional digits.
/// `None`: too large for the integer path (give up); `Some(None)`: not with `D` digits.
#[inline(always)]
fn shortest_with<const D: usize>(out: &mut [u8], v: f64, a: f64) -> Option<Option<usize>> {
    let scale = POW10[D];
    let x = a * scale as f64;
    if x >= MAX_SCALED {
        return None;
    }
    // Ties-to-even here: at a tie no integer `n` has `n / 10^D == a` (for an `n` that has,
    // the product `x` is within 0.25 of it), so both roundings answer "not with `D` digits".
    let (r, n) = round_even(x);
    // `r` and `scale` are exact, so the quotient is the correctly rounded value of the
    // decimal n / 10^D: exactly what parsing that decimal gives.
    if r / scale as f64 != a {
        return Some(None);
    }
    let mut k = 0;
    if v < 0.0 {
        out[0] = b'-';
        k = 1;
    }
    let int = n / scale;
    k += put_u64(&mut out[k..], int);
    let mut frac = n - int * scale;
    if frac != 0 {
        // Without the trailing zeros.
        let mut width = D;
        while frac % 10 == 0 {
            frac /= 10;
            width -= 1;
        }
        out[k] = b'.';
        put_padded(&mut out[k + 1..k + 1 + width], frac);
        k += 1 + width;
    }
    Some(Some(k))
}

/// The value of a plain decimal field (`[-]digits[.digits]`, at most 15 digits, nothing
/// else), exactly what `str::parse::<f64>` returns; `None` for anything else (the caller
/// then uses `str::parse`, which handles exponents, whitespace, long mantissas and errors).
///
/// With at most 15 digits the mantissa `m` is an exact integer below 2^53 and `10^k`
/// (k <= 15) is exact, so the one division `m / 10^k` is the correctly rounded value of the
/// decimal: the fast path of Clinger's algorithm, which the standard parser takes too.
pub fn parse_plain_decimal(field: &[u8]) -> Option<f64> {
    const POW10_F: [f64; 16] = [
        1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15,
    ];
    let (negative, digits) = match field.split_first() {
        Some((b'-', rest)) => (true, rest),
        _ => (false, field),
    };
    let mut m: u64 = 0;
    let mut n_digits = 0usize;
    let mut frac_digits = 0usize;
    let mut seen_point = false;
    for &b in digits {
        match b {
            b'0'..=b'9' => {
                m = m * 10 + u64::from(b - b'0');
                n_digits += 1;
                if n_digits > 15 {
                    return None;
                }
                frac_digits += usize::from(seen_point);
            }
            b'.' if !seen_point => seen_point = true,
            _ => return None,
        }
    }
    // "", "-", ".", "5." and ".5" go to the standard parser (which accepts the last two).
    if n_digits == 0 || (seen_point && (frac_digits == 0 || frac_digits == n_digits)) {
        return None;
    }
    let v = m as i64 as f64 / POW10_F[frac_digits];
    Some(if negative { -v } else { v })
}

/// Writes the decimal digits of `n` at the start of `out`; the number of digits.
#[inline(always)]
fn put_u64(out: &mut [u8], n: u64) -> usize {
    // The integer parts of recorded values: one or two digits, most often.
    if n < 10 {
        out[0] = b'0' + n as u8;
        return 1;
    }
    if n < 100 {
        out[..2].copy_from_slice(&DIGIT_PAIRS[2 * n as usize..2 * n as usize + 2]);
        return 2;
    }
    let mut digits = 3;
    while digits < 20 && n >= POW10_U64[digits] {
        digits += 1;
    }
    put_padded(&mut out[..digits], n);
    digits
}

/// Powers of ten up to 10^19.
const POW10_U64: [u64; 20] = {
    let mut p = [1u64; 20];
    let mut i = 1;
    while i < 20 {
        p[i] = p[i - 1] * 10;
        i += 1;
    }
    p
};

/// The digit pairs "00" to "99".
const DIGIT_PAIRS: [u8; 200] = {
    let mut t = [0u8; 200];
    let mut i = 0;
    while i < 100 {
        t[2 * i] = b'0' + (i / 10) as u8;
        t[2 * i + 1] = b'0' + (i % 10) as u8;
        i += 1;
    }
    t
};

/// Writes `n` (< 10^out.len()) into all of `out` as digits, zero-padded on the left (two
/// digits per division).
#[inline(always)]
fn put_padded(out: &mut [u8], mut n: u64) {
    let mut i = out.len();
    while i >= 2 {
        let d = (n % 100) as usize;
        n /= 100;
        out[i - 2..i].copy_from_slice(&DIGIT_PAIRS[2 * d..2 * d + 2]);
        i -= 2;
    }
    if i == 1 {
        out[0] = b'0' + (n % 10) as u8;
    }
}

/// The run of ASCII digits of `bytes` from `i` appended to `m` (`m * 10^k + run`, wrapping
/// past 19 digits; with `VALUE` false, `m` is left as it is): `(m, end of the run)`. Byte by
/// byte, sixteen bytes at a time where sixteen are left (one bounds check for them; the
/// loop over them is unrolled). A word-at-a-time (SWAR) version, fewer instructions, took
/// 2.4-2.6 ms per pass over the 20 s fixture's fields against 1.4-1.5 ms for the byte loop:
/// the position after a run then depends on the word's arithmetic (a chain of about 15
/// cycles per run), where the byte loop's well-predicted branches let the processor run
/// ahead to the next field.
#[inline(always)]
fn digit_run<const VALUE: bool>(bytes: &[u8], mut i: usize, mut m: u64) -> (u64, usize) {
    while let Some(block) = bytes.get(i..i + 16) {
        for (k, &b) in block.iter().enumerate() {
            let d = b.wrapping_sub(b'0');
            if d > 9 {
                return (m, i + k);
            }
            if VALUE {
                m = m.wrapping_mul(10).wrapping_add(u64::from(d));
            }
        }
        i += 16;
    }
    while let Some(&b) = bytes.get(i) {
        let d = b.wrapping_sub(b'0');
        if d > 9 {
            break;
        }
        if VALUE {
            m = m.wrapping_mul(10).wrapping_add(u64::from(d));
        }
        i += 1;
    }
    (m, i)
}

/// The field of `bytes` starting at `start` (up to the next `,`, `\r`, `\n` or the end)
/// read as [`parse_plain_decimal`] reads it, in one pass: `(value, end)` with `end` the
/// position of the delimiter; the value is `None` whenever [`parse_plain_decimal`] of the
/// field is.
#[inline(always)]
pub fn scan_plain_decimal(bytes: &[u8], start: usize) -> (Option<f64>, usize) {
    scan::<true>(bytes, start)
}

/// [`scan_plain_decimal`] without the value: `(whether the field is a plain decimal, end)`,
/// for a reading that is only checked (the digits are not accumulated).
#[inline(always)]
pub fn scan_plain_decimal_syntax(bytes: &[u8], start: usize) -> (bool, usize) {
    let (value, end) = scan::<false>(bytes, start);
    (value.is_some(), end)
}

/// [`scan_plain_decimal`], the value computed when `VALUE` (`Some(0.0)` for every plain
/// decimal otherwise).
#[inline(always)]
fn scan<const VALUE: bool>(bytes: &[u8], start: usize) -> (Option<f64>, usize) {
    const POW10_F: [f64; 16] = [
        1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15,
    ];
    let len = bytes.len();
    let mut i = start;
    let negative = i < len && bytes[i] == b'-';
    i += usize::from(negative);
    // The digits before the point, then (after one point) those after it: each loop does
    // only the digit's arithmetic, the counts are positions. `m` wraps only past 19 digits,
    // which are refused below anyway.
    let int_start = i;
    let (mut m, end) = digit_run::<VALUE>(bytes, i, 0);
    i = end;
    let int_digits = i - int_start;
    let seen_point = bytes.get(i) == Some(&b'.');
    let mut frac_digits = 0;
    if seen_point {
        i += 1;
        let frac_start = i;
        (m, i) = digit_run::<VALUE>(bytes, i, m);
        frac_digits = i - frac_start;
    }
    let n_digits = int_digits + frac_digits;
    if i < len && !matches!(bytes[i], b',' | b'\n' | b'\r') {
        // Something else in the field: find its end; the field is not a plain decimal.
        while i < len && !matches!(bytes[i], b',' | b'\n' | b'\r') {
            i += 1;
        }
        return (None, i);
    }
    if n_digits == 0
        || n_digits > 15
        || (seen_point && (frac_digits == 0 || frac_digits == n_digits))
    {
        return (None, i);
    }
    if !VALUE {
        return (Some(0.0), i);
    }
    let v = m as i64 as f64 / POW10_F[frac_digits];
    (Some(if negative { -v } else { v }), i)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn fixed(v: f64, d: usize) -> String {
        let mut b = Vec::new();
        push_fixed(&mut b, v, d);
        String::from_utf8(b).unwrap()
    }

    fn shortest(v: f64) -> String {
        let mut b = Vec::new();
        push_shortest(&mut b, v);
        String::from_utf8(b).unwrap()
    }

    const EDGES: [f64; 24] = [
        0.0,
        -0.0,
        1.0,
        -1.0,
        0.5,
        1.5,
        2.5,
        0.0000005,
        0.0000015,
        0.0000025,
        -0.0000004,
        1e-300,
        -1e-300,
        0.1 + 0.2,
        529.601003,
        550.0,
        19.999,
        0.001,
        1e15,
        1e16,
        123456789.12345679,
        f64::NAN,
        f64::INFINITY,
        f64::NEG_INFINITY,
    ];

    #[test]
    fn edge_values_format_as_the_standard_library_does() {
        for v in EDGES
            .into_iter()
            .chain([f64::MIN_POSITIVE, f64::MAX, f64::EPSILON])
        {
            assert_eq!(shortest(v), format!("{v}"), "shortest {v:e}");
            for d in 0..=9 {
                assert_eq!(fixed(v, d), format!("{v:.d$}"), "fixed {d} of {v:e}");
            }
        }
    }

    #[test]
    fn exact_ties_round_half_to_even_like_the_standard_library() {
        // 0.125 and 0.375 are exact in binary: true ties at 2 decimals.
        for v in [0.125, 0.375, 2.5, 0.5, 1.5, -0.125, 1234.5] {
            for d in 0..=3 {
                assert_eq!(fixed(v, d), format!("{v:.d$}"), "{v} at {d}");
            }
        }
    }

    #[test]
    fn sample_grid_time_stamps_format_as_the_standard_library_does() {
        // What recordings hold: k * dt, and readings with six decimals.
        for k in 0..200_000u32 {
            let t = k as f64 * 0.001;
            assert_eq!(shortest(t), format!("{t}"));
            let t = k as f64 / 3.0;
            assert_eq!(shortest(t), format!("{t}"));
            assert_eq!(fixed(t, 6), format!("{t:.6}"));
        }
    }

    #[test]
    fn time_stamps_lose_the_float_noise_of_their_grid_and_keep_their_value() {
        // Summed steps and k * dt: the decimal of the grid, not 0.030000000000000002.
        let mut summed = 0.0;
        for k in 0..20_000u32 {
            for (t, dt) in [(summed, 0.005), (k as f64 * 0.001, 0.001)] {
                let want = format!("{}", (k as f64 * dt * 1e9).round() / 1e9);
                assert_eq!(shortest(time_to_ns(t)), want, "k = {k}, dt = {dt}");
                assert!(want.len() <= 12, "{want}");
            }
            summed += 0.005;
        }
        assert_eq!(shortest(time_to_ns(6.0 * 0.005)), "0.03");
        // A stamp that is a decimal of at most 9 places is written as it is.
        for t in [0.0, 0.014998, 1234.567891, -0.25, 5e-9] {
            assert_eq!(time_to_ns(t).to_bits(), t.to_bits(), "{t}");
        }
        // One off the grid moves by at most half a nanosecond; huge and non-finite ones not.
        let t = 1.0 / 3000.0;
        assert!((time_to_ns(t) - t).abs() <= 0.5e-9);
        for t in [1e7, f64::INFINITY, f64::NAN] {
            assert_eq!(time_to_ns(t).to_bits(), t.to_bits(), "{t}");
        }
    }

    #[test]
    fn plain_decimals_parse_to_the_standard_librarys_value() {
        for s in [
            "0",
            "-0",
            "1",
            "0.001",
            "550.000000",
            "529.601003",
            "-12.5",
            "999999999999999",
            "0.00000000000001",
            "19.999",
            "00012.50",
        ] {
            let v = parse_plain_decimal(s.as_bytes()).unwrap();
            assert_eq!(v.to_bits(), s.parse::<f64>().unwrap().to_bits(), "{s}");
        }
        for s in [
            "",
            "-",
            ".",
            "5.",
            ".5",
            "1e3",
            " 1",
            "1 ",
            "+1",
            "1.2.3",
            "nan",
            "inf",
            "1234567890123456",
            "--1",
            "0x10",
        ] {
            assert_eq!(parse_plain_decimal(s.as_bytes()), None, "{s:?}");
        }
    }

    /// The one-pass scanner finds the field's end and reads it as `parse_plain_decimal`
    /// reads the field cut out: `s` is a row of fields from a small alphabet of the bytes
    /// that matter (digits, point, minus, delimiters, others).
    fn scan_agrees_on(s: &[u8]) {
        let mut start = 0;
        loop {
            let end = start
                + s[start..]
                    .iter()
                    .position(|b| matches!(b, b',' | b'\n' | b'\r'))
                    .unwrap_or(s.len() - start);
            let (v, got_end) = scan_plain_decimal(s, start);
            assert_eq!(
                got_end,
                end,
                "{:?} from {start}",
                String::from_utf8_lossy(s)
            );
            let want = parse_plain_decimal(&s[start..end]);
            assert_eq!(
                v.map(f64::to_bits),
                want.map(f64::to_bits),
                "{:?}",
                String::from_utf8_lossy(&s[start..end])
            );
            // The check without the value takes the same fields.
            assert_eq!(
                scan_plain_decimal_syntax(s, start),
                (want.is_some(), end),
                "{:?}",
                String::from_utf8_lossy(&s[start..end])
            );
            if end >= s.len() {
                break;
            }
            start = end + 1;
        }
    }

    #[test]
    fn the_scanner_reads_fields_as_parse_plain_decimal() {
        for s in [
            "0.001000,0,0,0,0,0.000000,550.000000,550.000000,529.601003,529.601003\n",
            "-12.5,5.,.5,,-,1e3, 1,1 ,+1,1.2.3,nan,1234567890123456,999999999999999\r\n",
            "--1,0x10,00012.50,-0,12345678901234567890123,7",
        ] {
            scan_agrees_on(s.as_bytes());
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(5_000))]
        #[test]
        fn the_scanner_agrees_on_random_rows(
            picks in proptest::collection::vec(0usize..16, 1..60),
        ) {
            const ALPHABET: &[u8; 16] = b"0123456789.-,\ne ";
            let s: Vec<u8> = picks.iter().map(|&i| ALPHABET[i]).collect();
            scan_agrees_on(&s);
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(5_000))]
        /// Every byte value next to runs of digits (`/`, `:`, 0x00, 0x80, 0xFF... must end a
        /// run), runs of up to 19 digits (past the 15 the scanner takes).
        #[test]
        fn the_scanner_agrees_on_rows_of_any_bytes(
            parts in proptest::collection::vec((0usize..20, any::<u8>(), 0usize..3), 1..12),
        ) {
            let mut s = Vec::new();
            for (run, other, delim) in parts {
                s.extend((0..run).map(|k| b'0' + ((k * 7 + run) % 10) as u8));
                s.push(other);
                s.extend((0..run % 3).map(|k| b'0' + (k as u8 * 3) % 10));
                s.push([b',', b'\n', b'.'][delim]);
            }
            scan_agrees_on(&s);
        }
    }

    proptest! {
        #[test]
        fn formatted_values_parse_back_exactly_as_the_standard_parser_does(
            v in -1e9f64..1e9, d in 0usize..=9,
        ) {
            for s in [format!("{v:.d$}"), format!("{v}")] {
                let std_v = s.parse::<f64>().unwrap();
                if let Some(fast) = parse_plain_decimal(s.as_bytes()) {
                    prop_assert_eq!(fast.to_bits(), std_v.to_bits(), "{}", s);
                }
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(20_000))]
        #[test]
        fn any_bit_pattern_formats_as_the_standard_library_does(bits in any::<u64>()) {
            let v = f64::from_bits(bits);
            prop_assert_eq!(shortest(v), format!("{v}"));
            prop_assert_eq!(fixed(v, 6), format!("{v:.6}"));
        }

        #[test]
        fn measured_range_values_format_as_the_standard_library_does(
            v in -1e7f64..1e7, d in 0usize..=9, short in 0u32..8,
        ) {
            // Values with few digits (the integer path) and full-precision ones.
            let q = 10f64.powi(short as i32);
            for v in [v, (v * q).round() / q] {
                prop_assert_eq!(fixed(v, d), format!("{v:.d$}"));
                prop_assert_eq!(shortest(v), format!("{v}"));
            }
        }
    }
}
