//! A whole control tick in 32-bit integer arithmetic for FPU-less cores (Cortex-M0), from raw
//! sensor counts to valve commands: what a 1 kHz tick costs where the fixed-point models are
//! meant to run (`scripts/bench-mcu.sh` measures it on QEMU's `microbit`).
//!
//! Per tick: pressure ADC counts and the encoder count are scaled to pascal and Q16 radian;
//! a reading at an ADC rail (0 or 4095 counts: open or shorted transducer) or an angle outside
//! the configured range latches a fault, so does a channel without a sample for more than
//! `stale_ticks` after its first one, a pressure above the over-pressure limit and a set-point
//! beyond its limit; while a channel has not delivered its first sample the valves hold and
//! the tick is not armed. Armed: velocity from the angle difference (first-order filter),
//! position PID -> desired torque (conditional integration: the integrator stops while the
//! output saturates in the same direction), torque estimate from the two muscle forces
//! (fixed force law) and the lever, a torque-loop integral correction (stopped while the
//! activation saturates), the inverse torque model -> symmetric pressure set-points, and per
//! muscle a proportional pressure loop with dead band -> valve command in [-1, 1] (Q16,
//! positive inflates). A latched fault outputs closed valves (hold).
//!
//! It is a reduced cascade next to the f32 tick of `src/tick.rs` (no feed-forward, no
//! residual monitor, no rate / jump checks, bang-bang-free proportional pressure loop): it
//! exists to carry the fixed-point models through a complete tick on the M0 and to measure
//! that tick, and it is checked bit for bit between the M0 image and the host
//! (`trace::fixed_path_digest`). No floating-point operation on its evaluation path
//! (`scripts/check-fixed-no-float.sh`); [`FixedTickConfig::from_params`] is the one float edge
//! (f64 pre-scaling of the f32 configuration, host or start-up).

use super::prescale::{round_i64, sat_i32, term_bits};
use super::{clamp_i32, term, FixedForceLaw, FixedTorqueModel, PressurePa, Stretch, TorqueNm};
use crate::tick::config::ControllerConfig;

/// One coefficient of `term(c, s, x)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Coef {
    c: i32,
    s: u32,
}

impl Coef {
    const ZERO: Coef = Coef { c: 0, s: 16 };

    /// `v` output LSB per input LSB for |x| <= x_max; ZERO (and `ok` cleared) if it does not fit.
    fn new(v: f64, x_max: f64, ok: &mut bool) -> Coef {
        match term_bits(v, x_max) {
            Some((c, s)) => Coef { c, s },
            None => {
                *ok = false;
                Coef::ZERO
            }
        }
    }

    #[inline(always)]
    fn apply(self, x: i32) -> i32 {
        term(self.c, self.s, x)
    }
}

/// Fault codes of the fixed tick (0 = none).
pub mod fault {
    /// Muscle 1 pressure reading at an ADC rail.
    pub const PRESSURE1_IMPLAUSIBLE: u8 = 1;
    /// Muscle 2 pressure reading at an ADC rail.
    pub const PRESSURE2_IMPLAUSIBLE: u8 = 2;
    /// Angle outside the configured range.
    pub const ANGLE_RANGE: u8 = 3;
    /// A channel delivered no sample for longer than the stale limit.
    pub const STALE: u8 = 4;
    /// A muscle pressure above the over-pressure limit.
    pub const OVER_PRESSURE: u8 = 5;
    /// Set-point beyond its limit.
    pub const SETPOINT: u8 = 6;
    /// The configuration does not fit the fixed formats.
    pub const CONFIG: u8 = 7;
}

/// Highest ADC count (12-bit converter): a reading there or at 0 is a rail.
pub const ADC_MAX: u16 = 4095;

