//! The GPU flash-attention kernels (wgpu) against matmul-softmax-matmul on flex: values, every
//! input's gradient, finite differences of the kernels' own forward pass, half precision; and
//! the memory a training step keeps on the adapter at two sequence lengths, against the size of
//! the scores that matmul-softmax-matmul would keep. The strided
//! inputs the model makes (slices of one projection, axes swapped) go through them in
//! [`super::backend`], which runs the tiny model's forward pass and training step on them.
//!
//! Runs in the default build (the `wgpu` feature) on a machine with a Vulkan/Metal/DX12 adapter
//! (Mesa's lavapipe is enough): `cargo test --release --test cli -- device::flash_attention`.
//! With `PRISM_REQUIRE_WGPU` set, a missing adapter is a failure instead of a skip.
#![cfg(feature = "wgpu")]

use crate::common;

use burn::tensor::{DType, Device, Distribution, Tensor};
use prism_kernels::device::{flash, supported};
use prism_kernels::unfused;

fn values<const D: usize>(x: Tensor<D>) -> Vec<f32> {
    x.into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .unwrap()
}

/// Asserts `|got - want| <= floor + rel |want|` entry by entry, naming the worst entry.
fn assert_close(what: &str, got: &[f32], want: &[f32], floor: f32, rel: f32) {
    assert_eq!(got.len(), want.len(), "{what}: lengths differ");
    let mut worst = (0usize, 0.0f32);
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        let excess = (g - w).abs() - (floor + rel * w.abs());
        assert!(g.is_finite(), "{what}[{i}] = {g}");
        if excess > worst.1 {
            worst = (i, excess);
        }
    }
    let i = worst.0;
    assert!(
        worst.1 <= 0.0,
        "{what}[{i}]: got {}, want {} (floor {floor}, relative {rel})",
        got[i],
        want[i]
    );
}

/// Shapes `[B, H, T, D]`: sequences shorter than a tile, not a multiple of the tiles, and
/// longer than two 64-row blocks; head widths of the configs (16 and 64) and the widest (128).
/// (Each head width compiles its own kernels, slow on a software adapter; the half-precision
/// test covers width 32.)
const SHAPES: [[usize; 4]; 3] = [[2, 3, 37, 16], [1, 2, 70, 64], [1, 1, 130, 128]];

/// Random directions each input's gradient is checked along by finite differences.
const DIRECTIONS: usize = 4;

fn random(shape: [usize; 4], device: &Device) -> Tensor<4> {
    Tensor::random(shape, Distribution::Normal(0.0, 1.0), device)
}

/// `x` copied to flex, where the references run: matmul-softmax-matmul on the CPU is a path
/// independent of the adapter's, and it autotunes no matrix product on the adapter (on a
/// software adapter each candidate kernel is a compile: minutes for the shapes here).
fn on_flex(x: &Tensor<4>) -> Tensor<4> {
    Tensor::from_data(x.to_data(), &Device::flex())
}

/// `(output, dq, dk, dv)` of `sum(f(q, k, v) * w)` on `device`'s autodiff twin.
fn forward_and_grads(
    f: fn(Tensor<4>, Tensor<4>, Tensor<4>) -> Tensor<4>,
    inputs: &[Tensor<4>; 3],
    weights: &Tensor<4>,
) -> [Vec<f32>; 4] {
    let ad = inputs[0].device().autodiff();
    let [q, k, v] = inputs
        .clone()
        .map(|x| Tensor::<4>::from_data(x.into_data(), &ad).require_grad());
    let w = Tensor::<4>::from_data(weights.to_data(), &ad);
    let out = f(q.clone(), k.clone(), v.clone());
    let grads = (out.clone() * w).sum().backward();
    let grad = |x: &Tensor<4>| values(x.grad(&grads).expect("a gradient"));
    [values(out), grad(&q), grad(&k), grad(&v)]
}

