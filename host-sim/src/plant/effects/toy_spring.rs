//! `[effects.toy_spring]`: a linear torsion spring on the joint, T = -k (beta - beta_0).
//!
//! A toy effect that exists only in the crate's unit tests: it is added the way
//! `docs/adding-an-effect.md` says (this one file and one line in the registry), and the
//! tests below check that the plant, the TOML, the validation, the diagnosis catalogue and
//! the synthetic truths all pick it up.

use serde::Deserialize;

use super::{Check, Effect, enabled_default, Hooks, Truth};
use crate::plant::effects::candidate::{torque_residual_scatter, clamp_to, Candidate, Screening, Setup};
use crate::plant::effects::candidate::{regress, Evidence};
use crate::plant::config::PlantConfig;
use crate::plant::tables::{ConfigError, ValveConfig};

/// The `[effects.toy_spring]` table.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ToySpring {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    /// k, stiffness (>= 0).
    pub stiffness_nm_per_rad: f64,
    /// beta_0, angle at which the spring is relaxed.
    pub rest_angle_rad: f64,
}

impl Hooks for ToySpring {
    parameters!(stiffness_nm_per_rad, rest_angle_rad);
    fn joint_torque_nm(&self, angle_rad: f64, _velocity_rad_s: f64) -> f64 {
        -self.stiffness_nm_per_rad * (angle_rad - self.rest_angle_rad)
    }
}

impl Effect for ToySpring {
    const TRUTHS: &'static [Truth] = &[Truth::new("toy_spring", "toy_spring", |_| "[effects.toy_spring]\nstiffness_nm_per_rad = 2.0\nrest_angle_rad = 0.0\n".into())];
    table_effect!();
    fn validate(&self, c: &Check) -> Result<(), ConfigError> {
        use crate::validate::Range;
        c.within(
            "stiffness_nm_per_rad",
            self.stiffness_nm_per_rad,
            Range::closed(0.0, 1000.0),
            "N m/rad",
        )?;
        c.within(
            "rest_angle_rad",
            self.rest_angle_rad,
            Range::closed(-std::f64::consts::PI, std::f64::consts::PI),
            "rad (degrees typed?)",
        )?;
        Ok(())
    }
}

effect_candidates!(ToySpring => ToySpringCandidate);

/// The spring's stiffness, relaxed at angle 0.
pub struct ToySpringCandidate;

