//! The product's frame: a scene traced at a quarter sample per pixel and reconstructed by
//! SSR, both recorded into one command buffer. `subpixel run`, `subpixel bench frame` and
//! the example viewer drive it; the data contract between its two halves is [`crate::frame`]
//! (the tracer writes [`crate::render::FrameBuffers`], the denoiser reads them as
//! [`crate::frame::FrameInputs`]), so neither [`crate::render`] nor [`crate::ssr`] imports
//! the other: this module joins them.
//!
//! ```no_run
//! # fn main() -> subpixel::Result<()> {
//! use subpixel::frame_loop::FrameLoop;
//! use subpixel::gpu::{Gpu, Profiler};
//! use subpixel::render::{FrameSettings, GpuScene, Mode, load_scene};
//! use subpixel::ssr::Weights;
//! let gpu = Gpu::new()?;
//! let scene = load_scene("builtin:cornell")?;
//! let gs = GpuScene::new(&gpu, &scene)?;
//! let (path, far) = scene.camera_path(&subpixel::render::CameraPathSpec::Static, 1, 8, 0, &gs.bvh)?;
//! let mut frames = FrameLoop::new(&gpu, &Weights::load("weights/ssr.safetensors")?, 128, 128)?;
//! let mut profiler = Profiler::new(&gpu, 16);
//! for f in 0..8 {
//!     let s = FrameSettings {
//!         background: scene.default_background(), // 0 here: the box has no sky
//!         ..FrameSettings::along(&path, f, Mode::Quarter, 1, far)
//!     };
//!     let mut encoder = gpu.device.create_command_encoder(&Default::default());
//!     frames.encode(&mut encoder, &gs, &s, Some(&mut profiler))?;
//!     profiler.submit(&gpu, encoder, None)?;
//! }
//! let denoised = frames.denoiser.read_output()?; // linear HDR, 128x128x3
//! # Ok(()) }
//! ```

use crate::error::{Error, Result};
use crate::gpu::{Gpu, Profiler};
use crate::nn::autotune::EngineOptions;
use crate::render::{FrameSettings, GpuScene, Tracer};
use crate::ssr::{AlbedoSource, Denoiser, EmissionFold, EmissionSource, EscapedSource, Granularity, Weights};

/// Camera rays per pixel axis of the background pass a model of config albedo "footprint"
/// needs in every frame, when the frame has no background of its own (2 x 2: the footprint
/// albedo's error is then that of a 2x2 supersampled G-buffer).
pub const FOOTPRINT_RAYS: u32 = 2;

/// The timed passes of a frame, in order: the tracer's (`background` only in frames with
/// a background), then the denoiser's.
pub const STAGES: [&str; 7] = ["gbuffer", "trace", "background", "pack", "tfa", "unet", "output"];

/// The path tracer and the denoiser of one render size.
pub struct FrameLoop {
    /// The 1/4-spp path tracer (its buffers hold the last frame's samples and G-buffers).
    pub tracer: Tracer,
    /// The SSR denoiser (its output holds the last frame's reconstruction).
    pub denoiser: Denoiser,
    /// For a model of config emission or escaped "background": the frame it is fed.
    fold: Option<EmissionFold>,
}

impl FrameLoop {
    /// A tracer and a denoiser (with `weights`) for `width x height` frames (and, for
    /// weights of config emission or escaped "background", the pass that takes the tracer's
    /// directly seen emission, or the samples that escaped, out of the colour they are fed,
    /// [`EmissionFold`]).
    pub fn new(gpu: &Gpu, weights: &Weights, width: u32, height: u32) -> Result<Self> {
        Self::with_options(gpu, weights, width, height, EngineOptions::default())
    }

    /// [`FrameLoop::new`] with the denoiser's engine choices made by `options`, as
    /// [`Denoiser::with_options`] takes them (e.g. `KernelChoice::Fixed(..)` for
    /// reproducible runs that tune nothing).
    pub fn with_options(
        gpu: &Gpu,
        weights: &Weights,
        width: u32,
        height: u32,
        options: EngineOptions,
    ) -> Result<Self> {
        let (emission, escaped) = (
            weights.config.emission_source()?,
            weights.config.escaped_source()?,
        );
        let fold = match (emission, escaped) {
            (EmissionSource::Network, EscapedSource::Network) => None,
            _ => Some(EmissionFold::new(gpu, width, height, emission, escaped)?),
        };
        Ok(Self {
            tracer: Tracer::new(gpu, width, height)?,
            denoiser: Denoiser::with_options(gpu, weights, width, height, options)?,
            fold,
        })
    }

    /// Records frame `s` of `scene` into `encoder`: the tracer's `gbuffer`, `trace` (and
    /// with `s.background` > 0, `background`) passes, then the denoiser's `pack`, `tfa`,
    /// `unet` and `output` passes, each timed by `profiler` when given (the output pass
    /// composites the background, [`crate::frame::FrameInputs`]). A model of config albedo
    /// "footprint" reads the background pass's footprint albedo in place of the G-buffer's,
    /// so its frames always have that pass (at least [`FOOTPRINT_RAYS`] rays per axis); so
    /// does a model of config emission "background", which is fed the colour without the
    /// samples' directly seen emission ([`EmissionFold`], a pass timed with `background`)
    /// and the footprint's as [`crate::frame::FrameInputs::emission`], and one of config
    /// escaped "background", fed the samples without those that escaped to the environment. Submit the encoder (e.g. [`Profiler::submit`]) to run it.
    pub fn encode(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        scene: &GpuScene,
        s: &FrameSettings,
        mut profiler: Option<&mut Profiler>,
    ) -> Result<()> {
        let footprint = self.denoiser.network().config.albedo_source()? == AlbedoSource::Footprint;
        let s = &FrameSettings {
            background: if footprint || self.fold.is_some() {
                s.background.max(FOOTPRINT_RAYS)
            } else {
                s.background
            },
            ..*s
        };
        self.tracer
            .encode_frame(encoder, scene, s, profiler.as_deref_mut())?;
        let b = &self.tracer.buffers;
        let mut inputs = b.inputs();
        if footprint {
            inputs.albedo_depth = &b
                .albedo_footprint
                .as_ref()
                .ok_or_else(|| {
                    Error::Invalid("frame loop: the background pass made no footprint albedo".into())
                })?
                .buffer;
        }
        if let Some(fold) = &mut self.fold {
            let missing =
                || Error::Invalid("frame loop: the background pass made no directly seen emission".into());
            let (Some(bg), Some(se), Some(ef)) = (&b.background, &b.sample_emission, &b.emission_footprint)
            else {
                return Err(missing());
            };
            let d = fold.dispatch(&b.color_mask.buffer, &se.buffer)?;
            d.record(&mut Profiler::pass(
                encoder,
                "background",
                profiler.as_deref_mut(),
            ));
            inputs.color_mask = &fold.color_mask.buffer;
            inputs.background = Some(&bg.buffer);
            // (read only by a model of config emission "background")
            inputs.emission = Some(&ef.buffer);
        }
        self.denoiser
            .denoise_profiled(encoder, &inputs, profiler, Granularity::Stage)?;
        Ok(())
    }
}
