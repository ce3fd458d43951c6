//! The training objective (paper Sec. 3.3):
//! `L = l_nvs L_nvs + l_gs L_gs + l_pts L_pts + l_smplx L_smplx + l_distill L_distill`,
//! with `L_nvs = MSE + l_lpips LPIPS` and `L_gs` alike, plus, beyond the paper,
//! `l_gs_opacity L_opacity` (see [`crate::opacity`]), `l_gs_centres L_centres` and
//! `l_gs_spread L_spread` (see [`crate::centres`]), and `l_laplacian L_lap` inside `L_nvs` and
//! `L_gs` (see [`laplacian_loss`]; all 0 in the paper config).

use burn::config::Config;
use burn::tensor::Tensor;

use crate::{
    DistillInputs, LossError, Lpips, PointLoss, SmplxParams, centres_loss, distill_loss,
    opacity_loss, point_loss, smplx_loss, spread_loss,
};

/// Weights of the objective: the `[losses]` section of the TOML configs. Defaults are the
/// paper's. A term whose weight is 0 is not computed (and not reported).
#[derive(Config, Debug, PartialEq)]
pub struct LossWeights {
    /// `l_nvs`, weight of the NVS decoder's image loss `L_nvs`.
    #[config(default = 1.0)]
    pub nvs: f64,
    /// `l_gs`, weight of the 3DGS head's image loss `L_gs`.
    #[config(default = 1.0)]
    pub gs: f64,
    /// `l_pts`, weight of the point-branch loss `L_pts`.
    #[config(default = 100.0)]
    pub pts: f64,
    /// `l_smplx`, weight of the SMPL-X parameter loss `L_smplx`.
    #[config(default = 1.0)]
    pub smplx: f64,
    /// `l_distill`, weight of the hidden-state distillation loss `L_distill`.
    #[config(default = 1.0)]
    pub distill: f64,
    /// `l_lpips`, weight of LPIPS inside `L_nvs` and `L_gs` (0 skips LPIPS entirely).
    #[config(default = 1.0)]
    pub lpips: f64,
    /// `a`, weight of the confidence regulariser `-a log C` of `L_pts`.
    #[config(default = 0.2)]
    pub confidence_alpha: f64,
    /// `l_gs_opacity`, weight of `L_opacity`, the 3DGS head's opacities against the source
    /// mask (not in the paper: 0 there; see [`crate::opacity`]).
    #[config(default = 0.0)]
    pub gs_opacity: f64,
    /// `l_holes`, weight of `L_holes`, the NVS decoder's squared error averaged over the holes
    /// of `I_gs` only: the target's foreground where the 3DGS render's coverage is low, where
    /// the decoder has to synthesise (not in the paper: 0 there; see [`holes_loss`]).
    #[config(default = 0.0)]
    pub nvs_holes: f64,
    /// `l_gs_centres`, weight of `L_centres`, the 3DGS head's Gaussian centres against the
    /// dataset's points on the source foreground (not in the paper: 0 there; see
    /// [`crate::centres`]).
    #[config(default = 0.0)]
    pub gs_centres: f64,
    /// `l_gs_spread`, weight of `L_spread`, the spread of the centres' errors about their
    /// image's mean error (not in the paper: 0 there; see [`crate::centres::spread_loss`]).
    #[config(default = 0.0)]
    pub gs_spread: f64,
    /// `l_laplacian`, weight of `L_lap` inside `L_nvs` and `L_gs`: the error's Laplacian, so
    /// pixel-level noise over a smooth truth costs more than a smooth offset (not in the
    /// paper: 0 there; see [`laplacian_loss`]).
    #[config(default = 0.0)]
    pub laplacian: f64,
    /// `L_lap`'s weight inside `L_gs` alone, where it differs from `laplacian` (unset: the
    /// same): the 3DGS render can be held smoother than the NVS decoder's output.
    pub gs_laplacian: Option<f64>,
}

impl LossWeights {
    /// `L_lap`'s weight inside `L_gs`: `gs_laplacian` where set, `laplacian` otherwise.
    pub fn laplacian_in_gs(&self) -> f64 {
        self.gs_laplacian.unwrap_or(self.laplacian)
    }
}

