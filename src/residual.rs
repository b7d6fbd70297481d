//! Model-based supervision of the valves and the supply: the pressure residual.
//!
//! Every `window_ticks` ticks (10 at 1 kHz: one PWM period of the on/off valves) each muscle's
//! measured pressure change over the window is compared with what the firmware's own model
//! of that muscle predicts from the valve commands it issued:
//!
//! ```text
//! dp/dt = (p_atm Q - P dV/dt) / V                      (P absolute, V = V(chi), chi from the angle)
//! Q     = u_in C P_s phi(P / P_s) - u_ex C P phi(p_atm / P)
//! phi(s) = 1 for s <= b,  sqrt(1 - ((s - b) / (1 - b))^2) above (ISO 6358 ellipse)
//! ```
//!
//! with the window means of the inflate and exhaust duties `u_in`, `u_ex`, the pressure,
//! angle and volume rate at the window's middle, the nominal supply `P_s`, conductance `C`
//! and critical ratio `b` of [`ValveModelParams`]. The residual
//! `e = (p_end - p_start) / T - dp/dt_model` is compared with
//! `R = residual_abs_pa_s + residual_rel (|inflow term| + |outflow term| + |volume term|)`:
//! the relative part absorbs model error (polytropic exponent, PWM edges, supply droop).
//! A residual beyond `R` in `persist_windows` consecutive windows is a fault; which one
//! follows from the sign and from what the valves were told:
//!
//! | residual | valves commanded | pressure | fault |
//! |---|---|---|---|
//! | `e > R` | exhaust open | rises | inlet stuck open (only inflow raises it) |
//! | `e > R` | exhaust open | does not rise | exhaust stuck closed |
//! | `e > R` | exhaust closed | - | inlet stuck open |
//! | `e < -R` | inlet open | - | the nearest of: inlet stuck closed (no inflow), supply lost (air flows back through the inlet for its duty), exhaust stuck open (inflow against a fully open exhaust) |
//! | `e < -R` | inlet closed | - | exhaust stuck open |
//!
//! A small or short opening leaves a per-window residual below `R`; the integrated check
//! covers it: per muscle and valve, the change the model expects from that valve and the
//! change measured net of the other terms are summed over the windows in which it was open;
//! once `integral_min_pa` is expected, less than `integral_fraction` of it seen is a fault
//! (inlet: classified as above; exhaust: stuck closed, or inlet stuck open if the pressure
//! rose), and the sums start over.
//!
//! A valve dead time (command to flow) up to one window (10 ms) is no fault although the
//! firmware does not know it: the per-window threshold widens by the change of the inflow and
//! outflow terms since the last window (the late flow of the last one lands in this one); the
//! integrated check also counts what the window after an opening sees (only in the valve's
//! favour: the gas returning to the wall temperature after a fast fill or vent runs the other
//! way, by a few hundred kPa/s that the isothermal model does not know), takes the other
//! valve's term with or without its late flow, whichever leaves more to the valve judged, and
//! judges only what was expected up to the last window. The price: a fresh opening is judged
//! one window later.
//!
//! What the integrated check does not know is also taken in the judged valve's favour, never
//! against it:
//! - For the exhaust, the inflow's term (both valves of one muscle open in one window, as a
//!   pressure loop flipping across its deadband does) at the threshold's relative margin
//!   `residual_rel`: a polytropic fill raises the pressure up to 1.4 times the isothermal
//!   model's change, which would otherwise count as an exhaust that did not vent. Not the
//!   other way round: a vent larger than modelled is what a stuck-open exhaust is, and the
//!   inlet's check is what sees it while the loop fills against it.
//! - The muscle's trend at rest: the measured rate net of the volume term over the windows in
//!   which both its valves were closed (and not just closed), an exponential mean over about
//!   four windows. A leak makes it negative (the inlet is credited with what the leak took), a
//!   chamber warming back after a vent positive (the exhaust is credited). A stuck valve still
//!   shows: net of the trend, nothing of the expected change is seen. A trend beyond the
//!   threshold's absolute part (`residual_abs_pa_s`) is no leak but an open path, a stuck-open
//!   exhaust venting at megapascals per second, and is not credited.
//!
//! - The gas's heat after a long opening: a fill heats the gas (the pressure rises up to 1.4
//!   times the isothermal model's change) and it cools back in the windows after, taking that
//!   surplus away again. A judged batch that was due at least three times `integral_min_pa`
//!   carries what it delivered beyond the model's expectation into the next batch, up to
//!   `integral_min_pa` (so a valve sticking right after it delivered is judged at most one
//!   batch later). An inlet opened in a window in which the exhaust's term is the larger is
//!   not judged in that window: the vent of a gas still hot from the fill drops the pressure
//!   faster than the model says and would swamp the inlet's share. Checked against a chamber
//!   exchanging heat with its wall (a model the monitor does not share) with thermal time
//!   constants from 0.2 s to 2 s; below about 0.15 s the cooling after a fill outruns what is
//!   carried and a loop refilling against it reads as a stuck-closed inlet.
//!
//! The price: an exhaust opened only in windows with a much larger inflow, or an inlet held
//! against a leak that needs a pulse in every window, is not judged by the integrated check; a
//! pressure loop that finds the valve stuck keeps opening it alone, and the per-window check
//! or the integrated one then sees it.
//!
//! The classes can overlap (a stuck-open exhaust while inflating at a small duty looks like
//! a lost supply); the fault is still that muscle's air path, and the safe state is the
//! same. While faulted (valves closed in
//! Hold) the residual keeps running: a stuck-open inlet or exhaust stays visible, so a reset
//! is refused while it persists; a stuck-closed valve or a lost supply is only seen again
//! when the valve is commanded open after a re-arm.
//!
//! The openings are what the valve driver actually switched (its PWM latches a duty per
//! period, so the mean command of a window can differ from it by most of a period): the
//! caller reports them with [`crate::tick::ControlTick::valves_applied`] (or, for on/off
//! valves, [`crate::tick::ControlTick::valves_switched`]: integer counts); without that
//! report the tick's command stands in for them (exact for proportional valves).
//!
//! Cost on the MCU: a few adds per tick (opening sums); the model runs once per window.

