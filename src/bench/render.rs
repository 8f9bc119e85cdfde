//! `subpixel bench render`: the GPU tracer's G-buffer and trace stages timed in quarter
//! and full mode, then each backend's reference throughput (paths/s, Mrays/s) side by side.

use std::time::Instant;

use anyhow::Result;

use crate::gpu::AdapterKind;
use crate::gpu::{Gpu, Profiler, StageStats};
use crate::render::CameraPath;
use crate::render::backend::{Backend, FrameRenderer};
use crate::render::gpu_scene::GpuScene;
use crate::render::load_scene_with;
use crate::render::scene::Scene;
use crate::render::tracer::{DEFAULT_MAX_DEPTH, FrameSettings, Mode, Tracer};

/// `subpixel bench render`: GPU time of the G-buffer and trace stages, quarter vs full.
#[derive(Debug, Clone, clap::Args)]
pub struct BenchRenderArgs {
    /// Scene (as for `render`).
    #[arg(long, default_value = "builtin:cornell")]
    pub scene: String,
    /// How the scene is built (`--props`).
    #[command(flatten)]
    pub scene_options: crate::render::SceneOptions,
    /// Image width (default: 1920 on a GPU, 256 on a CPU adapter).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height (default: 1080 on a GPU, 144 on a CPU adapter).
    #[arg(long)]
    pub height: Option<u32>,
    /// Timed frames per mode (default: 100 on a GPU, 3 on a CPU adapter).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    pub frames: Option<u32>,
    /// Untimed warm-up frames per mode.
    #[arg(long, default_value_t = 2)]
    pub warmup: u32,
    /// Largest number of path segments.
    #[arg(long, default_value_t = DEFAULT_MAX_DEPTH)]
    pub max_depth: u32,
    /// Backend to measure: cpu or gpu (default: both, side by side).
    #[arg(long, value_enum)]
    pub backend: Option<Backend>,
    /// Samples per pixel of the reference frame whose throughput (paths/s, Mrays/s) is
    /// compared between backends.
    #[arg(long, default_value_t = 16)]
    pub spp: u32,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, serde::Serialize)]
struct ModeTiming {
    mode: Mode,
    stages: Vec<StageStats>,
    cpu_wall: Option<crate::gpu::Stats>,
    mrays_per_s: f64,
}

/// Throughput of one backend on a reference frame.
#[derive(Debug, serde::Serialize)]
struct Throughput {
    backend: &'static str,
    threads: Option<usize>,
    paths: u64,
    rays: u64,
    seconds: f64,
    mpaths_per_s: f64,
    mrays_per_s: f64,
}

/// Renders one `spp`-sample reference of `scene` with `backend` after a 1-spp warm-up and
/// returns its throughput (wall time of the render, download included).
fn reference_throughput(
    scene: &Scene,
    backend: Backend,
    gpu: Option<&Gpu>,
    (width, height): (u32, u32),
    spp: u32,
    max_depth: u32,
) -> Result<Throughput> {
    let mut r = FrameRenderer::new(scene, backend, gpu, width, height)?;
    let far = scene.far_distance([&scene.camera.position]);
    let mut s = FrameSettings::new(scene.camera, Mode::Reference, far);
    s.max_depth = max_depth;
    s.spp = 1;
    r.frame(&s)?;
    s.spp = spp.max(1);
    s.seed = 1;
    let t = Instant::now();
    let (_, stats) = r.frame(&s)?;
    let seconds = t.elapsed().as_secs_f64();
    let paths = stats.samples;
    Ok(Throughput {
        backend: r.backend().name(),
        threads: (r.backend() == Backend::Cpu).then(rayon::current_num_threads),
        paths,
        rays: stats.rays,
        seconds,
        mpaths_per_s: paths as f64 / seconds.max(1e-12) / 1e6,
        mrays_per_s: stats.rays as f64 / seconds.max(1e-12) / 1e6,
    })
}

