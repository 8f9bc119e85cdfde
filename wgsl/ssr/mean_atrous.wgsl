// One level of the mean correction's edge-aware filter (config `mean_correction = "atrous"`,
// issue 11; reference src/nn/reference.rs `mean_atrous_factors`): each invocation takes one
// pixel of the W x H frame and averages the (samples, reconstruction) sums of ssr/mean_history
// (textures `src_s`, `src_r`) over the 5 x 5 taps `p.step` pixels apart, each weighted by the
// B-spline (1, 4, 6, 4, 1) / 16 per axis and by how well the tap's surface agrees with the
// pixel's:
//   max(n . n_q, 0)^(2^SQUARINGS) x exp(-|z - z_q| / max(z, z_q, 1e-4) / DEPTH_SIGMA)
// (n, z the sanitised normal and normalised depth that ssr/mean_history left in `guide`),
// normalised by the weights' sum (at least 1e-12). Taps outside the frame count 0. The
// denoiser runs ATROUS_LEVELS levels, steps 1, 2, 4, ...: without the template flag FINAL a
// level writes the averaged sums to the storage textures `dst_s`, `dst_r` for the next; with
// it, the last writes each pixel's factor, per channel
//   clamp((S + EPS) / (R + EPS), LO, HI),
// to `factors` (1 vec4 per pixel, w = 1), which store_output applies (as tiles of one pixel).
// Every tap is a texel fetch (see ssr/mean_history).
//
//#param FINAL 0

struct AtrousParams {
    width: u32,
    height: u32,
    step: u32,
    _pad: u32,
}

@group(0) @binding(0) var<uniform> p: AtrousParams;
@group(0) @binding(1) var src_s: texture_2d<f32>;
@group(0) @binding(2) var src_r: texture_2d<f32>;
@group(0) @binding(3) var guide: texture_2d<f32>;
//#if FINAL
@group(0) @binding(4) var<storage, read_write> factors: array<vec4<f32>>;
//#else
@group(0) @binding(4) var dst_s: texture_storage_2d<rgba32float, write>;
@group(0) @binding(5) var dst_r: texture_storage_2d<rgba32float, write>;
//#end

// Set by the denoiser from src/ssr/config.rs (ATROUS_NORMAL_SQUARINGS, ATROUS_DEPTH_SIGMA,
// ATROUS_EPS, MEAN_LO, MEAN_HI).
override SQUARINGS: u32 = 3u;
override DEPTH_SIGMA: f32 = 0.2;
override EPS: f32 = 3.90625e-7;
override LO: f32 = 0.67;
override HI: f32 = 1.5;

// The B-spline's taps: 1/16, 1/4, 3/8, 1/4, 1/16.
const TAPS = array<f32, 5>(0.0625, 0.25, 0.375, 0.25, 0.0625);

// Straight-line code (template repeats, not loops: lavapipe does not unroll) without
// branches: a tap outside the frame reads the nearest pixel inside it with weight 0.
@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= p.width || gid.y >= p.height) {
        return;
    }
    let g = textureLoad(guide, gid.xy, 0);
    let n = g.xyz;
    let z = g.w;
    let step = i32(p.step);
    let w_max = i32(p.width) - 1;
    let h_max = i32(p.height) - 1;
    var acc_s = vec4<f32>(0.0);
    var acc_r = vec4<f32>(0.0);
    var sum = 0.0;
//#repeat j 5
    {
        let qy = i32(gid.y) + (i32({j}) - 2) * step;
        let row = clamp(qy, 0, h_max);
        let in_y = qy >= 0 && qy <= h_max;
//#repeat i 5
        {
            let qx = i32(gid.x) + (i32({i}) - 2) * step;
            let q = vec2<i32>(clamp(qx, 0, w_max), row);
            let gq = textureLoad(guide, q, 0);
            let zq = gq.w;
            var c = max(dot(n, gq.xyz), 0.0);
            for (var k = 0u; k < SQUARINGS; k++) {
                c *= c;
            }
            let rel = abs(z - zq) / max(max(z, zq), 1.0e-4);
            let inside = in_y && qx >= 0 && qx <= w_max;
            let w = select(0.0, TAPS[{j}] * TAPS[{i}] * c * exp(-rel / DEPTH_SIGMA), inside);
            acc_s += w * textureLoad(src_s, q, 0);
            acc_r += w * textureLoad(src_r, q, 0);
            sum += w;
        }
//#end
    }
//#end
    let norm = 1.0 / max(sum, 1.0e-12);
//#if FINAL
    let f = clamp((acc_s.xyz * norm + EPS) / (acc_r.xyz * norm + EPS), vec3<f32>(LO), vec3<f32>(HI));
    factors[gid.y * p.width + gid.x] = vec4<f32>(f, 1.0);
//#else
    textureStore(dst_s, gid.xy, acc_s * norm);
    textureStore(dst_r, gid.xy, acc_r * norm);
//#end
}
