//! The firmware on a real board: STM32F407G-DISC1 (STM32F407 Discovery), `cargo flash`, on
//! RTIC 2 (hardware tasks; see docs/firmware.md for why RTIC and not embassy).
//!
//! Start-up, in this order (docs/firmware.md, "Board start-up"), still on the 16 MHz HSI:
//! 1. Valve pins driven to the configured safe state (`SAFE_STATE`) as plain outputs.
//! 2. Reset cause and the fault-latch record from the backup SRAM (`latch_bkpsram`).
//! 3. Independent watchdog started (10 ms, LSI: independent of the clock tree).
//! 4. Clock tree: 8 MHz HSE crystal, PLL to 168 MHz.
//! 5. Boot decision (`latch::boot_decision`): every reset but a power-on with a clean record
//!    starts with the stored fault (or `ResetLatched`) latched in the tick: the safe state
//!    from the first tick, checks and escalation running, until the operator's reset request
//!    (user button B1, held `RESET_HOLD_MS`) is accepted by the tick.
//! 6. A clean power-on first calibrates the pressure zero: both exhausts open for
//!    `CAL_VENT_MS`, then the mean of `CAL_AVG_MS` of samples is 0 Pa gauge. The encoder zero
//!    is the joint's pose at reset (docs/rig.md: the documented pose).
//!
//! Each tick:
//! - Sampling: TIM3 runs at `PAM_TICK_HZ` (compile-time, default 1000 Hz); its update event
//!   triggers ADC1 (both pressure transducers, IN11 / IN12 on PC1 / PC2, one scan), DMA2
//!   stream 0 writes them to memory. A buffer entry the DMA did not rewrite since the last
//!   tick reaches the tick as a missing sample (`wiring::take_fresh_counts`), which ages into a
//!   `...Stale` fault after 10 ticks.
//! - Control tick: the RTIC task bound to the DMA transfer-complete interrupt: joint encoder
//!   (TIM2 in encoder mode on PA15 / PB3), the control tick with the measured period (DWT),
//!   the set-point from the compiled-in scenario (`PAM_BOARD_SCENARIO`, build.rs), the four
//!   valve duties on TIM4 PWM CH1..CH4 (PD12..PD15), the latch record stored when it changes,
//!   and one stream record (`stream::TickRecord`, with its sequence number) over defmt RTT.
//! - Deadline: a tick must end within `DEADLINE_PERCENT` of its period and before the next
//!   samples arrive; only then is the watchdog fed; each miss is counted in
//!   `PAM_TICK_OVERRUNS`. A second timer (TIM5, one interrupt priority above the tick) fires
//!   if the tick has not ended by the deadline: it forces the valve pins to the safe state at
//!   register level and counts in `PAM_MONITOR_TRIPS`; the tick, if it ever ends, latches
//!   `Watchdog` and hands the pins back to the PWM (now carrying the safe command). A tick
//!   that never ends is not feeding the watchdog: reset, then a latched safe boot.
//! - HardFault (a panic ends there too, after logging its location): the valve pins to the
//!   configured safe state at register level, then the watchdog resets into a safe boot.
//!
//! Wiring and sensor scaling: `src/wiring.rs`. Not tested on hardware in this repository's
//! CI: the image is built (`cargo flash-build`), not run.
#![no_std]
#![no_main]

use core::sync::atomic::{AtomicBool, AtomicU32};

use cortex_m_rt::{exception, ExceptionFrame};
use defmt_rtt as _;
use pam_firmware::safety::SafeState;
use pam_firmware::wiring;
use stm32f4xx_hal::pac;

