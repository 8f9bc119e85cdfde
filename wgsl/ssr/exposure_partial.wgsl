// Exposure statistic, pass 1 of 2 (issue 11; training/ssr/model.py `_log_exposure`):
// per channel c, the sum of ln d_c and the count over the traced pixels (mask > 0.5) with
// d_c > 0, for d = color / (albedo + 0.00316) and for d = shadow (the inputs sanitised as
// pack_inputs does, ssr/lib/sanitize, without counting); and per channel the max over the
// traced pixels of the colour's d (the output ceiling's m_t; 0 with nothing traced). The
// pixels are those of the padded Wp x Hp frame the network sees (beyond W x H the edge is
// replicated, as pack_inputs does). Each workgroup strides over the pixels and writes one
// partial of 4 vec4: (sum ln d).rgb and count.rgb of the colour, then of the shadow; the w
// of the first three hold the max of the colour's d.r, d.g, d.b. exposure_final.wgsl
// combines the partials.

struct Params {
    width: u32,
    height: u32,
    padded_width: u32,
    padded_height: u32,
    groups: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> color_mask: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> albedo_depth: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> shadow_roughness: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> partials: array<vec4<f32>>;

const EPS: f32 = 0.00316;
const WG: u32 = 256u;

var<workgroup> color_sums: array<vec4<f32>, 256>;
var<workgroup> color_counts: array<vec4<f32>, 256>;
var<workgroup> shadow_sums: array<vec4<f32>, 256>;
var<workgroup> shadow_counts: array<vec4<f32>, 256>;

// ln d where it counts (d > 0 on a traced pixel), else 0; and the count.
fn ln_where(d: vec3<f32>, traced: bool) -> array<vec3<f32>, 2> {
    let use_it = vec3<bool>(traced) & (d > vec3<f32>(0.0));
    return array<vec3<f32>, 2>(
        select(vec3<f32>(0.0), log(select(vec3<f32>(1.0), d, use_it)), use_it),
        select(vec3<f32>(0.0), vec3<f32>(1.0), use_it),
    );
}

// sum_max: ssr/lib/exposure.wgsl.

@compute @workgroup_size(256, 1, 1)
fn main(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let n = p.padded_width * p.padded_height;
    var cs = vec3<f32>(0.0);
    var ck = vec3<f32>(0.0);
    var ss = vec3<f32>(0.0);
    var sk = vec3<f32>(0.0);
    var mx = vec3<f32>(0.0);
    for (var i = wid.x * WG + lid.x; i < n; i += p.groups * WG) {
        let x = i % p.padded_width;
        let y = i / p.padded_width;
        let src = min(y, p.height - 1u) * p.width + min(x, p.width - 1u);
        var ignored = 0u;
        let cm = color_mask[src];
        let traced = sanitize_mask(cm.w, &ignored) > 0.5;
        let a = sanitize_unit(albedo_depth[src].xyz, &ignored);
        let color = sanitize_radiance(cm.xyz, &ignored);
        let d = color / (a + vec3<f32>(EPS));
        let c = ln_where(d, traced);
        mx = select(mx, max(mx, d), traced);
        let s = ln_where(sanitize_radiance(shadow_roughness[src].xyz, &ignored), traced);
        cs += c[0];
        ck += c[1];
        ss += s[0];
        sk += s[1];
    }
    color_sums[lid.x] = vec4<f32>(cs, mx.x);
    color_counts[lid.x] = vec4<f32>(ck, mx.y);
    shadow_sums[lid.x] = vec4<f32>(ss, mx.z);
    shadow_counts[lid.x] = vec4<f32>(sk, 0.0);
    workgroupBarrier();
    for (var stride = WG / 2u; stride > 0u; stride /= 2u) {
        if (lid.x < stride) {
            color_sums[lid.x] = sum_max(color_sums[lid.x], color_sums[lid.x + stride]);
            color_counts[lid.x] = sum_max(color_counts[lid.x], color_counts[lid.x + stride]);
            shadow_sums[lid.x] = sum_max(shadow_sums[lid.x], shadow_sums[lid.x + stride]);
            shadow_counts[lid.x] += shadow_counts[lid.x + stride];
        }
        workgroupBarrier();
    }
    if (lid.x == 0u) {
        partials[4u * wid.x] = color_sums[0];
        partials[4u * wid.x + 1u] = color_counts[0];
        partials[4u * wid.x + 2u] = shadow_sums[0];
        partials[4u * wid.x + 3u] = shadow_counts[0];
    }
}
