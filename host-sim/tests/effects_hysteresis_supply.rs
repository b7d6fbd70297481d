//! `[effects.muscle_hysteresis]` (braid friction in the muscle tension) and
//! `[effects.supply_drop]` (static line drop, or a reservoir with its own state): each changes
//! what it should and only that, `enabled = false` is bit-identical to the nominal model,
//! TOML errors name the key, hysteresis dissipates, a supply drop slows inflation and
//! recovers at rest.

mod common;
use common::*;

use host_sim::plant::effects::{static_supply_pressure_pa, Supply};
use host_sim::plant::PlantState;
use host_sim::sim::{simulate, Integrator, SolverOptions};
use host_sim::{Plant, PlantConfig, ValveInputs};

fn nominal() -> Plant {
    plant_with("")
}

fn load_err(extra: &str) -> String {
    let text = format!("{}\n{extra}\n", nominal_text());
    match PlantConfig::from_toml_str(&text, "bad-effects.toml") {
        Ok(_) => panic!("expected an error for:\n{extra}"),
        Err(e) => e.to_string(),
    }
}

const HYSTERESIS: &str = "[effects.muscle_hysteresis]\nbase_force_n = 2.0\n\
    pressure_gain_n_per_pa = 1.5e-5\nsmoothing_rate_per_s = 0.01\n";
const STATIC_DROP: &str =
    "[effects.supply_drop]\nmodel = \"static\"\nresistance_pa_s_per_m3 = 9.0e6\n";
const RESERVOIR: &str = "[effects.supply_drop]\nmodel = \"reservoir\"\n\
    tank_volume_m3 = 5.0e-4\nfeed_conductance_m3_per_s_pa = 1.5e-8\n";

fn run(plant: &Plant) -> Vec<PlantState> {
    simulate(
        plant,
        &pulse_inputs(6000, 500),
        1e-3,
        &SolverOptions::default(),
    )
    .unwrap_or_else(|e| panic!("{e}"))
    .states
}

#[test]
fn disabled_effects_are_bit_identical_to_the_nominal_model() {
    let base = nominal();
    let states = run(&base);
    let meas = base.measure_series(&states, 1e-3);
    for table in [HYSTERESIS, STATIC_DROP, RESERVOIR] {
        let off = table.replacen('\n', "\nenabled = false\n", 1);
        let p = plant_with(&off);
        assert_eq!(p.effects, base.effects, "{off}");
        let s = run(&p);
        assert_eq!(s, states, "{off}");
        assert_eq!(p.measure_series(&s, 1e-3), meas, "{off}");
    }
    // Sanity of the excitation: the joint really moves both ways.
    let (lo, hi) = states.iter().fold((0.0f64, 0.0f64), |(lo, hi), x| {
        (lo.min(x.angle_rad), hi.max(x.angle_rad))
    });
    assert!(lo < -0.1 && hi > 0.1, "{lo} {hi}");
}

#[test]
fn toml_errors_name_the_key() {
    let cases = [
        (
            HYSTERESIS.replace("base_force_n = 2.0", "base_force_n = -1.0"),
            "effects.muscle_hysteresis.base_force_n",
        ),
        (
            HYSTERESIS.replace("smoothing_rate_per_s = 0.01", "smoothing_rate_per_s = 0.0"),
            "effects.muscle_hysteresis.smoothing_rate_per_s",
        ),
        (
            HYSTERESIS.replace("base_force_n", "base_forse_n"),
            "base_forse_n",
        ),
        (
            HYSTERESIS.replace("pressure_gain_n_per_pa = 1.5e-5\n", ""),
            "pressure_gain_n_per_pa",
        ),
        (
            STATIC_DROP.replace("resistance_pa_s_per_m3 = 9.0e6\n", ""),
            "effects.supply_drop.resistance_pa_s_per_m3",
        ),
        (
            STATIC_DROP.replace("9.0e6", "-1.0"),
            "effects.supply_drop.resistance_pa_s_per_m3",
        ),
        (
            format!("{STATIC_DROP}tank_volume_m3 = 1e-3\n"),
            "effects.supply_drop.tank_volume_m3",
        ),
        (
            RESERVOIR.replace("tank_volume_m3 = 5.0e-4\n", ""),
            "effects.supply_drop.tank_volume_m3",
        ),
        (
            RESERVOIR.replace("1.5e-8", "0.0"),
            "effects.supply_drop.feed_conductance_m3_per_s_pa",
        ),
        (
            format!("{RESERVOIR}resistance_pa_s_per_m3 = 1e6\n"),
            "effects.supply_drop.resistance_pa_s_per_m3",
        ),
        (RESERVOIR.replace("reservoir", "tank"), "model"),
        (RESERVOIR.replace("model = \"reservoir\"\n", ""), "model"),
        (format!("{RESERVOIR}tank_pressure = 1.0\n"), "tank_pressure"),
    ];
    for (extra, key) in cases {
        let e = load_err(&extra);
        assert!(e.contains(key), "expected `{key}` in: {e}");
        assert!(e.contains("bad-effects.toml"), "{e}");
    }
}

