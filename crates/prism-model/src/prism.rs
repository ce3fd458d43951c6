//! The cascade (paper Sec. 3.2): tokenizer -> stage I -> injection point -> stage III -> NVS
//! head.

use burn::module::Module;
use burn::tensor::{Device, Tensor};

use crate::attention::AttentionKind;
use crate::block::{PrismBlock, PrismBlockConfig};
use crate::config::PrismConfig;
use crate::head::{NvsHead, NvsHeadConfig};
use crate::stages::{HiddenStates, StageOne, StageThree};
use crate::tokenizer::{Tokenizer, TokenizerConfig};

impl PrismConfig {
    /// Builds the model with fresh weights: every projection `N(0, init_std)`, the blocks'
    /// output projections `N(0, init_std / sqrt(2 (M + N)))`, norms' gains 1.
    ///
    /// # Panics
    /// If the config is invalid; check it first with [`PrismConfig::validate`] (which
    /// [`crate::load_config`] does).
    pub fn init(&self, device: &Device) -> Prism {
        if let Err(err) = self.validate() {
            panic!("cannot build the model: {err}");
        }
        let kinds = self.attention_kinds().expect("validated");
        let block = |kind: AttentionKind| {
            PrismBlockConfig::new(self.width, self.heads)
                .with_mlp_ratio(self.mlp_ratio)
                .with_init_std(self.init_std)
                .with_num_blocks(self.num_blocks())
                .with_attention(kind)
                .with_feature_map(self.linear_feature_map)
                .with_linear_eps(self.linear_eps)
                .with_norm_eps(self.norm_eps)
                .init(device)
        };
        let (one, three) = kinds.split_at(self.stage_one_blocks);
        Prism {
            tokenizer: TokenizerConfig::new(self.width, self.patch_size)
                .with_init_std(self.init_std)
                .with_norm_eps(self.norm_eps)
                .init(device),
            stage_one: StageOne {
                blocks: one.iter().map(|&k| block(k)).collect(),
            },
            stage_three: StageThree {
                blocks: three.iter().map(|&k| block(k)).collect(),
            },
            nvs_head: NvsHeadConfig::new(self.width, self.patch_size)
                .with_init_std(self.init_std)
                .with_norm_eps(self.norm_eps)
                .init(device),
        }
    }
}

/// What one forward pass of [`Prism`] returns.
#[derive(Debug, Clone)]
pub struct PrismOutput {
    /// The synthesised target view `I_t`, `[B, 3, H, W]` in (0, 1).
    pub image: Tensor<4>,
    /// The hidden states (block outputs, `[B, T, d]`) of the blocks asked for, in the order
    /// asked for; empty when none was asked for.
    pub hidden: Vec<Tensor<3>>,
    /// `T_out`, the output tokens of stage III, `[B, T_s + T_t, d]`, source tokens first.
    pub t_out: Tensor<3>,
    /// `T_s`, the number of source tokens at the front of the sequence.
    pub source_tokens: usize,
}

impl PrismOutput {
    /// The source tokens of `T_out`, `[B, T_s, d]` (what the 3DGS head reads).
    pub fn source_t_out(&self) -> Tensor<3> {
        self.t_out.clone().narrow(1, 0, self.source_tokens)
    }

    /// The target tokens of `T_out`, `[B, T_t, d]` (what the NVS head reads).
    pub fn target_t_out(&self) -> Tensor<3> {
        let total = self.t_out.dims()[1];
        self.t_out
            .clone()
            .narrow(1, self.source_tokens, total - self.source_tokens)
    }
}

/// The PrismMirror network: `T_in = Tokenizer(I_s, P_s, P_t)`, `T_mid = StageOne(T_in)`,
/// `T'_mid = inject(T_mid, T_in)`, `T_out = StageThree(T'_mid)`,
/// `I_t = NvsHead(target tokens of T_out)`.
#[derive(Module, Debug)]
pub struct Prism {
    /// Patches and rays to `T_in`.
    pub tokenizer: Tokenizer,
    /// The `M` encoder blocks.
    pub stage_one: StageOne,
    /// The `N` decoder blocks.
    pub stage_three: StageThree,
    /// The NVS decoder.
    pub nvs_head: NvsHead,
}

impl Prism {
    /// `M + N`.
    pub fn num_blocks(&self) -> usize {
        self.stage_one.blocks.len() + self.stage_three.blocks.len()
    }

