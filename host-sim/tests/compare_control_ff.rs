//! `host-sim compare-control`: the pressure loop with and without the firmware's inverse
//! thermodynamic feed-forward. The CI run is `--quick` (nominal plant, first scenario of the
//! suite and of the held-out set); the full run is documented in docs/control.md.

mod common;

use common::*;

/// The verdict line's ratio.
fn ratio(stdout: &str) -> f64 {
    let line = stdout
        .lines()
        .find(|l| l.starts_with("verdict (exit status), nominal plant, suite"))
        .unwrap_or_else(|| panic!("no verdict line in\n{stdout}"));
    let after = line.rsplit(" = ").next().unwrap();
    after
        .split_whitespace()
        .next()
        .unwrap()
        .trim_end_matches('x')
        .parse()
        .unwrap()
}

/// The position MSE column of the row starting with `controller` on `set` in the nominal
/// plant's comparison table.
fn mse(stdout: &str, controller: &str, set: &str) -> f64 {
    let row = stdout
        .lines()
        .skip_while(|l| !l.starts_with("### nominal"))
        .find(|l| l.starts_with(&format!("| {controller}")) && l.contains(&format!("| {set} |")))
        .unwrap_or_else(|| panic!("no row {controller} / {set} in\n{stdout}"));
    row.split('|').nth(3).unwrap().trim().parse().unwrap()
}

#[test]
fn compare_control_prints_the_tables_and_exits_by_its_verdict() {
    let r = on_plant("compare-control", &plant(), &[&"--quick", &"--breakdown"]);
    let out = text(&r.stdout);
    let code = r.status.code();
    assert!(
        code == Some(0) || code == Some(1),
        "status {code:?}\n{out}\n{}",
        text(&r.stderr)
    );
    let q = ratio(&out);
    assert_eq!(
        code == Some(0),
        q >= 1.85,
        "verdict and status disagree: {q}\n{out}"
    );
    // The hybrid row (its volume trained on the plant's own training run) is there and runs
    // its own volume: on one of the two sets at least it differs from the analytical row.
    assert!(
        out.contains("hybrid volume training run: mass-flow MSE"),
        "{out}"
    );
    let hybrid = ["suite", "held-out moves", "jumps"]
        .map(|set| mse(&out, "+ hybrid model (learned volume), k = 1", set));
    let analytical = ["suite", "held-out moves", "jumps"]
        .map(|set| mse(&out, "+ analytical inverse model, k = 1 (isothermal)", set));
    assert!(hybrid.iter().all(|m| m.is_finite()), "{out}");
    assert!(hybrid != analytical, "{out}");
    for set in ["suite", "held-out moves", "jumps"] {
        let p_only = mse(&out, "P only", set);
        let am = mse(&out, "+ analytical inverse model, k = 1 (isothermal)", set);
        let poly = mse(
            &out,
            "+ analytical inverse model, k = 1.4 (polytropic)",
            set,
        );
        assert!(
            p_only.is_finite() && am.is_finite() && poly.is_finite(),
            "{out}"
        );
        // The feed-forward reaches the valves: the runs differ.
        assert!(
            p_only != am && am != poly,
            "{set}: {p_only} {am} {poly}\n{out}"
        );
    }
    // The verdict is the table's ratio of the cascades each at its own gains (the P-only
    // cascade of config/control_tuned.toml, the re-tuned one of config/control_tuned_ff.toml);
    // the same-gains ratio is printed on its own line.
    assert!(
        out.contains("(the cascade tuned with the pressure feed-forward on, with the options"),
        "{out}"
    );
    assert!(out.contains("suite (--quick: step_move only)"), "{out}");
    let table = mse(&out, "P only", "suite")
        / mse(&out, host_sim::control::compare_ff::RETUNED_ROW, "suite");
    assert!((table / q - 1.0).abs() < 0.01, "{table} vs {q}");
    let same = out
        .lines()
        .find(|l| l.starts_with("for comparison, same gains, nominal plant, suite"))
        .unwrap_or_else(|| panic!("no same-gains line\n{out}"));
    let same: f64 = same
        .rsplit(" = ")
        .next()
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.trim_end_matches('x').parse().ok())
        .unwrap_or_else(|| panic!("{same}"));
    let same_table = mse(&out, "P only", "suite")
        / mse(
            &out,
            "+ analytical inverse model, k = 1 (isothermal)",
            "suite",
        );
    assert!(
        (same_table / same - 1.0).abs() < 0.01,
        "{same_table} vs {same}"
    );
    // The breakdown's P-only position MSE (its own pass over the run's ticks) is the table's
    // on the one scenario of each set; its shares are percentages.
    for set in ["suite", "held-out moves", "jumps"] {
        let row = out
            .lines()
            .skip_while(|l| !l.starts_with("### Where the position error comes from"))
            .find(|l| l.starts_with("| P only |") && l.contains(&format!("| {set} |")))
            .unwrap_or_else(|| panic!("no breakdown row for {set}\n{out}"));
        let cols: Vec<&str> = row.split('|').map(str::trim).collect();
        let b: f64 = cols[3].parse().unwrap();
        let t = mse(&out, "P only", set);
        assert!(
            (b / t - 1.0).abs() < 2e-3,
            "{set}: breakdown {b} vs table {t}"
        );
        for c in [4, 9, 10] {
            let pct: f64 = cols[c].trim_end_matches(" %").parse().unwrap();
            assert!((0.0..=100.0).contains(&pct), "{row}");
        }
    }
    // The per-scenario table (one scenario per set here) repeats the set's rows.
    for set in ["suite", "held-out moves", "jumps"] {
        let row = out
            .lines()
            .skip_while(|l| !l.starts_with("per scenario"))
            .find(|l| l.starts_with(&format!("| {set} |")))
            .unwrap_or_else(|| panic!("no per-scenario row for {set}\n{out}"));
        let cols: Vec<&str> = row.split('|').map(str::trim).collect();
        for (col, controller) in [
            (3, "P only"),
            (4, "+ analytical inverse model, k = 1 (isothermal)"),
            (6, host_sim::control::compare_ff::RETUNED_ROW),
        ] {
            let v: f64 = cols[col].parse().unwrap();
            assert_eq!(v, mse(&out, controller, set), "{set} {controller}: {row}");
        }
    }
}

