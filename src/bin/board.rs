//! The firmware on a real board: STM32F407G-DISC1 (STM32F407 Discovery), `cargo flash`.
//!
//! - Control tick: TIM7 update interrupt at `PAM_TICK_HZ` (compile-time environment variable,
//!   default 1000 Hz). Each tick samples both pressure transducers (ADC1 IN11 / IN12 on PC1 /
//!   PC2, one ADC each), reads the joint encoder (TIM2 in encoder mode on PA15 / PB3, 32-bit),
//!   runs the control tick with the measured period (DWT cycle counter: a late tick latches
//!   `FaultCode::Watchdog`), drives the four on/off valves (PD12..PD15), then feeds the
//!   independent watchdog.
//! - Independent watchdog (IWDG, 10 ms): if the tick stops (hang, fault loop) the MCU resets;
//!   reset leaves every GPIO a floating input and the valve drivers' pull-downs close all valves
//!   (the safe state). A boot after a watchdog reset stays in that safe state (valves off,
//!   controller not run) until the next power-on / reset-button reset.
//! - HardFault (a panic ends there too, after logging its location): valves off at register level, then wait
//!   for the watchdog.
//! - defmt over RTT (defmt-rtt), read by `probe-rs run` (scripts/flash-run.sh).
//!
//! Wiring and sensor scaling: README.md, section "Real board", and `src/wiring.rs`. The board
//! implements the sensor / clock traits of `src/sensors.rs` (ADC, encoder timer, DWT cycle
//! counter) and drives the valves through `src/valves.rs`' `OnOffValves` (tick-level PWM).
#![no_std]
#![no_main]

use core::cell::{Cell, RefCell};
use core::convert::Infallible;

use cortex_m::interrupt::Mutex;
use cortex_m::peripheral::DWT;
use cortex_m_rt::{entry, exception, ExceptionFrame};
use defmt_rtt as _;
use stm32f4xx_hal::{
    adc::{
        config::{AdcConfig, SampleTime},
        Adc, Instance as AdcInstance,
    },
    gpio::{Analog, Output, PushPull, PC1, PC2, PD12, PD13, PD14, PD15},
    hal_02::{adc::Channel, Qei as _},
    pac::{self, interrupt, Interrupt, ADC1, TIM2, TIM7},
    prelude::*,
    qei::Qei,
    rcc::Config,
    timer::{CounterHz, Event, Flag},
    watchdog::IndependentWatchdog,
};

use pam_firmware::sensors::{AngleSensor, Clock, PressureScaling, PressureSensor, TickTimer};
use pam_firmware::tick::{ControlTick, ControllerConfig, SensorFrame, Setpoint};
use pam_firmware::valves::{OnOffPwmConfig, OnOffValves};
use pam_firmware::wiring;

/// Control tick rate [Hz]: `PAM_TICK_HZ` at build time, default 1000.
const TICK_HZ: u32 = match option_env!("PAM_TICK_HZ") {
    Some(s) => parse_hz(s),
    None => 1000,
};
/// Watchdog period [ms]: 10 ms, at least 2 tick periods at any rate.
const WATCHDOG_MS: u32 = {
    let two_ticks_ms = 2000 / TICK_HZ + 1;
    if two_ticks_ms > 10 {
        two_ticks_ms
    } else {
        10
    }
};
/// Core clock [Hz] (8 MHz HSE crystal of the Discovery board, PLL to 168 MHz).
const SYSCLK_HZ: u32 = 168_000_000;
/// Joint angle held by the controller [rad] (no host link on the board yet).
const SETPOINT_RAD: f32 = 0.0;

const fn parse_hz(s: &str) -> u32 {
    let b = s.as_bytes();
    let mut i = 0;
    let mut v: u32 = 0;
    while i < b.len() {
        assert!(
            b[i].is_ascii_digit() && v < 100_000,
            "PAM_TICK_HZ must be a decimal integer within 50..=10000"
        );
        v = v * 10 + (b[i] - b'0') as u32;
        i += 1;
    }
    assert!(
        v >= 50 && v <= 10_000,
        "PAM_TICK_HZ must be within 50..=10000"
    );
    v
}

/// [`PressureSensor`] view of one channel of the shared ADC1 (made for one reading).
struct AdcPressure<'a, ADC: AdcInstance, PIN> {
    adc: &'a mut Adc<ADC>,
    pin: &'a PIN,
    scaling: PressureScaling,
}

