//! A camera prepared for rasterization: world-to-camera transform, intrinsics, tile grid.

use glam::{Mat3, Vec3};
use prism_core::Camera;

use super::TILE_SIZE;

/// A [`Camera`] in the form the rasterizer uses.
#[derive(Clone, Copy, Debug)]
pub struct View {
    /// World-to-camera rotation `W`.
    pub rotation: Mat3,
    /// World-to-camera translation `t` (`p_cam = W p + t`).
    pub translation: Vec3,
    /// Focal length along x, pixels.
    pub fx: f32,
    /// Focal length along y, pixels.
    pub fy: f32,
    /// Principal point x, pixels.
    pub cx: f32,
    /// Principal point y, pixels.
    pub cy: f32,
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
}

impl View {
    /// Prepares `camera`.
    pub fn new(camera: &Camera) -> Self {
        let w2c = camera.w2c();
        let k = camera.intrinsics;
        Self {
            rotation: Mat3::from_mat4(w2c),
            translation: w2c.w_axis.truncate(),
            fx: k.fx,
            fy: k.fy,
            cx: k.cx,
            cy: k.cy,
            width: k.width as usize,
            height: k.height as usize,
        }
    }

    /// Number of tile columns.
    pub fn tiles_x(&self) -> usize {
        self.width.div_ceil(TILE_SIZE)
    }

    /// Number of tile rows.
    pub fn tiles_y(&self) -> usize {
        self.height.div_ceil(TILE_SIZE)
    }

    /// The `[min, max]` of `x/z` and of `y/z` used inside the projection Jacobian: the image's
    /// extent plus 30% of the half field of view on each side (3DGS's guard band).
    pub fn ratio_limits(&self) -> [[f32; 2]; 2] {
        let (w, h) = (self.width as f32, self.height as f32);
        let band_x = 0.3 * 0.5 * w / self.fx;
        let band_y = 0.3 * 0.5 * h / self.fy;
        [
            [
                -self.cx / self.fx - band_x,
                (w - self.cx) / self.fx + band_x,
            ],
            [
                -self.cy / self.fy - band_y,
                (h - self.cy) / self.fy + band_y,
            ],
        ]
    }
}
