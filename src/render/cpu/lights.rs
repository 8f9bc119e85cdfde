//! Twin of `wgsl/trace/lib/lights.wgsl`: next-event estimation on emissive triangles (by
//! power) and the environment (importance sampled from its CDFs, mixed with points on its
//! portals when it has any), and the MIS weights.

use glam::Vec3A as Vec3;

use super::common::{BIG, PI, TWO_PI, luminance};
use super::material::{interp_uv, material_emission, material_of, tri_info, tri_vec};
use crate::render::packed::{ENV_HDR, LIGHTS_HAVE_PASS, PackedScene};

#[inline]
fn v3(v: [f32; 4]) -> Vec3 {
    Vec3::new(v[0], v[1], v[2])
}

/// Power heuristic weight of the strategy with pdf `a` against `b`.
#[inline]
pub(crate) fn mis_power(a: f32, b: f32) -> f32 {
    let a2 = a * a;
    let b2 = b * b;
    if a2 + b2 <= 0.0 { 0.0 } else { a2 / (a2 + b2) }
}

/// The environment's header values and, per row, a guide table into its conditional CDF.
/// Large maps do not fit in cache: a sample's cost is its cache misses, so the guide narrows
/// the search to a few neighbouring packed (radiance, cdf) texels, the last of which holds
/// the radiance the sample returns.
#[derive(Debug, Clone)]
pub(crate) struct EnvInfo {
    pub w: u32,
    pub h: u32,
    pub total: f32,
    pub present: bool,
    pub floor: f32,
    /// Per row j, at `j * (GUIDE + 1) + k`: the first texel whose conditional CDF exceeds
    /// `k / GUIDE` (`w - 1` when none does). The texel sampled for `u` lies between the
    /// entries of `floor(u * GUIDE)` and the next, so the binary search runs over a few
    /// texels instead of the whole row, and finds the same texel.
    guide: Vec<u32>,
}

/// Buckets of the per-row guide tables: about `w / GUIDE` texels (two or three cache lines
/// for a 2048-wide map) per search where the row is even.
const GUIDE: usize = 256;

/// Threshold of guide bucket `k` (f32, as the searches compare).
#[inline]
fn guide_threshold(k: usize) -> f32 {
    k as f32 / GUIDE as f32
}

impl EnvInfo {
    pub fn new(sc: &PackedScene) -> Self {
        let e = sc.env[0];
        let (w, h) = (e[0].to_bits(), e[1].to_bits());
        let present = e[3].to_bits() != 0;
        let base = ENV_HDR + h as usize;
        let mut guide = Vec::new();
        if present {
            guide.reserve(h as usize * (GUIDE + 1));
            for texels in sc.env[base..base + (w * h) as usize].chunks_exact(w as usize) {
                guide.extend(guide_row(texels.len(), |i| texels[i][3]));
            }
        }
        Self {
            w,
            h,
            total: e[2],
            present,
            floor: sc.env[1][0],
            guide,
        }
    }
}

/// Light-list header values.
#[inline]
pub(crate) fn light_count(sc: &PackedScene) -> u32 {
    sc.lights[0][0].to_bits()
}

#[inline]
pub(crate) fn env_select_prob(sc: &PackedScene) -> f32 {
    sc.lights[0][2]
}

#[inline]
fn env_local(sc: &PackedScene, d: Vec3) -> Vec3 {
    Vec3::new(v3(sc.env[2]).dot(d), v3(sc.env[3]).dot(d), v3(sc.env[4]).dot(d))
}

fn env_pixel(sc: &PackedScene, ei: &EnvInfo, d: Vec3) -> (u32, u32) {
    let l = env_local(sc, d);
    let u = l.x.atan2(-l.z) / TWO_PI;
    let u = u - u.floor();
    let v = l.y.clamp(-1.0, 1.0).acos() / PI;
    (
        ((u * ei.w as f32) as u32).min(ei.w - 1),
        ((v * ei.h as f32) as u32).min(ei.h - 1),
    )
}

