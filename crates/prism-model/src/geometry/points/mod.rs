//! The point branch (paper Sec. 3.2, Stage II, lower branch): a DPT-style head on stage-I taps
//! predicts a world point and a confidence per source pixel; the points, as small Gaussians
//! carrying learned features, are splatted into the target view to give `F_pts`.
//!
//! Per source pixel the head ([`DptHead`]) gives `3 + F` raw values `(x_t, x_c, x_o, x_f)`:
//!
//! - distance along the pixel's unit ray `t = softplus(x_t + softplus^-1(depth_prior))` (the
//!   subject is about `depth_prior` = 2 m away at initialisation; with `anchor_height`, the
//!   distance to the person's plane judged from the silhouette's height instead, see
//!   [`anchor`]) and the world point
//!   `X = o + t d` (`o` the source camera centre, `d` the ray direction of the Plücker map): the
//!   ground-truth point map lies on the pixel rays, so only the distance is free;
//! - confidence `C = 1 + exp(x_c)` (`x_c` clamped to 15 against overflow), for `L_pts`;
//! - opacity `sigmoid(x_o)` and `F` feature channels `x_f` of the point's Gaussian.
//!
//! Splatting: one isotropic Gaussian per point, scale `t / f` (the footprint of one source
//! pixel at that distance, `f` the source focal length in pixels), rendered into the target
//! camera with [`prism_render::splat::render`]. `F_pts = [features, alpha, alpha (z - depth_prior)]`
//! (`F + 2` channels: the composited features, the coverage and the depth offset of the
//! visible points in the target camera). With `colours`, each point also carries its source
//! pixel's colour, so `F_pts` shows stage III the source warped into the target view at the
//! branch's depths (`F + 5` channels).

pub(crate) mod anchor;
pub(crate) mod dpt;

use burn::config::Config;
use burn::module::Module;
use burn::tensor::Device;
use burn::tensor::Tensor;
use burn::tensor::activation::softplus;
use prism_render::splat::{Gaussians, render};

use crate::views::{Views, focals, points_along_rays};
use dpt::{DptHead, DptHeadConfig};

/// Largest raw confidence value before `exp` (`C <= 1 + e^15`).
const MAX_CONFIDENCE_LOGIT: f32 = 15.0;

/// Configuration of a [`PointBranch`].
#[derive(Config, Debug)]
pub(crate) struct PointBranchConfig {
    /// Token width `d`.
    pub width: usize,
    /// The stage-I blocks read (see [`dpt::dpt_taps`]).
    pub taps: Vec<usize>,
    /// Patch size `p`.
    pub patch_size: usize,
    /// Channels of the DPT head's maps.
    pub channels: usize,
    /// Learned feature channels `F` carried by each point.
    pub features: usize,
    /// Distance (metres) of the points at initialisation.
    pub depth_prior: f64,
    /// The person's height (metres) from which the starting distances are judged (see
    /// [`anchor`]); 0 for `depth_prior` everywhere.
    #[config(default = 0.0)]
    pub anchor_height: f64,
    /// Standard deviation of the normal initialisation of the linear layers.
    #[config(default = 0.02)]
    pub init_std: f64,
    /// The points also carry their source pixel's colour into `F_pts`.
    #[config(default = false)]
    pub colours: bool,
}

impl PointBranchConfig {
    /// Builds the branch.
    pub(crate) fn init(&self, device: &Device) -> PointBranch {
        PointBranch {
            dpt: DptHeadConfig::new(
                self.width,
                self.taps.len(),
                self.channels,
                3 + self.features,
                self.patch_size,
            )
            .with_init_std(self.init_std)
            .init(device),
            taps: self.taps.clone(),
            features: self.features,
            depth_prior: self.depth_prior as f32,
            anchor_height: self.anchor_height as f32,
            colours: self.colours,
        }
    }
}

/// The point branch (see the module docs).
#[derive(Module, Debug)]
pub struct PointBranch {
    /// The DPT-style head.
    pub dpt: DptHead,
    #[module(skip)]
    taps: Vec<usize>,
    #[module(skip)]
    features: usize,
    #[module(skip)]
    depth_prior: f32,
    #[module(skip)]
    anchor_height: f32,
    #[module(skip)]
    colours: bool,
}

/// What the point branch predicts for a batch of `B` pairs.
#[derive(Clone, Debug)]
pub struct PointOutput {
    /// World point per source pixel, `[B, 3, H_s, W_s]`.
    pub points: Tensor<4>,
    /// Distance of each point along its source pixel's unit ray (metres), `[B, 1, H_s, W_s]`
    /// (what a 3DGS head with `gs_depth = "points"` starts from).
    pub distance: Tensor<4>,
    /// Confidence `C = 1 + exp(x) > 1` per source pixel, `[B, 1, H_s, W_s]`.
    pub confidence: Tensor<4>,
    /// The points' Gaussians (features: the `F` learned channels, then the colour with
    /// `colours`).
    pub gaussians: Gaussians,
    /// `F_pts`, `[B, F + 2, H, W]` (`F + 5` with colours) in the target view (see the module
    /// docs).
    pub features: Tensor<4>,
}

/// `x` with `softplus(x) = y`.
pub(crate) fn inverse_softplus(y: f32) -> f32 {
    (y.exp() - 1.0).max(1e-12).ln()
}

/// Per-pixel `[B, C, H, W]` maps as `[B, H W, C]` rows (one per Gaussian).
pub(crate) fn pixel_rows(x: Tensor<4>) -> Tensor<3> {
    let [b, c, h, w] = x.dims();
    x.reshape([b, c, h * w]).swap_dims(1, 2)
}

impl PointBranch {
    /// The stage-I blocks this branch reads (global indices).
    pub fn taps(&self) -> &[usize] {
        &self.taps
    }

