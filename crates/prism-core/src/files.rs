//! Atomic file writes, the one way prism writes a file.
//!
//! [`write_atomic`] stages the new contents beside the target (same folder, so the final rename
//! stays on one file system), syncs them, and renames them over the target: a reader, or a run
//! killed at any moment, finds the old file or the new one, never a partial one. On Linux the
//! staged file has no name until it is complete (`O_TMPFILE`); elsewhere (or where the file
//! system lacks `O_TMPFILE`) it is a hidden `.NAME.tmp-PID-N` sibling, removed on every error.
//! Replacing a file needs that name for the moment between naming the complete copy and the
//! rename (Linux cannot link a file over another), so a writer killed (SIGKILL) just then
//! leaves a complete hidden copy behind; the next write of the same file removes the copies of
//! writers that are no longer running.
//!
//! Folders (a checkpoint) are replaced by [`replace_dir`]: written under a staged name, every
//! file synced, then exchanged with the old folder in one rename (two renames where the file
//! system cannot exchange), the old folder removed only once the new one is on the disk; a crash
//! or a power cut at any moment leaves a complete folder that [`recover_dir`] makes the only one.

mod replace;

pub use replace::{
    ASIDE_SUFFIX, Disk, ReplaceFs, STAGED_SUFFIX, recover_dir, replace_dir, replace_dir_with,
    with_suffix,
};

use std::fs::{self, File};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use serde::Serialize;

/// Writes `path` atomically with the bytes `write` produces.
///
/// # Errors
/// Any I/O error of staging, syncing or renaming, or the one `write` returns; `path` is then
/// untouched and nothing is left behind. An error of the folder's sync after the rename is
/// returned too: `path` then holds the new contents, which a power cut could still undo.
pub fn write_atomic(
    path: &Path,
    write: impl FnOnce(&mut dyn Write) -> io::Result<()>,
) -> io::Result<()> {
    let staged = Staged::create(path)?;
    let mut out = BufWriter::new(&staged.file);
    write(&mut out)?;
    out.flush()?;
    drop(out);
    staged.file.sync_all()?;
    staged.publish(path)
}

/// Writes `bytes` to `path` atomically (see [`write_atomic`]).
///
/// # Errors
/// As [`write_atomic`].
pub fn write_bytes(path: &Path, bytes: &[u8]) -> io::Result<()> {
    write_atomic(path, |out| out.write_all(bytes))
}

/// Writes `value` to `path` as pretty JSON with a final newline, atomically.
///
/// # Errors
/// As [`write_atomic`]; a value that does not serialise is an `InvalidData` error.
pub fn write_json<T: Serialize + ?Sized>(path: &Path, value: &T) -> io::Result<()> {
    let mut text = serde_json::to_string_pretty(value).map_err(io::Error::other)?;
    text.push('\n');
    write_bytes(path, text.as_bytes())
}

