// Unidirectional path tracing with next-event estimation (emissive triangles and the
// environment) and multiple importance sampling (power heuristic).
//
// Modes (FrameParams.mode.x):
//   quarter:   one thread per 2x2 tile traces the pixel at the frame's tile offset, one
//              uniformly jittered sample; the other three pixels get colour 0, mask 0.
//   full:      one jittered sample in every pixel, mask 1.
//   reference: accum.y more jittered samples per pixel, averaged with the accum.x samples
//              already in color_mask (a plain mean: box filter).
// max_depth (mode.w) is the largest number of path segments: 1 = emitters seen directly,
// 2 = direct lighting, 3 = one indirect bounce, ... (Mitsuba's convention).
// shadow_roughness.xyz gets the NEE sample of the first hit: the light's radiance times its
// visibility (0 when occluded or when no light could be sampled).
// In frames with a background (accum.z > 0), sample_emission.xyz gets the samples' first-hit
// emission (the part of color_mask.xyz that is emission seen directly; 0 where not traced):
// the `emission` half of the directly seen emission (DESIGN.md section 3), and
// sample_emission.w the fraction of the samples whose camera ray escaped to the environment
// (hit nothing; 0 where not traced), whose radiance is then the environment seen directly
// (CPU twin: `first_hit` in src/render/cpu/integrator.rs).

@group(0) @binding(0) var<uniform> p: FrameParams;
// The scene at bindings 1-7 (trace/lib/scene.wgsl).
@group(0) @binding(8) var<storage, read_write> color_mask: array<vec4<f32>>;
@group(0) @binding(9) var<storage, read_write> shadow_roughness: array<vec4<f32>>;
// counters[0]: rays traced (camera, bounce and shadow rays), summed over invocations.
@group(0) @binding(10) var<storage, read_write> counters: array<atomic<u32>, 4>;
@group(0) @binding(11) var<storage, read_write> sample_emission: array<vec4<f32>>;

struct PathResult {
    radiance: vec3<f32>,
    shadow: vec3<f32>,
    // The emission of the surface the camera ray meets first (part of radiance).
    emission: vec3<f32>,
    // 1 where the camera ray hits nothing (its radiance is the environment's), else 0.
    escaped: f32,
}

fn rand3(state: ptr<function, u32>) -> vec3<f32> {
    let a = rand(state);
    let b = rand(state);
    let c = rand(state);
    return vec3<f32>(a, b, c);
}

// Most surfaces passing light straight through that one path segment or shadow ray
// crosses; beyond, the path ends and the shadow ray is blocked.
const MAX_PASSES: u32 = 16u;

// Transmittance (rgb) of the segment from o along unit d up to dist, and (w) the
// probability that a path crosses it the same way: 0 where something opaque blocks it;
// through MAT_PASS surfaces, the products of their transmittances and pass probabilities.
fn transmittance(o: vec3<f32>, d: vec3<f32>, dist: f32, skip: u32) -> vec4<f32> {
    if (occluded(o, d, dist, skip)) {
        return vec4<f32>(0.0);
    }
    if (!has_pass()) {
        return vec4<f32>(1.0);
    }
    var tr = vec4<f32>(1.0);
    var org = o;
    var left = dist;
    var skip_prim = skip;
    for (var k = 0u; k < MAX_PASSES; k++) {
        let hit = traverse(org, d, left, false, skip_prim);
        if (hit.prim == NO_HIT) {
            return tr;
        }
        let s = surface_at(hit, d);
        let pt = pass_through(s, -d);
        if (!pt.ok) {
            return vec4<f32>(0.0);
        }
        tr *= vec4<f32>(pt.t, pt.q);
        org = offset_ray(s.p, -s.ng);
        left -= hit.t;
        skip_prim = hit.prim;
    }
    return vec4<f32>(0.0);
}