    /// Channels of `F_pts`: `F + 2`, `F + 5` with colours.
    pub fn feature_channels(&self) -> usize {
        self.features + 2 + if self.colours { 3 } else { 0 }
    }

    /// The branch on the source tokens of its taps (`[B, T_s, d]` each, in the order of
    /// [`PointBranch::taps`]), the source image `[B, 3, H_s, W_s]` (read with `colours`), the
    /// source rays `[B, 6, H_s, W_s]` and the views; `F_pts` at the target size
    /// `height x width`.
    #[allow(clippy::too_many_arguments)]
    pub fn forward(
        &self,
        taps: &[Tensor<3>],
        source_image: &Tensor<4>,
        source_rays: &Tensor<4>,
        views: &Views,
        grid: (usize, usize),
        height: usize,
        width: usize,
    ) -> PointOutput {
        let [b, _, hs, ws] = source_rays.dims();
        let raw = self.dpt.forward(taps, grid, hs, ws);
        let start = raw.clone().narrow(1, 0, 1);
        let start = if self.anchor_height > 0.0 {
            let directions = source_rays.clone().narrow(1, 0, 3);
            let anchor = anchor::silhouette_anchor(
                source_image,
                &directions,
                views.background,
                self.anchor_height,
                self.depth_prior,
            );
            // softplus^-1 of the anchor, per pixel.
            start + anchor.exp().sub_scalar(1.0).clamp_min(1e-12).log()
        } else {
            start.add_scalar(inverse_softplus(self.depth_prior))
        };
        let distance = softplus(start, 1.0);
        let confidence = raw
            .clone()
            .narrow(1, 1, 1)
            .clamp_max(MAX_CONFIDENCE_LOGIT)
            .exp()
            .add_scalar(1.0);
        let opacity = raw.clone().narrow(1, 2, 1);
        let mut features = raw.narrow(1, 3, self.features);
        if self.colours {
            features = Tensor::cat(vec![features, source_image.clone()], 1);
        }
        let sources = views.source_at(ws, hs);
        let points = points_along_rays(source_rays, distance.clone(), &sources);

        let device = points.device();
        let distance_map = distance.clone();
        let log_scale = (distance / focals(&sources, &device)).log();
        let n = hs * ws;
        let gaussians = Gaussians {
            means: pixel_rows(points.clone()),
            log_scales: pixel_rows(log_scale).repeat_dim(2, 3),
            rotations: Tensor::<3>::from_data(
                burn::tensor::TensorData::new(vec![1.0f32, 0.0, 0.0, 0.0], [1, 1, 4]),
                &device,
            )
            .expand([b, n, 4]),
            opacity_logits: pixel_rows(opacity),
            features: pixel_rows(features),
        };
        let targets = views.target_at(width, height);
        let rendered = render(&gaussians, &targets).expect("points and target cameras fit");
        let offset = rendered.alpha.clone() * rendered.depth.clone().sub_scalar(self.depth_prior);
        let features = Tensor::cat(vec![rendered.features, rendered.alpha, offset], 1);
        PointOutput {
            points,
            distance: distance_map,
            confidence,
            gaussians,
            features,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::{ndarray, values, views};
    use burn::tensor::Distribution;
    use prism_core::rays::plucker_rays;

    #[test]
    fn points_lie_on_their_rays_and_the_head_trains() {
        let device = ndarray().autodiff();
        device.seed(7);
        let branch = PointBranchConfig::new(16, vec![0, 1], 8, 8, 4, 2.0).init(&device);
        let views = views(2, 16, 16);
        let rays = plucker_rays(&views.source, &device);
        let taps: Vec<Tensor<3>> = (0..2)
            .map(|_| Tensor::random([2, 4, 16], Distribution::Normal(0.0, 1.0), &device))
            .collect();
        let image = Tensor::<4>::random([2, 3, 16, 16], Distribution::Uniform(0.0, 1.0), &device);
        let out = branch.forward(&taps, &image, &rays, &views, (2, 2), 16, 16);
        assert_eq!(out.points.dims(), [2, 3, 16, 16]);
        assert_eq!(out.confidence.dims(), [2, 1, 16, 16]);
        assert_eq!(out.features.dims(), [2, 4 + 2, 16, 16]);
        let points = values(&out.points);
        let camera = views.source[0];
        let plane = 256;
        for i in 0..plane {
            let p = glam::Vec3::new(points[i], points[plane + i], points[2 * plane + i]);
            let (u, v, _) = camera.project(p);
            assert!((u - ((i % 16) as f32 + 0.5)).abs() < 1e-2);
            assert!((v - ((i / 16) as f32 + 0.5)).abs() < 1e-2);
            assert!(((p - camera.center()).length() - 2.0).abs() < 0.4);
        }
        // The splatted points cover part of the target views.
        let coverage = values(&out.features.clone().narrow(1, 4, 1));
        assert!(coverage.iter().any(|&a| a > 0.5));
        // A loss on the points and on F_pts reaches the DPT head.
        let loss = out.points.mean() + out.confidence.mean() + out.features.powi_scalar(2).mean();
        let grads = loss.backward();
        let refine = branch.dpt.refine[0].weight.val().grad(&grads).unwrap();
        assert!(values(&refine).iter().any(|&v| v != 0.0), "refine");
        for (name, g) in [
            (
                "reassemble",
                branch.dpt.reassemble[0].weight.val().grad(&grads),
            ),
            ("head_out", branch.dpt.head_out.weight.val().grad(&grads)),
        ] {
            let g = values(&g.unwrap_or_else(|| panic!("{name}: no gradient")));
            assert!(g.iter().any(|&v| v != 0.0), "{name}");
        }
    }
}
