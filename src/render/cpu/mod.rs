//! The CPU twin of the WGSL path tracer: the same integrator (materials and textures, BSDF
//! sampling and evaluation, light sampling, MIS, Russian roulette, alpha cut-outs,
//! dielectrics) and the same G-buffers, in Rust over the same CWBVH laid out for the CPU
//! ([`crate::render::wide_bvh`]), reading
//! the same [`PackedScene`] arrays as the GPU and drawing the same PCG random numbers, in
//! parallel over all cores (rayon). For a seed it is deterministic, whatever the thread
//! count. Each file mirrors one WGSL library file. Its vectors are glam's SIMD `Vec3A` and
//! `Mat3A`, imported under the names `Vec3` and `Mat3` so that the code reads like the WGSL
//! it mirrors.
//!
//! ```
//! # fn main() -> subpixel::Result<()> {
//! use subpixel::render::{CpuTracer, FrameSettings, Mode, PackedScene, load_scene};
//! let scene = load_scene("builtin:cornell")?;
//! let packed = PackedScene::new(&scene, u64::MAX)?;
//! let far = scene.far_distance([&scene.camera.position]);
//! let tracer = CpuTracer::new(16, 16)?;
//! let (frame, stats) = tracer.render(&packed, &FrameSettings::new(scene.camera, Mode::Full, far))?;
//! assert_eq!(frame.color.width, 16);
//! assert!(stats.rays >= 256);
//! # Ok(()) }
//! ```

// The twin keeps WGSL's NaN-rejecting comparisons (`!(x > 0.0)` is true for NaN) as written.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

mod bsdf;
mod common;
mod integrator;
mod lights;
mod material;
mod traverse;

use rayon::prelude::*;

use super::packed::PackedScene;
use super::settings::{
    EMISSION_OUTLINE_RAYS, FrameSettings, FrameStats, Mode, REFERENCE_SEED_XOR, ReferenceHalves, tile_offset,
};
use crate::error::{Error, Result};
use crate::frame::{Background, DirectEmission, HostFrame};
use crate::nn::HostTensor;
use integrator::{Params, gbuffer_of_hit, gbuffer_pixel, pixel_samples, primary_dir};
use lights::EnvInfo;

/// One pixel's buffers: colour+mask, albedo+depth, normal+metallic, shadow+roughness,
/// transparent, motion.
type PixelBuffers = ([f32; 4], [f32; 4], [f32; 4], [f32; 4], [f32; 3], [f32; 2]);

/// A surface that the G-buffer ray of a pixel meets, found by
/// [`CpuTracer::primary_surfaces`], with the G-buffer values a frame would hold for it.
#[derive(Debug, Clone, PartialEq)]
pub struct PrimarySurface {
    /// The triangle, as an index into the scene's triangles (`Scene::geometry`).
    pub triangle: u32,
    /// Its material, as an index into `Scene::materials`.
    pub material: u32,
    /// Distance along the (unit) ray.
    pub t: f32,
    /// Albedo.
    pub albedo: [f32; 3],
    /// Shading normal.
    pub normal: [f32; 3],
    /// Normalised depth.
    pub depth: f32,
    /// Metallic.
    pub metallic: f32,
    /// Roughness.
    pub roughness: f32,
    /// Transparent tint.
    pub transparent: [f32; 3],
    /// Motion in pixels.
    pub motion: [f32; 2],
}

/// Renders frames of one size on the CPU.
#[derive(Debug, Clone)]
pub struct CpuTracer {
    width: u32,
    height: u32,
}

/// Most pixels a CPU frame may have (8192 x 8192): a frame of the data contract (about 40
/// f32 channels with the background) then takes about 10 GiB, and larger sizes are far more
/// likely a typo than a render this machine can hold.
pub const MAX_PIXELS: u64 = 1 << 26;

