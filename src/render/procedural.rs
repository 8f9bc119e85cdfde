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

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{Mat3, Quat, Vec2, Vec3, Vec4};

use super::bvh::SceneBvh;
use super::camera::{Camera, CameraPathSpec, SplitMix};
use super::loader::{SceneOptions, load_environment, load_gltf};
use super::packed::straight_through;
use super::scene::{AlphaMode, Environment, Geometry, Material, Portal, Scene, Texture, Wrap, luminance};
use crate::error::{Error, Result};

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

// ---------------------------------------------------------------------------------------
// Props.

/// One loaded prop file.
#[derive(Debug, Clone)]
pub struct PropFile {
    /// The glTF file.
    pub path: PathBuf,
    /// Its content.
    pub scene: Scene,
    /// Materials used by at least 4 triangles, with their triangles (the "primitives").
    groups: Vec<(u32, Vec<u32>)>,
}

/// Props given by the user: glTF scenes to take objects from and environment maps.
#[derive(Debug, Clone, Default)]
pub struct PropLibrary {
    /// glTF files that loaded.
    pub files: Vec<PropFile>,
    /// Environment maps found (loaded when a scene uses them).
    pub environments: Vec<PathBuf>,
    /// Warnings of the loading (files skipped).
    pub warnings: Vec<String>,
    env_cache: HashMap<PathBuf, Option<Environment>>,
}

/// Largest prop loaded, in triangles (bigger files are skipped with a warning).
pub const MAX_PROP_TRIANGLES: usize = 1_000_000;

fn ext_of(p: &Path) -> String {
    p.extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default()
}

fn collect_files(dir: &Path, depth: u32, out: &mut Vec<PathBuf>) -> Result<()> {
    let rd = std::fs::read_dir(dir).map_err(|e| Error::File {
        path: dir.to_path_buf(),
        message: format!("cannot list the props folder: {e}"),
    })?;
    let mut entries: Vec<PathBuf> = rd.filter_map(|e| e.ok().map(|e| e.path())).collect();
    entries.sort();
    for p in entries {
        let hidden = p
            .file_name()
            .and_then(|n| n.to_str())
            .is_some_and(|n| n.starts_with('.'));
        if hidden {
            continue;
        }
        if p.is_dir() {
            if depth < 8 {
                collect_files(&p, depth + 1, out)?;
            }
        } else if matches!(ext_of(&p).as_str(), "gltf" | "glb" | "hdr" | "exr") {
            out.push(p);
        }
    }
    Ok(())
}

impl PropLibrary {
    /// Loads the props at `paths` (files or folders, searched recursively for `.gltf`,
    /// `.glb`, `.hdr` and `.exr`). A path that does not exist is an error; a glTF that does
    /// not load (broken, unsupported) is skipped with one warning naming it.
    pub fn load(paths: &[PathBuf]) -> Result<Self> {
        let mut files = Vec::new();
        for p in paths {
            if p.is_dir() {
                collect_files(p, 0, &mut files)?;
            } else if p.is_file() {
                files.push(p.clone());
            } else {
                return Err(Error::File {
                    path: p.clone(),
                    message: "no such props file or folder".into(),
                });
            }
        }
        let mut lib = PropLibrary::default();
        let mut seen = std::collections::HashSet::new();
        for f in files {
            if !seen.insert(f.clone()) {
                continue;
            }
            match ext_of(&f).as_str() {
                "gltf" | "glb" => match load_gltf(&f) {
                    Ok(scene) if scene.geometry.triangles.len() > MAX_PROP_TRIANGLES => {
                        lib.warnings.push(format!(
                            "prop {} skipped: {} triangles (at most {MAX_PROP_TRIANGLES})",
                            f.display(),
                            scene.geometry.triangles.len()
                        ));
                    }
                    Ok(scene) => {
                        let mut by_mat: Vec<Vec<u32>> = vec![Vec::new(); scene.materials.len()];
                        for (t, &m) in scene.geometry.materials.iter().enumerate() {
                            by_mat[m as usize].push(t as u32);
                        }
                        let groups = by_mat
                            .into_iter()
                            .enumerate()
                            .filter(|(_, t)| t.len() >= 4)
                            .map(|(m, t)| (m as u32, t))
                            .collect();
                        lib.files.push(PropFile {
                            path: f,
                            scene,
                            groups,
                        });
                    }
                    Err(e) => lib.warnings.push(format!("prop skipped: {e}")),
                },
                "hdr" | "exr" => lib.environments.push(f),
                _ => lib.warnings.push(format!(
                    "prop {} skipped: not a .gltf, .glb, .hdr or .exr file",
                    f.display()
                )),
            }
        }
        Ok(lib)
    }

    /// The environment map `i` (loaded once; `None` if it cannot be read or is not a
    /// 2:1 lat-long map, with a warning).
    fn environment(&mut self, i: usize, warnings: &mut Vec<String>) -> Option<Environment> {
        let path = self.environments.get(i)?.clone();
        if !self.env_cache.contains_key(&path) {
            let env = match load_environment(&path, 1.0, Mat3::IDENTITY) {
                Ok(e) if e.width >= e.height * 3 / 2 && e.width <= e.height * 5 / 2 => Some(e),
                Ok(e) => {
                    warnings.push(format!(
                        "environment {} skipped: {}x{} is not a 2:1 lat-long map",
                        path.display(),
                        e.width,
                        e.height
                    ));
                    None
                }
                Err(e) => {
                    warnings.push(format!("environment skipped: {e}"));
                    None
                }
            };
            self.env_cache.insert(path.clone(), env);
        }
        self.env_cache[&path].clone()
    }
}

