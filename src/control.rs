//! Pure control laws of the cascade of seed 003 Fig. 5 (position -> torque -> pressure),
//! each `step(&mut self, measurement, setpoint, dt) -> Result<command, ControlError>`:
//! no hidden time, no register types, no allocation.
//!
//! 1. [`PositionController`]: PID on the joint angle with derivative on measurement (the
//!    velocity estimate) and anti-windup (conditional integration + integrator clamp);
//!    output: desired joint torque [N m].
//! 2. [`TorqueController`]: torque feedback `T_est = (F1 - F2) r` with `F_i` from the
//!    identified force law at the measured pressure and the stretch of the measured angle,
//!    a PI correction on the torque error, and the inverse torque model (seed 003 eq. 11)
//!    giving the activation `dp`; output: symmetric pressure set-points
//!    `p1 = p0 - dp`, `p2 = p0 + dp`, clamped to [0, 600 kPa] gauge.
//! 3. [`PressureController`]: per muscle, P or PI with a deadband; output: valve command
//!    in [-1, 1] (> 0 inflate, < 0 exhaust).
//!
//! Every input may be NaN (ODrive `PhaseControlLaw` style): a non-finite input or result
//! returns [`ControlError`] and resets the law's internal state, so one bad value cannot
//! poison an integrator; the caller disarms.

use crate::force_law::{ForceEstimate, ForceFlags, ForceLawParams};
use crate::geometry::JointGeometry;
use crate::safety::{clamp_pressure_setpoint_pa, clamp_setpoint_to};
use crate::torque_model::TorqueModelParams;

/// Why a control law refused to produce a command.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ControlError {
    /// A measurement, set-point or dt was NaN / infinite (or dt <= 0).
    NonFiniteInput,
    /// An internal result was not finite (bad gains).
    NonFiniteOutput,
    /// The force law could not evaluate the measured state (singular).
    ForceLawInvalid,
}

/// Anti-windup input: which way the command downstream of a loop fell short of the request
/// last tick, in the loop's output direction (joint torque for the position and torque
/// loops): > 0 the applied command was below the requested one (more could not be
/// delivered: a pressure set-point or dp at its limit, valves fully open), < 0 above it, 0
/// nothing saturated. Only the sign is used: the integrator does not integrate in that
/// direction (conditional integration on the command actually applied).
pub type Shortfall = f32;

/// True when an integrator increment `di` would push further the way `shortfall` says the
/// downstream cannot follow.
#[inline(always)]
pub fn blocks(shortfall: Shortfall, di: f32) -> bool {
    di * shortfall > 0.0
}

/// A shortfall of the torque loop's command below this [N m] is float rounding, not
/// saturation.
const SHORTFALL_TOL_NM: f32 = 1e-4;

#[inline]
pub(crate) fn finite(xs: &[f32]) -> bool {
    // Branch-free: `x * 0` is +-0 for every finite x and NaN for NaN and +-inf, so the sum is
    // 0 exactly when all are finite (about 2 instructions per value on the Cortex-M4F
    // instead of a compare-and-branch chain).
    let mut acc = 0.0f32;
    for &x in xs {
        acc += x * 0.0;
    }
    acc == 0.0
}

#[inline]
fn clampf(x: f32, lim: f32) -> f32 {
    let lim = libm::fabsf(lim);
    // Usual case first, one comparison: |x| <= lim means x is returned below too (also for
    // x = -0); NaN x or lim fail it and take the full chain, which returns x then.
    if libm::fabsf(x) <= lim {
        x
    } else if x > lim {
        lim
    } else if x < -lim {
        -lim
    } else {
        x
    }
}

/// Gains of the position PID (angle error -> joint torque).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PidGains {
    /// Proportional gain [N m/rad].
    pub kp_nm_per_rad: f32,
    /// Integral gain [N m/(rad s)].
    pub ki_nm_per_rad_s: f32,
    /// Derivative gain [N m s/rad] (acts on the measured velocity, not on the error).
    pub kd_nm_s_per_rad: f32,
    /// |integral term| limit [N m].
    pub i_limit_nm: f32,
    /// |output| limit [N m].
    pub out_limit_nm: f32,
}

/// What the position loop measures.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct JointState {
    /// Joint angle [rad].
    pub angle_rad: f32,
    /// Joint velocity [rad/s].
    pub velocity_rad_s: f32,
}

/// Outer loop: angle -> desired joint torque.
///
/// `T = kp e + I - kd omega`, `I += ki e dt` (clamped to `i_limit`), where the integrator
/// only moves when the output is not saturated or the error drives it back out of
/// saturation (conditional integration).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PositionController {
    /// Gains.
    pub gains: PidGains,
    integral_nm: f32,
}

impl PositionController {
    /// A controller with a zero integrator.
    pub const fn new(gains: PidGains) -> Self {
        PositionController {
            gains,
            integral_nm: 0.0,
        }
    }

    /// Integrator state [N m].
    pub fn integral_nm(&self) -> f32 {
        self.integral_nm
    }

    /// Clears the integrator.
    pub fn reset(&mut self) {
        self.integral_nm = 0.0;
    }

    /// One step: desired joint torque [N m].
    pub fn step(
        &mut self,
        meas: JointState,
        setpoint_rad: f32,
        dt_s: f32,
    ) -> Result<f32, ControlError> {
        self.step_limited(meas, setpoint_rad, dt_s, 0.0)
    }

