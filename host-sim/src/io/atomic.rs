//! The one atomic file writer of host-sim: every output (CSV, TOML, PNG, SVG, HTML, JSON) goes
//! through here.
//!
//! A file is written to a temporary file in the target's directory (same file system, so the
//! final rename is atomic), flushed and synced, given the permissions of the file it replaces
//! (or 0644), then renamed over the target. A failed write never leaves a half-written target.
//!
//! A command writing several files opens a [`Transaction`] first: while it is open, finished
//! files are *staged* (kept as temporary files) instead of renamed, and only
//! [`Transaction::commit`] renames them all, after the whole run succeeded. Dropping the
//! transaction without committing (an error anywhere in the run) deletes the staged files and
//! the directories the run created: a failed run leaves nothing behind and the user's files as
//! they were. Without a transaction (library use, tests) each write is renamed at once.
//!
//! Every file written here carries host-sim's mark, and temporary files are registered for
//! removal on an interrupt: the rules of [`crate::output`].

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use tempfile::TempPath;

/// Staged files and created directories of the open transaction (`None`: no transaction).
static STAGE: Mutex<Option<Stage>> = Mutex::new(None);

#[derive(Default)]
struct Stage {
    /// (temporary file, target), in write order; one entry per target.
    files: Vec<(TempPath, PathBuf)>,
    /// Directories created by the run, outermost first.
    dirs: Vec<PathBuf>,
}

fn stage_lock() -> std::sync::MutexGuard<'static, Option<Stage>> {
    // A panic while holding the lock cannot leave the list inconsistent (pushes only).
    STAGE.lock().unwrap_or_else(|e| e.into_inner())
}

/// Writes `bytes` to `path` atomically (staged while a [`Transaction`] is open).
pub fn write_bytes(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    write_with(path, |w| w.write_all(bytes))
}

/// The buffered writer [`write_with`] hands out.
pub type Output<'a> = std::io::BufWriter<Writeback<'a>>;

/// Writes `path` atomically with `fill`, which writes the whole content into a buffered
/// writer; the target is replaced only after `fill` succeeded and the data is on disk.
/// Large outputs can be streamed: the data is handed to the disk as it is written
/// ([`Writeback`]), so the final sync waits for little more than the last megabyte.
pub fn write_with(
    path: &Path,
    fill: impl FnOnce(&mut Output<'_>) -> std::io::Result<()>,
) -> std::io::Result<()> {
    write_marked_with(path, true, fill)
}

/// Writes `bytes` to `path` atomically without host-sim's mark in it, for a table other
/// programs read (a spreadsheet takes a `#` line for a row): the caller lists it in its
/// folder's manifest ([`write_manifest`]), which marks it as host-sim's.
pub fn write_bytes_unmarked(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    write_marked_with(path, false, |w| w.write_all(bytes))
}

fn write_marked_with(
    path: &Path,
    mark: bool,
    fill: impl FnOnce(&mut Output<'_>) -> std::io::Result<()>,
) -> std::io::Result<()> {
    let tmp = temp_for(path)?;
    let binary = {
        let mut wb = Writeback::new(tmp.as_file());
        wb.marked = !mark;
        let mut w = std::io::BufWriter::new(wb);
        fill(&mut w)?;
        w.flush()?;
        w.get_ref().binary
    };
    finish(tmp, path)?;
    if binary {
        // No mark fits in a binary file (a firmware stream log): its folder's manifest
        // names it as host-sim's.
        let dir = crate::output::dir_of(path);
        write_manifest(&dir, &[path.to_path_buf()])?;
    }
    Ok(())
}

/// The temporary file of [`write_with`]: on Linux, every [`Writeback::EVERY_BYTES`] written
/// are handed to the disk at once (`sync_file_range(SYNC_FILE_RANGE_WRITE)`, which starts the
/// write-back without waiting for it), so that the `fsync` before the rename overlaps the
/// rest of the run instead of writing the whole file after it. Elsewhere a plain file.
pub struct Writeback<'a> {
    file: &'a std::fs::File,
    written: u64,
    started_to: u64,
    /// The first bytes were written (with host-sim's mark inserted where their format takes it).
    marked: bool,
    /// The content is binary (no mark fits in it): listed in its folder's manifest instead.
    binary: bool,
}

impl<'a> Writeback<'a> {
    /// Bytes between two write-back starts.
    pub const EVERY_BYTES: u64 = 256 * 1024;

    fn new(file: &'a std::fs::File) -> Self {
        Self {
            file,
            written: 0,
            started_to: 0,
            marked: false,
            binary: false,
        }
    }

    #[cfg(target_os = "linux")]
    fn start_writeback(&mut self) {
        use std::os::fd::AsRawFd as _;
        let len = self.written - self.started_to;
        if let (Ok(offset), Ok(len)) = (i64::try_from(self.started_to), i64::try_from(len)) {
            // SAFETY: a plain system call on a file descriptor this writer borrows (open for
            // its lifetime); it reads no memory of ours. A failure only means the final
            // fsync does all the work, as without this call.
            let _ = unsafe {
                libc::sync_file_range(
                    self.file.as_raw_fd(),
                    offset,
                    len,
                    libc::SYNC_FILE_RANGE_WRITE,
                )
            };
        }
        self.started_to = self.written;
    }

    #[cfg(not(target_os = "linux"))]
    fn start_writeback(&mut self) {
        self.started_to = self.written;
    }
}

impl std::io::Write for Writeback<'_> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        if !self.marked && !buf.is_empty() {
            self.marked = true;
            self.binary = crate::output::is_binary(buf);
            if let Some((at, mark)) = crate::output::mark_for(buf) {
                let mut f = self.file;
                f.write_all(&buf[..at])?;
                f.write_all(&mark)?;
                f.write_all(&buf[at..])?;
                self.written += (buf.len() + mark.len()) as u64;
                return Ok(buf.len());
            }
        }
        let n = self.file.write(buf)?;
        self.written += n as u64;
        if self.written - self.started_to >= Self::EVERY_BYTES {
            self.start_writeback();
        }
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.file.flush()
    }
}

