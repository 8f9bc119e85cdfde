//! GPU vs CPU-reference parity of every `wgsl/nn` kernel on random data at odd sizes and
//! channel counts, plus property tests. Runs on any adapter, including a CPU Vulkan driver.

mod common;

use common::*;
use subpixel::gpu::Grid;
use subpixel::nn::conv::{COOP_TOLERANCE, WINOGRAD_AT, WINOGRAD_BT, winograd_weights};
use subpixel::nn::ops::{self, Activation, Conv3x3, ConvKernel, PoolMode, TfaBlend, UpsampleMode};
use subpixel::nn::{DType, HostTensor, Tensor, reference};

/// The kernels a candidate test runs, out of `candidates`: all of them, except on the
/// cooperative-matrix run (`SUBPIXEL_EXPECT_COOP=1`, set by `tools/lavapipe_coop.sh`), which
/// repeats only the generic kernel and the cooperative-matrix tilings. The other tilings are
/// the same code on both drivers and are tested by the default run; compiling every one of
/// them again on Mesa 26's lavapipe took half an hour of CI.
fn under_test(candidates: Vec<ConvKernel>) -> Vec<ConvKernel> {
    if !coop_run() {
        return candidates;
    }
    candidates
        .into_iter()
        .filter(|k| matches!(k, ConvKernel::Generic | ConvKernel::Coop { .. }))
        .collect()
}

/// Whether this is the cooperative-matrix run (`SUBPIXEL_EXPECT_COOP=1`).
fn coop_run() -> bool {
    std::env::var("SUBPIXEL_EXPECT_COOP").as_deref() == Ok("1")
}

/// The tolerance of `kernel` against the f64 CPU reference `want`: `exact` for the f32
/// kernels; for the cooperative-matrix kernel (f16 operands), [`COOP_TOLERANCE`] of the
/// reference's largest magnitude.
fn kernel_tol(kernel: ConvKernel, want: &HostTensor, exact: Tol) -> Tol {
    match kernel {
        ConvKernel::Coop { .. } => Tol {
            abs: COOP_TOLERANCE * want.data.iter().fold(1.0f32, |m, v| m.max(v.abs())),
            rel: 0.0,
        },
        _ => exact,
    }
}

/// Asserts GPU tensor `t` matches `want` within `tol` (see [`assert_close`]).
fn assert_tensor(case: &str, t: &Tensor, want: &HostTensor, tol: Tol) {
    assert_close(case, &t.read(&gpu()).unwrap(), want, tol);
}

fn up(gpu: &subpixel::gpu::Gpu, name: &str, t: &HostTensor) -> Tensor {
    Tensor::from_host(gpu, name, t).unwrap()
}

fn run_conv(inputs: &[HostTensor], cout: u32, act: Activation, seed: u64) -> (HostTensor, HostTensor) {
    let g = gpu();
    let split: Vec<u32> = inputs.iter().map(|t| t.channels).collect();
    let cin: u32 = split.iter().sum();
    let weight = random_vec(seed, (cout * cin * 9) as usize, -0.5, 0.5);
    let bias = random_vec(seed + 1, cout as usize, -0.5, 0.5);
    let conv = Conv3x3::new(&g, "test", &weight, &bias, &split, cout, act).unwrap();
    let gins: Vec<Tensor> = inputs.iter().map(|t| up(&g, "in", t)).collect();
    let out = Tensor::new(&g, "out", inputs[0].width, inputs[0].height, cout).unwrap();
    let refs: Vec<&Tensor> = gins.iter().collect();
    ops::run(&g, &[&conv.bind(&g, &refs, &out).unwrap()]).unwrap();
    let hin: Vec<&HostTensor> = inputs.iter().collect();
    (
        out.read(&g).unwrap(),
        reference::conv3x3(&hin, &weight, &bias, cout, act),
    )
}

/// Case `i` of a table of layer shapes: random inputs of `split` channels at `size` (seeds
/// from `seeds.0`), and a layer `name` of `cout` outputs with random weights and bias (seeds
/// from `seeds.1`): the inputs, weights, bias and layer.
fn random_layer(
    name: &str,
    split: &[u32],
    cout: u32,
    act: Activation,
    (w, h): (u32, u32),
    seeds: (u64, u64),
    i: u64,
) -> (Vec<HostTensor>, Vec<f32>, Vec<f32>, Conv3x3) {
    let inputs: Vec<HostTensor> = split
        .iter()
        .enumerate()
        .map(|(k, &c)| random(seeds.0 + 10 * i + k as u64, w, h, c, -1.0, 1.0))
        .collect();
    let cin: u32 = split.iter().sum();
    let weight = random_vec(seeds.1 + i, (cout * cin * 9) as usize, -0.5, 0.5);
    let bias = random_vec(seeds.1 + 10 + i, cout as usize, -0.5, 0.5);
    let conv = Conv3x3::new(&gpu(), name, &weight, &bias, split, cout, act).unwrap();
    (inputs, weight, bias, conv)
}

#[test]
fn conv3x3_matches_reference() {
    let mut seed = 0;
    for &(w, h) in SIZES {
        for &c in CHANNELS {
            for (cout, act) in [
                (c, Activation::Relu),
                (3, Activation::None),
                (17, Activation::LeakyRelu(0.1)),
            ] {
                seed += 10;
                let x = random(seed, w, h, c, -1.0, 1.0);
                let (g, r) = run_conv(&[x], cout, act, seed);
                assert_close(&format!("conv3x3 {w}x{h} {c}->{cout} {act:?}"), &g, &r, REDUCTION);
            }
        }
    }
}

#[test]
fn conv3x3_concatenates_up_to_four_inputs() {
    for (i, split) in [vec![3, 1], vec![15, 4, 15, 3], vec![13, 32, 3], vec![4, 4, 4, 4]]
        .into_iter()
        .enumerate()
    {
        for &(w, h) in &[(7u32, 5u32), (33, 17)] {
            let inputs: Vec<HostTensor> = split
                .iter()
                .enumerate()
                .map(|(k, &c)| random(100 + k as u64, w, h, c, -1.0, 1.0))
                .collect();
            let (g, r) = run_conv(&inputs, 16, Activation::Relu, 7 + i as u64);
            assert_close(&format!("conv3x3 concat {split:?} {w}x{h}"), &g, &r, REDUCTION);
        }
    }
}

