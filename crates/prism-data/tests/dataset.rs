//! The dataset layer on a small analytic dataset: a sphere seen by the protocol's cameras,
//! rendered by ray casting here (independently of the project's rasterizer).

use std::path::Path;

use burn::data::dataset::Dataset;
use glam::Vec3;
use image::{Luma, Rgb, Rgb32FImage};
use prism_core::CameraRecord;
use prism_core::{BackendKind, Camera, Intrinsics, ViewingProtocol};
use prism_data::{
    DatasetMeta, DatasetReader, DatasetWriter, DepthMap, Mask, PointMap, PrismBatcher,
    SampleDataset, Split, SplitKind, SubjectRecord, TargetSelection, check_dataset,
};

const RES: u32 = 16;
const CENTRE: Vec3 = Vec3::new(0.0, 0.9, 0.0);
const RADIUS: f32 = 0.5;

/// The first hit of the ray through pixel (x, y)'s centre with the sphere.
fn hit(camera: &Camera, x: u32, y: u32) -> Option<Vec3> {
    let o = camera.center();
    let d = camera.ray_direction(x as f32 + 0.5, y as f32 + 0.5);
    let oc = o - CENTRE;
    let b = oc.dot(d);
    let disc = b * b - (oc.length_squared() - RADIUS * RADIUS);
    (disc >= 0.0).then(|| o + d * (-b - disc.sqrt()))
}

fn write_sphere_dataset(root: &Path, subjects: &[&str]) {
    let protocol = ViewingProtocol::default();
    let meta = DatasetMeta {
        format: "prism-dataset".into(),
        version: 1,
        width: RES,
        height: RES,
        background: [1.0, 1.0, 1.0],
        views: 105,
        subjects: subjects.iter().map(|s| s.to_string()).collect(),
        split: Split {
            train: subjects[..subjects.len() - 1]
                .iter()
                .map(|s| s.to_string())
                .collect(),
            test: vec![subjects[subjects.len() - 1].to_string()],
        },
        generator: serde_json::json!({"kind": "sphere-test"}),
    };
    let writer = DatasetWriter::open(root, meta).unwrap();
    for (s, name) in subjects.iter().enumerate() {
        let w = writer.begin_subject(name).unwrap();
        let mut records = Vec::new();
        let mut points = None;
        for view in protocol.views(s as u64) {
            let cam = protocol.camera(&view, Intrinsics::protocol_default(RES, RES));
            let rgb = Rgb32FImage::from_fn(RES, RES, |x, y| match hit(&cam, x, y) {
                Some(p) => Rgb([(p.y - 0.4).clamp(0.0, 1.0), 0.3, 0.1 * s as f32]),
                None => Rgb([1.0, 1.0, 1.0]),
            });
            let mask = Mask::from_fn(RES, RES, |x, y| {
                Luma([hit(&cam, x, y).map_or(0.0, |_| 1.0)])
            });
            let depth = DepthMap::from_fn(RES, RES, |x, y| {
                Luma([hit(&cam, x, y).map_or(0.0, |p| cam.project(p).2)])
            });
            w.write_view(view.index, &rgb, &mask, &depth).unwrap();
            if view.index == 0 {
                points = Some(PointMap {
                    width: RES,
                    height: RES,
                    points: (0..RES * RES)
                        .map(|i| hit(&cam, i % RES, i / RES).map_or([0.0; 3], |p| p.to_array()))
                        .collect(),
                });
            }
            records.push(CameraRecord::new(&view, &cam));
        }
        let record = SubjectRecord {
            source: "sphere".into(),
            mesh_to_world: glam::Mat4::IDENTITY.to_cols_array_2d(),
            height: 1.0,
        };
        let mut body = prism_body::BodyParams::rest("procedural:0");
        body.betas[0] = 0.5 + s as f32;
        w.finish(&records, &points.unwrap(), &record, Some(&body))
            .unwrap();
    }
}

