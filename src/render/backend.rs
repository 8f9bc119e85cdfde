//! Which renderer traces a frame: the WGSL tracer on the adapter, or its CPU twin
//! ([`super::cpu`]). Both produce every buffer of the data contract from one
//! [`PackedScene`]; [`FrameRenderer`] hides the difference from the front ends.

use std::sync::Arc;

use super::cpu::CpuTracer;
use super::gpu_scene::GpuScene;
use super::packed::PackedScene;
use super::scene::Scene;
use super::settings::ReferenceHalves;
use super::tracer::{FrameSettings, FrameStats, Tracer};
use crate::error::Result;
use crate::frame::HostFrame;
use crate::gpu::{AdapterKind, Gpu};
use crate::nn::Tensor;

/// The renderer a command uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    /// `gpu` on a real GPU, `cpu` when the adapter is a CPU driver (or there is none).
    Auto,
    /// The CPU twin of the integrator, on all cores.
    Cpu,
    /// The WGSL tracer on the adapter.
    Gpu,
}

impl Backend {
    /// The concrete backend for an adapter (`None`: no adapter could be opened).
    pub fn resolve(self, adapter: Option<AdapterKind>) -> Backend {
        match self {
            Backend::Auto => match adapter {
                Some(AdapterKind::Cpu) | None => Backend::Cpu,
                Some(_) => Backend::Gpu,
            },
            b => b,
        }
    }

    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            Backend::Auto => "auto",
            Backend::Cpu => "cpu",
            Backend::Gpu => "gpu",
        }
    }
}

/// The WGSL tracer's state in a [`FrameRenderer`].
pub struct GpuFrameRenderer {
    /// The device.
    pub gpu: Gpu,
    /// The uploaded scene.
    pub scene: GpuScene,
    /// The tracer and its frame buffers.
    pub tracer: Tracer,
    /// Reference accumulation target (made on first use).
    pub reference: Option<Tensor>,
}

/// A scene ready to render at one size on one backend.
pub enum FrameRenderer {
    /// The WGSL tracer.
    Gpu(Box<GpuFrameRenderer>),
    /// The CPU twin.
    Cpu {
        /// The packed scene.
        scene: Arc<PackedScene>,
        /// The tracer.
        tracer: CpuTracer,
    },
}

impl std::fmt::Debug for FrameRenderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "FrameRenderer({})", self.backend().name())
    }
}

impl FrameRenderer {
    /// Packs `scene` and prepares a `width x height` renderer on `backend` (`Auto` resolved
    /// against `gpu`'s adapter; `gpu` is needed for the GPU backend only).
    pub fn new(scene: &Scene, backend: Backend, gpu: Option<&Gpu>, width: u32, height: u32) -> Result<Self> {
        match backend.resolve(gpu.map(|g| g.kind())) {
            Backend::Gpu => {
                let gpu = gpu.ok_or_else(|| {
                    crate::error::Error::Invalid(
                        "the gpu backend needs a GPU adapter; none could be opened".into(),
                    )
                })?;
                let scene = GpuScene::new(gpu, scene)?;
                let tracer = Tracer::new(gpu, width, height)?;
                tracer.compile()?;
                Ok(FrameRenderer::Gpu(Box::new(GpuFrameRenderer {
                    gpu: gpu.clone(),
                    scene,
                    tracer,
                    reference: None,
                })))
            }
            _ => Ok(FrameRenderer::Cpu {
                scene: Arc::new(PackedScene::new(scene, u64::MAX)?),
                tracer: CpuTracer::new(width, height)?,
            }),
        }
    }

    /// The backend in use.
    pub fn backend(&self) -> Backend {
        match self {
            FrameRenderer::Gpu(_) => Backend::Gpu,
            FrameRenderer::Cpu { .. } => Backend::Cpu,
        }
    }

    /// The packed scene (BVH for camera paths, counts).
    pub fn packed(&self) -> &PackedScene {
        match self {
            FrameRenderer::Gpu(g) => &g.scene.packed,
            FrameRenderer::Cpu { scene, .. } => scene,
        }
    }

    /// Renders frame `s` and returns every buffer.
    pub fn frame(&mut self, s: &FrameSettings) -> Result<(HostFrame, FrameStats)> {
        match self {
            FrameRenderer::Gpu(g) => {
                let stats = g.tracer.render(&g.scene, s)?;
                Ok((g.tracer.buffers.download(&g.gpu)?, stats))
            }
            FrameRenderer::Cpu { scene, tracer } => tracer.render(scene, s),
        }
    }

    /// An `spp`-sample reference of frame `s`, as two halves of its samples.
    pub fn reference(&mut self, s: &FrameSettings, spp: u32) -> Result<ReferenceHalves> {
        match self {
            FrameRenderer::Gpu(g) => {
                let GpuFrameRenderer {
                    gpu,
                    scene,
                    tracer,
                    reference,
                } = &mut **g;
                if reference.is_none() {
                    *reference = Some(Tensor::new(gpu, "reference", tracer.width(), tracer.height(), 4)?);
                }
                let out = reference.as_ref().expect("made above");
                tracer.render_reference_halves(scene, s, spp, out)
            }
            FrameRenderer::Cpu { scene, tracer } => tracer.render_reference(scene, s, spp),
        }
    }

    /// An `spp`-sample reference of frame `s` whose sample count doubles until the PSNR
    /// between its halves (tonemapped, as `reference_noise`) reaches `target_db` or the
    /// count would exceed `max_spp`; returns it with its sample count. Each doubling traces
    /// as many samples as all before, and the halves stay those of one render of that many.
    pub fn reference_to_noise(
        &mut self,
        s: &FrameSettings,
        spp: u32,
        target_db: f64,
        max_spp: u32,
    ) -> Result<(ReferenceHalves, u32)> {
        let mut n = spp.max(1);
        let mut r = self.reference(s, n)?;
        let mut rays = r.rays;
        // A NaN PSNR (no samples differ in a way it can measure) counts as not reached.
        let reached = |r: &ReferenceHalves| crate::metrics::psnr(&r.first, &r.second) >= target_db;
        while n.saturating_mul(2) <= max_spp && !reached(&r) {
            r = match self {
                FrameRenderer::Gpu(g) => {
                    let out = g.reference.as_ref().expect("made by reference()");
                    g.tracer.extend_reference(&g.scene, s, n, out)?
                }
                FrameRenderer::Cpu { scene, tracer } => tracer.extend_reference(scene, s, &r, n)?,
            };
            rays += r.rays;
            n *= 2;
        }
        r.rays = rays;
        Ok((r, n))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auto_picks_cpu_on_cpu_drivers() {
        assert_eq!(Backend::Auto.resolve(Some(AdapterKind::Cpu)), Backend::Cpu);
        assert_eq!(Backend::Auto.resolve(None), Backend::Cpu);
        assert_eq!(Backend::Auto.resolve(Some(AdapterKind::Discrete)), Backend::Gpu);
        assert_eq!(Backend::Gpu.resolve(Some(AdapterKind::Cpu)), Backend::Gpu);
        assert_eq!(Backend::Cpu.resolve(Some(AdapterKind::Discrete)), Backend::Cpu);
    }
}
