// A tensor copied into a texture array for the convolutions that read their inputs as
// textures (issue 14; template flag TEX_IN of nn/conv3x3_blocked and nn/conv3x3_winograd,
// nn/lib/fetch): each invocation copies channel vec4 `gid.z` of pixel (gid.x, gid.y) of the
// `width x height` tensor `src` (`c4` vec4s per pixel, stored as f32 or f16: nn/lib/storage
// In0) to layer `gid.z` of `dst` (rgba32float, exact for both). On a CPU driver (llvmpipe)
// a storage-buffer load whose address differs per lane runs lane by lane with a bounds
// check each, a texel fetch vectorised: one such load per vec4 here saves the convolution
// its three or more per vec4 (every input vec4 serves three rows of taps).

struct Params {
    width: u32,
    height: u32,
    c4: u32,
    _pad: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> src: array<In0>;
@group(0) @binding(2) var dst: texture_storage_2d_array<rgba32float, write>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= p.width || gid.y >= p.height || gid.z >= p.c4) {
        return;
    }
    let v = vec4<f32>(src[(gid.y * p.width + gid.x) * p.c4 + gid.z]);
    textureStore(dst, gid.xy, gid.z, v);
}
