//! Path tracer tests on any adapter (a CPU Vulkan driver is enough), at tiny sizes.

mod common;

use common::{furnace, gpu};
use glam::{BVec3, Vec2, Vec3};
use rand::{Rng, SeedableRng, rngs::StdRng};
use subpixel::frame::HostFrame;
use subpixel::render::builtin::{self, CornellOptions};
use subpixel::render::scene::{Geometry, Material, Scene};
use subpixel::render::{Camera, FrameSettings, GpuScene, Mode, Tracer, query_rays};

fn render(scene: &Scene, gs: &GpuScene, w: u32, h: u32, s: &FrameSettings) -> HostFrame {
    let g = gpu();
    let mut t = Tracer::new(&g, w, h).unwrap();
    let _ = scene;
    t.render(gs, s).unwrap();
    t.buffers.download(&g).unwrap()
}

/// Writes an sRGB PNG of an HDR colour tensor when SUBPIXEL_DEBUG_PNG is set (debugging aid).
fn debug_png(name: &str, t: &subpixel::nn::HostTensor) {
    let Ok(dir) = std::env::var("SUBPIXEL_DEBUG_PNG") else {
        return;
    };
    let mut img = image::RgbImage::new(t.width, t.height);
    for y in 0..t.height {
        for x in 0..t.width {
            let c = |k: u32| {
                let v = t.at(x, y, k.min(t.channels - 1)).max(0.0);
                let v = v / (1.0 + v);
                (v.powf(1.0 / 2.2) * 255.0).round() as u8
            };
            img.put_pixel(x, y, image::Rgb([c(0), c(1), c(2)]));
        }
    }
    img.save(std::path::Path::new(&dir).join(format!("{name}.png")))
        .unwrap();
}

/// A uniformly random point of the cube [-r, r]^3.
fn in_cube(rng: &mut StdRng, r: f32) -> Vec3 {
    Vec3::new(
        rng.random_range(-r..r),
        rng.random_range(-r..r),
        rng.random_range(-r..r),
    )
}

fn random_mesh(rng: &mut StdRng, kind: usize) -> Scene {
    let mut g = Geometry::default();
    match kind {
        0 => {
            // Triangle soup.
            for _ in 0..400 {
                let c = in_cube(rng, 5.0);
                let p: Vec<Vec3> = (0..3).map(|_| c + in_cube(rng, 1.0)).collect();
                g.push_mesh(&p, None, None, None, &[[0, 1, 2]], 0);
            }
        }
        1 => {
            // Spheres and boxes.
            for i in 0..12 {
                let c = in_cube(rng, 4.0);
                if i % 2 == 0 {
                    builtin::push_sphere(&mut g, c, rng.random_range(0.3..1.5), 24, 12, 0);
                } else {
                    builtin::push_box(
                        &mut g,
                        c,
                        Vec3::splat(rng.random_range(0.2..1.0)),
                        glam::Quat::from_rotation_y(rng.random_range(0.0..3.0)),
                        0,
                    );
                }
            }
        }
        _ => {
            // An axis-aligned grid of quads (axis-aligned rays hit edges and planes exactly).
            for i in 0..20 {
                for j in 0..20 {
                    let o = Vec3::new(i as f32 - 10.0, j as f32 - 10.0, ((i * j) % 5) as f32);
                    g.push_quad([o, o + Vec3::X, o + Vec3::X + Vec3::Y, o + Vec3::Y], 0);
                }
            }
        }
    }
    Scene {
        name: format!("random mesh {kind}"),
        geometry: g,
        materials: vec![Material::diffuse("m", [0.5; 3])],
        textures: vec![],
        environment: None,
        camera: Camera {
            position: Vec3::Z * 10.0,
            target: Vec3::ZERO,
            up: Vec3::Y,
            yfov: 1.0,
        },
        film: (16, 16),
        camera_path: None,
        approximations: vec![],
    }
}

/// GPU traversal == obvhs CPU traversal: hit/miss, primitive, t within 1e-4 relative.
#[test]
fn gpu_traversal_matches_obvhs_cpu() {
    let g = gpu();
    let mut rng = StdRng::seed_from_u64(42);
    let mut checked = 0;
    let mut hits = 0;
    for kind in 0..3 {
        let scene = random_mesh(&mut rng, kind);
        let gs = GpuScene::new(&g, &scene).unwrap();
        let mut rays = Vec::new();
        for i in 0..3000 {
            let o = in_cube(&mut rng, 8.0);
            let mut d = if kind == 2 && i % 3 == 0 {
                // Axis-aligned directions.
                [Vec3::X, Vec3::Y, Vec3::Z, -Vec3::X, -Vec3::Y, -Vec3::Z][i % 6]
            } else if i % 3 == 1 {
                in_cube(&mut rng, 1.0)
            } else {
                // Aimed into the geometry.
                in_cube(&mut rng, 4.0) - o
            };
            if d.length() < 1e-3 {
                d = Vec3::X;
            }
            let tmax = if i % 4 == 0 {
                rng.random_range(0.5..10.0)
            } else {
                f32::INFINITY
            };
            rays.push((o, d.normalize(), tmax));
        }
        let gpu_hits = query_rays(&g, &gs, &rays, false).unwrap();
        let gpu_any = query_rays(&g, &gs, &rays, true).unwrap();
        for (i, ((o, d, tmax), gh)) in rays.iter().zip(&gpu_hits).enumerate() {
            let ch = gs.bvh.intersect(*o, *d, *tmax);
            match (ch, gh) {
                (None, None) => {}
                (Some((cp, ct)), Some((gp, gt))) => {
                    assert_eq!(cp, *gp, "mesh {kind} ray {i}: primitive");
                    assert!(
                        (ct - gt).abs() <= 1e-4 * ct.abs().max(1e-3),
                        "mesh {kind} ray {i}: t {ct} vs {gt}"
                    );
                    hits += 1;
                }
                _ => panic!("mesh {kind} ray {i}: cpu {ch:?} gpu {gh:?}"),
            }
            assert_eq!(
                gpu_any[i].is_some(),
                gs.bvh.occluded(*o, *d, *tmax),
                "mesh {kind} ray {i}: any hit"
            );
            checked += 1;
        }
    }
    assert!(
        hits > checked / 5,
        "too few hits to be meaningful: {hits} of {checked}"
    );
}

