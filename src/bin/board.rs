//! The firmware on a real board: STM32F407G-DISC1 (STM32F407 Discovery), `cargo flash`, on
//! RTIC 2 (hardware tasks; see docs/firmware.md for why RTIC and not embassy).
//!
//! - Sampling: TIM3 runs at `PAM_TICK_HZ` (compile-time environment variable, default
//!   1000 Hz); its update event (TRGO) triggers ADC1, which converts both pressure transducers
//!   in one scan (IN11 / IN12 on PC1 / PC2) and DMA2 stream 0 writes them to memory. No CPU
//!   time is spent waiting for a conversion.
//! - Control tick: the RTIC hardware task bound to the DMA transfer-complete interrupt, so it
//!   runs once per TIM3 period with fresh samples: swaps the DMA buffer, reads the joint
//!   encoder (TIM2 in encoder mode on PA15 / PB3, 32-bit), runs the control tick with the
//!   measured period (DWT cycle counter: a late tick latches `FaultCode::Watchdog`) and sets
//!   the four valve duties on TIM4 PWM channels 1..4 (PD12..PD15, `ProportionalValves`).
//! - Deadline: the tick must end within `DEADLINE_PERCENT` of its period and before the next
//!   samples arrive. Only a tick that met its deadline feeds the independent watchdog (IWDG,
//!   10 ms); each miss is counted in `PAM_TICK_OVERRUNS` (exported symbol, readable with a
//!   probe) and reported in the once-a-second status line. Persistent misses stop feeding:
//!   the MCU resets; reset leaves every GPIO a floating input and the valve drivers'
//!   pull-downs close all valves (the safe state). A boot after a watchdog reset stays in
//!   that safe state (valves off, controller not run) until the next power-on / reset.
//! - HardFault (a panic ends there too, after logging its location): valves off at register
//!   level, then wait for the watchdog.
//! - defmt over RTT (defmt-rtt), read by `probe-rs run` (scripts/flash-run.sh).
//!
//! Wiring and sensor scaling: `src/wiring.rs`. Not tested on hardware in this repository's
//! CI: the image is built (`cargo flash-build`), not run.
#![no_std]
#![no_main]

use core::sync::atomic::AtomicU32;

use cortex_m_rt::{exception, ExceptionFrame};
use defmt_rtt as _;
use stm32f4xx_hal::pac;

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
            "PAM_TICK_HZ must be a decimal integer within 200..=10000"
        );
        v = v * 10 + (b[i] - b'0') as u32;
        i += 1;
    }
    assert!(
        v >= 200 && v <= 10_000,
        "PAM_TICK_HZ must be within 200..=10000 (the gains are not stable below 200 Hz)"
    );
    v
}

/// A tick must end within this share of its period [%] to count as on time.
const DEADLINE_PERCENT: u32 = 80;
/// Valve PWM frequency [Hz] (on/off solenoid valves: a few times the tick rate's tenth).
const VALVE_PWM_HZ: u32 = 100;

/// Ticks that missed their deadline since reset (read it with a probe: `PAM_TICK_OVERRUNS`).
#[no_mangle]
pub static PAM_TICK_OVERRUNS: AtomicU32 = AtomicU32::new(0);

#[rtic::app(device = stm32f4xx_hal::pac, peripherals = true)]
mod app {
    use core::cell::Cell;
    use core::convert::Infallible;
    use core::sync::atomic::Ordering;

    use cortex_m::peripheral::{DWT, NVIC};
    use stm32f4xx_hal::{
        adc::{
            config::{AdcConfig, Dma, ExternalTrigger, SampleTime, Scan, Sequence, TriggerMode},
            Adc,
        },
        dma::{config::DmaConfig, PeripheralToMemory, Stream0, StreamsTuple, Transfer},
        hal_02::Qei as _,
        pac::{self, Interrupt, ADC1, DMA2, TIM2, TIM3, TIM4},
        prelude::*,
        qei::Qei,
        rcc::Config,
        timer::{CounterHz, ErasedChannel},
        watchdog::IndependentWatchdog,
    };

    use pam_firmware::sensors::{AngleSensor, Clock, PressureScaling, TickTimer};
    use pam_firmware::tick::{ControlTick, ControllerConfig, SensorFrame, Setpoint};
    use pam_firmware::valves::ProportionalValves;
    use pam_firmware::wiring;

    use super::{
        DEADLINE_PERCENT, PAM_TICK_OVERRUNS, SETPOINT_RAD, SYSCLK_HZ, TICK_HZ, VALVE_PWM_HZ,
        WATCHDOG_MS,
    };

    type AdcDma = Transfer<Stream0<DMA2>, 0, Adc<ADC1>, PeripheralToMemory, &'static mut [u16; 2]>;
    type Valve = ErasedChannel<TIM4>;
    type Valves = ProportionalValves<Valve, Valve, Valve, Valve>;

