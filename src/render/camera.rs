//! Pinhole cameras and camera paths (static, orbit, keyframed fly-through with Catmull-Rom
//! interpolation, optionally cut into shots), deterministic from a seed.
//!
//! **Cuts and motion vectors.** A fly-through with `cut_every: Some(n)` jumps to another
//! viewpoint every `n` frames ([`CameraPath::is_cut`] says where). The renderer computes
//! motion vectors from the previous frame's camera, so at a cut frame they reproject each
//! pixel into the *previous shot's* camera: geometrically correct, but most history they
//! point to shows something else or lies off screen. They do not pretend continuity, and a
//! denoiser has to reject that history (SSR's TFA learns to, given cuts in its training
//! data). A consumer that prefers to restart its history can test [`CameraPath::is_cut`].

use bytemuck::{Pod, Zeroable};
use glam::{Vec2, Vec3};

/// A pinhole camera looking from `position` at `target`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Eye position (world).
    pub position: Vec3,
    /// Point looked at.
    pub target: Vec3,
    /// Up hint.
    pub up: Vec3,
    /// Vertical field of view in radians.
    pub yfov: f32,
}

/// The camera as the WGSL `Camera` struct lays it out.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, PartialEq)]
pub struct GpuCamera {
    /// Position xyz, w = tan(yfov / 2).
    pub pos: [f32; 4],
    /// Right axis xyz, w = aspect (width / height).
    pub right: [f32; 4],
    /// Up axis.
    pub up: [f32; 4],
    /// Forward axis.
    pub fwd: [f32; 4],
}

impl Camera {
    /// Checks the camera can form an image: finite position, target and up, a target
    /// apart from the position, an up not parallel to the view direction, a field of view
    /// in (0, 180) degrees. The error names the field (a degenerate camera would render
    /// black frames or NaN motion vectors).
    pub fn check(&self) -> Result<(), String> {
        for (name, v) in [
            ("position", self.position),
            ("target", self.target),
            ("up", self.up),
        ] {
            if !v.is_finite() {
                return Err(format!("camera {name} {v} is not finite"));
            }
        }
        let view = self.target - self.position;
        let scale = self
            .position
            .abs()
            .max_element()
            .max(self.target.abs().max_element())
            .max(1.0);
        if !view.is_finite() || view.length() <= 1e-6 * scale {
            return Err(format!(
                "camera target {} equals its position {} (no view direction)",
                self.target, self.position
            ));
        }
        let (f, u) = (view.normalize(), self.up.normalize_or_zero());
        if u == Vec3::ZERO {
            return Err("camera up is the zero vector".into());
        }
        if f.cross(u).length() < 1e-4 {
            return Err(format!(
                "camera up {} is parallel to the view direction {f} (target - position)",
                self.up
            ));
        }
        if !(self.yfov > 1e-4 && self.yfov < std::f32::consts::PI - 1e-4) {
            return Err(format!(
                "camera yfov {} rad ({} degrees) must be in (0, 180) degrees",
                self.yfov,
                self.yfov.to_degrees()
            ));
        }
        Ok(())
    }

    /// Orthonormal `(right, up, forward)`.
    pub fn basis(&self) -> (Vec3, Vec3, Vec3) {
        let fwd = (self.target - self.position).normalize_or(Vec3::NEG_Z);
        let mut right = fwd.cross(self.up);
        if right.length_squared() < 1e-12 {
            right = fwd.cross(if fwd.y.abs() < 0.9 { Vec3::Y } else { Vec3::X });
        }
        let right = right.normalize();
        (right, right.cross(fwd), fwd)
    }

    /// GPU layout for an image of `width x height`.
    pub fn gpu(&self, width: u32, height: u32) -> GpuCamera {
        let (r, u, f) = self.basis();
        let aspect = width as f32 / height as f32;
        GpuCamera {
            pos: [
                self.position.x,
                self.position.y,
                self.position.z,
                (0.5 * self.yfov).tan(),
            ],
            right: [r.x, r.y, r.z, aspect],
            up: [u.x, u.y, u.z, 0.0],
            fwd: [f.x, f.y, f.z, 0.0],
        }
    }

    /// Unit direction through continuous pixel position `px` (pixel centres at +0.5, y down).
    pub fn ray_dir(&self, px: Vec2, width: u32, height: u32) -> Vec3 {
        let (r, u, f) = self.basis();
        let t = (0.5 * self.yfov).tan();
        let aspect = width as f32 / height as f32;
        let x = (2.0 * px.x / width as f32 - 1.0) * t * aspect;
        let y = (1.0 - 2.0 * px.y / height as f32) * t;
        (f + x * r + y * u).normalize()
    }

