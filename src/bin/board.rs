//! The firmware on a real board: STM32F407G-DISC1 (STM32F407 Discovery), `cargo flash`.
//!
//! - Control tick: TIM7 update interrupt at `PAM_TICK_HZ` (compile-time environment variable,
//!   default 1000 Hz). Each tick samples both pressure transducers (ADC1 IN11 / IN12 on PC1 /
//!   PC2), reads the joint encoder (TIM2 in encoder mode on PA15 / PB3, 32-bit), runs the control
//!   tick and drives the four on/off valves (PD12..PD15), then feeds the independent watchdog.
//! - Independent watchdog (IWDG, 10 ms): if the tick stops (hang, fault loop) the MCU resets;
//!   reset leaves every GPIO a floating input and the valve drivers' pull-downs close all valves
//!   (the safe state). A boot after a watchdog reset stays in that safe state (valves off,
//!   controller not run) until the next power-on / reset-button reset.
//! - HardFault (a panic ends there through panic-probe): valves off at register level, then wait
//!   for the watchdog.
//! - defmt over RTT (defmt-rtt), read by `probe-rs run` (scripts/flash-run.sh).
//!
//! Wiring and sensor scaling: README.md, section "Real board". Sensor adapters and the on/off
//! valve modulator are board-local here until `src/sensors.rs` / `src/valves.rs` (branch `ctrl`)
//! land.
#![no_std]
#![no_main]

use core::cell::RefCell;
use core::convert::Infallible;

use cortex_m::interrupt::Mutex;
use cortex_m_rt::{entry, exception, ExceptionFrame};
use defmt_rtt as _;
use embedded_hal::digital::OutputPin;
use panic_probe as _;
use stm32f4xx_hal::{
    adc::{
        config::{AdcConfig, SampleTime},
        Adc,
    },
    gpio::{Analog, Output, PushPull, PC1, PC2, PD12, PD13, PD14, PD15},
    hal_02::Qei as _,
    pac::{self, interrupt, Interrupt, ADC1, TIM2, TIM7},
    prelude::*,
    qei::Qei,
    rcc::Config,
    timer::{CounterHz, Event, Flag},
    watchdog::IndependentWatchdog,
};

use pam_firmware::sensor_scaling::{EncoderScaling, PressureScaling};
use pam_firmware::trace::{ControlTick, ControllerConfig, SensorFrame, Setpoint};

/// Control tick rate [Hz]: `PAM_TICK_HZ` at build time, default 1000.
const TICK_HZ: u32 = match option_env!("PAM_TICK_HZ") {
    Some(s) => parse_hz(s),
    None => 1000,
};
/// Watchdog period [ms]: 10 ticks at 1 kHz, at least 2 tick periods at any rate.
const WATCHDOG_MS: u32 = {
    let two_ticks_ms = 2000 / TICK_HZ + 1;
    if two_ticks_ms > 10 {
        two_ticks_ms
    } else {
        10
    }
};
/// Joint angle held by the controller [rad] (no host link on the board yet).
const SETPOINT_RAD: f32 = 0.0;

