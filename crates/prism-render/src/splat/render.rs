//! The differentiable Gaussian renderer on Burn tensors: [`Gaussians`] in, [`Rendered`] out.

use std::sync::Arc;

use burn::backend::Dispatch;
use burn::tensor::{Tensor, TensorData};
use prism_core::Camera;

use super::op::{SplatBackend, SplatCameras, SplatInputs};
use crate::RenderError;

/// `B x N` 3D Gaussians: `N` per batch element, each batch element seen by its own camera.
///
/// The parameters are the raw, unconstrained ones (as in a 3DGS PLY file), so that a network
/// head or an optimizer can produce them directly:
/// `scale = exp(log_scales)`, `rotation = rotations / |rotations|` (quaternion `w x y z`),
/// `opacity = sigmoid(opacity_logits)`.
#[derive(Clone, Debug)]
pub struct Gaussians {
    /// `[B, N, 3]` world-space centres (metres).
    pub means: Tensor<3>,
    /// `[B, N, 3]` natural log of the scales along the Gaussian's own axes.
    pub log_scales: Tensor<3>,
    /// `[B, N, 4]` rotation quaternions `w x y z`, any non-zero length.
    pub rotations: Tensor<3>,
    /// `[B, N, 1]` opacities before the sigmoid.
    pub opacity_logits: Tensor<3>,
    /// `[B, N, C]` features (or colours) composited into the image.
    pub features: Tensor<3>,
}

impl Gaussians {
    /// `[B, N, C]`, after checking that every tensor fits.
    ///
    /// # Errors
    /// [`RenderError::Input`] naming the tensor whose shape is wrong.
    pub fn dims(&self) -> Result<[usize; 3], RenderError> {
        let [b, n, c] = self.features.dims();
        let expect = |name: &str, dims: [usize; 3], last: usize| {
            if dims == [b, n, last] {
                Ok(())
            } else {
                Err(RenderError::Input(format!(
                    "{name} has shape {dims:?}, expected [{b}, {n}, {last}] (features are {:?})",
                    [b, n, c]
                )))
            }
        };
        expect("means", self.means.dims(), 3)?;
        expect("log_scales", self.log_scales.dims(), 3)?;
        expect("rotations", self.rotations.dims(), 4)?;
        expect("opacity_logits", self.opacity_logits.dims(), 1)?;
        if c == 0 {
            return Err(RenderError::Input("features have no channel".into()));
        }
        Ok([b, n, c])
    }
}

/// The output of [`render`] for `B` cameras of `H x W` pixels.
#[derive(Clone, Debug)]
pub struct Rendered {
    /// `[B, C, H, W]`: `sum_i f_i alpha_i T_i`, the features composited over a zero background.
    pub features: Tensor<4>,
    /// `[B, 1, H, W]`: the accumulated opacity `1 - prod_i (1 - alpha_i)`.
    pub alpha: Tensor<4>,
    /// `[B, 1, H, W]`: the expected camera-space depth `z` of the visible surface,
    /// `sum_i alpha_i T_i z_i / sum_i alpha_i T_i`, 0 where nothing is drawn.
    pub depth: Tensor<4>,
}

impl Rendered {
    /// The features over a constant `background` (`[C]`): `features + (1 - alpha) background`.
    pub fn over(&self, background: Tensor<1>) -> Tensor<4> {
        let [c] = background.dims();
        let background = background.reshape([1, c, 1, 1]);
        let rest = self.alpha.clone().neg().add_scalar(1.0);
        self.features.clone() + rest * background
    }
}

/// Alphas under this count as "nothing drawn" for the depth normalisation; any drawn pixel has
/// an alpha of at least 1/255.
const DEPTH_ALPHA_EPS: f32 = 1e-6;

/// Renders `B x N` Gaussians into `B` cameras (camera `b` sees the Gaussians of batch element
/// `b`), differentiably when the tensors are on an autodiff device.
///
/// EWA splatting as in 3DGS (Kerbl et al. 2023): each Gaussian is projected with the Jacobian of
/// the perspective projection, `Σ' = J W Σ W^T J^T + 0.3 I`; it covers the pixels within its
/// 3-sigma ellipse; tiles of 16x16 pixels composite their Gaussians front to back by depth with
/// `alpha = min(0.99, o exp(-d^T Σ'^-1 d / 2))`, skipping alphas below 1/255 and stopping
/// before the transmittance would fall below 1e-4. Gaussians closer than 1 cm to the camera
/// plane are not drawn. Gradients reach means, log-scales, rotations, opacity logits and
/// features (not the cameras).
///
/// # Errors
/// [`RenderError::Input`] when the shapes do not fit, the number of cameras is not `B`, or the
/// cameras do not share one non-empty image size.
pub fn render(gaussians: &Gaussians, cameras: &[Camera]) -> Result<Rendered, RenderError> {
    let [b, _, c] = gaussians.dims()?;
    if b == 0 {
        return Err(RenderError::Input("empty batch".into()));
    }
    if cameras.len() != b {
        return Err(RenderError::Input(format!(
            "{} cameras for a batch of {b}",
            cameras.len()
        )));
    }
    crate::image_size::image_size(cameras)?;
    let inputs = SplatInputs {
        means: gaussians.means.clone().into_dispatch(),
        log_scales: gaussians.log_scales.clone().into_dispatch(),
        rotations: gaussians.rotations.clone().into_dispatch(),
        opacity_logits: gaussians.opacity_logits.clone().into_dispatch(),
        features: gaussians.features.clone().into_dispatch(),
    };
    let cameras = SplatCameras(Arc::from(cameras));
    let out =
        Tensor::<4>::from_dispatch(<Dispatch as SplatBackend>::splat_rasterize(inputs, cameras));
    let features = out.clone().narrow(1, 0, c);
    let alpha = out.clone().narrow(1, c, 1);
    let accumulated_depth = out.narrow(1, c + 1, 1);
    let empty = alpha.clone().lower_elem(DEPTH_ALPHA_EPS);
    let depth =
        (accumulated_depth / alpha.clone().clamp_min(DEPTH_ALPHA_EPS)).mask_fill(empty, 0.0);
    Ok(Rendered {
        features,
        alpha,
        depth,
    })
}

/// A `[C]` tensor from a background colour, for [`Rendered::over`].
pub fn background(values: &[f32], device: &burn::tensor::Device) -> Tensor<1> {
    Tensor::from_data(TensorData::new(values.to_vec(), [values.len()]), device)
}
