//! The QEMU firmware run (`cargo qemu`: Cortex-M4F, hardware FPU) and a native run of the same
//! code (`pam_firmware::trace::TraceRunner`) must produce bit-for-bit identical per-tick outputs;
//! the Cortex-M0 image's fixed-point path (force law, torque model, whole fixed tick over the
//! trace) must equal the host's bit for bit; the on-target tests (defmt-test) must pass under
//! QEMU.
//!
//! Needs `qemu-system-arm` and `defmt-print` (scripts/setup.sh installs both). Without them the
//! test fails when `CI=true` and is skipped with a message otherwise.

use std::path::Path;
use std::process::{Command, Output};

use pam_firmware::trace::{TickRecord, TraceRunner, WORDS};

fn have(tool: &str) -> bool {
    Command::new("sh")
        .args(["-c", &format!("command -v {tool}")])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false)
}

fn host_records() -> Vec<TickRecord> {
    let mut r = TraceRunner::new();
    std::iter::from_fn(|| r.step()).collect()
}

/// Parses `tick=N out=w0,...,w8 hash=H` (hex words) from a decoded defmt line.
fn parse_tick(line: &str) -> Option<TickRecord> {
    let rest = &line[line.find("tick=")?..];
    let mut it = rest.split_whitespace();
    let tick = it.next()?.strip_prefix("tick=")?.parse().ok()?;
    let out = it.next()?.strip_prefix("out=")?;
    let hash = u32::from_str_radix(it.next()?.strip_prefix("hash=")?, 16).ok()?;
    let mut words = [0u32; WORDS];
    let mut n = 0;
    for (i, w) in out.split(',').enumerate() {
        *words.get_mut(i)? = u32::from_str_radix(w, 16).ok()?;
        n += 1;
    }
    (n == WORDS).then_some(TickRecord { tick, words, hash })
}

/// True when QEMU and defmt-print are installed; panics in CI (CI=true) when they are not.
fn qemu_available() -> bool {
    let missing: Vec<&str> = ["qemu-system-arm", "defmt-print"]
        .into_iter()
        .filter(|t| !have(t))
        .collect();
    if !missing.is_empty() {
        let msg = format!(
            "qemu_trace: {} not installed (run scripts/setup.sh)",
            missing.join(", ")
        );
        if std::env::var("CI").as_deref() == Ok("true") {
            panic!("{msg}: required in CI");
        }
        eprintln!("SKIPPED {msg}");
        return false;
    }
    true
}

/// `cargo <args>` from the repository root, defmt lines decoded as bare messages, QEMU given
/// 60 s (scripts/qemu-run.sh is the runner of both firmware targets).
fn cargo_run_in_qemu(args: &[&str]) -> Output {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    Command::new(cargo)
        .args(args)
        .current_dir(root)
        .env("DEFMT_PRINT_ARGS", "--log-format {s}")
        .env("QEMU_TIMEOUT_S", "60")
        .output()
        .unwrap_or_else(|e| panic!("cannot start cargo {}: {e}", args.join(" ")))
}

/// `cargo qemu [-- qemu args]` exactly as a developer runs it (alias in .cargo/config.toml).
fn cargo_qemu(qemu_args: &[&str]) -> Output {
    let mut args = vec!["qemu"];
    if !qemu_args.is_empty() {
        args.push("--");
        args.extend(qemu_args);
    }
    cargo_run_in_qemu(&args)
}

