//! The 3DGS head's rim Gaussians (`gs_rim_depth`): the source silhouette's edge pixels start as
//! Gaussians stretched back along their rays.
//!
//! A frontal photo sees the sides of a body only at grazing angles, within a pixel or two of
//! the silhouette. Turned by up to 30 degrees, the target view shows those sides as strips a few
//! pixels wide that no source pixel covers: most of the disoccluded region. A Gaussian per source
//! pixel, isotropic and the size of its footprint, leaves them to the background colour.
//!
//! The surface behind a silhouette pixel goes on backwards, away from the camera. So each rim
//! Gaussian starts with its centre moved `reach / 2` back along its ray and its scale along the
//! ray `reach / 3`: it spans its pixel's surface point and `reach` metres behind it, and draws
//! the pixel's colour over the side strip in a turned view, while from the source camera it
//! still covers its own pixel alone. Nothing comes forward of the surface, where a stretched
//! Gaussian would cover the person's front in a turned view. The head learns the rest.
//!
//! With the dataset's true depth and no learning (the true-depth warp), rim Gaussians reaching
//! 5 cm lift the small config's held-out views from 22.3 to 23.7 dB, and their disoccluded
//! region from 8.0 to 11.4 dB (BENCHMARKS.md, issue 42, "Rim Gaussians").
//!
//! The rim and the rotations are tensor arithmetic on the source image and its rays: no read
//! from the device.

use burn::tensor::Tensor;

use crate::heads::gaussian::person_mask;

/// The source silhouette's rim, `[B, 1, H, W]`: 1 on the person's pixels (away from the
/// background colour) that have a background pixel among their four neighbours, 0 elsewhere.
/// The image's border does not count as background: a person cut off by the frame has no rim
/// there.
pub(crate) fn silhouette_rim(source_image: &Tensor<4>, background: &[f32]) -> Tensor<4> {
    let person = person_mask(source_image, background);
    let inner = [(2, 1), (2, -1), (3, 1), (3, -1)]
        .into_iter()
        .fold(person.clone(), |inner, (dim, step)| {
            inner.min_pair(neighbour(&person, dim, step))
        });
    person - inner
}

/// `x` shifted by one pixel along `dim` (2: rows, 3: columns) so that each pixel holds its
/// neighbour's value at `step` (+1 or -1), the border pixels their own.
fn neighbour(x: &Tensor<4>, dim: usize, step: i32) -> Tensor<4> {
    let n = x.dims()[dim];
    if n < 2 {
        return x.clone();
    }
    if step > 0 {
        Tensor::cat(
            vec![
                x.clone().narrow(dim, 1, n - 1),
                x.clone().narrow(dim, n - 1, 1),
            ],
            dim,
        )
    } else {
        Tensor::cat(
            vec![x.clone().narrow(dim, 0, 1), x.clone().narrow(dim, 0, n - 1)],
            dim,
        )
    }
}

/// Per pixel, the unit quaternion (`w x y z`) that turns the Gaussian's third axis onto the
/// pixel's ray, `[B, 4, H, W]`, from the unit ray directions `[B, 3, H, W]`. The axis is
/// symmetric, so the ray or its opposite, whichever keeps the quaternion away from zero: `a =
/// sign(d_z) d`, `q = (1 + a_z, -a_y, a_x, 0) / |..|`.
pub(crate) fn ray_rotations(directions: &Tensor<4>) -> Tensor<4> {
    let sign = directions
        .clone()
        .narrow(1, 2, 1)
        .greater_equal_elem(0.0)
        .float()
        .mul_scalar(2.0)
        .sub_scalar(1.0);
    let a = directions.clone() * sign;
    let q = Tensor::cat(
        vec![
            a.clone().narrow(1, 2, 1).add_scalar(1.0),
            a.clone().narrow(1, 1, 1).neg(),
            a.clone().narrow(1, 0, 1),
            a.narrow(1, 2, 1).zeros_like(),
        ],
        1,
    );
    q.clone() / q.powi_scalar(2).sum_dim(1).sqrt()
}

