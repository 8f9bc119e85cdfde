//! The 3x3 convolution layer and its kernel family.
//!
//! One layer ([`Conv3x3`]) can run on four WGSL kernels, chosen per layer by
//! [`ConvKernel`]:
//! - `nn/conv3x3` ([`ConvKernel::Generic`]): one pixel and 16 output channels per
//!   invocation, shapes as runtime parameters, weights in a storage buffer. Runs any layer.
//! - `nn/conv3x3_blocked` ([`ConvKernel::Blocked`]): `px` adjacent pixels times `cob`
//!   output vec4s per invocation, shapes and activation as override constants (one
//!   pipeline per layer shape), weights in a 64 KiB uniform buffer. Runs layers whose
//!   packed weights fit it ([`Conv3x3::candidates`]).
//! - `nn/conv3x3_winograd` ([`ConvKernel::Winograd`]): Winograd's F(2x2, 3x3), `tx`
//!   adjacent 2x2 output tiles times `cob` output vec4s per invocation, 16 multiplications
//!   per tile and channel pair instead of 36, otherwise as the blocked kernel (its weights
//!   transformed on the host, 16 per input and output channel instead of 9).
//! - Either of the last two with `tex` (`-tex` in its name): the inputs read by texel
//!   fetches (template flag `TEX_IN`) from rgba32float texture arrays, one layer per channel
//!   vec4. CPU drivers vectorise texel fetches but load storage buffers lane by lane, so
//!   there the copies pay for themselves (README Performance); the autotuner tries the
//!   tilings of [`ConvKernel::texture_tilings`]. A bind alone copies each input to a texture
//!   of its own (`nn/to_texture`); in the network ([`TextureIo`], `ssr::shared_textures`)
//!   a tensor is copied once a frame for all its readers, or not at all when a kernel with
//!   uniform weights produces it and stores its output to the texture too (`TEX_OUT`).
//! - `nn/conv3x3_coop` ([`ConvKernel::Coop`]): an implicit matrix product on cooperative
//!   matrices (tensor cores), T x T matrices (16, or 8 where the adapter has only those),
//!   one subgroup per `mt * T` pixels times `nt * T` output channels, f16 operands and f32
//!   sums, weights as f16 in a storage buffer. Only on a device with wgpu's experimental
//!   cooperative matrices ([`Gpu::has_coop_matrix`]).
//!
//! The first two compute the same sums (in another order: taps by row, then inputs, then
//! columns in the blocked kernel), so both agree with the CPU reference
//! ([`super::reference::conv3x3`]) to the same float tolerance; the cooperative kernel
//! rounds its operands to f16 and agrees within [`COOP_TOLERANCE`]. A blocked or Winograd
//! kernel writing f16 activations (the f16 precision) reads its weights rounded to f16
//! too ([`WeightStorage`]): the same sums of the rounded weights. Which one is fastest
//! depends on the adapter, which is what [`super::autotune`] measures.

use std::collections::HashMap;
use std::sync::Mutex;

use bytemuck::{Pod, Zeroable};

use super::Tensor;
use super::ops::{Activation, Fetch, check_channels, distinct};
use super::tensor::padded;
use crate::error::{Error, Result};
use crate::gpu::{Dispatch, Gpu, Grid, Specialisation};

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ConvParams {
    width: u32,
    height: u32,
    n_inputs: u32,
    cout4: u32,
    cin4: [u32; 4],
    cin4_total: u32,
    act: u32,
    slope: f32,
    _pad: u32,
    src: [[u32; 4]; 4],
}

/// The parameter block of the specialised kernels (`Params` of nn/lib/conv_shape).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ShapedParams {
    width: u32,
    height: u32,
    _pad: [u32; 2],
    src: [[u32; 4]; 4],
}

/// The parameters of `nn/to_texture`.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ToTextureParams {
    width: u32,
    height: u32,
    c4: u32,
    _pad: u32,
}

/// Bytes of the rgba32float texture array `nn/to_texture` copies `t` to.
fn texture_bytes(t: &Tensor) -> u64 {
    t.width as u64 * t.height as u64 * t.c4() as u64 * 16
}

/// A texture array that holds a tensor for the kernels reading their inputs as textures
/// ([`activation_texture`]), and the view they bind.
#[derive(Debug)]
pub struct ActivationTexture {
    /// One rgba32float layer per channel vec4 (exact for f32 and f16 storage).
    pub texture: wgpu::Texture,
    /// Its 2D-array view.
    pub view: wgpu::TextureView,
}

/// An [`ActivationTexture`] for tensor `t`, filled by [`copy_to_texture`] or by the
/// convolution producing `t` ([`TextureIo::output`]); an error naming `user` where the
/// device's texture limits cannot hold it.
pub fn activation_texture(gpu: &Gpu, user: &str, t: &Tensor) -> Result<ActivationTexture> {
    let limits = gpu.device.limits();
    let (side, layers) = (limits.max_texture_dimension_2d, limits.max_texture_array_layers);
    if t.width > side || t.height > side || t.c4() > layers {
        return Err(Error::shape(
            user,
            format!(
                "{}x{} with {} vec4s per pixel exceeds the device's textures ({side} pixels a side, {layers} layers)",
                t.width,
                t.height,
                t.c4()
            ),
        ));
    }
    let texture = gpu.storage_texture_layers(
        &format!("subpixel.texture.{user}"),
        t.width,
        t.height,
        t.c4(),
        wgpu::TextureFormat::Rgba32Float,
    );
    let view = texture.create_view(&wgpu::TextureViewDescriptor {
        dimension: Some(wgpu::TextureViewDimension::D2Array),
        ..Default::default()
    });
    Ok(ActivationTexture { texture, view })
}

/// The dispatch of `nn/to_texture` copying `t` into `dst` (an [`activation_texture`] of it).
pub fn copy_to_texture(gpu: &Gpu, t: &Tensor, dst: &wgpu::TextureView) -> Result<Dispatch> {
    let params = ToTextureParams {
        width: t.width,
        height: t.height,
        c4: t.c4(),
        _pad: 0,
    };
    let mut copy = gpu.kernels.dispatch_with(
        "nn/to_texture",
        &Specialisation(vec![("F16_IN0", t.dtype.f16_flag() as f64)]),
        bytemuck::bytes_of(&params),
        &[
            t.buffer.as_entire_binding(),
            wgpu::BindingResource::TextureView(dst),
        ],
        Grid::Invocations([t.width, t.height, t.c4()]),
    )?;
    copy.bytes_read = t.bytes() + std::mem::size_of::<ToTextureParams>() as u64;
    copy.bytes_written = texture_bytes(t);
    Ok(copy)
}

/// Where an input of a convolution reading textures comes from ([`TextureIo::inputs`]).
#[derive(Debug, Clone, Copy)]
pub enum InputTexture<'a> {
    /// This texture array, which the bind fills first (copies the input there): the first
    /// reader of a tensor that no convolution writes as a texture.
    Fill(&'a wgpu::TextureView),
    /// This texture array, already holding the input when the bind's dispatches run:
    /// written by the convolution producing it ([`TextureIo::output`]) or by an earlier
    /// reader's [`InputTexture::Fill`].
    Filled(&'a wgpu::TextureView),
}

impl<'a> InputTexture<'a> {
    /// The texture array, filled or to fill.
    pub fn view(self) -> &'a wgpu::TextureView {
        match self {
            InputTexture::Fill(v) | InputTexture::Filled(v) => v,
        }
    }
}

/// The texture arrays one [`Conv3x3::bind_textured`] shares with the other steps of a
/// network, so that a tensor several convolutions read as a texture is copied once, or not
/// at all when a convolution produces it. The default shares nothing (as
/// [`Conv3x3::bind_with`]: each input copied to a texture of the bind's own).
#[derive(Debug, Clone, Default)]
pub struct TextureIo<'a> {
    /// Per input, in concatenation order, for a kernel reading textures (ignored by the
    /// others): where it comes from; `None` (or a shorter list) copies it to a texture of
    /// the bind's own.
    pub inputs: Vec<Option<InputTexture<'a>>>,
    /// An [`activation_texture`] of the output that a kernel with uniform weights
    /// ([`ConvKernel::Blocked`], [`ConvKernel::Winograd`]) also stores to (template flag
    /// `TEX_OUT`); an error for the other kernels.
    pub output: Option<&'a wgpu::TextureView>,
}