include!(concat!(env!("OUT_DIR"), "/board_profile.rs"));

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
/// The safe valve state of this build: the controller's configuration, the HardFault path
/// and the tick monitor all use it.
const SAFE_STATE: SafeState = SafeState::Hold;
/// `BSRR` word of the safe valve levels and valve-enable line (HardFault and tick monitor).
const SAFE_BSRR: u32 = wiring::safe_bsrr(SAFE_STATE);
/// Start-up calibration: both exhausts open this long before averaging [ms].
const CAL_VENT_MS: u32 = 1500;
/// Start-up calibration: averaging time of the pressure zero [ms].
const CAL_AVG_MS: u32 = 500;
/// The reset button (B1, PA0) must be held this long to request a re-arm [ms].
const RESET_HOLD_MS: u32 = 500;

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

// The outer loops of the cascade no slower than 200 Hz: a build that breaks it would latch a
// configuration fault at every power-up (`ControllerConfig::is_valid`).
const _: () = assert!(
    TICK_HZ / pam_firmware::constants::OUTER_PERIOD_TICKS as u32 >= 200,
    "config/controller.toml [rates] outer_period_ticks: at this PAM_TICK_HZ the outer loops \
     would run below 200 Hz (at most PAM_TICK_HZ / 200 ticks, 5 at 1000 Hz)"
);

/// A tick must end within this share of its period [%] to count as on time.
const DEADLINE_PERCENT: u32 = 80;
/// The tick deadline [us] (soft check in the tick, hard check by the TIM5 monitor).
const DEADLINE_US: u32 = 1_000_000 / TICK_HZ * DEADLINE_PERCENT / 100;
/// Valve PWM frequency [Hz] (on/off solenoid valves: a few times the tick rate's tenth).
const VALVE_PWM_HZ: u32 = 100;

/// Ticks that missed their deadline since reset (read it with a probe: `PAM_TICK_OVERRUNS`).
#[no_mangle]
pub static PAM_TICK_OVERRUNS: AtomicU32 = AtomicU32::new(0);
/// Times the tick monitor (TIM5) found a tick still running at its deadline and forced the
/// safe valve state.
#[no_mangle]
pub static PAM_MONITOR_TRIPS: AtomicU32 = AtomicU32::new(0);
/// Set by the tick monitor, taken by the tick.
static MONITOR_TRIPPED: AtomicBool = AtomicBool::new(false);

/// Drives the valve pins to the safe levels as plain GPIO outputs (away from the timer), at
/// register level: usable from any context, whatever owns the HAL objects.
///
/// # Safety
/// Writes GPIOD's BSRR (atomic) and read-modify-writes its MODER: call only where no other
/// code changes GPIOD's MODER concurrently (HardFault, the highest-priority task).
unsafe fn force_safe_valve_pins() {
    // SAFETY: see the function's contract; GPIOD's clock is on from the first line of init.
    let gpiod = unsafe { &*pac::GPIOD::ptr() };
    gpiod.bsrr().write(|w| unsafe { w.bits(SAFE_BSRR) });
    gpiod
        .moder()
        .modify(|r, w| unsafe { w.bits(wiring::valve_moder_output(r.bits())) });
}

/// Init step: ADC1 scanning IN11 (PC1) and IN12 (PC2) on each TIM3 TRGO, results by DMA2;
/// declares the transfer `$adc` and the spare buffer `$spare`. A macro expanded in place in
/// `init`: as a function the compiler lays `init` out differently (+4 B of flash, measured).
macro_rules! start_adc {
    ($dp:ident, $rcc:ident, $gpioc:ident, $adc:ident, $spare:ident) => {
        // ADC1: scan IN11 (PC1), IN12 (PC2) on each TIM3 TRGO, results by DMA.
        let adc_config = AdcConfig::default()
            .dma(Dma::Continuous)
            .scan(Scan::Enabled)
            .external_trigger(TriggerMode::RisingEdge, ExternalTrigger::Tim_3_trgo);
        let mut $adc = Adc::new($dp.ADC1, true, adc_config, &mut $rcc);
        let p1_pin = $gpioc.pc1.into_analog();
        let p2_pin = $gpioc.pc2.into_analog();
        $adc.configure_channel(&p1_pin, Sequence::One, SampleTime::Cycles_84);
        $adc.configure_channel(&p2_pin, Sequence::Two, SampleTime::Cycles_84);
        let dma = StreamsTuple::new($dp.DMA2, &mut $rcc);
        // Both buffers carry the fill marker: an entry the DMA did not write reads as missing.
        let first = cortex_m::singleton!(: [u16; 2] = [wiring::ADC_NOT_WRITTEN; 2]);
        let $spare = cortex_m::singleton!(: [u16; 2] = [wiring::ADC_NOT_WRITTEN; 2]);
        let (Some(first), Some($spare)) = (first, $spare) else {
            // init runs once: not reachable.
            cortex_m::asm::udf()
        };
        let dma_config = DmaConfig::default()
            .transfer_complete_interrupt(true)
            .memory_increment(true)
            .double_buffer(false);
        let mut $adc = Transfer::init_peripheral_to_memory(dma.0, $adc, first, None, dma_config);
    };
}

