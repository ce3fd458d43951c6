//! The true-depth warp, a baseline: the source view's foreground pixels as Gaussians at the
//! dataset's own 3D points, rendered into each target camera. It shows what a geometric
//! output like `I_gs` gives with the dataset's depth and the source's exact colours, so
//! `prism evaluate` scores it beside copy-source. It is not a bound: how well a splatted warp
//! does depends on its Gaussians' size, so evaluation sweeps the footprints in
//! [`WARP_FOOTPRINTS`] and reports the best.

use burn::tensor::{Device, Tensor};
use prism_data::{FOREGROUND, Sample};
use prism_render::splat::{GaussianCloud, SH_C0, background, render};

/// The sizes `prism evaluate` renders the warp at, in footprints of one source pixel at its
/// distance (isotropic Gaussians): from a tenth of a pixel (sharp, with gaps where the surface
/// stretches) to half a pixel (no gaps, softer); 0.3 and 0.5 are the tiny and small configs'
/// `gs_scale`.
pub const WARP_FOOTPRINTS: [f32; 4] = [0.1, 0.2, 0.3, 0.5];

/// Opacity of a foreground pixel's Gaussian (the largest the keying of `gs_keying` gives).
const WARP_OPACITY: f32 = 0.99;

/// The true-depth warp of each sample's source into its (first) target camera, its Gaussians
/// `footprint` source pixels wide, `[B, 3, H, W]` in [0, 1] over `bg`.
///
/// # Panics
/// If a sample's point map and source image differ in size.
pub fn true_depth_warp(
    samples: &[Sample],
    bg: [f32; 3],
    footprint: f32,
    device: &Device,
) -> Tensor<4> {
    let images = samples
        .iter()
        .map(|sample| {
            let camera = sample.targets[0].camera;
            let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
            let fill = background(&bg, device);
            let cloud = source_cloud(sample, footprint);
            if cloud.means.is_empty() {
                return fill
                    .reshape([1, 3, 1, 1])
                    .expand([1, 3, h as usize, w as usize]);
            }
            render(&cloud.to_gaussians(device), &[camera])
                .expect("one camera for one cloud")
                .over(fill)
                .clamp(0.0, 1.0)
        })
        .collect();
    Tensor::cat(images, 0)
}

