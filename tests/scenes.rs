//! Every scene under `$SUBPIXEL_SCENES` (default `../shared/scenes`) loads and renders at a
//! tiny size. Ignored by default (the scenes live outside the repository); CI runs them with
//! `cargo test --release --test scenes -- --ignored`.

mod common;

use std::path::PathBuf;

use subpixel::render::{CameraPath, FrameSettings, GpuScene, Mode, Tracer, load_scene, query_rays};

fn scenes_dir() -> PathBuf {
    std::env::var_os("SUBPIXEL_SCENES")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/scenes"))
}

fn scene_folders() -> Vec<PathBuf> {
    let dir = scenes_dir();
    let mut v: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("cannot list {}: {e} (set SUBPIXEL_SCENES)", dir.display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("scene.json").is_file())
        .collect();
    v.sort();
    v
}

#[test]
#[ignore]
fn every_scene_loads_and_renders() {
    let g = common::gpu();
    let folders = scene_folders();
    assert!(
        !folders.is_empty(),
        "no scene.json under {}",
        scenes_dir().display()
    );
    for dir in folders {
        let name = dir.display().to_string();
        let t0 = std::time::Instant::now();
        let scene = load_scene(&name).unwrap_or_else(|e| panic!("{e}"));
        scene.warn_approximations();
        let t_load = t0.elapsed();
        let gs = GpuScene::new(&g, &scene).unwrap_or_else(|e| panic!("{e}"));
        let t_upload = t0.elapsed() - t_load;
        // GPU traversal == obvhs CPU traversal on rays from the scene camera.
        let (r, u, f) = scene.camera.basis();
        let rays: Vec<_> = (0..2000)
            .map(|i| {
                let a = (i as f32 * 0.618_034).fract() * 2.0 - 1.0;
                let b = (i as f32 * 0.414_213_6).fract() * 2.0 - 1.0;
                (
                    scene.camera.position,
                    (f + 0.8 * a * r + 0.6 * b * u).normalize(),
                    f32::INFINITY,
                )
            })
            .collect();
        let hits = query_rays(&g, &gs, &rays, false).unwrap();
        let mut mismatches = 0;
        for ((o, d, tmax), h) in rays.iter().zip(&hits) {
            let c = gs.bvh.intersect(*o, *d, *tmax);
            let same = match (c, h) {
                (None, None) => true,
                (Some((cp, ct)), Some((gp, gt))) => cp == *gp && (ct - gt).abs() <= 1e-4 * ct.abs().max(1e-3),
                _ => false,
            };
            mismatches += !same as usize;
        }
        // Alpha-masked triangles are skipped by the GPU only (the CPU reference has no
        // textures): allow those few rays.
        let masked = scene
            .materials
            .iter()
            .any(|m| matches!(m.alpha, subpixel::render::scene::AlphaMode::Mask(_)));
        assert!(
            mismatches == 0 || (masked && mismatches < 100),
            "{name}: {mismatches} of 2000 rays differ"
        );
        // Tiny, with the film's aspect ratio.
        let (fw, fh) = scene.film;
        let w = 24u32;
        let h = ((w as f32 * fh as f32 / fw as f32).round() as u32).max(4);
        let path = CameraPath::from_spec(&"flythrough".parse().unwrap(), &scene.camera, 1, 3, &gs.bvh);
        let far = scene.far_distance([&scene.camera.position]);
        let mut t = Tracer::new(&g, w, h).unwrap();
        let mut total = 0.0f64;
        for (frame, mode) in [(0, Mode::Reference), (1, Mode::Quarter), (2, Mode::Full)] {
            let mut s = FrameSettings::new(path.camera(frame), mode, far);
            s.frame = frame;
            s.prev_camera = path.camera(frame.saturating_sub(1));
            s.spp = 4;
            s.max_depth = 4;
            let stats = t.render(&gs, &s).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert!(stats.rays > 0, "{name}: no rays traced");
            let f = t.buffers.download(&g).unwrap();
            for (buf, tensor, _) in f.fields() {
                assert!(
                    tensor.data.iter().all(|v| v.is_finite()),
                    "{name} {mode:?}: non-finite {buf}"
                );
            }
            assert!(
                f.color.data.iter().all(|&v| v >= 0.0),
                "{name}: negative radiance"
            );
            assert!(
                f.depth.data.iter().all(|&d| (0.0..=1.0).contains(&d)),
                "{name}: depth out of [0, 1]"
            );
            total += f.color.data.iter().map(|&v| v as f64).sum::<f64>();
            // Something is in view.
            assert!(
                f.depth.data.iter().any(|&d| d < 1.0),
                "{name}: the camera sees no geometry"
            );
        }
        assert!(total > 0.0, "{name}: black image");
        eprintln!(
            "{name}: ok ({} triangles, {w}x{h}; load {:.2} s, BVH + upload {:.2} s, total {:.2} s)",
            gs.triangle_count(),
            t_load.as_secs_f64(),
            t_upload.as_secs_f64(),
            t0.elapsed().as_secs_f64()
        );
    }
}

/// The CPU twin agrees with the WGSL tracer on every shared scene: G-buffers to float
/// tolerance, same-seed paths, and references that differ only by noise.
#[test]
#[ignore]
fn cpu_twin_agrees_on_every_scene() {
    for dir in scene_folders() {
        let name = dir.display().to_string();
        let scene = load_scene(&name).unwrap_or_else(|e| panic!("{e}"));
        let (fw, fh) = scene.film;
        let w = 32u32;
        let h = ((w as f32 * fh as f32 / fw as f32).round() as u32).max(4);
        let t0 = std::time::Instant::now();
        common::twin::assert_same_seed_frames_match(&scene, w, h);
        common::twin::assert_references_agree(&scene, w, h, 128);
        eprintln!("{name}: CPU twin agrees ({:.1} s)", t0.elapsed().as_secs_f64());
    }
}
