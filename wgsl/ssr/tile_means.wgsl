// The mean correction's statistic (config `mean_correction = "tiles"`, issue 11; reference
// src/nn/reference.rs `mean_tile_sums` and `mean_tile_factors`): the traced samples are an
// unbiased estimate of each pixel's radiance, so over a tile of TILE x TILE pixels and the
// last RING frames, the sum of the samples says how bright the reconstruction should be.
// One workgroup per tile of the W x H frame sums its pixels' shares (s, r) of ssr/lib/traced
// (0 where a pixel is not traced). Thread 0 writes (s, r) to slot `p.slot` of the ring (RING
// slots of tiles_x x tiles_y tiles, 2 vec4 per tile); on the first frame after a reset
// (`p.first`) it clears the other slots. Then, per channel, the factor over the ring,
//   clamp((sum s + EPS) / (sum r + EPS), LO, HI),
// goes to factors[tile] (w = 1); store_output applies it, interpolated between tile centres.
//
//#param BACKGROUND 0
//#param ESCAPED 0

// Params, TILE: ssr/lib/output.

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> src: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> color_mask: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> ring: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> factors: array<vec4<f32>>;
//#if BACKGROUND
@group(0) @binding(5) var<storage, read> background: array<vec4<f32>>;
//#end

// Set by the denoiser from src/ssr/config.rs (MEAN_RING, MEAN_EPS, MEAN_LO, MEAN_HI; TILE,
// in ssr/lib/output, a multiple of SIDE).
override RING: u32 = 4u;
override EPS: f32 = 1.0e-4;
override LO: f32 = 0.67;
override HI: f32 = 1.5;
const SIDE: u32 = 8u;

var<workgroup> sample_sums: array<vec4<f32>, 64>;
var<workgroup> recon_sums: array<vec4<f32>, 64>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    var s = vec3<f32>(0.0);
    var r = vec3<f32>(0.0);
    for (var j = 0u; j < TILE / SIDE; j++) {
        for (var i = 0u; i < TILE / SIDE; i++) {
            let x = wid.x * TILE + i * SIDE + lid.x;
            let y = wid.y * TILE + j * SIDE + lid.y;
            if (x < p.width && y < p.height) {
                let shares = traced_shares(x, y);
                s += shares.s;
                r += shares.r;
            }
        }
    }
    let l = lid.y * SIDE + lid.x;
    sample_sums[l] = vec4<f32>(s, 0.0);
    recon_sums[l] = vec4<f32>(r, 0.0);
    workgroupBarrier();
    for (var stride = 32u; stride > 0u; stride /= 2u) {
        if (l < stride) {
            sample_sums[l] += sample_sums[l + stride];
            recon_sums[l] += recon_sums[l + stride];
        }
        workgroupBarrier();
    }
    if (l == 0u) {
        let n = p.tiles_x * p.tiles_y;
        let tile = wid.y * p.tiles_x + wid.x;
        var total_s = sample_sums[0];
        var total_r = recon_sums[0];
        ring[2u * (p.slot * n + tile)] = total_s;
        ring[2u * (p.slot * n + tile) + 1u] = total_r;
        for (var k = 0u; k < RING; k++) {
            if (k != p.slot) {
                let at = 2u * (k * n + tile);
                if (p.first != 0u) {
                    ring[at] = vec4<f32>(0.0);
                    ring[at + 1u] = vec4<f32>(0.0);
                } else {
                    total_s += ring[at];
                    total_r += ring[at + 1u];
                }
            }
        }
        let f = clamp((total_s.xyz + EPS) / (total_r.xyz + EPS), vec3<f32>(LO), vec3<f32>(HI));
        factors[tile] = vec4<f32>(f, 1.0);
    }
}