/// Issue 14: every kernel the autotuner can pick for a layer (the generic kernel and every
/// register-blocked tiling that fits) agrees with the CPU reference, on shapes that
/// exercise partial pixel groups (odd widths), output blocks that do not divide the output
/// (28 channels = 7 vec4s, 17 = 5 with padding), concatenated inputs, padded channels and
/// each activation. Each shape is a compile of every candidate (seconds each on a CPU
/// driver), so each shape carries several of these cases.
#[test]
fn conv3x3_every_autotuner_candidate_matches_reference() {
    let g = gpu();
    // (input split, output channels, activation, size)
    type Shape = (&'static [u32], u32, Activation, (u32, u32));
    let shapes: &[Shape] = &[
        // Four inputs, three of them padded; 7 vec4s of output; odd width.
        (&[15, 4, 15, 3], 28, Activation::LeakyRelu(0.1), (33, 17)),
        // One padded input, 17 outputs; a 1-pixel-wide image.
        (&[5], 17, Activation::None, (1, 3)),
        // 64 -> 48: more weights than one uniform buffer holds: chunked dispatches.
        (&[64], 48, Activation::Relu, (9, 5)),
    ];
    let mut chunked = 0;
    let mut tried = 0;
    let mut coop_shapes = 0;
    for (i, &(split, cout, act, (w, h))) in shapes.iter().enumerate() {
        let (inputs, weight, bias, conv) =
            random_layer("candidate", split, cout, act, (w, h), (300, 50), i as u64);
        let gins: Vec<Tensor> = inputs.iter().map(|t| up(&g, "in", t)).collect();
        let refs: Vec<&Tensor> = gins.iter().collect();
        let hin: Vec<&HostTensor> = inputs.iter().collect();
        let want = reference::conv3x3(&hin, &weight, &bias, cout, act);
        let candidates = conv.candidates(&g);
        assert!(candidates.len() > 1, "{split:?}->{cout}: only {candidates:?}");
        let kernels = under_test(candidates);
        coop_shapes += kernels.iter().any(|k| matches!(k, ConvKernel::Coop { .. })) as u32;
        for kernel in kernels {
            let out = Tensor::new(&g, "out", w, h, cout).unwrap();
            let d = conv.bind_with(&g, kernel, &refs, &out).unwrap();
            // A kernel reading textures first copies each input to a texture array (one
            // more part each, which writes the rgba32float texture and reads the input).
            let copies = if kernel.reads_textures() { split.len() } else { 0 };
            chunked += (d.parts() > 1 + copies) as u32;
            // Compulsory traffic (roofline model): every input once, the output once.
            let inputs: u64 = gins.iter().map(|t| t.bytes()).sum();
            let textures: u64 = gins
                .iter()
                .map(|t| (t.width * t.height * t.channels.div_ceil(4) * 16) as u64)
                .sum();
            // (each part of a chunked dispatch binds the whole input and output)
            let parts = (d.parts() - copies) as u64;
            let copied = if copies > 0 { textures } else { 0 };
            assert_eq!(d.bytes_written, parts * out.bytes() + copied, "{kernel}");
            // The kernel's parts read the textures instead of the inputs.
            let inputs = if copies > 0 { textures } else { inputs };
            let extra = if copies > 0 {
                gins.iter().map(|t| t.bytes() + 16).sum()
            } else {
                0
            };
            // Weights: the generic kernel's storage copy, one 64 KiB uniform array per part,
            // or the cooperative kernel's f16 copy (16-channel blocks, outputs padded to 32).
            let padded = |c: u32| c.div_ceil(4) as u64 * 4;
            let cin_p: u64 = split.iter().map(|&c| padded(c)).sum();
            let blocks: u64 = split.iter().map(|&c| c.div_ceil(16) as u64).sum();
            let coop = 9 * blocks * 16 * (cout.div_ceil(32) as u64 * 32) * 2;
            let weights = (9 * cin_p * padded(cout) * 4).max(parts * 65536).max(coop);
            assert!(
                d.bytes_read > parts * inputs + extra
                    && d.bytes_read <= parts * (inputs + 1024) + weights + extra,
                "{kernel}: {}",
                d.bytes_read
            );
            ops::run(&g, &[&d]).unwrap();
            let got = out.read(&g).unwrap();
            assert_close(
                &format!("conv3x3 {kernel} {split:?}->{cout} {w}x{h}"),
                &got,
                &want,
                kernel_tol(kernel, &want, REDUCTION),
            );
            tried += 1;
        }
    }
    if coop_run() {
        // The cooperative-matrix run tests only the generic kernel and the coop tilings:
        // at least one coop tiling must apply to every shape.
        assert_eq!(coop_shapes as usize, shapes.len(), "shapes with a coop tiling");
    } else {
        assert!(tried >= 40, "{tried} kernel/shape pairs");
        // (chunked dispatches are the uniform-weight kernels', which that run leaves out)
        assert!(chunked >= 5, "{chunked} chunked dispatches");
    }
}

/// Issue 14, fewer copies: a kernel with uniform weights given a texture for its output
/// (template flag TEX_OUT) stores every output vec4 there too, as `nn/to_texture` would copy
/// it (the texture's layers hold the buffer's values to the bit, chunked layers included),
/// and a convolution reading textures that finds its input there computes to the bit what
/// it computes from a copy of its own.
#[test]
fn conv3x3_stores_its_output_to_a_texture_the_next_convolution_reads() {
    use subpixel::nn::conv::{InputTexture, TextureIo, activation_texture};
    let g = gpu();
    type Shape = (&'static [u32], u32, (u32, u32));
    // The second: more weights than one uniform buffer holds (chunked dispatches).
    let shapes: &[Shape] = &[(&[15, 4], 16, (19, 9)), (&[64], 48, (9, 5))];
    let mut tried = 0;
    for (i, &(split, cout, (w, h))) in shapes.iter().enumerate() {
        let (inputs, weight, bias, conv) = random_layer(
            "producer",
            split,
            cout,
            Activation::Relu,
            (w, h),
            (700, 70),
            i as u64,
        );
        // The next layer: 8 channels from the producer's output, read as a texture.
        let next_w = random_vec(90 + i as u64, (8 * cout * 9) as usize, -0.5, 0.5);
        let next = Conv3x3::new(&g, "consumer", &next_w, &[0.1; 8], &[cout], 8, Activation::None).unwrap();
        let reader: ConvKernel = "px4-cob1-tex".parse().unwrap();
        let gins: Vec<Tensor> = inputs.iter().map(|t| up(&g, "in", t)).collect();
        let refs: Vec<&Tensor> = gins.iter().collect();
        let hin: Vec<&HostTensor> = inputs.iter().collect();
        let want = reference::conv3x3(&hin, &weight, &bias, cout, Activation::Relu);
        for kernel in conv
            .candidates(&g)
            .into_iter()
            .filter(|k| !matches!(k, ConvKernel::Generic | ConvKernel::Coop { .. }))
        {
            let case = format!("{kernel} {split:?}->{cout} {w}x{h}");
            let out = Tensor::new(&g, "out", w, h, cout).unwrap();
            let tex = activation_texture(&g, "out", &out).unwrap();
            let io = TextureIo {
                inputs: vec![],
                output: Some(&tex.view),
            };
            ops::run(&g, &[&conv.bind_textured(&g, kernel, &refs, &out, &io).unwrap()]).unwrap();
            assert_close(&case, &out.read(&g).unwrap(), &want, REDUCTION);
            let stored: Vec<f32> =
                bytemuck::pod_collect_to_vec(&g.read_buffer(&out.buffer, 0, out.bytes()).unwrap());
            let texels: Vec<f32> = bytemuck::pod_collect_to_vec(&g.read_texture(&tex.texture).unwrap());
            let c4 = out.c4() as usize;
            let (wu, hu) = (w as usize, h as usize);
            for l in 0..c4 {
                for p in 0..wu * hu {
                    for k in 0..4 {
                        let (a, b) = (texels[(l * wu * hu + p) * 4 + k], stored[(p * c4 + l) * 4 + k]);
                        assert_eq!(
                            a.to_bits(),
                            b.to_bits(),
                            "{case}: layer {l}, pixel {p}, lane {k}: {a} against {b}"
                        );
                    }
                }
            }
            // The next convolution on the texture, against the same kernel copying its input.
            let got = Tensor::new(&g, "next", w, h, 8).unwrap();
            let io = TextureIo {
                inputs: vec![Some(InputTexture::Filled(&tex.view))],
                output: None,
            };
            let d = next.bind_textured(&g, reader, &[&out], &got, &io).unwrap();
            let own = Tensor::new(&g, "own", w, h, 8).unwrap();
            let d_own = next.bind_with(&g, reader, &[&out], &own).unwrap();
            assert_eq!(d.parts() + 1, d_own.parts(), "{case}: the copy left out");
            ops::run(&g, &[&d, &d_own]).unwrap();
            let (a, b) = (got.read(&g).unwrap(), own.read(&g).unwrap());
            assert!(
                a.data
                    .iter()
                    .zip(&b.data)
                    .all(|(x, y)| x.to_bits() == y.to_bits()),
                "{case}: next layer differs"
            );
            tried += 1;
        }
    }
    assert!(tried >= 20, "{tried} kernel/shape pairs");
}

/// Issue 14, fusion: a convolution that reads an input resampled on load (2x2 max or
/// average pooling of a tensor twice its size, odd sizes included so that windows are
/// clipped; 2x nearest or bilinear upsampling of one half its size) agrees with the CPU
/// reference of the resampling followed by the convolution, on every kernel the autotuner
/// can pick, beside an input read as stored; an input of the wrong size is an error that
/// names the layer, the input and the sizes.
#[test]
fn conv3x3_resamples_inputs_on_load() {
    use ops::Fetch;
    let g = gpu();
    let (w, h) = (11u32, 6u32);
    let mut tried = 0;
    // Each layer (a compile of every candidate) reads one input as stored, one pooled and
    // one upsampled: the four resamplings over two layers.
    for (i, resampled) in [
        [Fetch::Pool(PoolMode::Max), Fetch::Upsample(UpsampleMode::Nearest)],
        [
            Fetch::Pool(PoolMode::Average),
            Fetch::Upsample(UpsampleMode::Bilinear),
        ],
    ]
    .into_iter()
    .enumerate()
    {
        let seed = 700 + 10 * i as u64;
        // The stored tensors: 21x11 (clipped windows at the edge) for pooling, 6x3 for
        // upsampling.
        let stored: Vec<HostTensor> = resampled
            .iter()
            .enumerate()
            .map(|(k, fetch)| {
                let (sw, sh) = match fetch {
                    Fetch::Pool(_) => (2 * w - 1, 2 * h - 1),
                    _ => (w.div_ceil(2), h.div_ceil(2)),
                };
                random(seed + k as u64, sw, sh, 6, -1.0, 1.0)
            })
            .collect();
        let direct = random(seed + 5, w, h, 3, -1.0, 1.0);
        let read: Vec<HostTensor> = resampled
            .iter()
            .zip(&stored)
            .map(|(fetch, t)| match *fetch {
                Fetch::Pool(mode) => reference::pool2x2(t, mode),
                Fetch::Upsample(mode) => reference::upsample2x(t, mode, w, h),
                Fetch::Direct => unreachable!(),
            })
            .collect();
        let (split, cout) = ([3u32, 6, 6], 12u32);
        let weight = random_vec(seed + 6, (cout * 15 * 9) as usize, -0.5, 0.5);
        let bias = random_vec(seed + 7, cout as usize, -0.5, 0.5);
        let mut conv = Conv3x3::new(&g, "fused", &weight, &bias, &split, cout, Activation::Relu).unwrap();
        conv.set_fetch(&[Fetch::Direct, resampled[0], resampled[1]])
            .unwrap();
        let want = reference::conv3x3(
            &[&direct, &read[0], &read[1]],
            &weight,
            &bias,
            cout,
            Activation::Relu,
        );
        let gd = up(&g, "direct", &direct);
        let gs: Vec<Tensor> = stored.iter().map(|t| up(&g, "stored", t)).collect();
        let names = format!("{} and {}", resampled[0].name(), resampled[1].name());
        for kernel in under_test(conv.candidates(&g)) {
            let out = Tensor::new(&g, "out", w, h, cout).unwrap();
            let d = conv.bind_with(&g, kernel, &[&gd, &gs[0], &gs[1]], &out).unwrap();
            ops::run(&g, &[&d]).unwrap();
            let case = format!("conv3x3 {kernel} reading {names}");
            assert_tensor(&case, &out, &want, kernel_tol(kernel, &want, REDUCTION));
            // The autotuner's output check (its own inputs, the CPU resampling) agrees.
            let e = conv.output_error(&g, kernel, 13, 7, &[]).unwrap();
            let bound = if matches!(kernel, ConvKernel::Coop { .. }) {
                COOP_TOLERANCE
            } else {
                1e-5
            };
            assert!(e <= bound, "{case}: output check error {e:e}");
            tried += 1;
        }
        // An input at the layer's size instead of its stored size.
        let same = up(&g, "same", &random(1, w, h, 6, -1.0, 1.0));
        for k in 0..2 {
            let out = Tensor::new(&g, "out", w, h, cout).unwrap();
            let mut inputs = vec![&gd, &gs[0], &gs[1]];
            inputs[k + 1] = &same;
            let e = conv.bind(&g, &inputs, &out).unwrap_err().to_string();
            let expect = format!("input {} is {w}x{h}, expected", k + 1);
            assert!(
                e.contains("fused") && e.contains(&expect) && e.contains(resampled[k].name()),
                "{e}"
            );
        }
    }
    assert!(tried >= 2 * 10, "{tried} kernel/layer pairs");
    let mut conv = Conv3x3::new(&g, "fused", &[0.0; 27], &[0.0], &[3], 1, Activation::None).unwrap();
    let e = conv.set_fetch(&[]).unwrap_err().to_string();
    assert!(
        e.contains("fused") && e.contains("0 fetch modes for 1 inputs"),
        "{e}"
    );
}

/// The test GPU if it has SHADER_F16 (else `None`, the test skipped with a note).
fn f16_gpu() -> Option<subpixel::gpu::Gpu> {
    let g = gpu();
    if g.has(wgpu::Features::SHADER_F16) {
        Some(g)
    } else {
        eprintln!("skipped: {} has no SHADER_F16", g.describe());
        None
    }
}

/// `t` plus one f16 ulp (2^-10 relative) for a result rounded to f16.
const fn plus_f16_ulp(t: Tol) -> Tol {
    Tol {
        abs: t.abs,
        rel: t.rel + 1.0 / 1024.0,
    }
}

/// A host tensor's values rounded to f16 (what an f16 tensor stores).
fn to_f16(t: &HostTensor) -> HostTensor {
    let mut r = t.clone();
    for v in &mut r.data {
        *v = half::f16::from_f32(*v).to_f32();
    }
    r
}

/// What the Winograd kernel computes for an f16 output: F(2x2, 3x3) over 2x2 output tiles
/// (V = B^T d B of each 4x4 input patch, zero outside the image; Y = A^T (sum over input
/// channels of U . V) A), with each transformed 3x3 kernel U (`winograd_weights`) rounded
/// to f16 as the kernel stores it; then bias and activation. `x` holds the inputs'
/// channels concatenated; `weight` is OIHW.
fn winograd_f16_reference(
    x: &HostTensor,
    weight: &[f32],
    bias: &[f32],
    cout: u32,
    act: Activation,
) -> HostTensor {
    const BT: [[f32; 4]; 4] = WINOGRAD_BT;
    const AT: [[f32; 4]; 2] = WINOGRAD_AT;
    let cin = x.channels;
    let u: Vec<[f32; 16]> = (0..(cout * cin) as usize)
        .map(|k| {
            let g: [f32; 9] = weight[k * 9..k * 9 + 9].try_into().unwrap();
            winograd_weights(&g).map(|v| half::f16::from_f32(v).to_f32())
        })
        .collect();
    let at = |xx: i64, yy: i64, c: u32| -> f32 {
        if xx < 0 || yy < 0 || xx >= x.width as i64 || yy >= x.height as i64 {
            0.0
        } else {
            x.at(xx as u32, yy as u32, c)
        }
    };
    HostTensor::from_fn(x.width, x.height, cout, |px, py, co| {
        let (tx, ty) = (px as i64 / 2 * 2, py as i64 / 2 * 2);
        let (r, c) = ((py % 2) as usize, (px % 2) as usize);
        let mut sum = 0.0f32;
        for ci in 0..cin {
            let d = |k: usize, l: usize| at(tx - 1 + l as i64, ty - 1 + k as i64, ci);
            let uk = &u[(co * cin + ci) as usize];
            for i in 0..4 {
                for j in 0..4 {
                    let v: f32 = (0..4)
                        .map(|k| (0..4).map(|l| BT[i][k] * d(k, l) * BT[j][l]).sum::<f32>())
                        .sum();
                    sum += AT[r][i] * uk[i * 4 + j] * v * AT[c][j];
                }
            }
        }
        act.apply(sum + bias[co as usize])
    })
}

/// f16 storage (issue 14): every conv kernel the autotuner may pick (the layer is wide
/// enough for every tiling), with inputs stored as f16 and f32 mixed and an f16 output
/// (and an f32 one for two of them), against the CPU reference computed in f32
/// on the f16-rounded inputs (and, for the blocked and Winograd kernels writing f16, the
/// f16-rounded weights they store), its result rounded to f16 for an f16 output. Stated
/// tolerance: the f32 kernels' (sums in another order) plus 2^-10 relative for the
/// output's rounding (at most one f16 ulp: both sides round a value that differs by the
/// f32 tolerance). Pooling with f16 storage is exact (max) or within it (average).
#[test]
fn conv3x3_and_pooling_with_f16_storage_match_reference() {
    let Some(g) = f16_gpu() else { return };
    const F16_OUT: Tol = plus_f16_ulp(REDUCTION);
    let (split, cout, act, (w, h)) = ([15u32, 4, 8, 3], 32u32, Activation::LeakyRelu(0.1), (21u32, 9u32));
    let dtypes = [DType::F16, DType::F32, DType::F16, DType::F32];
    let inputs: Vec<HostTensor> = split
        .iter()
        .enumerate()
        .map(|(k, &c)| random(900 + k as u64, w, h, c, -2.0, 2.0))
        .collect();
    let stored: Vec<HostTensor> = inputs
        .iter()
        .zip(dtypes)
        .map(|(t, d)| if d == DType::F16 { to_f16(t) } else { t.clone() })
        .collect();
    let cin: u32 = split.iter().sum();
    let weight = random_vec(77, (cout * cin * 9) as usize, -0.5, 0.5);
    let bias = random_vec(78, cout as usize, -0.5, 0.5);
    let conv = Conv3x3::new(&g, "f16", &weight, &bias, &split, cout, act).unwrap();
    let gins: Vec<Tensor> = inputs
        .iter()
        .zip(dtypes)
        .map(|(t, d)| Tensor::from_host_typed(&g, "in", t, d).unwrap())
        .collect();
    let refs: Vec<&Tensor> = gins.iter().collect();
    let hin: Vec<&HostTensor> = stored.iter().collect();
    let want = reference::conv3x3(&hin, &weight, &bias, cout, act);
    // The kernels with uniform weights store them as f16 for an f16 output (`WeightStorage`):
    // the blocked kernel's reference is the convolution with the f16-rounded weights, the
    // Winograd kernel's F(2x2, 3x3) replayed on the CPU with its f16-rounded transformed
    // weights.
    let weight16: Vec<f32> = weight.iter().map(|&v| half::f16::from_f32(v).to_f32()).collect();
    let want_w16 = reference::conv3x3(&hin, &weight16, &bias, cout, act);
    let want_wino16 = winograd_f16_reference(&HostTensor::concat(&hin), &weight, &bias, cout, act);
    let mut tried = 0;
    let kernels = conv.candidates(&g);
    let coop = if g.has_coop_matrix() {
        ConvKernel::coop_tilings().len()
    } else {
        0
    };
    assert_eq!(
        kernels.len(),
        1 + ConvKernel::blocked_tilings().len()
            + ConvKernel::winograd_tilings().len()
            + ConvKernel::texture_tilings().len()
            + coop
    );
    let tested = under_test(kernels.clone());
    for &kernel in &tested {
        let outputs: &[DType] = if kernel == ConvKernel::Generic || kernel.to_string() == "px4-cob2" {
            &[DType::F16, DType::F32]
        } else {
            &[DType::F16]
        };
        for &out_dtype in outputs {
            let out = Tensor::new_typed(&g, "out", w, h, cout, out_dtype).unwrap();
            let d = conv.bind_with(&g, kernel, &refs, &out).unwrap();
            // Traffic accounting follows the storage: an f16 output is half the bytes (and
            // a kernel reading textures writes its f32 copies of the inputs first).
            let copied: u64 = if kernel.reads_textures() {
                refs.iter()
                    .map(|t| (t.width * t.height * t.channels.div_ceil(4) * 16) as u64)
                    .sum()
            } else {
                0
            };
            let copies = if kernel.reads_textures() { refs.len() } else { 0 };
            assert_eq!(
                d.bytes_written,
                (d.parts() - copies) as u64 * out.bytes() + copied,
                "{kernel}"
            );
            ops::run(&g, &[&d]).unwrap();
            let (expect, tol) = match (out_dtype, kernel) {
                (DType::F16, ConvKernel::Blocked { .. }) => (to_f16(&want_w16), F16_OUT),
                (DType::F16, ConvKernel::Winograd { .. }) => (to_f16(&want_wino16), F16_OUT),
                (DType::F16, _) => (to_f16(&want), kernel_tol(kernel, &want, F16_OUT)),
                (DType::F32, _) => (want.clone(), kernel_tol(kernel, &want, REDUCTION)),
            };
            assert_tensor(
                &format!("conv3x3 {kernel} f16/f32 inputs -> {}", out_dtype.name()),
                &out,
                &expect,
                tol,
            );
            tried += 1;
        }
    }
    let both = tested
        .iter()
        .filter(|k| **k == ConvKernel::Generic || k.to_string() == "px4-cob2")
        .count();
    assert_eq!(tried, tested.len() + both);
    // An f16 output saturates at f16's largest finite value instead of overflowing.
    let big = Conv3x3::new(&g, "big", &[1.0e3; 9], &[0.0], &[1], 1, Activation::None).unwrap();
    let x = Tensor::from_host(&g, "x", &HostTensor::from_fn(4, 4, 1, |_, _, _| 100.0)).unwrap();
    let out = Tensor::new_typed(&g, "out", 4, 4, 1, DType::F16).unwrap();
    for &kernel in &kernels[..2] {
        ops::run(&g, &[&big.bind_with(&g, kernel, &[&x], &out).unwrap()]).unwrap();
        let got = out.read(&g).unwrap();
        assert!(
            got.data.iter().all(|&v| v == 65504.0),
            "{kernel}: {:?}",
            &got.data[..4]
        );
    }
    // Pooling, f16 to f16 and across storages.
    let x = random(901, 13, 7, 12, -3.0, 3.0);
    for (src, dst) in [
        (DType::F16, DType::F16),
        (DType::F32, DType::F16),
        (DType::F16, DType::F32),
    ] {
        let t = Tensor::from_host_typed(&g, "x", &x, src).unwrap();
        let stored = if src == DType::F16 { to_f16(&x) } else { x.clone() };
        for mode in [PoolMode::Max, PoolMode::Average] {
            let out = Tensor::new_typed(&g, "out", 7, 4, 12, dst).unwrap();
            ops::run(&g, &[&ops::pool2x2(&g, mode, &t, &out).unwrap()]).unwrap();
            let want = reference::pool2x2(&stored, mode);
            let (want, tol) = match (dst, mode) {
                (DType::F16, PoolMode::Max) => (to_f16(&want), EXACT),
                (DType::F16, PoolMode::Average) => (to_f16(&want), F16_OUT),
                (_, PoolMode::Max) => (want, EXACT),
                (_, PoolMode::Average) => (want, ELEMENTWISE),
            };
            assert_tensor(
                &format!("pool {mode:?} {} -> {}", src.name(), dst.name()),
                &out,
                &want,
                tol,
            );
        }
    }
    // Kernels without an f16 variant refuse f16 tensors with a named error.
    let a = Tensor::new_typed(&g, "a", 8, 8, 4, DType::F16).unwrap();
    let b = Tensor::new(&g, "b", 16, 16, 4).unwrap();
    let e = ops::upsample2x(&g, UpsampleMode::Bilinear, &a, &b)
        .unwrap_err()
        .to_string();
    assert!(e.contains("upsample2x") && e.contains("f16"), "{e}");
}

/// f16 storage in the TFA blend, the remodulation (with its ceiling, which writes o back)
/// and the converting copy (issue 14): against the CPU reference on the f16-rounded
/// inputs, an f16 result rounded to f16. Stated tolerance: the f32 kernels' plus 2^-10
/// relative for the output's rounding (one f16 ulp), as for the convolutions.
#[test]
fn tfa_blend_remodulate_and_convert_with_f16_storage_match_reference() {
    let Some(g) = f16_gpu() else { return };
    const F16_OUT: Tol = plus_f16_ulp(ELEMENTWISE);
    let stored = |t: &HostTensor, d: DType| if d == DType::F16 { to_f16(t) } else { t.clone() };
    let (w, h, k, c) = (13u32, 7u32, 8u32, 15u32);
    let host = [
        random(950, w, h, k, -1.0, 1.0),
        random(951, w, h, k, -2.0, 2.0),
        random(952, w, h, k, -2.0, 2.0),
        random(953, w, h, c, -1.0, 1.0),
        random(954, w, h, c, -1.0, 1.0),
    ];
    let valid = HostTensor::from_fn(w, h, 1, |x, y, _| ((x + y) % 3 != 0) as u32 as f32);
    // Every input f16 (the network's f16 storage: A_t stays f32), then mixed.
    for dtypes in [
        [DType::F16, DType::F16, DType::F16, DType::F32, DType::F16],
        [DType::F32, DType::F16, DType::F32, DType::F16, DType::F32],
    ] {
        let ts: Vec<Tensor> = host
            .iter()
            .zip(dtypes)
            .map(|(t, d)| Tensor::from_host_typed(&g, "t", t, d).unwrap())
            .collect();
        let r: Vec<HostTensor> = host.iter().zip(dtypes).map(|(t, d)| stored(t, d)).collect();
        let (want, want_w) = reference::tfa_blend(&r[0], &r[1], &r[2], &r[3], &r[4], &valid);
        for out_dtype in [DType::F16, DType::F32] {
            let tv = up(&g, "valid", &valid);
            let out = Tensor::new_typed(&g, "out", w, h, c, out_dtype).unwrap();
            let wts = Tensor::new(&g, "weights", w, h, 4).unwrap();
            let blend = TfaBlend {
                r: &ts[0],
                e_cur: &ts[1],
                e_prev: &ts[2],
                cur: &ts[3],
                prev: &ts[4],
                valid: &tv,
                out: &out,
                weights: &wts,
            };
            let d = ops::tfa_blend(&g, blend).unwrap();
            assert_eq!(d.bytes_written, out.bytes() + wts.bytes());
            ops::run(&g, &[&d]).unwrap();
            let case = format!("tfa blend {dtypes:?} -> {}", out_dtype.name());
            assert_close(&case, &wts.read(&g).unwrap(), &want_w, ELEMENTWISE);
            match out_dtype {
                DType::F16 => assert_tensor(&case, &out, &to_f16(&want), F16_OUT),
                DType::F32 => assert_tensor(&case, &out, &want, ELEMENTWISE),
            }
        }
    }
    // The blend's `valid` and `weights` are f32 only, refused by name otherwise.
    let f16 = |c| Tensor::new_typed(&g, "x", w, h, c, DType::F16).unwrap();
    let (r, e, a) = (f16(k), f16(k), f16(c));
    let (vh, wts) = (f16(1), Tensor::new(&g, "weights", w, h, 4).unwrap());
    let out = f16(c);
    let blend = TfaBlend {
        r: &r,
        e_cur: &e,
        e_prev: &e,
        cur: &a,
        prev: &a,
        valid: &vh,
        out: &out,
        weights: &wts,
    };
    let err = ops::tfa_blend(&g, blend).unwrap_err().to_string();
    assert!(
        err.contains("tfa_blend") && err.contains("valid") && err.contains("f16"),
        "{err}"
    );

    // Remodulation with the ceiling, o and the albedo f16: o is capped and written back in
    // f16, the output (f32) remodulated from the capped o before its rounding.
    let o0 = to_f16(&random(960, w, h, 4, -1.0, 9.0));
    let albedo = to_f16(&random(961, w, h, 3, 0.0, 1.0));
    let sc = [0.5f32, 2.0, 3.0];
    let (gain, m) = (1.5f32, [400.0f32, 300.0, 800.0]);
    let mut sv = vec![sc[0], sc[1], sc[2], 9.0, 9.0, 9.0];
    sv.extend(m);
    let scale = up(&g, "scale", &HostTensor::from_vec(1, 1, 9, sv));
    let to = Tensor::from_host_typed(&g, "o", &o0, DType::F16).unwrap();
    let ta = Tensor::from_host_typed(&g, "albedo", &albedo, DType::F16).unwrap();
    let out = Tensor::new(&g, "out", w, h, 3).unwrap();
    ops::run(
        &g,
        &[&ops::remodulate(&g, &to, &ta, 0, &scale, Some(gain), &out).unwrap()],
    )
    .unwrap();
    let capped = reference::ceiling(&o0, gain, m, sc);
    let got = to.read(&g).unwrap();
    let got3 = HostTensor::from_fn(w, h, 3, |x, y, ch| got.at(x, y, ch));
    assert_close("f16 o capped in place", &got3, &to_f16(&capped), F16_OUT);
    assert_close(
        "remodulate f16 o and albedo",
        &out.read(&g).unwrap(),
        &reference::remodulate(&capped, &albedo, 0, sc),
        ELEMENTWISE,
    );
    // An f32 output is required.
    let e = ops::remodulate(&g, &to, &ta, 0, &scale, None, &f16(3))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("remodulate") && e.contains("out") && e.contains("f16"),
        "{e}"
    );

    // The converting copy (the first frame's A_t into W(A_acc)): f32 to f16 rounds (and
    // saturates at f16's largest finite value), f16 to f32 is exact.
    let mut x = random(970, w, h, c, -3.0, 3.0);
    x.data[0] = 1.0e6;
    x.data[1] = -1.0e6;
    let t32 = up(&g, "x", &x);
    let t16 = f16(c);
    let back = Tensor::new(&g, "back", w, h, c).unwrap();
    ops::run(
        &g,
        &[
            &ops::convert(&g, &t32, &t16).unwrap(),
            &ops::convert(&g, &t16, &back).unwrap(),
        ],
    )
    .unwrap();
    let mut want = to_f16(&x);
    want.data[0] = 65504.0;
    want.data[1] = -65504.0;
    let one_ulp = Tol {
        abs: 0.0,
        rel: 1.0 / 1024.0,
    };
    assert_tensor("convert f32 -> f16", &t16, &want, one_ulp);
    assert_close(
        "convert f16 -> f32",
        &back.read(&g).unwrap(),
        &t16.read(&g).unwrap(),
        EXACT,
    );
}

/// A layer whose single output block's weights exceed the blocked kernel's uniform array
/// runs on the generic kernel only (and on the cooperative-matrix kernel where the device
/// has it: its weights are in storage); asking for a tiling anyway is an error naming the
/// layer and why.
#[test]
fn conv3x3_too_large_for_uniform_weights_falls_back_to_generic() {
    let g = gpu();
    let (cin, cout) = (512u32, 8u32); // one output vec4: 9 * 128 * 4 = 4608 vec4s > 4096
    let conv = Conv3x3::new(
        &g,
        "wide",
        &vec![0.01; (cin * cout * 9) as usize],
        &vec![0.0; cout as usize],
        &[cin],
        cout,
        Activation::Relu,
    )
    .unwrap();
    let coop = if g.has_coop_matrix() {
        ConvKernel::coop_tilings()
    } else {
        vec![]
    };
    assert_eq!(conv.candidates(&g), [vec![ConvKernel::Generic], coop].concat());
    let x = Tensor::new(&g, "x", 8, 8, cin).unwrap();
    let out = Tensor::new(&g, "out", 8, 8, cout).unwrap();
    let e = conv
        .bind_with(
            &g,
            ConvKernel::Blocked {
                px: 4,
                cob: 1,
                tex: false,
            },
            &[&x],
            &out,
        )
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("wide") && e.contains("px4-cob1") && e.contains("4096"),
        "{e}"
    );
}

