//! Twin of `wgsl/trace/lib/material.wgsl`: bilinear texture lookups with wrap modes over the
//! packed RGBA8 texels, alpha cut-outs, emission, and the shading point of a hit.

use glam::{Vec2, Vec3A as Vec3, Vec4};

use super::common::{Hit, finite3};
use crate::render::packed::{
    GpuMaterial, MAT_THIN, NO_TEX, PackedScene, TRI_FLAG_HAS_TANGENT, TRI_FLAG_TANGENT_NEG, TRI_MATERIAL_MASK,
};
use crate::render::scene::SRGB_BYTE_TO_LINEAR;

const TEX_SRGB: u32 = 1;
const WRAP_CLAMP: u32 = 1;
const WRAP_MIRROR: u32 = 2;

fn wrap_coord(i: i32, n: i32, mode: u32) -> i32 {
    if mode == WRAP_CLAMP {
        return i.clamp(0, n - 1);
    }
    if mode == WRAP_MIRROR {
        let period = 2 * n;
        let m = i.rem_euclid(period);
        return if m >= n { period - 1 - m } else { m };
    }
    i.rem_euclid(n)
}

#[inline]
fn unpack(c: u32) -> Vec4 {
    Vec4::new(
        (c & 0xff) as f32,
        ((c >> 8) & 0xff) as f32,
        ((c >> 16) & 0xff) as f32,
        (c >> 24) as f32,
    ) / 255.0
}

#[inline]
fn texel(sc: &PackedScene, offset: u32, w: i32, x: i32, y: i32, srgb: bool) -> Vec4 {
    let c = sc.texels[(offset + (y * w + x) as u32) as usize];
    if srgb {
        let lut = &*SRGB_BYTE_TO_LINEAR;
        let ch = |k: u32| lut[((c >> k) & 0xff) as usize];
        Vec4::new(ch(0), ch(8), ch(16), (c >> 24) as f32 / 255.0)
    } else {
        unpack(c)
    }
}

/// Bilinear lookup of texture `tex` at `uv` (glTF convention), as `tex_sample` in WGSL.
pub(crate) fn tex_sample(sc: &PackedScene, tex: u32, uv: Vec2) -> Vec4 {
    let t4 = 4 * tex as usize;
    let offset = sc.texels[t4];
    let w = sc.texels[t4 + 1] as i32;
    let h = sc.texels[t4 + 2] as i32;
    let flags = sc.texels[t4 + 3];
    let srgb = flags & TEX_SRGB != 0;
    let ws = (flags >> 1) & 3;
    let wt = (flags >> 3) & 3;
    let ok = |v: f32| v.abs() <= 1.0e6;
    let uvs = Vec2::new(
        if ok(uv.x) { uv.x } else { 0.0 },
        if ok(uv.y) { uv.y } else { 0.0 },
    );
    let s = uvs * Vec2::new(w as f32, h as f32) - 0.5;
    let f = s.floor();
    let t = s - f;
    let x0 = wrap_coord(f.x as i32, w, ws);
    let x1 = wrap_coord(f.x as i32 + 1, w, ws);
    let y0 = wrap_coord(f.y as i32, h, wt);
    let y1 = wrap_coord(f.y as i32 + 1, h, wt);
    let a = texel(sc, offset, w, x0, y0, srgb);
    let b = texel(sc, offset, w, x1, y0, srgb);
    let c = texel(sc, offset, w, x0, y1, srgb);
    let d = texel(sc, offset, w, x1, y1, srgb);
    a.lerp(b, t.x).lerp(c.lerp(d, t.x), t.y)
}

/// Vertex indices and material word of triangle `prim` (BVH order).
#[inline]
pub(crate) fn tri_info(sc: &PackedScene, prim: u32) -> [u32; 4] {
    sc.tris[4 * prim as usize + 3].map(f32::to_bits)
}

#[inline]
pub(crate) fn tri_vec(sc: &PackedScene, prim: u32, k: usize) -> Vec3 {
    let v = sc.tris[4 * prim as usize + k];
    Vec3::new(v[0], v[1], v[2])
}

#[inline]
fn vert_uv(sc: &PackedScene, i: u32) -> Vec2 {
    Vec2::new(sc.verts[2 * i as usize][3], sc.verts[2 * i as usize + 1][3])
}

