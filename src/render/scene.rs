//! The scene model the tracer renders: world-space triangles with per-vertex attributes,
//! glTF metallic-roughness materials, RGBA8 textures, an optional lat-long environment map,
//! and a camera.

use std::path::PathBuf;

use glam::{Mat3, Vec2, Vec3, Vec4};

use super::camera::{Camera, CameraPath, CameraPathSpec, RayProbe};
use crate::error::{Error, Result};

/// Texture coordinate wrap mode (glTF sampler).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Wrap {
    /// Tile.
    #[default]
    Repeat,
    /// Clamp to the edge texel.
    Clamp,
    /// Tile, mirroring every other copy.
    Mirror,
}

impl Wrap {
    /// Code used by the WGSL texture sampler.
    pub fn code(self) -> u32 {
        match self {
            Wrap::Repeat => 0,
            Wrap::Clamp => 1,
            Wrap::Mirror => 2,
        }
    }
}

/// An 8-bit RGBA texture.
#[derive(Debug, Clone)]
pub struct Texture {
    /// Where it came from (file name or a description), for messages.
    pub name: String,
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// `width * height` texels, row-major from the top-left.
    pub texels: Vec<[u8; 4]>,
    /// The RGB channels hold sRGB-encoded colour (base colour, emissive).
    pub srgb: bool,
    /// Wrap modes along u and v.
    pub wrap: [Wrap; 2],
}

impl Texture {
    /// Mean of the linear RGB values (sRGB decoded when `srgb`).
    pub fn mean_rgb(&self) -> Vec3 {
        if self.texels.is_empty() {
            return Vec3::ZERO;
        }
        let lut = &*SRGB_BYTE_TO_LINEAR;
        let mut sum = glam::DVec3::ZERO;
        for t in &self.texels {
            let c = if self.srgb {
                Vec3::new(lut[t[0] as usize], lut[t[1] as usize], lut[t[2] as usize])
            } else {
                Vec3::new(t[0] as f32, t[1] as f32, t[2] as f32) / 255.0
            };
            sum += c.as_dvec3();
        }
        (sum / self.texels.len() as f64).as_vec3()
    }

    /// This texture at half resolution (2x2 box filter; odd edges clamp).
    pub fn halved(&self) -> Texture {
        let w = (self.width / 2).max(1);
        let h = (self.height / 2).max(1);
        let mut texels = Vec::with_capacity((w * h) as usize);
        for y in 0..h {
            for x in 0..w {
                let mut acc = [0u32; 4];
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let sx = (2 * x + dx).min(self.width - 1);
                    let sy = (2 * y + dy).min(self.height - 1);
                    let t = self.texels[(sy * self.width + sx) as usize];
                    for c in 0..4 {
                        acc[c] += t[c] as u32;
                    }
                }
                texels.push(acc.map(|a| ((a + 2) / 4) as u8));
            }
        }
        Texture {
            name: self.name.clone(),
            width: w,
            height: h,
            texels,
            srgb: self.srgb,
            wrap: self.wrap,
        }
    }
}

/// sRGB transfer function decode.
pub fn srgb_to_linear(c: Vec3) -> Vec3 {
    Vec3::new(srgb_decode(c.x), srgb_decode(c.y), srgb_decode(c.z))
}

/// sRGB transfer function decode of one channel.
#[inline]
pub fn srgb_decode(v: f32) -> f32 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// `srgb_decode(b / 255)` of every byte `b`: the decode of an sRGB texel channel, looked up
/// instead of evaluated (a `powf` per channel and texel was a few percent of a textured
/// scene's render time, and most of a procedural scene's construction); the same values to
/// the bit.
pub(crate) static SRGB_BYTE_TO_LINEAR: std::sync::LazyLock<[f32; 256]> =
    std::sync::LazyLock::new(|| std::array::from_fn(|b| srgb_decode(b as f32 / 255.0)));

/// How a material's alpha is used.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum AlphaMode {
    /// Alpha ignored.
    #[default]
    Opaque,
    /// Cut-out: surfaces with alpha below the cutoff are not there.
    Mask(f32),
}

