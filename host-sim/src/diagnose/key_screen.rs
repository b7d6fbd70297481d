//! Which keys of one valve or one muscle the selection refits.
//!
//! A key of one valve (`valve.inlet1.sonic_conductance_m3_per_s_pa`) or one muscle
//! (`muscle.m2.radius_m`) refines a shared key (`valve.sonic_conductance_m3_per_s_pa`,
//! `muscle.radius_m`). Refitting all of them would triple the refits of the selection, and
//! most recordings show no asymmetry at all; so they are screened on the equation-error
//! evidence first, and kept only when it points at that valve or that muscle.
//!
//! The evidence of a key is its sensitivity regression: at the measured states, the change
//! of the model's equations (torque balance, both pressure laws, the measured tensions)
//! when the key moves by 1 % is the regressor, the equations' residuals the data; each
//! equation is divided by its own size. A key of one part is kept when it explains more of
//! the residual (R^2) than its shared key by [`PART_R2_MARGIN`], at least
//! [`PART_R2_FLOOR`], and no less than any other part's key of the same field (the weak
//! inlet valve, not the other three).

use crate::plant::config::PlantConfig;
use crate::plant::{Plant, PlantState};

use super::candidates::Candidate;
use super::recalibrate::{keys, part_of, RecalKey};
use super::screen::Evidence;

/// A key of one part must explain this much more of the equation residual than its shared
/// key (R^2 points): a shared mis-set moves all parts alike, and its part keys then explain
/// less than it. Chosen on the tuning seeds (11, 12) of the independent rig.
pub const PART_R2_MARGIN: f64 = 0.05;
/// ... and at least this share of it.
pub const PART_R2_FLOOR: f64 = 0.05;

/// Samples of the evidence the regression reads at most (evenly strided).
const MAX_SAMPLES: usize = 4000;

/// The sensitivity regression of one key: R^2 and the fitted relative change of the key.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeyEvidence {
    pub r2: f64,
    /// The relative change of the key the residual asks for (0.1: 10 % up).
    pub relative_change: f64,
}

/// The equation-error rows of `plant` at sample `k`: the torque balance J alpha - r (F1 -
/// F2) (F measured when both force channels are), both chambers' dp/dt, both tensions.
fn rows(plant: &Plant, ev: &Evidence, forces: Option<[&[f64]; 2]>, k: usize) -> [f64; 5] {
    let x: &PlantState = &ev.states[k];
    let f_model = plant.tensions_n(x);
    let f_used = forces.map_or(f_model, |f| [f[0][k], f[1][k]]);
    let torque = plant.joint.inertia_kgm2 * ev.alpha_rad_s2[k]
        - plant.joint.sprocket_radius_m * (f_used[0] - f_used[1]);
    let d = plant.derivatives(x, &ev.inputs[k]);
    [torque, d.p1_abs_pa, d.p2_abs_pa, f_model[0], f_model[1]]
}

