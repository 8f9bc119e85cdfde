// 3x3 convolution by Winograd's minimal filtering F(2x2, 3x3) (issue 14): the same
// operation as nn/conv3x3 (stride 1, zero padding, bias, activation, up to 4 NHWC inputs
// read as if concatenated along channels, output kept finite), with 16 multiplications per
// 2x2 output tile and input-output channel pair instead of 36 (2.25x fewer):
// - the input tile d (4x4 pixels around a 2x2 output tile) is transformed to V = B^T d B,
//   the weights g (3x3, per input and output channel) to U = G g G^T on the host
//   (nn::conv packs them), the output is Y = A^T M A with M = sum over input channels of
//   U . V (elementwise), where
//     B^T = [1 0 -1 0; 0 1 1 0; 0 -1 1 0; 0 1 0 -1],  A^T = [1 1 1 0; 0 1 -1 -1],
//     G = [1 0 0; 1/2 1/2 1/2; 1/2 -1/2 1/2; 0 0 1];
//   exact in real arithmetic, so the kernel agrees with the CPU reference to float
//   tolerance (its sums run in another order, over transformed values);
// - each invocation computes TX horizontally adjacent 2x2 tiles times COB output vec4s,
//   in 16 * TX * COB named accumulators (the registry's template expansion unrolls them,
//   as in nn/conv3x3_blocked). The row half of the input transform is shared by adjacent
//   tiles, every weight vec4 serves TX tiles;
// - shapes, weights (a uniform buffer, [position(16)][ci4][co4 (CO_COUNT rounded up to
//   COB)][4 columns], column k of block (ci4, co4) holding input channel 4*ci4+k for output
//   channels 4*co4..4*co4+3), the split of large layers into dispatches (CO_BASE,
//   CO_COUNT), storage types and resampled inputs as nn/conv3x3_blocked.
// The grid: x over groups of TX tiles, y over pairs of rows, z over blocks of COB output
// vec4s.
//
//#param N_IN 4
//#param TX 1
//#param COB 1

