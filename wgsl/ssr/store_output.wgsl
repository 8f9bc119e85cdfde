// Writes the first 3 channels of a padded Wp x Hp tensor into the W x H output texture
// (rgba32float, alpha = 1), cropping the padding.

struct Params {
    width: u32,
    height: u32,
    padded_width: u32,
    c4: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> src: array<vec4<f32>>;
@group(0) @binding(2) var dst: texture_storage_2d<rgba32float, write>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= p.width || gid.y >= p.height) {
        return;
    }
    let v = src[(gid.y * p.padded_width + gid.x) * p.c4];
    textureStore(dst, vec2<u32>(gid.xy), vec4<f32>(v.xyz, 1.0));
}
