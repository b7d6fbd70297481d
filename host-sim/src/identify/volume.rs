//! `host-sim identify volume`: seed 004's hybrid model (HM, eq. 8-12), the muscle's chamber
//! volume `V(e, e', P, P')` as a feed-forward network trained on the mass flow.
//!
//! The network is the firmware's kernel ([`pam_firmware::volume_fnn`]: two hidden layers of
//! [`HIDDEN`] softsign units, normalised inputs, linear output scaled to m^3); here it runs in
//! f64 with its gradients. The hybrid mass flow is eq. 12,
//!
//! ```text
//! m' = (P/(R T) dV/dP + V/(k R T)) P' + P/(R T) dV/de e' = V P'/(k R T) + P/(R T) V'
//! ```
//!
//! with `V' = dV/de e' + dV/dP P'` (eq. 9), the network's directional derivative along
//! `(e', 0, P', 0)` (forward mode, one tangent pass), and `k`, `R`, `T` of
//! `config/pressure_ff.toml` (the firmware's). The loss is eq. 10,
//!
//! ```text
//! L = 1/N sum_n ((m'_HM,n - m'_n) / s_m)^2 + lambda/2 |theta|^2
//! ```
//!
//! (`s_m` = the target's standard deviation, so that `lambda` does not depend on the flow's
//! unit), minimised by the `levenberg-marquardt` crate (already the output-error and force-law
//! fitter: the loss is a sum of squares, residuals `(m'_HM,n - m'_n) / (s_m sqrt N)` and
//! `sqrt(lambda/2) theta_j`) with the analytic Jacobian (reverse mode through the value and
//! tangent passes). Random start from `--seed` (StdRng), so a run is reproducible.
//!
//! Samples from a recording: per muscle and per sample, `e` = the firmware geometry's
//! contraction at the recorded angle, `e'` and `P'` = Savitzky-Golay derivatives of the angle
//! and the pressure ([`crate::signal::savitzky_golay_derivative`]), `P` absolute, and the
//! target = the same Savitzky-Golay derivative of the integrated recorded mass flow
//! (`m_dot_1_kg_s`, `m_dot_2_kg_s`: a flow sensor on a rig, the plant's true net flow in
//! host-sim's recordings), so target and `P'` average over the same window.

use std::cell::Cell;
use std::fmt::Write as _;

use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{DMatrix, DVector, Dyn, Owned};
use pam_firmware::geometry::JointGeometry;
use pam_firmware::volume_fnn::VolumeFnn;
use rand::{Rng, SeedableRng};

use crate::io::recording::{Channel, MASS_FLOW_COLUMNS};
use crate::signal::half_window_samples;
use crate::Recording;

/// Units per hidden layer (the firmware kernel's).
pub const HIDDEN: usize = pam_firmware::volume_fnn::HIDDEN;
/// Weights and biases of the network.
pub const PARAMETERS: usize = pam_firmware::volume_fnn::PARAMETERS;

/// One training sample of one muscle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VolumeSample {
    /// Contraction `e` [-].
    pub contraction: f64,
    /// Contraction rate `e'` [1/s].
    pub contraction_rate_per_s: f64,
    /// Absolute pressure `P` [Pa].
    pub p_abs_pa: f64,
    /// Pressure rate `P'` [Pa/s].
    pub p_rate_pa_s: f64,
    /// Net mass flow into the muscle [kg/s] (the target).
    pub m_dot_kg_s: f64,
}

/// The thermodynamic constants of eq. 7 / 12.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Thermo {
    /// Polytropic index `k`.
    pub polytropic_index: f64,
    /// `R T` [J/kg].
    pub rt_j_per_kg: f64,
}

impl Thermo {
    /// The firmware's (`config/pressure_ff.toml`).
    pub fn firmware() -> Self {
        let c = pam_firmware::constants::PRESSURE_FF;
        Thermo {
            polytropic_index: c.polytropic_index as f64,
            rt_j_per_kg: c.gas_constant_j_per_kg_k as f64 * c.temperature_k as f64,
        }
    }

    /// Eq. 7 / 12: the mass flow [kg/s] of a sample for the volume `v_m3` and its rate.
    pub fn mass_flow_kg_s(&self, s: &VolumeSample, v_m3: f64, v_rate_m3_s: f64) -> f64 {
        (s.p_rate_pa_s * v_m3 / self.polytropic_index + s.p_abs_pa * v_rate_m3_s) / self.rt_j_per_kg
    }
}

/// The firmware's volume polynomial (eq. 7 with it is the analytical model).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VolumePoly {
    /// `b0..b3` [m^3].
    pub coefficients_m3: [f64; 4],
}

impl VolumePoly {
    /// `config/plant_constants.toml`'s.
    pub fn firmware() -> Self {
        VolumePoly {
            coefficients_m3: pam_firmware::constants::MUSCLE_VOLUME_POLY_M3.map(|c| c as f64),
        }
    }

    /// Eq. 7: the analytical model's mass flow [kg/s].
    pub fn mass_flow_kg_s(&self, s: &VolumeSample, thermo: &Thermo) -> f64 {
        let (v, vr) = self.volume_and_rate(s);
        thermo.mass_flow_kg_s(s, v, vr)
    }

    /// `V(e)` floored at `0.1 b0` (as the firmware) and `V' = dV/de e'`.
    pub fn volume_and_rate(&self, s: &VolumeSample) -> (f64, f64) {
        let [b0, b1, b2, b3] = self.coefficients_m3;
        let e = s.contraction;
        let v = (b0 + e * (b1 + e * (b2 + e * b3))).max(0.1 * b0);
        (
            v,
            (b1 + e * (2.0 * b2 + e * 3.0 * b3)) * s.contraction_rate_per_s,
        )
    }
}

/// The largest net mass flow into a muscle a recording may carry, kg/s.
pub const MAX_MASS_FLOW_KG_S: f64 = 0.1;

