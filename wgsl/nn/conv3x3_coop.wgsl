// 3x3 convolution on cooperative matrices (tensor cores; issue 14): the same operation as
// nn/conv3x3 (stride 1, zero padding, bias, activation, up to 4 NHWC inputs read as if
// concatenated along channels, output kept finite) as an implicit matrix product, with f16
// operands and f32 sums, on T x T matrices (T = 16, or 8 where the adapter has no 16x16x16
// f16 x f16 + f32 configuration at subgroup scope). Needs wgpu's
// EXPERIMENTAL_COOPERATIVE_MATRIX and SHADER_F16.
// - One workgroup is one subgroup (SG invocations, the adapter's subgroup size: 32 on
//   NVIDIA, 8 on lavapipe). It computes a tile of MT * T
//   horizontally adjacent pixels of RT rows times NT * T output channels, in RT * MT * NT
//   T x T f32 accumulators (named: unrolled by the registry's template expansion).
// - The sum runs over input blocks of T channels (each input's channels are padded to a
//   multiple of T on their own) and the 9 taps. Per block, the subgroup stages the RT + 2
//   rows around the tile's, of its pixels and their two neighbours (zero outside the image and
//   beyond the input's channels) in workgroup memory as f16, read through nn/lib/fetch
//   (so inputs may be resampled 2x on load); per tap, A is a T pixel x T channel window
//   of that tile and B the tap's T x T weights.
// - Weights: a storage array of f16 packed by nn::conv as
//   [block over the inputs][tap (9)][ci (T)][co (CO_PAD)], zero beyond the layer's
//   channels; CO_PAD is the output channels rounded up to a multiple of NT * T.
// - The accumulators start as the bias (a T x T tile of it staged in workgroup memory);
//   the epilogue stores each accumulator to workgroup memory, then the invocations apply
//   the activation and write the output tensor's vec4s (f32 or f16, nn/lib/storage).
// Every coopLoad/coopStore address and stride is a multiple of 16 bytes, as Vulkan asks.
// The grid: x over groups of MT * T pixels (SG invocations each), y over groups of RT rows,
// z over groups of NT output tiles.
//
//#param N_IN 4
//#param MT 1
//#param NT 1
//#param SG 32
//#param T 16
//#param RT 1

enable f16;
enable wgpu_cooperative_matrix;

// The shape, activation and parameter block: nn/lib/conv_shape.
override CO_PAD: u32 = 16u; // output channels of the packed weights (a multiple of NT * T)

// Pixels of the staged rows: the tile and one neighbour on each side.
const ROW: u32 = {MT}u * {T}u + 2u;
// vec4s of channels per block.
const C4: u32 = {T}u / 4u;
const F16_MAX: f32 = 65504.0;

@group(0) @binding(0) var<uniform> p: Params;
//#repeat k N_IN
@group(0) @binding({k+1}) var<storage, read> in{k}: array<In{k}>;
//#end
@group(0) @binding({N_IN+1}) var<storage, read> weights: array<f16>;
@group(0) @binding({N_IN+2}) var<storage, read> bias: array<vec4<f32>>;
@group(0) @binding({N_IN+3}) var<storage, read_write> out: array<Out>;

// A T x T f32 tile: the bias the accumulators start from, then each accumulator's sums.
var<workgroup> ctile: array<f32, {T}u * {T}u>;
// The staged input block: [row (RT + 2)][pixel (ROW)][channel (T)].
var<workgroup> xtile: array<f16, ({RT}u + 2u) * ROW * {T}u>;