/// Issue 14: the cooperative-matrix kernel on a device without cooperative matrices (Debian
/// 12's lavapipe, and any device unless `SUBPIXEL_COOP_MATRIX=1`) is never a candidate, and
/// asking for it is an error that names the layer and how to opt in. Under
/// `SUBPIXEL_EXPECT_COOP=1` (`tools/lavapipe_coop.sh`) a device without them fails instead:
/// the other tests would silently leave the kernel out.
#[test]
fn conv3x3_coop_without_cooperative_matrices_is_a_named_error() {
    let g = gpu();
    assert!(
        g.has_coop_matrix() || std::env::var("SUBPIXEL_EXPECT_COOP").as_deref() != Ok("1"),
        "SUBPIXEL_EXPECT_COOP=1 but {} has no cooperative matrices",
        g.describe()
    );
    if g.has_coop_matrix() {
        eprintln!("skipped: {} has cooperative matrices", g.describe());
        return;
    }
    let mut conv = Conv3x3::new(&g, "tc", &[0.5; 27], &[0.0], &[3], 1, Activation::None).unwrap();
    assert!(
        conv.candidates(&g)
            .iter()
            .all(|k| !matches!(k, ConvKernel::Coop { .. })),
        "{:?}",
        conv.candidates(&g)
    );
    let e = conv
        .set_kernel(&g, ConvKernel::Coop { mt: 1, nt: 1, rt: 1 })
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("'tc'") && e.contains("coop-m1-n1-r1") && e.contains("SUBPIXEL_COOP_MATRIX=1"),
        "{e}"
    );
}

