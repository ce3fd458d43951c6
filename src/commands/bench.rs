//! `prism bench`: benchmarks. `prism bench --config FILE --res R1,R2` is the speed table of a
//! config (teacher, student and all-Linear forward, and the training step); the subcommands
//! are the narrower benchmarks.

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::args::{DataArgs, JobArgs};
use super::tune::record::Adapter;
use anyhow::Context;
use clap::{Args, Subcommand};
use prism_core::BackendKind;
use prism_core::reads::{geometry_host_reads, host_reads};
use prism_core::steal::{StealProbe, percent};
use prism_data::DatasetReader;
use prism_model::{
    AttentionKind, BenchOptions, BenchRow, MemoryProbe, Precision, PrismConfig, bench_forward,
    load_config,
};
use prism_synth::ensure_synthetic_dataset;
use prism_train::{
    PipelineOptions, QuickstartPlan, RunOptions, TeacherTask, TrainingConfig, Validator,
    budget_curve, budget_markdown, distill_student, load_model, read_metrics, train,
};

/// Benchmarks; results are printed as a table and optionally written as JSON.
///
/// Without a subcommand: the speed table of one config. Forward latency (one source/target
/// pair, batch 1, inference, median after warm-up) and peak memory at each `--res` of the
/// `teacher` (every block Full), the `student` (the kinds the config's `[distill]` schedule
/// ends with) and `linear` (every block Linear), then the training step time of the teacher
/// on the config's synthetic data. The 3DGS head (a training signal) is left out of the
/// forward pass, as in serving.
#[derive(Args, Debug)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct BenchArgs {
    #[command(subcommand)]
    command: Option<BenchCommand>,
    #[command(flatten)]
    table: TableArgs,
}

/// Arguments of `prism bench --config FILE ...`.
#[derive(Args, Debug)]
struct TableArgs {
    /// Config file (TOML with `[model]` and `[distill]`; `[train]` and `[data]` for the
    /// training step).
    #[arg(long, value_name = "FILE", required = true)]
    config: Option<PathBuf>,
    /// Resolutions in pixels (square, comma-separated) [default: the config's].
    #[arg(long, value_name = "R1,R2,..", value_delimiter = ',')]
    res: Vec<usize>,
    /// Models to time (comma-separated): teacher, student, linear.
    #[arg(long, value_delimiter = ',', default_values = ["teacher", "student", "linear"],
          value_parser = ["teacher", "student", "linear"])]
    models: Vec<String>,
    /// Backend: ndarray, flex, wgpu or cuda (the GPU ones need their cargo feature).
    #[arg(long, default_value = "flex")]
    backend: BackendKind,
    /// Precision of the transformer blocks: f32, f16 or bf16 (the rest of the model stays
    /// f32). The forward rows store the blocks' weights in it; the training step computes in
    /// it with f32 master weights (as `train-teacher --precision`).
    #[arg(long, default_value = "f32")]
    precision: Precision,
    /// Untimed runs before timing.
    #[arg(long, default_value_t = 3)]
    warmup: usize,
    /// Timed runs (the median is reported).
    #[arg(long, default_value_t = 10)]
    iters: usize,
    /// Training steps to run for the step time (median after 2 warm-up steps); 0 skips it.
    #[arg(long, default_value_t = 6)]
    train_steps: usize,
    /// The dataset of the training step.
    #[command(flatten)]
    data: DataArgs,
    /// Also write `{"rows": [{"model", "res", "tokens", "ms", "fps", "peak_mem_bytes",
    /// "host_reads", "geometry_host_reads", "cpu_steal"}]}` to
    /// this file (the training step is the row `train_step`, `fps` its steps per second).
    /// `peak_mem_bytes` is the peak of the timed runs: the memory pools' bytes on GPU
    /// backends, the heap's growth above its size before the runs on the CPU ones (for the
    /// training step, the whole short run). `cpu_steal` is the share of the machine's CPU
    /// time the hypervisor ran something else while the row was timed (for the training step,
    /// the whole short run; null where not counted): a row with a high one is slower than its
    /// code.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
}

