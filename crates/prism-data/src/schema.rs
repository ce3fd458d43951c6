//! The on-disk dataset format (version 1): `dataset.json`, and per subject `cameras.json` and
//! `subject.json`. The full layout is documented in `FORMAT.md` at the repository root.

use serde::{Deserialize, Serialize};

pub use prism_core::CameraRecord;

/// Version of the dataset format this code reads and writes.
pub const FORMAT_VERSION: u32 = 1;
/// Value of `dataset.json`'s `format` field.
pub const FORMAT_NAME: &str = "prism-dataset";

/// `dataset.json`: what a dataset holds and how it was made.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DatasetMeta {
    /// Always [`FORMAT_NAME`].
    pub format: String,
    /// Format version ([`FORMAT_VERSION`]).
    pub version: u32,
    /// Image width of every view, pixels.
    pub width: u32,
    /// Image height of every view, pixels.
    pub height: u32,
    /// Background colour the RGB images are composited on, components in [0, 1].
    pub background: [f32; 3],
    /// Views per subject.
    pub views: usize,
    /// Every subject folder, in order.
    pub subjects: Vec<String>,
    /// Which subjects train and which are held out.
    pub split: Split,
    /// How the dataset was produced (generator name and settings); a rerun into the same folder
    /// must match it.
    pub generator: serde_json::Value,
}

/// The train / test split of a dataset.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Split {
    /// Training subjects.
    pub train: Vec<String>,
    /// Held-out subjects (validation and evaluation).
    pub test: Vec<String>,
}

/// Which part of a dataset to read (`train` or `test` in JSON).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SplitKind {
    /// The training subjects.
    Train,
    /// The held-out subjects.
    Test,
}

impl DatasetMeta {
    /// Whether `other` describes the same dataset settings: everything but the subject list
    /// and the split, which grow as subjects are written.
    pub fn same_settings(&self, other: &DatasetMeta) -> bool {
        let Self {
            format,
            version,
            width,
            height,
            background,
            views,
            subjects: _,
            split: _,
            generator,
        } = self;
        *format == other.format
            && *version == other.version
            && *width == other.width
            && *height == other.height
            && *background == other.background
            && *views == other.views
            && *generator == other.generator
    }

    /// The subjects of one split.
    pub fn subjects_of(&self, split: SplitKind) -> &[String] {
        match split {
            SplitKind::Train => &self.split.train,
            SplitKind::Test => &self.split.test,
        }
    }
}

/// `subject.json`: where a subject came from and how it was placed in the world.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SubjectRecord {
    /// The subject's origin: `procedural:SEED` or the scan file it was rendered from.
    pub source: String,
    /// The 4x4 similarity (row-major) from the source mesh's coordinates to the world.
    pub mesh_to_world: [[f32; 4]; 4],
    /// Height of the subject in the world after normalisation, metres.
    pub height: f32,
}

/// File names inside a dataset.
pub mod files {
    /// The dataset description.
    pub const DATASET: &str = "dataset.json";
    /// Per subject: the cameras of all views.
    pub const CAMERAS: &str = "cameras.json";
    /// Per subject: origin and placement.
    pub const SUBJECT: &str = "subject.json";
    /// Per subject, optional: the body-model fit.
    pub const BODY: &str = "body.json";
    /// Per subject: folder of 8-bit RGB views.
    pub const RGB: &str = "rgb";
    /// Per subject: folder of 8-bit alpha masks.
    pub const MASK: &str = "mask";
    /// Per subject: the source view's point map.
    pub const POINTS: &str = "points/000.npy";
    /// Per subject: folder of 16-bit depth maps in millimetres. Datasets written before
    /// depth was stored have none; their disoccluded regions are estimated.
    pub const DEPTH: &str = "depth";

    /// `rgb/NNN.png`, `mask/NNN.png` or `depth/NNN.png` of view `index`.
    pub fn view_png(folder: &str, index: usize) -> String {
        format!("{folder}/{index:03}.png")
    }
}
