//! `subpixel bench kernels`: every network kernel timed in isolation.

use crate::error::Result;
use crate::gpu::{Dispatch, Gpu, Stats, time_dispatch};
use crate::nn::autotune;
use crate::nn::ops::{self, Activation, Conv3x3, ConvKernel, PoolMode, TfaBlend, UpsampleMode};
use crate::nn::{HostTensor, Tensor};

/// Options of the kernel benchmark.
#[derive(Debug, Clone)]
pub struct KernelBenchOptions {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Channels of the tensors (conv3x3 is `channels -> channels`).
    pub channels: u32,
    /// Untimed runs first.
    pub warmup: u32,
    /// Timed runs.
    pub iterations: u32,
}

/// One kernel's timing.
#[derive(Debug, Clone, serde::Serialize)]
pub struct KernelTiming {
    /// Kernel and variant.
    pub name: String,
    /// Timing statistics.
    pub stats: Stats,
    /// Whether the time comes from GPU timestamps (else CPU wall time).
    pub gpu_timestamps: bool,
    /// Bytes read and written per run.
    pub bytes: u64,
    /// Floating-point operations per run (0 for data movement).
    pub flops: u64,
    /// Achieved GB/s at the median.
    pub gb_per_s: f64,
    /// Achieved GFLOP/s at the median (0 for data movement).
    pub gflop_per_s: f64,
    /// Fraction of the adapter's FP32 peak, where known.
    pub fraction_of_peak: Option<f64>,
}

struct Case {
    name: String,
    dispatch: Dispatch,
    bytes: u64,
    flops: u64,
}

fn random(w: u32, h: u32, c: u32, seed: u32) -> HostTensor {
    // A cheap deterministic hash; the values only need to be non-trivial.
    HostTensor::from_fn(w, h, c, |x, y, ch| {
        let mut v = x.wrapping_mul(73856093) ^ y.wrapping_mul(19349663) ^ ch.wrapping_mul(83492791) ^ seed;
        v ^= v >> 13;
        v = v.wrapping_mul(0x5bd1e995);
        v ^= v >> 15;
        (v & 0xffff) as f32 / 65535.0 - 0.5
    })
}

/// The benchmark's convolution: `c -> c` channels, relu, fixed non-trivial weights.
fn bench_conv(gpu: &Gpu, c: u32) -> Result<Conv3x3> {
    let wts: Vec<f32> = (0..c * c * 9).map(|i| ((i % 17) as f32 - 8.0) * 0.01).collect();
    Conv3x3::new(
        gpu,
        "bench",
        &wts,
        &vec![0.0; c as usize],
        &[c],
        c,
        Activation::Relu,
    )
}

