// Path tracer library: CWBVH traversal (Ylitie et al. 2017, compressed wide BVH as built by
// obvhs) with a per-ray stack, and the ray/triangle test.
//
// Node layout, 5 x vec4<u32> per node:
//   d0 = (p.x, p.y, p.z bits, e0 | e1 << 8 | e2 << 16 | imask << 24)
//   d1 = (child_base_idx, primitive_base_idx, child_meta[0..4], child_meta[4..8])
//   d2 = (child_min_x[0..4], child_min_x[4..8], child_max_x[0..4], child_max_x[4..8]); d3, d4: y, z
// A traversal group is (base index, hit mask): bits 24..31 of the mask are child nodes (by
// octant-adjusted slot), bits 0..23 are triangles relative to the base.

// Deepest tree the GPU stack holds; the host refuses deeper trees (render::bvh::STACK_SIZE).
const STACK_SIZE: u32 = 32u;
// Node boxes are entered from this distance on (as obvhs's CPU traversal does).
const NODE_T_MIN: f32 = 1.0e-4;

struct Hit {
    t: f32,
    prim: u32,   // BVH-order triangle index, NO_HIT on a miss
    u: f32,      // barycentric weight of v1
    v: f32,      // barycentric weight of v2
}

fn safe_rcp(x: f32) -> f32 {
    // As obvhs's `safe_inverse`: tiny components become +-1/eps; the sign is that of the
    // ray's octant (`d < 0` in traverse), so -0.0 counts as +0.0. (Taking it from the sign
    // bit made a ray with a -0.0 component miss every box whose slab held it; the CPU twin
    // gives obvhs directions without negative zeros, render::bvh::ray.)
    let eps = 1.1920929e-7;
    if (abs(x) <= eps) {
        return select(1.0, -1.0, x < 0.0) / eps;
    }
    return 1.0 / x;
}

// Moeller-Trumbore in the form obvhs's `Triangle::intersect` uses; returns (t, u, v) with
// t = BIG on a miss. A hit needs u, v, 1-u-v with clear sign bits and t in [tmin, tmax].
fn intersect_tri(prim: u32, o: vec3<f32>, d: vec3<f32>, tmin: f32, tmax: f32) -> vec3<f32> {
    let v0 = tris[4u * prim].xyz;
    let e1 = tris[4u * prim + 1u].xyz;
    let e2 = tris[4u * prim + 2u].xyz;
    let n = cross(e1, e2);
    let c = v0 - o;
    let r = cross(d, c);
    let det = dot(n, d);
    if (det == 0.0) {
        return vec3<f32>(BIG, 0.0, 0.0);
    }
    let inv_det = 1.0 / det;
    let u = dot(r, e2) * inv_det;
    let v = dot(r, e1) * inv_det;
    let w = 1.0 - u - v;
    let signs = (bitcast<u32>(u) | bitcast<u32>(v) | bitcast<u32>(w)) & 0x80000000u;
    if (signs != 0u) {
        return vec3<f32>(BIG, 0.0, 0.0);
    }
    let t = dot(n, c) * inv_det;
    if (t >= tmin && t <= tmax) {
        return vec3<f32>(t, u, v);
    }
    return vec3<f32>(BIG, 0.0, 0.0);
}

// Hit mask of the children of node `ni` intersected by the ray within (NODE_T_MIN, tmax).
fn intersect_node(ni: u32, o: vec3<f32>, inv_d: vec3<f32>, neg: vec3<bool>, oct_inv4: u32, tmax: f32) -> u32 {
    let d0 = bvh_nodes[5u * ni];
    let d1 = bvh_nodes[5u * ni + 1u];
    let dx = bvh_nodes[5u * ni + 2u];
    let dy = bvh_nodes[5u * ni + 3u];
    let dz = bvh_nodes[5u * ni + 4u];
    let p = bitcast<vec3<f32>>(d0.xyz);
    let e = vec3<u32>(d0.w & 0xffu, (d0.w >> 8u) & 0xffu, (d0.w >> 16u) & 0xffu);
    let ext = bitcast<vec3<f32>>(e << vec3<u32>(23u));
    let adj_inv = ext * inv_d;
    let adj_o = (p - o) * inv_d;
    var hitmask = 0u;
    for (var half = 0u; half < 2u; half++) {
        let meta4 = d1[2u + half];
        let is_inner4 = (meta4 & (meta4 << 1u)) & 0x10101010u;
        let inner_mask4 = (is_inner4 >> 4u) * 0xffu;
        let bit_index4 = (meta4 ^ (oct_inv4 & inner_mask4)) & 0x1f1f1f1fu;
        let child_bits4 = (meta4 >> 5u) & 0x07070707u;
        // Near/far planes by ray direction sign.
        let lo_x = select(dx[half], dx[2u + half], neg.x);
        let hi_x = select(dx[2u + half], dx[half], neg.x);
        let lo_y = select(dy[half], dy[2u + half], neg.y);
        let hi_y = select(dy[2u + half], dy[half], neg.y);
        let lo_z = select(dz[half], dz[2u + half], neg.z);
        let hi_z = select(dz[2u + half], dz[half], neg.z);
        for (var j = 0u; j < 4u; j++) {
            let sh = 8u * j;
            let qlo = vec3<f32>(vec3<u32>(lo_x >> sh, lo_y >> sh, lo_z >> sh) & vec3<u32>(0xffu));
            let qhi = vec3<f32>(vec3<u32>(hi_x >> sh, hi_y >> sh, hi_z >> sh) & vec3<u32>(0xffu));
            let t0 = qlo * adj_inv + adj_o;
            let t1 = qhi * adj_inv + adj_o;
            let tnear = max(max(t0.x, t0.y), max(t0.z, NODE_T_MIN));
            let tfar = min(min(t1.x, t1.y), min(t1.z, tmax));
            if (tnear <= tfar) {
                let bits = (child_bits4 >> sh) & 0xffu;
                let idx = (bit_index4 >> sh) & 0xffu;
                hitmask |= bits << idx;
            }
        }
    }
    return hitmask;
}