/// The samples of both muscles of a recording (angle_deg, p1_kpa, p2_kpa and the mass-flow
/// columns required), in time order per muscle (muscle 1's, then muscle 2's), leaving out the
/// `half_window` samples at each end where the derivative window is cut. Errors name the
/// missing column.
pub fn samples_from_recording(
    rec: &Recording,
    geometry: &JointGeometry,
    p_atm_pa: f64,
    half_window: usize,
) -> Result<[Vec<VolumeSample>; 2], String> {
    let need = |c: Channel| {
        rec.channel(c)
            .ok_or_else(|| format!("no `{}` column (needed by the volume fit)", c.name()))
    };
    let angle_deg = need(Channel::AngleDeg)?;
    let p_kpa = [need(Channel::P1Kpa)?, need(Channel::P2Kpa)?];
    let flows = rec.mass_flow_kg_s.as_ref().ok_or_else(|| {
        format!(
            "no `{}` / `{}` columns (the net mass flow into each muscle: a flow sensor's \
             reading; `host-sim simulate --scenario` writes the plant's)",
            MASS_FLOW_COLUMNS[0], MASS_FLOW_COLUMNS[1]
        )
    })?;
    // A valve a muscle of this size is driven through passes some 1e-2 kg/s; 0.1 kg/s
    // (about 5 000 standard litres a minute) is beyond any of them: a column in g/s or
    // another unit would train the network on flows a thousand times too large.
    for (i, f) in flows.iter().enumerate() {
        if let Some(k) = f.iter().position(|v| v.abs() > MAX_MASS_FLOW_KG_S) {
            return Err(format!(
                "column `{}` at t = {} s: {} kg/s, {} the {} kg/s no valve for a \
                 muscle of this size passes (the column is in kg/s: a flow in g/s is 1000 \
                 times too large)",
                MASS_FLOW_COLUMNS[i],
                crate::validate::Shown(rec.t_s[k]),
                crate::validate::Shown(f[k]),
                if f[k] < 0.0 {
                    "an outflow beyond"
                } else {
                    "above"
                },
                crate::validate::Shown(MAX_MASS_FLOW_KG_S)
            ));
        }
    }
    let n = rec.len();
    if n < 2 * half_window + 3 {
        return Err(format!(
            "{n} samples: fewer than the {} the derivative window needs",
            2 * half_window + 3
        ));
    }
    let dt = rec.sample_period_s();
    let ratio = geometry.sprocket_radius_m as f64 / geometry.rest_length_m as f64;
    let chi0 = geometry.initial_contraction as f64;
    let angle_rad: Vec<f64> = angle_deg.iter().map(|a| a.to_radians()).collect();
    let omega = crate::signal::savitzky_golay_derivative(&angle_rad, dt, half_window);
    let mut out: [Vec<VolumeSample>; 2] = Default::default();
    for (i, o) in out.iter_mut().enumerate() {
        let sign = if i == 0 { 1.0 } else { -1.0 };
        let p_pa: Vec<f64> = p_kpa[i].iter().map(|p| p * 1e3 + p_atm_pa).collect();
        let p_rate = crate::signal::savitzky_golay_derivative(&p_pa, dt, half_window);
        // Mass added up to t_k (the flow of sample k held over [t_k, t_k+1)).
        let mut mass = Vec::with_capacity(n);
        let mut acc = 0.0;
        for f in &flows[i] {
            mass.push(acc);
            acc += f * dt;
        }
        let m_dot = crate::signal::savitzky_golay_derivative(&mass, dt, half_window);
        for k in half_window..n - half_window - 1 {
            let s = VolumeSample {
                contraction: chi0 + sign * ratio * angle_rad[k],
                contraction_rate_per_s: sign * ratio * omega[k],
                p_abs_pa: p_pa[k],
                p_rate_pa_s: p_rate[k],
                m_dot_kg_s: m_dot[k],
            };
            if [
                s.contraction,
                s.contraction_rate_per_s,
                s.p_abs_pa,
                s.p_rate_pa_s,
                s.m_dot_kg_s,
            ]
            .iter()
            .any(|v| !v.is_finite())
            {
                return Err(format!("sample {k}: a non-finite value"));
            }
            o.push(s);
        }
    }
    check_flow_follows_pressure(&out)?;
    Ok(out)
}

/// The net flow into a muscle raises its pressure: each flow column must correlate positively
/// with its own muscle's pressure rate, and better than with the other muscle's. A sensor that
/// logs outflow as positive, or the two columns swapped, would train a network (and pass the
/// held-out comparison, the polynomial being as wrong on such data) that inverts the
/// feed-forward.
fn check_flow_follows_pressure(out: &[Vec<VolumeSample>; 2]) -> Result<(), String> {
    let corr = |a: &[VolumeSample], b: &[VolumeSample]| {
        let x: Vec<f64> = a.iter().map(|s| s.m_dot_kg_s).collect();
        let y: Vec<f64> = b.iter().map(|s| s.p_rate_pa_s).collect();
        crate::signal::correlation(&x, &y)
    };
    let own = [corr(&out[0], &out[0]), corr(&out[1], &out[1])];
    let cross = [corr(&out[0], &out[1]), corr(&out[1], &out[0])];
    // Antagonistic muscles' pressure rates run against each other: a negated column
    // correlates negatively with its own muscle and positively (less) with the other; swapped
    // columns positively (more) with the other muscle.
    if cross[0] > own[0].abs() && cross[1] > own[1].abs() {
        return Err(format!(
            "columns `{}` and `{}` follow the other muscle's pressure (correlation with their \
             own muscle's pressure rate {:.2} / {:.2}, with the other's {:.2} / {:.2}): the two \
             flow columns are swapped",
            MASS_FLOW_COLUMNS[0], MASS_FLOW_COLUMNS[1], own[0], own[1], cross[0], cross[1]
        ));
    }
    for i in 0..2 {
        if own[i] < 0.0 {
            // (|own| >= cross here, or the columns were named swapped above.)
            return Err(format!(
                "column `{}` runs against muscle {}'s pressure rate (correlation {:.2}): the \
                 column is the net flow INTO the muscle; a sensor logging the outflow as \
                 positive needs its sign flipped",
                MASS_FLOW_COLUMNS[i],
                i + 1,
                own[i]
            ));
        }
    }
    Ok(())
}

/// The network in f64 (the firmware kernel's structure).
#[derive(Clone, Debug, PartialEq)]
pub struct VolumeNet {
    /// Input means (e, e', P, P').
    pub input_mean: [f64; 4],
    /// Input standard deviations.
    pub input_std: [f64; 4],
    /// `w1` (row-major, H x 4), `b1`, `w2` (H x H), `b2`, `w3`, `b3`.
    pub theta: Vec<f64>,
    /// `V = volume_offset_m3 + volume_scale_m3 y`.
    pub volume_offset_m3: f64,
    pub volume_scale_m3: f64,
    /// Smallest volume the firmware returns [m^3].
    pub volume_floor_m3: f64,
}

/// `s(z)`, `s'(z)`, `s''(z)` of the softsign `z / (1 + |z|)`.
fn softsign(z: f64) -> (f64, f64, f64) {
    let d = 1.0 / (1.0 + z.abs());
    (z * d, d * d, -2.0 * z.signum() * d * d * d)
}

impl VolumeNet {
    /// The normalised inputs and the eq. 9 direction of a sample.
    fn inputs(&self, s: &VolumeSample) -> ([f64; 4], [f64; 4]) {
        let raw = [
            s.contraction,
            s.contraction_rate_per_s,
            s.p_abs_pa,
            s.p_rate_pa_s,
        ];
        let x = std::array::from_fn(|i| (raw[i] - self.input_mean[i]) / self.input_std[i]);
        let d = [
            s.contraction_rate_per_s / self.input_std[0],
            0.0,
            s.p_rate_pa_s / self.input_std[2],
            0.0,
        ];
        (x, d)
    }

