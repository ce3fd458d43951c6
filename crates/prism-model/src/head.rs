//! The NVS decoder (paper Sec. 3.1-3.2): target tokens to the target image.

use burn::config::Config;
use burn::module::Module;
use burn::nn::{Initializer, LayerNorm, LayerNormConfig, Linear, LinearConfig};
use burn::tensor::activation::sigmoid;
use burn::tensor::{Device, Tensor};

use crate::patch::unpatchify;

/// Configuration of an [`NvsHead`].
#[derive(Config, Debug)]
pub struct NvsHeadConfig {
    /// Token width `d`.
    pub width: usize,
    /// Patch size `p`.
    pub patch_size: usize,
    /// Standard deviation of the projection's normal initialisation.
    #[config(default = 0.02)]
    pub init_std: f64,
    /// `eps` of the LayerNorm.
    #[config(default = 1e-5)]
    pub norm_eps: f64,
}

impl NvsHeadConfig {
    /// Builds the head.
    pub fn init(&self, device: &Device) -> NvsHead {
        NvsHead {
            norm: LayerNormConfig::new(self.width)
                .with_bias(false)
                .with_epsilon(self.norm_eps)
                .init(device),
            linear: LinearConfig::new(self.width, 3 * self.patch_size * self.patch_size)
                .with_bias(false)
                .with_initializer(Initializer::Normal {
                    mean: 0.0,
                    std: self.init_std,
                })
                .init(device),
            patch_size: self.patch_size,
        }
    }
}

/// The NVS decoder: `I_t = unpatchify(sigmoid(Linear_out(LN(y))))` on the target tokens `y`.
#[derive(Module, Debug)]
pub struct NvsHead {
    /// LayerNorm (no bias) on the target tokens.
    pub norm: LayerNorm,
    /// `Linear_out`: width `d` to `3 p^2` colour values per patch, no bias.
    pub linear: Linear,
    patch_size: usize,
}

impl NvsHead {
    /// The target image `[B, 3, H, W]` in (0, 1) from the target tokens `[B, (H/p)(W/p), d]`.
    pub fn forward(&self, target_tokens: Tensor<3>, height: usize, width: usize) -> Tensor<4> {
        let patches = sigmoid(self.linear.forward(self.norm.forward(target_tokens)));
        unpatchify(patches, 3, height, width, self.patch_size)
    }
}