/// The closest hit of every triangle of `scene` tested one by one (Moeller-Trumbore in f64):
/// the independent expectation of the BVH traversals.
fn brute_force_hit(scene: &Scene, o: Vec3, d: Vec3, tmax: f32) -> Option<f32> {
    let g = &scene.geometry;
    let (o, d) = (o.as_dvec3(), d.as_dvec3());
    let mut best: Option<f64> = None;
    for t in &g.triangles {
        let [a, b, c] = t.map(|i| g.positions[i as usize].as_dvec3());
        let (e1, e2) = (b - a, c - a);
        let p = d.cross(e2);
        let det = e1.dot(p);
        if det.abs() < 1e-12 {
            continue;
        }
        let s = o - a;
        let u = s.dot(p) / det;
        let q = s.cross(e1);
        let v = d.dot(q) / det;
        let th = e2.dot(q) / det;
        if u >= 0.0 && v >= 0.0 && u + v <= 1.0 && th > 0.0 && th <= tmax as f64 {
            best = Some(best.map_or(th, |b: f64| b.min(th)));
        }
    }
    best.map(|t| t as f32)
}

/// Axis-parallel rays whose directions hold negative zeros (`-Vec3::Z` is (-0, -0, -1)) hit
/// what brute force hits, on the GPU and in the CPU BVH. Both traversals once took the
/// reciprocal's sign from the sign bit of -0.0 but the ray's octant from `d < 0`, and then
/// missed every box whose slab held the ray: a ray straight down onto a floor went through.
#[test]
fn signed_zero_directions_hit_what_brute_force_hits() {
    let g = gpu();
    let mut rng = StdRng::seed_from_u64(7);
    let scene = random_mesh(&mut rng, 2);
    let gs = GpuScene::new(&g, &scene).unwrap();
    let dirs = [
        -Vec3::X,
        -Vec3::Y,
        -Vec3::Z,
        Vec3::X,
        Vec3::Y,
        Vec3::Z,
        Vec3::new(-0.0, 0.0, 1.0),
        Vec3::new(0.0, -0.0, -1.0),
    ];
    let mut rays = Vec::new();
    for (k, &d) in dirs.iter().enumerate() {
        for _ in 0..200 {
            // Off the quads' edges and diagonals, above, below or among them.
            let (i, j) = (rng.random_range(-10..10), rng.random_range(-10..10));
            let z = [-3.0, 2.5, 8.0][rng.random_range(0..3)];
            let o = Vec3::new(i as f32 + 0.37, j as f32 + 0.61, z);
            let o = if k % 3 == 2 || k >= 6 {
                o
            } else {
                in_cube(&mut rng, 8.0)
            };
            rays.push((o, d, f32::INFINITY));
        }
    }
    let gpu_hits = query_rays(&g, &gs, &rays, false).unwrap();
    let gpu_any = query_rays(&g, &gs, &rays, true).unwrap();
    let mut hits = 0;
    for (i, (&(o, d, tmax), gh)) in rays.iter().zip(&gpu_hits).enumerate() {
        let want = brute_force_hit(&scene, o, d, tmax);
        let cpu = gs.bvh.intersect(o, d, tmax).map(|h| h.1);
        for (what, got) in [("GPU", gh.map(|h| h.1)), ("CPU BVH", cpu)] {
            match (want, got) {
                (None, None) => {}
                (Some(a), Some(b)) => assert!(
                    (a - b).abs() <= 1e-4 * a.max(1.0),
                    "{what} ray {i} {o} {d:?}: t {b} vs {a}"
                ),
                _ => panic!("{what} ray {i} from {o} along {d:?}: {got:?}, brute force {want:?}"),
            }
        }
        assert_eq!(
            gpu_any[i].is_some(),
            want.is_some(),
            "GPU any-hit ray {i} along {d:?}"
        );
        assert_eq!(
            gs.bvh.occluded(o, d, tmax),
            want.is_some(),
            "CPU occluded ray {i} along {d:?}"
        );
        hits += want.is_some() as usize;
    }
    assert!(hits > rays.len() / 5, "{hits} of {} rays hit", rays.len());
}

fn far_of(scene: &Scene) -> f32 {
    scene.far_distance([&scene.camera.position])
}

