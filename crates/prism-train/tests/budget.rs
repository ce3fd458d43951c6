//! `prism bench budget`'s library call on a shrunken quick start (32 px, a few steps, ndarray):
//! two multiples run as quick starts in their own folders, the table and the plot, a second
//! call keeps the finished multiples, and a call with another plan or config refuses them. The student job here fine-tunes the teacher's
//! weights with the teacher's objective (`prism distill-student` is the real one).

mod common;

use common::{fine_tune_student, shrunken_quickstart};
use prism_train::budget_curve;

#[test]
fn budget_curve_runs_each_multiple_once_and_plots_them() {
    let root = std::env::temp_dir().join(format!("prism-budget-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    // SAFETY: the only test of this binary.
    let (plan, options) = unsafe { shrunken_quickstart(&root, 2, 1, 2) };
    let student = &fine_tune_student;
    let (points, table) = budget_curve(&plan, &[1, 2], &options, student).unwrap();
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
    let (again, _) = budget_curve(&plan, &[1, 2, 3], &options, student).unwrap();
    for (a, p) in again.iter().zip(&points) {
        assert_eq!((a.multiple, a.teacher.steps), (p.multiple, p.teacher.steps));
        // Read back from JSON: equal to the last bit or so.
        assert!((a.student.model.psnr - p.student.model.psnr).abs() < 1e-9);
    }
    assert_eq!(again[2].teacher.steps, 6);
    assert_eq!(std::fs::read(&metrics).unwrap(), before);

    // Another plan (fewer views) or another config: the finished points are not reused, and
    // the refusal names the point and what differs.
    let fewer_views = prism_train::QuickstartPlan {
        eval_views: 1,
        ..plan.clone()
    };
    let mut other_config = plan.clone();
    other_config.config.train.lr_heads *= 2.0;
    for (changed, multiple, what) in [(fewer_views, 1, "plan"), (other_config, 2, "config")] {
        let err = budget_curve(&changed, &[multiple], &options, student)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains(&format!("{multiple}x/point.json"))
                && err.contains(&format!("another {what}")),
            "{err}"
        );
    }
    assert_eq!(std::fs::read(&metrics).unwrap(), before);
    let _ = std::fs::remove_dir_all(&root);
}
