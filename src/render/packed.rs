//! A scene packed into the flat arrays the path tracer reads (layouts in
//! `wgsl/trace/lib/common.wgsl` and `wgsl/trace/lib/lights.wgsl`): BVH nodes, triangles in
//! BVH order, vertex attributes, materials, texture headers and texels, the
//! emissive-triangle light list and the environment map with its sampling CDFs. The GPU
//! tracer uploads these arrays as they are ([`super::GpuScene`]); the CPU twin
//! ([`super::cpu`]) reads the very same arrays, so both backends render one representation.

use std::borrow::Cow;

use bytemuck::{Pod, Zeroable};
use glam::{Mat3, Vec3};

use super::bvh::SceneBvh;
use super::scene::{AlphaMode, Environment, Portal, Scene, Texture, luminance};
use crate::error::Result;

/// `Material` of the WGSL tracer (96 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, PartialEq)]
pub struct GpuMaterial {
    /// Base colour rgb, alpha.
    pub base_color: [f32; 4],
    /// Emission rgb (factor x strength), w = luminance used for light selection.
    pub emissive: [f32; 4],
    /// Metallic, perceptual roughness, transmission, ior.
    pub pbr: [f32; 4],
    /// Alpha cutoff, normal scale, specular factor, flags (u32 bits).
    pub extra: [f32; 4],
    /// Attenuation colour rgb, attenuation distance (0: none).
    pub attenuation: [f32; 4],
    /// Texture indices: base colour, metallic-roughness, normal, emissive (`u32::MAX`: none).
    pub textures: [u32; 4],
}

pub(crate) const NO_TEX: u32 = u32::MAX;
pub(crate) const MAT_DOUBLE_SIDED: u32 = 1;
pub(crate) const MAT_THIN: u32 = 2;
pub(crate) const MAT_ALPHA_MASK: u32 = 4;
/// Smooth thin-walled transmission: light goes straight through (a specular event), so NEE
/// shadow rays pass it, attenuated, and paths pass it without a scattering vertex
/// ([`straight_through`]).
pub(crate) const MAT_PASS: u32 = 8;
/// Roughness alpha floor of the GGX lobes (`ALPHA_MIN` in bsdf.wgsl): smoother surfaces
/// render as this one.
pub(crate) const GGX_ALPHA_MIN: f32 = 0.002;
pub(crate) const TRI_FLAG_ALPHA: u32 = 0x8000_0000;
pub(crate) const TRI_FLAG_TANGENT_NEG: u32 = 0x4000_0000;
pub(crate) const TRI_FLAG_HAS_TANGENT: u32 = 0x2000_0000;
/// The triangle's material is [`MAT_PASS`].
pub(crate) const TRI_FLAG_PASS: u32 = 0x1000_0000;
/// Bit of `lights[0].w` (over the portal count) set when some triangle is [`MAT_PASS`].
pub(crate) const LIGHTS_HAVE_PASS: u32 = 0x8000_0000;
pub(crate) const TRI_MATERIAL_MASK: u32 = 0x00ff_ffff;
/// Probability with which an environment light sample picks a point on a portal (when the
/// environment has any) rather than a direction from the map.
pub(crate) const PORTAL_PROBABILITY: f32 = 0.5;
/// Vec4s before the environment's marginal CDF (`ENV_HDR` in lights.wgsl).
pub(crate) const ENV_HDR: usize = 8;

/// The scene in the tracer's flat layout, on the host.
pub struct PackedScene {
    /// Scene name, for messages.
    pub name: String,
    /// The CWBVH (its nodes are the `bvh_nodes` array) and the leaf order.
    pub bvh: SceneBvh,
    /// Triangles in BVH order, 4 vec4 each (`tris`): v0, e1, e2 (w: the normal e1 x e2),
    /// vertex indices and material word.
    pub tris: Vec<[f32; 4]>,
    /// Vertex attributes, 2 vec4 each (`verts`).
    pub verts: Vec<[f32; 4]>,
    /// Materials (`materials`).
    pub materials: Vec<GpuMaterial>,
    /// Texture headers and RGBA8 texels (`texels`).
    pub texels: Vec<u32>,
    /// Emissive-triangle list, then the environment's portals (`lights`).
    pub lights: Vec<[f32; 4]>,
    /// Environment map and its CDFs (`env`).
    pub env: Vec<[f32; 4]>,
    /// Number of emissive triangles in the light list.
    pub emissive_triangles: u32,
    /// Probability with which NEE samples the environment.
    pub env_probability: f32,
    /// Scene bounds.
    pub bounds: (Vec3, Vec3),
    /// Adjustments made while packing (texture downscaling), also logged.
    pub adjustments: Vec<String>,
}

