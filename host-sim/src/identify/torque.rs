//! Identification of the simplified joint torque model (seed 003, eq. 11):
//!
//! ```text
//! T = A r^2 alpha + B r dp + C alpha'^3 + D alpha'
//! ```
//!
//! from samples of joint angle, muscle pressures and the force-derived torque
//! `T = (F1 - F2) r` (PLANT.md sign: positive torque drives the angle up). The activation is
//! the paper's symmetric scheme `p1 = p0 - dp`, `p2 = p0 + dp`, so `dp = (p2 - p1) / 2` and
//! `p0` is the mean of `(p1 + p2) / 2` over the data. The model is linear in A, B, C, D: an
//! ordinary least-squares problem (SVD, nalgebra).
//!
//! As in seed 003, the data should contain quasi-static motion at several activations and
//! motion at (piecewise) constant velocities; [`sweep_kinematics`] generates such a sweep.

use std::fmt::Write as _;

use nalgebra::{DMatrix, DVector};

use super::IdentError;

/// One sample for the torque fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TorqueSample {
    /// Joint angle [rad].
    pub angle_rad: f64,
    /// Joint velocity [rad/s].
    pub velocity_rad_s: f64,
    /// Gauge pressure of muscle 1 [Pa].
    pub p1_gauge_pa: f64,
    /// Gauge pressure of muscle 2 [Pa].
    pub p2_gauge_pa: f64,
    /// Torque from the measured tensions, (F1 - F2) r [N m].
    pub torque_nm: f64,
}

/// Fitted constants of eq. 11 in SI units (the firmware's `config/torque_model.toml`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TorqueModelFit {
    /// A [N/(m rad)].
    pub a_n_per_m_rad: f64,
    /// B [m^2].
    pub b_m2: f64,
    /// C [N m s^3/rad^3].
    pub c_nms3_per_rad3: f64,
    /// D [N m s/rad].
    pub d_nms_per_rad: f64,
    /// Sprocket radius r [m] (given, not fitted: seed 003 notes it differs between testbed and joint).
    pub sprocket_radius_m: f64,
    /// Mean pressure p0 of the data, gauge [Pa].
    pub p0_gauge_pa: f64,
    /// Largest |dp| in the data [Pa].
    pub dp_max_pa: f64,
}

impl TorqueModelFit {
    /// Model torque [N m].
    pub fn torque_nm(&self, angle_rad: f64, velocity_rad_s: f64, dp_pa: f64) -> f64 {
        let r = self.sprocket_radius_m;
        self.a_n_per_m_rad * r * r * angle_rad
            + self.b_m2 * r * dp_pa
            + self.c_nms3_per_rad3 * velocity_rad_s.powi(3)
            + self.d_nms_per_rad * velocity_rad_s
    }
}

/// Quality of the torque model against the force-derived torque.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TorqueFitQuality {
    /// NRMSE fit [%] (PLANT.md definition).
    pub fit_pct: f64,
    /// Mean absolute error [N m].
    pub mae_nm: f64,
    /// Root-mean-square error [N m].
    pub rmse_nm: f64,
    /// Largest absolute error [N m].
    pub max_abs_nm: f64,
    /// The same fit with the velocity terms dropped (static model, eq. 8) [%].
    pub static_fit_pct: f64,
    /// Number of samples.
    pub n: usize,
}

