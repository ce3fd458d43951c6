//! Seconds per training step of the shipped configs:
//! `cargo bench -p prism-train [-- CONFIG... ndarray|flex]`.
//!
//! Runs `prism_train::train` on each config's own `[data]` synthetic dataset (synthesised into
//! the cache on first use) for a few steps, exactly as `prism train-teacher` does (LPIPS in
//! the loss when the config weights it, one device), and prints the median of the per-step
//! times logged in `metrics.jsonl` after two warm-up steps. Validation and checkpoints are not
//! part of a step's time.

use prism_core::BackendKind;
use prism_synth::ensure_synthetic_dataset;
use prism_train::{RunOptions, TeacherTask, TrainingConfig, configs_dir, read_metrics, train};

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| a != "--bench")
        .collect();
    let mut configs: Vec<String> = args
        .iter()
        .filter(|a| a.parse::<BackendKind>().is_err())
        .cloned()
        .collect();
    let mut backends: Vec<BackendKind> = args.iter().filter_map(|a| a.parse().ok()).collect();
    if configs.is_empty() {
        configs = vec!["tiny".into(), "small".into()];
    }
    if backends.is_empty() {
        backends = vec![BackendKind::Ndarray, BackendKind::Flex];
    }
    println!("| config | backend | pairs / step | resolution | s / step (median) |");
    println!("|---|---|---|---|---|");
    for name in &configs {
        let mut config = TrainingConfig::load(configs_dir().join(format!("{name}.toml"))).unwrap();
        let steps = if config.model.resolution <= 64 { 22 } else { 8 };
        config.train.steps = steps;
        config.train.validate_every = 0;
        config.train.validation_views = 1;
        config.train.checkpoint_every = steps;
        let data = ensure_synthetic_dataset(&config.data, true).unwrap();
        for &backend in &backends {
            let out = tempfile::tempdir().unwrap();
            let options = RunOptions::new(out.path(), &data, backend);
            train(&config, &TeacherTask::default(), &options).unwrap();
            let mut times: Vec<f64> = read_metrics(&out.path().join(prism_train::METRICS_FILE))
                .unwrap()
                .iter()
                .filter_map(|l| l["seconds"].as_f64())
                .skip(2)
                .collect();
            times.sort_by(f64::total_cmp);
            println!(
                "| {name} | {backend} | {} | {} | {:.3} |",
                config.train.batch_size * config.train.targets_per_sample,
                config.model.resolution,
                times[times.len() / 2]
            );
        }
    }
}
