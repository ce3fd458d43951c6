//! Forward pass of the Gaussian rasterizer against closed-form expectations.

use crate::common;

use common::{Scene, axis_camera, device, host, orbit_camera};
use prism_render::RenderError;
use prism_render::splat::{MIN_ALPHA, Rendered, background, render};

fn pixel(r: &[f32], c: usize, h: usize, w: usize, y: usize, x: usize) -> f32 {
    r[(c * h + y) * w + x]
}

/// The expected alpha of a 2D Gaussian of covariance `cov` (with the dilation included) at
/// offset `(dx, dy)`, including the 3-sigma support and the 1/255 cut.
fn analytic_alpha(opacity: f32, cov: [[f32; 2]; 2], dx: f32, dy: f32) -> f32 {
    let det = cov[0][0] * cov[1][1] - cov[0][1] * cov[1][0];
    let (a, b, c) = (cov[1][1] / det, -cov[0][1] / det, cov[0][0] / det);
    let power = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy;
    let alpha = (opacity * (-power).exp()).min(0.99);
    if power > 4.5 || alpha < MIN_ALPHA {
        0.0
    } else {
        alpha
    }
}

fn check_against(r: &Rendered, colour: &[f32], z: f32, expected_alpha: impl Fn(f32, f32) -> f32) {
    let [_, c, h, w] = r.features.dims();
    let (f, a, d) = (
        host(r.features.clone()),
        host(r.alpha.clone()),
        host(r.depth.clone()),
    );
    let mut drawn = 0;
    for y in 0..h {
        for x in 0..w {
            let alpha = expected_alpha(x as f32 + 0.5, y as f32 + 0.5);
            let got = pixel(&a, 0, h, w, y, x);
            assert!(
                (got - alpha).abs() < 2e-6,
                "alpha at ({x}, {y}): {got} vs {alpha}"
            );
            for (k, col) in colour.iter().enumerate().take(c) {
                let got = pixel(&f, k, h, w, y, x);
                assert!(
                    (got - alpha * col).abs() < 2e-6,
                    "feature {k} at ({x}, {y})"
                );
            }
            let depth = pixel(&d, 0, h, w, y, x);
            if alpha > 0.0 {
                drawn += 1;
                assert!((depth - z).abs() < 1e-5, "depth at ({x}, {y}): {depth}");
            } else {
                assert_eq!(depth, 0.0);
            }
        }
    }
    assert!(drawn > 20, "only {drawn} pixels drawn");
}

#[test]
fn one_isotropic_gaussian_renders_to_the_analytic_2d_gaussian() {
    let dev = device();
    // Mean on the optical axis: the EWA Jacobian is exact there, J = diag(f/z).
    let (f, z, s, o) = (50.0f32, 2.0f32, 0.1f32, 0.8f32);
    let colour = [0.2, 0.5, 0.9];
    let mut scene = Scene::new(1, 3);
    // Any rotation leaves an isotropic Gaussian unchanged.
    scene.push(
        [0.0, 0.0, z],
        [s.ln(); 3],
        [0.3, -0.5, 0.7, 0.2],
        o,
        &colour,
    );
    let camera = axis_camera(f, 20.3, 17.8, 40, 36);
    let r = render(&scene.tensors(&dev), &[camera]).unwrap();
    let var = (f * s / z).powi(2) + 0.3;
    check_against(&r, &colour, z, |px, py| {
        analytic_alpha(o, [[var, 0.0], [0.0, var]], px - 20.3, py - 17.8)
    });
}

#[test]
fn an_anisotropic_gaussian_turned_about_the_view_axis_turns_in_the_image() {
    let dev = device();
    let (f, z, o) = (40.0f32, 1.5f32, 0.7f32);
    let (sx, sy) = (0.12f32, 0.04f32);
    let theta = 0.6f32;
    let mut scene = Scene::new(1, 1);
    // A rotation by theta about +z (the camera's view axis): x turns towards y (down).
    scene.push(
        [0.0, 0.0, z],
        [sx.ln(), sy.ln(), (0.05f32).ln()],
        [(theta / 2.0).cos(), 0.0, 0.0, (theta / 2.0).sin()],
        o,
        &[1.0],
    );
    let camera = axis_camera(f, 24.0, 24.0, 48, 48);
    let r = render(&scene.tensors(&dev), &[camera]).unwrap();
    let (a, b) = ((f * sx / z).powi(2), (f * sy / z).powi(2));
    let (cs, sn) = (theta.cos(), theta.sin());
    let cov = [
        [cs * cs * a + sn * sn * b + 0.3, cs * sn * (a - b)],
        [cs * sn * (a - b), sn * sn * a + cs * cs * b + 0.3],
    ];
    check_against(&r, &[1.0], z, |px, py| {
        analytic_alpha(o, cov, px - 24.0, py - 24.0)
    });
}