    /// [`Self::step`] with anti-windup from downstream: `downstream` ([`Shortfall`]) says
    /// which way the torque actually applied last tick fell short of the command (torque
    /// loop at its pressure or activation limits, valves fully open); the integrator does not
    /// move that way. 0 gives exactly [`Self::step`].
    pub fn step_limited(
        &mut self,
        meas: JointState,
        setpoint_rad: f32,
        dt_s: f32,
        downstream: Shortfall,
    ) -> Result<f32, ControlError> {
        if !finite(&[meas.angle_rad, meas.velocity_rad_s, setpoint_rad, dt_s]) || dt_s <= 0.0 {
            self.reset();
            return Err(ControlError::NonFiniteInput);
        }
        let out = self.step_finite(meas, setpoint_rad, dt_s, downstream)?;
        // `step_finite` relies on finite limits (a validated configuration) to tell a
        // non-finite result by NaN alone; gains given here directly may have infinite ones.
        if !finite(&[out, self.integral_nm]) {
            self.reset();
            return Err(ControlError::NonFiniteOutput);
        }
        Ok(out)
    }

    /// [`Self::step`] without its input check, for a caller that has validated the inputs
    /// (all finite, `dt_s > 0`): then the same result, bit for bit.
    #[inline(always)]
    pub(crate) fn step_finite(
        &mut self,
        meas: JointState,
        setpoint_rad: f32,
        dt_s: f32,
        downstream: Shortfall,
    ) -> Result<f32, ControlError> {
        let g = &self.gains;
        let e = setpoint_rad - meas.angle_rad;
        let pd = g.kp_nm_per_rad * e - g.kd_nm_s_per_rad * meas.velocity_rad_s;
        let unsat = pd + self.integral_nm;
        let lim = libm::fabsf(g.out_limit_nm);
        let saturated_high = unsat > lim;
        let saturated_low = unsat < -lim;
        let di = g.ki_nm_per_rad_s * e * dt_s;
        // Conditional integration: do not integrate further into saturation. (Unsaturated
        // - the usual case - is decided by one comparison; NaN takes the full test.)
        let within = libm::fabsf(unsat) <= lim;
        if (within || !((saturated_high && di > 0.0) || (saturated_low && di < 0.0)))
            && !blocks(downstream, di)
        {
            self.integral_nm = clampf(self.integral_nm + di, g.i_limit_nm);
        }
        let out = clampf(pd + self.integral_nm, lim);
        // Both are clamped to the limits, which the control tick's validated configuration
        // makes finite: each is then finite or NaN, and their sum is NaN exactly when one of
        // them is (`step_limited` checks the general case).
        if (out + self.integral_nm).is_nan() {
            self.reset();
            return Err(ControlError::NonFiniteOutput);
        }
        Ok(out)
    }
}

/// Gains of the torque loop's PI correction.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TorqueLoopGains {
    /// Proportional gain on the torque error [N m / N m].
    pub kp: f32,
    /// Integral gain on the torque error [1/s].
    pub ki_per_s: f32,
    /// |correction| limit [N m] (integrator and total correction).
    pub corr_limit_nm: f32,
    /// Ceiling of the pressure set-points [Pa gauge] (further capped at 600 kPa).
    pub p_set_max_gauge_pa: f32,
}

/// What the torque loop measures.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TorqueMeasurement {
    /// Muscle 1 gauge pressure [Pa].
    pub p1_gauge_pa: f32,
    /// Muscle 2 gauge pressure [Pa].
    pub p2_gauge_pa: f32,
    /// Joint angle [rad].
    pub angle_rad: f32,
    /// Joint velocity [rad/s].
    pub velocity_rad_s: f32,
}

/// Result of the torque loop.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PressureSetpoints {
    /// Muscle 1 set-point [Pa gauge], in [0, 600 kPa].
    pub p1_gauge_pa: f32,
    /// Muscle 2 set-point [Pa gauge], in [0, 600 kPa].
    pub p2_gauge_pa: f32,
    /// Activation dp [Pa].
    pub dp_pa: f32,
    /// Static muscle torque from the force law, `(F1 - F2) r` [N m].
    pub torque_est_nm: f32,
    /// True when the inverse model saturated dp.
    pub saturated: bool,
    /// The loop's command minus the torque the applied set-points give (dp at its limit or a
    /// pressure set-point clamped) [N m], 0 when not saturated: the position loop's
    /// anti-windup input ([`Shortfall`]) for the next tick.
    pub shortfall_nm: f32,
    /// Union of the force-law flags of both muscles (clamped inputs etc.).
    pub force_flags: ForceFlags,
}

/// Static joint torque `(F1 - F2) r` [N m] from the force law at the measured pressures
/// and the stretches of the measured angle, with the force-law flags of both muscles.
#[inline]
pub fn torque_estimate_nm(
    force_law: &ForceLawParams,
    geometry: &JointGeometry,
    p1_gauge_pa: f32,
    p2_gauge_pa: f32,
    angle_rad: f32,
) -> (f32, ForceFlags) {
    torque_from(
        |p, e| force_law.force_inline(p, e),
        geometry,
        p1_gauge_pa,
        p2_gauge_pa,
        angle_rad,
    )
}

/// [`torque_estimate_nm`] with the force law's evaluation `force(p_gauge_pa, stretch)` given:
/// the control tick passes [`ForceLawParams::force_regular`] (the same bits for a law that is
/// [regular](ForceLawParams::is_regular), finite pressures and an angle whose stretches are
/// finite: its validated configuration and channels, without the tests that cannot fail
/// there).
#[inline(always)]
pub(crate) fn torque_from(
    force: impl Fn(f32, f32) -> ForceEstimate,
    geometry: &JointGeometry,
    p1_gauge_pa: f32,
    p2_gauge_pa: f32,
    angle_rad: f32,
) -> (f32, ForceFlags) {
    let (e1, e2) = geometry.stretches(angle_rad);
    let f1 = force(p1_gauge_pa, e1);
    let f2 = force(p2_gauge_pa, e2);
    (
        (f1.force_n - f2.force_n) * geometry.sprocket_radius_m,
        f1.flags.union(f2.flags),
    )
}