use crate::geometry::JointGeometry;
use crate::math::within;
use crate::safety::{FaultCode, FaultSet};

/// The firmware's model of one muscle's pressure dynamics (both muscles are identical) and
/// the residual thresholds.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ValveModelParams {
    /// Atmospheric pressure [Pa absolute].
    pub p_atm_pa: f32,
    /// Nominal supply pressure [Pa gauge].
    pub supply_gauge_pa: f32,
    /// ISO 6358 sonic conductance of each valve [m^3 / (s Pa)].
    pub conductance_m3_per_s_pa: f32,
    /// ISO 6358 critical pressure ratio.
    pub critical_ratio: f32,
    /// Chamber volume `V(chi) = b0 + b1 chi + b2 chi^2 + b3 chi^3` [m^3].
    pub volume_poly_m3: [f32; 4],
    /// Absolute part of the residual threshold [Pa/s].
    pub residual_abs_pa_s: f32,
    /// Relative part of the residual threshold (of the summed model terms).
    pub residual_rel: f32,
    /// Window length [ticks] (>= 1).
    pub window_ticks: u32,
    /// Consecutive windows beyond the threshold that make a fault (>= 1).
    pub persist_windows: u32,
    /// Integrated check of a valve that should move the pressure: once the model expects at
    /// least this much change from it over its opening windows [Pa] ...
    pub integral_min_pa: f32,
    /// ... and less than this fraction of it was seen, the valve's path is faulty (stuck
    /// closed, or for the inlet also a lost supply / a stuck-open exhaust).
    pub integral_fraction: f32,
}

impl ValveModelParams {
    /// The reference plant (`shared/plant/reference-1dof.toml`): 600 kPa gauge supply,
    /// C = 8e-9 m^3/(s Pa), b = 0.433, the DMSP-20 volume polynomial; threshold 0.5 MPa/s +
    /// 50 % of the model terms, two 10-tick windows. The plant numbers come from
    /// `config/plant_constants.toml` (build.rs); the thresholds are design choices.
    ///
    /// Threshold rationale: a stuck-open inlet at 300 kPa raises the pressure at ~5 MPa/s
    /// (the model says 0); 500 Pa of sensor noise gives 0.07 MPa/s of noise on a 10 ms
    /// window; the relative part covers a polytropic exponent up to 1.4 and a supply droop.
    pub const REFERENCE: ValveModelParams = ValveModelParams {
        p_atm_pa: crate::constants::P_ATM_PA,
        supply_gauge_pa: crate::constants::SUPPLY_GAUGE_PA,
        conductance_m3_per_s_pa: crate::constants::VALVE_CONDUCTANCE_M3_PER_S_PA,
        critical_ratio: crate::constants::VALVE_CRITICAL_RATIO,
        volume_poly_m3: crate::constants::MUSCLE_VOLUME_POLY_M3,
        residual_abs_pa_s: 500_000.0,
        residual_rel: 0.5,
        window_ticks: 10,
        persist_windows: 2,
        // 5 kPa: ~7 sigma of the 500 Pa sensor noise on a pressure difference; 25 % leaves
        // the model a factor of 4 of error (polytropic exponent, supply droop, PWM edges).
        integral_min_pa: 5_000.0,
        integral_fraction: 0.25,
    };

    /// True when every parameter is usable.
    pub fn is_valid(&self) -> bool {
        let pos = |x: f32| x > 0.0 && within(x, 0.0, f32::MAX);
        pos(self.p_atm_pa)
            && within(self.supply_gauge_pa, 0.0, f32::MAX)
            && pos(self.conductance_m3_per_s_pa)
            && within(self.critical_ratio, 0.0, 1.0)
            && self.critical_ratio < 1.0
            && self
                .volume_poly_m3
                .iter()
                .all(|&b| within(b, -f32::MAX, f32::MAX))
            && self.volume_poly_m3[0] > 0.0
            && pos(self.residual_abs_pa_s)
            && within(self.residual_rel, 0.0, f32::MAX)
            && self.window_ticks >= 1
            && self.persist_windows >= 1
            && pos(self.integral_min_pa)
            && pos(self.integral_fraction)
            && self.integral_fraction < 1.0
    }

    /// ISO 6358 flow function (ellipse, no laminar patch) of the pressure ratio `s`.
    #[inline]
    fn phi(&self, s: f32) -> f32 {
        let b = self.critical_ratio;
        if s <= b {
            1.0
        } else if s >= 1.0 {
            0.0
        } else {
            let x = (s - b) / (1.0 - b);
            crate::math::sqrtf(1.0 - x * x)
        }
    }

