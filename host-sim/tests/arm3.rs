//! The 3-DOF arm of seed 001 (`host_sim::plant::arm3`): the rigid-body terms (M, C, G),
//! energy conservation, static equilibrium under gravity and friction, seed 001's stated
//! numbers, and the 1-DOF special case against the 1-DOF plant.

mod common;
use common::*;

use host_sim::fit::fit_percent;
use host_sim::io::arm3::PressureStepScenario;
use host_sim::io::recording::Channel;
use host_sim::plant::arm3::{Arm3, Arm3Config, Arm3Inputs, Arm3State, Links};
use host_sim::sim::arm3::{simulate_arm3, Arm3Integrator};
use host_sim::sim::{simulate, SolverOptions};
use host_sim::{Plant, PlantConfig, Recording, ValveInputs};
use nalgebra::{Matrix3, SVector, Vector3};
use ode_solvers::{Dopri5, System};

fn seed_arm() -> Arm3 {
    Arm3::load(arm3_plant()).unwrap_or_else(|e| panic!("{e}"))
}

fn grid() -> Vec<[f64; 3]> {
    let mut v = Vec::new();
    let n = 13;
    for a in 0..n {
        for b in 0..n {
            let q2 = -std::f64::consts::PI + 2.0 * std::f64::consts::PI * a as f64 / (n - 1) as f64;
            let q3 = -std::f64::consts::PI + 2.0 * std::f64::consts::PI * b as f64 / (n - 1) as f64;
            v.push([0.3 * a as f64, q2 + 0.01, q3 - 0.02]);
        }
    }
    v
}

const CLOSED: Arm3Inputs = [ValveInputs::CLOSED; 3];

#[test]
fn seed_file_has_the_paper_values() {
    let c = Arm3Config::load(arm3_plant()).unwrap();
    assert_eq!(c.links.inertia_x2_kgm2, 0.0514);
    assert_eq!(c.links.mass2_kg, 11.7805);
    assert_eq!(c.links.length2_m, 0.8099);
    assert_eq!(c.joint1.friction.cubic_nm_s3_per_rad3, 7.7218);
    assert_eq!(c.joint3.friction.quadratic_nm_s2_per_rad2, 0.4850);
    assert_eq!(c.joint2.muscle.volume_poly_m3[3], -1.538e-2);
    assert_eq!(c.valve.critical_ratio, 0.433);
}

#[test]
fn mass_matrix_is_symmetric_positive_definite_over_a_grid() {
    let links = seed_arm().links;
    for q in grid() {
        let m = links.mass_matrix(&q);
        assert!((m - m.transpose()).amax() == 0.0, "{m}");
        let eig = m.symmetric_eigen().eigenvalues;
        assert!(eig.min() > 1e-3, "M not positive definite at {q:?}: {eig}");
        assert!(m.cholesky().is_some());
    }
}

/// d f / d q[k] at `q` by central differences (step 1e-6 rad).
fn central_difference<T>(q: [f64; 3], k: usize, f: impl Fn(&[f64; 3]) -> T) -> T
where
    T: std::ops::Sub<Output = T> + std::ops::Div<f64, Output = T>,
{
    let h = 1e-6;
    let (mut qp, mut qm) = (q, q);
    qp[k] += h;
    qm[k] -= h;
    (f(&qp) - f(&qm)) / (2.0 * h)
}

/// At every grid point and for each joint k: the analytic partial `partial(q, k)` against the
/// central difference of `f` in `q[k]`, the size (`size`) of their difference below `tol`;
/// `what` names the partial in the message.
fn assert_partials_match<T>(
    what: &str,
    partial: impl Fn(&[f64; 3], usize) -> T,
    f: impl Fn(&[f64; 3]) -> T,
    size: impl Fn(T) -> f64,
    tol: f64,
) where
    T: Copy + std::fmt::Display + std::ops::Sub<Output = T> + std::ops::Div<f64, Output = T>,
{
    for q in grid() {
        for k in 0..3 {
            let fd = central_difference(q, k, &f);
            let d = partial(&q, k);
            assert!(size(fd - d) < tol, "{what}{} at {q:?}: {d} vs {fd}", k + 1);
        }
    }
}

#[test]
fn mass_matrix_partials_match_finite_differences() {
    let links = seed_arm().links;
    let partial = |q: &[f64; 3], k: usize| links.mass_matrix_partials(q)[k];
    assert_partials_match(
        "dM/dq",
        partial,
        |q| links.mass_matrix(q),
        |e| e.amax(),
        1e-7,
    );
}

#[test]
fn m_dot_minus_two_c_is_skew_symmetric() {
    let links = seed_arm().links;
    let qd = [0.7, -1.3, 2.1];
    for q in grid() {
        // M' along the motion by central differences (independent of the analytic partials).
        let h = 1e-6;
        let qp: [f64; 3] = std::array::from_fn(|i| q[i] + h * qd[i]);
        let qm: [f64; 3] = std::array::from_fn(|i| q[i] - h * qd[i]);
        let m_dot = (links.mass_matrix(&qp) - links.mass_matrix(&qm)) / (2.0 * h);
        let n = m_dot - 2.0 * links.coriolis_matrix(&q, &qd);
        assert!(
            (n + n.transpose()).amax() < 1e-6,
            "M' - 2C not skew at {q:?}: {n}"
        );
        // ... which makes q'^T (M' - 2C) q' vanish.
        let v = Vector3::from(qd);
        assert!(v.dot(&(n * v)).abs() < 1e-6);
    }
}

