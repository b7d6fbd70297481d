//! Sensor traits of our own (embedded-hal 1.0 has no ADC, encoder or timer traits), the
//! per-channel validation of measurements, and the joint velocity estimate.
//!
//! - [`PressureSensor`]: raw ADC counts -> gauge pressure [Pa] through a linear
//!   [`PressureScaling`].
//! - [`AngleSensor`]: quadrature-encoder counts -> joint angle [rad] (`counts_per_rev`).
//! - [`Clock`]: a monotonic tick counter.
//! - [`ChannelValidator`]: per-channel checks, run once per control tick: non-finite
//!   values, range, staleness (every measurement is aged every tick) and implausible jumps
//!   (a maximum rate of change).
//! - [`VelocityEstimator`]: first-order low-pass differentiator (documented there).
//!
//! Board code and host-sim fakes implement the traits; the control tick only sees the
//! converted values (`Option<f32>`), so it never touches a register.

use core::f32::consts::PI;

/// Linear ADC scaling: `p_gauge_pa = offset_pa + pa_per_count * counts`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PressureScaling {
    /// Pascal per ADC count.
    pub pa_per_count: f32,
    /// Gauge pressure at 0 counts [Pa] (negative for a 0.5-4.5 V type sensor).
    pub offset_pa: f32,
}

impl PressureScaling {
    /// Scaling of a ratiometric sensor whose `counts_at_zero` read 0 Pa gauge and
    /// `counts_at_full` read `full_scale_pa`. Identical counts give a NaN slope, which the
    /// validation then rejects (no panic).
    pub fn from_two_points(counts_at_zero: u32, counts_at_full: u32, full_scale_pa: f32) -> Self {
        let span = counts_at_full as f32 - counts_at_zero as f32;
        let pa_per_count = if span != 0.0 {
            full_scale_pa / span
        } else {
            f32::NAN
        };
        PressureScaling {
            pa_per_count,
            offset_pa: -pa_per_count * counts_at_zero as f32,
        }
    }

    /// Gauge pressure [Pa] for the raw counts (may be non-finite for a bad scaling; the
    /// validator catches that).
    #[inline]
    pub fn to_gauge_pa(&self, counts: u32) -> f32 {
        self.offset_pa + self.pa_per_count * counts as f32
    }
}

/// A sensor read as raw counts: an ADC's conversion results, an encoder's position.
pub trait CountingSensor {
    /// Bus / peripheral error.
    type Error;
    /// The raw reading.
    type Counts;
    /// The newest raw reading, `Ok(None)` when none is new since the last call.
    fn read_counts(&mut self) -> Result<Option<Self::Counts>, Self::Error>;
}

/// A muscle pressure sensor behind an ADC (counts: the newest conversion result).
pub trait PressureSensor: CountingSensor<Counts = u32> {
    /// The linear scaling of this channel.
    fn scaling(&self) -> PressureScaling;
    /// The newest gauge pressure [Pa], `Ok(None)` when no new sample is ready.
    fn read_gauge_pa(&mut self) -> Result<Option<f32>, Self::Error> {
        let s = self.scaling();
        Ok(self.read_counts()?.map(|c| s.to_gauge_pa(c)))
    }
}

/// A joint angle sensor: a quadrature encoder counter (counts: the signed position, 4x
/// decoded, zero at the reference angle).
pub trait AngleSensor: CountingSensor<Counts = i32> {
    /// Counts per revolution of the joint (e.g. 8000 as in seed 003's testbed).
    fn counts_per_rev(&self) -> u32;
    /// The newest joint angle [rad], `Ok(None)` when no new sample is ready.
    fn read_angle_rad(&mut self) -> Result<Option<f32>, Self::Error> {
        let cpr = self.counts_per_rev();
        Ok(self.read_counts()?.map(|c| counts_to_rad(c, cpr)))
    }
}

/// Encoder counts -> angle [rad]; `counts_per_rev == 0` gives NaN (rejected downstream).
#[inline]
pub fn counts_to_rad(counts: i32, counts_per_rev: u32) -> f32 {
    if counts_per_rev == 0 {
        return f32::NAN;
    }
    // Split to keep f32 precision for large counts: whole turns + remainder.
    let cpr = counts_per_rev as i64;
    let c = counts as i64;
    let turns = c.div_euclid(cpr);
    let rem = c.rem_euclid(cpr);
    2.0 * PI * (turns as f32 + rem as f32 / counts_per_rev as f32)
}

