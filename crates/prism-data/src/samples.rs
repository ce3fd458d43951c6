//! Training and evaluation samples as a Burn [`Dataset`]: one source view (view 0) with
//! several target views of the same subject, resized to the model's resolution.

use burn::data::dataset::{Dataset, DatasetError};
use image::Rgb32FImage;
use image::imageops::{FilterType, resize};
use rand::SeedableRng;
use rand::seq::index::sample;
use rand_chacha::ChaCha8Rng;

use super::disocclusion::{DepthView, RegionMethod, disoccluded_by_depth, disoccluded_region};
use super::error::{DataError, Result};
use super::io::{DepthMap, Mask, PointMap};
use super::reader::DatasetReader;
use super::schema::{CameraRecord, SplitKind};
use prism_body::BodyParams;
use prism_core::camera::Camera;
use prism_core::protocol::{EVAL_TARGETS, SOURCE_VIEW, TRAIN_TARGETS};

/// Which target views a sample takes.
#[derive(Clone, Debug, PartialEq)]
pub enum TargetSelection {
    /// `count` distinct views drawn at random from views 1..=104 (training): item `i` is
    /// subject `i % subjects` with its own seeded draw, so the dataset can be as long as wanted.
    Random {
        /// Targets per sample.
        count: usize,
        /// Items per subject (the dataset's length is this times the number of subjects).
        repeats: usize,
    },
    /// Every view 1..=100 of every subject, `per_sample` consecutive views per item
    /// (evaluation).
    Evaluation {
        /// Targets per sample; must divide 100.
        per_sample: usize,
    },
}

/// One loaded view.
#[derive(Clone, Debug)]
pub struct View {
    /// View index in the subject's folder.
    pub index: usize,
    /// Yaw of the view, degrees.
    pub yaw_deg: f32,
    /// Pitch of the view, degrees.
    pub pitch_deg: f32,
    /// The camera, rescaled to the sample resolution.
    pub camera: Camera,
    /// RGB in [0, 1].
    pub rgb: Rgb32FImage,
    /// Foreground alpha in [0, 1].
    pub mask: Mask,
    /// Depth of the surface at each pixel centre, when the dataset stores it and the samples
    /// were asked for it ([`SampleDataset::with_depth`]).
    pub depth: Option<DepthMap>,
}

/// A training or evaluation sample: the source view of one subject and some of its targets.
#[derive(Clone, Debug)]
pub struct Sample {
    /// Subject folder name.
    pub subject: String,
    /// The frontal source view.
    pub source: View,
    /// The target views.
    pub targets: Vec<View>,
    /// The source view's world-space point map (zeros off the mask).
    pub points: PointMap,
    /// The subject's body-model fit (`body.json`), when it has one.
    pub body: Option<BodyParams>,
}

/// What a batch needs of a sample besides its pixels: the subject, the cameras of its views
/// and its body-model fit. A trainer whose device loads its own share of a batch (a `prism
/// serve --data` server) reads only this, without the images.
#[derive(Clone, Debug)]
pub struct SampleMeta {
    /// Subject folder name.
    pub subject: String,
    /// The source view's camera, rescaled to the sample resolution.
    pub source_camera: Camera,
    /// The target views' indices, angles and cameras (the images left out).
    pub targets: Vec<ViewMeta>,
    /// The subject's body-model fit (`body.json`), when it has one.
    pub body: Option<BodyParams>,
}

/// A target view without its images.
#[derive(Clone, Copy, Debug)]
pub struct ViewMeta {
    /// View index in the subject's folder.
    pub index: usize,
    /// Yaw of the view, degrees.
    pub yaw_deg: f32,
    /// Pitch of the view, degrees.
    pub pitch_deg: f32,
    /// The camera, rescaled to the sample resolution.
    pub camera: Camera,
}

impl View {
    /// The view without its images.
    pub fn meta(&self) -> ViewMeta {
        ViewMeta {
            index: self.index,
            yaw_deg: self.yaw_deg,
            pitch_deg: self.pitch_deg,
            camera: self.camera,
        }
    }
}

impl Sample {
    /// The disoccluded region of target view `target` (1 inside, 0 outside) and how it was
    /// found: by the depth test when both the source and the target carry depth maps (see
    /// [`SampleDataset::with_depth`]), else estimated from the source's point map.
    ///
    /// # Panics
    /// If `target` is out of range.
    pub fn disoccluded_region(&self, target: usize) -> (Mask, RegionMethod) {
        let t = &self.targets[target];
        match (&self.source.depth, &t.depth) {
            (Some(source_depth), Some(target_depth)) => (
                disoccluded_by_depth(
                    DepthView {
                        camera: &self.source.camera,
                        mask: &self.source.mask,
                        depth: source_depth,
                    },
                    DepthView {
                        camera: &t.camera,
                        mask: &t.mask,
                        depth: target_depth,
                    },
                ),
                RegionMethod::DepthTest,
            ),
            _ => (
                disoccluded_region(&self.points, &self.source.mask, &t.camera, &t.mask),
                RegionMethod::Estimate,
            ),
        }
    }