fn reference(scene: &Scene, gs: &GpuScene, w: u32, h: u32, spp: u32, max_depth: u32, seed: u32) -> HostFrame {
    let mut s = FrameSettings::new(scene.camera, Mode::Reference, far_of(scene));
    s.spp = spp;
    s.max_depth = max_depth;
    s.seed = seed;
    render(scene, gs, w, h, &s)
}

/// The reference of `builtin:furnace` with its sphere made of `m`, at 12 x 12 pixels.
fn furnace_reference(m: Material, spp: u32, max_depth: u32, seed: u32) -> HostFrame {
    let scene = furnace::scene(m);
    let gs = GpuScene::new(&gpu(), &scene).unwrap();
    reference(&scene, &gs, 12, 12, spp, max_depth, seed)
}

fn mean(v: impl Iterator<Item = f32>) -> f64 {
    let (mut s, mut n) = (0f64, 0usize);
    for x in v {
        s += x as f64;
        n += 1;
    }
    s / n.max(1) as f64
}

/// A white Lambertian sphere in a uniform white environment is invisible: every pixel
/// converges to 1 (exercises BSDF sampling, environment importance sampling and MIS).
#[test]
fn white_furnace_converges_to_one() {
    let scene = builtin::furnace();
    let gs = GpuScene::new(&gpu(), &scene).unwrap();
    let f = reference(&scene, &gs, 16, 16, 256, 16, 1);
    debug_png("furnace", &f.color);
    let sphere: Vec<(u32, u32)> = (0..16)
        .flat_map(|y| (0..16).map(move |x| (x, y)))
        .filter(|&(x, y)| f.depth.at(x, y, 0) < 1.0)
        .collect();
    assert!(sphere.len() > 60, "the sphere covers {} pixels", sphere.len());
    for c in 0..3 {
        let m = mean(sphere.iter().map(|&(x, y)| f.color.at(x, y, c)));
        eprintln!("furnace channel {c}: sphere mean {m}");
        assert!((m - 1.0).abs() < 0.01, "furnace channel {c}: sphere mean {m}");
        let all = mean((0..256).map(|i| f.color.data[3 * i + c as usize]));
        assert!((all - 1.0).abs() < 0.01, "furnace channel {c}: image mean {all}");
    }
}

fn symmetric_cornell() -> Scene {
    builtin::cornell(&CornellOptions {
        objects: false,
        left: [0.63, 0.065, 0.05],
        right: [0.065, 0.63, 0.05],
        white: [0.725, 0.725, 0.7],
        light: [15.0, 15.0, 15.0],
    })
}

/// Cornell box energy: direct light adds to the emitter, indirect light adds more but
/// stays below the geometric-series bound; the back wall is mirror-symmetric with red and
/// green swapped (the walls are mirror colours).
#[test]
fn cornell_energy_and_back_wall_symmetry() {
    let scene = symmetric_cornell();
    let gs = GpuScene::new(&gpu(), &scene).unwrap();
    let (w, h) = (20, 20);
    let lum = |f: &HostFrame| {
        mean((0..w * h).map(|i| {
            let c = &f.color.data[3 * i as usize..3 * i as usize + 3];
            0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
        }))
    };
    let e1 = lum(&reference(&scene, &gs, w, h, 16, 1, 3));
    let e2 = lum(&reference(&scene, &gs, w, h, 64, 2, 4));
    let full = reference(&scene, &gs, w, h, 1024, 8, 5);
    debug_png("cornell_sym", &full.color);
    let ef = lum(&full);
    eprintln!("cornell energy: emitters {e1}, + direct {e2}, all {ef}");
    assert!(e1 > 0.0, "the light is visible: {e1}");
    let (direct, all) = (e2 - e1, ef - e1);
    assert!(direct > 0.05, "direct lighting {direct}");
    assert!(
        all > 1.2 * direct,
        "indirect light adds energy: {all} vs direct {direct}"
    );
    // Each bounce keeps at most the largest albedo (0.725) of the energy (+ 4% specular).
    assert!(
        all < direct / (1.0 - 0.765),
        "energy {all} exceeds the bound {}",
        direct / (1.0 - 0.765)
    );
    // Back wall: normal +z.
    let (mut left, mut right, mut n) = ([0f64; 3], [0f64; 3], 0);
    for y in 0..h {
        for x in 0..w / 2 {
            let m = w - 1 - x;
            let back = |x| full.normal.at(x, y, 2) > 0.99;
            if back(x) && back(m) {
                for c in 0..3 {
                    left[c as usize] += full.color.at(x, y, c) as f64;
                    right[c as usize] += full.color.at(m, y, c) as f64;
                }
                n += 1;
            }
        }
    }
    eprintln!("back wall ({n} pixel pairs): left {left:?} right {right:?}");
    assert!(n > 30, "back wall pixels {n}");
    // About 70k samples per half: Monte Carlo noise is about 1% here.
    let close = |a: f64, b: f64| (a - b).abs() <= 0.03 * a.abs().max(b.abs());
    assert!(
        close(left[0], right[1]),
        "left red {} vs right green {}",
        left[0],
        right[1]
    );
    assert!(
        close(left[1], right[0]),
        "left green {} vs right red {}",
        left[1],
        right[0]
    );
    assert!(close(left[2], right[2]), "blue {} vs {}", left[2], right[2]);
    assert!(
        left[0] > 1.05 * left[1] && right[1] > 1.05 * right[0],
        "colour bleeding: {left:?} {right:?}"
    );
}

