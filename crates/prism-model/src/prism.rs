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
        let t_out =
            self.stage_three
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