/// Output channels one `nn/conv3x3` invocation computes (4 vec4s).
const GENERIC_COUT_BLOCK: u32 = 16;
/// Capacity of `nn/conv3x3_blocked`'s uniform weight array, in vec4s (`MAX_WEIGHTS`).
pub const BLOCKED_MAX_WEIGHTS: u32 = 4096;
/// How the blocked and Winograd kernels store a layer's weights in their uniform array.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum WeightStorage {
    /// f32, the trained values.
    F32,
    /// The trained values rounded to f16, two to a u32 (template flag `W16` of
    /// nn/lib/uniform_weights): for a layer that writes f16 activations (the f16 precision),
    /// whose results are rounded to f16 anyway. Half the weight loads, which on CPU
    /// drivers cost as much per lane as activation loads.
    F16,
}

impl WeightStorage {
    /// The storage of the weights of a layer writing `output`.
    pub fn for_output(output: super::DType) -> Self {
        match output {
            super::DType::F16 => WeightStorage::F16,
            super::DType::F32 => WeightStorage::F32,
        }
    }

    fn name(self) -> &'static str {
        match self {
            WeightStorage::F32 => "f32",
            WeightStorage::F16 => "f16",
        }
    }
}

/// Most accumulators (`px * cob` vec4s) one blocked invocation may hold (`MAX_ACC`).
pub const BLOCKED_MAX_ACC: u32 = 32;
/// Most pixels per blocked invocation (`MAX_PX`).
pub const BLOCKED_MAX_PX: u32 = 16;
/// Most accumulators (`16 * tx * cob` vec4s) one Winograd invocation may hold.
pub const WINOGRAD_MAX_ACC: u32 = 64;
/// Largest error of the cooperative-matrix kernel against the CPU reference, relative to
/// the reference output's largest magnitude: its operands are rounded to f16 (11-bit
/// significands; a sum of n products then errs by about sqrt(n) * 2^-11 of the terms'
/// scale), its sums are f32.
pub const COOP_TOLERANCE: f32 = 4e-3;
/// Most accumulator matrices (`mt * nt * rt`) one cooperative-matrix subgroup may hold.
pub const COOP_MAX_ACC: u32 = 8;

/// The workgroup size of `nn/conv3x3_coop` on `gpu`: one subgroup, the adapter's largest
/// (where subgroups may be smaller, a workgroup holds several that repeat the same matrix
/// work: slower, not wrong, and the autotuner times it like any other).
fn coop_subgroup(gpu: &Gpu) -> u32 {
    gpu.info.subgroup_max_size.clamp(4, 128)
}

/// Which kernel runs a [`Conv3x3`], and with which tiling.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum ConvKernel {
    /// `nn/conv3x3`: one pixel x 16 output channels per invocation, weights in storage.
    Generic,
    /// `nn/conv3x3_blocked`: `px` pixels x `cob` output vec4s per invocation, weights in a
    /// uniform buffer.
    Blocked {
        /// Horizontally adjacent pixels per invocation (1..=16).
        px: u32,
        /// Output vec4s (4 channels each) per invocation (1..=32, `px * cob <= 32`).
        cob: u32,
        /// Whether the inputs are first copied to texture arrays and read as textures
        /// (`nn/to_texture`; template flag TEX_IN): faster where storage-buffer loads are
        /// slow (CPU drivers), one more pass per input elsewhere.
        #[serde(default)]
        tex: bool,
    },
    /// `nn/conv3x3_winograd`: F(2x2, 3x3) over `tx` adjacent 2x2 output tiles x `cob`
    /// output vec4s per invocation, transformed weights in a uniform buffer.
    Winograd {
        /// Horizontally adjacent 2x2 output tiles per invocation (1, 2 or 4).
        tx: u32,
        /// Output vec4s per invocation (1, 2 or 4; `16 * tx * cob <= 64`).
        cob: u32,
        /// Inputs read as textures, as for [`ConvKernel::Blocked`].
        #[serde(default)]
        tex: bool,
    },
    /// `nn/conv3x3_coop`: one subgroup per `mt` tiles of T pixels of `rt` rows times `nt`
    /// output tiles of T channels, on T x T cooperative matrices ([`Gpu::coop_tile`]).
    Coop {
        /// Pixel tiles per subgroup (1, 2 or 4).
        mt: u32,
        /// Output-channel tiles per subgroup (1 or 2).
        nt: u32,
        /// Rows per subgroup (1 or 2): more rows share each staged input row.
        rt: u32,
    },
}

/// The name suffix of a kernel reading its inputs as textures.
const TEX_SUFFIX: &str = "-tex";

fn tex_suffix(tex: bool) -> &'static str {
    if tex { TEX_SUFFIX } else { "" }
}

impl std::fmt::Display for ConvKernel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ConvKernel::Generic => write!(f, "generic"),
            ConvKernel::Blocked { px, cob, tex } => write!(f, "px{px}-cob{cob}{}", tex_suffix(*tex)),
            ConvKernel::Coop { mt, nt, rt } => write!(f, "coop-m{mt}-n{nt}-r{rt}"),
            ConvKernel::Winograd { tx, cob, tex } => write!(f, "wino-tx{tx}-cob{cob}{}", tex_suffix(*tex)),
        }
    }
}

impl std::str::FromStr for ConvKernel {
    type Err = Error;
    /// Parses `generic`, `pxP-cobC`, `wino-txT-cobC` (either with `-tex`: inputs read as
    /// textures) or `coop-mM-nN-rR` (as [`ConvKernel`]'s `Display` writes them).
    fn from_str(name: &str) -> Result<Self> {
        let bad = || {
            Error::Invalid(format!(
                "conv kernel '{name}': expected 'generic', 'pxP-cobC' (e.g. px4-cob2), 'wino-txT-cobC' (e.g. wino-tx2-cob1), either with '-tex' (e.g. px16-cob2-tex), or 'coop-mM-nN-rR' (e.g. coop-m2-n2-r1)"
            ))
        };
        if name == "generic" {
            return Ok(ConvKernel::Generic);
        }
        let (s, tex) = match name.strip_suffix(TEX_SUFFIX) {
            Some(rest) => (rest, true),
            None => (name, false),
        };
        // `NAMEa-NAMEb` fields after a prefix, each a number after its name.
        let fields = |rest: &str, names: &[&str]| -> Result<Vec<u32>> {
            let parts: Vec<&str> = rest.split('-').collect();
            if parts.len() != names.len() {
                return Err(bad());
            }
            parts
                .iter()
                .zip(names)
                .map(|(p, n)| p.strip_prefix(n).and_then(|v| v.parse().ok()).ok_or_else(bad))
                .collect()
        };
        let k = if let Some(rest) = s.strip_prefix("wino-") {
            let f = fields(rest, &["tx", "cob"])?;
            ConvKernel::Winograd {
                tx: f[0],
                cob: f[1],
                tex,
            }
        } else if let Some(rest) = s.strip_prefix("coop-") {
            if tex {
                return Err(bad());
            }
            let f = fields(rest, &["m", "n", "r"])?;
            ConvKernel::Coop {
                mt: f[0],
                nt: f[1],
                rt: f[2],
            }
        } else {
            let f = fields(s, &["px", "cob"])?;
            ConvKernel::Blocked {
                px: f[0],
                cob: f[1],
                tex,
            }
        };
        k.check_tiling()
            .map_err(|m| Error::Invalid(format!("conv kernel '{name}': {m}")))?;
        Ok(k)
    }
}

impl ConvKernel {
    /// The tilings the autotuner tries besides [`ConvKernel::Generic`] (before a layer's
    /// own limits prune them): 1 to 16 pixels times 1 to 8 output blocks, at most 32
    /// accumulators.
    pub fn blocked_tilings() -> Vec<ConvKernel> {
        let mut v = Vec::new();
        for px in [1, 2, 4, 8, 16] {
            for cob in [1, 2, 4, 8] {
                if px * cob <= BLOCKED_MAX_ACC {
                    v.push(ConvKernel::Blocked { px, cob, tex: false });
                }
            }
        }
        v
    }