impl CpuTracer {
    /// A tracer for `width x height` frames (each positive, at most [`MAX_PIXELS`] in all).
    pub fn new(width: u32, height: u32) -> Result<Self> {
        if width == 0 || height == 0 {
            return Err(Error::Invalid(format!(
                "image size {width}x{height}: width and height must be positive"
            )));
        }
        let pixels = width as u64 * height as u64;
        if pixels > MAX_PIXELS {
            return Err(Error::Invalid(format!(
                "image size {width}x{height}: {pixels} pixels, more than the {MAX_PIXELS} (8192 x 8192) a CPU \
                 frame may have (its buffers would take about {} GiB)",
                (pixels * 160) >> 30
            )));
        }
        Ok(Self { width, height })
    }

    /// Width.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height.
    pub fn height(&self) -> u32 {
        self.height
    }

    fn params(&self, s: &FrameSettings, seed: u32) -> Params {
        Params {
            cam: s.camera.gpu(self.width, self.height),
            prev: s.prev_camera.gpu(self.width, self.height),
            width: self.width,
            height: self.height,
            frame: s.frame,
            seed,
            max_depth: s.max_depth.max(1),
            far: s.far.max(1e-6),
        }
    }

    /// Every surface that the G-buffer ray of pixel (x, y) of frame `s` meets at the
    /// distance of its closest hit, up to relative `rel_eps`, nearest first: each with the
    /// G-buffer values of the pixel had the ray hit it. Several when the scene has
    /// overlapping surfaces there (z-fighting), where float rounding decides which one a
    /// traversal reports. With `graze > 0` (radians), also those of four rays tilted from it
    /// by that angle: where the ray passes within rounding of a triangle's edge (the corner
    /// of two walls), a backend whose arithmetic rounds otherwise (fused multiply-adds on a
    /// GPU) may report the surface on the other side of the edge. A brute-force test of
    /// every triangle (the BVH traversal's triangle test and alpha cut-outs, none of its
    /// order), for diagnostics and tests. A surface found by a tilted ray has the values of
    /// the pixel's own ray meeting that triangle's plane (just beyond its edge), so that
    /// depth and motion are those the other backend reports, not shifted by the tilt.
    pub fn primary_surfaces(
        &self,
        scene: &PackedScene,
        s: &FrameSettings,
        (x, y): (u32, u32),
        rel_eps: f32,
        graze: f32,
    ) -> Vec<PrimarySurface> {
        let p = self.params(s, s.seed);
        let d = primary_dir(&p, x, y);
        let o = glam::Vec3A::from_slice(&p.cam.pos[..3]);
        let mut dirs = vec![d];
        if graze > 0.0 {
            let (a, b) = glam::Vec3::from(d).any_orthonormal_pair();
            for t in [a, -a, b, -b] {
                dirs.push((d + glam::Vec3A::from(t) * graze.tan()).normalize());
            }
        }
        let mut found: Vec<PrimarySurface> = Vec::new();
        for dir in dirs {
            let mut hits: Vec<common::Hit> = (0..scene.tris.len() as u32 / 4)
                .filter_map(|prim| {
                    let (t, u, v) = traverse::intersect_tri(scene, prim, o, dir, 0.0, common::BIG)?;
                    let info = material::tri_info(scene, prim)[3];
                    (info & super::packed::TRI_FLAG_ALPHA == 0 || material::alpha_passes(scene, prim, u, v))
                        .then_some(common::Hit { t, prim, u, v })
                })
                .collect();
            hits.sort_by(|a, b| a.t.total_cmp(&b.t));
            let Some(nearest) = hits.first().map(|h| h.t) else {
                continue;
            };
            for h in hits
                .iter()
                .take_while(|h| h.t <= nearest + rel_eps * nearest.abs())
            {
                let triangle = scene.bvh.order[h.prim as usize];
                if found.iter().any(|f| f.triangle == triangle) {
                    continue;
                }
                // Along the pixel's own ray (the same hit for the untilted ray).
                let h = traverse::plane_hit(scene, h.prim, o, d).map_or(*h, |(t, u, v)| common::Hit {
                    t,
                    u,
                    v,
                    ..*h
                });
                let g = gbuffer_of_hit(scene, &p, x, y, d, &h);
                let [a0, a1, a2, depth] = g.albedo_depth;
                let [n0, n1, n2, metallic] = g.normal_metallic;
                found.push(PrimarySurface {
                    triangle,
                    material: material::tri_info(scene, h.prim)[3] & super::packed::TRI_MATERIAL_MASK,
                    t: h.t,
                    albedo: [a0, a1, a2],
                    normal: [n0, n1, n2],
                    depth,
                    metallic,
                    roughness: g.roughness,
                    transparent: g.transparent,
                    motion: g.motion,
                });
            }
        }
        found
    }