fn trace_path(o: vec3<f32>, d0: vec3<f32>, rng: ptr<function, u32>) -> PathResult {
    var res = PathResult(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0), 0.0);
    var ro = o;
    var rd = d0;
    var skip = NO_HIT;
    var thr = vec3<f32>(1.0);
    var prev_pdf = 0.0;
    // The previous path vertex (the environment's light pdf depends on it through portals).
    var prev_p = o;
    // Participating medium of the solid dielectric the path is inside (Beer-Lambert).
    var sigma = vec3<f32>(0.0);
    let max_depth = p.mode.w;
    let lights_on = has_lights();
    // Distance from the previous vertex along rd (it grows where the path passes light
    // straight through a surface), and how many such surfaces the path has passed.
    var seg = 0.0;
    var passes = 0u;
    var depth = 1u;
    loop {
        if (depth > max_depth) {
            break;
        }
        let hit = traverse(ro, rd, BIG, false, skip);
        if (hit.prim == NO_HIT) {
            if (depth == 1u && passes == 0u) {
                res.escaped = 1.0;
            }
            if (env_present()) {
                var w = 1.0;
                if (depth > 1u) {
                    w = mis_power(prev_pdf, env_select_prob() * env_light_pdf(prev_p, rd));
                }
                res.radiance += thr * env_radiance(rd) * w;
            }
            break;
        }
        if (any(sigma > vec3<f32>(0.0))) {
            thr *= exp(-sigma * hit.t);
        }
        seg += hit.t;
        let s = surface_at(hit, rd);
        if (any(s.emission > vec3<f32>(0.0))) {
            var w = 1.0;
            if (depth > 1u) {
                w = mis_power(prev_pdf, tri_light_pdf(hit.prim, seg, dot(s.ng, -rd)));
            }
            res.radiance += thr * s.emission * w;
        }
        if (depth == 1u && passes == 0u) {
            res.emission = s.emission;
        }
        let wo = -rd;
        let pt = pass_through(s, wo);
        if (pt.ok) {
            // Straight through (a specular event, not a vertex: depth, the previous vertex
            // and its pdf stay, times the probability of passing), or scatter here.
            if (rand(rng) < pt.q) {
                passes++;
                if (passes > MAX_PASSES) {
                    break;
                }
                thr *= pt.t / pt.q;
                prev_pdf *= pt.q;
                ro = offset_ray(s.p, -s.ng);
                skip = hit.prim;
                continue;
            }
            thr /= 1.0 - pt.q;
        }
        if (depth >= max_depth) {
            break;
        }
        // Next-event estimation.
        let ul = rand3(rng);
        if (lights_on) {
            let ls = sample_light(s.p, ul);
            if (ls.ok) {
                let ev = bsdf_eval(s, wo, ls.wi);
                if (any(ev.rgb > vec3<f32>(0.0)) || depth == 1u) {
                    let side = select(-s.ng, s.ng, dot(ls.wi, s.ng) > 0.0);
                    let org = offset_ray(s.p, side);
                    let tmax = select(ls.dist * 0.9999, BIG, ls.dist >= BIG);
                    let tr = transmittance(org, ls.wi, tmax, s.prim);
                    if (any(tr.rgb > vec3<f32>(0.0))) {
                        // The BSDF route to the same light passes the same surfaces with
                        // probability tr.w.
                        let w = mis_power(ls.pdf, ev.w * tr.w);
                        res.radiance += thr * ev.rgb * tr.rgb * ls.le * (w / ls.pdf);
                        if (depth == 1u) {
                            res.shadow = tr.rgb * ls.le;
                        }
                    }
                }
            }
        }
        // Continue the path by sampling the BSDF.
        let bs = bsdf_sample(s, wo, rand3(rng));
        if (!bs.ok) {
            break;
        }
        thr *= bs.weight;
        prev_pdf = bs.pdf;
        prev_p = s.p;
        seg = 0.0;
        if (bs.transmitted && s.transmission > 0.0 && (s.flags & MAT_THIN) == 0u) {
            if (s.front && s.attenuation.w > 0.0) {
                sigma = -log(clamp(s.attenuation.rgb, vec3<f32>(1.0e-6), vec3<f32>(1.0))) / s.attenuation.w;
            } else {
                sigma = vec3<f32>(0.0);
            }
        }
        ro = offset_ray(s.p, select(s.ng, -s.ng, bs.transmitted));
        rd = bs.wi;
        skip = hit.prim;
        if (depth >= 3u) {
            let q = min(max3(thr), 0.95);
            if (rand(rng) >= q) {
                break;
            }
            thr /= q;
        }
        if (!finite3(thr)) {
            break;
        }
        depth++;
    }
    if (!finite3(res.radiance)) {
        res.radiance = vec3<f32>(0.0);
    }
    return res;
}

