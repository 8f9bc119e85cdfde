//! `subpixel`: render, denoise and measure from the command line (a thin dispatcher).

use anyhow::Result;
use clap::{Parser, Subcommand};
use subpixel::render::cli::{BenchRenderArgs, RenderArgs, bench_render_command, render_command};

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
    /// Path trace a scene into one multi-channel EXR per frame.
    Render(RenderArgs),
    /// Time kernels, the renderer or the whole frame.
    Bench {
        #[command(subcommand)]
        what: BenchCommand,
    },
}

#[derive(Subcommand)]
enum BenchCommand {
    /// The path tracer: G-buffer and trace stages, quarter vs full.
    Render(BenchRenderArgs),
}

fn main() -> Result<()> {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    let cli = Cli::parse();
    match cli.command {
        Some(Command::Render(a)) => render_command(&a),
        Some(Command::Bench {
            what: BenchCommand::Render(a),
        }) => bench_render_command(&a),
        None => {
            use clap::CommandFactory;
            Cli::command().print_help()?;
            Ok(())
        }
    }
}