    /// `(y, y')`: the output and its directional derivative along `d`; with `grad`, adds
    /// `g_y dy/dtheta + g_t dy'/dtheta` to `grad.0` (reverse mode through both passes).
    fn eval(
        theta: &[f64],
        x: &[f64; 4],
        d: &[f64; 4],
        grad: Option<(&mut [f64], f64, f64)>,
    ) -> (f64, f64) {
        const H: usize = HIDDEN;
        let (w1, rest) = theta.split_at(4 * H);
        let (b1, rest) = rest.split_at(H);
        let (w2, rest) = rest.split_at(H * H);
        let (b2, rest) = rest.split_at(H);
        let (w3, b3) = rest.split_at(H);
        let Layer {
            a: a1,
            ad: ad1,
            s: s1,
            zd: zd1,
        } = Layer::<H>::forward(w1, b1, x, d);
        let Layer {
            a: a2,
            ad: ad2,
            s: s2,
            zd: zd2,
        } = Layer::<H>::forward(w2, b2, &a1, &ad1);
        let mut y = b3[0];
        let mut yd = 0.0;
        for j in 0..H {
            y += w3[j] * a2[j];
            yd += w3[j] * ad2[j];
        }
        if let Some((g, gy, gt)) = grad {
            let (gw1, rest) = g.split_at_mut(4 * H);
            let (gb1, rest) = rest.split_at_mut(H);
            let (gw2, rest) = rest.split_at_mut(H * H);
            let (gb2, rest) = rest.split_at_mut(H);
            let (gw3, gb3) = rest.split_at_mut(H);
            gb3[0] += gy;
            let mut gz2 = [0.0; H];
            let mut gzd2 = [0.0; H];
            for j in 0..H {
                gw3[j] += gy * a2[j] + gt * ad2[j];
                let (ga, gad) = (gy * w3[j], gt * w3[j]);
                let (_, sp, spp) = s2[j];
                gzd2[j] = gad * sp;
                gz2[j] = ga * sp + gad * spp * zd2[j];
            }
            let mut ga1 = [0.0; H];
            let mut gad1 = [0.0; H];
            for j in 0..H {
                gb2[j] += gz2[j];
                for i in 0..H {
                    gw2[j * H + i] += gz2[j] * a1[i] + gzd2[j] * ad1[i];
                    ga1[i] += w2[j * H + i] * gz2[j];
                    gad1[i] += w2[j * H + i] * gzd2[j];
                }
            }
            for j in 0..H {
                let (_, sp, spp) = s1[j];
                let gzd = gad1[j] * sp;
                let gz = ga1[j] * sp + gad1[j] * spp * zd1[j];
                gb1[j] += gz;
                for i in 0..4 {
                    gw1[j * 4 + i] += gz * x[i] + gzd * d[i];
                }
            }
        }
        (y, yd)
    }

    /// Eq. 8 and 9: the volume [m^3] and its rate [m^3/s] (unfloored).
    pub fn volume_and_rate(&self, s: &VolumeSample) -> (f64, f64) {
        let (x, d) = self.inputs(s);
        let (y, yd) = Self::eval(&self.theta, &x, &d, None);
        (
            self.volume_offset_m3 + self.volume_scale_m3 * y,
            self.volume_scale_m3 * yd,
        )
    }

    /// Eq. 12: the hybrid model's mass flow [kg/s].
    pub fn mass_flow_kg_s(&self, s: &VolumeSample, thermo: &Thermo) -> f64 {
        let (v, vr) = self.volume_and_rate(s);
        thermo.mass_flow_kg_s(s, v, vr)
    }

    /// The firmware's form (f32; the standard deviations as reciprocals).
    pub fn to_firmware(&self) -> VolumeFnn {
        const H: usize = HIDDEN;
        let t = &self.theta;
        let f = |x: f64| x as f32;
        VolumeFnn {
            input_mean: self.input_mean.map(f),
            input_inv_std: self.input_std.map(|s| (1.0 / s) as f32),
            w1: std::array::from_fn(|j| std::array::from_fn(|i| f(t[j * 4 + i]))),
            b1: std::array::from_fn(|j| f(t[4 * H + j])),
            w2: std::array::from_fn(|j| std::array::from_fn(|i| f(t[5 * H + j * H + i]))),
            b2: std::array::from_fn(|j| f(t[5 * H + H * H + j])),
            w3: std::array::from_fn(|j| f(t[6 * H + H * H + j])),
            b3: f(t[7 * H + H * H]),
            volume_offset_m3: f(self.volume_offset_m3),
            volume_scale_m3: f(self.volume_scale_m3),
            volume_floor_m3: f(self.volume_floor_m3),
        }
    }

