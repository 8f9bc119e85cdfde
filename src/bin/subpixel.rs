//! `subpixel`: render, denoise and measure from the command line.

use anyhow::Result;
use clap::{Parser, Subcommand};
use subpixel::bench::denoise::bench_denoise;
use subpixel::bench::kernels::{KernelBenchOptions, bench_kernels, table};
use subpixel::gpu::Gpu;
use subpixel::ssr::{SsrConfig, Weights};

/// The shipped weights, else random weights of the default config (timing only).
fn default_weights() -> Result<Weights> {
    let shipped = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("weights/ssr.safetensors");
    if shipped.exists() {
        return Ok(Weights::load(shipped)?);
    }
    Ok(Weights::random(&SsrConfig::default(), 0)?)
}

#[derive(Parser)]
#[command(
    name = "subpixel",
    version,
    about = "1/4-spp path tracing + SSR neural reconstruction on wgpu"
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Time kernels, the denoiser or the whole frame.
    Bench {
        #[command(subcommand)]
        what: BenchCommand,
    },
}

#[derive(Subcommand)]
enum BenchCommand {
    /// Each network kernel in isolation.
    Kernels(KernelsArgs),
    /// The SSR network: per layer (FLOPs, ms, GFLOP/s) and per stage (TFA, U-Net).
    Denoise(DenoiseBenchArgs),
}

#[derive(clap::Args)]
struct DenoiseBenchArgs {
    /// Frame width (default 1920, or 128 on a CPU adapter).
    #[arg(long)]
    width: Option<u32>,
    /// Frame height (default 1080, or 128 on a CPU adapter).
    #[arg(long)]
    height: Option<u32>,
    /// Weights file (default: the shipped weights, else random weights of the default config;
    /// the weights do not change the timing).
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

#[derive(clap::Args)]
struct KernelsArgs {
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

fn main() -> Result<()> {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    let cli = Cli::parse();
    match cli.command {
        Some(Command::Bench {
            what: BenchCommand::Kernels(a),
        }) => {
            let gpu = Gpu::new()?;
            let cpu = gpu.kind() == subpixel::gpu::AdapterKind::Cpu;
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
                    "{}x{}, {} channels, median over {iterations} runs after {} warm-up{}",
                    a.width,
                    a.height,
                    a.channels,
                    a.warmup,
                    if rows.first().is_some_and(|r| r.gpu_timestamps) {
                        " (GPU timestamps)"
                    } else {
                        " (CPU wall time: no timestamp queries)"
                    }
                );
                print!("{}", table(&rows));
            }
        }
        Some(Command::Bench {
            what: BenchCommand::Denoise(a),
        }) => {
            let gpu = Gpu::new()?;
            let cpu = gpu.kind() == subpixel::gpu::AdapterKind::Cpu;
            let (dw, dh, df) = if cpu { (128, 128, 5) } else { (1920, 1080, 100) };
            let weights = match &a.weights {
                Some(p) => Weights::load(p)?,
                None => default_weights()?,
            };
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
                print!("{}", subpixel::bench::denoise::table(&b));
            }
        }
        None => {
            anyhow::bail!("the main job (`subpixel run`) is not built yet; see `subpixel --help`")
        }
    }
    Ok(())
}
