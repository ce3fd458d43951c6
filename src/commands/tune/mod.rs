//! `prism tune`: measure, on this machine's GPU, what is fastest, and keep the choice.
//!
//! `prism tune attention` times a block's softmax attention (the model's call: heads split from
//! the joint projection, QK-norm, attention, heads merged) through each kernel the GPU backends
//! have (Burn's attention op, prism's flash kernels, prism's matmul-softmax-matmul) at a config's
//! shapes, with and without a gradient, and records the fastest of each for the adapter and the
//! inputs' precision ([`record`]). From then on, attention in that precision on that adapter
//! takes them wherever `PRISM_ATTENTION` does not say otherwise.

pub mod record;

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use burn::tensor::{Device, Distribution, Tensor};
use clap::{Args, Subcommand};
use prism_core::BackendKind;
use prism_kernels::{AttentionKernel, ChoiceOrigin, GpuAttention, Mixing};
use prism_model::{Precision, load_config, median, parse_config};

use record::{Adapter, Choice, KernelTime, Record, Shape};

/// What to tune.
#[derive(Subcommand, Debug)]
pub enum TuneCommand {
    /// Time a block's attention through each GPU kernel; keep the fastest for this adapter.
    ///
    /// Times the model's softmax attention call through Burn's attention op, prism's flash
    /// kernels and prism's matmul-softmax-matmul at a config's shapes, with and without a
    /// gradient, and keeps the fastest of each for this adapter and precision: attention on it
    /// takes them from then on, unless PRISM_ATTENTION says otherwise. Each record is
    /// <cache folder>/attention/<adapter's fingerprint>-<precision>.json; delete it to go back
    /// to Burn's ops.
    Attention(AttentionArgs),
}

impl TuneCommand {
    /// Runs the subcommand.
    pub fn run(self) -> anyhow::Result<()> {
        match self {
            Self::Attention(args) => args.run(),
        }
    }
}

/// Arguments of `prism tune attention`.
#[derive(Args, Debug)]
pub struct AttentionArgs {
    /// Config file whose `[model]` gives the shapes (heads, head width, tokens) [default: the
    /// small config, configs/small.toml, built in].
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Image side in pixels, which sets the tokens [default: the config's]. Tune at the
    /// resolution you train at: the kernels that keep the scores grow with its square.
    #[arg(long, value_name = "PIXELS")]
    res: Option<usize>,
    /// (source, target) pairs per call.
    #[arg(long, default_value_t = 1)]
    batch: usize,
    /// Precisions of the inputs to tune, each recorded apart (comma-separated: f32, f16,
    /// bf16) [default: those of the three the adapter computes in].
    #[arg(long, value_delimiter = ',')]
    precision: Vec<Precision>,
    /// GPU backend: wgpu or cuda.
    #[arg(long, default_value = "wgpu")]
    backend: BackendKind,
    /// Untimed calls of each kernel before timing (the first compiles it).
    #[arg(long, default_value_t = 2)]
    warmup: usize,
    /// Timed calls of each kernel (the median is kept).
    #[arg(long, default_value_t = 10)]
    iters: usize,
    /// Print the table without recording the choice.
    #[arg(long)]
    no_record: bool,
    /// Time nothing: say which kernels attention takes on this adapter, and why.
    #[arg(long)]
    show: bool,
}

impl AttentionArgs {
    fn run(self) -> anyhow::Result<()> {
        let device = self.backend.device()?;
        let adapter = Adapter::of(&device).with_context(|| {
            format!(
                "the {} backend runs on the CPU, where attention is one fused host kernel: \
                 there is nothing to tune (use --backend wgpu or cuda)",
                self.backend
            )
        })?;
        let precisions = self.precisions(&device, &adapter)?;
        if self.show {
            for precision in precisions {
                let choice = in_force(&device, precision);
                let (name, backend) = (&adapter.name, self.backend);
                println!("attention on {name} ({backend}) in {precision}: {choice}");
            }
            return Ok(());
        }
        for precision in precisions {
            self.tune(&device, &adapter, precision)?;
        }
        Ok(())
    }

    /// `--precision`'s list, each checked against the device, or the precisions of f32, f16
    /// and bf16 the device computes in.
    fn precisions(&self, device: &Device, adapter: &Adapter) -> anyhow::Result<Vec<Precision>> {
        if self.precision.is_empty() {
            let all = [Precision::F32, Precision::F16, Precision::Bf16];
            return Ok(all.into_iter().filter(|p| p.supported_on(device)).collect());
        }
        for precision in &self.precision {
            anyhow::ensure!(
                precision.supported_on(device),
                "the {} backend does not compute in {precision} on {}",
                self.backend,
                adapter.name
            );
        }
        Ok(self.precision.clone())
    }

