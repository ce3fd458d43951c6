//! Helpers shared by the end-to-end tests (the modules of `tests/cli`: a module uses the
//! helpers it needs).
//!
//! - runners: [`prism`] (the built binary with arguments, not yet run), [`prism_with_cache`]
//!   (the same with a private cache folder), [`run`] (`prism ARGS` run at once);
//! - outcomes: [`output`] (whatever the exit status), [`success`] (asserts exit 0) and
//!   [`failure`] (asserts the one-line `error: ` the binary prints on bad input); [`stdout`],
//!   [`stderr`] and [`text`] of an output;
//! - files: [`scratch`] (a fresh folder per test, removed when it passes), [`s`] (a path as an
//!   argument), [`cache`] (this process's dataset cache, holding one synthetic dataset),
//!   [`copy_dir`];
//! - devices: `wgpu_device` (with the `wgpu` feature: the adapter, or a skip, or a failure
//!   under `PRISM_REQUIRE_WGPU`), and [`device_shared`] / [`device_alone`], the wgpu device's
//!   lock.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Mutex, OnceLock, RwLock, RwLockReadGuard, RwLockWriteGuard};

use image::RgbImage;

/// The wgpu device of this process: the tests that run tensors on it share it (their checks
/// compare two paths on the same inputs), and a test that reads the device's memory pool holds
/// it alone ([`device_alone`]), since another test's tensors would change it.
static DEVICE: RwLock<()> = RwLock::new(());

/// Held by a test while it runs tensors on the wgpu device: see [`DEVICE`].
pub fn device_shared() -> RwLockReadGuard<'static, ()> {
    DEVICE
        .read()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// Held by a test that reads the wgpu device's memory pool: see [`DEVICE`].
pub fn device_alone() -> RwLockWriteGuard<'static, ()> {
    DEVICE
        .write()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// `prism ARGS`: the binary this test crate was built with, not yet run (add arguments or
/// environment, then run it with [`output`], [`success`] or [`failure`]).
pub fn prism(args: &[&str]) -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_prism"));
    cmd.args(args).env(prism_synth::CACHE_ENV, cache_dir());
    cmd
}

/// [`prism`] with its cache folder (datasets, downloads) at `cache` and without
/// `PRISM_LPIPS_WEIGHTS` from the caller's environment (the shipped LPIPS weights are used).
pub fn prism_with_cache(cache: &Path, args: &[&str]) -> Command {
    let mut cmd = prism(args);
    cmd.env(prism_synth::CACHE_ENV, cache)
        .env_remove("PRISM_LPIPS_WEIGHTS");
    cmd
}

/// Runs `prism ARGS` and returns its output, whatever the exit status.
pub fn run(args: &[&str]) -> Output {
    output(prism(args))
}

/// Runs `cmd` and returns its output, whatever the exit status.
pub fn output(mut cmd: Command) -> Output {
    cmd.output()
        .unwrap_or_else(|e| panic!("cannot run {cmd:?}: {e}"))
}

/// Runs `cmd`, asserts that it succeeded (showing what it printed if not) and returns its
/// output.
pub fn success(cmd: Command) -> Output {
    let shown = format!("{cmd:?}");
    let out = output(cmd);
    assert!(
        out.status.success(),
        "{shown} failed ({}):\n{}\n{}",
        out.status,
        stdout(&out),
        stderr(&out)
    );
    out
}

