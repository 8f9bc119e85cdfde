//! Benchmarks: kernels in isolation, the denoiser, the whole frame.

pub mod denoise;
pub mod frame;
pub mod kernels;
mod peak;
pub mod render;
pub mod roofline;

pub use peak::peak_fp32_gflops;