#[test]
fn conv3x3_identity_copies_input() {
    let g = gpu();
    for &c in CHANNELS {
        let x = random(3, 33, 17, c, -2.0, 2.0);
        let mut weight = vec![0.0; (c * c * 9) as usize];
        for i in 0..c {
            weight[((i * c + i) * 9 + 4) as usize] = 1.0; // centre tap
        }
        let conv = Conv3x3::new(
            &g,
            "identity",
            &weight,
            &vec![0.0; c as usize],
            &[c],
            c,
            Activation::None,
        )
        .unwrap();
        let t = up(&g, "x", &x);
        let out = Tensor::new(&g, "out", 33, 17, c).unwrap();
        ops::run(&g, &[&conv.bind(&g, &[&t], &out).unwrap()]).unwrap();
        assert_tensor(&format!("identity conv c={c}"), &out, &x, EXACT);
    }
}

#[test]
fn conv3x3_rejects_bad_shapes_with_named_errors() {
    let g = gpu();
    let w9 = vec![0.0; 4 * 3 * 9];
    let e = Conv3x3::new(&g, "enc1.0", &w9[..10], &[0.0; 4], &[3], 4, Activation::None).unwrap_err();
    assert!(
        e.to_string().contains("enc1.0") && e.to_string().contains("[4, 3, 3, 3]"),
        "{e}"
    );
    let conv = Conv3x3::new(&g, "enc1.0", &w9, &[0.0; 4], &[3], 4, Activation::None).unwrap();
    let x4 = Tensor::new(&g, "x", 8, 8, 4).unwrap();
    let out = Tensor::new(&g, "out", 8, 8, 4).unwrap();
    let e = conv.bind(&g, &[&x4], &out).unwrap_err().to_string();
    assert!(
        e.contains("enc1.0") && e.contains("[4]") && e.contains("[3]"),
        "{e}"
    );
    let x3 = Tensor::new(&g, "x", 8, 7, 3).unwrap();
    let e = conv.bind(&g, &[&x3], &out).unwrap_err().to_string();
    assert!(e.contains("8x7") && e.contains("8x8"), "{e}");
    let e = Tensor::new(&g, "empty", 0, 8, 3).unwrap_err().to_string();
    assert!(e.contains("0x8x3"), "{e}");
    let e = Conv3x3::new(&g, "five", &[], &[], &[1, 1, 1, 1, 1], 1, Activation::None).unwrap_err();
    assert!(e.to_string().contains("1 to 4"), "{e}");
}

