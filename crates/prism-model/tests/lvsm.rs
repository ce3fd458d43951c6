//! prism's backbone on a pretrained LVSM's weights computes what LVSM computes.
//!
//! The fixture (`tests/fixtures/`, made by `scripts/make_lvsm_fixture.py`) is a tiny
//! decoder-only LVSM (width 32, head dim 16, patch 8, 4 blocks) with random weights, saved as
//! PyTorch saves it, with an input batch and LVSM's prediction for it.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use burn::tensor::{Device, Tensor, TensorData};
use glam::Mat4;
use prism_core::rays::plucker_rays;
use prism_core::{BackendKind, Camera, Intrinsics};
use prism_model::{BlockPlacement, LvsmCheckpoint, ModelError, PrismConfig};

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures")
}

/// The fixture's tensors (f32 safetensors, read by hand: header length, JSON header, data).
fn read_safetensors(path: &Path) -> BTreeMap<String, (Vec<usize>, Vec<f32>)> {
    let bytes = std::fs::read(path).unwrap();
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    let data = &bytes[8 + n..];
    let mut out = BTreeMap::new();
    for (name, entry) in header.as_object().unwrap() {
        if name == "__metadata__" {
            continue;
        }
        assert_eq!(entry["dtype"], "F32", "{name}");
        let shape: Vec<usize> = entry["shape"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap() as usize)
            .collect();
        let offsets = entry["data_offsets"].as_array().unwrap();
        let (a, b) = (
            offsets[0].as_u64().unwrap() as usize,
            offsets[1].as_u64().unwrap() as usize,
        );
        let values = data[a..b]
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect();
        out.insert(name.clone(), (shape, values));
    }
    out
}

fn tensor4(t: &(Vec<usize>, Vec<f32>), device: &Device) -> Tensor<4> {
    let shape: [usize; 4] = t.0.clone().try_into().unwrap();
    Tensor::from_data(TensorData::new(t.1.clone(), shape), device)
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.to_data().convert::<f32>().try_to_vec::<f32>().unwrap()
}

fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

/// LVSM's Plücker order `(o x d, d)` to prism's `(d, o x d)`.
fn to_prism_order(lvsm: Tensor<4>) -> Tensor<4> {
    Tensor::cat(vec![lvsm.clone().narrow(1, 3, 3), lvsm.narrow(1, 0, 3)], 1)
}

/// A config with the fixture's sizes, geometry off, the paper's outputs.
fn config(stage_one: usize, stage_three: usize) -> PrismConfig {
    PrismConfig::new(32, 2, 8, stage_one, stage_three, 32)
}

fn checkpoint() -> LvsmCheckpoint {
    LvsmCheckpoint::read(&fixtures().join("lvsm_tiny.pt")).expect("the fixture reads")
}

fn device() -> Device {
    BackendKind::Ndarray.device().unwrap()
}

#[test]
fn the_fixture_is_read_with_its_layout() {
    let ckpt = checkpoint();
    let layout = ckpt.layout().unwrap();
    assert_eq!(
        (
            layout.width,
            layout.head_dim,
            layout.heads(),
            layout.patch_size
        ),
        (32, 16, 2, 8)
    );
    assert_eq!((layout.layers, layout.mlp_hidden), (4, 128));
    // 4 x 8 block tensors, 2 tokenizers, the input norm, the decoder's norm and linear.
    assert_eq!(ckpt.tensors.len(), 37);
    assert_eq!(
        ckpt.skipped.len(),
        1,
        "the perceptual loss's tensor is set aside"
    );
}

/// With the geometry parts off and `M + N` equal to LVSM's layer count, prism's forward equals
/// LVSM's, wherever the injection point sits.
#[test]
fn prism_on_lvsm_weights_computes_what_lvsm_computes() {
    for backend in [BackendKind::Ndarray, BackendKind::Flex] {
        equivalence_on(&backend.device().unwrap());
    }
}

