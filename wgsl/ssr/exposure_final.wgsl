// Exposure statistic, pass 2 of 2 (training/ssr/model.py `update_exposure`): adds up the
// partials of exposure_partial.wgsl and updates the exposure s, per channel, of the colour
// (vec4 0) and of the shadow (vec4 1):
//   have = count > 0, lg = sum / count                    (ln of the geometric mean)
//   first frame:  s = exp(have ? lg : 0)
//   later:        lp = ln(s_prev), d = lg - lp,
//                 s = exp(have ? (|d| > JUMP ? lg : lp + RATE d) : lp)   (JUMP = ln 2)
//   ratio = s_prev / s (1 on a first frame): history.wgsl re-exposes the history with it.
// and, per colour channel, the output ceiling's running max M of the demodulated colour
// samples (the max of the partials' m): first frame M = m, later M = max(m, p.decay M_prev).
// ln s is clamped to [-LN_S_MAX, LN_S_MAX] (a guard against hostile input, issue 12: far
// beyond any real frame's exposure, it keeps s, 1/s and the ratio finite and non-zero).
// `exposure` holds (s_prev, M_prev) on entry and (s, M) on exit, a 1x1x9 tensor packed in 3
// vec4: (colour.rgb, shadow.r), (shadow.gb, M.rg), (M.b, 0, 0, 0); `ratio` the ratio, 1x1x6
// in 2 vec4 likewise. With SHARED (config exposure "shared"), one exposure per buffer: the
// sums and counts of a buffer's three channels are pooled before the mean, so its three
// channels get the same s (the running max stays per channel).
//
//#param SHARED 0

struct Params {
    groups: u32,
    first: u32,
    decay: f32, // of the running max: src/ssr/config.rs CEILING_DECAY
    _pad0: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> partials: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> exposure: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> ratio: array<vec4<f32>>;

const RATE: f32 = 0.1;
const JUMP: f32 = 0.6931471805599453;
const WG: u32 = 64u;
const LN_S_MAX: f32 = 30.0;

// [colour sum, colour count, shadow sum, shadow count] per thread (w of the first three: the
// colour's max per channel), then tree-reduced.
var<workgroup> acc: array<array<vec4<f32>, 4>, 64>;

// combine: ssr/lib/exposure.wgsl.

@compute @workgroup_size(64, 1, 1)
fn main(@builtin(local_invocation_id) lid: vec3<u32>) {
    var a = array<vec4<f32>, 4>(vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0));
    for (var g = lid.x; g < p.groups; g += WG) {
        let i = 4u * g;
        a = combine(a, array<vec4<f32>, 4>(partials[i], partials[i + 1u], partials[i + 2u], partials[i + 3u]));
    }
    acc[lid.x] = a;
    workgroupBarrier();
    for (var stride = WG / 2u; stride > 0u; stride /= 2u) {
        if (lid.x < stride) {
            acc[lid.x] = combine(acc[lid.x], acc[lid.x + stride]);
        }
        workgroupBarrier();
    }
    if (lid.x == 0u) {
        let e0 = exposure[0];
        let e1 = exposure[1];
        let c = update(acc[0][0].xyz, acc[0][1].xyz, e0.xyz);
        let s = update(acc[0][2].xyz, acc[0][3].xyz, vec3<f32>(e0.w, e1.xy));
        let m = vec3<f32>(acc[0][0].w, acc[0][1].w, acc[0][2].w);
        let m_prev = vec3<f32>(e1.zw, exposure[2].x);
        let running = select(max(m, p.decay * m_prev), m, p.first != 0u);
        exposure[0] = vec4<f32>(c[0], s[0].x);
        exposure[1] = vec4<f32>(s[0].yz, running.xy);
        exposure[2] = vec4<f32>(running.z, 0.0, 0.0, 0.0);
        ratio[0] = vec4<f32>(c[1], s[1].x);
        ratio[1] = vec4<f32>(s[1].yz, 0.0, 0.0);
    }
}

// (s, s_prev / s) from the sums of ln d, the counts and s_prev.
fn update(channel_sum: vec3<f32>, channel_count: vec3<f32>, prev: vec3<f32>) -> array<vec3<f32>, 2> {
    var sum = channel_sum;
    var count = channel_count;
//#if SHARED
    sum = vec3<f32>(sum.x + sum.y + sum.z);
    count = vec3<f32>(count.x + count.y + count.z);
//#end
    let have = count > vec3<f32>(0.0);
    let mean = sum / max(count, vec3<f32>(1.0));
    // NaN fails the comparison (it cannot arise from sanitised inputs; belt and braces).
    let lg = select(vec3<f32>(0.0), clamp(mean, vec3<f32>(-LN_S_MAX), vec3<f32>(LN_S_MAX)), have & (abs(mean) <= vec3<f32>(3.0e38)));
    if (p.first != 0u) {
        return array<vec3<f32>, 2>(exp(lg), vec3<f32>(1.0));
    }
    let lp = clamp(log(prev), vec3<f32>(-LN_S_MAX), vec3<f32>(LN_S_MAX));
    let d = lg - lp;
    let eased = select(lp + RATE * d, lg, abs(d) > vec3<f32>(JUMP));
    let s_new = exp(select(lp, eased, have));
    return array<vec3<f32>, 2>(s_new, prev / s_new);
}
