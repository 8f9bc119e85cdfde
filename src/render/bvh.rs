//! The scene BVH: an obvhs compressed wide BVH (CWBVH, PLOC, medium preset) built on the
//! CPU over world-space triangles, checked against the GPU traversal stack.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use glam::{Vec3, Vec3A};
use obvhs::cwbvh::CwBvh;
use obvhs::ray::{Ray, RayHit};
use obvhs::triangle::Triangle;

use super::wide_bvh::WideBvh;
use crate::error::{Error, Result};

/// Entries of the per-ray traversal stack in `wgsl/trace/lib/bvh.wgsl` (`STACK_SIZE`). A
/// tree of depth d needs at most d - 1 entries; deeper trees are refused.
pub const STACK_SIZE: u32 = 32;

/// A built BVH and the triangle order of its leaves.
pub struct SceneBvh {
    /// The obvhs CWBVH.
    pub bvh: CwBvh,
    /// For each leaf slot (BVH order), the index of the scene triangle it holds.
    pub order: Vec<u32>,
    /// Triangles in BVH order (what the GPU gets, as f32).
    pub triangles: Vec<Triangle>,
    /// Depth in nodes of the deepest leaf (the root alone is depth 1).
    pub depth: u32,
    /// Wall time of the build.
    pub build_time: Duration,
    /// Zero-area or non-finite triangles left out of the tree.
    pub skipped_degenerate: usize,
    /// The same tree laid out for the CPU twin's traversal (its quantised bounds converted
    /// to floats once, in lanes).
    pub wide: WideBvh,
}

impl std::fmt::Debug for SceneBvh {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SceneBvh")
            .field("nodes", &self.bvh.nodes.len())
            .field("triangles", &self.triangles.len())
            .field("depth", &self.depth)
            .finish()
    }
}

/// Depth (in nodes) of the deepest path of `bvh`; 0 for an empty tree.
pub fn cwbvh_depth(bvh: &CwBvh) -> u32 {
    if bvh.nodes.is_empty() {
        return 0;
    }
    let mut max = 0;
    let mut stack = vec![(0u32, 1u32)];
    while let Some((i, d)) = stack.pop() {
        max = max.max(d);
        let n = &bvh.nodes[i as usize];
        for slot in 0..8u32 {
            if n.imask & (1 << slot) != 0 {
                let rel = (n.imask as u32 & ((1u32 << slot) - 1)).count_ones();
                stack.push((n.child_base_idx + rel, d + 1));
            }
        }
    }
    max
}

impl crate::render::camera::RayProbe for SceneBvh {
    fn first_hit(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<f32> {
        self.intersect(origin, dir, tmax).map(|(_, t)| t)
    }
}

impl SceneBvh {
    /// Builds the CWBVH of triangles `tris` (vertex positions by index) of scene `name`.
    /// Degenerate triangles (zero area, non-finite) are left out; none left, or a tree too
    /// deep for the GPU stack, is an error.
    pub fn build(name: &str, positions: &[Vec3], tris: &[[u32; 3]]) -> Result<Self> {
        let err = |message: String| Error::Scene {
            path: PathBuf::from(name),
            message,
        };
        let mut kept = Vec::with_capacity(tris.len());
        let mut input = Vec::with_capacity(tris.len());
        for (i, t) in tris.iter().enumerate() {
            let [a, b, c] = t.map(|k| positions[k as usize]);
            let area2 = (b - a).cross(c - a).length();
            if !(area2 > 0.0 && area2.is_finite()) {
                continue;
            }
            kept.push(i as u32);
            input.push(Triangle {
                v0: Vec3A::from(a),
                v1: Vec3A::from(b),
                v2: Vec3A::from(c),
            });
        }
        if input.is_empty() {
            return Err(err(if tris.is_empty() {
                "the scene has no triangles".into()
            } else {
                format!("all {} triangles are degenerate (zero area)", tris.len())
            }));
        }
        let start = Instant::now();
        let mut core_time = Duration::ZERO;
        let bvh = obvhs::cwbvh::builder::build_cwbvh_from_tris(
            &input,
            obvhs::BvhBuildParams::medium_build(),
            &mut core_time,
        );
        let build_time = start.elapsed();
        if bvh.nodes.is_empty() {
            return Err(err("the BVH build produced no nodes".into()));
        }
        let depth = cwbvh_depth(&bvh);
        if depth > STACK_SIZE {
            return Err(err(format!(
                "the BVH is {depth} levels deep, more than the GPU traversal stack of {STACK_SIZE} \
                 holds (many coincident or overlapping triangles?)"
            )));
        }
        let wide = WideBvh::new(&bvh);
        let order: Vec<u32> = bvh.primitive_indices.iter().map(|&p| kept[p as usize]).collect();
        let triangles: Vec<Triangle> = bvh.primitive_indices.iter().map(|&p| input[p as usize]).collect();
        let n = input.len();
        log::info!(
            "{name}: CWBVH of {n} triangles in {:.1} ms ({:.2} Mtri/s), {} nodes, depth {depth}{}",
            build_time.as_secs_f64() * 1e3,
            n as f64 / build_time.as_secs_f64().max(1e-9) / 1e6,
            bvh.nodes.len(),
            if tris.len() > n {
                format!(", {} degenerate triangles skipped", tris.len() - n)
            } else {
                String::new()
            }
        );
        Ok(Self {
            bvh,
            order,
            triangles,
            depth,
            build_time,
            skipped_degenerate: tris.len() - n,
            wide,
        })
    }

