//! Each served device's share of a training batch, loaded by its own server.
//!
//! A server started with `prism serve --data DIR` answers the operation [`SHARD_OP`]: given
//! the dataset items of its share, it reads them from its copy of the dataset and makes the
//! share's pixel planes on its device, exactly as the trainer would have (same code, same
//! values). Only the item numbers cross the network; the trainer keeps the cameras and body
//! fits, which it reads without the images.

use std::sync::{Arc, Mutex};

use burn::backend::ir::{BackendIr, CustomOpIr, HandleContainer};
use burn::server::RemoteServer;
use burn::tensor::{Device, Tensor, TensorData};
use prism_data::{BatchPixels, DatasetReader, PIXEL_PLANES, SampleDataset};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use prism_core::served::{self as ops, Call, ServedOp};

/// The operation's id.
pub const SHARD_OP: &str = "prism.shard.v1";

/// Bytes of a request (a share of a few hundred items fits): the length of the call's input.
pub const REQUEST_LEN: usize = 8192;

/// Bytes of the server's status answer (empty when the share was loaded, else why not): the
/// length of the call's last output.
pub const STATUS_LEN: usize = 1024;

/// The largest sample side a server loads, pixels.
pub const MAX_RESOLUTION: u32 = 4096;
/// The most values (all planes of all pairs) of one share: 4 GiB of `f32`.
pub const MAX_SHARE_VALUES: usize = 1 << 30;
/// The most training sets (one per targets, resolution and seed) a server keeps open; beyond
/// it the least recently used one is closed.
pub const MAX_TRAINING_SETS: usize = 4;

/// A device's share of a training step, as the trainer asks its server for it.
#[derive(Clone, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct ShardRequest {
    /// Target views per sample (`train.targets_per_sample`).
    pub targets: usize,
    /// Side of the samples, pixels (`model.resolution`).
    pub resolution: u32,
    /// The run's seed (it draws each item's targets).
    pub seed: u64,
    /// The share's items of the training set (see `SampleDataset::load`).
    pub items: Vec<usize>,
}

/// `server` loading shares from the dataset of `reader` on the backend of `device`.
///
/// # Errors
/// A device of a backend that cannot be served.
pub fn register(
    server: RemoteServer,
    device: &Device,
    reader: DatasetReader,
) -> Result<RemoteServer, String> {
    ops::register(
        server,
        device,
        Loader {
            reader,
            training_sets: Arc::new(Mutex::new(Recent::new(MAX_TRAINING_SETS))),
        },
    )
}

/// Asks the server of the served `device` for the pixel planes of `request`'s share (`[P, C,
/// R, R]` in the order of `prism_data::PIXEL_PLANES`, `P = items x targets`), made on the
/// server. Blocks until the server says whether it could load them.
///
/// # Errors
/// Not a served device, or the server could not load the share (its message).
pub fn load(device: &Device, request: &ShardRequest) -> Result<[Tensor<4>; 7], String> {
    let json = serde_json::to_vec(request).expect("a request serialises");
    if json.len() > REQUEST_LEN {
        return Err(format!(
            "a share of {} items is too large for one request",
            request.items.len()
        ));
    }
    request.check_limits()?;
    let call = request
        .plane_shapes()
        .into_iter()
        .fold(
            Call::new(device)?.input(ops::encode(&json, REQUEST_LEN)),
            Call::output,
        )
        .output([STATUS_LEN]);
    let mut outputs = call.send(SHARD_OP);
    let status = ops::read_message(outputs.pop().expect("the status output"))?;
    if !status.is_empty() {
        return Err(String::from_utf8_lossy(&status).into_owned());
    }
    let mut planes = outputs.into_iter().map(ops::served_tensor::<4>);
    Ok(std::array::from_fn(|_| {
        planes.next().expect("one output per plane")
    }))
}

/// The training sets a server keeps open, by (targets, resolution, seed).
type TrainingSets = Recent<(usize, u32, u64), Arc<SampleDataset>>;