    /// The model's pressure-rate terms [Pa/s] (inflow, outflow, volume change) of one muscle
    /// at gauge pressure `p_gauge_pa`, contraction `chi`, contraction rate `chi_rate_per_s`,
    /// with mean inflate / exhaust duties `u_in`, `u_ex`.
    pub fn rate_terms_pa_s(
        &self,
        p_gauge_pa: f32,
        chi: f32,
        chi_rate_per_s: f32,
        u_in: f32,
        u_ex: f32,
    ) -> (f32, f32, f32) {
        let [b0, b1, b2, b3] = self.volume_poly_m3;
        let v = b0 + chi * (b1 + chi * (b2 + chi * b3));
        let dv = (b1 + chi * (2.0 * b2 + chi * 3.0 * b3)) * chi_rate_per_s;
        // A chamber volume below a tenth of b0 is outside the model: no prediction.
        let v = if v > 0.1 * b0 { v } else { 0.1 * b0 };
        let p = p_gauge_pa + self.p_atm_pa;
        let p = if p > 1.0 { p } else { 1.0 };
        let ps = self.supply_gauge_pa + self.p_atm_pa;
        let k = self.p_atm_pa * self.conductance_m3_per_s_pa / v;
        // A valve that stayed closed over the window contributes nothing: its flow function
        // (a division and a square root) is skipped (same sum: the term would be +-0).
        let q_in = if u_in == 0.0 {
            0.0
        } else if ps >= p {
            u_in * k * ps * self.phi(p / ps)
        } else {
            -u_in * k * p * self.phi(ps / p)
        };
        let q_out = if u_ex == 0.0 {
            0.0
        } else if p >= self.p_atm_pa {
            -u_ex * k * p * self.phi(self.p_atm_pa / p)
        } else {
            u_ex * k * self.p_atm_pa * self.phi(p / self.p_atm_pa)
        };
        let q_vol = -p * dv / v;
        (q_in, q_out, q_vol)
    }
}

/// One muscle's window and persistence counters.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct MuscleWindow {
    p_start_pa: f32,
    /// Sums of the inflate and exhaust openings over the window.
    sum_in: f32,
    sum_ex: f32,
    above: u32,
    below: u32,
    /// The integrated checks of the inlet and of the exhaust.
    inlet: Integral,
    exhaust: Integral,
    /// The last window's inflow and outflow terms [Pa/s]: with a valve dead time, a window
    /// still sees part of the last one's flow.
    q_in_last_pa_s: f32,
    q_out_last_pa_s: f32,
    /// The muscle's own pressure trend while its valves rest [Pa/s]: the measured rate net
    /// of the volume term over the windows with both valves closed (and not just closed),
    /// smoothed. A leak makes it negative, the gas warming back after a vent positive.
    trend_pa_s: f32,
}

/// One valve's integrated check: over the consecutive windows with it commanded open, the
/// pressure change the model expects from it [Pa] and the change measured net of every other
/// model term [Pa] (both counted positive in the valve's direction); `was_open`: it was open
/// in the last window (whose late flow this window may still see).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct Integral {
    expected_pa: f32,
    seen_pa: f32,
    was_open: bool,
}

impl Integral {
    /// Adds one window of `t` s: the valve `open` with the model rate `q_pa_s` (>= 0), the
    /// rate `seen_pa_s` measured net of the other terms; judges once the expected change due
    /// (all but this window's: its flow may still be late) reaches `integral_min_pa`.
    /// Returns (lost: less than `integral_fraction` of it seen, rose: the pressure went the
    /// other way). Called only when the valve is or was open (else nothing is added and
    /// nothing newly due).
    #[inline(never)]
    fn add(
        &mut self,
        open: bool,
        q_pa_s: f32,
        seen_pa_s: f32,
        t: f32,
        p: &ValveModelParams,
    ) -> (bool, bool) {
        // Due: what was expected up to the last window (this window's flow may be late).
        let due_pa = self.expected_pa;
        {
            let seen_pa = seen_pa_s * t;
            if open {
                self.expected_pa += q_pa_s * t;
            }
            // A window after an opening (the valve closed again) counts only in the valve's
            // favour: it holds the late flow of a slow valve, but also the gas returning to
            // the wall temperature after a fast fill or vent (a few hundred kPa/s the
            // isothermal model does not know), which runs the other way.
            if open || seen_pa > 0.0 {
                self.seen_pa += seen_pa;
            }
        }
        self.was_open = open;
        let judged = due_pa >= p.integral_min_pa;
        let lost = judged && !(self.seen_pa >= p.integral_fraction * due_pa);
        let rose = self.seen_pa < -p.integral_fraction * due_pa;
        if judged {
            // What a long opening delivered beyond the model's expectation is carried into
            // the next sums, up to `integral_min_pa`: a polytropic fill raises the pressure
            // above the isothermal model's change, and the gas cooling back takes that
            // surplus away in the windows after (a short pulse right after a long fill would
            // otherwise look lost). Only after a long opening (at least
            // `CARRY_MIN_BATCHES` times `integral_min_pa` due), which moves the gas's
            // temperature: the surplus of short pulses is noise and PWM edges, and carried
            // it would hide the small deficit of an inlet filling against a stuck-open
            // exhaust. Capped, a valve sticking right after it delivered is judged at most
            // one batch later; a stuck valve leaves no surplus to carry.
            let surplus = self.seen_pa - self.expected_pa;
            *self = Integral {
                was_open: self.was_open,
                seen_pa: if !(due_pa >= CARRY_MIN_BATCHES * p.integral_min_pa) {
                    0.0
                } else if surplus > p.integral_min_pa {
                    p.integral_min_pa
                } else if surplus > 0.0 {
                    surplus
                } else {
                    0.0
                },
                ..Integral::default()
            };
        }
        (lost, rose)
    }
}

/// A judged batch carries its surplus into the next only when at least this many times
/// `integral_min_pa` was due (a fill or vent of 15 kPa and more at the reference's 5 kPa).
const CARRY_MIN_BATCHES: f32 = 3.0;

/// Weight of a resting window in the muscle's trend (an exponential mean over about four
/// windows: the 70 kPa/s of sensor noise on one window's rate falls to about 25 kPa/s).
const TREND_SMOOTHING: f32 = 0.25;

