//! The NVS decoder (paper Sec. 3.1-3.2): target tokens to the target image.
//!
//! With `nvs_output = "direct"` (the paper) the decoder regresses the colours,
//! `I_t = sigmoid(Linear_out(LN(y)))`. With `nvs_output = "residual"` it corrects the 3DGS
//! head's render, `I_t = clamp(I_gs + Linear_out(LN(y)), 0, 1)`, with `Linear_out` starting at
//! zero: from scratch, regressing every pixel is far slower to learn than moving the source's
//! pixels with a depth and fixing what that misses (disocclusions, shading). The clamp passes
//! gradients wherever the result is inside (0, 1), so holes where `I_gs` shows the background
//! are filled through it.

use burn::config::Config;
use burn::module::Module;
use burn::nn::{Initializer, LayerNorm, LayerNormConfig, Linear, LinearConfig};
use burn::tensor::activation::{gelu, sigmoid};
use burn::tensor::{Device, Tensor};
use prism_kernels::linear;

use serde::{Deserialize, Serialize};

use crate::heads::{head_map, values_per_channel};
use crate::tokenizer::patch::patchify;

/// What the NVS decoder predicts (`nvs_output` in `[model]`; see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum NvsOutput {
    /// The colours, through a sigmoid (the paper).
    #[default]
    Direct,
    /// A correction of the 3DGS head's render (needs the 3DGS head).
    Residual,
}

/// Configuration of an [`NvsHead`].
#[derive(Config, Debug)]
pub(crate) struct NvsHeadConfig {
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
    /// What the decoder predicts.
    #[config(default = "NvsOutput::Direct")]
    pub output: NvsOutput,
    /// The residual decoder also sees the render: each target token gets its `I_gs` patch
    /// (see [`RenderInput`]).
    #[config(default = false)]
    pub sees_render: bool,
    /// The output map's resolution: 0 for a free value per pixel (the paper's unpatchify),
    /// `f` for `f x f` values per token upsampled bilinearly ([`head_map`]).
    #[config(default = 0)]
    pub upsample: usize,
}

impl NvsHeadConfig {
    /// Builds the head.
    pub(crate) fn init(&self, device: &Device) -> NvsHead {
        NvsHead {
            norm: LayerNormConfig::new(self.width)
                .with_bias(false)
                .with_epsilon(self.norm_eps)
                .init(device),
            linear: LinearConfig::new(
                self.width,
                3 * values_per_channel(self.patch_size, self.upsample),
            )
            .with_bias(false)
            .with_initializer(match self.output {
                NvsOutput::Direct => Initializer::Normal {
                    mean: 0.0,
                    std: self.init_std,
                },
                NvsOutput::Residual => Initializer::Zeros,
            })
            .init(device),
            render_input: self.sees_render.then(|| {
                let linear = |inputs: usize| {
                    LinearConfig::new(inputs, self.width)
                        .with_initializer(Initializer::Normal {
                            mean: 0.0,
                            std: self.init_std,
                        })
                        .init(device)
                };
                RenderInput {
                    embed: linear(3 * self.patch_size * self.patch_size),
                    hidden: linear(self.width),
                }
            }),
            patch_size: self.patch_size,
            upsample: self.upsample,
            output: self.output,
        }
    }
}

/// What lets the residual decoder see the render it corrects: the `I_gs` patch of each target
/// token, embedded and added to the normalised token, then one hidden layer,
/// `h = GELU(W_h (LN(y) + W_e patch(I_gs)))`, before `Linear_out`. Without it the correction is
/// a function of the tokens only, blind to what `I_gs` shows at each pixel.
#[derive(Module, Debug)]
pub struct RenderInput {
    /// `W_e`: a `3 p^2` render patch to the token width.
    pub embed: Linear,
    /// `W_h`: the hidden layer.
    pub hidden: Linear,
}

/// The NVS decoder: `I_t = unpatchify(sigmoid(Linear_out(LN(y))))` on the target tokens `y`,
/// or `clamp(I_gs + unpatchify(Linear_out(LN(y))), 0, 1)` (see the module docs).
#[derive(Module, Debug)]
pub struct NvsHead {
    /// LayerNorm (no bias) on the target tokens.
    pub norm: LayerNorm,
    /// `Linear_out`: width `d` to `3 p^2` colour values per patch, no bias.
    pub linear: Linear,
    /// The render's patches as an input of the residual decoder, when configured.
    pub render_input: Option<RenderInput>,
    patch_size: usize,
    #[module(skip)]
    upsample: usize,
    #[module(skip)]
    output: NvsOutput,
}

