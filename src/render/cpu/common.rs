//! Twin of `wgsl/trace/lib/common.wgsl`: constants, the PCG random numbers (bit-identical to
//! the GPU's, so one seed drives both backends through the same sample sequence), the
//! orthonormal basis, ray offsetting and small helpers.

use glam::{Mat3A as Mat3, Vec3A as Vec3};

pub(crate) const PI: f32 = std::f32::consts::PI;
pub(crate) const TWO_PI: f32 = std::f32::consts::TAU;
pub(crate) const INV_PI: f32 = std::f32::consts::FRAC_1_PI;
pub(crate) const NO_HIT: u32 = u32::MAX;
pub(crate) const BIG: f32 = 3.0e38;

/// A ray hit (WGSL `Hit`): `prim` is the BVH-order triangle, [`NO_HIT`] on a miss; `u`, `v`
/// the barycentric weights of v1 and v2.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Hit {
    pub t: f32,
    pub prim: u32,
    pub u: f32,
    pub v: f32,
}

/// One PCG output permutation of `v` (as `pcg_hash` in WGSL).
#[inline]
pub(crate) fn pcg_hash(v: u32) -> u32 {
    let s = v.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let w = ((s >> ((s >> 28) + 4)) ^ s).wrapping_mul(277_803_737);
    (w >> 22) ^ w
}

/// The random state of sample `sample` of `pixel` in `frame` (as `rng_seed` in WGSL).
#[inline]
pub(crate) fn rng_seed(pixel: u32, frame: u32, sample: u32, seed: u32) -> u32 {
    pcg_hash(pixel ^ pcg_hash(frame ^ pcg_hash(sample ^ pcg_hash(seed))))
}

/// The per-path random number generator (WGSL `rand`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Rng(pub u32);

impl Rng {
    /// Uniform in [0, 1) with 24 bits.
    #[inline]
    pub fn next(&mut self) -> f32 {
        self.0 = self.0.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
        let s = self.0;
        let w = ((s >> ((s >> 28) + 4)) ^ s).wrapping_mul(277_803_737);
        (((w >> 22) ^ w) >> 8) as f32 * (1.0 / 16_777_216.0)
    }

    /// Two numbers, in order.
    #[inline]
    pub fn next2(&mut self) -> [f32; 2] {
        let a = self.next();
        let b = self.next();
        [a, b]
    }

    /// Three numbers, in order.
    #[inline]
    pub fn next3(&mut self) -> Vec3 {
        let a = self.next();
        let b = self.next();
        let c = self.next();
        Vec3::new(a, b, c)
    }
}

#[inline]
pub(crate) fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

#[inline]
pub(crate) fn max3(v: Vec3) -> f32 {
    v.x.max(v.y.max(v.z))
}

#[inline]
pub(crate) fn pow5(x: f32) -> f32 {
    let x2 = x * x;
    x2 * x2 * x
}

/// Orthonormal basis around unit `n` (Duff et al. 2017): columns t, b, n.
#[inline]
pub(crate) fn onb(n: Vec3) -> Mat3 {
    let s = if n.z >= 0.0 { 1.0 } else { -1.0 };
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    let t = Vec3::new(1.0 + s * n.x * n.x * a, s * b, -s * n.x);
    let bt = Vec3::new(b, s + n.y * n.y * a, -n.y);
    Mat3::from_cols(t, bt, n)
}

#[inline]
pub(crate) fn to_local(f: &Mat3, v: Vec3) -> Vec3 {
    Vec3::new(v.dot(f.x_axis), v.dot(f.y_axis), v.dot(f.z_axis))
}

#[inline]
pub(crate) fn to_world(f: &Mat3, v: Vec3) -> Vec3 {
    f.x_axis * v.x + f.y_axis * v.y + f.z_axis * v.z
}

/// Moves a ray origin off a surface along `n` (Waechter & Binder), as `offset_ray` in WGSL.
#[inline]
pub(crate) fn offset_ray(p: Vec3, n: Vec3) -> Vec3 {
    let one = |p: f32, n: f32| -> f32 {
        let of_i = (256.0 * n) as i32;
        let pi = f32::from_bits((p.to_bits() as i32).wrapping_add(if p < 0.0 { -of_i } else { of_i }) as u32);
        let pf = p + (1.0 / 32.0 / 65536.0) * n;
        if p.abs() < 1.0 / 32.0 { pf } else { pi }
    };
    Vec3::new(one(p.x, n.x), one(p.y, n.y), one(p.z, n.z))
}

/// Every component is finite and at most [`BIG`] in magnitude.
#[inline]
pub(crate) fn finite3(v: Vec3) -> bool {
    v.x.abs() <= BIG && v.y.abs() <= BIG && v.z.abs() <= BIG
}

/// WGSL `reflect(e, n)`: `e - 2 dot(n, e) n`.
#[inline]
pub(crate) fn reflect(e: Vec3, n: Vec3) -> Vec3 {
    e - 2.0 * n.dot(e) * n
}

/// WGSL `refract(e, n, eta)`: zero on total internal reflection.
#[inline]
pub(crate) fn refract(e: Vec3, n: Vec3, eta: f32) -> Vec3 {
    let d = n.dot(e);
    let k = 1.0 - eta * eta * (1.0 - d * d);
    if k < 0.0 {
        Vec3::ZERO
    } else {
        eta * e - (eta * d + k.sqrt()) * n
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pcg_matches_known_values() {
        // Reference values of the WGSL code's arithmetic, computed independently in u64.
        let h = |v: u64| {
            let s = (v * 747_796_405 + 2_891_336_453) & 0xffff_ffff;
            let w = (((s >> ((s >> 28) + 4)) ^ s) * 277_803_737) & 0xffff_ffff;
            ((w >> 22) ^ w) as u32
        };
        for v in [0u32, 1, 7, 123_456_789, u32::MAX] {
            assert_eq!(pcg_hash(v), h(v as u64));
        }
        let mut r = Rng(5);
        let x = r.next();
        assert!((0.0..1.0).contains(&x));
        assert_eq!(r.0, 5u32.wrapping_mul(747_796_405).wrapping_add(2_891_336_453));
    }

    #[test]
    fn onb_is_orthonormal() {
        for n in [Vec3::Z, -Vec3::Z, Vec3::new(0.3, -0.5, 0.8).normalize(), Vec3::X] {
            let f = onb(n);
            assert!((f.x_axis.dot(f.y_axis)).abs() < 1e-6);
            assert!((f.x_axis.length() - 1.0).abs() < 1e-5);
            assert!((f.z_axis - n).length() < 1e-6);
            let v = Vec3::new(0.2, 0.4, -0.1);
            assert!((to_world(&f, to_local(&f, v)) - v).length() < 1e-6);
        }
    }

    #[test]
    fn offset_moves_along_the_normal() {
        for p in [Vec3::new(100.0, -200.0, 0.001), Vec3::new(0.01, 5.0, -3.0)] {
            let n = Vec3::new(0.0, 1.0, 0.0);
            let q = offset_ray(p, n);
            assert!(q.y > p.y && (q.x - p.x).abs() < 1e-3 && (q.z - p.z).abs() < 1e-3);
        }
    }
}
