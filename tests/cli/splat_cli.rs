//! End-to-end tests of `prism splat render` through the built binary.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::Command;

use prism_core::camera::mat4_to_rows;
use prism_core::{Camera, Intrinsics};
use prism_render::splat::GaussianCloud;

use common::{failure, prism, s, scratch, stdout, success};

/// A red Gaussian in front of a green one, 2 m in front of a frontal camera; and the camera.
fn scene(dir: &Path) -> (PathBuf, PathBuf) {
    let cloud = GaussianCloud::from_colours(
        vec![[0.0, 0.9, 0.0], [0.05, 0.95, -0.5]],
        vec![[-2.5; 3], [-1.2; 3]],
        vec![[1.0, 0.0, 0.0, 0.0]; 2],
        vec![4.0, 4.0],
        &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
    );
    let ply = dir.join("scene.ply");
    cloud.write(&ply).unwrap();
    let camera = Camera::orbit(
        0.0,
        0.0,
        2.0,
        glam::Vec3::new(0.0, 0.9, 0.0),
        Intrinsics::protocol_default(48, 40),
    );
    let k = camera.intrinsics;
    let json = serde_json::json!({
        "index": 0, "yaw_deg": 0.0, "pitch_deg": 0.0,
        "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy,
        "c2w": mat4_to_rows(&camera.c2w), "width": k.width, "height": k.height,
    });
    let cam = dir.join("cam.json");
    std::fs::write(&cam, serde_json::to_string_pretty(&json).unwrap()).unwrap();
    (ply, cam)
}

/// `prism splat render --ply PLY --camera CAM --out OUT` followed by `extra`, not yet run.
fn render(ply: &Path, cam: &Path, out: &Path, extra: &[&str]) -> Command {
    let mut args = vec![
        "splat",
        "render",
        "--ply",
        s(ply),
        "--camera",
        s(cam),
        "--out",
        s(out),
    ];
    args.extend_from_slice(extra);
    prism(&args)
}

#[test]
fn renders_a_ply_file_into_a_png() {
    let dir = scratch("ok");
    let (ply, cam) = scene(&dir);
    let out = dir.join("out.png");
    success(render(
        &ply,
        &cam,
        &out,
        &["--background", "0,0,1", "--backend", "ndarray"],
    ));
    let image = image::open(&out).unwrap().to_rgb8();
    assert_eq!(image.dimensions(), (48, 40));
    // The red Gaussian covers the centre (the orbit centre projects to (24, 20)).
    let centre = image.get_pixel(23, 19).0;
    assert!(
        centre[0] > 200 && centre[1] < 60 && centre[2] < 60,
        "{centre:?}"
    );
    // Off the small red one but on the wide green one (further away, centred at (24.8, 19.2)).
    let side = image.get_pixel(31, 19).0;
    assert!(side[0] == 0 && side[1] > 80, "{side:?}");
    // The corners show the background.
    assert_eq!(image.get_pixel(0, 0).0, [0, 0, 255]);
    assert_eq!(image.get_pixel(47, 39).0, [0, 0, 255]);
    // The same on flex, the default backend.
    let out_flex = dir.join("flex.png");
    success(render(&ply, &cam, &out_flex, &["--background", "0,0,1"]));
    assert_eq!(image::open(&out_flex).unwrap().to_rgb8(), image);
}

/// Runs `render`, which must fail with one line (exit status 1, `error: `) naming `needle`,
/// writing nothing to `out`.
fn assert_fails(render: Command, needle: &str, out: &Path) {
    let err = failure(render);
    assert!(err.contains(needle), "{err}");
    assert!(!out.exists(), "an output was written");
}

#[test]
fn a_bad_background_is_a_clear_error() {
    let dir = scratch("bg");
    let (ply, cam) = scene(&dir);
    let out = dir.join("out.png");
    for (bg, needle) in [
        ("0,1.5,0", "1.5 is outside [0, 1]"),
        ("0,0", "expected R,G,B"),
        ("a,0,0", "`a` is not a number"),
    ] {
        assert_fails(
            render(&ply, &cam, &out, &["--background", bg]),
            needle,
            &out,
        );
    }
}

#[test]
fn missing_or_broken_inputs_are_errors_naming_the_file() {
    let dir = scratch("missing");
    let (ply, cam) = scene(&dir);
    let out = dir.join("out.png");
    let missing = dir.join("missing.ply");
    assert_fails(render(&missing, &cam, &out, &[]), "missing.ply", &out);
    let broken = dir.join("broken.json");
    std::fs::write(&broken, "{\"fx\": 10}").unwrap();
    assert_fails(render(&ply, &broken, &out, &[]), "broken.json", &out);
    let not_ply = dir.join("cam-as.ply");
    std::fs::copy(&cam, &not_ply).unwrap();
    assert_fails(render(&not_ply, &cam, &out, &[]), "cam-as.ply", &out);
    // An output directory that does not exist: nothing is left behind.
    let nowhere = dir.join("no/such/out.png");
    assert_fails(render(&ply, &cam, &nowhere, &[]), "out.png", &nowhere);
}

#[test]
fn help_describes_the_command() {
    let help = success(prism(&["splat", "render", "--help"]));
    let text = stdout(&help);
    for flag in ["--ply", "--camera", "--out", "--background", "--backend"] {
        assert!(text.contains(flag), "{text}");
    }
}
