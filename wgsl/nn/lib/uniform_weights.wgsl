// What the convolutions with weights in a uniform buffer (nn/conv3x3_blocked,
// nn/conv3x3_winograd) share: the output range of one dispatch (a layer whose weights
// exceed the uniform array runs as several, nn::conv packs them), the bindings after the
// parameter block (N_IN inputs, the weights, the bias, the output and, with the template
// flag TEX_OUT, the output's texture array) and the store of one output vec4. A kernel including this library declares template parameter N_IN, `p:
// Params` at binding 0, and includes nn/lib/storage and nn/lib/conv_shape.

override CO_BASE: u32 = 0u; // first output vec4 of this dispatch
override CO_COUNT: u32 = 1u; // output vec4s of this dispatch (its weights)

const MAX_WEIGHTS: u32 = 4096u; // vec4s: 64 KiB, WebGPU's default uniform binding size

//#if TEX_IN
//#repeat k N_IN
@group(0) @binding({k+1}) var in{k}: texture_2d_array<f32>;
//#end
//#else
//#repeat k N_IN
@group(0) @binding({k+1}) var<storage, read> in{k}: array<In{k}>;
//#end
//#end
//#param W16 0
// The weights: the packed f32 layout (nn::conv), or with the template flag W16 the same
// values rounded to f16, two per u32 (a convolution writing f16 activations: the f16
// precision of issue 14), so each vec4 of u32 holds two f32-layout vec4s, [4m + c] of
// the f32 layout at [2m + c / 2], components 2 (c % 2) and 2 (c % 2) + 1. Half the
// loads: on CPU drivers each per-lane weight load costs what an activation load does.
//#if W16
@group(0) @binding({N_IN+1}) var<uniform> weights: array<vec4<u32>, MAX_WEIGHTS>;
//#else
@group(0) @binding({N_IN+1}) var<uniform> weights: array<vec4<f32>, MAX_WEIGHTS>;
//#end
@group(0) @binding({N_IN+2}) var<storage, read> bias: array<vec4<f32>>;
@group(0) @binding({N_IN+3}) var<storage, read_write> out: array<Out>;
//#if TEX_OUT
// The output again, one layer per channel vec4, as nn/to_texture would copy it (the stored
// value, f16 storage widened back to f32): the convolutions reading it as a texture
// (TEX_IN) bind it instead of copying the output.
@group(0) @binding({N_IN+4}) var out_tex: texture_storage_2d_array<rgba32float, write>;
//#end

// Activation and finiteness (nn/lib/storage's to_out, as in nn/conv3x3), stored when the
// pixel and output block exist.
fn store(x: u32, y: u32, co4: u32, acc: vec4<f32>) {
    if (x >= p.width || y >= p.height || co4 >= min(COUT4, CO_BASE + CO_COUNT)) {
        return;
    }
    //#if TEX_OUT
    let v = to_out(activate(acc));
    out[(y * p.width + x) * COUT4 + co4] = v;
    textureStore(out_tex, vec2<u32>(x, y), co4, vec4<f32>(v));
    //#else
    out[(y * p.width + x) * COUT4 + co4] = to_out(activate(acc));
    //#end
}

// Four weights from two u32s of f16 pairs (W16): low half first, as packed by nn::conv.
fn halves(h: vec2<u32>) -> vec4<f32> {
    return vec4<f32>(unpack2x16float(h.x), unpack2x16float(h.y));
}
