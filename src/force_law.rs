//! Trig-free identified force law of a McKibben muscle (seed 002, eq. 6):
//!
//! ```text
//! F = (c1 P^2 + c2 e^2 + c3 P + c4 e + c5 P/e + c6) / (c7 P + c8 e) + c9 + c10 exp(e - 0.7)
//! ```
//!
//! Convention adopted here (documented in `config/force_law.toml` too):
//! - `P` is the **gauge pressure in MPa** (the unit of the paper's Fig. 4). The API takes
//!   pascal (`p_gauge_pa`) and converts at this one place.
//! - `e` is the **deformation L/L0** (the paper's Fig. 4 axis, 0.75 .. 1.05), not the
//!   contraction ratio of its eq. 4. With e >= 0.75 the terms `P/e` and `exp(e - 0.7)` stay
//!   well behaved.
//! - `F` is the tension in N, clamped at 0 (a muscle cannot push).
//!
//! Every input is checked: non-finite inputs give 0 N with [`ForceFlags::INVALID_INPUT`];
//! inputs outside the identified domain are clamped to its edge and flagged; a denominator
//! near zero gives 0 N with [`ForceFlags::SINGULAR`]. The function never panics and never
//! returns NaN.

/// Clamps the variable `$x` into `[$lo, $hi]`, adding the [`ForceFlags`] `$low` / `$high`
/// to `$flags` when it was below / above (a NaN fails both tests and passes unchanged): the
/// domain clamp of the f32 law and of the fixed-point law (`crate::fixed_point`). A macro,
/// so that each law keeps its straight-line code (a shared function cost instructions per
/// tick).
macro_rules! clamp_flagged {
    ($x:ident, $lo:expr, $hi:expr, $flags:ident, $low:ident, $high:ident) => {
        if $x < $lo {
            $x = $lo;
            $flags = $flags.union($crate::force_law::ForceFlags::$low);
        } else if $x > $hi {
            $x = $hi;
            $flags = $flags.union($crate::force_law::ForceFlags::$high);
        }
    };
}
pub(crate) use clamp_flagged;

/// Identified constants c1..c10 and the domain they were identified on.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ForceLawParams {
    /// c1..c10 of eq. 6 (P in MPa gauge, e = L/L0, F in N).
    pub c: [f32; 10],
    /// Highest gauge pressure of the identification data [Pa].
    pub p_gauge_max_pa: f32,
    /// Lowest deformation L/L0 of the identification data.
    pub stretch_min: f32,
    /// Highest deformation L/L0 of the identification data.
    pub stretch_max: f32,
}

/// Flags describing how a force estimate was obtained (bit set, 0 = clean).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ForceFlags(pub u8);

impl ForceFlags {
    /// No flag: the inputs were inside the identified domain.
    pub const NONE: ForceFlags = ForceFlags(0);
    /// A non-finite (NaN or infinite) input: the force is 0.
    pub const INVALID_INPUT: ForceFlags = ForceFlags(1 << 0);
    /// Pressure below 0 gauge: clamped to 0.
    pub const PRESSURE_LOW: ForceFlags = ForceFlags(1 << 1);
    /// Pressure above the identified maximum: clamped to it.
    pub const PRESSURE_HIGH: ForceFlags = ForceFlags(1 << 2);
    /// Deformation below the identified minimum: clamped to it.
    pub const STRETCH_LOW: ForceFlags = ForceFlags(1 << 3);
    /// Deformation above the identified maximum: clamped to it.
    pub const STRETCH_HIGH: ForceFlags = ForceFlags(1 << 4);
    /// Denominator `c7 P + c8 e` near zero, or a non-finite intermediate: the force is 0.
    pub const SINGULAR: ForceFlags = ForceFlags(1 << 5);

    /// Flags that mean the estimate cannot be trusted at all (as opposed to clamped inputs).
    pub const FATAL: ForceFlags = ForceFlags(Self::INVALID_INPUT.0 | Self::SINGULAR.0);

    /// True when no flag is set.
    #[inline]
    pub const fn is_clean(self) -> bool {
        self.0 == 0
    }
    /// True when any flag of `other` is set.
    #[inline]
    pub const fn contains_any(self, other: ForceFlags) -> bool {
        self.0 & other.0 != 0
    }
    /// Union of two flag sets.
    #[inline]
    pub const fn union(self, other: ForceFlags) -> ForceFlags {
        ForceFlags(self.0 | other.0)
    }
}

/// A force estimate with the flags that qualify it.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ForceEstimate {
    /// Tension [N], finite and >= 0.
    pub force_n: f32,
    /// How the estimate was obtained.
    pub flags: ForceFlags,
}

