// Tensor element types of kernels whose tensors may be stored as f32 or f16 (issue 14),
// chosen by template flags (0 f32, 1 f16): F16_IN0..F16_IN4 for the inputs' types
// In0..In4, F16_OUT for the output's type Out. Arithmetic stays f32: loads convert with
// vec4<f32>(...), stores with to_out(...), which also keeps the stored value finite: a
// non-finite value becomes 0 and finite ones are clamped to +-OUT_MAX (1e15 in f32, far
// beyond any real activation, so sums of them cannot overflow; f16's largest finite value,
// 65504, in f16). Template flag TEX_IN (0 or 1): a convolution whose inputs are read from
// texture arrays instead (nn/lib/fetch, nn/to_texture); TEX_OUT (0 or 1): one that also
// stores its output to a texture array for the convolutions that read it so
// (nn/lib/uniform_weights), which then need no copy of it.
//
//#param F16_IN0 0
//#param F16_IN1 0
//#param F16_IN2 0
//#param F16_IN3 0
//#param F16_IN4 0
//#param F16_OUT 0
//#param TEX_IN 0
//#param TEX_OUT 0
//#if F16_IN0+F16_IN1+F16_IN2+F16_IN3+F16_IN4+F16_OUT
enable f16;
//#end
//#repeat k 5
//#if F16_IN{k}
alias In{k} = vec4<f16>;
//#else
alias In{k} = vec4<f32>;
//#end
//#end
//#if F16_OUT
alias Out = vec4<f16>;
const OUT_MAX: f32 = 65504.0;
//#else
alias Out = vec4<f32>;
const OUT_MAX: f32 = 1.0e15;
//#end

// `r` as the output's type, finite.
fn to_out(r: vec4<f32>) -> Out {
    let lim = vec4<f32>(OUT_MAX);
    return Out(select(vec4<f32>(0.0), clamp(r, -lim, lim), abs(r) <= vec4<f32>(3.40282347e38)));
}
