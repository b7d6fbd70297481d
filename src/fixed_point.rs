//! Fixed-point build of the force law (seed 002, eq. 6) and of the torque model (seed 003,
//! eq. 11) for FPU-less cores (Cortex-M0/M0+/M3), on the [`fixed`] crate.
//!
//! Same API shape and the same flag semantics as the f32 versions in [`crate::force_law`]
//! and [`crate::torque_model`]; no floating-point operation on the evaluation path (only the
//! `*_from_f32` edge adapters and [`FixedForceLaw::from_params`] /
//! [`FixedTorqueModel::from_params`] touch floats; the MCU uses the compile-time constants
//! [`crate::constants::FIXED_FORCE_LAW`] and [`crate::constants::FIXED_TORQUE_MODEL`]).
//!
//! # Types at the interface
//!
//! | quantity                          | type                     | resolution | range       |
//! |-----------------------------------|--------------------------|------------|-------------|
//! | gauge pressure, dp \[Pa\]           | [`PressurePa`] = `I32F0` | 1 Pa       | +-2.1e9 Pa  |
//! | stretch L/L0                      | [`Stretch`] = `I16F16`   | 1.5e-5     | +-32768     |
//! | force \[N\]                         | [`ForceN`] = `I16F16`    | 1.5e-5 N   | 0..32768 N  |
//! | angle \[rad\], velocity \[rad/s\]     | `I16F16`                 | 1.5e-5     | +-32768     |
//! | torque \[N m\]                      | [`TorqueNm`] = `I16F16`  | 1.5e-5 N m | +-32768 N m |
//!
//! Readings that may be missing go through the `*_opt` functions (`None` plays the part of
//! the f32 law's NaN); the `*_from_f32` adapters quantise f32 values (host / FPU side).
//!
//! # Scaling
//!
//! The identified constants are large (|c| up to ~5.7e4) and cancel to forces of 0..~1900 N,
//! so every intermediate is `I32F32` (i64, 2^-32 resolution, range +-2.1e9): the terms of eq. 6
//! (<= ~1e5) keep ~10 decimal digits after the cancellation. Specifically:
//!
//! - `P` \[MPa\] = `p_gauge_pa / 10^6` in `I32F32` (an exact integer division, error < 2^-32).
//! - The two divisions of eq. 6 are merged into one:
//!   `N/den + c5 P/(e den) = (N e + c5 P) / (e den)` with `N = c1 P^2 + c2 e^2 + c3 P + c4 e + c6`.
//! - `c10 exp(e - 0.7)` is a table of `c10 exp(k_i - 0.7)` at 9 knots `k_i` spread over the
//!   stretch domain (computed in f64 at build time), times a degree-4 Taylor polynomial in
//!   `d = e - k_i` around the nearest knot (|d| <= 0.019 for the 0.75..1.05 domain, truncation
//!   error < 2e-11 relative, i.e. < 1e-6 N).
//! - Torque model: `A r^2`, `C`, `D` and `1/(B r)` in `I32F32`; `B r` (~5e-5 N m/Pa) in
//!   `I16F48` so that it keeps ~10 significant digits; `B r dp` is formed in i128 and
//!   narrowed to `I32F32`.
//! - Every operation is checked (force law: an overflow is reported like a non-finite
//!   intermediate of the f32 law, [`ForceFlags::SINGULAR`]) or saturating (torque model),
//!   so nothing can panic or wrap.
//!
//! The pre-scaling (f64) lives in `src/fixed_point/prescale.rs`, shared by `build.rs` and
//! `from_params`, and starts from the f32 constants, so the fixed model is the f32 model.
//! Domain bounds are rounded inwards to the input resolution: a quantised input is flagged
//! exactly when the f32 law flags the same value.
//!
//! # Accuracy (measured)
//!
//! `cargo test -p pam-firmware --lib fixed_point::tests::worst_case -- --nocapture` prints
//! the worst cases over dense grids of quantised inputs (the f32 and f64 references are
//! evaluated at exactly the same input values):
//!
//! - force, 301 x 301 grid, P 0..600 kPa, L/L0 0.75..1.05 (force 0..1839 N):
//!   max |fixed - f64| = 4.1e-5 N, max |fixed - f32| = 1.7e-2 N, which is the f32 law's own
//!   rounding (max |f32 - f64| = 1.7e-2 N): the fixed build is more accurate than the f32 one.
//!   Asserted: |fixed - f64| < 1e-3 N, |fixed - f32| < 0.1 N (0.005 % of the range).
//! - torque, 101^3 grid, angle +-1.5 rad, velocity +-10 rad/s, dp +-dp_limit (280 kPa):
//!   forward max |fixed - f64| = 7.6e-6 N m (asserted < 1e-4 N m), |fixed - f32| = 1.1e-5 N m;
//!   inverse at the same torque max |dp_fixed - dp_f32| = 0.23 Pa (dp is rounded to whole
//!   pascal; asserted <= 1 Pa); fixed round trip dp -> T -> dp exact on the grid (asserted
//!   <= 1 Pa, also by a property test).
//!
//! Clamping goes to the inward-rounded bounds, so an out-of-domain stretch is evaluated at
//! most one input LSB (1.5e-5) inside the f32 law's bound.
//!
//! # Cost and float-freedom
//!
//! The force law is ~20 `I32F32` multiplications (64 x 64 -> 128 bit) and one 128 / 64 bit
//! division. On thumbv6m (Cortex-M0) the evaluation functions call only `__aeabi_lmul`,
//! `__aeabi_ldivmod` and `__clzsi2` (LLVM expands the 128-bit division inline): no soft-float
//! and no panic path. `bash scripts/check-fixed-no-float.sh` checks this on the release
//! assembly. Not yet benchmarked on hardware.

