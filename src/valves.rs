//! Valve drivers over embedded-hal 1.0.
//!
//! - [`OnOffValves`]: two 2/2 on/off valves per muscle (inflate from supply, exhaust to
//!   atmosphere) = the 3/3 function of seed 000, driven by [`OutputPin`]s with tick-level
//!   PWM ([`OnOffPwmConfig`]).
//! - [`ProportionalValves`]: four PWM channels ([`SetDutyCycle`]), duty = |command|.
//!
//! Both never open the inflate and the exhaust valve of one muscle at once: pins that close
//! are always written before pins that open, so even within one call there is no instant
//! with both open. A non-finite command counts as 0 (closed).
//!
//! [`ValveOpenings`] reports what the valves are doing this tick: exactly the plant inputs
//! `u_in1, u_ex1, u_in2, u_ex2` of PLANT.md / RECORDING.md.

use embedded_hal::digital::OutputPin;
use embedded_hal::pwm::SetDutyCycle;

/// Per-muscle valve command in [-1, 1]: > 0 inflate duty (inflate valve open that fraction
/// of the time), < 0 exhaust duty, 0 both closed. Never inflate and exhaust one muscle at
/// once. Produced by the control tick ([`crate::tick`]), applied by the drivers below.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ValveCommand {
    /// Muscle 1 command.
    pub muscle1: f32,
    /// Muscle 2 command.
    pub muscle2: f32,
}

/// Valve openings in [0, 1] this tick (0 closed, 1 open; a PWM duty counts as the opening).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ValveOpenings {
    /// Muscle 1 inflate valve.
    pub u_in1: f32,
    /// Muscle 1 exhaust valve.
    pub u_ex1: f32,
    /// Muscle 2 inflate valve.
    pub u_in2: f32,
    /// Muscle 2 exhaust valve.
    pub u_ex2: f32,
}

impl ValveOpenings {
    /// The openings a command would produce on ideal proportional valves (duty = opening).
    /// Useful for simulation without a driver.
    pub fn from_command(cmd: &ValveCommand) -> Self {
        let (u_in1, u_ex1) = split(sanitize(cmd.muscle1));
        let (u_in2, u_ex2) = split(sanitize(cmd.muscle2));
        ValveOpenings {
            u_in1,
            u_ex1,
            u_in2,
            u_ex2,
        }
    }
}

/// The on/off valves switched open in one tick: one 16-bit lane per valve (inflate 1,
/// exhaust 1, inflate 2, exhaust 2 from the low end), each 0 or 1, so that the valve
/// supervision counts a window's open ticks with one 64-bit add per tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SwitchedValves(u64);

impl SwitchedValves {
    /// From the four valve states.
    #[inline(always)]
    pub fn new(in1: bool, ex1: bool, in2: bool, ex2: bool) -> Self {
        SwitchedValves(in1 as u64 | (ex1 as u64) << 16 | (in2 as u64) << 32 | (ex2 as u64) << 48)
    }

    /// The lanes (see the type).
    #[inline(always)]
    pub fn lanes(self) -> u64 {
        self.0
    }

    /// As openings (1 open, 0 closed).
    pub fn openings(self) -> ValveOpenings {
        let on = |k: u32| ((self.0 >> (16 * k)) & 1) as u8 as f32;
        ValveOpenings {
            u_in1: on(0),
            u_ex1: on(1),
            u_in2: on(2),
            u_ex2: on(3),
        }
    }
}

/// A pin / channel error, naming which valve failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error<EI1, EE1, EI2, EE2> {
    /// Muscle 1 inflate valve.
    Inflate1(EI1),
    /// Muscle 1 exhaust valve.
    Exhaust1(EE1),
    /// Muscle 2 inflate valve.
    Inflate2(EI2),
    /// Muscle 2 exhaust valve.
    Exhaust2(EE2),
}

