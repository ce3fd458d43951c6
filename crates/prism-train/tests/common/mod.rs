//! A small analytic dataset for the training tests: a "person" made of a head sphere and a
//! torso ellipsoid, lit by a fixed light, with a per-subject albedo, ray cast here
//! (independently of the project's renderer) in the protocol's 105 views.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard, OnceLock};

use glam::Vec3;
use image::{Luma, Rgb, Rgb32FImage};
use prism_core::BackendKind;
use prism_core::CameraRecord;
use prism_core::{Camera, Intrinsics, ViewingProtocol};
use prism_data::{DatasetMeta, DatasetWriter, DepthMap, Mask, PointMap, Split, SubjectRecord};
use prism_train::{Checkpoint, TrainingConfig, configs_dir, parameter_values};

struct Blob {
    centre: Vec3,
    radii: Vec3,
}

/// The nearest hit of the ray through pixel (x, y) with the subject's blobs: (point, normal).
fn hit(blobs: &[Blob], camera: &Camera, x: u32, y: u32) -> Option<(Vec3, Vec3)> {
    let o = camera.center();
    let d = camera.ray_direction(x as f32 + 0.5, y as f32 + 0.5);
    let mut best: Option<(f32, Vec3, Vec3)> = None;
    for b in blobs {
        // Scale space so the ellipsoid is a unit sphere.
        let oc = (o - b.centre) / b.radii;
        let dd = d / b.radii;
        let a = dd.dot(dd);
        let bq = oc.dot(dd);
        let c = oc.dot(oc) - 1.0;
        let disc = bq * bq - a * c;
        if disc < 0.0 {
            continue;
        }
        let t = (-bq - disc.sqrt()) / a;
        if t > 0.0 && best.is_none_or(|(bt, _, _)| t < bt) {
            let p = o + d * t;
            let n = ((p - b.centre) / (b.radii * b.radii)).normalize();
            best = Some((t, p, n));
        }
    }
    best.map(|(_, p, n)| (p, n))
}

/// Writes `subjects` subjects (the last one held out) at `res` x `res` into `root`.
pub fn write_dataset(root: &Path, subjects: usize, res: u32) {
    write_dataset_at_depth(root, subjects, res, 0.0);
}

/// As [`write_dataset`], with the subjects `depth` metres along +z from the cameras' orbit
/// centre: off the centre, a subject shifts across the image from view to view (parallax), so
/// copying the source view is a poor prediction and the views must be synthesised.
pub fn write_dataset_at_depth(root: &Path, subjects: usize, res: u32, depth: f32) {
    let protocol = ViewingProtocol::default();
    let names: Vec<String> = (0..subjects).map(|i| format!("s{i}")).collect();
    let meta = DatasetMeta {
        format: "prism-dataset".into(),
        version: 1,
        width: res,
        height: res,
        background: [1.0, 1.0, 1.0],
        views: 105,
        subjects: names.clone(),
        split: Split {
            train: names[..subjects - 1].to_vec(),
            test: names[subjects - 1..].to_vec(),
        },
        generator: serde_json::json!({"kind": "blob-test", "res": res, "depth": depth}),
    };
    let writer = DatasetWriter::open(root, meta).unwrap();
    let light = Vec3::new(0.5, 0.8, 0.6).normalize();
    for (s, name) in names.iter().enumerate() {
        if writer.is_done(name) {
            continue;
        }
        let f = s as f32 / subjects as f32;
        let blobs = [
            Blob {
                centre: Vec3::new(0.0, 1.55 + 0.05 * f, depth),
                radii: Vec3::splat(0.13),
            },
            Blob {
                centre: Vec3::new(0.0, 1.0, depth),
                radii: Vec3::new(0.28 + 0.06 * f, 0.45, 0.16),
            },
        ];
        let albedo = Vec3::new(0.9 - 0.5 * f, 0.4 + 0.4 * f, 0.3);
        let w = writer.begin_subject(name).unwrap();
        let mut records = Vec::new();
        let mut points = None;
        for view in protocol.views(s as u64) {
            let cam = protocol.camera(&view, Intrinsics::protocol_default(res, res));
            let rgb = Rgb32FImage::from_fn(res, res, |x, y| match hit(&blobs, &cam, x, y) {
                Some((p, n)) => {
                    let shade = 0.3 + 0.7 * n.dot(light).max(0.0);
                    // A stripe pattern on the torso front so views differ in detail.
                    let stripe = if p.z > 0.0 && ((p.y * 12.0).floor() as i32) % 2 == 0 {
                        0.6
                    } else {
                        1.0
                    };
                    let c = albedo * shade * stripe;
                    Rgb([c.x, c.y, c.z])
                }
                None => Rgb([1.0, 1.0, 1.0]),
            });
            let mask = Mask::from_fn(res, res, |x, y| {
                Luma([hit(&blobs, &cam, x, y).map_or(0.0, |_| 1.0)])
            });
            let depth = DepthMap::from_fn(res, res, |x, y| {
                Luma([hit(&blobs, &cam, x, y).map_or(0.0, |(p, _)| cam.project(p).2)])
            });
            w.write_view(view.index, &rgb, &mask, &depth).unwrap();
            if view.index == 0 {
                points = Some(PointMap {
                    width: res,
                    height: res,
                    points: (0..res * res)
                        .map(|i| {
                            hit(&blobs, &cam, i % res, i / res)
                                .map_or([0.0; 3], |(p, _)| p.to_array())
                        })
                        .collect(),
                });
            }
            records.push(CameraRecord::new(&view, &cam));
        }
        let record = SubjectRecord {
            source: "blob".into(),
            mesh_to_world: glam::Mat4::IDENTITY.to_cols_array_2d(),
            height: 1.7,
        };
        w.finish::<serde_json::Value>(&records, &points.unwrap(), &record, None)
            .unwrap();
    }
}

