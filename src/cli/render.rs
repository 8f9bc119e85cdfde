//! `subpixel render`: path-traced frames of a scene along a camera path, one
//! multi-channel EXR per frame (the data contract of DESIGN section 3), resumable, with
//! each sequence's `sequence.json` and reference-noise estimate. `subpixel dataset` renders
//! through it.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};

use crate::gpu::Gpu;
use crate::io::exr::FrameFile;
use crate::nn::HostTensor;
use crate::render::backend::{Backend, FrameRenderer};
use crate::render::camera::CameraPathSpec;
use crate::render::scene::Scene;
use crate::render::tracer::{DEFAULT_MAX_DEPTH, FrameSettings, Mode};
use crate::render::{CpuTracer, PackedScene};

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
    /// Double each reference's samples until the PSNR between its halves (the recorded
    /// `reference_noise`) reaches DB, up to `--reference-spp-max`; the samples each frame
    /// took go to `sequence.json` (`reference_spp_per_frame`). Needs an even
    /// `--reference-spp`.
    #[arg(long, value_name = "DB", requires = "reference_spp")]
    pub reference_noise_target: Option<f64>,
    /// Most samples a reference may take under `--reference-noise-target` (default: 16
    /// times `--reference-spp`).
    #[arg(long, value_name = "SPP", requires = "reference_noise_target")]
    pub reference_spp_max: Option<u32>,
    /// Also write a tonemapped PNG preview of the colour of every frame.
    #[arg(long)]
    pub png: bool,
    /// Skip frames whose EXR already exists (resume an interrupted render).
    #[arg(long)]
    pub resume: bool,
    /// Renderer: auto (the WGSL tracer on a real GPU, its CPU twin when the adapter is a
    /// CPU driver or there is none), cpu or gpu.
    #[arg(long, value_enum, default_value_t = Backend::Auto)]
    pub backend: Backend,
    /// Also store a 1-spp full-resolution colour of every frame (`full` channels: four
    /// times the samples of a quarter frame, for baselines such as OIDN).
    #[arg(long)]
    pub full_spp: bool,
    /// Also store the directly seen environment averaged over each pixel's footprint
    /// (`background` channels), the fraction of the footprint that escapes (`coverage`) and
    /// the first-hit base colour averaged over it (`albedo_footprint`), from N x N
    /// stratified camera rays per pixel (no path tracing; the denoiser composites the
    /// background), and the directly seen emission (`emission_footprint`, and `emission`
    /// and `escaped` for the traced samples). With `--resume`, frames written before without
    /// some of them get them added (by the CPU twin).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..))]
    pub background: Option<u32>,
    /// Camera path when neither `--path` nor the scene gives one (set by `subpixel
    /// dataset`: a fly-through whatever the shard's frame count).
    #[arg(skip)]
    pub fallback_path: Option<CameraPathSpec>,
    /// Extra keys for `sequence.json` (set by `subpixel dataset`). When given, every shard
    /// writes the same complete `sequence.json` before rendering its frames.
    #[arg(skip)]
    pub sequence_json: Option<serde_json::Map<String, serde_json::Value>>,
    /// How the scene is built (`--props`).
    #[command(flatten)]
    pub scene_options: crate::render::SceneOptions,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
}