#[test]
fn pooling_matches_reference_and_keeps_constants() {
    let g = gpu();
    for &(w, h) in SIZES {
        for &c in CHANNELS {
            let x = random(w as u64 * 31 + c as u64, w, h, c, -1.0, 1.0);
            let t = up(&g, "x", &x);
            for mode in [PoolMode::Max, PoolMode::Average] {
                let out = Tensor::new(&g, "out", w.div_ceil(2), h.div_ceil(2), c).unwrap();
                ops::run(&g, &[&ops::pool2x2(&g, mode, &t, &out).unwrap()]).unwrap();
                let tol = if mode == PoolMode::Max { EXACT } else { ELEMENTWISE };
                assert_tensor(
                    &format!("pool {mode:?} {w}x{h}x{c}"),
                    &out,
                    &reference::pool2x2(&x, mode),
                    tol,
                );
                let k = up(&g, "k", &HostTensor::from_fn(w, h, c, |_, _, _| 0.375));
                ops::run(&g, &[&ops::pool2x2(&g, mode, &k, &out).unwrap()]).unwrap();
                let konst = HostTensor::from_fn(w.div_ceil(2), h.div_ceil(2), c, |_, _, _| 0.375);
                assert_tensor(&format!("pool constant {mode:?} {w}x{h}"), &out, &konst, EXACT);
            }
        }
    }
}

