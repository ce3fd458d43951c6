//! `prism info`: size and cost of a model config.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use prism_model::{AttentionKind, ModelInfo, load_config, progressive_schedule};

/// Print a model's parameter counts (total and per part), the attention kind of every block,
/// the tokens per sequence and the forward FLOPs per frame (matrix products only, 2 FLOPs per
/// multiply-add: Full attention costs 4 T^2 d per block, Linear 4 T d (d_h + 1)).
#[derive(Args, Debug)]
pub struct InfoArgs {
    /// Config file (TOML with `[model]` and `[distill]` sections), e.g. configs/paper.toml.
    #[arg(long, value_name = "FILE")]
    config: PathBuf,
    /// Print JSON (with at least `parameters` and `blocks`) instead of a table.
    #[arg(long)]
    json: bool,
    /// Image size (square, pixels) for tokens and FLOPs [default: the config's resolution].
    #[arg(long, value_name = "PIXELS")]
    res: Option<usize>,
    /// Show the student's attention kinds at this distillation step (the `[distill]`
    /// schedule) instead of the config's `attention`.
    #[arg(long, value_name = "STEP")]
    distill_step: Option<usize>,
}

impl InfoArgs {
    /// Loads the config and prints the report.
    pub fn run(self) -> anyhow::Result<()> {
        let file = load_config(&self.config)?;
        let model = &file.model;
        let res = self.res.unwrap_or(model.resolution);
        if res == 0 || !res.is_multiple_of(model.patch_size) {
            anyhow::bail!(
                "--res {res} is not a positive multiple of the patch size {}",
                model.patch_size
            );
        }
        let kinds = match self.distill_step {
            Some(step) => progressive_schedule(step, &file.distill, model.num_blocks()),
            None => model
                .attention_kinds()
                .with_context(|| format!("{}", self.config.display()))?,
        };
        let info = ModelInfo::new(model, &kinds, res);
        if self.json {
            println!("{}", serde_json::to_string_pretty(&info)?);
        } else {
            print!("{}", table(&self.config.display().to_string(), &info));
        }
        Ok(())
    }
}

/// `1234567` -> `1,234,567`.
fn grouped(n: usize) -> String {
    let digits = n.to_string();
    let mut out = String::new();
    for (i, c) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

/// The human-readable report.
fn table(name: &str, info: &ModelInfo) -> String {
    let c = &info.parameter_counts;
    let f = &info.flops_per_frame;
    let pattern: String = info.blocks.iter().map(|b| b.attention.letter()).collect();
    let linear = info
        .blocks
        .iter()
        .filter(|b| b.attention == AttentionKind::Linear)
        .count();
    let g = |x: f64| format!("{:.3} GFLOP", x / 1e9);
    let mut s = String::new();
    s += &format!(
        "model {name}: width {}, {} heads, patch {}, {} blocks\n",
        info.width,
        info.heads,
        info.patch_size,
        info.blocks.len()
    );
    s += &format!("parameters        {:>14}\n", grouped(c.total));
    s += &format!("  tokenizer       {:>14}\n", grouped(c.tokenizer));
    s += &format!(
        "  stage one       {:>14}  ({} blocks of {})\n",
        grouped(c.stage_one),
        info.blocks
            .iter()
            .filter(|b| b.stage == "stage_one")
            .count(),
        grouped(c.per_block)
    );
    s += &format!("  stage three     {:>14}\n", grouped(c.stage_three));
    s += &format!("  nvs head        {:>14}\n", grouped(c.nvs_head));
    s += &format!("  injection       {:>14}\n", grouped(c.injection));
    let part = |n: usize| {
        if n == 0 {
            "off".to_string()
        } else {
            grouped(n)
        }
    };
    s += &format!(
        "  smplx branch    {:>14}  (triplane {})\n",
        part(c.smplx_branch),
        grouped(c.triplane)
    );
    s += &format!("  point branch    {:>14}\n", part(c.point_branch));
    s += &format!("  gs head         {:>14}\n", part(c.gs_head));
    s += &format!(
        "attention         {pattern}  ({linear} Linear, {} Full; F = full, L = linear)\n",
        info.blocks.len() - linear
    );
    s += &format!(
        "tokens            {} per sequence at {}x{} ({} source + {} target)\n",
        info.tokens_per_sequence,
        info.resolution,
        info.resolution,
        info.tokens_per_sequence / 2,
        info.tokens_per_sequence / 2
    );
    s += &format!("FLOPs per frame   {}\n", g(f.total));
    s += &format!("  tokenizer       {}\n", g(f.tokenizer));
    s += &format!("  projections+MLP {}\n", g(f.projections));
    s += &format!("  attention       {}\n", g(f.attention));
    s += &format!("  nvs head        {}\n", g(f.nvs_head));
    s += &format!("  geometry parts  {}\n", g(f.geometry));
    s += &format!(
        "  all Full        {}   all Linear {}\n",
        g(info.flops_per_frame_all_full),
        g(info.flops_per_frame_all_linear)
    );
    s
}