    /// All blocks in global order (stage I then stage III).
    pub fn blocks(&self) -> impl Iterator<Item = &PrismBlock> {
        self.stage_one
            .blocks
            .iter()
            .chain(self.stage_three.blocks.iter())
    }

    fn blocks_mut(&mut self) -> impl Iterator<Item = &mut PrismBlock> {
        self.stage_one
            .blocks
            .iter_mut()
            .chain(self.stage_three.blocks.iter_mut())
    }

    /// The attention kind of every block, in global order.
    pub fn attention_kinds(&self) -> Vec<AttentionKind> {
        self.blocks().map(PrismBlock::attention_kind).collect()
    }

    /// Sets the attention kind of every block in place (weights untouched), e.g. from
    /// [`crate::progressive_schedule`].
    ///
    /// # Panics
    /// If `kinds` does not have one entry per block.
    pub fn set_attention_kinds(&mut self, kinds: &[AttentionKind]) {
        assert_eq!(
            kinds.len(),
            self.num_blocks(),
            "set_attention_kinds: {} kinds for {} blocks",
            kinds.len(),
            self.num_blocks()
        );
        for (block, &kind) in self.blocks_mut().zip(kinds) {
            block.set_attention(kind);
        }
    }

    /// The injection point between stage I and stage III (paper Stage II).
    ///
    /// `T'_mid = T_mid + g_smpl F_smpl + g_pts F_pts + g_res T_in`; the geometry branches are
    /// not part of this model yet, so this is the identity `T'_mid = T_mid` (which is also what
    /// the zero-initialised injection computes at initialisation).
    pub fn inject(&self, t_mid: Tensor<3>, _t_in: &Tensor<3>) -> Tensor<3> {
        t_mid
    }

