//! Oracle swaps, a diagnostic of `prism evaluate --oracle`: the 3DGS head's Gaussians rendered
//! again with one of their predicted properties replaced by the truth, to find which one costs
//! the model its distance to the true-depth warp.
//!
//! The truth of each property, per source pixel (`N = H_s W_s` Gaussians per pair):
//! - depth: the dataset's 3D point of a foreground pixel (on the pixel's ray at the true
//!   depth); a background pixel keeps the model's centre;
//! - colour: the source pixel's own colour;
//! - opacity: the source mask (a foreground pixel at the warp's opacity, a background one
//!   transparent);
//! - scale: isotropic, the warp's footprint of one source pixel at the Gaussian's distance.
//!
//! Every swap is rendered like `I_gs` (over the background, in the target camera), and passed
//! through the model's NVS decoder as `I_gs` would be, giving the `I_t` the swap would make.
//! Two partial depth swaps move each foreground centre only part of the way to the truth (the
//! depth error halved, quartered), to show how the pictures grow with the depth's precision;
//! a third moves every centre by the same distance, the mean signed error (the bias removed).
//! Swapping all four is the true-depth warp drawn with the model's background Gaussians too;
//! "all but colour" is the true-depth warp with the model's colours. The truth never enters
//! the model's own predictions: this runs only in evaluation, on datasets with point maps.

use burn::tensor::{Device, Tensor, TensorData};
use prism_data::{FOREGROUND, Sample};
use prism_render::splat::{Gaussians, background, render};
use serde::Serialize;

/// Summary of the Gaussians' depth errors ([`OracleBatch::depth_errors`]) over every
/// evaluated view, metres.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct DepthError {
    /// Mean absolute error.
    pub mean: f64,
    /// Median absolute error.
    pub median: f64,
    /// 90th percentile of the absolute error.
    pub p90: f64,
    /// Mean signed error: positive when the Gaussians sit behind the truth on average.
    pub bias: f64,
}

impl DepthError {
    /// The summary of `errors` (signed, metres); `None` when there are none.
    pub fn of(errors: &[f32]) -> Option<Self> {
        if errors.is_empty() {
            return None;
        }
        let n = errors.len() as f64;
        let mut abs: Vec<f32> = errors.iter().map(|e| e.abs()).collect();
        abs.sort_by(f32::total_cmp);
        let at = |q: f64| f64::from(abs[((n - 1.0) * q).round() as usize]);
        Some(Self {
            mean: abs.iter().map(|&e| f64::from(e)).sum::<f64>() / n,
            median: at(0.5),
            p90: at(0.9),
            bias: errors.iter().map(|&e| f64::from(e)).sum::<f64>() / n,
        })
    }
}

/// Opacity of a foreground Gaussian in the opacity swap (the true-depth warp's).
const TRUE_OPACITY: f32 = 0.99;
/// Opacity of a background Gaussian in the opacity swap: none in effect.
const BACKGROUND_OPACITY: f32 = 1e-4;

/// Which of the Gaussians' properties take the truth's values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Swap {
    /// None: the model's Gaussians drawn again (the reference row; equal to `I_gs` for
    /// colour Gaussians).
    None,
    /// Centres at the true depth.
    Depth,
    /// Centres halfway from the model's depth to the true one: the depth error halved.
    HalfDepth,
    /// The depth error a quarter of the model's.
    QuarterDepth,
    /// Every foreground centre moved along its ray by the batch's mean signed depth error (one
    /// number from the truth): the bias removed, each centre's own error otherwise kept.
    Unbiased,
    /// The source pixels' colours.
    Colour,
    /// Opacities from the source mask.
    Opacity,
    /// Isotropic sizes of the warp's footprint.
    Scale,
    /// All four: the true-depth warp, with the model's background Gaussians kept.
    All,
    /// Depth, opacity and scale: the true-depth warp with the model's colours.
    AllButColour,
}

impl Swap {
    /// Every swap, in the report's order.
    pub const ALL: [Swap; 10] = [
        Swap::None,
        Swap::Depth,
        Swap::HalfDepth,
        Swap::QuarterDepth,
        Swap::Unbiased,
        Swap::Colour,
        Swap::Opacity,
        Swap::Scale,
        Swap::All,
        Swap::AllButColour,
    ];

