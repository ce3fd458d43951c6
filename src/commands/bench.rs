//! `prism bench`: benchmarks.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::{Args, Subcommand};
use prism_data::BackendKind;
use prism_model::{AttentionKind, BenchOptions, BenchRow, bench_forward, load_config};

/// Benchmarks; results are printed as a table and optionally written as JSON.
#[derive(Args, Debug)]
pub struct BenchArgs {
    #[command(subcommand)]
    command: BenchCommand,
}

/// What to benchmark.
#[derive(Subcommand, Debug)]
enum BenchCommand {
    /// Forward time per frame (one source/target pair, batch 1, inference) of model configs
    /// with every block Full and every block Linear, at several resolutions: the median after
    /// warm-up, showing how each grows with the number of tokens.
    Model(ModelBenchArgs),
}

/// Arguments of `prism bench model`.
#[derive(Args, Debug)]
struct ModelBenchArgs {
    /// Config files to benchmark (repeat the flag for several).
    #[arg(long, value_name = "FILE", default_values = ["configs/tiny.toml"])]
    config: Vec<PathBuf>,
    /// Resolutions in pixels (square; repeat the flag) [default: each config's resolution and
    /// twice it].
    #[arg(long, value_name = "PIXELS")]
    res: Vec<usize>,
    /// Attention kinds to run every block with (repeat the flag).
    #[arg(long, value_name = "KIND", default_values = ["full", "linear"], value_parser = parse_kind)]
    attention: Vec<AttentionKind>,
    /// Backend: ndarray, flex or wgpu.
    #[arg(long, default_value = "flex")]
    backend: BackendKind,
    /// Untimed runs before timing.
    #[arg(long, default_value_t = 3)]
    warmup: usize,
    /// Timed runs (the median is reported).
    #[arg(long, default_value_t = 10)]
    iters: usize,
    /// Also write `{"rows": [{"model", "res", "tokens", "ms", "fps", "peak_mem_bytes"}]}` to
    /// this file (`peak_mem_bytes` is null on the CPU backends, which do not report memory).
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
}

fn parse_kind(s: &str) -> Result<AttentionKind, String> {
    match s.to_ascii_lowercase().as_str() {
        "full" => Ok(AttentionKind::Full),
        "linear" => Ok(AttentionKind::Linear),
        _ => Err(format!(
            "unknown attention kind `{s}` (expected full or linear)"
        )),
    }
}

impl BenchArgs {
    /// Runs the chosen benchmark.
    pub fn run(self) -> anyhow::Result<()> {
        match self.command {
            BenchCommand::Model(args) => args.run(),
        }
    }
}

impl ModelBenchArgs {
    fn run(self) -> anyhow::Result<()> {
        let device = self.backend.device()?;
        let options = BenchOptions {
            warmup: self.warmup,
            iters: self.iters.max(1),
        };
        // Load and check every config before timing anything.
        let mut runs = Vec::new();
        for path in &self.config {
            let config = load_config(path)?.model;
            let name = path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| path.display().to_string());
            let resolutions = if self.res.is_empty() {
                vec![config.resolution, 2 * config.resolution]
            } else {
                self.res.clone()
            };
            if let Some(bad) = resolutions
                .iter()
                .find(|&&r| r == 0 || !r.is_multiple_of(config.patch_size))
            {
                anyhow::bail!(
                    "--res {bad} is not a positive multiple of the patch size {} of {}",
                    config.patch_size,
                    path.display()
                );
            }
            runs.push((name, config, resolutions));
        }
        println!(
            "{:<16} {:>6} {:>7} {:>10} {:>8} {:>12}",
            "model", "res", "tokens", "ms/frame", "fps", "peak_mem"
        );
        let mut rows = Vec::new();
        for (name, config, resolutions) in runs {
            device.seed(0);
            let mut model = config.try_init(&device)?;
            for &kind in &self.attention {
                model.set_attention_kinds(&vec![kind; model.num_blocks()]);
                for &res in &resolutions {
                    let label = format!("{name}/{}", kind.name());
                    let row = bench_forward(&model, &label, res, &device, options);
                    println!(
                        "{:<16} {:>6} {:>7} {:>10.2} {:>8.2} {:>12}",
                        row.model,
                        row.res,
                        row.tokens,
                        row.ms,
                        row.fps,
                        row.peak_mem_bytes
                            .map_or("n/a".to_string(), |b| b.to_string())
                    );
                    rows.push(row);
                }
            }
        }
        if let Some(path) = &self.json {
            write_json(path, &rows)?;
        }
        Ok(())
    }
}

/// Writes the rows as `{"rows": [...]}`, through a temporary file and a rename.
fn write_json(path: &Path, rows: &[BenchRow]) -> anyhow::Result<()> {
    let text = serde_json::to_string_pretty(&serde_json::json!({ "rows": rows }))?;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let tmp = path.with_extension("json.tmp");
    std::fs::write(&tmp, text + "\n").with_context(|| format!("cannot write {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
}
