//! Timings of the Gaussian rasterizer on the CPU backends, at the main job's sizes:
//! `cargo bench -p prism-render --bench splat [-- ndarray|flex]`.
//!
//! A batch of 4 surfaces of 128 x 128 pixel-aligned Gaussians, one per source pixel as the 3DGS
//! head and the point branch give them: an opaque, wavy figure about 2 m away on a faint
//! backdrop, each Gaussian half a source pixel's footprint wide. Each batch element is seen
//! from a target camera 10 to 30 degrees to the side. Features have 3 channels (the 3DGS head's
//! colours) or 11 (the point branch's features and colours). Prints the median of a few runs of
//! the forward pass, and of the forward and reverse passes together.

use std::time::Instant;

use burn::tensor::{Device, Tensor, TensorData};
use glam::Vec3;
use prism_core::{BackendKind, Camera, Intrinsics};
use prism_render::splat::{Gaussians, render};

/// Image side of the source and target cameras, in pixels.
const SIDE: u32 = 128;
/// Batch elements, one target camera each.
const BATCH: usize = 4;
/// Distance of the figure from the cameras, in metres.
const DISTANCE: f32 = 2.0;

fn median_ms(runs: usize, mut f: impl FnMut()) -> f64 {
    f(); // warm-up
    let mut times: Vec<f64> = (0..runs)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    times.sort_by(f64::total_cmp);
    times[runs / 2]
}

/// Host values of the batch's Gaussians, in the layout of [`Gaussians`]' tensors.
struct Scene {
    means: Vec<f32>,
    log_scales: Vec<f32>,
    rotations: Vec<f32>,
    opacity_logits: Vec<f32>,
    features: Vec<f32>,
    channels: usize,
}

impl Scene {
    /// One Gaussian per pixel of the frontal source camera, unprojected to a wavy surface.
    fn new(channels: usize) -> Self {
        let intrinsics = Intrinsics::protocol_default(SIDE, SIDE);
        let source = Camera::orbit(0.0, 0.0, DISTANCE, Vec3::ZERO, intrinsics);
        let mut scene = Self {
            means: vec![],
            log_scales: vec![],
            rotations: vec![],
            opacity_logits: vec![],
            features: vec![],
            channels,
        };
        let side = SIDE as f32;
        for b in 0..BATCH {
            for y in 0..SIDE {
                for x in 0..SIDE {
                    let (u, v) = (x as f32 + 0.5, y as f32 + 0.5);
                    let (nx, ny) = (2.0 * u / side - 1.0, 2.0 * v / side - 1.0);
                    // The figure: an upright ellipse, in front of the backdrop.
                    let inside = (nx / 0.45).powi(2) + (ny / 0.9).powi(2) < 1.0;
                    let depth = if inside {
                        DISTANCE - 0.15 * (1.0 - nx * nx).sqrt() + 0.02 * (9.0 * ny).sin()
                    } else {
                        DISTANCE + 0.5
                    };
                    let mean = source.unproject(u, v, depth);
                    scene.means.extend([mean.x, mean.y, mean.z]);
                    let scale = (0.5 * depth / intrinsics.fx).ln();
                    scene.log_scales.extend([scale; 3]);
                    scene.rotations.extend([1.0, 0.0, 0.0, 0.0]);
                    scene.opacity_logits.push(if inside { 3.0 } else { -3.0 });
                    let phase = (b * 7 + x as usize * 3 + y as usize * 5) as f32;
                    scene
                        .features
                        .extend((0..channels).map(|c| 0.5 + 0.5 * (phase + c as f32).sin()));
                }
            }
        }
        scene
    }

    fn tensor(values: &[f32], last: usize, device: &Device) -> Tensor<3> {
        let n = (SIDE * SIDE) as usize;
        Tensor::from_data(TensorData::new(values.to_vec(), [BATCH, n, last]), device)
    }

    fn gaussians(&self, device: &Device, grad: bool) -> Gaussians {
        let t = |values: &[f32], last| {
            let t = Self::tensor(values, last, device);
            if grad { t.require_grad() } else { t }
        };
        Gaussians {
            means: t(&self.means, 3),
            log_scales: t(&self.log_scales, 3),
            rotations: t(&self.rotations, 4),
            opacity_logits: t(&self.opacity_logits, 1),
            features: t(&self.features, self.channels),
        }
    }
}

/// The batch's target cameras: 10 to 30 degrees to either side, a little above or below.
fn targets() -> Vec<Camera> {
    let intrinsics = Intrinsics::protocol_default(SIDE, SIDE);
    [(10.0, 5.0), (-20.0, -5.0), (30.0, 0.0), (-30.0, 10.0)]
        .into_iter()
        .take(BATCH)
        .map(|(yaw, pitch)| Camera::orbit(yaw, pitch, DISTANCE, Vec3::ZERO, intrinsics))
        .collect()
}

fn bench(kind: BackendKind) {
    let device = kind.device().unwrap();
    let ad = device.clone().autodiff();
    let cameras = targets();
    for channels in [3, 11] {
        let scene = Scene::new(channels);
        let t = median_ms(9, || {
            let out = render(&scene.gaussians(&device, false), &cameras).unwrap();
            let _ = out.features.into_data();
        });
        println!("{kind}: forward, {BATCH} x {SIDE}^2 Gaussians, {channels} channels: {t:.1} ms");
        let t = median_ms(9, || {
            let g = scene.gaussians(&ad, true);
            let out = render(&g, &cameras).unwrap();
            let loss = out.features.sum() + out.alpha.sum() + out.depth.sum();
            let grads = loss.backward();
            let _ = g.means.grad(&grads).unwrap().into_data();
        });
        println!(
            "{kind}: forward + reverse, {BATCH} x {SIDE}^2 Gaussians, {channels} channels: {t:.1} ms"
        );
    }
}

fn main() {
    let kinds: Vec<BackendKind> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let kinds = if kinds.is_empty() {
        vec![BackendKind::Flex]
    } else {
        kinds
    };
    for kind in kinds {
        bench(kind);
    }
}