/// Fits eq. 11 to the samples with a given sprocket radius.
pub fn fit(
    samples: &[TorqueSample],
    sprocket_radius_m: f64,
) -> Result<(TorqueModelFit, TorqueFitQuality), IdentError> {
    if samples.len() < 8 {
        return Err(IdentError::Data(format!(
            "torque model: need at least 8 samples, got {}",
            samples.len()
        )));
    }
    if !(sprocket_radius_m > 0.0) {
        return Err(IdentError::Data(
            "torque model: sprocket radius must be > 0".into(),
        ));
    }
    let r = sprocket_radius_m;
    let p0 = samples
        .iter()
        .map(|s| 0.5 * (s.p1_gauge_pa + s.p2_gauge_pa))
        .sum::<f64>()
        / samples.len() as f64;
    let dp = |s: &TorqueSample| 0.5 * (s.p2_gauge_pa - s.p1_gauge_pa);
    let solve = |with_velocity: bool| -> Result<(DVector<f64>, Vec<f64>), IdentError> {
        let ncol = if with_velocity { 4 } else { 2 };
        let mut a = DMatrix::<f64>::zeros(samples.len(), ncol);
        let mut y = DVector::<f64>::zeros(samples.len());
        for (i, s) in samples.iter().enumerate() {
            a[(i, 0)] = r * r * s.angle_rad;
            a[(i, 1)] = r * dp(s);
            if with_velocity {
                a[(i, 2)] = s.velocity_rad_s.powi(3);
                a[(i, 3)] = s.velocity_rad_s;
            }
            y[i] = s.torque_nm;
        }
        let mut scale = vec![1.0; ncol];
        for (j, sc) in scale.iter_mut().enumerate() {
            let n = a.column(j).norm();
            if n > 0.0 {
                *sc = n;
                a.column_mut(j).scale_mut(1.0 / n);
            }
        }
        let theta = a
            .clone()
            .svd(true, true)
            .solve(&y, 1e-12)
            .map_err(|e| IdentError::Data(e.to_string()))?;
        let pred: Vec<f64> = (&a * &theta).iter().copied().collect();
        let theta = DVector::from_iterator(ncol, theta.iter().zip(&scale).map(|(t, s)| t / s));
        Ok((theta, pred))
    };
    let (theta, pred) = solve(true)?;
    let (_, pred_static) = solve(false)?;
    let y: Vec<f64> = samples.iter().map(|s| s.torque_nm).collect();
    let model = TorqueModelFit {
        a_n_per_m_rad: theta[0],
        b_m2: theta[1],
        c_nms3_per_rad3: theta[2],
        d_nms_per_rad: theta[3],
        sprocket_radius_m: r,
        p0_gauge_pa: p0,
        dp_max_pa: samples.iter().map(|s| dp(s).abs()).fold(0.0, f64::max),
    };
    let errs: Vec<f64> = pred.iter().zip(&y).map(|(p, m)| p - m).collect();
    let q = TorqueFitQuality {
        fit_pct: nrmse_fit_pct(&y, &pred),
        mae_nm: errs.iter().map(|e| e.abs()).sum::<f64>() / errs.len() as f64,
        rmse_nm: (errs.iter().map(|e| e * e).sum::<f64>() / errs.len() as f64).sqrt(),
        max_abs_nm: errs.iter().map(|e| e.abs()).fold(0.0, f64::max),
        static_fit_pct: nrmse_fit_pct(&y, &pred_static),
        n: samples.len(),
    };
    Ok((model, q))
}

/// PLANT.md fit: `100 (1 - ||y - y_hat|| / ||y - mean(y)||)`.
fn nrmse_fit_pct(y: &[f64], y_hat: &[f64]) -> f64 {
    let mean = y.iter().sum::<f64>() / y.len().max(1) as f64;
    let num: f64 = y
        .iter()
        .zip(y_hat)
        .map(|(a, b)| (a - b).powi(2))
        .sum::<f64>()
        .sqrt();
    let den: f64 = y.iter().map(|a| (a - mean).powi(2)).sum::<f64>().sqrt();
    if den > 0.0 {
        100.0 * (1.0 - num / den)
    } else if num == 0.0 {
        100.0
    } else {
        f64::NEG_INFINITY
    }
}

/// Velocity from uniformly sampled angles by a Savitzky-Golay first-derivative filter
/// ([`crate::signal::savitzky_golay_derivative`]).
pub fn savgol_velocity(angle_rad: &[f64], dt_s: f64, half_window: usize) -> Vec<f64> {
    crate::signal::savitzky_golay_derivative(angle_rad, dt_s, half_window)
}

/// Options of the kinematic identification sweep (seed 003: quasi-static motion at several
/// activations, then constant-velocity passes).
#[derive(Clone, Debug)]
pub struct TorqueSweep {
    /// Mid pressure p0, gauge [Pa].
    pub p0_gauge_pa: f64,
    /// Activation levels dp [Pa] (p1 = p0 - dp, p2 = p0 + dp).
    pub dp_levels_pa: Vec<f64>,
    /// Angle amplitude of the motion [rad].
    pub amplitude_rad: f64,
    /// Constant speeds of the passes [rad/s]; the smallest should be quasi-static.
    pub speeds_rad_s: Vec<f64>,
    /// Sample period [s].
    pub dt_s: f64,
}

impl Default for TorqueSweep {
    fn default() -> Self {
        TorqueSweep {
            p0_gauge_pa: 300_000.0,
            dp_levels_pa: vec![-200_000.0, -100_000.0, 0.0, 100_000.0, 200_000.0],
            amplitude_rad: 0.35,
            speeds_rad_s: vec![0.05, 1.0, 2.0, 4.0],
            dt_s: 0.001,
        }
    }
}