/// Quarter mode traces each pixel exactly once in any 4 consecutive frames (odd sizes too),
/// and untraced pixels hold zero colour and shadow.
#[test]
fn quarter_mask_covers_each_pixel_once_per_four_frames() {
    let scene = builtin::cornell(&CornellOptions::default());
    let g = gpu();
    let gs = GpuScene::new(&g, &scene).unwrap();
    let (w, h) = (13, 9);
    let mut t = Tracer::new(&g, w, h).unwrap();
    let mut masks = Vec::new();
    for frame in 0..6 {
        let mut s = FrameSettings::new(scene.camera, Mode::Quarter, far_of(&scene));
        s.frame = frame;
        s.max_depth = 3;
        t.render(&gs, &s).unwrap();
        let f = t.buffers.download(&g).unwrap();
        for i in 0..(w * h) as usize {
            let m = f.mask.data[i];
            assert!(m == 0.0 || m == 1.0, "mask {m}");
            if m == 0.0 {
                assert_eq!(&f.color.data[3 * i..3 * i + 3], &[0.0; 3]);
                assert_eq!(&f.shadow.data[3 * i..3 * i + 3], &[0.0; 3]);
            }
        }
        masks.push(f.mask);
    }
    for start in 0..3 {
        for y in 0..h {
            for x in 0..w {
                let count: f32 = (start..start + 4).map(|f| masks[f].at(x, y, 0)).sum();
                assert_eq!(
                    count,
                    1.0,
                    "pixel ({x},{y}) traced {count} times in frames {start}..{}",
                    start + 4
                );
            }
        }
    }
    // Full mode traces everything.
    let mut s = FrameSettings::new(scene.camera, Mode::Full, far_of(&scene));
    s.max_depth = 2;
    t.render(&gs, &s).unwrap();
    assert!(
        t.buffers
            .download(&g)
            .unwrap()
            .mask
            .data
            .iter()
            .all(|&m| m == 1.0)
    );
}

/// Motion vectors reproject frame t-1 onto frame t: prev_pos = pos + motion equals the
/// analytic projection, by the previous camera, of the first hit found by the CPU BVH.
#[test]
fn motion_vectors_match_analytic_reprojection() {
    let scene = builtin::cornell(&CornellOptions::default());
    let gs = GpuScene::new(&gpu(), &scene).unwrap();
    let (w, h) = (32, 24);
    let cam0 = scene.camera;
    let cam1 = Camera {
        position: cam0.position + Vec3::new(0.21, -0.07, -0.3),
        target: cam0.target + Vec3::new(-0.1, 0.05, 0.0),
        ..cam0
    };
    let far = far_of(&scene);
    let mut s = FrameSettings::new(cam1, Mode::Quarter, far);
    s.prev_camera = cam0;
    s.frame = 1;
    s.max_depth = 1;
    let f = render(&scene, &gs, w, h, &s);
    let (_, _, fwd) = cam1.basis();
    let (mut checked, mut worst) = (0, 0f32);
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let pos = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
            let d = cam1.ray_dir(pos, w, h);
            let Some((_, t)) = gs.bvh.intersect(cam1.position, d, f32::INFINITY) else {
                continue;
            };
            let p = cam1.position + t * d;
            // Same surface on the GPU (depth agrees), away from silhouettes.
            let depth = p.sub(cam1.position).dot(fwd) / far;
            if (f.depth.at(x, y, 0) - depth).abs() > 1e-4 {
                continue;
            }
            let expect = cam0.project(p, w, h).unwrap() - pos;
            let got = Vec2::new(f.motion.at(x, y, 0), f.motion.at(x, y, 1));
            worst = worst.max((got - expect).length());
            checked += 1;
        }
    }
    eprintln!("motion: {checked} pixels, worst error {worst} px");
    assert!(
        checked > (w - 2) * (h - 2) * 8 / 10,
        "only {checked} interior pixels compared"
    );
    assert!(worst < 0.05, "worst motion error {worst} px");
    // A static camera gives zero motion.
    let mut s0 = FrameSettings::new(cam0, Mode::Quarter, far);
    s0.max_depth = 1;
    let f0 = render(&scene, &gs, 8, 8, &s0);
    assert!(
        f0.motion.data.iter().all(|m| m.abs() < 1e-3),
        "static motion {:?}",
        &f0.motion.data[..4]
    );
}

use std::ops::Sub;

/// Reference mode converges: the variance of an N-spp pixel falls like 1/N.
#[test]
fn reference_variance_falls_like_one_over_n() {
    let scene = symmetric_cornell();
    let gs = GpuScene::new(&gpu(), &scene).unwrap();
    let (w, h) = (12, 12);
    let var_at = |spp: u32| {
        let runs: Vec<HostFrame> = (0..16)
            .map(|seed| reference(&scene, &gs, w, h, spp, 3, 100 + seed))
            .collect();
        let n = runs.len() as f64;
        let mut total = 0f64;
        for i in 0..(w * h * 3) as usize {
            let m: f64 = runs.iter().map(|r| r.color.data[i] as f64).sum::<f64>() / n;
            total += runs
                .iter()
                .map(|r| (r.color.data[i] as f64 - m).powi(2))
                .sum::<f64>()
                / (n - 1.0);
        }
        total / (w * h * 3) as f64
    };
    let v2 = var_at(2);
    let v8 = var_at(8);
    let ratio = v2 / v8;
    eprintln!("variance 2 spp {v2}, 8 spp {v8}, ratio {ratio}");
    assert!(
        v8 > 0.0 && (2.5..6.4).contains(&ratio),
        "variance 2 spp {v2}, 8 spp {v8}: ratio {ratio} (expected ~4)"
    );
}