#[test]
fn hysteresis_acts_on_the_muscle_tension_only_while_moving() {
    let h = plant_with(HYSTERESIS);
    let n = nominal();
    let mut x = n.initial_state();
    x.angle_rad = 0.1;
    x.p1_abs_pa += 50_000.0;
    // At rest: no friction force, identical tensions and derivatives.
    assert_eq!(h.tensions_n(&x), n.tensions_n(&x));
    let u = ValveInputs {
        u_in1: 1.0,
        ..ValveInputs::CLOSED
    };
    assert_eq!(h.derivatives(&x, &u), n.derivatives(&x, &u));

    // Moving: muscle 1 contracts (omega > 0), so it pulls less by F_h(pg1); muscle 2 is
    // stretched and pulls more by F_h(pg2); the pressure derivatives are unchanged.
    x.velocity_rad_s = 0.5;
    let rate = 0.025 / 0.25 * 0.5;
    let fh = |pg: f64| (2.0 + 1.5e-5 * pg) * (rate / 0.01f64).tanh();
    let (th, tn) = (h.tensions_n(&x), n.tensions_n(&x));
    let pg1 = x.p1_abs_pa - n.p_atm_pa;
    let pg2 = x.p2_abs_pa - n.p_atm_pa;
    assert!((tn[0] - th[0] - fh(pg1)).abs() < 1e-9, "{th:?} {tn:?}");
    assert!((th[1] - tn[1] - fh(pg2)).abs() < 1e-9, "{th:?} {tn:?}");
    let (dh, dn) = (h.derivatives(&x, &u), n.derivatives(&x, &u));
    assert_eq!(dh.p1_abs_pa, dn.p1_abs_pa);
    assert_eq!(dh.p2_abs_pa, dn.p2_abs_pa);
    assert_eq!(dh.angle_rad, dn.angle_rad);
    let torque = (dh.velocity_rad_s - dn.velocity_rad_s) * 0.014;
    assert!(
        (torque + (fh(pg1) + fh(pg2)) * 0.025).abs() < 1e-9,
        "{torque}"
    );

    // Joint friction, in contrast, decelerates the joint without touching the tensions.
    let jf = plant_with(
        "[effects.joint_friction]\ncoulomb_nm = 0.3\nbreakaway_nm = 0.3\n\
         stribeck_velocity_rad_s = 0.1\nviscous_nm_s_per_rad = 0.0\nsmoothing_velocity_rad_s = 0.01\n",
    );
    assert_eq!(jf.tensions_n(&x), tn);
    assert!(jf.derivatives(&x, &u).velocity_rad_s < dn.velocity_rad_s);
}

#[test]
fn hysteresis_always_dissipates() {
    let h = plant_with(HYSTERESIS);
    let n = nominal();
    let mut strict = 0;
    for ia in -4..=4 {
        for iw in -6..=6 {
            for (g1, g2) in [(0.0, 0.0), (1e5, 5e5), (5.5e5, 5.5e5), (6e5, 2e4)] {
                let x = PlantState {
                    angle_rad: 0.08 * ia as f64,
                    velocity_rad_s: 0.3 * iw as f64 * (iw as f64).abs(),
                    p1_abs_pa: n.p_atm_pa + g1,
                    p2_abs_pa: n.p_atm_pa + g2,
                };
                let dw = h.derivatives(&x, &ValveInputs::CLOSED).velocity_rad_s
                    - n.derivatives(&x, &ValveInputs::CLOSED).velocity_rad_s;
                // Power of the friction torque on the joint: never positive.
                let power = dw * 0.014 * x.velocity_rad_s;
                assert!(power <= 0.0, "{x:?}: {power}");
                if power < -1e-6 {
                    strict += 1;
                }
            }
        }
    }
    assert!(strict > 200, "{strict}");

    // A joint launched at 3 rad/s with the valves closed dissipates its kinetic energy
    // sooner with braid friction: it travels a shorter way before it stops.
    let excursion = |p: &Plant| {
        let mut x0 = p.initial_state();
        x0.velocity_rad_s = 3.0;
        let mut integ = Integrator::new(p, x0, SolverOptions::default());
        let mut peak = 0.0f64;
        for _ in 0..300 {
            peak = peak.max(integ.advance(ValveInputs::CLOSED, 1e-3).unwrap().angle_rad);
        }
        peak
    };
    let (eh, en) = (excursion(&h), excursion(&n));
    assert!(eh < 0.97 * en, "with friction {eh} rad, nominal {en} rad");
}

