// 3x3 convolution, stride 1, zero padding, bias, activation.
// Reads its input from up to 4 NHWC tensors as if they were concatenated along channels.
// Tensors: array<vec4<f32>>, channels padded to a multiple of 4 (padding is zero).
// Weights: packed [tap(9)][ci4 (over the concatenated padded inputs)][co4][4 columns],
// column k of block (ci4, co4) holds the weights of input channel 4*ci4+k for output
// channels 4*co4..4*co4+3. Each invocation computes one pixel and up to 4 output vec4s
// (16 channels); global_id.z selects the 16-channel block.
// Outputs are kept finite (issue 12; nn/lib/storage's to_out): a non-finite sum (from
// hostile weights or inputs) becomes 0 and finite ones are clamped far beyond any real
// activation, so that the layers after it (sums of 9 Cin products, dot products in the
// TFA) cannot overflow either. Each input and the output are stored as f32 or f16
// (nn/lib/storage); the sums are f32. Each input may be read resampled 2x (nn/lib/fetch:
// override FETCHk, its stored size in `src`), so a layer reads the pooled or upsampled
// tensor of the level beside it without a pass that stores it.
//
//#param N_IN 4

struct Params {
    width: u32,
    height: u32,
    n_inputs: u32,
    cout4: u32,
    cin4: vec4<u32>,      // padded channel count / 4 of each input
    cin4_total: u32,
    act: u32,             // 0 none, 1 relu, 2 leaky relu
    slope: f32,
    _pad: u32,
    src: array<vec4<u32>, 4>, // xy: the stored size of each input
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> in0: array<In0>;
@group(0) @binding(2) var<storage, read> in1: array<In1>;
@group(0) @binding(3) var<storage, read> in2: array<In2>;
@group(0) @binding(4) var<storage, read> in3: array<In3>;
@group(0) @binding(5) var<storage, read> weights: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read> bias: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read_write> out: array<Out>;

const COB: u32 = 4u;

fn fetch(k: u32, x: u32, y: u32, c4: u32, ci: u32) -> vec4<f32> {
    switch k {
        case 0u: { return load0(x, y, c4, ci); }
        case 1u: { return load1(x, y, c4, ci); }
        case 2u: { return load2(x, y, c4, ci); }
        default: { return load3(x, y, c4, ci); }
    }
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let x = gid.x;
    let y = gid.y;
    let co4_0 = gid.z * COB;
    if (x >= p.width || y >= p.height) {
        return;
    }
    let nb = min(COB, p.cout4 - co4_0);
    var acc: array<vec4<f32>, 4>;
    for (var j = 0u; j < nb; j++) {
        acc[j] = bias[co4_0 + j];
    }
    for (var tap = 0u; tap < 9u; tap++) {
        let xx = i32(x) + i32(tap % 3u) - 1;
        let yy = i32(y) + i32(tap / 3u) - 1;
        if (xx < 0 || yy < 0 || xx >= i32(p.width) || yy >= i32(p.height)) {
            continue;
        }
        var ci_base = 0u;
        for (var k = 0u; k < p.n_inputs; k++) {
            let c4 = p.cin4[k];
            for (var ci = 0u; ci < c4; ci++) {
                let v = fetch(k, u32(xx), u32(yy), c4, ci);
                let wrow = ((tap * p.cin4_total + ci_base + ci) * p.cout4 + co4_0) * 4u;
                for (var j = 0u; j < nb; j++) {
                    let w = wrow + j * 4u;
                    acc[j] += weights[w] * v.x + weights[w + 1u] * v.y + weights[w + 2u] * v.z
                        + weights[w + 3u] * v.w;
                }
            }
            ci_base += c4;
        }
    }
    let o = (y * p.width + x) * p.cout4 + co4_0;
    for (var j = 0u; j < nb; j++) {
        var r = acc[j];
        if (p.act == 1u) {
            r = max(r, vec4<f32>(0.0));
        } else if (p.act == 2u) {
            r = select(r * p.slope, r, r >= vec4<f32>(0.0));
        }
        out[o + j] = to_out(r);
    }
}
