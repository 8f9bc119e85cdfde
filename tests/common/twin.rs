//! The CPU twin against the WGSL tracer: shared checks of `tests/cpu_twin.rs` (built-in
//! scenes) and `tests/scenes.rs` (the shared scenes).

use std::sync::Arc;

use subpixel::frame::HostFrame;
use subpixel::nn::HostTensor;
use subpixel::render::scene::Scene;
use subpixel::render::{CpuTracer, FrameSettings, GpuScene, Mode, PackedScene, Tracer};

use super::gpu;

/// The scene packed once for both backends (no texture downscaling).
pub fn packed(scene: &Scene) -> Arc<PackedScene> {
    Arc::new(PackedScene::new(scene, u64::MAX).unwrap())
}

pub fn settings(scene: &Scene, mode: Mode, spp: u32, seed: u32) -> FrameSettings {
    let mut s = FrameSettings::new(scene.camera, mode, scene.far_distance([&scene.camera.position]));
    s.spp = spp;
    s.seed = seed;
    s.frame = 5;
    // A previous camera a little to the side: non-trivial motion vectors.
    let (r, _, _) = scene.camera.basis();
    let d = 0.02 * (scene.camera.target - scene.camera.position).length();
    s.prev_camera.position += r * d;
    s.prev_camera.target += r * d;
    s
}

pub fn gpu_frame(gs: &GpuScene, w: u32, h: u32, s: &FrameSettings) -> HostFrame {
    let g = gpu();
    let mut t = Tracer::new(&g, w, h).unwrap();
    t.render(gs, s).unwrap();
    t.buffers.download(&g).unwrap()
}

pub fn cpu_frame(p: &PackedScene, w: u32, h: u32, s: &FrameSettings) -> HostFrame {
    CpuTracer::new(w, h).unwrap().render(p, s).unwrap().0
}

pub fn channel_means(t: &HostTensor) -> Vec<f64> {
    let c = t.channels as usize;
    (0..c)
        .map(|k| t.data.iter().skip(k).step_by(c).map(|&v| v as f64).sum::<f64>() / (t.data.len() / c) as f64)
        .collect()
}

/// G-buffers agree to float tolerance; with the same seed nearly every traced pixel follows
/// the same path on both backends (quarter and full frames, `w x h`).
pub fn assert_same_seed_frames_match(scene: &Scene, w: u32, h: u32) {
    let p = packed(scene);
    let gs = GpuScene::upload(&gpu(), p.clone()).unwrap();
    for mode in [Mode::Quarter, Mode::Full] {
        let s = settings(scene, mode, 1, 7);
        let g = gpu_frame(&gs, w, h, &s);
        let c = cpu_frame(&p, w, h, &s);
        // Per pixel, every G-buffer agrees to float tolerance, except where the primary ray
        // meets two overlapping surfaces at the same distance (z-fighting in the scene): the
        // tie may break either way under float rounding, so there the depth must agree and
        // such pixels must stay rare.
        let n = (w * h) as usize;
        let mut ties = Vec::new();
        for i in 0..n {
            let mut differ = Vec::new();
            for (name, gt, ct) in [
                ("mask", &g.mask, &c.mask),
                ("albedo", &g.albedo, &c.albedo),
                ("normal", &g.normal, &c.normal),
                ("depth", &g.depth, &c.depth),
                ("metallic", &g.metallic, &c.metallic),
                ("roughness", &g.roughness, &c.roughness),
                ("transparent", &g.transparent, &c.transparent),
                ("motion", &g.motion, &c.motion),
            ] {
                let k = gt.channels as usize;
                for j in k * i..k * i + k {
                    let (a, b) = (gt.data[j], ct.data[j]);
                    if (a - b).abs() > 1e-4 + 1e-4 * b.abs() {
                        differ.push((name, a, b));
                    }
                }
            }
            if differ.is_empty() {
                continue;
            }
            let same_depth = (g.depth.data[i] - c.depth.data[i]).abs() <= 1e-4;
            assert!(
                same_depth && !differ.iter().any(|d| d.0 == "mask"),
                "{} {mode:?} pixel {i}: G-buffers differ (name, gpu, cpu): {differ:?}",
                scene.name
            );
            ties.push((i, differ));
        }
        if !ties.is_empty() {
            eprintln!(
                "{} {mode:?}: {} tie pixel(s): {:?}",
                scene.name,
                ties.len(),
                &ties[..ties.len().min(3)]
            );
        }
        assert!(
            ties.len() * 100 <= n,
            "{} {mode:?}: {} of {n} pixels hit a different surface at the same depth",
            scene.name,
            ties.len()
        );
        // Colour and NEE shadow: the same random numbers give the same paths, up to paths
        // that diverge through float rounding (a different branch taken).
        for (name, gt, ct) in [("color", &g.color, &c.color), ("shadow", &g.shadow, &c.shadow)] {
            let same = (0..n)
                .filter(|&i| {
                    (0..3).all(|k| {
                        let (a, b) = (gt.data[3 * i + k], ct.data[3 * i + k]);
                        (a - b).abs() <= 1e-3 * (1.0 + b.abs())
                    })
                })
                .count();
            eprintln!("{} {mode:?} {name}: {same}/{n} pixels identical", scene.name);
            assert!(
                same as f64 >= 0.95 * n as f64,
                "{} {mode:?} {name}: only {same}/{n} pixels agree",
                scene.name
            );
        }
    }
}

