//! Live 1/4-spp path tracing + SSR reconstruction in a window.
//!
//! ```sh
//! cargo run --release --example viewer -- builtin:cornell
//! cargo run --release --example viewer -- ../shared/scenes/living-room/scene.json --weights weights/ssr.safetensors
//! # headless (e.g. under Xvfb): render 8 frames, save a screenshot, exit
//! cargo run --release --example viewer -- builtin:cornell --frames 8 --screenshot shot.png
//! ```
//!
//! Keys: 1 input (1/4 spp) | 2 SSR | 3 split input/SSR | 4 TFA-accumulated colour |
//! 5 progressive reference (accumulates while the camera stands still) | 6 albedo |
//! 7 normal | 8 depth | 9 shadow | 0 motion | M mask | T transparent | G metallic |
//! R roughness. WASD/QE fly, drag the mouse to look, scroll for speed, P plays the scene's
//! camera path, F12 saves a screenshot, Esc quits.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Parser;
use glam::Vec3;
use subpixel::frame_loop::FrameLoop;
use subpixel::gpu::{AdapterKind, Bound, Dispatch, Gpu, Profiler};
use subpixel::nn::{Tensor, ops};
use subpixel::render::{Camera, CameraPath, FrameSettings, GpuScene, Mode, SceneOptions, load_scene_with};
use subpixel::ssr::Weights;
use subpixel::view::{Display, DisplayMode, Source, View};
use winit::application::ApplicationHandler;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{KeyCode, PhysicalKey};
use winit::window::{Window, WindowId};

#[derive(Parser)]
#[command(about = "subpixel viewer: live 1/4-spp path tracing + SSR")]
struct Args {
    /// Scene: builtin:NAME (builtin:procedural:SEED among them), a .gltf/.glb or a
    /// scene.json.
    #[arg(default_value = "builtin:cornell")]
    scene: String,
    /// How the scene is built (`--props`).
    #[command(flatten)]
    scene_options: SceneOptions,
    /// SSR weights (default: weights/ssr.safetensors).
    #[arg(long)]
    weights: Option<PathBuf>,
    /// Window width.
    #[arg(long, default_value_t = 960)]
    width: u32,
    /// Window height.
    #[arg(long, default_value_t = 540)]
    height: u32,
    /// Render resolution as a fraction of the window (default 1, or 0.25 on a CPU adapter).
    #[arg(long)]
    scale: Option<f32>,
    /// Render this many frames, save --screenshot and exit.
    #[arg(long)]
    frames: Option<u32>,
    /// Screenshot path (F12, or at exit with --frames).
    #[arg(long, default_value = "subpixel-screenshot.png")]
    screenshot: PathBuf,
    /// Start with the split input | SSR view (the same as `--view split`).
    #[arg(long)]
    split: bool,
    /// Start with this view (keys 1-9 and 0 switch views later).
    #[arg(long, value_enum)]
    view: Option<ViewKind>,
}

#[derive(Clone, Copy, PartialEq, Eq, Debug, clap::ValueEnum)]
enum ViewKind {
    Input,
    Ssr,
    Split,
    Accumulated,
    Reference,
    Albedo,
    Normal,
    Depth,
    Shadow,
    Motion,
    Mask,
    Transparent,
    Metallic,
    Roughness,
}

struct Fly {
    cam: Camera,
    yaw: f32,
    pitch: f32,
    speed: f32,
    keys: [bool; 6],
    dragging: bool,
    last_mouse: Option<(f64, f64)>,
    moved: bool,
}

impl Fly {
    fn new(cam: Camera, extent: f32) -> Self {
        let d = (cam.target - cam.position).normalize_or(Vec3::NEG_Z);
        Self {
            cam,
            yaw: d.x.atan2(-d.z),
            pitch: d.y.asin(),
            speed: 0.25 * extent,
            keys: [false; 6],
            dragging: false,
            last_mouse: None,
            moved: false,
        }
    }
    fn forward(&self) -> Vec3 {
        Vec3::new(
            self.yaw.sin() * self.pitch.cos(),
            self.pitch.sin(),
            -self.yaw.cos() * self.pitch.cos(),
        )
    }
    fn update(&mut self, dt: f32) {
        let f = self.forward();
        let r = f.cross(Vec3::Y).normalize_or(Vec3::X);
        let mut v = Vec3::ZERO;
        let dirs = [f, -f, -r, r, Vec3::Y, -Vec3::Y];
        for (k, d) in self.keys.iter().zip(dirs) {
            if *k {
                v += d;
            }
        }
        if v != Vec3::ZERO {
            self.cam.position += v.normalize() * self.speed * dt;
            self.moved = true;
        }
        self.cam.target = self.cam.position + f;
        self.cam.up = Vec3::Y;
    }
}

