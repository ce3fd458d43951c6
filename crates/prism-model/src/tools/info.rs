//! Size and cost of a model, computed from its config without building it (so `prism info`
//! answers at once even at paper scale).
//!
//! FLOPs count the matrix products only, 2 FLOPs per multiply-add; element-wise work (norms,
//! GELU, softmax, feature maps, residual adds) is left out. With `T` tokens per sequence, width
//! `d`, head dim `d_h` and MLP ratio `r`, per block:
//!
//! - projections and MLP: `2 T (3d^2 + d^2 + 2 r d^2)` (`24 T d^2` for `r = 4`);
//! - Full attention: `Q K^T` and `A V`, `2 T^2 d` each: `4 T^2 d`, quadratic in `T`;
//! - Linear attention: `phi(K)^T V` and `phi(Q) (phi(K)^T V)`, `2 T d d_h` each, plus the
//!   normaliser (`sum_j phi(k_j)` and `phi(q_i) . k_sum`, counted as `2 T d` each):
//!   `4 T d (d_h + 1)`, linear in `T`.
//!
//! The tokenizer costs `2 (T/2) (9 + 6) p^2 d`, the NVS head `2 (T/2) d 3 p^2`; the geometry
//! parts' dense layers are counted in [`FlopCounts::geometry`].

use serde::Serialize;

use crate::config::PrismConfig;
use crate::geometry::points::dpt::{dpt_taps, reassemble_factors};
use crate::geometry::smplx::SMPLX_OUTPUTS;
use crate::heads::gaussian::GAUSSIAN_CHANNELS;
use crate::heads::nvs::NvsOutput;
use crate::stages::attention::AttentionKind;
use crate::tokenizer::{SOURCE_CHANNELS, TARGET_CHANNELS};

/// Parameter counts of a model, total and per part.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct ParameterCounts {
    /// Everything.
    pub total: usize,
    /// The tokenizer (two projections and the LayerNorm).
    pub tokenizer: usize,
    /// The `M` blocks of stage I.
    pub stage_one: usize,
    /// The `N` blocks of stage III.
    pub stage_three: usize,
    /// The NVS head.
    pub nvs_head: usize,
    /// The injection: zero convolutions of the enabled branches and the gates.
    pub injection: usize,
    /// The SMPL-X branch (adapter, regressor, triplane); 0 when disabled.
    pub smplx_branch: usize,
    /// The point branch (DPT head); 0 when disabled.
    pub point_branch: usize,
    /// The 3DGS head; 0 when disabled.
    pub gs_head: usize,
    /// The triplane alone (part of `smplx_branch`).
    pub triplane: usize,
    /// One transformer block.
    pub per_block: usize,
}

/// Channels of `F_pts` for a config: the learned point features plus coverage and depth, and
/// the colour with `point_colours`.
fn point_map_channels(config: &PrismConfig) -> usize {
    config.point_features + 2 + if config.point_colours { 3 } else { 0 }
}

impl ParameterCounts {
    /// The counts of the model `config` builds (equal to Burn's `num_params` of each part).
    pub fn of(config: &PrismConfig) -> Self {
        let d = config.width;
        let p2 = config.patch_size * config.patch_size;
        let tokenizer = (SOURCE_CHANNELS + TARGET_CHANNELS) * p2 * d + d;
        let per_block = 2 * d + 4 * d * d + 2 * config.head_dim() + 2 * config.mlp_ratio * d * d;
        let stage_one = config.stage_one_blocks * per_block;
        let stage_three = config.stage_three_blocks * per_block;
        let sees_render = config.nvs_sees_render && config.nvs_output == NvsOutput::Residual;
        let out = crate::heads::values_per_channel(config.patch_size, config.head_upsample);
        let nvs_head = d
            + d * 3 * out
            + if sees_render {
                (3 * p2 + 1) * d + (d + 1) * d
            } else {
                0
            };
        let zero_conv = |channels: usize| (p2 * channels + 1) * d + 1;
        let mut injection = 1;
        if config.smplx_branch {
            injection += zero_conv(config.triplane_channels);
        }
        if config.point_branch {
            injection += zero_conv(point_map_channels(config));
        }
        let h = config.smplx_width;
        let r = config.triplane_resolution;
        let triplane = if config.smplx_branch {
            3 * config.triplane_channels * r * r
        } else {
            0
        };
        let smplx_branch = if config.smplx_branch {
            2 * d + (d * h + h) + h + (h * h + h) + (h * SMPLX_OUTPUTS + SMPLX_OUTPUTS) + triplane
        } else {
            0
        };
        let point_branch = if config.point_branch {
            let c = config.point_width;
            let taps = dpt_taps(config.stage_one_blocks).len();
            let reassemble: usize = reassemble_factors(config.patch_size)[..taps]
                .iter()
                .map(|f| (d + 1) * c * f * f)
                .sum();
            let refine = (taps - 1) * (9 * c * c + c);
            let head =
                9 * c * (c / 2) + c / 2 + (c / 2 + 1) * 32 + 33 * (3 + config.point_features);
            reassemble + refine + head
        } else {
            0
        };
        let gs_head = if config.gs_head {
            d + d * GAUSSIAN_CHANNELS * out
        } else {
            0
        };
        Self {
            total: tokenizer
                + stage_one
                + stage_three
                + nvs_head
                + injection
                + smplx_branch
                + point_branch
                + gs_head,
            tokenizer,
            stage_one,
            stage_three,
            nvs_head,
            injection,
            smplx_branch,
            point_branch,
            gs_head,
            triplane,
            per_block,
        }
    }
}