    /// The row name in reports.
    pub fn name(self) -> &'static str {
        match self {
            Swap::None => "none (the model's Gaussians)",
            Swap::Depth => "true depth",
            Swap::HalfDepth => "depth error halved",
            Swap::QuarterDepth => "depth error quartered",
            Swap::Unbiased => "depth bias removed",
            Swap::Colour => "source colours",
            Swap::Opacity => "opacity from the mask",
            Swap::Scale => "warp-footprint scales",
            Swap::All => "all four",
            Swap::AllButColour => "all but colour (warp, model's colours)",
        }
    }

    /// The share of the model's depth error a foreground centre keeps: 1 without a depth
    /// swap, 0 at the true depth.
    fn depth_error_kept(self) -> f32 {
        match self {
            Swap::Depth | Swap::All | Swap::AllButColour => 0.0,
            Swap::HalfDepth => 0.5,
            Swap::QuarterDepth => 0.25,
            Swap::None | Swap::Unbiased | Swap::Colour | Swap::Opacity | Swap::Scale => 1.0,
        }
    }

    fn colour(self) -> bool {
        matches!(self, Swap::Colour | Swap::All)
    }

    fn opacity(self) -> bool {
        matches!(self, Swap::Opacity | Swap::All | Swap::AllButColour)
    }

    fn scale(self) -> bool {
        matches!(self, Swap::Scale | Swap::All | Swap::AllButColour)
    }
}

/// The model's Gaussians of a batch read back to the host, with the truth of each sample's
/// source pixels, ready to be swapped and drawn.
pub struct OracleBatch {
    dims: [usize; 2],
    means: Vec<f32>,
    /// Each Gaussian's surface point (its centre unless set by [`OracleBatch::with_surface`]).
    surfaces: Vec<f32>,
    log_scales: Vec<f32>,
    rotations: Vec<f32>,
    opacity_logits: Vec<f32>,
    colours: Vec<f32>,
    true_means: Vec<f32>,
    true_colours: Vec<f32>,
    foreground: Vec<bool>,
    /// Each pair's source camera centre and focal length (pixels).
    sources: Vec<([f32; 3], f32)>,
}

fn host(t: Tensor<3>) -> Vec<f32> {
    t.into_data()
        .convert::<f32>()
        .try_into_vec()
        .expect("float tensor")
}

impl OracleBatch {
    /// The model's `gaussians` of `samples` (one pair each, colour features) and the samples'
    /// truth.
    ///
    /// # Panics
    /// If the Gaussians are not one per source pixel of each sample.
    pub fn new(samples: &[Sample], gaussians: &Gaussians) -> Self {
        let [b, n, c] = gaussians.features.dims();
        assert_eq!(b, samples.len(), "one pair per sample");
        assert_eq!(c, 3, "colour Gaussians");
        let mut true_means = Vec::with_capacity(b * n * 3);
        let mut true_colours = Vec::with_capacity(b * n * 3);
        let mut foreground = Vec::with_capacity(b * n);
        let mut sources = Vec::with_capacity(b);
        for sample in samples {
            let source = &sample.source;
            assert_eq!(sample.points.points.len(), n, "one point per source pixel");
            assert_eq!(
                source.rgb.pixels().len(),
                n,
                "one Gaussian per source pixel"
            );
            for ((point, rgb), alpha) in sample
                .points
                .points
                .iter()
                .zip(source.rgb.pixels())
                .zip(source.mask.pixels())
            {
                true_means.extend(point);
                true_colours.extend(rgb.0);
                foreground.push(alpha.0[0] > FOREGROUND);
            }
            let centre = source.camera.center();
            sources.push((centre.to_array(), source.camera.intrinsics.fx));
        }
        let means = host(gaussians.means.clone());
        Self {
            dims: [b, n],
            surfaces: means.clone(),
            means,
            log_scales: host(gaussians.log_scales.clone()),
            rotations: host(gaussians.rotations.clone()),
            opacity_logits: host(gaussians.opacity_logits.clone()),
            colours: host(gaussians.features.clone()),
            true_means,
            true_colours,
            foreground,
            sources,
        }
    }

    /// The Gaussians' surface points `[B, N, 3]` where they differ from their centres (the
    /// rim Gaussians of `gs_rim_depth` sit behind theirs by design, see
    /// `prism_model::GaussianOutput::surface`). Depth errors are then measured on the surface
    /// points, and the depth swaps move them, each centre keeping its offset from its own.
    ///
    /// # Panics
    /// If `surface` is not one point per Gaussian.
    pub fn with_surface(mut self, surface: &Tensor<3>) -> Self {
        let [b, n] = self.dims;
        assert_eq!(surface.dims(), [b, n, 3], "one surface point per Gaussian");
        self.surfaces = host(surface.clone());
        self
    }