    /// The `[volume_fnn]` table of `config/volume.toml` (build.rs reads it).
    pub fn toml_table(&self) -> String {
        const H: usize = HIDDEN;
        let t = &self.theta;
        let list = |v: &[f64]| {
            format!(
                "[{}]",
                v.iter()
                    .map(|x| format!("{x:e}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        };
        let rows = |v: &[f64], w: usize| {
            format!(
                "[\n{}]",
                v.chunks(w)
                    .map(|r| format!("  {},\n", list(r)))
                    .collect::<String>()
            )
        };
        let mut s = String::new();
        let _ = writeln!(s, "[volume_fnn]");
        let _ = writeln!(s, "hidden_units = [{H}, {H}]");
        let _ = writeln!(s, "activation = \"softsign\"");
        let _ = writeln!(s, "input_mean = {}", list(&self.input_mean));
        let _ = writeln!(s, "input_std = {}", list(&self.input_std));
        let _ = writeln!(s, "volume_offset_m3 = {:e}", self.volume_offset_m3);
        let _ = writeln!(s, "volume_scale_m3 = {:e}", self.volume_scale_m3);
        let _ = writeln!(s, "volume_floor_m3 = {:e}", self.volume_floor_m3);
        let _ = writeln!(s, "w1 = {}", rows(&t[..4 * H], 4));
        let _ = writeln!(s, "b1 = {}", list(&t[4 * H..5 * H]));
        let _ = writeln!(s, "w2 = {}", rows(&t[5 * H..5 * H + H * H], H));
        let _ = writeln!(s, "b2 = {}", list(&t[5 * H + H * H..6 * H + H * H]));
        let _ = writeln!(s, "w3 = {}", list(&t[6 * H + H * H..7 * H + H * H]));
        let _ = writeln!(s, "b3 = {:e}", t[7 * H + H * H]);
        s
    }
}

/// Training options.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainOptions {
    /// Weight decay `lambda` of eq. 10.
    pub weight_decay: f64,
    /// Seed of the random start.
    pub seed: u64,
    /// Levenberg-Marquardt budget: at most this many loss evaluations.
    pub max_evaluations: usize,
}

impl Default for TrainOptions {
    /// Seed 004's weight decay (1e-5); 2000 evaluations.
    fn default() -> Self {
        TrainOptions {
            weight_decay: 1e-5,
            seed: 1,
            max_evaluations: 2000,
        }
    }
}

/// A trained network and its figures.
#[derive(Clone, Debug)]
pub struct Trained {
    pub net: VolumeNet,
    /// Loss of eq. 10 at the start and at the end.
    pub loss_start: f64,
    pub loss_end: f64,
    /// Loss evaluations used.
    pub evaluations: usize,
    /// Why the optimiser stopped.
    pub termination: String,
}

/// Mean squared mass-flow error [(kg/s)^2] of `model` over `samples`.
pub fn mse_kg2_s2(samples: &[VolumeSample], model: impl Fn(&VolumeSample) -> f64) -> f64 {
    samples
        .iter()
        .map(|s| (model(s) - s.m_dot_kg_s).powi(2))
        .sum::<f64>()
        / samples.len().max(1) as f64
}

struct Problem<'a> {
    samples: &'a [VolumeSample],
    net: VolumeNet,
    thermo: Thermo,
    inv_sm_sqrt_n: f64,
    sqrt_half_lambda: f64,
    evaluations: Cell<usize>,
    progress: &'a dyn Fn(usize),
}

impl Problem<'_> {
    /// Residual of sample `s` and its `(g_y, g_t)` (d residual / d y, d residual / d y').
    fn factors(&self, s: &VolumeSample) -> (f64, f64) {
        let a = s.p_rate_pa_s / (self.thermo.polytropic_index * self.thermo.rt_j_per_kg);
        let b = s.p_abs_pa / self.thermo.rt_j_per_kg;
        let k = self.inv_sm_sqrt_n * self.net.volume_scale_m3;
        (a * k, b * k)
    }

    fn loss(&self) -> f64 {
        self.residuals_vec().iter().map(|r| r * r).sum()
    }

    fn residuals_vec(&self) -> Vec<f64> {
        let mut r = Vec::with_capacity(self.samples.len() + PARAMETERS);
        for s in self.samples {
            let m = self.net.mass_flow_kg_s(s, &self.thermo);
            r.push((m - s.m_dot_kg_s) * self.inv_sm_sqrt_n);
        }
        r.extend(self.net.theta.iter().map(|t| t * self.sqrt_half_lambda));
        r
    }
}

impl LeastSquaresProblem<f64, Dyn, Dyn> for Problem<'_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, x: &DVector<f64>) {
        self.net.theta.copy_from_slice(x.as_slice());
    }

    fn params(&self) -> DVector<f64> {
        DVector::from_column_slice(&self.net.theta)
    }

    fn residuals(&self) -> Option<DVector<f64>> {
        let n = self.evaluations.get() + 1;
        self.evaluations.set(n);
        (self.progress)(n);
        let r = DVector::from_vec(self.residuals_vec());
        r.iter().all(|v| v.is_finite()).then_some(r)
    }

    fn jacobian(&self) -> Option<DMatrix<f64>> {
        let n = self.samples.len();
        let mut j = DMatrix::<f64>::zeros(n + PARAMETERS, PARAMETERS);
        let mut row = vec![0.0; PARAMETERS];
        for (k, s) in self.samples.iter().enumerate() {
            row.iter_mut().for_each(|v| *v = 0.0);
            let (x, d) = self.net.inputs(s);
            let (gy, gt) = self.factors(s);
            VolumeNet::eval(&self.net.theta, &x, &d, Some((&mut row, gy, gt)));
            for (c, v) in row.iter().enumerate() {
                j[(k, c)] = *v;
            }
        }
        for c in 0..PARAMETERS {
            j[(n + c, c)] = self.sqrt_half_lambda;
        }
        j.iter().all(|v| v.is_finite()).then_some(j)
    }
}

/// Relative loss reduction below which the Levenberg-Marquardt iteration stops (the
/// crate's default, 1.5e-8, lets it creep on for thousands of evaluations at no gain on
/// held-out data).
pub const FTOL: f64 = 1e-6;

/// Trains the network on `samples` (eq. 10) from a random start (`opt.seed`); the output
/// scale and offset and the input normalisation come from the samples and the polynomial
/// volume `poly` (the offset its mean, the scale its spread, the floor its `0.1 b0`).
/// `progress` gets the number of loss evaluations so far.
pub fn train(
    samples: &[VolumeSample],
    poly: &VolumePoly,
    thermo: &Thermo,
    opt: &TrainOptions,
    progress: &dyn Fn(usize),
) -> Result<Trained, String> {
    if samples.len() < 2 * PARAMETERS {
        return Err(format!(
            "{} samples: at least {} needed for {PARAMETERS} weights",
            samples.len(),
            2 * PARAMETERS
        ));
    }
    let nf = samples.len() as f64;
    let stat = |f: &dyn Fn(&VolumeSample) -> f64| {
        let mean = samples.iter().map(f).sum::<f64>() / nf;
        let var = samples.iter().map(|s| (f(s) - mean).powi(2)).sum::<f64>() / nf;
        (mean, var.sqrt())
    };
    let cols: [&dyn Fn(&VolumeSample) -> f64; 4] = [
        &|s| s.contraction,
        &|s| s.contraction_rate_per_s,
        &|s| s.p_abs_pa,
        &|s| s.p_rate_pa_s,
    ];
    let mut input_mean = [0.0; 4];
    let mut input_std = [0.0; 4];
    for (i, c) in cols.iter().enumerate() {
        let (m, s) = stat(*c);
        input_mean[i] = m;
        if !(s > 0.0 && s.is_finite()) {
            return Err(format!(
                "input {} ({}) does not vary over the samples",
                i,
                ["e", "e'", "P", "P'"][i]
            ));
        }
        input_std[i] = s;
    }
    let (_, sm) = stat(&|s| s.m_dot_kg_s);
    if !(sm > 0.0 && sm.is_finite()) {
        return Err("the mass flow does not vary over the samples".into());
    }
    let (v_mean, v_std) = stat(&|s| poly.volume_and_rate(s).0);
    let b0 = poly.coefficients_m3[0];
    // Xavier-uniform start, reproducible from the seed.
    let mut rng = rand::rngs::StdRng::seed_from_u64(opt.seed);
    let mut theta = vec![0.0; PARAMETERS];
    let h = HIDDEN;
    let layers = [
        (0, 4 * h, 4, h),
        (5 * h, h * h, h, h),
        (6 * h + h * h, h, h, 1),
    ];
    for (start, len, fan_in, fan_out) in layers {
        let lim = (6.0 / (fan_in + fan_out) as f64).sqrt();
        for t in &mut theta[start..start + len] {
            *t = rng.random_range(-lim..lim);
        }
    }
    let net = VolumeNet {
        input_mean,
        input_std,
        theta,
        volume_offset_m3: v_mean,
        volume_scale_m3: v_std.max(0.05 * v_mean.abs()).max(1e-9),
        volume_floor_m3: 0.1 * b0,
    };
    let problem = Problem {
        samples,
        net,
        thermo: *thermo,
        inv_sm_sqrt_n: 1.0 / (sm * nf.sqrt()),
        sqrt_half_lambda: (opt.weight_decay / 2.0).sqrt(),
        evaluations: Cell::new(0),
        progress,
    };
    let loss_start = problem.loss();
    let patience = opt.max_evaluations.div_ceil(PARAMETERS + 1).max(1);
    let (problem, report) = LevenbergMarquardt::new()
        .with_patience(patience)
        .with_ftol(FTOL)
        .minimize(problem);
    let loss_end = problem.loss();
    if !loss_end.is_finite() || problem.net.theta.iter().any(|t| !t.is_finite()) {
        return Err(format!(
            "the fit diverged ({:?}); try another --seed",
            report.termination
        ));
    }
    Ok(Trained {
        evaluations: problem.evaluations.get(),
        net: problem.net,
        loss_start,
        loss_end,
        termination: format!("{:?}", report.termination),
    })
}