fn path_for(
    scene: &Scene,
    arg: &Option<CameraPathSpec>,
    fallback: &Option<CameraPathSpec>,
    frames: u32,
) -> CameraPathSpec {
    arg.clone()
        .or_else(|| scene.camera_path.clone())
        .or_else(|| fallback.clone())
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

impl RenderArgs {
    /// Most samples a reference may take under `--reference-noise-target`: its
    /// `--reference-spp-max`, by default 16 times `--reference-spp`; `None` without a target
    /// or a reference.
    pub fn reference_spp_cap(&self) -> Option<u32> {
        self.reference_noise_target?;
        let spp = self.reference_spp?;
        Some(self.reference_spp_max.unwrap_or(spp.saturating_mul(16)))
    }
}

/// Keys of `sequence.json` that describe how frames were made without changing what they
/// hold: a resumed render may differ in them.
const SEQUENCE_INFO_KEYS: &[&str] = &[
    "first_frame",
    "backend",
    "reference_noise",
    "reference_spp_per_frame",
    // a resume with `--background` adds it to the frames already there
    "background_lookups",
];

/// Frames over which the depth normalisation is computed, whatever the shard.
const FAR_HORIZON: u32 = 1024;

/// Renders `args.frames` frames into `args.out`.
pub fn render_command(args: &RenderArgs) -> Result<()> {
    if args.frames == 0 {
        bail!("--frames must be at least 1");
    }
    if args.spp == 0 {
        bail!("--spp must be at least 1");
    }
    if args.reference_spp == Some(0) {
        bail!("--reference-spp must be at least 1");
    }
    if let Some(db) = args.reference_noise_target {
        if !db.is_finite() || db <= 0.0 {
            bail!("--reference-noise-target must be a positive number of dB, not {db}");
        }
        if args.reference_spp.is_some_and(|n| n % 2 != 0) {
            bail!("--reference-noise-target needs an even --reference-spp (its halves are then equal)");
        }
    }
    if args.max_depth == 0 {
        bail!("--max-depth must be at least 1 (1 = emitters seen directly)");
    }
    let Some(end_frame) = args.first_frame.checked_add(args.frames) else {
        bail!(
            "--first-frame {} + --frames {} is past the largest frame index {}",
            args.first_frame,
            args.frames,
            u32::MAX
        );
    };
    let scene = crate::render::load_scene_with(&args.scene, &args.scene_options)?;
    scene.warn_approximations();
    let (w, h) = (
        args.width.unwrap_or(scene.film.0),
        args.height.unwrap_or(scene.film.1),
    );
    if w == 0 || h == 0 {
        bail!("image size {w}x{h}: width and height must be positive");
    }
    std::fs::create_dir_all(&args.out).with_context(|| format!("cannot create {}", args.out.display()))?;
    let gpu = open_gpu(args.backend)?;
    let t0 = Instant::now();
    let mut renderer = FrameRenderer::new(&scene, args.backend, gpu.as_ref(), w, h)?;
    let backend = renderer.backend();
    match (&gpu, backend) {
        (Some(g), Backend::Gpu) => eprintln!("backend: gpu ({})", g.describe()),
        _ => eprintln!("backend: cpu ({} threads)", rayon::current_num_threads()),
    }
    let load_time = t0.elapsed();
    let packed = renderer.packed();
    eprintln!(
        "scene {}: {} triangles, BVH {:.1} ms ({:.2} Mtri/s), {} emissive triangles, environment: {}",
        scene.name,
        packed.triangle_count(),
        packed.bvh.build_time.as_secs_f64() * 1e3,
        packed.triangle_count() as f64 / packed.bvh.build_time.as_secs_f64().max(1e-9) / 1e6,
        packed.emissive_triangles,
        scene
            .environment
            .as_ref()
            .map(|e| e.source.display().to_string())
            .unwrap_or_else(|| "none".into())
    );
    let spec = path_for(&scene, &args.path, &args.fallback_path, end_frame);
    let (path, far) = scene.camera_path(&spec, args.seed, end_frame, FAR_HORIZON, &packed.bvh)?;
    write_sequence_json(args, &scene, &spec, w, h, far)?;

    let bar = indicatif::ProgressBar::new(args.frames as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{bar:40} {pos}/{len} frames {elapsed_precise} eta {eta} {msg}",
        )
        .expect("valid template"),
    );
    let (mut rays, mut samples, mut render_secs) = (0u64, 0u64, 0f64);
    let mut skipped = 0;
    for k in 0..args.frames {
        let f = args.first_frame + k;
        let file = args.out.join(format!("frame_{f:04}.exr"));
        let seed = args.seed as u32 ^ (args.seed >> 32) as u32;
        let settings = FrameSettings {
            spp: args.spp,
            max_depth: args.max_depth,
            background: args.background.unwrap_or(0),
            ..FrameSettings::along(&path, f, args.mode, seed, far)
        };
        if args.resume && file.is_file() {
            if settings.background > 0 {
                add_background(&file, renderer.packed(), &settings)?;
            }
            skipped += 1;
            bar.inc(1);
            continue;
        }
        let t = Instant::now();
        let (frame, stats) = renderer.frame(&settings)?;
        rays += stats.rays;
        samples += stats.samples;
        let mut host = FrameFile {
            frame: Some(frame),
            ..Default::default()
        };
        let mut reference_spp = None;
        if let Some(spp) = args.reference_spp {
            let (r, spp) = match args.reference_noise_target {
                Some(db) => {
                    let max = args.reference_spp_cap().unwrap_or(spp);
                    renderer.reference_to_noise(&settings, spp, db, max)?
                }
                None => (renderer.reference(&settings, spp)?, spp),
            };
            rays += r.rays;
            samples += w as u64 * h as u64 * spp as u64;
            host.reference = Some(r.mean(spp));
            reference_spp = Some(spp);
            host.reference_half = Some(r.first);
        }
        if args.full_spp {
            let (full, stats) = renderer.frame(&FrameSettings {
                mode: Mode::Full,
                background: 0,
                ..settings
            })?;
            rays += stats.rays;
            samples += stats.samples;
            host.full = Some(full.color);
        }
        render_secs += t.elapsed().as_secs_f64();
        write_frame_atomically(&file, &host)?;
        if let (Some(spp), Some(_)) = (reference_spp, args.reference_noise_target) {
            // Recorded with the frame, so that a run stopped later loses none of them.
            update_sequence_json(&args.out, |o| {
                if let Some(e) = o
                    .entry("reference_spp_per_frame")
                    .or_insert_with(|| serde_json::json!({}))
                    .as_object_mut()
                {
                    e.insert(format!("frame_{f:04}"), serde_json::json!(spp));
                }
                Ok(true)
            })?;
        }
        if args.png {
            write_png(&args.out.join(format!("frame_{f:04}.png")), &host)?;
        }
        bar.set_message(format!(
            "{:.1} Mrays/s",
            rays as f64 / render_secs.max(1e-9) / 1e6
        ));
        bar.inc(1);
        if bar.is_hidden() {
            // No terminal (a background job's log): one line per frame instead of the bar.
            println!(
                "frame {f} written in {:.1} s ({}/{} of this run, {:.2} Mrays/s)",
                t.elapsed().as_secs_f64(),
                k + 1,
                args.frames,
                rays as f64 / render_secs.max(1e-9) / 1e6
            );
        }
    }
    bar.finish();
    if args.reference_spp.is_some() {
        update_reference_noise(&args.out)?;
    }
    if skipped > 0 {
        println!("skipped {skipped} frame(s) already in {}", args.out.display());
    }
    let rendered = args.frames - skipped;
    println!(
        "rendered {} frame(s) of {} at {w}x{h} on the {} backend, mode {:?}{}: {} rays, {} samples in {:.3} s \
         ({:.2} Mrays/s, {:.3} s per frame; scene load + BVH {:.3} s) -> {}",
        rendered,
        scene.name,
        backend.name(),
        args.mode,
        if args.mode == Mode::Reference {
            format!(" {} spp", args.spp)
        } else {
            String::new()
        },
        rays,
        samples,
        render_secs,
        rays as f64 / render_secs.max(1e-9) / 1e6,
        render_secs / rendered.max(1) as f64,
        load_time.as_secs_f64(),
        args.out.display()
    );
    Ok(())
}

