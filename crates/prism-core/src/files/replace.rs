//! Replacing a folder (a checkpoint) so that a crash or a power cut at any moment leaves a
//! complete one: [`replace_dir`] and its steps, [`recover_dir`] for what an interrupted one
//! leaves. The steps go through [`ReplaceFs`], so that a test can fail any call
//! (`crates/prism-core/tests/atomic_kill.rs`, `crates/prism-train/tests/train.rs`).

use std::fs::{self, File};
use std::io;
use std::path::{Path, PathBuf};

use super::{folder, sync_folder};

/// Suffix of a folder being written, before [`replace_dir`] moves it in; after an exchange, of
/// the old folder until it is removed.
pub const STAGED_SUFFIX: &str = ".partial";
/// Suffix of the previous folder, put aside while [`replace_dir`] moves the new one in on a
/// file system that cannot exchange two folders.
pub const ASIDE_SUFFIX: &str = ".old";

/// `dir` with `suffix` appended to its name (`step-2` -> `step-2.partial`).
pub fn with_suffix(dir: &Path, suffix: &str) -> PathBuf {
    let mut name = dir.as_os_str().to_owned();
    name.push(suffix);
    PathBuf::from(name)
}

/// The file-system calls a folder replace makes, one at a time. [`Disk`] makes them; a test's
/// implementation can fail any one (what a crash there leaves), refuse the exchange (the
/// fallback) or follow what each has put on the disk (what a power cut there keeps).
pub trait ReplaceFs {
    /// Flushes the contents of `file` to the disk.
    ///
    /// # Errors
    /// The I/O error, naming the file.
    fn sync_file(&mut self, file: &Path) -> io::Result<()>;

    /// Flushes the entries of the folder `dir` (names created, renamed or removed in it).
    ///
    /// # Errors
    /// The I/O error, naming the folder.
    fn sync_folder(&mut self, dir: &Path) -> io::Result<()>;

    /// Swaps the folders `a` and `b` in one atomic rename.
    ///
    /// # Errors
    /// Of kind [`io::ErrorKind::Unsupported`] where the file system cannot (nothing changed
    /// then); any other I/O error, naming the folders.
    fn exchange(&mut self, a: &Path, b: &Path) -> io::Result<()>;

    /// Renames `from` to `to`.
    ///
    /// # Errors
    /// The I/O error, naming both.
    fn rename(&mut self, from: &Path, to: &Path) -> io::Result<()>;

    /// Removes the folder `dir` and everything in it.
    ///
    /// # Errors
    /// The I/O error (of kind `NotFound` for a missing folder), naming the folder.
    fn remove_dir_all(&mut self, dir: &Path) -> io::Result<()>;
}

/// The file system itself: what [`replace_dir`] and [`recover_dir`] use.
#[derive(Clone, Copy, Debug, Default)]
pub struct Disk;

impl ReplaceFs for Disk {
    fn sync_file(&mut self, file: &Path) -> io::Result<()> {
        // Unix syncs a file opened for reading; Windows flushes only one opened for writing.
        File::options()
            .read(true)
            .write(!cfg!(unix))
            .open(file)
            .and_then(|f| f.sync_all())
            .map_err(|e| named(e, "syncing", file))
    }

    fn sync_folder(&mut self, dir: &Path) -> io::Result<()> {
        sync_folder(dir)
    }

    fn exchange(&mut self, a: &Path, b: &Path) -> io::Result<()> {
        exchange(a, b).map_err(|e| {
            let what = format!("exchanging {} and", a.display());
            named(e, &what, b)
        })
    }

    fn rename(&mut self, from: &Path, to: &Path) -> io::Result<()> {
        fs::rename(from, to).map_err(|e| {
            let what = format!("renaming {} to", from.display());
            named(e, &what, to)
        })
    }

    fn remove_dir_all(&mut self, dir: &Path) -> io::Result<()> {
        fs::remove_dir_all(dir).map_err(|e| named(e, "removing", dir))
    }
}

