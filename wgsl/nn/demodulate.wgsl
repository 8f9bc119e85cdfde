// Demodulation + log (DESIGN §3): e = ln(1 + color / (albedo + 0.00316)), per channel of
// the first 3 channels of `color` and `albedo`. Negative or non-finite colour counts as 0;
// albedo is clamped to [0, inf). Output: 3 channels (padded to 4, the 4th is 0).

// Params, EPS and albedo3: nn/lib/modulation.wgsl. `color` and `albedo` are stored as f32
// or f16 (nn/lib/storage: In0, In1; f32 arithmetic), the output as f32.

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> color: array<In0>;
@group(0) @binding(2) var<storage, read> albedo: array<In1>;
@group(0) @binding(3) var<storage, read_write> dst: array<vec4<f32>>;

fn clean(v: vec3<f32>) -> vec3<f32> {
    // NaN fails the comparison and becomes 0; +Inf fails the bound too.
    return select(vec3<f32>(0.0), v, v >= vec3<f32>(0.0) & v <= vec3<f32>(3.0e38));
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let pix = pixel_index(gid, p.width, p.height);
    if (pix == OUTSIDE) {
        return;
    }
    let c = clean(vec4<f32>(color[pix * p.src_c4]).xyz);
    let a = clean(albedo3(pix));
    dst[pix] = vec4<f32>(log(vec3<f32>(1.0) + c / (a + vec3<f32>(EPS))), 0.0);
}
