// Shared by the output passes, ssr/tile_means, ssr/mean_history and ssr/store_output: their
// parameters (src/ssr/denoiser.rs OutputParams; store_output leaves `slot` and `first`
// unused, mean_history `tiles_x`, `tiles_y` and `slot`) and the mean correction's tile side
// (src/ssr/config.rs MEAN_TILE, set by the denoiser).

struct Params {
    width: u32,
    height: u32,
    padded_width: u32,
    c4: u32,
    tiles_x: u32,
    tiles_y: u32,
    slot: u32,
    first: u32,
}

override TILE: u32 = 32u;
