//! `host-sim calibrate`: from a recording of the joint to the firmware's constants in one
//! command. Stages: refuse degenerate data -> torque model (seed 003 eq. 11) from the recording
//! -> the plant-derived constants (geometry, inertia, supply, valve, chamber volume) from the
//! plant file -> (with `--tune`) gains on the plant -> the files in `--out-dir`, each with its
//! provenance header, printing what changed (old -> new per key) against the files already
//! there. Every file goes through the one atomic writer inside the command's transaction
//! (`crate::io::atomic`): all files are replaced or none.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};

use crate::identify::cli::{torque_model_file, IdentifyTorqueArgs};
use crate::identify::write_atomic;
pub use crate::identify::{
    MIN_ANGLE_SD_DEG, MIN_IDENTIFIED_HELDOUT_FIT_PCT, MIN_PRESSURE_SD_KPA, MIN_TORQUE_FIT_PCT,
};
use crate::io::recording::Channel;
use crate::{Plant, Recording};

/// Margin above the supply before a pressure reading is refused [kPa] (sensor noise, droop).
pub const SUPPLY_MARGIN_KPA: f64 = 20.0;

/// `host-sim calibrate`.
#[derive(Debug)]
pub struct CalibrateArgs {
    /// Recording of the joint (RECORDING.md: angle_deg, p1_kpa, p2_kpa, optionally f1_n, f2_n):
    /// a motion through a range of angles under varying activation (e.g. `host-sim sweep torque`).
    pub recording: PathBuf,
    /// Plant file (PLANT.md format; e.g. the output of `host-sim identify plant`): geometry,
    /// inertia, supply, valve, and the force model when the recording has no tensions.
    pub plant: PathBuf,
    /// Directory of the firmware's constants (config/): torque_model.toml,
    /// joint_geometry.toml, plant_constants.toml (and with --tune control_tuned.toml) are
    /// replaced there.
    pub out_dir: PathBuf,
    /// Also tune the control gains on the plant file (`host-sim tune`, minutes).
    pub tune: bool,
    /// Worker threads of the tuner (with --tune; 1..=256, as every command's --threads).
    pub threads: usize,
    /// First identify these plant-file keys (comma separated, `key` or `key=lo:hi`, as
    /// `host-sim identify plant --params`) by replaying a valve-driven recording; the
    /// identified plant file (plant_identified.toml in --out-dir) then feeds every later stage.
    pub identify_plant: Vec<String>,
    /// The valve-driven recording of --identify-plant (columns t_s, u_in1, u_ex1, u_in2,
    /// u_ex2 and the measured channels) [default: --recording].
    pub plant_recording: Option<PathBuf>,
}

fn sd(v: &[f64]) -> f64 {
    let n = v.len().max(1) as f64;
    let m = v.iter().sum::<f64>() / n;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / n).sqrt()
}

