//! Each served device's share of a training batch, loaded by its own server.
//!
//! A server started with `prism serve --data DIR` answers the operation [`SHARD_OP`]: given
//! the dataset items of its share, it reads them from its copy of the dataset and makes the
//! share's pixel planes on its device, exactly as the trainer would have (same code, same
//! values). Only the item numbers cross the network; the trainer keeps the cameras and body
//! fits, which it reads without the images.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use burn::backend::ir::{BackendIr, CustomOpIr, HandleContainer};
use burn::server::RemoteServer;
use burn::tensor::{Device, Tensor, TensorData};
use prism_data::{BatchPixels, DatasetReader, PIXEL_PLANES, SampleDataset};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::handshake::config_digest;
use prism_core::served::{self as ops, Call, ServedOp};

/// The operation's id.
pub const SHARD_OP: &str = "prism.shard.v1";

/// Bytes of a request (a share of a few hundred items fits).
const REQUEST_LEN: usize = 8192;

/// Bytes of the server's status answer (empty when the share was loaded, else why not).
const STATUS_LEN: usize = 1024;

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

/// The digest of the dataset opened by `reader` (its `dataset.json`): a trainer and a server
/// with equal digests hold the same dataset.
pub fn dataset_digest(reader: &DatasetReader) -> String {
    let meta = serde_json::to_string(reader.meta()).expect("a dataset's meta serialises");
    config_digest(&meta)
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
            training_sets: Arc::default(),
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
    let pairs = request.items.len() * request.targets;
    let side = request.resolution as usize;
    let call = PIXEL_PLANES
        .iter()
        .fold(
            Call::new(device)?.input(ops::encode(&json, REQUEST_LEN)),
            |call, &c| call.output([pairs, c, side, side]),
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

/// The training sets a server was asked for, by (targets, resolution, seed).
type TrainingSets = HashMap<(usize, u32, u64), Arc<SampleDataset>>;

/// The server's handler: the training sets asked for, opened once each.
#[derive(Clone)]
struct Loader {
    reader: DatasetReader,
    training_sets: Arc<Mutex<TrainingSets>>,
}

impl Loader {
    /// The planes of `request`'s share, or why they cannot be loaded.
    fn planes(&self, request: &ShardRequest) -> Result<[TensorData; 7], String> {
        let key = (request.targets, request.resolution, request.seed);
        let set = {
            let mut sets = self
                .training_sets
                .lock()
                .map_err(|_| "the server's dataset cache is poisoned".to_string())?;
            match sets.get(&key) {
                Some(set) => set.clone(),
                None => {
                    let set = Arc::new(
                        SampleDataset::training(
                            self.reader.clone(),
                            request.targets,
                            request.resolution,
                            request.seed,
                        )
                        .map_err(|e| e.to_string())?,
                    );
                    sets.insert(key, set.clone());
                    set
                }
            }
        };
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
        let planes = request.and_then(|r| self.planes(&r)).and_then(|planes| {
            match planes
                .iter()
                .zip(&op.outputs)
                .find(|(data, out)| *data.shape() != out.shape)
            {
                Some((data, out)) => Err(format!(
                    "the share's planes are {:?}, the trainer expects {:?}",
                    data.shape(),
                    out.shape
                )),
                None => Ok(planes),
            }
        });
        let status = match planes {
            Ok(planes) => {
                for (index, data) in planes.into_iter().enumerate() {
                    ops::put_output::<B>(handles, op, index, data, device);
                }
                Vec::new()
            }
            Err(why) => {
                eprintln!("prism serve: cannot load a share: {why}");
                for (index, out) in op.outputs[..PIXEL_PLANES.len()].iter().enumerate() {
                    let zeros = TensorData::zeros::<f32, _>(out.shape.clone());
                    ops::put_output::<B>(handles, op, index, zeros, device);
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
