//! Twin of `wgsl/trace/lib/bvh.wgsl` over obvhs's own CPU CWBVH traversal: closest and any
//! hit, the triangle a ray leaves from skipped, alpha-masked triangles tested against their
//! material's cutoff, and the same Moeller-Trumbore test as the GPU.

use glam::Vec3A as Vec3;
use obvhs::ray::{Ray, RayHit};

use super::common::{BIG, Hit, NO_HIT};
use super::material::alpha_passes;
use crate::render::packed::{PackedScene, TRI_FLAG_ALPHA, TRI_FLAG_PASS};

/// `(t, u, v)` of the hit of triangle `prim` within `[tmin, tmax]`, as `intersect_tri`.
#[inline(always)]
pub(crate) fn intersect_tri(
    sc: &PackedScene,
    prim: u32,
    o: Vec3,
    d: Vec3,
    tmin: f32,
    tmax: f32,
) -> Option<(f32, f32, f32)> {
    let (t, u, v) = plane_hit(sc, prim, o, d)?;
    let w = 1.0 - u - v;
    if (u.to_bits() | v.to_bits() | w.to_bits()) & 0x8000_0000 != 0 {
        return None;
    }
    (t >= tmin && t <= tmax).then_some((t, u, v))
}

/// `(t, u, v)` where `o + t d` meets the plane of triangle `prim`, with the barycentric
/// weights of v1 and v2 (outside `[0, 1]` off the triangle); `None` parallel to it.
#[inline(always)]
pub(crate) fn plane_hit(sc: &PackedScene, prim: u32, o: Vec3, d: Vec3) -> Option<(f32, f32, f32)> {
    let t4 = &sc.tris[4 * prim as usize..4 * prim as usize + 3];
    let (v0, e1, e2) = (
        Vec3::from_slice(&t4[0][..3]),
        Vec3::from_slice(&t4[1][..3]),
        Vec3::from_slice(&t4[2][..3]),
    );
    // The packed normal e1 x e2 (computed once per triangle when packing).
    let n = Vec3::new(t4[0][3], t4[1][3], t4[2][3]);
    let c = v0 - o;
    let r = d.cross(c);
    let det = n.dot(d);
    if det == 0.0 {
        return None;
    }
    let inv_det = 1.0 / det;
    Some((n.dot(c) * inv_det, r.dot(e2) * inv_det, r.dot(e1) * inv_det))
}

/// Closest hit (or, with `any_hit`, any hit of a triangle that does not pass light straight
/// through: what blocks a shadow ray) along `o + t d` for `t` in `[0, tmax]`, ignoring
/// triangle `skip`. Counts one ray in `rays`.
pub(crate) fn traverse(
    sc: &PackedScene,
    o: Vec3,
    d: Vec3,
    tmax: f32,
    any_hit: bool,
    skip: u32,
    rays: &mut u64,
) -> Hit {
    *rays += 1;
    let mut best = Hit {
        t: tmax.min(BIG),
        prim: NO_HIT,
        u: 0.0,
        v: 0.0,
    };
    let bvh = &sc.bvh.bvh;
    if bvh.nodes.is_empty() {
        return best;
    }
    let ray = crate::render::bvh::ray(o, d, best.t);
    // The candidate test: the GPU's triangle test, then the skip and alpha rules. Passed by
    // value so that obvhs's traversal inlines it.
    let test = |r: &Ray, id: usize, best: &mut Hit| -> f32 {
        let prim = id as u32;
        if prim == skip {
            return f32::INFINITY;
        }
        let Some((t, u, v)) = intersect_tri(sc, prim, o, d, 0.0, r.tmax) else {
            return f32::INFINITY;
        };
        if t >= r.tmax {
            return f32::INFINITY;
        }
        let info = sc.tris[4 * id + 3][3].to_bits();
        if any_hit && info & TRI_FLAG_PASS != 0 {
            return f32::INFINITY;
        }
        if info & TRI_FLAG_ALPHA != 0 && !alpha_passes(sc, prim, u, v) {
            return f32::INFINITY;
        }
        *best = Hit { t, prim, u, v };
        t
    };
    if any_hit {
        bvh.ray_traverse_miss(ray, |r, id| test(r, id, &mut best));
    } else {
        let mut hit = RayHit::none();
        bvh.ray_traverse(ray, &mut hit, |r, id| test(r, id, &mut best));
    }
    best
}

/// Whether anything opaque (anything but surfaces that pass light straight through) blocks
/// the segment from `o` along unit `d` up to `dist`.
#[inline]
pub(crate) fn occluded(sc: &PackedScene, o: Vec3, d: Vec3, dist: f32, skip: u32, rays: &mut u64) -> bool {
    traverse(sc, o, d, dist, true, skip, rays).prim != NO_HIT
}
