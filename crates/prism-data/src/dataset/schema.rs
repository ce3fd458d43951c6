//! The on-disk dataset format (version 1): `dataset.json`, and per subject `cameras.json` and
//! `subject.json`. The full layout is documented in `FORMAT.md` at the repository root.

use serde::{Deserialize, Serialize};

use crate::camera::{Camera, Intrinsics, mat4_from_rows};
use crate::protocol::ViewAngles;

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

/// Which part of a dataset to read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
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

/// One entry of `cameras.json` (a JSON array of them, one per view, in view order).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraRecord {
    /// View index (may be left out of a single-view file).
    #[serde(default)]
    pub index: usize,
    /// Yaw of the view on the protocol's sphere, degrees (informational).
    #[serde(default)]
    pub yaw_deg: f32,
    /// Pitch of the view, degrees (informational).
    #[serde(default)]
    pub pitch_deg: f32,
    /// Focal length x, pixels.
    pub fx: f32,
    /// Focal length y, pixels.
    pub fy: f32,
    /// Principal point x, pixels.
    pub cx: f32,
    /// Principal point y, pixels.
    pub cy: f32,
    /// Camera-to-world 4x4, row-major, OpenCV axes.
    pub c2w: [[f32; 4]; 4],
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
}

impl CameraRecord {
    /// The record of a protocol view seen by `camera`.
    pub fn new(view: &ViewAngles, camera: &Camera) -> Self {
        let k = camera.intrinsics;
        Self {
            index: view.index,
            yaw_deg: view.yaw_deg,
            pitch_deg: view.pitch_deg,
            fx: k.fx,
            fy: k.fy,
            cx: k.cx,
            cy: k.cy,
            c2w: camera.c2w_rows(),
            width: k.width,
            height: k.height,
        }
    }

    /// Checks that the record is a sane pinhole camera: a non-empty image, positive finite
    /// focal lengths, a finite principal point, and a rigid `c2w` (proper rotation, last row
    /// `[0, 0, 0, 1]`).
    ///
    /// # Errors
    /// A message naming the bad value.
    pub fn validate(&self) -> Result<(), String> {
        if self.width == 0 || self.height == 0 {
            return Err(format!("empty image size {}x{}", self.width, self.height));
        }
        for (name, v) in [("fx", self.fx), ("fy", self.fy)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{name} = {v} is not a positive focal length"));
            }
        }
        for (name, v) in [("cx", self.cx), ("cy", self.cy)] {
            if !v.is_finite() {
                return Err(format!("{name} = {v} is not finite"));
            }
        }
        if self.c2w.iter().flatten().any(|v| !v.is_finite()) {
            return Err("c2w has a non-finite entry".into());
        }
        if self.c2w[3] != [0.0, 0.0, 0.0, 1.0] {
            return Err(format!(
                "the last row of c2w must be [0, 0, 0, 1], found {:?}",
                self.c2w[3]
            ));
        }
        let r = glam::Mat3::from_mat4(mat4_from_rows(&self.c2w));
        let off = (r.transpose() * r - glam::Mat3::IDENTITY)
            .to_cols_array()
            .iter()
            .fold(0.0f32, |m, v| m.max(v.abs()));
        if off > 1e-3 || (r.determinant() - 1.0).abs() > 1e-3 {
            return Err("c2w is not a rigid camera-to-world transform (its rotation is not a proper rotation)".into());
        }
        Ok(())
    }

    /// The camera this record describes (see [`CameraRecord::validate`] for checking it).
    pub fn camera(&self) -> Camera {
        let k = Intrinsics {
            fx: self.fx,
            fy: self.fy,
            cx: self.cx,
            cy: self.cy,
            width: self.width,
            height: self.height,
        };
        Camera::new(k, mat4_from_rows(&self.c2w))
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

    /// `rgb/NNN.png` or `mask/NNN.png` of view `index`.
    pub fn view_png(folder: &str, index: usize) -> String {
        format!("{folder}/{index:03}.png")
    }
}