/// Radiance of the environment towards direction `d` (nearest texel).
pub(crate) fn env_radiance(sc: &PackedScene, ei: &EnvInfo, d: Vec3) -> Vec3 {
    if !ei.present {
        return Vec3::ZERO;
    }
    let (x, y) = env_pixel(sc, ei, d);
    v3(sc.env[ENV_HDR + (ei.h + y * ei.w + x) as usize])
}

fn env_pixel_pdf(sc: &PackedScene, ei: &EnvInfo, px: (u32, u32), sin_t: f32) -> f32 {
    let rgb = v3(sc.env[ENV_HDR + (ei.h + px.1 * ei.w + px.0) as usize]);
    let row_sin = (PI * (px.1 as f32 + 0.5) / ei.h as f32).sin();
    let weight = (luminance(rgb) + ei.floor) * row_sin;
    let pmf = weight / ei.total;
    pmf * ei.w as f32 * ei.h as f32 / (2.0 * PI * PI * sin_t.max(1.0e-6))
}

/// Solid-angle pdf of sampling direction `d` from the environment.
pub(crate) fn env_pdf(sc: &PackedScene, ei: &EnvInfo, d: Vec3) -> f32 {
    if !ei.present {
        return 0.0;
    }
    let l = env_local(sc, d);
    let sin_t = (1.0 - l.y * l.y).max(0.0).sqrt();
    env_pixel_pdf(sc, ei, env_pixel(sc, ei, d), sin_t)
}

/// First index in `[0, n)` whose inclusive CDF `cdf(i)` exceeds `u` (`n - 1` when none
/// does), for a non-decreasing `cdf`.
#[inline]
fn search(n: u32, u: f32, cdf: impl Fn(u32) -> f32) -> u32 {
    let (mut lo, mut hi) = (0u32, n - 1);
    while lo < hi {
        let mid = (lo + hi) / 2;
        if cdf(mid) > u {
            hi = mid;
        } else {
            lo = mid + 1;
        }
    }
    lo
}

/// Guide table of one CDF row of `len` entries, `cdf(i)` each (see [`EnvInfo`]).
fn guide_row(len: usize, cdf: impl Fn(usize) -> f32) -> impl Iterator<Item = u32> {
    let mut i = 0usize;
    (0..=GUIDE).map(move |k| {
        let t = guide_threshold(k);
        while i + 1 < len && cdf(i) <= t {
            i += 1;
        }
        i as u32
    })
}

/// [`search`] over a row whose inclusive CDF is `cdf(i)`, restricted by its guide table
/// `guide`.
#[inline]
fn guided_search(guide: &[u32], u: f32, cdf: impl Fn(u32) -> f32) -> u32 {
    // The bucket k with threshold(k) <= u < threshold(k + 1).
    let mut k = ((u * GUIDE as f32) as usize).min(GUIDE - 1);
    while k > 0 && guide_threshold(k) > u {
        k -= 1;
    }
    while k + 1 < GUIDE && guide_threshold(k + 1) <= u {
        k += 1;
    }
    let (lo, hi) = (guide[k], guide[k + 1]);
    lo + search(hi - lo + 1, u, |m| cdf(lo + m))
}

/// One light sample (WGSL `LightSample`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct LightSample {
    pub wi: Vec3,
    /// Distance to the light point ([`BIG`] for the environment).
    pub dist: f32,
    /// Emitted radiance towards the shading point.
    pub le: Vec3,
    /// Solid-angle pdf, light choice included.
    pub pdf: f32,
}

/// Starts loading into the cache what [`sample_light`] will read when it samples the map:
/// for random numbers `u`, the texels its search ends among (their guide entries already
/// cached), and for `u_next`, the numbers of the sample after, the guide entries. A path
/// calls it before tracing each segment, so that the misses of a large map overlap the
/// traversal instead of following it. Only a hint: it changes no result.
#[inline]
pub(crate) fn prefetch_light(sc: &PackedScene, ei: &EnvInfo, u: Vec3, u_next: Vec3) {
    let pe = env_select_prob(sc);
    if !ei.present || portal_count(sc) != 0 {
        return;
    }
    let (w, h) = (ei.w, ei.h);
    let row_guide = |u: Vec3| {
        let j = search(h, u.y, |j| sc.env[ENV_HDR + j as usize][0]);
        let k = ((u.x * GUIDE as f32) as usize).min(GUIDE - 1);
        (j, j as usize * (GUIDE + 1) + k)
    };
    if u.z < pe {
        let (j, g) = row_guide(u);
        let base = ENV_HDR + (h + j * w) as usize;
        prefetch(&sc.env[base + ei.guide[g] as usize]);
        prefetch(&sc.env[base + ei.guide[g + 1] as usize]);
    }
    if u_next.z < pe {
        prefetch(&ei.guide[row_guide(u_next).1]);
    }
}

