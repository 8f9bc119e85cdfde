//! The `subpixel` command line: argument parsing and the commands' drivers.

mod bench;
mod dataset;
mod denoise;
mod eval;
pub mod render;
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
    Render(render::RenderArgs),
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
    // SAFETY: first thing in `main`, before any other thread exists.
    unsafe { quiet_headless_device_select() };
    env_logger::Builder::from_env(
        env_logger::Env::default().default_filter_or("warn,subpixel::nn::autotune=info"),
    )
    .init();
    let cli = Cli::parse();
    let result = match cli.command {
        Some(Command::Render(a)) => render::render_command(&a),
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

/// Turns Mesa's Vulkan device-select layer off on a machine without a Wayland session.
///
/// wgpu enables the Wayland surface extension wherever the Vulkan loader offers it; Mesa's
/// implicit device-select layer then connects to a Wayland display to order the GPUs, and
/// without `XDG_RUNTIME_DIR` (a headless server, CI, a container) libwayland prints "error:
/// XDG_RUNTIME_DIR is invalid or not set in the environment." for every instance: noise
/// that reads as a failure. The layer only orders adapters, which `Gpu` ranks itself, so
/// there (`XDG_RUNTIME_DIR`, `WAYLAND_DISPLAY` and `WAYLAND_SOCKET` unset) this sets the
/// layer's own switch `NODEVICE_SELECT=1`, unless the user set it.
///
/// # Safety
/// Changes the process environment: only while no other thread exists.
unsafe fn quiet_headless_device_select() {
    let unset = |k: &str| std::env::var_os(k).is_none_or(|v| v.is_empty());
    if ["XDG_RUNTIME_DIR", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"]
        .iter()
        .all(|k| unset(k))
        && std::env::var_os("NODEVICE_SELECT").is_none()
    {
        // SAFETY: the caller guarantees no other thread reads the environment meanwhile.
        unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
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

/// The environment variable naming the default weights file.
pub const WEIGHTS_ENV: &str = "SUBPIXEL_WEIGHTS";

/// Where the shipped weights were at build time (the last place looked).
fn compiled_weights_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("weights/ssr.safetensors")
}

/// The places the default weights are looked for, in order, given the environment
/// variable's value, the executable's folder and the working directory: next to the
/// executable (`ssr.safetensors`, `weights/`, and `../weights`, `../../weights` for
/// `target/release/`), the working directory's `weights/`, then the build's path. The
/// environment variable, when set, is the only place (an explicit choice never falls back).
fn weights_candidates(env: Option<PathBuf>, exe_dir: Option<&Path>, cwd: Option<&Path>) -> Vec<PathBuf> {
    if let Some(p) = env {
        return vec![p];
    }
    let file = "ssr.safetensors";
    let mut v = Vec::new();
    if let Some(d) = exe_dir {
        v.push(d.join(file));
        v.push(d.join("weights").join(file));
        v.push(d.join("../weights").join(file));
        v.push(d.join("../../weights").join(file));
    }
    if let Some(d) = cwd {
        v.push(d.join("weights").join(file));
    }
    v.push(compiled_weights_path());
    v
}

/// The first of `candidates` that is a file; else an error listing every place looked.
fn first_existing(candidates: &[PathBuf], from_env: bool) -> Result<PathBuf> {
    if let Some(p) = candidates.iter().find(|p| p.is_file()) {
        return Ok(p.clone());
    }
    let places: Vec<String> = candidates.iter().map(|p| format!("  {}", p.display())).collect();
    if from_env {
        anyhow::bail!(
            "{WEIGHTS_ENV} names a weights file that does not exist:\n{}",
            places.join("\n")
        );
    }
    anyhow::bail!(
        "no SSR weights found; give --weights FILE or set {WEIGHTS_ENV}. Looked in:\n{}",
        places.join("\n")
    )
}

/// The default weights file (no `--weights`): `$SUBPIXEL_WEIGHTS`, else the first of the
/// places `weights_candidates` lists that exists; the error lists them all.
pub fn default_weights_path() -> Result<PathBuf> {
    let env = std::env::var_os(WEIGHTS_ENV)
        .filter(|v| !v.is_empty())
        .map(PathBuf::from);
    let exe = std::env::current_exe().ok();
    let exe_dir = exe.as_deref().and_then(Path::parent);
    let cwd = std::env::current_dir().ok();
    let from_env = env.is_some();
    first_existing(&weights_candidates(env, exe_dir, cwd.as_deref()), from_env)
}

/// `--weights` when given, else the default weights file.
fn weights_path(arg: Option<&Path>) -> Result<PathBuf> {
    match arg {
        Some(p) => Ok(p.to_path_buf()),
        None => default_weights_path(),
    }
}

/// The given or default weights, else random weights of the default config (for timing
/// only).
fn weights_or_random(path: Option<&Path>) -> Result<Weights> {
    if let Some(p) = path {
        return Ok(Weights::load(p)?);
    }
    match default_weights_path() {
        Ok(p) => Ok(Weights::load(p)?),
        Err(_) if std::env::var_os(WEIGHTS_ENV).is_none() => Ok(Weights::random(&SsrConfig::default(), 0)?),
        Err(e) => Err(e),
    }
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

#[cfg(test)]
mod weights_tests {
    use super::*;

    /// The search order, and an error that lists every place looked when none exists.
    #[test]
    fn default_weights_are_searched_in_order() {
        let exe = Path::new("/opt/app/bin");
        let cwd = Path::new("/home/u/work");
        let c = weights_candidates(None, Some(exe), Some(cwd));
        let want: Vec<PathBuf> = [
            "/opt/app/bin/ssr.safetensors",
            "/opt/app/bin/weights/ssr.safetensors",
            "/opt/app/bin/../weights/ssr.safetensors",
            "/opt/app/bin/../../weights/ssr.safetensors",
            "/home/u/work/weights/ssr.safetensors",
        ]
        .iter()
        .map(PathBuf::from)
        .chain([compiled_weights_path()])
        .collect();
        assert_eq!(c, want);
        let env = PathBuf::from("/elsewhere/w.safetensors");
        assert_eq!(
            weights_candidates(Some(env.clone()), Some(exe), Some(cwd)),
            std::slice::from_ref(&env)
        );
        let missing: Vec<PathBuf> = want[..5].to_vec();
        let e = format!("{:#}", first_existing(&missing, false).unwrap_err());
        for p in &missing {
            assert!(e.contains(&p.display().to_string()), "{e}");
        }
        assert!(e.contains("--weights") && e.contains(WEIGHTS_ENV), "{e}");
        let e = format!("{:#}", first_existing(&[env], true).unwrap_err());
        assert!(
            e.contains(WEIGHTS_ENV) && e.contains("/elsewhere/w.safetensors"),
            "{e}"
        );
        let here = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("Cargo.toml");
        assert_eq!(
            first_existing(&[missing[0].clone(), here.clone()], false).unwrap(),
            here
        );
    }
}