use fixed::types::{I16F16, I16F48, I32F0, I32F32};

use crate::force_law::{ForceFlags, ForceLawParams};
use crate::torque_model::TorqueModelParams;

/// Pre-scaling of the constants into bit patterns (f64), shared with `build.rs`.
pub mod prescale;

use prescale::{ForceLawBits, TorqueModelBits, EXP_KNOTS};

/// Gauge pressure or pressure difference \[Pa\], whole pascal.
pub type PressurePa = I32F0;
/// Deformation L/L0.
pub type Stretch = I16F16;
/// Muscle tension \[N\].
pub type ForceN = I16F16;
/// Joint angle \[rad\].
pub type AngleRad = I16F16;
/// Joint velocity \[rad/s\].
pub type VelocityRadS = I16F16;
/// Joint torque \[N m\].
pub type TorqueNm = I16F16;

/// Internal format of every intermediate.
type Wide = I32F32;

/// |denominator| below this (1e-6, as in the f32 law) is singular, in `I32F32` bits.
const DEN_EPS_BITS: u64 = 4295;
/// Half an LSB of `I16F16`, in `I32F32` bits: added before narrowing to round to nearest.
const HALF_Q16_IN_Q32: i64 = 1 << 15;
/// Upper limit for any muscle pressure set-point \[Pa\] (= [`crate::P_MUSCLE_MAX_GAUGE_PA`]).
pub const P_MUSCLE_MAX_GAUGE_PA_FIXED: PressurePa = PressurePa::from_bits(600_000);

/// Fixed-point force law (eq. 6); see the [module docs](self).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FixedForceLaw {
    c: [Wide; 10],
    p_gauge_max_pa: PressurePa,
    stretch_min: Stretch,
    stretch_max: Stretch,
    knot: [Wide; EXP_KNOTS],
    c10_exp: [Wide; EXP_KNOTS],
    inv_knot_step: Wide,
}

/// A fixed-point force estimate with the flags that qualify it (as [`crate::force_law::ForceEstimate`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FixedForceEstimate {
    /// Tension \[N\], >= 0.
    pub force_n: ForceN,
    /// How the estimate was obtained.
    pub flags: ForceFlags,
}

impl FixedForceEstimate {
    const fn invalid(flags: ForceFlags) -> Self {
        FixedForceEstimate {
            force_n: ForceN::ZERO,
            flags,
        }
    }
}

/// f32 -> [`PressurePa`] at the edge (host / FPU side): `None` for NaN and infinities,
/// otherwise rounded to the nearest pascal, saturating at the type's range.
pub fn pressure_pa_from_f32(x: f32) -> Option<PressurePa> {
    if x.is_finite() {
        Some(PressurePa::saturating_from_num(x))
    } else {
        None
    }
}

/// f32 -> `I16F16` ([`Stretch`], [`AngleRad`], [`VelocityRadS`], [`TorqueNm`]) at the edge:
/// `None` for NaN and infinities, otherwise rounded to nearest, saturating.
pub fn q16_from_f32(x: f32) -> Option<I16F16> {
    if x.is_finite() {
        Some(I16F16::saturating_from_num(x))
    } else {
        None
    }
}

/// `I16F16` -> `I32F32`, exact.
#[inline]
const fn widen(x: I16F16) -> Wide {
    Wide::from_bits((x.to_bits() as i64) << 16)
}

/// `I32F32` -> `I16F16`, rounded to nearest, saturating.
#[inline]
fn narrow_sat(x: Wide) -> I16F16 {
    I16F16::saturating_from_num(x.saturating_add(Wide::from_bits(HALF_Q16_IN_Q32)))
}

impl FixedForceLaw {
    /// Builds the law from pre-scaled bit patterns (what `build.rs` emits).
    pub const fn from_bits(b: ForceLawBits) -> Self {
        let mut c = [Wide::ZERO; 10];
        let mut i = 0;
        while i < 10 {
            c[i] = Wide::from_bits(b.c_q32[i]);
            i += 1;
        }
        let mut knot = [Wide::ZERO; EXP_KNOTS];
        let mut c10_exp = [Wide::ZERO; EXP_KNOTS];
        let mut k = 0;
        while k < EXP_KNOTS {
            knot[k] = Wide::from_bits(b.knot_q32[k]);
            c10_exp[k] = Wide::from_bits(b.c10_exp_q32[k]);
            k += 1;
        }
        FixedForceLaw {
            c,
            p_gauge_max_pa: PressurePa::from_bits(b.p_gauge_max_pa),
            stretch_min: Stretch::from_bits(b.stretch_min_q16),
            stretch_max: Stretch::from_bits(b.stretch_max_q16),
            knot,
            c10_exp,
            inv_knot_step: Wide::from_bits(b.inv_knot_step_q32),
        }
    }

    /// Pre-scales f32 parameters at run time (host, or once at start-up: uses f64 soft-float
    /// on an FPU-less core). Gives the same constants as `build.rs` for the same parameters.
    pub fn from_params(p: &ForceLawParams) -> Self {
        Self::from_bits(prescale::force_law_bits(
            p.c.map(|x| x as f64),
            p.p_gauge_max_pa as f64,
            p.stretch_min as f64,
            p.stretch_max as f64,
            libm::exp,
        ))
    }