/// The raw offset `x` per pixel with `sigmoid(x)` placing a log-scale at `log(size)` within
/// `[lo + footprint, hi + footprint]` (natural logs; `footprint` the pixel's log-footprint,
/// `[B, 1, H, W]`), clamped inside the range.
pub(crate) fn scale_logits_for(size: f32, footprint: Tensor<4>, lo: f32, hi: f32) -> Tensor<4> {
    let u = footprint
        .neg()
        .add_scalar(size.ln() - lo)
        .div_scalar(hi - lo)
        .clamp(1e-6, 1.0 - 1e-6);
    (u.clone() / u.neg().add_scalar(1.0)).log()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::{ndarray, values};
    use burn::tensor::{Distribution, TensorData};

    #[test]
    fn the_rim_is_the_persons_edge_and_not_the_frame() {
        let device = ndarray();
        let (h, w) = (7, 8);
        // A person on rows 2..7 (touching the bottom of the frame), columns 2..6, on white.
        let mut data = vec![1.0f32; 3 * h * w];
        for y in 2..7 {
            for x in 2..6 {
                data[y * w + x] = 0.3;
            }
        }
        let image = Tensor::<4>::from_data(TensorData::new(data, [1, 3, h, w]), &device);
        let rim = values(&silhouette_rim(&image, &[1.0, 1.0, 1.0]));
        for y in 0..h {
            for x in 0..w {
                let person = (2..7).contains(&y) && (2..6).contains(&x);
                let edge = person && (y == 2 || x == 2 || x == 5);
                assert_eq!(rim[y * w + x], f32::from(u8::from(edge)), "({x}, {y})");
            }
        }
    }

    #[test]
    fn ray_rotations_turn_the_third_axis_onto_the_ray() {
        let device = ndarray();
        device.seed(2);
        let d = Tensor::<4>::random([2, 3, 3, 4], Distribution::Normal(0.0, 1.0), &device);
        let d = d.clone() / d.powi_scalar(2).sum_dim(1).sqrt();
        let q = values(&ray_rotations(&d));
        let d = values(&d);
        let plane = 12;
        for b in 0..2 {
            for i in 0..plane {
                let at = |c: usize, n: usize| b * n * plane + c * plane + i;
                let [w, x, y, z] = [0, 1, 2, 3].map(|c| q[at(c, 4)]);
                assert!((w * w + x * x + y * y + z * z - 1.0).abs() < 1e-5);
                // R(q) e_z, the third column of the rotation matrix.
                let axis = [
                    2.0 * (x * z + w * y),
                    2.0 * (y * z - w * x),
                    1.0 - 2.0 * (x * x + y * y),
                ];
                let ray = [0, 1, 2].map(|c| d[at(c, 3)]);
                let dot: f32 = axis.iter().zip(&ray).map(|(a, r)| a * r).sum();
                assert!((dot.abs() - 1.0).abs() < 1e-5, "{axis:?} against {ray:?}");
            }
        }
    }

    #[test]
    fn scale_logits_place_the_size_and_stay_in_range() {
        let device = ndarray();
        let (lo, hi) = (0.1f32.ln(), 10f32.ln());
        let footprint = Tensor::<4>::from_data(
            TensorData::new(vec![0.01f32.ln(), 0.02f32.ln(), 1e-6f32.ln()], [1, 1, 1, 3]),
            &device,
        );
        let x = scale_logits_for(0.03, footprint.clone(), lo, hi);
        let got = values(
            &burn::tensor::activation::sigmoid(x)
                .mul_scalar(hi - lo)
                .add_scalar(lo)
                .add(footprint),
        );
        assert!((got[0] - 0.03f32.ln()).abs() < 1e-4);
        assert!((got[1] - 0.03f32.ln()).abs() < 1e-4);
        // 30 000 footprints is out of range: the largest scale instead, 10 footprints.
        assert!((got[2] - (10.0 * 1e-6f32).ln()).abs() < 1e-3);
    }
}
