//! Each slot's regression: the residual of the slot's equation on the head of TRAIN (computed
//! from the measured states and their Savitzky-Golay derivatives, the diagnosis's
//! [`Evidence`]) and the library's columns (each term at the measured states, mapped into the
//! equation's units), then the sparse supports STLSQ finds over a grid of thresholds.

use crate::plant::channel::Channel;
use crate::plant::effects::candidate::{Evidence, Scatter};
use crate::plant::effects::discovered::{Discovered, Slot, Term, TermInput};

use super::sparse::{stlsq, Design, SparseFit};

/// The catalogue's counterpart of a library term: the effect or plant key that models the
/// same physics in another form (a sensor's gain or lag, friction, a leak, a valve's
/// conductance, a muscle's force keys, gravity), or `None` for physics the catalogue lacks
/// (velocity-squared damping, a nonlinear spring, end stops, a compliant or eccentric
/// transmission, a nonlinear transducer, a valve dead zone). A discovered term made only of
/// counterparts refines a catalogue answer; one with a term of its own shows that answer to
/// be a stand-in (`diagnose`'s stand-in check).
pub fn catalogue_counterpart(term: &Term) -> Option<&'static str> {
    use Term::*;
    match term {
        Speed | SignSpeed | TanhSpeed(_) => Some("joint_friction"),
        Angle => Some("gravity"),
        Force1 | Force2 | ForceDiff => Some("muscle.radius_m"),
        Pressure | SqrtPressure => Some("leakage"),
        InletFlow | ExhaustFlow => Some("valve.sonic_conductance_m3_per_s_pa"),
        Reading => Some("sensor_gain"),
        ReadingRate => Some("sensor_lag"),
        SpeedAbsSpeed | AngleSq | AngleCubed | DeadbandAngle(_) | SaturationAngle(_)
        | ShiftOneMinusCos | ShiftSin | ShiftAngleSq | ShiftAngleCubed | Stretch | PressureSq
        | InletDeadZone(_) | ExhaustDeadZone(_) | ReadingSq | ReadingCubed => None,
    }
}

/// Samples left out at each end of the head (the smoothed derivatives' edges).
const EDGE: usize = 20;

/// A sparse model of one slot from the equation error.
#[derive(Debug, Clone)]
pub struct SlotModel {
    pub slot: Slot,
    pub terms: Vec<Term>,
    /// Coefficients in the slot's unit over each term's.
    pub coefficients: Vec<f64>,
    /// Share of the equation residual's energy explained (uncentred R^2).
    pub r2: f64,
}

/// The residual of `slot`'s equation and its library's columns on samples `range` of the
/// evidence; `None` when the slot's channel was not measured.
pub fn design(
    ev: &Evidence,
    slot: Slot,
    library: &[Term],
    range: std::ops::Range<usize>,
) -> Option<Design> {
    let idx = rows(ev, range)?;
    let plant = &ev.plant;
    let (y, columns): (Vec<f64>, Vec<Vec<f64>>) = match slot {
        Slot::Transmission => transmission_design(ev, library, idx.clone(), &|k| tensions(ev, k)),
        Slot::Joint => {
            let inputs: Vec<TermInput> = idx.clone().map(|k| sample_input(ev, slot, k)).collect();
            (
                ev.torque_residual_nm[idx.clone()].to_vec(),
                library
                    .iter()
                    .map(|t| inputs.iter().map(|x| t.eval(x)).collect())
                    .collect(),
            )
        }
        Slot::ChamberP1 | Slot::ChamberP2 | Slot::Chambers => {
            let factor = plant.effects.pressure_rate_factor();
            let mut y = Vec::new();
            let mut columns: Vec<Vec<f64>> = vec![Vec::new(); library.len()];
            for &i in chambers_of(slot) {
                let res = ev.pressure_residual_pa_s[i].as_ref()?;
                y.extend_from_slice(&res[idx.clone()]);
                for k in idx.clone() {
                    // dp/dt gains p_atm Q / V from an added standard flow Q.
                    let chi = plant.joint.contractions(ev.angle_rad[k])[i];
                    let g = factor * plant.p_atm_pa / plant.muscle.volume_m3(chi);
                    let x = chamber_input(ev, i, k);
                    for (col, t) in columns.iter_mut().zip(library) {
                        col.push(g * t.eval(&x));
                    }
                }
            }
            (y, columns)
        }
        Slot::SensorAngle | Slot::SensorP1 | Slot::SensorP2 => {
            let res = ev.residual[sensor_channel(slot).index()].as_ref()?;
            ev.nominal[sensor_channel(slot).index()].as_ref()?;
            ev.nominal_rate[sensor_channel(slot).index()].as_ref()?;
            let inputs: Vec<TermInput> = idx.clone().map(|k| sample_input(ev, slot, k)).collect();
            (
                res[idx.clone()].to_vec(),
                library
                    .iter()
                    .map(|t| inputs.iter().map(|x| t.eval(x)).collect())
                    .collect(),
            )
        }
    };
    if y.iter()
        .chain(columns.iter().flatten())
        .any(|v| !v.is_finite())
    {
        return None;
    }
    Some(block_average(
        Design { y, columns },
        idx.len(),
        block_len(ev.dt_s),
    ))
}

