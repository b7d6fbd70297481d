//! Diagnosis of a 3-DOF arm recording, joint by joint, through the 1-DOF pipeline.
//!
//! Each joint of the arm is a muscle pair with its valves and pressures (the 1-DOF plant of
//! PLANT.md) driving one row of the arm's `M(q) q'' + C(q, q') q' + G(q) + F(q') = tau`.
//! With the recorded angles of all three joints, the row of joint i reads
//!
//! ```text
//! J_i q_i'' = tau_i + tau_load,i
//! tau_load,i = J_i q_i'' - [M(q) q'' + C(q, q') q' + G(q) + F(q')]_i
//! ```
//!
//! with `J_i = M_ii` at the recording's mean pose: the other joints' motion, gravity, the
//! coupling and the nominal friction of eq. 7 become a known external torque on a 1-DOF
//! joint (q' and q'' from the recorded angles by the diagnosis' differentiator). Each joint
//! is then diagnosed by [`super::diagnose`] as a 1-DOF plant carrying that load
//! ([`crate::plant::LoadTorque`]), with its own `[jointN.effects]`: which joint departs, the
//! effect or the recalibrated key and its parameters (an effect names its muscle where it
//! acts on one), the fits before and after per channel, on the held-out tail of the
//! recording as well. A joint that departs does not drag the others along: their loads are
//! computed from what the departing joint really did (its recorded angle). Its angle
//! sensor is the exception: an angle that reads off puts every other joint's load off.
//! When a departing joint's diagnosis names an angle offset or gain, its angle is
//! corrected and the departing joints are diagnosed again with the loads of the corrected
//! angles (each joint's own recording keeps what its sensors read).
//!
//! Limits: the load is built from the recorded angles, so the angle channels must be
//! recorded for all three joints; a LuGre joint's friction enters the load as eq. 7 with its
//! regularised sign (no bristle state); a separate check recording is not supported (the
//! held-out part is the tail of the recording).

use std::sync::Arc;

use crate::diagnose::{diagnose, DiagnoseError, DiagnoseOptions, Diagnosis, Differentiator};
use crate::io::arm3::{Arm3Recording, JOINTS};
use crate::io::recording::{Channel, Recording};
use crate::plant::arm3::{Arm3, Arm3Config, ArmJointConfig};
use crate::plant::config::{InitialConfig, JointConfig, PlantConfig};
use crate::plant::effects::{ChannelCalibration, EffectsConfig};
use crate::plant::LoadTorque;

/// The diagnosis of each joint of an arm recording.
#[derive(Debug)]
pub struct ArmDiagnosis {
    /// Joints 1..3 in order.
    pub joints: Vec<Diagnosis>,
    /// The 1-DOF inertia each joint was diagnosed with (`M_ii` at the mean pose) [kg m^2].
    pub inertia_kgm2: [f64; JOINTS],
    /// Joints (1-based) whose angle sensor the diagnosis found off; the departing joints
    /// were diagnosed again with the loads of the corrected angles.
    pub angle_corrected: Vec<usize>,
}

impl ArmDiagnosis {
    /// The joints (1-based) whose recording departs from the nominal model: the diagnosis
    /// named an effect or a recalibration, or found the joint unexplained.
    pub fn departing_joints(&self) -> Vec<usize> {
        self.joints
            .iter()
            .enumerate()
            .filter(|(_, d)| !d.nothing_missing)
            .map(|(i, _)| i + 1)
            .collect()
    }

    /// The answer in words, joint by joint.
    pub fn answer(&self) -> String {
        let departing = self.departing_joints();
        let mut s = if departing.is_empty() {
            "Arm: every joint is explained by the nominal model within its noise.\n".to_string()
        } else {
            format!(
                "Arm: joint{} {} depart{} from the nominal model.\n",
                if departing.len() > 1 { "s" } else { "" },
                departing
                    .iter()
                    .map(|j| j.to_string())
                    .collect::<Vec<_>>()
                    .join(", "),
                if departing.len() > 1 { "" } else { "s" },
            )
        };
        if !self.angle_corrected.is_empty() {
            s.push_str(&format!(
                "The angle sensor of joint(s) {:?} reads off: the departing joints were \
                 diagnosed again with the loads of the corrected angles.\n",
                self.angle_corrected
            ));
        }
        for (i, d) in self.joints.iter().enumerate() {
            s.push_str(&format!(
                "\n== joint {} (1-DOF view: J = {:.4} kg m^2 plus the load of the rest of the arm)\n",
                i + 1,
                self.inertia_kgm2[i]
            ));
            s.push_str(&d.answer());
        }
        s
    }