/// A hint to load the cache line of `v`.
#[inline(always)]
fn prefetch<T>(v: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch reads nothing into the program and cannot fault.
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>((v as *const T).cast());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = v;
}

fn env_sample(sc: &PackedScene, ei: &EnvInfo, u: [f32; 2]) -> Option<LightSample> {
    let (w, h) = (ei.w, ei.h);
    let marg = |j: u32| sc.env[ENV_HDR + j as usize][0];
    let j = search(h, u[1], marg);
    let c0 = if j > 0 { marg(j - 1) } else { 0.0 };
    let c1 = marg(j);
    let fv = ((u[1] - c0) / (c1 - c0).max(1.0e-12)).clamp(0.0, 0.99999);
    let base = ENV_HDR + (h + j * w) as usize;
    let row = &sc.env[base..base + w as usize];
    let cond = |i: u32| row[i as usize][3];
    let i = guided_search(
        &ei.guide[j as usize * (GUIDE + 1)..(j as usize + 1) * (GUIDE + 1)],
        u[0],
        cond,
    );
    let r0 = if i > 0 { cond(i - 1) } else { 0.0 };
    let r1 = cond(i);
    let fu = ((u[0] - r0) / (r1 - r0).max(1.0e-12)).clamp(0.0, 0.99999);
    let uu = (i as f32 + fu) / w as f32;
    let vv = (j as f32 + fv) / h as f32;
    let theta = PI * vv;
    let phi = TWO_PI * uu;
    let sin_t = theta.sin();
    let l = Vec3::new(sin_t * phi.sin(), theta.cos(), -sin_t * phi.cos());
    let d = Vec3::new(v3(sc.env[5]).dot(l), v3(sc.env[6]).dot(l), v3(sc.env[7]).dot(l)).normalize();
    let pdf = env_pixel_pdf(sc, ei, (i, j), sin_t);
    (pdf > 0.0).then(|| LightSample {
        wi: d,
        dist: BIG,
        le: v3(row[i as usize]),
        pdf,
    })
}

#[inline]
pub(crate) fn portal_count(sc: &PackedScene) -> u32 {
    sc.lights[0][3].to_bits() & !LIGHTS_HAVE_PASS
}

/// Some triangle passes light straight through ([`crate::render::packed::MAT_PASS`]).
#[inline]
pub(crate) fn has_pass(sc: &PackedScene) -> bool {
    sc.lights[0][3].to_bits() & LIGHTS_HAVE_PASS != 0
}

#[inline]
fn portal_base(sc: &PackedScene) -> usize {
    1 + light_count(sc) as usize
}

/// Probability with which an environment light sample picks a portal.
#[inline]
fn portal_prob(sc: &PackedScene) -> f32 {
    sc.lights[portal_base(sc) + 2][3]
}

