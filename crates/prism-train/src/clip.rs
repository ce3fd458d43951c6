//! Gradient clipping by the global norm, and the finiteness check of the non-finite guard.
//!
//! Burn's own `GradientClipping::Norm` clips every parameter's gradient separately; the
//! global-norm clipping of common practice treats all gradients as one vector:
//! `g <- g * min(1, c / |g|)` with `|g| = sqrt(sum over parameters of |g_p|^2)`.

use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::tensor::Tensor;

/// The global L2 norm of every gradient in `grads` of `module`'s parameters:
/// `sqrt(sum_p sum_i g_p,i^2)`. Computed on the device in one reduction, read back once.
/// NaN or infinite when any gradient element is.
///
/// # Panics
/// If the gradients are on several devices (move them to one first).
pub fn global_norm<M: Module>(module: &M, grads: &GradientsParams) -> f64 {
    struct SumSquares<'a> {
        grads: &'a GradientsParams,
        total: Option<Tensor<1>>,
    }
    impl ModuleVisitor for SumSquares<'_> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            if let Some(g) = self.grads.get::<D>(param.id) {
                let s = g.clone().mul(g).sum();
                self.total = Some(match self.total.take() {
                    Some(t) => t.add(s),
                    None => s,
                });
            }
        }
    }
    let mut visitor = SumSquares { grads, total: None };
    module.visit(&mut visitor);
    visitor.total.map_or(0.0, |t| {
        prism_core::reads::count_host_read();
        t.into_scalar::<f64>().sqrt()
    })
}

/// Multiplies every gradient of `module`'s parameters in `grads` by `factor`.
pub fn scale_gradients<M: Module>(
    module: &M,
    mut grads: GradientsParams,
    factor: f64,
) -> GradientsParams {
    struct Scale<'a> {
        grads: &'a mut GradientsParams,
        factor: f64,
    }
    impl ModuleVisitor for Scale<'_> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            if let Some(g) = self.grads.remove::<D>(param.id) {
                self.grads.register(param.id, g.mul_scalar(self.factor));
            }
        }
    }
    module.visit(&mut Scale {
        grads: &mut grads,
        factor,
    });
    grads
}

/// Clips `grads` to the global norm `max_norm` (no change when the norm is below it or when
/// `max_norm` is 0): `g <- g * max_norm / (norm + 1e-6)` when `norm > max_norm`.
/// Returns the gradients and the norm before clipping.
pub fn clip_global_norm<M: Module>(
    module: &M,
    grads: GradientsParams,
    max_norm: f64,
) -> (GradientsParams, f64) {
    let norm = global_norm(module, &grads);
    if max_norm > 0.0 && norm.is_finite() && norm > max_norm {
        (
            scale_gradients(module, grads, max_norm / (norm + 1e-6)),
            norm,
        )
    } else {
        (grads, norm)
    }
}

/// Copies every parameter of `module` to the host, by visiting order (for tests and the
/// equivalence checks of resume and multi-device training).
pub fn parameter_values<M: Module>(module: &M) -> Vec<Vec<f32>> {
    struct Collect(Vec<Vec<f32>>);
    impl ModuleVisitor for Collect {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.0.push(
                param
                    .val()
                    .into_data()
                    .convert::<f32>()
                    .try_into_vec::<f32>()
                    .expect("float parameter"),
            );
        }
    }
    let mut c = Collect(Vec::new());
    module.visit(&mut c);
    c.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::{Linear, LinearConfig};
    use prism_core::BackendKind;

    #[test]
    fn global_norm_and_clipping() {
        let device = BackendKind::Ndarray.device().unwrap().autodiff();
        let layer: Linear = LinearConfig::new(3, 2).init(&device);
        let x = Tensor::<2>::from_floats([[1.0, 2.0, 3.0]], &device);
        let loss = layer.forward(x).sum().mul_scalar(10.0);
        let grads = GradientsParams::from_grads(loss.backward(), &layer);
        // d/dW of 10 * sum(x W + b): every column is 10 x, so |g_W|^2 = 2 * 100 * 14 and
        // |g_b|^2 = 2 * 100.
        let expected = (2.0f64 * 100.0 * 14.0 + 200.0).sqrt();
        let norm = global_norm(&layer, &grads);
        assert!((norm - expected).abs() < 1e-4, "{norm} vs {expected}");
        let (clipped, before) = clip_global_norm(&layer, grads, 1.0);
        assert!((before - expected).abs() < 1e-4);
        let after = global_norm(&layer, &clipped);
        assert!((after - 1.0).abs() < 1e-5, "{after}");
        // Below the limit (or with 0) nothing changes.
        let (same, _) = clip_global_norm(&layer, clipped, 0.0);
        assert!((global_norm(&layer, &same) - after).abs() < 1e-9);
    }
}
