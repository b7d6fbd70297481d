//! Inverse thermodynamic feed-forward of the pressure loop (seed 004, eq. 7).
//!
//! From the desired pressure trajectory of one muscle (the pressure set-point `P` and the rate
//! `P'` of a desired pressure the tick hands in: the set-point itself, or the reference
//! trajectory's pressure), the chamber volume `V` and its rate `V'` (the firmware's volume
//! polynomial at the measured angle and a velocity, measured or desired), the mass flow that
//! produces it is
//!
//! ```text
//! m' = P' V / (k R T) + P V' / (R T)                                  (seed 004, eq. 7)
//! ```
//!
//! (`P` absolute; `k = 1` isothermal, `k = 1.4` adiabatic; `R`, `T` and `k` from
//! `config/pressure_ff.toml`). The valve that delivers it is inverted through its ISO 6358
//! flow model (sonic conductance `C`, critical ratio `b`, from `config/plant_constants.toml`):
//! the mass flow of a fully open valve from `p_up` to `p_down` is
//! `rho_ANR C p_up phi(p_down / p_up)`, `phi(s) = 1` for `s <= b` (choked) and
//! `sqrt(1 - ((s - b) / (1 - b))^2)` above (subsonic), with `rho_ANR = p_atm / (R 293.15 K)`.
//! Inflow (`m' > 0`) runs from the supply to the measured muscle pressure, outflow from the
//! muscle to the atmosphere; the duty is `m' / (rho_ANR C p_up phi)`, signed like the valve
//! command (> 0 inflate, < 0 exhaust) and clamped to [-1, 1]: a PWM duty for on/off valves
//! ([`crate::valves::OnOffValves`]), the opening for proportional ones. A duty below
//! `min_duty` is dropped (an on/off valve opens for at least its minimum on-time).
//!
//! The P loop stays on top: the tick adds this duty to the pressure loop's command and clamps
//! the sum to [-1, 1]. The duty is never NaN (non-finite inputs give 0), never inflates a
//! muscle at or above the pressure ceiling, and is 0 when the flow cannot go the wanted way
//! (muscle at or above the supply, or at or below the atmosphere). With `k = 1` and
//! `T = 293.15 K` it is the exact inverse of the plant's isothermal pressure equation
//! (`../shared/plant/PLANT.md`), so on the nominal plant the feedback only corrects errors.
//!
//! Cost: the volume polynomial and its slope (shared by both muscles up to the sign of the
//! contraction offset), per muscle one division for an inflow (two for an outflow) and one
//! square root when the flow is not choked. All reciprocals are precomputed. With
//! `update_period_ticks = N > 1` this runs on one tick in N and the duties are held in
//! between (`P'` is then the filtered difference over the N ticks); a held inflow duty is
//! dropped on every tick at which the measured pressure is at or above the ceiling. The
//! tracking benefit falls with N much faster than the cost (`docs/control.md`).

use crate::geometry::JointGeometry;
use crate::residual::ValveModelParams;

/// ANR reference temperature of the sonic conductance [K] (ISO 8778).
pub const T_ANR_K: f32 = 293.15;

/// Constants of the feed-forward (`config/pressure_ff.toml`).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PressureFfParams {
    /// On in the tick.
    pub enabled: bool,
    /// Polytropic index `k` of eq. 7 (1 = isothermal, 1.4 = adiabatic air), in [1, 1.67].
    pub polytropic_index: f32,
    /// Gas constant `R` [J/(kg K)].
    pub gas_constant_j_per_kg_k: f32,
    /// Gas temperature `T` [K].
    pub temperature_k: f32,
    /// Cut-off of the low-pass on the desired pressure's finite difference [Hz].
    pub rate_cutoff_hz: f32,
    /// Desired pressure rate `P'` from the reference trajectory (the set-point, its rate and
    /// acceleration through the inverse torque model: noise-free) instead of the finite
    /// difference of the torque loop's pressure set-point (which carries the feedback).
    pub rate_from_reference: bool,
    /// Volume rate `V'` from the set-point's rate instead of the measured velocity.
    pub volume_rate_from_reference: bool,
    /// Scale of the duty (1 = the model's), in [0, 2].
    pub gain: f32,
    /// Duties of a smaller magnitude are dropped (0), in [0, 1]: the on/off valve delivers
    /// flow in pulses of at least its minimum on-time, so a small duty only adds pulses.
    pub min_duty: f32,
    /// The feed-forward is evaluated once every this many ticks and held in between (1 =
    /// every tick), in [1, 100]; `P'` is then the filtered difference over the period. Fewer
    /// evaluations cost fewer instructions and track worse (`docs/control.md`).
    pub update_period_ticks: u16,
}