/// C of seed 001 eqs. 2-4 written out (Murray, Li, Sastry 1994 eq. 4.23 with their l1, r1,
/// r2 = our l2, lc2, lc3).
fn seed001_coriolis(l: &Links, q: &[f64; 3], qd: &[f64; 3]) -> Matrix3<f64> {
    let (s2, c2) = q[1].sin_cos();
    let (s23, c23) = (q[1] + q[2]).sin_cos();
    let s3 = q[2].sin();
    let g112 = (l.iy2 - l.iz2 - l.m2 * l.lc2 * l.lc2) * c2 * s2 + (l.iy3 - l.iz3) * c23 * s23
        - l.m3 * (l.l2 * c2 + l.lc3 * c23) * (l.l2 * s2 + l.lc3 * s23);
    let g113 = (l.iy3 - l.iz3) * c23 * s23 - l.m3 * l.lc3 * s23 * (l.l2 * c2 + l.lc3 * c23);
    let g223 = -l.l2 * l.m3 * l.lc3 * s3;
    let [w1, w2, w3] = *qd;
    Matrix3::new(
        g112 * w2 + g113 * w3,
        g112 * w1,
        g113 * w1,
        -g112 * w1,
        g223 * w3,
        g223 * (w2 + w3),
        -g113 * w1,
        -g223 * w2,
        0.0,
    )
}

#[test]
fn coriolis_matches_the_closed_form_of_seed001() {
    let links = seed_arm().links;
    for (i, q) in grid().into_iter().enumerate() {
        let qd = [0.5 + 0.01 * i as f64, -0.8, 1.7 - 0.02 * i as f64];
        let ours = links.coriolis_matrix(&q, &qd);
        let paper = seed001_coriolis(&links, &q, &qd);
        assert!((ours - paper).amax() < 1e-12, "{q:?}: {ours} vs {paper}");
    }
}

#[test]
fn gravity_is_the_gradient_of_the_potential_and_spares_joint_1() {
    let links = seed_arm().links;
    for q in grid() {
        assert_eq!(links.gravity_torques_nm(&q)[0], 0.0);
    }
    let partial = |q: &[f64; 3], k: usize| links.gravity_torques_nm(q)[k];
    assert_partials_match(
        "G",
        partial,
        |q| links.potential_energy_j(q),
        f64::abs,
        1e-6,
    );
    // Link 2 horizontal, link 3 in line: the whole weight moment on joint 2.
    let g = links.gravity_torques_nm(&[0.0, 0.0, 0.0]);
    let expect = 9.80665 * (11.7805 * 0.555 + 4.8147 * 0.8099 + 4.8147 * 0.191);
    assert!((g[1] - expect).abs() < 1e-9);
}

/// The rigid arm alone (no muscles): state (q, q').
struct Mechanics {
    links: Links,
    friction: Option<[host_sim::plant::arm3::Eq7Friction; 3]>,
}

impl System<f64, SVector<f64, 6>> for Mechanics {
    fn system(&self, _t: f64, y: &SVector<f64, 6>, dy: &mut SVector<f64, 6>) {
        let q = [y[0], y[1], y[2]];
        let qd = [y[3], y[4], y[5]];
        let fr = match &self.friction {
            None => [0.0; 3],
            Some(f) => std::array::from_fn(|i| f[i].torque_nm(qd[i])),
        };
        let a = self.links.acceleration(&q, &qd, &[0.0; 3], &fr);
        for i in 0..3 {
            dy[i] = qd[i];
            dy[3 + i] = a[i];
        }
    }
}

fn energies(links: &Links, friction: Option<[host_sim::plant::arm3::Eq7Friction; 3]>) -> Vec<f64> {
    let y0 = SVector::<f64, 6>::from([0.2, 0.4, -0.7, 1.5, -2.0, 3.0]);
    let mut s = Dopri5::new(
        Mechanics {
            links: *links,
            friction,
        },
        0.0,
        5.0,
        0.01,
        y0,
        1e-11,
        1e-11,
    );
    s.integrate().unwrap();
    s.y_out()
        .iter()
        .map(|y| {
            let q = [y[0], y[1], y[2]];
            let qd = [y[3], y[4], y[5]];
            links.kinetic_energy_j(&q, &qd) + links.potential_energy_j(&q)
        })
        .collect()
}

#[test]
fn unforced_frictionless_arm_conserves_energy_with_and_without_gravity() {
    let with_g = seed_arm().links;
    let zero_g = Links { g: 0.0, ..with_g };
    for links in [with_g, zero_g] {
        let e = energies(&links, None);
        let scale = e.iter().map(|v| v.abs()).fold(0.0, f64::max);
        let drift = e.iter().map(|v| (v - e[0]).abs()).fold(0.0, f64::max);
        println!(
            "g = {}: E0 = {} J, max |E - E0| = {drift:e} J",
            links.g, e[0]
        );
        assert!(
            drift < 1e-6 * scale,
            "energy drift {drift} J (scale {scale} J)"
        );
        // It does move: the kinetic energy is exchanged between the joints.
        assert!(scale > 1.0);
    }
}

