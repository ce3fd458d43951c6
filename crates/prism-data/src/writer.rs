//! Writing datasets. `meta` is the plan (every subject that should exist and the split); each
//! subject is staged in a hidden folder and renamed into place when complete, and `dataset.json`
//! is rewritten atomically after every subject, listing only the complete subjects of the plan
//! (in plan order, with the plan's split). So at any moment, even after a killed run or a
//! subject that failed, the folder is a valid dataset of what it holds, and a rerun with the
//! same settings skips the finished subjects.

use std::fs;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use image::Rgb32FImage;
use serde::Serialize;

use super::error::{DataError, Result};
use super::io::{
    DepthMap, Mask, PointMap, read_json, write_depth_png, write_json, write_mask_png, write_points,
    write_rgb_png,
};
use super::schema::{CameraRecord, DatasetMeta, Split, SubjectRecord, files};

/// Prefix of the staging folder of a subject being written.
const STAGING_PREFIX: &str = ".partial-";

/// A dataset folder being written.
#[derive(Debug)]
pub struct DatasetWriter {
    root: PathBuf,
    meta: DatasetMeta,
    /// What `dataset.json` listed when the folder was opened (`None` for a new folder).
    previous: Option<DatasetMeta>,
    /// Serialises the rewrites of `dataset.json`.
    publishing: Mutex<()>,
}

impl DatasetWriter {
    /// Opens `root` for writing the dataset planned by `meta`, creating it if needed, and
    /// writes its `dataset.json` (listing the subjects already complete).
    ///
    /// A folder that already holds a `dataset.json` is continued only if it was made with the
    /// same settings ([`DatasetMeta::same_settings`]: size, background, views, generator); its
    /// subject list may differ (a run that stopped early, subjects added to the plan).
    /// Leftovers of a killed run (staging folders) are removed.
    ///
    /// # Errors
    /// When the folder holds a dataset with other settings, or on I/O errors.
    pub fn open(root: &Path, meta: DatasetMeta) -> Result<Self> {
        fs::create_dir_all(root).map_err(|e| DataError::io(root, e))?;
        let meta_path = root.join(files::DATASET);
        let previous = if meta_path.exists() {
            let existing: DatasetMeta = read_json(&meta_path)?;
            if !existing.same_settings(&meta) {
                return Err(DataError::invalid(
                    &meta_path,
                    "the folder holds a dataset made with other settings; choose another --out or remove it",
                ));
            }
            Some(existing)
        } else {
            None
        };
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
        let writer = Self {
            root: root.to_path_buf(),
            meta,
            previous,
            publishing: Mutex::new(()),
        };
        writer.publish()?;
        Ok(writer)
    }

    /// The dataset's plan: every subject it should hold and their split.
    pub fn meta(&self) -> &DatasetMeta {
        &self.meta
    }

    /// The `dataset.json` found when the folder was opened, if there was one.
    pub fn previous(&self) -> Option<&DatasetMeta> {
        self.previous.as_ref()
    }

    /// The `dataset.json` of what the folder holds now: the plan restricted to the complete
    /// subjects, in plan order, each in its planned split.
    pub fn finished_meta(&self) -> DatasetMeta {
        let done = |names: &[String]| -> Vec<String> {
            names.iter().filter(|n| self.is_done(n)).cloned().collect()
        };
        DatasetMeta {
            subjects: done(&self.meta.subjects),
            split: Split {
                train: done(&self.meta.split.train),
                test: done(&self.meta.split.test),
            },
            ..self.meta.clone()
        }
    }

    /// Rewrites `dataset.json` (atomically) as [`DatasetWriter::finished_meta`]; called when
    /// the folder is opened and after every finished subject.
    pub fn publish(&self) -> Result<DatasetMeta> {
        let _guard = self
            .publishing
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        let meta = self.finished_meta();
        write_json(&self.root.join(files::DATASET), &meta)?;
        Ok(meta)
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
    pub fn begin_subject(&self, name: &str) -> Result<SubjectWriter<'_>> {
        let staging = self.root.join(format!("{STAGING_PREFIX}{name}"));
        if staging.exists() {
            fs::remove_dir_all(&staging).map_err(|e| DataError::io(&staging, e))?;
        }
        for sub in [files::RGB, files::MASK, files::DEPTH, "points"] {
            let dir = staging.join(sub);
            fs::create_dir_all(&dir).map_err(|e| DataError::io(&dir, e))?;
        }
        Ok(SubjectWriter {
            dataset: self,
            staging,
            target: self.root.join(name),
        })
    }
}

/// One subject being written; nothing is visible under its final name until [`finish`].
///
/// [`finish`]: SubjectWriter::finish
#[derive(Debug)]
pub struct SubjectWriter<'a> {
    dataset: &'a DatasetWriter,
    staging: PathBuf,
    target: PathBuf,
}

impl SubjectWriter<'_> {
    /// Writes view `index`'s RGB image, alpha mask and depth map. Safe to call from several
    /// threads.
    pub fn write_view(
        &self,
        index: usize,
        rgb: &Rgb32FImage,
        mask: &Mask,
        depth: &DepthMap,
    ) -> Result<()> {
        write_rgb_png(&self.staging.join(files::view_png(files::RGB, index)), rgb)?;
        write_mask_png(
            &self.staging.join(files::view_png(files::MASK, index)),
            mask,
        )?;
        write_depth_png(
            &self.staging.join(files::view_png(files::DEPTH, index)),
            depth,
        )
    }

    /// Writes the cameras, the source point map, the subject record and the optional body fit,
    /// then moves the subject into place and lists it in `dataset.json`.
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
        fs::rename(&self.staging, &self.target).map_err(|e| DataError::io(&self.target, e))?;
        self.dataset.publish().map(|_| ())
    }
}
