//! Twin of `wgsl/trace/pathtrace.wgsl` and `wgsl/trace/gbuffer.wgsl`: one path (NEE + MIS,
//! Russian roulette, Beer-Lambert media, alpha cut-outs), the mean of a pixel's jittered
//! samples, the G-buffers of primary visibility, and the pinhole camera.

use glam::{Vec2, Vec3A as Vec3};

use super::bsdf::{Lobes, bsdf_eval_with, bsdf_sample_with, pass_through};
use super::common::{BIG, Hit, NO_HIT, Rng, finite3, max3, offset_ray, rng_seed};
use super::lights::{
    EnvInfo, env_light_pdf, env_radiance, env_select_prob, has_lights, has_pass, mis_power, prefetch_light,
    sample_light, tri_light_pdf,
};
use super::material::surface_at;
use super::traverse::{occluded, traverse};
use crate::render::camera::GpuCamera;
use crate::render::packed::{MAT_THIN, PackedScene};

/// What the kernels read per frame (the CPU side of WGSL `FrameParams`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Params {
    pub cam: GpuCamera,
    pub prev: GpuCamera,
    pub width: u32,
    pub height: u32,
    pub frame: u32,
    pub seed: u32,
    pub max_depth: u32,
    pub far: f32,
}

#[inline]
fn v3(v: [f32; 4]) -> Vec3 {
    Vec3::new(v[0], v[1], v[2])
}

/// Unit direction through continuous pixel position `px` (WGSL `camera_dir`).
pub(crate) fn camera_dir(c: &GpuCamera, px: Vec2, size: Vec2) -> Vec3 {
    let ndc = Vec2::new(2.0 * px.x / size.x - 1.0, 1.0 - 2.0 * px.y / size.y);
    let x = ndc.x * c.pos[3] * c.right[3];
    let y = ndc.y * c.pos[3];
    (v3(c.fwd) + x * v3(c.right) + y * v3(c.up)).normalize()
}

/// Continuous pixel position of point (or direction) `p`; `None` behind the camera (WGSL
/// `camera_project`).
pub(crate) fn camera_project(c: &GpuCamera, p: Vec3, is_dir: bool, size: Vec2) -> Option<Vec2> {
    let v = if is_dir { p } else { p - v3(c.pos) };
    let z = v.dot(v3(c.fwd));
    if !(z > 1.0e-12) {
        return None;
    }
    let x = v.dot(v3(c.right)) / (z * c.pos[3] * c.right[3]);
    let y = v.dot(v3(c.up)) / (z * c.pos[3]);
    Some(Vec2::new((x + 1.0) * 0.5 * size.x, (1.0 - y) * 0.5 * size.y))
}

/// Radiance of one path and the NEE sample of its first hit.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct PathResult {
    pub radiance: Vec3,
    pub shadow: Vec3,
}