#[test]
#[cfg_attr(not(wgpu_adapter), ignore = "no wgpu adapter on this machine")]
fn flash_attention_matches_unfused_attention_values_and_gradients() {
    let _guard = common::device_shared();
    let Some(device) = common::wgpu_device() else {
        return;
    };
    for (i, shape) in SHAPES.into_iter().enumerate() {
        device.seed(10 + i as u64);
        let inputs = [0, 1, 2].map(|_| random(shape, &device));
        assert!(supported(&inputs[0], &inputs[1], &inputs[2]));
        let [q, k, v] = inputs.clone();
        let got = values(flash(q, k, v));
        let reference_inputs = inputs.clone().map(|x| on_flex(&x));
        let [q, k, v] = reference_inputs.clone();
        let want = values(unfused::attention(q, k, v));
        assert_close(&format!("{shape:?} output"), &got, &want, 1e-5, 1e-4);

        let weights = random(shape, &device);
        let flash_run = forward_and_grads(flash, &inputs, &weights);
        let reference =
            forward_and_grads(unfused::attention, &reference_inputs, &on_flex(&weights));
        for (name, (got, want)) in ["output", "dq", "dk", "dv"]
            .iter()
            .zip(flash_run.iter().zip(&reference))
        {
            assert_close(&format!("{shape:?} {name}"), got, want, 1e-5, 1e-3);
        }
    }
}

#[test]
#[cfg_attr(not(wgpu_adapter), ignore = "no wgpu adapter on this machine")]
fn flash_gradients_match_finite_differences_of_its_forward_pass() {
    let _guard = common::device_shared();
    let Some(device) = common::wgpu_device() else {
        return;
    };
    // The head width of the first shape of `SHAPES`, whose kernels are then compiled once.
    let shape = [1, 1, 6, 16];
    device.seed(21);
    let inputs = [0, 1, 2].map(|_| random(shape, &device));
    let weights = random(shape, &device);
    let [_, dq, dk, dv] = forward_and_grads(flash, &inputs, &weights);
    let host: Vec<Vec<f32>> = inputs.iter().map(|x| values(x.clone())).collect();
    let loss = |host: &[Vec<f32>]| -> f64 {
        let [q, k, v] = [0, 1, 2].map(|i| {
            Tensor::<4>::from_data(
                burn::tensor::TensorData::new(host[i].clone(), shape),
                &device,
            )
        });
        let out = flash(q, k, v) * weights.clone();
        out.sum().into_scalar::<f32>() as f64
    };
    // Central differences along random directions: each direction moves every entry of an
    // input at once, so a wrong entry anywhere in a gradient shows in its projection, at two
    // forward passes a direction instead of two an entry (each a round trip to the device).
    let h = 1e-2f32;
    for (input, analytic) in [dq, dk, dv].iter().enumerate() {
        for direction in 0..DIRECTIONS {
            let d = values(random(shape, &device));
            let moved = |sign: f32| {
                let mut moved = host.clone();
                for (x, v) in moved[input].iter_mut().zip(&d) {
                    *x += sign * h * v;
                }
                moved
            };
            let numeric = (loss(&moved(1.0)) - loss(&moved(-1.0))) / (2.0 * f64::from(h));
            let terms = analytic
                .iter()
                .zip(&d)
                .map(|(&g, &v)| f64::from(g) * f64::from(v));
            let along: f64 = terms.clone().sum();
            let scale: f64 = terms.map(f64::abs).sum();
            assert!(
                (along - numeric).abs() <= 1e-3 + 5e-3 * scale,
                "input {input}, direction {direction}: analytic {along}, finite difference \
                 {numeric} (scale {scale})"
            );
        }
    }
}

