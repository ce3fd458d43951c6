//! Mixed-precision training on flex (the CPU backend that computes in f16): exact unscaling of
//! a scaled loss's gradients, dynamic loss scaling on a planted f16 overflow, resumption of the
//! scale and the precision, and a clear error where the backend has no f16.

mod common;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use burn::tensor::Device;
use prism_core::BackendKind;
use prism_data::PrismBatch;
use prism_losses::LossTerms;
use prism_model::{Precision, Prism};
use prism_train::{
    Checkpoint, GRADIENT_OVERFLOW, LossScaleConfig, LossScaleState, RunOptions, StepLoss, Task,
    TeacherTask, TrainError, TrainingConfig, list_checkpoints, read_metrics, train,
};
use serde_json::Value;

/// One dataset for every test of this file: 4 subjects (one held out) at 32 px.
fn dataset() -> PathBuf {
    common::dataset_once(4)
}

/// A fresh run into `out` on flex with the blocks in `precision`.
fn options(out: &Path, precision: Precision) -> RunOptions {
    RunOptions {
        precision: Some(precision),
        ..RunOptions::new(out, dataset(), BackendKind::Flex)
    }
}

/// The tiny config at 32 px, `steps` steps, a checkpoint after every step, no LPIPS in the
/// loss, validation only at both ends.
fn tiny_config(steps: usize) -> TrainingConfig {
    common::tiny(|c| {
        c.model.resolution = 32;
        c.losses.lpips = 0.0;
        c.train.steps = steps;
        c.train.batch_size = 1;
        c.train.validate_every = 0;
        c.train.validation_views = 1;
        c.train.checkpoint_every = 1;
        c.train.keep_checkpoints = steps;
    })
}

/// The step lines of a run's log (validations and baselines left out).
fn step_lines(run: &Path) -> Vec<Value> {
    read_metrics(&run.join("metrics.jsonl"))
        .unwrap()
        .into_iter()
        .filter(|l| l.get("loss").is_some())
        .collect()
}

/// A step line's number (`key`).
fn number(line: &Value, key: &str) -> f64 {
    line[key]
        .as_f64()
        .unwrap_or_else(|| panic!("no {key} in {line}"))
}

fn weights(checkpoint: &Path) -> Vec<Vec<f32>> {
    common::weights(checkpoint, BackendKind::Flex)
}

fn checkpoint(run: &Path, step: usize) -> PathBuf {
    run.join(format!("checkpoints/step-{step:08}"))
}

/// Dividing the gradients of the scaled loss by the scale gives the unscaled gradients: the
/// logged gradient norms (taken after unscaling, before clipping) of a run scaled by 2^10 are
/// those of the same run unscaled, up to rounding (a missing or doubled division would be off
/// by a factor of 1024 or more), and so are its losses and weights. In f32, so that the scale
/// cannot change what underflows.
#[test]
fn gradients_of_a_scaled_loss_are_unscaled_exactly() {
    let _serial = common::serial();
    let config = tiny_config(2);
    let plain = tempfile::tempdir().unwrap();
    let scaled = tempfile::tempdir().unwrap();
    train(
        &config,
        &TeacherTask::default(),
        &options(plain.path(), Precision::F32),
    )
    .unwrap();
    let forced = RunOptions {
        loss_scale: Some(LossScaleConfig {
            initial: 1024.0,
            growth_interval: 100,
        }),
        ..options(scaled.path(), Precision::F32)
    };
    train(&config, &TeacherTask::default(), &forced).unwrap();
    let (a, b) = (step_lines(plain.path()), step_lines(scaled.path()));
    assert_eq!((a.len(), b.len()), (2, 2));
    for (a, b) in a.iter().zip(&b) {
        assert!(
            a.get("loss_scale").is_none(),
            "f32 scales nothing by default"
        );
        assert_eq!(number(b, "loss_scale"), 1024.0);
        for key in ["grad_norm", "loss"] {
            let (x, y) = (number(a, key), number(b, key));
            assert!(
                (x - y).abs() <= 1e-5 * x.abs(),
                "{key}: {x} unscaled, {y} scaled"
            );
        }
    }
    let (x, y) = (
        weights(&checkpoint(plain.path(), 2)),
        weights(&checkpoint(scaled.path(), 2)),
    );
    let diff = x
        .iter()
        .zip(&y)
        .flat_map(|(p, q)| p.iter().zip(q).map(|(a, b)| (a - b).abs()))
        .fold(0.0f32, f32::max);
    assert!(diff < 1e-6, "weights differ by {diff}");
}