    /// [`AngleSensor`] over TIM2 in encoder mode (32-bit counter: the count is the signed
    /// angle).
    pub struct QeiAngle {
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

    /// [`Clock`] over the DWT cycle counter, extended to 64 bits (read at least every 25 s:
    /// every tick reads it).
    pub struct DwtClock {
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

    #[shared]
    struct Shared {}

    #[local]
    struct Local {
        adc: AdcDma,
        spare: Option<&'static mut [u16; 2]>,
        angle: QeiAngle,
        scaling: PressureScaling,
        clock: DwtClock,
        period: TickTimer,
        valves: Valves,
        tick: ControlTick,
        /// Fed by the tick (None in the safe hold after a watchdog reset).
        watchdog: Option<IndependentWatchdog>,
        /// Fed by idle in the safe hold after a watchdog reset only.
        hold_watchdog: Option<IndependentWatchdog>,
        /// Kept alive: TIM3 paces the ADC (TRGO on update).
        _sampler: Option<CounterHz<TIM3>>,
        fault_reported: bool,
        ticks: u32,
    }

    #[init]
    fn init(cx: init::Context) -> (Shared, Local) {
        let dp: pac::Peripherals = cx.device;
        let mut core = cx.core;

        // Reset cause first: after a watchdog reset stay in the safe state.
        let watchdog_reset = dp.RCC.csr().read().wdgrstf().bit_is_set();
        dp.RCC.csr().modify(|_, w| w.rmvf().set_bit());

        // 8 MHz HSE crystal of the Discovery board -> 168 MHz.
        let mut rcc = dp.RCC.freeze(Config::hse(8.MHz()).sysclk(SYSCLK_HZ.Hz()));

        // Valves: TIM4 CH1..CH4 on PD12..PD15, duty 0 (closed) before anything else.
        let gpiod = dp.GPIOD.split(&mut rcc);
        let (_, (c1, c2, c3, c4)) = dp.TIM4.pwm_hz(VALVE_PWM_HZ.Hz(), &mut rcc);
        let mut chans = [
            c1.with(gpiod.pd12).erase(),
            c2.with(gpiod.pd13).erase(),
            c3.with(gpiod.pd14).erase(),
            c4.with(gpiod.pd15).erase(),
        ];
        for c in chans.iter_mut() {
            c.set_duty(0);
            c.enable();
        }
        let [c1, c2, c3, c4] = chans;
        let mut valves: Valves = ProportionalValves::new(c1, c2, c3, c4);
        let _ = valves.close_all();

        let mut watchdog = IndependentWatchdog::new(dp.IWDG);
        watchdog.stop_on_debug(&dp.DBGMCU, true);
        watchdog.start(WATCHDOG_MS.millis());

        let gpioa = dp.GPIOA.split(&mut rcc);
        let gpiob = dp.GPIOB.split(&mut rcc);
        let gpioc = dp.GPIOC.split(&mut rcc);
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

        // ADC1: scan IN11 (PC1), IN12 (PC2) on each TIM3 TRGO, results by DMA.
        let adc_config = AdcConfig::default()
            .dma(Dma::Continuous)
            .scan(Scan::Enabled)
            .external_trigger(TriggerMode::RisingEdge, ExternalTrigger::Tim_3_trgo);
        let mut adc = Adc::new(dp.ADC1, true, adc_config, &mut rcc);
        let p1_pin = gpioc.pc1.into_analog();
        let p2_pin = gpioc.pc2.into_analog();
        adc.configure_channel(&p1_pin, Sequence::One, SampleTime::Cycles_84);
        adc.configure_channel(&p2_pin, Sequence::Two, SampleTime::Cycles_84);
        let dma = StreamsTuple::new(dp.DMA2, &mut rcc);
        let first = cortex_m::singleton!(: [u16; 2] = [0; 2]).unwrap();
        let spare = cortex_m::singleton!(: [u16; 2] = [0; 2]).unwrap();
        let dma_config = DmaConfig::default()
            .transfer_complete_interrupt(true)
            .memory_increment(true)
            .double_buffer(false);
        let mut adc = Transfer::init_peripheral_to_memory(dma.0, adc, first, None, dma_config);

        core.DCB.enable_trace();
        core.DWT.enable_cycle_counter();
        let clock = DwtClock {
            last: Cell::new(0),
            high: Cell::new(0),
        };
        let mut period = TickTimer::new();

        let (watchdog, hold_watchdog, sampler) = if watchdog_reset {
            defmt::error!("reset by the watchdog: valves off, control not started");
            (None, Some(watchdog), None)
        } else {
            period.dt_s(&clock); // start the period measurement now
            adc.start(|_| {});
            let mut sampler = dp.TIM3.counter_hz(&mut rcc);
            // TRGO on update: each period starts one ADC scan.
            // SAFETY: CR2.MMS of TIM3, which `sampler` owns and does not use otherwise.
            unsafe { (*pac::TIM3::ptr()).cr2().modify(|_, w| w.mms().update()) };
            sampler.start(TICK_HZ.Hz()).unwrap();
            defmt::info!(
                "pam-firmware board (RTIC 2): tick {=u32} Hz from TIM3 -> ADC1 -> DMA2, \
                 deadline {=u32} %, watchdog {=u32} ms",
                TICK_HZ,
                DEADLINE_PERCENT,
                WATCHDOG_MS
            );
            (Some(watchdog), None, Some(sampler))
        };

        (
            Shared {},
            Local {
                adc,
                spare: Some(spare),
                angle,
                scaling: wiring::pressure_scaling(),
                clock,
                period,
                valves,
                tick: ControlTick::new(ControllerConfig::reference(TICK_HZ as f32)),
                watchdog,
                hold_watchdog,
                _sampler: sampler,
                fault_reported: false,
                ticks: 0,
            },
        )
    }