    /// The Winograd tilings the autotuner tries: 1, 2 or 4 tiles times 1, 2 or 4 output
    /// blocks, at most [`WINOGRAD_MAX_ACC`] accumulators (larger tilings were measured
    /// faster on a CPU driver only at sizes the network does not have, and compile slowly
    /// there: README Performance).
    pub fn winograd_tilings() -> Vec<ConvKernel> {
        let mut v = Vec::new();
        for tx in [1, 2, 4] {
            for cob in [1, 2, 4] {
                if 16 * tx * cob <= WINOGRAD_MAX_ACC {
                    v.push(ConvKernel::Winograd { tx, cob, tex: false });
                }
            }
        }
        v
    }

    /// The tilings the autotuner also tries with the inputs read as textures (`tex`): the
    /// register-blocked and Winograd tilings that were fastest that way on a CPU driver
    /// (README Performance; fewer than all, to bound the first tuning's compile time).
    pub fn texture_tilings() -> Vec<ConvKernel> {
        let blocked =
            [(16, 2), (8, 4), (8, 2), (4, 4)].map(|(px, cob)| ConvKernel::Blocked { px, cob, tex: true });
        let winograd = [(2, 2), (1, 4), (4, 1)].map(|(tx, cob)| ConvKernel::Winograd { tx, cob, tex: true });
        blocked.into_iter().chain(winograd).collect()
    }

    /// Every kernel the autotuner knows, in its order: the generic kernel, then the
    /// register-blocked, Winograd, texture-reading and cooperative-matrix tilings.
    pub fn catalogue() -> Vec<ConvKernel> {
        std::iter::once(ConvKernel::Generic)
            .chain(ConvKernel::blocked_tilings())
            .chain(ConvKernel::winograd_tilings())
            .chain(ConvKernel::texture_tilings())
            .chain(ConvKernel::coop_tilings())
            .collect()
    }

    /// Whether the kernel reads its inputs as textures.
    pub fn reads_textures(&self) -> bool {
        self.uniform_layout().is_some_and(|l| l.tex)
    }

    /// How a kernel with weights in a uniform buffer (blocked, Winograd) is shaped; `None`
    /// for the others.
    pub(crate) fn uniform_layout(&self) -> Option<UniformLayout> {
        match *self {
            ConvKernel::Blocked { px, cob, tex } => Some(UniformLayout {
                kernel: "nn/conv3x3_blocked",
                positions: 9,
                tiling: ("PX", px),
                tile: [px, 1],
                cob,
                tex,
            }),
            ConvKernel::Winograd { tx, cob, tex } => Some(UniformLayout {
                kernel: "nn/conv3x3_winograd",
                positions: 16,
                tiling: ("TX", tx),
                tile: [2 * tx, 2],
                cob,
                tex,
            }),
            ConvKernel::Generic | ConvKernel::Coop { .. } => None,
        }
    }

    /// The cooperative-matrix tilings the autotuner tries where the device has them: 1, 2
    /// or 4 pixel tiles times 1 or 2 channel tiles times 1 or 2 rows, at most
    /// [`COOP_MAX_ACC`] accumulators.
    pub fn coop_tilings() -> Vec<ConvKernel> {
        let mut v = Vec::new();
        for rt in [1, 2] {
            for mt in [1, 2, 4] {
                for nt in [1, 2] {
                    if mt * nt * rt <= COOP_MAX_ACC {
                        v.push(ConvKernel::Coop { mt, nt, rt });
                    }
                }
            }
        }
        v
    }

    fn check_tiling(&self) -> std::result::Result<(), String> {
        match *self {
            ConvKernel::Blocked { px, cob, .. } => {
                if px == 0 || cob == 0 || px > BLOCKED_MAX_PX || px * cob > BLOCKED_MAX_ACC {
                    return Err(format!(
                        "px and cob must be >= 1, px <= {BLOCKED_MAX_PX} and px * cob <= {BLOCKED_MAX_ACC}"
                    ));
                }
            }
            ConvKernel::Coop { mt, nt, rt } => {
                if ![1, 2, 4].contains(&mt)
                    || ![1, 2].contains(&nt)
                    || ![1, 2].contains(&rt)
                    || mt * nt * rt > COOP_MAX_ACC
                {
                    return Err(format!(
                        "mt must be 1, 2 or 4, nt and rt 1 or 2, and mt * nt * rt <= {COOP_MAX_ACC}"
                    ));
                }
            }
            ConvKernel::Winograd { tx, cob, .. } => {
                if ![1, 2, 4].contains(&tx) || ![1, 2, 4].contains(&cob) || 16 * tx * cob > WINOGRAD_MAX_ACC {
                    return Err(format!(
                        "tx and cob must be 1, 2 or 4, and 16 * tx * cob <= {WINOGRAD_MAX_ACC}"
                    ));
                }
            }
            ConvKernel::Generic => {}
        }
        Ok(())
    }
}

/// The shape of a convolution kernel with weights in a uniform buffer
/// ([`ConvKernel::uniform_layout`]).
pub(crate) struct UniformLayout {
    /// The WGSL kernel.
    pub kernel: &'static str,
    /// Packed weights per input and output channel pair: 9 taps, or the 16 positions of
    /// the Winograd transform ([`winograd_weights`]).
    pub positions: u32,
    /// The template parameter of the invocation's tile width, and its value.
    pub tiling: (&'static str, u32),
    /// Output pixels per invocation, across and down.
    pub tile: [u32; 2],
    /// Output vec4s per invocation (template parameter `COB`).
    pub cob: u32,
    /// Inputs read as textures (template flag `TEX_IN`).
    pub tex: bool,
}

/// Winograd F(2x2, 3x3)'s input transform B^T: V = B^T d B of a 4x4 input patch d (the
/// kernel's arithmetic, for CPU replays of it).
pub const WINOGRAD_BT: [[f32; 4]; 4] = [
    [1.0, 0.0, -1.0, 0.0],
    [0.0, 1.0, 1.0, 0.0],
    [0.0, -1.0, 1.0, 0.0],
    [0.0, 1.0, 0.0, -1.0],
];
/// Its output transform A^T: the 2x2 outputs Y = A^T M A of M = U . V summed over inputs.
pub const WINOGRAD_AT: [[f32; 4]; 2] = [[1.0, 1.0, 1.0, 0.0], [0.0, 1.0, -1.0, -1.0]];

/// Winograd's F(2x2, 3x3) weight transform `U = G g G^T` of one 3x3 kernel `g` (row-major
/// taps), as `nn/conv3x3_winograd` reads it (row-major 4x4), with
/// `G = [1 0 0; 1/2 1/2 1/2; 1/2 -1/2 1/2; 0 0 1]`.
pub fn winograd_weights(g: &[f32; 9]) -> [f32; 16] {
    const G: [[f32; 3]; 4] = [
        [1.0, 0.0, 0.0],
        [0.5, 0.5, 0.5],
        [0.5, -0.5, 0.5],
        [0.0, 0.0, 1.0],
    ];
    // G g (4x3), then (G g) G^T (4x4).
    let mut gg = [[0.0f32; 3]; 4];
    for (i, row) in gg.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| G[i][k] * g[k * 3 + j]).sum();
        }
    }
    let mut u = [0.0f32; 16];
    for i in 0..4 {
        for j in 0..4 {
            u[i * 4 + j] = (0..3).map(|k| gg[i][k] * G[j][k]).sum();
        }
    }
    u
}

/// A 3x3 convolution layer (stride 1, zero padding, bias, activation) over up to 4 input
/// tensors read as if concatenated along channels. Each input and the output may be
/// stored as f32 or f16 ([`super::DType`]); the sums are f32 either way.
#[derive(Debug)]
pub struct Conv3x3 {
    /// Layer name (for errors).
    pub name: String,
    /// Logical channels of each input tensor, in concatenation order.
    pub input_channels: Vec<u32>,
    /// Output channels.
    pub cout: u32,
    /// Activation.
    pub act: Activation,
    weight: Vec<f32>,
    bias_host: Vec<f32>,
    weights: wgpu::Buffer,
    bias: wgpu::Buffer,
    /// The kernel [`Conv3x3::bind`] uses ([`ConvKernel::Generic`] until set).
    kernel: ConvKernel,
    /// How it reads each input ([`Fetch::Direct`] until set).
    fetch: Vec<Fetch>,
    /// Uniform weight buffers of the blocked and Winograd kernels, by weight positions per
    /// channel pair (9, 16), output block `cob` (the packing's output stride depends on
    /// it) and storage (f16 pairs for a layer writing f16: [`WeightStorage`]).
    blocked: Mutex<HashMap<(u32, u32, WeightStorage), Vec<wgpu::Buffer>>>,
    /// f16 weight buffers of the cooperative-matrix kernel, by output tiles `nt` and matrix
    /// size.
    coop: Mutex<HashMap<(u32, u32), wgpu::Buffer>>,
}