#[test]
fn upsampling_matches_reference_and_keeps_constants() {
    let g = gpu();
    for &(w, h) in SIZES {
        for &c in CHANNELS {
            let x = random(w as u64 * 17 + c as u64, w, h, c, -1.0, 1.0);
            let t = up(&g, "x", &x);
            for mode in [UpsampleMode::Nearest, UpsampleMode::Bilinear] {
                for (ow, oh) in [(2 * w, 2 * h), (2 * w - 1, 2 * h - 1)] {
                    let out = Tensor::new(&g, "out", ow, oh, c).unwrap();
                    ops::run(&g, &[&ops::upsample2x(&g, mode, &t, &out).unwrap()]).unwrap();
                    let tol = if mode == UpsampleMode::Nearest {
                        EXACT
                    } else {
                        ELEMENTWISE
                    };
                    assert_tensor(
                        &format!("upsample {mode:?} {w}x{h}x{c} -> {ow}x{oh}"),
                        &out,
                        &reference::upsample2x(&x, mode, ow, oh),
                        tol,
                    );
                }
                let k = up(&g, "k", &HostTensor::from_fn(w, h, c, |_, _, _| -1.25));
                let out = Tensor::new(&g, "out", 2 * w, 2 * h, c).unwrap();
                ops::run(&g, &[&ops::upsample2x(&g, mode, &k, &out).unwrap()]).unwrap();
                let konst = HostTensor::from_fn(2 * w, 2 * h, c, |_, _, _| -1.25);
                assert_tensor(&format!("upsample constant {mode:?}"), &out, &konst, EXACT);
            }
        }
    }
    let out = Tensor::new(&g, "out", 10, 10, 3).unwrap();
    let small = Tensor::new(&g, "in", 4, 4, 3).unwrap();
    let e = ops::upsample2x(&g, UpsampleMode::Bilinear, &small, &out)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("upsample2x") && e.contains("10x10") && e.contains("4x4"),
        "{e}"
    );
}