/// Pa -> MPa, the law's pressure unit.
pub const MPA_PER_PA: f32 = 1.0e-6;

/// `libm::expf`, bit for bit, with its no-reduction branch (`2^-14 < |x| <= ln(2)/2`, where
/// the force law's `e - 0.7` lies for stretches 0.75 .. 1.0466) inlined: that branch is
/// copied from libm 0.2 `expf` (FreeBSD `e_expf.c`) with `k = 0, hi = x, lo = 0`; every
/// other argument goes to `libm::expf` itself. About 15 instructions less per call on the
/// Cortex-M4F (no call, no special-case and reduction tests). `expf_matches_libm_bitwise`
/// checks it against `libm::expf` over the whole inlined range and beyond.
#[inline(always)]
// P1, P2 are libm's literals, verbatim.
#[allow(clippy::excessive_precision)]
fn expf_libm(x: f32) -> f32 {
    const P1: f32 = 1.6666625440e-1;
    const P2: f32 = -2.7667332906e-3;
    let hx = x.to_bits() & 0x7fff_ffff;
    if hx > 0x3900_0000 && hx <= 0x3eb1_7218 {
        let xx = x * x;
        let c = x - xx * (P1 + xx * P2);
        1.0 + (x * c / (2.0 - c) - 0.0 + x)
    } else {
        libm::expf(x)
    }
}
/// |denominator| below this is treated as singular.
const DEN_EPS: f32 = 1.0e-6;

impl ForceLawParams {
    /// Raw eq. 6 with P in MPa gauge and e = L/L0, no checks (may return any f32).
    /// For identification and tests; the firmware uses [`ForceLawParams::force`].
    #[inline]
    pub fn eval_raw(&self, p_mpa: f32, e: f32) -> f32 {
        let c = &self.c;
        let num =
            c[0] * p_mpa * p_mpa + c[1] * e * e + c[2] * p_mpa + c[3] * e + c[4] * p_mpa / e + c[5];
        let den = c[6] * p_mpa + c[7] * e;
        num / den + c[8] + c[9] * expf_libm(e - 0.7)
    }

    /// Tension [N] of a muscle at gauge pressure `p_gauge_pa` and deformation `stretch`
    /// (L/L0), with domain checks. Never panics, never NaN.
    pub fn force(&self, p_gauge_pa: f32, stretch: f32) -> ForceEstimate {
        self.force_inline(p_gauge_pa, stretch)
    }

    /// [`Self::force`], always inlined (the general entry: any input, any parameter set).
    #[inline(always)]
    pub(crate) fn force_inline(&self, p_gauge_pa: f32, stretch: f32) -> ForceEstimate {
        // Both finite, in one test: `x * 0` is +-0 for finite x, NaN for NaN and +-inf.
        if !(p_gauge_pa * 0.0 + stretch * 0.0 == 0.0) {
            return ForceEstimate {
                force_n: 0.0,
                flags: ForceFlags::INVALID_INPUT,
            };
        }
        let (p_mpa, e, flags) = self.clamp_to_domain(p_gauge_pa, stretch);
        let c = &self.c;
        let den = c[6] * p_mpa + c[7] * e;
        // `e` is clamped to the domain, which must exclude 0 (checked at build time for the
        // generated constants); guard anyway so a bad parameter set cannot divide by zero.
        if !(libm::fabsf(den) > DEN_EPS) || !(libm::fabsf(e) > DEN_EPS) {
            return ForceEstimate {
                force_n: 0.0,
                flags: flags.union(ForceFlags::SINGULAR),
            };
        }
        let f = self.eval_raw(p_mpa, e);
        if !f.is_finite() {
            return ForceEstimate {
                force_n: 0.0,
                flags: flags.union(ForceFlags::SINGULAR),
            };
        }
        ForceEstimate {
            force_n: tension(f),
            flags,
        }
    }

    /// [`Self::force`] for a law that is [regular on its domain](Self::is_regular) and finite
    /// inputs (the control tick's: validated channels, a configuration checked with
    /// [`Self::is_regular`] and [`JointGeometry::stretches_finite_over`]). Then no test of
    /// `force_inline` can fail, and this is the same bits without them (never a FATAL flag).
    /// For other inputs it never panics and the force is NaN-free (`f > 0` is false for NaN)
    /// but may be infinite; the tick's finiteness test of the torque catches that.
    ///
    /// [`JointGeometry::stretches_finite_over`]: crate::geometry::JointGeometry::stretches_finite_over
    #[inline(always)]
    pub(crate) fn force_regular(&self, p_gauge_pa: f32, stretch: f32) -> ForceEstimate {
        let (p_mpa, e, flags) = self.clamp_to_domain(p_gauge_pa, stretch);
        ForceEstimate {
            force_n: tension(self.eval_raw(p_mpa, e)),
            flags,
        }
    }