/// Middle loop: desired joint torque -> pressure set-points.
///
/// ```text
/// T_est   = (F1(p1, e1(alpha)) - F2(p2, e2(alpha))) r           (static, force law)
/// T_err   = (T_des - D alpha' - C alpha'^3) - T_est               (static part of T_des)
/// T_cmd   = T_des + kp T_err + I,   I += ki T_err dt              (|I|, |kp T_err + I| <= corr_limit)
/// dp      = TORQUE_MODEL.activation(T_cmd, alpha, alpha')        (inverse of eq. 11)
/// p1, p2  = p0 - dp, p0 + dp                                      (clamped, <= 600 kPa)
/// ```
///
/// The integrator is frozen while the inverse model saturates (anti-windup).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TorqueController {
    /// Gains.
    pub gains: TorqueLoopGains,
    /// Force law for the torque feedback.
    pub force_law: ForceLawParams,
    /// Geometry for the stretches and the radius.
    pub geometry: JointGeometry,
    /// Torque model for the inverse (feed-forward) path.
    pub model: TorqueModelParams,
    integral_nm: f32,
    /// [`PressureSetpoints::shortfall_nm`] of the last step (anti-windup).
    shortfall_nm: f32,
}

impl TorqueController {
    /// A torque loop with a zero integrator.
    pub const fn new(
        gains: TorqueLoopGains,
        force_law: ForceLawParams,
        geometry: JointGeometry,
        model: TorqueModelParams,
    ) -> Self {
        TorqueController {
            gains,
            force_law,
            geometry,
            model,
            integral_nm: 0.0,
            shortfall_nm: 0.0,
        }
    }

    /// Integrator state [N m].
    pub fn integral_nm(&self) -> f32 {
        self.integral_nm
    }

    /// Clears the integrator and the anti-windup state.
    pub fn reset(&mut self) {
        self.integral_nm = 0.0;
        self.shortfall_nm = 0.0;
    }

    /// The last step's [`PressureSetpoints::shortfall_nm`] (0 after a reset).
    pub fn shortfall_nm(&self) -> f32 {
        self.shortfall_nm
    }

    /// One step: pressure set-points for the desired torque `torque_des_nm`.
    pub fn step(
        &mut self,
        meas: TorqueMeasurement,
        torque_des_nm: f32,
        dt_s: f32,
    ) -> Result<PressureSetpoints, ControlError> {
        let estimate = torque_estimate_nm(
            &self.force_law,
            &self.geometry,
            meas.p1_gauge_pa,
            meas.p2_gauge_pa,
            meas.angle_rad,
        );
        self.step_with_estimate(meas, estimate, torque_des_nm, dt_s)
    }

    /// [`TorqueController::step`] with the force-law torque estimate already computed by the
    /// caller as `torque_estimate_nm(&self.force_law, &self.geometry, p1, p2, angle)` of this
    /// `meas` (the control tick computes it once for its log and its feedback). Passing an
    /// estimate of other inputs or another force law gives a different loop.
    pub fn step_with_estimate(
        &mut self,
        meas: TorqueMeasurement,
        estimate: (f32, ForceFlags),
        torque_des_nm: f32,
        dt_s: f32,
    ) -> Result<PressureSetpoints, ControlError> {
        if !finite(&[
            meas.p1_gauge_pa,
            meas.p2_gauge_pa,
            meas.angle_rad,
            meas.velocity_rad_s,
            torque_des_nm,
            dt_s,
        ]) || dt_s <= 0.0
        {
            self.reset();
            return Err(ControlError::NonFiniteInput);
        }
        let dp_limit_pa = self.model.dp_limit_pa();
        let p_set_hi_pa = clamp_pressure_setpoint_pa(f32::INFINITY, self.gains.p_set_max_gauge_pa);
        self.step_finite(
            meas,
            estimate,
            torque_des_nm,
            dt_s,
            dp_limit_pa,
            p_set_hi_pa,
            0.0,
        )
    }

