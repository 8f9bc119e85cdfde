// The history, warped and made ready for the TFA and the U-Net in one pass (fusing two
// nn/warp passes and ssr/history, issue 14): per pixel,
// 1. backward warp (as nn/warp): bilinear fetch of last frame's A_acc (15 ch, 4 vec4) and o
//    (3 ch, 1 vec4) at prev_pos = pixel centre + motion; a prev_pos outside the image or a
//    non-finite motion is invalid (taps beyond the edge are clamped);
// 2. (rescale != 0, config exposure "channel") the log channels e (0..2) and
//    log1p(shadow) (9..11) of W(A_acc), and W(o), re-expressed in this frame's exposure,
//    v -> ln(1 + (exp(v) - 1) ratio) for v > 0 (kept for v <= 0), at most LOG_MAX;
// 3. (geometry != 0, config history "geometry") valid &= |W(depth_acc) - depth| <= 0.2 depth
//    and |W(normal_acc) - normal|^2 <= 0.25;
// invalid history is 0, and warp_valid.x says which is which. The same arithmetic as the
// three passes it replaces (training/ssr/model.py `SSRModel.history`).
// A_t layout (pack_inputs): vec4 0 = (e.rgb, albedo.r), 1 = (albedo.gb, n.xy),
// 2 = (n.z, log1p(shadow).rgb), 3 = (depth, metallic, roughness, 0).
// Last frame's A_acc and o, and W(A_acc), are stored as f32 or f16 (nn/lib/storage: In0,
// In1, Out; f32 arithmetic); the other tensors as f32.

struct Params {
    width: u32,
    height: u32,
    rescale: u32,
    geometry: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> a_acc_prev: array<In0>;
@group(0) @binding(2) var<storage, read> o_prev: array<In1>;
@group(0) @binding(3) var<storage, read> motion: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> a_t: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read> ratio: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> warp_acc: array<Out>;
@group(0) @binding(7) var<storage, read_write> warp_out: array<vec4<f32>>;
@group(0) @binding(8) var<storage, read_write> warp_valid: array<vec4<f32>>;

const DEPTH_TOL: f32 = 0.2;
const NORMAL_TOL: f32 = 0.25;
const LOG_MAX: f32 = 88.0;

fn rescale_log(v: vec3<f32>, r: vec3<f32>) -> vec3<f32> {
    let scaled = min(log(vec3<f32>(1.0) + (exp(v) - vec3<f32>(1.0)) * r), vec3<f32>(LOG_MAX));
    return select(v, scaled, v > vec3<f32>(0.0));
}

// Channel vec4 `c` of W(A_acc) at the taps `k` (Taps: nn/lib/warp).
fn acc_tap(k: Taps, c: u32) -> vec4<f32> {
    let a = vec4<f32>(a_acc_prev[4u * k.i00 + c]);
    let b = vec4<f32>(a_acc_prev[4u * k.i10 + c]);
    let d = vec4<f32>(a_acc_prev[4u * k.i01 + c]);
    let e = vec4<f32>(a_acc_prev[4u * k.i11 + c]);
    return bilinear(a, b, d, e, k.t);
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let pix = pixel_index(gid, p.width, p.height);
    if (pix == OUTSIDE) {
        return;
    }
    let k = warp_taps(gid.x, gid.y, motion[pix].xy, p.width, p.height);
    var ok = k.valid;
    var h0 = vec4<f32>(0.0);
    var h1 = vec4<f32>(0.0);
    var h2 = vec4<f32>(0.0);
    var h3 = vec4<f32>(0.0);
    var wo = vec4<f32>(0.0);
    if (ok) {
        h0 = acc_tap(k, 0u);
        h1 = acc_tap(k, 1u);
        h2 = acc_tap(k, 2u);
        h3 = acc_tap(k, 3u);
        wo = bilinear(
            vec4<f32>(o_prev[k.i00]), vec4<f32>(o_prev[k.i10]), vec4<f32>(o_prev[k.i01]), vec4<f32>(o_prev[k.i11]), k.t,
        );
    }
    if (p.rescale != 0u) {
        let r = ratio[0].xyz;
        h0 = vec4<f32>(rescale_log(h0.xyz, r), h0.w);
        h2 = vec4<f32>(h2.x, rescale_log(h2.yzw, vec3<f32>(ratio[0].w, ratio[1].xy)));
        wo = vec4<f32>(rescale_log(wo.xyz, r), wo.w);
    }
    if (p.geometry != 0u) {
        let c1 = a_t[4u * pix + 1u];
        let c2 = a_t[4u * pix + 2u];
        let d = a_t[4u * pix + 3u].x;
        let dn = vec3<f32>(h1.z, h1.w, h2.x) - vec3<f32>(c1.z, c1.w, c2.x);
        ok = ok && abs(h3.x - d) <= DEPTH_TOL * d && dot(dn, dn) <= NORMAL_TOL;
    }
    if (!ok) {
        h0 = vec4<f32>(0.0);
        h1 = vec4<f32>(0.0);
        h2 = vec4<f32>(0.0);
        h3 = vec4<f32>(0.0);
        wo = vec4<f32>(0.0);
    }
    warp_acc[4u * pix] = to_out(h0);
    warp_acc[4u * pix + 1u] = to_out(h1);
    warp_acc[4u * pix + 2u] = to_out(h2);
    warp_acc[4u * pix + 3u] = to_out(h3);
    warp_out[pix] = wo;
    warp_valid[pix] = vec4<f32>(select(0.0, 1.0, ok), 0.0, 0.0, 0.0);
}
