//! `prism quickstart --fast` end to end through the built binary: dataset, teacher, student,
//! both evaluations, the table and the phase timings (flex backend, fewer steps and views than
//! the plan's so the test takes about a minute on 2 cores; no GPU) and `--resume` on the
//! finished runs; then the framing `prism infer` gives photos is checked against the
//! synthesised people.

use crate::common;

use prism_train::infer::{PERSON_CENTRE_Y, PERSON_HEIGHT_FRACTION};

use common::{output, prism_with_cache, scratch, stderr, stdout, success};

#[test]
fn quickstart_fast_runs_end_to_end() {
    let root = scratch("fast");
    let out_dir = root.join("out");
    // The quick start of 4 + 4 steps into `out_dir`, with `extra` arguments.
    let quickstart = |extra: &[&str]| {
        let mut command = prism_with_cache(
            &root.join("cache"),
            &["quickstart", "--fast", "--quiet", "--backend", "flex"],
        );
        command
            .args(["--teacher-steps", "4", "--eval-views", "3"])
            .arg("--out")
            .arg(&out_dir)
            .args(extra);
        if !extra.contains(&"--student-steps") {
            command.args(["--student-steps", "4"]);
        }
        command
    };
    let out = success(quickstart(&[]));
    let stdout = stdout(&out);
    assert!(stdout.contains("| model | steps | train (s) | PSNR (dB) | SSIM | LPIPS | FPS |"));
    for model in ["teacher", "student"] {
        let row = stdout
            .lines()
            .find(|l| l.starts_with(&format!("| {model} | 4 |")))
            .unwrap_or_else(|| panic!("no {model} row in\n{stdout}"));
        // steps, train seconds, PSNR, SSIM, LPIPS, FPS: all finite numbers.
        let values: Vec<f64> = row
            .split('|')
            .skip(2)
            .filter(|c| !c.trim().is_empty())
            .map(|c| c.trim().parse().unwrap())
            .collect();
        assert_eq!(values.len(), 6, "{row}");
        assert!(values.iter().all(|v| v.is_finite()), "{row}");
        assert!(values[5] > 0.0, "{row}");
        let eval = out_dir.join(model).join("evaluation");
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(eval.join("evaluation.json")).unwrap())
                .unwrap();
        assert_eq!(json["views_per_subject"], 3);
        assert!(eval.join("report.md").is_file());
        assert!(stdout.contains(&format!(
            "{model} report: {}",
            eval.join("report.md").display()
        )));
        // The student's run holds its checkpoint at step 4.
        assert!(
            out_dir
                .join(model)
                .join("checkpoints/step-00000004")
                .is_dir()
        );
        // Its 3DGS head's render I_gs has its row, with the evaluation's scores.
        let gs = row_values(&stdout, &format!("| {model} I_gs (3DGS head) | - | - |"));
        assert_eq!(gs.len(), 3);
        assert!((gs[0] - json["gs"]["psnr"].as_f64().unwrap()).abs() < 1e-3);
        // The run folder has its training curves, drawn (not blank), and the evaluation a copy.
        common::assert_training_curves(&out_dir.join(model).join(prism_train::PLOT_FILE));
        assert!(eval.join("training-curves.png").is_file());
        assert!(stdout.contains(&format!("{model} training curves: ")));
    }
    // The copy-the-source baseline, on the same views as both models.
    let copy = row_values(&stdout, "| copy source (view 0) | - | - |");
    assert_eq!(copy.len(), 3, "{stdout}");
    let teacher_eval: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out_dir.join("teacher/evaluation/evaluation.json")).unwrap(),
    )
    .unwrap();
    assert!((copy[0] - teacher_eval["copy_source"]["psnr"].as_f64().unwrap()).abs() < 1e-3);
    assert!(
        copy.iter().all(|v| v.is_finite()) && copy[0] > 5.0,
        "{copy:?}"
    );
    assert_phase_timings(&stdout, &out_dir.join(prism_train::PHASES_FILE));
    // The student is the real distillation: the tiny schedule compressed to 4 steps ends with
    // 2 of each group of 3 blocks Linear, and L_distill is logged.
    let student = out_dir.join("student/checkpoints/step-00000004");
    let attention = std::fs::read_to_string(student.join("attention.json")).unwrap();
    assert_eq!(attention.matches("linear").count(), 4, "{attention}");
    let metrics = std::fs::read_to_string(out_dir.join("student/metrics.jsonl")).unwrap();
    assert!(metrics.contains("\"distill\""), "no L_distill logged");

    // `--resume` keeps the finished runs (nothing trained again, the same scores), and refuses
    // a student run made with another plan: its distillation schedule compressed to 4 steps
    // switches a block every step, one compressed to 8 every 2.
    let logs = || {
        ["teacher", "student"].map(|model| {
            std::fs::read_to_string(out_dir.join(model).join("metrics.jsonl")).unwrap()
        })
    };
    let trained = logs();
    let resumed = common::stdout(&success(quickstart(&["--resume"])));
    assert_eq!(logs(), trained, "--resume trained a finished run again");
    assert_eq!(
        row_values(&resumed, "| copy source (view 0) | - | - |"),
        copy
    );
    let again: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out_dir.join("teacher/evaluation/evaluation.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(again["psnr"], teacher_eval["psnr"]);
    let refused = output(quickstart(&["--resume", "--student-steps", "8"]));
    assert_eq!(refused.status.code(), Some(1), "{refused:?}");
    let said = stderr(&refused);
    let error = said.trim_end().lines().last().unwrap_or_default();
    assert!(
        error.starts_with("error: ") && error.contains("distill") && !said.contains("panicked"),
        "{said}"
    );
    assert_eq!(logs(), trained, "a refused resume changed a run");

    // `prism infer` frames photos like these training people: their frontal views' person
    // boxes average PERSON_HEIGHT_FRACTION of the height, centred PERSON_CENTRE_Y down.
    let data = std::fs::read_dir(root.join("cache/datasets"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data.join("dataset.json")).unwrap()).unwrap();
    let boxes: Vec<(f32, f32)> = meta["subjects"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| mask_box(&data.join(s.as_str().unwrap()).join("mask/000.png")))
        .collect();
    let n = boxes.len() as f32;
    let height = boxes.iter().map(|b| b.0).sum::<f32>() / n;
    let centre = boxes.iter().map(|b| b.1).sum::<f32>() / n;
    assert!(
        (height - PERSON_HEIGHT_FRACTION).abs() < 0.03,
        "mean person height {height}"
    );
    assert!(
        (centre - PERSON_CENTRE_Y).abs() < 0.02,
        "mean person centre {centre}"
    );
}