    /// Highest gauge pressure of the domain \[Pa\].
    pub const fn p_gauge_max_pa(&self) -> PressurePa {
        self.p_gauge_max_pa
    }
    /// Lowest stretch of the domain.
    pub const fn stretch_min(&self) -> Stretch {
        self.stretch_min
    }
    /// Highest stretch of the domain.
    pub const fn stretch_max(&self) -> Stretch {
        self.stretch_max
    }

    /// Tension \[N\] at gauge pressure `p_gauge_pa` and deformation `stretch` (L/L0), with the
    /// domain checks of [`ForceLawParams::force`]: out-of-domain inputs are clamped and
    /// flagged; a near-zero denominator or an overflowing intermediate gives 0 N with
    /// [`ForceFlags::SINGULAR`]. Never panics; the force is always >= 0.
    pub fn force(&self, p_gauge_pa: PressurePa, stretch: Stretch) -> FixedForceEstimate {
        let mut flags = ForceFlags::NONE;
        let mut p = p_gauge_pa;
        if p < PressurePa::ZERO {
            p = PressurePa::ZERO;
            flags = flags.union(ForceFlags::PRESSURE_LOW);
        } else if p > self.p_gauge_max_pa {
            p = self.p_gauge_max_pa;
            flags = flags.union(ForceFlags::PRESSURE_HIGH);
        }
        let mut e = stretch;
        if e < self.stretch_min {
            e = self.stretch_min;
            flags = flags.union(ForceFlags::STRETCH_LOW);
        } else if e > self.stretch_max {
            e = self.stretch_max;
            flags = flags.union(ForceFlags::STRETCH_HIGH);
        }
        match self.eval_clamped(p, e) {
            Some(f) => FixedForceEstimate { force_n: f, flags },
            None => FixedForceEstimate::invalid(flags.union(ForceFlags::SINGULAR)),
        }
    }

    /// As [`FixedForceLaw::force`], for readings that may be missing or invalid: `None`
    /// (e.g. a NaN that could not be converted) gives 0 N with [`ForceFlags::INVALID_INPUT`].
    pub fn force_opt(
        &self,
        p_gauge_pa: Option<PressurePa>,
        stretch: Option<Stretch>,
    ) -> FixedForceEstimate {
        match (p_gauge_pa, stretch) {
            (Some(p), Some(e)) => self.force(p, e),
            _ => FixedForceEstimate::invalid(ForceFlags::INVALID_INPUT),
        }
    }

    /// Edge adapter for f32 inputs (host / FPU side; uses float compares and conversions):
    /// non-finite inputs are [`ForceFlags::INVALID_INPUT`], finite ones are quantised with
    /// [`pressure_pa_from_f32`] / [`q16_from_f32`] (saturating, so huge values are flagged
    /// as out of domain).
    pub fn force_from_f32(&self, p_gauge_pa: f32, stretch: f32) -> FixedForceEstimate {
        self.force_opt(pressure_pa_from_f32(p_gauge_pa), q16_from_f32(stretch))
    }

    /// Eq. 6 on clamped inputs; `None` when singular or on overflow.
    fn eval_clamped(&self, p_gauge_pa: PressurePa, stretch: Stretch) -> Option<ForceN> {
        let c = &self.c;
        let p = Wide::checked_from_num(p_gauge_pa)?.checked_div_int(1_000_000)?;
        let e = widen(stretch);
        let p2 = p.checked_mul(p)?;
        let e2 = e.checked_mul(e)?;
        // N = c1 P^2 + c2 e^2 + c3 P + c4 e + c6
        let n = c[0]
            .checked_mul(p2)?
            .checked_add(c[1].checked_mul(e2)?)?
            .checked_add(c[2].checked_mul(p)?)?
            .checked_add(c[3].checked_mul(e)?)?
            .checked_add(c[5])?;
        let den = c[6].checked_mul(p)?.checked_add(c[7].checked_mul(e)?)?;
        if den.to_bits().unsigned_abs() <= DEN_EPS_BITS
            || e.to_bits().unsigned_abs() <= DEN_EPS_BITS
        {
            return None;
        }
        // N/den + c5 P/(e den) = (N e + c5 P) / (e den): one division instead of two.
        let num = n.checked_mul(e)?.checked_add(c[4].checked_mul(p)?)?;
        let q = checked_div_wide(num, e.checked_mul(den)?)?;
        let f = q.checked_add(c[8])?.checked_add(self.c10_exp_term(e)?)?;
        if f <= Wide::ZERO {
            return Some(ForceN::ZERO);
        }
        ForceN::checked_from_num(f.checked_add(Wide::from_bits(HALF_Q16_IN_Q32))?)
    }

    /// c10 exp(e - 0.7) for `e` inside the domain: nearest table knot times a degree-4
    /// Taylor polynomial of exp(d), d = e - knot.
    fn c10_exp_term(&self, e: Wide) -> Option<Wide> {
        let t = e
            .checked_sub(self.knot[0])?
            .checked_mul(self.inv_knot_step)?
            .checked_add(Wide::from_bits(1 << 31))?;
        let i = t.to_bits() >> 32;
        let i = if i < 0 {
            0
        } else if i > (EXP_KNOTS - 1) as i64 {
            EXP_KNOTS - 1
        } else {
            i as usize
        };
        let d = e.checked_sub(self.knot[i])?;
        // 1 + d (1 + d/2 (1 + d/3 (1 + d/4)))
        let mut h = Wide::ONE.checked_add(d.checked_div_int(4)?)?;
        h = Wide::ONE.checked_add(d.checked_mul(h)?.checked_div_int(3)?)?;
        h = Wide::ONE.checked_add(d.checked_mul(h)?.checked_div_int(2)?)?;
        h = Wide::ONE.checked_add(d.checked_mul(h)?)?;
        self.c10_exp[i].checked_mul(h)
    }
}