/// A glTF 2.0 metallic-roughness material with the extensions the tracer understands.
#[derive(Debug, Clone)]
pub struct Material {
    /// Name, for messages.
    pub name: String,
    /// Linear base colour factor (rgb) and alpha.
    pub base_color: [f32; 4],
    /// Base colour texture (sRGB), index into [`Scene::textures`].
    pub base_color_texture: Option<u32>,
    /// Metallic factor.
    pub metallic: f32,
    /// Perceptual roughness factor.
    pub roughness: f32,
    /// Metallic (B) / roughness (G) texture.
    pub metallic_roughness_texture: Option<u32>,
    /// Tangent-space normal map.
    pub normal_texture: Option<u32>,
    /// Normal map xy scale.
    pub normal_scale: f32,
    /// Emitted radiance: emissive factor x `KHR_materials_emissive_strength`.
    pub emissive: [f32; 3],
    /// Emissive texture (sRGB), multiplies `emissive`.
    pub emissive_texture: Option<u32>,
    /// `KHR_materials_transmission` factor.
    pub transmission: f32,
    /// `KHR_materials_ior` (1.5 by default).
    pub ior: f32,
    /// Thin-walled transmission (no `KHR_materials_volume`): light passes straight through.
    pub thin: bool,
    /// Volume attenuation colour (`KHR_materials_volume`).
    pub attenuation_color: [f32; 3],
    /// Volume attenuation distance; infinite for none.
    pub attenuation_distance: f32,
    /// Alpha mode.
    pub alpha: AlphaMode,
    /// Both faces are shaded; otherwise an opaque surface is black from behind.
    pub double_sided: bool,
    /// Strength of the dielectric specular layer (`KHR_materials_specular`; 1 by default,
    /// 0 gives a pure Lambertian diffuse).
    pub specular: f32,
}

impl Default for Material {
    fn default() -> Self {
        Self {
            name: "default".into(),
            base_color: [1.0; 4],
            base_color_texture: None,
            metallic: 1.0,
            roughness: 1.0,
            metallic_roughness_texture: None,
            normal_texture: None,
            normal_scale: 1.0,
            emissive: [0.0; 3],
            emissive_texture: None,
            transmission: 0.0,
            ior: 1.5,
            thin: true,
            attenuation_color: [1.0; 3],
            attenuation_distance: f32::INFINITY,
            alpha: AlphaMode::Opaque,
            double_sided: false,
            specular: 1.0,
        }
    }
}

impl Material {
    /// A diffuse (metallic 0, roughness 1) material of colour `rgb`.
    pub fn diffuse(name: &str, rgb: [f32; 3]) -> Self {
        Self {
            name: name.into(),
            base_color: [rgb[0], rgb[1], rgb[2], 1.0],
            metallic: 0.0,
            roughness: 1.0,
            ..Default::default()
        }
    }

    /// A metal (metallic 1) of reflectance at normal incidence `rgb` and `roughness`.
    pub fn metal(name: &str, rgb: [f32; 3], roughness: f32) -> Self {
        Self {
            name: name.into(),
            base_color: [rgb[0], rgb[1], rgb[2], 1.0],
            metallic: 1.0,
            roughness,
            ..Default::default()
        }
    }

    /// A dielectric (transmission 1) of tint `rgb`, `roughness` and index of refraction
    /// `ior`: a solid that refracts (`thin == false`), or a thin sheet seen from both sides.
    pub fn glass(name: &str, rgb: [f32; 3], roughness: f32, ior: f32, thin: bool) -> Self {
        Self {
            name: name.into(),
            base_color: [rgb[0], rgb[1], rgb[2], 1.0],
            metallic: 0.0,
            roughness,
            transmission: 1.0,
            ior,
            thin,
            double_sided: thin,
            ..Default::default()
        }
    }

    /// Luminance of the emitted radiance, texture mean included: the light-selection weight.
    pub fn emitted_luminance(&self, textures: &[Texture]) -> f32 {
        let mut e = Vec3::from(self.emissive);
        if let Some(t) = self.emissive_texture.and_then(|t| textures.get(t as usize)) {
            e *= t.mean_rgb();
        }
        luminance(e).max(0.0)
    }
}

/// Rec.709 luminance.
pub fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

