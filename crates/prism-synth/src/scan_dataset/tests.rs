//! `render_scans` on small scan folders written here: a person-sized slab in millimetres, off
//! centre, with a textured front (four coloured quadrants) and flat-coloured sides, as quads in
//! two materials.

use std::cell::RefCell;
use std::path::{Path, PathBuf};

use glam::Vec3;
use image::{Rgb, RgbImage};

use super::*;
use prism_body::BodyParams;
use prism_core::camera::mat4_from_rows;
use prism_data::{DatasetReader, check_dataset};

const RES: u32 = 64;

/// The slab's corners in the file (millimetres, Y up, facing +Z): x, y and z ranges.
const X: [f32; 2] = [275.0, 725.0];
const Y: [f32; 2] = [300.0, 2000.0];
const Z: [f32; 2] = [-250.0, -150.0];

/// Colours of the texture's quadrants: top-left, top-right, bottom-left, bottom-right.
const QUADRANTS: [[u8; 3]; 4] = [[220, 40, 40], [40, 200, 60], [40, 60, 220], [230, 210, 40]];
/// The flat colour of the sides and back.
const CLOTH: [f32; 3] = [0.2, 0.3, 0.8];

fn options() -> ScanDatasetOptions {
    ScanDatasetOptions {
        resolution: RES,
        supersample: 1,
        test_fraction: 0.34,
        ..Default::default()
    }
}

/// Writes subject folder `scans/name` with the slab; its front uses texture `texture`
/// (written as the four quadrants when `write_texture`).
fn write_person(scans: &Path, name: &str, texture: &str, write_texture: bool) -> PathBuf {
    let dir = scans.join(name);
    std::fs::create_dir_all(&dir).unwrap();
    if write_texture {
        RgbImage::from_fn(
            64,
            64,
            |x, y| Rgb(QUADRANTS[(y / 32 * 2 + x / 32) as usize]),
        )
        .save(dir.join(texture))
        .unwrap();
    }
    std::fs::write(
        dir.join("material0.mtl"),
        format!(
            "newmtl skin\nKd 1 1 1\nmap_Kd {texture}\n\nnewmtl cloth\nKd {} {} {}\n",
            CLOTH[0], CLOTH[1], CLOTH[2]
        ),
    )
    .unwrap();
    let mut obj = String::from("mtllib material0.mtl\n");
    // Corner k: x = X[k & 1], y = Y[(k >> 1) & 1], z = Z[k >> 2].
    for k in 0..8 {
        obj += &format!("v {} {} {}\n", X[k & 1], Y[(k >> 1) & 1], Z[k >> 2]);
    }
    obj += "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n";
    // The front (z = Z[1]) counter-clockwise from outside, with UVs; then the cloth quads.
    obj += "usemtl skin\nf 5/1 6/2 8/3 7/4\n";
    obj += "usemtl cloth\nf 2 1 3 4\nf 1 5 7 3\nf 6 2 4 8\nf 3 7 8 4\nf 1 2 6 5\n";
    let path = dir.join(format!("{name}.obj"));
    std::fs::write(&path, obj).unwrap();
    path
}

/// A body fit of subject folder `dir` in the scan's millimetres.
fn write_fit(dir: &Path, file: &str) -> BodyParams {
    let mut fit = BodyParams::rest("procedural:0");
    fit.betas[1] = 0.7;
    fit.pose[0] = [0.1, 0.4, -0.05];
    fit.pose[17] = [0.0, 0.0, 1.1];
    fit.expression[0] = 0.5;
    fit.scale = 1000.0;
    fit.transl = [500.0, 300.0, -200.0];
    fit.save(dir.join(file)).unwrap();
    fit
}

