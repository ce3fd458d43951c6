//! The point branch's starting distances from the source's silhouette (`anchor_height`).
//!
//! A photo alone does not say how far the person is, but a person of known height does: the
//! viewing protocol scales every subject to 1.80 +- 0.05 m. The foreground rows of the source
//! (its pixels away from the background colour) span an angle `theta` between the ray through
//! the top edge of the first row and the ray through the bottom edge of the last. A segment of
//! `height` metres, normal to their bisector `b`, spans that angle at the distance
//! `D = height / (2 tan(theta / 2))`. Each pixel's anchor is the distance along its ray to the
//! plane through that segment, `D / (d . b)`. The branch then learns the relief about the
//! anchor instead of about one distance for everyone.
//!
//! Everything is tensor arithmetic on the source image and its rays, so the anchor costs no
//! read from the device. Where the silhouette cannot measure a height (fewer than two
//! foreground rows) the anchor is the fixed prior. A person cut off by the frame is measured
//! all the same: in the protocol's frontal views the feet often touch the bottom row (11 of
//! the small config's 24 people), and the branch learns the correction.
//!
//! On the small config's 24 frontal views, with `height = 1.8`, the anchor is 5.2 cm from the
//! true distance on average over the person's pixels (bias -0.7 cm), where the shipped
//! teacher's own distances are 8 to 9 cm off, almost all of it a bias (BENCHMARKS.md, issue
//! 42, "The distance from the silhouette").

use burn::tensor::Tensor;

use crate::heads::gaussian::person_mask;

/// Per source pixel, the distance along its ray to the person's plane, `[B, 1, H, W]` (see the
/// module docs): from the source image `[B, 3, H, W]`, its unit ray directions `[B, 3, H, W]`,
/// the background colour, the person's `height` (metres) and the `fallback` distance.
pub(crate) fn silhouette_anchor(
    source_image: &Tensor<4>,
    directions: &Tensor<4>,
    background: [f32; 3],
    height: f32,
    fallback: f32,
) -> Tensor<4> {
    let [b, _, h, w] = source_image.dims();
    let person = person_mask(source_image, &background);
    // Rows with the person in them, counted down the image: the first such row has count 1,
    // the last the total.
    let rows = person.clone().max_dim(3);
    let count = rows.clone().cumsum(2);
    let total = rows.clone().sum_dim(2);
    let first = rows.clone() * count.clone().equal_elem(1.0).float();
    let last = rows.clone() * (count - total.clone()).abs().lower_elem(0.5).float();
    // The mean ray of the person's pixels in the first and last rows (pixel centres).
    let mean_ray = |row: Tensor<4>| {
        let weights = person.clone() * row.expand([b, 1, h, w]);
        unit((directions.clone() * weights).sum_dim(3).sum_dim(2))
    };
    let (top, bottom) = (mean_ray(first), mean_ray(last));
    // tan(theta / 2) between the two unit rays, widened from the rows' centres (n - 1 rows
    // apart) to their outer edges (n rows).
    let tan_half = norm(top.clone() - bottom.clone()) / norm(top.clone() + bottom.clone());
    let tan_half = tan_half * total.clone() / total.clone().sub_scalar(1.0).clamp_min(1.0);
    let distance = tan_half.clamp_min(1e-6).recip().mul_scalar(height / 2.0);
    let normal = unit(top + bottom);
    let along = (directions.clone() * normal).sum_dim(1).clamp_min(1e-3);
    let anchor = distance.expand([b, 1, h, w]) / along;
    let unmeasured = total.lower_elem(1.5);
    anchor.mask_fill(unmeasured.expand([b, 1, h, w]), fallback)
}

/// `x` over its length along dim 1.
fn unit(x: Tensor<4>) -> Tensor<4> {
    x.clone() / norm(x).clamp_min(1e-12)
}

/// The length of `x` along dim 1, `[B, 1, ..]`.
fn norm(x: Tensor<4>) -> Tensor<4> {
    x.powi_scalar(2).sum_dim(1).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::{ndarray, values};
    use burn::tensor::TensorData;
    use prism_core::rays::plucker_rays;
    use prism_core::{Camera, Intrinsics};

    /// A frontal camera at the origin looking along world -Z (the protocol's view 0 at height
    /// 0), 64 x 64 pixels, `f = 64`.
    fn camera() -> Camera {
        let k = Intrinsics::protocol_default(64, 64);
        Camera::look_at(glam::Vec3::ZERO, glam::Vec3::NEG_Z, glam::Vec3::Y, k)
    }

    /// A grey rectangle on white over rows `rows` and columns 20..44.
    fn rectangle(rows: std::ops::Range<usize>) -> Vec<f32> {
        let mut image = vec![1.0f32; 3 * 64 * 64];
        for c in 0..3 {
            for y in rows.clone() {
                for x in 20..44 {
                    image[c * 64 * 64 + y * 64 + x] = 0.3;
                }
            }
        }
        image
    }

    fn anchor(images: Vec<Vec<f32>>) -> Vec<f32> {
        let device = ndarray();
        let b = images.len();
        let image =
            Tensor::<4>::from_data(TensorData::new(images.concat(), [b, 3, 64, 64]), &device);
        let rays = plucker_rays(&vec![camera(); b], &device);
        let directions = rays.narrow(1, 0, 3);
        values(&silhouette_anchor(
            &image,
            &directions,
            [1.0, 1.0, 1.0],
            1.8,
            2.0,
        ))
    }

    #[test]
    fn a_person_of_the_given_height_is_placed_at_their_distance() {
        // 1.8 m at 2.4 m spans 64 * 0.9 / 2.4 = 24 pixels each side of the centre row: rows 8
        // to 55. At 3.6 m it spans 16: rows 16 to 47.
        let anchors = anchor(vec![rectangle(8..56), rectangle(16..48)]);
        let k = camera().intrinsics;
        for (i, expected) in [2.4f32, 3.6].into_iter().enumerate() {
            for (x, y) in [(32usize, 32usize), (0, 0), (63, 40), (10, 60)] {
                // Along the ray of pixel (x, y) to the plane z = -expected.
                let (u, v) = (
                    (x as f32 + 0.5 - k.cx) / k.fx,
                    (y as f32 + 0.5 - k.cy) / k.fy,
                );
                let along_ray = expected * (1.0 + u * u + v * v).sqrt();
                let got = anchors[i * 64 * 64 + y * 64 + x];
                assert!(
                    (got - along_ray).abs() < 1e-3 * along_ray,
                    "pair {i} pixel ({x}, {y}): {got} against {along_ray}"
                );
            }
        }
    }

    #[test]
    fn a_silhouette_without_a_height_gets_the_fallback() {
        // One row, and no person at all.
        let anchors = anchor(vec![rectangle(30..31), vec![1.0; 3 * 64 * 64]]);
        assert!(anchors.iter().all(|&a| a == 2.0), "{:?}", &anchors[..4]);
        // Cut off by the bottom edge: rows 32 to 63 read as a whole person of 1.8 m, whose
        // 32 rows put them at 64 * 1.8 / 32 = 3.6 m along the axis of their bisector.
        let cut = anchor(vec![rectangle(32..64)]);
        let centre = cut[48 * 64 + 32];
        assert!(centre > 3.0 && centre < 4.0, "{centre}");
    }
}
