// Pre-scaling of the model constants into fixed-point bit patterns, in f64.
//
// This file is shared, verbatim, by two users:
// - `build.rs` (`#[path]` module): emits `FIXED_FORCE_LAW` / `FIXED_TORQUE_MODEL` as bit
//   patterns, so the MCU never converts a float;
// - `crate::fixed_point` (`from_params`): builds the same tables at run time on the host or
//   at start-up, e.g. for freshly identified constants.
//
// It uses `core` only (no `std`, no `libm`): the exponential is passed in. The inputs are the
// f32 constants widened to f64, so the fixed model describes exactly the f32 model.
// Plain comments (not `//!`) because the file is also included as a module of build.rs.

/// 2^32: scale of the Q32 (I32F32 / ...F32) formats.
pub const Q32: f64 = 4_294_967_296.0;
/// 2^16: scale of the Q16 (I16F16) formats.
pub const Q16: f64 = 65_536.0;
/// 2^48: scale of the Q48 (I16F48) format.
pub const Q48: f64 = 281_474_976_710_656.0;
/// The offset of the exponential term of eq. 6.
pub const EXP_OFFSET: f64 = 0.7;
/// Upper limit of any muscle pressure set-point \[Pa\] (same value as
/// `crate::P_MUSCLE_MAX_GAUGE_PA`).
pub const P_MAX_PA: f64 = 600_000.0;

/// Nearest integer, saturating at the i64 range (NaN -> 0).
pub fn round_i64(x: f64) -> i64 {
    if x >= 0.0 {
        (x + 0.5) as i64
    } else {
        (x - 0.5) as i64
    }
}

/// Largest integer <= x, saturating (NaN -> 0).
pub fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x {
        t.saturating_sub(1)
    } else {
        t
    }
}

/// Smallest integer >= x, saturating (NaN -> 0).
pub fn ceil_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) < x {
        t.saturating_add(1)
    } else {
        t
    }
}

/// Saturating i64 -> i32.
pub fn sat_i32(x: i64) -> i32 {
    if x > i32::MAX as i64 {
        i32::MAX
    } else if x < i32::MIN as i64 {
        i32::MIN
    } else {
        x as i32
    }
}

// ---------------------------------------------------------------------------------------------
// Force law (eq. 6) for a 32-bit core without FPU or divider.
//
// Rewritten so that the large identified constants cancel here, in f64, and not at run time:
//
//   F(P, e) = k(e) + phi (A e phi + M(e)) / (e^2 + G e phi)
//
// with phi = p_gauge_pa / 2^20 (so P[MPa] = lambda phi, lambda = 1.048576), and
//   k(e) = F(0, e)          = c9 + c4/c8 + c10 exp(e - 0.7) + (c2/c8) e + (c6/c8) / e
//   A    = lambda^2 c1 / c8
//   M(e) = lambda (m2 e^2 + m1 e + m0) / c8^2,  m2 = -c7 c2, m1 = c3 c8 - c7 c4, m0 = c5 c8 - c7 c6
//   G    = lambda c7 / c8
// (F - k(e) = P (c1 c8 e P + m(e)) / (c8 e (c7 P + c8 e)), exact algebra.) k(e) is about
// F(0, e) (tens of newton) where the terms of eq. 6 are ~5e4 N each; every run-time quantity is
// a few thousand at most, so 32-bit integers with 10 fractional bits carry it.
//
// The stretch domain is cut into segments of 2^SEG_SHIFT Q16 LSB (1/32); inside a segment with
// centre c, x = e_q16 - c_q16 in [-1024, 1023] and t = x / 1024. Per segment, k is a cubic
// Taylor polynomial in t (truncation < 5e-3 N for e >= 0.7), M is exact (quadratic), A e,
// G e and e^2 are exact (linear / quadratic). The one division is a reciprocal: a
// piecewise-linear seed (SEED_MAX chords of 1/d over the denominator's proven range) and one
// Newton step.
// ---------------------------------------------------------------------------------------------

