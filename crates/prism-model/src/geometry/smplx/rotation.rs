//! The continuous 6D rotation representation (Zhou et al., CVPR 2019) that the SMPL-X branch
//! regresses joint rotations in.
//!
//! A rotation is given by two 3-vectors `a_1, a_2` (the first two columns of its matrix, before
//! orthonormalisation): `b_1 = a_1 / |a_1|`, `b_2 = normalise(a_2 - (b_1 . a_2) b_1)`,
//! `b_3 = b_1 x b_2`, `R = [b_1 b_2 b_3]` (columns). Unlike axis-angle or quaternions, every 6D
//! vector maps to a rotation continuously, which makes it easy to regress.

use burn::tensor::Tensor;

/// `eps` added under the square roots of the normalisations.
const NORM_EPS: f32 = 1e-8;

/// The 6D of the identity: `a_1 = (1, 0, 0)`, `a_2 = (0, 1, 0)`.
pub(crate) const IDENTITY_6D: [f32; 6] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0];

/// `[..., 3]` vectors divided by their length (with a small `eps` for stability).
fn normalise(v: Tensor<3>) -> Tensor<3> {
    let norm = (v.clone() * v.clone())
        .sum_dim(2)
        .add_scalar(NORM_EPS)
        .sqrt();
    v / norm
}

/// Rotation matrices `[B, J, 3, 3]` from 6D vectors `[B, J, 6]` laid out as `(a_1, a_2)`
/// (see the module docs). Differentiable.
pub(crate) fn rotation_6d_to_matrix(x: Tensor<3>) -> Tensor<4> {
    let [b, j, six] = x.dims();
    assert_eq!(six, 6, "6D rotations must have 6 components, got {six}");
    let a1 = x.clone().narrow(2, 0, 3);
    let a2 = x.narrow(2, 3, 3);
    let b1 = normalise(a1);
    let along = (b1.clone() * a2.clone()).sum_dim(2);
    let b2 = normalise(a2 - b1.clone() * along);
    let b3 = cross(&b1, &b2);
    // Columns b1 b2 b3: stack as [.., 3 (row), 3 (column)].
    Tensor::stack::<4>(vec![b1, b2, b3], 3).reshape([b, j, 3, 3])
}

/// The cross product of `[B, J, 3]` vectors.
fn cross(a: &Tensor<3>, b: &Tensor<3>) -> Tensor<3> {
    let c = |t: &Tensor<3>, i: usize| t.clone().narrow(2, i, 1);
    Tensor::cat(
        vec![
            c(a, 1) * c(b, 2) - c(a, 2) * c(b, 1),
            c(a, 2) * c(b, 0) - c(a, 0) * c(b, 2),
            c(a, 0) * c(b, 1) - c(a, 1) * c(b, 0),
        ],
        2,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::{ndarray, values};
    use burn::tensor::TensorData;
    use glam::{Mat3, Vec3};

    #[test]
    fn six_d_of_a_rotation_gives_the_rotation_back() {
        let device = ndarray();
        let rotations = [
            Mat3::IDENTITY,
            Mat3::from_axis_angle(Vec3::new(0.3, -0.8, 0.5).normalize(), 1.3),
            Mat3::from_axis_angle(Vec3::Z, -2.9),
        ];
        let mut six = Vec::new();
        for (k, r) in rotations.iter().enumerate() {
            // Scaled and skewed columns: the orthonormalisation must undo it.
            let a1 = r.x_axis * (1.0 + k as f32);
            let a2 = r.y_axis * 0.5 + r.x_axis * 0.3;
            six.extend(a1.to_array());
            six.extend(a2.to_array());
        }
        let x = Tensor::<3>::from_data(TensorData::new(six, [1, 3, 6]), &device);
        let m = values(&rotation_6d_to_matrix(x));
        for (k, r) in rotations.iter().enumerate() {
            for row in 0..3 {
                for col in 0..3 {
                    let got = m[k * 9 + row * 3 + col];
                    let want = r.col(col)[row];
                    assert!(
                        (got - want).abs() < 1e-5,
                        "{k} [{row}][{col}]: {got} vs {want}"
                    );
                }
            }
        }
        let id = Tensor::<3>::from_data(TensorData::new(IDENTITY_6D.to_vec(), [1, 1, 6]), &device);
        assert_eq!(
            values(&rotation_6d_to_matrix(id)),
            vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        );
    }
}
