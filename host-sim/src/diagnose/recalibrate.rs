//! Recalibration: a nominal parameter of the plant file that is simply off (a valve
//! conductance 30 % low, a muscle radius a few % large, a load on the joint) is the most
//! common mismatch on a real rig. Each refittable key is a [`Candidate`] with one parameter,
//! the key's value, bounded to a physical range around the nominal value, so recalibration
//! and missing physics compete in the same selection under the same acceptance rule (and a
//! recalibration, one parameter of the model the user already has, is preferred when an
//! effect does not beat it by that rule).
//!
//! Also here: [`Bounded`], which narrows a catalogue candidate's parameter bounds to the
//! physically possible range (a polytropic exponent between isothermal 1 and adiabatic 1.4).

use crate::plant::config::PlantConfig;

use super::candidates::{Candidate, ParamSpec, Screening, Setup};
use super::screen::Evidence;

/// One refittable key of the plant file.
pub struct RecalKey {
    /// Dotted key of the plant file.
    pub key: &'static str,
    pub label: &'static str,
    /// Bounds as factors of the nominal value (for a zero nominal value: absolute).
    pub lo_factor: f64,
    pub hi_factor: f64,
    pub(crate) get: fn(&PlantConfig) -> f64,
    pub(crate) set: fn(&mut PlantConfig, f64),
}

/// A [`RecalKey`] for a plain field `table.key` of the plant file.
macro_rules! field_key {
    ($table:ident . $field:ident, $label:expr, $lo:expr, $hi:expr) => {
        RecalKey {
            key: concat!(stringify!($table), ".", stringify!($field)),
            label: $label,
            lo_factor: $lo,
            hi_factor: $hi,
            get: |c| c.$table.$field,
            set: |c, v| c.$table.$field = v,
        }
    };
}

/// A [`RecalKey`] for key `$field` of valve `$i` (`[valve.inlet1]` ...: [`VALVE_TABLES`]
/// order), read through the valve's overrides and written into its own table.
macro_rules! valve_key {
    ($i:literal, $name:literal, $field:ident, $label:expr, $lo:expr, $hi:expr) => {
        RecalKey {
            key: concat!("valve.", $name, ".", stringify!($field)),
            label: $label,
            lo_factor: $lo,
            hi_factor: $hi,
            get: |c| c.valve.of($i).$field,
            set: |c, v| c.valve.override_mut($i).$field = Some(v),
        }
    };
}

/// A [`RecalKey`] for key `$field` of muscle `$i` (`[muscle.m1]`, `[muscle.m2]`), read
/// through the muscle's overrides and written into its own table.
macro_rules! muscle_key {
    ($i:literal, $name:literal, $field:ident, $label:expr, $lo:expr, $hi:expr) => {
        RecalKey {
            key: concat!("muscle.", $name, ".", stringify!($field)),
            label: $label,
            lo_factor: $lo,
            hi_factor: $hi,
            get: |c| c.muscle.of($i).$field,
            set: |c, v| c.muscle.override_mut($i).$field = Some(v),
        }
    };
}

/// A [`RecalKey`] for the initial contraction of muscle `$i` alone.
macro_rules! muscle_chi0_key {
    ($i:literal, $name:literal, $label:expr) => {
        RecalKey {
            key: concat!("muscle.", $name, ".initial_contraction"),
            label: $label,
            lo_factor: CHI0_FACTORS.0,
            hi_factor: CHI0_FACTORS.1,
            get: |c| {
                c.muscle
                    .initial_contraction_of($i, c.joint.initial_contraction)
            },
            set: |c, v| c.muscle.override_mut($i).initial_contraction = Some(v),
        }
    };
}

/// Search range of the muscles' geometry keys (rest length, end factor, sprocket radius) as
/// factors of the file's value: a tape measure is rarely 20 % off.
const GEOMETRY_FACTORS: (f64, f64) = (0.8, 1.25);
/// Search range of the initial contraction (chi0 0.14 -> 0.084 .. 0.196; it must stay below
/// the force law's maximum contraction, about 0.25 on the reference muscles).
const CHI0_FACTORS: (f64, f64) = (0.6, 1.4);
/// Search range of the Tondu force keys (radius, braid angle).
const FORCE_FACTORS: (f64, f64) = (0.7, 1.3);
/// Search range of a valve's sonic conductance.
const CONDUCTANCE_FACTORS: (f64, f64) = (0.2, 5.0);

