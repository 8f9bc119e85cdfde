//! The per-frame renderer: G-buffers from primary visibility, then path tracing in
//! `quarter`, `full` or `reference` mode, into the buffers of the denoiser contract
//! (DESIGN.md section 3).

use bytemuck::{Pod, Zeroable};

use super::camera::GpuCamera;
use super::gpu_scene::GpuScene;
use super::settings::ReferenceHalves;
pub use super::settings::{
    DEFAULT_MAX_DEPTH, FrameSettings, FrameStats, Mode, REFERENCE_SEED_XOR, TILE_OFFSETS, tile_offset,
};
use crate::error::{Error, Result};
use crate::frame::{Background, DirectEmission, HostFrame};
use crate::gpu::{Bound, Dispatch, Gpu, Grid, Profiler, Specialisation};
use crate::nn::{HostTensor, Tensor};

/// Parameters of the image kernels (WGSL `FrameParams`, 192 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct FrameParams {
    /// Camera of this frame.
    pub cam: GpuCamera,
    /// Camera of the previous frame.
    pub prev: GpuCamera,
    /// Width, height, frame index, seed.
    pub size: [u32; 4],
    /// Mode, tile dx, tile dy, max depth.
    pub mode: [u32; 4],
    /// Samples accumulated so far, samples in this pass, background lookups per axis.
    pub accum: [u32; 4],
    /// Far distance for depth normalisation.
    pub misc: [f32; 4],
}

/// Parameters of `trace/query` (16 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct QueryParams {
    /// Number of rays.
    pub count: u32,
    /// 1: any hit, 0: closest hit.
    pub any_hit: u32,
    /// Padding.
    pub pad: [u32; 2],
}

/// Uniform parameter sizes of the tracer kernels, checked against naga's layout.
pub const PARAM_SIZES: &[(&str, usize)] = &[
    ("trace/query", std::mem::size_of::<QueryParams>()),
    ("trace/gbuffer", std::mem::size_of::<FrameParams>()),
    ("trace/pathtrace", std::mem::size_of::<FrameParams>()),
    ("trace/background", std::mem::size_of::<FrameParams>()),
    ("trace/emission_outline", std::mem::size_of::<FrameParams>()),
];

/// The per-frame GPU buffers of the denoiser contract: W x H `vec4<f32>` each.
#[derive(Debug)]
pub struct FrameBuffers {
    /// (traced radiance rgb, 0 at untraced pixels; mask: 1 where traced this frame).
    pub color_mask: Tensor,
    /// (first-hit base colour rgb incl. texture, sky = 1; linear view depth / far, sky = 1).
    pub albedo_depth: Tensor,
    /// (first-hit world shading normal xyz in [-1, 1], sky = 0; metallic).
    pub normal_metallic: Tensor,
    /// (NEE light colour x visibility at the first hit of traced pixels, else 0; perceptual
    /// roughness).
    pub shadow_roughness: Tensor,
    /// (base colour x transmission of the first transmissive surface on the primary ray, 0
    /// where none; 0).
    pub transparent: Tensor,
    /// (screen-space motion in pixels, prev_pos = pos + motion with pos the pixel centre; 0, 0).
    pub motion: Tensor,
    /// (directly seen environment averaged over the pixel's footprint; coverage), present
    /// after a frame rendered with [`FrameSettings::background`] > 0.
    pub background: Option<Tensor>,
    /// (first-hit base colour averaged over the same footprint rays as the background, sky
    /// 1; the G-buffer's depth), present with the background: [`FrameBuffers::albedo_depth`]
    /// with the footprint albedo, for models that use it (config `albedo`).
    pub albedo_footprint: Option<Tensor>,
    /// (first-hit emission of the traced samples, the part of `color_mask` that is emission
    /// seen directly, 0 where not traced; the fraction of those samples whose camera ray
    /// escaped), present with the background ([`crate::frame::DirectEmission::samples`],
    /// [`crate::frame::DirectEmission::escaped`]).
    pub sample_emission: Option<Tensor>,
    /// (first-hit emission averaged over the background's footprint rays, and over
    /// [`super::EMISSION_OUTLINE_RAYS`] per axis on emitters' outlines; 0), present with the
    /// background ([`crate::frame::DirectEmission::footprint`]).
    pub emission_footprint: Option<Tensor>,
    /// The background pass's first-hit emission before the outline pass refines it.
    emission_coarse: Option<Tensor>,
}

