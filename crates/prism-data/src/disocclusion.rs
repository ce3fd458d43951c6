//! The disoccluded region of a target view: its foreground pixels whose surface the source
//! view does not see. There a warp of the source has nothing to copy; only a model that
//! synthesises unseen surface can be right.
//!
//! With depth maps (datasets store one per view) the region is exact, by the standard depth
//! test ([`disoccluded_by_depth`]): each target pixel's own surface point, from the target's
//! depth, is projected into the source, and it is seen there only if it is no farther than the
//! surface the source's depth map holds at that spot. Without target depth (datasets written
//! before depth was stored), [`disoccluded_region`] estimates the region from the source's
//! point map alone; [`RegionMethod`] says which of the two made a region.

use image::{ImageBuffer, Luma};
use prism_core::camera::Camera;
use serde::Serialize;

use super::io::{DepthMap, Mask, PointMap};

/// Mask values above this are foreground (the disoccluded region and the true-depth warp).
pub const FOREGROUND: f32 = 0.5;

/// How far (metres, along the source's view axis) a target surface point may lie behind the
/// source's depth map and still count as seen: depth maps store whole millimetres, and a
/// surface between two source pixel centres is interpolated from them.
pub const DEPTH_SLACK_M: f32 = 0.01;

/// How a disoccluded region was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RegionMethod {
    /// The depth test of every target pixel against the source's depth map (exact).
    DepthTest,
    /// The forward projection of the source's points, without target-side occlusion (an
    /// estimate, for datasets without depth maps).
    Estimate,
}

/// One view as the depth test reads it: its camera, foreground mask and depth map (all at
/// the same size).
#[derive(Clone, Copy, Debug)]
pub struct DepthView<'a> {
    /// The view's camera.
    pub camera: &'a Camera,
    /// Foreground alpha in [0, 1].
    pub mask: &'a Mask,
    /// Depth of the surface at each pixel centre (0: none).
    pub depth: &'a DepthMap,
}

impl DepthView<'_> {
    /// The depth of foreground pixel `(x, y)`, if it is one and has a surface.
    fn surface(&self, x: i64, y: i64) -> Option<f32> {
        let (w, h) = self.mask.dimensions();
        if x < 0 || y < 0 || x >= i64::from(w) || y >= i64::from(h) {
            return None;
        }
        let (x, y) = (x as u32, y as u32);
        let depth = self.depth.get_pixel(x, y).0[0];
        (self.mask.get_pixel(x, y).0[0] > FOREGROUND && depth > 0.0).then_some(depth)
    }
}

/// The disoccluded region (1 inside, 0 outside) of `target` for `source`, by the depth test:
/// a foreground target pixel is disoccluded when its surface point, projected into the source,
/// falls off the source's foreground, or lies more than [`DEPTH_SLACK_M`] behind the farthest
/// of the (up to four) source surfaces around the spot it lands on. Taking the farthest of the
/// four keeps a surface seen at a grazing angle seen; a point hidden behind other surface is
/// behind all four. A target pixel without depth (its centre ray misses while its coverage is
/// over half) is left out of the region: nothing says what it shows.
///
/// # Panics
/// If a view's mask and depth map differ in size.
pub fn disoccluded_by_depth(source: DepthView<'_>, target: DepthView<'_>) -> Mask {
    for view in [&source, &target] {
        assert_eq!(
            view.mask.dimensions(),
            view.depth.dimensions(),
            "one depth per mask pixel"
        );
    }
    let (w, h) = target.mask.dimensions();
    ImageBuffer::from_fn(w, h, |x, y| {
        let Some(depth) = target.surface(i64::from(x), i64::from(y)) else {
            return Luma([0.0]);
        };
        let point = target
            .camera
            .unproject(x as f32 + 0.5, y as f32 + 0.5, depth);
        let seen = seen_from(&source, point);
        Luma([if seen { 0.0 } else { 1.0 }])
    })
}

