// The second half of the input packing (ssr/pack_inputs builds A_t): at the padded size
// Wp x Hp (pixels beyond W x H replicate the edge),
//   MT (4 ch)     = [mask, transparent(3)]
//   motion (2 ch) = caller motion
// sanitised as in ssr/lib/sanitize; the changed transparent and motion values are counted
// in `sanitized` (inside W x H; the mask is counted by ssr/pack_inputs).

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> color_mask: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> transparent: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> motion: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> mt: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> motion_out: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> sanitized: array<atomic<u32>>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (outside_padded(gid)) {
        return;
    }
    let src = source_pixel(gid);
    var counted_elsewhere = 0u;
    let mask = sanitize_mask(color_mask[src].w, &counted_elsewhere);
    var bad = 0u;
    let tint = sanitize_unit(transparent[src].xyz, &bad);
    let mv = motion[src].xy;
    let m = vec2<f32>(finite_or_zero(mv.x, &bad), finite_or_zero(mv.y, &bad));
    count_sanitized(gid, bad);
    let dst = padded_pixel(gid);
    mt[dst] = vec4<f32>(mask, tint);
    motion_out[dst] = vec4<f32>(m, 0.0, 0.0);
}