/// A few Gaussians around the optical axis; moving the principal point moves their images by
/// exactly that much without changing their shapes.
fn cluster() -> Scene {
    let mut scene = Scene::new(1, 2);
    let q = [0.9, 0.1, -0.3, 0.25];
    scene.push([0.0, 0.0, 2.0], [-2.8, -3.3, -3.0], q, 0.9, &[1.0, 0.2]);
    scene.push(
        [0.05, -0.03, 1.8],
        [-3.1, -2.9, -3.4],
        [1.0, 0.0, 0.0, 0.0],
        0.6,
        &[0.3, 0.8],
    );
    scene.push(
        [-0.04, 0.02, 2.4],
        [-2.7, -3.4, -2.5],
        [0.5, 0.5, 0.5, -0.5],
        0.75,
        &[0.5, 0.5],
    );
    scene.push([0.02, 0.06, 2.1], [-3.5, -3.5, -3.5], q, 0.95, &[0.9, 0.1]);
    scene
}

#[test]
fn gaussians_straddling_tile_borders_render_like_gaussians_inside_a_tile() {
    let dev = device();
    let scene = cluster().tensors(&dev);
    // Principal point on the corner of four tiles, and in the middle of tile (2, 2).
    let straddling = axis_camera(50.0, 16.0, 16.0, 64, 64);
    let inside = axis_camera(50.0, 40.0, 40.0, 64, 64);
    let a = render(&scene, &[straddling]).unwrap();
    let b = render(&scene, &[inside]).unwrap();
    let (fa, fb) = (host(a.features.clone()), host(b.features.clone()));
    let (aa, ab) = (host(a.alpha.clone()), host(b.alpha.clone()));
    let (h, w) = (64, 64);
    let mut drawn = 0;
    for y in 0..h {
        for x in 0..w {
            let (xs, ys) = (x + 24, y + 24);
            let va = pixel(&aa, 0, h, w, y, x);
            let vb = if xs < w && ys < h {
                pixel(&ab, 0, h, w, ys, xs)
            } else {
                0.0
            };
            assert!((va - vb).abs() < 1e-6, "alpha at ({x}, {y}): {va} vs {vb}");
            if va > 0.0 {
                drawn += 1;
                for c in 0..2 {
                    let (ga, gb) = (pixel(&fa, c, h, w, y, x), pixel(&fb, c, h, w, ys, xs));
                    assert!((ga - gb).abs() < 1e-6);
                }
            }
        }
    }
    // The cluster covers all four tiles around the corner.
    assert!(drawn > 50, "{drawn}");
    for (x, y) in [(14, 14), (17, 14), (14, 17), (17, 17)] {
        assert!(pixel(&aa, 0, h, w, y, x) > 0.1);
    }
    // And the other image stays inside tile (2, 2), pixels 32..48.
    for y in 0..h {
        for x in 0..w {
            if pixel(&ab, 0, h, w, y, x) > 0.0 {
                assert!((32..48).contains(&x) && (32..48).contains(&y), "({x}, {y})");
            }
        }
    }
}

#[test]
fn front_to_back_compositing_with_occlusion_and_input_order_independence() {
    let dev = device();
    let camera = axis_camera(40.0, 16.0, 16.0, 32, 32);
    let (o1, o2) = (0.6f32, 0.7f32);
    let near = ([0.0, 0.0, 1.0], [-2.0; 3], o1, [1.0, 0.0, 0.25]);
    let far = ([0.0, 0.0, 3.0], [-1.0; 3], o2, [0.0, 1.0, 0.5]);
    type Blob = ([f32; 3], [f32; 3], f32, [f32; 3]);
    let render_in = |order: [&Blob; 2]| {
        let mut scene = Scene::new(1, 3);
        for (m, s, o, f) in order {
            scene.push(*m, *s, [1.0, 0.0, 0.0, 0.0], *o, f);
        }
        render(&scene.tensors(&dev), &[camera]).unwrap()
    };
    let r1 = render_in([&near, &far]);
    let r2 = render_in([&far, &near]);
    let (h, w) = (32, 32);
    let f = host(r1.features.clone());
    assert_eq!(f, host(r2.features.clone()));
    // The pixel whose centre is the common projected centre (16.5, 16.5) is 0.5 px off both.
    let g = |o: f32, s: f32, z: f32| {
        let var = (40.0 * s / z).powi(2) + 0.3;
        o * (-0.5 * 0.5 / var).exp()
    };
    let (a1, a2) = (g(o1, (-2.0f32).exp(), 1.0), g(o2, (-1.0f32).exp(), 3.0));
    for c in 0..3 {
        let expected = a1 * near.3[c] + (1.0 - a1) * a2 * far.3[c];
        assert!((pixel(&f, c, h, w, 16, 16) - expected).abs() < 1e-6);
    }
    let alpha = pixel(&host(r1.alpha.clone()), 0, h, w, 16, 16);
    assert!((alpha - (1.0 - (1.0 - a1) * (1.0 - a2))).abs() < 1e-6);
    let depth = pixel(&host(r1.depth.clone()), 0, h, w, 16, 16);
    let expected = (a1 * 1.0 + (1.0 - a1) * a2 * 3.0) / alpha;
    assert!((depth - expected).abs() < 1e-5);
}