/// The fault that explains muscle `$i`'s window (`None`: none), an expression: a lost exhaust
/// path, a persistent residual above or below its threshold, or a lost inlet path, each told
/// apart by the flow terms. A macro expanded in place in [`ResidualMonitor::evaluate`]: as a
/// function (even `#[inline(always)]`) LLVM simplifies it on its own first, and the
/// evaluation's machine code changes (measured on the Cortex-M4 image).
macro_rules! window_fault {
    ($t:ident, $i:ident, $w:ident, $q_in:ident, $q_out:ident, $q_vol:ident, $measured:ident, $u_in:ident, $p_mid:ident, $chi:ident, $chi_rate:ident, $ex_lost:ident, $in_lost:ident, $ex_rose:ident) => {{
        let rate_abs = $t.params.residual_abs_pa_s;
        if $ex_lost && !$in_lost {
            Some(if $ex_rose {
                pick($i, FaultCode::InletStuckOpen1, FaultCode::InletStuckOpen2)
            } else {
                pick(
                    $i,
                    FaultCode::ExhaustStuckClosed1,
                    FaultCode::ExhaustStuckClosed2,
                )
            })
        } else if $w.above >= $t.params.persist_windows {
            Some(if -$q_out > rate_abs && !($measured - $q_vol > rate_abs) {
                pick(
                    $i,
                    FaultCode::ExhaustStuckClosed1,
                    FaultCode::ExhaustStuckClosed2,
                )
            } else {
                pick($i, FaultCode::InletStuckOpen1, FaultCode::InletStuckOpen2)
            })
        } else if $w.below >= $t.params.persist_windows || $in_lost {
            Some(if $q_in > rate_abs || $in_lost {
                // Inflating and the pressure lags: the nearest of three explanations.
                // Inlet stuck closed: no inflow. Supply lost: the inlet lets air back
                // out (to a supply at atmosphere) for its duty. Exhaust stuck open: the
                // inflow against a fully open exhaust.
                let (_, full_out, _) = $t.params.rate_terms_pa_s($p_mid, $chi, $chi_rate, 0.0, 1.0);
                let closed = libm::fabsf($measured - ($q_vol + $q_out));
                let supply = libm::fabsf($measured - ($q_vol + $q_out + $u_in * full_out));
                let exhaust = libm::fabsf($measured - ($q_vol + $q_in + full_out));
                if exhaust < supply && exhaust < closed {
                    pick(
                        $i,
                        FaultCode::ExhaustStuckOpen1,
                        FaultCode::ExhaustStuckOpen2,
                    )
                } else if supply < closed {
                    FaultCode::SupplyLost
                } else {
                    pick(
                        $i,
                        FaultCode::InletStuckClosed1,
                        FaultCode::InletStuckClosed2,
                    )
                }
            } else {
                pick(
                    $i,
                    FaultCode::ExhaustStuckOpen1,
                    FaultCode::ExhaustStuckOpen2,
                )
            })
        } else {
            None
        }
    }};
}

/// The residual monitor of both muscles ([module documentation](self)).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ResidualMonitor {
    params: ValveModelParams,
    /// chi0 and r / l_n of the joint geometry.
    chi0: f32,
    geometry_ratio: f32,
    m: [MuscleWindow; 2],
    angle_start_rad: f32,
    /// Ticks each on/off valve was switched open in the window, one 16-bit lane per valve
    /// (inflate 1, exhaust 1, inflate 2, exhaust 2 from the low end): one 64-bit add a tick.
    switched_ticks: u64,
    /// Ticks and time in the window; `open` = a window is running.
    ticks: u32,
    elapsed_s: f32,
    open: bool,
    /// The faults of the last evaluation (kept until the next one).
    active: FaultSet,
}

impl ResidualMonitor {
    /// A monitor with no window yet.
    pub fn new(params: ValveModelParams, geometry: &JointGeometry) -> Self {
        ResidualMonitor {
            params,
            chi0: geometry.initial_contraction,
            geometry_ratio: geometry.sprocket_radius_m / geometry.rest_length_m,
            m: [MuscleWindow {
                p_start_pa: 0.0,
                sum_in: 0.0,
                sum_ex: 0.0,
                above: 0,
                below: 0,
                inlet: Integral::default(),
                exhaust: Integral::default(),
                q_in_last_pa_s: 0.0,
                q_out_last_pa_s: 0.0,
                trend_pa_s: 0.0,
            }; 2],
            angle_start_rad: 0.0,
            switched_ticks: 0,
            ticks: 0,
            elapsed_s: 0.0,
            open: false,
            active: FaultSet::EMPTY,
        }
    }

    /// The faults found by the last evaluation (empty when all is well).
    #[inline]
    pub fn active(&self) -> FaultSet {
        self.active
    }

    /// Forgets the window and the counters (e.g. a sample was missing).
    pub fn restart(&mut self) {
        self.open = false;
        for w in self.m.iter_mut() {
            w.inlet = Integral::default();
            w.exhaust = Integral::default();
            w.q_in_last_pa_s = 0.0;
            w.q_out_last_pa_s = 0.0;
            w.trend_pa_s = 0.0;
        }
        self.m[0].above = 0;
        self.m[0].below = 0;
        self.m[1].above = 0;
        self.m[1].below = 0;
        self.active = FaultSet::EMPTY;
    }

    /// Start of a tick: `fresh` = all three channels delivered a valid sample this tick
    /// (`p1`, `p2`, `angle` are those samples) and `dt_s` is valid. Evaluates the window when
    /// it is complete. Returns the active residual faults.
    #[inline]
    pub fn observe(&mut self, fresh: bool, p1: f32, p2: f32, angle: f32, dt_s: f32) -> FaultSet {
        if !fresh {
            // A window needs both its end points; keep the counters (a sensor fault is
            // handled by the channel checks) but drop the window.
            self.open = false;
            return self.active;
        }
        if self.open {
            self.ticks += 1;
            self.elapsed_s += dt_s;
            if self.ticks >= self.params.window_ticks {
                self.evaluate(p1, p2, angle);
                self.start(p1, p2, angle);
            }
        } else {
            self.start(p1, p2, angle);
        }
        self.active
    }