/// Opens the adapter when `backend` may use it: always for `gpu`, for `auto` when one can
/// be opened (none means the CPU backend), never for `cpu`.
pub fn open_gpu(backend: Backend) -> Result<Option<Gpu>> {
    match backend {
        Backend::Cpu => Ok(None),
        Backend::Gpu => Ok(Some(Gpu::new()?)),
        Backend::Auto => match Gpu::new() {
            Ok(g) => Ok(Some(g)),
            Err(e) => {
                log::warn!("no GPU adapter ({e}); rendering on the CPU");
                Ok(None)
            }
        },
    }
}

/// Writes frame file `file` under a temporary name first (`frame_NNNN.partial.exr`), so
/// that an interrupted write leaves no truncated frame for `--resume` to skip.
fn write_frame_atomically(file: &Path, ff: &FrameFile) -> Result<()> {
    let tmp = file.with_extension("partial.exr");
    crate::io::exr::write_frame(&tmp, ff)?;
    std::fs::rename(&tmp, file)
        .with_context(|| format!("cannot rename {} to {}", tmp.display(), file.display()))?;
    Ok(())
}

/// Adds the background (`background`, `coverage`, `albedo_footprint`, `emission_footprint`
/// and `emission` channels, `CpuTracer::background` with `settings.background` lookups per
/// pixel axis) to the frame file `file` when it lacks one (a frame rendered before
/// `--background` existed), and the parts a background written before them lacks (the
/// footprint albedo, the directly seen emission, the samples' escapes: its radiance and
/// coverage are kept as they are), rewriting the file atomically; a frame that has them all
/// is left alone.
fn add_background(file: &Path, packed: &PackedScene, settings: &FrameSettings) -> Result<()> {
    let mut ff = crate::io::exr::read_frame(file)?;
    let frame = ff
        .frame
        .as_mut()
        .with_context(|| format!("{}: a frame file without the renderer's buffers", file.display()))?;
    let (w, h) = frame.size()?;
    let tracer = CpuTracer::new(w, h)?;
    let mut changed = false;
    if !frame
        .background
        .as_ref()
        .is_some_and(|b| b.albedo.is_some() && b.emission.is_some())
    {
        let made = tracer.background(packed, settings)?;
        match &mut frame.background {
            Some(b) => {
                b.albedo = b.albedo.take().or(made.albedo);
                b.emission = b.emission.take().or(made.emission);
            }
            None => frame.background = Some(made),
        }
        changed = true;
    }
    if let Some(e) = frame.direct_emission_mut().filter(|e| e.escaped.is_none()) {
        // Written before the samples' escapes: replay the camera rays.
        e.escaped = Some(tracer.sample_first_hits(packed, settings).1);
        changed = true;
    }
    if changed {
        write_frame_atomically(file, &ff)?;
    }
    Ok(())
}

