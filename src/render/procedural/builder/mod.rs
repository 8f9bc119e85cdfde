//! The scene builder: one attempt at a scene, from its enclosure to its camera path.

use std::collections::HashMap;

use glam::{Vec2, Vec3};

use crate::render::camera::Camera;
use crate::render::procedural::props::*;
use crate::render::procedural::textures::*;
use crate::render::procedural::*;
use crate::render::scene::{Environment, Geometry, Material, Scene, Texture, luminance};

mod camera;
mod enclosures;
mod lighting;
mod materials;
mod objects;

/// A horizontal surface objects can stand on.
#[derive(Debug, Clone, Copy)]
pub(super) struct Area {
    min: Vec2,
    max: Vec2,
    y: f32,
}

impl Area {
    pub(in crate::render::procedural) fn size(&self) -> f32 {
        (self.max - self.min).max(Vec2::ZERO).element_product()
    }
}

/// Something placed: a vertical cylinder `(centre xz, radius, y range)` kept free.
#[derive(Debug, Clone, Copy)]
pub(super) struct Footprint {
    c: Vec2,
    r: f32,
    y0: f32,
    y1: f32,
}

/// Where objects were meant to be seen from: free space for the camera.
#[derive(Debug, Clone, Copy)]
pub(super) struct CameraRegion {
    min: Vec3,
    max: Vec3,
}

/// What materials are for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Use {
    /// An object with a closed surface (solid glass allowed).
    Closed,
    /// An open or one-sided surface.
    Open,
    /// Floor or ground.
    Floor,
    /// Walls.
    Wall,
}

pub(super) struct Builder<'a> {
    pub(super) rng: Rng,
    pub(super) lib: &'a mut PropLibrary,
    pub(super) scene: Scene,
    pub(super) enclosure: Enclosure,
    pub(super) areas: Vec<Area>,
    pub(super) placed: Vec<Footprint>,
    pub(super) camera_region: CameraRegion,
    /// Points worth looking at (object centres).
    pub(super) interests: Vec<Vec3>,
    /// A feature of the enclosure worth looking at (the steps).
    pub(super) feature: Option<Vec3>,
    pub(super) objects: usize,
    pub(super) object_tris: std::ops::Range<usize>,
    pub(super) props: Vec<String>,
    pub(super) prop_materials: HashMap<(usize, u32), u32>,
    pub(super) prop_textures: HashMap<(usize, u32), u32>,
    pub(super) prop_triangles: usize,
    pub(super) warnings: Vec<String>,
    /// Floor area, for light power.
    pub(super) floor_area: f32,
    /// Whether the enclosure is closed (orbits are then checked against the walls).
    pub(super) indoor: bool,
}

impl<'a> Builder<'a> {
    pub(in crate::render::procedural) fn new(seed: u64, sub: u64, lib: &'a mut PropLibrary) -> Self {
        let camera = Camera {
            position: Vec3::new(0.0, 1.5, 4.0),
            target: Vec3::new(0.0, 0.5, 0.0),
            up: Vec3::Y,
            yfov: 55f32.to_radians(),
        };
        Builder {
            rng: Rng::new(sub),
            lib,
            scene: Scene {
                name: format!("builtin:procedural:{seed}"),
                geometry: Geometry::default(),
                materials: Vec::new(),
                textures: Vec::new(),
                environment: None,
                camera,
                film: FILM,
                camera_path: None,
                approximations: Vec::new(),
            },
            enclosure: Enclosure::Room,
            areas: Vec::new(),
            placed: Vec::new(),
            camera_region: CameraRegion {
                min: Vec3::new(-1.0, 1.0, 2.0),
                max: Vec3::new(1.0, 2.0, 4.0),
            },
            interests: Vec::new(),
            feature: None,
            objects: 0,
            object_tris: 0..0,
            props: Vec::new(),
            prop_materials: HashMap::new(),
            prop_textures: HashMap::new(),
            prop_triangles: 0,
            warnings: Vec::new(),
            floor_area: 25.0,
            indoor: true,
        }
    }

    pub(in crate::render::procedural) fn material(&mut self, m: Material) -> u32 {
        self.scene.materials.push(m);
        self.scene.materials.len() as u32 - 1
    }

    pub(in crate::render::procedural) fn texture(&mut self, t: Texture) -> u32 {
        self.scene.textures.push(t);
        self.scene.textures.len() as u32 - 1
    }

    pub(in crate::render::procedural) fn tris(&self) -> usize {
        self.scene.geometry.triangles.len()
    }
}

/// Scales a material's base colour up so its luminance is at least `min` (large surfaces
/// that are almost black make dark, noisy images).
pub(super) fn brighten(m: &mut Material, min: f32) {
    let c = Vec3::new(m.base_color[0], m.base_color[1], m.base_color[2]);
    let l = luminance(c);
    let c = if l < min {
        if l > 1e-3 {
            (c * (min / l)).min(Vec3::splat(0.95))
        } else {
            Vec3::splat(min)
        }
    } else {
        c
    };
    m.base_color[..3].copy_from_slice(&c.to_array());
}

/// Mean radiance (luminance, times the scale) of an environment over the sphere, weighted
/// by solid angle.
pub fn mean_radiance(e: &Environment) -> f32 {
    let (mut sum, mut wsum) = (0.0f64, 0.0f64);
    for y in 0..e.height {
        let w = (((y as f64 + 0.5) / e.height as f64) * std::f64::consts::PI).sin();
        for x in 0..e.width {
            sum += w * luminance(Vec3::from(e.pixels[(y * e.width + x) as usize])) as f64;
            wsum += w;
        }
    }
    (sum / wsum.max(1e-12)) as f32 * e.scale
}
