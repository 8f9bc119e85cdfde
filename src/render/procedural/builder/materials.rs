//! Materials over the range the BSDF supports.

use glam::{Vec2, Vec3};

use super::*;
use crate::render::scene::{AlphaMode, Material, luminance};

impl Builder<'_> {
    /// A procedurally textured material: base colour, normal map, sometimes a roughness map.
    pub(in crate::render::procedural) fn textured(&mut self, pattern: Pattern, name: &str) -> Material {
        let r = &mut self.rng;
        let seed = r.sub() as u32;
        let a = colour(r, (0.1, 0.8), (0.35, 0.95));
        let b = colour(r, (0.0, 0.6), (0.1, 0.7));
        let mortar = colour(r, (0.0, 0.15), (0.6, 0.9));
        let variation = r.range(0.05, 0.35);
        // Per texel: the colour and the height.
        let (strength, field): (f32, Vec<(Vec3, f32)>) = match pattern {
            Pattern::Checker => {
                let cell = [8u32, 16, 32][r.index(3)];
                let groove = r.chance(0.5);
                let strength = if groove {
                    r.range(0.5, 2.0)
                } else {
                    r.range(0.2, 0.8)
                };
                let field = texels(|x, y| {
                    let on = ((x / cell) + (y / cell)).is_multiple_of(2);
                    let n = fbm(x as f32, y as f32, 16, 3, seed);
                    let edge = (x % cell)
                        .min(cell - 1 - x % cell)
                        .min((y % cell).min(cell - 1 - y % cell));
                    (
                        if on { a } else { b } * (1.0 - variation * 0.5 + variation * n),
                        if groove { (edge as f32).min(2.0) } else { 0.0 } + n * 2.0,
                    )
                });
                (strength, field)
            }
            Pattern::Stripes => {
                let period = [8u32, 16, 32, 64][r.index(4)];
                let diagonal = r.chance(0.3);
                let vertical = r.chance(0.5);
                let duty = r.range(0.3, 0.7);
                let strength = r.range(0.5, 3.0);
                let field = texels(|x, y| {
                    let s = if diagonal {
                        (x + y) % period
                    } else if vertical {
                        x % period
                    } else {
                        y % period
                    };
                    let t = s as f32 / period as f32;
                    let n = fbm(x as f32, y as f32, 32, 2, seed);
                    (
                        if t < duty { a } else { b } * (1.0 - variation * 0.3 + variation * 0.3 * n),
                        (t * std::f32::consts::TAU).sin() * period as f32 / 8.0,
                    )
                });
                (strength, field)
            }
            Pattern::Noise => {
                let period = [4u32, 8, 16][r.index(3)];
                let sharp = r.range(1.0, 4.0);
                let strength = r.range(2.0, 8.0);
                let field = texels(|x, y| {
                    let n = fbm(x as f32, y as f32, period, 4, seed);
                    let t = ((n - 0.5) * sharp + 0.5).clamp(0.0, 1.0);
                    (a.lerp(b, t), n * 4.0)
                });
                (strength, field)
            }
            Pattern::Bricks => {
                let (bw, bh) = ([16u32, 32][r.index(2)], [8u32, 16][r.index(2)]);
                let bw = bw.max(bh);
                let m = r.int(1, 2);
                let strength = r.range(0.6, 1.5);
                let field = texels(|x, y| {
                    let row = y / bh;
                    let xo = (x + if row % 2 == 1 { bw / 2 } else { 0 }) % TEX;
                    let (bx, by) = (xo % bw, y % bh);
                    let d = bx.min(bw - 1 - bx).min(by.min(bh - 1 - by));
                    let n = fbm(x as f32, y as f32, 32, 3, seed);
                    if d < m {
                        (mortar * (0.9 + 0.1 * n), 0.0)
                    } else {
                        let v = hash3(xo / bw, row, seed);
                        (
                            a * (1.0 - variation + 2.0 * variation * v) * (0.85 + 0.15 * n),
                            (d - m + 1).min(2) as f32 + n,
                        )
                    }
                });
                (strength, field)
            }
            Pattern::Tiles => {
                let cell = [16u32, 32, 64][r.index(3)];
                let m = r.int(1, 2);
                let strength = r.range(0.6, 1.5);
                let field = texels(|x, y| {
                    let (tx, ty) = (x % cell, y % cell);
                    let d = tx.min(cell - 1 - tx).min(ty.min(cell - 1 - ty));
                    let v = hash3(x / cell, y / cell, seed);
                    if d < m {
                        (mortar * 0.8, 0.0)
                    } else {
                        (
                            if v < 0.5 { a } else { b } * (1.0 - variation * 0.5 + variation * v),
                            (d - m + 1).min(3) as f32,
                        )
                    }
                });
                (strength, field)
            }
        };
        let (col, height): (Vec<Vec3>, Vec<f32>) = field.into_iter().unzip();
        let id = format!("{name} {}", pattern.name());
        let base = self.texture(texture(format!("{id} colour"), true, |x, y| {
            let c = col[(y * TEX + x) as usize].min(Vec3::splat(0.9));
            [
                linear_to_srgb_u8(c.x),
                linear_to_srgb_u8(c.y),
                linear_to_srgb_u8(c.z),
                255,
            ]
        }));
        let normal = self.texture(normal_map(format!("{id} normal"), &height, strength));
        let r = &mut self.rng;
        let glossy = r.chance(0.35);
        let (r0, r1) = if glossy {
            (r.range(0.05, 0.3), r.range(0.3, 0.6))
        } else {
            (r.range(0.5, 0.8), r.range(0.8, 1.0))
        };
        let rough_map = r.chance(0.5);
        let normal_scale = r.range(0.5, 1.0);
        let mr = if rough_map {
            let s = seed ^ 0xabc;
            Some(self.texture(texture(format!("{id} metal-rough"), false, |x, y| {
                let n = fbm(x as f32, y as f32, 8, 3, s);
                [0, ((r0 + (r1 - r0) * n) * 255.0) as u8, 0, 255]
            })))
        } else {
            None
        };
        Material {
            name: id,
            base_color: [1.0; 4],
            base_color_texture: Some(base),
            metallic: 0.0,
            roughness: if rough_map { 1.0 } else { 0.5 * (r0 + r1) },
            metallic_roughness_texture: mr,
            normal_texture: Some(normal),
            normal_scale,
            ..Material::diffuse("", [1.0; 3])
        }
    }

    /// A cut-out material: leaves or a grille, alpha-masked, double-sided.
    pub(in crate::render::procedural) fn cutout(&mut self, leaves: bool) -> Material {
        let r = &mut self.rng;
        let seed = r.sub();
        let (tex, name) = if leaves {
            let mut rr = Rng::new(seed);
            let n = rr.int(14, 30);
            let leaves: Vec<(Vec2, Vec2, f32, Vec3)> = (0..n)
                .map(|_| {
                    (
                        Vec2::new(rr.range(0.0, TEX as f32), rr.range(0.0, TEX as f32)),
                        Vec2::new(rr.range(8.0, 18.0), rr.range(3.5, 7.0)),
                        rr.range(0.0, std::f32::consts::PI),
                        colour(&mut rr, (0.5, 0.9), (0.25, 0.7)) * Vec3::new(0.6, 1.0, 0.5),
                    )
                })
                .collect();
            let t = texture("leaves".into(), true, |x, y| {
                for (c, rad, ang, col) in &leaves {
                    let mut d = Vec2::new(x as f32 + 0.5, y as f32 + 0.5) - *c;
                    d = (d + Vec2::splat(TEX as f32 * 0.5)).rem_euclid(Vec2::splat(TEX as f32))
                        - Vec2::splat(TEX as f32 * 0.5);
                    let (s, co) = ang.sin_cos();
                    let l = Vec2::new(co * d.x + s * d.y, -s * d.x + co * d.y) / *rad;
                    if l.length_squared() < 1.0 {
                        let vein = if l.y.abs() < 0.08 { 0.6 } else { 1.0 };
                        let c = *col * vein;
                        return [
                            linear_to_srgb_u8(c.x),
                            linear_to_srgb_u8(c.y),
                            linear_to_srgb_u8(c.z),
                            255,
                        ];
                    }
                }
                [40, 60, 30, 0]
            });
            (t, "leaves")
        } else {
            let cell = [8u32, 16, 32][r.index(3)];
            let bar = r.int(2, cell / 4 + 1);
            let round = r.chance(0.5);
            let c = colour(r, (0.0, 0.3), (0.2, 0.8));
            let px = [
                linear_to_srgb_u8(c.x),
                linear_to_srgb_u8(c.y),
                linear_to_srgb_u8(c.z),
            ];
            let t = texture("grille".into(), true, |x, y| {
                let (gx, gy) = (x % cell, y % cell);
                let solid = if round {
                    let d = Vec2::new(gx as f32 + 0.5, gy as f32 + 0.5) - Vec2::splat(cell as f32 * 0.5);
                    d.length() > cell as f32 * 0.5 - bar as f32 * 0.5
                } else {
                    gx < bar || gy < bar
                };
                [px[0], px[1], px[2], if solid { 255 } else { 0 }]
            });
            (t, "grille")
        };
        let metal = !leaves && self.rng.chance(0.5);
        let rough = self.rng.range(0.2, 0.9);
        let t = self.texture(tex);
        Material {
            name: name.into(),
            base_color_texture: Some(t),
            alpha: AlphaMode::Mask(0.5),
            double_sided: true,
            metallic: if metal { 1.0 } else { 0.0 },
            roughness: rough,
            ..Material::diffuse(name, [1.0; 3])
        }
    }

    /// A random metal: a named conductor's F0 (DESIGN scenes table), roughness 0-1.
    pub(in crate::render::procedural) fn metal(&mut self) -> Material {
        const F0: [(&str, [f32; 3]); 7] = [
            ("gold", [0.967, 0.802, 0.324]),
            ("silver", [0.975, 0.958, 0.906]),
            ("aluminium", [0.928, 0.918, 0.919]),
            ("copper", [0.952, 0.620, 0.511]),
            ("chrome", [0.688, 0.649, 0.687]),
            ("brass", [0.525, 0.393, 0.310]),
            ("tungsten", [0.575, 0.478, 0.433]),
        ];
        let r = &mut self.rng;
        let (name, f0) = F0[r.index(F0.len())];
        let roughness = match r.int(0, 3) {
            0 => 0.0,
            1 => r.range(0.0, 0.15),
            2 => r.range(0.15, 0.5),
            _ => r.range(0.5, 1.0),
        };
        Material::metal(&format!("{name} r{roughness:.2}"), f0, roughness)
    }

    pub(in crate::render::procedural) fn glass(&mut self, thin: bool) -> Material {
        let r = &mut self.rng;
        let roughness = if r.chance(0.6) { 0.0 } else { r.range(0.02, 0.5) };
        let ior = r.range(1.3, 1.8);
        let tint = if r.chance(0.4) {
            colour(r, (0.2, 0.7), (0.7, 1.0))
        } else {
            Vec3::ONE
        };
        let (attenuation_color, attenuation_distance) = if !thin && r.chance(0.4) {
            (colour(r, (0.3, 0.8), (0.5, 0.95)).to_array(), r.range(0.2, 2.0))
        } else {
            ([1.0; 3], f32::INFINITY)
        };
        let name = format!(
            "{} glass ior {ior:.2} r{roughness:.2}",
            if thin { "thin" } else { "solid" }
        );
        Material {
            attenuation_color,
            attenuation_distance,
            ..Material::glass(&name, tint.to_array(), roughness, ior, thin)
        }
    }

    pub(in crate::render::procedural) fn plain(&mut self, glossy: bool) -> Material {
        let r = &mut self.rng;
        let c = colour(r, (0.0, 0.9), (0.2, 0.95));
        let roughness = if glossy {
            r.range(0.0, 0.55)
        } else {
            r.range(0.65, 1.0)
        };
        let specular = if !glossy && r.chance(0.3) { 0.0 } else { 1.0 };
        Material {
            roughness,
            specular,
            ..Material::diffuse(if glossy { "glossy" } else { "diffuse" }, c.to_array())
        }
    }

    /// An emitter of radiance `radiance` (luminance) with a random tint.
    pub(in crate::render::procedural) fn emitter(&mut self, radiance: f32, name: &str) -> Material {
        let r = &mut self.rng;
        let tint = match r.int(0, 3) {
            0 => Vec3::new(1.0, 0.85, 0.65),
            1 => Vec3::new(0.85, 0.92, 1.0),
            2 => colour(r, (0.2, 0.8), (0.8, 1.0)),
            _ => Vec3::ONE,
        };
        let tint = tint / luminance(tint).max(1e-3);
        Material {
            emissive: (tint * radiance).to_array(),
            ..Material::diffuse(name, [0.8; 3])
        }
    }

    /// A material for `usage`, over the range the BSDF supports.
    pub(in crate::render::procedural) fn random_material(&mut self, usage: Use) -> u32 {
        let m = match usage {
            Use::Floor => match self.rng.weighted(&[6.0, 2.0, 1.0, 1.0]) {
                0 => {
                    let p = [
                        Pattern::Tiles,
                        Pattern::Checker,
                        Pattern::Noise,
                        Pattern::Bricks,
                        Pattern::Stripes,
                    ][self.rng.weighted(&[3.0, 2.0, 3.0, 1.0, 1.0])];
                    self.textured(p, "floor")
                }
                1 => {
                    let mut m = self.plain(false);
                    brighten(&mut m, 0.2);
                    m
                }
                2 => {
                    let mut m = self.plain(true);
                    brighten(&mut m, 0.2);
                    m
                }
                _ => {
                    let mut m = self.metal();
                    m.roughness = m.roughness.max(0.3);
                    m
                }
            },
            Use::Wall => match self.rng.weighted(&[5.0, 3.0, 1.0]) {
                0 => {
                    let mut m = self.plain(false);
                    brighten(&mut m, 0.3);
                    m
                }
                1 => {
                    let p = [
                        Pattern::Bricks,
                        Pattern::Stripes,
                        Pattern::Tiles,
                        Pattern::Noise,
                        Pattern::Checker,
                    ][self.rng.weighted(&[3.0, 2.0, 2.0, 2.0, 1.0])];
                    self.textured(p, "wall")
                }
                _ => {
                    let mut m = self.plain(true);
                    brighten(&mut m, 0.3);
                    m
                }
            },
            Use::Closed | Use::Open => {
                let w = [
                    3.0,                                          // diffuse
                    3.0,                                          // glossy
                    5.0,                                          // textured
                    4.0,                                          // metal
                    if usage == Use::Closed { 2.5 } else { 0.0 }, // solid glass
                    1.0,                                          // thin glass
                    0.8,                                          // emitter
                ];
                match self.rng.weighted(&w) {
                    0 => self.plain(false),
                    1 => self.plain(true),
                    2 => {
                        let p = Pattern::ALL[self.rng.index(5)];
                        self.textured(p, "object")
                    }
                    3 => self.metal(),
                    4 => self.glass(false),
                    5 => self.glass(true),
                    _ => {
                        let l = self.rng.range(2.0, 15.0);
                        self.emitter(l, "glowing")
                    }
                }
            }
        };
        self.material(m)
    }
}