/// PSNR (tonemapped, DESIGN §7) between the two halves of each reference in `dir`, from
/// the `reference` and `reference_half` channels of its frames, written into
/// `sequence.json` as `reference_noise` (per frame, mean and minimum).
pub fn update_reference_noise(dir: &Path) -> Result<()> {
    update_sequence_json(dir, |o| {
        let spp = o.get("reference_spp").and_then(|v| v.as_u64()).unwrap_or(0) as u32;
        let mut per_frame = serde_json::Map::new();
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
            .with_context(|| format!("cannot list {}", dir.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                let n = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
                n.starts_with("frame_") && n.ends_with(".exr") && !n.ends_with(".partial.exr")
            })
            .collect();
        files.sort();
        let mut values = Vec::new();
        for f in &files {
            let ff = crate::io::exr::read_frame(f)?;
            let (Some(r), Some(a)) = (ff.reference, ff.reference_half) else {
                continue;
            };
            let psnr = crate::metrics::reference_halves_psnr(&r, &a, spp);
            let name = f.file_stem().and_then(|n| n.to_str()).unwrap_or("").to_string();
            per_frame.insert(name, serde_json::json!(psnr));
            values.push(psnr);
        }
        if values.is_empty() {
            return Ok(false);
        }
        let finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
        let mean = finite.iter().sum::<f64>() / finite.len().max(1) as f64;
        let min = values.iter().copied().fold(f64::INFINITY, f64::min);
        o.insert(
            "reference_noise".into(),
            serde_json::json!({
                "measure": "PSNR (dB, tonemapped 8-bit) between the means of samples 0..spp/2 and spp/2..spp",
                "frames": values.len(),
                "mean_psnr_db": mean,
                "min_psnr_db": min,
                "per_frame": per_frame,
            }),
        );
        Ok(true)
    })
}