/// Init step: the start phase from the boot decision (an expression): the pressure zero
/// calibration after a clean power-on, else the control tick in the stored latched state (the
/// safe state until the reset button). A macro expanded in place in `init`: as a function the
/// compiler lays `init` out differently (-12 B of flash, measured).
macro_rules! boot_phase {
    ($boot:ident, $kept:ident, $reset:ident, $tick:ident) => {
        match $boot {
            BootDecision::Arm => {
                defmt::info!("power-on with a clean latch: pressure zero calibration");
                Phase::Calibrating {
                    ticks: 0,
                    sum_counts: [0; 2],
                    n: [0; 2],
                }
            }
            BootDecision::Safe(record) => {
                match $kept {
                    Some(c) => defmt::info!("encoder count {=i32} kept across the reset", c),
                    None => defmt::warn!("encoder zero is the pose at this reset"),
                }
                defmt::error!(
                    "boot after {} with latch {}: safe state until the reset button",
                    $reset,
                    record
                );
                $tick.restore_latch(&record);
                Phase::Running
            }
        }
    };
}

#[rtic::app(device = stm32f4xx_hal::pac, peripherals = true)]
mod app {
    use core::cell::Cell;
    use core::sync::atomic::Ordering;

    use cortex_m::peripheral::{DWT, NVIC};
    use stm32f4xx_hal::{
        adc::{
            config::{AdcConfig, Dma, ExternalTrigger, SampleTime, Scan, Sequence, TriggerMode},
            Adc,
        },
        dma::{config::DmaConfig, PeripheralToMemory, Stream0, StreamsTuple, Transfer},
        gpio::{
            self, Input, Output, PinState, PushPull, PA0, PA15, PB3, PD11, PD12, PD13, PD14, PD15,
        },
        hal_02::Qei as _,
        pac::{self, Interrupt, ADC1, DMA2, TIM2, TIM3, TIM4, TIM5},
        prelude::*,
        qei::Qei,
        rcc::{Config, Rcc},
        timer::{CounterHz, CounterUs, ErasedChannel, Event},
        watchdog::IndependentWatchdog,
    };

    use pam_firmware::latch::{self, BootDecision, LatchRecord, PersistentLatch, ResetButton};
    use pam_firmware::latch_bkpsram::{self, BackupSram, EncoderKeep};
    use pam_firmware::safety::{FaultCode, FaultSet, SafeState};
    use pam_firmware::sensors::{Clock, PressureScaling, TickTimer};
    use pam_firmware::stream::{TickRecord, MISSING_COUNTS};
    use pam_firmware::tick::{ControlTick, ControllerConfig, SensorFrame, Setpoint};
    use pam_firmware::valves::{ProportionalValves, ValveOpenings};
    use pam_firmware::wiring;

