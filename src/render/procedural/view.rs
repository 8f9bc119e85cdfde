//! The view check: what the camera sees of a generated scene, and its direct light.

use glam::{Vec2, Vec3};

use crate::render::bvh::SceneBvh;
use crate::render::camera::Camera;
use crate::render::procedural::*;
use crate::render::scene::{AlphaMode, Environment, Scene, luminance};

/// What the CPU BVH says about a camera's view: fractions of a 16 x 16 grid of primary
/// rays over the film.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewCheck {
    /// Rays that hit geometry.
    pub geometry: f32,
    /// Rays that hit objects (when the object triangles are known; else = `geometry`).
    pub objects: f32,
    /// Of the hits, those on a front face or a double-sided / transmissive material (the
    /// camera is not inside something).
    pub front: f32,
    /// Of the hits, those receiving direct light: an unoccluded emitter or environment
    /// direction (transmissive and cut-out surfaces let these test rays through).
    pub lit: f32,
    /// Whether an emitter or the environment is seen directly.
    pub light_in_view: bool,
    /// Distance to the first hit along the view direction (infinite: none).
    pub clearance: f32,
    /// Rays that hit something closer than 0.5 (a view blocked by something right in front).
    pub near: f32,
    /// The scene has an emitter or an environment.
    pub has_light: bool,
    /// Estimated mean radiance (luminance) of the image, from direct light only: emitters
    /// and sky seen directly (clamped at 4), plus albedo / pi times the direct irradiance
    /// (emitters sampled by power, the environment by cosine-distributed directions) at the
    /// first opaque hit. Indirect light comes on top, so the real image is brighter.
    pub estimate: f32,
}

impl ViewCheck {
    /// Whether a scene seen like this makes a useful, lit image: there is light, at least 30%
    /// of the view is geometry and 4% objects, 85% of the hits are front faces, 5% of the
    /// hits are directly lit (and the direct-light estimate is positive), the view is not
    /// blocked within 0.6 ahead, and at most 25% of it is closer than 0.5.
    pub fn ok(&self) -> bool {
        self.has_light
            && self.geometry >= 0.3
            && self.objects >= 0.04
            && self.front >= 0.85
            && self.lit >= 0.05
            && self.clearance > 0.6
            && self.near <= 0.25
            && self.estimate > 0.0
    }
}

/// The brightest part of an environment (texels above 20 times its mean), as a directional
/// light: luminance-weighted mean direction and the irradiance it gives at normal incidence.
pub(super) struct Sun {
    dir: Vec3,
    irradiance: f32,
    /// Scaled luminance above which a texel belongs to the sun.
    threshold: f32,
}

pub(super) fn sun_of(e: &Environment) -> Option<Sun> {
    let mean = mean_radiance(e) / e.scale.max(1e-12);
    if mean.is_nan() || mean <= 0.0 {
        return None;
    }
    let threshold = 20.0 * mean;
    let (mut dir, mut irr) = (Vec3::ZERO, 0.0f32);
    let (w, h) = (e.width as f32, e.height as f32);
    for y in 0..e.height {
        let theta = (y as f32 + 0.5) / h * std::f32::consts::PI;
        let texel_sr = theta.sin() * (std::f32::consts::PI / h) * (std::f32::consts::TAU / w);
        for x in 0..e.width {
            let l = luminance(Vec3::from(e.pixels[(y * e.width + x) as usize]));
            if l > threshold {
                let phi = (x as f32 + 0.5) / w * std::f32::consts::TAU;
                let d = Vec3::new(theta.sin() * phi.sin(), theta.cos(), -theta.sin() * phi.cos());
                dir += d * l * texel_sr;
                irr += l * texel_sr;
            }
        }
    }
    (irr > 0.0).then(|| Sun {
        dir: (e.to_world * dir).normalize_or(Vec3::Y),
        irradiance: irr * e.scale,
        threshold: threshold * e.scale,
    })
}