/// Pre-scaled configuration of [`FixedTick`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FixedTickConfig {
    valid: bool,
    adc_zero: i32,
    pa_per_count: Coef,
    rad_per_count: Coef,
    tick_hz: i32,
    vel_alpha: Coef,
    e0_q16: i32,
    stretch_per_rad: Coef,
    lever: Coef,
    kp: Coef,
    ki_dt: Coef,
    kd: Coef,
    i_limit_q24: i32,
    out_limit_q16: i32,
    kt_dt: Coef,
    corr_limit_q24: i32,
    kpp: Coef,
    deadband_pa: i32,
    p_over_pa: i32,
    angle_min_q16: i32,
    angle_max_q16: i32,
    setpoint_max_q16: i32,
    stale_ticks: u32,
    law: FixedForceLaw,
    model: FixedTorqueModel,
}

/// What the sensors delivered this tick, raw: `None` = no new sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct FixedFrame {
    /// Muscle 1 pressure ADC counts.
    pub p1_adc: Option<u16>,
    /// Muscle 2 pressure ADC counts.
    pub p2_adc: Option<u16>,
    /// Encoder count (signed, x4 quadrature).
    pub encoder: Option<i32>,
}

/// Everything one fixed tick produced.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct FixedTickOutput {
    /// Valve commands in [-1, 1] (Q16, positive inflates, 0 = hold), muscles 1 and 2.
    pub valves_q16: [i32; 2],
    /// Pressure set-points \[Pa\], muscles 1 and 2.
    pub p_set_pa: [i32; 2],
    /// Desired torque (position loop output) \[N m\], Q16.
    pub torque_des_q16: i32,
    /// Torque estimated from the muscle forces \[N m\], Q16.
    pub torque_est_q16: i32,
    /// Angle \[rad\] and velocity \[rad/s\] estimates, Q16.
    pub angle_q16: i32,
    /// See [`FixedTickOutput::angle_q16`].
    pub velocity_q16: i32,
    /// Latched fault code ([`fault`]), 0 = none.
    pub fault: u8,
    /// True when the cascade ran this tick.
    pub armed: bool,
}

impl FixedTickOutput {
    /// The outputs as 32-bit words (for hashing and logging).
    pub fn words(&self) -> [u32; 9] {
        [
            self.valves_q16[0] as u32,
            self.valves_q16[1] as u32,
            self.p_set_pa[0] as u32,
            self.p_set_pa[1] as u32,
            self.torque_des_q16 as u32,
            self.torque_est_q16 as u32,
            self.angle_q16 as u32,
            self.velocity_q16 as u32,
            self.fault as u32 | (self.armed as u32) << 8,
        ]
    }
}

