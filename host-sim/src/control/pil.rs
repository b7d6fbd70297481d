//! Processor in the loop: the firmware image `src/bin/pil.rs` under `qemu-system-arm`
//! (`netduinoplus2`, Cortex-M4F) as the [`Firmware`] side of a closed-loop run.
//!
//! Link: QEMU's semihosting console (`-semihosting-config enable=on,target=native`, which
//! is QEMU's stdin / stdout): host-sim writes QEMU's stdin and reads its stdout. Chosen over a UART chardev because it needs no UART driver in the
//! image (the board's control path is what is under test, not a QEMU peripheral model) and
//! a semihosting read blocks the emulated CPU until the host has sent the frame, which is the
//! lockstep: the firmware never reads a clock, the plant advances exactly one tick per
//! exchanged frame.
//!
//! Per tick the host sends one `pam_firmware::stream::SensorInput` (raw ADC counts, encoder
//! counts, set-point, measured period, MCU reset) and reads one `TickRecord` (the applied valve openings and the rest of
//! the per-tick stream), which is also appended to the stream log (`host-sim capture` turns
//! such a log into a recording). Every wait is bounded ([`PilOptions::tick_timeout`]); QEMU
//! missing, an image that does not start, a firmware that faults (it prints a `PIL-FAULT`
//! line and exits with status 1) or a stream out of sequence are errors naming the tick.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

use pam_firmware::safety::FaultCode;
use pam_firmware::stream::{
    RunConfig, SensorInput, TickRecord, CONFIG_LEN, FLAG_STOP, INPUT_LEN, MISSING_COUNTS,
    MISSING_ENCODER, RECORD_LEN, RECORD_SYNC, RESET_NONE,
};
use pam_firmware::tick::{TickOutput, ValveCommand};

use crate::control::closed_loop::{
    ClosedLoopError, Firmware, FirmwareInput, FirmwareTick, Scenario,
};
pub use crate::io::capture::check_elf_for;

/// How the emulator is run.
#[derive(Debug, Clone)]
pub struct PilOptions {
    /// The firmware image (ELF).
    pub elf: PathBuf,
    /// `qemu-system-arm` (name on PATH or path).
    pub qemu: PathBuf,
    /// Longest wait for one tick's record (the first one includes QEMU's start-up).
    pub tick_timeout: Duration,
    /// Extra QEMU arguments (e.g. `-append hardfault`).
    pub extra_args: Vec<String>,
}

impl PilOptions {
    /// The default image built by `cargo build -p pam-firmware --bin pil --features
    /// pam-firmware/firmware --release --target thumbv7em-none-eabihf` in the workspace.
    pub fn default_elf() -> PathBuf {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        root.join(DEFAULT_ELF_IN_WORKING_DIR)
    }

    pub fn new(elf: PathBuf) -> Self {
        Self {
            elf,
            qemu: "qemu-system-arm".into(),
            tick_timeout: Duration::from_secs(20),
            extra_args: Vec::new(),
        }
    }
}

/// The firmware running in QEMU.
pub struct QemuFirmware {
    child: Child,
    stdin: Option<ChildStdin>,
    rx: Receiver<Vec<u8>>,
    buf: Vec<u8>,
    opts: PilOptions,
    /// Every record received, in order (the per-tick stream).
    pub log: Vec<u8>,
}

fn err(tick: usize, msg: impl Into<String>) -> ClosedLoopError {
    ClosedLoopError::Firmware {
        tick,
        msg: msg.into(),
    }
}

