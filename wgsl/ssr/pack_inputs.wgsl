// Builds the network's A_t from four of the six per-frame buffers of the data contract
// (DESIGN §3, packed as vec4 per pixel at the caller's W x H) at the padded size Wp x Hp
// (pixels beyond W x H replicate the edge):
//   A_t (15 ch, 4 vec4) = [e(3), albedo(3), normal(3), log1p(shadow)(3), depth, metallic, roughness]
// with e = ln(1 + (color / s) / (albedo + 0.00316)) and log1p(shadow / s_shadow), s and
// s_shadow = the frame's exposure of colour and shadow (per channel; channels 0..5 of a 1x1x9 tensor,
// exposure_final.wgsl; 1 for version-1 weights). ssr/pack_mt builds the rest (mask,
// transparent, motion): the split keeps each kernel within WebGPU's default 8 storage
// buffers per stage.
// Every input is sanitised (ssr/lib/sanitize) and each value changed is counted in
// `sanitized` (only for pixels inside W x H, once each; the mask, read again by
// ssr/pack_mt, is counted here).

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> color_mask: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> albedo_depth: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> normal_metallic: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> shadow_roughness: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> a_t: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> sanitized: array<atomic<u32>>;
@group(0) @binding(7) var<storage, read> exposure: array<vec4<f32>>;

const EPS: f32 = 0.00316;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (outside_padded(gid)) {
        return;
    }
    let src = source_pixel(gid);
    var bad = 0u;
    let cm = color_mask[src];
    let ad = albedo_depth[src];
    let nm = normal_metallic[src];
    let sr = shadow_roughness[src];
    let color = sanitize_radiance(cm.xyz, &bad);
    _ = sanitize_mask(cm.w, &bad);
    let albedo = sanitize_unit(ad.xyz, &bad);
    let depth = in_range(ad.w, 0.0, 1.0, &bad);
    let normal = sanitize_normal(nm.xyz, &bad);
    let metallic = in_range(nm.w, 0.0, 1.0, &bad);
    let shadow_in = sanitize_radiance(sr.xyz, &bad);
    let roughness = in_range(sr.w, 0.0, 1.0, &bad);
    count_sanitized(gid, bad);
    let s = exposure[0].xyz;
    let e = log(vec3<f32>(1.0) + (color / s) / (albedo + vec3<f32>(EPS)));
    let s_shadow = vec3<f32>(exposure[0].w, exposure[1].xy);
    let shadow = log(vec3<f32>(1.0) + shadow_in / s_shadow);
    let dst = padded_pixel(gid);
    a_t[dst * 4u + 0u] = vec4<f32>(e, albedo.x);
    a_t[dst * 4u + 1u] = vec4<f32>(albedo.yz, normal.xy);
    a_t[dst * 4u + 2u] = vec4<f32>(normal.z, shadow);
    a_t[dst * 4u + 3u] = vec4<f32>(depth, metallic, roughness, 0.0);
}
