//! # subpixel
//!
//! Real-time path tracing at a quarter sample per pixel, reconstructed by the SSR neural
//! denoiser ("High-Quality Real-Time Rendering Using Subpixel Sampling Reconstruction"),
//! with every kernel hand-written in WGSL on wgpu.
//!
//! - [`gpu`]: device context, kernel registry, timestamp profiler.
//! - [`nn`]: GPU tensors, the network kernels and their CPU references.
//! - [`ssr`]: the SSR network, its weights and the embeddable [`ssr::Denoiser`].
//! - [`render`]: the 1/4-spp path tracer, its scenes and G-buffers.
//! - [`io`]: EXR frames, PNG previews, frame folders.
//! - [`metrics`]: image quality metrics; [`view`]: showing tensors on screen.

#![warn(missing_docs)]

pub mod bench;
pub mod cli;
pub mod error;
pub mod frame;
pub mod gpu;
pub mod io;
pub mod metrics;
pub mod nn;
pub mod render;
pub mod ssr;
pub mod view;

pub use error::{Error, Result};