/// The reasons a recording must not give firmware constants (empty: usable).
pub fn degenerate_reasons(rec: &Recording, plant: &Plant, file: &str) -> Vec<String> {
    let mut why = Vec::new();
    match rec.channel(Channel::AngleDeg) {
        Some(a) if !(sd(a) >= MIN_ANGLE_SD_DEG) => {
            // A spread that would be a motion in radians: the angle logged in radians.
            let as_rad_deg = sd(a).to_degrees();
            let unit = if as_rad_deg >= MIN_ANGLE_SD_DEG {
                format!(
                    ", or it is logged in radians (read as radians its sd is {as_rad_deg:.1} \
                     deg): check the angle unit, angle_deg is in degrees (RECORDING.md)"
                )
            } else {
                String::new()
            };
            why.push(format!(
                "{file}: angle_deg is constant (sd {:.3} deg < {MIN_ANGLE_SD_DEG} deg): the joint \
                 did not move{unit}",
                sd(a)
            ))
        }
        None => why.push(format!("{file}: no angle_deg column")),
        _ => {}
    }
    let supply_kpa = (plant.p_supply_abs_pa - plant.p_atm_pa) / 1e3;
    let (p1, p2) = (rec.channel(Channel::P1Kpa), rec.channel(Channel::P2Kpa));
    for (p, name) in [(p1, "p1_kpa"), (p2, "p2_kpa")] {
        match p {
            Some(p) => {
                if !(sd(p) >= MIN_PRESSURE_SD_KPA) {
                    let p_max = p.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                    let unit = if p_max < 10.0 {
                        format!(
                            " (at most {p_max:.3} kPa: logged in bar or MPa? the column is in kPa)"
                        )
                    } else {
                        String::new()
                    };
                    why.push(format!(
                        "{file}: {name} is constant (sd {:.3} kPa < {MIN_PRESSURE_SD_KPA} kPa){unit}: no activation to identify",
                        sd(p)
                    ));
                }
                let pmax = p.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
                if !(pmax <= supply_kpa + SUPPLY_MARGIN_KPA) {
                    why.push(format!(
                        "{file}: {name} reaches {pmax:.1} kPa, above the supply {supply_kpa:.1} kPa \
                         (+{SUPPLY_MARGIN_KPA} kPa), a pressure the controller's activation p0 -+ dp \
                         never sets: a wrong unit, a plant file of another supply, a broken \
                         sensor, or a muscle compressed with its valves closed (a run driven by \
                         valve pulses, not an activation sweep: `host-sim sweep torque` records one)"
                    ));
                }
            }
            None => why.push(format!("{file}: no {name} column")),
        }
    }
    if let (Some(p1), Some(p2)) = (p1, p2) {
        // Eq. 11's activation p1 = p0 - dp, p2 = p0 + dp: dp can reach supply / 2 at most.
        let dp_max = p1
            .iter()
            .zip(p2)
            .map(|(a, b)| 0.5 * (b - a).abs())
            .fold(0.0, f64::max);
        if !(dp_max <= 0.5 * supply_kpa + SUPPLY_MARGIN_KPA) {
            why.push(format!(
                "{file}: the activation dp = (p2 - p1) / 2 reaches {dp_max:.1} kPa, above half the \
                 supply ({:.1} kPa): no p0 can give it",
                0.5 * supply_kpa
            ));
        }
    }
    why
}

/// `key = number` pairs of every table of a TOML text (arrays flattened as `key[i]`).
fn numbers(text: &str) -> Vec<(String, f64)> {
    let Ok(t) = text.parse::<toml::Table>() else {
        return Vec::new();
    };
    let mut out = Vec::new();
    fn walk(prefix: &str, v: &toml::Value, out: &mut Vec<(String, f64)>) {
        match v {
            toml::Value::Float(x) => out.push((prefix.to_string(), *x)),
            toml::Value::Integer(i) => out.push((prefix.to_string(), *i as f64)),
            toml::Value::Array(a) => {
                for (i, x) in a.iter().enumerate() {
                    walk(&format!("{prefix}[{i}]"), x, out);
                }
            }
            toml::Value::Table(t) => {
                for (k, x) in t {
                    let p = if prefix.is_empty() {
                        k.clone()
                    } else {
                        format!("{prefix}.{k}")
                    };
                    walk(&p, x, out);
                }
            }
            _ => {}
        }
    }
    walk("", &toml::Value::Table(t), &mut out);
    out
}

/// What changed from the file at `old` (if any) to `new_text`, one line per key.
fn changes(old: &Path, new_text: &str) -> String {
    let before = std::fs::read_to_string(old)
        .map(|t| numbers(&t))
        .unwrap_or_default();
    let mut s = String::new();
    for (k, v) in numbers(new_text) {
        match before.iter().find(|(kb, _)| *kb == k) {
            Some((_, b)) if *b == v => {
                s += &format!("  {k} = {v:e} (unchanged)\n");
            }
            Some((_, b)) => s += &format!("  {k}: {b:e} -> {v:e}\n"),
            None => s += &format!("  {k} = {v:e} (new)\n"),
        }
    }
    for (k, b) in &before {
        if !s.contains(&format!("  {k} ")) && !s.contains(&format!("  {k}:")) {
            s += &format!("  {k} = {b:e} (removed)\n");
        }
    }
    s
}

