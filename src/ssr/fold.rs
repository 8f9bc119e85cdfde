//! The colour a model of config emission "background" is fed, on the GPU: the tracer's
//! colour without the traced samples' first-hit emission (`ssr/fold_emission`; CPU reference
//! [`crate::frame::HostFrame::fold_direct_emission`]); the denoiser's output pass adds the
//! footprint's emission instead ([`crate::frame::FrameInputs::emission`]).

use bytemuck::{Pod, Zeroable};

use crate::error::Result;
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
    /// Colour without the traced samples' first-hit emission (rgb, at least 0) + mask.
    pub color_mask: Tensor,
    bound: Bound<[wgpu::Buffer; 2], Dispatch>,
}

impl EmissionFold {
    /// Output buffers for `width x height` frames.
    pub fn new(gpu: &Gpu, width: u32, height: u32) -> Result<Self> {
        Ok(Self {
            gpu: gpu.clone(),
            color_mask: Tensor::new(gpu, "fold.color_mask", width, height, 4)?,
            bound: Bound::new(),
        })
    }

    /// The pass writing a frame's `color_mask` without its samples' first-hit emission
    /// (`sample_emission`; each `width x height` vec4) into [`EmissionFold::color_mask`],
    /// built at the first call with these buffers and reused after.
    pub fn dispatch(
        &mut self,
        color_mask: &wgpu::Buffer,
        sample_emission: &wgpu::Buffer,
    ) -> Result<&Dispatch> {
        let (width, height) = (self.color_mask.width, self.color_mask.height);
        let (gpu, out) = (&self.gpu, &self.color_mask.buffer);
        self.bound
            .get_or_build([color_mask.clone(), sample_emission.clone()], || {
                let params = FoldParams {
                    width,
                    height,
                    pad: [0; 2],
                };
                gpu.kernels.dispatch(
                    "ssr/fold_emission",
                    &Specialisation::none(),
                    bytemuck::bytes_of(&params),
                    &[color_mask, sample_emission, out],
                    Grid::pixels(width, height),
                )
            })
    }
}