/// A prescribed-motion sample of the sweep: the joint is moved (by hand in seed 003; by a
/// drive here) while the pressures are held.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KinematicSample {
    /// Time [s].
    pub t_s: f64,
    /// Joint angle [rad].
    pub angle_rad: f64,
    /// Joint velocity [rad/s].
    pub velocity_rad_s: f64,
    /// Held gauge pressure of muscle 1 [Pa].
    pub p1_gauge_pa: f64,
    /// Held gauge pressure of muscle 2 [Pa].
    pub p2_gauge_pa: f64,
}

/// The motion of the sweep: for every activation level and speed, a triangle wave between
/// `-amplitude` and `+amplitude` (two passes: up, down) at that constant speed.
pub fn sweep_kinematics(opt: &TorqueSweep) -> Vec<KinematicSample> {
    let mut out = Vec::new();
    let mut t = 0.0;
    for &dp in &opt.dp_levels_pa {
        for &w in &opt.speeds_rad_s {
            let w = w.abs().max(1e-6);
            let a = opt.amplitude_rad;
            // -a -> +a -> -a at speed w.
            let leg = 2.0 * a / w;
            let n = ((2.0 * leg) / opt.dt_s).round().max(2.0) as usize;
            for k in 0..n {
                let tau = k as f64 * opt.dt_s;
                let (angle, vel) = if tau < leg {
                    (-a + w * tau, w)
                } else {
                    (a - w * (tau - leg), -w)
                };
                out.push(KinematicSample {
                    t_s: t,
                    angle_rad: angle,
                    velocity_rad_s: vel,
                    p1_gauge_pa: opt.p0_gauge_pa - dp,
                    p2_gauge_pa: opt.p0_gauge_pa + dp,
                });
                t += opt.dt_s;
            }
        }
    }
    out
}

/// The sweep as a recording (RECORDING.md columns) of the plant: the joint is driven through
/// the motion of [`sweep_kinematics`] while regulators hold the pressures, and the channels are
/// what the plant's sensors report (tensions from its force model, with its damper). The valve
/// columns are 0: the pressures are regulator-held, so the file is not an open-loop replay.
pub fn sweep_recording(plant: &crate::Plant, opt: &TorqueSweep) -> crate::Recording {
    use crate::io::recording::Channel;
    let ks = sweep_kinematics(opt);
    let mut rec = crate::Recording {
        metadata: vec![
            ("sample_period_s".into(), format!("{}", opt.dt_s)),
            (
                "source".into(),
                format!(
                    "host-sim {} sweep torque: prescribed motion, regulator-held pressures ({})",
                    env!("CARGO_PKG_VERSION"),
                    crate::io::recording::VALVE_COLUMNS_UNUSED
                ),
            ),
        ],
        t_s: ks.iter().map(|k| k.t_s).collect(),
        inputs: vec![crate::ValveInputs::CLOSED; ks.len()],
        ..Default::default()
    };
    let meas: Vec<crate::Measurement> = ks
        .iter()
        .map(|k| {
            plant.measure(&crate::PlantState {
                angle_rad: k.angle_rad,
                velocity_rad_s: k.velocity_rad_s,
                p1_abs_pa: k.p1_gauge_pa + plant.p_atm_pa,
                p2_abs_pa: k.p2_gauge_pa + plant.p_atm_pa,
            })
        })
        .collect();
    for c in Channel::ALL {
        rec.set_channel(c, meas.iter().map(|m| c.of(m)).collect());
    }
    rec
}

/// Seed 003 fits only the points of constant velocity: keeps the samples whose velocity changes
/// by at most `max_accel_rad_s2` (as an average acceleration) over `half_window` samples either
/// side, which also drops the samples whose velocity estimate straddles a reversal.
pub fn constant_velocity_samples(
    samples: &[TorqueSample],
    dt_s: f64,
    half_window: usize,
    max_accel_rad_s2: f64,
) -> Vec<TorqueSample> {
    let n = samples.len();
    let m = half_window.max(1);
    (0..n)
        .filter(|&k| {
            let (lo, hi) = (k.saturating_sub(m), (k + m).min(n - 1));
            if hi == lo {
                return false;
            }
            let accel = (samples[hi].velocity_rad_s - samples[lo].velocity_rad_s)
                / ((hi - lo) as f64 * dt_s);
            accel.abs() <= max_accel_rad_s2
        })
        .map(|k| samples[k])
        .collect()
}

