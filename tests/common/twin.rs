//! The CPU twin against the WGSL tracer: shared checks of `tests/cpu_twin.rs` (built-in
//! scenes) and `tests/scenes.rs` (the shared scenes).

use std::sync::Arc;

use subpixel::frame::{Background, HostFrame};
use subpixel::nn::HostTensor;
use subpixel::render::scene::Scene;
use subpixel::render::{CpuTracer, FrameSettings, GpuScene, Mode, PackedScene, PrimarySurface, Tracer};

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

/// G-buffer values of pixel `i` of `f` (every buffer but colour and shadow), as
/// `(buffer, value)`, in the order of [`surface_values`].
fn pixel_values(f: &HostFrame, i: usize) -> Vec<(&'static str, f32)> {
    let mut v = Vec::new();
    for (name, t) in [
        ("albedo", &f.albedo),
        ("normal", &f.normal),
        ("depth", &f.depth),
        ("metallic", &f.metallic),
        ("roughness", &f.roughness),
        ("transparent", &f.transparent),
        ("motion", &f.motion),
    ] {
        let k = t.channels as usize;
        v.extend(t.data[k * i..k * i + k].iter().map(|&x| (name, x)));
    }
    v
}

/// The G-buffer values a pixel holds when its primary ray hits `s`.
fn surface_values(s: &PrimarySurface) -> Vec<(&'static str, f32)> {
    let mut v = Vec::new();
    for (name, x) in [
        ("albedo", &s.albedo[..]),
        ("normal", &s.normal[..]),
        ("depth", &[s.depth][..]),
        ("metallic", &[s.metallic][..]),
        ("roughness", &[s.roughness][..]),
        ("transparent", &s.transparent[..]),
        ("motion", &s.motion[..]),
    ] {
        v.extend(x.iter().map(|&x| (name, x)));
    }
    v
}

/// Float tolerance of the G-buffer comparisons (`b` the CPU's value).
fn close(a: f32, b: f32) -> bool {
    (a - b).abs() <= 1e-4 + 1e-4 * b.abs()
}

fn all_close(a: &[(&str, f32)], b: &[(&str, f32)]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| close(x.1, y.1))
}

/// Relative distance within which two surfaces along a ray are at the same distance.
const TIE_EPS: f32 = 1e-5;
/// Angle (radians, about 1/3000 of a pixel of these tests' images) within which a ray
/// grazes a triangle's edge.
const GRAZE: f32 = 1e-5;

