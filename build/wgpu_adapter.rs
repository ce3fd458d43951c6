//! Build script of the packages with GPU tests (`prism`, `prism-render`): sets the cfg
//! `wgpu_adapter` when this machine looks like it has a wgpu adapter, so that where it has
//! none the GPU tests are listed as ignored (`#[cfg_attr(not(wgpu_adapter), ignore = ...)]`),
//! not as passed. The look is a guess (a Vulkan driver's manifest, or macOS or Windows, whose
//! Metal and DX12 are always there), so the tests still check for a working adapter at run
//! time: they skip, saying so, where the guess was wrong, and fail under `PRISM_REQUIRE_WGPU`
//! (set by CI, whose `.ci/run` installs Mesa's lavapipe before it builds). The variable is not
//! read here: changing it would rebuild the packages.

/// Where Vulkan drivers put their manifests (the loader's search path on Linux).
const ICD_DIRS: [&str; 4] = [
    "/usr/share/vulkan/icd.d",
    "/etc/vulkan/icd.d",
    "/usr/local/share/vulkan/icd.d",
    "/usr/local/etc/vulkan/icd.d",
];

fn main() {
    println!("cargo::rustc-check-cfg=cfg(wgpu_adapter)");
    println!("cargo::rerun-if-env-changed=VK_ICD_FILENAMES");
    let mut vulkan = std::env::var_os("VK_ICD_FILENAMES").is_some();
    for dir in ICD_DIRS {
        if let Ok(mut entries) = std::fs::read_dir(dir) {
            println!("cargo::rerun-if-changed={dir}");
            vulkan |= entries.next().is_some();
        }
    }
    let os = std::env::var("CARGO_CFG_TARGET_OS").unwrap_or_default();
    let native = os == "macos" || os == "windows";
    if vulkan || native {
        println!("cargo::rustc-cfg=wgpu_adapter");
    }
}
