//! Differentiable 3D Gaussian splatting (Kerbl et al. 2023) on Burn tensors.
//!
//! - [`render()`] draws `B x N` [`Gaussians`] into `B` cameras and returns [`Rendered`] features,
//!   alpha and depth; on an autodiff device it is differentiable with respect to every Gaussian
//!   parameter (a custom backward pass, see [`op`]).
//! - [`ply`] reads and writes the standard 3DGS PLY layout ([`GaussianCloud`]);
//!   [`snapshot`] renders one to an RGB image, in a camera read by [`camera_file`].
//!
//! The CPU backends render on the host (parallel over tiles, `host`), the GPU backends in
//! CubeCL kernels on the device (`device`), from one definition of the constants and tile size.

pub mod camera_file;
#[cfg(any(feature = "wgpu", feature = "cuda"))]
mod device;
mod host;
pub mod op;
pub mod ply;
pub mod render;
pub mod snapshot;

pub use camera_file::read_camera;
pub use host::{
    DILATION, EXTENT_SIGMAS, MAX_ALPHA, MIN_ALPHA, MIN_TRANSMITTANCE, NEAR_PLANE, TILE_SIZE,
};
pub use ply::{GaussianCloud, SH_C0};
pub use render::{Gaussians, Rendered, background, render};
pub use snapshot::{parse_background, render_cloud, save_png};