    /// How far the model's Gaussians lie from the truth: for each source foreground pixel, its
    /// surface point's distance from the camera minus that of the dataset's point of the pixel
    /// (metres; positive: the Gaussian is too far). Both are on the pixel's ray, so this is the
    /// signed depth error.
    pub fn depth_errors(&self) -> Vec<f32> {
        let [_, n] = self.dims;
        (0..self.foreground.len())
            .filter(|&i| self.foreground[i])
            .map(|i| {
                let (centre, _) = self.sources[i / n];
                distance_from(centre, &self.surfaces[3 * i..3 * i + 3])
                    - distance_from(centre, &self.true_means[3 * i..3 * i + 3])
            })
            .collect()
    }

    /// The Gaussians with `swap`'s properties taken from the truth, the scales of the scale
    /// swap `footprint` source pixels wide.
    pub fn swapped(&self, swap: Swap, footprint: f32, device: &Device) -> Gaussians {
        let [b, n] = self.dims;
        let mut means = self.means.clone();
        let mut log_scales = self.log_scales.clone();
        let mut rotations = self.rotations.clone();
        let mut opacity = self.opacity_logits.clone();
        let colours = if swap.colour() {
            self.true_colours.clone()
        } else {
            self.colours.clone()
        };
        let logit = |p: f32| (p / (1.0 - p)).ln();
        let bias = if swap == Swap::Unbiased {
            let errors = self.depth_errors();
            errors.iter().sum::<f32>() / errors.len().max(1) as f32
        } else {
            0.0
        };
        for pair in 0..b {
            let (centre, focal) = self.sources[pair];
            for i in pair * n..(pair + 1) * n {
                let fg = self.foreground[i];
                let kept = swap.depth_error_kept();
                if kept < 1.0 && fg {
                    // All on the pixel's ray, so the mix is too; the centre keeps its offset
                    // from its surface point.
                    let range = 3 * i..3 * i + 3;
                    for (((mean, &centre), &model), &truth) in means[range.clone()]
                        .iter_mut()
                        .zip(&self.means[range.clone()])
                        .zip(&self.surfaces[range.clone()])
                        .zip(&self.true_means[range])
                    {
                        *mean = truth + kept * (model - truth) + (centre - model);
                    }
                }
                if bias != 0.0 && fg {
                    // Along the centre's own ray: nearer by the bias.
                    let mean = &mut means[3 * i..3 * i + 3];
                    let length = distance_from(centre, mean);
                    let scale = (length - bias).max(1e-3) / length;
                    for (m, c) in mean.iter_mut().zip(centre) {
                        *m = c + scale * (*m - c);
                    }
                }
                if swap.opacity() {
                    opacity[i] = logit(if fg { TRUE_OPACITY } else { BACKGROUND_OPACITY });
                }
                if swap.scale() {
                    let distance = distance_from(centre, &means[3 * i..3 * i + 3]);
                    let log_scale = (footprint * distance / focal).max(1e-9).ln();
                    log_scales[3 * i..3 * i + 3].fill(log_scale);
                    rotations[4 * i..4 * i + 4].copy_from_slice(&[1.0, 0.0, 0.0, 0.0]);
                }
            }
        }
        let tensor = |values: Vec<f32>, c: usize| {
            Tensor::<3>::from_data(TensorData::new(values, [b, n, c]), device)
        };
        Gaussians {
            means: tensor(means, 3),
            log_scales: tensor(log_scales, 3),
            rotations: tensor(rotations, 4),
            opacity_logits: tensor(opacity, 1),
            features: tensor(colours, 3),
        }
    }
}

/// The distance of point `p` (3 values) from the camera centre `c`.
fn distance_from(c: [f32; 3], p: &[f32]) -> f32 {
    p.iter()
        .zip(c)
        .map(|(p, c)| (p - c).powi(2))
        .sum::<f32>()
        .sqrt()
}

