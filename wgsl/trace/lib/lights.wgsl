// Path tracer library: next-event estimation on emissive triangles and the environment.
//
// lights[0] = (count bits, total selection power, probability of choosing the environment,
//     portal count bits | LIGHTS_HAVE_PASS)
// lights[1 + k] = (BVH-order triangle bits, cdf (inclusive), pmf, area): emissive triangles,
//     chosen in proportion to power = Material.emissive.w (luminance) x area.
// lights[1 + count + 3 k ..] = the environment's portals (render::scene::Portal), picked by
//     area: (corner xyz, cdf (inclusive)), (edge u xyz, total area), (edge v xyz, probability
//     of sampling a portal rather than the map). Seen from the side u x v points to.
// env[0] = (width bits, height bits, sum of the sampling weights, present bits)
// env[1] = (weight floor, 0, 0, 0)
// env[2..5) = rows of world -> map rotation (inverse of scene.json's to_world); env[5..8) = map -> world
// env[8 + j] = (marginal cdf of row j (inclusive), 0, 0, 0), j < height
// env[8 + height + j * width + i] = (radiance rgb (scaled), conditional cdf in row j (inclusive))
// Lat-long mapping (Mitsuba): d = inverse(to_world) * dir; u = frac(atan2(d.x, -d.z) / 2pi);
// v = acos(d.y) / pi; (0, 0) is the top-left pixel. Pixel weights are
// (luminance + floor) x sin(theta at the row centre); lookups are nearest-texel.

const ENV_HDR: u32 = 8u;

fn light_count() -> u32 {
    return bitcast<u32>(lights[0].x);
}

fn env_select_prob() -> f32 {
    return lights[0].z;
}

fn env_present() -> bool {
    return bitcast<u32>(env[0].w) != 0u;
}

fn mis_power(a: f32, b: f32) -> f32 {
    let a2 = a * a;
    let b2 = b * b;
    if (a2 + b2 <= 0.0) {
        return 0.0;
    }
    return a2 / (a2 + b2);
}

fn env_local(d: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(env[2].xyz, d), dot(env[3].xyz, d), dot(env[4].xyz, d));
}

fn env_pixel(d: vec3<f32>) -> vec2<u32> {
    let w = bitcast<u32>(env[0].x);
    let h = bitcast<u32>(env[0].y);
    let l = env_local(d);
    let u = fract(atan2(l.x, -l.z) / TWO_PI);
    let v = acos(clamp(l.y, -1.0, 1.0)) / PI;
    return vec2<u32>(min(u32(u * f32(w)), w - 1u), min(u32(v * f32(h)), h - 1u));
}

fn env_radiance(d: vec3<f32>) -> vec3<f32> {
    if (!env_present()) {
        return vec3<f32>(0.0);
    }
    let w = bitcast<u32>(env[0].x);
    let h = bitcast<u32>(env[0].y);
    let px = env_pixel(d);
    return env[ENV_HDR + h + px.y * w + px.x].rgb;
}

// Solid-angle pdf of env_sample for pixel px and a direction with sin(theta) = sin_t.
fn env_pixel_pdf(px: vec2<u32>, sin_t: f32) -> f32 {
    let w = bitcast<u32>(env[0].x);
    let h = bitcast<u32>(env[0].y);
    let rgb = env[ENV_HDR + h + px.y * w + px.x].rgb;
    let row_sin = sin(PI * (f32(px.y) + 0.5) / f32(h));
    let weight = (luminance(rgb) + env[1].x) * row_sin;
    let pmf = weight / env[0].z;
    return pmf * f32(w) * f32(h) / (2.0 * PI * PI * max(sin_t, 1.0e-6));
}

fn env_pdf(d: vec3<f32>) -> f32 {
    if (!env_present()) {
        return 0.0;
    }
    let l = env_local(d);
    let sin_t = sqrt(max(1.0 - l.y * l.y, 0.0));
    return env_pixel_pdf(env_pixel(d), sin_t);
}

// Binary searches: the first row (column) whose inclusive CDF exceeds u.
fn search_marginal(u: f32, h: u32) -> u32 {
    var lo = 0u;
    var hi = h - 1u;
    while (lo < hi) {
        let mid = (lo + hi) / 2u;
        if (env[ENV_HDR + mid].x > u) {
            hi = mid;
        } else {
            lo = mid + 1u;
        }
    }
    return lo;
}

