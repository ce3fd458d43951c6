//! The atomic writers under SIGKILL, and a folder replace under injected failures and power
//! cuts.
//! - A child process rewrites one file in a loop through `prism_core::files::write_atomic` and
//!   is killed at arbitrary moments; every time, the file is one complete version (the old one
//!   or a new one), and nothing else is left in its folder but, when the kill fell between
//!   naming a complete copy and renaming it, that hidden copy, which the next write removes.
//! - A child process replaces one folder in a loop through `prism_core::files::replace_dir`
//!   (a checkpoint's write) and is killed at arbitrary moments; every time, `recover_dir` leaves
//!   the folder complete (its files of one version) and nothing beside it.
//! - A folder replace fails at each of its calls, and a kill or a power cut follows
//!   (`power_cut`): `recover_dir` always leaves a complete folder.

#[cfg(unix)]
#[path = "atomic_kill/power_cut.rs"]
mod power_cut;

use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use prism_core::files::{
    STAGED_SUFFIX, recover_dir, replace_dir, with_suffix, write_atomic, write_bytes,
};

/// The variable that turns [`child_rewrites_the_file_forever`] on and names its file.
const TARGET_ENV: &str = "PRISM_ATOMIC_KILL_TARGET";
/// The variable that turns [`child_replaces_the_folder_forever`] on and names its folder.
const FOLDER_ENV: &str = "PRISM_ATOMIC_KILL_FOLDER";
/// Files of one version of the replaced folder.
const FOLDER_FILES: [&str; 3] = ["model.bpk", "optimizer.bpk", "state.json"];
/// Bytes of one version: an 8-byte version number, then the payload.
const PAYLOAD: usize = 4 << 20;
const CHUNK: usize = 64 << 10;
/// The line a child prints (it runs with `--nocapture`) once it has read its first version,
/// before it writes anything.
const STARTED: &str = "atomic_kill child: started";
/// The line a child prints after each write or replace that returned.
const WROTE: &str = "atomic_kill child: wrote a version";
/// Rounds of each kill test: the last one kills after a completed write.
const ROUNDS: usize = 12;

/// The payload byte of version `v`.
fn fill(v: u64) -> u8 {
    (v % 251) as u8 + 1
}

/// Checks that `path` holds one whole version and returns its number.
fn complete_version(path: &Path) -> u64 {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(
        bytes.len(),
        8 + PAYLOAD,
        "a partial file: {} bytes",
        bytes.len()
    );
    let v = u64::from_le_bytes(bytes[..8].try_into().unwrap());
    assert!(
        bytes[8..].iter().all(|&b| b == fill(v)),
        "version {v} mixed with another"
    );
    v
}

fn write_version(out: &mut dyn Write, v: u64) -> std::io::Result<()> {
    out.write_all(&v.to_le_bytes())?;
    let chunk = vec![fill(v); CHUNK];
    for _ in 0..PAYLOAD / CHUNK {
        out.write_all(&chunk)?;
    }
    Ok(())
}

/// Not a test of its own: the child process of [`a_killed_writer_leaves_the_old_or_the_new_file`]
/// (ignored, and a no-op without [`TARGET_ENV`]).
#[test]
#[ignore = "run as a child process by a_killed_writer_leaves_the_old_or_the_new_file"]
fn child_rewrites_the_file_forever() {
    let Some(path) = std::env::var_os(TARGET_ENV) else {
        return;
    };
    let path = Path::new(&path);
    let mut v = complete_version(path);
    println!("{STARTED}");
    loop {
        v += 1;
        write_atomic(path, |out| write_version(out, v)).unwrap();
        println!("{WROTE}");
    }
}

#[test]
fn a_killed_writer_leaves_the_old_or_the_new_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("state.bin");
    let mut first = Vec::new();
    write_version(&mut first, 0).unwrap();
    write_bytes(&path, &first).unwrap();
    let mut seed = 0x2545_f491_u64;
    let (mut changed, mut kept) = (0, 0);
    for round in 0..ROUNDS {
        let before = complete_version(&path);
        // A version takes a few ms: killed mid-write or between.
        let child = kill_midway(
            "child_rewrites_the_file_forever",
            TARGET_ENV,
            &path,
            clock_from(round),
            &mut seed,
        );
        let after = complete_version(&path);
        assert!(
            after >= before,
            "round {round}: went back from {before} to {after}"
        );
        if after > before {
            changed += 1;
        } else {
            kept += 1;
        }
        let staged = format!(".state.bin.tmp-{}-", child);
        let left: Vec<String> = names(dir.path())
            .into_iter()
            .filter(|n| n != "state.bin" && !n.starts_with(".state.bin.tmp-"))
            .collect();
        assert!(left.is_empty(), "round {round}: leftovers {left:?}");
        for name in names(dir.path()) {
            if name.starts_with(&staged) {
                // Killed between naming and renaming: the copy is a complete version.
                complete_version(&dir.path().join(name));
            }
        }
    }
    // The next write removes the copies of the killed writers.
    write_bytes(&path, &std::fs::read(&path).unwrap()).unwrap();
    assert_eq!(names(dir.path()), ["state.bin"], "leftovers after a write");
    // The child did write: some rounds ended on a newer version (the others were killed
    // before their first rename completed).
    assert!(
        changed > 0,
        "no round got past a write ({kept} kept the old file)"
    );
}

