//! The 3DGS head (paper Sec. 3.2, Stage III): one 3D Gaussian per source pixel from the source
//! tokens of `T_out`, rendered in the target camera over the background -> `I_gs`.
//!
//! Like the NVS decoder, the head is pixel-aligned: `LN`, then `Linear(d, 12 p^2)` without bias
//! and an unpatchify give 12 raw values per source pixel (with `head_upsample = f`,
//! `Linear(d, 12 f^2)` and a bilinear upsampling instead: smooth values, see
//! [`crate::heads::head_map`]), activated as
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
//! Options make the head a geometric prediction from the first step, for training from
//! scratch (pixel-aligned Gaussians that carry the source pixels, as GPS-Gaussian does):
//!
//! - `gs_colour = "source"`: the colour is the source pixel's, corrected by the head,
//!   `c = clamp(I_s + x_c, 0, 1)`, instead of `sigmoid(x_c)`; `gs_colour = "pixel"`: the
//!   source pixel's colour as it is, `c = I_s`; `gs_colour = "flow"`: the
//!   Gaussians splat their source pixel's coordinates instead of a colour, and `I_gs` samples
//!   the source image there (appearance flow from forward splatting, see [`GsColour::Flow`]);
//! - `gs_depth = "points"`: the distance is the point branch's (which `L_pts` supervises),
//!   corrected by the head, `t = t_pts + x_t`, instead of the head's own;
//! - `gs_keying = true`: the opacity starts from a key of the source on the background colour
//!   (every image the model sees is composited on it, photos by `prism infer` too),
//!   `o = sigmoid(logit(k) + x_o)` with `k = clamp(max_c |I_s - bg| / KEY_WIDTH, 0.01, 0.99)`:
//!   background pixels start transparent, the person opaque, and the head learns the
//!   exceptions (a white shirt on a white background) from `L_opacity` and the image losses;
//! - `gs_rim_depth = L`: the Gaussians of the source silhouette's rim start stretched back along
//!   their rays, spanning `L` metres behind their surface point, to cover the sides a turned
//!   view shows (see [`crate::heads::rim`]); every Gaussian's rotation then starts from the one
//!   that turns its third axis onto its ray instead of the identity.
//!
//! With any of them the projection starts at zero, so that at initialisation the Gaussians are
//! the source pixels at the point branch's depth (or `depth_prior`). `gs_scale` sets their
//! initial size in source-pixel footprints: the renderer adds 0.3 px^2 to every projected
//! covariance, so 1 footprint is already a blur of about 1.1 px, right for features, too wide
//! for colours.
//!
//! [`GaussianOutput::cloud`] turns the Gaussians of one pair into a standard 3DGS PLY
//! ([`GaussianCloud`], degree-0 colours).

use std::path::Path;

use burn::config::Config;
use burn::module::Module;
use burn::nn::{Initializer, LayerNorm, LayerNormConfig, Linear, LinearConfig};
use burn::tensor::activation::{sigmoid, softplus};
use burn::tensor::ops::{GridSampleOptions, GridSamplePaddingMode};
use burn::tensor::{Device, Tensor, TensorData};
use prism_core::axes::permute;
use prism_kernels::linear;
use prism_render::splat::{GaussianCloud, Gaussians, background, render};
use serde::{Deserialize, Serialize};

use crate::error::ModelError;
use crate::geometry::points::{inverse_softplus, pixel_rows};
use crate::heads::rim::{ray_rotations, scale_logits_for, silhouette_rim};
use crate::heads::{head_map, values_per_channel};
use crate::views::{Views, focals, points_along_rays};

/// Raw values per Gaussian: distance 1, log-scale 3, rotation 4, opacity 1, colour 3.
pub(crate) const GAUSSIAN_CHANNELS: usize = 12;
/// Smallest scale, in source-pixel footprints.
pub(crate) const MIN_SCALE_PIXELS: f32 = 0.1;
/// Largest scale, in source-pixel footprints.
pub(crate) const MAX_SCALE_PIXELS: f32 = 10.0;
/// Colour distance from the background (largest channel difference, in [0, 1]) at which the
/// key of `gs_keying` is fully opaque.
pub(crate) const KEY_WIDTH: f32 = 0.1;
/// The key's range: opacities at initialisation stay within `[KEY_FLOOR, 1 - KEY_FLOOR]`, so
/// that the learned correction can still move them.
pub(crate) const KEY_FLOOR: f32 = 0.01;