// ---------------------------------------------------------------------------------------
// Mesh generators.

/// Appends the rectangle with corner `o` and edges `u`, `v` (front face towards `u x v`),
/// texture coordinates in units of `tile` (u along `u`, v decreasing along `v`, starting at
/// `uv0` at the corner) and tangents along `u`.
pub fn push_rect(g: &mut Geometry, o: Vec3, u: Vec3, v: Vec3, uv0: Vec2, tile: f32, material: u32) {
    let n = u.cross(v).normalize_or_zero();
    let t = u.normalize_or_zero().extend(1.0);
    let (su, sv) = (u.length() / tile, v.length() / tile);
    let uv = [
        uv0,
        uv0 + Vec2::new(su, 0.0),
        uv0 + Vec2::new(su, -sv),
        uv0 + Vec2::new(0.0, -sv),
    ];
    g.push_mesh(
        &[o, o + u, o + u + v, o + v],
        Some(&[n; 4]),
        Some(&uv),
        Some(&[t; 4]),
        &[[0, 1, 2], [0, 2, 3]],
        material,
    );
}

/// Appends a wall: the rectangle `width x height` from corner `o` along the unit directions
/// `u` and `v` (front face towards `u x v`), minus the rectangular holes `[s0, s1, t0, t1]`
/// (in metres along `u` and `v`). Texture coordinates are continuous across the pieces.
#[allow(clippy::too_many_arguments)]
pub fn push_wall(
    g: &mut Geometry,
    o: Vec3,
    u: Vec3,
    v: Vec3,
    width: f32,
    height: f32,
    holes: &[[f32; 4]],
    tile: f32,
    material: u32,
) {
    let mut xs = vec![0.0, width];
    let mut ys = vec![0.0, height];
    for h in holes {
        xs.extend([h[0].clamp(0.0, width), h[1].clamp(0.0, width)]);
        ys.extend([h[2].clamp(0.0, height), h[3].clamp(0.0, height)]);
    }
    for v in [&mut xs, &mut ys] {
        v.sort_by(f32::total_cmp);
        v.dedup_by(|a, b| (*a - *b).abs() < 1e-5);
    }
    for j in 0..ys.len() - 1 {
        for i in 0..xs.len() - 1 {
            let (s0, s1, t0, t1) = (xs[i], xs[i + 1], ys[j], ys[j + 1]);
            let (cs, ct) = (0.5 * (s0 + s1), 0.5 * (t0 + t1));
            if holes
                .iter()
                .any(|h| cs > h[0] && cs < h[1] && ct > h[2] && ct < h[3])
            {
                continue;
            }
            push_rect(
                g,
                o + u * s0 + v * t0,
                u * (s1 - s0),
                v * (t1 - t0),
                Vec2::new(s0 / tile, -t0 / tile),
                tile,
                material,
            );
        }
    }
}

/// Appends a box of half-extents `h`, rotated by `rot`, centred at `c` (faces outwards),
/// with texture coordinates in units of `tile` and tangents.
pub fn push_box(g: &mut Geometry, c: Vec3, h: Vec3, rot: Quat, tile: f32, material: u32) {
    let (x, y, z) = (h.x, h.y, h.z);
    let faces = [
        (
            Vec3::new(-x, -y, z),
            Vec3::new(2. * x, 0., 0.),
            Vec3::new(0., 2. * y, 0.),
        ),
        (
            Vec3::new(x, -y, -z),
            Vec3::new(-2. * x, 0., 0.),
            Vec3::new(0., 2. * y, 0.),
        ),
        (
            Vec3::new(x, -y, z),
            Vec3::new(0., 0., -2. * z),
            Vec3::new(0., 2. * y, 0.),
        ),
        (
            Vec3::new(-x, -y, -z),
            Vec3::new(0., 0., 2. * z),
            Vec3::new(0., 2. * y, 0.),
        ),
        (
            Vec3::new(-x, y, z),
            Vec3::new(2. * x, 0., 0.),
            Vec3::new(0., 0., -2. * z),
        ),
        (
            Vec3::new(-x, -y, -z),
            Vec3::new(2. * x, 0., 0.),
            Vec3::new(0., 0., 2. * z),
        ),
    ];
    for (o, u, v) in faces {
        push_rect(g, c + rot * o, rot * u, rot * v, Vec2::ZERO, tile, material);
    }
}

/// Appends a UV sphere of radius `r` centred at `c` (faces outwards), with smooth normals,
/// texture coordinates (u around, repeated `repeat` times; v from the north pole) and
/// tangents along u.
pub fn push_sphere(g: &mut Geometry, c: Vec3, r: f32, segments: u32, rings: u32, repeat: f32, material: u32) {
    let uv_scale = Vec2::new(repeat, repeat * 0.5);
    g.push_uv_sphere(c, r, (segments, rings), uv_scale, true, material);
}

