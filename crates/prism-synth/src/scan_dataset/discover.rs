//! Finding the subjects of a scans folder: one sub-folder per subject holding one mesh
//! (`.obj`, `.gltf` or `.glb`) and optionally one body fit (`body.json`, `smplx.json` or
//! `smplx_param.json`).

use std::fs;
use std::path::{Path, PathBuf};

use prism_data::DataError;

/// File names of a body fit in a subject's scan folder (the `body.json` schema, in the scan's
/// coordinates), in the order they are looked for.
pub const FIT_NAMES: [&str; 3] = ["body.json", "smplx.json", "smplx_param.json"];

/// Extensions of the mesh files a subject folder may hold (any case).
pub const MESH_EXTENSIONS: [&str; 3] = ["obj", "gltf", "glb"];

/// One sub-folder of the scans folder.
#[derive(Clone, Debug, PartialEq)]
pub struct ScanSubject {
    /// The folder's name, which names the subject in the dataset.
    pub name: String,
    /// The folder.
    pub dir: PathBuf,
    /// The subject's mesh, or why the folder does not name exactly one.
    pub mesh: Result<PathBuf, String>,
    /// The body fit, if there is one, or why the folder holds several.
    pub fit: Result<Option<PathBuf>, String>,
}

/// The subject folders of `scans`, sorted by name; hidden folders (`.name`) and loose files
/// are ignored.
///
/// # Errors
/// When `scans` is not a readable folder or holds no sub-folder.
pub fn discover(scans: &Path) -> Result<Vec<ScanSubject>, DataError> {
    if !scans.is_dir() {
        return Err(DataError::invalid(scans, "no such scans folder"));
    }
    let mut dirs: Vec<(String, PathBuf)> = Vec::new();
    for entry in fs::read_dir(scans).map_err(|e| DataError::io(scans, e))? {
        let entry = entry.map_err(|e| DataError::io(scans, e))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        if !name.starts_with('.') && entry.path().is_dir() {
            dirs.push((name, entry.path()));
        }
    }
    if dirs.is_empty() {
        return Err(DataError::invalid(
            scans,
            "holds no subject folders (expected one folder per subject, each with one mesh)",
        ));
    }
    dirs.sort();
    dirs.into_iter()
        .map(|(name, dir)| {
            let files = files_of(&dir)?;
            Ok(ScanSubject {
                mesh: find_mesh(&dir, &files),
                fit: find_fit(&files),
                name,
                dir,
            })
        })
        .collect()
}

/// The plain files of `dir`, sorted.
fn files_of(dir: &Path) -> Result<Vec<PathBuf>, DataError> {
    let mut files = Vec::new();
    for entry in fs::read_dir(dir).map_err(|e| DataError::io(dir, e))? {
        let path = entry.map_err(|e| DataError::io(dir, e))?.path();
        if path.is_file() {
            files.push(path);
        }
    }
    files.sort();
    Ok(files)
}

fn find_mesh(dir: &Path, files: &[PathBuf]) -> Result<PathBuf, String> {
    let meshes: Vec<&PathBuf> = files
        .iter()
        .filter(|f| {
            f.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| MESH_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
        })
        .collect();
    match meshes[..] {
        [one] => Ok(one.clone()),
        [] => Err(format!(
            "{}: no mesh (expected one .obj, .gltf or .glb file)",
            dir.display()
        )),
        _ => Err(format!(
            "{}: several meshes ({}); keep one per subject folder",
            dir.display(),
            names(&meshes)
        )),
    }
}

fn find_fit(files: &[PathBuf]) -> Result<Option<PathBuf>, String> {
    let fits: Vec<&PathBuf> = files
        .iter()
        .filter(|f| {
            f.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| FIT_NAMES.contains(&n))
        })
        .collect();
    match fits[..] {
        [] => Ok(None),
        [one] => Ok(Some(one.clone())),
        _ => Err(format!(
            "{}: several body fits ({}); keep one",
            fits[0].parent().unwrap_or(Path::new("")).display(),
            names(&fits)
        )),
    }
}

fn names(paths: &[&PathBuf]) -> String {
    paths
        .iter()
        .map(|p| p.file_name().unwrap_or_default().to_string_lossy())
        .collect::<Vec<_>>()
        .join(", ")
}
