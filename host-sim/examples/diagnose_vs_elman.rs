//! Diagnosis vs the black-box residual model of seeds 000/004 (an Elman network on the
//! residual, `host_sim::diagnose::baseline`), trained on the same TRAIN recording (valve
//! pulses) and judged on a CHECK recording with unlike excitation (chirp + steps of
//! PWM-like duties). Prints a Markdown table of check-recording fits (README "Diagnosis vs
//! Elman"):
//!
//! `cargo run --release -p host-sim --example diagnose_vs_elman`

use std::path::PathBuf;

use host_sim::diagnose::baseline::{train, ElmanOptions};
use host_sim::diagnose::synth::{generate, plant_with, Excitation, SynthSpec};
use host_sim::diagnose::{diagnose, DiagnoseOptions};
use host_sim::fit::fit_percent;
use host_sim::sim::{simulate, SolverOptions};
use host_sim::{Channel, Plant, PlantConfig, Recording};

fn nominal_channels(cfg: &PlantConfig, rec: &Recording) -> Vec<host_sim::Measurement> {
    let plant = Plant::from_config(cfg);
    let dt = rec.sample_period_s();
    let sim = simulate(&plant, &rec.inputs, dt, &SolverOptions::default()).unwrap();
    plant.measure_series(&sim.states, dt)
}

/// (angle fit, lowest fit over the channels) of `pred` on `rec`.
fn fits(rec: &Recording, pred: &[Option<Vec<f64>>; 5]) -> (f64, f64) {
    let mut min = f64::INFINITY;
    let mut angle = f64::NAN;
    for c in Channel::ALL {
        if let (Some(y), Some(p)) = (rec.channel(c), &pred[c.index()]) {
            let f = fit_percent(y, p);
            min = min.min(f);
            if c == Channel::AngleDeg {
                angle = f;
            }
        }
    }
    (angle, min)
}

fn columns(m: &[host_sim::Measurement]) -> [Option<Vec<f64>>; 5] {
    std::array::from_fn(|i| Some(m.iter().map(|x| x.to_array()[i]).collect()))
}

fn main() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("plants/reference-1dof.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let nominal = PlantConfig::load(&path).unwrap();
    let cases: [&[&str]; 6] = [
        &["joint_friction"],
        &["muscle_hysteresis"],
        &["leakage"],
        &["polytropic"],
        &["gravity"],
        &["joint_friction", "leakage"],
    ];
    println!("| concealed | check angle fit %: nominal / Elman / diagnosed | check lowest channel fit %: nominal / Elman / diagnosed | named |");
    println!("|---|---|---|---|");
    for (i, truths) in cases.iter().enumerate() {
        let dt = 1e-3;
        let cfg = plant_with(&text, truths, dt).unwrap();
        let label = truths.join("+");
        let spec = |excitation, duration_s, seed| SynthSpec {
            excitation,
            duration_s,
            dt_s: dt,
            seed,
            noise: true,
            channels: [true; 5],
        };
        let tr = generate(
            &cfg,
            &spec(Excitation::Pulses, 10.0, 500 + i as u64),
            &label,
        )
        .unwrap();
        let ck = generate(
            &cfg,
            &spec(Excitation::ChirpSteps, 8.0, 600 + i as u64),
            &label,
        )
        .unwrap();
        let nom_tr = nominal_channels(&nominal, &tr);
        let nom_ck = nominal_channels(&nominal, &ck);
        let elman = train(&tr.inputs, &nom_tr, &tr.outputs, &ElmanOptions::default()).unwrap();
        let el_ck = elman.predict(&ck.inputs, &nom_ck).unwrap();
        let d = diagnose(
            &nominal,
            &tr,
            Some(&ck),
            &DiagnoseOptions::default(),
            &|_, _, _| {},
        )
        .unwrap();
        let dg_ck = columns(&d.check.as_ref().unwrap().corrected);
        let (na, nm) = fits(&ck, &columns(&nom_ck));
        let (ea, em) = fits(&ck, &el_ck);
        let (da, dm) = fits(&ck, &dg_ck);
        let named: Vec<&str> = d.effects.iter().map(|e| e.id.as_str()).collect();
        println!(
            "| {label} | {na:.1} / {ea:.1} / {da:.1} | {nm:.1} / {em:.1} / {dm:.1} | {} |",
            named.join("+")
        );
    }
}