    /// The sample without its pixels.
    pub fn meta(&self) -> SampleMeta {
        SampleMeta {
            subject: self.subject.clone(),
            source_camera: self.source.camera,
            targets: self.targets.iter().map(View::meta).collect(),
            body: self.body.clone(),
        }
    }
}

/// Samples of one split of a dataset, as a Burn dataset.
#[derive(Clone, Debug)]
pub struct SampleDataset {
    reader: DatasetReader,
    subjects: Vec<String>,
    cameras: Vec<Vec<CameraRecord>>,
    selection: TargetSelection,
    size: (u32, u32),
    seed: u64,
    depth: bool,
}

impl SampleDataset {
    /// The samples of `split` of the dataset opened by `reader`, at `size` (width, height; the
    /// dataset's own size when `None`). Cameras are read and checked now; images on `get`.
    ///
    /// # Errors
    /// An empty split, unreadable cameras, or an evaluation grouping that does not divide 100.
    pub fn new(
        reader: DatasetReader,
        split: SplitKind,
        selection: TargetSelection,
        size: Option<(u32, u32)>,
        seed: u64,
    ) -> Result<Self> {
        let meta = reader.meta();
        let subjects = meta.subjects_of(split).to_vec();
        let dataset_json = reader.root().join(super::schema::files::DATASET);
        if subjects.is_empty() {
            return Err(DataError::invalid(
                &dataset_json,
                format!("the {split:?} split has no subjects"),
            ));
        }
        match selection {
            TargetSelection::Evaluation { per_sample }
                if per_sample == 0 || 100 % per_sample != 0 =>
            {
                return Err(DataError::invalid(
                    &dataset_json,
                    "evaluation targets per sample must divide 100",
                ));
            }
            TargetSelection::Random { count, .. } if count == 0 || count > *TRAIN_TARGETS.end() => {
                return Err(DataError::invalid(
                    &dataset_json,
                    "targets per sample must be in 1..=104",
                ));
            }
            _ => {}
        }
        if meta.views <= *TRAIN_TARGETS.end() {
            return Err(DataError::invalid(
                &dataset_json,
                format!("{} views per subject, 105 needed", meta.views),
            ));
        }
        let cameras = subjects
            .iter()
            .map(|s| reader.cameras(s))
            .collect::<Result<Vec<_>>>()?;
        let size = size.unwrap_or((meta.width, meta.height));
        Ok(Self {
            reader,
            subjects,
            cameras,
            selection,
            size,
            seed,
            depth: false,
        })
    }

    /// The same samples with each view's depth map loaded too (evaluation's disoccluded
    /// regions need it; training does not read it).
    pub fn with_depth(self) -> Self {
        Self {
            depth: true,
            ..self
        }
    }

    /// A run's training samples: the training subjects at `resolution` x `resolution`,
    /// `targets` random target views each, drawn with `seed`. The trainer and every server
    /// that loads its share of a batch open it alike.
    ///
    /// # Errors
    /// As [`SampleDataset::new`].
    pub fn training(
        reader: DatasetReader,
        targets: usize,
        resolution: u32,
        seed: u64,
    ) -> Result<Self> {
        Self::new(
            reader,
            SplitKind::Train,
            TargetSelection::Random {
                count: targets,
                repeats: 1,
            },
            Some((resolution, resolution)),
            seed,
        )
    }

    /// The subjects of this split.
    pub fn subjects(&self) -> &[String] {
        &self.subjects
    }

    /// Subject index and target view indices of item `index`.
    pub fn plan(&self, index: usize) -> (usize, Vec<usize>) {
        let n = self.subjects.len();
        match self.selection {
            TargetSelection::Random { count, .. } => {
                let mut rng = ChaCha8Rng::seed_from_u64(
                    self.seed ^ (index as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15),
                );
                let pool: Vec<usize> = TRAIN_TARGETS.collect();
                let picks = sample(&mut rng, pool.len(), count)
                    .into_iter()
                    .map(|i| pool[i])
                    .collect();
                (index % n, picks)
            }
            TargetSelection::Evaluation { per_sample } => {
                let per_subject = EVAL_TARGETS.count() / per_sample;
                let first = EVAL_TARGETS.start() + (index % per_subject) * per_sample;
                (index / per_subject, (first..first + per_sample).collect())
            }
        }
    }

