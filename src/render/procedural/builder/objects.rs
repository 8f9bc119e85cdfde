//! Objects placed in the enclosure, props included.

use std::collections::HashMap;

use glam::{Quat, Vec2, Vec3};

use super::*;
use crate::render::procedural::shapes::*;
use crate::render::scene::Geometry;

impl Builder<'_> {
    /// A free spot of radius `r` and height `height` on one of the areas (weighted by size).
    pub(in crate::render::procedural) fn spot(&mut self, r: f32, height: f32) -> Option<Vec3> {
        let weights: Vec<f32> = self
            .areas
            .iter()
            .map(|a| {
                let s = a.max - a.min;
                if s.x > 2.0 * r && s.y > 2.0 * r {
                    a.size()
                } else {
                    0.0
                }
            })
            .collect();
        if weights.iter().all(|&w| w <= 0.0) {
            return None;
        }
        for _ in 0..30 {
            let a = self.areas[self.rng.weighted(&weights)];
            let c = Vec2::new(
                self.rng.range(a.min.x + r, a.max.x - r),
                self.rng.range(a.min.y + r, a.max.y - r),
            );
            let (y0, y1) = (a.y, a.y + height);
            let free = self
                .placed
                .iter()
                .all(|p| p.y1 < y0 || p.y0 > y1 || p.c.distance(c) > p.r + r + 0.05);
            if free {
                self.placed.push(Footprint { c, r, y0, y1 });
                return Some(Vec3::new(c.x, a.y, c.y));
            }
        }
        None
    }

    pub(in crate::render::procedural) fn populate(&mut self, n: u32) {
        let has_props = !self.lib.files.is_empty();
        let mut tries = 0;
        while self.objects < n as usize && tries < 4 * n {
            tries += 1;
            let w = [
                3.0,                               // box
                3.0,                               // sphere
                2.0,                               // cylinder
                if has_props { 5.0 } else { 0.0 }, // prop
                0.8,                               // table with things
                0.8,                               // plant
                0.6,                               // screen / pane
                0.5,                               // lamp (small light on a stand)
            ];
            match self.rng.weighted(&w) {
                0 => self.add_box(),
                1 => self.add_sphere(),
                2 => self.add_cylinder(),
                3 => self.add_prop(),
                4 => self.add_table(),
                5 => self.add_plant(),
                6 => self.add_screen(),
                _ => self.add_lamp(),
            }
        }
    }

    pub(in crate::render::procedural) fn object_size(&mut self) -> f32 {
        match self.rng.weighted(&[2.0, 5.0, 2.0]) {
            0 => self.rng.range(0.08, 0.2),
            1 => self.rng.range(0.2, 0.5),
            _ => self.rng.range(0.5, 0.9),
        }
    }

    pub(in crate::render::procedural) fn add_box(&mut self) {
        let s = self.object_size();
        let hx = s * self.rng.range(0.4, 1.0);
        let hz = s * self.rng.range(0.4, 1.0);
        let hy = s * self.rng.range(0.3, 1.2);
        let r = Vec2::new(hx, hz).length();
        let Some(p) = self.spot(r, 2.0 * hy) else {
            return;
        };
        let m = self.random_material(Use::Closed);
        let rot = Quat::from_rotation_y(self.rng.range(0.0, std::f32::consts::PI));
        let tile = self.rng.range(0.3, 1.0);
        let c = p + Vec3::Y * hy;
        push_box(&mut self.scene.geometry, c, Vec3::new(hx, hy, hz), rot, tile, m);
        self.done_object(c);
        // Sometimes something on top.
        if self.rng.chance(0.25) {
            let r2 = hx.min(hz) * 0.8;
            let m = self.random_material(Use::Closed);
            let top = p + Vec3::Y * (2.0 * hy + r2);
            push_sphere(&mut self.scene.geometry, top, r2, 32, 16, 2.0, m);
            self.done_object(top);
        }
    }

    pub(in crate::render::procedural) fn add_sphere(&mut self) {
        let r = 0.5 * self.object_size() + 0.05;
        let float = self.rng.chance(0.15);
        let lift = if float { self.rng.range(0.2, 1.0) } else { 0.0 };
        let Some(p) = self.spot(r, 2.0 * r + lift) else {
            return;
        };
        let m = self.random_material(Use::Closed);
        let c = p + Vec3::Y * (r + lift);
        let seg = if r > 0.3 { 48 } else { 32 };
        push_sphere(
            &mut self.scene.geometry,
            c,
            r,
            seg,
            seg / 2,
            self.rng.range(1.0, 4.0),
            m,
        );
        self.done_object(c);
    }

    pub(in crate::render::procedural) fn add_cylinder(&mut self) {
        let s = self.object_size();
        let r = s * self.rng.range(0.2, 0.6);
        let h = s * self.rng.range(0.5, 2.5);
        let Some(p) = self.spot(r, h) else {
            return;
        };
        let m = self.random_material(Use::Closed);
        push_cylinder(&mut self.scene.geometry, p, r, h, 32, self.rng.range(0.3, 1.0), m);
        self.done_object(p + Vec3::Y * 0.5 * h);
    }

    pub(in crate::render::procedural) fn add_table(&mut self) {
        let (tw, td) = (self.rng.range(0.5, 1.0), self.rng.range(0.4, 0.7));
        let th = self.rng.range(0.45, 0.8);
        let r = Vec2::new(tw, td).length();
        // Its footprint ends just below the top, so things can stand on it.
        let Some(p) = self.spot(r, th - 0.01) else {
            return;
        };
        let m = self.random_material(Use::Closed);
        let g = &mut self.scene.geometry;
        push_box(
            g,
            p + Vec3::Y * (th - 0.025),
            Vec3::new(tw, 0.025, td),
            Quat::IDENTITY,
            0.8,
            m,
        );
        for (sx, sz) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
            let leg = p + Vec3::new(sx * (tw - 0.05), 0.5 * (th - 0.05), sz * (td - 0.05));
            push_box(
                g,
                leg,
                Vec3::new(0.03, 0.5 * (th - 0.05), 0.03),
                Quat::IDENTITY,
                0.5,
                m,
            );
        }
        self.done_object(p + Vec3::Y * th);
        // Things on the table: a small area of its own.
        let area = Area {
            min: Vec2::new(p.x - tw + 0.05, p.z - td + 0.05),
            max: Vec2::new(p.x + tw - 0.05, p.z + td - 0.05),
            y: th,
        };
        let saved = std::mem::replace(&mut self.areas, vec![area]);
        let k = self.rng.int(1, 3);
        for _ in 0..k {
            match self.rng.int(0, 2) {
                0 => {
                    let r = self.rng.range(0.04, 0.15);
                    if let Some(q) = self.spot(r, 2.0 * r) {
                        let m = self.random_material(Use::Closed);
                        push_sphere(&mut self.scene.geometry, q + Vec3::Y * r, r, 32, 16, 1.0, m);
                        self.done_object(q + Vec3::Y * r);
                    }
                }
                1 => {
                    let r = self.rng.range(0.03, 0.1);
                    let h = self.rng.range(0.08, 0.35);
                    if let Some(q) = self.spot(r, h) {
                        let m = self.random_material(Use::Closed);
                        push_cylinder(&mut self.scene.geometry, q, r, h, 24, 0.3, m);
                        self.done_object(q + Vec3::Y * 0.5 * h);
                    }
                }
                _ => {
                    if self.lib.files.is_empty() {
                        let s = self.rng.range(0.05, 0.15);
                        if let Some(q) = self.spot(s * 1.42, 2.0 * s) {
                            let m = self.random_material(Use::Closed);
                            let rot = Quat::from_rotation_y(self.rng.range(0.0, 3.0));
                            push_box(
                                &mut self.scene.geometry,
                                q + Vec3::Y * s,
                                Vec3::splat(s),
                                rot,
                                0.3,
                                m,
                            );
                            self.done_object(q + Vec3::Y * s);
                        }
                    } else {
                        let s = self.rng.range(0.15, 0.4);
                        self.add_prop_sized(s);
                    }
                }
            }
        }
        self.areas = saved;
    }

    pub(in crate::render::procedural) fn add_plant(&mut self) {
        let pot_r = self.rng.range(0.1, 0.25);
        let pot_h = self.rng.range(0.15, 0.45);
        let leaf_h = self.rng.range(0.4, 1.4);
        let half = self.rng.range(0.25, 0.6);
        let Some(p) = self.spot(half.max(pot_r), pot_h + leaf_h) else {
            return;
        };
        let pot = self.random_material(Use::Closed);
        push_cylinder(&mut self.scene.geometry, p, pot_r, pot_h, 24, 0.4, pot);
        let m = self.cutout(true);
        let leaves = self.material(m);
        let cards = self.rng.int(2, 3);
        let a0 = self.rng.range(0.0, std::f32::consts::PI);
        for i in 0..cards {
            let a = a0 + i as f32 * std::f32::consts::PI / cards as f32;
            let u = Vec3::new(a.cos(), 0.0, -a.sin()) * 2.0 * half;
            let o = p + Vec3::Y * pot_h - 0.5 * u;
            push_rect(
                &mut self.scene.geometry,
                o,
                u,
                Vec3::Y * leaf_h,
                Vec2::ZERO,
                0.6,
                leaves,
            );
        }
        self.done_object(p + Vec3::Y * (pot_h + 0.5 * leaf_h));
    }

    pub(in crate::render::procedural) fn add_screen(&mut self) {
        let width = self.rng.range(0.6, 1.6);
        let height = self.rng.range(0.8, 1.8);
        let Some(p) = self.spot(0.5 * width, height) else {
            return;
        };
        let m = match self.rng.int(0, 2) {
            0 => {
                let m = self.glass(true);
                self.material(m)
            }
            1 => {
                let m = self.cutout(false);
                self.material(m)
            }
            _ => {
                let m = self.cutout(true);
                self.material(m)
            }
        };
        let a = self.rng.range(0.0, std::f32::consts::PI);
        let u = Vec3::new(a.cos(), 0.0, -a.sin()) * width;
        push_rect(
            &mut self.scene.geometry,
            p - 0.5 * u + Vec3::Y * 0.02,
            u,
            Vec3::Y * height,
            Vec2::ZERO,
            0.5,
            m,
        );
        // A frame foot.
        let foot = self.random_material(Use::Open);
        let rot = Quat::from_rotation_y(a);
        push_box(
            &mut self.scene.geometry,
            p + Vec3::Y * 0.02,
            Vec3::new(0.5 * width, 0.02, 0.08),
            rot,
            0.5,
            foot,
        );
        self.done_object(p + Vec3::Y * 0.5 * height);
    }

    pub(in crate::render::procedural) fn add_lamp(&mut self) {
        let h = self.rng.range(0.4, 1.7);
        let Some(p) = self.spot(0.15, h + 0.1) else {
            return;
        };
        let m = self.random_material(Use::Closed);
        push_cylinder(&mut self.scene.geometry, p, 0.015, h, 12, 1.0, m);
        push_cylinder(&mut self.scene.geometry, p, 0.12, 0.03, 24, 1.0, m);
        let power = self.rng.range(10.0, 60.0) * if self.indoor { 1.0 } else { 3.0 };
        self.small_light(p + Vec3::Y * (h + 0.06), power);
        self.done_object(p + Vec3::Y * h);
    }

    pub(in crate::render::procedural) fn done_object(&mut self, c: Vec3) {
        self.objects += 1;
        self.interests.push(c);
    }

    pub(in crate::render::procedural) fn add_prop(&mut self) {
        let s = self.rng.range(0.3, 1.4);
        self.add_prop_sized(s);
    }

    /// A prop (a whole glTF scene, or the triangles of one of its materials) scaled to a
    /// largest extent of `size`, turned about +y and set on a free spot.
    pub(in crate::render::procedural) fn add_prop_sized(&mut self, size: f32) {
        let nf = self.lib.files.len();
        if nf == 0 {
            return;
        }
        let fi = self.rng.index(nf);
        // Big files (whole rooms) mostly give one of their material groups.
        let file = &self.lib.files[fi];
        let p_whole = if file.scene.geometry.triangles.len() > 20_000 {
            0.15
        } else {
            0.5
        };
        let whole = file.groups.len() <= 1 || self.rng.chance(p_whole);
        let group = if whole {
            None
        } else {
            Some(self.rng.index(self.lib.files[fi].groups.len()))
        };
        let yaw = self.rng.range(0.0, std::f32::consts::TAU);
        let file = &self.lib.files[fi];
        let tris: Vec<u32> = match group {
            None => (0..file.scene.geometry.triangles.len() as u32).collect(),
            Some(k) => file.groups[k].1.clone(),
        };
        if self.prop_triangles + tris.len() > MAX_PROP_TRIANGLES {
            return;
        }
        let g = &file.scene.geometry;
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for &t in &tris {
            for &i in &g.triangles[t as usize] {
                lo = lo.min(g.positions[i as usize]);
                hi = hi.max(g.positions[i as usize]);
            }
        }
        let ext = hi - lo;
        if !ext.is_finite() || ext.max_element() <= 0.0 {
            return;
        }
        let scale = size / ext.max_element();
        let r = 0.5 * scale * Vec2::new(ext.x, ext.z).length();
        let Some(p) = self.spot(r.max(0.05), scale * ext.y) else {
            return;
        };
        let rot = Quat::from_rotation_y(yaw);
        let bottom = Vec3::new(0.5 * (lo.x + hi.x), lo.y, 0.5 * (lo.z + hi.z));
        // Copy the triangles, grouped by material, with remapped vertices.
        let file = &self.lib.files[fi];
        let g = &file.scene.geometry;
        let mut by_mat: Vec<(u32, Vec<u32>)> = Vec::new();
        for &t in &tris {
            let m = g.materials[t as usize];
            match by_mat.iter_mut().find(|(k, _)| *k == m) {
                Some((_, v)) => v.push(t),
                None => by_mat.push((m, vec![t])),
            }
        }
        let mut out = Geometry::default();
        let mut mats = Vec::new();
        for (m, ts) in &by_mat {
            let mut remap = HashMap::new();
            let (mut pos, mut nrm, mut uv, mut tan, mut idx) =
                (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
            for &t in ts {
                let tri = g.triangles[t as usize].map(|i| {
                    *remap.entry(i).or_insert_with(|| {
                        let k = i as usize;
                        pos.push(p + rot * ((g.positions[k] - bottom) * scale));
                        nrm.push(rot * g.normals[k]);
                        uv.push(g.uvs[k]);
                        let tg = g.tangents[k];
                        tan.push((rot * tg.truncate()).extend(tg.w));
                        pos.len() as u32 - 1
                    })
                });
                idx.push(tri);
            }
            mats.push(*m);
            out.push_mesh(&pos, Some(&nrm), Some(&uv), Some(&tan), &idx, *m);
        }
        // Materials and textures, each copied once per scene.
        for m in mats {
            if !self.prop_materials.contains_key(&(fi, m)) {
                let mut mat = self.lib.files[fi].scene.materials[m as usize].clone();
                for slot in [
                    &mut mat.base_color_texture,
                    &mut mat.metallic_roughness_texture,
                    &mut mat.normal_texture,
                    &mut mat.emissive_texture,
                ] {
                    if let Some(t) = *slot {
                        let id = match self.prop_textures.get(&(fi, t)) {
                            Some(&id) => id,
                            None => {
                                let tex = self.lib.files[fi].scene.textures[t as usize].clone();
                                self.scene.textures.push(tex);
                                let id = self.scene.textures.len() as u32 - 1;
                                self.prop_textures.insert((fi, t), id);
                                id
                            }
                        };
                        *slot = Some(id);
                    }
                }
                let id = self.material(mat);
                self.prop_materials.insert((fi, m), id);
            }
        }
        let base = self.scene.geometry.positions.len() as u32;
        let dst = &mut self.scene.geometry;
        dst.positions.extend_from_slice(&out.positions);
        dst.normals.extend_from_slice(&out.normals);
        dst.uvs.extend_from_slice(&out.uvs);
        dst.tangents.extend_from_slice(&out.tangents);
        for (t, m) in out.triangles.iter().zip(&out.materials) {
            dst.triangles.push(t.map(|i| i + base));
            dst.materials.push(self.prop_materials[&(fi, *m)]);
        }
        self.prop_triangles += tris.len();
        let file = &self.lib.files[fi];
        let name = match group {
            None => file.path.display().to_string(),
            Some(k) => format!(
                "{}#{}",
                file.path.display(),
                file.scene.materials[file.groups[k].0 as usize].name
            ),
        };
        for a in &file.scene.approximations {
            let note = format!("{}: {a}", file.path.display());
            if !self.scene.approximations.contains(&note) {
                self.scene.approximations.push(note);
            }
        }
        self.props.push(name);
        self.done_object(p + Vec3::Y * 0.5 * scale * ext.y);
    }
}