/// Fixed-point torque model (eq. 11) and its inverse; see the [module docs](self).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FixedTorqueModel {
    a_r2: Wide,
    b_r: I16F48,
    c: Wide,
    d: Wide,
    inv_b_r: Wide,
    p0_gauge_pa: PressurePa,
    dp_limit_pa: PressurePa,
}

/// Result of inverting the fixed-point torque model (as [`crate::torque_model::Activation`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FixedActivation {
    /// Activation dp \[Pa\], within `+-dp_limit_pa`.
    pub dp_pa: PressurePa,
    /// True when the desired torque needed more than the valid range (dp was clamped), or
    /// an input was missing (dp = 0).
    pub saturated: bool,
}

impl FixedActivation {
    const INVALID: FixedActivation = FixedActivation {
        dp_pa: PressurePa::ZERO,
        saturated: true,
    };
}

impl FixedTorqueModel {
    /// Builds the model from pre-scaled bit patterns (what `build.rs` emits).
    pub const fn from_bits(b: TorqueModelBits) -> Self {
        FixedTorqueModel {
            a_r2: Wide::from_bits(b.a_r2_q32),
            b_r: I16F48::from_bits(b.b_r_q48),
            c: Wide::from_bits(b.c_q32),
            d: Wide::from_bits(b.d_q32),
            inv_b_r: Wide::from_bits(b.inv_b_r_q32),
            p0_gauge_pa: PressurePa::from_bits(b.p0_gauge_pa),
            dp_limit_pa: PressurePa::from_bits(b.dp_limit_pa),
        }
    }

    /// Pre-scales f32 parameters at run time (host, or once at start-up).
    pub fn from_params(p: &TorqueModelParams) -> Self {
        Self::from_bits(prescale::torque_model_bits(
            p.a_n_per_m_rad as f64,
            p.b_m2 as f64,
            p.c_nms3_per_rad3 as f64,
            p.d_nms_per_rad as f64,
            p.sprocket_radius_m as f64,
            p.p0_gauge_pa as f64,
            p.dp_max_pa as f64,
        ))
    }

    /// Mid pressure p0 of the symmetric activation \[Pa\].
    pub const fn p0_gauge_pa(&self) -> PressurePa {
        self.p0_gauge_pa
    }

    /// The usable |dp| \[Pa\] (as [`TorqueModelParams::dp_limit_pa`], rounded down).
    pub const fn dp_limit_pa(&self) -> PressurePa {
        self.dp_limit_pa
    }

    /// Torque not depending on the activation, saturating.
    #[inline]
    fn passive(&self, angle: Wide, v: Wide) -> Wide {
        let v3 = v.saturating_mul(v).saturating_mul(v);
        self.a_r2
            .saturating_mul(angle)
            .saturating_add(self.c.saturating_mul(v3))
            .saturating_add(self.d.saturating_mul(v))
    }

    /// Forward model: joint torque \[N m\] at the angle, velocity and activation. Saturates at
    /// the range of [`TorqueNm`]; never panics.
    pub fn torque_nm(
        &self,
        angle_rad: AngleRad,
        velocity_rad_s: VelocityRadS,
        dp_pa: PressurePa,
    ) -> TorqueNm {
        // B r dp: Q48 x Q0 in i128 (|.| < 2^94), shifted to Q32 and saturated.
        let prod = (self.b_r.to_bits() as i128) * (dp_pa.to_bits() as i128);
        let active = sat_i128_to_i64(prod >> 16);
        let t = self
            .passive(widen(angle_rad), widen(velocity_rad_s))
            .saturating_add(Wide::from_bits(active));
        narrow_sat(t)
    }

    /// Inverse model: the activation dp \[Pa\] that yields `torque_nm` at the angle and
    /// velocity, rounded to whole pascal and clamped to `+-dp_limit_pa` (then `saturated`).
    /// A model with `B r = 0` gives dp = 0, saturated. Never panics.
    pub fn activation(
        &self,
        torque_nm: TorqueNm,
        angle_rad: AngleRad,
        velocity_rad_s: VelocityRadS,
    ) -> FixedActivation {
        if self.inv_b_r == Wide::ZERO {
            return FixedActivation::INVALID;
        }
        let rest =
            widen(torque_nm).saturating_sub(self.passive(widen(angle_rad), widen(velocity_rad_s)));
        let dp = rest.saturating_mul(self.inv_b_r).saturating_round();
        let dp = prescale::sat_i32(dp.to_bits() >> 32);
        let lim = self.dp_limit_pa.to_bits();
        if dp > lim {
            FixedActivation {
                dp_pa: PressurePa::from_bits(lim),
                saturated: true,
            }
        } else if dp < -lim {
            FixedActivation {
                dp_pa: PressurePa::from_bits(-lim),
                saturated: true,
            }
        } else {
            FixedActivation {
                dp_pa: PressurePa::from_bits(dp),
                saturated: false,
            }
        }
    }

