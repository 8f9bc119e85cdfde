//! Neural-network building blocks: GPU tensors, the WGSL op wrappers and their scalar
//! CPU references.
//!
//! Tensors are single images in NHWC layout with channels padded to a multiple of 4 and
//! stored as `array<vec4<f32>>`; padding channels are zero. The storage type is a
//! property of [`Tensor`] ([`DType`]): with `SHADER_F16`, the network can keep its
//! interior activations in f16 (half the bytes, f32 arithmetic in the kernels).

pub mod autotune;
pub mod conv;
pub mod ops;
pub mod reference;
mod tensor;

pub use reference::HostTensor;
pub use tensor::{DType, Tensor};
