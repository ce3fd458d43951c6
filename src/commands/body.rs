//! `prism body`: the body model in SMPL-X's layout and the procedural humanoid.

use std::path::PathBuf;

use clap::{Args, Subcommand};
use prism_data::BodyModel;
use prism_data::body::procedural;

/// Body model commands.
#[derive(Subcommand, Debug)]
pub enum BodyCommand {
    /// Write the procedural humanoid (SMPL-X key layout, 55-joint tree) as an .npz file.
    Synth(SynthArgs),
    /// Load a body model .npz (SMPL-X layout), check it and print its sizes.
    Info(InfoArgs),
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
        }
    }
}