/// The keys the diagnosis may recalibrate: the shared keys first, then the keys of one valve
/// or one muscle ([`is_part_key`]), which the pool keeps only when the evidence points at
/// that valve or muscle ([`super::key_screen::retain_indicated`]).
pub fn keys() -> Vec<RecalKey> {
    let (cl, ch) = CONDUCTANCE_FACTORS;
    let (fl, fh) = FORCE_FACTORS;
    let (gl, gh) = GEOMETRY_FACTORS;
    vec![
        field_key!(
            valve.sonic_conductance_m3_per_s_pa,
            "valve sonic conductance",
            cl,
            ch
        ),
        field_key!(muscle.radius_m, "muscle radius", fl, fh),
        field_key!(muscle.braid_angle_deg, "braid angle", fl, fh),
        RecalKey {
            // The whole volume polynomial is scaled; reported as its constant term b0.
            key: "muscle.volume_poly_m3",
            label: "muscle chamber volume (scale of the volume polynomial)",
            lo_factor: 0.5,
            hi_factor: 2.0,
            get: |c| c.muscle.volume_poly_m3[0],
            set: |c, v| {
                let s = v / c.muscle.volume_poly_m3[0];
                for b in &mut c.muscle.volume_poly_m3 {
                    *b *= s;
                }
            },
        },
        RecalKey {
            key: "muscle.damping_m2s",
            label: "muscle damping",
            lo_factor: 0.0,
            hi_factor: 20.0,
            get: |c| c.muscle.damping_m2s,
            set: |c, v| c.muscle.damping_m2s = v.max(0.0),
        },
        // Symmetric in ratio: a load added or taken off (a plant file of the loaded joint
        // on a recording of the bare one).
        field_key!(joint.inertia_kgm2, "joint inertia (load)", 1.0 / 30.0, 30.0),
        field_key!(environment.supply_gauge_pa, "supply pressure", 0.5, 1.3),
        field_key!(muscle.rest_length_m, "muscle rest length", gl, gh),
        field_key!(
            joint.initial_contraction,
            "initial contraction",
            CHI0_FACTORS.0,
            CHI0_FACTORS.1
        ),
        field_key!(muscle.end_factor, "muscle end factor", gl, gh),
        field_key!(joint.sprocket_radius_m, "sprocket radius", gl, gh),
        // 0.433 -> 0.22 .. 0.69 (ISO 6358 b of real valves: about 0.2 .. 0.5).
        field_key!(valve.critical_ratio, "valve critical ratio", 0.5, 1.6),
        valve_key!(
            0,
            "inlet1",
            sonic_conductance_m3_per_s_pa,
            "inlet valve 1 conductance",
            cl,
            ch
        ),
        valve_key!(
            1,
            "exhaust1",
            sonic_conductance_m3_per_s_pa,
            "exhaust valve 1 conductance",
            cl,
            ch
        ),
        valve_key!(
            2,
            "inlet2",
            sonic_conductance_m3_per_s_pa,
            "inlet valve 2 conductance",
            cl,
            ch
        ),
        valve_key!(
            3,
            "exhaust2",
            sonic_conductance_m3_per_s_pa,
            "exhaust valve 2 conductance",
            cl,
            ch
        ),
        muscle_key!(0, "m1", radius_m, "muscle 1 radius", fl, fh),
        muscle_key!(1, "m2", radius_m, "muscle 2 radius", fl, fh),
        muscle_key!(0, "m1", braid_angle_deg, "muscle 1 braid angle", fl, fh),
        muscle_key!(1, "m2", braid_angle_deg, "muscle 2 braid angle", fl, fh),
        muscle_key!(0, "m1", end_factor, "muscle 1 end factor", gl, gh),
        muscle_key!(1, "m2", end_factor, "muscle 2 end factor", gl, gh),
        muscle_key!(0, "m1", rest_length_m, "muscle 1 rest length", gl, gh),
        muscle_key!(1, "m2", rest_length_m, "muscle 2 rest length", gl, gh),
        muscle_chi0_key!(0, "m1", "muscle 1 initial contraction"),
        muscle_chi0_key!(1, "m2", "muscle 2 initial contraction"),
    ]
}