/// One softsign layer's forward pass with its tangent along the eq. 9 direction (the
/// network's two hidden layers).
struct Layer<const H: usize> {
    /// Activations.
    a: [f64; H],
    /// Their directional derivatives.
    ad: [f64; H],
    /// Softsign (value, first, second derivative) at each pre-activation.
    s: [(f64, f64, f64); H],
    /// Directional derivative of each pre-activation.
    zd: [f64; H],
}

impl<const H: usize> Layer<H> {
    /// The layer of weights `w` (`H` rows of `x.len()`) and biases `b` over the inputs `x`
    /// with directional derivatives `xd`.
    fn forward(w: &[f64], b: &[f64], x: &[f64], xd: &[f64]) -> Self {
        let n = x.len();
        let mut l = Layer {
            a: [0.0; H],
            ad: [0.0; H],
            s: [(0.0, 0.0, 0.0); H],
            zd: [0.0; H],
        };
        for j in 0..H {
            let mut z = b[j];
            let mut zd = 0.0;
            for i in 0..n {
                z += w[j * n + i] * x[i];
                zd += w[j * n + i] * xd[i];
            }
            l.s[j] = softsign(z);
            l.zd[j] = zd;
            l.a[j] = l.s[j].0;
            l.ad[j] = l.s[j].1 * zd;
        }
        l
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn net() -> VolumeNet {
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        VolumeNet {
            input_mean: [0.14, 0.0, 4.0e5, 0.0],
            input_std: [0.05, 0.5, 1.5e5, 1.0e6],
            theta: (0..PARAMETERS)
                .map(|_| rng.random_range(-0.9..0.9))
                .collect(),
            volume_offset_m3: 1.0e-4,
            volume_scale_m3: 2.0e-5,
            volume_floor_m3: 1.0e-6,
        }
    }

    fn sample() -> VolumeSample {
        VolumeSample {
            contraction: 0.16,
            contraction_rate_per_s: -0.3,
            p_abs_pa: 3.5e5,
            p_rate_pa_s: 4.0e5,
            m_dot_kg_s: 0.0,
        }
    }

    #[test]
    fn a_flow_column_in_another_unit_is_refused_by_its_sign() {
        let n = 40;
        let mut rec = Recording {
            t_s: (0..n).map(|k| k as f64 * 1e-3).collect(),
            inputs: vec![crate::plant::ValveInputs::default(); n],
            ..Recording::default()
        };
        rec.set_channel(Channel::AngleDeg, vec![0.0; n]);
        rec.set_channel(Channel::P1Kpa, vec![300.0; n]);
        rec.set_channel(Channel::P2Kpa, vec![300.0; n]);
        let geometry = JointGeometry::REFERENCE;
        for (flow, says) in [(5.0, "5 kg/s, above"), (-5.0, "-5 kg/s, an outflow beyond")] {
            let mut f = vec![0.0; n];
            f[10] = flow;
            rec.mass_flow_kg_s = Some([f, vec![0.0; n]]);
            let e = samples_from_recording(&rec, &geometry, 101_325.0, 3).unwrap_err();
            assert!(e.contains(says) && e.contains("g/s"), "{e}");
        }
    }

    #[test]
    fn the_gradient_matches_finite_differences() {
        let n = net();
        let s = sample();
        let (x, d) = n.inputs(&s);
        let (gy, gt) = (0.7, -1.3);
        let mut g = vec![0.0; PARAMETERS];
        VolumeNet::eval(&n.theta, &x, &d, Some((&mut g, gy, gt)));
        let f = |th: &[f64]| {
            let (y, yd) = VolumeNet::eval(th, &x, &d, None);
            gy * y + gt * yd
        };
        for c in 0..PARAMETERS {
            let h = 1e-6;
            let mut p = n.theta.clone();
            p[c] += h;
            let mut m = n.theta.clone();
            m[c] -= h;
            let fd = (f(&p) - f(&m)) / (2.0 * h);
            assert!(
                (g[c] - fd).abs() < 1e-6 * (1.0 + fd.abs()),
                "{c}: {} vs {fd}",
                g[c]
            );
        }
    }

    #[test]
    fn the_tangent_is_the_volume_rate_along_the_motion() {
        let n = net();
        let s = sample();
        let (_, rate) = n.volume_and_rate(&s);
        let h = 1e-5;
        let at = |t: f64| {
            n.volume_and_rate(&VolumeSample {
                contraction: s.contraction + s.contraction_rate_per_s * t,
                p_abs_pa: s.p_abs_pa + s.p_rate_pa_s * t,
                ..s
            })
            .0
        };
        let fd = (at(h) - at(-h)) / (2.0 * h);
        assert!(
            (rate - fd).abs() < 1e-6 * fd.abs().max(1e-12),
            "{rate} vs {fd}"
        );
    }

    #[test]
    fn the_firmware_kernel_agrees_with_the_f64_network() {
        let n = net();
        let fw = n.to_firmware();
        for s in [
            sample(),
            VolumeSample {
                contraction: 0.10,
                contraction_rate_per_s: 0.8,
                p_abs_pa: 5.5e5,
                p_rate_pa_s: -1.0e6,
                m_dot_kg_s: 0.0,
            },
        ] {
            let (v, r) = n.volume_and_rate(&s);
            let (vf, rf) = fw.volume_and_rate(
                s.contraction as f32,
                s.contraction_rate_per_s as f32,
                s.p_abs_pa as f32,
                s.p_rate_pa_s as f32,
            );
            assert!(((vf as f64) - v).abs() < 1e-5 * v.abs(), "{v} {vf}");
            assert!(
                ((rf as f64) - r).abs() < 1e-3 * r.abs().max(1e-9),
                "{r} {rf}"
            );
        }
    }
}

/// Arguments of `host-sim identify volume`.
#[derive(Debug)]
pub struct IdentifyVolumeArgs {
    /// Recording with angle_deg, p1_kpa, p2_kpa and the mass-flow columns m_dot_1_kg_s,
    /// m_dot_2_kg_s (RECORDING.md; `host-sim simulate --scenario` writes them).
    pub recording: std::path::PathBuf,
    /// Output TOML (the format of config/volume.toml).
    pub out: std::path::PathBuf,
    /// Seed of the random start (the same seed and recording give the same file;
    /// 0..=18446744073709551615).
    pub seed: u64,
    /// Weight decay lambda (the penalty on the network's squared weights in the training
    /// loss, eq. 10 of the learned-inverse-thermodynamics paper).
    pub weight_decay: f64,
    /// Levenberg-Marquardt budget [loss evaluations].
    pub max_evals: usize,
    /// Half window of the Savitzky-Golay derivatives [samples] [default: 10 ms worth].
    pub savgol_half_window: Option<usize>,
    /// Fraction of the recording (its tail) held out for the validation figures.
    pub holdout_fraction: f64,
    /// Also report the mass-flow errors on these recordings (not trained on; comma
    /// separated).
    pub validate: Vec<std::path::PathBuf>,
    /// At most this many training samples (both muscles; evenly thinned).
    pub max_samples: usize,
    /// Write the network even when its mass-flow error on the held-out tail (or on a
    /// --validate recording) is not below the polynomial volume's, or when nothing is held out
    /// to judge it by (docs/identification.md).
    pub allow_worse: bool,
}

/// Least training samples (both muscles) per network weight: fewer and the network fits the
/// noise of a short stretch of motion.
pub const MIN_SAMPLES_PER_WEIGHT: usize = 10;
/// Least joint angle range of the training part [deg]: below it the contraction barely
/// changes and the network learns nothing about the volume's dependence on it.
pub const MIN_TRAINING_ANGLE_RANGE_DEG: f64 = 5.0;

/// Refuses training data that cannot determine the network (before any training): fewer
/// than [`MIN_SAMPLES_PER_WEIGHT`] samples per weight, a joint that moves less than
/// [`MIN_TRAINING_ANGLE_RANGE_DEG`], or a pressure that does not vary (sd below
/// [`super::MIN_PRESSURE_SD_KPA`]) in the training part of the recording.
pub fn check_training_data(
    per_muscle: &[Vec<VolumeSample>; 2],
    holdout_fraction: f64,
    geometry: &JointGeometry,
) -> Result<(), String> {
    let advice = "record the joint moving over its range with the pressures varying \
                  (e.g. `host-sim simulate --scenario scenarios/volume_training.toml`), \
                  a few seconds at least";
    let train: Vec<&[VolumeSample]> = per_muscle
        .iter()
        .map(|m| &m[..((m.len() as f64) * (1.0 - holdout_fraction)).round() as usize])
        .collect();
    let n: usize = train.iter().map(|m| m.len()).sum();
    let need = MIN_SAMPLES_PER_WEIGHT * PARAMETERS;
    if n < need {
        return Err(format!(
            "{n} training samples (both muscles, after --holdout-fraction {holdout_fraction}): \
             fewer than the {need} ({MIN_SAMPLES_PER_WEIGHT} per weight of the {PARAMETERS}) \
             the network needs; {advice}"
        ));
    }
    let ratio = geometry.sprocket_radius_m as f64 / geometry.rest_length_m as f64;
    let (lo, hi) = train[0]
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), s| {
            (l.min(s.contraction), h.max(s.contraction))
        });
    let range_deg = ((hi - lo) / ratio).to_degrees();
    if !(range_deg >= MIN_TRAINING_ANGLE_RANGE_DEG) {
        return Err(format!(
            "column `angle_deg`: the joint moves over {range_deg:.2} deg in the training part \
             (the first {:.0} % of the recording), below the {MIN_TRAINING_ANGLE_RANGE_DEG} deg \
             the network needs to learn the volume's dependence on the contraction; {advice}",
            100.0 * (1.0 - holdout_fraction)
        ));
    }
    for (i, m) in train.iter().enumerate() {
        let mean = m.iter().map(|s| s.p_abs_pa).sum::<f64>() / m.len() as f64;
        let sd_kpa = (m.iter().map(|s| (s.p_abs_pa - mean).powi(2)).sum::<f64>() / m.len() as f64)
            .sqrt()
            / 1e3;
        let min_kpa = super::MIN_PRESSURE_SD_KPA;
        if !(sd_kpa >= min_kpa) {
            return Err(format!(
                "column `p{}_kpa`: sd {sd_kpa:.3} kPa in the training part, below {min_kpa} kPa: \
                 the pressure does not vary; {advice}",
                i + 1
            ));
        }
    }
    Ok(())
}

