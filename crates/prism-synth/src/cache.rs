//! The cache folder, and the config's default synthetic dataset kept in it.

use std::path::{Path, PathBuf};

use prism_core::progress::progress_bar;
use prism_core::protocol::NUM_VIEWS;
use prism_data::{DataError, SynthOptions};

use crate::synth::synth_dataset;

/// Environment variable naming the cache folder.
pub const CACHE_ENV: &str = "PRISM_CACHE_DIR";

/// The cache folder: `$PRISM_CACHE_DIR` when set, else the platform's cache folder with
/// `prism` in it (`$XDG_CACHE_HOME/prism` or `~/.cache/prism` on Linux,
/// `~/Library/Caches/prism` on macOS, `%LOCALAPPDATA%\prism` on Windows), else `.cache/prism`
/// under the current folder.
pub fn cache_dir() -> PathBuf {
    let var = |name: &str| {
        std::env::var_os(name)
            .filter(|v| !v.is_empty())
            .map(PathBuf::from)
    };
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

/// The layout of the cached synthetic datasets, in their folder names: a new layout is
/// synthesised afresh instead of reusing an older folder (2: every view stores its depth).
const CACHE_LAYOUT: u32 = 2;

/// The cache folder of the synthetic dataset `data` describes: a name made from every setting
/// and the cache layout, so that different settings never share a folder.
pub fn synthetic_dataset_dir(data: &SynthOptions) -> PathBuf {
    synthetic_dataset_dir_in(&cache_dir(), data)
}

/// [`synthetic_dataset_dir`] under the cache folder `cache` instead of [`cache_dir`]'s.
pub fn synthetic_dataset_dir_in(cache: &Path, data: &SynthOptions) -> PathBuf {
    let [r, g, b] = data.background;
    cache.join("datasets").join(format!(
        "synth-v{CACHE_LAYOUT}-n{}-r{}-seed{}-test{}-ss{}-bg{r}-{g}-{b}",
        data.subjects, data.resolution, data.seed, data.test_fraction, data.supersample
    ))
}

/// The synthetic dataset of `data`: synthesised into [`synthetic_dataset_dir`] by the first run
/// that needs it, reused by the later ones. The writer is atomic per subject, so a synthesis
/// that was killed resumes with the missing subjects. With `progress`, a bar on stderr.
///
/// # Errors
/// Synthesis errors (naming the file).
pub fn ensure_synthetic_dataset(
    options: &SynthOptions,
    progress: bool,
) -> Result<PathBuf, DataError> {
    ensure_synthetic_dataset_in(&cache_dir(), options, progress)
}

/// [`ensure_synthetic_dataset`] under the cache folder `cache` instead of [`cache_dir`]'s (a
/// process that works with several caches at once, such as a test binary).
///
/// # Errors
/// Synthesis errors (naming the file).
pub fn ensure_synthetic_dataset_in(
    cache: &Path,
    options: &SynthOptions,
    progress: bool,
) -> Result<PathBuf, DataError> {
    let dir = synthetic_dataset_dir_in(cache, options);
    let bar = progress_bar(
        progress,
        (options.subjects * NUM_VIEWS) as u64,
        "synthesising the dataset [{bar:30}] {pos}/{len} views {msg} (ETA {eta})",
    );
    let summary = synth_dataset(&dir, options, &|| bar.inc(1), &|name, skipped| {
        if skipped {
            bar.inc(NUM_VIEWS as u64);
        }
        bar.set_message(name.to_string());
    })?;
    bar.finish_and_clear();
    if progress && summary.written > 0 {
        eprintln!(
            "synthesised {} subjects into {}",
            summary.written,
            dir.display()
        );
    }
    Ok(dir)
}
