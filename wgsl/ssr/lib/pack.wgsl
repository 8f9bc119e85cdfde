// The grid of the input packing (ssr/pack_inputs, ssr/pack_mt): one invocation per pixel
// of the padded size Wp x Hp, reading the caller's W x H buffers with the edge replicated.

struct Params {
    width: u32,
    height: u32,
    padded_width: u32,
    padded_height: u32,
}

// Index in the caller's buffers of the pixel padded pixel (x, y) reads (needs the entry
// file's `p: Params`).
fn source_pixel(x: u32, y: u32) -> u32 {
    return min(y, p.height - 1u) * p.width + min(x, p.width - 1u);
}