impl PressureFfParams {
    /// Off (the tick's pressure loop is P only).
    pub const OFF: PressureFfParams = PressureFfParams {
        enabled: false,
        polytropic_index: 1.0,
        gas_constant_j_per_kg_k: 287.05,
        temperature_k: T_ANR_K,
        rate_cutoff_hz: 150.0,
        rate_from_reference: false,
        volume_rate_from_reference: false,
        gain: 1.0,
        min_duty: 0.0,
        update_period_ticks: 1,
    };

    /// Every constant finite and in its range (checked also when off).
    pub fn is_valid(&self) -> bool {
        let k = self.polytropic_index;
        (1.0..=1.67).contains(&k)
            && self.gas_constant_j_per_kg_k.is_finite()
            && self.gas_constant_j_per_kg_k > 0.0
            && self.temperature_k.is_finite()
            && self.temperature_k > 0.0
            && self.rate_cutoff_hz.is_finite()
            && self.rate_cutoff_hz > 0.0
            && (0.0..=2.0).contains(&self.gain)
            && (0.0..=1.0).contains(&self.min_duty)
            && (1..=100).contains(&self.update_period_ticks)
    }
}

/// The inverse model with its reciprocals precomputed.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InverseModel {
    inv_k: f32,
    inv_rt: f32,
    /// `gain / (rho_ANR C)` [s Pa m^3 / (kg m^3)]: mass flow -> `p_up phi duty`.
    gain_over_rho_c: f32,
    p_atm_pa: f32,
    ps_abs_pa: f32,
    inv_ps_abs: f32,
    critical_ratio: f32,
    inv_one_minus_b: f32,
    /// Ceiling of the muscle gauge pressure for an inflow [Pa].
    p_hi_gauge_pa: f32,
    /// |duty| below this gives 0.
    min_duty: f32,
}

/// Smallest `p_up phi` the duty divides by, as a fraction of `p_up`: below it (flow function
/// near 0, pressures almost equal) the valve cannot deliver, the duty is its limit.
const PHI_MIN: f32 = 1e-3;

impl InverseModel {
    /// From the feed-forward constants, the valve model and the pressure ceiling.
    pub fn new(ff: &PressureFfParams, valve: &ValveModelParams, p_hi_gauge_pa: f32) -> Self {
        let rho_anr = valve.p_atm_pa / (ff.gas_constant_j_per_kg_k * T_ANR_K);
        let ps = valve.supply_gauge_pa + valve.p_atm_pa;
        InverseModel {
            inv_k: 1.0 / ff.polytropic_index,
            inv_rt: 1.0 / (ff.gas_constant_j_per_kg_k * ff.temperature_k),
            gain_over_rho_c: ff.gain / (rho_anr * valve.conductance_m3_per_s_pa),
            p_atm_pa: valve.p_atm_pa,
            ps_abs_pa: ps,
            inv_ps_abs: 1.0 / ps,
            critical_ratio: valve.critical_ratio,
            inv_one_minus_b: 1.0 / (1.0 - valve.critical_ratio),
            p_hi_gauge_pa,
            min_duty: ff.min_duty,
        }
    }

    /// Eq. 7: mass flow [kg/s] for absolute pressure `p_abs_pa`, its rate `p_rate_pa_s`, the
    /// volume `v_m3` and its rate `v_rate_m3_s`.
    #[inline(always)]
    pub fn mass_flow_kg_s(
        &self,
        p_abs_pa: f32,
        p_rate_pa_s: f32,
        v_m3: f32,
        v_rate_m3_s: f32,
    ) -> f32 {
        (p_rate_pa_s * v_m3 * self.inv_k + p_abs_pa * v_rate_m3_s) * self.inv_rt
    }