#[test]
fn written_dataset_checks_clean_and_loads_into_batches() {
    let dir = tempfile::tempdir().unwrap();
    write_sphere_dataset(dir.path(), &["a", "b", "c"]);
    let report = check_dataset(dir.path());
    assert!(report.problems.is_empty(), "{:?}", report.problems);
    assert_eq!((report.subjects, report.views), (3, 315));

    let reader = DatasetReader::open(dir.path()).unwrap();
    let train = SampleDataset::new(
        reader.clone(),
        SplitKind::Train,
        TargetSelection::Random {
            count: 3,
            repeats: 4,
        },
        None,
        7,
    )
    .unwrap();
    assert_eq!(train.len(), 8);
    let s = train.get(5).unwrap();
    assert_eq!(s.subject, "b");
    assert_eq!(s.targets.len(), 3);
    assert!(s.targets.iter().all(|t| (1..=104).contains(&t.index)));
    assert_eq!(train.plan(5), train.plan(5), "plans are reproducible");

    let device = BackendKind::Ndarray.device().unwrap();
    let batch = PrismBatcher.batch_samples(&[train.get(0).unwrap(), s], &device);
    assert_eq!(batch.source_image.dims(), [6, 3, 16, 16]);
    assert_eq!(batch.target_rays.dims(), [6, 6, 16, 16]);
    assert_eq!(batch.source_points.dims(), [6, 3, 16, 16]);
    assert_eq!(batch.pairs.len(), 6);
    assert!(batch.bodies.iter().all(Option::is_some));
    let body = batch.body_tensors(&device);
    assert_eq!(body.pose.dims(), [6, 55, 3]);
    let betas = body.betas.into_data().try_into_vec::<f32>().unwrap();
    assert_eq!(
        (betas[0], betas[30]),
        (0.5, 1.5),
        "subject a then subject b"
    );
    // The source mask covers exactly the pixels with a point.
    let mask = batch
        .source_mask
        .clone()
        .into_data()
        .try_into_vec::<f32>()
        .unwrap();
    let pts = batch
        .source_points
        .clone()
        .into_data()
        .try_into_vec::<f32>()
        .unwrap();
    let plane = 256;
    for i in 0..plane {
        let has_point = (0..3).any(|c| pts[c * plane + i] != 0.0);
        assert_eq!(has_point, mask[i] > 0.5);
    }

    // Loading on worker threads through Burn's data loader.
    let loader = burn::data::dataloader::DataLoaderBuilder::new(PrismBatcher)
        .batch_size(2)
        .num_workers(2)
        .set_device(device.clone())
        .build(train.clone());
    let batches: Vec<_> = loader.iter().collect::<Result<_, _>>().unwrap();
    assert_eq!(batches.len(), 4);
    assert!(
        batches
            .iter()
            .all(|b| b.target_image.dims() == [6, 3, 16, 16])
    );

    // Evaluation: every view 1..=100 of the held-out subject, in order.
    let eval = SampleDataset::new(
        reader,
        SplitKind::Test,
        TargetSelection::Evaluation { per_sample: 4 },
        Some((8, 8)),
        0,
    )
    .unwrap();
    assert_eq!(eval.len(), 25);
    let views: Vec<usize> = (0..25).flat_map(|i| eval.plan(i).1).collect();
    assert_eq!(views, (1..=100).collect::<Vec<_>>());
    let small = eval.get(3).unwrap();
    assert_eq!((small.source.rgb.width(), small.points.width), (8, 8));
    assert_eq!(small.source.camera.intrinsics.fx, 8.0);
}

#[test]
fn check_names_every_broken_file() {
    let dir = tempfile::tempdir().unwrap();
    write_sphere_dataset(dir.path(), &["a", "b"]);
    std::fs::remove_file(dir.path().join("a/rgb/017.png")).unwrap();
    std::fs::write(dir.path().join("b/mask/003.png"), b"not a png").unwrap();
    let cams = dir.path().join("b/cameras.json");
    let mut records: Vec<CameraRecord> =
        serde_json::from_str(&std::fs::read_to_string(&cams).unwrap()).unwrap();
    records[5].fx = -1.0;
    std::fs::write(&cams, serde_json::to_string(&records).unwrap()).unwrap();
    let report = check_dataset(dir.path());
    let text: Vec<String> = report.problems.iter().map(|p| p.to_string()).collect();
    assert_eq!(text.len(), 3, "{text:#?}");
    assert!(text[0].contains("a/rgb/017.png"), "{text:#?}");
    assert!(
        text.iter().any(|t| t.contains("b/mask/003.png")),
        "{text:#?}"
    );
    assert!(
        text.iter()
            .any(|t| t.contains("b/cameras.json") && t.contains("view 5")),
        "{text:#?}"
    );

    // Loading a sample that needs the missing file is an error naming it.
    let reader = DatasetReader::open(dir.path()).unwrap();
    let eval = SampleDataset::new(
        reader,
        SplitKind::Train,
        TargetSelection::Evaluation { per_sample: 1 },
        None,
        0,
    )
    .unwrap();
    let err = eval.load(16).unwrap_err().to_string();
    assert!(err.contains("017.png"), "{err}");
}

#[test]
fn rerun_skips_finished_subjects_and_refuses_other_settings() {
    let dir = tempfile::tempdir().unwrap();
    write_sphere_dataset(dir.path(), &["a", "b"]);
    // A staging folder of a killed run is cleaned up when the dataset is reopened.
    std::fs::create_dir_all(dir.path().join(".partial-b")).unwrap();
    let meta: DatasetMeta =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("dataset.json")).unwrap())
            .unwrap();
    let writer = DatasetWriter::open(dir.path(), meta.clone()).unwrap();
    assert!(writer.is_done("a") && writer.is_done("b"));
    assert!(!dir.path().join(".partial-b").exists());
    let mut other = meta;
    other.width = 32;
    let err = DatasetWriter::open(dir.path(), other)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("dataset.json") && err.contains("other settings"),
        "{err}"
    );
}

#[test]
fn missing_dataset_json_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let report = check_dataset(dir.path());
    assert_eq!(report.problems.len(), 1);
    assert!(
        report.problems[0].path.ends_with("dataset.json"),
        "{:?}",
        report.problems
    );
}
