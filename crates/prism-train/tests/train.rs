//! The training loop on a small ray-cast dataset (ndarray backend).

mod common;

use std::path::PathBuf;
use std::sync::OnceLock;

use prism_data::BackendKind;
use prism_train::{RunOptions, TeacherTask, train};

/// One dataset for every test of this file: 5 subjects (one held out) at 32 px.
fn dataset() -> PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("prism-train-tests-{}", std::process::id()));
        common::write_dataset(&dir, 5, 32);
        dir
    })
    .clone()
}

fn options(out: &std::path::Path) -> RunOptions {
    let mut o = RunOptions::new(out, BackendKind::Ndarray);
    o.data = Some(dataset());
    o
}

#[test]
fn timing_probe() {
    let out = tempfile::tempdir().unwrap();
    let config = common::tiny(|c| {
        c.model.resolution = 32;
        c.train.steps = 10;
        c.train.validate_every = 0;
    });
    let t = std::time::Instant::now();
    let summary = train(&config, &TeacherTask::default(), &options(out.path())).unwrap();
    println!("{summary:#?} total {:?}", t.elapsed());
}
