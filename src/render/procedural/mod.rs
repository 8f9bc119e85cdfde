//! Procedural scenes, `builtin:procedural:SEED`: a different scene for every `u64` seed,
//! for training data with diversity (issue 10, part 4).
//!
//! Each scene is an **enclosure** ([`Enclosure`]: a closed room with windows, open ground
//! under an environment, a corridor, or a hall or terrace with a flight of steps) holding
//! 5-40 **objects** (boxes, spheres, cylinders, tables with things on them, plants and
//! screens with alpha cut-outs, glowing objects, and meshes taken from user-given glTF
//! **props**), with **materials** over the range the BSDF supports ([`MaterialKind`]:
//! diffuse, procedural textures (checker, stripes, noise, bricks, tiles) with normal and
//! roughness maps, glossy dielectrics, metals and glass of roughness 0-1, solid and thin
//! glass, cut-outs, emitters), **lights** (area lights of varied size and power, small bright
//! sources with hard shadows, emitters outside windows, environment maps from the props or a
//! procedural sky with a sun disc), a **camera** inside the enclosure looking at objects, and
//! a **camera path** ([`Scene::camera_path`]: static, orbits and fly-throughs, slow and fast,
//! and fly-throughs with cuts).
//!
//! The enclosure kind is `Enclosure::ALL[seed % 4]` (room, open ground, corridor, steps), so
//! any run of consecutive seeds covers every kind evenly; the rest is drawn from the seed.
//! Everything is a function of the seed (and of the props given): the generator uses a
//! seeded SplitMix64, never the clock or a global generator. A generated scene is checked
//! with the CPU BVH from its camera ([`check_view`]): enough of the view must be geometry,
//! some of it objects, the camera must not be inside anything, and direct light (an emitter
//! or the environment) must reach a part of what the camera sees. A seed whose scene fails
//! is retried with sub-seeds derived from it, so the result is still deterministic and never
//! an all-black image; after [`MAX_ATTEMPTS`] a simple, always valid fallback scene is used.
//! The same check estimates the image's mean radiance from direct light
//! ([`ViewCheck::estimate`]); outside [`EXPOSURE_RANGE`] every emitter and the environment
//! are scaled by one factor ([`Generated::light_gain`]), so scenes are neither near-black
//! nor blown out while their lights keep their power ratios.
//!
//! Props ([`SceneOptions::props`](super::loader::SceneOptions)) are explicit paths (glTF/glb
//! files, `.hdr`/`.exr` environment maps, or folders searched for both); a broken or
//! unsupported file is skipped with one warning naming it. A prop is a whole glTF scene or
//! the triangles of one of its materials (a glTF primitive), scaled and placed as an object.

use crate::error::{Error, Result};
use crate::render::camera::SplitMix;
use crate::render::loader::SceneOptions;
use crate::render::scene::{AlphaMode, Material, Scene};

mod builder;
mod props;
mod shapes;
#[cfg(test)]
mod tests;
mod textures;
mod view;

use builder::Builder;
pub use builder::mean_radiance;
pub use props::{MAX_PROP_TRIANGLES, PropFile, PropLibrary};
pub use shapes::{push_box, push_cylinder, push_rect, push_sphere, push_wall};
pub use view::{ViewCheck, check_view};

/// Scenes tried per seed (the first, then sub-seeds) before the fallback scene is used.
pub const MAX_ATTEMPTS: u32 = 12;

/// Estimated mean image radiance (direct light only, see [`ViewCheck::estimate`]) that needs
/// no exposure change; outside it, all lights are scaled to a mean of 0.15-0.4.
pub const EXPOSURE_RANGE: (f32, f32) = (0.08, 0.7);

/// Film size of procedural scenes.
pub const FILM: (u32, u32) = (256, 256);

/// The kinds of enclosure.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Enclosure {
    /// A closed room with 0-3 windows (to the environment or to emitters outside).
    Room,
    /// A ground plane under an environment.
    OpenGround,
    /// A long corridor, lit by rows of lamps and/or windows, sometimes open at its far end.
    Corridor,
    /// A flight of steps with a landing, in a hall or out in the open.
    Steps,
}

impl Enclosure {
    /// Every kind.
    pub const ALL: [Enclosure; 4] = [
        Enclosure::Room,
        Enclosure::OpenGround,
        Enclosure::Corridor,
        Enclosure::Steps,
    ];

    /// Short name.
    pub fn name(self) -> &'static str {
        match self {
            Enclosure::Room => "room",
            Enclosure::OpenGround => "open ground",
            Enclosure::Corridor => "corridor",
            Enclosure::Steps => "steps",
        }
    }
}

