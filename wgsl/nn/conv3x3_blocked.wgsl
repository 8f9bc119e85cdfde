// 3x3 convolution, register-blocked and specialised (issue 14): the same operation as
// nn/conv3x3 (stride 1, zero padding, bias, activation, up to 4 NHWC inputs read as if
// concatenated along channels, output kept finite; sums in another order), shaped at
// compile time so the driver gets one straight-line kernel per layer shape and tiling:
// - each invocation computes PX horizontally adjacent pixels times COB output vec4s, in
//   PX * COB named accumulators (unrolled by the registry's template expansion, see
//   src/gpu/template.rs: drivers such as lavapipe do not unroll loops, and an indexed
//   accumulator array would live in memory). Every input vec4 it loads serves 3 taps and
//   COB output blocks; every weight vec4 serves PX pixels;
// - N_IN inputs are bound, their channel counts and the output's are override constants:
//   no dynamic `switch` and no runtime loop bounds; only the image size is a parameter;
// - weights live in a uniform buffer (broadcast loads), packed per layer as
//   [tap(9)][ci4 over the concatenated inputs][co4 (CO_COUNT rounded up to COB)][4 columns];
//   column k of block (ci4, co4) holds the weights of input channel 4*ci4+k for output
//   channels 4*co4..4*co4+3. A layer whose weights exceed MAX_WEIGHTS runs as several
//   dispatches, each over CO_COUNT output vec4s from CO_BASE with its own weight buffer
//   (nn::conv packs them; a layer whose single output block does not fit runs on
//   nn/conv3x3, which reads weights from storage).
// - each input and the output are stored as f32 or f16 (nn/lib/storage: template flags,
//   `array<vec4<f16>>` with SHADER_F16); the sums are f32;
// - each input may be read resampled 2x (nn/lib/fetch: override FETCHk, its stored size in
//   `src`): the pooled or upsampled tensor of the level beside the layer, without a pass
//   that stores it.
// The grid: x over groups of PX pixels, y over rows, z over blocks of COB output vec4s.
//
//#param N_IN 4
//#param PX 1
//#param COB 1

// The shape, activation and parameter block: nn/lib/conv_shape; the output range, the
// other bindings and `store`: nn/lib/uniform_weights.
@group(0) @binding(0) var<uniform> p: Params;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let x0 = gid.x * {PX}u;
    let y = gid.y;
    let local0 = gid.z * {COB}u;
    let co0 = CO_BASE + local0;
    if (x0 >= p.width || y >= p.height) {
        return;
    }
    let cout4_stride = ((CO_COUNT + {COB}u - 1u) / {COB}u) * {COB}u;
    var cin4_total = 0u;
    //#repeat k N_IN
    cin4_total += CIN4_{k};
    //#end
    //#repeat j COB
    let b{j} = bias[min(co0 + {j}u, COUT4 - 1u)];
    //#repeat q PX
    var a{q}_{j} = b{j};
    //#end
    //#end
    let w_last = i32(p.width) - 1;
    for (var ty = 0u; ty < 3u; ty++) {
        let yy = i32(y) + i32(ty) - 1;
        if (yy < 0 || yy >= i32(p.height)) {
            continue;
        }
        var ci_base = 0u;
        //#repeat k N_IN
        for (var ci = 0u; ci < CIN4_{k}; ci++) {
            // The row's PX + 2 input vec4s (zero outside the image).
            //#repeat i PX+2
            let xx{i} = i32(x0) + {i} - 1;
            let v{i} = select(vec4<f32>(0.0), load{k}(u32(clamp(xx{i}, 0, w_last)), u32(yy), CIN4_{k}, ci), xx{i} >= 0 && xx{i} <= w_last);
            //#end
            //#repeat tx 3
            let wr{tx} = (((ty * 3u + {tx}u) * cin4_total + ci_base + ci) * cout4_stride + local0) * 4u;
            //#repeat j COB
            //#if W16
            let w{tx}_{j}_h0 = weights[(wr{tx} + {j}u * 4u) / 2u];
            let w{tx}_{j}_h1 = weights[(wr{tx} + {j}u * 4u) / 2u + 1u];
            let w{tx}_{j}_0 = halves(w{tx}_{j}_h0.xy);
            let w{tx}_{j}_1 = halves(w{tx}_{j}_h0.zw);
            let w{tx}_{j}_2 = halves(w{tx}_{j}_h1.xy);
            let w{tx}_{j}_3 = halves(w{tx}_{j}_h1.zw);
            //#else
            let w{tx}_{j}_0 = weights[wr{tx} + {j}u * 4u];
            let w{tx}_{j}_1 = weights[wr{tx} + {j}u * 4u + 1u];
            let w{tx}_{j}_2 = weights[wr{tx} + {j}u * 4u + 2u];
            let w{tx}_{j}_3 = weights[wr{tx} + {j}u * 4u + 3u];
            //#end
            //#repeat q PX
            a{q}_{j} += w{tx}_{j}_0 * v{q+tx}.x + w{tx}_{j}_1 * v{q+tx}.y + w{tx}_{j}_2 * v{q+tx}.z + w{tx}_{j}_3 * v{q+tx}.w;
            //#end
            //#end
            //#end
        }
        ci_base += CIN4_{k};
        //#end
    }
    //#repeat q PX
    //#repeat j COB
    store(x0 + {q}u, y, co0 + {j}u, a{q}_{j});
    //#end
    //#end
}
