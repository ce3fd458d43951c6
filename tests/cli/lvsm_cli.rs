//! End to end on the tiny LVSM fixture (crates/prism-model/tests/fixtures, made by
//! scripts/make_lvsm_fixture.py): `prism convert lvsm`, then `prism evaluate
//! --save-predictions`, then `prism train-teacher --init`, which trains the converted
//! backbone at `lr_backbone` and the new geometry parts and heads at `lr_heads`.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::Output;

use burn::module::{Module, ModuleVisitor, Param, ParamId};
use burn::tensor::Tensor;
use prism_core::BackendKind;
use prism_model::{GsColour, GsDepth, NvsOutput};
use prism_train::{heads_group_with, latest_checkpoint, load_model};

use common::{prism_with_cache, scratch, stdout, success, tiny_at_32px};

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("crates/prism-model/tests/fixtures/lvsm_tiny.pt")
}

/// configs/tiny.toml at the fixture's sizes (width 32, 2 heads, patch 8) with 2 + 4 blocks (2
/// more than the fixture's 4), the paper's outputs and every geometry part, at 32 px on 4
/// synthetic subjects; the backbone's learning rate far below the heads'.
fn config(dir: &Path) -> PathBuf {
    let mut c = tiny_at_32px();
    let m = &mut c.model;
    (m.width, m.heads, m.patch_size) = (32, 2, 8);
    (m.stage_one_blocks, m.stage_three_blocks) = (2, 4);
    m.gs_colour = GsColour::Regressed;
    m.gs_depth = GsDepth::Head;
    m.gs_scale = 1.0;
    m.gs_keying = false;
    m.nvs_output = NvsOutput::Direct;
    c.distill.group_size = 2;
    c.train.steps = 2;
    c.train.warmup_steps = 0;
    c.train.checkpoint_every = 2;
    c.train.lr_backbone = 1e-12;
    c.train.lr_heads = 1e-2;
    c.train.min_lr = 0.0;
    let path = dir.join("lvsm-tiny.toml");
    std::fs::write(&path, c.to_toml()).unwrap();
    path
}

/// `prism ARGS` with the cache folder `cache`, which must succeed.
fn prism(cache: &Path, args: &[&str]) -> Output {
    success(prism_with_cache(cache, args))
}

/// Every float parameter as (path, values).
fn parameters<M: Module>(module: &M) -> Vec<(String, Vec<f32>)> {
    struct Collect(Vec<String>, Vec<(String, Vec<f32>)>);
    impl ModuleVisitor for Collect {
        fn enter_module(&mut self, name: &str, _: &str) {
            self.0.push(name.into());
        }
        fn exit_module(&mut self, _: &str, _: &str) {
            self.0.pop();
        }
        fn visit_float<const D: usize>(&mut self, p: &Param<Tensor<D>>) {
            let v = p
                .val()
                .to_data()
                .convert::<f32>()
                .try_to_vec::<f32>()
                .unwrap();
            self.1.push((self.0.join("."), v));
        }
    }
    let mut c = Collect(Vec::new(), Vec::new());
    module.visit(&mut c);
    c.1
}

#[test]
fn convert_then_evaluate_then_train_from_the_converted_backbone() {
    let dir = scratch("e2e");
    let cache = dir.join("cache");
    let config = config(&dir);
    let ckpt = dir.join("lvsm-ckpt");
    let s = |p: &Path| p.to_str().unwrap().to_string();

    // Convert: the geometry parts are reported as freshly initialised.
    let out = prism(
        &cache,
        &[
            "convert",
            "lvsm",
            "--checkpoint",
            &s(&fixture()),
            "--config",
            &s(&config),
            "--out",
            &s(&ckpt),
        ],
    );
    let text = stdout(&out);
    assert!(text.contains("37 tensors mapped"), "{text}");
    for part in [
        "smplx_branch",
        "point_branch",
        "gs_head",
        "injection",
        "stage_three.blocks.2",
        "stage_three.blocks.3",
    ] {
        assert!(text.contains(part), "{part} not reported fresh:\n{text}");
    }
    assert!(text.contains("prism blocks [0, 1, 2, 3]"), "{text}");

    // Evaluate, saving every predicted view as SUBJECT/NNN.png.
    let preds = dir.join("preds");
    prism(
        &cache,
        &[
            "evaluate",
            "--checkpoint",
            &s(&ckpt),
            "--views",
            "3",
            "--save-predictions",
            &s(&preds),
            "--out",
            &s(&dir.join("evaluation")),
            "--backend",
            "ndarray",
            "--quiet",
        ],
    );
    let subjects: Vec<PathBuf> = std::fs::read_dir(&preds)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(subjects.len(), 1, "one test subject");
    let mut names: Vec<String> = std::fs::read_dir(&subjects[0])
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names.len(), 3, "{names:?}");
    for name in &names {
        assert!(
            name.len() == 7
                && name.ends_with(".png")
                && name[..3].bytes().all(|b| b.is_ascii_digit()),
            "{name}"
        );
        let image = image::open(subjects[0].join(name)).unwrap();
        assert_eq!((image.width(), image.height()), (32, 32));
    }

    // Train from the converted checkpoint: LVSM's backbone at lr_backbone (1e-12: it stays
    // put), the geometry parts, heads and the 2 new blocks at lr_heads (1e-2: they move).
    let run = dir.join("run");
    prism(
        &cache,
        &[
            "train-teacher",
            "--config",
            &s(&config),
            "--init",
            &s(&ckpt),
            "--out",
            &s(&run),
            "--backend",
            "ndarray",
            "--quiet",
        ],
    );
    let device = BackendKind::Ndarray.device().unwrap();
    let (before, _) = load_model(&ckpt, &device).unwrap();
    let trained = latest_checkpoint(&run).unwrap().expect("a checkpoint");
    let (after, _) = load_model(&trained, &device).unwrap();
    let (before, after) = (parameters(&before), parameters(&after));
    assert_eq!(before.len(), after.len());
    let heads = heads_group_with(&[4, 5], 2);
    let id = ParamId::new();
    let (mut moved_heads, mut moved_new_blocks) = (0, 0);
    for ((path, a), (_, b)) in before.iter().zip(&after) {
        let change = a
            .iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max);
        let trainee_path = format!("{}.{path}", prism_train::TRAINEE_FIELD);
        if heads.matches(&id, Some(&trainee_path)) {
            moved_heads += usize::from(change > 1e-4);
            if path.starts_with("stage_three.blocks.") {
                moved_new_blocks += usize::from(change > 1e-4);
            }
        } else {
            assert!(change < 1e-7, "backbone parameter {path} moved by {change}");
        }
    }
    assert!(moved_heads >= 2, "the NVS head trains at lr_heads");
    assert!(moved_new_blocks >= 2, "the new blocks train at lr_heads");
    let state = std::fs::read_to_string(ckpt.join("state.json")).unwrap();
    assert!(state.contains("\"new_blocks\""), "{state}");
    // The run's log shows both rates.
    let log = std::fs::read_to_string(run.join(prism_train::METRICS_FILE)).unwrap();
    let step = log
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .find(|v| v.get("lr_heads").is_some())
        .expect("a step line");
    assert_eq!(step["lr_heads"].as_f64(), Some(1e-2));
}
