// Builds the network inputs from the six per-frame buffers of the data contract
// (DESIGN §3, packed as vec4 per pixel at the caller's W x H) at the padded size
// Wp x Hp (pixels beyond W x H replicate the edge):
//   A_t (15 ch, 4 vec4) = [e(3), albedo(3), normal(3), log1p(shadow)(3), depth, metallic, roughness]
//   MT  (4 ch)          = [mask, transparent(3)]
//   motion (2 ch)       = caller motion
// with e = ln(1 + (color / s) / (albedo + 0.00316)) and log1p(shadow / s_shadow), s and
// s_shadow = the frame's exposure of colour and shadow (per channel; a 1x1x6 tensor,
// exposure_final.wgsl; 1 for version-1 weights). Non-finite
// input values become 0 and are counted in `sanitized` (only for pixels inside W x H, once
// each).

struct Params {
    width: u32,
    height: u32,
    padded_width: u32,
    padded_height: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> color_mask: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> albedo_depth: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> normal_metallic: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> shadow_roughness: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read> transparent: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read> motion: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read_write> a_t: array<vec4<f32>>;
@group(0) @binding(8) var<storage, read_write> mt: array<vec4<f32>>;
@group(0) @binding(9) var<storage, read_write> motion_out: array<vec4<f32>>;
@group(0) @binding(10) var<storage, read_write> sanitized: array<atomic<u32>>;
@group(0) @binding(11) var<storage, read> exposure: array<vec4<f32>>;

const EPS: f32 = 0.00316;

var<private> bad: u32 = 0u;

fn clean(v: vec4<f32>) -> vec4<f32> {
    // NaN fails the comparison; +-Inf fails the bound.
    let ok = abs(v) <= vec4<f32>(3.0e38);
    bad += u32(!ok.x) + u32(!ok.y) + u32(!ok.z) + u32(!ok.w);
    return select(vec4<f32>(0.0), v, ok);
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let x = gid.x;
    let y = gid.y;
    if (x >= p.padded_width || y >= p.padded_height) {
        return;
    }
    let src = min(y, p.height - 1u) * p.width + min(x, p.width - 1u);
    let cm = clean(color_mask[src]);
    let ad = clean(albedo_depth[src]);
    let nm = clean(normal_metallic[src]);
    let sr = clean(shadow_roughness[src]);
    let tr = clean(transparent[src]);
    let mv = clean(motion[src]);
    let inside = x < p.width && y < p.height;
    if (inside && bad > 0u) {
        atomicAdd(&sanitized[0], bad);
    }
    let albedo = ad.xyz;
    let s = exposure[0].xyz;
    let c = max(cm.xyz, vec3<f32>(0.0)) / s;
    let e = log(vec3<f32>(1.0) + c / (max(albedo, vec3<f32>(0.0)) + vec3<f32>(EPS)));
    let s_shadow = vec3<f32>(exposure[0].w, exposure[1].xy);
    let shadow = log(vec3<f32>(1.0) + max(sr.xyz, vec3<f32>(0.0)) / s_shadow);
    let dst = y * p.padded_width + x;
    a_t[dst * 4u + 0u] = vec4<f32>(e, albedo.x);
    a_t[dst * 4u + 1u] = vec4<f32>(albedo.yz, nm.xy);
    a_t[dst * 4u + 2u] = vec4<f32>(nm.z, shadow);
    a_t[dst * 4u + 3u] = vec4<f32>(ad.w, nm.w, sr.w, 0.0);
    mt[dst] = vec4<f32>(cm.w, tr.xyz);
    motion_out[dst] = vec4<f32>(mv.xy, 0.0, 0.0);
}
