//! glTF 2.0 (`.gltf` with its buffers, or `.glb`): triangle primitives of the default scene
//! with their node transforms, base-colour textures, `COLOR_0` vertex colours and
//! base-colour factors. glTF is Y-up, in metres, and its assets face +Z, as the protocol.
//!
//! glTF stores colour factors and vertex colours in linear light; they are converted to the
//! display (sRGB) values the renderer works in. Textures already are sRGB-encoded. The
//! base-colour factor does not tint a texture (the pixel is the texture colour), and
//! texture transforms and sampler modes are ignored (textures repeat).

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use glam::{Mat4, Vec2, Vec3};
use gltf::image::Format;

use super::GREY;
use super::error::ScanError;
use crate::material::{Material, Shading, Texture};
use crate::mesh::Mesh;

/// Deepest node hierarchy followed (guards against cyclic files).
const MAX_DEPTH: usize = 64;

/// A linear-light value as an sRGB-encoded display value (IEC 61966-2-1).
fn linear_to_srgb(x: f32) -> f32 {
    let x = x.clamp(0.0, 1.0);
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// Whether a relative URI percent-decodes to UTF-8 (the glTF importer assumes it does).
fn uri_is_decodable(uri: &str) -> bool {
    if uri.contains(':') {
        return true;
    }
    let bytes = uri.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%' {
            let hex = uri
                .get(i + 1..i + 3)
                .and_then(|h| u8::from_str_radix(h, 16).ok());
            match hex {
                Some(b) => {
                    out.push(b);
                    i += 3;
                    continue;
                }
                None => out.push(b'%'),
            }
        } else {
            out.push(bytes[i]);
        }
        i += 1;
    }
    String::from_utf8(out).is_ok()
}

/// A decoded glTF image as a texture (alpha dropped, 16-bit and float channels reduced to
/// 8 bits, grey expanded to RGB).
fn texture_of(image: &gltf::image::Data) -> Result<Arc<Texture>, String> {
    let (w, h) = (image.width as usize, image.height as usize);
    let n = w * h;
    let px = &image.pixels;
    let (channels, bytes) = match image.format {
        Format::R8 => (1, 1),
        Format::R8G8 => (2, 1),
        Format::R8G8B8 => (3, 1),
        Format::R8G8B8A8 => (4, 1),
        Format::R16 => (1, 2),
        Format::R16G16 => (2, 2),
        Format::R16G16B16 => (3, 2),
        Format::R16G16B16A16 => (4, 2),
        Format::R32G32B32FLOAT => (3, 4),
        Format::R32G32B32A32FLOAT => (4, 4),
    };
    if n == 0 || px.len() < n * channels * bytes {
        return Err(format!("image of {w}x{h} has too few pixels"));
    }
    let value = |i: usize, c: usize| -> u8 {
        let at = (i * channels + c) * bytes;
        match bytes {
            1 => px[at],
            // Little-endian 16-bit: the high byte.
            2 => px[at + 1],
            _ => {
                let f = f32::from_le_bytes([px[at], px[at + 1], px[at + 2], px[at + 3]]);
                (f.clamp(0.0, 1.0) * 255.0).round() as u8
            }
        }
    };
    let texels = (0..n)
        .map(|i| {
            if channels < 3 {
                [value(i, 0); 3]
            } else {
                [value(i, 0), value(i, 1), value(i, 2)]
            }
        })
        .collect();
    Ok(Arc::new(Texture::from_rgb8(w, h, texels)))
}