/// Checks that the GPU's G-buffers `g` and the CPU twin's `c` of frame `s` agree at every
/// pixel to float tolerance, except at genuine ties, and returns the number of ties.
///
/// A tie is a pixel whose primary ray meets two overlapping surfaces at the same distance
/// (z-fighting in the scene) or passes within rounding of the edge between two surfaces
/// (the corner of two walls), so that float rounding decides which one each backend's
/// traversal reports: there the backends may disagree, but only if a brute-force search of
/// every triangle along that ray and along rays tilted by [`GRAZE`]
/// ([`CpuTracer::primary_surfaces`], independent of either traversal) finds several
/// triangles at the distance of the closest hit (within [`TIE_EPS`]), and the GPU's and the
/// CPU's values are those of two different ones. The edge case was first seen on an H100
/// (builtin:cornell at 24x20, pixel (21, 0): the ceiling on the CPU, the right wall on the
/// GPU, whose compiler fuses multiply-adds); CPU drivers round as the twin does.
///
/// The ray may also pass within rounding of the edge two triangles share and slip between
/// them: the triangle test (Moeller-Trumbore, as both backends have it) is not watertight.
/// Then the brute-force search along the ray itself meets no triangle while the tilted rays
/// meet both, and a backend may report a miss (the sky's G-buffer values: albedo 1, depth 1,
/// normal, metallic, roughness and transparency 0; its motion is not compared) as one of
/// the candidates. Seen on an H100: builtin:cornell at 24x20, quarter frame, pixel (21, 19),
/// the corner of floor and right wall: the right wall on the GPU, a miss on the twin (and on
/// CPU drivers).
///
/// In the shared scenes: dining-room (the Breakfast Room) has one genuine tie at 32x18,
/// pixel (6, 15): its floor, FloorTiles triangles 269310-269313 in the plane y = -1.419958,
/// is overlapped by two triangles of material Walls (269314, 269315: a strip at z in
/// [-4.542, -4.056] in the same plane), t = 15.200357 vs 15.2003565. The 42 "ties" once
/// counted there (the old check allowed any same-depth difference, up to 1 % of pixels)
/// were no ties at all: single floor hits whose albedo the GPU got wrong, a repeat-wrapped
/// texture looked up at negative v, which on the GL backend (Mesa llvmpipe, no Vulkan
/// driver) computed `%` of a negative operand as unsigned (fixed in
/// `wgsl/trace/lib/material.wgsl`; `negative_texture_coordinates_match_the_gpu` in
/// `tests/cpu_twin.rs` keeps it fixed).
pub fn gbuffer_ties(
    scene: &Scene,
    p: &PackedScene,
    s: &FrameSettings,
    g: &HostFrame,
    c: &HostFrame,
) -> usize {
    let (w, h) = (g.albedo.width, g.albedo.height);
    let cpu = CpuTracer::new(w, h).unwrap();
    let mut ties = Vec::new();
    for i in 0..(w * h) as usize {
        let (x, y) = (i as u32 % w, i as u32 / w);
        assert_eq!(
            g.mask.data[i], c.mask.data[i],
            "{} {:?} pixel ({x}, {y}): mask",
            scene.name, s.mode
        );
        let (gv, cv) = (pixel_values(g, i), pixel_values(c, i));
        if all_close(&gv, &cv) {
            continue;
        }
        let differ: Vec<_> = gv
            .iter()
            .zip(&cv)
            .filter(|(a, b)| !close(a.1, b.1))
            .map(|(a, b)| (a.0, a.1, b.1))
            .collect();
        // The candidates: every surface the search finds, and a miss where the ray itself
        // slips through a seam between surfaces the tilted rays meet.
        let surfaces = cpu.primary_surfaces(p, s, (x, y), TIE_EPS, GRAZE);
        let mut candidates: Vec<Candidate> = surfaces
            .iter()
            .map(|t| {
                let label = format!(
                    "triangle {} material {:?} t {} albedo {:?} normal {:?}",
                    t.triangle, scene.materials[t.material as usize].name, t.t, t.albedo, t.normal
                );
                (label, surface_values(t), true)
            })
            .collect();
        if !surfaces.is_empty() && cpu.primary_surfaces(p, s, (x, y), TIE_EPS, 0.0).is_empty() {
            candidates.push(("a miss through the seam".into(), sky_values(), false));
        }
        let find = |v: &[(&str, f32)]| {
            candidates.iter().position(|(_, t, motion)| {
                v.len() == t.len()
                    && v.iter()
                        .zip(t)
                        .all(|(a, b)| (a.0 == "motion" && !motion) || close(a.1, b.1))
            })
        };
        let (gi, ci) = (find(&gv), find(&cv));
        let described: Vec<&String> = candidates.iter().map(|c| &c.0).collect();
        let (Some(gi), Some(ci)) = (gi, ci) else {
            panic!(
                "{} {:?} pixel ({x}, {y}): G-buffers differ (name, gpu, cpu): {differ:?}; the \
                 candidates at the closest hit: {described:#?}; the GPU's values are those of \
                 candidate {gi:?}, the CPU's of {ci:?}",
                scene.name, s.mode
            )
        };
        assert!(
            gi != ci,
            "{} {:?} pixel ({x}, {y}): G-buffers differ (name, gpu, cpu): {differ:?}, yet both \
             match the same candidate: {described:#?}",
            scene.name,
            s.mode
        );
        ties.push((x, y, candidates[gi].0.clone(), candidates[ci].0.clone()));
    }
    if !ties.is_empty() {
        eprintln!(
            "{} {:?}: {} tie pixel(s); first (x, y, GPU, CPU): {:?}",
            scene.name,
            s.mode,
            ties.len(),
            &ties[..ties.len().min(2)]
        );
    }
    ties.len()
}

