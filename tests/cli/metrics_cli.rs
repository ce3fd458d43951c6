//! End-to-end tests of `prism metrics` through the built binary (ndarray backend).

use crate::common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::{failure, output, scratch, success};

fn reference(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("crates/prism-losses/tests/reference")
        .join(name)
}

/// `prism metrics --pred PRED --gt GT --backend ndarray EXTRA` (`args` is `[PRED, GT]`) without
/// `PRISM_LPIPS_WEIGHTS` from the caller's environment, with `env` set if given; not yet run.
fn prism(args: &[&Path], extra: &[&str], env: Option<(&str, &str)>) -> Command {
    let mut cmd = common::prism(&["metrics"]);
    cmd.arg("--pred")
        .arg(args[0])
        .arg("--gt")
        .arg(args[1])
        .args(["--backend", "ndarray"])
        .args(extra)
        .env_remove("PRISM_LPIPS_WEIGHTS");
    if let Some((k, v)) = env {
        cmd.env(k, v);
    }
    cmd
}

fn reference_values(name: &str) -> (f64, f64, f64) {
    let text = std::fs::read_to_string(reference("reference.json")).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    let v = &json[name];
    (
        v["psnr"].as_f64().unwrap(),
        v["ssim"].as_f64().unwrap(),
        v["lpips_alex"].as_f64().unwrap(),
    )
}

fn assert_scores(v: &serde_json::Value, expected: (f64, f64, f64)) {
    assert!(
        (v["psnr"].as_f64().unwrap() - expected.0).abs() < 1e-6,
        "{v}"
    );
    assert!(
        (v["ssim"].as_f64().unwrap() - expected.1).abs() < 1e-4,
        "{v}"
    );
    assert!(
        (v["lpips"].as_f64().unwrap() - expected.2).abs() < 1e-3,
        "{v}"
    );
}

#[test]
fn pair_json_reproduces_the_reference() {
    let out = success(prism(
        &[
            &reference("coffee_tint_pred.png"),
            &reference("coffee_tint_target.png"),
        ],
        &["--json"],
        None,
    ));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v.as_object().unwrap().len(), 3);
    assert_scores(&v, reference_values("coffee_tint"));
}

#[test]
fn folder_json_scores_images_by_name_and_averages() {
    let dir = scratch("folders");
    let (pred, gt) = (dir.join("pred"), dir.join("gt"));
    std::fs::create_dir_all(&pred).unwrap();
    std::fs::create_dir_all(&gt).unwrap();
    for name in ["coffee_tint", "astronaut_noise"] {
        std::fs::copy(
            reference(&format!("{name}_pred.png")),
            pred.join(format!("{name}.png")),
        )
        .unwrap();
        std::fs::copy(
            reference(&format!("{name}_target.png")),
            gt.join(format!("{name}.png")),
        )
        .unwrap();
    }
    std::fs::write(gt.join("notes.txt"), "not scored").unwrap();
    let out = success(prism(&[&pred, &gt], &["--json"], None));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let images = v["images"].as_object().unwrap();
    assert_eq!(images.len(), 2);
    let (c, a) = (
        reference_values("coffee_tint"),
        reference_values("astronaut_noise"),
    );
    assert_scores(&images["coffee_tint.png"], c);
    assert_scores(&images["astronaut_noise.png"], a);
    assert_scores(
        &v["mean"],
        ((c.0 + a.0) / 2.0, (c.1 + a.1) / 2.0, (c.2 + a.2) / 2.0),
    );

    // Without --json: a table naming both images and the mean.
    let out = output(prism(&[&pred, &gt], &[], None));
    let table = String::from_utf8(out.stdout).unwrap();
    assert!(
        table.contains("coffee_tint.png") && table.contains("mean of 2"),
        "{table}"
    );

    // An image without a counterpart is named in the error.
    std::fs::copy(reference("coffee_tint_pred.png"), pred.join("extra.png")).unwrap();
    let err = failure(prism(&[&pred, &gt], &["--json"], None));
    assert!(
        err.contains("extra.png") && err.contains("counterpart"),
        "{err}"
    );
}

#[test]
fn different_sizes_are_an_error() {
    let err = failure(prism(
        &[
            &reference("coffee_tint_pred.png"),
            &reference("astronaut_noise_target.png"),
        ],
        &["--json"],
        None,
    ));
    assert!(
        err.contains("sizes differ") && err.contains("192x192") && err.contains("256x256"),
        "{err}"
    );
}

#[test]
fn a_file_that_is_not_an_image_is_an_error() {
    let dir = scratch("not-an-image");
    let fake = dir.join("fake.png");
    std::fs::write(&fake, "this is text, not a PNG").unwrap();
    let err = failure(prism(
        &[&fake, &reference("coffee_tint_target.png")],
        &[],
        None,
    ));
    assert!(
        err.contains("fake.png") && err.contains("not a readable image"),
        "{err}"
    );
}

#[test]
fn missing_weights_are_an_error() {
    let missing = "/nonexistent/prism/lpips_alex.safetensors";
    let err = failure(prism(
        &[
            &reference("coffee_tint_pred.png"),
            &reference("coffee_tint_target.png"),
        ],
        &["--json"],
        Some(("PRISM_LPIPS_WEIGHTS", missing)),
    ));
    assert!(
        err.contains("PRISM_LPIPS_WEIGHTS") && err.contains(missing),
        "{err}"
    );
    let err = failure(prism(
        &[
            &reference("coffee_tint_pred.png"),
            &reference("coffee_tint_target.png"),
        ],
        &["--lpips-weights", missing],
        None,
    ));
    assert!(err.contains(missing), "{err}");
}
