//! `prism data synth`: a dataset of procedural people under the paper's viewing protocol, so
//! that prism trains and is tested on a fresh machine with no download.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::body::BodyModel;
use crate::camera::{Intrinsics, mat4_to_rows};
use crate::dataset::render_subject::SubjectRender;
use crate::dataset::schema::{FORMAT_NAME, FORMAT_VERSION};
use crate::dataset::{DataError, DatasetMeta, DatasetWriter, Split, SubjectRecord};
use crate::people::{self, PeopleConfig};
use crate::protocol::{NUM_VIEWS, ViewingProtocol};
use crate::raster::RenderOptions;

/// Seed of the procedural body model every synthetic subject is built on.
pub const BODY_MODEL_SEED: u64 = 0;

/// Settings of a synthetic dataset; they are recorded in `dataset.json` so that a rerun into
/// the same folder continues only the same dataset.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SynthOptions {
    /// Number of subjects.
    pub subjects: usize,
    /// Image width and height in pixels.
    pub resolution: u32,
    /// Seed of the whole dataset (people, poses, placements, views).
    pub seed: u64,
    /// Fraction of the subjects held out for testing (the last ones).
    pub test_fraction: f32,
    /// Background colour, components in [0, 1].
    pub background: [f32; 3],
    /// Supersampling factor of the renderer (s x s samples per pixel).
    pub supersample: u32,
}

impl Default for SynthOptions {
    fn default() -> Self {
        Self {
            subjects: 16,
            resolution: 256,
            seed: 0,
            test_fraction: 0.125,
            background: [1.0; 3],
            supersample: 3,
        }
    }
}

/// What a synthesis run did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SynthSummary {
    /// Subjects rendered by this run.
    pub written: usize,
    /// Subjects already complete from an earlier run.
    pub skipped: usize,
}

/// The name of subject `i`.
pub fn subject_name(i: usize) -> String {
    format!("subject_{i:04}")
}

/// The seed of subject `i` of a dataset seeded with `seed` (a SplitMix64 step, so that nearby
/// dataset seeds give unrelated subjects).
pub fn subject_seed(seed: u64, i: usize) -> u64 {
    let mut z = seed.wrapping_add((i as u64 + 1).wrapping_mul(0x9e37_79b9_7f4a_7c15));
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The train / test split: the last `round(n * test_fraction)` subjects are held out, at least
/// one and at most `n - 1` when the fraction is positive (none with a single subject).
pub fn split(n: usize, test_fraction: f32) -> Split {
    let test = if test_fraction > 0.0 && n >= 2 {
        ((n as f32 * test_fraction).round() as usize).clamp(1, n - 1)
    } else {
        0
    };
    let names: Vec<String> = (0..n).map(subject_name).collect();
    Split {
        train: names[..n - test].to_vec(),
        test: names[n - test..].to_vec(),
    }
}

/// The `dataset.json` of a synthetic dataset.
pub fn dataset_meta(options: &SynthOptions) -> DatasetMeta {
    DatasetMeta {
        format: FORMAT_NAME.into(),
        version: FORMAT_VERSION,
        width: options.resolution,
        height: options.resolution,
        background: options.background,
        views: NUM_VIEWS,
        subjects: (0..options.subjects).map(subject_name).collect(),
        split: split(options.subjects, options.test_fraction),
        generator: serde_json::json!({
            "kind": "synth",
            "body_model": format!("procedural:{BODY_MODEL_SEED}"),
            "options": options,
        }),
    }
}

/// Writes the synthetic dataset into `out`, skipping subjects an earlier run finished.
/// `on_view` is called after every rendered view, `on_subject` after every subject (with its
/// name and whether it was skipped).
///
/// # Errors
/// Invalid options, a folder holding another dataset, or I/O errors (naming the file).
pub fn synth_dataset(
    out: &Path,
    options: &SynthOptions,
    on_view: &(dyn Fn() + Sync),
    on_subject: &dyn Fn(&str, bool),
) -> Result<SynthSummary, DataError> {
    if options.subjects == 0
        || options.resolution < 8
        || !(0.0..1.0).contains(&options.test_fraction)
    {
        return Err(DataError::invalid(
            out,
            "synthesis needs at least 1 subject, a resolution of at least 8 px and a test fraction in [0, 1)",
        ));
    }
    if options.background.iter().any(|c| !(0.0..=1.0).contains(c)) {
        return Err(DataError::invalid(
            out,
            "background components must be in [0, 1]",
        ));
    }
    let writer = DatasetWriter::open(out, dataset_meta(options))?;
    let model = BodyModel::procedural(BODY_MODEL_SEED);
    let people_config = PeopleConfig::for_resolution(options.resolution);
    let protocol = ViewingProtocol::default();
    let render_options = RenderOptions {
        supersample: options.supersample,
        background: options.background,
        ..Default::default()
    };
    let intrinsics = Intrinsics::protocol_default(options.resolution, options.resolution);
    let mut summary = SynthSummary::default();
    for i in 0..options.subjects {
        let name = subject_name(i);
        if writer.is_done(&name) {
            summary.skipped += 1;
            on_subject(&name, true);
            continue;
        }
        let seed = subject_seed(options.seed, i);
        let person = people::generate_with(&model, seed, &people_config);
        let placement = protocol.placement(seed);
        let record = SubjectRecord {
            source: format!("procedural:{seed}"),
            mesh_to_world: mat4_to_rows(&placement.transform(person.height)),
            height: placement.height,
        };
        let person = person.placed(&placement);
        let views = protocol.views(seed);
        let render = SubjectRender {
            protocol: &protocol,
            views: &views,
            intrinsics,
            options: &render_options,
        };
        render.write(
            &writer,
            &name,
            &person.mesh,
            &record,
            Some(&person.body),
            on_view,
        )?;
        summary.written += 1;
        on_subject(&name, false);
    }
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_holds_out_the_last_subjects() {
        let s = split(8, 0.125);
        assert_eq!(s.test, vec!["subject_0007"]);
        assert_eq!(s.train.len(), 7);
        assert_eq!(split(3, 0.1).test.len(), 1, "at least one test subject");
        assert!(split(1, 0.5).test.is_empty(), "a single subject trains");
        assert_eq!(
            split(4, 0.9).train.len(),
            1,
            "at least one training subject"
        );
        assert!(split(5, 0.0).test.is_empty());
    }

    #[test]
    fn subject_seeds_differ() {
        let seeds: std::collections::HashSet<u64> = (0..100).map(|i| subject_seed(0, i)).collect();
        assert_eq!(seeds.len(), 100);
        assert_ne!(subject_seed(0, 0), subject_seed(1, 0));
    }
}