    /// Renders frame `s` (every buffer of the data contract), as [`super::Tracer::render`]
    /// does on the GPU: quarter and full frames trace one sample per traced pixel, reference
    /// frames `s.spp` samples per pixel.
    pub fn render(&self, scene: &PackedScene, s: &FrameSettings) -> Result<(HostFrame, FrameStats)> {
        let (w, h) = (self.width, self.height);
        let p = self.params(s, s.seed);
        let ei = EnvInfo::new(scene);
        let (dx, dy) = tile_offset(s.frame);
        let spp = match s.mode {
            Mode::Reference => s.spp.max(1),
            _ => 1,
        };
        let traced = |x: u32, y: u32| match s.mode {
            Mode::Quarter => x % 2 == dx && y % 2 == dy,
            _ => true,
        };
        // One row per task: (rays, per-pixel buffers).
        let rows: Vec<(u64, Vec<PixelBuffers>)> = (0..h)
            .into_par_iter()
            .map(|y| {
                let mut rays = 0u64;
                let mut row = Vec::with_capacity(w as usize);
                for x in 0..w {
                    let g = gbuffer_pixel(scene, &p, x, y, &mut rays);
                    let (cm, sh) = if traced(x, y) {
                        let r = pixel_samples(scene, &ei, &p, x, y, 0, spp, &mut rays);
                        (r.radiance.extend(1.0).to_array(), r.shadow.to_array())
                    } else {
                        ([0.0; 4], [0.0; 3])
                    };
                    row.push((
                        cm,
                        g.albedo_depth,
                        g.normal_metallic,
                        [sh[0], sh[1], sh[2], g.roughness],
                        g.transparent,
                        g.motion,
                    ));
                }
                (rays, row)
            })
            .collect();
        let n = (w * h) as usize;
        let mut f = HostFrame {
            color: HostTensor::zeros(w, h, 3),
            mask: HostTensor::zeros(w, h, 1),
            albedo: HostTensor::zeros(w, h, 3),
            normal: HostTensor::zeros(w, h, 3),
            shadow: HostTensor::zeros(w, h, 3),
            transparent: HostTensor::zeros(w, h, 3),
            depth: HostTensor::zeros(w, h, 1),
            metallic: HostTensor::zeros(w, h, 1),
            roughness: HostTensor::zeros(w, h, 1),
            motion: HostTensor::zeros(w, h, 2),
            background: None,
        };
        let mut rays = 0;
        let mut i = 0;
        for (r, row) in rows {
            rays += r;
            for (cm, ad, nm, sr, tr, mv) in row {
                f.color.data[3 * i..3 * i + 3].copy_from_slice(&cm[..3]);
                f.mask.data[i] = cm[3];
                f.albedo.data[3 * i..3 * i + 3].copy_from_slice(&ad[..3]);
                f.depth.data[i] = ad[3];
                f.normal.data[3 * i..3 * i + 3].copy_from_slice(&nm[..3]);
                f.metallic.data[i] = nm[3];
                f.shadow.data[3 * i..3 * i + 3].copy_from_slice(&sr[..3]);
                f.roughness.data[i] = sr[3];
                f.transparent.data[3 * i..3 * i + 3].copy_from_slice(&tr);
                f.motion.data[2 * i..2 * i + 2].copy_from_slice(&mv);
                i += 1;
            }
        }
        debug_assert_eq!(i, n);
        if s.background > 0 {
            f.background = Some(self.background(scene, s)?);
        }
        let samples = match s.mode {
            Mode::Quarter => (w.div_ceil(2) as u64) * (h.div_ceil(2) as u64),
            _ => n as u64 * spp as u64,
        };
        Ok((f, FrameStats { rays, samples }))
    }

