//! Helpers shared by the integration tests: seeded random tensors and finite differences.

use burn::tensor::{Device, Tensor, TensorData};
use prism_core::BackendKind;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The ndarray device (the backend the tests must pass on).
pub fn ndarray() -> Device {
    BackendKind::Ndarray.device().unwrap()
}

/// Seeded uniform values in `[lo, hi)`.
pub fn uniform(seed: u64, len: usize, lo: f32, hi: f32) -> Vec<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..len).map(|_| rng.random_range(lo..hi)).collect()
}

/// A tensor from host values.
pub fn tensor<const D: usize>(values: Vec<f32>, shape: [usize; D], device: &Device) -> Tensor<D> {
    Tensor::from_data(TensorData::new(values, shape), device)
}

/// Host values of a tensor.
pub fn host<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_into_vec_as::<f32>().unwrap()
}

/// Checks the gradient `grad` of `f` at `x` against central differences along `direction`:
/// `<grad, v>` vs `(f(x + h v) - f(x - h v)) / 2h`, within `tol` relative to
/// `max(|<grad, v>|, sum_i |grad_i v_i|)` (the second guards against directions along which
/// the terms cancel, where f32 rounding of the value would dominate).
pub fn check_directional(
    f: &dyn Fn(&[f32]) -> f64,
    x: &[f32],
    grad: &[f32],
    direction: &[f32],
    h: f32,
    tol: f64,
    what: &str,
) {
    let shifted = |sign: f32| -> Vec<f32> {
        x.iter()
            .zip(direction)
            .map(|(&a, &v)| a + sign * h * v)
            .collect()
    };
    let numeric = (f(&shifted(1.0)) - f(&shifted(-1.0))) / (2.0 * f64::from(h));
    let analytic: f64 = grad
        .iter()
        .zip(direction)
        .map(|(&g, &v)| f64::from(g) * f64::from(v))
        .sum();
    let magnitude: f64 = grad
        .iter()
        .zip(direction)
        .map(|(&g, &v)| (f64::from(g) * f64::from(v)).abs())
        .sum();
    let scale = analytic.abs().max(magnitude).max(1e-6);
    assert!(
        (analytic - numeric).abs() / scale < tol,
        "{what}: analytic {analytic} vs finite difference {numeric}"
    );
    eprintln!("{what}: analytic {analytic:.6} finite difference {numeric:.6} scale {scale:.4}");
}
