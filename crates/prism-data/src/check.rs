//! `prism data check`: validates a dataset folder and reports every problem with its file.

use std::path::{Path, PathBuf};

use glam::Vec3;
use rayon::prelude::*;

use super::error::DataError;
use super::reader::DatasetReader;
use super::schema::files;
use prism_core::protocol::SOURCE_VIEW;

/// One problem found in a dataset.
#[derive(Clone, Debug, PartialEq)]
pub struct Problem {
    /// The file (or folder) concerned.
    pub path: PathBuf,
    /// What is wrong.
    pub message: String,
}

impl std::fmt::Display for Problem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.path.display(), self.message)
    }
}

impl From<DataError> for Problem {
    fn from(e: DataError) -> Self {
        let path = e.path().to_path_buf();
        let full = e.to_string();
        let prefix = format!("{}: ", path.display());
        let message = full.strip_prefix(&prefix).unwrap_or(&full).to_string();
        Self { path, message }
    }
}

/// What [`check_dataset`] looked at and found.
#[derive(Clone, Debug, Default)]
pub struct CheckReport {
    /// Subjects examined.
    pub subjects: usize,
    /// Views examined.
    pub views: usize,
    /// Every problem found.
    pub problems: Vec<Problem>,
}

/// Largest distance, in pixels, between a point of the source point map reprojected into the
/// source camera and its pixel centre.
const REPROJECTION_TOLERANCE_PX: f32 = 0.01;

/// Largest difference, in metres, between a source point's depth and the source view's
/// depth map at its pixel (the map stores whole millimetres).
const DEPTH_TOLERANCE_M: f32 = 2e-3;

/// Validates the dataset at `root`: `dataset.json`, and per subject the cameras (count, sizes,
/// rigid `c2w`, positive focal lengths, subject in front of the camera), every RGB and mask
/// image and, when the subject stores depth, every depth map (present, decodable, right size),
/// the point map (shape, finite, zero off the mask, reprojecting onto its pixel centres through
/// the source camera, at the source depth map's depths) and the JSON records.
pub fn check_dataset(root: &Path) -> CheckReport {
    let reader = match DatasetReader::open(root) {
        Ok(r) => r,
        Err(e) => {
            return CheckReport {
                problems: vec![e.into()],
                ..Default::default()
            };
        }
    };
    let meta = reader.meta().clone();
    let mut problems = Vec::new();
    for name in &meta.subjects {
        let in_train = meta.split.train.contains(name);
        let in_test = meta.split.test.contains(name);
        if in_train == in_test {
            problems.push(Problem {
                path: root.join(files::DATASET),
                message: format!(
                    "subject `{name}` must be in exactly one of split.train and split.test"
                ),
            });
        }
    }
    let per_subject: Vec<Vec<Problem>> = meta
        .subjects
        .par_iter()
        .map(|name| check_subject(&reader, name))
        .collect();
    problems.extend(per_subject.into_iter().flatten());
    CheckReport {
        subjects: meta.subjects.len(),
        views: meta.subjects.len() * meta.views,
        problems,
    }
}

fn check_subject(reader: &DatasetReader, name: &str) -> Vec<Problem> {
    let dir = reader.subject_dir(name);
    if !dir.is_dir() {
        return vec![Problem {
            path: dir,
            message: "subject folder is missing".into(),
        }];
    }
    let mut problems = Vec::new();
    let cameras = match reader.cameras(name) {
        Ok(c) => Some(c),
        Err(e) => {
            problems.push(e.into());
            None
        }
    };
    let cameras_path = dir.join(files::CAMERAS);
    if let Some(cameras) = &cameras {
        for c in cameras {
            if let Err(message) = c.validate() {
                problems.push(Problem {
                    path: cameras_path.clone(),
                    message: format!("view {}: {message}", c.index),
                });
            }
        }
    }
    if let Err(e) = reader.subject_record(name) {
        problems.push(e.into());
    }
    let body = reader.body_path(name);
    if body.exists()
        && let Err(e) = super::io::read_json::<prism_body::BodyParams>(&body)
    {
        problems.push(e.into());
    }
    let mut source_mask = None;
    let mut source_depth = None;
    let has_depth = reader.has_depth(name);
    for index in 0..reader.meta().views {
        match reader.view(name, index) {
            Ok((_, mask)) if index == SOURCE_VIEW => source_mask = Some(mask),
            Ok(_) => {}
            Err(e) => problems.push(e.into()),
        }
        if has_depth {
            match reader.depth(name, index) {
                Ok(depth) if index == SOURCE_VIEW => source_depth = depth,
                Ok(_) => {}
                Err(e) => problems.push(e.into()),
            }
        }
    }
    let points_path = dir.join(files::POINTS);
    match reader.points(name) {
        Err(e) => problems.push(e.into()),
        Ok(map) => {
            if let (Some(mask), Some(cameras)) = (source_mask, &cameras) {
                let source = cameras[SOURCE_VIEW].camera();
                let mut off_mask = 0;
                let mut bad_reprojection = 0;
                let mut non_finite = 0;
                let mut depth_mismatch = 0;
                let mut valid = 0;
                let mut centroid = Vec3::ZERO;
                for (i, p) in map.points.iter().enumerate() {
                    let p = Vec3::from_array(*p);
                    let (x, y) = (
                        (i as u32 % map.width) as f32 + 0.5,
                        (i as u32 / map.width) as f32 + 0.5,
                    );
                    if !p.is_finite() {
                        non_finite += 1;
                    } else if p != Vec3::ZERO {
                        if mask.as_raw()[i] == 0.0 {
                            off_mask += 1;
                        }
                        let (u, v, z) = source.project(p);
                        if z <= 0.0 || (u - x).hypot(v - y) > REPROJECTION_TOLERANCE_PX {
                            bad_reprojection += 1;
                        }
                        if let Some(depth) = &source_depth
                            && (depth.as_raw()[i] - z).abs() > DEPTH_TOLERANCE_M
                        {
                            depth_mismatch += 1;
                        }
                        valid += 1;
                        centroid += p;
                    }
                }
                let mut report = |count: usize, what: &str| {
                    if count > 0 {
                        problems.push(Problem {
                            path: points_path.clone(),
                            message: format!("{count} points {what}"),
                        });
                    }
                };
                report(non_finite, "are not finite");
                report(off_mask, "lie where the source mask is 0");
                report(
                    bad_reprojection,
                    "do not reproject onto their pixel centres in the source camera",
                );
                report(
                    depth_mismatch,
                    "are off the source view's depth map by more than 2 mm",
                );
                if valid == 0 {
                    problems.push(Problem {
                        path: points_path.clone(),
                        message: "the point map is empty".into(),
                    });
                } else {
                    let centroid = centroid / valid as f32;
                    for c in cameras {
                        let (u, v, z) = c.camera().project(centroid);
                        if z <= 0.0
                            || u < 0.0
                            || v < 0.0
                            || u > c.width as f32
                            || v > c.height as f32
                        {
                            problems.push(Problem {
                                path: cameras_path.clone(),
                                message: format!("view {}: the subject is not in view", c.index),
                            });
                        }
                    }
                }
            }
        }
    }
    problems
}