#[test]
#[cfg_attr(not(wgpu_adapter), ignore = "no wgpu adapter on this machine")]
fn half_precision_flash_attention_stays_close_to_f32() {
    let _guard = common::device_shared();
    let Some(device) = common::wgpu_device() else {
        return;
    };
    for dtype in [DType::F16, DType::BF16] {
        if !device.supports_dtype(dtype) {
            eprintln!("{dtype:?}: not supported by this adapter, not checked");
            continue;
        }
        let shape = [1, 2, 45, 32];
        device.seed(5);
        let inputs = [0, 1, 2].map(|_| random(shape, &device));
        let weights = random(shape, &device);
        let half = inputs.clone().map(|x| x.cast(dtype));
        assert!(supported(&half[0], &half[1], &half[2]));
        let run = forward_and_grads(flash, &half, &weights.clone().cast(dtype));
        let reference = forward_and_grads(
            unfused::attention,
            &inputs.map(|x| on_flex(&x)),
            &on_flex(&weights),
        );
        // Inputs rounded to 8 (bf16) or 11 (f16) significant bits, f32 sums inside.
        let (floor, rel) = if dtype == DType::BF16 {
            (4e-2, 4e-2)
        } else {
            (5e-3, 5e-3)
        };
        for (name, (got, want)) in ["output", "dq", "dk", "dv"]
            .iter()
            .zip(run.iter().zip(&reference))
        {
            assert_close(&format!("{dtype:?} {name}"), got, want, floor, rel);
        }
    }
}

/// Bytes the device's pools hold in live allocations once everything queued has run.
fn bytes_in_use(device: &Device) -> u64 {
    device.sync().expect("the device runs");
    device
        .memory_pool_usage()
        .expect("a pooled device")
        .bytes_in_use
}

/// The bytes flash attention's forward pass keeps for its backward pass (graph alive, inputs
/// allocated before), and the bytes in use once the gradients exist, for `heads` heads of
/// `tokens` tokens of width [`MEMORY_WIDTH`].
fn step_memory(device: &Device, heads: usize, tokens: usize) -> (u64, u64) {
    let ad = device.clone().autodiff();
    let shape = [1, heads, tokens, MEMORY_WIDTH];
    let [q, k, v] = [0, 1, 2]
        .map(|_| Tensor::<4>::random(shape, Distribution::Normal(0.0, 1.0), &ad).require_grad());
    let before = bytes_in_use(device);
    let loss = flash(q.clone(), k.clone(), v.clone()).sum();
    let kept = bytes_in_use(device) - before;
    let grads = loss.backward();
    let after = bytes_in_use(device) - before;
    drop(grads);
    (kept, after)
}

/// The head width of the memory test.
const MEMORY_WIDTH: usize = 16;

#[test]
#[cfg_attr(not(wgpu_adapter), ignore = "no wgpu adapter on this machine")]
fn training_memory_grows_linearly_in_tokens() {
    let _alone = common::device_alone();
    let Some(device) = common::wgpu_device() else {
        return;
    };
    let (heads, short, long) = (4, 256, 1024);
    let flash_short = step_memory(&device, heads, short);
    let flash_long = step_memory(&device, heads, long);
    eprintln!(
        "bytes kept by the forward pass at {short} / {long} tokens: {} / {}",
        flash_short.0, flash_long.0
    );
    // The counter sees the forward pass's allocations: at least its output is kept.
    let output = |tokens: usize| (heads * tokens * MEMORY_WIDTH * 4) as u64;
    assert!(
        flash_short.0 >= output(short) && flash_long.0 >= output(long),
        "the kept bytes ({} / {}) are below the output's ({} / {}): the counter misses \
         allocations",
        flash_short.0,
        flash_long.0,
        output(short),
        output(long)
    );
    // 4x the tokens: linear memory grows 4x, the T x T scores 16x.
    let ratio = |long: u64, short: u64| long as f64 / short.max(1) as f64;
    let flash_kept = ratio(flash_long.0, flash_short.0);
    let flash_after = ratio(flash_long.1, flash_short.1);
    assert!(
        flash_kept < 6.0 && flash_after < 6.0,
        "flash attention's memory grew {flash_kept:.1}x (kept) and {flash_after:.1}x (with \
         gradients) for 4x the tokens"
    );
    // At 1024 tokens, the scores alone (heads x 1024^2 x 4 bytes, what matmul-softmax-matmul
    // keeps) dwarf flash's whole state.
    let scores = (heads * long * long * 4) as u64;
    assert!(
        flash_long.0 * 8 < scores,
        "flash kept {} bytes at {long} tokens; the scores are {scores}",
        flash_long.0
    );
}
