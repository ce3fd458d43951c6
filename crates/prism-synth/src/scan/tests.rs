//! Tests of scan loading and normalisation on small files written to a temporary folder.

use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};
use image::{Rgb, RgbImage};

use super::*;
use crate::material::Shading;
use crate::mesh::Mesh;
use crate::raster::{RenderOptions, render};
use prism_core::camera::{Camera, Intrinsics};
use prism_core::protocol::{Placement, ViewingProtocol};

/// A fresh folder under the system's temporary directory, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(name: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("prism-scan-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }

    fn write(&self, name: &str, text: &str) -> PathBuf {
        let path = self.0.join(name);
        std::fs::write(&path, text).unwrap();
        path
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Six flat colours, one per cube face, in a 3 x 2 atlas of 32 x 32 blocks.
const FACE_COLORS: [[u8; 3]; 6] = [
    [200, 30, 30],
    [30, 200, 30],
    [30, 30, 200],
    [200, 200, 30],
    [30, 200, 200],
    [200, 30, 200],
];

fn atlas() -> RgbImage {
    RgbImage::from_fn(96, 64, |x, y| {
        Rgb(FACE_COLORS[(y / 32 * 3 + x / 32) as usize])
    })
}

/// The `vt` lines of atlas block `b`.
fn block_uvs(b: usize) -> String {
    block_uv_corners(b)
        .iter()
        .map(|uv| format!("vt {} {}\n", uv.x, uv.y))
        .collect()
}

/// Corners of each face of the unit cube, counter-clockwise seen from outside, in the order
/// +X, -X, +Y, -Y, +Z, -Z.
const CUBE_FACES: [[[f32; 3]; 4]; 6] = [
    [
        [0.5, -0.5, 0.5],
        [0.5, -0.5, -0.5],
        [0.5, 0.5, -0.5],
        [0.5, 0.5, 0.5],
    ],
    [
        [-0.5, -0.5, -0.5],
        [-0.5, -0.5, 0.5],
        [-0.5, 0.5, 0.5],
        [-0.5, 0.5, -0.5],
    ],
    [
        [-0.5, 0.5, 0.5],
        [0.5, 0.5, 0.5],
        [0.5, 0.5, -0.5],
        [-0.5, 0.5, -0.5],
    ],
    [
        [-0.5, -0.5, -0.5],
        [0.5, -0.5, -0.5],
        [0.5, -0.5, 0.5],
        [-0.5, -0.5, 0.5],
    ],
    [
        [-0.5, -0.5, 0.5],
        [0.5, -0.5, 0.5],
        [0.5, 0.5, 0.5],
        [-0.5, 0.5, 0.5],
    ],
    [
        [0.5, -0.5, -0.5],
        [-0.5, -0.5, -0.5],
        [-0.5, 0.5, -0.5],
        [0.5, 0.5, -0.5],
    ],
];

/// The inset UV rectangle of atlas block `b` (OBJ convention, v up): bottom-left,
/// bottom-right, top-right, top-left.
fn block_uv_corners(b: usize) -> [Vec2; 4] {
    let (col, row) = ((b % 3) as f32, (b / 3) as f32);
    let (u0, u1) = ((col + 0.25) / 3.0, (col + 0.75) / 3.0);
    // Image row 0 is the top: v = 1 - y / height.
    let (v1, v0) = (1.0 - (row + 0.25) / 2.0, 1.0 - (row + 0.75) / 2.0);
    [
        Vec2::new(u0, v0),
        Vec2::new(u1, v0),
        Vec2::new(u1, v1),
        Vec2::new(u0, v1),
    ]
}

/// A unit cube centred at the origin, one quad per face, face `i` textured with atlas
/// block `i` in the order +X, -X, +Y, -Y, +Z, -Z; faces use negative indices.
fn textured_cube(dir: &TempDir, texture: &str) -> PathBuf {
    dir.write(
        "cube.mtl",
        &format!("newmtl skin\nKd 1 1 1\nmap_Kd {texture}\n"),
    );
    let mut obj = String::from("# a textured cube\nmtllib cube.mtl\nusemtl skin\n");
    for (i, face) in CUBE_FACES.iter().enumerate() {
        for p in face {
            obj += &format!("v {} {} {}\n", p[0], p[1], p[2]);
        }
        obj += &block_uvs(i);
        obj += "f -4/-4 -3/-3 -2/-2 -1/-1\n";
    }
    dir.write("cube.obj", &obj)
}

fn rgb(c: [u8; 3]) -> [f32; 3] {
    c.map(|x| x as f32 / 255.0)
}

#[test]
fn multi_material_obj_with_quads_ngons_and_negative_indices() {
    let dir = TempDir::new("multi");
    RgbImage::from_pixel(4, 4, Rgb([10, 20, 30]))
        .save(dir.0.join("tex.png"))
        .unwrap();
    dir.write(
        "m.mtl",
        "newmtl red\nKd 1 0 0\n\nnewmtl textured\nKd 0.8 0.8 0.8\nmap_Kd -s 1 1 1 tex.png\n",
    );
    let obj = "mtllib m.mtl\n\
        v 9 9 9\n\
        v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n\
        vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
        usemtl red\n\
        f 2 3 4 5\n\
        usemtl textured\n\
        v 0 0 1\nv 1 0 1\nv 1.5 0.5 1\nv 1 1 1\nv 0 1 1\n\
        f -5/-4 -4/-3 -3/-2 -2/-1 -1/-1\n\
        o next\ng part\ns 1\nvn 0 0 1\n\
        f 2//-1 3//-1 4//-1\n";
    let path = dir.write("m.obj", obj);
    let (mesh, warnings) = load_scan(&path).unwrap();
    // The last face uses the textured material without UVs: grey, with a warning.
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    assert!(warnings[0].contains("m.obj:24") && warnings[0].contains("without texture"));
    assert_eq!(mesh.materials[3].name, "textured (no UVs)");
    assert_eq!(mesh.materials[3].shading, Shading::Flat(GREY));
    // Quad -> 2, pentagon -> 3, triangle -> 1; the unused vertex 1 is dropped.
    assert_eq!(mesh.triangles.len(), 6);
    assert_eq!(mesh.positions.len(), 9);
    assert!(!mesh.positions.contains(&Vec3::splat(9.0)));
    assert_eq!(mesh.materials[0].shading, Shading::Flat([1.0, 0.0, 0.0]));
    let Shading::Texture(texture) = &mesh.materials[1].shading else {
        panic!("{:?}", mesh.materials[1]);
    };
    assert_eq!((texture.width(), texture.height()), (4, 4));
    assert_eq!(mesh.triangle_materials, vec![0, 0, 1, 1, 1, 3]);
    // Corner UVs follow the vt indices of each corner.
    let first_textured = mesh.triangles[2];
    for (k, &v) in first_textured.iter().enumerate() {
        let p = mesh.positions[v as usize];
        let uv = mesh.corner_uvs[2][k];
        let expected = match (p.x, p.y) {
            (0.0, 0.0) => Vec2::new(0.0, 0.0),
            (1.0, 0.0) => Vec2::new(1.0, 0.0),
            (1.5, 0.5) => Vec2::new(1.0, 1.0),
            (1.0, 1.0) | (0.0, 1.0) => Vec2::new(0.0, 1.0),
            _ => panic!("unexpected corner {p}"),
        };
        assert_eq!(uv, expected, "corner {p}");
    }
    // The pentagon's triangles cover its area: 1 + 0.5 * 1 * 0.5.
    let area: f32 = (2..5)
        .map(|t| {
            let [a, b, c] = mesh.triangles[t].map(|i| mesh.positions[i as usize]);
            (b - a).cross(c - a).length() / 2.0
        })
        .sum();
    assert!((area - 1.25).abs() < 1e-6);
}

#[test]
fn vertex_colours_are_used_when_there_is_no_texture() {
    let dir = TempDir::new("colours");
    let path = dir.write(
        "c.obj",
        "v 0 0 0 255 0 0\nv 1 0 0 0 255 0\nv 0 1 0 0 0 255\nv 1 1 0 255 255 255\nf 1 2 4 3\n",
    );
    let (mesh, warnings) = load_scan(&path).unwrap();
    assert!(warnings.is_empty());
    assert!(mesh.materials.is_empty() && mesh.corner_uvs.is_empty());
    let color_at = |p: Vec3| mesh.colors[mesh.positions.iter().position(|&q| q == p).unwrap()];
    assert_eq!(color_at(Vec3::ZERO), [1.0, 0.0, 0.0]);
    assert_eq!(color_at(Vec3::X), [0.0, 1.0, 0.0]);
    assert_eq!(color_at(Vec3::ONE.with_z(0.0)), [1.0, 1.0, 1.0]);
    // Colours in [0, 1] are kept as they are.
    let path = dir.write(
        "d.obj",
        "v 0 0 0 0.2 0.4 0.6\nv 1 0 0 0 0 0\nv 0 1 0 0 0 0\nf 1 2 3\n",
    );
    assert_eq!(load_scan(&path).unwrap().0.colors[0], [0.2, 0.4, 0.6]);
}

#[test]
fn a_missing_texture_renders_grey_with_a_warning() {
    let dir = TempDir::new("missing");
    let path = textured_cube(&dir, "nowhere.jpeg");
    let (mesh, warnings) = load_scan(&path).unwrap();
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    assert!(warnings[0].contains("nowhere.jpeg") && warnings[0].contains("grey"));
    assert_eq!(mesh.materials[0].shading, Shading::Flat(GREY));
    let cam = Camera::orbit(
        0.0,
        0.0,
        3.0,
        Vec3::ZERO,
        Intrinsics::protocol_default(32, 32),
    );
    let out = render(&mesh, &cam, &RenderOptions::default()).unwrap();
    assert_eq!(out.rgb[out.index(16, 16)], GREY);
    // A missing material library is a warning too.
    let path = dir.write(
        "nolib.obj",
        "mtllib gone.mtl\nusemtl a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    );
    let (mesh, warnings) = load_scan(&path).unwrap();
    assert!(
        warnings.iter().any(|w| w.contains("gone.mtl")),
        "{warnings:?}"
    );
    assert_eq!(mesh.materials[0].shading, Shading::Flat(GREY));
}

/// The error message of loading `text` as an OBJ file.
fn error_of(dir: &TempDir, name: &str, text: &str) -> String {
    let path = dir.write(name, text);
    let err = load_scan(&path).unwrap_err().to_string();
    assert!(err.contains(name), "'{err}' does not name the file");
    err
}

#[test]
fn broken_files_are_errors_naming_file_and_line() {
    let dir = TempDir::new("broken");
    let e = error_of(&dir, "range.obj", "v 0 0 0\nv 1 0 0\nf 1 2 3\n");
    assert!(
        e.contains("range.obj:3") && e.contains("out of range"),
        "{e}"
    );
    let e = error_of(&dir, "neg.obj", "v 0 0 0\nf -1 -2 -3\n");
    assert!(e.contains("neg.obj:2"), "{e}");
    let e = error_of(&dir, "nan.obj", "v 0 0 0\nv 1 zero 0\n");
    assert!(e.contains("nan.obj:2") && e.contains("'zero'"), "{e}");
    let e = error_of(&dir, "zero.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n");
    assert!(e.contains("zero.obj:4"), "{e}");
    let e = error_of(&dir, "short.obj", "v 0 0 0\nv 1 0 0\nf 1 2\n");
    assert!(e.contains("short.obj:3") && e.contains("at least 3"), "{e}");
    let e = error_of(&dir, "empty.obj", "# nothing\nv 0 0 0\n");
    assert!(e.contains("no faces"), "{e}");
    // Binary garbage.
    let path = dir.0.join("garbage.obj");
    std::fs::write(&path, [0u8, 159, 146, 150, 10, 255, 0, 1, 2]).unwrap();
    let e = load_scan(&path).unwrap_err().to_string();
    assert!(e.contains("garbage.obj"), "{e}");
    // A file that does not exist, and an unknown format.
    let e = load_scan(Path::new("/nonexistent/scan.obj"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("/nonexistent/scan.obj"), "{e}");
    let e = load_scan(&dir.0.join("scan.ply")).unwrap_err().to_string();
    assert!(e.contains("scan.ply") && e.contains("unsupported"), "{e}");
}

#[test]
fn broken_material_library_is_an_error() {
    let dir = TempDir::new("badmtl");
    dir.write("bad.mtl", "Kd 1 0 0\n");
    let path = dir.write(
        "m.obj",
        "mtllib bad.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    );
    let e = load_scan(&path).unwrap_err().to_string();
    assert!(
        e.contains("bad.mtl:1") && e.contains("before any newmtl"),
        "{e}"
    );
}

#[test]
fn textured_cube_shows_the_expected_texels() {
    let dir = TempDir::new("cube");
    atlas().save(dir.0.join("atlas.png")).unwrap();
    let path = textured_cube(&dir, "atlas.png");
    let (mesh, warnings) = load_scan(&path).unwrap();
    assert!(warnings.is_empty(), "{warnings:?}");
    check_cube_render(&mesh, Vec3::ZERO, 1.0);
}

/// Renders a cube of the atlas's face colours (centre `centre`, edge `size`) frontally and
/// from above-right, and checks the texels at the centres of the visible faces.
fn check_cube_render(mesh: &Mesh, centre: Vec3, size: f32) {
    let k = Intrinsics::protocol_default(64, 64);
    // Frontal: the +Z face (block 4) fills the centre.
    let cam = Camera::orbit(0.0, 0.0, 3.0 * size, centre, k);
    let out = render(mesh, &cam, &RenderOptions::default()).unwrap();
    let got = out.rgb[out.index(32, 32)];
    assert!(close(got, rgb(FACE_COLORS[4])), "{got:?}");
    // From above-right: the +X, +Y and +Z faces show their blocks at their centres' pixels.
    let cam = Camera::orbit(30.0, 20.0, 3.0 * size, centre, k);
    let out = render(mesh, &cam, &RenderOptions::default()).unwrap();
    for (normal, block) in [(Vec3::X, 0), (Vec3::Y, 2), (Vec3::Z, 4)] {
        let (u, v, _) = cam.project(centre + normal * 0.5 * size);
        let (x, y) = (u as usize, v as usize);
        let got = out.rgb[out.index(x, y)];
        assert!(
            close(got, rgb(FACE_COLORS[block])),
            "face {normal} at ({x}, {y}): {got:?}"
        );
        assert_eq!(out.alpha[out.index(x, y)], 1.0);
    }
}

fn close(a: [f32; 3], b: [f32; 3]) -> bool {
    (0..3).all(|i| (a[i] - b[i]).abs() <= 2.0 / 255.0)
}

#[test]
fn jpeg_textures_load() {
    let dir = TempDir::new("jpeg");
    atlas().save(dir.0.join("atlas.jpg")).unwrap();
    let path = textured_cube(&dir, "atlas.jpg");
    let (mesh, warnings) = load_scan(&path).unwrap();
    assert!(warnings.is_empty(), "{warnings:?}");
    let cam = Camera::orbit(
        0.0,
        0.0,
        3.0,
        Vec3::ZERO,
        Intrinsics::protocol_default(32, 32),
    );
    let out = render(&mesh, &cam, &RenderOptions::default()).unwrap();
    let c = out.rgb[out.index(16, 16)];
    let expected = rgb(FACE_COLORS[4]);
    assert!((0..3).all(|i| (c[i] - expected[i]).abs() < 0.06), "{c:?}");
}

#[test]
fn orientation_options_map_up_and_facing() {
    let cases = [
        (UpAxis::Y, Facing::PlusZ, Vec3::Y, Vec3::Z),
        (UpAxis::Y, Facing::MinusZ, Vec3::Y, Vec3::NEG_Z),
        (UpAxis::Y, Facing::PlusX, Vec3::Y, Vec3::X),
        (UpAxis::Y, Facing::MinusX, Vec3::Y, Vec3::NEG_X),
        (UpAxis::Z, Facing::PlusZ, Vec3::Z, Vec3::NEG_Y),
        (UpAxis::Z, Facing::PlusX, Vec3::Z, Vec3::X),
    ];
    for (up, facing, file_up, file_front) in cases {
        let r = ScanOptions { up, facing }.orientation();
        assert!(
            (r.transform_vector3(file_up) - Vec3::Y).length() < 1e-6,
            "{up:?} {facing:?}"
        );
        assert!(
            (r.transform_vector3(file_front) - Vec3::Z).length() < 1e-6,
            "{up:?} {facing:?}"
        );
    }
    assert_eq!("z".parse::<UpAxis>(), Ok(UpAxis::Z));
    assert_eq!("-x".parse::<Facing>(), Ok(Facing::MinusX));
    assert!("w".parse::<UpAxis>().is_err() && "+y".parse::<Facing>().is_err());
}

#[test]
fn normalised_scan_has_the_drawn_height_on_the_floor_facing_plus_z() {
    // A "person" in millimetres, Z-up, facing -X after the up fix: a 400 x 300 x 1700 box
    // standing on z = 250 with a nose vertex on its front.
    let dir = TempDir::new("normalise");
    let mut obj = String::new();
    for &(x, y, z) in &[
        (-150.0, -200.0, 250.0),
        (150.0, -200.0, 250.0),
        (150.0, 200.0, 250.0),
        (-150.0, 200.0, 250.0),
        (-150.0, -200.0, 1950.0),
        (150.0, -200.0, 1950.0),
        (150.0, 200.0, 1950.0),
        (-150.0, 200.0, 1950.0),
        (-180.0, 0.0, 1800.0),
    ] {
        obj += &format!("v {} {} {}\n", x + 1000.0, y - 500.0, z);
    }
    obj += "f 1 2 3 4\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\nf 1 9 4\n";
    let path = dir.write("person.obj", &obj);
    let (mesh, _) = load_scan(&path).unwrap();
    let options = ScanOptions {
        up: UpAxis::Z,
        facing: Facing::MinusX,
    };
    let protocol = ViewingProtocol::default();
    for seed in [0, 1, 2] {
        let placement = protocol.placement(seed);
        let (placed, mesh_to_world) = normalise(&mesh, &options, &placement).unwrap();
        let (lo, hi) = placed.bounds().unwrap();
        let height = hi.y - lo.y;
        assert!((height - placement.height).abs() < 1e-4, "{height}");
        assert!((height - 1.80).abs() <= 0.05 + 1e-4);
        assert!(lo.y.abs() < 1e-5);
        let centre = (lo + hi) / 2.0;
        let t = placement.translation;
        assert!((centre.x - t[0]).abs() < 1e-4 && (centre.z - t[2]).abs() < 1e-4);
        // The nose is the most +Z point: the subject faces +Z.
        let nose = placed.positions.iter().position(|p| p.z == hi.z).unwrap();
        assert!((placed.positions[nose].y - 1.55 * placement.height / 1.7).abs() < 1e-3);
        // mesh_to_world maps the file's points onto the placed ones and is a similarity.
        for (a, b) in mesh.positions.iter().zip(&placed.positions) {
            assert!((mesh_to_world.transform_point3(*a) - *b).length() < 1e-5);
        }
        let m = glam::Mat3::from_mat4(mesh_to_world);
        let s = placement.height / 1700.0;
        let r = m * (1.0 / s);
        assert!((r.transpose() * r - glam::Mat3::IDENTITY).abs_diff_eq(glam::Mat3::ZERO, 1e-5));
        assert!(r.determinant() > 0.0);
    }
    // A mesh flat along the chosen up axis cannot be normalised.
    let flat = dir.write("flat.obj", "v 0 0 0\nv 1 0 0\nv 0 0 1\nf 1 2 3\n");
    let (mesh, _) = load_scan(&flat).unwrap();
    let placement = Placement {
        height: 1.8,
        translation: [0.0; 3],
    };
    assert!(normalise(&mesh, &ScanOptions::default(), &placement).is_err());
}

/// The binary buffer of a glTF cube: positions (scaled by `size`), UVs (glTF's v down) and
/// u16 indices, then `extra` bytes (an embedded image); returns the buffer and the JSON
/// fragments `bufferViews` and `accessors`.
fn gltf_cube_buffer(extra: &[u8]) -> (Vec<u8>, String) {
    let mut bin = Vec::new();
    for face in &CUBE_FACES {
        for p in face {
            for c in p {
                bin.extend_from_slice(&c.to_le_bytes());
            }
        }
    }
    for b in 0..6 {
        for uv in block_uv_corners(b) {
            bin.extend_from_slice(&uv.x.to_le_bytes());
            bin.extend_from_slice(&(1.0 - uv.y).to_le_bytes());
        }
    }
    for f in 0..6u16 {
        for i in [0, 1, 2, 0, 2, 3] {
            bin.extend_from_slice(&(4 * f + i).to_le_bytes());
        }
    }
    assert_eq!(bin.len(), 552);
    bin.extend_from_slice(extra);
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let views = format!(
        r#""bufferViews": [
            {{"buffer": 0, "byteOffset": 0, "byteLength": 288}},
            {{"buffer": 0, "byteOffset": 288, "byteLength": 192}},
            {{"buffer": 0, "byteOffset": 480, "byteLength": 72}},
            {{"buffer": 0, "byteOffset": 552, "byteLength": {}}}
        ],
        "accessors": [
            {{"bufferView": 0, "componentType": 5126, "count": 24, "type": "VEC3",
              "min": [-0.5, -0.5, -0.5], "max": [0.5, 0.5, 0.5]}},
            {{"bufferView": 1, "componentType": 5126, "count": 24, "type": "VEC2"}},
            {{"bufferView": 2, "componentType": 5123, "count": 36, "type": "SCALAR"}}
        ]"#,
        extra.len().max(1)
    );
    (bin, views)
}

/// The JSON of a glTF cube under a node scaled by 2 and lifted by 1 m, with a base-colour
/// texture from `image` (a JSON image object).
fn gltf_cube_json(buffer: &str, views: &str, image: &str) -> String {
    format!(
        r#"{{
        "asset": {{"version": "2.0"}},
        "scene": 0,
        "scenes": [{{"nodes": [0]}}],
        "nodes": [{{"mesh": 0, "scale": [2, 2, 2], "translation": [0, 1, 0]}}],
        "meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0, "TEXCOORD_0": 1}},
                                      "indices": 2, "material": 0}}]}}],
        "materials": [{{"name": "skin", "pbrMetallicRoughness": {{
            "baseColorTexture": {{"index": 0}}}}}}],
        "textures": [{{"source": 0}}],
        "images": [{image}],
        "buffers": [{buffer}],
        {views}
    }}"#
    )
}

