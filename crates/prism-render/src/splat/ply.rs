//! The standard 3DGS PLY layout (placeholder, filled below).
/// A set of Gaussians as stored in a 3DGS PLY file.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GaussianCloud {}