impl FixedTickConfig {
    /// Pre-scales the f32 controller configuration (f64 arithmetic: host, or once at
    /// start-up) for the given pressure scaling (ADC counts at 0 Pa and Pa per count) and
    /// encoder resolution. An unusable configuration gives a tick that latches
    /// [`fault::CONFIG`] at once.
    pub fn from_params(
        cfg: &ControllerConfig,
        adc_zero_counts: u16,
        pa_per_count: f64,
        encoder_counts_per_rev: u32,
    ) -> Self {
        let mut ok = cfg.is_valid() && encoder_counts_per_rev > 0;
        let f = |x: f32| x as f64;
        let q16 = 65_536.0;
        let q24 = 16_777_216.0;
        let hz = f(cfg.tick_hz);
        let dt = 1.0 / hz;
        let g = &cfg.geometry;
        let pid = &cfg.position;
        let alpha = 1.0 - libm::exp(-2.0 * core::f64::consts::PI * f(cfg.velocity_cutoff_hz) * dt);
        let to_q = |x: f64, q: f64| sat_i32(round_i64(x * q));
        let law = FixedForceLaw::from_params(&cfg.force_law);
        let model = FixedTorqueModel::from_params(&cfg.torque_model);
        ok &= law.is_valid() && model.is_valid() && (1.0..=1.0e5).contains(&hz);
        FixedTickConfig {
            adc_zero: adc_zero_counts as i32,
            pa_per_count: Coef::new(pa_per_count, 4096.0, &mut ok),
            rad_per_count: Coef::new(
                2.0 * core::f64::consts::PI / encoder_counts_per_rev as f64 * q16,
                (1 << 24) as f64,
                &mut ok,
            ),
            tick_hz: hz as i32,
            vel_alpha: Coef::new(alpha, (1 << 25) as f64, &mut ok),
            e0_q16: to_q(1.0 - f(g.initial_contraction), q16),
            stretch_per_rad: Coef::new(
                f(g.sprocket_radius_m) / f(g.rest_length_m),
                (1 << 20) as f64,
                &mut ok,
            ),
            lever: Coef::new(f(g.sprocket_radius_m), (1 << 27) as f64, &mut ok),
            kp: Coef::new(f(pid.kp_nm_per_rad), (1 << 21) as f64, &mut ok),
            ki_dt: Coef::new(
                f(pid.ki_nm_per_rad_s) * dt * 256.0,
                (1 << 21) as f64,
                &mut ok,
            ),
            kd: Coef::new(f(pid.kd_nm_s_per_rad), (1 << 21) as f64, &mut ok),
            i_limit_q24: to_q(f(pid.i_limit_nm), q24),
            out_limit_q16: to_q(f(pid.out_limit_nm), q16),
            kt_dt: Coef::new(
                f(cfg.torque.ki_per_s) * dt * 256.0,
                (1 << 24) as f64,
                &mut ok,
            ),
            corr_limit_q24: to_q(f(cfg.torque.corr_limit_nm), q24),
            kpp: Coef::new(f(cfg.pressure.kp_per_pa) * q16, (1 << 21) as f64, &mut ok),
            deadband_pa: to_q(f(cfg.pressure.deadband_pa), 1.0),
            p_over_pa: to_q(f(cfg.p_over_gauge_pa), 1.0),
            angle_min_q16: to_q(f(cfg.angle_limits.min), q16),
            angle_max_q16: to_q(f(cfg.angle_limits.max), q16),
            setpoint_max_q16: to_q(f(cfg.angle_setpoint_max_rad), q16),
            stale_ticks: cfg
                .pressure_limits
                .stale_ticks
                .min(cfg.angle_limits.stale_ticks),
            law,
            model,
            valid: ok
                && f(pid.i_limit_nm) * q24 < 2.0e9
                && f(pid.out_limit_nm) * q16 < 2.0e9
                && f(cfg.torque.corr_limit_nm) * q24 < 2.0e9
                && f(g.initial_contraction).abs() < 1.0,
        }
    }

    /// False when the configuration does not fit the fixed formats.
    pub const fn is_valid(&self) -> bool {
        self.valid
    }
}

/// The fixed-point control tick; see the [module docs](self).
#[derive(Clone, Copy, Debug)]
pub struct FixedTick {
    cfg: FixedTickConfig,
    p_pa: [i32; 2],
    p_age: [u32; 2],
    p_seen: [bool; 2],
    angle_q16: i32,
    angle_age: u32,
    angle_seen: bool,
    velocity_q16: i32,
    integ_q24: i32,
    corr_q24: i32,
    fault: u8,
}

/// Latches `code` unless a fault is latched already (the first one stays).
#[inline(always)]
fn latch(fault: &mut u8, code: u8) {
    if *fault == 0 {
        *fault = code;
    }
}

/// Set-point in mrad -> Q16 rad: floor(mrad x 65.536), no division (65.536 = 68 719 477 / 2^20
/// to 4e-9 relative).
#[inline]
pub fn mrad_to_q16(mrad: i32) -> i32 {
    term(68_719_477, 20, clamp_i32(mrad, -(1 << 20), 1 << 20))
}

impl FixedTick {
    /// A tick at start-up: no sample seen, integrators 0, no fault.
    pub fn new(cfg: FixedTickConfig) -> Self {
        FixedTick {
            cfg,
            p_pa: [0; 2],
            p_age: [0; 2],
            p_seen: [false; 2],
            angle_q16: 0,
            angle_age: 0,
            angle_seen: false,
            velocity_q16: 0,
            integ_q24: 0,
            corr_q24: 0,
            fault: if cfg.valid { 0 } else { fault::CONFIG },
        }
    }

    /// The latched fault code (0 = none).
    pub fn fault(&self) -> u8 {
        self.fault
    }