fn png_bytes(image: &RgbImage) -> Vec<u8> {
    let mut bytes = std::io::Cursor::new(Vec::new());
    image.write_to(&mut bytes, image::ImageFormat::Png).unwrap();
    bytes.into_inner()
}

#[test]
fn gltf_cube_with_external_buffer_and_texture_renders_its_texels() {
    let dir = TempDir::new("gltf");
    atlas().save(dir.0.join("atlas.png")).unwrap();
    let (bin, views) = gltf_cube_buffer(&[]);
    std::fs::write(dir.0.join("cube.bin"), &bin).unwrap();
    let buffer = format!(r#"{{"uri": "cube.bin", "byteLength": {}}}"#, bin.len());
    let path = dir.write(
        "cube.gltf",
        &gltf_cube_json(&buffer, &views, r#"{"uri": "atlas.png"}"#),
    );
    let (mesh, warnings) = load_scan(&path).unwrap();
    assert!(warnings.is_empty(), "{warnings:?}");
    assert_eq!(mesh.triangles.len(), 12);
    // The node's transform is applied: edge 2 m, centred 1 m up.
    let (lo, hi) = mesh.bounds().unwrap();
    assert!((lo - Vec3::new(-1.0, 0.0, -1.0)).length() < 1e-6);
    assert!((hi - Vec3::new(1.0, 2.0, 1.0)).length() < 1e-6);
    check_cube_render(&mesh, Vec3::Y, 2.0);
    // A missing image renders grey with a warning.
    let path = dir.write(
        "lost.gltf",
        &gltf_cube_json(&buffer, &views, r#"{"uri": "lost.png"}"#),
    );
    let (mesh, warnings) = load_scan(&path).unwrap();
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    assert!(warnings[0].contains("lost.png") || warnings[0].contains("image 0"));
    assert_eq!(mesh.materials[0].shading, Shading::Flat(GREY));
    // A missing buffer is an error naming the file.
    std::fs::remove_file(dir.0.join("cube.bin")).unwrap();
    let e = load_scan(&path).unwrap_err().to_string();
    assert!(e.contains("lost.gltf"), "{e}");
}

#[test]
fn glb_cube_with_embedded_texture_renders_its_texels() {
    let dir = TempDir::new("glb");
    let png = png_bytes(&atlas());
    let (bin, views) = gltf_cube_buffer(&png);
    let buffer = format!(r#"{{"byteLength": {}}}"#, bin.len());
    let image = r#"{"bufferView": 3, "mimeType": "image/png"}"#;
    let mut json = gltf_cube_json(&buffer, &views, image).into_bytes();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let mut glb = Vec::new();
    glb.extend_from_slice(b"glTF");
    glb.extend_from_slice(&2u32.to_le_bytes());
    glb.extend_from_slice(&((12 + 8 + json.len() + 8 + bin.len()) as u32).to_le_bytes());
    glb.extend_from_slice(&(json.len() as u32).to_le_bytes());
    glb.extend_from_slice(b"JSON");
    glb.extend_from_slice(&json);
    glb.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    glb.extend_from_slice(b"BIN\0");
    glb.extend_from_slice(&bin);
    let path = dir.0.join("cube.glb");
    std::fs::write(&path, &glb).unwrap();
    let (mesh, warnings) = load_scan(&path).unwrap();
    assert!(warnings.is_empty(), "{warnings:?}");
    check_cube_render(&mesh, Vec3::Y, 2.0);
    // A truncated file is an error naming it.
    std::fs::write(&path, &glb[..glb.len() / 2]).unwrap();
    let e = load_scan(&path).unwrap_err().to_string();
    assert!(e.contains("cube.glb"), "{e}");
}

#[test]
fn gltf_vertex_colours_are_converted_to_display_values() {
    let dir = TempDir::new("gltf-colours");
    let mut bin = Vec::new();
    for p in [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
        for c in p {
            bin.extend_from_slice(&c.to_le_bytes());
        }
    }
    for c in [[0.5f32, 0.0, 1.0], [0.5, 0.0, 1.0], [0.5, 0.0, 1.0]] {
        for x in c {
            bin.extend_from_slice(&x.to_le_bytes());
        }
    }
    std::fs::write(dir.0.join("t.bin"), &bin).unwrap();
    let json = r#"{
        "asset": {"version": "2.0"},
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "COLOR_0": 1}}]}],
        "buffers": [{"uri": "t.bin", "byteLength": 72}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36},
                        {"buffer": 0, "byteOffset": 36, "byteLength": 36}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
             "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC3"}]
    }"#;
    let path = dir.write("t.gltf", json);
    let (mesh, warnings) = load_scan(&path).unwrap();
    assert!(warnings.is_empty(), "{warnings:?}");
    assert_eq!(mesh.triangles, vec![[0, 1, 2]]);
    // Linear 0.5 is sRGB 0.7354.
    let c = mesh.colors[0];
    assert!((c[0] - 0.7354).abs() < 1e-3 && c[1] == 0.0 && (c[2] - 1.0).abs() < 1e-6);
    assert_eq!(mesh.materials[0].shading, Shading::VertexColors);
}