fn search_row(u: f32, row: u32, w: u32, h: u32) -> u32 {
    let base = ENV_HDR + h + row * w;
    var lo = 0u;
    var hi = w - 1u;
    while (lo < hi) {
        let mid = (lo + hi) / 2u;
        if (env[base + mid].w > u) {
            hi = mid;
        } else {
            lo = mid + 1u;
        }
    }
    return lo;
}

// Bit of lights[0].w (over the portal count) set when some triangle is MAT_PASS.
const LIGHTS_HAVE_PASS: u32 = 0x80000000u;

fn portal_count() -> u32 {
    return bitcast<u32>(lights[0].w) & ~LIGHTS_HAVE_PASS;
}

fn has_pass() -> bool {
    return (bitcast<u32>(lights[0].w) & LIGHTS_HAVE_PASS) != 0u;
}

fn portal_base() -> u32 {
    return 1u + light_count();
}

// Solid-angle pdf with which portal_sample from p picks direction d: the sum over the
// portals that the ray p + t d (t > 0) leaves through.
fn portal_pdf(p: vec3<f32>, d: vec3<f32>) -> f32 {
    var pdf = 0.0;
    for (var k = 0u; k < portal_count(); k++) {
        let b = portal_base() + 3u * k;
        let c = lights[b].xyz;
        let eu = lights[b + 1u].xyz;
        let ev = lights[b + 2u].xyz;
        let nn = cross(eu, ev);
        let dn = dot(d, nn);
        if (!(dn < 0.0)) {
            continue;
        }
        let t = dot(c - p, nn) / dn;
        if (!(t > 0.0)) {
            continue;
        }
        let r = p + t * d - c;
        let inv = 1.0 / dot(nn, nn);
        let s = dot(cross(r, ev), nn) * inv;
        let w = dot(cross(eu, r), nn) * inv;
        if (s >= 0.0 && s <= 1.0 && w >= 0.0 && w <= 1.0) {
            // Area density 1 / (total area), over |cos| = -dn / |nn| at distance t.
            pdf += t * t * length(nn) / (-dn * lights[b + 1u].w);
        }
    }
    return pdf;
}

// Solid-angle pdf of the environment's light samples from p (the environment's selection
// probability not included): the map's pdf, mixed with the portals' when there are any.
fn env_light_pdf(p: vec3<f32>, d: vec3<f32>) -> f32 {
    if (portal_count() == 0u) {
        return env_pdf(d);
    }
    let pp = lights[portal_base() + 2u].w;
    return (1.0 - pp) * env_pdf(d) + pp * portal_pdf(p, d);
}

struct LightSample {
    wi: vec3<f32>,
    dist: f32,          // distance to the light point (BIG for the environment)
    le: vec3<f32>,      // emitted radiance towards the shading point
    pdf: f32,           // solid angle, light choice included
    ok: bool,
}

fn env_sample(u: vec2<f32>) -> LightSample {
    var out = LightSample(vec3<f32>(0.0), BIG, vec3<f32>(0.0), 0.0, false);
    let w = bitcast<u32>(env[0].x);
    let h = bitcast<u32>(env[0].y);
    let j = search_marginal(u.y, h);
    let c0 = select(0.0, env[ENV_HDR + j - 1u].x, j > 0u);
    let c1 = env[ENV_HDR + j].x;
    let fv = clamp((u.y - c0) / max(c1 - c0, 1.0e-12), 0.0, 0.99999);
    let i = search_row(u.x, j, w, h);
    let base = ENV_HDR + h + j * w;
    let r0 = select(0.0, env[base + i - 1u].w, i > 0u);
    let r1 = env[base + i].w;
    let fu = clamp((u.x - r0) / max(r1 - r0, 1.0e-12), 0.0, 0.99999);
    let uu = (f32(i) + fu) / f32(w);
    let vv = (f32(j) + fv) / f32(h);
    let theta = PI * vv;
    let phi = TWO_PI * uu;
    let sin_t = sin(theta);
    let l = vec3<f32>(sin_t * sin(phi), cos(theta), -sin_t * cos(phi));
    let d = normalize(vec3<f32>(dot(env[5].xyz, l), dot(env[6].xyz, l), dot(env[7].xyz, l)));
    out.wi = d;
    out.le = env[base + i].rgb;
    out.pdf = env_pixel_pdf(vec2<u32>(i, j), sin_t);
    out.ok = out.pdf > 0.0;
    return out;
}