/// Eq. 7 with the firmware's volume explaining the flow columns this many times better with
/// one atmosphere taken off the pressures says the columns were logged absolute.
pub const ABSOLUTE_FLOW_GAIN_ABOVE: f64 = 4.0;

/// Refuses pressures logged absolute: the network would learn the volume of a muscle one
/// atmosphere higher than the firmware feeds it. Pressure enters eq. 7 through `P V'` only, so
/// the test has power where the joint moves; a polynomial unlike the rig's volume does not
/// gain from the shift.
pub fn check_gauge_pressures(
    per_muscle: &[Vec<VolumeSample>; 2],
    poly: &VolumePoly,
    thermo: &Thermo,
    p_atm_pa: f64,
) -> Result<(), String> {
    let samples = [per_muscle[0].as_slice(), per_muscle[1].as_slice()].concat();
    let flow = |s: &VolumeSample| poly.mass_flow_kg_s(s, thermo);
    let as_given = mse_kg2_s2(&samples, flow);
    let lowered: Vec<VolumeSample> = samples
        .iter()
        .map(|s| VolumeSample {
            p_abs_pa: s.p_abs_pa - p_atm_pa,
            ..*s
        })
        .collect();
    let shifted = mse_kg2_s2(&lowered, flow);
    if shifted * ABSOLUTE_FLOW_GAIN_ABOVE < as_given {
        return Err(format!(
            "the pressure columns look absolute, not gauge: eq. 7 with the firmware's volume \
             explains the flow columns {:.1} times better with one atmosphere ({:.3} kPa) taken \
             off them (mass-flow MSE {as_given:.3e} -> {shifted:.3e} (kg/s)^2). RECORDING.md's \
             columns are gauge: subtract p_atm or import with reference = \"absolute\"",
            as_given / shifted.max(f64::MIN_POSITIVE),
            p_atm_pa * 1e-3
        ));
    }
    Ok(())
}