/// A lat-long environment map (Mitsuba convention, see `scenes/README.md`).
#[derive(Debug, Clone)]
pub struct Environment {
    /// Where it came from.
    pub source: PathBuf,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Linear RGB radiance, row-major from the top-left (`v = 0` is straight up).
    pub pixels: Vec<[f32; 3]>,
    /// Radiance scale.
    pub scale: f32,
    /// Map-to-world rotation (`to_world` of `scene.json`).
    pub to_world: Mat3,
    /// Openings (windows, doors) through which the environment lights an interior. When
    /// there are any, half of the environment's light samples pick a point on one of them
    /// instead of a direction from the map. A sampling aid only: portals change the noise,
    /// never the expected image, even where they do not match the geometry.
    pub portals: Vec<Portal>,
}

/// An opening through which the environment is seen from inside a scene: the
/// parallelogram `corner + s u + t v`, `s` and `t` in `[0, 1]`, looked through from the side
/// that `u x v` points to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Portal {
    /// One corner.
    pub corner: Vec3,
    /// First edge from the corner.
    pub u: Vec3,
    /// Second edge from the corner.
    pub v: Vec3,
}

impl Portal {
    /// Area of the opening.
    pub fn area(&self) -> f32 {
        self.u.cross(self.v).length()
    }
}

impl Environment {
    /// A map of `width` x `height` linear RGB `pixels` (row-major from the top-left) from
    /// `source`, unscaled, unrotated, without portals.
    pub fn from_pixels(source: impl Into<PathBuf>, width: u32, height: u32, pixels: Vec<[f32; 3]>) -> Self {
        Self {
            source: source.into(),
            width,
            height,
            pixels,
            scale: 1.0,
            to_world: Mat3::IDENTITY,
            portals: Vec::new(),
        }
    }

    /// A constant environment of radiance `rgb` (a small map, so the CDF code path is used).
    pub fn uniform(rgb: [f32; 3]) -> Self {
        let (width, height) = (8, 4);
        Self::from_pixels(
            format!("uniform {rgb:?}"),
            width,
            height,
            vec![rgb; (width * height) as usize],
        )
    }

    /// Radiance (scaled) towards world direction `d`, nearest texel, as the GPU looks it up.
    pub fn radiance(&self, d: Vec3) -> Vec3 {
        let l = self.to_world.inverse() * d;
        let u = (l.x.atan2(-l.z) / std::f32::consts::TAU).rem_euclid(1.0);
        let v = l.y.clamp(-1.0, 1.0).acos() / std::f32::consts::PI;
        let x = ((u * self.width as f32) as u32).min(self.width - 1);
        let y = ((v * self.height as f32) as u32).min(self.height - 1);
        Vec3::from(self.pixels[(y * self.width + x) as usize]) * self.scale
    }
}

/// Triangles in world space with per-vertex attributes. Vertices are never shared between
/// triangles of different materials.
#[derive(Debug, Clone, Default)]
pub struct Geometry {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Vertex shading normals (unit).
    pub normals: Vec<Vec3>,
    /// Vertex texture coordinates (`TEXCOORD_0`), zero when absent.
    pub uvs: Vec<Vec2>,
    /// Vertex tangents (xyz, w = bitangent sign); `Vec4::ZERO` where absent.
    pub tangents: Vec<Vec4>,
    /// Vertex indices of each triangle (counter-clockwise front faces).
    pub triangles: Vec<[u32; 3]>,
    /// Material index of each triangle.
    pub materials: Vec<u32>,
}

impl Geometry {
    /// Appends a triangle mesh; normals default to the face normals, uvs to zero.
    #[allow(clippy::too_many_arguments)]
    pub fn push_mesh(
        &mut self,
        positions: &[Vec3],
        normals: Option<&[Vec3]>,
        uvs: Option<&[Vec2]>,
        tangents: Option<&[Vec4]>,
        triangles: &[[u32; 3]],
        material: u32,
    ) {
        let base = self.positions.len() as u32;
        self.positions.extend_from_slice(positions);
        match normals {
            Some(n) => self.normals.extend(n.iter().map(|v| v.normalize_or_zero())),
            None => {
                // Area-weighted face normals.
                let mut acc = vec![Vec3::ZERO; positions.len()];
                for t in triangles {
                    let [a, b, c] = t.map(|i| positions[i as usize]);
                    let n = (b - a).cross(c - a);
                    for &i in t {
                        acc[i as usize] += n;
                    }
                }
                self.normals.extend(acc.iter().map(|v| v.normalize_or_zero()));
            }
        }
        match uvs {
            Some(u) => self.uvs.extend_from_slice(u),
            None => self.uvs.extend(std::iter::repeat_n(Vec2::ZERO, positions.len())),
        }
        match tangents {
            Some(t) => self.tangents.extend_from_slice(t),
            None => self
                .tangents
                .extend(std::iter::repeat_n(Vec4::ZERO, positions.len())),
        }
        for t in triangles {
            self.triangles.push(t.map(|i| i + base));
            self.materials.push(material);
        }
    }