@compute @workgroup_size({SG}, 1, 1)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let x0 = wid.x * {MT}u * {T}u;
    let y0 = wid.y * {RT}u;
    let co_tile0 = wid.z * {NT}u;
    // No early return: the matrix operations need every invocation of the subgroup in
    // uniform control flow. The grid has no workgroup wholly outside the image; stores
    // check their pixel.
    // The accumulators start as the bias of their output tile.
    //#repeat n NT
    for (var e = lane; e < {T}u * {T}u; e += {SG}u) {
        let co = (co_tile0 + {n}u) * {T}u + (e % {T}u);
        ctile[e] = select(0.0, bias[min(co / 4u, COUT4 - 1u)][co % 4u], co < COUT4 * 4u);
    }
    workgroupBarrier();
    //#repeat r RT
    //#repeat m MT
    var acc{r}_{m}_{n} = coopLoadT<coop_mat{T}x{T}<f32, C>>(&ctile[0], {T}u);
    //#end
    //#end
    workgroupBarrier();
    //#end
    var blk = 0u; // block index over all inputs
    //#repeat k N_IN
    for (var b = 0u; b < (CIN4_{k} + C4 - 1u) / C4; b++) {
        // Stage rows y0-1..y0+RT, pixels x0-1..x0+MT*T, channels T*b..T*b+T-1 of input {k}.
        workgroupBarrier();
        for (var e = lane; e < ({RT}u + 2u) * ROW * C4; e += {SG}u) {
            let row = e / (ROW * C4);
            let px = (e / C4) % ROW;
            let c4 = e % C4;
            let xx = i32(x0 + px) - 1;
            let yy = i32(y0 + row) - 1;
            let ci = b * C4 + c4;
            var v = vec4<f32>(0.0);
            if (xx >= 0 && xx < i32(p.width) && yy >= 0 && yy < i32(p.height) && ci < CIN4_{k}) {
                v = clamp(load{k}(u32(xx), u32(yy), CIN4_{k}, ci), vec4<f32>(-F16_MAX), vec4<f32>(F16_MAX));
            }
            let i = (row * ROW + px) * {T}u + c4 * 4u;
            xtile[i] = f16(v.x);
            xtile[i + 1u] = f16(v.y);
            xtile[i + 2u] = f16(v.z);
            xtile[i + 3u] = f16(v.w);
        }
        workgroupBarrier();
        for (var tap = 0u; tap < 9u; tap++) {
            let ty = tap / 3u;
            let tx = tap % 3u;
            let wbase = ((blk * 9u + tap) * {T}u) * CO_PAD + co_tile0 * {T}u;
            //#repeat n NT
            let b{n} = coopLoadT<coop_mat{T}x{T}<f16, B>>(&weights[wbase + {n}u * {T}u], CO_PAD);
            //#end
            //#repeat r RT
            //#repeat m MT
            let a{r}_{m} = coopLoadT<coop_mat{T}x{T}<f16, A>>(&xtile[(({r}u + ty) * ROW + {m}u * {T}u + tx) * {T}u], {T}u);
            //#repeat n NT
            acc{r}_{m}_{n} = coopMultiplyAdd(a{r}_{m}, b{n}, acc{r}_{m}_{n});
            //#end
            //#end
            //#end
        }
        blk += 1u;
    }
    //#end
    // Epilogue: each accumulator through workgroup memory to the output's vec4s.
    //#repeat r RT
    //#repeat m MT
    //#repeat n NT
    workgroupBarrier();
    coopStoreT(acc{r}_{m}_{n}, &ctile[0], {T}u);
    workgroupBarrier();
    for (var e = lane; e < {T}u * C4; e += {SG}u) {
        let x = x0 + {m}u * {T}u + e / C4;
        let y = y0 + {r}u;
        let co4 = (co_tile0 + {n}u) * C4 + e % C4;
        if (x < p.width && y < p.height && co4 < COUT4) {
            let i = (e / C4) * {T}u + (e % C4) * 4u;
            let sums = vec4<f32>(ctile[i], ctile[i + 1u], ctile[i + 2u], ctile[i + 3u]);
            out[(y * p.width + x) * COUT4 + co4] = to_out(activate(sums));
        }
    }
    //#end
    //#end
    //#end
}
