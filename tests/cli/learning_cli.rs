//! The shipped configs learn view synthesis, through the built binary (flex backend, the
//! training the README recommends on a CPU): a small-config teacher (the quick start's config,
//! 40 steps) beats copying the source view on the held-out person's validation views, and
//! `prism infer` with it turns that person better than copying does, against ground-truth
//! renders of the yaw sweep's views. (The tiny model, 5 training people at 64 px, beats copying
//! on validation after 200 steps but is below it at 10 and 20 degrees of that sweep:
//! BENCHMARKS.md, "Learning from scratch".)

use crate::common;

use std::path::Path;

use image::RgbImage;
use prism_body::BodyModel;
use prism_core::{Intrinsics, ViewingProtocol};
use prism_synth::people::{self, PeopleConfig};
use prism_synth::synth::{BODY_MODEL_SEED, subject_name, subject_seed};
use prism_synth::{RenderOptions, render};
use prism_train::infer::{Sweep, sweep_views, view_file_name};
use prism_train::{TrainingConfig, configs_dir, read_metrics};

use common::{prism_with_cache, scratch, success};

/// The synthetic person `index` of the config's dataset, rendered in the protocol camera of
/// `yaw` degrees (pitch 0), as the dataset would store it.
fn ground_truth(config: &TrainingConfig, index: usize, yaw: f32) -> RgbImage {
    let data = &config.data;
    let seed = subject_seed(data.seed, index);
    let model = BodyModel::procedural(BODY_MODEL_SEED);
    let person =
        people::generate_with(&model, seed, &PeopleConfig::for_resolution(data.resolution));
    let protocol = ViewingProtocol::default();
    let person = person.placed(&protocol.placement(seed));
    let view = prism_core::ViewAngles {
        index: 0,
        yaw_deg: yaw,
        pitch_deg: 0.0,
    };
    let camera = protocol.camera(
        &view,
        Intrinsics::protocol_default(data.resolution, data.resolution),
    );
    let options = RenderOptions {
        supersample: data.supersample,
        background: data.background,
        ..Default::default()
    };
    let out = render(&person.mesh, &camera, &options).unwrap();
    RgbImage::from_fn(out.width as u32, out.height as u32, |x, y| {
        let c = out.rgb[out.index(x as usize, y as usize)];
        image::Rgb(c.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8))
    })
}

/// The small teacher's training steps: the longest test of the suite (2 cores of flex for
/// minutes), so as few as keep clear margins. At 40 steps: validation 20.61 dB against
/// copying's 18.10, the sweep's turned views 20.35 dB against 18.07, every view above copying
/// by 1 dB or more (BENCHMARKS.md, "CI on the slow Xeon host, third round").
const STEPS: usize = 40;

/// Trains `config_path` for `steps` steps into `run` (flex, quiet) with the cache `cache`.
fn train(cache: &Path, config_path: &Path, run: &Path, steps: usize) {
    let steps = steps.to_string();
    success(prism_with_cache(
        cache,
        &[
            "train-teacher",
            "--config",
            config_path.to_str().unwrap(),
            "--out",
            run.to_str().unwrap(),
            "--steps",
            &steps,
            "--backend",
            "flex",
            "--quiet",
        ],
    ));
}

#[test]
fn a_small_teacher_beats_copying_on_validation_and_turns_a_held_out_person_with_infer() {
    let dir = scratch("small");
    let cache = dir.join("cache");
    let run = dir.join("teacher");
    let config_path = configs_dir().join("small.toml");
    let config = TrainingConfig::load(&config_path).unwrap();
    train(&cache, &config_path, &run, STEPS);

    // Validation on the held-out person, against copying the source view.
    let metrics = read_metrics(&run.join("metrics.jsonl")).unwrap();
    let copy = metrics
        .iter()
        .find_map(|l| l["copy_source_psnr"].as_f64())
        .unwrap();
    let last = metrics
        .iter()
        .filter_map(|l| Some((l["step"].as_u64()?, l["val_psnr"].as_f64()?)))
        .next_back()
        .unwrap();
    println!(
        "validation at step {}: {:.3} dB, copy-source {copy:.3} dB",
        last.0, last.1
    );
    assert_eq!(last.0, STEPS as u64);
    assert!(
        last.1 > copy,
        "validation {:.3} dB vs copy-source {copy:.3} dB",
        last.1
    );

    // prism infer on the held-out person's frontal view (a square photo at the model's size, no
    // mask: framed as it is), the yaw sweep to +-30 degrees, against renders of those views.
    let held_out = config.data.subjects - 1;
    let dataset = std::fs::read_dir(cache.join("datasets"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let photo = dataset.join(subject_name(held_out)).join("rgb/000.png");
    let views_dir = dir.join("views");
    success(prism_with_cache(
        &cache,
        &[
            "infer",
            "--checkpoint",
            run.to_str().unwrap(),
            "--image",
            photo.to_str().unwrap(),
            "--out",
            views_dir.to_str().unwrap(),
            "--sweep",
            "yaw",
            "--backend",
            "flex",
            "--quiet",
        ],
    ));
    let source = image::open(&photo).unwrap().to_rgb8();
    let (mut model, mut copying) = (0.0, 0.0);
    let views = sweep_views(Sweep::Yaw, 10.0, 30.0);
    // The turned views: the sweep's frontal view is the photo itself.
    let turned: Vec<_> = views.iter().filter(|v| v.yaw_deg != 0.0).collect();
    for view in &turned {
        let truth = ground_truth(&config, held_out, view.yaw_deg);
        let predicted = image::open(views_dir.join(view_file_name(view)))
            .unwrap()
            .to_rgb8();
        let (m, c) = (
            common::psnr_8bit(&predicted, &truth),
            common::psnr_8bit(&source, &truth),
        );
        println!(
            "yaw {:+.0}: model {m:.3} dB, copy-source {c:.3} dB",
            view.yaw_deg
        );
        model += m / turned.len() as f64;
        copying += c / turned.len() as f64;
    }
    assert_eq!(views.first().unwrap().yaw_deg, -30.0);
    assert_eq!(views.last().unwrap().yaw_deg, 30.0);
    // The frontal view of the sweep is the photo itself: the ground truth is right.
    assert!(common::psnr_8bit(&source, &ground_truth(&config, held_out, 0.0)) > 40.0);
    println!("turned views' mean: model {model:.3} dB, copy-source {copying:.3} dB");
    assert!(
        model > copying,
        "model {model:.3} dB vs copy-source {copying:.3} dB"
    );
}
