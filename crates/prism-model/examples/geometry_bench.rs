//! What the geometry parts cost: forward time (inference) and training-step time (forward and
//! backward of a loss on every output) of a config with every part, without each part, and
//! without any (the plain backbone), plus the SMPL-X branch's steps one by one.
//!
//! ```bash
//! cargo run --release -p prism-model --example geometry_bench -- \
//!     --config configs/tiny.toml --batch 4 --backend flex
//! ```
//!
//! Median of `--iters` runs after one warm-up run; random weights and source image, protocol
//! cameras (source frontal, targets spread over +-20 degrees).

use std::time::Instant;

use burn::tensor::{Device, Distribution, Tensor};
use prism_core::BackendKind;
use prism_core::rays::plucker_rays;
use prism_model::{
    Prism, PrismConfig, PrismOutput, SourcePixels, Views, load_config, protocol_views,
};
use prism_render::triplane::sample_triplane;

struct Args {
    config: String,
    batch: usize,
    iters: usize,
    backend: BackendKind,
}

fn args() -> Args {
    let mut out = Args {
        config: "configs/tiny.toml".into(),
        batch: 4,
        iters: 5,
        backend: BackendKind::Flex,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let value = it.next().unwrap_or_else(|| panic!("{flag} needs a value"));
        match flag.as_str() {
            "--config" => out.config = value,
            "--batch" => out.batch = value.parse().expect("--batch N"),
            "--iters" => out.iters = value.parse().expect("--iters N"),
            "--backend" => {
                out.backend = match value.as_str() {
                    "flex" => BackendKind::Flex,
                    "ndarray" => BackendKind::Ndarray,
                    other => panic!("unknown backend {other}"),
                }
            }
            other => panic!("unknown flag {other}"),
        }
    }
    out
}

