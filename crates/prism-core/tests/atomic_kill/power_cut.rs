//! A folder replace (`prism_core::files::replace_dir_with`, a checkpoint's write) failed at each
//! of its calls, through a [`ReplaceFs`] that injects the failure, in both its ways (the atomic
//! exchange and the two renames of the fallback). At each failure the test takes what a kill
//! leaves (the disk as the calls left it) and what a power cut leaves (see [`power_cut`]), and
//! checks that `recover_dir` then gives a complete folder, of the old version or the new one,
//! and nothing beside it; once the replace is through, of the new one.

use std::collections::HashSet;
use std::fs::{self, File};
use std::io;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

use prism_core::files::{
    Disk, ReplaceFs, STAGED_SUFFIX, recover_dir, replace_dir_with, with_suffix,
};

/// Files of one version of the folder, one in a subfolder (the sync goes into folders).
const FILES: [&str; 3] = ["model.bpk", "parts/optimizer.bpk", "state.json"];
/// Bytes of each file: its version number, repeated.
const LEN: usize = 4096;

/// The disk, seen through a [`ReplaceFs`] whose call number `fail_at` (0-based) fails, which
/// refuses the exchange unless `exchange`, and which follows what a power cut would keep: the
/// files and folders synced, and the renames since the parent folder was last synced.
struct Faulty {
    calls: usize,
    fail_at: usize,
    exchange: bool,
    /// The folder holding the replaced folder.
    parent: PathBuf,
    /// Inodes of the files and folders whose contents are on the disk.
    synced: HashSet<u64>,
    /// Renames not yet on the disk, oldest first, as (from, to, whether an exchange).
    renames: Vec<(PathBuf, PathBuf, bool)>,
}

impl Faulty {
    /// Counts a call; the one numbered `fail_at` fails, as a crash there.
    fn call(&mut self) -> io::Result<()> {
        self.calls += 1;
        if self.calls - 1 == self.fail_at {
            return Err(io::Error::other("injected failure"));
        }
        Ok(())
    }
}

impl ReplaceFs for Faulty {
    fn sync_file(&mut self, file: &Path) -> io::Result<()> {
        self.call()?;
        Disk.sync_file(file)?;
        self.synced.insert(inode(file));
        Ok(())
    }

    fn sync_folder(&mut self, dir: &Path) -> io::Result<()> {
        self.call()?;
        Disk.sync_folder(dir)?;
        self.synced.insert(inode(dir));
        if dir == self.parent.as_path() {
            self.renames.clear();
        }
        Ok(())
    }

    fn exchange(&mut self, a: &Path, b: &Path) -> io::Result<()> {
        self.call()?;
        if !self.exchange {
            return Err(io::Error::new(io::ErrorKind::Unsupported, "no exchange"));
        }
        Disk.exchange(a, b)?;
        self.renames.push((a.to_path_buf(), b.to_path_buf(), true));
        Ok(())
    }

    fn rename(&mut self, from: &Path, to: &Path) -> io::Result<()> {
        self.call()?;
        Disk.rename(from, to)?;
        self.renames
            .push((from.to_path_buf(), to.to_path_buf(), false));
        Ok(())
    }

    fn remove_dir_all(&mut self, dir: &Path) -> io::Result<()> {
        self.call()?;
        assert!(
            self.renames.is_empty(),
            "{} removed while the renames before it were not on the disk",
            dir.display()
        );
        Disk.remove_dir_all(dir)
    }
}

fn inode(path: &Path) -> u64 {
    fs::metadata(path).unwrap().ino()
}

/// Writes version `v` of the folder into `dir`, without syncing (as Burn's recorder writes).
fn write_version(dir: &Path, v: u8) {
    for name in FILES {
        let path = dir.join(name);
        fs::create_dir_all(path.parent().unwrap()).unwrap();
        fs::write(path, [v; LEN]).unwrap();
    }
}

/// The inodes of `dir`, its folders and files.
fn inodes(dir: &Path, out: &mut HashSet<u64>) {
    out.insert(inode(dir));
    for entry in fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            inodes(&path, out);
        } else {
            out.insert(inode(&path));
        }
    }
}

