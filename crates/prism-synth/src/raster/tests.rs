//! Tests of the rasterizer against analytic values and an independent ray caster.

use std::sync::Arc;

use glam::{DVec3, Mat4, Vec2, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;
use crate::material::{Material, Shading, Texture};
use prism_core::camera::Intrinsics;

/// A camera at the origin looking along +z (OpenCV axes = world axes).
fn axis_camera(width: u32, height: u32, f: f32) -> Camera {
    let k = Intrinsics {
        fx: f,
        fy: f,
        cx: width as f32 / 2.0,
        cy: height as f32 / 2.0,
        width,
        height,
    };
    Camera::new(k, Mat4::IDENTITY)
}

/// The world point at depth `z` that `axis_camera` projects to continuous pixel `(u, v)`.
fn at_pixel(camera: &Camera, u: f32, v: f32, z: f32) -> Vec3 {
    camera.unproject(u, v, z)
}

/// A screen-aligned quad at depth `z` covering continuous pixels `[u0, u1] x [v0, v1]`, with
/// UVs from (0, 1) at the top-left to (1, 0) at the bottom-right.
fn quad(camera: &Camera, [u0, v0, u1, v1]: [f32; 4], z: f32, color: [f32; 3]) -> Mesh {
    let positions = vec![
        at_pixel(camera, u0, v0, z),
        at_pixel(camera, u1, v0, z),
        at_pixel(camera, u1, v1, z),
        at_pixel(camera, u0, v1, z),
    ];
    let mut m = Mesh::with_vertex_colors(positions, vec![[0, 1, 2], [0, 2, 3]], vec![color; 4]);
    let uv = [
        Vec2::new(0.0, 1.0),
        Vec2::new(1.0, 1.0),
        Vec2::new(1.0, 0.0),
        Vec2::new(0.0, 0.0),
    ];
    m.corner_uvs = vec![[uv[0], uv[1], uv[2]], [uv[0], uv[2], uv[3]]];
    m
}

fn options(supersample: u32) -> RenderOptions {
    RenderOptions {
        supersample,
        background: [0.0, 0.0, 1.0],
        near: 0.01,
    }
}

fn close(a: [f32; 3], b: [f32; 3], tol: f32) -> bool {
    (0..3).all(|i| (a[i] - b[i]).abs() <= tol)
}

#[test]
fn quad_covers_exactly_the_expected_pixels() {
    let cam = axis_camera(32, 32, 30.0);
    let red = [1.0, 0.0, 0.0];
    let mesh = quad(&cam, [8.0, 10.0, 20.0, 24.0], 2.0, red);
    for s in [1, 2, 3] {
        let out = render(&mesh, &cam, &options(s)).unwrap();
        for y in 0..32 {
            for x in 0..32 {
                let i = out.index(x, y);
                let inside = (8..20).contains(&x) && (10..24).contains(&y);
                let (alpha, color) = if inside {
                    (1.0, red)
                } else {
                    (0.0, [0.0, 0.0, 1.0])
                };
                assert_eq!(out.alpha[i], alpha, "alpha at ({x}, {y}), s = {s}");
                assert!(close(out.rgb[i], color, 1e-6), "rgb at ({x}, {y})");
                assert_eq!(out.centre_covered(x, y), inside);
                if inside {
                    assert!((out.depth[i] - 2.0).abs() < 1e-5);
                } else {
                    assert_eq!((out.points[i], out.depth[i]), ([0.0; 3], 0.0));
                }
            }
        }
    }
}

#[test]
fn supersampled_edges_give_fractional_alpha() {
    let cam = axis_camera(32, 16, 20.0);
    let green = [0.0, 1.0, 0.0];
    // Left edge through the middle of column 10: half of a 4x4 grid is covered.
    let mesh = quad(&cam, [10.5, 2.0, 30.0, 14.0], 3.0, green);
    let out = render(&mesh, &cam, &options(4)).unwrap();
    let i = out.index(10, 8);
    assert_eq!(out.alpha[i], 0.5);
    assert!(close(out.rgb[i], [0.0, 0.5, 0.5], 1e-6), "{:?}", out.rgb[i]);
    assert_eq!(out.alpha[out.index(9, 8)], 0.0);
    assert_eq!(out.alpha[out.index(11, 8)], 1.0);
    // A third of the way into column 10 with 3x3 sub-samples: two of three columns covered.
    let mesh = quad(&cam, [10.0 + 1.0 / 3.0, 2.0, 30.0, 14.0], 3.0, green);
    let out = render(&mesh, &cam, &options(3)).unwrap();
    assert!((out.alpha[out.index(10, 8)] - 2.0 / 3.0).abs() < 1e-6);
    // Corners: a quarter pixel with 4x4 (top-left corner in the middle of pixel (10, 2)).
    let mesh = quad(&cam, [10.5, 2.5, 30.0, 14.0], 3.0, green);
    let out = render(&mesh, &cam, &options(4)).unwrap();
    assert_eq!(out.alpha[out.index(10, 2)], 0.25);
    // Without supersampling alpha is binary.
    let out = render(&mesh, &cam, &options(1)).unwrap();
    assert!(out.alpha.iter().all(|&a| a == 0.0 || a == 1.0));
}

#[test]
fn near_surfaces_occlude_far_ones_in_any_order() {
    let cam = axis_camera(24, 24, 24.0);
    let near = quad(&cam, [4.0, 4.0, 16.0, 16.0], 1.5, [1.0, 0.0, 0.0]);
    let far = quad(&cam, [8.0, 8.0, 20.0, 20.0], 2.5, [0.0, 1.0, 0.0]);
    for (first, second) in [(&near, &far), (&far, &near)] {
        let mut mesh = first.clone();
        mesh.append(second);
        let out = render(&mesh, &cam, &options(2)).unwrap();
        let overlap = out.index(12, 12);
        assert!(close(out.rgb[overlap], [1.0, 0.0, 0.0], 1e-6));
        assert!((out.depth[overlap] - 1.5).abs() < 1e-5);
        let far_only = out.index(18, 18);
        assert!(close(out.rgb[far_only], [0.0, 1.0, 0.0], 1e-6));
        assert!((out.depth[far_only] - 2.5).abs() < 1e-5);
    }
}

#[test]
fn interpolation_is_perspective_correct() {
    // A floor at y = 0.5 (below the camera: OpenCV y points down) from z = 1 to z = 4, its
    // red channel growing linearly with depth: red = (z - 1) / 3.
    let cam = axis_camera(16, 64, 32.0);
    let positions = vec![
        Vec3::new(-2.0, 0.5, 1.0),
        Vec3::new(2.0, 0.5, 1.0),
        Vec3::new(2.0, 0.5, 4.0),
        Vec3::new(-2.0, 0.5, 4.0),
    ];
    let colors = vec![
        [0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
    ];
    let mesh = Mesh::with_vertex_colors(positions, vec![[0, 1, 2], [0, 2, 3]], colors);
    let out = render(&mesh, &cam, &options(1)).unwrap();
    let (fy, cy) = (32.0f64, 32.0f64);
    let mut checked = 0;
    for y in 0..64 {
        let v = y as f64 + 0.5;
        if v <= cy {
            continue;
        }
        // The centre ray meets the floor at z = 0.5 fy / (v - cy).
        let z = 0.5 * fy / (v - cy);
        if !(1.0..=4.0).contains(&z) {
            assert_eq!(out.alpha[out.index(8, y)], 0.0);
            continue;
        }
        let expected = ((z - 1.0) / 3.0) as f32;
        let got = out.rgb[out.index(8, y)];
        assert!(
            (got[0] - expected).abs() < 1e-5,
            "row {y}: {got:?} vs {expected}"
        );
        assert!((out.depth[out.index(8, y)] as f64 - z).abs() < 1e-5);
        // Interpolating in screen space instead would be far off in the middle rows.
        checked += 1;
    }
    assert!(checked > 10, "{checked}");
    // Screen-space interpolation between the rows where z = 1 (v = 48) and z = 4 (v = 36)
    // would give (48 - 39.5) / 12 = 0.71 at row 39 instead of (32 / 15 - 1) / 3 = 0.38: the
    // test tells the two apart.
    let row39 = out.rgb[out.index(8, 39)][0];
    assert!((row39 - 0.3778).abs() < 1e-3 && (row39 - 0.7083).abs() > 0.3);
}

/// Nearest hit of the ray `origin + t dir` (t > 0) with any triangle, by Moller-Trumbore in
/// double precision, and the smallest distance of that ray to an edge of any triangle it
/// nearly hits (to skip ambiguous pixels).
fn ray_cast(mesh: &Mesh, origin: DVec3, dir: DVec3) -> (Option<(f64, DVec3)>, f64) {
    let mut best: Option<(f64, DVec3)> = None;
    let mut margin = f64::INFINITY;
    for tri in &mesh.triangles {
        let [a, b, c] = tri.map(|i| mesh.positions[i as usize].as_dvec3());
        let (e1, e2) = (b - a, c - a);
        let p = dir.cross(e2);
        let det = e1.dot(p);
        if det.abs() < 1e-14 {
            continue;
        }
        let s = origin - a;
        let u = s.dot(p) / det;
        let q = s.cross(e1);
        let v = dir.dot(q) / det;
        let t = e2.dot(q) / det;
        if t <= 0.0 {
            continue;
        }
        let w = 1.0 - u - v;
        let m = u.min(v).min(w);
        margin = margin.min(m.abs());
        if m >= 0.0 && best.is_none_or(|(bt, _)| t < bt) {
            best = Some((t, origin + dir * t));
        }
    }
    (best, margin)
}

/// Compares the point map and depth with the independent ray caster at every pixel whose
/// centre ray is not within `1e-6` (barycentric) of a triangle edge.
fn check_against_ray_casting(mesh: &Mesh, cam: &Camera, near: f64) -> usize {
    let out = render(mesh, cam, &options(3)).unwrap();
    let c2w = cam.c2w.as_dmat4();
    let k = &cam.intrinsics;
    let origin = c2w.transform_point3(DVec3::ZERO);
    let mut hits = 0;
    for y in 0..out.height {
        for x in 0..out.width {
            let (u, v) = (x as f64 + 0.5, y as f64 + 0.5);
            let d_cam = DVec3::new(
                (u - k.cx as f64) / k.fx as f64,
                (v - k.cy as f64) / k.fy as f64,
                1.0,
            );
            let dir = c2w.transform_vector3(d_cam);
            let (hit, margin) = ray_cast(mesh, origin, dir);
            // The camera-space depth of a hit at parameter t along d_cam (z = 1) is t.
            let hit = hit.filter(|(t, _)| *t > near);
            let i = out.index(x, y);
            if margin < 1e-6 {
                continue;
            }
            match hit {
                Some((t, p)) => {
                    hits += 1;
                    assert!(out.centre_covered(x, y), "pixel ({x}, {y}) should be hit");
                    let got = Vec3::from_array(out.points[i]).as_dvec3();
                    assert!((got - p).length() < 1e-5, "({x}, {y}): {got} vs {p}");
                    assert!((out.depth[i] as f64 - t).abs() < 1e-5);
                    let (pu, pv, _) = cam.project(Vec3::from_array(out.points[i]));
                    assert!(
                        (pu as f64 - u).abs() < 2e-4 && (pv as f64 - v).abs() < 2e-4,
                        "({x}, {y}) reprojects to ({pu}, {pv})"
                    );
                }
                None => assert!(!out.centre_covered(x, y), "pixel ({x}, {y}) should miss"),
            }
        }
    }
    hits
}

#[test]
fn point_map_matches_independent_ray_casting() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    for t in 0..80 {
        let centre = Vec3::new(
            rng.random_range(-0.4..0.4),
            rng.random_range(0.3..1.5),
            rng.random_range(-0.4..0.4),
        );
        for _ in 0..3 {
            let offset = Vec3::new(
                rng.random_range(-0.25..0.25),
                rng.random_range(-0.25..0.25),
                rng.random_range(-0.25..0.25),
            );
            positions.push(centre + offset);
        }
        triangles.push([3 * t, 3 * t + 1, 3 * t + 2]);
    }
    let colors = vec![[0.5; 3]; positions.len()];
    let mesh = Mesh::with_vertex_colors(positions, triangles, colors);
    let cam = Camera::orbit(
        23.0,
        -14.0,
        2.0,
        Vec3::new(0.0, 0.9, 0.0),
        Intrinsics::protocol_default(48, 40),
    );
    let hits = check_against_ray_casting(&mesh, &cam, 0.01);
    assert!(hits > 300, "{hits}");
}

#[test]
fn triangles_behind_or_crossing_the_camera_are_clipped_at_the_near_plane() {
    let cam = Camera::orbit(
        10.0,
        5.0,
        2.0,
        Vec3::new(0.0, 0.9, 0.0),
        Intrinsics::protocol_default(40, 40),
    );
    let centre = cam.center();
    let (right, down, forward) = (
        cam.rotation().x_axis,
        cam.rotation().y_axis,
        cam.rotation().z_axis,
    );
    // A floor under the camera that reaches far behind it, a wall that passes through the
    // camera plane at a slant, and a triangle wholly behind the camera.
    let p = |r: f32, d: f32, f: f32| centre + right * r + down * d + forward * f;
    let positions = vec![
        p(-3.0, 0.6, -4.0),
        p(3.0, 0.6, -4.0),
        p(0.0, 0.6, 6.0),
        p(0.8, -2.0, -1.0),
        p(0.3, 2.0, 3.0),
        p(0.8, 2.0, -1.0),
        p(-1.0, -1.0, -2.0),
        p(1.0, -1.0, -2.0),
        p(0.0, 1.0, -2.0),
    ];
    let colors = vec![[0.3; 3]; positions.len()];
    let triangles = vec![[0, 1, 2], [3, 4, 5], [6, 7, 8]];
    let mesh = Mesh::with_vertex_colors(positions, triangles, colors);
    let hits = check_against_ray_casting(&mesh, &cam, 0.01);
    assert!(hits > 200, "{hits}");
    // Alone, the triangle behind the camera draws nothing.
    let behind = Mesh::with_vertex_colors(
        mesh.positions[6..].to_vec(),
        vec![[0, 1, 2]],
        vec![[0.3; 3]; 3],
    );
    let out = render(&behind, &cam, &options(2)).unwrap();
    assert!(out.alpha.iter().all(|&a| a == 0.0));
    // A near plane beyond the floor's visible part hides it: only depths past it remain.
    let far = RenderOptions {
        near: 1.5,
        ..options(1)
    };
    let out = render(&mesh, &cam, &far).unwrap();
    assert!(out.depth.iter().all(|&z| z == 0.0 || z > 1.5));
}

/// A 4x4 texture with a distinct colour per texel.
fn labelled_texture() -> Arc<Texture> {
    let texels = (0..16u8)
        .map(|i| [i * 16, 255 - i * 16, (i % 4) * 80])
        .collect();
    Arc::new(Texture::from_rgb8(4, 4, texels))
}

#[test]
fn textured_quad_shows_the_expected_texels() {
    let cam = axis_camera(48, 48, 40.0);
    let texture = labelled_texture();
    // 36 px for 4 texels: 9 px per texel, texel centres at pixel centres 4, 13, 22, 31 past
    // the quad's corner.
    let mut mesh = quad(&cam, [6.0, 5.0, 42.0, 41.0], 2.0, [0.0; 3]);
    mesh.materials = vec![Material::new("tex", Shading::Texture(texture.clone()))];
    mesh.triangle_materials = vec![0, 0];
    let out = render(&mesh, &cam, &options(1)).unwrap();
    for row in 0..4usize {
        for col in 0..4usize {
            let (x, y) = (6 + 4 + 9 * col, 5 + 4 + 9 * row);
            let t = (row * 4 + col) as u8;
            let expected = [t * 16, 255 - t * 16, (t % 4) * 80].map(|c| c as f32 / 255.0);
            let got = out.rgb[out.index(x, y)];
            assert!(close(got, expected, 1e-4), "texel ({col}, {row}): {got:?}");
        }
    }
    // With supersampling the texel centres keep their colour up to a little blending.
    let out = render(&mesh, &cam, &options(3)).unwrap();
    let got = out.rgb[out.index(6 + 4 + 9, 5 + 4 + 18)];
    let t = 9u8;
    let expected = [t * 16, 255 - t * 16, (t % 4) * 80].map(|c| c as f32 / 255.0);
    assert!(close(got, expected, 0.05), "{got:?}");
}

#[test]
fn minified_textures_are_filtered_not_aliased() {
    // A 256 x 256 one-texel checker on 16 x 16 pixels: 16 texels per pixel.
    let n = 256usize;
    let texels = (0..n * n)
        .map(|i| {
            if (i % n + i / n).is_multiple_of(2) {
                [255; 3]
            } else {
                [0; 3]
            }
        })
        .collect();
    let texture = Arc::new(Texture::from_rgb8(n, n, texels));
    let cam = axis_camera(32, 32, 30.0);
    let mut mesh = quad(&cam, [8.0, 8.0, 24.0, 24.0], 2.0, [0.0; 3]);
    mesh.materials = vec![Material::new("checker", Shading::Texture(texture))];
    mesh.triangle_materials = vec![0, 0];
    for s in [1, 3] {
        let out = render(&mesh, &cam, &options(s)).unwrap();
        for y in 9..23 {
            for x in 9..23 {
                let c = out.rgb[out.index(x, y)];
                assert!((c[0] - 0.5).abs() < 0.03, "({x}, {y}), s = {s}: {c:?}");
            }
        }
    }
}

#[test]
fn materials_mix_flat_vertex_and_texture_colours() {
    let cam = axis_camera(40, 20, 20.0);
    let left = quad(&cam, [2.0, 2.0, 18.0, 18.0], 2.0, [0.2, 0.4, 0.6]);
    let mut right = quad(&cam, [22.0, 2.0, 38.0, 18.0], 2.0, [0.0; 3]);
    right.materials = vec![Material::new("flat", Shading::Flat([0.9, 0.1, 0.3]))];
    right.triangle_materials = vec![0, 0];
    let mut mesh = left.clone();
    mesh.append(&right);
    assert_eq!(mesh.triangle_materials, vec![0, 0, 1, 1]);
    let out = render(&mesh, &cam, &options(2)).unwrap();
    assert!(close(out.rgb[out.index(10, 10)], [0.2, 0.4, 0.6], 1e-6));
    assert!(close(out.rgb[out.index(30, 10)], [0.9, 0.1, 0.3], 1e-6));
}

#[test]
fn invalid_meshes_and_options_are_errors() {
    let cam = axis_camera(8, 8, 8.0);
    let mut mesh = quad(&cam, [1.0, 1.0, 7.0, 7.0], 2.0, [1.0; 3]);
    mesh.triangles[1][2] = 9;
    assert!(matches!(
        render(&mesh, &cam, &options(1)),
        Err(RenderError::Mesh(MeshError::Index { index: 9, .. }))
    ));
    let mesh = quad(&cam, [1.0, 1.0, 7.0, 7.0], 2.0, [1.0; 3]);
    assert!(render(&mesh, &cam, &options(0)).is_err());
    let bad_near = RenderOptions {
        near: 0.0,
        ..options(1)
    };
    assert!(render(&mesh, &cam, &bad_near).is_err());
    assert!(render(&mesh, &axis_camera(0, 8, 8.0), &options(1)).is_err());
}

#[test]
fn output_does_not_depend_on_the_thread_count() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let positions: Vec<Vec3> = (0..300)
        .map(|_| {
            Vec3::new(
                rng.random_range(-0.5..0.5),
                rng.random_range(0.4..1.4),
                rng.random_range(-0.5..0.5),
            )
        })
        .collect();
    let triangles = (0..100).map(|t| [3 * t, 3 * t + 1, 3 * t + 2]).collect();
    let colors = (0..300).map(|i| [(i % 7) as f32 / 7.0, 0.5, 0.2]).collect();
    let mesh = Mesh::with_vertex_colors(positions, triangles, colors);
    let cam = Camera::orbit(
        0.0,
        0.0,
        2.0,
        Vec3::new(0.0, 0.9, 0.0),
        Intrinsics::protocol_default(40, 40),
    );
    let many = render(&mesh, &cam, &options(3)).unwrap();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let one = pool.install(|| render(&mesh, &cam, &options(3)).unwrap());
    assert_eq!(many, one);
}