/// Training and hold-out samples of a recording, thinned to at most `max_samples` training
/// samples: the tail `holdout_fraction` of each muscle's samples is held out.
pub fn split_samples(
    per_muscle: &[Vec<VolumeSample>; 2],
    holdout_fraction: f64,
    max_samples: usize,
) -> (Vec<VolumeSample>, Vec<VolumeSample>) {
    let mut train = Vec::new();
    let mut held = Vec::new();
    for m in per_muscle {
        let cut = ((m.len() as f64) * (1.0 - holdout_fraction)).round() as usize;
        train.extend_from_slice(&m[..cut]);
        held.extend_from_slice(&m[cut..]);
    }
    let stride = train.len().div_ceil(max_samples.max(1)).max(1);
    let train = train.into_iter().step_by(stride).collect();
    (train, held)
}

/// `host-sim identify volume`: trains, writes the TOML, returns the report. Steps: the files
/// checked, the samples of the recording and of the validation recordings, the training
/// data checked, the network trained, judged against the polynomial volume on data it was
/// not trained on, then written with its header.
pub fn run_identify_volume(a: &IdentifyVolumeArgs) -> anyhow::Result<String> {
    use anyhow::Context;
    check_volume_files(a)?;
    let rec = Recording::read(&a.recording)?.to_uniform();
    let file = a.recording.display().to_string();
    let hw = a
        .savgol_half_window
        .unwrap_or_else(|| half_window_samples(0.010, rec.sample_period_s()));
    if a.savgol_half_window.is_some() {
        crate::signal::window_fits(
            "--savgol-half-window",
            hw,
            rec.len(),
            rec.sample_period_s(),
            &file,
        )?;
    }
    let geometry = pam_firmware::constants::JOINT_GEOMETRY;
    let p_atm = pam_firmware::constants::P_ATM_PA as f64;
    let per_muscle = samples_from_recording(&rec, &geometry, p_atm, hw)
        .map_err(|e| anyhow::anyhow!("{file}: {e}"))?;
    // The validation recordings are read (and refused) before any training.
    let validation = validation_samples(a, &geometry, p_atm)?;
    check_training_data(&per_muscle, a.holdout_fraction, &geometry)
        .map_err(|e| anyhow::anyhow!("{file}: {e} (nothing written)"))?;
    let (train_s, held) = split_samples(&per_muscle, a.holdout_fraction, a.max_samples);
    let thermo = Thermo::firmware();
    let poly = VolumePoly::firmware();
    check_gauge_pressures(&per_muscle, &poly, &thermo, p_atm)
        .map_err(|e| anyhow::anyhow!("{file}: {e} (nothing written)"))?;
    let t =
        train_with_bar(a, &train_s, &poly, &thermo).map_err(|e| anyhow::anyhow!("{file}: {e}"))?;
    let mut sets = vec![
        ("training".to_string(), &train_s),
        ("held out (recording tail)".to_string(), &held),
    ];
    sets.extend(validation.iter().map(|(n, s)| (n.clone(), s)));
    sets.retain(|(_, s)| !s.is_empty());
    let poly_flow = |s: &VolumeSample| poly.mass_flow_kg_s(s, &thermo);
    let hm = |s: &VolumeSample| t.net.mass_flow_kg_s(s, &thermo);
    let errors: Vec<SetErrors> = sets
        .into_iter()
        .map(|(name, s)| SetErrors {
            name,
            samples: s.len(),
            poly_mse: mse_kg2_s2(s, poly_flow),
            hybrid_mse: mse_kg2_s2(s, hm),
        })
        .collect();
    let figures: Vec<String> = errors.iter().map(SetErrors::figure).collect();
    if !a.allow_worse {
        network_beats_polynomial(&errors).map_err(|e| anyhow::anyhow!("{file}: {e}"))?;
    }
    let fw = t.net.to_firmware();
    anyhow::ensure!(
        fw.is_valid(),
        "{file}: the trained weights do not fit the firmware's f32 (try another --seed)"
    );
    let header = volume_header(a, hw, &thermo, &t, &rec, &figures);
    let text = format!("{header}\n{}", t.net.toml_table());
    super::write_atomic(&a.out, text.as_bytes()).context("--out")?;
    let mut report = String::new();
    let _ = writeln!(
        report,
        "{}: hybrid volume, 2 x {HIDDEN} softsign units, {PARAMETERS} weights; loss {:.4e} -> {:.4e} in {} evaluations ({})",
        a.out.display(),
        t.loss_start,
        t.loss_end,
        t.evaluations,
        t.termination
    );
    for f in &figures {
        let _ = writeln!(report, "{f}");
    }
    Ok(report)
}

/// No output is an input, `--out` may be replaced, and no validation recording is the
/// training one (a validation recording is one the network was not trained on).
fn check_volume_files(a: &IdentifyVolumeArgs) -> anyhow::Result<()> {
    let mut inputs = vec![("--recording", a.recording.as_path())];
    inputs.extend(a.validate.iter().map(|v| ("--validate", v.as_path())));
    crate::validate::distinct_file_outputs(&inputs, &[("--out", &a.out)])
        .map_err(anyhow::Error::msg)?;
    crate::validate::replaceable("--out", &a.out, crate::validate::OutputKind::VOLUME_FNN)
        .map_err(anyhow::Error::msg)?;
    if let Some(v) = a
        .validate
        .iter()
        .find(|v| crate::validate::same_existing_file(v, &a.recording))
    {
        anyhow::bail!(
            "--validate {}: is the same file as --recording {}; give a recording the network \
             is not trained on (its own held-out part is already reported)",
            v.display(),
            a.recording.display()
        );
    }
    Ok(())
}

/// The samples of each `--validate` recording (both muscles), named for the report.
fn validation_samples(
    a: &IdentifyVolumeArgs,
    geometry: &JointGeometry,
    p_atm: f64,
) -> anyhow::Result<Vec<(String, Vec<VolumeSample>)>> {
    let mut validation = Vec::new();
    for v in &a.validate {
        let r = Recording::read(v)?.to_uniform();
        let hw_v = a
            .savgol_half_window
            .unwrap_or_else(|| half_window_samples(0.010, r.sample_period_s()));
        let [m1, m2] = samples_from_recording(&r, geometry, p_atm, hw_v)
            .map_err(|e| anyhow::anyhow!("{}: {e}", v.display()))?;
        validation.push((
            format!("{} (not trained on)", v.display()),
            [m1, m2].concat(),
        ));
    }
    Ok(validation)
}