/// What a material is, as far as the BSDF is concerned (for summaries and tests).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum MaterialKind {
    /// Emits light.
    Emitter,
    /// Alpha-masked cut-out.
    Cutout,
    /// Thin-walled transmission (a pane, a bubble).
    ThinGlass,
    /// Solid refracting dielectric (with a volume).
    SolidGlass,
    /// Metallic.
    Metal,
    /// Opaque dielectric with a base colour or normal texture.
    Textured,
    /// Opaque untextured dielectric with a visible specular lobe (roughness < 0.6).
    Glossy,
    /// Opaque untextured rough dielectric.
    Diffuse,
}

impl MaterialKind {
    /// Every kind.
    pub const ALL: [MaterialKind; 8] = [
        MaterialKind::Emitter,
        MaterialKind::Cutout,
        MaterialKind::ThinGlass,
        MaterialKind::SolidGlass,
        MaterialKind::Metal,
        MaterialKind::Textured,
        MaterialKind::Glossy,
        MaterialKind::Diffuse,
    ];

    /// The kind of `m` (the first that applies, in the order of [`MaterialKind::ALL`]).
    pub fn of(m: &Material) -> Self {
        if m.emissive.iter().any(|&e| e > 0.0) {
            MaterialKind::Emitter
        } else if matches!(m.alpha, AlphaMode::Mask(_)) {
            MaterialKind::Cutout
        } else if m.transmission > 0.5 {
            if m.thin {
                MaterialKind::ThinGlass
            } else {
                MaterialKind::SolidGlass
            }
        } else if m.metallic >= 0.5 {
            MaterialKind::Metal
        } else if m.base_color_texture.is_some() || m.normal_texture.is_some() {
            MaterialKind::Textured
        } else if m.roughness < 0.6 && m.specular > 0.0 {
            MaterialKind::Glossy
        } else {
            MaterialKind::Diffuse
        }
    }

    /// Short name.
    pub fn name(self) -> &'static str {
        match self {
            MaterialKind::Emitter => "emitter",
            MaterialKind::Cutout => "cut-out",
            MaterialKind::ThinGlass => "thin glass",
            MaterialKind::SolidGlass => "solid glass",
            MaterialKind::Metal => "metal",
            MaterialKind::Textured => "textured",
            MaterialKind::Glossy => "glossy",
            MaterialKind::Diffuse => "diffuse",
        }
    }
}

/// A generated scene and how it came about.
#[derive(Debug, Clone)]
pub struct Generated {
    /// The scene (named `builtin:procedural:SEED`).
    pub scene: Scene,
    /// Its enclosure.
    pub enclosure: Enclosure,
    /// Objects placed (a table with things on it counts each of them).
    pub objects: usize,
    /// Props placed, as `file` or `file#material`.
    pub props: Vec<String>,
    /// Which attempt passed the checks (0: the seed itself; `MAX_ATTEMPTS`: the fallback).
    pub attempt: u32,
    /// Warnings (props skipped, environment maps that could not be read); also logged.
    pub warnings: Vec<String>,
    /// The view check of the scene camera (its estimate after the exposure gain).
    pub view: ViewCheck,
    /// Factor applied to every emitter and the environment so the estimated image mean
    /// ([`ViewCheck::estimate`]) lies in [`EXPOSURE_RANGE`] (1: none was needed).
    pub light_gain: f32,
    /// Triangles of the objects (the rest is the enclosure and its lights).
    pub object_triangles: std::ops::Range<usize>,
}

/// Parses the seed of `builtin:procedural:SEED` (decimal, or hexadecimal with `0x`).
pub fn parse_seed(s: &str) -> Result<u64> {
    let t = s.trim();
    let v = match t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
        Some(h) => u64::from_str_radix(h, 16),
        None => t.parse::<u64>(),
    };
    v.map_err(|_| Error::Scene {
        path: format!("builtin:procedural:{s}").into(),
        message: format!("'{s}' is not a seed (an unsigned 64-bit integer, decimal or 0x hex)"),
    })
}

/// The scene of `seed` with the props of `options`; warnings are logged.
pub fn procedural(seed: u64, options: &SceneOptions) -> Result<Scene> {
    Ok(generate(seed, options)?.scene)
}

/// The scene of `seed` with the props of `options`, with what the generator did. Errors
/// only for props paths that do not exist; broken prop files are warnings.
pub fn generate(seed: u64, options: &SceneOptions) -> Result<Generated> {
    let mut lib = PropLibrary::load(&options.props)?;
    generate_with(seed, &mut lib)
}

