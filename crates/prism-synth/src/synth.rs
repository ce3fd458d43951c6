//! `prism data synth`: a dataset of procedural people under the paper's viewing protocol, so
//! that prism trains and is tested on a fresh machine with no download.

use std::path::Path;

use crate::people::{self, PeopleConfig};
use crate::render_subject::ProtocolRenderer;
use prism_body::BodyModel;
use prism_core::camera::mat4_to_rows;
use prism_data::plan::{check_settings, keyed_seed, protocol_meta, split_last};
use prism_data::{DataError, DatasetMeta, DatasetWriter, Split, SubjectRecord, SynthOptions};

/// Seed of the procedural body model every synthetic subject is built on.
pub const BODY_MODEL_SEED: u64 = 0;

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

/// The seed of subject `i` of a dataset seeded with `seed`.
pub fn subject_seed(seed: u64, i: usize) -> u64 {
    keyed_seed(seed, i as u64 + 1)
}

/// The train / test split: the last `round(n * test_fraction)` subjects are held out (see
/// [`split_last`]).
pub fn split(n: usize, test_fraction: f32) -> Split {
    split_last(&(0..n).map(subject_name).collect::<Vec<_>>(), test_fraction)
}

/// The `dataset.json` of a synthetic dataset.
pub fn dataset_meta(options: &SynthOptions) -> DatasetMeta {
    protocol_meta(
        options.resolution,
        options.background,
        (0..options.subjects).map(subject_name).collect(),
        options.test_fraction,
        serde_json::json!({
            "kind": "synth",
            "body_model": format!("procedural:{BODY_MODEL_SEED}"),
            "options": options,
        }),
    )
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
    if options.subjects == 0 {
        return Err(DataError::invalid(
            out,
            "synthesis needs at least 1 subject",
        ));
    }
    check_settings(
        out,
        options.resolution,
        options.test_fraction,
        options.background,
    )?;
    let writer = DatasetWriter::open(out, dataset_meta(options))?;
    let model = BodyModel::procedural(BODY_MODEL_SEED);
    let people_config = PeopleConfig::for_resolution(options.resolution);
    let renderer =
        ProtocolRenderer::new(options.resolution, options.background, options.supersample);
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
        let placement = renderer.protocol.placement(seed);
        let record = SubjectRecord {
            source: format!("procedural:{seed}"),
            mesh_to_world: mat4_to_rows(&placement.transform(person.height)),
            height: placement.height,
        };
        let person = person.placed(&placement);
        renderer.write(
            &writer,
            &name,
            seed,
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
    }

    #[test]
    fn subject_seeds_differ() {
        let seeds: std::collections::HashSet<u64> = (0..100).map(|i| subject_seed(0, i)).collect();
        assert_eq!(seeds.len(), 100);
        assert_ne!(subject_seed(0, 0), subject_seed(1, 0));
    }
}
