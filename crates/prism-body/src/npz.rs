//! Reading and writing body models as SMPL-X `.npz` archives.
//!
//! Floats may be stored as float32 or float64, integer arrays (`f`, `kintree_table`) as
//! int32/int64/uint32/uint64, in C or Fortran order, with or without compression, as the
//! official SMPL-X files are. The root's parent may be stored as -1 or as 2^32 - 1 (the uint32
//! wrap-around found in SMPL-family files). Keys prism does not use are ignored.

use std::fs::File;
use std::io::{BufReader, Read, Seek, Write};
use std::path::{Path, PathBuf};

use glam::Vec3;
use npyz::{DType, NpyFile, Order, TypeChar};
use zip::ZipArchive;
use zip::result::ZipError;
use zip::write::SimpleFileOptions;

use super::error::BodyError;
use super::joints::{NUM_BETAS, NUM_EXPRESSION, NUM_JOINTS, NUM_POSE_FEATURES};
use super::model::{BodyArrays, BodyModel, NUM_SHAPE_COEFFS};

/// Offset of the expression directions inside `shapedirs` of SMPL-X v1.1 (`S = 400`).
const V11_EXPRESSION_OFFSET: usize = 300;

/// An array read from the archive, converted to C order.
struct Array<T> {
    shape: Vec<u64>,
    data: Vec<T>,
}

struct Reader<R: Read + Seek> {
    archive: ZipArchive<R>,
    path: PathBuf,
}

impl<R: Read + Seek> Reader<R> {
    fn open_key(
        &mut self,
        key: &str,
        expected: &str,
    ) -> Result<NpyFile<impl Read + '_>, BodyError> {
        let path = &self.path;
        let io = |error| BodyError::Io {
            path: path.clone(),
            error,
        };
        match self.archive.by_name(&npy_name(key)) {
            Ok(entry) => NpyFile::new(entry).map_err(io),
            Err(ZipError::FileNotFound) => Err(BodyError::MissingKey {
                path: path.clone(),
                key: key.to_string(),
                expected: expected.to_string(),
            }),
            Err(error) => Err(io(error.into())),
        }
    }

    /// A float array (float32 or float64) as f32.
    fn floats(&mut self, key: &str, expected: &str) -> Result<Array<f32>, BodyError> {
        let path = self.path.clone();
        let file = self.open_key(key, expected)?;
        let shape = file.shape().to_vec();
        let order = file.order();
        let dtype_err = |dtype: &DType| BodyError::DType {
            path: path.clone(),
            key: key.to_string(),
            dtype: dtype.descr(),
            expected: "float32 or float64",
        };
        let io_err = |source| BodyError::Io {
            path: path.clone(),
            error: source,
        };
        let dtype = file.dtype();
        let data: Vec<f32> = match &dtype {
            DType::Plain(t) if t.type_char() == TypeChar::Float && t.size_field() == 4 => {
                file.into_vec::<f32>().map_err(io_err)?
            }
            DType::Plain(t) if t.type_char() == TypeChar::Float && t.size_field() == 8 => file
                .into_vec::<f64>()
                .map_err(io_err)?
                .into_iter()
                .map(|x| x as f32)
                .collect(),
            other => return Err(dtype_err(other)),
        };
        Ok(Array {
            data: to_c_order(data, &shape, order),
            shape,
        })
    }

    /// An integer array (signed or unsigned, 32 or 64 bit) as i64.
    fn ints(&mut self, key: &str, expected: &str) -> Result<Array<i64>, BodyError> {
        let path = self.path.clone();
        let file = self.open_key(key, expected)?;
        let shape = file.shape().to_vec();
        let order = file.order();
        let io_err = |source| BodyError::Io {
            path: path.clone(),
            error: source,
        };
        let dtype = file.dtype();
        let data: Vec<i64> = match &dtype {
            DType::Plain(t) => match (t.type_char(), t.size_field()) {
                (TypeChar::Int, 4) => file
                    .into_vec::<i32>()
                    .map_err(io_err)?
                    .into_iter()
                    .map(i64::from)
                    .collect(),
                (TypeChar::Int, 8) => file.into_vec::<i64>().map_err(io_err)?,
                (TypeChar::Uint, 4) => file
                    .into_vec::<u32>()
                    .map_err(io_err)?
                    .into_iter()
                    .map(i64::from)
                    .collect(),
                (TypeChar::Uint, 8) => file
                    .into_vec::<u64>()
                    .map_err(io_err)?
                    .into_iter()
                    .map(|x| x as i64)
                    .collect(),
                _ => {
                    return Err(BodyError::DType {
                        path,
                        key: key.to_string(),
                        dtype: dtype.descr(),
                        expected: "int32, int64, uint32 or uint64",
                    });
                }
            },
            other => {
                return Err(BodyError::DType {
                    path,
                    key: key.to_string(),
                    dtype: other.descr(),
                    expected: "int32, int64, uint32 or uint64",
                });
            }
        };
        Ok(Array {
            data: to_c_order(data, &shape, order),
            shape,
        })
    }

    fn shape_err(&self, key: &str, expected: String, actual: &[u64]) -> BodyError {
        BodyError::Shape {
            path: self.path.clone(),
            key: key.to_string(),
            expected,
            actual: actual.to_vec(),
        }
    }
}

