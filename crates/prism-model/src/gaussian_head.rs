//! The 3DGS head (paper Sec. 3.2, Stage III): one 3D Gaussian per source pixel from the source
//! tokens of `T_out`, rendered in the target camera over the background -> `I_gs`.
//!
//! Like the NVS decoder, the head is pixel-aligned: `LN`, then `Linear(d, 12 p^2)` without bias
//! and an unpatchify give 12 raw values per source pixel, activated as
//!
//! - distance along the pixel's unit ray `t = softplus(x_t + softplus^-1(depth_prior))` (about
//!   `depth_prior` = 2 m at initialisation, always positive), centre `mu = o + t d`;
//! - log-scales `log s_i = log(t / f) + log(0.1) + log(100) sigmoid(x_i)`: between 0.1 and 10
//!   times the footprint `t / f` of one source pixel at that distance (`f` the source focal
//!   length in pixels), one pixel at initialisation;
//! - rotation `q = (x_q + (1, 0, 0, 0)) / |x_q + (1, 0, 0, 0)|` (`w x y z`), the identity at
//!   initialisation;
//! - opacity `sigmoid(x_o)` (the logit is what the renderer and the PLY format store);
//! - colour `sigmoid(x_c)`, 3 channels in [0, 1].
//!
//! [`GaussianOutput::cloud`] turns the Gaussians of one pair into a standard 3DGS PLY
//! ([`GaussianCloud`], degree-0 colours).

use std::path::Path;

use burn::config::Config;
use burn::module::Module;
use burn::nn::{Initializer, LayerNorm, LayerNormConfig, Linear, LinearConfig};
use burn::tensor::activation::{sigmoid, softplus};
use burn::tensor::{Device, Tensor, TensorData};
use prism_render::splat::{GaussianCloud, Gaussians, background, render};

use crate::error::ModelError;
use crate::patch::unpatchify;
use crate::point_branch::{inverse_softplus, pixel_rows};
use crate::views::{Views, focals, points_along_rays};

/// Raw values per Gaussian: distance 1, log-scale 3, rotation 4, opacity 1, colour 3.
pub const GAUSSIAN_CHANNELS: usize = 12;
/// Smallest scale, in source-pixel footprints.
pub const MIN_SCALE_PIXELS: f32 = 0.1;
/// Largest scale, in source-pixel footprints.
pub const MAX_SCALE_PIXELS: f32 = 10.0;

/// Configuration of a [`GaussianHead`].
#[derive(Config, Debug)]
pub struct GaussianHeadConfig {
    /// Token width `d`.
    pub width: usize,
    /// Patch size `p`.
    pub patch_size: usize,
    /// Distance (metres) of the Gaussians at initialisation.
    pub depth_prior: f64,
    /// Standard deviation of the projection's normal initialisation.
    #[config(default = 0.02)]
    pub init_std: f64,
    /// `eps` of the LayerNorm.
    #[config(default = 1e-5)]
    pub norm_eps: f64,
}

impl GaussianHeadConfig {
    /// Builds the head.
    pub fn init(&self, device: &Device) -> GaussianHead {
        GaussianHead {
            norm: LayerNormConfig::new(self.width)
                .with_bias(false)
                .with_epsilon(self.norm_eps)
                .init(device),
            linear: LinearConfig::new(
                self.width,
                GAUSSIAN_CHANNELS * self.patch_size * self.patch_size,
            )
            .with_bias(false)
            .with_initializer(Initializer::Normal {
                mean: 0.0,
                std: self.init_std,
            })
            .init(device),
            patch_size: self.patch_size,
            depth_prior: self.depth_prior as f32,
        }
    }
}

/// The 3DGS head (see the module docs).
#[derive(Module, Debug)]
pub struct GaussianHead {
    /// LayerNorm (no bias) on the source tokens.
    pub norm: LayerNorm,
    /// `Linear(d, 12 p^2)`, no bias.
    pub linear: Linear,
    patch_size: usize,
    depth_prior: f32,
}

/// What the 3DGS head predicts for a batch of `B` pairs.
#[derive(Clone, Debug)]
pub struct GaussianOutput {
    /// One Gaussian per source pixel, `N = H_s W_s` per pair, row-major; features are RGB.
    pub gaussians: Gaussians,
    /// `I_gs`: the Gaussians rendered in the target camera over the background, `[B, 3, H, W]`.
    pub image: Tensor<4>,
    /// The rendered coverage `[B, 1, H, W]`.
    pub alpha: Tensor<4>,
}

