//! The crate's error type: every failure names what it was working on.

use std::path::PathBuf;

/// Errors reported by the subpixel library.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// No GPU adapter could be found.
    #[error(
        "no GPU adapter found{detail}.\n  Install a GPU driver with Vulkan support, or a CPU Vulkan driver \
         (Debian/Ubuntu: `apt-get install mesa-vulkan-drivers`).\n  WGPU_BACKEND and WGPU_ADAPTER_NAME choose among adapters."
    )]
    NoAdapter {
        /// Extra context, e.g. the adapter name that was asked for.
        detail: String,
    },
    /// The device could not be created.
    #[error("could not create a device on adapter '{adapter}': {source}")]
    RequestDevice {
        /// Adapter name.
        adapter: String,
        /// Underlying wgpu error.
        source: wgpu::RequestDeviceError,
    },
    /// A WGSL kernel failed to compile or its pipeline could not be created.
    #[error("kernel '{kernel}': {message}")]
    Kernel {
        /// Kernel name (its WGSL file stem).
        kernel: String,
        /// What went wrong.
        message: String,
    },
    /// The device's limits are below what some kernels need.
    #[error("{what} does not fit this device's limits: {message}")]
    Limits {
        /// What needed the kernels (e.g. "the denoiser").
        what: String,
        /// Each kernel and limit exceeded, with the numbers.
        message: String,
    },
    /// A tensor's shape did not match what an operation expects.
    #[error("{op}: {message}")]
    Shape {
        /// The operation (kernel) that rejected the input.
        op: String,
        /// What was expected and what came.
        message: String,
    },
    /// A required adapter feature is missing.
    #[error("{what} needs the adapter feature {feature:?}, which '{adapter}' does not offer")]
    MissingFeature {
        /// What needed the feature.
        what: String,
        /// The missing feature.
        feature: wgpu::Features,
        /// Adapter name.
        adapter: String,
    },
    /// A GPU readback or submission failed.
    #[error("GPU readback failed: {0}")]
    Readback(String),
    /// A file could not be read or was malformed.
    #[error("{}: {message}", path.display())]
    File {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
    /// Weights do not match the network.
    #[error("{}: {message}", path.display())]
    Weights {
        /// The weights file.
        path: PathBuf,
        /// What is wrong: which tensor, what was expected.
        message: String,
    },
    /// A scene could not be loaded.
    #[error("scene {}: {message}", path.display())]
    Scene {
        /// The scene file.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
    /// Invalid argument.
    #[error("{0}")]
    Invalid(String),
}

/// Result alias for the crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// Shorthand for a shape error of `op`.
    pub fn shape(op: &str, message: impl Into<String>) -> Self {
        Error::Shape {
            op: op.to_string(),
            message: message.into(),
        }
    }
}
