//! The recording lock: a file in the bag directory that the writer holds an exclusive
//! advisory lock (`flock`) on for as long as it writes, holding its process id and host
//! for people. The kernel releases the lock when the writer's process ends, however it
//! ends (SIGKILL, power kept), so "locked" means "a writer is alive", with no pid reuse to
//! fool it; a lock file left by a killed writer is stale and says so by being lockable.
//!
//! [`crate::recover`] refuses a bag whose writer is alive (it would move files from under
//! it); the reader says a bag is still being recorded when it finds it incomplete.

use std::fs::{self, File, OpenOptions};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use crate::error::{io, BagError, Result};

/// The lock file's name in the bag directory.
pub const LOCK_FILE: &str = "oilfilm-recording.lock";

/// Held by a writer: the lock is released and the file removed when it is dropped.
#[derive(Debug)]
pub(crate) struct RecordingLock {
    file: Option<File>,
    path: PathBuf,
}

impl RecordingLock {
    /// Creates and locks `dir/LOCK_FILE`, writing this process's id and host into it.
    pub(crate) fn acquire(dir: &Path) -> Result<Self> {
        let path = dir.join(LOCK_FILE);
        let mut file = OpenOptions::new().create(true).truncate(false).read(true).write(true).open(&path).map_err(io(&path))?;
        match file.try_lock() {
            Ok(()) => {}
            Err(fs::TryLockError::WouldBlock) => {
                let what = format!("another writer holds the bag ({})", holder(&path));
                return Err(BagError::Usage { path, what });
            }
            Err(fs::TryLockError::Error(e)) => return Err(io(&path)(e)),
        }
        file.set_len(0).map_err(io(&path))?;
        let host = fs::read_to_string("/proc/sys/kernel/hostname").map(|h| h.trim().to_string()).unwrap_or_default();
        write!(file, "pid {}\nhost {host}\n", std::process::id()).map_err(io(&path))?;
        file.flush().map_err(io(&path))?;
        Ok(Self { file: Some(file), path })
    }
}

impl Drop for RecordingLock {
    fn drop(&mut self) {
        // Removed while still locked, so no other writer can take a file about to vanish.
        let _ = fs::remove_file(&self.path);
        drop(self.file.take());
    }
}

/// What the lock file says (`pid N, host H`), for messages.
fn holder(path: &Path) -> String {
    let mut text = String::new();
    let _ = File::open(path).and_then(|f| f.take(256).read_to_string(&mut text));
    let words: Vec<&str> = text.split_whitespace().collect();
    let field = |key: &str| words.windows(2).find(|w| w[0] == key).map(|w| w[1].to_string());
    match (field("pid"), field("host")) {
        (Some(pid), Some(host)) => format!("pid {pid} on host {host}"),
        (Some(pid), None) => format!("pid {pid}"),
        _ => "a process that left no pid".into(),
    }
}

/// The state of a bag directory's recording lock.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Recording {
    /// No lock file: no writer of ours is or was writing (or it closed the bag).
    None,
    /// A lock file no process holds: its writer ended without closing the bag.
    Stale,
    /// A writer is alive: `holder` names it (`pid N on host H`).
    Alive { holder: String },
}

/// Whether a writer is alive on `dir` (tried without waiting; the lock is let go at once).
pub fn recording_state(dir: &Path) -> Result<Recording> {
    let path = dir.join(LOCK_FILE);
    let file = match File::open(&path) {
        Ok(f) => f,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Recording::None),
        Err(e) => return Err(io(&path)(e)),
    };
    match file.try_lock_shared() {
        Ok(()) => Ok(Recording::Stale),
        Err(fs::TryLockError::WouldBlock) => Ok(Recording::Alive { holder: holder(&path) }),
        Err(fs::TryLockError::Error(e)) => Err(io(&path)(e)),
    }
}

/// Removes a stale lock file (after recovery); a live one is left alone.
pub(crate) fn remove_stale(dir: &Path) -> Result<()> {
    if recording_state(dir)? == Recording::Stale {
        let path = dir.join(LOCK_FILE);
        fs::remove_file(&path).map_err(io(&path))?;
    }
    Ok(())
}
