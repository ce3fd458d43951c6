use std::sync::Arc;
use burn::optim::{AdamWConfig, GradientsParams};
use prism_data::BackendKind;
use prism_data::dataset::*;
use prism_train::*;
#[test]
fn overfit() {
    let env = |k: &str, d: f64| std::env::var(k).map(|s| s.parse().unwrap()).unwrap_or(d);
    let config = TrainingConfig::load(configs_dir().join("tiny.toml")).unwrap();
    let dir = std::path::PathBuf::from("/tmp/prism-cache/datasets/synth-n6-r64-seed0-test0.2-ss1-bg1-1-1");
    let reader = DatasetReader::open(&dir).unwrap();
    let res = env("P_RES", 32.0) as u32;
    let ds = SampleDataset::new(reader, SplitKind::Train, TargetSelection::Random { count: 2, repeats: 1 }, Some((res, res)), 0).unwrap();
    let device = BackendKind::Flex.device().unwrap().autodiff();
    device.seed(0);
    let mut model = Trainee { prism: config.model.init(&device) };
    let samples: Vec<_> = (0..2).map(|i| ds.load(i).unwrap()).collect();
    let batch = PrismBatcher.batch_samples(&samples, &device);
    let mut opt = AdamWConfig::new().with_epsilon(1e-8).init();
    let lr = env("P_LR", 1e-3);
    for step in 0..env("P_STEPS", 300.0) as usize {
        let out = model.prism.forward(batch.source_image.clone(), batch.source_rays.clone(), batch.target_rays.clone(), &[]);
        let loss = (out.image - batch.target_image.clone()).powi_scalar(2).mean();
        let v: f64 = loss.clone().into_scalar();
        let grads = GradientsParams::from_grads(loss.backward(), &model);
        if step % 25 == 0 { println!("{step} {v:.5} norm {:.5}", global_norm(&model, &grads)); }
        model = opt.step(lr, model, grads);
    }
    let _ = Arc::new(0);
}
