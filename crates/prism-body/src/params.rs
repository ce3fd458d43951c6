//! Body parameters: the `body.json` of a dataset subject.
//!
//! ```json
//! { "model": "procedural:0", "betas": [10 numbers], "pose": [55 x [x, y, z]],
//!   "expression": [10 numbers], "scale": 1.0, "transl": [x, y, z] }
//! ```
//!
//! `model` names the body model (`procedural:SEED` for [`BodyModel::procedural`], otherwise a
//! path to an SMPL-X `.npz`); `pose` is axis-angle per joint in SMPL-X order (global orientation,
//! 21 body joints, jaw, left eye, right eye, 15 left-hand, 15 right-hand joints), relative to
//! the parent joint; the posed body model maps to the world as
//! `world = scale * posed + transl`.

use std::path::Path;

use glam::{Mat4, Vec3};
use serde::{Deserialize, Serialize};

use super::error::{BodyError, memory_path};
use super::joints::{NUM_BETAS, NUM_EXPRESSION, NUM_JOINTS};
#[allow(unused_imports)]
use super::model::BodyModel;

/// Parameters of one posed body: shape, pose, expression and the subject-to-world similarity.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "RawBodyParams", into = "RawBodyParams")]
pub struct BodyParams {
    /// The body model: `procedural:SEED` or the path of an SMPL-X `.npz`.
    pub model: String,
    /// Shape coefficients.
    pub betas: [f32; NUM_BETAS],
    /// Axis-angle rotation of each joint relative to its parent, SMPL-X order.
    pub pose: [[f32; 3]; NUM_JOINTS],
    /// Expression coefficients.
    pub expression: [f32; NUM_EXPRESSION],
    /// Uniform scale from the body model's frame to the world.
    pub scale: f32,
    /// Translation applied after scaling: `world = scale * posed + transl`.
    pub transl: [f32; 3],
}

/// The JSON form, validated into [`BodyParams`].
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawBodyParams {
    model: String,
    betas: Vec<f32>,
    pose: Vec<Vec<f32>>,
    expression: Vec<f32>,
    scale: f32,
    transl: Vec<f32>,
}

impl TryFrom<RawBodyParams> for BodyParams {
    type Error = String;

    fn try_from(raw: RawBodyParams) -> Result<Self, String> {
        let fixed = |name: &str, v: &[f32], n: usize| -> Result<(), String> {
            if v.len() != n {
                return Err(format!("`{name}` has {} values, expected {n}", v.len()));
            }
            if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                return Err(format!("`{name}[{i}]` is not a finite number"));
            }
            Ok(())
        };
        fixed("betas", &raw.betas, NUM_BETAS)?;
        fixed("expression", &raw.expression, NUM_EXPRESSION)?;
        fixed("transl", &raw.transl, 3)?;
        if raw.pose.len() != NUM_JOINTS {
            return Err(format!(
                "`pose` has {} joints, expected {NUM_JOINTS} (SMPL-X order, axis-angle)",
                raw.pose.len()
            ));
        }
        let mut pose = [[0.0f32; 3]; NUM_JOINTS];
        for (j, r) in raw.pose.iter().enumerate() {
            fixed(&format!("pose[{j}]"), r, 3)?;
            pose[j].copy_from_slice(r);
        }
        if !(raw.scale.is_finite() && raw.scale > 0.0) {
            return Err(format!(
                "`scale` is {}, expected a positive number",
                raw.scale
            ));
        }
        let mut betas = [0.0; NUM_BETAS];
        betas.copy_from_slice(&raw.betas);
        let mut expression = [0.0; NUM_EXPRESSION];
        expression.copy_from_slice(&raw.expression);
        Ok(Self {
            model: raw.model,
            betas,
            pose,
            expression,
            scale: raw.scale,
            transl: [raw.transl[0], raw.transl[1], raw.transl[2]],
        })
    }
}

impl From<BodyParams> for RawBodyParams {
    fn from(p: BodyParams) -> Self {
        Self {
            model: p.model,
            betas: p.betas.to_vec(),
            pose: p.pose.iter().map(|r| r.to_vec()).collect(),
            expression: p.expression.to_vec(),
            scale: p.scale,
            transl: p.transl.to_vec(),
        }
    }
}

impl BodyParams {
    /// The rest pose of `model` (all coefficients and rotations zero, scale 1, no translation).
    pub fn rest(model: impl Into<String>) -> Self {
        Self {
            model: model.into(),
            betas: [0.0; NUM_BETAS],
            pose: [[0.0; 3]; NUM_JOINTS],
            expression: [0.0; NUM_EXPRESSION],
            scale: 1.0,
            transl: [0.0; 3],
        }
    }