/// A monotonic tick source (e.g. a SysTick / timer counter, or host-sim's step counter).
pub trait Clock {
    /// Ticks since start; never decreases.
    fn now_ticks(&self) -> u64;
    /// Tick frequency [Hz].
    fn tick_hz(&self) -> u32;
}

/// Measures the control period from a [`Clock`]: `dt_s` is the time since the previous
/// call. The first call returns the nominal period `1 / tick_hz`. A clock that went
/// backwards or a zero tick rate gives NaN, which the control tick answers with a
/// watchdog fault (no panic).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TickTimer {
    last_ticks: Option<u64>,
}

impl TickTimer {
    /// A timer that has not been read yet.
    pub const fn new() -> Self {
        TickTimer { last_ticks: None }
    }

    /// Seconds since the previous call.
    pub fn dt_s<C: Clock>(&mut self, clock: &C) -> f32 {
        let now = clock.now_ticks();
        let hz = clock.tick_hz();
        let prev = self.last_ticks.replace(now);
        if hz == 0 {
            return f32::NAN;
        }
        match prev {
            None => 1.0 / hz as f32,
            // Whole seconds and the remainder in 32-bit integers, then f32: no f64 (soft-float
            // on the M4F) and no 64-bit division. A gap beyond 2^32 clock ticks (25 s at
            // 168 MHz) is infinitely late for a control tick.
            Some(p) if now >= p => match u32::try_from(now - p) {
                Ok(d) => (d / hz) as f32 + (d % hz) as f32 / hz as f32,
                Err(_) => f32::INFINITY,
            },
            Some(_) => f32::NAN,
        }
    }
}

/// Limits for one measured channel.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ChannelLimits {
    /// Lowest plausible value (sensor range).
    pub min: f32,
    /// Highest plausible value (sensor range).
    pub max: f32,
    /// Largest physically possible rate of change [unit/s]; a jump larger than
    /// `max_rate_per_s * elapsed + jump_margin` between two samples is implausible.
    pub max_rate_per_s: f32,
    /// Allowance for noise / quantisation added to the jump limit [unit].
    pub jump_margin: f32,
    /// A channel whose newest sample is older than this many ticks is stale.
    pub stale_ticks: u32,
}

/// Why a channel is not usable.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ChannelFault {
    /// NaN or infinite sample.
    NotFinite,
    /// Sample outside `[min, max]`.
    OutOfRange,
    /// No new sample for more than `stale_ticks` ticks.
    Stale,
    /// Jump larger than the rate limit allows.
    Implausible,
}

/// State of a channel after this tick's update.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ChannelStatus {
    /// A valid value (the newest sample, `age_ticks` ticks old; 0 = new this tick).
    Valid {
        /// The value.
        value: f32,
        /// Ticks since it was sampled.
        age_ticks: u32,
    },
    /// No sample yet, still within the start-up allowance (`stale_ticks`).
    Waiting,
    /// The channel is faulty.
    Fault(ChannelFault),
}

impl ChannelStatus {
    /// The value when valid.
    #[inline]
    pub fn value(&self) -> Option<f32> {
        match *self {
            ChannelStatus::Valid { value, .. } => Some(value),
            _ => None,
        }
    }
}

/// Validates one channel, tick by tick. Not latching by itself (the safety layer latches):
/// a good sample after a bad one is valid again, except that the jump check compares with
/// the last *accepted* sample.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ChannelValidator {
    limits: ChannelLimits,
    last: Option<f32>,
    age_ticks: u32,
    /// Time since the last accepted sample [s] (for the jump limit).
    elapsed_s: f32,
}

impl ChannelValidator {
    /// A validator with no sample yet. An infinite bound is replaced by the largest finite
    /// f32 (the one range test then also rejects infinite samples).
    pub const fn new(limits: ChannelLimits) -> Self {
        let mut limits = limits;
        if limits.min == f32::NEG_INFINITY {
            limits.min = -f32::MAX;
        }
        if limits.max == f32::INFINITY {
            limits.max = f32::MAX;
        }
        ChannelValidator {
            limits,
            last: None,
            age_ticks: 0,
            elapsed_s: 0.0,
        }
    }

    /// The limits.
    pub fn limits(&self) -> &ChannelLimits {
        &self.limits
    }

    /// The last accepted sample (what a held `Valid` status reports), `None` before the first.
    #[inline(always)]
    pub fn last(&self) -> Option<f32> {
        self.last
    }

