//! End-to-end tests of `prism evaluate` and `prism infer` through the built binary (ndarray
//! backend), with a tiny teacher trained for a few steps on a tiny synthetic dataset in a
//! private cache folder.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use prism_train::{RunOptions, TeacherTask, TrainingConfig, train};

use common::{failure, prism_with_cache, s, scratch, stderr, success, tiny_at_32px};

/// The tests' tiny config (32 px, 4 subjects) trained 4 steps.
fn tiny_config() -> TrainingConfig {
    let mut c = tiny_at_32px();
    c.train.steps = 4;
    c.train.checkpoint_every = 4;
    c
}

/// The cache folder (the tiny dataset) and the run folder of a tiny teacher trained 4 steps,
/// made once per test process.
fn trained() -> &'static (PathBuf, PathBuf) {
    static RUN: OnceLock<(PathBuf, PathBuf)> = OnceLock::new();
    RUN.get_or_init(|| {
        let cache = scratch("cache").keep();
        let run = scratch("run").keep();
        let data =
            prism_synth::ensure_synthetic_dataset_in(&cache, &tiny_config().data, false).unwrap();
        let options = RunOptions::new(&run, data, prism_core::BackendKind::Ndarray);
        train(
            &tiny_config(),
            &TeacherTask {
                lpips_weights: None,
            },
            &options,
        )
        .unwrap();
        (cache, run)
    })
}

/// `prism ARGS --backend ndarray --quiet` with the tiny teacher's cache folder, not yet run.
fn prism(args: &[&str]) -> Command {
    let (cache, _) = trained();
    let mut cmd = prism_with_cache(cache, args);
    cmd.args(["--backend", "ndarray", "--quiet"]);
    cmd
}

