//! Linear blend skinning in plain f32, as SMPL-X defines it (for data generation).
//!
//! 1. `v_shaped = v_template + S beta + E psi` (shape and expression blend shapes);
//! 2. `J = J_regressor v_shaped` (rest joints);
//! 3. `v_posed = v_shaped + P vec(R_1 - I, ..., R_54 - I)` (pose correctives, `P` the posedirs
//!    reshaped `[V*3, 486]`, each `R_j - I` flattened row-major);
//! 4. `G_j = G_parent(j) [R_j | J_j - J_parent(j)]`, `G_0 = [R_0 | J_0]` (kinematic chain);
//! 5. `A_j = G_j [I | -J_j]` and `v = sum_j w_vj A_j v_posed` (skinning).

use glam::{Affine3A, Mat3, Vec3};

use super::joints::{NUM_BETAS, NUM_EXPRESSION, NUM_JOINTS, NUM_POSE_FEATURES};
use super::model::BodyModel;
use super::params::BodyParams;
use super::rotation::axis_angle_to_matrix;

/// A posed body: everything the skinning computed, for drawing and for skinning extra geometry
/// (clothes, hair) with the same joint transforms.
#[derive(Clone, Debug)]
pub struct PosedBody {
    /// The posed vertices `[V]`.
    pub vertices: Vec<Vec3>,
    /// The posed joint positions `[55]`.
    pub joints: Vec<Vec3>,
    /// `G_j`: the world frame of each joint (rotation of its rest-aligned axes and its posed
    /// position).
    pub joint_transforms: Vec<Affine3A>,
    /// `A_j = G_j [I | -J_j]`: maps a point of the shaped rest body that moves rigidly with joint
    /// `j` to its posed position.
    pub skinning_transforms: Vec<Affine3A>,
    /// The shaped rest vertices `v_shaped` (shape and expression, no pose).
    pub shaped: Vec<Vec3>,
    /// The rest joints `J` of the shaped body.
    pub rest_joints: Vec<Vec3>,
}

impl PosedBody {
    /// Skins a point of the shaped rest body with sparse weights `(joint, weight)`:
    /// `sum_j w_j A_j p`.
    pub fn skin_point(&self, point: Vec3, weights: &[(usize, f32)]) -> Vec3 {
        let m = blend(&self.skinning_transforms, weights.iter().copied());
        m.transform_point3(point)
    }

    /// Applies a similarity (or any affine map) to the posed result.
    pub fn transformed(mut self, m: Affine3A) -> Self {
        for v in &mut self.vertices {
            *v = m.transform_point3(*v);
        }
        for j in &mut self.joints {
            *j = m.transform_point3(*j);
        }
        for g in &mut self.joint_transforms {
            *g = m * *g;
        }
        for a in &mut self.skinning_transforms {
            *a = m * *a;
        }
        self
    }
}

/// The weighted sum of affine transforms (a 3x4 matrix, not in general rigid).
fn blend(transforms: &[Affine3A], weights: impl Iterator<Item = (usize, f32)>) -> Affine3A {
    let mut m = Mat3::ZERO;
    let mut t = Vec3::ZERO;
    for (j, w) in weights {
        let a = &transforms[j];
        m += Mat3::from(a.matrix3) * w;
        t += Vec3::from(a.translation) * w;
    }
    Affine3A::from_mat3_translation(m, t)
}

/// The pose feature of SMPL-X: `(R_j - I)` for joints 1..54, each flattened row-major.
pub fn pose_feature(rotations: &[Mat3]) -> [f32; NUM_POSE_FEATURES] {
    let mut out = [0.0f32; NUM_POSE_FEATURES];
    for (j, r) in rotations.iter().enumerate().skip(1) {
        for row in 0..3 {
            for col in 0..3 {
                let identity = if row == col { 1.0 } else { 0.0 };
                out[(j - 1) * 9 + row * 3 + col] = r.col(col)[row] - identity;
            }
        }
    }
    out
}

impl BodyModel {
    /// Linear blend skinning of the model in its own frame (see the module docs).
    pub fn lbs(
        &self,
        betas: &[f32; NUM_BETAS],
        pose: &[[f32; 3]; NUM_JOINTS],
        expression: &[f32; NUM_EXPRESSION],
    ) -> PosedBody {
        let shaped = self.shaped(betas, expression);
        let rest_joints = self.regress_joints(&shaped);
        let rotations: Vec<Mat3> = pose
            .iter()
            .map(|r| axis_angle_to_matrix(Vec3::from_array(*r)))
            .collect();

        // Pose correctives.
        let feature = pose_feature(&rotations);
        let active: Vec<(usize, f32)> = feature
            .iter()
            .copied()
            .enumerate()
            .filter(|(_, f)| *f != 0.0)
            .collect();
        let posed_rest: Vec<Vec3> = shaped
            .iter()
            .enumerate()
            .map(|(v, p)| {
                let mut out = *p;
                for d in 0..3 {
                    let row = &self.posedirs
                        [(v * 3 + d) * NUM_POSE_FEATURES..(v * 3 + d + 1) * NUM_POSE_FEATURES];
                    out[d] += active.iter().map(|(k, f)| row[*k] * f).sum::<f32>();
                }
                out
            })
            .collect();

        // Kinematic chain.
        let mut joint_transforms = vec![Affine3A::IDENTITY; NUM_JOINTS];
        for j in 0..NUM_JOINTS {
            let local_t = match self.parents[j] {
                Some(p) => rest_joints[j] - rest_joints[p],
                None => rest_joints[j],
            };
            let local = Affine3A::from_mat3_translation(rotations[j], local_t);
            joint_transforms[j] = match self.parents[j] {
                Some(p) => joint_transforms[p] * local,
                None => local,
            };
        }
        let skinning_transforms: Vec<Affine3A> = joint_transforms
            .iter()
            .zip(&rest_joints)
            .map(|(g, j)| *g * Affine3A::from_translation(-*j))
            .collect();
        let joints = joint_transforms
            .iter()
            .map(|g| Vec3::from(g.translation))
            .collect();

        // Skinning.
        let vertices = posed_rest
            .iter()
            .enumerate()
            .map(|(v, p)| {
                let w = self.vertex_weights(v);
                let m = blend(
                    &skinning_transforms,
                    w.iter().copied().enumerate().filter(|(_, w)| *w != 0.0),
                );
                m.transform_point3(*p)
            })
            .collect();

        PosedBody {
            vertices,
            joints,
            joint_transforms,
            skinning_transforms,
            shaped,
            rest_joints,
        }
    }

    /// The body of `params` in the world: skinning, then `world = scale * posed + transl`.
    pub fn pose(&self, params: &BodyParams) -> PosedBody {
        let posed = self.lbs(&params.betas, &params.pose, &params.expression);
        let m = Affine3A::from_scale_rotation_translation(
            Vec3::splat(params.scale),
            glam::Quat::IDENTITY,
            Vec3::from_array(params.transl),
        );
        posed.transformed(m)
    }
}
