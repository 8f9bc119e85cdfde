// Path tracer library: textures (manual bilinear filtering with wrap modes over one RGBA8
// storage buffer), alpha cut-outs, and the shading point of a hit (interpolated attributes,
// normal mapping, the material's textured parameters).

// Texture header flags (texels[4 * tex + 3]).
const TEX_SRGB: u32 = 1u;
// Wrap modes, 2 bits each: s at bit 1, t at bit 3.
const WRAP_REPEAT: u32 = 0u;
const WRAP_CLAMP: u32 = 1u;
const WRAP_MIRROR: u32 = 2u;

// The remainder of `i` by `n > 0` in [0, n) (Rust's `rem_euclid`). `%` only ever sees
// non-negative operands: WGSL defines it for negative ones, but naga's GLSL output for the GL
// backend is `%`, which GLSL leaves undefined there (Mesa llvmpipe's GL returns the unsigned
// remainder of the bit pattern: -4000 % 894 gave 450, not -424), so repeat-wrapped lookups
// at negative texture coordinates fetched the wrong texels on GL.
fn rem_euclid(i: i32, n: i32) -> i32 {
    if (i >= 0) {
        return i % n;
    }
    // -(i + 1) does not overflow, even for i32's minimum.
    return n - 1 - (-(i + 1)) % n;
}

fn wrap_coord(i: i32, n: i32, mode: u32) -> i32 {
    if (mode == WRAP_CLAMP) {
        return clamp(i, 0, n - 1);
    }
    if (mode == WRAP_MIRROR) {
        let period = 2 * n;
        let m = rem_euclid(i, period);
        return select(m, period - 1 - m, m >= n);
    }
    return rem_euclid(i, n);
}

fn texel(offset: u32, w: i32, x: i32, y: i32, srgb: bool) -> vec4<f32> {
    let c = unpack4x8unorm(texels[offset + u32(y * w + x)]);
    if (srgb) {
        return vec4<f32>(srgb_to_linear(c.rgb), c.a);
    }
    return c;
}

// Bilinear lookup of texture `tex` at `uv` (glTF convention: (0, 0) is the top-left texel
// corner). Colour textures are decoded from sRGB per texel before filtering.
fn tex_sample(tex: u32, uv: vec2<f32>) -> vec4<f32> {
    let offset = texels[4u * tex];
    let w = i32(texels[4u * tex + 1u]);
    let h = i32(texels[4u * tex + 2u]);
    let flags = texels[4u * tex + 3u];
    let srgb = (flags & TEX_SRGB) != 0u;
    let ws = (flags >> 1u) & 3u;
    let wt = (flags >> 3u) & 3u;
    let uvs = select(uv, vec2<f32>(0.0), !(abs(uv) <= vec2<f32>(1.0e6)));
    let s = uvs * vec2<f32>(f32(w), f32(h)) - 0.5;
    let f = floor(s);
    let t = s - f;
    let x0 = wrap_coord(i32(f.x), w, ws);
    let x1 = wrap_coord(i32(f.x) + 1, w, ws);
    let y0 = wrap_coord(i32(f.y), h, wt);
    let y1 = wrap_coord(i32(f.y) + 1, h, wt);
    let a = texel(offset, w, x0, y0, srgb);
    let b = texel(offset, w, x1, y0, srgb);
    let c = texel(offset, w, x0, y1, srgb);
    let d = texel(offset, w, x1, y1, srgb);
    return mix(mix(a, b, t.x), mix(c, d, t.x), t.y);
}

fn tri_info(prim: u32) -> vec4<u32> {
    return bitcast<vec4<u32>>(tris[4u * prim + 3u]);
}

fn vert_uv(i: u32) -> vec2<f32> {
    return vec2<f32>(verts[2u * i].w, verts[2u * i + 1u].w);
}

fn interp_uv(info: vec4<u32>, u: f32, v: f32) -> vec2<f32> {
    return vert_uv(info.x) * (1.0 - u - v) + vert_uv(info.y) * u + vert_uv(info.z) * v;
}

// Alpha of the material of triangle `prim` at barycentrics (u, v) is at least its cutoff.
fn alpha_passes(prim: u32, u: f32, v: f32) -> bool {
    let info = tri_info(prim);
    let m = materials[info.w & TRI_MATERIAL_MASK];
    var a = m.base_color.a;
    if (m.textures.x != NO_TEX) {
        a *= tex_sample(m.textures.x, interp_uv(info, u, v)).a;
    }
    return a >= m.extra.x;
}

// Emitted radiance of material m at uv (front side only is the caller's business).
fn material_emission(m: Material, uv: vec2<f32>) -> vec3<f32> {
    var e = m.emissive.rgb;
    if (m.textures.w != NO_TEX && any(e > vec3<f32>(0.0))) {
        e *= tex_sample(m.textures.w, uv).rgb;
    }
    return e;
}