/// The teacher's objective whose gradient (not its value) is multiplied by `factor` at `step`:
/// `L + (f L - stop_gradient(f L))` has the value of `L` and the gradient of `f L`.
struct Planted {
    inner: Arc<dyn StepLoss>,
    step: usize,
    factor: f64,
}

impl StepLoss for Planted {
    fn loss(&self, model: &Prism, batch: &PrismBatch, step: usize) -> LossTerms {
        let mut terms = self.inner.loss(model, batch, step);
        if step == self.step {
            let big = terms.total.clone().mul_scalar(self.factor);
            terms.total = terms.total.detach() + (big.clone() - big.detach());
        }
        terms
    }
}

/// The teacher's job with a [`Planted`] gradient at step 1 (0-based).
fn planted_task() -> impl Task {
    common::TeacherWith(|inner| -> Arc<dyn StepLoss> {
        Arc::new(Planted {
            inner,
            step: 1,
            factor: 2f64.powi(30),
        })
    })
}

/// Checks the scale of every step line against the rule: halved after an overflow, doubled
/// after `interval` applied steps in a row, unchanged otherwise. Returns the scales.
fn check_scale_rule(lines: &[Value], interval: usize) -> Vec<f64> {
    let scales: Vec<f64> = lines.iter().map(|l| number(l, "loss_scale")).collect();
    let mut finite = 0;
    for (i, line) in lines.iter().enumerate().skip(1) {
        let previous = &lines[i - 1];
        let expected = if previous["skipped"] == true {
            assert_eq!(previous["reason"], GRADIENT_OVERFLOW, "{previous}");
            finite = 0;
            scales[i - 1] / 2.0
        } else {
            finite += 1;
            if finite == interval {
                finite = 0;
                scales[i - 1] * 2.0
            } else {
                scales[i - 1]
            }
        };
        assert_eq!(scales[i], expected, "the scale of {line}");
    }
    scales
}

/// f16 training with dynamic loss scaling: the planted gradient overflows f16 at step 2, which
/// is skipped (the weights untouched) and halves the scale, without stopping the run although
/// `max_non_finite_steps` is 1; the scale doubles after 2 applied steps in a row; the
/// parameters stay f32. bf16 scales nothing.
#[test]
fn an_f16_overflow_halves_the_scale_and_skips_the_step() {
    let _serial = common::serial();
    let mut config = tiny_config(5);
    config.train.max_non_finite_steps = 1;
    let out = tempfile::tempdir().unwrap();
    let run = RunOptions {
        loss_scale: Some(LossScaleConfig {
            initial: 1024.0,
            growth_interval: 2,
        }),
        ..options(out.path(), Precision::F16)
    };
    let summary = train(&config, &planted_task(), &run).unwrap();
    assert_eq!((summary.steps, summary.skipped_steps), (5, 1));
    let lines = step_lines(out.path());
    let skipped: Vec<f64> = lines
        .iter()
        .filter(|l| l["skipped"] == true)
        .map(|l| number(l, "step"))
        .collect();
    assert_eq!(skipped, vec![2.0], "the planted step, and only it");
    let scales = check_scale_rule(&lines, 2);
    assert_eq!(scales, vec![1024.0, 1024.0, 512.0, 512.0, 1024.0]);
    assert_eq!(
        weights(&checkpoint(out.path(), 1)),
        weights(&checkpoint(out.path(), 2)),
        "the skipped step changes nothing"
    );
    let state = Checkpoint::read(out.path()).unwrap().state;
    assert_eq!(state.precision, Precision::F16);
    assert_eq!(
        state.loss_scale,
        Some(LossScaleState {
            scale: 1024.0,
            finite_steps: 1,
            growth_interval: 2,
        }),
        "doubled after step 4, one finite step since"
    );
    let model = Checkpoint::read(out.path())
        .unwrap()
        .load_model(&Device::flex())
        .unwrap();
    assert!(
        model
            .blocks()
            .all(|b| b.dtype() == burn::tensor::DType::F32),
        "f32 master weights"
    );

    // The same planted gradient in bf16 (f32's exponent range) needs no scale.
    let out = tempfile::tempdir().unwrap();
    let mut config = tiny_config(2);
    config.train.max_non_finite_steps = 1;
    let summary = train(
        &config,
        &planted_task(),
        &options(out.path(), Precision::Bf16),
    )
    .unwrap();
    assert_eq!(summary.skipped_steps, 0);
    assert!(
        step_lines(out.path())
            .iter()
            .all(|l| l.get("loss_scale").is_none())
    );
    assert_eq!(
        Checkpoint::read(out.path()).unwrap().state.precision,
        Precision::Bf16
    );
}