    /// Closest hit on the CPU (obvhs traversal, `Triangle::intersect`): `(BVH slot, t)`.
    pub fn intersect(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<(u32, f32)> {
        let ray = ray(origin.into(), dir.into(), tmax);
        let mut hit = RayHit::none();
        if self
            .bvh
            .ray_traverse(ray, &mut hit, |r, id| self.triangles[id].intersect(r))
        {
            Some((hit.primitive_id, hit.t))
        } else {
            None
        }
    }

    /// Whether anything is hit within `tmax` on the CPU.
    pub fn occluded(&self, origin: Vec3, dir: Vec3, tmax: f32) -> bool {
        let ray = ray(origin.into(), dir.into(), tmax);
        !self
            .bvh
            .ray_traverse_miss(ray, |r, id| self.triangles[id].intersect(r))
    }
}

/// The obvhs ray from `origin` along `dir` for `t` in `[0, tmax]`, with `dir`'s negative
/// zeros made positive: obvhs takes the ray's octant from `d < 0` but a zero component's
/// reciprocal from its sign bit, and a ray with a -0.0 component then misses every box whose
/// slab holds it (`-Vec3::Z` straight down through a floor). The WGSL traversal's `safe_rcp`
/// reads such a zero as +0.0 likewise.
#[inline]
pub(crate) fn ray(origin: glam::Vec3A, dir: glam::Vec3A, tmax: f32) -> Ray {
    Ray::new(origin, dir + glam::Vec3A::ZERO, 0.0, tmax)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_and_degenerate_scenes_are_errors() {
        let e = SceneBvh::build("empty.glb", &[], &[]).unwrap_err().to_string();
        assert!(e.contains("empty.glb") && e.contains("no triangles"), "{e}");
        let p = [Vec3::ZERO, Vec3::X, Vec3::X * 2.0];
        let e = SceneBvh::build("flat.glb", &p, &[[0, 1, 2], [0, 0, 1]])
            .unwrap_err()
            .to_string();
        assert!(e.contains("flat.glb") && e.contains("degenerate"), "{e}");
    }

    #[test]
    fn coincident_triangles_are_too_deep() {
        let p = [Vec3::ZERO, Vec3::X, Vec3::Y];
        let tris = vec![[0u32, 1, 2]; 2000];
        let e = SceneBvh::build("stack.glb", &p, &tris).unwrap_err().to_string();
        assert!(e.contains("stack.glb") && e.contains("deep"), "{e}");
    }

    #[test]
    fn leaf_order_maps_back_to_scene_triangles() {
        let mut p = Vec::new();
        let mut t = Vec::new();
        for i in 0..50u32 {
            let o = Vec3::new(i as f32, (i % 7) as f32, 0.0);
            p.extend([o, o + Vec3::X * 0.5, o + Vec3::Y * 0.5]);
            t.push([3 * i, 3 * i + 1, 3 * i + 2]);
        }
        t.push([0, 0, 0]); // degenerate, skipped
        let b = SceneBvh::build("grid", &p, &t).unwrap();
        assert_eq!(b.skipped_degenerate, 1);
        assert_eq!(b.order.len(), 50);
        for (slot, &orig) in b.order.iter().enumerate() {
            assert_eq!(Vec3::from(b.triangles[slot].v0), p[t[orig as usize][0] as usize]);
        }
        let (slot, tt) = b
            .intersect(Vec3::new(3.1, 3.1, 5.0), Vec3::NEG_Z, f32::INFINITY)
            .unwrap();
        assert_eq!(b.order[slot as usize], 3);
        assert!((tt - 5.0).abs() < 1e-5);
    }
}
