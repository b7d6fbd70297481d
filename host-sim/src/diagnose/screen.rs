//! Screening: equation-error evidence from the measured states (torque balance, pressure
//! law, tension law) and output-side evidence (residual lags, offsets), against which every
//! candidate's signature is regressed to rank it and seed its parameters.

use crate::io::recording::Recording;
use crate::plant::channel::Channel;
use crate::plant::config::PlantConfig;
use crate::plant::{Measurement, Plant, PlantState, ValveInputs};

use super::differentiate::Differentiator;

pub use crate::plant::effects::candidate::{regress, Evidence, Scatter, MAX_LAG_S};

impl Evidence {
    pub fn build(
        cfg: &PlantConfig,
        rec: &Recording,
        nominal: &[Measurement],
        diff: &dyn Differentiator,
    ) -> Self {
        let plant = Plant::from_config(cfg);
        let dt = rec.sample_period_s();
        let n = rec.len();
        let meas = |c: Channel| rec.channel(c);
        let nom = |c: Channel| -> Vec<f64> { nominal.iter().map(|m| c.of(m)).collect() };
        let angle_rad: Vec<f64> = match meas(Channel::AngleDeg) {
            Some(a) => a.iter().map(|d| d.to_radians()).collect(),
            None => nom(Channel::AngleDeg)
                .iter()
                .map(|d| d.to_radians())
                .collect(),
        };
        let omega = diff.derivative(&angle_rad, dt);
        let alpha = diff.derivative(&omega, dt);
        let pg = |c: Channel| -> Vec<f64> {
            match meas(c) {
                Some(v) => v.iter().map(|x| x * 1e3).collect(),
                None => nom(c).iter().map(|x| x * 1e3).collect(),
            }
        };
        let p_gauge_pa = [pg(Channel::P1Kpa), pg(Channel::P2Kpa)];
        let dp_meas = [
            meas(Channel::P1Kpa).map(|_| diff.derivative(&p_gauge_pa[0], dt)),
            meas(Channel::P2Kpa).map(|_| diff.derivative(&p_gauge_pa[1], dt)),
        ];
        let p_atm = plant.p_atm_pa;
        let r = plant.joint.sprocket_radius_m;
        let both_forces = meas(Channel::F1N).is_some() && meas(Channel::F2N).is_some();
        let any_force = meas(Channel::F1N).is_some() || meas(Channel::F2N).is_some();
        let mut torque_residual = vec![0.0; n];
        let mut nominal_dp = [vec![0.0; n], vec![0.0; n]];
        let mut force_res = [vec![0.0; n], vec![0.0; n]];
        let mut dchi1 = vec![0.0; n];
        let mut states = Vec::with_capacity(n);
        for k in 0..n {
            let x = PlantState {
                angle_rad: angle_rad[k],
                velocity_rad_s: omega[k],
                p1_abs_pa: p_gauge_pa[0][k] + p_atm,
                p2_abs_pa: p_gauge_pa[1][k] + p_atm,
            };
            let u: ValveInputs = rec.inputs[k];
            let f_model = plant.tensions_n(&x);
            let f_used = if both_forces {
                [
                    meas(Channel::F1N).unwrap()[k],
                    meas(Channel::F2N).unwrap()[k],
                ]
            } else {
                f_model
            };
            let load_nm = plant.load.as_ref().map_or(0.0, |l| l.at(k));
            torque_residual[k] =
                plant.joint.inertia_kgm2 * alpha[k] - r * (f_used[0] - f_used[1]) - load_nm;
            for (i, c) in [Channel::F1N, Channel::F2N].into_iter().enumerate() {
                if let Some(f) = meas(c) {
                    force_res[i][k] = f[k] - f_model[i];
                }
            }
            let d = plant.derivatives(&x, &u);
            nominal_dp[0][k] = d.p1_abs_pa;
            nominal_dp[1][k] = d.p2_abs_pa;
            dchi1[k] = plant.joint.contraction_rates(x.velocity_rad_s)[0];
            states.push(x);
        }
        let pressure_residual = [0, 1].map(|i| {
            dp_meas[i]
                .as_ref()
                .map(|d| d.iter().zip(&nominal_dp[i]).map(|(a, b)| a - b).collect())
        });
        let mut residual: [Option<Vec<f64>>; 5] = Default::default();
        let mut nominal_ch: [Option<Vec<f64>>; 5] = Default::default();
        let mut nominal_rate: [Option<Vec<f64>>; 5] = Default::default();
        let mut spread = [1.0; 5];
        let mut lag_samples = [0usize; 5];
        let mut lag_gain = [0.0; 5];
        let max_lag = ((MAX_LAG_S / dt).round() as usize).min(n / 4);
        for c in Channel::ALL {
            if let Some(y) = meas(c) {
                let yn = nom(c);
                residual[c.index()] = Some(y.iter().zip(&yn).map(|(a, b)| a - b).collect());
                nominal_ch[c.index()] = Some(yn.clone());
                nominal_rate[c.index()] = Some(diff.derivative(&yn, dt));
                let mean = y.iter().sum::<f64>() / n as f64;
                let sd = (y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n as f64).sqrt();
                spread[c.index()] = if sd > 0.0 { sd } else { 1.0 };
                let cost = |s: usize| -> f64 {
                    (max_lag..n)
                        .map(|k| (y[k] - yn[k - s]).powi(2))
                        .sum::<f64>()
                };
                let c0 = cost(0);
                let (mut best, mut best_cost) = (0, c0);
                for s in 1..=max_lag {
                    let cs = cost(s);
                    if cs < best_cost {
                        best = s;
                        best_cost = cs;
                    }
                }
                lag_samples[c.index()] = best;
                lag_gain[c.index()] = if c0 > 0.0 { 1.0 - best_cost / c0 } else { 0.0 };
            }
        }
        Self {
            dt_s: dt,
            angle_rad,
            omega_rad_s: omega,
            alpha_rad_s2: alpha,
            dchi1_per_s: dchi1,
            p_gauge_pa,
            torque_residual_nm: torque_residual,
            pressure_residual_pa_s: pressure_residual,
            nominal_dp,
            force_residual_n: any_force.then(|| {
                let [a, b] = force_res;
                [meas(Channel::F1N).map(|_| a), meas(Channel::F2N).map(|_| b)]
            }),
            residual,
            nominal: nominal_ch,
            nominal_rate,
            spread,
            lag_samples,
            lag_gain,
            inertia_kgm2: plant.joint.inertia_kgm2,
            sprocket_radius_m: r,
            plant,
            states,
            inputs: rec.inputs.clone(),
        }
    }
}