impl std::fmt::Debug for PackedScene {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PackedScene")
            .field("name", &self.name)
            .field("bvh", &self.bvh)
            .field("emissive_triangles", &self.emissive_triangles)
            .finish()
    }
}

/// Whether light goes straight through `m`: thin-walled transmission at the roughness floor
/// (a roughness texture could lift it off the floor, so none may be bound). The GGX lobe
/// there is so narrow that treating the transmission as a straight line changes the image
/// by less than the lobe's width, and NEE can then see lights through it.
pub(crate) fn straight_through(m: &super::scene::Material) -> bool {
    m.thin
        && m.transmission > 0.0
        && m.roughness * m.roughness <= GGX_ALPHA_MIN
        && m.metallic_roughness_texture.is_none()
}

/// Material table of `scene` in GPU layout.
pub fn gpu_materials(scene: &Scene) -> Vec<GpuMaterial> {
    scene
        .materials
        .iter()
        .map(|m| {
            let mut flags = 0;
            if m.double_sided {
                flags |= MAT_DOUBLE_SIDED;
            }
            if m.thin {
                flags |= MAT_THIN;
            }
            if straight_through(m) {
                flags |= MAT_PASS;
            }
            let cutoff = match m.alpha {
                AlphaMode::Opaque => 0.0,
                AlphaMode::Mask(c) => {
                    flags |= MAT_ALPHA_MASK;
                    c
                }
            };
            let tex = |t: Option<u32>| t.unwrap_or(NO_TEX);
            let att_dist = if m.attenuation_distance.is_finite() && m.attenuation_distance > 0.0 {
                m.attenuation_distance
            } else {
                0.0
            };
            GpuMaterial {
                base_color: m.base_color,
                emissive: [
                    m.emissive[0],
                    m.emissive[1],
                    m.emissive[2],
                    m.emitted_luminance(&scene.textures),
                ],
                pbr: [m.metallic, m.roughness, m.transmission, m.ior],
                extra: [cutoff, m.normal_scale, m.specular, f32::from_bits(flags)],
                attenuation: [
                    m.attenuation_color[0],
                    m.attenuation_color[1],
                    m.attenuation_color[2],
                    att_dist,
                ],
                textures: [
                    tex(m.base_color_texture),
                    tex(m.metallic_roughness_texture),
                    tex(m.normal_texture),
                    tex(m.emissive_texture),
                ],
            }
        })
        .collect()
}

/// Texture headers + texels; textures are halved (largest first) until they fit in
/// `budget_bytes`. Returns the words and the names of the downscaled textures.
pub fn pack_textures(textures: &[Texture], budget_bytes: u64) -> (Vec<u32>, Vec<String>) {
    let mut tex: Vec<Cow<Texture>> = textures.iter().map(Cow::Borrowed).collect();
    let header = 4 * tex.len() as u64;
    let mut halved = Vec::new();
    loop {
        let words: u64 = header + tex.iter().map(|t| t.texels.len() as u64).sum::<u64>();
        if words * 4 <= budget_bytes {
            break;
        }
        let (i, _) = tex
            .iter()
            .enumerate()
            .max_by_key(|(_, t)| t.texels.len())
            .expect("textures exceed the budget, so there is one");
        if tex[i].width == 1 && tex[i].height == 1 {
            break; // cannot shrink further; the upload will report the size
        }
        let name = tex[i].name.clone();
        tex[i] = Cow::Owned(tex[i].halved());
        if !halved.contains(&name) {
            halved.push(name);
        }
    }
    let mut words = Vec::with_capacity(header as usize);
    let mut offset = header as u32;
    for t in &tex {
        let flags = t.srgb as u32 | t.wrap[0].code() << 1 | t.wrap[1].code() << 3;
        words.extend([offset, t.width, t.height, flags]);
        offset += t.texels.len() as u32;
    }
    for t in &tex {
        words.extend(t.texels.iter().map(|c| u32::from_le_bytes(*c)));
    }
    (words, halved)
}

