//! `subpixel run`, the main job: a short sequence of a built-in scene path traced at 1/4
//! spp, reconstructed by SSR with the shipped weights, compared with a reference.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};

use crate::frame_loop::{FrameLoop, STAGES};
use crate::gpu::{AdapterKind, Gpu, Profiler};
use crate::io::png::{scale_for_height, write_png_row_scaled};
use crate::metrics;
use crate::render::{Backend, FrameRenderer, FrameSettings, GpuScene, Mode, PackedScene, load_scene_with};
use crate::ssr::Weights;

/// The smallest height of the main job's preview images, in pixels.
pub const PREVIEW_MIN_HEIGHT: u32 = 256;

#[derive(clap::Args)]
pub(super) struct RunArgs {
    /// Scene: builtin:NAME (builtin:procedural:SEED among them), a scene.json, a scene
    /// folder or a .gltf/.glb.
    #[arg(long, default_value = "builtin:cornell")]
    scene: String,
    /// How the scene is built (`--props`).
    #[command(flatten)]
    scene_options: crate::render::SceneOptions,
    /// Frames to render.
    #[arg(long, default_value_t = 8)]
    frames: u32,
    /// Width (default 1280, or 128 on a CPU adapter).
    #[arg(long)]
    width: Option<u32>,
    /// Height (default 720, or 128 on a CPU adapter).
    #[arg(long)]
    height: Option<u32>,
    /// Samples per pixel of the reference (default 1024, or 128 on a CPU adapter).
    #[arg(long)]
    reference_spp: Option<u32>,
    /// Weights (default: $SUBPIXEL_WEIGHTS, else the shipped weights/ssr.safetensors found
    /// next to the executable, in the working directory or at the build's path).
    #[arg(long)]
    weights: Option<PathBuf>,
    /// Output folder for the PNGs (input | SSR | reference).
    #[arg(long, default_value = "out/run")]
    out: PathBuf,
    /// Seed of the camera path and the sampler.
    #[arg(long, default_value_t = 7)]
    seed: u64,
    /// Renderer of the references: auto (the WGSL tracer on a real GPU, its CPU twin on a
    /// CPU adapter), cpu or gpu. The 1/4-spp inputs always come from the WGSL tracer, as in
    /// an embedding.
    #[arg(long, value_enum, default_value_t = Backend::Auto)]
    backend: Backend,
    /// Background lookups per pixel axis (N x N camera rays per pixel; the denoiser takes
    /// each pixel's directly seen environment from it); 0: none. Default: 2 for a scene
    /// with an environment, 0 without.
    #[arg(long, value_name = "N")]
    background: Option<u32>,
}

impl RunArgs {
    /// The defaults, as `subpixel run` with no arguments.
    pub(super) fn default_args() -> Self {
        use clap::FromArgMatches;
        let cmd = <Self as clap::Args>::augment_args(clap::Command::new("run"));
        Self::from_arg_matches(&cmd.get_matches_from(["run"])).expect("defaults parse")
    }
}