#[test]
fn compositing_stops_before_the_transmittance_falls_below_1e_4() {
    let dev = device();
    let camera = axis_camera(40.0, 8.0, 8.0, 16, 16);
    let mut scene = Scene::new(1, 1);
    // Large, nearly flat Gaussians: alpha ~ 0.95 at the centre pixel, 1.0e-4 < T after three
    // of them, and the fourth would take T to ~6e-6: it must not be drawn (its feature is huge).
    for (k, f) in [1.0f32, 2.0, 3.0, 1000.0].iter().enumerate() {
        scene.push(
            [0.0, 0.0, 1.0 + k as f32],
            [2.0; 3],
            [1.0, 0.0, 0.0, 0.0],
            0.95,
            &[*f],
        );
    }
    let r = render(&scene.tensors(&dev), &[camera]).unwrap();
    let v = pixel(&host(r.features), 0, 16, 16, 8, 8);
    let a = pixel(&host(r.alpha), 0, 16, 16, 8, 8);
    // Each alpha is 0.95 * exp(-tiny) ~ 0.95.
    let expected = 0.95 * (1.0 + 0.05 * 2.0 + 0.05 * 0.05 * 3.0);
    assert!((v - expected).abs() < 1e-3, "{v} vs {expected}");
    assert!((a - (1.0 - 0.05f32.powi(3))).abs() < 1e-4, "{a}");
}

#[test]
fn a_batch_renders_each_element_in_its_own_camera() {
    let dev = device();
    let mut one = cluster();
    let cams = [
        orbit_camera(24, 20, 30.0, 10.0, 5.0),
        orbit_camera(24, 20, 30.0, -20.0, -8.0),
    ];
    // Batch element 1 holds the same Gaussians moved into the orbit's centre.
    for m in one.means.chunks_mut(3) {
        m[1] += 0.9;
        m[2] -= 2.0;
    }
    let mut two = one.clone();
    two.batch = 2;
    for v in two.kinds_mut() {
        let copy = v.1.clone();
        v.1.extend(copy);
    }
    let batched = render(&two.tensors(&dev), &cams).unwrap();
    let bf = host(batched.features);
    let n = bf.len() / 2;
    for (b, cam) in cams.iter().enumerate() {
        let single = host(render(&one.tensors(&dev), &[*cam]).unwrap().features);
        assert_eq!(&bf[b * n..(b + 1) * n], &single[..]);
        assert!(single.iter().any(|&v| v > 0.05));
    }
}

#[test]
fn over_composites_the_background_behind_the_gaussians() {
    let dev = device();
    let mut scene = Scene::new(1, 3);
    scene.push(
        [0.0, 0.0, 2.0],
        [-2.0; 3],
        [1.0, 0.0, 0.0, 0.0],
        0.8,
        &[1.0, 0.0, 0.0],
    );
    let r = render(&scene.tensors(&dev), &[axis_camera(30.0, 8.0, 8.0, 16, 16)]).unwrap();
    let image = host(r.over(background(&[0.0, 0.0, 1.0], &dev)));
    let alpha = host(r.alpha);
    for (i, a) in alpha.iter().enumerate() {
        assert!((image[i] - a).abs() < 1e-6);
        assert!(image[256 + i].abs() < 1e-6);
        assert!((image[512 + i] - (1.0 - a)).abs() < 1e-6);
    }
    assert_eq!(image[2 * 256], 1.0, "a corner pixel shows the background");
}

#[test]
fn gaussians_behind_the_camera_or_on_its_plane_are_not_drawn() {
    let dev = device();
    let mut scene = Scene::new(1, 1);
    scene.push(
        [0.0, 0.0, -1.0],
        [0.0; 3],
        [1.0, 0.0, 0.0, 0.0],
        0.9,
        &[1.0],
    );
    scene.push([0.0, 0.0, 0.0], [0.0; 3], [1.0, 0.0, 0.0, 0.0], 0.9, &[1.0]);
    let r = render(&scene.tensors(&dev), &[axis_camera(30.0, 8.0, 8.0, 16, 16)]).unwrap();
    assert!(host(r.alpha).iter().all(|&a| a == 0.0));
}

#[test]
fn mismatched_inputs_are_clear_errors() {
    let dev = device();
    let scene = cluster();
    let cam = axis_camera(30.0, 8.0, 8.0, 16, 16);
    let err = render(&scene.tensors(&dev), &[cam, cam]).unwrap_err();
    assert!(matches!(err, RenderError::Input(_)), "{err}");
    assert!(
        err.to_string().contains("2 cameras for a batch of 1"),
        "{err}"
    );
    let mut g = scene.tensors(&dev);
    g.rotations = g.rotations.narrow(2, 0, 3);
    let err = render(&g, &[cam]).unwrap_err();
    assert!(err.to_string().contains("rotations"), "{err}");
    let mut two = scene.clone();
    two.batch = 2;
    for v in two.kinds_mut() {
        let copy = v.1.clone();
        v.1.extend(copy);
    }
    let other = axis_camera(30.0, 8.0, 8.0, 16, 17);
    let err = render(&two.tensors(&dev), &[cam, other]).unwrap_err();
    assert!(err.to_string().contains("16x16 and 16x17"), "{err}");
}
