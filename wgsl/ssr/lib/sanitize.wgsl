// Input sanitising shared by the kernels that read the caller's frame buffers (issue 12):
// every channel is brought into the range of the data contract (DESIGN §3) and every value
// changed is counted in `*bad`:
//   colour, shadow: finite and in [0, RADIANCE_MAX];   mask: 0 or 1 (> 0.5 is 1);
//   albedo, transparent, depth, metallic, roughness: [0, 1];
//   normal: unit length within NORMAL_TOL, or 0 (sky); one with a non-finite component is 0;
//   motion: finite.
// Non-finite values become 0 (NaN fails every comparison; +-Inf fails the F32_MAX bound);
// finite ones outside their range are clamped to it. In-range values pass unchanged.

const F32_MAX: f32 = 3.40282347e38;
// Far above any radiance a renderer feeds a denoiser, low enough that the demodulated,
// exposure-normalised logs stay far from f32 overflow.
const RADIANCE_MAX: f32 = 1.0e12;
const NORMAL_TOL: f32 = 0.05;

fn finite_or_zero(v: f32, bad: ptr<function, u32>) -> f32 {
    if (abs(v) <= F32_MAX) {
        return v;
    }
    *bad += 1u;
    return 0.0;
}

// `v` clamped to [lo, hi] (lo <= 0 <= hi); non-finite values become 0.
fn in_range(v: f32, lo: f32, hi: f32, bad: ptr<function, u32>) -> f32 {
    if (v >= lo && v <= hi) {
        return v;
    }
    *bad += 1u;
    return select(0.0, clamp(v, lo, hi), abs(v) <= F32_MAX);
}

fn in_range3(v: vec3<f32>, lo: f32, hi: f32, bad: ptr<function, u32>) -> vec3<f32> {
    return vec3<f32>(in_range(v.x, lo, hi, bad), in_range(v.y, lo, hi, bad), in_range(v.z, lo, hi, bad));
}

fn sanitize_mask(m: f32, bad: ptr<function, u32>) -> f32 {
    if (m == 0.0 || m == 1.0) {
        return m;
    }
    *bad += 1u;
    return select(0.0, 1.0, m > 0.5 && m <= F32_MAX);
}

fn sanitize_radiance(v: vec3<f32>, bad: ptr<function, u32>) -> vec3<f32> {
    return in_range3(v, 0.0, RADIANCE_MAX, bad);
}

fn sanitize_unit(v: vec3<f32>, bad: ptr<function, u32>) -> vec3<f32> {
    return in_range3(v, 0.0, 1.0, bad);
}

fn sanitize_normal(n: vec3<f32>, bad: ptr<function, u32>) -> vec3<f32> {
    let fin = abs(n) <= vec3<f32>(F32_MAX);
    if (!all(fin)) {
        *bad += u32(!fin.x) + u32(!fin.y) + u32(!fin.z);
        return vec3<f32>(0.0);
    }
    let m = max(max(abs(n.x), abs(n.y)), abs(n.z));
    if (m == 0.0) {
        return n;
    }
    // Scaled by the largest component first, so huge or tiny normals neither overflow
    // nor underflow.
    let u = n / m;
    let lu = length(u);
    if (abs(lu * m - 1.0) <= NORMAL_TOL) {
        return n;
    }
    *bad += 1u;
    return u / lu;
}