/// One path from `o` along `d0` (WGSL `trace_path`).
pub(crate) fn trace_path(
    sc: &PackedScene,
    ei: &EnvInfo,
    max_depth: u32,
    o: Vec3,
    d0: Vec3,
    rng: &mut Rng,
    rays: &mut u64,
) -> PathResult {
    let mut res = PathResult::default();
    let mut ro = o;
    let mut rd = d0;
    let mut skip = NO_HIT;
    let mut thr = Vec3::ONE;
    let mut prev_pdf = 0.0;
    // The previous path vertex (the environment's light pdf depends on it through portals).
    let mut prev_p = o;
    let mut sigma = Vec3::ZERO;
    let lights_on = has_lights(sc);
    // Distance from the previous vertex along rd (it grows where the path passes light
    // straight through a surface), and how many such surfaces the path has passed.
    let mut seg = 0.0;
    let mut passes = 0;
    let mut depth = 1;
    while depth <= max_depth {
        if lights_on && depth < max_depth {
            // The light sample after this segment draws the next three numbers, and the one
            // after the next segment three more after the BSDF's three and Russian
            // roulette's one (unless a surface that passes light draws one first).
            let mut ahead = *rng;
            let u = ahead.next3();
            ahead.next3();
            if depth >= 3 {
                ahead.next();
            }
            prefetch_light(sc, ei, u, ahead.next3());
        }
        let hit = traverse(sc, ro, rd, BIG, false, skip, rays);
        if hit.prim == NO_HIT {
            if ei.present {
                let w = if depth > 1 {
                    mis_power(prev_pdf, env_select_prob(sc) * env_light_pdf(sc, ei, prev_p, rd))
                } else {
                    1.0
                };
                res.radiance += thr * env_radiance(sc, ei, rd) * w;
            }
            break;
        }
        if sigma.cmpgt(Vec3::ZERO).any() {
            thr *= (-sigma * hit.t).exp();
        }
        seg += hit.t;
        let s = surface_at(sc, &hit, rd);
        if s.emission.cmpgt(Vec3::ZERO).any() {
            let w = if depth > 1 {
                mis_power(prev_pdf, tri_light_pdf(sc, hit.prim, seg, s.ng.dot(-rd)))
            } else {
                1.0
            };
            res.radiance += thr * s.emission * w;
        }
        let wo = -rd;
        let lobes = Lobes::new(&s, wo);
        if let Some((t, q)) = pass_through(&s, &lobes) {
            // Straight through (a specular event, not a vertex: depth, the previous vertex
            // and its pdf stay, times the probability of passing), or scatter here.
            if rng.next() < q {
                passes += 1;
                if passes > MAX_PASSES {
                    break;
                }
                thr *= t / q;
                prev_pdf *= q;
                ro = offset_ray(s.p, -s.ng);
                skip = hit.prim;
                continue;
            }
            thr /= 1.0 - q;
        }
        if depth >= max_depth {
            break;
        }
        let ul = rng.next3();
        if lights_on && let Some(ls) = sample_light(sc, ei, s.p, ul) {
            let (ev, ev_pdf) = bsdf_eval_with(&s, &lobes, ls.wi);
            if ev.cmpgt(Vec3::ZERO).any() || depth == 1 {
                let side = if ls.wi.dot(s.ng) > 0.0 { s.ng } else { -s.ng };
                let org = offset_ray(s.p, side);
                let tmax = if ls.dist >= BIG { BIG } else { ls.dist * 0.9999 };
                let (tr, q) = transmittance(sc, org, ls.wi, tmax, s.prim, rays);
                if tr.cmpgt(Vec3::ZERO).any() {
                    // The BSDF route to the same light passes the same surfaces with
                    // probability q.
                    let w = mis_power(ls.pdf, ev_pdf * q);
                    res.radiance += thr * ev * tr * ls.le * (w / ls.pdf);
                    if depth == 1 {
                        res.shadow = tr * ls.le;
                    }
                }
            }
        }
        let Some(bs) = bsdf_sample_with(&s, &lobes, rng.next3()) else {
            break;
        };
        thr *= bs.weight;
        prev_pdf = bs.pdf;
        prev_p = s.p;
        seg = 0.0;
        if bs.transmitted && s.transmission > 0.0 && s.flags & MAT_THIN == 0 {
            sigma = if s.front && s.attenuation.w > 0.0 {
                -Vec3::from_vec4(s.attenuation)
                    .clamp(Vec3::splat(1.0e-6), Vec3::ONE)
                    .ln()
                    / s.attenuation.w
            } else {
                Vec3::ZERO
            };
        }
        ro = offset_ray(s.p, if bs.transmitted { -s.ng } else { s.ng });
        rd = bs.wi;
        skip = hit.prim;
        if depth >= 3 {
            let q = max3(thr).min(0.95);
            if rng.next() >= q {
                break;
            }
            thr /= q;
        }
        if !finite3(thr) {
            break;
        }
        depth += 1;
    }
    if !finite3(res.radiance) {
        res.radiance = Vec3::ZERO;
    }
    res
}

/// Most surfaces passing light straight through that one path segment or shadow ray
/// crosses (WGSL `MAX_PASSES`); beyond, the path ends and the shadow ray is blocked.
const MAX_PASSES: u32 = 16;

/// Transmittance of the segment from `o` along unit `d` up to `dist` (WGSL
/// `transmittance`), and the probability that a path crosses it the same way: 0 where
/// something opaque blocks it; through surfaces that pass light straight through, the
/// products of their transmittances and of their pass probabilities.
fn transmittance(sc: &PackedScene, o: Vec3, d: Vec3, dist: f32, skip: u32, rays: &mut u64) -> (Vec3, f32) {
    if occluded(sc, o, d, dist, skip, rays) {
        return (Vec3::ZERO, 0.0);
    }
    if !has_pass(sc) {
        return (Vec3::ONE, 1.0);
    }
    let (mut tr, mut q) = (Vec3::ONE, 1.0);
    let (mut org, mut left, mut skip) = (o, dist, skip);
    for _ in 0..MAX_PASSES {
        let hit = traverse(sc, org, d, left, false, skip, rays);
        if hit.prim == NO_HIT {
            return (tr, q);
        }
        let s = surface_at(sc, &hit, d);
        let Some((t, p)) = pass_through(&s, &Lobes::new(&s, -d)) else {
            return (Vec3::ZERO, 0.0);
        };
        tr *= t;
        q *= p;
        org = offset_ray(s.p, -s.ng);
        left -= hit.t;
        skip = hit.prim;
    }
    (Vec3::ZERO, 0.0)
}

