//! The image size a batch of cameras renders at, checked the same way by every renderer (and
//! by a server before it runs a trainer's call, see [`crate::served`]).

use prism_core::Camera;

use crate::RenderError;

/// The largest image side prism renders, pixels: bigger sizes are refused before anything is
/// allocated for them.
pub const MAX_IMAGE_SIDE: u32 = 4096;

/// The `(width, height)` that all `cameras` share.
///
/// # Errors
/// [`RenderError::Input`] for no camera, an empty size, a side above [`MAX_IMAGE_SIDE`], or
/// cameras of different sizes.
pub fn image_size(cameras: &[Camera]) -> Result<(u32, u32), RenderError> {
    let size = |c: &Camera| (c.intrinsics.width, c.intrinsics.height);
    let Some(first) = cameras.first() else {
        return Err(RenderError::Input("no camera".into()));
    };
    let (w, h) = size(first);
    if w == 0 || h == 0 {
        return Err(RenderError::Input(format!("empty image size {w}x{h}")));
    }
    if w > MAX_IMAGE_SIDE || h > MAX_IMAGE_SIDE {
        return Err(RenderError::Input(format!(
            "an image size of {w}x{h} exceeds the limit of {MAX_IMAGE_SIDE} px a side"
        )));
    }
    if let Some(other) = cameras.iter().find(|c| size(c) != (w, h)) {
        let (w2, h2) = size(other);
        return Err(RenderError::Input(format!(
            "cameras of one batch must share one image size, got {w}x{h} and {w2}x{h2}"
        )));
    }
    Ok((w, h))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;
    use prism_core::Intrinsics;

    fn camera(w: u32, h: u32) -> Camera {
        Camera::look_at(
            Vec3::Z,
            Vec3::ZERO,
            Vec3::Y,
            Intrinsics::protocol_default(w, h),
        )
    }

    #[test]
    fn sizes_are_checked_against_the_limit_and_each_other() {
        assert_eq!(
            image_size(&[camera(48, 32), camera(48, 32)]).unwrap(),
            (48, 32)
        );
        let err = |cameras: &[Camera]| image_size(cameras).unwrap_err().to_string();
        assert!(err(&[]).contains("no camera"));
        assert!(err(&[camera(4097, 8)]).contains("limit of 4096"));
        assert!(err(&[camera(8, 8), camera(9, 8)]).contains("share one image size"));
    }
}