/// The environment buffer (layout in lights.wgsl); a 1x1 black placeholder when absent.
pub fn pack_environment(env: Option<&Environment>) -> Vec<[f32; 4]> {
    let Some(e) = env else {
        let mut v = vec![[0.0f32; 4]; ENV_HDR + 2];
        v[0] = [f32::from_bits(1), f32::from_bits(1), 1.0, f32::from_bits(0)];
        return v;
    };
    let (w, h) = (e.width as usize, e.height as usize);
    let px: Vec<Vec3> = e.pixels.iter().map(|p| Vec3::from(*p) * e.scale).collect();
    let mean_lum = px.iter().map(|c| luminance(*c).max(0.0) as f64).sum::<f64>() / px.len() as f64;
    // A small floor keeps every direction sampleable.
    let floor = (0.01 * mean_lum).max(1e-8) as f32;
    let mut weights = vec![0f64; w * h];
    for j in 0..h {
        let sin_t = (std::f64::consts::PI * (j as f64 + 0.5) / h as f64).sin();
        for i in 0..w {
            weights[j * w + i] = (luminance(px[j * w + i]).max(0.0) + floor) as f64 * sin_t;
        }
    }
    let total: f64 = weights.iter().sum();
    let mut out = vec![[0.0f32; 4]; ENV_HDR + h + w * h];
    out[0] = [
        f32::from_bits(w as u32),
        f32::from_bits(h as u32),
        total as f32,
        f32::from_bits(1),
    ];
    out[1] = [floor, 0.0, 0.0, 0.0];
    let w2e = e.to_world.inverse();
    let rows = |m: Mat3| [m.row(0), m.row(1), m.row(2)];
    for (k, r) in rows(w2e).iter().enumerate() {
        out[2 + k] = [r.x, r.y, r.z, 0.0];
    }
    for (k, r) in rows(e.to_world).iter().enumerate() {
        out[5 + k] = [r.x, r.y, r.z, 0.0];
    }
    let mut acc = 0f64;
    for j in 0..h {
        let row = &weights[j * w..(j + 1) * w];
        let row_sum: f64 = row.iter().sum();
        acc += row_sum;
        out[ENV_HDR + j] = [(acc / total) as f32, 0.0, 0.0, 0.0];
        let mut racc = 0f64;
        for i in 0..w {
            racc += row[i];
            let cdf = if row_sum > 0.0 {
                racc / row_sum
            } else {
                (i + 1) as f64 / w as f64
            };
            let c = px[j * w + i];
            out[ENV_HDR + h + j * w + i] = [c.x, c.y, c.z, cdf as f32];
        }
        out[ENV_HDR + h + j * w + w - 1][3] = 1.0;
    }
    out[ENV_HDR + h - 1][0] = 1.0;
    out
}

