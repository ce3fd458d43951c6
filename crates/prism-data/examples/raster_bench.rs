//! Times the CPU rasterizer on a 50k-triangle, person-sized mesh at 512 px with 3x3
//! supersampling, with vertex colours and with a 4096 x 4096 texture.
//!
//! `cargo run --release -p prism-data --example raster_bench [-- RES SUPERSAMPLE RUNS]`

use std::sync::Arc;
use std::time::Instant;

use glam::{Vec2, Vec3};
use prism_data::{
    Intrinsics, Material, Mesh, RenderOptions, Shading, Texture, ViewingProtocol, render,
};

/// A closed ellipsoid about the size of a standing person (1.8 m tall) with `2 * rings *
/// segments` triangles, vertex colours and per-corner UVs.
fn body(rings: usize, segments: usize) -> Mesh {
    let mut positions = Vec::new();
    let mut colors = Vec::new();
    let mut uvs = Vec::new();
    for r in 0..=rings {
        let theta = std::f32::consts::PI * r as f32 / rings as f32;
        for s in 0..=segments {
            let phi = std::f32::consts::TAU * s as f32 / segments as f32;
            let p = Vec3::new(
                0.25 * theta.sin() * phi.cos(),
                0.9 + 0.9 * theta.cos(),
                0.15 * theta.sin() * phi.sin(),
            );
            positions.push(p);
            colors.push([0.5 + 0.5 * phi.cos(), r as f32 / rings as f32, 0.4]);
            uvs.push(Vec2::new(
                s as f32 / segments as f32,
                1.0 - r as f32 / rings as f32,
            ));
        }
    }
    let mut triangles = Vec::new();
    let mut corner_uvs = Vec::new();
    let at = |r: usize, s: usize| (r * (segments + 1) + s) as u32;
    for r in 0..rings {
        for s in 0..segments {
            let q = [at(r, s), at(r + 1, s), at(r + 1, s + 1), at(r, s + 1)];
            for t in [[q[0], q[1], q[2]], [q[0], q[2], q[3]]] {
                triangles.push(t);
                corner_uvs.push(t.map(|i| uvs[i as usize]));
            }
        }
    }
    let mut mesh = Mesh::with_vertex_colors(positions, triangles, colors);
    mesh.corner_uvs = corner_uvs;
    mesh
}

fn main() {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .map(|a| a.parse().expect("arguments: RES SUPERSAMPLE RUNS"))
        .collect();
    let res = args.first().copied().unwrap_or(512) as u32;
    let supersample = args.get(1).copied().unwrap_or(3) as u32;
    let runs = args.get(2).copied().unwrap_or(10);
    let mut mesh = body(125, 200);
    let protocol = ViewingProtocol::default();
    let views = protocol.views(0);
    let k = Intrinsics::protocol_default(res, res);
    let options = RenderOptions {
        supersample,
        ..RenderOptions::default()
    };
    println!(
        "{} triangles, {res} px, {supersample}x{supersample} supersampling, {} threads",
        mesh.triangles.len(),
        rayon::current_num_threads()
    );
    let time = |mesh: &Mesh, label: &str| {
        let cam = protocol.camera(&views[1], k);
        render(mesh, &cam, &options).expect("valid mesh");
        let start = Instant::now();
        let mut covered = 0.0;
        for i in 0..runs {
            let cam = protocol.camera(&views[i % views.len()], k);
            covered += render(mesh, &cam, &options)
                .expect("valid mesh")
                .alpha
                .iter()
                .sum::<f32>();
        }
        let ms = start.elapsed().as_secs_f64() * 1e3 / runs as f64;
        let fraction = covered as f64 / (runs as f64 * (res * res) as f64);
        println!(
            "{label}: {ms:.1} ms per view ({:.0}% of pixels covered)",
            100.0 * fraction
        );
    };
    time(&mesh, "vertex colours");
    let n = 4096;
    let start = Instant::now();
    let texels = (0..n * n)
        .map(|i| {
            let (x, y) = (i % n, i / n);
            let v = if (x / 8 + y / 8) % 2 == 0 { 230 } else { 30 };
            [v, (x * 255 / n) as u8, (y * 255 / n) as u8]
        })
        .collect();
    let texture = Arc::new(Texture::from_rgb8(n, n, texels));
    println!(
        "4096 x 4096 texture with mip pyramid built in {:.0} ms",
        start.elapsed().as_secs_f64() * 1e3
    );
    mesh.materials = vec![Material::new("skin", Shading::Texture(texture))];
    mesh.triangle_materials = vec![0; mesh.triangles.len()];
    time(&mesh, "4k texture");
}
