//! The cache folder, and the config's default synthetic dataset kept in it.

use std::path::PathBuf;

use crate::config::SyntheticDataConfig;
use crate::error::{Result, TrainError};

/// Environment variable naming the cache folder.
pub const CACHE_ENV: &str = "PRISM_CACHE_DIR";

/// The cache folder: `$PRISM_CACHE_DIR` when set, else the platform's cache folder with
/// `prism` in it (`$XDG_CACHE_HOME/prism` or `~/.cache/prism` on Linux,
/// `~/Library/Caches/prism` on macOS, `%LOCALAPPDATA%\prism` on Windows), else `.cache/prism`
/// under the current folder.
pub fn cache_dir() -> PathBuf {
    let var = |name: &str| std::env::var_os(name).filter(|v| !v.is_empty()).map(PathBuf::from);
    if let Some(dir) = var(CACHE_ENV) {
        return dir;
    }
    let platform = if cfg!(target_os = "windows") {
        var("LOCALAPPDATA")
    } else if cfg!(target_os = "macos") {
        var("HOME").map(|h| h.join("Library").join("Caches"))
    } else {
        var("XDG_CACHE_HOME").or_else(|| var("HOME").map(|h| h.join(".cache")))
    };
    platform
        .unwrap_or_else(|| PathBuf::from(".cache"))
        .join("prism")
}

/// The cache folder of the synthetic dataset `data` describes: a name made from every setting,
/// so that different settings never share a folder.
pub fn synthetic_dataset_dir(data: &SyntheticDataConfig) -> PathBuf {
    cache_dir().join("datasets").join(format!(
        "synth-v1-n{}-r{}-seed{}-test{}-ss{}",
        data.subjects, data.resolution, data.seed, data.test_fraction, data.supersample
    ))
}

/// The synthetic dataset of `data`, synthesised into [`synthetic_dataset_dir`] if needed.
///
/// # Errors
/// Synthesis errors.
pub fn ensure_synthetic_dataset(data: &SyntheticDataConfig, _progress: bool) -> Result<PathBuf> {
    let dir = synthetic_dataset_dir(data);
    Err(TrainError::RunFolder {
        path: dir,
        message: "synthesis is not available yet; pass --data".into(),
    })
}
