//! Triplane features (EG3D-style neural textures, paper Sec. 3.2 and the supplement): three
//! axis-aligned feature planes over the cube `[-1, 1]^3`, sampled bilinearly at 3D points and
//! summed.
//!
//! `F(x, y, z) = bilinear(P_xy, (x, y)) + bilinear(P_xz, (x, z)) + bilinear(P_yz, (y, z))`,
//! each plane `[C, R, R]` with texel centres at `-1 + (i + 0.5) 2 / R` ("align corners = false")
//! and border padding (coordinates outside `[-1, 1]` read the edge texels); in plane `P_ab` the
//! first axis `a` picks the column and the second `b` the row.
//!
//! Burn's generic `grid_sample_2d` under autodiff is a slow decomposition into gathers, so
//! [`sample_triplane`] is its own operation with a hand-written backward pass (gradients for
//! the planes and the coordinates), computed on the host in parallel for every backend (see
//! [`op`]).

#[cfg(any(feature = "wgpu", feature = "cuda"))]
mod device;
mod host;
pub mod op;

use burn::backend::Dispatch;
use burn::tensor::Tensor;

pub use host::PLANE_AXES;
use op::TriplaneBackend;

use crate::RenderError;

/// Samples the triplane `planes` `[3, C, R, R]` (planes `xy`, `xz`, `yz`) at the points
/// `coords` `[B, 3, H, W]` (`x y z` in `[-1, 1]`): `[B, C, H, W]`, the sum of the three
/// bilinear samples (see the module docs). Differentiable in both inputs on an autodiff device.
///
/// # Errors
/// [`RenderError::Input`] when the shapes are not as above or the tensors' devices differ.
pub fn sample_triplane(planes: Tensor<4>, coords: Tensor<4>) -> Result<Tensor<4>, RenderError> {
    let [three, c, r, r2] = planes.dims();
    if three != 3 || r != r2 || r == 0 || c == 0 {
        return Err(RenderError::Input(format!(
            "triplane planes must be [3, C, R, R], got {:?}",
            planes.dims()
        )));
    }
    let [_, axes, _, _] = coords.dims();
    if axes != 3 {
        return Err(RenderError::Input(format!(
            "triplane coordinates must be [B, 3, H, W], got {:?}",
            coords.dims()
        )));
    }
    let device = planes.device();
    if coords.device() != device {
        return Err(RenderError::Input(
            "triplane planes and coordinates are on different devices".into(),
        ));
    }
    Ok(Tensor::from_dispatch(
        <Dispatch as TriplaneBackend>::triplane_sample(
            planes.into_dispatch(),
            coords.into_dispatch(),
        ),
    ))
}
