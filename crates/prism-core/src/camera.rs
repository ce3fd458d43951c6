//! Pinhole cameras in the OpenCV convention (x right, y down, looking along +z).
//!
//! A [`Camera`] is its [`Intrinsics`] (in pixels of the stored image size) and `c2w`, the 4x4
//! camera-to-world matrix. Pixel `(x, y)` has its centre at `(x + 0.5, y + 0.5)`.

use glam::{Mat3, Mat4, Vec3, Vec4};
use serde::{Deserialize, Serialize};

/// Pinhole intrinsics in pixels of an image of `width x height`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Focal length along x, in pixels.
    pub fx: f32,
    /// Focal length along y, in pixels.
    pub fy: f32,
    /// Principal point x, in pixels (the image centre is `width / 2`).
    pub cx: f32,
    /// Principal point y, in pixels.
    pub cy: f32,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
}

impl Intrinsics {
    /// The viewing protocol's default: `fx = fy = H` (vertical field of view 53.13 degrees),
    /// principal point at the image centre.
    pub fn protocol_default(width: u32, height: u32) -> Self {
        Self {
            fx: height as f32,
            fy: height as f32,
            cx: width as f32 / 2.0,
            cy: height as f32 / 2.0,
            width,
            height,
        }
    }

    /// The same camera for an image resized to `width x height`: focal lengths and principal
    /// point scale with the image along each axis.
    pub fn rescaled(&self, width: u32, height: u32) -> Self {
        let sx = width as f32 / self.width as f32;
        let sy = height as f32 / self.height as f32;
        Self {
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: self.cx * sx,
            cy: self.cy * sy,
            width,
            height,
        }
    }

    /// The 3x3 calibration matrix `K`.
    pub fn matrix(&self) -> Mat3 {
        Mat3::from_cols(
            Vec3::new(self.fx, 0.0, 0.0),
            Vec3::new(0.0, self.fy, 0.0),
            Vec3::new(self.cx, self.cy, 1.0),
        )
    }
}

/// A pinhole camera: intrinsics plus the camera-to-world transform (OpenCV axes).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Intrinsics in pixels of the stored image size.
    pub intrinsics: Intrinsics,
    /// Camera-to-world rigid transform; its columns are the camera's x, y, z axes and centre.
    pub c2w: Mat4,
}

impl Camera {
    /// A camera from intrinsics and a camera-to-world matrix.
    pub fn new(intrinsics: Intrinsics, c2w: Mat4) -> Self {
        Self { intrinsics, c2w }
    }

    /// A camera on a sphere of `radius` around `center`, looking at the centre.
    ///
    /// Yaw turns about the world's +Y axis and pitch lifts the camera above the horizon, so
    /// `(yaw, pitch) = (0, 0)` sits on the +Z axis looking towards -Z (the frontal view of a
    /// subject facing +Z); positive yaw moves the camera towards +X, positive pitch upwards.
    /// The image's "down" stays as close to world -Y as the viewing direction allows.
    pub fn orbit(
        yaw_deg: f32,
        pitch_deg: f32,
        radius: f32,
        center: Vec3,
        intrinsics: Intrinsics,
    ) -> Self {
        let (yaw, pitch) = (yaw_deg.to_radians(), pitch_deg.to_radians());
        let offset = Vec3::new(
            pitch.cos() * yaw.sin(),
            pitch.sin(),
            pitch.cos() * yaw.cos(),
        );
        let position = center + radius * offset;
        Self::look_at(position, center, Vec3::Y, intrinsics)
    }

    /// A camera at `eye` looking at `target`, with world `up` pointing up in the image.
    pub fn look_at(eye: Vec3, target: Vec3, up: Vec3, intrinsics: Intrinsics) -> Self {
        let z = (target - eye).normalize();
        let x = z.cross(up).normalize();
        let y = z.cross(x);
        let c2w = Mat4::from_cols(x.extend(0.0), y.extend(0.0), z.extend(0.0), eye.extend(1.0));
        Self { intrinsics, c2w }
    }

