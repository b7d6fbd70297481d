//! identify -> config -> build is one path:
//!
//! - `config/force_law.toml` and `config/torque_model.toml` (which `build.rs` turns into the
//!   firmware's constants) are exactly what `host-sim identify` produces from the data that
//!   `host-sim sweep` generates from the reference plant (the commands are in the files' headers
//!   and in README); re-running them here must give the checked-in constants.
//! - The eq. 6 proof: the firmware build of those constants (f32 `FORCE_LAW` and fixed-point
//!   `FIXED_FORCE_LAW`) reproduces the reference plant's Tondu force surface with a mean
//!   absolute error <= 0.77 % of the force range (seed 002's figure) over L/L0 0.75..1.05,
//!   0..600 kPa.

mod common;
use common::*;
use std::path::Path;

use host_sim::identify::cli::tondu_of;
use host_sim::identify::force::{self, ForceSweep};
use host_sim::PlantConfig;
use pam_firmware::constants::{FIXED_FORCE_LAW, FORCE_LAW};

fn table(path: &Path, name: &str) -> toml::Table {
    let t: toml::Table = std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .parse()
        .unwrap();
    t[name].as_table().unwrap().clone()
}

/// Sweeps `what` (`force`, `torque`) on the reference plant, runs `identify <what>
/// <data_flag> <sweep file> <extra> --out <name>.toml` on it, and returns the fresh table
/// `name` and the checked-in one of `config/<name>.toml`, which must have the same keys.
fn fresh_and_checked_in(
    what: &str,
    data_flag: &str,
    extra: &[&dyn AsRef<std::ffi::OsStr>],
    name: &str,
) -> (toml::Table, toml::Table) {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join(format!("{what}_sweep.csv"));
    let out = dir.path().join(format!("{name}.toml"));
    run_ok(&[&"sweep", &what, &"--plant", &plant(), &"--out", &data]);
    let head: [&dyn AsRef<std::ffi::OsStr>; 4] = [&"identify", &what, &data_flag, &data];
    let tail: [&dyn AsRef<std::ffi::OsStr>; 2] = [&"--out", &out];
    run_ok(&[&head[..], extra, &tail[..]].concat());
    let fresh = table(&out, name);
    let checked_in = table(&root().join(format!("config/{name}.toml")), name);
    assert_eq!(
        fresh.keys().collect::<Vec<_>>(),
        checked_in.keys().collect::<Vec<_>>()
    );
    (fresh, checked_in)
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * a.abs().max(b.abs()) + 1e-12
}

#[test]
fn checked_in_force_law_is_what_identify_gives_from_the_generated_sweep() {
    let (fresh, checked_in) = fresh_and_checked_in(
        "force",
        "--data",
        &[&"--p-gauge-max-kpa", &"600"],
        "force_law",
    );
    let c = |t: &toml::Table| -> Vec<f64> {
        t["c"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_float().unwrap())
            .collect()
    };
    // The same fit, compared as surfaces: eq. 6's large constants cancel, so a last-bit
    // difference of a platform's exp() could move single constants far more than the force.
    let (fc, cc) = (c(&fresh), c(&checked_in));
    let m_fresh = force::Eq6 {
        c: fc.clone().try_into().unwrap(),
    };
    let m_config = force::Eq6 {
        c: cc.clone().try_into().unwrap(),
    };
    let mut worst = (0.0f64, 0.0, 0.0);
    for i in 0..=60 {
        let p = 600e3 * i as f64 / 60.0;
        for j in 0..=60 {
            let e = 0.75 + 0.3 * j as f64 / 60.0;
            let d = (m_fresh.eval(p, e) - m_config.eval(p, e)).abs();
            if d > worst.0 {
                worst = (d, p, e);
            }
        }
    }
    assert!(
        worst.0 < 1e-3,
        "identify gives a force law {:.3e} N away from config/force_law.toml at {:.0} kPa, \
         L/L0 {:.3}: regenerate it (README, Identification)\nfresh:  {fc:?}\nconfig: {cc:?}",
        worst.0,
        worst.1 / 1e3,
        worst.2
    );
    for k in ["p_gauge_max_pa", "stretch_min", "stretch_max"] {
        let (a, b) = (
            fresh[k].as_float().unwrap(),
            checked_in[k].as_float().unwrap(),
        );
        assert!(close(a, b), "{k}: {a} vs {b}");
    }
}

#[test]
fn checked_in_torque_model_is_what_identify_gives_from_the_generated_sweep() {
    let (fresh, checked_in) = fresh_and_checked_in(
        "torque",
        "--recording",
        &[&"--plant", &plant(), &"--max-accel-rad-s2", &"2"],
        "torque_model",
    );
    for (k, v) in &fresh {
        let (a, b) = (v.as_float().unwrap(), checked_in[k].as_float().unwrap());
        // The file carries 7 significant digits.
        assert!(
            (a - b).abs() <= 1e-6 * a.abs().max(b.abs()) + 1e-12,
            "{k} = {a:e} from identify, {b:e} in config/torque_model.toml: regenerate it (README, Identification)"
        );
    }
}

#[test]
fn firmware_force_law_reproduces_the_tondu_surface_within_the_paper_error() {
    let truth = tondu_of(&PlantConfig::load(plant()).unwrap());
    // Noise-free surface on a 61 x 61 grid over the identification domain.
    let grid = force::sweep(&truth, &ForceSweep::noise_free_grid(61));
    let c = FORCE_LAW.c.map(|x| x as f64);
    let eq6_f64 = force::Eq6 { c };
    let f64_stats = force::error_stats(&grid, |p, e| eq6_f64.force_n(p, e));
    let f32_stats = force::error_stats(&grid, |p, e| {
        let r = FORCE_LAW.force(p as f32, e as f32);
        assert!(r.flags.is_clean(), "{p} {e} {:?}", r.flags);
        r.force_n as f64
    });
    let fixed_stats = force::error_stats(&grid, |p, e| {
        // Inputs on the domain edges may be flagged (the fixed-point bounds are rounded
        // inwards by < 1 LSB) and are then clamped: the value is still the law's.
        FIXED_FORCE_LAW
            .force_from_f32(p as f32, e as f32)
            .force_n
            .to_num::<f64>()
    });
    for (name, st) in [
        ("f64", &f64_stats),
        ("f32", &f32_stats),
        ("fixed", &fixed_stats),
    ] {
        println!(
            "{name:>5}: MAE {:.3} N = {:.3} % of range, max {:.2} N at {:.0} kPa, L/L0 {:.3}; worst region {}",
            st.mae_n, st.mae_pct_of_range, st.max_abs_n, st.max_at.0, st.max_at.1, st.worst_region
        );
        assert!(
            st.mae_pct_of_range <= 0.77,
            "{name}: MAE {:.3} % of range > 0.77 %",
            st.mae_pct_of_range
        );
    }
    // The builds agree with the f64 law far below the model error.
    assert!((f32_stats.mae_n - f64_stats.mae_n).abs() < 0.05);
    assert!((fixed_stats.mae_n - f64_stats.mae_n).abs() < 0.05);
}
