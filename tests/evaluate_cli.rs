//! End-to-end tests of `prism evaluate`, `prism infer` and `prism quickstart --fast` through the
//! built binary, on a tiny teacher trained on a tiny synthetic dataset in a private cache
//! folder (ndarray backend, except the quick start which runs on its default, flex).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

use image::AnimationDecoder;
use prism_train::{TrainingConfig, configs_dir, ensure_synthetic_dataset};

fn scratch(test: &str) -> PathBuf {
    let dir =
        std::env::temp_dir().join(format!("prism-evaluate-cli-{}-{test}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// configs/tiny.toml at 32 px without LPIPS in the loss, 4 subjects of 32 px (1 held out).
fn tiny_config(gs_head: bool) -> TrainingConfig {
    let mut c = TrainingConfig::load(configs_dir().join("tiny.toml")).unwrap();
    c.model.resolution = 32;
    c.model.gs_head = gs_head;
    c.losses.lpips = 0.0;
    if !gs_head {
        c.losses.gs = 0.0;
    }
    c.train.steps = 10;
    c.train.checkpoint_every = 10;
    c.train.validate_every = 0;
    c.train.validation_views = 2;
    c.data.subjects = 4;
    c.data.resolution = 32;
    c.data.test_fraction = 0.25;
    c
}

/// A trained tiny teacher, its dataset and the cache folder, shared by the tests.
struct Fixture {
    cache: PathBuf,
    data: PathBuf,
    run: PathBuf,
    run_without_gs: PathBuf,
}

fn fixture() -> &'static Fixture {
    static FIXTURE: OnceLock<Fixture> = OnceLock::new();
    FIXTURE.get_or_init(|| {
        let dir = scratch("fixture");
        let cache = dir.join("cache");
        // SAFETY: set once, before any child process is spawned or the variable is read.
        unsafe { std::env::set_var(prism_train::CACHE_ENV, &cache) };
        let data = ensure_synthetic_dataset(&tiny_config(true).data, false).unwrap();
        let mut runs = Vec::new();
        for gs_head in [true, false] {
            let name = if gs_head { "teacher" } else { "teacher-no-gs" };
            let config = dir.join(format!("{name}.toml"));
            std::fs::write(&config, tiny_config(gs_head).to_toml()).unwrap();
            let run = dir.join(name);
            ok(prism(
                &cache,
                &["train-teacher", "--config", s(&config), "--out", s(&run)],
                true,
            ));
            runs.push(run);
        }
        Fixture {
            cache,
            data,
            run: runs[0].clone(),
            run_without_gs: runs[1].clone(),
        }
    })
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn prism(cache: &Path, args: &[&str], ndarray: bool) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_prism"));
    cmd.args(args)
        .env(prism_train::CACHE_ENV, cache)
        .env_remove("PRISM_LPIPS_WEIGHTS");
    if ndarray {
        cmd.args(["--backend", "ndarray", "--quiet"]);
    }
    cmd.output().unwrap()
}

fn ok(out: Output) -> Output {
    assert!(
        out.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// A failing command's one-line error (exit status 1, no panic).
fn failure(out: Output) -> String {
    let err = String::from_utf8(out.stderr).unwrap();
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.starts_with("error: "), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(
        err.trim_end().lines().count(),
        1,
        "one line expected: {err}"
    );
    err
}

/// The bounding box (x0, y0, x1, y1), ends exclusive, of the pixels that are not the white
/// background.
fn person_box(image: &image::RgbImage) -> (u32, u32, u32, u32) {
    let (mut x0, mut y0, mut x1, mut y1) = (u32::MAX, u32::MAX, 0, 0);
    for (x, y, p) in image.enumerate_pixels() {
        if p.0.iter().any(|&c| c < 200) {
            (x0, y0) = (x0.min(x), y0.min(y));
            (x1, y1) = (x1.max(x + 1), y1.max(y + 1));
        }
    }
    (x0, y0, x1, y1)
}

fn read_json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn in_range(v: &serde_json::Value, key: &str, lo: f64, hi: f64) -> f64 {
    let x = v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("{key} missing: {v}"));
    assert!((lo..=hi).contains(&x), "{key} = {x} not in {lo}..={hi}");
    x
}

#[test]
fn evaluate_a_checkpoint_writes_every_key_in_range() {
    let f = fixture();
    let dir = scratch("checkpoint");
    let (json, out) = (dir.join("result.json"), dir.join("eval"));
    ok(prism(
        &f.cache,
        &[
            "evaluate",
            "--checkpoint",
            s(&f.run),
            "--data",
            s(&f.data),
            "--json",
            s(&json),
            "--out",
            s(&out),
            "--views",
            "20",
        ],
        true,
    ));
    let v = read_json(&json);
    assert_eq!(v, read_json(&out.join("evaluation.json")));
    let psnr = in_range(&v, "psnr", 3.0, 60.0);
    in_range(&v, "ssim", -1.0, 1.0);
    in_range(&v, "lpips", 0.0, 1.5);
    in_range(&v, "fps", 1e-3, 1e6);
    let subjects = v["subjects"].as_object().unwrap();
    assert_eq!(subjects.len(), 1, "one held-out subject");
    let (name, subject) = subjects.iter().next().unwrap();
    assert_eq!(subject["views"], 20);
    // One subject: the mean over subjects is that subject's mean.
    assert!((in_range(subject, "psnr", 3.0, 60.0) - psnr).abs() < 1e-9);
    let grid = out.join(subject["grid"].as_str().unwrap());
    let image = image::open(&grid).unwrap();
    // 4 views x (source, prediction, ground truth, error map) of 32 px.
    assert_eq!((image.width(), image.height()), (4 * 32, 4 * 32));
    for axis in ["yaw", "pitch"] {
        let bins = v["per_angle"][axis].as_array().unwrap();
        assert_eq!(bins.len(), 3, "0-10, 10-20, 20-30 degrees");
        let views: u64 = bins.iter().map(|b| b["views"].as_u64().unwrap()).sum();
        assert_eq!(views, 20);
        for b in bins.iter().filter(|b| b["views"].as_u64().unwrap() > 0) {
            in_range(b, "psnr", 3.0, 60.0);
            in_range(b, "ssim", -1.0, 1.0);
            in_range(b, "lpips", 0.0, 1.5);
        }
    }
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(
        report.contains(name) && report.contains("By |yaw|"),
        "{report}"
    );
}

/// `--pred/--gt` reproduces the independent reference values of the shared metric set.
#[test]
fn evaluate_pred_gt_reproduces_the_reference_metrics() {
    let f = fixture();
    let reference =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("crates/prism-losses/tests/reference");
    let dir = scratch("pred-gt");
    let (pred, gt) = (dir.join("pred"), dir.join("gt"));
    std::fs::create_dir_all(&pred).unwrap();
    std::fs::create_dir_all(&gt).unwrap();
    let names = ["astronaut_noise", "coffee_tint"];
    for name in names {
        std::fs::copy(
            reference.join(format!("{name}_pred.png")),
            pred.join(format!("{name}.png")),
        )
        .unwrap();
        std::fs::copy(
            reference.join(format!("{name}_target.png")),
            gt.join(format!("{name}.png")),
        )
        .unwrap();
    }
    let json = dir.join("scores.json");
    ok(prism(
        &f.cache,
        &[
            "evaluate",
            "--pred",
            s(&pred),
            "--gt",
            s(&gt),
            "--json",
            s(&json),
        ],
        false,
    ));
    let v = read_json(&json);
    let expected = read_json(&reference.join("reference.json"));
    let mut sums = [0.0; 3];
    for name in names {
        let got = &v["images"][format!("{name}.png")];
        let want = &expected[name];
        for (k, (key, tol)) in [("psnr", 1e-6), ("ssim", 1e-4), ("lpips_alex", 1e-3)]
            .into_iter()
            .enumerate()
        {
            let got = got[key.trim_end_matches("_alex")].as_f64().unwrap();
            let want = want[key].as_f64().unwrap();
            assert!((got - want).abs() < tol, "{name} {key}: {got} vs {want}");
            sums[k] += got / 2.0;
        }
    }
    for (k, key) in ["psnr", "ssim", "lpips"].into_iter().enumerate() {
        assert!(
            (v["mean"][key].as_f64().unwrap() - sums[k]).abs() < 1e-9,
            "{v}"
        );
    }
}

/// `prism infer` on a held-out subject's frontal view (with its mask): the frames of the sweep,
/// a GIF holding them all, a grid sweep, and the 3DGS head's Gaussians as a PLY.
#[test]
fn infer_writes_the_sweep_frames_a_gif_and_a_ply() {
    let f = fixture();
    let dir = scratch("infer");
    let meta = read_json(&f.data.join("dataset.json"));
    let subject = f.data.join(meta["split"]["test"][0].as_str().unwrap());
    let (photo, mask) = (subject.join("rgb/000.png"), subject.join("mask/000.png"));
    let out = dir.join("yaw");
    let ply = dir.join("person.ply");
    let stdout = ok(prism(
        &f.cache,
        &[
            "infer",
            "--checkpoint",
            s(&f.run),
            "--image",
            s(&photo),
            "--mask",
            s(&mask),
            "--out",
            s(&out),
            "--step",
            "10",
            "--export-ply",
            s(&ply),
        ],
        true,
    ))
    .stdout;
    assert!(String::from_utf8_lossy(&stdout).contains("7 views"));
    let mut frames: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .filter(|n| n.contains("_yaw"))
        .collect();
    frames.sort();
    let expected: Vec<String> = [-30, -20, -10, 0, 10, 20, 30]
        .iter()
        .enumerate()
        .map(|(i, y)| format!("{i:03}_yaw{y:+}_pitch+0.png"))
        .collect();
    assert_eq!(frames, expected);
    for name in &frames {
        let frame = image::open(out.join(name)).unwrap();
        assert_eq!((frame.width(), frame.height()), (32, 32));
    }
    let gif = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(
        std::fs::File::open(out.join("sweep.gif")).unwrap(),
    ))
    .unwrap();
    let gif_frames = gif.into_frames().collect_frames().unwrap();
    assert_eq!(gif_frames.len(), 7);
    // The GIF's middle frame is the frontal view's PNG (up to the GIF palette).
    let frontal = image::open(out.join(&expected[3])).unwrap().to_rgba8();
    let diff: f64 = gif_frames[3]
        .buffer()
        .pixels()
        .zip(frontal.pixels())
        .map(|(a, b)| {
            (0..3)
                .map(|c| (a[c] as f64 - b[c] as f64).abs())
                .sum::<f64>()
        })
        .sum::<f64>()
        / (32.0 * 32.0 * 3.0);
    assert!(diff < 8.0, "mean GIF difference {diff}");
    // The person is centred horizontally and as tall as in the training data's frontal views
    // (this subject stands off-centre: the protocol jitters the subjects +-0.1 m).
    let input = image::open(out.join("input.png")).unwrap().to_rgb8();
    let (x0, y0, x1, y1) = person_box(&input);
    let centre_x = (x0 + x1) as f32 / 2.0;
    assert!((centre_x - 16.0).abs() <= 1.0, "box x {x0}..{x1}");
    let height = (y1 - y0) as f32;
    let want = prism_train::infer::PERSON_HEIGHT_FRACTION * 32.0;
    assert!(
        (height - want).abs() <= 2.0,
        "box y {y0}..{y1}, {want} px expected"
    );
    // One Gaussian per source pixel.
    let bytes = std::fs::read(&ply).unwrap();
    let header = String::from_utf8_lossy(&bytes[..bytes.len().min(2000)]);
    assert!(
        header.starts_with("ply") && header.contains("element vertex 1024"),
        "{header}"
    );

    let grid = dir.join("grid");
    ok(prism(
        &f.cache,
        &[
            "infer",
            "--checkpoint",
            s(&f.run),
            "--image",
            s(&photo),
            "--out",
            s(&grid),
            "--sweep",
            "grid",
            "--step",
            "30",
        ],
        true,
    ));
    let count = std::fs::read_dir(&grid)
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .ends_with(".png")
        })
        .count();
    assert_eq!(count, 9 + 1, "3 x 3 views and input.png");
}