pub(crate) fn interp_uv(sc: &PackedScene, info: [u32; 4], u: f32, v: f32) -> Vec2 {
    vert_uv(sc, info[0]) * (1.0 - u - v) + vert_uv(sc, info[1]) * u + vert_uv(sc, info[2]) * v
}

#[inline]
pub(crate) fn material_of(sc: &PackedScene, info: [u32; 4]) -> &GpuMaterial {
    &sc.materials[(info[3] & TRI_MATERIAL_MASK) as usize]
}

/// The material's alpha at barycentrics (u, v) of `prim` reaches its cutoff.
pub(crate) fn alpha_passes(sc: &PackedScene, prim: u32, u: f32, v: f32) -> bool {
    let info = tri_info(sc, prim);
    let m = material_of(sc, info);
    let mut a = m.base_color[3];
    if m.textures[0] != NO_TEX {
        a *= tex_sample(sc, m.textures[0], interp_uv(sc, info, u, v)).w;
    }
    a >= m.extra[0]
}

/// Emitted radiance of `m` at `uv` (front side only is the caller's business).
pub(crate) fn material_emission(sc: &PackedScene, m: &GpuMaterial, uv: Vec2) -> Vec3 {
    let mut e = Vec3::new(m.emissive[0], m.emissive[1], m.emissive[2]);
    if m.textures[3] != NO_TEX && e.cmpgt(Vec3::ZERO).any() {
        e *= Vec3::from_vec4(tex_sample(sc, m.textures[3], uv));
    }
    e
}

/// A shading point (WGSL `Surface`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Surface {
    pub p: Vec3,
    /// Geometric normal, on the side of the incoming ray.
    pub ng: Vec3,
    /// Shading normal (interpolated, normal-mapped), same side as `ng`.
    pub ns: Vec3,
    /// The ray hit the front (counter-clockwise) face.
    pub front: bool,
    pub prim: u32,
    pub flags: u32,
    pub base: Vec3,
    pub metallic: f32,
    pub roughness: f32,
    pub transmission: f32,
    pub ior: f32,
    pub specular: f32,
    /// Emitted radiance towards the ray origin (0 off the front face).
    pub emission: Vec3,
    pub attenuation: Vec4,
}

impl Surface {
    /// Thin-walled transmission.
    pub fn thin(&self) -> bool {
        self.flags & MAT_THIN != 0
    }
}