    /// A UV sphere of radius `r` centred at `c` (faces outwards): `segments` around, `rings`
    /// from the north pole (at least 3 and 2), smooth normals, texture coordinates (u around,
    /// v from the north pole, each in [0, 1] times `uv_scale`) and, with `tangents`, tangents
    /// along u (for normal maps).
    pub fn push_uv_sphere(
        &mut self,
        c: Vec3,
        r: f32,
        (segments, rings): (u32, u32),
        uv_scale: Vec2,
        tangents: bool,
        material: u32,
    ) {
        let (segments, rings) = (segments.max(3), rings.max(2));
        let mut pos = Vec::new();
        let mut nrm = Vec::new();
        let mut uv = Vec::new();
        let mut tan = Vec::new();
        for j in 0..=rings {
            let v = j as f32 / rings as f32;
            let theta = v * std::f32::consts::PI;
            for i in 0..=segments {
                let u = i as f32 / segments as f32;
                let phi = u * std::f32::consts::TAU;
                let n = Vec3::new(theta.sin() * phi.cos(), theta.cos(), -theta.sin() * phi.sin());
                pos.push(c + r * n);
                nrm.push(n);
                uv.push(Vec2::new(u, v) * uv_scale);
                tan.push(Vec4::new(-phi.sin(), 0.0, -phi.cos(), 1.0));
            }
        }
        let mut tris = Vec::new();
        let row = segments + 1;
        for j in 0..rings {
            for i in 0..segments {
                let a = j * row + i;
                let b = a + row;
                // Counter-clockwise seen from outside.
                if j != 0 {
                    tris.push([a, b, a + 1]);
                }
                if j != rings - 1 {
                    tris.push([a + 1, b, b + 1]);
                }
            }
        }
        let tan = tangents.then_some(tan.as_slice());
        self.push_mesh(&pos, Some(&nrm), Some(&uv), tan, &tris, material);
    }

    /// Appends a quad with the `corners` `a b c d` (counter-clockwise seen from the front),
    /// uv (0, 1) at `a`, (1, 1) at `b`, (1, 0) at `c` and (0, 0) at `d`.
    pub fn push_quad(&mut self, corners: [Vec3; 4], material: u32) {
        let uv = [
            Vec2::new(0.0, 1.0),
            Vec2::new(1.0, 1.0),
            Vec2::new(1.0, 0.0),
            Vec2::new(0.0, 0.0),
        ];
        self.push_mesh(&corners, None, Some(&uv), None, &[[0, 1, 2], [0, 2, 3]], material);
    }

    /// Axis-aligned bounds `(min, max)` of all vertices.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.positions.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), p| (lo.min(*p), hi.max(*p)),
        )
    }
}

/// Everything the tracer needs to render.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Name (`builtin:cornell`, or the file).
    pub name: String,
    /// Triangles.
    pub geometry: Geometry,
    /// Materials.
    pub materials: Vec<Material>,
    /// Textures.
    pub textures: Vec<Texture>,
    /// Environment map, if any (none: black background).
    pub environment: Option<Environment>,
    /// The scene's camera.
    pub camera: Camera,
    /// Preferred image size.
    pub film: (u32, u32),
    /// Camera path given by the scene, if any.
    pub camera_path: Option<CameraPathSpec>,
    /// Material features that were approximated while loading (reported once as a warning).
    pub approximations: Vec<String>,
}