/// One Gaussian per foreground pixel of the source: at its point, with its colour,
/// `footprint` source pixels wide.
fn source_cloud(sample: &Sample, footprint: f32) -> GaussianCloud {
    let source = &sample.source;
    assert_eq!(
        (sample.points.width, sample.points.height),
        source.rgb.dimensions(),
        "one point per source pixel"
    );
    let centre = source.camera.center();
    let focal = source.camera.intrinsics.fx;
    let logit = (WARP_OPACITY / (1.0 - WARP_OPACITY)).ln();
    let mut cloud = GaussianCloud {
        means: Vec::new(),
        normals: Vec::new(),
        sh_dc: Vec::new(),
        sh_degree: 0,
        sh_rest: Vec::new(),
        opacity_logits: Vec::new(),
        log_scales: Vec::new(),
        rotations: Vec::new(),
    };
    let pixels = source.rgb.pixels().zip(source.mask.pixels());
    for (point, (rgb, alpha)) in sample.points.points.iter().zip(pixels) {
        if alpha.0[0] <= FOREGROUND {
            continue;
        }
        let distance = glam::Vec3::from_array(*point).distance(centre);
        let log_scale = (footprint * distance / focal).ln();
        cloud.means.push(*point);
        cloud.normals.push([0.0; 3]);
        cloud.sh_dc.push(rgb.0.map(|c| (c - 0.5) / SH_C0));
        cloud.opacity_logits.push(logit);
        cloud.log_scales.push([log_scale; 3]);
        cloud.rotations.push([1.0, 0.0, 0.0, 0.0]);
    }
    cloud
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use glam::Vec3;
    use image::{ImageBuffer, Luma, Rgb, Rgb32FImage};
    use prism_core::BackendKind;
    use prism_core::camera::{Camera, Intrinsics};
    use prism_data::{Mask, PointMap, View};

    const S: u32 = 32;
    const BG: [f32; 3] = [1.0, 1.0, 1.0];

    /// A camera 2 m in front of the plane z = 0, `dx` metres to the right.
    fn camera(dx: f32) -> Camera {
        let k = Intrinsics {
            fx: S as f32,
            fy: S as f32,
            cx: S as f32 / 2.0,
            cy: S as f32 / 2.0,
            width: S,
            height: S,
        };
        Camera::look_at(Vec3::new(dx, 0.0, 2.0), Vec3::new(dx, 0.0, 0.0), Vec3::Y, k)
    }

    fn view(camera: Camera, rgb: Rgb32FImage, mask: Mask) -> View {
        View {
            index: 0,
            yaw_deg: 0.0,
            pitch_deg: 0.0,
            camera,
            rgb,
            mask,
            depth: None,
        }
    }

    /// A square of 16 x 16 pixels on the plane z = 0, its colour a ramp in x and y, seen by
    /// the source camera; the target camera `dx` metres to the right. `foreground` false
    /// empties the mask.
    pub(crate) fn sample(dx: f32, foreground: bool) -> Sample {
        let source = camera(0.0);
        let inside = |x: u32, y: u32| foreground && (8..24).contains(&x) && (8..24).contains(&y);
        let rgb = ImageBuffer::from_fn(S, S, |x, y| {
            if inside(x, y) {
                Rgb([x as f32 / S as f32, 0.3, y as f32 / S as f32])
            } else {
                Rgb(BG)
            }
        });
        let mask = ImageBuffer::from_fn(S, S, |x, y| Luma([if inside(x, y) { 1.0 } else { 0.0 }]));
        let points = (0..S * S)
            .map(|i| {
                let (x, y) = (i % S, i / S);
                let point = source.unproject(x as f32 + 0.5, y as f32 + 0.5, 2.0);
                if inside(x, y) {
                    point.to_array()
                } else {
                    [0.0; 3]
                }
            })
            .collect();
        let target = view(camera(dx), rgb.clone(), mask.clone());
        Sample {
            subject: "plane".into(),
            source: view(source, rgb, mask),
            targets: vec![target],
            points: PointMap {
                width: S,
                height: S,
                points,
            },
            body: None,
        }
    }

    fn pixels(image: Tensor<4>) -> Vec<f32> {
        image.into_data().try_into_vec_as::<f32>().unwrap()
    }

    fn at(image: &[f32], c: usize, x: u32, y: u32) -> f32 {
        image[c * (S * S) as usize + (y * S + x) as usize]
    }

    #[test]
    fn the_warp_moves_the_source_by_its_true_depth() {
        let device = BackendKind::Ndarray.device().unwrap();
        // Into the source camera itself: the source's colours, away from the square's border
        // (the Gaussians blur it by about a pixel).
        let same = sample(0.0, true);
        let warp = pixels(true_depth_warp(
            std::slice::from_ref(&same),
            BG,
            0.3,
            &device,
        ));
        for y in 10..22 {
            for x in 10..22 {
                let source = same.source.rgb.get_pixel(x, y).0;
                for c in 0..3 {
                    let v = at(&warp, c, x, y);
                    assert!(
                        (v - source[c]).abs() < 0.03,
                        "({x}, {y}) {c}: {v} vs {source:?}"
                    );
                }
            }
        }
        assert_eq!(
            at(&warp, 0, 2, 2),
            1.0,
            "the background away from the square"
        );
        // A camera 0.25 m to the right, the plane 2 m away: 32 * 0.25 / 2 = 4 pixels of
        // parallax, so the square and its colours move 4 pixels to the left.
        let moved = pixels(true_depth_warp(&[sample(0.25, true)], BG, 0.3, &device));
        for y in 10..22 {
            for x in 6..18 {
                for c in 0..3 {
                    let (a, b) = (at(&moved, c, x, y), at(&warp, c, x + 4, y));
                    assert!((a - b).abs() < 1e-3, "({x}, {y}) {c}: {a} vs {b}");
                }
            }
        }
        assert_eq!(at(&moved, 0, 23, 16), 1.0, "uncovered on the right");
        // No foreground: the background.
        let empty = pixels(true_depth_warp(&[sample(0.0, false)], BG, 0.3, &device));
        assert!(empty.iter().all(|&v| v == 1.0));
    }
}