impl FrameBuffers {
    /// The buffers as the denoiser's [`crate::frame::FrameInputs`] (the same layout).
    pub fn inputs(&self) -> crate::frame::FrameInputs<'_> {
        crate::frame::FrameInputs {
            color_mask: &self.color_mask.buffer,
            albedo_depth: &self.albedo_depth.buffer,
            normal_metallic: &self.normal_metallic.buffer,
            shadow_roughness: &self.shadow_roughness.buffer,
            transparent: &self.transparent.buffer,
            motion: &self.motion.buffer,
            background: self.background.as_ref().map(|t| &t.buffer),
            emission: None,
        }
    }

    /// Zeroed buffers of `width x height`.
    pub fn new(gpu: &Gpu, width: u32, height: u32) -> Result<Self> {
        let t = |name: &str| Tensor::new(gpu, name, width, height, 4);
        Ok(Self {
            color_mask: t("frame.color_mask")?,
            albedo_depth: t("frame.albedo_depth")?,
            normal_metallic: t("frame.normal_metallic")?,
            shadow_roughness: t("frame.shadow_roughness")?,
            transparent: t("frame.transparent")?,
            motion: t("frame.motion")?,
            background: None,
            albedo_footprint: None,
            sample_emission: None,
            emission_footprint: None,
            emission_coarse: None,
        })
    }

    /// Width.
    pub fn width(&self) -> u32 {
        self.color_mask.width
    }

    /// Height.
    pub fn height(&self) -> u32 {
        self.color_mask.height
    }

    /// Downloads every buffer, split into the named host tensors of DESIGN.md section 3.
    pub fn download(&self, gpu: &Gpu) -> Result<HostFrame> {
        let cm = self.color_mask.read(gpu)?;
        let ad = self.albedo_depth.read(gpu)?;
        let nm = self.normal_metallic.read(gpu)?;
        let sr = self.shadow_roughness.read(gpu)?;
        let tr = self.transparent.read(gpu)?;
        let mv = self.motion.read(gpu)?;
        let background = match &self.background {
            Some(b) => {
                let bc = b.read(gpu)?;
                let albedo = match &self.albedo_footprint {
                    Some(a) => Some(channels(&a.read(gpu)?, &[0, 1, 2])),
                    None => None,
                };
                let emission = match (&self.sample_emission, &self.emission_footprint) {
                    (Some(e), Some(f)) => {
                        let e = e.read(gpu)?;
                        Some(DirectEmission {
                            footprint: channels(&f.read(gpu)?, &[0, 1, 2]),
                            samples: channels(&e, &[0, 1, 2]),
                            escaped: Some(channels(&e, &[3])),
                        })
                    }
                    _ => None,
                };
                Some(Background {
                    radiance: channels(&bc, &[0, 1, 2]),
                    coverage: channels(&bc, &[3]),
                    albedo,
                    emission,
                })
            }
            None => None,
        };
        Ok(HostFrame {
            color: channels(&cm, &[0, 1, 2]),
            mask: channels(&cm, &[3]),
            albedo: channels(&ad, &[0, 1, 2]),
            depth: channels(&ad, &[3]),
            normal: channels(&nm, &[0, 1, 2]),
            metallic: channels(&nm, &[3]),
            shadow: channels(&sr, &[0, 1, 2]),
            roughness: channels(&sr, &[3]),
            transparent: channels(&tr, &[0, 1, 2]),
            motion: channels(&mv, &[0, 1]),
            background,
        })
    }
}

/// The channels `which` of `t`, in that order.
pub fn channels(t: &HostTensor, which: &[u32]) -> HostTensor {
    HostTensor::from_fn(t.width, t.height, which.len() as u32, |x, y, c| {
        t.at(x, y, which[c as usize])
    })
}

/// The image kernels and their per-frame buffers for one resolution.
pub struct Tracer {
    gpu: Gpu,
    /// The frame's buffers.
    pub buffers: FrameBuffers,
    counters: wgpu::Buffer,
    /// Bound in place of [`FrameBuffers::sample_emission`] in trace passes of frames
    /// without a background (the kernel writes nothing there).
    stand_in: wgpu::Buffer,
    scratch: Option<(Tensor, Tensor)>,
    /// G-buffer, trace and background dispatches of `encode_frame`, for (scene BVH
    /// buffer, mode, with a background).
    frame_dispatches: Bound<(wgpu::Buffer, Mode, bool), FrameDispatches>,
    /// Most paths one reference dispatch traces (more samples are split into passes): keeps
    /// each dispatch short for the driver.
    pub paths_per_pass: u64,
}

