// Writes the first 3 channels of a padded Wp x Hp tensor into the W x H output texture
// (rgba32float, alpha = 1), cropping the padding.
// With template flag BACKGROUND (the caller gave the optional background buffer, DESIGN §3):
// a pixel's radiance is the directly seen environment over the part of its footprint that
// escapes (the background, xyz, premultiplied by that part) plus the rest's radiance, so the
// output is background + (1 - coverage) * reconstruction: the background alone where the
// coverage (w) is 1, the network's reconstruction alone where it is 0. Both are sanitised
// (background as colour, ssr/lib/sanitize; coverage into [0, 1], non-finite 0), values
// changed counted in `sanitized`. The network's own output (its history) is left as it was.
// With template flag MEAN (config `mean_correction = "tiles"`), the reconstruction is first
// multiplied by the mean correction's factors (ssr/tile_means, one per tile of TILE x TILE
// pixels), interpolated bilinearly between tile centres (edges held).
//
// With template flag EMISSION too (a model of config emission "background"), the directly
// seen emission over the pixel's footprint (`emission`, xyz; sanitised as colour) is added:
// emission + background + (1 - coverage) * reconstruction.
//
//#param BACKGROUND 0
//#param MEAN 0
//#param EMISSION 0

// Params, TILE: ssr/lib/output.

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> src: array<vec4<f32>>;
@group(0) @binding(2) var dst: texture_storage_2d<rgba32float, write>;
//#if BACKGROUND
@group(0) @binding(3) var<storage, read> background: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> sanitized: array<atomic<u32>>;
//#end
//#if EMISSION
@group(0) @binding(6) var<storage, read> emission: array<vec4<f32>>;
//#end
//#if MEAN
@group(0) @binding(5) var<storage, read> factors: array<vec4<f32>>;

// Tile row or column below `c` (pixel centre in tile units, tile centres at integers) and
// the weight of the next one, within `n` tiles.
fn tile_lerp(c: f32, n: u32) -> vec2<f32> {
    let i0 = clamp(floor(c), 0.0, f32(n - 1u));
    return vec2<f32>(i0, clamp(c - i0, 0.0, 1.0));
}

fn factor_at(x: u32, y: u32) -> vec3<f32> {
    let tx = tile_lerp((f32(x) + 0.5) / f32(TILE) - 0.5, p.tiles_x);
    let ty = tile_lerp((f32(y) + 0.5) / f32(TILE) - 0.5, p.tiles_y);
    let x0 = u32(tx.x);
    let y0 = u32(ty.x);
    let x1 = min(x0 + 1u, p.tiles_x - 1u);
    let y1 = min(y0 + 1u, p.tiles_y - 1u);
    let top = factors[y0 * p.tiles_x + x0].xyz * (1.0 - tx.y) + factors[y0 * p.tiles_x + x1].xyz * tx.y;
    let bottom = factors[y1 * p.tiles_x + x0].xyz * (1.0 - tx.y) + factors[y1 * p.tiles_x + x1].xyz * tx.y;
    return top * (1.0 - ty.y) + bottom * ty.y;
}
//#end

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= p.width || gid.y >= p.height) {
        return;
    }
    var rgb = src[(gid.y * p.padded_width + gid.x) * p.c4].xyz;
//#if MEAN
    rgb *= factor_at(gid.x, gid.y);
//#end
//#if BACKGROUND
    let b = background[gid.y * p.width + gid.x];
    var bad = 0u;
    let coverage = in_range(b.w, 0.0, 1.0, &bad);
    rgb = sanitize_radiance(b.xyz, &bad) + (1.0 - coverage) * rgb;
//#if EMISSION
    rgb += sanitize_radiance(emission[gid.y * p.width + gid.x].xyz, &bad);
//#end
    if (bad > 0u) {
        atomicAdd(&sanitized[0], bad);
    }
//#end
    textureStore(dst, vec2<u32>(gid.xy), vec4<f32>(rgb, 1.0));
}