/// `subpixel bench render`: the GPU tracer's stages in quarter and full mode, then the
/// reference throughput of each backend side by side.
pub fn bench_render_command(args: &BenchRenderArgs) -> Result<()> {
    let backends = match args.backend {
        None | Some(Backend::Auto) => vec![Backend::Gpu, Backend::Cpu],
        Some(b) => vec![b],
    };
    let gpu = if backends.contains(&Backend::Gpu) {
        Some(Gpu::new()?)
    } else {
        None
    };
    let cpu_adapter = gpu.as_ref().is_none_or(|g| g.kind() == AdapterKind::Cpu);
    let width = args.width.unwrap_or(if cpu_adapter { 256 } else { 1920 });
    let height = args.height.unwrap_or(if cpu_adapter { 144 } else { 1080 });
    let scene = load_scene_with(&args.scene, &args.scene_options)?;
    let stages = match &gpu {
        Some(g) => Some(gpu_stage_timing(args, g, &scene, width, height)?),
        None => None,
    };
    let mut throughput = Vec::new();
    for &b in &backends {
        throughput.push(reference_throughput(
            &scene,
            b,
            gpu.as_ref(),
            (width, height),
            args.spp,
            args.max_depth,
        )?);
    }
    let ratio = match (
        throughput.iter().find(|t| t.backend == "cpu"),
        throughput.iter().find(|t| t.backend == "gpu"),
    ) {
        (Some(c), Some(g)) => Some(c.mpaths_per_s / g.mpaths_per_s.max(1e-12)),
        _ => None,
    };
    if args.json {
        let out = serde_json::json!({
            "adapter": gpu.as_ref().map(|g| g.describe()),
            "scene": scene.name,
            "width": width, "height": height,
            "max_depth": args.max_depth,
            "gpu_stages": stages,
            "reference_spp": args.spp,
            "reference_throughput": throughput,
            "cpu_over_gpu_paths_per_s": ratio,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    if let Some(st) = &stages {
        st.print();
        println!();
    }
    println!(
        "reference throughput: {} {width}x{height}, {} spp, max depth {} (wall time of one frame after a warm-up)",
        scene.name, args.spp, args.max_depth
    );
    println!(
        "{:<8} {:>8} {:>12} {:>12} {:>10} {:>10} {:>10}",
        "backend", "threads", "paths", "rays", "seconds", "Mpaths/s", "Mrays/s"
    );
    for t in &throughput {
        println!(
            "{:<8} {:>8} {:>12} {:>12} {:>10.3} {:>10.3} {:>10.2}",
            t.backend,
            t.threads.map(|n| n.to_string()).unwrap_or_else(|| "-".into()),
            t.paths,
            t.rays,
            t.seconds,
            t.mpaths_per_s,
            t.mrays_per_s
        );
    }
    if let Some(r) = ratio {
        println!("cpu / gpu: {r:.1}x the paths per second");
    }
    if let Some(g) = &gpu {
        println!("adapter: {}", g.describe());
    }
    Ok(())
}

/// Per-stage GPU timings of quarter and full frames.
#[derive(Debug, serde::Serialize)]
struct StageTiming {
    adapter: String,
    scene: String,
    width: u32,
    height: u32,
    frames: u32,
    warmup: u32,
    max_depth: u32,
    modes: Vec<ModeTiming>,
    speedup_trace: Option<f64>,
    speedup_total: Option<f64>,
}

/// Times the G-buffer and trace stages in quarter and full mode on the GPU.
fn gpu_stage_timing(
    args: &BenchRenderArgs,
    gpu: &Gpu,
    scene: &Scene,
    width: u32,
    height: u32,
) -> Result<StageTiming> {
    let cpu = gpu.kind() == AdapterKind::Cpu;
    let frames = args.frames.unwrap_or(if cpu { 3 } else { 100 }).max(1);
    let gpu = gpu.clone();
    let gs = GpuScene::new(&gpu, scene)?;
    let mut tracer = Tracer::new(&gpu, width, height)?;
    tracer.compile()?;
    let path = CameraPath::checked(
        &"orbit".parse().expect("known"),
        &scene.camera,
        1,
        frames + args.warmup,
        &gs.bvh,
    )
    .map_err(|e| anyhow::anyhow!("scene {}: {e}", scene.name))?;
    let far = scene.far_distance([&scene.camera.position]);
    let mut results = Vec::new();
    for mode in [Mode::Quarter, Mode::Full] {
        let mut prof = Profiler::new(&gpu, 2);
        let mut rays = 0u64;
        let mut secs = 0.0;
        for i in 0..args.warmup + frames {
            let s = FrameSettings {
                max_depth: args.max_depth,
                ..FrameSettings::along(&path, i, mode, 7, far)
            };
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            tracer.encode_frame(&mut enc, &gs, &s, Some(&mut prof))?;
            let wall = prof.submit(&gpu, enc, None)? * 1e-3;
            if i < args.warmup {
                prof.clear();
                continue;
            }
            prof.record("cpu wall", wall * 1e3);
            rays += tracer.read_counter()?;
            secs += wall;
        }
        let _ = &mut tracer;
        let stages: Vec<StageStats> = prof
            .stats()
            .into_iter()
            .filter(|s| s.name != "cpu wall")
            .collect();
        let trace_s = prof
            .stat("trace")
            .map(|s| s.mean_ms * 1e-3 * frames as f64)
            .unwrap_or(secs);
        results.push(ModeTiming {
            mode,
            stages,
            cpu_wall: prof.stat("cpu wall"),
            mrays_per_s: rays as f64 / trace_s.max(1e-12) / 1e6,
        });
    }
    let stage = |m: usize, n: &str| {
        results[m]
            .stages
            .iter()
            .find(|s| s.name == n)
            .map(|s| s.stats.median_ms)
    };
    let total = |m: usize| Some(stage(m, "gbuffer")? + stage(m, "trace")?);
    let speedup_trace = stage(1, "trace").zip(stage(0, "trace")).map(|(f, q)| f / q);
    let speedup_total = total(1).zip(total(0)).map(|(f, q)| f / q);
    Ok(StageTiming {
        adapter: gpu.describe(),
        scene: scene.name.clone(),
        width,
        height,
        frames,
        warmup: args.warmup,
        max_depth: args.max_depth,
        modes: results,
        speedup_trace,
        speedup_total,
    })
}

impl StageTiming {
    fn stage(&self, m: usize, n: &str) -> Option<f64> {
        self.modes[m]
            .stages
            .iter()
            .find(|s| s.name == n)
            .map(|s| s.stats.median_ms)
    }

    fn total(&self, m: usize) -> Option<f64> {
        Some(self.stage(m, "gbuffer")? + self.stage(m, "trace")?)
    }

    fn print(&self) {
        println!(
            "{} | {} {}x{}, {} frames (+{} warm-up), max depth {}",
            self.adapter, self.scene, self.width, self.height, self.frames, self.warmup, self.max_depth
        );
        let timed = self
            .modes
            .first()
            .and_then(|r| r.stages.first())
            .map(|s| s.gpu)
            .unwrap_or(false);
        println!(
            "gpu backend, times in ms ({}), median / p95",
            if timed { "GPU timestamps" } else { "CPU wall" }
        );
        println!(
            "{:<8} {:>18} {:>18} {:>12} {:>10}",
            "mode", "gbuffer", "trace", "total", "Mrays/s"
        );
        for (i, r) in self.modes.iter().enumerate() {
            let f = |n: &str| {
                r.stages
                    .iter()
                    .find(|s| s.name == n)
                    .map(|s| format!("{:.3} / {:.3}", s.stats.median_ms, s.stats.p95_ms))
                    .unwrap_or_else(|| "-".into())
            };
            println!(
                "{:<8} {:>18} {:>18} {:>12} {:>10.1}",
                format!("{:?}", r.mode).to_lowercase(),
                f("gbuffer"),
                f("trace"),
                self.total(i)
                    .map(|t| format!("{t:.3}"))
                    .unwrap_or_else(|| "-".into()),
                r.mrays_per_s
            );
        }
        if let (Some(t), Some(a)) = (self.speedup_trace, self.speedup_total) {
            println!(
                "quarter vs full: trace {t:.2}x faster, gbuffer + trace {a:.2}x (paper: 12.79 ms -> 4.35 ms, 2.94x)"
            );
        }
    }
}