#[test]
fn friction_of_eq7_only_dissipates() {
    let arm = seed_arm();
    let e = energies(&arm.links, Some(arm.friction));
    for w in e.windows(2) {
        assert!(w[1] <= w[0] + 1e-9, "energy rose: {} -> {}", w[0], w[1]);
    }
    assert!(
        e[e.len() - 1] < e[0] - 1.0,
        "{} -> {}",
        e[0],
        e[e.len() - 1]
    );
}

fn residual_max(arm: &Arm3, x: &Arm3State) -> f64 {
    arm.static_residual_nm(&x.p_abs_pa, &x.angles_rad).amax()
}

#[test]
fn settled_initial_state_is_a_static_equilibrium_that_holds_under_gravity_and_friction() {
    let arm = seed_arm();
    let x0 = arm.initial;
    assert!(residual_max(&arm, &x0) < 1e-9);
    println!(
        "equilibrium at 550/550 kPa: {:?} deg",
        x0.angles_rad.map(f64::to_degrees)
    );
    // Joint 2 sags below the horizontal, joint 1 (no gravity) stays at its neutral angle.
    assert!(x0.angles_rad[0].abs() < 1e-9);
    assert!(x0.angles_rad[1] < -0.05);
    let sim = simulate_arm3(
        &arm,
        &vec![CLOSED; 3000],
        1e-3,
        &SolverOptions::default(),
        |_| {},
    )
    .unwrap();
    for x in &sim.states {
        for i in 0..3 {
            assert!((x.angles_rad[i] - x0.angles_rad[i]).abs() < 1e-6, "{x:?}");
            assert!(x.velocities_rad_s[i].abs() < 1e-5, "{x:?}");
        }
    }
}

#[test]
fn perturbed_arm_returns_to_the_equilibrium_with_closed_valves() {
    let arm = seed_arm();
    let x_eq = arm.initial;
    // Displace the joints with the valves closed: each chamber keeps p V(chi) of the
    // equilibrium (isothermal), so the equilibrium is still the one to return to.
    let mut x0 = x_eq;
    for (i, dq) in [0.05, 0.05, -0.05].into_iter().enumerate() {
        x0.angles_rad[i] += dq;
        let pair = &arm.pairs[i];
        let chi_eq = pair.contractions(x_eq.angles_rad[i]);
        let chi = pair.contractions(x0.angles_rad[i]);
        for m in 0..2 {
            x0.p_abs_pa[i][m] *= pair.muscle.volume_m3(chi_eq[m]) / pair.muscle.volume_m3(chi[m]);
        }
    }
    let mut integ = Arm3Integrator::new(&arm, x0, SolverOptions::default());
    let mut max_dev: f64 = 0.0;
    integ
        .advance_samples(CLOSED, 1e-2, 2500, |x| {
            max_dev = max_dev.max((x.angles_rad[1] - x_eq.angles_rad[1]).abs())
        })
        .unwrap();
    let x = integ.state();
    let dev: Vec<f64> = (0..3)
        .map(|i| x.angles_rad[i] - x_eq.angles_rad[i])
        .collect();
    println!(
        "after 25 s: deviation {dev:?} rad, velocities {:?}",
        x.velocities_rad_s
    );
    assert!(max_dev >= 0.05 - 1e-9);
    for i in 0..3 {
        assert!(dev[i].abs() < 2e-3, "joint {}: {dev:?}", i + 1);
        // Closed chambers: p V(q) is constant, so the pressures come back with the angles.
        for m in 0..2 {
            assert!(
                (x.p_abs_pa[i][m] - x_eq.p_abs_pa[i][m]).abs() < 2e3,
                "{x:?}"
            );
        }
    }
}

#[test]
fn static_force_difference_matches_seed001_eqs_21_22() {
    // Seed 001 eqs. 21-22: at rest the muscles of joints 2 and 3 hold
    // dF1 = [(m3 l2 + m2 lc2) cos q2 + m3 lc3 cos(q2 + q3)] g / r2 and dF2 = m3 lc3 cos(q2 + q3) g / r3.
    let arm = seed_arm();
    let l = &arm.links;
    for (d2, d3) in [(0.0, 0.0), (150e3, 0.0), (0.0, 200e3), (250e3, 450e3)] {
        let mut p = arm.initial.p_abs_pa;
        p[1][0] -= d2;
        p[2][1] -= d3;
        let q = arm.static_equilibrium(&p, arm.initial.angles_rad).unwrap();
        let x = Arm3State {
            angles_rad: q,
            velocities_rad_s: [0.0; 3],
            p_abs_pa: p,
            friction_z_rad: [0.0; 3],
            supply_abs_pa: arm.p_supply_abs_pa,
        };
        let m = arm.measure(&x);
        let (c2, c23) = (q[1].cos(), (q[1] + q[2]).cos());
        let df1 = ((l.m3 * l.l2 + l.m2 * l.lc2) * c2 + l.m3 * l.lc3 * c23) * l.g
            / arm.pairs[1].sprocket_radius_m;
        let df2 = l.m3 * l.lc3 * c23 * l.g / arm.pairs[2].sprocket_radius_m;
        assert!((m[1].f1_n - m[1].f2_n - df1).abs() < 1e-6, "{m:?} {df1}");
        assert!((m[2].f1_n - m[2].f2_n - df2).abs() < 1e-6, "{m:?} {df2}");
        assert!((m[0].f1_n - m[0].f2_n).abs() < 1e-6);
    }
}

