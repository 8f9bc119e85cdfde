//! The scene's CWBVH laid out for CPU traversal: the same tree as the GPU's, each node's
//! eight child boxes decompressed to floats (slightly grown, so that rounding never loses a
//! hit) and stored lane by lane, so that one ray meets all eight children in a few vector
//! instructions instead of dequantising them per ray. Traversal is single-ray, front to back,
//! with a fixed-size uninitialised stack.
//!
//! The closest-hit result does not depend on the order in which leaves are met: the caller's
//! leaf test keeps the nearest hit and, at equal distance, the lower triangle index, so the
//! answer is the one a brute-force loop over every triangle gives (what the tests check).

use std::mem::MaybeUninit;

use glam::Vec3A;
use obvhs::cwbvh::CwBvh;

/// Marks a child reference as a leaf: bits 27-30 hold its triangle count, bits 0-26 its
/// first triangle (BVH order).
const LEAF: u32 = 1 << 31;
const COUNT_SHIFT: u32 = 27;
const FIRST_MASK: u32 = (1 << COUNT_SHIFT) - 1;
/// Most triangles a tree laid out this way may hold.
pub const MAX_TRIANGLES: usize = FIRST_MASK as usize + 1;
/// Entries of the traversal stack: a tree of depth d (at most [`crate::render::bvh::STACK_SIZE`]
/// levels, which the build checks) leaves at most 7 per level on it.
const STACK: usize = 7 * crate::render::bvh::STACK_SIZE as usize + 8;
/// Relative slack of a box's entry (scaled down) and exit (scaled up) distances: more than
/// the rounding of the slab arithmetic and of the triangle test's distance, so that neither
/// a ray through a box's boundary nor a hit on its face at the closest distance so far is
/// culled.
const NEAR_SLACK: f32 = 1.0 - 1.0 / (1 << 16) as f32;
const FAR_SLACK: f32 = 1.0 + 1.0 / (1 << 16) as f32;

/// The triangle test of a traversal.
pub trait TriangleTest {
    /// Tests triangle `tri` (BVH order) against the hit so far at distance `best`, which it
    /// lowers when it accepts a nearer hit; returns whether the traversal stops.
    fn test(&mut self, tri: u32, best: &mut f32) -> bool;
}

/// One node: its eight children's boxes (`lo`, `hi` per axis, one lane per child; an empty
/// child's box is inverted so that no ray meets it) and references (an inner child's node
/// index, or [`LEAF`] with a triangle range).
#[derive(Debug, Clone, Copy)]
#[repr(C, align(32))]
struct WideNode {
    lo: [[f32; 8]; 3],
    hi: [[f32; 8]; 3],
    child: [u32; 8],
}

/// The CPU layout of a scene's CWBVH (see the module documentation).
#[derive(Debug, Clone, Default)]
pub struct WideBvh {
    nodes: Vec<WideNode>,
}

/// A ray's per-traversal constants: origin, reciprocal direction (a zero component's
/// reciprocal is +inf) and the sign of each direction component.
#[derive(Debug, Clone, Copy)]
pub struct WideRay {
    o: [f32; 3],
    inv: [f32; 3],
    neg: [bool; 3],
}

impl WideRay {
    /// The ray from `o` along `d` (any length; negative zeros count as positive, as in the
    /// WGSL traversal's `safe_rcp`).
    #[inline(always)]
    pub fn new(o: Vec3A, d: Vec3A) -> Self {
        let d = d + Vec3A::ZERO;
        Self {
            o: o.to_array(),
            inv: (1.0 / d).to_array(),
            neg: [d.x < 0.0, d.y < 0.0, d.z < 0.0],
        }
    }
}

/// `a` where it is greater than `b`, else `b` (so a NaN `a` yields `b`: a slab that a ray
/// lying in its plane makes undefined leaves the interval as it was).
#[inline(always)]
fn max_keep(a: f32, b: f32) -> f32 {
    if a > b { a } else { b }
}

/// `a` where it is less than `b`, else `b` (a NaN `a` yields `b`).
#[inline(always)]
fn min_keep(a: f32, b: f32) -> f32 {
    if a < b { a } else { b }
}

/// `v` moved outward (down for `lo`, up for `hi`) by more than the rounding of the CWBVH's
/// dequantisation.
fn grow(v: f32, up: bool) -> f32 {
    let step = v.abs() * (1.0 / (1 << 19) as f32) + f32::MIN_POSITIVE;
    if up { v + step } else { v - step }
}

impl WideBvh {
    /// The layout of `bvh` (from obvhs's builder). `None` when it holds more than
    /// [`MAX_TRIANGLES`] triangles.
    pub fn new(bvh: &CwBvh) -> Option<Self> {
        if bvh.primitive_indices.len() > MAX_TRIANGLES {
            return None;
        }
        let nodes = bvh
            .nodes
            .iter()
            .map(|n| {
                let mut w = WideNode {
                    lo: [[f32::INFINITY; 8]; 3],
                    hi: [[f32::NEG_INFINITY; 8]; 3],
                    child: [0; 8],
                };
                for slot in 0..8 {
                    if n.is_child_empty(slot) {
                        continue;
                    }
                    let b = n.child_aabb(slot);
                    for a in 0..3 {
                        w.lo[a][slot] = grow(b.min[a], false);
                        w.hi[a][slot] = grow(b.max[a], true);
                    }
                    w.child[slot] = if n.is_leaf(slot) {
                        let (first, count) = n.child_primitives(slot);
                        LEAF | (count << COUNT_SHIFT) | first
                    } else {
                        n.child_node_index(slot)
                    };
                }
                w
            })
            .collect();
        Some(Self { nodes })
    }