/// G-buffers: sky values, textured albedo of the walls, unit normals, the glass tint.
#[test]
fn gbuffers_follow_the_contract() {
    let scene = builtin::cornell(&CornellOptions::default());
    let gs = GpuScene::new(&gpu(), &scene).unwrap();
    let (w, h) = (32, 32);
    let mut s = FrameSettings::new(scene.camera, Mode::Quarter, far_of(&scene));
    s.max_depth = 2;
    let f = render(&scene, &gs, w, h, &s);
    debug_png("gb_albedo", &f.albedo);
    let mut saw_red = false;
    let mut saw_glass = false;
    for y in 0..h {
        for x in 0..w {
            let d = f.depth.at(x, y, 0);
            assert!((0.0..=1.0).contains(&d));
            if d < 1.0 {
                let n = Vec3::new(f.normal.at(x, y, 0), f.normal.at(x, y, 1), f.normal.at(x, y, 2));
                assert!((n.length() - 1.0).abs() < 1e-3, "normal {n} at {x},{y}");
            }
            let a = [f.albedo.at(x, y, 0), f.albedo.at(x, y, 1), f.albedo.at(x, y, 2)];
            if (a[0] - 0.63).abs() < 1e-6 && (a[1] - 0.065).abs() < 1e-6 {
                saw_red = true;
                assert!(f.normal.at(x, y, 0) > 0.99, "left wall normal faces +x");
            }
            if f.transparent.at(x, y, 0) > 0.5 {
                saw_glass = true;
            }
        }
    }
    assert!(saw_red && saw_glass, "red wall {saw_red}, glass {saw_glass}");
    // The furnace has sky around the sphere.
    let fs = builtin::furnace();
    let fgs = GpuScene::new(&gpu(), &fs).unwrap();
    let mut s = FrameSettings::new(fs.camera, Mode::Quarter, far_of(&fs));
    s.max_depth = 1;
    let f = render(&fs, &fgs, 8, 8, &s);
    assert_eq!(
        (f.albedo.at(0, 0, 0), f.depth.at(0, 0, 0), f.normal.at(0, 0, 2)),
        (1.0, 1.0, 0.0)
    );
}

/// The textured room (textures, normal map, alpha cut-out, environment + emitters) renders
/// finite, non-black images.
#[test]
fn textured_room_renders() {
    let scene = builtin::room();
    let gs = GpuScene::new(&gpu(), &scene).unwrap();
    assert!(gs.emissive_triangles > 0 && gs.env_probability > 0.0);
    let f = reference(&scene, &gs, 32, 24, 4, 4, 9);
    debug_png("room", &f.color);
    assert!(f.color.data.iter().all(|v| v.is_finite() && *v >= 0.0));
    assert!(mean(f.color.data.iter().copied()) > 0.01);
}

/// The `subpixel render` arguments of the CLI tests: builtin:cornell-empty, 2 quarter frames
/// of 9x7 along an orbit, an 8-spp reference, PNG previews and 1-spp frames, into `out`.
fn cli_render_args(
    backend: subpixel::render::Backend,
    out: std::path::PathBuf,
) -> subpixel::cli::render::RenderArgs {
    subpixel::cli::render::RenderArgs {
        scene: "builtin:cornell-empty".into(),
        mode: Mode::Quarter,
        spp: 1,
        frames: 2,
        first_frame: 0,
        width: Some(9),
        height: Some(7),
        max_depth: 3,
        seed: 5,
        path: Some("orbit".parse().unwrap()),
        reference_spp: Some(8),
        reference_noise_target: None,
        reference_spp_max: None,
        png: true,
        resume: false,
        backend,
        full_spp: true,
        background: None,
        scene_options: Default::default(),
        fallback_path: None,
        sequence_json: None,
        out,
    }
}