/// Everything that depends on the render size.
struct Frame {
    /// The path tracer and the denoiser.
    fl: FrameLoop,
    display: Display,
    accumulated: Tensor,
    reference: Tensor,
    reference_shadow: Tensor,
    reference_spp: u32,
    /// The reference trace, bound once per scene; its parameters change every frame.
    reference_trace: Bound<wgpu::Buffer, Dispatch>,
    /// The TFA-accumulated colour view, bound once per A_acc tensor.
    accumulated_view: [Bound<wgpu::Buffer, Dispatch>; 2],
}

struct App {
    args: Args,
    gpu: Gpu,
    scene: GpuScene,
    far: f32,
    /// Background lookups per pixel axis (the scene's default: 2 with an environment).
    background: u32,
    weights: Weights,
    path: Option<CameraPath>,
    fly: Fly,
    playing: bool,
    window: Option<Arc<Window>>,
    surface: Option<wgpu::Surface<'static>>,
    config: Option<wgpu::SurfaceConfiguration>,
    blitter: Option<wgpu::util::TextureBlitter>,
    frame: Option<Frame>,
    view: ViewKind,
    index: u32,
    prev_camera: Option<Camera>,
    profiler: Profiler,
    fps: Vec<f64>,
    last: Instant,
    error: Option<anyhow::Error>,
}

impl App {
    fn render_size(&self, w: u32, h: u32) -> (u32, u32) {
        let s = self.args.scale.unwrap_or(if self.gpu.kind() == AdapterKind::Cpu {
            0.25
        } else {
            1.0
        });
        // Multiples of 4, so the SSR output (padded to 4 internally) matches the frame buffers.
        let r = |n: u32| (((n as f32 * s) as u32) / 4 * 4).max(4);
        (r(w), r(h))
    }

    fn make_frame(&self, w: u32, h: u32) -> Result<Frame> {
        let (rw, rh) = self.render_size(w, h);
        Ok(Frame {
            fl: FrameLoop::new(&self.gpu, &self.weights, rw, rh)?,
            display: Display::new(&self.gpu, w, h)?,
            accumulated: Tensor::new(&self.gpu, "viewer.accumulated", rw, rh, 3)?,
            reference: Tensor::new(&self.gpu, "viewer.reference", rw, rh, 4)?,
            reference_shadow: Tensor::new(&self.gpu, "viewer.reference_shadow", rw, rh, 4)?,
            reference_spp: 0,
            reference_trace: Bound::new(),
            accumulated_view: [Bound::new(), Bound::new()],
        })
    }