// The shape, activation and parameter block: nn/lib/conv_shape; the output range, the
// other bindings and `store`: nn/lib/uniform_weights.
@group(0) @binding(0) var<uniform> p: Params;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let x0 = gid.x * 2u * {TX}u;
    let y0 = gid.y * 2u;
    let local0 = gid.z * {COB}u;
    let co0 = CO_BASE + local0;
    if (x0 >= p.width || y0 >= p.height) {
        return;
    }
    let cout4_stride = ((CO_COUNT + {COB}u - 1u) / {COB}u) * {COB}u;
    var cin4_total = 0u;
    //#repeat k N_IN
    cin4_total += CIN4_{k};
    //#end
    // Accumulators m(tile)_(row)_(column)_(output block) of the transformed positions.
    //#repeat t TX
    //#repeat i 4
    //#repeat j 4
    //#repeat b COB
    var m{t}_{i}_{j}_{b} = vec4<f32>(0.0);
    //#end
    //#end
    //#end
    //#end
    let w_last = i32(p.width) - 1;
    let h_last = i32(p.height) - 1;
    // The patch's rows and columns, and which of them lie inside the image.
    //#repeat r 4
    let yy{r} = i32(y0) + {r} - 1;
    let iny{r} = yy{r} >= 0 && yy{r} <= h_last;
    let ry{r} = u32(clamp(yy{r}, 0, h_last));
    //#end
    //#repeat c TX+TX+2
    let xx{c} = i32(x0) + {c} - 1;
    let inx{c} = xx{c} >= 0 && xx{c} <= w_last;
    let rx{c} = u32(clamp(xx{c}, 0, w_last));
    //#end
    var ci_base = 0u;
    //#repeat k N_IN
    for (var ci = 0u; ci < CIN4_{k}; ci++) {
        // The patch (zero outside the image), then B^T d per column.
        //#repeat c TX+TX+2
        //#repeat r 4
        let d{r}_{c} = select(vec4<f32>(0.0), load{k}(rx{c}, ry{r}, CIN4_{k}, ci), iny{r} && inx{c});
        //#end
        let s0_{c} = d0_{c} - d2_{c};
        let s1_{c} = d1_{c} + d2_{c};
        let s2_{c} = d2_{c} - d1_{c};
        let s3_{c} = d1_{c} - d3_{c};
        //#end
        // (B^T d) B per tile and row.
        //#repeat t TX
        //#repeat i 4
        let v{t}_{i}_0 = s{i}_{t+t} - s{i}_{t+t+2};
        let v{t}_{i}_1 = s{i}_{t+t+1} + s{i}_{t+t+2};
        let v{t}_{i}_2 = s{i}_{t+t+2} - s{i}_{t+t+1};
        let v{t}_{i}_3 = s{i}_{t+t+1} - s{i}_{t+t+3};
        //#end
        //#end
        //#repeat i 4
        //#repeat j 4
        let wr{i}_{j} = (((({i}u * 4u + {j}u) * cin4_total + ci_base + ci) * cout4_stride) + local0) * 4u;
        //#repeat b COB
        //#if W16
        let u{i}_{j}_{b}_h0 = weights[(wr{i}_{j} + {b}u * 4u) / 2u];
        let u{i}_{j}_{b}_h1 = weights[(wr{i}_{j} + {b}u * 4u) / 2u + 1u];
        let u{i}_{j}_{b}_0 = halves(u{i}_{j}_{b}_h0.xy);
        let u{i}_{j}_{b}_1 = halves(u{i}_{j}_{b}_h0.zw);
        let u{i}_{j}_{b}_2 = halves(u{i}_{j}_{b}_h1.xy);
        let u{i}_{j}_{b}_3 = halves(u{i}_{j}_{b}_h1.zw);
        //#else
        let u{i}_{j}_{b}_0 = weights[wr{i}_{j} + {b}u * 4u];
        let u{i}_{j}_{b}_1 = weights[wr{i}_{j} + {b}u * 4u + 1u];
        let u{i}_{j}_{b}_2 = weights[wr{i}_{j} + {b}u * 4u + 2u];
        let u{i}_{j}_{b}_3 = weights[wr{i}_{j} + {b}u * 4u + 3u];
        //#end
        //#repeat t TX
        m{t}_{i}_{j}_{b} += u{i}_{j}_{b}_0 * v{t}_{i}_{j}.x + u{i}_{j}_{b}_1 * v{t}_{i}_{j}.y + u{i}_{j}_{b}_2 * v{t}_{i}_{j}.z + u{i}_{j}_{b}_3 * v{t}_{i}_{j}.w;
        //#end
        //#end
        //#end
        //#end
    }
    ci_base += CIN4_{k};
    //#end
    // Y = A^T M A + bias per tile and output block.
    //#repeat b COB
    let bias{b} = bias[min(co0 + {b}u, COUT4 - 1u)];
    //#repeat t TX
    {
    //#repeat j 4
    let q0_{j} = m{t}_0_{j}_{b} + m{t}_1_{j}_{b} + m{t}_2_{j}_{b};
    let q1_{j} = m{t}_1_{j}_{b} - m{t}_2_{j}_{b} - m{t}_3_{j}_{b};
    //#end
    store(x0 + {t+t}u, y0, co0 + {b}u, bias{b} + q0_0 + q0_1 + q0_2);
    store(x0 + {t+t+1}u, y0, co0 + {b}u, bias{b} + q0_1 - q0_2 - q0_3);
    store(x0 + {t+t}u, y0 + 1u, co0 + {b}u, bias{b} + q1_0 + q1_1 + q1_2);
    store(x0 + {t+t+1}u, y0 + 1u, co0 + {b}u, bias{b} + q1_1 - q1_2 - q1_3);
    }
    //#end
    //#end
}
