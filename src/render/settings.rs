//! What a frame is rendered with and what comes back, the same for both backends (the
//! WGSL [`super::Tracer`] and the CPU twin [`super::CpuTracer`]): sampling mode, the 2x2
//! tile pattern, frame settings, counts, reference halves.

use super::camera::{Camera, CameraPath};
use crate::nn::HostTensor;

/// Sampling mode of the path tracer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// One pixel per 2x2 tile per frame (1/4 spp), rotating with [`TILE_OFFSETS`].
    Quarter,
    /// One sample in every pixel.
    Full,
    /// Progressive N spp per pixel, box filter (the plain mean of jittered samples).
    Reference,
}

impl Mode {
    /// The mode's number in the WGSL `FrameParams` (`mode.x`).
    pub(super) fn code(self) -> u32 {
        match self {
            Mode::Quarter => 0,
            Mode::Full => 1,
            Mode::Reference => 2,
        }
    }
}

/// Traced pixel `(dx, dy)` inside each 2x2 tile, for frame `t` at index `t mod 4`.
pub const TILE_OFFSETS: [(u32, u32); 4] = [(0, 0), (1, 1), (1, 0), (0, 1)];

/// The traced tile offset of frame `frame`.
pub fn tile_offset(frame: u32) -> (u32, u32) {
    TILE_OFFSETS[(frame % 4) as usize]
}

/// Seed variation of references (so a frame's reference never shares its samples).
pub const REFERENCE_SEED_XOR: u32 = 0x9e37_79b9;

/// Default `max_depth`: the largest number of path segments (1 = emitters seen directly,
/// 2 = direct lighting, 3 = one indirect bounce, ...).
pub const DEFAULT_MAX_DEPTH: u32 = 8;

/// Environment lookups per pixel axis of the background buffer the product's frame loop
/// renders for a scene with an environment ([`FrameSettings::background`]): 2 x 2 camera
/// rays per pixel. Measured (eighth session): on the val split the engine's output with a
/// 2 x 2 background scores 23.60 dB / 0.6606 against 23.63 / 0.6612 with 8 x 8 (22.95 /
/// 0.6496 without one), while on lavapipe a 4 x 4 background pass cost about as much as the
/// whole network per 128x128 frame and a 2 x 2 one about a tenth of that.
pub const DEFAULT_BACKGROUND: u32 = 2;

/// Camera rays per pixel axis of the directly seen emission ([`crate::frame::DirectEmission`])
/// on emitters' outlines ([`crate::frame::DirectEmission::outline`]) when the background has
/// fewer: there a few rays measure an emitter's coverage coarsely (2 x 2 rays miss an emitter
/// that covers a fifth of the pixel, which at an emitter's radiance is far from nothing), so
/// the outline's pixels are traced again with 8 x 8 rays, as the datasets' 8 x 8 background
/// traces every pixel. Outlines are a thin band, so this costs little.
pub const EMISSION_OUTLINE_RAYS: u32 = 8;

/// What one frame is rendered with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameSettings {
    /// Frame index (tile offset, random numbers).
    pub frame: u32,
    /// Camera of this frame.
    pub camera: Camera,
    /// Camera of the previous frame (the same camera for a first frame: zero motion).
    pub prev_camera: Camera,
    /// Sampling mode.
    pub mode: Mode,
    /// Samples per pixel in reference mode (ignored otherwise).
    pub spp: u32,
    /// Largest number of path segments, see [`DEFAULT_MAX_DEPTH`].
    pub max_depth: u32,
    /// Random seed.
    pub seed: u32,
    /// Distance that normalises view depth to [0, 1] (see [`super::Scene::far_distance`]).
    pub far: f32,
    /// Environment lookups per pixel axis of the optional background buffer
    /// ([`crate::frame::Background`]: `background x background` camera rays per pixel);
    /// 0: the frame has no background.
    pub background: u32,
}

impl FrameSettings {
    /// Settings for a static `camera` at frame 0.
    pub fn new(camera: Camera, mode: Mode, far: f32) -> Self {
        Self {
            frame: 0,
            camera,
            prev_camera: camera,
            mode,
            spp: 1,
            max_depth: DEFAULT_MAX_DEPTH,
            seed: 0,
            far,
            background: 0,
        }
    }

    /// Frame `frame` of a camera `path` at 1 spp: its camera, the previous frame's camera
    /// for the motion vectors (the same one at frame 0), [`DEFAULT_MAX_DEPTH`].
    pub fn along(path: &CameraPath, frame: u32, mode: Mode, seed: u32, far: f32) -> Self {
        Self {
            frame,
            camera: path.camera(frame),
            prev_camera: path.camera(frame.saturating_sub(1)),
            seed,
            ..Self::new(path.camera(frame), mode, far)
        }
    }
}

/// Counts of one rendered frame.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrameStats {
    /// Rays traced by the path tracer (camera, bounce and shadow rays).
    pub rays: u64,
    /// Samples traced (paths).
    pub samples: u64,
}

/// A reference rendered as two independent halves of its samples: their mean is the
/// reference, their difference measures its noise.
#[derive(Debug, Clone)]
pub struct ReferenceHalves {
    /// Mean of samples `0 .. spp / 2` (3 channels).
    pub first: HostTensor,
    /// Mean of samples `spp / 2 .. spp` (3 channels).
    pub second: HostTensor,
    /// Rays traced.
    pub rays: u64,
}

impl ReferenceHalves {
    /// The reference: the mean of all `spp` samples (the halves weighted by their counts).
    pub fn mean(&self, spp: u32) -> HostTensor {
        let a = (spp / 2) as f32 / spp.max(1) as f32;
        let mut out = self.first.clone();
        for (o, s) in out.data.iter_mut().zip(&self.second.data) {
            *o = a * *o + (1.0 - a) * s;
        }
        out
    }
}