/// Configuration of a [`GaussianHead`].
#[derive(Config, Debug)]
pub(crate) struct GaussianHeadConfig {
    /// Token width `d`.
    pub width: usize,
    /// Patch size `p`.
    pub patch_size: usize,
    /// Distance (metres) of the Gaussians at initialisation.
    pub depth_prior: f64,
    /// Where the Gaussians' colours come from.
    #[config(default = "GsColour::Regressed")]
    pub colour: GsColour,
    /// Where the Gaussians' distances come from.
    #[config(default = "GsDepth::Head")]
    pub depth: GsDepth,
    /// Scale of the Gaussians at initialisation, in source-pixel footprints (between
    /// [`MIN_SCALE_PIXELS`] and [`MAX_SCALE_PIXELS`], exclusive).
    #[config(default = 1.0)]
    pub scale: f64,
    /// Start the opacities from the source's key on the background colour.
    #[config(default = false)]
    pub keying: bool,
    /// How far (metres) the source silhouette's rim Gaussians reach back along their rays at
    /// initialisation (`heads/rim.rs`); 0 for none.
    #[config(default = 0.0)]
    pub rim_depth: f64,
    /// The raw values' resolution: 0 for a free value per pixel (the paper's unpatchify),
    /// `f` for `f x f` values per token upsampled bilinearly ([`head_map`]).
    #[config(default = 0)]
    pub upsample: usize,
    /// Standard deviation of the projection's normal initialisation.
    #[config(default = 0.02)]
    pub init_std: f64,
    /// `eps` of the LayerNorm.
    #[config(default = 1e-5)]
    pub norm_eps: f64,
}

impl GaussianHeadConfig {
    /// Builds the head.
    pub(crate) fn init(&self, device: &Device) -> GaussianHead {
        GaussianHead {
            norm: LayerNormConfig::new(self.width)
                .with_bias(false)
                .with_epsilon(self.norm_eps)
                .init(device),
            linear: LinearConfig::new(
                self.width,
                GAUSSIAN_CHANNELS * values_per_channel(self.patch_size, self.upsample),
            )
            .with_bias(false)
            .with_initializer(if self.is_geometric() {
                Initializer::Zeros
            } else {
                Initializer::Normal {
                    mean: 0.0,
                    std: self.init_std,
                }
            })
            .init(device),
            patch_size: self.patch_size,
            upsample: self.upsample,
            depth_prior: self.depth_prior as f32,
            colour: self.colour,
            depth: self.depth,
            scale_logit: scale_logit(self.scale as f32),
            keying: self.keying,
            rim_depth: self.rim_depth as f32,
        }
    }

    /// Whether the head starts from the source pixels (`colour` or `depth` taken from them):
    /// then its projection starts at zero.
    pub(crate) fn is_geometric(&self) -> bool {
        self.colour != GsColour::Regressed
            || self.depth == GsDepth::Points
            || self.keying
            || self.rim_depth > 0.0
    }
}

/// Where the 3DGS head's Gaussians take their colour (`gs_colour` in `[model]`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GsColour {
    /// `sigmoid(x_c)`, regressed by the head (the paper).
    #[default]
    Regressed,
    /// The source pixel's colour plus the head's correction, `clamp(I_s + x_c, 0, 1)`.
    Source,
    /// The source pixel's own colour, uncorrected (`I_s`): the head learns where the
    /// Gaussians go, not what colour they are.
    Pixel,
    /// Appearance flow: the Gaussians carry their source pixel's coordinates; the rendered
    /// coordinates (normalised by the coverage) sample the source image bilinearly, and
    /// `I_gs = alpha * I_s(uv) + (1 - alpha) * bg`. Splatting blurs the flow, not the colours,
    /// so `I_gs` keeps the source's sharpness. The Gaussians (and PLY) carry the source colours.
    Flow,
}