/// Random motion: mostly small, some off screen, some zero, one NaN.
fn random_motion(seed: u64, w: u32, h: u32) -> HostTensor {
    let m = random(seed, w, h, 2, -3.0, 3.0);
    let big = random(seed + 1, w, h, 2, -2.0 * w.max(h) as f32, 2.0 * w.max(h) as f32);
    let mut out = HostTensor::from_fn(w, h, 2, |x, y, c| match (x + 3 * y) % 5 {
        0 => 0.0,
        1 => big.at(x, y, c),
        _ => m.at(x, y, c),
    });
    if w * h > 4 {
        out.set(1, 0, 0, f32::NAN);
    }
    out
}

#[test]
fn warp_matches_reference() {
    let g = gpu();
    for &(w, h) in SIZES {
        for &c in CHANNELS {
            let x = random(c as u64 + w as u64, w, h, c, -1.0, 1.0);
            let mv = random_motion(w as u64 * 7 + c as u64, w, h);
            let (tx, tm) = (up(&g, "x", &x), up(&g, "motion", &mv));
            let out = Tensor::new(&g, "out", w, h, c).unwrap();
            let valid = Tensor::new(&g, "valid", w, h, 1).unwrap();
            ops::run(&g, &[&ops::warp(&g, &tx, &tm, &out, &valid).unwrap()]).unwrap();
            let (ro, rv) = reference::warp(&x, &mv);
            assert_tensor(&format!("warp valid {w}x{h}"), &valid, &rv, EXACT);
            assert_tensor(&format!("warp {w}x{h}x{c}"), &out, &ro, ELEMENTWISE);
        }
    }
}

#[test]
fn warp_zero_motion_is_identity_and_off_screen_is_invalid() {
    let g = gpu();
    let (w, h) = (33, 17);
    let x = random(5, w, h, 13, -1.0, 1.0);
    let tx = up(&g, "x", &x);
    let out = Tensor::new(&g, "out", w, h, 13).unwrap();
    let valid = Tensor::new(&g, "valid", w, h, 1).unwrap();
    let zero = up(&g, "motion", &HostTensor::zeros(w, h, 2));
    ops::run(&g, &[&ops::warp(&g, &tx, &zero, &out, &valid).unwrap()]).unwrap();
    assert_tensor("zero-motion warp", &out, &x, EXACT);
    assert!(valid.read(&g).unwrap().data.iter().all(|&v| v == 1.0));
    // Everything moves one full screen to the left: all invalid, all zero.
    let off = up(
        &g,
        "motion",
        &HostTensor::from_fn(w, h, 2, |_, _, c| if c == 0 { -(w as f32) } else { 0.0 }),
    );
    ops::run(&g, &[&ops::warp(&g, &tx, &off, &out, &valid).unwrap()]).unwrap();
    assert!(valid.read(&g).unwrap().data.iter().all(|&v| v == 0.0));
    assert!(out.read(&g).unwrap().data.iter().all(|&v| v == 0.0));
    // A half-pixel shift right averages two neighbours.
    let half = up(
        &g,
        "motion",
        &HostTensor::from_fn(w, h, 2, |_, _, c| if c == 0 { 0.5 } else { 0.0 }),
    );
    ops::run(&g, &[&ops::warp(&g, &tx, &half, &out, &valid).unwrap()]).unwrap();
    let o = out.read(&g).unwrap();
    for y in 0..h {
        for xx in 0..w - 1 {
            let want = 0.5 * (x.at(xx, y, 2) + x.at(xx + 1, y, 2));
            assert!((o.at(xx, y, 2) - want).abs() < 1e-6);
        }
    }
}

#[test]
fn tfa_blend_matches_reference_and_weights_sum_to_one() {
    let g = gpu();
    for &(w, h) in SIZES {
        for &c in CHANNELS {
            let k = 8;
            let seed = w as u64 * 13 + c as u64;
            let hr = random(seed, w, h, k, -1.0, 1.0);
            let hec = random(seed + 1, w, h, k, -2.0, 2.0);
            let hep = random(seed + 2, w, h, k, -2.0, 2.0);
            let hcur = random(seed + 3, w, h, c, -1.0, 1.0);
            let hprev = random(seed + 4, w, h, c, -1.0, 1.0);
            let hvalid = HostTensor::from_fn(w, h, 1, |x, y, _| ((x + y) % 3 != 0) as u32 as f32);
            let ts: Vec<Tensor> = [&hr, &hec, &hep, &hcur, &hprev, &hvalid]
                .iter()
                .map(|t| up(&g, "t", t))
                .collect();
            let out = Tensor::new(&g, "out", w, h, c).unwrap();
            let wts = Tensor::new(&g, "weights", w, h, 4).unwrap();
            let d = ops::tfa_blend(
                &g,
                TfaBlend {
                    r: &ts[0],
                    e_cur: &ts[1],
                    e_prev: &ts[2],
                    cur: &ts[3],
                    prev: &ts[4],
                    valid: &ts[5],
                    out: &out,
                    weights: &wts,
                },
            )
            .unwrap();
            ops::run(&g, &[&d]).unwrap();
            let (ro, rw) = reference::tfa_blend(&hr, &hec, &hep, &hcur, &hprev, &hvalid);
            let gw = wts.read(&g).unwrap();
            assert_close(&format!("tfa weights {w}x{h}"), &gw, &rw, ELEMENTWISE);
            assert_tensor(&format!("tfa blend {w}x{h}x{c}"), &out, &ro, ELEMENTWISE);
            for y in 0..h {
                for x in 0..w {
                    let (beta, alpha) = (gw.at(x, y, 0), gw.at(x, y, 1));
                    assert!((alpha + beta - 1.0).abs() < 1e-6, "weights sum {}", alpha + beta);
                    assert!((0.0..=1.0).contains(&alpha));
                    if hvalid.at(x, y, 0) == 0.0 {
                        assert_eq!(alpha, 0.0, "invalid history must get weight 0");
                    }
                }
            }
        }
    }
}