/// `subpixel render --reference-noise-target`: each frame's reference takes the samples its
/// halves need (recorded per frame as it is written, so an interrupted run loses none), up to
/// the cap; the recorded noise of the frames that stopped short of the cap reaches the
/// target; an odd base count is refused.
#[test]
fn render_command_meets_a_reference_noise_target() {
    use subpixel::cli::render::{RenderArgs, render_command};
    use subpixel::render::Backend;
    let out = std::env::temp_dir().join(format!("subpixel-render-noise-{}", std::process::id()));
    std::fs::remove_dir_all(&out).ok();
    let mut args = RenderArgs {
        scene: "builtin:room".into(),
        frames: 3,
        width: Some(12),
        height: Some(10),
        max_depth: 4,
        seed: 2,
        reference_spp: Some(7),
        reference_noise_target: Some(24.0),
        reference_spp_max: Some(112),
        png: false,
        full_spp: false,
        ..cli_render_args(Backend::Cpu, out.clone())
    };
    let e = render_command(&args).unwrap_err().to_string();
    assert!(e.contains("even --reference-spp"), "{e}");
    args.reference_spp = Some(8);
    args.reference_spp_max = Some(128);
    // A run stopped after its first frame (frame 1 cannot be written here) keeps that
    // frame's samples in sequence.json; the resumed run adds the others.
    let blocker = out.join("frame_0001.partial.exr");
    std::fs::create_dir_all(&blocker).unwrap();
    assert!(render_command(&args).is_err());
    let seq: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("sequence.json")).unwrap()).unwrap();
    assert_eq!(
        seq["reference_spp_per_frame"].as_object().map(|m| m.len()),
        Some(1),
        "{seq}"
    );
    std::fs::remove_dir_all(&blocker).unwrap();
    args.resume = true;
    render_command(&args).unwrap();
    let seq: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("sequence.json")).unwrap()).unwrap();
    let per_frame = seq["reference_spp_per_frame"]
        .as_object()
        .expect("per-frame samples");
    assert_eq!(per_frame.len(), 3, "{seq}");
    let mut doubled = 0;
    for (frame, n) in per_frame {
        let n = n.as_u64().unwrap();
        assert!([8, 16, 32, 64, 128].contains(&n), "{frame}: {n} spp");
        let noise = seq["reference_noise"]["per_frame"][frame].as_f64().unwrap();
        assert!(noise >= 24.0 || n == 128, "{frame}: {noise:.2} dB at {n} spp");
        doubled += (n > 8) as u32;
    }
    assert!(doubled > 0, "no frame needed more samples: {seq}");
    std::fs::remove_dir_all(&out).ok();
}

/// `subpixel render` writes readable EXR frames with every channel on both backends, with
/// the reference's noise measured from its halves; resuming with other parameters is refused.
#[test]
fn render_command_writes_exr_frames() {
    use subpixel::cli::render::render_command;
    use subpixel::render::Backend;
    for backend in [Backend::Gpu, Backend::Cpu] {
        let out = std::env::temp_dir().join(format!(
            "subpixel-render-cli-{}-{}",
            backend.name(),
            std::process::id()
        ));
        std::fs::remove_dir_all(&out).ok();
        let mut args = cli_render_args(backend, out.clone());
        render_command(&args).unwrap();
        for f in 0..2 {
            let frame = subpixel::io::exr::read_frame(&out.join(format!("frame_{f:04}.exr"))).unwrap();
            assert_eq!(frame.frame.as_ref().unwrap().size().unwrap(), (9, 7));
            assert!(frame.reference.is_some() && frame.reference_half.is_some() && frame.full.is_some());
            // The 1-spp frame traces every pixel; the quarter frame a quarter of them.
            let full = frame.full.unwrap();
            assert!(
                full.data.iter().filter(|v| **v > 0.0).count()
                    > frame
                        .frame
                        .unwrap()
                        .color
                        .data
                        .iter()
                        .filter(|v| **v > 0.0)
                        .count()
            );
            assert!(out.join(format!("frame_{f:04}.png")).is_file());
        }
        let seq: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("sequence.json")).unwrap()).unwrap();
        assert_eq!(seq["camera_path"], "orbit");
        assert_eq!(seq["backend"], backend.name());
        let noise = &seq["reference_noise"];
        assert_eq!(noise["frames"], 2, "{seq}");
        let psnr = noise["mean_psnr_db"].as_f64().unwrap();
        assert!(psnr > 5.0 && psnr < 60.0, "halves PSNR {psnr}");
        // Resume with another size: refused, naming the parameter; with the same: skipped.
        args.resume = true;
        args.width = Some(8);
        let e = render_command(&args).unwrap_err().to_string();
        assert!(
            e.contains("resolution") && e.contains(&out.display().to_string()),
            "{e}"
        );
        args.width = Some(9);
        render_command(&args).unwrap();
        // Resuming with --background adds the background to the frames already there and
        // changes nothing else in them.
        let read = |f: u32| subpixel::io::exr::read_frame(&out.join(format!("frame_{f:04}.exr"))).unwrap();
        let before = read(1);
        assert!(before.frame.as_ref().unwrap().background.is_none());
        args.background = Some(2);
        render_command(&args).unwrap();
        let mut after = read(1);
        let added = after.frame.as_mut().unwrap().background.take().unwrap();
        assert_eq!(
            (&after.frame, &after.reference, &after.reference_half, &after.full),
            (
                &before.frame,
                &before.reference,
                &before.reference_half,
                &before.full
            )
        );
        // A background written before the footprint albedo existed gets the albedo added
        // on resume, its radiance and coverage kept as they are.
        let albedo = added.albedo.clone().expect("footprint albedo added");
        assert_eq!((albedo.width, albedo.height, albedo.channels), (9, 7, 3));
        let mut old = read(1);
        let b = old.frame.as_mut().unwrap().background.as_mut().unwrap();
        b.albedo = None;
        b.radiance.data.iter_mut().for_each(|v| *v += 1.0);
        let kept = b.radiance.clone();
        subpixel::io::exr::write_frame(&out.join("frame_0001.exr"), &old).unwrap();
        render_command(&args).unwrap();
        let again = read(1).frame.unwrap().background.unwrap();
        assert_eq!((&again.radiance, &again.albedo), (&kept, &Some(albedo)));
        let (bg, cov) = (added.radiance, added.coverage);
        assert_eq!((bg.width, bg.height, bg.channels, cov.channels), (9, 7, 3, 1));
        assert!(cov.data.iter().all(|c| (0.0..=1.0).contains(c)));
        let seq: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("sequence.json")).unwrap()).unwrap();
        assert_eq!(seq["background_lookups"], 4, "{seq}");
        // A fresh render with --background writes it with each frame (the backend's own
        // background pass): the same coverage as the one added on resume (the CPU twin's),
        // up to rays grazing a silhouette on the GPU.
        std::fs::remove_dir_all(&out).ok();
        args.resume = false;
        render_command(&args).unwrap();
        let fresh = read(1).frame.unwrap().background.unwrap();
        let same = fresh
            .coverage
            .data
            .iter()
            .zip(&cov.data)
            .filter(|(a, b)| a == b)
            .count();
        assert!(
            20 * same >= 19 * cov.data.len(),
            "{backend:?}: coverage agrees at {same} of {} pixels",
            cov.data.len()
        );
        assert!(fresh.albedo.is_some(), "{backend:?}: footprint albedo written");
        if backend == Backend::Cpu {
            assert_eq!((&fresh.radiance, &fresh.coverage), (&bg, &cov));
        }
        std::fs::remove_dir_all(&out).ok();
    }
}

