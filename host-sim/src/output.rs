//! The rule every output of host-sim follows (files and report folders), beside the atomic
//! writer ([`crate::io::atomic`]) that writes them:
//!
//! - **host-sim replaces only what host-sim wrote.** Every file it writes carries a mark
//!   ([`MARK`]): a `# generator = host-sim VERSION` first line in CSV and TOML (a recording's
//!   metadata line), a `"generator"` field in a JSON object, an `<!-- generator = ... -->`
//!   comment in HTML and SVG, a `tEXt` chunk in PNG. A folder output (`--report DIR`,
//!   `--out-dir DIR`) also lists its files in a manifest ([`MANIFEST`]). An existing file
//!   without the mark, not listed in its folder's manifest, is refused before any work
//!   (exit status 2, the file named) unless the user passes `--force` ([`set_force`]);
//!   other files in an output folder are never touched.
//! - **A file not writable by its permission bits is refused** (not renamed over; `--force`
//!   replaces it), and every output folder is probed writable (a file created and removed)
//!   before the work.
//! - **Temporary files do not outlive the run**: they are named `.NAME.XXXXXX.tmp.EXT`
//!   `.NAME.PID.XXXXXX.tmp.EXT` ([`temp_name_pid`]); SIGINT and SIGTERM remove the run's own
//!   ([`crate::io::atomic::install_interrupt_cleanup`]), and those of a killed run (SIGKILL, power loss: its
//!   process is gone) are removed by the next run writing in that folder
//!   ([`remove_stale_temps`]).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;

/// The mark's key; its value is `host-sim VERSION`.
pub const MARK_KEY: &str = "generator";

/// The mark's value.
pub const MARK: &str = concat!("host-sim ", env!("CARGO_PKG_VERSION"));

/// The manifest of a folder output: one file name per line (after a mark line).
pub const MANIFEST: &str = ".host-sim-outputs";

static FORCE: AtomicBool = AtomicBool::new(false);

/// `--force`: replace existing files that host-sim did not write (and read-only ones).
pub fn set_force(on: bool) {
    FORCE.store(on, Ordering::Relaxed);
}

/// Whether `--force` was given.
pub fn forced() -> bool {
    FORCE.load(Ordering::Relaxed)
}

/// Bytes of an existing file read to find its mark.
const HEAD_BYTES: u64 = 64 << 10;

/// Whether `head` (the start of a file) carries host-sim's mark.
pub fn has_mark(head: &[u8]) -> bool {
    const PATTERNS: [&[u8]; 3] = [
        b"generator = host-sim",      // `#` comment / HTML, SVG comment
        b"\"generator\": \"host-sim", // JSON
        b"generator\0host-sim",       // PNG tEXt
    ];
    PATTERNS
        .iter()
        .any(|p| head.windows(p.len()).any(|w| w == *p))
}

/// Whether the file at `path` carries host-sim's mark (read from its first 64 KiB).
pub fn written_by_host_sim(path: &Path) -> bool {
    use std::io::Read as _;
    let mut head = Vec::new();
    std::fs::File::open(path)
        .and_then(|f| f.take(HEAD_BYTES).read_to_end(&mut head))
        .is_ok()
        && has_mark(&head)
}

/// The mark to insert into a file whose content starts with `first` (the first bytes
/// written): `(offset, bytes)`, or `None` when it has one already or is binary.
pub(crate) fn mark_for(first: &[u8]) -> Option<(usize, Vec<u8>)> {
    if first.is_empty() || has_mark(&first[..first.len().min(HEAD_BYTES as usize)]) {
        return None;
    }
    if first.starts_with(b"\x89PNG") || first[..first.len().min(512)].contains(&0) {
        return None; // binary: PNG is marked by `mark_png`
    }
    let start = first.iter().position(|b| !b.is_ascii_whitespace())?;
    match first[start] {
        b'{' => {
            let rest = &first[start + 1..];
            let empty = rest
                .iter()
                .find(|b| !b.is_ascii_whitespace())
                .is_some_and(|&b| b == b'}');
            let sep = if empty { "\n" } else { "," };
            Some((
                start + 1,
                format!("\n  \"{MARK_KEY}\": \"{MARK}\"{sep}").into_bytes(),
            ))
        }
        b'<' => {
            // After an XML declaration (it must come first), else at the start.
            let at = if first[start..].starts_with(b"<?xml") {
                first
                    .windows(2)
                    .position(|w| w == b"?>")
                    .map_or(0, |i| i + 2)
            } else {
                0
            };
            Some((at, format!("\n<!-- {MARK_KEY} = {MARK} -->\n").into_bytes()))
        }
        _ => Some((0, format!("# {MARK_KEY} = {MARK}\n").into_bytes())),
    }
}