    fn step(&mut self) -> Result<()> {
        let now = Instant::now();
        let dt = (now - self.last).as_secs_f32();
        self.fps.push(dt as f64);
        if self.fps.len() > 30 {
            self.fps.remove(0);
        }
        self.last = now;
        if self.playing
            && let Some(p) = &self.path
        {
            self.fly.cam = p.camera(self.index);
            self.fly.moved = true;
        } else {
            self.fly.update(dt);
        }
        let cam = self.fly.cam;
        let moved = std::mem::take(&mut self.fly.moved);
        let frame = self.frame.as_mut().expect("frame created on resume");
        let settings = FrameSettings {
            frame: self.index,
            camera: cam,
            prev_camera: self.prev_camera.unwrap_or(cam),
            mode: Mode::Quarter,
            spp: 1,
            max_depth: subpixel::render::DEFAULT_MAX_DEPTH,
            seed: 1,
            far: self.far,
            background: self.background,
        };
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        frame
            .fl
            .encode(&mut enc, &self.scene, &settings, Some(&mut self.profiler))?;
        let b = &frame.fl.tracer.buffers;
        if moved {
            frame.reference_spp = 0;
        }
        if self.view == ViewKind::Reference {
            let s = FrameSettings {
                mode: Mode::Reference,
                seed: 7 + self.index,
                ..settings
            };
            let accum = [frame.reference_spp, 1];
            let d = frame.reference_trace.get_or_build(self.scene.nodes.clone(), || {
                frame.fl.tracer.trace_dispatch(
                    &self.scene,
                    &s,
                    accum,
                    &frame.reference,
                    &frame.reference_shadow,
                )
            })?;
            frame.fl.tracer.write_params(d, &s, accum);
            d.encode(&mut enc);
            frame.reference_spp += 1;
        }
        if self.view == ViewKind::Accumulated {
            let net = frame.fl.denoiser.network();
            let a_acc = net.tensor("a_acc").expect("a_acc exists");
            let exposure = net.tensor("exposure").expect("exposure exists");
            // A_acc alternates between two tensors: one bound dispatch for each.
            let slot = &mut frame.accumulated_view[(frame.fl.denoiser.frames() % 2) as usize];
            let d = slot.get_or_build(a_acc.buffer.clone(), || {
                ops::remodulate(&self.gpu, a_acc, a_acc, 3, exposure, None, &frame.accumulated)
            })?;
            d.encode(&mut enc);
        }
        // The denoiser's output texture (composited with the background), as an embedding
        // would show it.
        let ssr = Source::Texture(frame.fl.denoiser.output());
        let t = Source::Tensor;
        let (src, other, mode, first, channels): (Source<'_>, Option<Source<'_>>, DisplayMode, u32, u32) =
            match self.view {
                ViewKind::Input => (t(&b.color_mask), None, DisplayMode::Radiance, 0, 3),
                ViewKind::Ssr => (ssr, None, DisplayMode::Radiance, 0, 3),
                ViewKind::Split => (t(&b.color_mask), Some(ssr), DisplayMode::Radiance, 0, 3),
                ViewKind::Accumulated => (t(&frame.accumulated), None, DisplayMode::Radiance, 0, 3),
                ViewKind::Reference => (t(&frame.reference), None, DisplayMode::Radiance, 0, 3),
                ViewKind::Albedo => (t(&b.albedo_depth), None, DisplayMode::Unit, 0, 3),
                ViewKind::Normal => (t(&b.normal_metallic), None, DisplayMode::Signed(1.0), 0, 3),
                ViewKind::Depth => (t(&b.albedo_depth), None, DisplayMode::Unit, 3, 1),
                ViewKind::Shadow => (t(&b.shadow_roughness), None, DisplayMode::Radiance, 0, 3),
                ViewKind::Motion => (t(&b.motion), None, DisplayMode::Signed(0.125), 0, 2),
                ViewKind::Mask => (t(&b.color_mask), None, DisplayMode::Unit, 3, 1),
                ViewKind::Transparent => (t(&b.transparent), None, DisplayMode::Unit, 0, 3),
                ViewKind::Metallic => (t(&b.normal_metallic), None, DisplayMode::Unit, 3, 1),
                ViewKind::Roughness => (t(&b.shadow_roughness), None, DisplayMode::Unit, 3, 1),
            };
        let fps = self.fps.len() as f64 / self.fps.iter().sum::<f64>().max(1e-9);
        let mut text = vec![format!(
            "{:?}  {:.1} fps  {}x{}  {}",
            self.view,
            fps,
            frame.fl.tracer.width(),
            frame.fl.tracer.height(),
            self.gpu.info.name
        )];
        let ms: Vec<String> = subpixel::frame_loop::STAGES
            .iter()
            .filter_map(|s| self.profiler.stat(s).map(|st| format!("{s} {:.2}", st.median_ms)))
            .collect();
        text.push(format!("GPU ms: {}", ms.join("  ")));
        if self.view == ViewKind::Reference {
            text.push(format!("reference: {} spp", frame.reference_spp));
        }
        let (w, h) = (
            self.config.as_ref().map_or(self.args.width, |c| c.width),
            self.config.as_ref().map_or(self.args.height, |c| c.height),
        );
        let view = View {
            mode,
            first,
            channels,
            split_x: other.map(|_| w / 2),
            text,
            text_scale: if w >= 1200 { 2 } else { 1 },
        };
        let _ = h;
        frame.display.draw(&mut enc, src, other, &view)?;
        self.profiler.resolve(&mut enc);
        let surface_tex = match &self.surface {
            Some(s) => match s.get_current_texture() {
                wgpu::CurrentSurfaceTexture::Success(t) | wgpu::CurrentSurfaceTexture::Suboptimal(t) => {
                    Some(t)
                }
                _ => None,
            },
            None => None,
        };
        if let (Some(t), Some(bl)) = (&surface_tex, &self.blitter) {
            let src_view = frame.display.texture().create_view(&Default::default());
            let dst_view = t.texture.create_view(&Default::default());
            bl.copy(&self.gpu.device, &mut enc, &src_view, &dst_view);
        }
        self.gpu.queue.submit([enc.finish()]);
        if let Some(t) = surface_tex {
            self.gpu.queue.present(t);
        }
        self.profiler.collect(&self.gpu)?;
        self.prev_camera = Some(cam);
        self.index += 1;
        Ok(())
    }

