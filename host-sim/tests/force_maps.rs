//! Eq. 6 on measured-style force maps (`identify::force_maps`: a thick-walled Chou-Hannaford
//! muscle with a slack threshold, 60-130 points, exactly 0 N where slack, noisy readings),
//! which are not written from eq. 6 nor from the plant's Tondu law.
//!
//! Seeds 1..=4 are the maps the fitter was developed on; seeds 101..=112 were never looked at
//! while developing and are reported separately. Target: the firmware's law max(eq. 6, 0)
//! within 0.77 % of the force range (seed 002's figure) on every map, with the held-out
//! (leave-one-length-out, leave-one-pressure-out) error reported beside it.

mod common;
use common::*;
use std::path::Path;

use host_sim::identify::force::{self, ForceSample};
use host_sim::identify::force_maps::{force_map, ForceMap, MapOptions};

const DEVELOPMENT_SEEDS: [u64; 4] = [1, 2, 3, 4];
const HELD_OUT_SEEDS: [u64; 12] = [101, 102, 103, 104, 105, 106, 107, 108, 109, 110, 111, 112];

/// MAE of the firmware law against the noise-free truth on a dense grid over the map's domain,
/// as % of the truth's force range.
fn truth_error_pct(map: &ForceMap, eq6: &force::Eq6) -> f64 {
    let (e0, e1) = (map.stretches[0], *map.stretches.last().unwrap());
    let p1 = *map.pressures_pa.last().unwrap();
    let mut grid = Vec::new();
    for i in 0..=40 {
        for j in 0..=40 {
            let e = e0 + (e1 - e0) * i as f64 / 40.0;
            let p = p1 * j as f64 / 40.0;
            grid.push(ForceSample {
                p_gauge_pa: p,
                stretch: e,
                force_n: map.muscle.force_n(p, e),
                branch: None,
            });
        }
    }
    force::error_stats(&grid, |p, e| eq6.force_n(p, e)).mae_pct_of_range
}

struct Row {
    seed: u64,
    n: usize,
    slack: usize,
    train_pct: f64,
    truth_pct: f64,
    lolo_pct: f64,
    lopo_pct: f64,
    starts: (usize, usize),
    tondu_pct: f64,
    ch_pct: f64,
}

fn row(seed: u64) -> Row {
    let map = force_map(&MapOptions {
        seed,
        branches: false,
    });
    let id = force::identify(&map.samples).unwrap();
    Row {
        seed,
        n: id.n_samples,
        slack: id.n_slack,
        train_pct: id.eq6_stats.mae_pct_of_range,
        truth_pct: truth_error_pct(&map, &id.eq6),
        lolo_pct: id.leave_length_out.as_ref().unwrap().mae_pct_of_range,
        lopo_pct: id.leave_pressure_out.as_ref().unwrap().mae_pct_of_range,
        starts: (id.eq6_fit.starts_at_best, id.eq6_fit.starts),
        tondu_pct: id.tondu_stats.mae_pct_of_range,
        ch_pct: id.chou_hannaford_stats.mae_pct_of_range,
    }
}

fn table(title: &str, rows: &[Row]) {
    println!("{title}");
    println!("seed    n slack  eq6 fit %  vs truth %  held-out length %  held-out pressure %  starts at best  Tondu %  Chou-H. %");
    for r in rows {
        println!(
            "{:4} {:4} {:5}  {:9.3}  {:10.3}  {:17.3}  {:19.3}  {:>8}/{:<5}  {:7.3}  {:9.3}",
            r.seed,
            r.n,
            r.slack,
            r.train_pct,
            r.truth_pct,
            r.lolo_pct,
            r.lopo_pct,
            r.starts.0,
            r.starts.1,
            r.tondu_pct,
            r.ch_pct
        );
    }
    let mean = |f: fn(&Row) -> f64| rows.iter().map(f).sum::<f64>() / rows.len() as f64;
    println!(
        "mean            {:9.3}  {:10.3}  {:17.3}  {:19.3}",
        mean(|r| r.train_pct),
        mean(|r| r.truth_pct),
        mean(|r| r.lolo_pct),
        mean(|r| r.lopo_pct)
    );
}

#[test]
fn eq6_reaches_the_paper_error_on_measured_style_maps() {
    let dev: Vec<Row> = DEVELOPMENT_SEEDS.iter().map(|&s| row(s)).collect();
    table("development maps", &dev);
    let held: Vec<Row> = HELD_OUT_SEEDS.iter().map(|&s| row(s)).collect();
    table("held-out maps (never used while developing)", &held);
    for r in dev.iter().chain(&held) {
        assert!(
            r.train_pct <= 0.77,
            "seed {}: eq. 6 MAE {:.3} % of range > 0.77 %",
            r.seed,
            r.train_pct
        );
        // The global search is not a lucky single start: more than one start reaches the best.
        assert!(r.starts.0 >= 2, "seed {}: {:?}", r.seed, r.starts);
        // eq. 6 beats the Tondu baseline (the Chou-Hannaford baseline, being of the
        // generator's family, sometimes comes close or wins: reported, not asserted).
        assert!(r.train_pct < r.tondu_pct, "seed {}", r.seed);
    }
}

