//! `prism data render`: a dataset from textured scans (THuman, 2K2K, own captures), each
//! normalised by the viewing protocol and rendered unlit with the renderer of `data synth`.
//!
//! The scans folder holds one folder per subject with one mesh (`.obj` + `.mtl` + textures, or
//! `.gltf` / `.glb`), e.g. THuman's `0000/0000.obj`, `0000/material0.mtl`,
//! `0000/material0.jpeg`, and optionally a body fit (see [`FIT_NAMES`]) in the scan's
//! coordinates. Each subject folder of the dataset is named like its scan folder.
//!
//! - Normalisation: the subject's seed is derived from `--seed` and its name only
//!   ([`named_seed`]), so a rerun, or a rerun with more scans, draws the same placement and
//!   views for it. [`normalise`] gives `mesh_to_world`, recorded row-major in `subject.json`
//!   with the absolute path of the mesh.
//! - Fits: moved into the world by the same `mesh_to_world` ([`BodyParams::transformed`]) and
//!   written as `body.json`; no fit, no `body.json`.
//! - Failures: a subject whose folder has no mesh or several, whose mesh or fit cannot be read,
//!   or whose render fails, is reported (file and problem) and skipped; the others are
//!   rendered. Missing textures are warnings (grey surfaces), not failures.
//! - `dataset.json` (see [`prism_data::DatasetWriter`]) is planned over every subject
//!   folder, sorted by name, with the last `test_fraction` held out; it lists only the subjects
//!   rendered, each in its planned split, and is rewritten atomically after each subject. A
//!   failed subject is therefore absent, and a rerun after fixing its scan renders it into the
//!   split it was planned in without moving any other subject. Adding scan folders changes the
//!   plan: subjects that then change split are reported.

mod discover;

#[cfg(test)]
mod tests;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde::{Deserialize, Serialize};

pub use discover::{FIT_NAMES, MESH_EXTENSIONS, ScanSubject, discover};

use crate::ProtocolRenderer;
use crate::scan::{Facing, ScanOptions, UpAxis, load_scan, normalise};
use prism_body::{BodyModel, BodyParams};
use prism_core::camera::mat4_to_rows;
use prism_data::plan::{check_settings, named_seed, protocol_meta};
use prism_data::{DataError, DatasetMeta, DatasetWriter, SubjectRecord};

/// Settings of a dataset rendered from scans; they are recorded in `dataset.json` so that a
/// rerun into the same folder continues only the same dataset.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScanDatasetOptions {
    /// Image width and height in pixels.
    pub resolution: u32,
    /// Seed of the placements and views (each subject's is derived from it and its name).
    pub seed: u64,
    /// Fraction of the subjects held out for testing (the last ones by name).
    pub test_fraction: f32,
    /// Background colour, components in [0, 1].
    pub background: [f32; 3],
    /// Supersampling factor of the renderer (s x s samples per pixel).
    pub supersample: u32,
    /// The scans' up axis.
    pub up: UpAxis,
    /// The scans' facing direction.
    pub facing: Facing,
}

impl Default for ScanDatasetOptions {
    fn default() -> Self {
        Self {
            resolution: 512,
            seed: 0,
            test_fraction: 0.125,
            background: [1.0; 3],
            supersample: 3,
            up: UpAxis::Y,
            facing: Facing::PlusZ,
        }
    }
}

/// What happens while a scans dataset is rendered, for progress reports.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ScanEvent<'a> {
    /// The subjects were found: `subjects` folders, of which `to_render` are not yet done.
    Planned {
        /// Subject folders in the scans folder.
        subjects: usize,
        /// Those an earlier run has not finished.
        to_render: usize,
    },
    /// A subject an earlier run finished is skipped.
    Skipped(&'a str),
    /// A subject renders, with a problem worth knowing (a missing texture, ...).
    Warning {
        /// The subject.
        subject: &'a str,
        /// What is wrong, naming the file.
        message: &'a str,
    },
    /// A subject was rendered and written.
    Rendered(&'a str),
    /// A subject could not be rendered and is left out.
    Failed {
        /// The subject.
        subject: &'a str,
        /// Why, naming the file.
        message: &'a str,
    },
}

/// A subject that could not be rendered.
#[derive(Clone, Debug, PartialEq)]
pub struct SubjectFailure {
    /// The subject (its scan folder's name).
    pub subject: String,
    /// Why, naming the file.
    pub message: String,
}

/// What a render run did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ScanSummary {
    /// Subjects rendered by this run.
    pub written: usize,
    /// Subjects already complete from an earlier run.
    pub skipped: usize,
    /// Subjects rendered by this run with a body fit.
    pub with_fit: usize,
    /// Warnings reported (missing textures and the like).
    pub warnings: usize,
    /// Subjects that could not be rendered, in name order.
    pub failed: Vec<SubjectFailure>,
    /// Subjects of an earlier run whose split changed because the scan folders changed.
    pub moved: Vec<String>,
    /// Complete subject folders of the dataset that have no scan folder any more (not listed
    /// in `dataset.json`).
    pub unlisted: Vec<String>,
    /// The final `dataset.json`.
    pub meta: Option<DatasetMeta>,
}

