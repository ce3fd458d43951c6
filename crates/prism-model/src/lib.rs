//! The PrismMirror network (paper Sec. 3.2 and 3.4) on Burn.
//!
//! - [`Tokenizer`]: source `[2I - 1, P_s]` and target `P_t` patches to `T_in`;
//! - [`PrismBlock`]: pre-norm transformer block whose [`SelfAttention`] is Full (softmax) or
//!   Linear (SANA) with the same weights, switchable in place;
//! - [`Prism`]: [`StageOne`] -> `T_mid` -> [`Prism::inject`] -> [`StageThree`] -> `T_out` ->
//!   [`NvsHead`];
//! - [`PrismConfig`] / [`DistillConfig`]: the `[model]` and `[distill]` sections of a TOML
//!   config ([`load_config`]), and [`progressive_schedule`], the stitching schedule;
//! - [`ModelInfo`]: parameter and FLOP counts; [`bench_forward`]: forward timing.

pub mod attention;
pub mod bench;
pub mod block;
pub mod config;
pub mod distill;
pub mod error;
pub mod head;
pub mod info;
pub mod patch;
pub mod prism;
pub mod stages;
pub mod tokenizer;

#[cfg(test)]
mod test_util;

pub use attention::{
    AttentionKind, FeatureMap, SelfAttention, SelfAttentionConfig, fused_attention,
    linear_attention, softmax_attention,
};
pub use bench::{BenchOptions, BenchRow, bench_forward};
pub use block::{Mlp, PrismBlock, PrismBlockConfig};
pub use config::{AttentionPattern, ModelConfigFile, PrismConfig, load_config, parse_config};
pub use distill::{DistillConfig, DistillLayers, DistillMode, progressive_schedule};
pub use error::ModelError;
pub use head::{NvsHead, NvsHeadConfig};
pub use info::{BlockInfo, FlopCounts, ModelInfo, ParameterCounts};
pub use patch::{patchify, unpatchify};
pub use prism::{Prism, PrismOutput};
pub use stages::{HiddenStates, StageOne, StageThree};
pub use tokenizer::{SOURCE_CHANNELS, TARGET_CHANNELS, Tokenizer, TokenizerConfig};