    /// Ticks since the last accepted sample (or since start).
    pub fn age_ticks(&self) -> u32 {
        self.age_ticks
    }

    /// Forgets the history (the next sample is not jump-checked).
    pub fn clear(&mut self) {
        // `new` keeps limits it already made finite as they are.
        *self = Self::new(self.limits);
    }

    /// One tick: ages the stored sample by one tick of `dt_s` seconds, then checks `sample`
    /// (`None` = no new sample this tick). Never panics.
    pub fn update(&mut self, sample: Option<f32>, dt_s: f32) -> ChannelStatus {
        self.update_with(sample, dt_s, dt_s.is_finite() && dt_s > 0.0)
    }

    /// [`Self::update`] with `dt_good = dt_s.is_finite() && dt_s > 0.0` known to the caller
    /// (the control tick decides it once for its three channels and the velocity).
    #[inline(always)]
    pub(crate) fn update_with(
        &mut self,
        sample: Option<f32>,
        dt_s: f32,
        dt_good: bool,
    ) -> ChannelStatus {
        // The aged counters, stored only where the sample is not accepted (an accepted
        // sample resets them).
        let age_ticks = self.age_ticks.saturating_add(1);
        let elapsed_s = if dt_good {
            self.elapsed_s + dt_s
        } else {
            self.elapsed_s
        };
        let l = &self.limits;
        if let Some(x) = sample {
            // One range test on the hot path (NaN fails it too); the cause only on a fault.
            let fault = if !(x >= l.min && x <= l.max) {
                Some(if x.is_finite() {
                    ChannelFault::OutOfRange
                } else {
                    ChannelFault::NotFinite
                })
            } else {
                match self.last {
                    // `!(a <= b)` also rejects a NaN limit.
                    Some(prev)
                        if !(libm::fabsf(x - prev)
                            <= l.max_rate_per_s * elapsed_s + l.jump_margin) =>
                    {
                        Some(ChannelFault::Implausible)
                    }
                    _ => None,
                }
            };
            if let Some(f) = fault {
                self.age_ticks = age_ticks;
                self.elapsed_s = elapsed_s;
                return ChannelStatus::Fault(f);
            }
            self.last = Some(x);
            self.age_ticks = 0;
            self.elapsed_s = 0.0;
            return ChannelStatus::Valid {
                value: x,
                age_ticks: 0,
            };
        }
        self.age_ticks = age_ticks;
        self.elapsed_s = elapsed_s;
        if self.age_ticks > l.stale_ticks {
            return ChannelStatus::Fault(ChannelFault::Stale);
        }
        match self.last {
            Some(value) => ChannelStatus::Valid {
                value,
                age_ticks: self.age_ticks,
            },
            None => ChannelStatus::Waiting,
        }
    }
}

/// Turns a sensor read that always returns a value (a DMA buffer, an encoder register)
/// into "a new sample or none", by the sample's sequence number: the DMA transfer count, an
/// end-of-conversion counter or a capture timestamp. A sequence number equal to the last one
/// means the sensor did not deliver: `None`, so the tick's stale check fires on the board
/// when the sensor or its DMA freezes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SequenceGate {
    last: Option<u32>,
}

impl SequenceGate {
    /// A gate that has seen no sample.
    pub const fn new() -> Self {
        SequenceGate { last: None }
    }

    /// `Some(value)` when `seq` differs from the previous call's, else `None`.
    #[inline]
    pub fn gate(&mut self, seq: u32, value: f32) -> Option<f32> {
        if self.last == Some(seq) {
            None
        } else {
            self.last = Some(seq);
            Some(value)
        }
    }
}

/// Joint velocity from the angle: a first-order low-pass differentiator.
///
/// ```text
/// v_raw = (theta_k - theta_last) / (t_k - t_last)       (on each new angle sample)
/// v_k   = v_{k-1} + a (v_raw - v_{k-1}),   a = dt / (tau + dt),   tau = 1 / (2 pi f_c)
/// ```
///
/// i.e. the discretised `G(s) = s / (tau s + 1)`: a differentiator below the cutoff `f_c`,
/// flat gain `1/tau` above it, which bounds the amplification of encoder quantisation
/// (one count of 8000 per rev at 1 kHz is 0.79 rad/s raw; with f_c = 40 Hz the filtered
/// step is 0.16 rad/s). The group delay at low frequency is `tau` (4 ms at 40 Hz).
/// Ticks without a new angle sample keep the estimate and accumulate the elapsed time, so
/// the next difference is divided by the true sample spacing.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct VelocityEstimator {
    tau_s: f32,
    last_angle_rad: Option<f32>,
    since_last_s: f32,
    velocity_rad_s: f32,
}

