//! The scene's CWBVH laid out for CPU traversal. It is the GPU's tree, traversed as the GPU
//! (`wgsl/trace/lib/bvh.wgsl`) and obvhs traverse it, with the same box arithmetic to the
//! bit, but each node's quantised child bounds are converted to floats once, when the scene
//! is packed, and stored lane by lane, instead of per ray and node (the conversion is what
//! obvhs's own SIMD node test spends most on); the triangle test is the caller's, inlined;
//! the stack is fixed-size and uninitialised.
//!
//! The order is the GPU's: at each node, the triangles of the leaves the ray meets, highest
//! index first, then the inner children in descending order of their slot exclusive-or the
//! ray's octant. So of two triangles hit at exactly the same distance (a ray through a shared
//! edge) the twin keeps the one the GPU keeps, the first met, and with the same random
//! numbers both backends trace the same paths. Postponed children whose boxes begin well
//! beyond the closest hit so far are dropped, which cannot change that hit.

use std::mem::MaybeUninit;

use glam::Vec3A;
use obvhs::cwbvh::CwBvh;

/// The `slot` of a leaf entry (or an empty one).
const LEAF: u8 = 0xff;
/// Entries of the traversal stack: a tree of depth d (at most [`crate::render::bvh::STACK_SIZE`]
/// levels, which the build checks) leaves at most 7 per level on it, and 8 at the last.
const STACK: usize = 7 * crate::render::bvh::STACK_SIZE as usize + 8;
/// Nearest entry distance of a box test (`NODE_T_MIN` in `wgsl/trace/lib/bvh.wgsl`, obvhs's
/// `EPSILON`): a box the ray leaves before it is not entered, on either backend.
const NODE_T_MIN: f32 = 1.0e-4;
/// A postponed child is dropped when its entry distance exceeds the closest hit by more
/// than this factor: far more than the rounding between a box's entry and that of the
/// boxes and triangles inside it.
const CULL_SLACK: f32 = 1.0 + 1.0 / (1 << 12) as f32;

/// What a traversal asks of its caller about each triangle it meets.
pub trait TriangleTest {
    /// Tests triangle `tri` (BVH order) against the hit so far at distance `best`, which it
    /// lowers when it accepts a nearer hit; returns whether the traversal stops.
    fn test(&mut self, tri: u32, best: &mut f32) -> bool;
}

/// One node: obvhs's quantised child bounds as floats (`q_lo`, `q_hi` per axis, one lane
/// per entry), its grid origin `p` and cell size `e`, and what its entries hold.
#[derive(Debug, Clone, Copy)]
#[repr(C, align(32))]
struct WideNode {
    q_lo: [[f32; 8]; 3],
    q_hi: [[f32; 8]; 3],
    p: Vec3A,
    e: Vec3A,
    /// An inner child's node index, or a leaf's triangles as bits: bit b for triangle
    /// `first + b` (obvhs's primitive hit bits).
    child: [u32; 8],
    /// An inner child's CWBVH slot (0-7), or [`LEAF`].
    slot: [u8; 8],
    /// The first triangle (BVH order) of the node's leaves.
    first: u32,
}

/// The CPU layout of a scene's CWBVH (see the module documentation).
#[derive(Debug, Clone)]
pub struct WideBvh {
    nodes: Vec<WideNode>,
}

/// A ray's per-traversal constants: origin, reciprocal direction (obvhs's `safe_inverse`,
/// the WGSL `safe_rcp`), the sign of each direction component and the ray's octant.
#[derive(Debug, Clone, Copy)]
pub struct WideRay {
    o: Vec3A,
    inv: Vec3A,
    neg: [bool; 3],
    /// The octant bits of obvhs's `ray_get_octant_inv4` (4 for x >= 0, 2 for y, 1 for z).
    oct: u8,
}

impl WideRay {
    /// The ray from `o` along `d` (negative zeros count as positive, as in the WGSL
    /// traversal).
    #[inline(always)]
    pub fn new(o: Vec3A, d: Vec3A) -> Self {
        let d = d + Vec3A::ZERO;
        let neg = [d.x < 0.0, d.y < 0.0, d.z < 0.0];
        Self {
            o,
            inv: Vec3A::from(d.to_array().map(obvhs::ray::safe_inverse)),
            neg,
            oct: (!neg[0] as u8) << 2 | (!neg[1] as u8) << 1 | !neg[2] as u8,
        }
    }
}

/// `max` as SSE's `maxps` (the second operand where either is NaN), as obvhs's node test.
#[inline(always)]
fn max_ps(a: f32, b: f32) -> f32 {
    if a > b { a } else { b }
}

/// `min` as SSE's `minps`.
#[inline(always)]
fn min_ps(a: f32, b: f32) -> f32 {
    if a < b { a } else { b }
}

