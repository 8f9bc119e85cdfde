//! The camera, its path, the check of a finished attempt and the fallback scene.

use glam::{Quat, Vec2, Vec3};

use super::*;
use crate::error::Result;
use crate::render::bvh::SceneBvh;
use crate::render::camera::{Camera, CameraPathSpec};
use crate::render::procedural::shapes::*;
use crate::render::procedural::view::*;
use crate::render::scene::Material;

impl Builder<'_> {
    /// A first camera (refined by [`Builder::finish`] with the BVH).
    pub(in crate::render::procedural) fn choose_camera_seed(&mut self) {
        let c = self.camera_candidate();
        self.scene.camera = c;
    }

    /// A camera in the camera region, away from objects, looking at one or a few of them
    /// (or at the enclosure's feature, such as the steps) from at least 1.2 m.
    pub(in crate::render::procedural) fn camera_candidate(&mut self) -> Camera {
        let reg = self.camera_region;
        let target = match self.feature {
            Some(f) if self.rng.chance(0.6) => f,
            _ if self.interests.is_empty() => Vec3::new(0.0, 0.5, 0.0),
            _ => {
                let k = self.rng.int(1, 3.min(self.interests.len() as u32)) as usize;
                let mut sum = Vec3::ZERO;
                for _ in 0..k {
                    sum += self.interests[self.rng.index(self.interests.len())];
                }
                sum / k as f32
            }
        };
        let mut best = None;
        for _ in 0..20 {
            let p = Vec3::new(
                self.rng.range(reg.min.x, reg.max.x),
                self.rng.range(reg.min.y, reg.max.y),
                self.rng.range(reg.min.z, reg.max.z),
            );
            let xz = Vec2::new(p.x, p.z);
            if self
                .placed
                .iter()
                .any(|f| f.c.distance(xz) < f.r + 0.3 && p.y > f.y0 - 0.3 && p.y < f.y1 + 0.3)
            {
                continue;
            }
            // Far enough, and looking down no steeper than about 50 degrees.
            let flat = Vec2::new(p.x - target.x, p.z - target.z).length();
            if p.distance(target) < 1.2 || p.y - target.y > 1.2 * flat {
                continue;
            }
            best = Some(p);
            break;
        }
        let position = best.unwrap_or(0.5 * (reg.min + reg.max));
        let target = if target.distance(position) < 0.5 {
            position + (target - position).normalize_or(Vec3::NEG_Z) + Vec3::NEG_Z
        } else {
            target
        };
        Camera {
            position,
            target,
            up: Vec3::Y,
            yfov: self.rng.range(40.0, 72.0).to_radians(),
        }
    }

    /// Checks the scene from cameras (the seed's, then up to 7 more candidates), chooses a
    /// camera path; `None` when no camera passes.
    pub(in crate::render::procedural) fn finish(mut self, attempt: u32) -> Result<Option<Generated>> {
        self.scene.validate()?;
        if self.objects < 5 {
            return Ok(None);
        }
        let bvh = match SceneBvh::build(
            &self.scene.name,
            &self.scene.geometry.positions,
            &self.scene.geometry.triangles,
        ) {
            Ok(b) => b,
            Err(e) => {
                log::debug!("{}: {e}", self.scene.name);
                return Ok(None);
            }
        };
        let mut camera = self.scene.camera;
        let mut view = None;
        for i in 0..8 {
            if i > 0 {
                camera = self.camera_candidate();
            }
            let v = check_view(&self.scene, &bvh, &camera, Some(self.object_tris.clone()));
            if v.ok() {
                view = Some(v);
                break;
            }
        }
        let Some(mut view) = view else {
            return Ok(None);
        };
        // Exposure: lights scaled so the estimated image is neither near-black nor blown out
        // (the power ratios between lights, and the variety within the range, are kept).
        let mut light_gain = 1.0;
        if !(EXPOSURE_RANGE.0..=EXPOSURE_RANGE.1).contains(&view.estimate) {
            let target = self.rng.range(0.15, 0.4);
            light_gain = (target / view.estimate).clamp(1.0 / 50.0, 50.0);
            for m in &mut self.scene.materials {
                for e in &mut m.emissive {
                    *e *= light_gain;
                }
            }
            if let Some(e) = &mut self.scene.environment {
                e.scale *= light_gain;
            }
            view.estimate *= light_gain;
        }
        self.scene.camera = camera;
        self.scene.camera_path = Some(self.camera_path(&bvh));
        Ok(Some(Generated {
            scene: self.scene,
            enclosure: self.enclosure,
            objects: self.objects,
            props: self.props,
            attempt,
            warnings: Vec::new(),
            view,
            light_gain,
            object_triangles: self.object_tris,
        }))
    }

    /// Whether the camera can stand at `p` (room around it) and see `target` from there.
    pub(in crate::render::procedural) fn clear_view(bvh: &SceneBvh, p: Vec3, target: Vec3) -> bool {
        let margin = 0.15;
        let roomy = [Vec3::X, Vec3::NEG_X, Vec3::Y, Vec3::NEG_Y, Vec3::Z, Vec3::NEG_Z]
            .iter()
            .all(|&d| bvh.intersect(p, d, margin).is_none());
        let to = target - p;
        let len = to.length();
        roomy && len > 0.3 && bvh.intersect(p, to / len, 0.6 * len).is_none()
    }

    /// The camera path: static, orbit (when the whole circle is clear), a generated or
    /// explicit fly-through (slow or fast), or a fly-through with cuts.
    pub(in crate::render::procedural) fn camera_path(&mut self, bvh: &SceneBvh) -> CameraPathSpec {
        let cam = self.scene.camera;
        let slow = self.rng.chance(0.5);
        let fpk = if slow {
            self.rng.range(40.0, 96.0)
        } else {
            self.rng.range(6.0, 16.0)
        };
        match self.rng.weighted(&[1.5, 2.0, 2.5, 2.0, 2.0]) {
            0 => CameraPathSpec::Static,
            1 => {
                // The whole circle: every step of it clear of geometry, room around every
                // position, and the target in view from most of them (objects may pass in
                // front of it).
                let rel = cam.position - cam.target;
                let on_circle = |i: u32| {
                    let a = i as f32 / 96.0 * std::f32::consts::TAU;
                    let (s, c) = a.sin_cos();
                    cam.target + Vec3::new(c * rel.x + s * rel.z, rel.y, -s * rel.x + c * rel.z)
                };
                let mut seen = 0;
                let mut clear = true;
                for i in 0..96 {
                    let (p, q) = (on_circle(i), on_circle(i + 1));
                    let d = q - p;
                    let step_clear = bvh
                        .intersect(p, d.normalize_or(Vec3::X), d.length() + 0.15)
                        .is_none();
                    let roomy = [Vec3::X, Vec3::NEG_X, Vec3::Y, Vec3::NEG_Y, Vec3::Z, Vec3::NEG_Z]
                        .iter()
                        .all(|&d| bvh.intersect(p, d, 0.15).is_none());
                    clear &= step_clear && roomy;
                    seen += Self::clear_view(bvh, p, cam.target) as u32;
                }
                let clear = clear && seen >= 72;
                if clear {
                    let deg = if slow {
                        self.rng.range(0.15, 0.5)
                    } else {
                        self.rng.range(1.5, 4.0)
                    };
                    CameraPathSpec::Orbit {
                        degrees_per_frame: Some(deg * self.rng.sign()),
                    }
                } else {
                    CameraPathSpec::FlyThrough {
                        keys: None,
                        frames_per_key: fpk,
                        cut_every: None,
                    }
                }
            }
            2 => CameraPathSpec::FlyThrough {
                keys: None,
                frames_per_key: fpk,
                cut_every: None,
            },
            k => {
                // Explicit keys: a walk through free space (consecutive keys joined by clear
                // segments) or viewpoints to cut between.
                let cuts = k == 4;
                let mut keys = vec![cam];
                for _ in 0..40 {
                    if keys.len() >= 5 {
                        break;
                    }
                    let c = self.camera_candidate();
                    let prev = keys[keys.len() - 1].position;
                    let d = c.position - prev;
                    let joined = cuts
                        || (d.length() > 1e-3
                            && bvh.intersect(prev, d.normalize(), d.length() + 0.2).is_none());
                    if Self::clear_view(bvh, c.position, c.target)
                        && joined
                        && check_view(&self.scene, bvh, &c, None).geometry >= 0.3
                    {
                        keys.push(Camera { yfov: cam.yfov, ..c });
                    }
                }
                if keys.len() < 2 {
                    return CameraPathSpec::Static;
                }
                let cut_every = if cuts { Some(self.rng.int(8, 32)) } else { None };
                CameraPathSpec::FlyThrough {
                    keys: Some(keys),
                    frames_per_key: if cuts { fpk.max(24.0) } else { fpk },
                    cut_every,
                }
            }
        }
    }

    /// The fallback: a simple open scene under a sky with a few objects in front of the
    /// camera and a lamp (always passes the view check).
    pub(in crate::render::procedural) fn fallback(&mut self) {
        self.enclosure = Enclosure::OpenGround;
        self.indoor = false;
        self.scene.environment = Some(self.sky(1.0));
        let ground = self.material(Material::diffuse("ground", [0.5, 0.5, 0.5]));
        push_rect(
            &mut self.scene.geometry,
            Vec3::new(-20.0, 0.0, 20.0),
            Vec3::X * 40.0,
            Vec3::NEG_Z * 40.0,
            Vec2::ZERO,
            1.0,
            ground,
        );
        self.object_tris = self.tris()..self.tris();
        let mats = [
            Material::diffuse("red", [0.7, 0.15, 0.1]),
            Material::metal("metal", [0.95, 0.93, 0.88], 0.2),
            Material::diffuse("blue", [0.1, 0.2, 0.7]),
        ];
        for (i, m) in mats.into_iter().enumerate() {
            let id = self.material(m);
            let x = (i as f32 - 1.0) * 1.2;
            push_sphere(
                &mut self.scene.geometry,
                Vec3::new(x, 0.5, 0.0),
                0.5,
                32,
                16,
                1.0,
                id,
            );
            self.done_object(Vec3::new(x, 0.5, 0.0));
        }
        let id = self.material(Material::diffuse("box", [0.8, 0.8, 0.75]));
        push_box(
            &mut self.scene.geometry,
            Vec3::new(0.0, 0.4, -1.5),
            Vec3::new(1.5, 0.4, 0.4),
            Quat::IDENTITY,
            1.0,
            id,
        );
        self.done_object(Vec3::new(0.0, 0.4, -1.5));
        let id = self.material(Material::glass("glass", [1.0; 3], 0.0, 1.5, false));
        push_sphere(
            &mut self.scene.geometry,
            Vec3::new(1.0, 0.3, 1.2),
            0.3,
            32,
            16,
            1.0,
            id,
        );
        self.done_object(Vec3::new(1.0, 0.3, 1.2));
        self.small_light(Vec3::new(1.5, 2.0, 1.0), 60.0);
        self.object_tris.end = self.tris();
        self.scene.camera = Camera {
            position: Vec3::new(0.0, 1.6, 4.5),
            target: Vec3::new(0.0, 0.4, 0.0),
            up: Vec3::Y,
            yfov: 50f32.to_radians(),
        };
        self.camera_region = CameraRegion {
            min: Vec3::new(-1.5, 1.2, 3.5),
            max: Vec3::new(1.5, 2.0, 5.5),
        };
    }
}
