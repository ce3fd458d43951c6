//! The host (CPU) rasterizer: forward and reverse pass on plain `f32` buffers, parallel over
//! Gaussians (projection) and over 16x16 tiles (compositing) with rayon.
//!
//! Every backend uses it through host memory: the tensors are read to the host, rendered here
//! and the result is uploaded to the tensors' device (see `op.rs`).

pub mod project;
pub mod raster;
pub mod view;

use prism_core::Camera;
use rayon::prelude::*;

use project::{Params, Projected, ProjectedGrads, project, project_backward};
use raster::{Composited, GRAD_HEAD, TileLists, bin, composite, composite_backward};
use view::View;

/// Side of the square screen tiles, in pixels.
pub const TILE_SIZE: usize = 16;
/// Added to the diagonal of every 2D covariance (pixels^2): the usual EWA low-pass filter.
pub const DILATION: f32 = 0.3;
/// A Gaussian's screen support, in standard deviations (Mahalanobis distance).
pub const EXTENT_SIGMAS: f32 = 3.0;
/// `power = d^T conic d / 2` beyond which a pixel is outside the 3-sigma support.
pub const MAX_POWER: f32 = 0.5 * EXTENT_SIGMAS * EXTENT_SIGMAS;
/// Gaussians whose camera-space depth is below this (metres) are not drawn.
pub const NEAR_PLANE: f32 = 0.01;
/// Alphas below this are skipped.
pub const MIN_ALPHA: f32 = 1.0 / 255.0;
/// Alphas are clamped to this.
pub const MAX_ALPHA: f32 = 0.99;
/// A pixel stops before the Gaussian that would take its transmittance below this.
pub const MIN_TRANSMITTANCE: f32 = 1e-4;

/// `B x N` Gaussians in host memory, row-major like the tensors they came from.
#[derive(Clone, Debug, Default)]
pub struct HostGaussians {
    /// Batch size `B` (one camera per batch element).
    pub batch: usize,
    /// Gaussians per batch element `N`.
    pub count: usize,
    /// Feature channels `C`.
    pub channels: usize,
    /// `[B, N, 3]`.
    pub means: Vec<f32>,
    /// `[B, N, 3]`.
    pub log_scales: Vec<f32>,
    /// `[B, N, 4]`, `w x y z`.
    pub rotations: Vec<f32>,
    /// `[B, N]`.
    pub opacity_logits: Vec<f32>,
    /// `[B, N, C]`.
    pub features: Vec<f32>,
}

impl HostGaussians {
    /// Gaussian `i` of batch element `b`.
    pub fn params(&self, b: usize, i: usize) -> Params {
        let g = b * self.count + i;
        let v3 = |v: &[f32]| [v[3 * g], v[3 * g + 1], v[3 * g + 2]];
        Params {
            mean: v3(&self.means),
            log_scale: v3(&self.log_scales),
            rotation: [
                self.rotations[4 * g],
                self.rotations[4 * g + 1],
                self.rotations[4 * g + 2],
                self.rotations[4 * g + 3],
            ],
            opacity_logit: self.opacity_logits[g],
        }
    }

    /// The `[N, C]` features of batch element `b`.
    pub fn features_of(&self, b: usize) -> &[f32] {
        let n = self.count * self.channels;
        &self.features[b * n..(b + 1) * n]
    }
}

/// What the reverse pass needs from the forward pass of one camera.
#[derive(Clone, Debug, Default)]
pub struct CameraTape {
    projected: Vec<Option<Projected>>,
    lists: TileLists,
    composited: Composited,
}

