//! The per-frame data contract (DESIGN §3), one home for it: a frame in host memory
//! ([`HostFrame`], one tensor per buffer) and a frame on the GPU as the denoiser reads it
//! ([`FrameInputs`], six borrowed storage buffers of `vec4<f32>` per pixel, and an optional
//! seventh, the [`Background`]). The renderer
//! (`render`) produces frames, the denoiser (`ssr`) consumes them; neither imports the
//! other.

mod host;
mod inputs;

pub use host::{AlbedoSource, Background, DirectEmission, EmissionSource, EscapedSource, HostFrame};
pub use inputs::FrameInputs;