impl GaussianOutput {
    /// The Gaussians of pair `b` as a standard 3DGS point cloud (degree-0 colours).
    ///
    /// # Errors
    /// [`ModelError::Render`] when `b` is out of range.
    pub fn cloud(&self, b: usize) -> Result<GaussianCloud, ModelError> {
        Ok(GaussianCloud::from_gaussians(&self.gaussians, b)?)
    }

    /// Writes the Gaussians of pair `b` as a standard 3DGS PLY file (atomically).
    ///
    /// # Errors
    /// [`ModelError::Render`] when `b` is out of range or the file cannot be written.
    pub fn save_ply(&self, b: usize, path: impl AsRef<Path>) -> Result<(), ModelError> {
        Ok(self.cloud(b)?.write(path)?)
    }
}

impl GaussianHead {
    /// The Gaussians of the source pixels from the source tokens of `T_out` `[B, T_s, d]` and
    /// the source rays `[B, 6, H_s, W_s]`, rendered in the target views at `height x width`.
    pub fn forward(
        &self,
        source_tokens: Tensor<3>,
        source_rays: &Tensor<4>,
        views: &Views,
        height: usize,
        width: usize,
    ) -> GaussianOutput {
        let [_, _, hs, ws] = source_rays.dims();
        let raw = unpatchify(
            self.linear.forward(self.norm.forward(source_tokens)),
            GAUSSIAN_CHANNELS,
            hs,
            ws,
            self.patch_size,
        );
        let device = raw.device();
        let sources = views.source_at(ws, hs);
        let distance = softplus(
            raw.clone()
                .narrow(1, 0, 1)
                .add_scalar(inverse_softplus(self.depth_prior)),
            1.0,
        );
        let means = points_along_rays(source_rays, distance.clone(), &sources);
        let footprint = (distance / focals(&sources, &device)).log();
        let (lo, hi) = (MIN_SCALE_PIXELS.ln(), MAX_SCALE_PIXELS.ln());
        let log_scales = sigmoid(raw.clone().narrow(1, 1, 3))
            .mul_scalar(hi - lo)
            .add_scalar(lo)
            + footprint;
        let identity = Tensor::<4>::from_data(
            TensorData::new(vec![1.0f32, 0.0, 0.0, 0.0], [1, 4, 1, 1]),
            &device,
        );
        let q = raw.clone().narrow(1, 4, 4) + identity;
        let rotations = q.clone() / (q.clone() * q).sum_dim(1).add_scalar(1e-12).sqrt();
        let opacity_logits = raw.clone().narrow(1, 8, 1);
        let colours = sigmoid(raw.narrow(1, 9, 3));
        let gaussians = Gaussians {
            means: pixel_rows(means),
            log_scales: pixel_rows(log_scales),
            rotations: pixel_rows(rotations),
            opacity_logits: pixel_rows(opacity_logits),
            features: pixel_rows(colours),
        };
        let targets = views.target_at(width, height);
        let rendered = render(&gaussians, &targets).expect("Gaussians and target cameras fit");
        let image = rendered.over(background(&views.background, &device));
        GaussianOutput {
            gaussians,
            image,
            alpha: rendered.alpha,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::{ndarray, values, views};
    use burn::tensor::Distribution;
    use prism_data::rays::plucker_rays;

    fn head(device: &Device) -> GaussianHead {
        GaussianHeadConfig::new(16, 8, 2.0).init(device)
    }

    #[test]
    fn gaussians_sit_on_the_source_rays_and_render_over_the_background() {
        let device = ndarray();
        device.seed(3);
        let head = head(&device);
        let mut views = views(2, 16, 24);
        views.background = [0.2, 0.4, 0.9];
        // Pair 1 looks away from the subject: nothing is drawn, I_gs is the background.
        let centre = views.target[1].center();
        views.target[1] = prism_data::Camera::look_at(
            centre,
            centre * 2.0,
            glam::Vec3::Y,
            views.target[1].intrinsics,
        );
        let rays = plucker_rays(&views.source, &device);
        let tokens = Tensor::<3>::random([2, 6, 16], Distribution::Normal(0.0, 1.0), &device);
        let out = head.forward(tokens, &rays, &views, 16, 24);
        assert_eq!(out.image.dims(), [2, 3, 16, 24]);
        assert_eq!(out.alpha.dims(), [2, 1, 16, 24]);
        assert_eq!(out.gaussians.means.dims(), [2, 16 * 24, 3]);
        assert_eq!(out.gaussians.rotations.dims(), [2, 16 * 24, 4]);
        assert_eq!(out.gaussians.features.dims(), [2, 16 * 24, 3]);
        // Every centre projects onto its own source pixel centre, about 2 m away.
        let means = values(&out.gaussians.means);
        let camera = views.source[0];
        for (i, m) in means[..16 * 24 * 3].chunks_exact(3).enumerate() {
            let p = glam::Vec3::from_slice(m);
            let (u, v, _) = camera.project(p);
            let (x, y) = ((i % 24) as f32 + 0.5, (i / 24) as f32 + 0.5);
            assert!(
                (u - x).abs() < 1e-2 && (v - y).abs() < 1e-2,
                "{i}: ({u}, {v})"
            );
            let d = (p - camera.center()).length();
            assert!((d - 2.0).abs() < 0.4, "distance {d}");
        }
        // Unit quaternions, colours in (0, 1), scales within the bounds around one pixel.
        for q in values(&out.gaussians.rotations).chunks_exact(4) {
            let n: f32 = q.iter().map(|v| v * v).sum();
            assert!((n - 1.0).abs() < 1e-4);
        }
        assert!(
            values(&out.gaussians.features)
                .iter()
                .all(|&c| c > 0.0 && c < 1.0)
        );
        let footprint = (2.0f32 / 16.0).ln();
        for s in values(&out.gaussians.log_scales) {
            assert!(
                s > footprint + MIN_SCALE_PIXELS.ln() - 0.2
                    && s < footprint + MAX_SCALE_PIXELS.ln() + 0.2
            );
        }
        let image = values(&out.image);
        let plane = 16 * 24;
        let alpha = values(&out.alpha);
        assert!(
            alpha[..plane].iter().any(|&a| a > 0.5),
            "pair 0 sees the Gaussians"
        );
        assert!(alpha[plane..].iter().all(|&a| a == 0.0));
        for c in 0..3 {
            for &v in &image[(3 + c) * plane..(4 + c) * plane] {
                assert_eq!(v, views.background[c]);
            }
        }
    }

    #[test]
    fn l_gs_trains_the_head() {
        let device = ndarray().autodiff();
        device.seed(4);
        let head = head(&device);
        let views = views(1, 16, 16);
        let rays = plucker_rays(&views.source, &device);
        let tokens = Tensor::<3>::random([1, 4, 16], Distribution::Normal(0.0, 1.0), &device);
        let target = Tensor::<4>::random([1, 3, 16, 16], Distribution::Uniform(0.0, 1.0), &device);
        let out = head.forward(tokens, &rays, &views, 16, 16);
        let grads = (out.image - target).powi_scalar(2).mean().backward();
        let g = values(&head.linear.weight.val().grad(&grads).unwrap());
        assert!(g.iter().all(|v| v.is_finite()) && g.iter().any(|&v| v != 0.0));
        let g = values(&head.norm.gamma.val().grad(&grads).unwrap());
        assert!(g.iter().any(|&v| v != 0.0));
    }

    #[test]
    fn exported_ply_reads_back() {
        let device = ndarray();
        device.seed(5);
        let head = head(&device);
        let views = views(2, 8, 8);
        let rays = plucker_rays(&views.source, &device);
        let tokens = Tensor::<3>::random([2, 1, 16], Distribution::Normal(0.0, 1.0), &device);
        let out = head.forward(tokens, &rays, &views, 8, 8);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("pair1.ply");
        out.save_ply(1, &path).unwrap();
        let cloud = GaussianCloud::read(&path).unwrap();
        assert_eq!(cloud.len(), 64);
        let means = values(&out.gaussians.means.clone().narrow(0, 1, 1));
        for (a, b) in cloud.means.concat().iter().zip(&means) {
            assert!((a - b).abs() < 1e-6);
        }
        let colours = values(&out.gaussians.features.clone().narrow(0, 1, 1));
        for (a, b) in cloud.colours().concat().iter().zip(&colours) {
            assert!((a - b).abs() < 1e-5);
        }
        assert!(out.save_ply(2, dir.path().join("none.ply")).is_err());
    }
}
