//! Outputs in flight, and what becomes of them when the run stops early.
//!
//! Every output is written to a temporary file beside it and renamed into
//! place ([`crate::io::output::atomic_write_file`]). The temporary files that
//! exist at any moment are registered here, so that whatever ends the run
//! removes them:
//! - a failed write drops its [`TempFile`], which deletes it;
//! - SIGINT or SIGTERM: [`install_signal_handlers`] starts a thread that,
//!   on the signal, takes the registry's lock (so no rename or new temporary
//!   can happen after it), deletes every registered file, prints one line
//!   and exits with 128 + the signal (130, 143);
//! - an allocation that fails: [`crate::runtime::memory::CountingAlloc`] calls
//!   [`remove_all_now`], which needs no memory, then exits 1.
//!
//! A temporary is created (`O_EXCL`, a name no other process uses) and
//! renamed while the lock is held, so a signal sees each output either
//! complete under its final name or not at all. Two processes writing one
//! directory each rename their own whole files; the last rename wins.

use std::ffi::CString;
use std::fs::File;
use std::io;
use std::io::Write as _;
use std::os::unix::ffi::OsStrExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

use crate::error::{HostError, Result};

/// The registered temporary files.
struct Registry {
    /// `(id, path)`: the path as a C string, so that removing it needs no
    /// allocation.
    files: Vec<(u64, CString)>,
    /// Set by the signal thread: no new temporary file, no rename.
    stopping: bool,
    /// Outputs renamed into place.
    committed: usize,
}

static REGISTRY: Mutex<Registry> = Mutex::new(Registry { files: Vec::new(), stopping: false, committed: 0 });
static NEXT_ID: AtomicU64 = AtomicU64::new(0);

fn registry() -> std::sync::MutexGuard<'static, Registry> {
    // A panic while holding the lock leaves the data consistent (every
    // change is a single push, remove or flag), so a poisoned lock is used.
    REGISTRY.lock().unwrap_or_else(|p| p.into_inner())
}

/// A temporary file beside an output, registered until it is renamed into
/// place or dropped (which deletes it).
#[derive(Debug)]
pub struct TempFile {
    id: u64,
    path: PathBuf,
    done: bool,
}

/// The error of a write refused because the run is stopping.
fn stopping() -> io::Error {
    io::Error::new(io::ErrorKind::Interrupted, "the run is being interrupted")
}

impl TempFile {
    /// Creates a new temporary file in `dir` for the output named `name`:
    /// `.NAME.PID-N.mcdenoise-tmp`, created exclusively.
    pub fn create(dir: &Path, name: &std::ffi::OsStr) -> io::Result<(TempFile, File)> {
        let id = NEXT_ID.fetch_add(1, Ordering::Relaxed);
        let mut file_name = std::ffi::OsString::from(".");
        file_name.push(name);
        file_name.push(format!(".{}-{id}.mcdenoise-tmp", std::process::id()));
        let path = dir.join(file_name);
        let c = CString::new(path.as_os_str().as_bytes())
            .map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "path contains a NUL byte"))?;
        let mut reg = registry();
        reg.files.reserve(1);
        if reg.stopping {
            return Err(stopping());
        }
        let file = std::fs::OpenOptions::new().write(true).create_new(true).open(&path)?;
        reg.files.push((id, c));
        Ok((TempFile { id, path, done: false }, file))
    }

    /// The temporary file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Renames the temporary file to `dest` (atomically replacing it).
    pub fn commit(mut self, dest: &Path) -> io::Result<()> {
        let mut reg = registry();
        if reg.stopping {
            return Err(stopping());
        }
        std::fs::rename(&self.path, dest)?;
        reg.files.retain(|(id, _)| *id != self.id);
        reg.committed += 1;
        self.done = true;
        Ok(())
    }
}

impl Drop for TempFile {
    fn drop(&mut self) {
        if !self.done {
            let mut reg = registry();
            let _ = std::fs::remove_file(&self.path);
            reg.files.retain(|(id, _)| *id != self.id);
        }
    }
}

/// Temporary files registered now (for tests and messages).
pub fn in_flight() -> usize {
    registry().files.len()
}

/// Outputs renamed into place by this process so far.
pub fn committed() -> usize {
    registry().committed
}