/// Where the 3DGS head's Gaussians take their distance along the source ray (`gs_depth`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GsDepth {
    /// `softplus(x_t + softplus^-1(depth_prior))`, the head's own (the paper).
    #[default]
    Head,
    /// The point branch's distance plus the head's correction, `t_pts + x_t` (needs the point
    /// branch).
    Points,
}

/// `logit(k)` of the key `k = clamp(max_c |I_s - bg| / KEY_WIDTH, KEY_FLOOR, 1 - KEY_FLOOR)` of
/// a source image `[B, 3, H, W]` on the background colour: `[B, 1, H, W]`.
pub(crate) fn key_logits(source_image: &Tensor<4>, background: &[f32]) -> Tensor<4> {
    let key = background_distance(source_image, background)
        .div_scalar(KEY_WIDTH)
        .clamp(KEY_FLOOR, 1.0 - KEY_FLOOR);
    (key.clone() / key.neg().add_scalar(1.0)).log()
}

/// Colour distance from the background (largest channel difference, in `[0, 1]`) above which a
/// source pixel counts as the person's (the silhouette anchor's and the rim's).
const PERSON_DISTANCE: f32 = 0.05;

/// The person's pixels of a source image `[B, 3, H, W]`, 1 where its colour is away from the
/// background's (more than [`PERSON_DISTANCE`]) and 0 elsewhere: `[B, 1, H, W]`.
pub(crate) fn person_mask(source_image: &Tensor<4>, background: &[f32]) -> Tensor<4> {
    background_distance(source_image, background)
        .greater_elem(PERSON_DISTANCE)
        .float()
}

/// Each pixel's colour distance from the background, `max_c |I_s - bg|` in `[0, 1]`, of a
/// source image `[B, 3, H, W]`: `[B, 1, H, W]` (every input is composited on the background,
/// so this tells the person from the background).
pub(crate) fn background_distance(source_image: &Tensor<4>, background: &[f32]) -> Tensor<4> {
    let device = source_image.device();
    let bg = Tensor::<4>::from_data(TensorData::new(background.to_vec(), [1, 3, 1, 1]), &device);
    (source_image.clone() - bg).abs().max_dim(1)
}

/// The raw offset `x` with `sigmoid(x)` placing the log-scale at `scale` footprints within
/// `[MIN_SCALE_PIXELS, MAX_SCALE_PIXELS]` (0 for one footprint).
fn scale_logit(scale: f32) -> f32 {
    let (lo, hi) = (MIN_SCALE_PIXELS.ln(), MAX_SCALE_PIXELS.ln());
    let u = ((scale.ln() - lo) / (hi - lo)).clamp(1e-6, 1.0 - 1e-6);
    (u / (1.0 - u)).ln()
}

/// The 3DGS head (see the module docs).
#[derive(Module, Debug)]
pub struct GaussianHead {
    /// LayerNorm (no bias) on the source tokens.
    pub norm: LayerNorm,
    /// `Linear(d, 12 p^2)`, no bias.
    pub linear: Linear,
    patch_size: usize,
    #[module(skip)]
    upsample: usize,
    depth_prior: f32,
    #[module(skip)]
    colour: GsColour,
    #[module(skip)]
    depth: GsDepth,
    #[module(skip)]
    scale_logit: f32,
    #[module(skip)]
    keying: bool,
    #[module(skip)]
    rim_depth: f32,
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
    /// Each Gaussian's point on its pixel's surface, `[B, N, 3]`: its centre, except for the
    /// rim Gaussians of `gs_rim_depth`, which sit behind theirs by design. What losses on the
    /// depth (`L_centres`, `L_spread`) and the depth's diagnostics measure.
    pub surface: Tensor<3>,
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

/// What the 3DGS head reads per source pixel besides the tokens.
#[derive(Clone, Debug)]
pub struct SourcePixels<'a> {
    /// The source image `[B, 3, H_s, W_s]` in [0, 1] (colours with `gs_colour = "source"` or
    /// `"flow"`, the key with `gs_keying`).
    pub image: &'a Tensor<4>,
    /// The source rays `[B, 6, H_s, W_s]`.
    pub rays: &'a Tensor<4>,
    /// The point branch's distances `[B, 1, H_s, W_s]` (read with `gs_depth = "points"`).
    pub distance: Option<Tensor<4>>,
}