#[test]
fn larger_deflation_gives_larger_deflection_as_seed001_states() {
    // Seed 001 sec. 4: "With the increasing value by which the muscle is deflated, the size of
    // the deflection of the links also increases."
    let arm = seed_arm();
    for j in 0..3 {
        for m in 0..2 {
            let mut last = 0.0;
            for d_kpa in [100.0, 250.0, 350.0, 450.0] {
                let mut p = arm.initial.p_abs_pa;
                p[j][m] -= d_kpa * 1e3;
                let q = arm.static_equilibrium(&p, arm.initial.angles_rad).unwrap();
                let dq = q[j] - arm.initial.angles_rad[j];
                // Deflating muscle 1 (which pulls the angle up) lowers the angle; muscle 2 raises it.
                let signed = if m == 0 { -dq } else { dq };
                assert!(
                    signed > last,
                    "joint {} muscle {} {d_kpa} kPa: {dq}",
                    j + 1,
                    m + 1
                );
                last = signed;
            }
        }
    }
}

#[test]
fn pressure_step_scenario_settles_to_the_static_equilibria() {
    let arm = seed_arm();
    // Seed 001's 120 s protocol: muscle 1 deflated over [5, 35) s, muscle 2 over [60, 90) s.
    let sc = PressureStepScenario::seed001();
    let (rec, states) = sc.run(&arm, &SolverOptions::default(), |_| {}).unwrap();
    assert_eq!(rec.len(), 120_000);
    for (k_end, m) in [(34_999usize, 0usize), (89_999, 1)] {
        let x = &states[k_end];
        let mut p = arm.initial.p_abs_pa;
        for (j, pj) in p.iter_mut().enumerate() {
            pj[m] -= sc.deflation_kpa[j] * 1e3;
            // The regulated pressures reached their references.
            assert!((x.p_abs_pa[j][m] - pj[m]).abs() < 2e3, "{x:?}");
        }
        let q = arm.static_equilibrium(&p, x.angles_rad).unwrap();
        for (j, qj) in q.iter().enumerate() {
            let err_deg = (x.angles_rad[j] - qj).to_degrees();
            println!(
                "muscle {} deflated, joint {}: {:.3} deg, static {:.3} deg",
                m + 1,
                j + 1,
                x.angles_rad[j].to_degrees(),
                qj.to_degrees()
            );
            assert!(
                err_deg.abs() < 0.5,
                "joint {}: {err_deg} deg from static",
                j + 1
            );
            assert!(
                (x.angles_rad[j] - arm.initial.angles_rad[j])
                    .to_degrees()
                    .abs()
                    > 2.0
            );
        }
    }
}

/// Solver tolerances at which the arm and the 1-DOF plant converge to the same solution.
fn tight() -> SolverOptions {
    SolverOptions {
        rtol: 1e-9,
        atol: 1e-9,
        ..SolverOptions::default()
    }
}

/// A 3-DOF arm whose joint 1 is the reference 1-DOF joint: its muscles, valves and
/// pressures; M11 = J (no link masses, I_y = I_z so that nothing depends on q2, q3); no
/// friction; joints 2 and 3 at rest with equal pressures and closed valves.
fn one_dof_arm_toml(c: &PlantConfig) -> String {
    let m = &c.muscle;
    let muscle = format!(
        "rest_length_m = {}\nradius_m = {}\nbraid_angle_deg = {}\nend_factor = {}\ndamping_m2s = {}\nvolume_poly_m3 = {:?}\n",
        m.rest_length_m, m.radius_m, m.braid_angle_deg, m.end_factor, m.damping_m2s, m.volume_poly_m3
    );
    // Joints 2 and 3 rest at their neutral angle (equal pressures: no torque).
    let joint = |n: usize, p1: f64, p2: f64, angle: f64| {
        let neutral = if n == 1 { 0.0 } else { angle };
        format!(
            "[joint{n}]\nsprocket_radius_m = {}\ninitial_contraction = {}\nneutral_angle_rad = {neutral}\n\
             [joint{n}.muscle]\n{muscle}\
             [joint{n}.friction]\ncoulomb_nm = 0.0\nviscous_nm_s_per_rad = 0.0\nquadratic_nm_s2_per_rad2 = 0.0\ncubic_nm_s3_per_rad3 = 0.0\nsign_smoothing_velocity_rad_s = 0.01\n\
             [joint{n}.initial]\nangle_rad = {angle}\nvelocity_rad_s = {}\np1_gauge_pa = {p1}\np2_gauge_pa = {p2}\n",
            c.joint.sprocket_radius_m, c.joint.initial_contraction,
            if n == 1 { c.initial.velocity_rad_s } else { 0.0 },
        )
    };
    format!(
        "kind = \"arm3\"\n[environment]\np_atm_pa = {}\nsupply_gauge_pa = {}\n\
         [valve]\nsonic_conductance_m3_per_s_pa = {}\ncritical_ratio = {}\nlaminar_ratio = {}\n\
         [links]\ninertia_x2_kgm2 = 0.01\ninertia_x3_kgm2 = 0.01\ninertia_y2_kgm2 = 0.002\ninertia_y3_kgm2 = 0.003\n\
         inertia_z1_kgm2 = {}\ninertia_z2_kgm2 = 0.002\ninertia_z3_kgm2 = 0.003\nmass2_kg = 0.0\nmass3_kg = 0.0\n\
         length2_m = 0.5\ncom2_m = 0.25\ncom3_m = 0.1\ngravity_m_s2 = 9.81\n{}{}{}",
        c.environment.p_atm_pa,
        c.environment.supply_gauge_pa,
        c.valve.sonic_conductance_m3_per_s_pa,
        c.valve.critical_ratio,
        c.valve.laminar_ratio,
        c.joint.inertia_kgm2 - 0.002 - 0.003,
        joint(1, c.initial.p1_gauge_pa, c.initial.p2_gauge_pa, c.initial.angle_rad),
        joint(2, 300e3, 300e3, 0.3),
        joint(3, 200e3, 200e3, -0.4),
    )
}