    use super::{
        BOARD_PROFILE, BOARD_SCENARIO, CAL_AVG_MS, CAL_VENT_MS, DEADLINE_PERCENT, DEADLINE_US,
        MONITOR_TRIPPED, PAM_MONITOR_TRIPS, PAM_TICK_OVERRUNS, RESET_HOLD_MS, SAFE_STATE,
        SYSCLK_HZ, TICK_HZ, VALVE_PWM_HZ, WATCHDOG_MS,
    };

    type AdcDma = Transfer<Stream0<DMA2>, 0, Adc<ADC1>, PeripheralToMemory, &'static mut [u16; 2]>;
    type Valve = ErasedChannel<TIM4>;
    type Valves = ProportionalValves<Valve, Valve, Valve, Valve>;
    /// The valve pins PD12..PD15 at their safe levels, before they switch to the timer.
    type ValvePins = (
        PD12<Output<PushPull>>,
        PD13<Output<PushPull>>,
        PD14<Output<PushPull>>,
        PD15<Output<PushPull>>,
    );

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

    /// Start-up calibration (clean power-on only) or control.
    pub enum Phase {
        /// Both exhausts open; `ticks` so far, sums and counts of the samples averaged.
        Calibrating {
            ticks: u32,
            sum_counts: [u32; 2],
            n: [u32; 2],
        },
        /// The control tick runs.
        Running,
    }

    /// Tick period [us] (exact for the rates that divide 1 MHz; the stream's time stamps).
    const US_PER_TICK: u32 = 1_000_000 / TICK_HZ;
    // Milliseconds to ticks at any allowed rate (200..=10000 Hz: no overflow, no zero).
    const CAL_VENT_TICKS: u32 = TICK_HZ * CAL_VENT_MS / 1000;
    const CAL_TICKS: u32 = CAL_VENT_TICKS + TICK_HZ * CAL_AVG_MS / 1000;

    #[shared]
    struct Shared {}

    #[local]
    struct Local {
        adc: AdcDma,
        spare: Option<&'static mut [u16; 2]>,
        qei: Qei<TIM2>,
        scaling: [PressureScaling; 2],
        clock: DwtClock,
        period: TickTimer,
        valves: Valves,
        /// The valve-driver enable line (PD11, `wiring::valve_enable`).
        valve_enable: PD11<Output<PushPull>>,
        tick: ControlTick,
        latch: PersistentLatch<BackupSram>,
        encoder_keep: EncoderKeep,
        button_pin: PA0<Input>,
        button: ResetButton,
        phase: Phase,
        watchdog: IndependentWatchdog,
        monitor: CounterUs<TIM5>,
        /// The monitor forced the pins to GPIO: hand them back to the PWM after the tick
        /// applied its (now safe) command.
        pins_forced: bool,
        /// Kept alive: TIM3 paces the ADC (TRGO on update).
        _sampler: CounterHz<TIM3>,
        fault_reported: bool,
        ticks: u32,
    }

