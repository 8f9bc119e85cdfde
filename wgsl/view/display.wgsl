// Display: shows one or two HDR tensors (split screen) in an rgba8unorm storage texture,
// with an 8x8 bitmap-font text overlay. Source pixels are fetched nearest-neighbour,
// scaled to the output size.
//   mode 0: radiance, Uncharted 2 filmic (exposure 2, white 11.2) + gamma 2.2
//   mode 1: signed values in [-1, 1] shown as [0, 1] (normals, motion / 8 px)
//   mode 2: values clamped to [0, 1] (albedo, depth, masks, roughness)
// `channels` = 1 shows channel `first` as grey, 2 shows (first, first+1, 0), 3 shows rgb.
// A source is a tensor (storage buffer, channels padded to 4) or, with template flag
// TEXTURE_A / TEXTURE_B, a float texture read texel by texel (e.g. the denoiser's output).
//
//#param TEXTURE_A 0
//#param TEXTURE_B 0

struct Params {
    out_w: u32,
    out_h: u32,
    src_w: u32,
    src_h: u32,
    mode: u32,
    first: u32,
    channels: u32,
    c4_a: u32,
    c4_b: u32,
    split_x: u32,     // output column where source B starts (>= out_w: no split)
    text_cols: u32,
    text_rows: u32,
    text_scale: u32,
    scale_b: f32,     // multiplier of mode 1 inputs (e.g. 1/8 for motion)
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
//#if TEXTURE_A
@group(0) @binding(1) var src_a: texture_2d<f32>;
//#else
@group(0) @binding(1) var<storage, read> src_a: array<vec4<f32>>;
//#end
//#if TEXTURE_B
@group(0) @binding(2) var src_b: texture_2d<f32>;
//#else
@group(0) @binding(2) var<storage, read> src_b: array<vec4<f32>>;
//#end
@group(0) @binding(3) var<storage, read> text: array<u32>;   // one char code per u32
@group(0) @binding(4) var<storage, read> font: array<u32>;   // 128 glyphs x 2 words (8 rows of 8 bits)
@group(0) @binding(5) var dst: texture_storage_2d<rgba8unorm, write>;

fn hable(x: vec3<f32>) -> vec3<f32> {
    let a = 0.15;
    let b = 0.50;
    let c = 0.10;
    let d = 0.20;
    let e = 0.02;
    let f = 0.30;
    return ((x * (a * x + c * b) + d * e) / (x * (a * x + b) + d * f)) - e / f;
}

fn tonemap(v: vec3<f32>) -> vec3<f32> {
    let x = select(vec3<f32>(0.0), max(v, vec3<f32>(0.0)), abs(v) <= vec3<f32>(3.0e38));
    let t = clamp(hable(2.0 * x) / hable(vec3<f32>(11.2)), vec3<f32>(0.0), vec3<f32>(1.0));
    return pow(t, vec3<f32>(1.0 / 2.2));
}

fn channel(use_b: bool, sx: u32, sy: u32, c: u32) -> f32 {
    let pix = sy * p.src_w + sx;
    if (use_b) {
//#if TEXTURE_B
        return textureLoad(src_b, vec2<u32>(sx, sy), 0)[c % 4u];
//#else
        return src_b[pix * p.c4_b + c / 4u][c % 4u];
//#end
    }
//#if TEXTURE_A
    return textureLoad(src_a, vec2<u32>(sx, sy), 0)[c % 4u];
//#else
    return src_a[pix * p.c4_a + c / 4u][c % 4u];
//#end
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let x = gid.x;
    let y = gid.y;
    if (x >= p.out_w || y >= p.out_h) {
        return;
    }
    let sx = min(x * p.src_w / p.out_w, p.src_w - 1u);
    let sy = min(y * p.src_h / p.out_h, p.src_h - 1u);
    let use_b = x >= p.split_x;
    var v = vec3<f32>(0.0);
    for (var i = 0u; i < min(p.channels, 3u); i++) {
        v[i] = channel(use_b, sx, sy, p.first + i);
    }
    if (p.channels == 1u) {
        v = vec3<f32>(v.x);
    }
    var rgb: vec3<f32>;
    if (p.mode == 0u) {
        rgb = tonemap(v);
    } else if (p.mode == 1u) {
        rgb = clamp(v * p.scale_b * 0.5 + vec3<f32>(0.5), vec3<f32>(0.0), vec3<f32>(1.0));
    } else {
        rgb = clamp(v, vec3<f32>(0.0), vec3<f32>(1.0));
    }
    if (p.split_x < p.out_w && x == p.split_x) {
        rgb = vec3<f32>(1.0);
    }
    // Text overlay: a dark box behind 8x8 glyphs scaled by text_scale.
    let cell = 8u * p.text_scale;
    let col = x / cell;
    let row = y / cell;
    if (col < p.text_cols && row < p.text_rows) {
        let code = text[row * p.text_cols + col] & 127u;
        let gx = (x % cell) / p.text_scale;
        let gy = (y % cell) / p.text_scale;
        let word = font[code * 2u + gy / 4u];
        let bits = (word >> ((gy % 4u) * 8u)) & 255u;
        let on = ((bits >> gx) & 1u) == 1u;
        rgb = select(rgb * 0.35, vec3<f32>(1.0, 1.0, 0.6), on);
    }
    textureStore(dst, vec2<u32>(x, y), vec4<f32>(rgb, 1.0));
}
