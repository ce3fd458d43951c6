//! Writing datasets: `dataset.json` first (the plan), then each subject staged in a hidden
//! folder and renamed into place when complete, so that a killed run leaves no half-written
//! subject and a rerun skips the finished ones.

use std::fs;
use std::path::{Path, PathBuf};

use image::Rgb32FImage;
use serde::Serialize;

use super::error::{DataError, Result};
use super::io::{
    Mask, PointMap, read_json, write_json, write_mask_png, write_points, write_rgb_png,
};
use super::schema::{CameraRecord, DatasetMeta, SubjectRecord, files};

/// Prefix of the staging folder of a subject being written.
const STAGING_PREFIX: &str = ".partial-";

/// A dataset folder being written.
#[derive(Debug)]
pub struct DatasetWriter {
    root: PathBuf,
    meta: DatasetMeta,
}

impl DatasetWriter {
    /// Opens `root` for writing the dataset `meta`, creating it if needed.
    ///
    /// A folder that already holds a `dataset.json` is continued only if it describes the same
    /// dataset (same subjects, size, background, generator settings); leftovers of a killed
    /// run (staging folders) are removed.
    ///
    /// # Errors
    /// When the folder holds a different dataset, or on I/O errors.
    pub fn open(root: &Path, meta: DatasetMeta) -> Result<Self> {
        fs::create_dir_all(root).map_err(|e| DataError::io(root, e))?;
        let meta_path = root.join(files::DATASET);
        if meta_path.exists() {
            let existing: DatasetMeta = read_json(&meta_path)?;
            if existing != meta {
                return Err(DataError::invalid(
                    &meta_path,
                    "the folder holds a dataset made with other settings; choose another --out or remove it",
                ));
            }
        } else {
            write_json(&meta_path, &meta)?;
        }
        for entry in fs::read_dir(root).map_err(|e| DataError::io(root, e))? {
            let entry = entry.map_err(|e| DataError::io(root, e))?;
            if entry
                .file_name()
                .to_string_lossy()
                .starts_with(STAGING_PREFIX)
            {
                fs::remove_dir_all(entry.path()).map_err(|e| DataError::io(entry.path(), e))?;
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

    /// Whether subject `name` was completely written by an earlier run.
    pub fn is_done(&self, name: &str) -> bool {
        self.root.join(name).is_dir()
    }

    /// Starts writing subject `name` into its staging folder.
    pub fn begin_subject(&self, name: &str) -> Result<SubjectWriter> {
        let staging = self.root.join(format!("{STAGING_PREFIX}{name}"));
        if staging.exists() {
            fs::remove_dir_all(&staging).map_err(|e| DataError::io(&staging, e))?;
        }
        for sub in [files::RGB, files::MASK, "points"] {
            let dir = staging.join(sub);
            fs::create_dir_all(&dir).map_err(|e| DataError::io(&dir, e))?;
        }
        Ok(SubjectWriter {
            staging,
            target: self.root.join(name),
        })
    }
}

/// One subject being written; nothing is visible under its final name until [`finish`].
///
/// [`finish`]: SubjectWriter::finish
#[derive(Debug)]
pub struct SubjectWriter {
    staging: PathBuf,
    target: PathBuf,
}

impl SubjectWriter {
    /// Writes view `index`'s RGB image and alpha mask. Safe to call from several threads.
    pub fn write_view(&self, index: usize, rgb: &Rgb32FImage, mask: &Mask) -> Result<()> {
        write_rgb_png(&self.staging.join(files::view_png(files::RGB, index)), rgb)?;
        write_mask_png(
            &self.staging.join(files::view_png(files::MASK, index)),
            mask,
        )
    }

    /// Writes the cameras, the source point map, the subject record and the optional body fit,
    /// then moves the subject into place.
    pub fn finish<B: Serialize>(
        self,
        cameras: &[CameraRecord],
        points: &PointMap,
        record: &SubjectRecord,
        body: Option<&B>,
    ) -> Result<()> {
        write_json(&self.staging.join(files::CAMERAS), &cameras)?;
        write_points(&self.staging.join(files::POINTS), points)?;
        write_json(&self.staging.join(files::SUBJECT), record)?;
        if let Some(body) = body {
            write_json(&self.staging.join(files::BODY), body)?;
        }
        fs::rename(&self.staging, &self.target).map_err(|e| DataError::io(&self.target, e))
    }
}
