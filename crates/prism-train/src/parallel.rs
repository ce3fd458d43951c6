//! Data parallelism with Burn's multi-device machinery.
//!
//! Each step's batch is split into one share per device. With one device the share runs on
//! the calling thread; with several, Burn's [`MultiDevicesTrainStep`] (what
//! `ExecutionStrategy::multi` runs inside burn-train's `Learner`) forks the model to every
//! device and runs [`TrainStep::step`] there in its worker thread. The gradients are brought to
//! the main device with [`GradientsParams::to_device`] and summed by Burn's
//! [`GradientsAccumulator`]; since every share's loss is weighted by its fraction of the batch
//! (see [`TrainItem::weight`]) the sum is the gradient of the whole batch's mean loss, and the
//! optimizer steps once on the main device (burn-train's `MultiDeviceOptim::OptimMainDevice`).
//!
//! On one local device of a CPU backend the batch may still be split: [`cpu_shares`] shares
//! run at once on rayon's pool, each on its own fork of the model (a fork has its own autodiff
//! graph), and their gradients are summed the same way. The step's kernels are parallel, but
//! between them it has serial stretches (Burn's element-wise ops and copies, the autodiff tape,
//! small products): about a quarter of a teacher step on two cores, while the other thread
//! waits. With two shares one share's serial stretch runs beside the other's work.
//!
//! The devices may be served by other machines (`prism serve`, Burn's remote backend): the
//! same step then forks the model to each served device and brings the gradients to the main
//! one with Burn's server-to-server transfers. Burn 0.22 has no all-reduce across servers (see
//! the README, "Training on several machines"), which is why the gradients are gathered.

use burn::data::dataloader::{DataLoaderIterator, Progress};
use burn::data::dataset::DatasetError;
use burn::module::Module;
use burn::optim::{GradientsAccumulator, GradientsParams};
use burn::tensor::Device;
use burn_train::train::{MultiDeviceStepError, MultiDevicesTrainStep};
use burn_train::{TrainOutput, TrainStep};
use prism_core::BackendKind;
use prism_remote::{DeviceList, Fingerprint, config_digest};
use rayon::prelude::*;

use crate::config::TrainingConfig;
use crate::error::{Result, TrainError};
use crate::served::{RESUME_HINT, device_names};
use crate::step::{StepValues, TrainItem, Trainee};

/// A device of a run.
#[derive(Clone, Debug)]
pub struct TrainingDevice {
    /// The device, with autodiff.
    pub device: Device,
    /// Its `--devices` entry (what errors call it).
    pub name: String,
    /// Whether its server loads the device's share of each batch (`prism serve --data`).
    pub loads_shares: bool,
}

/// The devices of a run, the first one the main device: `list`'s local devices on
/// `backend`, and its served devices (`prism serve`) connected with `token` and checked
/// against `fingerprint` (this release, the run's model config and dataset).
///
/// The CPU backends (ndarray, flex) have a single device each; several local "devices" are
/// then the same CPU device used by several worker threads, which exercises the multi-device
/// path (and can use idle cores) but is not faster than one device with its own threads. With
/// a GPU backend, the GPUs `0..count` ([`BackendKind::devices`]).
///
/// # Errors
/// A backend that is not compiled in; a served device that cannot be used.
pub fn training_devices(
    backend: BackendKind,
    list: &DeviceList,
    token: Option<&str>,
    fingerprint: &Fingerprint,
) -> Result<Vec<TrainingDevice>> {
    let devices: Vec<(Device, bool)> = if list.has_remote() {
        prism_remote::connect(list, &backend.device()?, token, fingerprint)?
            .into_iter()
            .map(|c| (c.device, c.loads_shares))
            .collect()
    } else {
        let local = backend.devices(list.len())?;
        local.into_iter().map(|device| (device, false)).collect()
    };
    Ok(devices
        .into_iter()
        .zip(device_names(list))
        .map(|((device, loads_shares), name)| TrainingDevice {
            device: device.autodiff(),
            name,
            loads_shares,
        })
        .collect())
}

/// What a trainer expects of every server: this release, and the digest of `config`'s model
/// (a server started with another model config is refused).
pub fn fingerprint(config: &TrainingConfig) -> Fingerprint {
    let model = serde_json::to_string(&config.model).expect("a model config serialises");
    Fingerprint::this_build(Some(config_digest(&model)))
}

/// The shares of each step's batch on one local device of a CPU backend: `asked`
/// (`--cpu-shares`), else two, whatever the number of threads (so that a run gives the same
/// bits on any core count). On a 2-core Xeon two shares took the teacher's step to 0.90x of
/// its time and the student's to 0.88x. Along a whole run the two shares' gradient is the
/// whole batch's to 1e-7 at every step, and over 18 training seeds each the main job's teacher
/// scored 20.86 dB with two shares and 20.97 with the batch whole, one standard error apart
/// (BENCHMARKS.md, issue 43's "Two shares again").
pub fn cpu_shares(asked: Option<usize>) -> usize {
    asked.unwrap_or(2)
}

/// Runs the forward and backward passes of a step's shares on their devices.
pub struct DataParallel {
    devices: Vec<Device>,
    names: Vec<String>,
    multi: Option<MultiDevicesTrainStep<Trainee>>,
    /// Shares of each step's batch: one per device, or with one device, those computed at
    /// once on rayon's pool.
    shares: usize,
}

