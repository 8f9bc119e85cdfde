// The mean correction's statistic at one pixel, shared by ssr/tile_means (summed per tile)
// and ssr/mean_history (per pixel, carried along the motion). The traced samples are an
// unbiased estimate of each pixel's radiance, so they say how bright the reconstruction
// should be. Where the pixel is traced (mask > 0.5):
//   s = sample - background          (the sample's share that the network reconstructs)
//   r = (1 - coverage) x output      (the network's reconstruction of that share)
// else both 0. With the flag ESCAPED (a model of config escaped = "background", whose input
// leaves out the samples that escaped to the environment) the samples left are of the part
// of the footprint that hits the scene, which the network reconstructs, so
//   s = (1 - coverage) x sample      (weighted as the reconstruction's share of the output) The inputs are sanitised as store_output and pack_inputs do (ssr/lib/sanitize,
// not counted here: those passes count them). Without the template flag BACKGROUND,
// background and coverage are 0. Refers to the including kernel's `p` (ssr/lib/output's
// Params), `src`, `color_mask` and, with BACKGROUND, `background`.
//
//#param BACKGROUND 0
//#param ESCAPED 0

struct Shares {
    s: vec3<f32>,
    r: vec3<f32>,
}

fn traced_shares(x: u32, y: u32) -> Shares {
    var ignored = 0u;
    let at = y * p.width + x;
    let cm = color_mask[at];
    if (sanitize_mask(cm.w, &ignored) <= 0.5) {
        return Shares(vec3<f32>(0.0), vec3<f32>(0.0));
    }
    var out = src[(y * p.padded_width + x) * p.c4].xyz;
    var sample = sanitize_radiance(cm.xyz, &ignored);
//#if BACKGROUND
    let b = background[at];
    let coverage = in_range(b.w, 0.0, 1.0, &ignored);
//#if ESCAPED
    sample *= 1.0 - coverage;
//#else
    sample -= sanitize_radiance(b.xyz, &ignored);
//#end
    out *= 1.0 - coverage;
//#end
    return Shares(sample, out);
}