/// What to benchmark.
#[derive(Subcommand, Debug)]
enum BenchCommand {
    /// Validation PSNR of a trained checkpoint with the blocks in f32 and in half precision,
    /// and the forward time of each.
    Precision(PrecisionBenchArgs),
    /// Forward time per frame (one source/target pair, batch 1, inference) of model configs
    /// with every block Full and every block Linear, at several resolutions: the median after
    /// warm-up, showing how each grows with the number of tokens.
    Model(ModelBenchArgs),
    /// The quick start at several multiples of its step counts (hours at 16x): PSNR of the NVS
    /// decoder, its 3DGS render I_gs and copy-source, overall and in the disoccluded region,
    /// against the budget (OUT/budget.md, OUT/budget.png; finished multiples are kept, an
    /// interrupted one continues from its runs' last checkpoints).
    Budget(BudgetBenchArgs),
}

/// Arguments of `prism bench budget`.
#[derive(Args, Debug)]
struct BudgetBenchArgs {
    /// The quick start's --fast plan (tiny config) instead of the standard one (small).
    #[arg(long)]
    fast: bool,
    /// Multiples of the plan's teacher and student steps.
    #[arg(long, value_name = "M", value_delimiter = ',', default_values = ["1", "4", "16"])]
    multiples: Vec<usize>,
    /// Folder of the quick starts and the curve [default: runs/budget-small or
    /// runs/budget-tiny].
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    #[command(flatten)]
    job: JobArgs,
}

impl BudgetBenchArgs {
    fn run(self) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.multiples.iter().all(|&m| m > 0),
            "--multiples must be at least 1"
        );
        let plan = if self.fast {
            QuickstartPlan::fast()?
        } else {
            QuickstartPlan::standard()?
        };
        let out = self
            .out
            .unwrap_or_else(|| PathBuf::from(format!("runs/budget-{}", plan.name)));
        let progress = !self.job.quiet;
        let options = PipelineOptions {
            data: ensure_synthetic_dataset(&plan.config.data, progress)?,
            out: out.clone(),
            backend: self.job.backend,
            lpips_weights: self.job.lpips_weights,
            progress,
        };
        let (points, table) = budget_curve(&plan, &self.multiples, &options, &distill_student)
            .with_context(|| format!("budget curve in {}", out.display()))?;
        print!("{}", budget_markdown(&plan, &points));
        println!("table {}", table.display());
        Ok(())
    }
}