/// How the torque samples of a recording were obtained.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TorqueSource {
    /// From the recorded tensions `f1_n`, `f2_n`.
    MeasuredTensions,
    /// From the plant's force model at the recorded pressures and angle (no tension columns).
    PlantForceModel,
}

/// Torque samples of a recording: angle from `angle_deg`, velocity by a Savitzky-Golay
/// derivative over `2 half_window + 1` samples, `dp` from `p1_kpa`, `p2_kpa`, and the torque
/// `(F1 - F2) r` with r of the plant, from the recorded tensions when present, else from the
/// plant's force model. `file` and `header_line` name the file in errors.
pub fn samples_from_recording(
    rec: &crate::Recording,
    plant: &crate::Plant,
    half_window: usize,
    file: &str,
    header_line: usize,
) -> Result<(Vec<TorqueSample>, TorqueSource), IdentError> {
    use crate::io::recording::Channel;
    let need = |c: Channel| {
        rec.channel(c).ok_or_else(|| {
            IdentError::at(
                file,
                header_line,
                c.name(),
                "required column is missing (identify torque needs angle_deg, p1_kpa, p2_kpa)",
            )
        })
    };
    let angle_deg = need(Channel::AngleDeg)?;
    let p1 = need(Channel::P1Kpa)?;
    let p2 = need(Channel::P2Kpa)?;
    let angle: Vec<f64> = angle_deg.iter().map(|a| a.to_radians()).collect();
    let vel = savgol_velocity(&angle, rec.sample_period_s(), half_window);
    let r = plant.joint.sprocket_radius_m;
    let (f1, f2) = (rec.channel(Channel::F1N), rec.channel(Channel::F2N));
    // One tension without the other cannot give (f1 - f2) r; falling back to the force
    // model silently would ignore the column the user recorded.
    if f1.is_some() != f2.is_some() {
        let (has, lacks) = if f1.is_some() {
            ("f1_n", "f2_n")
        } else {
            ("f2_n", "f1_n")
        };
        return Err(IdentError::at(
            file,
            header_line,
            lacks,
            &format!(
                "missing while `{has}` is there: the torque (f1_n - f2_n) r needs both tensions \
                 (remove `{has}` to take the torque from the plant's force model instead)"
            ),
        ));
    }
    let source = if f1.is_some() && f2.is_some() {
        TorqueSource::MeasuredTensions
    } else {
        TorqueSource::PlantForceModel
    };
    let samples = (0..rec.len())
        .map(|k| {
            let p1_gauge_pa = p1[k] * 1e3;
            let p2_gauge_pa = p2[k] * 1e3;
            let torque_nm = match (f1, f2) {
                (Some(f1), Some(f2)) => (f1[k] - f2[k]) * r,
                _ => {
                    let f = plant.tensions_n(&crate::PlantState {
                        angle_rad: angle[k],
                        velocity_rad_s: vel[k],
                        p1_abs_pa: p1_gauge_pa + plant.p_atm_pa,
                        p2_abs_pa: p2_gauge_pa + plant.p_atm_pa,
                    });
                    (f[0] - f[1]) * r
                }
            };
            TorqueSample {
                angle_rad: angle[k],
                velocity_rad_s: vel[k],
                p1_gauge_pa,
                p2_gauge_pa,
                torque_nm,
            }
        })
        .collect();
    Ok((samples, source))
}

