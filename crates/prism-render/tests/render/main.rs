//! prism-render's integration tests, as one test binary: the splatting rasterizer (forward
//! values, gradients, fitting, the device kernels against the host), triplanes, position maps and
//! PLY files. One binary links the Burn stack once, and its tests share the two cores.

mod common;
mod ply;
mod position_map;
mod splat_device;
mod splat_fit;
mod splat_forward;
mod splat_gradients;
mod triplane;