/// The samples of `range` a regression uses: [`EDGE`] left out at each end; `None` when
/// fewer than 50 remain.
fn rows(ev: &Evidence, range: std::ops::Range<usize>) -> Option<std::ops::Range<usize>> {
    let n = ev.angle_rad.len();
    let lo = range.start + EDGE;
    let hi = range.end.min(n).saturating_sub(EDGE);
    (hi > lo + 50).then_some(lo..hi)
}

/// The tensions the torque residual used at sample `k`: measured when both force channels
/// were, else the nominal tension law at the measured state.
fn tensions(ev: &Evidence, k: usize) -> [f64; 2] {
    let model = ev.plant.tensions_n(&ev.states[k]);
    match ev.force_residual_n.as_ref() {
        Some([Some(a), Some(b)]) => [model[0] + a[k], model[1] + b[k]],
        _ => model,
    }
}

/// The chambers (0, 1) a chamber slot's equation covers.
fn chambers_of(slot: Slot) -> &'static [usize] {
    match slot {
        Slot::ChamberP1 => &[0],
        Slot::ChamberP2 => &[1],
        _ => &[0, 1],
    }
}

/// The channel a sensor slot maps.
fn sensor_channel(slot: Slot) -> Channel {
    match slot {
        Slot::SensorAngle => Channel::AngleDeg,
        Slot::SensorP1 => Channel::P1Kpa,
        _ => Channel::P2Kpa,
    }
}

/// What chamber `i`'s terms are computed from at sample `k`: its gauge pressure, its
/// valves' openings and their nominal flows.
fn chamber_input(ev: &Evidence, i: usize, k: usize) -> TermInput {
    let plant = &ev.plant;
    let p_abs = ev.p_gauge_pa[i][k] + plant.p_atm_pa;
    let u = &ev.inputs[k];
    let (u_in, u_ex) = if i == 0 {
        (u.u_in1, u.u_ex1)
    } else {
        (u.u_in2, u.u_ex2)
    };
    TermInput {
        p_gauge_kpa: ev.p_gauge_pa[i][k] * 1e-3,
        openings: [u_in, u_ex],
        valve_flows_m3_s: [
            u_in * plant.valve.flow_m3_s(plant.p_supply_abs_pa, p_abs),
            -u_ex * plant.valve.flow_m3_s(p_abs, plant.p_atm_pa),
        ],
        ..TermInput::default()
    }
}

/// What `slot`'s terms are computed from at sample `k` (a chamber slot: its first chamber).
fn sample_input(ev: &Evidence, slot: Slot, k: usize) -> TermInput {
    match slot {
        Slot::Joint | Slot::Transmission => TermInput {
            angle_rad: ev.angle_rad[k],
            speed_rad_s: ev.omega_rad_s[k],
            tensions_n: tensions(ev, k),
            sprocket_radius_m: ev.plant.joint.sprocket_radius_m,
            ..TermInput::default()
        },
        Slot::ChamberP1 | Slot::ChamberP2 | Slot::Chambers => {
            chamber_input(ev, chambers_of(slot)[0], k)
        }
        Slot::SensorAngle | Slot::SensorP1 | Slot::SensorP2 => {
            let c = sensor_channel(slot).index();
            TermInput {
                reading: ev.nominal[c].as_ref().map_or(f64::NAN, |v| v[k]),
                reading_rate: ev.nominal_rate[c].as_ref().map_or(f64::NAN, |v| v[k]),
                ..TermInput::default()
            }
        }
    }
}

/// What the residual of `slot`'s equation is, with its unit (the y axis of the plot).
fn residual_label(slot: Slot) -> &'static str {
    match slot {
        Slot::Joint | Slot::Transmission => "torque balance residual [N m]",
        Slot::ChamberP1 | Slot::ChamberP2 | Slot::Chambers => "dp/dt residual [Pa/s]",
        Slot::SensorAngle => "angle residual [deg]",
        Slot::SensorP1 | Slot::SensorP2 => "pressure residual [kPa]",
    }
}

