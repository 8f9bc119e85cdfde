// One invocation per pixel of a row-major width x height image (8x8 workgroups over
// x, y): the pixel an invocation owns.

// What `pixel_index` returns for an invocation outside the image.
const OUTSIDE: u32 = 0xffffffffu;

// Row-major index of the invocation's pixel, or OUTSIDE (the invocation then returns).
fn pixel_index(gid: vec3<u32>, width: u32, height: u32) -> u32 {
    if (gid.x >= width || gid.y >= height) {
        return OUTSIDE;
    }
    return gid.y * width + gid.x;
}
