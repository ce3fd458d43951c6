//! `prism convert`: pretrained third-party models as prism checkpoints.

use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, Subcommand};
use prism_model::BlockPlacement;
use prism_train::{TrainingConfig, convert_lvsm};

/// Conversions of pretrained models into prism checkpoint folders.
#[derive(Subcommand, Debug)]
pub enum ConvertCommand {
    /// A pretrained decoder-only LVSM (its published PyTorch `.pt`) as the backbone of a prism
    /// config: tokenizers, input LayerNorm, every block and the NVS decoder receive LVSM's
    /// weights; the geometry parts keep a fresh initialisation. The folder written is what
    /// `evaluate`, `infer` and `train-teacher --init` read.
    Lvsm(ConvertLvsmArgs),
}

impl ConvertCommand {
    /// Runs the conversion.
    pub fn run(self) -> anyhow::Result<()> {
        match self {
            Self::Lvsm(args) => args.run(),
        }
    }
}

/// Arguments of `prism convert lvsm`.
#[derive(Args, Debug)]
pub struct ConvertLvsmArgs {
    /// The LVSM checkpoint: a PyTorch file whose `model` entry is the decoder-only model's
    /// state dict (or a bare state dict).
    #[arg(long, value_name = "FILE.pt")]
    checkpoint: PathBuf,
    /// The prism config (e.g. configs/paper.toml). Its width, heads, patch size and MLP ratio
    /// must be the checkpoint's, with at least as many blocks, and `nvs_output = "direct"`.
    #[arg(long, value_name = "CONFIG.toml")]
    config: PathBuf,
    /// The checkpoint folder to write (replaced if it exists).
    #[arg(long, value_name = "CKPT_DIR")]
    out: PathBuf,
    /// Which prism blocks receive LVSM's blocks, in order, when the config has more blocks
    /// than the checkpoint: `first` (prism's first L blocks: stage I holds LVSM's first M
    /// blocks, so the geometry branches fork from pretrained features), `last`, or a
    /// comma-separated list of L global block indices. The other blocks start as the identity
    /// (zero output projections), so the converted model computes LVSM's function exactly; a run
    /// started from the checkpoint (`train-teacher --init`) trains them at `lr_heads`.
    #[arg(long, value_name = "first|last|LIST", default_value = "first")]
    blocks: BlockPlacement,
}

impl ConvertLvsmArgs {
    /// Converts and prints what was mapped and what stays freshly initialised.
    pub fn run(self) -> anyhow::Result<()> {
        let config = TrainingConfig::load(&self.config)?;
        let conversion = convert_lvsm(&self.checkpoint, &config, &self.blocks, &self.out)
            .with_context(|| format!("converting {}", self.checkpoint.display()))?;
        let l = &conversion.layout;
        println!(
            "LVSM: width {}, {} heads of {}, patch {}, {} blocks, MLP {}",
            l.width,
            l.heads(),
            l.head_dim,
            l.patch_size,
            l.layers,
            l.mlp_hidden
        );
        let placement: Vec<String> = conversion.placement.iter().map(usize::to_string).collect();
        println!(
            "{} tensors mapped; LVSM blocks 0..{} -> prism blocks [{}]",
            conversion.mapped,
            l.layers,
            placement.join(", ")
        );
        if conversion.fresh.is_empty() {
            println!("every prism parameter comes from the checkpoint");
        } else {
            println!("freshly initialised (not in LVSM):");
            for part in &conversion.fresh {
                let new = if part.module.starts_with("stage_") {
                    " (new block: identity at the start)"
                } else {
                    ""
                };
                println!(
                    "  {:<24} {:>4} tensors {:>12} parameters{new}",
                    part.module, part.tensors, part.parameters
                );
            }
        }
        for note in &conversion.notes {
            println!("note: {note}");
        }
        println!("checkpoint: {}", self.out.display());
        Ok(())
    }
}
