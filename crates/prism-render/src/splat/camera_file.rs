//! One camera view in a JSON file, in the schema of a dataset's `cameras.json` entries:
//!
//! ```json
//! { "index": 0, "yaw_deg": 0.0, "pitch_deg": 0.0,
//!   "fx": 512.0, "fy": 512.0, "cx": 256.0, "cy": 256.0,
//!   "c2w": [[1, 0, 0, 0], [0, -1, 0, 0.9], [0, 0, -1, 2.0], [0, 0, 0, 1]],
//!   "width": 512, "height": 512 }
//! ```
//!
//! `c2w` is the row-major 4x4 camera-to-world matrix (OpenCV axes); `index`, `yaw_deg` and
//! `pitch_deg` only describe the view and may be left out. Other keys are ignored.

use std::path::Path;

use prism_data::camera::mat4_from_rows;
use prism_data::{Camera, Intrinsics};
use serde::Deserialize;

use crate::RenderError;

/// The JSON record of one view.
#[derive(Clone, Debug, Deserialize)]
pub struct ViewRecord {
    /// View index in its subject (informational).
    #[serde(default)]
    pub index: u32,
    /// Yaw of the view in degrees (informational).
    #[serde(default)]
    pub yaw_deg: f32,
    /// Pitch of the view in degrees (informational).
    #[serde(default)]
    pub pitch_deg: f32,
    /// Focal length along x, pixels.
    pub fx: f32,
    /// Focal length along y, pixels.
    pub fy: f32,
    /// Principal point x, pixels.
    pub cx: f32,
    /// Principal point y, pixels.
    pub cy: f32,
    /// Row-major camera-to-world matrix.
    pub c2w: [[f32; 4]; 4],
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
}

impl ViewRecord {
    /// The camera, after checking the values.
    ///
    /// # Errors
    /// A message naming the bad value.
    pub fn camera(&self) -> Result<Camera, String> {
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
        let c2w = mat4_from_rows(&self.c2w);
        let r = glam::Mat3::from_mat4(c2w);
        let orthonormal = (r.transpose() * r - glam::Mat3::IDENTITY)
            .to_cols_array()
            .iter()
            .all(|v| v.abs() < 1e-3);
        if !orthonormal
            || (r.determinant() - 1.0).abs() > 1e-3
            || self.c2w[3] != [0.0, 0.0, 0.0, 1.0]
        {
            return Err("c2w is not a rigid camera-to-world transform".into());
        }
        Ok(Camera::new(
            Intrinsics {
                fx: self.fx,
                fy: self.fy,
                cx: self.cx,
                cy: self.cy,
                width: self.width,
                height: self.height,
            },
            c2w,
        ))
    }
}

/// Reads one camera view from a JSON file.
///
/// # Errors
/// [`RenderError::Io`] or [`RenderError::Format`], naming the file and the problem.
pub fn read_camera(path: impl AsRef<Path>) -> Result<Camera, RenderError> {
    let path = path.as_ref();
    let text = std::fs::read_to_string(path).map_err(|e| RenderError::io(path, e))?;
    let record: ViewRecord = serde_json::from_str(&text)
        .map_err(|e| RenderError::format(path, format!("not a camera view: {e}")))?;
    record.camera().map_err(|m| RenderError::format(path, m))
}

#[cfg(test)]
mod tests {
    use super::*;
    use prism_data::camera::mat4_to_rows;

    #[test]
    fn a_view_round_trips_and_bad_values_are_named() {
        let cam = Camera::orbit(
            12.0,
            -5.0,
            2.0,
            glam::Vec3::new(0.0, 0.9, 0.0),
            Intrinsics::protocol_default(32, 24),
        );
        let k = cam.intrinsics;
        let json = serde_json::json!({
            "index": 3, "yaw_deg": 12.0, "pitch_deg": -5.0,
            "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy,
            "c2w": mat4_to_rows(&cam.c2w), "width": 32, "height": 24,
        });
        let record: ViewRecord = serde_json::from_value(json.clone()).unwrap();
        assert_eq!(record.camera().unwrap(), cam);
        let mut bad = json.clone();
        bad["fx"] = (-1.0).into();
        let record: ViewRecord = serde_json::from_value(bad).unwrap();
        assert!(record.camera().unwrap_err().contains("fx"));
        let mut bad = json;
        bad["c2w"][0][0] = 2.0.into();
        let record: ViewRecord = serde_json::from_value(bad).unwrap();
        assert!(record.camera().unwrap_err().contains("rigid"));
    }
}