    /// Continuous pixel position of world point `p`, `None` behind the camera.
    pub fn project(&self, p: Vec3, width: u32, height: u32) -> Option<Vec2> {
        let (r, u, f) = self.basis();
        let v = p - self.position;
        let z = v.dot(f);
        if z <= 1e-12 {
            return None;
        }
        let t = (0.5 * self.yfov).tan();
        let aspect = width as f32 / height as f32;
        let x = v.dot(r) / (z * t * aspect);
        let y = v.dot(u) / (z * t);
        Some(Vec2::new(
            (x + 1.0) * 0.5 * width as f32,
            (1.0 - y) * 0.5 * height as f32,
        ))
    }
}

/// A camera path as requested (by the CLI or `scene.json`), before it is made concrete.
#[derive(Debug, Clone, PartialEq)]
pub enum CameraPathSpec {
    /// The scene camera, every frame.
    Static,
    /// Orbit about the scene camera's target at its distance and height.
    Orbit {
        /// Degrees per frame (sign: direction); `None` picks from the seed.
        degrees_per_frame: Option<f32>,
    },
    /// Catmull-Rom fly-through. Keys given explicitly, or generated from the seed around the
    /// scene camera.
    FlyThrough {
        /// Explicit key cameras; `None`: generated.
        keys: Option<Vec<Camera>>,
        /// Frames between consecutive keys: the speed (small: fast, large: slow).
        frames_per_key: f32,
        /// Cut to another viewpoint every this many frames (`None`: one continuous shot).
        /// Shot `s` covers frames `s*n .. (s+1)*n`. With explicit keys, shot `s` starts at
        /// key `s` (modulo their number) and flies on towards the next ones; generated shots
        /// start from viewpoints around what the scene camera looks at (shot 0: the scene
        /// camera), each a generated fly-through of its own. Motion vectors at a cut frame
        /// refer to the previous shot's camera (see the module documentation).
        cut_every: Option<u32>,
    },
}

/// Frames between generated fly-through keys when not given.
pub const DEFAULT_FRAMES_PER_KEY: f32 = 24.0;

/// Fastest orbit, in degrees per frame (a turn per frame is already no motion to see).
pub const MAX_ORBIT_DEGREES_PER_FRAME: f32 = 360.0;

impl CameraPathSpec {
    /// Checks the spec's numbers and explicit keys; the error names the field.
    pub fn check(&self) -> Result<(), String> {
        match self {
            CameraPathSpec::Static => Ok(()),
            CameraPathSpec::Orbit {
                degrees_per_frame: Some(d),
            } if !(d.is_finite() && d.abs() <= MAX_ORBIT_DEGREES_PER_FRAME) => Err(format!(
                "camera path orbit: degrees_per_frame {d} must be finite and at most \
                 {MAX_ORBIT_DEGREES_PER_FRAME} in size"
            )),
            CameraPathSpec::Orbit { .. } => Ok(()),
            CameraPathSpec::FlyThrough {
                keys, frames_per_key, ..
            } => {
                if !(frames_per_key.is_finite() && *frames_per_key >= 1.0) {
                    return Err(format!(
                        "camera path flythrough: frames_per_key {frames_per_key} must be at least 1"
                    ));
                }
                for (i, k) in keys.iter().flatten().enumerate() {
                    k.check()
                        .map_err(|e| format!("camera path flythrough: keys[{i}]: {e}"))?;
                }
                Ok(())
            }
        }
    }
}
/// Frames per shot of `cuts` when not given.
pub const DEFAULT_CUT_EVERY: u32 = 16;

impl std::str::FromStr for CameraPathSpec {
    type Err = String;
    /// `static`, `orbit[:DEG_PER_FRAME]`, `flythrough[:FRAMES_PER_KEY]` or
    /// `cuts[:FRAMES_PER_SHOT[:FRAMES_PER_KEY]]` (a generated fly-through that cuts to another
    /// viewpoint every `FRAMES_PER_SHOT` frames).
    fn from_str(s: &str) -> Result<Self, String> {
        let mut parts = s.split(':');
        let name = parts.next().unwrap_or_default();
        let args: Vec<&str> = parts.collect();
        let bad = || {
            format!(
                "unknown camera path '{s}' (static, orbit[:DEG_PER_FRAME], flythrough[:FRAMES_PER_KEY] \
                 or cuts[:FRAMES_PER_SHOT[:FRAMES_PER_KEY]])"
            )
        };
        let num = |i: usize| -> Result<Option<f32>, String> {
            match args.get(i) {
                None => Ok(None),
                Some(a) => match a.parse::<f32>() {
                    Ok(v) if v.is_finite() => Ok(Some(v)),
                    _ => Err(format!("camera path '{s}': '{a}' is not a number")),
                },
            }
        };
        let positive = |v: Option<f32>, what: &str| -> Result<Option<f32>, String> {
            match v {
                Some(v) if v < 1.0 => Err(format!("camera path '{s}': {what} must be at least 1")),
                v => Ok(v),
            }
        };
        match name {
            "static" if args.is_empty() => Ok(Self::Static),
            "orbit" if args.len() <= 1 => Ok(Self::Orbit {
                degrees_per_frame: num(0)?,
            }),
            "flythrough" | "fly-through" | "fly" if args.len() <= 1 => Ok(Self::FlyThrough {
                keys: None,
                frames_per_key: positive(num(0)?, "frames per key")?.unwrap_or(DEFAULT_FRAMES_PER_KEY),
                cut_every: None,
            }),
            "cuts" if args.len() <= 2 => Ok(Self::FlyThrough {
                keys: None,
                frames_per_key: positive(num(1)?, "frames per key")?.unwrap_or(DEFAULT_FRAMES_PER_KEY),
                cut_every: Some(
                    positive(num(0)?, "frames per shot")?
                        .map(|v| v.round() as u32)
                        .unwrap_or(DEFAULT_CUT_EVERY),
                ),
            }),
            _ => Err(bad()),
        }
    }
}