/// A resumed f16 run continues with the checkpoint's scale and count of finite steps (the
/// scale doubling at the same step as without the interruption) and in the run's precision;
/// another precision is refused, and so is f16 on a backend without it.
#[test]
fn resume_restores_the_loss_scale_and_the_precision() {
    let _serial = common::serial();
    let config = tiny_config(5);
    let scaling = Some(LossScaleConfig {
        initial: 256.0,
        growth_interval: 3,
    });
    let full = tempfile::tempdir().unwrap();
    let run = RunOptions {
        loss_scale: scaling,
        ..options(full.path(), Precision::F16)
    };
    train(&config, &TeacherTask::default(), &run).unwrap();
    let scales = |dir: &Path| -> Vec<f64> {
        step_lines(dir)
            .iter()
            .map(|l| number(l, "loss_scale"))
            .collect()
    };
    assert_eq!(scales(full.path()), vec![256.0, 256.0, 256.0, 512.0, 512.0]);

    // Stopped after step 2: one finite step short of doubling.
    let cut = tempfile::tempdir().unwrap();
    common::copy_dir(full.path(), cut.path());
    for (step, dir) in list_checkpoints(cut.path()).unwrap() {
        if step > 2 {
            std::fs::remove_dir_all(dir).unwrap();
        }
    }
    assert_eq!(
        Checkpoint::read(cut.path()).unwrap().state.loss_scale,
        Some(LossScaleState {
            scale: 256.0,
            finite_steps: 2,
            growth_interval: 3,
        })
    );
    let mut resume = RunOptions::new(cut.path(), dataset(), BackendKind::Flex);
    resume.resume = true;
    resume.precision = Some(Precision::Bf16);
    let err = train(&config, &TeacherTask::default(), &resume)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("precision: f16 in the checkpoint, bf16"),
        "{err}"
    );
    // Without --precision and loss-scale settings: the run's own.
    resume.precision = None;
    let summary = train(&config, &TeacherTask::default(), &resume).unwrap();
    assert_eq!((summary.start_step, summary.steps), (2, 5));
    assert_eq!(scales(cut.path()), scales(full.path()));
    let losses =
        |dir: &Path| -> Vec<f64> { step_lines(dir).iter().map(|l| number(l, "loss")).collect() };
    assert_eq!(losses(cut.path()), losses(full.path()));
    assert_eq!(
        Checkpoint::read(cut.path()).unwrap().state,
        Checkpoint::read(full.path()).unwrap().state
    );

    // ndarray computes in f32 and f64 only.
    let out = tempfile::tempdir().unwrap();
    let on_ndarray = RunOptions {
        precision: Some(Precision::F16),
        ..RunOptions::new(out.path(), dataset(), BackendKind::Ndarray)
    };
    let err = train(&config, &TeacherTask::default(), &on_ndarray).unwrap_err();
    assert!(
        matches!(
            err,
            TrainError::UnsupportedPrecision {
                precision: Precision::F16,
                ..
            }
        ),
        "{err}"
    );
    assert!(
        err.to_string()
            .contains("ndarray backend cannot compute in f16")
    );
}