/// Whether content starting with `first` is binary other than PNG (no mark fits in it).
pub(crate) fn is_binary(first: &[u8]) -> bool {
    !first.starts_with(b"\x89PNG") && first[..first.len().min(512)].contains(&0)
}

/// Marks the PNG file at `path` with a `tEXt` chunk (`generator`, [`MARK`]) after its
/// header chunk; another file is left as it is.
pub(crate) fn mark_png(path: &Path) -> std::io::Result<()> {
    let bytes = std::fs::read(path)?;
    // Signature (8) + IHDR chunk (4 length + 4 type + 13 data + 4 CRC).
    const AFTER_IHDR: usize = 33;
    if !bytes.starts_with(b"\x89PNG\r\n\x1a\n")
        || bytes.len() < AFTER_IHDR
        || &bytes[12..16] != b"IHDR"
        || has_mark(&bytes[..bytes.len().min(HEAD_BYTES as usize)])
    {
        return Ok(());
    }
    let mut data = format!("{MARK_KEY}\0{MARK}").into_bytes();
    let mut chunk = Vec::with_capacity(data.len() + 12);
    chunk.extend_from_slice(&(data.len() as u32).to_be_bytes());
    let mut typed = b"tEXt".to_vec();
    typed.append(&mut data);
    chunk.extend_from_slice(&typed);
    chunk.extend_from_slice(&crc32(&typed).to_be_bytes());
    let mut out = Vec::with_capacity(bytes.len() + chunk.len());
    out.extend_from_slice(&bytes[..AFTER_IHDR]);
    out.extend_from_slice(&chunk);
    out.extend_from_slice(&bytes[AFTER_IHDR..]);
    std::fs::write(path, out)
}

/// Marks the file at `path` written by another writer (plotters): a PNG by [`mark_png`],
/// a text file (SVG) by [`mark_for`].
pub(crate) fn mark_file(path: &Path) -> std::io::Result<()> {
    let bytes = std::fs::read(path)?;
    if bytes.starts_with(b"\x89PNG") {
        return mark_png(path);
    }
    if let Some((at, mark)) = mark_for(&bytes) {
        let mut out = bytes;
        out.splice(at..at, mark);
        std::fs::write(path, out)?;
    }
    Ok(())
}

/// CRC-32 (ISO-HDLC, the PNG chunk checksum), bitwise: only the short mark chunk uses it.
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// The file names the manifest of `dir` lists (empty without one).
pub fn manifest_of(dir: &Path) -> Vec<String> {
    std::fs::read_to_string(dir.join(MANIFEST))
        .map(|t| {
            t.lines()
                .map(str::trim)
                .filter(|l| !l.is_empty() && !l.starts_with('#'))
                .map(str::to_owned)
                .collect()
        })
        .unwrap_or_default()
}

/// The manifest of `dir` once `files` (paths inside `dir`) are added to the files it listed
/// already: its path and its text (written by [`crate::io::atomic::write_manifest`]).
pub fn manifest_with(dir: &Path, files: &[PathBuf]) -> (PathBuf, String) {
    let mut names = manifest_of(dir);
    for f in files {
        let rel = f.strip_prefix(dir).unwrap_or(f);
        let name = rel.to_string_lossy().into_owned();
        if !names.contains(&name) {
            names.push(name);
        }
    }
    names.sort();
    let text = format!(
        "# The files host-sim wrote in this folder (it replaces only these; other files here \
         are never touched).\n{}\n",
        names.join("\n")
    );
    (dir.join(MANIFEST), text)
}