// A shading point.
struct Surface {
    p: vec3<f32>,
    ng: vec3<f32>,        // geometric normal, on the side of the incoming ray
    ns: vec3<f32>,        // shading normal (interpolated, normal-mapped), same side as ng
    front: bool,          // the ray hit the front (counter-clockwise) face
    prim: u32,
    mat: u32,
    flags: u32,           // Material flags
    base: vec3<f32>,      // textured base colour
    metallic: f32,
    roughness: f32,       // perceptual
    transmission: f32,
    ior: f32,
    specular: f32,
    emission: vec3<f32>,  // emitted radiance towards the ray origin (0 off the front face)
    attenuation: vec4<f32>,
    uv: vec2<f32>,
}

// The shading point of hit `h` of a ray with direction d.
fn surface_at(h: Hit, d: vec3<f32>) -> Surface {
    var s: Surface;
    let prim = h.prim;
    let info = tri_info(prim);
    let v0 = tris[4u * prim].xyz;
    let e1 = tris[4u * prim + 1u].xyz;
    let e2 = tris[4u * prim + 2u].xyz;
    let w0 = 1.0 - h.u - h.v;
    // v1 = v0 - e1, v2 = v0 + e2.
    s.p = v0 - e1 * h.u + e2 * h.v;
    // Counter-clockwise (glTF front) normal: cross(v1 - v0, v2 - v0) = -cross(e1, e2).
    let ng_ccw = normalize(-cross(e1, e2));
    s.front = dot(ng_ccw, d) < 0.0;
    s.prim = prim;
    s.mat = info.w & TRI_MATERIAL_MASK;
    let m = materials[s.mat];
    s.flags = bitcast<u32>(m.extra.w);

    let a0 = verts[2u * info.x];
    let a1 = verts[2u * info.y];
    let a2 = verts[2u * info.z];
    let b0 = verts[2u * info.x + 1u];
    let b1 = verts[2u * info.y + 1u];
    let b2 = verts[2u * info.z + 1u];
    let uv0 = vec2<f32>(a0.w, b0.w);
    let uv1 = vec2<f32>(a1.w, b1.w);
    let uv2 = vec2<f32>(a2.w, b2.w);
    s.uv = uv0 * w0 + uv1 * h.u + uv2 * h.v;
    var n = a0.xyz * w0 + a1.xyz * h.u + a2.xyz * h.v;
    if (!(dot(n, n) > 1.0e-12) || !finite3(n)) {
        n = ng_ccw;
    }
    n = normalize(n);
    // Shading normals that disagree with the winding are flipped onto its side.
    if (dot(n, ng_ccw) < 0.0) {
        n = -n;
    }

    var base = m.base_color.rgb;
    if (m.textures.x != NO_TEX) {
        base *= tex_sample(m.textures.x, s.uv).rgb;
    }
    var metallic = m.pbr.x;
    var roughness = m.pbr.y;
    if (m.textures.y != NO_TEX) {
        let mr = tex_sample(m.textures.y, s.uv);
        roughness *= mr.g;
        metallic *= mr.b;
    }
    if (m.textures.z != NO_TEX) {
        // Tangent frame: vertex tangents when present, else from the UV parameterisation.
        var t: vec3<f32>;
        var bsign = 1.0;
        if ((info.w & TRI_FLAG_HAS_TANGENT) != 0u) {
            t = b0.xyz * w0 + b1.xyz * h.u + b2.xyz * h.v;
            bsign = select(1.0, -1.0, (info.w & TRI_FLAG_TANGENT_NEG) != 0u);
        } else {
            let dp1 = -e1;
            let dp2 = e2;
            let duv1 = uv1 - uv0;
            let duv2 = uv2 - uv0;
            let det = duv1.x * duv2.y - duv1.y * duv2.x;
            let r = select(1.0 / det, 0.0, abs(det) < 1.0e-20);
            t = (dp1 * duv2.y - dp2 * duv1.y) * r;
            let bt = (dp2 * duv1.x - dp1 * duv2.x) * r;
            bsign = select(1.0, -1.0, dot(cross(n, t), bt) < 0.0);
        }
        t = t - n * dot(n, t);
        if (dot(t, t) > 1.0e-20 && finite3(t)) {
            t = normalize(t);
            let b = cross(n, t) * bsign;
            var tn = tex_sample(m.textures.z, s.uv).xyz * 2.0 - 1.0;
            tn = vec3<f32>(tn.xy * m.extra.y, tn.z);
            let mapped = t * tn.x + b * tn.y + n * tn.z;
            if (dot(mapped, mapped) > 1.0e-12 && dot(mapped, ng_ccw) > 0.0) {
                n = normalize(mapped);
            }
        }
    }
    s.ng = select(-ng_ccw, ng_ccw, s.front);
    s.ns = select(-n, n, s.front);
    s.base = base;
    s.metallic = clamp(metallic, 0.0, 1.0);
    s.roughness = clamp(roughness, 0.0, 1.0);
    s.transmission = clamp(m.pbr.z, 0.0, 1.0);
    s.ior = max(m.pbr.w, 1.0001);
    s.specular = m.extra.z;
    s.attenuation = m.attenuation;
    s.emission = vec3<f32>(0.0);
    if (s.front) {
        s.emission = material_emission(m, s.uv);
    }
    return s;
}