/// The stdout of a run that must have succeeded (`what` failed: status, stderr and stdout
/// shown otherwise).
fn succeeded(out: &Output, what: &str) -> String {
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{what} failed ({}):\n{}\n{stdout}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

#[test]
fn qemu_run_matches_host_run_bit_for_bit() {
    let host = host_records();
    assert_eq!(host.len(), TraceRunner::len());
    if !qemu_available() {
        return;
    }
    let out = cargo_qemu(&[]);
    let stdout = succeeded(&out, "cargo qemu");

    let qemu: Vec<TickRecord> = stdout.lines().filter_map(parse_tick).collect();
    assert_eq!(
        qemu.len(),
        host.len(),
        "QEMU logged {} ticks, host ran {}:\n{stdout}",
        qemu.len(),
        host.len()
    );
    for (q, h) in qemu.iter().zip(&host) {
        assert_eq!(
            q, h,
            "tick {}: QEMU (left) and host (right) differ (words are f32 bit patterns)",
            h.tick
        );
    }
    let done = stdout
        .lines()
        .find_map(|l| l.split("digest=").nth(1))
        .expect("no `trace done ... digest=` line");
    let digest = u32::from_str_radix(done.trim(), 16).expect("digest not hex");
    assert_eq!(digest, host.last().unwrap().hash);
    eprintln!(
        "qemu_trace: {} ticks identical, digest {digest:08x}",
        host.len()
    );
}

/// The Cortex-M0 image (no FPU, QEMU `microbit`) runs the fixed-point path over the trace and
/// prints its digest; the host run of the same function must give the same bits.
#[test]
fn qemu_m0_fixed_path_matches_host_bit_for_bit() {
    let (rows, hash) = pam_firmware::trace::fixed_path_digest();
    assert!(rows > 100, "only {rows} trace rows reach the fixed path");
    if !qemu_available() {
        return;
    }
    let image = "run -p pam-firmware --bin qemu_m0 --features pam-firmware/firmware --release \
                 --target thumbv6m-none-eabi";
    let out = cargo_run_in_qemu(&image.split_whitespace().collect::<Vec<_>>());
    let stdout = succeeded(&out, "qemu_m0");
    let line = stdout
        .lines()
        .find(|l| l.contains("fixed path rows="))
        .unwrap_or_else(|| panic!("no `fixed path` line:\n{stdout}"));
    let want = format!("fixed path rows={rows} digest={hash:08x}");
    assert!(line.contains(&want), "M0: `{line}`, host: `{want}`");
    eprintln!("qemu_m0: fixed path over {rows} rows identical, digest {hash:08x}");
}

/// The on-target tests (src/bin/on_target.rs, defmt-test) under QEMU netduinoplus2 through
/// `scripts/on-target.sh`: every test passes (exit status 0), and the fixed-point path's digest
/// computed on the Cortex-M4F equals the host's.
#[test]
fn on_target_tests_pass_under_qemu() {
    let (rows, hash) = pam_firmware::trace::fixed_path_digest();
    if !qemu_available() {
        return;
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut cmd = Command::new("bash");
    cmd.arg("scripts/on-target.sh")
        .current_dir(root)
        .env("DEFMT_PRINT_ARGS", "--log-format {s}")
        .env("QEMU_TIMEOUT_S", "120");
    if let Ok(cargo) = std::env::var("CARGO") {
        // The script calls `cargo`: the same one as this test run.
        let dir = Path::new(&cargo).parent().unwrap().to_owned();
        let path = std::env::var_os("PATH").unwrap_or_default();
        let mut paths = vec![dir];
        paths.extend(std::env::split_paths(&path));
        cmd.env("PATH", std::env::join_paths(paths).unwrap());
    }
    let out = cmd.output().expect("cannot start scripts/on-target.sh");
    let stdout = succeeded(&out, "on-target tests");
    assert!(stdout.contains("all tests passed!"), "{stdout}");
    let want = format!("on-target fixed path rows={rows} digest={hash:08x}");
    assert!(stdout.contains(&want), "want `{want}`:\n{stdout}");
    eprintln!("on_target: all passed under QEMU, {want}");
}

#[test]
fn qemu_panic_and_hardfault_exit_with_status_1() {
    if !qemu_available() {
        return;
    }
    for fault in ["panic", "hardfault"] {
        let out = cargo_qemu(&["-append", fault]);
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert_eq!(
            out.status.code(),
            Some(1),
            "{fault}: expected exit status 1, got {}:\n{stdout}\n{}",
            out.status,
            String::from_utf8_lossy(&out.stderr)
        );
        let marker = match fault {
            "panic" => "panicked at src/bin/qemu.rs:",
            _ => "HardFault at pc=",
        };
        assert!(stdout.contains(marker), "{fault}: no `{marker}`:\n{stdout}");
        assert!(
            !stdout.contains("trace done"),
            "{fault}: the trace must not run"
        );
    }
}

#[test]
fn parser_reads_a_decoded_line() {
    let r = parse_tick("INFO tick=7 out=0,1,a,b,c,d,e,f,100 hash=deadbeef").unwrap();
    assert_eq!(r.tick, 7);
    assert_eq!(r.words, [0, 1, 0xa, 0xb, 0xc, 0xd, 0xe, 0xf, 0x100]);
    assert_eq!(r.hash, 0xdead_beef);
    assert!(parse_tick("tick=7 out=0,1 hash=0").is_none());
}