/// The tiny config, with changes applied to its `[train]` section.
pub fn tiny(edit: impl FnOnce(&mut TrainingConfig)) -> TrainingConfig {
    let mut config = TrainingConfig::load(configs_dir().join("tiny.toml")).unwrap();
    edit(&mut config);
    config
}

/// The quick start's `--fast` plan shrunk for tests (32 px, 3 subjects of which 1 held out, no
/// LPIPS in the loss, no validation during training) with `teacher_steps`, `student_steps` and
/// `eval_views`, its dataset synthesised into `root/cache` (made this process's cache folder),
/// and options writing into `root/out` on ndarray.
///
/// # Safety
/// Sets the cache environment variable: call it once per test binary, before anything reads it.
pub unsafe fn shrunken_quickstart(
    root: &Path,
    teacher_steps: usize,
    student_steps: usize,
    eval_views: usize,
) -> (prism_train::QuickstartPlan, prism_train::PipelineOptions) {
    // SAFETY: as the caller promises.
    unsafe { std::env::set_var(prism_synth::CACHE_ENV, root.join("cache")) };
    let mut plan = prism_train::QuickstartPlan::fast().unwrap();
    plan.config.model.resolution = 32;
    plan.config.losses.lpips = 0.0;
    plan.config.train.validate_every = 0;
    plan.config.train.validation_views = 2;
    plan.config.data.subjects = 3;
    plan.config.data.resolution = 32;
    plan.config.data.test_fraction = 0.34;
    plan.teacher_steps = teacher_steps;
    plan.student_steps = student_steps;
    plan.eval_views = eval_views;
    let data = prism_synth::ensure_synthetic_dataset(&plan.config.data, false).unwrap();
    let options = prism_train::PipelineOptions {
        out: root.join("out"),
        data,
        backend: BackendKind::Ndarray,
        lpips_weights: None,
        progress: false,
    };
    (plan, options)
}

/// A cheap student job for pipeline tests: the teacher's objective, from the teacher's weights,
/// with the distillation's config ([`prism_train::student_config`], what a student run stores;
/// `prism distill-student` is the real job); a resumed run continues its own checkpoint.
pub fn fine_tune_student(
    config: &TrainingConfig,
    teacher: &Path,
    run: &prism_train::RunOptions,
) -> prism_train::error::Result<prism_train::RunSummary> {
    let run = prism_train::RunOptions {
        init: (!run.resume).then(|| teacher.to_path_buf()),
        ..run.clone()
    };
    prism_train::train(
        &prism_train::student_config(config),
        &prism_train::TeacherTask::default(),
        &run,
    )
}

/// One dataset for every test of a test binary (each is its own process): `subjects` subjects
/// (one held out) at 32 px, written on first use under the target folder's scratch space
/// (cargo's `CARGO_TARGET_TMPDIR`), which goes with the build, not in the system's `/tmp`,
/// where a dataset per test process would stay behind.
pub fn dataset_once(subjects: usize) -> PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
            .join(format!("prism-train-tests-{}", std::process::id()));
        write_dataset(&dir, subjects, 32);
        dir
    })
    .clone()
}

/// Held by every test that trains: the backends seed one process-wide random generator, so a
/// model initialised while another test seeds or initialises would get other weights (the
/// tests comparing runs bit for bit failed now and then when run in parallel).
pub fn serial() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// The parameter values of the checkpoint at `dir` (a run folder or one checkpoint), loaded on
/// `backend`.
pub fn weights(dir: &Path, backend: BackendKind) -> Vec<Vec<f32>> {
    let device = backend.device().unwrap();
    let model = Checkpoint::read(dir).unwrap().load_model(&device).unwrap();
    parameter_values(&model)
}

/// Copies a run folder (checkpoints, log) to `to`, to cut a run short without touching it.
pub fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).unwrap();
        }
    }
}

/// The teacher's job with its objective wrapped by `wrap` (a test's planted fault): a task
/// named "teacher", so that checkpoints and resumption treat it as the teacher.
pub struct TeacherWith<F>(pub F);

impl<F> prism_train::Task for TeacherWith<F>
where
    F: Fn(std::sync::Arc<dyn prism_train::StepLoss>) -> std::sync::Arc<dyn prism_train::StepLoss>
        + Send
        + Sync,
{
    fn name(&self) -> &str {
        "teacher"
    }

    fn step_loss(
        &self,
        config: &TrainingConfig,
        data: &prism_train::TaskData,
        device: &burn::tensor::Device,
    ) -> Result<std::sync::Arc<dyn prism_train::StepLoss>, prism_train::TrainError> {
        let teacher = prism_train::TeacherTask::default().step_loss(config, data, device)?;
        Ok((self.0)(teacher))
    }
}