impl std::fmt::Debug for Tracer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Tracer")
            .field("width", &self.buffers.width())
            .field("height", &self.buffers.height())
            .finish()
    }
}

/// The G-buffer, trace and (optional) background dispatches of one frame.
type FrameDispatches = (Dispatch, Dispatch, Option<[Dispatch; 2]>);

/// Default bound on the paths of one reference dispatch (see [`Tracer::paths_per_pass`]).
pub const PATHS_PER_PASS: u64 = 1 << 18;

/// Most samples one invocation traces in a pass. Mesa lavapipe (22.3) drops samples of
/// invocations that run long: one pass of 1024 samples per pixel lost about 20% of them,
/// and on the dining-room scene (270k triangles) passes of 64 samples lost some too (found
/// by the CPU twin: 31.5 dB between the two backends' 128-spp references with the same
/// random numbers, 56.8 dB with passes of 8).
pub const MAX_SAMPLES_PER_PASS: u32 = 8;

/// Samples per pixel of one reference pass of at most `paths` paths.
fn samples_per_pass(width: u32, height: u32, spp: u32, paths: u64) -> u32 {
    let px = (width as u64 * height as u64).max(1);
    (paths / px).clamp(1, spp.clamp(1, MAX_SAMPLES_PER_PASS) as u64) as u32
}

impl Tracer {
    /// A tracer for `width x height` frames.
    pub fn new(gpu: &Gpu, width: u32, height: u32) -> Result<Self> {
        gpu.kernels.check_limits(
            &format!("the path tracer (adapter '{}')", gpu.info.name),
            &[
                "trace/query",
                "trace/gbuffer",
                "trace/pathtrace",
                "trace/background",
            ],
        )?;
        Ok(Self {
            gpu: gpu.clone(),
            buffers: FrameBuffers::new(gpu, width, height)?,
            counters: gpu.counter_buffer("subpixel.trace.counters"),
            stand_in: gpu.counter_buffer("subpixel.trace.stand_in"),
            scratch: None,
            paths_per_pass: PATHS_PER_PASS,
            frame_dispatches: Bound::new(),
        })
    }

    /// Compiles the image kernels now (otherwise the first frame does).
    pub fn compile(&self) -> Result<()> {
        for k in ["trace/gbuffer", "trace/pathtrace", "trace/background"] {
            self.gpu.kernels.pipeline(k, &Specialisation::none())?;
        }
        Ok(())
    }

    /// Width.
    pub fn width(&self) -> u32 {
        self.buffers.width()
    }

    /// Height.
    pub fn height(&self) -> u32 {
        self.buffers.height()
    }

    fn params(&self, s: &FrameSettings, accum: [u32; 2]) -> FrameParams {
        let (w, h) = (self.width(), self.height());
        let (dx, dy) = tile_offset(s.frame);
        FrameParams {
            cam: s.camera.gpu(w, h),
            prev: s.prev_camera.gpu(w, h),
            size: [w, h, s.frame, s.seed],
            mode: [s.mode.code(), dx, dy, s.max_depth.max(1)],
            accum: [accum[0], accum[1], s.background, 0],
            misc: [s.far.max(1e-6), 0.0, 0.0, 0.0],
        }
    }

    /// The G-buffer dispatch of frame `s`.
    pub fn gbuffer_dispatch(&self, scene: &GpuScene, s: &FrameSettings) -> Result<Dispatch> {
        let b = &self.buffers;
        self.gpu.kernels.dispatch(
            "trace/gbuffer",
            &Specialisation::none(),
            bytemuck::bytes_of(&self.params(s, [0, 1])),
            &scene.bindings(&[
                &b.albedo_depth.buffer,
                &b.normal_metallic.buffer,
                &b.shadow_roughness.buffer,
                &b.transparent.buffer,
                &b.motion.buffer,
            ]),
            Grid::pixels(self.width(), self.height()),
        )
    }

