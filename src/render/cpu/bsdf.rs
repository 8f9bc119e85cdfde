//! Twin of `wgsl/trace/lib/bsdf.wgsl`: the glTF metallic-roughness BSDF with transmission
//! (metal, opaque dielectric and glass lobes; GGX with visible-normal sampling; one-sample
//! MIS over the sampling strategies).

use glam::{Mat3A as Mat3, Vec2, Vec3A as Vec3};

use super::common::{INV_PI, PI, TWO_PI, finite3, onb, pow5, reflect, refract, to_local, to_world};
use super::material::Surface;
use crate::render::packed::{GGX_ALPHA_MIN, MAT_DOUBLE_SIDED, MAT_PASS};

#[inline]
fn ggx_alpha(roughness: f32) -> f32 {
    (roughness * roughness).max(GGX_ALPHA_MIN)
}

#[inline]
fn ggx_d(a2: f32, cos_h: f32) -> f32 {
    let c2 = cos_h * cos_h;
    let k = c2 * (a2 - 1.0) + 1.0;
    a2 / (PI * k * k)
}

#[inline]
fn ggx_lambda(a2: f32, cos_t: f32) -> f32 {
    let c2 = (cos_t * cos_t).max(1.0e-12);
    let tan2 = (1.0 - c2).max(0.0) / c2;
    0.5 * ((1.0 + a2 * tan2).sqrt() - 1.0)
}

#[inline]
fn ggx_g1(a2: f32, cos_t: f32) -> f32 {
    1.0 / (1.0 + ggx_lambda(a2, cos_t))
}

#[inline]
fn ggx_g2(a2: f32, cos_o: f32, cos_i: f32) -> f32 {
    1.0 / (1.0 + ggx_lambda(a2, cos_o) + ggx_lambda(a2, cos_i))
}

/// Visible-normal sampling (Heitz 2018) around local +z; `wo.z > 0`.
fn sample_vndf(wo: Vec3, a: f32, u: Vec2) -> Vec3 {
    let vh = Vec3::new(a * wo.x, a * wo.y, wo.z).normalize();
    let lensq = vh.x * vh.x + vh.y * vh.y;
    let t1 = if lensq > 1.0e-12 {
        Vec3::new(-vh.y, vh.x, 0.0) / lensq.sqrt()
    } else {
        Vec3::X
    };
    let t2 = vh.cross(t1);
    let r = u.x.sqrt();
    let phi = TWO_PI * u.y;
    let p1 = r * phi.cos();
    let s = 0.5 * (1.0 + vh.z);
    let p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * (r * phi.sin());
    let nh = p1 * t1 + p2 * t2 + (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt() * vh;
    Vec3::new(a * nh.x, a * nh.y, nh.z.max(1.0e-6)).normalize()
}

/// Unpolarised dielectric Fresnel reflectance; `eta` = index beyond / index of incidence.
pub(crate) fn fresnel_dielectric(cos_i: f32, eta: f32) -> f32 {
    let sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    let rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    0.5 * (rs * rs + rp * rp)
}

#[inline]
fn schlick3(f0: Vec3, c: f32) -> Vec3 {
    f0 + (Vec3::ONE - f0) * pow5((1.0 - c).clamp(0.0, 1.0))
}

#[inline]
fn spec_fresnel(s: &Surface, c: f32) -> f32 {
    let f0 = (s.ior - 1.0) / (s.ior + 1.0);
    (s.specular * (f0 * f0 + (1.0 - f0 * f0) * pow5((1.0 - c).clamp(0.0, 1.0)))).min(1.0)
}

#[inline]
fn bsdf_black(s: &Surface) -> bool {
    !s.front && s.flags & MAT_DOUBLE_SIDED == 0 && s.transmission <= 0.0
}

/// Indices of refraction on the side of wo and beyond.
#[inline]
fn glass_etas(s: &Surface) -> (f32, f32) {
    if s.thin() || s.front {
        (1.0, s.ior)
    } else {
        (s.ior, 1.0)
    }
}

/// Lobe weights: metal, opaque, glass.
#[inline]
fn lobe_weights(s: &Surface) -> Vec3 {
    let m = s.metallic;
    Vec3::new(m, (1.0 - m) * (1.0 - s.transmission), (1.0 - m) * s.transmission)
}

/// Strategy probabilities: GGX reflection, cosine, glass.
#[inline]
fn strategy_probs(s: &Surface, cos_o: f32) -> Vec3 {
    let w = lobe_weights(s);
    let fe = spec_fresnel(s, cos_o);
    let q = Vec3::new(w.x + w.y * fe, w.y * (1.0 - fe), w.z);
    let sum = q.x + q.y + q.z;
    if sum <= 0.0 {
        Vec3::new(0.0, 1.0, 0.0)
    } else {
        q / sum
    }
}

/// Everything of the BSDF at one shading point that depends on the outgoing direction
/// only: computed once per path vertex and shared by the light sample's evaluation and the
/// BSDF sample (the same arithmetic as evaluating from scratch, done once).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Lobes {
    frame: Mat3,
    /// `wo` in the shading frame.
    lo: Vec3,
    a: f32,
    a2: f32,
    /// Lobe weights.
    w: Vec3,
    /// Strategy probabilities.
    q: Vec3,
    etas: (f32, f32),
    /// Nothing is reflected or transmitted (`bsdf_black`, or `wo` below the shading
    /// horizon).
    black: bool,
    /// Light goes straight through ([`MAT_PASS`]): the transmission is a specular event
    /// ([`pass_through`]), taken before the vertex scatters; the lobes evaluated and
    /// sampled here are the rest, given that it does not pass.
    pass: bool,
    /// With `pass`: the glass lobe's Fresnel reflectance at `wo` (the same one decides
    /// between passing and reflecting).
    fr_pass: f32,
}