/// `e` (of the same kind) saying `what` was done to `path`.
fn named(e: io::Error, what: &str, path: &Path) -> io::Error {
    io::Error::new(e.kind(), format!("{what} {}: {e}", path.display()))
}

/// Replaces the folder `dir` (if any) with the complete folder `staged` (`dir.partial`), on the
/// [`Disk`], in four steps:
/// 1. every file of `staged`, then every folder (`staged` last), is synced: what is moved in is
///    on the disk, whichever writer made it (Burn's recorder does not sync);
/// 2. where `dir` exists, the two folders are exchanged in one atomic rename (Linux's
///    `renameat2` with `RENAME_EXCHANGE`): `dir` is the new folder and `dir.partial` the old
///    one, and at no moment is there no `dir`. Where the file system cannot exchange (systems
///    other than Linux; on Linux, `EINVAL`, `ENOSYS` or `EOPNOTSUPP`: kernels before 3.15 and
///    file systems without the call, some network and FUSE ones), two renames do it instead:
///    the old folder is put aside as `dir.old`, then the new one is moved in, and for that
///    moment `dir` does not exist;
/// 3. the parent folder is synced: the renames are on the disk;
/// 4. only then is the old folder removed.
///
/// Whatever a crash or a power cut interrupts, `dir` or `dir.old` is a complete folder, and
/// [`recover_dir`] turns what is left into a complete `dir` and nothing beside it.
///
/// # Errors
/// As [`replace_dir_with`].
pub fn replace_dir(staged: &Path, dir: &Path) -> io::Result<()> {
    replace_dir_with(&mut Disk, staged, dir)
}

/// [`replace_dir`] through the calls of `calls`.
///
/// # Errors
/// The first failed call's error: the folders are left as the calls before it left them, which
/// [`recover_dir`] makes a complete `dir`.
pub fn replace_dir_with(calls: &mut impl ReplaceFs, staged: &Path, dir: &Path) -> io::Result<()> {
    sync_tree(calls, staged)?;
    let old = if dir.exists() {
        match calls.exchange(staged, dir) {
            Ok(()) => Some(staged.to_path_buf()),
            Err(e) if e.kind() == io::ErrorKind::Unsupported => {
                let aside = with_suffix(dir, ASIDE_SUFFIX);
                if aside.exists() {
                    // A leftover of an interrupted replace: `dir` is complete, and on the disk
                    // before the leftover goes.
                    calls.sync_folder(folder(dir))?;
                    calls.remove_dir_all(&aside)?;
                }
                calls.rename(dir, &aside)?;
                calls.rename(staged, dir)?;
                Some(aside)
            }
            Err(e) => return Err(e),
        }
    } else {
        calls.rename(staged, dir)?;
        None
    };
    calls.sync_folder(folder(dir))?;
    match old {
        Some(old) => calls.remove_dir_all(&old),
        None => Ok(()),
    }
}

/// Syncs every file under `dir`, then every folder, `dir` last (a folder after what it holds).
fn sync_tree(calls: &mut impl ReplaceFs, dir: &Path) -> io::Result<()> {
    for entry in fs::read_dir(dir).map_err(|e| named(e, "listing", dir))? {
        let entry = entry.map_err(|e| named(e, "listing", dir))?;
        let path = entry.path();
        let kind = entry.file_type().map_err(|e| named(e, "reading", &path))?;
        if kind.is_dir() {
            sync_tree(calls, &path)?;
        } else {
            calls.sync_file(&path)?;
        }
    }
    calls.sync_folder(dir)
}