#[test]
fn one_dof_special_case_matches_the_one_dof_plant_and_the_conformance_fixture() {
    let plant_path = fixture("reference-1dof.toml");
    let cfg = PlantConfig::load(&plant_path).unwrap();
    let plant = Plant::from_config(&cfg);
    let arm_cfg = Arm3Config::from_toml_str(&one_dof_arm_toml(&cfg), "one-dof-arm.toml")
        .unwrap_or_else(|e| panic!("{e}"));
    let arm = Arm3::from_config(&arm_cfg).unwrap();
    let m11 = arm.links.mass_matrix(&[0.0, 0.3, -0.4])[(0, 0)];
    assert!((m11 - cfg.joint.inertia_kgm2).abs() < 1e-15);

    let pulses = Recording::read(fixture("pulses_nominal.csv")).unwrap();
    let dt = pulses.sample_period_s();
    // Both at a tight tolerance: they must converge to the same solution.
    let opts = tight();
    let one = simulate(&plant, &pulses.inputs, dt, &opts).unwrap();
    let inputs: Vec<Arm3Inputs> = pulses
        .inputs
        .iter()
        .map(|u| [*u, ValveInputs::CLOSED, ValveInputs::CLOSED])
        .collect();
    let three = simulate_arm3(&arm, &inputs, dt, &opts, |_| {}).unwrap();
    assert_eq!(three.states.len(), one.states.len());
    let mut max_diff = [0.0f64; 5];
    let mut chans: [Vec<f64>; 5] = Default::default();
    for (x3, x1) in three.states.iter().zip(&one.states) {
        let a = arm.measure(x3)[0];
        let b = plant.measure(x1);
        let a = [a.angle_deg, a.p1_kpa, a.p2_kpa, a.f1_n, a.f2_n];
        for (i, (u, v)) in a.iter().zip(b.to_array()).enumerate() {
            max_diff[i] = max_diff[i].max((u - v).abs());
            chans[i].push(*u);
        }
        // Joints 2 and 3 stay where they are.
        assert_eq!(x3.angles_rad[1], 0.3);
        assert_eq!(x3.angles_rad[2], -0.4);
    }
    println!(
        "max |arm joint 1 - 1-DOF plant| (angle_deg, p1_kpa, p2_kpa, f1_n, f2_n): {max_diff:?}"
    );
    assert!(max_diff[0] < 1e-3, "{max_diff:?}");
    assert!(max_diff[1] < 0.05 && max_diff[2] < 0.05, "{max_diff:?}");
    assert!(max_diff[3] < 0.5 && max_diff[4] < 0.5, "{max_diff:?}");
    for c in Channel::ALL {
        let fit = fit_percent(pulses.channel(c).unwrap(), &chans[c.index()]);
        println!(
            "{}: fit {fit:.4} % against the conformance fixture",
            c.name()
        );
        assert!(fit >= 99.5, "{}: {fit}", c.name());
    }
}