// A direction from p through a point of a portal (u.z picks the portal by area, u.xy the
// point); pdf not set. Fails where p is not on the portal's inner side.
fn portal_sample(p: vec3<f32>, u: vec3<f32>) -> LightSample {
    var out = LightSample(vec3<f32>(0.0), BIG, vec3<f32>(0.0), 0.0, false);
    let n = portal_count();
    var k = 0u;
    while (k + 1u < n && lights[portal_base() + 3u * k].w <= u.z) {
        k++;
    }
    let b = portal_base() + 3u * k;
    let eu = lights[b + 1u].xyz;
    let ev = lights[b + 2u].xyz;
    let q = lights[b].xyz + u.x * eu + u.y * ev;
    var wi = q - p;
    let dist = length(wi);
    if (!(dist > 0.0)) {
        return out;
    }
    wi /= dist;
    if (!(dot(wi, cross(eu, ev)) < 0.0)) {
        return out;
    }
    out.wi = wi;
    out.le = env_radiance(wi);
    out.ok = true;
    return out;
}

// Solid-angle pdf with which sample_light picks the point on emissive triangle `prim` seen
// at distance dist under cos_l (cosine at the light).
fn tri_light_pdf(prim: u32, dist: f32, cos_l: f32) -> f32 {
    let total = lights[0].y;
    if (light_count() == 0u || total <= 0.0 || cos_l <= 0.0) {
        return 0.0;
    }
    let m = materials[tri_info(prim).w & TRI_MATERIAL_MASK];
    // pmf = power / total = lum x area / total; the area density 1/area cancels it.
    return (1.0 - env_select_prob()) * m.emissive.w * dist * dist / (total * cos_l);
}

fn sample_tri_light(p: vec3<f32>, u: vec3<f32>) -> LightSample {
    var out = LightSample(vec3<f32>(0.0), BIG, vec3<f32>(0.0), 0.0, false);
    let n = light_count();
    var lo = 0u;
    var hi = n - 1u;
    while (lo < hi) {
        let mid = (lo + hi) / 2u;
        if (lights[1u + mid].y > u.z) {
            hi = mid;
        } else {
            lo = mid + 1u;
        }
    }
    let entry = lights[1u + lo];
    let prim = bitcast<u32>(entry.x);
    let pmf = entry.z;
    let area = entry.w;
    let info = tri_info(prim);
    let v0 = tris[4u * prim].xyz;
    let e1 = tris[4u * prim + 1u].xyz;
    let e2 = tris[4u * prim + 2u].xyz;
    let su = sqrt(u.x);
    let bu = su * (1.0 - u.y);
    let bv = su * u.y;
    let q = v0 - e1 * bu + e2 * bv;
    let ng = normalize(-cross(e1, e2));
    var wi = q - p;
    let dist = length(wi);
    if (!(dist > 0.0) || !(area > 0.0)) {
        return out;
    }
    wi /= dist;
    let cos_l = dot(ng, -wi);
    if (cos_l <= 1.0e-6) {
        return out;
    }
    let m = materials[info.w & TRI_MATERIAL_MASK];
    out.wi = wi;
    out.dist = dist;
    out.le = material_emission(m, interp_uv(info, bu, bv));
    out.pdf = (1.0 - env_select_prob()) * pmf * dist * dist / (area * cos_l);
    out.ok = out.pdf > 0.0;
    return out;
}

// One light sample from point p: the environment with probability env_select_prob(), else
// an emissive triangle by power.
fn sample_light(p: vec3<f32>, u: vec3<f32>) -> LightSample {
    let pe = env_select_prob();
    if (u.z < pe) {
        if (portal_count() == 0u) {
            var s = env_sample(u.xy);
            s.pdf *= pe;
            return s;
        }
        // A portal or the map (u.z rescaled picks which, then the portal), weighed by
        // the mixture's pdf.
        let pp = lights[portal_base() + 2u].w;
        let ue = u.z / pe;
        var s: LightSample;
        var map_pdf: f32;
        if (ue < pp) {
            s = portal_sample(p, vec3<f32>(u.xy, ue / pp));
            map_pdf = env_pdf(s.wi);
        } else {
            s = env_sample(u.xy);
            map_pdf = s.pdf;
        }
        s.pdf = pe * ((1.0 - pp) * map_pdf + pp * portal_pdf(p, s.wi));
        s.ok = s.ok && s.pdf > 0.0;
        return s;
    }
    if (light_count() == 0u) {
        return LightSample(vec3<f32>(0.0), BIG, vec3<f32>(0.0), 0.0, false);
    }
    let uz = clamp((u.z - pe) / max(1.0 - pe, 1.0e-12), 0.0, 0.99999994);
    return sample_tri_light(p, vec3<f32>(u.xy, uz));
}

fn has_lights() -> bool {
    return light_count() > 0u || env_select_prob() > 0.0;
}
