// 2x resampling as a pass of its own, NHWC vec4 tensors: 2x2 pooling (max or average;
// the output is ceil(w/2) x ceil(h/2), windows clipped to the input, the average taken
// over the pixels inside) or 2x upsampling (nearest or bilinear, PyTorch
// `interpolate(scale_factor=2, align_corners=False)`; the output is normally 2w x 2h,
// source coordinates clamped to the input). The arithmetic is nn/lib/fetch's, which the
// convolutions also use to resample their inputs on load: FETCH0 picks the operation
// (1 nearest, 2 bilinear upsampling, 3 max, 4 average pooling). Input and output are
// stored as f32 or f16 (nn/lib/storage: In0, Out).
//
//#param N_IN 1

struct Params {
    width: u32,   // output size
    height: u32,
    c4: u32,      // vec4s per pixel of input and output
    _pad: u32,
    src: array<vec4<u32>, 4>, // xy: the input's size (element 0)
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> in0: array<In0>;
@group(0) @binding(2) var<storage, read_write> dst: array<Out>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= p.width || gid.y >= p.height) {
        return;
    }
    let o = (gid.y * p.width + gid.x) * p.c4;
    for (var c = 0u; c < p.c4; c++) {
        dst[o + c] = to_out(load0(gid.x, gid.y, p.c4, c));
    }
}