impl NvsHead {
    /// What the decoder predicts.
    pub fn output(&self) -> NvsOutput {
        self.output
    }

    /// The target image `[B, 3, H, W]` in [0, 1] from the target tokens `[B, (H/p)(W/p), d]`
    /// and, for `nvs_output = "residual"`, the 3DGS render `I_gs` `[B, 3, H, W]`.
    ///
    /// # Panics
    /// With `nvs_output = "residual"` and no render.
    pub fn forward(
        &self,
        target_tokens: Tensor<3>,
        height: usize,
        width: usize,
        render: Option<Tensor<4>>,
    ) -> Tensor<4> {
        let mut tokens = self.norm.forward(target_tokens);
        if let (Some(input), Some(render)) = (&self.render_input, &render) {
            let seen = linear(&input.embed, patchify(render.clone(), self.patch_size));
            tokens = gelu(linear(&input.hidden, tokens + seen));
        }
        let patches = linear(&self.linear, tokens);
        match self.output {
            NvsOutput::Direct => sigmoid(head_map(
                patches,
                3,
                height,
                width,
                self.patch_size,
                self.upsample,
            )),
            NvsOutput::Residual => {
                let render = render.expect("nvs_output = \"residual\" needs the 3DGS head");
                let correction =
                    head_map(patches, 3, height, width, self.patch_size, self.upsample);
                (render + correction).clamp(0.0, 1.0)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::{ndarray, values};
    use burn::tensor::Distribution;

    #[test]
    fn a_decoder_seeing_the_render_starts_at_it_and_corrects_it_by_what_it_shows() {
        let device = ndarray().autodiff();
        device.seed(3);
        let head = NvsHeadConfig::new(16, 4)
            .with_output(NvsOutput::Residual)
            .with_sees_render(true)
            .init(&device);
        let tokens = Tensor::<3>::random([1, 4, 16], Distribution::Normal(0.0, 1.0), &device);
        let render = Tensor::<4>::random([1, 3, 8, 8], Distribution::Uniform(0.2, 0.8), &device);
        let out = head.forward(tokens.clone(), 8, 8, Some(render.clone()));
        assert_eq!(values(&out), values(&render));
        // Every part of the render input gets a gradient once Linear_out has moved.
        let mut moved = head.clone();
        moved.linear.weight = moved
            .linear
            .weight
            .map(|w| w.random_like(Distribution::Normal(0.0, 0.1)));
        let out = moved.forward(tokens.clone(), 8, 8, Some(render.clone()));
        let grads = out.clone().sub_scalar(0.5).powi_scalar(2).mean().backward();
        let input = moved.render_input.as_ref().unwrap();
        for g in [
            input.embed.weight.val().grad(&grads),
            input.hidden.weight.val().grad(&grads),
        ] {
            assert!(values(&g.unwrap()).iter().any(|&v| v != 0.0));
        }
        // The correction depends on the render, not only on the tokens.
        let other = render.clone().add_scalar(0.1);
        let shifted = moved.forward(tokens, 8, 8, Some(other.clone()));
        let a = values(&(out - render));
        let b = values(&(shifted - other));
        assert!(a.iter().zip(&b).any(|(x, y)| (x - y).abs() > 1e-4));
    }

    #[test]
    fn residual_decoder_starts_at_the_render_and_learns_a_correction() {
        let device = ndarray().autodiff();
        device.seed(2);
        let head = NvsHeadConfig::new(16, 4)
            .with_output(NvsOutput::Residual)
            .init(&device);
        let tokens = Tensor::<3>::random([2, 4, 16], Distribution::Normal(0.0, 1.0), &device);
        let render = Tensor::<4>::random([2, 3, 8, 8], Distribution::Uniform(0.0, 1.0), &device);
        let out = head.forward(tokens.clone(), 8, 8, Some(render.clone()));
        assert_eq!(values(&out), values(&render));
        let grads = out.sub_scalar(0.5).powi_scalar(2).mean().backward();
        let g = values(&head.linear.weight.val().grad(&grads).unwrap());
        assert!(g.iter().any(|&v| v != 0.0));
        // The paper's decoder ignores the render and regresses through a sigmoid.
        let direct = NvsHeadConfig::new(16, 4).init(&device);
        let a = direct.forward(tokens.clone(), 8, 8, None);
        let b = direct.forward(tokens, 8, 8, Some(render));
        assert_eq!(values(&a), values(&b));
        assert!(values(&a).iter().all(|&v| v > 0.0 && v < 1.0));
    }
}
