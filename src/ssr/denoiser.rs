//! The embeddable denoiser: the caller's device, the caller's frame buffers, one output
//! texture.

use bytemuck::{Pod, Zeroable};

use super::config::{
    ATROUS_DECAY, ATROUS_DEPTH_SIGMA, ATROUS_EPS, ATROUS_LEVELS, ATROUS_NORMAL_SQUARINGS, CEILING_DECAY,
    EmissionSource, EscapedSource, ExposureMode, MEAN_EPS, MEAN_HI, MEAN_LO, MEAN_RING, MEAN_TILE,
    MeanCorrection,
};
pub use super::network::Granularity;
use super::network::StepCost;
use super::network::{Network, exposure_groups};
use super::weights::Weights;
use crate::error::{Error, Result};
pub use crate::frame::FrameInputs;
use crate::frame::HostFrame;
use crate::gpu::time_dispatch;
use crate::gpu::{Bound, Dispatch, Gpu, Grid, Profiler, Specialisation};
use crate::nn::HostTensor;
use crate::nn::autotune::{self, AtrousPixels, EngineOptions};

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PackParams {
    width: u32,
    height: u32,
    padded_width: u32,
    padded_height: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ExposurePartialParams {
    width: u32,
    height: u32,
    padded_width: u32,
    padded_height: u32,
    groups: u32,
    _pad: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ExposureFinalParams {
    groups: u32,
    first: u32,
    decay: f32,
    _pad: u32,
}

/// The exposure pass: the reduction over the caller's buffers, then the update of the
/// exposure, as on a first frame (`[1]`) or a later one (`[2]`).
type ExposureDispatches = [Dispatch; 3];

/// The caller's buffers a bound [`InputPasses`] reads: the six, the background and the
/// emission.
type InputKey = ([wgpu::Buffer; 6], Option<wgpu::Buffer>, Option<wgpu::Buffer>);

/// The dispatches bound to the caller's buffers: exposure, input packing, and the output
/// store (which reads the optional background).
struct InputPasses {
    exposure: Option<ExposureDispatches>,
    pack: [Dispatch; 2],
    /// The mean correction's sums (config `mean_correction = "tiles"` or `"atrous"`): one
    /// dispatch per ring slot, then the same on the first frame after a reset (clearing the
    /// others).
    mean: Option<Vec<Dispatch>>,
    /// With `"atrous"`, the filter's levels after the sums, the last writing the factors, for
    /// a frame whose sums went to the first or the second history pair (none for tiles).
    mean_filter: Vec<Vec<Dispatch>>,
    store: Dispatch,
    /// Whether `store` composites a background.
    background: bool,
}

/// The parameters of the output passes, `ssr/tile_means`, `ssr/mean_history` and
/// `ssr/store_output` (which leaves `slot` and `first` unused).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct OutputParams {
    width: u32,
    height: u32,
    padded_width: u32,
    c4: u32,
    tiles_x: u32,
    tiles_y: u32,
    slot: u32,
    first: u32,
}

/// The names of the [`ATROUS_LEVELS`] levels of the mean correction's filter, as passes
/// (profiler scopes, `step_costs`).
const ATROUS_LABELS: [&str; ATROUS_LEVELS as usize] = [
    "mean atrous 0",
    "mean atrous 1",
    "mean atrous 2",
    "mean atrous 3",
    "mean atrous 4",
];

/// The parameters of `ssr/mean_atrous`: the frame size and the level's tap spacing.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct AtrousParams {
    width: u32,
    height: u32,
    step: u32,
    _pad: u32,
}

/// The mean correction's state: the ring of per-tile sums of the last frames and the
/// factors the output pass applies. `"atrous"` keeps its factors per pixel (tiles of one
/// pixel, which the output pass applies as they are), its sums in `filter` instead of a ring.
struct MeanState {
    /// Tile side in pixels (1 for `"atrous"`).
    side: u32,
    tiles: (u32, u32),
    /// The ring of tile sums ([`MEAN_RING`] slots); none for `"atrous"`.
    ring: Option<wgpu::Buffer>,
    factors: wgpu::Buffer,
    filter: Option<AtrousBuffers>,
    /// The ring slot of the next frame (for `"atrous"`, its parity is the history pair
    /// the frame's sums go to).
    slot: u32,
}

/// The data of the `"atrous"` mean correction: rgba32float textures, the sums as one
/// texture of the samples' part (S) and one of the reconstruction's (R). Textures, because
/// the filter's 25 taps per pixel and level are then texel fetches, which CPU drivers
/// vectorise (storage-buffer loads there run lane by lane).
struct AtrousBuffers {
    /// The motion-carried sums: each frame writes one pair from the other
    /// (`ssr/mean_history`); the filter's first level then overwrites the other, which it no
    /// longer needs.
    sums: [SumTextures; 2],
    /// The filter's second pair.
    scratch: SumTextures,
    /// The frame's sanitised normals (xyz) and depths (w), left by `ssr/mean_history` for
    /// the filter.
    guide: wgpu::TextureView,
}

