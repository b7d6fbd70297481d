//! Measured-style isometric force maps, as a lab publishes them for a braided muscle (FESTO
//! DMSP-type): the force read at a handful of fixed lengths over a pressure grid up to
//! 600-700 kPa, lengths down to L/L0 ~ 0.74, 60-130 points, the muscle *slack* (the load
//! cell reads exactly 0 N) below a length-dependent threshold pressure, noisy pressure and
//! force readings, and optionally a rising and a falling branch.
//!
//! The generator is deliberately *not* eq. 6 nor the plant's Tondu surface, so a fit of eq. 6
//! to these maps is tested against a law it was not written from. Its truth is a thick-walled
//! Chou-Hannaford muscle (geometric law of the braid with the end-effect factor of Tondu and
//! Lopez, minus the work of the bladder wall), a bladder whose elasticity must be overcome
//! before the muscle pulls (threshold pressure growing with the contraction), a braid radius
//! that swells with pressure, and braid friction proportional to the force (opposite signs
//! on the rising and falling branches).

use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};

use super::force::{Branch, ForceSample};

/// The muscle behind a measured-style map (the "truth" of a generated map).
#[derive(Clone, Debug, PartialEq)]
pub struct MapMuscle {
    /// Inner radius of the braid at rest [m].
    pub r0_m: f64,
    /// Braid angle at rest [rad].
    pub alpha0_rad: f64,
    /// End-effect factor (Tondu and Lopez): the braid contracts as if by k * (1 - L/L0).
    pub end_factor: f64,
    /// Bladder wall thickness [m] (the Chou-Hannaford thick-wall correction).
    pub wall_m: f64,
    /// Threshold gauge pressure at rest length [Pa] (bladder pre-tension).
    pub p_threshold_rest_pa: f64,
    /// Growth of the threshold with the contraction: p_th = p_rest + this * (1 - L/L0)^2 [Pa].
    pub p_threshold_growth_pa: f64,
    /// Relative swelling of the braid radius per Pa (r = r0 (1 + s P)).
    pub swell_per_pa: f64,
    /// Braid friction as a fraction of the force: the rising branch reads F (1 - mu),
    /// the falling branch F (1 + mu).
    pub friction: f64,
}

impl MapMuscle {
    /// A DMSP-20-like muscle (10 mm radius, 600 kPa for about 1.5 kN at rest length).
    pub fn dmsp20() -> Self {
        MapMuscle {
            r0_m: 0.010,
            alpha0_rad: 24.0f64.to_radians(),
            end_factor: 1.25,
            wall_m: 0.0012,
            p_threshold_rest_pa: 15_000.0,
            p_threshold_growth_pa: 2.5e6,
            swell_per_pa: 8e-8,
            friction: 0.0,
        }
    }

    /// Threshold gauge pressure below which the muscle is slack at L/L0 = `stretch` [Pa].
    pub fn threshold_pa(&self, stretch: f64) -> f64 {
        let chi = (1.0 - stretch).max(0.0);
        self.p_threshold_rest_pa + self.p_threshold_growth_pa * chi * chi
    }

    /// Static force [N] without friction (>= 0; 0 when slack).
    pub fn force_n(&self, p_gauge_pa: f64, stretch: f64) -> f64 {
        let p_eff = p_gauge_pa - self.threshold_pa(stretch);
        if p_eff <= 0.0 {
            return 0.0;
        }
        let r = self.r0_m * (1.0 + self.swell_per_pa * p_gauge_pa);
        // Braid geometry: cos(alpha) = (1 - k chi) cos(alpha0); the thin-wall force is
        // pi r^2 P (3 cos^2 alpha - 1) / sin^2 alpha0 (Chou and Hannaford, with Tondu's k).
        let chi = 1.0 - stretch;
        let cos_a = ((1.0 - self.end_factor * chi) * self.alpha0_rad.cos()).clamp(-1.0, 1.0);
        let sin2_a0 = self.alpha0_rad.sin().powi(2);
        let thin = std::f64::consts::PI * r * r * p_eff * (3.0 * cos_a * cos_a - 1.0) / sin2_a0;
        // Thick wall: the bladder's own cross-section takes part of the pressure work
        // (Chou-Hannaford: pi P [D0 t (2 sin a0 - 1/sin a0) - t^2], D0 = 2 r).
        let sin_a0 = self.alpha0_rad.sin();
        let t = self.wall_m;
        let wall = std::f64::consts::PI
            * p_eff
            * (2.0 * r * t * (2.0 * sin_a0 - 1.0 / sin_a0) - t * t)
            * stretch;
        (thin + wall).max(0.0)
    }

