//! The disoccluded region of a target view: its foreground pixels that no visible point of
//! the source view lands on. There a warp of the source has nothing to copy; only a model that
//! synthesises unseen surface can be right.
//!
//! The source's visible surface is its point map (world points of the source pixels, on the
//! source's mask). Each point is projected into the target camera and marks the pixel it lands
//! in; a 3 x 3 closing then fills the one-pixel gaps that forward projection leaves where the
//! surface is stretched in the target view. The region is the target's mask minus those pixels.
//! Occlusion in the target view is not modelled (the dataset stores no target depth): a source
//! point hidden behind other surface in the target view still counts as seen.

use image::{ImageBuffer, Luma};
use prism_core::camera::Camera;

use super::io::{Mask, PointMap};

/// Mask values above this are foreground (the disoccluded region and the true-depth warp).
pub const FOREGROUND: f32 = 0.5;

/// The disoccluded region (1 inside, 0 outside) of the target view with camera `target` and
/// foreground `target_mask`, for the source view whose visible surface is `points` on
/// `source_mask`.
///
/// # Panics
/// If `points` and `source_mask` differ in size.
pub fn disoccluded_region(
    points: &PointMap,
    source_mask: &Mask,
    target: &Camera,
    target_mask: &Mask,
) -> Mask {
    assert_eq!(
        (points.width, points.height),
        source_mask.dimensions(),
        "one point per source pixel"
    );
    let (w, h) = target_mask.dimensions();
    let mut seen = vec![false; (w * h) as usize];
    for (point, alpha) in points.points.iter().zip(source_mask.pixels()) {
        if alpha.0[0] <= FOREGROUND {
            continue;
        }
        let (u, v, depth) = target.project(glam::Vec3::from_array(*point));
        if depth <= 0.0 || u < 0.0 || v < 0.0 || u >= w as f32 || v >= h as f32 {
            continue;
        }
        seen[(v as u32 * w + u as u32) as usize] = true;
    }
    let seen = erode(&dilate(&seen, w, h), w, h);
    ImageBuffer::from_fn(w, h, |x, y| {
        let i = (y * w + x) as usize;
        let inside = target_mask.get_pixel(x, y).0[0] > FOREGROUND && !seen[i];
        Luma([if inside { 1.0 } else { 0.0 }])
    })
}

/// `mask` with every pixel next to (3 x 3) a set pixel set.
fn dilate(mask: &[bool], w: u32, h: u32) -> Vec<bool> {
    neighbourhood(mask, w, h, false)
}

/// `mask` keeping only the pixels whose whole 3 x 3 neighbourhood is set (outside the image
/// counts as set, so the border does not erode).
fn erode(mask: &[bool], w: u32, h: u32) -> Vec<bool> {
    neighbourhood(mask, w, h, true)
}

/// For each pixel, whether all (`every`) or any (not `every`) of its 3 x 3 neighbourhood in
/// `mask` is set, pixels outside the image reading `every`.
fn neighbourhood(mask: &[bool], w: u32, h: u32, every: bool) -> Vec<bool> {
    let (w, h) = (i64::from(w), i64::from(h));
    let at = |x: i64, y: i64| {
        if x < 0 || y < 0 || x >= w || y >= h {
            every
        } else {
            mask[(y * w + x) as usize]
        }
    };
    let mut out = Vec::with_capacity(mask.len());
    for y in 0..h {
        for x in 0..w {
            let mut cells = (-1..=1).flat_map(|dy| (-1..=1).map(move |dx| (dx, dy)));
            out.push(if every {
                cells.all(|(dx, dy)| at(x + dx, y + dy))
            } else {
                cells.any(|(dx, dy)| at(x + dx, y + dy))
            });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;
    use prism_core::camera::Intrinsics;

    const W: u32 = 32;
    const H: u32 = 24;

    /// A camera at `eye` looking along -z (at `eye - z`).
    fn camera(eye: Vec3) -> Camera {
        Camera::look_at(
            eye,
            eye - Vec3::Z,
            Vec3::Y,
            Intrinsics::protocol_default(W, H),
        )
    }

    /// The source's view of a wall at z = 0, cut to the source pixels with `x < cut`: its
    /// points and mask.
    fn wall(source: &Camera, cut: u32) -> (PointMap, Mask) {
        let depth = source.center().z;
        let mut points = Vec::new();
        let mask = ImageBuffer::from_fn(W, H, |x, y| {
            let on = x < cut;
            let p = source.unproject(x as f32 + 0.5, y as f32 + 0.5, depth);
            points.push(if on { p.to_array() } else { [0.0; 3] });
            Luma([if on { 1.0 } else { 0.0 }])
        });
        let points = PointMap {
            width: W,
            height: H,
            points,
        };
        (points, mask)
    }

    fn full() -> Mask {
        ImageBuffer::from_pixel(W, H, Luma([1.0]))
    }

    /// The columns of row `y` inside the region.
    fn columns(region: &Mask, y: u32) -> Vec<u32> {
        (0..W)
            .filter(|&x| region.get_pixel(x, y).0[0] > 0.5)
            .collect()
    }

    #[test]
    fn from_the_source_itself_the_region_is_what_the_source_does_not_cover() {
        let source = camera(Vec3::new(0.0, 0.0, 2.0));
        let (points, mask) = wall(&source, 12);
        let region = disoccluded_region(&points, &mask, &source, &full());
        for y in 0..H {
            assert_eq!(columns(&region, y), (12..W).collect::<Vec<_>>(), "row {y}");
        }
        // Off the target's mask nothing is disoccluded.
        let none = ImageBuffer::from_pixel(W, H, Luma([0.0]));
        let region = disoccluded_region(&points, &mask, &source, &none);
        assert!(region.pixels().all(|p| p.0[0] == 0.0));
    }

    #[test]
    fn a_sideways_move_shifts_the_seen_part_by_its_parallax() {
        // The wall is 2 m away and fx = H = 24 px: moving the camera 0.25 m sideways moves
        // the wall's image by 24 * 0.25 / 2 = 3 px.
        let source = camera(Vec3::new(0.0, 0.0, 2.0));
        let (points, mask) = wall(&source, 12);
        let target = camera(Vec3::new(-0.25, 0.0, 2.0));
        let shift = target.project(Vec3::ZERO).0 - source.project(Vec3::ZERO).0;
        assert!((shift.abs() - 3.0).abs() < 1e-4, "{shift}");
        let seen: Vec<i64> = (0..12).map(|x| x + shift.round() as i64).collect();
        let expected: Vec<u32> = (0..W).filter(|&x| !seen.contains(&i64::from(x))).collect();
        let region = disoccluded_region(&points, &mask, &target, &full());
        for y in 0..H {
            assert_eq!(columns(&region, y), expected, "row {y}");
        }
    }

    #[test]
    fn gaps_of_a_stretched_surface_are_closed_and_points_behind_the_camera_ignored() {
        let source = camera(Vec3::new(0.0, 0.0, 2.0));
        let (mut points, mask) = wall(&source, W);
        // Every other column missing, as a surface stretched to twice its width would leave.
        for (i, p) in points.points.iter_mut().enumerate() {
            if i % 2 == 1 {
                *p = [0.0, 0.0, 10.0]; // behind the camera
            }
        }
        let region = disoccluded_region(&points, &mask, &source, &full());
        assert!(region.pixels().all(|p| p.0[0] == 0.0));
    }
}