    /// The background buffer of frame `s` ([`crate::frame::Background`]): per pixel, over
    /// `s.background x s.background` stratified positions in the pixel, the mean of the
    /// environment radiance along the camera rays that escape the scene (0 for rays that
    /// hit anything, glass included), the fraction that escape (coverage), the mean
    /// first-hit base colour (the footprint albedo, sky 1) and the directly seen emission
    /// ([`DirectEmission`]: the mean first-hit emission over the same rays, over
    /// [`EMISSION_OUTLINE_RAYS`] per axis on emitters' outlines when `s.background` is
    /// fewer, and that of the frame's own samples, replayed). Where the coverage is 1 the background is the pixel's
    /// radiance, estimated with lookups instead of path samples. The reference of the WGSL
    /// tracer's `trace/background` pass; an error when `s.background` is 0.
    pub fn background(&self, scene: &PackedScene, s: &FrameSettings) -> Result<Background> {
        let n = s.background;
        if n == 0 {
            return Err(Error::Invalid(
                "background: n must be at least 1 (n x n lookups per pixel)".into(),
            ));
        }
        let (w, h) = (self.width, self.height);
        let p = self.params(s, s.seed);
        let ei = EnvInfo::new(scene);
        let px: Vec<integrator::FootprintPixel> = (0..h)
            .into_par_iter()
            .flat_map_iter(|y| {
                let (p, ei) = (&p, &ei);
                (0..w).map(move |x| integrator::background_pixel(scene, ei, p, x, y, n, &mut 0))
            })
            .collect();
        let gather = |f: fn(&integrator::FootprintPixel) -> glam::Vec3A| {
            HostTensor::from_vec(w, h, 3, px.iter().flat_map(|q| f(q).to_array()).collect())
        };
        let coverage = px.iter().map(|q| q.coverage).collect();
        let (samples, escaped) = self.sample_first_hits(scene, s);
        let mut emission = DirectEmission {
            footprint: gather(|q| q.emission),
            samples,
            escaped: Some(escaped),
        };
        if n < EMISSION_OUTLINE_RAYS {
            // The outline's pixels again with more rays (WGSL `trace/emission_outline`).
            let outline = emission.outline();
            let refined: Vec<(usize, glam::Vec3A)> = outline
                .par_iter()
                .enumerate()
                .filter(|(_, rim)| **rim)
                .map(|(i, _)| {
                    let (x, y) = (i as u32 % w, i as u32 / w);
                    let e = integrator::footprint_emission(scene, &p, x, y, EMISSION_OUTLINE_RAYS, &mut 0);
                    (i, e)
                })
                .collect();
            for (i, e) in refined {
                emission.footprint.data[3 * i..3 * i + 3].copy_from_slice(&e.to_array());
            }
        }
        Ok(Background {
            radiance: gather(|q| q.environment),
            coverage: HostTensor::from_vec(w, h, 1, coverage),
            albedo: Some(gather(|q| q.albedo)),
            emission: Some(emission),
        })
    }

