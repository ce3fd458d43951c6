//! Half precision for the transformer blocks: their matrix products and activations in `f16`
//! (or `bf16`), everything around them (tokenizer, geometry branches, heads, losses) in `f32`,
//! in inference and in training alike.
//!
//! The blocks are where nearly all of the time goes (paper Sec. 4: attention and MLPs over
//! `T` tokens); the geometry parts read camera math and body models that want `f32`. Each
//! block has a compute precision (a setting, not a parameter): its forward pass casts its input
//! and its weights to it, and stage I and stage III cast their output (and any hidden state
//! taken out) back to `f32`. The casts are differentiable, so in training the parameters stay
//! `f32` master weights (and AdamW's moments `f32`) while autodiff brings each weight's
//! gradient back to `f32` through its cast ([`Prism::with_compute_precision`]). The
//! statistics of LayerNorm and the QK RMSNorms and the sums of linear attention are taken in
//! `f32` whatever the compute precision (see [`prism_kernels::unfused`] and
//! [`prism_kernels::unfused::linear_attention`]).

use std::fmt;
use std::str::FromStr;

use burn::module::{Module, ModuleMapper, Param};
use burn::tensor::{Device, FloatDType, Tensor};
use serde::{Deserialize, Serialize};

use crate::prism::Prism;
use crate::stages::block::PrismBlock;
use crate::stages::cast;

/// The floating-point precision the transformer blocks compute in (`f32`, `f16` or `bf16`
/// in config files, JSON and on the command line).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    /// 32-bit floats (the default).
    #[default]
    F32,
    /// IEEE half precision (10-bit mantissa).
    F16,
    /// bfloat16 (8-bit mantissa, f32's exponent range).
    Bf16,
}

impl Precision {
    /// The Burn float dtype.
    pub fn dtype(self) -> FloatDType {
        match self {
            Self::F32 => FloatDType::F32,
            Self::F16 => FloatDType::F16,
            Self::Bf16 => FloatDType::BF16,
        }
    }

    /// Whether `device` computes with this precision (storage and arithmetic). Every backend
    /// computes in f32, so only half precision asks the device (a served device answers over
    /// the network).
    pub fn supported_on(self, device: &Device) -> bool {
        self == Self::F32 || device.supports_dtype(self.dtype())
    }
}

impl FromStr for Precision {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "f32" => Ok(Self::F32),
            "f16" => Ok(Self::F16),
            "bf16" => Ok(Self::Bf16),
            _ => Err(format!(
                "unknown precision `{s}` (expected f32, f16 or bf16)"
            )),
        }
    }
}

impl fmt::Display for Precision {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::F32 => "f32",
            Self::F16 => "f16",
            Self::Bf16 => "bf16",
        })
    }
}

/// Casts every float parameter of a module to one dtype. On a tracked parameter the cast is a
/// node of the autodiff graph: the gradient reaches the parameter in its own dtype.
pub(crate) struct CastParams(pub(crate) FloatDType);

impl ModuleMapper for CastParams {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let dtype = self.0;
        param.map(|t| cast(t, dtype))
    }
}

impl Prism {
    /// The model with its transformer blocks (stage I and stage III) computing in
    /// `precision`, the parameters left as they are: what training uses, the parameters
    /// staying `f32` master weights whose gradients come back `f32`. The rest of the model
    /// computes in `f32`, and the forward pass still takes and returns `f32`.
    pub fn with_compute_precision(mut self, precision: Precision) -> Self {
        for block in self.blocks_mut() {
            block.set_compute_precision(precision);
        }
        self
    }

    /// The model with its transformer blocks computing in `precision` and their weights
    /// stored in the dtype they compute in ([`PrismBlock::working_dtype`]: bf16 on the CPU
    /// backends keeps f32 weights), for inference. Storing the weights in half precision
    /// halves their memory and saves casting every weight at every forward pass (one more
    /// kernel per weight per block, and a second copy of it), which is why inference stores
    /// them so; a model to be trained keeps `f32` weights ([`Prism::with_compute_precision`]),
    /// since an optimizer step on half-precision weights would round small updates away.
    /// [`Precision::F32`] gives the blocks back their training precision (exactly, from
    /// `f32`; after a round trip through half precision the rounding stays).
    pub fn with_block_precision(self, precision: Precision) -> Self {
        let mut model = self.with_compute_precision(precision);
        let dtype = match (model.blocks().next(), model.devices().first()) {
            (Some(block), Some(device)) => block.working_dtype(device),
            _ => precision.dtype(),
        };
        let mut mapper = CastParams(dtype);
        model.stage_one = model.stage_one.map(&mut mapper);
        model.stage_three = model.stage_three.map(&mut mapper);
        model
    }

