//! A procedural humanoid in SMPL-X's layout, so that prism runs and is tested without the
//! licensed SMPL-X files.
//!
//! Rest pose: a T-pose (arms horizontal along +-X, palms down, thumbs forward), Y-up, facing
//! +Z, the subject's left on +X, feet flat on `y = 0`; about 1.76 m to the top of the head.
//! The joints follow SMPL-X's order and parents (55: body, jaw, eyes, 3 joints per finger);
//! their rest frames are aligned with the world axes, as in SMPL-X, so that a pose means the
//! same rotation in both models.
//!
//! The body is made of closed parts that overlap at the joints (torso, neck, head with a face,
//! two eyeballs, upper limbs, palms, five fingers per hand, legs, feet): about 5,700 vertices.
//! - shape blend shapes (10): stature, girth, leg length, arm length, shoulder width, hip
//!   width, torso length, bust, belly, head size;
//! - expression blend shapes (10) on the face: smile, lips apart, brows raised, brows furrowed,
//!   pucker, mouth corners down, cheeks puffed, half smile, squint, chin forward;
//! - skinning weights blend smoothly between consecutive joints and sum to 1;
//! - the joint regressor's rows are convex combinations of the vertices around each joint;
//! - pose correctives bulge elbows, knees, hips and shoulders as they bend.
//!
//! The seed jitters the proportions by a few percent; every seed has the same topology.

mod head;
mod parts;
mod proportions;
mod rig;
mod shape;
mod skeleton;
mod tube;

use super::joints::{NUM_BETAS, NUM_EXPRESSION, NUM_JOINTS, smplx_parents};
use super::model::{BodyArrays, BodyModel, NUM_SHAPE_COEFFS};
use parts::Assembly;
use proportions::Proportions;

/// The `model` string of [`crate::BodyParams`] for the procedural model of `seed`.
pub fn model_name(seed: u64) -> String {
    format!("procedural:{seed}")
}

/// The seed of a `procedural:SEED` model name, `None` for other names (paths).
pub fn parse_model_name(name: &str) -> Option<u64> {
    name.strip_prefix("procedural:")?.parse().ok()
}

impl BodyModel {
    /// The procedural humanoid of `seed` (see the module docs), deterministic in the seed.
    pub fn procedural(seed: u64) -> BodyModel {
        let assembly = Assembly::build(&Proportions::from_seed(seed));
        let v = assembly.vertices.len();
        let shape = shape::shape_directions(&assembly);
        let expression = shape::expression_directions(&assembly);
        let mut shapedirs = vec![0.0f32; v * 3 * NUM_SHAPE_COEFFS];
        for i in 0..v {
            for d in 0..3 {
                let row = &mut shapedirs
                    [(i * 3 + d) * NUM_SHAPE_COEFFS..(i * 3 + d + 1) * NUM_SHAPE_COEFFS];
                for k in 0..NUM_BETAS {
                    row[k] = shape[i][k][d];
                }
                for k in 0..NUM_EXPRESSION {
                    row[NUM_BETAS + k] = expression[i][k][d];
                }
            }
        }
        let mut weights = vec![0.0f32; v * NUM_JOINTS];
        for (i, vert) in assembly.vertices.iter().enumerate() {
            let total: f32 = vert.weights.iter().map(|(_, w)| w).sum();
            for (j, w) in &vert.weights {
                weights[i * NUM_JOINTS + j] += w / total;
            }
        }
        let arrays = BodyArrays {
            v_template: assembly.vertices.iter().map(|v| v.position).collect(),
            faces: assembly.faces.clone(),
            shapedirs,
            posedirs: rig::pose_correctives(&assembly),
            j_regressor: rig::joint_regressor(&assembly),
            weights,
            parents: smplx_parents(),
        };
        BodyModel::from_arrays(arrays)
            .expect("the procedural model is consistent")
            .with_name(model_name(seed))
    }
}

#[cfg(test)]
mod tests;
