//! `subpixel bench denoise`: the SSR network timed per layer and per stage.

use super::roofline::{self, GpuModel, ModelledPass};
use crate::error::Result;
use crate::gpu::{AdapterKind, Gpu, Profiler, Stats};
use crate::nn::HostTensor;
use crate::nn::autotune::{EngineOptions, Precision};
use crate::ssr::{Denoiser, FrameInputs, Granularity, HostFrame, Weights};

/// One timed step.
#[derive(Debug, Clone, serde::Serialize)]
pub struct LayerTiming {
    /// Stage (`pack`, `tfa`, `unet`, `output`).
    pub stage: String,
    /// Layer label.
    pub name: String,
    /// FLOPs per frame (0 for data movement).
    pub flops: u64,
    /// Timing.
    pub stats: Stats,
    /// Achieved GFLOP/s at the median.
    pub gflop_per_s: f64,
}

/// Result of the denoiser benchmark.
#[derive(Debug, Clone, serde::Serialize)]
pub struct DenoiseBench {
    /// Adapter description.
    pub adapter: String,
    /// Frame size.
    pub width: u32,
    /// Frame height.
    pub height: u32,
    /// Timed frames.
    pub frames: u32,
    /// Whether GPU timestamps were used.
    pub gpu_timestamps: bool,
    /// Whether the adapter is a CPU driver (lavapipe), where `wall_ms` is the figure to
    /// compare with CPU implementations.
    pub cpu_adapter: bool,
    /// Median CPU wall time per frame, from submit to done (the stage run).
    pub wall_ms: f64,
    /// Whether each pass's own timestamps are meaningful (GPU timestamps on an adapter that
    /// is not a CPU driver: lavapipe's do not add up to the stage totals).
    pub per_pass_timestamps: bool,
    /// Per-layer timings (each layer in its own pass).
    pub layers: Vec<LayerTiming>,
    /// Per-stage timings (one pass per stage, as in production).
    pub stages: Vec<LayerTiming>,
    /// Median of the per-frame total of the stage timings, ms.
    pub total_ms: f64,
    /// FLOPs per frame.
    pub total_flops: u64,
    /// FLOPs per pixel.
    pub flops_per_pixel: f64,
    /// Achieved GFLOP/s over the whole network.
    pub gflop_per_s: f64,
    /// Fraction of the adapter's FP32 peak, where known.
    pub fraction_of_peak: Option<f64>,
    /// Each convolution layer and its kernel (autotuned or fixed).
    pub conv_kernels: Vec<(String, String)>,
    /// Dispatches per frame.
    pub dispatches: usize,
    /// Bytes of GPU memory the network's tensors hold (transient tensors share memory).
    pub tensor_bytes: u64,
    /// The GPU the roofline model describes.
    pub model: GpuModel,
    /// Storage of the network's interior activations (`f32`, `f16`).
    pub activations: String,
    /// Every pass of a frame in the roofline model.
    pub modelled: Vec<ModelledPass>,
    /// Their sum, ms.
    pub modelled_ms: f64,
}

/// A synthetic frame with every buffer non-trivial.
pub fn synthetic_frame(w: u32, h: u32, t: u32) -> HostFrame {
    let (dx, dy) = [(0, 0), (1, 1), (1, 0), (0, 1)][t as usize % 4];
    let mask = HostTensor::from_fn(w, h, 1, |x, y, _| (x % 2 == dx && y % 2 == dy) as u32 as f32);
    let f = |c, g: fn(u32, u32, u32) -> f32| HostTensor::from_fn(w, h, c, g);
    HostFrame {
        color: HostTensor::from_fn(w, h, 3, |x, y, c| {
            mask.at(x, y, 0) * ((x + 3 * y + c) % 7) as f32 * 0.3
        }),
        mask: mask.clone(),
        albedo: f(3, |x, _, c| 0.2 + 0.2 * ((x / 8 + c) % 4) as f32),
        normal: f(3, |_, _, c| if c == 2 { 1.0 } else { 0.0 }),
        shadow: HostTensor::from_fn(w, h, 3, |x, y, _| mask.at(x, y, 0)),
        transparent: f(3, |_, _, _| 0.0),
        depth: f(1, |_, y, _| 0.5 + 0.001 * y as f32),
        metallic: f(1, |_, _, _| 0.0),
        roughness: f(1, |_, _, _| 0.5),
        motion: f(2, |_, _, c| if c == 0 { 0.25 } else { 0.0 }),
        background: None,
    }
}