impl QemuFirmware {
    /// Starts QEMU with the image and sends the run configuration of `scenario`.
    pub fn start(opts: PilOptions, scenario: &Scenario) -> Result<Self, ClosedLoopError> {
        if !opts.elf.is_file() {
            return Err(err(
                0,
                format!(
                    "{}: no firmware image (build it: cargo build -p pam-firmware --bin pil \
                     --features pam-firmware/firmware --release --target thumbv7em-none-eabihf)",
                    opts.elf.display()
                ),
            ));
        }
        let mut child = Command::new(&opts.qemu)
            .args([
                "-machine",
                "netduinoplus2",
                "-display",
                "none",
                "-monitor",
                "none",
                "-serial",
                "none",
                "-semihosting-config",
                "enable=on,target=native",
                "-kernel",
            ])
            .arg(&opts.elf)
            .args(&opts.extra_args)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| {
                err(
                    0,
                    format!(
                        "cannot start {}: {e} (install QEMU: scripts/setup.sh)",
                        opts.qemu.display()
                    ),
                )
            })?;
        let mut stdout = child.stdout.take().expect("piped");
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            let mut chunk = [0u8; 4096];
            loop {
                match stdout.read(&mut chunk) {
                    Ok(0) | Err(_) => break,
                    Ok(n) => {
                        if tx.send(chunk[..n].to_vec()).is_err() {
                            break;
                        }
                    }
                }
            }
        });
        let stdin = child.stdin.take();
        let mut q = QemuFirmware {
            child,
            stdin,
            rx,
            buf: Vec::new(),
            opts,
            log: Vec::new(),
        };
        let dt_s = 1.0 / scenario.scenario.tick_hz;
        let scaling = pam_firmware::wiring::pressure_scaling();
        let cfg = RunConfig {
            tick_hz: scenario.scenario.tick_hz as f32,
            dt_s: dt_s as f32,
            pa_per_count: scaling.pa_per_count,
            offset_pa: scaling.offset_pa,
            counts_per_rev: pam_firmware::wiring::ENCODER_COUNTS_PER_REV,
        };
        let mut b = [0u8; CONFIG_LEN];
        cfg.encode(&mut b);
        q.send(0, &b)?;
        Ok(q)
    }

    fn send(&mut self, tick: usize, bytes: &[u8]) -> Result<(), ClosedLoopError> {
        let r = match self.stdin.as_mut() {
            Some(w) => w.write_all(bytes).and_then(|_| w.flush()),
            None => Err(std::io::Error::other("stdin closed")),
        };
        r.map_err(|e| self.dead(tick, &format!("cannot send to QEMU: {e}")))
    }

    /// The error for a QEMU that stopped answering: its exit status, its stderr and any
    /// `PIL-FAULT` text it printed.
    fn dead(&mut self, tick: usize, what: &str) -> ClosedLoopError {
        // Give QEMU a moment to exit, then collect what it said.
        let t0 = Instant::now();
        let status = loop {
            match self.child.try_wait() {
                Ok(Some(s)) => break Some(s),
                Ok(None) if t0.elapsed() < Duration::from_secs(2) => {
                    std::thread::sleep(Duration::from_millis(20))
                }
                _ => {
                    let _ = self.child.kill();
                    break self.child.wait().ok();
                }
            }
        };
        while let Ok(c) = self.rx.try_recv() {
            self.buf.extend(c);
        }
        let text = String::from_utf8_lossy(&self.buf);
        let fault = text
            .lines()
            .find(|l| l.contains("PIL-FAULT"))
            .map(|l| l[l.find("PIL-FAULT").unwrap_or(0)..].trim().to_string());
        let mut stderr = String::new();
        if let Some(mut e) = self.child.stderr.take() {
            let _ = e.read_to_string(&mut stderr);
        }
        let mut msg = what.to_string();
        if let Some(f) = fault {
            msg.push_str(&format!("; the firmware reported `{f}`"));
        }
        if let Some(s) = status {
            msg.push_str(&format!("; QEMU exited with {s}"));
        }
        // QEMU's first line in the message; a register dump or other long output after a
        // "details:" tail of a few lines, not in the one-line error.
        let mut lines = stderr
            .lines()
            .map(str::trim_end)
            .filter(|l| !l.trim().is_empty());
        if let Some(first) = lines.next() {
            msg.push_str(&format!("; QEMU said: {}", first.trim()));
            let rest: Vec<&str> = lines.collect();
            if !rest.is_empty() {
                const DETAIL_LINES: usize = 4;
                msg.push_str("\n  details:");
                for l in rest.iter().take(DETAIL_LINES) {
                    msg.push_str(&format!("\n    {l}"));
                }
                if rest.len() > DETAIL_LINES {
                    msg.push_str(&format!(
                        "\n    ... ({} more lines of QEMU output)",
                        rest.len() - DETAIL_LINES
                    ));
                }
            }
        }
        err(tick, msg)
    }

    /// Waits for the next valid record (skipping anything else), at most the tick timeout.
    fn next_record(&mut self, tick: usize) -> Result<TickRecord, ClosedLoopError> {
        let deadline = Instant::now() + self.opts.tick_timeout;
        loop {
            // Resynchronise on the sync bytes; keep text (a fault message) for the error.
            while self.buf.len() >= RECORD_LEN {
                match TickRecord::decode(&self.buf) {
                    Ok(r) => {
                        self.log.extend_from_slice(&self.buf[..RECORD_LEN]);
                        self.buf.drain(..RECORD_LEN);
                        return Ok(r);
                    }
                    Err(_) => {
                        if self.buf.starts_with(b"PIL-FAULT") {
                            break;
                        }
                        let skip = self.buf[1..]
                            .windows(2)
                            .position(|w| w == &RECORD_SYNC[..])
                            .map(|p| p + 1)
                            .unwrap_or(self.buf.len() - 1);
                        self.buf.drain(..skip);
                    }
                }
            }
            if self.buf.starts_with(b"PIL-FAULT") {
                return Err(self.dead(tick, "the firmware faulted"));
            }
            let left = deadline.saturating_duration_since(Instant::now());
            match self.rx.recv_timeout(left) {
                Ok(c) => self.buf.extend(c),
                Err(RecvTimeoutError::Timeout) => {
                    let _ = self.child.kill();
                    return Err(self.dead(
                        tick,
                        &format!(
                            "no record from the firmware within {:.1} s",
                            self.opts.tick_timeout.as_secs_f64()
                        ),
                    ));
                }
                Err(RecvTimeoutError::Disconnected) => {
                    return Err(self.dead(tick, "QEMU closed its output"));
                }
            }
        }
    }

    /// Sends the stop frame and waits (bounded) for QEMU to exit with status 0.
    pub fn finish(mut self, ticks: usize) -> Result<Vec<u8>, ClosedLoopError> {
        let stop = SensorInput {
            seq: ticks as u32,
            setpoint_rad: 0.0,
            p_counts: [MISSING_COUNTS; 2],
            encoder_counts: MISSING_ENCODER,
            flags: FLAG_STOP,
            reset: RESET_NONE,
            dt_s: 0.0,
        };
        let mut b = [0u8; INPUT_LEN];
        stop.encode(&mut b);
        self.send(ticks, &b)?;
        self.stdin = None;
        let t0 = Instant::now();
        loop {
            match self.child.try_wait() {
                Ok(Some(s)) if s.success() => return Ok(std::mem::take(&mut self.log)),
                Ok(Some(_)) => return Err(self.dead(ticks, "QEMU failed at the end of the run")),
                Ok(None) if t0.elapsed() < self.opts.tick_timeout => {
                    std::thread::sleep(Duration::from_millis(10))
                }
                _ => {
                    let _ = self.child.kill();
                    return Err(self.dead(ticks, "QEMU did not exit after the stop frame"));
                }
            }
        }
    }
}

