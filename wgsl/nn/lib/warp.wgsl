// The backward warp shared by nn/warp, ssr/warp_history and ssr/mean_history (reference
// src/nn/reference.rs `warp`): a pixel's position in the previous frame is its centre plus
// its motion (pixels); it is valid when the motion is finite and that position lies in
// [0, w) x [0, h), and then read bilinearly between the four nearest pixel centres, the taps
// clamped to the image.

fn finite(v: f32) -> bool {
    // NaN fails both comparisons; +-Inf fails the bound.
    return abs(v) <= 3.0e38;
}

// Bilinear taps of a backward warp: the four pixel indices (row-major), their columns and
// rows (`lo` = (x0, y0), `hi` = (x1, y1), for readers of textures), the weights (t.x, t.y)
// and whether the position is valid (the rest is 0 where it is not).
struct Taps {
    i00: u32,
    i10: u32,
    i01: u32,
    i11: u32,
    lo: vec2<u32>,
    hi: vec2<u32>,
    t: vec2<f32>,
    valid: bool,
}

// The taps of pixel (x, y) with motion `mv` in a width x height image.
fn warp_taps(x: u32, y: u32, mv: vec2<f32>, width: u32, height: u32) -> Taps {
    var k: Taps;
    let pos = vec2<f32>(f32(x) + 0.5, f32(y) + 0.5) + mv;
    let w = f32(width);
    let h = f32(height);
    k.valid = finite(mv.x) && finite(mv.y) && pos.x >= 0.0 && pos.y >= 0.0 && pos.x < w && pos.y < h;
    if (!k.valid) {
        return k;
    }
    let s = pos - vec2<f32>(0.5);
    let f = floor(s);
    k.t = s - f;
    let x0 = u32(clamp(f.x, 0.0, w - 1.0));
    let y0 = u32(clamp(f.y, 0.0, h - 1.0));
    let x1 = u32(clamp(f.x + 1.0, 0.0, w - 1.0));
    let y1 = u32(clamp(f.y + 1.0, 0.0, h - 1.0));
    k.i00 = y0 * width + x0;
    k.i10 = y0 * width + x1;
    k.i01 = y1 * width + x0;
    k.i11 = y1 * width + x1;
    k.lo = vec2<u32>(x0, y0);
    k.hi = vec2<u32>(x1, y1);
    return k;
}

// The bilinear mix of the values at the taps i00, i10, i01, i11.
fn bilinear(a: vec4<f32>, b: vec4<f32>, d: vec4<f32>, e: vec4<f32>, t: vec2<f32>) -> vec4<f32> {
    return mix(mix(a, b, t.x), mix(d, e, t.x), t.y);
}
