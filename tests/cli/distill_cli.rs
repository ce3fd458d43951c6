//! End-to-end test of `prism distill-student` through the built binary (ndarray backend): a
//! tiny teacher is trained, then distilled into the progressive student (interrupted and
//! resumed) and the paper's ablations, on a tiny synthetic dataset in a private cache folder.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::Output;

use prism_core::BackendKind;
use prism_model::AttentionKind;
use prism_synth::ensure_synthetic_dataset_in;
use prism_train::{Checkpoint, TrainingConfig, kinds_letters, load_model, read_metrics};

use common::{prism_with_cache, scratch, stdout, success, tiny_at_32px};

/// configs/tiny.toml (its `[distill]` schedule included) at 32 px without LPIPS in the loss
/// (LPIPS backward is slow on ndarray; validation still reports it), 4 subjects of 32 px, with
/// the paper's output parameterisation: the hidden-state comparison below is a property of the
/// schedule seen on the paper's model; with the shipped geometric outputs at this 24-step
/// budget the fully linear ablation's `L_distill` is not reliably above the progressive
/// student's (BENCHMARKS.md, "Distillation"), while `prism quickstart`'s test distils them.
fn tiny_config() -> TrainingConfig {
    let mut c = tiny_at_32px();
    c.model = c.model.clone().paper_outputs();
    c.losses.gs_opacity = 0.0;
    c.losses.smplx = 1.0;
    c
}

/// `prism ARGS --backend ndarray --quiet` with the cache folder `cache`, which must succeed.
fn prism(cache: &Path, args: &[&str]) -> Output {
    let mut cmd = prism_with_cache(cache, args);
    cmd.args(["--backend", "ndarray", "--quiet"]);
    success(cmd)
}

/// The validation PSNRs of a run, in order.
fn psnrs(run: &Path) -> Vec<f64> {
    read_metrics(&run.join("metrics.jsonl"))
        .unwrap()
        .iter()
        .filter_map(|l| l.get("val_psnr").and_then(|v| v.as_f64()))
        .collect()
}

/// The mean `L_distill` of a run's training steps.
fn mean_distill(run: &Path) -> f64 {
    let values: Vec<f64> = read_metrics(&run.join("metrics.jsonl"))
        .unwrap()
        .iter()
        .filter_map(|l| l.get("distill").and_then(|v| v.as_f64()))
        .collect();
    values.iter().sum::<f64>() / values.len() as f64
}

fn latest(run: &Path) -> PathBuf {
    prism_train::latest_checkpoint(run).unwrap().unwrap()
}

#[test]
fn distilled_student_stays_near_its_teacher_and_beats_the_fully_linear_ablation() {
    let dir = scratch("e2e");
    let cache = dir.join("cache");
    let config = tiny_config();
    ensure_synthetic_dataset_in(&cache, &config.data, false).unwrap();
    let config_path = dir.join("tiny.toml");
    std::fs::write(&config_path, config.to_toml()).unwrap();
    let cfg = config_path.to_str().unwrap();
    let path = |name: &str| dir.join(name).to_str().unwrap().to_string();

    let teacher = path("teacher");
    prism(
        &cache,
        &["train-teacher", "--config", cfg, "--out", &teacher],
    );
    let teacher_psnr = *psnrs(Path::new(&teacher)).last().unwrap();

    // The progressive student, stopped after 6 steps (between the two switches) and resumed.
    let student = path("student");
    let distill = |out: &str, extra: &[&str]| {
        let mut args = vec!["distill-student", "--config", cfg, "--teacher", &teacher];
        args.extend(["--out", out]);
        args.extend(extra);
        prism(&cache, &args)
    };
    let out = distill(&student, &["--steps", "6"]);
    let first = Checkpoint::read(&latest(Path::new(&student))).unwrap();
    assert_eq!(first.state.step, 6);
    assert_eq!(kinds_letters(&first.attention), "LFFLFF");
    // The announced schedule is the one this run follows, --steps included.
    let printed = stdout(&out);
    assert!(
        printed.contains("6 steps at lr 1.0e-3, final attention LFFLFF"),
        "{printed}"
    );
    let out = distill(&student, &["--resume"]);
    let stdout = stdout(&out);
    assert!(stdout.contains("trained steps 6..24"), "{stdout}");

    // Every switch is logged once, between steps, where the schedule says.
    let switches: Vec<(u64, String)> = read_metrics(&Path::new(&student).join("metrics.jsonl"))
        .unwrap()
        .iter()
        .filter_map(|l| {
            Some((
                l["step"].as_u64()?,
                l.get("attention")?.as_str()?.to_string(),
            ))
        })
        .collect();
    assert_eq!(
        switches,
        [
            (4, "LFFLFF".to_string()),
            // the resumption restores the kinds from the checkpoint: no spurious switch at 6
            (8, "LLFLLF".to_string()),
        ]
    );

    // The student starts as the teacher (same validation) and ends within 1 dB of it.
    let student_psnrs = psnrs(Path::new(&student));
    assert!(
        (student_psnrs[0] - teacher_psnr).abs() < 1e-3,
        "{student_psnrs:?} {teacher_psnr}"
    );
    let student_psnr = *student_psnrs.last().unwrap();

    // The student checkpoint loads (evaluate, infer) with its kinds: Full last of each group.
    let device = BackendKind::Ndarray.device().unwrap();
    let (model, loaded) = load_model(&latest(Path::new(&student)).join(""), &device).unwrap();
    assert_eq!(kinds_letters(&model.attention_kinds()), "LLFLLF");
    assert_eq!(model.attention_kinds(), loaded.distill.final_kinds(6));
    let (_, from_run) = load_model(Path::new(&student), &device).unwrap();
    assert_eq!(from_run.train.steps, 24);

    // The ablations train and evaluate from the same teacher.
    let fully = path("fully_linear");
    distill(&fully, &["--mode", "fully_linear"]);
    let fully_psnr = *psnrs(Path::new(&fully)).last().unwrap();
    let kinds = Checkpoint::read(&latest(Path::new(&fully)))
        .unwrap()
        .attention;
    assert!(kinds.iter().all(|&k| k == AttentionKind::Linear));
    for (mode, want) in [("all_at_once", "LLFLLF"), ("teacher", "FFFFFF")] {
        let out = path(&format!("ablation-{mode}"));
        distill(&out, &["--mode", mode, "--steps", "2"]);
        let checkpoint = Checkpoint::read(&latest(Path::new(&out))).unwrap();
        assert_eq!(kinds_letters(&checkpoint.attention), want, "{mode}");
        assert!(psnrs(Path::new(&out)).last().unwrap().is_finite(), "{mode}");
    }

    eprintln!(
        "PSNR: teacher {teacher_psnr:.3} dB, progressive student {student_psnr:.4} dB, \
         fully linear {fully_psnr:.4} dB"
    );
    assert!(
        (student_psnr - teacher_psnr).abs() < 1.0,
        "student {student_psnr} vs teacher {teacher_psnr}"
    );
    // Its hidden states stay further from the teacher's than the progressive student's.
    assert!(mean_distill(Path::new(&fully)) > mean_distill(Path::new(&student)));
    assert!(
        fully_psnr < student_psnr,
        "fully linear {fully_psnr} vs progressive {student_psnr}"
    );
}
