//! The quickstart's orchestration on a shrunken plan (32 px, a few steps, ndarray): dataset,
//! teacher, student job, both evaluations and the table. The student job here fine-tunes the
//! teacher's weights with the teacher's objective (`prism distill-student` is the real one).

mod common;

use common::{fine_tune_student, shrunken_quickstart};
use prism_train::{quickstart, quickstart_table};

#[test]
fn quickstart_trains_evaluates_both_models_and_tabulates() {
    let root = std::env::temp_dir().join(format!("prism-quickstart-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    // SAFETY: the only test of this binary.
    let (plan, options) = unsafe { shrunken_quickstart(&root, 3, 2, 4) };
    let report = quickstart(&plan, &options, &fine_tune_student).unwrap();
    assert_eq!((report.teacher.steps, report.student.steps), (3, 2));
    assert_eq!(report.teacher.run, root.join("out/teacher"));
    for model in [&report.teacher, &report.student] {
        let e = &model.evaluation;
        assert_eq!(e.views_per_subject, 4);
        assert_eq!(e.subjects.len(), 1);
        assert!(e.psnr.is_finite() && e.ssim.is_finite() && e.lpips.is_finite() && e.fps > 0.0);
        assert!(model.files.report.is_file() && model.files.json.is_file());
        assert!(model.files.grids.iter().all(|g| g.is_file()));
    }
    // The student starts from the teacher's weights, then trains on: other scores.
    assert_ne!(
        report.teacher.evaluation.psnr,
        report.student.evaluation.psnr
    );
    // Both are evaluated on the same views: the same copy-the-source baseline.
    assert_eq!(
        report.teacher.evaluation.copy_source,
        report.student.evaluation.copy_source
    );
    let table = quickstart_table(&report);
    assert!(
        table.contains("| teacher | 3 |") && table.contains("| student | 2 |"),
        "{table}"
    );
    let copy = &report.teacher.evaluation.copy_source;
    let copy_row = format!(
        "| copy source (view 0) | - | - | {:.3} | {:.4} | {:.4} | - |",
        copy.psnr, copy.ssim, copy.lpips
    );
    assert!(table.contains(&copy_row), "{table}");
    assert!(
        table.contains("| teacher I_gs (3DGS head) | - | - |")
            && table.contains("| student I_gs (3DGS head) | - | - |"),
        "{table}"
    );
    assert!(table.contains("student report: "), "{table}");
    let _ = std::fs::remove_dir_all(&root);
}
