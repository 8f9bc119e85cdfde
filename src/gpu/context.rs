//! Device context: adapter choice, features, limits.

use std::sync::Arc;

use super::kernels::{KernelRegistry, ParamsBinding};
use crate::error::{Error, Result};

/// Optional features the crate uses when the adapter offers them.
pub const WANTED_FEATURES: wgpu::Features = wgpu::Features::SHADER_F16
    .union(wgpu::Features::SUBGROUP)
    .union(wgpu::Features::TIMESTAMP_QUERY)
    .union(wgpu::Features::TIMESTAMP_QUERY_INSIDE_ENCODERS)
    .union(wgpu::Features::TIMESTAMP_QUERY_INSIDE_PASSES);

/// Broad class of the chosen adapter, in order of preference.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum AdapterKind {
    /// A discrete GPU.
    Discrete,
    /// An integrated GPU.
    Integrated,
    /// A virtual GPU.
    Virtual,
    /// Unknown kind.
    Other,
    /// A software rasteriser such as Mesa lavapipe.
    Cpu,
}

impl From<wgpu::DeviceType> for AdapterKind {
    fn from(t: wgpu::DeviceType) -> Self {
        match t {
            wgpu::DeviceType::DiscreteGpu => AdapterKind::Discrete,
            wgpu::DeviceType::IntegratedGpu => AdapterKind::Integrated,
            wgpu::DeviceType::VirtualGpu => AdapterKind::Virtual,
            wgpu::DeviceType::Cpu => AdapterKind::Cpu,
            wgpu::DeviceType::Other => AdapterKind::Other,
        }
    }
}

/// How to pick the adapter. The defaults honour `WGPU_BACKEND`, `WGPU_ADAPTER_NAME` and
/// `SUBPIXEL_COOP_MATRIX`.
///
/// ```no_run
/// use subpixel::gpu::{Gpu, GpuOptions};
/// // The discrete GPU, with the tensor-core convolution where its driver offers it.
/// let gpu = Gpu::with_options(&GpuOptions {
///     cooperative_matrix: Some(true),
///     ..Default::default()
/// })?;
/// println!("{}: cooperative matrices {:?}", gpu.describe(), gpu.coop_tile);
/// # Ok::<(), subpixel::Error>(())
/// ```
#[derive(Debug, Clone, Default)]
pub struct GpuOptions {
    /// Substring (case-insensitive) of the adapter name; falls back to `WGPU_ADAPTER_NAME`.
    pub adapter_name: Option<String>,
    /// Backends to consider; falls back to `WGPU_BACKEND`, then all.
    pub backends: Option<wgpu::Backends>,
    /// Whether to enable wgpu's experimental cooperative matrices (tensor cores) where the
    /// adapter has a configuration the `nn/conv3x3_coop` kernel uses (16x16x16 or 8x8x8, f16
    /// x f16 + f32; [`adapter_coop_tile`]); falls back to `SUBPIXEL_COOP_MATRIX` (`1`
    /// enables), then off. Experimental in
    /// wgpu 30: opt-in, and the autotuner checks the kernel's output before it times it.
    pub cooperative_matrix: Option<bool>,
}

/// Whether `SUBPIXEL_COOP_MATRIX` asks for cooperative matrices.
fn coop_from_env() -> bool {
    std::env::var("SUBPIXEL_COOP_MATRIX").is_ok_and(|v| v.trim() == "1")
}

/// The matrix size `nn/conv3x3_coop` would use on `adapter`: 16 where it offers 16x16x16
/// cooperative matrices with f16 A and B and an f32 accumulator at subgroup scope (what
/// wgpu reports), else 8 for 8x8x8 (Mesa's lavapipe); `None` without either, or without f16
/// shaders.
pub fn adapter_coop_tile(adapter: &wgpu::Adapter) -> Option<u32> {
    let features = adapter.features();
    if !features.contains(wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX | wgpu::Features::SHADER_F16) {
        return None;
    }
    let props = adapter.cooperative_matrix_properties();
    [16, 8].into_iter().find(|&t| {
        props.iter().any(|p| {
            (p.m_size, p.n_size, p.k_size) == (t, t, t)
                && p.ab_type == wgpu::CooperativeScalarType::F16
                && p.cr_type == wgpu::CooperativeScalarType::F32
        })
    })
}