    /// The children of `n` that `r` meets within `[0, tmax]` (a bit per slot), and their
    /// entry distances (less the slack).
    #[inline(always)]
    fn hit_children(n: &WideNode, r: &WideRay, tmax: f32, near: &mut [f32; 8]) -> u32 {
        let pick = |a: usize| {
            if r.neg[a] {
                (&n.hi[a], &n.lo[a])
            } else {
                (&n.lo[a], &n.hi[a])
            }
        };
        let ((nx, fx), (ny, fy), (nz, fz)) = (pick(0), pick(1), pick(2));
        let [ox, oy, oz] = r.o;
        let [ix, iy, iz] = r.inv;
        let mut hit = [false; 8];
        for i in 0..8 {
            let tn = max_keep(
                (nz[i] - oz) * iz,
                max_keep((ny[i] - oy) * iy, max_keep((nx[i] - ox) * ix, 0.0)),
            );
            let tf = min_keep(
                (fz[i] - oz) * iz,
                min_keep((fy[i] - oy) * iy, min_keep((fx[i] - ox) * ix, tmax)),
            );
            near[i] = tn * NEAR_SLACK;
            hit[i] = near[i] <= tf * FAR_SLACK;
        }
        let mut mask = 0;
        for (i, h) in hit.iter().enumerate() {
            mask |= (*h as u32) << i;
        }
        mask
    }

    /// Front-to-back closest-hit traversal of `r` within `[0, tmax]`: `test` sees each
    /// triangle whose box the ray enters nearer than the closest hit so far (or as near).
    /// Boxes farther than the closest distance are skipped; boxes at exactly that distance
    /// are not (the test breaks ties by triangle index).
    #[inline(always)]
    pub fn closest(&self, r: &WideRay, tmax: f32, test: &mut impl TriangleTest) {
        let mut best = tmax;
        self.dispatch::<false>(r, &mut best, test);
    }

    /// Any-hit traversal of `r` within `[0, tmax]`, in no particular order, until `test`
    /// asks to stop; whether it did.
    #[inline(always)]
    pub fn any(&self, r: &WideRay, tmax: f32, test: &mut impl TriangleTest) -> bool {
        let mut best = tmax;
        self.dispatch::<true>(r, &mut best, test)
    }

    /// [`Self::walk`] compiled for AVX2 (eight lanes in one register, the caller's test
    /// inlined into it) where the CPU has it. Only the instruction encoding differs: the
    /// arithmetic is the same IEEE operations, so the results are the same to the bit.
    #[inline(always)]
    fn dispatch<const ANY: bool>(&self, r: &WideRay, best: &mut f32, test: &mut impl TriangleTest) -> bool {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2.
            return unsafe { self.walk_avx2::<ANY>(r, best, test) };
        }
        self.walk::<ANY>(r, best, test)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn walk_avx2<const ANY: bool>(&self, r: &WideRay, best: &mut f32, test: &mut impl TriangleTest) -> bool {
        self.walk::<ANY>(r, best, test)
    }

    /// The traversal: `test` may lower `best` and stops it. With `ANY`, children are
    /// visited in slot order; otherwise nearest first, and postponed ones whose entry is
    /// beyond `best` are dropped.
    #[inline(always)]
    fn walk<const ANY: bool>(&self, r: &WideRay, best: &mut f32, test: &mut impl TriangleTest) -> bool {
        if self.nodes.is_empty() {
            return false;
        }
        let mut stack: [MaybeUninit<(u32, f32)>; STACK] = [const { MaybeUninit::uninit() }; STACK];
        let mut sp = 0usize;
        let mut near = [0.0f32; 8];
        let mut cur = 0u32;
        loop {
            if cur & LEAF == 0 {
                let n = &self.nodes[cur as usize];
                let mut mask = Self::hit_children(n, r, *best, &mut near);
                if mask != 0 {
                    if mask & (mask - 1) == 0 {
                        cur = n.child[mask.trailing_zeros() as usize];
                        continue;
                    }
                    if ANY {
                        // Postpone all but the first.
                        let first = mask.trailing_zeros() as usize;
                        mask &= mask - 1;
                        while mask != 0 {
                            let i = mask.trailing_zeros() as usize;
                            mask &= mask - 1;
                            stack[sp].write((n.child[i], near[i]));
                            sp += 1;
                        }
                        cur = n.child[first];
                        continue;
                    }
                    // Nearest first: order the hit children by entry distance, farthest
                    // pushed first, and go on with the nearest.
                    let mut order = [(0u32, 0.0f32); 8];
                    let mut k = 0;
                    while mask != 0 {
                        let i = mask.trailing_zeros() as usize;
                        mask &= mask - 1;
                        let e = (n.child[i], near[i]);
                        let mut j = k;
                        while j > 0 && order[j - 1].1 < e.1 {
                            order[j] = order[j - 1];
                            j -= 1;
                        }
                        order[j] = e;
                        k += 1;
                    }
                    for e in &order[..k - 1] {
                        stack[sp].write(*e);
                        sp += 1;
                    }
                    cur = order[k - 1].0;
                    continue;
                }
            } else {
                let first = cur & FIRST_MASK;
                let count = (cur & !LEAF) >> COUNT_SHIFT;
                for tri in first..first + count {
                    if test.test(tri, best) {
                        return true;
                    }
                }
            }
            // Next postponed child still in reach.
            loop {
                if sp == 0 {
                    return false;
                }
                sp -= 1;
                // SAFETY: entries below `sp` were written by the pushes above.
                let (c, tn) = unsafe { stack[sp].assume_init() };
                if ANY || tn <= *best {
                    cur = c;
                    break;
                }
            }
        }
    }
}