    /// The inputs clamped into the identified domain (pressure in MPa) with the flags of the
    /// clamps.
    #[inline(always)]
    fn clamp_to_domain(&self, p_gauge_pa: f32, stretch: f32) -> (f32, f32, ForceFlags) {
        let mut flags = ForceFlags::NONE;
        let mut p = p_gauge_pa;
        clamp_flagged!(
            p,
            0.0,
            self.p_gauge_max_pa,
            flags,
            PRESSURE_LOW,
            PRESSURE_HIGH
        );
        let mut e = stretch;
        clamp_flagged!(
            e,
            self.stretch_min,
            self.stretch_max,
            flags,
            STRETCH_LOW,
            STRETCH_HIGH
        );
        (p * MPA_PER_PA, e, flags)
    }

    /// True when eq. 6 is well posed on the whole identified domain (gauge pressure
    /// `0 ..= p_gauge_max_pa`, deformation `stretch_min ..= stretch_max`): finite constants
    /// and bounds, `stretch_min > 0`, the denominator `c7 P + c8 e` of one sign and clear of
    /// zero at the domain's four corners (it is linear, so over the whole domain; with a
    /// margin for the f32 rounding of its evaluation), and a force bounded well inside f32.
    /// Then [`Self::force`] never flags SINGULAR for a finite input. The control tick's
    /// configuration requires it ([`Self::force_regular`]); a law that fails it is singular
    /// somewhere it claims to be identified.
    pub fn is_regular(&self) -> bool {
        let fin = |x: f32| x.is_finite();
        if !(self.c.iter().all(|&c| fin(c))
            && fin(self.p_gauge_max_pa)
            && self.p_gauge_max_pa > 0.0
            && fin(self.stretch_min)
            && fin(self.stretch_max)
            && self.stretch_min > 1.0e-3
            && self.stretch_min <= self.stretch_max)
        {
            return false;
        }
        // In f32 (no soft-float f64 in the MCU image); the margins dwarf its rounding.
        let c = &self.c;
        let abs = libm::fabsf;
        // The value the law computes at the top of the range.
        let p_hi = self.p_gauge_max_pa * MPA_PER_PA;
        let (e_lo, e_hi) = (self.stretch_min, self.stretch_max);
        // The denominator at the four corners: at P = 0 it is `c8 e`, and each corner at
        // `p_hi` adds `c7 p_hi`. One sign at all four, clear of 0 by the margin.
        let (d00, d01) = (c[7] * e_lo, c[7] * e_hi);
        let (d10, d11) = (c[6] * p_hi + d00, c[6] * p_hi + d01);
        let lo = if d00 < d01 { d00 } else { d01 };
        let lo = if d10 < lo { d10 } else { lo };
        let lo = if d11 < lo { d11 } else { lo };
        let hi = if d00 > d01 { d00 } else { d01 };
        let hi = if d10 > hi { d10 } else { hi };
        let hi = if d11 > hi { d11 } else { hi };
        // Two roundings of terms at most this large (here and in the tick), and the
        // pressure's conversion, with a wide margin.
        let margin = 2.0 * DEN_EPS + 1.0e-5 * (abs(c[6]) * p_hi + abs(c[7]) * e_hi);
        let den_min = if lo > 0.0 { lo } else { -hi };
        if !(den_min > margin) {
            return false;
        }
        let num_max = abs(c[0]) * p_hi * p_hi
            + abs(c[1]) * e_hi * e_hi
            + abs(c[2]) * p_hi
            + abs(c[3]) * e_hi
            + abs(c[4]) * p_hi / e_lo
            + abs(c[5]);
        let x_max = if abs(e_hi - 0.7) > abs(e_lo - 0.7) {
            abs(e_hi - 0.7)
        } else {
            abs(e_lo - 0.7)
        };
        let f_max = num_max / den_min + abs(c[8]) + abs(c[9]) * libm::expf(x_max);
        f_max < 1.0e30
    }
}