    /// Makes [`FrameBuffers::background`], [`FrameBuffers::albedo_footprint`] and the
    /// directly seen emission ([`FrameBuffers::sample_emission`],
    /// [`FrameBuffers::emission_footprint`]) when frame `s` has a background (`s.background`
    /// > 0), drops them when not, so the denoiser never reads a stale one.
    fn prepare_background(&mut self, s: &FrameSettings) -> Result<()> {
        let b = &mut self.buffers;
        if s.background == 0 {
            b.background = None;
            b.albedo_footprint = None;
            b.sample_emission = None;
            b.emission_footprint = None;
            b.emission_coarse = None;
        } else if b.background.is_none() || b.albedo_footprint.is_none() || b.sample_emission.is_none() {
            let (w, h) = (b.width(), b.height());
            let t = |name: &str| Tensor::new(&self.gpu, name, w, h, 4);
            b.background = Some(t("frame.background")?);
            b.albedo_footprint = Some(t("frame.albedo_footprint")?);
            b.sample_emission = Some(t("frame.sample_emission")?);
            b.emission_footprint = Some(t("frame.emission_footprint")?);
            b.emission_coarse = Some(t("frame.emission_coarse")?);
        }
        Ok(())
    }

    /// The background dispatches of frame `s` (`s.background` lookups per pixel axis): the
    /// background pass, writing [`FrameBuffers::background`], [`FrameBuffers::albedo_footprint`]
    /// and the coarse first-hit emission, then the outline pass (`trace/emission_outline`),
    /// writing [`FrameBuffers::emission_footprint`] (all made by a frame with a background
    /// first).
    pub fn background_dispatches(&self, scene: &GpuScene, s: &FrameSettings) -> Result<[Dispatch; 2]> {
        let (w, h) = (self.width(), self.height());
        let fb = &self.buffers;
        let (Some(b), Some(a), Some(c), Some(e)) = (
            &fb.background,
            &fb.albedo_footprint,
            &fb.emission_coarse,
            &fb.emission_footprint,
        ) else {
            return Err(Error::Invalid(
                "background_dispatches: the frame buffers have no background (settings.background is 0)"
                    .into(),
            ));
        };
        let params = self.params(s, [0, 1]);
        let background = self.gpu.kernels.dispatch(
            "trace/background",
            &Specialisation::none(),
            bytemuck::bytes_of(&params),
            &scene.bindings(&[&b.buffer, &a.buffer, &fb.albedo_depth.buffer, &c.buffer]),
            Grid::pixels(w, h),
        )?;
        let outline = self.gpu.kernels.dispatch(
            "trace/emission_outline",
            &Specialisation::none(),
            bytemuck::bytes_of(&params),
            &scene.bindings(&[&c.buffer, &e.buffer]),
            Grid::pixels(w, h),
        )?;
        Ok([background, outline])
    }

    /// A path-tracing dispatch writing `color` and `shadow` (4-channel tensors of the frame
    /// size); `accum` = (samples already in `color`, samples of this pass) in reference mode.
    /// In a frame with a background it also writes [`FrameBuffers::sample_emission`] (made
    /// by the tracer's background preparation).
    pub fn trace_dispatch(
        &self,
        scene: &GpuScene,
        s: &FrameSettings,
        accum: [u32; 2],
        color: &Tensor,
        shadow: &Tensor,
    ) -> Result<Dispatch> {
        let (w, h) = (self.width(), self.height());
        let g = if s.mode == Mode::Quarter {
            Grid::pixels(w.div_ceil(2), h.div_ceil(2))
        } else {
            Grid::pixels(w, h)
        };
        // Without the frame's emission buffer the kernel writes none (accum.z, the
        // background's lookups, is its flag) and gets a stand-in binding.
        let (emission, s) = match (&self.buffers.sample_emission, s.background > 0) {
            (Some(e), true) => (&e.buffer, *s),
            _ => (&self.stand_in, FrameSettings { background: 0, ..*s }),
        };
        self.gpu.kernels.dispatch(
            "trace/pathtrace",
            &Specialisation::none(),
            bytemuck::bytes_of(&self.params(&s, accum)),
            &scene.bindings(&[&color.buffer, &shadow.buffer, &self.counters, emission]),
            g,
        )
    }