/// Segment width of the stretch domain: 2^SEG_SHIFT Q16 LSB (1/32 in L/L0).
pub const SEG_SHIFT: u32 = 11;
/// Most segments: the stretch domain may be up to SEG_MAX / 32 = 0.5 wide (L/L0 0.7..1.1 is 0.4).
pub const SEG_MAX: usize = 16;
/// Chords of the reciprocal's seed.
pub const SEED_MAX: usize = 32;
/// Force-like quantities (k, M, numerator, F) in Q10 newton (resolution 1e-3 N).
pub const Q_F: i32 = 10;
/// A e in Q16.
pub const Q_AE: i32 = 16;
/// Denominator, e^2 and G e in Q24.
pub const Q_D: i32 = 24;
/// Seed of the reciprocal in Q14.
pub const Q_R0: i32 = 14;
/// Largest gauge pressure the fixed law accepts as its domain bound \[Pa\]: phi16 =
/// (p + 8) >> 4 must fit 16 bits unsigned.
pub const P_MAX_FIXED_PA: f64 = 1_048_560.0;
/// MPa per unit of phi (phi = p / 2^20 Pa).
pub const LAMBDA_MPA: f64 = 1.048576;

/// Per segment: k (Q10, in t: k0..k3), M (Q10: m0, m1), A e at the centre (Q16), G e at the
/// centre (Q24), e^2 at the centre and its t coefficient (Q24).
pub const SEG_K0: usize = 0;
/// See [`SEG_K0`].
pub const SEG_M0: usize = 4;
/// See [`SEG_K0`].
pub const SEG_AE0: usize = 6;
/// See [`SEG_K0`].
pub const SEG_GE0: usize = 7;
/// See [`SEG_K0`].
pub const SEG_E20: usize = 8;
/// Words per segment.
pub const SEG_WORDS: usize = 10;

/// Bit patterns of the fixed-point force law.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ForceLawBits {
    /// False when the parameters do not fit the formats (or c8 = 0, a domain reaching e <= 0,
    /// a denominator that is not bounded away from 0, ...): every evaluation is then flagged
    /// singular. True for any law whose intermediates provably fit (checked below).
    pub valid: bool,
    /// Highest gauge pressure \[Pa\], rounded down (I32F0).
    pub p_gauge_max_pa: i32,
    /// Lowest stretch in Q16 (I16F16), rounded up: the fixed domain lies inside the f32 one,
    /// so a Q16 input is flagged exactly when its value is flagged by the f32 law.
    pub stretch_min_q16: i32,
    /// Highest stretch in Q16 (I16F16), rounded down (see `stretch_min_q16`).
    pub stretch_max_q16: i32,
    /// Per-segment words (see [`SEG_K0`] ... [`SEG_WORDS`]); segment i is centred on
    /// `stretch_min_q16 + i 2^SEG_SHIFT + 2^(SEG_SHIFT-1)`.
    pub seg: [[i32; SEG_WORDS]; SEG_MAX],
    /// t^2 coefficient of M (Q10), the same in every segment.
    pub m2: i32,
    /// t coefficient of A e (Q16).
    pub ae1: i32,
    /// t coefficient of G e (Q24).
    pub ge1: i32,
    /// Lower bound of the denominator over the whole domain (Q24), start of the seed table.
    pub d_lo_q24: i32,
    /// log2 of the seed chords' width (Q24 LSB), >= 15.
    pub seed_shift: i32,
    /// Per chord: 1/d at its start (Q14) and the drop of 1/d over the chord (Q14).
    pub seed: [[i32; 2]; SEED_MAX],
}

/// Rounds to i32 if |x| < `lim` (and finite); `None` otherwise.
fn fit(x: f64, lim: f64) -> Option<i32> {
    if x.is_finite() && x.abs() < lim && lim <= 2_147_483_647.0 {
        Some(round_i64(x) as i32)
    } else {
        None
    }
}

const B21: f64 = 2_097_152.0;
const B30: f64 = 1_073_741_824.0;
const B31: f64 = 2_147_483_647.0;

fn abs(x: f64) -> f64 {
    if x < 0.0 {
        -x
    } else {
        x
    }
}

/// Pre-scales the force-law constants (c1..c10 with P in MPa, e = L/L0). Never panics: any
/// parameter set gives bits, flagged `valid = false` when they do not fit.
pub fn force_law_bits(
    c: [f64; 10],
    p_gauge_max_pa: f64,
    stretch_min: f64,
    stretch_max: f64,
    exp: fn(f64) -> f64,
) -> ForceLawBits {
    let smin = sat_i32(ceil_i64(stretch_min * Q16));
    let smax = sat_i32(floor_i64(stretch_max * Q16));
    let smax = if smax < smin { smin } else { smax };
    let mut b = ForceLawBits {
        valid: false,
        p_gauge_max_pa: sat_i32(floor_i64(p_gauge_max_pa)),
        stretch_min_q16: smin,
        stretch_max_q16: smax,
        seg: [[0; SEG_WORDS]; SEG_MAX],
        m2: 0,
        ae1: 0,
        ge1: 0,
        d_lo_q24: 1 << 24,
        seed_shift: 15,
        seed: [[0; 2]; SEED_MAX],
    };
    if let Some(ok) = fill_force_law(&mut b, c, exp) {
        b.valid = ok;
    }
    if !b.valid {
        // Keep only the domain (flags still work); the tables are meaningless.
        b.seg = [[0; SEG_WORDS]; SEG_MAX];
        b.seed = [[0; 2]; SEED_MAX];
        b.m2 = 0;
        b.ae1 = 0;
        b.ge1 = 0;
        b.d_lo_q24 = 1 << 24;
        b.seed_shift = 15;
    }
    b
}

