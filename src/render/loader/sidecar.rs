//! The `scene.json` sidecar of `scenes/README.md`: the glTF it names, an environment map,
//! the camera, the film size and an optional camera path.

use std::path::Path;

use glam::{Mat3, Vec3};
use serde::Deserialize;

use super::{file_err, load_environment, load_gltf, scene_err};
use crate::error::Result;
use crate::render::camera::{Camera, CameraPathSpec};
use crate::render::scene::{Portal, Scene};

#[derive(Debug, Deserialize)]
struct Sidecar {
    gltf: String,
    environment: Option<EnvSpec>,
    camera: Option<CamSpec>,
    film: Option<[u32; 2]>,
    camera_path: Option<PathSpec>,
}

#[derive(Debug, Deserialize)]
struct EnvSpec {
    file: String,
    scale: Option<f32>,
    to_world: Option<[[f32; 4]; 4]>,
    rotation_y_deg: Option<f32>,
    mapping: Option<String>,
    portals: Option<Vec<PortalSpec>>,
}

/// Optional `environment.portals` of `scene.json` (an extension of the README schema): the
/// openings the environment lights the scene through, each `{"corner": [x, y, z], "u":
/// [..], "v": [..]}` in world space, seen from the side `u x v` points to
/// ([`crate::render::scene::Portal`]).
#[derive(Debug, Deserialize)]
struct PortalSpec {
    corner: [f32; 3],
    u: [f32; 3],
    v: [f32; 3],
}

#[derive(Debug, Deserialize)]
struct CamSpec {
    position: [f32; 3],
    target: [f32; 3],
    up: Option<[f32; 3]>,
    yfov_deg: f32,
}

/// Optional `camera_path` of `scene.json` (an extension of the README schema):
/// `{"type": "orbit", "degrees_per_frame": 0.5}` or
/// `{"type": "flythrough", "frames_per_key": 24, "keys": [{"position": [..], "target": [..]}, ..]}`,
/// optionally with `"cut_every": 16` (a cut to another viewpoint every 16 frames, see
/// [`CameraPathSpec::FlyThrough`]).
#[derive(Debug, Deserialize)]
#[serde(tag = "type", rename_all = "lowercase")]
enum PathSpec {
    Static,
    Orbit {
        degrees_per_frame: Option<f32>,
    },
    Flythrough {
        frames_per_key: Option<f32>,
        keys: Option<Vec<KeySpec>>,
        cut_every: Option<u32>,
    },
}

#[derive(Debug, Deserialize)]
struct KeySpec {
    position: [f32; 3],
    target: [f32; 3],
}

/// Loads a `scene.json` sidecar and the glTF it names.
pub fn load_sidecar(path: &Path) -> Result<Scene> {
    let bytes =
        crate::io::read_regular(path, u64::MAX).map_err(|e| file_err(path, format!("cannot read: {e}")))?;
    let text = String::from_utf8(bytes).map_err(|_| file_err(path, "cannot read: not UTF-8 text"))?;
    let side: Sidecar =
        serde_json::from_str(&text).map_err(|e| scene_err(path, format!("malformed scene.json: {e}")))?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut scene = load_gltf(&dir.join(&side.gltf))?;
    scene.name = path.display().to_string();
    if let Some(e) = &side.environment {
        if let Some(m) = &e.mapping
            && !m.trim_start().starts_with("mitsuba_latlong")
        {
            return Err(scene_err(
                path,
                format!("unsupported environment mapping '{m}' (mitsuba_latlong only)"),
            ));
        }
        let to_world = match (e.to_world, e.rotation_y_deg) {
            (Some(m), _) => {
                let r = Mat3::from_cols(
                    Vec3::new(m[0][0], m[1][0], m[2][0]),
                    Vec3::new(m[0][1], m[1][1], m[2][1]),
                    Vec3::new(m[0][2], m[1][2], m[2][2]),
                );
                if r.determinant().abs() <= 1e-6 || !r.is_finite() {
                    return Err(scene_err(path, "environment to_world is singular"));
                }
                r
            }
            (None, Some(deg)) => Mat3::from_rotation_y(deg.to_radians()),
            (None, None) => Mat3::IDENTITY,
        };
        let scale = e.scale.unwrap_or(1.0);
        if !scale.is_finite() || scale < 0.0 {
            return Err(scene_err(
                path,
                format!("environment scale {scale} must be finite and >= 0"),
            ));
        }
        let mut env = load_environment(&dir.join(&e.file), scale, to_world)?;
        for (k, q) in e.portals.iter().flatten().enumerate() {
            let portal = Portal {
                corner: Vec3::from(q.corner),
                u: Vec3::from(q.u),
                v: Vec3::from(q.v),
            };
            let area = portal.area();
            if !(area.is_finite() && area > 0.0 && portal.corner.is_finite()) {
                return Err(scene_err(
                    path,
                    format!(
                        "environment.portals[{k}] must have finite values and edges u, v that span \
                         an area (area {area})"
                    ),
                ));
            }
            env.portals.push(portal);
        }
        scene.environment = Some(env);
    }
    if let Some(c) = &side.camera {
        scene.camera = Camera {
            position: Vec3::from(c.position),
            target: Vec3::from(c.target),
            up: c.up.map(Vec3::from).unwrap_or(Vec3::Y),
            yfov: c.yfov_deg.to_radians(),
        };
        if !(scene.camera.yfov > 0.0 && scene.camera.yfov < std::f32::consts::PI) {
            return Err(scene_err(
                path,
                format!("camera yfov_deg {} out of (0, 180)", c.yfov_deg),
            ));
        }
        scene
            .camera
            .check()
            .map_err(|e| scene_err(path, format!("scene.json {e}")))?;
    }
    if let Some([w, h]) = side.film {
        if w == 0 || h == 0 {
            return Err(scene_err(path, "film size must be positive"));
        }
        scene.film = (w, h);
    }
    scene.camera_path = side.camera_path.map(|p| match p {
        PathSpec::Static => CameraPathSpec::Static,
        PathSpec::Orbit { degrees_per_frame } => CameraPathSpec::Orbit { degrees_per_frame },
        PathSpec::Flythrough {
            frames_per_key,
            keys,
            cut_every,
        } => CameraPathSpec::FlyThrough {
            keys: keys.map(|k| {
                k.iter()
                    .map(|k| Camera {
                        position: Vec3::from(k.position),
                        target: Vec3::from(k.target),
                        ..scene.camera
                    })
                    .collect()
            }),
            frames_per_key: frames_per_key.unwrap_or(crate::render::camera::DEFAULT_FRAMES_PER_KEY),
            cut_every,
        },
    });
    if let Some(spec) = &scene.camera_path {
        spec.check()
            .map_err(|e| scene_err(path, format!("scene.json {e}")))?;
    }
    if let Some(CameraPathSpec::FlyThrough {
        frames_per_key,
        cut_every,
        ..
    }) = &scene.camera_path
    {
        if !(frames_per_key.is_finite() && *frames_per_key >= 1.0) {
            return Err(scene_err(
                path,
                format!("camera_path.frames_per_key {frames_per_key} must be at least 1"),
            ));
        }
        if *cut_every == Some(0) {
            return Err(scene_err(path, "camera_path.cut_every must be at least 1"));
        }
    }
    Ok(scene)
}
