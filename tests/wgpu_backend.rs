//! The wgpu backend agrees with flex: a forward pass of the tiny model (geometry parts
//! included) and one training step (teacher objective, backward, SGD update) from the same
//! weights on the same batch, which on wgpu reads nothing back to the host in its geometry
//! operations (the device kernels) where on flex it does (the host path), nor in a training
//! step of the small config.
//!
//! Runs in the default build (the `wgpu` feature) on a machine with a Vulkan / Metal / DX12
//! adapter; Mesa's software Vulkan (lavapipe, Debian package `mesa-vulkan-drivers`) is enough, and `.ci/run`
//! installs it. Without an adapter the tests are listed as ignored (see `build/wgpu_adapter.rs`),
//! unless `PRISM_REQUIRE_WGPU=1` (set by CI), which turns the missing adapter into a failure.
#![cfg(feature = "wgpu")]

// Its own test binary, apart from tests/cli: the geometry-read counter is process-wide, and
// tests/cli's tests, which run side by side, train in-process on the CPU backends (whose host
// path counts).
#[path = "cli/common/mod.rs"]
mod common;

use std::path::Path;

use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::{AdamWConfig, GradientsParams, SgdConfig};
use burn::tensor::{Device, Tensor};
use prism_core::reads::geometry_host_reads;
use prism_data::{
    DatasetReader, PrismBatch, PrismBatcher, Sample, SampleDataset, SplitKind, TargetSelection,
};
use prism_model::{Prism, protocol_views};
use prism_synth::synthetic_dataset_dir_in;
use prism_train::{StepLoss, TeacherLoss, TrainingConfig};

fn tiny() -> TrainingConfig {
    config("tiny")
}

/// A shipped config, LPIPS off.
fn config(name: &str) -> TrainingConfig {
    let mut config = TrainingConfig::load(
        Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("configs/{name}.toml")),
    )
    .expect("shipped config");
    // LPIPS weighs in through the same tensor ops; leaving it out keeps the test fast.
    config.losses.lpips = 0.0;
    config
}

/// Every float parameter's values, in visiting order.
fn parameters(model: &Prism) -> Vec<Vec<f32>> {
    struct Collect(Vec<Vec<f32>>);
    impl ModuleVisitor for Collect {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.0.push(values(&param.val()));
        }
    }
    let mut collect = Collect(Vec::new());
    model.visit(&mut collect);
    collect.0
}

fn values<const D: usize>(t: &Tensor<D>) -> Vec<f32> {
    t.to_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .expect("f32")
}

/// Largest `|a - b|` relative to the largest `|b|`.
fn relative_error(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(1e-6f32, |m, v| m.max(v.abs()));
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
        / scale
}

#[test]
#[cfg_attr(not(wgpu_adapter), ignore = "no wgpu adapter on this machine")]
fn tiny_forward_on_wgpu_matches_flex() {
    let _alone = common::device_alone();
    let Some(wgpu) = common::wgpu_device() else {
        return;
    };
    let flex = Device::flex();
    flex.seed(5);
    let config = tiny();
    let model = config.model.init(&flex);
    let res = 32;
    let views = protocol_views(2, res);
    flex.seed(6);
    let image = Tensor::<4>::random(
        [2, 3, res, res],
        burn::tensor::Distribution::Uniform(0.0, 1.0),
        &flex,
    );
    let run = |model: &Prism, device: &Device| {
        let rays = |cams| prism_core::rays::plucker_rays(cams, device);
        let out = model.forward_views(
            image.clone().to_device(device),
            rays(&views.source),
            rays(&views.target),
            &views,
            &[1, 4],
        );
        let gs = out.gaussians.expect("tiny has the 3DGS head").image;
        (values(&out.image), values(&out.hidden[1]), values(&gs))
    };
    let want = run(&model, &flex);
    let got = run(&model.clone().to_device(&wgpu), &wgpu);
    for (name, g, w) in [
        ("image", &got.0, &want.0),
        ("hidden 4", &got.1, &want.1),
        ("I_gs", &got.2, &want.2),
    ] {
        let err = relative_error(g, w);
        assert!(err < 1e-3, "{name}: relative error {err}");
    }
}