/// Arguments of `prism bench model`.
#[derive(Args, Debug)]
struct ModelBenchArgs {
    /// Config files to benchmark (repeat the flag for several).
    #[arg(long, value_name = "FILE", default_values = ["configs/tiny.toml"])]
    config: Vec<PathBuf>,
    /// Resolutions in pixels (square; repeat the flag or separate with commas) [default: each
    /// config's resolution and twice it].
    #[arg(long, value_name = "PIXELS", value_delimiter = ',')]
    res: Vec<usize>,
    /// Attention kinds to run every block with (repeat the flag).
    #[arg(long, value_name = "KIND", default_values = ["full", "linear"], value_parser = parse_kind)]
    attention: Vec<AttentionKind>,
    /// Backend: ndarray, flex, wgpu or cuda.
    #[arg(long, default_value = "flex")]
    backend: BackendKind,
    /// Untimed runs before timing.
    #[arg(long, default_value_t = 3)]
    warmup: usize,
    /// Timed runs (the median is reported).
    #[arg(long, default_value_t = 10)]
    iters: usize,
    /// Also write `{"rows": [{"model", "res", "tokens", "ms", "fps", "peak_mem_bytes",
    /// "host_reads", "geometry_host_reads", "cpu_steal"}]}` to
    /// this file (`peak_mem_bytes`: the timed runs' peak, the memory pools' bytes on GPU
    /// backends, the heap's growth above its size before the runs on the CPU ones;
    /// `cpu_steal`: the hypervisor's share of the CPU time while the row was timed).
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
            Some(BenchCommand::Model(args)) => args.run(),
            Some(BenchCommand::Precision(args)) => args.run(),
            Some(BenchCommand::Budget(args)) => args.run(),
            None => self.table.run(),
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
            let default = [config.resolution, 2 * config.resolution];
            let resolutions = resolutions(&self.res, &default, &config, path)?;
            runs.push((name, config, resolutions));
        }
        print_header();
        let mut rows = Vec::new();
        for (name, config, resolutions) in runs {
            device.seed(0);
            let mut model = config.try_init(&device)?;
            for &kind in &self.attention {
                model.set_attention_kinds(&vec![kind; model.num_blocks()]);
                for &res in &resolutions {
                    let label = format!("{name}/{}", kind.name());
                    let row = bench_forward(&model, &label, res, &device, options);
                    print_row(&row);
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
    prism_core::files::write_bytes(path, (text + "\n").as_bytes())
        .with_context(|| format!("cannot write {}", path.display()))
}

/// Prints the header of the table of [`print_row`].
fn print_header() {
    println!(
        "{:<16} {:>6} {:>7} {:>10} {:>8} {:>12} {:>7} {:>9} {:>6}",
        "model", "res", "tokens", "ms/frame", "fps", "peak_mem", "reads", "geometry", "steal"
    );
}

/// Prints one row of the table `model res tokens ms/frame fps peak_mem reads geometry steal`
/// (`reads` and `geometry`: host reads per frame or step, all and the geometry operations';
/// `steal`: the share of the CPU time the hypervisor ran something else while the row was
/// timed, [`prism_core::steal`]).
fn print_row(row: &BenchRow) {
    println!(
        "{:<16} {:>6} {:>7} {:>10.2} {:>8.2} {:>12} {:>7.1} {:>9.1} {:>6}",
        row.model,
        row.res,
        row.tokens,
        row.ms,
        row.fps,
        row.peak_mem_bytes.map_or("n/a".to_string(), |b| format!(
            "{:.1} MiB",
            b as f64 / 1048576.0
        )),
        row.host_reads,
        row.geometry_host_reads,
        percent(row.cpu_steal)
    );
}

/// The resolutions to time: `--res` when given, else `default`; each must be a positive
/// multiple of the patch size of `config` (read from `path`, which the error names).
fn resolutions(
    requested: &[usize],
    default: &[usize],
    config: &PrismConfig,
    path: &Path,
) -> anyhow::Result<Vec<usize>> {
    let resolutions = if requested.is_empty() {
        default
    } else {
        requested
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
    Ok(resolutions.to_vec())
}

/// Checks that `precision` runs on the device of `backend`.
fn check_precision(precision: Precision, backend: BackendKind) -> anyhow::Result<()> {
    let device = backend.device()?;
    if !precision.supported_on(&device) {
        anyhow::bail!("the {backend} backend does not compute in {precision}");
    }
    Ok(())
}

impl TableArgs {
    fn run(self) -> anyhow::Result<()> {
        let path = self.config.clone().expect("clap requires --config");
        let file = load_config(&path)?;
        let config = file.model;
        let resolutions = resolutions(&self.res, &[config.resolution], &config, &path)?;
        check_precision(self.precision, self.backend)?;
        let training = if self.train_steps > 0 {
            Some(TrainingConfig::load(&path)?)
        } else {
            None
        };
        let device = self.backend.device()?;
        device.seed(0);
        // Serving renders the NVS decoder's image (the 3DGS head only where it is part of it).
        let mut model = config
            .try_init(&device)?
            .with_block_precision(self.precision)
            .without_training_heads();
        let n = model.num_blocks();
        let options = BenchOptions {
            warmup: self.warmup,
            iters: self.iters.max(1),
        };
        // On a CPU backend, the host kernels' code too (AVX-512, AVX2 or the baseline).
        let kernels = if prism_kernels::is_host(&device) {
            format!(", host kernels {}", prism_kernels::HostIsa::chosen().name())
        } else {
            String::new()
        };
        println!(
            "{} on {} ({}), blocks in {}{kernels}{}",
            path.display(),
            self.backend,
            device_name(&device),
            self.precision,
            attention_in_force(&device, self.precision)
        );
        print_header();
        let mut rows = Vec::new();
        for name in &self.models {
            let kinds = match name.as_str() {
                "teacher" => vec![AttentionKind::Full; n],
                "linear" => vec![AttentionKind::Linear; n],
                _ => file.distill.final_kinds(n),
            };
            model.set_attention_kinds(&kinds);
            for &res in &resolutions {
                let row = bench_forward(&model, name, res, &device, options);
                print_row(&row);
                rows.push(row);
            }
        }
        drop(model);
        if let Some(training) = training {
            let row = self.train_step(&training)?;
            print_row(&row);
            rows.push(row);
        }
        if let Some(path) = &self.json {
            write_json(path, &rows)?;
        }
        Ok(())
    }

    /// The teacher's training step on this backend: `train_steps` steps of `prism_train::train`
    /// (one device, no validation, the blocks computing in `--precision`), the median of the logged step times after two warm-up
    /// steps; peak memory over the whole run (model, optimizer, data, steps).
    fn train_step(&self, config: &TrainingConfig) -> anyhow::Result<BenchRow> {
        let mut config = config.clone();
        let steps = self.train_steps.max(3);
        config.train.steps = steps;
        config.train.validate_every = 0;
        config.train.validation_views = 1;
        config.train.checkpoint_every = steps;
        let data = self.data.resolve(&config.data, true)?;
        let out = std::env::temp_dir().join(format!("prism-bench-train-{}", std::process::id()));
        let options = RunOptions {
            precision: Some(self.precision),
            ..RunOptions::new(&out, data, self.backend)
        };
        let probe = MemoryProbe::start(&self.backend.device()?);
        let reads = (host_reads(), geometry_host_reads());
        let steal = StealProbe::start();
        let result = train(&config, &TeacherTask::default(), &options);
        let per_step = |now: u64, then: u64| (now - then) as f64 / steps as f64;
        let (all_reads, geometry_reads) = (
            per_step(host_reads(), reads.0),
            per_step(geometry_host_reads(), reads.1),
        );
        let peak = probe.peak_bytes();
        let metrics = result.and_then(|_| read_metrics(&out.join(prism_train::METRICS_FILE)));
        let _ = std::fs::remove_dir_all(&out);
        let mut times: Vec<f64> = metrics?
            .iter()
            .filter_map(|l| l["seconds"].as_f64())
            .skip(2)
            .collect();
        anyhow::ensure!(!times.is_empty(), "the training run logged no step times");
        times.sort_by(f64::total_cmp);
        let ms = 1e3 * times[times.len() / 2];
        let res = config.model.resolution;
        let p = config.model.patch_size;
        Ok(BenchRow {
            model: "train_step".into(),
            res,
            tokens: 2 * (res / p) * (res / p),
            ms,
            fps: 1e3 / ms,
            peak_mem_bytes: peak,
            host_reads: all_reads,
            geometry_host_reads: geometry_reads,
            cpu_steal: steal.share(),
        })
    }
}

/// The adapter's name on GPU backends, the backend's device otherwise.
fn device_name(device: &burn::tensor::Device) -> String {
    Adapter::of(device).map_or_else(|| format!("{device:?}"), |adapter| adapter.name)
}

/// On a GPU backend, `, attention` and the kernels in force for blocks in `precision` with where
/// they come from; empty on the CPU backends, where f32 attention is the fused host kernel.
fn attention_in_force(device: &burn::tensor::Device, precision: Precision) -> String {
    if prism_kernels::is_host(device) {
        return String::new();
    }
    format!(", attention {}", super::tune::in_force(device, precision))
}

/// Arguments of `prism bench precision`.
#[derive(Args, Debug)]
struct PrecisionBenchArgs {
    /// Checkpoint (or run folder: its latest checkpoint) to evaluate.
    #[arg(long, value_name = "PATH")]
    checkpoint: PathBuf,
    #[command(flatten)]
    data: DataArgs,
    /// Target views per held-out subject (evenly spread over views 1..=100).
    #[arg(long, default_value_t = 8)]
    views: usize,
    /// Half precision to compare with f32: f16 or bf16.
    #[arg(long, default_value = "f16")]
    precision: Precision,
    /// Backend: ndarray, flex, wgpu or cuda.
    #[arg(long, default_value = "flex")]
    backend: BackendKind,
}

impl PrecisionBenchArgs {
    fn run(self) -> anyhow::Result<()> {
        check_precision(self.precision, self.backend)?;
        let device = self.backend.device()?;
        let (model, config) = load_model(&self.checkpoint, &device)?;
        let data = self.data.resolve(&config.data, true)?;
        let reader = DatasetReader::open(&data)?;
        let validator = Validator::new(
            &reader,
            config.model.resolution as u32,
            self.views,
            None,
            &device,
        )?;
        println!(
            "{} on {}: {} held-out views at {} px",
            self.checkpoint.display(),
            self.backend,
            validator.len(),
            config.model.resolution
        );
        println!(
            "{:<10} {:>10} {:>8} {:>12}",
            "blocks", "PSNR (dB)", "SSIM", "s (all views)"
        );
        let mut psnr = Vec::new();
        for precision in [Precision::F32, self.precision] {
            let model = model.clone().with_block_precision(precision);
            let start = Instant::now();
            let (scores, _) = validator.validate(&model);
            let seconds = start.elapsed().as_secs_f64();
            println!(
                "{:<10} {:>10.6} {:>8.6} {:>12.2}",
                precision.to_string(),
                scores.psnr,
                scores.ssim,
                seconds
            );
            psnr.push(scores.psnr);
        }
        println!(
            "PSNR change {} - f32: {:+.6} dB",
            self.precision,
            psnr[1] - psnr[0]
        );
        Ok(())
    }
}
