//! # subpixel
//!
//! Real-time path tracing at a quarter sample per pixel, reconstructed by the SSR neural
//! denoiser ("High-Quality Real-Time Rendering Using Subpixel Sampling Reconstruction"),
//! with every kernel hand-written in WGSL on wgpu.
//!
//! - [`gpu`]: device context, kernel registry (WGSL templates, dispatch grids, the
//!   [`gpu::Bound`] caching policy), timestamp profiler.
//! - [`nn`]: GPU tensors, the network kernels (the conv3x3 family and its per-adapter
//!   autotuner) and their CPU references.
//! - [`ssr`]: the SSR network (declared once in [`ssr::graph`]), its weights and the
//!   embeddable [`ssr::Denoiser`].
//! - [`render`]: the 1/4-spp path tracer, its scenes and G-buffers.
//! - [`io`]: EXR frames, PNG previews, frame folders.
//! - [`metrics`]: image quality metrics; [`view`]: showing tensors on screen.
//! - [`frame`]: the per-frame data contract: a frame in host memory and on the GPU.
//! - [`frame_loop`]: the product's frame (trace at 1/4 spp, then SSR, in one command
//!   buffer), joining `render` and `ssr`.
//! - [`cli`], [`bench`](mod@bench): the `subpixel` command and its benchmarks (front ends).
//!
//! ## Data flow
//!
//! ```text
//!  builtin:NAME | builtin:procedural:SEED | scene.json | .gltf/.glb
//!        |  render::load_scene_with (render::loader, render::procedural)
//!        v
//!  render::Scene ----> render::bvh (obvhs CWBVH) ----> render::PackedScene (the tracer's arrays)
//!                                                          |
//!                     +------------------------------------+---------------------+
//!                     v                                                          v
//!        render::Tracer (WGSL, on the adapter)                 render::CpuTracer (CPU twin)
//!        writes render::FrameBuffers on the GPU                writes frame::HostFrame
//!                     |                                                          |
//!                     +---- per-frame contract (DESIGN §3): color, mask, albedo, normal,
//!                     |     shadow, transparent, depth, metallic, roughness, motion
//!                     v
//!        frame::FrameInputs (borrowed GPU buffers; the user's own buffers work the same)
//!                     |  ssr::Denoiser (ssr::graph's steps on nn kernels, autotuned per adapter)
//!                     v
//!        denoised radiance ----> io (EXR, PNG), metrics, view (display)
//! ```

#![warn(missing_docs)]

pub mod bench;
pub mod cli;
pub mod error;
pub mod frame;
pub mod frame_loop;
pub mod gpu;
pub mod io;
pub mod metrics;
pub mod nn;
pub mod render;
pub mod ssr;
pub mod view;

pub use error::{Error, Result};