/// The tension of a law value: negative (a muscle cannot push) and NaN give 0.
#[inline(always)]
fn tension(f: f32) -> f32 {
    if f > 0.0 {
        f
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::constants::FORCE_LAW;

    /// Hand-computed value of eq. 6 (f64, from the constants in config/force_law.toml).
    fn eq6_f64(c: &[f64; 10], p: f64, e: f64) -> f64 {
        (c[0] * p * p + c[1] * e * e + c[2] * p + c[3] * e + c[4] * p / e + c[5])
            / (c[6] * p + c[7] * e)
            + c[8]
            + c[9] * (e - 0.7).exp()
    }

    #[test]
    fn expf_matches_libm_bitwise() {
        // Every f32 in the inlined range (|x| in (2^-14, ln2/2]) is visited with a stride,
        // plus both edges and their neighbours on each side, for both signs.
        let lo = 0x3900_0000u32;
        let hi = 0x3eb1_7218u32;
        let mut bits: std::vec::Vec<u32> = (lo..=hi).step_by(97).collect();
        bits.extend([
            lo - 1,
            lo,
            lo + 1,
            lo + 2,
            hi - 1,
            hi,
            hi + 1,
            hi + 2,
            0,
            0x3f80_0000,
        ]);
        let mut n = 0;
        for b in bits {
            for x in [f32::from_bits(b), -f32::from_bits(b)] {
                assert_eq!(expf_libm(x).to_bits(), libm::expf(x).to_bits(), "x = {x:e}");
                n += 1;
            }
        }
        assert!(n > 200_000);
        for x in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 100.0, -100.0] {
            assert_eq!(expf_libm(x).to_bits(), libm::expf(x).to_bits());
        }
    }

    #[test]
    fn force_matches_double_precision_eq6_at_operating_point() {
        let c64 = FORCE_LAW.c.map(|x| x as f64);
        let want = eq6_f64(&c64, 0.55, 0.86);
        let got = FORCE_LAW.force(550_000.0, 0.86);
        assert!(got.flags.is_clean());
        // Large constants cancel: allow f32 rounding of a few 1e-3 relative to the terms.
        assert!(
            (got.force_n as f64 - want).abs() < 0.05,
            "{} vs {}",
            got.force_n,
            want
        );
    }

    #[test]
    fn reference_constants_reproduce_tondu_force_at_equilibrium() {
        // Tondu (PLANT.md) at 550 kPa, chi = 0.14: 529.601 N (first row of the fixtures).
        let f = FORCE_LAW.force(550_000.0, 0.86).force_n;
        assert!((f - 529.6).abs() < 30.0, "{f}");
    }

    #[test]
    fn non_finite_inputs_give_zero_and_flag() {
        for (p, e) in [
            (f32::NAN, 0.9),
            (3e5, f32::NAN),
            (f32::INFINITY, 0.9),
            (3e5, f32::NEG_INFINITY),
        ] {
            let r = FORCE_LAW.force(p, e);
            assert_eq!(r.force_n, 0.0);
            assert!(r.flags.contains_any(ForceFlags::INVALID_INPUT));
        }
    }

    #[test]
    fn out_of_domain_inputs_are_clamped_and_flagged() {
        let r = FORCE_LAW.force(-10_000.0, 0.9);
        assert!(r.flags.contains_any(ForceFlags::PRESSURE_LOW));
        assert_eq!(r.force_n, FORCE_LAW.force(0.0, 0.9).force_n);
        let r = FORCE_LAW.force(900_000.0, 1.2);
        assert!(r.flags.contains_any(ForceFlags::PRESSURE_HIGH));
        assert!(r.flags.contains_any(ForceFlags::STRETCH_HIGH));
        assert_eq!(r.force_n, FORCE_LAW.force(600_000.0, 1.05).force_n);
        let r = FORCE_LAW.force(300_000.0, 0.5);
        assert!(r.flags.contains_any(ForceFlags::STRETCH_LOW));
    }

    #[test]
    fn singular_denominator_is_flagged_not_divided() {
        let mut p = FORCE_LAW;
        p.c[6] = 0.0;
        p.c[7] = 0.0;
        let r = p.force(300_000.0, 0.9);
        assert_eq!(r.force_n, 0.0);
        assert!(r.flags.contains_any(ForceFlags::SINGULAR));
    }

    #[test]
    fn force_grows_with_pressure_and_stretch() {
        let lo = FORCE_LAW.force(200_000.0, 0.9).force_n;
        let hi = FORCE_LAW.force(500_000.0, 0.9).force_n;
        assert!(hi > lo);
        let short = FORCE_LAW.force(400_000.0, 0.8).force_n;
        let long = FORCE_LAW.force(400_000.0, 1.0).force_n;
        assert!(long > short);
    }

    #[test]
    fn regularity_is_decided_over_the_whole_domain() {
        assert!(FORCE_LAW.is_regular());
        let with = |edit: &dyn Fn(&mut ForceLawParams)| {
            let mut l = FORCE_LAW;
            edit(&mut l);
            l.is_regular()
        };
        // The denominator 0.52 P + e is 0.75 .. 1.36 on the domain; with c7 = -1.25 it is 0
        // at the corner (0.6 MPa, 0.75), with -1.2 clear of it, with -2 negative there.
        assert!(with(&|l| l.c[6] = -1.2));
        assert!(!with(&|l| l.c[6] = -1.25));
        assert!(!with(&|l| l.c[6] = -2.0));
        // ... at the corner within rounding of 0: refused with the margin.
        assert!(!with(&|l| l.c[6] = -(0.75 - 1.0e-7) / 0.6));
        assert!(!with(&|l| l.c[3] = f32::NAN));
        assert!(!with(&|l| l.p_gauge_max_pa = f32::INFINITY));
        assert!(!with(&|l| l.stretch_min = 0.0));
        assert!(!with(&|l| l.stretch_min = 1.1));
        // A force beyond 1e30 N somewhere on the domain.
        assert!(!with(&|l| l.c[9] = 1.0e31));
        assert!(with(&|l| l.c[9] = 1.0e20));
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(4096))]

        /// For a regular law and finite inputs the check-free evaluation of the control tick
        /// is the checked one, bit for bit, and never fatal; for an irregular one it still
        /// never gives NaN. The laws straddle the regularity margin (denominators through 0
        /// on and near the domain, stretch ranges down to 0.01).
        #[test]
        fn the_regular_force_is_the_checked_one_on_regular_laws(
            scale in proptest::array::uniform10(-3.0f32..3.0),
            c7 in -3.0f32..3.0,
            c8 in -2.0f32..2.0,
            p_max in 1.0e4f32..1.0e6,
            e_lo in 0.01f32..1.0,
            e_span in 0.0f32..0.5,
            p in -1.0e6f32..2.0e6,
            e in -1.0f32..2.0,
        ) {
            let mut l = FORCE_LAW;
            for (c, s) in l.c.iter_mut().zip(scale) {
                *c *= s;
            }
            l.c[6] = c7;
            l.c[7] = c8;
            l.p_gauge_max_pa = p_max;
            l.stretch_min = e_lo;
            l.stretch_max = e_lo + e_span;
            let fast = l.force_regular(p, e);
            proptest::prop_assert!(!fast.force_n.is_nan());
            if l.is_regular() {
                let checked = l.force(p, e);
                proptest::prop_assert!(!checked.flags.contains_any(ForceFlags::FATAL));
                proptest::prop_assert_eq!(fast.force_n.to_bits(), checked.force_n.to_bits());
                proptest::prop_assert_eq!(fast.flags, checked.flags);
            }
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(4096))]

        /// Any f32 bit patterns (NaN, infinities, subnormals, huge values): never panics,
        /// never NaN or negative, flags exactly describe the input class.
        #[test]
        fn force_of_any_f32_is_finite_non_negative_and_flagged([p, e] in crate::any_f32s()) {
            let l = &FORCE_LAW;
            let r = l.force(p, e);
            proptest::prop_assert!(r.force_n.is_finite() && r.force_n >= 0.0, "{:?}", r);
            if !p.is_finite() || !e.is_finite() {
                proptest::prop_assert_eq!(
                    r,
                    ForceEstimate { force_n: 0.0, flags: ForceFlags::INVALID_INPUT }
                );
            } else {
                let f = r.flags;
                proptest::prop_assert!(!f.contains_any(ForceFlags::FATAL));
                proptest::prop_assert_eq!(f.contains_any(ForceFlags::PRESSURE_LOW), p < 0.0);
                proptest::prop_assert_eq!(
                    f.contains_any(ForceFlags::PRESSURE_HIGH),
                    p > l.p_gauge_max_pa
                );
                proptest::prop_assert_eq!(f.contains_any(ForceFlags::STRETCH_LOW), e < l.stretch_min);
                proptest::prop_assert_eq!(
                    f.contains_any(ForceFlags::STRETCH_HIGH),
                    e > l.stretch_max
                );
                // Out of domain = the value at the clamped input.
                let pc = p.clamp(0.0, l.p_gauge_max_pa);
                let ec = e.clamp(l.stretch_min, l.stretch_max);
                proptest::prop_assert_eq!(r.force_n, l.force(pc, ec).force_n);
            }
        }
    }
}