    /// One tick: raw sensor samples and the angle set-point (Q16 rad, see [`mrad_to_q16`]).
    /// Never panics, for any input.
    pub fn step(&mut self, frame: &FixedFrame, setpoint_q16: i32) -> FixedTickOutput {
        // By reference: the configuration holds the force-law tables (~1 KiB), a copy per tick
        // would cost more than the arithmetic.
        let c = &self.cfg;
        // 1. Channels.
        for (i, s) in [frame.p1_adc, frame.p2_adc].into_iter().enumerate() {
            match s {
                Some(n) if n == 0 || n >= ADC_MAX => latch(
                    &mut self.fault,
                    [fault::PRESSURE1_IMPLAUSIBLE, fault::PRESSURE2_IMPLAUSIBLE][i],
                ),
                Some(n) => {
                    self.p_pa[i] = c.pa_per_count.apply(n as i32 - c.adc_zero);
                    self.p_age[i] = 0;
                    self.p_seen[i] = true;
                }
                None => self.p_age[i] = self.p_age[i].saturating_add(1),
            }
        }
        match frame.encoder {
            Some(n) => {
                let a = c.rad_per_count.apply(clamp_i32(n, -(1 << 24), 1 << 24));
                if a < c.angle_min_q16 || a > c.angle_max_q16 {
                    latch(&mut self.fault, fault::ANGLE_RANGE);
                }
                if self.angle_seen {
                    let diff = clamp_i32(a.wrapping_sub(self.angle_q16), -(1 << 20), 1 << 20);
                    let raw = clamp_i32(diff.wrapping_mul(c.tick_hz), -(1 << 24), 1 << 24);
                    self.velocity_q16 = self
                        .velocity_q16
                        .wrapping_add(c.vel_alpha.apply(raw.wrapping_sub(self.velocity_q16)));
                }
                self.angle_q16 = a;
                self.angle_age = 0;
                self.angle_seen = true;
            }
            None => self.angle_age = self.angle_age.saturating_add(1),
        }
        let stale = |seen: bool, age: u32| seen && age > c.stale_ticks;
        if stale(self.p_seen[0], self.p_age[0])
            || stale(self.p_seen[1], self.p_age[1])
            || stale(self.angle_seen, self.angle_age)
        {
            latch(&mut self.fault, fault::STALE);
        }
        if self.p_pa[0] > c.p_over_pa || self.p_pa[1] > c.p_over_pa {
            latch(&mut self.fault, fault::OVER_PRESSURE);
        }
        if setpoint_q16 < -c.setpoint_max_q16 || setpoint_q16 > c.setpoint_max_q16 {
            latch(&mut self.fault, fault::SETPOINT);
        }
        let mut out = FixedTickOutput {
            angle_q16: self.angle_q16,
            velocity_q16: self.velocity_q16,
            fault: self.fault,
            ..FixedTickOutput::default()
        };
        if self.fault != 0 || !(self.p_seen[0] && self.p_seen[1] && self.angle_seen) {
            self.integ_q24 = 0;
            self.corr_q24 = 0;
            return out;
        }
        // 2. Position PID -> desired torque (Q16), conditional integration.
        let (a, v) = (self.angle_q16, self.velocity_q16);
        let err = clamp_i32(setpoint_q16.wrapping_sub(a), -(1 << 21), 1 << 21);
        let pd =
            c.kp.apply(err)
                .wrapping_sub(c.kd.apply(clamp_i32(v, -(1 << 21), 1 << 21)));
        let pd = clamp_i32(pd, -(1 << 30), 1 << 30);
        let integ = clamp_i32(
            self.integ_q24.wrapping_add(c.ki_dt.apply(err)),
            -c.i_limit_q24,
            c.i_limit_q24,
        );
        let lim = c.out_limit_q16;
        let unsat = pd.wrapping_add(integ >> 8);
        let t_des = clamp_i32(unsat, -lim, lim);
        // Integrate unless the output saturates in the direction the error pushes it.
        if !((unsat > lim && err > 0) || (unsat < -lim && err < 0)) {
            self.integ_q24 = integ;
        }
        // 3. Torque estimate from the muscle forces: T = (F1 - F2) r.
        let de = c.stretch_per_rad.apply(clamp_i32(a, -(1 << 20), 1 << 20));
        let e1 = Stretch::from_bits(c.e0_q16.wrapping_sub(de));
        let e2 = Stretch::from_bits(c.e0_q16.wrapping_add(de));
        let f1 = c
            .law
            .force(PressurePa::from_bits(self.p_pa[0]), e1)
            .force_n
            .to_bits();
        let f2 = c
            .law
            .force(PressurePa::from_bits(self.p_pa[1]), e2)
            .force_n
            .to_bits();
        let t_est = c
            .lever
            .apply(clamp_i32(f1.wrapping_sub(f2), -(1 << 27), 1 << 27));
        // 4. Torque loop (integral correction) and the inverse model.
        let t_err = clamp_i32(t_des.wrapping_sub(t_est), -(1 << 24), 1 << 24);
        let corr = clamp_i32(
            self.corr_q24.wrapping_add(c.kt_dt.apply(t_err)),
            -c.corr_limit_q24,
            c.corr_limit_q24,
        );
        let inv = c.model.inverse_at(
            super::AngleRad::from_bits(a),
            super::VelocityRadS::from_bits(v),
        );
        let act = inv.activation(TorqueNm::from_bits(t_des.wrapping_add(corr >> 8)));
        if !act.saturated {
            self.corr_q24 = corr;
        }
        let (ps1, ps2) = c.model.pressures_gauge_pa(act.dp_pa);
        let p_set = [ps1.to_bits(), ps2.to_bits()];
        // 5. Pressure loops -> valve commands in [-1, 1] (Q16).
        let mut valves = [0i32; 2];
        for i in 0..2 {
            let e = clamp_i32(p_set[i].wrapping_sub(self.p_pa[i]), -(1 << 21), 1 << 21);
            if e > c.deadband_pa || e < -c.deadband_pa {
                valves[i] = clamp_i32(c.kpp.apply(e), -(1 << 16), 1 << 16);
            }
        }
        out.valves_q16 = valves;
        out.p_set_pa = p_set;
        out.torque_des_q16 = t_des;
        out.torque_est_q16 = t_est;
        out.armed = true;
        out
    }
}

