// The optional background buffer (DESIGN.md section 3) and the footprint albedo: per pixel,
// over n x n stratified camera rays through the pixel's footprint (n = p.accum.z), the
// environment seen directly (rays that hit anything, transmissive surfaces included, count
// 0), the fraction of those rays that escape (the coverage), and the mean first-hit base
// colour (the G-buffer's albedo, sky 1), written with the G-buffer's depth as
// albedo_footprint = (albedo, depth): the layout of albedo_depth, so a model that uses the
// footprint albedo reads this buffer in its place. Where the coverage is 1 the background
// is the pixel's radiance, estimated with n x n environment lookups instead of path samples.
// emission_coarse.xyz gets the mean first-hit emission over the same rays, which
// trace/emission_outline refines on emitters' outlines into the `emission_footprint` half of
// the directly seen emission (DESIGN.md section 3).
// Runs after the G-buffer pass.
// CPU twin: `background_pixel` in src/render/cpu/integrator.rs.

@group(0) @binding(0) var<uniform> p: FrameParams;
// The scene at bindings 1-7 (trace/lib/scene.wgsl).
@group(0) @binding(8) var<storage, read_write> background: array<vec4<f32>>;
@group(0) @binding(9) var<storage, read_write> albedo_footprint: array<vec4<f32>>;
@group(0) @binding(10) var<storage, read> albedo_depth: array<vec4<f32>>;
@group(0) @binding(11) var<storage, read_write> emission_coarse: array<vec4<f32>>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (outside_frame(gid, p.size)) {
        return;
    }
    let n = max(p.accum.z, 1u);
    let size = vec2<f32>(p.size.xy);
    let o = p.cam.pos.xyz;
    var sum = vec3<f32>(0.0);
    var albedo = vec3<f32>(0.0);
    var emission = vec3<f32>(0.0);
    var escaped = 0u;
    for (var j = 0u; j < n; j++) {
        for (var i = 0u; i < n; i++) {
            let d = footprint_dir(p.cam, gid.xy, i, j, n, size);
            let hit = traverse(o, d, BIG, false, NO_HIT);
            if (hit.prim == NO_HIT) {
                escaped += 1u;
                sum += env_radiance(d); // 0 without an environment
                albedo += vec3<f32>(1.0);
            } else {
                let s = surface_at(hit, d);
                albedo += s.base;
                emission += s.emission;
            }
        }
    }
    let count = f32(n * n);
    let at = gid.y * p.size.x + gid.x;
    background[at] = vec4<f32>(sum / count, f32(escaped) / count);
    albedo_footprint[at] = vec4<f32>(albedo / count, albedo_depth[at].w);
    emission_coarse[at] = vec4<f32>(emission / count, 0.0);
}
