//! The training data of every step: a pure function of (seed, step), split into one share per
//! device and loaded ahead of the training step by worker threads (or, for a device whose
//! server loads its own share, described only).

use std::ops::Range;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, sync_channel};
use std::thread;

use prism_data::{DataError, Sample, SampleDataset, SampleMeta};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use rayon::ThreadPool;
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

/// A device's share of a step's samples.
#[derive(Clone, Debug)]
pub enum Share {
    /// Loaded here, to be sent to the device.
    Loaded(Vec<Sample>),
    /// Loaded by the device's server (`prism serve --data`): the dataset items, and what the
    /// trainer needs of them besides their pixels.
    Served {
        /// The items (for [`SampleDataset::load`] on the server).
        items: Vec<usize>,
        /// The items' cameras and body fits.
        metas: Vec<SampleMeta>,
    },
}

impl Share {
    /// (source, target) pairs of the share.
    pub fn pairs(&self) -> usize {
        match self {
            Self::Loaded(samples) => samples.iter().map(|s| s.targets.len()).sum(),
            Self::Served { metas, .. } => metas.iter().map(|m| m.targets.len()).sum(),
        }
    }
}

/// How `samples` consecutive samples are split among `devices` devices: one range per share,
/// sizes differing by at most one (fewer shares than devices when there are fewer samples).
pub fn share_ranges(samples: usize, devices: usize) -> Vec<Range<usize>> {
    let shares = devices.min(samples).max(1);
    let (base, extra) = (samples / shares, samples % shares);
    let mut start = 0;
    (0..shares)
        .map(|i| {
            let len = base + usize::from(i < extra);
            start += len;
            start - len..start
        })
        .collect()
}

/// The shares of one step, or why they could not be loaded.
pub type StepShares = (usize, Result<Vec<Share>, DataError>);

/// Loads the shares of consecutive steps ahead of training: with `workers > 0` a background
/// thread keeps up to two steps ready, loading each step's samples in parallel on `workers`
/// threads; with 0 workers each step is loaded when asked for.
pub struct Prefetcher {
    source: Source,
}

enum Source {
    Inline {
        loader: StepLoader,
        steps: Range<usize>,
    },
    Thread {
        rx: Receiver<StepShares>,
    },
}

/// What loads a step: the dataset, the data order, and which devices' servers load their own
/// shares.
struct StepLoader {
    dataset: Arc<SampleDataset>,
    order: DataOrder,
    served: Vec<bool>,
}

impl StepLoader {
    /// The shares of `step`, loaded on `pool` (or on this thread).
    fn load(&self, step: usize, pool: Option<&ThreadPool>) -> Result<Vec<Share>, DataError> {
        let items = self.order.items(step);
        share_ranges(items.len(), self.served.len())
            .into_iter()
            .zip(&self.served)
            .map(|(range, &served)| {
                let items = items[range].to_vec();
                if served {
                    let metas = items
                        .iter()
                        .map(|&i| self.dataset.meta(i))
                        .collect::<Result<_, _>>()?;
                    return Ok(Share::Served { items, metas });
                }
                let samples = match pool {
                    Some(pool) => pool.install(|| {
                        items
                            .par_iter()
                            .map(|&i| self.dataset.load(i))
                            .collect::<Result<_, _>>()
                    }),
                    None => items.iter().map(|&i| self.dataset.load(i)).collect(),
                };
                samples.map(Share::Loaded)
            })
            .collect()
    }
}

impl Prefetcher {
    /// Starts loading steps `steps` of `order` from `dataset`, split among one device per
    /// entry of `served` (true where the device's server loads its own share).
    pub fn start(
        dataset: Arc<SampleDataset>,
        order: DataOrder,
        steps: Range<usize>,
        workers: usize,
        served: Vec<bool>,
    ) -> Self {
        let loader = StepLoader {
            dataset,
            order,
            served,
        };
        if workers == 0 {
            return Self {
                source: Source::Inline { loader, steps },
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
                    let shares = loader.load(step, Some(&pool));
                    // The receiver is gone when training stopped: stop loading.
                    if tx.send((step, shares)).is_err() {
                        break;
                    }
                }
            })
            .expect("spawn the data loading thread");
        Self {
            source: Source::Thread { rx },
        }
    }

    /// The next step's shares, in step order; `None` after the last step.
    pub fn next_step(&mut self) -> Option<StepShares> {
        match &mut self.source {
            Source::Inline { loader, steps } => {
                let step = steps.next()?;
                Some((step, loader.load(step, None)))
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

    #[test]
    fn shares_cover_the_batch_in_order_with_sizes_one_apart() {
        assert_eq!(share_ranges(5, 2), vec![0..3, 3..5]);
        assert_eq!(share_ranges(4, 4), vec![0..1, 1..2, 2..3, 3..4]);
        assert_eq!(share_ranges(2, 4), vec![0..1, 1..2]);
        assert_eq!(share_ranges(7, 1), vec![0..7]);
    }
}
