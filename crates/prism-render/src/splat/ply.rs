//! The standard 3DGS PLY layout (the one of the INRIA reference code, read by the common splat
//! viewers): one binary little-endian `vertex` element with the float properties
//!
//! ```text
//! x y z  nx ny nz  f_dc_0 f_dc_1 f_dc_2  f_rest_0 .. f_rest_{M-1}  opacity
//! scale_0 scale_1 scale_2  rot_0 rot_1 rot_2 rot_3
//! ```
//!
//! `opacity` is a logit, `scale_*` are natural logs, `rot_*` a quaternion `w x y z` (not
//! necessarily normalised), `f_dc_*` the degree-0 spherical-harmonics coefficients of R, G, B and
//! `f_rest_*` the higher degrees, channel-major (all of R's coefficients, then G's, then B's), so
//! `M = 3 ((d + 1)^2 - 1)` is 0, 9, 24 or 45 for degree `d = 0..=3`.
//!
//! Reading accepts any property order and any scalar property type, and ignores unknown
//! properties and elements after `vertex`; writing produces exactly the layout above.

use std::collections::HashMap;
use std::io::Write;
use std::path::Path;

use burn::tensor::{Device, Tensor, TensorData};

use super::render::Gaussians;
use crate::RenderError;

/// `Y_0^0 = 1 / (2 sqrt(pi))`: colour `= 0.5 + SH_C0 * f_dc` for the degree-0 term.
pub const SH_C0: f32 = 0.282_094_8;

/// Gaussians as stored in a 3DGS PLY file (the raw, unconstrained parameters).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GaussianCloud {
    /// Centres.
    pub means: Vec<[f32; 3]>,
    /// Normals (unused by 3DGS, written as zeros by most tools; kept for round trips).
    pub normals: Vec<[f32; 3]>,
    /// Degree-0 spherical-harmonics coefficients of R, G, B.
    pub sh_dc: Vec<[f32; 3]>,
    /// Spherical-harmonics degree, 0 to 3.
    pub sh_degree: usize,
    /// Per Gaussian `3 * ((sh_degree + 1)^2 - 1)` higher-degree coefficients in file order
    /// (channel-major), flattened.
    pub sh_rest: Vec<f32>,
    /// Opacities before the sigmoid.
    pub opacity_logits: Vec<f32>,
    /// Natural logs of the scales.
    pub log_scales: Vec<[f32; 3]>,
    /// Quaternions `w x y z`.
    pub rotations: Vec<[f32; 4]>,
}

/// Scalar property types of the PLY format.
#[derive(Clone, Copy, Debug)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    fn read(self, b: &[u8]) -> f32 {
        match self {
            Self::I8 => b[0] as i8 as f32,
            Self::U8 => b[0] as f32,
            Self::I16 => i16::from_le_bytes([b[0], b[1]]) as f32,
            Self::U16 => u16::from_le_bytes([b[0], b[1]]) as f32,
            Self::I32 => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
            Self::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
            Self::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            Self::F64 => {
                f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]) as f32
            }
        }
    }
}

/// Higher-degree coefficients per colour channel for SH degree `d`: `(d + 1)^2 - 1`.
pub fn sh_rest_per_channel(degree: usize) -> usize {
    (degree + 1) * (degree + 1) - 1
}

