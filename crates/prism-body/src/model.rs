//! The body model in SMPL-X's layout: template, faces, blend shapes, joint regressor, skinning
//! weights and kinematic tree.

use std::path::Path;

use glam::Vec3;

use super::error::{BodyError, memory_path};
use super::joints::{NUM_BETAS, NUM_EXPRESSION, NUM_JOINTS, NUM_POSE_FEATURES, SMPLX_PARENTS};

/// Number of blend-shape coefficients stored per vertex: 10 shape, then 10 expression.
pub const NUM_SHAPE_COEFFS: usize = NUM_BETAS + NUM_EXPRESSION;

/// A body model with SMPL-X's arrays (`.npz` keys in brackets), restricted to what prism uses:
/// 10 shape and 10 expression components.
///
/// Dense arrays are row-major, as numpy stores them:
/// - `v_template` `[V, 3]`: the rest-pose template;
/// - `f` `[F, 3]`: triangles;
/// - `shapedirs` `[V, 3, 20]`: shape directions 0..10 followed by expression directions 0..10
///   (taken from `[V, 3, 400]` files at 0..10 and 300..310, from `[V, 3, 20]` files as they are);
/// - `posedirs` `[V, 3, 486]`: pose-corrective directions, applied to the pose feature;
/// - `J_regressor` `[55, V]`: rest joints as linear combinations of the shaped vertices;
/// - `weights` `[V, 55]`: linear-blend-skinning weights;
/// - `kintree_table` `[2, 55]`: row 0 the parents (root -1).
#[derive(Clone, Debug, PartialEq)]
pub struct BodyModel {
    pub(crate) name: String,
    pub(crate) v_template: Vec<Vec3>,
    pub(crate) faces: Vec<[u32; 3]>,
    pub(crate) shapedirs: Vec<f32>,
    pub(crate) posedirs: Vec<f32>,
    pub(crate) j_regressor: Vec<f32>,
    pub(crate) weights: Vec<f32>,
    pub(crate) parents: Vec<Option<usize>>,
}

/// The raw arrays of a body model before validation (see [`BodyModel::from_arrays`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BodyArrays {
    /// `[V, 3]` rest template.
    pub v_template: Vec<Vec3>,
    /// `[F, 3]` triangles.
    pub faces: Vec<[u32; 3]>,
    /// `[V, 3, 20]` shape (0..10) and expression (10..20) directions, row-major.
    pub shapedirs: Vec<f32>,
    /// `[V, 3, 486]` pose-corrective directions, row-major.
    pub posedirs: Vec<f32>,
    /// `[55, V]` joint regressor, row-major.
    pub j_regressor: Vec<f32>,
    /// `[V, 55]` skinning weights, row-major.
    pub weights: Vec<f32>,
    /// Parent of each of the 55 joints (`None` for the root).
    pub parents: Vec<Option<usize>>,
}

impl BodyModel {
    /// A model from its arrays, checked for consistent shapes, a valid kinematic tree (parents
    /// before children) and face indices in range.
    ///
    /// # Errors
    /// [`BodyError::Shape`] or [`BodyError::Value`] naming the offending array.
    pub fn from_arrays(arrays: BodyArrays) -> Result<Self, BodyError> {
        Self::from_arrays_at(arrays, &memory_path())
    }

    /// The model's name, as `body.json` records it: `procedural:SEED`, the path it was loaded
    /// from, or `custom` for models built from arrays.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The same model under another name.
    pub fn with_name(mut self, name: impl Into<String>) -> Self {
        self.name = name.into();
        self
    }

    pub(crate) fn from_arrays_at(arrays: BodyArrays, path: &Path) -> Result<Self, BodyError> {
        let v = arrays.v_template.len() as u64;
        let j = NUM_JOINTS as u64;
        let shape_err = |key: &str, expected: String, actual: Vec<u64>| BodyError::Shape {
            path: path.to_path_buf(),
            key: key.to_string(),
            expected,
            actual,
        };
        if v == 0 {
            return Err(shape_err(
                "v_template",
                "[V, 3] with V > 0".into(),
                vec![0, 3],
            ));
        }
        let checks: [(&str, usize, u64, Vec<u64>); 4] = [
            (
                "shapedirs",
                arrays.shapedirs.len(),
                3 * NUM_SHAPE_COEFFS as u64,
                vec![v, 3, NUM_SHAPE_COEFFS as u64],
            ),
            (
                "posedirs",
                arrays.posedirs.len(),
                3 * NUM_POSE_FEATURES as u64,
                vec![v, 3, NUM_POSE_FEATURES as u64],
            ),
            ("J_regressor", arrays.j_regressor.len(), j, vec![j, v]),
            ("weights", arrays.weights.len(), j, vec![v, j]),
        ];
        for (key, len, per_vertex, expected) in checks {
            if len as u64 != v * per_vertex {
                return Err(shape_err(
                    key,
                    format!("{expected:?} with V = {v}"),
                    vec![len as u64],
                ));
            }
        }
        if arrays.parents.len() != NUM_JOINTS {
            return Err(shape_err(
                "kintree_table",
                format!("[2, {NUM_JOINTS}]"),
                vec![2, arrays.parents.len() as u64],
            ));
        }
        let value_err = |key: &str, message: String| BodyError::Value {
            path: path.to_path_buf(),
            key: key.to_string(),
            message,
        };
        for (i, p) in arrays.parents.iter().enumerate() {
            match (i, p) {
                (0, None) => {}
                (0, Some(p)) => {
                    return Err(value_err(
                        "kintree_table",
                        format!("the root (joint 0) has parent {p}, expected -1"),
                    ));
                }
                (_, None) => {
                    return Err(value_err(
                        "kintree_table",
                        format!("joint {i} has no parent (only joint 0 may be the root)"),
                    ));
                }
                (_, Some(p)) if *p >= i => {
                    return Err(value_err(
                        "kintree_table",
                        format!(
                            "joint {i} has parent {p}: parents must come before their children"
                        ),
                    ));
                }
                _ => {}
            }
        }
        if let Some((fi, tri)) = arrays
            .faces
            .iter()
            .enumerate()
            .find(|(_, t)| t.iter().any(|&k| k as u64 >= v))
        {
            return Err(value_err(
                "f",
                format!("face {fi} {tri:?} indexes past the {v} vertices"),
            ));
        }
        Ok(Self {
            name: if path == memory_path() {
                "custom".to_string()
            } else {
                path.display().to_string()
            },
            v_template: arrays.v_template,
            faces: arrays.faces,
            shapedirs: arrays.shapedirs,
            posedirs: arrays.posedirs,
            j_regressor: arrays.j_regressor,
            weights: arrays.weights,
            parents: arrays.parents,
        })
    }