/// Mean of samples `first .. first + count` of pixel (x, y) (WGSL `pixel_samples`).
#[allow(clippy::too_many_arguments)]
pub(crate) fn pixel_samples(
    sc: &PackedScene,
    ei: &EnvInfo,
    p: &Params,
    x: u32,
    y: u32,
    first: u32,
    count: u32,
    rays: &mut u64,
) -> PathResult {
    let mut sum = PathResult::default();
    for k in 0..count {
        let (mut rng, d) = sample_ray(p, x, y, first + k);
        let r = trace_path(sc, ei, p.max_depth, v3(p.cam.pos), d, &mut rng, rays);
        sum.radiance += r.radiance;
        sum.shadow += r.shadow;
    }
    let inv = 1.0 / count.max(1) as f32;
    PathResult {
        radiance: sum.radiance * inv,
        shadow: sum.shadow * inv,
    }
}

/// Sample `k` of pixel (x, y): its random number generator, after the pixel jitter it drew,
/// and its camera ray's direction (WGSL `pixel_samples`).
fn sample_ray(p: &Params, x: u32, y: u32, k: u32) -> (Rng, Vec3) {
    let size = Vec2::new(p.width as f32, p.height as f32);
    let mut rng = Rng(rng_seed(y * p.width + x, p.frame, k, p.seed));
    let [jx, jy] = rng.next2();
    let d = camera_dir(&p.cam, Vec2::new(x as f32 + jx, y as f32 + jy), size);
    (rng, d)
}

/// The directions of the `n x n` stratified camera rays of pixel (x, y) (the background's
/// footprint; WGSL `footprint_dir`).
fn footprint_dirs(p: &Params, x: u32, y: u32, n: u32) -> impl Iterator<Item = Vec3> + '_ {
    let size = Vec2::new(p.width as f32, p.height as f32);
    (0..n * n).map(move |k| {
        let (i, j) = (k % n, k / n);
        let px = Vec2::new(
            x as f32 + (i as f32 + 0.5) / n as f32,
            y as f32 + (j as f32 + 0.5) / n as f32,
        );
        camera_dir(&p.cam, px, size)
    })
}

/// The G-buffer values of one pixel (WGSL `gbuffer.wgsl`): albedo+depth, normal+metallic,
/// roughness, transparent, motion.
#[derive(Debug, Clone, Copy)]
pub(crate) struct GbufferPixel {
    pub albedo_depth: [f32; 4],
    pub normal_metallic: [f32; 4],
    pub roughness: f32,
    pub transparent: [f32; 3],
    pub motion: [f32; 2],
}

pub(crate) fn gbuffer_pixel(sc: &PackedScene, p: &Params, x: u32, y: u32, rays: &mut u64) -> GbufferPixel {
    let d = primary_dir(p, x, y);
    let hit = traverse(sc, v3(p.cam.pos), d, BIG, false, NO_HIT, rays);
    gbuffer_of_hit(sc, p, x, y, d, &hit)
}

/// Direction of the G-buffer ray of pixel (x, y): through the pixel centre.
pub(crate) fn primary_dir(p: &Params, x: u32, y: u32) -> Vec3 {
    let size = Vec2::new(p.width as f32, p.height as f32);
    camera_dir(&p.cam, Vec2::new(x as f32 + 0.5, y as f32 + 0.5), size)
}

/// The footprint values of one pixel ([`background_pixel`]).
#[derive(Debug, Clone, Copy)]
pub(crate) struct FootprintPixel {
    /// The directly seen environment: the mean of the environment radiance along the
    /// camera rays that escape, 0 for those that hit anything (transmissive surfaces
    /// included).
    pub environment: Vec3,
    /// The fraction of the rays that escape.
    pub coverage: f32,
    /// The mean first-hit base colour (the G-buffer's albedo, sky 1).
    pub albedo: Vec3,
    /// The mean first-hit emission (0 for rays that escape or hit a surface that does not
    /// emit towards the camera).
    pub emission: Vec3,
}

