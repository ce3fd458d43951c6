//! `prism tune attention` on the machine's adapter (lavapipe in CI): it times each kernel at the
//! tiny config's shapes, records the fastest for the adapter and the inputs' precision, and that
//! record is what attention in that precision on the adapter then takes, below
//! `PRISM_ATTENTION` and above the default.
#![cfg(feature = "wgpu")]

use std::path::Path;

use crate::common::{self, s, stderr, stdout, success};
use serde_json::Value;

/// `prism tune attention ARGS` with its cache folder at `cache`, no `PRISM_ATTENTION`, and
/// CubeCL's autotune at its minimal effort unless the caller's environment names one.
fn tune(cache: &Path, args: &[&str]) -> std::process::Command {
    let mut cmd = common::prism_with_cache(cache, &[&["tune", "attention"], args].concat());
    cmd.env_remove("PRISM_ATTENTION");
    if std::env::var_os("CUBECL_AUTOTUNE_LEVEL").is_none() {
        cmd.env("CUBECL_AUTOTUNE_LEVEL", "minimal");
    }
    cmd
}

/// The kernel of the fastest entry of a record's list.
fn fastest(times: &Value) -> &str {
    let times = times.as_array().expect("a list of times");
    let best = times
        .iter()
        .min_by(|a, b| {
            a["ms"]
                .as_f64()
                .unwrap()
                .total_cmp(&b["ms"].as_f64().unwrap())
        })
        .expect("kernels were timed");
    best["kernel"].as_str().unwrap()
}

/// The kernels of a record's list, in order.
fn kernels(times: &Value) -> Vec<&str> {
    times
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["kernel"].as_str().unwrap())
        .collect()
}

#[test]
#[cfg_attr(not(wgpu_adapter), ignore = "no wgpu adapter on this machine")]
fn tuning_attention_records_the_fastest_kernels_and_puts_them_in_force() {
    // The check below runs a tensor on this process's device.
    let _shared = common::device_shared();
    if common::wgpu_device().is_none() {
        return;
    }
    let dir = common::scratch("tune_attention");
    let cache = dir.join("cache");
    let show = || stdout(&success(tune(&cache, &["--show"])));
    const DEFAULT: &str = "inference burn, training unfused (the default";
    let before = show();
    assert!(before.contains(&format!("in f32: {DEFAULT}")), "{before}");

    let config = prism_train::configs_dir().join("tiny.toml");
    let args = [
        "--config",
        s(&config),
        "--res",
        "32",
        "--iters",
        "2",
        "--precision",
        "f32",
    ];
    let out = stdout(&success(tune(&cache, &args)));
    let records: Vec<_> = std::fs::read_dir(cache.join("attention"))
        .expect("the record's folder")
        .map(|entry| entry.unwrap().path())
        .collect();
    assert_eq!(records.len(), 1, "{records:?}");
    let path = &records[0];
    let record: Value = serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
    let adapter = record["adapter"]["name"].as_str().unwrap();
    assert!(
        out.contains(&format!("attention on {adapter} (wgpu)")),
        "{out}"
    );
    let fingerprint = record["adapter"]["fingerprint"].as_str().unwrap();
    assert!(
        path.ends_with(format!("{fingerprint}-f32.json")),
        "{path:?}"
    );
    // The tiny config at 32 px: 4 heads of width 16, a source's and a target's 4 x 4 patches.
    let shape = &record["shape"];
    let dims = ["batch", "heads", "tokens", "head_dim"].map(|k| shape[k].as_u64().unwrap());
    assert_eq!(dims, [1, 4, 32, 16], "{shape}");
    assert_eq!(shape["precision"], "f32");
    assert_eq!(kernels(&record["inference"]), ["burn", "flash", "unfused"]);
    assert_eq!(kernels(&record["training"]), ["flash", "unfused"]);
    for time in record["inference"].as_array().unwrap() {
        assert!(time["ms"].as_f64().unwrap() > 0.0, "{time}");
        assert!(time["kept_bytes"].is_null(), "{time}");
    }
    // With a gradient, matmul-softmax-matmul keeps the 4 x 32 x 32 scores for the backward
    // pass; the flash kernels keep an output and a log-sum-exp per row.
    let kept = |i: usize| record["training"][i]["kept_bytes"].as_u64().unwrap();
    let (flash, unfused) = (kept(0), kept(1));
    assert!(flash >= 4 * 32 * 16 * 4, "flash keeps {flash} bytes");
    let scores = 4 * 32 * 32 * 4;
    assert!(
        unfused >= flash + scores,
        "unfused keeps {unfused}, flash {flash}"
    );
    let choice = &record["choice"];
    let (inference, training) = (fastest(&record["inference"]), fastest(&record["training"]));
    assert_eq!(choice["inference"], inference);
    assert_eq!(choice["training"], training);
    let chosen = format!("inference {inference}, training {training}");
    assert!(out.contains(&format!("fastest: {chosen}")), "{out}");

    // The record is in force on this adapter for f32 inputs, below PRISM_ATTENTION; another
    // precision the adapter has (f16 on lavapipe) keeps the default.
    let after = show();
    let measured = format!(
        "in f32: {chosen} (measured by prism tune attention, {}",
        s(path)
    );
    assert!(after.contains(&measured), "{after}");
    for line in after.lines().filter(|line| !line.contains(" in f32: ")) {
        assert!(line.contains(DEFAULT), "{after}");
    }
    let mut flash_env = tune(&cache, &["--show"]);
    flash_env.env("PRISM_ATTENTION", "flash");
    let set = stdout(&success(flash_env));
    let flash_set = "in f32: inference flash, training flash (PRISM_ATTENTION)";
    assert!(set.contains(flash_set), "{set}");

    // A damaged record is named on stderr and ignored.
    std::fs::write(path, "{").unwrap();
    let damaged = success(tune(&cache, &["--show"]));
    let shown = stdout(&damaged);
    assert!(shown.contains(&format!("in f32: {DEFAULT}")), "{shown}");
    let err = stderr(&damaged);
    assert!(err.contains(&format!("{}: not a record", s(path))), "{err}");
}