/// A wgpu device with the crate's kernel registry.
///
/// Create one with [`Gpu::new`] (the crate picks the adapter) or wrap a device you
/// already own with [`Gpu::from_device`].
#[derive(Clone)]
pub struct Gpu {
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// Adapter information (name, driver, backend).
    pub info: wgpu::AdapterInfo,
    /// Compiled kernels, shared by clones.
    pub kernels: Arc<KernelRegistry>,
    /// The instance and adapter the device came from, when the crate created it (a
    /// window needs them to create and configure its surface); `None` for a wrapped device.
    pub origin: Option<(wgpu::Instance, wgpu::Adapter)>,
    /// The cooperative-matrix size (16 or 8) of `nn/conv3x3_coop` where the device has
    /// wgpu's experimental cooperative matrices and f16 shaders ([`adapter_coop_tile`]; 16
    /// for a wrapped device, whose adapter's configurations are unknown: the autotuner's
    /// output check guards it), else `None`.
    pub coop_tile: Option<u32>,
}

impl std::fmt::Debug for Gpu {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Gpu").field("adapter", &self.info.name).finish()
    }
}

impl Gpu {
    /// Picks the best adapter (discrete > integrated > CPU), honouring `WGPU_BACKEND` and
    /// `WGPU_ADAPTER_NAME`, and creates a device with the adapter's real limits and the
    /// optional features in `WANTED_FEATURES` (f16, subgroups, timestamp queries) it offers.
    pub fn new() -> Result<Self> {
        Self::with_options(&GpuOptions::default())
    }

    /// Like [`Gpu::new`] with explicit options.
    pub fn with_options(opts: &GpuOptions) -> Result<Self> {
        pollster::block_on(Self::new_async(opts))
    }

    async fn new_async(opts: &GpuOptions) -> Result<Self> {
        let backends = opts
            .backends
            .or_else(wgpu::Backends::from_env)
            .unwrap_or(wgpu::Backends::all());
        // Native backends first; GL only when nothing else exists (its probing is noisy
        // and its compute support limited).
        let primary = backends & wgpu::Backends::PRIMARY;
        let mut last_err = None;
        for set in [primary, backends] {
            if set.is_empty() {
                continue;
            }
            let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
            desc.backends = set;
            let instance = wgpu::Instance::new(desc);
            match Self::pick_adapter(&instance, set, opts).await {
                Ok(adapter) => {
                    let coop = opts.cooperative_matrix.unwrap_or_else(coop_from_env);
                    let mut gpu = Self::from_adapter_with(&adapter, coop).await?;
                    gpu.origin = Some((instance, adapter));
                    return Ok(gpu);
                }
                Err(e) => last_err = Some(e),
            }
            if set == backends {
                break;
            }
        }
        Err(last_err.unwrap_or(Error::NoAdapter {
            detail: String::new(),
        }))
    }

    /// Chooses among `instance`'s adapters as [`Gpu::new`] does.
    pub async fn pick_adapter(
        instance: &wgpu::Instance,
        backends: wgpu::Backends,
        opts: &GpuOptions,
    ) -> Result<wgpu::Adapter> {
        let wanted_name = opts
            .adapter_name
            .clone()
            .or_else(|| std::env::var("WGPU_ADAPTER_NAME").ok())
            .map(|s| s.to_lowercase());
        let adapters = instance.enumerate_adapters(backends).await;
        let available: Vec<String> = adapters
            .iter()
            .map(|a| {
                let i = a.get_info();
                format!("{} ({:?}, {:?})", i.name, i.backend, i.device_type)
            })
            .collect();
        let rank = |a: &wgpu::Adapter| {
            let i = a.get_info();
            let backend_rank = match i.backend {
                wgpu::Backend::Vulkan | wgpu::Backend::Metal | wgpu::Backend::Dx12 => 0,
                _ => 1,
            };
            (AdapterKind::from(i.device_type), backend_rank)
        };
        let best = adapters
            .into_iter()
            .filter(|a| match &wanted_name {
                Some(n) => a.get_info().name.to_lowercase().contains(n),
                None => true,
            })
            .min_by_key(rank);
        best.ok_or_else(|| Error::NoAdapter {
            detail: match (&wanted_name, available.is_empty()) {
                (Some(n), false) => format!(
                    " matching WGPU_ADAPTER_NAME '{n}' (available: {})",
                    available.join(", ")
                ),
                (Some(n), true) => format!(" (asked for '{n}', none available)"),
                (None, _) => format!(" for backends {backends:?}"),
            },
        })
    }