/// `config/joint_geometry.toml` from the plant file.
fn geometry_toml(plant: &Plant, plant_path: &Path) -> String {
    format!(
        "# Geometry of the antagonistic joint the firmware's torque estimate uses (src/geometry.rs,\n\
         # PLANT.md convention: chi1 = chi0 + (r / l_n) beta, chi2 = chi0 - (r / l_n) beta, L/L0 = 1 - chi).\n\
         # SI units. Written by `host-sim calibrate` from {} ([joint] sprocket_radius_m,\n\
         # initial_contraction; [muscle] rest_length_m). build.rs turns it into\n\
         # `pam_firmware::constants::JOINT_GEOMETRY` (= JointGeometry::REFERENCE) and checks that\n\
         # sprocket_radius_m agrees with config/torque_model.toml.\n\n\
         [joint_geometry]\n\
         sprocket_radius_m = {:?}\n\
         rest_length_m = {:?}\n\
         initial_contraction = {:?}\n",
        plant_path.display(),
        plant.joint.sprocket_radius_m,
        plant.muscle.rest_length_m,
        plant.joint.initial_contraction,
    )
}

/// `config/plant_constants.toml` from the plant file; the muscle's pressure rating (not in a
/// plant file) is kept from `old` (600 kPa, FESTO DMSP, if there is none).
fn plant_constants_toml(plant: &Plant, plant_path: &Path, old: &Path) -> String {
    let p_max = std::fs::read_to_string(old)
        .ok()
        .and_then(|t| {
            numbers(&t)
                .into_iter()
                .find(|(k, _)| k == "muscle.p_max_gauge_pa")
        })
        .map(|(_, v)| v)
        .unwrap_or(600_000.0);
    let v = plant.muscle.volume_poly_m3;
    format!(
        "# Plant-derived constants of the firmware: what the firmware knows of the joint beyond the force\n\
         # law (config/force_law.toml), the torque model (config/torque_model.toml) and the geometry\n\
         # (config/joint_geometry.toml). SI units. build.rs turns them into\n\
         # `pam_firmware::constants::{{JOINT_INERTIA_KGM2, P_MUSCLE_MAX_GAUGE_PA, ...}}`:\n\
         #   inertia_kgm2            -> the inertia torque J r'' of the cascade's trajectory feed-forward\n\
         #   p_max_gauge_pa          -> the ceiling of every muscle pressure set-point (the muscle's rating,\n\
         #                              kept from the previous file: a plant file does not state it)\n\
         #   environment, valve, volume_poly_m3 -> the valve / supply residual (src/residual.rs)\n\
         #\n\
         # Written by `host-sim calibrate` from {} ([environment], [muscle] volume_poly_m3,\n\
         # [joint] inertia_kgm2, [valve] sonic_conductance_m3_per_s_pa, critical_ratio).\n\n\
         [joint]\n\
         inertia_kgm2 = {:?}\n\n\
         [muscle]\n\
         p_max_gauge_pa = {:?}\n\
         volume_poly_m3 = [{:e}, {:e}, {:e}, {:e}]\n\n\
         [environment]\n\
         p_atm_pa = {:?}\n\
         supply_gauge_pa = {:?}\n\n\
         [valve]\n\
         sonic_conductance_m3_per_s_pa = {:e}\n\
         critical_ratio = {:?}\n",
        plant_path.display(),
        plant.joint.inertia_kgm2,
        p_max,
        v[0],
        v[1],
        v[2],
        v[3],
        plant.p_atm_pa,
        plant.p_supply_abs_pa - plant.p_atm_pa,
        plant.valve.sonic_conductance_m3_per_s_pa,
        plant.valve.critical_ratio,
    )
}

