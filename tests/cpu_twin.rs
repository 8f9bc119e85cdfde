//! The CPU twin of the path tracer against the WGSL tracer (any adapter; a CPU Vulkan
//! driver is enough), and its own furnace and energy tests.
//!
//! Both backends read the same packed scene and draw the same PCG random numbers, so with
//! one seed most paths are traced identically (a strong check of the integrator's logic);
//! with different seeds their images differ only by Monte Carlo noise.

mod common;

use std::sync::Arc;

use common::gpu;
use subpixel::frame::HostFrame;
use subpixel::nn::HostTensor;
use subpixel::render::builtin;
use subpixel::render::scene::{Material, Scene};
use subpixel::render::{CpuTracer, FrameSettings, GpuScene, Mode, PackedScene, Tracer, load_scene};

fn packed(scene: &Scene) -> Arc<PackedScene> {
    Arc::new(PackedScene::new(scene, u64::MAX).unwrap())
}

fn settings(scene: &Scene, mode: Mode, spp: u32, seed: u32) -> FrameSettings {
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

fn gpu_frame(gs: &GpuScene, w: u32, h: u32, s: &FrameSettings) -> HostFrame {
    let g = gpu();
    let mut t = Tracer::new(&g, w, h).unwrap();
    t.render(gs, s).unwrap();
    t.buffers.download(&g).unwrap()
}

fn cpu_frame(p: &PackedScene, w: u32, h: u32, s: &FrameSettings) -> HostFrame {
    CpuTracer::new(w, h).unwrap().render(p, s).unwrap().0
}

fn channel_means(t: &HostTensor) -> Vec<f64> {
    let c = t.channels as usize;
    (0..c)
        .map(|k| t.data.iter().skip(k).step_by(c).map(|&v| v as f64).sum::<f64>() / (t.data.len() / c) as f64)
        .collect()
}

/// The scenes every agreement test covers.
fn builtin_scenes() -> Vec<Scene> {
    ["builtin:cornell", "builtin:room", "builtin:furnace"]
        .iter()
        .map(|n| load_scene(n).unwrap())
        .collect()
}

/// G-buffers agree to float tolerance; with the same seed nearly every traced pixel follows
/// the same path on both backends.
#[test]
fn gbuffers_and_same_seed_paths_match_the_gpu() {
    for scene in builtin_scenes() {
        let p = packed(&scene);
        let gs = GpuScene::upload(&gpu(), p.clone()).unwrap();
        for mode in [Mode::Quarter, Mode::Full] {
            let (w, h) = (24, 20);
            let s = settings(&scene, mode, 1, 7);
            let g = gpu_frame(&gs, w, h, &s);
            let c = cpu_frame(&p, w, h, &s);
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
                let bad = gt
                    .data
                    .iter()
                    .zip(&ct.data)
                    .filter(|(a, b)| (*a - *b).abs() > 1e-4 + 1e-4 * b.abs())
                    .count();
                assert_eq!(bad, 0, "{} {mode:?}: {bad} values of '{name}' differ", scene.name);
            }
            // Colour and NEE shadow: the same random numbers give the same paths, up to
            // paths that diverge through float rounding (a different branch taken).
            for (name, gt, ct) in [("color", &g.color, &c.color), ("shadow", &g.shadow, &c.shadow)] {
                let n = (w * h) as usize;
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
}

/// High-spp references differ only by noise: per-channel means within 1.5 %, and the PSNR
/// between a CPU and a GPU render (different seeds) no lower, beyond 0.5 dB, than between
/// two GPU renders with different seeds.
#[test]
fn references_agree_up_to_noise() {
    for scene in builtin_scenes() {
        let p = packed(&scene);
        let gs = GpuScene::upload(&gpu(), p.clone()).unwrap();
        let (w, h, spp) = (24, 24, 128);
        let g1 = gpu_frame(&gs, w, h, &settings(&scene, Mode::Reference, spp, 1));
        let g2 = gpu_frame(&gs, w, h, &settings(&scene, Mode::Reference, spp, 2));
        let g3 = gpu_frame(&gs, w, h, &settings(&scene, Mode::Reference, spp, 5));
        let c3 = cpu_frame(&p, w, h, &settings(&scene, Mode::Reference, spp, 3));
        let c6 = cpu_frame(&p, w, h, &settings(&scene, Mode::Reference, spp, 6));
        // PSNR from the mean MSE over pairs (one pair's PSNR is itself noisy): the three GPU
        // pairs against the six CPU x GPU pairs, all of different seeds.
        let pooled = |pairs: &[(&HostTensor, &HostTensor)]| {
            let mse = pairs
                .iter()
                .map(|(a, b)| 10f64.powf(-subpixel::metrics::psnr(a, b) / 10.0))
                .sum::<f64>()
                / pairs.len() as f64;
            -10.0 * mse.log10()
        };
        let gg = pooled(&[
            (&g1.color, &g2.color),
            (&g1.color, &g3.color),
            (&g2.color, &g3.color),
        ]);
        let cg = pooled(&[
            (&c3.color, &g1.color),
            (&c3.color, &g2.color),
            (&c3.color, &g3.color),
            (&c6.color, &g1.color),
            (&c6.color, &g2.color),
            (&c6.color, &g3.color),
        ]);
        eprintln!("{}: PSNR GPU-GPU {gg:.2} dB, CPU-GPU {cg:.2} dB", scene.name);
        assert!(
            cg >= gg - 0.5,
            "{}: CPU-GPU PSNR {cg:.2} dB vs GPU-GPU {gg:.2} dB",
            scene.name
        );
        // Means: the two GPU renders against a long CPU render. Their difference is noise
        // whose standard error `se` is estimated from the two GPU renders' per-pixel
        // differences (pixels are independent). Within 1.5 % is asked; where the affordable
        // sample count leaves more noise than that (heavy-tailed caustics), the difference
        // must stay within 4 standard errors.
        let big = cpu_frame(&p, w, h, &settings(&scene, Mode::Reference, 8 * spp, 4));
        let (m1, m2, mc) = (
            channel_means(&g1.color),
            channel_means(&g2.color),
            channel_means(&big.color),
        );
        let n = (w * h) as usize;
        for k in 0..3 {
            let mg = 0.5 * (m1[k] + m2[k]);
            // Var of one render's mean: mean(d^2) / (2 n); the pooled GPU mean halves it;
            // the CPU mean (8x the samples) adds 1/8 of one render's.
            let d2 = (0..n)
                .map(|i| ((g1.color.data[3 * i + k] - g2.color.data[3 * i + k]) as f64).powi(2))
                .sum::<f64>()
                / n as f64;
            let var_one = d2 / (2.0 * n as f64);
            let se = (var_one / 2.0 + var_one / 8.0).sqrt();
            let diff = (mg - mc[k]).abs();
            eprintln!(
                "{} channel {k}: GPU {mg:.5} (seeds {:.5} {:.5}), CPU {:.5}: difference {:.2} %, standard error {:.2} %",
                scene.name,
                m1[k],
                m2[k],
                mc[k],
                100.0 * diff / mc[k],
                100.0 * se / mc[k]
            );
            assert!(
                diff <= (0.015 * mc[k].abs()).max(4.0 * se),
                "{} channel {k}: GPU mean {mg} vs CPU {} (standard error {se})",
                scene.name,
                mc[k]
            );
        }
    }
}

/// The CPU render is deterministic for a seed, whatever the number of threads.
#[test]
fn deterministic_for_a_seed_at_any_thread_count() {
    let scene = load_scene("builtin:room").unwrap();
    let p = packed(&scene);
    let s = settings(&scene, Mode::Reference, 4, 9);
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let three = rayon::ThreadPoolBuilder::new().num_threads(3).build().unwrap();
    let a = one.install(|| cpu_frame(&p, 17, 13, &s));
    let b = three.install(|| cpu_frame(&p, 17, 13, &s));
    assert_eq!(a, b);
    let mut s2 = s;
    s2.seed = 10;
    assert_ne!(cpu_frame(&p, 17, 13, &s2).color, a.color);
}

fn sphere_mean(f: &HostFrame, c: usize) -> (f64, usize) {
    let px: Vec<usize> = (0..f.depth.data.len())
        .filter(|&i| f.depth.data[i] < 1.0)
        .collect();
    let m = px.iter().map(|&i| f.color.data[3 * i + c] as f64).sum::<f64>() / px.len().max(1) as f64;
    (m, px.len())
}

/// White furnaces on the CPU: a white Lambertian, a smooth mirror, solid and thin glass in a
/// uniform white environment converge to 1 (energy neither gained nor lost).
#[test]
fn cpu_white_furnaces_converge_to_one() {
    let cases = [
        ("lambert", builtin::furnace().materials[0].clone()),
        (
            "mirror",
            Material {
                base_color: [1.0; 4],
                metallic: 1.0,
                roughness: 0.0,
                ..Default::default()
            },
        ),
        (
            "solid glass",
            Material {
                metallic: 0.0,
                roughness: 0.0,
                transmission: 1.0,
                thin: false,
                ..Default::default()
            },
        ),
        (
            "thin glass",
            Material {
                metallic: 0.0,
                roughness: 0.0,
                transmission: 1.0,
                thin: true,
                double_sided: true,
                ..Default::default()
            },
        ),
    ];
    for (name, m) in cases {
        let mut scene = builtin::furnace();
        scene.materials[0] = m;
        let p = packed(&scene);
        let mut s = settings(&scene, Mode::Reference, 256, 1);
        s.max_depth = 32;
        let f = cpu_frame(&p, 24, 24, &s);
        for c in 0..3 {
            let (m, n) = sphere_mean(&f, c);
            assert!(n > 100, "{name}: sphere covers {n} pixels");
            assert!((m - 1.0).abs() < 0.01, "furnace {name} channel {c}: {m}");
        }
    }
}

/// Rough materials never gain energy on the CPU either (the cases and bounds of the GPU's
/// `furnace_rough_materials_do_not_gain_energy`: single-scattering GGX loses some).
#[test]
fn cpu_rough_furnace_does_not_gain_energy() {
    let cases = [
        (
            "rough metal",
            Material {
                base_color: [1.0; 4],
                metallic: 1.0,
                roughness: 0.6,
                ..Default::default()
            },
        ),
        (
            "rough glass",
            Material {
                metallic: 0.0,
                roughness: 0.5,
                transmission: 1.0,
                thin: false,
                ..Default::default()
            },
        ),
        (
            "rough plastic",
            Material {
                metallic: 0.0,
                roughness: 0.4,
                ..Material::diffuse("p", [1.0; 3])
            },
        ),
    ];
    for (name, m) in cases {
        let mut scene = builtin::furnace();
        scene.materials[0] = m;
        let p = packed(&scene);
        let mut s = settings(&scene, Mode::Reference, 256, 8);
        s.max_depth = 32;
        let f = cpu_frame(&p, 24, 24, &s);
        assert!(f.color.data.iter().all(|v| v.is_finite()), "{name}: non-finite");
        let (m, _) = sphere_mean(&f, 0);
        eprintln!("cpu furnace {name}: {m}");
        assert!(m <= 1.015 && m > 0.75, "furnace {name}: {m}");
    }
}

/// The reference halves are independent estimates whose mean is the reference of `spp`
/// samples, on both backends; their PSNR grows with the sample count.
#[test]
fn reference_halves_measure_noise() {
    // Diffuse walls only: no caustics, so the halves' noise falls like 1/N.
    let scene = load_scene("builtin:cornell-empty").unwrap();
    let p = packed(&scene);
    let s = settings(&scene, Mode::Quarter, 1, 3);
    let t = CpuTracer::new(16, 16).unwrap();
    let r = t.render_reference(&p, &s, 64).unwrap();
    assert_ne!(r.first, r.second);
    let full = r.mean(64);
    let mut rs = s;
    rs.mode = Mode::Reference;
    rs.spp = 64;
    rs.seed ^= subpixel::render::REFERENCE_SEED_XOR;
    let direct = t.render(&p, &rs).unwrap().0.color;
    for (a, b) in full.data.iter().zip(&direct.data) {
        assert!((a - b).abs() <= 1e-4 * (1.0 + b.abs()), "{a} vs {b}");
    }
    let low = subpixel::metrics::psnr(&r.first, &r.second);
    let r4 = t.render_reference(&p, &s, 256).unwrap();
    let high = subpixel::metrics::psnr(&r4.first, &r4.second);
    // Four times the samples: the halves' MSE falls 4x (6 dB), less the 8-bit rounding.
    assert!(
        high > low + 4.5,
        "halves PSNR {low:.2} dB at 64 spp, {high:.2} dB at 256 spp"
    );
    // The GPU's halves: same samples, so they match the CPU's closely.
    let gs = GpuScene::upload(&gpu(), p.clone()).unwrap();
    let mut gt = Tracer::new(&gpu(), 16, 16).unwrap();
    let out = subpixel::nn::Tensor::new(&gpu(), "ref", 16, 16, 4).unwrap();
    let g = gt.render_reference_halves(&gs, &s, 64, &out).unwrap();
    let gpsnr = subpixel::metrics::psnr(&g.first, &r.first);
    assert!(gpsnr > 30.0, "GPU and CPU first halves: {gpsnr:.2} dB");
}