/// The residual of the table's equation on samples `range` (block-averaged as the
/// regression sees it; a chamber slot: its first chamber, the transmission: the torque
/// balance) against the argument of its first term, with the table's terms at its
/// coefficients as the curve: the report's picture of what the discovered term explains.
pub fn residual_scatter(
    ev: &Evidence,
    table: &Discovered,
    range: std::ops::Range<usize>,
) -> Option<Scatter> {
    let first = *table.terms.first()?;
    let idx = rows(ev, range.clone())?;
    let d = design(ev, table.slot, &table.terms, range)?;
    let b = block_len(ev.dt_s);
    let (x_label, arg) = first.argument();
    let seg = idx.len();
    let x: Vec<f64> = idx.map(|k| arg(&sample_input(ev, table.slot, k))).collect();
    let x = block_average(
        Design {
            y: x,
            columns: Vec::new(),
        },
        seg,
        b,
    )
    .y;
    // The first segment of the stacked design (its x has as many blocks).
    let m = x.len().min(d.y.len());
    let term: Vec<f64> = (0..m)
        .map(|j| {
            d.columns
                .iter()
                .zip(&table.coefficients)
                .map(|(col, c)| c * col[j])
                .sum()
        })
        .collect();
    let mut s = Scatter::new(x_label, residual_label(table.slot), &x[..m], &d.y[..m]);
    let mut curve: Vec<(f64, f64)> = x[..m]
        .iter()
        .copied()
        .zip(term)
        .filter(|(a, v)| a.is_finite() && v.is_finite())
        .collect();
    curve.sort_by(|a, b| a.0.total_cmp(&b.0));
    s.curve = curve;
    Some(s)
}

/// Length in time of the blocks [`block_average`] averages over.
pub const BLOCK_S: f64 = 0.02;

/// Samples per block at sample period `dt_s`.
fn block_len(dt_s: f64) -> usize {
    ((BLOCK_S / dt_s).round() as usize).max(1)
}

/// The design averaged over blocks of `b` samples within each segment of `seg` rows (the
/// rows of each chamber or channel, stacked): the same low-pass on the residual and on the
/// columns (the integral or "weak" form of the equation), so that the smoothing of the
/// differentiated residual meets the same smoothing of the terms, and the noise of the
/// second derivative averages out.
fn block_average(d: Design, seg: usize, b: usize) -> Design {
    if b <= 1 || seg < b {
        return d;
    }
    let avg = |v: &[f64]| -> Vec<f64> {
        v.chunks(seg)
            .flat_map(|s| s.chunks_exact(b).map(|c| c.iter().sum::<f64>() / b as f64))
            .collect()
    };
    Design {
        y: avg(&d.y),
        columns: d.columns.iter().map(|c| avg(c)).collect(),
    }
}

/// The transmission's regression: the torque balance's residual and, where a tension was
/// measured, the tension's residual (times r, in N m), against what each travel or stretch
/// term changes in them (to first order: a tension changes by its slope dF/dchi times the
/// extra contraction).
fn transmission_design(
    ev: &Evidence,
    library: &[Term],
    idx: std::ops::Range<usize>,
    forces: &dyn Fn(usize) -> [f64; 2],
) -> (Vec<f64>, Vec<Vec<f64>>) {
    let plant = &ev.plant;
    let r = plant.joint.sprocket_radius_m;
    let l = plant.muscle.rest_length_m;
    let measured: [Option<&Vec<f64>>; 2] = match ev.force_residual_n.as_ref() {
        Some([a, b]) => [a.as_ref(), b.as_ref()],
        None => [None, None],
    };
    let both = measured.iter().all(Option::is_some);
    let mut y = Vec::new();
    let mut columns: Vec<Vec<f64>> = vec![Vec::new(); library.len()];
    // Per sample: tensions used, slopes dF/dchi, the term inputs.
    let rows: Vec<([f64; 2], [f64; 2], TermInput)> = idx
        .clone()
        .map(|k| {
            let f = forces(k);
            let chi = plant.joint.contractions(ev.angle_rad[k]);
            let dchi = plant.joint.contraction_rates(ev.omega_rad_s[k]);
            let h = 1e-4;
            let slope: [f64; 2] = std::array::from_fn(|i| {
                let pg = ev.p_gauge_pa[i][k];
                (plant.muscle.tension_n(pg, chi[i] + h, dchi[i])
                    - plant.muscle.tension_n(pg, chi[i] - h, dchi[i]))
                    / (2.0 * h)
            });
            let x = TermInput {
                angle_rad: ev.angle_rad[k],
                speed_rad_s: ev.omega_rad_s[k],
                tensions_n: f,
                sprocket_radius_m: r,
                ..TermInput::default()
            };
            (f, slope, x)
        })
        .collect();
    y.extend_from_slice(&ev.torque_residual_nm[idx.clone()]);
    for (col, t) in columns.iter_mut().zip(library) {
        for (f, s, x) in &rows {
            let v = if *t == Term::Stretch {
                if both {
                    0.0
                } else {
                    r * (s[0] * f[0] - s[1] * f[1]) / l
                }
            } else {
                let val = t.eval(x);
                let mut v = (f[0] - f[1]) * t.travel_slope(x.angle_rad, r);
                if !both {
                    v += r * (s[0] + s[1]) * val / l;
                }
                v
            };
            col.push(v);
        }
    }
    for (i, m) in measured.iter().enumerate() {
        let Some(res) = m else { continue };
        y.extend(idx.clone().map(|k| r * res[k]));
        let sign = if i == 0 { 1.0 } else { -1.0 };
        for (col, t) in columns.iter_mut().zip(library) {
            for (f, s, x) in &rows {
                col.push(if *t == Term::Stretch {
                    r * s[i] * f[i] / l
                } else {
                    r * s[i] * sign * t.eval(x) / l
                });
            }
        }
    }
    (y, columns)
}

