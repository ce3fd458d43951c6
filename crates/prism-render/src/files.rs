//! Writing files so that nothing half-written is ever left behind.

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::RenderError;

/// Writes `bytes` to a temporary file next to `path`, then renames it into place: `path` is
/// either untouched or complete. The temporary file is removed on failure.
///
/// # Errors
/// [`RenderError::Io`] naming `path`.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), RenderError> {
    let tmp = temporary_path(path);
    let result = (|| {
        let mut file = std::fs::File::create(&tmp)?;
        file.write_all(bytes)?;
        file.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(RenderError::io(path, e));
    }
    Ok(())
}

/// `dir/.name.tmp-PID`, in the same directory so that the rename stays on one file system.
fn temporary_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.tmp-{}", std::process::id()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_completely_or_not_at_all() {
        let dir = std::env::temp_dir().join(format!("prism-render-files-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.bin");
        write_atomically(&path, b"hello").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"hello");
        // A directory that does not exist: an error naming the file, nothing left behind.
        let missing = dir.join("no/such/dir/b.bin");
        let err = write_atomically(&missing, b"x").unwrap_err();
        assert!(err.to_string().contains("b.bin"), "{err}");
        let left: Vec<_> = std::fs::read_dir(&dir).unwrap().collect();
        assert_eq!(left.len(), 1);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