/// A candidate of the tie check: its description, its G-buffer values ([`pixel_values`]
/// order) and whether its motion is compared.
type Candidate = (String, Vec<(&'static str, f32)>, bool);

/// A miss's G-buffer values in [`pixel_values`] order (albedo 1, normal 0, depth 1,
/// metallic 0, roughness 0, transparent 0; its motion, which depends on the camera, is not
/// compared and given as 0).
fn sky_values() -> Vec<(&'static str, f32)> {
    surface_values(&PrimarySurface {
        triangle: u32::MAX,
        material: u32::MAX,
        t: f32::INFINITY,
        albedo: [1.0; 3],
        normal: [0.0; 3],
        depth: 1.0,
        metallic: 0.0,
        roughness: 0.0,
        transparent: [0.0; 3],
        motion: [0.0; 2],
    })
}

/// The GPU's background `g` and the CPU twin's `c` (`n x n` rays per pixel) agree: the same
/// camera rays, so coverage and background agree to float tolerance at nearly every pixel.
/// The others are those where rays graze a silhouette (one backend's traversal reports the
/// hit, the other's not; at most 2 % of pixels): coverage then differs by a whole number of
/// rays, from 1 to n, since a straight edge passes through at most n points of the pixel's
/// n x n grid of rays (seen on an H100: two rays of a 2 x 2 grid on one edge of
/// builtin:cornell), or where a lookup direction lies within float rounding of an
/// environment texel boundary: the environment is looked up at the nearest texel, and the
/// GPU's `atan2` and `acos` differ from the CPU's in the last bits (at 4096 texels across,
/// about 0.04 texel), so one of the n^2 lookups may take the neighbouring texel, which on a
/// high-contrast map (barn-lamp's beach) moves that pixel by up to a third. Hence: at least 85 % of pixels
/// exact to 1e-5, and the mean relative difference over all pixels below 1 %.
///
/// The footprint albedo (both backends write it) is the mean first-hit base colour over the
/// same rays: where the coverage agrees it agrees to the G-buffers' float tolerance except
/// where a ray grazes the edge between two surfaces (the backends may then hit different
/// ones, as the G-buffers' ties): at least 95 % of those pixels. A pixel apart (of equal
/// coverage or not) is explained by seam rays when its difference is that of j rays
/// (1 <= j <= n, a straight edge's most) whose first hit has one base colour on one backend
/// and another on the other, both among the colours of `palette` (the frame's G-buffer
/// albedo: an untextured scene's colours, to 1e-3) and the sky's 1 (a ray that meets
/// nothing): a ray on the seam between two surfaces, or grazing a silhouette. Seen on an
/// H200: 9 of 476 pixels of builtin:cornell's quarter frame, each one ray of 4 on a wall
/// seam (white against red or green), where lavapipe hits the other wall. The mean absolute
/// difference over the pixels not so explained stays below 1e-3 of the whole frame.
pub fn assert_backgrounds_match(what: &str, g: &Background, c: &Background, n: u32, palette: &HostTensor) {
    let all = c.coverage.data.len();
    let (ga, ca) = (
        g.albedo.as_ref().expect("GPU footprint albedo"),
        c.albedo.as_ref().expect("CPU footprint albedo"),
    );
    let mut colours = distinct_colours(palette);
    colours.push([1.0; 3]);
    let (mut same_coverage, mut albedo_close, mut albedo_diff, mut seams) = (0, 0, 0f64, 0);
    // The pixels of equal coverage whose footprint albedo differs (index: GPU vs CPU), for
    // the failure message.
    let mut apart = Vec::new();
    let (mut exact, mut grazing, mut rel_sum) = (0, 0, 0f64);
    for i in 0..all {
        let (gcol, ccol) = (&ga.data[3 * i..3 * i + 3], &ca.data[3 * i..3 * i + 3]);
        assert!(
            gcol.iter()
                .chain(ccol)
                .all(|v| v.is_finite() && (0.0..=1.0).contains(v)),
            "{what} pixel {i}: footprint albedo {gcol:?} vs {ccol:?}"
        );
        let diff = gcol
            .iter()
            .zip(ccol)
            .map(|(a, b)| (a - b).abs() as f64)
            .sum::<f64>()
            / 3.0;
        let (gc, cc) = (g.coverage.data[i], c.coverage.data[i]);
        let close = gcol
            .iter()
            .zip(ccol)
            .all(|(a, b)| (a - b).abs() <= 1e-4 + 1e-4 * b.abs());
        let seam = !close && seam_rays(gcol, ccol, n, &colours);
        seams += seam as usize;
        if gc == cc {
            same_coverage += 1;
            if close {
                albedo_close += 1;
            } else {
                let kind = if seam { "seam rays" } else { "unexplained" };
                apart.push(format!("{i}: {gcol:?} vs {ccol:?} (coverage {gc}, {kind})"));
            }
        }
        if !seam {
            albedo_diff += diff;
        }
        let (gr, cr) = (
            &g.radiance.data[3 * i..3 * i + 3],
            &c.radiance.data[3 * i..3 * i + 3],
        );
        if gc == cc {
            let rel = gr
                .iter()
                .zip(cr)
                .map(|(a, b)| (a - b).abs() / (1e-3 + b.abs()))
                .fold(0f32, f32::max);
            assert!(rel.is_finite(), "{what} pixel {i}: background {gr:?} vs {cr:?}");
            rel_sum += rel as f64;
            exact += (rel <= 1e-5) as usize;
        } else {
            let rays = (gc - cc).abs() * (n * n) as f32;
            assert!(
                (rays - rays.round()).abs() < 1e-3 && (1.0..=n as f32).contains(&rays.round()),
                "{what} pixel {i}: coverage {gc} vs {cc}"
            );
            grazing += 1;
        }
    }
    let mean_rel = rel_sum / all as f64;
    assert!(
        grazing * 50 <= all && exact * 100 >= all * 85 && mean_rel < 0.01,
        "{what}: {grazing} grazing pixels, {exact} of {all} exact, mean relative difference {mean_rel:.4}"
    );
    let albedo_diff = albedo_diff / all as f64;
    eprintln!(
        "{what}: footprint albedo close at {albedo_close} of {same_coverage}, {seams} pixels of seam rays, mean difference elsewhere {albedo_diff:.2e}"
    );
    assert!(
        albedo_close * 100 >= same_coverage * 95 && albedo_diff < 1e-3,
        "{what}: footprint albedo close at {albedo_close} of {same_coverage} pixels of equal coverage, {seams} pixels of seam rays, mean absolute difference elsewhere {albedo_diff:.2e}; apart (pixel index: GPU vs CPU): {}",
        apart.join("; ")
    );
    // The footprint's first-hit emission: the same rays, so the same surfaces but where a
    // ray grazes an edge (as the albedo).
    let (ge, ce) = (
        g.emission.as_ref().expect("GPU directly seen emission"),
        c.emission.as_ref().expect("CPU directly seen emission"),
    );
    let close = (0..all)
        .filter(|&i| {
            (0..3).all(|k| {
                let (a, b) = (ge.footprint.data[3 * i + k], ce.footprint.data[3 * i + k]);
                (a - b).abs() <= 1e-4 * (1.0 + b.abs())
            })
        })
        .count();
    let lit = ce.footprint.data.iter().filter(|&&v| v > 0.0).count() / 3;
    eprintln!("{what}: footprint emission close at {close} of {all} ({lit} pixels see an emitter)");
    assert!(
        close * 100 >= all * 95,
        "{what}: footprint emission close at only {close} of {all} pixels"
    );
}

/// PSNR from the mean MSE of several PSNRs (one pair's PSNR is itself noisy).
pub fn pooled_psnr(psnrs: impl IntoIterator<Item = f64>) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for p in psnrs {
        sum += 10f64.powf(-p / 10.0);
        n += 1;
    }
    -10.0 * (sum / n as f64).log10()
}

/// Per-channel means (RGB) of images, averaged over the images.
pub fn pooled_means(images: &[HostTensor]) -> Vec<f64> {
    let m: Vec<Vec<f64>> = images.iter().map(channel_means).collect();
    (0..3)
        .map(|k| m.iter().map(|v| v[k]).sum::<f64>() / m.len() as f64)
        .collect()
}

/// G-buffers agree to float tolerance; with the same seed nearly every traced pixel follows
/// the same path on both backends (quarter and full frames, `w x h`); so do the
/// backgrounds (2 x 2 rays per pixel, [`assert_backgrounds_match`]).
pub fn assert_same_seed_frames_match(scene: &Scene, w: u32, h: u32) {
    let p = packed(scene);
    let gs = GpuScene::upload(&gpu(), p.clone()).unwrap();
    for mode in [Mode::Quarter, Mode::Full] {
        let s = FrameSettings {
            background: 2,
            ..settings(scene, mode, 1, 7)
        };
        let g = gpu_frame(&gs, w, h, &s);
        let c = cpu_frame(&p, w, h, &s);
        let what = format!("{} {mode:?}", scene.name);
        assert_backgrounds_match(
            &what,
            g.background.as_ref().unwrap(),
            c.background.as_ref().unwrap(),
            2,
            &c.albedo,
        );
        let ties = gbuffer_ties(scene, &p, &s, &g, &c);
        let n = (w * h) as usize;
        // Every tie is checked to be genuine; still, overlapping surfaces are the exception
        // in a scene, so ties on a quarter of the pixels would point at a systematic bug.
        assert!(
            4 * ties <= n,
            "{} {mode:?}: {ties} of {n} pixels hit different surfaces at the same distance",
            scene.name
        );
        // Colour and NEE shadow: the same random numbers give the same paths, up to paths
        // that diverge through float rounding (a different branch taken).
        // The samples' first-hit emission (the GPU's from its paths, the twin's replayed).
        let (ge, ce) = (
            &g.background.as_ref().unwrap().emission.as_ref().unwrap().samples,
            &c.background.as_ref().unwrap().emission.as_ref().unwrap().samples,
        );
        for (name, gt, ct) in [
            ("color", &g.color, &c.color),
            ("shadow", &g.shadow, &c.shadow),
            ("sample emission", ge, ce),
        ] {
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
    let pooled = |pairs: &[(&HostTensor, &HostTensor)]| {
        pooled_psnr(pairs.iter().map(|(a, b)| subpixel::metrics::psnr(a, b)))
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

/// The distinct colours of `albedo` (3 channels) to 1e-3, at most 64 (a textured frame's
/// many colours give none: no pair of them explains a difference).
pub fn distinct_colours(albedo: &HostTensor) -> Vec<[f32; 3]> {
    let mut out: Vec<[f32; 3]> = Vec::new();
    for px in albedo.data.chunks_exact(3) {
        let c = [px[0], px[1], px[2]];
        if !out
            .iter()
            .any(|o| o.iter().zip(&c).all(|(a, b)| (a - b).abs() <= 1e-3))
        {
            out.push(c);
            if out.len() > 64 {
                return Vec::new();
            }
        }
    }
    out
}

/// Whether footprint albedos `g` and `c` (means over `n x n` rays) differ by what j rays,
/// 1 <= j <= n, hitting a surface of one colour of `colours` on one backend and another on
/// the other would make: `n^2 (g - c) = j (a - b)` to 1e-3 per channel.
pub fn seam_rays(g: &[f32], c: &[f32], n: u32, colours: &[[f32; 3]]) -> bool {
    let d: Vec<f32> = g.iter().zip(c).map(|(a, b)| (n * n) as f32 * (a - b)).collect();
    (1..=n).any(|j| {
        colours.iter().any(|a| {
            colours
                .iter()
                .any(|b| (0..3).all(|k| (d[k] - j as f32 * (a[k] - b[k])).abs() <= 1e-3 * (n * n) as f32))
        })
    })
}
