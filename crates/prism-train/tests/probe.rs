mod common;
use prism_data::BackendKind;
use prism_train::{RunOptions, TeacherTask, train, ensure_synthetic_dataset, read_metrics};
#[test]
fn probe() {
    let env = |k: &str, d: f64| std::env::var(k).map(|s| s.parse().unwrap()).unwrap_or(d);
    let mut config = common::tiny(|c| {
        c.train.steps = env("P_STEPS", 100.0) as usize;
        c.train.validate_every = env("P_VAL", 50.0) as usize;
        c.losses.lpips = env("P_LPIPS", 0.0);
        c.train.lr_backbone = env("P_LR", 2e-3);
        c.train.lr_heads = c.train.lr_backbone;
        c.model.resolution = env("P_RES", 64.0) as usize;
        c.data.subjects = env("P_SUBJ", 6.0) as usize;
        c.train.batch_size = env("P_BATCH", 2.0) as usize;
        c.train.targets_per_sample = env("P_TGT", 2.0) as usize;
        c.train.warmup_steps = env("P_WARM", 4.0) as usize;
    });
    config.data.resolution = env("P_DRES", 64.0) as u32;
    let t = std::time::Instant::now();
    let dir = ensure_synthetic_dataset(&config.data, true).unwrap();
    println!("synth {:?} {}", t.elapsed(), dir.display());
    let out = tempfile::tempdir().unwrap();
    let out = std::mem::ManuallyDrop::new(out);
    println!("OUT {}", out.path().display());
    let mut o = RunOptions::new(out.path(), if env("P_FLEX", 0.0) > 0.0 { BackendKind::Flex } else { BackendKind::Ndarray });
    o.data = Some(dir);
    let t = std::time::Instant::now();
    let s = train(&config, &TeacherTask::default(), &o).unwrap();
    println!("train {:?} sps {}", t.elapsed(), s.seconds_per_step);
    for l in read_metrics(&out.path().join("metrics.jsonl")).unwrap() { if l.get("loss").is_none() { println!("{l}"); } }
}
