// Exp + remodulation (DESIGN §3): out = max(exp(o) - 1, 0) * (albedo + 0.00316) * scale,
// over the first 3 channels of `o` and of `albedo` from `albedo_offset` (SSR: the albedo
// that demodulated, or the accumulated one for version-1 weights); `scale` is one vec4 (rgb:
// the exposure). Output: 3 channels (padded to 4, the 4th is 0).
// Guards against hostile input (issue 12): o is taken as at most O_MAX (radiance e^50 times
// the exposure, far beyond any real pixel) and non-finite o as 0, so the output is finite.
// With template flag CEILING (SSR config `ceiling`), o is also capped at ln(1 + g M_c / s_c),
// g = p.ceiling, M = channels 6..8 of `scale` (the running max of the demodulated samples,
// exposure_final.wgsl), and the capped o is written back: it is the next frame's history.
//
//#param CEILING 0

// Params, EPS and albedo3: nn/lib/modulation.wgsl. `o` and `albedo` are stored as f32 or
// f16 (nn/lib/storage: In0, In1; f32 arithmetic), the output and `scale` as f32.

@group(0) @binding(0) var<uniform> p: Params;
//#if CEILING
@group(0) @binding(1) var<storage, read_write> o: array<In0>;
//#else
@group(0) @binding(1) var<storage, read> o: array<In0>;
//#end
@group(0) @binding(2) var<storage, read> albedo: array<In1>;
@group(0) @binding(3) var<storage, read_write> dst: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> scale: array<vec4<f32>>;

const O_MAX: f32 = 50.0;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let pix = pixel_index(gid, p.width, p.height);
    if (pix == OUTSIDE) {
        return;
    }
    let raw = vec4<f32>(o[pix * p.src_c4]);
    var e = min(select(vec3<f32>(0.0), raw.xyz, abs(raw.xyz) <= vec3<f32>(3.40282347e38)), vec3<f32>(O_MAX));
//#if CEILING
    let m = vec3<f32>(scale[1].zw, scale[2].x);
    e = min(e, log(vec3<f32>(1.0) + p.ceiling * m / scale[0].xyz));
    o[pix * p.src_c4] = In0(vec4<f32>(e, raw.w));
//#end
    let a = max(albedo3(pix), vec3<f32>(0.0));
    dst[pix] = vec4<f32>(max(exp(e) - vec3<f32>(1.0), vec3<f32>(0.0)) * (a + vec3<f32>(EPS)) * scale[0].xyz, 0.0);
}
