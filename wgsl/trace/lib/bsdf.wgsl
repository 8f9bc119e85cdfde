// Path tracer library: the glTF metallic-roughness BSDF with transmission.
//
// Three lobes, mixed by the material:
//   metal   (weight metallic):                 GGX reflection, Schlick Fresnel with F0 = base colour
//   opaque  (weight (1-metallic)(1-transm.)):  Lambert x (1 - F) + GGX reflection x F, where
//            F = specular x Schlick(F0 = ((ior-1)/(ior+1))^2) (glTF fresnel_mix, KHR_materials_specular)
//   glass   (weight (1-metallic) transm.):     GGX dielectric (Walter et al. 2007): reflection with
//            the exact dielectric Fresnel, refraction tinted by the base colour; thin-walled
//            materials transmit straight through (the reflected lobe mirrored by the surface).
// Roughness alpha = perceptual^2, clamped to ALPHA_MIN so smooth metals and glass stay
// microfacet lobes (no delta special cases). Sampling picks a strategy (GGX visible normals,
// cosine, dielectric) and weights with the full mixture pdf (one-sample MIS over lobes).
// Opaque single-sided surfaces are black from behind (as Mitsuba's one-sided BSDFs).

const ALPHA_MIN: f32 = 0.002;

fn ggx_alpha(roughness: f32) -> f32 {
    return max(roughness * roughness, ALPHA_MIN);
}

fn ggx_d(a2: f32, cos_h: f32) -> f32 {
    let c2 = cos_h * cos_h;
    let k = c2 * (a2 - 1.0) + 1.0;
    return a2 / (PI * k * k);
}

fn ggx_lambda(a2: f32, cos_t: f32) -> f32 {
    let c2 = max(cos_t * cos_t, 1.0e-12);
    let tan2 = max(1.0 - c2, 0.0) / c2;
    return 0.5 * (sqrt(1.0 + a2 * tan2) - 1.0);
}

fn ggx_g1(a2: f32, cos_t: f32) -> f32 {
    return 1.0 / (1.0 + ggx_lambda(a2, cos_t));
}

fn ggx_g2(a2: f32, cos_o: f32, cos_i: f32) -> f32 {
    return 1.0 / (1.0 + ggx_lambda(a2, cos_o) + ggx_lambda(a2, cos_i));
}

// Visible-normal sampling (Heitz 2018) around local +z; wo.z > 0.
fn sample_vndf(wo: vec3<f32>, a: f32, u: vec2<f32>) -> vec3<f32> {
    let vh = normalize(vec3<f32>(a * wo.x, a * wo.y, wo.z));
    let lensq = vh.x * vh.x + vh.y * vh.y;
    var t1 = vec3<f32>(1.0, 0.0, 0.0);
    if (lensq > 1.0e-12) {
        t1 = vec3<f32>(-vh.y, vh.x, 0.0) / sqrt(lensq);
    }
    let t2 = cross(vh, t1);
    let r = sqrt(u.x);
    let phi = TWO_PI * u.y;
    let p1 = r * cos(phi);
    let s = 0.5 * (1.0 + vh.z);
    let p2 = (1.0 - s) * sqrt(max(1.0 - p1 * p1, 0.0)) + s * (r * sin(phi));
    let nh = p1 * t1 + p2 * t2 + sqrt(max(1.0 - p1 * p1 - p2 * p2, 0.0)) * vh;
    return normalize(vec3<f32>(a * nh.x, a * nh.y, max(nh.z, 1.0e-6)));
}

// Unpolarised Fresnel reflectance at a dielectric boundary; eta = index beyond / index on
// the side of the incoming direction, cos_i > 0.
fn fresnel_dielectric(cos_i: f32, eta: f32) -> f32 {
    let sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if (sin2_t >= 1.0) {
        return 1.0;
    }
    let cos_t = sqrt(1.0 - sin2_t);
    let rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    let rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    return 0.5 * (rs * rs + rp * rp);
}

fn schlick3(f0: vec3<f32>, c: f32) -> vec3<f32> {
    return f0 + (1.0 - f0) * pow5(clamp(1.0 - c, 0.0, 1.0));
}

// Fresnel of the opaque dielectric layer.
fn spec_fresnel(s: Surface, c: f32) -> f32 {
    let f0 = (s.ior - 1.0) / (s.ior + 1.0);
    return min(s.specular * (f0 * f0 + (1.0 - f0 * f0) * pow5(clamp(1.0 - c, 0.0, 1.0))), 1.0);
}

