//! Loading scenes from files: glTF 2.0 (`.gltf`, `.glb`) and the `scene.json` sidecar of
//! `scenes/README.md` (environment map, camera, film, optional camera path).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{Mat3, Mat4, Vec2, Vec3, Vec4};
use serde::Deserialize;

use super::builtin::builtin;
use super::camera::{Camera, CameraPathSpec};
use super::scene::{AlphaMode, Environment, Geometry, Material, Scene, Texture, Wrap};
use crate::error::{Error, Result};

/// glTF extensions the loader understands; a file requiring any other is refused.
pub const SUPPORTED_EXTENSIONS: &[&str] = &[
    "KHR_materials_emissive_strength",
    "KHR_materials_transmission",
    "KHR_materials_ior",
    "KHR_materials_volume",
];

fn scene_err(path: &Path, message: impl Into<String>) -> Error {
    Error::Scene {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

fn file_err(path: &Path, message: impl Into<String>) -> Error {
    Error::File {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// Options of [`load_scene_with`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SceneOptions {
    /// Props for `builtin:procedural:SEED`: `.gltf`/`.glb` files (their meshes become
    /// objects), `.hdr`/`.exr` lat-long environment maps, or folders searched recursively for
    /// both. Only these paths are used (never an implicit scan of a scenes folder), so
    /// held-out scenes stay out by not naming them. Ignored, with a warning, by other scenes.
    pub props: Vec<PathBuf>,
}

/// [`load_scene`] with options: `builtin:procedural:SEED` takes its props from `options`
/// (see [`super::procedural`]); other scenes load as with [`load_scene`].
pub fn load_scene_with(spec: &str, options: &SceneOptions) -> Result<Scene> {
    if let Some(seed) = spec.strip_prefix("builtin:procedural:") {
        return super::procedural::procedural(super::procedural::parse_seed(seed)?, options);
    }
    if !options.props.is_empty() {
        log::warn!("props are used by builtin:procedural:SEED scenes only; ignored for {spec}");
    }
    load_scene(spec)
}

/// Loads `builtin:NAME` (including `builtin:procedural:SEED`, without props), a
/// `scene.json`, a folder holding one, or a `.gltf`/`.glb` file.
pub fn load_scene(spec: &str) -> Result<Scene> {
    if let Some(name) = spec.strip_prefix("builtin:") {
        return builtin(name);
    }
    let path = PathBuf::from(spec);
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

#[derive(Debug, Deserialize)]
struct Sidecar {
    gltf: String,
    #[serde(default)]
    environment: Option<EnvSpec>,
    #[serde(default)]
    camera: Option<CamSpec>,
    #[serde(default)]
    film: Option<[u32; 2]>,
    #[serde(default)]
    camera_path: Option<PathSpec>,
}

#[derive(Debug, Deserialize)]
struct EnvSpec {
    file: String,
    #[serde(default)]
    scale: Option<f32>,
    #[serde(default)]
    to_world: Option<[[f32; 4]; 4]>,
    #[serde(default)]
    rotation_y_deg: Option<f32>,
    #[serde(default)]
    mapping: Option<String>,
}

#[derive(Debug, Deserialize)]
struct CamSpec {
    position: [f32; 3],
    target: [f32; 3],
    #[serde(default)]
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
        #[serde(default)]
        degrees_per_frame: Option<f32>,
    },
    Flythrough {
        #[serde(default)]
        frames_per_key: Option<f32>,
        #[serde(default)]
        keys: Option<Vec<KeySpec>>,
        #[serde(default)]
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
        scene.environment = Some(load_environment(&dir.join(&e.file), scale, to_world)?);
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
            frames_per_key: frames_per_key.unwrap_or(super::camera::DEFAULT_FRAMES_PER_KEY),
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

/// Loads a lat-long environment map (`.hdr`, `.exr`, or anything the `image` crate reads).
pub fn load_environment(path: &Path, scale: f32, to_world: Mat3) -> Result<Environment> {
    let bytes = crate::io::read_regular(path, u64::MAX)
        .map_err(|e| file_err(path, format!("cannot open environment map: {e}")))?;
    let img = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| file_err(path, format!("cannot read environment map: {e}")))?
        .decode()
        .map_err(|e| file_err(path, format!("cannot decode environment map: {e}")))?
        .to_rgb32f();
    let (width, height) = img.dimensions();
    if width == 0 || height == 0 {
        return Err(file_err(path, "empty environment map"));
    }
    let pixels: Vec<[f32; 3]> = img
        .pixels()
        .map(|p| p.0.map(|v| if v.is_finite() { v.max(0.0) } else { 0.0 }))
        .collect();
    Ok(Environment {
        source: path.to_path_buf(),
        width,
        height,
        pixels,
        scale,
        to_world,
    })
}

/// Decodes standard base64 (data URIs).
fn base64_decode(s: &str) -> Option<Vec<u8>> {
    let mut out = Vec::with_capacity(s.len() * 3 / 4);
    let mut acc = 0u32;
    let mut bits = 0;
    for c in s.bytes() {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            b'=' | b'\n' | b'\r' | b' ' => continue,
            _ => return None,
        } as u32;
        acc = (acc << 6) | v;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
        }
    }
    Some(out)
}

fn percent_decode(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%'
            && i + 2 < b.len()
            && let Some(v) = std::str::from_utf8(&b[i + 1..i + 3])
                .ok()
                .and_then(|h| u8::from_str_radix(h, 16).ok())
        {
            out.push(v);
            i += 3;
            continue;
        }
        out.push(b[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// Bytes of a URI relative to `base`: a data URI or a file.
/// A file is read only when regular, and at most `cap` bytes of it (a buffer's declared
/// byteLength).
fn read_uri(gltf_path: &Path, base: &Path, uri: &str, what: &str, cap: u64) -> Result<(Vec<u8>, PathBuf)> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let (_, data) = rest
            .split_once(";base64,")
            .ok_or_else(|| scene_err(gltf_path, format!("{what}: unsupported data URI")))?;
        let bytes = base64_decode(data)
            .ok_or_else(|| scene_err(gltf_path, format!("{what}: malformed base64 data URI")))?;
        return Ok((bytes, gltf_path.to_path_buf()));
    }
    let file = base.join(percent_decode(uri));
    let bytes = crate::io::read_regular(&file, cap).map_err(|e| {
        file_err(
            &file,
            format!("{what} referenced by {} cannot be read: {e}", gltf_path.display()),
        )
    })?;
    Ok((bytes, file))
}

/// Checks, on the raw JSON of a `.gltf` or `.glb`, what the `gltf` crate would panic on
/// rather than report (its validation indexes a primitive's POSITION accessor unchecked,
/// its readers assert on strides and hit `unreachable!` on unexpected component types):
/// every accessor a primitive names exists and has the type and component type the spec
/// (and the reader) requires, strides hold their element, and accessor and view ranges lie
/// within their view and buffer. Unparsable JSON is left to the crate's own error.
fn check_gltf_json(bytes: &[u8]) -> std::result::Result<(), String> {
    use serde_json::Value;
    let parsed: Option<Value> = if bytes.starts_with(b"glTF") {
        gltf::binary::Glb::from_slice(bytes)
            .ok()
            .and_then(|glb| serde_json::from_slice(&glb.json).ok())
    } else {
        serde_json::from_slice(bytes).ok()
    };
    let Some(json) = parsed else {
        return Ok(());
    };
    let list = |k: &str| {
        json.get(k)
            .and_then(Value::as_array)
            .map(Vec::as_slice)
            .unwrap_or(&[])
    };
    let (accessors, views, buffers) = (list("accessors"), list("bufferViews"), list("buffers"));
    let uint = |v: &Value, k: &str| v.get(k).and_then(Value::as_u64);
    // Bytes per component of a componentType, and components per element of a type.
    let component_size = |t: u64| match t {
        5120 | 5121 => Some(1u64),
        5122 | 5123 => Some(2),
        5125 | 5126 => Some(4),
        _ => None,
    };
    let components = |t: &str| match t {
        "SCALAR" => Some(1u64),
        "VEC2" => Some(2),
        "VEC3" => Some(3),
        "VEC4" | "MAT2" => Some(4),
        "MAT3" => Some(9),
        "MAT4" => Some(16),
        _ => None,
    };
    // Views within their buffers.
    for (i, v) in views.iter().enumerate() {
        let (Some(b), Some(len)) = (uint(v, "buffer"), uint(v, "byteLength")) else {
            continue;
        };
        let off = uint(v, "byteOffset").unwrap_or(0);
        if let Some(buf) = buffers.get(b as usize)
            && let Some(blen) = uint(buf, "byteLength")
            && off.checked_add(len).is_none_or(|end| end > blen)
        {
            return Err(format!(
                "bufferViews[{i}] (offset {off}, length {len}) runs past buffer {b} ({blen} bytes)"
            ));
        }
    }
    // An accessor within its view, its view's stride holding its element.
    let check_accessor = |a: usize| -> std::result::Result<(), String> {
        let acc = &accessors[a];
        let ty = acc.get("type").and_then(Value::as_str).unwrap_or("");
        let (Some(csize), Some(n)) = (
            uint(acc, "componentType").and_then(component_size),
            components(ty),
        ) else {
            return Err(format!("accessors[{a}] has an unknown type or componentType"));
        };
        let elem = csize * n;
        let count = uint(acc, "count").unwrap_or(0);
        let Some(vi) = uint(acc, "bufferView") else {
            return Ok(());
        };
        let Some(view) = views.get(vi as usize) else {
            return Err(format!(
                "accessors[{a}].bufferView {vi} does not exist ({} views)",
                views.len()
            ));
        };
        let stride = match uint(view, "byteStride") {
            Some(s) if s < elem => {
                return Err(format!(
                    "bufferViews[{vi}].byteStride {s} is smaller than the {elem}-byte elements of accessors[{a}]"
                ));
            }
            Some(s) => s,
            None => elem,
        };
        let off = uint(acc, "byteOffset").unwrap_or(0);
        let vlen = uint(view, "byteLength").unwrap_or(0);
        let need = match count {
            0 => Some(off),
            c => (c - 1)
                .checked_mul(stride)
                .and_then(|x| x.checked_add(off))
                .and_then(|x| x.checked_add(elem)),
        };
        if need.is_none_or(|need| need > vlen) {
            return Err(format!(
                "accessors[{a}] ({count} elements of {elem} bytes, stride {stride}, offset {off}) \
                 runs past bufferViews[{vi}] ({vlen} bytes)"
            ));
        }
        Ok(())
    };
    for (m, mesh) in list("meshes").iter().enumerate() {
        let prims = mesh
            .get("primitives")
            .and_then(Value::as_array)
            .map(Vec::as_slice)
            .unwrap_or(&[]);
        for (p, prim) in prims.iter().enumerate() {
            let at = format!("meshes[{m}].primitives[{p}]");
            let accessor_of = |what: &str, v: &Value| -> std::result::Result<usize, String> {
                match v.as_u64() {
                    Some(a) if (a as usize) < accessors.len() => Ok(a as usize),
                    _ => Err(format!(
                        "{at}.{what}: accessor {v} does not exist ({} accessors)",
                        accessors.len()
                    )),
                }
            };
            let mut used: Vec<(String, usize)> = Vec::new();
            if let Some(attrs) = prim.get("attributes").and_then(Value::as_object) {
                for (name, v) in attrs {
                    let what = format!("attributes.{name}");
                    used.push((what.clone(), accessor_of(&what, v)?));
                }
            }
            let targets = prim.get("targets").and_then(Value::as_array);
            for (t, target) in targets.into_iter().flatten().enumerate() {
                for (name, v) in target.as_object().into_iter().flatten() {
                    let what = format!("targets[{t}].{name}");
                    used.push((what.clone(), accessor_of(&what, v)?));
                }
            }
            if let Some(v) = prim.get("indices") {
                used.push(("indices".into(), accessor_of("indices", v)?));
            }
            for (what, a) in &used {
                check_accessor(*a).map_err(|e| format!("{at}.{what}: {e}"))?;
                let acc = &accessors[*a];
                let ty = acc.get("type").and_then(Value::as_str).unwrap_or("");
                let ct = uint(acc, "componentType").unwrap_or(0);
                // What the spec allows (and the reader handles without panicking).
                type Allowed = (&'static [&'static str], &'static [u64], &'static str);
                let allowed: Option<Allowed> = match what.as_str() {
                    "indices" => Some((
                        &["SCALAR"],
                        &[5121, 5123, 5125],
                        "SCALAR of unsigned byte, short or int",
                    )),
                    "attributes.POSITION" | "attributes.NORMAL" => {
                        Some((&["VEC3"], &[5126], "VEC3 of float"))
                    }
                    "attributes.TANGENT" => Some((&["VEC4"], &[5126], "VEC4 of float")),
                    w if w.starts_with("attributes.TEXCOORD_") => Some((
                        &["VEC2"],
                        &[5121, 5123, 5126],
                        "VEC2 of float or normalised unsigned byte or short",
                    )),
                    w if w.starts_with("attributes.COLOR_") => Some((
                        &["VEC3", "VEC4"],
                        &[5121, 5123, 5126],
                        "VEC3 or VEC4 of float or normalised unsigned byte or short",
                    )),
                    _ => None,
                };
                if let Some((types, cts, text)) = allowed
                    && !(types.contains(&ty) && cts.contains(&ct))
                {
                    return Err(format!(
                        "{at}.{what}: accessors[{a}] is {ty} of componentType {ct}, expected {text}"
                    ));
                }
            }
        }
    }
    Ok(())
}

struct Loader<'a> {
    path: &'a Path,
    base: PathBuf,
    doc: gltf::Document,
    buffers: Vec<Vec<u8>>,
    images: HashMap<usize, image::RgbaImage>,
    textures: Vec<Texture>,
    texture_ids: HashMap<(usize, bool), u32>,
    approx: Vec<String>,
}

impl Loader<'_> {
    fn note(&mut self, s: String) {
        if !self.approx.contains(&s) {
            self.approx.push(s);
        }
    }

    fn image(&mut self, index: usize) -> Result<&image::RgbaImage> {
        if !self.images.contains_key(&index) {
            let img = self
                .doc
                .images()
                .nth(index)
                .ok_or_else(|| scene_err(self.path, format!("image {index} missing")))?;
            let what = format!(
                "image {index}{}",
                img.name().map(|n| format!(" '{n}'")).unwrap_or_default()
            );
            let (bytes, file) = match img.source() {
                gltf::image::Source::View { view, .. } => {
                    let buf = &self.buffers[view.buffer().index()];
                    let (o, l) = (view.offset(), view.length());
                    let slice = buf
                        .get(o..o + l)
                        .ok_or_else(|| scene_err(self.path, format!("{what}: buffer view out of range")))?;
                    (slice.to_vec(), self.path.to_path_buf())
                }
                gltf::image::Source::Uri { uri, .. } => {
                    read_uri(self.path, &self.base, uri, &what, u64::MAX)?
                }
            };
            let decoded = image::load_from_memory(&bytes)
                .map_err(|e| file_err(&file, format!("cannot decode {what}: {e}")))?
                .to_rgba8();
            self.images.insert(index, decoded);
        }
        Ok(&self.images[&index])
    }

    fn texture(
        &mut self,
        info: Option<(gltf::texture::Texture<'_>, u32)>,
        srgb: bool,
        slot: &str,
    ) -> Result<Option<u32>> {
        let Some((tex, coord)) = info else {
            return Ok(None);
        };
        if coord != 0 {
            self.note(format!(
                "{slot} texture uses TEXCOORD_{coord}; TEXCOORD_0 is used"
            ));
        }
        let key = (tex.index(), srgb);
        if let Some(&id) = self.texture_ids.get(&key) {
            return Ok(Some(id));
        }
        let image_index = tex.source().index();
        let name = tex
            .source()
            .name()
            .map(str::to_string)
            .or_else(|| match tex.source().source() {
                gltf::image::Source::Uri { uri, .. } => Some(uri.to_string()),
                _ => None,
            })
            .unwrap_or_else(|| format!("image {image_index}"));
        let sampler = tex.sampler();
        let wrap = |m: gltf::texture::WrappingMode| match m {
            gltf::texture::WrappingMode::ClampToEdge => Wrap::Clamp,
            gltf::texture::WrappingMode::MirroredRepeat => Wrap::Mirror,
            gltf::texture::WrappingMode::Repeat => Wrap::Repeat,
        };
        let w = [wrap(sampler.wrap_s()), wrap(sampler.wrap_t())];
        let img = self.image(image_index)?;
        let (width, height) = img.dimensions();
        if width == 0 || height == 0 {
            return Err(scene_err(self.path, format!("texture '{name}' is empty")));
        }
        let texels = img.pixels().map(|p| p.0).collect();
        self.textures.push(Texture {
            name,
            width,
            height,
            texels,
            srgb,
            wrap: w,
        });
        let id = self.textures.len() as u32 - 1;
        self.texture_ids.insert(key, id);
        Ok(Some(id))
    }

    fn material(&mut self, m: gltf::Material<'_>) -> Result<Material> {
        let name = m.name().unwrap_or("unnamed").to_string();
        let pbr = m.pbr_metallic_roughness();
        let base_color_texture = self.texture(
            pbr.base_color_texture().map(|t| (t.texture(), t.tex_coord())),
            true,
            "base colour",
        )?;
        let metallic_roughness_texture = self.texture(
            pbr.metallic_roughness_texture()
                .map(|t| (t.texture(), t.tex_coord())),
            false,
            "metallic-roughness",
        )?;
        let (normal_texture, normal_scale) = match m.normal_texture() {
            Some(n) => (
                self.texture(Some((n.texture(), n.tex_coord())), false, "normal")?,
                n.scale(),
            ),
            None => (None, 1.0),
        };
        let emissive_texture = self.texture(
            m.emissive_texture().map(|t| (t.texture(), t.tex_coord())),
            true,
            "emissive",
        )?;
        let strength = m.emissive_strength().unwrap_or(1.0);
        let emissive = m.emissive_factor().map(|e| e * strength);
        let (transmission, transmission_tex) = m
            .transmission()
            .map(|t| (t.transmission_factor(), t.transmission_texture().is_some()))
            .unwrap_or((0.0, false));
        if transmission_tex {
            self.note(format!(
                "material '{name}': transmission texture ignored (factor used)"
            ));
        }
        let volume = m.volume();
        if let Some(v) = &volume
            && v.thickness_texture().is_some()
        {
            self.note(format!("material '{name}': volume thickness texture ignored"));
        }
        let alpha = match m.alpha_mode() {
            gltf::material::AlphaMode::Opaque => AlphaMode::Opaque,
            gltf::material::AlphaMode::Mask => AlphaMode::Mask(m.alpha_cutoff().unwrap_or(0.5)),
            gltf::material::AlphaMode::Blend => {
                self.note(format!("material '{name}': alphaMode BLEND rendered as OPAQUE"));
                AlphaMode::Opaque
            }
        };
        let ior = m.ior().unwrap_or(1.5);
        Ok(Material {
            name,
            base_color: pbr.base_color_factor(),
            base_color_texture,
            metallic: pbr.metallic_factor(),
            roughness: pbr.roughness_factor(),
            metallic_roughness_texture,
            normal_texture,
            normal_scale,
            emissive,
            emissive_texture,
            transmission,
            ior: if ior.is_finite() && ior >= 1.0 { ior } else { 1.5 },
            thin: volume.is_none(),
            attenuation_color: volume.as_ref().map(|v| v.attenuation_color()).unwrap_or([1.0; 3]),
            attenuation_distance: volume
                .as_ref()
                .map(|v| v.attenuation_distance())
                .unwrap_or(f32::INFINITY),
            alpha,
            double_sided: m.double_sided(),
            specular: 1.0,
        })
    }
}

/// Loads a glTF 2.0 file (`.gltf` with its buffers and images, or `.glb`).
pub fn load_gltf(path: &Path) -> Result<Scene> {
    // The glTF reader indexes buffers directly; a file whose accessors overrun their views
    // must become an error naming the file, not a crash.
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| load_gltf_checked(path))).unwrap_or_else(|p| {
        let what = p
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_else(|| "unknown error".into());
        Err(scene_err(
            path,
            format!("malformed glTF (reading it failed: {what})"),
        ))
    })
}

