//! Forward-time benchmark of the model (what `prism bench` and `prism bench model` run): time
//! per frame of one (source, target) pair, median over repeated runs after warm-up, inference
//! mode (no autodiff; Full attention through prism's attention kernel on the CPU backends and
//! Burn's attention op on the GPU ones), and the peak memory of the timed runs
//! ([`MemoryProbe`]).

use std::time::Instant;

use burn::tensor::{Device, Distribution, Tensor};
use glam::Vec3;
use prism_core::rays::plucker_rays;
use prism_core::reads::{geometry_host_reads, host_reads};
use prism_core::steal::StealProbe;
use prism_core::{Camera, Intrinsics};
use serde::Serialize;

use crate::prism::Prism;
use crate::tools::memory::MemoryProbe;
use crate::views::Views;

/// Views of `b` pairs as the viewing protocol makes them, at `res x res`: the frontal source
/// camera and targets 20 degrees to the side and 10 degrees up (and further pairs spread
/// around), on the 2 m orbit around `(0, 0.9, 0)`, grey background.
pub fn protocol_views(b: usize, res: usize) -> Views {
    let k = Intrinsics::protocol_default(res as u32, res as u32);
    let centre = Vec3::new(0.0, 0.9, 0.0);
    let source = vec![Camera::orbit(0.0, 0.0, 2.0, centre, k); b];
    let target = (0..b)
        .map(|i| {
            let t = i as f32 / b.max(1) as f32;
            Camera::orbit(20.0 - 40.0 * t, 10.0 - 20.0 * t, 2.0, centre, k)
        })
        .collect();
    Views::new(source, target, [0.5, 0.5, 0.5])
}

/// One measurement.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BenchRow {
    /// Name of the model (config name and attention, e.g. `tiny/full`).
    pub model: String,
    /// Image size in pixels (square).
    pub res: usize,
    /// Tokens per sequence.
    pub tokens: usize,
    /// Median forward time of one frame, milliseconds.
    pub ms: f64,
    /// `1000 / ms`.
    pub fps: f64,
    /// Peak memory of the timed runs in bytes, as [`MemoryProbe`] measures it: the device
    /// pool's reservation on wgpu / cuda, the growth of the process's resident set on the CPU
    /// backends (Linux); `None` where neither is available.
    pub peak_mem_bytes: Option<u64>,
    /// Tensors read back to the host per frame (per step for the training step) at prism's
    /// transfer points ([`prism_core::reads`]): the frame itself, loss values for the log, the
    /// gradient norm, and the geometry operations' reads.
    pub host_reads: f64,
    /// The part of `host_reads` made by the geometry operations: 0 where they run on the
    /// device.
    pub geometry_host_reads: f64,
    /// The share of the machine's CPU time the hypervisor ran something else during the
    /// timed runs ([`prism_core::steal`]; `None` where it is not counted): a row timed while
    /// it was high is slower than its code.
    pub cpu_steal: Option<f64>,
}

/// How to time.
#[derive(Clone, Copy, Debug)]
pub struct BenchOptions {
    /// Untimed runs first.
    pub warmup: usize,
    /// Timed runs; the median is reported.
    pub iters: usize,
}

/// Times the forward pass of `model` on a random source image of `res x res` pixels with
/// batch 1, seen and rendered by [`protocol_views`] (so that the geometry parts, when the
/// model has them, work on a realistic body placement).
/// The time includes waiting for the device to finish (`Device::sync`).
pub fn bench_forward(
    model: &Prism,
    name: &str,
    res: usize,
    device: &Device,
    options: BenchOptions,
) -> BenchRow {
    let image = Tensor::<4>::random([1, 3, res, res], Distribution::Uniform(0.0, 1.0), device);
    let views = protocol_views(1, res);
    let source_rays = plucker_rays(&views.source, device);
    let target_rays = plucker_rays(&views.target, device);
    let run = || {
        let out = model.forward_views(
            image.clone(),
            source_rays.clone(),
            target_rays.clone(),
            &views,
            &[],
        );
        // Waits for the result: reading it back forces lazy backends to execute.
        prism_core::reads::count_host_read();
        let _ = out.image.into_data();
        let _ = device.sync();
    };
    for _ in 0..options.warmup {
        run();
    }
    let mut probe = MemoryProbe::start(device);
    let reads = (host_reads(), geometry_host_reads());
    let steal = StealProbe::start();
    let mut times: Vec<f64> = (0..options.iters.max(1))
        .map(|_| {
            let start = Instant::now();
            run();
            let ms = start.elapsed().as_secs_f64() * 1e3;
            probe.sample();
            ms
        })
        .collect();
    let per_frame = |now: u64, then: u64| (now - then) as f64 / times.len() as f64;
    let (all_reads, geometry_reads) = (
        per_frame(host_reads(), reads.0),
        per_frame(geometry_host_reads(), reads.1),
    );
    times.sort_by(|a, b| a.total_cmp(b));
    let ms = median(&times);
    let patch = model.tokenizer.patch_size();
    BenchRow {
        model: name.to_string(),
        res,
        tokens: 2 * (res / patch) * (res / patch),
        ms,
        fps: 1e3 / ms,
        peak_mem_bytes: probe.peak_bytes(),
        host_reads: all_reads,
        geometry_host_reads: geometry_reads,
        cpu_steal: steal.share(),
    }
}

/// The median of sorted values (the mean of the middle two of an even count).
pub fn median(sorted: &[f64]) -> f64 {
    let n = sorted.len();
    if n % 2 == 1 {
        sorted[n / 2]
    } else {
        0.5 * (sorted[n / 2 - 1] + sorted[n / 2])
    }
}
