//! Thin Rust wrappers of the `wgsl/nn` kernels. Each checks shapes, packs its parameters
//! and returns a [`Dispatch`] that can be recorded any number of times.

use bytemuck::{Pod, Zeroable};

pub use super::conv::{Conv3x3, ConvKernel};
use super::{DType, Tensor};
use crate::error::{Error, Result};
use crate::gpu::{Dispatch, Gpu, Grid, Specialisation};

/// Activation applied after a convolution.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Activation {
    /// Identity.
    None,
    /// `max(x, 0)`.
    Relu,
    /// `x` if `x >= 0` else `slope * x`.
    LeakyRelu(f32),
}

impl Activation {
    /// Applies the activation to one value.
    pub fn apply(self, v: f32) -> f32 {
        match self {
            Activation::None => v,
            Activation::Relu => v.max(0.0),
            Activation::LeakyRelu(s) => {
                if v >= 0.0 {
                    v
                } else {
                    s * v
                }
            }
        }
    }
    pub(super) fn code(self) -> (u32, f32) {
        match self {
            Activation::None => (0, 0.0),
            Activation::Relu => (1, 0.0),
            Activation::LeakyRelu(s) => (2, s),
        }
    }
}

/// 2x2 pooling mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PoolMode {
    /// Maximum of the window.
    Max,
    /// Mean of the window.
    Average,
}

/// 2x upsampling mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum UpsampleMode {
    /// Nearest neighbour.
    Nearest,
    /// Bilinear, PyTorch `align_corners=False`.
    Bilinear,
}

pub(super) fn check_size(op: &str, what: &str, t: &Tensor, w: u32, h: u32) -> Result<()> {
    if (t.width, t.height) != (w, h) {
        return Err(Error::shape(
            op,
            format!("{what} is {}x{}, expected {w}x{h}", t.width, t.height),
        ));
    }
    Ok(())
}

pub(super) fn check_channels(op: &str, what: &str, t: &Tensor, c: u32) -> Result<()> {
    if t.channels != c {
        return Err(Error::shape(
            op,
            format!("{what} has {} channels, expected {c}", t.channels),
        ));
    }
    Ok(())
}

fn check_min_channels(op: &str, what: &str, t: &Tensor, c: u32) -> Result<()> {
    if t.channels < c {
        return Err(Error::shape(
            op,
            format!("{what} has {} channels, expected at least {c}", t.channels),
        ));
    }
    Ok(())
}

/// Errors unless every tensor is stored as f32 (kernels without an f16 variant).
pub(crate) fn f32_only(op: &str, tensors: &[(&str, &Tensor)]) -> Result<()> {
    for (what, t) in tensors {
        if t.dtype != DType::F32 {
            return Err(Error::shape(
                op,
                format!(
                    "{what} is stored as {}; this kernel reads and writes f32 tensors only",
                    t.dtype.name()
                ),
            ));
        }
    }
    Ok(())
}