/// The error of [`OnOffValves`] with the pins `I1`, `E1`, `I2`, `E2`.
pub type PinsError<I1, E1, I2, E2> = Error<
    <I1 as embedded_hal::digital::ErrorType>::Error,
    <E1 as embedded_hal::digital::ErrorType>::Error,
    <I2 as embedded_hal::digital::ErrorType>::Error,
    <E2 as embedded_hal::digital::ErrorType>::Error,
>;

/// The error of [`ProportionalValves`] with the channels `I1`, `E1`, `I2`, `E2`.
pub type ChannelsError<I1, E1, I2, E2> = Error<
    <I1 as embedded_hal::pwm::ErrorType>::Error,
    <E1 as embedded_hal::pwm::ErrorType>::Error,
    <I2 as embedded_hal::pwm::ErrorType>::Error,
    <E2 as embedded_hal::pwm::ErrorType>::Error,
>;

/// NaN -> 0, clamp to [-1, 1].
#[inline]
fn sanitize(x: f32) -> f32 {
    // The usual command is already in [-1, 1] (one test; false for NaN and +-inf).
    if libm::fabsf(x) <= 1.0 {
        x
    } else if !x.is_finite() {
        // +-inf are commands too, but only NaN is meaningless; treat all non-finite as
        // closed (the safety layer never produces them).
        0.0
    } else {
        x.clamp(-1.0, 1.0)
    }
}

/// Command -> (inflate duty, exhaust duty), at most one non-zero.
#[inline]
fn split(x: f32) -> (f32, f32) {
    if x > 0.0 {
        (x, 0.0)
    } else if x < 0.0 {
        (0.0, -x)
    } else {
        (0.0, 0.0)
    }
}

/// Tick-level PWM of the on/off valves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct OnOffPwmConfig {
    /// PWM period in control ticks (>= 1; 10 at 1 kHz = 100 Hz PWM).
    pub period_ticks: u16,
    /// Minimum on-time of a valve pulse in ticks (clamped to `1..=period_ticks`).
    pub min_on_ticks: u16,
}

impl OnOffPwmConfig {
    /// 10 ticks period, 2 ticks minimum on-time (2 ms at 1 kHz: a fast switching valve).
    pub const REFERENCE: OnOffPwmConfig = OnOffPwmConfig {
        period_ticks: 10,
        min_on_ticks: 2,
    };

    fn normalized(self) -> (u16, u16) {
        let n = if self.period_ticks == 0 {
            1
        } else {
            self.period_ticks
        };
        let m = self.min_on_ticks.clamp(1, n);
        (n, m)
    }
}

/// Direction of one muscle's current pulse train.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
enum Dir {
    Closed,
    Inflate,
    Exhaust,
}

/// Tick-level PWM state of one muscle.
///
/// - The duty is latched at the start of each period: `on = round(|u| N + carry)`, with the
///   rounding remainder carried to the next period (so the mean duty is exact even with
///   the coarse resolution 1/N), and an on-time in `(0, min_on)` rounded to 0 or `min_on`.
/// - The valve is open for the first `on` ticks of the period.
/// - A change of direction (inflate <-> exhaust <-> closed) restarts the period at once, so
///   a command of 0 closes both valves in the same tick, and a safe "vent" (-1) opens the
///   exhaust valve in the same tick. Only then can a pulse be shorter than `min_on`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct PwmChannel {
    dir: Dir,
    phase: u16,
    on_ticks: u16,
    run: u16,
    carry: f32,
}

impl PwmChannel {
    const fn new() -> Self {
        PwmChannel {
            dir: Dir::Closed,
            phase: 0,
            on_ticks: 0,
            run: 0,
            carry: 0.0,
        }
    }