impl GaussianCloud {
    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.means.len()
    }

    /// Whether there is no Gaussian.
    pub fn is_empty(&self) -> bool {
        self.means.is_empty()
    }

    /// A degree-0 cloud from colours: `f_dc = (colour - 0.5) / SH_C0`, normals zero.
    pub fn from_colours(
        means: Vec<[f32; 3]>,
        log_scales: Vec<[f32; 3]>,
        rotations: Vec<[f32; 4]>,
        opacity_logits: Vec<f32>,
        colours: &[[f32; 3]],
    ) -> Self {
        Self {
            normals: vec![[0.0; 3]; means.len()],
            means,
            sh_dc: colours
                .iter()
                .map(|c| c.map(|v| (v - 0.5) / SH_C0))
                .collect(),
            sh_degree: 0,
            sh_rest: Vec::new(),
            opacity_logits,
            log_scales,
            rotations,
        }
    }

    /// The view-independent colours, from the degree-0 term: `max(0, 0.5 + SH_C0 f_dc)`.
    pub fn colours(&self) -> Vec<[f32; 3]> {
        self.sh_dc
            .iter()
            .map(|dc| dc.map(|v| (0.5 + SH_C0 * v).max(0.0)))
            .collect()
    }

    /// Checks that every field has one entry per Gaussian and the degree is 0 to 3.
    ///
    /// # Errors
    /// A message naming the inconsistent field.
    pub fn check(&self) -> Result<(), String> {
        let n = self.len();
        if self.sh_degree > 3 {
            return Err(format!("SH degree {} is not in 0..=3", self.sh_degree));
        }
        let rest = 3 * sh_rest_per_channel(self.sh_degree) * n;
        for (name, len, expected) in [
            ("normals", self.normals.len(), n),
            ("sh_dc", self.sh_dc.len(), n),
            ("sh_rest", self.sh_rest.len(), rest),
            ("opacity_logits", self.opacity_logits.len(), n),
            ("log_scales", self.log_scales.len(), n),
            ("rotations", self.rotations.len(), n),
        ] {
            if len != expected {
                return Err(format!("{name} has {len} values, expected {expected}"));
            }
        }
        Ok(())
    }

    /// The cloud as a batch of one for [`super::render()`], with the degree-0 colours as the
    /// three feature channels.
    pub fn to_gaussians(&self, device: &Device) -> Gaussians {
        let n = self.len();
        let t =
            |v: Vec<f32>, c: usize| Tensor::<3>::from_data(TensorData::new(v, [1, n, c]), device);
        Gaussians {
            means: t(self.means.concat(), 3),
            log_scales: t(self.log_scales.concat(), 3),
            rotations: t(self.rotations.concat(), 4),
            opacity_logits: t(self.opacity_logits.clone(), 1),
            features: t(self.colours().concat(), 3),
        }
    }

    /// Batch element `b` of `gaussians`, whose three feature channels are RGB colours in
    /// [0, 1], as a degree-0 cloud (for exporting predicted Gaussians).
    ///
    /// # Errors
    /// [`RenderError::Input`] when the shapes do not fit, there are not 3 channels or `b` is
    /// out of range.
    pub fn from_gaussians(gaussians: &Gaussians, b: usize) -> Result<Self, RenderError> {
        let [batch, _, c] = gaussians.dims()?;
        if c != 3 {
            return Err(RenderError::Input(format!(
                "a PLY file stores RGB colours, the Gaussians have {c} feature channels"
            )));
        }
        if b >= batch {
            return Err(RenderError::Input(format!(
                "batch element {b} of a batch of {batch}"
            )));
        }
        let host = |t: &Tensor<3>| -> Result<Vec<f32>, RenderError> {
            t.clone()
                .narrow(0, b, 1)
                .into_data()
                .convert::<f32>()
                .try_to_vec::<f32>()
                .map_err(|e| RenderError::Input(format!("reading Gaussians: {e:?}")))
        };
        let arrays3 = |v: Vec<f32>| -> Vec<[f32; 3]> {
            v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
        };
        let colours = arrays3(host(&gaussians.features)?);
        Ok(Self::from_colours(
            arrays3(host(&gaussians.means)?),
            arrays3(host(&gaussians.log_scales)?),
            host(&gaussians.rotations)?
                .chunks_exact(4)
                .map(|c| [c[0], c[1], c[2], c[3]])
                .collect(),
            host(&gaussians.opacity_logits)?,
            &colours,
        ))
    }

    /// Parses a PLY file's bytes; `path` only names the file in errors.
    ///
    /// # Errors
    /// [`RenderError::Format`] naming what is wrong.
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self, RenderError> {
        let bad = |msg: String| RenderError::format(path, msg);
        let header_end = find(bytes, b"end_header")
            .ok_or_else(|| bad("not a PLY file (no `end_header`)".into()))?;
        let mut body = header_end + b"end_header".len();
        match bytes.get(body) {
            Some(b'\n') => body += 1,
            Some(b'\r') if bytes.get(body + 1) == Some(&b'\n') => body += 2,
            _ => return Err(bad("malformed `end_header` line".into())),
        }
        let header = std::str::from_utf8(&bytes[..header_end])
            .map_err(|_| bad("the header is not text".into()))?;
        let mut lines = header.lines().map(str::trim).filter(|l| !l.is_empty());
        if lines.next() != Some("ply") {
            return Err(bad("not a PLY file (no `ply` magic line)".into()));
        }
        let mut count = None;
        let mut props: Vec<(String, Scalar)> = Vec::new();
        let mut in_vertex = false;
        for line in lines {
            let words: Vec<&str> = line.split_whitespace().collect();
            match words.as_slice() {
                ["format", "binary_little_endian", _] => {}
                ["format", other, ..] => {
                    return Err(bad(format!(
                        "PLY format `{other}` is not supported (only binary_little_endian)"
                    )));
                }
                ["comment", ..] | ["obj_info", ..] => {}
                ["element", name, n] => {
                    if count.is_some() {
                        // Elements after `vertex` are stored after its data: ignore them.
                        in_vertex = false;
                        continue;
                    }
                    if *name != "vertex" {
                        return Err(bad(format!(
                            "element `{name}` before `vertex` is not supported"
                        )));
                    }
                    count = Some(
                        n.parse::<usize>()
                            .map_err(|_| bad(format!("bad vertex count `{n}`")))?,
                    );
                    in_vertex = true;
                }
                ["property", "list", ..] if in_vertex => {
                    return Err(bad("list properties in `vertex` are not supported".into()));
                }
                ["property", ty, name] if in_vertex => {
                    let ty = Scalar::parse(ty)
                        .ok_or_else(|| bad(format!("unknown property type `{ty}`")))?;
                    props.push((name.to_string(), ty));
                }
                ["property", ..] => {}
                _ => return Err(bad(format!("unexpected header line `{line}`"))),
            }
        }
        let n = count.ok_or_else(|| bad("no `vertex` element".into()))?;
        let mut offsets = HashMap::new();
        let mut stride = 0;
        for (name, ty) in &props {
            offsets.insert(name.as_str(), (stride, *ty));
            stride += ty.size();
        }
        let field = |name: &str| -> Result<(usize, Scalar), RenderError> {
            offsets
                .get(name)
                .copied()
                .ok_or_else(|| bad(format!("missing vertex property `{name}`")))
        };
        let rest_count = (0..)
            .take_while(|k| offsets.contains_key(format!("f_rest_{k}").as_str()))
            .count();
        let sh_degree = (0..=3)
            .find(|d| 3 * sh_rest_per_channel(*d) == rest_count)
            .ok_or_else(|| {
                bad(format!(
                    "{rest_count} f_rest properties: expected 0, 9, 24 or 45 (SH degree 0 to 3)"
                ))
            })?;
        let data = &bytes[body..];
        if data.len() < n * stride {
            return Err(bad(format!(
                "truncated: {n} Gaussians need {} bytes of data, the file has {}",
                n * stride,
                data.len()
            )));
        }
        let get = |names: &[&str]| -> Result<Vec<(usize, Scalar)>, RenderError> {
            names.iter().map(|s| field(s)).collect()
        };
        let xyz = get(&["x", "y", "z"])?;
        let normal = get(&["nx", "ny", "nz"]).ok();
        let dc = get(&["f_dc_0", "f_dc_1", "f_dc_2"])?;
        let rest: Vec<String> = (0..rest_count).map(|k| format!("f_rest_{k}")).collect();
        let rest = get(&rest.iter().map(String::as_str).collect::<Vec<_>>())?;
        let opacity = field("opacity")?;
        let scale = get(&["scale_0", "scale_1", "scale_2"])?;
        let rot = get(&["rot_0", "rot_1", "rot_2", "rot_3"])?;

        let mut cloud = Self {
            sh_degree,
            ..Self::default()
        };
        for record in data[..n * stride].chunks_exact(stride) {
            let v = |(o, ty): (usize, Scalar)| ty.read(&record[o..o + ty.size()]);
            let a3 = |f: &[(usize, Scalar)]| [v(f[0]), v(f[1]), v(f[2])];
            cloud.means.push(a3(&xyz));
            cloud
                .normals
                .push(normal.as_ref().map_or([0.0; 3], |f| a3(f)));
            cloud.sh_dc.push(a3(&dc));
            cloud.sh_rest.extend(rest.iter().map(|f| v(*f)));
            cloud.opacity_logits.push(v(opacity));
            cloud.log_scales.push(a3(&scale));
            cloud
                .rotations
                .push([v(rot[0]), v(rot[1]), v(rot[2]), v(rot[3])]);
        }
        Ok(cloud)
    }

    /// Reads a 3DGS PLY file.
    ///
    /// # Errors
    /// [`RenderError::Io`] when the file cannot be read, [`RenderError::Format`] when it is not
    /// a 3DGS PLY file; both name the file.
    pub fn read(path: impl AsRef<Path>) -> Result<Self, RenderError> {
        let path = path.as_ref();
        let bytes = std::fs::read(path).map_err(|e| RenderError::io(path, e))?;
        Self::from_bytes(&bytes, path)
    }

    /// The file's bytes in the layout of the module documentation.
    ///
    /// # Errors
    /// When the fields are inconsistent (see [`GaussianCloud::check`]).
    pub fn to_bytes(&self) -> Result<Vec<u8>, String> {
        self.check()?;
        let rest = 3 * sh_rest_per_channel(self.sh_degree);
        let mut names: Vec<String> = [
            "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        names.extend((0..rest).map(|k| format!("f_rest_{k}")));
        names.extend(
            [
                "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
            ]
            .iter()
            .map(|s| s.to_string()),
        );
        let mut out = Vec::with_capacity(256 + self.len() * names.len() * 4);
        write!(
            out,
            "ply\nformat binary_little_endian 1.0\nelement vertex {}\n",
            self.len()
        )
        .expect("writing to memory");
        for name in &names {
            writeln!(out, "property float {name}").expect("writing to memory");
        }
        out.extend_from_slice(b"end_header\n");
        for i in 0..self.len() {
            let values = self.means[i]
                .iter()
                .chain(&self.normals[i])
                .chain(&self.sh_dc[i])
                .chain(&self.sh_rest[i * rest..(i + 1) * rest])
                .chain([&self.opacity_logits[i]])
                .chain(&self.log_scales[i])
                .chain(&self.rotations[i]);
            for v in values {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        Ok(out)
    }

    /// Writes a 3DGS PLY file, atomically (a temporary file renamed into place).
    ///
    /// # Errors
    /// [`RenderError::Io`] when the file cannot be written, [`RenderError::Format`] when the
    /// cloud's fields are inconsistent; both name the file.
    pub fn write(&self, path: impl AsRef<Path>) -> Result<(), RenderError> {
        let path = path.as_ref();
        let bytes = self.to_bytes().map_err(|m| RenderError::format(path, m))?;
        prism_core::files::write_bytes(path, &bytes).map_err(|e| RenderError::io(path, e))
    }
}

fn find(haystack: &[u8], needle: &[u8]) -> Option<usize> {
    haystack.windows(needle.len()).position(|w| w == needle)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colours_invert_from_colours() {
        let c = [[0.1, 0.5, 0.95]];
        let cloud = GaussianCloud::from_colours(
            vec![[0.0; 3]],
            vec![[0.0; 3]],
            vec![[1.0, 0.0, 0.0, 0.0]],
            vec![0.0],
            &c,
        );
        for (a, b) in cloud.colours()[0].iter().zip(c[0]) {
            assert!((a - b).abs() < 1e-6);
        }
        // Negative colours clamp to 0.
        let mut dark = cloud.clone();
        dark.sh_dc[0][0] = -10.0;
        assert_eq!(dark.colours()[0][0], 0.0);
    }

    #[test]
    fn headers_with_other_types_orders_and_elements_are_read() {
        let mut bytes = b"ply\r\nformat binary_little_endian 1.0\r\ncomment made by hand\r\n\
element vertex 1\r\nproperty double rot_0\r\nproperty float rot_1\r\nproperty float rot_2\r\n\
property float rot_3\r\nproperty float scale_0\r\nproperty float scale_1\r\n\
property float scale_2\r\nproperty float opacity\r\nproperty float f_dc_0\r\n\
property float f_dc_1\r\nproperty float f_dc_2\r\nproperty uchar red\r\nproperty float x\r\n\
property float y\r\nproperty float z\r\nelement face 0\r\nproperty list uchar int vertex_indices\r\n\
end_header\r\n"
            .to_vec();
        bytes.extend(0.5f64.to_le_bytes());
        for v in [0.1f32, 0.2, 0.3, -1.0, -2.0, -3.0, 0.7, 1.0, 2.0, 3.0] {
            bytes.extend(v.to_le_bytes());
        }
        bytes.push(200);
        for v in [4.0f32, 5.0, 6.0] {
            bytes.extend(v.to_le_bytes());
        }
        let c = GaussianCloud::from_bytes(&bytes, Path::new("hand.ply")).unwrap();
        assert_eq!(c.means, vec![[4.0, 5.0, 6.0]]);
        assert_eq!(c.rotations, vec![[0.5, 0.1, 0.2, 0.3]]);
        assert_eq!(c.log_scales, vec![[-1.0, -2.0, -3.0]]);
        assert_eq!(c.opacity_logits, vec![0.7]);
        assert_eq!(c.sh_dc, vec![[1.0, 2.0, 3.0]]);
        assert_eq!(c.normals, vec![[0.0; 3]]);
        assert_eq!(c.sh_degree, 0);
    }

    #[test]
    fn malformed_files_are_errors_naming_the_problem() {
        let p = Path::new("f.ply");
        let msg = |b: &[u8]| GaussianCloud::from_bytes(b, p).unwrap_err().to_string();
        assert!(msg(b"hello").contains("no `end_header`"));
        assert!(msg(b"ply\nformat ascii 1.0\nelement vertex 0\nend_header\n").contains("ascii"));
        let header = "ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nend_header\n";
        assert!(msg(header.as_bytes()).contains("truncated"));
        let mut ok = header.as_bytes().to_vec();
        ok.extend([0u8; 8]);
        assert!(msg(&ok).contains("missing vertex property `y`"));
        let rest = "ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float f_rest_0\nend_header\n";
        assert!(msg(rest.as_bytes()).contains("1 f_rest properties"));
        assert!(msg(rest.as_bytes()).starts_with("f.ply: "));
    }
}