/// Median milliseconds of `f` over `iters` runs after one warm-up.
fn time(iters: usize, mut f: impl FnMut()) -> f64 {
    f();
    let mut t: Vec<f64> = (0..iters)
        .map(|_| {
            let start = Instant::now();
            f();
            start.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
}

struct Inputs {
    image: Tensor<4>,
    source: Tensor<4>,
    target: Tensor<4>,
    views: Views,
}

fn inputs(b: usize, res: usize, device: &Device) -> Inputs {
    let views = protocol_views(b, res);
    Inputs {
        image: Tensor::random([b, 3, res, res], Distribution::Uniform(0.0, 1.0), device),
        source: plucker_rays(&views.source, device),
        target: plucker_rays(&views.target, device),
        views,
    }
}

fn forward(model: &Prism, x: &Inputs) -> PrismOutput {
    model.forward_views(
        x.image.clone(),
        x.source.clone(),
        x.target.clone(),
        &x.views,
        &[],
    )
}

/// A loss touching every output, as training does.
fn loss(out: &PrismOutput) -> Tensor<1> {
    let mut l = out.image.clone().powi_scalar(2).mean();
    if let Some(s) = &out.smplx {
        l = l + s.betas.clone().powi_scalar(2).mean() + s.rotations.clone().mean();
    }
    if let Some(p) = &out.points {
        l = l + p.points.clone().mean() + p.confidence.clone().mean();
    }
    if let Some(g) = &out.gaussians {
        l = l + g.image.clone().powi_scalar(2).mean();
    }
    l
}

/// `config` with the parts switched as given, and the paper's output parameterisation (the
/// shipped geometric outputs need the point branch and the 3DGS head together).
fn with(config: &PrismConfig, smplx: bool, points: bool, gs: bool) -> PrismConfig {
    let mut c = config.clone().paper_outputs();
    c.smplx_branch = smplx;
    c.point_branch = points;
    c.gs_head = gs;
    c
}

fn main() {
    let args = args();
    let device = args.backend.device().expect("backend");
    let config = load_config(&args.config).expect("config").model;
    let res = config.resolution;
    let b = args.batch;
    println!(
        "config {} at {res}x{res}, batch {b}, {:?}, median of {} runs",
        args.config, args.backend, args.iters
    );
    println!("| variant | forward ms | share of forward | train step ms | share of step |");
    println!("|---|---|---|---|---|");
    let variants = [
        ("full model", with(&config, true, true, true)),
        ("without SMPL-X branch", with(&config, false, true, true)),
        ("without point branch", with(&config, true, false, true)),
        ("without 3DGS head", with(&config, true, true, false)),
        ("plain backbone", with(&config, false, false, false)),
    ];
    // All variants are timed round-robin, so that a change of the machine's load hits them alike.
    let ad = device.clone().autodiff();
    let x = inputs(b, res, &device);
    let x_ad = Inputs {
        image: Tensor::from_data(x.image.clone().into_data(), &ad),
        source: Tensor::from_data(x.source.clone().into_data(), &ad),
        target: Tensor::from_data(x.target.clone().into_data(), &ad),
        views: x.views.clone(),
    };
    let models: Vec<(Prism, Prism)> = variants
        .iter()
        .map(|(_, c)| {
            device.seed(0);
            ad.seed(0);
            (c.init(&device), c.init(&ad))
        })
        .collect();
    let mut forward_ms = vec![Vec::new(); variants.len()];
    let mut step_ms = vec![Vec::new(); variants.len()];
    for iter in 0..=args.iters {
        for (k, (model, model_ad)) in models.iter().enumerate() {
            let start = Instant::now();
            let _ = forward(model, &x).image.into_data();
            let fwd = start.elapsed().as_secs_f64() * 1e3;
            let start = Instant::now();
            let _ = loss(&forward(model_ad, &x_ad)).backward();
            let step = start.elapsed().as_secs_f64() * 1e3;
            if iter > 0 {
                forward_ms[k].push(fwd);
                step_ms[k].push(step);
            }
        }
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let full = (median(&mut forward_ms[0]), median(&mut step_ms[0]));
    for (k, (name, _)) in variants.iter().enumerate() {
        let (fwd, step) = (median(&mut forward_ms[k]), median(&mut step_ms[k]));
        if k == 0 {
            println!("| {name} | {fwd:.1} | | {step:.1} | |");
        } else {
            println!(
                "| {name} | {fwd:.1} | {:.0}% | {step:.1} | {:.0}% |",
                100.0 * (full.0 - fwd) / full.0,
                100.0 * (full.1 - step) / full.1
            );
        }
    }

    // The SMPL-X branch step by step (forward, plain device).
    let model = &models[0].0;
    let branch = model
        .smplx_branch
        .as_ref()
        .expect("the config has the SMPL-X branch");
    let x = inputs(b, res, &device);
    let tokens = Tensor::<3>::random(
        [b, (res / config.patch_size).pow(2), config.width],
        Distribution::Normal(0.0, 1.0),
        &device,
    );
    let (betas, rotations, expression, camera) = branch.regress(tokens.clone());
    let regress = time(args.iters, || {
        let (b, ..) = branch.regress(tokens.clone());
        let _ = b.into_data();
    });
    let pose = time(args.iters, || {
        let world =
            branch.world_vertices(&betas, &rotations, &expression, &camera, &x.views.source);
        let _ = world.into_data();
    });
    let world = branch.world_vertices(&betas, &rotations, &expression, &camera, &x.views.source);
    let raster = time(args.iters, || {
        let maps =
            prism_render::mesh::rasterize_maps(world.clone(), branch.faces(), &x.views.target)
                .unwrap();
        let _ = maps.faces.into_data();
    });
    let map = time(args.iters, || {
        let (_, m) = branch.position_map(
            world.clone(),
            betas.clone(),
            expression.clone(),
            &x.views.target,
        );
        let _ = m.into_data();
    });
    let (_, position) = branch.position_map(
        world.clone(),
        betas.clone(),
        expression.clone(),
        &x.views.target,
    );
    let triplane = time(args.iters, || {
        let f = sample_triplane(branch.triplane.val(), position.clone()).unwrap();
        let _ = f.into_data();
    });
    let planes = Tensor::<4>::from_data(branch.triplane.val().into_data(), &ad).require_grad();
    let coords = Tensor::<4>::from_data(position.clone().into_data(), &ad).require_grad();
    let triplane_step = time(args.iters, || {
        let f = sample_triplane(planes.clone(), coords.clone()).unwrap();
        let _ = f.sum().backward();
    });
    println!();
    println!("SMPL-X branch steps (batch {b}, {res}x{res}, ms):");
    println!("| step | ms |");
    println!("|---|---|");
    println!("| adapter + regressor | {regress:.2} |");
    println!("| pose the body (BodyLayer) + place it (host) | {pose:.2} |");
    println!(
        "| rasterize {} triangles into {b} views | {raster:.2} |",
        branch.faces().len()
    );
    println!("| position map (rasterize + gather) | {map:.2} |");
    println!("| triplane sampling forward | {triplane:.2} |");
    println!("| triplane sampling forward + backward | {triplane_step:.2} |");

    // The point branch and the 3DGS head step by step (forward, plain device).
    let points = model
        .point_branch
        .as_ref()
        .expect("the config has the point branch");
    let grid = (res / config.patch_size, res / config.patch_size);
    let taps: Vec<Tensor<3>> = points.taps().iter().map(|_| tokens.clone()).collect();
    let dpt = time(args.iters, || {
        let _ = points.dpt.forward(&taps, grid, res, res).into_data();
    });
    let whole = time(args.iters, || {
        let out = points.forward(&taps, &x.image, &x.source, &x.views, grid, res, res);
        let _ = out.features.into_data();
    });
    let out = points.forward(&taps, &x.image, &x.source, &x.views, grid, res, res);
    let splat = time(args.iters, || {
        let r = prism_render::splat::render(&out.gaussians, &x.views.target).unwrap();
        let _ = r.features.into_data();
    });
    let head = model
        .gs_head
        .as_ref()
        .expect("the config has the 3DGS head");
    let gs = time(args.iters, || {
        let source = SourcePixels {
            image: &x.image,
            rays: &x.source,
            distance: Some(out.distance.clone()),
        };
        let out = head.forward(tokens.clone(), source, &x.views, res, res);
        let _ = out.image.into_data();
    });
    println!();
    println!("Point branch and 3DGS head (batch {b}, {res}x{res}, ms):");
    println!("| step | ms |");
    println!("|---|---|");
    println!("| point branch: DPT head | {dpt:.2} |");
    println!(
        "| point branch: splat {} points per view | {splat:.2} |",
        res * res
    );
    println!("| point branch: whole | {whole:.2} |");
    println!("| 3DGS head: whole (projection, activations, splat) | {gs:.2} |");

    // A frozen distillation teacher: the full forward pass for its hidden states, against the
    // trunk alone (no heads), on the shipped config, taking turns.
    let file = load_config(&args.config).expect("config");
    let layers = file
        .distill
        .layer_indices(config.num_blocks())
        .expect("distillation layers");
    device.seed(0);
    let teacher = config.init(&device);
    let (mut full, mut trunk) = (Vec::new(), Vec::new());
    for iter in 0..=args.iters {
        let start = Instant::now();
        let out = teacher.forward_views(
            x.image.clone(),
            x.source.clone(),
            x.target.clone(),
            &x.views,
            &layers,
        );
        let _ = out.hidden.into_iter().map(Tensor::into_data).count();
        let f = start.elapsed().as_secs_f64() * 1e3;
        let start = Instant::now();
        let hidden = teacher.hidden_states(
            x.image.clone(),
            x.source.clone(),
            x.target.clone(),
            &x.views,
            &layers,
        );
        let _ = hidden.into_iter().map(Tensor::into_data).count();
        let t = start.elapsed().as_secs_f64() * 1e3;
        if iter > 0 {
            full.push(f);
            trunk.push(t);
        }
    }
    let (full, trunk) = (median(&mut full), median(&mut trunk));
    println!();
    println!("A frozen teacher's hidden states {layers:?} (batch {b}, {res}x{res}, ms):");
    println!("| path | ms |");
    println!("|---|---|");
    println!("| the full forward pass | {full:.2} |");
    println!(
        "| the trunk alone (`Prism::hidden_states`) | {trunk:.2} ({:.2}x) |",
        trunk / full
    );
}