// Whether the surface reflects/transmits nothing (an opaque one-sided face seen from behind).
fn bsdf_black(s: Surface) -> bool {
    return !s.front && (s.flags & MAT_DOUBLE_SIDED) == 0u && s.transmission <= 0.0;
}

// Indices of refraction on the side of wo and beyond (solid dielectrics).
fn glass_etas(s: Surface) -> vec2<f32> {
    if ((s.flags & MAT_THIN) != 0u) {
        return vec2<f32>(1.0, s.ior);
    }
    return select(vec2<f32>(s.ior, 1.0), vec2<f32>(1.0, s.ior), s.front);
}

// Lobe weights (energy) and selection probabilities, x = metal, y = opaque, z = glass.
fn lobe_weights(s: Surface) -> vec3<f32> {
    let m = s.metallic;
    return vec3<f32>(m, (1.0 - m) * (1.0 - s.transmission), (1.0 - m) * s.transmission);
}

// Selection probabilities of the sampling strategies: x = GGX reflection, y = cosine, z = glass.
fn strategy_probs(s: Surface, cos_o: f32) -> vec3<f32> {
    let w = lobe_weights(s);
    let fe = spec_fresnel(s, cos_o);
    let q = vec3<f32>(w.x + w.y * fe, w.y * (1.0 - fe), w.z);
    let sum = q.x + q.y + q.z;
    if (sum <= 0.0) {
        return vec3<f32>(0.0, 1.0, 0.0);
    }
    return q / sum;
}

// The Fresnel reflectance at cos_o that decides between passing a MAT_PASS surface and
// reflecting off it (and weighs both).
fn pass_fresnel(s: Surface, cos_o: f32) -> f32 {
    let etas = glass_etas(s);
    return fresnel_dielectric(cos_o, etas.y / etas.x);
}

// f(wo, wi) |cos(n, wi)| in rgb and the sampling pdf (solid angle) of wi in w.
fn bsdf_eval(s: Surface, wo: vec3<f32>, wi: vec3<f32>) -> vec4<f32> {
    if (bsdf_black(s)) {
        return vec4<f32>(0.0);
    }
    let frame = onb(s.ns);
    let lo = to_local(frame, wo);
    let li = to_local(frame, wi);
    if (lo.z <= 1.0e-6) {
        return vec4<f32>(0.0);
    }
    let a = ggx_alpha(s.roughness);
    let a2 = a * a;
    let w = lobe_weights(s);
    let q = strategy_probs(s, lo.z);
    let etas = glass_etas(s);
    // Where light goes straight through (pass_through), the lobes given that it does not.
    let passes_light = (s.flags & MAT_PASS) != 0u;
    var fr_pass = 0.0;
    if (passes_light) {
        fr_pass = pass_fresnel(s, lo.z);
    }
    var f = vec3<f32>(0.0);
    var pdf = 0.0;
    let reflect_side = dot(wi, s.ng) > 0.0;
    if (reflect_side && li.z > 1.0e-6) {
        let h = normalize(lo + li);
        let oh = max(dot(lo, h), 1.0e-6);
        let d = ggx_d(a2, h.z);
        let spec = d * ggx_g2(a2, lo.z, li.z) / (4.0 * lo.z);
        let pdf_r = ggx_g1(a2, lo.z) * d / (4.0 * lo.z);
        f += w.x * schlick3(s.base, oh) * spec;
        let fd = spec_fresnel(s, oh);
        f += w.y * (fd * spec + (1.0 - fd) * s.base * INV_PI * li.z);
        pdf += q.x * pdf_r + q.y * li.z * INV_PI;
        if (w.z > 0.0) {
            var fr = fr_pass;
            if (!passes_light) {
                fr = fresnel_dielectric(oh, etas.y / etas.x);
            }
            f += w.z * fr * spec;
            pdf += q.z * fr * pdf_r;
        }
    } else if (!reflect_side && li.z < -1.0e-6 && w.z > 0.0 && !passes_light) {
        if ((s.flags & MAT_THIN) != 0u) {
            // Straight-through transmission: the mirrored reflection lobe.
            let lr = vec3<f32>(li.x, li.y, -li.z);
            let h = normalize(lo + lr);
            let oh = max(dot(lo, h), 1.0e-6);
            let d = ggx_d(a2, h.z);
            let fr = fresnel_dielectric(oh, etas.y / etas.x);
            f += w.z * (1.0 - fr) * s.base * d * ggx_g2(a2, lo.z, lr.z) / (4.0 * lo.z);
            pdf += q.z * (1.0 - fr) * ggx_g1(a2, lo.z) * d / (4.0 * lo.z);
        } else {
            var h = normalize(etas.x * lo + etas.y * li);
            if (h.z < 0.0) {
                h = -h;
            }
            let oh = dot(lo, h);
            let ih = dot(li, h);
            if (oh > 1.0e-6 && ih < -1.0e-6) {
                let fr = fresnel_dielectric(oh, etas.y / etas.x);
                let denom = etas.x * oh + etas.y * ih;
                let jac = etas.y * etas.y * abs(ih) / (denom * denom);
                let d = ggx_d(a2, h.z);
                f += w.z * (1.0 - fr) * s.base * d * ggx_g2(a2, lo.z, -li.z) * oh * jac / lo.z;
                pdf += q.z * (1.0 - fr) * ggx_g1(a2, lo.z) * oh * d / lo.z * jac;
            }
        }
    }
    if (passes_light) {
        pdf /= max(1.0 - q.z * (1.0 - fr_pass), 1.0e-12);
    }
    return vec4<f32>(f, pdf);
}