impl<ADC: AdcInstance, PIN: Channel<ADC, ID = u8>> PressureSensor for AdcPressure<'_, ADC, PIN> {
    type Error = Infallible;
    fn read_counts(&mut self) -> Result<Option<u32>, Infallible> {
        // A blocking single conversion (84 + 12 ADC cycles at 42 MHz: about 2.3 us).
        Ok(Some(
            self.adc.convert(self.pin, SampleTime::Cycles_84) as u32
        ))
    }
    fn scaling(&self) -> PressureScaling {
        self.scaling
    }
}

/// [`AngleSensor`] over TIM2 in encoder mode (32-bit counter: the count is the signed angle).
struct QeiAngle {
    qei: Qei<TIM2>,
}

impl AngleSensor for QeiAngle {
    type Error = Infallible;
    fn read_counts(&mut self) -> Result<Option<i32>, Infallible> {
        Ok(Some(self.qei.count() as i32))
    }
    fn counts_per_rev(&self) -> u32 {
        wiring::ENCODER_COUNTS_PER_REV
    }
}

/// [`Clock`] over the DWT cycle counter, extended to 64 bits (read at least every 25 s: every
/// tick reads it).
struct DwtClock {
    last: Cell<u32>,
    high: Cell<u64>,
}

impl Clock for DwtClock {
    fn now_ticks(&self) -> u64 {
        let now = DWT::cycle_count();
        if now < self.last.get() {
            self.high.set(self.high.get() + (1u64 << 32));
        }
        self.last.set(now);
        self.high.get() | now as u64
    }
    fn tick_hz(&self) -> u32 {
        SYSCLK_HZ
    }
}

type Valves = OnOffValves<
    PD12<Output<PushPull>>,
    PD13<Output<PushPull>>,
    PD14<Output<PushPull>>,
    PD15<Output<PushPull>>,
>;

struct Board {
    adc: Adc<ADC1>,
    p1_pin: PC1<Analog>,
    p2_pin: PC2<Analog>,
    scaling: PressureScaling,
    angle: QeiAngle,
    clock: DwtClock,
    period: TickTimer,
    valves: Valves,
    timer: CounterHz<TIM7>,
    watchdog: IndependentWatchdog,
    tick: ControlTick,
    fault_reported: bool,
    ticks: u32,
}

static BOARD: Mutex<RefCell<Option<Board>>> = Mutex::new(RefCell::new(None));

fn ok<T>(r: Result<T, Infallible>) -> T {
    match r {
        Ok(v) => v,
        Err(e) => match e {},
    }
}

impl Board {
    fn read_frame(&mut self) -> SensorFrame {
        let s = self.scaling;
        let mut p1 = AdcPressure {
            adc: &mut self.adc,
            pin: &self.p1_pin,
            scaling: s,
        };
        let p1_gauge_pa = ok(p1.read_gauge_pa());
        let mut p2 = AdcPressure {
            adc: &mut self.adc,
            pin: &self.p2_pin,
            scaling: s,
        };
        let p2_gauge_pa = ok(p2.read_gauge_pa());
        SensorFrame {
            p1_gauge_pa,
            p2_gauge_pa,
            angle_rad: ok(self.angle.read_angle_rad()),
        }
    }

    fn on_tick(&mut self) {
        self.timer.clear_flags(Flag::Update);
        // Measured period: a late tick (> dt_max_s) latches FaultCode::Watchdog in the tick.
        let dt_s = self.period.dt_s(&self.clock);
        let frame = self.read_frame();
        let sp = Setpoint {
            angle_rad: SETPOINT_RAD,
        };
        let out = self.tick.step(&frame, &sp, dt_s);
        // The tick outputs the safe valve command itself while a fault is latched.
        if self.valves.apply(&out.valves).is_err() {
            let _ = self.valves.close_all();
        }
        if let Some(f) = out.fault {
            if !self.fault_reported {
                self.fault_reported = true;
                defmt::error!("fault latched: {}; valves in the safe state", f);
            }
        }
        self.ticks = self.ticks.wrapping_add(1);
        if self.ticks % TICK_HZ == 0 {
            defmt::info!(
                "t={=u32}s angle={=f32} rad p1={=f32} Pa p2={=f32} Pa T_est={=f32} N m armed={=bool}",
                self.ticks / TICK_HZ,
                out.angle_est_rad,
                frame.p1_gauge_pa.unwrap_or(f32::NAN),
                frame.p2_gauge_pa.unwrap_or(f32::NAN),
                out.torque_est_nm,
                out.armed
            );
        }
        // Fed only by a completed tick: a stalled tick trips the watchdog.
        self.watchdog.feed();
    }
}

#[interrupt]
fn TIM7() {
    cortex_m::interrupt::free(|cs| {
        if let Some(b) = BOARD.borrow(cs).borrow_mut().as_mut() {
            b.on_tick();
        }
    });
}

