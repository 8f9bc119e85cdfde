// The grid of the input packing (ssr/pack_inputs, ssr/pack_mt): one invocation per pixel
// of the padded size Wp x Hp, reading the caller's W x H buffers with the edge replicated.

struct Params {
    width: u32,
    height: u32,
    padded_width: u32,
    padded_height: u32,
}

// The functions below need the entry file's `p: Params`; count_sanitized also its
// `sanitized` counter. Invocation `gid` packs padded pixel gid.xy.

// Whether invocation `gid` lies beyond the padded size Wp x Hp.
fn outside_padded(gid: vec3<u32>) -> bool {
    return gid.x >= p.padded_width || gid.y >= p.padded_height;
}

// Index in the caller's buffers of the pixel padded pixel gid.xy reads.
fn source_pixel(gid: vec3<u32>) -> u32 {
    return min(gid.y, p.height - 1u) * p.width + min(gid.x, p.width - 1u);
}

// Index in the padded outputs of padded pixel gid.xy.
fn padded_pixel(gid: vec3<u32>) -> u32 {
    return gid.y * p.padded_width + gid.x;
}

// Adds `bad`, the values sanitised at padded pixel gid.xy, to `sanitized` when the pixel
// lies inside W x H (the padding replicates edge pixels, counted once there).
fn count_sanitized(gid: vec3<u32>, bad: u32) {
    if (gid.x < p.width && gid.y < p.height && bad > 0u) {
        atomicAdd(&sanitized[0], bad);
    }
}