    /// Rewrites the parameters of a dispatch made by [`Tracer::trace_dispatch`] (or
    /// [`Tracer::gbuffer_dispatch`]) for frame `s` and accumulation `accum`, so a caller
    /// binds it once ([`crate::gpu::Bound`]) and replays it every frame; like
    /// [`Dispatch::write_params`], it takes effect at the next submission.
    pub fn write_params(&self, d: &Dispatch, s: &FrameSettings, accum: [u32; 2]) {
        d.write_params(&self.gpu.queue, bytemuck::bytes_of(&self.params(s, accum)));
    }

    fn pass(encoder: &mut wgpu::CommandEncoder, d: &Dispatch, profiler: Option<&mut Profiler>, label: &str) {
        d.record(&mut Profiler::pass(encoder, label, profiler));
    }

    /// Records one quarter or full frame (G-buffer pass labelled `gbuffer`, trace pass
    /// labelled `trace`, and with `s.background` > 0 a background pass labelled
    /// `background`) into `encoder`, timing them with `profiler` when given. A frame without
    /// a background drops the buffer, so the denoiser never reads a stale one.
    pub fn encode_frame(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        scene: &GpuScene,
        s: &FrameSettings,
        mut profiler: Option<&mut Profiler>,
    ) -> Result<()> {
        if s.mode == Mode::Reference {
            return Err(Error::Invalid(
                "encode_frame records quarter and full frames; reference frames use render".into(),
            ));
        }
        // The two dispatches are built once per scene and mode; every frame only rewrites
        // their (shared) parameters. One encode_frame per submission, as write_params says.
        let mut dispatches = std::mem::take(&mut self.frame_dispatches);
        self.prepare_background(s)?;
        let with_background = s.background > 0;
        let built = dispatches.get_or_build((scene.nodes.clone(), s.mode, with_background), || {
            let gb = self.gbuffer_dispatch(scene, s)?;
            let b = &self.buffers;
            let tr = self.trace_dispatch(scene, s, [0, 1], &b.color_mask, &b.shadow_roughness)?;
            let bg = if with_background {
                Some(self.background_dispatches(scene, s)?)
            } else {
                None
            };
            Ok::<_, Error>((gb, tr, bg))
        });
        let built = built.map(|_| ());
        // (Taken out so the build can borrow the tracer; put back before any return.)
        self.frame_dispatches = dispatches;
        built?;
        let (gb, tr, bg) = self.frame_dispatches.get().expect("built above");
        self.write_params(gb, s, [0, 1]);
        self.write_params(tr, s, [0, 1]);
        encoder.clear_buffer(&self.counters, 0, None);
        Self::pass(encoder, gb, profiler.as_deref_mut(), "gbuffer");
        Self::pass(encoder, tr, profiler.as_deref_mut(), "trace");
        if let Some(bg) = bg {
            for d in bg {
                self.write_params(d, s, [0, 1]);
                Self::pass(encoder, d, profiler.as_deref_mut(), "background");
            }
        }
        Ok(())
    }

    /// Renders frame `s` into [`Tracer::buffers`] and waits for it. Reference mode renders
    /// `s.spp` samples per pixel in passes of about a million paths.
    pub fn render(&mut self, scene: &GpuScene, s: &FrameSettings) -> Result<FrameStats> {
        let (w, h) = (self.width() as u64, self.height() as u64);
        let mut enc = self.encoder();
        if s.mode != Mode::Reference {
            self.encode_frame(&mut enc, scene, s, None)?;
            self.gpu.queue.submit([enc.finish()]);
            let samples = if s.mode == Mode::Quarter {
                (self.width().div_ceil(2) as u64) * (self.height().div_ceil(2) as u64)
            } else {
                w * h
            };
            return Ok(FrameStats {
                rays: self.read_counter()?,
                samples,
            });
        }
        self.prepare_background(s)?;
        let gb = self.gbuffer_dispatch(scene, s)?;
        Self::pass(&mut enc, &gb, None, "gbuffer");
        if s.background > 0 {
            for d in &self.background_dispatches(scene, s)? {
                Self::pass(&mut enc, d, None, "background");
            }
        }
        self.gpu.queue.submit([enc.finish()]);
        let b = &self.buffers;
        let rays = self.accumulate(scene, s, 0, s.spp, &b.color_mask, &b.shadow_roughness)?;
        Ok(FrameStats {
            rays,
            samples: w * h * s.spp.max(1) as u64,
        })
    }