/// `gaussians` drawn in each sample's (first) target camera over `bg`, `[B, 3, H, W]` in
/// [0, 1].
pub fn draw(gaussians: &Gaussians, samples: &[Sample], bg: [f32; 3], device: &Device) -> Tensor<4> {
    let cameras: Vec<_> = samples.iter().map(|s| s.targets[0].camera).collect();
    render(gaussians, &cameras)
        .expect("one camera per pair")
        .over(background(&bg, device))
        .clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::warp::true_depth_warp;
    use prism_core::BackendKind;

    /// A sample of the warp's tests: a 16 x 16 square on a plane 2 m away, the target 0.25 m
    /// to the right.
    fn sample() -> Sample {
        crate::warp::tests::sample(0.25, true)
    }

    fn image(t: Tensor<4>) -> Vec<f32> {
        t.into_data().try_into_vec_as::<f32>().unwrap()
    }

    /// Gaussians far from the truth: every pixel 3 m away on its ray, grey, half opaque,
    /// 5 cm wide and turned.
    fn wrong(samples: &[Sample], device: &Device) -> Gaussians {
        let b = samples.len();
        let n = (samples[0].points.width * samples[0].points.height) as usize;
        let mut means = Vec::new();
        for s in samples {
            for y in 0..s.points.height {
                for x in 0..s.points.width {
                    let p = s
                        .source
                        .camera
                        .unproject(x as f32 + 0.5, y as f32 + 0.5, 3.0);
                    means.extend(p.to_array());
                }
            }
        }
        let tensor = |values: Vec<f32>, c: usize| {
            Tensor::<3>::from_data(TensorData::new(values, [b, n, c]), device)
        };
        Gaussians {
            means: tensor(means, 3),
            log_scales: tensor(vec![0.05f32.ln(); b * n * 3], 3),
            rotations: tensor([0.9, 0.1, 0.0, 0.0].repeat(b * n), 4),
            opacity_logits: tensor(vec![0.0; b * n], 1),
            features: tensor(vec![0.5; b * n * 3], 3),
        }
    }

    #[test]
    fn swapping_everything_draws_the_true_depth_warp() {
        let device = BackendKind::Ndarray.device().unwrap();
        let samples = vec![sample()];
        let bg = [1.0; 3];
        let batch = OracleBatch::new(&samples, &wrong(&samples, &device));
        let warp = image(true_depth_warp(&samples, bg, 0.3, &device));
        let all = image(draw(
            &batch.swapped(Swap::All, 0.3, &device),
            &samples,
            bg,
            &device,
        ));
        // The background Gaussians are transparent, so all four swaps are the warp.
        let worst = warp
            .iter()
            .zip(&all)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-3, "largest difference {worst}");
        let none = image(draw(
            &batch.swapped(Swap::None, 0.3, &device),
            &samples,
            bg,
            &device,
        ));
        assert!(none.iter().zip(&warp).any(|(a, b)| (a - b).abs() > 0.1));
    }

    #[test]
    fn depth_errors_are_signed_distances_on_the_foreground() {
        let device = BackendKind::Ndarray.device().unwrap();
        let samples = vec![sample()];
        let model = wrong(&samples, &device);
        let errors = OracleBatch::new(&samples, &model).depth_errors();
        // The model's centres at depth 3 against the plane's points at depth 2, on the 16 x 16
        // foreground square only: each about a metre too far.
        let camera = &samples[0].source.camera;
        let want: Vec<f32> = (8..24)
            .flat_map(|y| (8..24).map(move |x| (x, y)))
            .map(|(x, y)| {
                let (x, y) = (x as f32 + 0.5, y as f32 + 0.5);
                (camera.unproject(x, y, 3.0) - camera.unproject(x, y, 2.0)).length()
            })
            .collect();
        assert_eq!(errors.len(), 16 * 16);
        for (e, w) in errors.iter().zip(&want) {
            assert!((e - w).abs() < 1e-4, "{e} vs {w}");
        }
        let summary = DepthError::of(&errors).unwrap();
        assert!(summary.mean > 0.99 && (summary.bias - summary.mean).abs() < 1e-9);
        assert!(summary.median <= summary.p90);
        // Mirrored: the same sizes, the opposite sign.
        let mirrored: Vec<f32> = errors.iter().map(|e| -e).collect();
        let flipped = DepthError::of(&mirrored).unwrap();
        assert_eq!(flipped.mean, summary.mean);
        assert_eq!(flipped.bias, -summary.bias);
        assert!(DepthError::of(&[]).is_none());
        // The depth swap puts them on the points; the partial ones keep a share of the error.
        for (swap, share) in [
            (Swap::Depth, 0.0),
            (Swap::HalfDepth, 0.5),
            (Swap::QuarterDepth, 0.25),
        ] {
            let swapped = OracleBatch::new(&samples, &model).swapped(swap, 0.3, &device);
            let errors = OracleBatch::new(&samples, &swapped).depth_errors();
            assert_eq!(errors.len(), 16 * 16);
            for (e, w) in errors.iter().zip(&want) {
                assert!(
                    (e - share * w).abs() < 1e-4,
                    "{swap:?}: {e} vs {share} x {w}"
                );
            }
        }
        // Without the bias each centre keeps its error less the mean: about 0 on this plane.
        let swapped = OracleBatch::new(&samples, &model).swapped(Swap::Unbiased, 0.3, &device);
        let errors = OracleBatch::new(&samples, &swapped).depth_errors();
        let mean = want.iter().sum::<f32>() / want.len() as f32;
        for (e, w) in errors.iter().zip(&want) {
            assert!((e - (w - mean)).abs() < 1e-4, "{e} vs {w} - {mean}");
        }
    }

    #[test]
    fn with_surface_points_the_depth_is_theirs_and_the_centres_keep_their_offsets() {
        let device = BackendKind::Ndarray.device().unwrap();
        let samples = vec![sample()];
        let model = wrong(&samples, &device);
        // Centres 10 cm behind surface points at depth 3 (rim Gaussians everywhere).
        let surface = model.means.clone();
        let centre = samples[0].source.camera.center();
        let origin = Tensor::<3>::from_data(
            TensorData::new(centre.to_array().to_vec(), [1, 1, 3]),
            &device,
        );
        let rays = surface.clone() - origin.clone();
        let length = rays.clone().powi_scalar(2).sum_dim(2).sqrt();
        let means = surface.clone() + rays.clone() / length.clone() * 0.1;
        let rimmed = Gaussians {
            means,
            ..model.clone()
        };
        let plain = OracleBatch::new(&samples, &model).depth_errors();
        let batch = OracleBatch::new(&samples, &rimmed).with_surface(&surface);
        assert_eq!(batch.depth_errors(), plain);
        // The true-depth swap puts each surface point on the truth, its centre 10 cm behind.
        let swapped = batch.swapped(Swap::Depth, 0.3, &device);
        let errors = OracleBatch::new(&samples, &swapped).depth_errors();
        assert_eq!(errors.len(), 16 * 16);
        for e in errors {
            assert!((e - 0.1).abs() < 1e-4, "{e}");
        }
    }

    #[test]
    fn each_swap_replaces_its_own_property_alone() {
        let device = BackendKind::Ndarray.device().unwrap();
        let samples = vec![sample()];
        let model = wrong(&samples, &device);
        let batch = OracleBatch::new(&samples, &model);
        let read = |g: &Gaussians| {
            [
                host(g.means.clone()),
                host(g.log_scales.clone()),
                host(g.rotations.clone()),
                host(g.opacity_logits.clone()),
                host(g.features.clone()),
            ]
        };
        let original = read(&model);
        let fg = &batch.foreground;
        assert_eq!(fg.iter().filter(|&&f| f).count(), 16 * 16);
        for swap in Swap::ALL {
            let got = read(&batch.swapped(swap, 0.3, &device));
            let [means, scales, rotations, opacity, colours] = &got;
            for i in 0..fg.len() {
                let mean = &means[3 * i..3 * i + 3];
                let kept = swap.depth_error_kept();
                for k in 0..3 {
                    let (truth, model) = (batch.true_means[3 * i + k], original[0][3 * i + k]);
                    let want = if fg[i] {
                        truth + kept * (model - truth)
                    } else {
                        model
                    };
                    // The unbiased centres move by the bias (checked in the depth-error test).
                    if swap != Swap::Unbiased || !fg[i] {
                        assert!((mean[k] - want).abs() < 1e-6, "{swap:?} {i}: {mean:?}");
                    }
                }
                let o = opacity[i];
                if swap.opacity() {
                    let p = 1.0 / (1.0 + (-o).exp());
                    let want = if fg[i] {
                        TRUE_OPACITY
                    } else {
                        BACKGROUND_OPACITY
                    };
                    assert!((p - want).abs() < 1e-5, "{swap:?} {i}: {p}");
                } else {
                    assert_eq!(o, 0.0, "{swap:?}");
                }
                let scale = &scales[3 * i..3 * i + 3];
                if swap.scale() {
                    // One footprint of 0.3 source pixels at the centre's distance.
                    let (centre, focal) = batch.sources[0];
                    let d = (0..3)
                        .map(|k| (mean[k] - centre[k]).powi(2))
                        .sum::<f32>()
                        .sqrt();
                    let want = (0.3 * d / focal).ln();
                    assert!(scale.iter().all(|s| (s - want).abs() < 1e-5), "{swap:?}");
                    assert_eq!(&rotations[4 * i..4 * i + 4], &[1.0, 0.0, 0.0, 0.0]);
                } else {
                    assert_eq!(scale, &original[1][3 * i..3 * i + 3], "{swap:?}");
                    assert_eq!(&rotations[4 * i..4 * i + 4], &original[2][4 * i..4 * i + 4]);
                }
            }
            let want = if swap.colour() {
                &batch.true_colours
            } else {
                &original[4]
            };
            assert_eq!(colours, want, "{swap:?}");
        }
    }
}
