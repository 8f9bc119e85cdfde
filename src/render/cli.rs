//! Command-line front ends: `subpixel render` (EXR frames) and `subpixel bench render`
//! (GPU time per stage, quarter vs full).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};

use super::camera::{CameraPath, CameraPathSpec};
use super::gpu_scene::GpuScene;
use super::loader::load_scene;
use super::scene::Scene;
use super::tracer::{DEFAULT_MAX_DEPTH, FrameSettings, Mode, Tracer};
use crate::gpu::{AdapterKind, Gpu, Profiler, StageStats};
use crate::io::exr::FrameFile;
use crate::nn::{HostTensor, Tensor};

/// `subpixel render`: path trace a scene into one multi-channel EXR per frame.
#[derive(Debug, Clone, clap::Args)]
pub struct RenderArgs {
    /// `builtin:cornell|cornell-empty|room|furnace`, a scene.json, a scene folder, or a .gltf/.glb.
    #[arg(long)]
    pub scene: String,
    /// quarter (1/4 spp, the rotating 2x2 pattern), full (1 spp) or reference (N spp, box filter).
    #[arg(long, value_enum, default_value_t = Mode::Quarter)]
    pub mode: Mode,
    /// Samples per pixel in reference mode.
    #[arg(long, default_value_t = 64)]
    pub spp: u32,
    /// Number of frames.
    #[arg(long, default_value_t = 1)]
    pub frames: u32,
    /// Index of the first frame (to shard a sequence over machines).
    #[arg(long, default_value_t = 0)]
    pub first_frame: u32,
    /// Image width (default: the scene's film).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height (default: the scene's film).
    #[arg(long)]
    pub height: Option<u32>,
    /// Largest number of path segments: 1 = emitters seen directly, 2 = direct lighting,
    /// 3 = one indirect bounce, ...
    #[arg(long, default_value_t = DEFAULT_MAX_DEPTH)]
    pub max_depth: u32,
    /// Seed of the random numbers and of the camera path.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Camera path: static, orbit or flythrough (default: the scene's, else static for one
    /// frame and flythrough for more).
    #[arg(long)]
    pub path: Option<CameraPathSpec>,
    /// Also render an N-spp reference of every frame into the `reference` channels.
    #[arg(long)]
    pub reference_spp: Option<u32>,
    /// Also write a tonemapped PNG preview of the colour of every frame.
    #[arg(long)]
    pub png: bool,
    /// Skip frames whose EXR already exists (resume an interrupted render).
    #[arg(long)]
    pub resume: bool,
    /// Extra keys for `sequence.json` (set by `subpixel dataset`). When given, every shard
    /// writes the same complete `sequence.json` before rendering its frames.
    #[arg(skip)]
    pub sequence_json: Option<serde_json::Map<String, serde_json::Value>>,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
}

/// `subpixel bench render`: GPU time of the G-buffer and trace stages, quarter vs full.
#[derive(Debug, Clone, clap::Args)]
pub struct BenchRenderArgs {
    /// Scene (as for `render`).
    #[arg(long, default_value = "builtin:cornell")]
    pub scene: String,
    /// Image width (default: 1920 on a GPU, 256 on a CPU adapter).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height (default: 1080 on a GPU, 144 on a CPU adapter).
    #[arg(long)]
    pub height: Option<u32>,
    /// Timed frames per mode (default: 100 on a GPU, 3 on a CPU adapter).
    #[arg(long)]
    pub frames: Option<u32>,
    /// Untimed warm-up frames per mode.
    #[arg(long, default_value_t = 2)]
    pub warmup: u32,
    /// Largest number of path segments.
    #[arg(long, default_value_t = DEFAULT_MAX_DEPTH)]
    pub max_depth: u32,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

fn path_for(scene: &Scene, arg: &Option<CameraPathSpec>, frames: u32) -> CameraPathSpec {
    arg.clone()
        .or_else(|| scene.camera_path.clone())
        .unwrap_or_else(|| {
            if frames <= 1 {
                CameraPathSpec::Static
            } else {
                "flythrough".parse().expect("known path")
            }
        })
}

fn spec_name(s: &CameraPathSpec) -> &'static str {
    match s {
        CameraPathSpec::Static => "static",
        CameraPathSpec::Orbit { .. } => "orbit",
        CameraPathSpec::FlyThrough { .. } => "flythrough",
    }
}

/// Frames over which the depth normalisation is computed, whatever the shard.
const FAR_HORIZON: u32 = 1024;

