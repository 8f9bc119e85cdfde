// Backward warp: bilinear fetch of `src` at prev_pos = pos + motion (pixels), where pos is
// the pixel centre (x + 0.5, y + 0.5). A sample whose prev_pos lies outside
// [0, w) x [0, h), or whose motion is not finite, is invalid: output 0, validity 0.
// Taps beyond the edge are clamped (border). Validity is written to channel 0 of `valid`.

struct Params {
    width: u32,
    height: u32,
    c4: u32,        // padded channels / 4 of src and dst
    motion_c4: u32, // padded channels / 4 of the motion tensor (motion in channels 0, 1)
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> src: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> motion: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> dst: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> valid: array<vec4<f32>>;

fn finite(v: f32) -> bool {
    // NaN fails both comparisons; +-Inf fails the bound.
    return abs(v) <= 3.0e38;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let pix = pixel_index(gid, p.width, p.height);
    if (pix == OUTSIDE) {
        return;
    }
    let x = gid.x;
    let y = gid.y;
    let mv = motion[pix * p.motion_c4].xy;
    let pos = vec2<f32>(f32(x) + 0.5, f32(y) + 0.5) + mv;
    let w = f32(p.width);
    let h = f32(p.height);
    let ok = finite(mv.x) && finite(mv.y) && pos.x >= 0.0 && pos.y >= 0.0 && pos.x < w && pos.y < h;
    if (!ok) {
        for (var c = 0u; c < p.c4; c++) {
            dst[pix * p.c4 + c] = vec4<f32>(0.0);
        }
        valid[pix] = vec4<f32>(0.0);
        return;
    }
    let s = pos - vec2<f32>(0.5);
    let f = floor(s);
    let t = s - f;
    let x0 = u32(clamp(f.x, 0.0, w - 1.0));
    let y0 = u32(clamp(f.y, 0.0, h - 1.0));
    let x1 = u32(clamp(f.x + 1.0, 0.0, w - 1.0));
    let y1 = u32(clamp(f.y + 1.0, 0.0, h - 1.0));
    for (var c = 0u; c < p.c4; c++) {
        let a = src[(y0 * p.width + x0) * p.c4 + c];
        let b = src[(y0 * p.width + x1) * p.c4 + c];
        let d = src[(y1 * p.width + x0) * p.c4 + c];
        let e = src[(y1 * p.width + x1) * p.c4 + c];
        dst[pix * p.c4 + c] = mix(mix(a, b, t.x), mix(d, e, t.x), t.y);
    }
    valid[pix] = vec4<f32>(1.0, 0.0, 0.0, 0.0);
}