    /// ISO 6358 flow function `phi(s)` (1 choked, the ellipse above the critical ratio, 0 at
    /// and above 1).
    #[inline(always)]
    fn phi(&self, s: f32) -> f32 {
        if s <= self.critical_ratio {
            1.0
        } else if s < 1.0 {
            let x = (s - self.critical_ratio) * self.inv_one_minus_b;
            crate::math::sqrtf(1.0 - x * x)
        } else {
            0.0
        }
    }

    /// The valve command in [-1, 1] (> 0 inflate, < 0 exhaust) that delivers `m_dot_kg_s` at
    /// the measured gauge pressure `p_meas_gauge_pa`. Never NaN: non-finite inputs give 0.
    // Not `f32::clamp`: its unreachable panic message would link core::fmt's float
    // formatting (~20 KiB of MCU flash), and the dropped duty is tested first.
    #[allow(clippy::manual_clamp)]
    #[inline(always)]
    pub fn duty(&self, m_dot_kg_s: f32, p_meas_gauge_pa: f32) -> f32 {
        let p = p_meas_gauge_pa + self.p_atm_pa;
        let d = if m_dot_kg_s > 0.0 {
            // Inflate: supply -> muscle; none at or above the ceiling or the supply.
            if !(p_meas_gauge_pa < self.p_hi_gauge_pa) || !(p < self.ps_abs_pa) {
                return 0.0;
            }
            let phi = self.phi(p * self.inv_ps_abs);
            let q = self.ps_abs_pa * if phi > PHI_MIN { phi } else { PHI_MIN };
            m_dot_kg_s * self.gain_over_rho_c / q
        } else if m_dot_kg_s < 0.0 {
            // Exhaust: muscle -> atmosphere; none at or below the atmosphere.
            if !(p > self.p_atm_pa) {
                return 0.0;
            }
            let phi = self.phi(self.p_atm_pa / p);
            let q = p * if phi > PHI_MIN { phi } else { PHI_MIN };
            m_dot_kg_s * self.gain_over_rho_c / q
        } else {
            // 0, or NaN.
            return 0.0;
        };
        // In [-1, 1]; NaN (an infinite flow over an infinite pressure) and a duty below the
        // minimum give 0. The dropped duty first: the usual case with a minimum duty, one
        // test (the minimum is at most 1, so a dropped duty is never one the clamp changes).
        if !(libm::fabsf(d) >= self.min_duty) {
            0.0
        } else if d >= 1.0 {
            1.0
        } else if d <= -1.0 {
            -1.0
        } else {
            d
        }
    }
}

/// One tick's inputs of the feed-forward ([`PressureFeedforward::step`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FfInputs {
    /// Pressure set-points (gauge) [Pa]: the `P` of eq. 7.
    pub set_pa: [f32; 2],
    /// Desired pressures (gauge) [Pa] whose filtered difference is `P'`.
    pub desired_pa: [f32; 2],
    /// Measured pressures (gauge) [Pa]: the valve's upstream or downstream side.
    pub meas_pa: [f32; 2],
    /// Joint angle [rad] (the volume's contraction).
    pub angle_rad: f32,
    /// Joint velocity [rad/s] that gives `V'` (measured or desired).
    pub velocity_rad_s: f32,
}

/// The feed-forward of both muscles with its state (the set-points' previous values and
/// filtered rates).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PressureFeedforward {
    model: InverseModel,
    /// Volume polynomial `b0..b3` [m^3], and its floor `0.1 b0`.
    poly: [f32; 4],
    v_floor_m3: f32,
    chi0: f32,
    geometry_ratio: f32,
    /// Low-pass weight per evaluation, times the evaluation rate [Hz].
    alpha: f32,
    alpha_tick_hz: f32,
    /// Previous desired pressures [Pa] and their filtered rates [Pa/s].
    prev_set_pa: [f32; 2],
    rate_pa_s: [f32; 2],
    init: bool,
    /// Evaluation period [ticks] (>= 1) and the ticks left until the next evaluation.
    period_ticks: u16,
    countdown_ticks: u16,
    /// The last evaluation's duties, held until the next one, and per muscle the measured
    /// gauge pressure at or above which the held duty is dropped (the ceiling for an
    /// inflow, +inf otherwise) [Pa].
    held: [f32; 2],
    held_below_pa: [f32; 2],
    /// The learned volume in place of the polynomial (feature `volume-fnn`).
    #[cfg(feature = "volume-fnn")]
    fnn: Option<&'static crate::volume_fnn::VolumeFnn>,
}