#[test]
fn demodulate_and_remodulate_match_reference_and_invert() {
    let g = gpu();
    for &(w, h) in SIZES {
        for &c in CHANNELS {
            let mut color = random(w as u64 + 3 * c as u64, w, h, c, 0.0, 50.0);
            color.data[0] = f32::NAN;
            if color.data.len() > 2 {
                color.data[1] = f32::INFINITY;
                color.data[2] = -1.0;
            }
            let albedo = random(w as u64 + 5, w, h, c, 0.0, 1.0);
            let off = c - 3; // albedo channels off..off+3, unaligned for most c
            let (tc, ta) = (up(&g, "color", &color), up(&g, "albedo", &albedo));
            let e = Tensor::new(&g, "e", w, h, 3).unwrap();
            let back = Tensor::new(&g, "back", w, h, 3).unwrap();
            let sc = [0.5f32, 2.0, 3.0]; // the exposure the SSR output is scaled by
            let scale = up(&g, "scale", &HostTensor::from_vec(1, 1, 3, sc.to_vec()));
            ops::run(
                &g,
                &[
                    &ops::demodulate(&g, &tc, &ta, off, &e).unwrap(),
                    &ops::remodulate(&g, &e, &ta, off, &scale, None, &back).unwrap(),
                ],
            )
            .unwrap();
            let re = reference::demodulate(&color, &albedo, off);
            let ge = e.read(&g).unwrap();
            assert!(ge.data.iter().all(|v| v.is_finite()), "NaN/Inf must be sanitised");
            assert_close(&format!("demodulate {w}x{h}x{c}"), &ge, &re, ELEMENTWISE);
            let gb = back.read(&g).unwrap();
            assert_close(
                &format!("remodulate {w}x{h}x{c}"),
                &gb,
                &reference::remodulate(&re, &albedo, off, sc),
                ELEMENTWISE,
            );
            // remodulate(demodulate(x)) == x * scale for finite non-negative colour
            let clean = HostTensor::from_fn(w, h, 3, |x, y, ch| {
                let v = color.at(x, y, ch);
                (if v.is_finite() && v >= 0.0 { v } else { 0.0 }) * sc[ch as usize]
            });
            assert_close(
                "demod/remod round trip",
                &gb,
                &clean,
                Tol { abs: 1e-4, rel: 1e-4 },
            );
        }
    }
}

/// The SSR output ceiling in nn/remodulate: o capped at ln(1 + g M / s_c) (M = channel 6 of
/// the scale tensor), written back into o, and the output remodulated from the capped o;
/// against the CPU reference, on values on both sides of the cap.
#[test]
fn remodulate_with_a_ceiling_caps_o_in_place() {
    let g = gpu();
    for &(w, h) in SIZES {
        let o0 = random(w as u64 + 11, w, h, 4, -1.0, 9.0);
        let albedo = random(w as u64 + 13, w, h, 3, 0.0, 1.0);
        let sc = [0.5f32, 2.0, 3.0];
        let (gain, m) = (1.5f32, [400.0f32, 300.0, 800.0]); // caps ln(1 + g m_c / s_c): 7.1, 5.4, 6.0
        let mut s = vec![sc[0], sc[1], sc[2], 9.0, 9.0, 9.0];
        s.extend(m);
        let scale_host = HostTensor::from_vec(1, 1, 9, s);
        let (to, ta) = (up(&g, "o", &o0), up(&g, "albedo", &albedo));
        let scale = up(&g, "scale", &scale_host);
        let out = Tensor::new(&g, "out", w, h, 3).unwrap();
        let d = ops::remodulate(&g, &to, &ta, 0, &scale, Some(gain), &out).unwrap();
        ops::run(&g, &[&d]).unwrap();
        let capped = reference::ceiling(&o0, gain, m, sc);
        let got = to.read(&g).unwrap();
        let got3 = HostTensor::from_fn(w, h, 3, |x, y, c| got.at(x, y, c));
        assert_close(&format!("ceiling {w}x{h}"), &got3, &capped, ELEMENTWISE);
        let clamped = (0..w * h * 3)
            .filter(|&i| capped.data[i as usize] < o0.at(i / 3 % w, i / 3 / w, i % 3))
            .count();
        if w * h > 30 {
            assert!(
                clamped > 0 && clamped < (w * h * 3) as usize,
                "{clamped} capped: both sides tested"
            );
        }
        for y in 0..h {
            for x in 0..w {
                assert_eq!(got.at(x, y, 3), o0.at(x, y, 3), "channel 3 of o is kept");
            }
        }
        assert_close(
            &format!("remodulate with ceiling {w}x{h}"),
            &out.read(&g).unwrap(),
            &reference::remodulate(&capped, &albedo, 0, sc),
            ELEMENTWISE,
        );
    }
    // a scale without M, a bad gain: errors naming them
    let o = up(&g, "o", &random(1, 4, 4, 3, 0.0, 1.0));
    let out = Tensor::new(&g, "out", 4, 4, 3).unwrap();
    let s3 = up(&g, "scale", &HostTensor::from_vec(1, 1, 3, vec![1.0; 3]));
    let e = ops::remodulate(&g, &o, &o, 0, &s3, Some(1.0), &out)
        .unwrap_err()
        .to_string();
    assert!(e.contains("scale"), "{e}");
    let s9 = up(&g, "scale", &HostTensor::from_vec(1, 1, 9, vec![1.0; 9]));
    let e = ops::remodulate(&g, &o, &o, 0, &s9, Some(f32::NAN), &out)
        .unwrap_err()
        .to_string();
    assert!(e.contains("ceiling gain"), "{e}");
}

#[test]
fn zero_sized_and_oversized_dispatches_are_errors() {
    let g = gpu();
    let e = g
        .kernels
        .dispatch(
            "nn/resample2x",
            &Default::default(),
            &[0u8; 80],
            &[],
            Grid::Workgroups([0, 1, 1]),
        )
        .unwrap_err()
        .to_string();
    assert!(e.contains("nn/resample2x") && e.contains("zero-sized"), "{e}");
    let big = g.device.limits().max_compute_workgroups_per_dimension + 1;
    let e = g
        .kernels
        .dispatch(
            "nn/resample2x",
            &Default::default(),
            &[0u8; 80],
            &[],
            Grid::Invocations([8 * big, 1, 1]),
        )
        .unwrap_err()
        .to_string();
    assert!(e.contains("exceeds"), "{e}");
    // Invocation grids become workgroups of the kernel's own size (resample2x: 8x8), in 2D
    // for large images (2048x1024 -> 1024x512: 128 x 64 workgroups). Only checks that the
    // dispatch is accepted (built), not run, to keep the CPU adapter fast.
    for ((w, h), groups) in [((18, 10), [2, 1, 1]), ((2048, 1024), [128, 64, 1])] {
        let x = Tensor::new(&g, "x", w, h, 4).unwrap();
        let out = Tensor::new(&g, "out", w.div_ceil(2), h.div_ceil(2), 4).unwrap();
        let d = ops::pool2x2(&g, PoolMode::Max, &x, &out).unwrap();
        assert_eq!(d.groups, groups, "{w}x{h}");
    }
}

#[test]
fn missing_feature_is_a_named_error() {
    let g = gpu();
    // Never requested by the crate, so no device has it.
    let e = g
        .require(
            wgpu::Features::TEXTURE_COMPRESSION_BC,
            "a BC-compressed texture path",
        )
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("a BC-compressed texture path") && e.contains(&g.info.name),
        "{e}"
    );
}
