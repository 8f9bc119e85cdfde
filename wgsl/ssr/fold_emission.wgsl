// The colour a model of config emission = "background" or escaped = "background" is fed
// (DESIGN §3, the directly seen emission): with EMISSION, the traced radiance without each
// traced sample's first-hit emission (at least 0; the mask kept): the output pass adds the
// first-hit emission averaged over the pixel's footprint instead (ssr/store_output,
// EMISSION), so the network reconstructs only reflected light; with ESCAPED, a traced
// pixel at least half of whose samples escaped to the environment (sample_emission.w) left
// out (colour and mask 0, as an untraced pixel): the background holds the environment it
// saw, and the network reconstructs the part of each footprint that hits the scene. CPU
// reference: HostFrame::fold_directly_seen (src/frame/host.rs). Both are template
// parameters: no uniform value steers a branch.
//
//#param EMISSION 1
//#param ESCAPED 0

struct Params {
    width: u32,
    height: u32,
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> color_mask: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> sample_emission: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> folded_color_mask: array<vec4<f32>>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let pix = pixel_index(gid, p.width, p.height);
    if (pix == OUTSIDE) {
        return;
    }
    let c = color_mask[pix];
    let e = sample_emission[pix];
    var out = c;
//#if EMISSION
    out = vec4<f32>(max(c.xyz - e.xyz, vec3<f32>(0.0)), c.w);
//#end
//#if ESCAPED
    if (e.w >= 0.5) {
        out = vec4<f32>(0.0);
    }
//#end
    folded_color_mask[pix] = out;
}