impl WideBvh {
    /// The layout of `bvh` (from obvhs's builder).
    pub fn new(bvh: &CwBvh) -> Self {
        let nodes = bvh
            .nodes
            .iter()
            .map(|n| {
                let mut w = WideNode {
                    q_lo: [[0.0; 8]; 3],
                    q_hi: [[0.0; 8]; 3],
                    p: Vec3A::from(n.p),
                    e: n.compute_extent(),
                    child: [0; 8],
                    slot: [LEAF; 8],
                    first: n.primitive_base_idx,
                };
                for i in 0..8 {
                    let (lo, hi) = (
                        [n.child_min_x[i], n.child_min_y[i], n.child_min_z[i]],
                        [n.child_max_x[i], n.child_max_y[i], n.child_max_z[i]],
                    );
                    for a in 0..3 {
                        w.q_lo[a][i] = lo[a] as f32;
                        w.q_hi[a][i] = hi[a] as f32;
                    }
                    if n.is_child_empty(i) {
                        continue;
                    }
                    if n.is_leaf(i) {
                        let (first, count) = n.child_primitives(i);
                        w.child[i] = ((1u32 << count) - 1) << (first - n.primitive_base_idx);
                    } else {
                        w.child[i] = n.child_node_index(i);
                        w.slot[i] = (n.child_meta[i] & 0b11111) - 24;
                    }
                }
                w
            })
            .collect();
        Self { nodes }
    }

    /// The entries of `n` whose boxes `r` meets within `[NODE_T_MIN, tmax]` (a bit per
    /// entry), and their entry distances: obvhs's `intersect_ray_simd`, operation for
    /// operation.
    #[inline(always)]
    fn hit_children(n: &WideNode, r: &WideRay, tmax: f32, near: &mut [f32; 8]) -> u32 {
        let adj_inv = (n.e * r.inv).to_array();
        let adj_o = ((n.p - r.o) * r.inv).to_array();
        let pick = |a: usize| {
            if r.neg[a] {
                (&n.q_hi[a], &n.q_lo[a])
            } else {
                (&n.q_lo[a], &n.q_hi[a])
            }
        };
        let ((nx, fx), (ny, fy), (nz, fz)) = (pick(0), pick(1), pick(2));
        let mut hit = [false; 8];
        for i in 0..8 {
            let tmin = max_ps(
                nx[i] * adj_inv[0] + adj_o[0],
                max_ps(ny[i] * adj_inv[1] + adj_o[1], nz[i] * adj_inv[2] + adj_o[2]),
            );
            let tmax_i = min_ps(
                fx[i] * adj_inv[0] + adj_o[0],
                min_ps(fy[i] * adj_inv[1] + adj_o[1], fz[i] * adj_inv[2] + adj_o[2]),
            );
            let tmin = max_ps(tmin, NODE_T_MIN);
            let tmax_i = min_ps(tmax_i, tmax);
            near[i] = tmin;
            hit[i] = tmin <= tmax_i;
        }
        let mut mask = 0;
        for (i, h) in hit.iter().enumerate() {
            mask |= (*h as u32) << i;
        }
        mask
    }

    /// Closest-hit traversal of `r` within `[0, tmax]` in the GPU's order: `test` sees each
    /// triangle of the leaves whose boxes the ray meets within the closest hit so far.
    #[inline(always)]
    pub fn closest(&self, r: &WideRay, tmax: f32, test: &mut impl TriangleTest) {
        let mut best = tmax;
        self.dispatch::<false>(r, &mut best, test);
    }

    /// Any-hit traversal of `r` within `[0, tmax]`, until `test` asks to stop; whether it
    /// did.
    #[inline(always)]
    pub fn any(&self, r: &WideRay, tmax: f32, test: &mut impl TriangleTest) -> bool {
        let mut best = tmax;
        self.dispatch::<true>(r, &mut best, test)
    }

    /// [`Self::walk`] compiled for AVX2 (eight lanes in one register, the caller's test
    /// inlined into it) where the CPU has it. Only the instruction encoding differs: the
    /// arithmetic is the same IEEE operations (no fused multiply-adds), so the results are
    /// the same to the bit.
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

    /// The traversal (see the module documentation): `test` may lower `best` and stop it.
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
            let n = &self.nodes[cur as usize];
            let mut mask = Self::hit_children(n, r, *best, &mut near);
            // The leaves' triangles, and the inner children by priority (slot ^ octant).
            let mut tris = 0u32;
            let mut inner = 0u32;
            let mut by_priority = [(0u32, 0.0f32); 8];
            while mask != 0 {
                let i = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                if n.slot[i] == LEAF {
                    tris |= n.child[i];
                } else {
                    let p = (n.slot[i] ^ r.oct) as usize;
                    inner |= 1 << p;
                    by_priority[p] = (n.child[i], near[i]);
                }
            }
            while tris != 0 {
                let b = 31 - tris.leading_zeros();
                tris &= !(1 << b);
                if test.test(n.first + b, best) && ANY {
                    return true;
                }
            }
            // Push the inner children lowest priority first, so that the highest is on top.
            while inner != 0 {
                let p = inner.trailing_zeros() as usize;
                inner &= inner - 1;
                stack[sp].write(by_priority[p]);
                sp += 1;
            }
            // The next postponed child still in reach.
            loop {
                if sp == 0 {
                    return false;
                }
                sp -= 1;
                // SAFETY: entries below `sp` were written by the pushes above.
                let (c, tn) = unsafe { stack[sp].assume_init() };
                if ANY || tn <= *best * CULL_SLACK {
                    cur = c;
                    break;
                }
            }
        }
    }
}
