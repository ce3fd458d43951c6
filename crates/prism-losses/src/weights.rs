//! Where the LPIPS weights are found.
//!
//! The weights (`lpips_alex.safetensors`, 9.9 MB, see `data/LPIPS_PROVENANCE.md`) are committed
//! under the workspace's `data/` folder and read at run time; they are never downloaded and
//! never embedded in the binary.

use std::path::{Path, PathBuf};

use crate::LossError;

/// File name of the LPIPS v0.1 AlexNet weights.
pub const LPIPS_WEIGHTS_FILE: &str = "lpips_alex.safetensors";

/// Environment variable that names the LPIPS weight file explicitly.
pub const LPIPS_WEIGHTS_ENV: &str = "PRISM_LPIPS_WEIGHTS";

/// The LPIPS weight file to use.
///
/// Search order:
/// 1. `explicit` (e.g. a `--lpips-weights` argument), which must exist;
/// 2. the environment variable `PRISM_LPIPS_WEIGHTS`, which must exist when set (no fallback, so
///    that a wrong setting is reported rather than silently replaced);
/// 3. `data/lpips_alex.safetensors` under the current directory;
/// 4. `data/lpips_alex.safetensors` under the workspace this crate was built from;
/// 5. next to the executable: `lpips_alex.safetensors` and `data/lpips_alex.safetensors` in its
///    folder (for an installed binary with the file copied beside it).
///
/// # Errors
/// [`LossError::WeightsNotFound`] naming every path tried, or
/// [`LossError::WeightsEnvMissing`] when the environment variable names no file.
pub fn find_lpips_weights(explicit: Option<&Path>) -> Result<PathBuf, LossError> {
    if let Some(path) = explicit {
        return existing(path.to_path_buf());
    }
    if let Some(value) = std::env::var_os(LPIPS_WEIGHTS_ENV).filter(|v| !v.is_empty()) {
        let path = PathBuf::from(value);
        return if path.is_file() {
            Ok(path)
        } else {
            Err(LossError::WeightsEnvMissing(path))
        };
    }
    let mut tried = vec![
        Path::new("data").join(LPIPS_WEIGHTS_FILE),
        workspace_root().join("data").join(LPIPS_WEIGHTS_FILE),
    ];
    if let Some(dir) = std::env::current_exe()
        .ok()
        .and_then(|exe| exe.parent().map(Path::to_path_buf))
    {
        tried.push(dir.join(LPIPS_WEIGHTS_FILE));
        tried.push(dir.join("data").join(LPIPS_WEIGHTS_FILE));
    }
    match tried.iter().find(|p| p.is_file()) {
        Some(found) => Ok(found.clone()),
        None => Err(LossError::WeightsNotFound { tried }),
    }
}

/// The workspace this crate was built from (two levels above its manifest).
fn workspace_root() -> PathBuf {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    manifest
        .parent()
        .and_then(Path::parent)
        .unwrap_or(manifest)
        .to_path_buf()
}

fn existing(path: PathBuf) -> Result<PathBuf, LossError> {
    if path.is_file() {
        Ok(path)
    } else {
        Err(LossError::WeightsNotFound { tried: vec![path] })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn explicit_path_must_exist_and_is_named_in_the_error() {
        let missing = Path::new("/nonexistent/prism/lpips.safetensors");
        let err = find_lpips_weights(Some(missing)).unwrap_err();
        assert!(
            err.to_string()
                .contains("/nonexistent/prism/lpips.safetensors")
        );
        let workspace = workspace_root().join("data").join(LPIPS_WEIGHTS_FILE);
        assert_eq!(find_lpips_weights(Some(&workspace)).unwrap(), workspace);
    }
}
