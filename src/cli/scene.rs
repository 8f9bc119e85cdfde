//! `subpixel scene`: summarise a scene (procedural or loaded) and optionally write a small
//! path-traced preview.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};

use crate::render::bvh::SceneBvh;
use crate::render::camera::{CameraPath, CameraPathSpec};
use crate::render::procedural::{self, Generated, PropLibrary, material_kinds, mean_radiance};
use crate::render::scene::{Scene, luminance};
use crate::render::{
    Backend, DEFAULT_MAX_DEPTH, FrameRenderer, FrameSettings, SceneOptions, load_scene_with,
};

#[derive(Debug, clap::Args)]
pub(super) struct SceneArgs {
    /// `builtin:procedural:SEED`, another `builtin:NAME`, a scene.json, a scene folder, or a
    /// .gltf/.glb.
    #[arg(long)]
    scene: String,
    /// How the scene is built (`--props`).
    #[command(flatten)]
    scene_options: SceneOptions,
    /// Write a path-traced preview PNG here.
    #[arg(long)]
    preview: Option<PathBuf>,
    /// Renderer of the preview: auto (GPU on a real GPU, the CPU twin on a CPU adapter or
    /// without one), cpu or gpu.
    #[arg(long, value_enum, default_value_t = Backend::Auto)]
    backend: Backend,
    /// Preview width.
    #[arg(long, default_value_t = 128)]
    width: u32,
    /// Preview height.
    #[arg(long, default_value_t = 128)]
    height: u32,
    /// Preview samples per pixel.
    #[arg(long, default_value_t = 16)]
    spp: u32,
    /// Preview the camera of this frame of the scene's camera path (0: the scene camera).
    #[arg(long, default_value_t = 0)]
    frame: u32,
    /// Largest number of path segments of the preview.
    #[arg(long, default_value_t = DEFAULT_MAX_DEPTH)]
    max_depth: u32,
}

fn describe_path(spec: &Option<CameraPathSpec>) -> String {
    match spec {
        None => "none (static, or the renderer's --path)".into(),
        Some(CameraPathSpec::Static) => "static".into(),
        Some(CameraPathSpec::Orbit { degrees_per_frame }) => match degrees_per_frame {
            Some(d) => format!("orbit, {d:.2} deg/frame"),
            None => "orbit, speed from the seed".into(),
        },
        Some(CameraPathSpec::FlyThrough {
            keys,
            frames_per_key,
            cut_every,
        }) => {
            let keys = match keys {
                Some(k) => format!("{} explicit keys", k.len()),
                None => "generated keys".into(),
            };
            let speed = if *frames_per_key >= 32.0 {
                "slow"
            } else if *frames_per_key <= 16.0 {
                "fast"
            } else {
                "medium"
            };
            let cuts = match cut_every {
                Some(n) => format!(", a cut every {n} frames"),
                None => String::new(),
            };
            format!("flythrough, {keys}, {frames_per_key:.0} frames per key ({speed}){cuts}")
        }
    }
}

