//! End-to-end tests of `prism data synth` and `prism data check` through the built binary.

use crate::common;

use std::path::Path;
use std::process::Output;

use common::{run, stderr, text};

fn synth(out: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "data",
        "synth",
        "--out",
        out.to_str().unwrap(),
        "--subjects",
        "3",
        "--res",
        "32",
    ];
    args.extend_from_slice(extra);
    run(&args)
}

#[test]
fn synth_then_check_then_rerun_then_corrupt() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("ds");
    let out = synth(&data, &["--test-fraction", "0.34"]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(text(&out).contains("3 subjects written"), "{}", text(&out));
    // On a pipe its progress comes as plain lines (the first one at once), with no terminal
    // escapes.
    let err = stderr(&out);
    assert!(
        err.contains("synth ") && err.contains("/315 views"),
        "{err}"
    );
    assert!(!err.contains('\u{1b}'), "{err}");

    let out = run(&["data", "check", data.to_str().unwrap()]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(
        text(&out).contains("ok (3 subjects, 315 views)"),
        "{}",
        text(&out)
    );

    // The dataset follows the format: split, 105 cameras, body fits, point map.
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data.join("dataset.json")).unwrap()).unwrap();
    assert_eq!(meta["split"]["test"], serde_json::json!(["subject_0002"]));
    assert_eq!(meta["width"], 32);
    let cams: Vec<serde_json::Value> = serde_json::from_str(
        &std::fs::read_to_string(data.join("subject_0000/cameras.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(cams.len(), 105);
    let body = prism_body::BodyParams::load(data.join("subject_0001/body.json")).unwrap();
    assert!(body.scale > 0.0);
    let subject: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(data.join("subject_0001/subject.json")).unwrap(),
    )
    .unwrap();
    let h = subject["height"].as_f64().unwrap();
    assert!((h - 1.80).abs() <= 0.05 + 1e-6, "height {h}");

    // Every view stores its depth map (16-bit millimetres), 0 exactly where the view's centre
    // rays miss the person; `data check` above compared the source's with the point map.
    for view in [0, 42, 104] {
        let depth = image::open(data.join(format!("subject_0000/depth/{view:03}.png")))
            .unwrap()
            .into_luma16();
        assert_eq!(depth.dimensions(), (32, 32));
        let metres: Vec<f32> = depth.pixels().map(|p| f32::from(p.0[0]) / 1000.0).collect();
        let on: Vec<f32> = metres.iter().copied().filter(|&d| d > 0.0).collect();
        // The protocol's cameras are 2 m from the person, who is a few tens of cm deep.
        assert!(on.len() > 50 && on.len() < metres.len(), "view {view}");
        assert!(on.iter().all(|&d| (1.4..2.6).contains(&d)), "view {view}");
    }

    // A rerun with the same settings skips every finished subject.
    let out = synth(&data, &["--test-fraction", "0.34"]);
    assert!(
        out.status.success() && text(&out).contains("0 subjects written, 3 already there"),
        "{}",
        text(&out)
    );
    // Other settings into the same folder are refused.
    let out = synth(&data, &["--seed", "9"]);
    assert!(
        !out.status.success() && text(&out).contains("other settings"),
        "{}",
        text(&out)
    );

    // A broken file makes check fail, naming it; so does a source depth map that disagrees
    // with the point map.
    std::fs::write(data.join("subject_0001/rgb/042.png"), b"broken").unwrap();
    let source_depth = data.join("subject_0002/depth/000.png");
    let mut depth = image::open(&source_depth).unwrap().into_luma16();
    depth
        .pixels_mut()
        .for_each(|p| p.0[0] = p.0[0].saturating_add(p.0[0].min(5)));
    depth.save(&source_depth).unwrap();
    let out = run(&["data", "check", data.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    for words in [
        "subject_0001/rgb/042.png",
        "subject_0002/points/000.npy",
        "off the source view's depth map",
    ] {
        assert!(text(&out).contains(words), "{words}: {}", text(&out));
    }
}

#[test]
fn synth_is_reproducible_and_rejects_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    for d in [&a, &b] {
        let out = run(&[
            "data",
            "synth",
            "--out",
            d.to_str().unwrap(),
            "--subjects",
            "1",
            "--res",
            "16",
        ]);
        assert!(out.status.success(), "{}", text(&out));
    }
    for f in [
        "subject_0000/rgb/000.png",
        "subject_0000/rgb/077.png",
        "subject_0000/points/000.npy",
    ] {
        assert_eq!(
            std::fs::read(a.join(f)).unwrap(),
            std::fs::read(b.join(f)).unwrap(),
            "{f}"
        );
    }
    let out = synth(&dir.path().join("c"), &["--background", "2,0,0"]);
    assert!(
        !out.status.success() && text(&out).contains("[0, 1]"),
        "{}",
        text(&out)
    );
    let out = run(&[
        "data",
        "check",
        dir.path().join("nothing").to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out).contains("nothing"), "{}", text(&out));
}
