//! Axis-angle rotations (Rodrigues' formula), shared by the f32 and the tensor body models.
//!
//! For `r = theta * axis`, `R = cos(theta) I + A K + B r r^T` with `K = [r]_x`,
//! `A = sin(theta) / theta` and `B = (1 - cos(theta)) / theta^2 = 2 sin^2(theta / 2) / theta^2`
//! (the half-angle form keeps `B` accurate in f32 for small angles), and `cos(theta) = 1 - B theta^2`.
//! Below [`SMALL_ANGLE_SQ`] both coefficients use their Taylor series, so that values and
//! gradients stay finite at `r = 0`.

use glam::{Mat3, Vec3};

/// `theta^2` below which `A` and `B` use their Taylor series.
pub const SMALL_ANGLE_SQ: f32 = 1e-3;

/// The Rodrigues coefficients `(A, B)` for `theta^2 = t2`.
pub fn rodrigues_coefficients(t2: f32) -> (f32, f32) {
    if t2 < SMALL_ANGLE_SQ {
        (
            1.0 - t2 / 6.0 + t2 * t2 / 120.0,
            0.5 - t2 / 24.0 + t2 * t2 / 720.0,
        )
    } else {
        let theta = t2.sqrt();
        let half = (0.5 * theta).sin();
        (theta.sin() / theta, 2.0 * half * half / t2)
    }
}

/// The rotation matrix of the axis-angle vector `r`.
pub fn axis_angle_to_matrix(r: Vec3) -> Mat3 {
    let t2 = r.length_squared();
    let (a, b) = rodrigues_coefficients(t2);
    let c = 1.0 - b * t2;
    let (x, y, z) = (r.x, r.y, r.z);
    // Columns of R (glam is column-major): R[row][col].
    Mat3::from_cols(
        Vec3::new(c + b * x * x, a * z + b * x * y, -a * y + b * x * z),
        Vec3::new(-a * z + b * x * y, c + b * y * y, a * x + b * y * z),
        Vec3::new(a * y + b * x * z, -a * x + b * y * z, c + b * z * z),
    )
}

/// The axis-angle vector of a rotation matrix (angle in `[0, pi]`).
pub fn matrix_to_axis_angle(m: Mat3) -> Vec3 {
    let q = glam::Quat::from_mat3(&m).normalize();
    let (axis, angle) = q.to_axis_angle();
    if angle > std::f32::consts::PI {
        -axis * (2.0 * std::f32::consts::PI - angle)
    } else {
        axis * angle
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_glam_and_round_trips() {
        for r in [
            Vec3::new(0.3, -1.2, 0.5),
            Vec3::new(1e-4, 2e-4, -1e-4),
            Vec3::new(0.0, 0.0, 2.5),
            Vec3::ZERO,
            Vec3::new(0.02, 0.0, 0.01),
        ] {
            let m = axis_angle_to_matrix(r);
            let reference = if r.length() > 0.0 {
                Mat3::from_axis_angle(r.normalize(), r.length())
            } else {
                Mat3::IDENTITY
            };
            assert!(m.abs_diff_eq(reference, 1e-6), "{r}: {m} vs {reference}");
            assert!((matrix_to_axis_angle(m) - r).length() < 1e-4, "{r}");
        }
        // A rotation about +Z by +90 degrees maps +X to +Y.
        let m = axis_angle_to_matrix(Vec3::new(0.0, 0.0, std::f32::consts::FRAC_PI_2));
        assert!((m * Vec3::X - Vec3::Y).length() < 1e-6);
    }
}
