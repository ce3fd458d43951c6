//! `prism body`: the body model in SMPL-X's layout and the procedural humanoid.

use std::path::PathBuf;
use std::time::Instant;

use burn::tensor::{Device, Tensor, TensorData};

use clap::{Args, Subcommand};
use prism_body::procedural;
use prism_body::{BodyLayer, NUM_BETAS, NUM_EXPRESSION, NUM_JOINTS};
use prism_body::{BodyModel, BodyParams};
use prism_core::BackendKind;
use prism_synth::people::{PeopleConfig, generate_with};

/// Body model commands.
#[derive(Subcommand, Debug)]
pub enum BodyCommand {
    /// Write the procedural humanoid (SMPL-X key layout, 55-joint tree) as an .npz file.
    Synth(SynthArgs),
    /// Load a body model .npz (SMPL-X layout), check it and print its sizes.
    Info(InfoArgs),
    /// Time the body model: batched tensor skinning (forward, forward + backward), f32
    /// skinning and the people generator.
    Bench(BenchArgs),
}

/// Arguments of `prism body synth`.
#[derive(Args, Debug)]
pub struct SynthArgs {
    /// Output .npz file (written atomically).
    #[arg(long)]
    pub out: PathBuf,
    /// Seed of the procedural model (it jitters the proportions; every seed has the same
    /// topology). Body parameters name the model `procedural:SEED`.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// Arguments of `prism body info`.
#[derive(Args, Debug)]
pub struct InfoArgs {
    /// A body model .npz (e.g. SMPLX_NEUTRAL.npz or the output of `prism body synth`).
    pub model: PathBuf,
}

/// Arguments of `prism body bench`.
#[derive(Args, Debug)]
pub struct BenchArgs {
    /// Batch size of the tensor skinning.
    #[arg(long, default_value_t = 8)]
    pub batch: usize,
    /// Timed repetitions (after one warm-up run).
    #[arg(long, default_value_t = 10)]
    pub iters: usize,
    /// Backend: ndarray, flex or wgpu.
    #[arg(long, default_value = "flex")]
    pub backend: BackendKind,
    /// A body model .npz to time instead of the procedural model.
    #[arg(long)]
    pub model: Option<PathBuf>,
}

impl BodyCommand {
    /// Runs the command.
    pub fn run(self) -> anyhow::Result<()> {
        match self {
            BodyCommand::Synth(args) => {
                let model = BodyModel::procedural(args.seed);
                model.save_npz(&args.out)?;
                println!(
                    "wrote {} ({}: {} vertices, {} faces)",
                    args.out.display(),
                    procedural::model_name(args.seed),
                    model.num_vertices(),
                    model.faces().len()
                );
                Ok(())
            }
            BodyCommand::Info(args) => {
                let model = BodyModel::load_npz(&args.model)?;
                let joints = model.rest_joints();
                let mut lo = [f32::INFINITY; 3];
                let mut hi = [f32::NEG_INFINITY; 3];
                for j in &joints {
                    for d in 0..3 {
                        lo[d] = lo[d].min(j[d]);
                        hi[d] = hi[d].max(j[d]);
                    }
                }
                println!("{}", args.model.display());
                println!("  vertices      {}", model.num_vertices());
                println!("  faces         {}", model.faces().len());
                println!(
                    "  joints        55 (SMPL-X tree: {})",
                    if model.has_smplx_tree() { "yes" } else { "no" }
                );
                println!("  joint extent  {lo:.3?} .. {hi:.3?}");
                Ok(())
            }
            BodyCommand::Bench(args) => bench(&args),
        }
    }
}

/// Mean seconds per call of `f` over `iters` calls, after one warm-up call.
fn time(iters: usize, mut f: impl FnMut()) -> f64 {
    f();
    let start = Instant::now();
    for _ in 0..iters {
        f();
    }
    start.elapsed().as_secs_f64() / iters.max(1) as f64
}

fn bench(args: &BenchArgs) -> anyhow::Result<()> {
    let model = match &args.model {
        Some(path) => BodyModel::load_npz(path)?,
        None => BodyModel::procedural(0),
    };
    let b = args.batch.max(1);
    let n = args.iters.max(1);
    println!(
        "body model {} ({} vertices), batch {b}, backend {}",
        model.name(),
        model.num_vertices(),
        args.backend
    );
    // Deterministic, moderately posed parameters.
    let wave = |i: usize, scale: f32| ((i as f32 * 0.618).fract() - 0.5) * scale;
    let betas: Vec<f32> = (0..b * NUM_BETAS).map(|i| wave(i, 2.0)).collect();
    let expr: Vec<f32> = (0..b * NUM_EXPRESSION).map(|i| wave(i + 7, 1.0)).collect();
    let pose: Vec<f32> = (0..b * NUM_JOINTS * 3).map(|i| wave(i + 3, 0.6)).collect();
    let inputs = |device: &Device| {
        (
            Tensor::<2>::from_data(TensorData::new(betas.clone(), [b, NUM_BETAS]), device),
            Tensor::<3>::from_data(TensorData::new(pose.clone(), [b, NUM_JOINTS, 3]), device),
            Tensor::<2>::from_data(TensorData::new(expr.clone(), [b, NUM_EXPRESSION]), device),
        )
    };

    let device = args.backend.device()?;
    let layer = BodyLayer::new(&model, &device);
    let forward = time(n, || {
        let (x, p, e) = inputs(&device);
        let out = layer.forward(x, p, e);
        let _ = out.vertices.into_data();
    });
    println!(
        "tensor skinning forward            {:8.2} ms per batch",
        forward * 1e3
    );

    let ad = args.backend.autodiff_device()?;
    let layer = BodyLayer::new(&model, &ad);
    let backward = time(n, || {
        let (x, p, e) = inputs(&ad);
        let (x, p, e) = (x.require_grad(), p.require_grad(), e.require_grad());
        let out = layer.forward(x, p.clone(), e);
        let grads = (out.vertices.sum() + out.joints.sum()).backward();
        let _ = p.grad(&grads).map(|g| g.into_data());
    });
    println!(
        "tensor skinning forward + backward {:8.2} ms per batch",
        backward * 1e3
    );

    let mut params = BodyParams::rest(model.name());
    params.betas.copy_from_slice(&betas[..NUM_BETAS]);
    params.expression.copy_from_slice(&expr[..NUM_EXPRESSION]);
    for (j, r) in params.pose.iter_mut().enumerate() {
        r.copy_from_slice(&pose[j * 3..j * 3 + 3]);
    }
    let lbs = time(n, || {
        let _ = model.pose(&params);
    });
    println!(
        "f32 skinning                       {:8.2} ms per body",
        lbs * 1e3
    );
    for subdivisions in [1, 2] {
        let config = PeopleConfig { subdivisions };
        let mut seed = 0;
        let people = time(n, || {
            seed += 1;
            let _ = generate_with(&model, seed, &config);
        });
        println!(
            "people::generate (subdivisions {subdivisions})  {:8.2} ms per person",
            people * 1e3
        );
    }
    Ok(())
}