    #[init]
    fn init(cx: init::Context) -> (Shared, Local) {
        let dp: pac::Peripherals = cx.device;
        let mut core = cx.core;

        // 1. Valve pins to the safe state before anything else (still on the 16 MHz HSI).
        let mut rcc = dp.RCC.constrain();
        let (valve_enable, valve_pins) = safe_valve_pins(dp.GPIOD.split(&mut rcc));

        // 2. Reset cause and latch record (RCC_CSR and the backup SRAM; the HAL does not touch
        //    the reset flags).
        let (storage, reset) = latch_bkpsram::init();
        let encoder_keep = storage.encoder_keep();

        // 3. Watchdog (LSI), before the clock tree: a hang in the PLL set-up resets.
        let mut watchdog = IndependentWatchdog::new(dp.IWDG);
        watchdog.stop_on_debug(&dp.DBGMCU, true);
        watchdog.start(WATCHDOG_MS.millis());

        // 4. Clock tree: 8 MHz HSE crystal of the Discovery board -> 168 MHz.
        let mut rcc = rcc.freeze(Config::hse(8.MHz()).sysclk(SYSCLK_HZ.Hz()));
        watchdog.feed();

        // 5. Boot decision.
        let (latch, boot) = PersistentLatch::boot(storage, reset);
        let mut cfg = ControllerConfig::reference(TICK_HZ as f32);
        cfg.safe_state = SAFE_STATE;
        let mut tick = ControlTick::new(cfg);

        let valves = start_valves(dp.TIM4, valve_pins, &mut rcc);
        let gpioa = dp.GPIOA.split(&mut rcc);
        let gpiob = dp.GPIOB.split(&mut rcc);
        let gpioc = dp.GPIOC.split(&mut rcc);
        // PA15 / PB3 boot as JTAG (AF0); SWD does not need them. Internal pull-ups for
        // open-collector encoder outputs.
        let encoder_pins = (
            gpioa.pa15.into_pull_up_input(),
            gpiob.pb3.into_pull_up_input(),
        );
        let (qei, kept) = start_encoder(dp.TIM2, encoder_pins, &mut rcc, &encoder_keep, reset);
        // User button B1 (PA0, high when pressed; pull-down on the board and here).
        let button_pin = gpioa.pa0.into_pull_down_input();
        start_adc!(dp, rcc, gpioc, adc, spare);

        core.DCB.enable_trace();
        core.DWT.enable_cycle_counter();
        let clock = DwtClock {
            last: Cell::new(0),
            high: Cell::new(0),
        };
        let mut period = TickTimer::new();
        let phase = boot_phase!(boot, kept, reset, tick);

        // Tick monitor: TIM5 at 1 MHz, started by each tick, stopped when it ends.
        let mut monitor = dp.TIM5.counter_us(&mut rcc);
        monitor.listen(Event::Update);

        period.dt_s(&clock); // start the period measurement now
        adc.start(|_| {});
        let sampler = start_sampler(dp.TIM3, &mut rcc);

        (
            Shared {},
            Local {
                adc,
                spare: Some(spare),
                qei,
                scaling: [wiring::pressure_scaling(); 2],
                clock,
                period,
                valves,
                valve_enable,
                tick,
                latch,
                encoder_keep,
                button_pin,
                button: ResetButton::new(TICK_HZ * RESET_HOLD_MS / 1000),
                phase,
                watchdog,
                monitor,
                pins_forced: false,
                _sampler: sampler,
                fault_reported: false,
                ticks: 0,
            },
        )
    }

    /// The valve pins PD12..PD15 (inflate 1, exhaust 1, inflate 2, exhaust 2) and the
    /// valve-driver enable PD11 as outputs at the safe state's levels: the driver's supply
    /// first, off unless the safe state holds a valve open.
    #[inline(always)]
    fn safe_valve_pins(gpiod: gpio::gpiod::Parts) -> (PD11<Output<PushPull>>, ValvePins) {
        let lv = wiring::safe_valve_levels(SAFE_STATE);
        let st = |b: bool| if b { PinState::High } else { PinState::Low };
        let valve_enable = gpiod
            .pd11
            .into_push_pull_output_in_state(st(wiring::safe_valve_enable(SAFE_STATE)));
        let pd12 = gpiod.pd12.into_push_pull_output_in_state(st(lv[0]));
        let pd13 = gpiod.pd13.into_push_pull_output_in_state(st(lv[1]));
        let pd14 = gpiod.pd14.into_push_pull_output_in_state(st(lv[2]));
        let pd15 = gpiod.pd15.into_push_pull_output_in_state(st(lv[3]));
        (valve_enable, (pd12, pd13, pd14, pd15))
    }