/// Fills the tables; `Some(true)` when every bound holds, `None`/`Some(false)` otherwise.
fn fill_force_law(b: &mut ForceLawBits, c: [f64; 10], exp: fn(f64) -> f64) -> Option<bool> {
    let mut i = 0;
    while i < 10 {
        if !c[i].is_finite() {
            return None;
        }
        i += 1;
    }
    let pmax = b.p_gauge_max_pa as f64;
    if !(pmax > 0.0 && pmax <= P_MAX_FIXED_PA) || c[7] == 0.0 {
        return None;
    }
    let (smin, smax) = (b.stretch_min_q16, b.stretch_max_q16);
    // e > 0 over the whole domain, at most SEG_MAX segments.
    if smin <= 0 || smax <= smin {
        return None;
    }
    let n_seg = (((smax - smin) >> SEG_SHIFT) + 1) as usize;
    if n_seg > SEG_MAX {
        return None;
    }
    let c8 = c[7];
    let lam = LAMBDA_MPA;
    let a = lam * lam * c[0] / c8;
    let g = lam * c[6] / c8;
    let m2 = lam * (-c[6] * c[1]) / (c8 * c8);
    let m1 = lam * (c[2] * c8 - c[6] * c[3]) / (c8 * c8);
    let m0 = lam * (c[4] * c8 - c[6] * c[5]) / (c8 * c8);
    let k_const = c[8] + c[3] / c8;
    let (k_lin, k_inv) = (c[1] / c8, c[5] / c8);
    let half = (1i32 << (SEG_SHIFT - 1)) as f64;
    let h = half / Q16; // t = 1 <-> xi = h
    let qf = (1i64 << Q_F) as f64;
    let qae = (1i64 << Q_AE) as f64;
    let qd = (1i64 << Q_D) as f64;
    b.m2 = fit(m2 * h * h * qf, B21)?;
    b.ae1 = fit(a * h * qae, B21)?;
    b.ge1 = fit(g * h * qd, B21)?;
    let e2_2 = (h * h * qd) as i64; // t^2 coefficient of e^2: 2^12, exact
    let phi_max = ((b.p_gauge_max_pa + 8) >> 4) as f64; // phi16 = (p + 8) >> 4 <= 65535
    let (mut d_lo, mut d_hi, mut bn_max, mut bk_max) = (f64::MAX, 0.0f64, 0.0f64, 0.0f64);
    let mut s = 0;
    while s < n_seg {
        let cq = smin + ((s as i32) << SEG_SHIFT) + (1 << (SEG_SHIFT - 1));
        let ce = cq as f64 / Q16;
        let ex = c[9] * exp(ce - EXP_OFFSET);
        let k0 = k_const + ex + k_lin * ce + k_inv / ce;
        let k1 = ex + k_lin - k_inv / (ce * ce);
        let k2 = ex / 2.0 + k_inv / (ce * ce * ce);
        let k3 = ex / 6.0 - k_inv / (ce * ce * ce * ce);
        let w = &mut b.seg[s];
        w[SEG_K0 + 3] = fit(k3 * h * h * h * qf, B21)?;
        w[SEG_K0 + 2] = fit(k2 * h * h * qf, B21)?;
        w[SEG_K0 + 1] = fit(k1 * h * qf, B21)?;
        w[SEG_K0] = fit(k0 * qf, B30)?;
        w[SEG_M0] = fit((m2 * ce * ce + m1 * ce + m0) * qf, B30)?;
        w[SEG_M0 + 1] = fit((2.0 * m2 * ce + m1) * h * qf, B21)?;
        w[SEG_AE0] = fit(a * ce * qae, B30)?;
        w[SEG_GE0] = fit(g * ce * qd, B30)?;
        w[SEG_E20] = fit(ce * ce * qd, B30)?;
        w[SEG_E20 + 1] = fit(2.0 * ce * h * qd, B21)?;
        // Bounds of every intermediate over |t| <= 1 (integer units, +1 per floor).
        let f = |x: i32| abs(x as f64);
        let bk2 = f(w[SEG_K0 + 2]) + f(w[SEG_K0 + 3]) + 1.0;
        let bk1 = f(w[SEG_K0 + 1]) + bk2 + 1.0;
        let bk0 = f(w[SEG_K0]) + bk1 + 1.0;
        let bm1 = f(w[SEG_M0 + 1]) + f(b.m2) + 1.0;
        let bm0 = f(w[SEG_M0]) + bm1 + 1.0;
        let be1 = f(w[SEG_E20 + 1]) + e2_2 as f64 + 1.0;
        if bk2 >= B21 || bk1 >= B21 || bm1 >= B21 || be1 >= B21 || bk0 >= B30 {
            return Some(false);
        }
        let bae = f(w[SEG_AE0]) + f(b.ae1) + 1.0;
        let inner = bae * phi_max / 4_194_304.0 + 1.0 + bm0; // Ae phi >> 22, + M
        let bn = inner * phi_max / 65_536.0 + 1.0;
        if inner >= B31 || bn >= B30 {
            return Some(false);
        }
        let e2_lo = w[SEG_E20] as f64 - be1 - 1.0;
        let e2_hi = w[SEG_E20] as f64 + be1 + 1.0;
        let ge_lo = w[SEG_GE0] as f64 - f(b.ge1) - 1.0;
        let ge_hi = w[SEG_GE0] as f64 + f(b.ge1) + 1.0;
        let gphi_lo = if ge_lo < 0.0 {
            ge_lo * phi_max / 65_536.0 - 1.0
        } else {
            -1.0
        };
        let gphi_hi = if ge_hi > 0.0 {
            ge_hi * phi_max / 65_536.0 + 1.0
        } else {
            0.0
        };
        let lo = e2_lo + gphi_lo;
        let hi = e2_hi + gphi_hi;
        d_lo = if lo < d_lo { lo } else { d_lo };
        d_hi = if hi > d_hi { hi } else { d_hi };
        bn_max = if bn > bn_max { bn } else { bn_max };
        bk_max = if bk0 > bk_max { bk0 } else { bk_max };
        s += 1;
    }
    // Denominator in [1/3, 4) (Q24): the reciprocal stays below 3 (Q14 seed fits 16 bits,
    // Q29 reciprocal fits 31 bits).
    if !(d_lo >= qd / 3.0 && d_hi < 4.0 * qd) {
        return Some(false);
    }
    let d_lo_i = floor_i64(d_lo);
    let d_hi_i = ceil_i64(d_hi);
    let mut shift = 15;
    while ((d_hi_i - d_lo_i) >> shift) >= SEED_MAX as i64 {
        shift += 1;
    }
    b.d_lo_q24 = d_lo_i as i32;
    b.seed_shift = shift;
    let width = (1i64 << shift) as f64;
    let qr0 = (1i64 << Q_R0) as f64;
    let mut j = 0;
    while j < SEED_MAX {
        let a0 = (d_lo_i as f64 + j as f64 * width) / qd;
        let a1 = (d_lo_i as f64 + (j + 1) as f64 * width) / qd;
        let r_a = round_i64(qr0 / a0);
        let r_b = round_i64(qr0 / a1);
        b.seed[j] = [r_a as i32, (r_a - r_b) as i32];
        // Chord error of 1/d on [a0, a1] is (a1 - a0)^2 / (4 a0 a1); with the Q14 rounding it
        // must stay below 2^-8 so that one Newton step leaves < 2^-16 (real law: < 1e-6).
        let chord = (a1 - a0) * (a1 - a0) / (4.0 * a0 * a1) + 1.0 / qr0 * a1;
        if chord >= 1.0 / 256.0 || r_a >= 65_536 || (r_a - r_b) >= 65_536 {
            return Some(false);
        }
        j += 1;
    }
    // |q| <= |num| / d_lo (with the Newton residual), F = k + q must fit with margin.
    let bq = bn_max * qd / d_lo * 1.01 + 4.0;
    if bq + bk_max >= B30 {
        return Some(false);
    }
    Some(true)
}

