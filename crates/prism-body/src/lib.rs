//! The body model: SMPL-X's `.npz` layout, its parameters (`body.json`), linear blend skinning
//! in plain f32 and in Burn tensor ops, and a procedural humanoid with the same layout.
//!
//! The real SMPL-X model is a licensed download: users pass its path. [`BodyModel::procedural`]
//! builds a model with the same arrays and the same 55-joint tree, so that everything runs and
//! is tested without it.

mod error;
pub mod joints;
mod layer;
mod lbs;
mod model;
mod npz;
mod params;
pub mod procedural;
pub mod rotation;
mod transform;

pub use error::BodyError;
pub use joints::{
    Finger, JOINT_NAMES, NUM_BETAS, NUM_EXPRESSION, NUM_JOINTS, NUM_POSE_FEATURES, SMPLX_PARENTS,
    joint,
};
pub use layer::{BodyLayer, BodyOutput, rodrigues};
pub use lbs::{PosedBody, pose_feature};
pub use model::{BodyArrays, BodyModel, NUM_SHAPE_COEFFS};
pub use params::BodyParams;

#[cfg(test)]
mod tests;
