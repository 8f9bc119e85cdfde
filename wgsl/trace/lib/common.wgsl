// Path tracer library: shared constants, scene data layouts, random numbers and helpers.
// The scene's storage buffers, declared once in trace/lib/scene.wgsl (bindings 1-7, the
// only library with bindings) for every tracer kernel (see src/render/gpu_scene.rs):
//   bvh_nodes: array<vec4<u32>>  CWBVH nodes, 5 x vec4<u32> each (obvhs CwBvhNode, 80 bytes)
//   tris:      array<vec4<f32>>  4 x vec4 per triangle in BVH leaf order:
//                                v0 (w unused), e1 = v0 - v1, e2 = v2 - v0, info (bitcast u32:
//                                vertex indices i0, i1, i2, material | TRI_FLAG_*)
//   verts:     array<vec4<f32>>  2 x vec4 per vertex: (normal.xyz, uv.x), (tangent.xyz, uv.y)
//   materials: array<Material>
//   texels:    array<u32>        4 u32 header per texture (offset, width, height, flags), then
//                                RGBA8 texels packed as u32 (unpack4x8unorm)
//   lights:    array<vec4<f32>>  emissive triangles for next-event estimation (lights.wgsl)
//   env:       array<vec4<f32>>  environment map and its sampling CDFs (lights.wgsl)

const PI: f32 = 3.14159265358979;
const TWO_PI: f32 = 6.28318530717959;
const INV_PI: f32 = 0.318309886183791;
const NO_HIT: u32 = 0xffffffffu;
const NO_TEX: u32 = 0xffffffffu;
const BIG: f32 = 3.0e38;

// Rays traced by this invocation (traverse() counts them; kernels may report the total).
var<private> rays_traced: u32 = 0u;

// tris[4 * prim + 3].w (as u32): material index and flags.
const TRI_MATERIAL_MASK: u32 = 0x00ffffffu;
const TRI_FLAG_ALPHA: u32 = 0x80000000u;        // the material is alpha-tested (MASK)
const TRI_FLAG_TANGENT_NEG: u32 = 0x40000000u;  // bitangent sign of the vertex tangents is -1
const TRI_FLAG_HAS_TANGENT: u32 = 0x20000000u;  // vertex tangents are present
const TRI_FLAG_PASS: u32 = 0x10000000u;         // the material is MAT_PASS

// Material.flags bits.
const MAT_DOUBLE_SIDED: u32 = 1u;
const MAT_THIN: u32 = 2u;        // thin-walled transmission (no KHR_materials_volume)
const MAT_ALPHA_MASK: u32 = 4u;
const MAT_PASS: u32 = 8u;        // smooth thin transmission: light goes straight through (bsdf.wgsl)

// Mirrors `GpuMaterial` in src/render/gpu_scene.rs (96 bytes, checked by a test).
struct Material {
    base_color: vec4<f32>,   // rgb factor, alpha factor
    emissive: vec4<f32>,     // rgb = factor x strength; w = luminance used for light selection
    pbr: vec4<f32>,          // metallic, perceptual roughness, transmission, ior
    extra: vec4<f32>,        // alpha cutoff, normal scale, specular factor, flags (bitcast u32)
    attenuation: vec4<f32>,  // volume attenuation colour rgb, attenuation distance (0: none)
    textures: vec4<u32>,     // base colour, metallic-roughness, normal, emissive (NO_TEX: none)
}

// Mirrors `GpuCamera`: a pinhole camera. Pixel (x, y) has its centre at (x + 0.5, y + 0.5),
// y grows downwards.
struct Camera {
    pos: vec4<f32>,     // xyz, w = tan(yfov / 2)
    right: vec4<f32>,   // xyz, w = aspect (width / height)
    up: vec4<f32>,      // xyz, w unused
    fwd: vec4<f32>,     // xyz, w unused
}

// ---- random numbers: PCG (O'Neill) state advance + output permutation ----

fn pcg_hash(v: u32) -> u32 {
    let s = v * 747796405u + 2891336453u;
    let w = ((s >> ((s >> 28u) + 4u)) ^ s) * 277803737u;
    return (w >> 22u) ^ w;
}

fn rng_seed(pixel: u32, frame: u32, sample: u32, seed: u32) -> u32 {
    return pcg_hash(pixel ^ pcg_hash(frame ^ pcg_hash(sample ^ pcg_hash(seed))));
}

fn rand(state: ptr<function, u32>) -> f32 {
    *state = *state * 747796405u + 2891336453u;
    let s = *state;
    let w = ((s >> ((s >> 28u) + 4u)) ^ s) * 277803737u;
    return f32(((w >> 22u) ^ w) >> 8u) * (1.0 / 16777216.0);
}

fn rand2(state: ptr<function, u32>) -> vec2<f32> {
    let a = rand(state);
    let b = rand(state);
    return vec2<f32>(a, b);
}

// ---- helpers ----

fn luminance(c: vec3<f32>) -> f32 {
    return dot(c, vec3<f32>(0.2126, 0.7152, 0.0722));
}

fn max3(v: vec3<f32>) -> f32 {
    return max(v.x, max(v.y, v.z));
}

fn pow5(x: f32) -> f32 {
    let x2 = x * x;
    return x2 * x2 * x;
}

// Orthonormal basis around unit n (Duff et al. 2017): columns t, b, n.
fn onb(n: vec3<f32>) -> mat3x3<f32> {
    let s = select(-1.0, 1.0, n.z >= 0.0);
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    let t = vec3<f32>(1.0 + s * n.x * n.x * a, s * b, -s * n.x);
    let bt = vec3<f32>(b, s + n.y * n.y * a, -n.y);
    return mat3x3<f32>(t, bt, n);
}

fn to_local(f: mat3x3<f32>, v: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(v, f[0]), dot(v, f[1]), dot(v, f[2]));
}

fn to_world(f: mat3x3<f32>, v: vec3<f32>) -> vec3<f32> {
    return f[0] * v.x + f[1] * v.y + f[2] * v.z;
}

// Moves a ray origin off a surface along the (geometric) normal n, which points to the side
// the ray leaves from (Waechter & Binder, Ray Tracing Gems ch. 6): integer ulp offsets far
// from the origin, a small float offset near it.
fn offset_ray(p: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    let of_i = vec3<i32>(256.0 * n);
    let pi = bitcast<vec3<f32>>(bitcast<vec3<i32>>(p) + select(of_i, -of_i, p < vec3<f32>(0.0)));
    let pf = p + (1.0 / 32.0 / 65536.0) * n;
    return select(pi, pf, abs(p) < vec3<f32>(1.0 / 32.0));
}

fn srgb_to_linear(c: vec3<f32>) -> vec3<f32> {
    let lo = c / 12.92;
    let hi = pow((c + 0.055) / 1.055, vec3<f32>(2.4));
    return select(hi, lo, c <= vec3<f32>(0.04045));
}

fn finite3(v: vec3<f32>) -> bool {
    return all(abs(v) <= vec3<f32>(BIG));
}