    /// Item `index` without its pixels (see [`SampleDataset::plan`]): cameras and the body
    /// fit only, no image is read.
    ///
    /// # Errors
    /// An unreadable `body.json`.
    pub fn meta(&self, index: usize) -> Result<SampleMeta> {
        let (subject_index, targets) = self.plan(index);
        let (w, h) = self.size;
        let records = &self.cameras[subject_index];
        Ok(SampleMeta {
            subject: self.subjects[subject_index].clone(),
            source_camera: records[SOURCE_VIEW].camera().rescaled(w, h),
            targets: targets
                .into_iter()
                .map(|t| ViewMeta {
                    index: t,
                    yaw_deg: records[t].yaw_deg,
                    pitch_deg: records[t].pitch_deg,
                    camera: records[t].camera().rescaled(w, h),
                })
                .collect(),
            body: self.body(subject_index)?,
        })
    }

    /// Loads item `index` (see [`SampleDataset::plan`]).
    pub fn load(&self, index: usize) -> Result<Sample> {
        let (subject_index, targets) = self.plan(index);
        let subject = &self.subjects[subject_index];
        let body = self.body(subject_index)?;
        let mut points = self.reader.points(subject)?;
        if (points.width, points.height) != self.size {
            points = resize_points(&points, self.size);
        }
        Ok(Sample {
            subject: subject.clone(),
            source: self.load_view(subject_index, SOURCE_VIEW)?,
            targets: targets
                .into_iter()
                .map(|t| self.load_view(subject_index, t))
                .collect::<Result<_>>()?,
            points,
            body,
        })
    }

    /// The body fit of subject `subject_index`, when it has one.
    fn body(&self, subject_index: usize) -> Result<Option<BodyParams>> {
        let body_path = self.reader.body_path(&self.subjects[subject_index]);
        if body_path.exists() {
            Ok(Some(super::io::read_json(&body_path)?))
        } else {
            Ok(None)
        }
    }

    fn load_view(&self, subject_index: usize, index: usize) -> Result<View> {
        let record = &self.cameras[subject_index][index];
        let (rgb, mask) = self.reader.view(&self.subjects[subject_index], index)?;
        let (w, h) = self.size;
        let (rgb, mask) = if (rgb.width(), rgb.height()) == (w, h) {
            (rgb, mask)
        } else {
            (
                resize(&rgb, w, h, FilterType::Triangle),
                resize(&mask, w, h, FilterType::Triangle),
            )
        };
        let depth = if self.depth {
            self.reader
                .depth(&self.subjects[subject_index], index)?
                .map(|d| resize_nearest(d, (w, h)))
        } else {
            None
        };
        Ok(View {
            index,
            yaw_deg: record.yaw_deg,
            pitch_deg: record.pitch_deg,
            camera: record.camera().rescaled(w, h),
            rgb,
            mask,
            depth,
        })
    }
}

/// The source pixel, along an axis of `from` pixels, of pixel `i` of `to`: nearest neighbour at
/// the new pixel centres.
fn nearest(i: u32, to: u32, from: u32) -> u32 {
    (((i as f32 + 0.5) * from as f32 / to as f32) as u32).min(from - 1)
}

/// Resamples a depth map to `size` by nearest neighbour (as [`resize_points`]: averaging
/// depths across an edge would invent surface between the two sides).
fn resize_nearest(map: DepthMap, (w, h): (u32, u32)) -> DepthMap {
    if map.dimensions() == (w, h) {
        return map;
    }
    let (from_w, from_h) = map.dimensions();
    DepthMap::from_fn(w, h, |x, y| {
        *map.get_pixel(nearest(x, w, from_w), nearest(y, h, from_h))
    })
}

/// Resamples a point map to `size` by nearest neighbour at the new pixel centres (points are
/// surface positions: averaging them would invent points between surfaces).
pub fn resize_points(map: &PointMap, (w, h): (u32, u32)) -> PointMap {
    let mut points = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        let src_y = nearest(y, h, map.height);
        for x in 0..w {
            let src_x = nearest(x, w, map.width);
            points.push(map.points[(src_y * map.width + src_x) as usize]);
        }
    }
    PointMap {
        width: w,
        height: h,
        points,
    }
}

impl Dataset<Sample> for SampleDataset {
    fn get(&self, index: usize) -> std::result::Result<Sample, DatasetError> {
        if index >= self.len() {
            return Err(DatasetError::new(DataError::invalid(
                self.reader.root(),
                format!("sample {index} is out of range ({} samples)", self.len()),
            )));
        }
        self.load(index).map_err(DatasetError::new)
    }

    fn len(&self) -> usize {
        match self.selection {
            TargetSelection::Random { repeats, .. } => self.subjects.len() * repeats,
            TargetSelection::Evaluation { per_sample } => {
                self.subjects.len() * (EVAL_TARGETS.count() / per_sample)
            }
        }
    }
}
