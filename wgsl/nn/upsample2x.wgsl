// 2x upsampling, nearest or bilinear (PyTorch `interpolate(scale_factor=2,
// align_corners=False)` semantics), NHWC vec4 tensors. The output size is a parameter
// (normally 2w x 2h); source coordinates are clamped to the input.

// Params: nn/lib/resample.wgsl (p.mode: 0 nearest, 1 bilinear).

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> src: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> dst: array<vec4<f32>>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let x = gid.x;
    let y = gid.y;
    if (x >= p.out_w || y >= p.out_h) {
        return;
    }
    let o = (y * p.out_w + x) * p.c4;
    if (p.mode == 0u) {
        let sx = min(x / 2u, p.in_w - 1u);
        let sy = min(y / 2u, p.in_h - 1u);
        let i = (sy * p.in_w + sx) * p.c4;
        for (var c = 0u; c < p.c4; c++) {
            dst[o + c] = src[i + c];
        }
        return;
    }
    let fx = max((f32(x) + 0.5) * 0.5 - 0.5, 0.0);
    let fy = max((f32(y) + 0.5) * 0.5 - 0.5, 0.0);
    let x0 = min(u32(fx), p.in_w - 1u);
    let y0 = min(u32(fy), p.in_h - 1u);
    let x1 = min(x0 + 1u, p.in_w - 1u);
    let y1 = min(y0 + 1u, p.in_h - 1u);
    let tx = fx - f32(x0);
    let ty = fy - f32(y0);
    for (var c = 0u; c < p.c4; c++) {
        let a = src[(y0 * p.in_w + x0) * p.c4 + c];
        let b = src[(y0 * p.in_w + x1) * p.c4 + c];
        let d = src[(y1 * p.in_w + x0) * p.c4 + c];
        let e = src[(y1 * p.in_w + x1) * p.c4 + c];
        dst[o + c] = mix(mix(a, b, tx), mix(d, e, tx), ty);
    }
}