/// Appends a closed cylinder of radius `r` and height `h` standing on the point `base`
/// (axis +y), with smooth sides, flat caps, texture coordinates in units of `tile` and
/// tangents.
pub fn push_cylinder(g: &mut Geometry, base: Vec3, r: f32, h: f32, segments: u32, tile: f32, material: u32) {
    let segments = segments.max(3);
    let circumference = std::f32::consts::TAU * r;
    let mut pos = Vec::new();
    let mut nrm = Vec::new();
    let mut uv = Vec::new();
    let mut tan = Vec::new();
    for j in 0..2u32 {
        let y = j as f32 * h;
        for i in 0..=segments {
            let phi = i as f32 / segments as f32 * std::f32::consts::TAU;
            let n = Vec3::new(phi.cos(), 0.0, -phi.sin());
            pos.push(base + r * n + Vec3::Y * y);
            nrm.push(n);
            uv.push(Vec2::new(
                i as f32 / segments as f32 * circumference / tile,
                -y / tile,
            ));
            tan.push(Vec4::new(-phi.sin(), 0.0, -phi.cos(), 1.0));
        }
    }
    let row = segments + 1;
    let mut tris = Vec::new();
    for i in 0..segments {
        let (a, b) = (i, i + 1);
        let (c, d) = (b + row, a + row);
        tris.push([a, b, c]);
        tris.push([a, c, d]);
    }
    g.push_mesh(&pos, Some(&nrm), Some(&uv), Some(&tan), &tris, material);
    // Caps: centre + rim.
    for top in [false, true] {
        let y = if top { h } else { 0.0 };
        let n = if top { Vec3::Y } else { Vec3::NEG_Y };
        let mut p = vec![base + Vec3::Y * y];
        let mut t = vec![Vec2::ZERO];
        for i in 0..segments {
            let phi = i as f32 / segments as f32 * std::f32::consts::TAU;
            let off = Vec3::new(phi.cos(), 0.0, -phi.sin()) * r;
            p.push(base + off + Vec3::Y * y);
            t.push(Vec2::new(off.x, if top { off.z } else { -off.z }) / tile);
        }
        let tris: Vec<[u32; 3]> = (0..segments)
            .map(|i| {
                let (a, b) = (1 + i, 1 + (i + 1) % segments);
                if top { [0, a, b] } else { [0, b, a] }
            })
            .collect();
        let k = p.len();
        g.push_mesh(
            &p,
            Some(&vec![n; k]),
            Some(&t),
            Some(&vec![Vec4::new(1.0, 0.0, 0.0, 1.0); k]),
            &tris,
            material,
        );
    }
}

// ---------------------------------------------------------------------------------------
// Textures.

/// Texture size of the procedural textures.
const TEX: u32 = 128;

fn hash3(x: u32, y: u32, s: u32) -> f32 {
    let h = mix(((x as u64) << 40) ^ ((y as u64) << 20) ^ s as u64);
    (h >> 40) as f32 / (1u64 << 24) as f32
}

/// Tileable value noise of lattice period `period` at texel `(x, y)` of a `TEX`-texel tile.
fn value_noise(x: f32, y: f32, period: u32, seed: u32) -> f32 {
    let cell = TEX as f32 / period as f32;
    let (fx, fy) = (x / cell, y / cell);
    let (ix, iy) = (fx.floor(), fy.floor());
    let (tx, ty) = (fx - ix, fy - iy);
    let s = |v: f32| v * v * (3.0 - 2.0 * v);
    let (sx, sy) = (s(tx), s(ty));
    let at = |i: f32, j: f32| {
        let i = (i as i64).rem_euclid(period as i64) as u32;
        let j = (j as i64).rem_euclid(period as i64) as u32;
        hash3(i, j, seed)
    };
    let a = at(ix, iy) + (at(ix + 1.0, iy) - at(ix, iy)) * sx;
    let b = at(ix, iy + 1.0) + (at(ix + 1.0, iy + 1.0) - at(ix, iy + 1.0)) * sx;
    a + (b - a) * sy
}

/// Tileable fractal noise in about [0, 1].
fn fbm(x: f32, y: f32, base_period: u32, octaves: u32, seed: u32) -> f32 {
    let (mut sum, mut amp, mut norm, mut period) = (0.0, 1.0, 0.0, base_period);
    for o in 0..octaves {
        sum += amp * value_noise(x, y, period.min(TEX), seed.wrapping_add(o * 7919));
        norm += amp;
        amp *= 0.5;
        period *= 2;
    }
    sum / norm
}

fn linear_to_srgb_u8(c: f32) -> u8 {
    let c = c.clamp(0.0, 1.0);
    let s = if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0).round() as u8
}

/// `f(x, y)` of every texel of a TEX x TEX image, row by row.
fn texels<T>(f: impl Fn(u32, u32) -> T) -> Vec<T> {
    let mut texels = Vec::with_capacity((TEX * TEX) as usize);
    for y in 0..TEX {
        for x in 0..TEX {
            texels.push(f(x, y));
        }
    }
    texels
}

fn texture(name: String, srgb: bool, f: impl Fn(u32, u32) -> [u8; 4]) -> Texture {
    Texture {
        name,
        width: TEX,
        height: TEX,
        texels: texels(f),
        srgb,
        wrap: [Wrap::Repeat; 2],
    }
}

/// A tangent-space normal map of the tileable height field `h` (in texels of height per
/// texel) scaled by `strength`.
fn normal_map(name: String, heights: &[f32], strength: f32) -> Texture {
    let n = TEX as i64;
    let at = |x: i64, y: i64| heights[(y.rem_euclid(n) * n + x.rem_euclid(n)) as usize];
    texture(name, false, |x, y| {
        let (x, y) = (x as i64, y as i64);
        let dx = 0.5 * (at(x + 1, y) - at(x - 1, y));
        let dy = 0.5 * (at(x, y + 1) - at(x, y - 1));
        // Tangent space: +x right (u), +y up the image (towards decreasing v).
        let nrm = Vec3::new(-strength * dx, strength * dy, 1.0).normalize();
        let e = |v: f32| ((v * 0.5 + 0.5) * 255.0).round() as u8;
        [e(nrm.x), e(nrm.y), e(nrm.z), 255]
    })
}

/// The procedural texture patterns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Pattern {
    Checker,
    Stripes,
    Noise,
    Bricks,
    Tiles,
}

