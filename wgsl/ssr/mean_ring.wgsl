// The mean correction's per-pixel sums (config `mean_correction = "atrous"`, issue 11;
// reference src/nn/reference.rs `mean_pixel_sums`): as ssr/tile_means, but per pixel. Each
// invocation takes one pixel of the W x H frame: where it is traced (mask > 0.5)
//   s = sample - background          (the sample's share that the network reconstructs)
//   r = (1 - coverage) x output      (the network's reconstruction of that share)
// else (0, 0), with the inputs sanitised as store_output and pack_inputs do (ssr/lib/sanitize,
// not counted here: those passes count them); without the template flag BACKGROUND,
// background and coverage are 0. It writes (s, r) to this frame's slot of the ring (MEAN_RING
// = 4 slots of W x H pixels, 2 vec4 per pixel, one buffer each, so that each fits a storage
// binding at 1080p: the denoiser binds this frame's as `ring_now` and the other three after
// it); on the first frame after a reset (`p.first`) it clears the other slots. The sums
// over the ring go to `sums` (2 vec4 per pixel), which ssr/mean_atrous filters into the
// factors.
//
//#param BACKGROUND 0

// Params: ssr/lib/output (`tiles_x`, `tiles_y` and `slot` unused).

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> src: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> color_mask: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> ring_now: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> ring_a: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> ring_b: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> ring_c: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read_write> sums: array<vec4<f32>>;
//#if BACKGROUND
@group(0) @binding(8) var<storage, read> background: array<vec4<f32>>;
//#end

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= p.width || gid.y >= p.height) {
        return;
    }
    let x = gid.x;
    let y = gid.y;
    let at = y * p.width + x;
    var s = vec3<f32>(0.0);
    var r = vec3<f32>(0.0);
    var ignored = 0u;
    let cm = color_mask[at];
    if (sanitize_mask(cm.w, &ignored) > 0.5) {
        r = src[(y * p.padded_width + x) * p.c4].xyz;
        s = sanitize_radiance(cm.xyz, &ignored);
//#if BACKGROUND
        let b = background[at];
        let coverage = in_range(b.w, 0.0, 1.0, &ignored);
        s -= sanitize_radiance(b.xyz, &ignored);
        r *= 1.0 - coverage;
//#end
    }
    let i = 2u * at;
    var total_s = vec4<f32>(s, 0.0);
    var total_r = vec4<f32>(r, 0.0);
    ring_now[i] = total_s;
    ring_now[i + 1u] = total_r;
    if (p.first != 0u) {
        ring_a[i] = vec4<f32>(0.0);
        ring_a[i + 1u] = vec4<f32>(0.0);
        ring_b[i] = vec4<f32>(0.0);
        ring_b[i + 1u] = vec4<f32>(0.0);
        ring_c[i] = vec4<f32>(0.0);
        ring_c[i + 1u] = vec4<f32>(0.0);
    } else {
        total_s += ring_a[i] + ring_b[i] + ring_c[i];
        total_r += ring_a[i + 1u] + ring_b[i + 1u] + ring_c[i + 1u];
    }
    sums[i] = total_s;
    sums[i + 1u] = total_r;
}