    /// Creates the device on a chosen adapter (cooperative matrices as
    /// `SUBPIXEL_COOP_MATRIX` says, see [`GpuOptions::cooperative_matrix`]).
    pub async fn from_adapter(adapter: &wgpu::Adapter) -> Result<Self> {
        Self::from_adapter_with(adapter, coop_from_env()).await
    }

    /// [`Gpu::from_adapter`], with wgpu's experimental cooperative matrices enabled when
    /// `cooperative_matrix` is set and the adapter has the configuration the crate uses
    /// ([`adapter_coop_tile`]).
    pub async fn from_adapter_with(adapter: &wgpu::Adapter, cooperative_matrix: bool) -> Result<Self> {
        let info = adapter.get_info();
        let mut features = adapter.features() & WANTED_FEATURES;
        let tile = if cooperative_matrix {
            adapter_coop_tile(adapter)
        } else {
            None
        };
        let coop = tile.is_some();
        let experimental_features = if coop {
            features |= wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX;
            // SAFETY: wgpu's experimental features may hold bugs (its contract for this
            // token). The crate uses this one only in `nn/conv3x3_coop`, whose output the
            // autotuner compares with the CPU reference before choosing it, and only when
            // the caller opted in.
            unsafe { wgpu::ExperimentalFeatures::enabled() }
        } else {
            wgpu::ExperimentalFeatures::disabled()
        };
        if cooperative_matrix && !coop {
            log::info!(
                "{}: no 16x16x16 or 8x8x8 f16 cooperative matrices with f32 sums; the tensor-core convolution is off",
                info.name
            );
        }
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("subpixel.device"),
                required_features: features,
                required_limits: adapter.limits(),
                experimental_features,
                memory_hints: wgpu::MemoryHints::Performance,
                trace: wgpu::Trace::Off,
            })
            .await
            .map_err(|source| Error::RequestDevice {
                adapter: info.name.clone(),
                source,
            })?;
        // The adapter's own matrix size (a wrapped device is assumed to have 16).
        Ok(Self {
            coop_tile: tile,
            ..Self::from_device(&device, &queue, info)
        })
    }

    /// Wraps a device the caller already owns (the embedding route).
    pub fn from_device(device: &wgpu::Device, queue: &wgpu::Queue, info: wgpu::AdapterInfo) -> Self {
        Self {
            device: device.clone(),
            queue: queue.clone(),
            kernels: Arc::new(KernelRegistry::new(device, ParamsBinding::for_adapter(&info))),
            info,
            origin: None,
            coop_tile: device
                .features()
                .contains(wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX | wgpu::Features::SHADER_F16)
                .then_some(16),
        }
    }

    /// Broad class of the adapter.
    pub fn kind(&self) -> AdapterKind {
        self.info.device_type.into()
    }

    /// Whether the device can run `nn/conv3x3_coop`: created with wgpu's experimental
    /// cooperative matrices and f16 shaders (for a wrapped device, the caller's choice of
    /// features; the adapter's matrix configurations are then unknown, and the
    /// autotuner's output check is what guards them).
    pub fn has_coop_matrix(&self) -> bool {
        self.coop_tile.is_some()
    }

    /// Whether the device was created with `feature`.
    pub fn has(&self, feature: wgpu::Features) -> bool {
        self.device.features().contains(feature)
    }

    /// Errors unless the device has `feature`.
    pub fn require(&self, feature: wgpu::Features, what: &str) -> Result<()> {
        if self.has(feature) {
            Ok(())
        } else {
            Err(Error::MissingFeature {
                what: what.to_string(),
                feature,
                adapter: self.info.name.clone(),
            })
        }
    }

    /// One line naming the adapter, its backend and driver.
    pub fn describe(&self) -> String {
        format!(
            "{} ({:?}, {:?}, driver {} {})",
            self.info.name, self.info.backend, self.info.device_type, self.info.driver, self.info.driver_info
        )
    }

    /// A 2D texture a kernel writes (storage binding) and others read or copy out
    /// (texture binding, copy source): the denoiser's output, the display target.
    pub fn storage_texture(
        &self,
        label: &str,
        width: u32,
        height: u32,
        format: wgpu::TextureFormat,
    ) -> wgpu::Texture {
        self.storage_texture_layers(label, width, height, 1, format)
    }

    /// [`Gpu::storage_texture`] with `layers` array layers (the convolutions' texture
    /// copies of their inputs, one layer per channel vec4).
    pub fn storage_texture_layers(
        &self,
        label: &str,
        width: u32,
        height: u32,
        layers: u32,
        format: wgpu::TextureFormat,
    ) -> wgpu::Texture {
        self.device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size: wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: layers,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage: wgpu::TextureUsages::STORAGE_BINDING
                | wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        })
    }

    /// Four `u32` counters that kernels add to (storage binding) and the host clears and
    /// reads back (copy destination and source): the tracer's statistics, the denoiser's
    /// count of sanitised input values.
    pub fn counter_buffer(&self, label: &str) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: 16,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    /// Blocks until all submitted work is done.
    pub fn wait(&self) -> Result<()> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| Error::Readback(e.to_string()))
    }

    /// Copies `size` bytes of `buffer` (which needs `COPY_SRC`) back to the CPU.
    pub fn read_buffer(&self, buffer: &wgpu::Buffer, offset: u64, size: u64) -> Result<Vec<u8>> {
        self.read_back(size, |enc, staging| {
            enc.copy_buffer_to_buffer(buffer, offset, staging, 0, size)
        })
    }

    /// Copies a 2D texture (made with `COPY_SRC`, a format with a fixed texel size) to the
    /// host and blocks until done: its rows, top to bottom, without padding (layer after
    /// layer for an array).
    pub fn read_texture(&self, texture: &wgpu::Texture) -> Result<Vec<u8>> {
        let (w, h, layers) = (texture.width(), texture.height(), texture.depth_or_array_layers());
        let texel = texture.format().block_copy_size(None).ok_or_else(|| {
            Error::Readback(format!(
                "texture format {:?} has no fixed texel size",
                texture.format()
            ))
        })?;
        let row = w * texel;
        let padded = row.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
        let bytes = self.read_back(padded as u64 * h as u64 * layers as u64, |enc, staging| {
            enc.copy_texture_to_buffer(
                texture.as_image_copy(),
                wgpu::TexelCopyBufferInfo {
                    buffer: staging,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(padded),
                        rows_per_image: Some(h),
                    },
                },
                wgpu::Extent3d {
                    width: w,
                    height: h,
                    depth_or_array_layers: layers,
                },
            )
        })?;
        Ok(bytes
            .chunks_exact(padded as usize)
            .flat_map(|r| &r[..row as usize])
            .copied()
            .collect())
    }

    /// Runs `copy` (into a mappable staging buffer of `size` bytes), waits and returns
    /// the staging buffer's bytes.
    fn read_back(
        &self,
        size: u64,
        copy: impl FnOnce(&mut wgpu::CommandEncoder, &wgpu::Buffer),
    ) -> Result<Vec<u8>> {
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("subpixel.readback"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("subpixel.readback"),
            });
        copy(&mut enc, &staging);
        self.queue.submit([enc.finish()]);
        let slice = staging.slice(..);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.wait()?;
        rx.recv()
            .map_err(|e| Error::Readback(e.to_string()))?
            .map_err(|e| Error::Readback(e.to_string()))?;
        let data = slice
            .get_mapped_range()
            .map_err(|e| Error::Readback(e.to_string()))?
            .to_vec();
        staging.unmap();
        Ok(data)
    }
}
