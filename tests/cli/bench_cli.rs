//! End-to-end tests of `prism bench --config FILE --res ...` through the built binary (flex,
//! the default backend), on the tiny config at tiny resolutions.

use crate::common;

use std::path::PathBuf;
use std::process::Command;

use prism_train::{TrainingConfig, configs_dir};

use common::{output, prism_with_cache, scratch, stderr, stdout, success};

/// configs/tiny.toml at 32 px without LPIPS, its synthetic data 4 subjects of 32 px, written
/// into `dir`.
fn tiny_config(dir: &std::path::Path) -> PathBuf {
    let mut c = TrainingConfig::load(configs_dir().join("tiny.toml")).unwrap();
    c.model.resolution = 32;
    c.losses.lpips = 0.0;
    c.data.subjects = 4;
    c.data.resolution = 32;
    c.data.test_fraction = 0.25;
    let path = dir.join("bench.toml");
    std::fs::write(&path, c.to_toml()).unwrap();
    path
}

#[test]
fn bench_times_teacher_student_linear_and_the_training_step() {
    let dir = scratch("table");
    let config = tiny_config(&dir);
    let json = dir.join("out/bench.json");
    let out = success(prism_with_cache(
        &dir.join("cache"),
        &[
            "bench",
            "--config",
            config.to_str().unwrap(),
            "--res",
            "16,32,64",
            "--warmup",
            "1",
            "--iters",
            "2",
            "--train-steps",
            "3",
            "--json",
            json.to_str().unwrap(),
        ],
    ));
    let stdout = stdout(&out);
    let value: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let rows = value["rows"].as_array().unwrap();
    let names: Vec<(&str, u64)> = rows
        .iter()
        .map(|r| (r["model"].as_str().unwrap(), r["res"].as_u64().unwrap()))
        .collect();
    assert_eq!(
        names,
        [
            ("teacher", 16),
            ("teacher", 32),
            ("teacher", 64),
            ("student", 16),
            ("student", 32),
            ("student", 64),
            ("linear", 16),
            ("linear", 32),
            ("linear", 64),
            ("train_step", 32),
        ]
    );
    for row in rows {
        let ms = row["ms"].as_f64().unwrap();
        let fps = row["fps"].as_f64().unwrap();
        assert!(ms > 0.0 && (fps * ms - 1000.0).abs() < 1e-6, "{row}");
        let res = row["res"].as_u64().unwrap();
        assert_eq!(row["tokens"].as_u64().unwrap(), 2 * (res / 8) * (res / 8));
        // The binary counts its heap: the CPU backend's peak is measured, never null.
        let peak = row["peak_mem_bytes"]
            .as_u64()
            .expect("peak memory measured");
        assert!(peak > 0, "{row}");
        // The CPU backends run the geometry on the host: its reads are counted per row.
        let reads = row["geometry_host_reads"]
            .as_f64()
            .expect("geometry reads counted");
        let all = row["host_reads"].as_f64().expect("reads counted");
        // At least the frame (or the step's logged losses) is read back.
        assert!(all > 0.0 && all >= reads, "{row}");
        // The hypervisor's share of the CPU time, where a clock tick passed while timing.
        assert!(
            row["cpu_steal"]
                .as_f64()
                .is_none_or(|s| (0.0..=1.0).contains(&s)),
            "{row}"
        );
    }
    // The training run lasts many clock ticks: Linux's counters give its share.
    let steal = rows[9]["cpu_steal"].as_f64().expect("steal counted");
    assert!((0.0..=1.0).contains(&steal), "{steal}");
    // The training run holds the model, its optimizer state and a batch's graph: more than
    // one inference forward pass at the same size.
    let peak = |i: usize| rows[i]["peak_mem_bytes"].as_u64().unwrap();
    assert!(
        peak(9) > peak(1),
        "train {} vs forward {}",
        peak(9),
        peak(1)
    );
    // Bigger images need more memory for the same model. Compared at 16 and 64 px: any row can
    // also hold about 1 MB of first-use scratch of a worker thread that joins only then (seen:
    // teacher 16 px 3.0 MB against 32 px 1.0 MB under CI load; student 16 px 1.9 MB against
    // 32 px 1.0 MB), more than 16 and 32 px differ by (0.9 and 1.0 MB) and less than 16 and 64
    // px do (0.9 and 3.8 MB).
    assert!(peak(5) > peak(3), "64 px {} vs 16 px {}", peak(5), peak(3));
    assert!(stdout.contains("train_step"), "{stdout}");
}