fn load_gltf_checked(path: &Path) -> Result<Scene> {
    let bytes = crate::io::read_regular(path, u64::MAX)
        .map_err(|e| file_err(path, format!("cannot read glTF: {e}")))?;
    check_gltf_json(&bytes).map_err(|e| scene_err(path, format!("malformed glTF: {e}")))?;
    let gltf = gltf::Gltf::from_slice(&bytes).map_err(|e| scene_err(path, format!("malformed glTF: {e}")))?;
    let base = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let mut approx = Vec::new();
    for ext in gltf.extensions_required() {
        if !SUPPORTED_EXTENSIONS.contains(&ext) {
            return Err(scene_err(
                path,
                format!("requires the unsupported glTF extension {ext}"),
            ));
        }
    }
    let ignored: Vec<&str> = gltf
        .extensions_used()
        .filter(|e| !SUPPORTED_EXTENSIONS.contains(e))
        .collect();
    if !ignored.is_empty() {
        approx.push(format!("extensions ignored: {}", ignored.join(", ")));
    }
    let gltf::Gltf { document, blob } = gltf;
    let mut buffers = Vec::new();
    for b in document.buffers() {
        let data = match b.source() {
            gltf::buffer::Source::Bin => blob
                .clone()
                .ok_or_else(|| scene_err(path, "buffer refers to a missing GLB binary chunk"))?,
            gltf::buffer::Source::Uri(uri) => {
                read_uri(
                    path,
                    &base,
                    uri,
                    &format!("buffer {}", b.index()),
                    b.length() as u64,
                )?
                .0
            }
        };
        if data.len() < b.length() {
            return Err(scene_err(
                path,
                format!(
                    "buffer {} holds {} bytes, {} declared",
                    b.index(),
                    data.len(),
                    b.length()
                ),
            ));
        }
        buffers.push(data);
    }
    let mut loader = Loader {
        path,
        base,
        doc: document,
        buffers,
        images: HashMap::new(),
        textures: Vec::new(),
        texture_ids: HashMap::new(),
        approx,
    };
    let doc = loader.doc.clone();
    let mut materials = Vec::new();
    for m in doc.materials() {
        materials.push(loader.material(m)?);
    }
    let default_material = materials.len() as u32;
    materials.push(Material::default());

    let mut geometry = Geometry::default();
    let mut camera = None;
    let mut skipped_modes = 0usize;
    let scene = doc
        .default_scene()
        .or_else(|| doc.scenes().next())
        .ok_or_else(|| scene_err(path, "the glTF has no scene"))?;
    let mut stack: Vec<(gltf::Node, Mat4)> = scene.nodes().map(|n| (n, Mat4::IDENTITY)).collect();
    let mut visited = 0usize;
    while let Some((node, parent)) = stack.pop() {
        visited += 1;
        if visited > 1_000_000 {
            return Err(scene_err(path, "node hierarchy too large or cyclic"));
        }
        let local = Mat4::from_cols_array_2d(&node.transform().matrix());
        let world = parent * local;
        if !world.is_finite() {
            return Err(scene_err(
                path,
                format!("node {} has a non-finite transform", node.index()),
            ));
        }
        if camera.is_none()
            && let Some(c) = node.camera()
            && let gltf::camera::Projection::Perspective(p) = c.projection()
        {
            let pos = world.transform_point3(Vec3::ZERO);
            let fwd = world.transform_vector3(Vec3::NEG_Z).normalize_or(Vec3::NEG_Z);
            let up = world.transform_vector3(Vec3::Y).normalize_or(Vec3::Y);
            let c = Camera {
                position: pos,
                target: pos + fwd,
                up,
                yfov: p.yfov(),
            };
            c.check()
                .map_err(|e| scene_err(path, format!("glTF {e} (camera of node {})", node.index())))?;
            camera = Some(c);
        }
        if let Some(mesh) = node.mesh() {
            let normal_m = Mat3::from_mat4(world).inverse().transpose();
            let m3 = Mat3::from_mat4(world);
            let flip = m3.determinant() < 0.0;
            for prim in mesh.primitives() {
                if prim.mode() != gltf::mesh::Mode::Triangles {
                    skipped_modes += 1;
                    continue;
                }
                let bufs = &loader.buffers;
                let reader = prim.reader(|b| bufs.get(b.index()).map(|v| v.as_slice()));
                let what = format!("mesh {} primitive {}", mesh.index(), prim.index());
                let positions: Vec<Vec3> = reader
                    .read_positions()
                    .ok_or_else(|| scene_err(path, format!("{what} has no POSITION")))?
                    .map(|p| world.transform_point3(Vec3::from(p)))
                    .collect();
                let n = positions.len();
                let normals: Option<Vec<Vec3>> = reader.read_normals().map(|it| {
                    it.map(|v| (normal_m * Vec3::from(v)).normalize_or_zero())
                        .collect()
                });
                let uvs: Option<Vec<Vec2>> = reader
                    .read_tex_coords(0)
                    .map(|it| it.into_f32().map(Vec2::from).collect());
                let tangents: Option<Vec<Vec4>> = reader.read_tangents().map(|it| {
                    it.map(|t| {
                        let v = (m3 * Vec3::new(t[0], t[1], t[2])).normalize_or_zero();
                        v.extend(if flip { -t[3] } else { t[3] })
                    })
                    .collect()
                });
                for (attr, len) in [
                    ("NORMAL", normals.as_ref().map(|v| v.len())),
                    ("TEXCOORD_0", uvs.as_ref().map(|v| v.len())),
                    ("TANGENT", tangents.as_ref().map(|v| v.len())),
                ] {
                    if let Some(l) = len
                        && l != n
                    {
                        return Err(scene_err(
                            path,
                            format!("{what}: {attr} has {l} entries, POSITION {n}"),
                        ));
                    }
                }
                let indices: Vec<u32> = match reader.read_indices() {
                    Some(i) => i.into_u32().collect(),
                    None => (0..n as u32).collect(),
                };
                if !indices.len().is_multiple_of(3) {
                    return Err(scene_err(
                        path,
                        format!("{what}: index count {} is not a multiple of 3", indices.len()),
                    ));
                }
                if let Some(&bad) = indices.iter().find(|&&i| i as usize >= n) {
                    return Err(scene_err(
                        path,
                        format!("{what}: index {bad} past its {n} vertices"),
                    ));
                }
                let tris: Vec<[u32; 3]> = indices
                    .chunks_exact(3)
                    .map(|c| {
                        if flip {
                            [c[0], c[2], c[1]]
                        } else {
                            [c[0], c[1], c[2]]
                        }
                    })
                    .collect();
                let material = prim
                    .material()
                    .index()
                    .map(|i| i as u32)
                    .unwrap_or(default_material);
                geometry.push_mesh(
                    &positions,
                    normals.as_deref(),
                    uvs.as_deref(),
                    tangents.as_deref(),
                    &tris,
                    material,
                );
            }
        }
        for child in node.children() {
            stack.push((child, world));
        }
    }
    if skipped_modes > 0 {
        log::warn!(
            "{}: {skipped_modes} non-triangle primitive(s) (points/lines/strips) skipped",
            path.display()
        );
    }
    if geometry.triangles.is_empty() {
        return Err(scene_err(path, "the glTF scene has no triangles"));
    }
    let (lo, hi) = geometry.bounds();
    let camera = camera.unwrap_or_else(|| {
        let c = 0.5 * (lo + hi);
        let r = 0.5 * (hi - lo).length().max(1e-3);
        Camera {
            position: c + Vec3::new(0.0, 0.0, 2.5 * r),
            target: c,
            up: Vec3::Y,
            yfov: 45f32.to_radians(),
        }
    });
    let scene = Scene {
        name: path.display().to_string(),
        geometry,
        materials,
        textures: loader.textures,
        environment: None,
        camera,
        film: (512, 512),
        camera_path: None,
        approximations: loader.approx,
    };
    scene.validate()?;
    Ok(scene)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_and_percent() {
        assert_eq!(base64_decode("aGVsbG8=").unwrap(), b"hello");
        assert_eq!(base64_decode("AAEC").unwrap(), vec![0, 1, 2]);
        assert!(base64_decode("a*b").is_none());
        assert_eq!(percent_decode("a%20b.png"), "a b.png");
        assert_eq!(percent_decode("100%"), "100%");
    }

    fn base64_encode(b: &[u8]) -> String {
        const A: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
        let mut s = String::new();
        for c in b.chunks(3) {
            let n =
                (c[0] as u32) << 16 | (*c.get(1).unwrap_or(&0) as u32) << 8 | *c.get(2).unwrap_or(&0) as u32;
            for k in 0..4 {
                if k <= c.len() {
                    s.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
                } else {
                    s.push('=');
                }
            }
        }
        s
    }

    /// A one-triangle glTF (positions + u16 indices in a data URI); `extra` is merged into
    /// the root object, `node` into the node.
    fn tiny_gltf(extra: &str, node: &str, material: &str) -> String {
        let mut bytes = Vec::new();
        for v in [[0f32, 0., 0.], [1., 0., 0.], [0., 1., 0.]] {
            for c in v {
                bytes.extend(c.to_le_bytes());
            }
        }
        for i in [0u16, 1, 2, 0] {
            bytes.extend(i.to_le_bytes());
        }
        format!(
            r#"{{"asset": {{"version": "2.0"}}, "scene": 0, "scenes": [{{"nodes": [0]}}],
            "nodes": [{{"mesh": 0 {node}}}],
            "meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0}}, "indices": 1 {material}}}]}}],
            "accessors": [
              {{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0,0,0], "max": [1,1,0]}},
              {{"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"}}],
            "bufferViews": [{{"buffer": 0, "byteOffset": 0, "byteLength": 36}}, {{"buffer": 0, "byteOffset": 36, "byteLength": 6}}],
            "buffers": [{{"byteLength": 44, "uri": "data:application/octet-stream;base64,{}"}}] {extra}}}"#,
            base64_encode(&bytes)
        )
    }

    fn tmp(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("subpixel-loader-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn tiny_gltf_loads_with_node_transform_and_mirroring() {
        let d = tmp("ok");
        let p = d.join("t.gltf");
        std::fs::write(&p, tiny_gltf("", r#", "translation": [0, 0, -5]"#, "")).unwrap();
        let s = load_scene(p.to_str().unwrap()).unwrap();
        assert_eq!(s.geometry.triangles.len(), 1);
        assert_eq!(s.geometry.positions[1], Vec3::new(1.0, 0.0, -5.0));
        // Default material: glTF defaults.
        assert_eq!(s.materials.last().unwrap().metallic, 1.0);
        // A mirroring transform keeps the front face (winding flipped).
        std::fs::write(&p, tiny_gltf("", r#", "scale": [-1, 1, 1]"#, "")).unwrap();
        let s = load_scene(p.to_str().unwrap()).unwrap();
        let [a, b, c] = s.geometry.triangles[0].map(|i| s.geometry.positions[i as usize]);
        assert!((b - a).cross(c - a).z > 0.0, "front face must still face +z");
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn bad_files_are_named_errors() {
        let d = tmp("bad");
        // Malformed JSON.
        let p = d.join("broken.gltf");
        std::fs::write(&p, "{ not json").unwrap();
        let e = load_scene(p.to_str().unwrap()).unwrap_err().to_string();
        assert!(e.contains("broken.gltf") && e.contains("malformed"), "{e}");
        // Unsupported required extension.
        let p = d.join("draco.gltf");
        let ext = r#", "extensionsUsed": ["KHR_draco_mesh_compression"], "extensionsRequired": ["KHR_draco_mesh_compression"]"#;
        std::fs::write(&p, tiny_gltf(ext, "", "")).unwrap();
        let e = load_scene(p.to_str().unwrap()).unwrap_err().to_string();
        assert!(
            e.contains("draco.gltf") && e.contains("KHR_draco_mesh_compression"),
            "{e}"
        );
        // Missing texture file.
        let p = d.join("tex.gltf");
        let extra = r#", "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
            "textures": [{"source": 0}], "images": [{"uri": "missing_albedo.png"}]"#;
        std::fs::write(&p, tiny_gltf(extra, "", r#", "material": 0"#)).unwrap();
        let e = load_scene(p.to_str().unwrap()).unwrap_err().to_string();
        assert!(e.contains("missing_albedo.png") && e.contains("tex.gltf"), "{e}");
        // Undecodable texture.
        std::fs::write(d.join("missing_albedo.png"), b"not a png").unwrap();
        let e = load_scene(p.to_str().unwrap()).unwrap_err().to_string();
        assert!(e.contains("missing_albedo.png") && e.contains("decode"), "{e}");
        // Unreadable / corrupt environment map.
        let ok = d.join("ok.gltf");
        std::fs::write(&ok, tiny_gltf("", "", "")).unwrap();
        let json = d.join("scene.json");
        std::fs::write(
            &json,
            r#"{"gltf": "ok.gltf", "environment": {"file": "sky.hdr", "scale": 1.0}}"#,
        )
        .unwrap();
        let e = load_scene(d.to_str().unwrap()).unwrap_err().to_string();
        assert!(e.contains("sky.hdr"), "{e}");
        std::fs::write(d.join("sky.hdr"), b"#?RADIANCE\ngarbage").unwrap();
        let e = load_scene(json.to_str().unwrap()).unwrap_err().to_string();
        assert!(e.contains("sky.hdr") && e.contains("environment"), "{e}");
        // Malformed scene.json.
        std::fs::write(&json, r#"{"environment": null}"#).unwrap();
        let e = load_scene(json.to_str().unwrap()).unwrap_err().to_string();
        assert!(e.contains("scene.json") && e.contains("gltf"), "{e}");
        // Missing file, unknown extension.
        let e = load_scene(d.join("nope.glb").to_str().unwrap())
            .unwrap_err()
            .to_string();
        assert!(e.contains("nope.glb"), "{e}");
        std::fs::write(d.join("x.obj"), "").unwrap();
        let e = load_scene(d.join("x.obj").to_str().unwrap())
            .unwrap_err()
            .to_string();
        assert!(e.contains("x.obj"), "{e}");
        std::fs::remove_dir_all(&d).ok();
    }

    /// Issue 12 item 9: a FIFO or a device as glTF, buffer, image or environment map is
    /// refused (regular files only) instead of blocking or reading forever.
    #[cfg(unix)]
    #[test]
    fn special_files_are_refused() {
        let d = tmp("special");
        let fifo = d.join("fifo.bin");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        assert!(made.map(|s| s.success()).unwrap_or(false), "mkfifo");
        let e = load_scene("/dev/zero").unwrap_err().to_string();
        assert!(e.contains("/dev/zero"), "{e}");
        std::os::unix::fs::symlink("/dev/zero", d.join("zero.gltf")).unwrap();
        let e = load_scene(d.join("zero.gltf").to_str().unwrap())
            .unwrap_err()
            .to_string();
        assert!(e.contains("zero.gltf") && e.contains("not a regular file"), "{e}");
        std::os::unix::fs::symlink(&fifo, d.join("fifo.glb")).unwrap();
        let e = load_scene(d.join("fifo.glb").to_str().unwrap())
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a regular file"), "{e}");
        // A buffer and an image that are a FIFO and /dev/zero.
        let data_uri = tiny_gltf("", "", "");
        let with_buffer = |uri: &str| {
            let at = data_uri.find("data:application").unwrap();
            let end = at + data_uri[at..].find('"').unwrap();
            format!("{}{uri}{}", &data_uri[..at], &data_uri[end..])
        };
        for uri in ["fifo.bin", "/dev/zero"] {
            let p = d.join("buf.gltf");
            std::fs::write(&p, with_buffer(uri)).unwrap();
            let e = load_scene(p.to_str().unwrap()).unwrap_err().to_string();
            assert!(
                e.contains("not a regular file") && e.contains("buffer 0"),
                "{uri}: {e}"
            );
        }
        let p = d.join("tex.gltf");
        let extra = r#", "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
            "textures": [{"source": 0}], "images": [{"uri": "fifo.bin"}]"#;
        std::fs::write(&p, tiny_gltf(extra, "", r#", "material": 0"#)).unwrap();
        let e = load_scene(p.to_str().unwrap()).unwrap_err().to_string();
        assert!(e.contains("fifo.bin") && e.contains("not a regular file"), "{e}");
        std::fs::write(d.join("ok.gltf"), tiny_gltf("", "", "")).unwrap();
        std::fs::write(
            d.join("scene.json"),
            r#"{"gltf": "ok.gltf", "environment": {"file": "fifo.bin", "scale": 1.0}}"#,
        )
        .unwrap();
        let e = load_scene(d.join("scene.json").to_str().unwrap())
            .unwrap_err()
            .to_string();
        assert!(e.contains("fifo.bin") && e.contains("not a regular file"), "{e}");
        std::fs::remove_dir_all(&d).ok();
    }

    /// Issue 12 item 6: glTF files that made the `gltf` crate panic (its message and a
    /// backtrace reached the user before the clean error) are refused from their JSON, by
    /// the loader itself, without any panic.
    #[test]
    fn gltf_crate_panics_are_prevented() {
        let d = tmp("panics");
        let json: serde_json::Value = serde_json::from_str(&tiny_gltf("", "", "")).unwrap();
        type Edit = fn(&mut serde_json::Value);
        let cases: [(&str, Edit, &str); 6] = [
            (
                "indices of float VEC3",
                |j| j["meshes"][0]["primitives"][0]["indices"] = 0.into(),
                "indices: accessors[0] is VEC3 of componentType 5126, expected SCALAR",
            ),
            (
                "POSITION accessor out of range",
                |j| j["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = 9.into(),
                "attributes.POSITION: accessor 9 does not exist",
            ),
            (
                "indices accessor out of range",
                |j| j["meshes"][0]["primitives"][0]["indices"] = 7.into(),
                "indices: accessor 7 does not exist",
            ),
            (
                "byteStride smaller than the element",
                |j| j["bufferViews"][0]["byteStride"] = 4.into(),
                "byteStride 4 is smaller than the 12-byte elements",
            ),
            (
                "TEXCOORD_0 of unsigned int",
                |j| {
                    j["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = 2.into();
                    j["accessors"].as_array_mut().unwrap().push(serde_json::json!(
                        {"bufferView": 0, "componentType": 5125, "count": 3, "type": "VEC2"}
                    ));
                },
                "TEXCOORD_0: accessors[2] is VEC2 of componentType 5125",
            ),
            (
                "accessor past its view",
                |j| j["accessors"][0]["count"] = 1_000_000.into(),
                "runs past bufferViews[0]",
            ),
        ];
        for (name, edit, want) in cases {
            let mut j = json.clone();
            edit(&mut j);
            let p = d.join("m.gltf");
            std::fs::write(&p, j.to_string()).unwrap();
            let r = std::panic::catch_unwind(|| load_gltf_checked(&p));
            let e = r
                .unwrap_or_else(|_| panic!("{name}: the loader panicked"))
                .map(|_| ())
                .unwrap_err()
                .to_string();
            assert!(e.contains("m.gltf") && e.contains(want), "{name}: {e}");
        }
        std::fs::remove_dir_all(&d).ok();
    }

    /// Issue 12 item 7: degenerate cameras in scene.json or glTF are errors naming the
    /// field, not black frames or NaN motion.
    #[test]
    fn degenerate_cameras_are_named_errors() {
        let d = tmp("cams");
        std::fs::write(d.join("ok.gltf"), tiny_gltf("", "", "")).unwrap();
        let json = d.join("scene.json");
        let cam = |c: &str, path: &str| {
            std::fs::write(&json, format!(r#"{{"gltf": "ok.gltf", "camera": {c} {path}}}"#)).unwrap();
            load_scene(json.to_str().unwrap())
                .map(|_| ())
                .map_err(|e| e.to_string())
        };
        let good = r#"{"position": [0, 0, 3], "target": [0, 0, 0], "up": [0, 1, 0], "yfov_deg": 40}"#;
        cam(good, "").unwrap();
        for (c, want) in [
            (
                r#"{"position": [0, 0, 3], "target": [0, 0, 3], "yfov_deg": 40}"#,
                "target",
            ),
            (
                r#"{"position": [0, 0, 3], "target": [0, 0, 0], "up": [0, 0, 1], "yfov_deg": 40}"#,
                "up",
            ),
            (
                r#"{"position": [0, 0, 3], "target": [0, 0, 0], "up": [0, 0, 0], "yfov_deg": 40}"#,
                "up",
            ),
            (
                r#"{"position": [1e39, 0, 3], "target": [0, 0, 0], "yfov_deg": 40}"#,
                "position",
            ),
            (
                r#"{"position": [0, 0, 3], "target": [0, 0, 0], "yfov_deg": 0}"#,
                "yfov",
            ),
        ] {
            let e = cam(c, "").unwrap_err();
            assert!(e.contains("scene.json") && e.contains(want), "{c}: {e}");
        }
        for (p, want) in [
            (
                r#", "camera_path": {"type": "orbit", "degrees_per_frame": 1e39}"#,
                "degrees_per_frame",
            ),
            (
                r#", "camera_path": {"type": "orbit", "degrees_per_frame": 1e30}"#,
                "degrees_per_frame",
            ),
            (
                r#", "camera_path": {"type": "flythrough", "keys": [{"position": [0, 0, 3], "target": [0, 0, 0]}, {"position": [1, 1, 1], "target": [1, 1, 1]}]}"#,
                "keys[1]",
            ),
        ] {
            let e = cam(good, p).unwrap_err();
            assert!(e.contains("scene.json") && e.contains(want), "{p}: {e}");
        }
        // A glTF camera with yfov 0.
        let p = d.join("cam.gltf");
        let extra = r#", "cameras": [{"type": "perspective", "perspective": {"yfov": 0.0, "znear": 0.1}}]"#;
        std::fs::write(&p, tiny_gltf(extra, r#", "camera": 0"#, "")).unwrap();
        let e = load_scene(p.to_str().unwrap()).unwrap_err().to_string();
        assert!(
            e.contains("cam.gltf") && e.contains("yfov") && e.contains("node 0"),
            "{e}"
        );
        std::fs::remove_dir_all(&d).ok();
    }

    /// A buffer file longer than its declared byteLength loads (only the declared bytes are
    /// read: `read_regular`'s cap, tested in `io`).
    #[test]
    fn buffers_are_read_up_to_their_declared_length() {
        let d = tmp("cap");
        let g = tiny_gltf("", "", "");
        let at = g.find("data:application").unwrap();
        let end = at + g[at..].find('"').unwrap();
        let b64 = &g[at + "data:application/octet-stream;base64,".len()..end];
        let mut bytes = base64_decode(b64).unwrap();
        bytes.extend(std::iter::repeat_n(0xAB, 1 << 20));
        std::fs::write(d.join("big.bin"), &bytes).unwrap();
        let p = d.join("cap.gltf");
        std::fs::write(&p, format!("{}big.bin{}", &g[..at], &g[end..])).unwrap();
        let s = load_scene(p.to_str().unwrap()).unwrap();
        assert_eq!(s.geometry.triangles.len(), 1);
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn sidecar_environment_and_camera() {
        let d = tmp("side");
        std::fs::write(d.join("ok.gltf"), tiny_gltf("", "", "")).unwrap();
        // A 4x2 RGB float EXR environment, via the image crate.
        let img = image::Rgb32FImage::from_fn(4, 2, |x, y| image::Rgb([x as f32, y as f32, 1.0]));
        image::DynamicImage::ImageRgb32F(img)
            .save(d.join("env.exr"))
            .unwrap();
        std::fs::write(
            d.join("scene.json"),
            r#"{"gltf": "ok.gltf",
                "environment": {"file": "env.exr", "scale": 2.0, "rotation_y_deg": 90.0,
                                "mapping": "mitsuba_latlong: ..."},
                "camera": {"position": [0, 0, 3], "target": [0, 0, 0], "up": [0, 1, 0], "yfov_deg": 40},
                "film": [64, 32],
                "camera_path": {"type": "orbit", "degrees_per_frame": 2.0}}"#,
        )
        .unwrap();
        let s = load_scene(d.to_str().unwrap()).unwrap();
        let e = s.environment.as_ref().unwrap();
        assert_eq!((e.width, e.height, e.scale), (4, 2, 2.0));
        assert_eq!(s.film, (64, 32));
        assert!((s.camera.yfov - 40f32.to_radians()).abs() < 1e-6);
        assert_eq!(
            s.camera_path,
            Some(CameraPathSpec::Orbit {
                degrees_per_frame: Some(2.0)
            })
        );
        // Mitsuba lat-long: with to_world = rotate 90 deg about +y, world +x maps to map
        // direction +z: u = atan2(0, -1) / 2pi = 0.5 -> column 2; v = 0.5 -> row 1.
        let c = e.radiance(Vec3::X);
        assert_eq!(c, Vec3::new(2.0, 1.0, 1.0) * 2.0);
        // World -z maps to map +x (rotated): u = atan2(1, 0) / 2pi = 0.25 -> column 1.
        let c = e.radiance(Vec3::NEG_Z);
        assert_eq!(c, Vec3::new(1.0, 1.0, 1.0) * 2.0);
        std::fs::remove_dir_all(&d).ok();
    }
}
