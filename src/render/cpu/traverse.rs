//! Twin of `wgsl/trace/lib/bvh.wgsl` over the same CWBVH laid out for the CPU
//! ([`crate::render::wide_bvh`]): closest and any
//! hit, the triangle a ray leaves from skipped, alpha-masked triangles tested against their
//! material's cutoff, and the same Moeller-Trumbore test as the GPU.

use glam::Vec3A as Vec3;

use super::common::{BIG, Hit, NO_HIT};
use super::material::alpha_passes;
use crate::render::packed::{PackedScene, TRI_FLAG_ALPHA, TRI_FLAG_PASS};
use crate::render::wide_bvh::{TriangleTest, WideRay};

/// The Moeller-Trumbore terms of triangle `prim` for the ray `o + t d`, in the form obvhs's
/// `Triangle::intersect` and the WGSL `intersect_tri` use: the numerators of `t` and of the
/// barycentric weights `u`, `v` of v1 and v2, and their common denominator (zero parallel
/// to the plane).
#[inline(always)]
fn mt_terms(sc: &PackedScene, prim: u32, o: Vec3, d: Vec3) -> (f32, f32, f32, f32) {
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
    (n.dot(c), r.dot(e2), r.dot(e1), n.dot(d))
}

/// `(t, u, v)` of the hit of triangle `prim` within `[tmin, tmax]`, as `intersect_tri`.
/// Most misses are told by the signs of `u` and `v` before the division: a product's sign
/// is the exclusive or of its factors', so the result is the GPU's to the bit.
#[inline(always)]
pub(crate) fn intersect_tri(
    sc: &PackedScene,
    prim: u32,
    o: Vec3,
    d: Vec3,
    tmin: f32,
    tmax: f32,
) -> Option<(f32, f32, f32)> {
    const SIGN: u32 = 0x8000_0000;
    let (tn, un, vn, det) = mt_terms(sc, prim, o, d);
    if det == 0.0 {
        return None;
    }
    let ds = det.to_bits() & SIGN;
    if ((un.to_bits() ^ ds) | (vn.to_bits() ^ ds)) & SIGN != 0 {
        return None;
    }
    let inv_det = 1.0 / det;
    let (u, v) = (un * inv_det, vn * inv_det);
    let w = 1.0 - u - v;
    if (u.to_bits() | v.to_bits() | w.to_bits()) & SIGN != 0 {
        return None;
    }
    let t = tn * inv_det;
    (t >= tmin && t <= tmax).then_some((t, u, v))
}

/// `(t, u, v)` where `o + t d` meets the plane of triangle `prim`, with the barycentric
/// weights of v1 and v2 (outside `[0, 1]` off the triangle); `None` parallel to it.
#[inline(always)]
pub(crate) fn plane_hit(sc: &PackedScene, prim: u32, o: Vec3, d: Vec3) -> Option<(f32, f32, f32)> {
    let (tn, un, vn, det) = mt_terms(sc, prim, o, d);
    if det == 0.0 {
        return None;
    }
    let inv_det = 1.0 / det;
    Some((tn * inv_det, un * inv_det, vn * inv_det))
}

/// Closest hit (or, with `any_hit`, any hit of a triangle that does not pass light straight
/// through: what blocks a shadow ray) along `o + t d` for `t` in `[0, tmax)`, ignoring
/// triangle `skip`, over the scene's [`WideBvh`](crate::render::wide_bvh::WideBvh) in the GPU's
/// order (of hits at the same distance the first met wins, as on the GPU). Counts one ray
/// in `rays`.
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
    let limit = tmax.min(BIG);
    let ray = WideRay::new(o, d);
    let wide = &sc.bvh.wide;
    let mut test = Candidate {
        sc,
        o,
        d,
        any_hit,
        skip,
        best: Hit {
            t: limit,
            prim: NO_HIT,
            u: 0.0,
            v: 0.0,
        },
    };
    if any_hit {
        wide.any(&ray, limit, &mut test);
    } else {
        wide.closest(&ray, limit, &mut test);
    }
    test.best
}

/// The candidate test of [`traverse`]: the GPU's triangle test, then the skip and alpha
/// rules.
struct Candidate<'a> {
    sc: &'a PackedScene,
    o: Vec3,
    d: Vec3,
    any_hit: bool,
    skip: u32,
    /// The hit so far.
    best: Hit,
}

impl TriangleTest for Candidate<'_> {
    #[inline(always)]
    fn test(&mut self, prim: u32, best_t: &mut f32) -> bool {
        if self.accept(prim) {
            *best_t = self.best.t;
            return self.any_hit;
        }
        false
    }
}

