//! Wavefront OBJ: positions (with the `v x y z r g b` vertex-colour extension), texture
//! coordinates, polygonal faces with absolute or negative (relative) indices, `usemtl` and
//! `mtllib` materials. Normals, groups, smoothing groups, lines and points are ignored.
//!
//! Hand-written rather than through the `tobj` crate: tobj 4.0.5, run on the inputs of
//! `scan/tests.rs`, cannot give what those tests check:
//! - `tobj::LoadError` is a bare enum: no line numbers for errors (`range.obj:3`) or warnings
//!   (the first face of a textured material without UVs), no offending token (`'zero'`);
//! - a face without `vt` gets a made-up texture coordinate (the first or the previous one), so
//!   such faces cannot be rendered grey; `f 1 2` loads as a line instead of an error; index 0
//!   of `vt` reads as "none"; mixed coloured and plain vertices are an error;
//! - vertices are copied per object and material (the multi-material test's 9 vertices come
//!   out as 12); trailing comments, `\` continuations and `vt u` are errors;
//! - it panics on damaged input: `f 1/-44 ...` overflows in `add_vertex_multi_index` with
//!   overflow checks on, as in tests (1 of the 150 damaged files of
//!   `damaged_files_are_errors_or_meshes_never_panics`), and its MTL reader on `Kd 0.5`
//!   (`parse_float3` unwraps); MTL `Kd` before `newmtl` is dropped silently.
//!
//! Its triangulation is a fan (convex faces only; `triangulate.rs` ear-clips concave ones). Speed
//! is no reason either: on `examples/scan_bench.rs`'s 300,000-triangle scan (39 MB, release, 2
//! cores) tobj parses in 0.28 s, this module parses and builds the [`Mesh`] in 0.35 s, and
//! converting tobj's output into a `Mesh` would add to the 0.28 s.

use std::collections::HashMap;
use std::path::Path;

use glam::{Vec2, Vec3};

use super::GREY;
use super::error::ScanError;
use super::mtl::{MtlMaterial, parse_mtl};
use super::text::{floats, logical_lines, read_text};
use super::textures::TextureCache;
use super::triangulate::triangulate;
use crate::material::{Material, Shading};
use crate::mesh::Mesh;

/// No texture coordinate at a face corner.
const NO_UV: u32 = u32::MAX;

/// One polygonal face: a range of `ObjData::corners`, its material and its line.
struct Face {
    start: usize,
    len: usize,
    /// Index into `ObjData::material_names`, `None` before any `usemtl`.
    material: Option<usize>,
    line: usize,
}

/// The statements of an OBJ file, with indices resolved to 0-based.
#[derive(Default)]
struct ObjData {
    positions: Vec<Vec3>,
    colors: Vec<Option<[f32; 3]>>,
    uvs: Vec<Vec2>,
    /// `(position, uv or NO_UV)` per face corner.
    corners: Vec<(u32, u32)>,
    faces: Vec<Face>,
    /// `mtllib` files with their line.
    libraries: Vec<(usize, String)>,
    /// Material names in order of first `usemtl`.
    material_names: Vec<String>,
    /// Unknown statements (skipped with a warning).
    unknown: Vec<String>,
}

/// Resolves an OBJ index (1-based, or negative relative to the `count` elements so far).
fn resolve(
    token: &str,
    count: usize,
    what: &str,
    path: &Path,
    line: usize,
) -> Result<u32, ScanError> {
    let i: i64 = token.parse().map_err(|_| {
        ScanError::syntax(
            path,
            line,
            format!("{what} index '{token}' is not an integer"),
        )
    })?;
    let index = match i {
        0 => {
            return Err(ScanError::syntax(
                path,
                line,
                format!("{what} index 0 (OBJ indices start at 1)"),
            ));
        }
        i if i > 0 => i - 1,
        i => count as i64 + i,
    };
    if index < 0 || index >= count as i64 {
        return Err(ScanError::syntax(
            path,
            line,
            format!("{what} index {i} out of range: {count} defined so far"),
        ));
    }
    Ok(index as u32)
}

