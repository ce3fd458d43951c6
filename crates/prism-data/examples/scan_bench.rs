//! Times one scan subject end to end: load a textured OBJ (written here: a person-sized
//! mesh with a 4096 x 4096 JPEG texture), normalise it by the viewing protocol and render
//! the protocol's 105 views.
//!
//! `cargo run --release -p prism-data --example scan_bench [-- RES TRIANGLES]`

use std::fmt::Write as _;
use std::time::Instant;

use image::{Rgb, RgbImage};
use prism_data::{
    Intrinsics, RenderOptions, ScanOptions, ViewingProtocol, load_scan, normalise, render,
};

#[path = "common/body.rs"]
mod common;
use common::body;

fn main() {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .map(|a| a.parse().expect("arguments: RES TRIANGLES"))
        .collect();
    let res = args.first().copied().unwrap_or(512) as u32;
    let triangles = args.get(1).copied().unwrap_or(300_000) as f64;
    let rings = (triangles / 3.2).sqrt().round() as usize;
    let mesh = body(rings, (rings as f64 * 1.6).round() as usize);

    // Write the scan as THuman lays it out (in millimetres, to exercise the normalisation).
    let dir = std::env::temp_dir().join(format!("prism-scan-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temporary folder");
    let mut obj = String::from("mtllib material0.mtl\nusemtl material0\n");
    for p in &mesh.positions {
        let _ = writeln!(obj, "v {} {} {}", p.x * 1000.0, p.y * 1000.0, p.z * 1000.0);
    }
    for (t, uv) in mesh.corner_uvs.iter().enumerate() {
        for c in uv {
            let _ = writeln!(obj, "vt {} {}", c.x, c.y);
        }
        let v = mesh.triangles[t];
        let k = 3 * t + 1;
        let _ = writeln!(
            obj,
            "f {}/{} {}/{} {}/{}",
            v[0] + 1,
            k,
            v[1] + 1,
            k + 1,
            v[2] + 1,
            k + 2
        );
    }
    std::fs::write(dir.join("0000.obj"), obj).expect("write obj");
    std::fs::write(
        dir.join("material0.mtl"),
        "newmtl material0\nKd 1 1 1\nmap_Kd material0.jpeg\n",
    )
    .expect("write mtl");
    RgbImage::from_fn(4096, 4096, |x, y| {
        let v = if (x / 8 + y / 8) % 2 == 0 { 230 } else { 30 };
        Rgb([v, (x / 16) as u8, (y / 16) as u8])
    })
    .save(dir.join("material0.jpeg"))
    .expect("write texture");

    let start = Instant::now();
    let (scan, warnings) = load_scan(&dir.join("0000.obj")).expect("load");
    let load_s = start.elapsed().as_secs_f64();
    assert!(warnings.is_empty(), "{warnings:?}");
    let protocol = ViewingProtocol::default();
    let start = Instant::now();
    let (placed, _) =
        normalise(&scan, &ScanOptions::default(), &protocol.placement(0)).expect("normalise");
    let normalise_s = start.elapsed().as_secs_f64();
    let k = Intrinsics::protocol_default(res, res);
    let start = Instant::now();
    for view in protocol.views(0) {
        let out = render(
            &placed,
            &protocol.camera(&view, k),
            &RenderOptions::default(),
        )
        .expect("render");
        assert!(out.alpha.iter().any(|&a| a > 0.0));
    }
    let render_s = start.elapsed().as_secs_f64();
    println!(
        "{} triangles, 4096^2 JPEG texture, {res} px, 3x3 supersampling, {} threads",
        scan.triangles.len(),
        rayon::current_num_threads()
    );
    println!("load (OBJ + MTL + JPEG + mip pyramid): {load_s:.2} s");
    println!("normalise: {normalise_s:.3} s");
    println!(
        "render 105 views: {render_s:.1} s ({:.0} ms per view)",
        render_s * 1e3 / 105.0
    );
    let _ = std::fs::remove_dir_all(&dir);
}