    /// [`Self::step_with_estimate`] without its input check, for a caller that has
    /// validated the inputs (all finite, `dt_s > 0`) and passes the configuration constants
    /// `dp_limit_pa = self.model.dp_limit_pa()` and `p_set_hi_pa =
    /// clamp_pressure_setpoint_pa(f32::INFINITY, self.gains.p_set_max_gauge_pa)`: then the
    /// same result, bit for bit.
    // The tick's hot path: the inputs in registers, not packed into a struct for one call.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(crate) fn step_finite(
        &mut self,
        meas: TorqueMeasurement,
        estimate: (f32, ForceFlags),
        torque_des_nm: f32,
        dt_s: f32,
        dp_limit_pa: f32,
        p_set_hi_pa: f32,
        downstream: Shortfall,
    ) -> Result<PressureSetpoints, ControlError> {
        let (t_est, flags) = estimate;
        if flags.contains_any(ForceFlags::FATAL) {
            self.reset();
            return Err(ControlError::ForceLawInvalid);
        }
        let v = meas.velocity_rad_s;
        let m = &self.model;
        let t_dyn = m.d_nms_per_rad * v + m.c_nms3_per_rad3 * v * v * v;
        let t_err = (torque_des_nm - t_dyn) - t_est;
        let g = &self.gains;
        let lim = libm::fabsf(g.corr_limit_nm);
        // Angle and velocity are finite here.
        let inverse = m.inverse_at_finite(meas.angle_rad, v, dp_limit_pa);
        // Anti-windup: conditional integration on the command actually applied. The
        // integrator does not move the way the last command fell short (dp at its limit or a
        // pressure set-point clamped) or the way the valves could not follow (`downstream`).
        let di = g.ki_per_s * t_err * dt_s;
        if !blocks(self.shortfall_nm + downstream, di) {
            self.integral_nm = clampf(self.integral_nm + di, lim);
        }
        let t_cmd = torque_des_nm + clampf(g.kp * t_err + self.integral_nm, lim);
        let act = inverse.activation(t_cmd);
        // `clamp_pressure_setpoint_pa(m.pressures_gauge_pa(dp), p_set_max)` in one clamp per
        // muscle (the same value for every input: both map NaN and p <= 0 to +0, and the
        // bound is min(p_set_max, P_MUSCLE_MAX) <= the model's own bound).
        let p1 = clamp_setpoint_to(m.p0_gauge_pa - act.dp_pa, p_set_hi_pa);
        let p2 = clamp_setpoint_to(m.p0_gauge_pa + act.dp_pa, p_set_hi_pa);
        // What these set-points give against what was asked (sign = direction of the limit).
        let short = t_cmd - inverse.torque_nm(0.5 * (p2 - p1));
        self.shortfall_nm = if libm::fabsf(short) > SHORTFALL_TOL_NM {
            short
        } else {
            0.0
        };
        // p1, p2 (clamped, NaN -> 0) and dp (finite by construction of `activation`) are
        // always finite.
        if !finite(&[t_est, t_cmd, self.integral_nm]) {
            self.reset();
            return Err(ControlError::NonFiniteOutput);
        }
        Ok(PressureSetpoints {
            p1_gauge_pa: p1,
            p2_gauge_pa: p2,
            dp_pa: act.dp_pa,
            torque_est_nm: t_est,
            saturated: act.saturated,
            shortfall_nm: self.shortfall_nm,
            force_flags: flags,
        })
    }
}

/// Gains of a per-muscle pressure loop. Units: `kp` [1/Pa], `ki` [1/(Pa s)].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PressureLoopGains {
    /// Proportional gain (valve command per Pa of error).
    pub kp_per_pa: f32,
    /// Integral gain (0 = pure P).
    pub ki_per_pa_s: f32,
    /// |error| at or below this gives command 0 (valves closed) and freezes the integrator [Pa].
    pub deadband_pa: f32,
    /// |integral term| limit (valve command units, <= 1).
    pub i_limit: f32,
}

/// Inner loop: pressure set-point -> valve command in [-1, 1].
///
/// `u = kp e + I` outside the deadband, 0 inside it; `I += ki e dt` only outside the
/// deadband and when `u` is not saturated in the direction of `e` (anti-windup).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PressureController {
    /// Gains.
    pub gains: PressureLoopGains,
    integral: f32,
}

impl PressureController {
    /// A loop with a zero integrator.
    pub const fn new(gains: PressureLoopGains) -> Self {
        PressureController {
            gains,
            integral: 0.0,
        }
    }

    /// Clears the integrator.
    pub fn reset(&mut self) {
        self.integral = 0.0;
    }

    /// One step: valve command in [-1, 1] (> 0 inflate, < 0 exhaust, 0 closed).
    pub fn step(
        &mut self,
        p_meas_gauge_pa: f32,
        p_set_gauge_pa: f32,
        dt_s: f32,
    ) -> Result<f32, ControlError> {
        if !finite(&[p_meas_gauge_pa, p_set_gauge_pa, dt_s]) || dt_s <= 0.0 {
            self.reset();
            return Err(ControlError::NonFiniteInput);
        }
        self.step_finite(p_meas_gauge_pa, p_set_gauge_pa, dt_s)
    }

    /// [`Self::step`] without its input check, for a caller that has validated the inputs
    /// (all finite, `dt_s > 0`): then the same result, bit for bit.
    #[inline(always)]
    pub(crate) fn step_finite(
        &mut self,
        p_meas_gauge_pa: f32,
        p_set_gauge_pa: f32,
        dt_s: f32,
    ) -> Result<f32, ControlError> {
        let g = &self.gains;
        let e = p_set_gauge_pa - p_meas_gauge_pa;
        if libm::fabsf(e) <= g.deadband_pa {
            return Ok(0.0);
        }
        let p = g.kp_per_pa * e;
        // P-only loop (ki = 0, the reference) with the integrator at +0: `di` is +-0 (finite
        // e and dt), +0 + +-0 = +0 and clampf(+0, any limit) = +0, so the integrator update
        // below would leave it bit for bit unchanged; skip it.
        let integral_idle = g.ki_per_pa_s == 0.0 && self.integral.to_bits() == 0;
        if !integral_idle {
            let di = g.ki_per_pa_s * e * dt_s;
            let unsat = p + self.integral;
            if !((unsat >= 1.0 && di > 0.0) || (unsat <= -1.0 && di < 0.0)) {
                self.integral = clampf(self.integral + di, g.i_limit);
            }
        }
        let u = clampf(p + self.integral, 1.0);
        // Clamped to [-1, 1]: finite unless NaN.
        if u.is_nan() {
            self.reset();
            return Err(ControlError::NonFiniteOutput);
        }
        Ok(u)
    }
}