#[test]
fn hysteresis_shows_in_the_measured_forces_against_the_nominal_force_law() {
    // The diagnosis signature: with braid friction the measured tension departs from the
    // nominal tension of the measured state, opposite to the contraction rate; joint
    // friction changes the motion but leaves that relation exact.
    let n = nominal();
    for (extra, expect_force_residual) in [
        (HYSTERESIS, true),
        (
            "[effects.joint_friction]\ncoulomb_nm = 0.4\nbreakaway_nm = 0.4\n\
             stribeck_velocity_rad_s = 0.1\nviscous_nm_s_per_rad = 0.0\nsmoothing_velocity_rad_s = 0.01\n",
            false,
        ),
    ] {
        let p = plant_with(extra);
        let states = run(&p);
        let meas = p.measure_series(&states, 1e-3);
        let mut max_abs = 0.0f64;
        let mut against_rate = 0usize;
        let mut moving = 0usize;
        for (x, m) in states.iter().zip(&meas) {
            let r = m.f1_n - n.tensions_n(x)[0];
            max_abs = max_abs.max(r.abs());
            if x.velocity_rad_s.abs() > 0.2 && n.tensions_n(x)[0] > 50.0 {
                moving += 1;
                if r * x.velocity_rad_s < 0.0 {
                    against_rate += 1;
                }
            }
        }
        if expect_force_residual {
            assert!(max_abs > 3.0, "{max_abs}");
            assert!(moving > 100 && against_rate == moving, "{against_rate}/{moving}");
        } else {
            assert!(max_abs < 1e-9, "{max_abs}");
        }
        // And the motion differs from the nominal one in both cases.
        let nominal_states = run(&n);
        let d = states
            .iter()
            .zip(&nominal_states)
            .map(|(a, b)| (a.angle_rad - b.angle_rad).abs())
            .fold(0.0, f64::max);
        assert!(d > 1e-3, "{extra}: {d}");
    }
}

#[test]
fn static_drop_matches_the_choked_closed_form_and_solves_subsonic_flow() {
    let p = plant_with(STATIC_DROP);
    let Supply::Static {
        resistance_pa_s_per_m3: r,
    } = *p.effects.supply()
    else {
        panic!("{:?}", p.effects.supply())
    };
    let ps0 = p.p_supply_abs_pa;
    let c = p.valve.sonic_conductance_m3_per_s_pa;
    // Choked (p_i / p_s below the critical ratio): Q = C p_s u, so p_s = p_s0 / (1 + R C sum u).
    let low = [150_000.0, 200_000.0];
    for u in [[1.0, 0.0], [1.0, 1.0], [0.3, 0.6]] {
        let ps = static_supply_pressure_pa(&p.valve, ps0, r, low, u);
        let exact = ps0 / (1.0 + r * c * (u[0] + u[1]));
        assert!((ps - exact).abs() < 1e-3, "{u:?}: {ps} vs {exact}");
    }
    // Subsonic and laminar: the returned pressure satisfies p = p_s0 - R q(p).
    for pc in [
        [500_000.0, 650_000.0],
        [690_000.0, 700_000.0],
        [701_000.0, 100_000.0],
    ] {
        let u = [1.0, 1.0];
        let ps = static_supply_pressure_pa(&p.valve, ps0, r, pc, u);
        let q: f64 = (0..2).map(|i| u[i] * p.valve.flow_m3_s(ps, pc[i])).sum();
        assert!((ps - (ps0 - r * q)).abs() < 1e-6, "{pc:?}: {ps}");
        assert!(ps <= ps0 && ps >= pc[0].min(pc[1]).min(ps0), "{ps}");
    }
    // Closed inlets: no drop.
    assert_eq!(
        static_supply_pressure_pa(&p.valve, ps0, r, low, [0.0, 0.0]),
        ps0
    );
}

/// Starts both muscles at 100 kPa gauge (an equilibrium at angle 0, by symmetry).
fn low_pressure_plant(extra: &str) -> Plant {
    let text = nominal_text()
        .replace("p1_gauge_pa = 550000.0", "p1_gauge_pa = 100000.0")
        .replace("p2_gauge_pa = 550000.0", "p2_gauge_pa = 100000.0");
    let text = format!("{text}\n{extra}\n");
    Plant::from_config(&PlantConfig::from_toml_str(&text, "low.toml").unwrap())
}