#[test]
fn bench_rejects_a_resolution_that_is_not_a_multiple_of_the_patch() {
    let dir = scratch("bad-res");
    let config = tiny_config(&dir);
    // The speed table and `bench model` check `--res` the same way, before timing anything.
    for command in [&["bench"][..], &["bench", "model"]] {
        let mut args = command.to_vec();
        args.extend(["--config", config.to_str().unwrap(), "--res", "32,20"]);
        let out = output(prism_with_cache(&dir.join("cache"), &args));
        assert_eq!(out.status.code(), Some(1), "{command:?}");
        let stderr = stderr(&out);
        assert!(
            stderr.contains("--res 20") && stderr.contains("patch size 8"),
            "{command:?}: {stderr}"
        );
        assert!(!stderr.contains("panicked"), "{stderr}");
    }
}

#[test]
fn bench_needs_a_config_or_a_subcommand() {
    let dir = scratch("no-config");
    let out = output(prism_with_cache(&dir.join("cache"), &["bench"]));
    assert!(!out.status.success());
    let stderr = stderr(&out);
    assert!(stderr.contains("--config"), "{stderr}");
}

/// `scripts/peer/backbone.toml` must stay a valid config with the shapes that
/// `scripts/peer/compare.py` gives the PyTorch peer, and `prism bench` must run it.
#[test]
fn the_pytorch_peer_config_has_the_peer_shapes_and_runs() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scripts/peer/backbone.toml");
    let c = TrainingConfig::load(&path).unwrap();
    let m = &c.model;
    assert_eq!(
        (m.width, m.heads, m.patch_size, m.mlp_ratio),
        (256, 4, 8, 4)
    );
    assert_eq!((m.stage_one_blocks, m.stage_three_blocks), (2, 4));
    assert!(!m.smplx_branch && !m.point_branch && !m.gs_head);
    assert_eq!(c.distill.group_size, 6);
    assert_eq!((c.train.batch_size, c.train.targets_per_sample), (1, 1));
    assert_eq!((c.losses.lpips, c.losses.gs), (0.0, 0.0));
    // compare.py reads the PyTorch side's shapes from the same file.
    let script = format!(
        "import sys; sys.path.insert(0, {dir:?}); import compare; \
         print(' '.join(compare.backbone_shapes({path:?})))",
        dir = path.parent().unwrap(),
        path = path,
    );
    let mut python = Command::new("python3");
    python.args(["-c", &script]);
    let shapes = stdout(&success(python));
    assert_eq!(
        shapes.trim(),
        "--width 256 --heads 4 --patch 8 --blocks 6 --group 6 --mlp-ratio 4",
        "compare.py passes other shapes"
    );

    let dir = scratch("peer");
    let out = success(prism_with_cache(
        &dir,
        &[
            "bench",
            "--config",
            path.to_str().unwrap(),
            "--res",
            "16",
            "--models",
            "teacher,linear",
        ]
        .into_iter()
        .chain(["--warmup", "0", "--iters", "1", "--train-steps", "0"])
        .collect::<Vec<_>>(),
    ));
    let table = stdout(&out);
    assert!(
        table.contains("teacher") && table.contains("linear"),
        "{table}"
    );
}

/// `compare.py --rounds N` compares each side's median over the rounds and gives the range of
/// the rounds' own ratios; a row only one side timed is left out.
#[test]
fn the_pytorch_comparison_takes_the_median_of_its_rounds() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scripts/peer");
    let script = format!(
        "import sys, json, contextlib, io; sys.path.insert(0, {dir:?}); import compare\n\
         side = lambda ms: {{('linear', 128): {{'ms': ms}}, ('train_step', 128): {{'ms': 2 * ms}}}}\n\
         rounds = [dict(prism=side(p), torch=side(t)) for p, t in [(10, 20), (30, 20), (20, 40)]]\n\
         rounds[0]['prism'][('teacher', 128)] = {{'ms': 5}}\n\
         with contextlib.redirect_stdout(io.StringIO()) as table:\n    rows = compare.table([compare.round_rows(r) for r in rounds])\n\
         print(json.dumps(dict(rows=rows, table=table.getvalue())))",
    );
    let mut python = Command::new("python3");
    python.args(["-c", &script]);
    let out: serde_json::Value = serde_json::from_str(&stdout(&success(python))).unwrap();
    let rows = out["rows"].as_array().unwrap();
    let what: Vec<&str> = rows.iter().map(|r| r["what"].as_str().unwrap()).collect();
    assert_eq!(what, ["linear", "train_step"], "{out}");
    for (row, scale) in rows.iter().zip([1.0, 2.0]) {
        assert_eq!(row["prism_ms"], 20.0 * scale);
        assert_eq!(row["torch_ms"], 20.0 * scale);
        assert_eq!(row["ratio"], 1.0);
        assert_eq!(
            (&row["ratio_min"], &row["ratio_max"]),
            (&0.5.into(), &1.5.into())
        );
    }
    let table = out["table"].as_str().unwrap();
    assert!(
        table.contains("| linear | 128 | 20.0 | 20.0 | 1.00x | 0.50x to 1.50x |"),
        "{table}"
    );
}