/// Runs `render_scans`, collecting the events as lines.
fn run(scans: &Path, out: &Path, options: &ScanDatasetOptions) -> (ScanSummary, Vec<String>) {
    let events = RefCell::new(Vec::new());
    let summary = render_scans(scans, out, options, &|| {}, &|e| {
        events.borrow_mut().push(match e {
            ScanEvent::Planned {
                subjects,
                to_render,
            } => format!("planned {subjects} {to_render}"),
            ScanEvent::Skipped(s) => format!("skipped {s}"),
            ScanEvent::Warning { subject, message } => format!("warning {subject}: {message}"),
            ScanEvent::Rendered(s) => format!("rendered {s}"),
            ScanEvent::Failed { subject, message } => format!("failed {subject}: {message}"),
        });
    })
    .unwrap();
    (summary, events.into_inner())
}

fn close(a: [f32; 3], b: [f32; 3]) -> bool {
    (0..3).all(|i| (a[i] - b[i]).abs() <= 2.0 / 255.0)
}

/// The colour of the source view at the file point `p` of subject `name`.
fn source_colour_at(reader: &DatasetReader, name: &str, p: Vec3) -> [f32; 3] {
    let record = reader.subject_record(name).unwrap();
    let world = mat4_from_rows(&record.mesh_to_world).transform_point3(p);
    let camera = reader.cameras(name).unwrap()[0].camera();
    let (u, v, z) = camera.project(world);
    assert!(z > 0.0);
    let (rgb, mask) = reader.view(name, 0).unwrap();
    assert_eq!(mask.get_pixel(u as u32, v as u32).0[0], 1.0);
    rgb.get_pixel(u as u32, v as u32).0
}