pub(super) fn run(a: &RunArgs) -> Result<()> {
    let wpath =
        super::weights_path(a.weights.as_deref()).context("the main job needs trained SSR weights")?;
    let weights = Weights::load(&wpath)?;
    if weights.is_random_init() {
        eprintln!(
            "warning: {} holds random test weights: the SSR column shows no denoising",
            wpath.display()
        );
    }
    if a.frames == 0 {
        bail!("--frames must be at least 1");
    }
    let gpu = Gpu::new()?;
    let cpu = gpu.kind() == AdapterKind::Cpu;
    let (w, h) = (
        a.width.unwrap_or(if cpu { 128 } else { 1280 }),
        a.height.unwrap_or(if cpu { 128 } else { 720 }),
    );
    let spp = a.reference_spp.unwrap_or(if cpu { 128 } else { 1024 });
    println!("adapter: {}", gpu.describe());
    let shown = std::fs::canonicalize(&wpath).unwrap_or_else(|_| wpath.clone());
    println!("weights: {} ({})", shown.display(), weights.config.describe());
    if cpu {
        println!("CPU adapter: {w}x{h}, reference {spp} spp (a GPU runs 1280x720 by default)");
    }
    let scene = load_scene_with(&a.scene, &a.scene_options)?;
    scene.warn_approximations();
    // The camera path is checked against the CPU BVH before anything is uploaded.
    let packed = std::sync::Arc::new(PackedScene::new(
        &scene,
        gpu.device.limits().max_storage_buffer_binding_size,
    )?);
    let flythrough = "flythrough".parse().expect("known path");
    let (path, far) = scene.camera_path(&flythrough, a.seed, a.frames, 0, &packed.bvh)?;
    let gs = GpuScene::upload(&gpu, packed)?;
    let mut frames = FrameLoop::new(&gpu, &weights, w, h)?;
    let mut reference = FrameRenderer::new(&scene, a.backend, Some(&gpu), w, h)?;
    println!("references: {} backend", reference.backend().name());
    let background = a.background.unwrap_or(scene.default_background());
    if background > 0 {
        println!(
            "background: {background}x{background} environment lookups per pixel, composited by the denoiser"
        );
    }
    std::fs::create_dir_all(&a.out).with_context(|| format!("cannot create {}", a.out.display()))?;
    let mut prof = Profiler::new(&gpu, 16);
    let mut rows = Vec::new();
    let pb = super::progress(a.frames as u64, "frames");
    let mut walls = Vec::new();
    // Previews at least PREVIEW_MIN_HEIGHT pixels tall (small CPU-adapter renders are
    // upscaled by an integer factor, pixel for pixel).
    let preview_scale = scale_for_height(h, PREVIEW_MIN_HEIGHT);
    for f in 0..a.frames {
        let settings = FrameSettings {
            background,
            ..FrameSettings::along(&path, f, Mode::Quarter, a.seed as u32, far)
        };
        let t0 = std::time::Instant::now();
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        frames.encode(&mut enc, &gs, &settings, Some(&mut prof))?;
        prof.submit(&gpu, enc, None)?;
        walls.push(t0.elapsed().as_secs_f64() * 1e3);
        let input = frames.tracer.buffers.download(&gpu)?.color;
        let ssr = frames.denoiser.read_output()?;
        let rref = reference.reference(&settings, spp)?.mean(spp);
        write_png_row_scaled(
            &a.out.join(format!("frame_{f:04}.png")),
            &[&input, &ssr, &rref],
            preview_scale,
        )?;
        rows.push([
            metrics::psnr(&input, &rref),
            metrics::ssim(&input, &rref),
            metrics::psnr(&ssr, &rref),
            metrics::ssim(&ssr, &rref),
        ]);
        pb.inc(1);
    }
    pb.finish_and_clear();
    println!(
        "\n{:>5} {:>11} {:>11} {:>11} {:>11}",
        "frame", "input PSNR", "input SSIM", "SSR PSNR", "SSR SSIM"
    );
    for (f, r) in rows.iter().enumerate() {
        println!(
            "{f:>5} {:>11.2} {:>11.4} {:>11.2} {:>11.4}",
            r[0], r[1], r[2], r[3]
        );
    }
    let n = rows.len() as f64;
    let mean = |i: usize| rows.iter().map(|r| r[i]).sum::<f64>() / n;
    println!(
        "{:>5} {:>11.2} {:>11.4} {:>11.2} {:>11.4}",
        "mean",
        mean(0),
        mean(1),
        mean(2),
        mean(3)
    );
    let stages: Vec<String> = STAGES
        .iter()
        .filter_map(|s| prof.stat(s).map(|st| format!("{s} {:.2}", st.median_ms)))
        .collect();
    let total: f64 = STAGES
        .iter()
        .filter_map(|s| prof.stat(s).map(|st| st.median_ms))
        .sum();
    let wall = crate::gpu::Stats::from_samples(&walls).expect("frames ran");
    println!(
        "\ntime per frame at {w}x{h} (median over {} frames): {} ms of GPU ({}), {:.2} ms CPU wall{}",
        a.frames,
        if prof.gpu_timed() {
            format!("{total:.2}")
        } else {
            "n/a".into()
        },
        stages.join(", "),
        wall.median_ms,
        if cpu {
            " (CPU adapter: about 1000x slower than a GPU)"
        } else {
            ""
        }
    );
    println!(
        "images: {}/frame_NNNN.png (input | SSR | reference {spp} spp{})",
        a.out.display(),
        if preview_scale > 1 {
            format!(", each pixel drawn {preview_scale}x{preview_scale}")
        } else {
            String::new()
        }
    );
    Ok(())
}
