//! Moving a body fit with its scan: a similarity applied to the world of a fit, expressed as new
//! body parameters (global orientation, scale, translation), and naming body models.
//!
//! SMPL-X's global rotation `R_0 = rot(pose[0])` turns the body about its root joint `J_0` (the
//! rest pelvis of the shaped body), not about the origin: with `u` the posed vertices without
//! global rotation,
//!
//! `world = s (R_0 (u - J_0) + J_0) + t`.
//!
//! Under a similarity `M = [s_M Q | t_M]` (`Q` a rotation) the same form holds with
//!
//! `R_0' = Q R_0`, `s' = s_M s`, `t' = M (s J_0 + t) - s' J_0`,
//!
//! since `M world = s' (Q R_0 (u - J_0)) + M (s J_0 + t)` and `s J_0 + t` is the root joint in
//! the world (it does not move with `R_0`). `J_0` depends on the shape and expression, so the
//! body model is needed.

use std::path::Path;

use glam::{Mat3, Mat4, Vec3};

use super::error::{BodyError, memory_path};
use super::joints::{NUM_BETAS, NUM_EXPRESSION};
use super::model::BodyModel;
use super::params::BodyParams;
use super::procedural::parse_model_name;
use super::rotation::{axis_angle_to_matrix, matrix_to_axis_angle};

/// Largest deviation of `Q^T Q` from the identity accepted for the rotation of a similarity.
const SIMILARITY_TOLERANCE: f32 = 1e-4;

impl BodyModel {
    /// The model a [`BodyParams::model`] string names: `procedural:SEED` builds the procedural
    /// humanoid, anything else is the path of an SMPL-X-layout `.npz` (relative paths from the
    /// current folder).
    ///
    /// # Errors
    /// A malformed `procedural:` name, or a model file that cannot be loaded.
    pub fn load_named(name: &str) -> Result<Self, BodyError> {
        if let Some(seed) = parse_model_name(name) {
            return Ok(Self::procedural(seed));
        }
        if name.starts_with("procedural:") {
            return Err(BodyError::Params {
                path: memory_path(),
                message: format!("model `{name}`: expected procedural:SEED with an integer seed"),
            });
        }
        Self::load_npz(Path::new(name))
    }

    /// `J_0`, the rest root joint of the body shaped by `betas` and `expression` (the point the
    /// global orientation turns about).
    pub fn root_joint(&self, betas: &[f32; NUM_BETAS], expression: &[f32; NUM_EXPRESSION]) -> Vec3 {
        let v = self.num_vertices();
        let row = &self.j_regressor[..v];
        let shaped = self.shaped(betas, expression);
        row.iter()
            .zip(&shaped)
            .filter(|(w, _)| **w != 0.0)
            .fold(Vec3::ZERO, |acc, (w, p)| acc + *w * *p)
    }
}