// Light going straight through a MAT_PASS surface towards -wo (a specular event, taken
// before the vertex scatters): the transmittance t (the glass lobe's share of what the
// Fresnel reflectance at wo lets through, tinted) and the probability q with which a path
// passes (the glass strategy's share of the same).
struct Pass {
    t: vec3<f32>,
    q: f32,
    ok: bool,
}

fn pass_through(s: Surface, wo: vec3<f32>) -> Pass {
    var out = Pass(vec3<f32>(0.0), 0.0, false);
    if ((s.flags & MAT_PASS) == 0u || bsdf_black(s)) {
        return out;
    }
    let lo = to_local(onb(s.ns), wo);
    if (lo.z <= 1.0e-6) {
        return out;
    }
    let w = lobe_weights(s);
    let q = strategy_probs(s, lo.z);
    let fr = pass_fresnel(s, lo.z);
    out.t = w.z * (1.0 - fr) * s.base;
    out.q = q.z * (1.0 - fr);
    out.ok = true;
    return out;
}

struct BsdfSample {
    wi: vec3<f32>,
    weight: vec3<f32>,   // f |cos| / pdf
    pdf: f32,
    ok: bool,
    transmitted: bool,   // wi left through the surface
}

fn bsdf_sample(s: Surface, wo: vec3<f32>, u: vec3<f32>) -> BsdfSample {
    var out = BsdfSample(vec3<f32>(0.0), vec3<f32>(0.0), 0.0, false, false);
    if (bsdf_black(s)) {
        return out;
    }
    let frame = onb(s.ns);
    let lo = to_local(frame, wo);
    if (lo.z <= 1.0e-6) {
        return out;
    }
    let a = ggx_alpha(s.roughness);
    let q = strategy_probs(s, lo.z);
    let etas = glass_etas(s);
    // Where the surface passes light, the strategies given that it does not: the glass
    // strategy only reflects.
    let passes_light = (s.flags & MAT_PASS) != 0u;
    var scatter = 1.0;
    if (passes_light) {
        scatter = 1.0 - q.z * (1.0 - pass_fresnel(s, lo.z));
    }
    let uzs = u.z * scatter;
    var li: vec3<f32>;
    if (uzs < q.x) {
        let h = sample_vndf(lo, a, u.xy);
        li = reflect(-lo, h);
    } else if (uzs < q.x + q.y) {
        let r = sqrt(u.x);
        let phi = TWO_PI * u.y;
        li = vec3<f32>(r * cos(phi), r * sin(phi), sqrt(max(1.0 - u.x, 0.0)));
    } else if (passes_light) {
        li = reflect(-lo, sample_vndf(lo, a, u.xy));
    } else {
        let uz = clamp((uzs - q.x - q.y) / max(q.z, 1.0e-12), 0.0, 1.0);
        let h = sample_vndf(lo, a, u.xy);
        let oh = dot(lo, h);
        let fr = fresnel_dielectric(max(oh, 1.0e-6), etas.y / etas.x);
        let lr = reflect(-lo, h);
        if (uz < fr) {
            li = lr;
        } else if ((s.flags & MAT_THIN) != 0u) {
            li = vec3<f32>(lr.x, lr.y, -lr.z);
        } else {
            li = refract(-lo, h, etas.x / etas.y);
            if (dot(li, li) == 0.0) {
                return out;
            }
        }
    }
    let wi = normalize(to_world(frame, li));
    let ev = bsdf_eval(s, wo, wi);
    if (!(ev.w > 0.0) || !finite3(ev.rgb)) {
        return out;
    }
    out.wi = wi;
    out.weight = ev.rgb / ev.w;
    out.pdf = ev.w;
    out.ok = true;
    out.transmitted = dot(wi, s.ng) < 0.0;
    return out;
}