/// A cache of at most `capacity` values, the most recently used first: beyond it the least
/// recently used value is dropped.
#[derive(Debug)]
struct Recent<K, V> {
    entries: Vec<(K, V)>,
    capacity: usize,
}

impl<K: PartialEq, V: Clone> Recent<K, V> {
    /// An empty cache of at most `capacity` values.
    fn new(capacity: usize) -> Self {
        Self {
            entries: Vec::new(),
            capacity,
        }
    }

    /// The value of `key`, made by `make` if it is not cached; it becomes the most recent.
    ///
    /// # Errors
    /// `make`'s error (nothing is cached then).
    fn get_or_try_insert<E>(
        &mut self,
        key: K,
        make: impl FnOnce() -> Result<V, E>,
    ) -> Result<V, E> {
        let value = match self.entries.iter().position(|(k, _)| *k == key) {
            Some(at) => self.entries.remove(at).1,
            None => make()?,
        };
        self.entries.insert(0, (key, value.clone()));
        self.entries.truncate(self.capacity);
        Ok(value)
    }
}

impl ShardRequest {
    /// Checks the request against the server's limits, before anything is allocated for it.
    ///
    /// # Errors
    /// The limit it exceeds, named with its value.
    pub fn check_limits(&self) -> Result<(), String> {
        if self.resolution == 0 || self.resolution > MAX_RESOLUTION {
            return Err(format!(
                "a resolution of {} px is outside the server's limit of 1 to {MAX_RESOLUTION}",
                self.resolution
            ));
        }
        let side = self.resolution as usize;
        let values = self
            .items
            .len()
            .checked_mul(self.targets)
            .and_then(|pairs| pairs.checked_mul(PIXEL_PLANES.iter().sum::<usize>()))
            .and_then(|v| v.checked_mul(side * side));
        match values {
            Some(v) if v <= MAX_SHARE_VALUES => Ok(()),
            _ => Err(format!(
                "a share of {} items x {} targets at {side} px exceeds the server's limit of \
                 {MAX_SHARE_VALUES} values",
                self.items.len(),
                self.targets
            )),
        }
    }

    /// The shapes of the share's planes, in the order of `PIXEL_PLANES`.
    fn plane_shapes(&self) -> Vec<[usize; 4]> {
        let side = self.resolution as usize;
        let pairs = self.items.len() * self.targets;
        PIXEL_PLANES
            .iter()
            .map(|&c| [pairs, c, side, side])
            .collect()
    }
}

/// The server's handler: the training sets asked for, opened once each.
#[derive(Clone)]
struct Loader {
    reader: DatasetReader,
    training_sets: Arc<Mutex<TrainingSets>>,
}

impl Loader {
    /// The training set of `request`, opened or taken from the cache (kept bounded).
    fn training_set(&self, request: &ShardRequest) -> Result<Arc<SampleDataset>, String> {
        let key = (request.targets, request.resolution, request.seed);
        let mut sets = self
            .training_sets
            .lock()
            .map_err(|_| "the server's dataset cache is poisoned".to_string())?;
        sets.get_or_try_insert(key, || {
            SampleDataset::training(
                self.reader.clone(),
                request.targets,
                request.resolution,
                request.seed,
            )
            .map(Arc::new)
            .map_err(|e| e.to_string())
        })
    }

    /// The planes of `request`'s share, or why they cannot be loaded.
    fn planes(&self, request: &ShardRequest) -> Result<[TensorData; 7], String> {
        let set = self.training_set(request)?;
        let samples = request
            .items
            .par_iter()
            .map(|&item| set.load(item))
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| e.to_string())?;
        if samples.is_empty() {
            return Err("an empty share".into());
        }
        Ok(BatchPixels::of(&samples).into_data())
    }
}

impl ServedOp for Loader {
    const ID: &'static str = SHARD_OP;