/// Whether `key` belongs to one valve or one muscle (`valve.inlet1.*`, `muscle.m2.*`).
pub fn is_part_key(key: &str) -> bool {
    part_of(key).is_some()
}

/// The shared key a key of one valve or one muscle refines, with the part's index:
/// `valve.inlet1.sonic_conductance_m3_per_s_pa` -> (`valve.sonic_conductance_m3_per_s_pa`,
/// valve 0); `muscle.m2.initial_contraction` -> (`joint.initial_contraction`, muscle 1).
pub fn part_of(key: &str) -> Option<(String, usize)> {
    let mut it = key.splitn(3, '.');
    let (table, part, field) = (it.next()?, it.next()?, it.next()?);
    let i = match table {
        "valve" => crate::plant::config::VALVE_TABLES
            .iter()
            .position(|t| *t == part)?,
        "muscle" => crate::plant::config::MUSCLE_TABLES
            .iter()
            .position(|t| *t == part)?,
        _ => return None,
    };
    let shared = if table == "muscle" && field == "initial_contraction" {
        "joint.initial_contraction".to_string()
    } else {
        format!("{table}.{field}")
    };
    Some((shared, i))
}

/// Keys a recording cannot tell apart, each group with the name the answer gives it: the
/// Tondu force keys scale the force alike, and the contraction keys all move the muscles'
/// operating point on the force law. Per muscle the same groups hold within that muscle.
/// (The valve conductance and the chamber volume are a look-alike pair of the answer too.)
pub const GROUPS: &[(&str, &[&str])] = &[
    (
        "muscle radius or braid angle",
        &["muscle.radius_m", "muscle.braid_angle_deg"],
    ),
    (
        "muscle 1 radius or braid angle",
        &["muscle.m1.radius_m", "muscle.m1.braid_angle_deg"],
    ),
    (
        "muscle 2 radius or braid angle",
        &["muscle.m2.radius_m", "muscle.m2.braid_angle_deg"],
    ),
    (
        "muscle end factor, initial contraction or rest length",
        &[
            "muscle.end_factor",
            "joint.initial_contraction",
            "muscle.rest_length_m",
        ],
    ),
    (
        "muscle 1 end factor, initial contraction or rest length",
        &[
            "muscle.m1.end_factor",
            "muscle.m1.initial_contraction",
            "muscle.m1.rest_length_m",
        ],
    ),
    (
        "muscle 2 end factor, initial contraction or rest length",
        &[
            "muscle.m2.end_factor",
            "muscle.m2.initial_contraction",
            "muscle.m2.rest_length_m",
        ],
    ),
];

