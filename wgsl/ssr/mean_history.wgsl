// The mean correction's per-pixel sums (config `mean_correction = "atrous"`, issue 11;
// reference src/nn/reference.rs `mean_pixel_sums` and `warp`): as ssr/tile_means' statistic,
// but per pixel and carried along the motion. Each invocation takes one pixel of the W x H
// frame: its shares (s, r) of ssr/lib/traced (0 where it is not traced). Unless this is the
// first frame after a reset (`p.first`), the last frame's sums (textures `prev_s`, `prev_r`)
// are added, warped to this frame and weighted by DECAY: (s, r) + DECAY W(prev), W the
// backward warp of nn/lib/warp (bilinear at the pixel centre plus the caller's motion, taps
// clamped at the edges; a position outside the frame or a non-finite motion gives 0). The
// sums go to the storage textures `now_s`, `now_r`, which ssr/mean_atrous filters into the
// factors and the next frame reads as `prev`. The pass also leaves each pixel's guide for
// the filter in `guide`: the caller's normal (xyz) and normalised depth (w), sanitised as
// pack_inputs does (not counted here: that pass counts them).
//
// The filter's data are textures, not buffers: its 25 taps per pixel and level are texel
// fetches, which CPU drivers (llvmpipe) vectorise, where storage-buffer loads run lane by
// lane with a bounds check each (issue 14).
//
//#param BACKGROUND 0
//#param ESCAPED 0

// Params: ssr/lib/output (`tiles_x`, `tiles_y` and `slot` unused).

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> src: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> color_mask: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> motion: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> normal_metallic: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read> albedo_depth: array<vec4<f32>>;
@group(0) @binding(6) var prev_s: texture_2d<f32>;
@group(0) @binding(7) var prev_r: texture_2d<f32>;
@group(0) @binding(8) var now_s: texture_storage_2d<rgba32float, write>;
@group(0) @binding(9) var now_r: texture_storage_2d<rgba32float, write>;
@group(0) @binding(10) var guide: texture_storage_2d<rgba32float, write>;
//#if BACKGROUND
@group(0) @binding(11) var<storage, read> background: array<vec4<f32>>;
//#end

// The texel of `t` at column x and row y.
fn texel(t: texture_2d<f32>, x: u32, y: u32) -> vec4<f32> {
    return textureLoad(t, vec2<u32>(x, y), 0);
}

// Set by the denoiser from src/ssr/config.rs (ATROUS_DECAY).
override DECAY: f32 = 0.7;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= p.width || gid.y >= p.height) {
        return;
    }
    let x = gid.x;
    let y = gid.y;
    let at = y * p.width + x;
    let pos = vec2<u32>(x, y);
    var ignored = 0u;
    let n = sanitize_normal(normal_metallic[at].xyz, &ignored);
    textureStore(guide, pos, vec4<f32>(n, in_range(albedo_depth[at].w, 0.0, 1.0, &ignored)));
    let shares = traced_shares(x, y);
    var s = vec4<f32>(shares.s, 0.0);
    var r = vec4<f32>(shares.r, 0.0);
    if (p.first == 0u) {
        let k = warp_taps(x, y, motion[at].xy, p.width, p.height);
        if (k.valid) {
            let ws = bilinear(
                texel(prev_s, k.lo.x, k.lo.y), texel(prev_s, k.hi.x, k.lo.y),
                texel(prev_s, k.lo.x, k.hi.y), texel(prev_s, k.hi.x, k.hi.y), k.t,
            );
            let wr = bilinear(
                texel(prev_r, k.lo.x, k.lo.y), texel(prev_r, k.hi.x, k.lo.y),
                texel(prev_r, k.lo.x, k.hi.y), texel(prev_r, k.hi.x, k.hi.y), k.t,
            );
            s += DECAY * ws;
            r += DECAY * wr;
        }
    }
    textureStore(now_s, pos, s);
    textureStore(now_r, pos, r);
}