    /// As [`FixedTorqueModel::activation`] for inputs that may be missing: any `None` gives
    /// dp = 0, saturated (as a non-finite input of the f32 model).
    pub fn activation_opt(
        &self,
        torque_nm: Option<TorqueNm>,
        angle_rad: Option<AngleRad>,
        velocity_rad_s: Option<VelocityRadS>,
    ) -> FixedActivation {
        match (torque_nm, angle_rad, velocity_rad_s) {
            (Some(t), Some(a), Some(v)) => self.activation(t, a, v),
            _ => FixedActivation::INVALID,
        }
    }

    /// Edge adapter for f32 inputs (host / FPU side): non-finite inputs give dp = 0,
    /// saturated; finite ones are quantised with [`q16_from_f32`].
    pub fn activation_from_f32(
        &self,
        torque_nm: f32,
        angle_rad: f32,
        velocity_rad_s: f32,
    ) -> FixedActivation {
        self.activation_opt(
            q16_from_f32(torque_nm),
            q16_from_f32(angle_rad),
            q16_from_f32(velocity_rad_s),
        )
    }

    /// Pressure set-points (p1, p2) \[Pa\] of the symmetric activation `p1 = p0 - dp`,
    /// `p2 = p0 + dp`, each clamped to `\[0, 600 kPa\]`.
    pub fn pressures_gauge_pa(&self, dp_pa: PressurePa) -> (PressurePa, PressurePa) {
        let clamp = |p: PressurePa| {
            if p < PressurePa::ZERO {
                PressurePa::ZERO
            } else if p > P_MUSCLE_MAX_GAUGE_PA_FIXED {
                P_MUSCLE_MAX_GAUGE_PA_FIXED
            } else {
                p
            }
        };
        (
            clamp(self.p0_gauge_pa.saturating_sub(dp_pa)),
            clamp(self.p0_gauge_pa.saturating_add(dp_pa)),
        )
    }
}

/// `I32F32` division (truncating, like `fixed`'s), `None` for a zero divisor or overflow.
/// Spelled out with `i128::checked_div` because `I32F32::checked_div` leaves an (unreachable)
/// divide-by-zero panic branch in the thumbv6m code; this way the force law has no panic path.
#[inline]
fn checked_div_wide(n: Wide, d: Wide) -> Option<Wide> {
    let q = ((n.to_bits() as i128) << 32).checked_div(d.to_bits() as i128)?;
    i64::try_from(q).ok().map(Wide::from_bits)
}

