//! End-to-end tests of `prism data render` through the built binary, on scans written here in
//! THuman's layout (`NNNN/NNNN.obj`, `material0.mtl`, `material0.jpeg`).

use crate::common;

use std::path::Path;
use std::process::Output;

use prism_body::BodyParams;
use prism_data::DatasetReader;

use common::{run, stderr, stdout};

/// Writes `scans/name` as THuman lays a scan out, here a person-sized box in centimetres with
/// Z up (front towards -Y): the front textured by `material0.jpeg` (written when `texture`),
/// the rest in a flat second material, all quads.
fn write_scan(scans: &Path, name: &str, texture: bool) {
    let dir = scans.join(name);
    std::fs::create_dir_all(&dir).unwrap();
    if texture {
        image::RgbImage::from_fn(32, 32, |x, y| {
            image::Rgb([(x * 8) as u8, (y * 8) as u8, 120])
        })
        .save(dir.join("material0.jpeg"))
        .unwrap();
    }
    std::fs::write(
        dir.join("material0.mtl"),
        "newmtl material0\nKd 1 1 1\nmap_Kd material0.jpeg\nnewmtl hair\nKd 0.1 0.05 0.0\n",
    )
    .unwrap();
    let (x, y, z) = ([-22.0, 23.0], [-12.0, 13.0], [5.0, 175.0]);
    let mut obj = String::from("mtllib material0.mtl\n");
    for k in 0..8 {
        obj += &format!("v {} {} {}\n", x[k & 1], y[(k >> 2) & 1], z[(k >> 1) & 1]);
    }
    obj += "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl material0\nf 1/1 2/2 4/3 3/4\n";
    obj += "usemtl hair\nf 6 5 7 8\nf 5 1 3 7\nf 2 6 8 4\nf 3 4 8 7\nf 5 6 2 1\n";
    std::fs::write(dir.join(format!("{name}.obj")), obj).unwrap();
}

fn render(scans: &Path, out: &Path) -> Output {
    run(&[
        "data",
        "render",
        "--scans",
        scans.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--res",
        "32",
        "--supersample",
        "1",
        "--up",
        "z",
        "--facing",
        "+z",
        "--test-fraction",
        "0.34",
    ])
}

