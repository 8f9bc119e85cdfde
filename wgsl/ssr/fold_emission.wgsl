// The colour a model of config emission = "background" is fed (DESIGN §3, the directly seen
// emission): the traced radiance without each traced sample's first-hit emission (at least
// 0; the mask kept). The output pass adds the first-hit emission averaged over the pixel's
// footprint instead (ssr/store_output, EMISSION), so the network reconstructs only
// reflected light. CPU reference: HostFrame::fold_direct_emission (src/frame/host.rs).

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
    folded_color_mask[pix] = vec4<f32>(max(c.xyz - sample_emission[pix].xyz, vec3<f32>(0.0)), c.w);
}