/// The group of [`GROUPS`] `key` belongs to: its name and members.
pub fn group_of(key: &str) -> Option<(&'static str, &'static [&'static str])> {
    GROUPS
        .iter()
        .find(|(_, members)| members.contains(&key))
        .copied()
}

/// A round-1 share within this many points of the named key's makes a group member as
/// likely as the named key: the recording did not tell them apart.
pub const GROUP_TIE_POINTS: f64 = 10.0;

/// The answer's statement for each named key of a [`GROUPS`] group: the group's name, what
/// each member removed alone in round 1 (`share(key)`, 0..1; `None`: not refitted) and
/// whether the recording told them apart.
pub fn group_notes(named: &[&str], share: impl Fn(&str) -> Option<f64>) -> Vec<String> {
    let pct = |k: &str| share(k).map(|v| 100.0 * v.max(0.0));
    named
        .iter()
        .filter_map(|k| {
            let (name, members) = group_of(k)?;
            let own = pct(k).unwrap_or(0.0);
            let others: Vec<String> = members
                .iter()
                .filter(|m| *m != k)
                .map(|m| match pct(m) {
                    Some(p) => format!("{m} {p:.0} %"),
                    None => format!("{m} not refitted"),
                })
                .collect();
            let tied = members
                .iter()
                .filter(|m| *m != k)
                .any(|m| pct(m).is_some_and(|p| own - p < GROUP_TIE_POINTS));
            Some(format!(
                "{k} is one of a group of keys this plant model moves alike ({name}): \
                 recalibrating it removes {own:.0} % of the held-out error beyond noise, {}; {}",
                others.join(", "),
                if tied {
                    "this recording cannot tell them apart: read the answer as the group, and \
                     measure one of them to fix the others."
                } else {
                    "this recording prefers it, but measure it before trusting it over the others."
                }
            ))
        })
        .collect()
}

/// A recalibration candidate: one key, its nominal value and bounds.
pub struct Recal {
    pub k: RecalKey,
    pub nominal: f64,
    /// A catalogue candidate whose screening gives a better start than the nominal value
    /// (the inertia screening regresses the torque balance on the acceleration).
    pub screen_with: Option<Box<dyn Candidate>>,
}

impl Recal {
    pub fn bounds(&self) -> (f64, f64) {
        let n = self.nominal.abs().max(1e-300);
        (self.k.lo_factor * n, self.k.hi_factor * n)
    }
}

/// The recalibration candidates for a nominal plant (keys with a zero or non-finite
/// nominal value are left out: a factor of nothing bounds nothing).
pub fn candidates(nominal: &PlantConfig) -> Vec<Box<dyn Candidate>> {
    keys()
        .into_iter()
        .filter_map(|k| {
            let v = (k.get)(nominal);
            if !(v.is_finite() && v > 0.0) {
                return None;
            }
            let screen_with: Option<Box<dyn Candidate>> = if k.key == "joint.inertia_kgm2" {
                Some(Box::new(crate::plant::effects::inertia::InertiaCandidate))
            } else {
                None
            };
            Some(Box::new(Recal {
                k,
                nominal: v,
                screen_with,
            }) as Box<dyn Candidate>)
        })
        .collect()
}

/// A recalibration that moves its key by less than this fraction of the plant file's value
/// leaves the file as it is (0.1 %: finer than a rig's parameter is measured): it is dropped
/// from the answer, however much residue it fits (it would tell the user to change 25.3 deg
/// to 25.3 deg).
pub const RECAL_NEGLIGIBLE: f64 = 1e-3;

/// Whether a candidate id is a recalibrated plant key (dotted) rather than an effect.
pub fn is_recal_id(id: &str) -> bool {
    id.contains('.')
}

impl Candidate for Recal {
    fn id(&self) -> &'static str {
        self.k.key
    }
    fn label(&self) -> &'static str {
        self.k.label
    }
    fn params(&self, _s: &Setup) -> Vec<ParamSpec> {
        let (lo, hi) = self.bounds();
        vec![ParamSpec {
            name: self.k.key.to_string(),
            lo,
            hi,
            scale: self.nominal.abs(),
        }]
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        let (lo, hi) = self.bounds();
        if let Some(c) = &self.screen_with {
            let mut sc = c.screen(ev, s);
            sc.initial = vec![sc
                .initial
                .first()
                .copied()
                .unwrap_or(self.nominal)
                .clamp(lo, hi)];
            return sc;
        }
        Screening {
            score: f64::NAN,
            initial: vec![self.nominal],
            note: format!(
                "the plant file's {} ({}) refitted within [{lo:.4e}, {hi:.4e}]",
                self.k.label, self.k.key
            ),
            scatter: None,
        }
    }
    fn apply(&self, cfg: &mut PlantConfig, params: &[f64], _s: &Setup) {
        (self.k.set)(cfg, params[0]);
    }
    fn changes_nothing(&self, params: &[f64]) -> bool {
        (params[0] / self.nominal - 1.0).abs() < RECAL_NEGLIGIBLE
    }
    fn describe(&self, params: &[f64], _s: &Setup) -> String {
        format!(
            "{} = {:.4e} instead of the nominal {:.4e} ({:+.1} %)",
            self.k.key,
            params[0],
            self.nominal,
            100.0 * (params[0] / self.nominal - 1.0)
        )
    }
}