#[test]
fn one_dof_special_case_with_friction_matches_the_one_dof_joint_friction_effect() {
    // Eq. 7 with f_e = f_g = 0 is the 1-DOF [effects.joint_friction] without a Stribeck dip
    // (breakaway = Coulomb), both with sgn(w) ~ tanh(w / w_eps).
    let (f_c, f_d, w_eps) = (0.15, 0.004, 0.01);
    let mut cfg = PlantConfig::load(fixture("reference-1dof.toml")).unwrap();
    cfg.effects.joint_friction = Some(host_sim::plant::effects::JointFriction {
        enabled: true,
        coulomb_nm: f_c,
        breakaway_nm: f_c,
        stribeck_velocity_rad_s: 1.0,
        viscous_nm_s_per_rad: f_d,
        smoothing_velocity_rad_s: w_eps,
    });
    let plant = Plant::from_config(&cfg);
    let text = one_dof_arm_toml(&cfg).replacen(
        "coulomb_nm = 0.0\nviscous_nm_s_per_rad = 0.0",
        &format!("coulomb_nm = {f_c}\nviscous_nm_s_per_rad = {f_d}"),
        1,
    );
    let arm =
        Arm3::from_config(&Arm3Config::from_toml_str(&text, "friction-arm.toml").unwrap()).unwrap();
    assert_eq!(arm.friction[0].f_c, f_c);
    assert_eq!(arm.friction[1].f_c, 0.0);
    let pulses = Recording::read(fixture("pulses_nominal.csv")).unwrap();
    let n = 5000; // 5 s
    let dt = pulses.sample_period_s();
    let opts = tight();
    let one = simulate(&plant, &pulses.inputs[..n], dt, &opts).unwrap();
    let inputs: Vec<Arm3Inputs> = pulses.inputs[..n]
        .iter()
        .map(|u| [*u, ValveInputs::CLOSED, ValveInputs::CLOSED])
        .collect();
    let three = simulate_arm3(&arm, &inputs, dt, &opts, |_| {}).unwrap();
    let mut max_angle_diff_deg: f64 = 0.0;
    let mut max_effect_deg: f64 = 0.0;
    let frictionless = simulate(
        &Plant::from_config(&PlantConfig::load(fixture("reference-1dof.toml")).unwrap()),
        &pulses.inputs[..n],
        dt,
        &opts,
    )
    .unwrap();
    for k in 0..n {
        let a = three.states[k].angles_rad[0].to_degrees();
        let b = one.states[k].angle_rad.to_degrees();
        max_angle_diff_deg = max_angle_diff_deg.max((a - b).abs());
        max_effect_deg =
            max_effect_deg.max((b - frictionless.states[k].angle_rad.to_degrees()).abs());
    }
    println!("friction changes the angle by up to {max_effect_deg} deg; arm vs 1-DOF: {max_angle_diff_deg} deg");
    assert!(max_effect_deg > 0.1, "{max_effect_deg}");
    assert!(max_angle_diff_deg < 1e-4, "{max_angle_diff_deg}");
}

#[test]
fn muscle_driven_arm_obeys_the_power_balance() {
    // d/dt (T + V) = (tau_muscle - F) . q' along any motion of the full plant: the muscle
    // torques and the friction enter through M^-1 with the right signs, C does no work.
    let arm = seed_arm();
    let sc = PressureStepScenario {
        switch_times_s: [0.2, 1.2, 1.4, 2.4],
        duration_s: 3.0,
        dt_s: 2e-4,
        ..PressureStepScenario::seed001()
    };
    let opts = SolverOptions {
        rtol: 1e-10,
        atol: 1e-10,
        ..SolverOptions::default()
    };
    let (_, states) = sc.run(&arm, &opts, |_| {}).unwrap();
    let energy = |x: &Arm3State| {
        arm.links
            .kinetic_energy_j(&x.angles_rad, &x.velocities_rad_s)
            + arm.links.potential_energy_j(&x.angles_rad)
    };
    let power = |x: &Arm3State| {
        let tau = arm.muscle_torques_nm(x);
        let f = arm.friction_torques_nm(&x.velocities_rad_s);
        (0..3)
            .map(|i| (tau[i] - f[i]) * x.velocities_rad_s[i])
            .sum::<f64>()
    };
    let e0 = energy(&states[0]);
    let mut work = 0.0;
    let mut max_err: f64 = 0.0;
    let mut max_change: f64 = 0.0;
    for w in states.windows(2) {
        work += 0.5 * (power(&w[0]) + power(&w[1])) * sc.dt_s;
        let change = energy(&w[1]) - e0;
        max_change = max_change.max(change.abs());
        max_err = max_err.max((change - work).abs());
    }
    println!("max |E - E0| = {max_change} J, max |E - E0 - work| = {max_err} J");
    assert!(max_change > 1.0, "{max_change}");
    assert!(max_err < 1e-5 * max_change, "{max_err} J vs {max_change} J");
}

/// Joint 1 (vertical axis, no gravity) released `delta_rad` away from its muscle
/// equilibrium with closed valves: (travel from release to 10 s, drift from 5 s to 10 s, the
/// muscle torque at release).
fn joint1_travel(arm: &Arm3, delta_rad: f64) -> (f64, f64, f64) {
    let mut x = arm.initial;
    x.angles_rad[0] += delta_rad;
    let tau = arm.muscle_torques_nm(&x)[0];
    let mut it = host_sim::sim::arm3::Arm3Integrator::new(arm, x, SolverOptions::default());
    let closed = [ValveInputs::CLOSED; 3];
    it.advance_samples(closed, 1e-3, 5_000, |_| {}).unwrap();
    let q5 = it.state().angles_rad[0];
    it.advance_samples(closed, 1e-3, 5_000, |_| {}).unwrap();
    let q10 = it.state().angles_rad[0];
    ((q10 - x.angles_rad[0]).abs(), (q10 - q5).abs(), tau)
}