/// Inputs of `L_opacity` (see [`opacity_loss`]).
#[derive(Clone, Debug)]
pub struct OpacityInputs {
    /// The 3DGS head's opacity logits, one row per source pixel, `[B, N, 1]`.
    pub logits: Tensor<3>,
    /// The source foreground mask in the same order, `[B, N, 1]` (see
    /// [`crate::opacity::pixel_rows`]).
    pub mask: Tensor<3>,
}

/// Inputs of `L_centres` (see [`centres_loss`]).
#[derive(Clone, Debug)]
pub struct CentreInputs {
    /// The 3DGS head's Gaussian centres, one row per source pixel, `[B, N, 3]`.
    pub centres: Tensor<3>,
    /// The true points in the same order, `[B, N, 3]` (see [`crate::opacity::pixel_rows`]).
    pub points: Tensor<3>,
    /// The source foreground mask in the same order, `[B, N, 1]`.
    pub mask: Tensor<3>,
}

/// Inputs of `L_pts` (see [`point_loss`]).
#[derive(Clone, Debug)]
pub struct PointInputs {
    /// Predicted world points per source pixel, `[B, 3, H, W]`.
    pub points: Tensor<4>,
    /// Ground-truth points, `[B, 3, H, W]`.
    pub points_gt: Tensor<4>,
    /// Predicted confidence `C > 0`, `[B, 1, H, W]`.
    pub confidence: Tensor<4>,
    /// Foreground mask (foreground where > 0.5), `[B, 1, H, W]`.
    pub mask: Tensor<4>,
}

/// Inputs of `L_smplx` (see [`smplx_loss`]).
#[derive(Clone, Debug)]
pub struct SmplxInputs {
    /// The regressed parameters.
    pub pred: SmplxParams,
    /// The fitted parameters.
    pub gt: SmplxParams,
    /// `[B]`, 1 where the subject has a fit, 0 where not; `None`: all have one.
    pub has_fit: Option<Tensor<1>>,
}

/// What one training step has to supervise; absent parts are not computed.
#[derive(Clone, Debug, Default)]
pub struct LossInputs {
    /// The target view both images are scored against, `[B, 3, H, W]` in [0, 1].
    pub target: Option<Tensor<4>>,
    /// The NVS decoder's output, `[B, 3, H, W]`.
    pub nvs: Option<Tensor<4>>,
    /// The 3DGS head's render, `[B, 3, H, W]`.
    pub gs: Option<Tensor<4>>,
    /// 3DGS head opacities and the source mask.
    pub gs_opacity: Option<OpacityInputs>,
    /// 3DGS head centres and the true points.
    pub gs_centres: Option<CentreInputs>,
    /// Point-branch prediction and targets.
    pub pts: Option<PointInputs>,
    /// SMPL-X branch prediction and fit.
    pub smplx: Option<SmplxInputs>,
    /// Student and teacher hidden states.
    pub distill: Option<DistillInputs>,
    /// Per-pixel weights of `L_holes`, `[B, 1, H, W]` in [0, 1] (constants).
    pub nvs_holes: Option<Tensor<4>>,
}

impl LossInputs {
    /// No inputs yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// With the target view (what [`LossInputs::with_nvs`] and [`LossInputs::with_gs`]
    /// predict). One target for both images, so that LPIPS computes its features once.
    pub fn with_target(mut self, gt: Tensor<4>) -> Self {
        self.target = Some(gt);
        self
    }

    /// With the NVS decoder's prediction of the target.
    pub fn with_nvs(mut self, pred: Tensor<4>) -> Self {
        self.nvs = Some(pred);
        self
    }

    /// With the 3DGS head's render of the target.
    pub fn with_gs(mut self, pred: Tensor<4>) -> Self {
        self.gs = Some(pred);
        self
    }

    /// With the 3DGS head's opacity logits and the source mask.
    pub fn with_gs_opacity(mut self, opacity: OpacityInputs) -> Self {
        self.gs_opacity = Some(opacity);
        self
    }

    /// With the 3DGS head's centres and the true points.
    pub fn with_gs_centres(mut self, centres: CentreInputs) -> Self {
        self.gs_centres = Some(centres);
        self
    }