impl PressureFeedforward {
    /// From the tick's constants: feed-forward, valve model (volume, conductance), joint
    /// geometry, pressure ceiling, nominal tick rate.
    pub fn new(
        ff: &PressureFfParams,
        valve: &ValveModelParams,
        geometry: &JointGeometry,
        p_hi_gauge_pa: f32,
        tick_hz: f32,
    ) -> Self {
        let period_ticks = ff.update_period_ticks.max(1);
        let update_hz = tick_hz / period_ticks as f32;
        let tau = 1.0 / (2.0 * core::f32::consts::PI * ff.rate_cutoff_hz);
        let alpha = 1.0 / (1.0 + tau * update_hz);
        let alpha = if alpha.is_finite() && alpha > 0.0 && alpha <= 1.0 {
            alpha
        } else {
            1.0
        };
        PressureFeedforward {
            model: InverseModel::new(ff, valve, p_hi_gauge_pa),
            poly: valve.volume_poly_m3,
            v_floor_m3: 0.1 * valve.volume_poly_m3[0],
            chi0: geometry.initial_contraction,
            geometry_ratio: geometry.sprocket_radius_m / geometry.rest_length_m,
            alpha,
            alpha_tick_hz: alpha * update_hz,
            prev_set_pa: [0.0; 2],
            rate_pa_s: [0.0; 2],
            init: false,
            period_ticks,
            countdown_ticks: 0,
            held: [0.0; 2],
            held_below_pa: [f32::INFINITY; 2],
            #[cfg(feature = "volume-fnn")]
            fnn: None,
        }
    }

    /// With the hybrid model's learned volume ([`crate::volume_fnn`], seed 004 eq. 12) in
    /// place of the polynomial (`None`: the polynomial).
    #[cfg(feature = "volume-fnn")]
    pub fn with_volume_fnn(mut self, fnn: Option<&'static crate::volume_fnn::VolumeFnn>) -> Self {
        self.fnn = fnn;
        self
    }

    /// Forgets the set-point history (the next step evaluates, starting at rate 0).
    pub fn reset(&mut self) {
        self.init = false;
        self.rate_pa_s = [0.0; 2];
        self.countdown_ticks = 0;
        self.held = [0.0; 2];
    }

    /// The filtered desired-pressure rates [Pa/s].
    pub fn rates_pa_s(&self) -> [f32; 2] {
        self.rate_pa_s
    }

    /// One tick: the feed-forward duties of both muscles for the pressure set-points `set_pa`
    /// (the `P` of eq. 7), the desired pressures `desired_pa` whose filtered finite difference
    /// is `P'` (the set-points themselves, or the reference trajectory's pressures), the
    /// measured pressures `meas_pa` (gauge), the angle and the velocity that gives `V'`
    /// (measured or desired). Evaluated on the first tick and then once every
    /// `update_period_ticks`; in between the last duties are held ([`Self::held`]). Each
    /// duty in [-1, 1], never NaN; non-finite inputs give 0 and reset the history (the next
    /// tick evaluates).
    pub fn step(
        &mut self,
        set_pa: [f32; 2],
        desired_pa: [f32; 2],
        meas_pa: [f32; 2],
        angle_rad: f32,
        velocity_rad_s: f32,
    ) -> [f32; 2] {
        let x = FfInputs {
            set_pa,
            desired_pa,
            meas_pa,
            angle_rad,
            velocity_rad_s,
        };
        let sum = set_pa[0]
            + set_pa[1]
            + desired_pa[0]
            + desired_pa[1]
            + meas_pa[0]
            + meas_pa[1]
            + angle_rad
            + velocity_rad_s;
        if !sum.is_finite() {
            self.reset();
            return [0.0; 2];
        }
        match self.held(meas_pa) {
            Some(d) => d,
            None => self.evaluate_finite(&x),
        }
    }

