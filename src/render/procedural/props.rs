//! Props: glTF meshes and environment maps from user-given paths, placed as objects.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::Mat3;

use crate::error::{Error, Result};
use crate::render::loader::{load_environment, load_gltf};
use crate::render::scene::{Environment, Scene};

/// One loaded prop file.
#[derive(Debug, Clone)]
pub struct PropFile {
    /// The glTF file.
    pub path: PathBuf,
    /// Its content.
    pub scene: Scene,
    /// Materials used by at least 4 triangles, with their triangles (the "primitives").
    pub(super) groups: Vec<(u32, Vec<u32>)>,
}

/// Props given by the user: glTF scenes to take objects from and environment maps.
#[derive(Debug, Clone, Default)]
pub struct PropLibrary {
    /// glTF files that loaded.
    pub files: Vec<PropFile>,
    /// Environment maps found (loaded when a scene uses them).
    pub environments: Vec<PathBuf>,
    /// Warnings of the loading (files skipped).
    pub warnings: Vec<String>,
    env_cache: HashMap<PathBuf, Option<Environment>>,
}

/// Largest prop loaded, in triangles (bigger files are skipped with a warning).
pub const MAX_PROP_TRIANGLES: usize = 1_000_000;

pub(super) fn ext_of(p: &Path) -> String {
    p.extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default()
}

pub(super) fn collect_files(dir: &Path, depth: u32, out: &mut Vec<PathBuf>) -> Result<()> {
    let rd = std::fs::read_dir(dir).map_err(|e| Error::File {
        path: dir.to_path_buf(),
        message: format!("cannot list the props folder: {e}"),
    })?;
    let mut entries: Vec<PathBuf> = rd.filter_map(|e| e.ok().map(|e| e.path())).collect();
    entries.sort();
    for p in entries {
        let hidden = p
            .file_name()
            .and_then(|n| n.to_str())
            .is_some_and(|n| n.starts_with('.'));
        if hidden {
            continue;
        }
        if p.is_dir() {
            if depth < 8 {
                collect_files(&p, depth + 1, out)?;
            }
        } else if matches!(ext_of(&p).as_str(), "gltf" | "glb" | "hdr" | "exr") {
            out.push(p);
        }
    }
    Ok(())
}

impl PropLibrary {
    /// Loads the props at `paths` (files or folders, searched recursively for `.gltf`,
    /// `.glb`, `.hdr` and `.exr`). A path that does not exist is an error; a glTF that does
    /// not load (broken, unsupported) is skipped with one warning naming it.
    pub fn load(paths: &[PathBuf]) -> Result<Self> {
        let mut files = Vec::new();
        for p in paths {
            if p.is_dir() {
                collect_files(p, 0, &mut files)?;
            } else if p.is_file() {
                files.push(p.clone());
            } else {
                return Err(Error::File {
                    path: p.clone(),
                    message: "no such props file or folder".into(),
                });
            }
        }
        let mut lib = PropLibrary::default();
        let mut seen = std::collections::HashSet::new();
        for f in files {
            if !seen.insert(f.clone()) {
                continue;
            }
            match ext_of(&f).as_str() {
                "gltf" | "glb" => match load_gltf(&f) {
                    Ok(scene) if scene.geometry.triangles.len() > MAX_PROP_TRIANGLES => {
                        lib.warnings.push(format!(
                            "prop {} skipped: {} triangles (at most {MAX_PROP_TRIANGLES})",
                            f.display(),
                            scene.geometry.triangles.len()
                        ));
                    }
                    Ok(scene) => {
                        let mut by_mat: Vec<Vec<u32>> = vec![Vec::new(); scene.materials.len()];
                        for (t, &m) in scene.geometry.materials.iter().enumerate() {
                            by_mat[m as usize].push(t as u32);
                        }
                        let groups = by_mat
                            .into_iter()
                            .enumerate()
                            .filter(|(_, t)| t.len() >= 4)
                            .map(|(m, t)| (m as u32, t))
                            .collect();
                        lib.files.push(PropFile {
                            path: f,
                            scene,
                            groups,
                        });
                    }
                    Err(e) => lib.warnings.push(format!("prop skipped: {e}")),
                },
                "hdr" | "exr" => lib.environments.push(f),
                _ => lib.warnings.push(format!(
                    "prop {} skipped: not a .gltf, .glb, .hdr or .exr file",
                    f.display()
                )),
            }
        }
        Ok(lib)
    }

    /// The environment map `i` (loaded once; `None` if it cannot be read or is not a
    /// 2:1 lat-long map, with a warning).
    pub(super) fn environment(&mut self, i: usize, warnings: &mut Vec<String>) -> Option<Environment> {
        let path = self.environments.get(i)?.clone();
        if !self.env_cache.contains_key(&path) {
            let env = match load_environment(&path, 1.0, Mat3::IDENTITY) {
                Ok(e) if e.width >= e.height * 3 / 2 && e.width <= e.height * 5 / 2 => Some(e),
                Ok(e) => {
                    warnings.push(format!(
                        "environment {} skipped: {}x{} is not a 2:1 lat-long map",
                        path.display(),
                        e.width,
                        e.height
                    ));
                    None
                }
                Err(e) => {
                    warnings.push(format!("environment skipped: {e}"));
                    None
                }
            };
            self.env_cache.insert(path.clone(), env);
        }
        self.env_cache[&path].clone()
    }
}