/// Loads a glTF or GLB file into a [`Mesh`] in the file's coordinates (node transforms of
/// the default scene applied), with warnings about what could not be used.
pub(crate) fn load_gltf(path: &Path) -> Result<(Mesh, Vec<String>), ScanError> {
    let invalid = |e: gltf::Error| match e {
        gltf::Error::Io(source) => ScanError::Io {
            path: path.to_path_buf(),
            source,
        },
        e => ScanError::invalid(path, e.to_string()),
    };
    let file = gltf::Gltf::open(path).map_err(invalid)?;
    let document = &file.document;
    for buffer in document.buffers() {
        if let gltf::buffer::Source::Uri(uri) = buffer.source()
            && !uri_is_decodable(uri)
        {
            return Err(ScanError::invalid(path, format!("bad buffer URI '{uri}'")));
        }
    }
    let base = path.parent().unwrap_or(Path::new("."));
    let buffers = gltf::import_buffers(document, Some(base), file.blob.clone())
        .map_err(|e| ScanError::invalid(path, format!("cannot load buffers: {e}")))?;
    let mut warnings = Vec::new();

    // Base-colour textures, decoded once per image.
    let mut images: HashMap<usize, Option<Arc<Texture>>> = HashMap::new();
    let mut load_image = |image: gltf::Image<'_>, warnings: &mut Vec<String>| {
        images
            .entry(image.index())
            .or_insert_with(|| {
                let source = image.source();
                let decoded = match &source {
                    gltf::image::Source::Uri { uri, .. } if !uri_is_decodable(uri) => {
                        Err(format!("bad image URI '{uri}'"))
                    }
                    gltf::image::Source::View { view, .. }
                        if buffers
                            .get(view.buffer().index())
                            .is_none_or(|b| view.offset() + view.length() > b.len()) =>
                    {
                        Err("image buffer view out of range".to_string())
                    }
                    _ => gltf::image::Data::from_source(source, Some(base), &buffers)
                        .map_err(|e| e.to_string())
                        .and_then(|data| texture_of(&data)),
                };
                decoded
                    .map_err(|why| {
                        warnings.push(format!(
                            "{}: image {}: {why}: rendered grey",
                            path.display(),
                            image.index()
                        ));
                    })
                    .ok()
            })
            .clone()
    };

    let mut mesh = Mesh::default();
    let mut textured = false;
    // Our material per (glTF material, primitive has vertex colours).
    let mut material_ids: HashMap<(Option<usize>, bool), u32> = HashMap::new();
    let mut stack: Vec<(gltf::Node<'_>, Mat4, usize)> = match document
        .default_scene()
        .or_else(|| document.scenes().next())
    {
        Some(scene) => scene.nodes().map(|n| (n, Mat4::IDENTITY, 0)).collect(),
        None => document.nodes().map(|n| (n, Mat4::IDENTITY, 0)).collect(),
    };
    let mut skipped_modes = false;
    while let Some((node, parent, depth)) = stack.pop() {
        let transform = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        if depth < MAX_DEPTH {
            stack.extend(node.children().map(|c| (c, transform, depth + 1)));
        }
        let Some(gmesh) = node.mesh() else { continue };
        for primitive in gmesh.primitives() {
            if primitive.mode() != gltf::mesh::Mode::Triangles {
                skipped_modes = true;
                continue;
            }
            let reader = primitive.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
            let Some(positions) = reader.read_positions() else {
                continue;
            };
            let positions: Vec<Vec3> = positions
                .map(|p| transform.transform_point3(Vec3::from_array(p)))
                .collect();
            let count = positions.len();
            let indices: Vec<u32> = match reader.read_indices() {
                Some(i) => i.into_u32().collect(),
                None => (0..count as u32).collect(),
            };
            if let Some(&bad) = indices.iter().find(|&&i| i as usize >= count) {
                return Err(ScanError::invalid(
                    path,
                    format!(
                        "mesh {}: index {bad} past its {count} vertices",
                        gmesh.index()
                    ),
                ));
            }
            let colors: Option<Vec<[f32; 3]>> = reader
                .read_colors(0)
                .map(|c| c.into_rgb_f32().map(|c| c.map(linear_to_srgb)).collect());
            let material = primitive.material();
            let pbr = material.pbr_metallic_roughness();
            let texture = pbr.base_color_texture().and_then(|info| {
                let set = info.tex_coord();
                let uvs: Vec<Vec2> = reader
                    .read_tex_coords(set)?
                    .into_f32()
                    // glTF's v runs down the image; the mesh's runs up.
                    .map(|[u, v]| Vec2::new(u, 1.0 - v))
                    .collect();
                Some((info.texture().source(), uvs))
            });
            let has_colors = colors.as_ref().is_some_and(|c| c.len() == count);
            let key = (material.index(), has_colors);
            let (shading, uvs) = match texture {
                Some((image, uvs)) if uvs.len() == count => {
                    match load_image(image, &mut warnings) {
                        Some(t) => (Shading::Texture(t), Some(uvs)),
                        None => (Shading::Flat(GREY), None),
                    }
                }
                _ if has_colors => (Shading::VertexColors, None),
                _ => {
                    let f = pbr.base_color_factor();
                    (Shading::Flat([f[0], f[1], f[2]].map(linear_to_srgb)), None)
                }
            };
            let key = (key.0, key.1 || matches!(shading, Shading::Texture(_)));
            let id = *material_ids.entry(key).or_insert_with(|| {
                let name = material
                    .index()
                    .map_or("default".to_string(), |i| format!("glTF material {i}"));
                mesh.materials.push(Material::new(name, shading.clone()));
                (mesh.materials.len() - 1) as u32
            });
            let offset = mesh.positions.len() as u32;
            mesh.positions.extend(positions);
            match colors.filter(|_| has_colors) {
                Some(c) => mesh.colors.extend(c),
                None => mesh.colors.extend(std::iter::repeat_n(GREY, count)),
            }
            for tri in indices.chunks_exact(3) {
                mesh.triangles
                    .push([tri[0] + offset, tri[1] + offset, tri[2] + offset]);
                mesh.triangle_materials.push(id);
                let corner = |k: usize| uvs.as_ref().map_or(Vec2::ZERO, |u| u[tri[k] as usize]);
                mesh.corner_uvs.push([corner(0), corner(1), corner(2)]);
            }
            textured |= uvs.is_some();
        }
    }
    if skipped_modes {
        warnings.push(format!(
            "{}: skipped primitives that are not triangle lists",
            path.display()
        ));
    }
    if mesh.triangles.is_empty() {
        return Err(ScanError::invalid(path, "no triangles: nothing to render"));
    }
    if !textured {
        mesh.corner_uvs.clear();
    }
    mesh.validate()
        .map_err(|e| ScanError::invalid(path, e.to_string()))?;
    Ok((mesh, warnings))
}