impl VelocityEstimator {
    /// Estimator with cutoff `cutoff_hz` (non-finite or <= 0 gives an unfiltered
    /// difference quotient).
    pub fn new(cutoff_hz: f32) -> Self {
        let tau_s = if cutoff_hz.is_finite() && cutoff_hz > 0.0 {
            1.0 / (2.0 * PI * cutoff_hz)
        } else {
            0.0
        };
        Self::with_tau(tau_s)
    }

    /// Estimator with time constant `tau_s` and no history.
    const fn with_tau(tau_s: f32) -> Self {
        VelocityEstimator {
            tau_s,
            last_angle_rad: None,
            since_last_s: 0.0,
            velocity_rad_s: 0.0,
        }
    }

    /// Time constant tau [s].
    pub fn tau_s(&self) -> f32 {
        self.tau_s
    }

    /// Current estimate [rad/s].
    pub fn velocity_rad_s(&self) -> f32 {
        self.velocity_rad_s
    }

    /// Forgets the history (estimate 0, next sample starts over).
    pub fn reset(&mut self) {
        *self = Self::with_tau(self.tau_s);
    }

    /// One tick of `dt_s`; `angle_rad` is a new *validated* sample or `None`.
    /// Non-finite inputs are ignored (the estimate holds). Returns the estimate.
    pub fn update(&mut self, angle_rad: Option<f32>, dt_s: f32) -> f32 {
        self.update_with(
            angle_rad.filter(|a| a.is_finite()),
            dt_s,
            dt_s.is_finite() && dt_s > 0.0,
        )
    }

