//! The PrismMirror network (paper Sec. 3.2 and 3.4) on Burn.
//!
//! - [`Tokenizer`]: source `[2I - 1, P_s]` and target `P_t` patches to `T_in`;
//! - [`PrismBlock`]: pre-norm transformer block whose [`SelfAttention`] is Full (softmax) or
//!   Linear (SANA) with the same weights, switchable in place;
//! - [`Prism`]: [`StageOne`] -> `T_mid` -> the geometry branches ([`SmplxBranch`]: SMPL-X
//!   parameters, position map, triplane features `F_smpl`; [`PointBranch`]: DPT point map,
//!   splatted features `F_pts`) -> [`Injection`] (zero convolutions and gates) ->
//!   [`StageThree`] -> `T_out` -> [`NvsHead`] (`I_t`) and [`GaussianHead`] (`I_gs`);
//!   [`Views`] carries the cameras the geometry parts need;
//! - [`PrismConfig`] / [`DistillConfig`]: the `[model]` and `[distill]` sections of a TOML
//!   config ([`load_config`]), and [`progressive_schedule`], the stitching schedule;
//! - [`ModelInfo`]: parameter and FLOP counts; [`bench_forward`]: forward timing.

pub mod attention;
pub mod bench;
pub mod block;
pub mod body_model;
pub mod config;
pub mod distill;
pub mod dpt;
pub mod error;
pub mod gaussian_head;
pub mod head;
pub mod info;
pub mod injection;
pub mod lvsm;
pub mod memory;
pub mod patch;
pub mod placement;
pub mod point_branch;
pub mod precision;
pub mod prism;
pub mod rotation;
pub mod smplx_branch;
pub mod stages;
pub mod tokenizer;
pub mod views;

#[cfg(test)]
mod test_util;

pub use attention::{
    AttentionKind, FeatureMap, SelfAttention, SelfAttentionConfig, linear_attention,
};
pub use bench::{BenchOptions, BenchRow, bench_forward, protocol_views};
pub use block::{Mlp, PrismBlock, PrismBlockConfig};
pub use config::{AttentionPattern, ModelConfigFile, PrismConfig, load_config, parse_config};
pub use distill::{DistillConfig, DistillLayers, DistillMode, progressive_schedule};
pub use dpt::{DptHead, DptHeadConfig, dpt_taps};
pub use error::ModelError;
pub use gaussian_head::{GaussianHead, GaussianHeadConfig, GaussianOutput, SourcePixels};
pub use head::{NvsHead, NvsHeadConfig};
pub use info::{BlockInfo, FlopCounts, ModelInfo, ParameterCounts};
pub use injection::{Injection, InjectionConfig, ZeroConv};
pub use lvsm::{BlockPlacement, LvsmCheckpoint, LvsmConversion, LvsmLayout};
pub use memory::{MemoryProbe, PeakAllocator};
pub use patch::{patchify, unpatchify};
pub use point_branch::{PointBranch, PointBranchConfig, PointOutput};
pub use precision::Precision;
pub use prism::{Prism, PrismOutput};
pub use smplx_branch::{SmplxBranch, SmplxBranchConfig, SmplxOutput, SmplxTargets};
pub use stages::{HiddenStates, StageOne, StageThree};
pub use tokenizer::{SOURCE_CHANNELS, TARGET_CHANNELS, Tokenizer, TokenizerConfig};
pub use views::Views;