/// Whether world point `point` is on the surface `source` sees (see [`disoccluded_by_depth`]).
fn seen_from(source: &DepthView<'_>, point: glam::Vec3) -> bool {
    let (u, v, z) = source.camera.project(point);
    let (w, h) = source.mask.dimensions();
    let inside = (0.0..w as f32).contains(&u) && (0.0..h as f32).contains(&v);
    if z <= 0.0 || !inside {
        return false;
    }
    // The four pixel centres around (u, v).
    let (x0, y0) = ((u - 0.5).floor() as i64, (v - 0.5).floor() as i64);
    let farthest = [(0, 0), (1, 0), (0, 1), (1, 1)]
        .into_iter()
        .filter_map(|(dx, dy)| source.surface(x0 + dx, y0 + dy))
        .reduce(f32::max);
    farthest.is_some_and(|d| z <= d + DEPTH_SLACK_M)
}

/// The disoccluded region (1 inside, 0 outside) of the target view with camera `target` and
/// foreground `target_mask`, estimated for the source view whose visible surface is `points` on
/// `source_mask`, for datasets without depth maps.
///
/// Each source point is projected into the target camera and marks the pixel it lands in; a
/// 3 x 3 closing then fills the one-pixel gaps that forward projection leaves where the
/// surface is stretched in the target view. The region is the target's mask minus those
/// pixels. Occlusion in the target view is not modelled: a source point hidden behind other
/// surface in the target view still counts as seen, and the closing also fills disoccluded
/// strips one or two pixels wide. [`disoccluded_by_depth`] has neither fault.
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

    /// The fin of the depth-test scene: a box 6 cm thick, 60 cm tall, standing 50 cm out of
    /// the wall z = 0, seen from cameras to its left and right.
    const FIN: [Vec3; 2] = [Vec3::new(-0.03, -0.3, 0.0), Vec3::new(0.03, 0.3, 0.5)];
    const SIDE: u32 = 48;

    /// Where the ray `origin + t * dir` enters the fin (slab test), if it meets it at t > 0.
    fn fin_entry(origin: Vec3, dir: Vec3) -> Option<f32> {
        let (a, b) = ((FIN[0] - origin) / dir, (FIN[1] - origin) / dir);
        let (near, far) = (a.min(b).max_element(), a.max(b).min_element());
        (near <= far && far > 0.0).then_some(near.max(0.0))
    }

    /// The scene's surface point through pixel `(x, y)`'s centre: the fin, else the wall.
    fn scene_hit(camera: &Camera, x: u32, y: u32) -> Vec3 {
        let (o, d) = (
            camera.center(),
            camera.ray_direction(x as f32 + 0.5, y as f32 + 0.5),
        );
        let wall = -o.z / d.z;
        o + d * fin_entry(o, d).map_or(wall, |t| t.min(wall))
    }

    /// A camera of the fin scene at `x` metres, 2 m from the wall, looking at the fin.
    fn fin_camera(x: f32) -> Camera {
        Camera::look_at(
            Vec3::new(x, 0.0, 2.0),
            Vec3::new(0.0, 0.0, 0.25),
            Vec3::Y,
            Intrinsics::protocol_default(SIDE, SIDE),
        )
    }

    /// A view's full mask and its depth map, by ray casting.
    fn fin_view(camera: &Camera) -> (Mask, DepthMap) {
        let depth = ImageBuffer::from_fn(SIDE, SIDE, |x, y| {
            Luma([camera.project(scene_hit(camera, x, y)).2])
        });
        (ImageBuffer::from_pixel(SIDE, SIDE, Luma([1.0])), depth)
    }

    /// The exact region, by geometry alone: a target pixel is disoccluded when the segment from
    /// the source's centre to its surface point passes through the fin first, or the point
    /// projects outside the source image.
    fn fin_truth(source: &Camera, target: &Camera) -> Vec<bool> {
        let mut truth = Vec::new();
        for y in 0..SIDE {
            for x in 0..SIDE {
                let p = scene_hit(target, x, y);
                let (u, v, _) = source.project(p);
                let inside = (0.0..SIDE as f32).contains(&u) && (0.0..SIDE as f32).contains(&v);
                let blocked =
                    fin_entry(source.center(), p - source.center()).is_some_and(|t| t < 1.0 - 1e-4);
                truth.push(blocked || !inside);
            }
        }
        truth
    }

    #[test]
    fn the_depth_test_finds_the_exact_region_behind_and_beside_a_fin() {
        let (source, target) = (fin_camera(-0.5), fin_camera(0.5));
        let (source_mask, source_depth) = fin_view(&source);
        let (target_mask, target_depth) = fin_view(&target);
        let region = disoccluded_by_depth(
            DepthView {
                camera: &source,
                mask: &source_mask,
                depth: &source_depth,
            },
            DepthView {
                camera: &target,
                mask: &target_mask,
                depth: &target_depth,
            },
        );
        let truth = fin_truth(&source, &target);
        let inside: Vec<bool> = region.pixels().map(|p| p.0[0] > 0.5).collect();
        // The region is the fin's right face, which the source (to the left) never sees, and
        // the wall right of the fin that the fin hides from the source: both a few pixels wide.
        let on_fin = |i: usize| {
            let p = scene_hit(&target, i as u32 % SIDE, i as u32 / SIDE);
            (p.x - FIN[1].x).abs() < 1e-4 && p.z > 1e-4
        };
        let truth_count = truth.iter().filter(|&&t| t).count();
        let face = (0..truth.len()).filter(|&i| truth[i] && on_fin(i)).count();
        assert!(
            face >= 20 && truth_count - face >= 20,
            "{face} {truth_count}"
        );
        let wrong: Vec<usize> = (0..truth.len())
            .filter(|&i| inside[i] != truth[i])
            .collect();
        // Depth maps sample each surface at pixel centres, so where an occluding edge crosses a
        // source pixel the test can be off by that pixel: only on the region's border, and
        // rarely.
        let on_border = |i: usize| {
            let (x, y) = ((i as u32 % SIDE) as i64, (i as u32 / SIDE) as i64);
            let side = i64::from(SIDE);
            (-1..=1)
                .flat_map(|dy| (-1..=1).map(move |dx| (x + dx, y + dy)))
                .any(|(a, b)| {
                    (0..side).contains(&a)
                        && (0..side).contains(&b)
                        && truth[(b * side + a) as usize] != truth[i]
                })
        };
        println!("{truth_count} pixels disoccluded, {} differ", wrong.len());
        assert!(
            wrong.iter().all(|&i| on_border(i)),
            "off the border: {wrong:?}"
        );
        assert!(
            wrong.len() * 50 < truth_count,
            "{} of {truth_count}",
            wrong.len()
        );
        // The estimate from the source's points alone (for datasets without depth) misses most
        // of the fin's face: the wall the source sees left of the fin, hidden behind the fin
        // from the target, lands on the face in the target (34 of its 48 pixels). The depth
        // test above misses at most the few pixels it gets wrong.
        let points = PointMap {
            width: SIDE,
            height: SIDE,
            points: (0..SIDE * SIDE)
                .map(|i| scene_hit(&source, i % SIDE, i / SIDE).to_array())
                .collect(),
        };
        let estimate = disoccluded_region(&points, &source_mask, &target, &target_mask);
        let missed = (0..truth.len())
            .filter(|&i| truth[i] && on_fin(i) && estimate.as_raw()[i] < 0.5)
            .count();
        assert!(
            missed * 2 > face,
            "the estimate misses only {missed} of the fin's {face} face pixels: it models \
             occlusion now, and the depth test is no longer the only exact region"
        );
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
