//! Forward time of the teacher, the distilled student and the fully-linear ablation of a config,
//! measured in one run with `prism_model::bench_forward` (inference, batch 1, median after
//! warm-up): the kinds come from the config's `[distill]` section.
//!
//! `cargo run --release -p prism-train --example distill_speed -- configs/small.toml 128 256`

use prism_data::BackendKind;
use prism_model::{BenchOptions, DistillMode, bench_forward};
use prism_train::{TrainingConfig, kinds_letters};

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let path = args.next().unwrap_or_else(|| "configs/small.toml".into());
    let config = TrainingConfig::load(&path)?;
    let resolutions: Vec<usize> = args.map(|a| a.parse()).collect::<Result<_, _>>()?;
    let resolutions = if resolutions.is_empty() {
        vec![config.model.resolution, 2 * config.model.resolution]
    } else {
        resolutions
    };
    let device = BackendKind::Flex.device()?;
    device.seed(0);
    let mut model = config.model.init(&device);
    let blocks = model.num_blocks();
    let options = BenchOptions {
        warmup: 3,
        iters: 10,
    };
    println!(
        "{:<14} {:<14} {:>6} {:>10}",
        "model", "attention", "res", "ms/frame"
    );
    for (name, mode) in [
        ("teacher", DistillMode::Teacher),
        ("student", DistillMode::Progressive),
        ("fully_linear", DistillMode::FullyLinear),
    ] {
        let mut distill = config.distill.clone();
        distill.mode = mode;
        let kinds = distill.final_kinds(blocks);
        model.set_attention_kinds(&kinds);
        for &res in &resolutions {
            let row = bench_forward(&model, name, res, &device, options);
            println!(
                "{:<14} {:<14} {:>6} {:>10.2}",
                name,
                kinds_letters(&kinds),
                res,
                row.ms
            );
        }
    }
    Ok(())
}
