//! The `subpixel` command line: argument parsing and the commands' drivers.

mod bench;
mod dataset;
mod denoise;
mod eval;
mod run;
mod scene;

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Result;
use clap::{Parser, Subcommand};

use crate::ssr::{SsrConfig, Weights};

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
    Render(crate::render::cli::RenderArgs),
    /// The main job: render a short 1/4-spp sequence, denoise it, compare with a reference.
    Run(run::RunArgs),
    /// Render training / validation / test sequences (inputs, buffers and references).
    Dataset(dataset::DatasetArgs),
    /// Denoise a folder of frame EXRs with SSR.
    Denoise(denoise::DenoiseArgs),
    /// Score predictions against references (PSNR, SSIM, RMSE, relMSE, temporal error).
    Eval(eval::EvalArgs),
    /// Summarise a scene (procedural ones included) and write a path-traced preview PNG.
    Scene(scene::SceneArgs),
    /// Time the whole frame per stage (default), or kernels, the denoiser, the renderer.
    Bench {
        #[command(subcommand)]
        what: Option<bench::BenchCommand>,
    },
}

/// Runs the CLI; errors are printed with their causes.
pub fn main() -> ExitCode {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    let cli = Cli::parse();
    let result = match cli.command {
        Some(Command::Render(a)) => crate::render::cli::render_command(&a),
        Some(Command::Run(a)) => run::run(&a),
        Some(Command::Dataset(a)) => dataset::run(&a),
        Some(Command::Denoise(a)) => denoise::run(&a),
        Some(Command::Eval(a)) => eval::run(&a),
        Some(Command::Scene(a)) => scene::run(&a),
        Some(Command::Bench { what }) => bench::run(what),
        None => run::run(&run::RunArgs::default_args()),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// `path` absolute with symlinks and `..` resolved, also when its tail does not exist yet
/// (each existing prefix is canonicalised, the rest taken as written).
fn resolved(path: &Path) -> Result<PathBuf> {
    use std::path::Component;
    let abs = std::path::absolute(path)?;
    let mut out = PathBuf::new();
    for c in abs.components() {
        match c {
            Component::ParentDir => {
                out.pop();
            }
            Component::CurDir => {}
            other => {
                out.push(other);
                if let Ok(real) = out.canonicalize() {
                    out = real;
                }
            }
        }
    }
    Ok(out)
}

/// Refuses an output folder that is the input folder, lies inside it or contains it
/// (paths resolved, symlinks followed): writing there would overwrite or mix with the input.
fn refuse_overlap(input_flag: &str, input: &Path, out_flag: &str, out: &Path) -> Result<()> {
    let (i, o) = (resolved(input)?, resolved(out)?);
    let how = if i == o {
        "is the same folder as"
    } else if o.starts_with(&i) {
        "lies inside"
    } else if i.starts_with(&o) {
        "contains"
    } else {
        return Ok(());
    };
    anyhow::bail!(
        "{out_flag} {} {how} {input_flag} {} ({}): the outputs would overwrite or mix with the \
         input frames; choose a separate folder",
        out.display(),
        input.display(),
        i.display()
    )
}

/// The shipped weights file.
pub fn shipped_weights_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("weights/ssr.safetensors")
}

/// The shipped weights, else random weights of the default config (for timing only).
fn weights_or_random(path: Option<&Path>) -> Result<Weights> {
    if let Some(p) = path {
        return Ok(Weights::load(p)?);
    }
    let shipped = shipped_weights_path();
    if shipped.exists() {
        return Ok(Weights::load(shipped)?);
    }
    Ok(Weights::random(&SsrConfig::default(), 0)?)
}

/// A progress bar with the crate's style.
fn progress(len: u64, what: &str) -> indicatif::ProgressBar {
    let pb = indicatif::ProgressBar::new(len);
    pb.set_style(
        indicatif::ProgressStyle::with_template("{msg:>10} [{bar:40}] {pos}/{len} {per_sec} eta {eta}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    pb.set_message(what.to_string());
    pb
}
