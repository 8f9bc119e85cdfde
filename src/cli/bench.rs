//! `subpixel bench ...`.

use anyhow::Result;
use clap::Subcommand;

use crate::bench::denoise::{bench_denoise, table as denoise_table};
use crate::bench::kernels::{KernelBenchOptions, bench_kernels, table as kernels_table};
use crate::gpu::{AdapterKind, Gpu};

#[derive(Subcommand)]
pub(super) enum BenchCommand {
    /// The whole frame (the default): G-buffer, trace, TFA, U-Net per stage, quarter vs full.
    Frame(FrameBenchArgs),
    /// Each network kernel in isolation.
    Kernels(KernelsArgs),
    /// The SSR network: per layer (FLOPs, ms, GFLOP/s) and per stage (TFA, U-Net).
    Denoise(DenoiseBenchArgs),
    /// The path tracer: G-buffer and trace stages, quarter vs full.
    Render(crate::bench::render::BenchRenderArgs),
}

#[derive(clap::Args)]
pub(super) struct KernelsArgs {
    /// Image width.
    #[arg(long, default_value_t = 1920)]
    width: u32,
    /// Image height.
    #[arg(long, default_value_t = 1080)]
    height: u32,
    /// Channels (conv3x3 runs channels -> channels).
    #[arg(long, default_value_t = 32)]
    channels: u32,
    /// Timed iterations per kernel (default: 100 on a GPU, 5 on a CPU adapter).
    #[arg(long)]
    iterations: Option<u32>,
    /// Untimed warm-up iterations.
    #[arg(long, default_value_t = 3)]
    warmup: u32,
    /// Print JSON instead of a table.
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args, Default)]
pub(super) struct FrameBenchArgs {
    /// Sizes, WxH (default 1920x1080 and 2048x1024, or 128x128 on a CPU adapter).
    #[arg(long, value_delimiter = ',')]
    sizes: Vec<String>,
    /// Scene.
    #[arg(long, default_value = "builtin:cornell")]
    scene: String,
    #[command(flatten)]
    run: NetworkRunArgs,
}

/// Weights and frame counts of the benchmarks that run the network.
#[derive(clap::Args)]
pub(super) struct NetworkRunArgs {
    /// Weights file (default: the shipped weights, else random weights of the default
    /// config; the values do not change the timing, the config may: a model of config albedo
    /// "footprint", the shipped one, adds the background pass to every frame).
    #[arg(long)]
    weights: Option<std::path::PathBuf>,
    /// Timed frames (default 100 on a GPU; 3 for `frame`, 5 for `denoise` on a CPU adapter).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    frames: Option<u32>,
    /// Untimed warm-up frames.
    #[arg(long, default_value_t = 5)]
    warmup: u32,
    /// Print JSON instead of tables.
    #[arg(long)]
    json: bool,
}

impl Default for NetworkRunArgs {
    fn default() -> Self {
        Self {
            weights: None,
            frames: None,
            warmup: 5,
            json: false,
        }
    }
}

#[derive(clap::Args)]
pub(super) struct DenoiseBenchArgs {
    /// Frame width (default 1920, or 128 on a CPU adapter).
    #[arg(long)]
    width: Option<u32>,
    /// Frame height (default 1080, or 128 on a CPU adapter).
    #[arg(long)]
    height: Option<u32>,
    #[command(flatten)]
    run: NetworkRunArgs,
    /// GPU of the roofline model: h100 or rtx4070.
    #[arg(long, default_value = "h100")]
    model: String,
    /// Storage of the network's interior activations: f32, f16 (needs SHADER_F16) or auto
    /// (f16 where the autotuner measures it faster); default: SUBPIXEL_PRECISION, else f32.
    /// The roofline model counts the bytes the engine then moves.
    #[arg(long)]
    precision: Option<crate::nn::autotune::Precision>,
    /// Skip the timing (one untimed frame) and print the roofline model only, e.g. at
    /// 1920x1080 on a machine without that GPU.
    #[arg(long)]
    model_only: bool,
    /// Model the convolutions on tensor cores (the cooperative-matrix kernel: dense f16
    /// with f32 sums) instead of the FP32 peak.
    #[arg(long)]
    tensor_cores: bool,
}