/// The sensitivity regression of `key` on the evidence `ev` of the model `nominal`.
pub fn key_evidence(nominal: &PlantConfig, ev: &Evidence, key: &RecalKey) -> Option<KeyEvidence> {
    let n = ev
        .states
        .len()
        .min(ev.inputs.len())
        .min(ev.alpha_rad_s2.len());
    if n < 10 {
        return None;
    }
    let v0 = (key.get)(nominal);
    if !(v0.is_finite() && v0 > 0.0) {
        return None;
    }
    const STEP: f64 = 0.01;
    let mut moved = nominal.clone();
    (key.set)(&mut moved, v0 * (1.0 + STEP));
    let (p0, p1) = (Plant::from_config(nominal), Plant::from_config(&moved));
    let both_forces = ev
        .force_residual_n
        .as_ref()
        .is_some_and(|f| f[0].is_some() && f[1].is_some());
    // The measured tensions: the nominal model's plus their residual.
    let measured_forces: Option<[Vec<f64>; 2]> = both_forces.then(|| {
        let fr = ev.force_residual_n.as_ref().expect("both forces");
        [0, 1].map(|i| {
            let r = fr[i].as_ref().expect("both forces");
            (0..n)
                .map(|k| p0.tensions_n(&ev.states[k])[i] + r[k])
                .collect()
        })
    });
    let forces = measured_forces.as_ref().map(|f| [&f[0][..], &f[1][..]]);
    let stride = (n / MAX_SAMPLES).max(1);
    let idx: Vec<usize> = (0..n).step_by(stride).collect();
    // Residual (data) and regressor of each equation, before scaling.
    let mut data: [Vec<f64>; 5] = Default::default();
    let mut reg: [Vec<f64>; 5] = Default::default();
    let mut size = [0.0f64; 5];
    let pressure = &ev.pressure_residual_pa_s;
    let force = ev.force_residual_n.as_ref();
    for &k in &idx {
        let a = rows(&p0, ev, forces, k);
        let b = rows(&p1, ev, forces, k);
        // Residuals as measured minus model; the torque row is a balance (0 when the model
        // is right), so its residual is the balance and the key's change enters negated.
        let res = [
            Some(-ev.torque_residual_nm[k]),
            pressure[0].as_ref().map(|r| r[k]),
            pressure[1].as_ref().map(|r| r[k]),
            force.and_then(|f| f[0].as_ref()).map(|r| r[k]),
            force.and_then(|f| f[1].as_ref()).map(|r| r[k]),
        ];
        for e in 0..5 {
            if let Some(r) = res[e] {
                let g = (b[e] - a[e]) / STEP;
                if r.is_finite() && g.is_finite() {
                    data[e].push(r);
                    reg[e].push(g);
                    // The torque row's size is the inertia torque's (the balance is ~0).
                    let m = if e == 0 {
                        p0.joint.inertia_kgm2 * ev.alpha_rad_s2[k]
                    } else {
                        a[e]
                    };
                    size[e] += m * m;
                }
            }
        }
    }
    let (mut gr, mut gg, mut rr) = (0.0, 0.0, 0.0);
    for e in 0..5 {
        if data[e].is_empty() {
            continue;
        }
        // Each equation in units of its own size (the model's RMS over the samples).
        let s = (size[e] / data[e].len() as f64).sqrt();
        if !(s > 0.0) {
            continue;
        }
        let w = 1.0 / (s * s * data[e].len() as f64);
        for (r, g) in data[e].iter().zip(&reg[e]) {
            gr += w * g * r;
            gg += w * g * g;
            rr += w * r * r;
        }
    }
    if !(gg > 0.0 && rr > 0.0) {
        return None;
    }
    Some(KeyEvidence {
        r2: (gr * gr / (gg * rr)).clamp(0.0, 1.0),
        relative_change: gr / gg,
    })
}

/// The pool without the keys of one part that the evidence does not point at (module
/// documentation); every other candidate is kept, in order.
pub fn retain_indicated(
    cands: Vec<Box<dyn Candidate>>,
    nominal: &PlantConfig,
    ev: &Evidence,
) -> Vec<Box<dyn Candidate>> {
    let all = keys();
    let r2_of = |key: &str| -> f64 {
        all.iter()
            .find(|k| k.key == key)
            .and_then(|k| key_evidence(nominal, ev, k))
            .map_or(0.0, |e| e.r2)
    };
    let mut memo: std::collections::BTreeMap<String, f64> = Default::default();
    let mut r2 = |key: &str| -> f64 {
        if let Some(v) = memo.get(key) {
            return *v;
        }
        let v = r2_of(key);
        memo.insert(key.to_string(), v);
        v
    };
    let mut keep = Vec::with_capacity(cands.len());
    for c in cands {
        let id = c.id();
        let Some((shared, _)) = part_of(id) else {
            keep.push(c);
            continue;
        };
        let own = r2(id);
        let siblings: Vec<&'static str> = all
            .iter()
            .map(|k| k.key)
            .filter(|k| *k != id && part_of(k).is_some_and(|(s, _)| s == shared))
            .collect();
        let best_sibling = siblings.iter().map(|k| r2(k)).fold(0.0, f64::max);
        let parent = r2(&shared);
        if own >= PART_R2_FLOOR && own >= parent + PART_R2_MARGIN && own >= best_sibling {
            keep.push(c);
        }
    }
    keep
}