impl BodyParams {
    /// These parameters moved by the similarity `m` (uniform scale, rotation, translation):
    /// the body they pose is the original posed body mapped by `m` (see the module docs for the
    /// equations). `model` must be the body model the parameters refer to (it gives `J_0`).
    ///
    /// # Errors
    /// [`BodyError::Params`] when `m` is not a similarity with positive scale and a proper
    /// rotation.
    pub fn transformed(&self, model: &BodyModel, m: Mat4) -> Result<Self, BodyError> {
        let not_similarity = |why: &str| BodyError::Params {
            path: memory_path(),
            message: format!("cannot move the body fit by {m}: {why}"),
        };
        if m.row(3) != glam::Vec4::W || !m.is_finite() {
            return Err(not_similarity("not an affine map"));
        }
        let a = Mat3::from_mat4(m);
        let s_m = a.x_axis.length();
        if s_m <= 0.0 {
            return Err(not_similarity("zero scale"));
        }
        let q = a * (1.0 / s_m);
        let orthogonality = (q.transpose() * q - Mat3::IDENTITY)
            .to_cols_array()
            .iter()
            .fold(0.0f32, |e, x| e.max(x.abs()));
        if orthogonality > SIMILARITY_TOLERANCE || q.determinant() <= 0.0 {
            return Err(not_similarity(
                "not a uniform scale times a proper rotation",
            ));
        }
        let j0 = model.root_joint(&self.betas, &self.expression);
        let root_world = self.scale * j0 + Vec3::from_array(self.transl);
        let scale = s_m * self.scale;
        let transl = m.transform_point3(root_world) - scale * j0;
        let global = q * axis_angle_to_matrix(Vec3::from_array(self.pose[0]));
        let mut pose = self.pose;
        pose[0] = matrix_to_axis_angle(global).to_array();
        Ok(Self {
            pose,
            scale,
            transl: transl.to_array(),
            ..self.clone()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A posed, shaped fit away from the origin, as a scan's fit would be (millimetres).
    fn fit() -> BodyParams {
        let mut p = BodyParams::rest("procedural:0");
        p.betas[0] = 0.8;
        p.betas[3] = -0.5;
        p.expression[1] = 0.6;
        p.pose[0] = [0.3, -0.8, 0.2];
        p.pose[1] = [-0.4, 0.1, 0.0];
        p.pose[16] = [0.0, 0.2, -1.0];
        p.pose[18] = [0.1, -1.1, 0.0];
        p.scale = 950.0;
        p.transl = [120.0, -40.0, 900.0];
        p
    }

    fn max_error(a: &[Vec3], b: &[Vec3]) -> f32 {
        a.iter()
            .zip(b)
            .map(|(x, y)| (*x - *y).length())
            .fold(0.0, f32::max)
    }

    #[test]
    fn transformed_fit_poses_the_mapped_body() {
        let model = BodyModel::load_named("procedural:0").unwrap();
        let fit = fit();
        // Similarities of the four orientations a scan is normalised from (Y up facing +-Z,
        // Z up facing +-X), with a mm -> m scale and a shift, and a general one.
        let z_up = Mat4::from_rotation_x(-std::f32::consts::FRAC_PI_2);
        let mut maps: Vec<(BodyParams, Mat4)> = [
            Mat4::IDENTITY,
            Mat4::from_rotation_y(std::f32::consts::PI),
            Mat4::from_rotation_y(-std::f32::consts::FRAC_PI_2) * z_up,
            Mat4::from_rotation_y(std::f32::consts::FRAC_PI_2) * z_up,
        ]
        .into_iter()
        .map(|orientation| {
            Mat4::from_translation(Vec3::new(0.05, 0.9, -0.08))
                * Mat4::from_scale(Vec3::splat(1.0e-3))
                * orientation
        })
        .map(|m| (fit.clone(), m))
        .collect();
        // A general similarity of a fit in metres.
        let metres = BodyParams {
            scale: 0.95,
            transl: [0.12, -0.04, 0.9],
            ..fit.clone()
        };
        maps.push((
            metres,
            Mat4::from_scale_rotation_translation(
                Vec3::splat(0.7),
                glam::Quat::from_axis_angle(Vec3::new(1.0, 2.0, -0.5).normalize(), 2.9),
                Vec3::new(-3.0, 0.2, 1.0),
            ),
        ));
        for (fit, m) in maps {
            let original = model.pose(&fit).vertices;
            let moved = fit.transformed(&model, m).unwrap();
            moved.validate().unwrap();
            let got = model.pose(&moved).vertices;
            let expected: Vec<Vec3> = original.iter().map(|p| m.transform_point3(*p)).collect();
            let err = max_error(&got, &expected);
            assert!(err < 1e-4, "max error {err} m under {m}");
            // Only the global orientation, scale and translation change.
            assert_eq!(moved.pose[1..], fit.pose[1..]);
            assert_eq!((moved.betas, moved.expression), (fit.betas, fit.expression));
        }
    }

    #[test]
    fn root_joint_is_the_posed_pelvis_and_bad_maps_are_refused() {
        let model = BodyModel::procedural(1);
        let fit = fit();
        let posed = model.lbs(&fit.betas, &fit.pose, &fit.expression);
        let j0 = model.root_joint(&fit.betas, &fit.expression);
        assert!((posed.joints[0] - j0).length() < 1e-6);
        let shear = Mat4::from_cols_array(&[
            1.0, 0.0, 0.0, 0.0, 0.5, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
        ]);
        let mirror = Mat4::from_scale(Vec3::new(-1.0, 1.0, 1.0));
        for m in [shear, mirror, Mat4::ZERO] {
            let e = fit.transformed(&model, m).unwrap_err().to_string();
            assert!(e.contains("cannot move the body fit"), "{e}");
        }
        let e = BodyModel::load_named("procedural:x")
            .unwrap_err()
            .to_string();
        assert!(e.contains("procedural:SEED"), "{e}");
        let e = BodyModel::load_named("/nonexistent/SMPLX.npz")
            .unwrap_err()
            .to_string();
        assert!(e.contains("/nonexistent/SMPLX.npz"), "{e}");
    }
}