/// The shipped gains file `config/<shipped>` copied to `dir/<name>` with `line` added at the
/// top of its `[cascade]` table.
fn shipped_gains_with(
    dir: &std::path::Path,
    shipped: &str,
    name: &str,
    line: &str,
) -> std::path::PathBuf {
    let text = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../config")
            .join(shipped),
    )
    .unwrap();
    assert!(text.contains("\n[cascade]\n"));
    let path = dir.join(name);
    std::fs::write(
        &path,
        text.replacen("\n[cascade]\n", &format!("\n[cascade]\n{line}\n"), 1),
    )
    .unwrap();
    path
}

/// The feed-forward within the MCU budget: the outer loops on every second tick and the
/// feed-forward evaluated on every second tick (`bash scripts/bench-mcu.sh`, "ff split
/// tick"), both as the gains files record them. Every row runs at those rates, and the
/// verdict still holds.
#[test]
fn compare_control_at_half_rate_outer_loops_keeps_the_verdict() {
    // The P-only gains file records the rate it was tuned at (as `tune --outer-period-ticks 2`
    // writes it): with no --outer-period-ticks, every row runs at that rate, and the report
    // says that the re-tuned gains were tuned at another.
    let dir = tempfile::tempdir().unwrap();
    let gains = shipped_gains_with(
        dir.path(),
        "control_tuned.toml",
        "control_tuned_split.toml",
        "outer_period_ticks = 2",
    );
    // The re-tuned gains file records the feed-forward's evaluation period (as `tune
    // --pressure-ff --ff-update-ticks 2` writes it): the feed-forward rows run at it.
    let ff_gains = shipped_gains_with(
        dir.path(),
        "control_tuned_ff.toml",
        "control_tuned_ff.toml",
        "pressure_ff_update_period_ticks = 2",
    );
    let r = on_plant(
        "compare-control",
        &plant(),
        &[&"--quick", &"--gains", &gains, &"--ff-gains", &ff_gains],
    );
    let out = text(&r.stdout);
    assert!(
        out.contains("evaluated every 2 tick(s); outer loops (position, torque) every 2 tick(s)"),
        "{out}"
    );
    let notes: Vec<&str> = out
        .lines()
        .filter(|l| l.starts_with("note: gains"))
        .collect();
    assert!(
        notes.len() == 1
            && notes[0].contains("control_tuned_ff.toml")
            && notes[0].contains("were tuned with the outer loops every 1 tick(s)"),
        "{out}"
    );
    let q = ratio(&out);
    assert_eq!(r.status.code(), Some(0), "{q}\n{out}\n{}", text(&r.stderr));
    assert!(q >= 1.85, "{q}\n{out}");
}

