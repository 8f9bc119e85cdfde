// 2x2 pooling (max or average), NHWC vec4 tensors.
// Output is ceil(w/2) x ceil(h/2); windows are clipped to the input, and the average is
// taken over the pixels inside it.
// Input and output are stored as f32 or f16 (nn/lib/storage: In0, Out); the arithmetic is
// f32.

// Params: nn/lib/resample.wgsl (p.mode: 0 max, 1 average).

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> src: array<In0>;
@group(0) @binding(2) var<storage, read_write> dst: array<Out>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let x = gid.x;
    let y = gid.y;
    if (x >= p.out_w || y >= p.out_h) {
        return;
    }
    let x1 = min(2u * x + 1u, p.in_w - 1u);
    let y1 = min(2u * y + 1u, p.in_h - 1u);
    let n = f32((x1 - 2u * x + 1u) * (y1 - 2u * y + 1u));
    for (var c = 0u; c < p.c4; c++) {
        let a = vec4<f32>(src[((2u * y) * p.in_w + 2u * x) * p.c4 + c]);
        let b = vec4<f32>(src[((2u * y) * p.in_w + x1) * p.c4 + c]);
        let d = vec4<f32>(src[(y1 * p.in_w + 2u * x) * p.c4 + c]);
        let e = vec4<f32>(src[(y1 * p.in_w + x1) * p.c4 + c]);
        var r: vec4<f32>;
        if (p.mode == 0u) {
            r = max(max(a, b), max(d, e));
        } else {
            // Clipped taps repeat an in-window pixel; count each distinct pixel once.
            var s = a;
            if (x1 != 2u * x) { s += b; }
            if (y1 != 2u * y) { s += d; }
            if (x1 != 2u * x && y1 != 2u * y) { s += e; }
            r = s / n;
        }
        dst[(y * p.out_w + x) * p.c4 + c] = to_out(r);
    }
}