/// Reorders a Fortran-order buffer into C order (no-op for C order).
fn to_c_order<T: Copy>(data: Vec<T>, shape: &[u64], order: Order) -> Vec<T> {
    if shape.len() < 2 || matches!(order, Order::C) {
        return data;
    }
    let dims: Vec<usize> = shape.iter().map(|&d| d as usize).collect();
    let mut out = Vec::with_capacity(data.len());
    let mut index = vec![0usize; dims.len()];
    for _ in 0..data.len() {
        // Fortran offset of the current C-order multi-index.
        let mut offset = 0;
        let mut stride = 1;
        for (i, d) in index.iter().zip(&dims) {
            offset += i * stride;
            stride *= d;
        }
        out.push(data[offset]);
        for k in (0..dims.len()).rev() {
            index[k] += 1;
            if index[k] < dims[k] {
                break;
            }
            index[k] = 0;
        }
    }
    out
}

impl BodyModel {
    /// Loads a body model from an SMPL-X `.npz` file.
    ///
    /// # Errors
    /// A message naming the file and, for a missing or misshapen array, the key with its expected
    /// and actual shape.
    pub fn load_npz(path: impl AsRef<Path>) -> Result<Self, BodyError> {
        let path = path.as_ref();
        let io = |source| BodyError::Io {
            path: path.to_path_buf(),
            error: source,
        };
        let file = File::open(path).map_err(io)?;
        let archive = ZipArchive::new(BufReader::new(file)).map_err(|error| io(error.into()))?;
        let mut r = Reader {
            archive,
            path: path.to_path_buf(),
        };

        let t = r.floats("v_template", "[V, 3]")?;
        if t.shape.len() != 2 || t.shape[1] != 3 || t.shape[0] == 0 {
            return Err(r.shape_err("v_template", "[V, 3] with V > 0".into(), &t.shape));
        }
        let v = t.shape[0];
        let v_template: Vec<Vec3> = t.data.chunks_exact(3).map(Vec3::from_slice).collect();

        let f = r.ints("f", "[F, 3]")?;
        if f.shape.len() != 2 || f.shape[1] != 3 {
            return Err(r.shape_err("f", "[F, 3]".into(), &f.shape));
        }
        let mut faces = Vec::with_capacity(f.data.len() / 3);
        for (i, c) in f.data.chunks_exact(3).enumerate() {
            let mut tri = [0u32; 3];
            for (k, &x) in c.iter().enumerate() {
                tri[k] = u32::try_from(x).map_err(|_| BodyError::Value {
                    path: path.to_path_buf(),
                    key: "f".into(),
                    message: format!("face {i} has the negative or huge index {x}"),
                })?;
            }
            faces.push(tri);
        }

        let s = r.floats("shapedirs", &format!("[{v}, 3, 20] or [{v}, 3, 400]"))?;
        let expr_offset = match s.shape.as_slice() {
            [sv, 3, 400] if *sv == v => V11_EXPRESSION_OFFSET,
            [sv, 3, 20] if *sv == v => NUM_BETAS,
            _ => {
                return Err(r.shape_err(
                    "shapedirs",
                    format!("[{v}, 3, 20] or [{v}, 3, 400] (SMPL-X v1.0 or v1.1)"),
                    &s.shape,
                ));
            }
        };
        let stride = s.shape[2] as usize;
        let mut shapedirs = Vec::with_capacity(v as usize * 3 * NUM_SHAPE_COEFFS);
        for row in s.data.chunks_exact(stride) {
            shapedirs.extend_from_slice(&row[..NUM_BETAS]);
            shapedirs.extend_from_slice(&row[expr_offset..expr_offset + NUM_EXPRESSION]);
        }

        let expect = |shape: &[u64]| format!("{shape:?}");
        let p_shape = [v, 3, NUM_POSE_FEATURES as u64];
        let p = r.floats("posedirs", &expect(&p_shape))?;
        if p.shape != p_shape {
            return Err(r.shape_err("posedirs", expect(&p_shape), &p.shape));
        }
        let j_shape = [NUM_JOINTS as u64, v];
        let j = r.floats("J_regressor", &expect(&j_shape))?;
        if j.shape != j_shape {
            return Err(r.shape_err("J_regressor", expect(&j_shape), &j.shape));
        }
        let w_shape = [v, NUM_JOINTS as u64];
        let w = r.floats("weights", &expect(&w_shape))?;
        if w.shape != w_shape {
            return Err(r.shape_err("weights", expect(&w_shape), &w.shape));
        }
        let k_shape = [2, NUM_JOINTS as u64];
        let k = r.ints("kintree_table", &expect(&k_shape))?;
        if k.shape != k_shape {
            return Err(r.shape_err("kintree_table", expect(&k_shape), &k.shape));
        }
        let parents = k.data[..NUM_JOINTS]
            .iter()
            .map(|&p| {
                if p < 0 || p == u32::MAX as i64 {
                    None
                } else {
                    Some(p as usize)
                }
            })
            .collect();

        BodyModel::from_arrays_at(
            BodyArrays {
                v_template,
                faces,
                shapedirs,
                posedirs: p.data,
                j_regressor: j.data,
                weights: w.data,
                parents,
            },
            path,
        )
    }