/// The phase table is printed with every phase, and its JSON holds non-negative seconds that
/// add up to no more than the wall time (per model, and for the whole quick start), and the
/// run's CPU steal share.
fn assert_phase_timings(stdout: &str, json: &std::path::Path) {
    assert!(
        stdout.contains("| phase | teacher (s) | student (s) | total (s) |"),
        "{stdout}"
    );
    for phase in [
        "dataset (synthesis or cache)",
        "data loading (step waits for the prefetcher)",
        "training steps",
        "validation",
        "- of which LPIPS",
        "checkpoints",
        "evaluation",
        "setup and the rest",
        "wall time",
    ] {
        assert!(
            stdout.contains(&format!("| {phase} | ")),
            "no {phase} row in\n{stdout}"
        );
    }
    let phases: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(json).unwrap()).unwrap();
    let seconds = |v: &serde_json::Value, key: &str| {
        let s = v[key].as_f64().unwrap_or_else(|| panic!("no {key} in {v}"));
        assert!(s >= 0.0, "{key} {s} in {v}");
        s
    };
    let mut covered = seconds(&phases, "dataset_seconds");
    for model in ["teacher", "student"] {
        let m = &phases[model];
        let top = [
            "data_wait",
            "steps",
            "validation",
            "checkpoints",
            "evaluation",
            "other",
        ];
        let sum: f64 = top.iter().map(|k| seconds(m, k)).sum();
        let wall = seconds(m, "wall_seconds");
        assert!(
            sum <= wall + 1e-9,
            "{model}: phases {sum} s > wall {wall} s"
        );
        assert!(
            seconds(m, "steps") > 0.0 && seconds(m, "evaluation") > 0.0,
            "{m}"
        );
        assert!(
            seconds(m, "validation_lpips") <= seconds(m, "validation"),
            "{m}"
        );
        assert!(
            seconds(m, "evaluation_lpips") <= seconds(m, "evaluation"),
            "{m}"
        );
        covered += wall;
    }
    let wall = seconds(&phases, "wall_seconds");
    assert!(
        covered <= wall + 1e-9,
        "{covered} s of phases > {wall} s wall"
    );
    // The hypervisor's share of the CPU time, counted by Linux over the whole run.
    let steal = phases["cpu_steal"].as_f64().expect("steal counted");
    assert!((0.0..=1.0).contains(&steal), "{steal}");
    assert!(stdout.contains(", CPU steal "), "{stdout}");
}

/// The numbers of the table row of `stdout` that starts with `prefix` (its `-` cells skipped).
fn row_values(stdout: &str, prefix: &str) -> Vec<f64> {
    let row = stdout
        .lines()
        .find(|l| l.starts_with(prefix))
        .unwrap_or_else(|| panic!("no row {prefix} in\n{stdout}"));
    row[prefix.len()..]
        .split('|')
        .map(str::trim)
        .filter(|c| !c.is_empty() && *c != "-")
        .map(|c| c.parse().unwrap())
        .collect()
}

/// The bounding box height and centre (fractions of the image height) of `alpha > 0.5`.
fn mask_box(path: &std::path::Path) -> (f32, f32) {
    let mask = image::open(path).unwrap().to_luma8();
    let rows: Vec<u32> = (0..mask.height())
        .filter(|&y| (0..mask.width()).any(|x| mask.get_pixel(x, y).0[0] > 127))
        .collect();
    let (top, bottom) = (rows[0] as f32, *rows.last().unwrap() as f32 + 1.0);
    let h = mask.height() as f32;
    ((bottom - top) / h, (top + bottom) / 2.0 / h)
}
