//! Each fused kernel against the composition of Burn ops it replaces: values (inference and
//! autodiff) and the gradients of every input, on ndarray and flex.

// burn-ndarray is deprecated upstream, but the project's tests run on it.
#![allow(deprecated)]

use burn::module::Module;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::{LinearConfig, PaddingConfig2d};
use burn::tensor::{Device, Distribution, Tensor};
use prism_kernels::{
    Bf16Kernel, FeatureMap, Mixing, attention, attention_bf16, conv2d, gelu, is_fused,
    is_fused_conv2d, layer_norm, linear, matmul_bf16, matmul_left, max_pool2d, rms_norm,
    self_attention, unfused,
};

fn devices() -> [(&'static str, Device); 2] {
    [("ndarray", Device::ndarray()), ("flex", Device::flex())]
}

fn values<const D: usize>(x: Tensor<D>) -> Vec<f32> {
    x.into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .unwrap()
}

fn max_diff<const D: usize>(a: Tensor<D>, b: Tensor<D>) -> f32 {
    assert_eq!(a.dims(), b.dims());
    values(a)
        .iter()
        .zip(values(b))
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

fn random<const D: usize>(shape: [usize; D], device: &Device) -> Tensor<D> {
    Tensor::random(shape, Distribution::Normal(0.0, 1.0), device)
}

/// Compares `fused` with `reference` on the inputs: the values without autodiff, then the
/// values and every input's gradient of `sum(f(inputs) * w)` under autodiff.
fn check<const D: usize, const N: usize>(
    name: &str,
    shapes: [Vec<usize>; N],
    fused: impl Fn([Tensor<D>; N]) -> Tensor<D>,
    reference: impl Fn([Tensor<D>; N]) -> Tensor<D>,
    tolerance: f32,
) {
    for (backend, device) in devices() {
        device.seed(3);
        let inputs: [Tensor<D>; N] = shapes.clone().map(|s| {
            let t: Tensor<D> = Tensor::random(s, Distribution::Normal(0.0, 1.0), &device);
            t
        });
        assert!(
            is_fused(&inputs[0]),
            "{name} on {backend}: the fused path must be taken"
        );
        let err = max_diff(fused(inputs.clone()), reference(inputs.clone()));
        assert!(
            err < tolerance,
            "{name} on {backend}: forward differs by {err}"
        );

        let ad = device.autodiff();
        let tracked = || {
            inputs
                .clone()
                .map(|t| Tensor::from_data(t.into_data(), &ad).require_grad())
        };
        let (a, b) = (tracked(), tracked());
        let (ya, yb) = (fused(a.clone()), reference(b.clone()));
        let weights = Tensor::<D>::random(ya.dims(), Distribution::Normal(0.0, 1.0), &ad);
        let err = max_diff(ya.clone().inner(), yb.clone().inner());
        assert!(
            err < tolerance,
            "{name} on {backend} (autodiff): forward differs by {err}"
        );
        let (ga, gb) = (
            (ya * weights.clone()).sum().backward(),
            (yb * weights).sum().backward(),
        );
        for (i, (xa, xb)) in a.iter().zip(&b).enumerate() {
            let (da, db) = (xa.grad(&ga).unwrap(), xb.grad(&gb).unwrap());
            let scale = values(db.clone())
                .iter()
                .fold(1.0f32, |m, v| m.max(v.abs()));
            let err = max_diff(da, db) / scale;
            assert!(
                err < tolerance,
                "{name} on {backend}: gradient of input {i} differs by {err} (relative)"
            );
        }
    }
}

#[test]
fn gelu_matches_burn() {
    // The reference is GELU composed from `erf`: Burn's own `gelu` differentiates the tanh
    // approximation on ndarray (its default `gelu_backward`), 7e-4 off the exact derivative.
    let exact =
        |x: Tensor<3>| x.clone() * 0.5 * ((x * std::f64::consts::FRAC_1_SQRT_2).erf() + 1.0);
    check::<3, 1>(
        "gelu",
        [vec![3, 70, 33]],
        |[x]| gelu(x * 3.0),
        |[x]| exact(x * 3.0),
        2e-6,
    );
    // A tracked input that another tensor still holds: GELU and its kept derivative go into
    // new buffers, and the input is left for its other reader.
    check::<3, 1>(
        "gelu of a shared input",
        [vec![3, 70, 33]],
        |[x]| {
            let h = x * 3.0;
            gelu(h.clone()) + h
        },
        |[x]| {
            let h = x * 3.0;
            exact(h.clone()) + h
        },
        2e-6,
    );
    // One chunk of the host kernel, and several with a partial last one (a shared input is
    // read into a new buffer chunk by chunk).
    for (backend, device) in devices() {
        for shape in [[5, 40], [5, 8003]] {
            let x = random(shape, &device) * 3.0;
            let want = unfused::gelu(x.clone());
            // A shared input is left as it was; one no one else holds may be overwritten.
            let before = x.to_data();
            let shared = gelu(x.clone());
            assert_eq!(
                x.to_data(),
                before,
                "gelu on {backend} {shape:?} changed its shared input"
            );
            for (case, y) in [("shared", shared), ("owned", gelu(x))] {
                let err = max_diff(y, want.clone());
                assert!(
                    err < 2e-6,
                    "gelu on {backend} {shape:?} ({case} input): differs from Burn's by {err}"
                );
            }
        }
    }
}

#[test]
fn layer_norm_matches_burn() {
    check::<3, 1>(
        "layer_norm",
        [vec![2, 37, 48]],
        |[x]| layer_norm(x.clone() * 2.0 + 1.0, gamma_of(&x), 1e-5),
        |[x]| unfused::layer_norm(x.clone() * 2.0 + 1.0, gamma_of(&x), 1e-5),
        2e-5,
    );
}

#[test]
fn rms_norm_matches_burn() {
    check::<4, 1>(
        "rms_norm",
        [vec![2, 3, 37, 16]],
        |[x]| rms_norm(x.clone() * 2.0 + 1.0, gamma_of(&x), 1e-5),
        |[x]| unfused::rms_norm(x.clone() * 2.0 + 1.0, gamma_of(&x), 1e-5),
        2e-5,
    );
}

/// A gain vector that depends on `x` (so that its gradient is checked too): the mean of `x`
/// over every dimension but the last, plus one.
fn gamma_of<const D: usize>(x: &Tensor<D>) -> Tensor<1> {
    let d = x.dims()[D - 1];
    x.clone().reshape([-1, d as i32]).mean_dim(0).reshape([d]) + 1.0
}

#[test]
fn attention_matches_burn() {
    // 150 tokens: two full query blocks and a partial one.
    let shape = vec![2, 3, 150, 16];
    check::<4, 3>(
        "attention",
        [shape.clone(), shape.clone(), shape],
        |[q, k, v]| attention(q * 2.0, k, v),
        |[q, k, v]| unfused::attention(q * 2.0, k, v),
        2e-5,
    );
}

#[test]
fn attention_takes_strided_inputs() {
    // Transposed views are read through a contiguous copy.
    check::<4, 3>(
        "attention on transposed inputs",
        [vec![1, 2, 16, 40], vec![1, 2, 16, 40], vec![1, 2, 16, 40]],
        |[q, k, v]| attention(q.swap_dims(2, 3), k.swap_dims(2, 3), v.swap_dims(2, 3)),
        |[q, k, v]| unfused::attention(q.swap_dims(2, 3), k.swap_dims(2, 3), v.swap_dims(2, 3)),
        2e-5,
    );
}

/// The joint self-attention against Burn's ops (permute, narrow, QK-norm, attention, merge),
/// softmax and linear with both feature maps: values, and the gradients of `qkv` and of both
/// gains. 70 tokens: a full query block and a partial one; 2 heads of 16.
#[test]
fn self_attention_matches_burn() {
    let gain = |g: Tensor<3>| g.reshape([16]) + 1.0;
    let linear = |feature_map| Mixing::Linear {
        feature_map,
        eps: 1e-6,
    };
    let mixings = [
        Mixing::Softmax { bf16: false },
        linear(FeatureMap::Relu),
        linear(FeatureMap::Elu1),
    ];
    for mixing in mixings {
        check::<3, 3>(
            &format!("self_attention ({mixing:?})"),
            [vec![2, 70, 96], vec![1, 1, 16], vec![1, 1, 16]],
            |[qkv, q_gain, k_gain]| {
                self_attention(qkv * 2.0, gain(q_gain), gain(k_gain), 2, 1e-5, mixing)
            },
            |[qkv, q_gain, k_gain]| {
                unfused::self_attention(qkv * 2.0, gain(q_gain), gain(k_gain), 2, 1e-5, mixing)
            },
            2e-5,
        );
    }
}

/// With `bf16`, the joint kernel gives what the composition gives around the bf16 attention
/// (the same host kernels on the same values), whichever bf16 kernel this CPU runs.
#[test]
fn self_attention_in_bf16_matches_the_composition() {
    for (backend, device) in devices() {
        let qkv = random([1, 45, 3 * 3 * 8], &device);
        let (q_gain, k_gain) = (random([8], &device), random([8], &device));
        let bf16 = Mixing::Softmax { bf16: true };
        let got = self_attention(qkv.clone(), q_gain.clone(), k_gain.clone(), 3, 1e-5, bf16);
        let want = unfused::heads_attention(qkv, 3, |q, k, v| {
            attention_bf16(rms_norm(q, q_gain, 1e-5), rms_norm(k, k_gain, 1e-5), v)
        });
        let err = max_diff(got, want);
        assert!(
            err < 1e-6,
            "bf16 self-attention on {backend}: differs by {err}"
        );
    }
}

/// `linear` against Burn's `Linear` on a 3D input, with and without bias and at a size that
/// runs one thread and one that runs several: values, and the gradients of the input, the
/// weight and the bias.
#[test]
fn linear_matches_burn() {
    for (backend, device) in devices() {
        device.seed(6);
        let ad = device.clone().autodiff();
        for ([b, t, k, n], bias) in [([2, 5, 7, 3], true), ([3, 70, 64, 96], false)] {
            let name = format!("linear {k}->{n} on {backend}, bias {bias}");
            let layer = LinearConfig::new(k, n).with_bias(bias).init(&ad);
            let x = random([b, t, k], &ad).require_grad();
            assert!(is_fused(&x), "{name}: the fused path must be taken");
            let plain = layer.valid();
            let err = max_diff(
                linear(&plain, x.clone().inner()),
                plain.forward(x.clone().inner()),
            );
            assert!(err < 1e-5, "{name}: forward differs by {err}");
            let (ya, yb) = (linear(&layer, x.clone()), layer.forward(x.clone()));
            let err = max_diff(ya.clone(), yb.clone());
            assert!(err < 1e-5, "{name} (autodiff): forward differs by {err}");
            let w = random(ya.dims(), &ad);
            let (ga, gb) = ((ya * w.clone()).sum().backward(), (yb * w).sum().backward());
            let err = max_diff(x.grad(&ga).unwrap(), x.grad(&gb).unwrap());
            assert!(err < 1e-4, "{name}: dx differs by {err}");
            let weight = layer.weight.val();
            let err = max_diff(weight.grad(&ga).unwrap(), weight.grad(&gb).unwrap());
            assert!(err < 1e-4, "{name}: dweight differs by {err}");
            if let Some(bias) = &layer.bias {
                let bias = bias.val();
                let err = max_diff(bias.grad(&ga).unwrap(), bias.grad(&gb).unwrap());
                assert!(err < 1e-4, "{name}: dbias differs by {err}");
            }
        }
    }
}

/// `matmul_left` (`w x_b + bias` per batch item) against Burn's batched matmul, on ndarray and
/// flex: values, and the gradients of `x`, `w` and the bias; and with a constant `w` and no
/// bias (the DPT's upsampling along the height).
#[test]
fn matmul_left_matches_burn() {
    for (backend, device) in devices() {
        device.seed(8);
        let ad = device.clone().autodiff();
        for ([b, c, n, o], tracked) in [([2, 5, 7, 3], true), ([3, 16, 130, 32], false)] {
            let name = format!("matmul_left {c}->{o} on {backend}, tracked w {tracked}");
            let x = random([b, c, n], &ad).require_grad();
            assert!(is_fused(&x), "{name}: the fused path must be taken");
            let (w, bias) = (random([o, c], &ad), random([o], &ad));
            let (w, bias) = if tracked {
                (w.require_grad(), Some(bias.require_grad()))
            } else {
                (w, None)
            };
            let ya = matmul_left(w.clone(), x.clone(), bias.clone());
            let yb = w.clone().unsqueeze::<3>().matmul(x.clone());
            let yb = match &bias {
                Some(bias) => yb + bias.clone().reshape([1, o, 1]),
                None => yb,
            };
            assert_eq!(ya.dims(), [b, o, n], "{name}: shape");
            let err = max_diff(ya.clone(), yb.clone());
            assert!(err < 1e-5, "{name}: forward differs by {err}");
            let g = random([b, o, n], &ad);
            let (ga, gb) = ((ya * g.clone()).sum().backward(), (yb * g).sum().backward());
            let err = max_diff(x.grad(&ga).unwrap(), x.grad(&gb).unwrap());
            assert!(err < 1e-4, "{name}: dx differs by {err}");
            if tracked {
                let err = max_diff(w.grad(&ga).unwrap(), w.grad(&gb).unwrap());
                assert!(err < 1e-4, "{name}: dw differs by {err}");
                let bias = bias.unwrap();
                let err = max_diff(bias.grad(&ga).unwrap(), bias.grad(&gb).unwrap());
                assert!(err < 1e-4, "{name}: dbias differs by {err}");
            }
        }
    }
}

/// The convolutions of the DPT head and of LPIPS's AlexNet (3 x 3 same, 11 x 11 with stride 4,
/// 5 x 5, a 1 x 1 without bias), and a rectangular one, against Burn's `Conv2d`: values, and the
/// gradients of the input, weight and bias; with a frozen layer (LPIPS's), the input's alone.
#[test]
fn conv2d_matches_burn() {
    let layers = |device: &Device| -> Vec<(&'static str, Conv2d, [usize; 4])> {
        let config = |i, o, k: [usize; 2]| Conv2dConfig::new([i, o], k);
        vec![
            (
                "3x3 same",
                config(5, 4, [3, 3])
                    .with_padding(PaddingConfig2d::Same)
                    .init(device),
                [2, 5, 9, 7],
            ),
            (
                "11x11 stride 4",
                config(3, 4, [11, 11])
                    .with_stride([4, 4])
                    .with_padding(PaddingConfig2d::Explicit(2, 2, 2, 2))
                    .init(device),
                [2, 3, 23, 19],
            ),
            (
                "5x5",
                config(3, 2, [5, 5])
                    .with_padding(PaddingConfig2d::Explicit(2, 2, 2, 2))
                    .init(device),
                [1, 3, 6, 8],
            ),
            (
                "1x1 without bias",
                config(6, 1, [1, 1]).with_bias(false).init(device),
                [3, 6, 5, 4],
            ),
            (
                "3x2 stride 2x1, padding 0x1",
                config(2, 3, [3, 2])
                    .with_stride([2, 1])
                    .with_padding(PaddingConfig2d::Explicit(0, 1, 0, 1))
                    .init(device),
                [2, 2, 8, 5],
            ),
        ]
    };
    for (backend, device) in devices() {
        device.seed(5);
        let ad = device.clone().autodiff();
        for (name, layer, shape) in layers(&ad) {
            let x = random(shape, &ad).require_grad();
            assert!(
                is_fused_conv2d(&layer, &x),
                "{name} on {backend}: the fused path must be taken"
            );
            let plain = layer.valid();
            let x_plain = x.clone().inner();
            let err = max_diff(conv2d(&plain, x_plain.clone()), plain.forward(x_plain));
            assert!(err < 1e-5, "{name} on {backend}: forward differs by {err}");

            let (ya, yb) = (conv2d(&layer, x.clone()), layer.forward(x.clone()));
            let w = random(ya.dims(), &ad);
            let (ga, gb) = (
                (ya * w.clone()).sum().backward(),
                (yb * w.clone()).sum().backward(),
            );
            let grad = |p: &str, a: Option<Tensor<4>>, b: Option<Tensor<4>>| {
                let (a, b) = (a.expect(p), b.expect(p));
                let err = max_diff(a, b);
                assert!(err < 1e-4, "{name} on {backend}: d{p} differs by {err}");
            };
            grad("x", x.grad(&ga), x.grad(&gb));
            grad(
                "w",
                layer.weight.val().grad(&ga),
                layer.weight.val().grad(&gb),
            );
            if let Some(bias) = &layer.bias {
                let (a, b) = (bias.val().grad(&ga), bias.val().grad(&gb));
                let err = max_diff(a.unwrap(), b.unwrap());
                assert!(err < 1e-4, "{name} on {backend}: dbias differs by {err}");
            }

            let frozen = layer.clone().no_grad();
            let grads = (conv2d(&frozen, x.clone()) * w).sum().backward();
            assert!(frozen.weight.val().grad(&grads).is_none());
            grad("x (frozen layer)", x.grad(&grads), x.grad(&gb));
        }
    }
}

#[test]
fn max_pool2d_matches_burn() {
    use burn::tensor::{module, ops::MaxPoolOptions};
    // LPIPS's pools (3x3 at stride 2, odd sides leaving a column unread), and a window wider
    // than its stride along one axis only.
    for (shape, kernel, stride) in [
        ([2, 3, 31, 31], [3, 3], [2, 2]),
        ([1, 2, 9, 12], [2, 3], [2, 1]),
    ] {
        check::<4, 1>(
            "max_pool2d",
            [shape.to_vec()],
            |[x]| max_pool2d(x, kernel, stride),
            |[x]| module::max_pool2d(x, MaxPoolOptions::new(kernel).with_stride(stride)),
            1e-7,
        );
    }
}

#[test]
fn frozen_inputs_get_no_gradient_and_the_rest_do() {
    for (backend, device) in devices() {
        let ad = device.autodiff();
        let x = random([4, 8], &ad).require_grad();
        let gamma = random([8], &ad);
        let y = layer_norm(x.clone(), gamma.clone(), 1e-5);
        let grads = (y * random([4, 8], &ad)).sum().backward();
        assert!(x.grad(&grads).is_some(), "{backend}: x must get a gradient");
        assert!(
            gamma.grad(&grads).is_none(),
            "{backend}: a constant gain gets none"
        );
    }
}

#[test]
fn other_backends_and_dtypes_take_the_burn_ops() {
    let x = random([2, 4], &Device::flex()).cast(burn::tensor::DType::F16);
    assert!(!is_fused(&x));
    let reference = unfused::gelu(x.clone());
    assert_eq!(max_diff(gelu(x), reference), 0.0);
}

#[test]
fn half_precision_norms_take_their_statistics_in_f32() {
    let device = Device::flex();
    let x = random([3, 64], &device) * 50.0 + 300.0;
    let gamma = random([64], &device);
    let want = unfused::layer_norm(x.clone(), gamma.clone(), 1e-5);
    let half = |t: Tensor<2>| t.cast(burn::tensor::DType::F16);
    let got = layer_norm(half(x), gamma.cast(burn::tensor::DType::F16), 1e-5);
    assert_eq!(got.dtype(), burn::tensor::DType::F16);
    // f16 keeps about 3 digits of the normalised values (|y| up to a few units).
    let err = max_diff(got.cast(burn::tensor::DType::F32), want);
    assert!(err < 2e-2, "f16 LayerNorm differs by {err}");
}

/// The bf16 products against Burn's matmul of the operands cast to bf16 (on flex: ndarray
/// has no bf16), on ndarray and flex: values, and both gradients under autodiff. Burn's
/// reference rounds each gradient to bf16 after its product (the cast's backward pass) where
/// the kernel rounds the output gradient before it, so the gradients agree to bf16's
/// precision, not f32's.
#[test]
fn bf16_matmul_matches_burn() {
    eprintln!("bf16 kernel: {:?}", Bf16Kernel::chosen());
    let reference = Device::flex().autodiff();
    reference.seed(5);
    let (x, w, g) = (
        random([2, 37, 48], &reference).require_grad(),
        random([48, 70], &reference).require_grad(),
        random([2, 37, 70], &reference),
    );
    let want = unfused::matmul_bf16(x.clone(), w.clone());
    let grads = (want.clone() * g.clone()).sum().backward();
    let want = [
        values(want),
        values(x.grad(&grads).unwrap()),
        values(w.grad(&grads).unwrap()),
    ];
    let relative = |got: Vec<f32>, want: &[f32]| {
        let scale = want.iter().fold(1.0f32, |m, v| m.max(v.abs()));
        got.iter()
            .zip(want)
            .map(|(p, q)| (p - q).abs())
            .fold(0.0, f32::max)
            / scale
    };
    for (backend, device) in devices() {
        let on = |t: Tensor<3>| Tensor::<3>::from_data(t.inner().into_data(), &device);
        let plain = matmul_bf16(
            on(x.clone()),
            Tensor::from_data(w.clone().inner().into_data(), &device),
        );
        let err = relative(values(plain), &want[0]);
        assert!(
            err < 1e-6,
            "bf16 matmul on {backend}: forward differs by {err}"
        );

        let ad = device.autodiff();
        let xa = Tensor::<3>::from_data(x.clone().inner().into_data(), &ad).require_grad();
        let wa = Tensor::<2>::from_data(w.clone().inner().into_data(), &ad).require_grad();
        let ga = Tensor::<3>::from_data(g.clone().inner().into_data(), &ad);
        let grads = (matmul_bf16(xa.clone(), wa.clone()) * ga).sum().backward();
        let dx = relative(values(xa.grad(&grads).unwrap()), &want[1]);
        let dw = relative(values(wa.grad(&grads).unwrap()), &want[2]);
        assert!(
            dx < 1e-2 && dw < 1e-2,
            "bf16 matmul on {backend}: gradients differ by {dx}, {dw}"
        );
    }
}

/// On operands and output weights that bf16 holds exactly (multiples of 1/8 up to 4) every
/// product and sum is exact: the values and both gradients equal the f32 products', and
/// central differences with a step of 1/8 (which keeps the operands exact) give the same
/// gradient.
#[test]
fn bf16_matmul_is_exact_where_bf16_holds_the_values() {
    for (backend, device) in devices() {
        let ad = device.clone().autodiff();
        let lattice = |shape: Vec<usize>, seed: u64| {
            device.seed(seed);
            let t = Tensor::<3>::random(shape, Distribution::Uniform(-4.0, 4.0), &device);
            (t * 8.0).round() / 8.0
        };
        let x = lattice(vec![3, 5, 24], 1);
        let w = lattice(vec![1, 24, 40], 2).squeeze_dim::<2>(0);
        let g = lattice(vec![3, 5, 40], 3);
        // In f64 from the (exact) values, so that the sum is exact too.
        let gv = values(g.clone());
        let loss = |x: Tensor<3>| -> f64 {
            let y = values(matmul_bf16(x, w.clone()));
            y.iter().zip(&gv).map(|(a, b)| *a as f64 * *b as f64).sum()
        };
        let exact = x.clone().matmul(w.clone().unsqueeze());
        assert_eq!(
            max_diff(matmul_bf16(x.clone(), w.clone()), exact),
            0.0,
            "{backend}"
        );

        let on_ad = |t: Tensor<3>| Tensor::<3>::from_data(t.into_data(), &ad).require_grad();
        let (xa, xb) = (on_ad(x.clone()), on_ad(x.clone()));
        let wa = Tensor::<2>::from_data(w.clone().into_data(), &ad).require_grad();
        let wb = Tensor::<2>::from_data(w.clone().into_data(), &ad).require_grad();
        let gad = Tensor::<3>::from_data(g.clone().into_data(), &ad);
        let ga = (matmul_bf16(xa.clone(), wa.clone()) * gad.clone())
            .sum()
            .backward();
        let gb = (xb.clone().matmul(wb.clone().unsqueeze()) * gad)
            .sum()
            .backward();
        let dx = xa.grad(&ga).unwrap();
        assert_eq!(
            max_diff(dx.clone(), xb.grad(&gb).unwrap()),
            0.0,
            "{backend}: dx"
        );
        assert_eq!(
            max_diff(wa.grad(&ga).unwrap(), wb.grad(&gb).unwrap()),
            0.0,
            "{backend}: dw"
        );

        let dx = values(dx);
        let h = 0.125;
        for i in [0, 7, 40, 119] {
            let bump = |sign: f32| {
                let mut v = values(x.clone());
                v[i] += sign * h;
                loss(Tensor::from_data(
                    burn::tensor::TensorData::new(v, [3, 5, 24]),
                    &device,
                ))
            };
            let fd = (bump(1.0) - bump(-1.0)) / (2.0 * h as f64);
            assert_eq!(fd, dx[i] as f64, "{backend}: central difference of x[{i}]");
        }
    }
}
