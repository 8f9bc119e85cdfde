//! Loading scenes from files, one module per format: `gltf` (glTF 2.0, `.gltf` and
//! `.glb`), `sidecar` (the `scene.json` of `scenes/README.md`: environment map, camera,
//! film, optional camera path) and `environment` (lat-long environment maps). This module
//! picks the loader for a path; [`super::load_scene`] reads scene specifications.

mod environment;
mod gltf;
mod sidecar;
#[cfg(test)]
mod tests;

pub use environment::load_environment;
pub use gltf::{SUPPORTED_EXTENSIONS, load_gltf};
pub use sidecar::load_sidecar;

use std::path::{Path, PathBuf};

use super::scene::Scene;
use crate::error::{Error, Result};

pub(super) fn scene_err(path: &Path, message: impl Into<String>) -> Error {
    Error::Scene {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

pub(super) fn file_err(path: &Path, message: impl Into<String>) -> Error {
    Error::File {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// Options of [`super::load_scene_with`]; also the `--props` option of every command that
/// loads a scene (flattened into its arguments).
#[derive(Debug, Clone, Default, PartialEq, clap::Args)]
pub struct SceneOptions {
    /// Props for `builtin:procedural:SEED`: `.gltf`/`.glb` files (their meshes become
    /// objects), `.hdr`/`.exr` lat-long environment maps, or folders searched recursively for
    /// both (repeatable). Only these paths are used (never an implicit scan of a scenes
    /// folder), so held-out scenes stay out of training data by not naming them. Ignored,
    /// with a warning, by other scenes.
    #[arg(long)]
    pub props: Vec<PathBuf>,
}

/// Loads a scene file: a `scene.json`, a folder holding one, or a `.gltf`/`.glb` file.
pub fn load_path(path: &Path) -> Result<Scene> {
    let path = path.to_path_buf();
    if path.is_dir() {
        let json = path.join("scene.json");
        if !json.is_file() {
            return Err(scene_err(&path, "a scene folder needs a scene.json"));
        }
        return load_sidecar(&json);
    }
    if !path.exists() {
        return Err(file_err(&path, "no such file"));
    }
    match path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("json") => load_sidecar(&path),
        Some("gltf") | Some("glb") => load_gltf(&path),
        _ => Err(scene_err(
            &path,
            "expected builtin:NAME, a scene.json, a scene folder, or a .gltf/.glb file",
        )),
    }
}