impl Pattern {
    const ALL: [Pattern; 5] = [
        Pattern::Checker,
        Pattern::Stripes,
        Pattern::Noise,
        Pattern::Bricks,
        Pattern::Tiles,
    ];
    fn name(self) -> &'static str {
        match self {
            Pattern::Checker => "checker",
            Pattern::Stripes => "stripes",
            Pattern::Noise => "noise",
            Pattern::Bricks => "bricks",
            Pattern::Tiles => "tiles",
        }
    }
}

/// A random colour (linear RGB) of saturation and value in the given ranges.
fn colour(rng: &mut Rng, sat: (f32, f32), val: (f32, f32)) -> Vec3 {
    let h = rng.f() * 6.0;
    let s = rng.range(sat.0, sat.1);
    let v = rng.range(val.0, val.1);
    let c = v * s;
    let x = c * (1.0 - ((h % 2.0) - 1.0).abs());
    let (r, g, b) = match h as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let m = v - c;
    // HSV is taken as sRGB-encoded; decode to linear.
    super::scene::srgb_to_linear(Vec3::new(r + m, g + m, b + m))
}

// ---------------------------------------------------------------------------------------
// The scene builder.

/// A horizontal surface objects can stand on.
#[derive(Debug, Clone, Copy)]
struct Area {
    min: Vec2,
    max: Vec2,
    y: f32,
}

impl Area {
    fn size(&self) -> f32 {
        (self.max - self.min).max(Vec2::ZERO).element_product()
    }
}

/// Something placed: a vertical cylinder `(centre xz, radius, y range)` kept free.
#[derive(Debug, Clone, Copy)]
struct Footprint {
    c: Vec2,
    r: f32,
    y0: f32,
    y1: f32,
}

/// Where objects were meant to be seen from: free space for the camera.
#[derive(Debug, Clone, Copy)]
struct CameraRegion {
    min: Vec3,
    max: Vec3,
}

/// What materials are for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Use {
    /// An object with a closed surface (solid glass allowed).
    Closed,
    /// An open or one-sided surface.
    Open,
    /// Floor or ground.
    Floor,
    /// Walls.
    Wall,
}

struct Builder<'a> {
    rng: Rng,
    lib: &'a mut PropLibrary,
    scene: Scene,
    enclosure: Enclosure,
    areas: Vec<Area>,
    placed: Vec<Footprint>,
    camera_region: CameraRegion,
    /// Points worth looking at (object centres).
    interests: Vec<Vec3>,
    /// A feature of the enclosure worth looking at (the steps).
    feature: Option<Vec3>,
    objects: usize,
    object_tris: std::ops::Range<usize>,
    props: Vec<String>,
    prop_materials: HashMap<(usize, u32), u32>,
    prop_textures: HashMap<(usize, u32), u32>,
    prop_triangles: usize,
    warnings: Vec<String>,
    /// Floor area, for light power.
    floor_area: f32,
    /// Whether the enclosure is closed (orbits are then checked against the walls).
    indoor: bool,
}