#[test]
fn renders_scans_reports_failures_and_reruns() {
    let tmp = tempfile::tempdir().unwrap();
    let scans = tmp.path().join("scans");
    let out = tmp.path().join("dataset");
    let a_mesh = write_person(&scans, "a", "material0.png", true);
    let fit = write_fit(&scans.join("a"), "smplx.json");
    write_person(&scans, "b", "missing.png", false);
    let c_mesh = write_person(&scans, "c", "material0.png", true);
    std::fs::write(&c_mesh, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n").unwrap();
    std::fs::create_dir_all(scans.join("d")).unwrap();
    write_person(&scans, "e", "material0.png", true);
    std::fs::copy(&a_mesh, scans.join("e/copy.obj")).unwrap();
    std::fs::create_dir_all(scans.join(".hidden")).unwrap();
    std::fs::write(scans.join("notes.txt"), "not a subject").unwrap();

    let (summary, events) = run(&scans, &out, &options());
    assert_eq!(events[0], "planned 5 5");
    assert_eq!(
        (summary.written, summary.skipped, summary.with_fit),
        (2, 0, 1)
    );
    // The missing texture is a warning naming it; the subject renders.
    assert_eq!(summary.warnings, 1, "{events:?}");
    assert!(
        events
            .iter()
            .any(|e| e.starts_with("warning b: ") && e.contains("missing.png")),
        "{events:?}"
    );
    // The broken mesh names its file and line; empty and ambiguous folders are explained.
    let failed: Vec<(&str, &str)> = summary
        .failed
        .iter()
        .map(|f| (f.subject.as_str(), f.message.as_str()))
        .collect();
    assert_eq!(failed.len(), 3, "{failed:?}");
    assert!(
        failed[0].0 == "c" && failed[0].1.contains("c.obj:4"),
        "{failed:?}"
    );
    assert!(failed[1].0 == "d" && failed[1].1.contains("no mesh"));
    assert!(failed[2].0 == "e" && failed[2].1.contains("several meshes (copy.obj, e.obj)"));

    // dataset.json lists the rendered subjects in their planned split: a b c | d e.
    let report = check_dataset(&out);
    assert!(report.problems.is_empty(), "{:?}", report.problems);
    assert_eq!((report.subjects, report.views), (2, 210));
    let reader = DatasetReader::open(&out).unwrap();
    let meta = reader.meta();
    assert_eq!(meta.subjects, vec!["a", "b"]);
    assert_eq!(
        (meta.split.train.clone(), meta.split.test.len()),
        (vec!["a".to_string(), "b".into()], 0)
    );
    assert_eq!(meta.generator["options"]["facing"], "+z");
    assert!(!out.join(".partial-c").exists() && !out.join("c").exists());

    // Heights: the record, the mesh mapped by mesh_to_world, and the point map's extent.
    for name in ["a", "b"] {
        let record = reader.subject_record(name).unwrap();
        assert!((record.height - 1.80).abs() <= 0.05, "{}", record.height);
        assert!(
            record.source.ends_with(&format!("{name}.obj"))
                && Path::new(&record.source).is_absolute()
        );
        let m = mat4_from_rows(&record.mesh_to_world);
        let ys: Vec<f32> = (0..8)
            .map(|k| {
                m.transform_point3(Vec3::new(X[k & 1], Y[(k >> 1) & 1], Z[k >> 2]))
                    .y
            })
            .collect();
        let (lo, hi) = ys
            .iter()
            .fold((f32::MAX, f32::MIN), |(l, h), y| (l.min(*y), h.max(*y)));
        assert!(
            lo.abs() < 1e-4 && (hi - record.height).abs() < 1e-4,
            "{lo} {hi}"
        );
        let points = reader.points(name).unwrap();
        let visible: Vec<f32> = points
            .points
            .iter()
            .filter(|p| **p != [0.0; 3])
            .map(|p| p[1])
            .collect();
        let (lo, hi) = visible
            .iter()
            .fold((f32::MAX, f32::MIN), |(l, h), y| (l.min(*y), h.max(*y)));
        // Pixel centres sample the slab: its extent is at most two pixels (~6.6 cm) short.
        let pixel = 2.1 / RES as f32;
        assert!(lo >= -1e-4 && lo < 2.0 * pixel, "{name}: lowest point {lo}");
        assert!(
            hi <= record.height + 1e-4 && hi > record.height - 2.0 * pixel,
            "{name}: {hi}"
        );
    }

    // The source view shows the texture's quadrants where the front's quadrant centres
    // project, the flat material on the side, and grey for the missing texture.
    let front = Z[1];
    let at =
        |fx: f32, fy: f32| Vec3::new(X[0] + fx * (X[1] - X[0]), Y[0] + fy * (Y[1] - Y[0]), front);
    for (q, (fx, fy)) in [(0.25, 0.75), (0.75, 0.75), (0.25, 0.25), (0.75, 0.25)]
        .into_iter()
        .enumerate()
    {
        let got = source_colour_at(&reader, "a", at(fx, fy));
        let expected = QUADRANTS[q].map(|c| c as f32 / 255.0);
        assert!(
            close(got, expected),
            "quadrant {q}: {got:?} vs {expected:?}"
        );
        let got = source_colour_at(&reader, "b", at(fx, fy));
        assert!(close(got, crate::scan::GREY), "missing texture: {got:?}");
    }
    // The corner views see the sides or the top, in the flat material.
    for view in 101..=104 {
        let (rgb, _) = reader.view("a", view).unwrap();
        assert!(rgb.pixels().any(|p| close(p.0, CLOTH)), "view {view}");
    }

    // The fit moved with the scan: body.json poses the fit's body mapped by mesh_to_world.
    assert!(!reader.body_path("b").exists());
    let body = BodyParams::load(reader.body_path("a")).unwrap();
    let model = BodyModel::procedural(0);
    let m = mat4_from_rows(&reader.subject_record("a").unwrap().mesh_to_world);
    let expected: Vec<Vec3> = model
        .pose(&fit)
        .vertices
        .iter()
        .map(|p| m.transform_point3(*p))
        .collect();
    let got = model.pose(&body).vertices;
    let err = got
        .iter()
        .zip(&expected)
        .map(|(a, b)| (*a - *b).length())
        .fold(0.0, f32::max);
    assert!(err < 1e-4, "body.json is off by {err} m");

    // A rerun skips the finished subjects and fails the same broken ones.
    let before = std::fs::read(out.join("a/rgb/050.png")).unwrap();
    let (summary, events) = run(&scans, &out, &options());
    assert_eq!(
        (summary.written, summary.skipped, summary.failed.len()),
        (0, 2, 3)
    );
    assert_eq!(events[0], "planned 5 3");
    // Fixing the broken scan renders it into its planned split; nothing else moves.
    write_person(&scans, "c", "material0.png", true);
    let (summary, _) = run(&scans, &out, &options());
    assert_eq!(
        (summary.written, summary.skipped, summary.failed.len()),
        (1, 2, 2)
    );
    assert!(summary.moved.is_empty() && summary.unlisted.is_empty());
    let meta = DatasetReader::open(&out).unwrap().meta().clone();
    assert_eq!(meta.subjects, vec!["a", "b", "c"]);
    assert_eq!(meta.split.train, vec!["a", "b", "c"]);
    assert_eq!(std::fs::read(out.join("a/rgb/050.png")).unwrap(), before);
    assert!(check_dataset(&out).problems.is_empty());

    // Other settings into the same folder are refused.
    let other = ScanDatasetOptions {
        seed: 1,
        ..options()
    };
    let e = render_scans(&scans, &out, &other, &|| {}, &|_| {})
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("dataset.json") && e.contains("other settings"),
        "{e}"
    );
}