/// Times the network on synthetic frames: `(warmup, frames)`: untimed frames, then timed,
/// once with a pass per layer and once with a pass per stage (with `frames == 0`: one
/// untimed frame, for the roofline model alone), and models each pass on `model`. The
/// activations are stored as `precision` resolves.
pub fn bench_denoise(
    gpu: &Gpu,
    weights: &Weights,
    (w, h): (u32, u32),
    (warmup, frames): (u32, u32),
    model: &GpuModel,
    precision: Precision,
) -> Result<DenoiseBench> {
    let options = EngineOptions {
        precision,
        ..Default::default()
    };
    let mut den = Denoiser::with_options(gpu, weights, w, h, options)?;
    let mut packed: Vec<Vec<[f32; 4]>> = synthetic_frame(w, h, 0)
        .pack(crate::ssr::AlbedoSource::Centre)?
        .into();
    // Any further buffer the model needs (background and emission for one that draws the
    // directly seen emission): none in view (zero environment, coverage 0, zero emission).
    packed.resize(
        weights.config.input_names()?.len(),
        vec![[0f32; 4]; (w * h) as usize],
    );
    let bufs: Vec<wgpu::Buffer> = packed
        .iter()
        .map(|d| {
            use wgpu::util::DeviceExt;
            gpu.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("subpixel.bench.input"),
                contents: bytemuck::cast_slice(d),
                usage: wgpu::BufferUsages::STORAGE,
            })
        })
        .collect();
    let inputs = FrameInputs::from_slice(&bufs)?;
    let flops: Vec<(&'static str, String, u64)> = den
        .network()
        .step_costs()
        .into_iter()
        .map(|c| (c.stage, c.label, c.flops))
        .collect();
    let total_flops: u64 = flops.iter().map(|f| f.2).sum();
    let (warmup, frames) = if frames == 0 { (1, 0) } else { (warmup, frames) };
    let run = |den: &mut Denoiser, granularity: Granularity| -> Result<(Profiler, Vec<f64>)> {
        let mut prof = Profiler::new(gpu, 64);
        let mut totals = Vec::new();
        for i in 0..warmup + frames {
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            den.denoise_profiled(&mut enc, &inputs, Some(&mut prof), granularity)?;
            let wall = prof.submit(gpu, enc, Some("frame (CPU wall)"))?;
            if i + 1 == warmup {
                prof.clear();
                totals.clear();
            } else if i >= warmup {
                totals.push(wall);
            }
        }
        Ok((prof, totals))
    };
    let timing = |prof: &Profiler, stage: &str, name: &str, flops: u64| {
        prof.stat(name).map(|stats| LayerTiming {
            stage: stage.to_string(),
            name: name.to_string(),
            flops,
            gflop_per_s: if flops > 0 {
                flops as f64 / (stats.median_ms * 1e-3) * 1e-9
            } else {
                0.0
            },
            stats,
        })
    };
    let (lp, _) = run(&mut den, Granularity::Layer)?;
    let mut layers = Vec::new();
    layers.extend(timing(&lp, "pack", "pack", 0));
    for (stage, label, f) in &flops {
        layers.extend(timing(&lp, stage, label, *f));
    }
    // Every pass's cost (the packing's known once a frame has bound the inputs); the
    // output stage's passes, each timed alone, under these labels.
    let costs = den.step_costs();
    for c in costs.iter().filter(|c| c.stage == "output") {
        layers.extend(timing(&lp, "output", &c.label, c.flops));
    }
    let (sp, walls) = run(&mut den, Granularity::Stage)?;
    let wall_ms = Stats::from_samples(&walls).map_or(0.0, |s| s.median_ms);
    let stage_flops = |s: &str| flops.iter().filter(|f| f.0 == s).map(|f| f.2).sum::<u64>();
    let stages: Vec<LayerTiming> = ["pack", "tfa", "unet", "output"]
        .iter()
        .filter_map(|s| timing(&sp, s, s, stage_flops(s)))
        .collect();
    let total_ms = if sp.gpu_timed() {
        stages.iter().map(|s| s.stats.median_ms).sum()
    } else {
        sp.stat("frame (CPU wall)").map(|s| s.median_ms).unwrap_or(0.0)
    };
    let gflop_per_s = if total_ms > 0.0 {
        total_flops as f64 / (total_ms * 1e-3) * 1e-9
    } else {
        0.0
    };
    let peak = crate::bench::peak_fp32_gflops(&gpu.info.name);
    let modelled = roofline::model(model, &costs);
    let modelled_ms = modelled.iter().map(|p| p.modelled_ms).sum();
    Ok(DenoiseBench {
        adapter: gpu.describe(),
        width: w,
        height: h,
        frames,
        gpu_timestamps: sp.gpu_timed(),
        cpu_adapter: gpu.kind() == AdapterKind::Cpu,
        wall_ms,
        per_pass_timestamps: lp.gpu_timed() && gpu.kind() != AdapterKind::Cpu,
        layers,
        stages,
        total_ms,
        total_flops,
        flops_per_pixel: total_flops as f64 / (den.network().width as f64 * den.network().height as f64),
        gflop_per_s,
        fraction_of_peak: peak.map(|p| gflop_per_s / p),
        conv_kernels: den
            .network()
            .conv_kernels()
            .into_iter()
            .map(|(n, k)| (n.to_string(), k.to_string()))
            .collect(),
        dispatches: costs.len(),
        tensor_bytes: den.network().memory_bytes(),
        model: model.clone(),
        activations: den.network().activations().name().to_string(),
        modelled,
        modelled_ms,
    })
}

