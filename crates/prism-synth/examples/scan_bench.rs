//! Times one scan subject end to end: load a textured OBJ (written here: a person-sized
//! mesh with a 4096 x 4096 JPEG texture), normalise it by the viewing protocol and render
//! the protocol's 105 views.
//!
//! `cargo run --release -p prism-data --example scan_bench [-- RES TRIANGLES]`
//!
//! `... --example scan_bench -- write DIR [TRIANGLES]` only writes the scan, as THuman lays it
//! out (`DIR/0000/0000.obj`, `material0.mtl`, `material0.jpeg`), to time `prism data render`
//! on it.

use std::fmt::Write as _;
use std::time::Instant;

use image::{Rgb, RgbImage};
use prism_core::{Intrinsics, ViewingProtocol};
use prism_synth::{RenderOptions, ScanOptions, load_scan, normalise, render};

#[path = "common/body.rs"]
mod common;
use common::body;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.first().map(String::as_str) == Some("write") {
        let dir = std::path::PathBuf::from(args.get(1).expect("arguments: write DIR [TRIANGLES]"));
        let triangles = args
            .get(2)
            .map_or(300_000.0, |t| t.parse().expect("TRIANGLES"));
        let dir = dir.join("0000");
        write_scan(&dir, triangles);
        println!("wrote {}", dir.display());
        return;
    }
    let args: Vec<usize> = args
        .into_iter()
        .map(|a| a.parse().expect("arguments: RES TRIANGLES"))
        .collect();
    let res = args.first().copied().unwrap_or(512) as u32;
    let triangles = args.get(1).copied().unwrap_or(300_000) as f64;
    let dir = std::env::temp_dir().join(format!("prism-scan-bench-{}", std::process::id()));
    write_scan(&dir, triangles);
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

/// Writes a person-sized scan of about `triangles` triangles into `dir` as THuman lays it out
/// (in millimetres, to exercise the normalisation), with a 4096 x 4096 JPEG texture.
fn write_scan(dir: &std::path::Path, triangles: f64) {
    let rings = (triangles / 3.2).sqrt().round() as usize;
    let mesh = body(rings, (rings as f64 * 1.6).round() as usize);
    std::fs::create_dir_all(dir).expect("scan folder");
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
}
