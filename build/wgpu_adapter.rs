//! Build script of the packages with GPU tests (`prism`, `prism-render`): sets the cfg
//! `wgpu_adapter` when this machine looks like it has a wgpu adapter, so that where it has
//! none the GPU tests are listed as ignored (`#[cfg_attr(not(wgpu_adapter), ignore = ...)]`),
//! not as passed. The look is a guess (a Vulkan driver's manifest, or macOS or Windows, whose
//! Metal and DX12 are always there), so the tests still check for a working adapter at run
//! time: they skip, saying so, where the guess was wrong, and fail under `PRISM_REQUIRE_WGPU`
//! (set by CI, whose `.ci/run` installs Mesa's lavapipe before it builds). The variable is not
//! read here: changing it would rebuild the packages.
//!
//! The guess is redone whenever a driver is installed or removed, so that a target folder
//! built before Mesa's lavapipe was installed does not keep its GPU tests ignored: cargo reruns
//! this script when one of the loader's variables naming driver manifests changes, and when a
//! manifest folder changes or, where it does not exist yet, its nearest existing ancestor
//! (`BASE/vulkan`, or for the data folders the base itself, which the package creating
//! `vulkan/icd.d` changes). Cargo walks a watched folder on every build: `/usr/share` (some
//! 50 000 entries, under a second) is watched only where it has no `vulkan` folder, and then
//! any package installed reruns the guess and rebuilds the two packages (and their dependents).

use std::path::Path;

/// The bases of the Vulkan loader's manifest search path on Linux: drivers put their manifests
/// in `BASE/vulkan/icd.d`. With each, whether the base itself is watched where `BASE/vulkan`
/// is missing: yes for the data folders, where driver packages (Mesa's) put their manifests,
/// so that the first driver installed is seen; no for the configuration folders, which change
/// whenever a library is installed (`/etc/ld.so.cache`) and would rerun the guess for nothing.
/// (The XDG folder `/etc/xdg` is left out: desktop packages, such as the Chromium that CI
/// installs while it builds, add autostart entries to it.)
const ICD_BASES: [(&str, bool); 4] = [
    ("/usr/share", true),
    ("/etc", false),
    ("/usr/local/share", true),
    ("/usr/local/etc", false),
];

/// The loader's variables that name driver manifests, replacing or adding to the folders.
const ICD_VARIABLES: [&str; 3] = ["VK_ICD_FILENAMES", "VK_DRIVER_FILES", "VK_ADD_DRIVER_FILES"];

fn main() {
    println!("cargo::rustc-check-cfg=cfg(wgpu_adapter)");
    let mut vulkan = false;
    for variable in ICD_VARIABLES {
        println!("cargo::rerun-if-env-changed={variable}");
        vulkan |= std::env::var_os(variable).is_some_and(|v| !v.is_empty());
    }
    for (base, watch_base) in ICD_BASES {
        let icd = Path::new(base).join("vulkan/icd.d");
        // `icd.d`, `vulkan`, then the base.
        let depth = if watch_base { 3 } else { 2 };
        if let Some(watched) = icd.ancestors().take(depth).find(|p| p.is_dir()) {
            println!("cargo::rerun-if-changed={}", watched.display());
        }
        vulkan |= has_manifest(&icd);
    }
    let os = std::env::var("CARGO_CFG_TARGET_OS").unwrap_or_default();
    let native = os == "macos" || os == "windows";
    if vulkan || native {
        println!("cargo::rustc-cfg=wgpu_adapter");
    }
}

/// Whether `dir` holds a driver manifest (a `.json` file).
fn has_manifest(dir: &Path) -> bool {
    std::fs::read_dir(dir).is_ok_and(|entries| {
        entries
            .flatten()
            .any(|e| e.path().extension().is_some_and(|x| x == "json"))
    })
}