/// The storage template flags (nn/lib/storage) of a kernel reading `inputs` (`F16_IN0`,
/// ...) and writing `out` (`F16_OUT`), as each is stored.
pub(crate) fn storage_flags(inputs: &[&Tensor], out: Option<&Tensor>) -> Specialisation {
    const IN: [&str; 5] = ["F16_IN0", "F16_IN1", "F16_IN2", "F16_IN3", "F16_IN4"];
    assert!(inputs.len() <= IN.len(), "nn/lib/storage has {} inputs", IN.len());
    let mut flags: Vec<(&'static str, f64)> = IN
        .iter()
        .zip(inputs)
        .map(|(n, t)| (*n, t.dtype.f16_flag() as f64))
        .collect();
    if let Some(o) = out {
        flags.push(("F16_OUT", o.dtype.f16_flag() as f64));
    }
    Specialisation(flags)
}

pub(super) fn distinct(op: &str, out: &Tensor, inputs: &[&Tensor]) -> Result<()> {
    if inputs.iter().any(|i| i.buffer == out.buffer) {
        return Err(Error::shape(
            op,
            "the output tensor is also an input (in-place is not supported)",
        ));
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------
// pooling and upsampling

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ResampleParams {
    width: u32,
    height: u32,
    c4: u32,
    _pad: u32,
    src: [[u32; 4]; 4],
}

/// How a kernel reads an input tensor (`nn/lib/fetch`): as stored, or resampled 2x on load
/// (the U-Net's pooling and upsampling between levels, fused into the convolution that
/// reads them, or run as a pass of its own by [`pool2x2`] and [`upsample2x`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Fetch {
    /// As stored, at the reader's size.
    #[default]
    Direct,
    /// 2x upsampled from a tensor of `ceil(w/2) x ceil(h/2)`.
    Upsample(UpsampleMode),
    /// 2x2 pooled from a tensor of `2w-1..=2w x 2h-1..=2h` (windows clipped to it).
    Pool(PoolMode),
}

impl Fetch {
    /// Its `FETCHk` code in `nn/lib/fetch`.
    pub fn code(self) -> u32 {
        match self {
            Fetch::Direct => 0,
            Fetch::Upsample(UpsampleMode::Nearest) => 1,
            Fetch::Upsample(UpsampleMode::Bilinear) => 2,
            Fetch::Pool(PoolMode::Max) => 3,
            Fetch::Pool(PoolMode::Average) => 4,
        }
    }

    /// The size of a stored tensor that a reader of `w x h` reads through it (for pooling,
    /// the even one of the two that fit).
    pub fn stored_size(self, w: u32, h: u32) -> (u32, u32) {
        match self {
            Fetch::Direct => (w, h),
            Fetch::Upsample(_) => (w.div_ceil(2), h.div_ceil(2)),
            Fetch::Pool(_) => (2 * w, 2 * h),
        }
    }

    /// Whether a reader of `w x h` can read a stored tensor of `src_w x src_h` through it.
    pub fn fits(self, src_w: u32, src_h: u32, w: u32, h: u32) -> bool {
        match self {
            Fetch::Direct => (src_w, src_h) == (w, h),
            Fetch::Upsample(_) => (w.div_ceil(2), h.div_ceil(2)) == (src_w, src_h),
            Fetch::Pool(_) => (src_w.div_ceil(2), src_h.div_ceil(2)) == (w, h),
        }
    }

    /// Short name (cache keys, reports): `direct`, `up-nearest`, `up-bilinear`,
    /// `pool-max`, `pool-average`.
    pub fn name(self) -> &'static str {
        match self {
            Fetch::Direct => "direct",
            Fetch::Upsample(UpsampleMode::Nearest) => "up-nearest",
            Fetch::Upsample(UpsampleMode::Bilinear) => "up-bilinear",
            Fetch::Pool(PoolMode::Max) => "pool-max",
            Fetch::Pool(PoolMode::Average) => "pool-average",
        }
    }
}

/// 2x2 pooling of `input` into `out` (`ceil(w/2) x ceil(h/2)`, same channels); either
/// may be stored as f16.
pub fn pool2x2(gpu: &Gpu, mode: PoolMode, input: &Tensor, out: &Tensor) -> Result<Dispatch> {
    check_size(
        "pool2x2",
        "output",
        out,
        input.width.div_ceil(2),
        input.height.div_ceil(2),
    )?;
    resample("pool2x2", gpu, Fetch::Pool(mode), input, out)
}

/// 2x upsampling of `input` into `out`, whose size must be within 2x of the input
/// (`2w-1..=2w` by `2h-1..=2h`, so padded odd sizes work).
pub fn upsample2x(gpu: &Gpu, mode: UpsampleMode, input: &Tensor, out: &Tensor) -> Result<Dispatch> {
    let op = "upsample2x";
    if !Fetch::Upsample(mode).fits(input.width, input.height, out.width, out.height) {
        return Err(Error::shape(
            op,
            format!(
                "output {}x{} is not a 2x upsampling of input {}x{}",
                out.width, out.height, input.width, input.height
            ),
        ));
    }
    f32_only(op, &[("input", input), ("output", out)])?;
    resample(op, gpu, Fetch::Upsample(mode), input, out)
}

/// A copy of `input` into `out` (same size and channels) in `out`'s storage (f32 or f16;
/// finite values beyond f16's range clamped to it, as every f16 store): `nn/resample2x`
/// reading as stored.
pub fn convert(gpu: &Gpu, input: &Tensor, out: &Tensor) -> Result<Dispatch> {
    check_size("convert", "output", out, input.width, input.height)?;
    resample("convert", gpu, Fetch::Direct, input, out)
}

/// The dispatch of `nn/resample2x` for operation `op` once the sizes are checked: same
/// channels, distinct buffers, one thread per output pixel.
fn resample(op: &str, gpu: &Gpu, fetch: Fetch, input: &Tensor, out: &Tensor) -> Result<Dispatch> {
    check_channels(op, "output", out, input.channels)?;
    distinct(op, out, &[input])?;
    let mut src = [[0; 4]; 4];
    src[0] = [input.width, input.height, 0, 0];
    let params = ResampleParams {
        width: out.width,
        height: out.height,
        c4: input.c4(),
        _pad: 0,
        src,
    };
    let spec = Specialisation(vec![
        ("F16_IN0", input.dtype.f16_flag() as f64),
        ("F16_OUT", out.dtype.f16_flag() as f64),
        ("FETCH0", fetch.code() as f64),
    ]);
    gpu.kernels.dispatch(
        "nn/resample2x",
        &spec,
        bytemuck::bytes_of(&params),
        &[&input.buffer, &out.buffer],
        Grid::pixels(out.width, out.height),
    )
}

// ---------------------------------------------------------------------------------------
// TFA blend

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct BlendParams {
    width: u32,
    height: u32,
    k4: u32,
    c4: u32,
}

/// Tensors of one TFA blend.
#[derive(Debug, Clone, Copy)]
pub struct TfaBlend<'a> {
    /// Reference features R (K ch).
    pub r: &'a Tensor,
    /// Embedding of the current features (K ch).
    pub e_cur: &'a Tensor,
    /// Embedding of the warped history (K ch).
    pub e_prev: &'a Tensor,
    /// Current features (C ch).
    pub cur: &'a Tensor,
    /// Warped history (C ch).
    pub prev: &'a Tensor,
    /// History validity (channel 0).
    pub valid: &'a Tensor,
    /// Blended output (C ch).
    pub out: &'a Tensor,
    /// Per-pixel (beta, alpha, s_cur, s_prev) (4 ch).
    pub weights: &'a Tensor,
}