impl Scene {
    /// Checks indices, finiteness and non-emptiness.
    pub fn validate(&self) -> Result<()> {
        let err = |message: String| Error::Scene {
            path: PathBuf::from(&self.name),
            message,
        };
        let g = &self.geometry;
        if g.triangles.is_empty() {
            return Err(err("the scene has no triangles".into()));
        }
        let n = g.positions.len();
        if g.normals.len() != n || g.uvs.len() != n || g.tangents.len() != n {
            return Err(err("vertex attribute arrays differ in length".into()));
        }
        if self.materials.len() > 1 << 24 {
            return Err(err(format!(
                "{} materials; at most 2^24 are supported",
                self.materials.len()
            )));
        }
        if n > u32::MAX as usize {
            return Err(err(format!("{n} vertices; at most 2^32 - 1 are supported")));
        }
        if g.materials.len() != g.triangles.len() {
            return Err(err("one material index per triangle is needed".into()));
        }
        if let Some(t) = g.triangles.iter().find(|t| t.iter().any(|&i| i as usize >= n)) {
            return Err(err(format!("triangle {t:?} indexes past the {n} vertices")));
        }
        if let Some(m) = g.materials.iter().find(|&&m| m as usize >= self.materials.len()) {
            return Err(err(format!(
                "material index {m} out of {} materials",
                self.materials.len()
            )));
        }
        if let Some(p) = g.positions.iter().find(|p| !p.is_finite()) {
            return Err(err(format!("non-finite vertex position {p}")));
        }
        for m in &self.materials {
            for t in [
                m.base_color_texture,
                m.metallic_roughness_texture,
                m.normal_texture,
                m.emissive_texture,
            ]
            .into_iter()
            .flatten()
            {
                if t as usize >= self.textures.len() {
                    return Err(err(format!("material '{}' uses missing texture {t}", m.name)));
                }
            }
        }
        for t in &self.textures {
            if t.width == 0 || t.height == 0 || t.texels.len() != (t.width * t.height) as usize {
                return Err(err(format!("texture '{}' has an inconsistent size", t.name)));
            }
        }
        if let Some(e) = &self.environment
            && (e.width == 0 || e.height == 0 || e.pixels.len() != (e.width * e.height) as usize)
        {
            return Err(err(format!(
                "environment {} has an inconsistent size",
                e.source.display()
            )));
        }
        Ok(())
    }

    /// Scene bounds `(min, max)`.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.geometry.bounds()
    }

    /// Background lookups per pixel axis for this scene's frames by default
    /// ([`super::settings::DEFAULT_BACKGROUND`] with an environment, none without: a
    /// closed scene shows no sky).
    pub fn default_background(&self) -> u32 {
        if self.environment.is_some() {
            super::settings::DEFAULT_BACKGROUND
        } else {
            0
        }
    }

    /// Distance used to normalise view depth for camera positions `eyes`: the farthest
    /// distance from any of them to the scene's bounding sphere's far side.
    pub fn far_distance<'a>(&self, eyes: impl IntoIterator<Item = &'a Vec3>) -> f32 {
        let (lo, hi) = self.bounds();
        let centre = 0.5 * (lo + hi);
        let radius = 0.5 * (hi - lo).length();
        let far = eyes
            .into_iter()
            .map(|e| e.distance(centre) + radius)
            .fold(radius.max(1e-6), f32::max);
        far.max(1e-6)
    }

    /// The camera path `spec` from the scene's camera, checked against its geometry
    /// (`probe`: the CPU BVH, e.g. of its [`super::PackedScene`], before any upload), and
    /// the [`Scene::far_distance`] covering the scene camera and the path's first
    /// `horizon.max(frames)` eyes. An error names the scene and what is wrong with the path.
    pub fn camera_path(
        &self,
        spec: &CameraPathSpec,
        seed: u64,
        frames: u32,
        horizon: u32,
        probe: &dyn RayProbe,
    ) -> Result<(CameraPath, f32)> {
        let path = CameraPath::checked(spec, &self.camera, seed, frames, probe)
            .map_err(|e| Error::Invalid(format!("scene {}: {e}", self.name)))?;
        let eyes: Vec<Vec3> = (0..horizon.max(frames))
            .map(|f| path.camera(f).position)
            .collect();
        let far = self.far_distance(eyes.iter().chain([&self.camera.position]));
        Ok((path, far))
    }

    /// Logs the approximations made while loading, as one warning.
    pub fn warn_approximations(&self) {
        if !self.approximations.is_empty() {
            log::warn!(
                "{}: approximated material features: {}",
                self.name,
                self.approximations.join("; ")
            );
        }
    }
}