/// Forward FLOPs of one frame (one (source, target) pair), by part.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct FlopCounts {
    /// Everything.
    pub total: f64,
    /// The tokenizer's projections.
    pub tokenizer: f64,
    /// The blocks' projections and MLPs (independent of the attention kind).
    pub projections: f64,
    /// The attention of all blocks (depends on each block's kind).
    pub attention: f64,
    /// The NVS head's projection.
    pub nvs_head: f64,
    /// The geometry parts' dense layers: the SMPL-X adapter and regressor and its triplane
    /// taps, the point branch's DPT head, the zero convolutions and the 3DGS head's projection
    /// (rasterization and splatting are not matrix products and are left out).
    pub geometry: f64,
}

/// Forward FLOPs of the geometry parts of one frame of `s` pixels (see [`FlopCounts::geometry`]).
fn geometry_flops(config: &PrismConfig, s: f64) -> f64 {
    let d = config.width as f64;
    let p2 = (config.patch_size * config.patch_size) as f64;
    let tokens = s / p2;
    let mut flops = 0.0;
    if config.smplx_branch {
        let h = config.smplx_width as f64;
        let c = config.triplane_channels as f64;
        flops += 2.0 * tokens * (d * h + 2.0 * h) + 2.0 * (h * h + h * SMPLX_OUTPUTS as f64);
        // Three planes, four bilinear taps per channel and pixel.
        flops += 2.0 * 12.0 * c * s;
        flops += 2.0 * s * c * d;
    }
    if config.point_branch {
        let c = config.point_width as f64;
        let taps = dpt_taps(config.stage_one_blocks).len();
        let factors = reassemble_factors(config.patch_size);
        for (k, &f) in factors[..taps].iter().enumerate() {
            let area = tokens * (f * f) as f64;
            flops += 2.0 * tokens * d * c * (f * f) as f64;
            if k + 1 < taps {
                flops += 2.0 * 9.0 * c * c * area;
            }
        }
        flops += 2.0 * 9.0 * c * (c / 2.0) * tokens * (factors[0] * factors[0]) as f64;
        flops += 2.0 * s * (c / 2.0 * 32.0 + 32.0 * (3 + config.point_features) as f64);
        flops += 2.0 * s * point_map_channels(config) as f64 * d;
    }
    if config.gs_head {
        flops += 2.0 * tokens * d * GAUSSIAN_CHANNELS as f64 * p2;
    }
    flops
}

/// Forward FLOPs of one block's attention with `tokens` tokens (see the module docs).
pub(crate) fn attention_flops(config: &PrismConfig, kind: AttentionKind, tokens: usize) -> f64 {
    let (t, d, dh) = (tokens as f64, config.width as f64, config.head_dim() as f64);
    match kind {
        AttentionKind::Full => 4.0 * t * t * d,
        AttentionKind::Linear => 4.0 * t * d * (dh + 1.0),
    }
}