/// Finishes or undoes a [`replace_dir`] of `dir` that a crash or a power cut interrupted: with
/// `dir` missing, the old folder put aside (`dir.old`) is renamed back; then, once `dir` is on
/// the disk, the aside folder and the staged one (`dir.partial`: the new folder not moved in,
/// or the old one after an exchange) are removed. Returns whether anything was found.
///
/// # Errors
/// I/O errors of the renames, syncs and removals, naming the folder.
pub fn recover_dir(dir: &Path) -> io::Result<bool> {
    let aside = with_suffix(dir, ASIDE_SUFFIX);
    let staged = with_suffix(dir, STAGED_SUFFIX);
    if !aside.exists() && !staged.exists() {
        return Ok(false);
    }
    let mut disk = Disk;
    if !dir.exists() && aside.exists() {
        disk.rename(&aside, dir)?;
    }
    disk.sync_folder(folder(dir))?;
    for leftover in [aside, staged] {
        if leftover.exists() {
            disk.remove_dir_all(&leftover)?;
        }
    }
    Ok(true)
}

/// Swaps the folders `a` and `b` with `renameat2(RENAME_EXCHANGE)`; `Unsupported` where the
/// kernel or the file system lacks it.
#[cfg(target_os = "linux")]
fn exchange(a: &Path, b: &Path) -> io::Result<()> {
    use std::ffi::CString;
    use std::os::unix::ffi::OsStrExt;

    let c_path = |p: &Path| {
        CString::new(p.as_os_str().as_bytes())
            .map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "a path with a NUL byte"))
    };
    let (a, b) = (c_path(a)?, c_path(b)?);
    // SAFETY: both arguments are valid NUL-terminated paths that outlive the call.
    let rc = unsafe {
        libc::renameat2(
            libc::AT_FDCWD,
            a.as_ptr(),
            libc::AT_FDCWD,
            b.as_ptr(),
            libc::RENAME_EXCHANGE,
        )
    };
    if rc == 0 {
        return Ok(());
    }
    let e = io::Error::last_os_error();
    match e.raw_os_error() {
        Some(libc::EINVAL | libc::ENOSYS | libc::EOPNOTSUPP) => {
            Err(io::Error::new(io::ErrorKind::Unsupported, e))
        }
        _ => Err(e),
    }
}

/// No atomic exchange of two folders outside Linux: [`replace_dir`] falls back to two renames.
#[cfg(not(target_os = "linux"))]
fn exchange(_: &Path, _: &Path) -> io::Result<()> {
    Err(io::Error::new(
        io::ErrorKind::Unsupported,
        "no atomic exchange of two folders on this system",
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::files::tests::names;

    /// A folder holding one file, `v`, with `version` in it.
    fn folder_version(dir: &Path, version: u32) {
        fs::create_dir_all(dir).unwrap();
        fs::write(dir.join("v"), version.to_string()).unwrap();
    }

    fn read_version(dir: &Path) -> u32 {
        fs::read_to_string(dir.join("v")).unwrap().parse().unwrap()
    }

    #[test]
    fn replacing_a_missing_folder_moves_the_new_one_in() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("out");
        let staged = with_suffix(&dir, STAGED_SUFFIX);
        folder_version(&staged, 7);
        replace_dir(&staged, &dir).unwrap();
        assert_eq!(read_version(&dir), 7);
        assert_eq!(names(root.path()), ["out"]);
        assert!(!recover_dir(&dir).unwrap());
    }

    /// The file system of the test (ext4 or tmpfs on Linux) exchanges two folders: the path
    /// replaces take there is the atomic one.
    #[cfg(target_os = "linux")]
    #[test]
    fn two_folders_are_exchanged_in_one_rename() {
        let root = tempfile::tempdir().unwrap();
        let (a, b) = (root.path().join("a"), root.path().join("b"));
        folder_version(&a, 1);
        folder_version(&b, 2);
        Disk.exchange(&a, &b).unwrap();
        assert_eq!((read_version(&a), read_version(&b)), (2, 1));
        let err = Disk.exchange(&a, &root.path().join("c")).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::NotFound, "{err}");
        assert!(err.to_string().contains("exchanging"), "{err}");
    }
}