/// Renders `args.frames` frames into `args.out`.
pub fn render_command(args: &RenderArgs) -> Result<()> {
    if args.frames == 0 {
        bail!("--frames must be at least 1");
    }
    let scene = load_scene(&args.scene)?;
    scene.warn_approximations();
    let (w, h) = (
        args.width.unwrap_or(scene.film.0),
        args.height.unwrap_or(scene.film.1),
    );
    if w == 0 || h == 0 {
        bail!("image size {w}x{h}: width and height must be positive");
    }
    std::fs::create_dir_all(&args.out).with_context(|| format!("cannot create {}", args.out.display()))?;
    let gpu = Gpu::new()?;
    eprintln!("adapter: {}", gpu.describe());
    let t0 = Instant::now();
    let gs = GpuScene::new(&gpu, &scene)?;
    eprintln!(
        "scene {}: {} triangles, BVH {:.1} ms ({:.2} Mtri/s), {} emissive triangles, environment: {}",
        scene.name,
        gs.triangle_count(),
        gs.bvh.build_time.as_secs_f64() * 1e3,
        gs.triangle_count() as f64 / gs.bvh.build_time.as_secs_f64().max(1e-9) / 1e6,
        gs.emissive_triangles,
        scene
            .environment
            .as_ref()
            .map(|e| e.source.display().to_string())
            .unwrap_or_else(|| "none".into())
    );
    let load_time = t0.elapsed();
    let spec = path_for(&scene, &args.path, args.first_frame + args.frames);
    let path = CameraPath::from_spec(
        &spec,
        &scene.camera,
        args.seed,
        args.first_frame + args.frames,
        &gs.bvh,
    );
    let horizon: Vec<_> = (0..FAR_HORIZON.max(args.first_frame + args.frames))
        .map(|f| path.camera(f).position)
        .collect();
    let far = scene.far_distance(horizon.iter().chain([&scene.camera.position]));
    let mut tracer = Tracer::new(&gpu, w, h)?;
    let t_compile = Instant::now();
    tracer.compile()?;
    let compile_time = t_compile.elapsed();
    let reference = match args.reference_spp {
        Some(_) => Some(Tensor::new(&gpu, "reference", w, h, 4)?),
        None => None,
    };
    write_sequence_json(args, &scene, &spec, w, h, far)?;

    let bar = indicatif::ProgressBar::new(args.frames as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{bar:40} {pos}/{len} frames {elapsed_precise} eta {eta} {msg}",
        )
        .expect("valid template"),
    );
    let (mut rays, mut samples, mut gpu_secs) = (0u64, 0u64, 0f64);
    let mut skipped = 0;
    for k in 0..args.frames {
        let f = args.first_frame + k;
        let file = args.out.join(format!("frame_{f:04}.exr"));
        if args.resume && file.is_file() {
            skipped += 1;
            bar.inc(1);
            continue;
        }
        let settings = FrameSettings {
            frame: f,
            camera: path.camera(f),
            prev_camera: path.camera(f.saturating_sub(1)),
            mode: args.mode,
            spp: args.spp,
            max_depth: args.max_depth,
            seed: args.seed as u32 ^ (args.seed >> 32) as u32,
            far,
        };
        let t = Instant::now();
        let stats = tracer.render(&gs, &settings)?;
        rays += stats.rays;
        samples += stats.samples;
        let mut host = FrameFile {
            frame: Some(tracer.buffers.download(&gpu)?),
            ..Default::default()
        };
        if let (Some(spp), Some(r)) = (args.reference_spp, &reference) {
            rays += tracer.render_reference(&gs, &settings, spp, r)?;
            samples += w as u64 * h as u64 * spp as u64;
            host.reference = Some(super::tracer::channels(&r.read(&gpu)?, &[0, 1, 2]));
        }
        gpu_secs += t.elapsed().as_secs_f64();
        // Written under a temporary name first, so an interrupted render leaves no
        // truncated frame for --resume to skip.
        let tmp = args.out.join(format!("frame_{f:04}.partial.exr"));
        crate::io::exr::write_frame(&tmp, &host)?;
        std::fs::rename(&tmp, &file)
            .with_context(|| format!("cannot rename {} to {}", tmp.display(), file.display()))?;
        if args.png {
            write_png(&args.out.join(format!("frame_{f:04}.png")), &host)?;
        }
        bar.set_message(format!("{:.1} Mrays/s", rays as f64 / gpu_secs.max(1e-9) / 1e6));
        bar.inc(1);
    }
    bar.finish();
    if skipped > 0 {
        println!("skipped {skipped} frame(s) already in {}", args.out.display());
    }
    let rendered = args.frames - skipped;
    println!(
        "rendered {} frame(s) of {} at {w}x{h}, mode {:?}{}: {} rays, {} samples in {:.3} s \
         ({:.2} Mrays/s, {:.3} s per frame; scene load + BVH {:.3} s, kernel compilation {:.3} s) -> {}",
        rendered,
        scene.name,
        args.mode,
        if args.mode == Mode::Reference {
            format!(" {} spp", args.spp)
        } else {
            String::new()
        },
        rays,
        samples,
        gpu_secs,
        rays as f64 / gpu_secs.max(1e-9) / 1e6,
        gpu_secs / rendered.max(1) as f64,
        load_time.as_secs_f64(),
        compile_time.as_secs_f64(),
        args.out.display()
    );
    Ok(())
}

