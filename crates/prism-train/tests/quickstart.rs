//! The quickstart's orchestration on a shrunken plan (32 px, a few steps, ndarray): dataset,
//! teacher, student job, both evaluations, the table and the phase timings. The student job
//! here fine-tunes the teacher's weights with the teacher's objective (`prism distill-student`
//! is the real one). Then the same quickstart killed at several points and run again: it
//! continues.

mod common;

use common::{fine_tune_student, shrunken_quickstart};
use std::path::Path;

use prism_core::phases::Phase;
use prism_train::{list_checkpoints, phase_table, quickstart, quickstart_table};

#[test]
fn quickstart_trains_evaluates_both_models_and_tabulates() {
    let root = std::env::temp_dir().join(format!("prism-quickstart-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    // SAFETY: the only test of this binary.
    let (mut plan, options) = unsafe { shrunken_quickstart(&root, 3, 2, 4) };
    // A checkpoint after every step, two kept: a kill can be simulated by removing the last.
    plan.config.train.checkpoint_every = 1;
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
    // Where the time went: steps and evaluation measured, nothing counted twice.
    for model in [&report.teacher, &report.student] {
        let phases = &model.phases;
        let rows = phases.rows();
        assert!(rows.iter().all(|&(_, _, s)| s >= 0.0), "{rows:?}");
        let steps = rows.iter().find(|r| r.0 == "steps").unwrap().2;
        assert!(steps > 0.0 && phases.evaluation.get(Phase::Evaluation) > 0.0);
        assert!(phases.wall_seconds <= report.wall_seconds);
    }
    let phase_table = phase_table(&report, 0.0);
    assert!(phase_table.contains("| training steps | "), "{phase_table}");

    let (teacher, student) = (root.join("out/teacher"), root.join("out/student"));
    // Run again: both finished runs are kept, not trained again.
    let (teacher_log, student_log) = (metrics(&teacher), metrics(&student));
    let again = quickstart(&plan, &options, &fine_tune_student).unwrap();
    assert_eq!(metrics(&teacher), teacher_log);
    assert_eq!(metrics(&student), student_log);
    assert_eq!(
        again.student.evaluation.psnr,
        report.student.evaluation.psnr
    );

    // Killed after the student's first step: the student continues from it, exactly.
    kill_at_last_but_one(&student);
    let resumed = quickstart(&plan, &options, &fine_tune_student).unwrap();
    let log = metrics(&student);
    assert_eq!(
        log[0], student_log[0],
        "the first step is not trained again"
    );
    assert_ne!(log[1], student_log[1], "the second step is trained again");
    assert_eq!(metrics(&teacher), teacher_log);
    let close = |a: f64, b: f64| (a - b).abs() < 1e-6 * b.abs().max(1.0);
    let student_psnr = report.student.evaluation.psnr;
    assert!(close(resumed.student.evaluation.psnr, student_psnr));

    // Killed during the teacher: it continues, and the student starts over from the new teacher.
    kill_at_last_but_one(&teacher);
    let resumed = quickstart(&plan, &options, &fine_tune_student).unwrap();
    let log = metrics(&teacher);
    assert_eq!(log[..2], teacher_log[..2]);
    assert_ne!(log[2], teacher_log[2]);
    assert_ne!(
        metrics(&student)[0],
        student_log[0],
        "the student is trained again"
    );
    assert!(close(
        resumed.teacher.evaluation.psnr,
        report.teacher.evaluation.psnr
    ));
    assert!(close(resumed.student.evaluation.psnr, student_psnr));

    // Another config on the finished folder is refused, naming the setting, not reused.
    let mut other = plan.clone();
    other.config.train.lr_heads *= 2.0;
    let err = quickstart(&other, &options, &fine_tune_student)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("out/teacher") && err.contains("train.lr_heads") && err.contains("--out"),
        "{err}"
    );
    assert_eq!(metrics(&teacher), log);
    let _ = std::fs::remove_dir_all(&root);
}

/// The lines of a run's metrics log that record training steps.
fn metrics(run: &Path) -> Vec<String> {
    std::fs::read_to_string(run.join(prism_train::METRICS_FILE))
        .unwrap()
        .lines()
        .filter(|line| line.contains("\"seconds\""))
        .map(str::to_owned)
        .collect()
}

/// The run as a kill before its last checkpoint leaves it.
fn kill_at_last_but_one(run: &Path) {
    let (_, last) = list_checkpoints(run).unwrap().pop().unwrap();
    std::fs::remove_dir_all(last).unwrap();
}