#[test]
fn render_reports_failures_checks_and_reruns() {
    let tmp = tempfile::tempdir().unwrap();
    let scans = tmp.path().join("THuman2.1_Release");
    let data = tmp.path().join("ds");
    write_scan(&scans, "0000", true);
    let mut fit = BodyParams::rest("procedural:0");
    fit.pose[0] = [std::f32::consts::FRAC_PI_2, 0.0, 0.0];
    fit.scale = 100.0;
    fit.transl = [0.0, 0.0, 90.0];
    fit.save(scans.join("0000/smplx.json")).unwrap();
    write_scan(&scans, "0001", false);
    write_scan(&scans, "0002", true);
    std::fs::write(scans.join("0002/0002.obj"), "v 0 0 0\nv 1 0\n").unwrap();

    // The broken scan is reported with its file and line, the others render, status 1.
    let out = render(&scans, &data);
    assert_eq!(
        out.status.code(),
        Some(1),
        "{}{}",
        stdout(&out),
        stderr(&out)
    );
    let err = stderr(&out);
    assert!(
        err.contains("warning: 0001:") && err.contains("material0.jpeg"),
        "{err}"
    );
    assert!(
        err.contains("error: 0002:") && err.contains("0002.obj:2"),
        "{err}"
    );
    assert!(
        err.contains("1 subject(s) could not be rendered: 0002"),
        "{err}"
    );
    // Its progress on a pipe comes as plain lines (the first one at once), with no terminal
    // escapes.
    assert!(
        err.contains("render ") && err.contains("/315 views"),
        "{err}"
    );
    assert!(!err.contains('\u{1b}'), "{err}");
    assert!(
        stdout(&out).contains("2 subjects rendered (1 with a body fit), 0 already there, 1 failed"),
        "{}",
        stdout(&out)
    );

    // The result is a valid dataset of the rendered subjects.
    let check = run(&["data", "check", data.to_str().unwrap()]);
    assert!(
        check.status.success() && stdout(&check).contains("ok (2 subjects, 210 views)"),
        "{}{}",
        stdout(&check),
        stderr(&check)
    );
    let reader = DatasetReader::open(&data).unwrap();
    assert_eq!(reader.meta().subjects, vec!["0000", "0001"]);
    for name in ["0000", "0001"] {
        let record = reader.subject_record(name).unwrap();
        assert!((record.height - 1.80).abs() <= 0.05, "{}", record.height);
        let ys: Vec<f32> = reader
            .points(name)
            .unwrap()
            .points
            .iter()
            .filter(|p| **p != [0.0; 3])
            .map(|p| p[1])
            .collect();
        let hi = ys.iter().copied().fold(f32::MIN, f32::max);
        let lo = ys.iter().copied().fold(f32::MAX, f32::min);
        // At 32 px a pixel spans about 6.6 cm on the subject.
        assert!((-1e-4..0.14).contains(&lo), "{name}: {lo}");
        assert!(
            hi <= record.height + 1e-4 && hi > record.height - 0.14,
            "{name}: {hi}"
        );
        assert!(
            hi - lo > 1.60 && hi - lo <= 1.85 + 1e-4,
            "{name}: {lo}..{hi}"
        );
    }
    assert!(reader.body_path("0000").exists() && !reader.body_path("0001").exists());
    let body = BodyParams::load(reader.body_path("0000")).unwrap();
    assert!(
        (body.scale - 100.0 * 1.8 / 170.0).abs() < 0.06,
        "{}",
        body.scale
    );

    // A rerun skips the finished subjects and still reports the broken one.
    let out = render(&scans, &data);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        stdout(&out).contains("0 subjects rendered (0 with a body fit), 2 already there, 1 failed"),
        "{}",
        stdout(&out)
    );
    // Fixed, it renders and the command succeeds.
    write_scan(&scans, "0002", true);
    let out = render(&scans, &data);
    assert!(out.status.success(), "{}{}", stdout(&out), stderr(&out));
    assert!(
        stdout(&out).contains("1 subjects rendered"),
        "{}",
        stdout(&out)
    );
    let check = run(&["data", "check", data.to_str().unwrap()]);
    assert!(
        stdout(&check).contains("ok (3 subjects, 315 views)"),
        "{}",
        stdout(&check)
    );
    let meta = DatasetReader::open(&data).unwrap().meta().clone();
    assert_eq!(meta.split.test, vec!["0002"]);
}

#[test]
fn render_rejects_bad_arguments_with_one_line() {
    let tmp = tempfile::tempdir().unwrap();
    let scans = tmp.path().join("scans");
    write_scan(&scans, "a", true);
    let out_dir = tmp.path().join("ds");
    let render_with = |extra: &[&str]| {
        let mut args = vec![
            "data",
            "render",
            "--scans",
            scans.to_str().unwrap(),
            "--out",
            out_dir.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        run(&args)
    };
    for (extra, expected) in [
        (&["--facing", "up"][..], "facing must be one of"),
        (&["--up", "x"][..], "up axis must be y or z"),
        (&["--res", "4"][..], "at least 8 px"),
        (&["--background", "1,2,0"][..], "[0, 1]"),
    ] {
        let out = render_with(extra);
        assert_eq!(
            out.status.code(),
            Some(if extra[0] == "--res" { 1 } else { 2 })
        );
        assert!(
            stderr(&out).contains(expected),
            "{extra:?}: {}",
            stderr(&out)
        );
        assert!(!stderr(&out).contains("panicked"));
    }
    assert!(!out_dir.exists(), "nothing written for bad arguments");
    let out = run(&[
        "data",
        "render",
        "--scans",
        tmp.path().join("missing").to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        stderr(&out).contains("missing: no such scans folder"),
        "{}",
        stderr(&out)
    );
}