    /// Advances one tick with command `u` (sanitized); returns (inflate open, exhaust open).
    #[inline(always)]
    fn tick(&mut self, u: f32, n: u16, min_on: u16) -> (bool, bool) {
        let dir = if u > 0.0 {
            Dir::Inflate
        } else if u < 0.0 {
            Dir::Exhaust
        } else {
            Dir::Closed
        };
        if dir != self.dir {
            self.dir = dir;
            self.phase = 0;
            self.run = 0;
            self.carry = 0.0;
        }
        if self.dir == Dir::Closed {
            self.phase = 0;
            self.on_ticks = 0;
            return (false, false);
        }
        if self.phase == 0 {
            let nf = n as f32;
            let x = libm::fabsf(u) * nf + self.carry;
            let mut on = libm::floorf(x + 0.5);
            if on < 0.0 {
                on = 0.0;
            } else if on > nf {
                on = nf;
            }
            let mf = min_on as f32;
            if on > 0.0 && on < mf {
                on = if x >= 0.5 * mf { mf } else { 0.0 };
            }
            // Carry bounded to one period so a long saturation cannot store a burst.
            self.carry = (x - on).clamp(-nf, nf);
            self.on_ticks = on as u16;
        } else if u >= 1.0 || u <= -1.0 {
            // A full-scale command (the vent safe state among others) opens the valve at
            // once, not at the start of the next switching period.
            self.on_ticks = n;
        }
        let open = self.phase < self.on_ticks || (self.run > 0 && self.run < min_on);
        self.run = if open { self.run.saturating_add(1) } else { 0 };
        self.phase = if self.phase + 1 >= n {
            0
        } else {
            self.phase + 1
        };
        match self.dir {
            Dir::Inflate => (open, false),
            Dir::Exhaust => (false, open),
            Dir::Closed => (false, false),
        }
    }
}

/// The methods both drivers share over their four outputs `inflate1`, `exhaust1`,
/// `inflate2`, `exhaust2`: `release`; `close_outputs`, every output closed through its method
/// `$close` (all tried, the first error returned); `write`, the four output levels through
/// `$pass` (one output, one pass: the closing pass first, then the opening one, so that
/// the inflate and exhaust valve of a muscle are never open at once); `closed_on_error`, a
/// write's error after every valve was driven closed (best effort).
macro_rules! four_outputs {
    ($what:literal, $close:ident, $pass:ident, $level:ty, $err:ident) => {
        #[doc = concat!("Gives the ", $what, " back.")]
        pub fn release(self) -> (I1, E1, I2, E2) {
            (self.inflate1, self.exhaust1, self.inflate2, self.exhaust2)
        }

        fn close_outputs(&mut self) -> Result<(), $err<I1, E1, I2, E2>> {
            let r1 = self.inflate1.$close().map_err(Error::Inflate1);
            let r2 = self.exhaust1.$close().map_err(Error::Exhaust1);
            let r3 = self.inflate2.$close().map_err(Error::Inflate2);
            let r4 = self.exhaust2.$close().map_err(Error::Exhaust2);
            r1.and(r2).and(r3).and(r4)
        }

        fn write(&mut self, [l1, l2, l3, l4]: [$level; 4]) -> Result<(), $err<I1, E1, I2, E2>> {
            for opening in [false, true] {
                $pass(&mut self.inflate1, l1, opening).map_err(Error::Inflate1)?;
                $pass(&mut self.exhaust1, l2, opening).map_err(Error::Exhaust1)?;
                $pass(&mut self.inflate2, l3, opening).map_err(Error::Inflate2)?;
                $pass(&mut self.exhaust2, l4, opening).map_err(Error::Exhaust2)?;
            }
            Ok(())
        }

        fn closed_on_error<T>(
            &mut self,
            written: Result<(), $err<I1, E1, I2, E2>>,
            ok: T,
        ) -> Result<T, $err<I1, E1, I2, E2>> {
            if let Err(e) = written {
                let _ = self.close_all();
                return Err(e);
            }
            Ok(ok)
        }
    };
}

/// One pass of [`OnOffValves`]' write on one pin: set to `open` in the pass of that level.
#[inline(always)]
fn pass_pin<P: OutputPin>(pin: &mut P, open: bool, opening: bool) -> Result<(), P::Error> {
    if open != opening {
        return Ok(());
    }
    pin.set_state(open.into())
}