    /// The JSON of the arm: one 1-DOF diagnosis per joint.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "kind": "arm3",
            "departing_joints": self.departing_joints(),
            "angle_corrected_joints": self.angle_corrected,
            "joints": self.joints.iter().enumerate().map(|(i, d)| {
                let mut j = d.to_json();
                if let Some(o) = j.as_object_mut() {
                    o.insert("joint".into(), (i + 1).into());
                    o.insert("inertia_kgm2".into(), self.inertia_kgm2[i].into());
                }
                j
            }).collect::<Vec<_>>(),
        })
    }
}

/// The 1-DOF plant of joint `joint` (0-based) of `arm`: its muscles, valves, supply,
/// `[jointN.effects]`, inertia `inertia_kgm2`, the initial state of `initial` (the arm's,
/// after settling) in the joint's own frame (angle 0 at `neutral_angle_rad`), no load.
pub fn joint_plant_config(
    cfg: &Arm3Config,
    initial: &crate::plant::arm3::Arm3State,
    joint: usize,
    inertia_kgm2: f64,
) -> PlantConfig {
    let j: &ArmJointConfig = [&cfg.joint1, &cfg.joint2, &cfg.joint3][joint];
    let p_atm = cfg.environment.p_atm_pa;
    PlantConfig {
        environment: cfg.environment.clone(),
        muscle: j.muscle.clone(),
        joint: JointConfig {
            sprocket_radius_m: j.sprocket_radius_m,
            inertia_kgm2,
            initial_contraction: j.initial_contraction,
            angle_min_rad: None,
            angle_max_rad: None,
            end_stop_stiffness_nm_per_rad: None,
            end_stop_damping_nms_per_rad: None,
        },
        valve: cfg.valve.clone(),
        initial: InitialConfig {
            angle_rad: initial.angles_rad[joint] - j.neutral_angle_rad,
            velocity_rad_s: initial.velocities_rad_s[joint],
            p1_gauge_pa: initial.p_abs_pa[joint][0] - p_atm,
            p2_gauge_pa: initial.p_abs_pa[joint][1] - p_atm,
        },
        // The arm's shared supply drop, if the nominal arm has one, as the joint's own: the
        // joint then sees the drop of its own inlet flow only (the other joints' draw is
        // not in the 1-DOF plant).
        effects: EffectsConfig {
            supply_drop: cfg.effects.supply_drop.clone(),
            ..j.effects.clone()
        },
        load: None,
    }
}

/// The external torque on each joint from the rest of the arm (see the module
/// documentation), at every sample of `rec`, and the 1-DOF inertias `M_ii` at the mean
/// pose. Needs the angle channel of every joint.
pub fn load_torques_nm(
    arm: &Arm3,
    rec: &Arm3Recording,
    diff: &dyn Differentiator,
) -> Result<([Vec<f64>; JOINTS], [f64; JOINTS]), DiagnoseError> {
    let dt = rec.sample_period_s();
    let mut q = Vec::with_capacity(JOINTS);
    for j in 0..JOINTS {
        let a = rec.channel(j, Channel::AngleDeg).ok_or_else(|| {
            DiagnoseError::Data(format!(
                "the arm diagnosis needs the angle of every joint: column {} is missing",
                crate::io::arm3::column("angle_deg", j)
            ))
        })?;
        q.push(a.iter().map(|d| d.to_radians()).collect::<Vec<f64>>());
    }
    let qd: Vec<Vec<f64>> = q.iter().map(|a| diff.derivative(a, dt)).collect();
    let qdd: Vec<Vec<f64>> = qd.iter().map(|w| diff.derivative(w, dt)).collect();
    let n = rec.len();
    let pose = |k: usize| [q[0][k], q[1][k], q[2][k]];
    let mut inertia = [0.0; JOINTS];
    for k in 0..n {
        let m = arm.links.mass_matrix(&pose(k));
        for (i, v) in inertia.iter_mut().enumerate() {
            *v += m[(i, i)] / n as f64;
        }
    }
    let mut load: [Vec<f64>; JOINTS] = Default::default();
    for l in load.iter_mut() {
        l.reserve(n);
    }
    for k in 0..n {
        let qk = pose(k);
        let wk = [qd[0][k], qd[1][k], qd[2][k]];
        let ak = nalgebra::Vector3::new(qdd[0][k], qdd[1][k], qdd[2][k]);
        let rows = arm.links.mass_matrix(&qk) * ak
            + arm.links.coriolis_matrix(&qk, &wk) * nalgebra::Vector3::from(wk)
            + arm.links.gravity_torques_nm(&qk)
            + nalgebra::Vector3::from(arm.friction_torques_nm(&wk));
        for i in 0..JOINTS {
            load[i].push(inertia[i] * ak[i] - rows[i]);
        }
    }
    Ok((load, inertia))
}

