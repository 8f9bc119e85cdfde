// How a kernel reads each of its inputs (issue 14, fusion): the 2x resampling between
// U-Net levels is done on load by the convolution that reads it, so that it needs no pass
// and no tensor of its own (nn/resample2x runs the same arithmetic as a pass). Override
// constant FETCHk of input k:
//   0  as stored: a tensor of the reader's size;
//   1  2x nearest upsampling of a tensor of half the size (rounded up);
//   2  2x bilinear upsampling (PyTorch align_corners=False), source coordinates clamped;
//   3  2x2 max pooling of a tensor of twice the size (windows clipped to it);
//   4  2x2 average pooling (over the pixels inside the window).
// The stored tensor's size is p.src[k].xy (the kernel's parameter block) and its element
// type the input's alias of nn/lib/storage; the arithmetic is f32. A kernel including
// this library declares template parameter N_IN, bindings in0, in1, ... (N_IN of them)
// and a parameter block `p` with `src: array<vec4<u32>, 4>`.

override FETCH0: u32 = 0u;
override FETCH1: u32 = 0u;
override FETCH2: u32 = 0u;
override FETCH3: u32 = 0u;

//#repeat k N_IN
//#if TEX_IN
// With the template flag TEX_IN the inputs are texture arrays (the convolution copied each
// to one with nn/to_texture: a layer per channel vec4) and `raw{k}` fetches texels, which CPU
// drivers vectorise where they run storage-buffer loads lane by lane; the same arithmetic.
fn raw{k}(x: u32, y: u32, ci: u32) -> vec4<f32> {
    return textureLoad(in{k}, vec2<u32>(x, y), ci, 0);
}

// Channel vec4 `ci` of input {k} at pixel (x, y) of the layer's image (`c4` unused).
fn load{k}(x: u32, y: u32, c4: u32, ci: u32) -> vec4<f32> {
    let s = p.src[{k}].xy;
    if (FETCH{k} == 0u) {
        return raw{k}(x, y, ci);
    }
    if (FETCH{k} == 1u) {
        return raw{k}(min(x / 2u, s.x - 1u), min(y / 2u, s.y - 1u), ci);
    }
    if (FETCH{k} == 2u) {
        let fx = max((f32(x) + 0.5) * 0.5 - 0.5, 0.0);
        let fy = max((f32(y) + 0.5) * 0.5 - 0.5, 0.0);
        let x0 = min(u32(fx), s.x - 1u);
        let y0 = min(u32(fy), s.y - 1u);
        let x1 = min(x0 + 1u, s.x - 1u);
        let y1 = min(y0 + 1u, s.y - 1u);
        let tx = fx - f32(x0);
        let ty = fy - f32(y0);
        let a = raw{k}(x0, y0, ci);
        let b = raw{k}(x1, y0, ci);
        let d = raw{k}(x0, y1, ci);
        let e = raw{k}(x1, y1, ci);
        return mix(mix(a, b, tx), mix(d, e, tx), ty);
    }
    let x1 = min(2u * x + 1u, s.x - 1u);
    let y1 = min(2u * y + 1u, s.y - 1u);
    let a = raw{k}(2u * x, 2u * y, ci);
    let b = raw{k}(x1, 2u * y, ci);
    let d = raw{k}(2u * x, y1, ci);
    let e = raw{k}(x1, y1, ci);
    if (FETCH{k} == 3u) {
        return max(max(a, b), max(d, e));
    }
    // Clipped taps repeat an in-window pixel; count each distinct pixel once.
    var sum = a;
    if (x1 != 2u * x) { sum += b; }
    if (y1 != 2u * y) { sum += d; }
    if (x1 != 2u * x && y1 != 2u * y) { sum += e; }
    return sum / f32((x1 - 2u * x + 1u) * (y1 - 2u * y + 1u));
}
//#else
// The same arithmetic over storage buffers, written out rather than through a `raw{k}` as
// above: this is the text every driver's shader cache already holds for the buffer tilings
// (an extra function changes their SPIR-V, and a first tuning then recompiles all of them:
// about 20 minutes on a 2-core CPU driver).
// Channel vec4 `ci` (of `c4` per pixel) of input {k} at pixel (x, y) of the layer's image.
fn load{k}(x: u32, y: u32, c4: u32, ci: u32) -> vec4<f32> {
    let s = p.src[{k}].xy;
    if (FETCH{k} == 0u) {
        return vec4<f32>(in{k}[(y * s.x + x) * c4 + ci]);
    }
    if (FETCH{k} == 1u) {
        let i = min(y / 2u, s.y - 1u) * s.x + min(x / 2u, s.x - 1u);
        return vec4<f32>(in{k}[i * c4 + ci]);
    }
    if (FETCH{k} == 2u) {
        let fx = max((f32(x) + 0.5) * 0.5 - 0.5, 0.0);
        let fy = max((f32(y) + 0.5) * 0.5 - 0.5, 0.0);
        let x0 = min(u32(fx), s.x - 1u);
        let y0 = min(u32(fy), s.y - 1u);
        let x1 = min(x0 + 1u, s.x - 1u);
        let y1 = min(y0 + 1u, s.y - 1u);
        let tx = fx - f32(x0);
        let ty = fy - f32(y0);
        let a = vec4<f32>(in{k}[(y0 * s.x + x0) * c4 + ci]);
        let b = vec4<f32>(in{k}[(y0 * s.x + x1) * c4 + ci]);
        let d = vec4<f32>(in{k}[(y1 * s.x + x0) * c4 + ci]);
        let e = vec4<f32>(in{k}[(y1 * s.x + x1) * c4 + ci]);
        return mix(mix(a, b, tx), mix(d, e, tx), ty);
    }
    let x1 = min(2u * x + 1u, s.x - 1u);
    let y1 = min(2u * y + 1u, s.y - 1u);
    let a = vec4<f32>(in{k}[((2u * y) * s.x + 2u * x) * c4 + ci]);
    let b = vec4<f32>(in{k}[((2u * y) * s.x + x1) * c4 + ci]);
    let d = vec4<f32>(in{k}[(y1 * s.x + 2u * x) * c4 + ci]);
    let e = vec4<f32>(in{k}[(y1 * s.x + x1) * c4 + ci]);
    if (FETCH{k} == 3u) {
        return max(max(a, b), max(d, e));
    }
    // Clipped taps repeat an in-window pixel; count each distinct pixel once.
    var sum = a;
    if (x1 != 2u * x) { sum += b; }
    if (y1 != 2u * y) { sum += d; }
    if (x1 != 2u * x && y1 != 2u * y) { sum += e; }
    return sum / f32((x1 - 2u * x + 1u) * (y1 - 2u * y + 1u));
}
//#end
//#end
