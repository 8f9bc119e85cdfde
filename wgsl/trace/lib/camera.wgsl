// Path tracer library: the pinhole camera and the per-frame parameters of the image kernels.

// Mirrors `FrameParams` in src/render/tracer.rs (192 bytes, checked by a test).
struct FrameParams {
    cam: Camera,
    prev: Camera,          // camera of the previous frame (motion vectors)
    size: vec4<u32>,       // width, height, frame index, seed
    mode: vec4<u32>,       // mode (0 quarter, 1 full, 2 reference), tile dx, tile dy, max_depth
    accum: vec4<u32>,      // samples accumulated so far, samples in this pass, background lookups per axis, 0
    misc: vec4<f32>,       // scene far distance (depth normalisation), 0, 0, 0
}

const MODE_QUARTER: u32 = 0u;
const MODE_FULL: u32 = 1u;
const MODE_REFERENCE: u32 = 2u;

// Whether invocation `gid` of an image kernel lies outside the frame (size.xy: width, height).
fn outside_frame(gid: vec3<u32>, size: vec4<u32>) -> bool {
    return gid.x >= size.x || gid.y >= size.y;
}

// Unit direction through continuous pixel position px of a width x height image.
fn camera_dir(c: Camera, px: vec2<f32>, size: vec2<f32>) -> vec3<f32> {
    let ndc = vec2<f32>(2.0 * px.x / size.x - 1.0, 1.0 - 2.0 * px.y / size.y);
    let x = ndc.x * c.pos.w * c.right.w;
    let y = ndc.y * c.pos.w;
    return normalize(c.fwd.xyz + x * c.right.xyz + y * c.up.xyz);
}

// Direction of stratified camera ray (i, j) of the n x n rays through pixel `pix` of a
// width x height image (the background's footprint).
fn footprint_dir(c: Camera, pix: vec2<u32>, i: u32, j: u32, n: u32, size: vec2<f32>) -> vec3<f32> {
    let px = vec2<f32>(
        f32(pix.x) + (f32(i) + 0.5) / f32(n),
        f32(pix.y) + (f32(j) + 0.5) / f32(n),
    );
    return camera_dir(c, px, size);
}

// Continuous pixel position of world point p (or of direction p at infinity when is_dir);
// z = 1 when in front of the camera, 0 behind it.
fn camera_project(c: Camera, p: vec3<f32>, is_dir: bool, size: vec2<f32>) -> vec3<f32> {
    let v = select(p - c.pos.xyz, p, is_dir);
    let z = dot(v, c.fwd.xyz);
    if (!(z > 1.0e-12)) {
        return vec3<f32>(0.0, 0.0, 0.0);
    }
    let x = dot(v, c.right.xyz) / (z * c.pos.w * c.right.w);
    let y = dot(v, c.up.xyz) / (z * c.pos.w);
    return vec3<f32>((x + 1.0) * 0.5 * size.x, (1.0 - y) * 0.5 * size.y, 1.0);
}