    /// A tick between evaluations: the held duties, each dropped (0) while its muscle's
    /// measured gauge pressure `meas_pa` is at or above the ceiling (a held inflow) or not
    /// finite; `None` on a tick that evaluates (then call [`Self::evaluate_finite`]). No
    /// division, no root: the usual tick when evaluating once per PWM period.
    #[inline(always)]
    pub fn held(&mut self, meas_pa: [f32; 2]) -> Option<[f32; 2]> {
        if self.countdown_ticks == 0 {
            return None;
        }
        self.countdown_ticks -= 1;
        let hold = |i: usize| {
            if meas_pa[i] < self.held_below_pa[i] {
                self.held[i]
            } else {
                0.0
            }
        };
        Some([hold(0), hold(1)])
    }

    /// The evaluating tick of [`Self::step`] (after [`Self::held`] returned `None`) for
    /// inputs known to be finite (the armed tick's: validated channels, the torque loop's
    /// clamped set-points, a finite set-point and its derivatives): the same bits, without
    /// the finiteness test. The duties are held for the next `update_period_ticks - 1` ticks.
    /// A non-finite input here still gives no NaN duty (see [`InverseModel::duty`]), but the
    /// filtered rate keeps it until [`Self::reset`].
    #[inline(always)]
    pub fn evaluate_finite(&mut self, x: &FfInputs) -> [f32; 2] {
        self.countdown_ticks = self.period_ticks - 1;
        if !self.init {
            self.prev_set_pa = x.desired_pa;
            self.init = true;
        }
        let out = self.evaluate(x);
        if self.period_ticks > 1 {
            let p_hi = self.model.p_hi_gauge_pa;
            self.held = out;
            self.held_below_pa = out.map(|d| if d > 0.0 { p_hi } else { f32::INFINITY });
        }
        out
    }

    /// One evaluation: the filtered rates advance by one period, the duties of eq. 7 through
    /// the inverse valve. The volume source is chosen once per evaluation (not per muscle):
    /// the polynomial loop then has no call in it and keeps its constants in registers.
    #[inline(always)]
    fn evaluate(&mut self, x: &FfInputs) -> [f32; 2] {
        #[cfg(feature = "volume-fnn")]
        if let Some(n) = self.fnn {
            return self.muscles(x, |chi, chi_rate, p_abs, p_rate| {
                n.volume_and_rate(chi, chi_rate, p_abs, p_rate)
            });
        }
        let [b0, b1, b2, b3] = self.poly;
        let v_floor_m3 = self.v_floor_m3;
        // `dV/dchi chi'` with `chi' = sign dchi'`: the same bits as `(dV/dchi sign) dchi'` (a
        // product with +-1 is exact, and rounding is symmetric in the sign).
        self.muscles(x, |chi, chi_rate, _, _| {
            let v = b0 + chi * (b1 + chi * (b2 + chi * b3));
            let v = if v > v_floor_m3 { v } else { v_floor_m3 };
            let v_rate = (b1 + chi * (2.0 * b2 + chi * 3.0 * b3)) * chi_rate;
            (v, v_rate)
        })
    }