impl Conv3x3 {
    /// Checks OIHW `weight` (`[cout][sum(input_channels)][3][3]`) and `bias` (`[cout]`)
    /// and uploads them.
    pub fn new(
        gpu: &Gpu,
        name: &str,
        weight: &[f32],
        bias: &[f32],
        input_channels: &[u32],
        cout: u32,
        act: Activation,
    ) -> Result<Self> {
        let (packed, b) = Self::pack(name, weight, bias, input_channels, cout)?;
        use wgpu::util::DeviceExt;
        let mk = |label: &str, data: &[f32]| {
            gpu.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(&format!("subpixel.{name}.{label}")),
                contents: bytemuck::cast_slice(data),
                usage: wgpu::BufferUsages::STORAGE,
            })
        };
        Ok(Self {
            name: name.to_string(),
            input_channels: input_channels.to_vec(),
            cout,
            act,
            weight: weight.to_vec(),
            bias_host: bias.to_vec(),
            weights: mk("weight", &packed),
            bias: mk("bias", &b),
            kernel: ConvKernel::Generic,
            fetch: vec![Fetch::Direct; input_channels.len()],
            blocked: Mutex::new(HashMap::new()),
            coop: Mutex::new(HashMap::new()),
        })
    }

    /// Packs weights into `nn/conv3x3`'s layout `[tap][ci4][co4][4 columns][4 rows]` and
    /// pads the bias to a multiple of 4. Returns `(weights, bias)`.
    pub fn pack(
        name: &str,
        weight: &[f32],
        bias: &[f32],
        input_channels: &[u32],
        cout: u32,
    ) -> Result<(Vec<f32>, Vec<f32>)> {
        Self::pack_strided(name, weight, bias, input_channels, cout, padded(cout) / 4, 9)
    }

    /// [`Conv3x3::pack`] with `cout4_stride >= cout4` output vec4s per `(tap, ci4)` row
    /// (the blocked kernel rounds the output up to its block; extra columns are zero), and
    /// `positions` 9 (the taps) or 16 (each 3x3 kernel through [`winograd_weights`], for
    /// `nn/conv3x3_winograd`).
    fn pack_strided(
        name: &str,
        weight: &[f32],
        bias: &[f32],
        input_channels: &[u32],
        cout: u32,
        cout4_stride: u32,
        positions: u32,
    ) -> Result<(Vec<f32>, Vec<f32>)> {
        let op = format!("conv3x3 '{name}'");
        if input_channels.is_empty() || input_channels.len() > 4 || input_channels.contains(&0) {
            return Err(Error::shape(
                &op,
                format!("takes 1 to 4 non-empty inputs, got channel split {input_channels:?}"),
            ));
        }
        if cout == 0 {
            return Err(Error::shape(&op, "cout must be > 0"));
        }
        let cin: u32 = input_channels.iter().sum();
        let expect = (cout * cin * 9) as usize;
        if weight.len() != expect {
            return Err(Error::shape(
                &op,
                format!(
                    "weight has {} values, expected [{cout}, {cin}, 3, 3] = {expect}",
                    weight.len()
                ),
            ));
        }
        if bias.len() != cout as usize {
            return Err(Error::shape(
                &op,
                format!("bias has {} values, expected {cout}", bias.len()),
            ));
        }
        let cin4: u32 = input_channels.iter().map(|&c| padded(c) / 4).sum();
        let mut packed = vec![0.0f32; (positions * cin4 * cout4_stride * 16) as usize];
        let mut base_logical = 0;
        let mut base_padded = 0;
        for &c in input_channels {
            for ci in 0..c {
                let li = base_logical + ci; // logical input channel (PyTorch index)
                let pi = base_padded + ci; // padded slot
                for co in 0..cout {
                    let at = ((co * cin + li) * 9) as usize;
                    let g: [f32; 9] = weight[at..at + 9].try_into().expect("9 taps");
                    let values = if positions == 16 {
                        winograd_weights(&g).to_vec()
                    } else {
                        g.to_vec()
                    };
                    for (pos, &wv) in (0..).zip(&values) {
                        // [position][ci4][co4][col k = pi%4][row = co%4]
                        let idx = ((((pos * cin4 + pi / 4) * cout4_stride + co / 4) * 4 + pi % 4) * 4
                            + co % 4) as usize;
                        packed[idx] = wv;
                    }
                }
            }
            base_logical += c;
            base_padded += padded(c);
        }
        let mut b = bias.to_vec();
        b.resize(padded(cout) as usize, 0.0);
        Ok((packed, b))
    }

    /// Packs OIHW `weight` for `nn/conv3x3_coop` with `tile x tile` matrices:
    /// `[block][tap][ci (tile)][co (co_pad)]`, where the blocks are each input's channels in
    /// groups of `tile` (the last one zero-padded) in input order, and output channels at or
    /// beyond `cout` are zero. As f32; the kernel reads them as f16.
    pub fn pack_coop(weight: &[f32], input_channels: &[u32], cout: u32, tile: u32, co_pad: u32) -> Vec<f32> {
        let cin: u32 = input_channels.iter().sum();
        let blocks: u32 = input_channels.iter().map(|&c| c.div_ceil(tile)).sum();
        let mut packed = vec![0.0f32; (blocks * 9 * tile * co_pad) as usize];
        let (mut base_logical, mut base_block) = (0, 0);
        for &c in input_channels {
            for ci in 0..c {
                let li = base_logical + ci;
                let blk = base_block + ci / tile;
                for co in 0..cout {
                    for tap in 0..9 {
                        let idx = ((blk * 9 + tap) * tile + ci % tile) * co_pad + co;
                        packed[idx as usize] = weight[((co * cin + li) * 9 + tap) as usize];
                    }
                }
            }
            base_logical += c;
            base_block += c.div_ceil(tile);
        }
        packed
    }

    /// Output channels of the cooperative kernel's packed weights with `nt` output tiles of
    /// `tile` channels per subgroup: `cout` rounded up to a multiple of `nt * tile`.
    fn coop_co_pad(&self, nt: u32, tile: u32) -> u32 {
        self.cout.div_ceil(nt * tile) * nt * tile
    }

    /// The cooperative kernel's f16 weights for `nt` output tiles of `tile` channels per
    /// subgroup, uploaded on first use.
    fn coop_buffer(&self, gpu: &Gpu, nt: u32, tile: u32) -> wgpu::Buffer {
        let mut cache = self.coop.lock().unwrap();
        cache
            .entry((nt, tile))
            .or_insert_with(|| {
                let co_pad = self.coop_co_pad(nt, tile);
                let packed = Self::pack_coop(&self.weight, &self.input_channels, self.cout, tile, co_pad);
                let half: Vec<half::f16> = packed.iter().map(|&v| half::f16::from_f32(v)).collect();
                use wgpu::util::DeviceExt;
                gpu.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some(&format!("subpixel.{}.weight.coop-n{nt}-t{tile}", self.name)),
                    contents: bytemuck::cast_slice(&half),
                    usage: wgpu::BufferUsages::STORAGE,
                })
            })
            .clone()
    }

    /// Runs `kernel` on this layer at `w x h` (its fetch modes; inputs stored as `dtypes`,
    /// deterministic pseudo-random values in [-1, 1]) and returns its largest error against
    /// the CPU reference ([`super::reference::conv3x3`] after the CPU resampling of each
    /// input), relative to the reference's largest magnitude (at least 1). Non-finite
    /// outputs count as infinitely wrong. The autotuner runs it on kernels whose arithmetic
    /// the crate cannot check on every adapter before use (the cooperative-matrix kernel).
    pub fn output_error(
        &self,
        gpu: &Gpu,
        kernel: ConvKernel,
        w: u32,
        h: u32,
        dtypes: &[super::DType],
    ) -> Result<f32> {
        let mut errors = self.output_errors(gpu, &[kernel], w, h, dtypes)?;
        errors.pop().expect("one kernel, one result")
    }

    /// [`Conv3x3::output_error`] of each of `kernels`, on one set of inputs and one CPU
    /// reference: an error building those is the outer one, a kernel that fails to bind or
    /// run gets its own.
    pub fn output_errors(
        &self,
        gpu: &Gpu,
        kernels: &[ConvKernel],
        w: u32,
        h: u32,
        dtypes: &[super::DType],
    ) -> Result<Vec<Result<f32>>> {
        use super::ops::run;
        use super::reference::{self, HostTensor};
        let mut stored = Vec::new();
        let mut seen = Vec::new();
        for (i, (&c, &fetch)) in self.input_channels.iter().zip(&self.fetch).enumerate() {
            let (sw, sh) = fetch.stored_size(w, h);
            let host = HostTensor::from_fn(sw, sh, c, |x, y, ch| {
                let v = (x * 37 + y * 101 + ch * 13 + i as u32 * 7) % 97;
                v as f32 / 48.0 - 1.0
            });
            let dtype = dtypes.get(i).copied().unwrap_or(super::DType::F32);
            let t = super::Tensor::from_host_typed(gpu, "check.in", &host, dtype)?;
            // What the kernel reads: the stored values (f16-rounded when so stored).
            let host = t.read(gpu)?;
            seen.push(match fetch {
                Fetch::Direct => host.clone(),
                Fetch::Pool(mode) => reference::pool2x2(&host, mode),
                Fetch::Upsample(mode) => reference::upsample2x(&host, mode, w, h),
            });
            stored.push(t);
        }
        let out = super::Tensor::new(gpu, "check.out", w, h, self.cout)?;
        let refs: Vec<&super::Tensor> = stored.iter().collect();
        let hin: Vec<&HostTensor> = seen.iter().collect();
        let want = reference::conv3x3(&hin, &self.weight, &self.bias_host, self.cout, self.act);
        let scale = want.data.iter().fold(1.0f32, |m, v| m.max(v.abs()));
        Ok(kernels
            .iter()
            .map(|&kernel| {
                run(gpu, &[&self.bind_with(gpu, kernel, &refs, &out)?])?;
                let got = out.read(gpu)?;
                Ok(got.data.iter().zip(&want.data).fold(0.0f32, |m, (g, r)| {
                    let e = (g - r).abs() / scale;
                    if e.is_finite() { m.max(e) } else { f32::INFINITY }
                }))
            })
            .collect())
    }

    /// FLOPs per output pixel (multiply and add counted separately).
    pub fn flops_per_pixel(&self) -> u64 {
        18 * self.input_channels.iter().sum::<u32>() as u64 * self.cout as u64
    }

    fn cin4_total(&self) -> u32 {
        self.input_channels.iter().map(|&c| padded(c) / 4).sum()
    }

    /// Vec4s of packed weights a kernel with uniform weights (`positions` per channel
    /// pair: 9 blocked, 16 Winograd) needs per output block of `cob` vec4s.
    fn blocked_weights(&self, positions: u32, cob: u32) -> u32 {
        positions * self.cin4_total() * cob * 4
    }

    /// The output ranges `(first vec4, vec4s)` a kernel with uniform weights (`positions`
    /// per channel pair) and output block `cob` runs this layer in: as few dispatches as
    /// the uniform weight array allows (one for every layer of the shipped network on the
    /// blocked kernel). Empty when one block's weights do not fit.
    fn blocked_chunks(&self, positions: u32, cob: u32) -> Vec<(u32, u32)> {
        let cout4 = padded(self.cout) / 4;
        let per_block = self.blocked_weights(positions, cob);
        let blocks = BLOCKED_MAX_WEIGHTS / per_block.max(1);
        if blocks == 0 {
            return Vec::new();
        }
        let step = blocks * cob;
        (0..cout4.div_ceil(step))
            .map(|i| (i * step, step.min(cout4 - i * step)))
            .collect()
    }

    /// Why `kernel` cannot run this layer on `gpu`, or `None` when it can.
    pub fn unsupported(&self, gpu: &Gpu, kernel: ConvKernel) -> Option<String> {
        if let ConvKernel::Coop { .. } = kernel {
            if let Err(m) = kernel.check_tiling() {
                return Some(m);
            }
            if !gpu.has_coop_matrix() {
                return Some(
                    "the device has no cooperative matrices (wgpu's EXPERIMENTAL_COOPERATIVE_MATRIX \
                     with SHADER_F16; opt in with SUBPIXEL_COOP_MATRIX=1 where the adapter has them)"
                        .into(),
                );
            }
            return None;
        }
        // The generic kernel runs every layer (no reason, `None`).
        let UniformLayout { positions, cob, .. } = kernel.uniform_layout()?;
        if let Err(m) = kernel.check_tiling() {
            return Some(m);
        }
        let cout4 = padded(self.cout) / 4;
        if cob > cout4 {
            return Some(format!("cob {cob} exceeds the layer's {cout4} output vec4s"));
        }
        let need = self.blocked_weights(positions, cob);
        if need > BLOCKED_MAX_WEIGHTS {
            return Some(format!(
                "one output block's packed weights are {need} vec4s, more than the uniform array's {BLOCKED_MAX_WEIGHTS}"
            ));
        }
        let have = gpu.device.limits().max_uniform_buffer_binding_size;
        if have < BLOCKED_MAX_WEIGHTS as u64 * 16 {
            return Some(format!(
                "the device's uniform bindings hold {have} bytes, the kernel needs {}",
                BLOCKED_MAX_WEIGHTS * 16
            ));
        }
        None
    }

    /// The kernels that can run this layer on `gpu`: [`ConvKernel::Generic`], every
    /// blocked and Winograd tiling that fits (of [`ConvKernel::blocked_tilings`],
    /// [`ConvKernel::winograd_tilings`] and [`ConvKernel::texture_tilings`]), and the
    /// cooperative-matrix tilings where the device has them.
    pub fn candidates(&self, gpu: &Gpu) -> Vec<ConvKernel> {
        ConvKernel::catalogue()
            .into_iter()
            .filter(|&k| self.unsupported(gpu, k).is_none())
            .collect()
    }

    /// Checks the inputs' channel split, sizes and the output against the layer.
    fn check(&self, inputs: &[&Tensor], out: &Tensor) -> Result<()> {
        let op = format!("conv3x3 '{}'", self.name);
        let got: Vec<u32> = inputs.iter().map(|t| t.channels).collect();
        if got != self.input_channels {
            return Err(Error::shape(
                &op,
                format!("input channels {got:?}, expected {:?}", self.input_channels),
            ));
        }
        for (i, (t, f)) in inputs.iter().zip(&self.fetch).enumerate() {
            if !f.fits(t.width, t.height, out.width, out.height) {
                let (sw, sh) = f.stored_size(out.width, out.height);
                return Err(Error::shape(
                    &op,
                    format!(
                        "input {i} is {}x{}, expected {sw}x{sh} (read {} for a {}x{} output)",
                        t.width,
                        t.height,
                        f.name(),
                        out.width,
                        out.height
                    ),
                ));
            }
        }
        check_channels(&op, "output", out, self.cout)?;
        distinct(&op, out, inputs)
    }

    /// The kernel [`Conv3x3::bind`] uses.
    pub fn kernel(&self) -> ConvKernel {
        self.kernel
    }

    /// How the layer reads each input (every [`Fetch::Direct`] unless set).
    pub fn fetch(&self) -> &[Fetch] {
        &self.fetch
    }

    /// Makes the layer read its inputs through `fetch` (one per input): e.g. the pooled or
    /// upsampled tensor of the U-Net level beside it, resampled on load instead of by a
    /// pass of its own. An error names the layer when the count is wrong.
    pub fn set_fetch(&mut self, fetch: &[Fetch]) -> Result<()> {
        if fetch.len() != self.input_channels.len() {
            return Err(Error::shape(
                &format!("conv3x3 '{}'", self.name),
                format!(
                    "{} fetch modes for {} inputs",
                    fetch.len(),
                    self.input_channels.len()
                ),
            ));
        }
        self.fetch = fetch.to_vec();
        Ok(())
    }

    /// Makes [`Conv3x3::bind`] use `kernel`; an error names the layer and why when the
    /// kernel cannot run it.
    pub fn set_kernel(&mut self, gpu: &Gpu, kernel: ConvKernel) -> Result<()> {
        if let Some(why) = self.unsupported(gpu, kernel) {
            return Err(Error::shape(
                &format!("conv3x3 '{}'", self.name),
                format!("kernel {kernel} cannot run it: {why}"),
            ));
        }
        self.kernel = kernel;
        Ok(())
    }

    /// Binds `inputs` (in concatenation order) and `out` on the layer's kernel
    /// ([`Conv3x3::set_kernel`]; [`ConvKernel::Generic`], which runs every layer, unless set).
    pub fn bind(&self, gpu: &Gpu, inputs: &[&Tensor], out: &Tensor) -> Result<Dispatch> {
        self.bind_with(gpu, self.kernel, inputs, out)
    }

    /// Binds `inputs` and `out` on `kernel`; an error names the layer and why when the
    /// kernel cannot run it ([`Conv3x3::unsupported`]).
    pub fn bind_with(
        &self,
        gpu: &Gpu,
        kernel: ConvKernel,
        inputs: &[&Tensor],
        out: &Tensor,
    ) -> Result<Dispatch> {
        self.bind_textured(gpu, kernel, inputs, out, &TextureIo::default())
    }

    /// [`Conv3x3::bind_with`] sharing texture arrays with the rest of a network: the inputs
    /// a kernel reading textures finds in `io.inputs`, and the texture `io.output` the
    /// kernel also stores its output to (a network's producer of a tensor that convolutions
    /// read as a texture); an error names the layer when `io.output` is given to a kernel
    /// without uniform weights.
    pub fn bind_textured(
        &self,
        gpu: &Gpu,
        kernel: ConvKernel,
        inputs: &[&Tensor],
        out: &Tensor,
        io: &TextureIo<'_>,
    ) -> Result<Dispatch> {
        self.check(inputs, out)?;
        if io.output.is_some() && kernel.uniform_layout().is_none() {
            return Err(Error::shape(
                &format!("conv3x3 '{}'", self.name),
                format!("kernel {kernel} cannot store its output to a texture"),
            ));
        }
        if let Some(why) = self.unsupported(gpu, kernel) {
            return Err(Error::shape(
                &format!("conv3x3 '{}'", self.name),
                format!("kernel {kernel} cannot run it: {why}"),
            ));
        }
        let (w, h) = (out.width, out.height);
        let mut bufs: Vec<&wgpu::Buffer> = inputs.iter().map(|t| &t.buffer).collect();
        let mut cin4 = [0u32; 4];
        let mut src = [[0u32; 4]; 4];
        for (i, t) in inputs.iter().enumerate() {
            cin4[i] = t.c4();
            src[i] = [t.width, t.height, 0, 0];
        }
        let (act, slope) = self.act.code();
        // Storage of each input slot (unused slots repeat the first input) and the output.
        let f16 = |i: usize| inputs.get(i).unwrap_or(&inputs[0]).dtype.f16_flag() as f64;
        // How each input slot is read (unused slots as stored).
        let fetch = |i: usize| self.fetch.get(i).map_or(0, |f| f.code()) as f64;
        let storage = [
            ("F16_IN0", f16(0)),
            ("F16_IN1", f16(1)),
            ("F16_IN2", f16(2)),
            ("F16_IN3", f16(3)),
            ("F16_OUT", out.dtype.f16_flag() as f64),
            ("FETCH0", fetch(0)),
            ("FETCH1", fetch(1)),
            ("FETCH2", fetch(2)),
            ("FETCH3", fetch(3)),
        ];
        // What the specialised kernels (blocked, cooperative) share: the storage, the shapes
        // and activation as override constants (nn/lib/conv_shape), and the parameters.
        let shaped = || {
            let mut spec = Specialisation(storage.to_vec());
            spec.0.extend([
                ("N_IN", inputs.len() as f64),
                ("CIN4_0", cin4[0] as f64),
                ("CIN4_1", cin4[1] as f64),
                ("CIN4_2", cin4[2] as f64),
                ("CIN4_3", cin4[3] as f64),
                ("COUT4", out.c4() as f64),
                ("ACT", act as f64),
                ("SLOPE", slope as f64),
            ]);
            spec
        };
        let shaped_params = ShapedParams {
            width: w,
            height: h,
            _pad: [0; 2],
            src,
        };
        match kernel {
            ConvKernel::Generic => {
                let params = ConvParams {
                    width: w,
                    height: h,
                    n_inputs: inputs.len() as u32,
                    cout4: out.c4(),
                    cin4,
                    cin4_total: cin4.iter().sum(),
                    act,
                    slope,
                    _pad: 0,
                    src,
                };
                // nn/conv3x3 declares 4 inputs: repeat the first in unused slots.
                while bufs.len() < 4 {
                    bufs.push(&inputs[0].buffer);
                }
                bufs.extend([&self.weights, &self.bias, &out.buffer]);
                gpu.kernels.dispatch(
                    "nn/conv3x3",
                    &Specialisation(storage.to_vec()),
                    bytemuck::bytes_of(&params),
                    &bufs,
                    Grid::Invocations([w, h, padded(self.cout).div_ceil(GENERIC_COUT_BLOCK)]),
                )
            }
            ConvKernel::Blocked { .. } | ConvKernel::Winograd { .. } => {
                // The kernels with uniform weights: one dispatch per output range whose
                // weights fit the array, each invocation over a tile of `tile` pixels.
                let UniformLayout {
                    kernel: name,
                    positions,
                    tiling,
                    tile,
                    cob,
                    tex,
                } = kernel.uniform_layout().expect("a kernel with uniform weights");
                let chunks = self.blocked_chunks(positions, cob);
                let storage = WeightStorage::for_output(out.dtype);
                let weights = self.blocked_buffers(gpu, positions, cob, storage)?;
                // With `tex`, each input read from a texture array: the network's (filled
                // first by this bind where `io` says so), else one of its own, copied first.
                let mut parts = Vec::with_capacity(chunks.len() + inputs.len());
                let mut own: Vec<Option<wgpu::TextureView>> = Vec::new();
                if tex {
                    for (i, t) in inputs.iter().enumerate() {
                        own.push(match io.inputs.get(i).copied().flatten() {
                            Some(InputTexture::Fill(view)) => {
                                parts.push(copy_to_texture(gpu, t, view)?);
                                None
                            }
                            Some(InputTexture::Filled(_)) => None,
                            None => {
                                let user = format!("conv3x3 '{}' input {i}", self.name);
                                let texture = activation_texture(gpu, &user, t)?;
                                parts.push(copy_to_texture(gpu, t, &texture.view)?);
                                Some(texture.view)
                            }
                        });
                    }
                }
                let views: Vec<&wgpu::TextureView> = own
                    .iter()
                    .enumerate()
                    .map(|(i, own)| match (own, io.inputs.get(i).copied().flatten()) {
                        (Some(view), _) => view,
                        (None, Some(shared)) => shared.view(),
                        (None, None) => unreachable!("an input without a shared texture has its own"),
                    })
                    .collect();
                for (&(base, count), weights) in chunks.iter().zip(&weights) {
                    let mut spec = shaped();
                    spec.0.extend([
                        ("CO_BASE", base as f64),
                        ("CO_COUNT", count as f64),
                        (tiling.0, tiling.1 as f64),
                        ("COB", cob as f64),
                        ("TEX_IN", tex as u32 as f64),
                        ("W16", (storage == WeightStorage::F16) as u32 as f64),
                    ]);
                    if io.output.is_some() {
                        spec.0.push(("TEX_OUT", 1.0));
                    }
                    let grid =
                        Grid::Invocations([w.div_ceil(tile[0]), h.div_ceil(tile[1]), count.div_ceil(cob)]);
                    let params = bytemuck::bytes_of(&shaped_params);
                    parts.push(if tex || io.output.is_some() {
                        let mut r: Vec<wgpu::BindingResource<'_>> = if tex {
                            views
                                .iter()
                                .map(|v| wgpu::BindingResource::TextureView(v))
                                .collect()
                        } else {
                            bufs.iter().map(|b| b.as_entire_binding()).collect()
                        };
                        r.extend([
                            weights.as_entire_binding(),
                            self.bias.as_entire_binding(),
                            out.buffer.as_entire_binding(),
                        ]);
                        if let Some(view) = io.output {
                            r.push(wgpu::BindingResource::TextureView(view));
                        }
                        let mut d = gpu.kernels.dispatch_with(name, &spec, params, &r, grid)?;
                        // Traffic as `dispatch` counts it: the inputs (as textures, rgba32float,
                        // or as stored), the parameters, weights and bias read, the output
                        // written (and its texture).
                        let read: u64 = if tex {
                            inputs.iter().map(|t| texture_bytes(t)).sum()
                        } else {
                            // Each distinct buffer once.
                            let mut seen: Vec<&wgpu::Buffer> = Vec::new();
                            inputs
                                .iter()
                                .filter(|t| {
                                    let new = !seen.contains(&&t.buffer);
                                    seen.push(&t.buffer);
                                    new
                                })
                                .map(|t| t.bytes())
                                .sum()
                        };
                        d.bytes_read = read + params.len() as u64 + weights.size() + self.bias.size();
                        d.bytes_written = out.bytes() + io.output.map_or(0, |_| texture_bytes(out));
                        d
                    } else {
                        let mut b = bufs.clone();
                        b.extend([weights, &self.bias, &out.buffer]);
                        gpu.kernels.dispatch(name, &spec, params, &b, grid)?
                    });
                }
                let mut parts = parts.into_iter();
                let first = parts.next().expect("a supported layer has at least one chunk");
                Ok(first.chain(parts))
            }
            ConvKernel::Coop { mt, nt, rt } => {
                let tile = gpu.coop_tile.unwrap_or(16);
                let co_pad = self.coop_co_pad(nt, tile);
                let mut spec = shaped();
                spec.0.extend([
                    ("CO_PAD", co_pad as f64),
                    ("MT", mt as f64),
                    ("NT", nt as f64),
                    ("RT", rt as f64),
                    ("SG", coop_subgroup(gpu) as f64),
                    ("T", tile as f64),
                ]);
                let weights = self.coop_buffer(gpu, nt, tile);
                bufs.extend([&weights, &self.bias, &out.buffer]);
                // One subgroup per tile of mt * T pixels and nt * T output channels.
                gpu.kernels.dispatch(
                    "nn/conv3x3_coop",
                    &spec,
                    bytemuck::bytes_of(&shaped_params),
                    &bufs,
                    Grid::Invocations([
                        w.div_ceil(mt * tile) * coop_subgroup(gpu),
                        h.div_ceil(rt),
                        co_pad / (nt * tile),
                    ]),
                )
            }
        }
    }

    /// The uniform weights of the blocked (`positions` 9) or Winograd (16) kernel for
    /// output block `cob`, one buffer per output range of [`Conv3x3::blocked_chunks`] (a
    /// full 64 KiB array each, zero beyond the packed weights), stored as `storage`,
    /// uploaded on first use.
    fn blocked_buffers(
        &self,
        gpu: &Gpu,
        positions: u32,
        cob: u32,
        storage: WeightStorage,
    ) -> Result<Vec<wgpu::Buffer>> {
        let mut cache = self.blocked.lock().unwrap();
        if let Some(b) = cache.get(&(positions, cob, storage)) {
            return Ok(b.clone());
        }
        let cin: u32 = self.input_channels.iter().sum();
        let per_out = (cin * 9) as usize;
        let mut buffers = Vec::new();
        for (base, count) in self.blocked_chunks(positions, cob) {
            // The chunk's output channels as a layer of their own.
            let lo = base * 4;
            let hi = ((base + count) * 4).min(self.cout);
            let (mut packed, _) = Self::pack_strided(
                &self.name,
                &self.weight[lo as usize * per_out..hi as usize * per_out],
                &self.bias_host[lo as usize..hi as usize],
                &self.input_channels,
                hi - lo,
                count.div_ceil(cob) * cob,
                positions,
            )?;
            packed.resize(BLOCKED_MAX_WEIGHTS as usize * 4, 0.0);
            let bytes: Vec<u8> = match storage {
                WeightStorage::F32 => bytemuck::cast_slice(&packed).to_vec(),
                WeightStorage::F16 => {
                    // As the tensors' f16 uploads: consecutive halves, the first in the low
                    // half of each u32 (`unpack2x16float`); the same 64 KiB array.
                    let mut half: Vec<half::f16> = packed.iter().map(|&v| half::f16::from_f32(v)).collect();
                    if let Some(i) = half.iter().position(|h| !h.is_finite()) {
                        return Err(Error::Invalid(format!(
                            "conv3x3 '{}': packed weight {i} ({}) is beyond f16's range, which the \
                             f16 precision stores it in",
                            self.name, packed[i]
                        )));
                    }
                    half.resize(packed.len() * 2, half::f16::ZERO);
                    bytemuck::cast_slice(&half).to_vec()
                }
            };
            use wgpu::util::DeviceExt;
            buffers.push(gpu.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(&format!(
                    "subpixel.{}.weight.p{positions}.cob{cob}.{}.from{base}",
                    self.name,
                    storage.name()
                )),
                contents: bytemuck::cast_slice(&bytes),
                usage: wgpu::BufferUsages::UNIFORM,
            }));
        }
        cache.insert((positions, cob, storage), buffers.clone());
        Ok(buffers)
    }
}