/// The reference configuration with the reference wiring (`src/wiring.rs`) at the trace's
/// tick rate, pre-scaled (f64: host or start-up).
pub fn reference_from_params(tick_hz: f32) -> FixedTickConfig {
    use crate::wiring;
    let pa_per_count = wiring::PRESSURE_FULL_SCALE_PA as f64
        / (wiring::PRESSURE_COUNTS_AT_FULL - wiring::PRESSURE_COUNTS_AT_ZERO) as f64;
    FixedTickConfig::from_params(
        &ControllerConfig::reference(tick_hz),
        wiring::PRESSURE_COUNTS_AT_ZERO as u16,
        pa_per_count,
        wiring::ENCODER_COUNTS_PER_REV,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trace::{TraceRunner, SENSOR_TRACE, TRACE_TICK_HZ};
    use proptest::prelude::*;
    use std::vec::Vec;

    fn replay() -> Vec<FixedTickOutput> {
        let mut t = FixedTick::new(reference_from_params(TRACE_TICK_HZ));
        SENSOR_TRACE
            .iter()
            .map(|r| t.step(&r.fixed_frame(), mrad_to_q16(r.angle_set_mrad as i32)))
            .collect()
    }

    #[test]
    fn reference_configuration_fits() {
        assert!(reference_from_params(TRACE_TICK_HZ).is_valid());
        assert_eq!(mrad_to_q16(1000), 65_536);
        assert_eq!(mrad_to_q16(-300), -19_661);
    }

    #[test]
    fn replay_arms_controls_and_faults_on_the_shorted_sensor() {
        let out = replay();
        assert_eq!(out.len(), 500);
        assert!(!out[0].armed, "no sensors yet: disarmed");
        assert!(out[10].armed);
        // After the set-point step the position loop asks for torque and the valves move.
        assert!(out[60..200].iter().any(|o| o.torque_des_q16 != 0));
        assert!(out[60..200]
            .iter()
            .any(|o| o.valves_q16[0] != 0 || o.valves_q16[1] != 0));
        // Missing samples below the stale limit do not fault.
        assert!(out[152].armed && out[202].armed);
        // The shorted muscle 2 transducer (4095 counts) at tick 460 latches: valves hold.
        for o in &out[460..] {
            assert_eq!(o.fault, fault::PRESSURE2_IMPLAUSIBLE);
            assert!(!o.armed);
            assert_eq!(o.valves_q16, [0, 0]);
        }
        assert!(out[..460].iter().all(|o| o.fault == 0));
    }

    /// The torque estimate of the fixed tick against the f32 tick's (a separate code path:
    /// f32 sensor scaling, f32 force law) on every tick where both are armed: within
    /// 5e-3 N m (the fixed law tracks the f32 law within 0.1 N per muscle, times the two
    /// muscles and the 0.025 m lever).
    #[test]
    fn torque_estimate_matches_the_f32_tick() {
        let fixed = replay();
        let mut r = TraceRunner::new();
        let mut worst = 0.0f64;
        let mut n = 0;
        for (i, fx) in fixed.iter().enumerate() {
            let rec = r.step().unwrap();
            let armed32 = rec.words[8] >> 8 == 1;
            if fx.armed && armed32 {
                let t32 = f32::from_bits(rec.words[5]) as f64;
                let a32 = f32::from_bits(rec.words[6]) as f64;
                let tf = fx.torque_est_q16 as f64 / 65_536.0;
                let af = fx.angle_q16 as f64 / 65_536.0;
                assert!((af - a32).abs() < 1e-4, "tick {i}: angle {af} vs {a32}");
                worst = worst.max((tf - t32).abs());
                n += 1;
            }
        }
        std::println!(
            "fixed tick vs f32 tick: torque estimate max diff {worst:.2e} N m over {n} ticks"
        );
        assert!(n > 400, "{n}");
        assert!(worst < 5e-3, "{worst}");
    }

    #[test]
    fn position_integrator_stops_while_the_output_saturates() {
        let cfg = reference_from_params(TRACE_TICK_HZ);
        let mut t = FixedTick::new(cfg);
        let frame = FixedFrame {
            p1_adc: Some(1500),
            p2_adc: Some(1500),
            encoder: Some(0),
        };
        // 0.8 rad error x kp 29.7 = 23.7 N m > the 10 N m output limit: saturated.
        for _ in 0..50 {
            let o = t.step(&frame, mrad_to_q16(800));
            assert!(o.armed);
            assert_eq!(o.torque_des_q16, cfg.out_limit_q16);
        }
        assert_eq!(t.integ_q24, 0, "no wind-up while saturated");
        // Small error (unsaturated): it integrates.
        t.step(&frame, mrad_to_q16(10));
        assert!(t.integ_q24 > 0);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2048))]

        /// Any raw samples and set-points: never panics; valves within [-1, 1], pressure
        /// set-points within [0, 600 kPa].
        #[test]
        fn any_inputs_are_safe(
            steps in proptest::collection::vec(
                (proptest::option::of(any::<u16>()), proptest::option::of(any::<u16>()),
                 proptest::option::of(any::<i32>()), any::<i32>()), 1..40),
        ) {
            let mut t = FixedTick::new(reference_from_params(TRACE_TICK_HZ));
            for (p1, p2, enc, sp) in steps {
                let o = t.step(&FixedFrame { p1_adc: p1, p2_adc: p2, encoder: enc }, sp);
                for v in o.valves_q16 {
                    prop_assert!((-(1 << 16)..=(1 << 16)).contains(&v));
                }
                for p in o.p_set_pa {
                    prop_assert!((0..=600_000).contains(&p));
                }
                prop_assert!(!(o.armed && o.fault != 0));
            }
        }
    }
}
