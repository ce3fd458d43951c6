//! `prism bench budget`'s library call on a shrunken quick start (32 px, a few steps, ndarray):
//! two multiples run as quick starts in their own folders, the table and the plot, and a
//! second call keeps the finished multiples. The student job here fine-tunes the teacher's
//! weights with the teacher's objective (`prism distill-student` is the real one).

use std::path::Path;

use prism_core::BackendKind;
use prism_train::{
    PipelineOptions, QuickstartPlan, RunOptions, TeacherTask, TrainingConfig, budget_curve, train,
};

#[test]
fn budget_curve_runs_each_multiple_once_and_plots_them() {
    let root = std::env::temp_dir().join(format!("prism-budget-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    // SAFETY: the only test of this binary; set before anything reads it.
    unsafe { std::env::set_var(prism_synth::CACHE_ENV, root.join("cache")) };
    let mut plan = QuickstartPlan::fast().unwrap();
    plan.config.model.resolution = 32;
    plan.config.losses.lpips = 0.0;
    plan.config.train.validate_every = 0;
    plan.config.train.validation_views = 2;
    plan.config.data.subjects = 3;
    plan.config.data.resolution = 32;
    plan.config.data.test_fraction = 0.34;
    plan.teacher_steps = 2;
    plan.student_steps = 1;
    plan.eval_views = 2;
    let data = prism_synth::ensure_synthetic_dataset(&plan.config.data, false).unwrap();
    let options = PipelineOptions {
        out: root.join("out"),
        data,
        backend: BackendKind::Ndarray,
        lpips_weights: None,
        progress: false,
    };
    let student = |config: &TrainingConfig, teacher: &Path, run: &RunOptions| {
        let run = RunOptions {
            init: Some(teacher.to_path_buf()),
            ..run.clone()
        };
        train(config, &TeacherTask::default(), &run)
    };
    let (points, table) = budget_curve(&plan, &[1, 2], &options, &student).unwrap();
    let steps: Vec<(usize, usize, usize)> = points
        .iter()
        .map(|p| (p.multiple, p.teacher.steps, p.student.steps))
        .collect();
    assert_eq!(steps, [(1, 2, 1), (2, 4, 2)]);
    for p in &points {
        assert!(p.teacher.model.psnr.is_finite() && p.teacher.gs.is_some());
        assert!(p.teacher.model_disoccluded.is_some());
        assert_eq!(p.teacher.copy_source, points[0].student.copy_source);
        assert!(
            root.join(format!("out/{}x/point.json", p.multiple))
                .is_file()
        );
    }
    let md = std::fs::read_to_string(&table).unwrap();
    assert!(md.contains("| 2x | teacher | 4 |"), "{md}");
    assert!(md.contains("| 1x | progressive | 1 |"), "{md}");
    let plot = image::open(root.join("out/budget.png")).unwrap();
    assert_eq!((plot.width(), plot.height()), (1280, 900));

    // Again with a third multiple: the first two are read back, not trained again.
    let metrics = root.join("out/2x/teacher/metrics.jsonl");
    let before = std::fs::read(&metrics).unwrap();
    let (again, _) = budget_curve(&plan, &[1, 2, 3], &options, &student).unwrap();
    for (a, p) in again.iter().zip(&points) {
        assert_eq!((a.multiple, a.teacher.steps), (p.multiple, p.teacher.steps));
        // Read back from JSON: equal to the last bit or so.
        assert!((a.student.model.psnr - p.student.model.psnr).abs() < 1e-9);
    }
    assert_eq!(again[2].teacher.steps, 6);
    assert_eq!(std::fs::read(&metrics).unwrap(), before);
    let _ = std::fs::remove_dir_all(&root);
}