impl FlopCounts {
    /// FLOPs of one frame of `height x width` pixels with the given block kinds.
    pub fn of(config: &PrismConfig, kinds: &[AttentionKind], height: usize, width: usize) -> Self {
        let tokens = config.tokens_per_sequence(height, width);
        let per_image = (tokens / 2) as f64;
        let (d, p2) = (
            config.width as f64,
            (config.patch_size * config.patch_size) as f64,
        );
        let r = config.mlp_ratio as f64;
        let tokenizer = 2.0 * per_image * ((SOURCE_CHANNELS + TARGET_CHANNELS) as f64) * p2 * d;
        let projections =
            kinds.len() as f64 * 2.0 * tokens as f64 * (4.0 * d * d + 2.0 * r * d * d);
        let attention = kinds
            .iter()
            .map(|&k| attention_flops(config, k, tokens))
            .sum();
        let nvs_head = 2.0 * per_image * d * 3.0 * p2;
        let geometry = geometry_flops(config, (height * width) as f64);
        Self {
            total: tokenizer + projections + attention + nvs_head + geometry,
            tokenizer,
            projections,
            attention,
            nvs_head,
            geometry,
        }
    }
}

/// One block in [`ModelInfo`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BlockInfo {
    /// Global block index `0..M+N`.
    pub index: usize,
    /// `stage_one` or `stage_three`.
    pub stage: &'static str,
    /// `full` or `linear`.
    pub attention: AttentionKind,
    /// Forward FLOPs of this block's attention per frame.
    pub attention_flops: f64,
}

/// What `prism info` reports about a model config.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ModelInfo {
    /// Parameter count of the whole model.
    pub parameters: usize,
    /// Parameter counts per part.
    pub parameter_counts: ParameterCounts,
    /// Token width `d`.
    pub width: usize,
    /// Attention heads.
    pub heads: usize,
    /// Patch size `p`.
    pub patch_size: usize,
    /// Image size the counts are for (square).
    pub resolution: usize,
    /// Tokens per (source, target) sequence: `2 (H/p)(W/p)`.
    pub tokens_per_sequence: usize,
    /// One entry per block, in global order.
    pub blocks: Vec<BlockInfo>,
    /// Forward FLOPs of one frame, by part.
    pub flops_per_frame: FlopCounts,
    /// The same frame with every block Full (the teacher).
    pub flops_per_frame_all_full: f64,
    /// The same frame with every block Linear.
    pub flops_per_frame_all_linear: f64,
}

impl ModelInfo {
    /// The report for `config` with the block kinds `kinds` at `resolution x resolution`.
    ///
    /// # Panics
    /// If `kinds` does not have one entry per block.
    pub fn new(config: &PrismConfig, kinds: &[AttentionKind], resolution: usize) -> Self {
        assert_eq!(kinds.len(), config.num_blocks(), "one kind per block");
        let tokens = config.tokens_per_sequence(resolution, resolution);
        let counts = ParameterCounts::of(config);
        let blocks = kinds
            .iter()
            .enumerate()
            .map(|(index, &attention)| BlockInfo {
                index,
                stage: if index < config.stage_one_blocks {
                    "stage_one"
                } else {
                    "stage_three"
                },
                attention,
                attention_flops: attention_flops(config, attention, tokens),
            })
            .collect();
        let uniform = |kind| {
            FlopCounts::of(
                config,
                &vec![kind; config.num_blocks()],
                resolution,
                resolution,
            )
            .total
        };
        Self {
            parameters: counts.total,
            parameter_counts: counts,
            width: config.width,
            heads: config.heads,
            patch_size: config.patch_size,
            resolution,
            tokens_per_sequence: tokens,
            blocks,
            flops_per_frame: FlopCounts::of(config, kinds, resolution, resolution),
            flops_per_frame_all_full: uniform(AttentionKind::Full),
            flops_per_frame_all_linear: uniform(AttentionKind::Linear),
        }
    }
}