fn summary(scene: &Scene, generated: Option<&Generated>) -> Result<()> {
    let g = &scene.geometry;
    let (lo, hi) = scene.bounds();
    println!("scene {}", scene.name);
    if let Some(info) = generated {
        println!(
            "  enclosure: {}; {} objects; attempt {}{}",
            info.enclosure.name(),
            info.objects,
            info.attempt,
            if info.attempt == procedural::MAX_ATTEMPTS {
                " (the fallback scene)"
            } else {
                ""
            }
        );
        if !info.props.is_empty() {
            println!("  props placed: {}", info.props.join(", "));
        }
        for w in &info.warnings {
            println!("  warning: {w}");
        }
    }
    println!(
        "  triangles: {}, vertices: {}, bounds {:.2?} .. {:.2?}",
        g.triangles.len(),
        g.positions.len(),
        lo.to_array(),
        hi.to_array()
    );
    let kinds: Vec<String> = material_kinds(scene)
        .into_iter()
        .map(|(k, n)| format!("{} {n}", k.name()))
        .collect();
    let texels: u64 = scene
        .textures
        .iter()
        .map(|t| t.width as u64 * t.height as u64)
        .sum();
    println!(
        "  materials: {} ({}); textures: {} ({:.2} Mtexels)",
        scene.materials.len(),
        kinds.join(", "),
        scene.textures.len(),
        texels as f64 / 1e6
    );
    // Lights: emissive triangles, grouped by material, with their power.
    let mut power = vec![0.0f64; scene.materials.len()];
    let mut count = vec![0usize; scene.materials.len()];
    for (t, &m) in g.triangles.iter().zip(&g.materials) {
        let l = scene.materials[m as usize].emitted_luminance(&scene.textures);
        if l > 0.0 {
            let [a, b, c] = t.map(|i| g.positions[i as usize]);
            power[m as usize] += (0.5 * (b - a).cross(c - a).length() * l * std::f32::consts::PI) as f64;
            count[m as usize] += 1;
        }
    }
    let lights: Vec<String> = (0..scene.materials.len())
        .filter(|&m| count[m] > 0)
        .map(|m| {
            format!(
                "'{}' ({} tri, radiance {:.1}, power {:.1})",
                scene.materials[m].name,
                count[m],
                luminance(glam::Vec3::from(scene.materials[m].emissive)),
                power[m]
            )
        })
        .collect();
    println!(
        "  lights: {} emissive triangle(s) in {} emitter(s){}{}",
        count.iter().sum::<usize>(),
        lights.len(),
        if lights.is_empty() { "" } else { ": " },
        lights.join(", ")
    );
    match &scene.environment {
        Some(e) => println!(
            "  environment: {} ({}x{}, scale {:.3}, mean radiance {:.3}); {} portal(s){}",
            e.source.display(),
            e.width,
            e.height,
            e.scale,
            mean_radiance(e),
            e.portals.len(),
            if e.portals.is_empty() {
                String::new()
            } else {
                format!(
                    " of {:.2} m^2 (openings it is sampled through)",
                    e.portals.iter().map(|q| q.area()).sum::<f32>()
                )
            }
        ),
        None => println!("  environment: none (black)"),
    }
    let c = &scene.camera;
    println!(
        "  camera: position {:.2?}, target {:.2?}, yfov {:.1} deg; film {}x{}",
        c.position.to_array(),
        c.target.to_array(),
        c.yfov.to_degrees(),
        scene.film.0,
        scene.film.1
    );
    println!("  camera path: {}", describe_path(&scene.camera_path));
    if let Some(info) = generated {
        let v = &info.view;
        println!(
            "  exposure: estimated mean radiance {:.3} (direct light only){}",
            v.estimate,
            if info.light_gain != 1.0 {
                format!(", every light scaled by {:.3}", info.light_gain)
            } else {
                String::new()
            }
        );
        println!(
            "  view check: {:.0}% geometry, {:.0}% objects, {:.0}% of hits directly lit, {:.0}% nearer than \
             0.5, clearance ahead {:.2}",
            100.0 * v.geometry,
            100.0 * v.objects,
            100.0 * v.lit,
            100.0 * v.near,
            v.clearance
        );
    }
    if !scene.approximations.is_empty() {
        println!("  approximated: {}", scene.approximations.join("; "));
    }
    Ok(())
}

pub(super) fn run(a: &SceneArgs) -> Result<()> {
    if a.width == 0 || a.height == 0 || a.spp == 0 {
        bail!("--width, --height and --spp must be positive");
    }
    let options = &a.scene_options;
    let (scene, generated) = match a.scene.strip_prefix("builtin:procedural:") {
        Some(seed) => {
            let seed = procedural::parse_seed(seed)?;
            let mut lib = PropLibrary::load(&options.props)?;
            let g = procedural::generate_with(seed, &mut lib)?;
            (g.scene.clone(), Some(g))
        }
        None => (load_scene_with(&a.scene, options)?, None),
    };
    scene.validate()?;
    summary(&scene, generated.as_ref())?;
    let Some(out) = &a.preview else {
        return Ok(());
    };
    let camera = if a.frame == 0 {
        scene.camera
    } else {
        let spec = scene.camera_path.clone().unwrap_or(CameraPathSpec::Static);
        let bvh = SceneBvh::build(&scene.name, &scene.geometry.positions, &scene.geometry.triangles)?;
        CameraPath::checked(&spec, &scene.camera, 0, a.frame + 1, &bvh)
            .map_err(|e| anyhow::anyhow!("scene {}: {e}", scene.name))?
            .camera(a.frame)
    };
    let gpu = super::render::open_gpu(a.backend)?;
    let mut renderer = FrameRenderer::new(&scene, a.backend, gpu.as_ref(), a.width, a.height)?;
    let far = scene.far_distance([&camera.position]);
    let settings = FrameSettings {
        max_depth: a.max_depth,
        ..FrameSettings::new(camera, crate::render::Mode::Reference, far)
    };
    let t = std::time::Instant::now();
    let reference = renderer.reference(&settings, a.spp)?;
    let rays = reference.rays;
    let host = reference.mean(a.spp);
    let mean: f64 = (0..a.width * a.height)
        .map(|i| {
            let px = &host.data[3 * i as usize..3 * i as usize + 3];
            luminance(glam::Vec3::new(px[0], px[1], px[2])) as f64
        })
        .sum::<f64>()
        / (a.width * a.height) as f64;
    if let Some(parent) = out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).with_context(|| format!("cannot create {}", parent.display()))?;
    }
    crate::io::png::write_png_row(out, &[&host])?;
    println!(
        "preview: {}x{} at {} spp on {} in {:.2} s ({} rays), mean radiance {:.3} -> {}",
        a.width,
        a.height,
        a.spp,
        match (&gpu, renderer.backend()) {
            (Some(g), Backend::Gpu) => g.describe(),
            _ => format!("the CPU twin ({} threads)", rayon::current_num_threads()),
        },
        t.elapsed().as_secs_f64(),
        rays,
        mean,
        out.display()
    );
    Ok(())
}