fn read_json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// The folder of the tiny synthetic dataset in the test's cache.
fn dataset_dir(cache: &Path) -> PathBuf {
    std::fs::read_dir(cache.join("datasets"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path()
}

/// The per-angle bins of a method: lower bounds and the number of views they hold.
fn bins(v: &serde_json::Value, axis: &str) -> Vec<(f64, u64)> {
    v["per_angle"][axis]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| {
            (
                b["from_deg"].as_f64().unwrap(),
                b["views"].as_u64().unwrap(),
            )
        })
        .collect()
}

fn assert_scores_in_range(v: &serde_json::Value) {
    let psnr = v["psnr"].as_f64().unwrap();
    let ssim = v["ssim"].as_f64().unwrap();
    let lpips = v["lpips"].as_f64().unwrap();
    assert!(psnr > 3.0 && psnr < 60.0, "{v}");
    assert!(ssim > -1.0 && ssim <= 1.0, "{v}");
    assert!(lpips > 0.0 && lpips < 1.5, "{v}");
}

#[test]
fn evaluate_writes_every_key_the_report_and_the_grids() {
    let (cache, run_dir) = trained();
    let dir = scratch("evaluate");
    let json = dir.join("scores.json");
    let out = dir.join("eval");
    success(prism(&[
        "evaluate",
        "--checkpoint",
        s(run_dir),
        "--json",
        s(&json),
        "--out",
        s(&out),
        "--oracle",
    ]));
    let v = read_json(&json);
    assert_eq!(v, read_json(&out.join("evaluation.json")));
    assert_scores_in_range(&v);
    assert!(v["fps"].as_f64().unwrap() > 0.0);
    assert_eq!(v["views_per_subject"], 100);
    // One held-out subject of 4, with its 100 views.
    let subjects = v["subjects"].as_object().unwrap();
    assert_eq!(subjects.len(), 1);
    let (name, subject) = subjects.iter().next().unwrap();
    assert_eq!(subject["views"], 100);
    assert_scores_in_range(subject);
    // With one subject, the means are that subject's.
    assert_eq!(subject["psnr"], v["psnr"]);
    // Angle bins: 0-10, 10-20, 20-30 of |yaw| and |pitch|, together the 100 views.
    for axis in ["yaw", "pitch"] {
        let bins = v["per_angle"][axis].as_array().unwrap();
        let from: Vec<f64> = bins
            .iter()
            .map(|b| b["from_deg"].as_f64().unwrap())
            .collect();
        assert_eq!(from, vec![0.0, 10.0, 20.0], "{axis}");
        let views: u64 = bins.iter().map(|b| b["views"].as_u64().unwrap()).sum();
        assert_eq!(views, 100);
        bins.iter().for_each(assert_scores_in_range);
    }

    // The copy-the-source baseline, in the model's structure, on the same views: its PSNR is
    // the mean over views 1..=100 of the PSNR of view 0 against each, computed here from the
    // dataset's PNGs.
    let copy = &v["copy_source"];
    assert_scores_in_range(copy);
    assert_eq!(copy["subjects"][name]["views"], 100);
    assert_eq!(copy["subjects"][name]["psnr"], copy["psnr"]);
    for axis in ["yaw", "pitch"] {
        assert_eq!(bins(copy, axis), bins(&v, axis), "{axis}");
    }
    let subject_dir = dataset_dir(cache).join(name);
    let rgb = |view: usize| {
        image::open(subject_dir.join(format!("rgb/{view:03}.png")))
            .unwrap()
            .to_rgb8()
    };
    let source = rgb(0);
    let expected = (1..=100)
        .map(|t| common::psnr_8bit(&source, &rgb(t)))
        .sum::<f64>()
        / 100.0;
    let got = copy["psnr"].as_f64().unwrap();
    assert!(
        (got - expected).abs() < 1e-3,
        "copy source PSNR {got} vs {expected}"
    );
    // The source is not the target: SSIM below 1, LPIPS above 0.
    assert!(copy["ssim"].as_f64().unwrap() < 0.99, "{copy}");

    // The tiny teacher has a 3DGS head: I_gs is scored on the same views.
    let gs = &v["gs"];
    for key in ["psnr", "ssim", "lpips"] {
        assert!(gs[key].as_f64().unwrap().is_finite(), "{gs}");
    }
    assert_ne!(gs["psnr"], v["psnr"]);
    // Every method is also scored in the disoccluded region, found by the depth test on the
    // dataset's depth maps; the copy of the source scores worse there than overall (those are
    // the pixels it cannot explain).
    for method in [&v, copy, gs] {
        for key in ["psnr_disoccluded", "ssim_disoccluded", "lpips_disoccluded"] {
            assert!(method[key].as_f64().unwrap().is_finite(), "{key}: {method}");
        }
    }
    assert!(
        copy["psnr_disoccluded"].as_f64().unwrap() < copy["psnr"].as_f64().unwrap(),
        "{copy}"
    );
    // Filling the region from the ground truth removes error and nothing else; the copy of
    // the source has all of its region wrong, so it gains.
    for method in [&v, gs] {
        let (filled, psnr) = (
            method["psnr_region_filled"].as_f64().unwrap(),
            method["psnr"].as_f64().unwrap(),
        );
        assert!(filled >= psnr, "{method}");
    }
    assert!(
        copy["psnr_region_filled"].as_f64().unwrap() > copy["psnr"].as_f64().unwrap() + 0.01,
        "{copy}"
    );
    // The source warped at the true depth beats copying it: the target views are other
    // viewpoints of the same surface.
    let warp = &v["true_depth_warp"];
    assert!(
        warp["psnr"].as_f64().unwrap() > copy["psnr"].as_f64().unwrap() + 0.2,
        "{warp} vs {copy}"
    );
    assert!(
        warp["psnr_disoccluded"].as_f64().unwrap().is_finite(),
        "{warp}"
    );
    // The warp is a baseline swept over its Gaussians' size on training subjects: the one
    // scored on the test views is the best there.
    let sweep = v["true_depth_warp_sweep"].as_array().unwrap();
    let footprints: Vec<f64> = sweep
        .iter()
        .map(|f| f["footprint"].as_f64().unwrap())
        .collect();
    assert_eq!(footprints.len(), 4);
    let best = sweep
        .iter()
        .max_by(|a, b| {
            a["psnr"]
                .as_f64()
                .unwrap()
                .total_cmp(&b["psnr"].as_f64().unwrap())
        })
        .unwrap();
    assert_eq!(best["footprint"], v["true_depth_warp_footprint"]);
    assert_ne!(
        best["psnr"], warp["psnr"],
        "not scored on the test views: {sweep:?}"
    );
    assert!(
        sweep.iter().any(|f| f["psnr"] != best["psnr"]),
        "the footprint changes the warp: {sweep:?}"
    );
    assert_eq!(gs["subjects"][name]["views"], 100);
    for axis in ["yaw", "pitch"] {
        assert_eq!(bins(gs, axis), bins(&v, axis), "{axis}");
    }

    // Speckle: every method scored against the truth's smooth pixels; the copy of another
    // view, with its edges in the wrong places, is noisier there than the truth.
    let speckle = &v["speckle"];
    assert!(
        speckle["truth_laplacian"].as_f64().unwrap() > 0.0,
        "{speckle}"
    );
    for key in ["model", "gs", "true_depth_warp"] {
        assert!(speckle[key].as_f64().unwrap() > 0.0, "{key}: {speckle}");
    }
    assert!(speckle["copy_source"].as_f64().unwrap() > 1.0, "{speckle}");

    // The oracle swaps: the model's own Gaussians drawn again are its I_gs (and I_t), and all
    // four properties from the truth draw the true-depth warp.
    let oracle = v["oracle"].as_array().unwrap();
    let swaps: Vec<&str> = oracle.iter().map(|r| r["swap"].as_str().unwrap()).collect();
    assert_eq!(
        swaps,
        [
            "none",
            "depth",
            "half_depth",
            "quarter_depth",
            "unbiased",
            "colour",
            "opacity",
            "scale",
            "all",
            "all_but_colour"
        ]
    );
    let psnr = |m: &serde_json::Value| m["psnr"].as_f64().unwrap();
    assert!(
        (psnr(&oracle[0]["gs"]) - psnr(gs)).abs() < 1e-4,
        "{:?}",
        oracle[0]
    );
    assert!(
        (psnr(&oracle[0]["nvs"]) - psnr(&v)).abs() < 1e-4,
        "{:?}",
        oracle[0]
    );
    assert!(
        (psnr(&oracle[8]["gs"]) - psnr(warp)).abs() < 0.1,
        "{:?}",
        oracle[8]
    );
    for row in oracle {
        assert!(row["gs"]["psnr_disoccluded"].as_f64().unwrap().is_finite());
        assert!(row["nvs_speckle"].as_f64().unwrap() > 0.0);
    }
    // The Gaussians' depth error: a trained tiny model is centimetres off, not metres.
    let depth = &v["depth_error"];
    let (mean, median, p90) = (
        depth["mean"].as_f64().unwrap(),
        depth["median"].as_f64().unwrap(),
        depth["p90"].as_f64().unwrap(),
    );
    assert!(mean > 0.0 && mean < 0.5, "depth error {depth}");
    assert!(median <= p90 && depth["bias"].as_f64().unwrap().abs() <= mean);

    assert_eq!(v["disoccluded_by"], "depth_test");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("| PSNR (dB) | SSIM | LPIPS | FPS (1 pair) |"));
    for words in [
        "tested against the source's depth map",
        "## Speckle",
        "## Oracle swaps",
        "| all but colour (warp, model's colours) |",
        "from the dataset's points on average over the source foreground",
        "the most that a better guess of what the source does not see can add",
    ] {
        assert!(report.contains(words), "{words}: {report}");
    }
    for row in [
        "| model (NVS decoder I_t) |",
        "| model's 3DGS head (I_gs) |",
    ] {
        assert!(report.contains(row), "{row}: {report}");
    }
    let copy_row = format!(
        "| copy source (view 0) | {:.3} | {:.4} | {:.4} | - |",
        got,
        copy["ssim"].as_f64().unwrap(),
        copy["lpips"].as_f64().unwrap()
    );
    assert!(report.contains(&copy_row), "{copy_row}: {report}");
    assert!(report.contains(&format!("grids/{name}.png")));
    // The run's training curves, beside the report.
    assert!(
        report.contains("![training curves](training-curves.png)"),
        "{report}"
    );
    let curves = image::open(out.join("training-curves.png")).unwrap();
    let (w, h) = prism_train::PLOT_SIZE;
    assert_eq!((curves.width(), curves.height()), (w, h));
    // 4 rows of source | prediction | ground truth | error map, 32 px each.
    let grid = image::open(out.join("grids").join(format!("{name}.png"))).unwrap();
    assert_eq!((grid.width(), grid.height()), (4 * 32, 4 * 32));
}

