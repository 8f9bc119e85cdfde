// Shared by demodulate and remodulate: their parameter block, the albedo offset EPS of
// DESIGN §3, and the albedo read. `albedo3` reads the entry file's bindings `p` (Params)
// and `albedo` (WGSL resolves module-scope names in any order).

struct Params {
    width: u32,
    height: u32,
    src_c4: u32,        // vec4s per pixel of the first input (color or o)
    albedo_c4: u32,
    albedo_offset: u32, // first albedo channel
    ceiling: f32,       // remodulate with CEILING: the output ceiling's gain
    _pad1: u32,
    _pad2: u32,
}

const EPS: f32 = 0.00316;

// Three consecutive channels of `albedo` starting at `albedo_offset` (any alignment).
fn albedo3(pix: u32) -> vec3<f32> {
    var v: vec3<f32>;
    for (var i = 0u; i < 3u; i++) {
        let c = p.albedo_offset + i;
        v[i] = f32(albedo[pix * p.albedo_c4 + c / 4u][c % 4u]);
    }
    return v;
}