    /// What the samples frame `s` traces (one per traced pixel in quarter and full frames,
    /// `s.spp` in reference frames) see first, averaged, 0 where not traced: their first-hit
    /// emission (3 channels; the part of the frame's `color` that is emission seen directly,
    /// [`DirectEmission::samples`]) and the fraction of them whose camera ray escaped (1
    /// channel, [`DirectEmission::escaped`]). Replays the camera rays only.
    pub fn sample_first_hits(&self, scene: &PackedScene, s: &FrameSettings) -> (HostTensor, HostTensor) {
        let (w, h) = (self.width, self.height);
        let p = self.params(s, s.seed);
        let (dx, dy) = tile_offset(s.frame);
        let spp = match s.mode {
            Mode::Reference => s.spp.max(1),
            _ => 1,
        };
        let hits: Vec<(glam::Vec3A, f32)> = (0..h)
            .into_par_iter()
            .flat_map_iter(|y| {
                let p = &p;
                (0..w).map(move |x| {
                    let traced = s.mode != Mode::Quarter || (x % 2 == dx && y % 2 == dy);
                    if traced {
                        integrator::first_hit(scene, p, x, y, 0, spp, &mut 0)
                    } else {
                        (glam::Vec3A::ZERO, 0.0)
                    }
                })
            })
            .collect();
        let emission = hits.iter().flat_map(|(e, _)| e.to_array()).collect();
        let escaped = hits.iter().map(|(_, a)| *a).collect();
        (
            HostTensor::from_vec(w, h, 3, emission),
            HostTensor::from_vec(w, h, 1, escaped),
        )
    }

    /// Radiance of samples `first .. first + count` per pixel of frame `s` with `seed`.
    fn radiance(
        &self,
        scene: &PackedScene,
        s: &FrameSettings,
        seed: u32,
        first: u32,
        count: u32,
    ) -> (HostTensor, u64) {
        let (w, h) = (self.width, self.height);
        let p = self.params(s, seed);
        let ei = EnvInfo::new(scene);
        let rows: Vec<(u64, Vec<f32>)> = (0..h)
            .into_par_iter()
            .map(|y| {
                let mut rays = 0u64;
                let mut row = Vec::with_capacity(3 * w as usize);
                for x in 0..w {
                    let r = pixel_samples(scene, &ei, &p, x, y, first, count, &mut rays);
                    row.extend(r.radiance.to_array());
                }
                (rays, row)
            })
            .collect();
        let rays = rows.iter().map(|r| r.0).sum();
        let data = rows.into_iter().flat_map(|r| r.1).collect();
        (HostTensor::from_vec(w, h, 3, data), rays)
    }

    /// An `spp`-sample reference of frame `s` (independent of the frame's own samples: the
    /// seed is varied as on the GPU), rendered as two halves.
    pub fn render_reference(
        &self,
        scene: &PackedScene,
        s: &FrameSettings,
        spp: u32,
    ) -> Result<ReferenceHalves> {
        let spp = spp.max(1);
        let seed = s.seed ^ REFERENCE_SEED_XOR;
        let half = spp / 2;
        let (first, r1) = self.radiance(scene, s, seed, 0, half);
        let (second, r2) = self.radiance(scene, s, seed, half, spp - half);
        let first = if half == 0 { second.clone() } else { first };
        Ok(ReferenceHalves {
            first,
            second,
            rays: r1 + r2,
        })
    }

    /// The `2 spp`-sample reference of frame `s` from its `spp`-sample one `r`
    /// ([`CpuTracer::render_reference`] or an earlier extension): the first half is `r`'s
    /// mean (samples `0 .. spp`), the second is traced (samples `spp .. 2 spp`), so the halves
    /// are those a `2 spp` render would have.
    pub fn extend_reference(
        &self,
        scene: &PackedScene,
        s: &FrameSettings,
        r: &ReferenceHalves,
        spp: u32,
    ) -> Result<ReferenceHalves> {
        let spp = spp.max(1);
        let (second, rays) = self.radiance(scene, s, s.seed ^ REFERENCE_SEED_XOR, spp, spp);
        Ok(ReferenceHalves {
            first: r.mean(spp),
            second,
            rays,
        })
    }
}