impl Drop for QemuFirmware {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

impl Firmware for QemuFirmware {
    fn tick(&mut self, k: usize, input: &FirmwareInput) -> Result<FirmwareTick, ClosedLoopError> {
        let FirmwareInput::Raw(input) = input else {
            return Err(err(
                k,
                "processor in the loop needs the sensors in board counts \
                 ([sensors] board_counts = true)",
            ));
        };
        let mut b = [0u8; INPUT_LEN];
        input.encode(&mut b);
        self.send(k, &b)?;
        let r = self.next_record(k)?;
        if r.seq != k as u32 {
            return Err(err(
                k,
                format!("stream out of sequence: record {} for tick {k}", r.seq),
            ));
        }
        Ok(FirmwareTick {
            pins: std::array::from_fn(|i| r.openings[i] >= 0.5),
            out: TickOutput {
                valves: ValveCommand::default(),
                p1_set_gauge_pa: 0.0,
                p2_set_gauge_pa: 0.0,
                torque_des_nm: 0.0,
                torque_est_nm: 0.0,
                angle_est_rad: if r.angle_rad.is_finite() {
                    r.angle_rad
                } else {
                    0.0
                },
                velocity_est_rad_s: 0.0,
                fault: FaultCode::from_code(r.fault),
                armed: r.armed,
                // Not in the stream record.
                active: pam_firmware::safety::FaultSet::EMPTY,
            },
        })
    }
}

/// The first tick where two runs differ on the valve columns or the angle (bit for bit),
/// as `(tick, field, a, b)`; `None` when they agree on every tick of both.
pub fn first_difference(
    a: &crate::control::closed_loop::ClosedLoopRun,
    b: &crate::control::closed_loop::ClosedLoopRun,
) -> Option<(usize, &'static str, f64, f64)> {
    let n = a.rows.len().min(b.rows.len());
    for k in 0..n {
        let (ra, rb) = (&a.rows[k], &b.rows[k]);
        let fields = [
            ("u_in1", ra.inputs.u_in1, rb.inputs.u_in1),
            ("u_ex1", ra.inputs.u_ex1, rb.inputs.u_ex1),
            ("u_in2", ra.inputs.u_in2, rb.inputs.u_in2),
            ("u_ex2", ra.inputs.u_ex2, rb.inputs.u_ex2),
            ("angle", ra.state.angle_rad, rb.state.angle_rad),
        ];
        for (name, x, y) in fields {
            if x.to_bits() != y.to_bits() {
                return Some((k, name, x, y));
            }
        }
    }
    if a.rows.len() != b.rows.len() {
        return Some((n, "ticks", a.rows.len() as f64, b.rows.len() as f64));
    }
    None
}

/// Arguments of `host-sim pil`.
/// `pil`'s firmware image without `--elf`, relative to the working directory.
pub const DEFAULT_ELF_IN_WORKING_DIR: &str = "target/thumbv7em-none-eabihf/release/pil";

#[derive(Debug)]
pub struct PilArgs {
    /// Plant parameter file (TOML).
    pub plant: PathBuf,
    /// Closed-loop scenario (TOML). The firmware gets raw board counts: the scenario's
    /// [sensors] run with `board_counts = true` (turned on, and said, when the file leaves it
    /// off). Its [expect] bounds are checked on the firmware's run (exit status 1 if not met).
    pub scenario: PathBuf,
    /// Output recording (RECORDING.md), as `simulate --scenario` writes it.
    pub out: PathBuf,
    /// Firmware image [default: target/thumbv7em-none-eabihf/release/pil under the working
    /// directory].
    pub elf: Option<PathBuf>,
    /// Also write the firmware's per-tick stream (binary records) here, for `host-sim capture`.
    pub log: Option<PathBuf>,
    /// Longest wait for one tick's answer from QEMU [s] (1..=600).
    pub tick_timeout_s: f64,
}

/// `host-sim pil`: runs the scenario with the firmware under QEMU, writes the recording,
/// checks the scenario's `[expect]` on it (the summary `simulate --scenario` prints), then
/// runs the in-process loop on the same scenario and compares them bit for bit (valve
/// columns and angle). Both run with the sensors in board counts (`[sensors] board_counts`
/// is turned on when the scenario leaves it off). Returns the report and whether the runs
/// matched and the expectations were met.
pub fn run_pil(a: &PilArgs) -> anyhow::Result<(String, bool)> {
    use anyhow::Context;
    if !(a.tick_timeout_s >= 1.0 && a.tick_timeout_s <= 600.0) {
        anyhow::bail!(
            "--tick-timeout-s {}: outside the allowed range 1..=600 s",
            a.tick_timeout_s
        );
    }
    let mut inputs = vec![
        ("--plant", a.plant.as_path()),
        ("--scenario", a.scenario.as_path()),
    ];
    if let Some(elf) = &a.elf {
        inputs.push(("--elf", elf.as_path()));
    }
    let mut outputs = vec![("--out", a.out.as_path())];
    if let Some(log) = &a.log {
        outputs.push(("--log", log.as_path()));
    }
    crate::validate::distinct_file_outputs(&inputs, &outputs).map_err(anyhow::Error::msg)?;
    // The default image is the one under the working directory (a checkout's build), never
    // the build tree host-sim itself was compiled in: that could be another checkout's
    // firmware.
    let elf = a
        .elf
        .clone()
        .unwrap_or_else(|| PathBuf::from(DEFAULT_ELF_IN_WORKING_DIR));
    check_elf(&elf).map_err(|e| {
        anyhow::anyhow!(
            "{} {}: {e}",
            if a.elf.is_some() {
                "--elf"
            } else {
                "the default firmware image (no --elf; under the working directory)"
            },
            elf.display()
        )
    })?;
    let plant = crate::plant::Plant::load(&a.plant)?;
    let (text, file) = crate::io::scenario::read_scenario_text(&a.scenario)?;
    let mut scenario = Scenario::from_toml_str(&text, &file)?;
    // The image runs the reference configuration.
    let limit_rad =
        pam_firmware::tick::ControllerConfig::reference(scenario.scenario.tick_hz as f32)
            .angle_setpoint_max_rad;
    scenario.setpoint.check_within(&text, &file, limit_rad)?;
    let forced = !scenario.sensors.board_counts;
    scenario.sensors.board_counts = true;
    let mut opts = PilOptions::new(elf.clone());
    opts.tick_timeout = Duration::from_secs_f64(a.tick_timeout_s);
    let (run, log) = run_scenario(&plant, &scenario, opts).with_context(|| {
        format!(
            "processor-in-the-loop run of the image {} on {} failed",
            elf.display(),
            a.scenario.display()
        )
    })?;
    let mut rec = crate::control::run_files::run_recording(
        &run,
        &a.plant.display().to_string(),
        &a.scenario.display().to_string(),
        None,
    );
    rec.metadata.push((
        "firmware".into(),
        "QEMU netduinoplus2 image src/bin/pil.rs (processor in the loop)".into(),
    ));
    if let Some(p) = &a.log {
        crate::io::recording::write_atomically(p, |w| w.write_all(&log))
            .with_context(|| format!("{}: cannot write the stream log", p.display()))?;
    }
    rec.write(&a.out)?;
    let cfg = pam_firmware::tick::ControllerConfig::reference(scenario.scenario.tick_hz as f32);
    let reference = crate::control::closed_loop::run_with(&plant, &scenario, cfg, &mut |_| {})?;
    let mut report = String::new();
    if forced {
        report.push_str(
            "the scenario's sensors run in board counts for this comparison \
             ([sensors] board_counts = true; `simulate --scenario` reproduces it with that key)\n",
        );
    }
    report.push_str(&format!(
        "wrote {}: {} ticks from the firmware under QEMU ({} stream bytes, {} per tick)\n",
        a.out.display(),
        run.rows.len(),
        log.len(),
        RECORD_LEN
    ));
    let difference = first_difference(&run, &reference);
    // The pressure set-points are not in the firmware's stream record: those of the
    // in-process run of the same firmware code, when the two runs match bit for bit (else
    // unknown, and the summary says so).
    let mut run = run;
    run.max_p_set_gauge_pa = match difference {
        None => reference.max_p_set_gauge_pa,
        Some(_) => f64::NAN,
    };
    let fails = run.check();
    report.push_str(&crate::control::run_files::summary(&run, &scenario, &fails));
    let same = match difference {
        None => {
            report.push_str(&format!(
                "matches the in-process closed loop bit for bit on all {} ticks (u_in1, u_ex1, \
                 u_in2, u_ex2, angle)\n",
                run.rows.len()
            ));
            true
        }
        Some((k, field, x, y)) => {
            report.push_str(&format!(
                "MISMATCH with the in-process closed loop: first at tick {k} (t = {:.6} s), \
                 field {field}: QEMU {x:e}, in-process {y:e}\n",
                k as f64 / scenario.scenario.tick_hz
            ));
            false
        }
    };
    Ok((report, same && fails.is_empty()))
}

/// Checks that `elf` can be a firmware image for the board before QEMU is started: an
/// existing, non-empty regular file with an ELF header for 32-bit little-endian ARM (what
/// `cargo build --target thumbv7em-none-eabihf` writes). Reads the 20 header bytes only.
pub fn check_elf(elf: &std::path::Path) -> Result<(), String> {
    check_elf_for(
        elf,
        "build it: cargo build -p pam-firmware --bin pil --features pam-firmware/firmware \
         --release --target thumbv7em-none-eabihf",
    )
}

/// Runs `scenario` on `plant` with the firmware under QEMU; returns the run and the stream.
pub fn run_scenario(
    plant: &crate::plant::Plant,
    scenario: &Scenario,
    opts: PilOptions,
) -> Result<(crate::control::closed_loop::ClosedLoopRun, Vec<u8>), ClosedLoopError> {
    let mut fw = QemuFirmware::start(opts, scenario)?;
    let run =
        crate::control::closed_loop::run_with_firmware(plant, scenario, &mut fw, &mut |_| {})?;
    let log = fw.finish(run.rows.len())?;
    Ok((run, log))
}
