//! The subpixel-sampling path tracer (DESIGN.md section 5): scenes (built-in, glTF 2.0 +
//! `scene.json`), an obvhs CWBVH traversed in WGSL, a unidirectional path tracer with
//! next-event estimation and MIS, G-buffers from primary visibility, and camera paths.
//!
//! ```no_run
//! # fn main() -> subpixel::Result<()> {
//! use subpixel::render::{FrameSettings, GpuScene, Mode, Tracer, load_scene};
//! let gpu = subpixel::gpu::Gpu::new()?;
//! let scene = load_scene("builtin:cornell")?;
//! let gpu_scene = GpuScene::new(&gpu, &scene)?;
//! let mut tracer = Tracer::new(&gpu, 64, 64)?;
//! let far = scene.far_distance([&scene.camera.position]);
//! tracer.render(&gpu_scene, &FrameSettings::new(scene.camera, Mode::Quarter, far))?;
//! let frame = tracer.buffers.download(&gpu)?; // colour, mask, albedo, normal, ...
//! # Ok(()) }
//! ```

pub mod backend;
pub mod builtin;
pub mod bvh;
pub mod camera;
pub mod cpu;
pub mod gpu_scene;
pub mod load;
pub mod loader;
pub mod packed;
pub mod procedural;
pub mod scene;
pub mod settings;
pub mod tracer;
pub mod wide_bvh;

pub use backend::{Backend, FrameRenderer, GpuFrameRenderer};
pub use camera::{Camera, CameraPath, CameraPathSpec};
pub use cpu::{CpuTracer, PrimarySurface};
pub use gpu_scene::GpuScene;
pub use load::{load_scene, load_scene_with};
pub use loader::SceneOptions;
pub use packed::PackedScene;
pub use scene::{Material, Scene};
pub use settings::ReferenceHalves;
pub use settings::{DEFAULT_BACKGROUND, EMISSION_OUTLINE_RAYS};
pub use tracer::{
    DEFAULT_MAX_DEPTH, FrameBuffers, FrameSettings, FrameStats, Mode, PARAM_SIZES, REFERENCE_SEED_XOR,
    TILE_OFFSETS, Tracer, query_rays, tile_offset,
};