#[test]
fn branches_are_fitted_separately_and_their_gap_matches_the_friction() {
    let map = force_map(&MapOptions {
        seed: 5,
        branches: true,
    });
    let id = force::identify(&map.samples).unwrap();
    println!("{}", id.summary());
    let h = id.hysteresis.as_ref().expect("both branches");
    // True gap: 2 mu F at the points where the muscle pulls.
    let gaps: Vec<f64> = map
        .samples
        .iter()
        .map(|s| 2.0 * map.muscle.friction * map.muscle.force_n(s.p_gauge_pa, s.stretch))
        .filter(|g| *g > 0.0)
        .collect();
    let truth = gaps.iter().sum::<f64>() / gaps.len() as f64;
    assert!(
        (h.gap_mean_n - truth).abs() < 0.35 * truth,
        "gap {:.2} N vs true {truth:.2} N",
        h.gap_mean_n
    );
    assert!(h.rising.1.mae_pct_of_range <= 0.77 && h.falling.1.mae_pct_of_range <= 0.77);
}

#[test]
fn the_physical_baselines_are_fitted_inside_their_bounds() {
    // On maps the unbounded Tondu fit used to collapse to r0 = 0.000 mm. Bounded, r0 stays
    // a radius; r0 and alpha0 trade off against each other on these maps (a thin muscle with
    // a flat braid pulls like a thicker one with a steeper braid), so a parameter that ends
    // on its bound is reported as a warning.
    for seed in [1, 101] {
        let map = force_map(&MapOptions {
            seed,
            branches: false,
        });
        let id = force::identify(&map.samples).unwrap();
        let (lo, hi) = force::TONDU_BOUNDS;
        let tondu = [
            id.tondu.r0_m * 1e3,
            id.tondu.alpha0_rad.to_degrees(),
            id.tondu.k,
        ];
        let ch = &id.chou_hannaford;
        let chx = [ch.r0_m * 1e3, ch.alpha0_rad.to_degrees(), ch.k];
        for (name, x) in [("Tondu", tondu), ("Chou-Hannaford", chx)] {
            assert!(x[0] > 1.5, "seed {seed}: {name} r0 {} mm", x[0]);
            for i in 0..3 {
                assert!((lo[i]..=hi[i]).contains(&x[i]), "seed {seed}: {name} {x:?}");
                let tol = 1e-3 * (hi[i] - lo[i]);
                if x[i] <= lo[i] + tol || x[i] >= hi[i] - tol {
                    assert!(
                        id.warnings
                            .iter()
                            .any(|w| w.starts_with(name) && w.contains("on its bound")),
                        "seed {seed}: {name} {x:?} on a bound without a warning: {:?}",
                        id.warnings
                    );
                }
            }
        }
    }
}

fn refused(data: &Path, body: &str, want: &str) {
    let out = data.with_file_name("force.toml");
    std::fs::write(data, body).unwrap();
    let r = host_sim(&[&"identify", &"force", &"--data", &data, &"--out", &out]);
    assert_eq!(r.status.code(), Some(2), "{body}");
    let err = text(&r.stderr);
    assert!(err.contains(want), "{err}");
    assert!(!out.exists(), "a constants file was written");
}

#[test]
fn bad_maps_are_refused_with_a_reason_and_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("map.csv");
    // No positive force: the muscle never pulled.
    let mut body = String::from("p_kpa,stretch,f_n\n");
    for e in [0.8, 0.9, 1.0] {
        for p in 0..10 {
            body.push_str(&format!("{},{e},0\n", p * 60));
        }
    }
    refused(&data, &body, "no sample has a positive force");
    // One length only.
    let mut body = String::from("p_kpa,stretch,f_n\n");
    for p in 0..30 {
        body.push_str(&format!("{},0.9,{}\n", p * 20, p * 30));
    }
    refused(&data, &body, "one length");
    // Pressures in MPa in the kPa column.
    let mut body = String::from("p_kpa,stretch,f_n\n");
    for e in [0.8, 0.9, 1.0] {
        for p in 0..10 {
            body.push_str(&format!("{},{e},{}\n", p as f64 * 0.06, p * 100));
        }
    }
    refused(&data, &body, "look like MPa");
    // Pressures in Pa: the line and the field are named.
    let body = "p_kpa,stretch,f_n\n100,0.9,50\n600000,0.9,900\n";
    refused(&data, body, "map.csv:3: field `p_kpa`");
}

#[test]
fn sweep_force_map_then_identify_force_writes_the_report_into_the_constants_file() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("map.csv");
    let out = dir.path().join("force.toml");
    let r = host_sim(&[&"sweep", &"force-map", &"--seed", &"7", &"--out", &data]);
    assert!(r.status.success(), "{}", text(&r.stderr));
    let r = host_sim(&[&"identify", &"force", &"--data", &data, &"--out", &out]);
    assert!(r.status.success(), "{}", text(&r.stderr));
    let s = text(&r.stdout);
    println!("{s}");
    for want in [
        "slack",
        "global search:",
        "held out, one length at a time",
        "held out, one pressure level at a time",
        "Chou-H.",
        "Tondu fit: r0 = ",
        "c10 = ",
    ] {
        assert!(s.contains(want), "missing {want:?} in\n{s}");
    }
    let toml = std::fs::read_to_string(&out).unwrap();
    assert!(toml.contains("# global search:") && toml.contains("truth = r0"));
    let t: toml::Table = toml.parse().unwrap();
    assert_eq!(t["force_law"]["c"].as_array().unwrap().len(), 10);
}