    /// The camera centre in world space.
    pub fn center(&self) -> Vec3 {
        self.c2w.w_axis.truncate()
    }

    /// The camera-to-world rotation.
    pub fn rotation(&self) -> Mat3 {
        Mat3::from_mat4(self.c2w)
    }

    /// The world-to-camera transform (the inverse of `c2w`).
    pub fn w2c(&self) -> Mat4 {
        self.c2w.inverse()
    }

    /// The same camera for an image resized to `width x height`.
    pub fn rescaled(&self, width: u32, height: u32) -> Self {
        Self {
            intrinsics: self.intrinsics.rescaled(width, height),
            c2w: self.c2w,
        }
    }

    /// A world point in camera coordinates.
    pub fn world_to_camera(&self, point: Vec3) -> Vec3 {
        self.w2c().transform_point3(point)
    }

    /// Projects a world point to continuous pixel coordinates `(u, v)` and its depth (the
    /// camera-space z). Pixel `(x, y)`'s centre projects to `(x + 0.5, y + 0.5)`. Points behind
    /// the camera get a negative depth; their `(u, v)` is meaningless.
    pub fn project(&self, point: Vec3) -> (f32, f32, f32) {
        let p = self.world_to_camera(point);
        let k = &self.intrinsics;
        (k.fx * p.x / p.z + k.cx, k.fy * p.y / p.z + k.cy, p.z)
    }