    /// Saves the model as an SMPL-X v1.0-style `.npz` (float32 arrays, `shapedirs [V, 3, 20]`,
    /// int32 faces, int64 `kintree_table` with -1 for the root), compressed. The file is written
    /// to a temporary name next to `path` and renamed, so that it is never half-written.
    ///
    /// # Errors
    /// When the file cannot be written.
    pub fn save_npz(&self, path: impl AsRef<Path>) -> Result<(), BodyError> {
        let path = path.as_ref();
        let io = |error| BodyError::Io {
            path: path.to_path_buf(),
            error,
        };
        let bytes = self.npz_bytes().map_err(io)?;
        prism_core::files::write_bytes(path, &bytes).map_err(io)
    }

    /// The compressed `.npz` archive in memory (the zip writer needs to seek).
    fn npz_bytes(&self) -> std::io::Result<Vec<u8>> {
        let v = self.num_vertices() as u64;
        let j = NUM_JOINTS as u64;
        let options = SimpleFileOptions::default()
            .compression_method(zip::CompressionMethod::Deflated)
            .compression_level(Some(1))
            .large_file(true);
        let mut zip = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
        let f32s = |x: &[f32]| x.iter().flat_map(|a| a.to_le_bytes()).collect::<Vec<u8>>();
        let template: Vec<f32> = self.v_template.iter().flat_map(|p| p.to_array()).collect();
        let faces: Vec<u8> = self
            .faces
            .iter()
            .flatten()
            .flat_map(|&i| (i as i32).to_le_bytes())
            .collect();
        let mut kintree: Vec<i64> = self
            .parents
            .iter()
            .map(|p| p.map_or(-1, |p| p as i64))
            .collect();
        kintree.extend(0..NUM_JOINTS as i64);
        let kintree: Vec<u8> = kintree.iter().flat_map(|k| k.to_le_bytes()).collect();
        let arrays: [(&str, &str, Vec<u64>, Vec<u8>); 7] = [
            ("v_template", "<f4", vec![v, 3], f32s(&template)),
            ("f", "<i4", vec![self.faces.len() as u64, 3], faces),
            (
                "shapedirs",
                "<f4",
                vec![v, 3, NUM_SHAPE_COEFFS as u64],
                f32s(&self.shapedirs),
            ),
            (
                "posedirs",
                "<f4",
                vec![v, 3, NUM_POSE_FEATURES as u64],
                f32s(&self.posedirs),
            ),
            ("J_regressor", "<f4", vec![j, v], f32s(&self.j_regressor)),
            ("weights", "<f4", vec![v, j], f32s(&self.weights)),
            ("kintree_table", "<i8", vec![2, j], kintree),
        ];
        for (key, descr, shape, bytes) in arrays {
            zip.start_file(npy_name(key), options)?;
            zip.write_all(&npy_header(descr, &shape))?;
            zip.write_all(&bytes)?;
        }
        let archive = zip.finish()?;
        Ok(archive.into_inner())
    }
}

/// The name of an array's member in an `.npz` archive, as NumPy's `savez` writes it.
pub(crate) fn npy_name(key: &str) -> String {
    format!("{key}.npy")
}

/// The header of a version 1.0 `.npy` file for a C-order array: magic, version, header length
/// and the header dictionary padded with spaces to a multiple of 64 bytes.
fn npy_header(descr: &str, shape: &[u64]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape = if dims.len() == 1 {
        format!("({},)", dims[0])
    } else {
        format!("({})", dims.join(", "))
    };
    let mut dict = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
    let unpadded = 10 + dict.len() + 1;
    dict.push_str(&" ".repeat((64 - unpadded % 64) % 64));
    dict.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&(dict.len() as u16).to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fortran_order_is_transposed_to_c_order() {
        // A 2x3 matrix [[0,1,2],[3,4,5]] stored column-major.
        let fortran = vec![0, 3, 1, 4, 2, 5];
        assert_eq!(
            to_c_order(fortran, &[2, 3], Order::Fortran),
            vec![0, 1, 2, 3, 4, 5]
        );
        // 2x2x2: element (i, j, k) = 4i + 2j + k; Fortran offset i + 2j + 4k.
        let mut f = vec![0; 8];
        for i in 0..2 {
            for j in 0..2 {
                for k in 0..2 {
                    f[i + 2 * j + 4 * k] = 4 * i + 2 * j + k;
                }
            }
        }
        assert_eq!(
            to_c_order(f, &[2, 2, 2], Order::Fortran),
            (0..8).collect::<Vec<_>>()
        );
    }
}