/// Per-pixel dot-product scores, 2-way softmax and blend (DESIGN §4 TFA). R, the
/// embeddings, `cur`, `prev` and `out` may be stored as f16; `valid` and `weights` are f32.
pub fn tfa_blend(gpu: &Gpu, t: TfaBlend<'_>) -> Result<Dispatch> {
    let op = "tfa_blend";
    let (w, h) = (t.cur.width, t.cur.height);
    for (n, x) in [
        ("R", t.r),
        ("E_cur", t.e_cur),
        ("E_prev", t.e_prev),
        ("prev", t.prev),
        ("valid", t.valid),
        ("out", t.out),
        ("weights", t.weights),
    ] {
        check_size(op, n, x, w, h)?;
    }
    check_channels(op, "E_cur", t.e_cur, t.r.channels)?;
    check_channels(op, "E_prev", t.e_prev, t.r.channels)?;
    check_channels(op, "prev", t.prev, t.cur.channels)?;
    check_channels(op, "out", t.out, t.cur.channels)?;
    check_channels(op, "weights", t.weights, 4)?;
    check_min_channels(op, "valid", t.valid, 1)?;
    f32_only(op, &[("valid", t.valid), ("weights", t.weights)])?;
    let ins = [t.r, t.e_cur, t.e_prev, t.cur, t.prev, t.valid];
    distinct(op, t.out, &ins)?;
    distinct(op, t.weights, &ins)?;
    let params = BlendParams {
        width: w,
        height: h,
        k4: t.r.c4(),
        c4: t.cur.c4(),
    };
    if t.valid.c4() != 1 {
        return Err(Error::shape(op, "valid must have at most 4 channels"));
    }
    gpu.kernels.dispatch(
        "nn/tfa_blend",
        &storage_flags(&[t.r, t.e_cur, t.e_prev, t.cur, t.prev], Some(t.out)),
        bytemuck::bytes_of(&params),
        &[
            &t.r.buffer,
            &t.e_cur.buffer,
            &t.e_prev.buffer,
            &t.cur.buffer,
            &t.prev.buffer,
            &t.valid.buffer,
            &t.out.buffer,
            &t.weights.buffer,
        ],
        Grid::pixels(w, h),
    )
}