/// Solid-angle pdf with which [`portal_sample`] from `p` picks direction `d`: the sum over
/// the portals that the ray `p + t d` (`t > 0`) leaves through.
pub(crate) fn portal_pdf(sc: &PackedScene, p: Vec3, d: Vec3) -> f32 {
    let mut pdf = 0.0;
    for k in 0..portal_count(sc) as usize {
        let b = portal_base(sc) + 3 * k;
        let (c, eu, ev) = (v3(sc.lights[b]), v3(sc.lights[b + 1]), v3(sc.lights[b + 2]));
        let nn = eu.cross(ev);
        let dn = d.dot(nn);
        if !(dn < 0.0) {
            continue;
        }
        let t = (c - p).dot(nn) / dn;
        if !(t > 0.0) {
            continue;
        }
        let r = p + t * d - c;
        let inv = 1.0 / nn.dot(nn);
        let s = r.cross(ev).dot(nn) * inv;
        let w = eu.cross(r).dot(nn) * inv;
        if (0.0..=1.0).contains(&s) && (0.0..=1.0).contains(&w) {
            // Area density 1 / (total area), over |cos| = -dn / |nn| at distance t.
            pdf += t * t * nn.length() / (-dn * sc.lights[b + 1][3]);
        }
    }
    pdf
}

/// Solid-angle pdf of the environment's light samples from `p` (its selection probability
/// not included): the map's pdf, mixed with the portals' when there are any.
pub(crate) fn env_light_pdf(sc: &PackedScene, ei: &EnvInfo, p: Vec3, d: Vec3) -> f32 {
    if portal_count(sc) == 0 {
        return env_pdf(sc, ei, d);
    }
    let pp = portal_prob(sc);
    (1.0 - pp) * env_pdf(sc, ei, d) + pp * portal_pdf(sc, p, d)
}

/// A direction from `p` through a point of a portal (`u.z` picks the portal by area, `u.x`
/// and `u.y` the point), with pdf 0 (the caller weighs it); `None` where `p` is not on the
/// portal's inner side.
fn portal_sample(sc: &PackedScene, ei: &EnvInfo, p: Vec3, u: Vec3) -> Option<LightSample> {
    let n = portal_count(sc) as usize;
    let mut k = 0;
    while k + 1 < n && sc.lights[portal_base(sc) + 3 * k][3] <= u.z {
        k += 1;
    }
    let b = portal_base(sc) + 3 * k;
    let (eu, ev) = (v3(sc.lights[b + 1]), v3(sc.lights[b + 2]));
    let q = v3(sc.lights[b]) + u.x * eu + u.y * ev;
    let mut wi = q - p;
    let dist = wi.length();
    if !(dist > 0.0) {
        return None;
    }
    wi /= dist;
    if !(wi.dot(eu.cross(ev)) < 0.0) {
        return None;
    }
    Some(LightSample {
        wi,
        dist: BIG,
        le: env_radiance(sc, ei, wi),
        pdf: 0.0,
    })
}

/// Solid-angle pdf with which [`sample_light`] picks the point on emissive triangle `prim`
/// seen at distance `dist` under `cos_l`.
pub(crate) fn tri_light_pdf(sc: &PackedScene, prim: u32, dist: f32, cos_l: f32) -> f32 {
    let total = sc.lights[0][1];
    if light_count(sc) == 0 || total <= 0.0 || cos_l <= 0.0 {
        return 0.0;
    }
    let m = material_of(sc, tri_info(sc, prim));
    (1.0 - env_select_prob(sc)) * m.emissive[3] * dist * dist / (total * cos_l)
}

fn sample_tri_light(sc: &PackedScene, p: Vec3, u: Vec3) -> Option<LightSample> {
    let n = light_count(sc);
    let k = search(n, u.z, |k| sc.lights[1 + k as usize][1]);
    let entry = sc.lights[1 + k as usize];
    let prim = entry[0].to_bits();
    let pmf = entry[2];
    let area = entry[3];
    let info = tri_info(sc, prim);
    let v0 = tri_vec(sc, prim, 0);
    let e1 = tri_vec(sc, prim, 1);
    let e2 = tri_vec(sc, prim, 2);
    let su = u.x.sqrt();
    let bu = su * (1.0 - u.y);
    let bv = su * u.y;
    let q = v0 - e1 * bu + e2 * bv;
    let ng = (-e1.cross(e2)).normalize();
    let mut wi = q - p;
    let dist = wi.length();
    if !(dist > 0.0) || !(area > 0.0) {
        return None;
    }
    wi /= dist;
    let cos_l = ng.dot(-wi);
    if cos_l <= 1.0e-6 {
        return None;
    }
    let m = material_of(sc, info);
    let pdf = (1.0 - env_select_prob(sc)) * pmf * dist * dist / (area * cos_l);
    (pdf > 0.0).then(|| LightSample {
        wi,
        dist,
        le: material_emission(sc, m, interp_uv(sc, info, bu, bv)),
        pdf,
    })
}