#[test]
fn a_dataset_without_depth_maps_gets_the_estimated_region_and_the_report_says_so() {
    let (cache, run_dir) = trained();
    let dir = scratch("no-depth");
    let data = dir.join("data");
    common::copy_dir(&dataset_dir(cache), &data);
    // A dataset written before views stored their depth.
    for subject in std::fs::read_dir(&data).unwrap() {
        let depth = subject.unwrap().path().join("depth");
        if depth.is_dir() {
            std::fs::remove_dir_all(depth).unwrap();
        }
    }
    let out = dir.join("eval");
    success(prism(&[
        "evaluate",
        "--checkpoint",
        s(run_dir),
        "--data",
        s(&data),
        "--views",
        "4",
        "--out",
        s(&out),
    ]));
    let v = read_json(&out.join("evaluation.json"));
    assert_eq!(v["disoccluded_by"], "estimate");
    assert!(v["psnr_disoccluded"].as_f64().unwrap().is_finite(), "{v}");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    for words in ["this dataset stores no depth maps", "not a bound"] {
        assert!(report.contains(words), "{words}: {report}");
    }
}

#[test]
fn evaluate_pred_gt_reproduces_the_reference_metrics() {
    let reference =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("crates/prism-losses/tests/reference");
    let dir = scratch("pred-gt");
    let (pred, gt) = (dir.join("pred"), dir.join("gt"));
    std::fs::create_dir_all(&pred).unwrap();
    std::fs::create_dir_all(&gt).unwrap();
    for name in ["astronaut_noise", "coffee_tint"] {
        let file = format!("{name}.png");
        std::fs::copy(reference.join(format!("{name}_pred.png")), pred.join(&file)).unwrap();
        std::fs::copy(reference.join(format!("{name}_target.png")), gt.join(&file)).unwrap();
    }
    let json = dir.join("scores.json");
    success(prism(&[
        "evaluate",
        "--pred",
        s(&pred),
        "--gt",
        s(&gt),
        "--json",
        s(&json),
    ]));
    let v = read_json(&json);
    let expected = read_json(&reference.join("reference.json"));
    let mut means = [0.0; 3];
    for name in ["astronaut_noise", "coffee_tint"] {
        let got = &v["images"][format!("{name}.png")];
        let want = &expected[name];
        for (k, (key, want_key, tol)) in [
            ("psnr", "psnr", 1e-6),
            ("ssim", "ssim", 1e-4),
            ("lpips", "lpips_alex", 1e-3),
        ]
        .into_iter()
        .enumerate()
        {
            let (g, w) = (got[key].as_f64().unwrap(), want[want_key].as_f64().unwrap());
            assert!((g - w).abs() < tol, "{name} {key}: {g} vs {w}");
            means[k] += w / 2.0;
        }
    }
    assert!((v["mean"]["psnr"].as_f64().unwrap() - means[0]).abs() < 1e-6);
    assert!((v["mean"]["lpips"].as_f64().unwrap() - means[2]).abs() < 1e-3);
}

