//! Writes `tests/traces/arm3_sensor_trace.csv`: the raw sensor trace of the 3-DOF arm that the QEMU
//! benchmark image feeds to the firmware's arm tick (`scripts/bench-mcu.sh`, row "arm tick").
//!
//! The trace is a closed-loop run of `scenarios/arm3/step.toml` (the firmware's `ArmTick` on
//! `host-sim/plants/arm3-seed001.toml`), ticks 3 500 to 4 999: the start phase is over and
//! all three joints step at 4 s. Each joint's true angle and pressures are converted to the
//! raw counts of `src/wiring.rs` (12-bit ADC, 455 counts = 0 Pa, 4095 = 1 MPa; x4 encoder of
//! 8000 counts per turn). Replayed open loop, the trace does not react to the commands.
//!
//! `cargo run --release -p host-sim --example gen_arm3_trace` (re-run only to change the
//! scenario; the CSV in the repository is the source of truth).
use std::fmt::Write as _;

use host_sim::control::arm3_loop::{run_arm, ArmScenario};
use host_sim::plant::arm3::Arm3;
use pam_firmware::arm::ArmConfig;
use pam_firmware::wiring::{
    ENCODER_COUNTS_PER_REV, PRESSURE_COUNTS_AT_FULL, PRESSURE_COUNTS_AT_ZERO,
    PRESSURE_FULL_SCALE_PA,
};

const FIRST_TICK: usize = 3_500;
const TICKS: usize = 1_500;

fn main() -> anyhow::Result<()> {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let arm = Arm3::load(root.join("host-sim/plants/arm3-seed001.toml"))?;
    let scenario = ArmScenario::load(root.join("scenarios/arm3/step.toml"))?;
    let run = run_arm(
        &arm,
        &scenario,
        ArmConfig::reference(scenario.scenario.tick_hz as f32),
    )?;
    anyhow::ensure!(run.first_fault().is_none(), "the step run faulted");
    let pa_per_count =
        PRESSURE_FULL_SCALE_PA as f64 / (PRESSURE_COUNTS_AT_FULL - PRESSURE_COUNTS_AT_ZERO) as f64;
    let adc = |p_gauge_pa: f64| {
        ((p_gauge_pa / pa_per_count).round() as i64 + PRESSURE_COUNTS_AT_ZERO as i64).clamp(0, 4095)
    };
    let encoder = |angle_rad: f64| {
        (angle_rad / std::f64::consts::TAU * ENCODER_COUNTS_PER_REV as f64).round() as i64
    };
    let mut csv = String::from(
        "# Raw sensor trace of the 3-DOF arm for the QEMU arm-tick benchmark\n\
         # (host-sim/examples/gen_arm3_trace.rs: scenarios/arm3/step.toml, ticks 3500-4999).\n\
         # tick_hz = 1000; counts per src/wiring.rs.\n\
         tick",
    );
    for j in 1..=3 {
        write!(
            csv,
            ",angle_set_mrad_j{j},p1_adc_counts_j{j},p2_adc_counts_j{j},encoder_counts_j{j}"
        )?;
    }
    csv.push('\n');
    for (k, row) in run.rows[FIRST_TICK..FIRST_TICK + TICKS].iter().enumerate() {
        write!(csv, "{k}")?;
        for j in 0..3 {
            let [p1, p2] = row.state.p_abs_pa[j].map(|p| p - run.p_atm_pa);
            write!(
                csv,
                ",{},{},{},{}",
                (row.setpoint_rad[j] * 1000.0).round() as i64,
                adc(p1),
                adc(p2),
                encoder(row.state.angles_rad[j])
            )?;
        }
        csv.push('\n');
    }
    let out = root.join("tests/traces/arm3_sensor_trace.csv");
    host_sim::io::atomic::write_bytes(&out, csv.as_bytes())?;
    println!("{}: {TICKS} ticks", out.display());
    Ok(())
}
