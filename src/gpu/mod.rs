//! GPU plumbing: device context, the WGSL kernel registry (with its template expansion)
//! and the timestamp profiler.

mod bound;
mod context;
mod kernels;
mod profiler;
pub mod template;

pub use bound::Bound;
pub use context::{AdapterKind, Gpu, GpuOptions, adapter_coop_tile};
pub use kernels::{
    Dispatch, Grid, KERNELS, KernelNeeds, KernelRegistry, KernelSource, ParamsBinding, Specialisation,
    check_limits, kernel_needs, kernel_source, libraries, validate_wgsl,
};
pub use profiler::{Profiler, StageStats, Stats, time_dispatch};