/// The `dataset.json` plan of a scans dataset with these subject folders.
pub fn dataset_meta(options: &ScanDatasetOptions, subjects: &[ScanSubject]) -> DatasetMeta {
    protocol_meta(
        options.resolution,
        options.background,
        subjects.iter().map(|s| s.name.clone()).collect(),
        options.test_fraction,
        serde_json::json!({"kind": "scans", "options": options}),
    )
}

/// Renders every subject folder of `scans` into the dataset `out` (see the module docs),
/// skipping subjects an earlier run finished and reporting progress through `on_view` (after
/// every rendered view) and `on_event`.
///
/// Failures of single subjects do not stop the run: they are in [`ScanSummary::failed`].
///
/// # Errors
/// Invalid options, a scans folder without subject folders, an output folder inside the scans
/// folder or holding another dataset, or I/O errors on the dataset (naming the file).
pub fn render_scans(
    scans: &Path,
    out: &Path,
    options: &ScanDatasetOptions,
    on_view: &(dyn Fn() + Sync),
    on_event: &dyn Fn(ScanEvent<'_>),
) -> Result<ScanSummary, DataError> {
    check_settings(
        out,
        options.resolution,
        options.test_fraction,
        options.background,
    )?;
    let inside = |a: &Path, b: &Path| {
        std::path::absolute(a)
            .ok()
            .zip(std::path::absolute(b).ok())
            .is_some_and(|(a, b)| a.starts_with(b))
    };
    if inside(out, scans) {
        return Err(DataError::invalid(
            out,
            "the output folder must not be inside the scans folder",
        ));
    }
    let subjects = discover(scans)?;
    let writer = DatasetWriter::open(out, dataset_meta(options, &subjects))?;
    let renderer =
        ProtocolRenderer::new(options.resolution, options.background, options.supersample);
    let scan_options = ScanOptions {
        up: options.up,
        facing: options.facing,
    };
    let mut summary = ScanSummary {
        moved: moved_subjects(writer.previous(), writer.meta()),
        unlisted: unlisted_subjects(out, &subjects)?,
        ..Default::default()
    };
    on_event(ScanEvent::Planned {
        subjects: subjects.len(),
        to_render: subjects.iter().filter(|s| !writer.is_done(&s.name)).count(),
    });
    let mut models = ModelCache::default();
    for subject in &subjects {
        if writer.is_done(&subject.name) {
            summary.skipped += 1;
            on_event(ScanEvent::Skipped(&subject.name));
            continue;
        }
        let warn = |message: &str| {
            on_event(ScanEvent::Warning {
                subject: &subject.name,
                message,
            });
        };
        let job = SubjectJob {
            subject,
            seed: named_seed(options.seed, &subject.name),
            scan_options: &scan_options,
            renderer: &renderer,
        };
        match job.run(&writer, &mut models, on_view, &warn) {
            Ok(outcome) => {
                summary.written += 1;
                summary.with_fit += usize::from(outcome.with_fit);
                summary.warnings += outcome.warnings;
                on_event(ScanEvent::Rendered(&subject.name));
            }
            Err(message) => {
                on_event(ScanEvent::Failed {
                    subject: &subject.name,
                    message: &message,
                });
                summary.failed.push(SubjectFailure {
                    subject: subject.name.clone(),
                    message,
                });
            }
        }
    }
    summary.meta = Some(writer.publish()?);
    Ok(summary)
}

/// One subject to render.
struct SubjectJob<'a> {
    subject: &'a ScanSubject,
    seed: u64,
    scan_options: &'a ScanOptions,
    renderer: &'a ProtocolRenderer,
}