/// One pass of [`ProportionalValves`]' write on one channel: zero duties in the closing
/// pass, the others in the opening pass.
#[inline(always)]
fn pass_duty<P: SetDutyCycle>(pwm: &mut P, duty: u16, opening: bool) -> Result<(), P::Error> {
    if (duty != 0) == opening {
        pwm.set_duty_cycle(duty)
    } else {
        Ok(())
    }
}

/// Two on/off 2/2 valves per muscle (3/3 function), driven by GPIO with tick-level PWM.
/// `I1`/`E1`: inflate/exhaust pin of muscle 1, `I2`/`E2`: of muscle 2; high = open.
pub struct OnOffValves<I1, E1, I2, E2> {
    inflate1: I1,
    exhaust1: E1,
    inflate2: I2,
    exhaust2: E2,
    n: u16,
    min_on: u16,
    ch1: PwmChannel,
    ch2: PwmChannel,
}

impl<I1, E1, I2, E2> OnOffValves<I1, E1, I2, E2>
where
    I1: OutputPin,
    E1: OutputPin,
    I2: OutputPin,
    E2: OutputPin,
{
    /// Takes the pins; they are not touched until [`Self::close_all`] or [`Self::apply`].
    pub fn new(
        inflate1: I1,
        exhaust1: E1,
        inflate2: I2,
        exhaust2: E2,
        cfg: OnOffPwmConfig,
    ) -> Self {
        let (n, min_on) = cfg.normalized();
        OnOffValves {
            inflate1,
            exhaust1,
            inflate2,
            exhaust2,
            n,
            min_on,
            ch1: PwmChannel::new(),
            ch2: PwmChannel::new(),
        }
    }

    four_outputs!("pins", set_low, pass_pin, bool, PinsError);

    /// Closes all four valves and resets the PWM state. Tries every pin even if one fails;
    /// returns the first error.
    pub fn close_all(&mut self) -> Result<(), PinsError<I1, E1, I2, E2>> {
        self.ch1 = PwmChannel::new();
        self.ch2 = PwmChannel::new();
        self.close_outputs()
    }

    /// One tick: advances the PWM and writes the pins (closing pins first, then opening
    /// pins). On a pin error every valve is driven closed (best effort) and the error is
    /// returned.
    pub fn apply(
        &mut self,
        cmd: &ValveCommand,
    ) -> Result<ValveOpenings, PinsError<I1, E1, I2, E2>> {
        self.apply_switched(cmd).map(SwitchedValves::openings)
    }

    /// [`Self::apply`], returning which valves it switched open (what the control
    /// tick's valve supervision counts: [`crate::tick::ControlTick::valves_switched`]).
    #[inline(never)]
    pub fn apply_switched(
        &mut self,
        cmd: &ValveCommand,
    ) -> Result<SwitchedValves, PinsError<I1, E1, I2, E2>> {
        let (in1, ex1) = self.ch1.tick(sanitize(cmd.muscle1), self.n, self.min_on);
        let (in2, ex2) = self.ch2.tick(sanitize(cmd.muscle2), self.n, self.min_on);
        debug_assert!(!(in1 && ex1 || in2 && ex2));
        let written = self.write([in1, ex1, in2, ex2]);
        self.closed_on_error(written, SwitchedValves::new(in1, ex1, in2, ex2))
    }
}

/// Four proportional (PWM-driven) valves: inflate/exhaust per muscle, duty = |command|.
pub struct ProportionalValves<I1, E1, I2, E2> {
    inflate1: I1,
    exhaust1: E1,
    inflate2: I2,
    exhaust2: E2,
}

/// Duty cycle for the fraction `u` in [0, 1] of `max`.
#[inline]
fn duty_of(u: f32, max: u16) -> u16 {
    let d = libm::floorf(u * max as f32 + 0.5);
    if !(d > 0.0) {
        0
    } else if d >= max as f32 {
        max
    } else {
        d as u16
    }
}

