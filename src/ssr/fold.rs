//! The colour a model of config emission "background" or escaped "background" is fed, on
//! the GPU (`ssr/fold_emission`; CPU reference [`crate::frame::HostFrame::fold_directly_seen`]):
//! the tracer's colour without the traced samples' first-hit emission, which the denoiser's
//! output pass adds from the footprint instead ([`crate::frame::FrameInputs::emission`]),
//! and without the traced pixels whose samples escaped to the environment, which the
//! background holds ([`crate::frame::EscapedSource`]).

use bytemuck::{Pod, Zeroable};

use crate::error::Result;
use crate::frame::{EmissionSource, EscapedSource};
use crate::gpu::{Bound, Dispatch, Gpu, Grid, Specialisation};
use crate::nn::Tensor;

/// Uniform parameters of `ssr/fold_emission`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct FoldParams {
    /// Frame width.
    pub width: u32,
    /// Frame height.
    pub height: u32,
    /// Padding.
    pub pad: [u32; 2],
}

/// The folded colour of one frame size, and the pass that writes it (bound once per pair of
/// input buffers: a frame loop replays it).
#[derive(Debug)]
pub struct EmissionFold {
    gpu: Gpu,
    /// The colour (rgb, at least 0) + mask a model is fed.
    pub color_mask: Tensor,
    /// Template parameters EMISSION and ESCAPED of `ssr/fold_emission`.
    spec: Specialisation,
    bound: Bound<[wgpu::Buffer; 2], Dispatch>,
}

impl EmissionFold {
    /// Output buffers for `width x height` frames of a model of configs `emission` and
    /// `escaped` (the pass folds what they leave to the output pass; with both `network`
    /// it copies).
    pub fn new(
        gpu: &Gpu,
        width: u32,
        height: u32,
        emission: EmissionSource,
        escaped: EscapedSource,
    ) -> Result<Self> {
        Ok(Self {
            gpu: gpu.clone(),
            color_mask: Tensor::new(gpu, "fold.color_mask", width, height, 4)?,
            spec: Specialisation(vec![
                ("EMISSION", (emission == EmissionSource::Background) as u32 as f64),
                ("ESCAPED", (escaped == EscapedSource::Background) as u32 as f64),
            ]),
            bound: Bound::new(),
        })
    }

    /// The pass writing a frame's `color_mask` as the model is fed it (from the tracer's
    /// `sample_emission`: the samples' first-hit emission and escaped fraction; each
    /// `width x height` vec4) into [`EmissionFold::color_mask`], built at the first call
    /// with these buffers and reused after.
    pub fn dispatch(
        &mut self,
        color_mask: &wgpu::Buffer,
        sample_emission: &wgpu::Buffer,
    ) -> Result<&Dispatch> {
        let (width, height) = (self.color_mask.width, self.color_mask.height);
        let (gpu, out, spec) = (&self.gpu, &self.color_mask.buffer, &self.spec);
        self.bound
            .get_or_build([color_mask.clone(), sample_emission.clone()], || {
                let params = FoldParams {
                    width,
                    height,
                    pad: [0; 2],
                };
                gpu.kernels.dispatch(
                    "ssr/fold_emission",
                    spec,
                    bytemuck::bytes_of(&params),
                    &[color_mask, sample_emission, out],
                    Grid::pixels(width, height),
                )
            })
    }
}
