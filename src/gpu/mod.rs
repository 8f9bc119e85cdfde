//! GPU plumbing: device context, the WGSL kernel registry and the timestamp profiler.

mod context;
mod kernels;
mod profiler;

pub use context::{AdapterKind, Gpu, GpuOptions};
pub use kernels::{
    Dispatch, KERNELS, KernelRegistry, KernelSource, Specialisation, kernel_source, libraries,
};
pub use profiler::{Profiler, StageStats, Stats};