/// Physical bounds on catalogue parameters (candidate id, parameter name, lo, hi): the fit
/// never leaves them, and an answer at one says so.
pub const PHYSICAL_BOUNDS: [(&str, &str, f64, f64); 1] = [
    // Between isothermal (1) and adiabatic air (1.4): a chamber that is not heated cannot
    // go below 1.
    ("polytropic", "exponent", 1.0, 1.4),
];

/// A catalogue candidate with its bounds narrowed to [`PHYSICAL_BOUNDS`].
pub struct Bounded(pub Box<dyn Candidate>);

impl Candidate for Bounded {
    fn id(&self) -> &'static str {
        self.0.id()
    }
    fn label(&self) -> &'static str {
        self.0.label()
    }
    fn params(&self, s: &Setup) -> Vec<ParamSpec> {
        let id = self.0.id();
        self.0
            .params(s)
            .into_iter()
            .map(|mut p| {
                for (cid, name, lo, hi) in PHYSICAL_BOUNDS {
                    if cid == id && name == p.name {
                        p.lo = p.lo.max(lo);
                        p.hi = p.hi.min(hi);
                    }
                }
                p
            })
            .collect()
    }
    fn fixed(&self) -> Vec<(&'static str, f64)> {
        self.0.fixed()
    }
    fn screen(&self, ev: &Evidence, s: &Setup) -> Screening {
        let mut sc = self.0.screen(ev, s);
        let specs = self.params(s);
        for (v, p) in sc.initial.iter_mut().zip(&specs) {
            *v = v.clamp(p.lo, p.hi);
        }
        sc
    }
    fn apply(&self, cfg: &mut PlantConfig, params: &[f64], s: &Setup) {
        self.0.apply(cfg, params, s)
    }
    fn changes_dynamics(&self) -> bool {
        self.0.changes_dynamics()
    }
    fn grid(&self, initial: &[f64], s: &Setup) -> Option<Vec<Vec<f64>>> {
        self.0.grid(initial, s)
    }
    fn refine_after_grid(&self) -> bool {
        self.0.refine_after_grid()
    }
    fn describe(&self, params: &[f64], s: &Setup) -> String {
        self.0.describe(params, s)
    }
}

/// Share of a non-zero bound within which a refitted plant-file key counts as at its bound:
/// the diagnosis searches a key only within a factor range of the file's value (radius
/// 0.7x..1.3x), so a key that ends at 1.29x most likely lies beyond the range.
pub const RECAL_NEAR_BOUND: f64 = 0.02;

