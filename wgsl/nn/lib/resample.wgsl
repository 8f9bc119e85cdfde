// Shared by the resampling kernels (pool2x2, upsample2x): their parameter block (the
// bindings stay in each kernel). `mode` is the kernel's variant (pool2x2: 0 max,
// 1 average; upsample2x: 0 nearest, 1 bilinear).

struct Params {
    in_w: u32,
    in_h: u32,
    out_w: u32,
    out_h: u32,
    c4: u32,
    mode: u32,
    _pad0: u32,
    _pad1: u32,
}
