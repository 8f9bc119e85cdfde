// G-buffers from primary visibility at pixel centres (DESIGN.md section 3): albedo + depth,
// shading normal + metallic, roughness (w of shadow_roughness, whose xyz the path tracer
// fills; zeroed here), transparent tint, and motion vectors from the previous camera.

@group(0) @binding(0) var<uniform> p: FrameParams;
// The scene at bindings 1-7 (trace/lib/scene.wgsl).
@group(0) @binding(8) var<storage, read_write> albedo_depth: array<vec4<f32>>;
@group(0) @binding(9) var<storage, read_write> normal_metallic: array<vec4<f32>>;
@group(0) @binding(10) var<storage, read_write> shadow_roughness: array<vec4<f32>>;
@group(0) @binding(11) var<storage, read_write> transparent: array<vec4<f32>>;
@group(0) @binding(12) var<storage, read_write> motion: array<vec4<f32>>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (outside_frame(gid, p.size)) {
        return;
    }
    let i = gid.y * p.size.x + gid.x;
    let size = vec2<f32>(p.size.xy);
    let pos = vec2<f32>(f32(gid.x) + 0.5, f32(gid.y) + 0.5);
    let d = camera_dir(p.cam, pos, size);
    let hit = traverse(p.cam.pos.xyz, d, BIG, false, NO_HIT);
    var prev: vec3<f32>;
    if (hit.prim == NO_HIT) {
        albedo_depth[i] = vec4<f32>(1.0, 1.0, 1.0, 1.0);
        normal_metallic[i] = vec4<f32>(0.0);
        shadow_roughness[i] = vec4<f32>(0.0);
        transparent[i] = vec4<f32>(0.0);
        prev = camera_project(p.prev, d, true, size);
    } else {
        let s = surface_at(hit, d);
        let depth = clamp(dot(s.p - p.cam.pos.xyz, p.cam.fwd.xyz) / p.misc.x, 0.0, 1.0);
        albedo_depth[i] = vec4<f32>(s.base, depth);
        normal_metallic[i] = vec4<f32>(s.ns, s.metallic);
        shadow_roughness[i] = vec4<f32>(0.0, 0.0, 0.0, s.roughness);
        transparent[i] = vec4<f32>(s.base * s.transmission, 0.0);
        prev = camera_project(p.prev, s.p, false, size);
    }
    if (prev.z > 0.0) {
        motion[i] = vec4<f32>(prev.xy - pos, 0.0, 0.0);
    } else {
        // Behind the previous camera: point far off screen, so history is rejected.
        motion[i] = vec4<f32>(-1.0e6, -1.0e6, 0.0, 0.0);
    }
}
