//! The mesh rasterizer against an independent per-pixel ray cast: a posed body seen by a
//! protocol camera, its position map (barycentric interpolation of the canonical rest-pose
//! positions over the visible faces) compared with the rest-pose position at the nearest
//! ray-triangle intersection (Möller-Trumbore over every triangle), pixel by pixel.

use burn::tensor::{Tensor, TensorData};
use glam::{DVec3, Vec3};
use prism_body::{BodyModel, BodyParams};
use prism_core::{BackendKind, Camera, Intrinsics};
use prism_render::mesh::{rasterize, rasterize_maps};

#[cfg(feature = "wgpu")]
use crate::common;

/// The nearest hit of the ray `origin + t dir` (t > 0) with the mesh: `(face, [b0, b1, b2], t)`.
fn ray_cast(
    origin: DVec3,
    dir: DVec3,
    vertices: &[Vec3],
    faces: &[[u32; 3]],
) -> Option<(usize, [f64; 3], f64)> {
    let mut best: Option<(usize, [f64; 3], f64)> = None;
    for (f, tri) in faces.iter().enumerate() {
        let [a, b, c] = tri.map(|i| vertices[i as usize].as_dvec3());
        let (e1, e2) = (b - a, c - a);
        let p = dir.cross(e2);
        let det = e1.dot(p);
        if det.abs() < 1e-12 {
            continue;
        }
        let inv = 1.0 / det;
        let s = origin - a;
        let u = s.dot(p) * inv;
        if !(0.0..=1.0).contains(&u) {
            continue;
        }
        let q = s.cross(e1);
        let v = dir.dot(q) * inv;
        if v < 0.0 || u + v > 1.0 {
            continue;
        }
        let t = e2.dot(q) * inv;
        if t > 0.0 && best.is_none_or(|(_, _, bt)| t < bt) {
            best = Some((f, [1.0 - u - v, u, v], t));
        }
    }
    best
}

#[test]
fn position_map_matches_a_ray_cast() {
    let model = BodyModel::procedural(3);
    let mut params = BodyParams::rest("procedural:3");
    params.betas[0] = 0.5;
    params.pose[16] = [0.0, 0.0, -1.1]; // left shoulder down
    params.pose[17] = [0.0, 0.0, 1.0]; // right shoulder down
    params.pose[4] = [0.6, 0.0, 0.0]; // right knee
    params.pose[0] = [0.0, 0.3, 0.0]; // turned a little
    params.scale = 1.02;
    params.transl = [0.03, 0.0, -0.05];
    let posed = model.pose(&params);
    let faces = model.faces().to_vec();
    let (w, h) = (40u32, 48u32);
    let k = Intrinsics::protocol_default(w, h);
    let cameras = [
        Camera::orbit(0.0, 0.0, 2.0, Vec3::new(0.0, 0.9, 0.0), k),
        Camera::orbit(23.0, -17.0, 2.0, Vec3::new(0.0, 0.9, 0.0), k),
    ];
    let meshes = [posed.vertices.as_slice(), posed.vertices.as_slice()];
    let fragments = rasterize(&meshes, &faces, &cameras).unwrap();

    // Canonical attributes: the shaped rest-pose vertices, differently per batch element.
    let device = BackendKind::Ndarray.device().unwrap();
    let rest: Vec<f32> = posed
        .shaped
        .iter()
        .chain(posed.shaped.iter())
        .flat_map(|p| p.to_array())
        .collect();
    let v = posed.shaped.len();
    let attributes = Tensor::<3>::from_data(TensorData::new(rest, [2, v, 3]), &device);
    let map = fragments.interpolate(attributes, &faces);
    assert_eq!(map.dims(), [2, 3, h as usize, w as usize]);
    let map: Vec<f32> = map.into_data().try_to_vec::<f32>().unwrap();
    let mask: Vec<f32> = fragments
        .mask(&device)
        .into_data()
        .try_to_vec::<f32>()
        .unwrap();

    let plane = (w * h) as usize;
    let (mut covered, mut disagree) = (0, 0);
    for (b, camera) in cameras.iter().enumerate() {
        let origin = camera.center().as_dvec3();
        let rotation = camera.rotation();
        for y in 0..h as usize {
            for x in 0..w as usize {
                let pixel = Vec3::new(
                    (x as f32 + 0.5 - k.cx) / k.fx,
                    (y as f32 + 0.5 - k.cy) / k.fy,
                    1.0,
                );
                let dir = (rotation * pixel).normalize().as_dvec3();
                let i = b * plane + y * w as usize + x;
                let hit = ray_cast(origin, dir, &posed.vertices, &faces);
                assert_eq!(hit.is_some(), mask[i] == 1.0, "coverage at {b} ({x}, {y})");
                let Some((face, bary, t)) = hit else {
                    assert!((0..3).all(|c| map[(b * 3 + c) * plane + y * w as usize + x] == 0.0));
                    continue;
                };
                covered += 1;
                if fragments.face_at(b, x, y) != Some(face) {
                    disagree += 1;
                }
                let expected: DVec3 = (0..3)
                    .map(|c| posed.shaped[faces[face][c] as usize].as_dvec3() * bary[c])
                    .sum();
                let got = DVec3::new(
                    map[b * 3 * plane + y * w as usize + x] as f64,
                    map[(b * 3 + 1) * plane + y * w as usize + x] as f64,
                    map[(b * 3 + 2) * plane + y * w as usize + x] as f64,
                );
                // Where two faces tie (a shared edge, overlapping closed parts) the positions
                // still agree; elsewhere they agree to float precision.
                assert!(
                    (got - expected).length() < 2e-3,
                    "camera {b} pixel ({x}, {y}): {got} vs {expected} (face {face})"
                );
                // The rasterizer's depth is the camera z of the ray's hit.
                let z = t * dir.dot(rotation.z_axis.as_dvec3());
                let depth = fragments.depth[i] as f64;
                assert!((depth - z).abs() < 1e-4, "depth {depth} vs {z}");
            }
        }
    }
    assert!(covered > 400, "the body covers {covered} pixels");
    assert!(
        disagree * 100 <= covered,
        "{disagree} of {covered} faces differ"
    );
}