/// The footprint values of pixel (x, y) (WGSL `background.wgsl`), over `n x n` stratified
/// positions in the pixel.
pub(crate) fn background_pixel(
    sc: &PackedScene,
    ei: &EnvInfo,
    p: &Params,
    x: u32,
    y: u32,
    n: u32,
    rays: &mut u64,
) -> FootprintPixel {
    let o = v3(p.cam.pos);
    let (mut sum, mut escaped, mut albedo) = (Vec3::ZERO, 0u32, Vec3::ZERO);
    let mut emission = Vec3::ZERO;
    for d in footprint_dirs(p, x, y, n) {
        let hit = traverse(sc, o, d, BIG, false, NO_HIT, rays);
        if hit.prim == NO_HIT {
            escaped += 1;
            sum += env_radiance(sc, ei, d); // 0 without an environment
            albedo += Vec3::ONE;
        } else {
            let s = surface_at(sc, &hit, d);
            albedo += s.base;
            emission += s.emission;
        }
    }
    let count = (n * n) as f32;
    FootprintPixel {
        environment: sum / count,
        coverage: escaped as f32 / count,
        albedo: albedo / count,
        emission: emission / count,
    }
}

/// The mean first-hit emission over the `n x n` stratified camera rays of pixel (x, y)
/// ([`background_pixel`]'s rays; WGSL `trace/emission_outline`).
pub(crate) fn footprint_emission(
    sc: &PackedScene,
    p: &Params,
    x: u32,
    y: u32,
    n: u32,
    rays: &mut u64,
) -> Vec3 {
    let o = v3(p.cam.pos);
    let mut emission = Vec3::ZERO;
    for d in footprint_dirs(p, x, y, n) {
        let hit = traverse(sc, o, d, BIG, false, NO_HIT, rays);
        if hit.prim != NO_HIT {
            emission += surface_at(sc, &hit, d).emission;
        }
    }
    emission / (n * n) as f32
}

/// What samples `first .. first + count` of pixel (x, y) see first, averaged: the emission
/// of the surface each sample's camera ray meets (before any scattering or straight-through
/// passing), which [`trace_path`] adds to the sample's radiance with weight 1, and the
/// fraction of the camera rays that escape (hit nothing: their radiance is the environment
/// along them; WGSL `PathResult.escaped`). Replays only the camera rays, with the same random
/// numbers.
#[allow(clippy::too_many_arguments)]
pub(crate) fn first_hit(
    sc: &PackedScene,
    p: &Params,
    x: u32,
    y: u32,
    first: u32,
    count: u32,
    rays: &mut u64,
) -> (Vec3, f32) {
    let (mut sum, mut escaped) = (Vec3::ZERO, 0u32);
    for k in 0..count {
        let (_, d) = sample_ray(p, x, y, first + k);
        let hit = traverse(sc, v3(p.cam.pos), d, BIG, false, NO_HIT, rays);
        if hit.prim == NO_HIT {
            escaped += 1;
        } else {
            sum += surface_at(sc, &hit, d).emission;
        }
    }
    let inv = 1.0 / count.max(1) as f32;
    (sum * inv, escaped as f32 * inv)
}

/// The G-buffer values of pixel (x, y) whose primary ray (direction `d`) has hit `hit`.
pub(crate) fn gbuffer_of_hit(
    sc: &PackedScene,
    p: &Params,
    x: u32,
    y: u32,
    d: Vec3,
    hit: &Hit,
) -> GbufferPixel {
    let size = Vec2::new(p.width as f32, p.height as f32);
    let pos = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
    let (mut g, prev) = if hit.prim == NO_HIT {
        (
            GbufferPixel {
                albedo_depth: [1.0; 4],
                normal_metallic: [0.0; 4],
                roughness: 0.0,
                transparent: [0.0; 3],
                motion: [0.0; 2],
            },
            camera_project(&p.prev, d, true, size),
        )
    } else {
        let s = surface_at(sc, hit, d);
        let depth = ((s.p - v3(p.cam.pos)).dot(v3(p.cam.fwd)) / p.far).clamp(0.0, 1.0);
        let t = s.base * s.transmission;
        (
            GbufferPixel {
                albedo_depth: [s.base.x, s.base.y, s.base.z, depth],
                normal_metallic: [s.ns.x, s.ns.y, s.ns.z, s.metallic],
                roughness: s.roughness,
                transparent: [t.x, t.y, t.z],
                motion: [0.0; 2],
            },
            camera_project(&p.prev, s.p, false, size),
        )
    };
    g.motion = match prev {
        Some(q) => [q.x - pos.x, q.y - pos.y],
        None => [-1.0e6, -1.0e6],
    };
    g
}