/// Runs a command that must fail as the binary fails on bad input: exit status 1 and one line
/// on stderr starting `error: `, no panic. Returns that stderr.
pub fn failure(cmd: Command) -> String {
    let out = output(cmd);
    assert!(!out.status.success(), "expected failure, got {out:?}");
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(err.starts_with("error: "), "{err}");
    assert_eq!(
        err.trim_end().lines().count(),
        1,
        "one line expected: {err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    err
}

/// What a run printed on stdout (lossy UTF-8).
pub fn stdout(out: &Output) -> String {
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// What a run printed on stderr (lossy UTF-8).
pub fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// What a run printed: stdout, then stderr.
pub fn text(out: &Output) -> String {
    stdout(out) + &stderr(out)
}

/// A fresh, empty scratch folder for one test, `N-TEST` in this process's folder (see
/// [`process_root`]). It is removed when the test ends, and kept when the test fails, so that
/// what it wrote can be read; the next run of this test binary removes it then.
pub fn scratch(test: &str) -> Scratch {
    // Numbered: the tests of this binary run side by side, and two may pick the same name.
    static NEXT: AtomicUsize = AtomicUsize::new(0);
    let dir = process_root().join(format!("{}-{test}", NEXT.fetch_add(1, Ordering::Relaxed)));
    std::fs::create_dir_all(&dir).unwrap();
    Scratch(dir)
}

/// A test's scratch folder ([`scratch`]): a path that removes its folder when dropped, unless
/// the thread is panicking (a failed assertion keeps the test's files).
pub struct Scratch(PathBuf);

impl Scratch {
    /// The folder, kept past this value: for folders the whole process shares, which the next
    /// run of the test binary removes with [`process_root`]'s sweep.
    pub fn keep(self) -> PathBuf {
        let dir = self.0.clone();
        std::mem::forget(self);
        dir
    }
}

impl std::ops::Deref for Scratch {
    type Target = Path;

    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for Scratch {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        if !std::thread::panicking() {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// This process's folder of scratch folders, `prism-CRATE-PID` in the system's temporary
/// folder. Made on first use, which also removes the folders that earlier runs of this test
/// binary left (a failed test's, the shared cache): those whose process no longer runs
/// (Linux; elsewhere they stay).
pub fn process_root() -> &'static Path {
    static ROOT: OnceLock<PathBuf> = OnceLock::new();
    ROOT.get_or_init(|| {
        let prefix = format!("prism-{}-", env!("CARGO_CRATE_NAME"));
        let temp = std::env::temp_dir();
        // Without `/proc`, whether a process still runs is not known: nothing is removed.
        if Path::new("/proc/self").exists() {
            remove_ended_roots(&temp, &prefix);
        }
        let root = temp.join(format!("{prefix}{}", std::process::id()));
        std::fs::create_dir_all(&root).unwrap();
        root
    })
}

/// Removes the folders `PREFIX + PID` in `temp` whose process no longer runs (`/proc/PID`).
fn remove_ended_roots(temp: &Path, prefix: &str) {
    for entry in std::fs::read_dir(temp).into_iter().flatten().flatten() {
        let name = entry.file_name();
        let pid = name.to_str().and_then(|n| n.strip_prefix(prefix));
        let ended = pid.is_some_and(|pid| {
            pid.parse::<u32>().is_ok() && !Path::new("/proc").join(pid).exists()
        });
        if ended {
            let _ = std::fs::remove_dir_all(entry.path());
        }
    }
}

/// configs/tiny.toml at 32 px (LPIPS's minimum is 31) on 4 synthetic subjects of 32 px, 1 held
/// out, without LPIPS in the loss (its backward is slow on ndarray; evaluations still score it)
/// and without validation during training: the end-to-end tests' model and dataset.
pub fn tiny_at_32px() -> prism_train::TrainingConfig {
    let path = prism_train::configs_dir().join("tiny.toml");
    let mut c = prism_train::TrainingConfig::load(path).unwrap();
    c.model.resolution = 32;
    c.losses.lpips = 0.0;
    c.train.validate_every = 0;
    c.train.validation_views = 2;
    c.data.subjects = 4;
    c.data.resolution = 32;
    c.data.test_fraction = 0.25;
    c
}

/// The cache folder shared by this test process's tests (the children of [`prism`] get it as
/// `$PRISM_CACHE_DIR`; a test with a private cache uses [`prism_with_cache`]). The process's
/// environment is never changed: its tests run side by side.
pub fn cache_dir() -> PathBuf {
    static CACHE: OnceLock<PathBuf> = OnceLock::new();
    CACHE.get_or_init(|| scratch("cache").keep()).clone()
}

/// [`cache_dir`], holding the synthetic dataset `data` describes (synthesised by the first
/// test that asks for it, while the others wait).
pub fn cache(data: &prism_data::SynthOptions) -> PathBuf {
    static SYNTHESIS: Mutex<()> = Mutex::new(());
    let dir = cache_dir();
    let _one = SYNTHESIS
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner());
    prism_synth::ensure_synthetic_dataset_in(&dir, data, false).unwrap();
    dir
}

/// Copies the folder `from` to `to`, recursively.
pub fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).unwrap();
        }
    }
}

