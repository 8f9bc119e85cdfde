//! `subpixel bench ...`.

use anyhow::Result;
use clap::Subcommand;

use crate::bench::denoise::{bench_denoise, table as denoise_table};
use crate::bench::kernels::{KernelBenchOptions, bench_kernels, table as kernels_table};
use crate::gpu::{AdapterKind, Gpu};

#[derive(Subcommand)]
pub(super) enum BenchCommand {
    /// Each network kernel in isolation.
    Kernels(KernelsArgs),
    /// The SSR network: per layer (FLOPs, ms, GFLOP/s) and per stage (TFA, U-Net).
    Denoise(DenoiseBenchArgs),
    /// The path tracer: G-buffer and trace stages, quarter vs full.
    Render(crate::render::cli::BenchRenderArgs),
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

#[derive(clap::Args)]
pub(super) struct DenoiseBenchArgs {
    /// Frame width (default 1920, or 128 on a CPU adapter).
    #[arg(long)]
    width: Option<u32>,
    /// Frame height (default 1080, or 128 on a CPU adapter).
    #[arg(long)]
    height: Option<u32>,
    /// Weights file (default: the shipped weights, else random weights of the default
    /// config; the values do not change the timing).
    #[arg(long)]
    weights: Option<std::path::PathBuf>,
    /// Timed frames (default 100 on a GPU, 5 on a CPU adapter).
    #[arg(long)]
    frames: Option<u32>,
    /// Untimed warm-up frames.
    #[arg(long, default_value_t = 5)]
    warmup: u32,
    /// Print JSON instead of tables.
    #[arg(long)]
    json: bool,
}

pub(super) fn run(what: BenchCommand) -> Result<()> {
    if let BenchCommand::Render(a) = &what {
        return crate::render::cli::bench_render_command(a);
    }
    let gpu = Gpu::new()?;
    let cpu = gpu.kind() == AdapterKind::Cpu;
    match what {
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
            if a.json {
                let out = serde_json::json!({
                    "adapter": gpu.describe(),
                    "width": a.width, "height": a.height, "channels": a.channels,
                    "iterations": iterations,
                    "kernels": rows,
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
            }
        }
        BenchCommand::Denoise(a) => {
            let (dw, dh, df) = if cpu { (128, 128, 5) } else { (1920, 1080, 100) };
            let weights = super::weights_or_random(a.weights.as_deref())?;
            let b = bench_denoise(
                &gpu,
                &weights,
                a.width.unwrap_or(dw),
                a.height.unwrap_or(dh),
                a.warmup,
                a.frames.unwrap_or(df),
            )?;
            if a.json {
                println!("{}", serde_json::to_string_pretty(&b)?);
            } else {
                print!("{}", denoise_table(&b));
            }
        }
        BenchCommand::Render(_) => unreachable!("handled above"),
    }
    Ok(())
}
