//! Geometry operations on a served device (Burn's remote backend, `prism serve`).
//!
//! prism's geometry operations are backend extensions of the backends that run locally
//! (flex, ndarray, CubeCL); a served device is none of them. On such a device an operation
//! runs on this machine's CPU instead: its inputs are moved here, the operation runs on flex,
//! its outputs go back. Autodiff follows the moves (Burn's differentiable cross-backend
//! transfer), so the operation's gradient reaches the served tensors.

use burn::tensor::Device;
use prism_core::backend::is_served;

/// The device a geometry operation on `device` runs on instead: `None` where prism's backend
/// extensions cover `device`; this machine's flex device (with `device`'s autodiff) for a
/// served device.
pub(crate) fn host_for(device: &Device) -> Option<Device> {
    is_served(device).then(|| Device::flex().with_autodiff_context_from(device))
}
