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

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let pix = pixel_index(gid, p.width, p.height);
    if (pix == OUTSIDE) {
        return;
    }
    let x = gid.x;
    let y = gid.y;
    let k = warp_taps(x, y, motion[pix * p.motion_c4].xy, p.width, p.height);
    if (!k.valid) {
        for (var c = 0u; c < p.c4; c++) {
            dst[pix * p.c4 + c] = vec4<f32>(0.0);
        }
        valid[pix] = vec4<f32>(0.0);
        return;
    }
    for (var c = 0u; c < p.c4; c++) {
        let a = src[k.i00 * p.c4 + c];
        let b = src[k.i10 * p.c4 + c];
        let d = src[k.i01 * p.c4 + c];
        let e = src[k.i11 * p.c4 + c];
        dst[pix * p.c4 + c] = bilinear(a, b, d, e, k.t);
    }
    valid[pix] = vec4<f32>(1.0, 0.0, 0.0, 0.0);
}
