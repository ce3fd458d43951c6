//! `prism quickstart --fast` end to end through the built binary: dataset, teacher, student,
//! both evaluations and the table (flex backend, fewer steps and views than the plan's so the
//! test takes about a minute on 2 cores; no GPU).

use std::process::Command;

#[test]
fn quickstart_fast_runs_end_to_end() {
    let root = std::env::temp_dir().join(format!("prism-quickstart-cli-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let out_dir = root.join("out");
    let out = Command::new(env!("CARGO_BIN_EXE_prism"))
        .args(["quickstart", "--fast", "--quiet", "--backend", "flex"])
        .args([
            "--teacher-steps",
            "4",
            "--student-steps",
            "4",
            "--eval-views",
            "3",
        ])
        .arg("--out")
        .arg(&out_dir)
        .env(prism_train::CACHE_ENV, root.join("cache"))
        .env_remove("PRISM_LPIPS_WEIGHTS")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
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
    }
    let _ = std::fs::remove_dir_all(&root);
}
