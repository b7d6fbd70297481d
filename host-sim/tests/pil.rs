//! Processor in the loop: the firmware image `src/bin/pil.rs` under qemu-system-arm closes
//! the loop with the plant and matches the in-process closed loop bit for bit; its per-tick
//! stream becomes a recording through `host-sim capture` that `simulate` replays; QEMU
//! failures are clear, bounded errors.
//!
//! Needs `qemu-system-arm` and the thumbv7em-none-eabihf target: without them the QEMU tests
//! fail when `CI=true` and are skipped with a message otherwise.

mod common;
use common::*;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use host_sim::control::closed_loop::{run_with, Scenario};
use host_sim::control::pil::{first_difference, run_scenario, PilOptions};
use host_sim::{Plant, Recording};

/// The step scenario, shortened to 1.5 s (1500 ticks), sensors in board counts.
fn scenario(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(root().join("scenarios/step.toml"))
        .unwrap()
        .replace("[sensors]\n", "[sensors]\nboard_counts = true\n")
        .replace("duration_s = 4.0", "duration_s = 1.5")
        .replace("at_s = 1.0", "at_s = 0.3")
        .replace("settle_after_s = 2.0", "settle_after_s = 1.2");
    let p = dir.join("step.toml");
    std::fs::write(&p, text).unwrap();
    p
}