    /// The valves on TIM4 CH1..CH4 (PD12..PD15), duties at the safe state before the pins
    /// switch to the timer.
    #[inline(always)]
    fn start_valves(tim4: TIM4, pins: ValvePins, rcc: &mut Rcc) -> Valves {
        let (pd12, pd13, pd14, pd15) = pins;
        let (_, (c1, c2, c3, c4)) = tim4.pwm_hz(VALVE_PWM_HZ.Hz(), rcc);
        let mut chans = [
            c1.with(pd12).erase(),
            c2.with(pd13).erase(),
            c3.with(pd14).erase(),
            c4.with(pd15).erase(),
        ];
        for c in chans.iter_mut() {
            c.enable();
        }
        let [c1, c2, c3, c4] = chans;
        let mut valves: Valves = ProportionalValves::new(c1, c2, c3, c4);
        let _ = valves.apply(&SAFE_STATE.command());
        valves
    }

    /// The encoder on TIM2 (PA15 / PB3). The counter starts at 0 (the encoder zero is the
    /// pose at reset), or, after a reset that is not a power-on, carries on from the count
    /// kept in the backup SRAM (the joint does not move in the milliseconds of a reset);
    /// returns that count too.
    #[inline(always)]
    fn start_encoder(
        tim2: TIM2,
        pins: (PA15<Input>, PB3<Input>),
        rcc: &mut Rcc,
        encoder_keep: &EncoderKeep,
        reset: latch::ResetCause,
    ) -> (Qei<TIM2>, Option<i32>) {
        let qei = Qei::new(tim2, pins, rcc);
        let kept = latch::encoder_at_boot(encoder_keep.read(), reset);
        if let Some(c) = kept {
            // SAFETY: TIM2's counter register, owned by `qei`, written once before it is read.
            unsafe { (*pac::TIM2::ptr()).cnt().write(|w| w.bits(c as u32)) };
        }
        (qei, kept)
    }

    /// TIM3 at the tick rate, its update as TRGO: each period starts one ADC scan (and so one
    /// tick). Logs the board's configuration.
    #[inline(always)]
    fn start_sampler(tim3: TIM3, rcc: &mut Rcc) -> CounterHz<TIM3> {
        let mut sampler = tim3.counter_hz(rcc);
        // TRGO on update: each period starts one ADC scan.
        // SAFETY: CR2.MMS of TIM3, which `sampler` owns and does not use otherwise.
        unsafe { (*pac::TIM3::ptr()).cr2().modify(|_, w| w.mms().update()) };
        if sampler.start(TICK_HZ.Hz()).is_err() {
            // No ticks: the watchdog is not fed and resets into a latched safe boot.
            defmt::error!("TIM3 did not start");
        }
        defmt::info!(
            "pam-firmware board (RTIC 2): tick {=u32} Hz from TIM3 -> ADC1 -> DMA2, \
             deadline {=u32} us, watchdog {=u32} ms, scenario {=str}",
            TICK_HZ,
            DEADLINE_US,
            WATCHDOG_MS,
            BOARD_SCENARIO
        );
        sampler
    }

    #[idle]
    fn idle(_: idle::Context) -> ! {
        loop {
            cortex_m::asm::wfi();
        }
    }

    /// The tick monitor: the tick did not end by its deadline. Safe valve levels at register
    /// level (this task preempts the tick), counted; the tick latches the fault when it ends.
    #[task(binds = TIM5, priority = 3)]
    fn tick_monitor(_: tick_monitor::Context) {
        // SAFETY: TIM5's SR and CR1 (stop, clear the update flag): the tick only starts and
        // stops the counter, it cannot run while this higher-priority task runs. The pins:
        // the highest-priority code touching GPIOD's MODER (see force_safe_valve_pins).
        unsafe {
            let tim5 = &*pac::TIM5::ptr();
            tim5.cr1().modify(|_, w| w.cen().clear_bit());
            tim5.sr().write(|w| w.bits(!1u32));
            super::force_safe_valve_pins();
        }
        PAM_MONITOR_TRIPS.fetch_add(1, Ordering::Relaxed);
        MONITOR_TRIPPED.store(true, Ordering::Release);
    }