impl Candidate for ToySpringCandidate {
    candidate_spec! {
        id: "toy_spring",
        label: "torsion spring",
        params: [("stiffness_nm_per_rad", 0.0, 100.0, 1.0)],
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        // J alpha - T_muscles = -k beta: the torque residual follows -beta.
        let minus_angle: Vec<f64> = ev.angle_rad.iter().map(|b| -b).collect();
        let (c, r2) = regress(&ev.torque_residual_nm, &[&minus_angle]);
        Screening {
            score: r2,
            initial: clamp_to(&self.params(s), vec![c[0]]),
            note: format!("the torque balance residual follows -angle (R^2 {r2:.2})"),
            scatter: torque_residual_scatter(ev, "joint angle [rad]", &ev.angle_rad),
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], _s: &Setup) {
        cfg.effects.toy_spring = Some(ToySpring {
            enabled: true,
            stiffness_nm_per_rad: p[0],
            rest_angle_rad: 0.0,
        });
    }
    fn describe(&self, p: &[f64], _s: &Setup) -> String {
        format!("a torsion spring of {:.3} N m/rad on the joint", p[0])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plant::effects::candidate::Evidence;
    use crate::diagnose::synth::{generate, plant_with, truth_names, Excitation, SynthSpec};
    use crate::diagnose::{catalogue, SavitzkyGolay};
    use crate::plant::{Plant, PlantState, ValveInputs};
    use crate::sim::{simulate, SolverOptions};

    fn nominal_text() -> String {
        std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tests/fixtures/reference-1dof.toml"
        ))
        .unwrap()
    }

    fn with_spring(k: f64) -> String {
        format!(
            "{}\n[effects.toy_spring]\nstiffness_nm_per_rad = {k:e}\nrest_angle_rad = 0.0\n",
            nominal_text()
        )
    }

    #[test]
    fn the_table_reaches_the_right_hand_side() {
        let nominal = Plant::from_config(&PlantConfig::from_toml_str(&nominal_text(), "n.toml").unwrap());
        let cfg = PlantConfig::from_toml_str(&with_spring(3.0), "spring.toml").unwrap();
        assert!(cfg.effects.toy_spring.is_some());
        let sprung = Plant::from_config(&cfg);
        let x = PlantState {
            angle_rad: 0.2,
            ..nominal.initial_state()
        };
        let u = ValveInputs::CLOSED;
        let d0 = nominal.derivatives(&x, &u).velocity_rad_s;
        let d1 = sprung.derivatives(&x, &u).velocity_rad_s;
        // The spring adds -k beta / J to the angular acceleration.
        let want = -3.0 * 0.2 / cfg.joint.inertia_kgm2;
        assert!(((d1 - d0) - want).abs() < 1e-9 * want.abs(), "{} vs {want}", d1 - d0);
        // Every run lists it with its parameters.
        assert_eq!(
            sprung.effects_summary(),
            "toy_spring(stiffness_nm_per_rad = 3, rest_angle_rad = 0)"
        );
        // Switched off, it is gone.
        let off = with_spring(3.0).replace("rest_angle_rad = 0.0", "rest_angle_rad = 0.0\nenabled = false");
        let off = Plant::from_config(&PlantConfig::from_toml_str(&off, "off.toml").unwrap());
        assert_eq!(off.derivatives(&x, &u), nominal.derivatives(&x, &u));
        assert!(off.active_effects().is_empty());
    }

    #[test]
    fn bad_values_name_the_key_and_the_file() {
        let e = PlantConfig::from_toml_str(&with_spring(-1.0), "bad-spring.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("effects.toy_spring.stiffness_nm_per_rad"), "{e}");
        assert!(e.contains("bad-spring.toml"), "{e}");
        let e = PlantConfig::from_toml_str(
            &with_spring(1.0).replace("rest_angle_rad", "rest_angel_rad"),
            "typo.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("rest_angel_rad"), "{e}");
    }

    #[test]
    fn the_diagnosis_screens_and_refits_it() {
        assert!(catalogue().iter().any(|c| c.id() == "toy_spring"));
        assert!(truth_names().contains(&"toy_spring"));
        let dt = 1e-3;
        let cfg = plant_with(&nominal_text(), &["toy_spring"], dt).unwrap();
        assert_eq!(
            cfg.effects.toy_spring.as_ref().map(|s| s.stiffness_nm_per_rad),
            Some(2.0)
        );
        let spec = SynthSpec {
            excitation: Excitation::Pulses,
            duration_s: 4.0,
            dt_s: dt,
            seed: 5,
            noise: true,
            channels: [true; 5],
        };
        let rec = generate(&cfg, &spec, "toy_spring").unwrap();
        let nominal_cfg = plant_with(&nominal_text(), &[], dt).unwrap();
        let nominal = Plant::from_config(&nominal_cfg);
        let sim = simulate(&nominal, &rec.inputs, dt, &SolverOptions::default()).unwrap();
        let nominal_meas = nominal.measure_series(&sim.states, dt);
        let ev = Evidence::build(&nominal_cfg, &rec, &nominal_meas, &SavitzkyGolay::default());
        let setup = Setup {
            dt_s: dt,
            present: [true; 5],
        };
        let cands = catalogue();
        let toy = cands.iter().find(|c| c.id() == "toy_spring").unwrap();
        let s = toy.screen(&ev, &setup);
        assert!(s.score > 0.5, "screening R^2 {}", s.score);
        assert!((s.initial[0] - 2.0).abs() < 0.4, "stiffness guess {}", s.initial[0]);
        // Switched on with the screened stiffness, the plant matches the recording better.
        let mut fitted = nominal_cfg.clone();
        toy.apply(&mut fitted, &s.initial, &setup);
        let angle_err = |p: &Plant| {
            let sim = simulate(p, &rec.inputs, dt, &SolverOptions::default()).unwrap();
            let m = p.measure_series(&sim.states, dt);
            let y = rec.channel(crate::plant::channel::Channel::AngleDeg).unwrap();
            m.iter().zip(y).map(|(a, b)| (a.angle_deg - b).powi(2)).sum::<f64>()
        };
        let before = angle_err(&nominal);
        let after = angle_err(&Plant::from_config(&fitted));
        assert!(after < 0.1 * before, "angle SSE {before} -> {after}");
    }
}