/// One light sample from `p`: the environment with probability [`env_select_prob`], else an
/// emissive triangle by power.
pub(crate) fn sample_light(sc: &PackedScene, ei: &EnvInfo, p: Vec3, u: Vec3) -> Option<LightSample> {
    let pe = env_select_prob(sc);
    if u.z < pe {
        if portal_count(sc) == 0 {
            return env_sample(sc, ei, [u.x, u.y]).map(|mut s| {
                s.pdf *= pe;
                s
            });
        }
        // A portal or the map (u.z rescaled picks which, then the portal), weighed by the
        // mixture's pdf.
        let pp = portal_prob(sc);
        let ue = u.z / pe;
        let (s, map_pdf) = if ue < pp {
            let s = portal_sample(sc, ei, p, Vec3::new(u.x, u.y, ue / pp))?;
            (s, env_pdf(sc, ei, s.wi))
        } else {
            let s = env_sample(sc, ei, [u.x, u.y])?;
            (s, s.pdf)
        };
        let pdf = pe * ((1.0 - pp) * map_pdf + pp * portal_pdf(sc, p, s.wi));
        return (pdf > 0.0).then_some(LightSample { pdf, ..s });
    }
    if light_count(sc) == 0 {
        return None;
    }
    let uz = ((u.z - pe) / (1.0 - pe).max(1.0e-12)).clamp(0.0, 0.999_999_94);
    sample_tri_light(sc, p, Vec3::new(u.x, u.y, uz))
}