impl Lobes {
    pub fn new(s: &Surface, wo: Vec3) -> Self {
        let frame = onb(s.ns);
        let lo = to_local(&frame, wo);
        let a = ggx_alpha(s.roughness);
        let black = bsdf_black(s) || lo.z <= 1.0e-6;
        let q = if black {
            Vec3::ZERO
        } else {
            strategy_probs(s, lo.z)
        };
        let etas = glass_etas(s);
        let pass = s.flags & MAT_PASS != 0 && !black;
        let fr_pass = if pass {
            fresnel_dielectric(lo.z, etas.1 / etas.0)
        } else {
            0.0
        };
        Self {
            frame,
            lo,
            a,
            a2: a * a,
            w: lobe_weights(s),
            q,
            etas,
            black,
            pass,
            fr_pass,
        }
    }

    /// The probability that the vertex scatters (1 where the surface does not pass light).
    fn scatter(&self) -> f32 {
        if self.pass {
            1.0 - self.q.z * (1.0 - self.fr_pass)
        } else {
            1.0
        }
    }
}

/// Where light goes straight through the surface ([`MAT_PASS`]): its transmittance
/// towards `wo`'s opposite (the glass lobe's share of what the Fresnel reflectance lets
/// through, tinted) and the probability with which a path passes (the glass strategy's
/// share of the same). `None` elsewhere.
pub(crate) fn pass_through(s: &Surface, l: &Lobes) -> Option<(Vec3, f32)> {
    l.pass
        .then(|| (l.w.z * (1.0 - l.fr_pass) * s.base, l.q.z * (1.0 - l.fr_pass)))
}

/// `f(wo, wi) |cos(n, wi)|` and the solid-angle sampling pdf of `wi`.
#[cfg(test)]
pub(crate) fn bsdf_eval(s: &Surface, wo: Vec3, wi: Vec3) -> (Vec3, f32) {
    bsdf_eval_with(s, &Lobes::new(s, wo), wi)
}

/// [`bsdf_eval`] with the outgoing direction's [`Lobes`].
pub(crate) fn bsdf_eval_with(s: &Surface, l: &Lobes, wi: Vec3) -> (Vec3, f32) {
    if l.black {
        return (Vec3::ZERO, 0.0);
    }
    let (lo, w, q, etas, a2) = (l.lo, l.w, l.q, l.etas, l.a2);
    let li = to_local(&l.frame, wi);
    let mut f = Vec3::ZERO;
    let mut pdf = 0.0;
    let reflect_side = wi.dot(s.ng) > 0.0;
    if reflect_side && li.z > 1.0e-6 {
        let h = (lo + li).normalize();
        let oh = lo.dot(h).max(1.0e-6);
        let d = ggx_d(a2, h.z);
        let spec = d * ggx_g2(a2, lo.z, li.z) / (4.0 * lo.z);
        let pdf_r = ggx_g1(a2, lo.z) * d / (4.0 * lo.z);
        f += w.x * schlick3(s.base, oh) * spec;
        let fd = spec_fresnel(s, oh);
        f += w.y * (fd * spec + (1.0 - fd) * s.base * INV_PI * li.z);
        pdf += q.x * pdf_r + q.y * li.z * INV_PI;
        if w.z > 0.0 {
            let fr = if l.pass {
                l.fr_pass
            } else {
                fresnel_dielectric(oh, etas.1 / etas.0)
            };
            f += w.z * fr * spec * Vec3::ONE;
            pdf += q.z * fr * pdf_r;
        }
    } else if !reflect_side && li.z < -1.0e-6 && w.z > 0.0 && !l.pass {
        if s.thin() {
            let lr = Vec3::new(li.x, li.y, -li.z);
            let h = (lo + lr).normalize();
            let oh = lo.dot(h).max(1.0e-6);
            let d = ggx_d(a2, h.z);
            let fr = fresnel_dielectric(oh, etas.1 / etas.0);
            f += w.z * (1.0 - fr) * s.base * d * ggx_g2(a2, lo.z, lr.z) / (4.0 * lo.z);
            pdf += q.z * (1.0 - fr) * ggx_g1(a2, lo.z) * d / (4.0 * lo.z);
        } else {
            let mut h = (etas.0 * lo + etas.1 * li).normalize();
            if h.z < 0.0 {
                h = -h;
            }
            let oh = lo.dot(h);
            let ih = li.dot(h);
            if oh > 1.0e-6 && ih < -1.0e-6 {
                let fr = fresnel_dielectric(oh, etas.1 / etas.0);
                let denom = etas.0 * oh + etas.1 * ih;
                let jac = etas.1 * etas.1 * ih.abs() / (denom * denom);
                let d = ggx_d(a2, h.z);
                f += w.z * (1.0 - fr) * s.base * d * ggx_g2(a2, lo.z, -li.z) * oh * jac / lo.z;
                pdf += q.z * (1.0 - fr) * ggx_g1(a2, lo.z) * oh * d / lo.z * jac;
            }
        }
    }
    if l.pass {
        pdf /= l.scatter().max(1.0e-12);
    }
    (f, pdf)
}