/// The folder a file path lives in (`.` for a bare name).
fn folder(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// A hidden sibling name for a staged copy of `path`, unique within the process.
fn sibling_name(path: &Path) -> io::Result<PathBuf> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let name = path.file_name().ok_or_else(|| {
        io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("{} is not a file path", path.display()),
        )
    })?;
    let mut staged = std::ffi::OsString::from(".");
    staged.push(name);
    staged.push(format!(
        ".tmp-{}-{}",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    Ok(path.with_file_name(staged))
}

/// New contents of a file, staged beside it until [`Staged::publish`].
struct Staged {
    file: File,
    /// The staged copy's name; `None` while it has none (`O_TMPFILE`).
    name: Option<PathBuf>,
}

impl Staged {
    fn create(path: &Path) -> io::Result<Self> {
        let name = sibling_name(path)?;
        #[cfg(target_os = "linux")]
        if let Some(file) = unnamed::create(folder(path)) {
            return Ok(Self { file, name: None });
        }
        let file = File::options().write(true).create_new(true).open(&name)?;
        Ok(Self {
            file,
            name: Some(name),
        })
    }

    /// Gives the staged contents the name `path`, replacing what was there.
    fn publish(mut self, path: &Path) -> io::Result<()> {
        let name = match self.name.take() {
            Some(name) => name,
            #[cfg(target_os = "linux")]
            None => {
                // Straight to the target when it does not exist yet: no name in between.
                match unnamed::link(&self.file, path) {
                    Ok(()) => return try_sync_folder(path),
                    Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {}
                    Err(e) => return Err(e),
                }
                let name = sibling_name(path)?;
                unnamed::link(&self.file, &name)?;
                name
            }
            #[cfg(not(target_os = "linux"))]
            None => unreachable!("unnamed staging is Linux only"),
        };
        if let Err(e) = fs::rename(&name, path) {
            let _ = fs::remove_file(&name);
            return Err(e);
        }
        remove_abandoned_copies(path);
        try_sync_folder(path)
    }
}

/// Removes the staged copies of `path` (`.NAME.tmp-PID-N`) whose writer is no longer running:
/// what a writer killed between naming its copy and renaming it leaves.
fn remove_abandoned_copies(path: &Path) {
    let Some(name) = path.file_name().and_then(|n| n.to_str()) else {
        return;
    };
    let prefix = format!(".{name}.tmp-");
    let Ok(entries) = fs::read_dir(folder(path)) else {
        return;
    };
    for entry in entries.flatten() {
        let file = entry.file_name();
        let pid = file
            .to_str()
            .and_then(|f| f.strip_prefix(&prefix))
            .and_then(|rest| rest.split('-').next())
            .and_then(|pid| pid.parse::<u32>().ok());
        if let Some(pid) = pid
            && pid != std::process::id()
            && !running(pid)
        {
            let _ = fs::remove_file(entry.path());
        }
    }
}

/// Whether the process `pid` runs (on Linux, from `/proc`; elsewhere assumed, so that nothing
/// is removed where it cannot be told).
fn running(pid: u32) -> bool {
    if cfg!(target_os = "linux") && Path::new("/proc/self").is_dir() {
        Path::new(&format!("/proc/{pid}")).exists()
    } else {
        true
    }
}

impl Drop for Staged {
    fn drop(&mut self) {
        if let Some(name) = &self.name {
            let _ = fs::remove_file(name);
        }
    }
}

/// Syncs the folder of `path`, so that a rename into it survives a power cut (see
/// [`sync_folder`]).
fn try_sync_folder(path: &Path) -> io::Result<()> {
    sync_folder(folder(path))
}

/// Syncs the folder `dir`: its entries (the names created, renamed or removed in it) survive a
/// power cut. On Unix its error is returned, naming the folder; elsewhere (where a folder cannot
/// be opened for syncing) the sync is skipped.
fn sync_folder(dir: &Path) -> io::Result<()> {
    if cfg!(unix) {
        File::open(dir)
            .and_then(|f| f.sync_all())
            .map_err(|e| io::Error::new(e.kind(), format!("syncing {}: {e}", dir.display())))
    } else {
        Ok(())
    }
}

#[cfg(target_os = "linux")]
mod unnamed {
    //! Linux's unnamed temporary files: `open(folder, O_TMPFILE)`, then `linkat` through
    //! `/proc/self/fd` once complete.

    use std::ffi::CString;
    use std::fs::File;
    use std::io;
    use std::os::unix::ffi::OsStrExt;
    use std::os::unix::fs::OpenOptionsExt;
    use std::os::unix::io::AsRawFd;
    use std::path::Path;

    /// An unnamed file in `folder`, or `None` where the file system (or a missing `/proc`)
    /// does not allow one.
    pub(super) fn create(folder: &Path) -> Option<File> {
        if !Path::new("/proc/self/fd").is_dir() {
            return None;
        }
        File::options()
            .write(true)
            .mode(0o666)
            .custom_flags(libc::O_TMPFILE)
            .open(folder)
            .ok()
    }

    /// Gives the unnamed `file` the name `path`; `AlreadyExists` if that name is taken.
    pub(super) fn link(file: &File, path: &Path) -> io::Result<()> {
        let from = CString::new(format!("/proc/self/fd/{}", file.as_raw_fd()))
            .map_err(io::Error::other)?;
        let to = CString::new(path.as_os_str().as_bytes()).map_err(io::Error::other)?;
        // SAFETY: both arguments are valid NUL-terminated paths that outlive the call.
        let rc = unsafe {
            libc::linkat(
                libc::AT_FDCWD,
                from.as_ptr(),
                libc::AT_FDCWD,
                to.as_ptr(),
                libc::AT_SYMLINK_FOLLOW,
            )
        };
        if rc == 0 {
            Ok(())
        } else {
            Err(io::Error::last_os_error())
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// The names in `dir`, sorted (shared with `replace`'s tests).
    pub(crate) fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn writes_new_and_replaces_existing_files_leaving_nothing_else() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.json");
        write_json(&path, &[1, 2]).unwrap();
        assert_eq!(fs::read_to_string(&path).unwrap(), "[\n  1,\n  2\n]\n");
        write_bytes(&path, b"new").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"new");
        assert_eq!(names(dir.path()), ["a.json"]);
    }

    #[test]
    fn a_failed_write_keeps_the_old_file_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.txt");
        write_bytes(&path, b"old").unwrap();
        let err = write_atomic(&path, |out| {
            out.write_all(b"half")?;
            Err(io::Error::other("encoder failed"))
        })
        .unwrap_err();
        assert_eq!(err.to_string(), "encoder failed");
        assert_eq!(fs::read(&path).unwrap(), b"old");
        assert_eq!(names(dir.path()), ["a.txt"]);
    }

    #[test]
    fn a_missing_folder_is_an_error_not_a_panic() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("no/such/a.txt");
        assert!(write_bytes(&path, b"x").is_err());
        assert!(!path.exists());
    }

    #[test]
    fn named_staging_is_removed_on_failure() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("b.txt");
        let staged = sibling_name(&path).unwrap();
        let file = File::create(&staged).unwrap();
        drop(Staged {
            file,
            name: Some(staged.clone()),
        });
        assert!(!staged.exists());
    }
}