/// Every float parameter of a module as (path, values flattened to one dimension), in visiting
/// order; paths are the modules' field names joined by dots (`stage_one.blocks.0.mlp...`).
pub(crate) fn named_parameters<M: burn::module::Module>(
    module: &M,
) -> Vec<(String, burn::tensor::Tensor<1>)> {
    use burn::module::{ModuleVisitor, Param};
    use burn::tensor::Tensor;
    struct Collect {
        path: Vec<String>,
        out: Vec<(String, Tensor<1>)>,
    }
    impl ModuleVisitor for Collect {
        fn enter_module(&mut self, name: &str, _container_type: &str) {
            self.path.push(name.to_string());
        }
        fn exit_module(&mut self, _name: &str, _container_type: &str) {
            self.path.pop();
        }
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let n: usize = param.val().dims().iter().product();
            self.out
                .push((self.path.join("."), param.val().reshape([n])));
        }
    }
    let mut collect = Collect {
        path: Vec::new(),
        out: Vec::new(),
    };
    module.visit(&mut collect);
    collect.out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::load_config;
    use std::path::Path;

    fn config(name: &str) -> PrismConfig {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../../configs/{name}.toml"));
        load_config(path).unwrap().model
    }

    #[test]
    fn paper_scale_counts() {
        let paper = config("paper");
        let counts = ParameterCounts::of(&paper);
        // Per block: 2 LayerNorm gains (2 x 768) + qkv (768 x 2304) + out (768 x 768)
        // + QK-norm gains (2 x 64) + MLP (768 x 3072 + 3072 x 768).
        assert_eq!(
            counts.per_block,
            1536 + 1_769_472 + 589_824 + 128 + 4_718_592
        );
        // Tokenizer: (9 + 6) x 64 x 768 + LayerNorm 768; head: 768 + 768 x 192.
        assert_eq!(counts.tokenizer, 737_280 + 768);
        assert_eq!(counts.nvs_head, 768 + 147_456);
        let backbone = counts.tokenizer + counts.stage_one + counts.stage_three + counts.nvs_head;
        assert_eq!(backbone, 255_750_144);
        // Geometry: the triplane (3 planes of 32 x 256 x 256), the injection (two zero
        // convolutions p^2 C -> d with bias, three gates) and the 3DGS head (LN + d x 12 p^2).
        assert_eq!(counts.triplane, 3 * 32 * 256 * 256);
        assert_eq!(
            counts.injection,
            (64 * 32 + 1) * 768 + (64 * 18 + 1) * 768 + 3
        );
        assert_eq!(counts.gs_head, 768 + 768 * 12 * 64);
        assert_eq!(
            counts.total,
            backbone
                + counts.injection
                + counts.smplx_branch
                + counts.point_branch
                + counts.gs_head
        );

        // Smooth heads (`head_upsample = 2`): 2 x 2 values per token and channel.
        let mut smooth = paper.clone();
        smooth.head_upsample = 2;
        let smooth_counts = ParameterCounts::of(&smooth);
        assert_eq!(smooth_counts.nvs_head, 768 + 768 * 3 * 4);
        assert_eq!(smooth_counts.gs_head, 768 + 768 * 12 * 4);

        let kinds = vec![AttentionKind::Full; 36];
        let info = ModelInfo::new(&paper, &kinds, 512);
        assert_eq!(info.tokens_per_sequence, 8192);
        assert_eq!(info.blocks.len(), 36);
        // Full attention per block: Q K^T and A V, 8192^2 x 768 multiply-adds each.
        let t = 8192.0f64;
        assert_eq!(info.blocks[0].attention_flops, 4.0 * t * t * 768.0);
        let json = serde_json::to_value(&info).unwrap();
        assert_eq!(json["parameters"], counts.total);
        assert_eq!(json["blocks"].as_array().unwrap().len(), 36);
        assert_eq!(json["blocks"][35]["attention"], "full");
    }

    #[test]
    fn full_attention_grows_quadratically_and_linear_linearly() {
        let tiny = config("tiny");
        let full = |t| attention_flops(&tiny, AttentionKind::Full, t);
        let linear = |t| attention_flops(&tiny, AttentionKind::Linear, t);
        assert_eq!(full(512) / full(128), 16.0);
        assert_eq!(linear(512) / linear(128), 4.0);
        let kinds = vec![AttentionKind::Linear; 6];
        let info = ModelInfo::new(&tiny, &kinds, 64);
        assert_eq!(info.flops_per_frame.total, info.flops_per_frame_all_linear);
        assert!(info.flops_per_frame_all_linear < info.flops_per_frame_all_full);
        let f = info.flops_per_frame;
        assert_eq!(
            f.total,
            f.tokenizer + f.projections + f.attention + f.nvs_head + f.geometry
        );
        // Projections and MLP: 24 T d^2 per block for an MLP ratio of 4.
        assert_eq!(f.projections, 6.0 * 24.0 * 128.0 * 64.0 * 64.0);
    }
}