/// A sampled direction (WGSL `BsdfSample`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct BsdfSample {
    pub wi: Vec3,
    /// `f |cos| / pdf`.
    pub weight: Vec3,
    pub pdf: f32,
    /// `wi` left through the surface.
    pub transmitted: bool,
}

/// Samples a direction with the random numbers `u` (WGSL `bsdf_sample`).
#[cfg(test)]
pub(crate) fn bsdf_sample(s: &Surface, wo: Vec3, u: Vec3) -> Option<BsdfSample> {
    bsdf_sample_with(s, &Lobes::new(s, wo), u)
}

/// [`bsdf_sample`] with the outgoing direction's [`Lobes`].
pub(crate) fn bsdf_sample_with(s: &Surface, l: &Lobes, u: Vec3) -> Option<BsdfSample> {
    if l.black {
        return None;
    }
    let (lo, q, a) = (l.lo, l.q, l.a);
    // Where the surface passes light, the strategies given that it does not: the glass
    // strategy only reflects.
    let uz = u.z * l.scatter();
    let li = if uz < q.x {
        let h = sample_vndf(lo, a, Vec2::new(u.x, u.y));
        reflect(-lo, h)
    } else if uz < q.x + q.y {
        let r = u.x.sqrt();
        let phi = TWO_PI * u.y;
        Vec3::new(r * phi.cos(), r * phi.sin(), (1.0 - u.x).max(0.0).sqrt())
    } else if l.pass {
        reflect(-lo, sample_vndf(lo, a, Vec2::new(u.x, u.y)))
    } else {
        let uz = ((uz - q.x - q.y) / q.z.max(1.0e-12)).clamp(0.0, 1.0);
        let h = sample_vndf(lo, a, Vec2::new(u.x, u.y));
        let oh = lo.dot(h);
        let etas = l.etas;
        let fr = fresnel_dielectric(oh.max(1.0e-6), etas.1 / etas.0);
        let lr = reflect(-lo, h);
        if uz < fr {
            lr
        } else if s.thin() {
            Vec3::new(lr.x, lr.y, -lr.z)
        } else {
            let t = refract(-lo, h, etas.0 / etas.1);
            if t.dot(t) == 0.0 {
                return None;
            }
            t
        }
    };
    let wi = to_world(&l.frame, li).normalize();
    let (f, pdf) = bsdf_eval_with(s, l, wi);
    if !(pdf > 0.0) || !finite3(f) {
        return None;
    }
    Some(BsdfSample {
        wi,
        weight: f / pdf,
        pdf,
        transmitted: wi.dot(s.ng) < 0.0,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec4;

    fn surface(metallic: f32, roughness: f32, transmission: f32) -> Surface {
        Surface {
            p: Vec3::ZERO,
            ng: Vec3::Z,
            ns: Vec3::Z,
            front: true,
            prim: 0,
            flags: 0,
            base: Vec3::splat(0.8),
            metallic,
            roughness,
            transmission,
            ior: 1.5,
            specular: 1.0,
            emission: Vec3::ZERO,
            attenuation: Vec4::ZERO,
        }
    }

    /// The sampled weight is f cos / pdf of bsdf_eval, and a Monte Carlo estimate of the
    /// albedo from bsdf_eval with cosine sampling agrees with the one from bsdf_sample.
    #[test]
    fn sampling_agrees_with_evaluation() {
        let wo = Vec3::new(0.3, 0.1, 0.9).normalize();
        for (m, r, t) in [(0.0, 1.0, 0.0), (1.0, 0.3, 0.0), (0.0, 0.5, 0.0), (0.5, 0.7, 0.0)] {
            let s = surface(m, r, t);
            let mut rng = super::super::common::Rng(17);
            let n = 200_000;
            let (mut by_sampling, mut by_eval) = (0.0f64, 0.0f64);
            for _ in 0..n {
                if let Some(bs) = bsdf_sample(&s, wo, rng.next3()) {
                    by_sampling += bs.weight.x as f64;
                }
                // Uniform hemisphere estimate of the same integral.
                let [u1, u2] = rng.next2();
                let z = u1;
                let rr = (1.0 - z * z).max(0.0).sqrt();
                let phi = TWO_PI * u2;
                let wi = Vec3::new(rr * phi.cos(), rr * phi.sin(), z);
                by_eval += (bsdf_eval(&s, wo, wi).0.x * TWO_PI) as f64;
            }
            let (a, b) = (by_sampling / n as f64, by_eval / n as f64);
            assert!(
                (a - b).abs() < 0.02 * b.max(0.05),
                "m {m} r {r}: sampled {a} vs evaluated {b}"
            );
            assert!(a <= 1.0 + 1e-3, "energy gain {a}");
        }
    }

    /// Smooth thin glass that passes light straight through: the lobes it samples when it
    /// scatters (it reflects, or its diffuse part does) integrate, by sampling and by
    /// evaluation, to the same reflectance, and reflectance plus transmittance is 1 for
    /// clear glass and below 1 for a tinted, part-diffuse pane.
    #[test]
    fn straight_through_glass_conserves_energy() {
        let wo = Vec3::new(0.3, 0.1, 0.9).normalize();
        for (transmission, base, clear) in [(1.0, 1.0, true), (0.6, 0.8, false)] {
            let mut s = surface(0.0, 0.0, transmission);
            s.flags = crate::render::packed::MAT_THIN | MAT_PASS;
            s.base = Vec3::splat(base);
            let l = Lobes::new(&s, wo);
            let (t, q) = pass_through(&s, &l).expect("passes light");
            assert!(q > 0.0 && q < 1.0 && t.x > 0.0, "t {t}, q {q}");
            let mut rng = super::super::common::Rng(5);
            let n = 400_000;
            let (mut by_sampling, mut by_eval) = (0.0f64, 0.0f64);
            for _ in 0..n {
                if let Some(bs) = bsdf_sample_with(&s, &l, rng.next3()) {
                    assert!(!bs.transmitted, "a scattering sample went through");
                    by_sampling += bs.weight.x as f64;
                }
                let [u1, u2] = rng.next2();
                let rr = (1.0 - u1 * u1).max(0.0).sqrt();
                let phi = TWO_PI * u2;
                let wi = Vec3::new(rr * phi.cos(), rr * phi.sin(), u1);
                by_eval += (bsdf_eval_with(&s, &l, wi).0.x * TWO_PI) as f64;
            }
            // Reflection off a floor-roughness lobe: uniform sampling finds it rarely, so
            // the evaluation estimate is compared for the diffuse pane only.
            let reflect = by_sampling / n as f64;
            if !clear {
                let eval = by_eval / n as f64;
                assert!(
                    (reflect - eval).abs() < 0.02 * eval,
                    "sampled {reflect} vs evaluated {eval}"
                );
            }
            let total = reflect + t.x as f64;
            if clear {
                assert!((total - 1.0).abs() < 0.01, "clear pane: R + T = {total}");
            } else {
                assert!(total < 1.0, "tinted pane: R + T = {total}");
            }
        }
    }

    #[test]
    fn one_sided_back_faces_are_black() {
        let mut s = surface(0.0, 1.0, 0.0);
        s.front = false;
        assert!(bsdf_sample(&s, Vec3::Z, Vec3::splat(0.5)).is_none());
        assert_eq!(bsdf_eval(&s, Vec3::Z, Vec3::Z).1, 0.0);
        s.flags = MAT_DOUBLE_SIDED;
        assert!(bsdf_eval(&s, Vec3::Z, Vec3::Z).1 > 0.0);
    }

    #[test]
    fn fresnel_limits() {
        assert!((fresnel_dielectric(1.0, 1.5) - 0.04).abs() < 1e-4);
        assert_eq!(fresnel_dielectric(0.1, 1.0 / 1.5), 1.0); // total internal reflection
    }
}