/// The child's line after which [`kill_midway`] starts its clock in round `round`: its start,
/// so that the kill falls at any point of its loop however long the process takes to start,
/// and in the last round its first completed write, so that every run checks that a completed
/// write survives the kill (on a slow host the earlier rounds may all end before one).
fn clock_from(round: usize) -> &'static str {
    if round + 1 == ROUNDS { WROTE } else { STARTED }
}

/// Runs `child`, an ignored test of this binary, with `env` naming `target`, and kills it
/// (SIGKILL on Unix: no destructor, no cleanup runs) 5 to 60 ms, drawn from `seed`, after it
/// prints the line `start_line`. Returns its process id.
fn kill_midway(child: &str, env: &str, target: &Path, start_line: &str, seed: &mut u64) -> u32 {
    let mut process = Command::new(std::env::current_exe().unwrap())
        .args(["--exact", child, "--ignored", "--nocapture"])
        .env(env, target)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // Kept open until the kill: a child whose stdout is closed would fail on its next line.
    let mut lines = BufReader::new(process.stdout.take().unwrap()).lines();
    loop {
        match lines.next() {
            Some(Ok(line)) if line == start_line => break,
            Some(Ok(_)) => {}
            _ => panic!("{child} ended before printing {start_line:?}"),
        }
    }
    *seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
    std::thread::sleep(Duration::from_millis(5 + (*seed >> 33) % 56));
    process.kill().unwrap();
    process.wait().unwrap();
    process.id()
}

/// The names in `dir`, sorted.
fn names(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// Writes version `v` of the folder: each of [`FOLDER_FILES`] holds a version of [`PAYLOAD`]
/// bytes.
fn write_folder_version(dir: &Path, v: u64) {
    std::fs::create_dir_all(dir).unwrap();
    for name in FOLDER_FILES {
        let mut bytes = Vec::new();
        write_version(&mut bytes, v).unwrap();
        std::fs::write(dir.join(name), bytes).unwrap();
    }
}

/// Checks that `dir` holds exactly the files of one version, and returns it.
fn complete_folder(dir: &Path) -> u64 {
    assert_eq!(names(dir), FOLDER_FILES, "{}", dir.display());
    let versions: Vec<u64> = FOLDER_FILES
        .iter()
        .map(|name| complete_version(&dir.join(name)))
        .collect();
    assert!(
        versions.iter().all(|&v| v == versions[0]),
        "files of several versions: {versions:?}"
    );
    versions[0]
}

/// Not a test of its own: the child process of
/// [`a_killed_folder_replace_leaves_a_complete_folder`] (ignored, and a no-op without
/// [`FOLDER_ENV`]).
#[test]
#[ignore = "run as a child process by a_killed_folder_replace_leaves_a_complete_folder"]
fn child_replaces_the_folder_forever() {
    let Some(dir) = std::env::var_os(FOLDER_ENV) else {
        return;
    };
    let dir = Path::new(&dir);
    let staged = with_suffix(dir, STAGED_SUFFIX);
    let mut v = complete_folder(dir);
    println!("{STARTED}");
    loop {
        v += 1;
        // What a checkpoint's save does: recover, stage, replace.
        recover_dir(dir).unwrap();
        write_folder_version(&staged, v);
        replace_dir(&staged, dir).unwrap();
        println!("{WROTE}");
    }
}

#[test]
fn a_killed_folder_replace_leaves_a_complete_folder() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("step-00000002");
    write_folder_version(&dir, 0);
    let mut seed = 0x9e37_79b9_u64;
    let (mut changed, mut recovered) = (0, 0);
    for round in 0..ROUNDS {
        let before = complete_folder(&dir);
        // A version is three 4 MiB files, a few ms to write: killed at any point of the loop.
        kill_midway(
            "child_replaces_the_folder_forever",
            FOLDER_ENV,
            &dir,
            clock_from(round),
            &mut seed,
        );
        if recover_dir(&dir).unwrap() {
            recovered += 1;
        }
        let after = complete_folder(&dir);
        assert!(
            after >= before,
            "round {round}: went back from {before} to {after}"
        );
        if after > before {
            changed += 1;
        }
        assert_eq!(
            names(root.path()),
            ["step-00000002"],
            "round {round}: leftovers"
        );
    }
    assert!(changed > 0, "no round got past a replace");
    assert!(recovered > 0, "no round was killed mid-replace");
}