// ---------------------------------------------------------------------------------------
// warp

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct WarpParams {
    width: u32,
    height: u32,
    c4: u32,
    motion_c4: u32,
}

/// Bilinear backward warp of `src` by `motion` (channels 0, 1 in pixels) into `out`, with
/// validity in channel 0 of `valid`.
pub fn warp(gpu: &Gpu, src: &Tensor, motion: &Tensor, out: &Tensor, valid: &Tensor) -> Result<Dispatch> {
    let op = "warp";
    let (w, h) = (src.width, src.height);
    check_size(op, "motion", motion, w, h)?;
    check_size(op, "out", out, w, h)?;
    check_size(op, "valid", valid, w, h)?;
    check_min_channels(op, "motion", motion, 2)?;
    check_channels(op, "out", out, src.channels)?;
    if valid.c4() != 1 {
        return Err(Error::shape(op, "valid must have 1 to 4 channels"));
    }
    distinct(op, out, &[src, motion])?;
    distinct(op, valid, &[src, motion, out])?;
    f32_only(
        op,
        &[("src", src), ("motion", motion), ("out", out), ("valid", valid)],
    )?;
    let params = WarpParams {
        width: w,
        height: h,
        c4: src.c4(),
        motion_c4: motion.c4(),
    };
    gpu.kernels.dispatch(
        "nn/warp",
        &Specialisation::none(),
        bytemuck::bytes_of(&params),
        &[&src.buffer, &motion.buffer, &out.buffer, &valid.buffer],
        Grid::pixels(w, h),
    )
}

// ---------------------------------------------------------------------------------------
// demodulation

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ModParams {
    width: u32,
    height: u32,
    a_c4: u32,
    b_c4: u32,
    b_offset: u32,
    ceiling: f32,
    _pad: [u32; 2],
}