    fn frames_left(&self) -> Option<u32> {
        self.args.frames.map(|n| n.saturating_sub(self.index))
    }

    fn screenshot(&self) -> Result<()> {
        let frame = self.frame.as_ref().context("nothing rendered yet")?;
        let img = frame.display.read_rgba()?;
        // A blank (uniform) image means nothing was drawn: say so rather than save it silently.
        let lum = |p: &image::Rgba<u8>| p.0[0] as u32 + p.0[1] as u32 + p.0[2] as u32;
        let (lo, hi) = img
            .pixels()
            .fold((u32::MAX, 0), |(l, h), p| (l.min(lum(p)), h.max(lum(p))));
        anyhow::ensure!(
            hi > lo + 6,
            "the rendered image is blank (uniform colour); not saving it"
        );
        img.save(&self.args.screenshot)
            .with_context(|| format!("cannot write {}", self.args.screenshot.display()))?;
        println!("saved {}", self.args.screenshot.display());
        Ok(())
    }

    fn resize(&mut self, w: u32, h: u32) -> Result<()> {
        if let (Some(s), Some(c)) = (&self.surface, &mut self.config) {
            c.width = w.max(1);
            c.height = h.max(1);
            s.configure(&self.gpu.device, c);
        }
        // New size: new buffers, and the denoiser's history starts afresh.
        self.frame = Some(self.make_frame(w.max(1), h.max(1))?);
        self.prev_camera = None;
        Ok(())
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, el: &ActiveEventLoop) {
        if self.window.is_some() {
            return;
        }
        let attrs = Window::default_attributes()
            .with_title(format!("subpixel — {}", self.args.scene))
            .with_inner_size(winit::dpi::PhysicalSize::new(self.args.width, self.args.height));
        let result = (|| -> Result<()> {
            let window = Arc::new(el.create_window(attrs)?);
            let (instance, adapter) = self
                .gpu
                .origin
                .as_ref()
                .context("the GPU context has no instance")?;
            let surface = instance.create_surface(window.clone())?;
            let size = window.inner_size();
            let mut config = surface
                .get_default_config(adapter, size.width.max(1), size.height.max(1))
                .context("the window surface is not supported by the adapter")?;
            config.usage = wgpu::TextureUsages::RENDER_ATTACHMENT;
            surface.configure(&self.gpu.device, &config);
            self.blitter = Some(wgpu::util::TextureBlitter::new(&self.gpu.device, config.format));
            self.surface = Some(surface);
            self.config = Some(config);
            self.window = Some(window);
            self.resize(size.width, size.height)
        })();
        if let Err(e) = result {
            self.error = Some(e);
            el.exit();
        }
    }