    /// End of a tick: the valve openings commanded for the next period (inflate 1,
    /// exhaust 1, inflate 2, exhaust 2, each in [0, 1]).
    #[inline(always)]
    pub fn openings(&mut self, in1: f32, ex1: f32, in2: f32, ex2: f32) {
        let a = &mut self.m[0];
        a.sum_in += in1;
        a.sum_ex += ex1;
        let b = &mut self.m[1];
        b.sum_in += in2;
        b.sum_ex += ex2;
    }

    /// End of a tick, for on/off valves: which valves the driver switched open (the lanes
    /// of [`crate::valves::SwitchedValves`]). Counts like [`Self::openings`] with 0 / 1.
    #[inline(always)]
    pub fn switched(&mut self, lanes: u64) {
        self.switched_ticks += lanes;
    }

    fn start(&mut self, p1: f32, p2: f32, angle: f32) {
        self.open = true;
        self.switched_ticks = 0;
        self.ticks = 0;
        self.elapsed_s = 0.0;
        self.angle_start_rad = angle;
        for (w, p) in self.m.iter_mut().zip([p1, p2]) {
            w.p_start_pa = p;
            w.sum_in = 0.0;
            w.sum_ex = 0.0;
        }
    }

    #[cold]
    #[inline(never)]
    fn evaluate(&mut self, p1: f32, p2: f32, angle: f32) {
        let t = self.elapsed_s;
        let n = self.ticks as f32;
        if !(t > 0.0) || !(n > 0.0) {
            return;
        }
        let mut active = FaultSet::EMPTY;
        let inv_n = 1.0 / n;
        let inv_t = 1.0 / t;
        let angle_mid = 0.5 * (self.angle_start_rad + angle);
        let angle_rate = (angle - self.angle_start_rad) * inv_t;
        for i in 0..2 {
            let p_end = if i == 0 { p1 } else { p2 };
            let w = self.m[i];
            let p_mid = 0.5 * (w.p_start_pa + p_end);
            let lanes = self.switched_ticks >> (32 * i);
            let u_in = (w.sum_in + (lanes & 0xffff) as u16 as f32) * inv_n;
            let u_ex = (w.sum_ex + (lanes >> 16) as u16 as f32) * inv_n;
            let (chi, chi_rate) = self.contraction(i, angle_mid, angle_rate);
            let (q_in, q_out, q_vol) = self
                .params
                .rate_terms_pa_s(p_mid, chi, chi_rate, u_in, u_ex);
            let measured = (p_end - w.p_start_pa) * inv_t;
            let e = measured - (q_in + q_out + q_vol);
            // A valve answering up to one window late moves the last window's flow into this
            // one: the threshold widens by the change of the flow terms since the last
            // window.
            let d_in = w.q_in_last_pa_s - q_in;
            let d_out = w.q_out_last_pa_s - q_out;
            let r = self.params.residual_abs_pa_s
                + self.params.residual_rel
                    * (libm::fabsf(q_in) + libm::fabsf(q_out) + libm::fabsf(q_vol))
                + libm::fabsf(d_in)
                + libm::fabsf(d_out);
            let w = &mut self.m[i];
            w.q_in_last_pa_s = q_in;
            w.q_out_last_pa_s = q_out;
            // NaN residuals count as neither (the channel checks catch NaN samples).
            w.above = if e > r { w.above.saturating_add(1) } else { 0 };
            w.below = if e < -r { w.below.saturating_add(1) } else { 0 };
            // The integrated check: a small or short opening gives a per-window residual
            // below the threshold, but its expected effect adds up over the windows in which
            // the valve was open (windows with it closed add nothing and clear nothing). Once
            // the expected change is large enough the path is judged, and the sums start over.
            // What one valve is seen doing is the measured change net of the other terms, the
            // other valve's taken with or without its late flow, whichever leaves more to the
            // valve judged (an exhaust still venting while the inlet opens must not count
            // against the inlet).
            // (`d_out`, `d_in`: the last window's term minus this one's.)
            let q_out_other = if d_out < 0.0 { q_out + d_out } else { q_out };
            // An inlet opened beside a larger vent is not judged in that window: a vent of
            // hot gas after a fill drops the pressure up to 1.4 times the isothermal model's
            // change, which swamps the inlet's share. A loop that finds its inlet stuck
            // closed opens it alone.
            let in_open = u_in > 0.0 && q_in > 0.0 && !(q_out_other < -q_in);
            // The inflow's term is as uncertain as the per-window threshold allows (a
            // polytropic fill raises the pressure up to 1.4 times the isothermal model's
            // change): the exhaust is judged against it at its upper margin. Not the other
            // way round: a vent larger than modelled is what a stuck-open exhaust is, and the
            // inlet's check is what sees it while the loop fills against it.
            let rel = self.params.residual_rel;
            // The muscle's trend at rest counts in the valve's favour only: a leak the inlet
            // makes up for, a warming the exhaust works against. A stuck valve still shows:
            // net of its trend, nothing of the expected change is seen. A trend beyond the
            // threshold's absolute part is no leak but an open path (a stuck-open exhaust
            // vents at megapascals per second), and is not credited.
            let trend = if libm::fabsf(w.trend_pa_s) <= self.params.residual_abs_pa_s {
                w.trend_pa_s
            } else {
                0.0
            };
            // (Comparisons, not f32::min / max: those carry NaN handling the gate made moot.)
            let (leak, warming) = if trend < 0.0 {
                (-trend, 0.0)
            } else {
                (0.0, trend)
            };
            let resting = !(u_in > 0.0 || u_ex > 0.0 || w.inlet.was_open || w.exhaust.was_open);
            // (Out of line, called only when there is something to add.)
            let (in_lost, _) = if in_open || w.inlet.was_open {
                w.inlet.add(
                    in_open,
                    q_in,
                    measured - q_vol - q_out_other + leak,
                    t,
                    &self.params,
                )
            } else {
                (false, false)
            };
            let ex_open = u_ex > 0.0 && q_out < 0.0;
            let q_in_other = if d_in > 0.0 { q_in + d_in } else { q_in };
            // Exhausting and the pressure even rose: air comes in, the inlet is stuck open.
            let (ex_lost, ex_rose) = if ex_open || w.exhaust.was_open {
                w.exhaust.add(
                    ex_open,
                    -q_out,
                    q_vol + q_in_other + rel * libm::fabsf(q_in_other) - measured + warming,
                    t,
                    &self.params,
                )
            } else {
                (false, false)
            };
            if resting && measured.is_finite() {
                w.trend_pa_s += TREND_SMOOTHING * (measured - q_vol - w.trend_pa_s);
            }
            let code = window_fault!(
                self, i, w, q_in, q_out, q_vol, measured, u_in, p_mid, chi, chi_rate, ex_lost,
                in_lost, ex_rose
            );
            if let Some(c) = code {
                active.insert(c);
            }
        }
        self.active = active;
    }