/// Checks that `dir` holds exactly the files of one version, whole, and returns it.
fn complete_version(dir: &Path) -> u8 {
    let mut found = Vec::new();
    collect_files(dir, dir, &mut found);
    found.sort();
    let mut want: Vec<String> = FILES.iter().map(|s| s.to_string()).collect();
    want.sort();
    assert_eq!(found, want, "{}", dir.display());
    let versions: Vec<u8> = FILES
        .iter()
        .map(|name| {
            let bytes = fs::read(dir.join(name)).unwrap();
            assert!(
                bytes.len() == LEN && bytes.iter().all(|&b| b == bytes[0]),
                "{name}: a partial file ({} bytes)",
                bytes.len()
            );
            bytes[0]
        })
        .collect();
    assert!(
        versions.iter().all(|&v| v == versions[0]),
        "files of several versions: {versions:?}"
    );
    versions[0]
}

fn collect_files(root: &Path, dir: &Path, out: &mut Vec<String>) {
    for entry in fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            collect_files(root, &path, out);
        } else {
            let relative = path.strip_prefix(root).unwrap();
            out.push(relative.to_string_lossy().replace('\\', "/"));
        }
    }
}

/// What a power cut right after the last call leaves, with the last `undone` renames not yet on
/// the disk lost (a journal keeps the renames in order, so a prefix of them survives): every
/// file not synced loses its contents, every folder not synced loses what was made in it (all
/// it holds: the only such folders are the staged ones).
fn power_cut(calls: &Faulty, undone: usize) {
    for (from, to, exchanged) in calls.renames.iter().rev().take(undone) {
        if *exchanged {
            Disk.exchange(from, to).unwrap();
        } else {
            fs::rename(to, from).unwrap();
        }
    }
    lose_unsynced(&calls.parent, &calls.synced);
}

fn lose_unsynced(dir: &Path, synced: &HashSet<u64>) {
    for entry in fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        let kept = synced.contains(&inode(&path));
        if path.is_dir() {
            if kept {
                lose_unsynced(&path, synced);
            } else {
                fs::remove_dir_all(&path).unwrap();
                fs::create_dir(&path).unwrap();
            }
        } else if !kept {
            File::create(&path).unwrap();
        }
    }
}

/// How a replace is interrupted.
#[derive(Clone, Copy, Debug)]
enum Cut {
    /// The process dies: the disk holds what the calls did.
    Kill,
    /// The machine loses power, with this many of the last renames not yet on the disk lost.
    Power(usize),
}

/// Replaces version 1 of a folder with version 2, failing call `fail_at`, cuts as `cut` says,
/// recovers, and returns the version left; `None` where `cut` loses more renames than were
/// pending. Panics unless a complete folder, and nothing beside it, is left.
fn replace_and_cut(exchange: bool, fail_at: usize, cut: Cut) -> Option<(u8, bool)> {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("step-00000002");
    let staged = with_suffix(&dir, STAGED_SUFFIX);
    write_version(&dir, 1);
    // The old folder was moved in by an earlier replace: on the disk.
    let mut synced = HashSet::new();
    inodes(&dir, &mut synced);
    write_version(&staged, 2);
    let mut calls = Faulty {
        calls: 0,
        fail_at,
        exchange,
        parent: root.path().to_path_buf(),
        synced,
        renames: Vec::new(),
    };
    let through = replace_dir_with(&mut calls, &staged, &dir).is_ok();
    match cut {
        Cut::Kill => {}
        Cut::Power(undone) if undone > calls.renames.len() => return None,
        Cut::Power(undone) => power_cut(&calls, undone),
    }
    recover_dir(&dir).unwrap();
    let names: Vec<String> = fs::read_dir(root.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, ["step-00000002"], "leftovers");
    Some((complete_version(&dir), through))
}

#[test]
fn a_replace_failed_or_cut_at_any_call_leaves_a_complete_folder() {
    for exchange in [true, false] {
        let mut fail_at = 0;
        loop {
            let mut through = false;
            for cut in [Cut::Kill, Cut::Power(0), Cut::Power(1), Cut::Power(2)] {
                let context = format!("exchange {exchange}, call {fail_at} failed, {cut:?}");
                let result = std::panic::catch_unwind(|| replace_and_cut(exchange, fail_at, cut));
                let Some((version, done)) =
                    result.unwrap_or_else(|_| panic!("{context}: see the panic above"))
                else {
                    continue;
                };
                through = done;
                if done && matches!(cut, Cut::Kill | Cut::Power(0)) {
                    assert_eq!(version, 2, "{context}: the replace was through");
                }
            }
            if through {
                break;
            }
            fail_at += 1;
        }
    }
}
