// The mean correction's per-pixel sums (config `mean_correction = "atrous"`, issue 11;
// reference src/nn/reference.rs `mean_pixel_sums` and `warp`): as ssr/tile_means' statistic,
// but per pixel and carried along the motion. Each invocation takes one pixel of the W x H
// frame: its shares (s, r) of ssr/lib/traced (0 where it is not traced). Unless this is the
// first frame after a reset (`p.first`), the last frame's sums (`prev`, 2 vec4 per pixel)
// are added, warped to this frame and weighted by DECAY: (s, r) + DECAY W(prev), W the
// backward warp of nn/lib/warp (bilinear at the pixel centre plus the caller's motion, taps
// clamped at the edges; a position outside the frame or a non-finite motion gives 0). The
// sums go to `sums` (2 vec4 per pixel), which ssr/mean_atrous filters into the factors and
// the next frame reads as `prev`.
//
//#param BACKGROUND 0
//#param ESCAPED 0

// Params: ssr/lib/output (`tiles_x`, `tiles_y` and `slot` unused).

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> src: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> color_mask: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> motion: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> prev: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> sums: array<vec4<f32>>;
//#if BACKGROUND
@group(0) @binding(6) var<storage, read> background: array<vec4<f32>>;
//#end

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
    let shares = traced_shares(x, y);
    var s = vec4<f32>(shares.s, 0.0);
    var r = vec4<f32>(shares.r, 0.0);
    if (p.first == 0u) {
        let k = warp_taps(x, y, motion[at].xy, p.width, p.height);
        if (k.valid) {
            let ws = bilinear(prev[2u * k.i00], prev[2u * k.i10], prev[2u * k.i01], prev[2u * k.i11], k.t);
            let wr = bilinear(
                prev[2u * k.i00 + 1u], prev[2u * k.i10 + 1u], prev[2u * k.i01 + 1u], prev[2u * k.i11 + 1u], k.t,
            );
            s += DECAY * ws;
            r += DECAY * wr;
        }
    }
    sums[2u * at] = s;
    sums[2u * at + 1u] = r;
}