/// Writes `path` atomically through a writer that needs a file *path* (plotters' backends):
/// `draw` gets the temporary file's path and must write the whole file there.
pub fn write_via_path<E>(
    path: &Path,
    draw: impl FnOnce(&Path) -> Result<(), E>,
) -> Result<(), ViaPathError<E>> {
    let tmp = temp_for(path).map_err(ViaPathError::Io)?;
    draw(tmp.path()).map_err(ViaPathError::Write)?;
    crate::output::mark_file(tmp.path()).map_err(ViaPathError::Io)?;
    finish(tmp, path).map_err(ViaPathError::Io)
}

/// Error of [`write_via_path`]: the writer's own error or an I/O error of the temporary file.
#[derive(Debug)]
pub enum ViaPathError<E> {
    /// The writer failed.
    Write(E),
    /// Creating, syncing or renaming the temporary file failed.
    Io(std::io::Error),
}

/// `std::fs::create_dir_all` that remembers, inside a [`Transaction`], which directories it
/// created, so that a failed run removes them again.
pub fn create_dir_all(dir: &Path) -> std::io::Result<()> {
    let mut missing = Vec::new();
    let mut d = Some(dir);
    while let Some(p) = d {
        if p.as_os_str().is_empty() || p.exists() {
            break;
        }
        missing.push(p.to_owned());
        d = p.parent();
    }
    std::fs::create_dir_all(dir)?;
    if let Some(stage) = stage_lock().as_mut() {
        missing.reverse();
        stage.dirs.extend(missing);
    }
    Ok(())
}

fn dir_of(path: &Path) -> PathBuf {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_owned(),
        _ => PathBuf::from("."),
    }
}

fn temp_for(path: &Path) -> std::io::Result<tempfile::NamedTempFile> {
    let name = path.file_name().ok_or_else(|| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("{}: not a file path", path.display()),
        )
    })?;
    let ext = path
        .extension()
        .map(|e| format!(".{}", e.to_string_lossy()))
        .unwrap_or_default();
    // The target's extension is kept: plotters picks the image encoder from it. The process
    // id tells a killed run's temporary file from a running one's (`output::temp_name_pid`).
    let tmp = tempfile::Builder::new()
        .prefix(&format!(
            ".{}.{}.",
            name.to_string_lossy(),
            std::process::id()
        ))
        .rand_bytes(crate::output::TEMP_RANDOM_LEN)
        .suffix(&format!(".tmp{ext}"))
        .tempfile_in(dir_of(path))?;
    crate::output::register_temp(tmp.path())?;
    Ok(tmp)
}