    /// [`Self::update`] with `dt_good = dt_s.is_finite() && dt_s > 0.0` known to the caller
    /// and `angle_rad` finite when `Some` (the control tick passes validated samples).
    #[inline(always)]
    pub(crate) fn update_with(&mut self, angle_rad: Option<f32>, dt_s: f32, dt_good: bool) -> f32 {
        if !dt_good {
            return self.velocity_rad_s;
        }
        let since_last_s = self.since_last_s + dt_s;
        let Some(theta) = angle_rad else {
            self.since_last_s = since_last_s;
            return self.velocity_rad_s;
        };
        if let Some(prev) = self.last_angle_rad {
            let h = since_last_s;
            let v_raw = (theta - prev) / h;
            let a = h / (self.tau_s + h);
            let v = self.velocity_rad_s + a * (v_raw - self.velocity_rad_s);
            if v.is_finite() {
                self.velocity_rad_s = v;
            }
        }
        self.last_angle_rad = Some(theta);
        self.since_last_s = 0.0;
        self.velocity_rad_s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits() -> ChannelLimits {
        ChannelLimits {
            min: -50_000.0,
            max: 1_000_000.0,
            max_rate_per_s: 10_000_000.0,
            jump_margin: 10_000.0,
            stale_ticks: 5,
        }
    }

    #[test]
    fn scaling_maps_two_points_linearly() {
        let s = PressureScaling::from_two_points(400, 3600, 1_000_000.0);
        assert!((s.to_gauge_pa(400)).abs() < 1e-3);
        assert!((s.to_gauge_pa(3600) - 1_000_000.0).abs() < 1.0);
        assert!((s.to_gauge_pa(2000) - 500_000.0).abs() < 1.0);
    }

    #[test]
    fn degenerate_scaling_gives_nan_which_validation_rejects() {
        let s = PressureScaling::from_two_points(100, 100, 1e6);
        let mut v = ChannelValidator::new(limits());
        assert_eq!(
            v.update(Some(s.to_gauge_pa(100)), 1e-3),
            ChannelStatus::Fault(ChannelFault::NotFinite)
        );
    }

    #[test]
    fn encoder_counts_convert_to_radians() {
        assert!((counts_to_rad(2000, 8000) - PI / 2.0).abs() < 1e-6);
        assert!((counts_to_rad(-2000, 8000) + PI / 2.0).abs() < 1e-6);
        assert!((counts_to_rad(8000 * 3 + 4000, 8000) - 7.0 * PI).abs() < 1e-4);
        assert!(counts_to_rad(5, 0).is_nan());
        assert!(counts_to_rad(i32::MIN, 8000).is_finite());
    }

    struct FakeEncoder(i32);
    impl CountingSensor for FakeEncoder {
        type Error = ();
        type Counts = i32;
        fn read_counts(&mut self) -> Result<Option<i32>, ()> {
            Ok(Some(self.0))
        }
    }
    impl AngleSensor for FakeEncoder {
        fn counts_per_rev(&self) -> u32 {
            8000
        }
    }
    struct FakeAdc(Option<u32>);
    impl CountingSensor for FakeAdc {
        type Error = ();
        type Counts = u32;
        fn read_counts(&mut self) -> Result<Option<u32>, ()> {
            Ok(self.0.take())
        }
    }
    impl PressureSensor for FakeAdc {
        fn scaling(&self) -> PressureScaling {
            PressureScaling {
                pa_per_count: 250.0,
                offset_pa: -100_000.0,
            }
        }
    }

    #[test]
    fn trait_default_methods_convert_units() {
        let mut e = FakeEncoder(4000);
        assert!((e.read_angle_rad().unwrap().unwrap() - PI).abs() < 1e-6);
        let mut a = FakeAdc(Some(2000));
        assert_eq!(a.read_gauge_pa().unwrap(), Some(400_000.0));
        assert_eq!(a.read_gauge_pa().unwrap(), None);
    }

    struct FakeClock(core::cell::Cell<u64>, u32);
    impl Clock for FakeClock {
        fn now_ticks(&self) -> u64 {
            self.0.get()
        }
        fn tick_hz(&self) -> u32 {
            self.1
        }
    }

    #[test]
    fn tick_timer_measures_elapsed_time_and_flags_backwards_clock() {
        let c = FakeClock(core::cell::Cell::new(1_000), 1_000_000);
        let mut t = TickTimer::new();
        assert_eq!(t.dt_s(&c), 1e-6);
        c.0.set(2_000);
        assert!((t.dt_s(&c) - 1e-3).abs() < 1e-9);
        c.0.set(1_500);
        assert!(t.dt_s(&c).is_nan());
        let z = FakeClock(core::cell::Cell::new(0), 0);
        assert!(TickTimer::new().dt_s(&z).is_nan());
        // 168 MHz cycle counter: 1 ms and 2.5 s exactly as f64 would give them (to f32),
        // a gap beyond 2^32 cycles is infinitely late.
        let c = FakeClock(core::cell::Cell::new(10), 168_000_000);
        let mut t = TickTimer::new();
        t.dt_s(&c);
        for d in [168_000u64, 420_000_000, 1, 167_999_999] {
            let now = c.0.get() + d;
            c.0.set(now);
            let want = (d as f64 / 168e6) as f32;
            let got = t.dt_s(&c);
            assert!(
                (got - want).abs() <= 2.0 * f32::EPSILON * want,
                "{d}: {got} vs {want}"
            );
        }
        c.0.set(c.0.get() + (1u64 << 32));
        assert_eq!(t.dt_s(&c), f32::INFINITY);
    }

    #[test]
    fn validator_accepts_good_samples() {
        let mut v = ChannelValidator::new(limits());
        assert_eq!(
            v.update(Some(300_000.0), 1e-3),
            ChannelStatus::Valid {
                value: 300_000.0,
                age_ticks: 0
            }
        );
        assert_eq!(v.update(Some(305_000.0), 1e-3).value(), Some(305_000.0));
    }

    #[test]
    fn validator_rejects_nan_and_inf() {
        let mut v = ChannelValidator::new(limits());
        for x in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            assert_eq!(
                v.update(Some(x), 1e-3),
                ChannelStatus::Fault(ChannelFault::NotFinite)
            );
        }
    }

    #[test]
    fn validator_rejects_out_of_range() {
        let mut v = ChannelValidator::new(limits());
        assert_eq!(
            v.update(Some(-60_000.0), 1e-3),
            ChannelStatus::Fault(ChannelFault::OutOfRange)
        );
        assert_eq!(
            v.update(Some(2e6), 1e-3),
            ChannelStatus::Fault(ChannelFault::OutOfRange)
        );
    }