/// A saturated step, with and without anti-windup from downstream: the joint (inertia
/// 0.01 kg m^2, damping 0.05 N m s/rad) only receives +-0.8 N m (the torque the
/// pressures can give), far below the position loop's own 10 N m limit, so the loop's
/// conditional integration alone never sees saturation. Step 0 -> 1 rad, 4 s at 1 kHz.
/// Returns (overshoot [rad], largest integrator [N m], settling time to +-0.02 rad [s]).
/// A test scenario: the host tests and the on-target tests (src/bin/on_target.rs) run it.
#[cfg(any(test, feature = "on-target-tests"))]
#[doc(hidden)]
pub fn saturated_step(anti_windup: bool) -> (f32, f32, f32) {
    let mut c = PositionController::new(PidGains {
        kp_nm_per_rad: 4.0,
        ki_nm_per_rad_s: 10.0,
        kd_nm_s_per_rad: 0.3,
        i_limit_nm: 2.0,
        out_limit_nm: 10.0,
    });
    let (j, b, t_sat, dt) = (0.01f32, 0.05f32, 0.8f32, 1e-3f32);
    let (mut a, mut w) = (0.0f32, 0.0f32);
    let mut short = 0.0f32;
    let (mut peak, mut i_max, mut settled_at) = (0.0f32, 0.0f32, 0.0f32);
    for k in 0..4000 {
        let meas = JointState {
            angle_rad: a,
            velocity_rad_s: w,
        };
        let down = if anti_windup { short } else { 0.0 };
        let t_cmd = c.step_limited(meas, 1.0, dt, down).unwrap();
        let t_applied = t_cmd.clamp(-t_sat, t_sat);
        short = t_cmd - t_applied;
        w += (t_applied - b * w) / j * dt;
        a += w * dt;
        peak = peak.max(a);
        i_max = i_max.max(c.integral_nm().abs());
        if (a - 1.0).abs() > 0.02 {
            settled_at = (k + 1) as f32 * dt;
        }
    }
    (peak - 1.0, i_max, settled_at)
}