fn write_sequence_json(
    args: &RenderArgs,
    scene: &Scene,
    spec: &CameraPathSpec,
    w: u32,
    h: u32,
    far: f32,
) -> Result<()> {
    let mut json = serde_json::json!({
        "scene": args.scene,
        "scene_name": scene.name,
        "mode": args.mode,
        "camera_path": spec_name(spec),
        "seed": args.seed,
        "spp": if args.mode == Mode::Reference { Some(args.spp) } else { None },
        "reference_spp": args.reference_spp,
        "resolution": [w, h],
        "frames": args.frames,
        "first_frame": args.first_frame,
        "max_depth": args.max_depth,
        "far": far,
    });
    if let (Some(extra), Some(o)) = (&args.sequence_json, json.as_object_mut()) {
        o.remove("first_frame");
        o.extend(extra.clone());
    }
    let name = if args.first_frame == 0 || args.sequence_json.is_some() {
        "sequence.json".to_string()
    } else {
        format!("sequence_{:04}.json", args.first_frame)
    };
    let p = args.out.join(name);
    std::fs::write(&p, serde_json::to_string_pretty(&json)?)
        .with_context(|| format!("cannot write {}", p.display()))?;
    Ok(())
}

/// Tonemapped 8-bit preview of an HDR tensor's first 3 channels (the tonemap of the
/// metrics, DESIGN §7).
pub fn tonemap_png(path: &Path, t: &HostTensor) -> Result<()> {
    Ok(crate::io::png::write_png_row(path, &[t])?)
}

fn write_png(path: &Path, f: &FrameFile) -> Result<()> {
    let frame = f.frame.as_ref().expect("rendered frames hold buffers");
    tonemap_png(path, f.reference.as_ref().unwrap_or(&frame.color))
}

#[derive(Debug, serde::Serialize)]
struct ModeTiming {
    mode: Mode,
    stages: Vec<StageStats>,
    cpu_wall: Option<crate::gpu::Stats>,
    mrays_per_s: f64,
}

/// Times the G-buffer and trace stages in quarter and full mode.
pub fn bench_render_command(args: &BenchRenderArgs) -> Result<()> {
    let gpu = Gpu::new()?;
    let cpu = gpu.kind() == AdapterKind::Cpu;
    let frames = args.frames.unwrap_or(if cpu { 3 } else { 100 }).max(1);
    let width = args.width.unwrap_or(if cpu { 256 } else { 1920 });
    let height = args.height.unwrap_or(if cpu { 144 } else { 1080 });
    let scene = load_scene(&args.scene)?;
    let gs = GpuScene::new(&gpu, &scene)?;
    let mut tracer = Tracer::new(&gpu, width, height)?;
    tracer.compile()?;
    let path = CameraPath::from_spec(
        &"orbit".parse().expect("known"),
        &scene.camera,
        1,
        frames + args.warmup,
        &gs.bvh,
    );
    let far = scene.far_distance([&scene.camera.position]);
    let mut results = Vec::new();
    for mode in [Mode::Quarter, Mode::Full] {
        let mut prof = Profiler::new(&gpu, 2);
        let mut rays = 0u64;
        let mut secs = 0.0;
        for i in 0..args.warmup + frames {
            let s = FrameSettings {
                frame: i,
                camera: path.camera(i),
                prev_camera: path.camera(i.saturating_sub(1)),
                mode,
                spp: 1,
                max_depth: args.max_depth,
                seed: 7,
                far,
            };
            let t = Instant::now();
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            tracer.encode_frame(&mut enc, &gs, &s, Some(&mut prof))?;
            prof.resolve(&mut enc);
            gpu.queue.submit([enc.finish()]);
            gpu.wait()?;
            let wall = t.elapsed().as_secs_f64();
            prof.collect(&gpu)?;
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
    if args.json {
        let out = serde_json::json!({
            "adapter": gpu.describe(),
            "scene": scene.name,
            "width": width, "height": height,
            "frames": frames, "max_depth": args.max_depth,
            "modes": results,
            "speedup_trace": speedup_trace,
            "speedup_total": speedup_total,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    println!(
        "{} | {} {}x{}, {frames} frames (+{} warm-up), max depth {}",
        gpu.describe(),
        scene.name,
        width,
        height,
        args.warmup,
        args.max_depth
    );
    let timed = results
        .first()
        .and_then(|r| r.stages.first())
        .map(|s| s.gpu)
        .unwrap_or(false);
    println!(
        "times in ms ({}), median / p95",
        if timed { "GPU timestamps" } else { "CPU wall" }
    );
    println!(
        "{:<8} {:>18} {:>18} {:>12} {:>10}",
        "mode", "gbuffer", "trace", "total", "Mrays/s"
    );
    for (i, r) in results.iter().enumerate() {
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
            total(i).map(|t| format!("{t:.3}")).unwrap_or_else(|| "-".into()),
            r.mrays_per_s
        );
    }
    if let (Some(t), Some(a)) = (speedup_trace, speedup_total) {
        println!(
            "quarter vs full: trace {t:.2}x faster, gbuffer + trace {a:.2}x (paper: 12.79 ms -> 4.35 ms, 2.94x)"
        );
    }
    Ok(())
}
