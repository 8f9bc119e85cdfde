//! Procedural textures: value noise, patterns, colours, normal maps.

use glam::Vec3;

use crate::render::procedural::*;
use crate::render::scene::{Texture, Wrap};

/// Texture size of the procedural textures.
pub(super) const TEX: u32 = 128;

pub(super) fn hash3(x: u32, y: u32, s: u32) -> f32 {
    let h = mix(((x as u64) << 40) ^ ((y as u64) << 20) ^ s as u64);
    (h >> 40) as f32 / (1u64 << 24) as f32
}

/// Tileable value noise of lattice period `period` at texel `(x, y)` of a `TEX`-texel tile.
pub(super) fn value_noise(x: f32, y: f32, period: u32, seed: u32) -> f32 {
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
pub(super) fn fbm(x: f32, y: f32, base_period: u32, octaves: u32, seed: u32) -> f32 {
    let (mut sum, mut amp, mut norm, mut period) = (0.0, 1.0, 0.0, base_period);
    for o in 0..octaves {
        sum += amp * value_noise(x, y, period.min(TEX), seed.wrapping_add(o * 7919));
        norm += amp;
        amp *= 0.5;
        period *= 2;
    }
    sum / norm
}

pub(super) fn linear_to_srgb_u8(c: f32) -> u8 {
    let c = c.clamp(0.0, 1.0);
    let s = if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0).round() as u8
}

/// `f(x, y)` of every texel of a TEX x TEX image, row by row.
pub(super) fn texels<T>(f: impl Fn(u32, u32) -> T) -> Vec<T> {
    let mut texels = Vec::with_capacity((TEX * TEX) as usize);
    for y in 0..TEX {
        for x in 0..TEX {
            texels.push(f(x, y));
        }
    }
    texels
}

pub(super) fn texture(name: String, srgb: bool, f: impl Fn(u32, u32) -> [u8; 4]) -> Texture {
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
pub(super) fn normal_map(name: String, heights: &[f32], strength: f32) -> Texture {
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
pub(super) enum Pattern {
    Checker,
    Stripes,
    Noise,
    Bricks,
    Tiles,
}

impl Pattern {
    pub(super) const ALL: [Pattern; 5] = [
        Pattern::Checker,
        Pattern::Stripes,
        Pattern::Noise,
        Pattern::Bricks,
        Pattern::Tiles,
    ];
    pub(super) fn name(self) -> &'static str {
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
pub(super) fn colour(rng: &mut Rng, sat: (f32, f32), val: (f32, f32)) -> Vec3 {
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
    crate::render::scene::srgb_to_linear(Vec3::new(r + m, g + m, b + m))
}
