//! The baselines' scores, kept between evaluations of several models on the same views.
//!
//! Copy-source and the true-depth warp do not depend on the model. A pipeline that evaluates
//! more than one model on one dataset (`prism quickstart`'s teacher and student, `prism
//! ablate`'s rows) renders and scores them once, through the [`BaselineCache`] its
//! [`crate::EvaluateOptions`] share.

use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, PoisonError};

use prism_data::SplitKind;

use crate::evaluate::{FootprintPsnr, MethodTally};

/// What the baselines' scores depend on: the dataset, the resolution, the views and their
/// batches, and the LPIPS network ([`prism_losses::Lpips::digest`]).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct BaselineKey {
    dataset: PathBuf,
    resolution: u32,
    views: Vec<usize>,
    batch: usize,
    lpips: Option<u64>,
}

impl BaselineKey {
    /// The key of an evaluation of the dataset at `dataset` (its folder, compared as a
    /// canonical path where it has one).
    pub(crate) fn new(
        dataset: &Path,
        resolution: u32,
        views: &[usize],
        batch: usize,
        lpips: Option<u64>,
    ) -> Self {
        Self {
            dataset: dataset
                .canonicalize()
                .unwrap_or_else(|_| dataset.to_path_buf()),
            resolution,
            views: views.to_vec(),
            batch,
            lpips,
        }
    }
}

/// The baselines' tallies over every scored view, and the warp's footprint sweep.
#[derive(Clone)]
pub(crate) struct Baselines {
    /// Copy-source's scores and speckle sums.
    pub copy: MethodTally,
    /// The true-depth warp's scores and speckle sums, at the chosen footprint.
    pub warp: MethodTally,
    /// The warp's mean PSNR at each footprint tried.
    pub sweep: Vec<FootprintPsnr>,
    /// The split the footprint was chosen on.
    pub chosen_on: SplitKind,
}

/// The last evaluation's baselines with their key, shared by every clone of the
/// [`crate::EvaluateOptions`] that holds it. An evaluation with another key scores the
/// baselines anew and replaces them.
#[derive(Clone, Default)]
pub struct BaselineCache(Arc<Mutex<Option<(BaselineKey, Baselines)>>>);

impl BaselineCache {
    /// The baselines kept for `key`, if any.
    pub(crate) fn get(&self, key: &BaselineKey) -> Option<Baselines> {
        let kept = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        kept.as_ref()
            .filter(|(k, _)| k == key)
            .map(|(_, baselines)| baselines.clone())
    }

    /// Keeps `baselines`, scored for `key`.
    pub(crate) fn put(&self, key: BaselineKey, baselines: Baselines) {
        *self.0.lock().unwrap_or_else(PoisonError::into_inner) = Some((key, baselines));
    }
}

impl fmt::Debug for BaselineCache {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let kept = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        let key = kept.as_ref().map(|(key, _)| key);
        f.debug_tuple("BaselineCache").field(&key).finish()
    }
}
