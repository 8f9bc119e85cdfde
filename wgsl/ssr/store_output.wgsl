// Writes the first 3 channels of a padded Wp x Hp tensor into the W x H output texture
// (rgba32float, alpha = 1), cropping the padding.
// With template flag BACKGROUND (the caller gave the optional background buffer, DESIGN §3):
// a pixel's radiance is the directly seen environment over the part of its footprint that
// escapes (the background, xyz, premultiplied by that part) plus the rest's radiance, so the
// output is background + (1 - coverage) * reconstruction: the background alone where the
// coverage (w) is 1, the network's reconstruction alone where it is 0. Both are sanitised
// (background as colour, ssr/lib/sanitize; coverage into [0, 1], non-finite 0), values
// changed counted in `sanitized`. The network's own output (its history) is left as it was.
//
//#param BACKGROUND 0

struct Params {
    width: u32,
    height: u32,
    padded_width: u32,
    c4: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> src: array<vec4<f32>>;
@group(0) @binding(2) var dst: texture_storage_2d<rgba32float, write>;
//#if BACKGROUND
@group(0) @binding(3) var<storage, read> background: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> sanitized: array<atomic<u32>>;
//#end

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= p.width || gid.y >= p.height) {
        return;
    }
    var rgb = src[(gid.y * p.padded_width + gid.x) * p.c4].xyz;
//#if BACKGROUND
    let b = background[gid.y * p.width + gid.x];
    var bad = 0u;
    let coverage = in_range(b.w, 0.0, 1.0, &bad);
    rgb = sanitize_radiance(b.xyz, &bad) + (1.0 - coverage) * rgb;
    if (bad > 0u) {
        atomicAdd(&sanitized[0], bad);
    }
//#end
    textureStore(dst, vec2<u32>(gid.xy), vec4<f32>(rgb, 1.0));
}
