//! The training data of every step: a pure function of (seed, step), loaded ahead of the
//! training step by worker threads.

use std::ops::Range;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, sync_channel};
use std::thread;

use prism_data::{DataError, Sample, SampleDataset};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// Steps loaded ahead of the one being trained on.
const LOOKAHEAD: usize = 2;

/// Which dataset items a training step uses.
///
/// The samples of the run form one endless sequence `k = 0, 1, 2, ...`; step `s` takes samples
/// `s B .. (s + 1) B` (`B` the batch size). Sample `k` belongs to epoch `e = k / n` (`n`
/// training subjects) and is subject `perm_e[k mod n]`, where `perm_e` is a permutation of the
/// subjects seeded by `(seed, e)`: every epoch visits every subject once, in a fresh order. Its
/// targets are drawn by [`SampleDataset::plan`] from the dataset index `e n + perm_e[k mod n]`,
/// so the same subject gets new target views in every epoch.
///
/// Everything depends only on (seed, step): a resumed run sees exactly the data an
/// uninterrupted run would have seen.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DataOrder {
    /// The run's seed.
    pub seed: u64,
    /// Number of training subjects `n`.
    pub subjects: usize,
    /// Samples per step `B`.
    pub batch_size: usize,
}

impl DataOrder {
    /// The dataset indices (for [`SampleDataset::load`]) of step `step`'s samples.
    pub fn items(&self, step: usize) -> Vec<usize> {
        let n = self.subjects.max(1);
        let first = step * self.batch_size;
        let mut cached: Option<(usize, Vec<usize>)> = None;
        (first..first + self.batch_size)
            .map(|k| {
                let epoch = k / n;
                let perm = match &cached {
                    Some((e, p)) if *e == epoch => p,
                    _ => &cached.insert((epoch, self.permutation(epoch))).1,
                };
                epoch * n + perm[k % n]
            })
            .collect()
    }

    /// The subject order of `epoch`.
    fn permutation(&self, epoch: usize) -> Vec<usize> {
        let mut rng = ChaCha8Rng::seed_from_u64(
            self.seed ^ (epoch as u64 + 1).wrapping_mul(0xd1b5_4a32_d192_ed03),
        );
        let mut perm: Vec<usize> = (0..self.subjects).collect();
        perm.shuffle(&mut rng);
        perm
    }
}

/// The samples of one step, or why they could not be loaded.
pub type StepSamples = (usize, Result<Vec<Sample>, DataError>);

/// Loads the samples of consecutive steps ahead of training: with `workers > 0` a background
/// thread keeps up to two steps ready, loading each step's samples in parallel on `workers`
/// threads; with 0 workers each step is loaded when asked for.
pub struct Prefetcher {
    source: Source,
}

enum Source {
    Inline {
        dataset: Arc<SampleDataset>,
        order: DataOrder,
        steps: Range<usize>,
    },
    Thread {
        rx: Receiver<StepSamples>,
    },
}

impl Prefetcher {
    /// Starts loading steps `steps` of `order` from `dataset`.
    pub fn start(
        dataset: Arc<SampleDataset>,
        order: DataOrder,
        steps: Range<usize>,
        workers: usize,
    ) -> Self {
        if workers == 0 {
            return Self {
                source: Source::Inline {
                    dataset,
                    order,
                    steps,
                },
            };
        }
        let (tx, rx) = sync_channel(LOOKAHEAD);
        thread::Builder::new()
            .name("prism-data".into())
            .spawn(move || {
                let Ok(pool) = rayon::ThreadPoolBuilder::new()
                    .num_threads(workers)
                    .thread_name(|i| format!("prism-data-{i}"))
                    .build()
                else {
                    return;
                };
                for step in steps {
                    let items = order.items(step);
                    let samples = pool.install(|| {
                        items
                            .par_iter()
                            .map(|&i| dataset.load(i))
                            .collect::<Result<Vec<_>, _>>()
                    });
                    // The receiver is gone when training stopped: stop loading.
                    if tx.send((step, samples)).is_err() {
                        break;
                    }
                }
            })
            .expect("spawn the data loading thread");
        Self {
            source: Source::Thread { rx },
        }
    }

    /// The next step's samples, in step order; `None` after the last step.
    pub fn next_step(&mut self) -> Option<StepSamples> {
        match &mut self.source {
            Source::Inline {
                dataset,
                order,
                steps,
            } => {
                let step = steps.next()?;
                let samples = order
                    .items(step)
                    .into_iter()
                    .map(|i| dataset.load(i))
                    .collect();
                Some((step, samples))
            }
            Source::Thread { rx } => rx.recv().ok(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_epoch_visits_every_subject_once_and_steps_are_reproducible() {
        let order = DataOrder {
            seed: 7,
            subjects: 5,
            batch_size: 3,
        };
        let all: Vec<usize> = (0..10).flat_map(|s| order.items(s)).collect();
        assert_eq!(all.len(), 30);
        for epoch in 0..6 {
            let mut subjects: Vec<usize> = all[epoch * 5..epoch * 5 + 5]
                .iter()
                .map(|i| i % 5)
                .collect();
            subjects.sort_unstable();
            assert_eq!(subjects, vec![0, 1, 2, 3, 4], "epoch {epoch}");
            assert!(all[epoch * 5..epoch * 5 + 5].iter().all(|i| i / 5 == epoch));
        }
        // A pure function of (seed, step).
        assert_eq!(order.items(7), order.items(7));
        let other = DataOrder { seed: 8, ..order };
        assert_ne!(
            (0..4).flat_map(|s| order.items(s)).collect::<Vec<_>>(),
            (0..4).flat_map(|s| other.items(s)).collect::<Vec<_>>()
        );
    }
}