impl Candidate<'_> {
    /// Whether triangle `prim` is hit nearer than the hit so far, and then it becomes the
    /// hit so far.
    #[inline(always)]
    fn accept(&mut self, prim: u32) -> bool {
        let Some((t, u, v)) = intersect_tri(self.sc, prim, self.o, self.d, 0.0, self.best.t) else {
            return false;
        };
        if !(t < self.best.t) || !self.admits(prim, u, v) {
            return false;
        }
        self.best = Hit { t, prim, u, v };
        true
    }

    /// The rules after the triangle test: not the skipped triangle, not a surface that
    /// passes light for a shadow ray, not cut out by its alpha at `(u, v)`.
    #[inline(always)]
    fn admits(&self, prim: u32, u: f32, v: f32) -> bool {
        let info = self.sc.tris[4 * prim as usize + 3][3].to_bits();
        prim != self.skip
            && !(self.any_hit && info & TRI_FLAG_PASS != 0)
            && (info & TRI_FLAG_ALPHA == 0 || alpha_passes(self.sc, prim, u, v))
    }
}

/// Whether anything opaque (anything but surfaces that pass light straight through) blocks
/// the segment from `o` along unit `d` up to `dist`.
#[inline]
pub(crate) fn occluded(sc: &PackedScene, o: Vec3, d: Vec3, dist: f32, skip: u32, rays: &mut u64) -> bool {
    traverse(sc, o, d, dist, true, skip, rays).prim != NO_HIT
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::cpu::common::Rng;
    use crate::render::load::load_scene;
    use obvhs::ray::RayHit;

    /// The twin's hit rules (skip, pass-through, alpha) for the ray `o + t d`, for the
    /// references below.
    fn rules(sc: &PackedScene, o: Vec3, d: Vec3, any_hit: bool, skip: u32) -> Candidate<'_> {
        let best = Hit {
            t: BIG,
            prim: NO_HIT,
            u: 0.0,
            v: 0.0,
        };
        Candidate {
            sc,
            o,
            d,
            any_hit,
            skip,
            best,
        }
    }

    /// The same rules over obvhs's own CWBVH traversal (what the twin used before the wide
    /// layout, in the GPU's order).
    fn obvhs_traverse(rules: &Candidate, tmax: f32) -> Hit {
        let (sc, o, d) = (rules.sc, rules.o, rules.d);
        let mut best = Hit {
            t: tmax.min(BIG),
            prim: NO_HIT,
            u: 0.0,
            v: 0.0,
        };
        let ray = crate::render::bvh::ray(o, d, best.t);
        let test = |r: &obvhs::ray::Ray, id: usize, best: &mut Hit| -> f32 {
            let prim = id as u32;
            let Some((t, u, v)) = intersect_tri(sc, prim, o, d, 0.0, r.tmax) else {
                return f32::INFINITY;
            };
            if t >= r.tmax || !rules.admits(prim, u, v) {
                return f32::INFINITY;
            }
            *best = Hit { t, prim, u, v };
            t
        };
        if rules.any_hit {
            sc.bvh.bvh.ray_traverse_miss(ray, |r, id| test(r, id, &mut best));
        } else {
            sc.bvh
                .bvh
                .ray_traverse(ray, &mut RayHit::none(), |r, id| test(r, id, &mut best));
        }
        best
    }

    /// The independent expectation: every triangle tested; the nearest accepted distance
    /// below `tmax` and every triangle hit there (several where the ray meets a shared edge).
    fn brute_force(rules: &Candidate, tmax: f32) -> (f32, Vec<u32>) {
        let (sc, o, d) = (rules.sc, rules.o, rules.d);
        let (mut best, mut at) = (tmax.min(BIG), Vec::new());
        for prim in 0..sc.bvh.triangles.len() as u32 {
            let Some((t, u, v)) = intersect_tri(sc, prim, o, d, 0.0, tmax.min(BIG)) else {
                continue;
            };
            if t >= tmax.min(BIG) || !rules.admits(prim, u, v) {
                continue;
            }
            if at.is_empty() || t < best {
                (best, at) = (t, vec![prim]);
            } else if t == best {
                at.push(prim);
            }
        }
        (best, at)
    }

    fn uniform_dir(rng: &mut Rng) -> Vec3 {
        let z = 1.0 - 2.0 * rng.next();
        let r = (1.0 - z * z).max(0.0).sqrt();
        let phi = std::f32::consts::TAU * rng.next();
        Vec3::new(r * phi.cos(), r * phi.sin(), z)
    }

    /// Rays from random points of the scene's bounds and from points on triangles (leaving
    /// them, as paths do), in random directions, along the axes (zero direction components)
    /// and through the midpoints of triangle edges (shared edges: ties): the closest hit is
    /// the very hit, to the bit, that obvhs's traversal in the GPU's order gives, and the
    /// brute-force nearest (one of the triangles at that distance) up to the rounding of the
    /// box tests, which both share (beyond 2e-4 of the origin, see `NODE_T_MIN`); any-hit
    /// agrees with both.
    #[test]
    fn wide_traversal_matches_obvhs_and_brute_force() {
        for name in [
            "builtin:cornell",
            "builtin:room",
            "builtin:procedural:3",
            "builtin:procedural:11",
        ] {
            let scene = load_scene(name).unwrap();
            let sc = PackedScene::new(&scene, u64::MAX).unwrap();
            let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
            for t in &sc.bvh.triangles {
                for v in [t.v0, t.v1, t.v2] {
                    lo = lo.min(v);
                    hi = hi.max(v);
                }
            }
            let n = sc.bvh.triangles.len() as u32;
            let mut rng = Rng(0x5eed ^ n);
            let (mut hits, mut ties, mut grazing) = (0, 0, 0);
            for k in 0..3000 {
                let (o, skip) = if k % 3 == 0 {
                    let prim = (rng.next() * n as f32) as u32 % n;
                    let t = &sc.bvh.triangles[prim as usize];
                    let (a, b) = (rng.next(), rng.next());
                    let (a, b) = if a + b > 1.0 { (1.0 - a, 1.0 - b) } else { (a, b) };
                    (t.v0 + a * (t.v1 - t.v0) + b * (t.v2 - t.v0), prim)
                } else {
                    (lo + (hi - lo) * rng.next3(), NO_HIT)
                };
                let d = match k % 10 {
                    1 => [Vec3::X, Vec3::NEG_X, Vec3::Y, Vec3::NEG_Y, Vec3::Z, Vec3::NEG_Z][k / 10 % 6],
                    2 | 5 | 8 => {
                        let t = &sc.bvh.triangles[(rng.next() * n as f32) as usize % n as usize];
                        let mid = [(t.v0 + t.v1) * 0.5, (t.v1 + t.v2) * 0.5, (t.v2 + t.v0) * 0.5][k % 3];
                        (mid - o).normalize_or(Vec3::Z)
                    }
                    _ => uniform_dir(&mut rng),
                };
                let tmax = if k % 4 == 0 {
                    (hi - lo).length() * rng.next()
                } else {
                    BIG
                };
                for any_hit in [false, true] {
                    let mut rays = 0;
                    let got = traverse(&sc, o, d, tmax, any_hit, skip, &mut rays);
                    let rules = rules(&sc, o, d, any_hit, skip);
                    let old = obvhs_traverse(&rules, tmax);
                    let (t_min, at) = brute_force(&rules, tmax);
                    assert_eq!(rays, 1);
                    let why = format!("{name} ray {k} from {o} along {d} (any hit: {any_hit})");
                    assert_eq!(got.prim != NO_HIT, old.prim != NO_HIT, "{why}: against obvhs");
                    // The brute force is the expectation for rays in random directions whose
                    // nearest hit is beyond NODE_T_MIN (1e-4: boxes a ray leaves within it are
                    // not entered, on the GPU as here). Rays through edges run along box
                    // faces, where the box tests' rounding (the GPU's too) may lose a hit:
                    // for them obvhs alone is the expectation.
                    let obvhs_only = matches!(k % 10, 2 | 5 | 8) || (!at.is_empty() && t_min < 2.0e-4);
                    if !obvhs_only {
                        assert_eq!(got.prim != NO_HIT, !at.is_empty(), "{why}");
                    }
                    if !any_hit {
                        assert_eq!(
                            (got.prim, got.t.to_bits(), got.u.to_bits(), got.v.to_bits()),
                            (old.prim, old.t.to_bits(), old.u.to_bits(), old.v.to_bits()),
                            "{why}: against obvhs"
                        );
                        if !at.is_empty() && !obvhs_only {
                            // The nearest up to the rounding of the box tests (as on the GPU,
                            // a ray through a box's very edge may miss it): within 1e-5 of it.
                            assert!(
                                got.t <= t_min * (1.0 + 1.0e-5),
                                "{why}: {} against {t_min}",
                                got.t
                            );
                            if got.t == t_min {
                                assert!(at.contains(&got.prim), "{why}: {} not among {at:?}", got.prim);
                            } else {
                                grazing += 1;
                            }
                        }
                        hits += !at.is_empty() as u32;
                        ties += (at.len() > 1) as u32;
                    }
                }
            }
            // Most rays hit something, and some meet two triangles at once: the comparison
            // is not vacuous and the order of ties is exercised.
            assert!(
                hits > 1500 && ties > 10 && grazing < 10,
                "{name}: {hits} hits of 3000 rays, {ties} ties, {grazing} nearest hits missed by an ulp"
            );
        }
    }
}
