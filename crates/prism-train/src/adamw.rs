//! The runs' optimizer: Burn's AdamW, its update computed in one pass on the CPU backends.
//!
//! Burn's `AdamW` computes a parameter's update as a dozen element-wise tensor ops, each a new
//! tensor written by one thread. On the backbone's training step that was 14% of the step's
//! time on one core, while the other waited (BENCHMARKS, "AdamW in one pass"). [`FusedAdamW`]
//! runs the same arithmetic as one kernel over the parameter, its gradient and both moments
//! ([`prism_kernels::adamw_step`]), split over threads, and gives Burn's values bit for bit.
//! Its state is Burn's `AdamWState`, so checkpoints are the same files either way. Tensors the
//! kernel does not take (GPU backends, other dtypes) step through Burn's `AdamW`.

use burn::optim::{
    AdamW, AdamWConfig, AdamWState, AdaptiveMomentumState, LearningRate, ModuleOptimizer, Optimizer,
};
use burn::tensor::{Device, Tensor};
use prism_kernels::AdamWStep;

/// AdamW with Burn's arithmetic and state, stepping host f32 parameters in one fused pass.
#[derive(Clone)]
pub struct FusedAdamW {
    /// Burn's optimizer, for the tensors the kernel does not take.
    burn: AdamW,
    /// The same settings for the kernel; each step fills in its learning rate and count.
    settings: AdamWStep,
}

impl FusedAdamW {
    /// The optimizer of `beta_1`, `beta_2`, `epsilon` and decoupled `weight_decay` (no
    /// AMSGrad, no cautious decay), as a whole-module optimizer.
    pub fn module_optimizer(
        beta_1: f32,
        beta_2: f32,
        epsilon: f32,
        weight_decay: f32,
    ) -> ModuleOptimizer {
        let burn = AdamWConfig::new()
            .with_beta_1(beta_1)
            .with_beta_2(beta_2)
            .with_epsilon(epsilon)
            .with_weight_decay(weight_decay)
            .build();
        let settings = AdamWStep {
            lr: 0.0,
            beta_1,
            beta_2,
            epsilon,
            weight_decay,
            time: 0,
        };
        ModuleOptimizer::from(Self { burn, settings })
    }
}

impl Optimizer for FusedAdamW {
    type State<const D: usize> = AdamWState<D>;

    fn step<const D: usize>(
        &self,
        lr: LearningRate,
        tensor: Tensor<D>,
        grad: Tensor<D>,
        state: Option<Self::State<D>>,
    ) -> (Tensor<D>, Option<Self::State<D>>) {
        if !(prism_kernels::is_fused(&tensor) && prism_kernels::is_fused(&grad)) {
            return self.burn.step(lr, tensor, grad, state);
        }
        let time = state.as_ref().map_or(0, |s| s.momentum.time) + 1;
        let moments = state.map(|s| (s.momentum.moment_1, s.momentum.moment_2));
        let step = AdamWStep {
            lr,
            time,
            ..self.settings
        };
        let (tensor, moment_1, moment_2) = prism_kernels::adamw_step(tensor, grad, moments, step);
        let momentum = AdaptiveMomentumState::new(time, moment_1, moment_2);
        (tensor, Some(AdamWState::new(momentum)))
    }

    fn to_device<const D: usize>(state: Self::State<D>, device: &Device) -> Self::State<D> {
        <AdamW as Optimizer>::to_device(state, device)
    }
}

#[cfg(test)]
mod tests {
    use burn::nn::{Linear, LinearConfig};
    use burn::optim::GradientsParams;
    use burn::tensor::{Distribution, Tensor};
    use prism_core::BackendKind;

    use super::*;

    /// A linear layer and a fixed regression for it, on `backend` under autodiff.
    fn problem(backend: BackendKind) -> (Linear, Tensor<2>, Tensor<2>) {
        let device = backend.device().unwrap().autodiff();
        device.seed(7);
        let layer = LinearConfig::new(48, 40).init(&device);
        let x = Tensor::<2>::random([64, 48], Distribution::Normal(0.0, 1.0), &device);
        let y = Tensor::<2>::random([64, 40], Distribution::Normal(0.0, 1.0), &device);
        (layer, x, y)
    }

    /// `layer` trained `steps` steps on `(x, y)` by `optim`: its weights after each step, the
    /// layer and the optimizer.
    fn train(
        mut optim: ModuleOptimizer,
        mut layer: Linear,
        (x, y): (&Tensor<2>, &Tensor<2>),
        steps: usize,
    ) -> (Vec<Vec<f32>>, Linear, ModuleOptimizer) {
        let mut values = Vec::new();
        for step in 0..steps {
            let loss = (layer.forward(x.clone()) - y.clone()).powi_scalar(2).mean();
            let grads = GradientsParams::from_grads(loss.backward(), &layer);
            // A learning rate that changes, as the runs' schedules do.
            let lr = 1e-2 / (1.0 + step as f64);
            layer = optim.step(lr, layer, grads);
            values.push(layer.weight.val().into_data().try_to_vec::<f32>().unwrap());
        }
        (values, layer, optim)
    }

    fn fused() -> ModuleOptimizer {
        FusedAdamW::module_optimizer(0.9, 0.999, 1e-8, 0.05)
    }

    fn burns() -> ModuleOptimizer {
        AdamWConfig::new()
            .with_beta_1(0.9)
            .with_beta_2(0.999)
            .with_epsilon(1e-8)
            .with_weight_decay(0.05)
            .init()
    }

    fn bits(values: &[Vec<f32>]) -> Vec<Vec<u32>> {
        values
            .iter()
            .map(|v| v.iter().map(|x| x.to_bits()).collect())
            .collect()
    }

    #[test]
    fn steps_as_burns_adamw_bit_for_bit_on_the_cpu_backends() {
        for backend in [BackendKind::Flex, BackendKind::Ndarray] {
            let (layer, x, y) = problem(backend);
            let (want, ..) = train(burns(), layer.clone(), (&x, &y), 5);
            let (got, ..) = train(fused(), layer, (&x, &y), 5);
            assert_eq!(bits(&got), bits(&want), "{backend:?}");
            // The weights moved: the comparison is not of two untouched layers.
            assert_ne!(want[0], want[4]);
        }
    }

    #[test]
    fn its_state_is_burns_and_resumes_either_way() {
        let (layer, x, y) = problem(BackendKind::Flex);
        let data = (&x, &y);
        let (_, fused_layer, fused_optim) = train(fused(), layer.clone(), data, 3);
        let (_, burn_layer, burn_optim) = train(burns(), layer, data, 3);
        // Each optimizer resumed from the other's state goes on as the other would.
        let from_fused = burns().load_record(fused_optim.to_record());
        let from_burn = fused().load_record(burn_optim.to_record());
        let (a, ..) = train(from_fused, fused_layer.clone(), data, 2);
        let (b, ..) = train(from_burn, burn_layer, data, 2);
        assert_eq!(bits(&a), bits(&b));
        // The state was loaded: a fresh optimizer takes other steps.
        let (fresh, ..) = train(burns(), fused_layer, data, 2);
        assert_ne!(bits(&a), bits(&fresh));
    }
}