/// Whether `path`'s permission bits let no one write it (0444): refused, not renamed over.
fn read_only(meta: &std::fs::Metadata) -> Option<String> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt as _;
        let mode = meta.permissions().mode() & 0o7777;
        (mode & 0o222 == 0).then(|| format!("is read-only (mode {mode:04o})"))
    }
    #[cfg(not(unix))]
    {
        meta.permissions().readonly().then(|| "is read-only".into())
    }
}

/// The rule for one output file, checked before any work: `Err` naming `flag` and `path`
/// when an existing file there would be replaced although host-sim did not write it (no
/// mark, not in its folder's manifest) or it is read-only, unless `--force`; also when its
/// folder cannot be written. An absent or empty file is replaceable.
pub fn check_file(flag: &str, path: &Path) -> Result<(), String> {
    let dir = dir_of(path);
    if dir.is_dir() {
        probe_writable(flag, &dir)?;
        remove_stale_temps(&dir);
    }
    let Ok(meta) = std::fs::metadata(path) else {
        return Ok(());
    };
    if !meta.is_file() {
        return Err(format!(
            "{flag} {}: exists and is not a regular file; give a file path",
            path.display()
        ));
    }
    if forced() {
        return Ok(());
    }
    if let Some(ro) = read_only(&meta) {
        return Err(format!(
            "{flag} {}: {ro}; host-sim does not replace a file its owner made read-only: give \
             another file, or pass --force to replace it",
            path.display()
        ));
    }
    if meta.len() == 0 || written_by_host_sim(path) || listed_in_manifest(path) {
        return Ok(());
    }
    Err(format!(
        "{flag} {}: exists and was not written by host-sim (it has no `{MARK_KEY} = host-sim` \
         mark); host-sim replaces only its own outputs: give another file, move this one away, \
         or pass --force to replace it",
        path.display()
    ))
}

/// The rule for a folder output (`--report DIR`, `--out-dir DIR`) and the `files` the run
/// writes in it: the folder is absent (created) or a writable directory, and each of the
/// files passes [`check_file`] (a file its manifest lists is the folder's own).
pub fn check_dir(flag: &str, dir: &Path, files: &[PathBuf]) -> Result<(), String> {
    if dir.exists() && !dir.is_dir() {
        return Err(format!(
            "{flag} {}: exists and is not a directory; give a directory (created if missing)",
            dir.display()
        ));
    }
    // The folder, or the nearest existing folder above it (where it will be created).
    let mut existing = dir.to_path_buf();
    while !existing.is_dir() {
        match existing.parent() {
            Some(p) if !p.as_os_str().is_empty() => existing = p.to_path_buf(),
            _ => {
                existing = PathBuf::from(".");
                break;
            }
        }
    }
    probe_writable(flag, &existing)?;
    for f in files {
        check_file(flag, f)?;
    }
    Ok(())
}

/// Whether host-sim wrote the file at `path`: it carries the mark, or its folder's manifest
/// lists it.
pub fn is_own(path: &Path) -> bool {
    written_by_host_sim(path) || listed_in_manifest(path)
}

fn listed_in_manifest(path: &Path) -> bool {
    let Some(name) = path.file_name() else {
        return false;
    };
    let name = name.to_string_lossy();
    let dir = dir_of(path);
    if manifest_of(&dir).iter().any(|n| *n == name) {
        return true;
    }
    // A file of a sub-folder the parent's manifest lists (`joint1/index.html`).
    match (dir.parent(), dir.file_name()) {
        (Some(up), Some(sub)) if !up.as_os_str().is_empty() => {
            let rel = format!("{}/{name}", sub.to_string_lossy());
            manifest_of(up).contains(&rel)
        }
        _ => false,
    }
}