#[test]
fn compare_control_refuses_bad_arguments_with_status_2() {
    // A bad value of each feed-forward option: the error names the option (and the range).
    for (option, value, wants) in [
        ("--ff-gain", "5", &["--ff-gain 5", "0..=2"][..]),
        ("--ff-cutoff-hz", "0", &["--ff-cutoff-hz"]),
        ("--ff-min-duty", "1.5", &["--ff-min-duty 1.5", "0..=1"]),
        ("--ff-rate-from", "measured", &["--ff-rate-from"]),
        (
            "--ff-update-ticks",
            "0",
            &["'0' for '--ff-update-ticks <N>'", "1..=100"],
        ),
        (
            "--ff-update-ticks",
            "2.5",
            &["--ff-update-ticks", "not a whole number", "1..=100"],
        ),
        (
            "--outer-period-ticks",
            "6",
            &["'6' for '--outer-period-ticks <N>'", "1..=5"],
        ),
        (
            "--outer-period-ticks",
            "-1",
            &["'-1' for '--outer-period-ticks <N>'", "1..=5"],
        ),
    ] {
        let e = exits(
            2,
            &on_plant("compare-control", &plant(), &[&"--quick", &option, &value]),
        );
        assert!(wants.iter().all(|w| e.contains(w)), "{e}");
    }
    let e = exits(
        2,
        &on_plant("compare-control", &"/nonexistent/p.toml", &[&"--quick"]),
    );
    assert!(e.contains("/nonexistent/p.toml"), "{e}");
    // Another of the product's files given as the plant: named for what it is.
    let gains_as_plant =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/control_tuned.toml");
    let e = exits(
        2,
        &on_plant("compare-control", &gains_as_plant, &[&"--quick"]),
    );
    assert!(
        e.contains("control_tuned.toml")
            && e.contains("this is a control gains file")
            && e.contains("not a plant file")
            && !e.contains("volume_poly_m3"),
        "{e}"
    );
    let e = exits(
        2,
        &on_plant(
            "compare-control",
            &plant(),
            &[&"--quick", &"--ff-gains", &"/nonexistent/ff.toml"],
        ),
    );
    assert!(
        e.contains("/nonexistent/ff.toml") && e.contains("--ff-gains"),
        "{e}"
    );
    // Gains files swapped: each option refuses the other kind of file, naming it.
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let p_only = root.join("config/control_tuned.toml");
    let with_ff = root.join("config/control_tuned_ff.toml");
    for (option, file, wants) in [
        (
            "--gains",
            &with_ff,
            ["control_tuned_ff.toml (--gains)", "--ff-gains"],
        ),
        (
            "--ff-gains",
            &p_only,
            ["control_tuned.toml (--ff-gains)", "--pressure-ff"],
        ),
    ] {
        let e = exits(
            2,
            &on_plant("compare-control", &plant(), &[&"--quick", &option, file]),
        );
        assert!(wants.iter().all(|w| e.contains(w)), "{e}");
    }
}

#[test]
fn compare_control_outside_the_repository_names_the_gains_it_used() {
    // Run from a directory of the user's: no config/ there -> the shipped gains, said so.
    let dir = tempfile::tempdir().unwrap();
    let run = || {
        bin()
            .current_dir(dir.path())
            .args(["compare-control", "--quick", "--plant"])
            .arg(plant())
            .output()
            .unwrap()
    };
    let r = run();
    let out = text(&r.stdout);
    assert!(
        matches!(r.status.code(), Some(0 | 1)),
        "{out}\n{}",
        text(&r.stderr)
    );
    let first = out.lines().next().unwrap_or("");
    assert!(first.contains("gains the shipped gains"), "{first}");
    // Both tunings the shipped ones: the verdict compares like with like, no warning.
    assert!(!out.contains("warning: the verdict compares"), "{out}");
    let second = out.lines().nth(1).unwrap_or("");
    assert!(
        second.contains("re-tuned rows: gains the shipped gains (config/control_tuned_ff.toml"),
        "{second}"
    );
    // The user's own config/control_tuned.toml in the working directory is used and named.
    std::fs::create_dir(dir.path().join("config")).unwrap();
    let own = dir.path().join("config/control_tuned.toml");
    std::fs::write(
        &own,
        host_sim::control::compare::SHIPPED_CONTROL_TUNED.replace("\n[", "\n# the user's copy\n["),
    )
    .unwrap();
    let r = run();
    let out = text(&r.stdout);
    let first = out.lines().next().unwrap_or("");
    let own = own.canonicalize().unwrap();
    assert!(
        first.contains(&format!(
            "gains {} (in the working directory)",
            own.display()
        )),
        "{first}"
    );
    // A P-only tuning of the user's own (here: another position gain) against the shipped
    // feed-forward tuning: the verdict is said to compare tunings of different origin.
    let shipped = host_sim::control::compare::SHIPPED_CONTROL_TUNED;
    let kp = shipped
        .lines()
        .find(|l| l.starts_with("position_kp_nm_per_rad"))
        .unwrap();
    let mine = dir.path().join("mine.toml");
    std::fs::write(
        &mine,
        shipped.replacen(kp, "position_kp_nm_per_rad = 20.0", 1),
    )
    .unwrap();
    let r = bin()
        .current_dir(dir.path())
        .args(["compare-control", "--quick", "--plant"])
        .arg(plant())
        .arg("--gains")
        .arg(&mine)
        .output()
        .unwrap();
    let out = text(&r.stdout);
    assert!(
        out.contains("warning: the verdict compares the gains")
            && out.contains("with the shipped --ff-gains")
            && out.contains("host-sim tune --pressure-ff"),
        "{out}\n{}",
        text(&r.stderr)
    );
    // A broken file there is an error naming it, not a silent fall-back.
    std::fs::write(dir.path().join("config/control_tuned.toml"), "[cascade\n").unwrap();
    let e = exits(2, &run());
    assert!(e.contains("control_tuned.toml"), "{e}");
}