#[entry]
fn main() -> ! {
    let dp = pac::Peripherals::take().unwrap();

    // Reset cause first: after a watchdog reset stay in the safe state.
    let watchdog_reset = dp.RCC.csr().read().wdgrstf().bit_is_set();
    dp.RCC.csr().modify(|_, w| w.rmvf().set_bit());

    // 8 MHz HSE crystal of the Discovery board -> 168 MHz.
    let mut rcc = dp.RCC.freeze(Config::hse(8.MHz()).sysclk(168.MHz()));

    let gpiod = dp.GPIOD.split(&mut rcc);
    let mut valves: Valves = OnOffValves::new(
        gpiod.pd12.into_push_pull_output(),
        gpiod.pd13.into_push_pull_output(),
        gpiod.pd14.into_push_pull_output(),
        gpiod.pd15.into_push_pull_output(),
        OnOffPwmConfig::REFERENCE,
    );
    // Valves closed before anything else can fail (GPIO writes on this chip cannot fail).
    let _ = valves.close_all();

    let mut watchdog = IndependentWatchdog::new(dp.IWDG);
    watchdog.stop_on_debug(&dp.DBGMCU, true);
    watchdog.start(WATCHDOG_MS.millis());

    if watchdog_reset {
        defmt::error!("reset by the watchdog: valves off, control not started");
        // Valves already low. Keep them so; feed so the board does not reset-loop.
        loop {
            watchdog.feed();
            cortex_m::asm::delay(168_000);
        }
    }

    let gpioa = dp.GPIOA.split(&mut rcc);
    let gpiob = dp.GPIOB.split(&mut rcc);
    let gpioc = dp.GPIOC.split(&mut rcc);
    let adc = Adc::new(dp.ADC1, true, AdcConfig::default(), &mut rcc);
    // PA15 / PB3 boot as JTAG (AF0); SWD does not need them. Internal pull-ups for
    // open-collector encoder outputs.
    let angle = QeiAngle {
        qei: Qei::new(
            dp.TIM2,
            (
                gpioa.pa15.into_pull_up_input(),
                gpiob.pb3.into_pull_up_input(),
            ),
            &mut rcc,
        ),
    };

    let mut cp = cortex_m::Peripherals::take().unwrap();
    cp.DCB.enable_trace();
    cp.DWT.enable_cycle_counter();
    let clock = DwtClock {
        last: Cell::new(0),
        high: Cell::new(0),
    };
    let mut period = TickTimer::new();
    period.dt_s(&clock); // start the period measurement now

    let mut timer = dp.TIM7.counter_hz(&mut rcc);
    timer.start(TICK_HZ.Hz()).unwrap();
    timer.listen(Event::Update);

    let board = Board {
        adc,
        p1_pin: gpioc.pc1.into_analog(),
        p2_pin: gpioc.pc2.into_analog(),
        scaling: wiring::pressure_scaling(),
        angle,
        clock,
        period,
        valves,
        timer,
        watchdog,
        tick: ControlTick::new(ControllerConfig::reference(TICK_HZ as f32)),
        fault_reported: false,
        ticks: 0,
    };
    cortex_m::interrupt::free(|cs| BOARD.borrow(cs).replace(Some(board)));
    defmt::info!(
        "pam-firmware board: tick {=u32} Hz, watchdog {=u32} ms",
        TICK_HZ,
        WATCHDOG_MS
    );
    // SAFETY: the handler only touches BOARD inside a critical section.
    unsafe { cortex_m::peripheral::NVIC::unmask(Interrupt::TIM7) };

    loop {
        cortex_m::asm::wfi();
    }
}

/// Panic: log the location (not the message: see Cargo.toml), then fault (valves off below).
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    match info.location() {
        Some(l) => defmt::error!("panicked at {=str}:{=u32}", l.file(), l.line()),
        None => defmt::error!("panicked"),
    }
    cortex_m::asm::udf()
}

#[exception]
unsafe fn HardFault(_ef: &ExceptionFrame) -> ! {
    // Valves off at register level (the HAL objects may be borrowed): PD12..PD15 low via BSRR.
    // SAFETY: a single write to GPIOD's set/reset register; nothing else runs any more.
    let gpiod = unsafe { &*pac::GPIOD::ptr() };
    gpiod.bsrr().write(|w| {
        w.br12()
            .set_bit()
            .br13()
            .set_bit()
            .br14()
            .set_bit()
            .br15()
            .set_bit()
    });
    // The watchdog is no longer fed: it resets the MCU, which boots into the safe state.
    loop {
        cortex_m::asm::nop();
    }
}