/// Ray queries against a scene, for camera paths generated inside it.
pub trait RayProbe {
    /// Distance to the first surface along the unit direction `dir` from `origin` within
    /// `tmax`, if any.
    fn first_hit(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<f32>;
}

/// Empty space: nothing is ever hit.
impl RayProbe for () {
    fn first_hit(&self, _origin: Vec3, _dir: Vec3, _tmax: f32) -> Option<f32> {
        None
    }
}

/// The position `home + s * offset` for the largest `s` in 1, 1/2, 1/4, ... (down to 0, the
/// home position itself) such that the move from `prev` is clear of geometry by a margin
/// and the view towards `target` is not blocked within a quarter of `focus`. The margin is
/// 5% of `focus`, also checked along the six axes around the position.
fn clear_position(
    probe: &dyn RayProbe,
    home: Vec3,
    prev: Vec3,
    offset: Vec3,
    target: Vec3,
    focus: f32,
) -> Vec3 {
    let margin = 0.05 * focus;
    let segment_clear = |a: Vec3, b: Vec3| {
        let d = b - a;
        let len = d.length();
        len < 1e-9 * focus || probe.first_hit(a, d / len, len + margin).is_none()
    };
    let view_clear = |p: Vec3| {
        let d = (target - p).normalize_or_zero();
        d == Vec3::ZERO || probe.first_hit(p, d, 0.25 * focus).is_none()
    };
    let mut s = 1.0f32;
    for _ in 0..10 {
        let p = home + offset * s;
        let room = [Vec3::X, Vec3::NEG_X, Vec3::Y, Vec3::NEG_Y, Vec3::Z, Vec3::NEG_Z]
            .iter()
            .all(|&d| probe.first_hit(p, d, margin).is_none());
        if room && segment_clear(home, p) && segment_clear(prev, p) && view_clear(p) {
            return p;
        }
        s *= 0.5;
    }
    home
}

/// Another viewpoint on what `base` looks at, for a cut: the base camera swung about its
/// focus point (the first surface along its view, else its target) by 40-140 degrees either
/// way, at 0.7-1.2 times the distance and a little higher or lower. A candidate is kept when
/// the straight move from the base camera to it is clear of geometry (so it never stands
/// outside the room the base camera is in), it has room around it and an unobstructed view
/// of the focus point; after 12 failed candidates the view turns about the base position
/// instead, and at worst the base camera is kept.
/// The distance to what `base` looks at (the first surface along its view, else its
/// target) and that point.
fn focus(base: &Camera, probe: &dyn RayProbe) -> (f32, Vec3) {
    let (_, _, f) = base.basis();
    let look = base.position.distance(base.target).max(1e-6);
    let focus = probe
        .first_hit(base.position, f, f32::INFINITY)
        .unwrap_or(look)
        .max(1e-6);
    (focus, base.position + f * focus)
}

fn shot_viewpoint(base: &Camera, probe: &dyn RayProbe, rng: &mut SplitMix) -> Camera {
    let (_, _, f) = base.basis();
    let (focus, aim) = focus(base, probe);
    let margin = 0.05 * focus;
    let roomy = |p: Vec3| {
        [Vec3::X, Vec3::NEG_X, Vec3::Y, Vec3::NEG_Y, Vec3::Z, Vec3::NEG_Z]
            .iter()
            .all(|&d| probe.first_hit(p, d, margin).is_none())
    };
    for _ in 0..12 {
        let angle = (40.0 + 100.0 * rng.next_f32()).to_radians() * rng.signed().signum();
        let dist = 0.7 + 0.5 * rng.next_f32();
        let lift = 0.2 * focus * rng.signed();
        let rel = base.position - aim;
        let (s, c) = angle.sin_cos();
        let rotated = Vec3::new(c * rel.x + s * rel.z, rel.y, -s * rel.x + c * rel.z) * dist;
        let p = aim + rotated + Vec3::Y * lift;
        let to = aim - p;
        let len = to.length();
        if !p.is_finite() || len < 1e-6 {
            continue;
        }
        // Reachable from the base camera in a straight line (so never outside the room
        // the base camera stands in), with room around it and a clear view of the focus.
        let step = p - base.position;
        let reach = step.length();
        let reachable = reach < 1e-6
            || probe
                .first_hit(base.position, step / reach, reach + margin)
                .is_none();
        let clear = probe.first_hit(p, to / len, 0.9 * len).is_none();
        if clear && reachable && roomy(p) {
            return Camera {
                position: p,
                target: aim,
                ..*base
            };
        }
    }
    for _ in 0..6 {
        let angle = (30.0 + 60.0 * rng.next_f32()).to_radians() * rng.signed().signum();
        let (s, c) = angle.sin_cos();
        let d = Vec3::new(c * f.x + s * f.z, f.y, -s * f.x + c * f.z);
        if let Some(t) = probe.first_hit(base.position, d, f32::INFINITY)
            && t > 0.25 * focus
        {
            return Camera {
                target: base.position + d * t,
                ..*base
            };
        }
    }
    *base
}

/// A concrete camera path: a camera per frame.
#[derive(Debug, Clone, PartialEq)]
pub enum CameraPath {
    /// One camera.
    Static(Camera),
    /// Circle about `centre` in the horizontal plane.
    Orbit {
        /// Camera at angle 0 (its target, up, fov are kept).
        base: Camera,
        /// Orbit centre (the base camera's target).
        centre: Vec3,
        /// Angle of frame 0, radians.
        start: f32,
        /// Radians per frame.
        step: f32,
    },
    /// Catmull-Rom spline through key cameras (positions and targets).
    Keyframes {
        /// Key cameras (at least 2).
        keys: Vec<Camera>,
        /// Frames between keys.
        frames_per_key: f32,
    },
    /// Shots of `frames_per_shot` frames each, with a cut (a jump) between them. Frame `f`
    /// is frame `f % frames_per_shot` of shot `f / frames_per_shot` (the last shot holds
    /// for frames past the end).
    Cuts {
        /// The shots (at least 1).
        shots: Vec<CameraPath>,
        /// Frames per shot (at least 1).
        frames_per_shot: u32,
    },
}

/// SplitMix64: a tiny deterministic generator for camera paths.
#[derive(Debug, Clone)]
pub struct SplitMix(u64);

impl SplitMix {
    /// Generator for `seed`.
    pub fn new(seed: u64) -> Self {
        Self(seed ^ 0x5851_f42d_4c95_7f2d)
    }
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    /// Uniform in `[0, 1)`.
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }
    /// Uniform in `[-1, 1)`.
    pub fn signed(&mut self) -> f32 {
        2.0 * self.next_f32() - 1.0
    }
}