    /// The model's arrays (the inverse of [`BodyModel::from_arrays`]).
    pub fn into_arrays(self) -> BodyArrays {
        BodyArrays {
            v_template: self.v_template,
            faces: self.faces,
            shapedirs: self.shapedirs,
            posedirs: self.posedirs,
            j_regressor: self.j_regressor,
            weights: self.weights,
            parents: self.parents,
        }
    }

    /// Number of vertices `V`.
    pub fn num_vertices(&self) -> usize {
        self.v_template.len()
    }

    /// The rest-pose template `[V]`.
    pub fn v_template(&self) -> &[Vec3] {
        &self.v_template
    }

    /// The triangles `[F]`.
    pub fn faces(&self) -> &[[u32; 3]] {
        &self.faces
    }

    /// Shape (0..10) and expression (10..20) directions, `[V, 3, 20]` row-major.
    pub fn shapedirs(&self) -> &[f32] {
        &self.shapedirs
    }

    /// Pose-corrective directions, `[V, 3, 486]` row-major.
    pub fn posedirs(&self) -> &[f32] {
        &self.posedirs
    }

    /// The joint regressor, `[55, V]` row-major.
    pub fn j_regressor(&self) -> &[f32] {
        &self.j_regressor
    }

    /// Skinning weights, `[V, 55]` row-major.
    pub fn weights(&self) -> &[f32] {
        &self.weights
    }

    /// The skinning weights of vertex `v` (55 values).
    pub fn vertex_weights(&self, v: usize) -> &[f32] {
        &self.weights[v * NUM_JOINTS..(v + 1) * NUM_JOINTS]
    }

    /// Parent of each joint (`None` for the root).
    pub fn parents(&self) -> &[Option<usize>] {
        &self.parents
    }

    /// Whether the kinematic tree is SMPL-X's.
    pub fn has_smplx_tree(&self) -> bool {
        self.parents
            .iter()
            .zip(SMPLX_PARENTS)
            .all(|(p, q)| p.map_or(-1, |p| p as i32) == q)
    }

    /// The template deformed by shape and expression blend shapes:
    /// `v_shaped = v_template + sum_k beta_k S_k + sum_k psi_k E_k`.
    pub fn shaped(
        &self,
        betas: &[f32; NUM_BETAS],
        expression: &[f32; NUM_EXPRESSION],
    ) -> Vec<Vec3> {
        let mut coeffs = [0.0f32; NUM_SHAPE_COEFFS];
        coeffs[..NUM_BETAS].copy_from_slice(betas);
        coeffs[NUM_BETAS..].copy_from_slice(expression);
        self.v_template
            .iter()
            .enumerate()
            .map(|(v, t)| {
                let mut out = *t;
                for d in 0..3 {
                    let row = &self.shapedirs
                        [(v * 3 + d) * NUM_SHAPE_COEFFS..(v * 3 + d + 1) * NUM_SHAPE_COEFFS];
                    out[d] += row.iter().zip(&coeffs).map(|(a, b)| a * b).sum::<f32>();
                }
                out
            })
            .collect()
    }

    /// Joints regressed from vertices: `J = J_regressor * vertices`.
    pub fn regress_joints(&self, vertices: &[Vec3]) -> Vec<Vec3> {
        let v = self.num_vertices();
        (0..NUM_JOINTS)
            .map(|j| {
                let row = &self.j_regressor[j * v..(j + 1) * v];
                row.iter()
                    .zip(vertices)
                    .filter(|(w, _)| **w != 0.0)
                    .fold(Vec3::ZERO, |acc, (w, p)| acc + *w * *p)
            })
            .collect()
    }

    /// The rest joints of the template (zero shape and expression).
    pub fn rest_joints(&self) -> Vec<Vec3> {
        self.regress_joints(&self.v_template)
    }
}
