//! End-to-end tests of `prism body` through the built binary.

use std::path::PathBuf;
use std::process::{Command, Output};

fn scratch(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("prism-body-{}-{test}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn prism(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_prism"))
        .arg("body")
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn synth_writes_a_model_that_loads_and_info_describes_it() {
    let dir = scratch("synth");
    let out = dir.join("body.npz");
    let run = prism(&["synth", "--out", out.to_str().unwrap(), "--seed", "2"]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(String::from_utf8_lossy(&run.stdout).contains("procedural:2"));
    // Only the model file: the temporary file was renamed.
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
    let model = prism_body::BodyModel::load_npz(&out).unwrap();
    assert_eq!(
        model.into_arrays(),
        prism_body::BodyModel::procedural(2).into_arrays()
    );
    let info = prism(&["info", out.to_str().unwrap()]);
    assert!(info.status.success());
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(text.contains("SMPL-X tree: yes"), "{text}");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_bad_model_file_is_one_clear_error() {
    let dir = scratch("bad");
    let bad = dir.join("broken.npz");
    std::fs::write(&bad, b"not a zip archive").unwrap();
    let run = prism(&["info", bad.to_str().unwrap()]);
    assert_eq!(run.status.code(), Some(1));
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(
        err.starts_with("error: ") && err.contains("broken.npz"),
        "{err}"
    );
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(!err.contains("panicked"));
    let run = prism(&[
        "synth",
        "--out",
        dir.join("missing/dir/x.npz").to_str().unwrap(),
    ]);
    assert_eq!(run.status.code(), Some(1));
    std::fs::remove_dir_all(dir).unwrap();
}