/// Builds the PIL image; `None` (test skipped) when QEMU is not installed outside CI.
fn pil_elf() -> Option<PathBuf> {
    let have_qemu = Command::new("sh")
        .args(["-c", "command -v qemu-system-arm"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !have_qemu {
        if std::env::var("CI").as_deref() == Ok("true") {
            panic!("pil: qemu-system-arm not installed: required in CI");
        }
        eprintln!("SKIPPED pil: qemu-system-arm not installed (scripts/setup.sh)");
        return None;
    }
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .args([
            "build",
            "-p",
            "pam-firmware",
            "--bin",
            "pil",
            "--features",
            "pam-firmware/firmware",
            "--release",
            "--target",
            "thumbv7em-none-eabihf",
        ])
        .current_dir(root())
        .output()
        .expect("cannot run cargo");
    assert!(
        out.status.success(),
        "building the PIL image failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    Some(PilOptions::default_elf())
}

#[test]
fn pil_matches_the_in_process_loop_bit_for_bit_and_capture_replays() {
    let Some(elf) = pil_elf() else { return };
    let dir = tempfile::tempdir().unwrap();
    let s = scenario(dir.path());
    let out = dir.path().join("pil.csv");
    let log = dir.path().join("pil.stream");
    let t0 = std::time::Instant::now();
    let r = on_plant(
        "pil",
        &plant(),
        &[
            &"--scenario",
            &s,
            &"--out",
            &out,
            &"--log",
            &log,
            &"--elf",
            &elf,
        ],
    );
    let stdout = ok(&r);
    assert!(stdout.contains("bit for bit on all 1500 ticks"), "{stdout}");
    // The scenario's [expect] is checked on the firmware's run, as simulate does.
    assert!(stdout.contains("expectations: met"), "{stdout}");
    eprintln!("pil: 1500 ticks in {:.2} s", t0.elapsed().as_secs_f64());

    // The recording equals `simulate --scenario`'s on the valve columns and the angle.
    let sim = dir.path().join("sim.csv");
    let r = on_plant("simulate", &plant(), &[&"--scenario", &s, &"--out", &sim]);
    ok(&r);
    let (a, b) = (
        Recording::read(&out).unwrap(),
        Recording::read(&sim).unwrap(),
    );
    assert_eq!(a.inputs, b.inputs);
    assert_eq!(
        a.channel(host_sim::Channel::AngleDeg),
        b.channel(host_sim::Channel::AngleDeg)
    );
    assert!(a.inputs.iter().any(|u| u.u_in1 == 1.0) && a.inputs.iter().any(|u| u.u_in1 == 0.0));

    // The stream: 46 bytes per tick, captured into a recording simulate replays.
    assert_eq!(std::fs::metadata(&log).unwrap().len(), 1500 * 46);
    let cap = dir.path().join("cap.csv");
    let r = host_sim(&[&"capture", &"--log", &log, &"--out", &cap]);
    ok(&r);
    let c = Recording::read(&cap).unwrap();
    assert_eq!(c.len(), 1500);
    assert_eq!(c.inputs, a.inputs, "captured openings = applied openings");
    assert!((c.sample_period_s() - 1e-3).abs() < 1e-12);
    // The firmware's scaled angle is the encoder-quantised true angle (8000 counts per turn).
    let (ca, aa) = (
        c.channel(host_sim::Channel::AngleDeg).unwrap(),
        a.channel(host_sim::Channel::AngleDeg).unwrap(),
    );
    for (k, (x, y)) in ca.iter().zip(aa).enumerate() {
        assert!(
            (x - y).abs() <= 360.0 / 8000.0 + 1e-6,
            "tick {k}: {x} vs {y}"
        );
    }
    let rep = dir.path().join("rep.csv");
    let r = on_plant("simulate", &plant(), &[&"--inputs", &cap, &"--out", &rep]);
    ok(&r);
    // Replaying the captured openings open loop reproduces the closed-loop angle.
    let rr = Recording::read(&rep).unwrap();
    let fit = host_sim::fit::fit_percent(aa, rr.channel(host_sim::Channel::AngleDeg).unwrap());
    assert!(
        fit > 99.0,
        "replay of the captured run fits the angle {fit} %"
    );

    // A lost record is reported, not interpolated.
    let bytes = std::fs::read(&log).unwrap();
    let mut cut = bytes[..100 * 46].to_vec();
    cut.extend_from_slice(&bytes[101 * 46..]);
    let lossy = dir.path().join("lossy.stream");
    std::fs::write(&lossy, cut).unwrap();
    let never = dir.path().join("never.csv");
    let r = host_sim(&[&"capture", &"--log", &lossy, &"--out", &never]);
    assert_refused(&r, &["sequence 101 after 99", "1 record(s) lost"], &never);
}

#[test]
fn a_faulting_firmware_and_a_missing_qemu_are_clear_bounded_errors() {
    let Some(elf) = pil_elf() else { return };
    let dir = tempfile::tempdir().unwrap();
    let plant = Plant::load(plant()).unwrap();
    let sc = Scenario::load(scenario(dir.path())).unwrap();

    // The image run with `-append <mode>` fails on tick 0 naming `needle`, within `max_s`.
    let fails_on_tick_0 = |mode: &str, tick_timeout_s: u64, needle: &str, max_s: u64| {
        let mut opts = PilOptions::new(elf.clone());
        opts.extra_args = vec!["-append".into(), mode.into()];
        opts.tick_timeout = Duration::from_secs(tick_timeout_s);
        let t0 = std::time::Instant::now();
        let r = run_scenario(&plant, &sc, opts);
        assert!(
            t0.elapsed() < Duration::from_secs(max_s),
            "{mode}: {:?}",
            t0.elapsed()
        );
        error_naming(r, &["tick 0", needle]);
    };
    fails_on_tick_0("hardfault", 10, "PIL-FAULT HardFault", 10);

    let mut opts = PilOptions::new(elf.clone());
    opts.qemu = "/nonexistent/qemu-system-arm".into();
    let r = run_scenario(&plant, &sc, opts);
    error_naming(r, &["cannot start /nonexistent/qemu-system-arm"]);

    let opts = PilOptions::new(dir.path().join("no-such.elf"));
    let r = run_scenario(&plant, &sc, opts);
    error_naming(r, &["no-such.elf", "no firmware image"]);

    // A hung image (never answers): the tick timeout ends the run with a clear error.
    fails_on_tick_0("hang", 2, "no record from the firmware within 2.0 s", 8);

    // An image that is not firmware: QEMU refuses it or it never answers; bounded either way.
    let junk = dir.path().join("junk.elf");
    std::fs::write(&junk, b"not an ELF").unwrap();
    let mut opts = PilOptions::new(junk);
    opts.tick_timeout = Duration::from_secs(3);
    let t0 = std::time::Instant::now();
    let e = run_scenario(&plant, &sc, opts).unwrap_err().to_string();
    assert!(e.contains("tick 0"), "{e}");
    assert!(t0.elapsed() < Duration::from_secs(10), "{:?}", t0.elapsed());

    // A copy of the image cut short (an interrupted download) is refused before QEMU starts
    // (QEMU aborted on it with a register dump), naming --elf; the output is not written.
    let bytes = std::fs::read(&elf).unwrap();
    let cut = dir.path().join("cut.elf");
    std::fs::write(&cut, &bytes[..bytes.len() / 3]).unwrap();
    let out = dir.path().join("never.csv");
    let r = on_plant(
        "pil",
        &common::plant(),
        &[
            &"--scenario",
            &scenario(dir.path()),
            &"--out",
            &out,
            &"--elf",
            &cut,
        ],
    );
    assert_refused(&r, &["--elf", "cut.elf", "truncated or damaged ELF"], &out);
}

#[test]
fn pil_checks_the_scenarios_expectations_on_the_firmwares_run() {
    let Some(elf) = pil_elf() else { return };
    let dir = tempfile::tempdir().unwrap();
    let s = scenario(dir.path());
    // A bound the step cannot meet: 0.1 mrad after 1.2 s.
    let text = std::fs::read_to_string(&s)
        .unwrap()
        .replace("max_abs_error_rad = 0.01", "max_abs_error_rad = 0.0001");
    std::fs::write(&s, text).unwrap();
    let out = dir.path().join("pil.csv");
    let r = on_plant(
        "pil",
        &common::plant(),
        &[&"--scenario", &s, &"--out", &out, &"--elf", &elf],
    );
    let stdout = String::from_utf8_lossy(&r.stdout);
    assert_eq!(r.status.code(), Some(1), "{stdout}");
    assert!(stdout.contains("expectation not met"), "{stdout}");
    // The runs still agree; the recording is written.
    assert!(stdout.contains("bit for bit"), "{stdout}");
    assert!(out.exists());
}

#[test]
fn a_difference_names_the_first_tick_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let plant = Plant::load(plant()).unwrap();
    let sc = Scenario::load(scenario(dir.path())).unwrap();
    let cfg = pam_firmware::tick::ControllerConfig::reference(1000.0);
    let a = run_with(&plant, &sc, cfg, &mut |_| {}).unwrap();
    let mut b = a.clone();
    assert_eq!(first_difference(&a, &b), None);
    b.rows[700].inputs.u_ex2 = 1.0 - b.rows[700].inputs.u_ex2;
    b.rows[900].state.angle_rad += 1e-12;
    assert_eq!(
        first_difference(&a, &b).map(|d| (d.0, d.1)),
        Some((700, "u_ex2"))
    );
}

#[test]
fn capture_reads_defmt_print_text_lines_and_refuses_a_missing_sample() {
    use pam_firmware::stream::{TickRecord, RECORD_LEN};
    let dir = tempfile::tempdir().unwrap();
    let rec = |seq: u32, angle: f32| TickRecord {
        seq,
        t_us: 1000 * seq,
        setpoint_rad: 0.1,
        openings: [1.0, 0.0, (seq % 2) as f32, 1.0],
        p_counts: [1547, 1600],
        encoder_counts: 12,
        p_gauge_pa: [266_601.56, 279_541.0],
        angle_rad: angle,
        fault: 0,
        armed: true,
    };
    let line = |r: &TickRecord| {
        let mut b = [0u8; RECORD_LEN];
        r.encode(&mut b);
        let bytes: Vec<String> = b.iter().map(|x| x.to_string()).collect();
        format!("0.001 INFO stream [{}]\n", bytes.join(", "))
    };
    let mut text = String::from("INFO pam-firmware board: streaming\n");
    for k in 0..5 {
        text += &line(&rec(k, 0.01 * k as f32));
    }
    let log = dir.path().join("rtt.txt");
    std::fs::write(&log, &text).unwrap();
    let out = dir.path().join("c.csv");
    let r = host_sim(&[&"capture", &"--log", &log, &"--out", &out]);
    ok(&r);
    let c = Recording::read(&out).unwrap();
    assert_eq!(c.len(), 5);
    assert_eq!(c.inputs[1].u_in2, 1.0);
    assert!((c.channel(host_sim::Channel::P1Kpa).unwrap()[0] - 266.60156).abs() < 1e-3);
    assert!(
        (c.channel(host_sim::Channel::AngleDeg).unwrap()[3] - 0.03f32.to_degrees() as f64).abs()
            < 1e-4
    );

    // A line logged twice is dropped and counted; the same sequence number with other
    // content, or a record whose zero byte reads 0xFF, is refused.
    let twice = dir.path().join("twice.txt");
    std::fs::write(&twice, text.clone() + &line(&rec(4, 0.04))).unwrap();
    let r = host_sim(&[&"capture", &"--log", &twice, &"--out", &out]);
    ok(&r);
    assert!(
        String::from_utf8_lossy(&r.stdout).contains("1 repeated record(s) dropped"),
        "{}",
        String::from_utf8_lossy(&r.stdout)
    );
    assert_eq!(Recording::read(&out).unwrap().len(), 5);
    let n = dir.path().join("n.csv");
    std::fs::write(&twice, text.clone() + &line(&rec(4, 0.05))).unwrap();
    let r = host_sim(&[&"capture", &"--log", &twice, &"--out", &n]);
    assert_refused(
        &r,
        &[
            "twice.txt: line 7",
            "sequence 4 after 4",
            "repeated with other content",
        ],
        &n,
    );
    let mut b = [0u8; RECORD_LEN];
    rec(5, 0.05).encode(&mut b);
    let zero = (2..44).find(|i| b[*i] == 0).expect("a zero byte");
    b[zero] = 0xFF;
    let bytes: Vec<String> = b.iter().map(|x| x.to_string()).collect();
    let flipped = dir.path().join("flipped.txt");
    std::fs::write(
        &flipped,
        text.clone() + &format!("0.006 INFO stream [{}]\n", bytes.join(", ")),
    )
    .unwrap();
    let r = host_sim(&[&"capture", &"--log", &flipped, &"--out", &n]);
    assert_refused(
        &r,
        &[
            "flipped.txt:7",
            "not a stream record (checksum mismatch: a corrupted byte)",
            "--split",
        ],
        &n,
    );

    text += &line(&rec(5, f32::NAN));
    std::fs::write(&log, &text).unwrap();
    let r = host_sim(&[&"capture", &"--log", &log, &"--out", &n]);
    assert_refused(&r, &["rtt.txt: line 7", "no angle sample"], &n);
}

#[test]
fn capture_splits_a_run_at_its_gaps_and_names_faulted_ticks() {
    use pam_firmware::stream::{TickRecord, RECORD_LEN};
    let dir = tempfile::tempdir().unwrap();
    let rec = |seq: u32| TickRecord {
        seq,
        t_us: 1000 * seq + 500,
        setpoint_rad: 0.1,
        openings: [1.0, 0.0, (seq % 2) as f32, 1.0],
        p_counts: [1547, 1600],
        encoder_counts: 12,
        p_gauge_pa: [266_601.56, 279_541.0],
        angle_rad: 0.001 * seq as f32,
        // A sensor fault latched from tick 15 on: the safe state's openings, still data.
        fault: if seq >= 15 { 9 } else { 0 },
        armed: seq < 15,
    };
    let bytes_of = |r: &TickRecord| {
        let mut b = [0u8; RECORD_LEN];
        r.encode(&mut b);
        b
    };
    // Raw: ticks 0..30, tick 8 lost, tick 12's angle missing, tick 20 corrupted (one byte).
    let mut raw = Vec::new();
    for k in 0..30u32 {
        let mut r = rec(k);
        if k == 8 {
            continue;
        }
        if k == 12 {
            r.angle_rad = f32::NAN;
        }
        let mut b = bytes_of(&r);
        if k == 20 {
            b[10] ^= 0x40;
        }
        raw.extend_from_slice(&b);
    }
    let log = dir.path().join("run.stream");
    std::fs::write(&log, &raw).unwrap();
    let out = dir.path().join("run.csv");
    let seg = |n: usize| dir.path().join(format!("run-{n}.csv"));

    // Without the flag: refused at the first gap, naming the flag; nothing written.
    let r = host_sim(&[&"capture", &"--log", &log, &"--out", &out]);
    assert_refused(
        &r,
        &["sequence 9 after 7", "1 record(s) lost", "--split"],
        &out,
    );
    // A file of a segment's name that is not a capture's: overwritten only as an output,
    // and one beyond this capture's segments (run-5.csv) is named and left alone.
    std::fs::write(seg(5), "mine\n").unwrap();

    let r = host_sim(&[&"capture", &"--log", &log, &"--out", &out, &"--split"]);
    ok(&r);
    let stdout = String::from_utf8_lossy(&r.stdout).to_string();
    assert!(!out.exists(), "segments only");
    let piece = |n: usize| Recording::read(seg(n)).unwrap();
    // 0..=7 | 9..=11 | (12 missing) 13..=19 | (20 corrupted) 21..=29
    let lens: Vec<usize> = (1..=4).map(|n| piece(n).len()).collect();
    assert_eq!(lens, [8, 3, 7, 9], "{stdout}");
    for needle in [
        "sequence 8..=8: 1 record(s) lost",
        "sequence 12: no angle sample",
        "a corrupted record, not a lost one",
        "4 segment(s)",
        "1 tick(s) without a sensor sample dropped",
        "run-5.csv is not part of this capture (4 segments)",
    ] {
        assert!(stdout.contains(needle), "{needle:?} in {stdout}");
    }
    assert_eq!(std::fs::read_to_string(seg(5)).unwrap(), "mine\n");
    // Each segment starts at t = 0, keeps the firmware's time in its source line, and the
    // period is the stamped one exactly; times carry no float noise.
    let p3 = piece(3);
    assert_eq!(p3.t_s[0], 0.0);
    assert!(std::fs::read_to_string(seg(3))
        .unwrap()
        .contains("\n0.006,"));
    let meta = |r: &Recording, k: &str| {
        r.metadata
            .iter()
            .find(|(key, _)| key == k)
            .map(|(_, v)| v.clone())
            .unwrap_or_default()
    };
    let src = meta(&p3, "source");
    assert!(
        src.contains("sequence 13..=19") && src.contains("firmware time 0.0135 s"),
        "{src}"
    );
    assert_eq!(meta(&p3, "sample_period_s"), "0.001");
    // The latched fault (from tick 15) is named in the segments that hold it, not before.
    assert!(meta(&piece(1), "faulted").is_empty());
    let f = meta(&p3, "faulted");
    assert!(
        f.contains("5 tick(s)") && f.contains("sequence 15") && f.contains("AngleStale"),
        "{f}"
    );
    assert_eq!(meta(&p3, "armed_ticks"), "2 of 7");

    // The same OUT again from a log without gaps: one recording, OUT itself; the earlier
    // capture's segments are removed (they would pass for part of this run), the user's
    // file is not.
    let clean: Vec<u8> = (0..30u32).flat_map(|k| bytes_of(&rec(k))).collect();
    std::fs::write(&log, &clean).unwrap();
    let r = host_sim(&[&"capture", &"--log", &log, &"--out", &out, &"--split"]);
    let stdout = ok(&r);
    assert_eq!(Recording::read(&out).unwrap().len(), 30);
    for n in 1..=4 {
        assert!(!seg(n).exists(), "run-{n}.csv left: {stdout}");
    }
    assert!(
        stdout.contains("removed") && stdout.contains("a segment of an earlier capture"),
        "{stdout}"
    );
    assert!(seg(5).exists());

    // Consecutive sequence numbers whose stamps jump (a clock set, a late tick): the log's
    // byte is named, not the recording never written; with --split a gap like the others.
    let jumped: Vec<u8> = (0..20u32)
        .flat_map(|k| {
            bytes_of(&TickRecord {
                t_us: 1000 * k + if k >= 10 { 100_000 } else { 0 },
                ..rec(k)
            })
        })
        .collect();
    std::fs::write(&log, &jumped).unwrap();
    let j = dir.path().join("j.csv");
    let r = host_sim(&[&"capture", &"--log", &log, &"--out", &j]);
    assert_refused(
        &r,
        &[
            "run.stream: byte",
            "sequence 10 after 9",
            "moves 101000 us between consecutive ticks (the tick period is 1000 us)",
            "--split",
        ],
        &j,
    );
    let stdout = ok(&host_sim(&[
        &"capture", &"--log", &log, &"--out", &j, &"--split",
    ]));
    assert!(stdout.contains("2 segment(s)"), "{stdout}");
    for n in 1..=2 {
        let p = dir.path().join(format!("j-{n}.csv"));
        assert_eq!(Recording::read(&p).unwrap().len(), 10);
    }

    // The 32-bit microsecond stamp wraps (every 71.6 min): time goes on across it; a
    // firmware restart (sequence back to 0) is a new run, refused without --split.
    let near = u32::MAX - 2_500;
    let wrapped: Vec<u8> = (0..6u32)
        .flat_map(|k| {
            bytes_of(&TickRecord {
                t_us: near.wrapping_add(1000 * k),
                ..rec(k)
            })
        })
        .collect();
    std::fs::write(&log, &wrapped).unwrap();
    let w = dir.path().join("w.csv");
    ok(&host_sim(&[&"capture", &"--log", &log, &"--out", &w]));
    assert_eq!(
        Recording::read(&w).unwrap().t_s,
        [0.0, 0.001, 0.002, 0.003, 0.004, 0.005]
    );
    let mut restarted = clean[..10 * RECORD_LEN].to_vec();
    restarted.extend_from_slice(&clean[..5 * RECORD_LEN]);
    std::fs::write(&log, &restarted).unwrap();
    let rr = dir.path().join("rr.csv");
    let r = host_sim(&[&"capture", &"--log", &log, &"--out", &rr]);
    assert_refused(
        &r,
        &["sequence 0 after 9", "firmware that restarted", "--split"],
        &rr,
    );
    let stdout = ok(&host_sim(&[
        &"capture", &"--log", &log, &"--out", &rr, &"--split",
    ]));
    assert!(stdout.contains("the firmware restarted"), "{stdout}");
    let rr2 = dir.path().join("rr-2.csv");
    assert_eq!(Recording::read(&rr2).unwrap().len(), 5);

    // A corrupted first record: named, not dropped without a word.
    let mut first_bad = clean.clone();
    first_bad[10] ^= 0x40;
    std::fs::write(&log, &first_bad).unwrap();
    let fb = dir.path().join("fb.csv");
    let stdout = ok(&host_sim(&[&"capture", &"--log", &log, &"--out", &fb]));
    assert!(
        stdout.contains("before the first record do not decode but hold a record's sync bytes"),
        "{stdout}"
    );
    assert_eq!(Recording::read(&fb).unwrap().len(), 29);

    // Text (defmt-print lines): a corrupted line is a gap in split mode, and the log's last
    // line cut inside its record is ignored with a note in either mode.
    let line = |b: &[u8]| {
        let v: Vec<String> = b.iter().map(|x| x.to_string()).collect();
        format!("0.001 INFO stream [{}]\n", v.join(", "))
    };
    let mut text = String::new();
    for k in 0..10u32 {
        let mut b = bytes_of(&rec(k));
        if k == 4 {
            b[7] ^= 1;
        }
        text += &line(&b);
    }
    let cut = line(&bytes_of(&rec(10)));
    text += &cut[..cut.len() / 2];
    let txt = dir.path().join("rtt.txt");
    std::fs::write(&txt, &text).unwrap();
    let t = dir.path().join("t.csv");
    let r = host_sim(&[&"capture", &"--log", &txt, &"--out", &t, &"--split"]);
    let stdout = ok(&r);
    assert!(
        stdout.contains("line 5 between them is not a stream record (checksum mismatch"),
        "{stdout}"
    );
    assert!(
        stdout.contains("line 11, the log's last, is cut"),
        "{stdout}"
    );
    assert_eq!(
        Recording::read(dir.path().join("t-1.csv")).unwrap().len(),
        4
    );
    assert_eq!(
        Recording::read(dir.path().join("t-2.csv")).unwrap().len(),
        5
    );

    // A log with nothing but ticks without samples: a clear error, nothing written.
    let mut none = Vec::new();
    for k in 0..5u32 {
        let mut r = rec(k);
        r.p_gauge_pa[1] = f32::NAN;
        none.extend_from_slice(&bytes_of(&r));
    }
    std::fs::write(&log, &none).unwrap();
    let n = dir.path().join("n.csv");
    let r = host_sim(&[&"capture", &"--log", &log, &"--out", &n, &"--split"]);
    assert_refused(
        &r,
        &["5 without a sensor sample", "at least 2 consecutive ticks"],
        &n,
    );
    assert!(!dir.path().join("n-1.csv").exists());
}

#[test]
fn capture_names_the_logs_record_for_an_implausible_reading_not_the_output() {
    use pam_firmware::stream::{TickRecord, RECORD_LEN};
    let dir = tempfile::tempdir().unwrap();
    // 40 ticks; tick 30 scaled p1 to 1e9 Pa (a board configured for another sensor).
    let mut raw = Vec::new();
    for seq in 0..40u32 {
        let r = TickRecord {
            seq,
            t_us: 1000 * seq,
            setpoint_rad: 0.1,
            openings: [1.0, 0.0, 0.0, 1.0],
            p_counts: [1547, 1600],
            encoder_counts: 12,
            p_gauge_pa: [if seq == 30 { 1e9 } else { 266_601.56 }, 279_541.0],
            angle_rad: 0.001 * seq as f32,
            fault: 0,
            armed: true,
        };
        let mut b = [0u8; RECORD_LEN];
        r.encode(&mut b);
        raw.extend_from_slice(&b);
    }
    let log = dir.path().join("bad.stream");
    std::fs::write(&log, &raw).unwrap();
    // An existing good recording as --out stays as it was.
    let out = previous_output(dir.path(), "rec.csv");
    let r = host_sim(&[&"capture", &"--log", &log, &"--out", &out]);
    let err = exits(2, &r);
    for needle in [
        "bad.stream: record of sequence 30: p1_kpa",
        "a value in Pa?",
    ] {
        assert!(err.contains(needle), "{needle:?} in {err}");
    }
    assert!(!err.contains("rec.csv"), "{err}");
    assert_kept(&out);
}