#[test]
fn interpolation_gradients_reach_the_vertices() {
    // One triangle facing the camera; the position map's sum has gradient sum_pixels b_i.
    let device = BackendKind::Ndarray.device().unwrap().autodiff();
    let k = Intrinsics::protocol_default(16, 16);
    let camera = Camera::look_at(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, Vec3::Y, k);
    let vertices = [
        Vec3::new(-0.5, -0.5, 0.0),
        Vec3::new(0.6, -0.4, 0.0),
        Vec3::new(0.0, 0.6, 0.0),
    ];
    let faces = [[0u32, 1, 2]];
    let fragments = rasterize(&[&vertices], &faces, &[camera]).unwrap();
    let attributes = Tensor::<3>::from_data(
        TensorData::new(
            vec![1.0f32, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            [1, 3, 3],
        ),
        &device,
    )
    .require_grad();
    let map = fragments.interpolate(attributes.clone(), &faces);
    let grads = map.sum().backward();
    let grad: Vec<f32> = attributes
        .grad(&grads)
        .unwrap()
        .into_data()
        .try_to_vec::<f32>()
        .unwrap();
    let mut expected = [0.0f64; 3];
    for (f, b) in fragments.faces.iter().zip(&fragments.barycentrics) {
        if *f == 0 {
            for c in 0..3 {
                expected[c] += b[c] as f64;
            }
        }
    }
    let covered = fragments.faces.iter().filter(|&&f| f == 0).count();
    assert!(covered > 20, "{covered} pixels");
    for vtx in 0..3 {
        for c in 0..3 {
            let g = grad[vtx * 3 + c] as f64;
            assert!(
                (g - expected[vtx]).abs() < 1e-3,
                "vertex {vtx}: {g} vs {}",
                expected[vtx]
            );
        }
    }
    // Barycentrics sum to one on every covered pixel.
    for (f, b) in fragments.faces.iter().zip(&fragments.barycentrics) {
        if *f == 0 {
            assert!((b.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        }
    }
}

#[test]
fn bad_inputs_are_errors() {
    let k = Intrinsics::protocol_default(8, 8);
    let camera = Camera::look_at(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, Vec3::Y, k);
    let vertices = [Vec3::ZERO, Vec3::X, Vec3::Y];
    assert!(rasterize(&[&vertices], &[[0, 1, 3]], &[camera]).is_err());
    assert!(rasterize(&[&vertices, &vertices], &[[0, 1, 2]], &[camera]).is_err());
    let other = Camera::look_at(
        Vec3::new(0.0, 0.0, 2.0),
        Vec3::ZERO,
        Vec3::Y,
        Intrinsics::protocol_default(8, 9),
    );
    assert!(rasterize(&[&vertices, &vertices], &[[0, 1, 2]], &[camera, other]).is_err());
}

/// A posed body in two protocol cameras, its rest positions as per-vertex attributes.
fn posed_scene() -> (Vec<Vec3>, Vec<Vec3>, Vec<[u32; 3]>, [Camera; 2]) {
    let model = BodyModel::procedural(3);
    let mut params = BodyParams::rest("procedural:3");
    params.pose[16] = [0.0, 0.0, -1.1];
    params.pose[4] = [0.6, 0.0, 0.0];
    params.pose[0] = [0.0, 0.3, 0.0];
    let posed = model.pose(&params);
    let k = Intrinsics::protocol_default(40, 48);
    let cameras = [
        Camera::orbit(0.0, 0.0, 2.0, Vec3::new(0.0, 0.9, 0.0), k),
        Camera::orbit(23.0, -17.0, 2.0, Vec3::new(0.0, 0.9, 0.0), k),
    ];
    (
        posed.vertices.clone(),
        posed.shaped.clone(),
        model.faces().to_vec(),
        cameras,
    )
}

/// `[2, V, 3]` of the same mesh twice.
fn twice(points: &[Vec3], device: &burn::tensor::Device) -> Tensor<3> {
    let flat: Vec<f32> = points
        .iter()
        .chain(points)
        .flat_map(|p| p.to_array())
        .collect();
    Tensor::from_data(TensorData::new(flat, [2, points.len(), 3]), device)
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().convert::<f32>().try_to_vec::<f32>().unwrap()
}

/// The tensor rasterizer on a CPU backend is the host rasterizer: the same faces,
/// barycentrics and position map.
#[test]
fn tensor_fragments_are_the_host_fragments_on_the_cpu() {
    let (vertices, rest, faces, cameras) = posed_scene();
    let device = BackendKind::Ndarray.device().unwrap();
    let host = rasterize(&[&vertices, &vertices], &faces, &cameras).unwrap();
    let maps = rasterize_maps(twice(&vertices, &device), &faces, &cameras).unwrap();
    let ids: Vec<i32> = values(maps.faces.clone())
        .iter()
        .map(|&f| f as i32)
        .collect();
    assert_eq!(ids, host.faces);
    let bary: Vec<f32> = host.barycentrics.iter().flatten().copied().collect();
    assert_eq!(values(maps.barycentrics.clone()), bary);
    assert_eq!(values(maps.mask()), values(host.mask(&device)));
    let want = values(host.interpolate(twice(&rest, &device), &faces));
    let got = values(maps.interpolate(twice(&rest, &device), &faces));
    assert_eq!(got, want);
}

/// The device rasterizer (wgpu) finds what the host one finds: the same visible face on all
/// but a few edge pixels (it works in f32 where the host uses f64), the same position map
/// there, and no read from the device.
#[cfg(feature = "wgpu")]
#[test]
#[cfg_attr(not(wgpu_adapter), ignore = "no wgpu adapter on this machine")]
fn the_device_rasterizer_matches_the_host() {
    let _serial = common::serial();
    let Some(gpu) = common::wgpu() else { return };
    let (vertices, rest, faces, cameras) = posed_scene();
    let cpu = BackendKind::Ndarray.device().unwrap();
    let reads = prism_core::reads::geometry_host_reads();
    let maps = rasterize_maps(twice(&vertices, &gpu), &faces, &cameras).unwrap();
    let map = maps.interpolate(twice(&rest, &gpu), &faces);
    assert_eq!(
        prism_core::reads::geometry_host_reads(),
        reads,
        "the device rasterizer read from the device"
    );
    let want_maps = rasterize_maps(twice(&vertices, &cpu), &faces, &cameras).unwrap();
    let want = values(want_maps.interpolate(twice(&rest, &cpu), &faces));
    let (ids, want_ids) = (values(maps.faces.clone()), values(want_maps.faces.clone()));
    let covered = want_ids.iter().filter(|&&f| f >= 0.0).count();
    assert!(covered > 300, "{covered} pixels covered");
    let differ = ids.iter().zip(&want_ids).filter(|(a, b)| a != b).count();
    assert!(
        differ * 50 <= covered,
        "{differ} of {covered} pixels see another face"
    );
    let got = values(map);
    let plane = ids.len();
    let mut far = 0;
    for (i, (g, w)) in got.iter().zip(&want).enumerate() {
        let pixel = (i / (3 * plane / 2)) * (plane / 2) + i % (plane / 2);
        if ids[pixel] == want_ids[pixel] && (g - w).abs() > 1e-4 {
            far += 1;
        }
    }
    assert_eq!(
        far, 0,
        "position map values differ on pixels with the same face"
    );
}
