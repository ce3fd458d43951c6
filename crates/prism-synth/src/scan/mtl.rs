//! Wavefront MTL material libraries: the parts an unlit renderer needs (`newmtl`, `Kd`,
//! `map_Kd`).
//!
//! Hand-written for the reasons in `obj.rs`: tobj's MTL reader has no line numbers, panics on a
//! one-value `Kd`, keeps a `map_Kd`'s options in its file name and drops statements before the
//! first `newmtl` without an error.

use std::path::Path;

use super::error::ScanError;
use super::text::{floats, logical_lines, read_text};

/// One `newmtl` block.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct MtlMaterial {
    /// The material's name.
    pub name: String,
    /// Diffuse colour `Kd`, if given.
    pub diffuse: Option<[f32; 3]>,
    /// Diffuse texture `map_Kd` as written (relative to the MTL file), if given.
    pub diffuse_map: Option<String>,
}

/// Parses an MTL file. Statements other than `newmtl`, `Kd` and `map_Kd` are ignored
/// (lighting terms mean nothing to an unlit renderer).
pub(crate) fn parse_mtl(path: &Path) -> Result<Vec<MtlMaterial>, ScanError> {
    let text = read_text(path)?;
    let mut materials: Vec<MtlMaterial> = Vec::new();
    for (line, content) in logical_lines(&text) {
        let (keyword, rest) = content
            .split_once(char::is_whitespace)
            .map(|(k, r)| (k, r.trim()))
            .unwrap_or((content.as_str(), ""));
        match keyword {
            "newmtl" => {
                if rest.is_empty() {
                    return Err(ScanError::syntax(path, line, "newmtl without a name"));
                }
                materials.push(MtlMaterial {
                    name: rest.to_string(),
                    diffuse: None,
                    diffuse_map: None,
                });
            }
            "Kd" | "map_Kd" => {
                let current = materials.last_mut().ok_or_else(|| {
                    ScanError::syntax(path, line, format!("{keyword} before any newmtl"))
                })?;
                if keyword == "Kd" {
                    let tokens: Vec<&str> = rest.split_whitespace().collect();
                    if tokens.first() == Some(&"spectral") || tokens.first() == Some(&"xyz") {
                        continue;
                    }
                    let v = floats(&tokens, 1, 3, path, line, "Kd")?;
                    current.diffuse = Some(if v.len() == 3 {
                        [v[0], v[1], v[2]]
                    } else {
                        [v[0]; 3]
                    });
                } else {
                    let file = map_file_name(rest);
                    if file.is_empty() {
                        return Err(ScanError::syntax(path, line, "map_Kd without a file name"));
                    }
                    current.diffuse_map = Some(file);
                }
            }
            _ => {}
        }
    }
    Ok(materials)
}

/// The file name of a texture map statement, after its options (`-s 1 1 1`, `-clamp on`,
/// ...). Backslashes (from Windows exporters) become slashes.
fn map_file_name(rest: &str) -> String {
    let tokens: Vec<&str> = rest.split_whitespace().collect();
    let mut i = 0;
    while i < tokens.len() && tokens[i].starts_with('-') && tokens[i].len() > 1 {
        let arity = match tokens[i] {
            "-o" | "-s" | "-t" => 3,
            "-mm" => 2,
            _ => 1,
        };
        i += 1;
        // Options with up to three numbers may give fewer.
        let mut taken = 0;
        while taken < arity && i < tokens.len() {
            let numeric = tokens[i].parse::<f32>().is_ok();
            if taken > 0 && !numeric {
                break;
            }
            i += 1;
            taken += 1;
        }
    }
    tokens[i.min(tokens.len())..].join(" ").replace('\\', "/")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn map_options_are_skipped() {
        assert_eq!(map_file_name("material0.jpeg"), "material0.jpeg");
        assert_eq!(map_file_name("-s 1 1 1 -o 0 0 tex/a b.png"), "tex/a b.png");
        assert_eq!(
            map_file_name("-clamp on -bm 0.5 maps\\skin.jpg"),
            "maps/skin.jpg"
        );
        assert_eq!(map_file_name("-mm 0 1 skin.png"), "skin.png");
    }
}