/// Runs the benchmark and returns one row per kernel variant.
pub fn bench_kernels(gpu: &Gpu, o: &KernelBenchOptions) -> Result<Vec<KernelTiming>> {
    let (w, h, c) = (o.width, o.height, o.channels);
    let t = |name: &str, w, h, c, seed| Tensor::from_host(gpu, name, &random(w, h, c, seed));
    let x = t("x", w, h, c, 1)?;
    let y = Tensor::new(gpu, "y", w, h, c)?;
    let half = Tensor::new(gpu, "half", w.div_ceil(2), h.div_ceil(2), c)?;
    let small = t("small", w.div_ceil(2), h.div_ceil(2), c, 2)?;
    let k = 8;
    let (r, ec, ep) = (t("r", w, h, k, 3)?, t("ec", w, h, k, 4)?, t("ep", w, h, k, 5)?);
    let prev = t("prev", w, h, c, 6)?;
    let weights = Tensor::new(gpu, "weights", w, h, 4)?;
    let motion = t("motion", w, h, 2, 7)?;
    let valid = Tensor::new(gpu, "valid", w, h, 1)?;
    let rgb = t("rgb", w, h, 3, 8)?;
    let albedo = t("albedo", w, h, 3, 9)?;
    let rgb_out = Tensor::new(gpu, "rgb_out", w, h, 3)?;
    let ones = Tensor::from_host(gpu, "ones", &HostTensor::from_vec(1, 1, 3, vec![1.0; 3]))?;

    let px = w as u64 * h as u64;
    let b = |t: &Tensor| t.bytes();
    let mut cases = Vec::new();
    let conv = bench_conv(gpu, c)?;
    let candidates = conv.candidates(gpu);
    // The experimental tensor-core kernel: its agreement with the CPU reference (what the
    // autotuner requires) beside its time, all tilings on one set of inputs; a failure is
    // reported, not fatal.
    let coop: Vec<ConvKernel> = candidates
        .iter()
        .copied()
        .filter(|k| matches!(k, ConvKernel::Coop { .. }))
        .collect();
    let (cw, ch) = autotune::COOP_CHECK_SIZE;
    let mut coop_errors = if coop.is_empty() {
        Vec::new()
    } else {
        conv.output_errors(gpu, &coop, cw, ch, &[])?
    }
    .into_iter();
    for kernel in candidates {
        let mut name = format!("conv3x3 {c}->{c} relu {kernel}");
        let dispatch = if let ConvKernel::Coop { .. } = kernel {
            let checked = coop_errors
                .next()
                .expect("one check per cooperative tiling")
                .and_then(|e| Ok((e, conv.bind_with(gpu, kernel, &[&x], &y)?)));
            match checked {
                Ok((e, d)) => {
                    name += &format!(" (error vs CPU {e:.1e})");
                    d
                }
                Err(e) => {
                    log::warn!("conv3x3 {kernel} skipped: {e}");
                    continue;
                }
            }
        } else {
            conv.bind_with(gpu, kernel, &[&x], &y)?
        };
        cases.push(Case {
            name,
            dispatch,
            bytes: b(&x) + b(&y) + (c * c * 9 * 4) as u64,
            flops: conv.flops_per_pixel() * px,
        });
    }
    for (mode, n) in [(PoolMode::Max, "max"), (PoolMode::Average, "avg")] {
        cases.push(Case {
            name: format!("pool2x2 {n}"),
            dispatch: ops::pool2x2(gpu, mode, &x, &half)?,
            bytes: b(&x) + b(&half),
            flops: 0,
        });
    }
    for (mode, n) in [
        (UpsampleMode::Nearest, "nearest"),
        (UpsampleMode::Bilinear, "bilinear"),
    ] {
        cases.push(Case {
            name: format!("upsample2x {n}"),
            dispatch: ops::upsample2x(gpu, mode, &small, &y)?,
            bytes: b(&small) + b(&y),
            flops: 0,
        });
    }
    cases.push(Case {
        name: format!("tfa_blend K={k}"),
        dispatch: ops::tfa_blend(
            gpu,
            TfaBlend {
                r: &r,
                e_cur: &ec,
                e_prev: &ep,
                cur: &x,
                prev: &prev,
                valid: &valid,
                out: &y,
                weights: &weights,
            },
        )?,
        bytes: 3 * b(&r) + 3 * b(&x) + b(&valid) + b(&weights),
        flops: 0,
    });
    cases.push(Case {
        name: "warp".into(),
        dispatch: ops::warp(gpu, &x, &motion, &y, &valid)?,
        bytes: 2 * b(&x) + b(&motion) + b(&valid),
        flops: 0,
    });
    cases.push(Case {
        name: "demodulate".into(),
        dispatch: ops::demodulate(gpu, &rgb, &albedo, 0, &rgb_out)?,
        bytes: 3 * b(&rgb),
        flops: 0,
    });
    cases.push(Case {
        name: "remodulate".into(),
        dispatch: ops::remodulate(gpu, &rgb, &albedo, 0, &ones, None, &rgb_out)?,
        bytes: 3 * b(&rgb),
        flops: 0,
    });

    let peak = crate::bench::peak_fp32_gflops(&gpu.info.name);
    let mut rows = Vec::new();
    for case in &cases {
        let (stats, gpu_timestamps) = time_dispatch(gpu, &case.dispatch, o.warmup, o.iterations)?;
        let secs = stats.median_ms * 1e-3;
        let gflop_per_s = if case.flops > 0 {
            case.flops as f64 / secs * 1e-9
        } else {
            0.0
        };
        rows.push(KernelTiming {
            name: case.name.clone(),
            stats,
            gpu_timestamps,
            bytes: case.bytes,
            flops: case.flops,
            gb_per_s: case.bytes as f64 / secs * 1e-9,
            gflop_per_s,
            fraction_of_peak: peak.filter(|_| case.flops > 0).map(|p| gflop_per_s / p),
        });
    }
    Ok(rows)
}

/// The autotuner's kernel for the benchmark's conv3x3 (`channels -> channels`, relu) at
/// its size: `(choice, whether it came from the cache, the size it was tuned at)`.
pub fn conv_choice(gpu: &Gpu, o: &KernelBenchOptions) -> Result<(ConvKernel, bool, (u32, u32))> {
    let conv = bench_conv(gpu, o.channels)?;
    let storage = autotune::LayerStorage::f32(&conv);
    let (t, cached) = autotune::tune(gpu, &conv, o.width, o.height, &storage, None)?;
    let size = autotune::tuning_size(gpu, &conv, o.width, o.height, &storage);
    Ok((t.choice, cached, size))
}

/// Formats the rows as a table.
pub fn table(rows: &[KernelTiming]) -> String {
    let width = rows.iter().map(|r| r.name.len()).max().unwrap_or(0).max(34);
    let mut s = format!(
        "{:<width$} {:>10} {:>10} {:>10} {:>11} {:>9}\n",
        "kernel", "median ms", "p95 ms", "GB/s", "GFLOP/s", "% peak"
    );
    for r in rows {
        let gf = if r.flops > 0 {
            format!("{:.1}", r.gflop_per_s)
        } else {
            "-".into()
        };
        let pk = r
            .fraction_of_peak
            .map(|f| format!("{:.1}", 100.0 * f))
            .unwrap_or_else(|| "-".into());
        s += &format!(
            "{:<width$} {:>10.4} {:>10.4} {:>10.1} {:>11} {:>9}\n",
            r.name, r.stats.median_ms, r.stats.p95_ms, r.gb_per_s, gf, pk
        );
    }
    s
}
