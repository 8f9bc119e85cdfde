// What the specialised convolutions (nn/conv3x3_blocked, nn/conv3x3_coop) share: the layer's
// shape and activation as override constants, their parameter block (only the image size
// and the stored size of each input, which nn/lib/fetch reads, are runtime values), and the
// activation. A kernel including this library declares `p: Params` at binding 0.

override CIN4_0: u32 = 1u;  // padded channels / 4 of each input (inputs N_IN.. unused)
override CIN4_1: u32 = 1u;
override CIN4_2: u32 = 1u;
override CIN4_3: u32 = 1u;
override COUT4: u32 = 1u;   // padded output channels / 4 (the output tensor's stride)
override ACT: u32 = 0u;     // 0 none, 1 relu, 2 leaky relu
override SLOPE: f32 = 0.0;  // leaky relu slope

struct Params {
    width: u32,
    height: u32,
    _pad0: u32,
    _pad1: u32,
    src: array<vec4<u32>, 4>, // xy: the stored size of each input
}

// The layer's activation of a vec4 of sums.
fn activate(acc: vec4<f32>) -> vec4<f32> {
    if (ACT == 1u) {
        return max(acc, vec4<f32>(0.0));
    }
    if (ACT == 2u) {
        return select(acc * SLOPE, acc, acc >= vec4<f32>(0.0));
    }
    return acc;
}
