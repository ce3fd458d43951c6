//! One camera view in a JSON file, in the schema of a dataset's `cameras.json` entries:
//!
//! ```json
//! { "index": 0, "yaw_deg": 0.0, "pitch_deg": 0.0,
//!   "fx": 512.0, "fy": 512.0, "cx": 256.0, "cy": 256.0,
//!   "c2w": [[1, 0, 0, 0], [0, -1, 0, 0.9], [0, 0, -1, 2.0], [0, 0, 0, 1]],
//!   "width": 512, "height": 512 }
//! ```
//!
//! This is [`CameraRecord`]: `c2w` is the row-major 4x4 camera-to-world matrix (OpenCV axes);
//! `index`, `yaw_deg` and `pitch_deg` only describe the view and may be left out. Other keys are
//! ignored.

use std::path::Path;

use prism_core::Camera;
use prism_core::CameraRecord;

use crate::RenderError;

/// Reads one camera view from a JSON file.
///
/// # Errors
/// [`RenderError::Io`] or [`RenderError::Format`], naming the file and the problem.
pub fn read_camera(path: impl AsRef<Path>) -> Result<Camera, RenderError> {
    let path = path.as_ref();
    let text = std::fs::read_to_string(path).map_err(|e| RenderError::io(path, e))?;
    let record: CameraRecord = serde_json::from_str(&text)
        .map_err(|e| RenderError::format(path, format!("not a camera view: {e}")))?;
    record
        .validate()
        .map_err(|m| RenderError::format(path, m))?;
    Ok(record.camera())
}

#[cfg(test)]
mod tests {
    use super::*;
    use prism_core::Intrinsics;
    use prism_core::camera::mat4_to_rows;

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
        let record: CameraRecord = serde_json::from_value(json.clone()).unwrap();
        record.validate().unwrap();
        assert_eq!(record.camera(), cam);
        let mut bad = json.clone();
        bad["fx"] = (-1.0).into();
        let record: CameraRecord = serde_json::from_value(bad).unwrap();
        assert!(record.validate().unwrap_err().contains("fx"));
        let mut bad = json;
        bad["c2w"][0][0] = 2.0.into();
        let record: CameraRecord = serde_json::from_value(bad).unwrap();
        assert!(record.validate().unwrap_err().contains("rigid"));
    }
}
