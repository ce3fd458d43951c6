//! Reordering a tensor's axes in a form every backend runs, served devices included.
//!
//! Burn 0.22.1's fusion client records a float `permute` as an *int* operation. A local fused
//! backend does not mind (it runs the closure it was given), but a served device (Burn's remote
//! backend, which is fusion-wrapped whenever Burn's `fusion` feature is on, as it is in the GPU
//! build) replays the recorded operation on the server, which then looks for an int tensor,
//! finds a float one and drops the session. [`permute`] builds the same reordering out of axis
//! swaps, which are recorded correctly; like `permute`, each swap only changes the view.

use burn::tensor::Tensor;

/// `tensor` with its axes reordered: axis `i` of the result is axis `axes[i]` of `tensor`, as
/// [`Tensor::permute`] does.
///
/// # Panics
/// If `axes` is not a permutation of `0..D`.
pub fn permute<const D: usize>(tensor: Tensor<D>, axes: [usize; D]) -> Tensor<D> {
    let mut seen = [false; D];
    for &axis in &axes {
        assert!(
            axis < D && !std::mem::replace(&mut seen[axis], true),
            "{axes:?} is not a permutation of 0..{D}"
        );
    }
    // Selection by swaps: `current[i]` is the source axis now at position `i`.
    let mut current: [usize; D] = std::array::from_fn(|i| i);
    let mut tensor = tensor;
    for (position, &wanted) in axes.iter().enumerate() {
        let at = current
            .iter()
            .position(|&axis| axis == wanted)
            .expect("a permutation holds every axis");
        if at != position {
            tensor = tensor.swap_dims(position, at);
            current.swap(position, at);
        }
    }
    tensor
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::{Device, TensorData};

    /// Every permutation of four axes agrees with Burn's own `permute`, values and shape.
    #[allow(clippy::disallowed_methods)] // the reference the helper is checked against
    #[test]
    fn matches_burn_permute_for_every_order_of_four_axes() {
        let device = Device::default();
        let values: Vec<f32> = (0..2 * 3 * 4 * 5).map(|v| v as f32).collect();
        let tensor = Tensor::<4>::from_data(TensorData::new(values, [2, 3, 4, 5]), &device);
        let mut orders = Vec::new();
        for a in 0..4 {
            for b in 0..4 {
                for c in 0..4 {
                    for d in 0..4 {
                        let axes = [a, b, c, d];
                        let mut sorted = axes;
                        sorted.sort_unstable();
                        if sorted == [0, 1, 2, 3] {
                            orders.push(axes);
                        }
                    }
                }
            }
        }
        assert_eq!(orders.len(), 24);
        for axes in orders {
            let ours = permute(tensor.clone(), axes);
            let burn = tensor.clone().permute(axes);
            assert_eq!(ours.dims(), burn.dims(), "{axes:?}");
            assert_eq!(ours.into_data(), burn.into_data(), "{axes:?}");
        }
    }

    #[test]
    #[should_panic(expected = "is not a permutation")]
    fn refuses_a_repeated_axis() {
        let tensor = Tensor::<3>::zeros([1, 2, 3], &Device::default());
        let _ = permute(tensor, [0, 1, 1]);
    }
}
