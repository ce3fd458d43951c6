//! The PrismMirror network (paper Sec. 3.2 and 3.4) on Burn.
//!
//! The modules follow the paper; everything public is re-exported here, at the crate root.
//!
//! - `tokenizer`: source `[2I - 1, P_s]` and target `P_t` patches to `T_in` ([`Tokenizer`]);
//! - `stages`: stage I and stage III ([`StageOne`], [`StageThree`]), runs of pre-norm
//!   transformer blocks ([`PrismBlock`]) whose [`SelfAttention`] is Full (softmax) or Linear
//!   (SANA) with the same weights, switchable in place ([`AttentionKind`]);
//! - `geometry`: stage II, the SMPL-X branch (`geometry::smplx`, [`SmplxBranch`]: SMPL-X
//!   parameters, position map, triplane features `F_smpl`), the point branch
//!   (`geometry::points`, [`PointBranch`]: DPT point map, splatted features `F_pts`) and the
//!   [`Injection`] (zero convolutions and gates);
//! - `heads`: [`NvsHead`] (`I_t`, `heads::nvs`) and [`GaussianHead`] (`I_gs`, `heads::gaussian`);
//! - `distill`: [`DistillConfig`] and [`progressive_schedule`], the stitching schedule;
//! - [`Prism`] (`prism`): the cascade of all of these; [`Views`] carries the cameras the
//!   geometry parts need, [`Precision`] runs the blocks in half precision;
//! - `config`: [`PrismConfig`], the `[model]` section of a TOML config, and the loader of the
//!   `[model]` and `[distill]` sections ([`load_config`]; [`describe_toml_error`] words a TOML
//!   error the same way for every crate's sections);
//! - `tools`: [`ModelInfo`] (parameter and FLOP counts), [`bench_forward`] (forward timing,
//!   [`MemoryProbe`]) and [`LvsmCheckpoint`] (pretrained LVSM backbones).

mod config;
mod distill;
mod error;
mod geometry;
mod heads;
mod precision;
mod prism;
mod stages;
mod tokenizer;
mod tools;
mod views;

#[cfg(test)]
mod test_util;

pub use config::{
    AttentionPattern, ModelConfigFile, PrismConfig, describe_toml_error, load_config, parse_config,
};
pub use distill::{DistillConfig, DistillLayers, DistillMode, progressive_schedule};
pub use error::ModelError;
pub use geometry::injection::{Injection, ZeroConv};
pub use geometry::points::dpt::DptHead;
pub use geometry::points::{PointBranch, PointOutput};
pub use geometry::smplx::{SmplxBranch, SmplxOutput, SmplxTargets};
pub use heads::gaussian::{GaussianHead, GaussianOutput, GsColour, GsDepth, SourcePixels};
pub use heads::nvs::{NvsHead, NvsOutput};
pub use precision::Precision;
pub use prism::{Prism, PrismOutput};
pub use stages::attention::{AttentionKind, FeatureMap, SelfAttention};
pub use stages::block::{Mlp, PrismBlock};
pub use stages::{HiddenStates, StageOne, StageThree};
pub use tokenizer::Tokenizer;
pub use tools::bench::{BenchOptions, BenchRow, bench_forward, median, protocol_views};
pub use tools::info::{BlockInfo, FlopCounts, ModelInfo, ParameterCounts};
pub use tools::lvsm::{
    BlockPlacement, FreshPart, LvsmCheckpoint, LvsmConversion, LvsmLayout, LvsmTensor,
};
pub use tools::memory::{MemoryProbe, PeakAllocator};
pub use views::Views;