/// Parses the statements of an OBJ file.
fn parse_obj(path: &Path) -> Result<ObjData, ScanError> {
    let text = read_text(path)?;
    let mut data = ObjData::default();
    let mut current: Option<usize> = None;
    let mut material_ids: HashMap<String, usize> = HashMap::new();
    for (line, content) in logical_lines(&text) {
        let mut tokens = content.split_whitespace();
        let keyword = tokens.next().unwrap_or("");
        let args: Vec<&str> = tokens.collect();
        match keyword {
            "v" => {
                let v = floats(&args, 3, 7, path, line, "vertex")?;
                data.positions.push(Vec3::new(v[0], v[1], v[2]));
                data.colors.push(match v.len() {
                    // x y z r g b [a]
                    6 | 7 => Some([v[3], v[4], v[5]]),
                    3 | 4 => None,
                    n => {
                        return Err(ScanError::syntax(
                            path,
                            line,
                            format!("vertex with {n} numbers: expected x y z [w] or x y z r g b"),
                        ));
                    }
                });
            }
            "vt" => {
                let v = floats(&args, 1, 3, path, line, "texture coordinate")?;
                data.uvs
                    .push(Vec2::new(v[0], v.get(1).copied().unwrap_or(0.0)));
            }
            "f" => {
                if args.len() < 3 {
                    return Err(ScanError::syntax(
                        path,
                        line,
                        format!("face with {} corners (at least 3 needed)", args.len()),
                    ));
                }
                let start = data.corners.len();
                for corner in &args {
                    let mut parts = corner.split('/');
                    let v = parts.next().unwrap_or("");
                    let position = resolve(v, data.positions.len(), "vertex", path, line)?;
                    let uv = match parts.next() {
                        Some(t) if !t.is_empty() => {
                            resolve(t, data.uvs.len(), "texture coordinate", path, line)?
                        }
                        _ => NO_UV,
                    };
                    data.corners.push((position, uv));
                }
                // A face mixing corners with and without UVs is treated as having none.
                let slice = &mut data.corners[start..];
                if slice.iter().any(|c| c.1 == NO_UV) {
                    slice.iter_mut().for_each(|c| c.1 = NO_UV);
                }
                data.faces.push(Face {
                    start,
                    len: args.len(),
                    material: current,
                    line,
                });
            }
            "usemtl" => {
                let name = args.join(" ");
                let next = material_ids.len();
                let id = *material_ids.entry(name.clone()).or_insert(next);
                if id == next {
                    data.material_names.push(name);
                }
                current = Some(id);
            }
            "mtllib" => {
                if args.is_empty() {
                    return Err(ScanError::syntax(path, line, "mtllib without a file name"));
                }
                data.libraries.push((line, args.join(" ")));
            }
            "vn" | "vp" | "o" | "g" | "s" | "l" | "p" | "cstype" | "deg" | "curv" | "surf"
            | "parm" | "end" | "mg" | "usemap" | "maplib" | "lod" | "bevel" | "c_interp"
            | "d_interp" | "shadow_obj" | "trace_obj" | "ctech" | "stech" | "bmat" | "step"
            | "curv2" | "trim" | "hole" | "scrv" | "sp" | "con" => {}
            other if other.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') => {
                if !data.unknown.iter().any(|k| k == other) {
                    data.unknown.push(other.to_string());
                }
            }
            other => {
                return Err(ScanError::syntax(
                    path,
                    line,
                    format!(
                        "unknown statement '{}': not a Wavefront OBJ file?",
                        other.escape_debug()
                    ),
                ));
            }
        }
    }
    Ok(data)
}

/// Reads the material libraries named by `mtllib` (relative to the OBJ's folder). A
/// library that cannot be read is a warning (its materials render grey); one that reads but
/// does not parse is an error.
fn read_libraries(
    path: &Path,
    data: &ObjData,
    warnings: &mut Vec<String>,
) -> Result<HashMap<String, (MtlMaterial, std::path::PathBuf)>, ScanError> {
    let folder = path.parent().unwrap_or(Path::new("."));
    let mut materials = HashMap::new();
    for (_, library) in &data.libraries {
        // Several libraries may share one statement; a single name may contain spaces.
        let whole = folder.join(library);
        let files: Vec<std::path::PathBuf> = if whole.is_file() {
            vec![whole]
        } else {
            library.split_whitespace().map(|f| folder.join(f)).collect()
        };
        for file in files {
            if !file.is_file() {
                warnings.push(format!(
                    "material library {} not found: its materials render grey",
                    file.display()
                ));
                continue;
            }
            for m in parse_mtl(&file)? {
                materials.entry(m.name.clone()).or_insert((m, file.clone()));
            }
        }
    }
    Ok(materials)
}

