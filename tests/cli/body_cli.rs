//! End-to-end tests of `prism body` through the built binary.

use crate::common;

use common::{failure, prism, run, s, scratch, stdout, success};

#[test]
fn synth_writes_a_model_that_loads_and_info_describes_it() {
    let dir = scratch("synth");
    let out = dir.join("body.npz");
    let synth = success(prism(&["body", "synth", "--out", s(&out), "--seed", "2"]));
    assert!(stdout(&synth).contains("procedural:2"));
    // Only the model file: the temporary file was renamed.
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
    let model = prism_body::BodyModel::load_npz(&out).unwrap();
    assert_eq!(
        model.into_arrays(),
        prism_body::BodyModel::procedural(2).into_arrays()
    );
    let info = success(prism(&["body", "info", s(&out)]));
    let text = stdout(&info);
    assert!(text.contains("SMPL-X tree: yes"), "{text}");
}

#[test]
fn a_bad_model_file_is_one_clear_error() {
    let dir = scratch("bad");
    let bad = dir.join("broken.npz");
    std::fs::write(&bad, b"not a zip archive").unwrap();
    // Exit status 1, one line `error: ...`, no panic.
    let err = failure(prism(&["body", "info", s(&bad)]));
    assert!(err.contains("broken.npz"), "{err}");
    let out = run(&["body", "synth", "--out", s(&dir.join("missing/dir/x.npz"))]);
    assert_eq!(out.status.code(), Some(1));
}