impl DataParallel {
    /// Workers for `devices` (the first is the main device). With one device, each step's
    /// batch is cut into `shares` shares computed at once; with several, into one share per
    /// device (`shares` is then ignored).
    ///
    /// # Panics
    /// If `devices` is empty.
    pub fn new(devices: Vec<TrainingDevice>, shares: usize) -> Self {
        assert!(!devices.is_empty(), "at least one device");
        let names = devices.iter().map(|d| d.name.clone()).collect();
        let devices: Vec<Device> = devices.into_iter().map(|d| d.device).collect();
        let multi = (devices.len() > 1).then(|| MultiDevicesTrainStep::new(&devices));
        let shares = if devices.len() > 1 {
            devices.len()
        } else {
            shares.max(1)
        };
        Self {
            devices,
            names,
            multi,
            shares,
        }
    }

    /// Shares of each step's batch (fewer when the batch has fewer samples).
    pub fn shares(&self) -> usize {
        self.shares
    }

    /// The index of the device share `share` runs on.
    pub fn device_of(&self, share: usize) -> usize {
        share % self.devices.len()
    }

    /// Device `index`'s failure `why` as an error naming it.
    pub fn failure(&self, index: usize, why: &str) -> TrainError {
        TrainError::Worker(format!(
            "device {index} ({}) failed: {why}",
            self.names[index]
        ))
    }

    /// The devices, main device first.
    pub fn devices(&self) -> &[Device] {
        &self.devices
    }

    /// The main device (where the model and the optimizer live).
    pub fn main_device(&self) -> &Device {
        &self.devices[0]
    }

    /// Forward and backward of `shares` (share `i` on device [`DataParallel::device_of`]`(i)`;
    /// fewer shares than devices leave the last devices idle). Returns the summed gradients on
    /// the main device and the summed values of the shares.
    ///
    /// # Errors
    /// [`TrainError::Worker`] when a worker panicked.
    pub fn forward_backward(
        &self,
        model: &Trainee,
        shares: Vec<TrainItem>,
    ) -> Result<(GradientsParams, StepValues)> {
        let Some(multi) = &self.multi else {
            return Ok(self.concurrent(model, shares));
        };
        let mut shares = shares.into_iter();
        let mut loaders: Vec<Box<dyn DataLoaderIterator<TrainItem>>> = (0..self.devices.len())
            .map(|_| Box::new(OneShare(shares.next())) as Box<dyn DataLoaderIterator<TrainItem>>)
            .collect();
        let (outputs, _) = multi.step(&mut loaders, model).map_err(|e| match e {
            MultiDeviceStepError::Workers(failures) => {
                let failure = &failures[0];
                let hint = if self.names[failure.device_id].starts_with("remote:") {
                    format!(" (its server stopped answering?); {RESUME_HINT}")
                } else {
                    String::new()
                };
                let message = failure.message.lines().next().unwrap_or_default();
                self.failure(failure.device_id, &format!("{message}{hint}"))
            }
            other => TrainError::Worker(other.to_string()),
        })?;
        let main = self.main_device();
        let mut outputs: Vec<_> = outputs.into_iter().map(|o| o.output).collect();
        outputs.sort_by_key(|o| o.item.share);
        Ok(summed(
            model,
            outputs.into_iter().map(|mut output| {
                output.grads = output.grads.to_device(main, model);
                output
            }),
        ))
    }

    /// The shares of one device, computed at once on rayon's pool: the first on `model`, each
    /// other on a fork of it (the same weights under new autodiff leaves, so that every
    /// share's backward pass walks its own graph). The gradients are summed in share order, so
    /// a step gives the same result whichever thread ran which share.
    fn concurrent(&self, model: &Trainee, shares: Vec<TrainItem>) -> (GradientsParams, StepValues) {
        let device = self.main_device();
        let outputs: Vec<_> = shares
            .into_par_iter()
            .enumerate()
            .map(|(i, share)| match i {
                0 => TrainStep::step(model, share),
                _ => TrainStep::step(&model.clone().fork(device), share),
            })
            .collect();
        summed(model, outputs)
    }
}

/// The shares' outputs, in share order and with their gradients on the main device: the
/// gradients summed, and the values.
fn summed(
    model: &Trainee,
    outputs: impl IntoIterator<Item = TrainOutput<StepValues>>,
) -> (GradientsParams, StepValues) {
    let mut accumulator = GradientsAccumulator::new();
    let mut values = Vec::new();
    for output in outputs {
        accumulator.accumulate(model, output.grads);
        values.push(output.item);
    }
    (accumulator.grads(), StepValues::sum(&values))
}

/// A data loader iterator over at most one share: what one worker of
/// [`MultiDevicesTrainStep::step`] takes for one step.
struct OneShare(Option<TrainItem>);

impl Iterator for OneShare {
    type Item = std::result::Result<TrainItem, DatasetError>;

    fn next(&mut self) -> Option<Self::Item> {
        self.0.take().map(Ok)
    }
}

impl DataLoaderIterator<TrainItem> for OneShare {
    fn progress(&self) -> Progress {
        Progress::new(usize::from(self.0.is_none()), 1, None)
    }
}