/// As [`generate`], with props loaded once by [`PropLibrary::load`] (to generate many
/// scenes from the same props).
pub fn generate_with(seed: u64, lib: &mut PropLibrary) -> Result<Generated> {
    let mut warnings = lib.warnings.clone();
    for attempt in 0..MAX_ATTEMPTS {
        let sub = if attempt == 0 {
            seed
        } else {
            mix(seed ^ mix(attempt as u64 ^ 0x0005_eed0_fa77_e3b7))
        };
        let mut b = Builder::new(seed, sub, lib);
        // The seed picks the enclosure round-robin (consecutive seeds cover every kind);
        // retries keep it.
        b.build(Enclosure::ALL[(seed % Enclosure::ALL.len() as u64) as usize]);
        if sabotaged(attempt) {
            // Test hook: this attempt loses its lights.
            for m in &mut b.scene.materials {
                m.emissive = [0.0; 3];
            }
            b.scene.environment = None;
        }
        warnings.append(&mut b.warnings);
        if let Some(g) = b.finish(attempt)? {
            return Ok(done(g, seed, warnings));
        }
        log::debug!("builtin:procedural:{seed}: attempt {attempt} failed its view check, retrying");
    }
    let mut b = Builder::new(seed, mix(seed ^ 0xfa11_bac4), lib);
    b.fallback();
    warnings.append(&mut b.warnings);
    match b.finish(MAX_ATTEMPTS)? {
        Some(g) => Ok(done(g, seed, warnings)),
        None => Err(Error::Scene {
            path: format!("builtin:procedural:{seed}").into(),
            message: "no attempt, not even the fallback scene, passed the view check".into(),
        }),
    }
}

fn done(mut g: Generated, seed: u64, warnings: Vec<String>) -> Generated {
    let mut seen = Vec::new();
    for w in warnings {
        if !seen.contains(&w) {
            log::warn!("builtin:procedural:{seed}: {w}");
            seen.push(w);
        }
    }
    g.warnings = seen;
    g
}

#[cfg(test)]
thread_local! {
    static SABOTAGE: std::cell::Cell<u32> = const { std::cell::Cell::new(0) };
}

#[cfg(test)]
fn sabotaged(attempt: u32) -> bool {
    SABOTAGE.with(|s| attempt < s.get())
}

#[cfg(not(test))]
fn sabotaged(_attempt: u32) -> bool {
    false
}

/// SplitMix64 finaliser: a well-mixed 64-bit hash.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Random numbers for the generator.
struct Rng(SplitMix);

impl Rng {
    fn new(seed: u64) -> Self {
        Rng(SplitMix::new(seed))
    }
    fn f(&mut self) -> f32 {
        self.0.next_f32()
    }
    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.f()
    }
    /// Uniform integer in `lo..=hi`.
    fn int(&mut self, lo: u32, hi: u32) -> u32 {
        lo + (self.0.next_u64() % (hi - lo + 1) as u64) as u32
    }
    fn chance(&mut self, p: f32) -> bool {
        self.f() < p
    }
    fn index(&mut self, n: usize) -> usize {
        (self.0.next_u64() % n.max(1) as u64) as usize
    }
    /// An index drawn with the given weights.
    fn weighted(&mut self, w: &[f32]) -> usize {
        let total: f32 = w.iter().sum();
        let mut x = self.f() * total;
        for (i, &wi) in w.iter().enumerate() {
            if x < wi {
                return i;
            }
            x -= wi;
        }
        w.len() - 1
    }
    fn sign(&mut self) -> f32 {
        if self.chance(0.5) { 1.0 } else { -1.0 }
    }
    fn sub(&mut self) -> u64 {
        self.0.next_u64()
    }
}

/// Counts of materials by kind, in the order of [`MaterialKind::ALL`] (only kinds used by
/// some triangle).
pub fn material_kinds(scene: &Scene) -> Vec<(MaterialKind, usize)> {
    let mut used = vec![false; scene.materials.len()];
    for &m in &scene.geometry.materials {
        if let Some(u) = used.get_mut(m as usize) {
            *u = true;
        }
    }
    MaterialKind::ALL
        .iter()
        .map(|&k| {
            let n = scene
                .materials
                .iter()
                .zip(&used)
                .filter(|(m, u)| **u && MaterialKind::of(m) == k)
                .count();
            (k, n)
        })
        .filter(|&(_, n)| n > 0)
        .collect()
}
