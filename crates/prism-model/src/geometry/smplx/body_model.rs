//! The body model the SMPL-X branch poses, named in the config (`model.body_model`):
//! `procedural:SEED` for the procedural humanoid that ships with prism, or the path of an
//! SMPL-X `.npz` (the licensed download).

use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex, OnceLock};

use prism_body::BodyModel;
use prism_body::procedural::parse_model_name;

use crate::error::ModelError;

/// Whether `spec` names a procedural model (`procedural:SEED`).
pub(crate) fn is_procedural(spec: &str) -> bool {
    parse_model_name(spec).is_some()
}

/// Checks a body-model spec without loading it: a procedural name, or an existing file.
///
/// # Errors
/// [`ModelError::Invalid`] for `model.body_model`.
pub(crate) fn check_body_model(spec: &str) -> Result<(), ModelError> {
    if is_procedural(spec) {
        return Ok(());
    }
    if spec.starts_with("procedural") {
        return Err(ModelError::invalid(
            "model.body_model",
            format!("`{spec}` is not `procedural:SEED` with an integer seed"),
        ));
    }
    if !Path::new(spec).is_file() {
        return Err(ModelError::invalid(
            "model.body_model",
            format!("`{spec}` is neither `procedural:SEED` nor an existing SMPL-X .npz file"),
        ));
    }
    Ok(())
}

/// Loads (once per process: later calls share it) the body model `spec` names.
///
/// # Errors
/// [`ModelError::Body`] when the `.npz` cannot be read or is not an SMPL-X model.
pub(crate) fn load_body_model(spec: &str) -> Result<Arc<BodyModel>, ModelError> {
    static CACHE: OnceLock<Mutex<HashMap<String, Arc<BodyModel>>>> = OnceLock::new();
    let cache = CACHE.get_or_init(Default::default);
    if let Some(model) = cache.lock().expect("body model cache").get(spec) {
        return Ok(model.clone());
    }
    if !is_procedural(spec) {
        check_body_model(spec)?;
    }
    let model = BodyModel::load_named(spec).map_err(ModelError::Body)?;
    let model = Arc::new(model);
    cache
        .lock()
        .expect("body model cache")
        .insert(spec.to_string(), model.clone());
    Ok(model)
}
