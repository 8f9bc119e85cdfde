// The warped history, made ready for the TFA and the U-Net (training/ssr/model.py
// `SSRModel.history`), in place on W(A_acc) (15 ch), W(o) (3 ch) and the warp validity:
//   rescale (config exposure "channel"): the log channels e (0..2) and log1p(shadow) (9..11)
//     of W(A_acc) and W(o) are re-expressed in this frame's exposure,
//     v -> ln(1 + (exp(v) - 1) ratio) for v > 0 (kept for v <= 0), ratio = s_prev / s
//     (a 1x1x6 tensor: colour rgb for e and W(o), then shadow rgb), at most LOG_MAX (a
//     guard against hostile input, issue 12: exp of a huge history overflows to +Inf);
//   geometry (config history "geometry"): valid &= |W(depth_acc) - depth| <= 0.2 depth and
//     |W(normal_acc) - normal|^2 <= 0.25; invalid history is 0 (as an off-screen sample).
// A_t layout (pack_inputs): vec4 0 = (e.rgb, albedo.r), 1 = (albedo.gb, n.xy),
// 2 = (n.z, log1p(shadow).rgb), 3 = (depth, metallic, roughness, 0).

struct Params {
    width: u32,
    height: u32,
    rescale: u32,
    geometry: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> a_t: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> warp_acc: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> warp_out: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> warp_valid: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read> ratio: array<vec4<f32>>;

const DEPTH_TOL: f32 = 0.2;
const NORMAL_TOL: f32 = 0.25;
const LOG_MAX: f32 = 88.0;

fn rescale_log(v: vec3<f32>, r: vec3<f32>) -> vec3<f32> {
    let scaled = min(log(vec3<f32>(1.0) + (exp(v) - vec3<f32>(1.0)) * r), vec3<f32>(LOG_MAX));
    return select(v, scaled, v > vec3<f32>(0.0));
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= p.width || gid.y >= p.height) {
        return;
    }
    let pix = gid.y * p.width + gid.x;
    var h0 = warp_acc[4u * pix];
    var h1 = warp_acc[4u * pix + 1u];
    var h2 = warp_acc[4u * pix + 2u];
    var h3 = warp_acc[4u * pix + 3u];
    var wo = warp_out[pix];
    if (p.rescale != 0u) {
        let r = ratio[0].xyz;
        h0 = vec4<f32>(rescale_log(h0.xyz, r), h0.w);
        h2 = vec4<f32>(h2.x, rescale_log(h2.yzw, vec3<f32>(ratio[0].w, ratio[1].xy)));
        wo = vec4<f32>(rescale_log(wo.xyz, r), wo.w);
    }
    var ok = warp_valid[pix].x > 0.5;
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
    warp_acc[4u * pix] = h0;
    warp_acc[4u * pix + 1u] = h1;
    warp_acc[4u * pix + 2u] = h2;
    warp_acc[4u * pix + 3u] = h3;
    warp_out[pix] = wo;
    warp_valid[pix] = vec4<f32>(select(0.0, 1.0, ok), 0.0, 0.0, 0.0);
}