    /// The subject-to-world similarity `world = scale * posed + transl` as a matrix.
    pub fn world_transform(&self) -> Mat4 {
        Mat4::from_translation(Vec3::from_array(self.transl))
            * Mat4::from_scale(Vec3::splat(self.scale))
    }

    /// These parameters seen through a further placement `m` (a uniform scale followed by a
    /// translation, e.g. [`crate::Placement::transform`]): the result maps the body model to
    /// `m * world`, i.e. `scale' = s_m * scale`, `transl' = s_m * transl + t_m`.
    pub fn placed(&self, m: Mat4) -> Self {
        let s = m.x_axis.truncate().length();
        let t = m.w_axis.truncate();
        let transl = s * Vec3::from_array(self.transl) + t;
        Self {
            scale: s * self.scale,
            transl: transl.to_array(),
            ..self.clone()
        }
    }

    /// Parses `body.json` text; `path` names the source in errors.
    ///
    /// # Errors
    /// [`BodyError::Params`] naming the file and the bad field.
    pub fn from_json(text: &str, path: &Path) -> Result<Self, BodyError> {
        serde_json::from_str(text).map_err(|e| BodyError::Params {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
    }

    /// Reads and validates a `body.json`.
    ///
    /// # Errors
    /// When the file cannot be read or is not valid body parameters.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, BodyError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|source| BodyError::Io {
            path: path.to_path_buf(),
            error: source,
        })?;
        Self::from_json(&text, path)
    }

    /// The parameters as pretty JSON.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("body parameters serialize")
    }

    /// Writes `body.json` atomically (temporary file, then rename).
    ///
    /// # Errors
    /// When the file cannot be written.
    pub fn save(&self, path: impl AsRef<Path>) -> Result<(), BodyError> {
        let path = path.as_ref();
        let text = self.to_json();
        prism_core::files::write_bytes(path, text.as_bytes()).map_err(|source| BodyError::Io {
            path: path.to_path_buf(),
            error: source,
        })
    }

    /// Checks the parameters in memory (finite values, positive scale), as loading does.
    ///
    /// # Errors
    /// [`BodyError::Params`] naming the bad field.
    pub fn validate(&self) -> Result<(), BodyError> {
        BodyParams::try_from(RawBodyParams::from(self.clone()))
            .map(|_| ())
            .map_err(|message| BodyError::Params {
                path: memory_path(),
                message,
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_round_trip_and_length_errors() {
        let mut p = BodyParams::rest("procedural:3");
        p.betas[2] = 0.5;
        p.pose[18] = [0.0, -1.2, 0.1];
        p.expression[9] = -0.25;
        p.scale = 1.1;
        p.transl = [0.05, 0.0, -0.02];
        let json = p.to_json();
        let back = BodyParams::from_json(&json, Path::new("body.json")).unwrap();
        assert_eq!(back, p);

        let mut v: serde_json::Value = serde_json::from_str(&json).unwrap();
        v["pose"].as_array_mut().unwrap().pop();
        let err = BodyParams::from_json(&v.to_string(), Path::new("s/body.json")).unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.contains("s/body.json") && msg.contains("`pose` has 54 joints"),
            "{msg}"
        );

        let mut v: serde_json::Value = serde_json::from_str(&json).unwrap();
        v["betas"] = serde_json::json!([1.0, 2.0]);
        let msg = BodyParams::from_json(&v.to_string(), Path::new("b.json"))
            .unwrap_err()
            .to_string();
        assert!(msg.contains("`betas` has 2 values, expected 10"), "{msg}");

        let mut v: serde_json::Value = serde_json::from_str(&json).unwrap();
        v["pose"][3] = serde_json::json!([1.0]);
        let msg = BodyParams::from_json(&v.to_string(), Path::new("b.json"))
            .unwrap_err()
            .to_string();
        assert!(msg.contains("`pose[3]` has 1 values, expected 3"), "{msg}");

        let mut v: serde_json::Value = serde_json::from_str(&json).unwrap();
        v["scale"] = serde_json::json!(0.0);
        assert!(BodyParams::from_json(&v.to_string(), Path::new("b.json")).is_err());
    }

    #[test]
    fn placement_composes_with_the_subject_transform() {
        let mut p = BodyParams::rest("procedural:0");
        p.scale = 2.0;
        p.transl = [0.0, 0.1, 0.0];
        let m =
            Mat4::from_translation(Vec3::new(0.05, 0.0, -0.1)) * Mat4::from_scale(Vec3::splat(0.9));
        let q = p.placed(m);
        let x = Vec3::new(0.3, 1.2, -0.4);
        let expected = m.transform_point3(p.world_transform().transform_point3(x));
        let got = q.world_transform().transform_point3(x);
        assert!(
            (got - expected).length() < 1e-5,
            "{got} vs {expected}, {q:?}"
        );
    }
}