    /// The forward pass on a batch of (source, target) pairs.
    ///
    /// - `source_image`: `[B, 3, H, W]` in [0, 1];
    /// - `source_rays`, `target_rays`: Plücker rays `[B, 6, H, W]`;
    /// - `hidden_layers`: global block indices (`0..M+N`) whose outputs to return in
    ///   [`PrismOutput::hidden`] (empty for none).
    ///
    /// `H` and `W` must be multiples of the patch size; any such size works (there is no
    /// positional embedding).
    ///
    /// # Panics
    /// On mismatched shapes or a hidden layer index `>= M + N`.
    pub fn forward(
        &self,
        source_image: Tensor<4>,
        source_rays: Tensor<4>,
        target_rays: Tensor<4>,
        hidden_layers: &[usize],
    ) -> PrismOutput {
        let num_blocks = self.num_blocks();
        if let Some(bad) = hidden_layers.iter().find(|&&i| i >= num_blocks) {
            panic!("hidden layer {bad} requested from a model of {num_blocks} blocks");
        }
        let [_, _, height, width] = target_rays.dims();
        let p = self.tokenizer.patch_size();
        let source_tokens = {
            let [_, _, h, w] = source_image.dims();
            (h / p) * (w / p)
        };
        let mut hidden = HiddenStates::new(hidden_layers);
        let t_in = self
            .tokenizer
            .forward(source_image, source_rays, target_rays);
        let t_mid = self.stage_one.forward(t_in.clone(), &mut hidden);
        let t_mid = self.inject(t_mid, &t_in);
        let t_out = self
            .stage_three
            .forward(t_mid, self.stage_one.blocks.len(), &mut hidden);
        let total = t_out.dims()[1];
        let target = t_out
            .clone()
            .narrow(1, source_tokens, total - source_tokens);
        let image = self.nvs_head.forward(target, height, width);
        PrismOutput {
            image,
            hidden: hidden.into_vec(),
            t_out,
            source_tokens,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::load_config;
    use crate::info::ParameterCounts;
    use crate::test_util::{max_abs_diff, ndarray, parameters, values};
    use burn::module::{ModuleVisitor, Param};
    use burn::tensor::Distribution;
    use burn::tensor::Gradients;
    use std::path::Path;

    fn config(name: &str) -> PrismConfig {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../../configs/{name}.toml"));
        load_config(path).unwrap().model
    }

    /// A batch of `b` random (source image, source rays, target rays) at `h x w`.
    fn inputs(b: usize, h: usize, w: usize, device: &Device) -> [Tensor<4>; 3] {
        device.seed(11);
        [
            Tensor::random([b, 3, h, w], Distribution::Uniform(0.0, 1.0), device),
            Tensor::random([b, 6, h, w], Distribution::Normal(0.0, 1.0), device),
            Tensor::random([b, 6, h, w], Distribution::Normal(0.0, 1.0), device),
        ]
    }

    fn forward(model: &Prism, x: &[Tensor<4>; 3], hidden: &[usize]) -> PrismOutput {
        model.forward(x[0].clone(), x[1].clone(), x[2].clone(), hidden)
    }

    #[test]
    fn output_shapes_and_hidden_states_only_when_asked() {
        let device = ndarray();
        let config = config("tiny");
        device.seed(1);
        let model = config.init(&device);
        // Not square and not the config's resolution: there is no positional embedding.
        let x = inputs(2, 32, 48, &device);
        let out = forward(&model, &x, &[]);
        assert_eq!(out.image.dims(), [2, 3, 32, 48]);
        assert_eq!(out.t_out.dims(), [2, 2 * 4 * 6, 64]);
        assert_eq!(out.source_tokens, 24);
        assert_eq!(out.source_t_out().dims(), [2, 24, 64]);
        assert_eq!(out.target_t_out().dims(), [2, 24, 64]);
        assert!(out.hidden.is_empty());
        let image = values(&out.image);
        assert!(image.iter().all(|&v| v > 0.0 && v < 1.0), "sigmoid output");

        let asked = [5, 1, 5];
        let with_hidden = forward(&model, &x, &asked);
        assert_eq!(with_hidden.hidden.len(), 3);
        for state in &with_hidden.hidden {
            assert_eq!(state.dims(), [2, 48, 64]);
        }
        // Block M + N - 1 is the last one: its output is T_out (the injection is the identity).
        assert_eq!(values(&with_hidden.hidden[0]), values(&with_hidden.t_out));
        assert_eq!(values(&with_hidden.hidden[2]), values(&with_hidden.t_out));
        // Block 1 (the last of stage I) gives T_mid, which the stage-III blocks then change.
        assert!(max_abs_diff(&values(&with_hidden.hidden[1]), &values(&with_hidden.t_out)) > 1e-3);
        // Asking for hidden states does not change the result.
        assert_eq!(values(&with_hidden.image), image);
    }

    #[test]
    #[should_panic(expected = "hidden layer 6")]
    fn a_hidden_layer_beyond_the_network_is_refused() {
        let device = ndarray();
        let model = config("tiny").init(&device);
        forward(&model, &inputs(1, 16, 16, &device), &[6]);
    }

    #[test]
    fn switching_attention_keeps_parameters_bit_identical() {
        let device = ndarray();
        let mut model = config("tiny").init(&device);
        let before = parameters(&model);
        let x = inputs(1, 32, 32, &device);
        let full = values(&forward(&model, &x, &[]).image);
        use AttentionKind::{Full as F, Linear as L};
        let mixed = [L, L, F, L, F, F];
        model.set_attention_kinds(&mixed);
        assert_eq!(model.attention_kinds(), mixed.to_vec());
        let after = parameters(&model);
        assert_eq!(before.len(), after.len());
        for ((name, a), (_, b)) in before.iter().zip(&after) {
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(a), bits(b), "{name} changed");
        }
        // The switch changes what the model computes, and switching back restores it.
        let hybrid = values(&forward(&model, &x, &[]).image);
        assert!(max_abs_diff(&full, &hybrid) > 1e-6);
        model.set_attention_kinds(&[F; 6]);
        assert_eq!(values(&forward(&model, &x, &[]).image), full);
    }

    /// Every float parameter's gradient, by path.
    fn gradients(model: &Prism, grads: &Gradients) -> Vec<(String, Option<Vec<f32>>)> {
        struct Collect<'a> {
            grads: &'a Gradients,
            path: Vec<String>,
            out: Vec<(String, Option<Vec<f32>>)>,
        }
        impl ModuleVisitor for Collect<'_> {
            fn enter_module(&mut self, name: &str, _: &str) {
                self.path.push(name.to_string());
            }
            fn exit_module(&mut self, _: &str, _: &str) {
                self.path.pop();
            }
            fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
                let grad = param.val().grad(self.grads).map(|g| values(&g));
                self.out.push((self.path.join("."), grad));
            }
        }
        let mut collect = Collect {
            grads,
            path: Vec::new(),
            out: Vec::new(),
        };
        model.visit(&mut collect);
        collect.out
    }

    #[test]
    fn every_parameter_gets_a_finite_nonzero_gradient() {
        use AttentionKind::{Full as F, Linear as L};
        let device = ndarray().autodiff();
        for kinds in [[F; 6], [L, F, L, L, F, F]] {
            device.seed(3);
            let mut model = config("tiny").init(&device);
            model.set_attention_kinds(&kinds);
            let x = inputs(2, 32, 32, &device);
            let target =
                Tensor::<4>::random([2, 3, 32, 32], Distribution::Uniform(0.0, 1.0), &device);
            let out = forward(&model, &x, &[2]);
            // An image loss plus a term on a hidden state, as distillation uses.
            let loss = (out.image - target).powi_scalar(2).mean()
                + out.hidden[0].clone().powi_scalar(2).mean() * 1e-3;
            let grads = loss.backward();
            let all = gradients(&model, &grads);
            assert_eq!(all.len(), 3 + 6 * 8 + 2, "parameter tensors");
            for (name, grad) in all {
                let grad = grad.unwrap_or_else(|| panic!("{kinds:?}: {name} has no gradient"));
                assert!(
                    grad.iter().all(|g| g.is_finite()),
                    "{kinds:?}: {name} not finite"
                );
                assert!(grad.iter().any(|&g| g != 0.0), "{kinds:?}: {name} is zero");
            }
        }
    }

    #[test]
    fn ndarray_and_flex_give_the_same_forward() {
        use AttentionKind::{Full as F, Linear as L};
        let nd = ndarray();
        let flex = prism_data::BackendKind::Flex.device().unwrap();
        let mut model = config("tiny").init(&nd);
        model.set_attention_kinds(&[F, L, F, L, L, F]);
        let on_flex = model.clone().to_device(&flex);
        assert_eq!(on_flex.attention_kinds(), model.attention_kinds());
        let x = inputs(2, 32, 32, &nd);
        let x_flex = x.clone().map(|t| t.to_device(&flex));
        let a = forward(&model, &x, &[1, 4]);
        let b = forward(&on_flex, &x_flex, &[1, 4]);
        let err = max_abs_diff(&values(&a.image), &values(&b.image));
        assert!(err < 1e-4, "image: max difference {err}");
        for (ha, hb) in a.hidden.iter().zip(&b.hidden) {
            let err = max_abs_diff(&values(ha), &values(hb));
            assert!(err < 1e-4, "hidden: max difference {err}");
        }
    }

    #[test]
    fn analytic_parameter_counts_match_the_built_models() {
        let device = ndarray();
        for name in ["tiny", "small"] {
            let config = config(name);
            let model = config.init(&device);
            let counts = ParameterCounts::of(&config);
            assert_eq!(counts.total, model.num_params(), "{name}");
            assert_eq!(counts.tokenizer, model.tokenizer.num_params(), "{name}");
            assert_eq!(counts.stage_one, model.stage_one.num_params(), "{name}");
            assert_eq!(counts.stage_three, model.stage_three.num_params(), "{name}");
            assert_eq!(counts.nvs_head, model.nvs_head.num_params(), "{name}");
        }
    }

    #[test]
    fn initialisation_follows_the_config() {
        let device = ndarray();
        device.seed(5);
        let config = config("small");
        let model = config.init(&device);
        let std = |v: &[f32]| {
            let mean = v.iter().sum::<f32>() / v.len() as f32;
            (v.iter().map(|x| (x - mean).powi(2)).sum::<f32>() / v.len() as f32).sqrt()
        };
        let block = &model.stage_three.blocks[0];
        let qkv = std(&values(&block.attention.qkv.weight.val()));
        let fc_out = std(&values(&block.mlp.fc_out.weight.val()));
        let out_std = 0.02 / (2.0f32 * 12.0).sqrt();
        assert!((qkv - 0.02).abs() < 0.02 * 0.05, "qkv std {qkv}");
        assert!(
            (fc_out - out_std).abs() < out_std * 0.05,
            "fc_out std {fc_out}"
        );
        let gamma = values(&block.attention_norm.gamma.val());
        assert!(gamma.iter().all(|&g| g == 1.0));
        assert!(block.attention_norm.beta.is_none(), "no biases");
        assert!(model.tokenizer.source.bias.is_none() && block.attention.qkv.bias.is_none());
    }
}