#[test]
fn lugre_friction_sticks_below_the_breakaway_torque_where_the_regularised_sign_creeps() {
    use host_sim::plant::arm3::LuGreConfig;
    let regularised = seed_arm();
    let f_c = regularised.friction[0].f_c;
    let mut lugre = seed_arm();
    lugre.friction[0].lugre = Some(LuGreConfig {
        static_nm: 1.5 * f_c,
        stribeck_velocity_rad_s: 0.01,
        stiffness_nm_per_rad: 1000.0,
        damping_nm_s_per_rad: 60.0,
    });
    // A release whose muscle torque is 80 % of the Coulomb level: a hold phase.
    let (_, _, tau_per_mrad) = joint1_travel(&regularised, 1e-3);
    let delta = 0.8 * f_c / tau_per_mrad.abs() * 1e-3;
    let (creep, creep_late, tau) = joint1_travel(&regularised, delta);
    let (stick, stick_late, _) = joint1_travel(&lugre, delta);
    println!(
        "released {:.3} deg away, muscle torque {tau:.4} N m (f_c {f_c:.4}): the regularised \
         sign creeps {:.3} deg back ({:.2e} deg from 5 s to 10 s), LuGre moves {:.2e} deg \
         ({:.2e} deg from 5 s to 10 s)",
        delta.to_degrees(),
        creep.to_degrees(),
        creep_late.to_degrees(),
        stick.to_degrees(),
        stick_late.to_degrees(),
    );
    assert!((tau.abs() / f_c - 0.8).abs() < 0.05, "{tau}");
    // The regularised sign creeps back towards the muscle equilibrium; LuGre deflects its
    // bristles and holds.
    assert!(creep > 0.5 * delta, "{creep} of {delta}");
    assert!(stick < 0.1 * delta, "{stick} of {delta}");
    assert!(stick_late < 1e-3 * delta, "{stick_late} of {delta}");
    // Released further (the muscle torque 3x the Coulomb level, above the breakaway torque),
    // the LuGre joint slides back.
    let (slid, _, _) = joint1_travel(&lugre, 3.0 * delta);
    assert!(slid > 0.5 * delta, "{slid} of {}", 3.0 * delta);
}

#[test]
fn the_lugre_table_is_read_from_the_plant_file_and_checked() {
    let text = std::fs::read_to_string(arm3_plant()).unwrap();
    let with = |table: &str| {
        text.replacen(
            "[joint1.friction]",
            &format!("{table}\n[joint1.friction]"),
            1,
        )
    };
    let ok = with(
        "[joint1.friction.lugre]\nstatic_nm = 0.3\nstribeck_velocity_rad_s = 0.01\n\
         stiffness_nm_per_rad = 1000.0\ndamping_nm_s_per_rad = 60.0\n",
    );
    let c = Arm3Config::from_toml_str(&ok, "arm.toml").unwrap();
    assert_eq!(c.joint1.friction.lugre.unwrap().static_nm, 0.3);
    let bad = ok.replace(
        "stiffness_nm_per_rad = 1000.0",
        "stiffness_nm_per_rad = -1.0",
    );
    error_naming(
        Arm3Config::from_toml_str(&bad, "arm.toml"),
        &["arm.toml", "friction.lugre.stiffness_nm_per_rad"],
    );
}

/// Joint 1 of the 1-DOF special case with `joint_effect` in `[joint1.effects]` (or
/// `arm_effect` in the arm's `[effects]`) against the 1-DOF plant with the same table in its
/// `[effects]`, over the first 4 s of the conformance pulses: every recorded channel.
/// Returns the largest difference per channel and the largest change the effect makes.
fn arm_joint1_against_one_dof(one_dof_effect: &str, arm_effect: &str) -> ([f64; 5], [f64; 5]) {
    let base = std::fs::read_to_string(fixture("reference-1dof.toml")).unwrap();
    let cfg = PlantConfig::from_toml_str(&format!("{base}\n{one_dof_effect}"), "one-dof.toml")
        .unwrap_or_else(|e| panic!("{e}"));
    let nominal = Plant::from_config(&PlantConfig::load(fixture("reference-1dof.toml")).unwrap());
    let plant = Plant::from_config(&cfg);
    let text = format!("{}\n{arm_effect}", one_dof_arm_toml(&cfg));
    let arm = Arm3::from_config(
        &Arm3Config::from_toml_str(&text, "effect-arm.toml").unwrap_or_else(|e| panic!("{e}")),
    )
    .unwrap();
    let pulses = Recording::read(fixture("pulses_nominal.csv")).unwrap();
    let n = 4000;
    let dt = pulses.sample_period_s();
    let opts = tight();
    let one = simulate(&plant, &pulses.inputs[..n], dt, &opts).unwrap();
    let one = plant.measure_series(&one.states, dt);
    let none = simulate(&nominal, &pulses.inputs[..n], dt, &opts).unwrap();
    let none = nominal.measure_series(&none.states, dt);
    let inputs: Vec<Arm3Inputs> = pulses.inputs[..n]
        .iter()
        .map(|u| [*u, ValveInputs::CLOSED, ValveInputs::CLOSED])
        .collect();
    let three = simulate_arm3(&arm, &inputs, dt, &opts, |_| {}).unwrap();
    let three = arm.measure_run(&three.states, dt);
    let (mut diff, mut effect) = ([0.0f64; 5], [0.0f64; 5]);
    for k in 0..n {
        let a = three[k][0];
        let a = [a.angle_deg, a.p1_kpa, a.p2_kpa, a.f1_n, a.f2_n];
        let b = one[k].to_array();
        let c = none[k].to_array();
        for i in 0..5 {
            diff[i] = diff[i].max((a[i] - b[i]).abs());
            effect[i] = effect[i].max((b[i] - c[i]).abs());
        }
    }
    (diff, effect)
}