/// What rendering one subject gave.
struct Outcome {
    with_fit: bool,
    warnings: usize,
}

impl SubjectJob<'_> {
    /// Loads, normalises and renders the subject, moving its fit along; the error is a line
    /// naming the file and the problem.
    fn run(
        &self,
        writer: &DatasetWriter,
        models: &mut ModelCache,
        on_view: &(dyn Fn() + Sync),
        warn: &dyn Fn(&str),
    ) -> Result<Outcome, String> {
        let mesh_path = self.subject.mesh.clone()?;
        // The fit is read before the mesh so that a broken fit fails fast.
        let fit = match self.subject.fit.clone()? {
            Some(path) => {
                let fit = BodyParams::load(&path).map_err(|e| e.to_string())?;
                let model = models
                    .get(&fit.model)
                    .map_err(|e| format!("{}: body model: {e}", path.display()))?;
                Some((path, fit, model))
            }
            None => None,
        };
        let (mesh, warnings) = load_scan(&mesh_path).map_err(|e| e.to_string())?;
        for w in &warnings {
            warn(w);
        }
        let placement = self.renderer.protocol.placement(self.seed);
        let (placed, mesh_to_world) = normalise(&mesh, self.scan_options, &placement)
            .map_err(|e| format!("{}: {e}", mesh_path.display()))?;
        drop(mesh);
        let body = fit
            .map(|(path, fit, model)| {
                fit.transformed(&model, mesh_to_world)
                    .map_err(|e| format!("{}: {e}", path.display()))
            })
            .transpose()?;
        let source = std::path::absolute(&mesh_path).unwrap_or_else(|_| mesh_path.clone());
        let record = SubjectRecord {
            source: source.display().to_string(),
            mesh_to_world: mat4_to_rows(&mesh_to_world),
            height: placement.height,
        };
        self.renderer
            .write(
                writer,
                &self.subject.name,
                self.seed,
                &placed,
                &record,
                body.as_ref(),
                on_view,
            )
            .map_err(|e| e.to_string())?;
        Ok(Outcome {
            with_fit: body.is_some(),
            warnings: warnings.len(),
        })
    }
}

/// Body models by `model` name, each loaded once (failures too, so a missing SMPL-X file is
/// not read again for every subject).
#[derive(Default)]
struct ModelCache {
    models: HashMap<String, Result<Arc<BodyModel>, String>>,
}

impl ModelCache {
    fn get(&mut self, name: &str) -> Result<Arc<BodyModel>, String> {
        self.models
            .entry(name.to_string())
            .or_insert_with(|| {
                BodyModel::load_named(name)
                    .map(Arc::new)
                    .map_err(|e| e.to_string())
            })
            .clone()
    }
}

/// Subjects of the earlier `dataset.json` that the new plan puts in the other split.
fn moved_subjects(previous: Option<&DatasetMeta>, plan: &DatasetMeta) -> Vec<String> {
    let Some(previous) = previous else {
        return Vec::new();
    };
    let mut moved: Vec<String> = previous
        .split
        .train
        .iter()
        .filter(|s| plan.split.test.contains(s))
        .chain(
            previous
                .split
                .test
                .iter()
                .filter(|s| plan.split.train.contains(s)),
        )
        .cloned()
        .collect();
    moved.sort();
    moved
}

/// Complete subject folders of `out` (holding a `subject.json`) without a scan folder.
fn unlisted_subjects(out: &Path, subjects: &[ScanSubject]) -> Result<Vec<String>, DataError> {
    let mut unlisted = Vec::new();
    let Ok(entries) = std::fs::read_dir(out) else {
        return Ok(unlisted);
    };
    for entry in entries {
        let entry = entry.map_err(|e| DataError::io(out, e))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        let path: PathBuf = entry.path();
        if !name.starts_with('.')
            && path.join(prism_data::schema::files::SUBJECT).is_file()
            && !subjects.iter().any(|s| s.name == name)
        {
            unlisted.push(name);
        }
    }
    unlisted.sort();
    Ok(unlisted)
}
