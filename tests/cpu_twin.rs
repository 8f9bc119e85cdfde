//! The CPU twin of the path tracer against the WGSL tracer (any adapter; a CPU Vulkan
//! driver is enough), and its own furnace and energy tests.
//!
//! Both backends read the same packed scene and draw the same PCG random numbers, so with
//! one seed most paths are traced identically (a strong check of the integrator's logic);
//! with different seeds their images differ only by Monte Carlo noise.

mod common;

use common::twin::{
    assert_backgrounds_match, assert_references_agree, assert_same_seed_frames_match, cpu_frame,
    distinct_colours, gbuffer_ties, gpu_frame, packed, pooled_means, pooled_psnr, seam_rays, settings,
};
use common::{furnace, gpu};
use subpixel::frame::HostFrame;
use subpixel::render::builtin;
use subpixel::render::scene::{Material, Scene, Wrap};
use subpixel::render::{CpuTracer, GpuScene, Mode, Tracer, load_scene};

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
        assert_same_seed_frames_match(&scene, 24, 20);
    }
}

/// The brute-force search behind the G-buffer tie check sees a ray that grazes the edge
/// between two surfaces: on builtin:cornell at 24x20 (quarter frame), pixel (21, 0) meets
/// the ceiling within rounding of its edge with the right wall. An H100 reported the wall
/// there and the twin the ceiling; the search finds only the ceiling along the ray itself,
/// and both once rays tilted by 1e-5 radians are searched too.
#[test]
fn edge_grazing_rays_find_both_surfaces() {
    let scene = load_scene("builtin:cornell").unwrap();
    let p = packed(&scene);
    let s = settings(&scene, Mode::Quarter, 1, 7);
    let cpu = CpuTracer::new(24, 20).unwrap();
    let material = |t: &subpixel::render::PrimarySurface| scene.materials[t.material as usize].name.clone();
    let along: Vec<String> = cpu
        .primary_surfaces(&p, &s, (21, 0), 1e-5, 0.0)
        .iter()
        .map(material)
        .collect();
    let grazing: Vec<String> = cpu
        .primary_surfaces(&p, &s, (21, 0), 1e-5, 1e-5)
        .iter()
        .map(material)
        .collect();
    assert_eq!(along, ["white"], "along the ray");
    assert_eq!(grazing, ["white", "right"], "with tilted rays");
    // The wall's values are those of the pixel's own ray meeting the wall's plane at the
    // corner, where it meets the ceiling: the same depth and motion to float tolerance (an
    // H100's wall pixel was once rejected for the motion of the tilted ray, 3e-4 pixels
    // off). The twin's own G-buffer there is the ceiling's.
    let surfaces = cpu.primary_surfaces(&p, &s, (21, 0), 1e-5, 1e-5);
    let (ceiling, wall) = (&surfaces[0], &surfaces[1]);
    let frame = cpu_frame(&p, 24, 20, &s);
    assert_eq!(frame.depth.data[21], ceiling.depth);
    assert_eq!(&frame.motion.data[42..44], &ceiling.motion[..]);
    assert!(
        (wall.depth - ceiling.depth).abs() <= 1e-6,
        "depth {} vs {}",
        wall.depth,
        ceiling.depth
    );
    assert!(
        (wall.t - ceiling.t).abs() <= 1e-5 * ceiling.t,
        "t {} vs {}",
        wall.t,
        ceiling.t
    );
    for k in 0..2 {
        assert!(
            (wall.motion[k] - ceiling.motion[k]).abs() <= 1e-5,
            "motion {:?} vs {:?}",
            wall.motion,
            ceiling.motion
        );
    }
}