/// Saturating i128 -> i64.
#[inline]
fn sat_i128_to_i64(x: i128) -> i64 {
    if x > i64::MAX as i128 {
        i64::MAX
    } else if x < i64::MIN as i128 {
        i64::MIN
    } else {
        x as i64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::constants::{FIXED_FORCE_LAW, FIXED_TORQUE_MODEL, FORCE_LAW, TORQUE_MODEL};
    use crate::P_MUSCLE_MAX_GAUGE_PA;
    use proptest::prelude::*;
    use std::println;

    /// Eq. 6 in f64 with the f32 constants, on inputs inside the domain.
    fn eq6_f64(p_pa: f64, e: f64) -> f64 {
        let c = FORCE_LAW.c.map(|x| x as f64);
        let p = p_pa * 1e-6;
        let f = (c[0] * p * p + c[1] * e * e + c[2] * p + c[3] * e + c[4] * p / e + c[5])
            / (c[6] * p + c[7] * e)
            + c[8]
            + c[9] * (e - 0.7).exp();
        f.max(0.0)
    }

    /// Eq. 11 in f64 with the f32 constants.
    fn eq11_f64(angle: f64, v: f64, dp: f64) -> f64 {
        let m = &TORQUE_MODEL;
        let r = m.sprocket_radius_m as f64;
        m.a_n_per_m_rad as f64 * r * r * angle
            + m.b_m2 as f64 * r * dp
            + m.c_nms3_per_rad3 as f64 * v * v * v
            + m.d_nms_per_rad as f64 * v
    }

    fn q16(x: f64) -> I16F16 {
        I16F16::from_num(x)
    }

    #[test]
    fn run_time_prescaling_gives_the_build_time_constants() {
        assert_eq!(FixedForceLaw::from_params(&FORCE_LAW), FIXED_FORCE_LAW);
        assert_eq!(
            FixedTorqueModel::from_params(&TORQUE_MODEL),
            FIXED_TORQUE_MODEL
        );
    }

    #[test]
    fn domain_bounds_are_rounded_inwards() {
        let l = &FIXED_FORCE_LAW;
        assert!(l.stretch_min().to_num::<f32>() >= FORCE_LAW.stretch_min);
        assert!(l.stretch_max().to_num::<f32>() <= FORCE_LAW.stretch_max);
        // One LSB further out is outside the f32 domain.
        let below = Stretch::from_bits(l.stretch_min().to_bits() - 1);
        let above = Stretch::from_bits(l.stretch_max().to_bits() + 1);
        assert!(below.to_num::<f32>() < FORCE_LAW.stretch_min);
        assert!(above.to_num::<f32>() > FORCE_LAW.stretch_max);
        assert_eq!(l.p_gauge_max_pa(), PressurePa::from_num(600_000));
    }

    /// Worst-case error of the fixed force law on a 301 x 301 grid over the whole domain,
    /// against f64 and against the f32 law at the same (quantised) inputs.
    #[test]
    fn worst_case_force_error_on_301x301_grid() {
        let l = &FIXED_FORCE_LAW;
        let (mut fix_f64, mut fix_f32, mut f32_f64) = (0.0f64, 0.0f64, 0.0f64);
        let (mut at_fix_f64, mut at_fix_f32) = ((0, 0.0), (0, 0.0));
        let mut f_max = 0.0f64;
        for i in 0..=300 {
            let p = PressurePa::from_num(2000 * i);
            for j in 0..=300 {
                let e = q16(0.75 + 0.3 * j as f64 / 300.0).clamp(l.stretch_min(), l.stretch_max());
                let (p32, e32) = (p.to_num::<f32>(), e.to_num::<f32>());
                let fx = l.force(p, e);
                let fl = FORCE_LAW.force(p32, e32);
                assert!(fx.flags.is_clean(), "{p} {e} {:?}", fx.flags);
                assert!(fl.flags.is_clean());
                let fx = fx.force_n.to_num::<f64>();
                let want = eq6_f64(p32 as f64, e32 as f64);
                f_max = f_max.max(want);
                let d64 = (fx - want).abs();
                let d32 = (fx - fl.force_n as f64).abs();
                if d64 > fix_f64 {
                    fix_f64 = d64;
                    at_fix_f64 = (p.to_num::<i32>(), e32);
                }
                if d32 > fix_f32 {
                    fix_f32 = d32;
                    at_fix_f32 = (p.to_num::<i32>(), e32);
                }
                f32_f64 = f32_f64.max((fl.force_n as f64 - want).abs());
            }
        }
        println!(
            "force law, 301x301 grid, P 0..600 kPa, L/L0 0.75..1.05, F 0..{f_max:.1} N:\n  \
             max |fixed - f64| = {fix_f64:.3e} N at (P, e) = {at_fix_f64:?}\n  \
             max |fixed - f32| = {fix_f32:.3e} N at (P, e) = {at_fix_f32:?}\n  \
             max |f32 - f64|   = {f32_f64:.3e} N"
        );
        assert!(fix_f64 < 1e-3, "{fix_f64}");
        assert!(fix_f32 < 0.1, "{fix_f32}");
    }

    /// Worst-case error of the fixed torque model (forward and inverse) on a 101^3 grid.
    #[test]
    fn worst_case_torque_error_on_101_cubed_grid() {
        let m = &FIXED_TORQUE_MODEL;
        let lim = m.dp_limit_pa().to_num::<i32>();
        assert_eq!(lim as f32, TORQUE_MODEL.dp_limit_pa());
        let (mut fwd_f64, mut fwd_f32, mut inv_f32, mut round_trip) =
            (0.0f64, 0.0f64, 0.0f32, 0i32);
        for i in 0..=100 {
            let a = q16(-1.5 + 3.0 * i as f64 / 100.0);
            for j in 0..=100 {
                let v = q16(-10.0 + 20.0 * j as f64 / 100.0);
                for k in 0..=100 {
                    let dp = PressurePa::from_num(-lim + (2 * lim / 100) * k);
                    let (a32, v32, dp32) =
                        (a.to_num::<f32>(), v.to_num::<f32>(), dp.to_num::<f32>());
                    let t = m.torque_nm(a, v, dp);
                    let want = eq11_f64(a32 as f64, v32 as f64, dp32 as f64);
                    fwd_f64 = fwd_f64.max((t.to_num::<f64>() - want).abs());
                    let t32 = TORQUE_MODEL.torque_nm(a32, v32, dp32);
                    fwd_f32 = fwd_f32.max((t.to_num::<f64>() - t32 as f64).abs());
                    // Inverse at the same (quantised) torque: fixed vs f32.
                    let act = m.activation(t, a, v);
                    let act32 = TORQUE_MODEL.activation(t.to_num::<f32>(), a32, v32);
                    inv_f32 = inv_f32.max((act.dp_pa.to_num::<f32>() - act32.dp_pa).abs());
                    round_trip = round_trip.max((act.dp_pa - dp).abs().to_num::<i32>());
                }
            }
        }
        println!(
            "torque model, 101^3 grid, angle +-1.5 rad, velocity +-10 rad/s, dp +-{lim} Pa:\n  \
             forward max |fixed - f64| = {fwd_f64:.3e} N m, max |fixed - f32| = {fwd_f32:.3e} N m\n  \
             inverse max |dp_fixed - dp_f32| = {inv_f32:.3} Pa, \
             round trip max |dp' - dp| = {round_trip} Pa"
        );
        assert!(fwd_f64 < 1e-4, "{fwd_f64}");
        assert!(inv_f32 <= 1.0, "{inv_f32}");
        assert!(round_trip <= 1, "{round_trip}");
    }

    #[test]
    fn missing_inputs_give_zero_and_invalid_flag() {
        let l = &FIXED_FORCE_LAW;
        for r in [
            l.force_opt(None, Some(q16(0.9))),
            l.force_opt(Some(PressurePa::from_num(300_000)), None),
            l.force_from_f32(f32::NAN, 0.9),
            l.force_from_f32(3e5, f32::INFINITY),
        ] {
            assert_eq!(r, FixedForceEstimate::invalid(ForceFlags::INVALID_INPUT));
        }
    }

    #[test]
    fn out_of_domain_inputs_are_clamped_and_flagged_like_f32() {
        let l = &FIXED_FORCE_LAW;
        let r = l.force_from_f32(-10_000.0, 0.9);
        assert!(r.flags.contains_any(ForceFlags::PRESSURE_LOW));
        assert_eq!(r.force_n, l.force_from_f32(0.0, 0.9).force_n);
        let r = l.force_from_f32(9e30, 1.2);
        assert_eq!(
            r.flags,
            ForceFlags::PRESSURE_HIGH.union(ForceFlags::STRETCH_HIGH)
        );
        assert_eq!(
            r.force_n,
            l.force(l.p_gauge_max_pa(), l.stretch_max()).force_n
        );
        let r = l.force_from_f32(300_000.0, -1e30);
        assert_eq!(r.flags, ForceFlags::STRETCH_LOW);
        // Same flags as the f32 law on the four edges of the domain.
        for (p, e) in [
            (-1.0f32, 0.9f32),
            (600_001.0, 0.9),
            (3e5, 0.7499),
            (3e5, 1.0501),
        ] {
            assert_eq!(
                l.force_from_f32(p, e).flags,
                FORCE_LAW.force(p, e).flags,
                "{p} {e}"
            );
        }
    }

    #[test]
    fn singular_denominator_is_flagged_not_divided() {
        let mut p = FORCE_LAW;
        p.c[6] = 0.0;
        p.c[7] = 0.0;
        let l = FixedForceLaw::from_params(&p);
        let r = l.force_from_f32(300_000.0, 0.9);
        assert_eq!(r, FixedForceEstimate::invalid(ForceFlags::SINGULAR));
    }

    #[test]
    fn overflowing_intermediate_is_flagged_singular() {
        let mut p = FORCE_LAW;
        p.c[1] = 3.0e9; // c2 e^2 no longer fits I32F32
        let r = FixedForceLaw::from_params(&p).force_from_f32(300_000.0, 1.0);
        assert_eq!(r, FixedForceEstimate::invalid(ForceFlags::SINGULAR));
    }

    #[test]
    fn force_grows_with_pressure_and_stretch() {
        let l = &FIXED_FORCE_LAW;
        let f = |p: f32, e: f32| l.force_from_f32(p, e).force_n;
        assert!(f(500_000.0, 0.9) > f(200_000.0, 0.9));
        assert!(f(400_000.0, 1.0) > f(400_000.0, 0.8));
    }

    #[test]
    fn uninvertible_model_gives_zero_saturated() {
        let mut p = TORQUE_MODEL;
        p.b_m2 = 0.0;
        let m = FixedTorqueModel::from_params(&p);
        assert_eq!(
            m.activation(q16(1.0), q16(0.1), q16(0.0)),
            FixedActivation::INVALID
        );
    }

    #[test]
    fn inverse_saturates_at_the_limit_and_pressures_stay_in_range() {
        let m = &FIXED_TORQUE_MODEL;
        let act = m.activation(TorqueNm::MAX, q16(0.0), q16(0.0));
        assert!(act.saturated);
        assert_eq!(act.dp_pa.abs(), m.dp_limit_pa());
        let act = m.activation(TorqueNm::MIN, q16(0.0), q16(0.0));
        assert!(act.saturated);
        assert_eq!(act.dp_pa.abs(), m.dp_limit_pa());
        let (p1, p2) = m.pressures_gauge_pa(PressurePa::from_num(50_000));
        assert_eq!((p1.to_num::<i32>(), p2.to_num::<i32>()), (250_000, 350_000));
        assert_eq!(
            m.activation_from_f32(f32::NAN, 0.0, 0.0),
            FixedActivation::INVALID
        );
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(4096))]

        /// Any f32 bit pattern: never panics, force >= 0, flags as the f32 law would set them
        /// for the quantised inputs, INVALID_INPUT exactly for non-finite inputs.
        #[test]
        fn fixed_force_from_any_f32_is_safe_and_flagged(p in proptest::num::f32::ANY, e in proptest::num::f32::ANY) {
            let l = &FIXED_FORCE_LAW;
            let r = l.force_from_f32(p, e);
            prop_assert!(r.force_n >= ForceN::ZERO);
            if !p.is_finite() || !e.is_finite() {
                prop_assert_eq!(r, FixedForceEstimate::invalid(ForceFlags::INVALID_INPUT));
            } else {
                let (pq, eq) = (pressure_pa_from_f32(p).unwrap(), q16_from_f32(e).unwrap());
                prop_assert_eq!(r, l.force(pq, eq));
                prop_assert!(!r.flags.contains_any(ForceFlags::FATAL));
                prop_assert_eq!(r.flags.contains_any(ForceFlags::PRESSURE_LOW), pq < 0);
                prop_assert_eq!(r.flags.contains_any(ForceFlags::PRESSURE_HIGH), pq > l.p_gauge_max_pa());
                prop_assert_eq!(r.flags.contains_any(ForceFlags::STRETCH_LOW), eq < l.stretch_min());
                prop_assert_eq!(r.flags.contains_any(ForceFlags::STRETCH_HIGH), eq > l.stretch_max());
                // Flags agree with the f32 law at the quantised value.
                prop_assert_eq!(r.flags, FORCE_LAW.force(pq.to_num::<f32>(), eq.to_num::<f32>()).flags);
            }
        }

        /// Any fixed bit pattern: never panics, force >= 0 and equal to the force at the
        /// clamped inputs.
        #[test]
        fn fixed_force_from_any_bits_is_safe(pb in any::<i32>(), eb in any::<i32>()) {
            let l = &FIXED_FORCE_LAW;
            let r = l.force(PressurePa::from_bits(pb), Stretch::from_bits(eb));
            prop_assert!(r.force_n >= ForceN::ZERO);
            prop_assert!(!r.flags.contains_any(ForceFlags::FATAL));
            let pc = PressurePa::from_bits(pb).clamp(PressurePa::ZERO, l.p_gauge_max_pa());
            let ec = Stretch::from_bits(eb).clamp(l.stretch_min(), l.stretch_max());
            prop_assert_eq!(r.force_n, l.force(pc, ec).force_n);
        }

        /// Inside the domain, random points: fixed within 0.1 N of the f32 law.
        #[test]
        fn fixed_force_tracks_f32_inside_domain(p in 0i32..=600_000, e in 49152i32..=68812) {
            let (p, e) = (PressurePa::from_bits(p), Stretch::from_bits(e));
            let fx = FIXED_FORCE_LAW.force(p, e);
            let fl = FORCE_LAW.force(p.to_num::<f32>(), e.to_num::<f32>());
            prop_assert!(fx.flags.is_clean());
            prop_assert!((fx.force_n.to_num::<f32>() - fl.force_n).abs() < 0.1);
        }

        /// Any parameter set (NaN, huge, zero constants or domains) pre-scales without
        /// panicking, and the resulting law still never panics nor returns a negative force.
        #[test]
        fn any_parameters_give_a_safe_fixed_law(
            c in proptest::array::uniform10(proptest::num::f32::ANY),
            bounds in proptest::array::uniform3(proptest::num::f32::ANY),
            tm in proptest::array::uniform7(proptest::num::f32::ANY),
            pb in any::<i32>(), eb in any::<i32>(), t in any::<i32>(), a in any::<i32>(),
        ) {
            let l = FixedForceLaw::from_params(&ForceLawParams {
                c, p_gauge_max_pa: bounds[0], stretch_min: bounds[1], stretch_max: bounds[2],
            });
            let r = l.force(PressurePa::from_bits(pb), Stretch::from_bits(eb));
            prop_assert!(r.force_n >= ForceN::ZERO);
            let m = FixedTorqueModel::from_params(&TorqueModelParams {
                a_n_per_m_rad: tm[0], b_m2: tm[1], c_nms3_per_rad3: tm[2], d_nms_per_rad: tm[3],
                sprocket_radius_m: tm[4], p0_gauge_pa: tm[5], dp_max_pa: tm[6],
            });
            let act = m.activation(TorqueNm::from_bits(t), AngleRad::from_bits(a), VelocityRadS::ZERO);
            prop_assert!(act.dp_pa.abs() <= m.dp_limit_pa());
            let _ = m.torque_nm(AngleRad::from_bits(a), VelocityRadS::from_bits(t), PressurePa::from_bits(pb));
            let (p1, p2) = m.pressures_gauge_pa(act.dp_pa);
            prop_assert!(p1 >= 0 && p2 >= 0 && p1 <= P_MUSCLE_MAX_GAUGE_PA_FIXED && p2 <= P_MUSCLE_MAX_GAUGE_PA_FIXED);
        }

        /// Forward model: any bit patterns, never panics (saturates).
        #[test]
        fn fixed_torque_forward_never_panics(a in any::<i32>(), v in any::<i32>(), dp in any::<i32>()) {
            let _ = FIXED_TORQUE_MODEL.torque_nm(
                AngleRad::from_bits(a), VelocityRadS::from_bits(v), PressurePa::from_bits(dp));
        }

        /// Inverse from any f32 bit patterns: |dp| within the limit, pressures in \[0, 600 kPa\].
        #[test]
        fn fixed_activation_is_bounded_for_any_f32(
            t in proptest::num::f32::ANY, a in proptest::num::f32::ANY, v in proptest::num::f32::ANY,
        ) {
            let m = &FIXED_TORQUE_MODEL;
            let act = m.activation_from_f32(t, a, v);
            prop_assert!(act.dp_pa.abs() <= m.dp_limit_pa());
            if !t.is_finite() || !a.is_finite() || !v.is_finite() {
                prop_assert_eq!(act, FixedActivation::INVALID);
            }
            let (p1, p2) = m.pressures_gauge_pa(act.dp_pa);
            for p in [p1, p2] {
                prop_assert!(p >= 0 && p <= P_MUSCLE_MAX_GAUGE_PA_FIXED);
            }
        }

        /// Inverse from any fixed bit patterns: bounded, pressures in range for any dp.
        #[test]
        fn fixed_activation_and_pressures_bounded_for_any_bits(
            t in any::<i32>(), a in any::<i32>(), v in any::<i32>(), dp in any::<i32>(),
        ) {
            let m = &FIXED_TORQUE_MODEL;
            let act = m.activation(TorqueNm::from_bits(t), AngleRad::from_bits(a), VelocityRadS::from_bits(v));
            prop_assert!(act.dp_pa.abs() <= m.dp_limit_pa());
            let (p1, p2) = m.pressures_gauge_pa(PressurePa::from_bits(dp));
            for p in [p1, p2] {
                prop_assert!(p >= 0 && p.to_num::<f32>() <= P_MUSCLE_MAX_GAUGE_PA);
            }
        }

        /// Inside the range the inverse undoes the forward model to within 1 Pa.
        #[test]
        fn fixed_inverse_round_trips_forward_inside_range(
            a in -1.5f64..1.5, v in -10.0f64..10.0, frac in -1.0f64..1.0,
        ) {
            let m = &FIXED_TORQUE_MODEL;
            let dp = PressurePa::from_num((frac * m.dp_limit_pa().to_num::<f64>()).round() as i32);
            let (a, v) = (q16(a), q16(v));
            let act = m.activation(m.torque_nm(a, v, dp), a, v);
            prop_assert!((act.dp_pa - dp).abs() <= 1, "{} vs {}", act.dp_pa, dp);
            prop_assert!(!act.saturated || (dp.abs() >= m.dp_limit_pa() - PressurePa::ONE));
        }
    }
}