    /// Times each kernel with `precision` inputs, prints the table and, unless `--no-record`,
    /// records the fastest of each for the adapter.
    fn tune(&self, device: &Device, adapter: &Adapter, precision: Precision) -> anyhow::Result<()> {
        let (shape, norm_eps) = self.shape(precision)?;
        println!(
            "attention on {} ({}): {} pair(s) x {} heads x {} tokens x head width {}, {}",
            adapter.name,
            self.backend,
            shape.batch,
            shape.heads,
            shape.tokens,
            shape.head_dim,
            shape.precision
        );
        let timer = Timer {
            device: device.clone(),
            shape: [shape.batch, shape.heads, shape.tokens, shape.head_dim],
            norm_eps,
            precision,
            warmup: self.warmup,
            iters: self.iters.max(1),
        };
        let kernels = timer.kernels();
        println!(
            "{:<10} {:<8} {:>10} {:>14}",
            "mode", "kernel", "ms", "kept_for_grad"
        );
        let inference = timer.time_all("inference", &kernels.0, false)?;
        let training = timer.time_all("training", &kernels.1, true)?;
        let choice = Choice::fastest(&inference, &training)?;
        let attention = choice.attention()?;
        let record = Record {
            adapter: adapter.clone(),
            backend: self.backend.to_string(),
            prism: env!("CARGO_PKG_VERSION").into(),
            shape,
            inference,
            training,
            choice,
        };
        if self.no_record {
            println!("fastest: {attention} (not recorded)");
            return Ok(());
        }
        let path = adapter.record_path(precision);
        record.write(&path)?;
        println!(
            "fastest: {attention}; recorded for this adapter in {}",
            path.display()
        );
        if let Some(set) = GpuAttention::from_environment() {
            println!("(PRISM_ATTENTION is set, and takes precedence: {set})");
        }
        Ok(())
    }

    /// The shapes to time at: the config's heads and head width, the tokens of `--res`, in
    /// `precision`; and the config's `norm_eps` (of QK-norm).
    fn shape(&self, precision: Precision) -> anyhow::Result<(Shape, f64)> {
        let (config, model) = match &self.config {
            Some(path) => (path.display().to_string(), load_config(path)?.model),
            None => {
                let path = "configs/small.toml";
                let file = parse_config(prism_train::quickstart::SMALL_CONFIG, Path::new(path));
                (path.to_string(), file?.model)
            }
        };
        let res = self.res.unwrap_or(model.resolution);
        anyhow::ensure!(
            res >= model.patch_size && res.is_multiple_of(model.patch_size),
            "--res {res} is not a positive multiple of the config's patch size {}",
            model.patch_size
        );
        anyhow::ensure!(self.batch >= 1, "--batch must be at least 1");
        let side = res / model.patch_size;
        let shape = Shape {
            config,
            resolution: res,
            batch: self.batch,
            heads: model.heads,
            tokens: 2 * side * side,
            head_dim: model.width / model.heads,
            precision: precision.to_string(),
        };
        Ok((shape, model.norm_eps))
    }
}

/// The kernels attention with `precision` inputs takes on `device` on this thread, and where
/// that choice comes from: `inference burn, training flash (PRISM_ATTENTION)`.
pub fn in_force(device: &Device, precision: Precision) -> String {
    let (choice, origin) = GpuAttention::in_force(device, precision.dtype().into());
    let origin = match origin {
        ChoiceOrigin::Thread => "set in code".to_string(),
        ChoiceOrigin::Environment => "PRISM_ATTENTION".to_string(),
        ChoiceOrigin::Measured => Adapter::of(device).map_or_else(
            || "measured by prism tune attention".to_string(),
            |adapter| {
                format!(
                    "measured by prism tune attention, {}",
                    adapter.record_path(precision).display()
                )
            },
        ),
        ChoiceOrigin::Default => "the default; prism tune attention measures this adapter".into(),
    };
    format!("{choice} ({origin})")
}

/// Times a block's attention on one device at one shape.
struct Timer {
    device: Device,
    /// `[batch, heads, tokens, head_dim]`.
    shape: [usize; 4],
    /// QK-norm's epsilon.
    norm_eps: f64,
    precision: Precision,
    warmup: usize,
    iters: usize,
}

impl Timer {
    /// The kernels to time without and with a gradient: every one, less the flash kernels
    /// where they do not take this shape (a head wider than they allow).
    fn kernels(&self) -> (Vec<AttentionKernel>, Vec<AttentionKernel>) {
        let one_head = [1, 1, 1, self.shape[3]];
        let [q, k, v] = std::array::from_fn(|_| self.random(one_head, &self.device));
        let flash = prism_kernels::device::supported(&q, &k, &v);
        if !flash {
            println!("(the flash kernels do not take this shape: not timed)");
        }
        let keep = |kernels: &[AttentionKernel]| {
            kernels
                .iter()
                .copied()
                .filter(|&k| flash || k != AttentionKernel::Flash)
                .collect()
        };
        (
            keep(&AttentionKernel::ALL),
            keep(&AttentionKernel::TRAINING),
        )
    }

