//! The pressure loops' inverse thermodynamic feed-forward ([`crate::pressure_ff`]) inside the
//! control tick (compiled in with the `pressure-ff` feature:
//! `cargo test -p pam-firmware --lib --features pressure-ff`).

use crate::tick::{ControlTick, ControllerConfig, SensorFrame, Setpoint};

fn cfg(enabled: bool) -> ControllerConfig {
    let mut c = ControllerConfig::reference(1000.0);
    c.pressure_ff.enabled = enabled;
    c
}

fn frame(p1: f32, p2: f32, a: f32) -> SensorFrame {
    SensorFrame {
        p1_gauge_pa: Some(p1),
        p2_gauge_pa: Some(p2),
        angle_rad: Some(a),
    }
}

/// Runs two ticks (configurations `a` and `b`) side by side for 400 ticks of a sine
/// set-point on the frames `frame(k)`; checks that `b`'s valve commands stay finite and in
/// [-1, 1]; returns on how many ticks the two commands differ.
fn count_differing(
    a: ControllerConfig,
    b: ControllerConfig,
    frame: impl Fn(usize) -> SensorFrame,
) -> usize {
    let (mut ta, mut tb) = (ControlTick::new(a), ControlTick::new(b));
    let mut differ = 0;
    for k in 0..400 {
        let sp = Setpoint {
            angle_rad: 0.3 * libm::sinf(k as f32 * 0.02),
        };
        let f = frame(k);
        let x = ta.step(&f, &sp, 1e-3);
        let y = tb.step(&f, &sp, 1e-3);
        for u in [y.valves.muscle1, y.valves.muscle2] {
            assert!(u.is_finite() && (-1.0..=1.0).contains(&u), "{k}: {u}");
        }
        if x.valves != y.valves {
            differ += 1;
        }
    }
    differ
}

#[test]
fn the_feed_forward_reaches_the_valves_and_stays_in_range() {
    let differ = count_differing(cfg(false), cfg(true), |k| {
        frame(550e3 + 100.0 * k as f32, 550e3 - 100.0 * k as f32, 0.0)
    });
    // The frames do not follow the commands (the supervision faults both ticks after a
    // while, then both hold the safe state); before that the feed-forward shows.
    assert!(differ > 0, "the feed-forward never changed a valve command");
}

#[test]
fn the_evaluation_period_reaches_the_tick() {
    // Evaluated once every 10 ticks against every tick, on the same frames: the commands
    // differ (and stay in range: `count_differing`); a period out of its range is a
    // configuration fault.
    let mut every_tenth = cfg(true);
    every_tenth.pressure_ff.update_period_ticks = 10;
    let differ = count_differing(cfg(true), every_tenth, |k| {
        frame(300e3 + 100.0 * k as f32, 300e3 - 100.0 * k as f32, 0.0)
    });
    assert!(differ > 0, "the period never changed a valve command");
    every_tenth.pressure_ff.update_period_ticks = 0;
    assert!(!every_tenth.is_valid());
}

#[test]
fn a_bad_sensor_still_gives_the_safe_state_and_a_bad_constant_is_a_config_fault() {
    let mut t = ControlTick::new(cfg(true));
    let sp = Setpoint { angle_rad: 0.2 };
    t.step(&frame(550e3, 550e3, 0.0), &sp, 1e-3);
    for bad in [f32::NAN, f32::INFINITY, -1e9] {
        let o = t.step(&frame(bad, 550e3, 0.0), &sp, 1e-3);
        assert!(o.valves.muscle1.is_finite() && o.valves.muscle2.is_finite());
    }
    let mut c = cfg(true);
    c.pressure_ff.polytropic_index = f32::NAN;
    assert!(!c.is_valid());
    let mut t = ControlTick::new(c);
    let o = t.step(&frame(550e3, 550e3, 0.0), &sp, 1e-3);
    assert!(!o.armed);
    assert_eq!(
        o.valves,
        ControlTick::new(cfg(false))
            .step(&frame(f32::NAN, 0.0, 0.0), &sp, 1e-3)
            .valves
    );
}

/// The hybrid model's learned volume in the tick's feed-forward (compiled in with the
/// `volume-fnn` feature: `cargo test -p pam-firmware --lib --features volume-fnn`).
#[cfg(feature = "volume-fnn")]
mod hybrid {
    use crate::tick::{ControlTick, ControllerConfig, SensorFrame, Setpoint};

    fn cfg(fnn: Option<&'static crate::volume_fnn::VolumeFnn>) -> ControllerConfig {
        let mut c = ControllerConfig::reference(1000.0);
        c.pressure_ff.enabled = true;
        c.volume_fnn = fnn;
        c
    }

    #[test]
    fn the_learned_volume_changes_the_duty_and_stays_in_range() {
        let net = &crate::constants::VOLUME_FNN;
        let differ = super::count_differing(cfg(None), cfg(Some(net)), |k| SensorFrame {
            p1_gauge_pa: Some(300e3 + 50.0 * k as f32),
            p2_gauge_pa: Some(300e3 - 50.0 * k as f32),
            angle_rad: Some(0.1 * libm::sinf(k as f32 * 0.01)),
        });
        assert!(
            differ > 0,
            "the learned volume never changed a valve command"
        );
    }

    #[test]
    fn bad_weights_are_a_config_fault() {
        static BAD: crate::volume_fnn::VolumeFnn = {
            let mut n = crate::constants::VOLUME_FNN;
            n.volume_floor_m3 = -1.0;
            n
        };
        let c = cfg(Some(&BAD));
        assert!(!c.is_valid());
        let mut t = ControlTick::new(c);
        let f = SensorFrame {
            p1_gauge_pa: Some(300e3),
            p2_gauge_pa: Some(300e3),
            angle_rad: Some(0.0),
        };
        let o = t.step(&f, &Setpoint { angle_rad: 0.1 }, 1e-3);
        assert!(!o.armed);
        assert!(cfg(Some(&crate::constants::VOLUME_FNN)).is_valid());
    }
}