fn catmull_rom(p0: Vec3, p1: Vec3, p2: Vec3, p3: Vec3, t: f32) -> Vec3 {
    let t2 = t * t;
    let t3 = t2 * t;
    0.5 * ((2.0 * p1)
        + (p2 - p0) * t
        + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * t2
        + (3.0 * p1 - p0 - 3.0 * p2 + p3) * t3)
}

impl CameraPath {
    /// Makes `spec` concrete around `base` for `frames` frames. Generated paths depend on
    /// `seed` only (and the base camera): orbits of different seeds sweep disjoint arcs
    /// (seed 0 starts at the base camera, then alternating sides), fly-throughs visit
    /// different random key positions.
    ///
    /// `probe` answers ray queries against the scene (a [`crate::render::bvh::SceneBvh`], or
    /// `&()` for empty space): generated fly-through keys never move through geometry and
    /// never stand right in front of a wall.
    pub fn from_spec(
        spec: &CameraPathSpec,
        base: &Camera,
        seed: u64,
        frames: u32,
        probe: &dyn RayProbe,
    ) -> Self {
        if let CameraPathSpec::FlyThrough {
            keys,
            frames_per_key,
            cut_every: Some(n),
        } = spec
        {
            return Self::cuts(
                keys.as_deref(),
                *frames_per_key,
                (*n).max(1),
                base,
                seed,
                frames,
                probe,
            );
        }
        match spec {
            CameraPathSpec::Static => CameraPath::Static(*base),
            CameraPathSpec::Orbit { degrees_per_frame } => {
                let mut rng = SplitMix::new(seed);
                let dir = if rng.next_u64() & 1 == 0 { 1.0 } else { -1.0 };
                let speed = degrees_per_frame.unwrap_or(dir * (0.75 + 0.5 * rng.next_f32()));
                let step = speed.to_radians();
                // Disjoint arcs: seed k occupies slot ceil(k/2) on alternating sides, each slot
                // as wide as the longest sweep of any seed (1.25 deg/frame) plus a gap.
                let slot = (1.25f32.to_radians() * frames.max(1) as f32 + 5f32.to_radians())
                    .min(std::f32::consts::TAU);
                let k = seed % 1_000_000;
                let index = k.div_ceil(2) as f32 * if k % 2 == 1 { 1.0 } else { -1.0 };
                let mut start = index * slot;
                if step < 0.0 {
                    start += -step * frames.saturating_sub(1) as f32; // sweep back into the slot
                }
                CameraPath::Orbit {
                    base: *base,
                    centre: base.target,
                    start,
                    step,
                }
            }
            CameraPathSpec::FlyThrough {
                keys: Some(keys),
                frames_per_key,
                ..
            } if keys.len() >= 2 => CameraPath::Keyframes {
                keys: keys.clone(),
                frames_per_key: frames_per_key.max(1.0),
            },
            CameraPathSpec::FlyThrough { frames_per_key, .. } => {
                let mut rng = SplitMix::new(seed ^ 0xf1f1_7ab1e);
                let fpk = frames_per_key.max(1.0);
                let n = 2 + (frames as f32 / fpk).ceil() as usize;
                let (r, u, f) = base.basis();
                // The scale of the motion is the distance to what the camera looks at:
                // scenes whose target is only a unit direction move as much as those whose
                // target is the object looked at.
                let (focus, aim) = focus(base, probe);
                let amp = 0.08 * focus;
                let mut keys = Vec::with_capacity(n);
                let mut prev = base.position;
                for i in 0..n {
                    // Key 0 is the base camera jittered; later keys drift forward a little.
                    let drift = f * (0.03 * focus * i as f32) * rng.signed().signum();
                    let offset = drift
                        + r * (amp * rng.signed())
                        + u * (0.5 * amp * rng.signed())
                        + f * (0.5 * amp * rng.signed());
                    let target = aim + r * (amp * rng.signed()) + u * (0.5 * amp * rng.signed());
                    let position = clear_position(probe, base.position, prev, offset, target, focus);
                    prev = position;
                    keys.push(Camera {
                        position,
                        target,
                        ..*base
                    });
                }
                CameraPath::Keyframes {
                    keys,
                    frames_per_key: fpk,
                }
            }
        }
    }