pub(crate) fn dir_of(path: &Path) -> PathBuf {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_owned(),
        _ => PathBuf::from("."),
    }
}

/// Creates and removes a probe file in `dir`: an unwritable output folder is found before
/// the work, not by the rename after it.
pub fn probe_writable(flag: &str, dir: &Path) -> Result<(), String> {
    let probe = dir.join(format!(".host-sim-probe.{}.tmp", std::process::id()));
    match std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
    {
        Ok(f) => {
            drop(f);
            let _ = std::fs::remove_file(&probe);
            Ok(())
        }
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
            let _ = std::fs::remove_file(&probe);
            Ok(())
        }
        Err(e) => Err(format!(
            "{flag}: cannot write in the folder {}: {e}",
            dir.display()
        )),
    }
}

/// The process id in `name` when it is a temporary file name of the atomic writer,
/// `.NAME.PID.XXXXXX.tmp[.EXT]` (six random characters), or of a writability probe,
/// `.host-sim-probe.PID.tmp`; `Some(None)` for an earlier version's `.NAME.XXXXXX.tmp[.EXT]`;
/// `None` for any other name.
pub fn temp_name_pid(name: &str) -> Option<Option<u32>> {
    if let Some(pid) = name
        .strip_prefix(".host-sim-probe.")
        .and_then(|r| r.strip_suffix(".tmp"))
    {
        return pid.parse().ok().map(Some);
    }
    let body = name.strip_prefix('.')?;
    let i = body.rfind(".tmp")?;
    let after = &body[i + 4..];
    if !(after.is_empty() || (after.starts_with('.') && !after[1..].contains('.'))) {
        return None;
    }
    let (target, rand) = body[..i].rsplit_once('.')?;
    if target.is_empty()
        || rand.len() != TEMP_RANDOM_LEN
        || !rand.chars().all(|c| c.is_ascii_alphanumeric())
    {
        return None;
    }
    match target.rsplit_once('.') {
        Some((t, pid)) if !t.is_empty() && pid.bytes().all(|b| b.is_ascii_digit()) => {
            pid.parse().ok().map(Some)
        }
        _ => Some(None),
    }
}

/// Whether `name` is a temporary file name of host-sim ([`temp_name_pid`]).
pub fn is_temp_name(name: &str) -> bool {
    temp_name_pid(name).is_some()
}

/// Random characters in a temporary file name.
pub(crate) const TEMP_RANDOM_LEN: usize = 6;

/// Whether process `pid` is running (`true` where that cannot be told).
fn process_alive(pid: u32) -> bool {
    if pid == std::process::id() {
        return true;
    }
    #[cfg(target_os = "linux")]
    {
        Path::new("/proc").join(pid.to_string()).exists()
    }
    #[cfg(not(target_os = "linux"))]
    {
        true
    }
}

/// Removes the temporary files a killed run (SIGKILL, power loss) left in `dir`, saying so
/// on stderr: those whose process is gone, and an earlier version's (no process id in the
/// name) older than an hour. Those of a run still going are named, not touched. Returns the
/// paths removed.
pub fn remove_stale_temps(dir: &Path) -> Vec<PathBuf> {
    let mut removed = Vec::new();
    let Ok(entries) = std::fs::read_dir(dir) else {
        return removed;
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(pid) = temp_name_pid(&name) else {
            continue;
        };
        let Ok(meta) = e.metadata() else { continue };
        if !meta.is_file() || pid == Some(std::process::id()) {
            continue;
        }
        let stale = match pid {
            Some(pid) => !process_alive(pid),
            None => meta
                .modified()
                .ok()
                .and_then(|m| m.elapsed().ok())
                .is_some_and(|a| a >= std::time::Duration::from_secs(3600)),
        };
        if stale {
            if std::fs::remove_file(e.path()).is_ok() {
                eprintln!(
                    "note: removed {}: a temporary file of an interrupted host-sim run",
                    e.path().display()
                );
                removed.push(e.path());
            }
        } else if REPORTED
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .insert(e.path())
        {
            eprintln!(
                "note: {} is a temporary file of another host-sim run still going (left as it is)",
                e.path().display()
            );
        }
    }
    removed
}