fn test_env(w: u32, h: u32, rot_deg: f32) -> subpixel::render::scene::Environment {
    let mut pixels = Vec::new();
    for y in 0..h {
        for x in 0..w {
            pixels.push([
                0.2 + x as f32 * 0.1,
                0.1 + y as f32 * 0.3,
                0.5 + ((x * 7 + y * 3) % 5) as f32 * 0.2,
            ]);
        }
    }
    subpixel::render::scene::Environment {
        source: "test env".into(),
        width: w,
        height: h,
        pixels,
        scale: 1.5,
        to_world: glam::Mat3::from_rotation_y(rot_deg.to_radians()) * glam::Mat3::from_rotation_x(0.3),
        portals: Vec::new(),
    }
}

fn env_scene(env: subpixel::render::scene::Environment, geometry: Geometry, camera: Camera) -> Scene {
    Scene {
        name: "env test".into(),
        geometry,
        materials: vec![Material {
            specular: 0.0,
            ..Material::diffuse("white", [1.0; 3])
        }],
        textures: vec![],
        environment: Some(env),
        camera,
        film: (16, 16),
        camera_path: None,
        approximations: vec![],
    }
}

/// The GPU's lat-long lookup (Mitsuba convention, to_world, scale) equals the CPU's.
#[test]
fn environment_lookup_matches_cpu() {
    let env = test_env(8, 4, 37.0);
    let mut g = Geometry::default();
    // A tiny triangle far behind the camera (a scene needs geometry).
    g.push_mesh(
        &[
            Vec3::new(0.0, 0.0, 100.0),
            Vec3::new(0.01, 0.0, 100.0),
            Vec3::new(0.0, 0.01, 100.0),
        ],
        None,
        None,
        None,
        &[[0, 1, 2]],
        0,
    );
    let camera = Camera {
        position: Vec3::ZERO,
        target: Vec3::new(0.3, 0.2, -1.0),
        up: Vec3::Y,
        yfov: 2.2,
    };
    let scene = env_scene(env.clone(), g, camera);
    let gs = GpuScene::new(&gpu(), &scene).unwrap();
    let (w, h) = (24, 16);
    let mut s = FrameSettings::new(camera, Mode::Full, far_of(&scene));
    s.max_depth = 1;
    let f = render(&scene, &gs, w, h, &s);
    let mut compared = 0;
    for y in 0..h {
        for x in 0..w {
            let corners = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (0.5, 0.5)]
                .map(|(dx, dy)| env.radiance(camera.ray_dir(Vec2::new(x as f32 + dx, y as f32 + dy), w, h)));
            if corners.iter().all(|c| (*c - corners[0]).length() < 1e-6) {
                let got = Vec3::new(f.color.at(x, y, 0), f.color.at(x, y, 1), f.color.at(x, y, 2));
                assert!(
                    (got - corners[0]).length() < 1e-5,
                    "pixel {x},{y}: gpu {got} cpu {}",
                    corners[0]
                );
                compared += 1;
            }
        }
    }
    assert!(compared > 100, "only {compared} pixels inside one texel");
}