    /// The shots of a fly-through with cuts every `n` frames: `ceil(frames / n)` of them.
    fn cuts(
        keys: Option<&[Camera]>,
        frames_per_key: f32,
        n: u32,
        base: &Camera,
        seed: u64,
        frames: u32,
        probe: &dyn RayProbe,
    ) -> Self {
        let count = frames.max(1).div_ceil(n).clamp(1, 4096) as usize;
        let fpk = frames_per_key.max(1.0);
        let shots = match keys {
            Some([]) => vec![CameraPath::Static(*base)],
            Some([only]) => vec![CameraPath::Static(*only)],
            Some(keys) => (0..count)
                .map(|s| {
                    let k = s % keys.len();
                    let rotated: Vec<Camera> = keys[k..].iter().chain(&keys[..k]).copied().collect();
                    CameraPath::Keyframes {
                        keys: rotated,
                        frames_per_key: fpk,
                    }
                })
                .collect(),
            None => {
                let mut rng = SplitMix::new(seed ^ 0xc075_c075);
                let single = CameraPathSpec::FlyThrough {
                    keys: None,
                    frames_per_key: fpk,
                    cut_every: None,
                };
                (0..count)
                    .map(|s| {
                        let shot_base = if s == 0 {
                            *base
                        } else {
                            shot_viewpoint(base, probe, &mut rng)
                        };
                        let shot_seed = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15).wrapping_add(s as u64);
                        CameraPath::from_spec(&single, &shot_base, shot_seed, n, probe)
                    })
                    .collect()
            }
        };
        CameraPath::Cuts {
            shots,
            frames_per_shot: n,
        }
    }

    /// Whether frame `frame` starts a new shot (a cut: the camera jumps, and the motion
    /// vectors of this frame refer to the previous shot's camera).
    pub fn is_cut(&self, frame: u32) -> bool {
        let CameraPath::Cuts {
            shots,
            frames_per_shot,
        } = self
        else {
            return false;
        };
        let n = (*frames_per_shot).max(1);
        frame > 0 && frame.is_multiple_of(n) && (frame / n) < shots.len() as u32
    }

    /// [`CameraPath::from_spec`] after checking the base camera and the spec, then every
    /// camera of frames `0..frames` (an interpolated or orbiting camera can degenerate too):
    /// the error names the field, and the frame.
    pub fn checked(
        spec: &CameraPathSpec,
        base: &Camera,
        seed: u64,
        frames: u32,
        probe: &dyn RayProbe,
    ) -> Result<Self, String> {
        base.check()?;
        spec.check()?;
        let path = Self::from_spec(spec, base, seed, frames, probe);
        for f in 0..frames {
            path.camera(f)
                .check()
                .map_err(|e| format!("camera path, frame {f}: {e}"))?;
        }
        Ok(path)
    }

    /// Camera of frame `frame`.
    pub fn camera(&self, frame: u32) -> Camera {
        match self {
            CameraPath::Cuts {
                shots,
                frames_per_shot,
            } => {
                let n = (*frames_per_shot).max(1);
                let s = (frame / n) as usize;
                match shots.get(s) {
                    Some(shot) => shot.camera(frame % n),
                    None => match shots.last() {
                        Some(last) => last.camera(frame - (shots.len() as u32 - 1) * n),
                        None => Camera {
                            position: Vec3::ZERO,
                            target: Vec3::NEG_Z,
                            up: Vec3::Y,
                            yfov: 1.0,
                        },
                    },
                }
            }
            CameraPath::Static(c) => *c,
            CameraPath::Orbit {
                base,
                centre,
                start,
                step,
            } => {
                let rel = base.position - *centre;
                let a = start + step * frame as f32;
                let (s, c) = a.sin_cos();
                let rotated = Vec3::new(c * rel.x + s * rel.z, rel.y, -s * rel.x + c * rel.z);
                Camera {
                    position: *centre + rotated,
                    target: *centre,
                    ..*base
                }
            }
            CameraPath::Keyframes { keys, frames_per_key } => {
                let n = keys.len();
                let x = frame as f32 / frames_per_key;
                let i = (x.floor() as usize).min(n.saturating_sub(2));
                let t = (x - i as f32).clamp(0.0, 1.0);
                let k = |j: isize| keys[j.clamp(0, n as isize - 1) as usize];
                let (k0, k1, k2, k3) = (
                    k(i as isize - 1),
                    k(i as isize),
                    k(i as isize + 1),
                    k(i as isize + 2),
                );
                Camera {
                    position: catmull_rom(k0.position, k1.position, k2.position, k3.position, t),
                    target: catmull_rom(k0.target, k1.target, k2.target, k3.target, t),
                    up: k1.up,
                    yfov: k1.yfov + (k2.yfov - k1.yfov) * t,
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn base() -> Camera {
        Camera {
            position: Vec3::new(0.0, 1.0, 5.0),
            target: Vec3::new(0.0, 1.0, 0.0),
            up: Vec3::Y,
            yfov: 0.7,
        }
    }

    /// `n` keys: [`base`] moved to x = 0, 1, .. at y = 0.
    fn keys_along_x(n: u32) -> Vec<Camera> {
        (0..n)
            .map(|i| Camera {
                position: Vec3::new(i as f32, 0.0, 5.0),
                ..base()
            })
            .collect()
    }

    #[test]
    fn project_inverts_ray_dir() {
        let c = base();
        for &(x, y) in &[(0.5f32, 0.5f32), (31.5, 7.25), (63.9, 47.0)] {
            let d = c.ray_dir(Vec2::new(x, y), 64, 48);
            let p = c.position + 3.7 * d;
            let q = c.project(p, 64, 48).unwrap();
            assert!((q - Vec2::new(x, y)).length() < 1e-3, "{q} vs {x},{y}");
        }
    }

    #[test]
    fn paths_are_deterministic_and_differ_per_seed() {
        for spec in ["orbit", "flythrough"] {
            let spec: CameraPathSpec = spec.parse().unwrap();
            let a = CameraPath::from_spec(&spec, &base(), 7, 60, &());
            let b = CameraPath::from_spec(&spec, &base(), 7, 60, &());
            let c = CameraPath::from_spec(&spec, &base(), 8, 60, &());
            assert_eq!(a, b);
            for f in [0, 13, 59] {
                assert_eq!(a.camera(f), b.camera(f));
                assert!(
                    a.camera(f).position.distance(c.camera(f).position) > 1e-4,
                    "{spec:?} frame {f}"
                );
            }
        }
    }

    /// A closed box `[-1, 1]^3` of 12 triangles.
    fn box_room() -> crate::render::bvh::SceneBvh {
        let v: Vec<Vec3> = (0..8)
            .map(|i| Vec3::new([-1.0, 1.0][i & 1], [-1.0, 1.0][(i >> 1) & 1], [-1.0, 1.0][i >> 2]))
            .collect();
        let quads = [
            [0, 1, 3, 2],
            [4, 6, 7, 5],
            [0, 4, 5, 1],
            [2, 3, 7, 6],
            [0, 2, 6, 4],
            [1, 5, 7, 3],
        ];
        let tris: Vec<[u32; 3]> = quads
            .iter()
            .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
            .collect();
        crate::render::bvh::SceneBvh::build("box", &v, &tris).unwrap()
    }

    #[test]
    fn flythrough_stays_inside_a_room() {
        // A camera close to the wall behind it and to the one on its right: unconstrained
        // keys would leave the room; constrained ones stay inside with a margin, and still move.
        let room = box_room();
        let cam = Camera {
            position: Vec3::new(0.88, 0.0, 0.85),
            target: Vec3::new(-1.0, 0.0, 0.85),
            up: Vec3::Y,
            yfov: 0.8,
        };
        let spec: CameraPathSpec = "flythrough".parse().unwrap();
        let (mut moved, mut would_leave, mut total) = (0, 0, 0);
        for seed in 0..40 {
            let free = CameraPath::from_spec(&spec, &cam, seed, 48, &());
            let CameraPath::Keyframes { keys: free_keys, .. } = &free else {
                unreachable!()
            };
            would_leave += free_keys
                .iter()
                .filter(|k| k.position.abs().max_element() > 1.0)
                .count();
            let path = CameraPath::from_spec(&spec, &cam, seed, 48, &room);
            let CameraPath::Keyframes { keys, .. } = &path else {
                unreachable!()
            };
            total += keys.len();
            for k in keys {
                // The margin is 5% of the focus distance (1.88): 0.094.
                assert!(
                    k.position.abs().max_element() < 1.0 - 0.09,
                    "seed {seed}: key {k:?}"
                );
                moved += usize::from(k.position.distance(cam.position) > 1e-3);
                // Nothing blocks the view within a quarter of the focus distance.
                let d = (k.target - k.position).normalize();
                assert!(
                    room.intersect(k.position, d, 0.25 * 1.88).is_none(),
                    "seed {seed}"
                );
            }
            for f in 0..48 {
                let p = path.camera(f).position;
                assert!(p.abs().max_element() < 1.0, "seed {seed} frame {f}: {p}");
            }
        }
        assert!(
            would_leave > 10,
            "the test camera is not close enough to the walls"
        );
        assert!(
            2 * moved > total,
            "constrained keys should still move ({moved} of {total})"
        );
    }

    #[test]
    fn orbit_arcs_of_different_seeds_are_disjoint() {
        let spec: CameraPathSpec = "orbit".parse().unwrap();
        let frames = 40;
        let arcs: Vec<(f32, f32)> = (0..6)
            .map(|s| {
                let CameraPath::Orbit { start, step, .. } =
                    CameraPath::from_spec(&spec, &base(), s, frames, &())
                else {
                    unreachable!()
                };
                let end = start + step * (frames - 1) as f32;
                (start.min(end), start.max(end))
            })
            .collect();
        for i in 0..arcs.len() {
            for j in i + 1..arcs.len() {
                let (a, b) = (arcs[i], arcs[j]);
                assert!(a.1 < b.0 || b.1 < a.0, "seeds {i} and {j} overlap: {a:?} {b:?}");
            }
        }
    }

    /// Issue 12 item 7: degenerate cameras and paths are named errors; a path whose
    /// interpolated cameras degenerate names the frame.
    #[test]
    fn degenerate_cameras_and_paths_are_refused() {
        base().check().unwrap();
        let bad = |c: Camera, want: &str| {
            let e = c.check().unwrap_err();
            assert!(e.contains(want), "{c:?}: {e}");
        };
        bad(
            Camera {
                target: base().position,
                ..base()
            },
            "target",
        );
        bad(
            Camera {
                up: Vec3::new(0.0, 0.0, 2.0),
                ..base()
            },
            "parallel",
        );
        bad(
            Camera {
                up: Vec3::ZERO,
                ..base()
            },
            "up",
        );
        bad(
            Camera {
                position: Vec3::new(f32::NAN, 0.0, 0.0),
                ..base()
            },
            "position",
        );
        bad(
            Camera {
                position: Vec3::new(f32::INFINITY, 0.0, 0.0),
                ..base()
            },
            "position",
        );
        bad(Camera { yfov: 0.0, ..base() }, "yfov");
        bad(
            Camera {
                yfov: std::f32::consts::PI,
                ..base()
            },
            "yfov",
        );
        let orbit = |d: f32| CameraPathSpec::Orbit {
            degrees_per_frame: Some(d),
        };
        for d in [1e38, f32::NEG_INFINITY, f32::NAN, 361.0] {
            let e = CameraPath::checked(&orbit(d), &base(), 0, 8, &()).unwrap_err();
            assert!(e.contains("degrees_per_frame"), "{d}: {e}");
        }
        CameraPath::checked(&orbit(-360.0), &base(), 0, 8, &()).unwrap();
        // Keys with position == target, and a base camera that is degenerate.
        let keys = vec![
            base(),
            Camera {
                position: base().target,
                ..base()
            },
        ];
        let fly = CameraPathSpec::FlyThrough {
            keys: Some(keys),
            frames_per_key: 4.0,
            cut_every: None,
        };
        let e = CameraPath::checked(&fly, &base(), 0, 8, &()).unwrap_err();
        assert!(e.contains("keys[1]") && e.contains("target"), "{e}");
        let e = CameraPath::checked(
            &CameraPathSpec::Static,
            &Camera { yfov: 0.0, ..base() },
            0,
            1,
            &(),
        )
        .unwrap_err();
        assert!(e.contains("yfov"), "{e}");
        // Two valid keys whose spline passes the target through the eye half-way: the
        // frame where they meet is named.
        let a = Camera {
            position: Vec3::new(0.0, 0.0, 1.0),
            target: Vec3::new(0.0, 0.0, -1.0),
            up: Vec3::Y,
            yfov: 0.7,
        };
        let b = Camera {
            position: Vec3::new(0.0, 0.0, -1.0),
            target: Vec3::new(0.0, 0.0, 1.0),
            ..a
        };
        let cross = CameraPathSpec::FlyThrough {
            keys: Some(vec![a, b]),
            frames_per_key: 4.0,
            cut_every: None,
        };
        let e = CameraPath::checked(&cross, &a, 0, 5, &()).unwrap_err();
        assert!(e.contains("frame 2") && e.contains("target"), "{e}");
    }

    #[test]
    fn path_specs_parse_with_speeds_and_cuts() {
        let p = |s: &str| s.parse::<CameraPathSpec>();
        assert_eq!(p("static"), Ok(CameraPathSpec::Static));
        assert_eq!(
            p("orbit:2.5"),
            Ok(CameraPathSpec::Orbit {
                degrees_per_frame: Some(2.5)
            })
        );
        assert_eq!(
            p("flythrough:8"),
            Ok(CameraPathSpec::FlyThrough {
                keys: None,
                frames_per_key: 8.0,
                cut_every: None
            })
        );
        assert_eq!(
            p("cuts"),
            Ok(CameraPathSpec::FlyThrough {
                keys: None,
                frames_per_key: DEFAULT_FRAMES_PER_KEY,
                cut_every: Some(DEFAULT_CUT_EVERY)
            })
        );
        assert_eq!(
            p("cuts:10:48"),
            Ok(CameraPathSpec::FlyThrough {
                keys: None,
                frames_per_key: 48.0,
                cut_every: Some(10)
            })
        );
        for bad in [
            "cuts:0",
            "flythrough:0.5",
            "orbit:x",
            "static:1",
            "spiral",
            "cuts:1:2:3",
        ] {
            assert!(p(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn generated_cuts_jump_between_shots_and_move_within() {
        let room = box_room();
        let cam = Camera {
            position: Vec3::new(0.5, 0.0, 0.6),
            target: Vec3::new(-1.0, -0.2, -0.5),
            up: Vec3::Y,
            yfov: 0.8,
        };
        let spec: CameraPathSpec = "cuts:12:6".parse().unwrap();
        let path = CameraPath::from_spec(&spec, &cam, 3, 60, &room);
        let again = CameraPath::from_spec(&spec, &cam, 3, 60, &room);
        assert_eq!(path, again, "deterministic");
        let CameraPath::Cuts {
            shots,
            frames_per_shot,
        } = &path
        else {
            panic!("{path:?}")
        };
        assert_eq!((shots.len(), *frames_per_shot), (5, 12));
        assert!(path.camera(0).position.distance(cam.position) < 0.5);
        let (mut jumps, mut within) = (0.0f32, 0.0f32);
        for f in 1..60 {
            let (a, b) = (path.camera(f), path.camera(f - 1));
            let step = a.position.distance(b.position) + a.target.distance(b.target);
            if path.is_cut(f) {
                jumps = jumps.max(step);
                assert_eq!(f % 12, 0);
            } else {
                within = within.max(step);
                assert_ne!(f % 12, 0);
            }
            // Every shot stays inside the room.
            let p = path.camera(f).position;
            assert!(p.abs().max_element() < 1.0, "frame {f}: {p}");
        }
        assert!(
            jumps > 5.0 * within,
            "cuts jump ({jumps}) much farther than frames move ({within})"
        );
        // Explicit keys: shot s starts at key s.
        let keys = keys_along_x(3);
        let spec = CameraPathSpec::FlyThrough {
            keys: Some(keys.clone()),
            frames_per_key: 30.0,
            cut_every: Some(10),
        };
        let path = CameraPath::from_spec(&spec, &base(), 0, 40, &());
        for s in 0..4u32 {
            let k = &keys[s as usize % 3];
            assert!(
                path.camera(10 * s).position.distance(k.position) < 1e-5,
                "shot {s}"
            );
            assert_eq!(path.is_cut(10 * s), s > 0);
        }
        // Frames past the last shot continue it rather than jumping.
        assert!(!path.is_cut(40) && !path.is_cut(50));
    }

    #[test]
    fn keyframes_pass_through_keys() {
        let keys = keys_along_x(4);
        let path = CameraPath::Keyframes {
            keys: keys.clone(),
            frames_per_key: 10.0,
        };
        for (i, k) in keys.iter().enumerate().take(3) {
            assert!(path.camera(10 * i as u32).position.distance(k.position) < 1e-5);
        }
        // Smooth in between.
        let mid = path.camera(15).position;
        assert!((mid.x - 1.5).abs() < 1e-4, "{mid}");
    }
}