/// Deletes every registered temporary file without allocating and without
/// waiting for the lock (for the out-of-memory path: if the thread that ran
/// out holds the lock, nothing is removed). Returns how many were removed.
pub fn remove_all_now() -> usize {
    match REGISTRY.try_lock() {
        Ok(mut reg) => remove_locked(&mut reg),
        Err(std::sync::TryLockError::Poisoned(p)) => remove_locked(&mut p.into_inner()),
        Err(std::sync::TryLockError::WouldBlock) => 0,
    }
}

fn remove_locked(reg: &mut Registry) -> usize {
    reg.stopping = true;
    let mut n = 0;
    for (_, c) in &reg.files {
        // SAFETY: `c` is a valid NUL-terminated string that outlives the call.
        if unsafe { libc::unlink(c.as_ptr()) } == 0 {
            n += 1;
        }
    }
    n
}

/// Ends the process for signal `sig`: removes the temporary files (holding
/// the lock, so no output is renamed after), prints one line, exits
/// `128 + sig`.
fn stop_for(sig: i32) -> ! {
    let mut reg = registry();
    remove_locked(&mut reg);
    let name = match sig {
        libc::SIGINT => "SIGINT",
        libc::SIGTERM => "SIGTERM",
        _ => "a signal",
    };
    let n = reg.committed;
    let clear = if std::io::IsTerminal::is_terminal(&std::io::stderr()) { "\r\x1b[2K" } else { "" };
    eprintln!(
        "{clear}mcdenoise: interrupted by {name} after {n} complete output file{}; no partial file left",
        if n == 1 { "" } else { "s" }
    );
    std::process::exit(128 + sig)
}

/// Installs the handling of SIGINT and SIGTERM (a thread that waits for
/// them, see the module notes) and ignores SIGXFSZ, so that a write past
/// the file-size limit (`ulimit -f`) fails with an error the run reports,
/// instead of killing it. Call once, from `main`.
pub fn install_signal_handlers() -> io::Result<()> {
    // SAFETY: setting a signal's disposition to SIG_IGN has no preconditions.
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
    let mut signals = signal_hook::iterator::Signals::new([signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM])?;
    std::thread::Builder::new().name("mcdenoise-signals".into()).spawn(move || {
        if let Some(sig) = signals.forever().next() {
            stop_for(sig);
        }
    })?;
    Ok(())
}

/// Writes `path` atomically: `write` fills a new temporary file next to it
/// (registered in [`crate::runtime::cleanup`], so an interrupted run removes it),
/// which is flushed and renamed over `path` only when `write` succeeded.
/// On any failure the temporary file is gone and `path` is as it was.
pub fn atomic_write_file(
    path: &Path,
    write: impl FnOnce(&mut std::io::BufWriter<&mut std::fs::File>) -> std::result::Result<(), String>,
) -> Result<()> {
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = path.file_name().ok_or_else(|| HostError::write(path, "no file name"))?;
    let (tmp, mut file) = TempFile::create(dir, name).map_err(|e| write_error(path, &e))?;
    let mut buffered = std::io::BufWriter::with_capacity(1 << 16, &mut file);
    write(&mut buffered)
        .and_then(|()| buffered.flush().map_err(|e| io_reason(&e)))
        .map_err(|e| HostError::write(path, e))?;
    drop(buffered);
    drop(file);
    tmp.commit(path).map_err(|e| write_error(path, &e))
}

/// Writes `path` atomically through a writer that takes the temporary
/// file's path (it already exists, empty). Prefer [`atomic_write_file`]:
/// between a signal's removal of the temporary file and the exit, a writer
/// that reopens it by path could create it again.
pub fn atomic_write(path: &Path, write: impl FnOnce(&Path) -> std::result::Result<(), String>) -> Result<()> {
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = path.file_name().ok_or_else(|| HostError::write(path, "no file name"))?;
    let (tmp, file) = TempFile::create(dir, name).map_err(|e| write_error(path, &e))?;
    drop(file);
    write(tmp.path()).map_err(|e| HostError::write(path, e))?;
    tmp.commit(path).map_err(|e| write_error(path, &e))
}

/// The reason of a failed write in words a user acts on: the OS text, led
/// by what it means where that is not plain (a full disk, the file-size
/// limit).
pub fn io_reason(e: &std::io::Error) -> String {
    let hint = match e.raw_os_error() {
        Some(libc::ENOSPC) => "the disk is full: ",
        Some(libc::EFBIG) => "the file-size limit (ulimit -f) is reached: ",
        _ => "",
    };
    format!("{hint}{e}")
}

fn write_error(path: &Path, e: &std::io::Error) -> HostError {
    HostError::write(path, io_reason(e))
}
