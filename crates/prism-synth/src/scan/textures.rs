//! Loading texture images (PNG, JPEG) for scan materials, each file once.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::material::Texture;

/// Loads textures by path, decoding each file once however many materials use it.
#[derive(Default)]
pub(crate) struct TextureCache {
    loaded: HashMap<PathBuf, Result<Arc<Texture>, String>>,
}

impl TextureCache {
    /// The texture at `path`, or why it cannot be used (missing, unreadable, not an image).
    pub fn get(&mut self, path: &Path) -> Result<Arc<Texture>, String> {
        self.loaded
            .entry(path.to_path_buf())
            .or_insert_with(|| load_texture(path))
            .clone()
    }
}

/// Decodes an image file into a texture (alpha is dropped: renders are unlit and opaque).
fn load_texture(path: &Path) -> Result<Arc<Texture>, String> {
    if !path.is_file() {
        return Err(format!("texture {} not found", path.display()));
    }
    let image =
        image::open(path).map_err(|e| format!("cannot decode texture {}: {e}", path.display()))?;
    if image.width() == 0 || image.height() == 0 {
        return Err(format!("texture {} is empty", path.display()));
    }
    Ok(Arc::new(Texture::from_image(&image.to_rgb8())))
}