static REPORTED: Mutex<std::collections::BTreeSet<PathBuf>> =
    Mutex::new(std::collections::BTreeSet::new());

/// Temporary files of this run not yet renamed or removed.
static LIVE: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// Set once an interrupt arrived: no new temporary file is created after it.
static INTERRUPTED: AtomicBool = AtomicBool::new(false);

fn live() -> std::sync::MutexGuard<'static, Vec<PathBuf>> {
    LIVE.lock().unwrap_or_else(|p| p.into_inner())
}

/// Records a temporary file of this run (removed on an interrupt); `Err` once interrupted.
pub(crate) fn register_temp(path: &Path) -> std::io::Result<()> {
    if INTERRUPTED.load(Ordering::SeqCst) {
        let _ = std::fs::remove_file(path);
        return Err(std::io::Error::new(
            std::io::ErrorKind::Interrupted,
            "interrupted",
        ));
    }
    live().push(path.to_owned());
    Ok(())
}

/// Forgets a temporary file (renamed into place or removed).
pub(crate) fn forget_temp(path: &Path) {
    live().retain(|p| p != path);
}

/// Removes every temporary file of this run (an interrupt).
pub fn remove_live_temps() {
    let paths = std::mem::take(&mut *live());
    for p in paths {
        let _ = std::fs::remove_file(&p);
    }
}

/// Marks the run as interrupted: temporary files registered from now on are removed at once.
pub fn mark_interrupted() {
    INTERRUPTED.store(true, Ordering::SeqCst);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temp_names_of_the_atomic_writer_are_recognised_and_user_names_are_not() {
        assert_eq!(
            temp_name_pid(".sim.csv.4242.Ab3xYz.tmp.csv"),
            Some(Some(4242))
        );
        assert_eq!(temp_name_pid(".host-sim-probe.1234.tmp"), Some(Some(1234)));
        assert_eq!(temp_name_pid(".sim.csv.Ab3xYz.tmp.csv"), Some(None));
        assert!(is_temp_name(".index.html.77.q1w2e3.tmp.html"));
        assert!(is_temp_name(".noext.aaaaaa.tmp"));
        assert!(!is_temp_name("sim.csv"));
        assert!(!is_temp_name(".bashrc"));
        assert!(!is_temp_name(".sim.csv.tmp.csv"));
        assert!(!is_temp_name(".sim.csv.toolong7.tmp.csv"));
        assert!(!is_temp_name("notes.tmp"));
    }

    #[test]
    fn marks_go_where_each_format_allows_a_comment() {
        let (at, m) = mark_for(b"t_s,u_in1\n0,0\n").unwrap();
        assert_eq!(at, 0);
        assert!(has_mark(&m));
        let (at, m) = mark_for(b"{\n  \"verdict\": 1\n}\n").unwrap();
        let mut j = b"{\n  \"verdict\": 1\n}\n".to_vec();
        j.splice(at..at, m);
        let v: serde_json::Value = serde_json::from_slice(&j).unwrap();
        assert_eq!(v[MARK_KEY], MARK);
        assert_eq!(v["verdict"], 1);
        let mut e = b"{}".to_vec();
        let (at, m) = mark_for(&e).unwrap();
        e.splice(at..at, m);
        assert!(serde_json::from_slice::<serde_json::Value>(&e).is_ok());
        let x = b"<?xml version=\"1.0\"?>\n<svg/>";
        let (at, _) = mark_for(x).unwrap();
        assert_eq!(at, 21);
        assert!(mark_for(b"# generator = host-sim 0.1.0\nt_s\n").is_none());
    }

    #[test]
    fn the_png_mark_is_a_valid_chunk() {
        // CRC-32 of "IEND" is the constant every PNG ends with.
        assert_eq!(crc32(b"IEND"), 0xAE42_6082);
    }
}
