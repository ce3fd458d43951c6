//! Reading datasets: `dataset.json`, subjects' cameras and views, validated on load.

use std::path::{Path, PathBuf};

use image::Rgb32FImage;

use super::error::{DataError, Result};
use super::io::{
    DepthMap, Mask, PointMap, read_depth, read_json, read_mask, read_points, read_rgb,
};
use super::schema::{CameraRecord, DatasetMeta, FORMAT_NAME, FORMAT_VERSION, SubjectRecord, files};

/// An opened dataset folder.
#[derive(Clone, Debug)]
pub struct DatasetReader {
    root: PathBuf,
    meta: DatasetMeta,
}

impl DatasetReader {
    /// Opens a dataset folder and validates its `dataset.json`.
    ///
    /// # Errors
    /// A missing or malformed `dataset.json`, another format or version, an inconsistent split.
    pub fn open(root: &Path) -> Result<Self> {
        let path = root.join(files::DATASET);
        if !root.is_dir() {
            return Err(DataError::invalid(root, "no such dataset folder"));
        }
        let meta: DatasetMeta = read_json(&path)?;
        if meta.format != FORMAT_NAME {
            return Err(DataError::invalid(
                &path,
                format!("format is `{}`, expected `{FORMAT_NAME}`", meta.format),
            ));
        }
        if meta.version != FORMAT_VERSION {
            return Err(DataError::invalid(
                &path,
                format!(
                    "format version {} is not supported (this prism reads version {FORMAT_VERSION})",
                    meta.version
                ),
            ));
        }
        if meta.width == 0 || meta.height == 0 {
            return Err(DataError::invalid(&path, "image size must be positive"));
        }
        for name in meta.split.train.iter().chain(&meta.split.test) {
            if !meta.subjects.contains(name) {
                return Err(DataError::invalid(
                    &path,
                    format!("split names `{name}`, which is not in `subjects`"),
                ));
            }
        }
        Ok(Self {
            root: root.to_path_buf(),
            meta,
        })
    }

    /// The dataset's description.
    pub fn meta(&self) -> &DatasetMeta {
        &self.meta
    }

    /// The dataset folder.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// The folder of subject `name`.
    pub fn subject_dir(&self, name: &str) -> PathBuf {
        self.root.join(name)
    }

    /// The cameras of subject `name`, one per view in view order.
    ///
    /// # Errors
    /// A missing file, a wrong number of views, indices out of order, or sizes that differ from
    /// the dataset's.
    pub fn cameras(&self, name: &str) -> Result<Vec<CameraRecord>> {
        let path = self.subject_dir(name).join(files::CAMERAS);
        let cameras: Vec<CameraRecord> = read_json(&path)?;
        if cameras.len() != self.meta.views {
            return Err(DataError::invalid(
                &path,
                format!("{} views, expected {}", cameras.len(), self.meta.views),
            ));
        }
        for (i, c) in cameras.iter().enumerate() {
            if c.index != i {
                return Err(DataError::invalid(
                    &path,
                    format!("entry {i} has index {}", c.index),
                ));
            }
            if (c.width, c.height) != (self.meta.width, self.meta.height) {
                return Err(DataError::invalid(
                    &path,
                    format!(
                        "view {i} is {}x{}, the dataset is {}x{}",
                        c.width, c.height, self.meta.width, self.meta.height
                    ),
                ));
            }
        }
        Ok(cameras)
    }

    /// The subject record (origin and placement) of subject `name`.
    pub fn subject_record(&self, name: &str) -> Result<SubjectRecord> {
        read_json(&self.subject_dir(name).join(files::SUBJECT))
    }

    /// The path of subject `name`'s optional `body.json` (which may not exist).
    pub fn body_path(&self, name: &str) -> PathBuf {
        self.subject_dir(name).join(files::BODY)
    }

    /// View `index` of subject `name`: its RGB image and alpha mask, checked against the
    /// dataset's image size.
    pub fn view(&self, name: &str, index: usize) -> Result<(Rgb32FImage, Mask)> {
        let dir = self.subject_dir(name);
        let rgb_path = dir.join(files::view_png(files::RGB, index));
        let mask_path = dir.join(files::view_png(files::MASK, index));
        let rgb = read_rgb(&rgb_path)?;
        self.check_size(&rgb_path, rgb.width(), rgb.height())?;
        let mask = read_mask(&mask_path)?;
        self.check_size(&mask_path, mask.width(), mask.height())?;
        Ok((rgb, mask))
    }

    /// Whether subject `name` stores depth maps (datasets written before depth was stored do
    /// not).
    pub fn has_depth(&self, name: &str) -> bool {
        self.subject_dir(name).join(files::DEPTH).is_dir()
    }

    /// View `index`'s depth map of subject `name`, checked against the dataset's image size;
    /// `None` when the subject stores no depth (see [`DatasetReader::has_depth`]).
    ///
    /// # Errors
    /// A subject with depth maps but this one missing or unreadable (named with the file).
    pub fn depth(&self, name: &str, index: usize) -> Result<Option<DepthMap>> {
        if !self.has_depth(name) {
            return Ok(None);
        }
        let path = self
            .subject_dir(name)
            .join(files::view_png(files::DEPTH, index));
        let depth = read_depth(&path)?;
        self.check_size(&path, depth.width(), depth.height())?;
        Ok(Some(depth))
    }

    /// The source view's point map of subject `name`.
    pub fn points(&self, name: &str) -> Result<PointMap> {
        let path = self.subject_dir(name).join(files::POINTS);
        let map = read_points(&path)?;
        self.check_size(&path, map.width, map.height)?;
        Ok(map)
    }

    fn check_size(&self, path: &Path, width: u32, height: u32) -> Result<()> {
        if (width, height) != (self.meta.width, self.meta.height) {
            return Err(DataError::invalid(
                path,
                format!(
                    "is {width}x{height}, the dataset is {}x{}",
                    self.meta.width, self.meta.height
                ),
            ));
        }
        Ok(())
    }
}