impl GaussianHead {
    /// Where the colours come from.
    pub fn colour(&self) -> GsColour {
        self.colour
    }

    /// Where the distances come from.
    pub fn depth(&self) -> GsDepth {
        self.depth
    }

    /// The Gaussians of the source pixels from the source tokens of `T_out` `[B, T_s, d]` and
    /// what the head reads per source pixel (`source`), rendered in the target views at
    /// `height x width`.
    ///
    /// # Panics
    /// With `gs_depth = "points"` and no point distances.
    pub fn forward(
        &self,
        source_tokens: Tensor<3>,
        source: SourcePixels<'_>,
        views: &Views,
        height: usize,
        width: usize,
    ) -> GaussianOutput {
        let SourcePixels {
            image: source_image,
            rays: source_rays,
            distance: point_distance,
        } = source;
        let [_, _, hs, ws] = source_rays.dims();
        let raw = head_map(
            linear(&self.linear, self.norm.forward(source_tokens)),
            GAUSSIAN_CHANNELS,
            hs,
            ws,
            self.patch_size,
            self.upsample,
        );
        let device = raw.device();
        let sources = views.source_at(ws, hs);
        let x_t = raw.clone().narrow(1, 0, 1);
        let distance = match self.depth {
            GsDepth::Head => softplus(x_t.add_scalar(inverse_softplus(self.depth_prior)), 1.0),
            GsDepth::Points => {
                let base = point_distance.expect("gs_depth = \"points\" needs the point branch");
                // Never behind the camera, whatever the correction.
                (base + x_t).clamp_min(1e-3)
            }
        };
        let (lo, hi) = (MIN_SCALE_PIXELS.ln(), MAX_SCALE_PIXELS.ln());
        let mut scale_logits = raw.clone().narrow(1, 1, 3).add_scalar(self.scale_logit);
        let (distance, rotation_base, surface) = if self.rim_depth > 0.0 {
            // Rim Gaussians span their surface point and `rim_depth` behind it along the ray.
            let surface = points_along_rays(source_rays, distance.clone(), &sources);
            let rim = silhouette_rim(source_image, &views.background);
            let distance = distance + rim.clone().mul_scalar(self.rim_depth / 2.0);
            let footprint = (distance.clone().detach() / focals(&sources, &device)).log();
            let along = scale_logits_for(self.rim_depth / 3.0, footprint, lo, hi);
            let [b, _, h, w] = rim.dims();
            let offset = Tensor::cat(
                vec![
                    Tensor::zeros([b, 2, h, w], &device),
                    rim * along.sub_scalar(self.scale_logit),
                ],
                1,
            );
            scale_logits = scale_logits + offset;
            let directions = source_rays.clone().narrow(1, 0, 3);
            (
                distance,
                ray_rotations(&directions),
                Some(pixel_rows(surface)),
            )
        } else {
            let identity = Tensor::<4>::from_data(
                TensorData::new(vec![1.0f32, 0.0, 0.0, 0.0], [1, 4, 1, 1]),
                &device,
            );
            (distance, identity, None)
        };
        // Sizes in footprints at the Gaussian's own distance: from the source camera a rim
        // Gaussian covers its pixel as the others do.
        let footprint = (distance.clone() / focals(&sources, &device)).log();
        let means = pixel_rows(points_along_rays(source_rays, distance, &sources));
        // Without rim Gaussians the surface points are the centres, the same tensor.
        let surface = surface.unwrap_or_else(|| means.clone());
        let log_scales = sigmoid(scale_logits).mul_scalar(hi - lo).add_scalar(lo) + footprint;
        let q = raw.clone().narrow(1, 4, 4) + rotation_base;
        let rotations = q.clone() / (q.clone() * q).sum_dim(1).add_scalar(1e-12).sqrt();
        let mut opacity_logits = raw.clone().narrow(1, 8, 1);
        if self.keying {
            opacity_logits = opacity_logits + key_logits(source_image, &views.background);
        }
        let x_c = raw.narrow(1, 9, 3);
        let colours = match self.colour {
            GsColour::Regressed => sigmoid(x_c),
            GsColour::Source => (source_image.clone() + x_c).clamp(0.0, 1.0),
            GsColour::Pixel => source_image.clone(),
            // The flow carries the colours; the Gaussians keep the source's for the PLY.
            GsColour::Flow => source_image.clone(),
        };
        let gaussians = Gaussians {
            means,
            log_scales: pixel_rows(log_scales),
            rotations: pixel_rows(rotations),
            opacity_logits: pixel_rows(opacity_logits),
            features: pixel_rows(colours),
        };
        let targets = views.target_at(width, height);
        let bg = background(&views.background, &device);
        let (image, alpha) = if self.colour == GsColour::Flow {
            let coordinates = Gaussians {
                features: pixel_rows(source_coordinates(source_image)),
                ..gaussians.clone()
            };
            let rendered = render(&coordinates, &targets).expect("Gaussians and cameras fit");
            let alpha = rendered.alpha.clone();
            let grid = permute(
                rendered.features / alpha.clone().clamp_min(FLOW_ALPHA_EPS),
                [0, 2, 3, 1],
            );
            let sampled = source_image.clone().grid_sample_2d(
                grid,
                GridSampleOptions::default().with_padding_mode(GridSamplePaddingMode::Border),
            );
            let [c] = bg.dims();
            let bg = bg.reshape([1, c, 1, 1]);
            let image = sampled * alpha.clone() + (alpha.clone().neg().add_scalar(1.0)) * bg;
            (image, alpha)
        } else {
            let rendered = render(&gaussians, &targets).expect("Gaussians and cameras fit");
            (rendered.over(bg), rendered.alpha)
        };
        GaussianOutput {
            gaussians,
            image,
            alpha,
            surface,
        }
    }
}