impl<'a> Builder<'a> {
    fn new(seed: u64, sub: u64, lib: &'a mut PropLibrary) -> Self {
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

    fn material(&mut self, m: Material) -> u32 {
        self.scene.materials.push(m);
        self.scene.materials.len() as u32 - 1
    }

    fn texture(&mut self, t: Texture) -> u32 {
        self.scene.textures.push(t);
        self.scene.textures.len() as u32 - 1
    }

    fn tris(&self) -> usize {
        self.scene.geometry.triangles.len()
    }

    // --- Materials -------------------------------------------------------------------

    /// A procedurally textured material: base colour, normal map, sometimes a roughness map.
    fn textured(&mut self, pattern: Pattern, name: &str) -> Material {
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
    fn cutout(&mut self, leaves: bool) -> Material {
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
    fn metal(&mut self) -> Material {
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

    fn glass(&mut self, thin: bool) -> Material {
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

    fn plain(&mut self, glossy: bool) -> Material {
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
    fn emitter(&mut self, radiance: f32, name: &str) -> Material {
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
    fn random_material(&mut self, usage: Use) -> u32 {
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

    // --- Environment -----------------------------------------------------------------

    /// An environment: a map from the props (randomly rotated, normalised to a mean
    /// radiance of about `level`), else a procedural sky with a sun.
    fn environment(&mut self, level: f32) -> Environment {
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
    fn sky(&mut self, level: f32) -> Environment {
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
        let mut e = Environment {
            source: PathBuf::from(format!(
                "procedural sky (sun {:.0} deg up)",
                elevation.to_degrees()
            )),
            width: w,
            height: h,
            pixels,
            scale: 1.0,
            to_world: Mat3::IDENTITY,
            portals: Vec::new(),
        };
        let mean = mean_radiance(&e);
        e.scale = if mean > 0.0 { level / mean } else { 1.0 };
        e
    }

    // --- Lights ----------------------------------------------------------------------

    /// An area light: a rectangle centred at `c` with edges `u`, `v` (facing `u x v`) of
    /// total power about `power`.
    fn area_light(&mut self, c: Vec3, u: Vec3, v: Vec3, power: f32) {
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
    fn small_light(&mut self, c: Vec3, power: f32) {
        let r = self.rng.range(0.015, 0.05);
        let l = power / (4.0 * std::f32::consts::PI * std::f32::consts::PI * r * r);
        let m = self.emitter(l.min(20000.0), "small light");
        let m = self.material(m);
        push_sphere(&mut self.scene.geometry, c, r, 12, 6, 1.0, m);
    }

    /// Interior lights of a room `[-w/2, w/2] x [0, h] x [-d/2, d/2]` (as seen from inside).
    fn ceiling_lights(&mut self, w: f32, d: f32, h: f32, area_lights: u32, small: u32, power: f32) {
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

    // --- Enclosures ------------------------------------------------------------------

    /// Builds the scene of enclosure kind `kind`.
    fn build(&mut self, kind: Enclosure) {
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
    fn windows(&mut self, width: f32, height: f32, n: u32) -> Vec<[f32; 4]> {
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
    fn box_room(
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
    fn dress_windows(
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

    fn room(&mut self) {
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
    fn maybe_wall_panel(&mut self, w: f32, d: f32, h: f32, power: f32) {
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

    fn open_ground(&mut self) {
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

    fn corridor(&mut self) {
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
    fn cut_right_wall(&mut self, w: f32, l: f32, h: f32, holes: &[[f32; 4]]) {
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

    fn steps(&mut self) {
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

    // --- Objects ---------------------------------------------------------------------

    /// A free spot of radius `r` and height `height` on one of the areas (weighted by size).
    fn spot(&mut self, r: f32, height: f32) -> Option<Vec3> {
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

    fn populate(&mut self, n: u32) {
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

    fn object_size(&mut self) -> f32 {
        match self.rng.weighted(&[2.0, 5.0, 2.0]) {
            0 => self.rng.range(0.08, 0.2),
            1 => self.rng.range(0.2, 0.5),
            _ => self.rng.range(0.5, 0.9),
        }
    }

    fn add_box(&mut self) {
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

    fn add_sphere(&mut self) {
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

    fn add_cylinder(&mut self) {
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

    fn add_table(&mut self) {
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

    fn add_plant(&mut self) {
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

    fn add_screen(&mut self) {
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

    fn add_lamp(&mut self) {
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

    fn done_object(&mut self, c: Vec3) {
        self.objects += 1;
        self.interests.push(c);
    }

    fn add_prop(&mut self) {
        let s = self.rng.range(0.3, 1.4);
        self.add_prop_sized(s);
    }

    /// A prop (a whole glTF scene, or the triangles of one of its materials) scaled to a
    /// largest extent of `size`, turned about +y and set on a free spot.
    fn add_prop_sized(&mut self, size: f32) {
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

    // --- Camera ----------------------------------------------------------------------

    /// A first camera (refined by [`Builder::finish`] with the BVH).
    fn choose_camera_seed(&mut self) {
        let c = self.camera_candidate();
        self.scene.camera = c;
    }

    /// A camera in the camera region, away from objects, looking at one or a few of them
    /// (or at the enclosure's feature, such as the steps) from at least 1.2 m.
    fn camera_candidate(&mut self) -> Camera {
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
    fn finish(mut self, attempt: u32) -> Result<Option<Generated>> {
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
    fn clear_view(bvh: &SceneBvh, p: Vec3, target: Vec3) -> bool {
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
    fn camera_path(&mut self, bvh: &SceneBvh) -> CameraPathSpec {
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
    fn fallback(&mut self) {
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

/// Scales a material's base colour up so its luminance is at least `min` (large surfaces
/// that are almost black make dark, noisy images).
fn brighten(m: &mut Material, min: f32) {
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

// ---------------------------------------------------------------------------------------
// The view check.

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
struct Sun {
    dir: Vec3,
    irradiance: f32,
    /// Scaled luminance above which a texel belongs to the sun.
    threshold: f32,
}

fn sun_of(e: &Environment) -> Option<Sun> {
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

// ---------------------------------------------------------------------------------------
// Summary.

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

#[cfg(test)]
mod tests {
    use super::*;

    fn fingerprint(s: &Scene) -> u64 {
        let mut h = 0xcbf2_9ce4_8422_2325u64;
        let mut eat = |v: u64| {
            h ^= v;
            h = h.wrapping_mul(0x0100_0000_01b3);
        };
        for p in &s.geometry.positions {
            for c in p.to_array() {
                eat(c.to_bits() as u64);
            }
        }
        for t in &s.geometry.triangles {
            eat(((t[0] as u64) << 32) ^ ((t[1] as u64) << 16) ^ t[2] as u64);
        }
        for &m in &s.geometry.materials {
            eat(m as u64);
        }
        for m in &s.materials {
            for c in m.base_color.iter().chain(&m.emissive).chain([
                &m.metallic,
                &m.roughness,
                &m.transmission,
                &m.ior,
            ]) {
                eat(c.to_bits() as u64);
            }
            eat(m.base_color_texture.map_or(u64::MAX, |t| t as u64));
        }
        for t in &s.textures {
            for px in t.texels.iter().step_by(17) {
                eat(u32::from_le_bytes(*px) as u64);
            }
        }
        if let Some(e) = &s.environment {
            eat(e.scale.to_bits() as u64);
            for p in e.pixels.iter().step_by(97) {
                eat(p[0].to_bits() as u64);
            }
        }
        eat(s.camera.position.x.to_bits() as u64);
        eat(format!("{:?}", s.camera_path).len() as u64);
        h
    }

    fn no_props() -> PropLibrary {
        PropLibrary::default()
    }

    /// The environment's portals are the open windows and those with smooth panes: through
    /// each, at least one of three points is open or behind such a pane or a cut-out grille
    /// (objects placed against a wall may cover the rest), a rough pane is never met, and
    /// the camera, in the room, is on its inner side.
    #[test]
    fn portals_are_open_windows() {
        let mut lib = no_props();
        let (mut with, mut portals, mut panes) = (0, 0, 0);
        for seed in 0..48u64 {
            let s = generate_with(seed, &mut lib).unwrap().scene;
            let Some(e) = &s.environment else { continue };
            if e.portals.is_empty() {
                continue;
            }
            with += 1;
            let bvh = SceneBvh::build(&s.name, &s.geometry.positions, &s.geometry.triangles).unwrap();
            for q in &e.portals {
                portals += 1;
                let n = q.u.cross(q.v).normalize();
                let mut open = 0;
                for (a, b) in [(0.5, 0.5), (0.2, 0.3), (0.8, 0.7)] {
                    let p = q.corner + a * q.u + b * q.v;
                    let hit = bvh.intersect(p + 0.1 * n, -n, 0.2);
                    let Some((tri, _)) = hit else {
                        open += 1;
                        continue;
                    };
                    let m = &s.materials[s.geometry.materials[bvh.order[tri as usize] as usize] as usize];
                    let rough_pane = m.thin && m.transmission > 0.0 && !straight_through(m);
                    assert!(!rough_pane, "seed {seed}: portal {q:?} behind a rough pane");
                    if straight_through(m) {
                        panes += 1;
                        open += 1;
                    } else if matches!(m.alpha, AlphaMode::Mask(_)) {
                        open += 1; // a grille: cut-outs let shadow rays through
                    }
                }
                assert!(open > 0, "seed {seed}: portal {q:?} is blocked");
                assert!(
                    (s.camera.position - q.corner).dot(n) > 0.0,
                    "seed {seed}: portal {q:?} faces away from the camera in the room"
                );
            }
        }
        assert!(
            with >= 5 && portals >= with && panes > 0,
            "{with} scenes with {portals} portals, {panes} pane hits"
        );
    }

    #[test]
    fn seeds_validate_light_and_see_geometry() {
        let mut enclosures = std::collections::BTreeSet::new();
        let mut kinds = std::collections::BTreeSet::new();
        let mut paths = std::collections::BTreeSet::new();
        let mut prints = std::collections::HashSet::new();
        let mut lib = no_props();
        for seed in 0..64u64 {
            let g = generate_with(seed, &mut lib).unwrap();
            let s = &g.scene;
            s.validate().unwrap_or_else(|e| panic!("seed {seed}: {e}"));
            assert_eq!(s.name, format!("builtin:procedural:{seed}"));
            assert!(
                (5..=40).contains(&g.objects) || g.attempt == MAX_ATTEMPTS,
                "seed {seed}: {} objects",
                g.objects
            );
            // Light: an emitter used by a triangle, or an environment.
            let emitter = s
                .geometry
                .materials
                .iter()
                .any(|&m| s.materials[m as usize].emitted_luminance(&s.textures) > 0.0);
            assert!(emitter || s.environment.is_some(), "seed {seed}: no light");
            // Visible geometry from the camera, checked independently here.
            let bvh = SceneBvh::build(&s.name, &s.geometry.positions, &s.geometry.triangles).unwrap();
            let (w, h) = s.film;
            let mut hit = 0;
            for j in 0..8 {
                for i in 0..8 {
                    let px = Vec2::new(
                        (i as f32 + 0.5) * w as f32 / 8.0,
                        (j as f32 + 0.5) * h as f32 / 8.0,
                    );
                    let d = s.camera.ray_dir(px, w, h);
                    hit += bvh.intersect(s.camera.position, d, f32::INFINITY).is_some() as u32;
                }
            }
            assert!(hit >= 16, "seed {seed}: only {hit} of 64 rays hit geometry");
            assert!(g.view.ok(), "seed {seed}: {:?}", g.view);
            // Exposure: the direct-light estimate of the image mean is never near-black.
            assert!(
                g.view.estimate >= 0.02 && g.view.estimate <= 2.0,
                "seed {seed}: estimate {} (gain {})",
                g.view.estimate,
                g.light_gain
            );
            enclosures.insert(g.enclosure);
            for (k, _) in material_kinds(s) {
                kinds.insert(k);
            }
            paths.insert(match &s.camera_path {
                Some(CameraPathSpec::Static) => "static",
                Some(CameraPathSpec::Orbit { .. }) => "orbit",
                Some(CameraPathSpec::FlyThrough {
                    cut_every: Some(_), ..
                }) => "cuts",
                Some(CameraPathSpec::FlyThrough { keys: Some(_), .. }) => "keys",
                Some(CameraPathSpec::FlyThrough { .. }) => "flythrough",
                None => "none",
            });
            assert!(
                prints.insert(fingerprint(s)),
                "seed {seed} repeats an earlier scene"
            );
        }
        assert_eq!(enclosures.len(), Enclosure::ALL.len(), "{enclosures:?}");
        assert_eq!(kinds.len(), MaterialKind::ALL.len(), "{kinds:?}");
        for p in ["static", "orbit", "flythrough", "keys", "cuts"] {
            assert!(paths.contains(p), "no {p} camera path in 64 seeds: {paths:?}");
        }
    }

    #[test]
    fn same_seed_same_scene() {
        for seed in [0u64, 7, 12345, u64::MAX] {
            let a = procedural(seed, &SceneOptions::default()).unwrap();
            let b = procedural(seed, &SceneOptions::default()).unwrap();
            assert_eq!(a.geometry.triangles.len(), b.geometry.triangles.len());
            assert_eq!(fingerprint(&a), fingerprint(&b), "seed {seed}");
            assert_eq!(a.camera, b.camera);
            assert_eq!(a.camera_path, b.camera_path);
        }
        let a = fingerprint(&procedural(1, &SceneOptions::default()).unwrap());
        let b = fingerprint(&procedural(2, &SceneOptions::default()).unwrap());
        assert_ne!(a, b);
    }

    #[test]
    fn seeds_parse_and_resolve() {
        assert_eq!(parse_seed("42").unwrap(), 42);
        assert_eq!(parse_seed("0xff").unwrap(), 255);
        assert_eq!(parse_seed(&u64::MAX.to_string()).unwrap(), u64::MAX);
        let e = parse_seed("seven").unwrap_err().to_string();
        assert!(e.contains("builtin:procedural:seven"), "{e}");
        let s = super::super::load::load_scene("builtin:procedural:3").unwrap();
        assert_eq!(s.name, "builtin:procedural:3");
        assert!(super::super::load::load_scene("builtin:procedural:").is_err());
        assert!(super::super::load::load_scene("builtin:procedural:-1").is_err());
    }

    #[test]
    fn failed_attempts_retry_deterministically() {
        SABOTAGE.with(|s| s.set(3));
        let a = generate(5, &SceneOptions::default()).unwrap();
        let b = generate(5, &SceneOptions::default()).unwrap();
        SABOTAGE.with(|s| s.set(0));
        assert!(a.attempt >= 3, "attempt {}", a.attempt);
        assert!(a.view.ok() && a.view.has_light);
        assert_eq!(fingerprint(&a.scene), fingerprint(&b.scene));
        // Every attempt sabotaged: the fallback scene.
        SABOTAGE.with(|s| s.set(MAX_ATTEMPTS));
        let f = generate(5, &SceneOptions::default()).unwrap();
        SABOTAGE.with(|s| s.set(0));
        assert_eq!(f.attempt, MAX_ATTEMPTS);
        assert!(f.view.ok());
        f.scene.validate().unwrap();
    }

    #[test]
    fn view_check_rejects_dark_and_empty_views() {
        let g = generate(11, &SceneOptions::default()).unwrap();
        let mut s = g.scene.clone();
        let bvh = SceneBvh::build(&s.name, &s.geometry.positions, &s.geometry.triangles).unwrap();
        assert!(check_view(&s, &bvh, &s.camera, Some(g.object_triangles.clone())).ok());
        // Looking away from everything, from far outside.
        let away = Camera {
            position: Vec3::new(0.0, 500.0, 0.0),
            target: Vec3::new(0.0, 1000.0, 0.0),
            ..s.camera
        };
        let v = check_view(&s, &bvh, &away, None);
        assert!(!v.ok() && v.geometry == 0.0, "{v:?}");
        // No light at all.
        for m in &mut s.materials {
            m.emissive = [0.0; 3];
        }
        s.environment = None;
        let v = check_view(&s, &bvh, &s.camera, None);
        assert!(!v.ok() && !v.has_light && v.lit == 0.0, "{v:?}");
    }

    /// A glTF box (24 vertices, normals, uvs) with one material, as a data URI.
    fn box_gltf() -> String {
        let mut g = Geometry::default();
        push_box(
            &mut g,
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(0.5, 1.0, 0.25),
            Quat::IDENTITY,
            1.0,
            0,
        );
        let mut bytes = Vec::new();
        for p in &g.positions {
            for c in p.to_array() {
                bytes.extend(c.to_le_bytes());
            }
        }
        let nb = bytes.len();
        for t in &g.triangles {
            for i in t {
                bytes.extend((*i as u16).to_le_bytes());
            }
        }
        let ib = bytes.len() - nb;
        let b64 = {
            const A: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
            let mut s = String::new();
            for c in bytes.chunks(3) {
                let n = (c[0] as u32) << 16
                    | (*c.get(1).unwrap_or(&0) as u32) << 8
                    | *c.get(2).unwrap_or(&0) as u32;
                for k in 0..4 {
                    s.push(if k <= c.len() {
                        A[(n >> (18 - 6 * k) & 63) as usize] as char
                    } else {
                        '='
                    });
                }
            }
            s
        };
        format!(
            r#"{{"asset": {{"version": "2.0"}}, "scene": 0, "scenes": [{{"nodes": [0]}}],
            "nodes": [{{"mesh": 0}}],
            "materials": [{{"name": "teal", "pbrMetallicRoughness": {{"baseColorFactor": [0.1, 0.6, 0.6, 1], "metallicFactor": 0, "roughnessFactor": 0.4}}}}],
            "meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0}}, "indices": 1, "material": 0}}]}}],
            "accessors": [
              {{"bufferView": 0, "componentType": 5126, "count": {nv}, "type": "VEC3", "min": [-0.5, 0, -0.25], "max": [0.5, 2, 0.25]}},
              {{"bufferView": 1, "componentType": 5123, "count": {ni}, "type": "SCALAR"}}],
            "bufferViews": [{{"buffer": 0, "byteOffset": 0, "byteLength": {nb}}}, {{"buffer": 0, "byteOffset": {nb}, "byteLength": {ib}}}],
            "buffers": [{{"byteLength": {total}, "uri": "data:application/octet-stream;base64,{b64}"}}]}}"#,
            nv = g.positions.len(),
            ni = g.triangles.len() * 3,
            total = bytes.len(),
        )
    }

    #[test]
    fn broken_props_are_skipped_with_one_warning() {
        let d = crate::io::test_dir("props");
        let sub = d.join("nested");
        std::fs::create_dir_all(&sub).unwrap();
        std::fs::write(d.join("broken.gltf"), "{ this is not glTF").unwrap();
        std::fs::write(sub.join("good.gltf"), box_gltf()).unwrap();
        std::fs::write(d.join("notes.txt"), "ignored").unwrap();
        let opts = SceneOptions {
            props: vec![d.clone()],
        };
        let mut lib = PropLibrary::load(&opts.props).unwrap();
        assert_eq!(lib.files.len(), 1, "{:?}", lib.warnings);
        assert_eq!(lib.warnings.len(), 1, "{:?}", lib.warnings);
        assert!(lib.warnings[0].contains("broken.gltf"), "{:?}", lib.warnings);
        let mut used = 0;
        for seed in 0..12 {
            let g = generate_with(seed, &mut lib).unwrap();
            g.scene.validate().unwrap();
            assert!(g.view.ok());
            let named: Vec<_> = g.warnings.iter().filter(|w| w.contains("broken.gltf")).collect();
            assert_eq!(named.len(), 1, "seed {seed}: {:?}", g.warnings);
            used += g.props.len();
            if !g.props.is_empty() {
                assert!(g.scene.materials.iter().any(|m| m.name == "teal"));
                assert!(g.props.iter().all(|p| p.contains("good.gltf")));
            }
        }
        assert!(used > 0, "the good prop was never placed");
        // The same through the public entry point.
        let s = super::super::load::load_scene_with("builtin:procedural:4", &opts).unwrap();
        s.validate().unwrap();
        // A props path that does not exist is an error naming it.
        let e = generate(
            1,
            &SceneOptions {
                props: vec![d.join("missing-folder")],
            },
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("missing-folder"), "{e}");
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn mesh_generators_face_outwards_with_consistent_tangents() {
        let mut g = Geometry::default();
        let c = Vec3::new(1.0, 2.0, -3.0);
        push_sphere(&mut g, c, 0.7, 16, 8, 1.0, 0);
        push_box(
            &mut g,
            c,
            Vec3::new(0.3, 0.5, 0.2),
            Quat::from_rotation_y(0.4),
            1.0,
            0,
        );
        push_cylinder(&mut g, c - Vec3::Y * 0.5, 0.4, 1.0, 12, 1.0, 0);
        for (k, t) in g.triangles.iter().enumerate() {
            let [a, b, cc] = t.map(|i| g.positions[i as usize]);
            let n = (b - a).cross(cc - a);
            let mid = (a + b + cc) / 3.0;
            assert!(n.dot(mid - c) > 0.0, "triangle {k} faces inwards");
            for &i in t {
                let (nn, tt) = (g.normals[i as usize], g.tangents[i as usize]);
                assert!(nn.dot(n.normalize()) > 0.0 || n.length() < 1e-6, "normal of {k}");
                assert!(
                    tt.truncate().dot(nn).abs() < 1e-3,
                    "tangent not perpendicular at {k}"
                );
                assert!(tt.w == 1.0);
            }
        }
        // Box faces: the bitangent (n x t) runs towards decreasing v, like the builtin room.
        let mut g = Geometry::default();
        push_box(&mut g, Vec3::ZERO, Vec3::ONE, Quat::IDENTITY, 1.0, 0);
        for t in &g.triangles {
            let [i0, i1, i2] = t.map(|i| i as usize);
            let (p0, p1, p2) = (g.positions[i0], g.positions[i1], g.positions[i2]);
            let (u0, u1, u2) = (g.uvs[i0], g.uvs[i1], g.uvs[i2]);
            // dP/dv from the triangle.
            let (e1, e2) = (p1 - p0, p2 - p0);
            let (d1, d2) = (u1 - u0, u2 - u0);
            let r = 1.0 / (d1.x * d2.y - d2.x * d1.y);
            let dpdv = (e2 * d1.x - e1 * d2.x) * r;
            let b = g.normals[i0].cross(g.tangents[i0].truncate());
            assert!(b.dot(dpdv) < 0.0, "bitangent along +v");
        }
        // A wall with a hole leaves the hole open and covers the rest.
        let mut g = Geometry::default();
        push_wall(
            &mut g,
            Vec3::ZERO,
            Vec3::X,
            Vec3::Y,
            4.0,
            3.0,
            &[[1.0, 2.0, 1.0, 2.0]],
            1.0,
            0,
        );
        let area: f32 = g
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| g.positions[i as usize]);
                0.5 * (b - a).cross(c - a).length()
            })
            .sum();
        assert!((area - 11.0).abs() < 1e-4, "{area}");
        let bvh = SceneBvh::build("wall", &g.positions, &g.triangles).unwrap();
        assert!(
            bvh.intersect(Vec3::new(1.5, 1.5, 1.0), Vec3::NEG_Z, 5.0)
                .is_none()
        );
        assert!(
            bvh.intersect(Vec3::new(0.5, 1.5, 1.0), Vec3::NEG_Z, 5.0)
                .is_some()
        );
    }

    #[test]
    fn explicit_cut_paths_jump_between_keys() {
        use super::super::camera::CameraPath;
        let mut found = false;
        for seed in 0..64u64 {
            let s = procedural(seed, &SceneOptions::default()).unwrap();
            let Some(
                spec @ CameraPathSpec::FlyThrough {
                    cut_every: Some(n),
                    keys: Some(keys),
                    ..
                },
            ) = &s.camera_path
            else {
                continue;
            };
            found = true;
            let bvh = SceneBvh::build(&s.name, &s.geometry.positions, &s.geometry.triangles).unwrap();
            let path = CameraPath::from_spec(spec, &s.camera, 0, 4 * n, &bvh);
            assert_eq!(path.camera(0).position, keys[0].position);
            assert!(path.is_cut(*n) && !path.is_cut(*n - 1) && !path.is_cut(0));
            assert!(path.camera(*n).position.distance(keys[1].position) < 1e-5);
            break;
        }
        assert!(found, "no seed of 0..64 has explicit cuts");
    }
}