    /// With the point branch's points and confidence and their targets.
    pub fn with_pts(mut self, pts: PointInputs) -> Self {
        self.pts = Some(pts);
        self
    }

    /// With the SMPL-X branch's parameters and the fit.
    pub fn with_smplx(mut self, smplx: SmplxInputs) -> Self {
        self.smplx = Some(smplx);
        self
    }

    /// With the weights of the holes of `I_gs` for `L_holes` (see [`holes_loss`]).
    pub fn with_nvs_holes(mut self, weights: Tensor<4>) -> Self {
        self.nvs_holes = Some(weights);
        self
    }

    /// With student and teacher hidden states of the distilled layers.
    pub fn with_distill(mut self, student: Vec<Tensor<3>>, teacher: Vec<Tensor<3>>) -> Self {
        self.distill = Some(DistillInputs { student, teacher });
        self
    }
}

/// The value of every computed term, unweighted, plus the weighted `total`, each `[1]`.
///
/// Names: `nvs_holes`, `nvs_mse`, `nvs_lpips`, `nvs_laplacian`, `gs_mse`, `gs_lpips`,
/// `gs_laplacian`, `gs_opacity`,
/// `gs_centres`, `gs_spread`, `pts`,
/// `smplx`, `distill` (in this order, those computed only) and `total`.
#[derive(Clone, Debug)]
pub struct LossTerms {
    /// `L`, the weighted sum: what to call `backward` on.
    pub total: Tensor<1>,
    /// The computed terms, unweighted, in the order above.
    pub terms: Vec<(&'static str, Tensor<1>)>,
}

impl LossTerms {
    /// A term by name (`"total"` included); `None` when it was not computed.
    pub fn get(&self, name: &str) -> Option<&Tensor<1>> {
        if name == "total" {
            return Some(&self.total);
        }
        self.terms.iter().find(|(n, _)| *n == name).map(|(_, t)| t)
    }

    /// Names of the computed terms, then `"total"`.
    pub fn names(&self) -> Vec<&'static str> {
        self.terms
            .iter()
            .map(|(n, _)| *n)
            .chain(["total"])
            .collect()
    }

    /// Every term and the total read back as numbers, for logging (synchronises the device).
    pub fn values(&self) -> Vec<(&'static str, f64)> {
        self.terms
            .iter()
            .map(|(n, t)| (*n, t))
            .chain([("total", &self.total)])
            .map(|(n, t)| {
                prism_core::reads::count_host_read();
                (n, t.clone().into_scalar::<f64>())
            })
            .collect()
    }
}

/// The objective: the loss weights and, when LPIPS is weighted, the LPIPS network.
#[derive(Debug)]
pub struct Objective {
    weights: LossWeights,
    lpips: Option<Lpips>,
}

impl Objective {
    /// An objective with these weights. `lpips` must be given (on the training device, e.g.
    /// from [`Lpips::load_default`]) when `weights.lpips` and an image weight are nonzero.
    ///
    /// # Errors
    /// [`LossError::LpipsRequired`] when LPIPS is weighted but missing.
    pub fn new(weights: LossWeights, lpips: Option<Lpips>) -> Result<Self, LossError> {
        let images_weighted = weights.nvs != 0.0 || weights.gs != 0.0;
        if weights.lpips != 0.0 && images_weighted && lpips.is_none() {
            return Err(LossError::LpipsRequired(weights.lpips));
        }
        Ok(Self { weights, lpips })
    }

    /// The weights.
    pub fn weights(&self) -> &LossWeights {
        &self.weights
    }

    /// The LPIPS network, when loaded.
    pub fn lpips(&self) -> Option<&Lpips> {
        self.lpips.as_ref()
    }

