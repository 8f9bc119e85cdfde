//! glTF 2.0 (`.gltf` with its buffers and images, `.glb`): meshes, metallic-roughness
//! materials with the supported extensions, textures, node transforms and the first camera,
//! with every malformed input a named error (never a panic).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{Mat3, Mat4, Vec2, Vec3, Vec4};

use super::{file_err, scene_err};
use crate::error::Result;
use crate::render::camera::Camera;
use crate::render::scene::{AlphaMode, Geometry, Material, Scene, Texture, Wrap};

/// glTF extensions the loader understands; a file requiring any other is refused.
pub const SUPPORTED_EXTENSIONS: &[&str] = &[
    "KHR_materials_emissive_strength",
    "KHR_materials_transmission",
    "KHR_materials_ior",
    "KHR_materials_volume",
];

/// Decodes the base64 payload of a data URI (RFC 4648 standard alphabet; padding optional).
pub(super) fn base64_decode(s: &str) -> Option<Vec<u8>> {
    use base64::Engine;
    use base64::engine::{DecodePaddingMode, GeneralPurpose, GeneralPurposeConfig};
    const DATA_URI: GeneralPurpose = GeneralPurpose::new(
        &base64::alphabet::STANDARD,
        GeneralPurposeConfig::new().with_decode_padding_mode(DecodePaddingMode::Indifferent),
    );
    DATA_URI.decode(s.trim()).ok()
}

/// A relative URI's `%XX` escapes decoded (a file name with spaces is written `a%20b.png`).
pub(super) fn percent_decode(s: &str) -> String {
    percent_encoding::percent_decode_str(s)
        .decode_utf8_lossy()
        .into_owned()
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

pub(super) fn load_gltf_checked(path: &Path) -> Result<Scene> {
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
