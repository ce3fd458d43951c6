//! `prism convert lvsm`: a pretrained LVSM decoder-only checkpoint as a prism checkpoint
//! folder (the mapping is `prism_model::LvsmCheckpoint::convert`'s).

use std::path::Path;

use prism_core::BackendKind;
use prism_model::{BlockPlacement, LvsmCheckpoint, LvsmConversion};

use crate::checkpoint::save_model_checkpoint;
use crate::config::TrainingConfig;
use crate::error::Result;

/// The `task` of a converted checkpoint's `state.json`.
pub const LVSM_TASK: &str = "lvsm";

/// Reads the LVSM checkpoint `checkpoint` (a PyTorch file), maps it into the model of `config`
/// (LVSM's blocks into the prism blocks `placement` names; the geometry parts and any new
/// block keep a fresh initialisation seeded by `train.seed`) and writes the checkpoint folder
/// `out`, which `evaluate`, `infer` and `train-teacher --init` read. The new blocks are
/// recorded in its `state.json`, so that a run started from it trains them at `lr_heads`.
///
/// # Errors
/// An unreadable checkpoint, one that does not fit the config (the error names the first
/// mismatch), or I/O errors.
pub fn convert_lvsm(
    checkpoint: &Path,
    config: &TrainingConfig,
    placement: &BlockPlacement,
    out: &Path,
) -> Result<LvsmConversion> {
    let backend = BackendKind::Ndarray;
    let device = backend.device()?;
    let lvsm = LvsmCheckpoint::read(checkpoint)?;
    device.seed(config.train.seed);
    let (model, conversion) = lvsm.convert(&config.model, placement, &device)?;
    save_model_checkpoint(
        out,
        config,
        &model,
        LVSM_TASK,
        &backend.to_string(),
        &conversion.new_blocks,
    )?;
    Ok(conversion)
}
