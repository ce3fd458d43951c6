//! The weak-perspective camera `pi = (s, tx, ty)` of the SMPL-X branch and how it places the
//! body in the world through the source camera.
//!
//! The branch computes these with tensor ops on the model's device
//! (`SmplxBranch::world_vertices` and `SmplxBranch::targets`); the functions here are the same
//! formulas on the host, the reference its tests check against.
//!
//! The body model gives posed vertices `v` and joints in its own frame (Y up). A dataset's
//! `body.json` places them in the world by a uniform scale and a translation,
//! `world = sigma v + transl`. The anchor of the camera is the root joint `J_0` (the pelvis; it
//! does not move with the pose, only with the shape), at `P = sigma J_0 + transl` in the world
//! and `(X, Y, Z) = W P + t` in the source camera (OpenCV axes, `W, t` world-to-camera). Then
//!
//! ```text
//! s  = sigma / Z      projected size of one body-model unit at the anchor,
//!                     in focal-normalised image units ((u - cx) / fx)
//! tx = X / Z          the anchor's normalised image position
//! ty = Y / Z
//! ```
//!
//! and the inverse, given `pi` and `sigma`, is
//!
//! ```text
//! Z = sigma / s,  P = C + R (Z tx, Z ty, Z),  world(v) = sigma (v - J_0) + P
//! ```
//!
//! with `C` the camera centre and `R` the camera-to-world rotation; with the `sigma` that
//! defined `pi` this gives back `sigma v + transl` exactly.
//!
//! A weak-perspective camera has three numbers and the placement four (`sigma` and `transl`):
//! seen from the source camera alone, a larger body further away looks the same. The branch
//! resolves it with the viewing protocol, which scales every subject to a fixed height: the
//! predicted body is given `sigma = h / (max_y v - min_y v)`, the scale that makes its posed
//! height `h` metres (config `body_height`; 1.77 m for the procedural people of `prism data
//! synth`, whose meshes are 1.80 m tall with hair and shoes: measured over 40 subjects, standard
//! deviation 1 cm, plus the protocol's +-5 cm height jitter). The source view is exact for any
//! `sigma`; a wrong `sigma` shifts the body along the source rays, which the target views see.

#[cfg(test)]
use glam::{Mat3, Vec3};
#[cfg(test)]
use prism_core::Camera;

/// The weak-perspective camera `(s, tx, ty)` of a body with root joint `root` (model frame)
/// placed by `world = scale v + transl`, seen by `camera` (see the module docs).
#[cfg(test)]
pub(crate) fn weak_perspective(scale: f32, transl: Vec3, root: Vec3, camera: &Camera) -> [f32; 3] {
    let anchor = scale * root + transl;
    let p = camera.world_to_camera(anchor);
    [scale / p.z, p.x / p.z, p.y / p.z]
}

/// The world placement of posed vertices `v` (model frame) from the weak-perspective camera
/// `pi = (s, tx, ty)`, the root joint `root` and the scale `scale`:
/// `world(v) = scale (v - J_0) + C + R (Z tx, Z ty, Z)`, `Z = scale / s`.
#[cfg(test)]
pub(crate) fn place(
    vertices: &[Vec3],
    root: Vec3,
    pi: [f32; 3],
    scale: f32,
    camera: &Camera,
) -> Vec<Vec3> {
    let [s, tx, ty] = pi;
    let z = scale / s;
    let rotation = Mat3::from_mat4(camera.c2w);
    let anchor = camera.center() + rotation * Vec3::new(z * tx, z * ty, z);
    vertices
        .iter()
        .map(|&v| scale * (v - root) + anchor)
        .collect()
}

/// The scale that makes posed vertices `height` tall along Y: `height / (max_y - min_y)`.
#[cfg(test)]
pub(crate) fn scale_for_height(vertices: &[Vec3], height: f32) -> f32 {
    let (lo, hi) = vertices
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v.y), hi.max(v.y))
        });
    let extent = hi - lo;
    if extent.is_finite() && extent > 0.0 {
        height / extent
    } else {
        1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use prism_core::Intrinsics;

    #[test]
    fn placement_inverts_the_weak_perspective_camera() {
        let camera = Camera::orbit(
            8.0,
            -5.0,
            2.0,
            Vec3::new(0.02, 0.9, 0.0),
            Intrinsics::protocol_default(64, 64),
        );
        let vertices = [
            Vec3::new(0.1, 0.2, -0.1),
            Vec3::new(-0.3, 1.6, 0.05),
            Vec3::new(0.0, 0.0, 0.2),
        ];
        let root = Vec3::new(0.01, 0.95, 0.0);
        let (scale, transl) = (1.07, Vec3::new(0.04, 0.01, -0.08));
        let pi = weak_perspective(scale, transl, root, &camera);
        // Near the protocol's values: s about scale / 2, the anchor near the image centre.
        assert!((pi[0] - scale / 2.0).abs() < 0.1, "{pi:?}");
        assert!(pi[1].abs() < 0.2 && pi[2].abs() < 0.2, "{pi:?}");
        let placed = place(&vertices, root, pi, scale, &camera);
        for (p, v) in placed.iter().zip(&vertices) {
            let want = scale * *v + transl;
            assert!((*p - want).length() < 1e-5, "{p} vs {want}");
        }
        // The anchor projects where (tx, ty) says.
        let (u, v, _) = camera.project(scale * root + transl);
        let k = camera.intrinsics;
        assert!(((u - k.cx) / k.fx - pi[1]).abs() < 1e-5);
        assert!(((v - k.cy) / k.fy - pi[2]).abs() < 1e-5);
        // Another scale keeps every vertex on its source ray.
        let other = place(&vertices, root, pi, 1.3 * scale, &camera);
        for (a, b) in other.iter().zip(&placed) {
            let (ua, va, _) = camera.project(*a);
            let (ub, vb, _) = camera.project(*b);
            assert!((ua - ub).abs() < 1e-3 && (va - vb).abs() < 1e-3);
        }
        assert!((scale_for_height(&vertices, 1.8) - 1.8 / 1.6).abs() < 1e-6);
    }
}