    #[idle(local = [hold_watchdog])]
    fn idle(cx: idle::Context) -> ! {
        loop {
            match cx.local.hold_watchdog.as_mut() {
                // Safe hold after a watchdog reset: valves stay closed, keep the MCU alive.
                Some(w) => {
                    w.feed();
                    cortex_m::asm::delay(SYSCLK_HZ / 1000);
                }
                None => cortex_m::asm::wfi(),
            }
        }
    }

    /// The control tick: once per sampling period, when the DMA has delivered both pressures.
    #[task(binds = DMA2_STREAM0, priority = 2, local = [adc, spare, angle, scaling, clock, period, valves, tick, watchdog, fault_reported, ticks])]
    fn control_tick(cx: control_tick::Context) {
        let l = cx.local;
        let start = DWT::cycle_count();
        l.adc.clear_transfer_complete();
        let (p1_counts, p2_counts) = match l.spare.take() {
            Some(buf) => match l.adc.next_transfer(buf) {
                Ok((done, _)) => {
                    let c = (done[0], done[1]);
                    *l.spare = Some(done);
                    (Some(c.0), Some(c.1))
                }
                // Not expected (single buffer); no samples this tick: the tick ages them.
                Err(_) => (None, None),
            },
            None => (None, None),
        };
        let s = *l.scaling;
        let frame = SensorFrame {
            p1_gauge_pa: p1_counts.map(|c| s.to_gauge_pa(c as u32)),
            p2_gauge_pa: p2_counts.map(|c| s.to_gauge_pa(c as u32)),
            angle_rad: match l.angle.read_angle_rad() {
                Ok(a) => a,
                Err(e) => match e {},
            },
        };
        // Measured period: a late tick (> dt_max_s) latches FaultCode::Watchdog in the tick.
        let dt_s = l.period.dt_s(l.clock);
        let out = l.tick.step(
            &frame,
            &Setpoint {
                angle_rad: SETPOINT_RAD,
            },
            dt_s,
        );
        // The tick outputs the safe valve command itself while a fault is latched.
        // The openings the driver actually switched feed the valve / supply residual.
        match l.valves.apply(&out.valves) {
            Ok(o) => l.tick.valves_applied(&o),
            Err(_) => {
                let _ = l.valves.close_all();
            }
        }
        if let Some(f) = out.fault {
            if !*l.fault_reported {
                *l.fault_reported = true;
                defmt::error!("fault latched: {}; valves in the safe state", f);
            }
        }
        *l.ticks = l.ticks.wrapping_add(1);
        if *l.ticks % TICK_HZ == 0 {
            defmt::info!(
                "t={=u32}s angle={=f32} rad p1={=f32} Pa p2={=f32} Pa T_est={=f32} N m armed={=bool} overruns={=u32}",
                *l.ticks / TICK_HZ,
                out.angle_est_rad,
                frame.p1_gauge_pa.unwrap_or(f32::NAN),
                frame.p2_gauge_pa.unwrap_or(f32::NAN),
                out.torque_est_nm,
                out.armed,
                PAM_TICK_OVERRUNS.load(Ordering::Relaxed)
            );
        }
        // Deadline: done within DEADLINE_PERCENT of the period, and the next samples have not
        // arrived meanwhile (their interrupt would be pending). Only then feed the watchdog.
        let budget = SYSCLK_HZ / TICK_HZ / 100 * DEADLINE_PERCENT;
        let on_time = DWT::cycle_count().wrapping_sub(start) <= budget
            && !NVIC::is_pending(Interrupt::DMA2_STREAM0);
        if on_time {
            if let Some(w) = l.watchdog.as_mut() {
                w.feed();
            }
        } else {
            PAM_TICK_OVERRUNS.fetch_add(1, Ordering::Relaxed);
        }
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