/// A white Lambertian plane under a non-uniform environment (with a bright texel) shows
/// E(n)/pi, the cosine-weighted environment integrated on the CPU: environment importance
/// sampling, the BSDF sampling and their MIS weights agree with the integral.
#[test]
fn environment_lighting_matches_cpu_integral() {
    let mut env = test_env(16, 8, 20.0);
    env.pixels[2 * 16 + 5] = [60.0, 50.0, 40.0]; // a "sun" in the upper hemisphere
    let mut g = Geometry::default();
    let v = Vec3::new;
    g.push_quad(
        [
            v(-50., 0., 50.),
            v(50., 0., 50.),
            v(50., 0., -50.),
            v(-50., 0., -50.),
        ],
        0,
    );
    let camera = Camera {
        position: Vec3::new(0.0, 3.0, 0.0),
        target: Vec3::ZERO,
        up: Vec3::Z,
        yfov: 0.8,
    };
    let scene = env_scene(env.clone(), g, camera);
    let gs = GpuScene::new(&gpu(), &scene).unwrap();
    let f = reference(&scene, &gs, 12, 12, 512, 2, 11);
    // CPU: (1/pi) * integral over the upper hemisphere of L(w) cos(theta_y) dw.
    let (ew, eh) = (env.width, env.height);
    let sub = 24;
    let mut expect = glam::DVec3::ZERO;
    for j in 0..eh * sub {
        for i in 0..ew * sub {
            let u = (i as f64 + 0.5) / (ew * sub) as f64;
            let v = (j as f64 + 0.5) / (eh * sub) as f64;
            let (theta, phi) = (v * std::f64::consts::PI, u * std::f64::consts::TAU);
            let l = glam::DVec3::new(theta.sin() * phi.sin(), theta.cos(), -theta.sin() * phi.cos());
            let d = env.to_world.as_dmat3() * l;
            if d.y <= 0.0 {
                continue;
            }
            let dw = 2.0 * std::f64::consts::PI * std::f64::consts::PI * theta.sin()
                / ((ew * sub) as f64 * (eh * sub) as f64);
            let px = env.pixels[(j / sub * ew + i / sub) as usize];
            expect +=
                glam::DVec3::new(px[0] as f64, px[1] as f64, px[2] as f64) * env.scale as f64 * d.y * dw;
        }
    }
    expect /= std::f64::consts::PI;
    for c in 0..3 {
        let m = mean((0..144).map(|i| f.color.data[3 * i + c]));
        eprintln!("env lighting channel {c}: gpu {m} cpu {}", expect[c]);
        assert!(
            (m - expect[c]).abs() < 0.015 * expect[c],
            "channel {c}: gpu {m} vs cpu {}",
            expect[c]
        );
    }
}

/// Energy-conserving smooth materials are invisible in a uniform white environment too:
/// a white mirror, a solid glass sphere and a thin-walled glass sphere.
#[test]
fn furnace_smooth_metal_and_glass() {
    for (name, m) in furnace::smooth() {
        let (m, n) = furnace::sphere_mean(&furnace_reference(m, 64, 32, 2), 0);
        assert!(n > 30);
        eprintln!("furnace {name}: {m}");
        assert!((m - 1.0).abs() < 0.02, "furnace {name}: {m}");
    }
}

/// A white Lambertian sphere inside a closed box whose inner walls emit radiance 1 (and
/// reflect nothing) converges to 1 as in a white furnace: next-event estimation on emissive
/// triangles of different sizes (power-proportional choice) and its MIS with BSDF sampling.
#[test]
fn emissive_box_furnace_converges_to_one() {
    let mut scene = builtin::furnace();
    scene.environment = None;
    scene.materials.push(Material {
        emissive: [1.0; 3],
        specular: 0.0,
        ..Material::diffuse("glow", [0.0; 3])
    });
    let (lo, hi) = (Vec3::new(-2.0, -1.5, -3.0), Vec3::new(2.5, 1.5, 6.0));
    // Corner 0bXYZ of the box: a set bit takes `hi` along its axis, a clear one `lo`.
    let c = |xyz: u8| Vec3::select(BVec3::new(xyz & 4 != 0, xyz & 2 != 0, xyz & 1 != 0), hi, lo);
    let g = &mut scene.geometry;
    // Inward-facing faces (counter-clockwise seen from inside).
    let faces = [
        [c(0b000), c(0b001), c(0b101), c(0b100)], // floor
        [c(0b010), c(0b110), c(0b111), c(0b011)], // ceiling
        [c(0b000), c(0b100), c(0b110), c(0b010)], // back
        [c(0b101), c(0b001), c(0b011), c(0b111)], // front
        [c(0b001), c(0b000), c(0b010), c(0b011)], // left
        [c(0b100), c(0b101), c(0b111), c(0b110)], // right
    ];
    for [a, b, cc, d] in faces {
        let n = (b - a).cross(cc - a);
        assert!(n.dot(-(a + cc) * 0.5) > 0.0, "face must point inwards");
        g.push_quad([a, b, cc, d], 1);
    }
    let gs = GpuScene::new(&gpu(), &scene).unwrap();
    assert_eq!(gs.emissive_triangles, 12);
    let f = reference(&scene, &gs, 12, 12, 256, 16, 4);
    let sphere: Vec<usize> = (0..144)
        .filter(|&i| f.albedo.data[3 * i] == 1.0 && f.depth.data[i] < 0.5)
        .collect();
    assert!(sphere.len() > 30, "sphere pixels {}", sphere.len());
    let m = mean(sphere.iter().map(|&i| f.color.data[3 * i + 1]));
    let all = mean((0..144).map(|i| f.color.data[3 * i + 1]));
    eprintln!("emissive box furnace: sphere {m}, image {all}");
    assert!(
        (m - 1.0).abs() < 0.01 && (all - 1.0).abs() < 0.01,
        "sphere {m}, image {all}"
    );
}

/// Rough materials never create energy in the white furnace (single-scattering GGX loses a
/// little), and stay finite.
#[test]
fn furnace_rough_materials_do_not_gain_energy() {
    for (name, m) in furnace::rough() {
        let f = furnace_reference(m, 128, 32, 8);
        assert!(f.color.data.iter().all(|v| v.is_finite()), "{name}: non-finite");
        let (m, _) = furnace::sphere_mean(&f, 0);
        eprintln!("furnace {name}: {m}");
        assert!(m <= 1.015 && m > 0.75, "furnace {name}: {m}");
    }
}
