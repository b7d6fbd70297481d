//! `[effects.muscle_hysteresis]`: friction in the braid (thread on thread, thread on bladder;
//! seed 003 names both, and finds the torque hysteresis to be a velocity-dependent offset on
//! the static characteristic that widens with speed), as a force in each muscle opposing its
//! contraction rate, with a magnitude proportional to the gauge pressure (the normal force
//! between the braid threads grows with it):
//!
//! F_h,i = (f0 + k_p max(pg_i, 0)) tanh(dchi_i/dt / v_s),
//! F_i = max(0, Fs_i - gamma pg_i dchi_i/dt - F_h,i).
//!
//! It acts inside the muscle, so it shows in the measured tensions `f1_n`, `f2_n` (a
//! contracting muscle pulls less, a stretched one more); joint friction does not. It is
//! memoryless (no extra ODE state): seed 003 measured an offset that is a function of the
//! velocity, not a history-dependent loop, and a tanh-regularized Coulomb term keeps the
//! right-hand side smooth for the explicit integrator. It always dissipates: the change of
//! joint torque it causes has the sign of -omega.
//!
//! Diagnosis: the force residuals (or, without force channels, the torque balance) against
//! the contraction direction. Truth: 6 N + 2 N per 100 kPa.

use serde::Deserialize;

use super::{Check, Effect, enabled_default, Hooks, Truth};
use crate::plant::effects::candidate::{clamp_to, Candidate, Screening, Setup};
use crate::plant::effects::candidate::{regress, Evidence, Scatter};
use crate::plant::config::PlantConfig;
use crate::plant::tables::{ConfigError, ValveConfig};

/// The `[effects.muscle_hysteresis]` table.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MuscleHysteresis {
    #[serde(default = "enabled_default")]
    pub enabled: bool,
    /// f0, friction force at zero gauge pressure (>= 0).
    pub base_force_n: f64,
    /// k_p, friction force per pascal of gauge pressure (>= 0).
    pub pressure_gain_n_per_pa: f64,
    /// v_s, contraction rate (1/s, dchi/dt) at which the friction reaches tanh(1) = 76 % of
    /// its level (> 0; small: Coulomb-like, large: viscous-like).
    pub smoothing_rate_per_s: f64,
}

impl MuscleHysteresis {
    /// Friction force F_h opposing a contraction rate `contraction_rate_per_s` (positive while
    /// contracting), at gauge pressure `p_gauge_pa`.
    #[inline(always)]
    pub fn force_n(&self, p_gauge_pa: f64, contraction_rate_per_s: f64) -> f64 {
        (self.base_force_n + self.pressure_gain_n_per_pa * p_gauge_pa.max(0.0))
            * (contraction_rate_per_s / self.smoothing_rate_per_s).tanh()
    }
}

impl Hooks for MuscleHysteresis {
    parameters!(base_force_n, pressure_gain_n_per_pa, smoothing_rate_per_s);
    #[inline(always)]
    fn muscle_friction_n(&self, p_gauge_pa: f64, contraction_rate_per_s: f64) -> Option<f64> {
        Some(self.force_n(p_gauge_pa, contraction_rate_per_s))
    }
}

impl Effect for MuscleHysteresis {
    const TRUTHS: &'static [Truth] = &[Truth::new("muscle_hysteresis", "muscle_hysteresis", |_| "[effects.muscle_hysteresis]\nbase_force_n = 6.0\npressure_gain_n_per_pa = 2.0e-5\nsmoothing_rate_per_s = 0.02\n".into())];
    table_effect!();
    fn validate(&self, c: &Check) -> Result<(), ConfigError> {
        check_fields!(self, c, positive: smoothing_rate_per_s);
        use crate::validate::Range;
        c.within(
            "base_force_n",
            self.base_force_n,
            Range::closed(0.0, 5000.0),
            "N (the band's half-width at zero pressure)",
        )?;
        c.within(
            "pressure_gain_n_per_pa",
            self.pressure_gain_n_per_pa,
            Range::closed(0.0, 0.01),
            "N/Pa (N/kPa typed?)",
        )?;
        Ok(())
    }
}