/// The G-buffer check counts as ties (and accepts) the two ways an H100 differed from the
/// twin on builtin:cornell at 24x20: pixel (21, 0), whose ray grazes the edge of ceiling and
/// right wall, given the wall's values; pixel (21, 19), whose ray slips through the seam
/// of floor and right wall (the twin reports a miss), given the wall's. Anything else there,
/// the floor's albedo on the wall say, is still a failure.
#[test]
fn edge_and_seam_ties_are_accepted_and_nothing_else() {
    let scene = load_scene("builtin:cornell").unwrap();
    let p = packed(&scene);
    let s = subpixel::render::FrameSettings {
        background: 2,
        ..settings(&scene, Mode::Quarter, 1, 7)
    };
    let (w, h) = (24, 20);
    let cpu = CpuTracer::new(w, h).unwrap();
    let c = cpu_frame(&p, w, h, &s);
    assert_eq!(
        c.depth.data[(19 * w + 21) as usize],
        1.0,
        "the twin's ray slips through the seam"
    );
    let set = |f: &mut HostFrame, (x, y): (u32, u32), t: &subpixel::render::PrimarySurface| {
        let i = (y * w + x) as usize;
        f.albedo.data[3 * i..3 * i + 3].copy_from_slice(&t.albedo);
        f.normal.data[3 * i..3 * i + 3].copy_from_slice(&t.normal);
        f.depth.data[i] = t.depth;
        f.metallic.data[i] = t.metallic;
        f.roughness.data[i] = t.roughness;
        f.transparent.data[3 * i..3 * i + 3].copy_from_slice(&t.transparent);
        f.motion.data[2 * i..2 * i + 2].copy_from_slice(&t.motion);
    };
    let wall = |px| {
        cpu.primary_surfaces(&p, &s, px, 1e-5, 1e-5)
            .into_iter()
            .find(|t| scene.materials[t.material as usize].name == "right")
            .unwrap()
    };
    let mut g = c.clone();
    set(&mut g, (21, 0), &wall((21, 0)));
    set(&mut g, (21, 19), &wall((21, 19)));
    assert_eq!(gbuffer_ties(&scene, &p, &s, &g, &c), 2);
    let mut wrong = wall((21, 19));
    wrong.albedo = [0.725, 0.71, 0.68];
    set(&mut g, (21, 19), &wrong);
    let r = std::panic::catch_unwind(|| gbuffer_ties(&scene, &p, &s, &g, &c));
    assert!(r.is_err(), "a wrong albedo at the seam must fail the check");
}

/// Repeat- and mirror-wrapped textures looked up at negative texture coordinates match.
/// WGSL defines `%` of negative operands, but naga's GLSL output does not (on Mesa
/// llvmpipe's GL, -4000 % 894 gave 450): the GPU's wrap once fetched the wrong texels there
/// on the GL backend (the floor of the shared dining-room scene).
#[test]
fn negative_texture_coordinates_match_the_gpu() {
    let mut scene = load_scene("builtin:room").unwrap();
    assert!(!scene.textures.is_empty());
    for uv in &mut scene.geometry.uvs {
        *uv -= glam::Vec2::new(7.3, 5.6);
    }
    for (k, t) in scene.textures.iter_mut().enumerate() {
        if k % 2 == 1 {
            t.wrap = [Wrap::Mirror; 2];
        }
        // Sizes that are not powers of two (for those, the unsigned remainder is right).
        let (w, h) = (t.width - 3, t.height - 5);
        t.texels = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| t.texels[(y * t.width + x) as usize])
            .collect();
        (t.width, t.height) = (w, h);
    }
    assert_same_seed_frames_match(&scene, 24, 20);
}