/// Loads an OBJ file (and its MTL libraries and textures) into a [`Mesh`] in the file's own
/// coordinates, with the warnings about what could not be used.
///
/// Materials: `map_Kd` gives a texture; without one, vertex colours if the file has them,
/// else the `Kd` colour. A missing library, material or texture renders grey (0.5) with a
/// warning. Vertex colours above 1 are taken as 0..255. Only vertices that faces use are
/// kept.
pub(crate) fn load_obj(path: &Path) -> Result<(Mesh, Vec<String>), ScanError> {
    let data = parse_obj(path)?;
    if data.faces.is_empty() {
        return Err(ScanError::invalid(path, "no faces: nothing to render"));
    }
    let mut warnings = Vec::new();
    if !data.unknown.is_empty() {
        warnings.push(format!(
            "{}: skipped unknown statements: {}",
            path.display(),
            data.unknown.join(", ")
        ));
    }
    let has_colors = data.colors.iter().any(Option::is_some);
    let color_scale = if data.colors.iter().flatten().flatten().any(|&c| c > 1.0) {
        1.0 / 255.0
    } else {
        1.0
    };
    let untextured = if has_colors {
        Shading::VertexColors
    } else {
        Shading::Flat(GREY)
    };
    let libraries = read_libraries(path, &data, &mut warnings)?;
    let mut textures = TextureCache::default();

    // One material per `usemtl` name, plus a default for faces before any `usemtl` and a
    // fallback per textured material for faces without UVs.
    let mut materials: Vec<Material> = Vec::new();
    for name in &data.material_names {
        let shading = match libraries.get(name) {
            None => {
                if !data.libraries.is_empty() {
                    warnings.push(format!(
                        "{}: material '{name}' is not defined in its libraries: rendered grey",
                        path.display()
                    ));
                }
                untextured.clone()
            }
            Some((m, library)) => match &m.diffuse_map {
                Some(file) => {
                    let file = library.parent().unwrap_or(Path::new(".")).join(file);
                    match textures.get(&file) {
                        Ok(texture) => Shading::Texture(texture),
                        Err(why) => {
                            warnings.push(format!("material '{name}': {why}: rendered grey"));
                            Shading::Flat(GREY)
                        }
                    }
                }
                None if has_colors => Shading::VertexColors,
                None => Shading::Flat(m.diffuse.unwrap_or(GREY)),
            },
        };
        materials.push(Material::new(name.clone(), shading));
    }
    let default_material = materials.len();
    materials.push(Material::new("default", untextured.clone()));
    let mut without_uvs: HashMap<usize, u32> = HashMap::new();

    // Keep only referenced vertices, in order of first use.
    let mut remap = vec![u32::MAX; data.positions.len()];
    let mut positions = Vec::new();
    let mut colors = Vec::new();
    let mut triangles = Vec::new();
    let mut triangle_materials = Vec::new();
    let mut corner_uvs = Vec::new();
    for face in &data.faces {
        let corners = &data.corners[face.start..face.start + face.len];
        let mut material = face.material.unwrap_or(default_material);
        let has_uv = corners[0].1 != NO_UV;
        if matches!(materials[material].shading, Shading::Texture(_)) && !has_uv {
            let fallback = *without_uvs.entry(material).or_insert_with(|| {
                warnings.push(format!(
                    "{}:{}: faces of textured material '{}' without texture coordinates: \
                     rendered grey",
                    path.display(),
                    face.line,
                    materials[material].name
                ));
                materials.push(Material::new(
                    format!("{} (no UVs)", materials[material].name),
                    Shading::Flat(GREY),
                ));
                (materials.len() - 1) as u32
            });
            material = fallback as usize;
        }
        let points: Vec<Vec3> = corners
            .iter()
            .map(|c| data.positions[c.0 as usize])
            .collect();
        for tri in triangulate(&points) {
            let ids = tri.map(|k| {
                let v = corners[k].0 as usize;
                if remap[v] == u32::MAX {
                    remap[v] = positions.len() as u32;
                    positions.push(data.positions[v]);
                    colors.push(
                        data.colors[v]
                            .map(|c| c.map(|x| (x * color_scale).clamp(0.0, 1.0)))
                            .unwrap_or(GREY),
                    );
                }
                remap[v]
            });
            triangles.push(ids);
            triangle_materials.push(material as u32);
            corner_uvs.push(tri.map(|k| {
                let t = corners[k].1;
                if t == NO_UV {
                    Vec2::ZERO
                } else {
                    data.uvs[t as usize]
                }
            }));
        }
    }
    let textured = materials
        .iter()
        .any(|m| matches!(m.shading, Shading::Texture(_)));
    let mut mesh = Mesh::with_vertex_colors(positions, triangles, colors);
    if !materials.iter().all(|m| m.shading == Shading::VertexColors) {
        mesh.materials = materials;
        mesh.triangle_materials = triangle_materials;
    }
    if textured {
        mesh.corner_uvs = corner_uvs;
    }
    mesh.validate()
        .map_err(|e| ScanError::invalid(path, e.to_string()))?;
    Ok((mesh, warnings))
}