/// Formats the benchmark as tables.
pub fn table(b: &DenoiseBench) -> String {
    let mut s = format!(
        "adapter: {}\nSSR at {}x{}, median over {} frames ({})\n\n",
        b.adapter,
        b.width,
        b.height,
        b.frames,
        if b.gpu_timestamps {
            "GPU timestamps"
        } else {
            "CPU wall time"
        }
    );
    s += &format!(
        "{:<7} {:<20} {:>10} {:>10} {:>10} {:>10}\n",
        "stage", "layer", "MFLOP", "median ms", "p95 ms", "GFLOP/s"
    );
    for l in &b.layers {
        let gf = if l.flops > 0 {
            format!("{:.1}", l.gflop_per_s)
        } else {
            "-".into()
        };
        s += &format!(
            "{:<7} {:<20} {:>10.1} {:>10.4} {:>10.4} {:>10}\n",
            l.stage,
            l.name,
            l.flops as f64 * 1e-6,
            l.stats.median_ms,
            l.stats.p95_ms,
            gf
        );
    }
    let layer_sum: f64 = b.layers.iter().map(|l| l.stats.median_ms).sum();
    if b.gpu_timestamps && (layer_sum > 2.0 * b.total_ms || 2.0 * layer_sum < b.total_ms) {
        s += &format!(
            "warning: the per-layer medians add up to {layer_sum:.3} ms but the stages to {:.3} ms; \
             this adapter's per-pass timestamps are not reliable (CPU drivers such as lavapipe)\n",
            b.total_ms
        );
    }
    s += "\nper stage (one pass each, as in production):\n";
    for l in &b.stages {
        s += &format!(
            "{:<7} {:>10.1} MFLOP {:>10.4} ms median {:>10.4} ms p95\n",
            l.name,
            l.flops as f64 * 1e-6,
            l.stats.median_ms,
            l.stats.p95_ms
        );
    }
    s += &format!(
        "total   {:>10.1} MFLOP {:>10.4} ms  ({:.0} FLOP/px, {:.1} GFLOP/s{})\n",
        b.total_flops as f64 * 1e-6,
        b.total_ms,
        b.flops_per_pixel,
        b.gflop_per_s,
        b.fraction_of_peak
            .map(|f| format!(", {:.1}% of FP32 peak", 100.0 * f))
            .unwrap_or_default()
    );
    s += &format!(
        "CPU wall per frame {:.4} ms median (submit to done; on a CPU driver the frame's true cost)\n",
        b.wall_ms
    );
    s += &format!(
        "\nnetwork tensors: {:.1} MB of GPU memory (transient tensors share it by lifetime)\n",
        b.tensor_bytes as f64 * 1e-6
    );
    s += &format!(
        "conv kernels: {}\n",
        b.conv_kernels
            .iter()
            .map(|(n, k)| format!("{n} {k}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    s += &format!(
        "\nroofline model on {} ({:.1} TFLOP/s FP32{}, {:.0} GB/s, {} us per pass) at {}x{}, {} passes per frame, {} activations:\n",
        b.model.name,
        b.model.peak_gflops * 1e-3,
        if b.model.tensor_cores {
            format!(
                "; convolutions on tensor cores at {:.1} TFLOP/s f16 with f32 sums",
                b.model.tensor_gflops * 1e-3
            )
        } else {
            String::new()
        },
        b.model.bandwidth_gbs,
        b.model.pass_us,
        b.width,
        b.height,
        b.dispatches,
        b.activations
    );
    // Beside each pass, its own measured time where it was timed alone (the per-layer run)
    // and the adapter's per-pass timestamps are meaningful. A stage timed as a whole (its
    // layer named after the stage, as `pack`) gets its measured time on a row of its
    // own after its last pass, against the sum of its passes' modelled times.
    let per_pass = b.frames > 0 && b.per_pass_timestamps;
    let timed = |stage: &str, name: &str| {
        b.layers
            .iter()
            .find(|l| l.stage == stage && l.name == name)
            .map(|l| l.stats.median_ms)
    };
    let measured = |p: &ModelledPass| timed(&p.stage, &p.name);
    s += &format!(
        "{:<7} {:<20} {:>10} {:>10} {:>10} {:>8} {:>12}{}\n",
        "stage",
        "pass",
        "MFLOP",
        "MB read",
        "MB written",
        "bound",
        "modelled ms",
        if per_pass {
            "  measured ms  measured/modelled"
        } else {
            ""
        }
    );
    let beside = |measured: Option<f64>, modelled_ms: f64| match measured.filter(|_| per_pass) {
        Some(m) => format!(" {m:>12.4} {:>18.1}", m / modelled_ms),
        None if per_pass => format!(" {:>12} {:>18}", "-", "-"),
        None => String::new(),
    };
    for (i, p) in b.modelled.iter().enumerate() {
        s += &format!(
            "{:<7} {:<20} {:>10.1} {:>10.2} {:>10.2} {:>8} {:>12.4}{}\n",
            p.stage,
            p.name,
            p.flops as f64 * 1e-6,
            p.bytes_read as f64 * 1e-6,
            p.bytes_written as f64 * 1e-6,
            p.bound,
            p.modelled_ms,
            beside(measured(p), p.modelled_ms)
        );
        let last_of_stage = b.modelled.get(i + 1).is_none_or(|n| n.stage != p.stage);
        if let Some(m) = timed(&p.stage, &p.stage).filter(|_| per_pass && last_of_stage) {
            let passes: Vec<_> = b.modelled.iter().filter(|q| q.stage == p.stage).collect();
            let modelled: f64 = passes.iter().map(|q| q.modelled_ms).sum();
            s += &format!(
                "{:<7} {:<20} {:>10.1} {:>10.2} {:>10.2} {:>8} {:>12.4}{}\n",
                p.stage,
                format!("(stage, {} passes)", passes.len()),
                passes.iter().map(|q| q.flops).sum::<u64>() as f64 * 1e-6,
                passes.iter().map(|q| q.bytes_read).sum::<u64>() as f64 * 1e-6,
                passes.iter().map(|q| q.bytes_written).sum::<u64>() as f64 * 1e-6,
                "",
                modelled,
                beside(Some(m), modelled)
            );
        }
    }
    let bytes: u64 = b.modelled.iter().map(|p| p.bytes_read + p.bytes_written).sum();
    let measured = if b.frames > 0 {
        format!("measured here {:.4} ms", b.total_ms)
    } else {
        "not timed (--model-only)".to_string()
    };
    s += &format!(
        "modelled total {:.4} ms ({:.1} MB moved); {measured}\n",
        b.modelled_ms,
        bytes as f64 * 1e-6,
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pass(stage: &str, name: &str, modelled_ms: f64) -> ModelledPass {
        ModelledPass {
            stage: stage.into(),
            name: name.into(),
            flops: 0,
            bytes_read: 0,
            bytes_written: 0,
            modelled_ms,
            bound: "memory",
        }
    }

    fn timed(stage: &str, name: &str, median_ms: f64) -> LayerTiming {
        LayerTiming {
            stage: stage.into(),
            name: name.into(),
            flops: 0,
            stats: Stats::from_samples(&[median_ms]).unwrap(),
            gflop_per_s: 0.0,
        }
    }

    fn bench(per_pass_timestamps: bool) -> DenoiseBench {
        DenoiseBench {
            adapter: "test".into(),
            width: 4,
            height: 4,
            frames: 1,
            gpu_timestamps: true,
            cpu_adapter: false,
            wall_ms: 0.7,
            per_pass_timestamps,
            layers: vec![timed("unet", "unet.enc1.0", 0.5), timed("output", "output", 0.03)],
            stages: Vec::new(),
            total_ms: 0.6,
            total_flops: 0,
            flops_per_pixel: 0.0,
            gflop_per_s: 0.0,
            fraction_of_peak: None,
            conv_kernels: Vec::new(),
            dispatches: 3,
            tensor_bytes: 0,
            model: GpuModel::preset("h100").unwrap(),
            activations: "f32".into(),
            modelled: vec![
                pass("pack", "pack_inputs", 0.1),
                pass("unet", "unet.enc1.0", 0.25),
                pass("output", "mean history", 0.005),
                pass("output", "store output", 0.01),
            ],
            modelled_ms: 0.36,
        }
    }

    /// Each modelled pass shows its own measured time and the ratio where it was timed
    /// alone, `-` where not; a stage timed as a whole (`output`) gets one row after its
    /// passes, its time against their modelled sum; a CPU driver's per-pass timestamps are
    /// left out.
    #[test]
    fn modelled_passes_show_their_measured_time() {
        let t = table(&bench(true));
        let model = t.split("roofline model").nth(1).unwrap().to_string();
        let row = |name: &str| model.lines().find(|l| l.contains(name)).unwrap().to_string();
        assert!(t.contains("measured/modelled"));
        assert!(
            row("unet.enc1.0 ")
                .trim_end()
                .ends_with("0.5000                2.0"),
            "{t}"
        );
        assert!(row("store output").trim_end().ends_with('-'), "{t}");
        assert!(row("mean history").trim_end().ends_with('-'), "{t}");
        let stage = row("(stage, 2 passes)");
        assert!(stage.starts_with("output "), "{t}");
        assert!(
            stage
                .trim_end()
                .ends_with("0.0150       0.0300                2.0"),
            "{t}"
        );
        assert!(
            !model.contains("(stage, 1 passes)"),
            "pack was not timed as a stage: {t}"
        );
        assert!(row("pack_inputs").trim_end().ends_with('-'), "{t}");
        let t = table(&bench(false));
        assert!(!t.contains("measured/modelled"));
        let model = t.split("roofline model").nth(1).unwrap();
        let pack = model.lines().find(|l| l.contains("pack_inputs")).unwrap();
        assert!(pack.trim_end().ends_with("0.1000"), "{t}");
    }
}
