//! 3DGS PLY files: round trips for SH degrees 0 to 3, a hand-made degree-3 file, conversion to
//! and from tensors, and rendering a file.

use crate::common;

use std::path::PathBuf;

use common::{axis_camera, device, host};
use prism_render::splat::ply::sh_rest_per_channel;
use prism_render::splat::{GaussianCloud, SH_C0, render, render_cloud};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("prism-ply-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn random_cloud(n: usize, degree: usize, seed: u64) -> GaussianCloud {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut a3 = |lo: f32, hi: f32| -> Vec<[f32; 3]> {
        (0..n)
            .map(|_| std::array::from_fn(|_| rng.random_range(lo..hi)))
            .collect()
    };
    let (means, normals, sh_dc, log_scales) =
        (a3(-1.0, 1.0), a3(-1.0, 1.0), a3(-2.0, 2.0), a3(-5.0, -1.0));
    let mut rng = ChaCha8Rng::seed_from_u64(seed + 1);
    GaussianCloud {
        means,
        normals,
        sh_dc,
        sh_degree: degree,
        sh_rest: (0..n * 3 * sh_rest_per_channel(degree))
            .map(|_| rng.random_range(-0.5..0.5))
            .collect(),
        opacity_logits: (0..n).map(|_| rng.random_range(-3.0..3.0)).collect(),
        log_scales,
        rotations: (0..n)
            .map(|_| std::array::from_fn(|_| rng.random_range(-1.0..1.0)))
            .collect(),
    }
}

#[test]
fn files_round_trip_exactly_for_every_sh_degree() {
    let dir = temp_dir("round-trip");
    for degree in 0..=3 {
        let cloud = random_cloud(37, degree, degree as u64);
        let path = dir.join(format!("degree{degree}.ply"));
        cloud.write(&path).unwrap();
        let back = GaussianCloud::read(&path).unwrap();
        assert_eq!(back, cloud, "degree {degree}");
        // The header is the standard one.
        let bytes = std::fs::read(&path).unwrap();
        let header = String::from_utf8_lossy(&bytes[..bytes.len().min(4000)]).to_string();
        let rest = 3 * sh_rest_per_channel(degree);
        assert!(header.starts_with("ply\nformat binary_little_endian 1.0\nelement vertex 37\n"));
        assert!(header.contains("property float f_dc_2\n"));
        assert_eq!(header.matches("property float f_rest_").count(), rest);
        let props = 17 + rest;
        let header_len = header.find("end_header\n").unwrap() + "end_header\n".len();
        assert_eq!(bytes.len(), header_len + 37 * props * 4);
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_hand_made_degree_3_file_is_read_field_by_field() {
    // The reference layout, written out here independently of the writer.
    let mut names: Vec<String> = [
        "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
    ]
    .map(String::from)
    .to_vec();
    names.extend((0..45).map(|k| format!("f_rest_{k}")));
    names.extend(
        [
            "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
        ]
        .map(String::from),
    );
    let mut bytes =
        b"ply\nformat binary_little_endian 1.0\ncomment degree 3\nelement vertex 2\n".to_vec();
    for n in &names {
        bytes.extend(format!("property float {n}\n").bytes());
    }
    bytes.extend(b"end_header\n");
    // Gaussian g's property p has the value 1000 g + p.
    for g in 0..2 {
        for p in 0..names.len() {
            bytes.extend((1000.0 * g as f32 + p as f32).to_le_bytes());
        }
    }
    let dir = temp_dir("degree3");
    let path = dir.join("d3.ply");
    std::fs::write(&path, &bytes).unwrap();
    let c = GaussianCloud::read(&path).unwrap();
    assert_eq!(c.sh_degree, 3);
    assert_eq!(c.len(), 2);
    assert_eq!(c.means[1], [1000.0, 1001.0, 1002.0]);
    assert_eq!(c.normals[0], [3.0, 4.0, 5.0]);
    assert_eq!(c.sh_dc[0], [6.0, 7.0, 8.0]);
    assert_eq!(c.sh_rest.len(), 90);
    assert_eq!(c.sh_rest[0], 9.0);
    assert_eq!(c.sh_rest[45 + 44], 1053.0);
    assert_eq!(c.opacity_logits, vec![54.0, 1054.0]);
    assert_eq!(c.log_scales[0], [55.0, 56.0, 57.0]);
    assert_eq!(c.rotations[1], [1058.0, 1059.0, 1060.0, 1061.0]);
    // Written back, it is the same file.
    c.write(&path).unwrap();
    let again = std::fs::read(&path).unwrap();
    let skip = |b: &[u8]| b.windows(10).position(|w| w == b"end_header").unwrap();
    assert_eq!(again[skip(&again)..], bytes[skip(&bytes)..]);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn missing_and_unwritable_files_are_errors_naming_them() {
    let dir = temp_dir("errors");
    let missing = dir.join("nothing.ply");
    let err = GaussianCloud::read(&missing).unwrap_err().to_string();
    assert!(err.contains("nothing.ply"), "{err}");
    let cloud = random_cloud(3, 1, 9);
    let err = cloud
        .write(dir.join("no/dir/x.ply"))
        .unwrap_err()
        .to_string();
    assert!(err.contains("x.ply"), "{err}");
    let mut broken = cloud;
    broken.sh_rest.pop();
    let err = broken
        .write(dir.join("broken.ply"))
        .unwrap_err()
        .to_string();
    assert!(err.contains("sh_rest"), "{err}");
    assert!(!dir.join("broken.ply").exists());
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn clouds_convert_to_and_from_gaussians_and_render_with_their_dc_colour() {
    let dev = device();
    let mut cloud = random_cloud(20, 2, 4);
    for (m, s) in cloud.means.iter_mut().zip(cloud.log_scales.iter_mut()) {
        m[2] = m[2].abs() + 1.5;
        *s = [-3.0; 3];
    }
    let colours = cloud.colours();
    for (c, dc) in colours.iter().zip(&cloud.sh_dc) {
        for k in 0..3 {
            assert!((c[k] - (0.5 + SH_C0 * dc[k]).max(0.0)).abs() < 1e-6);
        }
    }
    let g = cloud.to_gaussians(&dev);
    let back = GaussianCloud::from_gaussians(&g, 0).unwrap();
    assert_eq!(back.means, cloud.means);
    assert_eq!(back.rotations, cloud.rotations);
    assert_eq!(back.opacity_logits, cloud.opacity_logits);
    for (a, b) in back.colours().iter().zip(&colours) {
        for k in 0..3 {
            assert!((a[k] - b[k]).abs() < 1e-5);
        }
    }

    let camera = axis_camera(20.0, 12.0, 10.0, 24, 20);
    let bg = [0.2, 0.4, 0.6];
    let image = render_cloud(&cloud, &camera, bg, &dev).unwrap();
    let r = render(&g, &[camera]).unwrap();
    let (f, a) = (host(r.features), host(r.alpha));
    let mut drawn = 0;
    for (x, y, p) in image.enumerate_pixels() {
        let i = (y * 24 + x) as usize;
        if a[i] > 0.01 {
            drawn += 1;
        }
        for c in 0..3 {
            let v = (f[c * 480 + i] + (1.0 - a[i]) * bg[c]).clamp(0.0, 1.0);
            assert_eq!(p[c], (v * 255.0).round() as u8);
        }
    }
    assert!(drawn > 10, "{drawn}");
    // An empty cloud renders the background.
    let empty = GaussianCloud::default();
    let image = render_cloud(&empty, &camera, bg, &dev).unwrap();
    assert!(image.pixels().all(|p| p.0 == [51, 102, 153]));
}