// ---------------------------------------------------------------------------------------------
// Torque model (eq. 11) for a 32-bit core without FPU or divider.
//
//   T = (A r^2) alpha + (B r) dp + C v^3 + D v
//
// Inputs in their interface formats (alpha, v in Q16, dp in whole pascal), clamped to the
// domain below. Every term is one `term(c, s, x) = floor(c x / 2^s)`: a coefficient word `c`
// and shift `s` chosen here per term so that `c` keeps as many bits as the input's range
// allows while the intermediate floor(c x / 2^16) fits 31 bits (run time: three 32-bit
// `muls`, no 64-bit product). The terms add up in an internal torque format Q(qt), with qt
// the largest of 16..=28 for which the sum's proven bound fits 2^30. The inverse needs no
// division: 1/(B r) is a coefficient of the same kind, applied to the torque rest clamped to
// what dp_limit can reach.
// ---------------------------------------------------------------------------------------------

/// Angle domain of the fixed torque model: +-4 rad (Q16 bits), past the end stops (+-2.6 rad).
pub const TM_ANGLE_MAX_Q16: i32 = 4 << 16;
/// Velocity domain: +-16 rad/s (Q16 bits).
pub const TM_VELOCITY_MAX_Q16: i32 = 16 << 16;
/// dp domain of the forward model: +-2^20 Pa (beyond any gauge pressure of the muscles).
pub const TM_DP_MAX_PA: i32 = 1 << 20;
/// The scaled torque rest of the inverse stays below 2^24 (its coefficient keeps >= 22 bits).
pub const TM_REST_BITS: u32 = 24;