/// The shading point of hit `h` of a ray with direction `d` (WGSL `surface_at`).
pub(crate) fn surface_at(sc: &PackedScene, h: &Hit, d: Vec3) -> Surface {
    let prim = h.prim;
    let info = tri_info(sc, prim);
    let v0 = tri_vec(sc, prim, 0);
    let e1 = tri_vec(sc, prim, 1);
    let e2 = tri_vec(sc, prim, 2);
    let w0 = 1.0 - h.u - h.v;
    let p = v0 - e1 * h.u + e2 * h.v;
    let ng_ccw = (-e1.cross(e2)).normalize();
    let front = ng_ccw.dot(d) < 0.0;
    let m = material_of(sc, info);
    let flags = m.extra[3].to_bits();

    let a = |i: u32| Vec4::from(sc.verts[2 * i as usize]);
    let b = |i: u32| Vec4::from(sc.verts[2 * i as usize + 1]);
    let (a0, a1, a2) = (a(info[0]), a(info[1]), a(info[2]));
    let (b0, b1, b2) = (b(info[0]), b(info[1]), b(info[2]));
    let uv0 = Vec2::new(a0.w, b0.w);
    let uv1 = Vec2::new(a1.w, b1.w);
    let uv2 = Vec2::new(a2.w, b2.w);
    let uv = uv0 * w0 + uv1 * h.u + uv2 * h.v;
    let mut n = Vec3::from_vec4(a0) * w0 + Vec3::from_vec4(a1) * h.u + Vec3::from_vec4(a2) * h.v;
    if !(n.dot(n) > 1.0e-12) || !finite3(n) {
        n = ng_ccw;
    }
    n = n.normalize();
    if n.dot(ng_ccw) < 0.0 {
        n = -n;
    }

    let mut base = Vec3::new(m.base_color[0], m.base_color[1], m.base_color[2]);
    if m.textures[0] != NO_TEX {
        base *= Vec3::from_vec4(tex_sample(sc, m.textures[0], uv));
    }
    let mut metallic = m.pbr[0];
    let mut roughness = m.pbr[1];
    if m.textures[1] != NO_TEX {
        let mr = tex_sample(sc, m.textures[1], uv);
        roughness *= mr.y;
        metallic *= mr.z;
    }
    if m.textures[2] != NO_TEX {
        let mut t;
        let bsign;
        if info[3] & TRI_FLAG_HAS_TANGENT != 0 {
            t = Vec3::from_vec4(b0) * w0 + Vec3::from_vec4(b1) * h.u + Vec3::from_vec4(b2) * h.v;
            bsign = if info[3] & TRI_FLAG_TANGENT_NEG != 0 {
                -1.0
            } else {
                1.0
            };
        } else {
            let dp1 = -e1;
            let dp2 = e2;
            let duv1 = uv1 - uv0;
            let duv2 = uv2 - uv0;
            let det = duv1.x * duv2.y - duv1.y * duv2.x;
            let r = if det.abs() < 1.0e-20 { 0.0 } else { 1.0 / det };
            t = (dp1 * duv2.y - dp2 * duv1.y) * r;
            let bt = (dp2 * duv1.x - dp1 * duv2.x) * r;
            bsign = if n.cross(t).dot(bt) < 0.0 { -1.0 } else { 1.0 };
        }
        t -= n * n.dot(t);
        if t.dot(t) > 1.0e-20 && finite3(t) {
            t = t.normalize();
            let bt = n.cross(t) * bsign;
            let tn = Vec3::from_vec4(tex_sample(sc, m.textures[2], uv)) * 2.0 - 1.0;
            let tn = Vec3::new(tn.x * m.extra[1], tn.y * m.extra[1], tn.z);
            let mapped = t * tn.x + bt * tn.y + n * tn.z;
            if mapped.dot(mapped) > 1.0e-12 && mapped.dot(ng_ccw) > 0.0 {
                n = mapped.normalize();
            }
        }
    }
    let emission = if front {
        material_emission(sc, m, uv)
    } else {
        Vec3::ZERO
    };
    Surface {
        p,
        ng: if front { ng_ccw } else { -ng_ccw },
        ns: if front { n } else { -n },
        front,
        prim,
        flags,
        base,
        metallic: metallic.clamp(0.0, 1.0),
        roughness: roughness.clamp(0.0, 1.0),
        transmission: m.pbr[2].clamp(0.0, 1.0),
        ior: m.pbr[3].max(1.0001),
        specular: m.extra[2],
        emission,
        attenuation: Vec4::from(m.attenuation),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_modes() {
        assert_eq!(wrap_coord(-1, 4, 0), 3);
        assert_eq!(wrap_coord(5, 4, 0), 1);
        assert_eq!(wrap_coord(-3, 4, WRAP_CLAMP), 0);
        assert_eq!(wrap_coord(9, 4, WRAP_CLAMP), 3);
        // Mirror: 0 1 2 3 3 2 1 0 | 0 1 ...
        assert_eq!(wrap_coord(4, 4, WRAP_MIRROR), 3);
        assert_eq!(wrap_coord(7, 4, WRAP_MIRROR), 0);
        assert_eq!(wrap_coord(-1, 4, WRAP_MIRROR), 0);
    }

    #[test]
    fn unpack_is_little_endian_rgba() {
        let c = unpack(u32::from_le_bytes([255, 0, 51, 102]));
        assert_eq!(c, Vec4::new(1.0, 0.0, 0.2, 0.4));
    }

    /// The sRGB lookup gives the decode of the unpacked byte to the bit, for every byte.
    #[test]
    fn srgb_lookup_is_the_decode() {
        for b in 0..=255u32 {
            let want = crate::render::scene::srgb_decode(unpack(b).x);
            assert_eq!(
                SRGB_BYTE_TO_LINEAR[b as usize].to_bits(),
                want.to_bits(),
                "byte {b}"
            );
        }
    }
}