#[test]
fn supply_drop_slows_inflation_only() {
    for extra in [STATIC_DROP, RESERVOIR] {
        let d = low_pressure_plant(extra);
        let n = low_pressure_plant("");
        let x = n.initial_state();
        let inflate = ValveInputs {
            u_in1: 1.0,
            ..ValveInputs::CLOSED
        };
        let exhaust = ValveInputs {
            u_ex1: 1.0,
            u_ex2: 1.0,
            ..ValveInputs::CLOSED
        };
        // Right-hand side at the same state: only the inflow changes.
        let p_tank = n.p_supply_abs_pa - 80_000.0;
        let (dd, _) = d.derivatives_with_supply(&x, p_tank, &inflate);
        let dn = n.derivatives(&x, &inflate);
        assert!(dd.p1_abs_pa < dn.p1_abs_pa && dd.p1_abs_pa > 0.0, "{extra}");
        assert_eq!(dd.p2_abs_pa, dn.p2_abs_pa);
        assert_eq!(dd.velocity_rad_s, dn.velocity_rad_s);
        for u in [ValveInputs::CLOSED, exhaust] {
            assert_eq!(
                d.derivatives_with_supply(&x, p_tank, &u).0,
                n.derivatives(&x, &u)
            );
        }

        // Simulated: 0.3 s of inflating muscle 1 (both inlets), then rest.
        let inputs: Vec<ValveInputs> = (0..2500)
            .map(|k| {
                if k < 300 {
                    ValveInputs {
                        u_in1: 1.0,
                        u_in2: 1.0,
                        ..ValveInputs::CLOSED
                    }
                } else {
                    ValveInputs::CLOSED
                }
            })
            .collect();
        let opts = SolverOptions::default();
        let sd = simulate(&d, &inputs, 1e-3, &opts).unwrap().states;
        let sn = simulate(&n, &inputs, 1e-3, &opts).unwrap().states;
        // Slower inflation: p1 lags the nominal one by a clear margin after 50 ms.
        let gap = sn[50].p1_abs_pa - sd[50].p1_abs_pa;
        assert!(gap > 5_000.0, "{extra}: {gap}");
        for k in 1..300 {
            assert!(sd[k].p1_abs_pa <= sn[k].p1_abs_pa + 1e-6, "{extra} @ {k}");
        }
    }
}

#[test]
fn reservoir_sags_while_drawing_and_refills_at_rest() {
    let d = low_pressure_plant(RESERVOIR);
    assert!(d.has_supply_state());
    let ps0 = d.p_supply_abs_pa;
    let mut integ = Integrator::new(&d, d.initial_state(), SolverOptions::default());
    assert_eq!(integ.supply_abs_pa(), ps0);
    let both_in = ValveInputs {
        u_in1: 1.0,
        u_in2: 1.0,
        ..ValveInputs::CLOSED
    };
    let mut min_tank = ps0;
    for _ in 0..200 {
        integ.advance(both_in, 1e-3).unwrap();
        min_tank = min_tank.min(integ.supply_abs_pa());
    }
    // Realistic sag: tens of kPa below the 6 bar supply while two muscles fill.
    assert!(ps0 - min_tank > 20_000.0, "sag {}", ps0 - min_tank);
    // The muscles never exceed the tank pressure they are filled from by more than the
    // integration error.
    let x = integ.state();
    assert!(x.p1_abs_pa < integ.supply_abs_pa() + 1.0);
    // At rest the tank refills toward p_s0 (monotonically, within the solver tolerance).
    let mut prev = integ.supply_abs_pa();
    for _ in 0..3000 {
        integ.advance(ValveInputs::CLOSED, 1e-3).unwrap();
        let p = integ.supply_abs_pa();
        assert!(p >= prev - 1e-3 && p <= ps0 + 1e-3, "{prev} -> {p}");
        prev = p;
    }
    assert!(
        (ps0 - prev).abs() < 1.0,
        "after 3 s at rest: {}",
        ps0 - prev
    );

    // The same run through `simulate` (dense multi-sample segments) agrees with the
    // per-tick integrator.
    let inputs: Vec<ValveInputs> = (0..400)
        .map(|k| {
            if k < 200 {
                both_in
            } else {
                ValveInputs::CLOSED
            }
        })
        .collect();
    let s = simulate(&d, &inputs, 1e-3, &SolverOptions::default()).unwrap();
    let mut integ = Integrator::new(&d, d.initial_state(), SolverOptions::default());
    for u in &inputs {
        integ.advance(*u, 1e-3).unwrap();
    }
    let (a, b) = (s.final_state, integ.state());
    assert!((a.p1_abs_pa - b.p1_abs_pa).abs() < 50.0, "{a:?} {b:?}");
    assert!((a.angle_rad - b.angle_rad).abs() < 1e-4, "{a:?} {b:?}");
}