/// Runs `host-sim calibrate`; returns the report for stdout. Fails (nothing written) on
/// degenerate data or a poor torque fit. Stages: the outputs checked, 0. the plant-file keys
/// identified (optional), the recording checked, 1. the torque model, 2. the plant-derived
/// constants, 3. the gains (optional); then every file replaced.
pub fn run_calibrate(a: &CalibrateArgs) -> Result<String> {
    let dest = |name: &str| a.out_dir.join(name);
    check_calibrate_outputs(a)?;
    let mut out = String::new();
    let identified = identify_plant_stage(a, &mut out)?;
    let final_plant = dest("plant_identified.toml");
    // The plant file of the later stages, and the name their provenance headers give it.
    let (plant_path, plant_name) = match &identified {
        Some((tmp, _)) => (tmp.path().to_owned(), final_plant.clone()),
        None => (a.plant.clone(), a.plant.clone()),
    };
    let plant = Plant::load(&plant_path)?;
    let rec = Recording::read(&a.recording)?;
    // A recording made on another plant file than the one given: the geometry, supply and
    // valve constants written below are the given file's, so say so first.
    if let Some(w) = crate::io::recording::other_plant_warning(
        &rec.metadata,
        &a.plant,
        &a.recording,
        "calibrating with the geometry, supply and valve of",
    ) {
        eprintln!("{w}");
    }
    let why = degenerate_reasons(&rec, &plant, &a.recording.display().to_string());
    if !why.is_empty() {
        bail!(
            "refusing to write firmware constants (nothing written):\n  {}",
            why.join("\n  ")
        );
    }
    // Stage 1: the torque model.
    let torque_toml = torque_stage(a, &plant_path, &plant_name, &mut out)?;
    // Stage 2: the plant-derived constants.
    let files = [
        ("torque_model.toml", torque_toml),
        ("joint_geometry.toml", geometry_toml(&plant, &plant_name)),
        (
            "plant_constants.toml",
            plant_constants_toml(&plant, &plant_name, &dest("plant_constants.toml")),
        ),
    ];
    for (name, text) in &files {
        out += &format!("{}:\n{}", dest(name).display(), changes(&dest(name), text));
    }
    // Stage 3: the gains (optional, minutes). Written (staged) by the tuner itself.
    if a.tune {
        out += &tune_stage(a, &plant_path)?;
    }
    // Every stage passed: replace the files (staged in the command's transaction: all or none).
    for (name, text) in &files {
        write_atomic(&dest(name), text.as_bytes())?;
    }
    if let Some((_, body)) = &identified {
        write_atomic(&final_plant, body.as_bytes())?;
    }
    out += &format!(
        "wrote {} files in {}; rebuild the firmware (`cargo flash-build` / `cargo flash`) to use them\n",
        files.len() + usize::from(a.tune) + usize::from(identified.is_some()),
        a.out_dir.display()
    );
    Ok(out)
}

/// The files calibrate writes: `--out-dir` is a directory, no file it replaces is one it
/// reads (e.g. --plant config/plant_constants.toml), and every file it replaces parses (its
/// values are what the report compares with, and the muscle's pressure rating is kept from
/// plant_constants.toml: a file that does not parse would silently reset the rating to
/// 600 kPa).
fn check_calibrate_outputs(a: &CalibrateArgs) -> Result<()> {
    if !a.out_dir.is_dir() {
        bail!(
            "--out-dir {}: does not exist or is not a directory (the firmware's config/ directory)",
            a.out_dir.display()
        );
    }
    let mut inputs = vec![
        ("--recording", a.recording.as_path()),
        ("--plant", a.plant.as_path()),
    ];
    if let Some(r) = &a.plant_recording {
        inputs.push(("--plant-recording", r.as_path()));
    }
    let written: Vec<PathBuf> = [
        ("plant_identified.toml", !a.identify_plant.is_empty()),
        ("torque_model.toml", true),
        ("joint_geometry.toml", true),
        ("plant_constants.toml", true),
        ("control_tuned.toml", a.tune),
    ]
    .iter()
    .filter(|(_, on)| *on)
    .map(|(n, _)| a.out_dir.join(n))
    .collect();
    let outputs: Vec<(&str, &Path)> = written.iter().map(|p| ("--out-dir", p.as_path())).collect();
    crate::validate::distinct_outputs(&inputs, &outputs).map_err(anyhow::Error::msg)?;
    for p in &written {
        if let Ok(text) = std::fs::read_to_string(p) {
            if let Err(e) = text.parse::<toml::Table>() {
                let at = e
                    .span()
                    .map(|s| format!(":{}", text[..s.start].matches('\n').count() + 1))
                    .unwrap_or_default();
                bail!(
                    "{}{at}: the file calibrate would replace does not parse ({}); nothing \
                     written: fix or remove it first (calibrate keeps the muscle's pressure \
                     rating muscle.p_max_gauge_pa from plant_constants.toml and reports every \
                     change against these files)",
                    p.display(),
                    e.message()
                );
            }
        }
    }
    Ok(())
}