/// Renders `B` cameras. Returns the `[B, C + 2, H, W]` image (features, alpha, accumulated
/// depth `sum_i w_i z_i`) and, per camera, the tape for [`backward`].
///
/// The cameras render in parallel as well as the work within each (projection, tiles): one
/// camera's serial parts (sorting into tiles, gathering its tiles' pixels) and its last tiles
/// overlap the other cameras' work instead of leaving the other threads idle. Each camera's
/// result is the same as rendered alone.
///
/// All cameras must share one image size (checked by the caller).
pub fn forward(gaussians: &HostGaussians, cameras: &[Camera]) -> (Vec<f32>, Vec<CameraTape>) {
    let mut tapes: Vec<CameraTape> = cameras
        .par_iter()
        .enumerate()
        .map(|(b, camera)| {
            let view = View::new(camera);
            let projected: Vec<Option<Projected>> = (0..gaussians.count)
                .into_par_iter()
                .map(|i| project(&gaussians.params(b, i), &view))
                .collect();
            let lists = bin(&projected, &view);
            let composited = composite(
                &projected,
                gaussians.features_of(b),
                gaussians.channels,
                &lists,
                &view,
            );
            CameraTape {
                projected,
                lists,
                composited,
            }
        })
        .collect();
    // The tape keeps only what the reverse pass reads.
    let mut image = Vec::with_capacity(tapes.iter().map(|t| t.composited.image.len()).sum());
    for tape in &mut tapes {
        image.append(&mut tape.composited.image);
    }
    (image, tapes)
}

/// The reverse pass of [`forward`]: from `dL/d(image)` (`[B, C + 2, H, W]`) to the gradients
/// of every input, returned as a [`HostGaussians`] of gradients.
pub fn backward(
    gaussians: &HostGaussians,
    cameras: &[Camera],
    tapes: &[CameraTape],
    grad_image: &[f32],
) -> HostGaussians {
    let (n, c) = (gaussians.count, gaussians.channels);
    let mut grads = HostGaussians {
        batch: gaussians.batch,
        count: n,
        channels: c,
        means: vec![0.0; gaussians.means.len()],
        log_scales: vec![0.0; gaussians.log_scales.len()],
        rotations: vec![0.0; gaussians.rotations.len()],
        opacity_logits: vec![0.0; gaussians.opacity_logits.len()],
        features: vec![0.0; gaussians.features.len()],
    };
    let stride = GRAD_HEAD + c;
    // The cameras in parallel, as in `forward`; each writes its own Gaussians' gradients below.
    let per_camera: Vec<_> = cameras
        .par_iter()
        .zip(tapes)
        .enumerate()
        .map(|(b, (camera, tape))| {
            let view = View::new(camera);
            let per_image = (c + 2) * view.width * view.height;
            let projected_grads = composite_backward(
                &tape.projected,
                gaussians.features_of(b),
                c,
                &tape.lists,
                &view,
                &tape.composited,
                &grad_image[b * per_image..(b + 1) * per_image],
            );
            let params: Vec<_> = (0..n)
                .into_par_iter()
                .map(|i| {
                    let s = &projected_grads[i * stride..i * stride + GRAD_HEAD];
                    if tape.projected[i].is_none() {
                        return Default::default();
                    }
                    let g = ProjectedGrads {
                        uv: [s[0], s[1]],
                        depth: s[2],
                        conic: [s[3], s[4], s[5]],
                        opacity: s[6],
                    };
                    project_backward(&gaussians.params(b, i), &view, &g)
                })
                .collect();
            (projected_grads, params)
        })
        .collect();
    for (b, (projected_grads, params)) in per_camera.iter().enumerate() {
        for (i, p) in params.iter().enumerate() {
            let g = b * n + i;
            grads.means[3 * g..3 * g + 3].copy_from_slice(&p.mean);
            grads.log_scales[3 * g..3 * g + 3].copy_from_slice(&p.log_scale);
            grads.rotations[4 * g..4 * g + 4].copy_from_slice(&p.rotation);
            grads.opacity_logits[g] = p.opacity_logit;
            for k in 0..c {
                grads.features[g * c + k] = projected_grads[i * stride + GRAD_HEAD + k];
            }
        }
    }
    grads
}