    /// Both muscles' duties with the volume and its rate from `volume(chi, chi_rate, p_abs,
    /// p_rate)` (contraction, its rate, absolute set-point pressure and its filtered rate).
    #[inline(always)]
    fn muscles(
        &mut self,
        x: &FfInputs,
        volume: impl Fn(f32, f32, f32, f32) -> (f32, f32),
    ) -> [f32; 2] {
        let FfInputs {
            set_pa,
            desired_pa,
            meas_pa,
            angle_rad,
            velocity_rad_s,
        } = *x;
        let dchi = self.geometry_ratio * angle_rad;
        let dchi_rate = self.geometry_ratio * velocity_rad_s;
        let mut out = [0.0; 2];
        // Muscle 1 contracts with the angle, muscle 2 the other way.
        let signs = [1.0f32, -1.0];
        for i in 0..2 {
            let r = &mut self.rate_pa_s[i];
            *r += self.alpha_tick_hz * (desired_pa[i] - self.prev_set_pa[i]) - self.alpha * *r;
            self.prev_set_pa[i] = desired_pa[i];
            let chi = self.chi0 + signs[i] * dchi;
            let p_abs = set_pa[i] + self.model.p_atm_pa;
            let (v, v_rate) = volume(chi, signs[i] * dchi_rate, p_abs, *r);
            let m = self.model.mass_flow_kg_s(p_abs, *r, v, v_rate);
            out[i] = self.model.duty(m, meas_pa[i]);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params() -> ValveModelParams {
        ValveModelParams::REFERENCE
    }

    fn model() -> InverseModel {
        InverseModel::new(&PressureFfParams::OFF, &params(), 600_000.0)
    }

    /// The plant's isothermal pressure rate (PLANT.md) for an inflow duty `u`, written from
    /// the plant equations (ANR volume flow), not from the kernel.
    fn plant_rate_in(u: f64, p_gauge: f64, v: f64) -> f64 {
        let p = params();
        let (pa, c, b) = (
            p.p_atm_pa as f64,
            p.conductance_m3_per_s_pa as f64,
            p.critical_ratio as f64,
        );
        let ps = p.supply_gauge_pa as f64 + pa;
        let pm = p_gauge + pa;
        let s = pm / ps;
        let phi = if s <= b {
            1.0
        } else {
            (1.0 - ((s - b) / (1.0 - b)).powi(2)).sqrt()
        };
        pa * u * c * ps * phi / v
    }

    #[test]
    fn isothermal_duty_inverts_the_plant_choked_and_unchoked() {
        let m = model();
        let v = 1.0e-4;
        for &(p_gauge, rate) in &[
            (100_000.0f32, 2.0e6f32),
            (300_000.0, 1.0e6),
            (550_000.0, 2.0e5),
        ] {
            // Choked below b (p/ps <= 0.433 <=> p_gauge <= ~202 kPa), subsonic above.
            let mdot = m.mass_flow_kg_s(p_gauge + 101_325.0, rate, v, 0.0);
            let u = m.duty(mdot, p_gauge);
            assert!(u > 0.0 && u < 1.0, "{p_gauge} {rate} -> {u}");
            let got = plant_rate_in(u as f64, p_gauge as f64, v as f64);
            assert!(
                (got / rate as f64 - 1.0).abs() < 1e-3,
                "{p_gauge}: {got} vs {rate}"
            );
        }
    }

    #[test]
    fn duties_below_the_minimum_are_dropped() {
        let m = InverseModel::new(
            &PressureFfParams {
                min_duty: 0.2,
                ..PressureFfParams::OFF
            },
            &params(),
            600_000.0,
        );
        let full = model();
        for mdot in [1e-5f32, -1e-5, 1e-4, -1e-4, 3e-3, -3e-3] {
            let d = full.duty(mdot, 300_000.0);
            let got = m.duty(mdot, 300_000.0);
            assert_eq!(got, if d.abs() >= 0.2 { d } else { 0.0 }, "{mdot}: {d}");
        }
        // Both cases occur: a duty dropped and one kept.
        assert!(full.duty(1e-5, 300_000.0).abs() < 0.2 && full.duty(3e-3, 300_000.0) > 0.2);
    }

    #[test]
    fn duty_is_continuous_across_the_critical_ratio() {
        let m = model();
        let ps = 701_325.0f32;
        let p_crit = 0.433 * ps - 101_325.0;
        let mdot = 1e-4;
        let below = m.duty(mdot, p_crit - 1.0);
        let above = m.duty(mdot, p_crit + 1.0);
        assert!((below - above).abs() < 1e-4, "{below} {above}");
    }

    #[test]
    fn zero_pressure_difference_and_edges_give_bounded_duty() {
        let m = model();
        // Muscle at the supply: no inflow possible.
        assert_eq!(m.duty(1e-3, 600_000.0), 0.0);
        // At the ceiling: no inflow.
        let m2 = InverseModel::new(&PressureFfParams::OFF, &params(), 500_000.0);
        assert_eq!(m2.duty(1e-3, 500_000.0), 0.0);
        // Just below the supply: flow function ~0, duty at its limit, not infinite.
        assert_eq!(m.duty(1e-3, 599_999.0), 1.0);
        // Muscle at the atmosphere: no outflow.
        assert_eq!(m.duty(-1e-3, 0.0), 0.0);
        assert_eq!(m.duty(-1e-3, -10_000.0), 0.0);
        // Just above the atmosphere: the exhaust limit.
        assert_eq!(m.duty(-1e-3, 1.0), -1.0);
        assert_eq!(m.duty(0.0, 300_000.0), 0.0);
        assert_eq!(m.duty(f32::MAX, 100_000.0), 1.0);
        assert_eq!(m.duty(-f32::MAX, 100_000.0), -1.0);
    }

    /// The feed-forward of the test parameters on the reference joint, 600 kPa supply, 1 kHz.
    fn reference_ff() -> PressureFeedforward {
        PressureFeedforward::new(
            &PressureFfParams::OFF,
            &params(),
            &JointGeometry::REFERENCE,
            600_000.0,
            1000.0,
        )
    }

    #[test]
    fn nan_and_infinite_inputs_never_give_nan() {
        let m = model();
        for a in crate::HOSTILE_F32 {
            for b in crate::HOSTILE_F32 {
                let d = m.duty(a, b);
                assert!(
                    d.is_finite() && (-1.0..=1.0).contains(&d),
                    "duty({a}, {b}) = {d}"
                );
            }
        }
        let mut ff = reference_ff();
        for a in crate::HOSTILE_F32 {
            let o = ff.step([a, 3e5], [3e5, a], [3e5, a], a, 0.1);
            assert!(
                o.iter().all(|x| x.is_finite() && (-1.0..=1.0).contains(x)),
                "{a}: {o:?}"
            );
        }
        // After a non-finite input the history restarts: a steady set-point gives no duty.
        ff.step([f32::NAN, 0.0], [0.0; 2], [0.0; 2], 0.0, 0.0);
        let o = ff.step([3e5, 3e5], [3e5, 3e5], [3e5, 3e5], 0.0, 0.0);
        assert_eq!(o, [0.0, 0.0]);
    }

    /// 200 ticks of a fresh reference feed-forward with the chosen inputs (set-points,
    /// desired pressures, measured pressures) ramping at 1 MPa/s (muscle 1 up from 200 kPa,
    /// muscle 2 down from 500 kPa), the others steady at 300 kPa: the last duty and the
    /// feed-forward.
    fn ramped(ramp: [bool; 3]) -> ([f32; 2], PressureFeedforward) {
        let mut ff = reference_ff();
        let mut o = [0.0; 2];
        for k in 0..200 {
            let s = k as f32 * 1000.0;
            let [sp, desired, measured] = ramp.map(|r| {
                if r {
                    [200_000.0 + s, 500_000.0 - s]
                } else {
                    [300_000.0; 2]
                }
            });
            o = ff.step(sp, desired, measured, 0.0, 0.0);
        }
        (o, ff)
    }

    fn assert_rates_of_the_ramp(ff: &PressureFeedforward) {
        let r = ff.rates_pa_s();
        assert!(
            (r[0] - 1.0e6).abs() < 1e3 && (r[1] + 1.0e6).abs() < 1e3,
            "{r:?}"
        );
    }

    #[test]
    fn rising_setpoint_inflates_falling_exhausts_and_the_rate_filter_converges() {
        let (o, ff) = ramped([true; 3]);
        assert_rates_of_the_ramp(&ff);
        assert!(o[0] > 0.0 && o[1] < 0.0, "{o:?}");
        // A muscle contracting (its volume rising: muscle 1 at a positive velocity) at a steady
        // set-point needs inflow, the other one (lengthening) outflow.
        let mut ff2 = ff;
        ff2.reset();
        let o = ff2.step([300_000.0; 2], [300_000.0; 2], [300_000.0; 2], 0.0, 1.0);
        assert!(o[0] > 0.0 && o[1] < 0.0, "{o:?}");
    }

    #[test]
    fn the_rate_is_that_of_the_desired_pressures_not_of_the_set_points() {
        // Steady set-points, desired pressures ramping: the rate and the duty's sign follow
        // the desired pressures.
        let (o, ff) = ramped([false, true, false]);
        assert_rates_of_the_ramp(&ff);
        assert!(o[0] > 0.0 && o[1] < 0.0, "{o:?}");
        // Ramping set-points under steady desired pressures: no rate, no duty.
        let (o, _) = ramped([true, false, false]);
        assert_eq!(o, [0.0, 0.0]);
    }

    /// The reference feed-forward evaluated once every `n` ticks.
    fn decimated(n: u16) -> PressureFeedforward {
        PressureFeedforward::new(
            &PressureFfParams {
                update_period_ticks: n,
                ..PressureFfParams::OFF
            },
            &params(),
            &JointGeometry::REFERENCE,
            600_000.0,
            1000.0,
        )
    }

    #[test]
    fn a_decimated_feed_forward_evaluates_once_per_period_and_holds_in_between() {
        // The ramp of `ramped` (1 MPa/s up in muscle 1, down in muscle 2) at 1 kHz, evaluated
        // every 10 ticks and every tick side by side: the decimated duties change only on
        // ticks 0, 10, 20, ...; its filtered rate (a difference over the period) converges to
        // the ramp's rate, and once it has, an evaluating tick gives the every-tick duty.
        let (mut dec, mut every) = (decimated(10), reference_ff());
        let mut prev = [f32::NAN; 2];
        let mut changes = 0;
        for k in 0..200 {
            let s = k as f32 * 1000.0;
            let p = [200_000.0 + s, 500_000.0 - s];
            let o = dec.step(p, p, p, 0.0, 0.0);
            let e = every.step(p, p, p, 0.0, 0.0);
            if o != prev {
                assert_eq!(k % 10, 0, "tick {k}: {o:?} after {prev:?}");
                changes += 1;
            }
            if k % 10 == 0 && k >= 100 {
                for i in 0..2 {
                    assert!(
                        (o[i] - e[i]).abs() <= 0.01 * e[i].abs() && e[i] != 0.0,
                        "tick {k}: {o:?} vs every tick {e:?}"
                    );
                }
            }
            prev = o;
        }
        assert_eq!(changes, 20);
        assert_rates_of_the_ramp(&dec);
        assert!(prev[0] > 0.0 && prev[1] < 0.0, "{prev:?}");
    }

    #[test]
    fn a_held_inflow_is_dropped_at_the_ceiling_and_on_a_bad_pressure() {
        // Evaluated on a rising set-point (inflow in muscle 1), then held: muscle 1's held
        // duty stops at the ceiling (600 kPa here) and on a NaN pressure; muscle 2's exhaust
        // duty is held on.
        let mut ff = decimated(10);
        let mut o = [0.0; 2];
        for k in 0..11 {
            let s = k as f32 * 1000.0;
            let p = [200_000.0 + s, 500_000.0 - s];
            o = ff.step(p, p, p, 0.0, 0.0);
        }
        assert!(o[0] > 0.0 && o[1] < 0.0, "{o:?}");
        let set = [211_000.0, 489_000.0];
        let held = ff.step(set, set, [300_000.0, 489_000.0], 0.0, 0.0);
        assert_eq!(held, o);
        let at_ceiling = ff.step(set, set, [600_000.0, 489_000.0], 0.0, 0.0);
        assert_eq!(at_ceiling, [0.0, o[1]]);
        assert_eq!(ff.held([f32::NAN, 489_000.0]), Some([0.0, o[1]]));
        // Below the ceiling again: held as before, until the period ends.
        assert_eq!(ff.held([300_000.0, 489_000.0]), Some(o));
        // A reset: the next tick evaluates (with no history: rate 0, no duty).
        ff.reset();
        assert_eq!(ff.held([300_000.0; 2]), None);
        assert_eq!(ff.step(set, set, set, 0.0, 0.0), [0.0, 0.0]);
    }

    #[test]
    fn adiabatic_index_asks_for_less_flow() {
        let iso = model();
        let adi = InverseModel::new(
            &PressureFfParams {
                polytropic_index: 1.4,
                ..PressureFfParams::OFF
            },
            &params(),
            600_000.0,
        );
        let a = iso.mass_flow_kg_s(3e5, 1e6, 1e-4, 0.0);
        let b = adi.mass_flow_kg_s(3e5, 1e6, 1e-4, 0.0);
        assert!((a / b - 1.4).abs() < 1e-5);
    }

    #[test]
    fn generated_constants_are_valid() {
        assert!(crate::constants::PRESSURE_FF.is_valid());
        assert!(PressureFfParams::OFF.is_valid());
        assert!(!PressureFfParams {
            polytropic_index: f32::NAN,
            ..PressureFfParams::OFF
        }
        .is_valid());
        assert!(!PressureFfParams {
            gain: -1.0,
            ..PressureFfParams::OFF
        }
        .is_valid());
        for n in [0, 101] {
            assert!(!PressureFfParams {
                update_period_ticks: n,
                ..PressureFfParams::OFF
            }
            .is_valid());
        }
    }
}