fn equivalence_on(device: &Device) {
    let device = device.clone();
    let io = read_safetensors(&fixtures().join("lvsm_tiny_io.safetensors"));
    let image = tensor4(&io["source_image"], &device);
    let source_rays = to_prism_order(tensor4(&io["source_plucker"], &device));
    let target_rays = to_prism_order(tensor4(&io["target_plucker"], &device));
    let expected = &io["render"].1;
    let spread = expected.iter().copied().fold(f32::MIN, f32::max)
        - expected.iter().copied().fold(f32::MAX, f32::min);
    assert!(spread > 0.3, "the fixture's prediction varies ({spread})");
    let ckpt = checkpoint();
    for (m, n) in [(1, 3), (2, 2), (3, 1)] {
        let (model, conversion) = ckpt
            .convert(&config(m, n), &BlockPlacement::First, &device)
            .unwrap();
        assert_eq!(conversion.placement, vec![0, 1, 2, 3]);
        assert!(conversion.new_blocks.is_empty());
        assert_eq!(conversion.mapped, 37);
        let fresh: Vec<&str> = conversion.fresh.iter().map(|f| f.module.as_str()).collect();
        assert_eq!(
            fresh,
            ["injection"],
            "only the zero gate g_res is not LVSM's"
        );
        let out = model.forward(image.clone(), source_rays.clone(), target_rays.clone(), &[]);
        assert_eq!(out.image.dims(), [2, 3, 32, 32]);
        let diff = max_abs_diff(&values(out.image), expected);
        println!("M = {m}, N = {n}: max abs difference {diff:e}");
        assert!(diff < 1e-4, "M = {m}, N = {n}: max abs difference {diff}");
    }
    // The test sees the conventions: LVSM's ray order fed to prism gives another image.
    let (model, _) = ckpt
        .convert(&config(2, 2), &BlockPlacement::First, &device)
        .unwrap();
    let lvsm_order = |name: &str| tensor4(&io[name], &device);
    let out = model.forward(
        image,
        lvsm_order("source_plucker"),
        lvsm_order("target_plucker"),
        &[],
    );
    let diff = max_abs_diff(&values(out.image), expected);
    assert!(diff > 1e-2, "rays in the wrong order: {diff}");
}

/// prism's own rays of the fixture's cameras are LVSM's, channels reordered.
#[test]
fn prism_rays_are_lvsm_rays_reordered() {
    let device = device();
    let io = read_safetensors(&fixtures().join("lvsm_tiny_io.safetensors"));
    let k = &io["fxfycxcy"].1;
    let intrinsics = Intrinsics {
        fx: k[0],
        fy: k[1],
        cx: k[2],
        cy: k[3],
        width: 32,
        height: 32,
    };
    for (cams, plucker) in [
        ("source_c2w", "source_plucker"),
        ("target_c2w", "target_plucker"),
    ] {
        let c2w = &io[cams].1;
        let cameras: Vec<Camera> = c2w
            .chunks_exact(16)
            .map(|m| {
                let rows: [f32; 16] = m.try_into().unwrap();
                Camera::new(intrinsics, Mat4::from_cols_array(&rows).transpose())
            })
            .collect();
        let ours = values(plucker_rays(&cameras, &device));
        let theirs = values(to_prism_order(tensor4(&io[plucker], &device)));
        let diff = max_abs_diff(&ours, &theirs);
        assert!(diff < 1e-5, "{plucker}: {diff}");
    }
}

/// More blocks than LVSM's: the new blocks start as the identity, so the model still computes
/// LVSM's function, whichever blocks receive LVSM's.
#[test]
fn new_blocks_start_as_the_identity() {
    let device = device();
    let io = read_safetensors(&fixtures().join("lvsm_tiny_io.safetensors"));
    let image = tensor4(&io["source_image"], &device);
    let source_rays = to_prism_order(tensor4(&io["source_plucker"], &device));
    let target_rays = to_prism_order(tensor4(&io["target_plucker"], &device));
    let ckpt = checkpoint();
    for (placement, new) in [
        (BlockPlacement::First, vec![4, 5]),
        (BlockPlacement::Last, vec![0, 1]),
        (BlockPlacement::List(vec![0, 2, 3, 5]), vec![1, 4]),
    ] {
        let (model, conversion) = ckpt.convert(&config(2, 4), &placement, &device).unwrap();
        assert_eq!(conversion.new_blocks, new);
        let fresh_blocks = conversion
            .fresh
            .iter()
            .filter(|f| f.module.starts_with("stage_"))
            .count();
        assert_eq!(fresh_blocks, new.len(), "{:?}", conversion.fresh);
        let out = model.forward(image.clone(), source_rays.clone(), target_rays.clone(), &[]);
        let diff = max_abs_diff(&values(out.image), &io["render"].1);
        assert!(diff < 1e-4, "{placement}: {diff}");
    }
}