const fn parse_hz(s: &str) -> u32 {
    let b = s.as_bytes();
    let mut i = 0;
    let mut v: u32 = 0;
    while i < b.len() {
        assert!(
            b[i].is_ascii_digit(),
            "PAM_TICK_HZ must be a decimal integer"
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

/// One muscle's inflate / exhaust valve pair driven by tick-level pulse-density modulation:
/// the valve in the command's direction opens on a fraction |command| of the ticks; the other
/// is always closed first, so one muscle never inflates and exhausts at once. Board-local until
/// `src/valves.rs` (`OnOffValves`) lands.
struct OnOffMuscle<I, E> {
    inflate: I,
    exhaust: E,
    acc: f32,
}

impl<I, E> OnOffMuscle<I, E>
where
    I: OutputPin<Error = Infallible>,
    E: OutputPin<Error = Infallible>,
{
    fn new(mut inflate: I, mut exhaust: E) -> Self {
        let _ = inflate.set_low();
        let _ = exhaust.set_low();
        OnOffMuscle {
            inflate,
            exhaust,
            acc: 0.0,
        }
    }

    fn close(&mut self) {
        let _ = self.inflate.set_low();
        let _ = self.exhaust.set_low();
        self.acc = 0.0;
    }

    fn apply(&mut self, command: f32) {
        // NaN compares false everywhere: treated as 0 (closed).
        let duty = if command > 1.0 || command < -1.0 {
            1.0
        } else if command > 0.0 {
            command
        } else if command < 0.0 {
            -command
        } else {
            0.0
        };
        self.acc += duty;
        let open = self.acc >= 1.0;
        if open {
            self.acc -= 1.0;
        }
        if open && command > 0.0 {
            let _ = self.exhaust.set_low();
            let _ = self.inflate.set_high();
        } else if open && command < 0.0 {
            let _ = self.inflate.set_low();
            let _ = self.exhaust.set_high();
        } else {
            let _ = self.inflate.set_low();
            let _ = self.exhaust.set_low();
            if duty == 0.0 {
                self.acc = 0.0;
            }
        }
    }
}

type Out<P> = P;
struct Board {
    adc: Adc<ADC1>,
    p1_pin: PC1<Analog>,
    p2_pin: PC2<Analog>,
    encoder: Qei<TIM2>,
    muscle1: OnOffMuscle<Out<PD12<Output<PushPull>>>, Out<PD13<Output<PushPull>>>>,
    muscle2: OnOffMuscle<Out<PD14<Output<PushPull>>>, Out<PD15<Output<PushPull>>>>,
    timer: CounterHz<TIM7>,
    watchdog: IndependentWatchdog,
    tick: ControlTick,
    pressure: PressureScaling,
    angle: EncoderScaling,
    fault_reported: bool,
    ticks: u32,
}

static BOARD: Mutex<RefCell<Option<Board>>> = Mutex::new(RefCell::new(None));

impl Board {
    /// Board-local sensor adapter: both ADC channels and the encoder, as a frame.
    fn read_frame(&mut self) -> SensorFrame {
        let p1 = self.adc.convert(&self.p1_pin, SampleTime::Cycles_84);
        let p2 = self.adc.convert(&self.p2_pin, SampleTime::Cycles_84);
        let count = self.encoder.count() as i32; // TIM2 is 32-bit: sign by reinterpretation
        SensorFrame {
            p1_gauge_pa: Some(self.pressure.gauge_pa(p1)),
            p2_gauge_pa: Some(self.pressure.gauge_pa(p2)),
            angle_rad: Some(self.angle.angle_rad(count)),
        }
    }

    fn on_tick(&mut self) {
        self.timer.clear_flags(Flag::Update);
        let frame = self.read_frame();
        let sp = Setpoint {
            angle_rad: SETPOINT_RAD,
        };
        let out = self.tick.step(&frame, &sp, 1.0 / TICK_HZ as f32);
        if out.fault.is_some() {
            self.muscle1.close();
            self.muscle2.close();
            if !self.fault_reported {
                self.fault_reported = true;
                defmt::error!(
                    "fault {=u8}: valves in the safe state",
                    out.fault.map(|f| f as u8).unwrap_or(0)
                );
            }
        } else {
            self.muscle1.apply(out.valves.muscle1);
            self.muscle2.apply(out.valves.muscle2);
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
    let muscle1 = OnOffMuscle::new(
        gpiod.pd12.into_push_pull_output(),
        gpiod.pd13.into_push_pull_output(),
    );
    let muscle2 = OnOffMuscle::new(
        gpiod.pd14.into_push_pull_output(),
        gpiod.pd15.into_push_pull_output(),
    );

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
    let encoder = Qei::new(
        dp.TIM2,
        (
            gpioa.pa15.into_pull_up_input(),
            gpiob.pb3.into_pull_up_input(),
        ),
        &mut rcc,
    );

    let mut timer = dp.TIM7.counter_hz(&mut rcc);
    timer.start(TICK_HZ.Hz()).unwrap();
    timer.listen(Event::Update);

    let board = Board {
        adc,
        p1_pin: gpioc.pc1.into_analog(),
        p2_pin: gpioc.pc2.into_analog(),
        encoder,
        muscle1,
        muscle2,
        timer,
        watchdog,
        tick: ControlTick::new(ControllerConfig::reference(TICK_HZ as f32)),
        pressure: PressureScaling::REFERENCE,
        angle: EncoderScaling::REFERENCE,
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

#[exception]
unsafe fn HardFault(_ef: &ExceptionFrame) -> ! {
    // Valves off at register level (the HAL objects may be borrowed): PD12..PD15 low via BSRR.
    // SAFETY: a single write to GPIOD's set/reset register; nothing else runs any more.
    let gpiod = unsafe { &*pac::GPIOD::ptr() };
    gpiod
        .bsrr()
        .write(|w| w.br12().set_bit().br13().set_bit().br14().set_bit().br15().set_bit());
    // The watchdog is no longer fed: it resets the MCU, which boots into the safe state.
    loop {
        cortex_m::asm::nop();
    }
}