    #[test]
    fn validator_ages_measurements_every_tick_and_flags_stale() {
        let mut v = ChannelValidator::new(limits());
        assert!(v.update(Some(1.0), 1e-3).value().is_some());
        for k in 1..=5 {
            assert_eq!(
                v.update(None, 1e-3),
                ChannelStatus::Valid {
                    value: 1.0,
                    age_ticks: k
                }
            );
        }
        assert_eq!(
            v.update(None, 1e-3),
            ChannelStatus::Fault(ChannelFault::Stale)
        );
        // A fresh sample makes it valid again (latching is the safety layer's job).
        assert_eq!(v.update(Some(2.0), 1e-3).value(), Some(2.0));
    }

    #[test]
    fn validator_waits_for_first_sample_then_times_out() {
        let mut v = ChannelValidator::new(limits());
        for _ in 0..5 {
            assert_eq!(v.update(None, 1e-3), ChannelStatus::Waiting);
        }
        assert_eq!(
            v.update(None, 1e-3),
            ChannelStatus::Fault(ChannelFault::Stale)
        );
    }

    #[test]
    fn validator_flags_implausible_jump_but_allows_rate_over_elapsed_time() {
        let mut v = ChannelValidator::new(limits());
        v.update(Some(100_000.0), 1e-3);
        // 1 ms: allowed 10 kPa + 10 kPa margin.
        assert_eq!(
            v.update(Some(130_000.0), 1e-3),
            ChannelStatus::Fault(ChannelFault::Implausible)
        );
        // The rejected sample is not accepted; after 3 more ms (4 ms since the last
        // accepted sample) 130 kPa is within 40 + 10 kPa.
        v.update(None, 1e-3);
        v.update(None, 1e-3);
        assert_eq!(v.update(Some(130_000.0), 1e-3).value(), Some(130_000.0));
    }

    #[test]
    fn velocity_estimator_tracks_a_ramp() {
        let mut ve = VelocityEstimator::new(40.0);
        let dt = 1e-3;
        let mut v = 0.0;
        for k in 0..200 {
            v = ve.update(Some(2.0 * k as f32 * dt), dt);
        }
        assert!((v - 2.0).abs() < 1e-3, "{v}");
    }

    #[test]
    fn velocity_estimator_uses_true_spacing_when_samples_are_missing() {
        let mut ve = VelocityEstimator::new(1e6); // practically unfiltered
        let dt = 1e-3;
        ve.update(Some(0.0), dt);
        ve.update(None, dt);
        let v = ve.update(Some(0.002), dt); // 2 ms later
        assert!((v - 1.0).abs() < 1e-3, "{v}");
    }

    #[test]
    fn velocity_estimator_filters_quantisation_step() {
        let mut ve = VelocityEstimator::new(40.0);
        let dt = 1e-3;
        ve.update(Some(0.0), dt);
        let count = 2.0 * PI / 8000.0;
        let v = ve.update(Some(count), dt);
        let raw = count / dt;
        let a = dt / (1.0 / (2.0 * PI * 40.0) + dt);
        assert!((v - a * raw).abs() < 1e-5);
        assert!(v < 0.25 * raw);
    }

    #[test]
    fn velocity_estimator_ignores_nan_and_bad_dt() {
        let mut ve = VelocityEstimator::new(40.0);
        ve.update(Some(0.0), 1e-3);
        assert_eq!(ve.update(Some(f32::NAN), 1e-3), 0.0);
        assert_eq!(ve.update(Some(1.0), f32::NAN), 0.0);
        assert_eq!(ve.update(Some(1.0), -1.0), 0.0);
        assert!(ve.update(Some(1e-3), 1e-3).is_finite());
    }

    #[test]
    fn sequence_gate_drops_repeated_samples() {
        let mut g = SequenceGate::new();
        assert_eq!(g.gate(7, 1.0), Some(1.0));
        assert_eq!(g.gate(7, 1.0), None);
        assert_eq!(g.gate(8, 2.0), Some(2.0));
        // A frozen DMA: the stale check of the channel fires after `stale_ticks`.
        let mut v = ChannelValidator::new(ChannelLimits {
            min: -1.0,
            max: 1.0,
            max_rate_per_s: 10.0,
            jump_margin: 0.1,
            stale_ticks: 3,
        });
        assert!(v.update(g.gate(9, 0.5), 1e-3).value().is_some());
        let mut last = ChannelStatus::Waiting;
        for _ in 0..4 {
            last = v.update(g.gate(9, 0.5), 1e-3);
        }
        assert_eq!(last, ChannelStatus::Fault(ChannelFault::Stale));
    }
}