    /// Renders an `spp`-sample reference of frame `s` (independent of the frame's own
    /// samples) into `out` (4 channels: radiance, 1), leaving the frame buffers untouched.
    pub fn render_reference(
        &mut self,
        scene: &GpuScene,
        s: &FrameSettings,
        spp: u32,
        out: &Tensor,
    ) -> Result<u64> {
        self.check_reference_out("render_reference", out)?;
        if self.scratch.is_none() {
            let t = Tensor::new(&self.gpu, "trace.scratch_shadow", self.width(), self.height(), 4)?;
            let c = Tensor::new(&self.gpu, "trace.scratch_color", 1, 1, 4)?;
            self.scratch = Some((t, c));
        }
        let s = reference_settings(s);
        let (shadow, _) = self.scratch.as_ref().expect("created above");
        self.accumulate(scene, &s, 0, spp, out, shadow)
    }

    /// As [`Tracer::render_reference`], and also returns the two halves of the samples
    /// (samples `0 .. spp / 2` and `spp / 2 .. spp`, 3 channels each) whose difference
    /// measures the reference's noise; `out` holds the full reference.
    pub fn render_reference_halves(
        &mut self,
        scene: &GpuScene,
        s: &FrameSettings,
        spp: u32,
        out: &Tensor,
    ) -> Result<ReferenceHalves> {
        let spp = spp.max(1);
        let half = spp / 2;
        if half == 0 {
            let rays = self.render_reference(scene, s, 1, out)?;
            let full = channels(&out.read(&self.gpu)?, &[0, 1, 2]);
            return Ok(ReferenceHalves {
                first: full.clone(),
                second: full,
                rays,
            });
        }
        let rays = self.render_reference(scene, s, half, out)?;
        // Continue the same accumulation (samples half .. spp) in place.
        let mut r = self.continue_reference(scene, s, half, spp - half, out)?;
        r.rays += rays;
        Ok(r)
    }

    /// The `2 spp`-sample reference of frame `s` from its `spp`-sample one, which `out` holds
    /// ([`Tracer::render_reference_halves`] or an earlier extension): samples `spp .. 2 spp`
    /// are added to `out` in place; the halves returned are samples `0 .. spp` and
    /// `spp .. 2 spp`, as a `2 spp` render's.
    pub fn extend_reference(
        &mut self,
        scene: &GpuScene,
        s: &FrameSettings,
        spp: u32,
        out: &Tensor,
    ) -> Result<ReferenceHalves> {
        self.check_reference_out("extend_reference", out)?;
        let spp = spp.max(1);
        self.continue_reference(scene, s, spp, spp, out)
    }

    /// Adds samples `start .. start + count` of frame `s`'s reference to `out`, which holds
    /// the mean of the `start` before them, and returns the two parts as halves: `first`
    /// the mean before, `second` the mean of the samples added.
    fn continue_reference(
        &mut self,
        scene: &GpuScene,
        s: &FrameSettings,
        start: u32,
        count: u32,
        out: &Tensor,
    ) -> Result<ReferenceHalves> {
        let first = channels(&out.read(&self.gpu)?, &[0, 1, 2]);
        let Some((shadow, _)) = self.scratch.as_ref() else {
            return Err(Error::shape(
                "extend_reference",
                "no reference to extend: render_reference_halves first",
            ));
        };
        let rays = self.accumulate(scene, &reference_settings(s), start, count, out, shadow)?;
        // full = (start * first + count * second) / (start + count).
        let (a, b, n) = (start as f32, count as f32, (start + count) as f32);
        let mut second = channels(&out.read(&self.gpu)?, &[0, 1, 2]);
        for (o, f) in second.data.iter_mut().zip(&first.data) {
            *o = (n * *o - a * f) / b;
        }
        Ok(ReferenceHalves { first, second, rays })
    }

    /// `out` is a reference target of this tracer's size (4 channels).
    fn check_reference_out(&self, what: &str, out: &Tensor) -> Result<()> {
        if (out.width, out.height) != (self.width(), self.height()) || out.channels != 4 {
            return Err(Error::shape(
                what,
                format!("output must be {}x{}x4", self.width(), self.height()),
            ));
        }
        Ok(())
    }

