//! Times the CPU rasterizer on a 50k-triangle, person-sized mesh at 512 px with 3x3
//! supersampling, with vertex colours and with a 4096 x 4096 texture.
//!
//! `cargo run --release -p prism-data --example raster_bench [-- RES SUPERSAMPLE RUNS TRIANGLES]`

use std::sync::Arc;
use std::time::Instant;

use prism_core::{Intrinsics, ViewingProtocol};
use prism_synth::{Material, Mesh, RenderOptions, Shading, Texture, render};

#[path = "common/body.rs"]
mod common;
use common::body;

fn main() {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .map(|a| {
            a.parse()
                .expect("arguments: RES SUPERSAMPLE RUNS TRIANGLES")
        })
        .collect();
    let res = args.first().copied().unwrap_or(512) as u32;
    let supersample = args.get(1).copied().unwrap_or(3) as u32;
    let runs = args.get(2).copied().unwrap_or(10);
    // 2 * rings * segments triangles with segments = 1.6 rings (50k: 125 x 200).
    let triangles = args.get(3).copied().unwrap_or(50_000) as f64;
    let rings = (triangles / 3.2).sqrt().round() as usize;
    let mut mesh = body(rings, (rings as f64 * 1.6).round() as usize);
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