fn finish(tmp: tempfile::NamedTempFile, path: &Path) -> std::io::Result<()> {
    // Never rename over a directory, device or pipe (the commands refuse them up front; this
    // guards every other caller).
    if let Ok(m) = std::fs::metadata(path) {
        if !m.is_file() {
            return Err(std::io::Error::other(format!(
                "{}: exists and is not a regular file; not replaced",
                path.display()
            )));
        }
    }
    tmp.as_file().sync_all()?;
    set_output_permissions(tmp.as_file(), path)?;
    let tmp = tmp.into_temp_path();
    let mut guard = stage_lock();
    match guard.as_mut() {
        Some(stage) => {
            // A second write of the same target replaces the first staged one.
            stage.files.retain(|(_, t)| t != path);
            stage.files.push((tmp, path.to_owned()));
            Ok(())
        }
        None => {
            drop(guard);
            let t = tmp.to_path_buf();
            let r = tmp.persist(path).map_err(|e| e.error);
            crate::output::forget_temp(&t);
            r
        }
    }
}

/// Temporary files are created private (0600); give the output the permissions of the file
/// it replaces, or ordinary ones (0644) for a new file.
fn set_output_permissions(file: &std::fs::File, target: &Path) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let perm = match std::fs::metadata(target) {
            Ok(m) => m.permissions(),
            Err(_) => std::fs::Permissions::from_mode(0o644),
        };
        file.set_permissions(perm)?;
    }
    #[cfg(not(unix))]
    let _ = (file, target);
    Ok(())
}

/// All outputs of one command: staged until [`commit`](Self::commit), discarded on drop.
/// One transaction at a time per process.
#[must_use = "dropping a transaction discards every staged output"]
pub struct Transaction {
    _private: (),
}

impl Transaction {
    /// Opens the transaction; every atomic write from now on is staged.
    ///
    /// # Panics
    /// If a transaction is already open (a programming error).
    pub fn begin() -> Transaction {
        let mut guard = stage_lock();
        assert!(
            guard.is_none(),
            "atomic::Transaction::begin: one is already open"
        );
        *guard = Some(Stage::default());
        Transaction { _private: () }
    }

    /// Renames every staged file over its target, in write order.
    pub fn commit(self) -> std::io::Result<()> {
        let stage = stage_lock().take().unwrap_or_default();
        std::mem::forget(self);
        for (tmp, target) in stage.files {
            let t = tmp.to_path_buf();
            crate::output::forget_temp(&t);
            tmp.persist(&target).map_err(|e| {
                std::io::Error::new(e.error.kind(), format!("{}: {}", target.display(), e.error))
            })?;
        }
        Ok(())
    }
}

impl Drop for Transaction {
    fn drop(&mut self) {
        discard_staged();
    }
}

/// Deletes the staged files of the open transaction and the directories the run created
/// (a failed or interrupted run).
pub(crate) fn discard_staged() {
    if let Some(stage) = stage_lock().take() {
        drop(stage.files); // TempPath deletes its file
        for d in stage.dirs.iter().rev() {
            let _ = std::fs::remove_dir(d); // only if empty
        }
    }
}

/// Writes the manifest of `dir`: the files it listed already and `files` (paths inside
/// `dir`), atomically through the run's transaction.
pub fn write_manifest(dir: &Path, files: &[PathBuf]) -> std::io::Result<()> {
    let (path, text) = crate::output::manifest_with(dir, files);
    write_bytes(&path, text.as_bytes())
}

/// On SIGINT or SIGTERM: removes the run's temporary files and the folders it created (the
/// user's files stay as they were: nothing was renamed yet), then exits with status 130
/// (SIGINT) or 143 (SIGTERM). Installed once by the command line. (Elsewhere than Unix the
/// default action applies; the next run removes the temporary files.)
#[cfg(not(unix))]
pub fn install_interrupt_cleanup() {}

/// On SIGINT or SIGTERM: removes the run's temporary files and the folders it created (the
/// user's files stay as they were: nothing was renamed yet), then exits with status 130
/// (SIGINT) or 143 (SIGTERM). Installed once by the command line.
#[cfg(unix)]
pub fn install_interrupt_cleanup() {
    use signal_hook::consts::{SIGINT, SIGTERM};
    let Ok(mut signals) = signal_hook::iterator::Signals::new([SIGINT, SIGTERM]) else {
        return; // no handler: the default action (temporaries are then removed next run)
    };
    std::thread::spawn(move || {
        if let Some(sig) = signals.forever().next() {
            crate::output::mark_interrupted();
            crate::output::remove_live_temps();
            discard_staged();
            crate::output::remove_live_temps();
            let what = if sig == SIGINT { "SIGINT" } else { "SIGTERM" };
            eprintln!("\ninterrupted ({what}): nothing written, temporary files removed");
            std::process::exit(128 + sig);
        }
    });
}