impl<I1, E1, I2, E2> ProportionalValves<I1, E1, I2, E2>
where
    I1: SetDutyCycle,
    E1: SetDutyCycle,
    I2: SetDutyCycle,
    E2: SetDutyCycle,
{
    /// Takes the channels.
    pub fn new(inflate1: I1, exhaust1: E1, inflate2: I2, exhaust2: E2) -> Self {
        ProportionalValves {
            inflate1,
            exhaust1,
            inflate2,
            exhaust2,
        }
    }

    four_outputs!(
        "channels",
        set_duty_cycle_fully_off,
        pass_duty,
        u16,
        ChannelsError
    );

    /// Sets all four duties to 0 (tries all, returns the first error).
    pub fn close_all(&mut self) -> Result<(), ChannelsError<I1, E1, I2, E2>> {
        self.close_outputs()
    }

    /// Applies the command: the channel of the unused direction is set to 0 first, then
    /// the used one to `|command|` of its maximum duty. On error all are driven to 0 (best
    /// effort) and the error is returned.
    pub fn apply(
        &mut self,
        cmd: &ValveCommand,
    ) -> Result<ValveOpenings, ChannelsError<I1, E1, I2, E2>> {
        let (in1, ex1) = split(sanitize(cmd.muscle1));
        let (in2, ex2) = split(sanitize(cmd.muscle2));
        // One max_duty_cycle() read per channel per tick.
        let m = [
            self.inflate1.max_duty_cycle(),
            self.exhaust1.max_duty_cycle(),
            self.inflate2.max_duty_cycle(),
            self.exhaust2.max_duty_cycle(),
        ];
        let d = [
            duty_of(in1, m[0]),
            duty_of(ex1, m[1]),
            duty_of(in2, m[2]),
            duty_of(ex2, m[3]),
        ];
        let written = self.write(d);
        let openings = ValveOpenings {
            u_in1: frac(d[0], m[0]),
            u_ex1: frac(d[1], m[1]),
            u_in2: frac(d[2], m[2]),
            u_ex2: frac(d[3], m[3]),
        };
        self.closed_on_error(written, openings)
    }
}