/// Bit patterns of the fixed-point torque model.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TorqueModelBits {
    /// False when the constants are not finite or their bounds do not fit the formats: the
    /// forward model then gives 0 N m and the inverse dp = 0, saturated.
    pub valid: bool,
    /// Internal torque format Q(qt), 16..=28.
    pub qt: u32,
    /// A r^2 term: coefficient word and shift (alpha in Q16 -> Q(qt)).
    pub a_c: i32,
    /// See [`TorqueModelBits::a_c`].
    pub a_s: u32,
    /// B r term (dp in Pa -> Q(qt)).
    pub b_c: i32,
    /// See [`TorqueModelBits::b_c`].
    pub b_s: u32,
    /// C term (v^3 in Q16 -> Q(qt)).
    pub c_c: i32,
    /// See [`TorqueModelBits::c_c`].
    pub c_s: u32,
    /// D term (v in Q16 -> Q(qt)).
    pub d_c: i32,
    /// See [`TorqueModelBits::d_c`].
    pub d_s: u32,
    /// 1/(B r): (rest >> rest_shift) in Q(qt - rest_shift) -> dp in Q1 (half pascal, for
    /// rounding). 0 when B r is 0 (the model cannot be inverted).
    pub inv_c: i32,
    /// See [`TorqueModelBits::inv_c`].
    pub inv_s: u32,
    /// See [`TorqueModelBits::inv_c`].
    pub rest_shift: u32,
    /// The inverse clamps the desired torque to +-t_clamp (Q16): past it dp saturates anyway.
    pub t_clamp_q16: i32,
    /// ... and the rest (torque minus passive torque, Q(qt)) to +-rest_lim = |B r| (dp_limit + 2).
    pub rest_lim: i32,
    /// p0 \[Pa\], rounded.
    pub p0_gauge_pa: i32,
    /// Usable |dp| \[Pa\], rounded down: `min(dp_max, p0, P_MAX - p0)`, at least 0.
    pub dp_limit_pa: i32,
}

/// The coefficient word and shift of `term(c, s, x) = floor(c x / 2^s)` for `v` output LSB
/// per input LSB and |x| <= x_max: the largest s in 16..=47 with |c| (x_max + 1) < 2^47 and
/// |c| < 2^31. None when even s = 16 does not fit (or v is not finite).
pub fn term_bits(v: f64, x_max: f64) -> Option<(i32, u32)> {
    if !v.is_finite() {
        return None;
    }
    if v == 0.0 {
        return Some((0, 16));
    }
    let mut s = 47u32;
    loop {
        let c = round_i64(v * (1u64 << s) as f64);
        let ca = abs(c as f64);
        if ca * (x_max + 1.0) < 140_737_488_355_328.0 && ca < 2_147_483_647.0 {
            return Some((c as i32, s));
        }
        if s == 16 {
            return None;
        }
        s -= 1;
    }
}