/// The scene has something NEE can sample.
pub(crate) fn has_lights(sc: &PackedScene) -> bool {
    light_count(sc) > 0 || env_select_prob(sc) > 0.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::cpu::common::Rng;

    /// The guided search finds the texel of the plain binary search (WGSL's), for rows with
    /// flat stretches, steps, zero-weight texels and narrow spikes.
    #[test]
    fn guided_search_matches_binary_search() {
        let mut rng = Rng(3);
        for w in [1usize, 2, 7, 64, 2048] {
            for kind in 0..4 {
                let weights: Vec<f64> = (0..w)
                    .map(|i| match kind {
                        0 => 1.0,
                        1 => {
                            if rng.next() < 0.5 {
                                0.0
                            } else {
                                rng.next() as f64
                            }
                        }
                        2 => {
                            if i == w / 3 {
                                1000.0
                            } else {
                                0.001
                            }
                        }
                        _ => (rng.next() as f64).powi(8),
                    })
                    .collect();
                let total: f64 = weights.iter().sum::<f64>().max(1e-30);
                let mut acc = 0.0;
                let mut row: Vec<f32> = weights
                    .iter()
                    .map(|x| {
                        acc += x;
                        (acc / total) as f32
                    })
                    .collect();
                *row.last_mut().unwrap() = 1.0;
                let guide: Vec<u32> = guide_row(row.len(), |i| row[i]).collect();
                let mut us: Vec<f32> = (0..2000).map(|_| rng.next()).collect();
                us.extend((0..=GUIDE).map(guide_threshold));
                us.extend(row.iter().copied());
                for u in us {
                    let u = u.min(0.999_999_94);
                    let want = search(w as u32, u, |i| row[i as usize]);
                    assert_eq!(
                        guided_search(&guide, u, |i| row[i as usize]),
                        want,
                        "w {w} kind {kind} u {u}"
                    );
                }
            }
        }
    }

    /// The search finds what a linear scan finds (the first entry above `u`, else the last)
    /// for every length up to 70, on CDFs with flat stretches and repeated values, at random
    /// `u` and at every entry's value exactly.
    #[test]
    fn search_is_the_first_entry_above_u() {
        let mut rng = Rng(11);
        for n in 1..=70usize {
            let mut acc = 0.0f32;
            let cdf: Vec<f32> = (0..n)
                .map(|_| {
                    if rng.next() < 0.6 {
                        acc += rng.next();
                    }
                    acc
                })
                .collect();
            let mut us: Vec<f32> = (0..200).map(|_| rng.next() * (acc + 0.5)).collect();
            us.extend(cdf.iter().copied());
            us.extend([0.0, -1.0, acc, acc + 1.0]);
            for u in us {
                let want = cdf.iter().position(|&c| c > u).unwrap_or(n - 1) as u32;
                assert_eq!(search(n as u32, u, |i| cdf[i as usize]), want, "n {n} u {u}");
            }
        }
    }

    /// Portal sampling's pdf is the density of its samples. From a point with two portals
    /// in front (the nearer one seen in front of part of the farther one) and a third it is
    /// outside of: the pdf integrates to the probability that a sample succeeds (the third
    /// portal's samples fail), and over portal samples the mean of f / pdf is the integral
    /// of f over the directions the pdf covers (both against uniform sphere sampling).
    #[test]
    fn portal_pdf_is_the_density_of_portal_samples() {
        use crate::render::scene::Portal;
        let mut scene = crate::render::builtin::furnace();
        let portal = |corner: Vec3, u: Vec3, v: Vec3| Portal {
            corner: corner.into(),
            u: u.into(),
            v: v.into(),
        };
        let portals = vec![
            portal(Vec3::new(-0.5, 0.0, -1.0), Vec3::X, Vec3::Y),
            portal(Vec3::new(-1.0, -0.5, -2.0), 2.0 * Vec3::X, 2.0 * Vec3::Y),
            portal(Vec3::new(-0.5, -0.5, 1.0), Vec3::X, Vec3::Y),
        ];
        let areas: Vec<f32> = portals.iter().map(|q| q.area()).collect();
        scene.environment.as_mut().unwrap().portals = portals;
        let sc = PackedScene::new(&scene, u64::MAX).unwrap();
        let ei = EnvInfo::new(&sc);
        assert_eq!(portal_count(&sc), 3);
        let p = Vec3::new(0.1, 0.3, 0.0);
        let axis = Vec3::new(0.3, 0.2, -1.0).normalize();
        let f = |d: Vec3| (3.0 * d.dot(axis)).exp() as f64;
        let mut rng = Rng(11);
        // Uniform sphere sampling: the pdf's integral and f's over where the pdf is positive.
        let n = 2_000_000;
        let (mut pdf_integral, mut f_integral) = (0.0f64, 0.0f64);
        for _ in 0..n {
            let [a, b, _] = rng.next3().to_array();
            let z = 1.0 - 2.0 * a;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = TWO_PI * b;
            let d = Vec3::new(r * phi.cos(), r * phi.sin(), z);
            let pdf = portal_pdf(&sc, p, d) as f64;
            pdf_integral += pdf;
            if pdf > 0.0 {
                f_integral += f(d);
            }
        }
        let sphere = 4.0 * std::f64::consts::PI / n as f64;
        let (pdf_integral, f_integral) = (pdf_integral * sphere, f_integral * sphere);
        let success = 1.0 - areas[2] as f64 / areas.iter().sum::<f32>() as f64;
        assert!(
            (pdf_integral - success).abs() < 0.01,
            "integral of the portal pdf {pdf_integral}, expected {success}"
        );
        // Portal samples: f / pdf, 0 for the samples that fail.
        let m = 400_000;
        let mut estimate = 0.0f64;
        let mut failed = 0;
        for _ in 0..m {
            match portal_sample(&sc, &ei, p, rng.next3()) {
                Some(s) => estimate += f(s.wi) / portal_pdf(&sc, p, s.wi) as f64,
                None => failed += 1,
            }
        }
        estimate /= m as f64;
        let fail_rate = failed as f64 / m as f64;
        assert!(
            (fail_rate - (1.0 - success)).abs() < 0.005,
            "{failed} of {m} samples failed"
        );
        assert!(
            (estimate / f_integral - 1.0).abs() < 0.015,
            "portal estimate {estimate}, sphere estimate {f_integral}"
        );
    }
}