#[test]
fn damaged_files_are_errors_or_meshes_never_panics() {
    use rand::{Rng, SeedableRng};
    let dir = TempDir::new("damaged");
    atlas().save(dir.0.join("atlas.png")).unwrap();
    let obj = std::fs::read(textured_cube(&dir, "atlas.png")).unwrap();
    let png = png_bytes(&atlas());
    let (bin, views) = gltf_cube_buffer(&png);
    std::fs::write(dir.0.join("cube.bin"), &bin).unwrap();
    let buffer = format!(r#"{{"uri": "cube.bin", "byteLength": {}}}"#, bin.len());
    let gltf = gltf_cube_json(&buffer, &views, r#"{"uri": "atlas.png"}"#).into_bytes();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    for (name, original) in [("d.obj", &obj), ("d.gltf", &gltf)] {
        for _ in 0..150 {
            let mut bytes = original.clone();
            match rng.random_range(0..3) {
                0 => bytes.truncate(rng.random_range(0..bytes.len())),
                1 => {
                    for _ in 0..rng.random_range(1..4) {
                        let i = rng.random_range(0..bytes.len());
                        bytes[i] = rng.random();
                    }
                }
                _ => {
                    let i = rng.random_range(0..bytes.len());
                    let digit = b"0123456789-%/."[rng.random_range(0..14)];
                    bytes.insert(i, digit);
                }
            }
            let path = dir.0.join(name);
            std::fs::write(&path, &bytes).unwrap();
            match load_scan(&path) {
                Ok((mesh, _)) => {
                    assert_eq!(mesh.validate(), Ok(()));
                    let cam = Camera::orbit(
                        0.0,
                        0.0,
                        3.0,
                        Vec3::ZERO,
                        Intrinsics::protocol_default(8, 8),
                    );
                    render(&mesh, &cam, &RenderOptions::default()).unwrap();
                }
                Err(e) => assert!(e.to_string().contains(name), "{e}"),
            }
        }
    }
}