/// The input check every position loop (`step(meas, setpoint_rad, dt_s)`) shares, for its
/// unit tests: after `warm_up` steps towards `setpoint_rad` from rest the integral is
/// positive; a NaN set-point is [`ControlError::NonFiniteInput`] and zeroes it; an infinite
/// angle or velocity and a period of 0, below 0 or NaN are errors.
#[cfg(test)]
pub(crate) fn assert_refuses_bad_inputs_and_resets<C, T: core::fmt::Debug>(
    c: &mut C,
    step: fn(&mut C, JointState, f32, f32) -> Result<T, ControlError>,
    integral: fn(&C) -> f32,
    setpoint_rad: f32,
    warm_up: usize,
) {
    let rest = JointState {
        angle_rad: 0.0,
        velocity_rad_s: 0.0,
    };
    for _ in 0..warm_up {
        step(c, rest, setpoint_rad, 1e-3).unwrap();
    }
    assert!(integral(c) > 0.0);
    let r = step(c, rest, f32::NAN, 1e-3);
    assert!(matches!(r, Err(ControlError::NonFiniteInput)), "{r:?}");
    assert_eq!(integral(c), 0.0);
    for bad in [
        JointState {
            angle_rad: f32::INFINITY,
            ..rest
        },
        JointState {
            velocity_rad_s: f32::INFINITY,
            ..rest
        },
    ] {
        assert!(step(c, bad, 0.0, 1e-3).is_err(), "{bad:?}");
    }
    for dt_s in [0.0, -1e-3, f32::NAN] {
        assert!(step(c, rest, 0.0, dt_s).is_err(), "dt_s = {dt_s}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::constants::{FORCE_LAW, TORQUE_MODEL};
    use crate::P_MUSCLE_MAX_GAUGE_PA;

    fn pid() -> PositionController {
        PositionController::new(PidGains {
            kp_nm_per_rad: 4.0,
            ki_nm_per_rad_s: 10.0,
            kd_nm_s_per_rad: 0.3,
            i_limit_nm: 2.0,
            out_limit_nm: 10.0,
        })
    }

    #[test]
    fn position_loop_with_infinite_limits_refuses_an_infinite_output() {
        // Gains given directly (not through a validated tick configuration) may have
        // infinite limits; an overflowing output is still an error, never +-inf.
        let mut p = PositionController::new(PidGains {
            kp_nm_per_rad: f32::MAX,
            ki_nm_per_rad_s: 0.0,
            kd_nm_s_per_rad: 0.0,
            i_limit_nm: f32::INFINITY,
            out_limit_nm: f32::INFINITY,
        });
        let meas = JointState {
            angle_rad: 0.0,
            velocity_rad_s: 0.0,
        };
        assert_eq!(p.step(meas, 2.0, 1e-3), Err(ControlError::NonFiniteOutput));
        // Within range the same gains work.
        assert_eq!(p.step(meas, 0.0, 1e-3), Ok(0.0));
    }

    const EDGE_VALUES: [f32; 14] = [
        0.0,
        -0.0,
        1e-45,
        -1e-45,
        0.5,
        -0.5,
        1.0,
        -1.0,
        3.0,
        -3.0,
        f32::MAX,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::NAN,
    ];

    #[test]
    fn clampf_matches_the_plain_comparison_chain_bitwise() {
        // The chain `clampf` had before its in-range fast path.
        let chain = |x: f32, lim: f32| {
            let lim = libm::fabsf(lim);
            if x > lim {
                lim
            } else if x < -lim {
                -lim
            } else {
                x
            }
        };
        for x in EDGE_VALUES {
            for lim in EDGE_VALUES {
                assert_eq!(
                    clampf(x, lim).to_bits(),
                    chain(x, lim).to_bits(),
                    "x {x:e} lim {lim:e}"
                );
            }
        }
    }

    #[test]
    fn p_only_pressure_loop_matches_the_full_integrator_update_bitwise() {
        // The loop before the P-only skip of the integrator update (same gains, kp = 0 too,
        // which makes p = -0 for negative errors: the sign of zero must survive).
        struct Reference {
            g: PressureLoopGains,
            integral: f32,
        }
        impl Reference {
            fn step(&mut self, p_meas: f32, p_set: f32, dt_s: f32) -> f32 {
                let g = &self.g;
                let e = p_set - p_meas;
                if libm::fabsf(e) <= g.deadband_pa {
                    return 0.0;
                }
                let p = g.kp_per_pa * e;
                let di = g.ki_per_pa_s * e * dt_s;
                let unsat = p + self.integral;
                if !((unsat >= 1.0 && di > 0.0) || (unsat <= -1.0 && di < 0.0)) {
                    self.integral = clampf(self.integral + di, g.i_limit);
                }
                clampf(p + self.integral, 1.0)
            }
        }
        for (kp, i_limit) in [
            (1.0 / 30_000.0, 0.0),
            (0.0, 0.0),
            (1e-4, 5.0),
            (0.0, f32::NAN),
        ] {
            for ki in [0.0f32, -0.0] {
                let g = PressureLoopGains {
                    kp_per_pa: kp,
                    ki_per_pa_s: ki,
                    deadband_pa: 3_000.0,
                    i_limit,
                };
                let mut reference = Reference { g, integral: 0.0 };
                let mut fast = PressureController::new(g);
                for k in 0..2_000 {
                    let x = k as f32;
                    let p_meas = 300_000.0 + 200_000.0 * libm::sinf(0.013 * x);
                    let p_set = 300_000.0 + 250_000.0 * libm::sinf(0.007 * x + 1.0);
                    let want = reference.step(p_meas, p_set, 1e-3);
                    let got = fast.step(p_meas, p_set, 1e-3).unwrap();
                    assert_eq!(got.to_bits(), want.to_bits(), "kp {kp} ki {ki} tick {k}");
                    assert_eq!(fast.integral.to_bits(), reference.integral.to_bits());
                }
            }
        }
    }

    #[test]
    fn finite_rejects_exactly_nan_and_infinities() {
        let ok = [
            0.0f32,
            -0.0,
            1.0,
            -3e38,
            f32::MIN_POSITIVE,
            f32::MAX,
            f32::MIN,
            1e-45,
        ];
        assert!(finite(&ok));
        assert!(finite(&[]));
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -f32::NAN] {
            for pos in 0..ok.len() {
                let mut xs = ok;
                xs[pos] = bad;
                assert!(!finite(&xs), "{bad} at {pos}");
            }
        }
    }

    #[test]
    fn torque_step_with_the_callers_estimate_equals_step() {
        // The control tick passes its own force-law estimate; the loop must then behave bit
        // for bit as if it had computed it, over a spread of states and a running integrator.
        let mut a = torque_loop();
        let mut b = torque_loop();
        for k in 0..400 {
            let x = k as f32;
            let meas = TorqueMeasurement {
                p1_gauge_pa: 300_000.0 + 250_000.0 * libm::sinf(0.05 * x),
                p2_gauge_pa: 300_000.0 - 250_000.0 * libm::sinf(0.031 * x),
                angle_rad: 0.5 * libm::sinf(0.02 * x),
                velocity_rad_s: 2.0 * libm::cosf(0.07 * x),
            };
            let t_des = 8.0 * libm::sinf(0.013 * x);
            let est = torque_estimate_nm(
                &b.force_law,
                &b.geometry,
                meas.p1_gauge_pa,
                meas.p2_gauge_pa,
                meas.angle_rad,
            );
            assert_eq!(
                a.step(meas, t_des, 1e-3),
                b.step_with_estimate(meas, est, t_des, 1e-3)
            );
            assert_eq!(a.integral_nm().to_bits(), b.integral_nm().to_bits());
        }
    }

    fn torque_loop() -> TorqueController {
        TorqueController::new(
            TorqueLoopGains {
                kp: 0.0,
                ki_per_s: 20.0,
                corr_limit_nm: 2.0,
                p_set_max_gauge_pa: 600_000.0,
            },
            FORCE_LAW,
            JointGeometry::REFERENCE,
            TORQUE_MODEL,
        )
    }

    const AT_REST: JointState = JointState {
        angle_rad: 0.0,
        velocity_rad_s: 0.0,
    };

    #[test]
    fn position_error_gives_torque_toward_setpoint() {
        let mut c = pid();
        let t = c.step(AT_REST, 0.2, 1e-3).unwrap();
        assert!(t > 0.0);
        let t = c.step(AT_REST, -0.2, 1e-3).unwrap();
        assert!(t < 0.0);
    }

    #[test]
    fn derivative_acts_on_measurement_not_setpoint() {
        let mut a = pid();
        let mut b = pid();
        // A set-point step does not produce a derivative kick: both outputs differ only by
        // kp * step + integral.
        let t0 = a.step(AT_REST, 0.0, 1e-3).unwrap();
        let t1 = b.step(AT_REST, 0.1, 1e-3).unwrap();
        assert!((t1 - t0 - (4.0 * 0.1 + 10.0 * 0.1 * 1e-3)).abs() < 1e-5);
        // Moving toward positive angles brakes.
        let mut c = pid();
        let t = c
            .step(
                JointState {
                    angle_rad: 0.0,
                    velocity_rad_s: 2.0,
                },
                0.0,
                1e-3,
            )
            .unwrap();
        assert!((t + 0.6).abs() < 1e-6);
    }

    #[test]
    fn anti_windup_from_downstream_saturation_cuts_the_overshoot_of_a_saturated_step() {
        let (os_with, i_with, ts_with) = saturated_step(true);
        let (os_without, i_without, ts_without) = saturated_step(false);
        std::println!(
            "saturated step 0 -> 1 rad: with anti-windup overshoot {os_with:.3} rad, \
             |I| max {i_with:.2} N m, settled {ts_with:.3} s; without: overshoot \
             {os_without:.3} rad, |I| max {i_without:.2} N m, settled {ts_without:.3} s"
        );
        // Without: the integrator winds up while the torque is saturated, and the
        // joint overshoots by a lot; with: it stays small and so does the overshoot.
        assert!(i_without > 1.0, "{i_without}");
        assert!(i_with < 0.5 * i_without, "{i_with} vs {i_without}");
        assert!(os_with < 0.5 * os_without, "{os_with} vs {os_without}");
        assert!(ts_with < ts_without, "{ts_with} vs {ts_without}");
        // Both reach the set-point in the end.
        assert!(ts_with < 4.0 && ts_without < 4.0);
    }

    #[test]
    fn downstream_saturation_blocks_only_its_own_direction() {
        let meas = JointState {
            angle_rad: 0.0,
            velocity_rad_s: 0.0,
        };
        let high: Shortfall = 1.0;
        // Positive error -> positive increment: blocked by `high`.
        let mut c = pid();
        c.step_limited(meas, 0.1, 0.01, high).unwrap();
        assert_eq!(c.integral_nm(), 0.0);
        // Negative error -> negative increment: integrates (drives out of saturation).
        c.step_limited(meas, -0.1, 0.01, high).unwrap();
        assert!(c.integral_nm() < 0.0);
        // No downstream saturation: exactly `step`.
        let (mut a, mut b) = (pid(), pid());
        for k in 0..50 {
            let sp = (k as f32 * 0.1).sin();
            let x = a.step(meas, sp, 0.01).unwrap();
            let y = b.step_limited(meas, sp, 0.01, 0.0).unwrap();
            assert_eq!(x.to_bits(), y.to_bits());
        }
    }

    /// The torque loop at its pressure ceiling: a set-point clamp (not the model's dp limit)
    /// stops the integrator in the blocked direction and reports the saturation; a
    /// reversed error integrates again.
    #[test]
    fn torque_loop_integrator_stops_at_the_pressure_ceiling() {
        let mut t = torque_loop();
        t.gains.p_set_max_gauge_pa = 320_000.0; // only 20 kPa above p0: dp is clipped there
        let meas = TorqueMeasurement {
            p1_gauge_pa: 300e3,
            p2_gauge_pa: 300e3,
            angle_rad: 0.0,
            velocity_rad_s: 0.0,
        };
        // A large torque demand in either direction saturates a set-point at the ceiling.
        for t_des in [5.0f32, -5.0] {
            t.reset();
            let mut i_after_first = None;
            for _ in 0..200 {
                let ps = t.step(meas, t_des, 1e-3).unwrap();
                assert!(!ps.saturated, "dp itself stays inside its own limit");
                assert!(ps.p1_gauge_pa.max(ps.p2_gauge_pa) <= 320_000.0);
                // The shortfall points the way of the demand.
                assert!(
                    ps.shortfall_nm * t_des > 0.0,
                    "{t_des}: {}",
                    ps.shortfall_nm
                );
                // The first step integrates (nothing known to be saturated yet), then the
                // integrator stays where it is: the error keeps pointing into the limit.
                match i_after_first {
                    None => i_after_first = Some(t.integral_nm()),
                    Some(i) => assert_eq!(t.integral_nm(), i, "{t_des}"),
                }
            }
        }
        // The error reversed (after the negative demand, a positive one): the last command
        // fell short downwards, the increment is upwards, so the integrator moves again.
        let before = t.integral_nm();
        t.step(meas, 5.0, 1e-3).unwrap();
        assert!(t.integral_nm() > before, "{} vs {before}", t.integral_nm());
    }

    #[test]
    fn integrator_is_bounded_and_does_not_wind_up_in_saturation() {
        let mut c = pid();
        for _ in 0..100_000 {
            let t = c.step(AT_REST, 100.0, 1e-3).unwrap();
            assert!(t <= 10.0);
        }
        // Output saturated from the first step: the integrator never moved.
        assert_eq!(c.integral_nm(), 0.0);
        let mut c = pid();
        for _ in 0..100_000 {
            c.step(AT_REST, 0.1, 1e-3).unwrap();
        }
        assert!((c.integral_nm() - 2.0).abs() < 1e-6);
    }

    #[test]
    fn position_loop_rejects_nan_and_resets_integrator() {
        assert_refuses_bad_inputs_and_resets(
            &mut pid(),
            PositionController::step,
            PositionController::integral_nm,
            0.1,
            10,
        );
    }

    #[test]
    fn torque_estimate_is_zero_at_symmetric_equilibrium() {
        let (t, flags) = torque_estimate_nm(
            &FORCE_LAW,
            &JointGeometry::REFERENCE,
            550_000.0,
            550_000.0,
            0.0,
        );
        assert!(t.abs() < 1e-3);
        assert!(flags.is_clean());
    }

    #[test]
    fn torque_estimate_sign_follows_muscle_one() {
        let (t, _) = torque_estimate_nm(
            &FORCE_LAW,
            &JointGeometry::REFERENCE,
            400_000.0,
            200_000.0,
            0.0,
        );
        assert!(t > 0.0, "{t}");
    }

    /// Both muscles at 300 kPa gauge, the joint at rest at `angle_rad`.
    fn both_at_300_kpa(angle_rad: f32) -> TorqueMeasurement {
        TorqueMeasurement {
            p1_gauge_pa: 300_000.0,
            p2_gauge_pa: 300_000.0,
            angle_rad,
            velocity_rad_s: 0.0,
        }
    }

    #[test]
    fn torque_loop_positive_torque_inflates_muscle_one() {
        let mut c = torque_loop();
        let m = both_at_300_kpa(0.0);
        let s = c.step(m, 2.0, 1e-3).unwrap();
        assert!(s.p1_gauge_pa > 300_000.0 && s.p2_gauge_pa < 300_000.0);
        assert!((s.p1_gauge_pa + s.p2_gauge_pa - 600_000.0).abs() < 1.0);
        // Pure feed-forward on the first step (integrator only 1 ms old): dp ~ T / (B r).
        let dp_ff = 2.0 / (TORQUE_MODEL.b_m2 * TORQUE_MODEL.sprocket_radius_m);
        assert!((s.dp_pa - dp_ff).abs() < 0.05 * dp_ff.abs());
    }

    #[test]
    fn torque_loop_holds_angle_against_passive_stiffness() {
        let mut c = torque_loop();
        let m = both_at_300_kpa(0.2);
        let s = c.step(m, 0.0, 1e-3).unwrap();
        // Holding +0.2 rad needs muscle 1 above muscle 2.
        assert!(s.p1_gauge_pa > s.p2_gauge_pa);
    }

    #[test]
    fn torque_integrator_removes_model_mismatch() {
        // Measured pressures fixed at p0: T_est ~ 0 while 1 N m is wanted; the integrator
        // must push the set-points further over time, bounded by corr_limit.
        let mut c = torque_loop();
        let m = both_at_300_kpa(0.0);
        let first = c.step(m, 1.0, 1e-3).unwrap();
        let mut last = first;
        for _ in 0..2000 {
            last = c.step(m, 1.0, 1e-3).unwrap();
        }
        assert!(last.p1_gauge_pa > first.p1_gauge_pa + 1_000.0);
        assert!((c.integral_nm() - 2.0).abs() < 1e-4);
    }

    #[test]
    fn torque_loop_setpoints_never_exceed_600_kpa() {
        let mut c = torque_loop();
        for t in [-1e6f32, -50.0, 0.0, 50.0, 1e6] {
            let s = c
                .step(
                    TorqueMeasurement {
                        p1_gauge_pa: 0.0,
                        p2_gauge_pa: 600_000.0,
                        angle_rad: 0.5,
                        velocity_rad_s: -3.0,
                    },
                    t,
                    1e-3,
                )
                .unwrap();
            assert!(s.p1_gauge_pa <= P_MUSCLE_MAX_GAUGE_PA && s.p1_gauge_pa >= 0.0);
            assert!(s.p2_gauge_pa <= P_MUSCLE_MAX_GAUGE_PA && s.p2_gauge_pa >= 0.0);
        }
    }

    #[test]
    fn torque_loop_rejects_nan() {
        let mut c = torque_loop();
        let m = TorqueMeasurement {
            p1_gauge_pa: f32::NAN,
            ..Default::default()
        };
        assert_eq!(c.step(m, 1.0, 1e-3), Err(ControlError::NonFiniteInput));
        assert!(c
            .step(TorqueMeasurement::default(), f32::NAN, 1e-3)
            .is_err());
    }

    fn ploop(ki: f32) -> PressureController {
        PressureController::new(PressureLoopGains {
            kp_per_pa: 1.0 / 50_000.0,
            ki_per_pa_s: ki,
            deadband_pa: 2_000.0,
            i_limit: 0.2,
        })
    }

    #[test]
    fn pressure_loop_inflates_below_and_exhausts_above_setpoint() {
        let mut c = ploop(0.0);
        assert!((c.step(275_000.0, 300_000.0, 1e-3).unwrap() - 0.5).abs() < 1e-6);
        assert!((c.step(325_000.0, 300_000.0, 1e-3).unwrap() + 0.5).abs() < 1e-6);
        assert_eq!(c.step(0.0, 600_000.0, 1e-3).unwrap(), 1.0);
        assert_eq!(c.step(600_000.0, 0.0, 1e-3).unwrap(), -1.0);
    }

    #[test]
    fn pressure_loop_deadband_closes_valves() {
        let mut c = ploop(1e-3);
        assert_eq!(c.step(301_999.0, 300_000.0, 1e-3).unwrap(), 0.0);
        assert_eq!(c.step(298_001.0, 300_000.0, 1e-3).unwrap(), 0.0);
    }

    #[test]
    fn pressure_loop_integrator_is_bounded() {
        let mut c = ploop(1.0);
        for _ in 0..10_000 {
            let u = c.step(290_000.0, 300_000.0, 1e-3).unwrap();
            assert!(u <= 1.0);
        }
        assert!(c.integral <= 0.2 + 1e-6);
    }

    #[test]
    fn pressure_loop_rejects_nan() {
        let mut c = ploop(0.0);
        assert_eq!(
            c.step(f32::NAN, 300_000.0, 1e-3),
            Err(ControlError::NonFiniteInput)
        );
        assert!(c.step(300_000.0, f32::INFINITY, 1e-3).is_err());
        assert!(c.step(300_000.0, 300_000.0, f32::NAN).is_err());
    }
}