/// `p` as a command-line argument (test paths are UTF-8).
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// PSNR (dB) of two 8-bit RGB images as the metric defines it: `10 log10(1 / MSE)` over all
/// pixels and channels, values in [0, 1].
pub fn psnr_8bit(a: &RgbImage, b: &RgbImage) -> f64 {
    assert_eq!(a.dimensions(), b.dimensions());
    let mse = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(&x, &y)| ((x as f64 - y as f64) / 255.0).powi(2))
        .sum::<f64>()
        / a.as_raw().len() as f64;
    10.0 * (1.0 / mse).log10()
}

/// Asserts that `path` is a run's training-curves PNG: the plot's size, curves drawn on white
/// (between 2 % and half of the pixels not white).
pub fn assert_training_curves(path: &Path) {
    let plot = image::open(path).unwrap().to_rgb8();
    assert_eq!(plot.dimensions(), prism_train::PLOT_SIZE);
    let drawn = plot.pixels().filter(|p| p.0 != [255, 255, 255]).count();
    let total = plot.pixels().len();
    assert!(
        drawn > total / 50 && drawn < total / 2,
        "{}: {drawn} of {total} pixels drawn",
        path.display()
    );
}

/// The wgpu device when an adapter answers, else `None` (or a panic under CI's
/// `PRISM_REQUIRE_WGPU=1`). CubeCL's autotune runs at its minimal effort in the tests
/// ([`minimal_autotune`]).
#[cfg(feature = "wgpu")]
pub fn wgpu_device() -> Option<burn::tensor::Device> {
    minimal_autotune();
    let device = prism_core::BackendKind::Wgpu
        .device()
        .expect("built with the wgpu feature");
    let probe = device.clone();
    let works = std::panic::catch_unwind(move || {
        burn::tensor::Tensor::<1>::from_floats([1.0, 2.0], &probe)
            .sum()
            .into_scalar::<f32>()
            == 3.0
    });
    match works {
        Ok(true) => Some(device),
        _ if std::env::var_os("PRISM_REQUIRE_WGPU").is_some() => {
            panic!("PRISM_REQUIRE_WGPU is set but no wgpu adapter works (install Mesa's lavapipe)")
        }
        _ => {
            eprintln!("skipped: no wgpu adapter (install mesa-vulkan-drivers for lavapipe)");
            None
        }
    }
}

/// Sets CubeCL's autotune to its minimal effort for this process, before its first kernel,
/// unless `CUBECL_AUTOTUNE_LEVEL` asks for another. The GPU tests compare values, not speed,
/// and on a fresh checkout CubeCL's autotune cache (`target/environment`) is empty: at its
/// default effort it first times every candidate kernel of every matrix-product shape on the
/// adapter (the model's tests, `device::backend`, on lavapipe: 977 s that way, 413 s at minimal
/// effort; BENCHMARKS.md, "A clean CI run on this host, measured").
#[cfg(feature = "wgpu")]
fn minimal_autotune() {
    use cubecl::config::autotune::AutotuneLevel;
    use cubecl::config::{CubeClRuntimeConfig, RuntimeConfig};
    let mut config = CubeClRuntimeConfig::from_current_dir();
    config.autotune.level = AutotuneLevel::Minimal;
    // `false` when CubeCL's settings were already read: an earlier call set them, or something
    // read them first, which the check below tells apart.
    CubeClRuntimeConfig::try_set(config.override_from_env());
    if std::env::var_os("CUBECL_AUTOTUNE_LEVEL").is_none() {
        assert!(
            matches!(
                CubeClRuntimeConfig::get().autotune.level,
                AutotuneLevel::Minimal
            ),
            "CubeCL's settings were read before the tests could set its minimal autotune"
        );
    }
}
