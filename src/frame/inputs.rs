//! One frame of inputs on the GPU, borrowed: what a renderer hands the denoiser.

use crate::error::{Error, Result};

/// One frame of inputs (DESIGN §3), borrowed from the caller's renderer: six storage
/// buffers of `width * height` `vec4<f32>` (row-major, 16 bytes per pixel), each created
/// with `BufferUsages::STORAGE`:
///
/// | buffer | x y z | w |
/// |---|---|---|
/// | `color_mask` | traced radiance (0 at untraced pixels) | mask (1 where traced) |
/// | `albedo_depth` | first-hit albedo (sky 1): at the pixel centre, or averaged over the pixel's footprint for a model of config albedo "footprint" | linear depth / far (sky 1) |
/// | `normal_metallic` | world normal in [-1, 1] (sky 0) | metallic |
/// | `shadow_roughness` | NEE light x visibility at traced pixels | perceptual roughness |
/// | `transparent` | first transmissive tint (0 where none) | unused |
/// | `motion` | x, y: motion in pixels, `prev = pos + motion` | unused |
/// | `background` (optional) | directly seen environment over the pixel's footprint (rays that hit anything count 0) | coverage: fraction of the footprint that escapes |
/// | `emission` (optional, with a background) | directly seen emission over the pixel's footprint (the first-hit emission of the footprint's rays) | unused |
///
/// With a `background`, the output is `background + (1 - coverage) x reconstruction`: the
/// environment part of each pixel comes from the background, the network reconstructs the
/// rest (the background alone where the coverage is 1; [`crate::frame::Background`]);
/// without one, every pixel is the network's reconstruction.
///
/// Which albedo goes in `albedo_depth` is the model's choice
/// ([`crate::frame::AlbedoSource`], `Weights::config.albedo_source()`): the G-buffer's at the
/// pixel centre, or the first-hit base colour averaged over the pixel's footprint (the
/// shipped model: what the reference sees where a pixel mixes surfaces; the tracer's
/// background pass writes it, [`crate::render::FrameBuffers::albedo_footprint`], which the
/// frame loop passes here).
///
/// So is who reconstructs the emission of the surfaces the camera sees directly
/// ([`crate::frame::EmissionSource`], `Weights::config.emission_source()`): a model of
/// config emission "background" wants `color_mask` without each traced sample's first-hit
/// emission, and the first-hit emission averaged over the pixel's footprint in `emission`
/// (with a `background`, even without an environment); the output pass adds it, so
/// emitters come back without noise: `emission + background + (1 - coverage) x
/// reconstruction`. The frame loop takes the colour without the samples' emission from the
/// tracer's directly seen emission with `ssr/fold_emission` ([`crate::ssr::EmissionFold`]).
#[derive(Debug, Clone, Copy)]
pub struct FrameInputs<'a> {
    /// Radiance rgb + mask.
    pub color_mask: &'a wgpu::Buffer,
    /// Albedo rgb + depth.
    pub albedo_depth: &'a wgpu::Buffer,
    /// Normal xyz + metallic.
    pub normal_metallic: &'a wgpu::Buffer,
    /// Shadow rgb + roughness.
    pub shadow_roughness: &'a wgpu::Buffer,
    /// Transparent tint rgb.
    pub transparent: &'a wgpu::Buffer,
    /// Motion xy.
    pub motion: &'a wgpu::Buffer,
    /// Background rgb + coverage, optional.
    pub background: Option<&'a wgpu::Buffer>,
    /// Directly seen emission rgb, optional (with a background; models of config emission
    /// "background").
    pub emission: Option<&'a wgpu::Buffer>,
}

impl<'a> FrameInputs<'a> {
    /// The six buffers in the order of the table above (e.g. a `Vec` of them), seven with
    /// the background, eight with the background and the emission; an error naming the
    /// count for any other number.
    pub fn from_slice(buffers: &'a [wgpu::Buffer]) -> Result<Self> {
        if !(6..=8).contains(&buffers.len()) {
            return Err(Error::shape(
                "denoiser input",
                format!(
                    "{} buffers, expected 6 ({}), 7 (and background) or 8 (and emission)",
                    buffers.len(),
                    Self::NAMES.join(", ")
                ),
            ));
        }
        Ok(Self {
            color_mask: &buffers[0],
            albedo_depth: &buffers[1],
            normal_metallic: &buffers[2],
            shadow_roughness: &buffers[3],
            transparent: &buffers[4],
            motion: &buffers[5],
            background: buffers.get(6),
            emission: buffers.get(7),
        })
    }

    /// The six buffers in the order of the table above.
    pub(crate) fn buffers(&self) -> [&wgpu::Buffer; 6] {
        [
            self.color_mask,
            self.albedo_depth,
            self.normal_metallic,
            self.shadow_roughness,
            self.transparent,
            self.motion,
        ]
    }

    /// The buffers' names, in the order of the table above (labels for a renderer's own
    /// buffers, the order [`FrameInputs::from_slice`] takes them in).
    pub const NAMES: [&'static str; 6] = [
        "color_mask",
        "albedo_depth",
        "normal_metallic",
        "shadow_roughness",
        "transparent",
        "motion",
    ];

    /// Every buffer's name, the optional two last, in [`FrameInputs::from_slice`]'s order;
    /// [`crate::ssr::SsrConfig::input_names`] says how many of them a model needs.
    pub const ALL_NAMES: [&'static str; 8] = [
        Self::NAMES[0],
        Self::NAMES[1],
        Self::NAMES[2],
        Self::NAMES[3],
        Self::NAMES[4],
        Self::NAMES[5],
        "background",
        "emission",
    ];
}