/// Names of the parameters of `c` that ended at a bound: within 0.1 % of their scale, or for
/// a recalibrated key within [`RECAL_NEAR_BOUND`] of a non-zero bound.
pub fn at_bounds(c: &dyn Candidate, params: &[f64], s: &Setup) -> Vec<(String, f64)> {
    if c.grid(params, s).is_some() {
        return Vec::new();
    }
    let recal = is_recal_id(c.id());
    c.params(s)
        .iter()
        .zip(params)
        .filter_map(|(p, v)| {
            let tol_of = |bound: f64| {
                if recal && bound != 0.0 {
                    RECAL_NEAR_BOUND * bound.abs()
                } else {
                    1e-3 * p.scale.abs().max(1e-300)
                }
            };
            if p.lo.is_finite() && (v - p.lo).abs() <= tol_of(p.lo) {
                Some((p.name.clone(), p.lo))
            } else if p.hi.is_finite() && (p.hi - v).abs() <= tol_of(p.hi) {
                Some((p.name.clone(), p.hi))
            } else {
                None
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn nominal() -> PlantConfig {
        PlantConfig::reference()
    }

    #[test]
    fn every_key_reads_and_writes_its_field() {
        let cfg = nominal();
        let s = Setup {
            dt_s: 1e-3,
            present: [true; 5],
        };
        for c in candidates(&cfg) {
            let p = c.params(&s);
            assert_eq!(p.len(), 1);
            assert!(p[0].lo < p[0].scale && p[0].scale < p[0].hi, "{}", c.id());
            let mut m = cfg.clone();
            c.apply(&mut m, &[1.1 * p[0].scale], &s);
            assert_ne!(m, cfg, "{} changed nothing", c.id());
            assert!(is_recal_id(c.id()));
        }
        let mut m = cfg.clone();
        let vol = candidates(&cfg)
            .into_iter()
            .find(|c| c.id() == "muscle.volume_poly_m3")
            .unwrap();
        vol.apply(&mut m, &[2.0 * cfg.muscle.volume_poly_m3[0]], &s);
        for (a, b) in m
            .muscle
            .volume_poly_m3
            .iter()
            .zip(&cfg.muscle.volume_poly_m3)
        {
            assert!((a - 2.0 * b).abs() <= 1e-15 * b.abs().max(1.0));
        }
    }

    #[test]
    fn a_key_of_one_part_writes_its_own_table_and_names_its_shared_key() {
        let cfg = nominal();
        let s = Setup {
            dt_s: 1e-3,
            present: [true; 5],
        };
        let pool = candidates(&cfg);
        let find = |id: &str| pool.iter().find(|c| c.id() == id).unwrap();
        let mut m = cfg.clone();
        find("valve.exhaust2.sonic_conductance_m3_per_s_pa").apply(&mut m, &[4e-9], &s);
        assert_eq!(m.valve.sonic_conductance_m3_per_s_pa, 8e-9);
        assert_eq!(m.valve.of(3).sonic_conductance_m3_per_s_pa, 4e-9);
        assert_eq!(m.valve.of(2).sonic_conductance_m3_per_s_pa, 8e-9);
        find("muscle.m1.initial_contraction").apply(&mut m, &[0.12], &s);
        assert_eq!(
            m.muscle
                .initial_contraction_of(0, m.joint.initial_contraction),
            0.12
        );
        assert_eq!(m.joint.initial_contraction, 0.14);
        assert_eq!(
            part_of("muscle.m2.initial_contraction"),
            Some(("joint.initial_contraction".into(), 1))
        );
        assert_eq!(
            part_of("valve.inlet2.sonic_conductance_m3_per_s_pa"),
            Some(("valve.sonic_conductance_m3_per_s_pa".into(), 2))
        );
        assert_eq!(part_of("muscle.radius_m"), None);
        assert!(!is_part_key("joint.inertia_kgm2"));
        // Every group member is a key.
        let ids: Vec<&str> = keys().iter().map(|k| k.key).collect();
        for (_, members) in GROUPS {
            assert!(members.iter().all(|m| ids.contains(m)), "{members:?}");
        }
    }

    #[test]
    fn a_named_key_of_a_group_is_reported_with_the_group() {
        let share = |k: &str| match k {
            "muscle.radius_m" => Some(0.9),
            "muscle.braid_angle_deg" => Some(0.85),
            _ => None,
        };
        let notes = group_notes(&["muscle.radius_m", "leakage"], share);
        assert_eq!(notes.len(), 1);
        assert!(
            notes[0].contains("muscle radius or braid angle"),
            "{}",
            notes[0]
        );
        assert!(notes[0].contains("cannot tell them apart"), "{}", notes[0]);
        let clear = group_notes(&["muscle.radius_m"], |k| {
            (k == "muscle.radius_m").then_some(0.9)
        });
        assert!(clear[0].contains("not refitted"), "{}", clear[0]);
        assert!(clear[0].contains("prefers it"), "{}", clear[0]);
    }

    #[test]
    fn polytropic_exponent_is_bounded_to_physics() {
        let s = Setup {
            dt_s: 1e-3,
            present: [true; 5],
        };
        let b = Bounded(Box::new(
            crate::plant::effects::polytropic::PolytropicCandidate,
        ));
        let p = b.params(&s);
        assert_eq!((p[0].lo, p[0].hi), (1.0, 1.4));
        assert_eq!(
            at_bounds(&b, &[1.4], &s),
            vec![("exponent".to_string(), 1.4)]
        );
        assert!(at_bounds(&b, &[1.2], &s).is_empty());
    }
}