/// One (S, R) pair of the mean correction's sums.
struct SumTextures {
    s: wgpu::TextureView,
    r: wgpu::TextureView,
}

impl SumTextures {
    fn new(gpu: &Gpu, label: &str, width: u32, height: u32) -> Self {
        let view = |part: &str| sum_texture(gpu, &format!("{label}_{part}"), width, height);
        Self {
            s: view("s"),
            r: view("r"),
        }
    }
}

/// A view of a new `width x height` rgba32float texture for the mean correction.
fn sum_texture(gpu: &Gpu, label: &str, width: u32, height: u32) -> wgpu::TextureView {
    gpu.storage_texture(label, width, height, wgpu::TextureFormat::Rgba32Float)
        .create_view(&Default::default())
}

/// Every kernel the denoiser runs: [`Denoiser::new`] checks them against the device's
/// limits (they all fit WebGPU's defaults, `wgpu::Limits::default()`).
pub const KERNELS_USED: &[&str] = &[
    "ssr/pack_inputs",
    "ssr/pack_mt",
    "ssr/exposure_partial",
    "ssr/exposure_final",
    "ssr/warp_history",
    "ssr/store_output",
    "ssr/tile_means",
    "ssr/mean_history",
    "ssr/mean_atrous",
    "nn/conv3x3",
    "nn/conv3x3_blocked",
    "nn/conv3x3_winograd",
    "nn/tfa_blend",
    "nn/resample2x",
    "nn/remodulate",
];

/// Size in bytes of the SSR kernels' uniform `Params`, for the naga layout test.
pub const PARAM_SIZES: &[(&str, usize)] = &[
    ("ssr/pack_inputs", std::mem::size_of::<PackParams>()),
    ("ssr/pack_mt", std::mem::size_of::<PackParams>()),
    ("ssr/store_output", std::mem::size_of::<OutputParams>()),
    ("ssr/tile_means", std::mem::size_of::<OutputParams>()),
    ("ssr/mean_history", std::mem::size_of::<OutputParams>()),
    ("ssr/mean_atrous", std::mem::size_of::<AtrousParams>()),
    (
        "ssr/exposure_partial",
        std::mem::size_of::<ExposurePartialParams>(),
    ),
    ("ssr/exposure_final", std::mem::size_of::<ExposureFinalParams>()),
    (
        "ssr/warp_history",
        std::mem::size_of::<super::network::WarpHistoryParams>(),
    ),
    ("ssr/fold_emission", std::mem::size_of::<super::FoldParams>()),
];

/// The SSR denoiser, embeddable in any wgpu renderer.
///
/// ```no_run
/// # fn demo(device: &wgpu::Device, queue: &wgpu::Queue, inputs: subpixel::ssr::FrameInputs<'_>)
/// #     -> subpixel::Result<()> {
/// use subpixel::ssr::{Denoiser, Weights};
/// let weights = Weights::load("weights/ssr.safetensors")?;
/// let mut denoiser = Denoiser::new(device, queue, &weights, 1920, 1080)?;
/// let mut encoder = device.create_command_encoder(&Default::default());
/// let output: &wgpu::Texture = denoiser.denoise(&mut encoder, &inputs)?; // rgba32float, linear HDR
/// queue.submit([encoder.finish()]);
/// # Ok(()) }
/// ```
pub struct Denoiser {
    gpu: Gpu,
    weights: Weights,
    net: Network,
    width: u32,
    height: u32,
    output: wgpu::Texture,
    /// The passes bound to the caller's buffers (six, and the background when given).
    inputs: Bound<InputKey, InputPasses>,
    /// The denoiser's own input buffers for [`Denoiser::denoise_host`] (the six and a
    /// background), made on first use; never the caller's buffers of an earlier
    /// [`Denoiser::denoise`].
    host_inputs: Option<Vec<wgpu::Buffer>>,
    sanitized: wgpu::Buffer,
    /// Config `mean_correction = "tiles"`: its buffers and ring position.
    mean: Option<MeanState>,
    first: bool,
    frames: u64,
    options: EngineOptions,
}