    /// [`Timer::time`] of each kernel, each printed as a row of the table as it is timed.
    ///
    /// # Errors
    /// A device that stopped running the kernels.
    fn time_all(
        &self,
        mode: &str,
        kernels: &[AttentionKernel],
        tracked: bool,
    ) -> anyhow::Result<Vec<KernelTime>> {
        let mib = |bytes: u64| format!("{:.1} MiB", bytes as f64 / (1024.0 * 1024.0));
        kernels
            .iter()
            .map(|&kernel| {
                let time = self.time(kernel, tracked)?;
                let kept = time.kept_bytes.map_or("-".into(), mib);
                println!("{mode:<10} {:<8} {:>10.3} {kept:>14}", time.kernel, time.ms);
                Ok(time)
            })
            .collect()
    }

    /// A tensor of standard normal values of `shape`, in the precision, on `device`.
    fn random<const D: usize>(&self, shape: [usize; D], device: &Device) -> Tensor<D> {
        Tensor::<D>::random(shape, Distribution::Normal(0.0, 1.0), device)
            .cast(self.precision.dtype())
    }

    /// The median time of one call of a block's attention (`prism_kernels::self_attention`
    /// on a random joint projection `[batch, tokens, 3 heads head_dim]`, QK-norm's gains at 1)
    /// through `kernel` (with a gradient when `tracked`: forward and backward of
    /// `sum(attention * w)`, the gains' gradients included), and with a gradient the bytes its
    /// forward pass keeps for the backward pass.
    ///
    /// # Errors
    /// A device that stopped running the kernels.
    fn time(&self, kernel: AttentionKernel, tracked: bool) -> anyhow::Result<KernelTime> {
        let choice = GpuAttention::new(kernel, kernel);
        let device = if tracked {
            self.device.clone().autodiff()
        } else {
            self.device.clone()
        };
        let [batch, heads, tokens, head_dim] = self.shape;
        let width = heads * head_dim;
        let gain = || Tensor::<1>::ones([head_dim], &device).cast(self.precision.dtype());
        let mut qkv: Tensor<3> = self.random([batch, tokens, 3 * width], &device);
        let (mut q_gain, mut k_gain) = (gain(), gain());
        if tracked {
            qkv = qkv.require_grad();
            q_gain = q_gain.require_grad();
            k_gain = k_gain.require_grad();
        }
        let weights = self.random([batch, tokens, width], &device);
        let softmax = Mixing::Softmax { bf16: false };
        let forward = || {
            choice.run(|| {
                let (q, k) = (q_gain.clone(), k_gain.clone());
                prism_kernels::self_attention(qkv.clone(), q, k, heads, self.norm_eps, softmax)
            })
        };
        let call = || {
            let out = forward();
            let kept = tracked.then(|| {
                let grads = (out.clone() * weights.clone()).sum().backward();
                (qkv.grad(&grads), q_gain.grad(&grads), k_gain.grad(&grads))
            });
            let synced = self.sync();
            drop((out, kept));
            synced
        };
        for _ in 0..self.warmup {
            call()?;
        }
        let mut times: Vec<f64> = (0..self.iters)
            .map(|_| {
                let start = Instant::now();
                call()?;
                Ok(start.elapsed().as_secs_f64() * 1e3)
            })
            .collect::<anyhow::Result<_>>()?;
        times.sort_by(f64::total_cmp);
        let kept_bytes = if tracked {
            let before = self.bytes_in_use()?;
            let out = forward();
            let after = self.bytes_in_use()?;
            drop(out);
            before
                .zip(after)
                .map(|(before, after)| after.saturating_sub(before))
        } else {
            None
        };
        Ok(KernelTime {
            kernel: kernel.name().into(),
            ms: median(&times),
            kept_bytes,
        })
    }

    /// Waits for everything queued on the device.
    ///
    /// # Errors
    /// A device that stopped running the kernels.
    fn sync(&self) -> anyhow::Result<()> {
        self.device
            .sync()
            .map_err(|err| anyhow::anyhow!("the device stopped: {err:?}"))
    }

    /// Bytes the device's pools hold in live allocations once everything queued has run,
    /// where the backend reports them.
    ///
    /// # Errors
    /// A device that stopped running the kernels.
    fn bytes_in_use(&self) -> anyhow::Result<Option<u64>> {
        self.sync()?;
        Ok(self
            .device
            .memory_pool_usage()
            .map(|usage| usage.bytes_in_use))
    }
}