/// Coverage under which a target pixel's splatted source coordinates are not normalised by
/// it (they are near zero there, and so is their weight in `I_gs`).
const FLOW_ALPHA_EPS: f32 = 1e-4;

/// Each source pixel's own centre in the normalised coordinates of `grid_sample`
/// (`align_corners = false`: `2 (x + 1/2) / W - 1`), `[B, 2, H, W]` (x then y), on the device
/// and with the batch size of `like` `[B, _, H, W]`.
fn source_coordinates(like: &Tensor<4>) -> Tensor<4> {
    let [b, _, h, w] = like.dims();
    let mut data = Vec::with_capacity(2 * h * w);
    data.extend((0..h * w).map(|i| (2 * (i % w) + 1) as f32 / w as f32 - 1.0));
    data.extend((0..h * w).map(|i| (2 * (i / w) + 1) as f32 / h as f32 - 1.0));
    Tensor::<4>::from_data(TensorData::new(data, [1, 2, h, w]), &like.device()).expand([b, 2, h, w])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::{ndarray, values, views};
    use burn::tensor::Distribution;
    use prism_core::rays::plucker_rays;

    /// The source pixels without point distances.
    fn pixels<'a>(image: &'a Tensor<4>, rays: &'a Tensor<4>) -> SourcePixels<'a> {
        SourcePixels {
            image,
            rays,
            distance: None,
        }
    }

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
        views.target[1] = prism_core::Camera::look_at(
            centre,
            centre * 2.0,
            glam::Vec3::Y,
            views.target[1].intrinsics,
        );
        let rays = plucker_rays(&views.source, &device);
        let tokens = Tensor::<3>::random([2, 6, 16], Distribution::Normal(0.0, 1.0), &device);
        let image = Tensor::<4>::zeros([2, 3, 16, 24], &device);
        let out = head.forward(tokens, pixels(&image, &rays), &views, 16, 24);
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
        let image = Tensor::<4>::zeros([1, 3, 16, 16], &device);
        let out = head.forward(tokens, pixels(&image, &rays), &views, 16, 16);
        let grads = (out.image - target).powi_scalar(2).mean().backward();
        let g = values(&head.linear.weight.val().grad(&grads).unwrap());
        assert!(g.iter().all(|v| v.is_finite()) && g.iter().any(|&v| v != 0.0));
        let g = values(&head.norm.gamma.val().grad(&grads).unwrap());
        assert!(g.iter().any(|&v| v != 0.0));
    }

    #[test]
    fn pixel_colours_stay_the_source_pixels_whatever_the_head_predicts() {
        let device = ndarray();
        device.seed(8);
        let mut head = GaussianHeadConfig::new(16, 8, 2.0)
            .with_colour(GsColour::Pixel)
            .with_upsample(2)
            .init(&device);
        // A trained head: non-zero weights everywhere, colour channels included.
        head.linear.weight = head.linear.weight.clone().map(|w| {
            w.clone().add(Tensor::random(
                w.shape(),
                Distribution::Normal(0.0, 0.5),
                &device,
            ))
        });
        let views = views(1, 16, 16);
        let rays = plucker_rays(&views.source, &device);
        let tokens = Tensor::<3>::random([1, 4, 16], Distribution::Normal(0.0, 1.0), &device);
        let image = Tensor::<4>::random([1, 3, 16, 16], Distribution::Uniform(0.0, 1.0), &device);
        let out = head.forward(tokens, pixels(&image, &rays), &views, 16, 16);
        let colours = values(&out.gaussians.features);
        let source = values(&image);
        for i in 0..256 {
            for c in 0..3 {
                assert_eq!(colours[i * 3 + c], source[c * 256 + i]);
            }
        }
        // The rest of the Gaussians did move: the head is not idle.
        assert!(
            values(&out.gaussians.opacity_logits)
                .iter()
                .any(|&x| x != 0.0)
        );
    }

    #[test]
    fn geometric_head_starts_at_the_source_pixels_on_the_point_depths() {
        let device = ndarray().autodiff();
        device.seed(6);
        let head = GaussianHeadConfig::new(16, 8, 2.0)
            .with_colour(GsColour::Source)
            .with_depth(GsDepth::Points)
            .with_scale(0.3)
            .init(&device);
        let views = views(1, 16, 16);
        let rays = plucker_rays(&views.source, &device);
        let tokens = Tensor::<3>::random([1, 4, 16], Distribution::Normal(0.0, 1.0), &device);
        let image = Tensor::<4>::random([1, 3, 16, 16], Distribution::Uniform(0.0, 1.0), &device);
        let distance =
            Tensor::<4>::random([1, 1, 16, 16], Distribution::Uniform(1.5, 2.5), &device)
                .require_grad();
        let source = SourcePixels {
            image: &image,
            rays: &rays,
            distance: Some(distance.clone()),
        };
        let out = head.forward(tokens, source, &views, 16, 16);
        // Colours are the source pixels, row-major.
        let colours = values(&out.gaussians.features);
        let source = values(&image);
        for i in 0..256 {
            for c in 0..3 {
                assert_eq!(colours[i * 3 + c], source[c * 256 + i]);
            }
        }
        // Centres sit at the given distances along the rays, opacity 1/2, 0.3 footprints wide.
        let camera = views.source[0];
        let d = values(&distance);
        for (i, m) in values(&out.gaussians.means).chunks_exact(3).enumerate() {
            let p = glam::Vec3::from_slice(m);
            assert!(((p - camera.center()).length() - d[i]).abs() < 1e-4);
        }
        assert!(
            values(&out.gaussians.opacity_logits)
                .iter()
                .all(|&x| x == 0.0)
        );
        let f = camera.intrinsics.fx;
        for (i, s) in values(&out.gaussians.log_scales).iter().enumerate() {
            let want = (0.3 * d[i / 3] / f).ln();
            assert!((s - want).abs() < 1e-4, "{s} vs {want}");
        }
        // The image loss reaches the depths and the head.
        let target = Tensor::<4>::random([1, 3, 16, 16], Distribution::Uniform(0.0, 1.0), &device);
        let grads = (out.image - target).powi_scalar(2).mean().backward();
        assert!(
            values(&distance.grad(&grads).unwrap())
                .iter()
                .any(|&g| g != 0.0)
        );
        assert!(
            values(&head.linear.weight.val().grad(&grads).unwrap())
                .iter()
                .any(|&g| g != 0.0)
        );
    }

    #[test]
    fn rim_gaussians_reach_back_along_their_rays_and_cover_the_turned_views_sides() {
        let device = ndarray();
        device.seed(9);
        let (h, w) = (24, 24);
        let mut views = views(1, h, w);
        views.background = [1.0, 1.0, 1.0];
        // A flat grey person 2 m away, rows 4..20 and columns 8..16, on the white background.
        let mut data = vec![1.0f32; 3 * h * w];
        for y in 4..20 {
            for x in 8..16 {
                for c in 0..3 {
                    data[c * h * w + y * w + x] = 0.4;
                }
            }
        }
        let image = Tensor::<4>::from_data(TensorData::new(data, [1, 3, h, w]), &device);
        let rays = plucker_rays(&views.source, &device);
        let tokens = Tensor::<3>::random([1, 9, 16], Distribution::Normal(0.0, 1.0), &device);
        let distance = Tensor::<4>::full([1, 1, h, w], 2.0, &device);
        let run = |rim_depth: f64, views: &Views| {
            let head = GaussianHeadConfig::new(16, 8, 2.0)
                .with_colour(GsColour::Source)
                .with_depth(GsDepth::Points)
                .with_scale(0.5)
                .with_keying(true)
                .with_rim_depth(rim_depth)
                .init(&device);
            let source = SourcePixels {
                image: &image,
                rays: &rays,
                distance: Some(distance.clone()),
            };
            head.forward(tokens.clone(), source, views, h, w)
        };
        let out = run(0.3, &views);
        let camera = views.source[0];
        let f = camera.intrinsics.fx;
        let means = values(&out.gaussians.means);
        let surface = values(&out.surface);
        let scales = values(&out.gaussians.log_scales);
        let rotations = values(&out.gaussians.rotations);
        let ray_dirs = values(&rays.clone().narrow(1, 0, 3));
        for i in 0..h * w {
            let (x, y) = (i % w, i / w);
            let person = (4..20).contains(&y) && (8..16).contains(&x);
            let rim = person && (y == 4 || y == 19 || x == 8 || x == 15);
            let p = glam::Vec3::from_slice(&means[3 * i..3 * i + 3]);
            let want = if rim { 2.15 } else { 2.0 };
            assert!(
                ((p - camera.center()).length() - want).abs() < 1e-4,
                "({x}, {y})"
            );
            // The surface point stays on the surface, on the centre's ray.
            let s = glam::Vec3::from_slice(&surface[3 * i..3 * i + 3]);
            assert!(((s - camera.center()).length() - 2.0).abs() < 1e-4);
            assert!(
                (s - camera.center())
                    .normalize()
                    .dot((p - camera.center()).normalize())
                    > 0.9999
            );
            let across = (0.5 * want / f).ln();
            let along = if rim { 0.1f32.ln() } else { across };
            for (axis, want) in [across, across, along].into_iter().enumerate() {
                let got = scales[3 * i + axis];
                assert!(
                    (got - want).abs() < 1e-3,
                    "({x}, {y}) axis {axis}: {got} vs {want}"
                );
            }
            // The third axis lies on the ray.
            let [qw, qx, qy, qz] = [0, 1, 2, 3].map(|c| rotations[4 * i + c]);
            let axis = glam::Vec3::new(
                2.0 * (qx * qz + qw * qy),
                2.0 * (qy * qz - qw * qx),
                1.0 - 2.0 * (qx * qx + qy * qy),
            );
            let ray = glam::Vec3::new(ray_dirs[i], ray_dirs[h * w + i], ray_dirs[2 * h * w + i]);
            assert!((axis.dot(ray).abs() - 1.0).abs() < 1e-4, "({x}, {y})");
        }
        // Turned 25 degrees, the rim (reaching 30 cm, 1.5 px here) covers what the plain
        // Gaussians leave uncovered beside the person; from the source camera it covers what
        // they do.
        let plain = values(&run(0.0, &views).alpha);
        let rimmed = values(&out.alpha);
        let beside = |alpha: &[f32]| {
            (alpha.iter().zip(&plain))
                .filter(|&(_, &p)| p < 0.1)
                .map(|(a, _)| a)
                .sum::<f32>()
        };
        assert!(
            beside(&rimmed) > beside(&plain) + 4.0,
            "{} against {}",
            beside(&rimmed),
            beside(&plain)
        );
        let coverage = |out: &GaussianOutput| values(&out.alpha).iter().sum::<f32>();
        let mut own = views.clone();
        own.target = own.source.clone();
        let (rimmed, plain) = (coverage(&run(0.3, &own)), coverage(&run(0.0, &own)));
        assert!(
            (rimmed - plain).abs() < 1e-3 * plain,
            "{rimmed} against {plain}"
        );
    }

    #[test]
    fn flow_render_gives_back_the_source_in_its_own_camera_and_keys_the_background() {
        let device = ndarray().autodiff();
        device.seed(8);
        let head = GaussianHeadConfig::new(16, 8, 2.0)
            .with_colour(GsColour::Flow)
            .with_scale(0.3)
            .with_keying(true)
            .init(&device);
        let (h, w) = (24, 24);
        let mut views = views(1, h, w);
        views.background = [1.0, 1.0, 1.0];
        views.target = views.source.clone();
        // A dark smooth square person on the white background.
        let mut data = vec![1.0f32; 3 * h * w];
        for y in 4..20 {
            for x in 4..20 {
                for c in 0..3 {
                    data[c * h * w + y * w + x] = 0.1 + 0.02 * x as f32 + 0.01 * (y + c) as f32;
                }
            }
        }
        let image = Tensor::<4>::from_data(TensorData::new(data.clone(), [1, 3, h, w]), &device);
        // The key: opaque on the person, transparent on the background.
        let key = sigmoid(key_logits(&image, &views.background));
        let key = values(&key);
        assert!((key[10 * w + 10] - (1.0 - KEY_FLOOR)).abs() < 1e-5);
        assert!((key[0] - KEY_FLOOR).abs() < 1e-5);
        let rays = plucker_rays(&views.source, &device);
        let tokens = Tensor::<3>::random([1, 9, 16], Distribution::Normal(0.0, 1.0), &device);
        let out = head.forward(tokens, pixels(&image, &rays), &views, h, w);
        let got = values(&out.image);
        for y in 0..h {
            for x in 0..w {
                let inside = (6..18).contains(&x) && (6..18).contains(&y);
                let outside = !(2..22).contains(&x) || !(2..22).contains(&y);
                for c in 0..3 {
                    let i = c * h * w + y * w + x;
                    if inside || outside {
                        assert!(
                            (got[i] - data[i]).abs() < 0.02,
                            "({x}, {y}, {c}): {} vs {}",
                            got[i],
                            data[i]
                        );
                    }
                }
            }
        }
        // The image loss moves the Gaussians (through the sampled coordinates).
        let target = Tensor::<4>::random([1, 3, h, w], Distribution::Uniform(0.0, 1.0), &device);
        let grads = (out.image - target).powi_scalar(2).mean().backward();
        let g = values(&head.linear.weight.val().grad(&grads).unwrap());
        assert!(g.iter().all(|v| v.is_finite()) && g.iter().any(|&v| v != 0.0));
    }

    #[test]
    fn exported_ply_reads_back() {
        let device = ndarray();
        device.seed(5);
        let head = head(&device);
        let views = views(2, 8, 8);
        let rays = plucker_rays(&views.source, &device);
        let tokens = Tensor::<3>::random([2, 1, 16], Distribution::Normal(0.0, 1.0), &device);
        let image = Tensor::<4>::zeros([2, 3, 8, 8], &device);
        let out = head.forward(tokens, pixels(&image, &rays), &views, 8, 8);
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
