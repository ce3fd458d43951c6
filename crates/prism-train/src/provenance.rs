//! What a stored result of a long job was made from. An ablation's row and a point of a budget
//! curve are kept on disk and read back by the next run instead of being trained again; each
//! carries the digests of its config, its dataset and its plan, and a result whose digests
//! differ from what the run asks is refused with one line that says which, never reused.

use std::path::Path;

use prism_data::DatasetReader;
use prism_remote::{config_digest, dataset_digest};
use serde::{Deserialize, Serialize};

use crate::config::TrainingConfig;
use crate::error::{Result, TrainError};

/// The digests of what a stored result was made from (empty in files written before results
/// carried them).
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Provenance {
    /// Digest of every setting of the config its run trained with.
    pub config: String,
    /// Digest of the dataset it was trained and scored on (its `dataset.json` and file list).
    pub dataset: String,
    /// Digest of the plan that made it (steps, views, row or multiple).
    pub plan: String,
}

impl Provenance {
    /// The provenance of a result made by training with `config` on the dataset whose
    /// [`dataset_digest_of`] is `dataset`, as `plan` says.
    pub fn new(config: &TrainingConfig, dataset: &str, plan: &impl Serialize) -> Self {
        let text = |v: serde_json::Value| config_digest(&v.to_string());
        Self {
            config: text(serde_json::to_value(config).expect("a config serialises")),
            dataset: dataset.to_string(),
            plan: text(serde_json::to_value(plan).expect("a plan serialises")),
        }
    }

    /// Checks that `stored`, read from `file`, was made from this provenance.
    ///
    /// # Errors
    /// [`TrainError::RunFolder`] naming `file` and what differs.
    pub fn check(&self, stored: &Self, file: &Path) -> Result<()> {
        let differs: Vec<&str> = [
            ("config", &stored.config, &self.config),
            ("dataset", &stored.dataset, &self.dataset),
            ("plan", &stored.plan, &self.plan),
        ]
        .into_iter()
        .filter(|(_, a, b)| a != b)
        .map(|(what, _, _)| what)
        .collect();
        if differs.is_empty() {
            return Ok(());
        }
        let why = if *stored == Self::default() {
            "carries no record of its config, dataset and plan (an older prism wrote it)".into()
        } else {
            format!(
                "was made with another {} than this run asks",
                differs.join(" and another ")
            )
        };
        Err(TrainError::RunFolder {
            path: file.to_path_buf(),
            message: format!("{why}: use another --out, or remove its folder to make it again"),
        })
    }
}

/// The digest of the dataset at `data` (its `dataset.json` and file list): computed once per
/// long job, for the provenance of each of its results.
///
/// # Errors
/// A dataset that cannot be opened or listed.
pub fn dataset_digest_of(data: &Path) -> Result<String> {
    let reader = DatasetReader::open(data)?;
    dataset_digest(&reader).map_err(|e| TrainError::io(data, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_check_names_what_differs() {
        let ours = Provenance {
            config: "a".into(),
            dataset: "b".into(),
            plan: "c".into(),
        };
        let file = Path::new("out/teacher/row.json");
        assert!(ours.check(&ours.clone(), file).is_ok());
        let other_plan = Provenance {
            plan: "d".into(),
            ..ours.clone()
        };
        let err = ours.check(&other_plan, file).unwrap_err().to_string();
        assert!(
            err.starts_with("out/teacher/row.json: was made with another plan than this run asks"),
            "{err}"
        );
        let other_data_and_plan = Provenance {
            dataset: "e".into(),
            ..other_plan
        };
        let err = ours
            .check(&other_data_and_plan, file)
            .unwrap_err()
            .to_string();
        assert!(err.contains("another dataset and another plan"), "{err}");
        let err = ours
            .check(&Provenance::default(), file)
            .unwrap_err()
            .to_string();
        assert!(err.contains("an older prism wrote it"), "{err}");
    }
}