impl TorqueModelFit {
    /// The `config/torque_model.toml` text (the firmware's build reads it). `dp_max_pa` is the
    /// usable activation the controller may command.
    pub fn to_toml(&self, q: &TorqueFitQuality, source: &str, dp_max_pa: f64) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "# Simplified torque model of the antagonistic joint (seed 003 eq. 11), SI units:"
        );
        super::toml_header(
            &mut s,
            &[
                "#",
                "#   T = A r^2 alpha + B r dp + C alpha'^3 + D alpha'",
                "#",
                "#   T      joint torque [N m], positive when it drives the angle up (PLANT.md: T = (F1 - F2) r)",
                "#   alpha  joint angle [rad], alpha' joint velocity [rad/s]",
                "#   dp     activation [Pa] with the paper's symmetric scheme p1 = p0 - dp, p2 = p0 + dp",
                "#          (gauge). On the reference joint muscle 1 pulls the angle up, so B < 0 here.",
                "#   A [N/(m rad)], B [m^2], C [N m s^3/rad^3], D [N m s/rad]",
                "#",
                "# Paper values for comparison (converted from pi-rad and kg/cm^2 in src/torque_model.rs::paper_si):",
                "#   A = -73670 N/(m pi), B = 174.2 N cm^2/kg, C = 0.07 N m (s/pi)^3, D = 0.45 N m s/pi.",
                "#",
            ],
            "torque",
            source,
            q.n,
        );
        let _ = writeln!(
            s,
            "# Fit against the force-derived torque: {:.3} % (static part only: {:.3} %), MAE {:.4} N m, max {:.4} N m",
            q.fit_pct, q.static_fit_pct, q.mae_nm, q.max_abs_nm
        );
        let _ = writeln!(s, "\n[torque_model]");
        let _ = writeln!(s, "a_n_per_m_rad = {:.6e}", self.a_n_per_m_rad);
        let _ = writeln!(s, "b_m2 = {:.6e}", self.b_m2);
        let _ = writeln!(s, "c_nms3_per_rad3 = {:.6e}", self.c_nms3_per_rad3);
        let _ = writeln!(s, "d_nms_per_rad = {:.6e}", self.d_nms_per_rad);
        let _ = writeln!(s, "sprocket_radius_m = {:.6}", self.sprocket_radius_m);
        let _ = writeln!(s, "p0_gauge_pa = {:.1}", self.p0_gauge_pa);
        let _ = writeln!(s, "dp_max_pa = {:.1}", dp_max_pa);
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn linear_truth_is_recovered_exactly() {
        let truth = TorqueModelFit {
            a_n_per_m_rad: -23_000.0,
            b_m2: -1.9e-3,
            c_nms3_per_rad3: 0.01,
            d_nms_per_rad: -0.3,
            sprocket_radius_m: 0.025,
            p0_gauge_pa: 300_000.0,
            dp_max_pa: 200_000.0,
        };
        let samples: Vec<TorqueSample> = sweep_kinematics(&TorqueSweep::default())
            .iter()
            .map(|k| {
                let dp = 0.5 * (k.p2_gauge_pa - k.p1_gauge_pa);
                TorqueSample {
                    angle_rad: k.angle_rad,
                    velocity_rad_s: k.velocity_rad_s,
                    p1_gauge_pa: k.p1_gauge_pa,
                    p2_gauge_pa: k.p2_gauge_pa,
                    torque_nm: truth.torque_nm(k.angle_rad, k.velocity_rad_s, dp),
                }
            })
            .collect();
        let (m, q) = fit(&samples, 0.025).unwrap();
        assert!(
            (m.a_n_per_m_rad / truth.a_n_per_m_rad - 1.0).abs() < 1e-6,
            "{m:?}"
        );
        assert!((m.b_m2 / truth.b_m2 - 1.0).abs() < 1e-6);
        assert!((m.c_nms3_per_rad3 / truth.c_nms3_per_rad3 - 1.0).abs() < 1e-5);
        assert!((m.d_nms_per_rad / truth.d_nms_per_rad - 1.0).abs() < 1e-6);
        assert!(q.fit_pct > 99.99);
        assert!((m.p0_gauge_pa - 300_000.0).abs() < 1e-6);
    }

    #[test]
    fn constant_velocity_filter_drops_the_reversals_only() {
        let opt = TorqueSweep {
            dp_levels_pa: vec![0.0],
            speeds_rad_s: vec![1.0],
            dt_s: 0.005,
            ..TorqueSweep::default()
        };
        let ks = sweep_kinematics(&opt);
        let angle: Vec<f64> = ks.iter().map(|k| k.angle_rad).collect();
        let v = savgol_velocity(&angle, opt.dt_s, 5);
        let samples: Vec<TorqueSample> = ks
            .iter()
            .zip(&v)
            .map(|(k, v)| TorqueSample {
                angle_rad: k.angle_rad,
                velocity_rad_s: *v,
                p1_gauge_pa: k.p1_gauge_pa,
                p2_gauge_pa: k.p2_gauge_pa,
                torque_nm: 0.0,
            })
            .collect();
        let kept = constant_velocity_samples(&samples, opt.dt_s, 5, 2.0);
        // One reversal in the middle (+-10 samples) and the two ends (one-sided estimates).
        assert!(kept.len() < samples.len() && kept.len() + 30 > samples.len());
        assert!(kept
            .iter()
            .all(|s| (s.velocity_rad_s.abs() - 1.0).abs() < 1e-9));
    }
}