/// Size in bytes of each conv kernel's `Params` as the Rust side lays it out.
pub const PARAM_SIZES: &[(&str, usize)] = &[
    ("nn/conv3x3", std::mem::size_of::<ConvParams>()),
    ("nn/conv3x3_blocked", std::mem::size_of::<ShapedParams>()),
    ("nn/conv3x3_winograd", std::mem::size_of::<ShapedParams>()),
    ("nn/conv3x3_coop", std::mem::size_of::<ShapedParams>()),
    ("nn/to_texture", std::mem::size_of::<ToTextureParams>()),
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kernel_names_round_trip() {
        for k in std::iter::once(ConvKernel::Generic)
            .chain(ConvKernel::blocked_tilings())
            .chain(ConvKernel::winograd_tilings())
            .chain(ConvKernel::texture_tilings())
            .chain(ConvKernel::coop_tilings())
        {
            assert_eq!(k.to_string().parse::<ConvKernel>().unwrap(), k);
        }
        for bad in [
            "px0-cob1",
            "px16-cob16",
            "px32-cob1",
            "px4",
            "cob4-px4",
            "fast",
            "coop-m3-n1-r1",
            "coop-m1-n4-r1",
            "coop-m1",
            "coop-m2-n2",
            "coop-m4-n2-r2",
            "coop-m1-n1-r1-x",
            "wino-tx3-cob1",
            "wino-tx16-cob4",
            "wino-tx2",
            "wino-tx1-cob8",
        ] {
            let e = bad.parse::<ConvKernel>().unwrap_err().to_string();
            assert!(e.contains(bad), "{e}");
        }
    }

    /// `nn/conv3x3_coop`'s arithmetic replayed on the CPU from [`Conv3x3::pack_coop`]'s
    /// layout: per row tile of 16 pixels and output tile of 16 channels, the bias, then for
    /// each input block of 16 channels the staged rows (zero outside the image and beyond
    /// the input's channels) and per tap the 16x16 product of the f16-rounded pixel window
    /// and weights, summed in f32. It matches the f64 CPU reference within
    /// [`COOP_TOLERANCE`] on shapes with partial tiles, padded channels and several inputs,
    /// which checks the packing and the kernel's indexing; what it cannot check is the
    /// driver's matrix arithmetic, which the autotuner checks on the device
    /// ([`Conv3x3::output_error`]).
    #[test]
    fn coop_packing_and_tiling_replayed_on_the_cpu_match_the_reference() {
        use crate::nn::reference::{self, HostTensor};
        let f16 = |v: f32| half::f16::from_f32(v.clamp(-65504.0, 65504.0)).to_f32();
        type Shape = (&'static [u32], u32, (u32, u32), u32, u32);
        let shapes: &[Shape] = &[
            (&[15, 4, 15, 3], 16, (33, 5), 2, 1),
            (&[32, 3], 28, (19, 4), 1, 2),
            (&[8], 40, (40, 3), 4, 2),
            (&[5], 3, (1, 3), 1, 1),
        ];
        for (i, &(split, cout, (w, h), mt, nt)) in shapes.iter().enumerate() {
            for tile in [16u32, 8] {
                let cin: u32 = split.iter().sum();
                let mut seed = 12345u32 + i as u32;
                let mut rnd = || {
                    seed = seed.wrapping_mul(1664525).wrapping_add(1013904223);
                    (seed >> 8) as f32 / (1u32 << 24) as f32 * 2.0 - 1.0
                };
                let inputs: Vec<HostTensor> = split
                    .iter()
                    .map(|&c| {
                        let data: Vec<f32> = (0..w * h * c).map(|_| rnd()).collect();
                        HostTensor::from_fn(w, h, c, |x, y, ch| data[((y * w + x) * c + ch) as usize])
                    })
                    .collect();
                let weight: Vec<f32> = (0..cout * cin * 9).map(|_| rnd() * 0.5).collect();
                let bias: Vec<f32> = (0..cout).map(|_| rnd() * 0.5).collect();
                let co_pad = cout.div_ceil(nt * tile) * nt * tile;
                let packed: Vec<f32> = Conv3x3::pack_coop(&weight, split, cout, tile, co_pad)
                    .into_iter()
                    .map(f16)
                    .collect();
                let mut got = HostTensor::zeros(w, h, cout);
                for y in 0..h {
                    for x0 in (0..w).step_by((mt * tile) as usize) {
                        for co_tile in 0..co_pad / tile {
                            for m in 0..mt {
                                // acc[r][c]: pixel x0 + tile m + r, output channel tile co_tile + c.
                                let mut acc = vec![vec![0.0f32; tile as usize]; tile as usize];
                                for (c, col) in (0..tile).zip(0..) {
                                    let co = co_tile * tile + c;
                                    let b = if co < cout { bias[co as usize] } else { 0.0 };
                                    acc.iter_mut().for_each(|row| row[col] = b);
                                }
                                let mut blk = 0;
                                for (k, inp) in inputs.iter().enumerate() {
                                    for b in 0..split[k].div_ceil(tile) {
                                        // staged[row][px][ch], px = x - x0 + 1.
                                        let row_px = mt * tile + 2;
                                        let staged = |row: u32, px: u32, ch: u32| {
                                            let (xx, yy) =
                                                (x0 as i32 + px as i32 - 1, y as i32 + row as i32 - 1);
                                            let ci = b * tile + ch;
                                            if xx < 0
                                                || yy < 0
                                                || xx >= w as i32
                                                || yy >= h as i32
                                                || ci >= split[k]
                                            {
                                                0.0
                                            } else {
                                                f16(inp.at(xx as u32, yy as u32, ci))
                                            }
                                        };
                                        for tap in 0..9u32 {
                                            let (ty, tx) = (tap / 3, tap % 3);
                                            for (r, acc_row) in acc.iter_mut().enumerate() {
                                                let px = m * tile + tx + r as u32;
                                                assert!(px < row_px);
                                                for (c, a) in acc_row.iter_mut().enumerate() {
                                                    for kk in 0..tile {
                                                        let wi = ((blk * 9 + tap) * tile + kk) * co_pad
                                                            + co_tile * tile
                                                            + c as u32;
                                                        *a += staged(ty, px, kk) * packed[wi as usize];
                                                    }
                                                }
                                            }
                                        }
                                        blk += 1;
                                    }
                                }
                                for (r, acc_row) in acc.iter().enumerate() {
                                    let x = x0 + m * tile + r as u32;
                                    for (c, &a) in acc_row.iter().enumerate() {
                                        let co = co_tile * tile + c as u32;
                                        if x < w && co < cout {
                                            got.set(x, y, co, a);
                                        }
                                    }
                                }
                            }
                        }
                    }
                }
                let hin: Vec<&HostTensor> = inputs.iter().collect();
                let want = reference::conv3x3(&hin, &weight, &bias, cout, Activation::None);
                let scale = want.data.iter().fold(1.0f32, |m, v| m.max(v.abs()));
                let err = got
                    .data
                    .iter()
                    .zip(&want.data)
                    .fold(0.0f32, |m, (g, r)| m.max((g - r).abs() / scale));
                assert!(
                    err <= COOP_TOLERANCE,
                    "{split:?}->{cout} {w}x{h} m{mt} n{nt} t{tile}: error {err:e}"
                );
                // And the rounding is real: f16 operands are not f32 ones.
                assert!(err > 1e-6, "{split:?}->{cout}: error {err:e}");
            }
        }
    }

    /// Winograd's F(2x2, 3x3) with [`winograd_weights`]: `A^T [U . (B^T d B)] A` of a 4x4
    /// input patch `d` equals the four outputs of the direct 3x3 correlation, for random
    /// kernels and patches (the transforms written out independently of the kernel's).
    #[test]
    fn winograd_transform_gives_the_direct_correlation() {
        let mut seed = 99u32;
        let mut rnd = || {
            seed = seed.wrapping_mul(1664525).wrapping_add(1013904223);
            (seed >> 8) as f32 / (1u32 << 24) as f32 * 2.0 - 1.0
        };
        const BT: [[f32; 4]; 4] = WINOGRAD_BT;
        const AT: [[f32; 4]; 2] = WINOGRAD_AT;
        for _ in 0..100 {
            let g: [f32; 9] = std::array::from_fn(|_| rnd());
            let d: [[f32; 4]; 4] = std::array::from_fn(|_| std::array::from_fn(|_| rnd()));
            let u = winograd_weights(&g);
            // V = B^T d B, M = U . V, Y = A^T M A.
            let v = |i: usize, j: usize| -> f32 {
                (0..4)
                    .map(|k| (0..4).map(|l| BT[i][k] * d[k][l] * BT[j][l]).sum::<f32>())
                    .sum()
            };
            for r in 0..2 {
                for c in 0..2 {
                    let y: f32 = (0..4)
                        .map(|i| {
                            (0..4)
                                .map(|j| AT[r][i] * u[i * 4 + j] * v(i, j) * AT[c][j])
                                .sum::<f32>()
                        })
                        .sum();
                    let direct: f32 = (0..3)
                        .map(|ky| (0..3).map(|kx| g[ky * 3 + kx] * d[r + ky][c + kx]).sum::<f32>())
                        .sum();
                    assert!((y - direct).abs() <= 1e-5, "({r}, {c}): {y} against {direct}");
                }
            }
        }
    }

    /// The strided packing puts each weight where the blocked kernel reads it and zeroes
    /// the padding columns.
    #[test]
    fn strided_packing_places_every_weight() {
        let (split, cout) = ([3u32, 5], 6u32);
        let cin: u32 = split.iter().sum();
        let w: Vec<f32> = (0..cout * cin * 9).map(|i| i as f32 + 1.0).collect();
        let stride = 4; // cout4 = 2, rounded up to a block of 4
        let (p, _) =
            Conv3x3::pack_strided("t", &w, &vec![0.0; cout as usize], &split, cout, stride, 9).unwrap();
        let cin4 = 1 + 2;
        assert_eq!(p.len(), (9 * cin4 * stride * 16) as usize);
        let slot = |li: u32| if li < 3 { li } else { 4 + li - 3 };
        let mut seen = 0;
        for co in 0..cout {
            for li in 0..cin {
                for tap in 0..9 {
                    let pi = slot(li);
                    let idx = (((tap * cin4 + pi / 4) * stride + co / 4) * 4 + pi % 4) * 4 + co % 4;
                    assert_eq!(p[idx as usize], w[((co * cin + li) * 9 + tap) as usize]);
                    seen += 1;
                }
            }
        }
        assert_eq!(p.iter().filter(|&&v| v != 0.0).count(), seen);
    }
}
