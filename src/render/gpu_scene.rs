//! A scene uploaded for the WGSL tracer: each array of a [`PackedScene`] in one storage
//! buffer (layouts in `wgsl/trace/lib/common.wgsl` and `wgsl/trace/lib/lights.wgsl`).

use std::borrow::Cow;
use std::path::PathBuf;
use std::sync::Arc;

use wgpu::util::DeviceExt;

use super::packed::PackedScene;
use super::scene::Scene;
use crate::error::{Error, Result};
use crate::gpu::Gpu;

/// The scene on the GPU: the storage buffers of its [`PackedScene`], which it keeps (and
/// dereferences to) for CPU queries, camera paths and the CPU twin of the tracer.
pub struct GpuScene {
    /// CWBVH nodes (`bvh_nodes`).
    pub nodes: wgpu::Buffer,
    /// Triangles in BVH order (`tris`).
    pub tris: wgpu::Buffer,
    /// Vertex attributes (`verts`).
    pub verts: wgpu::Buffer,
    /// Materials (`materials`).
    pub materials: wgpu::Buffer,
    /// Texture headers and texels (`texels`).
    pub texels: wgpu::Buffer,
    /// Emissive triangle list (`lights`).
    pub lights: wgpu::Buffer,
    /// Environment map and CDFs (`env`).
    pub env: wgpu::Buffer,
    /// The host arrays these buffers were made from.
    pub packed: Arc<PackedScene>,
}

impl GpuScene {
    /// The scene's buffers in the order of their bindings (1-7, `trace/lib/scene.wgsl`),
    /// followed by `rest` (the kernel's own bindings, from 8): the buffer list of every
    /// tracer dispatch.
    pub fn bindings<'a>(&'a self, rest: &[&'a wgpu::Buffer]) -> Vec<&'a wgpu::Buffer> {
        let mut b = vec![
            &self.nodes,
            &self.tris,
            &self.verts,
            &self.materials,
            &self.texels,
            &self.lights,
            &self.env,
        ];
        b.extend_from_slice(rest);
        b
    }
}

impl std::ops::Deref for GpuScene {
    type Target = PackedScene;
    fn deref(&self) -> &PackedScene {
        &self.packed
    }
}

impl std::fmt::Debug for GpuScene {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuScene").field("packed", &self.packed).finish()
    }
}

fn storage(gpu: &Gpu, scene: &str, label: &str, bytes: &[u8]) -> Result<wgpu::Buffer> {
    let limit = gpu.device.limits().max_storage_buffer_binding_size;
    if bytes.len() as u64 > limit {
        return Err(Error::Scene {
            path: PathBuf::from(scene),
            message: format!(
                "its {label} need {} bytes, more than the adapter's storage binding limit of {limit} bytes",
                bytes.len()
            ),
        });
    }
    // wgpu cannot bind an empty buffer: pad to at least one vec4.
    let mut data = Cow::Borrowed(bytes);
    if data.len() < 16 {
        let mut v = data.into_owned();
        v.resize(16, 0);
        data = Cow::Owned(v);
    }
    Ok(gpu.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some(&format!("subpixel.scene.{label}")),
        contents: &data,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
    }))
}

impl GpuScene {
    /// Builds the BVH of `scene`, packs it (textures downscaled to the adapter's storage
    /// binding limit if needed) and uploads everything.
    pub fn new(gpu: &Gpu, scene: &Scene) -> Result<Self> {
        let limit = gpu.device.limits().max_storage_buffer_binding_size;
        Self::upload(gpu, Arc::new(PackedScene::new(scene, limit)?))
    }

    /// Uploads an already packed scene.
    pub fn upload(gpu: &Gpu, packed: Arc<PackedScene>) -> Result<Self> {
        let p = &*packed;
        let name = p.name.as_str();
        use bytemuck::cast_slice as b;
        Ok(Self {
            nodes: storage(gpu, name, "BVH nodes", b(&p.bvh.bvh.nodes))?,
            tris: storage(gpu, name, "triangles", b(&p.tris))?,
            verts: storage(gpu, name, "vertices", b(&p.verts))?,
            materials: storage(gpu, name, "materials", b(&p.materials))?,
            texels: storage(gpu, name, "textures", b(&p.texels))?,
            lights: storage(gpu, name, "lights", b(&p.lights))?,
            env: storage(gpu, name, "environment map", b(&p.env))?,
            packed,
        })
    }
}

#[cfg(test)]
mod tests {
    use crate::render::packed::GpuMaterial;

    /// Rust structs shared with WGSL have naga's size.
    #[test]
    fn shared_struct_sizes_match_naga() {
        let k = crate::gpu::kernel_source("trace/pathtrace").unwrap();
        let module = naga::front::wgsl::parse_str(k.source).unwrap();
        let mut layouter = naga::proc::Layouter::default();
        layouter.update(module.to_ctx()).unwrap();
        for (name, size) in [
            ("Material", std::mem::size_of::<GpuMaterial>()),
            ("Camera", std::mem::size_of::<crate::render::camera::GpuCamera>()),
            (
                "FrameParams",
                std::mem::size_of::<crate::render::tracer::FrameParams>(),
            ),
        ] {
            let (h, _) = module
                .types
                .iter()
                .find(|(_, t)| t.name.as_deref() == Some(name))
                .unwrap_or_else(|| panic!("no WGSL struct {name}"));
            assert_eq!(layouter[h].size as usize, size, "struct {name}");
        }
    }
}