/// Applies `change` to the object of `dir/sequence.json` (read once) and, if it says it
/// changed something, writes it back atomically; no `sequence.json` (a shard's own
/// `sequence_NNNN.json`) is left alone.
fn update_sequence_json(
    dir: &Path,
    change: impl FnOnce(&mut serde_json::Map<String, serde_json::Value>) -> Result<bool>,
) -> Result<()> {
    let json_path = dir.join("sequence.json");
    let Ok(text) = std::fs::read_to_string(&json_path) else {
        return Ok(());
    };
    let mut json: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("cannot parse {}", json_path.display()))?;
    let Some(o) = json.as_object_mut() else {
        return Ok(());
    };
    if !change(o)? {
        return Ok(());
    }
    let tmp = dir.join("sequence.json.partial");
    std::fs::write(&tmp, serde_json::to_string_pretty(&json)?)
        .with_context(|| format!("cannot write {}", tmp.display()))?;
    std::fs::rename(&tmp, &json_path).with_context(|| format!("cannot write {}", json_path.display()))?;
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
        "reference_noise_target": args.reference_noise_target,
        "reference_spp_max": args.reference_spp_cap(),
        "resolution": [w, h],
        "frames": args.frames,
        "first_frame": args.first_frame,
        "max_depth": args.max_depth,
        "far": far,
        "backend": args.backend.name(),
        "full_spp": args.full_spp,
        "background_lookups": args.background.map(|n| n * n),
        "props": args.scene_options.props.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
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
    // Resuming (or another shard of the same sequence) must not mix frames rendered with
    // other parameters; a plain render overwrites.
    if let Ok(text) = std::fs::read_to_string(&p)
        && let Ok(old) = serde_json::from_str::<serde_json::Value>(&text)
        && let (Some(old), Some(new)) = (old.as_object(), json.as_object_mut())
    {
        let has_frames = std::fs::read_dir(&args.out)
            .map(|d| {
                d.filter_map(|e| e.ok())
                    .any(|e| e.file_name().to_string_lossy().ends_with(".exr"))
            })
            .unwrap_or(false);
        if has_frames && args.resume {
            for (k, v) in new.iter() {
                if SEQUENCE_INFO_KEYS.contains(&k.as_str()) {
                    continue;
                }
                if let Some(o) = old.get(k)
                    && !same_setting(o, v)
                {
                    bail!(
                        "{} holds frames rendered with {k} = {o}, not {v}: render into another folder, \
                         or delete it to start over",
                        args.out.display()
                    );
                }
            }
        }
        for key in ["reference_noise", "reference_spp_per_frame"] {
            if let Some(v) = old.get(key) {
                new.insert(key.into(), v.clone());
            }
        }
    }
    let tmp = p.with_extension("json.partial");
    std::fs::write(&tmp, serde_json::to_string_pretty(&json)?)
        .with_context(|| format!("cannot write {}", tmp.display()))?;
    std::fs::rename(&tmp, &p).with_context(|| format!("cannot write {}", p.display()))?;
    Ok(())
}

/// Whether a setting read back from a `sequence.json` is the one about to be written. The
/// renderer's real-valued settings (`far`) are `f32`: two numbers are the same setting when
/// they round to the same `f32`, so a decimal written and read back by another JSON
/// implementation (or an older parser that was one f64 ulp off) still matches.
fn same_setting(old: &serde_json::Value, new: &serde_json::Value) -> bool {
    use serde_json::Value;
    match (old, new) {
        (Value::Number(a), Value::Number(b)) if a.is_f64() || b.is_f64() => {
            matches!((a.as_f64(), b.as_f64()), (Some(x), Some(y)) if x as f32 == y as f32)
        }
        (Value::Array(a), Value::Array(b)) => {
            a.len() == b.len() && a.iter().zip(b).all(|(x, y)| same_setting(x, y))
        }
        _ => old == new,
    }
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

#[cfg(test)]
mod tests {
    use super::same_setting;
    use serde_json::json;

    /// The far distance of a sequence rendered in an earlier session, as read back from its
    /// sequence.json (one f64 ulp away from the f32 the renderer computes now), is the same
    /// setting; a different far distance, count or name is not.
    #[test]
    fn settings_read_back_match_at_the_renderers_precision() {
        let now = json!(18.337_331_f32);
        let written: serde_json::Value = serde_json::from_str(&now.to_string()).unwrap();
        assert!(same_setting(&written, &now));
        assert!(same_setting(&json!(18.337331771850582_f64), &now));
        assert!(!same_setting(&json!(18.3374_f64), &now));
        assert!(same_setting(&json!([128, 128]), &json!([128, 128])));
        assert!(!same_setting(&json!([128, 128]), &json!([128, 64])));
        assert!(!same_setting(&json!(8), &json!(9)));
        assert!(!same_setting(&json!("flythrough"), &json!("orbit")));
    }
}