// Closest hit (any_hit = false) or any hit of a triangle that does not pass light straight
// through (true: what blocks a shadow ray) along o + t d, t in [0, tmax]. Triangle
// `skip` (the one the ray leaves from, or NO_HIT) is ignored; alpha-masked triangles are
// tested against their material's alpha cutoff.
fn traverse(o: vec3<f32>, d: vec3<f32>, tmax: f32, any_hit: bool, skip: u32) -> Hit {
    var hit = Hit(min(tmax, BIG), NO_HIT, 0.0, 0.0);
    rays_traced += 1u;
    if (arrayLength(&bvh_nodes) < 5u) {
        return hit;
    }
    let inv_d = vec3<f32>(safe_rcp(d.x), safe_rcp(d.y), safe_rcp(d.z));
    let neg = d < vec3<f32>(0.0);
    let oct_inv4 = select(0x04040404u, 0u, neg.x) | select(0x02020202u, 0u, neg.y) | select(0x01010101u, 0u, neg.z);
    var stack: array<vec2<u32>, STACK_SIZE>;
    var sp = 0u;
    var node_group = vec2<u32>(0u, 0x80000000u);
    var tri_group = vec2<u32>(0u, 0u);
    var done = false;
    loop {
        while (tri_group.y != 0u) {
            let local = firstLeadingBit(tri_group.y);
            tri_group.y &= ~(1u << local);
            let prim = tri_group.x + local;
            if (prim == skip) {
                continue;
            }
            let r = intersect_tri(prim, o, d, 0.0, hit.t);
            if (r.x < hit.t) {
                let info = bitcast<u32>(tris[4u * prim + 3u].w);
                if (any_hit && (info & TRI_FLAG_PASS) != 0u) {
                    continue;
                }
                if ((info & TRI_FLAG_ALPHA) != 0u && !alpha_passes(prim, r.y, r.z)) {
                    continue;
                }
                hit = Hit(r.x, prim, r.y, r.z);
                if (any_hit) {
                    done = true;
                    break;
                }
            }
        }
        if (done) {
            break;
        }
        tri_group = vec2<u32>(0u, 0u);
        if ((node_group.y & 0xff000000u) != 0u) {
            let hits_imask = node_group.y;
            let child_bit = firstLeadingBit(hits_imask);
            let base = node_group.x;
            node_group.y &= ~(1u << child_bit);
            if ((node_group.y & 0xff000000u) != 0u) {
                if (sp < STACK_SIZE) {
                    stack[sp] = node_group;
                    sp++;
                }
            }
            let slot = (child_bit - 24u) ^ (oct_inv4 & 0xffu);
            let rel = countOneBits(hits_imask & ~(0xffffffffu << slot));
            let ni = base + rel;
            let mask = intersect_node(ni, o, inv_d, neg, oct_inv4, hit.t);
            let d0w = bvh_nodes[5u * ni].w;
            let d1 = bvh_nodes[5u * ni + 1u];
            node_group = vec2<u32>(d1.x, (mask & 0xff000000u) | (d0w >> 24u));
            tri_group = vec2<u32>(d1.y, mask & 0x00ffffffu);
        } else {
            node_group = vec2<u32>(0u, 0u);
        }
        if (tri_group.y == 0u && (node_group.y & 0xff000000u) == 0u) {
            if (sp == 0u) {
                break;
            }
            sp--;
            node_group = stack[sp];
        }
    }
    return hit;
}

// Whether anything opaque (anything but MAT_PASS surfaces) blocks the segment from o along
// unit d up to distance `dist`.
fn occluded(o: vec3<f32>, d: vec3<f32>, dist: f32, skip: u32) -> bool {
    return traverse(o, d, dist, true, skip).prim != NO_HIT;
}