    /// The precision the transformer blocks compute in (the first block's; every block has the
    /// same unless set one by one).
    pub fn block_precision(&self) -> Precision {
        self.blocks()
            .next()
            .map_or(Precision::F32, PrismBlock::compute_precision)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol_views;
    use crate::stages::attention::AttentionKind;
    use crate::test_util::{max_abs_diff, tiny_with, values};
    use burn::module::ModuleVisitor;
    use burn::tensor::{DType, Distribution};
    use prism_core::rays::plucker_rays;

    /// A source image and the rays of one protocol pair at 16 px.
    fn pair(device: &Device) -> [Tensor<4>; 3] {
        let views = protocol_views(1, 16);
        device.seed(5);
        let image = Tensor::<4>::random([1, 3, 16, 16], Distribution::Uniform(0.0, 1.0), device);
        [
            image,
            plucker_rays(&views.source, device),
            plucker_rays(&views.target, device),
        ]
    }

    /// The backbone in f16 on flex: f32 in and out, close to the f32 model (half precision
    /// keeps about 3 decimal digits), and back to f32 exactly when cast back from f32 weights.
    /// Computing in f16 from f32 weights gives what stored f16 weights give.
    #[test]
    fn half_precision_blocks_stay_close_to_f32() {
        let device = Device::flex();
        assert!(Precision::F16.supported_on(&device));
        device.seed(3);
        let model = tiny_with(false, false, false).init(&device);
        let [image, rs, rt] = pair(&device);
        let run = |m: &Prism| m.forward(image.clone(), rs.clone(), rt.clone(), &[1]);
        let reference = run(&model);
        let half = model.clone().with_block_precision(Precision::F16);
        assert_eq!(half.block_precision(), Precision::F16);
        let out = run(&half);
        assert_eq!(out.image.dtype(), DType::F32);
        assert_eq!(out.hidden[0].dtype(), DType::F32);
        let err = max_abs_diff(&values(&out.image), &values(&reference.image));
        assert!(err > 0.0 && err < 5e-3, "f16 image error {err}");
        let hidden_err = max_abs_diff(&values(&out.hidden[0]), &values(&reference.hidden[0]));
        assert!(hidden_err < 2e-2, "f16 hidden error {hidden_err}");
        let computed = model.clone().with_compute_precision(Precision::F16);
        assert!(computed.blocks().all(|b| b.dtype() == DType::F32));
        assert_eq!(values(&run(&computed).image), values(&out.image));
        let back = model.clone().with_block_precision(Precision::F32);
        assert_eq!(values(&run(&back).image), values(&reference.image));
    }

    /// Every float parameter's value dtype, and its gradient in `grads` (values and dtype).
    fn gradients(model: &Prism, grads: &burn::tensor::Gradients) -> Vec<(DType, DType, Vec<f32>)> {
        struct Collect<'a>(&'a burn::tensor::Gradients, Vec<(DType, DType, Vec<f32>)>);
        impl ModuleVisitor for Collect<'_> {
            fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
                let value = param.val();
                let grad = value.grad(self.0).expect("every parameter has a gradient");
                self.1.push((value.dtype(), grad.dtype(), values(&grad)));
            }
        }
        let mut collect = Collect(grads, Vec::new());
        model.visit(&mut collect);
        collect.1
    }

    /// Mixed-precision training: with the blocks computing in f16 or bf16 (softmax and linear
    /// attention both), the parameters and their gradients stay f32 and the gradients are
    /// those of the f32 model up to half precision's rounding (relative to the whole gradient's
    /// norm: f16 keeps 11 significant bits, bf16 8).
    #[test]
    fn compute_precision_trains_f32_weights_with_gradients_close_to_f32() {
        let device = Device::flex().autodiff();
        device.seed(3);
        let mut model = tiny_with(false, false, false).init(&device);
        let kinds: Vec<AttentionKind> = (0..model.num_blocks())
            .map(|i| [AttentionKind::Full, AttentionKind::Linear][i % 2])
            .collect();
        model.set_attention_kinds(&kinds);
        let [image, rs, rt] = pair(&device);
        let target = Tensor::<4>::random([1, 3, 16, 16], Distribution::Uniform(0.0, 1.0), &device);
        let grads_of = |m: &Prism| {
            let out = m.forward(image.clone(), rs.clone(), rt.clone(), &[]);
            let loss = (out.image - target.clone()).square().mean();
            gradients(m, &loss.backward())
        };
        let reference = grads_of(&model);
        let norm = |g: &[(DType, DType, Vec<f32>)]| {
            g.iter()
                .flat_map(|(_, _, v)| v.iter().map(|x| (*x as f64).powi(2)))
                .sum::<f64>()
                .sqrt()
        };
        for (precision, tolerance) in [(Precision::F16, 5e-3), (Precision::Bf16, 4e-2)] {
            let half = model.clone().with_compute_precision(precision);
            let got = grads_of(&half);
            assert_eq!(got.len(), reference.len());
            assert!(
                got.iter()
                    .all(|(v, g, _)| *v == DType::F32 && *g == DType::F32),
                "{precision}: parameters and gradients stay f32"
            );
            let diff: f64 = got
                .iter()
                .zip(&reference)
                .flat_map(|((_, _, a), (_, _, b))| {
                    a.iter()
                        .zip(b)
                        .map(|(x, y)| (*x as f64 - *y as f64).powi(2))
                })
                .sum::<f64>()
                .sqrt();
            let relative = diff / norm(&reference);
            assert!(
                relative > 0.0 && relative < tolerance,
                "{precision}: relative gradient error {relative}"
            );
        }
    }

    #[test]
    fn precision_names_round_trip() {
        for p in [Precision::F32, Precision::F16, Precision::Bf16] {
            assert_eq!(p.to_string().parse::<Precision>().unwrap(), p);
            let json = serde_json::to_string(&p).unwrap();
            assert_eq!(json, format!("\"{p}\""));
            assert_eq!(serde_json::from_str::<Precision>(&json).unwrap(), p);
        }
        assert!("f8".parse::<Precision>().unwrap_err().contains("f8"));
    }
}