/// `spp`-sample references (`w x h`) differ only by noise: the PSNR between CPU and GPU
/// renders of different seeds no lower, beyond 0.5 dB, than between GPU renders of
/// different seeds, and per-channel means within 1.5 %. Common random numbers keep the
/// comparison sharp on heavy-tailed scenes: the CPU renders use the GPU renders' seeds, and
/// each is compared with the GPU renders of the *other* seeds, so a systematic difference
/// between the backends shows while their shared sampling noise cancels.
pub fn assert_references_agree(scene: &Scene, w: u32, h: u32, spp: u32) {
    let p = packed(scene);
    let gs = GpuScene::upload(&gpu(), p.clone()).unwrap();
    let seeds = [1u32, 2, 5];
    let g: Vec<HostTensor> = seeds
        .iter()
        .map(|&k| gpu_frame(&gs, w, h, &settings(scene, Mode::Reference, spp, k)).color)
        .collect();
    let c: Vec<HostTensor> = seeds
        .iter()
        .map(|&k| cpu_frame(&p, w, h, &settings(scene, Mode::Reference, spp, k)).color)
        .collect();
    // PSNR from the mean MSE over pairs (one pair's PSNR is itself noisy).
    let pooled = |pairs: &[(&HostTensor, &HostTensor)]| {
        let mse = pairs
            .iter()
            .map(|(a, b)| 10f64.powf(-subpixel::metrics::psnr(a, b) / 10.0))
            .sum::<f64>()
            / pairs.len() as f64;
        -10.0 * mse.log10()
    };
    let mut gg_pairs = Vec::new();
    let mut cg_pairs = Vec::new();
    for i in 0..seeds.len() {
        for j in 0..seeds.len() {
            if i < j {
                gg_pairs.push((&g[i], &g[j]));
            }
            if i != j {
                cg_pairs.push((&c[i], &g[j]));
            }
        }
    }
    // Same seeds: nearly every sample follows the same path, so the two references are
    // nearly the same image (this caught lavapipe dropping samples of long GPU passes).
    for i in 0..seeds.len() {
        let same = subpixel::metrics::psnr(&c[i], &g[i]);
        eprintln!(
            "{}: seed {}: PSNR CPU-GPU with the same random numbers {same:.2} dB",
            scene.name, seeds[i]
        );
        assert!(
            same >= 40.0,
            "{}: same-seed references differ: {same:.2} dB",
            scene.name
        );
    }
    let gg = pooled(&gg_pairs);
    let cg = pooled(&cg_pairs);
    eprintln!("{}: PSNR GPU-GPU {gg:.2} dB, CPU-GPU {cg:.2} dB", scene.name);
    assert!(
        cg >= gg - 0.5,
        "{}: CPU-GPU PSNR {cg:.2} dB vs GPU-GPU {gg:.2} dB",
        scene.name
    );
    let pooled_means = |t: &[HostTensor]| {
        let m: Vec<Vec<f64>> = t.iter().map(channel_means).collect();
        (0..3)
            .map(|k| m.iter().map(|v| v[k]).sum::<f64>() / m.len() as f64)
            .collect::<Vec<f64>>()
    };
    let (mg, mc) = (pooled_means(&g), pooled_means(&c));
    for k in 0..3 {
        let rel = (mg[k] - mc[k]).abs() / mc[k].abs().max(1e-6);
        eprintln!(
            "{} channel {k}: GPU {:.5}, CPU {:.5} ({:.3} %)",
            scene.name,
            mg[k],
            mc[k],
            100.0 * rel
        );
        assert!(
            rel <= 0.015,
            "{} channel {k}: GPU mean {} vs CPU {}",
            scene.name,
            mg[k],
            mc[k]
        );
    }
}