    /// The force on a branch (friction sign), >= 0.
    pub fn branch_force_n(&self, p_gauge_pa: f64, stretch: f64, branch: Branch) -> f64 {
        let f = self.force_n(p_gauge_pa, stretch);
        match branch {
            Branch::Pressurising => f * (1.0 - self.friction),
            Branch::Depressurising => f * (1.0 + self.friction),
        }
    }
}

/// How a measured-style map is drawn.
#[derive(Clone, Debug, PartialEq)]
pub struct MapOptions {
    /// Random seed: picks the muscle (within DMSP-like ranges), the grid and the noise.
    pub seed: u64,
    /// Both branches (rising and falling) at every length, with braid friction.
    pub branches: bool,
}

/// A generated map with its truth.
#[derive(Clone, Debug)]
pub struct ForceMap {
    /// The muscle that produced it.
    pub muscle: MapMuscle,
    /// The samples.
    pub samples: Vec<ForceSample>,
    /// Force sensor noise [N] (standard deviation).
    pub force_noise_n: f64,
    /// Pressure sensor noise [Pa] (standard deviation).
    pub pressure_noise_pa: f64,
    /// Nominal lengths L/L0 of the map.
    pub stretches: Vec<f64>,
    /// Nominal pressures of the map [Pa].
    pub pressures_pa: Vec<f64>,
}