#[test]
fn added_and_removed_scans_are_reported_and_broken_fits_fail() {
    let tmp = tempfile::tempdir().unwrap();
    let scans = tmp.path().join("scans");
    let out = tmp.path().join("dataset");
    let options = ScanDatasetOptions {
        resolution: 16,
        test_fraction: 0.5,
        ..options()
    };
    for name in ["p", "q"] {
        write_person(&scans, name, "material0.png", true);
    }
    let (summary, _) = run(&scans, &out, &options);
    assert_eq!(summary.written, 2);
    assert_eq!(summary.meta.unwrap().split.test, vec!["q"]);
    // Two more scans and p removed: the plan q r s holds out r and s, so q moves to train;
    // p's folder is unlisted. A broken fit fails its subject, naming the file.
    for name in ["r", "s"] {
        write_person(&scans, name, "material0.png", true);
    }
    std::fs::write(scans.join("s/body.json"), "{\"model\": \"procedural:0\"}").unwrap();
    std::fs::remove_dir_all(scans.join("p")).unwrap();
    let (summary, _) = run(&scans, &out, &options);
    assert_eq!(summary.moved, vec!["q"]);
    assert_eq!(summary.unlisted, vec!["p"]);
    assert_eq!(summary.failed.len(), 1);
    assert!(
        summary.failed[0].message.contains("s/body.json"),
        "{:?}",
        summary.failed
    );
    let meta = summary.meta.unwrap();
    assert_eq!(meta.subjects, vec!["q", "r"]);
    assert_eq!(meta.split.train, vec!["q"]);
    assert_eq!(meta.split.test, vec!["r"]);
    // Put p back: the plan p q r s holds out r and s; p's finished folder is listed again.
    write_person(&scans, "p", "material0.png", true);
    let (summary, _) = run(&scans, &out, &options);
    assert_eq!(
        (summary.written, summary.skipped, summary.failed.len()),
        (0, 3, 1)
    );
    assert!(summary.moved.is_empty() && summary.unlisted.is_empty());
    assert_eq!(summary.meta.unwrap().split.train, vec!["p", "q"]);

    // The output folder may not be inside the scans folder.
    let e = render_scans(&scans, &scans.join("ds"), &options, &|| {}, &|_| {})
        .unwrap_err()
        .to_string();
    assert!(e.contains("inside the scans folder"), "{e}");
    let e = render_scans(&tmp.path().join("none"), &out, &options, &|| {}, &|_| {})
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("none") && e.contains("no such scans folder"),
        "{e}"
    );
}