// Mean of `count` jittered samples in pixel (x, y), numbered from `first`.
fn pixel_samples(x: u32, y: u32, first: u32, count: u32) -> PathResult {
    let w = p.size.x;
    let size = vec2<f32>(f32(w), f32(p.size.y));
    var sum = PathResult(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0), 0.0);
    for (var k = 0u; k < count; k++) {
        var rng = rng_seed(y * w + x, p.size.z, first + k, p.size.w);
        let jitter = rand2(&rng);
        let d = camera_dir(p.cam, vec2<f32>(f32(x), f32(y)) + jitter, size);
        let r = trace_path(p.cam.pos.xyz, d, &rng);
        sum.radiance += r.radiance;
        sum.shadow += r.shadow;
        sum.emission += r.emission;
        sum.escaped += r.escaped;
    }
    let inv = 1.0 / f32(max(count, 1u));
    return PathResult(sum.radiance * inv, sum.shadow * inv, sum.emission * inv, sum.escaped * inv);
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let w = p.size.x;
    let h = p.size.y;
    let quarter = p.mode.x == MODE_QUARTER;
    var x = gid.x;
    var y = gid.y;
    if (quarter) {
        if (gid.x >= (w + 1u) / 2u || gid.y >= (h + 1u) / 2u) {
            return;
        }
        // Clear the tile's untraced pixels; trace the one at the frame's offset.
        for (var k = 0u; k < 4u; k++) {
            let cx = 2u * gid.x + (k & 1u);
            let cy = 2u * gid.y + (k >> 1u);
            if (cx < w && cy < h && !((k & 1u) == p.mode.y && (k >> 1u) == p.mode.z)) {
                let ci = cy * w + cx;
                color_mask[ci] = vec4<f32>(0.0);
                shadow_roughness[ci] = vec4<f32>(0.0, 0.0, 0.0, shadow_roughness[ci].w);
                if (p.accum.z > 0u) {
                    sample_emission[ci] = vec4<f32>(0.0);
                }
            }
        }
        x = 2u * gid.x + p.mode.y;
        y = 2u * gid.y + p.mode.z;
    }
    if (x >= w || y >= h) {
        return;
    }
    let i = y * w + x;
    let done = select(p.accum.x, 0u, quarter);
    let count = select(max(p.accum.y, 1u), 1u, quarter);
    let r = pixel_samples(x, y, done, count);
    var c = r.radiance;
    var sh = r.shadow;
    var e = vec4<f32>(r.emission, r.escaped);
    if (done > 0u) {
        let a = f32(done) / f32(done + count);
        c = mix(c, color_mask[i].rgb, a);
        sh = mix(sh, shadow_roughness[i].xyz, a);
        if (p.accum.z > 0u) {
            e = mix(e, sample_emission[i], a);
        }
    }
    color_mask[i] = vec4<f32>(c, 1.0);
    shadow_roughness[i] = vec4<f32>(sh, shadow_roughness[i].w);
    if (p.accum.z > 0u) {
        sample_emission[i] = e;
    }
    atomicAdd(&counters[0], rays_traced);
}