    /// The world point at continuous pixel coordinates `(u, v)` and camera-space depth `z`;
    /// the inverse of [`Camera::project`].
    pub fn unproject(&self, u: f32, v: f32, depth: f32) -> Vec3 {
        let k = &self.intrinsics;
        let p = Vec3::new((u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0) * depth;
        self.c2w.transform_point3(p)
    }

    /// The unit world-space direction of the ray through continuous pixel coordinates
    /// `(u, v)`: `normalize(R_c2w * K^-1 * [u, v, 1])`.
    pub fn ray_direction(&self, u: f32, v: f32) -> Vec3 {
        let k = &self.intrinsics;
        let d = Vec3::new((u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0);
        (self.rotation() * d).normalize()
    }

    /// The Plücker ray `(d, o x d)` of pixel `(x, y)` (through its centre), paper Eq. 1.
    pub fn plucker(&self, x: u32, y: u32) -> [f32; 6] {
        let d = self.ray_direction(x as f32 + 0.5, y as f32 + 0.5);
        let m = self.center().cross(d);
        [d.x, d.y, d.z, m.x, m.y, m.z]
    }

    /// The row-major 4x4 `c2w`, as stored in `cameras.json`.
    pub fn c2w_rows(&self) -> [[f32; 4]; 4] {
        mat4_to_rows(&self.c2w)
    }
}

/// A 4x4 matrix as row-major nested arrays (the JSON layout of the dataset).
pub fn mat4_to_rows(m: &Mat4) -> [[f32; 4]; 4] {
    let t = m.transpose();
    [
        t.x_axis.to_array(),
        t.y_axis.to_array(),
        t.z_axis.to_array(),
        t.w_axis.to_array(),
    ]
}

/// A 4x4 matrix from row-major nested arrays.
pub fn mat4_from_rows(rows: &[[f32; 4]; 4]) -> Mat4 {
    Mat4::from_cols(
        Vec4::from_array(rows[0]),
        Vec4::from_array(rows[1]),
        Vec4::from_array(rows[2]),
        Vec4::from_array(rows[3]),
    )
    .transpose()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        Camera::orbit(
            17.0,
            -12.0,
            2.0,
            Vec3::new(0.05, 0.9, -0.03),
            Intrinsics::protocol_default(64, 48),
        )
    }

    #[test]
    fn principal_ray_of_identity_camera_is_plus_z() {
        let k = Intrinsics {
            fx: 10.0,
            fy: 10.0,
            cx: 2.5,
            cy: 1.5,
            width: 5,
            height: 3,
        };
        let c = Camera::new(k, Mat4::IDENTITY);
        // Pixel (2, 1) has its centre at (2.5, 1.5): the principal point.
        let r = c.plucker(2, 1);
        let expected = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        for (a, b) in r.iter().zip(expected) {
            assert!((a - b).abs() < 1e-7, "{r:?}");
        }
    }

    #[test]
    fn frontal_orbit_looks_at_minus_z_with_image_down_world_down() {
        let c = Camera::orbit(
            0.0,
            0.0,
            2.0,
            Vec3::ZERO,
            Intrinsics::protocol_default(8, 8),
        );
        assert!((c.center() - Vec3::new(0.0, 0.0, 2.0)).length() < 1e-6);
        let r = c.rotation();
        assert!((r.z_axis - Vec3::NEG_Z).length() < 1e-6);
        assert!((r.y_axis - Vec3::NEG_Y).length() < 1e-6);
        assert!((r.x_axis - Vec3::X).length() < 1e-6);
        // Positive yaw moves towards +X, positive pitch upwards.
        let c = Camera::orbit(
            30.0,
            20.0,
            2.0,
            Vec3::ZERO,
            Intrinsics::protocol_default(8, 8),
        );
        assert!(c.center().x > 0.0 && c.center().y > 0.0);
    }

    #[test]
    fn orbit_keeps_radius_and_looks_at_centre() {
        let c = cam();
        let centre = Vec3::new(0.05, 0.9, -0.03);
        assert!(((c.center() - centre).length() - 2.0).abs() < 1e-5);
        let (u, v, z) = c.project(centre);
        assert!((u - 32.0).abs() < 1e-3 && (v - 24.0).abs() < 1e-3 && (z - 2.0).abs() < 1e-5);
    }

    #[test]
    fn unproject_round_trips() {
        let c = cam();
        for &(u, v, d) in &[(0.5, 0.5, 1.0), (33.2, 7.9, 2.5), (63.5, 47.5, 0.3)] {
            let p = c.unproject(u, v, d);
            let (u2, v2, d2) = c.project(p);
            assert!((u - u2).abs() < 1e-3 && (v - v2).abs() < 1e-3 && (d - d2).abs() < 1e-5);
        }
    }

    #[test]
    fn plucker_moment_is_orthogonal_to_direction() {
        let c = cam();
        for (x, y) in [(0, 0), (10, 40), (63, 47)] {
            let r = c.plucker(x, y);
            let d = Vec3::new(r[0], r[1], r[2]);
            let m = Vec3::new(r[3], r[4], r[5]);
            assert!((d.length() - 1.0).abs() < 1e-6);
            assert!(d.dot(m).abs() < 1e-6);
        }
    }

    #[test]
    fn rays_of_one_point_in_two_views_pass_through_it() {
        let a = cam();
        let b = Camera::orbit(
            -25.0,
            20.0,
            2.0,
            Vec3::new(0.0, 0.9, 0.0),
            Intrinsics::protocol_default(64, 48),
        );
        let p = Vec3::new(0.1, 1.1, 0.2);
        for c in [a, b] {
            let (u, v, _) = c.project(p);
            let d = c.ray_direction(u, v);
            let m = c.center().cross(d);
            // A point lies on the Plücker line (d, m) iff p x d = m.
            assert!((p.cross(d) - m).length() < 1e-5);
        }
    }

    #[test]
    fn rescaling_keeps_the_projection_in_relative_units() {
        let c = cam();
        let s = c.rescaled(128, 96);
        let p = Vec3::new(0.2, 1.3, 0.1);
        let (u, v, _) = c.project(p);
        let (u2, v2, _) = s.project(p);
        assert!((u2 - 2.0 * u).abs() < 1e-3 && (v2 - 2.0 * v).abs() < 1e-3);
    }

    #[test]
    fn row_major_round_trip() {
        let c = cam();
        let rows = c.c2w_rows();
        assert_eq!(rows[0][3], c.center().x);
        assert_eq!(mat4_from_rows(&rows), c.c2w);
    }
}
