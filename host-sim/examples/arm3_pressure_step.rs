//! The 3-DOF arm of seed 001 on its pressure-step excitation (seed 001 section 4: all muscles
//! at 550 kPa, muscle 1 and then muscle 2 of every joint deflated by 350 / 250 / 450 kPa for
//! joints 1 / 2 / 3), pressure-regulated valves, all joints at once. Writes the 3-joint
//! recording (replayable with `host-sim simulate --plant ... --inputs`) and a plot.
//!
//! cargo run --release -p host-sim --example arm3_pressure_step -- [PLANT.toml] [OUT_DIR]

use std::path::PathBuf;

use anyhow::Result;
use host_sim::io::arm3::{plot_arm3, PressureStepScenario, JOINTS};
use host_sim::plant::arm3::Arm3;
use host_sim::sim::SolverOptions;

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let plant = args.next().map(PathBuf::from).unwrap_or_else(|| {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("plants/arm3-seed001.toml")
    });
    let out_dir = args
        .next()
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("target/arm3"));
    std::fs::create_dir_all(&out_dir)?;
    let arm = Arm3::load(&plant)?;
    let sc = PressureStepScenario::seed001();
    let t0 = std::time::Instant::now();
    let (mut rec, states) = sc.run(&arm, &SolverOptions::default(), |_| {})?;
    let wall_s = t0.elapsed().as_secs_f64();
    rec.metadata
        .insert(0, ("plant".into(), plant.display().to_string()));
    let csv = out_dir.join("pressure_step.csv");
    let png = out_dir.join("pressure_step.png");
    rec.write(&csv)?;
    plot_arm3(&png, None, &rec)?;

    println!("plant {}", plant.display());
    println!(
        "initial (static equilibrium at 550/550 kPa): q = [{:.3}, {:.3}, {:.3}] deg",
        arm.initial.angles_rad[0].to_degrees(),
        arm.initial.angles_rad[1].to_degrees(),
        arm.initial.angles_rad[2].to_degrees()
    );
    // Angle at the end of each plateau, relative to the start.
    let at = |t: f64| &states[((t / sc.dt_s).round() as usize).min(states.len() - 1) - 1];
    let [_, t2, _, t4] = sc.switch_times_s;
    println!("joint  deflation_kpa  dq_muscle1_deflated_deg  dq_muscle2_deflated_deg");
    for j in 0..JOINTS {
        let q0 = arm.initial.angles_rad[j];
        println!(
            "j{}     {:>6.0}         {:>+10.3}               {:>+10.3}",
            j + 1,
            sc.deflation_kpa[j],
            (at(t2).angles_rad[j] - q0).to_degrees(),
            (at(t4).angles_rad[j] - q0).to_degrees()
        );
    }
    println!(
        "{:.1} s simulated in {:.3} s wall ({:.0}x real time); wrote {} and {}",
        sc.duration_s,
        wall_s,
        sc.duration_s / wall_s,
        csv.display(),
        png.display()
    );
    Ok(())
}