/// Pre-scales the torque-model constants (SI units, see `TorqueModelParams`).
pub fn torque_model_bits(
    a_n_per_m_rad: f64,
    b_m2: f64,
    c_nms3_per_rad3: f64,
    d_nms_per_rad: f64,
    sprocket_radius_m: f64,
    p0_gauge_pa: f64,
    dp_max_pa: f64,
) -> TorqueModelBits {
    let r = sprocket_radius_m;
    let a_r2 = a_n_per_m_rad * r * r;
    let b_r = b_m2 * r;
    let room = if p0_gauge_pa < P_MAX_PA - p0_gauge_pa {
        p0_gauge_pa
    } else {
        P_MAX_PA - p0_gauge_pa
    };
    let room = if room > 0.0 { room } else { 0.0 };
    let lim = if dp_max_pa < room { dp_max_pa } else { room };
    let lim = if lim > 0.0 { lim } else { 0.0 };
    let dp_limit_pa = sat_i32(floor_i64(lim));
    let mut b = TorqueModelBits {
        valid: false,
        qt: 16,
        a_c: 0,
        a_s: 16,
        b_c: 0,
        b_s: 16,
        c_c: 0,
        c_s: 16,
        d_c: 0,
        d_s: 16,
        inv_c: 0,
        inv_s: 16,
        rest_shift: 0,
        t_clamp_q16: 0,
        rest_lim: 0,
        p0_gauge_pa: sat_i32(round_i64(p0_gauge_pa)),
        dp_limit_pa,
    };
    let fin = |x: f64| x.is_finite();
    if !(fin(a_r2) && fin(b_r) && fin(c_nms3_per_rad3) && fin(d_nms_per_rad) && fin(p0_gauge_pa)) {
        return b;
    }
    // Bounds [N m] over the domain.
    let am = TM_ANGLE_MAX_Q16 as f64 / Q16;
    let vm = TM_VELOCITY_MAX_Q16 as f64 / Q16;
    let passive = abs(a_r2) * am + abs(c_nms3_per_rad3) * vm * vm * vm + abs(d_nms_per_rad) * vm;
    let active = abs(b_r) * TM_DP_MAX_PA as f64;
    let t_clamp = passive + abs(b_r) * (dp_limit_pa as f64 + 2.0) + 1.0;
    let bound = {
        let fwd = passive + active;
        let inv = t_clamp + passive;
        if fwd > inv {
            fwd
        } else {
            inv
        }
    };
    // Largest qt with bound 2^qt (+ a few LSB of floors) below 2^30.
    let mut qt = 28u32;
    while bound * (1u64 << qt) as f64 + 64.0 >= 1_073_741_824.0 {
        if qt == 16 {
            return b;
        }
        qt -= 1;
    }
    let sq = (1u64 << qt) as f64;
    let q16_to_qt = sq / Q16;
    // Inputs: alpha, v, v^3 in Q16 (|v^3| <= 16^3 2^16 + a few LSB), dp in Pa.
    let v3_max = vm * vm * vm * Q16 + 64.0;
    let (Some(a), Some(bb), Some(c), Some(d)) = (
        term_bits(a_r2 * q16_to_qt, TM_ANGLE_MAX_Q16 as f64),
        term_bits(b_r * sq, TM_DP_MAX_PA as f64),
        term_bits(c_nms3_per_rad3 * q16_to_qt, v3_max),
        term_bits(d_nms_per_rad * q16_to_qt, TM_VELOCITY_MAX_Q16 as f64),
    ) else {
        return b;
    };
    (b.a_c, b.a_s, b.b_c, b.b_s, b.c_c, b.c_s, b.d_c, b.d_s) =
        (a.0, a.1, bb.0, bb.1, c.0, c.1, d.0, d.1);
    b.qt = qt;
    b.t_clamp_q16 = sat_i32(ceil_i64(t_clamp * Q16));
    if b_r != 0.0 {
        let rest_lim = ceil_i64(abs(b_r) * (dp_limit_pa as f64 + 2.0) * sq);
        let mut k = 0u32;
        while (rest_lim >> k) >= (1i64 << TM_REST_BITS) {
            k += 1;
        }
        // dp [Q1 Pa] = rest 2^k / 2^qt / (B r) * 2.
        let Some(inv) = term_bits(
            2.0 * (1u64 << k) as f64 / (sq * b_r),
            ((rest_lim >> k) + 1) as f64,
        ) else {
            return b;
        };
        b.rest_lim = rest_lim as i32;
        b.rest_shift = k;
        (b.inv_c, b.inv_s) = inv;
    }
    b.valid = true;
    b
}