/// A config of another size fails with an error naming the first mismatch.
#[test]
fn a_checkpoint_of_another_size_gives_a_clear_error() {
    let ckpt = checkpoint();
    let device = device();
    let cases = [
        (
            PrismConfig::new(64, 4, 8, 2, 2, 32),
            "model.width = 64, the checkpoint's width is 32",
        ),
        (PrismConfig::new(32, 4, 8, 2, 2, 32), "model.heads = 4"),
        (
            PrismConfig::new(32, 2, 4, 2, 2, 32),
            "model.patch_size = 4, the checkpoint's patch size is 8",
        ),
        (
            PrismConfig::new(32, 2, 8, 1, 2, 32),
            "stage_three_blocks = 3, the checkpoint has 4 blocks",
        ),
        (
            PrismConfig::new(32, 2, 8, 2, 2, 32).with_mlp_ratio(2),
            "model.mlp_ratio = 2",
        ),
    ];
    for (config, wanted) in cases {
        let err = ckpt
            .convert(&config, &BlockPlacement::First, &device)
            .map(|_| ())
            .unwrap_err();
        assert!(matches!(err, ModelError::Lvsm { .. }));
        let text = err.to_string();
        assert!(text.contains(wanted), "`{text}` should say `{wanted}`");
        assert!(text.contains("lvsm_tiny.pt"), "{text}");
    }
}

/// The geometry parts keep their fresh initialisation and are reported so.
#[test]
fn geometry_parts_are_reported_fresh() {
    let config = config(2, 2)
        .with_smplx_branch(true)
        .with_point_branch(true)
        .with_gs_head(true)
        .with_smplx_width(16)
        .with_triplane_resolution(8)
        .with_triplane_channels(4)
        .with_point_width(8)
        .with_point_features(2);
    let (_, conversion) = checkpoint()
        .convert(&config, &BlockPlacement::First, &device())
        .unwrap();
    let fresh: Vec<&str> = conversion.fresh.iter().map(|f| f.module.as_str()).collect();
    for part in ["smplx_branch", "point_branch", "gs_head", "injection"] {
        assert!(fresh.contains(&part), "{part} in {fresh:?}");
    }
    assert!(
        !fresh
            .iter()
            .any(|f| f.starts_with("stage_") || *f == "tokenizer")
    );
}

/// The paper's config fits the published 512 px decoder-only LVSM (width 768, 12 heads of 64,
/// patch 8, 24 blocks, MLP 3072): shapes only, no weights.
#[test]
fn the_paper_config_fits_the_published_layout() {
    let (d, dh, p, layers) = (768, 64, 8, 24);
    let mut shapes: Vec<(String, Vec<usize>)> = vec![
        ("image_tokenizer.1.weight".into(), vec![d, 9 * p * p]),
        ("target_pose_tokenizer.1.weight".into(), vec![d, 6 * p * p]),
        ("transformer_input_layernorm.weight".into(), vec![d]),
        ("image_token_decoder.0.weight".into(), vec![d]),
        ("image_token_decoder.1.weight".into(), vec![3 * p * p, d]),
    ];
    for i in 0..layers {
        for (part, shape) in [
            ("norm1.weight", vec![d]),
            ("attn.to_qkv.weight", vec![3 * d, d]),
            ("attn.q_norm.weight", vec![dh]),
            ("attn.k_norm.weight", vec![dh]),
            ("attn.fc.weight", vec![d, d]),
            ("norm2.weight", vec![d]),
            ("mlp.mlp.0.weight", vec![4 * d, d]),
            ("mlp.mlp.2.weight", vec![d, 4 * d]),
        ] {
            shapes.push((format!("module.transformer_blocks.{i}.{part}"), shape));
        }
    }
    let tensors = shapes
        .into_iter()
        .map(|(name, shape)| {
            let tensor = prism_model::LvsmTensor {
                shape,
                values: Vec::new(),
            };
            (name, tensor)
        })
        .collect();
    let ckpt =
        LvsmCheckpoint::from_tensors(Path::new("lvsm_scene_decoder_only_res512.pt"), tensors);
    let paper = prism_model::load_config(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/paper.toml"),
    )
    .unwrap()
    .model;
    let (layout, placement) = ckpt.check_fits(&paper, &BlockPlacement::First).unwrap();
    assert_eq!(layout.heads(), 12);
    assert_eq!(placement, (0..24).collect::<Vec<_>>());
    assert_eq!(paper.num_blocks(), 36);
}