    /// Adds samples `start .. start + spp` to `color` (which holds the mean of the `start`
    /// samples before them).
    fn accumulate(
        &self,
        scene: &GpuScene,
        s: &FrameSettings,
        start: u32,
        spp: u32,
        color: &Tensor,
        shadow: &Tensor,
    ) -> Result<u64> {
        let spp = start + spp.max(1);
        let per = samples_per_pass(self.width(), self.height(), spp, self.paths_per_pass);
        let mut done = start;
        let mut rays = 0u64;
        let s = FrameSettings {
            mode: Mode::Reference,
            ..*s
        };
        while done < spp {
            let n = per.min(spp - done);
            let d = self.trace_dispatch(scene, &s, [done, n], color, shadow)?;
            let mut enc = self.encoder();
            enc.clear_buffer(&self.counters, 0, None);
            Self::pass(&mut enc, &d, None, "trace");
            self.gpu.queue.submit([enc.finish()]);
            rays += self.read_counter()?;
            done += n;
        }
        Ok(rays)
    }

    fn encoder(&self) -> wgpu::CommandEncoder {
        self.gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("subpixel.trace"),
            })
    }

    /// Rays counted by the last trace pass (waits for the GPU).
    pub fn read_counter(&self) -> Result<u64> {
        let bytes = self.gpu.read_buffer(&self.counters, 0, 16)?;
        let c: &[u32] = bytemuck::cast_slice(&bytes);
        Ok(c[0] as u64)
    }
}

/// The settings of frame `s`'s reference: reference mode, with the reference's own seed
/// (independent of the frame's samples).
fn reference_settings(s: &FrameSettings) -> FrameSettings {
    FrameSettings {
        mode: Mode::Reference,
        seed: s.seed ^ REFERENCE_SEED_XOR,
        background: 0,
        ..*s
    }
}

/// Closest hits of rays on the GPU (`trace/query`): per ray `(origin, direction, tmax)`,
/// returns `(BVH slot, t)` or `None`; with `any_hit`, any hit within tmax.
pub fn query_rays(
    gpu: &Gpu,
    scene: &GpuScene,
    rays: &[(glam::Vec3, glam::Vec3, f32)],
    any_hit: bool,
) -> Result<Vec<Option<(u32, f32)>>> {
    use wgpu::util::DeviceExt;
    if rays.is_empty() {
        return Ok(Vec::new());
    }
    let data: Vec<[f32; 4]> = rays
        .iter()
        .flat_map(|(o, d, t)| [[o.x, o.y, o.z, *t], [d.x, d.y, d.z, 0.0]])
        .collect();
    let ray_buf = gpu.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("subpixel.query.rays"),
        contents: bytemuck::cast_slice(&data),
        usage: wgpu::BufferUsages::STORAGE,
    });
    let hits = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("subpixel.query.hits"),
        size: 16 * rays.len() as u64,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    let params = QueryParams {
        count: rays.len() as u32,
        any_hit: any_hit as u32,
        pad: [0; 2],
    };
    let n = rays.len() as u32;
    let d = gpu.kernels.dispatch(
        "trace/query",
        &Specialisation::none(),
        bytemuck::bytes_of(&params),
        &scene.bindings(&[&ray_buf, &hits]),
        Grid::Invocations([n, 1, 1]),
    )?;
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    d.encode(&mut enc);
    gpu.queue.submit([enc.finish()]);
    let bytes = gpu.read_buffer(&hits, 0, 16 * rays.len() as u64)?;
    let h: &[[f32; 4]] = bytemuck::cast_slice(&bytes);
    Ok(h.iter()
        .map(|v| {
            let prim = v[1].to_bits();
            (prim != u32::MAX).then_some((prim, v[0]))
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quarter_offsets_cover_each_tile_once() {
        let mut seen = [[0; 2]; 2];
        for t in 0..4 {
            let (dx, dy) = tile_offset(t);
            seen[dy as usize][dx as usize] += 1;
        }
        assert_eq!(seen, [[1, 1], [1, 1]]);
        assert_eq!(tile_offset(1), (1, 1));
        assert_eq!(tile_offset(6), (1, 0));
    }

    #[test]
    fn reference_passes_are_bounded() {
        assert_eq!(samples_per_pass(256, 256, 16, 1 << 20), MAX_SAMPLES_PER_PASS);
        assert_eq!(samples_per_pass(1920, 1080, 64, 1 << 20), 1);
        assert_eq!(samples_per_pass(8, 8, 3, 1 << 20), 3.min(MAX_SAMPLES_PER_PASS));
        assert_eq!(samples_per_pass(8, 8, 1000, 1 << 20), MAX_SAMPLES_PER_PASS);
    }
}