#[test]
fn valve_dead_time_sensor_lag_and_supply_drop_on_the_arm_match_the_one_dof_plant() {
    // (1-DOF table, the same on the arm): a dead time of 8.5 samples, sensor lags on every
    // channel group, both supply-drop forms (joints 2 and 3 draw nothing here).
    let cases = [
        (
            "[effects.valve_dead_time]\ndelay_s = 0.0085\n",
            "[joint1.effects.valve_dead_time]\ndelay_s = 0.0085\n",
        ),
        (
            "[effects.sensor_lag]\nangle_time_constant_s = 0.015\npressure_time_constant_s = 0.008\nforce_time_constant_s = 0.004\n",
            "[joint1.effects.sensor_lag]\nangle_time_constant_s = 0.015\npressure_time_constant_s = 0.008\nforce_time_constant_s = 0.004\n",
        ),
        (
            "[effects.supply_drop]\nmodel = \"static\"\nresistance_pa_s_per_m3 = 2.0e7\n",
            "[effects.supply_drop]\nmodel = \"static\"\nresistance_pa_s_per_m3 = 2.0e7\n",
        ),
        (
            "[effects.supply_drop]\nmodel = \"reservoir\"\ntank_volume_m3 = 5.0e-4\nfeed_conductance_m3_per_s_pa = 6.0e-9\n",
            "[effects.supply_drop]\nmodel = \"reservoir\"\ntank_volume_m3 = 5.0e-4\nfeed_conductance_m3_per_s_pa = 6.0e-9\n",
        ),
    ];
    for (one_dof, arm) in cases {
        let (diff, effect) = arm_joint1_against_one_dof(one_dof, arm);
        println!(
            "{}: effect {effect:.3?}, arm - 1-DOF {diff:?}",
            arm.lines().next().unwrap()
        );
        // The effect changes the pressures by kPa; the two implementations agree to within
        // the integrators' tolerance.
        assert!(
            effect[1] > 2.0 || effect[0] > 0.5,
            "{arm}: effect too small {effect:?}"
        );
        assert!(diff[0] < 1e-3, "{arm}: {diff:?}");
        assert!(diff[1] < 0.05 && diff[2] < 0.05, "{arm}: {diff:?}");
        assert!(diff[3] < 0.5 && diff[4] < 0.5, "{arm}: {diff:?}");
    }
}

#[test]
fn the_supply_is_shared_a_joint_fills_slower_while_another_draws() {
    // Static line resistance on the arm's supply: joint 1's muscle 1 inflating alone, and
    // the same while joint 2's and joint 3's muscle 1 inflate too. Without the drop the other
    // joints change joint 1's pressure only through the arm's motion (below 0.1 %).
    let run = |supply: &str, others: bool| -> f64 {
        let text = std::fs::read_to_string(arm3_plant()).unwrap();
        let arm = Arm3::from_config(
            &Arm3Config::from_toml_str(&format!("{text}\n{supply}"), "arm.toml").unwrap(),
        )
        .unwrap();
        let inflate = ValveInputs {
            u_in1: 1.0,
            ..ValveInputs::CLOSED
        };
        let u = [
            inflate,
            if others { inflate } else { ValveInputs::CLOSED },
            if others { inflate } else { ValveInputs::CLOSED },
        ];
        let sim =
            simulate_arm3(&arm, &vec![u; 50], 1e-3, &SolverOptions::default(), |_| {}).unwrap();
        sim.final_state.p_abs_pa[0][0] - arm.initial.p_abs_pa[0][0]
    };
    let drop = "[effects.supply_drop]\nmodel = \"static\"\nresistance_pa_s_per_m3 = 2.0e7\n";
    let (alone, shared) = (run(drop, false), run(drop, true));
    let (ideal_alone, ideal_shared) = (run("", false), run("", true));
    println!("joint 1 muscle 1 rise in 50 ms [Pa]: ideal {ideal_alone:.0} / {ideal_shared:.0}, drop alone {alone:.0}, with the other joints drawing {shared:.0}");
    assert!((ideal_alone - ideal_shared).abs() < 1e-3 * ideal_alone);
    assert!(alone < 0.99 * ideal_alone, "{alone} vs {ideal_alone}");
    assert!(shared < 0.97 * alone, "{shared} vs {alone}");
}

#[test]
fn a_joint_supply_drop_is_refused_the_arm_supply_is_checked() {
    let text = std::fs::read_to_string(arm3_plant()).unwrap();
    let with = |extra: &str| Arm3Config::from_toml_str(&format!("{text}\n{extra}"), "arm.toml");
    error_naming(
        with("[joint2.effects.supply_drop]\nmodel = \"static\"\nresistance_pa_s_per_m3 = 2.0e7\n"),
        &["arm.toml", "joint2.effects.supply_drop", "share"],
    );
    error_naming(
        with("[effects.supply_drop]\nmodel = \"static\"\ntank_volume_m3 = 1.0e-3\n"),
        &["effects.supply_drop.tank_volume_m3"],
    );
    let e = error_naming(
        with("[joint1.effects.valve_dead_time]\ndelay_s = -0.01\n"),
        &["joint1.effects.valve_dead_time.delay_s"],
    );
    // The error names the line of the key, as for a 1-DOF plant file.
    let line = text.lines().count() + 3;
    assert!(e.contains(&format!("arm.toml:{line}:")), "line {line}: {e}");
}