impl PackedScene {
    /// Builds the BVH of `scene` and packs everything; textures are halved (largest first)
    /// until they fit in `texture_budget_bytes` (`u64::MAX`: never).
    pub fn new(scene: &Scene, texture_budget_bytes: u64) -> Result<Self> {
        scene.validate()?;
        let name = scene.name.as_str();
        let g = &scene.geometry;
        let bvh = SceneBvh::build(name, &g.positions, &g.triangles)?;
        let mats = gpu_materials(scene);

        // Triangles in BVH order: v0, e1 = v0 - v1, e2 = v2 - v0 (their w components hold the
        // unnormalised normal e1 x e2, for the CPU twin's ray test), info.
        let mut tris: Vec<[f32; 4]> = Vec::with_capacity(4 * bvh.order.len());
        let mut lights: Vec<(u32, f64, f32)> = Vec::new(); // (slot, power, area)
        let mut any_pass = false;
        for (slot, &orig) in bvh.order.iter().enumerate() {
            let idx = g.triangles[orig as usize];
            let [v0, v1, v2] = idx.map(|i| g.positions[i as usize]);
            let (e1, e2) = (v0 - v1, v2 - v0);
            let mat = g.materials[orig as usize];
            let mut info = mat & TRI_MATERIAL_MASK;
            if matches!(scene.materials[mat as usize].alpha, AlphaMode::Mask(_)) {
                info |= TRI_FLAG_ALPHA;
            }
            if mats[mat as usize].extra[3].to_bits() & MAT_PASS != 0 {
                info |= TRI_FLAG_PASS;
                any_pass = true;
            }
            let tans = idx.map(|i| g.tangents[i as usize]);
            if tans.iter().all(|t| t.truncate().length_squared() > 0.0) {
                info |= TRI_FLAG_HAS_TANGENT;
                if tans[0].w < 0.0 {
                    info |= TRI_FLAG_TANGENT_NEG;
                }
            }
            let n = e1.cross(e2);
            tris.push([v0.x, v0.y, v0.z, n.x]);
            tris.push([e1.x, e1.y, e1.z, n.y]);
            tris.push([e2.x, e2.y, e2.z, n.z]);
            tris.push([idx[0], idx[1], idx[2], info].map(f32::from_bits));
            let lum = mats[mat as usize].emissive[3];
            if lum > 0.0 {
                let area = 0.5 * e1.cross(e2).length();
                if area > 0.0 {
                    lights.push((slot as u32, lum as f64 * area as f64, area));
                }
            }
        }
        let mut verts: Vec<[f32; 4]> = Vec::with_capacity(2 * g.positions.len());
        for i in 0..g.positions.len() {
            let (n, uv, t) = (g.normals[i], g.uvs[i], g.tangents[i]);
            verts.push([n.x, n.y, n.z, uv.x]);
            verts.push([t.x, t.y, t.z, uv.y]);
        }
        let total: f64 = lights.iter().map(|l| l.1).sum();
        let env_probability = match (scene.environment.is_some(), lights.is_empty()) {
            (true, true) => 1.0,
            (true, false) => 0.5,
            (false, _) => 0.0,
        };
        let portals: &[Portal] = match &scene.environment {
            Some(e) => &e.portals,
            None => &[],
        };
        let portals: Vec<&Portal> = portals
            .iter()
            .filter(|q| q.area() > 0.0 && q.area().is_finite())
            .collect();
        let mut light_buf = vec![[
            f32::from_bits(lights.len() as u32),
            total as f32,
            env_probability,
            f32::from_bits(portals.len() as u32 | if any_pass { LIGHTS_HAVE_PASS } else { 0 }),
        ]];
        let mut acc = 0.0f64;
        for (k, &(slot, power, area)) in lights.iter().enumerate() {
            acc += power;
            let cdf = if k + 1 == lights.len() {
                1.0
            } else {
                (acc / total) as f32
            };
            light_buf.push([f32::from_bits(slot), cdf, (power / total) as f32, area]);
        }
        // Portals after the triangles, 3 vec4 each (layout in lights.wgsl), picked by area.
        let portal_area: f64 = portals.iter().map(|q| q.area() as f64).sum();
        let mut acc = 0.0f64;
        for (k, q) in portals.iter().enumerate() {
            acc += q.area() as f64;
            let cdf = if k + 1 == portals.len() {
                1.0
            } else {
                (acc / portal_area) as f32
            };
            light_buf.push([q.corner.x, q.corner.y, q.corner.z, cdf]);
            light_buf.push([q.u.x, q.u.y, q.u.z, portal_area as f32]);
            light_buf.push([q.v.x, q.v.y, q.v.z, PORTAL_PROBABILITY]);
        }

        let (texels, halved) = pack_textures(&scene.textures, texture_budget_bytes);
        let mut adjustments = Vec::new();
        if !halved.is_empty() {
            let msg = format!(
                "{} texture(s) downscaled to fit a {} MiB texture budget: {}",
                halved.len(),
                texture_budget_bytes >> 20,
                halved.join(", ")
            );
            log::warn!("{name}: {msg}");
            adjustments.push(msg);
        }
        let env = pack_environment(scene.environment.as_ref());
        Ok(Self {
            name: scene.name.clone(),
            tris,
            verts,
            materials: mats,
            texels,
            lights: light_buf,
            env,
            emissive_triangles: lights.len() as u32,
            env_probability,
            bounds: g.bounds(),
            bvh,
            adjustments,
        })
    }

    /// Number of triangles in the BVH.
    pub fn triangle_count(&self) -> usize {
        self.bvh.triangles.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::scene::Wrap;

    #[test]
    fn textures_are_halved_to_fit() {
        let t = |n: &str, s: u32| Texture {
            name: n.into(),
            width: s,
            height: s,
            texels: vec![[255, 0, 0, 255]; (s * s) as usize],
            srgb: true,
            wrap: [Wrap::Repeat, Wrap::Clamp],
        };
        let tex = [t("big", 64), t("small", 8)];
        let (w, halved) = pack_textures(&tex, u64::MAX);
        assert!(halved.is_empty());
        assert_eq!(w.len(), 8 + 64 * 64 + 64);
        assert_eq!(&w[..8], &[8, 64, 64, 1 | 1 << 3, 8 + 4096, 8, 8, 1 | 1 << 3]);
        let (w, halved) = pack_textures(&tex, 4 * (8 + 32 * 32 + 64));
        assert_eq!(halved, vec!["big".to_string()]);
        assert_eq!(w[1], 32);
    }

    #[test]
    fn environment_cdfs_are_monotone_and_end_at_one() {
        let mut e = Environment::uniform([1.0, 2.0, 3.0]);
        e.pixels[5] = [100.0, 100.0, 100.0];
        let v = pack_environment(Some(&e));
        let (w, h) = (e.width as usize, e.height as usize);
        let mut last = 0.0;
        for j in 0..h {
            assert!(v[ENV_HDR + j][0] >= last);
            last = v[ENV_HDR + j][0];
            let mut r = 0.0;
            for i in 0..w {
                let c = v[ENV_HDR + h + j * w + i][3];
                assert!(c >= r);
                r = c;
            }
            assert_eq!(r, 1.0);
        }
        assert_eq!(last, 1.0);
    }
}
