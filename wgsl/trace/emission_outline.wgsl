// The directly seen emission on emitters' outlines (DESIGN.md section 3): the background
// pass's first-hit emission over n x n rays (n = p.accum.z), `coarse`, copied to
// `emission_footprint`, except on pixels whose 3x3 neighbourhood (within the frame) holds
// both pixels that see an emitter (some channel above 0) and pixels that see none, which
// are traced again with OUTLINE x OUTLINE stratified rays when n is fewer: there a few rays
// measure an emitter's coverage coarsely. Runs after the background pass.
// CPU twin: `CpuTracer::background` (src/render/cpu/mod.rs) with `footprint_emission` and
// `DirectEmission::outline`.

// src/render/settings.rs EMISSION_OUTLINE_RAYS.
const OUTLINE: u32 = 8u;

@group(0) @binding(0) var<uniform> p: FrameParams;
// The scene at bindings 1-7 (trace/lib/scene.wgsl).
@group(0) @binding(8) var<storage, read> coarse: array<vec4<f32>>;
@group(0) @binding(9) var<storage, read_write> emission_footprint: array<vec4<f32>>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (outside_frame(gid, p.size)) {
        return;
    }
    let w = p.size.x;
    let h = p.size.y;
    let at = gid.y * w + gid.x;
    var any_lit = false;
    var any_dark = false;
    for (var dy = -1; dy <= 1; dy++) {
        for (var dx = -1; dx <= 1; dx++) {
            let nx = i32(gid.x) + dx;
            let ny = i32(gid.y) + dy;
            if (nx >= 0 && ny >= 0 && nx < i32(w) && ny < i32(h)) {
                let lit = any(coarse[u32(ny) * w + u32(nx)].xyz > vec3<f32>(0.0));
                any_lit = any_lit || lit;
                any_dark = any_dark || !lit;
            }
        }
    }
    if (!(any_lit && any_dark) || p.accum.z >= OUTLINE) {
        emission_footprint[at] = coarse[at];
        return;
    }
    let size = vec2<f32>(p.size.xy);
    let o = p.cam.pos.xyz;
    var emission = vec3<f32>(0.0);
    for (var j = 0u; j < OUTLINE; j++) {
        for (var i = 0u; i < OUTLINE; i++) {
            let d = footprint_dir(p.cam, gid.xy, i, j, OUTLINE, size);
            let hit = traverse(o, d, BIG, false, NO_HIT);
            if (hit.prim != NO_HIT) {
                emission += surface_at(hit, d).emission;
            }
        }
    }
    emission_footprint[at] = vec4<f32>(emission / f32(OUTLINE * OUTLINE), 0.0);
}