    fn window_event(&mut self, el: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        let r = (|| -> Result<()> {
            match event {
                WindowEvent::CloseRequested => el.exit(),
                WindowEvent::Resized(s) => self.resize(s.width, s.height)?,
                WindowEvent::KeyboardInput { event, .. } => {
                    let down = event.state == ElementState::Pressed;
                    let PhysicalKey::Code(k) = event.physical_key else {
                        return Ok(());
                    };
                    let fly_key = [
                        KeyCode::KeyW,
                        KeyCode::KeyS,
                        KeyCode::KeyA,
                        KeyCode::KeyD,
                        KeyCode::KeyE,
                        KeyCode::KeyQ,
                    ]
                    .iter()
                    .position(|c| *c == k);
                    if let Some(i) = fly_key {
                        self.fly.keys[i] = down;
                        return Ok(());
                    }
                    if !down {
                        return Ok(());
                    }
                    let v = match k {
                        KeyCode::Digit1 => Some(ViewKind::Input),
                        KeyCode::Digit2 => Some(ViewKind::Ssr),
                        KeyCode::Digit3 => Some(ViewKind::Split),
                        KeyCode::Digit4 => Some(ViewKind::Accumulated),
                        KeyCode::Digit5 => Some(ViewKind::Reference),
                        KeyCode::Digit6 => Some(ViewKind::Albedo),
                        KeyCode::Digit7 => Some(ViewKind::Normal),
                        KeyCode::Digit8 => Some(ViewKind::Depth),
                        KeyCode::Digit9 => Some(ViewKind::Shadow),
                        KeyCode::Digit0 => Some(ViewKind::Motion),
                        KeyCode::KeyM => Some(ViewKind::Mask),
                        KeyCode::KeyT => Some(ViewKind::Transparent),
                        KeyCode::KeyG => Some(ViewKind::Metallic),
                        KeyCode::KeyR => Some(ViewKind::Roughness),
                        _ => None,
                    };
                    if let Some(v) = v {
                        if v == ViewKind::Reference {
                            if let Some(f) = &mut self.frame {
                                f.reference_spp = 0;
                            }
                        }
                        self.view = v;
                    }
                    match k {
                        KeyCode::KeyP => self.playing = !self.playing && self.path.is_some(),
                        KeyCode::F12 => self.screenshot()?,
                        KeyCode::Escape => el.exit(),
                        _ => {}
                    }
                }
                WindowEvent::MouseInput {
                    state,
                    button: MouseButton::Left,
                    ..
                } => {
                    self.fly.dragging = state == ElementState::Pressed;
                    self.fly.last_mouse = None;
                }
                WindowEvent::CursorMoved { position, .. } if self.fly.dragging => {
                    if let Some((x, y)) = self.fly.last_mouse {
                        self.fly.yaw += 0.005 * (position.x - x) as f32;
                        self.fly.pitch = (self.fly.pitch - 0.005 * (position.y - y) as f32).clamp(-1.5, 1.5);
                        self.fly.moved = true;
                    }
                    self.fly.last_mouse = Some((position.x, position.y));
                }
                WindowEvent::MouseWheel { delta, .. } => {
                    let d = match delta {
                        MouseScrollDelta::LineDelta(_, y) => y,
                        MouseScrollDelta::PixelDelta(p) => p.y as f32 / 40.0,
                    };
                    self.fly.speed *= 1.2f32.powf(d);
                }
                WindowEvent::RedrawRequested => {
                    self.step()?;
                    if self.frames_left() == Some(0) {
                        self.screenshot()?;
                        el.exit();
                    } else if let Some(w) = &self.window {
                        w.request_redraw();
                    }
                }
                _ => {}
            }
            Ok(())
        })();
        if let Err(e) = r {
            self.error = Some(e);
            el.exit();
        }
    }

    fn about_to_wait(&mut self, _el: &ActiveEventLoop) {
        if let Some(w) = &self.window {
            w.request_redraw();
        }
    }
}

fn main() -> Result<()> {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    let args = Args::parse();
    let gpu = Gpu::new()?;
    let scene = load_scene_with(&args.scene, &args.scene_options)?;
    let weights_path = args
        .weights
        .clone()
        .unwrap_or_else(|| PathBuf::from("weights/ssr.safetensors"));
    let weights = Weights::load(&weights_path)?;
    let (lo, hi) = scene.bounds();
    let extent = (hi - lo).length().max(1e-3);
    let far = scene.far_distance([&scene.camera.position]);
    let background = scene.default_background();
    let gpu_scene = GpuScene::new(&gpu, &scene)?;
    let path = scene
        .camera_path
        .as_ref()
        .map(|spec| CameraPath::from_spec(spec, &scene.camera, 1, 240, &gpu_scene.bvh));
    let event_loop = EventLoop::new()?;
    event_loop.set_control_flow(ControlFlow::Poll);
    let mut app = App {
        view: args.view.unwrap_or(if args.split {
            ViewKind::Split
        } else {
            ViewKind::Ssr
        }),
        profiler: Profiler::new(&gpu, 16),
        fly: Fly::new(scene.camera, extent),
        playing: path.is_some() && args.frames.is_some(),
        path,
        args,
        gpu,
        scene: gpu_scene,
        far,
        background,
        weights,
        window: None,
        surface: None,
        config: None,
        blitter: None,
        frame: None,
        index: 0,
        prev_camera: None,
        fps: Vec::new(),
        last: Instant::now(),
        error: None,
    };
    event_loop.run_app(&mut app)?;
    if let Some(e) = app.error {
        return Err(e);
    }
    Ok(())
}
