// Ray queries against the scene BVH: one closest (or any) hit per ray. Used to test the
// GPU traversal against obvhs's CPU traversal, and for picking.
// rays[2i] = (origin, tmax), rays[2i + 1] = (direction, 0);
// hits[i] = (t, triangle bits (BVH order, NO_HIT on a miss), u, v).

struct QueryParams {
    count: u32,
    any_hit: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> q: QueryParams;
// The scene at bindings 1-7 (trace/lib/scene.wgsl).
@group(0) @binding(8) var<storage, read> rays: array<vec4<f32>>;
@group(0) @binding(9) var<storage, read_write> hits: array<vec4<f32>>;

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if (i >= q.count) {
        return;
    }
    let a = rays[2u * i];
    let b = rays[2u * i + 1u];
    let h = traverse(a.xyz, b.xyz, a.w, q.any_hit != 0u, NO_HIT);
    if (h.prim == NO_HIT) {
        hits[i] = vec4<f32>(BIG, bitcast<f32>(NO_HIT), 0.0, 0.0);
    } else {
        hits[i] = vec4<f32>(h.t, bitcast<f32>(h.prim), h.u, h.v);
    }
}
