//! Half-precision inference: the transformer blocks' weights and activations in `f16` (or
//! `bf16`), everything around them (tokenizer, geometry branches, heads) in `f32`.
//!
//! The blocks are where nearly all of the time goes (paper Sec. 4: attention and MLPs over
//! `T` tokens); the geometry parts read camera math and body models that want `f32`. Stage I
//! and stage III cast their input to the blocks' dtype once and their output (and any hidden
//! state taken out) back to `f32`. Linear attention accumulates in `f32` whatever the dtype
//! (see [`crate::stages::attention::linear_attention`]).

use std::fmt;
use std::str::FromStr;

use burn::module::{Module, ModuleMapper, Param};
use burn::tensor::{DType, Device, FloatDType, Tensor};

use crate::prism::Prism;
use crate::stages::cast;

/// The floating-point precision of the transformer blocks at inference.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Precision {
    /// 32-bit floats (training precision; the default).
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

    /// Whether `device` computes with this precision (storage and arithmetic).
    pub fn supported_on(self, device: &Device) -> bool {
        device.supports_dtype(self.dtype())
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

/// Casts every float parameter of a module to one dtype.
struct CastParams(FloatDType);

impl ModuleMapper for CastParams {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let dtype = self.0;
        param.map(|t| cast(t, dtype))
    }
}

impl Prism {
    /// The model with its transformer blocks (stage I and stage III) in `precision`, for
    /// inference; the rest stays `f32`, and the forward pass still takes and returns `f32`.
    /// [`Precision::F32`] gives the blocks back their training precision (exactly, from
    /// `f32`; after a round trip through half precision the rounding stays).
    pub fn with_block_precision(mut self, precision: Precision) -> Self {
        let mut mapper = CastParams(precision.dtype());
        self.stage_one = self.stage_one.map(&mut mapper);
        self.stage_three = self.stage_three.map(&mut mapper);
        self
    }

    /// The precision of the transformer blocks (that of the first block's weights).
    pub fn block_precision(&self) -> Precision {
        match self.blocks().next().map(|b| b.dtype()) {
            Some(DType::F16) => Precision::F16,
            Some(DType::BF16) => Precision::Bf16,
            _ => Precision::F32,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol_views;
    use crate::test_util::{max_abs_diff, tiny_with, values};
    use burn::tensor::Distribution;
    use prism_core::rays::plucker_rays;

    /// The backbone in f16 on flex: f32 in and out, close to the f32 model (half precision
    /// keeps about 3 decimal digits), and back to f32 exactly when cast back from f32 weights.
    #[test]
    fn half_precision_blocks_stay_close_to_f32() {
        let device = Device::flex();
        assert!(Precision::F16.supported_on(&device));
        device.seed(3);
        let model = tiny_with(false, false, false).init(&device);
        let views = protocol_views(1, 16);
        let image = Tensor::<4>::random([1, 3, 16, 16], Distribution::Uniform(0.0, 1.0), &device);
        let (rs, rt) = (
            plucker_rays(&views.source, &device),
            plucker_rays(&views.target, &device),
        );
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
        let back = model.clone().with_block_precision(Precision::F32);
        assert_eq!(values(&run(&back).image), values(&reference.image));
    }

    #[test]
    fn precision_names_round_trip() {
        for p in [Precision::F32, Precision::F16, Precision::Bf16] {
            assert_eq!(p.to_string().parse::<Precision>().unwrap(), p);
        }
        assert!("f8".parse::<Precision>().unwrap_err().contains("f8"));
    }
}
