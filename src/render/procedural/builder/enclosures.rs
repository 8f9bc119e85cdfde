//! Enclosures: rooms with windows, open ground, corridors, steps.

use glam::{Quat, Vec2, Vec3};

use super::*;
use crate::render::packed::straight_through;
use crate::render::procedural::shapes::*;
use crate::render::scene::{Material, Portal};

impl Builder<'_> {
    /// Builds the scene of enclosure kind `kind`.
    pub(in crate::render::procedural) fn build(&mut self, kind: Enclosure) {
        self.enclosure = kind;
        match kind {
            Enclosure::Room => self.room(),
            Enclosure::OpenGround => self.open_ground(),
            Enclosure::Corridor => self.corridor(),
            Enclosure::Steps => self.steps(),
        }
        self.object_tris = self.tris()..self.tris();
        let budget = self.areas.iter().map(Area::size).sum::<f32>();
        let max = ((budget / 1.2) as u32).clamp(5, 37);
        let n = self.rng.int(5, max);
        self.populate(n);
        self.object_tris.end = self.tris();
        self.choose_camera_seed();
    }

    /// Windows for a wall `width x height`: up to `n` non-overlapping holes.
    pub(in crate::render::procedural) fn windows(
        &mut self,
        width: f32,
        height: f32,
        n: u32,
    ) -> Vec<[f32; 4]> {
        let mut holes: Vec<[f32; 4]> = Vec::new();
        for _ in 0..n * 4 {
            if holes.len() as u32 >= n {
                break;
            }
            let r = &mut self.rng;
            let ww = r.range(0.6, (0.45 * width).clamp(0.7, 2.5));
            let sill = r.range(0.4, 1.0);
            let wh = r.range(0.7, (height - sill - 0.3).max(0.75));
            if sill + wh > height - 0.15 || ww > width - 0.4 {
                continue;
            }
            let s0 = r.range(0.2, width - ww - 0.2);
            let hole = [s0, s0 + ww, sill, sill + wh];
            if holes.iter().all(|o| hole[1] + 0.3 < o[0] || o[1] + 0.3 < hole[0]) {
                holes.push(hole);
            }
        }
        holes
    }

    /// Four walls, floor and ceiling of `[-w/2, w/2] x [0, h] x [-d/2, d/2]`, with windows
    /// on some walls. Returns the windows as (wall origin, u, v, hole).
    #[allow(clippy::type_complexity)]
    pub(in crate::render::procedural) fn box_room(
        &mut self,
        w: f32,
        d: f32,
        h: f32,
        windows: u32,
        open_back: bool,
    ) -> Vec<(Vec3, Vec3, Vec3, [f32; 4])> {
        let floor = self.random_material(Use::Floor);
        let wall = self.random_material(Use::Wall);
        let wall2 = if self.rng.chance(0.4) {
            self.random_material(Use::Wall)
        } else {
            wall
        };
        let ceiling = {
            let c = colour(&mut self.rng, (0.0, 0.1), (0.7, 0.95));
            self.material(Material::diffuse("ceiling", c.to_array()))
        };
        let tile = self.rng.range(0.6, 2.0);
        let wtile = self.rng.range(0.8, 2.5);
        let g = &mut self.scene.geometry;
        push_rect(
            g,
            Vec3::new(-0.5 * w, 0.0, 0.5 * d),
            Vec3::X * w,
            Vec3::NEG_Z * d,
            Vec2::ZERO,
            tile,
            floor,
        );
        push_rect(
            g,
            Vec3::new(-0.5 * w, h, -0.5 * d),
            Vec3::X * w,
            Vec3::Z * d,
            Vec2::ZERO,
            1.0,
            ceiling,
        );
        // (origin, u, v, length, material): back, front, left, right; all face inwards.
        let walls = [
            (Vec3::new(-0.5 * w, 0.0, -0.5 * d), Vec3::X, w, wall),
            (Vec3::new(0.5 * w, 0.0, 0.5 * d), Vec3::NEG_X, w, wall2),
            (Vec3::new(-0.5 * w, 0.0, 0.5 * d), Vec3::NEG_Z, d, wall2),
            (Vec3::new(0.5 * w, 0.0, -0.5 * d), Vec3::Z, d, wall),
        ];
        let mut per_wall = [0u32; 4];
        for _ in 0..windows {
            // Mostly not on the front wall (behind the camera).
            per_wall[[0, 2, 3, 1, 0][self.rng.index(5)]] += 1;
        }
        let mut out = Vec::new();
        for (i, (o, u, len, m)) in walls.into_iter().enumerate() {
            let mut holes = self.windows(len, h, per_wall[i]);
            if i == 0 && open_back {
                let m = (0.1 * len).min(0.4);
                holes = vec![[m, len - m, 0.0, h - 0.3]];
            }
            push_wall(&mut self.scene.geometry, o, u, Vec3::Y, len, h, &holes, wtile, m);
            for hole in holes {
                out.push((o, u, Vec3::Y, hole));
            }
        }
        self.floor_area = w * d;
        out
    }

    /// Panes, grilles and outside emitters of windows.
    pub(in crate::render::procedural) fn dress_windows(
        &mut self,
        windows: &[(Vec3, Vec3, Vec3, [f32; 4])],
        outside_emitters: bool,
        power: f32,
    ) {
        let pane = self.rng.chance(0.5);
        let grille = self.rng.chance(0.25);
        let glass = if pane { Some(self.glass(true)) } else { None };
        let glass = glass.map(|mut g| {
            g.roughness = if self.rng.chance(0.7) { 0.0 } else { g.roughness };
            self.material(g)
        });
        let grille = if grille {
            let m = self.cutout(false);
            Some(self.material(m))
        } else {
            None
        };
        let n_win = windows.len().max(1) as f32;
        for &(o, u, v, [s0, s1, t0, t1]) in windows {
            let inward = u.cross(v);
            let corner = o + u * s0 + v * t0;
            let (du, dv) = (u * (s1 - s0), v * (t1 - t0));
            let paned = glass.is_some() && t0 > 0.0;
            // Shadow rays pass smooth thin panes (straight through), not rough ones.
            let clear = glass.is_none_or(|m| straight_through(&self.scene.materials[m as usize]));
            if (!paned || clear)
                && let Some(env) = self.scene.environment.as_mut()
            {
                // An open or clear window lets the environment in: sample it through the
                // opening.
                env.portals.push(Portal { corner, u: du, v: dv });
            }
            if let Some(m) = glass
                && paned
            {
                push_rect(
                    &mut self.scene.geometry,
                    corner + inward * 0.02,
                    du,
                    dv,
                    Vec2::ZERO,
                    1.0,
                    m,
                );
            }
            if let Some(m) = grille
                && t0 > 0.0
            {
                push_rect(
                    &mut self.scene.geometry,
                    corner + inward * 0.05,
                    du,
                    dv,
                    Vec2::ZERO,
                    0.5,
                    m,
                );
            }
            if outside_emitters {
                let dist = self.rng.range(0.3, 3.0);
                let grow = 1.0 + dist;
                let c = corner + 0.5 * (du + dv) - inward * dist;
                let p = power / n_win * self.rng.range(0.6, 1.4);
                self.area_light(c, du * grow, dv * grow, p);
            }
        }
    }

    pub(in crate::render::procedural) fn room(&mut self) {
        self.enclosure = Enclosure::Room;
        let r = &mut self.rng;
        let (w, d, h) = (r.range(4.0, 9.0), r.range(4.0, 9.0), r.range(2.6, 4.0));
        let windows = [0, 1, 1, 2, 2, 3][r.index(6)];
        let outside_emitters = windows > 0 && r.chance(0.4);
        let k = r.range(1.5, 6.0);
        let power = k * w * d;
        let wins = self.box_room(w, d, h, windows, false);
        if windows > 0 && !outside_emitters {
            let level = self.rng.range(1.5, 4.0);
            self.scene.environment = Some(self.environment(level));
        }
        self.dress_windows(&wins, outside_emitters, power * 1.5);
        let (mut area, mut small) = (self.rng.int(0, 3), self.rng.int(0, 2));
        if windows == 0 && area + small == 0 {
            area = 1;
        }
        if windows > 0 && self.rng.chance(0.4) {
            area = 0;
            small = 0;
        }
        self.ceiling_lights(w, d, h, area, small, power);
        self.maybe_wall_panel(w, d, h, power);
        self.areas.push(Area {
            min: Vec2::new(-0.5 * w + 0.3, -0.5 * d + 0.3),
            max: Vec2::new(0.5 * w - 0.3, 0.5 * d - 0.3),
            y: 0.0,
        });
        self.camera_region = CameraRegion {
            min: Vec3::new(-0.5 * w + 0.4, 1.1, -0.5 * d + 0.4),
            max: Vec3::new(0.5 * w - 0.4, (h - 0.4).min(2.0), 0.5 * d - 0.4),
        };
        self.indoor = true;
    }

    /// Sometimes an emissive panel on a side wall.
    pub(in crate::render::procedural) fn maybe_wall_panel(&mut self, w: f32, d: f32, h: f32, power: f32) {
        if !self.rng.chance(0.2) {
            return;
        }
        let r = &mut self.rng;
        let (pw, ph) = (r.range(0.3, 1.5), r.range(0.2, 0.8));
        let y = r.range(1.0, (h - ph - 0.2).max(1.05));
        let z = r.range(-0.5 * d + pw, 0.5 * d - pw);
        let p = power * r.range(0.2, 0.6);
        // On the left wall (x = -w/2), facing +x: u = -z, v = +y.
        self.area_light(
            Vec3::new(-0.5 * w + 0.01, y + 0.5 * ph, z),
            Vec3::NEG_Z * pw,
            Vec3::Y * ph,
            p,
        );
    }

    pub(in crate::render::procedural) fn open_ground(&mut self) {
        self.enclosure = Enclosure::OpenGround;
        self.indoor = false;
        let level = self.rng.range(0.6, 2.0);
        self.scene.environment = Some(self.environment(level));
        let ground = self.random_material(Use::Floor);
        let tile = self.rng.range(0.8, 3.0);
        let s = 40.0;
        push_rect(
            &mut self.scene.geometry,
            Vec3::new(-s, 0.0, s),
            Vec3::X * 2.0 * s,
            Vec3::NEG_Z * 2.0 * s,
            Vec2::ZERO,
            tile,
            ground,
        );
        let radius = self.rng.range(3.0, 7.0);
        // Some architecture: pillars or a low wall behind the objects.
        if self.rng.chance(0.5) {
            let m = self.random_material(Use::Wall);
            let n = self.rng.int(2, 6);
            let round = self.rng.chance(0.5);
            for i in 0..n {
                let x = -radius + 2.0 * radius * (i as f32 + 0.5) / n as f32;
                let z = -radius - self.rng.range(0.5, 1.5);
                let ph = self.rng.range(1.5, 4.0);
                if round {
                    push_cylinder(
                        &mut self.scene.geometry,
                        Vec3::new(x, 0.0, z),
                        0.25,
                        ph,
                        24,
                        1.0,
                        m,
                    );
                } else {
                    push_box(
                        &mut self.scene.geometry,
                        Vec3::new(x, 0.5 * ph, z),
                        Vec3::new(0.25, 0.5 * ph, 0.25),
                        Quat::IDENTITY,
                        1.0,
                        m,
                    );
                }
            }
        } else if self.rng.chance(0.5) {
            let m = self.random_material(Use::Wall);
            let wh = self.rng.range(0.8, 2.5);
            let z = -radius - 0.5;
            push_box(
                &mut self.scene.geometry,
                Vec3::new(0.0, 0.5 * wh, z),
                Vec3::new(radius, 0.5 * wh, 0.15),
                Quat::IDENTITY,
                1.5,
                m,
            );
        }
        // Dusk: a dim environment with lamps.
        if self.rng.chance(0.25) {
            if let Some(e) = &mut self.scene.environment {
                e.scale *= 0.15;
            }
            let n = self.rng.int(1, 3);
            for _ in 0..n {
                let c = Vec3::new(
                    self.rng.range(-radius, radius),
                    self.rng.range(1.5, 3.0),
                    self.rng.range(-radius, radius),
                );
                let p = self.rng.range(30.0, 150.0);
                if self.rng.chance(0.5) {
                    self.small_light(c, p);
                } else {
                    let s = self.rng.range(0.3, 1.0);
                    self.area_light(c, Vec3::X * s, Vec3::Z * s, p);
                }
                self.placed.push(Footprint {
                    c: Vec2::new(c.x, c.z),
                    r: 0.3,
                    y0: c.y - 0.3,
                    y1: c.y + 0.3,
                });
            }
        }
        self.areas.push(Area {
            min: Vec2::splat(-radius),
            max: Vec2::splat(radius),
            y: 0.0,
        });
        self.floor_area = 4.0 * radius * radius;
        let far = radius + self.rng.range(2.0, 6.0);
        self.camera_region = CameraRegion {
            min: Vec3::new(-far, 0.6, radius * 0.5),
            max: Vec3::new(far, 3.0, far),
        };
    }

    pub(in crate::render::procedural) fn corridor(&mut self) {
        self.enclosure = Enclosure::Corridor;
        self.indoor = true;
        let r = &mut self.rng;
        let (w, l, h) = (r.range(1.8, 3.2), r.range(10.0, 28.0), r.range(2.4, 3.4));
        let open_end = r.chance(0.3);
        let side_windows = if r.chance(0.4) { r.int(1, 4) } else { 0 };
        let lamps = r.int(0, 2); // 0: area row, 1: bulbs, 2: both
        // Built as a room of width w and depth l.
        let wins = self.box_room(w, l, h, 0, open_end);
        // Side windows on the right wall (x = +w/2, u = +z).
        let mut side = Vec::new();
        if side_windows > 0 {
            side = self.windows(l, h, side_windows);
            // Rebuild the right wall with holes: remove its plain version (the last pieces
            // pushed by box_room for wall 3 are replaced by a new wall).
        }
        let power = self.rng.range(1.5, 5.0) * w * l;
        if open_end || !side.is_empty() {
            let level = self.rng.range(1.0, 3.0);
            self.scene.environment = Some(self.environment(level));
        }
        if !side.is_empty() {
            self.cut_right_wall(w, l, h, &side);
        }
        let mut all: Vec<(Vec3, Vec3, Vec3, [f32; 4])> = wins;
        for hole in side {
            all.push((Vec3::new(0.5 * w, 0.0, -0.5 * l), Vec3::Z, Vec3::Y, hole));
        }
        let outside = self.scene.environment.is_none() && !all.is_empty();
        self.dress_windows(&all, outside, power);
        let spacing = self.rng.range(2.5, 5.0);
        let count = ((l / spacing) as u32).max(1);
        let lit = self.scene.environment.is_some();
        for i in 0..count {
            let z = -0.5 * l + (i as f32 + 0.5) * l / count as f32;
            let p = power / count as f32;
            if lamps != 1 {
                let sx = self.rng.range(0.2, 0.6) * w;
                let sz = self.rng.range(0.2, 1.0);
                self.area_light(Vec3::new(0.0, h - 0.01, z), Vec3::X * sx, Vec3::Z * sz, p);
            }
            if lamps >= 1 && !(lit && self.rng.chance(0.5)) {
                let x = self.rng.range(-0.3, 0.3) * w;
                self.small_light(Vec3::new(x, h - 0.3, z), p);
            }
        }
        self.areas.push(Area {
            min: Vec2::new(-0.5 * w + 0.25, -0.5 * l + 0.3),
            max: Vec2::new(0.5 * w - 0.25, 0.5 * l - 2.5),
            y: 0.0,
        });
        self.camera_region = CameraRegion {
            min: Vec3::new(-0.5 * w + 0.4, 1.2, 0.5 * l - 2.2),
            max: Vec3::new(0.5 * w - 0.4, (h - 0.4).min(1.9), 0.5 * l - 0.4),
        };
        self.floor_area = w * l;
    }

    /// Replaces the plain right wall (x = +w/2) of a box room with one that has `holes`.
    pub(in crate::render::procedural) fn cut_right_wall(
        &mut self,
        w: f32,
        l: f32,
        h: f32,
        holes: &[[f32; 4]],
    ) {
        // The right wall was pushed as the last wall: find its triangles (x = w/2, facing -x)
        // and drop them, then push the wall again with holes in the same material.
        let g = &mut self.scene.geometry;
        let x = 0.5 * w;
        let mut material = None;
        let mut keep = Vec::with_capacity(g.triangles.len());
        for (t, &m) in g.triangles.iter().zip(&g.materials) {
            let on_wall = t.iter().all(|&i| (g.positions[i as usize].x - x).abs() < 1e-4)
                && g.normals[t[0] as usize].x < -0.5;
            if on_wall {
                material = Some(m);
            } else {
                keep.push((*t, m));
            }
        }
        let Some(m) = material else {
            return;
        };
        g.triangles = keep.iter().map(|k| k.0).collect();
        g.materials = keep.iter().map(|k| k.1).collect();
        push_wall(
            g,
            Vec3::new(x, 0.0, -0.5 * l),
            Vec3::Z,
            Vec3::Y,
            l,
            h,
            holes,
            1.5,
            m,
        );
    }

    pub(in crate::render::procedural) fn steps(&mut self) {
        self.enclosure = Enclosure::Steps;
        let indoor = self.rng.chance(0.5);
        self.indoor = indoor;
        let r = &mut self.rng;
        let n = r.int(4, 12);
        let rise = r.range(0.12, 0.25);
        let run = r.range(0.28, 0.5);
        let landing = r.range(1.0, 2.0);
        let depth = n as f32 * run + landing;
        let (w, d, h) = (
            r.range(5.0, 10.0),
            (depth + r.range(4.0, 8.0)).max(7.0),
            (n as f32 * rise + r.range(2.2, 3.0)).max(3.0),
        );
        let sw = r.range(1.5, 0.8 * w);
        let x0 = r.range(-0.5 * w + 0.5 * sw, 0.5 * w - 0.5 * sw);
        let zb = -0.5 * d + depth; // front edge of the first step
        let power = r.range(2.0, 6.0) * w * d;
        if indoor {
            let windows = self.rng.int(0, 2);
            let outside = windows > 0 && self.rng.chance(0.4);
            let wins = self.box_room(w, d, h, windows, false);
            if windows > 0 && !outside {
                let level = self.rng.range(1.5, 4.0);
                self.scene.environment = Some(self.environment(level));
            }
            self.dress_windows(&wins, outside, power);
            let area = if windows == 0 {
                self.rng.int(1, 3)
            } else {
                self.rng.int(0, 2)
            };
            let small = self.rng.int(0, 2);
            self.ceiling_lights(w, d, h, area, small, power);
        } else {
            let level = self.rng.range(0.6, 2.0);
            self.scene.environment = Some(self.environment(level));
            let ground = self.random_material(Use::Floor);
            push_rect(
                &mut self.scene.geometry,
                Vec3::new(-30.0, 0.0, 30.0),
                Vec3::X * 60.0,
                Vec3::NEG_Z * 60.0,
                Vec2::ZERO,
                self.rng.range(0.8, 2.5),
                ground,
            );
            self.floor_area = w * d;
        }
        let step_m = if self.rng.chance(0.5) {
            self.random_material(Use::Floor)
        } else {
            self.random_material(Use::Wall)
        };
        let solid = self.rng.chance(0.6);
        for i in 0..n {
            let top = (i + 1) as f32 * rise;
            let z1 = zb - i as f32 * run;
            let z0 = z1 - run;
            let (y0, z0) = if solid {
                (0.0, z0)
            } else {
                (top - rise.min(0.08), z0)
            };
            push_box(
                &mut self.scene.geometry,
                Vec3::new(x0, 0.5 * (y0 + top), 0.5 * (z0 + z1)),
                Vec3::new(0.5 * sw, 0.5 * (top - y0), 0.5 * (z1 - z0)),
                Quat::IDENTITY,
                0.5,
                step_m,
            );
            if sw > 0.8 {
                self.areas.push(Area {
                    min: Vec2::new(x0 - 0.5 * sw + 0.15, z0 + 0.06),
                    max: Vec2::new(x0 + 0.5 * sw - 0.15, z1 - 0.06),
                    y: top,
                });
            }
        }
        // The landing, up to the back wall.
        let top = n as f32 * rise;
        let lz1 = zb - n as f32 * run;
        let lz0 = -0.5 * d;
        push_box(
            &mut self.scene.geometry,
            Vec3::new(x0, 0.5 * top, 0.5 * (lz0 + lz1)),
            Vec3::new(0.5 * sw, 0.5 * top, 0.5 * (lz1 - lz0)),
            Quat::IDENTITY,
            0.5,
            step_m,
        );
        self.areas.push(Area {
            min: Vec2::new(x0 - 0.5 * sw + 0.2, lz0 + 0.2),
            max: Vec2::new(x0 + 0.5 * sw - 0.2, lz1 - 0.2),
            y: top,
        });
        // The floor in front of and beside the steps.
        self.areas.push(Area {
            min: Vec2::new(-0.5 * w + 0.3, zb + 0.2),
            max: Vec2::new(0.5 * w - 0.3, 0.5 * d - 0.3),
            y: 0.0,
        });
        for (a, b) in [
            (-0.5 * w + 0.3, x0 - 0.5 * sw - 0.2),
            (x0 + 0.5 * sw + 0.2, 0.5 * w - 0.3),
        ] {
            if b - a > 0.6 {
                self.areas.push(Area {
                    min: Vec2::new(a, -0.5 * d + 0.3),
                    max: Vec2::new(b, zb),
                    y: 0.0,
                });
            }
        }
        self.feature = Some(Vec3::new(x0, 0.5 * top, 0.5 * (lz0 + zb)));
        self.camera_region = CameraRegion {
            min: Vec3::new(-0.5 * w + 0.4, 1.2, zb + 1.0),
            max: Vec3::new(0.5 * w - 0.4, (h - 0.4).min(2.2), 0.5 * d - 0.4),
        };
    }
}
