//! The stored gains (no re-tuning) off the tuning suite: held-out set-point sequences and
//! plants with concealed effects (`control::robustness`). The full table is printed
//! (`cargo run -p host-sim --example robustness` prints the same); what holds is asserted,
//! and docs/identification.md says plainly what does not (the cascade's lead over the PID on
//! the held-out suite is 1.27x, not 2x; on the 11 x load the suite-tuned cascade and PD leave
//! the 0.5 rad band).

use host_sim::control::compare::{control_tuned_path, suite_scenarios, ControlTuning};
use host_sim::control::robustness::{
    format_table, held_out_scenarios, table, Row, CONDITIONS, SUPERVISION_OFF_DEAD_TIME,
    TUNING_HOLD_SD_MAX_RAD,
};
use std::ops::RangeBounds;

/// The reference plant file's text.
fn reference_text() -> String {
    let plant =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/reference-1dof.toml");
    std::fs::read_to_string(plant).unwrap()
}

/// The gains of `host-sim tune --robust` (config/control_robust.toml).
fn robust_gains() -> ControlTuning {
    ControlTuning::load(&control_tuned_path().with_file_name("control_robust.toml")).unwrap()
}

/// The cascade's lead over the PID (PID MSE / cascade MSE) on row `r` lies in `lead`.
fn assert_lead_over_pid(r: &Row, lead: impl RangeBounds<f64> + std::fmt::Debug) {
    assert!(
        lead.contains(&r.lead_over_pid()),
        "{}: lead {:.2} not in {lead:?}",
        r.condition,
        r.lead_over_pid()
    );
}

#[test]
fn stored_gains_on_held_out_sequences_and_concealed_effects() {
    let text = reference_text();
    let tuning = ControlTuning::load(&control_tuned_path()).unwrap();
    let rows = table(&text, &tuning, &held_out_scenarios().unwrap(), &[]);
    println!("{}", format_table(&rows));
    assert_eq!(rows.len(), CONDITIONS.len());
    // The valve supervision tolerates the 8 ms valve dead time (no false alarm): the row
    // with it on is the row with it off, run for run.
    let dead_time = |name: &str| {
        rows.iter()
            .find(|r| r.condition == name)
            .unwrap_or_else(|| panic!("a row {name}"))
    };
    let (on, off) = (
        dead_time("valve dead time 8 ms"),
        dead_time(SUPERVISION_OFF_DEAD_TIME),
    );
    for (a, b) in on.cells.iter().zip(&off.cells) {
        assert_eq!(a.mse_rad2, b.mse_rad2);
        // Tuned without a robustness term, every law swings at rest with the dead time.
        assert!(!a.stable && a.max_abs_rad < 0.5, "{a:?}");
    }
    // Every law stays stable on the held-out sequences under every other effect but the
    // 11 x load.
    for r in rows
        .iter()
        .filter(|r| !r.condition.starts_with("11 x") && !r.condition.starts_with("valve dead time"))
    {
        for c in &r.cells {
            assert!(c.stable, "{}: {c:?}", r.condition);
        }
        // The model-based cascade keeps its lead over the PD everywhere.
        assert!(
            r.cells[1].mse_rad2 >= 2.0 * r.cells[0].mse_rad2,
            "{}: cascade {:.3e} vs PD {:.3e}",
            r.condition,
            r.cells[0].mse_rad2,
            r.cells[1].mse_rad2
        );
        // ... and is never worse than the PID on the held-out sequences.
        assert_lead_over_pid(r, 1.0..);
    }
}

/// The gains of `host-sim tune --robust` (config/control_robust.toml: every law tuned on the
/// tuning suite for the worst of the nominal plant and the 8 ms valve dead time, stable with a
/// margin on the 11 x load), scored on the held-out sequences: every law is stable on every
/// plant (no fault, bounded, no limit cycle at rest); the cascade keeps a 2x lead over the PID
/// on the nominal plant and under every effect but the 11 x load, where the PID, tuned to stay
/// at rest there, is as good as the cascade (stated, so a change shows).
#[test]
fn robust_gains_hold_the_lead_on_held_out_sequences() {
    let text = reference_text();
    let tuning = robust_gains();
    let rows = table(&text, &tuning, &held_out_scenarios().unwrap(), &[]);
    println!("{}", format_table(&rows));
    for r in &rows {
        for (law, c) in ["cascade", "PD", "PID"].iter().zip(&r.cells) {
            assert!(c.stable, "{}: {law} {c:?}", r.condition);
        }
        if r.condition.starts_with("11 x") {
            assert_lead_over_pid(r, 0.5..2.0);
        } else {
            assert_lead_over_pid(r, 2.0..);
        }
    }
}

/// The stability criterion sees a limit cycle that stays inside the 0.5 rad band: the PID of
/// an earlier `tune --robust` (stable on the 11 x load by the band alone) swings at rest on
/// the 11 x load's step with a spread of 0.1 rad or more; the stored robust PID comes to rest.
#[test]
fn a_limit_cycle_inside_the_band_is_unstable() {
    let text = reference_text();
    let stored = robust_gains();
    let mut earlier = stored;
    earlier.pid.kp_pa_per_rad = 163199.796875;
    earlier.pid.ki_pa_per_rad_s = 2837019.75;
    earlier.pid.kd_pa_s_per_rad = 10305.80078125;
    let loaded = CONDITIONS
        .iter()
        .position(|c| c.0.starts_with("11 x"))
        .unwrap();
    let suite = suite_scenarios().unwrap();
    let pid = |t: &ControlTuning| table(&text, t, &suite, &[loaded])[0].cells[2].clone();
    let (was, now) = (pid(&earlier), pid(&stored));
    assert!(was.max_abs_rad < 0.5, "{was:?}");
    assert!(was.hold_sd_rad >= 0.1 && !was.stable, "{was:?}");
    assert!(
        now.hold_sd_rad <= TUNING_HOLD_SD_MAX_RAD && now.stable,
        "{now:?}"
    );
}
