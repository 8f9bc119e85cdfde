//! Environment maps, the procedural sky, area and small lights.

use glam::{Mat3, Vec2, Vec3};

use super::*;
use crate::render::procedural::shapes::*;
use crate::render::scene::{Environment, luminance};

impl Builder<'_> {
    /// An environment: a map from the props (randomly rotated, normalised to a mean
    /// radiance of about `level`), else a procedural sky with a sun.
    pub(in crate::render::procedural) fn environment(&mut self, level: f32) -> Environment {
        let n = self.lib.environments.len();
        if n > 0 && self.rng.chance(0.75) {
            let i = self.rng.index(n);
            let rot = self.rng.range(0.0, std::f32::consts::TAU);
            let gain = self.rng.range(0.7, 1.4);
            if let Some(mut e) = self.lib.environment(i, &mut self.warnings) {
                let mean = mean_radiance(&e);
                e.scale = if mean > 0.0 { level * gain / mean } else { 1.0 };
                e.to_world = Mat3::from_rotation_y(rot);
                return e;
            }
        }
        self.sky(level)
    }

    /// A procedural sky: zenith-to-horizon gradient, a ground below the horizon, and
    /// (mostly) a sun disc of 0.7-3 degrees radius whose irradiance is 2-10 times the sky's.
    pub(in crate::render::procedural) fn sky(&mut self, level: f32) -> Environment {
        let r = &mut self.rng;
        let (w, h) = (512u32, 256u32);
        let elevation = r.range(8.0, 70.0).to_radians();
        let azimuth = r.range(0.0, std::f32::consts::TAU);
        let sun_dir = Vec3::new(
            elevation.cos() * azimuth.sin(),
            elevation.sin(),
            -elevation.cos() * azimuth.cos(),
        );
        let has_sun = r.chance(0.8);
        let sun_radius = r.range(0.7, 3.0).to_radians();
        let sun_ratio = r.range(2.0, 10.0);
        let overcast = r.range(0.0, 1.0);
        let zenith = Vec3::new(0.2, 0.4, 1.0).lerp(Vec3::splat(0.8), overcast);
        let horizon =
            Vec3::new(0.9, 0.92, 1.0).lerp(Vec3::new(1.0, 0.8, 0.6), r.range(0.0, 0.5 * (1.0 - overcast)));
        let ground = colour(r, (0.1, 0.4), (0.15, 0.4));
        let warm = (1.0 - elevation / 1.2).clamp(0.0, 1.0);
        let sun_colour = Vec3::ONE.lerp(Vec3::new(1.0, 0.7, 0.4), warm);
        let dir = |x: u32, y: u32| {
            let u = (x as f32 + 0.5) / w as f32;
            let v = (y as f32 + 0.5) / h as f32;
            let (theta, phi) = (v * std::f32::consts::PI, u * std::f32::consts::TAU);
            Vec3::new(theta.sin() * phi.sin(), theta.cos(), -theta.sin() * phi.cos())
        };
        let texel_sr = |y: u32| {
            let theta = (y as f32 + 0.5) / h as f32 * std::f32::consts::PI;
            theta.sin() * (std::f32::consts::PI / h as f32) * (std::f32::consts::TAU / w as f32)
        };
        let mut pixels = Vec::with_capacity((w * h) as usize);
        let (mut sky_irr, mut sun_sr) = (0.0f32, 0.0f32);
        for y in 0..h {
            for x in 0..w {
                let d = dir(x, y);
                let c = if d.y > 0.0 {
                    let t = d.y.powf(0.4);
                    let glow = if has_sun {
                        (d.dot(sun_dir).max(0.0)).powf(8.0) * 0.6 * (1.0 - overcast)
                    } else {
                        0.0
                    };
                    horizon.lerp(zenith, t) + sun_colour * glow
                } else {
                    ground * (0.5 + 0.5 * (1.0 + d.y))
                };
                if d.y > 0.0 {
                    sky_irr += luminance(c) * d.y * texel_sr(y);
                }
                if has_sun && d.dot(sun_dir) > sun_radius.cos() {
                    sun_sr += texel_sr(y);
                }
                pixels.push(c.to_array());
            }
        }
        if has_sun && sun_sr > 0.0 {
            // Radiance such that the sun's irradiance (at normal incidence) is sun_ratio
            // times the sky's on a horizontal plane.
            let l = sun_ratio * sky_irr * (1.0 - 0.8 * overcast) / sun_sr;
            for y in 0..h {
                for x in 0..w {
                    if dir(x, y).dot(sun_dir) > sun_radius.cos() {
                        pixels[(y * w + x) as usize] = (sun_colour * l).to_array();
                    }
                }
            }
        }
        let source = format!("procedural sky (sun {:.0} deg up)", elevation.to_degrees());
        let mut e = Environment::from_pixels(source, w, h, pixels);
        let mean = mean_radiance(&e);
        e.scale = if mean > 0.0 { level / mean } else { 1.0 };
        e
    }

    /// An area light: a rectangle centred at `c` with edges `u`, `v` (facing `u x v`) of
    /// total power about `power`.
    pub(in crate::render::procedural) fn area_light(&mut self, c: Vec3, u: Vec3, v: Vec3, power: f32) {
        let area = u.cross(v).length().max(1e-4);
        let l = (power / (std::f32::consts::PI * area)).clamp(0.5, 5000.0);
        let m = self.emitter(l, "area light");
        let m = self.material(m);
        push_rect(
            &mut self.scene.geometry,
            c - 0.5 * (u + v),
            u,
            v,
            Vec2::ZERO,
            1.0,
            m,
        );
    }

    /// A small bright sphere (hard shadows) of power about `power`.
    pub(in crate::render::procedural) fn small_light(&mut self, c: Vec3, power: f32) {
        let r = self.rng.range(0.015, 0.05);
        let l = power / (4.0 * std::f32::consts::PI * std::f32::consts::PI * r * r);
        let m = self.emitter(l.min(20000.0), "small light");
        let m = self.material(m);
        push_sphere(&mut self.scene.geometry, c, r, 12, 6, 1.0, m);
    }

    /// Interior lights of a room `[-w/2, w/2] x [0, h] x [-d/2, d/2]` (as seen from inside).
    pub(in crate::render::procedural) fn ceiling_lights(
        &mut self,
        w: f32,
        d: f32,
        h: f32,
        area_lights: u32,
        small: u32,
        power: f32,
    ) {
        let total = (area_lights + small).max(1) as f32;
        for _ in 0..area_lights {
            let r = &mut self.rng;
            let size = r.range(0.2, 2.0f32.min(0.5 * w.min(d)));
            let aspect = r.range(0.25, 1.0);
            let (sx, sz) = if r.chance(0.5) {
                (size, size * aspect)
            } else {
                (size * aspect, size)
            };
            let cx = r.range(-0.5 * w + sx, 0.5 * w - sx);
            let cz = r.range(-0.5 * d + sz, 0.5 * d - sz);
            let p = power / total * r.range(0.5, 1.5);
            // Facing down: u = +x, v = +z gives x cross z = -y.
            self.area_light(Vec3::new(cx, h - 0.01, cz), Vec3::X * sx, Vec3::Z * sz, p);
        }
        for _ in 0..small {
            let r = &mut self.rng;
            let c = Vec3::new(
                r.range(-0.4 * w, 0.4 * w),
                h - r.range(0.3, (0.5 * h).max(0.35)),
                r.range(-0.4 * d, 0.4 * d),
            );
            let p = power / total * r.range(0.5, 1.5);
            self.small_light(c, p);
            self.placed.push(Footprint {
                c: Vec2::new(c.x, c.z),
                r: 0.1,
                y0: c.y - 0.1,
                y1: h,
            });
        }
    }
}
