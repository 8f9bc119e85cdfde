//! GPU tensors.

use super::HostTensor;
use crate::error::{Error, Result};
use crate::gpu::Gpu;

/// Storage type of a tensor's elements.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DType {
    /// 32-bit float, `array<vec4<f32>>`.
    F32,
    /// 16-bit float, `array<vec4<f16>>` (needs `SHADER_F16`): half the bytes; kernels
    /// convert on load and store and compute in f32.
    F16,
}

impl DType {
    /// Bytes per element.
    pub fn size(self) -> u64 {
        match self {
            DType::F32 => 4,
            DType::F16 => 2,
        }
    }

    /// Its name in kernels and messages (`f32`, `f16`).
    pub fn name(self) -> &'static str {
        match self {
            DType::F32 => "f32",
            DType::F16 => "f16",
        }
    }

    /// 1 for f16, 0 for f32: the value of a kernel's storage template flag.
    pub fn f16_flag(self) -> u32 {
        u32::from(self == DType::F16)
    }
}

/// A `height x width x channels` image on the GPU, NHWC, channels padded to a multiple of 4.
#[derive(Debug)]
pub struct Tensor {
    /// Storage buffer (`STORAGE | COPY_SRC | COPY_DST`).
    pub buffer: wgpu::Buffer,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Logical channel count.
    pub channels: u32,
    /// Element type.
    pub dtype: DType,
}

/// Channels rounded up to a multiple of 4.
pub fn padded(c: u32) -> u32 {
    c.div_ceil(4) * 4
}

/// Bytes of a `width x height x channels` tensor of `dtype` (channels padded to 4).
pub fn tensor_bytes(width: u32, height: u32, channels: u32, dtype: DType) -> u64 {
    width as u64 * height as u64 * padded(channels) as u64 * dtype.size()
}

impl Tensor {
    /// A zero-filled f32 tensor.
    pub fn new(gpu: &Gpu, label: &str, width: u32, height: u32, channels: u32) -> Result<Self> {
        Self::new_typed(gpu, label, width, height, channels, DType::F32)
    }

    /// A zero-filled tensor of `dtype`; f16 needs a device with `SHADER_F16`.
    pub fn new_typed(
        gpu: &Gpu,
        label: &str,
        width: u32,
        height: u32,
        channels: u32,
        dtype: DType,
    ) -> Result<Self> {
        if dtype == DType::F16 {
            gpu.require(wgpu::Features::SHADER_F16, &format!("f16 tensor '{label}'"))?;
        }
        if width == 0 || height == 0 || channels == 0 {
            return Err(Error::shape(
                label,
                format!("tensor of size {width}x{height}x{channels}: every dimension must be > 0"),
            ));
        }
        let size = tensor_bytes(width, height, channels, dtype);
        let max = gpu.device.limits().max_buffer_size;
        if size > max {
            return Err(Error::shape(
                label,
                format!("{width}x{height}x{channels} needs {size} bytes, more than the adapter's {max}"),
            ));
        }
        let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(&format!("subpixel.{label}")),
            size,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Ok(Self {
            buffer,
            width,
            height,
            channels,
            dtype,
        })
    }

    /// Another handle to the same memory, for a tensor of the same shape whose lifetime
    /// does not overlap this one's (the network's memory sharing).
    pub fn share(&self) -> Self {
        Self {
            buffer: self.buffer.clone(),
            width: self.width,
            height: self.height,
            channels: self.channels,
            dtype: self.dtype,
        }
    }

    /// Uploads a host tensor (padding its channels) as f32.
    pub fn from_host(gpu: &Gpu, label: &str, host: &HostTensor) -> Result<Self> {
        Self::from_host_typed(gpu, label, host, DType::F32)
    }

    /// Uploads a host tensor as `dtype` (f16 rounds each value to nearest).
    pub fn from_host_typed(gpu: &Gpu, label: &str, host: &HostTensor, dtype: DType) -> Result<Self> {
        let t = Self::new_typed(gpu, label, host.width, host.height, host.channels, dtype)?;
        t.write(gpu, host)?;
        Ok(t)
    }

    /// Overwrites the contents with `host`, which must have the same shape.
    pub fn write(&self, gpu: &Gpu, host: &HostTensor) -> Result<()> {
        if (host.width, host.height, host.channels) != (self.width, self.height, self.channels) {
            return Err(Error::shape(
                "tensor upload",
                format!(
                    "expected {}x{}x{}, got {}x{}x{}",
                    self.width, self.height, self.channels, host.width, host.height, host.channels
                ),
            ));
        }
        let padded = host.to_padded();
        match self.dtype {
            DType::F32 => gpu
                .queue
                .write_buffer(&self.buffer, 0, bytemuck::cast_slice(&padded)),
            DType::F16 => {
                let half: Vec<half::f16> = padded.iter().map(|&v| half::f16::from_f32(v)).collect();
                gpu.queue
                    .write_buffer(&self.buffer, 0, bytemuck::cast_slice(&half));
            }
        }
        Ok(())
    }

    /// Downloads the tensor (logical channels only).
    pub fn read(&self, gpu: &Gpu) -> Result<HostTensor> {
        let bytes = gpu.read_buffer(&self.buffer, 0, self.buffer.size())?;
        let data: Vec<f32> = match self.dtype {
            DType::F32 => bytemuck::cast_slice(&bytes).to_vec(),
            DType::F16 => bytes
                .chunks_exact(2)
                .map(|c| half::f16::from_le_bytes([c[0], c[1]]).to_f32())
                .collect(),
        };
        Ok(HostTensor::from_padded(
            self.width,
            self.height,
            self.channels,
            &data,
        ))
    }

    /// Padded channel count / 4 (vec4s per pixel).
    pub fn c4(&self) -> u32 {
        padded(self.channels) / 4
    }

    /// Number of pixels.
    pub fn pixels(&self) -> u64 {
        self.width as u64 * self.height as u64
    }

    /// `(width, height, channels)`.
    pub fn shape(&self) -> (u32, u32, u32) {
        (self.width, self.height, self.channels)
    }

    /// Bytes of storage.
    pub fn bytes(&self) -> u64 {
        self.buffer.size()
    }
}