/// Trains the network on `train_s` with a progress bar over the loss evaluations.
fn train_with_bar(
    a: &IdentifyVolumeArgs,
    train_s: &[VolumeSample],
    poly: &VolumePoly,
    thermo: &Thermo,
) -> Result<Trained, String> {
    let opt = TrainOptions {
        weight_decay: a.weight_decay,
        seed: a.seed,
        max_evaluations: a.max_evals,
    };
    let bar = indicatif::ProgressBar::with_draw_target(
        Some(a.max_evals as u64),
        indicatif::ProgressDrawTarget::stderr(),
    );
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{spinner} identify volume [{bar:40}] {pos}/{len} loss evaluations {elapsed}",
        )
        .expect("static template")
        .progress_chars("=> "),
    );
    let t = train(train_s, poly, thermo, &opt, &|n| bar.set_position(n as u64))?;
    bar.finish_and_clear();
    Ok(t)
}

/// The mass-flow errors of the polynomial volume and of the network on one data set.
struct SetErrors {
    name: String,
    samples: usize,
    /// Mass-flow MSE [(kg/s)^2].
    poly_mse: f64,
    hybrid_mse: f64,
}

impl SetErrors {
    /// The report's line of the set.
    fn figure(&self) -> String {
        let (name, n, a, h) = (&self.name, self.samples, self.poly_mse, self.hybrid_mse);
        format!(
            "{name}: {n} samples, mass-flow MSE polynomial volume {a:.3e}, hybrid {h:.3e} (kg/s)^2 ({:.2}x)",
            a / h
        )
    }
}

/// The network is judged on data it was not trained on (every set but "training"): there
/// must be some, and it must beat the polynomial volume on each; the refusal says why (within
/// 20 % of the polynomial everywhere: the polynomial already describes this muscle).
fn network_beats_polynomial(errors: &[SetErrors]) -> Result<(), String> {
    let judged: Vec<&SetErrors> = errors.iter().filter(|e| e.name != "training").collect();
    if judged.is_empty() {
        return Err(
            "nothing held out to judge the network by (--holdout-fraction 0 and no \
             --validate); nothing written. Give --holdout-fraction > 0 or --validate R2.csv; \
             --allow-worse writes the network anyway"
                .into(),
        );
    }
    let worse: Vec<String> = judged
        .iter()
        .filter(|e| !(e.hybrid_mse < e.poly_mse))
        .map(|e| {
            let (name, p, h) = (&e.name, e.poly_mse, e.hybrid_mse);
            format!(
                "{name}: hybrid {h:.3e} vs polynomial {p:.3e} (kg/s)^2 ({:.2}x)",
                p / h
            )
        })
        .collect();
    // Within 20 % of the polynomial everywhere it is judged: the polynomial volume already
    // describes this muscle, and more recording would not change that.
    let close = judged.iter().all(|e| e.poly_mse / e.hybrid_mse >= 0.8);
    let advice = if close {
        "the network matches the polynomial volume without beating it: the polynomial \
         already describes this muscle's volume, and the network has nothing to add; keep \
         the polynomial volume (--allow-worse writes the network anyway)"
    } else {
        "record the joint moving over its whole range with varying pressures, and more \
                      of it (e.g. `host-sim simulate --scenario scenarios/volume_training.toml`); \
                      or keep the polynomial volume; --allow-worse writes the network anyway"
    };
    if !worse.is_empty() {
        return Err(format!(
            "the trained network's mass-flow error is not below the polynomial \
             volume's on data it was not trained on, so it would make the feed-forward worse; \
             nothing written.\n  {}\n{advice}",
            worse.join("\n  ")
        ));
    }
    Ok(())
}

/// The volume file's header: what the network is, the command that wrote it, the training,
/// the recording's provenance and the error of each data set.
fn volume_header(
    a: &IdentifyVolumeArgs,
    hw: usize,
    thermo: &Thermo,
    t: &Trained,
    rec: &Recording,
    figures: &[String],
) -> String {
    let file = a.recording.display().to_string();
    let mut header = String::new();
    let _ = writeln!(
        header,
        "# Hybrid-model chamber volume of the pressure feed-forward (seed 004 eq. 8-12;\n\
         # src/volume_fnn.rs): V(e, e', P, P') by a network of two hidden layers of {HIDDEN} softsign\n\
         # units ({PARAMETERS} weights), inputs normalised by the means / standard deviations below,\n\
         # V = volume_offset_m3 + volume_scale_m3 y, floored at volume_floor_m3. build.rs turns it\n\
         # into `pam_firmware::constants::VOLUME_FNN` (used with the crate feature `volume-fnn`).\n\
         # Inputs: e = contraction (config/joint_geometry.toml at the angle), e' [1/s], P [Pa abs],\n\
         # P' [Pa/s]; eq. 12 with k = {}, R T = {} J/kg (config/pressure_ff.toml).\n\
         #\n\
         # Written by `host-sim identify volume --recording {file} --seed {} --weight-decay {}\n\
         #   --max-evals {} --holdout-fraction {} --max-samples {}` (Savitzky-Golay half window {hw}).\n\
         # Levenberg-Marquardt: loss (eq. 10) {:.4e} -> {:.4e} in {} evaluations ({}).",
        thermo.polytropic_index,
        thermo.rt_j_per_kg,
        a.seed,
        a.weight_decay,
        a.max_evals,
        a.holdout_fraction,
        a.max_samples,
        t.loss_start,
        t.loss_end,
        t.evaluations,
        t.termination,
    );
    let meta: Vec<String> = ["plant", "scenario", "source"]
        .iter()
        .filter_map(|k| rec.meta(k).map(|v| format!("{k} = {v}")))
        .collect();
    if !meta.is_empty() {
        let _ = writeln!(header, "# The recording's {}.", meta.join(", "));
    }
    for f in figures {
        let _ = writeln!(header, "# {f}");
    }
    header
}

#[cfg(test)]
mod judge_tests {
    use super::*;

    fn set(name: &str, poly_mse: f64, hybrid_mse: f64) -> SetErrors {
        SetErrors {
            name: name.into(),
            samples: 100,
            poly_mse,
            hybrid_mse,
        }
    }

    #[test]
    fn the_network_must_beat_the_polynomial_on_every_set_it_was_not_trained_on() {
        assert!(
            network_beats_polynomial(&[set("training", 1.0, 2.0), set("held out", 2.0, 1.0)])
                .is_ok()
        );
        let only_training = network_beats_polynomial(&[set("training", 2.0, 1.0)]).unwrap_err();
        assert!(
            only_training.starts_with("nothing held out"),
            "{only_training}"
        );
        let worse = network_beats_polynomial(&[set("held out", 1.0, 2.0), set("R2", 2.0, 1.0)])
            .unwrap_err();
        assert!(
            worse.contains("held out: hybrid") && !worse.contains("R2:"),
            "{worse}"
        );
        assert!(worse.contains("record the joint moving"), "{worse}");
        // Within 20 % of the polynomial everywhere: the polynomial already describes it.
        let close = network_beats_polynomial(&[set("held out", 1.0, 1.1)]).unwrap_err();
        assert!(close.contains("nothing to add"), "{close}");
    }
}