    fn run<B: BackendIr>(
        &self,
        handles: &mut HandleContainer<B::Handle>,
        op: &CustomOpIr,
        device: &B::Device,
    ) {
        let request =
            serde_json::from_slice::<ShardRequest>(&ops::input_message::<B>(handles, op, 0))
                .map_err(|e| format!("not a share request ({e})"));
        // Within the limits, and the outputs declared are the request's: checked before
        // anything is loaded or allocated.
        let request = request.and_then(|r| r.check_limits().map(|()| r));
        let request = request.and_then(|r| {
            let declared: Vec<&[usize]> = op.outputs.iter().map(|o| &o.shape[..]).collect();
            let wanted = r.plane_shapes();
            let mut expected: Vec<&[usize]> = wanted.iter().map(|s| &s[..]).collect();
            expected.push(&[STATUS_LEN]);
            if declared == expected {
                Ok(r)
            } else {
                Err(format!(
                    "the call declares outputs {declared:?}, the request makes {expected:?}"
                ))
            }
        });
        let planes = request.and_then(|r| self.planes(&r));
        let status = match planes {
            Ok(planes) => {
                for (index, data) in planes.into_iter().enumerate() {
                    ops::put_output::<B>(handles, op, index, data, device);
                }
                Vec::new()
            }
            Err(why) => {
                eprintln!("prism serve: cannot load a share: {why}");
                // One value each, whatever the call declared: nothing a caller sizes is
                // allocated for a refused share (the trainer reads the status, not these).
                for index in 0..PIXEL_PLANES.len().min(op.outputs.len()) {
                    let zero = TensorData::new(vec![0.0f32], [1]);
                    ops::put_output::<B>(handles, op, index, zero, device);
                }
                let mut why = format!("the server cannot load its share: {why}").into_bytes();
                why.truncate(STATUS_LEN);
                why
            }
        };
        let status = TensorData::new(ops::encode(&status, STATUS_LEN), [STATUS_LEN]);
        ops::put_output::<B>(handles, op, PIXEL_PLANES.len(), status, device);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cache_keeps_the_most_recent_values_up_to_its_capacity() {
        let mut cache = Recent::new(2);
        let made = std::cell::Cell::new(0);
        let get = |cache: &mut Recent<u64, u64>, key: u64| {
            cache
                .get_or_try_insert(key, || {
                    made.set(made.get() + 1);
                    Ok::<_, ()>(key * 10)
                })
                .unwrap()
        };
        assert_eq!(get(&mut cache, 1), 10);
        assert_eq!(get(&mut cache, 2), 20);
        assert_eq!(get(&mut cache, 1), 10); // cached: 1 is now the most recent
        assert_eq!(get(&mut cache, 3), 30); // drops 2, the least recent
        assert_eq!(cache.entries.len(), 2);
        assert_eq!(get(&mut cache, 1), 10);
        assert_eq!(get(&mut cache, 2), 20); // made again
        assert_eq!(made.get(), 4);
        // A flood of keys never grows it past its capacity.
        for key in 100..200 {
            get(&mut cache, key);
        }
        assert_eq!(cache.entries.len(), 2);
        let failed = cache.get_or_try_insert(7, || Err::<u64, _>("cannot"));
        assert_eq!(failed, Err("cannot"));
        assert_eq!(cache.entries.len(), 2);
    }

    #[test]
    fn requests_past_the_limits_are_refused_naming_the_limit() {
        let request = |resolution, items: usize, targets| ShardRequest {
            targets,
            resolution,
            seed: 0,
            items: (0..items).collect(),
        };
        assert!(request(256, 8, 4).check_limits().is_ok());
        let side = request(100_000, 1, 1).check_limits().unwrap_err();
        assert!(side.contains("limit of 1 to 4096"), "{side}");
        assert!(request(0, 1, 1).check_limits().is_err());
        let big = request(4096, 100, 4).check_limits().unwrap_err();
        assert!(big.contains(&MAX_SHARE_VALUES.to_string()), "{big}");
        assert!(request(4096, 1, usize::MAX).check_limits().is_err());
    }
}
