//! The tokenizer (paper Sec. 3.1): source and target patches to the input sequence `T_in`.

pub(crate) mod patch;

use burn::config::Config;
use burn::module::Module;
use burn::nn::{Initializer, LayerNorm, LayerNormConfig, Linear, LinearConfig};
use burn::tensor::{Device, Tensor};

use patch::patchify;

/// Channels of a source pixel: `[2I - 1 (3), P_s (6)]`.
pub(crate) const SOURCE_CHANNELS: usize = 9;
/// Channels of a target pixel: `P_t (6)`.
pub(crate) const TARGET_CHANNELS: usize = 6;

/// Configuration of a [`Tokenizer`].
#[derive(Config, Debug)]
pub(crate) struct TokenizerConfig {
    /// Token width `d`.
    pub width: usize,
    /// Patch size `p`.
    pub patch_size: usize,
    /// Standard deviation of the projections' normal initialisation.
    #[config(default = 0.02)]
    pub init_std: f64,
    /// `eps` of the LayerNorm on the sequence.
    #[config(default = 1e-5)]
    pub norm_eps: f64,
}

impl TokenizerConfig {
    /// Builds the tokenizer.
    pub(crate) fn init(&self, device: &Device) -> Tokenizer {
        let features = self.patch_size * self.patch_size;
        let linear = |channels: usize| {
            LinearConfig::new(features * channels, self.width)
                .with_bias(false)
                .with_initializer(Initializer::Normal {
                    mean: 0.0,
                    std: self.init_std,
                })
                .init(device)
        };
        Tokenizer {
            source: linear(SOURCE_CHANNELS),
            target: linear(TARGET_CHANNELS),
            norm: LayerNormConfig::new(self.width)
                .with_bias(false)
                .with_epsilon(self.norm_eps)
                .init(device),
            patch_size: self.patch_size,
        }
    }
}

/// Turns a (source, target) pair into the input sequence of the cascade:
///
/// `x_j = Linear_inp([2 I_s - 1, P_s]_j)`, `q_j = Linear_tar(P_t,j)`,
/// `T_in = LN([x, q])`.
#[derive(Module, Debug)]
pub struct Tokenizer {
    /// `Linear_inp`: source patches (`9 p^2` features) to width `d`, no bias.
    pub source: Linear,
    /// `Linear_tar`: target ray patches (`6 p^2` features) to width `d`, no bias.
    pub target: Linear,
    /// LayerNorm (no bias) on the concatenated sequence.
    pub norm: LayerNorm,
    patch_size: usize,
}

impl Tokenizer {
    /// The patch size `p`.
    pub fn patch_size(&self) -> usize {
        self.patch_size
    }

    /// Source tokens `x`: `[B, (H/p)(W/p), d]` from the image `[B, 3, H, W]` in [0, 1] and its
    /// Plücker rays `[B, 6, H, W]`.
    pub fn source_tokens(&self, image: Tensor<4>, rays: Tensor<4>) -> Tensor<3> {
        let pixels = Tensor::cat(vec![image * 2.0 - 1.0, rays], 1);
        prism_kernels::linear(&self.source, patchify(pixels, self.patch_size))
    }

    /// Target tokens `q`: `[B, (H/p)(W/p), d]` from the target Plücker rays `[B, 6, H, W]`.
    pub fn target_tokens(&self, rays: Tensor<4>) -> Tensor<3> {
        prism_kernels::linear(&self.target, patchify(rays, self.patch_size))
    }

    /// `T_in = LN([x, q])`: `[B, T_s + T_t, d]`, source tokens first.
    ///
    /// # Panics
    /// If the image sizes are not multiples of the patch size or the batches differ.
    pub fn forward(
        &self,
        source_image: Tensor<4>,
        source_rays: Tensor<4>,
        target_rays: Tensor<4>,
    ) -> Tensor<3> {
        let x = self.source_tokens(source_image, source_rays);
        let q = self.target_tokens(target_rays);
        self.norm.forward(Tensor::cat(vec![x, q], 1))
    }
}