fn modulation(
    gpu: &Gpu,
    kernel: &str,
    a: &Tensor,
    albedo: &Tensor,
    albedo_channel: u32,
    scale: Option<(&Tensor, Option<f32>)>,
    out: &Tensor,
) -> Result<Dispatch> {
    let (w, h) = (a.width, a.height);
    let ceiling = scale.and_then(|(_, c)| c);
    check_min_channels(kernel, "input", a, 3)?;
    check_min_channels(kernel, "albedo", albedo, albedo_channel + 3)?;
    check_size(kernel, "albedo", albedo, w, h)?;
    check_size(kernel, "out", out, w, h)?;
    check_channels(kernel, "out", out, 3)?;
    distinct(kernel, out, &[a, albedo])?;
    // The input and the albedo are read as stored (f32 or f16).
    f32_only(kernel, &[("out", out)])?;
    if let Some((s, _)) = scale {
        f32_only(kernel, &[("scale", s)])?;
        check_size(kernel, "scale", s, 1, 1)?;
        check_min_channels(kernel, "scale", s, if ceiling.is_some() { 9 } else { 3 })?;
        distinct(kernel, out, &[s])?;
    }
    if let Some(g) = ceiling
        && (g.is_nan() || g <= 0.0 || g.is_infinite())
    {
        return Err(Error::Invalid(format!(
            "{kernel}: ceiling gain {g}, expected a finite value > 0"
        )));
    }
    let params = ModParams {
        width: w,
        height: h,
        a_c4: a.c4(),
        b_c4: albedo.c4(),
        b_offset: albedo_channel,
        ceiling: ceiling.unwrap_or(0.0),
        _pad: [0; 2],
    };
    let mut buffers = vec![&a.buffer, &albedo.buffer, &out.buffer];
    if let Some((s, _)) = scale {
        buffers.push(&s.buffer);
    }
    let mut spec = storage_flags(&[a, albedo], None);
    // Only nn/remodulate has the flag (nn/demodulate has no scale).
    if ceiling.is_some() {
        spec.0.push(("CEILING", 1.0));
    }
    gpu.kernels.dispatch(
        kernel,
        &spec,
        bytemuck::bytes_of(&params),
        &buffers,
        Grid::pixels(w, h),
    )
}

/// `out = ln(1 + color / (albedo + 0.00316))` over the first 3 channels of `color` and
/// channels `albedo_channel..albedo_channel + 3` of `albedo`.
/// `color` and `albedo` may be stored as f16 (the output is f32).
pub fn demodulate(
    gpu: &Gpu,
    color: &Tensor,
    albedo: &Tensor,
    albedo_channel: u32,
    out: &Tensor,
) -> Result<Dispatch> {
    modulation(gpu, "nn/demodulate", color, albedo, albedo_channel, None, out)
}

/// `out = max(exp(o) - 1, 0) * (albedo + 0.00316) * scale` over the first 3 channels of `o`
/// and channels `albedo_channel..albedo_channel + 3` of `albedo`; `scale` is a 1x1 tensor
/// whose first 3 channels scale (SSR: the frame's colour exposure).
///
/// With `ceiling = Some(g)` (SSR config `ceiling`), o is first capped at
/// `ln(1 + g M_c / scale_c)`, M = channels 6..8 of `scale` (SSR: the running max of the
/// demodulated samples), and the capped values are written back into `o`
/// ([`reference::ceiling`](crate::nn::reference::ceiling)). `o` and `albedo` may be stored
/// as f16 (the output is f32).
pub fn remodulate(
    gpu: &Gpu,
    o: &Tensor,
    albedo: &Tensor,
    albedo_channel: u32,
    scale: &Tensor,
    ceiling: Option<f32>,
    out: &Tensor,
) -> Result<Dispatch> {
    let scale = Some((scale, ceiling));
    modulation(gpu, "nn/remodulate", o, albedo, albedo_channel, scale, out)
}

/// Encodes `dispatches` (each in its own pass) and submits them; returns when done.
pub fn run(gpu: &Gpu, dispatches: &[&Dispatch]) -> Result<()> {
    let mut enc = gpu
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("subpixel.nn.run"),
        });
    for d in dispatches {
        d.encode(&mut enc);
    }
    gpu.queue.submit([enc.finish()]);
    gpu.wait()
}

/// Size in bytes of each kernel's uniform `Params` as the Rust side lays it out, for the
/// test that compares them with naga's layout.
pub const PARAM_SIZES: &[(&str, usize)] = &[
    ("nn/resample2x", std::mem::size_of::<ResampleParams>()),
    ("nn/tfa_blend", std::mem::size_of::<BlendParams>()),
    ("nn/warp", std::mem::size_of::<WarpParams>()),
    ("nn/demodulate", std::mem::size_of::<ModParams>()),
    ("nn/remodulate", std::mem::size_of::<ModParams>()),
];
