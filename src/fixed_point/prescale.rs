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
/// Knots of the exp(e - 0.7) table: 8 equal intervals over the stretch domain.
pub const EXP_KNOTS: usize = 9;
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

/// Bit patterns of the fixed-point force law.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ForceLawBits {
    /// c1..c10 in Q32 (I32F32).
    pub c_q32: [i64; 10],
    /// Highest gauge pressure \[Pa\], rounded down (I32F0).
    pub p_gauge_max_pa: i32,
    /// Lowest stretch in Q16 (I16F16), rounded up: the fixed domain lies inside the f32 one,
    /// so a Q16 input is flagged exactly when its value is flagged by the f32 law.
    pub stretch_min_q16: i32,
    /// Highest stretch in Q16 (I16F16), rounded down (see `stretch_min_q16`).
    pub stretch_max_q16: i32,
    /// Stretch at the exp-table knots in Q32 (exact: derived from the Q16 bounds).
    pub knot_q32: [i64; EXP_KNOTS],
    /// c10 * exp(knot - 0.7) in Q32.
    pub c10_exp_q32: [i64; EXP_KNOTS],
    /// 1 / knot spacing in Q32 (0 for an empty domain).
    pub inv_knot_step_q32: i64,
}

/// Pre-scales the force-law constants (c1..c10 with P in MPa, e = L/L0).
pub fn force_law_bits(
    c: [f64; 10],
    p_gauge_max_pa: f64,
    stretch_min: f64,
    stretch_max: f64,
    exp: fn(f64) -> f64,
) -> ForceLawBits {
    let mut c_q32 = [0i64; 10];
    let mut i = 0;
    while i < 10 {
        c_q32[i] = round_i64(c[i] * Q32);
        i += 1;
    }
    let smin = sat_i32(ceil_i64(stretch_min * Q16));
    let smax = sat_i32(floor_i64(stretch_max * Q16));
    let smax = if smax < smin { smin } else { smax };
    let min_q32 = (smin as i64) << 16;
    let span_q32 = ((smax as i64) - (smin as i64)) << 16;
    let step_q32 = span_q32 / (EXP_KNOTS as i64 - 1);
    let inv_knot_step_q32 = if step_q32 > 0 {
        round_i64(Q32 * Q32 / step_q32 as f64)
    } else {
        0
    };
    let mut knot_q32 = [0i64; EXP_KNOTS];
    let mut c10_exp_q32 = [0i64; EXP_KNOTS];
    let mut k = 0;
    while k < EXP_KNOTS {
        let knot = min_q32 + (k as i64) * step_q32;
        knot_q32[k] = knot;
        c10_exp_q32[k] = round_i64(c[9] * exp(knot as f64 / Q32 - EXP_OFFSET) * Q32);
        k += 1;
    }
    ForceLawBits {
        c_q32,
        p_gauge_max_pa: sat_i32(floor_i64(p_gauge_max_pa)),
        stretch_min_q16: smin,
        stretch_max_q16: smax,
        knot_q32,
        c10_exp_q32,
        inv_knot_step_q32,
    }
}

/// Bit patterns of the fixed-point torque model.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TorqueModelBits {
    /// A r^2 \[N m/rad\] in Q32.
    pub a_r2_q32: i64,
    /// B r \[N m/Pa\] in Q48 (I16F48): B r is ~1e-5, Q32 would keep only ~5 digits.
    pub b_r_q48: i64,
    /// C \[N m s^3/rad^3\] in Q32.
    pub c_q32: i64,
    /// D \[N m s/rad\] in Q32.
    pub d_q32: i64,
    /// 1 / (B r) \[Pa/(N m)\] in Q32; 0 when B r is 0 (the model cannot be inverted).
    pub inv_b_r_q32: i64,
    /// p0 \[Pa\], rounded.
    pub p0_gauge_pa: i32,
    /// Usable |dp| \[Pa\], rounded down: `min(dp_max, p0, P_MAX - p0)`, at least 0.
    pub dp_limit_pa: i32,
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
    let b_r = b_m2 * r;
    let room = if p0_gauge_pa < P_MAX_PA - p0_gauge_pa {
        p0_gauge_pa
    } else {
        P_MAX_PA - p0_gauge_pa
    };
    let room = if room > 0.0 { room } else { 0.0 };
    let lim = if dp_max_pa < room { dp_max_pa } else { room };
    let lim = if lim > 0.0 { lim } else { 0.0 };
    TorqueModelBits {
        a_r2_q32: round_i64(a_n_per_m_rad * r * r * Q32),
        b_r_q48: round_i64(b_r * Q48),
        c_q32: round_i64(c_nms3_per_rad3 * Q32),
        d_q32: round_i64(d_nms_per_rad * Q32),
        inv_b_r_q32: if b_r != 0.0 { round_i64(Q32 / b_r) } else { 0 },
        p0_gauge_pa: sat_i32(round_i64(p0_gauge_pa)),
        dp_limit_pa: sat_i32(floor_i64(lim)),
    }
}