/// A folder of frames is rendered frame by frame.
#[test]
fn infer_renders_a_folder_of_frames() {
    let f = fixture();
    let dir = scratch("frames");
    let meta = read_json(&f.data.join("dataset.json"));
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    for (k, name) in meta["split"]["train"].as_array().unwrap()[..2]
        .iter()
        .enumerate()
    {
        let rgb = f.data.join(name.as_str().unwrap()).join("rgb/000.png");
        std::fs::copy(rgb, frames.join(format!("frame{k}.png"))).unwrap();
    }
    let out = dir.join("out");
    let run = ok(prism(
        &f.cache,
        &[
            "infer",
            "--checkpoint",
            s(&f.run),
            "--image",
            s(&frames),
            "--out",
            s(&out),
            "--step",
            "30",
        ],
        true,
    ));
    assert!(String::from_utf8_lossy(&run.stderr).contains("warning: "));
    for k in 0..2 {
        let folder = out.join(format!("frame{k}"));
        assert!(folder.join("sweep.gif").is_file());
        assert!(folder.join("001_yaw+0_pitch+0.png").is_file());
    }
}

#[test]
fn bad_inputs_are_one_clear_line() {
    let f = fixture();
    let dir = scratch("errors");
    let meta = read_json(&f.data.join("dataset.json"));
    let subject = f.data.join(meta["split"]["test"][0].as_str().unwrap());
    let photo = subject.join("rgb/000.png");
    let infer = |image: &Path, extra: &[&str], run: &Path| {
        let mut args = vec![
            "infer",
            "--checkpoint",
            s(run),
            "--image",
            s(image),
            "--out",
            s(&dir),
        ];
        args.extend_from_slice(extra);
        prism(&f.cache, &args, true)
    };
    // An unreadable image.
    let junk = dir.join("junk.png");
    std::fs::write(&junk, b"not a png").unwrap();
    let err = failure(infer(&junk, &[], &f.run));
    assert!(err.contains("junk.png"), "{err}");
    // A mask of another size.
    let small = dir.join("small.png");
    image::GrayImage::new(8, 8).save(&small).unwrap();
    let err = failure(infer(&photo, &["--mask", s(&small)], &f.run));
    assert!(err.contains("small.png") && err.contains("8x8"), "{err}");
    // An empty mask.
    let empty = dir.join("empty.png");
    image::GrayImage::new(32, 32).save(&empty).unwrap();
    let err = failure(infer(&photo, &["--mask", s(&empty)], &f.run));
    assert!(err.contains("empty"), "{err}");
    // A PLY from a model without a 3DGS head.
    let ply = dir.join("x.ply");
    let err = failure(infer(&photo, &["--export-ply", s(&ply)], &f.run_without_gs));
    assert!(err.contains("3DGS head"), "{err}");
    assert!(!ply.exists());
    // A checkpoint whose config is not the one its weights were trained with.
    let ckpt = prism_train::latest_checkpoint(&f.run).unwrap().unwrap();
    let other = dir.join("other-config");
    std::fs::create_dir_all(&other).unwrap();
    for entry in std::fs::read_dir(&ckpt).unwrap() {
        let entry = entry.unwrap();
        std::fs::copy(entry.path(), other.join(entry.file_name())).unwrap();
    }
    let mut config = tiny_config(true);
    config.model.width = 32;
    std::fs::write(other.join("config.toml"), config.to_toml()).unwrap();
    let err = failure(prism(
        &f.cache,
        &["evaluate", "--checkpoint", s(&other), "--data", s(&f.data)],
        true,
    ));
    assert!(err.contains("other-config"), "{err}");
    // Images of different sizes.
    let (pred, gt) = (dir.join("p"), dir.join("g"));
    std::fs::create_dir_all(&pred).unwrap();
    std::fs::create_dir_all(&gt).unwrap();
    image::RgbImage::new(40, 40)
        .save(pred.join("a.png"))
        .unwrap();
    image::RgbImage::new(48, 40).save(gt.join("a.png")).unwrap();
    let err = failure(prism(
        &f.cache,
        &["evaluate", "--pred", s(&pred), "--gt", s(&gt)],
        true,
    ));
    assert!(err.contains("a.png"), "{err}");
}