    /// Contraction and contraction rate of muscle `i` (PLANT.md: muscle 1 contracts when
    /// the angle grows).
    #[inline]
    fn contraction(&self, i: usize, angle_rad: f32, angle_rate_rad_s: f32) -> (f32, f32) {
        let c = self.geometry_ratio;
        let d = c * angle_rad;
        let dr = c * angle_rate_rad_s;
        if i == 0 {
            (self.chi0 + d, dr)
        } else {
            (self.chi0 - d, -dr)
        }
    }
}

#[inline]
fn pick(i: usize, a: FaultCode, b: FaultCode) -> FaultCode {
    if i == 0 {
        a
    } else {
        b
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT: f32 = 1e-3;

    /// Runs `ticks` ticks with a fixed inflate duty on muscle 1 (muscle 2 closed), the angle
    /// at 0 and muscle 1's pressure following `p1(k)`; returns the tick of the first fault.
    fn run(duty: f32, ticks: u32, p1: impl Fn(u32) -> f32) -> Option<(u32, FaultSet)> {
        run_with(ValveModelParams::REFERENCE, duty, ticks, p1)
    }

    fn run_with(
        params: ValveModelParams,
        duty: f32,
        ticks: u32,
        p1: impl Fn(u32) -> f32,
    ) -> Option<(u32, FaultSet)> {
        let mut m = ResidualMonitor::new(params, &JointGeometry::REFERENCE);
        for k in 0..ticks {
            let f = m.observe(true, p1(k), 300_000.0, 0.0, DT);
            if !f.is_empty() {
                return Some((k, f));
            }
            m.openings(duty, 0.0, 0.0, 0.0);
        }
        None
    }

    /// At inlet duty `duty` with the pressure not moving (a stuck-closed inlet), the monitor
    /// reports the inlet (or a lost supply) within `max_ticks`.
    fn assert_stuck_inlet_seen_within(duty: f32, max_ticks: u32) {
        let (k, f) = run(duty, 200, |_| 300_000.0).expect("a stuck-closed inlet is seen");
        assert!(k <= max_ticks, "seen after {k} ticks");
        assert!(
            f.contains(FaultCode::InletStuckClosed1) || f.contains(FaultCode::SupplyLost),
            "{f:?}"
        );
    }

    /// The model's expected rate of muscle 1 at 300 kPa, the angle at 0, inlet duty `duty`.
    fn expected_rate(duty: f32) -> f32 {
        let g = JointGeometry::REFERENCE;
        let (q_in, _, _) = ValveModelParams::REFERENCE.rate_terms_pa_s(
            300_000.0,
            g.initial_contraction,
            0.0,
            duty,
            0.0,
        );
        q_in
    }

    #[test]
    fn small_inflate_duty_without_a_rise_is_a_fault_within_50_ms() {
        // 10 % duty: per window the missing rise is below the rate threshold, but it adds up.
        let duty = 0.1;
        assert!(expected_rate(duty) < ValveModelParams::REFERENCE.residual_abs_pa_s);
        assert_stuck_inlet_seen_within(duty, 50);
    }

    #[test]
    fn switched_counts_and_reported_openings_judge_alike() {
        // An on/off inlet at 3 of every 10 ticks against a pressure that does not rise: the
        // integer counts and the 0 / 1 openings give the same faults at the same tick.
        let first_fault = |switched: bool| {
            let mut m =
                ResidualMonitor::new(ValveModelParams::REFERENCE, &JointGeometry::REFERENCE);
            for k in 0..400u32 {
                let f = m.observe(true, 300_000.0, 300_000.0, 0.0, DT);
                if !f.is_empty() {
                    return Some((k, f));
                }
                let open = k % 10 < 3;
                if switched {
                    m.switched(
                        crate::valves::SwitchedValves::new(open, false, false, true).lanes(),
                    );
                } else {
                    m.openings(open as u8 as f32, 0.0, 0.0, 1.0);
                }
            }
            None
        };
        let a = first_fault(false);
        assert!(a.is_some());
        assert_eq!(a, first_fault(true));
    }

    /// Muscle 1's pressure when the inlet opens at tick 0 at full duty and the air arrives
    /// `delay_ticks` later, rising at the model's rate (linearised at 300 kPa).
    fn delayed_rise(delay_ticks: u32) -> impl Fn(u32) -> f32 {
        let rate = expected_rate(1.0);
        move |k| 300_000.0 + rate * k.saturating_sub(delay_ticks) as f32 * DT
    }

    #[test]
    fn a_valve_answering_8_ms_late_is_no_fault() {
        // 60 ticks: the linearised rise stays below the supply.
        assert!(run(1.0, 60, delayed_rise(8)).is_none());
        // ... and the same opening with no rise at all is a fault.
        assert!(run(1.0, 60, |_| 300_000.0).is_some());
    }

    #[test]
    fn a_pulse_answering_late_after_its_window_is_no_fault() {
        // One 1-tick inlet pulse at the end of every other window, the air arriving 8 ticks
        // later, in the window after it, when the inlet is closed again.
        let rate = expected_rate(1.0);
        let pulse_pa = rate * DT;
        let mut m = ResidualMonitor::new(ValveModelParams::REFERENCE, &JointGeometry::REFERENCE);
        let mut p = 300_000.0f32;
        for k in 0..2000u32 {
            // pulse at ticks 9, 29, 49, ... arrives at 17, 37, ...
            if k >= 17 && (k - 17) % 20 == 0 {
                p += pulse_pa;
            }
            let f = m.observe(true, p, 300_000.0, 0.0, DT);
            assert!(f.is_empty(), "tick {k}: {f:?}");
            let duty = if k % 20 == 9 { 1.0 } else { 0.0 };
            m.openings(duty, 0.0, 0.0, 0.0);
        }
    }

    #[test]
    fn exhaust_pulses_on_a_chamber_warming_back_are_no_fault() {
        // Muscle 2 at 300 kPa, a 1-tick exhaust pulse every 17 ticks dropping the pressure
        // by the model's amount, and between the pulses the pressure rising back at
        // 180 kPa/s (the gas warming to the wall temperature after the vent), as a chamber
        // with heat transfer does; the isothermal model expects no rise.
        let g = JointGeometry::REFERENCE;
        let (_, q_out, _) = ValveModelParams::REFERENCE.rate_terms_pa_s(
            300_000.0,
            g.initial_contraction,
            0.0,
            0.0,
            1.0,
        );
        let drop_pa = -q_out * DT;
        let run = |rise_pa_s: f32| {
            let mut m = ResidualMonitor::new(ValveModelParams::REFERENCE, &g);
            let mut p = 300_000.0f32;
            for k in 0..1000u32 {
                let f = m.observe(true, 300_000.0, p, 0.0, DT);
                if !f.is_empty() {
                    return Some((k, f));
                }
                let pulse = k % 17 == 0;
                m.openings(0.0, 0.0, 0.0, if pulse { 1.0 } else { 0.0 });
                p += if pulse { -drop_pa } else { rise_pa_s * DT };
            }
            None
        };
        assert_eq!(run(180_000.0), None);
        // ... while the same pulses with no drop at all are a stuck-closed exhaust.
        let stuck = {
            let mut m = ResidualMonitor::new(ValveModelParams::REFERENCE, &g);
            let mut first = None;
            for k in 0..1000u32 {
                let f = m.observe(true, 300_000.0, 300_000.0, 0.0, DT);
                if !f.is_empty() {
                    first = Some(f);
                    break;
                }
                m.openings(0.0, 0.0, 0.0, if k % 17 == 0 { 1.0 } else { 0.0 });
            }
            first
        };
        assert!(
            stuck.is_some_and(|f| f.contains(FaultCode::ExhaustStuckClosed2)),
            "{stuck:?}"
        );
    }

    #[test]
    fn an_exhaust_pulse_beside_a_polytropic_fill_is_no_fault() {
        // Muscle 1 from 300 kPa, filled in steps: in one window the inlet opens for 3 ticks
        // and the exhaust for 1 (a loop flipping across its deadband), in the next the inlet
        // alone for 3, then a window holds; every opening moves the pressure at 1.4 times the
        // isothermal model's rate (gas with no time to exchange heat). Net of the model's
        // inflow, the fill's polytropic excess is larger than the exhaust's drop: without the
        // margin on the other valve's term it reads as an exhaust that let nothing out, and
        // even as air coming in (a stuck-open inlet).
        let g = JointGeometry::REFERENCE;
        let params = ValveModelParams::REFERENCE;
        let mut m = ResidualMonitor::new(params, &g);
        let mut p = 300_000.0f32;
        for k in 0..150u32 {
            let f = m.observe(true, p, 300_000.0, 0.0, DT);
            assert!(f.is_empty(), "tick {k}, {p} Pa: {f:?}");
            let (u_in, u_ex) = match k % 30 {
                1..=3 | 11..=13 => (1.0, 0.0),
                6 => (0.0, 1.0),
                _ => (0.0, 0.0),
            };
            m.openings(u_in, u_ex, 0.0, 0.0);
            let (q_in, q_out, _) =
                params.rate_terms_pa_s(p, g.initial_contraction, 0.0, u_in, u_ex);
            p += 1.4 * (q_in + q_out) * DT;
        }
    }

    /// Muscle 1 leaking at `leak_pa_s` from 300 kPa, held by a pressure loop that opens the
    /// inlet for one tick whenever the sensor reads below 297 kPa; the inlet lets in
    /// `inflow` times the model's change. The sensor has 500 Pa of uniform noise (a fixed
    /// pseudo-random sequence). Returns the first fault.
    fn leak_held_by_pulses(leak_pa_s: f32, inflow: f32, ticks: u32) -> Option<(u32, FaultSet)> {
        let g = JointGeometry::REFERENCE;
        let params = ValveModelParams::REFERENCE;
        let mut m = ResidualMonitor::new(params, &g);
        let mut p = 300_000.0f32;
        let mut seed = 12_345u32;
        for k in 0..ticks {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let noise = ((seed >> 8) as f32 / (1u32 << 24) as f32 - 0.5) * 1_000.0;
            let sensed = p + noise;
            let f = m.observe(true, sensed, 300_000.0, 0.0, DT);
            if !f.is_empty() {
                return Some((k, f));
            }
            let u_in = if sensed < 297_000.0 { 1.0 } else { 0.0 };
            m.openings(u_in, 0.0, 0.0, 0.0);
            let (q_in, _, _) = params.rate_terms_pa_s(p, g.initial_contraction, 0.0, u_in, 0.0);
            p += (inflow * q_in - leak_pa_s) * DT;
        }
        None
    }

    #[test]
    fn inlet_pulses_making_up_for_a_leak_are_no_fault() {
        // 300 kPa/s (a leak of about 7 % of the valve's conductance): a one-tick pulse every
        // 14 ticks or so, each window with a pulse sees about a third of its rise. Judged
        // without the muscle's trend at rest, that reads as a stuck-closed inlet at 150 ms.
        assert_eq!(leak_held_by_pulses(300_000.0, 1.0, 5_000), None);
        // ... while the same leak with the inlet stuck closed is seen within 30 ms.
        let (k, f) = leak_held_by_pulses(300_000.0, 0.0, 5_000).expect("a stuck inlet is seen");
        assert!(k <= 30, "seen after {k} ticks");
        assert!(
            f.contains(FaultCode::InletStuckClosed1) || f.contains(FaultCode::SupplyLost),
            "{f:?}"
        );
    }

    /// Muscle 1 as a chamber of fixed volume whose gas exchanges heat with its wall (not the
    /// monitor's isothermal model): `p_m` is the pressure the gas would have at the wall
    /// temperature (the mass, moved by the valves at the model's isothermal rates), `theta`
    /// the gas's temperature over the wall's; air comes in at the wall temperature, the
    /// outflow leaves at the gas's, and `tau_s` is the thermal time constant. A pressure
    /// loop (proportional valves, 20 kPa to full opening) follows a set-point stepping
    /// between 150 and 400 kPa every 120 ms; `inlet_works`: the inlet lets air in.
    /// Returns the first fault.
    fn thermal_chamber_loop(tau_s: f32, inlet_works: bool) -> Option<(u32, FaultSet)> {
        const KAPPA: f32 = 1.4;
        let g = JointGeometry::REFERENCE;
        let params = ValveModelParams::REFERENCE;
        let p_atm = params.p_atm_pa;
        let mut m = ResidualMonitor::new(params, &g);
        let (mut p_m, mut theta) = (p_atm + 150_000.0, 1.0f32);
        for k in 0..2_000u32 {
            let p = p_m * theta - p_atm;
            let f = m.observe(true, p, 300_000.0, 0.0, DT);
            if !f.is_empty() {
                return Some((k, f));
            }
            let set = if (k / 120) % 2 == 0 {
                400_000.0
            } else {
                150_000.0
            };
            let u = ((set - p) / 20_000.0).clamp(-1.0, 1.0);
            let (u_in, u_ex) = if u > 0.0 { (u, 0.0) } else { (0.0, -u) };
            m.openings(u_in, u_ex, 0.0, 0.0);
            let (q_in, q_out, _) =
                params.rate_terms_pa_s(p, g.initial_contraction, 0.0, u_in, u_ex);
            let q_in = if inlet_works { q_in } else { 0.0 };
            // Energy of the gas (p V = m R T): air in at the wall temperature, out at the gas's
            // (a choked mass flow goes as 1 / sqrt(T)), heat to the wall.
            let p_abs = p_m * theta;
            let sqrt_theta = libm::sqrtf(theta);
            let dp = KAPPA * (q_in + sqrt_theta * q_out) + p_m * (1.0 - theta) / tau_s;
            let dp_m = q_in + q_out / sqrt_theta;
            p_m += dp_m * DT;
            theta = (p_abs + dp * DT) / p_m;
        }
        None
    }

    #[test]
    fn a_pressure_loop_on_a_chamber_exchanging_heat_is_no_fault() {
        // Thermal time constants of 0.2 s to 2 s (0.24 s: the reference muscle at 300 kPa with
        // hA = 2 W/K). Below about 0.15 s the gas cooling after a fill outruns what is carried,
        // the loop refills against it in every window, and that reads as a stuck inlet. After
        // a fill the gas cools back and the pressure falls faster than the isothermal model
        // says; a loop overshooting then pulses both valves: read as a stuck-closed inlet
        // without the carried surplus of the fill and without leaving a pulse beside a larger
        // vent unjudged.
        for tau_s in [0.2, 0.24, 0.5, 2.0] {
            assert_eq!(thermal_chamber_loop(tau_s, true), None, "tau {tau_s} s");
        }
        // ... while the same loop with its inlet stuck closed is seen within 30 ms.
        let (k, f) = thermal_chamber_loop(0.15, false).expect("a stuck inlet is seen");
        assert!(k <= 30, "seen after {k} ticks");
        assert!(
            f.contains(FaultCode::InletStuckClosed1) || f.contains(FaultCode::SupplyLost),
            "{f:?}"
        );
    }

    #[test]
    fn a_stuck_closed_inlet_is_still_seen_within_30_ms() {
        assert_stuck_inlet_seen_within(1.0, 30);
    }

    #[test]
    fn a_rise_at_half_the_model_rate_is_no_fault() {
        let duty = 0.1;
        let rate = 0.5 * expected_rate(duty);
        assert!(run(duty, 2000, |k| 300_000.0 + rate * k as f32 * DT).is_none());
    }
}