/// Checks the view of `camera` on `scene` with its CPU BVH `bvh`; `objects` is the range of
/// object triangles, if known.
pub fn check_view(
    scene: &Scene,
    bvh: &SceneBvh,
    camera: &Camera,
    objects: Option<std::ops::Range<usize>>,
) -> ViewCheck {
    const N: u32 = 16;
    let (w, h) = scene.film;
    let g = &scene.geometry;
    let mats = &scene.materials;
    let emitted: Vec<f32> = mats
        .iter()
        .map(|m| m.emitted_luminance(&scene.textures))
        .collect();
    let tri_area = |t: usize| {
        let [a, b, c] = g.triangles[t].map(|i| g.positions[i as usize]);
        0.5 * (b - a).cross(c - a).length()
    };
    // Emissive triangles with their cumulative power.
    let mut emissive = Vec::new();
    let mut cdf = Vec::new();
    let mut power = 0.0f32;
    for t in 0..g.triangles.len() {
        let l = emitted[g.materials[t] as usize];
        let area = tri_area(t);
        if l > 0.0 && area > 0.0 {
            power += l * area;
            emissive.push(t);
            cdf.push(power);
        }
    }
    // Diffuse albedo (luminance) of each material: base colour times its texture's mean;
    // metals count half their reflectance.
    let albedo: Vec<f32> = mats
        .iter()
        .map(|m| {
            let mut c = Vec3::new(m.base_color[0], m.base_color[1], m.base_color[2]);
            if let Some(t) = m.base_color_texture.and_then(|t| scene.textures.get(t as usize)) {
                c *= t.mean_rgb();
            }
            let l = luminance(c).clamp(0.0, 1.0);
            if m.metallic >= 0.5 { 0.5 * l } else { l }
        })
        .collect();
    let env_power = scene.environment.as_ref().map(mean_radiance).unwrap_or(0.0);
    let has_light = !emissive.is_empty() || env_power > 0.0;
    let passes = |tri: usize| {
        let m = &mats[g.materials[tri] as usize];
        m.transmission > 0.0 || matches!(m.alpha, AlphaMode::Mask(_))
    };
    // First opaque hit (passing transmissive and cut-out surfaces), within tmax.
    let opaque_hit = |o: Vec3, d: Vec3, tmax: f32| -> Option<(usize, f32)> {
        let mut start = 0.0;
        for _ in 0..16 {
            let (slot, t) = bvh.intersect(o + d * start, d, tmax - start)?;
            let tri = bvh.order[slot as usize] as usize;
            if !passes(tri) {
                return Some((tri, start + t));
            }
            start += t + 1e-3;
            if start >= tmax {
                return None;
            }
        }
        None
    };
    let tri_normal = |t: usize| {
        let [a, b, c] = g.triangles[t].map(|i| g.positions[i as usize]);
        (b - a).cross(c - a).normalize_or_zero()
    };
    let scale = (scene.bounds().1 - scene.bounds().0).length().max(1e-3);
    let eps = 1e-4 * scale;
    let (mut hits, mut obj, mut front, mut lit, mut near) = (0u32, 0u32, 0u32, 0u32, 0u32);
    let mut estimate = 0.0f64;
    let env = scene.environment.as_ref();
    let sun = env.and_then(sun_of);
    let mut light_in_view = false;
    let mut rng = Rng::new(0x71e7);
    for j in 0..N {
        for i in 0..N {
            let px = Vec2::new(
                (i as f32 + 0.5) / N as f32 * w as f32,
                (j as f32 + 0.5) / N as f32 * h as f32,
            );
            let d = camera.ray_dir(px, w, h);
            let Some((slot, t)) = bvh.intersect(camera.position, d, f32::INFINITY) else {
                light_in_view |= env_power > 0.0;
                if let Some(e) = env {
                    estimate += luminance(e.radiance(d)).min(4.0) as f64;
                }
                continue;
            };
            hits += 1;
            near += (t < 0.5) as u32;
            let tri = bvh.order[slot as usize] as usize;
            if objects.as_ref().is_none_or(|r| r.contains(&tri)) {
                obj += 1;
            }
            let m = &mats[g.materials[tri] as usize];
            let n = tri_normal(tri);
            if n.dot(d) < 0.0 || m.double_sided || m.transmission > 0.0 {
                front += 1;
            }
            if emitted[g.materials[tri] as usize] > 0.0 {
                light_in_view = true;
                lit += 1;
                estimate += emitted[g.materials[tri] as usize].min(4.0) as f64;
                continue;
            }
            // Direct light at the first opaque hit along the ray.
            let Some((tri, t)) = (if passes(tri) {
                opaque_hit(camera.position, d, f32::INFINITY)
            } else {
                Some((tri, t))
            }) else {
                continue;
            };
            let mut n = tri_normal(tri);
            if n.dot(d) > 0.0 {
                n = -n;
            }
            let p = camera.position + d * t + n * eps;
            let mut irradiance = 0.0f32;
            // Emitters: 8 points chosen by power (triangle by power, uniform on it).
            const EMITTER_SAMPLES: u32 = 8;
            if power > 0.0 {
                for _ in 0..EMITTER_SAMPLES {
                    let x = rng.f() * power;
                    let k = cdf.partition_point(|&c| c <= x).min(emissive.len() - 1);
                    let e = emissive[k];
                    let [a, b, c] = g.triangles[e].map(|i| g.positions[i as usize]);
                    let (u, v) = (rng.f(), rng.f());
                    let (u, v) = if u + v > 1.0 { (1.0 - u, 1.0 - v) } else { (u, v) };
                    let q = a + (b - a) * u + (c - a) * v;
                    let to = q - p;
                    let dist2 = to.length_squared().max(1e-8);
                    let dist = dist2.sqrt();
                    let dir = to / dist;
                    let en = tri_normal(e);
                    let (cos_p, cos_e) = (dir.dot(n), en.dot(-dir));
                    if cos_p <= 0.0 || cos_e <= 0.0 {
                        continue;
                    }
                    if opaque_hit(p, dir, dist * (1.0 - 1e-3)).is_none_or(|(h, _)| h == e) {
                        // L cos cos / d^2 over the pdf (l area / power) / area.
                        irradiance += power * cos_p * cos_e / dist2;
                    }
                }
                irradiance /= EMITTER_SAMPLES as f32;
            }
            // Environment: 24 cosine-distributed directions.
            let mut is_lit = irradiance > 0.0;
            if let Some(e) = env.filter(|_| env_power > 0.0) {
                let (tx, ty) = {
                    let a = if n.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
                    let tx = n.cross(a).normalize();
                    (tx, n.cross(tx))
                };
                // The sun (the brightest texels) as one directional light; the cosine samples
                // below see the rest of the sky, clamped below the sun's level.
                if let Some(sun) = &sun {
                    let c = sun.dir.dot(n);
                    if c > 0.0 && opaque_hit(p, sun.dir, f32::INFINITY).is_none() {
                        irradiance += sun.irradiance * c;
                        is_lit = true;
                    }
                }
                let cap = sun.as_ref().map_or(f32::INFINITY, |s| s.threshold);
                let mut sum = 0.0;
                for _ in 0..24 {
                    let (r1, r2) = (rng.f(), rng.f());
                    let (s, c) = (std::f32::consts::TAU * r1).sin_cos();
                    let rr = r2.sqrt();
                    let dir = (tx * (rr * c) + ty * (rr * s) + n * (1.0 - r2).max(0.0).sqrt()).normalize();
                    if opaque_hit(p, dir, f32::INFINITY).is_none() {
                        is_lit = true;
                        sum += luminance(e.radiance(dir)).min(cap);
                    }
                }
                irradiance += std::f32::consts::PI * sum / 24.0;
            }
            lit += is_lit as u32;
            estimate += (albedo[g.materials[tri] as usize] * irradiance / std::f32::consts::PI) as f64;
        }
    }
    let total = (N * N) as f32;
    let clearance = bvh
        .intersect(camera.position, camera.basis().2, f32::INFINITY)
        .map(|(_, t)| t)
        .unwrap_or(f32::INFINITY);
    ViewCheck {
        geometry: hits as f32 / total,
        objects: obj as f32 / total,
        front: front as f32 / hits.max(1) as f32,
        lit: lit as f32 / hits.max(1) as f32,
        light_in_view,
        clearance,
        near: near as f32 / total,
        has_light,
        estimate: (estimate / total as f64) as f32,
    }
}
