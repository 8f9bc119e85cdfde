// One level of the mean correction's edge-aware filter (config `mean_correction = "atrous"`,
// issue 11; reference src/nn/reference.rs `mean_atrous_factors`): for each pixel of the
// W x H frame (PX of them per invocation, below), it averages the (samples,
// reconstruction) sums of ssr/mean_history (textures `src_s`, `src_r`) over the 5 x 5 taps `p.step` pixels apart, each weighted by the
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

// Pixels per invocation: PX pixels of one row, `p.step` apart, whose taps share PX + 4
// columns, so each tap texel (guide and sums) is fetched once for all of them instead of
// once per pixel (on CPU drivers the fetches are most of the pass). Invocation x covers
// the pixels base + k step, k < PX, base = (x / step) PX step + x % step: neighbouring
// invocations take neighbouring pixels (the host dispatches ceil(W / (PX step)) step
// invocations per row). Each pixel's sums add the same terms in the same order as with one
// pixel per invocation.
//#param PX 4

// Straight-line code (template repeats, not loops: lavapipe does not unroll) without
// branches: a tap outside the frame reads the nearest pixel inside it with weight 0, and a
// pixel beyond the frame's right edge is computed like one inside but not stored.
@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let step = p.step;
    let base = (gid.x / step) * ({PX} * step) + gid.x % step;
    let y = gid.y;
    if (base >= p.width || y >= p.height) {
        return;
    }
    let w_max = i32(p.width) - 1;
    let h_max = i32(p.height) - 1;
//#repeat k PX
    let x{k} = base + {k}u * step;
    let g{k} = textureLoad(guide, vec2<u32>(min(x{k}, p.width - 1u), y), 0);
    let n{k} = g{k}.xyz;
    let z{k} = g{k}.w;
    var acc_s{k} = vec4<f32>(0.0);
    var acc_r{k} = vec4<f32>(0.0);
    var sum{k} = 0.0;
//#end
//#repeat j 5
    {
        let qy = i32(y) + (i32({j}) - 2) * i32(step);
        let row = clamp(qy, 0, h_max);
        let in_y = qy >= 0 && qy <= h_max;
        // The row's PX + 4 tap columns, each fetched once.
//#repeat m PX+4
        let qx{m} = i32(base) + (i32({m}) - 2) * i32(step);
        let q{m} = vec2<i32>(clamp(qx{m}, 0, w_max), row);
        let inside{m} = in_y && qx{m} >= 0 && qx{m} <= w_max;
        let gq{m} = textureLoad(guide, q{m}, 0);
        let s{m} = textureLoad(src_s, q{m}, 0);
        let r{m} = textureLoad(src_r, q{m}, 0);
//#end
        // Pixel k's tap i is column k + i.
//#repeat k PX
//#repeat i 5
        {
            let zq = gq{k+i}.w;
            var c = max(dot(n{k}, gq{k+i}.xyz), 0.0);
            for (var e = 0u; e < SQUARINGS; e++) {
                c *= c;
            }
            // One division per tap: the depth term's two divisors multiplied (on an H200 the
            // levels ran at about one tap per SM clock: the per-tap arithmetic bounds them).
            let rel = abs(z{k} - zq) / (max(max(z{k}, zq), 1.0e-4) * DEPTH_SIGMA);
            let w = select(0.0, TAPS[{j}] * TAPS[{i}] * c * exp(-rel), inside{k+i});
            acc_s{k} += w * s{k+i};
            acc_r{k} += w * r{k+i};
            sum{k} += w;
        }
//#end
//#end
    }
//#end
//#repeat k PX
    if (x{k} < p.width) {
        let norm = 1.0 / max(sum{k}, 1.0e-12);
//#if FINAL
        let f = clamp((acc_s{k}.xyz * norm + EPS) / (acc_r{k}.xyz * norm + EPS), vec3<f32>(LO), vec3<f32>(HI));
        factors[y * p.width + x{k}] = vec4<f32>(f, 1.0);
//#else
        textureStore(dst_s, vec2<u32>(x{k}, y), acc_s{k} * norm);
        textureStore(dst_r, vec2<u32>(x{k}, y), acc_r{k} * norm);
//#end
    }
//#end
}
