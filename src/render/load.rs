//! Scene specifications: `builtin:NAME` ([`super::builtin`]), `builtin:procedural:SEED`
//! ([`super::procedural`], with props from [`SceneOptions`]), or a file or folder
//! ([`super::loader`]).

use std::path::Path;

use super::builtin::builtin;
use super::loader::{SceneOptions, load_path};
use super::procedural::{parse_seed, procedural};
use super::scene::Scene;
use crate::error::Result;

/// Loads `builtin:NAME` (including `builtin:procedural:SEED`, without props), a
/// `scene.json`, a folder holding one, or a `.gltf`/`.glb` file.
pub fn load_scene(spec: &str) -> Result<Scene> {
    load_scene_with(spec, &SceneOptions::default())
}

/// [`load_scene`] with options: `builtin:procedural:SEED` takes its props from `options`
/// (see [`super::procedural`]); other scenes load as with [`load_scene`].
pub fn load_scene_with(spec: &str, options: &SceneOptions) -> Result<Scene> {
    if let Some(seed) = spec.strip_prefix("builtin:procedural:") {
        return procedural(parse_seed(seed)?, options);
    }
    if !options.props.is_empty() {
        log::warn!("props are used by builtin:procedural:SEED scenes only; ignored for {spec}");
    }
    if let Some(name) = spec.strip_prefix("builtin:") {
        return builtin(name);
    }
    load_path(Path::new(spec))
}