/// The quick start, end to end on its default backend: data, teacher, student, both
/// evaluations, the table.
#[test]
fn quickstart_fast_runs_end_to_end() {
    let dir = scratch("quickstart");
    let out = dir.join("qs");
    let run = ok(prism(
        &dir.join("cache"),
        &["quickstart", "--fast", "--quiet", "--out", s(&out)],
        false,
    ));
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        stdout.contains("| teacher |") && stdout.contains("| student |"),
        "{stdout}"
    );
    for model in ["teacher", "student"] {
        let v = read_json(&out.join(model).join("evaluation/evaluation.json"));
        in_range(&v, "psnr", 3.0, 60.0);
        in_range(&v, "ssim", -1.0, 1.0);
        in_range(&v, "lpips", 0.0, 1.5);
        in_range(&v, "fps", 1e-3, 1e6);
        assert_eq!(v["views_per_subject"], 100);
        assert!(stdout.contains(&format!("{model} report: ")), "{stdout}");
    }
    assert!(out.join("quickstart.md").is_file());
    // The student ends with the tiny schedule's Linear blocks.
    let attention = std::fs::read_to_string(
        prism_train::latest_checkpoint(&out.join("student"))
            .unwrap()
            .unwrap()
            .join("attention.json"),
    )
    .unwrap();
    assert!(attention.contains("linear"), "{attention}");
    // A rerun reuses both runs and only evaluates again.
    let rerun = ok(prism(
        &dir.join("cache"),
        &["quickstart", "--fast", "--out", s(&out)],
        false,
    ));
    assert!(String::from_utf8_lossy(&rerun.stderr).contains("reusing"));
}