/// Draws one measured-style map. The muscle, the grid (5..9 lengths from ~0.74 to 1.0, 10..15
/// pressures up to 600..700 kPa, 60..130 points per branch) and the noise (force sd 0.15..0.4 %
/// of full scale plus 0.5 N quantisation, pressure sd 1..3 kPa) are drawn from the seed.
pub fn force_map(opt: &MapOptions) -> ForceMap {
    let mut rng = rand::rngs::StdRng::seed_from_u64(opt.seed ^ 0x5eed_f04c_e3a9);
    let u = |rng: &mut rand::rngs::StdRng, lo: f64, hi: f64| lo + (hi - lo) * rng.random::<f64>();
    let muscle = MapMuscle {
        r0_m: u(&mut rng, 0.0045, 0.0105),
        alpha0_rad: u(&mut rng, 20.0, 28.0).to_radians(),
        end_factor: u(&mut rng, 1.05, 1.45),
        wall_m: u(&mut rng, 0.0006, 0.0016),
        p_threshold_rest_pa: u(&mut rng, 5_000.0, 30_000.0),
        p_threshold_growth_pa: u(&mut rng, 1.5e6, 4.0e6),
        swell_per_pa: u(&mut rng, 0.0, 1.5e-7),
        friction: if opt.branches {
            u(&mut rng, 0.02, 0.06)
        } else {
            0.0
        },
    };
    let p_max = (u(&mut rng, 600.0, 700.0) / 10.0).round() * 10_000.0;
    // Lengths: as many as fit 60..130 points with 10..15 pressures.
    let (n_e, n_p) = loop {
        let n_e = rng.random_range(5..=9usize);
        let n_p = rng.random_range(10..=15usize);
        if (60..=130).contains(&(n_e * n_p)) {
            break (n_e, n_p);
        }
    };
    let e_min = u(&mut rng, 0.735, 0.76);
    let stretches: Vec<f64> = (0..n_e)
        .map(|i| {
            let e = e_min + (1.0 - e_min) * i as f64 / (n_e - 1) as f64;
            (e * 1000.0).round() / 1000.0
        })
        .collect();
    let pressures_pa: Vec<f64> = (0..n_p)
        .map(|j| p_max * j as f64 / (n_p - 1) as f64)
        .collect();
    let f_full = muscle.force_n(p_max, 1.0);
    let force_noise_n = f_full * u(&mut rng, 0.0015, 0.004);
    let pressure_noise_pa = u(&mut rng, 1_000.0, 3_000.0);
    let fnoise = Normal::new(0.0, force_noise_n).expect("finite sd");
    let pnoise = Normal::new(0.0, pressure_noise_pa).expect("finite sd");
    let branches: &[Branch] = if opt.branches {
        &[Branch::Pressurising, Branch::Depressurising]
    } else {
        &[Branch::Pressurising]
    };
    let mut samples = Vec::new();
    for &e in &stretches {
        for &b in branches {
            let order: Vec<f64> = match b {
                Branch::Pressurising => pressures_pa.clone(),
                Branch::Depressurising => pressures_pa.iter().rev().copied().collect(),
            };
            for p in order {
                // The regulator holds p; the sensor reads it with noise (never below 0 gauge).
                let p_meas = (p + pnoise.sample(&mut rng)).max(0.0);
                let f_true = muscle.branch_force_n(p, e, b);
                // A slack muscle reads exactly 0 N (the cable is slack, the amplifier is zeroed);
                // a pulling one reads the force with noise, quantised to 0.5 N.
                let f_meas = if f_true > 0.0 {
                    (((f_true + fnoise.sample(&mut rng)) * 2.0).round() / 2.0).max(0.0)
                } else {
                    0.0
                };
                samples.push(ForceSample {
                    p_gauge_pa: p_meas,
                    stretch: e,
                    force_n: f_meas,
                    branch: opt.branches.then_some(b),
                });
            }
        }
    }
    ForceMap {
        muscle,
        samples,
        force_noise_n,
        pressure_noise_pa,
        stretches,
        pressures_pa,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn maps_look_measured() {
        for seed in 0..40 {
            let m = force_map(&MapOptions {
                seed,
                branches: false,
            });
            let n = m.samples.len();
            assert!((60..=130).contains(&n), "seed {seed}: {n} points");
            let pmax = m.pressures_pa.last().copied().unwrap();
            assert!((600e3..=700e3).contains(&pmax), "{pmax}");
            assert!(m.stretches[0] < 0.761 && m.stretches[0] > 0.73);
            let slack = m.samples.iter().filter(|s| s.force_n == 0.0).count();
            let pos = m.samples.iter().filter(|s| s.force_n > 0.0).count();
            assert!(
                slack >= m.stretches.len(),
                "seed {seed}: {slack} slack points"
            );
            assert!(pos > n / 2, "seed {seed}: {pos} positive of {n}");
            // The threshold grows with the contraction: the shortest length is slack at a
            // higher pressure than the rest length.
            assert!(m.muscle.threshold_pa(0.75) > 2.0 * m.muscle.threshold_pa(1.0));
        }
    }

    #[test]
    fn branches_are_ordered_by_friction() {
        let m = force_map(&MapOptions {
            seed: 3,
            branches: true,
        });
        let mu = &m.muscle;
        assert!(mu.friction > 0.0);
        let up = mu.branch_force_n(500e3, 0.9, Branch::Pressurising);
        let down = mu.branch_force_n(500e3, 0.9, Branch::Depressurising);
        assert!(down > up && up > 0.0);
        assert_eq!(
            m.samples.len(),
            2 * m.stretches.len() * m.pressures_pa.len()
        );
    }

    #[test]
    fn dmsp20_is_in_the_datasheet_range() {
        let m = MapMuscle::dmsp20();
        let f = m.force_n(600e3, 1.0);
        assert!((1000.0..2000.0).contains(&f), "{f}");
        assert_eq!(m.force_n(10e3, 0.8), 0.0);
        // Force falls with contraction at a fixed pressure.
        assert!(m.force_n(600e3, 0.8) < 0.6 * f);
    }
}
