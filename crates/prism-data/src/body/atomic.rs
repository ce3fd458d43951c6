//! Atomic file writes: write to a temporary file next to the target, sync, then rename.

use std::fs::File;
use std::io;
use std::path::Path;

/// Writes `path` through `write`, which receives a fresh temporary file next to `path` and
/// returns it when done; the temporary file is synced and renamed over `path`, or removed on
/// failure, so that `path` is never half-written.
pub(crate) fn write_atomic(
    path: &Path,
    write: impl FnOnce(File) -> io::Result<File>,
) -> io::Result<()> {
    let name = path
        .file_name()
        .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, "not a file path"))?;
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(name);
    tmp_name.push(format!(".tmp{}", std::process::id()));
    let tmp = path.with_file_name(tmp_name);
    let result = File::create(&tmp)
        .and_then(write)
        .and_then(|file| file.sync_all())
        .and_then(|_| std::fs::rename(&tmp, path));
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}
