//! End-to-end test of `prism ablate` through the built binary (ndarray backend): two rows (the
//! teacher and the progressive student distilled from it) of a 32 px tiny config trained a few
//! steps on a tiny synthetic dataset, the table, its JSON and chart; a second run keeps the
//! finished rows (a student run whose row file was lost is scored again) and adds a new one; a
//! finished row at another budget is refused.

use crate::common;

use std::path::Path;

use prism_train::Ablation;

use common::{cache, failure, prism_with_cache, s, scratch, stdout, success, tiny_at_32px};

fn ablate(
    cache: &Path,
    config: &Path,
    out: &Path,
    rows: &str,
    steps: &str,
) -> std::process::Command {
    let mut cmd = prism_with_cache(
        cache,
        &[
            "ablate",
            "--config",
            s(config),
            "--out",
            s(out),
            "--rows",
            rows,
            "--steps",
            steps,
            "--views",
            "3",
        ],
    );
    cmd.args(["--backend", "ndarray", "--quiet"]);
    cmd
}

fn read_ablation(out: &Path) -> Ablation {
    serde_json::from_str(&std::fs::read_to_string(out.join("ablation.json")).unwrap()).unwrap()
}

#[test]
fn ablate_trains_scores_and_keeps_finished_rows() {
    let config = tiny_at_32px();
    let cache = cache(&config.data);
    let dir = scratch("ablate");
    let config_path = dir.join("tiny.toml");
    std::fs::write(&config_path, config.to_toml()).unwrap();
    let out = dir.join("ablation");

    let first = success(ablate(&cache, &config_path, &out, "progressive", "4"));
    let ablation = read_ablation(&out);
    assert_eq!(
        (
            ablation.teacher_steps,
            ablation.student_steps,
            ablation.views
        ),
        (4, 2, 3)
    );
    let names: Vec<&str> = ablation.rows.iter().map(|r| r.row.as_str()).collect();
    assert_eq!(names, ["teacher", "progressive"]);
    for row in &ablation.rows {
        assert_eq!(row.views, 3);
        for scores in [Some(row.model), row.gs, Some(row.copy_source)] {
            let scores = scores.unwrap();
            assert!(scores.psnr.is_finite() && scores.ssim.is_finite() && scores.lpips.is_finite());
        }
        assert!(row.model_disoccluded.unwrap().psnr.is_finite(), "{row:?}");
        assert!(row.gs_disoccluded.is_some() && row.copy_source_disoccluded.is_some());
        assert!(row.fps > 0.0 && row.seconds_per_step > 0.0, "{row:?}");
        assert!(out.join(&row.row).join("row.json").is_file());
    }
    let (teacher, student) = (&ablation.rows[0], &ablation.rows[1]);
    assert_eq!((teacher.steps, student.steps), (4, 2));
    // The same views: the same baseline; the student trained on from the teacher: other scores.
    assert_eq!(teacher.copy_source, student.copy_source);
    assert_ne!(teacher.model, student.model);
    // The student ends fully stitched: its checkpoint has Linear blocks.
    let attention = std::fs::read_to_string(
        prism_train::latest_checkpoint(&out.join("progressive"))
            .unwrap()
            .unwrap()
            .join("attention.json"),
    )
    .unwrap();
    assert!(attention.contains("\"linear\""), "{attention}");
    let table = std::fs::read_to_string(out.join("ablation.md")).unwrap();
    assert!(
        table.contains("| teacher (full attention) | 4 |"),
        "{table}"
    );
    assert!(
        table.contains("| student, progressive stitching | 2 |"),
        "{table}"
    );
    assert!(table.contains("In the disoccluded region"), "{table}");
    assert!(stdout(&first).contains("| copy source (view 0) |"));
    let chart = image::open(out.join("ablation.png")).unwrap();
    assert_eq!((chart.width(), chart.height()), (1280, 1200));

    // Again with another row: the two finished rows are kept as they are, the new one trained.
    // The student's row file is removed first, as when a job is killed while it scores the row:
    // its finished run is kept (not refused as another config's, not trained again) and scored
    // again.
    let teacher_metrics = std::fs::read(out.join("teacher/metrics.jsonl")).unwrap();
    let student_metrics = std::fs::read(out.join("progressive/metrics.jsonl")).unwrap();
    std::fs::remove_file(out.join("progressive/row.json")).unwrap();
    success(ablate(
        &cache,
        &config_path,
        &out,
        "no_points,progressive",
        "4",
    ));
    let again = read_ablation(&out);
    let names: Vec<&str> = again.rows.iter().map(|r| r.row.as_str()).collect();
    assert_eq!(names, ["teacher", "progressive", "no_points"]);
    assert_eq!(again.rows[0], ablation.rows[0]);
    assert_eq!(again.rows[1].model, ablation.rows[1].model);
    assert_eq!(
        std::fs::read(out.join("teacher/metrics.jsonl")).unwrap(),
        teacher_metrics
    );
    assert_eq!(
        std::fs::read(out.join("progressive/metrics.jsonl")).unwrap(),
        student_metrics
    );
    assert!(again.rows[2].gs.is_some(), "no_points keeps its 3DGS head");

    // Another budget on the same folder is refused, naming the finished row's file and what
    // differs: the plan.
    let err = failure(ablate(&cache, &config_path, &out, "teacher", "6"));
    assert!(
        err.contains("teacher/row.json") && err.contains("another plan"),
        "{err}"
    );
    let err = failure(ablate(&cache, &config_path, &out, "teacher,nope", "4"));
    assert!(err.contains("unknown ablation row \"nope\""), "{err}");
}