/// The variants of a slot's library with at most one member of each parametrised family
/// (one smoothing speed of tanh, one dead band, one saturation): members of a family are
/// nearly collinear, and least squares would spread a term over them.
fn variants(library: &[Term]) -> Vec<Vec<Term>> {
    let family = |t: &Term| -> Option<u8> {
        match t {
            Term::TanhSpeed(_) => Some(0),
            Term::DeadbandAngle(_) => Some(1),
            Term::SaturationAngle(_) => Some(2),
            Term::InletDeadZone(_) => Some(3),
            Term::ExhaustDeadZone(_) => Some(4),
            _ => None,
        }
    };
    let plain: Vec<Term> = library
        .iter()
        .filter(|t| family(t).is_none())
        .copied()
        .collect();
    let mut out = vec![plain];
    for f in 0..5u8 {
        let members: Vec<Term> = library
            .iter()
            .filter(|t| family(t) == Some(f))
            .copied()
            .collect();
        if members.is_empty() {
            continue;
        }
        out = out
            .into_iter()
            .flat_map(|v| {
                members.iter().map(move |m| {
                    let mut w = v.clone();
                    w.push(*m);
                    w
                })
            })
            .collect();
    }
    out
}

/// STLSQ thresholds tried (coefficients of unit-RMS columns on a unit-RMS residual).
pub const THRESHOLDS: [f64; 6] = [0.03, 0.06, 0.1, 0.2, 0.35, 0.6];

/// The distinct sparse models of `slot` with at most `max_terms` terms, best R^2 first.
pub fn slot_models(
    ev: &Evidence,
    slot: Slot,
    range: std::ops::Range<usize>,
    max_terms: usize,
) -> Vec<SlotModel> {
    let mut out: Vec<SlotModel> = Vec::new();
    for lib in variants(&slot.library()) {
        let Some(d) = design(ev, slot, &lib, range.clone()) else {
            return out;
        };
        for lambda in THRESHOLDS {
            let Some(SparseFit {
                support,
                coefficients,
                r2,
            }) = stlsq(&d, lambda)
            else {
                continue;
            };
            if support.len() > max_terms {
                continue;
            }
            let terms: Vec<Term> = support.iter().map(|&i| lib[i]).collect();
            if out.iter().any(|m| m.terms == terms) {
                continue;
            }
            out.push(SlotModel {
                slot,
                terms,
                coefficients,
                r2,
            });
        }
    }
    out.sort_by(|a, b| b.r2.total_cmp(&a.r2));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lag_a_gain_and_a_leak_have_counterparts_and_new_physics_has_none() {
        assert_eq!(
            catalogue_counterpart(&Term::ReadingRate),
            Some("sensor_lag")
        );
        assert_eq!(catalogue_counterpart(&Term::Reading), Some("sensor_gain"));
        assert_eq!(catalogue_counterpart(&Term::Pressure), Some("leakage"));
        for t in [
            Term::SpeedAbsSpeed,
            Term::AngleCubed,
            Term::Stretch,
            Term::ReadingSq,
            Term::DeadbandAngle(0.2),
            Term::InletDeadZone(0.2),
        ] {
            assert_eq!(catalogue_counterpart(&t), None, "{t:?}");
        }
    }
}