#[test]
fn infer_writes_the_sweep_a_gif_and_the_gaussians() {
    let (cache, run_dir) = trained();
    let subject = std::fs::read_dir(cache.join("datasets"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path()
        .join("subject_0003");
    let dir = scratch("infer");
    let out = dir.join("views");
    let ply = dir.join("person.ply");
    success(prism(&[
        "infer",
        "--checkpoint",
        s(run_dir),
        "--image",
        s(&subject.join("rgb/000.png")),
        "--mask",
        s(&subject.join("mask/000.png")),
        "--out",
        s(&out),
        "--sweep",
        "yaw",
        "--step",
        "15",
        "--export-ply",
        s(&ply),
    ]));
    let mut names: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    let expected = [
        "input.png",
        "sweep.gif",
        "view_000_yaw-30_pitch+00.png",
        "view_001_yaw-15_pitch+00.png",
        "view_002_yaw+00_pitch+00.png",
        "view_003_yaw+15_pitch+00.png",
        "view_004_yaw+30_pitch+00.png",
    ];
    assert_eq!(names, expected);
    let view = image::open(out.join(expected[2])).unwrap();
    assert_eq!((view.width(), view.height()), (32, 32));
    use image::AnimationDecoder;
    let gif = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(
        std::fs::File::open(out.join("sweep.gif")).unwrap(),
    ))
    .unwrap();
    let frames = gif.into_frames().collect_frames().unwrap();
    assert_eq!(frames.len(), 5);
    // The GIF's frames are the PNGs (up to the GIF palette).
    let png = image::open(out.join(expected[6])).unwrap().to_rgb8();
    let last = frames[4].buffer();
    let diff: f64 = png
        .pixels()
        .zip(last.pixels())
        .map(|(a, b)| {
            (0..3)
                .map(|c| (a[c] as f64 - b[c] as f64).abs())
                .sum::<f64>()
        })
        .sum::<f64>()
        / (32.0 * 32.0 * 3.0);
    assert!(diff < 12.0, "mean difference {diff}");
    // A precision the backend does not compute in is refused before anything is written.
    let refused = dir.join("refused");
    let err = failure(prism(&[
        "infer",
        "--checkpoint",
        s(run_dir),
        "--image",
        s(&subject.join("rgb/000.png")),
        "--out",
        s(&refused),
        "--precision",
        "bf16",
    ]));
    assert!(
        err.contains("ndarray backend cannot compute in bf16"),
        "{err}"
    );
    assert!(!refused.exists());
    // A standard 3DGS PLY: one Gaussian per source pixel.
    let bytes = std::fs::read(&ply).unwrap();
    let header = String::from_utf8_lossy(&bytes[..bytes.len().min(600)]).to_string();
    assert!(header.starts_with("ply\n"), "{header}");
    assert!(header.contains("element vertex 1024"), "{header}");

    // A folder of frames: one subfolder per frame.
    let frames_dir = dir.join("video");
    std::fs::create_dir_all(&frames_dir).unwrap();
    for k in 0..2 {
        std::fs::copy(
            subject.join(format!("rgb/00{k}.png")),
            frames_dir.join(format!("frame{k}.png")),
        )
        .unwrap();
    }
    let video_out = dir.join("video-views");
    let output = success(prism(&[
        "infer",
        "--checkpoint",
        s(run_dir),
        "--image",
        s(&frames_dir),
        "--out",
        s(&video_out),
        "--sweep",
        "pitch",
        "--step",
        "30",
    ]));
    // No mask and no alpha: a warning per frame.
    assert!(stderr(&output).contains("warning"));
    for k in 0..2 {
        let frame = video_out.join(format!("frame{k}"));
        assert!(frame.join("sweep.gif").is_file());
        assert!(frame.join("view_002_yaw+00_pitch+30.png").is_file());
    }
}

#[test]
fn bad_input_is_one_clear_line() {
    let (cache, run_dir) = trained();
    let dir = scratch("bad");
    let not_an_image = dir.join("photo.png");
    std::fs::write(&not_an_image, b"not a png").unwrap();
    let err = failure(prism(&[
        "infer",
        "--checkpoint",
        s(run_dir),
        "--image",
        s(&not_an_image),
        "--out",
        s(&dir.join("o")),
    ]));
    assert!(
        err.contains("photo.png") && err.contains("not a readable image"),
        "{err}"
    );

    let subject = std::fs::read_dir(cache.join("datasets"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path()
        .join("subject_0003");
    let small_mask = dir.join("mask.png");
    image::GrayImage::new(8, 8).save(&small_mask).unwrap();
    let err = failure(prism(&[
        "infer",
        "--checkpoint",
        s(run_dir),
        "--image",
        s(&subject.join("rgb/000.png")),
        "--mask",
        s(&small_mask),
        "--out",
        s(&dir.join("o")),
    ]));
    assert!(err.contains("the mask is 8x8"), "{err}");

    let err = failure(prism(&[
        "evaluate",
        "--checkpoint",
        s(&dir.join("no-such-run")),
    ]));
    assert!(err.contains("no-such-run"), "{err}");

    // Images of different sizes.
    let (pred, gt) = (dir.join("a.png"), dir.join("b.png"));
    image::RgbImage::new(40, 40).save(&pred).unwrap();
    image::RgbImage::new(48, 40).save(&gt).unwrap();
    let err = failure(prism(&["evaluate", "--pred", s(&pred), "--gt", s(&gt)]));
    assert!(err.contains("a.png"), "{err}");
}

/// A checkpoint whose config.toml is not the one its weights were trained with, and a PLY
/// export from a model built without the 3DGS head: one clear line each, nothing written.
#[test]
fn another_config_and_a_missing_3dgs_head_are_one_clear_line() {
    let (_, run_dir) = trained();
    let dir = scratch("config");
    // Copy the checkpoint, then give it a config of another width.
    let checkpoint = prism_train::latest_checkpoint(run_dir).unwrap().unwrap();
    let other = dir.join("other-config");
    std::fs::create_dir_all(&other).unwrap();
    for entry in std::fs::read_dir(&checkpoint).unwrap() {
        let entry = entry.unwrap();
        std::fs::copy(entry.path(), other.join(entry.file_name())).unwrap();
    }
    let mut config = tiny_config();
    config.model.width = 32;
    std::fs::write(other.join("config.toml"), config.to_toml()).unwrap();
    let err = failure(prism(&["evaluate", "--checkpoint", s(&other)]));
    assert!(err.contains("other-config"), "{err}");
    let photo = dir.join("photo.png");
    image::RgbImage::from_pixel(32, 32, image::Rgb([200, 10, 10]))
        .save(&photo)
        .unwrap();
    let err = failure(prism(&[
        "infer",
        "--checkpoint",
        s(&other),
        "--image",
        s(&photo),
        "--out",
        s(&dir.join("o")),
    ]));
    assert!(err.contains("other-config"), "{err}");

    // A one-step teacher without the 3DGS head.
    let mut no_gs = tiny_config();
    no_gs.model.gs_head = false;
    // tiny.toml's NVS decoder corrects the 3DGS render: without the head, the paper's decoder.
    no_gs.model.nvs_output = prism_model::NvsOutput::Direct;
    no_gs.losses.gs = 0.0;
    no_gs.train.steps = 1;
    no_gs.train.checkpoint_every = 1;
    let no_gs_run = dir.join("no-gs");
    let cache = &trained().0;
    train(
        &no_gs,
        &TeacherTask {
            lpips_weights: None,
        },
        &RunOptions::new(
            &no_gs_run,
            prism_synth::ensure_synthetic_dataset_in(cache, &no_gs.data, false).unwrap(),
            prism_core::BackendKind::Ndarray,
        ),
    )
    .unwrap();
    let ply = dir.join("person.ply");
    let err = failure(prism(&[
        "infer",
        "--checkpoint",
        s(&no_gs_run),
        "--image",
        s(&photo),
        "--out",
        s(&dir.join("views")),
        "--export-ply",
        s(&ply),
    ]));
    assert!(err.contains("3DGS head"), "{err}");
    assert!(!ply.exists());

    // Its evaluation has no `gs` entry, and its copy-source baseline on the 2 validation views
    // is the one training validation logged.
    let json = dir.join("no-gs.json");
    let out = dir.join("no-gs-eval");
    success(prism(&[
        "evaluate",
        "--checkpoint",
        s(&no_gs_run),
        "--views",
        "2",
        "--json",
        s(&json),
        "--out",
        s(&out),
    ]));
    let v = read_json(&json);
    assert!(v.get("gs").is_none(), "{v}");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(!report.contains("I_gs"), "{report}");
    let logged = prism_train::read_metrics(&no_gs_run.join("metrics.jsonl"))
        .unwrap()
        .into_iter()
        .find(|l| l.get("copy_source_psnr").is_some())
        .unwrap();
    for key in ["psnr", "ssim", "lpips"] {
        let (got, want) = (
            v["copy_source"][key].as_f64().unwrap(),
            logged[format!("copy_source_{key}")].as_f64().unwrap(),
        );
        assert!((got - want).abs() < 1e-6, "{key}: {got} vs {want}");
    }
}