impl Denoiser {
    /// A denoiser for `width x height` frames on the caller's device. Fails (naming the
    /// kernel and the limit) when the device's limits are below what a kernel needs; every
    /// kernel fits WebGPU's default limits.
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        weights: &Weights,
        width: u32,
        height: u32,
    ) -> Result<Self> {
        let gpu = Gpu::from_device(device, queue, device.adapter_info());
        Self::with_gpu(&gpu, weights, width, height)
    }

    /// A denoiser on a [`Gpu`] context. Each convolution runs on the kernel the
    /// autotuner picks for this adapter ([`crate::nn::autotune`]: measured once per layer
    /// shape and cached on disk), or the one `SUBPIXEL_CONV_KERNEL` fixes; activations are
    /// f32 unless `SUBPIXEL_PRECISION` says `f16` or `auto`; the pooled encoder levels are
    /// pooled on load or by passes as measured faster, unless `SUBPIXEL_POOLING` says
    /// `load` or `pass`.
    pub fn with_gpu(gpu: &Gpu, weights: &Weights, width: u32, height: u32) -> Result<Self> {
        Self::with_options(gpu, weights, width, height, EngineOptions::default())
    }

    /// [`Denoiser::with_gpu`] with the engine's choices made by `options` (e.g.
    /// `KernelChoice::Fixed(..)` for reproducible timings, `Precision::F16` for half the
    /// activation bytes).
    pub fn with_options(
        gpu: &Gpu,
        weights: &Weights,
        width: u32,
        height: u32,
        options: EngineOptions,
    ) -> Result<Self> {
        if width == 0 || height == 0 {
            return Err(Error::shape(
                "denoiser",
                format!("frame size {width}x{height} must be non-zero"),
            ));
        }
        gpu.kernels.check_limits("the denoiser", KERNELS_USED)?;
        let mean_correction = weights.config.mean_correction()?;
        if mean_correction == MeanCorrection::Atrous {
            // A bad SUBPIXEL_ATROUS_PIXELS fails here, before the network is built (and
            // tuned), rather than at the first frame.
            options.atrous_pixels.resolve()?;
        }
        // The engine pads frames internally (4 for a 3-level U-Net, 8 for 4 levels).
        let pad = weights.config.pad_multiple();
        let net = Network::new(
            gpu,
            weights,
            width.next_multiple_of(pad),
            height.next_multiple_of(pad),
            options,
        )?;
        let output = Self::make_output(gpu, width, height);
        let mean = match mean_correction {
            MeanCorrection::None => None,
            kind => {
                let (side, atrous) = match kind {
                    MeanCorrection::Tiles { side } => (side, false),
                    _ => (1, true),
                };
                let tiles = (width.div_ceil(side), height.div_ceil(side));
                let n = tiles.0 as u64 * tiles.1 as u64;
                let buffer = |label: &str, size: u64| {
                    gpu.device.create_buffer(&wgpu::BufferDescriptor {
                        label: Some(label),
                        size,
                        usage: wgpu::BufferUsages::STORAGE,
                        mapped_at_creation: false,
                    })
                };
                Some(MeanState {
                    side,
                    tiles,
                    ring: (!atrous).then(|| buffer("subpixel.ssr.mean_ring", n * MEAN_RING as u64 * 32)),
                    factors: buffer("subpixel.ssr.mean_factors", n * 16),
                    filter: atrous.then(|| AtrousBuffers {
                        sums: [
                            SumTextures::new(gpu, "subpixel.ssr.mean_sums_a", width, height),
                            SumTextures::new(gpu, "subpixel.ssr.mean_sums_b", width, height),
                        ],
                        scratch: SumTextures::new(gpu, "subpixel.ssr.mean_filter", width, height),
                        guide: sum_texture(gpu, "subpixel.ssr.mean_guide", width, height),
                    }),
                    slot: 0,
                })
            }
        };
        Ok(Self {
            gpu: gpu.clone(),
            weights: weights.clone(),
            net,
            width,
            height,
            output,
            inputs: Bound::new(),
            host_inputs: None,
            sanitized: gpu.counter_buffer("subpixel.ssr.sanitized"),
            mean,
            first: true,
            frames: 0,
            options,
        })
    }

    fn make_output(gpu: &Gpu, width: u32, height: u32) -> wgpu::Texture {
        gpu.storage_texture(
            "subpixel.ssr.output",
            width,
            height,
            wgpu::TextureFormat::Rgba32Float,
        )
    }

    /// The output store: the network's output, cropped, into the output texture, composited
    /// with the background (`background + (1 - coverage) x output`) when the caller gives one,
    /// the output first scaled by the mean correction's factors when the config has it.
    /// The directly seen emission the output pass adds: the caller's `emission` for a model
    /// of config emission "background" (an error naming the buffers without it or without a
    /// background), none for others.
    fn emission_input<'b>(&self, inputs: &FrameInputs<'b>) -> Result<Option<&'b wgpu::Buffer>> {
        if self.net.config.emission_source()? == EmissionSource::Network {
            return Ok(None);
        }
        match (inputs.background, inputs.emission) {
            (Some(_), Some(e)) => Ok(Some(e)),
            _ => Err(Error::shape(
                "denoiser input",
                "the model takes the directly seen emission from the output pass (config emission \"background\"): \
                 give FrameInputs::emission and FrameInputs::background (and a colour without the samples' \
                 first-hit emission)",
            )),
        }
    }

    fn store_dispatch(
        &self,
        background: Option<&wgpu::Buffer>,
        emission: Option<&wgpu::Buffer>,
    ) -> Result<Dispatch> {
        let params = self.output_params(0, false);
        let view = self.output.create_view(&Default::default());
        let mut resources = vec![
            self.net.output().buffer.as_entire_binding(),
            wgpu::BindingResource::TextureView(&view),
        ];
        // Bindings 3 and 4 (background, counter) are not in the layout without a background:
        // any buffer holds their places before the factors (binding 5).
        let b = background.unwrap_or(&self.sanitized);
        resources.push(b.as_entire_binding());
        resources.push(self.sanitized.as_entire_binding());
        // Binding 5 (factors) holds its place for the emission (binding 6) without a mean
        // correction.
        match (&self.mean, emission) {
            (Some(m), _) => resources.push(m.factors.as_entire_binding()),
            (None, Some(_)) => resources.push(self.sanitized.as_entire_binding()),
            (None, None) => {}
        }
        if let Some(e) = emission {
            resources.push(e.as_entire_binding());
        }
        self.gpu.kernels.dispatch_with(
            "ssr/store_output",
            &Specialisation(vec![
                ("BACKGROUND", background.is_some() as u32 as f64),
                ("EMISSION", emission.is_some() as u32 as f64),
                ("MEAN", self.mean.is_some() as u32 as f64),
                ("TILE", self.mean.as_ref().map_or(MEAN_TILE, |m| m.side) as f64),
            ]),
            bytemuck::bytes_of(&params),
            &resources,
            Grid::pixels(self.width, self.height),
        )
    }

    fn output_params(&self, slot: u32, first: bool) -> OutputParams {
        let tiles = self.mean.as_ref().map_or((0, 0), |m| m.tiles);
        OutputParams {
            width: self.width,
            height: self.height,
            padded_width: self.net.width,
            c4: self.net.output().c4(),
            tiles_x: tiles.0,
            tiles_y: tiles.1,
            slot,
            first: first as u32,
        }
    }

    /// The mean correction's sums for each ring slot, then for each slot on a first frame
    /// (`None` without the option): `ssr/tile_means`, or with `"atrous"` `ssr/mean_history`
    /// into the history pair of the slot's parity, from the other.
    fn mean_dispatches(&self, inputs: &FrameInputs<'_>) -> Result<Option<Vec<Dispatch>>> {
        let (color_mask, background) = (inputs.color_mask, inputs.background);
        let Some(m) = &self.mean else {
            return Ok(None);
        };
        // A model of config escaped "background" is fed only the samples that hit the scene
        // (and always a background, `input_passes`).
        let escaped = self.net.config.escaped_source()? == EscapedSource::Background;
        let escaped = ("ESCAPED", escaped as u32 as f64);
        if let Some(a) = &m.filter {
            let spec = Specialisation(vec![
                ("BACKGROUND", background.is_some() as u32 as f64),
                escaped,
                ("DECAY", ATROUS_DECAY as f64),
            ]);
            let mut out = Vec::new();
            for first in [false, true] {
                for slot in 0..MEAN_RING {
                    let (now, prev) = (&a.sums[slot as usize % 2], &a.sums[1 - slot as usize % 2]);
                    let view = wgpu::BindingResource::TextureView;
                    let mut resources = vec![
                        self.net.output().buffer.as_entire_binding(),
                        color_mask.as_entire_binding(),
                        inputs.motion.as_entire_binding(),
                        inputs.normal_metallic.as_entire_binding(),
                        inputs.albedo_depth.as_entire_binding(),
                        view(&prev.s),
                        view(&prev.r),
                        view(&now.s),
                        view(&now.r),
                        view(&a.guide),
                    ];
                    resources.extend(background.map(|b| b.as_entire_binding()));
                    out.push(self.gpu.kernels.dispatch_with(
                        "ssr/mean_history",
                        &spec,
                        bytemuck::bytes_of(&self.output_params(slot, first)),
                        &resources,
                        Grid::pixels(self.width, self.height),
                    )?);
                }
            }
            return Ok(Some(out));
        }
        let spec = Specialisation(vec![
            ("BACKGROUND", background.is_some() as u32 as f64),
            escaped,
            ("TILE", m.side as f64),
            ("RING", MEAN_RING as f64),
            ("EPS", MEAN_EPS as f64),
            ("LO", MEAN_LO as f64),
            ("HI", MEAN_HI as f64),
        ]);
        let mut resources = vec![
            self.net.output().buffer.as_entire_binding(),
            color_mask.as_entire_binding(),
            m.ring.as_ref().expect("tiles have a ring").as_entire_binding(),
            m.factors.as_entire_binding(),
        ];
        resources.extend(background.map(|b| b.as_entire_binding()));
        let mut out = Vec::new();
        for first in [false, true] {
            for slot in 0..MEAN_RING {
                out.push(self.gpu.kernels.dispatch_with(
                    "ssr/tile_means",
                    &spec,
                    bytemuck::bytes_of(&self.output_params(slot, first)),
                    &resources,
                    Grid::Workgroups([m.tiles.0, m.tiles.1, 1]),
                )?);
            }
        }
        Ok(Some(out))
    }

    /// With `"atrous"`, for sums in either history pair, the [`ATROUS_LEVELS`] levels of
    /// the mean correction's filter: from the sums into the other history pair (which the
    /// next frame no longer reads), then alternating between it and the scratch pair, the
    /// last writing the factors, guided by the normals and depths `ssr/mean_history` left;
    /// none otherwise. Each invocation filters the pixels the options fix, or the faster
    /// of the candidates timed here ([`AtrousPixels::Auto`]).
    fn mean_filter_dispatches(&self) -> Result<Vec<Vec<Dispatch>>> {
        let Some((m, ab)) = self.mean.as_ref().and_then(|m| m.filter.as_ref().map(|f| (m, f))) else {
            return Ok(Vec::new());
        };
        let px = match self.options.atrous_pixels.resolve()? {
            AtrousPixels::Fixed(px) => px,
            _ if !self.options.measures()? => AtrousPixels::DEFAULT,
            _ => self.fastest_atrous(ab, &m.factors)?,
        };
        (0..2)
            .map(|parity| self.mean_filter_levels(ab, parity, &m.factors, px))
            .collect()
    }

    /// The faster of [`AtrousPixels::CANDIDATES`] for this frame size on this adapter, by
    /// the sum of the filter's levels' median times (measured once per process, and said
    /// when measured: later calls, at each rebinding of the caller's buffers, reuse it).
    fn fastest_atrous(&self, ab: &AtrousBuffers, factors: &wgpu::Buffer) -> Result<u32> {
        let mut best: Option<(f64, u32)> = None;
        let (mut said, mut measured) = (Vec::new(), false);
        for px in AtrousPixels::CANDIDATES {
            let key = format!(
                "{} mean atrous {px} px {}x{}",
                self.gpu.describe(),
                self.width,
                self.height
            );
            let ms = autotune::timed_once(key, || {
                measured = true;
                let mut ms = 0.0;
                for d in self.mean_filter_levels(ab, 0, factors, px)? {
                    ms += time_dispatch(&self.gpu, &d, 1, autotune::TUNE_ITERATIONS)?
                        .0
                        .median_ms;
                }
                Ok(ms)
            })?;
            said.push(format!("{px} px {ms:.3} ms"));
            if best.is_none_or(|(b, _)| ms < b) {
                best = Some((ms, px));
            }
        }
        let (_, px) = best.expect("there are candidates");
        if measured {
            log::info!(
                "mean correction's a-trous filter at {}x{}: {px} pixels per invocation ({})",
                self.width,
                self.height,
                said.join(", ")
            );
        }
        Ok(px)
    }

    fn mean_filter_levels(
        &self,
        ab: &AtrousBuffers,
        parity: usize,
        factors: &wgpu::Buffer,
        px: u32,
    ) -> Result<Vec<Dispatch>> {
        let (sums, other, scratch) = (&ab.sums[parity], &ab.sums[1 - parity], &ab.scratch);
        let view = wgpu::BindingResource::TextureView;
        let mut out = Vec::new();
        for level in 0..ATROUS_LEVELS {
            let last = level + 1 == ATROUS_LEVELS;
            let src = match level {
                0 => sums,
                l if l % 2 == 1 => other,
                _ => scratch,
            };
            let params = AtrousParams {
                width: self.width,
                height: self.height,
                step: 1 << level,
                _pad: 0,
            };
            let mut resources = vec![view(&src.s), view(&src.r), view(&ab.guide)];
            if last {
                resources.push(factors.as_entire_binding());
            } else {
                let dst = if level % 2 == 0 { other } else { scratch };
                resources.extend([view(&dst.s), view(&dst.r)]);
            }
            // `px` pixels a step apart per invocation: `step` invocations per `px` steps of
            // a row.
            let step = params.step;
            let columns = self.width.div_ceil(px * step) * step;
            out.push(self.gpu.kernels.dispatch_with(
                "ssr/mean_atrous",
                &Specialisation(vec![
                    ("PX", px as f64),
                    ("FINAL", last as u32 as f64),
                    ("SQUARINGS", ATROUS_NORMAL_SQUARINGS as f64),
                    ("DEPTH_SIGMA", ATROUS_DEPTH_SIGMA as f64),
                    ("EPS", ATROUS_EPS as f64),
                    ("LO", MEAN_LO as f64),
                    ("HI", MEAN_HI as f64),
                ]),
                bytemuck::bytes_of(&params),
                &resources,
                Grid::Invocations([columns, self.height, 1]),
            )?);
        }
        Ok(out)
    }

    /// What each pass of a frame costs, in execution order: `pack` (exposure and input
    /// packing; empty until the first frame bound the caller's buffers), the network's
    /// steps, `output` (the copy into the output texture, with the background when one is
    /// bound).
    pub fn step_costs(&self) -> Vec<StepCost> {
        let mut out = Vec::new();
        let px = self.width as u64 * self.height as u64 * 16;
        let mut background = false;
        if let Some(passes) = self.inputs.get() {
            background = passes.background;
            for d in passes.exposure.iter().flatten().chain(passes.pack.iter()) {
                out.push(StepCost {
                    stage: "pack",
                    label: d.kernel.trim_start_matches("ssr/").to_string(),
                    flops: 0,
                    bytes_read: d.bytes_read,
                    bytes_written: d.bytes_written,
                    matrix: false,
                });
            }
        }
        out.extend(self.net.step_costs());
        if let Some(m) = &self.mean {
            let reads = self.net.output().bytes() + px * if background { 2 } else { 1 };
            if m.filter.is_some() {
                // The motion, the last frame's sums and the caller's normals and depths read;
                // this frame's sums and the guide written (2 + 1 vec4 per pixel); each level
                // reads the sums and the guide once (its 25 taps from cache) and writes the
                // next sums or the factors.
                out.push(StepCost {
                    stage: "output",
                    label: "mean history".into(),
                    flops: 0,
                    bytes_read: reads + 5 * px,
                    bytes_written: 3 * px,
                    matrix: false,
                });
                for (level, label) in ATROUS_LABELS.into_iter().enumerate() {
                    let last = level + 1 == ATROUS_LEVELS as usize;
                    out.push(StepCost {
                        stage: "output",
                        label: label.into(),
                        // 25 taps: the weight (about 20 operations) and 8 multiply-adds
                        flops: 25 * 36 * (px / 16),
                        bytes_read: 3 * px,
                        bytes_written: if last { px } else { 2 * px },
                        matrix: false,
                    });
                }
            } else {
                out.push(StepCost {
                    stage: "output",
                    label: "mean tiles".into(),
                    flops: 0,
                    bytes_read: reads,
                    bytes_written: 0,
                    matrix: false,
                });
            }
        }
        out.push(StepCost {
            stage: "output",
            label: "store output".into(),
            flops: 0,
            bytes_read: self.net.output().bytes() + if background { px } else { 0 },
            bytes_written: px,
            matrix: false,
        });
        out
    }

    /// Frame width.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Frame height.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The weights in use.
    pub fn weights(&self) -> &Weights {
        &self.weights
    }

    /// The output texture (`rgba32float`, linear HDR radiance, `width x height`).
    pub fn output(&self) -> &wgpu::Texture {
        &self.output
    }

    /// The network (for inspection of intermediates and per-layer FLOPs).
    pub fn network(&self) -> &Network {
        &self.net
    }

    /// Forgets the history (call on a camera cut); the next frame starts afresh, exposure
    /// and the mean correction's sums of earlier frames included. Without it, history whose
    /// depth or normal disagrees with the new frame is rejected per pixel (version-2
    /// weights), but history that happens to agree is kept.
    pub fn reset(&mut self) {
        self.first = true;
    }

    /// Changes the frame size; reallocates and resets the history.
    pub fn resize(&mut self, width: u32, height: u32) -> Result<()> {
        if (width, height) == (self.width, self.height) {
            return Ok(());
        }
        *self = Self::with_options(&self.gpu, &self.weights, width, height, self.options)?;
        Ok(())
    }

    /// Frames denoised since creation.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// Records the reconstruction of one frame into `encoder` and returns the output
    /// texture (valid once the encoder's commands have run).
    pub fn denoise(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        inputs: &FrameInputs<'_>,
    ) -> Result<&wgpu::Texture> {
        self.denoise_profiled(encoder, inputs, None, Granularity::Stage)
    }

    /// [`Denoiser::denoise`] with GPU timestamp scopes (`pack`, `tfa`, `unet`, `output` or
    /// one per layer).
    pub fn denoise_profiled(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        inputs: &FrameInputs<'_>,
        mut profiler: Option<&mut Profiler>,
        granularity: Granularity,
    ) -> Result<&wgpu::Texture> {
        self.bind_inputs(inputs)?;
        let passes = self.inputs.get().expect("bound above");
        {
            let mut pass = Profiler::pass(encoder, "pack", profiler.as_deref_mut());
            if let Some(e) = &passes.exposure {
                e[0].record(&mut pass);
                e[if self.first { 1 } else { 2 }].record(&mut pass);
            }
            for d in &passes.pack {
                d.record(&mut pass);
            }
        }
        self.net
            .record(encoder, self.first, profiler.as_deref_mut(), granularity);
        // The output stage's dispatches, labelled as in `step_costs`: one timed pass for
        // the stage, or (per layer) one each.
        let (mean, levels) = match (&passes.mean, self.mean.as_mut()) {
            (Some(d), Some(m)) => {
                // On a first frame any slot will do: that dispatch clears the others (tiles)
                // or ignores the history (`"atrous"`). With `"atrous"`, the filter of the
                // history pair that slot wrote.
                let levels = passes.mean_filter.get(m.slot as usize % 2);
                let label = if levels.is_some() {
                    "mean history"
                } else {
                    "mean tiles"
                };
                let d = &d[(m.slot + if self.first { MEAN_RING } else { 0 }) as usize];
                m.slot = (m.slot + 1) % MEAN_RING;
                (Some((label, d)), levels)
            }
            _ => (None, None),
        };
        let output = mean
            .into_iter()
            .chain(ATROUS_LABELS.into_iter().zip(levels.into_iter().flatten()))
            .chain(std::iter::once(("store output", &passes.store)));
        if granularity == Granularity::Layer {
            for (label, d) in output {
                d.record(&mut Profiler::pass(encoder, label, profiler.as_deref_mut()));
            }
        } else {
            let mut pass = Profiler::pass(encoder, "output", profiler);
            for (_, d) in output {
                d.record(&mut pass);
            }
        }
        self.first = false;
        self.frames += 1;
        Ok(&self.output)
    }

    fn bind_inputs(&mut self, inputs: &FrameInputs<'_>) -> Result<()> {
        let key = (
            inputs.buffers().map(|b| b.clone()),
            inputs.background.cloned(),
            inputs.emission.cloned(),
        );
        let mut bound = std::mem::take(&mut self.inputs);
        let built = bound.get_or_build(key, || self.input_passes(inputs)).map(|_| ());
        // (Taken out so the build can borrow the denoiser; put back before any return.)
        self.inputs = bound;
        built
    }

    /// The passes reading the caller's buffers (exposure, packing, output store), after
    /// checking them.
    fn input_passes(&self, inputs: &FrameInputs<'_>) -> Result<InputPasses> {
        let need = self.width as u64 * self.height as u64 * 16;
        let named = inputs
            .buffers()
            .into_iter()
            .zip(FrameInputs::NAMES)
            .chain(inputs.background.map(|b| (b, "background")))
            .chain(inputs.emission.map(|b| (b, "emission")));
        for (b, name) in named {
            if b.size() < need {
                return Err(Error::shape(
                    "denoiser input",
                    format!(
                        "buffer '{name}' is {} bytes, expected at least {need} ({}x{} vec4<f32>)",
                        b.size(),
                        self.width,
                        self.height
                    ),
                ));
            }
            if !b.usage().contains(wgpu::BufferUsages::STORAGE) {
                return Err(Error::shape(
                    "denoiser input",
                    format!("buffer '{name}' lacks BufferUsages::STORAGE"),
                ));
            }
        }
        if self.net.config.escaped_source()? == EscapedSource::Background && inputs.background.is_none() {
            return Err(Error::shape(
                "denoiser input",
                "the model leaves the samples that escaped to the environment to the background (config escaped \
                 \"background\"): give FrameInputs::background (and a colour without the traced pixels whose \
                 samples escaped)",
            ));
        }
        let (a_t, mt, motion) = self.net.inputs();
        let params = PackParams {
            width: self.width,
            height: self.height,
            padded_width: self.net.width,
            padded_height: self.net.height,
        };
        let (partials, exposure, ratio) = self.net.exposure();
        let grid = Grid::pixels(self.net.width, self.net.height);
        let pack_a = self.gpu.kernels.dispatch(
            "ssr/pack_inputs",
            &Specialisation::none(),
            bytemuck::bytes_of(&params),
            &[
                inputs.color_mask,
                inputs.albedo_depth,
                inputs.normal_metallic,
                inputs.shadow_roughness,
                &a_t.buffer,
                &self.sanitized,
                &exposure.buffer,
            ],
            grid,
        )?;
        let pack_mt = self.gpu.kernels.dispatch(
            "ssr/pack_mt",
            &Specialisation::none(),
            bytemuck::bytes_of(&params),
            &[
                inputs.color_mask,
                inputs.transparent,
                inputs.motion,
                &mt.buffer,
                &motion.buffer,
                &self.sanitized,
            ],
            grid,
        )?;
        let mode = self.weights.config.exposure_mode()?;
        let e = match mode {
            ExposureMode::None => None,
            ExposureMode::Channel | ExposureMode::Shared => {
                let groups = exposure_groups(self.net.width, self.net.height);
                let partial = ExposurePartialParams {
                    width: self.width,
                    height: self.height,
                    padded_width: self.net.width,
                    padded_height: self.net.height,
                    groups,
                    _pad: [0; 3],
                };
                let reduce = self.gpu.kernels.dispatch(
                    "ssr/exposure_partial",
                    &Specialisation::none(),
                    bytemuck::bytes_of(&partial),
                    &[
                        inputs.color_mask,
                        inputs.albedo_depth,
                        inputs.shadow_roughness,
                        &partials.buffer,
                    ],
                    Grid::Workgroups([groups, 1, 1]),
                )?;
                let update = |first: bool| {
                    let params = ExposureFinalParams {
                        groups,
                        first: first as u32,
                        decay: CEILING_DECAY,
                        _pad: 0,
                    };
                    self.gpu.kernels.dispatch(
                        "ssr/exposure_final",
                        &Specialisation(vec![("SHARED", (mode == ExposureMode::Shared) as u32 as f64)]),
                        bytemuck::bytes_of(&params),
                        &[&partials.buffer, &exposure.buffer, &ratio.buffer],
                        Grid::Workgroups([1, 1, 1]),
                    )
                };
                Some([reduce, update(true)?, update(false)?])
            }
        };
        Ok(InputPasses {
            exposure: e,
            pack: [pack_a, pack_mt],
            mean: self.mean_dispatches(inputs)?,
            mean_filter: self.mean_filter_dispatches()?,
            store: self.store_dispatch(inputs.background, self.emission_input(inputs)?)?,
            background: inputs.background.is_some(),
        })
    }

    /// Number of input values changed by the sanitising since creation (blocks on a
    /// readback): non-finite values (replaced by 0) and values outside their channel's range
    /// (clamped to it: mask 0 or 1, albedo, transparent, depth, metallic and roughness in
    /// [0, 1], colour, shadow and the background where it is used in [0, 1e12], normals of
    /// unit length or 0).
    pub fn sanitized_count(&self) -> Result<u64> {
        let b = self.gpu.read_buffer(&self.sanitized, 0, 4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as u64)
    }

    /// Offline convenience: uploads a frame from host memory, denoises it, waits and
    /// returns the output (3 channels, `width x height`). A model of config albedo
    /// `footprint` takes the frame's footprint albedo ([`HostFrame::pack`]); one of config
    /// emission `background` is fed the colour without the samples' directly seen emission
    /// and the footprint's as `emission`, one of config escaped `background` the samples
    /// without those that escaped to the environment ([`HostFrame::fold_directly_seen`]).
    pub fn denoise_host(&mut self, frame: &HostFrame) -> Result<HostTensor> {
        let (w, h) = frame.size()?;
        if (w, h) != (self.width, self.height) {
            return Err(Error::shape(
                "denoiser",
                format!(
                    "frame is {w}x{h}, the denoiser was made for {}x{}",
                    self.width, self.height
                ),
            ));
        }
        // A model of config emission "background" gets the colour without the samples'
        // directly seen emission, and the footprint's for the output pass, one of config
        // escaped "background" the samples without those that escaped, as the frame loop
        // feeds them.
        let source = self.net.config.emission_source()?;
        let frame = frame.fold_directly_seen(source, self.net.config.escaped_source()?)?;
        let packed = frame.pack(self.net.config.albedo_source()?)?;
        let background = frame.pack_background()?;
        let emission = match source {
            EmissionSource::Background => frame.pack_emission(),
            EmissionSource::Network => None,
        };
        let bufs = self.host_buffers();
        let data = packed.iter().chain(&background).chain(&emission);
        for (b, data) in bufs.iter().zip(data) {
            self.gpu.queue.write_buffer(b, 0, bytemuck::cast_slice(data));
        }
        let used = 6 + background.is_some() as usize + emission.is_some() as usize;
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        let inputs = FrameInputs::from_slice(&bufs[..used])?;
        self.denoise(&mut enc, &inputs)?;
        self.gpu.queue.submit([enc.finish()]);
        self.gpu.wait()?;
        self.read_output()
    }

    /// Input buffers owned by the denoiser for [`Denoiser::denoise_host`] (made once): the
    /// six of [`FrameInputs::NAMES`], then the background and the emission.
    fn host_buffers(&mut self) -> Vec<wgpu::Buffer> {
        let size = self.width as u64 * self.height as u64 * 16;
        let gpu = &self.gpu;
        self.host_inputs
            .get_or_insert_with(|| {
                FrameInputs::NAMES
                    .iter()
                    .chain(&["background", "emission"])
                    .map(|n| {
                        gpu.device.create_buffer(&wgpu::BufferDescriptor {
                            label: Some(&format!("subpixel.ssr.host.{n}")),
                            size,
                            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                            mapped_at_creation: false,
                        })
                    })
                    .collect()
            })
            .clone()
    }

    /// Reads the output texture (`width x height`, 3 channels) back to the host.
    pub fn read_output(&self) -> Result<HostTensor> {
        let bytes = self.gpu.read_texture(&self.output)?;
        let rgba: Vec<f32> = bytemuck::pod_collect_to_vec(&bytes);
        Ok(HostTensor::from_fn(self.width, self.height, 3, |x, y, c| {
            rgba[((y * self.width + x) * 4 + c) as usize]
        }))
    }
}