pub(super) fn run(what: Option<BenchCommand>) -> Result<()> {
    let what = what.unwrap_or(BenchCommand::Frame(FrameBenchArgs {
        scene: "builtin:cornell".into(),
        ..Default::default()
    }));
    if let BenchCommand::Render(a) = &what {
        // The renderer's benchmark picks its own adapter and defaults.
        return crate::bench::render::bench_render_command(a);
    }
    let gpu = Gpu::new()?;
    let cpu = gpu.kind() == AdapterKind::Cpu;
    match what {
        BenchCommand::Render(_) => {} // returned above
        BenchCommand::Frame(a) => {
            let sizes: Vec<String> = if a.sizes.is_empty() {
                if cpu {
                    vec!["128x128".into()]
                } else {
                    vec!["1920x1080".into(), "2048x1024".into()]
                }
            } else {
                a.sizes.clone()
            };
            let frames = a.run.frames.unwrap_or(if cpu { 3 } else { 100 });
            let weights = super::weights_or_random(a.run.weights.as_deref())?;
            let scene = crate::render::load_scene(&a.scene)?;
            let gs = crate::render::GpuScene::new(&gpu, &scene)?;
            let mut rows = Vec::new();
            for s in &sizes {
                let (w, h) = s
                    .split_once('x')
                    .and_then(|(w, h)| Some((w.parse::<u32>().ok()?, h.parse::<u32>().ok()?)))
                    .ok_or_else(|| anyhow::anyhow!("--sizes: '{s}' is not WxH"))?;
                for mode in [crate::render::Mode::Quarter, crate::render::Mode::Full] {
                    rows.push(crate::bench::frame::bench_frame(
                        &gpu,
                        &scene,
                        &gs,
                        &weights,
                        (w, h),
                        mode,
                        (a.run.warmup, frames),
                    )?);
                }
            }
            if a.run.json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(
                        &serde_json::json!({"adapter": gpu.describe(), "results": rows})
                    )?
                );
            } else {
                print!("{}", crate::bench::frame::table(&gpu.describe(), &rows));
            }
        }
        BenchCommand::Kernels(a) => {
            let iterations = a.iterations.unwrap_or(if cpu { 5 } else { 100 });
            let opts = KernelBenchOptions {
                width: a.width,
                height: a.height,
                channels: a.channels,
                warmup: a.warmup,
                iterations,
            };
            let rows = bench_kernels(&gpu, &opts)?;
            let (choice, cached, (tw, th)) = crate::bench::kernels::conv_choice(&gpu, &opts)?;
            let tuned = format!(
                "autotuner's choice for conv3x3 {c}->{c} relu: {choice} ({} at {tw}x{th}; {} overrides)",
                if cached {
                    "cached, measured"
                } else {
                    "measured now"
                },
                crate::nn::autotune::ENV_KERNEL,
                c = a.channels
            );
            if a.json {
                let out = serde_json::json!({
                    "adapter": gpu.describe(),
                    "width": a.width, "height": a.height, "channels": a.channels,
                    "iterations": iterations,
                    "kernels": rows,
                    "conv_choice": choice.to_string(),
                });
                println!("{}", serde_json::to_string_pretty(&out)?);
            } else {
                println!("adapter: {}", gpu.describe());
                println!(
                    "{}x{}, {} channels, median over {iterations} runs after {} warm-up ({})",
                    a.width,
                    a.height,
                    a.channels,
                    a.warmup,
                    if rows.first().is_some_and(|r| r.gpu_timestamps) {
                        "GPU timestamps"
                    } else {
                        "CPU wall time: no timestamp queries"
                    }
                );
                print!("{}", kernels_table(&rows));
                println!("{tuned}");
            }
        }
        BenchCommand::Denoise(a) => {
            let (dw, dh, df) = if cpu { (128, 128, 5) } else { (1920, 1080, 100) };
            let weights = super::weights_or_random(a.run.weights.as_deref())?;
            let model = crate::bench::roofline::GpuModel::preset(&a.model)?.with_tensor_cores(a.tensor_cores);
            let frames = if a.model_only {
                0
            } else {
                a.run.frames.unwrap_or(df)
            };
            let b = bench_denoise(
                &gpu,
                &weights,
                (a.width.unwrap_or(dw), a.height.unwrap_or(dh)),
                (a.run.warmup, frames),
                &model,
                a.precision.unwrap_or_default(),
            )?;
            if a.run.json {
                println!("{}", serde_json::to_string_pretty(&b)?);
            } else {
                print!("{}", denoise_table(&b));
            }
        }
    }
    Ok(())
}