#[inline]
fn frac(d: u16, max: u16) -> f32 {
    if max == 0 {
        0.0
    } else {
        d as f32 / max as f32
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use embedded_hal_mock::eh1::digital::{Mock as PinMock, State, Transaction as PinTx};
    use embedded_hal_mock::eh1::pwm::{Mock as PwmMock, Transaction as PwmTx};
    use std::vec::Vec;

    fn cmd(m1: f32, m2: f32) -> ValveCommand {
        ValveCommand {
            muscle1: m1,
            muscle2: m2,
        }
    }

    /// Infallible fake output (pin or PWM channel) logging its writes as (output id,
    /// level) to a shared log.
    struct LogOutput<'a, L> {
        id: u8,
        log: &'a core::cell::RefCell<Vec<(u8, L)>>,
    }
    impl<L> LogOutput<'_, L> {
        fn record(&mut self, level: L) -> Result<(), core::convert::Infallible> {
            self.log.borrow_mut().push((self.id, level));
            Ok(())
        }
    }
    /// Four outputs, ids 0 to 3 (inflate 1, exhaust 1, inflate 2, exhaust 2), on `log`.
    fn log_outputs<L>(log: &core::cell::RefCell<Vec<(u8, L)>>) -> [LogOutput<'_, L>; 4] {
        core::array::from_fn(|k| LogOutput { id: k as u8, log })
    }
    impl embedded_hal::digital::ErrorType for LogOutput<'_, bool> {
        type Error = core::convert::Infallible;
    }
    impl OutputPin for LogOutput<'_, bool> {
        fn set_low(&mut self) -> Result<(), Self::Error> {
            self.record(false)
        }
        fn set_high(&mut self) -> Result<(), Self::Error> {
            self.record(true)
        }
    }
    impl embedded_hal::pwm::ErrorType for LogOutput<'_, u16> {
        type Error = core::convert::Infallible;
    }
    impl SetDutyCycle for LogOutput<'_, u16> {
        fn max_duty_cycle(&self) -> u16 {
            100
        }
        fn set_duty_cycle(&mut self, duty: u16) -> Result<(), Self::Error> {
            self.record(duty)
        }
    }

    type MockValves = OnOffValves<PinMock, PinMock, PinMock, PinMock>;

    /// On/off valves (reference PWM) on four mock pins expecting `tx[k]` on pin k (in1, ex1,
    /// in2, ex2); `drive` runs them, then every mock checks it saw all its transactions.
    fn on_mock_pins(tx: [&[PinTx]; 4], drive: impl FnOnce(&mut MockValves)) {
        let mut pins = tx.map(PinMock::new);
        let [in1, ex1, in2, ex2] = pins.clone();
        drive(&mut OnOffValves::new(
            in1,
            ex1,
            in2,
            ex2,
            OnOffPwmConfig::REFERENCE,
        ));
        for p in pins.iter_mut() {
            p.done();
        }
    }

    /// `ticks` pin writes: high for the first `high` of them, low after.
    fn pulse(high: usize, ticks: usize) -> Vec<PinTx> {
        (0..ticks)
            .map(|k| PinTx::set(if k < high { State::High } else { State::Low }))
            .collect()
    }

    #[test]
    fn switched_valves_read_back_as_openings() {
        for bits in 0u8..16 {
            let b = |k: u8| bits & (1 << k) != 0;
            let s = SwitchedValves::new(b(0), b(1), b(2), b(3));
            let o = s.openings();
            assert_eq!(
                [o.u_in1, o.u_ex1, o.u_in2, o.u_ex2],
                [0, 1, 2, 3].map(|k| b(k) as u8 as f32)
            );
            // One count per open valve, each in its own 16-bit lane.
            assert_eq!(s.lanes().count_ones(), bits.count_ones());
        }
    }

    #[test]
    fn on_off_pin_sequence_full_inflate_muscle1_exhaust_muscle2() {
        // Every tick: lows first (ex1, in2), then highs (in1, ex2).
        let tick = |_: ()| {
            [
                (PinTx::set(State::Low), 1u8),
                (PinTx::set(State::Low), 2),
                (PinTx::set(State::High), 0),
                (PinTx::set(State::High), 3),
            ]
        };
        let mut per_pin: [Vec<PinTx>; 4] = Default::default();
        for _ in 0..3 {
            for (t, pin) in tick(()) {
                per_pin[pin as usize].push(t);
            }
        }
        let [in1, ex1, in2, ex2] = &per_pin;
        on_mock_pins([in1, ex1, in2, ex2], |v| {
            for _ in 0..3 {
                let o = v.apply(&cmd(1.0, -1.0)).unwrap();
                assert_eq!(
                    o,
                    ValveOpenings {
                        u_in1: 1.0,
                        u_ex1: 0.0,
                        u_in2: 0.0,
                        u_ex2: 1.0
                    }
                );
            }
        });
    }

    #[test]
    fn on_off_pin_sequence_over_one_pwm_period() {
        // Muscle 1 over one 10-tick period: inflate high for the first ticks, then low; every
        // other pin low every tick.
        // +0.3: 3 ticks high, 7 low.
        // +0.15 with min on 2: 1.5 ticks rounds to 2 = min on -> high, high, low x8.
        let low10 = pulse(0, 10);
        for (u, high) in [(0.3, 3), (0.15, 2)] {
            on_mock_pins([&pulse(high, 10), &low10, &low10, &low10], |v| {
                for _ in 0..10 {
                    v.apply(&cmd(u, 0.0)).unwrap();
                }
            });
        }
    }

    #[test]
    fn on_off_close_all_drives_every_pin_low() {
        let low = pulse(0, 1);
        on_mock_pins([&low, &low, &low, &low], |v| v.close_all().unwrap());
    }

    #[test]
    fn on_off_pin_error_closes_all_and_names_the_valve() {
        use embedded_hal_mock::eh1::MockError;
        use std::io::ErrorKind;
        // in1 fails on set_high; then close_all drives all low.
        let in1_tx = [
            PinTx::set(State::High).with_error(MockError::Io(ErrorKind::Other)),
            PinTx::set(State::Low),
        ];
        let other_tx = pulse(0, 2);
        on_mock_pins([&in1_tx, &other_tx, &other_tx, &other_tx], |v| {
            let r = v.apply(&cmd(1.0, 0.0));
            assert!(matches!(r, Err(Error::Inflate1(_))));
        });
    }

    /// Runs `cmds` through an OnOffValves on logging pins; returns per-tick openings and
    /// checks the write-order invariant on the way.
    fn run(cmds: &[ValveCommand], cfg: OnOffPwmConfig) -> Vec<ValveOpenings> {
        let log = core::cell::RefCell::new(Vec::new());
        let [in1, ex1, in2, ex2] = log_outputs(&log);
        let mut v = OnOffValves::new(in1, ex1, in2, ex2, cfg);
        let mut level = [false; 4];
        let mut out = Vec::new();
        for c in cmds {
            out.push(v.apply(c).unwrap());
            for &(id, hi) in log.borrow().iter() {
                level[id as usize] = hi;
                // After every single pin write, no muscle has both valves open.
                assert!(!(level[0] && level[1]), "muscle 1 inflate+exhaust open");
                assert!(!(level[2] && level[3]), "muscle 2 inflate+exhaust open");
            }
            log.borrow_mut().clear();
        }
        out
    }

    #[test]
    fn on_off_duty_maps_to_on_ticks_per_period() {
        let cmds = [cmd(0.3, -0.7); 20];
        let o = run(&cmds, OnOffPwmConfig::REFERENCE);
        let in1: Vec<f32> = o.iter().map(|x| x.u_in1).collect();
        let ex2: Vec<f32> = o.iter().map(|x| x.u_ex2).collect();
        let want1 = [1., 1., 1., 0., 0., 0., 0., 0., 0., 0.];
        let want2 = [1., 1., 1., 1., 1., 1., 1., 0., 0., 0.];
        assert_eq!(&in1[..10], &want1);
        assert_eq!(&in1[10..], &want1);
        assert_eq!(&ex2[..10], &want2);
        assert!(o.iter().all(|x| x.u_ex1 == 0.0 && x.u_in2 == 0.0));
    }

    #[test]
    fn on_off_small_duty_respects_min_on_time_and_mean_duty() {
        let cfg = OnOffPwmConfig {
            period_ticks: 10,
            min_on_ticks: 3,
        };
        let cmds = [cmd(0.05, 0.0); 1000];
        let o = run(&cmds, cfg);
        // Every pulse lasts at least 3 ticks.
        let mut run_len = 0;
        let mut pulses = Vec::new();
        for x in &o {
            if x.u_in1 > 0.0 {
                run_len += 1;
            } else if run_len > 0 {
                pulses.push(run_len);
                run_len = 0;
            }
        }
        assert!(!pulses.is_empty());
        assert!(pulses.iter().all(|&p| p >= 3), "{pulses:?}");
        // The mean duty is kept by the carried remainder.
        let mean = o.iter().map(|x| x.u_in1).sum::<f32>() / o.len() as f32;
        assert!((mean - 0.05).abs() < 0.005, "{mean}");
    }

    #[test]
    fn on_off_zero_command_closes_in_same_tick() {
        let mut cmds = [cmd(0.5, 0.5); 4];
        cmds[2] = cmd(0.0, 0.0);
        let o = run(&cmds, OnOffPwmConfig::REFERENCE);
        assert_eq!(o[1].u_in1, 1.0);
        assert_eq!(o[2], ValveOpenings::default());
    }

    #[test]
    fn on_off_reversal_switches_valve_in_same_tick_never_both() {
        let mut cmds = [cmd(0.5, -0.5); 4];
        cmds[2] = cmd(-1.0, 1.0);
        let o = run(&cmds, OnOffPwmConfig::REFERENCE);
        assert_eq!((o[1].u_in1, o[1].u_ex1), (1.0, 0.0));
        assert_eq!((o[2].u_in1, o[2].u_ex1), (0.0, 1.0));
        assert_eq!((o[2].u_in2, o[2].u_ex2), (1.0, 0.0));
    }

    #[test]
    fn on_off_nan_command_is_closed() {
        let o = run(
            &[
                cmd(f32::NAN, f32::INFINITY),
                cmd(f32::NEG_INFINITY, f32::NAN),
            ],
            OnOffPwmConfig::REFERENCE,
        );
        assert!(o.iter().all(|x| *x == ValveOpenings::default()));
    }

    #[test]
    fn on_off_degenerate_config_does_not_panic() {
        let cfg = OnOffPwmConfig {
            period_ticks: 0,
            min_on_ticks: 0,
        };
        // Period 1 tick: the duty is realised by the carried remainder alone.
        let o = run(&[cmd(0.2, -0.9); 100], cfg);
        assert!(o.iter().all(|x| x.u_ex1 == 0.0 && x.u_in2 == 0.0));
        let in1 = o.iter().map(|x| x.u_in1).sum::<f32>() / 100.0;
        let ex2 = o.iter().map(|x| x.u_ex2).sum::<f32>() / 100.0;
        assert!((in1 - 0.2).abs() < 0.02, "{in1}");
        assert!((ex2 - 0.9).abs() < 0.02, "{ex2}");
    }

    #[test]
    fn proportional_duty_is_abs_command_against_mock() {
        let max = 1000u16;
        let in1_tx = [PwmTx::max_duty_cycle(max), PwmTx::set_duty_cycle(250)];
        let ex1_tx = [PwmTx::max_duty_cycle(max), PwmTx::set_duty_cycle(0)];
        let in2_tx = [PwmTx::max_duty_cycle(max), PwmTx::set_duty_cycle(0)];
        let ex2_tx = [PwmTx::max_duty_cycle(max), PwmTx::set_duty_cycle(1000)];
        let mut in1 = PwmMock::new(&in1_tx);
        let mut ex1 = PwmMock::new(&ex1_tx);
        let mut in2 = PwmMock::new(&in2_tx);
        let mut ex2 = PwmMock::new(&ex2_tx);
        let mut v = ProportionalValves::new(in1.clone(), ex1.clone(), in2.clone(), ex2.clone());
        let o = v.apply(&cmd(0.25, -1.0)).unwrap();
        assert_eq!(
            o,
            ValveOpenings {
                u_in1: 0.25,
                u_ex1: 0.0,
                u_in2: 0.0,
                u_ex2: 1.0
            }
        );
        in1.done();
        ex1.done();
        in2.done();
        ex2.done();
    }

    #[test]
    fn proportional_reversal_zeroes_before_opening_never_both() {
        let log = core::cell::RefCell::new(Vec::new());
        let [in1, ex1, in2, ex2] = log_outputs(&log);
        let mut v = ProportionalValves::new(in1, ex1, in2, ex2);
        let mut duty = [0u16; 4];
        for c in [
            cmd(0.6, -0.2),
            cmd(-0.6, 0.2),
            cmd(f32::NAN, 1.0),
            cmd(-1.0, -1.0),
        ] {
            v.apply(&c).unwrap();
            for &(id, d) in log.borrow().iter() {
                duty[id as usize] = d;
                assert!(duty[0] == 0 || duty[1] == 0);
                assert!(duty[2] == 0 || duty[3] == 0);
            }
            log.borrow_mut().clear();
        }
        assert_eq!(duty, [0, 100, 0, 100]);
    }

    #[test]
    fn duty_rounding_and_clamping() {
        assert_eq!(duty_of(0.25, 1000), 250);
        assert_eq!(duty_of(1.5, 1000), 1000);
        assert_eq!(duty_of(f32::NAN, 1000), 0);
        assert_eq!(duty_of(-0.1, 1000), 0);
        assert_eq!(split(sanitize(-0.4)), (0.0, 0.4));
        assert_eq!(ValveOpenings::from_command(&cmd(f32::NAN, -2.0)).u_ex2, 1.0);
    }
}
