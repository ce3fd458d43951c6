//! A camera as a JSON record: the entries of a dataset's `cameras.json` and the camera files
//! that `prism splat` and `prism infer` read.

use serde::{Deserialize, Serialize};

use crate::camera::{Camera, Intrinsics, mat4_from_rows};
use crate::protocol::ViewAngles;

/// A camera as JSON: one entry of a dataset's `cameras.json` (a JSON array of them, one per
/// view, in view order), and the camera file of `prism splat` / `prism infer`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraRecord {
    /// View index (may be left out of a single-view file).
    #[serde(default)]
    pub index: usize,
    /// Yaw of the view on the protocol's sphere, degrees (informational).
    #[serde(default)]
    pub yaw_deg: f32,
    /// Pitch of the view, degrees (informational).
    #[serde(default)]
    pub pitch_deg: f32,
    /// Focal length x, pixels.
    pub fx: f32,
    /// Focal length y, pixels.
    pub fy: f32,
    /// Principal point x, pixels.
    pub cx: f32,
    /// Principal point y, pixels.
    pub cy: f32,
    /// Camera-to-world 4x4, row-major, OpenCV axes.
    pub c2w: [[f32; 4]; 4],
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
}

impl CameraRecord {
    /// The record of a protocol view seen by `camera`.
    pub fn new(view: &ViewAngles, camera: &Camera) -> Self {
        let k = camera.intrinsics;
        Self {
            index: view.index,
            yaw_deg: view.yaw_deg,
            pitch_deg: view.pitch_deg,
            fx: k.fx,
            fy: k.fy,
            cx: k.cx,
            cy: k.cy,
            c2w: camera.c2w_rows(),
            width: k.width,
            height: k.height,
        }
    }

    /// Checks that the record is a sane pinhole camera: a non-empty image, positive finite
    /// focal lengths, a finite principal point, and a rigid `c2w` (proper rotation, last row
    /// `[0, 0, 0, 1]`).
    ///
    /// # Errors
    /// A message naming the bad value.
    pub fn validate(&self) -> Result<(), String> {
        if self.width == 0 || self.height == 0 {
            return Err(format!("empty image size {}x{}", self.width, self.height));
        }
        for (name, v) in [("fx", self.fx), ("fy", self.fy)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{name} = {v} is not a positive focal length"));
            }
        }
        for (name, v) in [("cx", self.cx), ("cy", self.cy)] {
            if !v.is_finite() {
                return Err(format!("{name} = {v} is not finite"));
            }
        }
        if self.c2w.iter().flatten().any(|v| !v.is_finite()) {
            return Err("c2w has a non-finite entry".into());
        }
        if self.c2w[3] != [0.0, 0.0, 0.0, 1.0] {
            return Err(format!(
                "the last row of c2w must be [0, 0, 0, 1], found {:?}",
                self.c2w[3]
            ));
        }
        let r = glam::Mat3::from_mat4(mat4_from_rows(&self.c2w));
        let off = (r.transpose() * r - glam::Mat3::IDENTITY)
            .to_cols_array()
            .iter()
            .fold(0.0f32, |m, v| m.max(v.abs()));
        if off > 1e-3 || (r.determinant() - 1.0).abs() > 1e-3 {
            return Err("c2w is not a rigid camera-to-world transform (its rotation is not a proper rotation)".into());
        }
        Ok(())
    }

    /// The camera this record describes (see [`CameraRecord::validate`] for checking it).
    pub fn camera(&self) -> Camera {
        let k = Intrinsics {
            fx: self.fx,
            fy: self.fy,
            cx: self.cx,
            cy: self.cy,
            width: self.width,
            height: self.height,
        };
        Camera::new(k, mat4_from_rows(&self.c2w))
    }
}
