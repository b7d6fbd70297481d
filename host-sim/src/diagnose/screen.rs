//! Screening: equation-error evidence from the measured states (torque balance, pressure
//! law, tension law) and output-side evidence (residual lags, offsets), against which every
//! candidate's signature is regressed to rank it and seed its parameters.

use crate::io::recording::{Channel, Recording};
use crate::plant::config::PlantConfig;
use crate::plant::{Measurement, Plant, PlantState, ValveInputs};

use super::differentiate::Differentiator;

/// Residual against a regressor, subsampled for a plot.
#[derive(Debug, Clone)]
pub struct Scatter {
    pub x_label: String,
    pub y_label: String,
    pub points: Vec<(f64, f64)>,
}

impl Scatter {
    pub fn new(x_label: &str, y_label: &str, x: &[f64], y: &[f64]) -> Self {
        let n = x.len().min(y.len());
        let stride = (n / 1500).max(1);
        Self {
            x_label: x_label.into(),
            y_label: y_label.into(),
            points: (0..n)
                .step_by(stride)
                .filter(|k| x[*k].is_finite() && y[*k].is_finite())
                .map(|k| (x[k], y[k]))
                .collect(),
        }
    }
}

/// Least squares y ~ sum_j c_j x_j (no intercept: the signatures are physical); returns the
/// coefficients and R^2 = 1 - SS_res / SS_y (uncentred, clipped to [0, 1]).
pub fn regress(y: &[f64], xs: &[&[f64]]) -> (Vec<f64>, f64) {
    let m = xs.len();
    let n = y.len();
    let mut a = nalgebra::DMatrix::<f64>::zeros(m, m);
    let mut b = nalgebra::DVector::<f64>::zeros(m);
    let mut ss = 0.0;
    for k in 0..n {
        if !y[k].is_finite() || xs.iter().any(|x| !x[k].is_finite()) {
            continue;
        }
        ss += y[k] * y[k];
        for i in 0..m {
            b[i] += xs[i][k] * y[k];
            for j in 0..m {
                a[(i, j)] += xs[i][k] * xs[j][k];
            }
        }
    }
    if ss == 0.0 {
        return (vec![0.0; m], 0.0);
    }
    // Scale-invariant ridge on the diagonal against collinear regressors.
    for i in 0..m {
        a[(i, i)] *= 1.0 + 1e-9;
        if a[(i, i)] == 0.0 {
            a[(i, i)] = 1.0;
        }
    }
    let Some(c) = a.clone().cholesky().map(|ch| ch.solve(&b)) else {
        return (vec![0.0; m], 0.0);
    };
    let explained = (c.transpose() * &b)[(0, 0)];
    let r2 = (explained / ss).clamp(0.0, 1.0);
    (c.iter().copied().collect(), r2)
}

/// The evidence the candidates screen.
#[derive(Debug, Clone)]
pub struct Evidence {
    pub dt_s: f64,
    pub angle_rad: Vec<f64>,
    pub omega_rad_s: Vec<f64>,
    pub alpha_rad_s2: Vec<f64>,
    pub dchi1_per_s: Vec<f64>,
    /// Gauge pressures (measured, else simulated).
    pub p_gauge_pa: [Vec<f64>; 2],
    /// J alpha - r (F1 - F2), F measured when both force channels are, else from the
    /// nominal tension law at the measured state.
    pub torque_residual_nm: Vec<f64>,
    /// dp/dt measured - dp/dt nominal at the measured state (where the channel was measured).
    pub pressure_residual_pa_s: [Option<Vec<f64>>; 2],
    /// Nominal dp/dt at the measured state.
    pub nominal_dp: [Vec<f64>; 2],
    /// F measured - F nominal at the measured state (when any force channel was measured).
    pub force_residual_n: Option<[Option<Vec<f64>>; 2]>,
    /// Measured - nominal simulation, per channel present.
    pub residual: [Option<Vec<f64>>; 5],
    /// The nominal simulation of each channel present.
    pub nominal: [Option<Vec<f64>>; 5],
    /// d/dt of the nominal simulation of each measured channel (a lag tau leaves a
    /// residual of about -tau times it).
    pub nominal_rate: [Option<Vec<f64>>; 5],
    /// Standard deviation of each measured channel (1 when absent).
    pub spread: [f64; 5],
    /// Shift (samples) by which the nominal simulation best matches each channel.
    pub lag_samples: [usize; 5],
    /// Share of the residual energy that shift removes.
    pub lag_gain: [f64; 5],
    pub inertia_kgm2: f64,
    pub sprocket_radius_m: f64,
    /// The nominal plant.
    pub plant: Plant,
    /// The measured state at every sample (angle, its smoothed derivative, pressures
    /// measured else simulated), for candidates that build their own regressors.
    pub states: Vec<PlantState>,
    /// The recording's valve inputs.
    pub inputs: Vec<ValveInputs>,
}

/// Longest lag searched by cross-correlation.
pub const MAX_LAG_S: f64 = 0.05;

impl Evidence {
    /// Residual of channel `c` against its nominal rate (the lag signature).
    pub fn lag_scatter(&self, c: Channel) -> Option<Scatter> {
        Some(Scatter::new(
            &format!("nominal d({})/dt [{} per s]", c.name(), c.name()),
            &format!("{} residual, measured - nominal", c.name()),
            self.nominal_rate[c.index()].as_ref()?,
            self.residual[c.index()].as_ref()?,
        ))
    }

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