/// Stage 0 (with `--identify-plant`): identifies plant-file keys from the valve recording;
/// refused under [`MIN_IDENTIFIED_HELDOUT_FIT_PCT`]. The identified file is staged in a
/// temporary file beside the config for the later stages (returned with its text), and
/// written at the end.
fn identify_plant_stage(
    a: &CalibrateArgs,
    out: &mut String,
) -> Result<Option<(tempfile::NamedTempFile, String)>> {
    if a.identify_plant.is_empty() {
        return Ok(None);
    }
    let valve_rec = a.plant_recording.as_ref().unwrap_or(&a.recording);
    let (fit, body) = crate::identify::plant::identify_plant_text(
        valve_rec,
        &a.plant,
        &a.identify_plant,
        &crate::identify::plant::PlantFitOptions::default(),
    )
    .map_err(|e| {
        anyhow::anyhow!("refusing to write firmware constants (nothing written): {e:#}")
    })?;
    let (hb, ha) = fit.holdout_mean_pct();
    if !(ha >= MIN_IDENTIFIED_HELDOUT_FIT_PCT) {
        bail!(
            "refusing to write firmware constants (nothing written): the identified plant \
             does not describe {} (held-out fit {hb:.1} % -> {ha:.1} %, at least \
             {MIN_IDENTIFIED_HELDOUT_FIT_PCT} % needed): the recording does not excite \
             these keys, it is not a valve-driven recording, or another part of the plant \
             file is wrong",
            valve_rec.display()
        );
    }
    *out += &format!(
        "plant identified from {} (held-out fit {hb:.3} % -> {ha:.3} %):\n",
        valve_rec.display()
    );
    for (k, old, new) in &fit.params {
        *out += &format!("  {k}: {old:e} -> {new:e}\n");
    }
    let tmp = tempfile::Builder::new()
        .prefix(".plant_identified.")
        .suffix(".toml")
        .tempfile_in(&a.out_dir)
        .with_context(|| format!("--out-dir {}", a.out_dir.display()))?;
    std::fs::write(tmp.path(), &body).with_context(|| format!("{}", tmp.path().display()))?;
    Ok(Some((tmp, body)))
}

/// Stage 1: the torque model of the recording on the plant at `plant_path` (named
/// `plant_name` in its provenance), refused under [`MIN_TORQUE_FIT_PCT`]; its file's text.
fn torque_stage(
    a: &CalibrateArgs,
    plant_path: &Path,
    plant_name: &Path,
    out: &mut String,
) -> Result<String> {
    let mut torque = torque_model_file(&IdentifyTorqueArgs {
        recording: a.recording.clone(),
        plant: plant_path.to_path_buf(),
        out: a.out_dir.join("torque_model.toml"),
        savgol_half_window: None,
        dp_max_kpa: None,
        max_accel_rad_s2: None,
        allow_poor_fit: false,
    })
    .map_err(|e| {
        anyhow::anyhow!("refusing to write firmware constants (nothing written): {e:#}")
    })?;
    if !(torque.fit_pct >= MIN_TORQUE_FIT_PCT) {
        bail!(
            "refusing to write firmware constants (nothing written): the torque model fits the \
             data {:.2} %, below {MIN_TORQUE_FIT_PCT} % (noise, or a joint eq. 11 does not describe)",
            torque.fit_pct
        );
    }
    torque.toml = torque.toml.replace(
        &plant_path.display().to_string(),
        &plant_name.display().to_string(),
    );
    *out += &format!(
        "torque model: fit {:.3} % (>= {MIN_TORQUE_FIT_PCT} %)\n",
        torque.fit_pct
    );
    Ok(torque.toml)
}

/// Stage 3 (`--tune`): the gains tuned on the plant at `plant_path` and written by the tuner
/// itself; its report and the changes to control_tuned.toml.
fn tune_stage(a: &CalibrateArgs, plant_path: &Path) -> Result<String> {
    let control = a.out_dir.join("control_tuned.toml");
    let (r, text) = crate::control::tune::run_tune_text(&crate::control::tune::TuneArgs {
        plant: plant_path.to_path_buf(),
        out: control.clone(),
        threads: a.threads,
        warm_start: false,
        setpoint_cutoff_hz: 150.0,
        transition_s: None,
        cascade_start: Vec::new(),
        no_step_constraints: false,
        robust: false,
        pressure_ff: false,
        stable_on_jumps: false,
        outer_period_ticks: None,
        ff_update_ticks: None,
    })
    .context("tuning the gains")?;
    Ok(format!(
        "{r}{}:\n{}",
        control.display(),
        changes(&control, &text)
    ))
}