    /// Evaluates every term that has inputs and a nonzero weight, and the weighted total
    /// `L = l_nvs (MSE + l_lpips LPIPS)_nvs + l_gs (MSE + l_lpips LPIPS)_gs + l_pts L_pts +
    /// l_smplx L_smplx + l_distill L_distill + l_gs_opacity L_opacity + l_gs_centres L_centres
    /// + l_gs_spread L_spread`. MSE and LPIPS are means over the batch.
    ///
    /// The target's LPIPS features are computed once, for both images.
    ///
    /// # Errors
    /// [`LossError::NoTerms`] when nothing was computed; [`LossError::NoTarget`] when an
    /// image is weighted without a target.
    pub fn forward(&self, inputs: LossInputs) -> Result<LossTerms, LossError> {
        let w = &self.weights;
        let mut terms: Vec<(&'static str, Tensor<1>)> = Vec::new();
        let mut total: Option<Tensor<1>> = None;
        let mut add = |weight: f64, value: &Tensor<1>| {
            let weighted = value.clone().mul_scalar(weight);
            total = Some(match total.take() {
                Some(t) => t.add(weighted),
                None => weighted,
            });
        };

        let target = inputs.target;
        let target_of = || target.clone().ok_or(LossError::NoTarget);
        if let (Some(pred), Some(weights)) = (&inputs.nvs, inputs.nvs_holes)
            && w.nvs_holes != 0.0
        {
            let value = holes_loss(pred.clone(), target_of()?, weights);
            add(w.nvs_holes, &value);
            terms.push(("nvs_holes", value));
        }
        let images = [
            (
                "nvs_mse",
                "nvs_lpips",
                "nvs_laplacian",
                w.nvs,
                w.laplacian,
                inputs.nvs,
            ),
            (
                "gs_mse",
                "gs_lpips",
                "gs_laplacian",
                w.gs,
                w.laplacian_in_gs(),
                inputs.gs,
            ),
        ];
        // The target's LPIPS features, computed for the first image scored and kept for the
        // second.
        let mut reference = None;
        for (mse_name, lpips_name, laplacian_name, weight, laplacian, pred) in images {
            let Some(pred) = pred.filter(|_| weight != 0.0) else {
                continue;
            };
            let gt = target_of()?;
            let mse = mse_loss(pred.clone(), gt.clone());
            add(weight, &mse);
            terms.push((mse_name, mse));
            if let Some(lpips) = self.lpips.as_ref().filter(|_| w.lpips != 0.0) {
                let reference = reference.get_or_insert_with(|| lpips.loss_reference(gt.clone()));
                let value = reference.forward(pred.clone()).mean();
                add(weight * w.lpips, &value);
                terms.push((lpips_name, value));
            }
            if laplacian != 0.0 {
                let value = laplacian_loss(pred, gt);
                add(weight * laplacian, &value);
                terms.push((laplacian_name, value));
            }
        }
        if let Some(o) = inputs.gs_opacity.filter(|_| w.gs_opacity != 0.0) {
            let value = opacity_loss(o.logits, o.mask);
            add(w.gs_opacity, &value);
            terms.push(("gs_opacity", value));
        }
        if let Some(c) = inputs
            .gs_centres
            .filter(|_| w.gs_centres != 0.0 || w.gs_spread != 0.0)
        {
            if w.gs_centres != 0.0 {
                let value = centres_loss(c.centres.clone(), c.points.clone(), c.mask.clone());
                add(w.gs_centres, &value);
                terms.push(("gs_centres", value));
            }
            if w.gs_spread != 0.0 {
                let value = spread_loss(c.centres, c.points, c.mask);
                add(w.gs_spread, &value);
                terms.push(("gs_spread", value));
            }
        }
        if let Some(p) = inputs.pts.filter(|_| w.pts != 0.0) {
            let loss: PointLoss = point_loss(
                p.points,
                p.points_gt,
                p.confidence,
                p.mask,
                w.confidence_alpha,
            );
            let value = loss.total();
            add(w.pts, &value);
            terms.push(("pts", value));
        }
        if let Some(s) = inputs.smplx.filter(|_| w.smplx != 0.0) {
            let value = smplx_loss(&s.pred, &s.gt, s.has_fit);
            add(w.smplx, &value);
            terms.push(("smplx", value));
        }
        if let Some(d) = inputs.distill.filter(|_| w.distill != 0.0) {
            let value = distill_loss(&d.student, &d.teacher);
            add(w.distill, &value);
            terms.push(("distill", value));
        }
        let total = total.ok_or(LossError::NoTerms)?;
        Ok(LossTerms { total, terms })
    }
}

/// `L_holes`: the squared error of `pred` against `gt` (`[B, 3, H, W]`) averaged with the
/// per-pixel `weights` (`[B, 1, H, W]`), `sum(w (pred - gt)^2) / (3 sum(w) + 1)`, `[1]`: an
/// image whose holes are few still has its error there count in full, and none gives 0.
pub fn holes_loss(pred: Tensor<4>, gt: Tensor<4>, weights: Tensor<4>) -> Tensor<1> {
    let d = pred.sub(gt);
    let weighted = d.clone().mul(d).mul(weights.clone()).sum();
    weighted.div(weights.sum().mul_scalar(3.0).add_scalar(1.0))
}

/// `L_lap`: the mean absolute difference of the two images' Laplacians (`[B, C, H, W]`, the
/// 5-point stencil `4 x - x_left - x_right - x_up - x_down` on the interior pixels), `[1]`.
/// The Laplacian is linear, so this is the error image's: a smooth error (an offset, a ramp)
/// costs nothing, and pixel-level noise on a smooth truth, the speckle `prism evaluate`
/// scores, costs about four times its size; where the truth has an edge, the prediction's
/// matching edge costs nothing either.
pub fn laplacian_loss(pred: Tensor<4>, gt: Tensor<4>) -> Tensor<1> {
    let [b, c, h, w] = pred.dims();
    assert!(
        h >= 3 && w >= 3,
        "L_lap needs images of at least 3 x 3 pixels, got {h} x {w}"
    );
    let e = pred.sub(gt);
    let at = |rows: std::ops::Range<usize>, cols: std::ops::Range<usize>| {
        e.clone().slice([0..b, 0..c, rows, cols])
    };
    let (inner_h, inner_w) = (1..h - 1, 1..w - 1);
    let laplacian = at(inner_h.clone(), inner_w.clone()).mul_scalar(4.0)
        - at(inner_h.clone(), 0..w - 2)
        - at(inner_h, 2..w)
        - at(0..h - 2, inner_w.clone())
        - at(2..h, inner_w);
    laplacian.abs().mean()
}

/// Mean squared error over all elements, `[1]`.
pub fn mse_loss(pred: Tensor<4>, gt: Tensor<4>) -> Tensor<1> {
    let d = pred.sub(gt);
    d.clone().mul(d).mean()
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::TensorData;
    use prism_core::BackendKind;

    #[test]
    fn laplacian_loss_takes_noise_and_leaves_offsets_and_shared_edges() {
        let device = BackendKind::Ndarray.device().unwrap();
        let (h, w) = (6, 7);
        // The truth: a smooth ramp with a sharp step down its middle column.
        let truth: Vec<f32> = (0..3 * h * w)
            .map(|i| {
                let (y, x) = ((i / w) % h, i % w);
                0.05 * y as f32 + if x >= 3 { 0.5 } else { 0.0 }
            })
            .collect();
        let image = |v: Vec<f32>| Tensor::<4>::from_data(TensorData::new(v, [1, 3, h, w]), &device);
        let loss =
            |pred: Vec<f32>| laplacian_loss(image(pred), image(truth.clone())).into_scalar::<f32>();
        // An offset of the whole image, with the same edge: nothing.
        assert!(loss(truth.iter().map(|t| t + 0.2).collect()) < 1e-6);
        // One pixel of channel 0 0.1 too bright, at (y, x) = (2, 1): its own stencil gives 0.4,
        // and three of its neighbours, (1, 1), (3, 1) and (2, 2), have stencils giving 0.1
        // each ((2, 0) is on the border, which has none); 3 channels x 4 x 5 stencils in all.
        let want = (0.4 + 3.0 * 0.1) / (3.0 * 4.0 * 5.0);
        assert!((loss(with_spot(&truth, w)) - want).abs() < 1e-6);
        // Noise on the smooth truth costs more than the same-sized smooth error.
        let noise: Vec<f32> = (0..truth.len())
            .map(|i| truth[i] + if (i + i / w) % 2 == 0 { 0.03 } else { -0.03 })
            .collect();
        let ramp: Vec<f32> = (0..truth.len())
            .map(|i| truth[i] + 0.03 * ((i % w) as f32 / w as f32))
            .collect();
        assert!(loss(noise) > 10.0 * loss(ramp).max(1e-4));
        // The objective adds it to both images' losses with their weights, when weighted.
        let (pred, gt) = (image(with_spot(&truth, w)), image(truth.clone()));
        let inputs = LossInputs::new()
            .with_target(gt)
            .with_nvs(pred.clone())
            .with_gs(pred);
        let weights = |l: f64| {
            LossWeights::new()
                .with_lpips(0.0)
                .with_gs(0.5)
                .with_laplacian(l)
        };
        let terms = |l: f64| {
            Objective::new(weights(l), None)
                .unwrap()
                .forward(inputs.clone())
                .unwrap()
        };
        let (off, on) = (terms(0.0), terms(3.0));
        assert!(off.get("nvs_laplacian").is_none() && off.get("gs_laplacian").is_none());
        let term = on.get("gs_laplacian").unwrap().clone().into_scalar::<f64>();
        assert!((term - f64::from(want)).abs() < 1e-6, "{term}");
        let (total, mse) = (
            on.total.into_scalar::<f64>(),
            off.total.into_scalar::<f64>(),
        );
        assert!((total - (mse + 1.5 * 3.0 * term)).abs() < 1e-6, "{total}");
        // `gs_laplacian` weighs `L_gs`'s term alone: 3 in `L_nvs`, 2 in `L_gs` (weight 0.5).
        let apart = Objective::new(weights(3.0).with_gs_laplacian(Some(2.0)), None)
            .unwrap()
            .forward(inputs.clone())
            .unwrap()
            .total
            .into_scalar::<f64>();
        assert!(
            (apart - (mse + (3.0 + 0.5 * 2.0) * term)).abs() < 1e-6,
            "{apart}"
        );
    }

    /// `truth` with channel 0's pixel (2, 1) 0.1 brighter, in images `w` pixels wide.
    fn with_spot(truth: &[f32], w: usize) -> Vec<f32> {
        let mut spot = truth.to_vec();
        spot[2 * w + 1] += 0.1;
        spot
    }

    #[test]
    fn holes_loss_is_the_error_averaged_over_the_weighted_pixels() {
        let device = BackendKind::Ndarray.device().unwrap();
        // One 2 x 2 image: errors 0.1, 0.2, 0.3, 0.4 (every channel); weights 1, 0.5, 0, 0.
        let pred: Vec<f32> = (0..12).map(|i| 0.1 * (i % 4 + 1) as f32).collect();
        let pred = Tensor::<4>::from_data(TensorData::new(pred, [1, 3, 2, 2]), &device);
        let gt = Tensor::<4>::zeros([1, 3, 2, 2], &device);
        let w = Tensor::<4>::from_data(
            TensorData::new(vec![1.0f32, 0.5, 0.0, 0.0], [1, 1, 2, 2]),
            &device,
        );
        let value = holes_loss(pred.clone(), gt.clone(), w.clone()).into_scalar::<f64>();
        let expected = 3.0 * (0.01 + 0.5 * 0.04) / (3.0 * 1.5 + 1.0);
        assert!((value - expected).abs() < 1e-7, "{value} vs {expected}");
        // Without holes the term is 0; the objective computes it only when weighted.
        let none = holes_loss(pred.clone(), gt.clone(), w.clone().zeros_like());
        assert_eq!(none.into_scalar::<f64>(), 0.0);
        let inputs = LossInputs::new()
            .with_target(gt)
            .with_nvs(pred)
            .with_nvs_holes(w);
        let weights = |holes: f64| LossWeights::new().with_lpips(0.0).with_nvs_holes(holes);
        let off = Objective::new(weights(0.0), None)
            .unwrap()
            .forward(inputs.clone())
            .unwrap();
        assert!(off.get("nvs_holes").is_none());
        let on = Objective::new(weights(2.0), None)
            .unwrap()
            .forward(inputs)
            .unwrap();
        let term = on.get("nvs_holes").unwrap().clone().into_scalar::<f64>();
        assert!((term - expected).abs() < 1e-7);
        let total = on.total.into_scalar::<f64>();
        let mse = off.total.into_scalar::<f64>();
        assert!((total - (mse + 2.0 * expected)).abs() < 1e-6, "{total}");
    }
}