/// Joint `joint` of `rec` as a 1-DOF recording in the joint's own frame (angle 0 at the
/// neutral angle).
pub fn joint_recording(cfg: &Arm3Config, rec: &Arm3Recording, joint: usize) -> Recording {
    let neutral_deg = [&cfg.joint1, &cfg.joint2, &cfg.joint3][joint]
        .neutral_angle_rad
        .to_degrees();
    let mut r = rec.joint_recording(joint);
    if let Some(a) = r.outputs[Channel::AngleDeg.index()].as_mut() {
        for v in a.iter_mut() {
            *v -= neutral_deg;
        }
    }
    r
}

/// Diagnoses every joint of an arm recording against the nominal arm `cfg` (see the module
/// documentation). `progress(done, total, message)` as [`diagnose`]'s, over all joints.
pub fn diagnose_arm(
    cfg: &Arm3Config,
    rec: &Arm3Recording,
    opts: &DiagnoseOptions,
    progress: &(dyn Fn(u64, u64, &str) + Sync),
) -> Result<ArmDiagnosis, DiagnoseError> {
    let arm = Arm3::from_config(cfg).map_err(|e| DiagnoseError::Data(e.to_string()))?;
    let diff = crate::diagnose::SavitzkyGolay::default();
    let (load, inertia) = load_torques_nm(&arm, rec, &diff)?;
    let run = |i: usize, load_i: Vec<f64>, pass: &str| -> Result<Diagnosis, DiagnoseError> {
        let mut plant = joint_plant_config(cfg, &arm.initial, i, inertia[i]);
        plant.load = Some(LoadTorque {
            torque_nm: Arc::from(load_i),
        });
        let train = joint_recording(cfg, rec, i);
        let label = format!("joint {}{pass}", i + 1);
        diagnose(&plant, &train, None, opts, &|done, total, msg| {
            progress(
                i as u64 * total + done,
                JOINTS as u64 * total,
                &format!("{label}: {msg}"),
            )
        })
    };
    let mut joints = Vec::with_capacity(JOINTS);
    for (i, load_i) in load.into_iter().enumerate() {
        joints.push(run(i, load_i, "")?);
    }
    // An angle sensor that reads off on one joint puts the other joints' loads off too
    // (they are computed from its angle). When a departing joint's diagnosis names an
    // angle calibration, its angle is corrected and the departing joints are diagnosed
    // again with loads from the corrected angle.
    let corrections: Vec<Option<ChannelCalibration>> = joints
        .iter()
        .map(|d| {
            if d.nothing_missing {
                return None;
            }
            d.corrected
                .effects
                .sensor
                .as_ref()
                .filter(|s| s.enabled)
                .and_then(|s| s.angle_deg)
                .filter(|c| *c != ChannelCalibration::IDENTITY && c.gain != 0.0)
        })
        .collect();
    let mut angle_corrected = Vec::new();
    if corrections.iter().any(Option::is_some) {
        let mut fixed = rec.clone();
        for (j, c) in corrections.iter().enumerate() {
            let Some(c) = c else { continue };
            if let Some(a) = fixed.outputs[j][Channel::AngleDeg.index()].as_mut() {
                for v in a.iter_mut() {
                    *v = (*v - c.offset) / c.gain;
                }
            }
            angle_corrected.push(j + 1);
        }
        // Every departing joint again, the corrected ones too: their own load was computed
        // from their own angle (their recording keeps the sensor's reading).
        let (load2, _) = load_torques_nm(&arm, &fixed, &diff)?;
        for (i, load_i) in load2.into_iter().enumerate() {
            if !joints[i].nothing_missing {
                joints[i] = run(i, load_i, " (loads from the corrected angles)")?;
            }
        }
    }
    Ok(ArmDiagnosis {
        joints,
        inertia_kgm2: inertia,
        angle_corrected,
    })
}