/// High-spp references differ only by noise (see [`assert_references_agree`]).
#[test]
fn references_agree_up_to_noise() {
    for scene in builtin_scenes() {
        assert_references_agree(&scene, 24, 24, 128);
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

/// The CPU reference of `builtin:furnace` with its sphere made of `m`: 24 x 24 pixels,
/// `spp` samples with seed `seed`, at most 32 bounces.
fn cpu_furnace(m: Material, spp: u32, seed: u32) -> HostFrame {
    let scene = furnace::scene(m);
    let mut s = settings(&scene, Mode::Reference, spp, seed);
    s.max_depth = 32;
    cpu_frame(&packed(&scene), 24, 24, &s)
}

/// White furnaces on the CPU: a white Lambertian, a smooth mirror, solid and thin glass in a
/// uniform white environment converge to 1 (energy neither gained nor lost).
#[test]
fn cpu_white_furnaces_converge_to_one() {
    let mut cases = vec![("lambert", builtin::furnace().materials[0].clone())];
    cases.extend(furnace::smooth());
    for (name, m) in cases {
        let f = cpu_furnace(m, 256, 1);
        for c in 0..3 {
            let (m, n) = furnace::sphere_mean(&f, c);
            assert!(n > 100, "{name}: sphere covers {n} pixels");
            assert!((m - 1.0).abs() < 0.01, "furnace {name} channel {c}: {m}");
        }
    }
}

/// Rough materials never gain energy on the CPU either (the cases and bounds of the GPU's
/// `furnace_rough_materials_do_not_gain_energy`: single-scattering GGX loses some).
#[test]
fn cpu_rough_furnace_does_not_gain_energy() {
    for (name, m) in furnace::rough() {
        let f = cpu_furnace(m, 256, 8);
        assert!(f.color.data.iter().all(|v| v.is_finite()), "{name}: non-finite");
        let (m, _) = furnace::sphere_mean(&f, 0);
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

/// The background (the directly seen environment over each pixel's footprint) against the
/// path tracer: where a pixel is wholly sky its reference radiance is the environment along
/// its escaping rays, so the two estimate the same integral (stratified lookups against
/// jittered path samples); where it is wholly geometry the background is 0; coverage is the
/// escaping fraction, in [0, 1], and 0 and 1 both occur on an open-ground scene.
#[test]
fn background_matches_the_reference_on_wholly_sky_pixels() {
    let scene = load_scene("builtin:procedural:1").unwrap();
    let p = packed(&scene);
    let (w, h) = (32, 32);
    let mut s = settings(&scene, Mode::Reference, 256, 3);
    s.background = 8;
    let tracer = CpuTracer::new(w, h).unwrap();
    let made = tracer.background(&p, &s).unwrap();
    let (bg, cov) = (made.radiance, made.coverage);
    let reference = tracer.render_reference(&p, &s, 256).unwrap().mean(256);
    let g = cpu_frame(&p, w, h, &s);
    let (mut sky, mut ground, mut rel_sum) = (0, 0, 0.0f64);
    for i in 0..(w * h) as usize {
        let c = cov.data[i];
        assert!((0.0..=1.0).contains(&c), "coverage {c} at {i}");
        let b = &bg.data[3 * i..3 * i + 3];
        if c == 1.0 {
            sky += 1;
            // the G-buffer ray through the pixel centre escapes too: sky albedo 1, depth 1
            assert_eq!(g.depth.data[i], 1.0, "pixel {i}");
            for (&bk, &r) in b.iter().zip(&reference.data[3 * i..3 * i + 3]) {
                let r = r as f64;
                rel_sum += (bk as f64 - r).abs() / r.max(1e-3);
            }
        } else if c == 0.0 {
            ground += 1;
            assert_eq!(b, [0.0; 3], "pixel {i}");
        }
    }
    assert!(sky > 50 && ground > 50, "sky {sky}, ground {ground} pixels");
    let mean_rel = rel_sum / (3 * sky) as f64;
    assert!(
        mean_rel < 0.01,
        "background vs reference on sky pixels: mean relative difference {mean_rel}"
    );
    s.background = 0;
    assert!(tracer.background(&p, &s).is_err());
}

/// The footprint albedo against an independent estimate of the same box filter: the
/// G-buffer albedo (first-hit base colour at pixel centres, sky 1) of an n-times-larger
/// frame of the same camera, averaged over each n x n block. The larger frame's pixel
/// centres are the footprint's stratified positions ((n x + i + 1/2) / (n W) =
/// (x + (i + 1/2) / n) / W), and with n a power of two the two expressions round alike
/// (scaling by 2 is exact), so the same rays are traced: every pixel agrees to the float
/// rounding of the sums (1e-5). (With n = 3 on the Cornell box, 5 of 320 pixels differed by
/// a ray: a ray that lies exactly on the edge between two walls takes one wall or the other
/// depending on the last bit.) On an open-ground scene (sky and textured ground) and the
/// Cornell box (coloured walls meeting along edges), with mixed pixels present.
#[test]
fn footprint_albedo_is_the_box_filtered_gbuffer() {
    for (name, n) in [("builtin:procedural:1", 4u32), ("builtin:cornell", 2)] {
        let scene = load_scene(name).unwrap();
        let p = packed(&scene);
        let (w, h) = (20u32, 16u32);
        let mut s = settings(&scene, Mode::Quarter, 1, 3);
        s.background = n;
        let albedo = CpuTracer::new(w, h)
            .unwrap()
            .background(&p, &s)
            .unwrap()
            .albedo
            .unwrap();
        let fine = cpu_frame(&p, n * w, n * h, &s).albedo;
        let (mut close, mut mixed, mut diff) = (0, 0, 0f64);
        for y in 0..h {
            for x in 0..w {
                let mut want = [0f64; 3];
                let mut uniform = true;
                for (k, v) in want.iter_mut().enumerate() {
                    let first = fine.at(n * x, n * y, k as u32);
                    for j in 0..n {
                        for i in 0..n {
                            let a = fine.at(n * x + i, n * y + j, k as u32);
                            *v += a as f64;
                            uniform &= a == first;
                        }
                    }
                    *v /= (n * n) as f64;
                }
                mixed += !uniform as usize;
                let got: Vec<f64> = (0..3).map(|k| albedo.at(x, y, k) as f64).collect();
                let d = got
                    .iter()
                    .zip(&want)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0f64, f64::max);
                close += (d <= 1e-5) as usize;
                diff += got.iter().zip(&want).map(|(a, b)| (a - b).abs()).sum::<f64>() / 3.0;
            }
        }
        let all = (w * h) as usize;
        let diff = diff / all as f64;
        assert!(
            close == all,
            "{name}: footprint albedo within 1e-5 of the box-filtered fine G-buffer at {close} of {all} pixels, mean difference {diff:.2e}"
        );
        assert!(
            mixed > 10 && mixed < all - 10,
            "{name}: {mixed} of {all} pixels mix surfaces"
        );
    }
}

/// The WGSL tracer's background pass (`trace/background`) against the CPU twin's
/// ([`assert_backgrounds_match`]) on an open-ground scene with 3 x 3 rays per pixel, quarter
/// and reference frames, with wholly sky and wholly ground pixels both present; a frame
/// without a background has none on either backend.
#[test]
fn background_matches_the_gpu() {
    let scene = load_scene("builtin:procedural:1").unwrap();
    let p = packed(&scene);
    let gs = GpuScene::upload(&gpu(), p.clone()).unwrap();
    let (w, h, n) = (24u32, 20u32, 3u32);
    for mode in [Mode::Quarter, Mode::Reference] {
        let mut s = settings(&scene, mode, 2, 7);
        s.background = n;
        let g = gpu_frame(&gs, w, h, &s).background.expect("GPU background");
        let frame = cpu_frame(&p, w, h, &s);
        let c = frame.background.clone().expect("CPU background");
        assert_backgrounds_match(&format!("{mode:?}"), &g, &c, n, &frame.albedo);
        let sky = c.coverage.data.iter().filter(|&&v| v == 1.0).count();
        assert!(
            sky > 20 && sky < (w * h) as usize - 20,
            "{mode:?}: {sky} wholly sky pixels"
        );
        // One tracer: a frame without a background drops the last one's.
        let mut t = Tracer::new(&gpu(), w, h).unwrap();
        t.render(&gs, &s).unwrap();
        assert!(t.buffers.inputs().background.is_some());
        s.background = 0;
        t.render(&gs, &s).unwrap();
        assert!(t.buffers.inputs().background.is_none());
        assert!(t.buffers.download(&gpu()).unwrap().background.is_none());
        assert!(cpu_frame(&p, w, h, &s).background.is_none());
    }
}

/// Environment portals on both backends: on a room lit through an open window, same-seed
/// frames and high-spp references agree as for the builtin scenes.
#[test]
fn portal_sampling_matches_the_gpu() {
    let scene = common::window_room::scene(true, false);
    assert_same_seed_frames_match(&scene, 24, 20);
    assert_references_agree(&scene, 24, 24, 128);
}

/// Light passing straight through smooth thin glass, on both backends: on the window room
/// with a pane (part diffuse, tinted) and its portal, same-seed frames and high-spp
/// references agree as for the builtin scenes.
#[test]
fn straight_through_glass_matches_the_gpu() {
    let scene = common::window_room::scene(true, true);
    assert_same_seed_frames_match(&scene, 24, 20);
    assert_references_agree(&scene, 24, 24, 128);
}

/// Portals change the noise, never the image: the window room with and without its portal
/// ([`assert_same_image_less_noise`], 1,024 spp), the halves at least 6 dB closer with it.
#[test]
fn portals_keep_the_image_and_cut_the_noise() {
    let with = common::window_room::scene(true, false);
    let without = common::window_room::scene(false, false);
    assert_same_image_less_noise(&with, &without, 1024, 6.0);
}

/// Smooth thin glass passes light straight through: a pane at roughness 0 (straight
/// through; NEE sees the sky through it) against the same pane at roughness 0.045, just
/// above the floor, where it is a GGX lobe 1 % wider than the floor's, sampled as any rough
/// glass; in the paned window room. The same image ([`assert_same_image_less_noise`],
/// 2,048 spp), with its portal the halves at least 6 dB closer; without it (where the MIS
/// weights of both routes through the pane matter most) at least 1 dB.
#[test]
fn straight_through_glass_keeps_the_image_and_cuts_the_noise() {
    let room = |portals: bool, roughness: f32| {
        let mut scene = common::window_room::scene(portals, true);
        scene.materials[1].roughness = roughness;
        scene
    };
    assert_same_image_less_noise(&room(true, 0.0), &room(true, 0.045), 2048, 6.0);
    assert_same_image_less_noise(&room(false, 0.0), &room(false, 0.045), 2048, 1.0);
}

/// Scenes `better` and `plain` render the same image up to noise (CPU twin, `spp`-sample
/// references of three seeds each at 24 x 24: the PSNR between a render of `better` and one
/// of `plain` no lower, beyond 0.5 dB, than between two of `plain`; channel means within
/// 1.5 %), and `better`'s reference halves are at least `gain_db` closer than `plain`'s.
fn assert_same_image_less_noise(better: &Scene, plain: &Scene, spp: u32, gain_db: f64) {
    let (w, h) = (24u32, 24u32);
    let t = CpuTracer::new(w, h).unwrap();
    let render = |scene: &Scene, seed: u32| {
        let s = settings(scene, Mode::Reference, spp, seed);
        t.render_reference(&packed(scene), &s, spp).unwrap()
    };
    let seeds = [1u32, 2, 5];
    let with: Vec<_> = seeds.iter().map(|&k| render(better, k)).collect();
    let without: Vec<_> = seeds.iter().map(|&k| render(plain, k)).collect();
    let (mut same, mut mixed) = (Vec::new(), Vec::new());
    for i in 0..seeds.len() {
        for j in 0..seeds.len() {
            let (a, b) = (without[i].mean(spp), without[j].mean(spp));
            if i < j {
                same.push(subpixel::metrics::psnr(&a, &b));
            }
            if i != j {
                mixed.push(subpixel::metrics::psnr(&with[i].mean(spp), &b));
            }
        }
    }
    let (same, mixed) = (pooled_psnr(same), pooled_psnr(mixed));
    eprintln!("PSNR plain-plain {same:.2} dB, better-plain {mixed:.2} dB");
    assert!(
        mixed >= same - 0.5,
        "the images differ: {mixed:.2} vs {same:.2} dB"
    );
    let mean = |v: &[subpixel::render::ReferenceHalves]| {
        pooled_means(&v.iter().map(|r| r.mean(spp)).collect::<Vec<_>>())
    };
    let (mw, mo) = (mean(&with), mean(&without));
    for c in 0..3 {
        let rel = (mw[c] - mo[c]).abs() / mo[c];
        assert!(rel < 0.015, "channel {c}: mean {} against {}", mw[c], mo[c]);
    }
    let halves = |v: &[subpixel::render::ReferenceHalves]| {
        pooled_psnr(v.iter().map(|r| subpixel::metrics::psnr(&r.first, &r.second)))
    };
    let (hw, ho) = (halves(&with), halves(&without));
    eprintln!("PSNR between halves: better {hw:.2} dB, plain {ho:.2} dB");
    assert!(hw >= ho + gain_db, "halves: {hw:.2} dB against {ho:.2} dB");
}

/// A reference extended from `spp` to `2 spp` samples holds the halves of a `2 spp` render
/// (CPU twin and WGSL tracer), and `reference_to_noise` doubles until the halves' PSNR
/// reaches its target, never past the cap, and not once more than needed.
#[test]
fn references_extend_to_a_noise_target() {
    use subpixel::render::backend::{Backend, FrameRenderer};
    let scene = common::window_room::scene(false, false);
    let (w, h) = (16u32, 12u32);
    let s = settings(&scene, Mode::Quarter, 1, 3);
    let close = |what: &str, a: &subpixel::nn::HostTensor, b: &subpixel::nn::HostTensor, tol: f32| {
        for (x, y) in a.data.iter().zip(&b.data) {
            assert!((x - y).abs() <= tol * (1.0 + y.abs()), "{what}: {x} vs {y}");
        }
    };
    for backend in [Backend::Cpu, Backend::Gpu] {
        let g = gpu();
        let mut r = FrameRenderer::new(&scene, backend, Some(&g), w, h).unwrap();
        let direct = r.reference(&s, 32).unwrap();
        let base = r.reference(&s, 16).unwrap();
        let extended = match &mut r {
            FrameRenderer::Cpu { scene, tracer } => tracer.extend_reference(scene, &s, &base, 16).unwrap(),
            FrameRenderer::Gpu(gr) => {
                let out = gr.reference.as_ref().unwrap();
                gr.tracer.extend_reference(&gr.scene, &s, 16, out).unwrap()
            }
        };
        let name = backend.name();
        close(
            &format!("{name} first half"),
            &extended.first,
            &direct.first,
            1e-4,
        );
        close(
            &format!("{name} second half"),
            &extended.second,
            &direct.second,
            1e-4,
        );
        // Under a target: the count where the halves first reach it, or the cap.
        let psnr_at = |r: &mut FrameRenderer, n: u32| {
            let h = r.reference(&s, n).unwrap();
            subpixel::metrics::psnr(&h.first, &h.second)
        };
        let (p8, p32) = (psnr_at(&mut r, 8), psnr_at(&mut r, 32));
        let target = 0.5 * (p8 + p32);
        let (got, n) = r.reference_to_noise(&s, 8, target, 256).unwrap();
        let p = subpixel::metrics::psnr(&got.first, &got.second);
        eprintln!("{name}: 8 spp {p8:.2} dB, 32 spp {p32:.2} dB; target {target:.2}: {n} spp, {p:.2} dB");
        assert!(
            p >= target && n > 8 && n <= 32,
            "{name}: {n} spp, {p:.2} dB for {target:.2}"
        );
        assert!(
            psnr_at(&mut r, n / 2) < target,
            "{name}: {n} spp where {} reached the target",
            n / 2
        );
        close(
            &format!("{name} target reference"),
            &got.mean(n),
            &r.reference(&s, n).unwrap().mean(n),
            1e-4,
        );
        let (_, capped) = r.reference_to_noise(&s, 8, 200.0, 64).unwrap();
        assert_eq!(capped, 64, "{name}: an unreachable target stops at the cap");
        let (_, easy) = r.reference_to_noise(&s, 8, 1.0, 64).unwrap();
        assert_eq!(easy, 8, "{name}: a target already met renders the base count");
    }
}

/// A lone emissive square (double-sided, diffuse) facing the camera, nothing else and no
/// environment: every path's radiance is the square's emission where its camera ray meets
/// it and 0 elsewhere (nothing else emits or reflects light onto it).
fn lone_emitter(emission: [f32; 3]) -> Scene {
    use glam::Vec3;
    use subpixel::render::Camera;
    use subpixel::render::scene::Geometry;
    let v = Vec3::new;
    let mut g = Geometry::default();
    g.push_quad(
        [
            v(-0.5, -0.5, -2.0),
            v(0.5, -0.5, -2.0),
            v(0.5, 0.5, -2.0),
            v(-0.5, 0.5, -2.0),
        ],
        0,
    );
    Scene {
        name: "lone emitter".into(),
        geometry: g,
        materials: vec![Material {
            double_sided: true,
            emissive: emission,
            ..Material::diffuse("lamp", [0.8, 0.8, 0.8])
        }],
        textures: vec![],
        environment: None,
        camera: Camera {
            position: Vec3::ZERO,
            target: v(0.1, 0.05, -1.0),
            up: Vec3::Y,
            yfov: 1.0,
        },
        film: (24, 24),
        camera_path: None,
        approximations: vec![],
    }
}

/// The directly seen emission ([`subpixel::frame::DirectEmission`]) on a scene where it is
/// all the light there is ([`lone_emitter`]): each traced pixel's sample emission is its
/// colour (the replayed camera ray meets what the path met), so the colour a model of
/// emission "background" is fed has none left; untraced pixels hold 0; the footprint
/// emission is the emission times the fraction of the 8 x 8 rays that meet the square:
/// exactly the emission inside it, 0 outside, strictly between on its rim, and the share of
/// the footprint rays that meet it (the same rays the footprint albedo averages: base
/// colour 0.8 there, sky 1 elsewhere) says by how much; with 2 x 2 background rays the
/// footprint emission is the same (its outline traced again with 8 x 8 rays).
#[test]
fn direct_emission_is_all_the_light_of_a_lone_emitter() {
    let le = [3.0, 2.0, 1.0];
    let scene = lone_emitter(le);
    let p = packed(&scene);
    let (w, h) = (24u32, 24u32);
    let mut s = settings(&scene, Mode::Quarter, 1, 11);
    s.background = 8;
    let f = cpu_frame(&p, w, h, &s);
    let b = f.background.as_ref().expect("background");
    let e = b.emission.as_ref().expect("directly seen emission");
    let (mut lit, mut traced) = (0, 0);
    for i in 0..(w * h) as usize {
        let sample = &e.samples.data[3 * i..3 * i + 3];
        let color = &f.color.data[3 * i..3 * i + 3];
        if f.mask.data[i] == 1.0 {
            traced += 1;
            for (c, s) in color.iter().zip(sample) {
                assert!(
                    (c - s).abs() <= 1e-6 * c.abs().max(1.0),
                    "pixel {i}: colour {color:?}, sample emission {sample:?}"
                );
            }
            lit += (sample[0] > 0.0) as usize;
        } else {
            assert_eq!(sample, [0.0; 3], "untraced pixel {i}");
        }
        // the share of the footprint on the square, from the footprint albedo (0.8 on it, 1 off)
        let albedo = b.albedo.as_ref().unwrap().data[3 * i];
        let share = (1.0 - albedo) / 0.2;
        for (k, &l) in le.iter().enumerate() {
            let fp = e.footprint.data[3 * i + k];
            assert!(
                (fp - share * l).abs() < 1e-4,
                "pixel {i}: footprint emission {fp}, share {share} of {l}"
            );
        }
    }
    assert!(
        traced == (w * h / 4) as usize && lit > 20 && lit < traced - 20,
        "{lit} of {traced} traced pixels on the square"
    );
    let inside = e.footprint.data.chunks(3).filter(|c| c[0] == le[0]).count();
    let rim = e
        .footprint
        .data
        .chunks(3)
        .filter(|c| c[0] > 0.0 && c[0] < le[0])
        .count();
    assert!(
        inside > 50 && rim > 10,
        "{inside} pixels inside the square, {rim} on its rim"
    );
    // With 2 x 2 background rays the outline is traced again with 8 x 8: the footprint
    // emission is then that of an 8 x 8 background at every pixel (inside and outside the
    // square 2 x 2 rays are exact; on its outline the 8 x 8 rays are the same rays).
    let mut s2 = s;
    s2.background = 2;
    let coarse = cpu_frame(&p, w, h, &s2).background.unwrap().emission.unwrap();
    for (i, (a, b)) in coarse.footprint.data.iter().zip(&e.footprint.data).enumerate() {
        assert!(
            (a - b).abs() <= 1e-5 * le[0],
            "pixel {}: 2 x 2 rays {a}, 8 x 8 rays {b}",
            i / 3
        );
    }
    let folded = f
        .fold_directly_seen(
            subpixel::frame::EmissionSource::Background,
            subpixel::frame::EscapedSource::Network,
        )
        .unwrap();
    assert!(
        folded.color.data.iter().all(|&c| c.abs() <= 1e-6),
        "colour left after folding"
    );
    let packed = folded.pack_emission().expect("the emission the output pass adds");
    for (px, fp) in packed.iter().zip(e.footprint.data.chunks_exact(3)) {
        assert_eq!(&px[..3], fp);
    }
    assert_eq!(folded.background, f.background, "the background is left as it is");
}

/// On the Cornell box (its ceiling light in view, reflected light everywhere) the two
/// estimates of the directly seen emission agree: the mean of 256 jittered samples' first-hit
/// emission per pixel (a reference frame's `samples`) against the 8 x 8 stratified footprint:
/// the same pixel-box integral. Both are exactly the light's emission inside it and 0 off it;
/// on its rim they differ only by noise. The sample emission is part of the colour (never
/// above it).
#[test]
fn direct_emission_samples_and_footprint_agree_on_the_cornell_box() {
    let scene = load_scene("builtin:cornell").unwrap();
    let le = scene
        .materials
        .iter()
        .map(|m| m.emissive)
        .find(|e| e[0] > 0.0)
        .expect("an emitter");
    let p = packed(&scene);
    let (w, h) = (64u32, 64u32);
    let mut s = settings(&scene, Mode::Reference, 256, 4);
    s.background = 8;
    let f = cpu_frame(&p, w, h, &s);
    let e = f.background.unwrap().emission.unwrap();
    let (mut inside, mut rim, mut diff) = (0, 0, 0f64);
    for i in 0..(w * h) as usize {
        let (fp, sm) = (e.footprint.data[3 * i], e.samples.data[3 * i]);
        for k in 0..3 {
            assert!(
                e.samples.data[3 * i + k] <= f.color.data[3 * i + k] * (1.0 + 1e-5) + 1e-6,
                "pixel {i}"
            );
        }
        if fp == le[0] {
            inside += 1;
            assert_eq!(sm, le[0], "pixel {i} inside the light");
        } else if fp == 0.0 {
            // a sample may graze the light from a pixel whose 64 footprint rays all miss it
            assert!(sm <= 0.05 * le[0], "pixel {i}: samples {sm}, footprint 0");
        } else {
            rim += 1;
            diff += ((sm - fp) / le[0]).abs() as f64;
        }
    }
    assert!(
        inside >= 4 && rim >= 4,
        "{inside} pixels inside the light, {rim} on its rim"
    );
    let mean = diff / rim as f64;
    assert!(mean < 0.05, "rim pixels: mean difference {mean} of the emission");
}

/// The directly seen emission on both backends ([`assert_same_seed_frames_match`]: the
/// footprint's over the background rays, the samples' along the same paths): on the lone
/// emitter, where a quarter of the pixels see it (the builtin scenes' test covers the
/// Cornell box's light).
#[test]
fn direct_emission_matches_the_gpu() {
    assert_same_seed_frames_match(&lone_emitter([3.0, 2.0, 1.0]), 24, 24);
}

/// The traced samples' escapes ([`subpixel::frame::DirectEmission::escaped`]) on the white
/// furnace (a sphere in a uniform environment of radiance 1): on both backends a traced
/// pixel's value is 0 or 1 (one sample), 1 wherever the whole footprint sees the sky and 0
/// wherever none of it does; a sample that escaped made no surface vertex, so its colour is
/// the environment's 1 exactly, its shadow and first-hit emission 0; on the sphere's
/// silhouette some traced samples escape and some do not; untraced pixels hold 0; the two
/// backends agree on every traced pixel but grazing ties (at most 2 %).
#[test]
fn escaped_samples_are_the_camera_rays_that_meet_nothing() {
    let scene = builtin::furnace();
    let p = packed(&scene);
    let gs = GpuScene::upload(&gpu(), p.clone()).unwrap();
    let (w, h) = (32u32, 32u32);
    let mut s = settings(&scene, Mode::Quarter, 1, 3);
    s.background = 4;
    let mut escapes = Vec::new();
    for (what, f) in [
        ("gpu", gpu_frame(&gs, w, h, &s)),
        ("cpu", cpu_frame(&p, w, h, &s)),
    ] {
        let b = f.background.as_ref().expect("background");
        let e = b.emission.as_ref().expect("directly seen emission");
        let esc = e.escaped.as_ref().expect("the samples' escapes");
        let (mut rim_sky, mut rim_hit) = (0, 0);
        for i in 0..(w * h) as usize {
            let (a, cov) = (esc.data[i], b.coverage.data[i]);
            if f.mask.data[i] < 0.5 {
                assert_eq!(a, 0.0, "{what}: untraced pixel {i}");
                continue;
            }
            assert!(a == 0.0 || a == 1.0, "{what} pixel {i}: escaped {a}");
            if cov == 1.0 {
                assert_eq!(a, 1.0, "{what} pixel {i}: wholly sky footprint");
            } else if cov == 0.0 {
                assert_eq!(a, 0.0, "{what} pixel {i}: footprint wholly on the sphere");
            } else if a == 1.0 {
                rim_sky += 1;
            } else {
                rim_hit += 1;
            }
            if a == 1.0 {
                let rgb = |t: &subpixel::nn::HostTensor| t.data[3 * i..3 * i + 3].to_vec();
                for (c, want) in [
                    (rgb(&f.color), 1.0),
                    (rgb(&f.shadow), 0.0),
                    (rgb(&e.samples), 0.0),
                ] {
                    assert!(
                        c.iter().all(|v| (v - want).abs() <= 1e-6),
                        "{what} pixel {i}: escaped sample with {c:?}"
                    );
                }
            }
        }
        assert!(
            rim_sky > 0 && rim_hit > 0,
            "{what}: silhouette samples {rim_sky} sky, {rim_hit} sphere"
        );
        escapes.push(esc.data.clone());
    }
    let differ = escapes[0].iter().zip(&escapes[1]).filter(|(a, b)| a != b).count();
    assert!(
        differ * 50 <= (w * h / 4) as usize,
        "{differ} traced pixels escape on one backend only"
    );
}

/// The footprint albedo's seam rays ([`assert_backgrounds_match`]) on what an H200 gave
/// (`tools/gpu_runs/2026-12-04-h200-b/test_cpu_twin.log`): builtin:cornell's quarter frame,
/// 2 x 2 rays, pixels where one ray hit another wall than on the CPU twin; each is explained
/// by the scene's base colours, a ray grazing a silhouette by a base colour and the sky's,
/// and differences no pair of them makes are not.
#[test]
fn seam_rays_explain_a_wall_seam_and_nothing_else() {
    let cornell = builtin::CornellOptions::default();
    let palette = subpixel::nn::HostTensor::from_fn(3, 1, 3, |x, _, c| {
        [cornell.white, cornell.left, cornell.right][x as usize][c as usize]
    });
    let colours = distinct_colours(&palette);
    assert_eq!(colours.len(), 3);
    let seen: [([f32; 3], [f32; 3]); 5] = [
        ([0.70124996, 0.54875, 0.5225], [0.6775, 0.3875, 0.365]),
        ([0.28625, 0.515, 0.23825002], [0.4325, 0.58, 0.38549998]),
        ([0.6775, 0.3875, 0.365], [0.65375, 0.22625, 0.20750001]),
        ([0.4325, 0.58, 0.38549998], [0.5787501, 0.645, 0.53275]),
        ([0.6775, 0.3875, 0.365], [0.70124996, 0.54875, 0.52250004]),
    ];
    for (g, c) in seen {
        assert!(seam_rays(&g, &c, 2, &colours), "{g:?} vs {c:?}");
    }
    // One ray of four grazing the box's silhouette: it meets the sky (albedo 1) on one
    // backend and the white wall on the other.
    let mut sky = colours.clone();
    sky.push([1.0; 3]);
    let wall = cornell.white;
    let grazing: Vec<f32> = wall.iter().map(|w| w + (1.0 - w) / 4.0).collect();
    assert!(seam_rays(&grazing, &wall, 2, &sky));
    assert!(!seam_rays(&grazing, &wall, 2, &colours));
    // Half a ray's worth, a difference of one channel alone, and the right difference
    // between colours the frame does not hold are not seam rays.
    let white = cornell.white;
    let half: Vec<f32> = (0..3)
        .map(|k| white[k] - (white[k] - cornell.left[k]) / 8.0)
        .collect();
    assert!(!seam_rays(&white, &half, 2, &colours));
    assert!(!seam_rays(&[0.5, 0.5, 0.5], &[0.6, 0.5, 0.5], 2, &colours));
    let two = distinct_colours(&subpixel::nn::HostTensor::from_fn(2, 1, 3, |x, _, c| {
        [cornell.white, cornell.left][x as usize][c as usize]
    }));
    assert!(!seam_rays(&seen[1].0, &seen[1].1, 2, &two));
}