    /// The control tick: once per sampling period, when the DMA has delivered both pressures.
    #[task(binds = DMA2_STREAM0, priority = 2, local = [adc, spare, qei, scaling, clock, period, valves, valve_enable, tick, latch, encoder_keep, button_pin, button, phase, watchdog, monitor, pins_forced, fault_reported, ticks])]
    fn control_tick(cx: control_tick::Context) {
        let mut l = cx.local;
        let start = DWT::cycle_count();
        let _ = l.monitor.start(DEADLINE_US.micros());
        l.adc.clear_transfer_complete();
        let counts = match l.spare.take() {
            Some(buf) => match l.adc.next_transfer(buf) {
                Ok((done, _)) => {
                    let c = wiring::take_fresh_counts(done);
                    *l.spare = Some(done);
                    c
                }
                // Not expected (single buffer); no samples this tick: the tick ages them.
                Err(_) => [None; 2],
            },
            None => [None; 2],
        };
        let encoder_counts = l.qei.count() as i32;
        l.encoder_keep.write(latch::encoder_words(encoder_counts));
        // Keep the period measurement current in every phase.
        let dt_s = l.period.dt_s(l.clock);

        match l.phase {
            Phase::Calibrating {
                ticks,
                sum_counts,
                n,
            } => {
                let _ = l.valves.apply(&SafeState::Vent.command());
                l.valve_enable.set_high();
                if *ticks >= CAL_VENT_TICKS {
                    for i in 0..2 {
                        if let Some(c) = counts[i] {
                            sum_counts[i] = sum_counts[i].saturating_add(c as u32);
                            n[i] += 1;
                        }
                    }
                }
                *ticks += 1;
                if *ticks >= CAL_TICKS {
                    let codes = [
                        FaultCode::PressureImplausible1,
                        FaultCode::PressureImplausible2,
                    ];
                    for i in 0..2 {
                        match wiring::calibrated_pressure_scaling(sum_counts[i], n[i]) {
                            Ok(s) => {
                                l.scaling[i] = s;
                                defmt::info!(
                                    "pressure {=usize} zero: {=f32} counts",
                                    i + 1,
                                    -s.offset_pa / s.pa_per_count
                                );
                            }
                            Err(e) => {
                                defmt::error!("pressure {=usize} zero refused: {}", i + 1, e);
                                l.tick.restore_latch(&LatchRecord {
                                    cause: Some(codes[i]),
                                    seen: FaultSet::of(codes[i]),
                                    vented: [false; 2],
                                });
                            }
                        }
                    }
                    *l.phase = Phase::Running;
                }
            }
            Phase::Running => run(&mut l, counts, encoder_counts, dt_s),
        }

        // Deadline: done within DEADLINE_PERCENT of the period, and the next samples have not
        // arrived meanwhile (their interrupt would be pending). Only then feed the watchdog.
        let _ = l.monitor.cancel();
        let budget = SYSCLK_HZ / TICK_HZ / 100 * DEADLINE_PERCENT;
        let on_time = DWT::cycle_count().wrapping_sub(start) <= budget
            && !NVIC::is_pending(Interrupt::DMA2_STREAM0);
        if on_time {
            l.watchdog.feed();
        } else {
            PAM_TICK_OVERRUNS.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// One control tick proper (phase `Running`).
    fn run(
        l: &mut control_tick::LocalResources<'_>,
        counts: [Option<u16>; 2],
        encoder_counts: i32,
        dt_s: f32,
    ) {
        let s = *l.scaling;
        let frame = SensorFrame {
            p1_gauge_pa: counts[0].map(|c| s[0].to_gauge_pa(c as u32)),
            p2_gauge_pa: counts[1].map(|c| s[1].to_gauge_pa(c as u32)),
            angle_rad: Some(wiring::angle_rad(encoder_counts)),
        };
        let t_s = *l.ticks as f32 / TICK_HZ as f32;
        let setpoint_rad = BOARD_PROFILE.at(t_s);
        // Measured period: a late tick (> dt_max_s) latches FaultCode::Watchdog in the tick.
        let out = l.tick.step(
            &frame,
            &Setpoint {
                angle_rad: setpoint_rad,
            },
            dt_s,
        );
        // The tick outputs the safe valve command itself while a fault is latched.
        // The openings the driver actually switched feed the valve / supply residual.
        let applied = match l.valves.apply(&out.valves) {
            Ok(o) => {
                l.tick.valves_applied(&o);
                o
            }
            Err(_) => {
                let _ = l.valves.close_all();
                ValveOpenings::from_command(&SafeState::Hold.command())
            }
        };
        // The tick monitor fired during this tick: latch it; the pins go back to the PWM
        // once the tick outputs the safe command (from the next tick on).
        if MONITOR_TRIPPED.swap(false, Ordering::Acquire) {
            l.tick.restore_latch(&LatchRecord {
                cause: Some(FaultCode::Watchdog),
                seen: FaultSet::of(FaultCode::Watchdog),
                vented: [false; 2],
            });
            *l.pins_forced = true;
        } else if *l.pins_forced && l.tick.fault().is_some() {
            // SAFETY: MODER of GPIOD; the monitor (the only other writer) is not armed here
            // (it is started by the tick and has not fired in this tick).
            unsafe {
                (*pac::GPIOD::ptr())
                    .moder()
                    .modify(|r, w| w.bits(wiring::valve_moder_alternate(r.bits())));
            }
            *l.pins_forced = false;
        }
        // The drivers' supply: on while armed, and while faulted only if the safe command
        // opens a valve; with the pins forced by the monitor, that of the safe state.
        let enable = if *l.pins_forced {
            wiring::safe_valve_enable(SAFE_STATE)
        } else {
            wiring::valve_enable(out.armed, &out.valves)
        };
        if enable {
            l.valve_enable.set_high();
        } else {
            l.valve_enable.set_low();
        }
        // Operator's reset: accepted by the tick only when every cause is gone.
        if l.button.update(l.button_pin.is_high()) {
            if l.tick.reset() {
                l.latch.cleared();
                *l.fault_reported = false;
                defmt::info!("reset accepted: armed");
            } else {
                defmt::warn!("reset refused: a cause persists");
            }
        }
        l.latch.update(l.tick.latch_record());
        if let Some(f) = out.fault {
            if !*l.fault_reported {
                *l.fault_reported = true;
                defmt::error!("fault latched: {}; valves in the safe state", f);
            }
        }
        // The stream record of this tick (docs/rig.md).
        let rec = TickRecord::of_tick(
            *l.ticks,
            l.ticks.wrapping_mul(US_PER_TICK),
            setpoint_rad,
            counts.map(|c| c.unwrap_or(MISSING_COUNTS)),
            encoder_counts,
            &frame,
            &out,
            [applied.u_in1, applied.u_ex1, applied.u_in2, applied.u_ex2],
        );
        rec.log();
        *l.ticks = l.ticks.wrapping_add(1);
        if *l.ticks % TICK_HZ == 0 {
            defmt::info!(
                "t={=u32}s angle={=f32} rad p1={=f32} Pa p2={=f32} Pa armed={=bool} overruns={=u32} monitor={=u32}",
                *l.ticks / TICK_HZ,
                out.angle_est_rad,
                rec.p_gauge_pa[0],
                rec.p_gauge_pa[1],
                out.armed,
                PAM_TICK_OVERRUNS.load(Ordering::Relaxed),
                PAM_MONITOR_TRIPS.load(Ordering::Relaxed)
            );
        }
    }
}

/// Panic: log the location (not the message: see Cargo.toml), then fault (valves safe below).
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
    // The valve pins to the configured safe state at register level (the HAL objects may be
    // borrowed; a BSRR write alone would not reach pins on the timer's alternate function).
    // SAFETY: nothing else runs any more.
    unsafe { force_safe_valve_pins() };
    // The watchdog is no longer fed: it resets the MCU, which boots into the safe state.
    loop {
        cortex_m::asm::nop();
    }
}