/// One teacher step (forward, objective, backward, plain SGD) on a batch of the tiny synthetic
/// dataset, from the same weights: the same loss and the same update of every weight; the
/// step's geometry operations read from the host on flex (so the counter is live), never on
/// wgpu, nor in a step of the small config.
///
/// The update is SGD's, `-lr g`, so it is the gradient itself: a gradient wrong by a factor
/// `k` gives a relative error of `|k - 1|` (1 for a planted factor of 2, against the tolerance
/// of 2e-2). AdamW's first update, about `lr sign(g)`, would hide any positive factor.
#[test]
#[cfg_attr(not(wgpu_adapter), ignore = "no wgpu adapter on this machine")]
fn one_training_step_on_wgpu_matches_flex_without_geometry_reads() {
    let _alone = common::device_alone();
    let Some(wgpu) = common::wgpu_device() else {
        return;
    };
    let config = tiny();
    assert!(config.model.smplx_branch && config.model.point_branch);
    let (samples, background) = samples(&config, 2, 32);
    let flex = Device::flex();
    flex.seed(7);
    let initial = config.model.init(&flex);

    let step = |device: &Device| {
        let before = geometry_host_reads();
        let ad = device.clone().autodiff();
        let batch: PrismBatch = PrismBatcher.batch_samples(&samples, &ad);
        // Moved onto the autodiff device, `train` turns the parameters' gradients on.
        let model = initial.clone().to_device(&ad).train();
        let loss = TeacherLoss::new(&config, background, None, &ad).expect("objective");
        let terms = loss.loss(&model, &batch, 0);
        let total = values(&terms.total.clone().inner())[0];
        let grads = GradientsParams::from_grads(terms.total.backward(), &model);
        let mut optim = SgdConfig::new().init();
        let model = optim.step(1.0, model, grads);
        let _ = device.sync();
        let reads = geometry_host_reads() - before;
        (total, parameters(&model.valid()), reads)
    };
    let (loss_flex, params_flex, reads_flex) = step(&flex);
    let (loss_wgpu, params_wgpu, reads_wgpu) = step(&wgpu);
    assert!(reads_flex > 0, "the host path counts its reads");
    assert_eq!(
        reads_wgpu, 0,
        "geometry reads of the tiny config's step on wgpu"
    );
    assert!(loss_flex.is_finite() && loss_flex > 0.0);
    assert!(
        (loss_wgpu - loss_flex).abs() <= 1e-4 * loss_flex.abs(),
        "loss {loss_wgpu} on wgpu vs {loss_flex} on flex"
    );
    let before = parameters(&initial);
    let mut moved = 0;
    for ((w, f), b) in params_wgpu.iter().zip(&params_flex).zip(&before) {
        // Compare the updates (the gradients, at lr 1), not the weights, so that a small
        // update is not hidden by a large weight.
        let update_w: Vec<f32> = w.iter().zip(b).map(|(x, y)| x - y).collect();
        let update_f: Vec<f32> = f.iter().zip(b).map(|(x, y)| x - y).collect();
        if update_f.iter().any(|u| u.abs() > 1e-6) {
            moved += 1;
        }
        let err = relative_error(&update_w, &update_f);
        assert!(err < 2e-2, "update differs by {err} (relative)");
    }
    assert!(moved > 10, "only {moved} parameters moved");

    // Nor does a step of the small config (wider branches and heads), on the tiny dataset's
    // people (the reads do not depend on the data). In this test, not one of its own: both
    // hold the device alone, and a second test would only wait for the lock on a test thread.
    let mut small = self::config("small");
    small.data = config.data.clone();
    assert!(small.model.smplx_branch && small.model.point_branch);
    assert_eq!(geometry_reads_of_a_step(&small, &wgpu, 32), 0, "small");
}

/// The first `count` training samples of `config`'s synthetic dataset (two targets each) at
/// `size` pixels, and the dataset's background colour.
fn samples(config: &TrainingConfig, count: usize, size: u32) -> (Vec<Sample>, [f32; 3]) {
    let data = synthetic_dataset_dir_in(&common::cache(&config.data), &config.data);
    let reader = DatasetReader::open(&data).expect("dataset");
    let background = reader.meta().background;
    let dataset = SampleDataset::new(
        reader,
        SplitKind::Train,
        TargetSelection::Random {
            count: 2,
            repeats: 1,
        },
        Some((size, size)),
        0,
    )
    .expect("samples");
    let samples = (0..count).map(|i| dataset.load(i).unwrap()).collect();
    (samples, background)
}

/// The geometry reads of one teacher step (forward, objective, backward, AdamW) of `config`
/// on `device`, on a batch of its synthetic dataset at `size` pixels.
fn geometry_reads_of_a_step(config: &TrainingConfig, device: &Device, size: u32) -> u64 {
    let (samples, background) = samples(config, 1, size);
    let ad = device.clone().autodiff();
    device.seed(3);
    let model = config.model.init(device).to_device(&ad).train();
    let batch: PrismBatch = PrismBatcher.batch_samples(&samples, &ad);
    let loss = TeacherLoss::new(config, background, None, &ad).expect("objective");
    let before = geometry_host_reads();
    let terms = loss.loss(&model, &batch, 0);
    let grads = GradientsParams::from_grads(terms.total.backward(), &model);
    let model = AdamWConfig::new().init().step(1e-3, model, grads);
    let _ = device.sync();
    let reads = geometry_host_reads() - before;
    drop(model);
    reads
}
