//! # subpixel
//!
//! Real-time path tracing at a quarter sample per pixel, reconstructed by the SSR neural
//! denoiser ("High-Quality Real-Time Rendering Using Subpixel Sampling Reconstruction"),
//! with every kernel hand-written in WGSL on wgpu.
//!
//! - [`gpu`]: device context, kernel registry, timestamp profiler.
//! - [`nn`]: GPU tensors, the network kernels and their CPU references.
//! - [`render`]: the 1/4-spp path tracer, its scenes and G-buffers.
//! - [`io`]: EXR frame files.

#![warn(missing_docs)]

pub mod error;
pub mod gpu;
pub mod io;
pub mod nn;
pub mod render;

pub use error::{Error, Result};