effect_candidates!(MuscleHysteresis => MuscleHysteresisCandidate);

/// Contraction-rate scale of the braid-friction candidate.
pub const HYSTERESIS_SMOOTHING_PER_S: f64 = 0.01;

/// Braid friction with a fixed smoothing rate.
pub struct MuscleHysteresisCandidate;

impl Candidate for MuscleHysteresisCandidate {
    candidate_spec! {
        id: "muscle_hysteresis",
        label: "muscle (braid) hysteresis",
        params: [("base_force_n", 0.0, 500.0, 5.0), ("pressure_gain_n_per_pa", 0.0, 1e-3, 1e-5)],
        fixed: [("smoothing_rate_per_s", HYSTERESIS_SMOOTHING_PER_S)],
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        let th: Vec<f64> = ev
            .dchi1_per_s
            .iter()
            .map(|d| (d / HYSTERESIS_SMOOTHING_PER_S).tanh())
            .collect();
        let (c, r2, scatter) = if let Some(fr) = &ev.force_residual_n {
            // F_i,meas - F_i,nominal = -(f0 + k pg_i) tanh(dchi_i / v), dchi_2 = -dchi_1.
            let mut y = Vec::new();
            let mut x0 = Vec::new();
            let mut x1 = Vec::new();
            for (i, sgn) in [(0usize, 1.0), (1, -1.0)] {
                if let Some(r) = &fr[i] {
                    for k in 0..th.len() {
                        y.push(r[k]);
                        x0.push(-sgn * th[k]);
                        x1.push(-sgn * th[k] * ev.p_gauge_pa[i][k].max(0.0));
                    }
                }
            }
            let (c, r2) = regress(&y, &[&x0, &x1]);
            let sc = fr[0].as_ref().map(|r| {
                Scatter::new(
                    "muscle 1 contraction rate dchi1/dt [1/s]",
                    "f1 residual F1 measured - F1 nominal [N]",
                    &ev.dchi1_per_s,
                    r,
                )
            });
            (c, r2, sc)
        } else {
            // Without force sensors it shows only in the torque balance:
            // dT = -r tanh(dchi1/v) (2 f0 + k (pg1 + pg2)).
            let r = ev.sprocket_radius_m;
            let x0: Vec<f64> = th.iter().map(|t| -2.0 * r * t).collect();
            let x1: Vec<f64> = th
                .iter()
                .enumerate()
                .map(|(k, t)| {
                    -r * t * (ev.p_gauge_pa[0][k].max(0.0) + ev.p_gauge_pa[1][k].max(0.0))
                })
                .collect();
            let (c, r2) = regress(&ev.torque_residual_nm, &[&x0, &x1]);
            let sc = Scatter::new(
                "muscle 1 contraction rate dchi1/dt [1/s]",
                "torque balance residual [N m]",
                &ev.dchi1_per_s,
                &ev.torque_residual_nm,
            );
            (c, r2, Some(sc))
        };
        Screening {
            score: r2,
            initial: clamp_to(&self.params(s), vec![c[0], c[1]]),
            note: if ev.force_residual_n.is_some() {
                format!("the measured tensions fall short of the nominal ones by a force that follows the contraction direction (R^2 {r2:.2})")
            } else {
                format!("the torque balance residual follows -sign(contraction rate) (R^2 {r2:.2}); no force channel to confirm it is in the muscles")
            },
            scatter,
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, p: &[f64], _s: &Setup) {
        cfg.effects.muscle_hysteresis = Some(MuscleHysteresis {
            enabled: true,
            base_force_n: p[0],
            pressure_gain_n_per_pa: p[1],
            smoothing_rate_per_s: HYSTERESIS_SMOOTHING_PER_S,
        });
    }
    fn describe(&self, p: &[f64], _s: &Setup) -> String {
        format!(
            "braid friction inside the muscles, {:.2} N + {:.2} N per 100 kPa gauge, opposing the contraction",
            p[0],
            p[1] * 1e5
        )
    }
}
