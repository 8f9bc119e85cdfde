// Temporal feature accumulation blend (DESIGN §4):
//   s_cur = <E_cur, R>, s_prev = <E_prev, R>          (per-pixel dot products over K ch)
//   (beta, alpha) = softmax(s_cur, s_prev), alpha := 0 where the history is invalid
//   out = alpha * prev + beta * cur                    (C ch)
// Writes `out` and `weights` = (beta, alpha, s_cur, s_prev) per pixel. R, E_cur, E_prev,
// cur, prev and out are stored as f32 or f16 (nn/lib/storage: In0..In4, Out; f32
// arithmetic), `valid` and `weights` as f32.

struct Params {
    width: u32,
    height: u32,
    k4: u32,   // padded K / 4 of R, E_cur, E_prev
    c4: u32,   // padded C / 4 of cur, prev, out
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> r: array<In0>;
@group(0) @binding(2) var<storage, read> e_cur: array<In1>;
@group(0) @binding(3) var<storage, read> e_prev: array<In2>;
@group(0) @binding(4) var<storage, read> cur: array<In3>;
@group(0) @binding(5) var<storage, read> prev: array<In4>;
@group(0) @binding(6) var<storage, read> valid: array<vec4<f32>>; // channel 0
@group(0) @binding(7) var<storage, read_write> out: array<Out>;
@group(0) @binding(8) var<storage, read_write> weights: array<vec4<f32>>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let pix = pixel_index(gid, p.width, p.height);
    if (pix == OUTSIDE) {
        return;
    }
    var s_cur = 0.0;
    var s_prev = 0.0;
    for (var k = 0u; k < p.k4; k++) {
        let rr = vec4<f32>(r[pix * p.k4 + k]);
        s_cur += dot(vec4<f32>(e_cur[pix * p.k4 + k]), rr);
        s_prev += dot(vec4<f32>(e_prev[pix * p.k4 + k]), rr);
    }
    var alpha = 0.0;
    var beta = 1.0;
    if (valid[pix].x > 0.5) {
        let m = max(s_cur, s_prev);
        let a = exp(s_prev - m);
        let b = exp(s_cur - m);
        alpha = a / (a + b);
        beta = b / (a + b);
    }
    for (var c = 0u; c < p.c4; c++) {
        let i = pix * p.c4 + c;
        out[i] = to_out(alpha * vec4<f32>(prev[i]) + beta * vec4<f32>(cur[i]));
    }
    weights[pix] = vec4<f32>(beta, alpha, s_cur, s_prev);
}
