//! `prism quickstart --fast` end to end through the built binary, on its default backend
//! (flex) and a private cache folder: dataset synthesis, teacher, the real student
//! distillation, both evaluations and the table.

use std::path::{Path, PathBuf};
use std::process::Command;

use prism_train::infer::{PERSON_CENTRE_Y, PERSON_HEIGHT_FRACTION};

fn read_json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn in_range(v: &serde_json::Value, key: &str, lo: f64, hi: f64) {
    let x = v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("{key} missing: {v}"));
    assert!((lo..=hi).contains(&x), "{key} = {x} not in {lo}..={hi}");
}

/// The bounding box height and centre (fractions of the image height) of `alpha > 0.5`.
fn mask_box(path: &Path) -> (f32, f32) {
    let mask = image::open(path).unwrap().to_luma8();
    let rows: Vec<u32> = (0..mask.height())
        .filter(|&y| (0..mask.width()).any(|x| mask.get_pixel(x, y).0[0] > 127))
        .collect();
    let (top, bottom) = (rows[0] as f32, *rows.last().unwrap() as f32 + 1.0);
    let h = mask.height() as f32;
    ((bottom - top) / h, (top + bottom) / 2.0 / h)
}

#[test]
fn quickstart_fast_runs_end_to_end() {
    let dir: PathBuf =
        std::env::temp_dir().join(format!("prism-quickstart-cli-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let out = dir.join("qs");
    let run = Command::new(env!("CARGO_BIN_EXE_prism"))
        .args(["quickstart", "--fast", "--quiet", "--out"])
        .arg(&out)
        .env(prism_train::CACHE_ENV, dir.join("cache"))
        .env_remove("PRISM_LPIPS_WEIGHTS")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(
        stdout.contains("| teacher | 120 |") && stdout.contains("| student | 60 |"),
        "{stdout}"
    );
    for model in ["teacher", "student"] {
        let v = read_json(&out.join(model).join("evaluation/evaluation.json"));
        in_range(&v, "psnr", 3.0, 60.0);
        in_range(&v, "ssim", -1.0, 1.0);
        in_range(&v, "lpips", 0.0, 1.5);
        in_range(&v, "fps", 1e-3, 1e6);
        assert_eq!(v["views_per_subject"], 10);
        assert!(v["subjects"].as_object().is_some_and(|s| !s.is_empty()));
        assert!(
            v["per_angle"]["yaw"].is_array() && v["per_angle"]["pitch"].is_array(),
            "{v}"
        );
        assert!(stdout.contains(&format!("{model} report: ")), "{stdout}");
    }
    // The student is the real distillation: it ends with the tiny schedule's Linear blocks
    // (2 of each group of 3) and logged the switches and L_distill.
    let student = out.join("student");
    let checkpoint = prism_train::latest_checkpoint(&student).unwrap().unwrap();
    let attention = std::fs::read_to_string(checkpoint.join("attention.json")).unwrap();
    assert_eq!(attention.matches("linear").count(), 4, "{attention}");
    let metrics = std::fs::read_to_string(student.join("metrics.jsonl")).unwrap();
    assert!(metrics.contains("\"distill\""), "no L_distill logged");

    // `prism infer` frames photos like these training people: the frontal views' person boxes
    // average PERSON_HEIGHT_FRACTION of the height, centred PERSON_CENTRE_Y down.
    let data = std::fs::read_dir(dir.join("cache/datasets"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let subjects = read_json(&data.join("dataset.json"))["subjects"].clone();
    let boxes: Vec<(f32, f32)> = subjects
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
    let _ = std::fs::remove_dir_all(&dir);
}
